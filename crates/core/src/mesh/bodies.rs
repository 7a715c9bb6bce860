//! Bodies that touch face to face: closed surfaces written into one file
//! whose welded vertices join them along a common wall.
//!
//! A segmentation of several labels is often exported as one file, each
//! label's surface with its own vertices: 3D Slicer writes every segment
//! of a segmentation into one OBJ, and merges them into one STL on
//! request. Where two labels touch, both surfaces run through the same
//! voxel faces (or the same marching-cubes triangles), wound opposite
//! ways. Welding by position then joins the two surfaces into one
//! non-manifold complex: every edge of the wall has four faces, every
//! vertex of it is non-manifold, and the smoothing reads the two bodies
//! as one. [`touching_bodies`] finds, at every vertex, which of its faces
//! lie on which body's side, so that a weld can keep the sides apart.
//!
//! Two faces that leave an edge at the same angle mark two bodies that
//! touch: a wall's face from each side, passing the edge opposite ways,
//! or the same surface written twice into one file. The faces are joined
//! into sheets: those the file joins by a vertex of its own (a file that
//! writes each body with its own vertices says so exactly), those across
//! an edge of two faces, and, around an edge of more, a face and the next
//! face inside the same body: a face's body lies behind it (against its
//! normal), so turning about the edge from a face into its body, the first
//! face met, coincident faces passed over, is the body's other face there
//! when it passes the edge the other way. A turn never joins two sheets
//! with coincident faces between them: where two labels' marching cubes
//! triangulate their wall differently, it can meet the other label's face
//! first. A voxel mask's own sheets part where its voxels touch along an
//! edge, so sheets are not bodies; at each vertex, though, two sheets with
//! coincident faces between them (there or anywhere) are on two sides, and
//! every other sheet there takes the first side no such pair separates it
//! from. A mask whose parts touch only along an edge keeps one side
//! everywhere.

use super::{Mesh, Topology};
use glam::DVec3;
use rayon::prelude::*;

/// Most faces at one edge that are sorted around it: two bodies touching
/// give an edge four faces, two masks each touching itself along the edge
/// eight. An edge with more joins none of its faces (they join their
/// sheets elsewhere or stay apart), which bounds the work per edge.
pub(super) const MAX_SORTED_FACES: usize = 16;

/// Most sheets at one vertex that are sorted into sides; a vertex with
/// more keeps them on one side (it stays joined), which bounds the work
/// per vertex.
const MAX_SHEETS: usize = 16;

/// Most sheets with coincident faces that are searched for one that two
/// closed sheets have in common ([`vertex_sides`]); a sheet with more
/// joins as if one were shared, which bounds the work per vertex.
const PARTNER_CHECKS: usize = 64;

/// Angles about an edge closer than this (radians) are one: coincident
/// faces, the wall's two sides, differ only by rounding.
pub(super) const SAME_ANGLE: f64 = 1e-9;

/// Faces or vertices per parallel task: enough to outweigh the task's
/// cost.
const CHUNK: usize = 4096;

/// Where welded bodies touch face to face: which side of its vertex each
/// face corner lies on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TouchingBodies {
    /// One entry per face corner, in the order of
    /// [`Mesh::face_vertices`]: the corner's side of its vertex, numbered
    /// from 0 in the order of the sides' lowest faces there (0 at every
    /// vertex no two bodies share).
    pub corner_side: Vec<u32>,
    /// Pairs `(f, g)`, `f < g`, of coincident faces on different sheets:
    /// the walls the bodies share, each face pair once.
    pub shared: Vec<(u32, u32)>,
}

