//! A folded sheet of no grid: `z = amplitude sin(2 pi x / wavelength)`,
//! tessellated on its own surface with its points jittered along it, as
//! the marching cubes of a smooth map of a gyrus places them.

use super::normal_deviate;
use crate::mesh::Mesh;
use glam::DVec3;
use std::f64::consts::TAU;

/// The surface `z = amplitude sin(2 pi x / wavelength)`, unbounded in `y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SineSheet {
    /// Length of one fold and its counterfold along `x`.
    pub wavelength: f64,
    /// Height of a fold above the sheet's middle.
    pub amplitude: f64,
}

/// Samples of the sheet's section that [`SineSheet::distance`] searches
/// before it refines the nearest.
const DISTANCE_SAMPLES: usize = 256;

/// Ternary-search steps that refine the nearest sample: each keeps two
/// thirds of the interval, so 60 take a sample's spacing below `1e-10` of
/// itself.
const DISTANCE_REFINEMENTS: u32 = 60;

impl SineSheet {
    fn height(&self, x: f64) -> f64 {
        self.amplitude * (TAU * x / self.wavelength).sin()
    }

    /// Distance from `p` to the sheet: the nearest point of its section in
    /// `p`'s plane `y = const`, which lies within `p`'s height above the
    /// sheet of `p.x`; sampled, then refined by ternary search.
    pub fn distance(&self, p: DVec3) -> f64 {
        let d2 = |x: f64| (p.x - x).powi(2) + (p.z - self.height(x)).powi(2);
        let reach = (p.z - self.height(p.x)).abs();
        if reach == 0.0 {
            return 0.0;
        }
        let step = 2.0 * reach / DISTANCE_SAMPLES as f64;
        let best = (0..=DISTANCE_SAMPLES)
            .map(|i| p.x - reach + step * i as f64)
            .min_by(|&a, &b| d2(a).total_cmp(&d2(b)))
            .unwrap_or(p.x);
        let (mut lo, mut hi) = (best - step, best + step);
        for _ in 0..DISTANCE_REFINEMENTS {
            let (a, b) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
            if d2(a) < d2(b) {
                hi = b;
            } else {
                lo = a;
            }
        }
        d2(0.5 * (lo + hi)).sqrt()
    }

    /// The unit normal of the sheet at `(x, y)`, pointing up.
    pub fn normal_at(&self, x: f64) -> DVec3 {
        let slope = self.amplitude * TAU / self.wavelength * (TAU * x / self.wavelength).cos();
        DVec3::new(-slope, 0.0, 1.0).normalize()
    }
}

/// The sheet over an `n` x `n` grid of unit spacing whose points are
/// jittered along `x` and `y` by a seeded normal deviate of `0.3` (clamped
/// to 1.5 of it) and lie on the sheet: no two 2-rings alike, none
/// symmetric. Its rim is the mesh's boundary.
pub fn tessellated_sine_sheet(wavelength: f64, amplitude: f64, n: u32) -> (SineSheet, Mesh) {
    let sheet = SineSheet {
        wavelength,
        amplitude,
    };
    let jitter = |seed, k| 0.3 * normal_deviate(seed, u64::from(k)).clamp(-1.5, 1.5);
    let mut p = Vec::with_capacity((n * n) as usize);
    for i in 0..n {
        for j in 0..n {
            let x = f64::from(i) + jitter(5, i * n + j);
            let y = f64::from(j) + jitter(6, i * n + j);
            p.push(DVec3::new(x, y, sheet.height(x)));
        }
    }
    let mut faces = Vec::with_capacity(2 * p.len());
    for i in 0..n.saturating_sub(1) {
        for j in 0..n.saturating_sub(1) {
            let (a, b) = (i * n + j, (i + 1) * n + j);
            faces.push([a, b, b + 1]);
            faces.push([a, b + 1, a + 1]);
        }
    }
    let m = Mesh::from_polygons(p, &faces).expect("a jittered grid");
    (sheet, m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_distance_is_the_nearest_point_of_the_section() {
        let sheet = SineSheet {
            wavelength: 6.0,
            amplitude: 1.0,
        };
        for x in [0.0, 0.7, 1.5, 3.2] {
            let on = DVec3::new(x, 2.0, sheet.height(x));
            assert!(sheet.distance(on) < 1e-12);
            let n = sheet.normal_at(x);
            // Along the normal, by less than the radius of curvature.
            for h in [0.05, -0.2] {
                let d = sheet.distance(on + h * n);
                assert!((d - h.abs()).abs() < 1e-6, "{x} {h}: {d}");
            }
        }
    }
}
