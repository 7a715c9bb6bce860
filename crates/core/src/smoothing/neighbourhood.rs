//! Fitting neighbourhoods: for each vertex, the neighbours its quadric is
//! fitted to, in one flat CSR array built once (connectivity never changes,
//! so neither do the neighbourhoods).

use crate::mesh::{RingWalker, Topology};
use half::f16;
use rayon::prelude::*;
use std::cell::RefCell;
use std::ops::Range;

/// Per-vertex neighbour lists in CSR form, stored in the chunks they were
/// built in (one copy, no concatenation: the lists are the largest arrays of
/// a run).
#[derive(Debug, Clone, Default)]
pub struct Neighbourhoods {
    /// `offsets[v]..offsets[v + 1]`: vertex `v`'s entries, counted from the
    /// start of its chunk.
    offsets: Vec<u32>,
    /// Entries of vertices `c * CHUNK..(c + 1) * CHUNK`.
    chunks: Vec<Vec<u32>>,
}

/// One weight per entry of a [`Neighbourhoods`] (the linear fit weights of
/// the adaptive passes), in the same chunks. Half precision (11 significant
/// bits): the weights are stored for every neighbour of every vertex, and
/// a weight's rounding moves a vertex by far less than its fit's own error.
#[derive(Debug, Clone, Default)]
pub struct NeighbourWeights {
    chunks: Vec<Vec<f16>>,
}

impl NeighbourWeights {
    /// The weights of vertex `v`'s neighbours in `hoods` (the lists these
    /// weights were made for, [`Neighbourhoods::zero_weights`]).
    #[inline]
    pub fn get(&self, hoods: &Neighbourhoods, v: usize) -> &[f16] {
        &self.chunks[v / CHUNK][hoods.span(v)]
    }

    /// Every chunk of `CHUNK` vertices with a function giving vertex `v`'s
    /// weights (`v` counted in the whole mesh) inside it, for filling the
    /// chunks in parallel.
    pub fn chunks_mut<'a>(
        &'a mut self,
        hoods: &'a Neighbourhoods,
    ) -> impl Iterator<Item = ChunkWeights<'a>> {
        self.chunks
            .iter_mut()
            .enumerate()
            .map(move |(c, weights)| ChunkWeights {
                first: c * CHUNK,
                weights,
                hoods,
            })
    }
}

/// The weights of one chunk of vertices ([`NeighbourWeights::chunks_mut`]).
pub struct ChunkWeights<'a> {
    first: usize,
    weights: &'a mut [f16],
    hoods: &'a Neighbourhoods,
}

impl ChunkWeights<'_> {
    /// The weights of vertex `v`, which must lie in this chunk.
    #[inline]
    pub fn get_mut(&mut self, v: usize) -> &mut [f16] {
        debug_assert!(v - self.first < CHUNK);
        &mut self.weights[self.hoods.span(v)]
    }
}

thread_local! {
    static WALKER: RefCell<RingWalker> = RefCell::new(RingWalker::default());
    static LIST: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
}

/// Vertices per chunk of stored lists (and per parallel work item when
/// building them).
pub const CHUNK: usize = 1024;

impl Neighbourhoods {
    /// Neighbours of vertex `v`.
    #[inline]
    pub fn get(&self, v: usize) -> &[u32] {
        &self.chunks[v / CHUNK][self.span(v)]
    }

    /// Where vertex `v`'s entries lie in its chunk (`v / CHUNK`).
    #[inline]
    fn span(&self, v: usize) -> Range<usize> {
        let start = self.offsets[v] as usize;
        // The last vertex of a chunk ends at the chunk's end.
        let end = if (v + 1).is_multiple_of(CHUNK) {
            self.chunks[v / CHUNK].len()
        } else {
            self.offsets[v + 1] as usize
        };
        start..end
    }

    /// One zero weight per stored entry, laid out like the lists.
    pub fn zero_weights(&self) -> NeighbourWeights {
        NeighbourWeights {
            chunks: self
                .chunks
                .iter()
                .map(|c| vec![f16::ZERO; c.len()])
                .collect(),
        }
    }

    /// Number of vertices covered.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// True when no vertex is covered.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Total number of stored neighbour entries.
    pub fn total(&self) -> usize {
        self.chunks.iter().map(Vec::len).sum()
    }