/// Where the bodies of `mesh` touch face to face (module docs); `None`
/// when no two sheets have coincident faces. `file`, when given, is the
/// same faces on the file's own vertices, before the weld that made
/// `mesh`. Time linear in the corners.
pub fn touching_bodies(
    mesh: &Mesh,
    topo: &Topology,
    file: Option<&Mesh>,
) -> Option<TouchingBodies> {
    let around: Vec<Around> = (0..topo.edges().len())
        .into_par_iter()
        .with_min_len(CHUNK)
        .flat_map_iter(|e| {
            let faces = topo.edge_faces(e);
            match faces.len() {
                3..=MAX_SORTED_FACES => pair_around(mesh, topo.edges()[e], faces),
                _ => Vec::new(),
            }
        })
        .collect();
    if !around.iter().any(|a| matches!(a, Around::Coincident(..))) {
        return None;
    }
    // Sheets (module docs): by the file's vertices and the edges of two
    // faces, then by the turns that join no coincident faces.
    let mut sheets = UnionFind::new(mesh.num_faces());
    if let Some(file) = file {
        join_by_file_vertices(file, &mut sheets);
    }
    for e in 0..topo.edges().len() {
        if let [f, g] = topo.edge_faces(e) {
            sheets.union(*f as usize, *g as usize);
        }
    }
    let coincident: Vec<(u32, u32)> = around
        .iter()
        .filter_map(|a| match *a {
            Around::Coincident(f, g) => Some((f, g)),
            Around::Link(..) => None,
        })
        .collect();
    let mut joined = Apart::new(
        (0..mesh.num_faces())
            .map(|f| sheets.find(f) as u32)
            .collect(),
        &coincident,
    );
    for a in &around {
        if let Around::Link(f, g) = *a {
            joined.join(f as usize, g as usize);
        }
    }
    let sheet: Vec<u32> = (0..mesh.num_faces())
        .map(|f| joined.find(f) as u32)
        .collect();
    let mut shared: Vec<(u32, u32)> = coincident
        .into_iter()
        .filter(|&(f, g)| sheet[f as usize] != sheet[g as usize])
        .collect();
    shared.sort_unstable();
    shared.dedup();
    if shared.is_empty() {
        return None;
    }
    // The sheet pairs with coincident faces between them, both ways,
    // sorted.
    let mut apart: Vec<(u32, u32)> = shared
        .iter()
        .flat_map(|&(f, g)| {
            let (s, t) = (sheet[f as usize], sheet[g as usize]);
            [(s, t), (t, s)]
        })
        .collect();
    apart.sort_unstable();
    apart.dedup();
    // Sheets the file closes on its own vertices: the file keeps two of
    // them apart wherever the weld would join them only at a vertex or an
    // edge, unless both have coincident faces with one third sheet (two
    // parts of one label beside another).
    let mut closed = vec![file.is_some(); mesh.num_faces()];
    if let Some(file) = file {
        for (f, open) in open_in_file(file).into_iter().enumerate() {
            if open && let Some(c) = closed.get_mut(sheet[f] as usize) {
                *c = false;
            }
        }
    }
    // Per vertex, its sheets' sides (empty where it has one side).
    let sides: Vec<Vec<(u32, u32)>> = (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(CHUNK)
        .map(|v| vertex_sides(topo.vertex_faces(v), &sheet, &apart, &closed))
        .collect();
    let sides = &sides;
    let corner_side: Vec<u32> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(CHUNK)
        .flat_map_iter(|f| {
            let s = sheet[f];
            mesh.face(f).iter().map(move |&v| {
                sides[v as usize]
                    .iter()
                    .find(|&&(t, _)| t == s)
                    .map_or(0, |&(_, side)| side)
            })
        })
        .collect();
    Some(TouchingBodies {
        corner_side,
        shared,
    })
}

/// Joins the faces of `file` that share a vertex into one sheet.
fn join_by_file_vertices(file: &Mesh, sheets: &mut UnionFind) {
    let mut first = vec![u32::MAX; file.num_vertices()];
    for f in 0..file.num_faces().min(sheets.parent.len()) {
        for &v in file.face(f) {
            match first.get_mut(v as usize) {
                Some(s) if *s == u32::MAX => *s = f as u32,
                Some(s) => sheets.union(*s as usize, f),
                None => {}
            }
        }
    }
}

/// Per face of `file`, whether one of its sides has no face passing it
/// the other way on the file's own vertices (an open rim of the file: a
/// crack the weld closes, or every side of a separate face).
fn open_in_file(file: &Mesh) -> Vec<bool> {
    fn sides(face: &[u32]) -> impl Iterator<Item = (u32, u32)> + '_ {
        let k = face.len();
        (0..k).map(move |i| (face[i], face[(i + 1) % k]))
    }
    let mut passes: Vec<u64> = file
        .faces()
        .flat_map(sides)
        .map(|(a, b)| u64::from(a) << 32 | u64::from(b))
        .collect();
    passes.par_sort_unstable();
    file.faces()
        .map(|face| {
            sides(face).any(|(a, b)| {
                passes
                    .binary_search(&(u64::from(b) << 32 | u64::from(a)))
                    .is_err()
            })
        })
        .collect()
}

