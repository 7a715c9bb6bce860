//! Every committed fixture (`tests/fixtures`, copied from public test
//! suites; see `fixtures/ATTRIBUTION.md`) either round-trips or is refused
//! with a specific error code.
//!
//! Round trip: read, write unchanged and read again (same counts, same
//! positions, same glTF node/material structure), then smooth with the
//! default pipeline, write with the per-vertex results, read again: the
//! positions are the smoothed ones (to f32 precision for glTF) and nothing
//! else of the document changed.
//!
//! `MESHSMOOTH_FORMATS_DIR=/path cargo test --test formats_roundtrip -- --ignored`
//! runs the same checks over another directory tree (for instance the
//! team's full data set), printing each file's outcome.

use glam::DVec3;
use meshsmooth_core::io::{self, Format, ReadLimits, VertexResults, WriteOptions};
use meshsmooth_core::{NoProgress, Params};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures");

/// Fixtures that must be refused, with the code.
const REFUSED: &[(&str, &str)] = &[
    ("gltf/draco/2CylinderEngine.gltf", "unsupported_extension"),
    (
        "gltf/external_bin/Mesh_PrimitiveMode_13.gltf",
        "external_uri_not_allowed",
    ),
    (
        "gltf/external_bin/Mesh_PrimitiveMode_14.gltf",
        "external_uri_not_allowed",
    ),
    (
        "gltf/external_bin/Mesh_PrimitiveMode_15.gltf",
        "external_uri_not_allowed",
    ),
    ("gltf/invalid_glb/bom.glb", "glb_invalid"),
    ("gltf/invalid_glb/chunk_too_big.glb", "glb_invalid"),
    ("gltf/invalid_glb/empty_file.glb", "glb_invalid"),
    ("gltf/invalid_glb/empty_json_chunk.glb", "gltf_invalid"),
    ("gltf/invalid_glb/empty_json_object.glb", "gltf_invalid"),
    ("gltf/invalid_glb/extra_data.glb", "glb_invalid"),
    ("gltf/invalid_glb/invalid_json_chunk.glb", "gltf_invalid"),
    ("gltf/invalid_glb/invalid_magic.glb", "glb_invalid"),
    ("gltf/invalid_glb/invalid_version.glb", "glb_invalid"),
    ("gltf/invalid_glb/json_and_two_buffers.glb", "glb_invalid"),
    ("gltf/invalid_glb/length_mismatch.glb", "glb_invalid"),
    ("gltf/invalid_glb/misplaced_bin_chunk.glb", "glb_invalid"),
    ("gltf/invalid_glb/no_header.glb", "glb_invalid"),
    ("gltf/invalid_glb/only_bin_chunk.glb", "glb_invalid"),
    ("gltf/invalid_glb/only_header.glb", "glb_invalid"),
    ("gltf/invalid_glb/truncated_chunk_data.glb", "glb_invalid"),
    ("gltf/invalid_glb/truncated_chunk_header.glb", "glb_invalid"),
    ("gltf/invalid_glb/two_bin_chunks.glb", "glb_invalid"),
    ("gltf/invalid_glb/two_empty_bin_chunks.glb", "glb_invalid"),
    ("gltf/invalid_glb/two_empty_json_chunks.glb", "glb_invalid"),
    ("gltf/invalid_glb/two_images.glb", "no_faces"),
    ("gltf/invalid_glb/two_valid_json_chunks.glb", "glb_invalid"),
    ("gltf/invalid_glb/unaligned_chunk.glb", "no_faces"),
    ("gltf/invalid_glb/unknown_chunk.glb", "glb_invalid"),
    ("gltf/invalid_glb/valid.glb", "no_faces"),
    ("gltf/invalid_glb/valid_buffer.glb", "no_faces"),
    ("gltf/invalid_glb/zero_chunk_header.glb", "glb_invalid"),
    ("gltf/invalid_glb/zero_length.glb", "glb_invalid"),
    ("obj/assimp_box_UTF16BE.obj", "parse_error"),
    // `3.1+e2` is not a number.
    ("obj/assimp_number_formats.obj", "parse_error"),
    ("obj/tobj_invalid_index.obj", "face_index_out_of_range"),
    ("obj/tobj_lines.obj", "no_faces"),
    ("obj/trimesh_face_in_group_name.obj", "no_faces"),
    ("obj/trimesh_notenoughindices.obj", "parse_error"),
];

