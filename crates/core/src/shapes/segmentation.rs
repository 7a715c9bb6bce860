//! Shapes that look like segmentations: thin shells, thin tubes, solids
//! whose masks touch (non-manifold contacts) and a folded sheet, each with
//! its exact distance, and seeded families of grid placements (sub-voxel
//! offsets and rotations) so a result is judged over where the grid falls,
//! not at one lucky placement.

use super::{Ellipsoid, Shape, Sphere, Torus, VoxelMask, voxel_boundary_mesh};
use crate::mesh::Mesh;
use glam::{DMat3, DQuat, DVec3, IVec3};

/// The solid between two concentric spheres: a closed sheet
/// `outer - inner` voxels thick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shell {
    /// Centre.
    pub center: DVec3,
    /// Inner radius (> 0).
    pub inner: f64,
    /// Outer radius (> `inner`).
    pub outer: f64,
}

impl Shape for Shell {
    fn inside(&self, p: DVec3) -> bool {
        let r = (p - self.center).length();
        r > self.inner && r < self.outer
    }

    fn distance(&self, p: DVec3) -> f64 {
        let r = (p - self.center).length();
        (r - self.inner).abs().min((r - self.outer).abs())
    }

    fn volume(&self) -> f64 {
        4.0 / 3.0 * std::f64::consts::PI * (self.outer.powi(3) - self.inner.powi(3))
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        (self.center - self.outer, self.center + self.outer)
    }
}

/// Two disjoint spheres: their union's surface is both spheres, so the
/// distance is the nearer one's. Placed tangent (or a fraction of a voxel
/// apart) their voxel masks touch along edges or at corners: the
/// non-manifold contacts of segmented cells and vessels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpherePair {
    /// First sphere.
    pub a: Sphere,
    /// Second sphere, disjoint from the first.
    pub b: Sphere,
}

impl Shape for SpherePair {
    fn inside(&self, p: DVec3) -> bool {
        self.a.inside(p) || self.b.inside(p)
    }

    fn distance(&self, p: DVec3) -> f64 {
        self.a.distance(p).min(self.b.distance(p))
    }

    fn volume(&self) -> f64 {
        self.a.volume() + self.b.volume()
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        let (a0, a1) = self.a.bounds();
        let (b0, b1) = self.b.bounds();
        (a0.min(b0), a1.max(b1))
    }
}

/// A folded sheet, gyrus-like: the points within `thickness / 2` of the
/// sinusoidal midsurface `z = amplitude sin(2 pi x / wavelength)` over
/// `|x| < half_length`, `|y| < half_width`. The distance is exact to the
/// sheet's two folded faces (the midsurface distance is minimised
/// numerically) and to its flat rim walls, and a lower bound only within
/// half a thickness of the rim's edges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoldedSheet {
    /// Peak height of the fold.
    pub amplitude: f64,
    /// Length of one fold.
    pub wavelength: f64,
    /// Thickness of the sheet (less than twice the fold's smallest radius
    /// of curvature, `wavelength^2 / (4 pi^2 amplitude)`).
    pub thickness: f64,
    /// Half extent along x.
    pub half_length: f64,
    /// Half extent along y.
    pub half_width: f64,
}

impl FoldedSheet {
    fn mid(&self, x: f64) -> f64 {
        let k = std::f64::consts::TAU / self.wavelength;
        self.amplitude * (k * x).sin()
    }

    /// Distance in the xz plane from `(x, z)` to the midsurface curve.
    fn midsurface_distance(&self, x: f64, z: f64) -> f64 {
        let k = std::f64::consts::TAU / self.wavelength;
        let (a, k2) = (self.amplitude, k * k);
        // The nearest point is within `|z| + amplitude` of x: sample that
        // span, then polish the best sample with Newton steps on the
        // squared distance's derivative.
        let reach = z.abs() + a + self.thickness;
        let steps = ((2.0 * reach / self.wavelength) * 64.0).ceil().max(16.0) as usize;
        let d2 = |t: f64| (t - x).powi(2) + (self.mid(t) - z).powi(2);
        let mut best = x;
        for i in 0..=steps {
            let t = x - reach + 2.0 * reach * i as f64 / steps as f64;
            if d2(t) < d2(best) {
                best = t;
            }
        }
        let mut t = best;
        for _ in 0..8 {
            let (s, c) = (k * t).sin_cos();
            let h = a * s - z;
            let g = (t - x) + h * a * k * c;
            let gp = 1.0 + (a * k * c).powi(2) - h * a * k2 * s;
            if gp <= 0.0 {
                break;
            }
            let next = t - g / gp;
            if d2(next) > d2(t) {
                break;
            }
            t = next;
        }
        d2(t).min(d2(best)).sqrt()
    }

