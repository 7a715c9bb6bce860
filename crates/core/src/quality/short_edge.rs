//! Short-edge fix (paper section 2.4; algorithm notes section 8).
//!
//! An edge `(v1, v2)` is short when it is shorter than a fraction of the
//! mean edge length. For end point `v1`, let `c` and `d` be the other ends
//! of `v1`'s sides in the two faces that share the short edge; the
//! bisector of the angle `c v1 d` on the side away from `v2` (in the
//! tangent plane at `v1`) meets the polygon of `v1`'s link (the other
//! corners of its faces) at `p1`; that is the intersection of the plane
//! through the bisector and the normal with the edges around `v1`.
//! Likewise `p2` for `v2`. The two end points move to the trisection points
//! of the polyline `p1 v1 v2 p2`, so the edge becomes a third of it, and are
//! then lifted onto their local fitted quadrics (section 3, fitted to the
//! 2-ring in the frame of the current position and normal) so the shape is
//! kept.
//!
//! A move is kept only when the edge gets longer and nothing gets worse
//! (see `MoveTester`): no face becomes inverted relative to the input, no
//! quad becomes twisted, no defect count grows and the smallest
//! split-triangle angle of the faces around the two end points does not
//! shrink. Otherwise both end points stay.
//!
//! Order: Gauss-Seidel, sequential, edges in ascending edge order within a
//! sweep (deterministic); later sweeps revisit only the edges still short,
//! and of those only the ones near a vertex that moved since they were last
//! tried (a try reads nothing farther, [`DEPENDENCY_RINGS`], so one whose
//! surroundings stand still would be refused again); the fix stops after a
//! sweep that moves nothing or after `max_sweeps`.
//! Only edges with two interior end points and exactly two faces move.

use super::local::{LocalSurface, MoveTester, is_hub, ordered_link};
use crate::mesh::{Mesh, Topology, VertexKind, mean_edge_length};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// What the short-edge fix did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ShortEdgeStats {
    /// Short-edge threshold used, in mesh units.
    pub threshold: f64,
    /// Short edges before the fix.
    pub found: u64,
    /// Accepted moves (an edge lengthened), over all sweeps.
    pub lengthened: u64,
    /// Tried moves refused because they would have made something worse,
    /// or short edges that could not be constructed for (boundary,
    /// non-manifold); an edge refused again in a later sweep counts again,
    /// whether tried anew or skipped because nothing near it has moved.
    pub rejected: u64,
    /// Sweeps run.
    pub sweeps: u64,
    /// Short edges after the fix (same threshold).
    pub remaining: u64,
}

/// How far, in steps from a vertex to the corners of its faces, a try on an
/// edge reads positions from either end point: its fitted surface takes
/// the 2-ring ([`LocalSurface::at`]: the neighbours' neighbours) with each
/// point's own vertex normal (the corners of that point's faces); the
/// link, the end point's normal and the faces [`MoveTester`] judges lie
/// one step out. A hub's neighbours are not in a 2-ring through it, so the
/// steps do not go on through a hub.
const DEPENDENCY_RINGS: usize = 3;

/// The tick of an edge not tried yet (and of every edge once the ticks run
/// out): such an edge is always tried.
const NEVER_TRIED: u32 = u32::MAX;

/// Marks with `tick` (in `touched`) every vertex within
/// [`DEPENDENCY_RINGS`] of `moved`, not going on through hubs: the end
/// points of the edges whose try may now come out otherwise. `frontier`
/// and `next` are scratch.
fn mark_near(
    mesh: &Mesh,
    topo: &Topology,
    moved: [usize; 2],
    tick: u32,
    touched: &mut [u32],
    frontier: &mut Vec<u32>,
    next: &mut Vec<u32>,
) {
    frontier.clear();
    for v in moved {
        if touched[v] != tick {
            touched[v] = tick;
            frontier.push(v as u32);
        }
    }
    for _ in 0..DEPENDENCY_RINGS {
        next.clear();
        for &v in frontier.iter() {
            if is_hub(topo, v as usize) {
                continue;
            }
            for &f in topo.vertex_faces(v as usize) {
                for &c in mesh.face(f as usize) {
                    if touched[c as usize] != tick {
                        touched[c as usize] = tick;
                        next.push(c);
                    }
                }
            }
        }
        std::mem::swap(frontier, next);
    }
}

