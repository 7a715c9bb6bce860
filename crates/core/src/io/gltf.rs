//! glTF 2.0 reading and writing: `.gltf` with embedded `data:` buffers and
//! `.glb`.
//!
//! Reading gathers every triangle primitive of every mesh into one [`Mesh`]
//! in the meshes' own (local) space; no node transform is applied. Each
//! POSITION accessor contributes its vertices once, in the order first met
//! (meshes, then primitives, in index order), however many primitives use
//! it. Strips and fans become triangles (their degenerate joining
//! triangles dropped); points and lines are left out, and a document with
//! nothing else is refused. Indices may be u8, u16 or u32 or absent;
//! buffer views may be interleaved; accessors may be sparse; positions may
//! be float or (`KHR_mesh_quantization`) normalized or plain integers.
//!
//! Every read is bounds-checked against the real buffer bytes before
//! anything is allocated for it; an accessor without a buffer view may not
//! claim more elements than the file has bytes. Buffers must be in the GLB
//! binary chunk or in base64 `data:` URIs: other URIs are never fetched and
//! are refused. Image URIs are neither fetched nor needed and are kept as
//! they are. Required extensions that change how geometry is stored (Draco,
//! meshopt) or that this reader does not know are refused by name.
//!
//! Writing keeps the JSON document (materials, textures, nodes, animations,
//! extras, unknown extensions and properties) and every buffer byte, and
//! replaces only the positions: in place when the data is plain float in a
//! buffer view used by nothing else, otherwise by pointing the accessor at
//! new float data appended to buffer 0. Accessor `min`/`max` are updated.
//! NORMAL attributes are recomputed (area-weighted, across seams that had
//! the same normal before). JSON object keys come out sorted.

use super::weld::{FastMap, FastState};
use super::{IoError, ReadLimits, VertexResults};
use crate::error::MeshError;
use crate::mesh::Mesh;
use base64::Engine as _;
use glam::DVec3;
use serde::Deserialize;
use serde_json::{Map, Value, json};
use std::collections::HashMap;

const FORMAT: &str = "glTF";
const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
const ARRAY_BUFFER: u32 = 34962;
const FLOAT: u32 = 5126;

/// Required extensions that do not change how vertex positions and
/// indices are stored, so a document using them can be smoothed and
/// written back. `KHR_materials_` covers every material extension.
const HARMLESS_EXTENSIONS: &[&str] = &[
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "KHR_texture_basisu",
    "KHR_lights_punctual",
    "KHR_xmp_json_ld",
    "KHR_animation_pointer",
    "EXT_texture_webp",
    "EXT_texture_avif",
    "EXT_mesh_gpu_instancing",
    "EXT_lights_image_based",
    "MSFT_texture_dds",
];
/// Compressions whose data this reader cannot decode; a primitive using
/// one that is not required still has plain accessors, which are used, and
/// the writer drops the compressed copy.
const DRACO: &str = "KHR_draco_mesh_compression";

/// What a glTF document needs besides the mesh to be written back.
#[derive(Debug, Clone)]
pub struct GltfSource {
    /// Whether the input was a `.glb`.
    pub binary: bool,
    root: Value,
    /// Decoded bytes of every buffer (exactly `byteLength` long).
    buffers: Vec<Vec<u8>>,
    /// One per POSITION accessor read, in mesh vertex order.
    blocks: Vec<Block>,
    normals: Vec<NormalTarget>,
    /// Every primitive with a POSITION attribute: (mesh, primitive, block),
    /// points and lines included, for the per-vertex result attributes.
    primitives: Vec<(usize, usize, Option<usize>)>,
    num_vertices: usize,
}

#[derive(Debug, Clone)]
struct Block {
    accessor: usize,
    /// The glTF mesh that first uses it.
    mesh: usize,
    /// First mesh vertex of this accessor's elements.
    start: usize,
    count: usize,
    in_place: Option<InPlace>,
}

/// Where a dense float VEC3 accessor's elements lie, for in-place writes.
#[derive(Debug, Clone, Copy)]
struct InPlace {
    buffer: usize,
    offset: usize,
    stride: usize,
}

#[derive(Debug, Clone)]
struct NormalTarget {
    accessor: usize,
    block: usize,
    /// The normals as read, one per vertex of the block.
    original: Vec<DVec3>,
    /// Triangles of the primitives using this NORMAL, block-local.
    triangles: Vec<[u32; 3]>,
    in_place: Option<InPlace>,
}

impl GltfSource {
    /// Vertices of the (unwelded) mesh read from the document.
    pub fn num_vertices(&self) -> usize {
        self.num_vertices
    }

    /// For each vertex, the index of the glTF mesh it belongs to: welding
    /// joins vertices of one mesh only, since each mesh lives in its own
    /// space.
    pub fn vertex_groups(&self) -> Vec<u32> {
        let mut groups = vec![0; self.num_vertices];
        for b in &self.blocks {
            if let Some(part) = groups.get_mut(b.start..b.start + b.count) {
                part.fill(b.mesh as u32);
            }
        }
        groups
    }
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
struct Accessor {
    buffer_view: Option<usize>,
    #[serde(default)]
    byte_offset: u64,
    component_type: u32,
    #[serde(default)]
    normalized: bool,
    count: u64,
    #[serde(rename = "type")]
    kind: String,
    sparse: Option<Sparse>,
}

#[derive(Debug, Deserialize)]
struct Sparse {
    count: u64,
    indices: SparseIndices,
    values: SparseValues,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
struct SparseIndices {
    buffer_view: usize,
    #[serde(default)]
    byte_offset: u64,
    component_type: u32,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
struct SparseValues {
    buffer_view: usize,
    #[serde(default)]
    byte_offset: u64,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
struct BufferView {
    buffer: usize,
    #[serde(default)]
    byte_offset: u64,
    byte_length: u64,
    byte_stride: Option<u64>,
}

fn invalid(message: String) -> IoError {
    IoError::GltfInvalid {
        accessor: None,
        message,
    }
}

fn invalid_accessor(accessor: usize, message: String) -> IoError {
    IoError::GltfInvalid {
        accessor: Some(accessor),
        message: format!("accessor {accessor}: {message}"),
    }
}

fn glb_invalid(message: String) -> IoError {
    IoError::GlbInvalid(message)
}

/// Whether `bytes` start with the GLB magic.
pub fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(GLB_MAGIC)
}

fn u32_le(bytes: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?))
}

/// Splits a GLB into its JSON chunk and optional BIN chunk. Chunks of
/// unknown type are skipped, as the specification asks.
fn parse_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), IoError> {
    if bytes.len() < 12 {
        return Err(glb_invalid(format!(
            "the file has {} bytes; a GLB starts with a 12-byte header",
            bytes.len()
        )));
    }
    if !is_glb(bytes) {
        return Err(glb_invalid(
            "the file does not start with the `glTF` magic".into(),
        ));
    }
    let version = u32_le(bytes, 4).unwrap_or(0);
    if version != 2 {
        return Err(glb_invalid(format!(
            "GLB container version {version}; only version 2 is supported"
        )));
    }
    let length = u32_le(bytes, 8).unwrap_or(0) as usize;
    if length != bytes.len() {
        return Err(glb_invalid(format!(
            "the header gives a length of {length} bytes but the file has {}",
            bytes.len()
        )));
    }
    let mut json = None;
    let mut bin = None;
    let mut pos = 12;
    let mut index = 0;
    while pos < bytes.len() {
        let (Some(len), Some(kind)) = (u32_le(bytes, pos), u32_le(bytes, pos + 4)) else {
            return Err(glb_invalid(format!(
                "chunk {index} at byte {pos}: the file ends inside the 8-byte chunk header"
            )));
        };
        let start = pos + 8;
        let Some(data) = start
            .checked_add(len as usize)
            .and_then(|end| bytes.get(start..end))
        else {
            return Err(glb_invalid(format!(
                "chunk {index} at byte {pos} claims {len} bytes but only {} remain",
                bytes.len().saturating_sub(start)
            )));
        };
        match kind {
            CHUNK_JSON if index == 0 => json = Some(data),
            CHUNK_JSON => return Err(glb_invalid(format!("chunk {index} is a second JSON chunk"))),
            CHUNK_BIN if index == 1 => bin = Some(data),
            CHUNK_BIN if index == 0 => {
                return Err(glb_invalid("the first chunk must be JSON, not BIN".into()));
            }
            CHUNK_BIN => {
                return Err(glb_invalid(format!(
                    "chunk {index} is a BIN chunk; only the second chunk may be BIN"
                )));
            }
            _ if index == 0 => {
                return Err(glb_invalid(format!(
                    "the first chunk has type 0x{kind:08X}; it must be JSON"
                )));
            }
            _ => {}
        }
        pos = start + len as usize;
        index += 1;
    }
    let json = json.ok_or_else(|| glb_invalid("the file has no JSON chunk".into()))?;
    if json.starts_with(b"\xEF\xBB\xBF") {
        return Err(glb_invalid(
            "the JSON chunk starts with a byte-order mark, which GLB forbids".into(),
        ));
    }
    Ok((json, bin))
}

