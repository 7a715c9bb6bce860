//! Bodies that touch face to face: two labels of one segmentation written
//! into one file, each with its own vertices. Each is welded and smoothed
//! as it would be alone, whatever the format, and the report says so.

use glam::{DVec3, IVec3};
use meshsmooth_core::io::{self, Format, ReadLimits, ReadOptions};
use meshsmooth_core::job::{self, Request};
use meshsmooth_core::shapes::{VoxelMask, label_complex, voxel_boundary_mesh};
use meshsmooth_core::{Mesh, NoProgress, Params};
use std::sync::atomic::AtomicBool;

const RADIUS: f64 = 7.3;

/// The voxels of a ball of [`RADIUS`] whose centre's x is below (`left`)
/// or at least (not `left`) `split`: two labels that touch along a disc.
fn half_ball(left: bool, split: usize) -> VoxelMask {
    let n = 2 * RADIUS.ceil() as usize + 2;
    let centre = DVec3::splat(n as f64 / 2.0 + 0.21);
    VoxelMask::from_fn(IVec3::ZERO, [n, n, n], |i, j, k| {
        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
        c.distance(centre) < RADIUS && (i < split) == left
    })
}

/// The voxel quads of a ball in two labels split off centre (at x = 6):
/// a cap and the rest, whose volume restorations differ.
fn cap_and_rest() -> [Mesh; 2] {
    [true, false].map(|left| voxel_boundary_mesh(&half_ball(left, 6)))
}

/// `meshes` in one mesh, each with its own vertices.
fn together(meshes: &[&Mesh]) -> Mesh {
    let mut positions = Vec::new();
    let mut faces: Vec<Vec<u32>> = Vec::new();
    for m in meshes {
        let base = positions.len() as u32;
        positions.extend_from_slice(m.positions());
        faces.extend(m.faces().map(|f| f.iter().map(|&v| v + base).collect()));
    }
    Mesh::from_polygons(positions, &faces).unwrap()
}

fn bytes(mesh: &Mesh, format: Format) -> Vec<u8> {
    let mut out = Vec::new();
    match format {
        Format::Obj => io::obj::write_obj_plain(mesh, mesh.positions(), &mut out).unwrap(),
        _ => io::stl::write_stl_plain(mesh, mesh.positions(), false, &mut out).unwrap(),
    }
    out
}

/// The smoothed file and the job's report.
fn smooth(file: &[u8], format: Format) -> (Vec<u8>, meshsmooth_core::report::QualityReport) {
    let params = Params::default();
    let request = Request {
        bytes: file,
        format,
        params: &params,
        limits: ReadLimits::default(),
        output_format: None,
    };
    let out = job::run(&request, &NoProgress, &AtomicBool::new(false)).unwrap();
    (out.bytes, out.report)
}

/// The file's vertex positions, in its own order (unwelded).
fn file_positions(file: &[u8], format: Format) -> Vec<DVec3> {
    let options = ReadOptions {
        weld: Some(false),
        ..ReadOptions::default()
    };
    let doc = io::read_with(file, format, &options).unwrap();
    doc.mesh.positions().to_vec()
}

/// Each output position by the bits of its input position (the file's
/// vertices at one position agree), sorted.
fn by_input_position(input: &[DVec3], output: &[DVec3]) -> Vec<([u64; 3], DVec3)> {
    let mut out: Vec<([u64; 3], DVec3)> = input
        .iter()
        .zip(output)
        .map(|(p, &q)| (p.to_array().map(f64::to_bits), q))
        .collect();
    out.sort_by_key(|x| x.0);
    out.dedup_by_key(|x| x.0);
    out
}

/// `mesh` with each vertex moved to its output position in `table`
/// ([`by_input_position`]).
fn moved(mesh: &Mesh, table: &[([u64; 3], DVec3)]) -> Mesh {
    let at = |p: DVec3| {
        let key = p.to_array().map(f64::to_bits);
        let i = table.binary_search_by_key(&key, |x| x.0).unwrap();
        table[i].1
    };
    let mut out = mesh.clone();
    out.set_positions(mesh.positions().iter().map(|&p| at(p)).collect())
        .unwrap();
    out
}