fn short_edges(topo: &Topology, positions: &[DVec3], threshold: f64) -> Vec<u32> {
    let t2 = threshold * threshold;
    let edges = topo.edges();
    (0..edges.len() as u32)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&e| {
            let [a, b] = edges[e as usize];
            positions[a as usize].distance_squared(positions[b as usize]) < t2
        })
        .collect()
}

/// Lengthens edges shorter than `fraction` times the mean edge length (of
/// `positions`) by the trisection construction; at most `max_sweeps`
/// sweeps. Moves vertices in `positions` in place (one entry per vertex;
/// `input`, the input positions, likewise).
#[allow(clippy::too_many_arguments)]
pub fn fix_short_edges(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    fraction: f64,
    max_sweeps: u32,
    min_normal_cos: f64,
) -> ShortEdgeStats {
    let plan = Plan {
        bound,
        fraction,
        max_sweeps,
        min_normal_cos,
        skip_unmoved: true,
    };
    sweep_short_edges(mesh, topo, positions, input, plan)
}

/// [`fix_short_edges`]'s arguments past the positions, and whether a
/// sweep skips the edges that nothing near has moved since they were
/// refused (the tests try every edge in every sweep to check the skip).
#[derive(Clone, Copy)]
struct Plan<'a> {
    bound: Option<&'a FidelityBound>,
    fraction: f64,
    max_sweeps: u32,
    min_normal_cos: f64,
    skip_unmoved: bool,
}

fn sweep_short_edges(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    plan: Plan,
) -> ShortEdgeStats {
    let Plan {
        bound,
        fraction,
        max_sweeps,
        min_normal_cos,
        skip_unmoved,
    } = plan;
    let threshold = fraction * mean_edge_length(mesh, positions);
    let short = short_edges(topo, positions, threshold);
    let mut stats = ShortEdgeStats {
        threshold,
        found: short.len() as u64,
        ..ShortEdgeStats::default()
    };
    let mut fixer = Fixer {
        min_normal_cos,
        tester: MoveTester::bounded(bound),
        ..Fixer::default()
    };
    // Each short edge with the tick it was last tried at; each vertex with
    // the tick of the last move near it (ticks count the moves kept).
    let mut short: Vec<(u32, u32)> = short.into_iter().map(|e| (e, NEVER_TRIED)).collect();
    let mut touched = vec![0u32; positions.len()];
    let mut tick = 0u32;
    let (mut frontier, mut next) = (Vec::new(), Vec::new());
    while !short.is_empty() && stats.sweeps < max_sweeps as u64 {
        stats.sweeps += 1;
        let mut changed = false;
        for (e, tried) in short.iter_mut() {
            let [a, b] = topo.edges()[*e as usize];
            let (a, b) = (a as usize, b as usize);
            if skip_unmoved && *tried != NEVER_TRIED && touched[a] <= *tried && touched[b] <= *tried
            {
                // Nothing it reads has moved since it was refused: it would
                // be refused again, and counts so.
                stats.rejected += 1;
                continue;
            }
            *tried = tick;
            if fixer.lengthen(mesh, topo, *e as usize, positions, input) {
                stats.lengthened += 1;
                changed = true;
                // At the last tick every edge counts as never tried, so a
                // mesh with that many moves is tried in full.
                tick = tick.saturating_add(1);
                mark_near(
                    mesh,
                    topo,
                    [a, b],
                    tick,
                    &mut touched,
                    &mut frontier,
                    &mut next,
                );
            } else {
                stats.rejected += 1;
            }
        }
        let t2 = threshold * threshold;
        let p: &[DVec3] = positions;
        short.retain(|&(e, _)| {
            let [a, b] = topo.edges()[e as usize];
            p[a as usize].distance_squared(p[b as usize]) < t2
        });
        if !changed {
            break;
        }
    }
    stats.remaining = short.len() as u64;
    if stats.sweeps == max_sweeps as u64 && !short.is_empty() {
        stats.remaining = short_edges(topo, positions, threshold).len() as u64;
    }
    stats
}

#[derive(Debug, Default)]
struct Fixer {
    /// [`LocalSurface::at`]'s facing rule.
    min_normal_cos: f64,
    ring: Vec<u32>,
    link: Vec<u32>,
    tester: MoveTester,
}