fn mesh_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if Format::from_file_name(&path.to_string_lossy()).is_some() {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

/// The JSON of a `.gltf` or `.glb`.
fn gltf_json(bytes: &[u8]) -> Value {
    let json = if bytes.starts_with(b"glTF") {
        let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        &bytes[20..20 + len]
    } else {
        bytes
    };
    serde_json::from_slice(json).unwrap()
}

/// What must survive a write unchanged: everything but accessors, buffer
/// views, buffers and the primitives' attribute lists (which may gain the
/// result attributes) and Draco copies.
fn structure(root: &Value) -> Value {
    let mut root = root.clone();
    let obj = root.as_object_mut().unwrap();
    for key in ["accessors", "bufferViews", "buffers"] {
        obj.remove(key);
    }
    for mesh in obj
        .get_mut("meshes")
        .and_then(Value::as_array_mut)
        .into_iter()
        .flatten()
    {
        for p in mesh["primitives"].as_array_mut().unwrap() {
            let attributes = p["attributes"].as_object_mut().unwrap();
            attributes.retain(|k, _| !k.starts_with('_'));
        }
    }
    root
}

/// Reads, writes unchanged, smooths and writes with results; panics with
/// the file name on any broken property. Returns the error code when the
/// first read is refused.
fn check(path: &Path) -> Result<String, String> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).unwrap();
    let format = Format::from_file_name(&name).unwrap();
    let limits = ReadLimits::default();
    let doc = io::read(&bytes, format, &limits).map_err(|e| e.code().as_str().to_owned())?;

    // Identity write.
    let out = io::write(&doc, doc.mesh.positions(), format).unwrap();
    let again = io::read(&out, format, &limits).unwrap();
    assert_eq!(
        again.mesh, doc.mesh,
        "{name}: identity write changed the mesh"
    );
    assert_eq!(again.num_file_vertices(), doc.num_file_vertices(), "{name}");
    if format == Format::Ply {
        assert!(out == bytes, "{name}: identity write is not byte-identical");
    }
    if matches!(format, Format::Gltf | Format::Glb) {
        assert_eq!(
            structure(&gltf_json(&out)),
            structure(&gltf_json(&bytes)),
            "{name}: document structure changed"
        );
    }

    // Smooth, write with results, read back.
    let params = Params::default();
    let smoothed = meshsmooth_core::run(&doc.mesh, &params, &NoProgress, &AtomicBool::new(false))
        .map_err(|e| format!("smoothing failed: {e}"))
        .unwrap();
    let options = WriteOptions {
        results: Some(VertexResults::from(&smoothed.per_vertex)),
        ..WriteOptions::default()
    };
    let out = io::write_with(&doc, &smoothed.positions, format, &options).unwrap();
    let again = io::read(&out, format, &limits).unwrap();
    assert_eq!(again.mesh.num_vertices(), doc.mesh.num_vertices(), "{name}");
    assert_eq!(again.mesh.num_faces(), doc.mesh.num_faces(), "{name}");
    assert_eq!(again.num_file_vertices(), doc.num_file_vertices(), "{name}");
    let expected = doc.expand_positions(&smoothed.positions);
    let got = again.expand_positions(again.mesh.positions());
    for (v, (a, b)) in got.iter().zip(&expected).enumerate() {
        let tolerance = if matches!(format, Format::Gltf | Format::Glb) {
            1e-6 * b.abs().max_element().max(1.0)
        } else {
            0.0
        };
        assert!(
            (*a - *b).abs().max_element() <= tolerance,
            "{name}: vertex {v} read back as {a}, written as {b}"
        );
    }
    if matches!(format, Format::Gltf | Format::Glb) {
        let before = gltf_json(&bytes);
        let after = gltf_json(&out);
        assert_eq!(structure(&after), structure(&before), "{name}");
        for mesh in after["meshes"].as_array().unwrap() {
            for p in mesh["primitives"].as_array().unwrap() {
                let mode = p.get("mode").and_then(Value::as_u64).unwrap_or(4);
                if mode >= 4 {
                    assert!(p["attributes"].get("_LABEL").is_some(), "{name}: {p}");
                }
            }
        }
    }
    Ok(format!(
        "ok: {} file vertices -> {} welded, {} faces",
        doc.num_file_vertices(),
        doc.mesh.num_vertices(),
        doc.mesh.num_faces()
    ))
}

#[test]
fn every_fixture_round_trips_or_is_refused_with_its_code() {
    let root = Path::new(FIXTURES);
    let files = mesh_files(root);
    assert!(files.len() >= 50, "fixtures missing: {}", files.len());
    let mut round_trips = 0;
    for path in &files {
        let relative = path
            .strip_prefix(root)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let expected = REFUSED
            .iter()
            .find(|(f, _)| *f == relative)
            .map(|(_, c)| *c);
        match (check(path), expected) {
            (Ok(_), None) => round_trips += 1,
            (Err(code), Some(want)) => assert_eq!(code, want, "{relative}"),
            (Ok(s), Some(want)) => panic!("{relative}: expected `{want}`, got {s}"),
            (Err(code), None) => panic!("{relative}: refused with `{code}`"),
        }
    }
    for (f, _) in REFUSED {
        assert!(root.join(f).exists(), "{f} is listed but missing");
    }
    assert_eq!(round_trips, files.len() - REFUSED.len());
}