#[test]
fn two_labels_in_one_file_smooth_as_each_alone() {
    // Restoring the cap's and the rest's volumes together would move both
    // (by half a percent and more of their volumes).
    let labels = cap_and_rest();
    let both = together(&[&labels[0], &labels[1]]);
    let alone: Vec<Mesh> = labels
        .iter()
        .map(|m| {
            let (out, _) = smooth(&bytes(m, Format::Obj), Format::Obj);
            moved(
                m,
                &by_input_position(m.positions(), &file_positions(&out, Format::Obj)),
            )
        })
        .collect();
    for format in [Format::Obj, Format::Stl] {
        let file = bytes(&both, format);
        let doc = io::read(&file, format, &ReadLimits::default()).unwrap();
        let bodies = doc.bodies.as_ref().expect("two bodies told apart");
        assert_eq!(bodies.count, 2, "{format}");
        // Each body keeps its own copy of the wall's vertices.
        assert_eq!(
            doc.mesh.num_vertices(),
            labels[0].num_vertices() + labels[1].num_vertices(),
            "{format}"
        );

        let (out, report) = smooth(&file, format);
        assert_eq!(report.mesh.touching_bodies, 2);
        assert_eq!(report.mesh.shared_faces as usize, bodies.shared.len());
        assert!(report.walls_parted.is_some_and(|w| w.max > 0.0));
        assert!(
            report
                .warnings
                .iter()
                .any(|w| w.contains("touch face to face")),
            "{:?}",
            report.warnings
        );
        // The first label's vertices come first in the file (an STL has
        // three a triangle, two triangles a quad).
        let (input, output) = (file_positions(&file, format), file_positions(&out, format));
        let split_at = match format {
            Format::Obj => labels[0].num_vertices(),
            _ => 6 * labels[0].num_faces(),
        };
        for (k, range) in [0..split_at, split_at..input.len()].into_iter().enumerate() {
            let got = moved(
                &labels[k],
                &by_input_position(&input[range.clone()], &output[range]),
            );
            // The same surface as alone: the same volume, and the same
            // positions but for the seeds of the adaptive neighbourhoods,
            // picked by vertex number (the file numbers them otherwise).
            let volume = got.signed_volume() / alone[k].signed_volume() - 1.0;
            assert!(volume.abs() < 1e-4, "{format} label {k}: volume {volume}");
            let squares: f64 = got
                .positions()
                .iter()
                .zip(alone[k].positions())
                .map(|(a, b)| a.distance_squared(*b))
                .sum();
            let rms = (squares / got.num_vertices() as f64).sqrt();
            assert!(rms < 0.01, "{format} label {k}: {rms} voxel");
        }
    }
}

#[test]
fn one_label_touching_itself_along_an_edge_is_one_body() {
    // Two voxels of one mask touching along an edge share no face: no
    // bodies are told apart, and the file welds as before.
    let mask = VoxelMask::from_fn(IVec3::ZERO, [2, 2, 1], |i, j, _| i == j);
    let mesh = voxel_boundary_mesh(&mask);
    let doc = io::read(
        &bytes(&mesh, Format::Stl),
        Format::Stl,
        &ReadLimits::default(),
    )
    .unwrap();
    assert!(doc.bodies.is_none());
    assert_eq!(doc.mesh.num_vertices(), mesh.num_vertices());
}

#[test]
fn a_surface_written_twice_smooths_as_once() {
    // The same ball twice in one file (an object exported twice): every
    // face coincides with its copy, wound alike.
    let ball = voxel_boundary_mesh(&half_ball(true, usize::MAX));
    let twice = together(&[&ball, &ball]);
    let file = bytes(&twice, Format::Obj);
    let doc = io::read(&file, Format::Obj, &ReadLimits::default()).unwrap();
    let bodies = doc.bodies.as_ref().expect("the copies told apart");
    assert_eq!((bodies.count, bodies.shared.len()), (2, ball.num_faces()));
    assert_eq!(doc.mesh.num_vertices(), twice.num_vertices());

    let (out, _) = smooth(&file, Format::Obj);
    let out = file_positions(&out, Format::Obj);
    let (once, _) = smooth(&bytes(&ball, Format::Obj), Format::Obj);
    let once = Mesh::from_polygons(
        file_positions(&once, Format::Obj),
        &ball.faces().map(<[u32]>::to_vec).collect::<Vec<_>>(),
    )
    .unwrap();
    let n = ball.num_vertices();
    for copy in [&out[..n], &out[n..]] {
        let mut got = ball.clone();
        got.set_positions(copy.to_vec()).unwrap();
        let volume = got.signed_volume() / once.signed_volume() - 1.0;
        assert!(volume.abs() < 1e-4, "volume {volume}");
    }
}

