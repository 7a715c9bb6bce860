//! Growth of each vertex's neighbourhood, ring by ring, by the tests of
//! [`GrowthRule`] (paper section 2.3); seeds' growth shared with their
//! neighbours ([`super::seeds`]).

use super::seeds::{ROBUST_SLACK, SEED_GROUP, SHARED_FROM_RING, pick_seeds, push_near_rings};
use crate::mesh::{RingWalker, Topology};
use crate::smoothing::label::{Label, agrees};
use crate::smoothing::neighbourhood::{BEAM_WIDTH, Neighbourhoods, Thinning, push_ring_sample};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::atomic::{AtomicU8, Ordering};

/// A grown neighbourhood keeps its inner rings whole only while they hold
/// at most `max_points / WHOLE_INNER_DIVISOR` points ([`push_thinned`](crate::smoothing::neighbourhood::push_thinned));
/// the rest of the budget samples the outer rings, so a large ring spreads
/// its fit over the whole disc. Keeping more of the budget for the inner
/// rings biases fits on large flat rings; keeping none loses the near
/// points that curved surfaces need (`docs/tuning.md`).
pub const WHOLE_INNER_DIVISOR: usize = 4;

/// How neighbourhoods may grow.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GrowthRule {
    /// Largest ring, `>= 2`.
    pub k_max: u32,
    /// Most fitted points per vertex.
    pub max_points: usize,
    /// Upper bound on the standard deviation of `H l` over the set.
    pub std_bound: f64,
    /// Largest rise of that standard deviation a new ring may cause.
    pub std_tolerance: f64,
    /// Upper bound on the expected outward bias of one projection,
    /// `rho^4 kappa^3 / 48`, in units of the mean edge length.
    pub bias_bound: f64,
    /// Mean edge length `l`.
    pub edge_length: f64,
    /// Label tolerances `t_H`, `t_K` (section 6).
    pub tolerance_h: f64,
    /// See `tolerance_h`.
    pub tolerance_k: f64,
    /// Margin of the label agreement test ([`agrees`]).
    pub label_margin: f64,
    /// Fraction of a ring's candidates that may disagree before growth
    /// stops (0: any disagreeing candidate stops it, the paper's rule).
    pub label_disagreement: f64,
}

/// Chosen neighbourhoods and the final ring size `k` of every vertex.
#[derive(Debug, Clone)]
pub struct AdaptiveNeighbourhoods {
    /// Thinned neighbour lists.
    pub hoods: Neighbourhoods,
    /// Final ring size per vertex (0 for isolated vertices).
    pub ring: Vec<u8>,
}

/// Running mean/variance of `H l` over a set.
#[derive(Clone, Copy, Default)]
struct Moments {
    n: f64,
    sum: f64,
    sum2: f64,
}

impl Moments {
    fn add(&mut self, x: f64) {
        self.n += 1.0;
        self.sum += x;
        self.sum2 += x * x;
    }
    fn std(&self) -> f64 {
        if self.n < 2.0 {
            return 0.0;
        }
        let m = self.sum / self.n;
        (self.sum2 / self.n - m * m).max(0.0).sqrt()
    }
}

/// Per vertex, from its curvature `(H, K)`: bit `b` is set when the vertex
/// agrees with label `b` under `rule`'s tolerances and margin ([`agrees`]).
/// Growth reads one byte per candidate instead of its curvature and four
/// comparisons.
pub fn agreement_masks(curvature: &[(f64, f64)], rule: &GrowthRule) -> Vec<u8> {
    let (l, th, tk, margin) = (
        rule.edge_length,
        rule.tolerance_h,
        rule.tolerance_k,
        rule.label_margin,
    );
    curvature
        .par_iter()
        .map(|&(h, k)| {
            Label::ALL
                .iter()
                .filter(|&&of| agrees(of, h, k, l, th, tk, margin))
                .fold(0u8, |mask, &of| mask | 1 << of as u8)
        })
        .collect()
}

