//! The shapes that look like segmentations (thin shells, thin tubes,
//! spheres whose masks touch, folded sheets), each at 8 seeded grid
//! placements and meshed both as voxel quads and by marching cubes: the
//! default pipeline keeps every vertex within one voxel of where it was and
//! ends closer to the true surface than it started, and folds no face,
//! twists no quad and leaves no angle under 18 degrees on any of them.
//! `cargo run --release -p meshsmooth-core --example placements` prints
//! the full figures.

use meshsmooth_core::shapes::{self, Shape};
use meshsmooth_core::{Mesh, NoProgress, Params, SmoothOutput, run};
use std::sync::atomic::AtomicBool;

const PLACEMENTS: u64 = 8;

/// The smallest triangle-split angle every output keeps, in degrees: the
/// sharp-angle fix's threshold (20) less a margin for faces that the
/// fidelity bound keeps from opening all the way. Where voxels touch, the
/// angles at the shared corner open only if that corner may move too. On
/// the folded sheets, thin tubes and touching spheres some faces open only
/// when the fix may move a vertex along its own surface, not only onto its
/// fitted quadric (`quality/sharp_angle.rs`).
const MIN_ANGLE_DEG: f64 = 18.0;

fn check<S: Shape + Copy>(name: &str, shape: S) {
    for seed in 0..PLACEMENTS {
        let placed = shapes::placed(shape, seed);
        let mask = shapes::voxel_mask(&placed);
        for (kind, mesh) in [
            ("voxel", shapes::voxel_boundary_mesh(&mask)),
            ("mc", shapes::marching_cubes_mesh(&mask)),
        ] {
            let what = format!("{kind} {name} placement {seed}");
            check_run(&what, &placed, &mesh);
        }
    }
}