/// The bodies of `split` (its topology `topo`), a mesh whose touching
/// bodies no longer share a vertex, whose face pairs `shared` lie on two
/// bodies' walls ([`TouchingBodies::shared`]): each vertex's body, and the
/// number of bodies. The components that share walls with one component
/// are one class unless a wall lies between them (the fragments of one
/// label around another); then each class, in the order of its lowest
/// component, takes the first body none of whose classes it shares a wall
/// with (a greedy colouring), so that two labels give two bodies however
/// many fragments each has; the components that share no wall join the
/// first body.
pub fn body_ids(split: &Mesh, topo: &Topology, shared: &[(u32, u32)]) -> (Vec<u32>, usize) {
    let (component, count) = topo.component_ids();
    let component_of = |f: u32| {
        split
            .face(f as usize)
            .first()
            .map_or(0, |&v| component[v as usize])
    };
    let mut walls: Vec<(u32, u32)> = shared
        .iter()
        .map(|&(f, g)| (component_of(f), component_of(g)))
        .filter(|&(a, b)| a != b)
        .flat_map(|(a, b)| [(a, b), (b, a)])
        .collect();
    walls.sort_unstable();
    walls.dedup();
    let mut classes = Apart::new((0..count as u32).collect(), &walls);
    for facing in walls.chunk_by(|a, b| a.0 == b.0) {
        if let Some(&(_, first)) = facing.first() {
            for &(_, other) in &facing[1..] {
                classes.join(first as usize, other as usize);
            }
        }
    }
    let mut facing: Vec<Vec<usize>> = vec![Vec::new(); count];
    for &(a, b) in &walls {
        let (x, y) = (classes.find(a as usize), classes.find(b as usize));
        facing[x].push(y);
    }
    let mut body = vec![u32::MAX; count];
    let mut bodies = 0u32;
    let mut taken: Vec<bool> = Vec::new();
    let of_component: Vec<u32> = (0..count)
        .map(|c| {
            let root = classes.find(c);
            if body[root] == u32::MAX {
                // The first free body is at most the number of walls.
                taken.clear();
                taken.resize((bodies as usize).min(facing[root].len() + 1), false);
                for &y in &facing[root] {
                    if let Some(t) = taken.get_mut(body[y] as usize) {
                        *t = true;
                    }
                }
                body[root] = taken.iter().position(|&t| !t).unwrap_or(taken.len()) as u32;
                bodies = bodies.max(body[root] + 1);
            }
            body[root]
        })
        .collect();
    let of_vertex = component
        .iter()
        .map(|&c| of_component[c as usize])
        .collect();
    (of_vertex, bodies as usize)
}

/// Work per conflict, in list entries scanned, that [`Apart::join`] may
/// spend: a multiple of the conflicts keeps the joins linear in the input,
/// far more than two or three labels' fragments need.
const JOIN_WORK: usize = 64;

/// Classes of items, each with the items it must not share a class with:
/// a union-find whose joins refuse to put a conflicting pair together.
struct Apart {
    classes: UnionFind,
    /// Per class root, the items in conflict with the class (merged
    /// smaller into larger).
    against: Vec<Vec<u32>>,
    /// What the conflict tests may still scan ([`JOIN_WORK`]); once spent,
    /// no more classes join.
    budget: usize,
}

impl Apart {
    /// Classes given by `parent` (each item's root, a root its own), with
    /// the item pairs `conflicts` kept apart.
    fn new(parent: Vec<u32>, conflicts: &[(u32, u32)]) -> Self {
        let mut against = vec![Vec::new(); parent.len()];
        for &(a, b) in conflicts {
            let (ra, rb) = (parent[a as usize], parent[b as usize]);
            if ra != rb {
                against[ra as usize].push(b);
                against[rb as usize].push(a);
            }
        }
        Apart {
            classes: UnionFind { parent },
            against,
            budget: JOIN_WORK * (conflicts.len() + 1),
        }
    }

