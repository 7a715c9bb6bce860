//! The regions of a multi-label complex: a surface that bounds several
//! labels of a segmentation with each wall between two labels written
//! once.
//!
//! VTK's surface nets over a label map (`vtkSurfaceNets3D`, pyvista's
//! `contour_labels` with internal boundaries) write such a complex: a face
//! between two labels has a label on each side, and where three labels
//! meet an edge has three faces (or more). Smoothed as one surface, a wall
//! has no inside: the volume restoration's offset along the normals grows
//! one label and shrinks the other, and the volume it restores is no
//! label's. [`regions`] finds the labels' regions from the geometry alone,
//! so that each label can be smoothed as the closed surface it is
//! (`pipeline::regions`).
//!
//! Each face has two sides: behind it (against its normal) and in front.
//! Around an edge the faces are sorted by the angle at which they leave it;
//! two faces next to each other in that order bound one sector, so the
//! side of one that faces the other and the side of the other that faces
//! back lie in the same region (a face passing the edge forward has its
//! front a quarter turn ahead of its wing). The sides so joined, over the
//! whole of a closed mesh, are the surfaces of the regions: a region's
//! outer surface encloses a positive volume seen from its own side, the
//! space around the mesh a negative one (as does a cavity seen from the
//! solid around it).
//! A mask's own surface, however it touches itself along edges, gives each
//! face one bounded side; a complex gives its walls two.

use super::bodies::{MAX_SORTED_FACES, SAME_ANGLE, UnionFind, sorted_wings, wing_of};
use super::{Mesh, Topology, bounding_box, cone_volume6, cone_volume6_about};
use glam::DVec3;
use rayon::prelude::*;

/// Faces per parallel task: enough to outweigh the task's cost.
const CHUNK: usize = 4096;

/// A side enclosing less than this share of the cube of the mesh's
/// bounding-box diagonal bounds no region: rounding, not a label.
const MIN_REGION_VOLUME: f64 = 1e-12;

/// No region on that side of a face ([`Regions::sides`]).
pub const OUTSIDE: u32 = u32::MAX;

/// The bounded regions of a complex, by face side.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Regions {
    /// Per face, the region behind it (against its normal) and the region
    /// in front of it, numbered from 0 in the order of their lowest face
    /// (whatever the faces' winding); [`OUTSIDE`] where that side is
    /// unbounded.
    pub sides: Vec<[u32; 2]>,
    /// Number of bounded regions.
    pub count: usize,
    /// Faces with a bounded region on both sides: the walls the regions
    /// share.
    pub walls: usize,
}

impl Regions {
    /// The sum of the regions' volumes with `mesh`'s vertices at
    /// `positions`: each face counts for the region behind it as written
    /// and for the region in front of it turned over, so a wall counts for
    /// both.
    pub fn volume(&self, mesh: &Mesh, positions: &[DVec3]) -> f64 {
        let v6: f64 = mesh
            .faces()
            .zip(&self.sides)
            .map(|(face, sides)| {
                let v = cone_volume6(face, positions);
                let behind = if sides[0] == OUTSIDE { 0.0 } else { v };
                let front = if sides[1] == OUTSIDE { 0.0 } else { -v };
                behind + front
            })
            .sum();
        v6 / 6.0
    }
}

