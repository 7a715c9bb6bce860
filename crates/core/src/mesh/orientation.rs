//! Consistent face winding: which faces a file winds against their
//! neighbours, and whether a closed mesh is wound inside out.
//!
//! Every stage reads the winding: the fits' normals and their facing
//! filter (algorithm notes, section 2), the convex / concave labels of the
//! paper's Table 2, the volume restoration and the quality fixes' test for
//! inverted faces (section 2.4). Files do not always agree with themselves:
//! STL stores each facet on its own and many writers wind some facets the
//! other way; a mesh written with a mirroring transform is inside out as a
//! whole. [`orientation`] finds the turns that make the winding agree
//! across every edge shared by exactly two faces, keeping each patch's
//! majority, then turns the whole mesh if it is closed and encloses a
//! negative volume. A closed mesh of several bodies whose own windings
//! disagree (one written inside out beside others wound outward, a file
//! merged from two writers) turns each body that encloses a negative
//! volume and lies within no other body's bounding box
//! ([`inside_out_bodies`]): a body inside another may be a cavity, wound
//! inward on purpose. A mesh already wound consistently and outward gets
//! no turn, so its run is the same as without this step.

use super::{Mesh, Topology, cone_volume6};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU8, Ordering};

/// Faces per parallel task of the edge walk: enough to outweigh the task's
/// cost, few enough that two threads share a small mesh.
const FACE_CHUNK: usize = 4096;

/// The turns [`orientation`] found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Orientation {
    /// Per face, true when its corners are to be taken in reverse order;
    /// empty when every face turns alike (all when `inside_out`, none
    /// otherwise).
    turned: Vec<bool>,
    /// Faces turned.
    pub turned_faces: usize,
    /// True when the closed mesh, once consistent, enclosed a negative
    /// volume and every face was turned once more.
    pub inside_out: bool,
    /// Bodies turned whole on their own: each enclosed a negative volume,
    /// lay within no other body's bounding box, and another body so placed
    /// was wound outward. Never with `inside_out`.
    pub inside_out_bodies: usize,
    /// Faces of those bodies (included in `turned_faces`).
    pub inside_out_body_faces: usize,
    /// Edges between two faces still wound the same way: a surface that
    /// cannot be oriented (a Moebius strip) keeps one such seam per loop.
    pub seams: usize,
}

/// Which of a two-face edge's faces ([`Topology::edge_faces`]) pass it from
/// its lower vertex to its higher one (bit 0: the first face, bit 1: the
/// second), and which passes were seen (bits 2 and 3; a face passing the
/// edge twice sets bit 4 and the edge joins nothing).
type EdgePasses = u8;
const TWICE: EdgePasses = 1 << 4;
const BOTH_SEEN: EdgePasses = 0b1100;

/// Whether an edge's two faces pass it the same way (then one of them is
/// wound against the other); `None` when it joins no two faces.
fn same_way(p: EdgePasses) -> Option<bool> {
    (p & TWICE == 0 && p & BOTH_SEEN == BOTH_SEEN).then_some((p & 1) == ((p >> 1) & 1))
}

