//! Fitting neighbourhoods: for each vertex, the neighbours its quadric is
//! fitted to, in one flat CSR array built once (connectivity never changes,
//! so neither do the neighbourhoods).
//!
//! The lists are the largest arrays of a run (56 neighbours a vertex by
//! default), so they are stored compressed ([`Neighbourhoods`]): each list
//! sorted, as 16-bit gaps between consecutive entries. Meshes from voxel
//! grids, marching cubes and most writers number nearby vertices closely,
//! so nearly every gap fits; a larger one takes an escape and 32 bits.

use crate::mesh::{RingWalker, Topology};
use crate::sort::sort_short;
use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;
use std::cell::RefCell;
use std::ops::Range;

/// Per-vertex neighbour lists in CSR form, stored in the chunks they were
/// built in (one copy, no concatenation).
///
/// A list is stored in 16-bit units: its smallest entry in two units (low,
/// high half), then each following entry (in ascending order) as its gap to
/// the one before, one unit when the gap is below `ESCAPE` (`0xFFFF`), else the unit
/// `ESCAPE` and two units for the gap. Entry `i` starts at a unit of its
/// own, which is where [`NeighbourWeights`] keeps its weight.
#[derive(Debug, Clone, Default)]
pub struct Neighbourhoods {
    /// `offsets[v]..offsets[v + 1]`: vertex `v`'s units, counted from the
    /// start of its chunk.
    offsets: Vec<u32>,
    /// Units of vertices `c * CHUNK..(c + 1) * CHUNK`.
    chunks: Vec<Vec<u16>>,
}

/// The unit announcing a gap too large for one unit.
const ESCAPE: u16 = u16::MAX;

/// One weight per stored unit of a [`Neighbourhoods`] (the linear fit
/// weights of the adaptive passes), in the same chunks: entry `i`'s weight
/// sits at entry `i`'s first unit, the other units' weights are unused.
/// Half precision (11 significant bits): the weights are stored for every
/// neighbour of every vertex, and a weight's rounding moves a vertex by far
/// less than its fit's own error.
#[derive(Debug, Clone, Default)]
pub struct NeighbourWeights {
    chunks: Vec<Vec<f16>>,
}

impl NeighbourWeights {
    /// Vertex `v`'s weights in `hoods` (the lists these weights were made
    /// for, [`Neighbourhoods::zero_weights`]), one per unit: the weight of
    /// the entry starting at unit `u` ([`Neighbourhoods::entries`]) is
    /// element `u`.
    #[inline]
    pub fn get(&self, hoods: &Neighbourhoods, v: usize) -> &[f16] {
        &self.chunks[v / CHUNK][hoods.span(v)]
    }

    /// Vertex `v`'s weights in `hoods` converted to single precision into
    /// `out` (cleared first), laid out as [`NeighbourWeights::get`]: one
    /// vector conversion instead of one per weight.
    #[inline]
    pub fn get_f32_into(&self, hoods: &Neighbourhoods, v: usize, out: &mut Vec<f32>) {
        widen_into(self.get(hoods, v), out);
    }

    /// Every chunk of `CHUNK` vertices with a function setting vertex `v`'s
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

/// `w` converted to single precision into `out` (replacing its contents),
/// eight at a time with F16C where the CPU has it (one call a list; the
/// `half` crate's slice conversion makes one a chunk), else by `half`. The
/// conversion is exact either way. (`out` is resized, not cleared first:
/// the conversion overwrites every entry, and a cleared buffer would be
/// zeroed anew for every vertex.)
#[inline]
fn widen_into(w: &[f16], out: &mut Vec<f32>) {
    out.resize(w.len(), 0.0);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("f16c") && std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU supports F16C and AVX (checked just above).
        return unsafe { widen_f16c(w, out) };
    }
    w.convert_to_f32_slice(out);
}

