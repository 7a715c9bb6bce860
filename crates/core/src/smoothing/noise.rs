//! The input's noise, for a mesh cut from no grid: how far the smoothing may
//! move a vertex across the surface the input already describes.
//!
//! A voxel or marching-cubes mesh of a mask says where its surface is only to
//! within the voxel its corners or edge midpoints came from, and the fidelity
//! bound gives each vertex that voxel ([`super::fidelity`]). A mesh of no
//! grid (the marching cubes of a probability map, a blurred or decimated
//! mask's mesh, a molecular surface, a neuron) carries no such scale: its
//! vertices may already lie on a smooth surface, or carry scanner noise. The
//! paper's passes (section 2.3) treat both alike, and on a smooth surface
//! whose folds are two or three edges across their fits flatten the folds
//! by as much as the ball of the bound lets them.
//!
//! The input says how rough it is. Each interior vertex's height above the
//! surface fitted to its 2-ring (the vertex itself left out, as the passes'
//! fits do, [`crate::fit::quadric_fit`]) is its surface's failure to
//! predict it: noise, plus shape at the scale of an edge that the fit
//! cannot follow. The fit that predicts is the quadric with its cubic terms
//! ([`FitModel::Cubic`]): across a fold two or three edges wide the
//! curvature changes sign within a 2-ring, which a quadric's prediction
//! would count as noise of a tenth of an edge on a clean fold, and the
//! cubic terms take up. Their median over the mesh, in mean edge lengths,
//! is the mesh's noise estimate; where the vertices carry independent noise
//! of standard deviation `sigma` along the normal, it is about `0.85 sigma`
//! (the median of a normal deviate's absolute value, `0.674 sigma`, times
//! the spread the fit's own prediction error adds, which ten coefficients
//! widen more than six). A vertex may then move across its input surface
//! by [`Params::noise_bound`] times that estimate (times its own mean edge):
//! the default 2 is 1.7 standard deviations of such noise, which lets the
//! passes take out all but the noise's tails and keeps them from reshaping
//! the surface beneath it: on a real map's mesh a move farther across is
//! mostly the fits flattening a fold two or three edges across. Along the
//! surface the ball of the bound still decides, and "across" is measured
//! from the input's own quadric through the input position (the quadric
//! alone: its curvature at the vertex, without the cubic terms' tilt away
//! from it), so a move along a curved surface is not a move across it.
//!
//! [`Params::noise_bound`]: crate::Params::noise_bound

use crate::fit::frame::Frame;
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::fit::quadric_fit::{Facing, FitKind, FitModel, fit_neighbours};
use crate::mesh::{Mesh, Topology, VertexKind};
use crate::smoothing::neighbourhood::with_walker;
use crate::smoothing::project::mean_edge_at;
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// The rings of a vertex whose fit predicts it: the fewest that give a
/// quadric's six coefficients more points than unknowns on a regular mesh
/// (a triangle mesh's 2-ring has 18 vertices, enough for the cubic's ten;
/// a quad mesh's 12, where the quadric predicts alone); where fewer face
/// the vertex, the fit falls back to a plane and the vertex keeps the ball
/// alone.
pub const NOISE_RING: usize = 2;

/// Fewest fitted vertices that give a noise estimate: the median of fewer
/// is too uncertain to bound anything by (its standard error is about
/// `1.25 / sqrt(n)` of it), and a mesh that small keeps the ball alone.
pub const MIN_NOISE_FITS: usize = 32;

/// Halvings that find how much of a move stays within the ball in
/// [`SurfaceSlab::clamp_within`]: to a millionth of a millionth of it.
const BALL_BISECTIONS: u32 = 40;

/// A curved slab about a vertex's input surface: the points whose height
/// above the input's quadric through the input position, `h(x, y) = a x^2
/// + b x y + c y^2 + e x + f y` in the frame of the input normal, is at
/// most `half_width` either way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSlab {
    normal: Vec3,
    coeffs: [f32; 5],
    half_width: f32,
}

impl SurfaceSlab {
    /// The frame the slab is measured in, at the input position (origin 0:
    /// offsets from it).
    fn frame(&self) -> Frame {
        Frame::new(DVec3::ZERO, self.normal.as_dvec3())
    }

    /// How far offset `d` from the input position lies above the input's
    /// surface, with the slab's frame and the offset in it.
    fn height_above(&self, d: DVec3) -> (Frame, DVec3, f64) {
        let frame = self.frame();
        let l = frame.to_local(d);
        let [a, b, c, e, f] = self.coeffs.map(f64::from);
        let surface = a * l.x * l.x + b * l.x * l.y + c * l.y * l.y + e * l.x + f * l.y;
        (frame, l, l.z - surface)
    }

    /// Whether offset `d` lies in the slab (with a relative `slack`).
    pub fn contains(&self, d: DVec3, slack: f64) -> bool {
        self.height_above(d).2.abs() <= f64::from(self.half_width) * (1.0 + slack)
    }