/// Grows every vertex's neighbourhood by the rule above. `labels`,
/// `agreement` ([`agreement_masks`]), `h_scaled` (`H l`) and unit `normals`
/// have one entry per vertex, all from `positions`.
///
/// Seeds ([`pick_seeds`]) grow by the rule; a vertex next to a seed whose
/// growth passed every test with room to spare shares its outer rings
/// ([`SHARED_FROM_RING`], [`ROBUST_SLACK`]); the others grow themselves.
pub fn adaptive_neighbourhoods(
    topo: &Topology,
    positions: &[DVec3],
    labels: &[Label],
    agreement: &[u8],
    h_scaled: &[f32],
    normals: &[Vec3],
    rule: GrowthRule,
) -> AdaptiveNeighbourhoods {
    let ring: Vec<AtomicU8> = (0..topo.num_vertices()).map(|_| AtomicU8::new(0)).collect();
    let whole_inner = rule.max_points / WHOLE_INNER_DIVISOR;
    let grow_and_thin = |v: usize, w: &mut RingWalker, out: &mut Vec<u32>| {
        let growth = grow(
            topo, v, w, positions, normals, labels, agreement, h_scaled, rule,
        );
        let thinning = Thinning::plan(w, rule.max_points, whole_inner);
        thinning.push(w, out);
        (growth, thinning)
    };
    let own_rings = SHARED_FROM_RING - 1;
    let hoods = Neighbourhoods::build_chunked(
        topo,
        SEED_GROUP,
        |range, w| SeedGroup::grow(topo, range, w, &grow_and_thin),
        |group, v, w, out| {
            let i = v - group.first;
            // A seed whose growth was clear-cut and which carries `v`'s
            // label: `v`'s own seed, or else another seed next to it.
            let shares = |s: usize| {
                group.seed[s] as usize == s
                    && group.grown[s].growth.robust
                    && labels[v] == labels[group.first + s]
            };
            let own = group.seed[i] as usize;
            let next = topo.neighbors(v).iter().filter_map(|&j| {
                (j as usize)
                    .checked_sub(group.first)
                    .filter(|&l| l < group.seed.len())
            });
            let shared = if own == i {
                None
            } else {
                std::iter::once(own)
                    .chain(next)
                    .find(|&s| shares(s))
                    .map(|s| &group.grown[s])
            };
            let rings = if own == i {
                let seed = &group.grown[i];
                out.extend_from_slice(&group.lists[seed.list.clone()]);
                seed.growth.rings
            } else if let Some(seed) = shared
                && push_near_rings(topo, v, w, own_rings, whole_inner, &seed.thinning, out)
            {
                let near: usize = seed.thinning.quota[..=own_rings]
                    .iter()
                    .map(|&q| usize::from(q))
                    .sum();
                // The vertex is in its seed's first ring, never in these;
                // its own rings may hold a point or two more than the
                // seed's, which the outer samples make room for.
                let outer = &group.lists[seed.list.start + near..seed.list.end];
                let room = rule.max_points.saturating_sub(out.len());
                push_ring_sample(outer, room, out);
                seed.growth.rings
            } else {
                out.clear();
                grow_and_thin(v, w, out).0.rings
            };
            ring[v].store(rings, Ordering::Relaxed);
        },
    );
    AdaptiveNeighbourhoods {
        hoods,
        ring: ring.into_iter().map(AtomicU8::into_inner).collect(),
    }
}

/// What a seed's growth left in its [`SeedGroup`].
#[derive(Clone)]
struct Grown {
    growth: Growth,
    thinning: Thinning,
    /// Its thinned list in [`SeedGroup::lists`], ring by ring.
    list: Range<usize>,
}

/// The seeds of one group of vertices ([`SEED_GROUP`]) and their grown
/// neighbourhoods.
struct SeedGroup {
    first: usize,
    /// Per vertex of the group: the index in the group of its seed
    /// (itself for a seed), a vertex of the group at most one edge away.
    seed: Vec<u32>,
    /// Per vertex: its growth, when it is a seed.
    grown: Vec<Grown>,
    lists: Vec<u32>,
}

impl SeedGroup {
    /// Picks the seeds of `range` ([`pick_seeds`]) and grows them with
    /// `grow_and_thin`.
    fn grow(
        topo: &Topology,
        range: Range<usize>,
        w: &mut RingWalker,
        grow_and_thin: &impl Fn(usize, &mut RingWalker, &mut Vec<u32>) -> (Growth, Thinning),
    ) -> SeedGroup {
        let first = range.start;
        let seed = pick_seeds(topo, range);
        let mut grown = vec![
            Grown {
                growth: Growth::default(),
                thinning: Thinning::default(),
                list: 0..0,
            };
            seed.len()
        ];
        let mut lists = Vec::new();
        for (s, grown) in grown.iter_mut().enumerate() {
            if seed[s] as usize == s {
                let start = lists.len();
                let (growth, thinning) = grow_and_thin(first + s, w, &mut lists);
                *grown = Grown {
                    growth,
                    thinning,
                    list: start..lists.len(),
                };
            }
        }
        SeedGroup {
            first,
            seed,
            grown,
            lists,
        }
    }
}