/// The regions of `mesh` (module docs) when it is a closed complex: `None`
/// unless the mesh has no open edge, an edge has an odd number of faces
/// (the rim of a wall, where it meets another surface) and a face has a
/// bounded region on each side; also `None` where the sides cannot
/// be told apart (coincident faces, an edge of more than
/// `MAX_SORTED_FACES` faces or of no length, a face passing an edge twice,
/// a face with one region on both sides). Time linear in the corners.
pub fn regions(mesh: &Mesh, topo: &Topology) -> Option<Regions> {
    // An open complex (a label map cut at the image's edge) lets the labels
    // that reach the cut leak into the space around it: only some could be
    // told apart, and the rest would smooth apart from them.
    if topo.num_boundary_edges() > 0 {
        return None;
    }
    let edges = topo.edges();
    let odd = (0..edges.len())
        .into_par_iter()
        .with_min_len(CHUNK)
        .any(|e| {
            let k = topo.edge_faces(e).len();
            k >= 3 && k % 2 == 1
        });
    if !odd {
        return None;
    }
    // The side pairs that meet in the edges' sectors (side `2 f` behind
    // face `f`, `2 f + 1` in front), a list per parallel task; `None` where
    // an edge cannot be read. The joins' result does not depend on their
    // order.
    let links: Option<Vec<Vec<(u32, u32)>>> = (0..edges.len())
        .into_par_iter()
        .with_min_len(CHUNK)
        .fold(
            || Some(Vec::new()),
            |pairs, e| {
                let mut pairs = pairs?;
                sector_links(mesh, edges[e], topo.edge_faces(e), &mut pairs)?;
                Some(pairs)
            },
        )
        .collect();
    let mut sides = UnionFind::new(2 * mesh.num_faces());
    for (s, t) in links?.into_iter().flatten() {
        sides.union(s as usize, t as usize);
    }
    let root: Vec<u32> = (0..2 * mesh.num_faces())
        .map(|s| sides.find(s) as u32)
        .collect();
    // Six times each side surface's volume, from its own side: behind a
    // face the face as written, in front of it the face reversed. About
    // the box's centre, so that far coordinates lose no digits.
    let (lo, hi) = bounding_box(mesh.positions())?;
    let centre = (lo + hi) / 2.0;
    let mut volume6 = vec![0.0f64; root.len()];
    for f in 0..mesh.num_faces() {
        let v = cone_volume6_about(mesh.face(f), mesh.positions(), centre);
        volume6[root[2 * f] as usize] += v;
        volume6[root[2 * f + 1] as usize] -= v;
    }
    let floor = 6.0 * MIN_REGION_VOLUME * (hi - lo).length().powi(3);
    let mut region = vec![OUTSIDE; root.len()];
    let mut count = 0u32;
    let mut walls = 0;
    let mut face_sides = Vec::with_capacity(mesh.num_faces());
    for f in 0..mesh.num_faces() {
        // The regions are numbered in the order of their lowest face, the
        // larger first at a face that is the lowest of two: an order that
        // does not depend on the faces' winding.
        let (a, b) = (root[2 * f] as usize, root[2 * f + 1] as usize);
        let order = if volume6[b] > volume6[a] {
            [b, a]
        } else {
            [a, b]
        };
        for r in order {
            if volume6[r] > floor && region[r] == OUTSIDE {
                region[r] = count;
                count += 1;
            }
        }
        let pair = [region[a], region[b]];
        if pair[0] != OUTSIDE && pair[1] != OUTSIDE {
            if pair[0] == pair[1] {
                return None;
            }
            walls += 1;
        }
        face_sides.push(pair);
    }
    (walls > 0).then_some(Regions {
        sides: face_sides,
        count: count as usize,
        walls,
    })
}

