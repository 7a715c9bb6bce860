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
//!
//! On a voxel lattice the input's polygons are the mask's voxel faces, so
//! its volume is the mask's, an unbiased estimate of the true volume; the
//! output's vertices sample a smooth surface, which bulges past the flat
//! faces between them wherever it is curved. Restoring the polygons' volume
//! would hold the vertices outside a convex surface and inside a concave
//! one by that bulge (about `e^2 / (8 r)` for edges `e` on a tube of radius
//! `r`: a twentieth of a voxel on a tube three voxels across). There the
//! restoration gives the smooth surface the input volume instead
//! ([`VolumeParts::for_voxel_lattice`], [`face_bulge`]), the polygons
//! keeping within [`BULGE_TOLERANCE`] of theirs.

use crate::fit::normals::vertex_normals;
use crate::mesh::{Mesh, Topology, VolumeApexes};
use glam::DVec3;
use rayon::prelude::*;

/// How far a part's polygon volume may end from its input volume when the
/// restoration gives the smooth surface through its vertices the input
/// volume ([`VolumeParts::for_voxel_lattice`]), as a fraction of the input
/// volume. The bulge is a few tenths of a percent on a voxel sphere or a
/// cortex mask but reaches 6% of a tube three voxels across, whose
/// polygons then enclose visibly less than its mask: a user who measures a
/// neurite's volume from the mesh reads the polygons, and the smoothing
/// promises them within 2% of the input's. Past this share the vertices
/// stay outside the smooth surface by the rest of the bulge.
pub const BULGE_TOLERANCE: f64 = 0.015;

/// A restoration offset larger than this fraction of the mean edge length
/// is no smoothing bias to undo. A part that needs more after the passes is
/// left as it is (the pipeline's first restoration), and a connected
/// component that would need more on its own has collapsed: a fragment or
/// a hole a voxel or two across, thinner than the fits and the relaxation
/// reach, whose mask overstates it (the truth of a feature sampled at its
/// peak is thinner than the voxel it lit). A collapsed component neither
/// takes an offset nor counts toward its part's target: counted, a few
/// collapsed holes would push every other cavity's surface out to make up
/// their volume. A rod two voxels across still comes back within it.
pub const MAX_VOLUME_OFFSET: f64 = 0.5;

/// The part of a vertex whose component collapsed ([`MAX_VOLUME_OFFSET`]):
/// in no part, never moved by the restoration.
const NO_PART: u32 = u32::MAX;

/// The parts whose volumes are restored one by one, each with one offset:
/// the connected components of positive signed volume in the input (solids)
/// and those of negative volume (the surfaces of cavities), with the signed
/// volume each part enclosed in the input.
#[derive(Debug, Clone)]
pub struct VolumeParts {
    /// Each vertex's part ([`NO_PART`] once its component collapsed).
    part_of: Vec<u32>,
    /// Each part's signed volume at the input positions.
    targets: Vec<f64>,
    /// Each vertex's connected component and the apexes every volume is
    /// taken from ([`VolumeApexes`]: each component's input centroid, so
    /// that a surface with edges of an odd number of faces is restored
    /// alike wherever its file puts the origin).
    apexes: VolumeApexes,
    /// Each component's signed volume at the input positions.
    component_volumes: Vec<f64>,
    /// The offset beyond which a component has collapsed
    /// ([`MAX_VOLUME_OFFSET`] of the input's mean edge length).
    collapse_offset: f64,
    /// Whether the smooth surface through the vertices, rather than their
    /// polygons, gets each part's input volume back (within
    /// [`BULGE_TOLERANCE`]).
    smooth_surface: bool,
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
    /// The signed volume change the collapsed components
    /// ([`MAX_VOLUME_OFFSET`]) hold, left as they are, relative to the
    /// magnitude of the whole input's volume.
    pub collapsed: f64,
    /// The change of the polygons' volume the restoration aimed at,
    /// relative to the magnitude of the whole input's volume: 0, but on a
    /// voxel lattice, where the smooth surface through the vertices gets
    /// the input volume ([`VolumeParts::for_voxel_lattice`]), and where
    /// components collapsed (`collapsed`, included).
    pub aimed: f64,
}

