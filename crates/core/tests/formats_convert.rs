//! Format detection, conversions between formats, welding across formats
//! and a structural check of the glTF we write, on generated meshes.

use glam::DVec3;
use meshsmooth_core::io::{self, Format, ReadLimits, ReadOptions, VertexResults, WriteOptions};
use meshsmooth_core::shapes::mc_sphere;
use meshsmooth_core::{Mesh, NoProgress, Params};
use serde_json::Value;
use std::sync::atomic::AtomicBool;

/// A marching-cubes sphere with f32-exact positions and vertices numbered
/// in order of first use by the faces, so a welded STL of it reads back as
/// exactly this mesh.
fn sphere() -> Mesh {
    let (_, mesh) = mc_sphere(6.0);
    let mut new_index = vec![u32::MAX; mesh.num_vertices()];
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    for face in mesh.faces() {
        let mut f = Vec::new();
        for &v in face {
            if new_index[v as usize] == u32::MAX {
                new_index[v as usize] = positions.len() as u32;
                let p = mesh.positions()[v as usize];
                positions.push(DVec3::new(
                    f64::from(p.x as f32),
                    f64::from(p.y as f32),
                    f64::from(p.z as f32),
                ));
            }
            f.push(new_index[v as usize]);
        }
        faces.push(f);
    }
    Mesh::from_polygons(positions, &faces).unwrap()
}

fn obj_bytes(mesh: &Mesh) -> Vec<u8> {
    let mut out = Vec::new();
    io::obj::write_obj_plain(mesh, mesh.positions(), &mut out).unwrap();
    out
}

fn limits() -> ReadLimits {
    ReadLimits::default()
}