impl Fixer {
    /// Tries the trisection move on edge `e`; returns whether it was kept.
    fn lengthen(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        e: usize,
        positions: &mut [DVec3],
        input: &[DVec3],
    ) -> bool {
        let [a, b] = topo.edges()[e];
        let (a, b) = (a as usize, b as usize);
        if topo.kind(a) != VertexKind::Interior
            || topo.kind(b) != VertexKind::Interior
            || topo.edge_faces(e).len() != 2
        {
            return false;
        }
        let Some((pa, sa)) = self.far_point(mesh, topo, a, b, positions) else {
            return false;
        };
        let Some((pb, sb)) = self.far_point(mesh, topo, b, a, positions) else {
            return false;
        };
        let polyline = [pa, positions[a], positions[b], pb];
        let na = along(&polyline, 1.0 / 3.0);
        let nb = along(&polyline, 2.0 / 3.0);
        let (xa, ya) = sa.tangent(na);
        let (xb, yb) = sb.tangent(nb);
        let (na, nb) = (sa.point(xa, ya), sb.point(xb, yb));
        if !(na.is_finite() && nb.is_finite()) {
            return false;
        }
        let old = positions[a].distance(positions[b]);
        if na.distance(nb) <= old {
            return false;
        }
        self.tester
            .begin(mesh, topo, &[a, b], positions, input, 1.0);
        let verdict = self.tester.judge(mesh, &[(a, na), (b, nb)], positions);
        if verdict.keeps_quality() {
            positions[a] = na;
            positions[b] = nb;
            true
        } else {
            false
        }
    }

    /// The point `p1` for end point `v` of the short edge `(v, w)`, and the
    /// fitted surface at `v`.
    fn far_point(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        v: usize,
        w: usize,
        positions: &[DVec3],
    ) -> Option<(DVec3, LocalSurface)> {
        if !ordered_link(mesh, topo, v, &mut self.link) {
            return None;
        }
        let surface = LocalSurface::at(
            mesh,
            topo,
            v,
            positions,
            &mut self.ring,
            self.min_normal_cos,
        )?;
        let m = self.link.len();
        let i = self.link.iter().position(|&x| x as usize == w)?;
        // Going counter-clockwise the link runs d .. w .. c, where d and c
        // are the edge neighbours of v nearest to w on either side (the
        // other ends of v's sides in the two faces on edge (v, w)).
        let is_nb = |x: u32| topo.neighbors(v).binary_search(&x).is_ok();
        let c = (1..m).map(|k| self.link[(i + k) % m]).find(|&x| is_nb(x))?;
        let d = (1..m)
            .map(|k| self.link[(i + m - k) % m])
            .find(|&x| is_nb(x))?;
        let (cx, cy) = surface.tangent(positions[c as usize]);
        let (dx, dy) = surface.tangent(positions[d as usize]);
        // Bisect the counter-clockwise sweep from c to d: the sector without w.
        let ac = cy.atan2(cx);
        let mut sweep = dy.atan2(dx) - ac;
        if sweep <= 0.0 {
            sweep += TAU;
        }
        let (sy, sx) = (ac + 0.5 * sweep).sin_cos();
        // Nearest crossing of the ray t (sx, sy), t > 0, with a link side.
        let mut best: Option<(f64, DVec3)> = None;
        for k in 0..m {
            let (q0, q1) = (
                positions[self.link[k] as usize],
                positions[self.link[(k + 1) % m] as usize],
            );
            let (x0, y0) = surface.tangent(q0);
            let (x1, y1) = surface.tangent(q1);
            // Solve t (sx, sy) = (x0, y0) + s (x1 - x0, y1 - y0).
            let (ex, ey) = (x1 - x0, y1 - y0);
            let den = sx * ey - sy * ex;
            if den.abs() < 1e-300 {
                continue;
            }
            let t = (x0 * ey - y0 * ex) / den;
            let s = (x0 * sy - y0 * sx) / den;
            if t > 0.0 && (0.0..=1.0).contains(&s) && best.is_none_or(|(bt, _)| t < bt) {
                best = Some((t, q0.lerp(q1, s)));
            }
        }
        best.map(|(_, p)| (p, surface))
    }
}