/// The turns that wind `mesh` consistently and, when it is closed, outward.
///
/// Faces meet across the edges shared by exactly two faces; a non-manifold
/// edge or a face passing the same edge twice joins nothing. In each patch
/// so joined, the winding of the larger part is kept (on a tie, that of its
/// lowest face). Time linear in the corners (one edge lookup per side).
pub fn orientation(mesh: &Mesh, topo: &Topology) -> Orientation {
    let closed = topo.num_boundary_edges() == 0;
    let (passes, disagree) = edge_passes(mesh, topo);
    if !disagree {
        // Every face agrees with its neighbours (the usual file): only the
        // bodies or the whole may turn.
        return turn_outward(mesh, topo, closed, Vec::new(), 0);
    }
    // The other face across each side of `f`, and whether the two wind the
    // edge the same way.
    let across = |f: usize, a: u32, b: u32| -> Option<(usize, bool)> {
        let e = topo.edge(a as usize, b as usize)?;
        let same = same_way(passes[e])?;
        let faces = topo.edge_faces(e);
        let other = if faces[0] as usize == f {
            faces[1]
        } else {
            faces[0]
        };
        Some((other as usize, same))
    };

    const UNSEEN: u8 = 2;
    let n = mesh.num_faces();
    let mut state = vec![UNSEEN; n];
    let mut patch = Vec::new();
    let mut seams = 0;
    for seed in 0..n {
        if state[seed] != UNSEEN {
            continue;
        }
        state[seed] = 0;
        patch.clear();
        patch.push(seed as u32);
        let mut next = 0;
        while let Some(&f) = patch.get(next) {
            next += 1;
            let f = f as usize;
            let face = mesh.face(f);
            for (j, &a) in face.iter().enumerate() {
                let b = face[(j + 1) % face.len()];
                let Some((g, same)) = across(f, a, b) else {
                    continue;
                };
                let want = state[f] ^ u8::from(same);
                if state[g] == UNSEEN {
                    state[g] = want;
                    patch.push(g as u32);
                } else if state[g] != want && f < g {
                    seams += 1;
                }
            }
        }
        let turned = patch.iter().filter(|&&f| state[f as usize] == 1).count();
        if 2 * turned > patch.len() {
            for &f in &patch {
                state[f as usize] ^= 1;
            }
        }
    }

    let turned: Vec<bool> = state.iter().map(|&s| s == 1).collect();
    turn_outward(mesh, topo, closed, turned, seams)
}

/// The orientation of `mesh` with its faces `turned` to agree (empty: none
/// turned), made outward when it is `closed`: first each body wound inside
/// out on its own ([`inside_out_bodies`]), then the whole when it still
/// encloses a negative volume.
fn turn_outward(
    mesh: &Mesh,
    topo: &Topology,
    closed: bool,
    mut turned: Vec<bool>,
    seams: usize,
) -> Orientation {
    let n = mesh.num_faces();
    let mut inside_out_bodies = 0;
    let mut inside_out_body_faces = 0;
    let mut inside_out = false;
    if closed {
        let (component, count) = topo.component_ids();
        let mut bodies = BodyVolumes::of(mesh, component, count, &turned);
        if let Some(turns) = self::inside_out_bodies(mesh, component, &bodies) {
            turned.resize(n, false);
            for (f, t) in turned.iter_mut().enumerate() {
                if let Some(&first) = mesh.face(f).first()
                    && turns[component[first as usize] as usize]
                {
                    *t = !*t;
                    inside_out_body_faces += 1;
                }
            }
            for (v, _) in bodies.volume6.iter_mut().zip(&turns).filter(|(_, t)| **t) {
                *v = -*v;
            }
            inside_out_bodies = turns.iter().filter(|&&t| t).count();
        }
        inside_out = bodies.volume6.iter().sum::<f64>() < 0.0;
    }
    if inside_out {
        turned.resize(n, false);
        for t in &mut turned {
            *t = !*t;
        }
    }
    let turned_faces = turned.iter().filter(|&&t| t).count();
    Orientation {
        turned,
        turned_faces,
        inside_out,
        inside_out_bodies,
        inside_out_body_faces,
        seams,
    }
}

/// Most bounding-box comparisons [`inside_out_bodies`] makes, per face of
/// the mesh: each body against every other, which a file of a few bodies
/// keeps far below one pass over its faces; past this a file of very many
/// bodies keeps the file's winding rather than cost more than linear time.
const NESTING_WORK: usize = 8;

/// Six times the signed volume each connected component encloses, its
/// faces turned as given (empty: none), and whether it has faces (an
/// isolated vertex is a component of its own, with none).
struct BodyVolumes {
    volume6: Vec<f64>,
    has_faces: Vec<bool>,
}