    fn find(&mut self, i: usize) -> usize {
        self.classes.find(i)
    }

    /// Joins the classes of `a` and `b` unless a conflict lies between
    /// them (or the budget is spent).
    fn join(&mut self, a: usize, b: usize) {
        let (x, y) = (self.find(a), self.find(b));
        if x == y {
            return;
        }
        let (small, large) = if self.against[x].len() <= self.against[y].len() {
            (x, y)
        } else {
            (y, x)
        };
        let Some(left) = self.budget.checked_sub(self.against[small].len() + 1) else {
            return;
        };
        self.budget = left;
        let list = std::mem::take(&mut self.against[small]);
        if list.iter().any(|&c| self.find(c as usize) == large) {
            self.against[small] = list;
            return;
        }
        self.against[large].extend(list);
        self.classes.parent[small] = large as u32;
    }
}

/// The sides of the sheets at a vertex with `faces`: each sheet, in the
/// order of its lowest face there, takes the first side none of whose
/// sheets has coincident faces with it anywhere (`apart`: sheet pairs,
/// both ways, sorted) or is, like it, closed on the file's own vertices
/// (`closed`, by sheet) with no coincident faces with a third sheet in
/// common, or a new one. Empty when every sheet takes side 0, or the
/// vertex has more than [`MAX_SHEETS`] sheets.
fn vertex_sides(
    faces: &[u32],
    sheet: &[u32],
    apart: &[(u32, u32)],
    closed: &[bool],
) -> Vec<(u32, u32)> {
    let mut sheets = [0u32; MAX_SHEETS];
    let mut count = 0;
    for &f in faces {
        let s = sheet[f as usize];
        if !sheets[..count].contains(&s) {
            if count == MAX_SHEETS {
                return Vec::new();
            }
            sheets[count] = s;
            count += 1;
        }
    }
    if count < 2 {
        return Vec::new();
    }
    let is_closed = |s: u32| closed.get(s as usize).copied().unwrap_or(false);
    // The sheets with coincident faces with `s`: its run of `apart`, which
    // holds each pair both ways, sorted.
    let partners = |s: u32| {
        let start = apart.partition_point(|p| p.0 < s);
        apart[start..]
            .iter()
            .take_while(move |p| p.0 == s)
            .map(|p| p.1)
    };
    let coincident = |s: u32, t: u32| apart.binary_search(&(s, t)).is_ok();
    // A partner shared, among the first few of the sheet with fewer
    // (past them, taken as shared: the sheets join as a mask's parts do).
    let few = |s: u32| partners(s).take(PARTNER_CHECKS + 1).count();
    let share_partner = |s: u32, t: u32| {
        let (s, t) = if few(s) <= few(t) { (s, t) } else { (t, s) };
        few(s) > PARTNER_CHECKS || partners(s).any(|x| coincident(x, t))
    };
    let is_apart =
        |s: u32, t: u32| coincident(s, t) || (is_closed(s) && is_closed(t) && !share_partner(s, t));
    let mut side_of = [0u32; MAX_SHEETS];
    let mut sides = 0u32;
    for i in 0..count {
        let side = (0..sides)
            .find(|&k| (0..i).all(|j| side_of[j] != k || !is_apart(sheets[i], sheets[j])))
            .unwrap_or(sides);
        if side == sides {
            sides += 1;
        }
        side_of[i] = side;
    }
    if sides < 2 {
        return Vec::new();
    }
    (0..count).map(|i| (sheets[i], side_of[i])).collect()
}

/// What the faces around an edge of more than two say.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Around {
    /// Two faces of one body, next to each other inside it.
    Link(u32, u32),
    /// Two coincident faces (`f < g`): two bodies' walls, wound opposite
    /// ways, or a surface written twice, wound alike.
    Coincident(u32, u32),
}

/// A face at an edge: which way it passes the edge (`true`: from the
/// edge's first vertex to its second) and the angle about the edge at
/// which it leaves it. A face passing the edge forward has its outward
/// normal a quarter turn ahead of its wing.
#[derive(Clone, Copy)]
pub(super) struct Wing {
    pub face: u32,
    pub forward: bool,
    pub angle: f64,
}

