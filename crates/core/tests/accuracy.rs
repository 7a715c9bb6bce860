//! Issue 3 acceptance on analytic shapes with DEFAULT parameters: the
//! smoothed voxel-boundary and marching-cubes meshes lie closer to the true
//! surface than the best any Laplacian/Taubin/windowed-sinc variant reaches
//! at any iteration count (figures measured by the team with trimesh, VTK,
//! PyMeshLab, Open3D and libigl), the volume is kept, and the quality step
//! leaves no twisted quad, no inverted face and no angle below 15 degrees.

use meshsmooth_core::report::InputGrid;
use meshsmooth_core::shapes::{self, Shape};
use meshsmooth_core::{Mesh, NoProgress, Params, SmoothOutput, run};
use std::sync::atomic::AtomicBool;

fn smooth(mesh: &Mesh) -> SmoothOutput {
    run(
        mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .expect("smoothing runs")
}

/// Checks accuracy, volume and quality; returns the output RMS.
fn check(name: &str, shape: &dyn Shape, mesh: &Mesh, max_rms: f64) -> f64 {
    let out = smooth(mesh);
    assert_eq!(out.positions.len(), mesh.num_vertices());
    assert!(out.positions.iter().all(|p| p.is_finite()), "{name}: NaN");
    let rms_in = shapes::rms_distance(shape, mesh.positions());
    let rms = shapes::rms_distance(shape, &out.positions);
    assert!(
        rms <= max_rms,
        "{name}: RMS {rms:.4} > {max_rms} (input {rms_in:.4})"
    );
    let vol = meshsmooth_core::mesh::signed_volume(mesh, &out.positions);
    let err = vol / shape.volume() - 1.0;
    assert!(
        err.abs() <= 0.005,
        "{name}: volume off by {:.3}%",
        err * 100.0
    );
    let f = out
        .report
        .stages
        .final_stage
        .as_ref()
        .expect("final stage measured");
    assert_eq!(f.twisted_quads, 0, "{name}: twisted quads");
    assert_eq!(f.inverted_faces, 0, "{name}: inverted faces");
    let min = f.triangle_angles.min_deg.expect("angles measured");
    assert!(min >= 15.0, "{name}: min triangle-split angle {min:.2}");
    assert_eq!(f.triangle_angles.below_15, 0);
    rms
}

#[test]
fn voxel_sphere_r12_beats_baselines_by_a_quarter() {
    let (s, m) = shapes::voxel_sphere(12.0);
    // Best baseline 0.049 voxel; target 0.75 x 0.049.
    check("voxel sphere r=12", &s, &m, 0.037);
}

#[test]
fn voxel_torus_beats_baselines_by_a_quarter() {
    let (t, m) = shapes::voxel_torus(20.0, 8.0);
    // Best baseline 0.080 voxel; target 0.75 x 0.080.
    check("voxel torus", &t, &m, 0.060);
}

#[test]
fn voxel_ellipsoid_beats_baselines_by_a_quarter() {
    let (e, m) = shapes::voxel_ellipsoid(30.0, 20.0, 12.0);
    // Best baseline 0.055 voxel; target 0.75 x 0.055.
    check("voxel ellipsoid", &e, &m, 0.041);
}

#[test]
fn marching_cubes_sphere_and_torus_beat_best_baselines() {
    let (s, m) = shapes::mc_sphere(12.0);
    check("mc sphere r=12", &s, &m, 0.046);
    let (t, m) = shapes::mc_torus(20.0, 8.0);
    check("mc torus", &t, &m, 0.085);
}

#[test]
fn a_marching_cubes_mesh_on_an_oblique_grid_smooths_as_on_the_axes() {
    // An image with an oblique affine, its marching cubes written in world
    // coordinates (single precision): the grid is found in its own frame,
    // and the result is the axis-aligned one's, rotated.
    let (t, m) = shapes::mc_torus(20.0, 8.0);
    let aligned = shapes::rms_distance(&t, &smooth(&m).positions);
    let rot = glam::DQuat::from_euler(glam::EulerRot::ZYX, 0.4, -0.25, 0.9);
    let origin = glam::DVec3::new(-96.5, 131.2, -72.8);
    let mut oblique = m.clone();
    for p in oblique.positions_mut() {
        *p = (rot * *p + origin).as_vec3().as_dvec3();
    }
    let out = smooth(&oblique);
    let grid = out.report.wang_yu.as_ref().map(|w| w.input_grid);
    assert_eq!(grid, Some(InputGrid::MarchingCubes));
    let back: Vec<_> = out
        .positions
        .iter()
        .map(|p| rot.inverse() * (*p - origin))
        .collect();
    let rotated = shapes::rms_distance(&t, &back);
    assert!(
        (rotated - aligned).abs() <= 0.01 * aligned,
        "oblique grid RMS {rotated:.4} against {aligned:.4} on the axes"
    );
}

#[test]
fn the_report_names_the_grid_the_input_was_cut_from() {
    let grid = |mesh: &Mesh| smooth(mesh).report.wang_yu.map(|w| w.input_grid);
    let (_, voxel) = shapes::voxel_sphere(6.0);
    assert_eq!(grid(&voxel), Some(InputGrid::Voxel));
    let (sphere, mc) = shapes::mc_sphere(6.0);
    assert_eq!(grid(&mc), Some(InputGrid::MarchingCubes));
    // The same triangles with their vertices on the sphere: no grid.
    let mut on_sphere = mc.clone();
    for p in on_sphere.positions_mut() {
        *p = sphere.center + sphere.radius * (*p - sphere.center).normalize();
    }
    assert_eq!(grid(&on_sphere), Some(InputGrid::None));
}

#[test]
fn a_mesh_of_no_grid_keeps_a_smooth_surface_and_loses_its_noise() {
    // A torus whose tube is three or four edges across, every vertex on
    // it: the passes' fits would flatten the tube's curvature, and the
    // input's own noise (none) says they should not.
    let (torus, mesh) = shapes::tessellated_torus(10.0, 2.5, 0.7);
    let edge = mesh.mean_edge_length();
    let free = Params {
        noise_bound: None,
        ..Params::default()
    };
    let rms_free = shapes::rms_distance(
        &torus,
        &run(&mesh, &free, &NoProgress, &AtomicBool::new(false))
            .expect("smoothing runs")
            .positions,
    );
    let out = smooth(&mesh);
    let rms = shapes::rms_distance(&torus, &out.positions);
    let noise = out.report.wang_yu.as_ref().and_then(|w| w.input_noise);
    assert!(noise.is_some_and(|n| n < 0.01), "{noise:?}");
    assert!(
        rms < 0.01 * edge && rms_free > 5.0 * rms,
        "RMS {rms:.4} against {rms_free:.4} without the noise bound"
    );
    // The same torus with noise of a tenth of an edge along the normals:
    // estimated as such, and most of it taken out.
    let mut noisy = mesh.clone();
    for (i, p) in noisy.positions_mut().iter_mut().enumerate() {
        *p += torus.normal_at(*p) * 0.1 * edge * shapes::normal_deviate(7, i as u64);
    }
    let rms_in = shapes::rms_distance(&torus, noisy.positions());
    let out = smooth(&noisy);
    let rms = shapes::rms_distance(&torus, &out.positions);
    let noise = out.report.wang_yu.as_ref().and_then(|w| w.input_noise);
    assert!(noise.is_some_and(|n| n > 0.06 && n < 0.095), "{noise:?}");
    assert!(
        rms < 0.7 * rms_in,
        "noisy torus: RMS {rms:.4} against {rms_in:.4} in"
    );
    let f = out.report.stages.final_stage.expect("final stage measured");
    assert_eq!(f.inverted_faces, 0);
    assert!(f.triangle_angles.min_deg.is_some_and(|a| a >= 20.0));
}

#[test]
fn a_voxel_mesh_written_as_triangles_smooths_as_its_voxel_faces() {
    // STL and glTF hold triangles only: each square split along a
    // diagonal, here alternating between the two.
    let (sphere, quads) = shapes::voxel_sphere(8.0);
    let tris: Vec<[u32; 3]> = quads
        .faces()
        .enumerate()
        .flat_map(|(f, q)| {
            let s = f % 2;
            let c = |i: usize| q[(i + s) % 4];
            [[c(0), c(1), c(2)], [c(0), c(2), c(3)]]
        })
        .collect();
    let split = Mesh::from_polygons(quads.positions().to_vec(), &tris).unwrap();
    let (a, b) = (smooth(&quads), smooth(&split));
    let summary = b.report.wang_yu.as_ref().unwrap();
    assert_eq!(summary.input_grid, InputGrid::Voxel);
    assert_eq!(summary.paired_triangles, quads.num_faces() as u64);
    // As close to the sphere as the quads, every corner within a voxel of
    // where it was (its dual voxel, or the quality fixes' room).
    let (rms_a, rms_b) = (
        shapes::rms_distance(&sphere, &a.positions),
        shapes::rms_distance(&sphere, &b.positions),
    );
    assert!(rms_b < 1.05 * rms_a, "{rms_b} against {rms_a} as quads");
    let input = quads.positions();
    assert!(
        b.positions
            .iter()
            .zip(input)
            .all(|(p, q)| (*p - *q).length() <= 1.0 + 1e-9)
    );
    // Measured on the file's triangles: nothing folded or sharp there.
    let last = b.report.stages.final_stage.as_ref().unwrap();
    assert_eq!(last.triangle_angles.count, 3 * split.num_faces() as u64);
    assert_eq!(last.inverted_faces, 0);
    assert!(
        last.triangle_angles.min_deg >= Some(15.0),
        "{:?}",
        last.triangle_angles.min_deg
    );
}

#[test]
fn smoothing_moves_the_voxel_sphere_much_closer() {
    let (s, m) = shapes::voxel_sphere(8.0);
    let out = smooth(&m);
    let before = shapes::rms_distance(&s, m.positions());
    let after = shapes::rms_distance(&s, &out.positions);
    assert!(after < 0.15 * before, "{before} -> {after}");
}

#[test]
fn reported_curvature_is_the_spheres_and_its_variation_drops() {
    // The input and every later stage use the same 2-ring estimator, so the
    // input's staircase shows as a large variation and the smoothed sphere's
    // as a small one; the per-vertex mean curvature is about -1/r (convex,
    // outward normals).
    let r = 12.0;
    let (_, m) = shapes::voxel_sphere(r);
    let variation = |out: &SmoothOutput, stage: &str| {
        let s = &out.report.stages;
        let measures = match stage {
            "input" => s.input.as_ref(),
            "adaptive" => s.adaptive.as_ref(),
            _ => s.final_stage.as_ref(),
        };
        measures
            .and_then(|m| m.curvature_variation.as_ref())
            .unwrap_or_else(|| panic!("{stage} has a curvature variation"))
            .mean_scaled
    };
    let out = smooth(&m);
    let h = &out.per_vertex.mean_curvature;
    assert_eq!(h.len(), m.num_vertices());
    let mean = h.iter().sum::<f64>() / h.len() as f64;
    assert!((mean * r + 1.0).abs() < 0.03, "mean H {mean} vs -1/{r}");
    let spread = (h.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / h.len() as f64).sqrt();
    // The fidelity bound holds the staircase's deepest corners on the walls
    // of their dual voxels, where the curvature bends a little: the spread
    // stays under an eighth of the sphere's curvature.
    assert!(spread < 0.125 / r, "H spread {spread}");
    // The staircase's variation falls more than thirtyfold. (The lattice
    // fairing, which makes the accuracy independent of where the grid
    // falls, leaves this grid-symmetric sphere a little less even than the
    // relaxation alone: about 0.011 against 0.007, docs/tuning.md.)
    let input = variation(&out, "input");
    let (a, f) = (variation(&out, "adaptive"), variation(&out, "final"));
    assert!(
        a < 0.03 * input && f < 0.03 * input,
        "{a} {f} vs input {input}"
    );

    // A baseline reports the same measure for its output: Taubin keeps
    // much more of the staircase than the adaptive fits.
    let params = Params {
        method: meshsmooth_core::params::Method::Taubin,
        ..Params::default()
    };
    let taubin = run(&m, &params, &NoProgress, &AtomicBool::new(false)).expect("runs");
    // The input's curvature is the same whichever method smooths it, and
    // the same as a report of the mesh alone (Wang-Yu takes it from its
    // first initial pass, the others fit it for the report).
    let report = meshsmooth_core::pipeline::measure(&m, &Params::default());
    let input_stage = |r: &meshsmooth_core::report::QualityReport| {
        r.stages.input.as_ref().and_then(|s| s.curvature_variation)
    };
    assert!(input_stage(&report).is_some());
    assert_eq!(input_stage(&out.report), input_stage(&report));
    assert_eq!(input_stage(&taubin.report), input_stage(&report));
    let (wang_yu, baseline) = (variation(&out, "final"), variation(&taubin, "final"));
    assert!(
        baseline < input && wang_yu < 0.2 * baseline,
        "{wang_yu} vs {baseline}"
    );
}

#[test]
fn without_quality_fixes_the_final_curvature_is_the_adaptive_stages() {
    let (_, m) = shapes::voxel_sphere(6.0);
    let mut params = Params::default();
    params.quality.enabled = false;
    let out = run(&m, &params, &NoProgress, &AtomicBool::new(false)).expect("runs");
    let s = &out.report.stages;
    let (adaptive, last) = (
        s.adaptive.as_ref().unwrap(),
        s.final_stage.as_ref().unwrap(),
    );
    assert!(adaptive.curvature_variation.is_some());
    assert_eq!(adaptive.curvature_variation, last.curvature_variation);
}

#[test]
fn output_is_identical_with_one_and_two_threads() {
    // A torus, two spheres whose masks touch (non-manifold vertices,
    // which the sharp-angle fix's second run moves), and a noisy torus of
    // no grid (the noise estimate and its slabs).
    let (_, torus) = shapes::voxel_torus(10.0, 4.0);
    let touching = shapes::voxel_boundary_mesh(&shapes::voxel_mask(&shapes::placed(
        shapes::sphere_pair(5.0, 0.0),
        0,
    )));
    let (smooth_torus, mut noisy) = shapes::tessellated_torus(8.0, 2.0, 0.7);
    for (i, p) in noisy.positions_mut().iter_mut().enumerate() {
        *p += smooth_torus.normal_at(*p) * 0.07 * shapes::normal_deviate(3, i as u64);
    }
    let run_with = |m: &Mesh, threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| smooth(m))
    };
    let bits = |o: &SmoothOutput| -> Vec<u64> {
        o.positions
            .iter()
            .flat_map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
            .collect()
    };
    for m in [torus, touching, noisy] {
        let a = run_with(&m, 1);
        let b = run_with(&m, 2);
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(a.per_vertex.label, b.per_vertex.label);
    }
}

