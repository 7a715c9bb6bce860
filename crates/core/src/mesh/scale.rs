//! A power of two that brings a mesh's edges to unit length, for a mesh
//! whose units put them far from it.
//!
//! The quadric fits (section 2.2 of Wang & Yu) sum fourth and higher powers
//! of local coordinates; with edges near `1e20` or `1e-20` (a surface in
//! metres of a structure nanometres across, or in picometres of one metres
//! across) those sums leave the range of a double and the fits fail or
//! round away, so the same shape would smooth differently, or not at all,
//! depending on its units. Scaling by a power of two changes no digit of a
//! coordinate, and every step of the method is covariant under it, so a
//! mesh scaled to unit edges smooths as it would in any unit where its
//! fits stay in range, and scaling the results back is exact.

use super::{Mesh, mean_edge_length};
use glam::DVec3;

/// Meshes whose mean edge length lies within `2^-UNIT_BAND ..= 2^UNIT_BAND`
/// are smoothed in their own units. The method's results are the same
/// bits at every power-of-two scale well beyond this band (the fits'
/// sums stay normal doubles), so the band only keeps ordinary units
/// (nanometres to kilometres) free of a rescaling step they do not need.
pub const UNIT_BAND: i32 = 32;

/// A power of two to multiply a mesh's coordinates by ([`UnitScale::of`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnitScale {
    /// The exponent `e` of the factor `2^e`, within the normal doubles'
    /// `-1022..=1023`.
    exponent: i32,
}

impl UnitScale {
    /// The scale that brings `mesh`'s mean edge length into `[1, 2)`, or
    /// `None` when it lies within [`UNIT_BAND`] already, or the mesh has
    /// no edge of positive length. The edges are measured on coordinates
    /// first brought below 2 by the power of two of the largest, so that
    /// meshes near the ends of the double range measure without overflow.
    pub fn of(mesh: &Mesh) -> Option<UnitScale> {
        let largest = mesh
            .positions()
            .iter()
            .map(|p| p.abs().max_element())
            .fold(0.0, f64::max);
        if largest == 0.0 {
            return None;
        }
        let coarse = -exponent(largest);
        let factor = power_of_two(coarse);
        let scaled: Vec<DVec3> = mesh.positions().iter().map(|&p| p * factor).collect();
        let edge = mean_edge_length(mesh, &scaled);
        if !(edge > 0.0 && edge.is_finite()) {
            return None;
        }
        // The file's mean edge length is `edge * 2^-coarse`.
        let edge_exponent = exponent(edge) - coarse;
        if edge_exponent.abs() <= UNIT_BAND {
            return None;
        }
        Some(UnitScale {
            exponent: (-edge_exponent).clamp(-1022, 1023),
        })
    }

    /// The factor `2^e` that takes the file's coordinates to unit edges.
    pub fn factor(self) -> f64 {
        power_of_two(self.exponent)
    }

    /// The factor `2^-e` that takes lengths at unit edges back to the
    /// file's units.
    pub fn inverse(self) -> f64 {
        power_of_two(-self.exponent)
    }

    /// `mesh` with its coordinates multiplied by [`UnitScale::factor`].
    pub fn apply(self, mesh: &Mesh) -> Mesh {
        let factor = self.factor();
        let mut scaled = mesh.clone();
        for p in scaled.positions_mut() {
            *p *= factor;
        }
        scaled
    }
}

/// `floor(log2(x))` for a positive finite `x`, subnormals included.
fn exponent(x: f64) -> i32 {
    x.log2().floor() as i32
}

/// `2^e` as a double, exactly, for `e` clamped to the normal doubles'
/// exponents `-1022..=1023`.
fn power_of_two(e: i32) -> f64 {
    let e = e.clamp(-1022, 1023);
    f64::from_bits(((e + 1023) as u64) << 52)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_unit_cube;

    fn scaled(mesh: &Mesh, s: f64) -> Mesh {
        let mut m = mesh.clone();
        for p in m.positions_mut() {
            *p *= s;
        }
        m
    }

    #[test]
    fn powers_of_two_are_exact_over_the_normal_range() {
        for e in [-1022, -600, -1, 0, 1, 52, 600, 1023] {
            assert_eq!(power_of_two(e), 2f64.powi(e), "2^{e}");
        }
        assert_eq!(exponent(1.0), 0);
        assert_eq!(exponent(1.5), 0);
        assert_eq!(exponent(0.75), -1);
        assert_eq!(exponent(f64::MIN_POSITIVE / 8.0), -1025);
    }

    #[test]
    fn ordinary_units_are_left_alone() {
        let cube = test_unit_cube();
        for s in [1.0, 1e-9, 1e9, 2f64.powi(-UNIT_BAND), 2f64.powi(UNIT_BAND)] {
            assert_eq!(UnitScale::of(&scaled(&cube, s)), None, "scale {s}");
        }
    }

    #[test]
    fn extreme_units_are_brought_to_unit_edges_and_back_exactly() {
        let cube = test_unit_cube();
        for s in [1e-300, 1e-40, 1e40, 1e300, 2f64.powi(UNIT_BAND + 1)] {
            let mesh = scaled(&cube, s);
            let unit = UnitScale::of(&mesh).expect("an extreme scale is rescaled");
            let at_unit = unit.apply(&mesh);
            let edge = at_unit.mean_edge_length();
            assert!((1.0..2.0).contains(&edge), "scale {s}: mean edge {edge}");
            for (a, b) in at_unit.positions().iter().zip(mesh.positions()) {
                assert_eq!(*a * unit.inverse(), *b, "scale {s}");
            }
        }
    }

    #[test]
    fn a_mesh_without_extent_is_left_alone() {
        let cube = test_unit_cube();
        assert_eq!(UnitScale::of(&scaled(&cube, 0.0)), None);
    }
}