/// The faces `faces` at edge `[a, b]` sorted by the angle about the edge
/// at which each leaves it (ties by face number); `None` when the edge has
/// no length, a face lies in its line, or a face passes it other than
/// once (that face left out).
pub(super) fn sorted_wings(mesh: &Mesh, [a, b]: [u32; 2], faces: &[u32]) -> Option<Vec<Wing>> {
    let p = mesh.positions();
    let (pa, pb) = (p[a as usize], p[b as usize]);
    let axis = (pb - pa).normalize_or_zero();
    if axis == DVec3::ZERO {
        return None;
    }
    let mut across: Option<(DVec3, DVec3)> = None;
    let mut wings: Vec<Wing> = Vec::with_capacity(faces.len());
    for &f in faces {
        let Some((forward, wing)) = wing_of(mesh.face(f as usize), a, b) else {
            continue;
        };
        let w = p[wing as usize] - pa;
        let w = w - axis * axis.dot(w);
        let (x, y) = *across.get_or_insert_with(|| {
            let x = w.normalize_or_zero();
            (x, axis.cross(x))
        });
        if x == DVec3::ZERO {
            return None;
        }
        wings.push(Wing {
            face: f,
            forward,
            angle: w.dot(y).atan2(w.dot(x)),
        });
    }
    wings.sort_by(|s, t| s.angle.total_cmp(&t.angle).then(s.face.cmp(&t.face)));
    Some(wings)
}

/// The mutual choices of the faces around edge `[a, b]` (module docs),
/// and the pairs of coincident faces.
fn pair_around(mesh: &Mesh, edge: [u32; 2], faces: &[u32]) -> Vec<Around> {
    let Some(wings) = sorted_wings(mesh, edge, faces) else {
        return Vec::new();
    };
    // Groups of coincident faces, in angle order (the last group may wrap
    // round to the first).
    let mut group = vec![0usize; wings.len()];
    let mut groups = 0;
    for i in 0..wings.len() {
        if i > 0 && wings[i].angle - wings[i - 1].angle > SAME_ANGLE {
            groups += 1;
        }
        group[i] = groups;
    }
    let mut groups = groups + 1;
    if groups > 1
        && let (Some(first), Some(last)) = (wings.first(), wings.last())
        && first.angle + std::f64::consts::TAU - last.angle <= SAME_ANGLE
    {
        let wrapped = groups - 1;
        for g in &mut group {
            if *g == wrapped {
                *g = 0;
            }
        }
        groups -= 1;
    }
    if groups < 2 {
        return Vec::new();
    }
    // A face passing the edge forward has its outward normal a quarter
    // turn ahead of its wing, so its body lies behind: the body's next face
    // is in the group before (and passes the edge backward).
    let choice = |i: usize| -> Option<usize> {
        let w = wings[i];
        let target = if w.forward {
            (group[i] + groups - 1) % groups
        } else {
            (group[i] + 1) % groups
        };
        let mut found = None;
        for (j, u) in wings.iter().enumerate() {
            if group[j] == target && u.forward != w.forward {
                if found.is_some() {
                    return None;
                }
                found = Some(j);
            }
        }
        found
    };
    let links = (0..wings.len()).filter_map(|i| {
        let j = choice(i)?;
        (i < j && choice(j) == Some(i)).then_some(Around::Link(wings[i].face, wings[j].face))
    });
    let coincident = (0..wings.len()).flat_map(|i| {
        let (group, wings) = (&group, &wings);
        (i + 1..wings.len()).filter_map(move |j| {
            let (s, t) = (wings[i].face, wings[j].face);
            (group[i] == group[j]).then(|| Around::Coincident(s.min(t), s.max(t)))
        })
    });
    links.chain(coincident).collect()
}

/// Which way `face` passes the edge `[a, b]` (`true`: from `a` to `b`)
/// and its corner after the edge; `None` when it passes it other than
/// once.
pub(super) fn wing_of(face: &[u32], a: u32, b: u32) -> Option<(bool, u32)> {
    let k = face.len();
    let mut found = None;
    for (i, &c) in face.iter().enumerate() {
        let next = face[(i + 1) % k];
        let pass = if c == a && next == b {
            Some(true)
        } else if c == b && next == a {
            Some(false)
        } else {
            None
        };
        if let Some(forward) = pass {
            if found.is_some() {
                return None;
            }
            found = Some((forward, face[(i + 2) % k]));
        }
    }
    found
}