/// [`widen_into`]'s conversion with F16C, `w` and `out` of equal length.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,f16c")]
fn widen_f16c(w: &[f16], out: &mut [f32]) {
    use std::arch::x86_64::{__m128i, _mm_loadu_si128, _mm256_cvtph_ps, _mm256_storeu_ps};
    let convert = |h: &[f16; 8], f: &mut [f32; 8]| {
        // SAFETY: 8 halves (16 bytes) in, 8 singles (32 bytes) out, both
        // unaligned accesses within the arrays.
        unsafe {
            let x = _mm256_cvtph_ps(_mm_loadu_si128(h.as_ptr().cast::<__m128i>()));
            _mm256_storeu_ps(f.as_mut_ptr(), x);
        }
    };
    let mut hs = w.chunks_exact(8);
    let mut fs = out.chunks_exact_mut(8);
    for (h, f) in (&mut hs).zip(&mut fs) {
        if let (Ok(h), Ok(f)) = (<&[f16; 8]>::try_from(h), <&mut [f32; 8]>::try_from(f)) {
            convert(h, f);
        }
    }
    let (h_rest, f_rest) = (hs.remainder(), fs.into_remainder());
    let mut h = [f16::ZERO; 8];
    let mut f = [0.0f32; 8];
    h[..h_rest.len()].copy_from_slice(h_rest);
    convert(&h, &mut f);
    f_rest.copy_from_slice(&f[..f_rest.len()]);
}

/// The weights of one chunk of vertices ([`NeighbourWeights::chunks_mut`]).
pub struct ChunkWeights<'a> {
    first: usize,
    weights: &'a mut [f16],
    hoods: &'a Neighbourhoods,
}

impl<'a> ChunkWeights<'a> {
    /// The lists these weights are laid out like.
    pub fn hoods(&self) -> &'a Neighbourhoods {
        self.hoods
    }

    /// Vertex `v`'s weights, which must lie in this chunk, as
    /// [`NeighbourWeights::get_f32_into`] gives them.
    pub fn get_f32_into(&self, v: usize, out: &mut Vec<f32>) {
        debug_assert!(v - self.first < CHUNK);
        widen_into(&self.weights[self.hoods.span(v)], out);
    }

    /// Sets vertex `v`'s weights, which must lie in this chunk, rounded to
    /// half precision: `by_entry[i]` is the weight of its `i`-th neighbour
    /// in ascending order (the order of [`Neighbourhoods::get_into`]);
    /// missing ones are 0.
    pub fn set(&mut self, v: usize, by_entry: &[f32]) {
        debug_assert!(v - self.first < CHUNK);
        let span = self.hoods.span(v);
        let units = &mut self.weights[span];
        units.fill(f16::ZERO);
        if let ([first, _, rest @ ..], [w0, by_rest @ ..]) = (&mut *units, by_entry)
            && rest.len() == by_rest.len()
        {
            // No escape: entry `i > 0` is unit `i + 1`; one vector
            // conversion.
            *first = f16::from_f32(*w0);
            rest.convert_from_f32_slice(by_rest);
            return;
        }
        for ((unit, _), &w) in self.hoods.entries(v).zip(by_entry) {
            units[unit] = f16::from_f32(w);
        }
    }
}

/// The entries of one stored list with the unit each starts at
/// ([`Neighbourhoods::entries`]).
#[derive(Debug, Clone)]
pub struct Entries<'a> {
    units: &'a [u16],
    next: usize,
    value: u32,
}

impl Iterator for Entries<'_> {
    /// `(unit, neighbour)`.
    type Item = (usize, u32);

    #[inline]
    fn next(&mut self) -> Option<(usize, u32)> {
        let at = self.next;
        let gap = *self.units.get(at)?;
        if at == 0 {
            let high = self.units.get(1).copied().unwrap_or(0);
            self.value = u32::from(gap) | u32::from(high) << 16;
            self.next = 2;
        } else if gap != ESCAPE {
            self.value = self.value.wrapping_add(u32::from(gap));
            self.next = at + 1;
        } else {
            let low = self.units.get(at + 1).copied().unwrap_or(0);
            let high = self.units.get(at + 2).copied().unwrap_or(0);
            self.value = self
                .value
                .wrapping_add(u32::from(low) | u32::from(high) << 16);
            self.next = at + 3;
        }
        Some((at, self.value))
    }
}

/// Appends the sorted, distinct `entries` to `out` in the stored form
/// ([`Neighbourhoods`]).
fn encode(entries: &[u32], out: &mut Vec<u16>) {
    let Some((&first, rest)) = entries.split_first() else {
        return;
    };
    out.extend([first as u16, (first >> 16) as u16]);
    let mut prev = first;
    for &e in rest {
        let gap = e - prev;
        if gap < u32::from(ESCAPE) {
            out.push(gap as u16);
        } else {
            out.extend([ESCAPE, gap as u16, (gap >> 16) as u16]);
        }
        prev = e;
    }
}