/// Parses a `.gltf` (JSON) or `.glb` (by its magic) into the mesh of all
/// its triangle primitives and what [`write_gltf`] needs.
pub fn read_gltf(bytes: &[u8], limits: &ReadLimits) -> Result<(Mesh, GltfSource), IoError> {
    let binary = is_glb(bytes);
    let (json, bin) = if binary {
        parse_glb(bytes)?
    } else {
        (bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes), None)
    };
    let root: Value = serde_json::from_slice(json)
        .map_err(|e| invalid(format!("the JSON does not parse: {e}")))?;
    if !root.is_object() {
        return Err(invalid("the JSON document is not an object".into()));
    }
    check_asset(&root)?;
    check_required_extensions(&root)?;
    let buffers = load_buffers(&root, bin)?;
    let mut reader = Reader {
        root: &root,
        buffers: &buffers,
        limits,
        input_len: bytes.len(),
        positions: Vec::new(),
        faces: Vec::new(),
        blocks: Vec::new(),
        block_of: HashMap::new(),
        normals: Vec::new(),
        normal_of: HashMap::new(),
        primitives: Vec::new(),
        skipped: None,
    };
    reader.read_meshes()?;
    let Reader {
        positions,
        faces,
        mut blocks,
        mut normals,
        primitives,
        skipped,
        ..
    } = reader;
    if faces.is_empty() {
        return Err(match skipped {
            Some((mesh, primitive, mode)) => IoError::UnsupportedPrimitiveMode {
                mesh,
                primitive,
                mode,
            },
            None => IoError::NoFaces {
                format: FORMAT,
                message: format!(
                    "the document has {} vertices in triangle primitives and no triangles; smoothing needs a surface",
                    positions.len()
                ),
            },
        });
    }
    // An accessor used as NORMAL and as POSITION holds positions.
    normals.retain(|n| blocks.iter().all(|b| b.accessor != n.accessor));
    mark_in_place(&root, &buffers, &mut blocks, &mut normals);
    let num_vertices = positions.len();
    let offsets = (0..=faces.len()).map(|f| 3 * f as u32).collect();
    let corners = faces.into_iter().flatten().collect();
    let mesh = Mesh::new(positions, offsets, corners)?;
    let source = GltfSource {
        binary,
        root,
        buffers,
        blocks,
        normals,
        primitives,
        num_vertices,
    };
    Ok((mesh, source))
}

fn check_asset(root: &Value) -> Result<(), IoError> {
    let version = root
        .get("asset")
        .and_then(|a| a.get("version"))
        .and_then(Value::as_str)
        .ok_or_else(|| invalid("the document has no `asset.version`".into()))?;
    if !version.starts_with("2.") {
        return Err(IoError::Unsupported {
            format: FORMAT,
            message: format!("glTF version {version}; only 2.x is supported"),
        });
    }
    Ok(())
}

fn check_required_extensions(root: &Value) -> Result<(), IoError> {
    let Some(required) = root.get("extensionsRequired").and_then(Value::as_array) else {
        return Ok(());
    };
    for name in required.iter().filter_map(Value::as_str) {
        let harmless = name.starts_with("KHR_materials_") || HARMLESS_EXTENSIONS.contains(&name);
        if !harmless {
            return Err(IoError::UnsupportedExtension {
                format: FORMAT,
                name: name.to_owned(),
            });
        }
    }
    Ok(())
}

fn load_buffers(root: &Value, bin: Option<&[u8]>) -> Result<Vec<Vec<u8>>, IoError> {
    let Some(list) = root.get("buffers") else {
        return Ok(Vec::new());
    };
    let list = list
        .as_array()
        .ok_or_else(|| invalid("`buffers` is not an array".into()))?;
    let mut buffers = Vec::with_capacity(list.len());
    for (i, buffer) in list.iter().enumerate() {
        let length = buffer
            .get("byteLength")
            .and_then(Value::as_u64)
            .ok_or_else(|| invalid(format!("buffer {i} has no valid `byteLength`")))?;
        let data = match buffer.get("uri") {
            None => match (i, bin) {
                (0, Some(bin)) => bin.to_vec(),
                _ => {
                    return Err(invalid(format!(
                        "buffer {i} has no `uri` and is not the GLB binary chunk"
                    )));
                }
            },
            Some(uri) => {
                let uri = uri.as_str().ok_or_else(|| {
                    invalid(format!("buffer {i} has a `uri` that is not a string"))
                })?;
                decode_data_uri(uri).map_err(|e| match e {
                    DataUriError::External => IoError::ExternalUri {
                        what: "buffer",
                        index: i,
                        uri: shorten(uri).to_owned(),
                    },
                    DataUriError::Malformed(why) => invalid(format!("buffer {i}: {why}")),
                })?
            }
        };
        if (data.len() as u64) < length {
            return Err(invalid(format!(
                "buffer {i} declares {length} bytes but holds only {}",
                data.len()
            )));
        }
        let mut data = data;
        data.truncate(length as usize);
        buffers.push(data);
    }
    Ok(buffers)
}

fn shorten(text: &str) -> &str {
    let mut end = text.len().min(80);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    text.get(..end).unwrap_or_default()
}

enum DataUriError {
    External,
    Malformed(String),
}

/// Decodes a base64 `data:` URI; anything else is external.
fn decode_data_uri(uri: &str) -> Result<Vec<u8>, DataUriError> {
    let Some(rest) = uri.strip_prefix("data:") else {
        return Err(DataUriError::External);
    };
    let Some((meta, payload)) = rest.split_once(',') else {
        return Err(DataUriError::Malformed("the data: URI has no `,`".into()));
    };
    if !meta.ends_with(";base64") {
        return Err(DataUriError::Malformed(
            "only base64 data: URIs are supported".into(),
        ));
    }
    let engine = base64::engine::GeneralPurpose::new(
        &base64::alphabet::STANDARD,
        base64::engine::GeneralPurposeConfig::new()
            .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
    );
    engine
        .decode(payload.trim_end())
        .map_err(|e| DataUriError::Malformed(format!("bad base64 in the data: URI ({e})")))
}

/// Base64 `data:` URI of `bytes`.
fn encode_data_uri(bytes: &[u8]) -> String {
    let mut uri = String::from("data:application/octet-stream;base64,");
    base64::engine::general_purpose::STANDARD.encode_string(bytes, &mut uri);
    uri
}

/// Decoding state while walking the meshes.
struct Reader<'a> {
    root: &'a Value,
    buffers: &'a [Vec<u8>],
    limits: &'a ReadLimits,
    input_len: usize,
    positions: Vec<DVec3>,
    faces: Vec<[u32; 3]>,
    blocks: Vec<Block>,
    block_of: HashMap<usize, usize>,
    normals: Vec<NormalTarget>,
    /// NORMAL accessor -> its target, or None when it is shared with
    /// another POSITION accessor (left as it is).
    normal_of: HashMap<usize, Option<usize>>,
    primitives: Vec<(usize, usize, Option<usize>)>,
    /// First points or lines primitive: (mesh, primitive, mode).
    skipped: Option<(usize, usize, u64)>,
}

/// Component types and their byte sizes.
fn component_size(component_type: u32) -> Option<usize> {
    match component_type {
        5120 | 5121 => Some(1),
        5122 | 5123 => Some(2),
        5125 | 5126 => Some(4),
        _ => None,
    }
}

fn type_components(kind: &str) -> Option<usize> {
    Some(match kind {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" | "MAT2" => 4,
        "MAT3" => 9,
        "MAT4" => 16,
        _ => return None,
    })
}

/// One component as f64 (little endian), normalized to [-1, 1] / [0, 1]
/// when asked.
fn component(bytes: &[u8], component_type: u32, normalized: bool) -> Option<f64> {
    let b = |n: usize| bytes.get(..n);
    Some(match component_type {
        5120 => {
            let c = f64::from(i8::from_le_bytes(b(1)?.try_into().ok()?));
            if normalized { (c / 127.0).max(-1.0) } else { c }
        }
        5121 => {
            let c = f64::from(b(1)?[0]);
            if normalized { c / 255.0 } else { c }
        }
        5122 => {
            let c = f64::from(i16::from_le_bytes(b(2)?.try_into().ok()?));
            if normalized {
                (c / 32767.0).max(-1.0)
            } else {
                c
            }
        }
        5123 => {
            let c = f64::from(u16::from_le_bytes(b(2)?.try_into().ok()?));
            if normalized { c / 65535.0 } else { c }
        }
        5125 => f64::from(u32::from_le_bytes(b(4)?.try_into().ok()?)),
        5126 => f64::from(f32::from_le_bytes(b(4)?.try_into().ok()?)),
        _ => return None,
    })
}