impl BodyVolumes {
    /// The volumes of the `count` components `component` numbers
    /// ([`Topology::component_ids`]), each face counted in its first
    /// corner's component.
    fn of(mesh: &Mesh, component: &[u32], count: usize, turned: &[bool]) -> Self {
        let p = mesh.positions();
        let mut volume6 = vec![0.0f64; count];
        let mut has_faces = vec![false; count];
        for (f, face) in mesh.faces().enumerate() {
            let Some(&first) = face.first() else {
                continue;
            };
            let c = component[first as usize] as usize;
            let v = cone_volume6(face, p);
            volume6[c] += if turned.get(f).copied().unwrap_or(false) {
                -v
            } else {
                v
            };
            has_faces[c] = true;
        }
        BodyVolumes { volume6, has_faces }
    }
}

/// Per component (`component`, one id per vertex), whether it is a body of
/// a closed `mesh` wound inside out on its own: a body (a vertex-connected
/// component, with its volume in `bodies`) that encloses a negative volume
/// and whose bounding box lies in no other body's, where some other body
/// so placed is wound outward. `None` when there is nothing to turn: one
/// body, every body outward, or every such outermost body inside out (the
/// whole mesh turns then, cavities included). A body within another's box
/// keeps its winding: it may be a cavity, wound inward on purpose, or a
/// body of its own (a nucleus in its cell), and the winding is all that
/// tells the two apart.
fn inside_out_bodies(mesh: &Mesh, component: &[u32], bodies: &BodyVolumes) -> Option<Vec<bool>> {
    let BodyVolumes { volume6, has_faces } = bodies;
    let count = volume6.len();
    if count < 2 || volume6.iter().all(|&v| v >= 0.0) {
        return None;
    }
    let p = mesh.positions();
    let mut lo = vec![DVec3::INFINITY; count];
    let mut hi = vec![DVec3::NEG_INFINITY; count];
    for (v, &c) in component.iter().enumerate() {
        lo[c as usize] = lo[c as usize].min(p[v]);
        hi[c as usize] = hi[c as usize].max(p[v]);
    }
    let with_faces: Vec<usize> = (0..count).filter(|&c| has_faces[c]).collect();
    if with_faces.len().saturating_mul(with_faces.len())
        > NESTING_WORK.saturating_mul(mesh.num_faces())
    {
        return None;
    }
    let outer: Vec<bool> = (0..count)
        .map(|c| {
            has_faces[c]
                && !with_faces
                    .iter()
                    .any(|&d| d != c && lo[d].cmple(lo[c]).all() && hi[d].cmpge(hi[c]).all())
        })
        .collect();
    if !(0..count).any(|c| outer[c] && volume6[c] > 0.0) {
        return None;
    }
    let turns: Vec<bool> = (0..count).map(|c| outer[c] && volume6[c] < 0.0).collect();
    turns.contains(&true).then_some(turns)
}

