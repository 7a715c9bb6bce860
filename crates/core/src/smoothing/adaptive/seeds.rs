//! Seeds of the adaptive neighbourhoods: the vertices that grow by the
//! rule and whose clear-cut growth their neighbours share.

use crate::mesh::{RingWalker, Topology};
use crate::smoothing::neighbourhood::{BEAM_WIDTH, Thinning, push_ring_sample, whole_inner_rings};
use std::ops::Range;

/// A vertex sharing its seed's neighbourhood walks its own rings below
/// this one and takes the seed's thinned samples from this ring out
/// ([`adaptive_neighbourhoods`](super::adaptive_neighbourhoods)): the fit's near points, which weigh most,
/// stay centred on the vertex, and the long walk out to `k_max` rings is
/// made once per seed. A vertex shares when its seed (or, failing that,
/// another seed next to it) carries its label and grew to `k_max` with
/// every test passed with room to spare ([`ROBUST_SLACK`]), so the
/// vertex's own growth would very likely have reached `k_max` too. The
/// seeds cover every vertex within one edge and are about a quarter of the
/// vertices of a voxel sphere ([`SEED_GROUP`]). From this ring out the
/// seed's samples are as good as the vertex's own: sharing from here
/// keeps the analytic shapes' accuracy within the noise of growing every
/// vertex, at a fraction of the walking; sharing without the margins, or
/// seeds two edges away, cost accuracy (`docs/tuning.md`).
pub const SHARED_FROM_RING: usize = 5;

/// Seeds are picked among the vertices of a group of this many chunks of
/// lists ([`Neighbourhoods::build_chunked`](crate::smoothing::neighbourhood::Neighbourhoods::build_chunked), [`pick_seeds`]): a vertex's
/// seed lies in its group, and on a voxel sphere the rows of the next
/// slice fall in the same group of 4096 vertices far more often than in
/// the same chunk of 1024, so fewer vertices are seeds. Larger groups
/// gain little more and hold more lists at once (`docs/tuning.md`).
pub const SEED_GROUP: usize = 4;

/// A seed's growth is shared ([`SHARED_FROM_RING`]) only when every ring
/// it accepted passed each test of [`GrowthRule`](super::GrowthRule) within `1 - ROBUST_SLACK`
/// of its bound (label disagreement, bias, the rise and the bound of the
/// curvature spread): a seed that passed its tests only narrowly could
/// have stopped earlier for a neighbour. Accuracy barely moves between
/// 0.3 and 0.6 while a smaller slack lets more vertices share
/// (`docs/tuning.md`).
pub const ROBUST_SLACK: f64 = 0.3;

/// Seeds for the vertices of `range` (a group of chunks,
/// [`Neighbourhoods::build_chunked`](crate::smoothing::neighbourhood::Neighbourhoods::build_chunked)): for each, the index in `range` of
/// its seed, itself or a neighbour in `range`, so every vertex is at most
/// one edge from its seed. In vertex order, each vertex not yet next to a
/// seed makes a seed of whichever of itself and its neighbours in `range`
/// is next to the most vertices without one (the last on ties): on a voxel
/// sphere about a quarter of the vertices are seeds with ranges of 4096.
pub fn pick_seeds(topo: &Topology, range: Range<usize>) -> Vec<u32> {
    const NONE: u32 = u32::MAX;
    let first = range.start;
    let local = |j: u32| (j as usize).checked_sub(first).filter(|&l| l < range.len());
    let mut seed = vec![NONE; range.len()];
    let unseeded = |seed: &[u32], c: usize| {
        usize::from(seed[c] == NONE)
            + topo
                .neighbors(first + c)
                .iter()
                .filter(|&&j| local(j).is_some_and(|l| seed[l] == NONE))
                .count()
    };
    for v in 0..range.len() {
        if seed[v] != NONE {
            continue;
        }
        let (mut s, mut best) = (v, unseeded(&seed, v));
        for l in topo.neighbors(first + v).iter().filter_map(|&j| local(j)) {
            let c = unseeded(&seed, l);
            if c > best || (c == best && l > s) {
                (s, best) = (l, c);
            }
        }
        seed[s] = s as u32;
        for &j in topo.neighbors(first + s) {
            if let Some(l) = local(j)
                && seed[l] == NONE
            {
                seed[l] = s as u32;
            }
        }
    }
    seed
}

/// Walks vertex `v`'s first `rings` rings as growth does and appends them:
/// its inner rings whole as [`push_thinned`](crate::smoothing::neighbourhood::push_thinned) keeps them, the others thinned
/// to the quotas of `thinning` (its seed's). False, with `out` partly
/// written, when `v` keeps all `rings` whole or its component ends first.
pub fn push_near_rings(
    topo: &Topology,
    v: usize,
    w: &mut RingWalker,
    rings: usize,
    whole_inner: usize,
    thinning: &Thinning,
    out: &mut Vec<u32>,
) -> bool {
    w.start(topo, v);
    for r in 0..rings {
        let beam = if r < 2 { usize::MAX } else { BEAM_WIDTH };
        if w.grow_beam(topo, beam).is_empty() {
            return false;
        }
    }
    let kept_rings = whole_inner_rings(w, rings, whole_inner);
    if kept_rings == rings {
        return false;
    }
    for r in 1..=rings {
        let quota = if r <= kept_rings {
            usize::MAX
        } else {
            usize::from(thinning.quota[r])
        };
        push_ring_sample(w.ring(r), quota, out);
    }
    true
}
