//! Analytic test shapes (sphere, torus, ellipsoid) with exact distance
//! functions, and the meshes a segmentation pipeline makes of them: the
//! welded quad boundary of a binary voxel mask ([`voxel_boundary_mesh`]),
//! its marching-cubes triangulation ([`marching_cubes_mesh`]) and the
//! complex of several labels' boundaries with their walls written once
//! ([`label_complex`]); and, for a
//! mesh cut from no grid, a torus tessellated on its own surface
//! ([`tessellated_torus`], with seeded noise from [`normal_deviate`]) and a
//! folded sheet tessellated on its own surface ([`tessellated_sine_sheet`]).
//!
//! Everything is in voxel units: voxel `(i, j, k)` of a [`VoxelMask`] covers
//! the unit cube whose lowest corner is `origin + (i, j, k)`, and meshes are
//! built in the same coordinates as the shape, so
//! [`rms_distance`]`(shape, mesh.positions())` measures how far a mesh lies
//! from the true surface in voxels. Generation is deterministic.

mod ellipsoid;
mod limits;
mod marching_cubes;
mod segmentation;
mod sheet;
mod voxel;

pub use limits::{big_face, double_cones, fan, prisms};
pub use marching_cubes::marching_cubes_mesh;
pub use segmentation::{
    FoldedSheet, Placed, Shell, SpherePair, edge_touching_blocks, folded_sheet, placed, placement,
    placement_families, shell, sphere_pair, tube,
};
pub use sheet::{SineSheet, tessellated_sine_sheet};
pub use voxel::{VOXEL_MARGIN, VoxelMask, label_complex, voxel_boundary_mesh, voxel_mask};

use crate::mesh::Mesh;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// An analytic solid with a closed surface.
pub trait Shape: Sync {
    /// Whether `p` lies strictly inside the solid.
    fn inside(&self, p: DVec3) -> bool;
    /// Unsigned Euclidean distance from `p` to the surface.
    fn distance(&self, p: DVec3) -> f64;
    /// Volume of the solid.
    fn volume(&self) -> f64;
    /// Axis-aligned bounding box `(min, max)` of the solid.
    fn bounds(&self) -> (DVec3, DVec3);
}

impl<S: Shape + ?Sized> Shape for &S {
    fn inside(&self, p: DVec3) -> bool {
        (**self).inside(p)
    }

    fn distance(&self, p: DVec3) -> f64 {
        (**self).distance(p)
    }

    fn volume(&self) -> f64 {
        (**self).volume()
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        (**self).bounds()
    }
}

/// Ball of `radius` about `center`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    /// Centre.
    pub center: DVec3,
    /// Radius (> 0).
    pub radius: f64,
}

impl Shape for Sphere {
    fn inside(&self, p: DVec3) -> bool {
        (p - self.center).length_squared() < self.radius * self.radius
    }

    fn distance(&self, p: DVec3) -> f64 {
        ((p - self.center).length() - self.radius).abs()
    }

    fn volume(&self) -> f64 {
        4.0 / 3.0 * PI * self.radius.powi(3)
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        (self.center - self.radius, self.center + self.radius)
    }
}

/// Solid torus about the z axis through `center`: the points within `minor`
/// of the circle of radius `major` in the plane `z = center.z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Torus {
    /// Centre of the hole.
    pub center: DVec3,
    /// Radius of the tube's centre circle (> `minor`).
    pub major: f64,
    /// Radius of the tube (> 0).
    pub minor: f64,
}

impl Torus {
    /// Distance from `p` to the tube's centre circle.
    fn tube_distance(&self, p: DVec3) -> f64 {
        let d = p - self.center;
        let rho = (d.x * d.x + d.y * d.y).sqrt() - self.major;
        (rho * rho + d.z * d.z).sqrt()
    }

    /// Signed distance from `p` to the surface, positive outside.
    pub fn signed_distance(&self, p: DVec3) -> f64 {
        self.tube_distance(p) - self.minor
    }