impl VolumeParts {
    /// The solids and the cavities of `mesh` and their input volumes; with
    /// `bodies` (one entry per vertex: a file whose bodies touch face to
    /// face, [`crate::io::FileBodies`]), each body's solids and its
    /// cavities, as they would be alone. `bodies` of another length count
    /// as one body.
    pub fn new(mesh: &Mesh, topo: &Topology, bodies: Option<&[u32]>) -> Self {
        let apexes = VolumeApexes::new(topo, mesh.positions());
        let (component, count) = (apexes.component(), apexes.count());
        let component_volumes = part_volumes(mesh, mesh.positions(), component, count, &apexes);
        let bodies = bodies.filter(|b| b.len() == component.len());
        let mut body_of = vec![0u32; count];
        if let Some(bodies) = bodies {
            // A component lies in one body: the body of any of its vertices.
            for (&c, &b) in component.iter().zip(bodies) {
                body_of[c as usize] = b;
            }
        }
        // One part per body and sign, numbered in that order.
        let key = |c: u32| (body_of[c as usize], component_volumes[c as usize] < 0.0);
        let mut keys: Vec<(u32, bool)> = (0..count as u32).map(key).collect();
        keys.sort_unstable();
        keys.dedup();
        let part_of: Vec<u32> = component
            .iter()
            .map(|&c| keys.binary_search(&key(c)).unwrap_or(0) as u32)
            .collect();
        let targets = part_volumes(mesh, mesh.positions(), &part_of, keys.len(), &apexes);
        VolumeParts {
            part_of,
            targets,
            apexes,
            component_volumes,
            collapse_offset: MAX_VOLUME_OFFSET * mesh.mean_edge_length(),
            smooth_surface: false,
        }
    }

    /// These parts less the components that have collapsed at `positions`
    /// (whose volume change over their area there exceeds the collapse
    /// offset, or whose volume changed sign), with their parts' targets
    /// reduced by the collapsed components' input volumes, and the signed
    /// volume change the collapsed components hold; `None` when none
    /// collapsed.
    fn without_collapsed(&self, mesh: &Mesh, positions: &[DVec3]) -> Option<(VolumeParts, f64)> {
        let count = self.component_volumes.len();
        let component = self.apexes.component();
        let now = part_volumes(mesh, positions, component, count, &self.apexes);
        let face_area: Vec<f64> = (0..mesh.num_faces())
            .into_par_iter()
            .with_min_len(4096)
            .map(|f| crate::mesh::vector_area(mesh.face(f), positions).length())
            .collect();
        let area = sum_by_part(mesh, component, &face_area, count);
        let collapsed: Vec<bool> = (0..count)
            .map(|c| {
                let (input, v) = (self.component_volumes[c], now[c]);
                v / input <= 0.0 || (input - v).abs() > self.collapse_offset * area[c]
            })
            .collect();
        if !collapsed.iter().any(|&c| c) {
            return None;
        }
        let change: f64 = (0..now.len())
            .filter(|&c| collapsed[c])
            .map(|c| now[c] - self.component_volumes[c])
            .sum();
        let mut settled = self.clone();
        for (v, part) in settled.part_of.iter_mut().enumerate() {
            if collapsed[component[v] as usize] {
                *part = NO_PART;
            }
        }
        settled.targets = part_volumes(
            mesh,
            mesh.positions(),
            &settled.part_of,
            self.targets.len(),
            &self.apexes,
        );
        Some((settled, change))
    }

    /// The parts of a voxel-boundary mesh, whose flat input faces enclose
    /// the mask's volume: the restoration gives that volume to the smooth
    /// surface through the output's vertices (module docs).
    pub fn for_voxel_lattice(mesh: &Mesh, topo: &Topology, bodies: Option<&[u32]>) -> Self {
        VolumeParts {
            smooth_surface: true,
            ..VolumeParts::new(mesh, topo, bodies)
        }
    }

    /// The input volume of the whole mesh, in magnitude (at least the
    /// smallest positive number, to divide by).
    fn total_target(&self) -> f64 {
        self.targets
            .iter()
            .sum::<f64>()
            .abs()
            .max(f64::MIN_POSITIVE)
    }

    /// Each part's signed volume at `positions`.
    fn volumes(&self, mesh: &Mesh, positions: &[DVec3]) -> Vec<f64> {
        part_volumes(
            mesh,
            positions,
            &self.part_of,
            self.targets.len(),
            &self.apexes,
        )
    }

    /// The apexes every volume of these parts is taken from, for a caller
    /// that measures the whole mesh's volume the same way.
    pub fn apexes(&self) -> &VolumeApexes {
        &self.apexes
    }
}