    /// Offset `d` moved along the slab's normal into the slab: unchanged
    /// when it is in it.
    pub fn clamp(&self, d: DVec3) -> DVec3 {
        let (frame, l, above) = self.height_above(d);
        let w = f64::from(self.half_width);
        if above.abs() <= w {
            return d;
        }
        frame.to_world(DVec3::new(l.x, l.y, l.z - (above - above.clamp(-w, w))))
    }

    /// Offset `d` brought into the slab and within `radius` of the input
    /// position, both exactly: into the slab along its normal, and when that
    /// lies beyond the ball, the same for the longest part of `d` whose
    /// point does not (bisection; moving a point into a curved slab
    /// changes its distance, so neither step alone keeps the other's bound).
    pub fn clamp_within(&self, d: DVec3, radius: f64) -> DVec3 {
        let inside = self.clamp(d);
        if inside.length() <= radius {
            return inside;
        }
        let (mut short, mut long) = (0.0, 1.0);
        for _ in 0..BALL_BISECTIONS {
            let mid = 0.5 * (short + long);
            if self.clamp(d * mid).length() <= radius {
                short = mid;
            } else {
                long = mid;
            }
        }
        self.clamp(d * short)
    }

    /// The input normal the slab is measured along (unit).
    pub fn normal(&self) -> DVec3 {
        self.normal.as_dvec3().normalize()
    }

    /// The same slab `factor` times as wide.
    pub fn scaled(self, factor: f64) -> Self {
        SurfaceSlab {
            half_width: (f64::from(self.half_width) * factor) as f32,
            ..self
        }
    }

    /// Half the slab's width.
    #[cfg(test)]
    pub fn half_width(&self) -> f64 {
        f64::from(self.half_width)
    }
}

/// The input's noise estimate and the slabs it gives.
#[derive(Debug, Clone)]
pub struct InputNoise {
    /// Median height of an interior vertex above its 2-ring's fit (the
    /// quadric with its cubic terms), in mean edge lengths of that vertex.
    pub median: f64,
    /// Per vertex: its slab, `reach` times the median times its mean edge
    /// either way, or `None` (not interior, no quadric fitted) where the
    /// ball alone decides.
    pub slabs: Vec<Option<SurfaceSlab>>,
}