/// The outcome of one vertex's growth ([`grow`]).
#[derive(Debug, Clone, Copy, Default)]
struct Growth {
    /// Rings kept.
    rings: u8,
    /// Whether it reached `k_max` with every test passed by a margin
    /// ([`ROBUST_SLACK`]).
    robust: bool,
}

/// Grows the walk at `v` by `rule`.
#[allow(clippy::too_many_arguments)]
fn grow(
    topo: &Topology,
    v: usize,
    w: &mut RingWalker,
    positions: &[DVec3],
    normals: &[Vec3],
    labels: &[Label],
    agreement: &[u8],
    h_scaled: &[f32],
    rule: GrowthRule,
) -> Growth {
    w.start(topo, v);
    // Every accepted ring within this fraction of each bound: robust.
    let keep = 1.0 - ROBUST_SLACK;
    let mut robust = true;
    let mut m = Moments::default();
    m.add(h_scaled[v].into());
    for _ in 0..2 {
        for &j in w.grow(topo) {
            m.add(h_scaled[j as usize].into());
        }
    }
    let centre = positions[v];
    let normal = normals[v].as_dvec3().normalize_or_zero();
    let own = 1u8 << labels[v] as u8;
    let mut s_k = m.std();
    SCRATCH.with_borrow_mut(|scratch| {
        while w.rings() < rule.k_max as usize {
            let candidates = w.grow_beam(topo, BEAM_WIDTH);
            if candidates.is_empty() {
                w.discard_last();
                break;
            }
            let ring = ring_stats(
                candidates, positions, centre, normal, agreement, own, h_scaled, scratch,
            );
            if ring.disagreeing as f64 > rule.label_disagreement * candidates.len() as f64 {
                w.discard_last();
                break;
            }
            robust &=
                ring.disagreeing as f64 <= keep * rule.label_disagreement * candidates.len() as f64;
            // A candidate at height `z` over the tangent plane and radius `rho`
            // implies a normal curvature `2 z / rho^2`; the largest over the ring
            // estimates `kappa_max`, and a fit out to the ring's mean radius
            // then sits `rho^4 kappa^3 / 48` above the surface.
            let rho2 = ring.radius2 / candidates.len() as f64;
            let kappa = 2.0 * ring.bend;
            let bias = rho2 * rho2 * kappa.powi(3) / 48.0;
            if bias > rule.bias_bound * rule.edge_length {
                w.discard_last();
                break;
            }
            robust &= bias <= keep * rule.bias_bound * rule.edge_length;
            let grown = Moments {
                n: m.n + candidates.len() as f64,
                sum: m.sum + ring.h_sum,
                sum2: m.sum2 + ring.h_sum2,
            };
            let s_next = grown.std();
            if !(s_next <= s_k + rule.std_tolerance && s_next <= rule.std_bound) {
                w.discard_last();
                break;
            }
            robust &= s_next <= s_k + keep * rule.std_tolerance && s_next <= keep * rule.std_bound;
            m = grown;
            s_k = s_next;
        }
    });
    // Rings 1 and 2 are always kept, even when a component is smaller.
    Growth {
        rings: w.rings() as u8,
        robust: robust && w.rings() == rule.k_max as usize,
    }
}

/// What the growth rule reads from the candidates of one new ring.
struct RingStats {
    /// Candidates that disagree with the vertex's label.
    disagreeing: usize,
    /// Sum of the candidates' `H l`.
    h_sum: f64,
    /// Sum of their squares.
    h_sum2: f64,
    /// Sum of their squared distances from the vertex's normal line.
    radius2: f64,
    /// Largest `|z| / rho^2` (height over the tangent plane by squared
    /// distance from the normal line) among them.
    bend: f64,
}

/// Independent partial sums in the ring statistics: candidate `k` of a
/// block goes to lane `k % LANES`, and the lanes are combined in a fixed
/// order, so the result does not depend on how the code is vectorised.
const LANES: usize = 4;

/// Candidates gathered per block of [`ring_stats`].
const BLOCK: usize = 64;

thread_local! {
    /// One [`RingScratch`] per thread, reused by every vertex's growth.
    static SCRATCH: std::cell::RefCell<RingScratch> = std::cell::RefCell::new(RingScratch::default());
}