/// The signed volume at `positions` of each of `count` parts, vertex `v` in
/// part `part_of[v]` (a face belongs to its first corner's part; faces of
/// [`NO_PART`] count nowhere), each face's cone taken from its `apexes`.
/// The faces' volumes are computed in parallel and summed in face order:
/// the same bits whatever the thread count.
fn part_volumes(
    mesh: &Mesh,
    positions: &[DVec3],
    part_of: &[u32],
    count: usize,
    apexes: &VolumeApexes,
) -> Vec<f64> {
    let per_face: Vec<f64> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| apexes.cone_volume6(mesh.face(f), positions) / 6.0)
        .collect();
    sum_by_part(mesh, part_of, &per_face, count)
}

/// The volume by which the smooth surface through a face's corners
/// exceeds the face (its bulge): a surface of Hessian `H` over a face lies
/// `-(1/2) sum_{i<j} l_i l_j e_ij.H e_ij` off the plane through its
/// corners (barycentric `l`), and a face's barycentric products average
/// `1/12`, so the mean gap over the face is `(1/24) sum_e kappa_e |e|^2`
/// over its edges, `kappa_e |e|^2 = (n_j - n_i).(x_j - x_i)` with the unit
/// vertex normals `n`. Positive where the surface is convex (outward
/// normals diverge), negative where concave; a quad's bilinear patch gives
/// the same sum over its four edges.
fn face_bulge(face: &[u32], positions: &[DVec3], normals: &[DVec3]) -> f64 {
    let area = crate::mesh::vector_area(face, positions).length();
    let k = face.len();
    let turn: f64 = (0..k)
        .map(|i| {
            let (a, b) = (face[i] as usize, face[(i + 1) % k] as usize);
            (normals[b] - normals[a]).dot(positions[b] - positions[a])
        })
        .sum();
    area * turn / 24.0
}

/// Each of `count` parts' sum of a per-face value ([`part_volumes`]).
fn sum_by_part(mesh: &Mesh, part_of: &[u32], per_face: &[f64], count: usize) -> Vec<f64> {
    let mut sums = vec![0.0; count];
    for (f, &x) in per_face.iter().enumerate() {
        if let Some(&first) = mesh.face(f).first()
            && let Some(sum) = sums.get_mut(part_of[first as usize] as usize)
        {
            *sum += x;
        }
    }
    sums
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
    let face_area: Vec<f64> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| mesh.face_vector_area(f).length())
        .collect();
    let whole = parts.total_target();
    let settled = parts.without_collapsed(mesh, positions);
    let collapsed = settled.as_ref().map_or(0.0, |s| s.1 / whole);
    let parts = settled.as_ref().map_or(parts, |s| &s.0);
    let count = parts.targets.len();
    let normals = vertex_normals(mesh, topo, positions);
    let base: Vec<DVec3> = positions.to_vec();
    let area = sum_by_part(mesh, &parts.part_of, &face_area, count);
    drop(face_area);
    let current = parts.volumes(mesh, positions);
    let targets = &restoration_targets(mesh, parts, positions, &normals);
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
                let d = delta.get(parts.part_of[v] as usize).copied().unwrap_or(0.0);
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
    let mut v1 = parts.volumes(mesh, positions);
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
        v1 = parts.volumes(mesh, positions);
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
    // The change the parts in `left` still hold, relative to the whole.
    let left_in = |left: &dyn Fn(usize) -> bool| -> f64 {
        let change: f64 = (0..count)
            .filter(|&p| left(p))
            .map(|p| current[p] - targets[p])
            .sum();
        change / whole
    };
    let aimed =
        (targets.iter().sum::<f64>() - parts.targets.iter().sum::<f64>()) / whole + collapsed;
    let delta: Vec<f64> = (0..count)
        .map(|p| if kept[p] { d1[p] } else { 0.0 })
        .collect();
    let any = kept.iter().any(|&k| k);
    if any {
        apply(&delta, positions);
    }
    if !any || !accept(positions) {
        positions.copy_from_slice(&base);
        return Restored {
            mean_offset: 0.0,
            left: left_in(&|_| true),
            collapsed,
            aimed,
        };
    }
    let moved_area: f64 = (0..count).filter(|&p| kept[p]).map(|p| area[p]).sum();
    let mean_offset = (0..count).map(|p| delta[p] * area[p]).sum::<f64>() / moved_area;
    Restored {
        mean_offset,
        left: left_in(&|p| !kept[p]),
        collapsed,
        aimed,
    }
}

