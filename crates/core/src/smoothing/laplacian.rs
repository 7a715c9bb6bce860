//! Baseline: uniform Laplacian (umbrella) smoothing with Jacobi updates.
//!
//! `p_i' = p_i + lambda * (mean_{j in N_1(i)} p_j - p_i)` for every movable
//! vertex, where `N_1(i)` are the vertices joined to `i` by a face side (for
//! quads: the four edge neighbours, not the diagonals). Vertices that are
//! not movable stay put: the pipeline's
//! [`movable_mask`](crate::pipeline::movable_mask) fixes boundary,
//! non-manifold and isolated vertices. Each step reads the previous
//! positions only (double buffered) and computes every vertex
//! independently in parallel, so the result does not depend on the number
//! of threads.

use crate::control::{Cancelled, check};
use crate::mesh::Topology;
#[cfg(test)]
use crate::mesh::{Mesh, signed_volume};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;

/// One umbrella step with factor `lambda` from `from` into `to` (both one
/// entry per vertex). A negative `lambda` inflates (Taubin's `mu` step).
pub fn umbrella_step(
    topo: &Topology,
    movable: &[bool],
    lambda: f64,
    from: &[DVec3],
    to: &mut [DVec3],
) {
    to.par_iter_mut()
        .enumerate()
        .with_min_len(4096)
        .for_each(|(v, out)| {
            let p = from[v];
            let nb = topo.neighbors(v);
            *out = if movable[v] && !nb.is_empty() {
                let c: DVec3 =
                    nb.iter().map(|&j| from[j as usize]).sum::<DVec3>() / nb.len() as f64;
                p + lambda * (c - p)
            } else {
                p
            };
        });
}

/// `iterations` umbrella steps with factor `lambda`, starting from
/// `positions` (one per vertex; `movable` likewise). Returns the smoothed
/// positions; checks `cancel` before every step.
pub fn laplacian_smooth(
    topo: &Topology,
    movable: &[bool],
    positions: &[DVec3],
    iterations: u32,
    lambda: f64,
    cancel: &AtomicBool,
) -> Result<Vec<DVec3>, Cancelled> {
    let mut cur = positions.to_vec();
    let mut next = cur.clone();
    for _ in 0..iterations {
        check(cancel)?;
        umbrella_step(topo, movable, lambda, &cur, &mut next);
        std::mem::swap(&mut cur, &mut next);
    }
    Ok(cur)
}

/// Laplacian smoothing with a volume constraint: after each umbrella step
/// all vertices (fixed ones included) are scaled about their mean position
/// so the signed enclosed volume of `mesh` stays that of `positions`.
///
/// The constraint only makes sense for a closed mesh: when the mesh has a
/// boundary edge, or either volume is not positive, a step is left
/// unscaled, which makes this plain [`laplacian_smooth`].
#[cfg(test)]
pub fn laplacian_smooth_preserving_volume(
    mesh: &Mesh,
    topo: &Topology,
    movable: &[bool],
    positions: &[DVec3],
    iterations: u32,
    lambda: f64,
    cancel: &AtomicBool,
) -> Result<Vec<DVec3>, Cancelled> {
    let closed = topo.num_boundary_edges() == 0;
    let target = signed_volume(mesh, positions);
    let mut cur = positions.to_vec();
    let mut next = cur.clone();
    for _ in 0..iterations {
        check(cancel)?;
        umbrella_step(topo, movable, lambda, &cur, &mut next);
        std::mem::swap(&mut cur, &mut next);
        if closed {
            rescale_to_volume(mesh, &mut cur, target);
        }
    }
    Ok(cur)
}