fn smooth(mesh: &Mesh) -> meshsmooth_core::SmoothOutput {
    meshsmooth_core::run(
        mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .unwrap()
}

#[test]
fn welded_stl_sphere_equals_the_obj_sphere_and_smooths_identically() {
    let mesh = sphere();
    assert!(mesh.num_vertices() > 500, "{}", mesh.num_vertices());
    let obj = io::read(&obj_bytes(&mesh), Format::Obj, &limits()).unwrap();
    assert_eq!(obj.mesh, mesh);
    for stl_ascii in [false, true] {
        let options = WriteOptions {
            stl_ascii,
            ..WriteOptions::default()
        };
        let stl = io::write_with(&obj, obj.mesh.positions(), Format::Stl, &options).unwrap();
        let doc = io::read(&stl, Format::Stl, &limits()).unwrap();
        assert_eq!(doc.num_file_vertices(), 3 * mesh.num_faces());
        assert_eq!(
            doc.mesh, mesh,
            "welded STL (ascii: {stl_ascii}) differs from the OBJ"
        );

        let a = smooth(&obj.mesh);
        let b = smooth(&doc.mesh);
        assert_eq!(a.positions, b.positions);
        assert!(
            a.positions
                .iter()
                .zip(mesh.positions())
                .any(|(p, q)| p != q),
            "smoothing moved nothing"
        );
        // Written back, every STL corner carries its welded vertex's
        // smoothed position (to f32), so the seams stay closed.
        let out = io::write(&doc, &b.positions, Format::Stl).unwrap();
        let again = io::read(&out, Format::Stl, &limits()).unwrap();
        assert_eq!(again.mesh.num_vertices(), mesh.num_vertices());
        assert_eq!(again.mesh.face_vertices(), mesh.face_vertices());
        for (p, q) in again.mesh.positions().iter().zip(&b.positions) {
            assert!((*p - *q).abs().max_element() < 1e-5, "{p} vs {q}");
        }
    }
}

#[test]
fn welding_is_optional_and_tolerance_relative() {
    let mesh = sphere();
    let obj = io::read(&obj_bytes(&mesh), Format::Obj, &limits()).unwrap();
    let stl = io::write(&obj, obj.mesh.positions(), Format::Stl).unwrap();
    let off = ReadOptions {
        weld: Some(false),
        ..ReadOptions::default()
    };
    let raw = io::read_with(&stl, Format::Stl, &off).unwrap();
    assert_eq!(raw.mesh.num_vertices(), 3 * mesh.num_faces());
    assert!(raw.vertex_map.is_none());
    // OBJ is not welded by default; asking welds it (nothing to join here).
    let on = ReadOptions {
        weld: Some(true),
        weld_tolerance: 1e-9,
        ..ReadOptions::default()
    };
    let obj_welded = io::read_with(&obj_bytes(&mesh), Format::Obj, &on).unwrap();
    assert_eq!(obj_welded.mesh, mesh);
    // A tolerance of a tenth of the diagonal merges neighbours.
    let coarse = ReadOptions {
        weld_tolerance: 0.1,
        ..ReadOptions::default()
    };
    let merged = io::read_with(&stl, Format::Stl, &coarse).unwrap();
    assert!(merged.mesh.num_vertices() < mesh.num_vertices() / 4);
    assert_eq!(merged.num_file_vertices(), 3 * mesh.num_faces());
}

#[test]
fn results_follow_welding_into_every_file_vertex() {
    // Box.glb: 24 file vertices (split at the cube's edges), 8 welded.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/gltf/Box.glb");
    let doc = io::read(&std::fs::read(path).unwrap(), Format::Glb, &limits()).unwrap();
    assert_eq!((doc.num_file_vertices(), doc.mesh.num_vertices()), (24, 8));
    let labels: Vec<u8> = (0..8).collect();
    let displacement: Vec<f64> = (0..8).map(|v| f64::from(v) * 0.25).collect();
    let options = WriteOptions {
        results: Some(VertexResults {
            label: &labels,
            displacement: &displacement,
            ..VertexResults::default()
        }),
        ..WriteOptions::default()
    };
    let out = io::write_with(&doc, doc.mesh.positions(), Format::Glb, &options).unwrap();
    check_gltf_structure(&out);
    let map = doc.vertex_map.clone().unwrap();
    for (name, values) in [
        ("_LABEL", labels.iter().map(|&l| f64::from(l)).collect()),
        ("_DISPLACEMENT", displacement),
    ] {
        let stored = float_attribute(&out, name);
        let expected: Vec<f32> = map.iter().map(|&k| values[k as usize] as f32).collect();
        assert_eq!(stored, expected, "{name}");
    }
    // Another format gets the welded mesh.
    let ply = io::write(&doc, doc.mesh.positions(), Format::Ply).unwrap();
    let ply_doc = io::read(&ply, Format::Ply, &limits()).unwrap();
    assert_eq!(ply_doc.mesh, doc.mesh);
}

/// The f32 values of attribute `name` of the first primitive of a GLB.
fn float_attribute(glb: &[u8], name: &str) -> Vec<f32> {
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let root: Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let bin = &glb[28 + json_len..];
    let a = &root["accessors"][root["meshes"][0]["primitives"][0]["attributes"][name]
        .as_u64()
        .unwrap() as usize];
    assert_eq!(a["componentType"], 5126);
    let v = &root["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let start = (v.get("byteOffset").and_then(Value::as_u64).unwrap_or(0)
        + a.get("byteOffset").and_then(Value::as_u64).unwrap_or(0)) as usize;
    (0..a["count"].as_u64().unwrap() as usize)
        .map(|i| f32::from_le_bytes(bin[start + 4 * i..start + 4 * i + 4].try_into().unwrap()))
        .collect()
}

#[test]
fn every_format_converts_to_every_other() {
    let mesh = sphere();
    let source = io::read(&obj_bytes(&mesh), Format::Obj, &limits()).unwrap();
    for &from in Format::ALL {
        let bytes = io::write(&source, source.mesh.positions(), from).unwrap();
        let doc = io::read(&bytes, from, &limits()).unwrap();
        assert_eq!(doc.mesh, mesh, "{from}");
        for &to in Format::ALL {
            let out = io::write(&doc, doc.mesh.positions(), to).unwrap();
            let back = io::read(&out, to, &limits()).unwrap();
            assert_eq!(back.mesh, mesh, "{from} -> {to}");
            assert_eq!(Format::sniff(&out).map(same_family), Some(same_family(to)));
        }
    }
}

/// `.gltf` and `.glb` are one reader.
fn same_family(f: Format) -> Format {
    if f == Format::Glb { Format::Gltf } else { f }
}

#[test]
fn detection_by_name_content_type_and_content() {
    for (name, f) in [
        ("a.OBJ", Format::Obj),
        ("b/c.gltf", Format::Gltf),
        ("scan.GLB", Format::Glb),
        ("x.ply", Format::Ply),
        ("part.stl", Format::Stl),
        ("2jho.OFF", Format::Off),
    ] {
        assert_eq!(Format::from_file_name(name), Some(f), "{name}");
        assert_eq!(f.name().parse::<Format>(), Ok(f));
        assert_eq!(Format::from_content_type(f.content_type()), Some(f));
    }
    for (ct, f) in [
        ("model/gltf-binary", Format::Glb),
        ("model/gltf+json; charset=utf-8", Format::Gltf),
        ("application/sla", Format::Stl),
        ("model/x.stl-ascii", Format::Stl),
        ("application/ply", Format::Ply),
        ("application/x-off", Format::Off),
    ] {
        assert_eq!(Format::from_content_type(ct), Some(f), "{ct}");
    }
    let sniffed = |b: &[u8]| Format::sniff(b);
    assert_eq!(sniffed(b"glTF\x02\0\0\0"), Some(Format::Glb));
    assert_eq!(sniffed(b"ply\r\nformat ascii 1.0\r\n"), Some(Format::Ply));
    assert_eq!(sniffed(b"  {\"asset\":{}}"), Some(Format::Gltf));
    assert_eq!(sniffed(b"solid cube\nfacet normal"), Some(Format::Stl));
    assert_eq!(sniffed(b"# GAMer\nOFF\n4622 9244 0\n"), Some(Format::Off));
    // A binary STL whose header starts with `solid` is still STL, and one
    // whose header reads like OBJ too: the size decides.
    let mut bin = vec![b' '; 84 + 50];
    bin[..8].copy_from_slice(b"v 1 2 3\n");
    bin[80..84].copy_from_slice(&1u32.to_le_bytes());
    assert_eq!(sniffed(&bin), Some(Format::Stl));
    assert_eq!(sniffed(b"v 1 2 3\nf 1 1 1\n"), Some(Format::Obj));
    assert_eq!(sniffed(b"\x00\x01binary junk"), None);
}

/// Checks what the Khronos validator checks about data layout on a glTF
/// we wrote: every accessor inside its buffer view, views inside buffers,
/// float components 4-byte aligned, POSITION min/max equal to the data.
fn check_gltf_structure(bytes: &[u8]) {
    let (json, bin) = if bytes.starts_with(b"glTF") {
        let total = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        assert_eq!(total, bytes.len());
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        assert_eq!(json_len % 4, 0, "JSON chunk padded");
        let json = &bytes[20..20 + json_len];
        let bin_len = u32::from_le_bytes(bytes[20 + json_len..24 + json_len].try_into().unwrap());
        assert_eq!(bin_len % 4, 0, "BIN chunk padded");
        (json, Some(&bytes[28 + json_len..]))
    } else {
        (bytes, None)
    };
    let root: Value = serde_json::from_slice(json).unwrap();
    assert_eq!(root["asset"]["version"], "2.0");
    let buffers: Vec<Vec<u8>> = root["buffers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            let len = b["byteLength"].as_u64().unwrap() as usize;
            match b.get("uri").and_then(Value::as_str) {
                Some(uri) => {
                    use base64::Engine as _;
                    let payload = uri.split_once(";base64,").unwrap().1;
                    let data = base64::engine::general_purpose::STANDARD
                        .decode(payload)
                        .unwrap();
                    assert_eq!(data.len(), len, "byteLength of a data: buffer");
                    data
                }
                None => {
                    let bin = bin.expect("a buffer without uri needs the BIN chunk");
                    assert!(bin.len() >= len && bin.len() - len < 4, "BIN chunk length");
                    bin[..len].to_vec()
                }
            }
        })
        .collect();
    let views = root["bufferViews"].as_array().unwrap();
    for v in views {
        let buffer = &buffers[v["buffer"].as_u64().unwrap() as usize];
        let end = v.get("byteOffset").and_then(Value::as_u64).unwrap_or(0)
            + v["byteLength"].as_u64().unwrap();
        assert!(end as usize <= buffer.len(), "view {v} outside its buffer");
    }
    for (i, a) in root["accessors"].as_array().unwrap().iter().enumerate() {
        let Some(view) = a.get("bufferView").and_then(Value::as_u64) else {
            continue;
        };
        let view = &views[view as usize];
        let comps = match a["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC3" => 3,
            other => panic!("unexpected type {other}"),
        };
        let ct = a["componentType"].as_u64().unwrap();
        let size = if ct == 5126 || ct == 5125 { 4 } else { 2 };
        let stride = view
            .get("byteStride")
            .and_then(Value::as_u64)
            .unwrap_or(comps * size);
        let offset = a.get("byteOffset").and_then(Value::as_u64).unwrap_or(0);
        let count = a["count"].as_u64().unwrap();
        assert!(
            offset + stride * (count - 1) + comps * size <= view["byteLength"].as_u64().unwrap()
        );
        let start = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) + offset;
        assert_eq!(start % size, 0, "accessor {i} misaligned");
        if ct == 5126 && a.get("min").is_some() {
            let buffer = &buffers[view["buffer"].as_u64().unwrap() as usize];
            let mut lo = vec![f32::INFINITY; comps as usize];
            let mut hi = vec![f32::NEG_INFINITY; comps as usize];
            for e in 0..count {
                for c in 0..comps {
                    let at = (start + e * stride + 4 * c) as usize;
                    let x = f32::from_le_bytes(buffer[at..at + 4].try_into().unwrap());
                    lo[c as usize] = lo[c as usize].min(x);
                    hi[c as usize] = hi[c as usize].max(x);
                }
            }
            let as_f32 = |v: &Value| -> Vec<f32> {
                v.as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap() as f32)
                    .collect()
            };
            assert_eq!(as_f32(&a["min"]), lo, "accessor {i} min");
            assert_eq!(as_f32(&a["max"]), hi, "accessor {i} max");
        }
    }
}

#[test]
fn written_gltf_is_structurally_valid() {
    let mesh = sphere();
    let doc = io::read(&obj_bytes(&mesh), Format::Obj, &limits()).unwrap();
    let smoothed = smooth(&doc.mesh);
    let options = WriteOptions {
        results: Some(VertexResults::from(&smoothed.per_vertex)),
        ..WriteOptions::default()
    };
    for to in [Format::Gltf, Format::Glb] {
        let plain = io::write_with(&doc, &smoothed.positions, to, &options).unwrap();
        check_gltf_structure(&plain);
        // And the document rewritten by the glTF writer itself.
        let gltf_doc = io::read(&plain, to, &limits()).unwrap();
        let again = smooth(&gltf_doc.mesh);
        let rewritten = io::write_with(&gltf_doc, &again.positions, to, &options).unwrap();
        check_gltf_structure(&rewritten);
    }
}
