//! The fidelity bound: how far a vertex may move from where the input put
//! it, so the smoothed surface stays true to the segmentation it came from.
//!
//! The paper (section 2.2-2.3) moves each vertex onto its fitted quadric
//! with no limit; on thin sheets, tubes and non-manifold contacts the fits
//! then pull vertices across the structure and faces fold. What a vertex's
//! input position says about the true surface decides the bound:
//! - A vertex of a voxel lattice (a voxel-boundary mesh: every edge at the
//!   vertex runs along one of the lattice's three axes) sits at a corner
//!   shared by eight voxels, some inside and some outside. The true surface
//!   separates those voxels' centres, which are the corners of the cube of
//!   half-width half a voxel around the vertex (its dual voxel): the true
//!   surface crosses that cube, so the vertex is held inside it, axis by
//!   axis in the lattice's frame.
//! - Any other vertex (marching cubes, molecular surfaces, neurons) is held
//!   within a ball around its input position.
//!
//! Both sizes are `max_displacement` times the vertex's mean input edge
//! length: 0.5 gives the dual voxel on a lattice, so no vertex of a voxel
//! mesh moves more than `sqrt(3) / 2` voxel.

use super::project::mean_edge_at;
use crate::mesh::lattice::{along_axis, lattice_frame};
use crate::mesh::{Mesh, Topology};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A run's fidelity bound, if any, with the input positions it holds the
/// vertices to and the vertices it has held back so far.
#[derive(Debug)]
pub struct Fidelity<'a> {
    bound: Option<(&'a FidelityBound, &'a [DVec3])>,
    /// Per vertex (when bounded): whether the bound has held it back;
    /// shared with the [`Fidelity::with_bound`]s made from this one.
    held: Arc<[AtomicBool]>,
}

impl<'a> Fidelity<'a> {
    /// Holds `input.len()` vertices to `bound` around `input`, or lets
    /// them move freely when `bound` is `None`.
    pub fn new(bound: Option<&'a FidelityBound>, input: &'a [DVec3]) -> Self {
        Fidelity {
            bound: bound.map(|b| (b, input)),
            held: if bound.is_some() {
                (0..input.len()).map(|_| AtomicBool::new(false)).collect()
            } else {
                Arc::new([])
            },
        }
    }

    /// The same input positions held to `bound` instead, recording into
    /// the same held-back vertices (the quality fixes' wider bound counts
    /// with the smoothing's); unbounded when either is.
    pub fn with_bound(&self, bound: Option<&'a FidelityBound>) -> Self {
        match (self.bound, bound) {
            (Some((_, input)), Some(b)) => Fidelity {
                bound: Some((b, input)),
                held: Arc::clone(&self.held),
            },
            _ => Fidelity {
                bound: None,
                held: Arc::new([]),
            },
        }
    }

    /// No bound: every vertex moves freely.
    #[cfg(test)]
    pub fn unbounded() -> Self {
        Fidelity {
            bound: None,
            held: Arc::new([]),
        }
    }

    /// Brings `positions` back within the bound (nothing when unbounded).
    pub fn apply(&self, positions: &mut [DVec3]) {
        if let Some((bound, input)) = self.bound {
            bound.clamp(input, positions, &self.held);
        }
    }

    /// Vertices held back at least once, by this bound or by another
    /// made from it with [`Fidelity::with_bound`].
    pub fn held_back(&self) -> u64 {
        self.held
            .iter()
            .filter(|h| h.load(Ordering::Relaxed))
            .count() as u64
    }
}

/// Relative slack of [`FidelityBound::allows`]: a vertex the clamp put on
/// its bound's surface is still allowed after rounding.
const ALLOW_SLACK: f64 = 1e-9;

/// Per-vertex bound on the distance from the input position, built once
/// from the input mesh.
#[derive(Debug, Clone)]
pub struct FidelityBound {
    /// The lattice's axes, when the mesh has one.
    frame: Option<[DVec3; 3]>,
    /// Per vertex: a box half-width (positive, lattice vertices) or a ball
    /// radius (negative, stored as its negation); 0 holds the vertex fixed.
    size: Arc<[f32]>,
}

