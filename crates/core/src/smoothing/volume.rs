//! Volume restoration: an offset along the vertex normals that brings each
//! closed part of a mesh back to the volume it enclosed in the input.
//!
//! Quadric projection does not shrink a surface the way Laplacian smoothing
//! does, but it is not exactly volume-neutral either: large fits on curved
//! regions bias away from the centre of curvature (the sphere/paraboloid
//! mismatch grows like `rho^4 / R^3`) and flattened voxel plateaus bias
//! inward. A uniform offset removes the mean of that bias without touching
//! the shape.
//!
//! The bias follows the sign of the curvature: it inflates convex surfaces
//! and deflates concave ones. A closed surface that bounds a cavity (the
//! inner surface of a shell, a vessel wall or a cyst in an organ; a
//! connected component of negative signed volume) is mostly concave, so its
//! bias shrinks the solid while the outer surface's grows it: their volume
//! changes cancel, and one offset for the whole mesh would leave both where
//! the bias put them. The solids and the cavities are therefore restored by
//! an offset each ([`VolumeParts`]). Solids share one offset: a small solid
//! that lost much of its volume (a fragment one voxel thick, whose mask
//! overstates it) is not inflated back on its own.

use crate::fit::normals::vertex_normals;
use crate::mesh::{Mesh, Topology};
use glam::DVec3;
use rayon::prelude::*;

/// The parts whose volumes are restored one by one, each with one offset:
/// the connected components of positive signed volume in the input (solids)
/// and those of negative volume (the surfaces of cavities), with the signed
/// volume each part enclosed in the input.
#[derive(Debug, Clone)]
pub struct VolumeParts {
    /// Each vertex's part.
    part_of: Vec<u32>,
    /// Each part's signed volume at the input positions.
    targets: Vec<f64>,
}

/// What [`restore_volume`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Restored {
    /// The offsets applied, weighted by their parts' areas: 0 when no part
    /// moved.
    pub mean_offset: f64,
    /// The signed volume change the parts left as they were still hold,
    /// relative to the magnitude of the whole input's volume.
    pub left: f64,
}

impl VolumeParts {
    /// The solids and the cavities of `mesh` and their input volumes.
    pub fn new(mesh: &Mesh, topo: &Topology) -> Self {
        let (component, count) = topo.component_ids();
        let components = VolumeParts {
            part_of: component,
            targets: Vec::new(),
        };
        let volumes = components.volumes(mesh, mesh.positions(), count);
        let cavity: Vec<bool> = volumes.iter().map(|&v| v < 0.0).collect();
        let two = cavity.iter().any(|&c| c) && cavity.iter().any(|&c| !c);
        let part_of: Vec<u32> = components
            .part_of
            .iter()
            .map(|&c| u32::from(two && cavity[c as usize]))
            .collect();
        let mut parts = VolumeParts {
            part_of,
            targets: Vec::new(),
        };
        parts.targets = parts.volumes(mesh, mesh.positions(), 1 + usize::from(two));
        parts
    }

    /// The input volume of the whole mesh.
    fn total_target(&self) -> f64 {
        self.targets.iter().sum()
    }

    /// Each part's signed volume at `positions` (a face belongs to its first
    /// corner's part). The faces' volumes are computed in parallel and
    /// summed in face order: the same bits whatever the thread count.
    fn volumes(&self, mesh: &Mesh, positions: &[DVec3], count: usize) -> Vec<f64> {
        let per_face: Vec<f64> = (0..mesh.num_faces())
            .into_par_iter()
            .with_min_len(4096)
            .map(|f| face_volume(mesh.face(f), positions))
            .collect();
        self.sum_by_part(mesh, &per_face, count)
    }

    /// Each part's sum of a per-face value.
    fn sum_by_part(&self, mesh: &Mesh, per_face: &[f64], count: usize) -> Vec<f64> {
        let mut sums = vec![0.0; count];
        for (f, &x) in per_face.iter().enumerate() {
            if let Some(&first) = mesh.face(f).first() {
                sums[self.part_of[first as usize] as usize] += x;
            }
        }
        sums
    }
}