/// Scales `positions` about their mean so the signed volume of `mesh`
/// becomes `target`. Returns the factor applied (1 when either volume is
/// not positive or there are no vertices).
#[cfg(test)]
pub fn rescale_to_volume(mesh: &Mesh, positions: &mut [DVec3], target: f64) -> f64 {
    let volume = signed_volume(mesh, positions);
    if positions.is_empty() || volume <= 0.0 || target <= 0.0 || !volume.is_finite() {
        return 1.0;
    }
    let s = (target / volume).cbrt();
    let c = positions.iter().sum::<DVec3>() / positions.len() as f64;
    positions
        .par_iter_mut()
        .with_min_len(4096)
        .for_each(|p| *p = c + s * (*p - c));
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::BoundaryRule;
    use crate::pipeline::movable_mask;
    use crate::shapes::{Shape, rms_distance, voxel_sphere};

    #[test]
    fn smoothing_brings_a_voxel_sphere_closer_to_the_sphere() {
        let (sphere, mesh) = voxel_sphere(12.0);
        let topo = Topology::build(&mesh);
        let movable = movable_mask(&topo, BoundaryRule::Fixed);
        let no = AtomicBool::new(false);
        let before = rms_distance(&sphere, mesh.positions());
        let after = laplacian_smooth(&topo, &movable, mesh.positions(), 5, 0.5, &no).unwrap();
        let rms = rms_distance(&sphere, &after);
        assert!(rms < 0.5 * before, "rms {before} -> {rms}");
        // Plain Laplacian shrinks; the constrained variant does not.
        let v0 = mesh.signed_volume();
        let shrunk = laplacian_smooth(&topo, &movable, mesh.positions(), 50, 0.5, &no).unwrap();
        assert!(signed_volume(&mesh, &shrunk) < 0.97 * v0);
        let kept = laplacian_smooth_preserving_volume(
            &mesh,
            &topo,
            &movable,
            mesh.positions(),
            50,
            0.5,
            &no,
        )
        .unwrap();
        assert!((signed_volume(&mesh, &kept) / v0 - 1.0).abs() < 1e-9);
        assert!(rms_distance(&sphere, &kept) < rms_distance(&sphere, &shrunk));
        assert!(rms_distance(&sphere, &kept) < sphere.distance(sphere.center));
    }

    #[test]
    fn fixed_vertices_stay_and_zero_lambda_is_identity() {
        // An open grid of 3x3 quads: only the centre 4 vertices move.
        let positions: Vec<DVec3> = (0..16)
            .map(|v| DVec3::new((v % 4) as f64, (v / 4) as f64, ((v * 7) % 3) as f64))
            .collect();
        let faces: Vec<[u32; 4]> = (0..9)
            .map(|q| {
                let (i, j) = (q % 3, q / 3);
                let v = j * 4 + i;
                [v, v + 1, v + 5, v + 4]
            })
            .collect();
        let mesh = Mesh::from_polygons(positions.clone(), &faces).unwrap();
        let topo = Topology::build(&mesh);
        let movable = movable_mask(&topo, BoundaryRule::Fixed);
        assert_eq!(movable.iter().filter(|&&m| m).count(), 4);
        let no = AtomicBool::new(false);
        let out = laplacian_smooth(&topo, &movable, &positions, 7, 0.6, &no).unwrap();
        for v in 0..16 {
            assert_eq!(out[v] == positions[v], !movable[v], "vertex {v}");
        }
        // Open mesh: the volume constraint does nothing.
        let same =
            laplacian_smooth_preserving_volume(&mesh, &topo, &movable, &positions, 7, 0.6, &no)
                .unwrap();
        assert_eq!(same, out);
        assert_eq!(
            laplacian_smooth(&topo, &movable, &positions, 7, 0.0, &no).unwrap(),
            positions
        );
    }

    #[test]
    fn one_step_is_the_umbrella_formula_and_cancel_stops() {
        let (_, mesh) = voxel_sphere(4.0);
        let topo = Topology::build(&mesh);
        let movable = movable_mask(&topo, BoundaryRule::Fixed);
        let p = mesh.positions();
        let no = AtomicBool::new(false);
        let out = laplacian_smooth(&topo, &movable, p, 1, 0.25, &no).unwrap();
        for v in 0..p.len() {
            let nb = topo.neighbors(v);
            let c = nb.iter().map(|&j| p[j as usize]).sum::<DVec3>() / nb.len() as f64;
            let expected = if movable[v] {
                p[v] + 0.25 * (c - p[v])
            } else {
                p[v]
            };
            assert!(out[v].distance(expected) < 1e-12);
        }
        let yes = AtomicBool::new(true);
        assert_eq!(
            laplacian_smooth(&topo, &movable, p, 3, 0.5, &yes),
            Err(Cancelled)
        );
        assert_eq!(
            laplacian_smooth(&topo, &movable, p, 0, 0.5, &yes).unwrap(),
            p
        );
    }

    /// Best RMS distance to the true surface that each baseline reaches at
    /// any iteration count in 1..=200 (default λ = 0.5, μ = -0.53):
    /// `cargo test --release -p meshsmooth-core -- --ignored baselines --nocapture`.
    #[test]
    #[ignore]
    fn baselines_best_rms() {
        use crate::shapes::{mc_ellipsoid, mc_sphere, mc_torus, voxel_ellipsoid, voxel_torus};
        let p = crate::params::BaselineParams::default();
        let cases: Vec<(&str, Box<dyn Shape>, Mesh)> = vec![
            boxed("voxel sphere r=12", voxel_sphere(12.0)),
            boxed("voxel sphere r=40", voxel_sphere(40.0)),
            boxed("voxel torus 20/8", voxel_torus(20.0, 8.0)),
            boxed(
                "voxel ellipsoid 30/20/12",
                voxel_ellipsoid(30.0, 20.0, 12.0),
            ),
            boxed("mc sphere r=12", mc_sphere(12.0)),
            boxed("mc sphere r=40", mc_sphere(40.0)),
            boxed("mc torus 20/8", mc_torus(20.0, 8.0)),
            boxed("mc ellipsoid 30/20/12", mc_ellipsoid(30.0, 20.0, 12.0)),
        ];
        for (name, shape, mesh) in cases {
            let topo = Topology::build(&mesh);
            let movable = movable_mask(&topo, BoundaryRule::Fixed);
            let v0 = mesh.signed_volume();
            let input = rms_distance(shape.as_ref(), mesh.positions());
            let mut line = format!("{name:<26} input {input:.4}");
            for method in ["laplacian", "laplacian+volume", "taubin"] {
                let mut cur = mesh.positions().to_vec();
                let mut next = cur.clone();
                let mut best = (f64::INFINITY, 0, 0.0);
                for it in 1..=200 {
                    umbrella_step(&topo, &movable, p.lambda, &cur, &mut next);
                    std::mem::swap(&mut cur, &mut next);
                    match method {
                        "taubin" => {
                            umbrella_step(&topo, &movable, p.mu, &cur, &mut next);
                            std::mem::swap(&mut cur, &mut next);
                        }
                        "laplacian+volume" => {
                            rescale_to_volume(&mesh, &mut cur, v0);
                        }
                        _ => {}
                    }
                    let rms = rms_distance(shape.as_ref(), &cur);
                    if rms < best.0 {
                        best = (rms, it, signed_volume(&mesh, &cur) / v0 - 1.0);
                    }
                }
                line += &format!(
                    " | {method} {:.4} @{} (dV {:+.2}%)",
                    best.0,
                    best.1,
                    100.0 * best.2
                );
            }
            println!("{line}");
        }
    }

    fn boxed<S: Shape + 'static>(name: &str, (s, m): (S, Mesh)) -> (&str, Box<dyn Shape>, Mesh) {
        (name, Box::new(s), m)
    }
}