/// One block of candidates in structure-of-arrays form, relative to the
/// growing vertex, zero-padded to whole lanes.
struct RingScratch {
    x: [f64; BLOCK],
    y: [f64; BLOCK],
    z: [f64; BLOCK],
    h: [f64; BLOCK],
}

impl Default for RingScratch {
    fn default() -> Self {
        RingScratch {
            x: [0.0; BLOCK],
            y: [0.0; BLOCK],
            z: [0.0; BLOCK],
            h: [0.0; BLOCK],
        }
    }
}

/// The [`RingStats`] of `candidates` around `centre` with unit `normal`;
/// `own` is the bit of the label they should agree with
/// ([`agreement_masks`]). The candidates are gathered a block at a time,
/// then the arithmetic runs in vector lanes (AVX2 where the CPU has it).
#[allow(clippy::too_many_arguments)]
#[inline]
fn ring_stats(
    candidates: &[u32],
    positions: &[DVec3],
    centre: DVec3,
    normal: DVec3,
    agreement: &[u8],
    own: u8,
    h_scaled: &[f32],
    scratch: &mut RingScratch,
) -> RingStats {
    let mut disagreeing = 0;
    let mut acc = RingLanes::default();
    for block in candidates.chunks(BLOCK) {
        for (k, &j) in block.iter().enumerate() {
            let j = j as usize;
            disagreeing += usize::from(agreement[j] & own == 0);
            let d = positions[j] - centre;
            (scratch.x[k], scratch.y[k], scratch.z[k]) = (d.x, d.y, d.z);
            scratch.h[k] = f64::from(h_scaled[j]);
        }
        let padded = block.len().next_multiple_of(LANES);
        for k in block.len()..padded {
            (scratch.x[k], scratch.y[k], scratch.z[k], scratch.h[k]) = (0.0, 0.0, 0.0, 0.0);
        }
        acc.add_block(scratch, padded, normal);
    }
    let total = |a: [f64; LANES]| (a[0] + a[1]) + (a[2] + a[3]);
    RingStats {
        disagreeing,
        h_sum: total(acc.h_sum),
        h_sum2: total(acc.h_sum2),
        radius2: total(acc.radius2),
        bend: acc
            .bend
            .into_iter()
            .fold(0.0, |m, b| if b > m { b } else { m }),
    }
}

/// Lane sums of [`ring_stats`].
#[derive(Default)]
struct RingLanes {
    h_sum: [f64; LANES],
    h_sum2: [f64; LANES],
    radius2: [f64; LANES],
    bend: [f64; LANES],
}