    /// Builds the lists with `select(v, walker, out)`, which appends vertex
    /// `v`'s neighbours to `out` using a thread-local [`RingWalker`]. Runs in
    /// parallel; the result does not depend on the thread count.
    pub fn build<F>(topo: &Topology, select: F) -> Neighbourhoods
    where
        F: Fn(usize, &mut RingWalker, &mut Vec<u32>) + Sync,
    {
        let n = topo.num_vertices();
        let built: Vec<(Vec<u32>, Vec<u32>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let range = c * CHUNK..((c + 1) * CHUNK).min(n);
                let mut starts = Vec::with_capacity(range.len());
                // Built in a reused thread-local list and copied out at its
                // exact size: no growing and shrinking of a list per chunk.
                let out = WALKER.with(|w| {
                    LIST.with(|out| {
                        let (mut w, mut out) = (w.borrow_mut(), out.borrow_mut());
                        out.clear();
                        for v in range {
                            starts.push(out.len() as u32);
                            select(v, &mut w, &mut out);
                        }
                        out.to_vec()
                    })
                });
                (starts, out)
            })
            .collect();
        let mut offsets = Vec::with_capacity(n + 1);
        let mut chunks = Vec::with_capacity(built.len());
        for (starts, out) in built {
            offsets.extend_from_slice(&starts);
            chunks.push(out);
        }
        offsets.push(chunks.last().map_or(0, |c| c.len() as u32));
        Neighbourhoods { offsets, chunks }
    }

    /// `f(v, neighbours)` for every vertex, with the neighbours chosen by
    /// `select` as in [`Neighbourhoods::build`] but never stored: for
    /// neighbourhoods used once, at the cost of one thread-local list.
    /// Runs in parallel; the result does not depend on the thread count.
    pub fn map<T, S, F>(topo: &Topology, select: S, f: F) -> Vec<T>
    where
        T: Send,
        S: Fn(usize, &mut RingWalker, &mut Vec<u32>) + Sync,
        F: Fn(usize, &[u32]) -> T + Sync,
    {
        (0..topo.num_vertices())
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|v| {
                WALKER.with(|w| {
                    LIST.with(|out| {
                        let mut out = out.borrow_mut();
                        out.clear();
                        select(v, &mut w.borrow_mut(), &mut out);
                        f(v, &out)
                    })
                })
            })
            .collect()
    }

    /// The 2-ring of every vertex, thinned to at most `max_points` (ring 1
    /// kept whole when it fits).
    pub fn two_ring(topo: &Topology, max_points: usize) -> Neighbourhoods {
        Neighbourhoods::build(topo, |v, w, out| {
            w.start(topo, v);
            w.grow(topo);
            w.grow(topo);
            push_thinned(w, max_points, max_points / 2, out);
        })
    }
}

/// Appends the walker's rings to `out`, at most `max_points` of them: inner
/// rings are kept whole while they total at most `whole_inner` points, and
/// the remaining budget is shared among the outer rings in proportion to
/// their sizes, each thinned by an even stride so the points stay spread
/// around the vertex.
pub fn push_thinned(w: &RingWalker, max_points: usize, whole_inner: usize, out: &mut Vec<u32>) {
    let all = w.found();
    if all.len() <= max_points {
        out.extend_from_slice(all);
        return;
    }
    // Keep whole rings from the inside while they fit.
    let mut kept_rings = 0;
    let mut kept = 0;
    while kept_rings < w.rings() && kept + w.ring(kept_rings + 1).len() <= whole_inner {
        kept += w.ring(kept_rings + 1).len();
        kept_rings += 1;
    }
    out.extend_from_slice(&all[..kept]);
    let rest = &all[kept..];
    let budget = max_points - kept;
    // Spread the budget over the outer rings by their sizes.
    let mut taken = 0usize;
    let mut seen = 0usize;
    for r in kept_rings + 1..=w.rings() {
        let ring = w.ring(r);
        seen += ring.len();
        let quota = budget * seen / rest.len() - taken;
        taken += quota;
        if quota == 0 {
            continue;
        }
        let step = ring.len() as f64 / quota as f64;
        for q in 0..quota {
            let idx = ((q as f64 + 0.5) * step) as usize;
            out.push(ring[idx.min(ring.len() - 1)]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_grid as grid;

    #[test]
    fn lists_match_the_walk_across_chunk_boundaries() {
        let m = grid(50);
        let t = Topology::build(&m);
        assert!(t.num_vertices() > 2 * CHUNK);
        let hoods = Neighbourhoods::two_ring(&t, 512);
        assert_eq!(hoods.len(), t.num_vertices());
        let mut w = RingWalker::default();
        let mut total = 0;
        for v in 0..t.num_vertices() {
            assert_eq!(hoods.get(v), w.k_ring(&t, v, 2), "vertex {v}");
            total += hoods.get(v).len();
        }
        assert_eq!(hoods.total(), total);
    }
}
