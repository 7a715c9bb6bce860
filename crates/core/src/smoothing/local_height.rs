//! The passes' drift across a surface of no grid, taken back: after the
//! adaptive passes (section 2.3), each vertex's 1-ring keeps its input's
//! smoothed height across the input surface.
//!
//! On a mesh cut from no grid the passes' moves across the surface are
//! two things added ([`super::noise`]): the input's noise taken out, which
//! is independent from vertex to vertex and averages to almost nothing over
//! a few neighbours, and the fits' own bias, which flattens a fold two or
//! three edges wide or shrinks a tube as a whole and moves neighbours
//! alike. A smoothed mean of the move across over a vertex's 1-ring (along
//! its input normal) is then the bias, up to the noise's own mean over
//! those vertices, and taking it back keeps the noise taken out and gives
//! the shape back. This is Tukey's twicing (the smoother's residual
//! smoothed and added back), with a second smoother on the 1-rings: the
//! smallest that averages the noise and follows the bias of folds a few
//! edges wide ([`take_back_drift`] says which). Moves along the surface
//! (the passes' own tangential moves, and what the quality fixes do after)
//! are untouched.

use crate::mesh::Topology;
use glam::DVec3;
use rayon::prelude::*;

/// Takes from every vertex that has an input normal (`normal(v)`, unit)
/// and is `movable` its drift: the smoothed move across of its 1-ring.
/// Each vertex's move across is `(positions[v] - input[v]) . normal(v)`;
/// its lazy mean is half its own and half its facing neighbours' mean; the
/// drift is the facing neighbours' mean of their lazy means, taken back
/// along the vertex's normal. A neighbour faces a vertex when it has an
/// input normal making a cosine of at least `min_cos` with the vertex's:
/// one facing away lies across a thin part or a fold, where its move says
/// nothing of this side's height (as the passes' fits leave it out,
/// [`crate::fit::quadric_fit::Facing`]). Neighbours count whether or not
/// they move themselves.
///
/// The smoother, `W (I + W) / 2` with `W` the 1-ring mean, follows a bias
/// that neighbours share in full, weighs the vertex's own move (its own
/// noise taken out) at about `1 / (2 deg^2)`, and gives back nothing of the
/// mesh's finest pattern, a checkerboard, whose 1-ring mean is its own
/// negative: a plain mean over the vertex and its ring would give part of
/// such noise back, on a quad mesh with its sign flipped.
///
/// Returns the root mean square of what was taken back over the vertices
/// it was taken from (0 when none). Deterministic: every mean is summed in
/// 1-ring order from the positions before any change.
pub fn take_back_drift(
    topo: &Topology,
    input: &[DVec3],
    positions: &mut [DVec3],
    movable: &[bool],
    min_cos: f64,
    normal: impl Fn(usize) -> Option<DVec3> + Sync,
) -> f64 {
    let current: &[DVec3] = positions;
    let n = topo.num_vertices();
    let normals: Vec<Option<DVec3>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(&normal)
        .collect();
    let across: Vec<Option<f64>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| normals[v].map(|m| (current[v] - input[v]).dot(m)))
        .collect();
    // The mean of `values` over `v`'s facing neighbours.
    let ring_mean = |v: usize, values: &[Option<f64>]| {
        let m = normals[v]?;
        let (mut sum, mut count) = (0.0, 0usize);
        for &j in topo.neighbors(v) {
            let j = j as usize;
            if let Some(x) = values[j]
                && normals[j].is_some_and(|k| k.dot(m) >= min_cos)
            {
                sum += x;
                count += 1;
            }
        }
        (count > 0).then(|| sum / count as f64)
    };
    let lazy: Vec<Option<f64>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| {
            let own = across[v]?;
            Some(ring_mean(v, &across).map_or(own, |w| 0.5 * (own + w)))
        })
        .collect();
    let shifts: Vec<Option<DVec3>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| {
            if !movable.get(v).copied().unwrap_or(false) {
                return None;
            }
            Some(normals[v]? * ring_mean(v, &lazy)?)
        })
        .collect();
    let (mut squares, mut count) = (0.0, 0usize);
    for (p, shift) in positions.iter_mut().zip(&shifts) {
        if let Some(s) = shift {
            *p -= *s;
            squares += s.length_squared();
            count += 1;
        }
    }
    if count == 0 {
        0.0
    } else {
        (squares / count as f64).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::{normal_deviate, tessellated_torus};

    #[test]
    fn a_drift_that_neighbours_share_is_taken_back_and_noise_stays_taken_out() {
        let (torus, mesh) = tessellated_torus(10.0, 2.5, 0.7);
        let topo = Topology::build(&mesh);
        let input = mesh.positions();
        let normals: Vec<DVec3> = input.iter().map(|&p| torus.normal_at(p)).collect();
        let movable = vec![true; input.len()];
        // The passes' two moves: a bias that varies slowly round the torus
        // (up to a seventh of an edge), and noise taken out, different at
        // every vertex; plus a move along the surface.
        let bias = |p: DVec3| 0.1 * (p.y.atan2(p.x) * 3.0).sin();
        let noise = |i: usize| 0.03 * normal_deviate(7, i as u64);
        let tangent = |p: DVec3| DVec3::Z.cross(p).normalize() * 0.05;
        let mut positions: Vec<DVec3> = input
            .iter()
            .enumerate()
            .map(|(i, &p)| p + (bias(p) - noise(i)) * torus.normal_at(p) + tangent(p))
            .collect();
        // What is left across the surface, less the noise taken out.
        let left = |positions: &[DVec3]| {
            rms((0..input.len()).map(|i| (positions[i] - input[i]).dot(normals[i]) + noise(i)))
        };
        let before = left(&positions);
        let taken = take_back_drift(&topo, input, &mut positions, &movable, 0.5, |v| {
            normals.get(v).copied()
        });
        assert!(taken > 0.05, "{taken}");
        // The bias, down to a small part of it, and the noise still taken
        // out: what is left is the noise's mean over a 1-ring, well under
        // the noise itself (which is what would be left had the vertices
        // gone back to their input).
        let after = left(&positions);
        let noise_rms = rms((0..input.len()).map(noise));
        assert!(before > 0.065, "{before}");
        assert!(after < 0.3 * before, "{before} -> {after}");
        assert!(after < 0.6 * noise_rms, "{noise_rms} -> {after}");
        // The move along the surface stays.
        for (&x, &p) in input.iter().zip(&positions) {
            let along = (p - x) - (p - x).dot(torus.normal_at(x)) * torus.normal_at(x);
            assert!((along - tangent(x)).length() < 1e-9);
        }
    }

    fn rms(values: impl Iterator<Item = f64>) -> f64 {
        let (s, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
        (s / n as f64).sqrt()
    }

    #[test]
    fn fixed_vertices_and_vertices_without_a_normal_stay() {
        let (torus, mesh) = tessellated_torus(10.0, 2.5, 0.7);
        let topo = Topology::build(&mesh);
        let input = mesh.positions();
        let mut positions: Vec<DVec3> = input
            .iter()
            .map(|&p| p + 0.1 * torus.normal_at(p))
            .collect();
        let movable: Vec<bool> = (0..input.len()).map(|v| v % 3 != 0).collect();
        take_back_drift(&topo, input, &mut positions, &movable, 0.5, |v| {
            (v % 3 != 1).then(|| torus.normal_at(input[v]))
        });
        for (v, (&x, &p)) in input.iter().zip(&positions).enumerate() {
            let across = (p - x).dot(torus.normal_at(x));
            if v % 3 == 2 {
                // Its 1-ring moved 0.1 out as a whole (along normals that
                // turn a little from its own): back near the input.
                assert!(across.abs() < 0.01, "{v}: {across}");
            } else {
                assert!((across - 0.1).abs() < 1e-12, "{v}: {across}");
            }
        }
    }
}