#[test]
fn welded_gltf_keeps_the_file_vertex_count_and_closes_seams() {
    // Box.glb: 24 vertices split along the cube's edges, 8 corners.
    let bytes = std::fs::read(Path::new(FIXTURES).join("gltf/Box.glb")).unwrap();
    let doc = io::read(&bytes, Format::Glb, &ReadLimits::default()).unwrap();
    assert_eq!(doc.num_file_vertices(), 24);
    assert_eq!(doc.mesh.num_vertices(), 8);
    let moved: Vec<DVec3> = doc.mesh.positions().iter().map(|p| *p * 1.5).collect();
    let out = io::write(&doc, &moved, Format::Glb).unwrap();
    let again = io::read(&out, Format::Glb, &ReadLimits::default()).unwrap();
    assert_eq!(again.num_file_vertices(), 24);
    assert_eq!(again.mesh.num_vertices(), 8, "seams stayed closed");
    let unwelded = io::read_with(
        &out,
        Format::Glb,
        &io::ReadOptions {
            weld: Some(false),
            ..io::ReadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(unwelded.mesh.num_vertices(), 24);
    assert_eq!(unwelded.mesh.positions(), &doc.expand_positions(&moved)[..]);
}

#[test]
fn gltf_and_glb_convert_into_each_other() {
    for (name, from, to) in [
        ("BoxTextured.glb", Format::Glb, Format::Gltf),
        ("BoxTextured_embedded.gltf", Format::Gltf, Format::Glb),
        ("MultipleScenes.gltf", Format::Gltf, Format::Glb),
    ] {
        let bytes = std::fs::read(Path::new(FIXTURES).join("gltf").join(name)).unwrap();
        let doc = io::read(&bytes, from, &ReadLimits::default()).unwrap();
        let out = io::write(&doc, doc.mesh.positions(), to).unwrap();
        assert_eq!(out.starts_with(b"glTF"), to == Format::Glb, "{name}");
        let again = io::read(&out, to, &ReadLimits::default()).unwrap();
        assert_eq!(again.mesh, doc.mesh, "{name}");
        assert_eq!(
            structure(&gltf_json(&out)),
            structure(&gltf_json(&bytes)),
            "{name}"
        );
    }
}

#[test]
#[ignore = "reads MESHSMOOTH_FORMATS_DIR; prints every file's outcome"]
fn external_directory_round_trips_or_is_refused() {
    let Ok(dir) = std::env::var("MESHSMOOTH_FORMATS_DIR") else {
        eprintln!("MESHSMOOTH_FORMATS_DIR is not set");
        return;
    };
    for path in mesh_files(Path::new(&dir)) {
        match std::panic::catch_unwind(|| check(&path)) {
            Ok(Ok(s)) => println!("{}: {s}", path.display()),
            Ok(Err(code)) => println!("{}: refused: {code}", path.display()),
            Err(_) => println!("{}: FAILED (see the panic above)", path.display()),
        }
    }
}

/// Writes what the writers produce for every glTF fixture (smoothed, with
/// per-vertex results, in both containers) and for an OBJ converted to glTF
/// into `MESHSMOOTH_FORMATS_OUT`, for an external validator.
#[test]
#[ignore = "writes files into MESHSMOOTH_FORMATS_OUT for the Khronos validator"]
fn dump_written_gltf_for_validation() {
    let Ok(out_dir) = std::env::var("MESHSMOOTH_FORMATS_OUT") else {
        eprintln!("MESHSMOOTH_FORMATS_OUT is not set");
        return;
    };
    let out_dir = Path::new(&out_dir);
    std::fs::create_dir_all(out_dir).unwrap();
    let root = Path::new(FIXTURES);
    let inputs = mesh_files(&root.join("gltf"))
        .into_iter()
        .chain([root.join("obj/spot_control_mesh.obj")]);
    for path in inputs {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let bytes = std::fs::read(&path).unwrap();
        let format = Format::from_file_name(&path.to_string_lossy()).unwrap();
        let Ok(doc) = io::read(&bytes, format, &ReadLimits::default()) else {
            continue;
        };
        let smoothed = meshsmooth_core::run(
            &doc.mesh,
            &Params::default(),
            &NoProgress,
            &AtomicBool::new(false),
        )
        .unwrap();
        let options = WriteOptions {
            results: Some(VertexResults::from(&smoothed.per_vertex)),
            ..WriteOptions::default()
        };
        for to in [Format::Gltf, Format::Glb] {
            let out = io::write_with(&doc, &smoothed.positions, to, &options).unwrap();
            let file = out_dir.join(format!("{name}.{}.{}", format.name(), to.extension()));
            std::fs::write(file, out).unwrap();
        }
    }
}