impl<'a> Reader<'a> {
    fn array(&self, key: &str) -> &'a [Value] {
        self.root
            .get(key)
            .and_then(Value::as_array)
            .map_or(&[], Vec::as_slice)
    }

    fn accessor(&self, index: usize) -> Result<Accessor, IoError> {
        let value = self
            .array("accessors")
            .get(index)
            .ok_or_else(|| invalid_accessor(index, "no such accessor".into()))?;
        Accessor::deserialize(value).map_err(|e| invalid_accessor(index, e.to_string()))
    }

    /// Bytes of buffer view `view`, bounds-checked, and its stride.
    fn view(&self, view: usize, accessor: usize) -> Result<(&[u8], Option<u64>), IoError> {
        let value = self.array("bufferViews").get(view).ok_or_else(|| {
            invalid_accessor(accessor, format!("buffer view {view} does not exist"))
        })?;
        let v = BufferView::deserialize(value)
            .map_err(|e| invalid(format!("buffer view {view}: {e}")))?;
        let buffer = self.buffers.get(v.buffer).ok_or_else(|| {
            invalid(format!(
                "buffer view {view} refers to missing buffer {}",
                v.buffer
            ))
        })?;
        let end = v.byte_offset.checked_add(v.byte_length);
        let bytes = end
            .filter(|&e| e <= buffer.len() as u64)
            .and_then(|e| buffer.get(v.byte_offset as usize..e as usize))
            .ok_or_else(|| {
                invalid(format!(
                    "buffer view {view} (bytes {}..+{}) lies outside buffer {} of {} bytes",
                    v.byte_offset,
                    v.byte_length,
                    v.buffer,
                    buffer.len()
                ))
            })?;
        Ok((bytes, v.byte_stride))
    }

    /// Decodes every element of accessor `index` with `decode` (given the
    /// element's bytes), checking each read against the buffer first.
    fn elements<T: Copy + Default>(
        &self,
        index: usize,
        acc: &Accessor,
        decode: impl Fn(&[u8]) -> Option<T>,
    ) -> Result<Vec<T>, IoError> {
        let err = |m: String| invalid_accessor(index, m);
        let components = type_components(&acc.kind)
            .ok_or_else(|| err(format!("unknown type `{}`", shorten(&acc.kind))))?;
        let size = component_size(acc.component_type)
            .ok_or_else(|| err(format!("unknown component type {}", acc.component_type)))?;
        let element = components * size;
        if acc.count == 0 {
            return Err(err("count is 0".into()));
        }
        let count = acc.count as usize;
        let mut values = match acc.buffer_view {
            Some(view) => {
                let (bytes, stride) = self.view(view, index)?;
                let stride = stride.map_or(element as u64, |s| s);
                if stride < element as u64 {
                    return Err(err(format!(
                        "byte stride {stride} is smaller than the {element}-byte element"
                    )));
                }
                let needed = u128::from(acc.byte_offset)
                    + u128::from(stride) * u128::from(acc.count - 1)
                    + element as u128;
                if needed > bytes.len() as u128 {
                    return Err(err(format!(
                        "{} elements need {needed} bytes of buffer view {view}, which has {}",
                        acc.count,
                        bytes.len()
                    )));
                }
                let stride = stride as usize;
                let base = bytes.get(acc.byte_offset as usize..).unwrap_or_default();
                let mut values = Vec::with_capacity(count);
                for i in 0..count {
                    let value = base
                        .get(i * stride..i * stride + element)
                        .and_then(&decode)
                        .ok_or_else(|| err(format!("element {i} cannot be decoded")))?;
                    values.push(value);
                }
                values
            }
            None => {
                if acc.sparse.is_none() {
                    return Err(err("it has neither a buffer view nor sparse values".into()));
                }
                // Zeros plus sparse substitutions: bound the claimed count by
                // the input size, since no buffer backs it.
                if count > self.input_len {
                    return Err(err(format!(
                        "it has no buffer view and claims {count} elements, more than the file has bytes"
                    )));
                }
                vec![T::default(); count]
            }
        };
        if let Some(sparse) = &acc.sparse {
            self.apply_sparse(index, sparse, count, element, &decode, &mut values)?;
        }
        Ok(values)
    }

    fn apply_sparse<T>(
        &self,
        index: usize,
        sparse: &Sparse,
        count: usize,
        element: usize,
        decode: &impl Fn(&[u8]) -> Option<T>,
        values: &mut [T],
    ) -> Result<(), IoError> {
        let err = |m: String| invalid_accessor(index, m);
        let n = sparse.count;
        if n == 0 || n > count as u64 {
            return Err(err(format!("sparse count {n} is not in 1..={count}")));
        }
        let n = n as usize;
        let index_size = match sparse.indices.component_type {
            5121 => 1,
            5123 => 2,
            5125 => 4,
            t => return Err(err(format!("sparse indices have component type {t}"))),
        };
        let (ibytes, _) = self.view(sparse.indices.buffer_view, index)?;
        let ibytes = ibytes
            .get(sparse.indices.byte_offset as usize..)
            .filter(|b| b.len() as u128 >= (n * index_size) as u128)
            .ok_or_else(|| err("sparse indices run past their buffer view".into()))?;
        let (vbytes, _) = self.view(sparse.values.buffer_view, index)?;
        let vbytes = vbytes
            .get(sparse.values.byte_offset as usize..)
            .filter(|b| b.len() as u128 >= (n * element) as u128)
            .ok_or_else(|| err("sparse values run past their buffer view".into()))?;
        for k in 0..n {
            let target = component(
                ibytes.get(k * index_size..).unwrap_or_default(),
                sparse.indices.component_type,
                false,
            )
            .unwrap_or(f64::MAX);
            let value = vbytes
                .get(k * element..(k + 1) * element)
                .and_then(decode)
                .ok_or_else(|| err(format!("sparse value {k} cannot be decoded")))?;
            let slot = values
                .get_mut(target as usize)
                .filter(|_| target < count as f64);
            let Some(slot) = slot else {
                return Err(err(format!(
                    "sparse index {target} is beyond the {count} elements"
                )));
            };
            *slot = value;
        }
        Ok(())
    }

    /// VEC3 values of an accessor (positions or normals).
    fn vec3s(&self, index: usize, acc: &Accessor, what: &str) -> Result<Vec<DVec3>, IoError> {
        if acc.kind != "VEC3" {
            return Err(invalid_accessor(
                index,
                format!("{what} must be VEC3, not {}", shorten(&acc.kind)),
            ));
        }
        let ct = acc.component_type;
        if ct == 5125 || (ct == FLOAT && acc.normalized) {
            return Err(invalid_accessor(
                index,
                format!(
                    "{what} cannot have component type {ct}{}",
                    if acc.normalized { " normalized" } else { "" }
                ),
            ));
        }
        let size = component_size(ct).unwrap_or(4);
        let norm = acc.normalized;
        let values = self.elements(index, acc, |b| {
            Some(DVec3::new(
                component(b, ct, norm)?,
                component(b.get(size..)?, ct, norm)?,
                component(b.get(2 * size..)?, ct, norm)?,
            ))
        })?;
        if let Some(i) = values.iter().position(|p| !p.is_finite()) {
            return Err(invalid_accessor(
                index,
                format!("element {i} has a non-finite coordinate (NaN or infinity)"),
            ));
        }
        Ok(values)
    }

    fn indices(&self, index: usize) -> Result<Vec<u32>, IoError> {
        let acc = self.accessor(index)?;
        if acc.kind != "SCALAR"
            || !matches!(acc.component_type, 5121 | 5123 | 5125)
            || acc.normalized
        {
            return Err(invalid_accessor(
                index,
                format!(
                    "indices must be SCALAR unsigned byte, short or int, not {} of component type {}",
                    shorten(&acc.kind),
                    acc.component_type
                ),
            ));
        }
        let ct = acc.component_type;
        self.elements(index, &acc, |b| component(b, ct, false).map(|v| v as u32))
    }

    fn read_meshes(&mut self) -> Result<(), IoError> {
        let meshes = self.array("meshes");
        for (m, mesh) in meshes.iter().enumerate() {
            let primitives = mesh
                .get("primitives")
                .and_then(Value::as_array)
                .map_or(&[][..], Vec::as_slice);
            for (p, primitive) in primitives.iter().enumerate() {
                self.primitive(m, p, primitive)?;
            }
        }
        Ok(())
    }

    fn primitive(&mut self, m: usize, p: usize, primitive: &Value) -> Result<(), IoError> {
        let field = |key: &str| -> Result<Option<usize>, IoError> {
            match primitive.get(key) {
                None => Ok(None),
                Some(v) => v.as_u64().map(|i| Some(i as usize)).ok_or_else(|| {
                    invalid(format!("mesh {m} primitive {p}: `{key}` is not an index"))
                }),
            }
        };
        let attributes = primitive.get("attributes");
        let attribute = |key: &str| -> Result<Option<usize>, IoError> {
            match attributes.and_then(|a| a.get(key)) {
                None => Ok(None),
                Some(v) => v.as_u64().map(|i| Some(i as usize)).ok_or_else(|| {
                    invalid(format!(
                        "mesh {m} primitive {p}: attribute {key} is not an index"
                    ))
                }),
            }
        };
        let mode = match primitive.get("mode") {
            None => 4,
            Some(v) => v.as_u64().ok_or_else(|| {
                invalid(format!("mesh {m} primitive {p}: `mode` is not an integer"))
            })?,
        };
        let Some(position) = attribute("POSITION")? else {
            return Ok(());
        };
        match mode {
            4..=6 => {}
            0..=3 => {
                self.skipped.get_or_insert((m, p, mode));
                self.primitives
                    .push((m, p, self.block_of.get(&position).copied()));
                return Ok(());
            }
            _ => {
                return Err(invalid(format!(
                    "mesh {m} primitive {p} has mode {mode}; glTF modes are 0 to 6"
                )));
            }
        }
        let block = self.block(position, m)?;
        self.primitives.push((m, p, Some(block)));
        let (start, count) = self
            .blocks
            .get(block)
            .map(|b| (b.start, b.count))
            .unwrap_or_default();
        let indices = match field("indices")? {
            Some(a) => {
                let indices = self.indices(a)?;
                if let Some(&bad) = indices.iter().find(|&&i| i as usize >= count) {
                    return Err(invalid_accessor(
                        a,
                        format!(
                            "index {bad} is beyond POSITION accessor {position}'s {count} vertices"
                        ),
                    ));
                }
                indices
            }
            None => (0..count as u32).collect(),
        };
        let triangles = triangles(&indices, mode)
            .map_err(|why| invalid(format!("mesh {m} primitive {p}: {why}")))?;
        let total = self.faces.len() + triangles.len();
        if total > self.limits.max_faces {
            return Err(IoError::Limit {
                what: "face",
                count: total,
                limit: self.limits.max_faces,
            });
        }
        let offset = start as u32;
        self.faces.extend(
            triangles
                .iter()
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
        if let Some(normal) = attribute("NORMAL")? {
            self.normal(normal, block, count, triangles)?;
        }
        Ok(())
    }

    /// The block of POSITION accessor `index`, reading it the first time.
    fn block(&mut self, index: usize, mesh: usize) -> Result<usize, IoError> {
        if let Some(&b) = self.block_of.get(&index) {
            return Ok(b);
        }
        let acc = self.accessor(index)?;
        let total = (self.positions.len() as u64).saturating_add(acc.count);
        if total > self.limits.max_vertices as u64 {
            return Err(IoError::Limit {
                what: "vertex",
                count: usize::try_from(total).unwrap_or(usize::MAX),
                limit: self.limits.max_vertices,
            });
        }
        let values = self.vec3s(index, &acc, "POSITION")?;
        let block = Block {
            accessor: index,
            mesh,
            start: self.positions.len(),
            count: values.len(),
            in_place: None,
        };
        self.positions.extend(values);
        self.blocks.push(block);
        self.block_of.insert(index, self.blocks.len() - 1);
        Ok(self.blocks.len() - 1)
    }

    fn normal(
        &mut self,
        index: usize,
        block: usize,
        count: usize,
        triangles: Vec<[u32; 3]>,
    ) -> Result<(), IoError> {
        match self.normal_of.get(&index).copied() {
            Some(None) => {}
            Some(Some(t)) => {
                if let Some(target) = self.normals.get_mut(t) {
                    if target.block == block {
                        target.triangles.extend(triangles);
                    } else {
                        // One NORMAL with two POSITION accessors: keep it.
                        self.normals.remove(t);
                        self.normal_of.insert(index, None);
                        for v in self.normal_of.values_mut() {
                            if let Some(k) = v
                                && *k > t
                            {
                                *k -= 1;
                            }
                        }
                    }
                }
            }
            None => {
                let acc = self.accessor(index)?;
                if acc.count != count as u64 {
                    return Err(invalid_accessor(
                        index,
                        format!("NORMAL has {} elements but POSITION has {count}", acc.count),
                    ));
                }
                let original = self.vec3s(index, &acc, "NORMAL")?;
                self.normals.push(NormalTarget {
                    accessor: index,
                    block,
                    original,
                    triangles,
                    in_place: None,
                });
                self.normal_of.insert(index, Some(self.normals.len() - 1));
            }
        }
        Ok(())
    }
}