/// The point at `fraction` of the length along `polyline`.
fn along(polyline: &[DVec3], fraction: f64) -> DVec3 {
    let total: f64 = polyline.windows(2).map(|w| w[0].distance(w[1])).sum();
    let mut left = fraction * total;
    for w in polyline.windows(2) {
        let l = w[0].distance(w[1]);
        if left <= l && l > 0.0 {
            return w[0].lerp(w[1], left / l);
        }
        left -= l;
    }
    polyline[polyline.len() - 1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::fixtures::{at, grid, min_split_angle};
    use crate::report::measure_stage;

    #[test]
    fn skipping_the_edges_nothing_near_has_moved_changes_nothing() {
        // A bumpy grid whose rows are squeezed together in places: many
        // short edges side by side, some lengthened only once a neighbour
        // has moved. Trying every short edge in every sweep and skipping
        // the ones whose surroundings stood still must give the same
        // positions and counts.
        let m = grid(24);
        let t = Topology::build(&m);
        let input: Vec<DVec3> = m
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let squeeze = if (i / 25) % 3 == 1 { 0.7 } else { 0.0 };
                let (dx, dy) = (
                    crate::shapes::normal_deviate(3, i as u64),
                    crate::shapes::normal_deviate(4, i as u64),
                );
                DVec3::new(
                    p.x + 0.15 * dx,
                    p.y - squeeze + 0.15 * dy,
                    0.3 * (0.7 * p.x).sin() * (0.5 * p.y).cos(),
                )
            })
            .collect();
        let plan = Plan {
            bound: None,
            fraction: 0.4,
            max_sweeps: 20,
            min_normal_cos: 0.5,
            skip_unmoved: true,
        };
        let (mut skipped, mut every) = (input.clone(), input.clone());
        let a = sweep_short_edges(&m, &t, &mut skipped, &input, plan);
        let b = sweep_short_edges(
            &m,
            &t,
            &mut every,
            &input,
            Plan {
                skip_unmoved: false,
                ..plan
            },
        );
        assert!(a.found > 20 && a.lengthened > 0 && a.sweeps > 2, "{a:?}");
        assert_eq!(a, b);
        assert_eq!(skipped, every);
    }

    #[test]
    fn a_short_edge_is_lengthened_on_the_surface() {
        let m = grid(6);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        let (a, b) = (at(6, 2, 3), at(6, 3, 3));
        // Both ends of edge (2,3)-(3,3) pulled together: length 0.08.
        p[a] = DVec3::new(2.46, 3.0, 0.0);
        p[b] = DVec3::new(2.54, 3.0, 0.0);
        let angle_before = min_split_angle(&m, &p, None);
        let stats = fix_short_edges(&m, &t, &mut p, &input, None, 0.2, 10, 0.5);
        assert_eq!(stats.found, 1);
        assert_eq!(stats.lengthened, 1);
        assert_eq!(stats.remaining, 0);
        let len = p[a].distance(p[b]);
        assert!(len > stats.threshold, "edge now {len}");
        assert!(p.iter().all(|q| q.z.abs() < 1e-9), "stays on the plane");
        let after = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!((after.inverted_faces, after.twisted_quads), (0, 0));
        assert!(min_split_angle(&m, &p, None) >= angle_before);
    }

    #[test]
    fn the_far_point_follows_the_bisector_away_from_the_partner() {
        let m = grid(4);
        let t = Topology::build(&m);
        let mut f = Fixer {
            min_normal_cos: 0.5,
            ..Fixer::default()
        };
        let (a, b) = (at(4, 2, 2), at(4, 3, 2));
        let (p1, _) = f.far_point(&m, &t, a, b, m.positions()).unwrap();
        // The other sides at (2,2) in the two faces on the edge run to (2,1)
        // and (2,3): the bisector away from (3,2) points to -x and meets the
        // link at (1,2).
        assert!(p1.distance(DVec3::new(1.0, 2.0, 0.0)) < 1e-12, "{p1}");
    }

    #[test]
    fn polyline_trisection() {
        let line = [DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0)];
        assert!((along(&line, 0.25) - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        assert!((along(&line, 0.75) - DVec3::new(1.0, 0.5, 0.0)).length() < 1e-15);
        assert_eq!(along(&line, 1.0), line[2]);
    }
}