    /// Signed distance: negative inside.
    fn signed(&self, p: DVec3) -> f64 {
        let sheet = self.midsurface_distance(p.x, p.z) - 0.5 * self.thickness;
        let rim_x = p.x.abs() - self.half_length;
        let rim_y = p.y.abs() - self.half_width;
        sheet.max(rim_x).max(rim_y)
    }
}

impl Shape for FoldedSheet {
    fn inside(&self, p: DVec3) -> bool {
        self.signed(p) < 0.0
    }

    fn distance(&self, p: DVec3) -> f64 {
        self.signed(p).abs()
    }

    fn volume(&self) -> f64 {
        // Length of the midsurface curve over the sheet times the width
        // times the thickness (exact for a sheet thinner than its folds'
        // curvature radius), by the trapezoid rule.
        let n = 4096;
        let h = 2.0 * self.half_length / n as f64;
        let k = std::f64::consts::TAU / self.wavelength;
        let len: f64 = (0..n)
            .map(|i| {
                let x = -self.half_length + (i as f64 + 0.5) * h;
                (1.0 + (self.amplitude * k * (k * x).cos()).powi(2)).sqrt() * h
            })
            .sum();
        len * 2.0 * self.half_width * self.thickness
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        let e = DVec3::new(
            self.half_length,
            self.half_width,
            self.amplitude + self.thickness,
        );
        (-e, e)
    }
}

/// A shape moved to a grid placement: rotated about its own origin, then
/// translated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placed<S> {
    /// The shape in its own coordinates.
    pub shape: S,
    /// Rotation applied first.
    pub rotation: DQuat,
    /// Translation applied after the rotation.
    pub offset: DVec3,
}

impl<S: Shape> Placed<S> {
    fn local(&self, p: DVec3) -> DVec3 {
        self.rotation.inverse() * (p - self.offset)
    }
}

impl<S: Shape> Shape for Placed<S> {
    fn inside(&self, p: DVec3) -> bool {
        self.shape.inside(self.local(p))
    }

    fn distance(&self, p: DVec3) -> f64 {
        self.shape.distance(self.local(p))
    }

    fn volume(&self) -> f64 {
        self.shape.volume()
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        // The rotated box's bounds: each axis spans the absolute rotation
        // matrix times the half extents.
        let (lo, hi) = self.shape.bounds();
        let (c, e) = (0.5 * (lo + hi), 0.5 * (hi - lo));
        let m = DMat3::from_quat(self.rotation);
        let abs = DMat3::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let (c, e) = (self.rotation * c + self.offset, abs * e);
        (c - e, c + e)
    }
}

/// A seeded placement: a sub-voxel offset in `[0, 1)^3` and a rotation
/// uniform over all rotations. The same `seed` gives the same placement
/// everywhere.
pub fn placement(seed: u64) -> (DVec3, DQuat) {
    let mut state = seed ^ 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        // SplitMix64: tiny, well mixed, no dependency.
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let offset = DVec3::new(next(), next(), next());
    // Shoemake's uniform random unit quaternion.
    let (u1, u2, u3) = (next(), next(), next());
    let tau = std::f64::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let q = DQuat::from_xyzw(
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
        b * (tau * u3).cos(),
    );
    (offset, q.normalize())
}

/// `shape` at placement `seed` ([`placement`]).
pub fn placed<S: Shape>(shape: S, seed: u64) -> Placed<S> {
    let (offset, rotation) = placement(seed);
    Placed {
        shape,
        rotation,
        offset,
    }
}

/// The analytic families measured at seeded placements
/// (`examples/placements`, `examples/shape_meshes`): the engine's sphere,
/// torus and ellipsoid, and the segmentation-like thin shapes, each with a
/// short name (for file names) and a description.
pub fn placement_families() -> Vec<(&'static str, &'static str, Box<dyn Shape>)> {
    let sphere = |radius| Sphere {
        center: DVec3::ZERO,
        radius,
    };
    vec![
        ("sphere", "voxel sphere r=12", Box::new(sphere(12.0))),
        ("torus", "voxel torus 20/8", Box::new(tube(20.0, 8.0))),
        (
            "ellipsoid",
            "voxel ellipsoid 30/20/12",
            Box::new(Ellipsoid {
                center: DVec3::ZERO,
                semi_axes: DVec3::new(30.0, 20.0, 12.0),
            }),
        ),
        ("shell2", "shell r=12 t=2", Box::new(shell(12.0, 2.0))),
        ("shell3", "shell r=12 t=3", Box::new(shell(12.0, 3.0))),
        ("tube1.5", "tube 12/1.5", Box::new(tube(12.0, 1.5))),
        ("tube2", "tube 12/2", Box::new(tube(12.0, 2.0))),
        ("tube3", "tube 12/3", Box::new(tube(12.0, 3.0))),
        (
            "tangent",
            "tangent spheres r=6",
            Box::new(sphere_pair(6.0, 0.0)),
        ),
        (
            "gap",
            "spheres r=6 gap 0.5",
            Box::new(sphere_pair(6.0, 0.5)),
        ),
        ("fold2", "folded sheet t=2", Box::new(folded_sheet(2.0))),
        ("fold3", "folded sheet t=3", Box::new(folded_sheet(3.0))),
    ]
}