/// Triangles of a primitive of `mode` (4, 5 or 6) over `indices`; the
/// degenerate triangles that join strips and fans are dropped.
fn triangles(indices: &[u32], mode: u64) -> Result<Vec<[u32; 3]>, String> {
    let n = indices.len();
    let distinct = |t: &[u32; 3]| t[0] != t[1] && t[1] != t[2] && t[0] != t[2];
    let at = |i: usize| indices.get(i).copied().unwrap_or(0);
    Ok(match mode {
        4 => {
            if !n.is_multiple_of(3) {
                return Err(format!("{n} indices do not make whole triangles"));
            }
            indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect()
        }
        5 => (0..n.saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [at(i), at(i + 1), at(i + 2)]
                } else {
                    [at(i), at(i + 2), at(i + 1)]
                }
            })
            .filter(distinct)
            .collect(),
        _ => (0..n.saturating_sub(2))
            .map(|i| [at(i + 1), at(i + 2), at(0)])
            .filter(distinct)
            .collect(),
    })
}

/// Decides which POSITION and NORMAL accessors are overwritten in place:
/// dense float VEC3 data in a buffer view without extensions that no
/// other accessor, sparse part or image uses.
fn mark_in_place(
    root: &Value,
    buffers: &[Vec<u8>],
    blocks: &mut [Block],
    normals: &mut [NormalTarget],
) {
    let rewritten: Vec<usize> = blocks
        .iter()
        .map(|b| b.accessor)
        .chain(normals.iter().map(|n| n.accessor))
        .collect();
    let empty = Vec::new();
    let accessors = root
        .get("accessors")
        .and_then(Value::as_array)
        .unwrap_or(&empty);
    let views = root
        .get("bufferViews")
        .and_then(Value::as_array)
        .unwrap_or(&empty);
    // Buffer views used by anything other than a rewritten accessor's base.
    let mut foreign = vec![false; views.len()];
    let mut mark = |v: Option<&Value>| {
        if let Some(slot) = v
            .and_then(Value::as_u64)
            .and_then(|v| foreign.get_mut(v as usize))
        {
            *slot = true;
        }
    };
    for (i, acc) in accessors.iter().enumerate() {
        if !rewritten.contains(&i) {
            mark(acc.get("bufferView"));
        }
        if let Some(sparse) = acc.get("sparse") {
            mark(sparse.get("indices").and_then(|s| s.get("bufferView")));
            mark(sparse.get("values").and_then(|s| s.get("bufferView")));
        }
    }
    for image in root
        .get("images")
        .and_then(Value::as_array)
        .unwrap_or(&empty)
    {
        mark(image.get("bufferView"));
    }
    let place = |index: usize| -> Option<(InPlace, usize)> {
        let acc = Accessor::deserialize(accessors.get(index)?).ok()?;
        if acc.sparse.is_some()
            || acc.component_type != FLOAT
            || acc.normalized
            || acc.kind != "VEC3"
        {
            return None;
        }
        let view_index = acc.buffer_view?;
        if *foreign.get(view_index)? {
            return None;
        }
        let view_value = views.get(view_index)?;
        if view_value.get("extensions").is_some() {
            return None;
        }
        let view = BufferView::deserialize(view_value).ok()?;
        let stride = view.byte_stride.unwrap_or(12) as usize;
        let offset = (view.byte_offset + acc.byte_offset) as usize;
        // Bounds were checked on reading; check again for the writer.
        let end = stride
            .checked_mul(usize::try_from(acc.count).ok()?.checked_sub(1)?)?
            .checked_add(offset)?
            .checked_add(12)?;
        (end <= buffers.get(view.buffer)?.len()).then_some((
            InPlace {
                buffer: view.buffer,
                offset,
                stride,
            },
            end,
        ))
    };
    let mut places: Vec<Option<(InPlace, usize)>> = rewritten.iter().map(|&a| place(a)).collect();
    drop_overlapping(&mut places);
    let mut places = places.into_iter().map(|p| p.map(|(place, _)| place));
    for b in blocks.iter_mut() {
        b.in_place = places.next().flatten();
    }
    for n in normals.iter_mut() {
        n.in_place = places.next().flatten();
    }
}