thread_local! {
    static WALKER: RefCell<RingWalker> = RefCell::new(RingWalker::default());
    static LIST: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
    static UNITS: RefCell<Vec<u16>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's ring walker, the one the neighbourhoods
/// walk with (freed with the rest by [`release_walk_scratch`]): a walk per
/// vertex in a parallel loop allocates no stamp of its own.
pub fn with_walker<R>(f: impl FnOnce(&mut RingWalker) -> R) -> R {
    WALKER.with(|w| f(&mut w.borrow_mut()))
}

/// Frees the scratch every thread of the pool keeps for walking rings (a
/// 4-byte stamp per mesh vertex per thread, and the last chunk's lists):
/// before the adaptive passes, where a run's memory peaks and no ring is
/// walked. The next walk allocates it again.
pub fn release_walk_scratch() {
    rayon::broadcast(|_| {
        WALKER.with(|w| *w.borrow_mut() = RingWalker::default());
        LIST.with(|l| *l.borrow_mut() = Vec::new());
        UNITS.with(|u| *u.borrow_mut() = Vec::new());
    });
}

/// Vertices per chunk of stored lists (and per parallel work item when
/// building them).
pub const CHUNK: usize = 1024;

impl Neighbourhoods {
    /// Vertex `v`'s neighbours in ascending order, each with the unit its
    /// stored form starts at (see [`NeighbourWeights::get`]).
    #[inline]
    pub fn entries(&self, v: usize) -> Entries<'_> {
        Entries {
            units: &self.chunks[v / CHUNK][self.span(v)],
            next: 0,
            value: 0,
        }
    }

    /// Writes vertex `v`'s neighbours, in ascending order, to `out`
    /// (cleared first).
    #[inline]
    pub fn get_into(&self, v: usize, out: &mut Vec<u32>) {
        out.clear();
        out.extend(self.entries(v).map(|(_, j)| j));
    }

    /// Where vertex `v`'s units lie in its chunk (`v / CHUNK`).
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

    /// One zero weight per stored unit, laid out like the lists.
    pub fn zero_weights(&self) -> NeighbourWeights {
        NeighbourWeights {
            chunks: self
                .chunks
                .iter()
                .map(|c| vec![f16::ZERO; c.len()])
                .collect(),
        }
    }

    #[cfg(test)]
    /// Number of vertices covered.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    #[cfg(test)]
    /// Total number of stored 16-bit units (the lists' memory is twice
    /// this in bytes).
    pub fn units(&self) -> usize {
        self.chunks.iter().map(Vec::len).sum()
    }

    #[cfg(test)]
    /// Builds the lists with `select(v, walker, out)`, which appends vertex
    /// `v`'s neighbours (distinct, in any order) to `out` using a
    /// thread-local [`RingWalker`]. Runs in parallel; the result does not
    /// depend on the thread count.
    pub fn build<F>(topo: &Topology, select: F) -> Neighbourhoods
    where
        F: Fn(usize, &mut RingWalker, &mut Vec<u32>) + Sync,
    {
        Neighbourhoods::build_chunked(topo, 1, |_, _| (), |(), v, w, out| select(v, w, out))
    }

    /// Like [`Neighbourhoods::build`], with state per group of `group`
    /// chunks of [`CHUNK`] vertices: `prepare(range, walker)` runs first for
    /// each group (`range`), then `select(&state, v, walker, out)` for each
    /// of its vertices in order. `select` may append an entry more than
    /// once. The groups are fixed, so the result does not depend on the
    /// thread count.
    pub fn build_chunked<S, P, F>(
        topo: &Topology,
        group: usize,
        prepare: P,
        select: F,
    ) -> Neighbourhoods
    where
        P: Fn(Range<usize>, &mut RingWalker) -> S + Sync,
        F: Fn(&S, usize, &mut RingWalker, &mut Vec<u32>) + Sync,
    {
        let n = topo.num_vertices();
        let span = group.max(1) * CHUNK;
        let built: Vec<(Vec<u32>, Vec<u16>)> = (0..n.div_ceil(span))
            .into_par_iter()
            .flat_map_iter(|g| {
                let range = g * span..((g + 1) * span).min(n);
                // Built in reused thread-local lists and copied out at each
                // chunk's exact size: no growing and shrinking of a list per
                // chunk.
                WALKER.with(|w| {
                    LIST.with(|list| {
                        UNITS.with(|units| {
                            let (mut w, mut list, mut units) =
                                (w.borrow_mut(), list.borrow_mut(), units.borrow_mut());
                            let state = prepare(range.clone(), &mut w);
                            range
                                .clone()
                                .step_by(CHUNK)
                                .map(|first| {
                                    let chunk = first..(first + CHUNK).min(range.end);
                                    let mut starts = Vec::with_capacity(chunk.len());
                                    units.clear();
                                    for v in chunk {
                                        starts.push(units.len() as u32);
                                        list.clear();
                                        select(&state, v, &mut w, &mut list);
                                        sort_short(&mut list);
                                        list.dedup();
                                        encode(&list, &mut units);
                                    }
                                    (starts, units.to_vec())
                                })
                                .collect::<Vec<_>>()
                        })
                    })
                })
            })
            .collect();
        let mut offsets = Vec::with_capacity(n + 1);
        let mut chunks = Vec::with_capacity(built.len());
        for (starts, units) in built {
            offsets.extend_from_slice(&starts);
            chunks.push(units);
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

    #[cfg(test)]
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

/// Beyond ring 2, rings are walked by [`RingWalker::grow_beam`] expanding
/// at most this many vertices per ring: the candidates are a well-spread
/// sample of each ring, so growth to ring `k` costs `O(k)`.
pub const BEAM_WIDTH: usize = 12;

/// Where a fitting pass takes each vertex's neighbours from.
#[derive(Debug, Clone, Copy)]
pub enum HoodSource<'a> {
    /// Stored lists, in ascending order (passes that keep fit weights need
    /// these: the weights are laid out like them).
    Stored(&'a Neighbourhoods),
    /// Every vertex's `rings`-ring, walked when the vertex is fitted and
    /// chosen by [`select_rings`], in walk order; never stored.
    Walked {
        /// Rings walked.
        rings: u32,
        /// Most points kept.
        max_points: usize,
    },
}

impl HoodSource<'_> {
    /// Vertex `v`'s neighbours, written to `out` (cleared first).
    #[inline]
    pub fn get_into(&self, topo: &Topology, v: usize, out: &mut Vec<u32>) {
        match *self {
            HoodSource::Stored(hoods) => hoods.get_into(v, out),
            HoodSource::Walked { rings, max_points } => {
                out.clear();
                WALKER.with(|w| select_rings(&mut w.borrow_mut(), topo, v, rings, max_points, out));
            }
        }
    }
}

/// Appends vertex `v`'s `rings`-ring, walked with `w`, to `out`: rings 1
/// and 2 whole, later rings as growth walks them (a sample of
/// [`BEAM_WIDTH`] vertices expanded per ring), thinned to at most
/// `max_points` with inner rings kept whole while they hold half of them
/// ([`push_thinned`]).
pub fn select_rings(
    w: &mut RingWalker,
    topo: &Topology,
    v: usize,
    rings: u32,
    max_points: usize,
    out: &mut Vec<u32>,
) {
    w.start(topo, v);
    for r in 0..rings {
        let beam = if r < 2 { usize::MAX } else { BEAM_WIDTH };
        if w.grow_beam(topo, beam).is_empty() {
            w.discard_last();
            break;
        }
    }
    push_thinned(w, max_points, max_points / 2, out);
}

/// How [`push_thinned`] thins a walk: `quota[r]` points of ring `r`
/// (1-based), its inner rings whole ([`whole_inner_rings`]).
#[derive(Debug, Clone, Copy)]
pub struct Thinning {
    /// Points taken from each ring; every point of every ring when the
    /// walk holds at most `max_points`.
    pub quota: [u16; MAX_RINGS + 1],
}

/// Most rings a [`Thinning`] plans for (the largest `k_max`).
pub const MAX_RINGS: usize = 32;

impl Default for Thinning {
    fn default() -> Self {
        Thinning {
            quota: [0; MAX_RINGS + 1],
        }
    }
}

/// How many of the walker's first `rings` rings, from the inside, total at
/// most `whole_inner` points: the rings a thinning keeps whole.
pub fn whole_inner_rings(w: &RingWalker, rings: usize, whole_inner: usize) -> usize {
    let (mut kept_rings, mut kept) = (0, 0);
    while kept_rings < rings && kept + w.ring(kept_rings + 1).len() <= whole_inner {
        kept += w.ring(kept_rings + 1).len();
        kept_rings += 1;
    }
    kept_rings
}

impl Thinning {
    /// The thinning of `w`'s rings to at most `max_points` points, inner
    /// rings kept whole while they total at most `whole_inner`, the rest of
    /// the budget shared among the outer rings in proportion to their sizes
    /// (quotas of at most `max_points`).
    pub fn plan(w: &RingWalker, max_points: usize, whole_inner: usize) -> Thinning {
        let rings = w.rings().min(MAX_RINGS);
        let all = w.found().len();
        let kept_rings = if all <= max_points {
            rings
        } else {
            whole_inner_rings(w, rings, whole_inner)
        };
        let mut quota = [0u16; MAX_RINGS + 1];
        for (r, q) in quota.iter_mut().enumerate().take(kept_rings + 1).skip(1) {
            *q = w.ring(r).len() as u16;
        }
        if kept_rings == rings {
            return Thinning { quota };
        }
        let kept = w.found_in(kept_rings);
        let (rest, budget) = (all - kept, max_points - kept);
        let mut taken = 0usize;
        let mut seen = 0usize;
        for (r, q) in quota
            .iter_mut()
            .enumerate()
            .take(rings + 1)
            .skip(kept_rings + 1)
        {
            seen += w.ring(r).len();
            let share = budget * seen / rest - taken;
            taken += share;
            *q = share as u16;
        }
        Thinning { quota }
    }
}

/// Appends `quota` points of `ring`, evenly spread along it: point `q` is
/// entry `floor((q + 1/2) len / quota)`, stepped in integers (a float
/// product and a saturating conversion per point cost more than the rest
/// of the thinning).
#[inline]
pub fn push_ring_sample(ring: &[u32], quota: usize, out: &mut Vec<u32>) {
    if quota >= ring.len() {
        out.extend_from_slice(ring);
        return;
    }
    if quota == 0 {
        return;
    }
    // Entry `q` is `(2q + 1) len / (2 quota)`: start at `len / (2 quota)`
    // and add `len / quota` (whole part and remainder) per point.
    let (len, den) = (ring.len(), 2 * quota);
    let (step, step_rest) = (2 * len / den, 2 * len % den);
    let (mut index, mut rest) = (len / den, len % den);
    out.reserve(quota);
    for _ in 0..quota {
        // Below `len`: `(2q + 1) len < 2 quota len`.
        out.push(ring[index]);
        index += step;
        rest += step_rest;
        if rest >= den {
            rest -= den;
            index += 1;
        }
    }
}

/// Appends the walker's rings to `out`, at most `max_points` of them: inner
/// rings are kept whole while they total at most `whole_inner` points, and
/// the remaining budget is shared among the outer rings in proportion to
/// their sizes, each thinned by an even stride so the points stay spread
/// around the vertex ([`Thinning`]).
pub fn push_thinned(w: &RingWalker, max_points: usize, whole_inner: usize, out: &mut Vec<u32>) {
    if w.found().len() <= max_points {
        out.extend_from_slice(w.found());
    } else {
        Thinning::plan(w, max_points, whole_inner).push(w, out);
    }
}

impl Thinning {
    /// Appends the walker's rings, thinned by this plan (made for them).
    pub fn push(&self, w: &RingWalker, out: &mut Vec<u32>) {
        for r in 1..=w.rings().min(MAX_RINGS) {
            push_ring_sample(w.ring(r), usize::from(self.quota[r]), out);
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
        let mut list = Vec::new();
        let mut units = 0;
        for v in 0..t.num_vertices() {
            let mut ring = w.k_ring(&t, v, 2).to_vec();
            ring.sort_unstable();
            hoods.get_into(v, &mut list);
            assert_eq!(list, ring, "vertex {v}");
            // Two units for the first entry, one for each gap (all small).
            units += list.len() + 1;
        }
        assert_eq!(hoods.units(), units);
    }

    #[test]
    fn ring_samples_are_evenly_spread() {
        let mut out = Vec::new();
        for len in 1..120u32 {
            let ring: Vec<u32> = (0..len).map(|i| 1000 + i).collect();
            for quota in 0..len as usize + 3 {
                out.clear();
                push_ring_sample(&ring, quota, &mut out);
                let n = len as usize;
                let expected: Vec<u32> = if quota >= n {
                    ring.clone()
                } else {
                    (0..quota)
                        .map(|q| ring[(2 * q + 1) * n / (2 * quota)])
                        .collect()
                };
                assert_eq!(out, expected, "len {len}, quota {quota}");
            }
        }
    }

    #[test]
    fn large_gaps_round_trip_through_an_escape() {
        let list = [
            0u32,
            1,
            65_534,
            65_535 + 65_534,
            65_535 + 65_534 + 65_535,
            u32::MAX,
        ];
        let mut units = Vec::new();
        encode(&list, &mut units);
        // 2 for the first entry, 1 each for the gaps 1 and 65533 (below the
        // escape), 3 each for 65535, 65535 and the last gap.
        assert_eq!(units.len(), 2 + 2 + 3 * 3);
        let decoded: Vec<(usize, u32)> = Entries {
            units: &units,
            next: 0,
            value: 0,
        }
        .collect();
        assert_eq!(decoded.iter().map(|e| e.1).collect::<Vec<_>>(), list);
        assert_eq!(
            decoded.iter().map(|e| e.0).collect::<Vec<_>>(),
            [0, 2, 3, 4, 7, 10]
        );
    }

    #[test]
    fn weights_follow_their_entries() {
        let m = grid(6);
        let t = Topology::build(&m);
        let hoods = Neighbourhoods::two_ring(&t, 512);
        let mut weights = hoods.zero_weights();
        let v = 24;
        let mut list = Vec::new();
        hoods.get_into(v, &mut list);
        let by_entry: Vec<f32> = (0..list.len()).map(|i| i as f32).collect();
        for mut chunk in weights.chunks_mut(&hoods) {
            chunk.set(v, &by_entry);
        }
        let stored = weights.get(&hoods, v);
        let mut as_f32 = Vec::new();
        weights.get_f32_into(&hoods, v, &mut as_f32);
        for (i, (unit, j)) in hoods.entries(v).enumerate() {
            assert_eq!(j, list[i]);
            assert_eq!(stored[unit], f16::from_f32(by_entry[i]));
            assert_eq!(as_f32[unit], i as f32);
        }
        assert!(weights.get(&hoods, v + 1).iter().all(|w| *w == f16::ZERO));
    }

    #[test]
    fn widening_is_the_exact_conversion_at_every_length() {
        let all: Vec<f16> = (0..40u16)
            .map(|i| f16::from_bits(i.wrapping_mul(0x9E37) ^ 0x3C00))
            .chain([
                f16::INFINITY,
                f16::NEG_INFINITY,
                f16::MIN_POSITIVE_SUBNORMAL,
            ])
            .collect();
        let mut out = vec![7.0; 3];
        for len in 0..=all.len() {
            widen_into(&all[..len], &mut out);
            let expected: Vec<f32> = all[..len].iter().map(|h| h.to_f32()).collect();
            assert_eq!(out.len(), len);
            for (a, b) in out.iter().zip(&expected) {
                assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
            }
        }
    }

    #[test]
    fn weights_follow_entries_stored_with_an_escape() {
        let m = grid(265);
        let t = Topology::build(&m);
        let n = t.num_vertices() as u32;
        assert!(n > 66_000);
        // Vertex v lists v + 1 and v + 66000: a gap past one unit.
        let hoods = Neighbourhoods::build(&t, |v, _, out| {
            out.extend([(v as u32 + 66_000) % n, (v as u32 + 1) % n]);
        });
        let v = 5;
        let mut list = Vec::new();
        hoods.get_into(v, &mut list);
        assert_eq!(list, [6, 66_005]);
        let mut weights = hoods.zero_weights();
        for mut chunk in weights.chunks_mut(&hoods).take(1) {
            chunk.set(v, &[0.25, -0.5]);
        }
        let stored = weights.get(&hoods, v);
        let by_unit: Vec<(usize, f32)> = hoods
            .entries(v)
            .map(|(unit, _)| (unit, stored[unit].to_f32()))
            .collect();
        assert_eq!(by_unit, [(0, 0.25), (2, -0.5)]);
        assert_eq!(stored.len(), 5, "2 units, the escape and 2 more");
    }
}