/// A shell of `thickness` voxels with outer radius `outer`, centred at
/// the origin.
pub fn shell(outer: f64, thickness: f64) -> Shell {
    Shell {
        center: DVec3::ZERO,
        inner: outer - thickness,
        outer,
    }
}

/// A torus of tube radius `minor` about the z axis through the origin.
pub fn tube(major: f64, minor: f64) -> Torus {
    Torus {
        center: DVec3::ZERO,
        major,
        minor,
    }
}

/// Two spheres of `radius`, `gap` voxels apart along the x axis (0:
/// tangent), symmetric about the origin.
pub fn sphere_pair(radius: f64, gap: f64) -> SpherePair {
    let c = DVec3::X * (radius + 0.5 * gap);
    SpherePair {
        a: Sphere { center: -c, radius },
        b: Sphere { center: c, radius },
    }
}

/// A folded sheet of `thickness` voxels: two folds of `wavelength` 16 and
/// amplitude 4 (a fold's curvature radius about 1.6 voxels at its crest,
/// like a narrow gyrus), 32 x 20 voxels.
pub fn folded_sheet(thickness: f64) -> FoldedSheet {
    FoldedSheet {
        amplitude: 4.0,
        wavelength: 16.0,
        thickness,
        half_length: 16.0,
        half_width: 10.0,
    }
}

/// The voxel-boundary mesh of two 5 x 5 x 5 blocks of voxels that touch
/// only along one edge: a non-manifold edge shared by four faces, the
/// smallest of the contacts a segmentation mask makes.
pub fn edge_touching_blocks() -> Mesh {
    let mask = VoxelMask::from_fn(IVec3::ZERO, [14, 14, 7], |i, j, k| {
        (1..6).contains(&k)
            && ((1..6).contains(&i) && (1..6).contains(&j)
                || (6..11).contains(&i) && (6..11).contains(&j))
    });
    voxel_boundary_mesh(&mask)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::voxel_mask;

    #[test]
    fn placements_are_seeded_and_spread() {
        assert_eq!(placement(3), placement(3));
        let offsets: Vec<DVec3> = (0..8).map(|s| placement(s).0).collect();
        assert!(
            offsets
                .iter()
                .all(|o| o.min_element() >= 0.0 && o.max_element() < 1.0)
        );
        assert!(offsets.windows(2).all(|w| w[0] != w[1]));
        let (_, q) = placement(5);
        assert!((q.length() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn distances_vanish_on_the_surfaces_and_grow_off_them() {
        let s = shell(8.0, 2.0);
        assert!(s.distance(DVec3::X * 6.0) < 1e-12 && s.distance(DVec3::Y * 8.0) < 1e-12);
        assert!((s.distance(DVec3::Z * 7.0) - 1.0).abs() < 1e-12);
        let f = folded_sheet(2.0);
        // Above the crest at x = wavelength / 4 the top face is at z = 5.
        let crest = DVec3::new(4.0, 0.0, 5.0);
        assert!(f.distance(crest) < 1e-9, "{}", f.distance(crest));
        assert!((f.distance(crest + DVec3::Z) - 1.0).abs() < 1e-9);
        assert!(f.inside(DVec3::new(4.0, 0.0, 4.0)) && !f.inside(DVec3::new(4.0, 0.0, 0.0)));
        // A placed shape measures in its own frame.
        let p = placed(s, 2);
        let q = p.rotation * (DVec3::X * 6.5) + p.offset;
        assert!((p.distance(q) - 0.5).abs() < 1e-9);
        assert!(p.inside(q));
    }

    #[test]
    fn volumes_match_the_voxel_counts() {
        let cases: Vec<(&str, Box<dyn Shape>)> = vec![
            ("shell", Box::new(placed(shell(10.0, 3.0), 1))),
            ("sheet", Box::new(placed(folded_sheet(3.0), 2))),
            ("pair", Box::new(placed(sphere_pair(6.0, 0.0), 3))),
        ];
        for (name, shape) in cases {
            let count = voxel_mask(shape.as_ref()).count_inside() as f64;
            let rel = (count - shape.volume()).abs() / shape.volume();
            assert!(
                rel < 0.05,
                "{name}: {count} voxels vs volume {}",
                shape.volume()
            );
        }
    }
}