/// `mesh` smoothed at the defaults, with no face folded and no quad
/// twisted.
fn smoothed_unfolded(what: &str, mesh: &Mesh) -> SmoothOutput {
    let out = run(
        mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .unwrap_or_else(|e| panic!("{what}: {e}"));
    let fin = out.report.stages.final_stage.as_ref().expect("final stage");
    assert_eq!(fin.inverted_faces, 0, "{what}: folded faces");
    assert_eq!(fin.twisted_quads, 0, "{what}: twisted quads");
    out
}

fn check_run(what: &str, shape: &dyn Shape, mesh: &Mesh) {
    let out = smoothed_unfolded(what, mesh);
    let fin = out.report.stages.final_stage.as_ref().expect("final stage");
    let smallest = fin.triangle_angles.min_deg.unwrap_or(0.0);
    assert!(
        smallest >= MIN_ANGLE_DEG,
        "{what}: smallest angle {smallest}"
    );
    // Voxel corners may go to their dual voxel's corner (sqrt(3)/2 voxel);
    // the quality fixes get a ball of one voxel.
    assert!(
        fin.displacement.max <= 1.0 + 1e-9,
        "{what}: moved {}",
        fin.displacement.max
    );
    let (rms_in, rms_out) = (
        shapes::rms_distance(shape, mesh.positions()),
        shapes::rms_distance(shape, &out.positions),
    );
    assert!(rms_out < rms_in, "{what}: rms {rms_in} -> {rms_out}");
    let held = out
        .report
        .wang_yu
        .as_ref()
        .and_then(|w| w.fidelity_held_back);
    assert!(
        held.is_some(),
        "{what}: the report counts the held-back vertices"
    );
}

#[test]
fn thin_shells() {
    check("shell t=2", shapes::shell(10.0, 2.0));
    check("shell t=3", shapes::shell(10.0, 3.0));
}

#[test]
fn thin_tubes() {
    for minor in [1.5, 2.0, 3.0] {
        check(&format!("tube r={minor}"), shapes::tube(10.0, minor));
    }
}

#[test]
fn touching_spheres() {
    check("tangent spheres", shapes::sphere_pair(5.0, 0.0));
    check("spheres 0.5 apart", shapes::sphere_pair(5.0, 0.5));
}

#[test]
fn folded_sheets() {
    check("folded sheet t=2", shapes::folded_sheet(2.0));
    check("folded sheet t=3", shapes::folded_sheet(3.0));
}

#[test]
fn touching_masks_make_non_manifold_contacts() {
    // The family exercises what it is for: across its placements the
    // tangent spheres' masks touch along edges or at corners.
    let contacts: usize = (0..PLACEMENTS)
        .map(|seed| {
            let mask = shapes::voxel_mask(&shapes::placed(shapes::sphere_pair(5.0, 0.0), seed));
            let mesh = shapes::voxel_boundary_mesh(&mask);
            let topo = meshsmooth_core::Topology::build(&mesh);
            topo.kinds()
                .iter()
                .filter(|k| **k == meshsmooth_core::VertexKind::NonManifold)
                .count()
        })
        .sum();
    assert!(contacts > 0, "no placement makes a non-manifold contact");
}

/// The mean signed distance from a sphere of `radius` about `centre` of the
/// vertices whose input lies on the side of `split` that `outer` says.
fn mean_radial_error(
    input: &[glam::DVec3],
    output: &[glam::DVec3],
    centre: glam::DVec3,
    split: f64,
    outer: bool,
    radius: f64,
) -> f64 {
    let errors: Vec<f64> = input
        .iter()
        .zip(output)
        .filter(|(i, _)| ((**i - centre).length() > split) == outer)
        .map(|(_, o)| (*o - centre).length() - radius)
        .collect();
    errors.iter().sum::<f64>() / errors.len() as f64
}

#[test]
fn both_surfaces_of_a_shell_stay_where_they_were() {
    // The fits push a convex surface outwards and a concave one inwards, so
    // both surfaces of a shell drift away from its centre while its volume
    // barely changes: the outer surface and the cavity's each get their
    // volume back, and neither is left offset.
    let (outer, thickness) = (10.0, 2.0);
    let shell = shapes::placed(shapes::shell(outer, thickness), 3);
    let centre = 0.5 * (shell.bounds().0 + shell.bounds().1);
    let mask = shapes::voxel_mask(&shell);
    for (kind, mesh) in [
        ("voxel", shapes::voxel_boundary_mesh(&mask)),
        ("mc", shapes::marching_cubes_mesh(&mask)),
    ] {
        let out = run(
            &mesh,
            &Params::default(),
            &NoProgress,
            &AtomicBool::new(false),
        )
        .unwrap_or_else(|e| panic!("{kind}: {e}"));
        let split = outer - 0.5 * thickness;
        for (side, is_outer, radius) in
            [("outer", true, outer), ("inner", false, outer - thickness)]
        {
            let e = mean_radial_error(
                mesh.positions(),
                &out.positions,
                centre,
                split,
                is_outer,
                radius,
            );
            assert!(
                e.abs() < 0.03,
                "{kind} shell, {side} surface: offset {e:+.4} voxel"
            );
        }
    }
}

#[test]
fn thick_slices_are_smoothed_within_their_own_voxels() {
    // A thick-slice image: voxels 2.5 times as long across the slices (z).
    // The voxel sphere's mesh stretched so is the mask of the sphere
    // stretched so (an ellipsoid), sampled on that grid. The dual voxels are
    // as long across the slices: the terraces at the poles may come down to
    // the surface, and the sides may not leave their thin voxels.
    let spacing = glam::DVec3::new(1.0, 1.0, 2.5);
    let (sphere, voxel) = shapes::voxel_sphere(10.0);
    let mut mesh = voxel.clone();
    for p in mesh.positions_mut() {
        *p *= spacing;
    }
    let truth = shapes::Ellipsoid {
        center: sphere.center * spacing,
        semi_axes: sphere.radius * spacing,
    };
    let what = "voxel sphere on 1 x 1 x 2.5 voxels";
    let out = smoothed_unfolded(what, &mesh);
    // Within one voxel of where it was, counted in each axis's spacing.
    let farthest = out
        .positions
        .iter()
        .zip(mesh.positions())
        .map(|(p, q)| ((*p - *q) / spacing).length())
        .fold(0.0, f64::max);
    assert!(farthest <= 1.0 + 1e-9, "{what}: moved {farthest} voxels");
    let (rms_in, rms_out) = (
        shapes::rms_distance(&truth, mesh.positions()),
        shapes::rms_distance(&truth, &out.positions),
    );
    assert!(rms_out < 0.15 * rms_in, "{what}: rms {rms_in} -> {rms_out}");
}