impl FidelityBound {
    /// The bound for `mesh`'s input positions with sizes of
    /// `max_displacement` mean edge lengths (per vertex, its own edges).
    pub fn new(mesh: &Mesh, topo: &Topology, max_displacement: f64) -> Self {
        let p = mesh.positions();
        let frame = lattice_frame(topo, p);
        let size = (0..topo.num_vertices())
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| {
                let nb = topo.neighbors(v);
                if nb.is_empty() {
                    return 0.0;
                }
                let s = (max_displacement * mean_edge_at(topo, p, v)) as f32;
                let on_lattice = frame.is_some_and(|f| {
                    nb.iter()
                        .all(|&j| along_axis(&f, p[j as usize] - p[v]).is_some())
                });
                if on_lattice { s } else { -s }
            })
            .collect::<Vec<f32>>()
            .into();
        FidelityBound { frame, size }
    }

    /// The ball of `factor` times this bound's size at every vertex: the
    /// room the quality fixes get, which must be able to open a triangle
    /// that the box's walls flattened.
    pub fn widened(&self, factor: f64) -> Self {
        FidelityBound {
            frame: None,
            size: self
                .size
                .iter()
                .map(|&s| -(s.abs() * factor as f32))
                .collect::<Vec<f32>>()
                .into(),
        }
    }

    /// The same bound with every size times `factor`, in the same frame.
    pub fn scaled(&self, factor: f64) -> Self {
        FidelityBound {
            frame: self.frame,
            size: self
                .size
                .iter()
                .map(|&s| s * factor as f32)
                .collect::<Vec<f32>>()
                .into(),
        }
    }

    /// Whether position `p` of vertex `v` (input position `input`) is
    /// within the bound.
    pub fn allows(&self, v: usize, input: DVec3, p: DVec3) -> bool {
        let Some(&s) = self.size.get(v) else {
            return true;
        };
        let d = p - input;
        match self.frame {
            Some(f) if s > 0.0 => {
                let h = f64::from(s) * (1.0 + ALLOW_SLACK);
                f.iter().all(|a| a.dot(d).abs() <= h)
            }
            _ => d.length() <= f64::from(s).abs() * (1.0 + ALLOW_SLACK),
        }
    }

    /// The lattice's axes (the standard axes when the mesh has none) and
    /// the per-vertex sizes in them: a box half-width along each axis
    /// (positive), a ball radius (negative, stored as its negation), or 0
    /// for a vertex held fixed. For solvers that iterate in the lattice's
    /// frame, where a box is a clamp per coordinate.
    pub fn in_frame(&self) -> ([DVec3; 3], &[f32]) {
        (
            self.frame.unwrap_or([DVec3::X, DVec3::Y, DVec3::Z]),
            &self.size,
        )
    }

    /// Whether the mesh was recognised as a voxel lattice.
    pub fn has_lattice(&self) -> bool {
        self.frame.is_some()
    }

    /// Brings every vertex of `positions` back within its bound around
    /// `input` (the same vertex's input position) and marks in `held` the
    /// vertices it moved. Deterministic and parallel per vertex.
    fn clamp(&self, input: &[DVec3], positions: &mut [DVec3], held: &[AtomicBool]) {
        let frame = self.frame.unwrap_or([DVec3::X, DVec3::Y, DVec3::Z]);
        positions
            .par_iter_mut()
            .zip(input)
            .zip(&self.size[..])
            .zip(held)
            .with_min_len(4096)
            .for_each(|(((p, &o), &s), held)| {
                let d = *p - o;
                let bounded = if s > 0.0 {
                    let h = f64::from(s);
                    let local = DVec3::new(d.dot(frame[0]), d.dot(frame[1]), d.dot(frame[2]));
                    let c = local.clamp(DVec3::splat(-h), DVec3::splat(h));
                    if c == local {
                        return;
                    }
                    c.x * frame[0] + c.y * frame[1] + c.z * frame[2]
                } else {
                    let r = -f64::from(s);
                    let len = d.length();
                    if len <= r {
                        return;
                    }
                    d * (r / len)
                };
                *p = o + bounded;
                held.store(true, Ordering::Relaxed);
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn voxel_meshes_get_the_dual_voxel_and_others_a_ball() {
        let (_, voxel) = shapes::voxel_sphere(6.0);
        let topo = Topology::build(&voxel);
        let bound = FidelityBound::new(&voxel, &topo, 0.5);
        assert!(bound.has_lattice());
        assert!(bound.size.iter().all(|&s| (s - 0.5).abs() < 1e-6));

        let (_, mc) = shapes::mc_sphere(6.0);
        let topo = Topology::build(&mc);
        let bound = FidelityBound::new(&mc, &topo, 0.5);
        assert!(!bound.has_lattice());
        assert!(bound.size.iter().all(|&s| s < 0.0));
    }

    #[test]
    fn a_rotated_lattice_is_found_and_clamped_in_its_own_frame() {
        let (_, voxel) = shapes::voxel_sphere(5.0);
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        let mut mesh = voxel.clone();
        for p in mesh.positions_mut() {
            *p = rot * *p;
        }
        let topo = Topology::build(&mesh);
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        assert!(bound.has_lattice());
        // A move of 0.4 voxel along two lattice axes is inside the dual
        // voxel (0.57 from the corner); 0.7 along one is not.
        let input = mesh.positions();
        let mut p = input.to_vec();
        p[0] += rot * DVec3::new(0.4, -0.4, 0.0);
        p[1] += rot * DVec3::new(0.0, 0.0, 0.7);
        let fidelity = Fidelity::new(Some(&bound), input);
        fidelity.apply(&mut p);
        assert_eq!(fidelity.held_back(), 1);
        assert!(!fidelity.held[0].load(Ordering::Relaxed));
        assert!((p[0].distance(input[0]) - 0.4 * 2f64.sqrt()).abs() < 1e-9);
        assert!((p[1].distance(input[1]) - 0.5).abs() < 1e-6);
    }
}