/// Each part's polygon volume to restore: its input volume, less on a voxel
/// lattice the bulge of the smooth surface through `positions` (kept within
/// [`BULGE_TOLERANCE`] of the input volume). The bulge barely changes under
/// the restoration's offset (the edges' turning grows by the offset times
/// the normals' squared differences), so it is taken once, before.
fn restoration_targets(
    mesh: &Mesh,
    parts: &VolumeParts,
    positions: &[DVec3],
    normals: &[DVec3],
) -> Vec<f64> {
    if !parts.smooth_surface {
        return parts.targets.clone();
    }
    let per_face: Vec<f64> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| face_bulge(mesh.face(f), positions, normals))
        .collect();
    let bulge = sum_by_part(mesh, &parts.part_of, &per_face, parts.targets.len());
    parts
        .targets
        .iter()
        .zip(bulge)
        .map(|(&t, b)| {
            let room = BULGE_TOLERANCE * t.abs();
            t - b.clamp(-room, room)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Topology, signed_volume, test_walled_sphere};
    use crate::shapes::{self, voxel_sphere};

    #[test]
    fn a_walled_surface_is_restored_alike_wherever_the_origin_lies() {
        // A voxel sphere with a wall across it, whose rim edges three faces
        // share (as at a neuron's junctions): its faces enclose no volume
        // independent of the cones' apex, and the restoration of the same
        // shrink must not depend on where the origin lies.
        let run = |shift: DVec3| {
            let mesh = test_walled_sphere(6.0, shift);
            let topo = Topology::build(&mesh);
            let parts = VolumeParts::new(&mesh, &topo, None);
            let c = mesh.positions().iter().sum::<DVec3>() / mesh.num_vertices() as f64;
            let mut p: Vec<DVec3> = mesh
                .positions()
                .iter()
                .map(|&p| c + 0.99 * (p - c))
                .collect();
            let movable = vec![true; p.len()];
            let done = restore_volume(&mesh, &topo, &parts, &mut p, &movable, 1.0, |_| true);
            (
                done.mean_offset,
                p.iter().map(|&q| q - shift).collect::<Vec<_>>(),
            )
        };
        let (here, at_home) = run(DVec3::ZERO);
        let (there, far) = run(DVec3::new(4000.0, -2500.0, 1200.0));
        assert!(here > 0.0, "{here}");
        assert!((here - there).abs() <= 1e-9 * here, "{here} vs {there}");
        let most = at_home
            .iter()
            .zip(&far)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0, f64::max);
        assert!(most < 1e-6, "{most}");
    }

    #[test]
    fn restores_the_volume_unless_the_result_is_rejected() {
        let (_, mesh) = voxel_sphere(6.0);
        let topo = Topology::build(&mesh);
        let parts = VolumeParts::new(&mesh, &topo, None);
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
    fn the_bulge_is_the_volume_between_the_faces_and_the_smooth_surface() {
        // A latitude-longitude sphere with its vertices on the sphere: its
        // faces enclose less than the ball by about their bulge.
        let (r, n) = (5.0, 12);
        let mut positions = vec![DVec3::new(0.0, 0.0, r), DVec3::new(0.0, 0.0, -r)];
        for i in 1..n {
            let theta = std::f64::consts::PI * i as f64 / n as f64;
            for j in 0..2 * n {
                let phi = std::f64::consts::PI * j as f64 / n as f64;
                positions.push(
                    r * DVec3::new(
                        theta.sin() * phi.cos(),
                        theta.sin() * phi.sin(),
                        theta.cos(),
                    ),
                );
            }
        }
        let at = |i: usize, j: usize| (2 + (i - 1) * 2 * n + j % (2 * n)) as u32;
        let mut faces: Vec<Vec<u32>> = Vec::new();
        for j in 0..2 * n {
            faces.push(vec![0, at(1, j), at(1, j + 1)]);
            faces.push(vec![1, at(n - 1, j + 1), at(n - 1, j)]);
            for i in 1..n - 1 {
                faces.push(vec![at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        let mesh = Mesh::from_polygons(positions, &faces).unwrap();
        let topo = Topology::build(&mesh);
        let normals = vertex_normals(&mesh, &topo, mesh.positions());
        let bulge: f64 = (0..mesh.num_faces())
            .map(|f| face_bulge(mesh.face(f), mesh.positions(), &normals))
            .sum();
        let ball = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        let polygons = mesh.signed_volume();
        assert!(bulge > 0.0);
        let (before, after) = ((ball - polygons).abs(), (ball - polygons - bulge).abs());
        assert!(after < 0.1 * before, "{before} -> {after}");

        // Restored as a voxel lattice's parts, the polygons aim at the
        // input volume less the bulge, within the tolerance.
        let parts = VolumeParts::for_voxel_lattice(&mesh, &topo, None);
        let targets = restoration_targets(&mesh, &parts, mesh.positions(), &normals);
        let room = BULGE_TOLERANCE * polygons;
        assert!((targets[0] - (polygons - bulge.min(room))).abs() < 1e-9 * polygons);
        let plain = VolumeParts::new(&mesh, &topo, None);
        let targets = restoration_targets(&mesh, &plain, mesh.positions(), &normals);
        assert_eq!(targets, plain.targets);
        assert!((targets[0] - polygons).abs() < 1e-9 * polygons);
    }

    #[test]
    fn a_collapsed_fragment_neither_moves_nor_inflates_the_rest() {
        // A ball and a small fragment far from it, both solids: the ball
        // shrunk a little (a fit's bias), the fragment to a tenth of its
        // volume (thinner than the smoothing's reach). One offset for both
        // would push the ball past its own volume to make up the
        // fragment's loss.
        let (_, ball) = voxel_sphere(6.0);
        let (_, bit) = voxel_sphere(1.5);
        let n = ball.num_vertices();
        let far = DVec3::new(40.0, 0.0, 0.0);
        let positions: Vec<DVec3> = ball
            .positions()
            .iter()
            .copied()
            .chain(bit.positions().iter().map(|&p| p + far))
            .collect();
        let faces: Vec<Vec<u32>> = ball
            .faces()
            .map(<[u32]>::to_vec)
            .chain(
                bit.faces()
                    .map(|f| f.iter().map(|&v| v + n as u32).collect()),
            )
            .collect();
        let mesh = Mesh::from_polygons(positions, &faces).unwrap();
        let topo = Topology::build(&mesh);
        let parts = VolumeParts::new(&mesh, &topo, None);
        assert_eq!(parts.targets.len(), 1, "two solids, one part");
        let ball_faces = &faces[..ball.num_faces()];
        let ball_volume = |q: &[DVec3]| {
            let m = Mesh::from_polygons(q[..n].to_vec(), ball_faces).unwrap();
            signed_volume(&m, m.positions())
        };
        let input_ball = ball_volume(mesh.positions());
        let mut p: Vec<DVec3> = mesh
            .positions()
            .iter()
            .enumerate()
            .map(|(v, &x)| {
                if v < n {
                    x * 0.99
                } else {
                    far + (x - far) * 0.1f64.cbrt()
                }
            })
            .collect();
        let shrunk = p.clone();
        let movable = vec![true; mesh.num_vertices()];
        let done = restore_volume(&mesh, &topo, &parts, &mut p, &movable, 1.0, |_| true);
        assert!(done.mean_offset > 0.0);
        let restored = ball_volume(&p);
        assert!(
            (restored - input_ball).abs() <= 1e-6 * input_ball,
            "the ball has {restored} of {input_ball}"
        );
        assert_eq!(p[n..], shrunk[n..], "the fragment stays as it collapsed");
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
        let parts = VolumeParts::new(&mesh, &topo, None);
        assert_eq!(parts.targets.len(), 2, "outer and inner surface");
        assert!(parts.targets[0] > 0.0 && parts.targets[1] < 0.0);
        let c = mesh.positions().iter().sum::<DVec3>() / mesh.num_vertices() as f64;
        let mut p: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|&x| x + 0.1 * (x - c).normalize())
            .collect();
        let before = parts.volumes(&mesh, &p);
        for (b, t) in before.iter().zip(&parts.targets) {
            assert!((b - t).abs() > 0.01 * t.abs(), "{b} vs {t}");
        }
        let movable = vec![true; mesh.num_vertices()];
        let done = restore_volume(&mesh, &topo, &parts, &mut p, &movable, 1.0, |_| true);
        assert_eq!(done.left, 0.0);
        let after = parts.volumes(&mesh, &p);
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
