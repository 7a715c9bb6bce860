//! k-ring queries: `N_k(i)`, every vertex within `k` edges of `i` (not `i`).

use super::Topology;
use super::topology::NEIGHBOR_BLOCK;

/// Breadth-first ring walker with reusable scratch, so repeated queries
/// allocate nothing once warmed up. One walker per thread.
#[derive(Debug, Default, Clone)]
pub struct RingWalker {
    stamp: Vec<u32>,
    generation: u32,
    /// Vertices found so far, ring by ring (the centre is not included):
    /// the first `len` entries. The buffer only grows, so walks after the
    /// first write into memory already there.
    found: Vec<u32>,
    len: usize,
    /// `found[ring_starts[r]..ring_starts[r+1]]` is ring `r + 1`.
    ring_starts: Vec<usize>,
    centre: u32,
}

impl RingWalker {
    /// A walker for meshes with `num_vertices` vertices.
    pub fn new(num_vertices: usize) -> Self {
        RingWalker {
            stamp: vec![0; num_vertices],
            ..Default::default()
        }
    }

    /// Starts a walk at `centre`, forgetting the previous one.
    pub fn start(&mut self, topo: &Topology, centre: usize) {
        if self.stamp.len() < topo.num_vertices() {
            self.stamp.resize(topo.num_vertices(), 0);
        }
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.stamp.iter_mut().for_each(|s| *s = 0);
            self.generation = 1;
        }
        self.len = 0;
        self.ring_starts.clear();
        self.ring_starts.push(0);
        self.centre = centre as u32;
        self.stamp[centre] = self.generation;
    }

    /// Adds the next ring (vertices at exactly one more edge) and returns it;
    /// empty when the component is exhausted.
    pub fn grow(&mut self, topo: &Topology) -> &[u32] {
        self.grow_beam(topo, usize::MAX)
    }

    /// Like [`RingWalker::grow`], but expands at most `beam` vertices of the
    /// last ring, chosen by an even stride through it, so a walk to ring `k`
    /// costs `O(k * beam)` instead of `O(k^2)`. The result is then a
    /// well-spread sample of the next ring rather than all of it (a vertex of
    /// the sample may be closer than `k + 1` edges when its shorter path runs
    /// through an unexpanded vertex).
    pub fn grow_beam(&mut self, topo: &Topology, beam: usize) -> &[u32] {
        let g = self.generation;
        let start = self.len;
        let mut end = start;
        let ring_count = self.ring_starts.len();
        let (frontier, take) = if ring_count == 1 {
            (0..0, 1)
        } else {
            let range = self.ring_starts[ring_count - 2]..self.ring_starts[ring_count - 1];
            let take = range.len().min(beam.max(1));
            (range, take)
        };
        // The `q`-th expanded vertex is `frontier[q * len / take]`, stepped
        // without a division per vertex.
        let (len, mut index, mut rest) = (frontier.len(), frontier.start, 0);
        let (step, step_rest) = (len / take.max(1), len % take.max(1));
        for _ in 0..take {
            let u = if ring_count == 1 {
                self.centre as usize
            } else {
                self.found[index] as usize
            };
            index += step;
            rest += step_rest;
            if rest >= take {
                rest -= take;
                index += 1;
            }
            // Branch-free marking: whether a neighbour is new is close to a
            // coin toss, so a branch on it would mispredict half the time.
            if self.found.len() < end + NEIGHBOR_BLOCK {
                self.found.resize(2 * (end + NEIGHBOR_BLOCK), 0);
            }
            if let Some((block, n)) = topo.neighbor_block(u) {
                // Every entry of the block, those past the list writing
                // back the stamp they read (a vertex of this list seen in
                // the block is already stamped: stamps are set in order).
                for (k, &w) in block.iter().enumerate() {
                    let stamp = &mut self.stamp[w as usize];
                    let live = k < n;
                    let fresh = live & (*stamp != g);
                    *stamp = if live { g } else { *stamp };
                    self.found[end] = w;
                    end += usize::from(fresh);
                }
                continue;
            }
            let nb = topo.neighbors(u);
            if self.found.len() < end + nb.len() {
                self.found.resize(2 * (end + nb.len()), 0);
            }
            for &w in nb {
                let stamp = &mut self.stamp[w as usize];
                let fresh = *stamp != g;
                *stamp = g;
                self.found[end] = w;
                end += usize::from(fresh);
            }
        }
        self.len = end;
        self.ring_starts.push(end);
        &self.found[start..end]
    }

    /// Drops the last grown ring (used when growth is rejected). Its
    /// vertices stay marked, so growing again returns nothing new.
    pub fn discard_last(&mut self) {
        if self.ring_starts.len() > 1 {
            let s = self.ring_starts[self.ring_starts.len() - 2];
            self.len = s;
            self.ring_starts.pop();
        }
    }

    /// All vertices found so far (rings 1..=k), ring by ring.
    pub fn found(&self) -> &[u32] {
        &self.found[..self.len]
    }

    /// How many vertices rings `1..=r` hold.
    pub fn found_in(&self, r: usize) -> usize {
        self.ring_starts[r]
    }

    /// Number of complete rings walked.
    pub fn rings(&self) -> usize {
        self.ring_starts.len() - 1
    }

    /// Ring `r` (1-based) of the current walk.
    pub fn ring(&self, r: usize) -> &[u32] {
        &self.found[self.ring_starts[r - 1]..self.ring_starts[r]]
    }

    /// Collects `N_k(centre)` into the walker and returns it.
    pub fn k_ring(&mut self, topo: &Topology, centre: usize, k: usize) -> &[u32] {
        self.start(topo, centre);
        for _ in 0..k {
            if self.grow(topo).is_empty() {
                break;
            }
        }
        &self.found[..self.len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::tests::grid;
    use glam::DVec3;

    #[test]
    fn quad_grid_rings_have_4_then_12_vertices() {
        let n = 6u32;
        let m = grid(n);
        let t = Topology::build(&m);
        let centre = (3 * (n + 1) + 3) as usize;
        let mut w = RingWalker::new(m.num_vertices());
        assert_eq!(w.k_ring(&t, centre, 1).len(), 4);
        assert_eq!(w.k_ring(&t, centre, 2).len(), 12);
        assert_eq!(w.ring(2).len(), 8);
        assert!(!w.found().contains(&(centre as u32)));
    }

    #[test]
    fn beam_walk_past_an_exhausted_component_is_empty() {
        let m = crate::mesh::Mesh::from_polygons(
            vec![DVec3::ZERO, DVec3::X, DVec3::Y],
            &[[0u32, 1, 2]],
        )
        .unwrap();
        let t = Topology::build(&m);
        let mut w = RingWalker::new(3);
        w.start(&t, 0);
        assert_eq!(w.grow_beam(&t, 4).len(), 2);
        assert!(w.grow_beam(&t, 4).is_empty());
        assert!(w.grow_beam(&t, 4).is_empty(), "growing from an empty ring");
        assert_eq!(w.rings(), 3);
    }

    #[test]
    fn beam_walk_samples_each_ring() {
        let n = 20u32;
        let m = grid(n);
        let t = Topology::build(&m);
        let c = (10 * (n + 1) + 10) as usize;
        let mut w = RingWalker::new(m.num_vertices());
        w.start(&t, c);
        for _ in 0..8 {
            let ring = w.grow_beam(&t, 6);
            assert!(!ring.is_empty() && ring.len() <= 6 * 4);
        }
        // The last ring's sample lies far out in every direction.
        let pos = m.positions();
        let ring = w.ring(8);
        for (dx, dy) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
            let reach = ring
                .iter()
                .map(|&v| (pos[v as usize] - pos[c]).dot(DVec3::new(dx, dy, 0.0)))
                .fold(f64::MIN, f64::max);
            assert!(reach >= 5.0, "direction ({dx}, {dy}) reaches {reach}");
        }
    }
}