    /// The outward unit normal of the surface nearest `p` (`p` off the
    /// tube's centre circle and the z axis).
    pub fn normal_at(&self, p: DVec3) -> DVec3 {
        let d = p - self.center;
        let radial = DVec3::new(d.x, d.y, 0.0).normalize();
        (d - self.major * radial).normalize()
    }
}

/// A standard normal deviate, the same on every machine for the same
/// `seed` and index `i` (Box-Muller on a 64-bit mix of both): noise for
/// test meshes.
pub fn normal_deviate(seed: u64, i: u64) -> f64 {
    let uniform = |k: u64| {
        let mut x =
            k.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed.wrapping_mul(0xD1B5_4A32_D192_ED03);
        x ^= x >> 31;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 29;
        x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
        x ^= x >> 32;
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let (u, v) = (uniform(2 * i), uniform(2 * i + 1));
    (-2.0 * u.ln()).sqrt() * (2.0 * PI * v).cos()
}

/// The torus about the z axis through the origin and a triangle mesh of
/// its surface with edges of about `edge`: a grid of `major` and `minor`
/// angle steps, every vertex exactly on the surface. A mesh of no voxel
/// grid that is already smooth (as the marching cubes of a probability map
/// is), to check that smoothing leaves such a surface where it is.
pub fn tessellated_torus(major: f64, minor: f64, edge: f64) -> (Torus, Mesh) {
    let t = Torus {
        center: DVec3::ZERO,
        major,
        minor,
    };
    let steps = |r: f64| ((2.0 * PI * r / edge).round() as u32).max(3);
    let (nu, nv) = (steps(major), steps(minor));
    let mut p = Vec::with_capacity((nu * nv) as usize);
    for i in 0..nu {
        let (su, cu) = (2.0 * PI * f64::from(i) / f64::from(nu)).sin_cos();
        for j in 0..nv {
            let (sv, cv) = (2.0 * PI * f64::from(j) / f64::from(nv)).sin_cos();
            let r = major + minor * cv;
            p.push(DVec3::new(r * cu, r * su, minor * sv));
        }
    }
    let at = |i: u32, j: u32| (i % nu) * nv + j % nv;
    let mut faces = Vec::with_capacity(2 * p.len());
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            faces.push([a, b, c]);
            faces.push([a, c, d]);
        }
    }
    let m = Mesh::from_polygons(p, &faces).expect("a torus grid");
    (t, m)
}

impl Shape for Torus {
    fn inside(&self, p: DVec3) -> bool {
        self.tube_distance(p) < self.minor
    }

    fn distance(&self, p: DVec3) -> f64 {
        (self.tube_distance(p) - self.minor).abs()
    }

    fn volume(&self) -> f64 {
        2.0 * PI * PI * self.major * self.minor * self.minor
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        let e = DVec3::new(self.major + self.minor, self.major + self.minor, self.minor);
        (self.center - e, self.center + e)
    }
}

/// Axis-aligned solid ellipsoid `sum ((p - center)_i / semi_axes_i)^2 < 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipsoid {
    /// Centre.
    pub center: DVec3,
    /// Semi-axis lengths along x, y and z (each > 0).
    pub semi_axes: DVec3,
}

impl Ellipsoid {
    /// The point of the surface nearest to `p` (Eberly, "Distance from a
    /// point to an ellipse, an ellipsoid, or a hyperellipsoid", 2013).
    pub fn closest_point(&self, p: DVec3) -> DVec3 {
        self.center + ellipsoid::closest_point(self.semi_axes, p - self.center)
    }
}

impl Shape for Ellipsoid {
    fn inside(&self, p: DVec3) -> bool {
        ((p - self.center) / self.semi_axes).length_squared() < 1.0
    }

    fn distance(&self, p: DVec3) -> f64 {
        p.distance(self.closest_point(p))
    }