/// Most in-place candidates whose byte ranges may overlap one another
/// before all of them are written by appending instead (bounds the sweep).
const MAX_OVERLAPPING: usize = 64;

/// Withdraws in-place writing from candidates whose elements could share
/// bytes with another's (aliased accessors): they get new data instead.
/// Interleaved accessors (same stride, disjoint slots within it) keep it.
fn drop_overlapping(places: &mut [Option<(InPlace, usize)>]) {
    let mut order: Vec<usize> = (0..places.len())
        .filter(|&i| places.get(i).is_some_and(Option::is_some))
        .collect();
    let key = |i: usize| {
        places
            .get(i)
            .copied()
            .flatten()
            .map_or((0, 0, 0), |(p, end)| (p.buffer, p.offset, end))
    };
    order.sort_by_key(|&i| key(i));
    let compatible = |a: InPlace, b: InPlace| {
        let s = a.stride.max(1);
        let d = (b.offset % s + s - a.offset % s) % s;
        a.stride == b.stride && d >= 12 && s - d >= 12
    };
    let mut conflicted = vec![false; places.len()];
    let mut open: Vec<usize> = Vec::new();
    for &i in &order {
        let (buffer, start, _) = key(i);
        open.retain(|&j| {
            let (b, _, end) = key(j);
            b == buffer && end > start
        });
        if open.len() >= MAX_OVERLAPPING {
            conflicted.iter_mut().for_each(|c| *c = true);
            break;
        }
        for &j in &open {
            let (Some(Some((a, _))), Some(Some((b, _)))) = (places.get(j), places.get(i)) else {
                continue;
            };
            if !compatible(*a, *b) {
                conflicted[i] = true;
                conflicted[j] = true;
            }
        }
        open.push(i);
    }
    for (p, c) in places.iter_mut().zip(conflicted) {
        if c {
            *p = None;
        }
    }
}

/// Writes the document `src` was read from with `positions` (one per
/// vertex of the unwelded mesh [`read_gltf`] returned) and optional
/// per-vertex `results` (each empty or one entry per vertex) added to
/// every primitive as float attributes `_LABEL`, `_MEAN_CURVATURE`,
/// `_GAUSSIAN_CURVATURE`, `_DISPLACEMENT`. `binary` picks `.glb` (buffer 0
/// in the BIN chunk) or `.gltf` (every buffer as a base64 `data:` URI).
pub fn write_gltf(
    src: &GltfSource,
    positions: &[DVec3],
    results: Option<&VertexResults>,
    binary: bool,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    IoError::check_position_count(src.num_vertices, positions.len())?;
    check_f32(positions)?;
    let mut doc = Writer {
        root: src.root.clone(),
        buffers: src.buffers.clone(),
        modified: vec![false; src.buffers.len()],
    };
    for block in &src.blocks {
        let values = positions
            .get(block.start..block.start + block.count)
            .unwrap_or_default();
        doc.write_vec3(block.accessor, values, block.in_place, true)?;
    }
    for target in &src.normals {
        let Some(block) = src.blocks.get(target.block) else {
            continue;
        };
        let values = positions
            .get(block.start..block.start + block.count)
            .unwrap_or_default();
        let normals = vertex_normals(values, target);
        let keep_bounds = doc.accessor_has_bounds(target.accessor);
        doc.write_vec3(target.accessor, &normals, target.in_place, keep_bounds)?;
    }
    if let Some(results) = results {
        doc.add_results(src, results)?;
    }
    doc.drop_draco(src);
    doc.finish(binary, out)
}

/// Refuses positions that are not finite in f32.
fn check_f32(positions: &[DVec3]) -> Result<(), IoError> {
    let bad = positions.iter().position(|p| {
        !(p.x as f32).is_finite() || !(p.y as f32).is_finite() || !(p.z as f32).is_finite()
    });
    match bad {
        Some(vertex) => Err(MeshError::NonFinitePosition { vertex }.into()),
        None => Ok(()),
    }
}

/// Area-weighted vertex normals over the target's triangles; vertices at
/// the same new position whose original normals were equal share one
/// normal (seams split only for texture coordinates stay smooth, hard
/// edges stay hard). A vertex without area keeps its original normal.
fn vertex_normals(positions: &[DVec3], target: &NormalTarget) -> Vec<DVec3> {
    // Keyed by the f32 values the file will hold.
    let bits = |x: f64| (x as f32 + 0.0).to_bits();
    let key = |p: DVec3, n: DVec3| {
        [
            bits(p.x),
            bits(p.y),
            bits(p.z),
            bits(n.x),
            bits(n.y),
            bits(n.z),
        ]
    };
    let mut group_of: FastMap<[u32; 6], u32> =
        FastMap::with_capacity_and_hasher(positions.len(), FastState::new());
    let groups: Vec<u32> = positions
        .iter()
        .zip(&target.original)
        .map(|(&p, &n)| {
            let next = group_of.len() as u32;
            *group_of.entry(key(p, n)).or_insert(next)
        })
        .collect();
    let mut sums = vec![DVec3::ZERO; group_of.len()];
    let at = |i: u32| positions.get(i as usize).copied().unwrap_or_default();
    for t in &target.triangles {
        let n = (at(t[1]) - at(t[0])).cross(at(t[2]) - at(t[0]));
        for &c in t {
            if let Some(s) = groups
                .get(c as usize)
                .and_then(|&g| sums.get_mut(g as usize))
            {
                *s += n;
            }
        }
    }
    groups
        .iter()
        .zip(&target.original)
        .map(|(&g, &old)| {
            let n = sums
                .get(g as usize)
                .copied()
                .unwrap_or_default()
                .normalize_or_zero();
            if n == DVec3::ZERO { old } else { n }
        })
        .collect()
}

/// The document being written.
struct Writer {
    root: Value,
    buffers: Vec<Vec<u8>>,
    modified: Vec<bool>,
}

impl Writer {
    fn list_mut(&mut self, key: &str) -> Option<&mut Vec<Value>> {
        let slot = self
            .root
            .as_object_mut()?
            .entry(key)
            .or_insert_with(|| Value::Array(Vec::new()));
        if !slot.is_array() {
            *slot = Value::Array(Vec::new());
        }
        slot.as_array_mut()
    }

    fn accessor_mut(&mut self, index: usize) -> Option<&mut Map<String, Value>> {
        self.list_mut("accessors")?.get_mut(index)?.as_object_mut()
    }

    fn accessor_has_bounds(&mut self, index: usize) -> bool {
        self.accessor_mut(index)
            .is_some_and(|a| a.contains_key("min") || a.contains_key("max"))
    }

    /// Appends `data` to buffer 0 (4-byte aligned) as a new vertex buffer
    /// view and returns its index.
    fn append_view(&mut self, data: &[u8]) -> Result<usize, IoError> {
        if self.buffers.is_empty() {
            self.buffers.push(Vec::new());
            self.modified.push(true);
            if let Some(list) = self.list_mut("buffers") {
                list.push(json!({ "byteLength": 0 }));
            }
        }
        let buffer = self
            .buffers
            .first_mut()
            .ok_or_else(|| invalid("no buffer".into()))?;
        buffer.resize(buffer.len().next_multiple_of(4), 0);
        let offset = buffer.len();
        buffer.extend_from_slice(data);
        if let Some(m) = self.modified.first_mut() {
            *m = true;
        }
        let views = self
            .list_mut("bufferViews")
            .ok_or_else(|| invalid("the document is not a JSON object".into()))?;
        views.push(json!({
            "buffer": 0,
            "byteOffset": offset,
            "byteLength": data.len(),
            "target": ARRAY_BUFFER,
        }));
        Ok(views.len() - 1)
    }