/// A GLB holding `meshes` as glTF meshes of their own (one node each),
/// triangles, f32 positions and u32 indices in one binary chunk.
fn glb(meshes: &[&Mesh]) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut gltf_meshes, mut nodes) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (k, m) in meshes.iter().enumerate() {
        let start = bin.len();
        for p in m.positions() {
            for c in p.to_array() {
                bin.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        let positions_end = bin.len();
        let mut count = 0;
        for f in m.faces() {
            for w in f.windows(2).skip(1) {
                for i in [f[0], w[0], w[1]] {
                    bin.extend_from_slice(&i.to_le_bytes());
                    count += 1;
                }
            }
        }
        let (lo, hi) = m
            .positions()
            .iter()
            .fold(([f64::MAX; 3], [f64::MIN; 3]), |(lo, hi), p| {
                let a = p.to_array();
                (
                    std::array::from_fn(|i| lo[i].min(a[i])),
                    std::array::from_fn(|i| hi[i].max(a[i])),
                )
            });
        views.push(serde_json::json!({"buffer": 0, "byteOffset": start, "byteLength": positions_end - start}));
        views.push(serde_json::json!({"buffer": 0, "byteOffset": positions_end, "byteLength": bin.len() - positions_end}));
        accessors.push(serde_json::json!({"bufferView": 2 * k, "componentType": 5126, "count": m.num_vertices(), "type": "VEC3", "min": lo, "max": hi}));
        accessors.push(serde_json::json!({"bufferView": 2 * k + 1, "componentType": 5125, "count": count, "type": "SCALAR"}));
        gltf_meshes.push(serde_json::json!({"primitives": [{"attributes": {"POSITION": 2 * k}, "indices": 2 * k + 1}]}));
        nodes.push(serde_json::json!({"mesh": k}));
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..meshes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": gltf_meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut text = serde_json::to_vec(&json).unwrap();
    text.resize(text.len().next_multiple_of(4), b' ');
    bin.resize(bin.len().next_multiple_of(4), 0);
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + text.len() + 8 + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

#[test]
fn the_meshes_of_a_gltf_smooth_each_as_alone() {
    // Two labels as two glTF meshes: never welded to each other (each
    // lives in its own space), and each gets its own volume back.
    let labels = cap_and_rest();
    let file = glb(&[&labels[0], &labels[1]]);
    let doc = io::read(&file, Format::Glb, &ReadLimits::default()).unwrap();
    let bodies = doc.bodies.as_ref().expect("one body per glTF mesh");
    assert_eq!((bodies.count, bodies.shared.len()), (2, 0));
    let (out, report) = smooth(&file, Format::Glb);
    assert_eq!(
        report.mesh.touching_bodies, 0,
        "the meshes do not share a vertex"
    );
    let out = file_positions(&out, Format::Glb);
    let n = labels[0].num_vertices();
    for (k, copy) in [&out[..n], &out[n..]].into_iter().enumerate() {
        let (alone, _) = smooth(&glb(&[&labels[k]]), Format::Glb);
        let alone = file_positions(&alone, Format::Glb);
        let (mut got, mut want) = (labels[k].clone(), labels[k].clone());
        got.set_positions(copy.to_vec()).unwrap();
        want.set_positions(alone).unwrap();
        let volume = got.signed_volume() / want.signed_volume() - 1.0;
        assert!(volume.abs() < 1e-4, "label {k}: volume {volume}");
    }
}

#[test]
fn two_labels_as_one_complex_smooth_region_by_region() {
    // The cap and the rest with their wall written once, as VTK's surface
    // nets write a label map: each label is smoothed as its own closed
    // surface and each wall vertex takes the mean of the two.
    let labels = cap_and_rest();
    let mesh = label_complex(&[half_ball(true, 6), half_ball(false, 6)]);
    let params = Params::default();
    let cancel = AtomicBool::new(false);
    let out = meshsmooth_core::run(&mesh, &params, &NoProgress, &cancel).unwrap();
    let report = &out.report;
    let walls = labels[0].num_faces() + labels[1].num_faces() - mesh.num_faces();
    assert_eq!(report.mesh.regions, 2);
    assert_eq!(report.mesh.region_walls as usize, walls);
    assert!(report.walls_joined.is_some_and(|w| w.max > 0.0));
    assert!(report.joined_fixes.is_some());
    assert!(
        report
            .warnings
            .iter()
            .any(|w| w.contains("complex of 2 regions")),
        "{:?}",
        report.warnings
    );
    let final_stage = report.stages.final_stage.as_ref().unwrap();
    assert_eq!(
        (final_stage.inverted_faces, final_stage.twisted_quads),
        (0, 0)
    );

    // Each label alone, by input position; a complex vertex on both labels
    // (the wall's) is expected at their mean.
    let alone: Vec<Vec<([u64; 3], DVec3)>> = labels
        .iter()
        .map(|m| {
            let o = meshsmooth_core::run(m, &params, &NoProgress, &cancel).unwrap();
            by_input_position(m.positions(), &o.positions)
        })
        .collect();
    let (mut squares, mut wall_vertices) = (0.0, 0);
    for (p, q) in mesh.positions().iter().zip(&out.positions) {
        let key = p.to_array().map(f64::to_bits);
        let found: Vec<DVec3> = alone
            .iter()
            .filter_map(|t| t.binary_search_by_key(&key, |x| x.0).ok().map(|i| t[i].1))
            .collect();
        if found.len() == 2 {
            wall_vertices += 1;
        }
        let expected = found.iter().sum::<DVec3>() / found.len() as f64;
        squares += q.distance_squared(expected);
    }
    assert!(wall_vertices > 0);
    let rms = (squares / mesh.num_vertices() as f64).sqrt();
    assert!(rms < 0.02, "{rms} voxel from the labels' own results");
}