    fn volume(&self) -> f64 {
        4.0 / 3.0 * PI * self.semi_axes.x * self.semi_axes.y * self.semi_axes.z
    }

    fn bounds(&self) -> (DVec3, DVec3) {
        (self.center - self.semi_axes, self.center + self.semi_axes)
    }
}

/// Root-mean-square distance from `positions` to the surface of `shape`;
/// 0 for no positions.
pub fn rms_distance<S: Shape + ?Sized>(shape: &S, positions: &[DVec3]) -> f64 {
    if positions.is_empty() {
        return 0.0;
    }
    let sum: f64 = positions
        .par_iter()
        .map(|&p| {
            let d = shape.distance(p);
            d * d
        })
        .sum();
    (sum / positions.len() as f64).sqrt()
}

/// Largest distance from `positions` to the surface of `shape`; 0 for no
/// positions.
pub fn max_distance<S: Shape + ?Sized>(shape: &S, positions: &[DVec3]) -> f64 {
    positions
        .par_iter()
        .map(|&p| shape.distance(p))
        .reduce(|| 0.0, f64::max)
}

/// Where the convenience generators put a shape's centre: a fixed
/// non-integer point, so the shape is not symmetric on the voxel grid.
pub const CENTER_OFFSET: DVec3 = DVec3::new(0.37, 0.21, 0.13);

/// Sphere of `radius` voxels centred at [`CENTER_OFFSET`] and the welded
/// quad boundary of its voxel mask.
pub fn voxel_sphere(radius: f64) -> (Sphere, Mesh) {
    let s = Sphere {
        center: CENTER_OFFSET,
        radius,
    };
    let m = voxel_boundary_mesh(&voxel_mask(&s));
    (s, m)
}

/// Torus (axis z) centred at [`CENTER_OFFSET`] and the welded quad boundary
/// of its voxel mask.
pub fn voxel_torus(major: f64, minor: f64) -> (Torus, Mesh) {
    let t = torus(major, minor);
    let m = voxel_boundary_mesh(&voxel_mask(&t));
    (t, m)
}

/// Ellipsoid with semi-axes `a`, `b`, `c` (along x, y, z) centred at
/// [`CENTER_OFFSET`] and the welded quad boundary of its voxel mask.
pub fn voxel_ellipsoid(a: f64, b: f64, c: f64) -> (Ellipsoid, Mesh) {
    let e = ellipsoid(a, b, c);
    let m = voxel_boundary_mesh(&voxel_mask(&e));
    (e, m)
}

/// Sphere as in [`voxel_sphere`], meshed by [`marching_cubes_mesh`].
pub fn mc_sphere(radius: f64) -> (Sphere, Mesh) {
    let s = Sphere {
        center: CENTER_OFFSET,
        radius,
    };
    let m = marching_cubes_mesh(&voxel_mask(&s));
    (s, m)
}

/// Torus as in [`voxel_torus`], meshed by [`marching_cubes_mesh`].
pub fn mc_torus(major: f64, minor: f64) -> (Torus, Mesh) {
    let t = torus(major, minor);
    let m = marching_cubes_mesh(&voxel_mask(&t));
    (t, m)
}

/// Ellipsoid as in [`voxel_ellipsoid`], meshed by [`marching_cubes_mesh`].
pub fn mc_ellipsoid(a: f64, b: f64, c: f64) -> (Ellipsoid, Mesh) {
    let e = ellipsoid(a, b, c);
    let m = marching_cubes_mesh(&voxel_mask(&e));
    (e, m)
}

fn torus(major: f64, minor: f64) -> Torus {
    Torus {
        center: CENTER_OFFSET,
        major,
        minor,
    }
}

fn ellipsoid(a: f64, b: f64, c: f64) -> Ellipsoid {
    Ellipsoid {
        center: CENTER_OFFSET,
        semi_axes: DVec3::new(a, b, c),
    }
}

#[cfg(test)]
mod tests;