/// Each edge's [`EdgePasses`], from one walk over every face's sides (in
/// parallel: the bits are or-ed, in any order, and only a face's own
/// second pass sets [`TWICE`]), and whether any two faces wind an edge
/// the same way.
fn edge_passes(mesh: &Mesh, topo: &Topology) -> (Vec<EdgePasses>, bool) {
    let passes: Vec<AtomicU8> = (0..topo.edges().len()).map(|_| AtomicU8::new(0)).collect();
    (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(FACE_CHUNK)
        .for_each(|f| {
            let face = mesh.face(f);
            for (j, &a) in face.iter().enumerate() {
                let b = face[(j + 1) % face.len()];
                let Some(e) = topo.edge(a as usize, b as usize) else {
                    continue;
                };
                let faces = topo.edge_faces(e);
                if faces.len() != 2 {
                    continue;
                }
                let slot = usize::from(faces[1] as usize == f);
                let seen = 1 << (2 + slot);
                let before =
                    passes[e].fetch_or(seen | (u8::from(a < b) << slot), Ordering::Relaxed);
                if before & seen != 0 {
                    passes[e].fetch_or(TWICE, Ordering::Relaxed);
                }
            }
        });
    let passes: Vec<EdgePasses> = passes.into_iter().map(AtomicU8::into_inner).collect();
    let disagree = passes.par_iter().any(|&p| same_way(p) == Some(true));
    (passes, disagree)
}

impl Orientation {
    /// True when no face turns.
    pub fn is_identity(&self) -> bool {
        self.turned_faces == 0
    }

    /// `mesh` with the turned faces' corners in reverse order (the same
    /// positions, faces and face order), or `None` when no face turns.
    pub fn apply(&self, mesh: &Mesh) -> Option<Mesh> {
        if self.is_identity() {
            return None;
        }
        let mut corners = Vec::with_capacity(mesh.face_vertices().len());
        for (f, face) in mesh.faces().enumerate() {
            if self.turned.get(f).copied().unwrap_or(self.inside_out) {
                corners.extend(face.iter().rev());
            } else {
                corners.extend_from_slice(face);
            }
        }
        // The same offsets and corners, each face's in another order: no
        // validation to repeat.
        Some(Mesh {
            positions: mesh.positions.clone(),
            face_offsets: mesh.face_offsets.clone(),
            face_vertices: corners,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{test_grid, test_unit_cube as cube};
    use glam::DVec3;

    fn turn(mesh: &Mesh, faces: &[usize]) -> Mesh {
        let polygons: Vec<Vec<u32>> = mesh
            .faces()
            .enumerate()
            .map(|(f, c)| {
                let mut c = c.to_vec();
                if faces.contains(&f) {
                    c.reverse();
                }
                c
            })
            .collect();
        Mesh::from_polygons(mesh.positions().to_vec(), &polygons).unwrap()
    }

    fn oriented(mesh: &Mesh) -> (Orientation, Mesh) {
        let o = orientation(mesh, &Topology::build(mesh));
        let m = o.apply(mesh).unwrap_or_else(|| mesh.clone());
        (o, m)
    }

    #[test]
    fn a_consistent_outward_mesh_turns_nothing() {
        let (o, m) = oriented(&cube());
        assert!(o.is_identity());
        assert_eq!(m, cube());
        let grid = test_grid(6);
        assert!(orientation(&grid, &Topology::build(&grid)).is_identity());
    }

    #[test]
    fn faces_wound_against_their_neighbours_turn_back() {
        let (o, m) = oriented(&turn(&cube(), &[1, 4]));
        assert_eq!((o.turned_faces, o.inside_out, o.seams), (2, false, 0));
        assert_eq!(m, cube());
        // An open grid: the minority turns, whichever face the walk starts at.
        let grid = test_grid(5);
        let (o, m) = oriented(&turn(&grid, &[0, 3, 7]));
        assert_eq!(o.turned_faces, 3);
        assert_eq!(m, grid);
    }

    #[test]
    fn a_closed_mesh_inside_out_turns_whole() {
        let all: Vec<usize> = (0..6).collect();
        let (o, m) = oriented(&turn(&cube(), &all));
        assert_eq!((o.turned_faces, o.inside_out), (6, true));
        assert_eq!(m, cube());
        // Inside out and with one face wound against the rest.
        let (o, m) = oriented(&turn(&cube(), &[0, 1, 2, 3, 4]));
        assert_eq!((o.turned_faces, o.inside_out), (5, true));
        assert_eq!(m, cube());
        assert!(m.signed_volume() > 0.0);
    }

    /// Cubes of the unit cube's faces, cube `k` scaled by `scale[k]` about
    /// its centre and moved by `at[k]`, those in `inward` wound inside out.
    fn cubes(at: &[DVec3], scale: &[f64], inward: &[usize]) -> Mesh {
        let one = cube();
        let mut p = Vec::new();
        let mut polygons: Vec<Vec<u32>> = Vec::new();
        for (k, (&at, &scale)) in at.iter().zip(scale).enumerate() {
            let base = p.len() as u32;
            p.extend(
                one.positions()
                    .iter()
                    .map(|&q| (q - DVec3::splat(0.5)) * scale + at),
            );
            for face in one.faces() {
                let mut c: Vec<u32> = face.iter().map(|&v| v + base).collect();
                if inward.contains(&k) {
                    c.reverse();
                }
                polygons.push(c);
            }
        }
        Mesh::from_polygons(p, &polygons).unwrap()
    }

    #[test]
    fn a_body_wound_inside_out_beside_an_outward_one_turns_alone() {
        let apart = [DVec3::ZERO, DVec3::new(3.0, 0.0, 0.0)];
        // The second body alone is inside out; both enclose the same
        // volume, so the whole's volume says nothing.
        let (o, m) = oriented(&cubes(&apart, &[1.0, 1.0], &[1]));
        assert_eq!(
            (o.turned_faces, o.inside_out, o.inside_out_bodies),
            (6, false, 1)
        );
        assert_eq!((o.inside_out_body_faces, o.seams), (6, 0));
        assert_eq!(m, cubes(&apart, &[1.0, 1.0], &[]));
        // The first alone: the same.
        let (o, m) = oriented(&cubes(&apart, &[1.0, 2.0], &[0]));
        assert_eq!((o.inside_out, o.inside_out_bodies), (false, 1));
        assert_eq!(m, cubes(&apart, &[1.0, 2.0], &[]));
        // Both: the whole turns, as one body would.
        let (o, _) = oriented(&cubes(&apart, &[1.0, 1.0], &[0, 1]));
        assert_eq!(
            (o.turned_faces, o.inside_out, o.inside_out_bodies),
            (12, true, 0)
        );
    }

    #[test]
    fn a_body_inside_another_keeps_its_winding() {
        let nested = [DVec3::ZERO, DVec3::ZERO];
        // A hollow cube, its cavity wound inward: nothing turns.
        let hollow = cubes(&nested, &[3.0, 1.0], &[1]);
        assert!(oriented(&hollow).0.is_identity());
        // The same written inside out as a whole: the whole turns back, the
        // cavity with it.
        let (o, m) = oriented(&cubes(&nested, &[3.0, 1.0], &[0]));
        assert_eq!((o.inside_out, o.inside_out_bodies), (true, 0));
        assert_eq!(m, hollow);
        // A body wound outward inside another (a nucleus in its cell) stays.
        assert!(oriented(&cubes(&nested, &[3.0, 1.0], &[])).0.is_identity());
        // Beside an outward body, a hollow cube written inside out: its
        // outer wall turns, and its cavity, inside it, keeps its winding.
        let three = [DVec3::ZERO, DVec3::ZERO, DVec3::new(5.0, 0.0, 0.0)];
        let (o, m) = oriented(&cubes(&three, &[3.0, 1.0, 1.0], &[0, 1]));
        assert_eq!((o.inside_out, o.inside_out_bodies), (false, 1));
        assert_eq!(m, cubes(&three, &[3.0, 1.0, 1.0], &[1]));
    }

    #[test]
    fn a_moebius_strip_keeps_one_seam() {
        // Four quads round a loop, the last joined to the first with a
        // half twist.
        let p: Vec<DVec3> = (0..8)
            .map(|i| {
                let t = (i / 2) as f64 * std::f64::consts::FRAC_PI_2;
                let h = if i % 2 == 0 { -0.3 } else { 0.3 };
                DVec3::new(t.cos() * 2.0, t.sin() * 2.0, h)
            })
            .collect();
        let m = Mesh::from_polygons(
            p,
            &[[0u32, 2, 3, 1], [2, 4, 5, 3], [4, 6, 7, 5], [6, 1, 0, 7]],
        )
        .unwrap();
        let o = orientation(&m, &Topology::build(&m));
        assert_eq!(o.seams, 1);
        assert!(!o.inside_out);
    }

    #[test]
    fn a_face_passing_an_edge_twice_joins_nothing_there() {
        // A triangle and a degenerate face passing the edge 0-1 both ways:
        // the two share that edge alone, which says nothing of how they wind.
        let p = vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
        let m = Mesh::from_polygons(p, &[vec![0u32, 1, 2], vec![0, 1, 0, 3]]).unwrap();
        let o = orientation(&m, &Topology::build(&m));
        assert_eq!((o.turned_faces, o.seams), (0, 0));
    }
}