#[test]
fn a_folded_mesh_of_no_grid_keeps_its_folds_and_loses_its_noise() {
    // Folds eight edges long and one edge deep, as the marching cubes of a
    // cortex's probability map has them, with noise of a tenth of an edge
    // along the normals: the passes' fits flatten such folds by about as
    // much as they take out of the noise, and the drift their neighbours
    // share is taken back.
    let (sheet, clean) = shapes::tessellated_sine_sheet(8.0, 1.0, 40);
    let edge = clean.mean_edge_length();
    let mut noisy = clean.clone();
    for (i, p) in noisy.positions_mut().iter_mut().enumerate() {
        *p += sheet.normal_at(p.x) * 0.1 * edge * shapes::normal_deviate(7, i as u64);
    }
    // Away from the rim, which stays where it is.
    let inner = |p: &glam::DVec3| (5.0..35.0).contains(&p.x) && (5.0..35.0).contains(&p.y);
    let rms = |positions: &[glam::DVec3], input: &Mesh| {
        let d: Vec<f64> = positions
            .iter()
            .zip(input.positions())
            .filter(|(_, q)| inner(q))
            .map(|(p, _)| sheet.distance(*p))
            .collect();
        (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt()
    };
    // Without the drift taken back neither holds: the folds flatten.
    let cases = [
        ("clean", &clean, 0.035 * edge),
        ("noisy", &noisy, 0.7 * rms(noisy.positions(), &noisy)),
    ];
    for (name, input, limit) in cases {
        let out = smooth(input);
        let after = rms(&out.positions, input);
        assert!(after < limit, "{name}: RMS {after:.4}, limit {limit:.4}");
        let f = out.report.stages.final_stage.expect("final stage measured");
        assert_eq!(f.inverted_faces, 0, "{name}");
    }
}