/// Union-find over `0..n` with path halving.
pub(super) struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    pub(super) fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
        }
    }

    pub(super) fn find(&mut self, mut i: usize) -> usize {
        while self.parent[i] as usize != i {
            self.parent[i] = self.parent[self.parent[i] as usize];
            i = self.parent[i] as usize;
        }
        i
    }

    pub(super) fn union(&mut self, a: usize, b: usize) {
        let (a, b) = (self.find(a), self.find(b));
        if a != b {
            self.parent[a.max(b)] = a.min(b) as u32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit cubes at `origins`: each cube's corners (the unit cube's,
    /// [`crate::mesh::test_unit_cube`], moved) and its six faces, outward,
    /// on the vertices `index` gives its corners.
    fn cube_corners_and_faces(
        origins: &[[i32; 3]],
        mut index: impl FnMut(DVec3) -> u32,
    ) -> Vec<[u32; 4]> {
        let unit = crate::mesh::test_unit_cube();
        let mut faces = Vec::new();
        for o in origins {
            let shift = DVec3::new(f64::from(o[0]), f64::from(o[1]), f64::from(o[2]));
            let corners: Vec<u32> = unit.positions().iter().map(|&p| index(p + shift)).collect();
            faces.extend(
                unit.faces()
                    .map(|f| [0, 1, 2, 3].map(|k| corners[f[k] as usize])),
            );
        }
        faces
    }

    /// Cubes at `origins` on one welded lattice of vertices.
    fn cubes(origins: &[[i32; 3]]) -> Mesh {
        let mut positions: Vec<DVec3> = Vec::new();
        let faces =
            cube_corners_and_faces(origins, |p| match positions.iter().position(|&q| q == p) {
                Some(i) => i as u32,
                None => {
                    positions.push(p);
                    positions.len() as u32 - 1
                }
            });
        Mesh::from_polygons(positions, &faces).unwrap()
    }

    /// Cubes at `origins`, each on eight vertices of its own (as a file
    /// that writes each body apart), faces in the order of [`cubes`].
    fn cubes_apart(origins: &[[i32; 3]]) -> Mesh {
        let mut positions: Vec<DVec3> = Vec::new();
        let faces = cube_corners_and_faces(origins, |p| {
            positions.push(p);
            positions.len() as u32 - 1
        });
        Mesh::from_polygons(positions, &faces).unwrap()
    }

    #[test]
    fn two_cubes_sharing_a_face_take_two_sides_of_its_corners() {
        let mesh = cubes(&[[0, 0, 0], [1, 0, 0]]);
        let topo = Topology::build(&mesh);
        let bodies = touching_bodies(&mesh, &topo, None).expect("two bodies");
        // Cube 0's face x+ (5) is cube 1's face x- (10).
        assert_eq!(bodies.shared, vec![(5, 10)]);
        for f in 0..mesh.num_faces() {
            for (j, &v) in mesh.face(f).iter().enumerate() {
                let side = bodies.corner_side[4 * f + j];
                let on_wall = mesh.positions()[v as usize].x == 1.0;
                assert_eq!(side, u32::from(f >= 6 && on_wall), "face {f} corner {j}");
            }
        }
    }

    #[test]
    fn a_row_of_three_cubes_shares_two_faces_and_one_alone_none() {
        let mesh = cubes(&[[0, 0, 0], [1, 0, 0], [2, 0, 0]]);
        let bodies = touching_bodies(&mesh, &Topology::build(&mesh), None).unwrap();
        assert_eq!(bodies.shared.len(), 2);
        let one = cubes(&[[0, 0, 0]]);
        assert_eq!(touching_bodies(&one, &Topology::build(&one), None), None);
    }

    #[test]
    fn cubes_touching_along_an_edge_stay_joined() {
        // A voxel mask's two voxels touching along an edge: no repeated
        // face, so nothing is told apart.
        let mesh = cubes(&[[0, 0, 0], [1, 1, 0]]);
        assert_eq!(touching_bodies(&mesh, &Topology::build(&mesh), None), None);
    }

    #[test]
    fn a_mask_touching_itself_along_an_edge_keeps_one_side_beside_another_body() {
        // Cubes A (0,0,0) and B (1,1,0) are one mask touching along an
        // edge; C (1,0,0) and D (0,1,0) another, filling the other two
        // voxels around it: eight faces at that edge. A and B take one
        // side of its vertices, C and D the other.
        let mesh = cubes(&[[0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0]]);
        let bodies = touching_bodies(&mesh, &Topology::build(&mesh), None).unwrap();
        assert_eq!(bodies.shared.len(), 4);
        let p = mesh.positions();
        let centre = |v: u32| p[v as usize].x == 1.0 && p[v as usize].y == 1.0;
        let mut sides = [Vec::new(), Vec::new()];
        for f in 0..mesh.num_faces() {
            for (j, &v) in mesh.face(f).iter().enumerate() {
                if centre(v) {
                    sides[usize::from(f >= 12)].push(bodies.corner_side[4 * f + j]);
                }
            }
        }
        assert!(sides[0].iter().all(|&s| s == 0), "{:?}", sides[0]);
        assert!(sides[1].iter().all(|&s| s == 1), "{:?}", sides[1]);
    }

    #[test]
    fn closed_file_parts_meeting_at_an_edge_stay_apart() {
        // Cubes A and B share a face; C touches B along an edge only. In a
        // file that gives each cube its own vertices (and closes each), C
        // keeps its own side of that edge; without the file's vertices
        // (an STL) it joins B there, as a mask's parts do.
        let mesh = cubes(&[[0, 0, 0], [1, 0, 0], [2, 1, 0]]);
        let file = cubes_apart(&[[0, 0, 0], [1, 0, 0], [2, 1, 0]]);
        let topo = Topology::build(&mesh);
        let edge_sides = |bodies: &TouchingBodies| {
            let p = mesh.positions();
            let mut sides = [Vec::new(), Vec::new()];
            for f in 6..18 {
                for (j, &v) in mesh.face(f).iter().enumerate() {
                    let q = p[v as usize];
                    if q.x == 2.0 && q.y == 1.0 {
                        sides[usize::from(f >= 12)].push(bodies.corner_side[4 * f + j]);
                    }
                }
            }
            sides
        };
        let apart = touching_bodies(&mesh, &topo, Some(&file)).unwrap();
        let [b, c] = edge_sides(&apart);
        assert!(b.iter().all(|&s| c.iter().all(|&t| s != t)), "{b:?} {c:?}");
        let joined = touching_bodies(&mesh, &topo, None).unwrap();
        let [b, c] = edge_sides(&joined);
        assert!(b.iter().chain(&c).all(|&s| s == b[0]), "{b:?} {c:?}");
    }

    #[test]
    fn wings_around_a_shared_edge_pair_within_each_body() {
        // The edge from (1,0,0) to (1,0,1) of two cubes sharing the face
        // x = 1: each cube's two faces there choose each other, and the
        // shared faces are coincident.
        let mesh = cubes(&[[0, 0, 0], [1, 0, 0]]);
        let topo = Topology::build(&mesh);
        let p = mesh.positions();
        let at = |q: DVec3| p.iter().position(|&x| x == q).unwrap();
        let (a, b) = (at(DVec3::new(1.0, 0.0, 0.0)), at(DVec3::new(1.0, 0.0, 1.0)));
        let e = topo.edge(a, b).unwrap();
        let faces = topo.edge_faces(e);
        assert_eq!(faces.len(), 4);
        let mut around: Vec<Around> = pair_around(&mesh, topo.edges()[e], faces)
            .into_iter()
            .map(|x| match x {
                Around::Link(f, g) => Around::Link(f.min(g), f.max(g)),
                c => c,
            })
            .collect();
        around.sort_unstable_by_key(|x| match *x {
            Around::Link(f, g) => (0, f, g),
            Around::Coincident(f, g) => (1, f, g),
        });
        // Faces: cube 0 y- (2) and x+ (5); cube 1 x- (10) and y- (8).
        assert_eq!(
            around,
            vec![
                Around::Link(2, 5),
                Around::Link(8, 10),
                Around::Coincident(5, 10)
            ]
        );
    }
}