/// Estimates `mesh`'s noise and each interior vertex's slab, `reach` times
/// the estimate wide either way. A neighbour whose input normal makes a
/// cosine below `min_cos` with the vertex's is left out of its fit (the far
/// side of a thin part, as in the passes). `None` when fewer than
/// [`MIN_NOISE_FITS`] vertices have a quadric. Deterministic: each vertex's
/// fit depends on the input alone.
pub fn estimate(mesh: &Mesh, topo: &Topology, reach: f64, min_cos: f64) -> Option<InputNoise> {
    let p = mesh.positions();
    let normals = vertex_normals_f32_by_faces(mesh, topo, p);
    let fits: Vec<Option<(SurfaceSlab, f64, f64)>> = (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| {
            let n = normals[v];
            if topo.kind(v) != VertexKind::Interior || n == Vec3::ZERO {
                return None;
            }
            let frame = Frame::new(p[v], n.as_dvec3());
            let facing = Facing {
                normals: &normals,
                min_cos,
            };
            let (fit, predicted) = with_walker(|walker| {
                let ring = walker.k_ring(topo, v, NOISE_RING);
                let fit = fit_neighbours(&frame, p, ring, FitModel::Quadric, Some(facing));
                let cubic = fit_neighbours(&frame, p, ring, FitModel::Cubic, Some(facing));
                // Too few points for the cubic terms: the quadric predicts.
                let predicted = if cubic.kind == FitKind::Cubic {
                    cubic.height()
                } else {
                    fit.height()
                };
                (fit, predicted)
            });
            let edge = mean_edge_at(topo, p, v);
            // A NaN edge (coincident or non-finite input) fits nothing.
            if fit.kind != FitKind::Quadric || edge.is_nan() || edge <= 0.0 {
                return None;
            }
            let [a, b, c, e, f, _] = fit.coeffs;
            let slab = SurfaceSlab {
                normal: n,
                coeffs: [a, b, c, e, f].map(|x| x as f32),
                half_width: 0.0,
            };
            Some((slab, predicted.abs() / edge, edge))
        })
        .collect();
    let mut heights: Vec<f64> = fits.iter().flatten().map(|f| f.1).collect();
    if heights.len() < MIN_NOISE_FITS {
        return None;
    }
    let mid = heights.len() / 2;
    let median = *heights.select_nth_unstable_by(mid, f64::total_cmp).1;
    let slabs = fits
        .into_iter()
        .map(|fit| {
            fit.map(|(slab, _, edge)| SurfaceSlab {
                half_width: (reach * median * edge) as f32,
                ..slab
            })
        })
        .collect();
    Some(InputNoise { median, slabs })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::{normal_deviate, tessellated_sine_sheet, tessellated_torus};

    #[test]
    fn the_estimate_follows_the_noise_and_not_the_shape() {
        let (torus, mesh) = tessellated_torus(10.0, 2.5, 0.7);
        let topo = Topology::build(&mesh);
        let clean = estimate(&mesh, &topo, 4.0, 0.5).expect("a torus has quadrics");
        // On the surface: the fit predicts each vertex to a small fraction
        // of an edge.
        assert!(clean.median < 0.01, "{}", clean.median);
        assert!(clean.slabs.iter().all(Option::is_some));
        for sigma in [0.05, 0.1, 0.2] {
            let m = estimate_with_noise(&mesh, &topo, sigma, |_, q| torus.normal_at(q));
            assert!(m > 0.6 * sigma && m < 0.95 * sigma, "sigma {sigma}: {m}");
        }
    }

    /// The estimate of `mesh` with seeded normal noise of `sigma` mean
    /// edges along `normal(vertex, position)`.
    fn estimate_with_noise(
        mesh: &Mesh,
        topo: &Topology,
        sigma: f64,
        normal: impl Fn(usize, DVec3) -> DVec3,
    ) -> f64 {
        let edge = mesh.mean_edge_length();
        let mut noisy = mesh.clone();
        for (i, q) in noisy.positions_mut().iter_mut().enumerate() {
            *q += normal(i, *q) * sigma * edge * normal_deviate(1, i as u64);
        }
        estimate(&noisy, topo, 4.0, 0.5).expect("fits").median
    }

    #[test]
    fn a_folds_changing_curvature_is_not_noise() {
        // A fold six edges long and one edge deep, like a gyrus of a
        // marching-cubes cortex: its curvature changes sign across a
        // 2-ring, which a quadric's prediction counts as noise and the
        // cubic's takes up.
        let (_, mesh) = tessellated_sine_sheet(6.0, 1.0, 40);
        let topo = Topology::build(&mesh);
        let clean = estimate(&mesh, &topo, 4.0, 0.5).expect("fits").median;
        assert!(clean < 0.03, "{clean}");
        // Noise on the fold is still seen as noise.
        let normals = vertex_normals_f32_by_faces(&mesh, &topo, mesh.positions());
        for sigma in [0.05, 0.1, 0.2] {
            let m = estimate_with_noise(&mesh, &topo, sigma, |i, _| normals[i].as_dvec3());
            assert!(m > 0.6 * sigma && m < 1.1 * sigma, "sigma {sigma}: {m}");
        }
    }

    #[test]
    fn the_slab_follows_the_input_surface() {
        let (torus, mesh) = tessellated_torus(10.0, 2.5, 0.7);
        let topo = Topology::build(&mesh);
        let noise = estimate(&mesh, &topo, 4.0, 0.5).expect("fits");
        let p = mesh.positions();
        let v = 17;
        let unit = noise.slabs[v].expect("an interior vertex");
        // A slab a hundredth of a unit wide either way.
        let w = 0.01;
        let slab = unit.scaled(w / unit.half_width());
        assert!((slab.half_width() - w).abs() < 1e-9);
        let n = torus.normal_at(p[v]);
        // Half a unit round the tube, back onto the torus: 0.05 below the
        // tangent plane, so outside a flat slab, but on the input surface.
        let around = n.cross(DVec3::new(-p[v].y, p[v].x, 0.0)).normalize();
        let along = p[v] + 0.5 * around;
        let on_surface = along - torus.signed_distance(along) * torus.normal_at(along);
        assert!((on_surface - p[v]).dot(n) < -4.0 * w);
        assert!(slab.contains(on_surface - p[v], 0.0));
        // Across it by more than the slab: brought back to its face.
        let out = slab.clamp(on_surface - p[v] + 3.0 * w * n);
        assert!(slab.contains(out, 1e-9));
        assert!(!slab.contains(out + 0.1 * w * n, 0.0));
        assert!(torus.signed_distance(p[v] + out) < 1.2 * w);
        assert_eq!(slab.clamp(on_surface - p[v]), on_surface - p[v]);
        // Held in a ball as well: in both, exactly, however far it went.
        for far in [0.3, 1.0, 5.0] {
            let d = far * (around + 0.5 * n);
            let held = slab.clamp_within(d, 0.4);
            assert!(slab.contains(held, 1e-9), "{far}");
            assert!(held.length() <= 0.4, "{far}");
            if far == 0.3 {
                assert_eq!(held, slab.clamp(d));
            }
        }
        assert!((slab.scaled(2.0).half_width() - 2.0 * w).abs() < 1e-9);
    }

    #[test]
    fn too_few_fits_give_no_estimate() {
        let mesh = crate::shapes::double_cones(1, 6);
        let topo = Topology::build(&mesh);
        assert!(estimate(&mesh, &topo, 4.0, 0.5).is_none());
    }
}