/// Signed volume of the cone from the origin over one face (fanned from its
/// first corner), as [`crate::mesh::signed_volume`] sums it.
fn face_volume(face: &[u32], positions: &[DVec3]) -> f64 {
    let Some(&first) = face.first() else {
        return 0.0;
    };
    let o = positions[first as usize];
    let mut v = 0.0;
    for j in 1..face.len().saturating_sub(1) {
        let a = positions[face[j] as usize];
        let b = positions[face[j + 1] as usize];
        v += o.dot(a.cross(b));
    }
    v / 6.0
}

/// Moves every movable vertex of part `p` by `delta_p * n_i`, solving for
/// each part's `delta_p` with a few secant steps so its signed volume equals
/// its input volume ([`VolumeParts`]). A part stays where it is when it has
/// no area, its volumes do not share a sign, or the offset it needs exceeds
/// `max_offset` or does not converge: the restoration corrects a small
/// smoothing bias, it never inflates a surface that is not a consistently
/// oriented closed one. Nothing moves when `accept` rejects the moved
/// positions.
pub fn restore_volume(
    mesh: &Mesh,
    topo: &Topology,
    parts: &VolumeParts,
    positions: &mut [DVec3],
    movable: &[bool],
    max_offset: f64,
    accept: impl Fn(&[DVec3]) -> bool,
) -> Restored {
    let count = parts.targets.len();
    let normals = vertex_normals(mesh, topo, positions);
    let base: Vec<DVec3> = positions.to_vec();
    let face_area: Vec<f64> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| mesh.face_vector_area(f).length())
        .collect();
    let area = parts.sum_by_part(mesh, &face_area, count);
    drop(face_area);
    let current = parts.volumes(mesh, positions, count);
    let targets = &parts.targets;
    let close = |v: f64, t: f64, tol: f64| (v - t).abs() <= tol * t.abs();
    // Parts to solve for: closed-looking, with area, not yet at their volume.
    let solving: Vec<bool> = (0..count)
        .map(|p| {
            area[p] > 0.0 && targets[p] * current[p] > 0.0 && !close(current[p], targets[p], 1e-12)
        })
        .collect();
    let apply = |delta: &[f64], out: &mut [DVec3]| {
        out.par_iter_mut()
            .with_min_len(4096)
            .enumerate()
            .for_each(|(v, o)| {
                let d = delta[parts.part_of[v] as usize];
                *o = if movable[v] {
                    base[v] + d * normals[v]
                } else {
                    base[v]
                };
            });
    };
    // V_p(delta) is nearly linear with slope = the part's area; refine by
    // secant, all parts at once.
    let (mut d0, mut v0) = (vec![0.0; count], current.clone());
    let mut d1: Vec<f64> = (0..count)
        .map(|p| {
            if solving[p] {
                (targets[p] - current[p]) / area[p]
            } else {
                0.0
            }
        })
        .collect();
    apply(&d1, positions);
    let mut v1 = parts.volumes(mesh, positions, count);
    for _ in 0..4 {
        let mut stepped = false;
        for p in (0..count).filter(|&p| solving[p]) {
            if close(v1[p], targets[p], 1e-12) || v1[p] == v0[p] {
                continue;
            }
            let d2 = d1[p] + (targets[p] - v1[p]) * (d1[p] - d0[p]) / (v1[p] - v0[p]);
            (d0[p], v0[p]) = (d1[p], v1[p]);
            d1[p] = d2;
            stepped = true;
        }
        if !stepped {
            break;
        }
        apply(&d1, positions);
        v1 = parts.volumes(mesh, positions, count);
    }
    // Parts whose offset is out of bounds or did not converge stay.
    let kept: Vec<bool> = (0..count)
        .map(|p| {
            solving[p]
                && d1[p].is_finite()
                && d1[p].abs() <= max_offset
                && close(v1[p], targets[p], 1e-6)
        })
        .collect();
    let delta: Vec<f64> = (0..count)
        .map(|p| if kept[p] { d1[p] } else { 0.0 })
        .collect();
    if kept.iter().any(|&k| k) {
        apply(&delta, positions);
    } else {
        positions.copy_from_slice(&base);
    }
    let unrestored = |vols: &[f64]| -> f64 {
        let left: f64 = (0..count)
            .filter(|&p| !kept[p])
            .map(|p| vols[p] - targets[p])
            .sum();
        left / parts.total_target().abs().max(f64::MIN_POSITIVE)
    };
    if !kept.iter().any(|&k| k) || !accept(positions) {
        positions.copy_from_slice(&base);
        return Restored {
            mean_offset: 0.0,
            left: (current.iter().sum::<f64>() - parts.total_target())
                / parts.total_target().abs().max(f64::MIN_POSITIVE),
        };
    }
    let moved_area: f64 = (0..count).filter(|&p| kept[p]).map(|p| area[p]).sum();
    let mean_offset = (0..count)
        .filter(|&p| kept[p])
        .map(|p| delta[p] * area[p])
        .sum::<f64>()
        / moved_area;
    Restored {
        mean_offset,
        left: unrestored(&current),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Topology, signed_volume};
    use crate::shapes::{self, voxel_sphere};

    #[test]
    fn restores_the_volume_unless_the_result_is_rejected() {
        let (_, mesh) = voxel_sphere(6.0);
        let topo = Topology::build(&mesh);
        let parts = VolumeParts::new(&mesh, &topo);
        let movable = vec![true; mesh.num_vertices()];
        let target = mesh.signed_volume();
        // Shrink by 1% along the radius: about 3% of the volume.
        let c = mesh.positions().iter().sum::<DVec3>() / mesh.num_vertices() as f64;
        let shrunk: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|&p| c + 0.99 * (p - c))
            .collect();

        let mut p = shrunk.clone();
        let refused = restore_volume(&mesh, &topo, &parts, &mut p, &movable, 1.0, |_| false);
        assert_eq!(refused.mean_offset, 0.0);
        assert!(refused.left < -0.02, "{refused:?}");
        assert_eq!(p, shrunk, "a rejected offset leaves every vertex in place");

        let done = restore_volume(&mesh, &topo, &parts, &mut p, &movable, 1.0, |_| true);
        assert!(done.mean_offset > 0.0);
        assert_eq!(done.left, 0.0);
        let v = signed_volume(&mesh, &p);
        assert!((v - target).abs() <= 1e-6 * target, "{v} vs {target}");

        // An offset beyond the bound is refused.
        let mut q = shrunk.clone();
        let refused = restore_volume(&mesh, &topo, &parts, &mut q, &movable, 1e-3, |_| true);
        assert_eq!(refused.mean_offset, 0.0);
        assert_eq!(q, shrunk);
    }

    #[test]
    fn each_surface_of_a_shell_gets_its_own_volume_back() {
        // Both surfaces of a shell pushed away from its centre: the outer
        // one encloses more, the inner one's hole encloses less, and the
        // whole volume barely changes, so one offset for the whole mesh
        // would leave both where they are.
        let shell = shapes::shell(8.0, 2.0);
        let mesh = shapes::voxel_boundary_mesh(&shapes::voxel_mask(&shell));
        let topo = Topology::build(&mesh);
        let parts = VolumeParts::new(&mesh, &topo);
        assert_eq!(parts.targets.len(), 2, "outer and inner surface");
        assert!(parts.targets[0] > 0.0 && parts.targets[1] < 0.0);
        let c = mesh.positions().iter().sum::<DVec3>() / mesh.num_vertices() as f64;
        let mut p: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|&x| x + 0.1 * (x - c).normalize())
            .collect();
        let count = parts.targets.len();
        let before = parts.volumes(&mesh, &p, count);
        for (b, t) in before.iter().zip(&parts.targets) {
            assert!((b - t).abs() > 0.01 * t.abs(), "{b} vs {t}");
        }
        let movable = vec![true; mesh.num_vertices()];
        let done = restore_volume(&mesh, &topo, &parts, &mut p, &movable, 1.0, |_| true);
        assert_eq!(done.left, 0.0);
        let after = parts.volumes(&mesh, &p, count);
        for (a, t) in after.iter().zip(&parts.targets) {
            assert!((a - t).abs() <= 1e-6 * t.abs(), "{a} vs {t}");
        }
        // Both surfaces went back towards the centre.
        let radius = |q: &[DVec3], outer: bool| {
            let r: Vec<f64> = q
                .iter()
                .zip(mesh.positions())
                .filter(|(_, x)| ((**x - c).length() > 7.0) == outer)
                .map(|(y, _)| (*y - c).length())
                .collect();
            r.iter().sum::<f64>() / r.len() as f64
        };
        let pushed: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|&x| x + 0.1 * (x - c).normalize())
            .collect();
        for outer in [true, false] {
            let (was, now) = (radius(&pushed, outer), radius(&p, outer));
            assert!(now < was - 0.05, "outer {outer}: {now} vs {was}");
        }
    }
}