/// Appends to `out` the side pairs that meet in the sectors around edge
/// `edge` with `faces` (module docs); `None` when the edge cannot be read.
fn sector_links(
    mesh: &Mesh,
    edge: [u32; 2],
    faces: &[u32],
    out: &mut Vec<(u32, u32)>,
) -> Option<()> {
    let side = |f: u32, front: bool| 2 * f + u32::from(front);
    match *faces {
        [f, g] => {
            // Two faces bound the edge's two sectors, whichever way round
            // they lie.
            let (f_forward, _) = wing_of(mesh.face(f as usize), edge[0], edge[1])?;
            let (g_forward, _) = wing_of(mesh.face(g as usize), edge[0], edge[1])?;
            out.push((side(f, f_forward), side(g, !g_forward)));
            out.push((side(g, g_forward), side(f, !f_forward)));
        }
        _ if faces.len() > MAX_SORTED_FACES => return None,
        _ => {
            let wings = sorted_wings(mesh, edge, faces)?;
            if wings.len() != faces.len() {
                return None;
            }
            let k = wings.len();
            for i in 0..k {
                let (w, u) = (wings[i], wings[(i + 1) % k]);
                let gap = if i + 1 == k {
                    u.angle + std::f64::consts::TAU - w.angle
                } else {
                    u.angle - w.angle
                };
                if gap <= SAME_ANGLE {
                    return None;
                }
                // `w`'s side toward larger angles, `u`'s toward smaller.
                out.push((side(w.face, w.forward), side(u.face, !u.forward)));
            }
        }
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit cubes at `origins`, each the region of its label, on one welded
    /// lattice; the faces two cubes share written once (wound for the
    /// first cube that writes them).
    fn label_cubes(origins: &[[i32; 3]]) -> Mesh {
        let unit = crate::mesh::test_unit_cube();
        let mut positions: Vec<DVec3> = Vec::new();
        let mut faces: Vec<[u32; 4]> = Vec::new();
        let mut seen: Vec<[u32; 4]> = Vec::new();
        for o in origins {
            let shift = DVec3::new(f64::from(o[0]), f64::from(o[1]), f64::from(o[2]));
            let corners: Vec<u32> = unit
                .positions()
                .iter()
                .map(|&p| {
                    let p = p + shift;
                    match positions.iter().position(|&q| q == p) {
                        Some(i) => i as u32,
                        None => {
                            positions.push(p);
                            (positions.len() - 1) as u32
                        }
                    }
                })
                .collect();
            for f in unit.faces() {
                let face = [0, 1, 2, 3].map(|k| corners[f[k] as usize]);
                let mut key = face;
                key.sort_unstable();
                if !seen.contains(&key) {
                    seen.push(key);
                    faces.push(face);
                }
            }
        }
        Mesh::from_polygons(positions, &faces).unwrap()
    }

    #[test]
    fn a_fin_on_a_mask_is_no_complex() {
        // A cube with an open square hanging off one edge: three faces
        // there, but the fin's rim is open.
        let cube = crate::mesh::test_unit_cube();
        let mut positions = cube.positions().to_vec();
        let [a, b] = (0..positions.len() as u32)
            .filter(|&v| {
                let p = positions[v as usize];
                p.x == 1.0 && p.z == 1.0
            })
            .collect::<Vec<_>>()[..]
        else {
            panic!("the cube has one edge at x = z = 1");
        };
        let up = DVec3::new(1.0, 0.0, 1.0);
        positions.push(positions[b as usize] + up);
        positions.push(positions[a as usize] + up);
        let n = positions.len() as u32;
        let mut faces: Vec<Vec<u32>> = cube.faces().map(<[u32]>::to_vec).collect();
        faces.push(vec![a, b, n - 2, n - 1]);
        let mesh = Mesh::from_polygons(positions, &faces).unwrap();
        let topo = Topology::build(&mesh);
        assert!((0..topo.edges().len()).any(|e| topo.edge_faces(e).len() == 3));
        assert_eq!(regions(&mesh, &topo), None);
    }

    #[test]
    fn three_labels_in_a_row_have_two_walls() {
        // Cubes side by side: the two inner faces are walls, and each
        // wall's rim has three faces (the wall, a side of each cube).
        let mesh = label_cubes(&[[0, 0, 0], [1, 0, 0], [2, 0, 0]]);
        let r = regions(&mesh, &Topology::build(&mesh)).expect("a complex");
        assert_eq!((r.count, r.walls), (3, 2));
    }

    #[test]
    fn three_labels_meeting_at_edges_are_three_regions() {
        // An L of three cubes: two walls.
        let mesh = label_cubes(&[[0, 0, 0], [1, 0, 0], [0, 1, 0]]);
        let topo = Topology::build(&mesh);
        let r = regions(&mesh, &topo).expect("a complex");
        assert_eq!((r.count, r.walls), (3, 2));
        // Every face but the walls has one bounded side.
        let one_sided = r
            .sides
            .iter()
            .filter(|s| (s[0] == OUTSIDE) != (s[1] == OUTSIDE))
            .count();
        assert_eq!(one_sided, mesh.num_faces() - 2);
        // The regions' volumes: three unit cubes.
        assert!((r.volume(&mesh, mesh.positions()) - 3.0).abs() < 1e-12);
        // Each region is closed: six faces bound each cube.
        for region in 0..3 {
            let faces = r.sides.iter().filter(|s| s.contains(&region)).count();
            assert_eq!(faces, 6, "region {region}");
        }
    }

    #[test]
    fn the_regions_do_not_depend_on_the_winding() {
        let mesh = label_cubes(&[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]);
        let topo = Topology::build(&mesh);
        let r = regions(&mesh, &topo).expect("a complex");
        assert_eq!((r.count, r.walls), (4, 4));
        let turned: Vec<Vec<u32>> = mesh
            .faces()
            .enumerate()
            .map(|(f, face)| {
                let mut face = face.to_vec();
                if f % 3 == 0 {
                    face.reverse();
                }
                face
            })
            .collect();
        let turned = Mesh::from_polygons(mesh.positions().to_vec(), &turned).unwrap();
        let t = regions(&turned, &Topology::build(&turned)).expect("a complex");
        // The same regions, numbered alike.
        for (f, (a, b)) in r.sides.iter().zip(&t.sides).enumerate() {
            let b = if f % 3 == 0 { [b[1], b[0]] } else { *b };
            assert_eq!(*a, b, "face {f}");
        }
    }
}