    /// Replaces accessor `index`'s values by `values` (as f32), in place or
    /// as new float data, and sets its `min`/`max` when `bounds`.
    fn write_vec3(
        &mut self,
        index: usize,
        values: &[DVec3],
        in_place: Option<InPlace>,
        bounds: bool,
    ) -> Result<(), IoError> {
        let floats: Vec<[f32; 3]> = values
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        match in_place.filter(|p| self.buffers.get(p.buffer).is_some()) {
            Some(place) => {
                if let Some(buffer) = self.buffers.get_mut(place.buffer) {
                    for (i, v) in floats.iter().enumerate() {
                        let at = place.offset + i * place.stride;
                        if let Some(dst) = buffer.get_mut(at..at + 12) {
                            for (d, c) in dst.chunks_exact_mut(4).zip(v) {
                                d.copy_from_slice(&c.to_le_bytes());
                            }
                        }
                    }
                }
                if let Some(m) = self.modified.get_mut(place.buffer) {
                    *m = true;
                }
            }
            None => {
                let data: Vec<u8> = floats
                    .iter()
                    .flatten()
                    .flat_map(|c| c.to_le_bytes())
                    .collect();
                let view = self.append_view(&data)?;
                if let Some(acc) = self.accessor_mut(index) {
                    acc.insert("bufferView".into(), json!(view));
                    acc.remove("byteOffset");
                    acc.insert("componentType".into(), json!(FLOAT));
                    acc.remove("normalized");
                    acc.remove("sparse");
                }
            }
        }
        if bounds {
            let start = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            let (lo, hi) = floats.iter().fold(start, |(lo, hi), v| {
                (
                    std::array::from_fn(|k| lo[k].min(v[k])),
                    std::array::from_fn(|k| hi[k].max(v[k])),
                )
            });
            if let Some(acc) = self.accessor_mut(index) {
                acc.insert("min".into(), json!(lo.map(f64::from)));
                acc.insert("max".into(), json!(hi.map(f64::from)));
            }
        }
        Ok(())
    }

    /// Adds the per-vertex results as float SCALAR attributes.
    fn add_results(&mut self, src: &GltfSource, results: &VertexResults) -> Result<(), IoError> {
        let n = src.num_vertices;
        let labels: Vec<f64> = results.label.iter().map(|&l| f64::from(l)).collect();
        let columns = [
            ("_LABEL", &labels[..]),
            ("_MEAN_CURVATURE", results.mean_curvature),
            ("_GAUSSIAN_CURVATURE", results.gaussian_curvature),
            ("_DISPLACEMENT", results.displacement),
        ];
        for (name, values) in columns {
            if values.is_empty() {
                continue;
            }
            if values.len() != n {
                return Err(IoError::PositionCount {
                    expected: n,
                    got: values.len(),
                });
            }
            let mut accessor_of_block = HashMap::new();
            for (b, block) in src.blocks.iter().enumerate() {
                let part = values
                    .get(block.start..block.start + block.count)
                    .unwrap_or_default();
                let floats: Vec<f32> = part.iter().map(|&v| v as f32).collect();
                if let Some(i) = floats.iter().position(|v| !v.is_finite()) {
                    return Err(invalid(format!(
                        "{name} of vertex {} is not finite",
                        block.start + i
                    )));
                }
                let data: Vec<u8> = floats.iter().flat_map(|c| c.to_le_bytes()).collect();
                let view = self.append_view(&data)?;
                let lo = floats.iter().copied().fold(f32::INFINITY, f32::min);
                let hi = floats.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                let accessors = self
                    .list_mut("accessors")
                    .ok_or_else(|| invalid("the document is not a JSON object".into()))?;
                accessors.push(json!({
                    "bufferView": view,
                    "componentType": FLOAT,
                    "count": block.count,
                    "type": "SCALAR",
                    "min": [f64::from(lo)],
                    "max": [f64::from(hi)],
                }));
                accessor_of_block.insert(b, accessors.len() - 1);
            }
            for &(m, p, block) in &src.primitives {
                let Some(&accessor) = block.and_then(|b| accessor_of_block.get(&b)) else {
                    continue;
                };
                if let Some(attributes) = self
                    .list_mut("meshes")
                    .and_then(|meshes| meshes.get_mut(m))
                    .and_then(|mesh| mesh.get_mut("primitives"))
                    .and_then(|ps| ps.get_mut(p))
                    .and_then(|prim| prim.get_mut("attributes"))
                    .and_then(Value::as_object_mut)
                {
                    attributes.insert(name.into(), json!(accessor));
                }
            }
        }
        Ok(())
    }

    /// Removes the Draco copy of every rewritten primitive (readers that
    /// decode Draco would show the old geometry) and the extension's
    /// declaration when nothing uses it any more.
    fn drop_draco(&mut self, src: &GltfSource) {
        let mut still_used = false;
        let rewritten: Vec<(usize, usize)> = src
            .primitives
            .iter()
            .filter(|(_, _, b)| b.is_some())
            .map(|&(m, p, _)| (m, p))
            .collect();
        for (m, mesh) in self.list_mut("meshes").into_iter().flatten().enumerate() {
            let Some(primitives) = mesh.get_mut("primitives").and_then(Value::as_array_mut) else {
                continue;
            };
            for (p, primitive) in primitives.iter_mut().enumerate() {
                let Some(extensions) = primitive
                    .get_mut("extensions")
                    .and_then(Value::as_object_mut)
                else {
                    continue;
                };
                if !extensions.contains_key(DRACO) {
                    continue;
                }
                if rewritten.contains(&(m, p)) {
                    extensions.remove(DRACO);
                    if extensions.is_empty()
                        && let Some(prim) = primitive.as_object_mut()
                    {
                        prim.remove("extensions");
                    }
                } else {
                    still_used = true;
                }
            }
        }
        if !still_used
            && let Some(used) = self
                .root
                .get_mut("extensionsUsed")
                .and_then(Value::as_array_mut)
        {
            used.retain(|e| e.as_str() != Some(DRACO));
        }
    }