impl RingLanes {
    /// Adds the first `len` (a multiple of [`LANES`]) gathered candidates.
    #[inline]
    fn add_block(&mut self, s: &RingScratch, len: usize, normal: DVec3) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { self.add_block_avx2(s, len, normal) };
        }
        self.add_block_lanes(s, len, normal);
    }

    /// [`RingLanes::add_block_lanes`] compiled for AVX2 (same operations,
    /// same order: identical results).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn add_block_avx2(&mut self, s: &RingScratch, len: usize, normal: DVec3) {
        self.add_block_lanes(s, len, normal);
    }

    #[inline(always)]
    fn add_block_lanes(&mut self, s: &RingScratch, len: usize, normal: DVec3) {
        type Lanes = [f64; LANES];
        let at = |a: &[f64; BLOCK], k: usize| -> Lanes { std::array::from_fn(|i| a[k + i]) };
        let (mut h_sum, mut h_sum2) = (self.h_sum, self.h_sum2);
        let (mut radius2, mut bend) = (self.radius2, self.bend);
        for k in (0..len.min(BLOCK)).step_by(LANES) {
            let (x, y, zc, h) = (at(&s.x, k), at(&s.y, k), at(&s.z, k), at(&s.h, k));
            // As `DVec3::dot` and `length_squared` compute them.
            let z: Lanes =
                std::array::from_fn(|i| x[i] * normal.x + y[i] * normal.y + zc[i] * normal.z);
            let r2: Lanes = std::array::from_fn(|i| {
                let t = x[i] * x[i] + y[i] * y[i] + zc[i] * zc[i] - z[i] * z[i];
                if t > 0.0 { t } else { 0.0 }
            });
            // Finite and non-negative: plain comparisons instead of
            // `f64::max`'s NaN handling.
            let b: Lanes = std::array::from_fn(|i| {
                let q = z[i].abs() / r2[i];
                if r2[i] > 0.0 { q } else { 0.0 }
            });
            radius2 = std::array::from_fn(|i| radius2[i] + r2[i]);
            bend = std::array::from_fn(|i| if b[i] > bend[i] { b[i] } else { bend[i] });
            h_sum = std::array::from_fn(|i| h_sum[i] + h[i]);
            h_sum2 = std::array::from_fn(|i| h_sum2[i] + h[i] * h[i]);
        }
        (self.h_sum, self.h_sum2, self.radius2, self.bend) = (h_sum, h_sum2, radius2, bend);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::smoothing::neighbourhood::{CHUNK, push_thinned};

    #[test]
    fn ring_statistics_match_a_plain_loop_over_the_candidates() {
        // More candidates than one block, one of them on the normal line.
        let n = 150;
        let positions: Vec<DVec3> = (0..n)
            .map(|i| {
                let t = i as f64;
                DVec3::new((t * 0.37).sin() * t, (t * 0.73).cos() * t, (t * 0.11).sin())
            })
            .collect();
        let h_scaled: Vec<f32> = (0..n).map(|i| (i as f32 * 0.01).sin()).collect();
        let agreement: Vec<u8> = (0..n)
            .map(|i| if i % 3 == 0 { 0b0010 } else { 0b0001 })
            .collect();
        let centre = DVec3::new(0.0, 0.0, 0.5);
        let normal = DVec3::Z;
        let mut candidates: Vec<u32> = (1..n as u32).rev().collect();
        candidates.push(0);
        let mut positions = positions;
        positions[0] = centre + 2.0 * normal;
        let mut scratch = RingScratch::default();
        let got = ring_stats(
            &candidates,
            &positions,
            centre,
            normal,
            &agreement,
            0b0001,
            &h_scaled,
            &mut scratch,
        );
        let (mut h_sum, mut h_sum2, mut radius2, mut bend) = (0.0, 0.0, 0.0, 0.0f64);
        for &j in &candidates {
            let h = f64::from(h_scaled[j as usize]);
            h_sum += h;
            h_sum2 += h * h;
            let d = positions[j as usize] - centre;
            let z = d.dot(normal);
            let r2 = (d.length_squared() - z * z).max(0.0);
            radius2 += r2;
            if r2 > 0.0 {
                bend = bend.max(z.abs() / r2);
            }
        }
        assert_eq!(
            got.disagreeing,
            candidates.iter().filter(|&&j| j % 3 == 0).count()
        );
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
        assert!(close(got.h_sum, h_sum), "{} vs {h_sum}", got.h_sum);
        assert!(close(got.h_sum2, h_sum2));
        assert!(close(got.radius2, radius2));
        assert_eq!(got.bend, bend, "a maximum has no rounding");
        assert!(bend > 0.0 && bend.is_finite());
    }

    /// A flat `n` x `n` grid of unit quads, every vertex labelled flat,
    /// and a growth rule for it.
    fn flat_grid(n: u32, k_max: u32) -> (crate::Mesh, Topology, GrowthRule) {
        let mesh = crate::mesh::test_grid(n);
        let topo = Topology::build(&mesh);
        let rule = GrowthRule {
            k_max,
            max_points: 56,
            std_bound: 0.05,
            std_tolerance: 0.005,
            bias_bound: 0.06,
            edge_length: 1.0,
            tolerance_h: 0.04,
            tolerance_k: 0.002,
            label_margin: 0.04,
            label_disagreement: 0.25,
        };
        (mesh, topo, rule)
    }

    /// Every vertex's neighbourhood grown by itself, as if no seed shared.
    fn grown_alone(
        topo: &Topology,
        positions: &[DVec3],
        rule: GrowthRule,
    ) -> (Vec<Vec<u32>>, Vec<u8>) {
        let n = topo.num_vertices();
        let (labels, agreement) = (vec![Label::Flat; n], vec![1u8; n]);
        let (h, normals) = (vec![0.0f32; n], vec![Vec3::Z; n]);
        let mut w = RingWalker::default();
        (0..n)
            .map(|v| {
                let g = grow(
                    topo, v, &mut w, positions, &normals, &labels, &agreement, &h, rule,
                );
                let mut list = Vec::new();
                push_thinned(
                    &w,
                    rule.max_points,
                    rule.max_points / WHOLE_INNER_DIVISOR,
                    &mut list,
                );
                list.sort_unstable();
                (list, g.rings)
            })
            .unzip()
    }

    fn neighbourhoods(
        topo: &Topology,
        positions: &[DVec3],
        rule: GrowthRule,
    ) -> AdaptiveNeighbourhoods {
        let n = topo.num_vertices();
        adaptive_neighbourhoods(
            topo,
            positions,
            &vec![Label::Flat; n],
            &vec![1u8; n],
            &vec![0.0; n],
            &vec![Vec3::Z; n],
            rule,
        )
    }

    #[test]
    fn every_vertex_has_a_seed_at_most_one_edge_away_in_its_group() {
        let (_, topo, _) = flat_grid(70, 8);
        let n = topo.num_vertices();
        assert!(n > SEED_GROUP * CHUNK);
        let mut seeds = 0;
        for first in (0..n).step_by(SEED_GROUP * CHUNK) {
            let range = first..(first + SEED_GROUP * CHUNK).min(n);
            let grown = std::cell::Cell::new(0);
            let chunk = SeedGroup::grow(
                &topo,
                range.clone(),
                &mut RingWalker::default(),
                &|v, _, out| {
                    grown.set(grown.get() + 1);
                    out.push(v as u32);
                    (Growth::default(), Thinning::default())
                },
            );
            for (i, &s) in chunk.seed.iter().enumerate() {
                let (v, s) = (first + i, first + s as usize);
                assert!(range.contains(&s), "vertex {v}: seed {s} outside its group");
                assert!(
                    s == v || topo.neighbors(v).contains(&(s as u32)),
                    "vertex {v}: seed {s}"
                );
                assert_eq!(
                    chunk.seed[s - first] as usize,
                    s - first,
                    "a seed is its own seed"
                );
                let list = &chunk.lists[chunk.grown[s - first].list.clone()];
                assert_eq!(list, [s as u32], "the seed's own growth");
            }
            let here = chunk
                .seed
                .iter()
                .enumerate()
                .filter(|&(i, &s)| s as usize == i)
                .count();
            assert_eq!(grown.get(), here, "each seed grown once");
            seeds += here;
        }
        // A grid needs a fifth of its vertices at best; greedy picking in
        // vertex order stays close.
        assert!(seeds * 10 < 3 * n, "{seeds} seeds of {n}");
    }

    #[test]
    fn a_vertex_grows_itself_unless_its_seed_reached_k_max() {
        // Rings run out at the grid's edge before k_max: no seed is robust,
        // and every list is the vertex's own growth.
        let (mesh, topo, rule) = flat_grid(12, 32);
        let got = neighbourhoods(&topo, mesh.positions(), rule);
        let (lists, rings) = grown_alone(&topo, mesh.positions(), rule);
        let mut list = Vec::new();
        for (v, alone) in lists.iter().enumerate() {
            got.hoods.get_into(v, &mut list);
            assert_eq!(&list, alone, "vertex {v}");
        }
        assert_eq!(got.ring, rings);
    }

    #[test]
    fn shared_neighbourhoods_keep_the_vertex_near_rings() {
        let (mesh, topo, rule) = flat_grid(70, 10);
        let got = neighbourhoods(&topo, mesh.positions(), rule);
        let (lists, rings) = grown_alone(&topo, mesh.positions(), rule);
        let mut w = RingWalker::default();
        let (mut list, mut shared) = (Vec::new(), 0);
        let (mut points, mut alone) = (0, 0);
        for v in 0..topo.num_vertices() {
            got.hoods.get_into(v, &mut list);
            if list == lists[v] {
                assert_eq!(got.ring[v], rings[v]);
                continue;
            }
            // Shared: the seed reached k_max, and so does the vertex.
            shared += 1;
            assert_eq!(got.ring[v], 10);
            assert_eq!(rings[v], 10, "vertex {v}");
            // A point or two of the seed's may repeat one of the vertex's.
            assert!(list.len() <= rule.max_points && 4 * list.len() >= 3 * lists[v].len());
            (points, alone) = (points + list.len(), alone + lists[v].len());
            assert!(!list.contains(&(v as u32)));
            // Rings 1 and 2 whole, and every point within the vertex's
            // own 11-ring.
            w.k_ring(&topo, v, 2);
            assert!(w.found().iter().all(|j| list.contains(j)), "vertex {v}");
            w.k_ring(&topo, v, 11);
            assert!(list.iter().all(|j| w.found().contains(j)), "vertex {v}");
        }
        assert!(shared * 2 > topo.num_vertices(), "{shared} shared");
        assert!(
            points * 10 >= alone * 9,
            "{points} points shared, {alone} alone"
        );
    }
}