    /// Serialises the document: buffer byte lengths and URIs, then JSON or
    /// GLB.
    fn finish(mut self, binary: bool, out: &mut Vec<u8>) -> Result<(), IoError> {
        let buffers = std::mem::take(&mut self.buffers);
        let modified = std::mem::take(&mut self.modified);
        for (i, entry) in self.list_mut("buffers").into_iter().flatten().enumerate() {
            let (Some(data), Some(obj)) = (buffers.get(i), entry.as_object_mut()) else {
                continue;
            };
            obj.insert("byteLength".into(), json!(data.len()));
            if binary && i == 0 {
                obj.remove("uri");
            } else if modified.get(i).copied().unwrap_or(true) || !obj.contains_key("uri") {
                obj.insert("uri".into(), json!(encode_data_uri(data)));
            }
        }
        let json = serde_json::to_vec(&self.root)
            .map_err(|e| invalid(format!("the JSON could not be written: {e}")))?;
        if !binary {
            out.extend_from_slice(&json);
            return Ok(());
        }
        let bin = buffers.first().map(Vec::as_slice);
        let json_len = json.len().next_multiple_of(4);
        let bin_len = bin.map_or(0, |b| b.len().next_multiple_of(4));
        let total = 12 + 8 + json_len + bin.map_or(0, |_| 8 + bin_len);
        let total32 = u32::try_from(total).map_err(|_| IoError::Limit {
            what: "GLB byte",
            count: total,
            limit: u32::MAX as usize,
        })?;
        out.reserve(total);
        out.extend_from_slice(GLB_MAGIC);
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&total32.to_le_bytes());
        out.extend_from_slice(&(json_len as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
        out.extend_from_slice(&json);
        out.resize(out.len() + json_len - json.len(), b' ');
        if let Some(bin) = bin {
            out.extend_from_slice(&(bin_len as u32).to_le_bytes());
            out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
            out.extend_from_slice(bin);
            out.resize(out.len() + bin_len - bin.len(), 0);
        }
        Ok(())
    }
}

/// Writes `mesh` with `positions` (one per vertex) as a new glTF document:
/// one node, one mesh, one triangle primitive (polygons split into fans)
/// with POSITION, area-weighted NORMAL, u32 indices and the optional
/// per-vertex `results` as in [`write_gltf`]. `binary` picks `.glb` or
/// `.gltf` with an embedded buffer.
pub fn write_gltf_plain(
    mesh: &Mesh,
    positions: &[DVec3],
    results: Option<&VertexResults>,
    binary: bool,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    let n = mesh.num_vertices();
    IoError::check_position_count(n, positions.len())?;
    check_f32(positions)?;
    let mut indices: Vec<u32> = Vec::new();
    for face in mesh.faces() {
        let first = face.first().copied().unwrap_or(0);
        for w in face.windows(2).skip(1) {
            indices.extend_from_slice(&[first, w[0], w[1]]);
        }
    }
    let triangles: Vec<[u32; 3]> = indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let index_bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let root = json!({
        "asset": { "version": "2.0", "generator": "meshsmooth" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [{
            "attributes": { "POSITION": 0, "NORMAL": 1 },
            "indices": 2,
            "mode": 4,
        }] }],
        "accessors": [
            { "bufferView": 1, "componentType": FLOAT, "count": n, "type": "VEC3", "min": [0, 0, 0], "max": [0, 0, 0] },
            { "bufferView": 2, "componentType": FLOAT, "count": n, "type": "VEC3" },
            { "bufferView": 0, "componentType": 5125, "count": indices.len(), "type": "SCALAR" },
        ],
        "bufferViews": [
            { "buffer": 0, "byteOffset": 0, "byteLength": index_bytes.len(), "target": 34963 },
            { "buffer": 0, "byteOffset": index_bytes.len(), "byteLength": 12 * n, "target": ARRAY_BUFFER },
            { "buffer": 0, "byteOffset": index_bytes.len() + 12 * n, "byteLength": 12 * n, "target": ARRAY_BUFFER },
        ],
        "buffers": [{ "byteLength": index_bytes.len() + 24 * n }],
    });
    let mut buffer = index_bytes;
    buffer.resize(buffer.len() + 24 * n, 0);
    let source = GltfSource {
        binary,
        root,
        buffers: vec![buffer],
        blocks: vec![Block {
            accessor: 0,
            mesh: 0,
            start: 0,
            count: n,
            in_place: Some(InPlace {
                buffer: 0,
                offset: 4 * indices.len(),
                stride: 12,
            }),
        }],
        normals: vec![NormalTarget {
            accessor: 1,
            block: 0,
            original: vec![DVec3::ZERO; n],
            triangles,
            in_place: Some(InPlace {
                buffer: 0,
                offset: 4 * indices.len() + 12 * n,
                stride: 12,
            }),
        }],
        primitives: vec![(0, 0, Some(0))],
        num_vertices: n,
    };
    write_gltf(&source, positions, results, binary, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GLB or glTF holding one buffer with `data` and the given JSON
    /// (whose buffer 0 gets the data).
    fn document(mut root: Value, data: &[u8], binary: bool) -> Vec<u8> {
        if binary {
            root["buffers"] = json!([{ "byteLength": data.len() }]);
            let src = GltfSource {
                binary,
                root,
                buffers: vec![data.to_vec()],
                blocks: Vec::new(),
                normals: Vec::new(),
                primitives: Vec::new(),
                num_vertices: 0,
            };
            let mut out = Vec::new();
            write_gltf(&src, &[], None, true, &mut out).unwrap();
            out
        } else {
            root["buffers"] = json!([{ "byteLength": data.len(), "uri": encode_data_uri(data) }]);
            serde_json::to_vec(&root).unwrap()
        }
    }

    fn f32s(values: &[f32]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    /// A unit square: 4 positions (float), 6 u16 indices; mode and extra
    /// fields merged into the primitive.
    fn square(primitive_extra: Value) -> (Value, Vec<u8>) {
        let mut data = f32s(&[0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.]);
        for i in [0u16, 1, 2, 0, 2, 3] {
            data.extend_from_slice(&i.to_le_bytes());
        }
        let mut primitive = json!({ "attributes": { "POSITION": 0 }, "indices": 1 });
        if let (Some(p), Some(extra)) = (primitive.as_object_mut(), primitive_extra.as_object()) {
            p.extend(extra.clone());
        }
        let root = json!({
            "asset": { "version": "2.0" },
            "meshes": [{ "primitives": [primitive] }],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0,0,0], "max": [1,1,0] },
                { "bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR" },
            ],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": 48 },
                { "buffer": 0, "byteOffset": 48, "byteLength": 12 },
            ],
        });
        (root, data)
    }

    fn limits() -> ReadLimits {
        ReadLimits::default()
    }

    #[test]
    fn reads_and_writes_back_identically_in_both_containers() {
        let (root, data) = square(json!({}));
        for binary in [false, true] {
            let bytes = document(root.clone(), &data, binary);
            let (mesh, src) = read_gltf(&bytes, &limits()).unwrap();
            assert_eq!(src.binary, binary);
            assert_eq!(mesh.num_vertices(), 4);
            assert_eq!(mesh.face(1), &[0, 2, 3]);
            let mut out = Vec::new();
            write_gltf(&src, mesh.positions(), None, binary, &mut out).unwrap();
            let (again, src2) = read_gltf(&out, &limits()).unwrap();
            assert_eq!(again, mesh);
            assert_eq!(
                src2.buffers, src.buffers,
                "in-place write of the same values"
            );
        }
    }

    #[test]
    fn moved_positions_update_min_max_in_place() {
        let (root, data) = square(json!({}));
        let bytes = document(root, &data, true);
        let (mesh, src) = read_gltf(&bytes, &limits()).unwrap();
        let moved: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|p| *p * 2.0 + DVec3::Z)
            .collect();
        let mut out = Vec::new();
        write_gltf(&src, &moved, None, true, &mut out).unwrap();
        let (again, src2) = read_gltf(&out, &limits()).unwrap();
        assert_eq!(
            src2.buffers,
            src.buffers
                .iter()
                .map(|b| b.len())
                .map(|n| {
                    let mut b = f32s(
                        &moved
                            .iter()
                            .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
                            .collect::<Vec<_>>(),
                    );
                    b.extend_from_slice(&src.buffers[0][48..n]);
                    b
                })
                .collect::<Vec<_>>(),
            "in place: same buffer, new positions"
        );
        assert_eq!(again.positions(), &moved[..]);
        assert_eq!(src2.root["accessors"][0]["min"], json!([0.0, 0.0, 1.0]));
        assert_eq!(src2.root["accessors"][0]["max"], json!([2.0, 2.0, 1.0]));
    }

    #[test]
    fn aliased_accessors_are_not_overwritten_in_place() {
        // Found by fuzzing: one accessor as POSITION and NORMAL; and two
        // POSITION accessors over the same bytes.
        let (mut root, data) = square(json!({ "attributes": { "POSITION": 0, "NORMAL": 0 } }));
        let alias = root["accessors"][0].clone();
        root["accessors"].as_array_mut().unwrap().push(alias);
        let second = json!({ "primitives": [{ "attributes": { "POSITION": 2 }, "indices": 1 }] });
        root["meshes"].as_array_mut().unwrap().push(second);
        let bytes = document(root, &data, true);
        let (mesh, src) = read_gltf(&bytes, &limits()).unwrap();
        assert_eq!(mesh.num_vertices(), 8);
        assert!(src.normals.is_empty());
        assert!(src.blocks.iter().all(|b| b.in_place.is_none()));
        let moved: Vec<DVec3> = (0..8).map(|v| DVec3::splat(v as f64)).collect();
        let mut out = Vec::new();
        write_gltf(&src, &moved, None, true, &mut out).unwrap();
        let (again, _) = read_gltf(&out, &limits()).unwrap();
        assert_eq!(again.positions(), &moved[..]);
    }

    #[test]
    fn strips_and_fans_become_triangles() {
        assert_eq!(
            triangles(&[0, 1, 2, 3, 3, 4, 5, 6], 5).unwrap(),
            vec![[0, 1, 2], [1, 3, 2], [3, 4, 5], [4, 6, 5]]
        );
        assert_eq!(
            triangles(&[0, 1, 2, 3], 6).unwrap(),
            vec![[1, 2, 0], [2, 3, 0]]
        );
        assert!(triangles(&[0, 1, 2, 3], 4).is_err());
    }

    #[test]
    fn points_only_is_refused_by_mode() {
        let (root, data) = square(json!({ "mode": 0 }));
        let e = read_gltf(&document(root, &data, false), &limits()).unwrap_err();
        assert_eq!(e.code(), "unsupported_primitive_mode");
        assert!(e.to_string().contains("POINTS"), "{e}");
    }

    #[test]
    fn external_and_required_extensions_are_refused_by_name() {
        let (mut root, _) = square(json!({}));
        root["buffers"] = json!([{ "byteLength": 60, "uri": "square.bin" }]);
        let e = read_gltf(&serde_json::to_vec(&root).unwrap(), &limits()).unwrap_err();
        assert_eq!(e.code(), "external_uri_not_allowed");
        assert!(e.to_string().contains("square.bin"), "{e}");
        let (mut root, data) = square(json!({}));
        root["extensionsRequired"] = json!(["KHR_materials_unlit", "EXT_meshopt_compression"]);
        let e = read_gltf(&document(root, &data, false), &limits()).unwrap_err();
        assert_eq!(e.code(), "unsupported_extension");
        assert!(e.to_string().contains("EXT_meshopt_compression"), "{e}");
    }

    #[test]
    fn lying_counts_and_offsets_are_errors_not_allocations() {
        for (path, value) in [
            ("count", json!(1_000_000)),
            ("byteOffset", json!(u64::MAX)),
            ("bufferView", json!(7)),
            ("componentType", json!(5125)),
            ("type", json!("VEC4")),
        ] {
            let (mut root, data) = square(json!({}));
            root["accessors"][0][path] = value;
            let e = read_gltf(&document(root, &data, true), &limits()).unwrap_err();
            assert_eq!(e.code(), "gltf_invalid", "{path}: {e}");
            assert!(e.to_string().contains("accessor 0"), "{path}: {e}");
        }
        let (mut root, data) = square(json!({}));
        root["accessors"][0]["count"] = json!(4_000_000_000u64);
        let e = read_gltf(&document(root, &data, true), &limits()).unwrap_err();
        assert_eq!(e.code(), "limit_exceeded");
        let (mut root, data) = square(json!({}));
        root["bufferViews"][0]["byteLength"] = json!(1u64 << 40);
        let e = read_gltf(&document(root, &data, true), &limits()).unwrap_err();
        assert!(e.to_string().contains("lies outside buffer 0"), "{e}");
        let (mut root, data) = square(json!({}));
        root["accessors"][1]["count"] = json!(7);
        let e = read_gltf(&document(root, &data, false), &limits()).unwrap_err();
        assert!(e.to_string().contains("accessor 1"), "{e}");
    }

    #[test]
    fn sparse_and_quantized_positions_are_decoded_and_written_as_float() {
        // Base: u16 normalized positions; sparse replaces vertex 2.
        let mut data = Vec::new();
        for c in [0u16, 0, 0, 65535, 0, 0, 0, 0, 0, 0, 65535, 0] {
            data.extend_from_slice(&c.to_le_bytes());
        }
        for i in [0u16, 1, 2, 0, 2, 3] {
            data.extend_from_slice(&i.to_le_bytes());
        }
        data.extend_from_slice(&2u16.to_le_bytes()); // sparse index, at 36
        data.extend_from_slice(&[0, 0]);
        for c in [65535u16, 65535, 0, 0] {
            data.extend_from_slice(&c.to_le_bytes()); // sparse value, at 40
        }
        let root = json!({
            "asset": { "version": "2.0" },
            "extensionsUsed": ["KHR_mesh_quantization"],
            "extensionsRequired": ["KHR_mesh_quantization"],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
            "accessors": [
                { "bufferView": 0, "componentType": 5123, "normalized": true, "count": 4, "type": "VEC3",
                  "min": [0,0,0], "max": [1,1,0],
                  "sparse": { "count": 1, "indices": { "bufferView": 2, "componentType": 5123 },
                              "values": { "bufferView": 3 } } },
                { "bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR" },
            ],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": 24 },
                { "buffer": 0, "byteOffset": 24, "byteLength": 12 },
                { "buffer": 0, "byteOffset": 36, "byteLength": 2 },
                { "buffer": 0, "byteOffset": 40, "byteLength": 6 },
            ],
        });
        let bytes = document(root, &data, false);
        let (mesh, src) = read_gltf(&bytes, &limits()).unwrap();
        assert_eq!(mesh.positions()[2], DVec3::new(1.0, 1.0, 0.0));
        assert_eq!(mesh.positions()[3], DVec3::new(0.0, 1.0, 0.0));
        assert!(src.blocks[0].in_place.is_none());
        let moved: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|p| *p + DVec3::Z * 0.5)
            .collect();
        let mut out = Vec::new();
        write_gltf(&src, &moved, None, false, &mut out).unwrap();
        let (again, src2) = read_gltf(&out, &limits()).unwrap();
        assert_eq!(again.positions(), &moved[..]);
        let acc = &src2.root["accessors"][0];
        assert_eq!(acc["componentType"], json!(5126));
        assert!(acc.get("sparse").is_none() && acc.get("normalized").is_none());
    }

    #[test]
    fn normals_are_recomputed_keeping_hard_edges() {
        // Two quads folded at x = 1 with split vertices along the fold: the
        // fold is a hard edge (different normals), the split at y is not.
        let p = [
            [0., 0., 0.],
            [1., 0., 0.],
            [1., 1., 0.],
            [0., 1., 0.],
            [1., 0., 0.],
            [1., 0., 1.],
            [1., 1., 1.],
            [1., 1., 0.],
        ];
        let n = [[0., 0., 1.]; 4].into_iter().chain([[-1., 0., 0.]; 4]);
        let mut data = f32s(&p.concat());
        data.extend(f32s(&n.collect::<Vec<_>>().concat()));
        for i in [0u16, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7] {
            data.extend_from_slice(&i.to_le_bytes());
        }
        let root = json!({
            "asset": { "version": "2.0" },
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0, "NORMAL": 1 }, "indices": 2 }] }],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3", "min": [0,0,0], "max": [1,1,1] },
                { "bufferView": 1, "componentType": 5126, "count": 8, "type": "VEC3" },
                { "bufferView": 2, "componentType": 5123, "count": 12, "type": "SCALAR" },
            ],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": 96 },
                { "buffer": 0, "byteOffset": 96, "byteLength": 96 },
                { "buffer": 0, "byteOffset": 192, "byteLength": 24 },
            ],
        });
        let bytes = document(root, &data, true);
        let (mesh, src) = read_gltf(&bytes, &limits()).unwrap();
        // Tilt the first quad: its normal changes, the second's does not.
        let mut moved = mesh.positions().to_vec();
        moved[0].z = 1.0;
        moved[3].z = 1.0;
        let mut out = Vec::new();
        write_gltf(&src, &moved, None, true, &mut out).unwrap();
        let (_, src2) = read_gltf(&out, &limits()).unwrap();
        let normals = &src2.normals[0].original;
        let tilted = DVec3::new(1.0, 0.0, 1.0).normalize();
        for (v, n) in normals.iter().enumerate() {
            let expected = if v < 4 { tilted } else { DVec3::NEG_X };
            assert!((*n - expected).length() < 1e-6, "{v}: {n}");
        }
    }

    #[test]
    fn results_become_attributes_of_every_primitive() {
        let (root, data) = square(json!({}));
        let bytes = document(root, &data, true);
        let (mesh, src) = read_gltf(&bytes, &limits()).unwrap();
        let label = [0u8, 1, 2, 3];
        let h = [0.5, 0.25, -0.5, 1.0];
        let results = VertexResults {
            label: &label,
            mean_curvature: &h,
            gaussian_curvature: &[],
            displacement: &[],
        };
        let mut out = Vec::new();
        write_gltf(&src, mesh.positions(), Some(&results), true, &mut out).unwrap();
        let (_, src2) = read_gltf(&out, &limits()).unwrap();
        let attributes = &src2.root["meshes"][0]["primitives"][0]["attributes"];
        let a = attributes["_MEAN_CURVATURE"].as_u64().unwrap() as usize;
        let reader = Reader {
            root: &src2.root,
            buffers: &src2.buffers,
            limits: &limits(),
            input_len: out.len(),
            positions: Vec::new(),
            faces: Vec::new(),
            blocks: Vec::new(),
            block_of: HashMap::new(),
            normals: Vec::new(),
            normal_of: HashMap::new(),
            primitives: Vec::new(),
            skipped: None,
        };
        let acc = reader.accessor(a).unwrap();
        let values = reader
            .elements(a, &acc, |b| component(b, FLOAT, false))
            .unwrap();
        assert_eq!(values, h);
        assert!(attributes.get("_LABEL").is_some());
        assert!(attributes.get("_DISPLACEMENT").is_none());
    }

    #[test]
    fn glb_container_errors_are_specific() {
        let e = |b: &[u8]| read_gltf(b, &limits()).unwrap_err();
        assert_eq!(e(b"glTF").code(), "glb_invalid");
        assert!(
            e(b"glTF\x01\0\0\0\x0c\0\0\0")
                .to_string()
                .contains("version 1")
        );
        let (root, data) = square(json!({}));
        let mut bytes = document(root, &data, true);
        bytes.push(0);
        assert!(e(&bytes).to_string().contains("length"));
        let len = bytes.len() - 1;
        bytes.truncate(len - 4);
        bytes[8..12].copy_from_slice(&((len - 4) as u32).to_le_bytes());
        assert!(e(&bytes).to_string().contains("claims"), "{}", e(&bytes));
    }

    #[test]
    fn plain_writer_output_reads_back() {
        let mesh = Mesh::from_polygons(
            vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y],
            &[[0u32, 1, 2, 3]],
        )
        .unwrap();
        for binary in [false, true] {
            let mut out = Vec::new();
            write_gltf_plain(&mesh, mesh.positions(), None, binary, &mut out).unwrap();
            let (again, src) = read_gltf(&out, &limits()).unwrap();
            assert_eq!(again.positions(), mesh.positions());
            assert_eq!(again.num_faces(), 2);
            assert_eq!(src.normals[0].original[0], DVec3::Z);
        }
    }
}
