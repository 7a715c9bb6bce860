//! Voxel faces that an exporter split into triangles, paired back.
//!
//! STL and glTF hold triangles only, and most exporters split every square
//! of a voxel-boundary mesh along a diagonal. The diagonals run across the
//! lattice's axes, so such a mesh is no voxel lattice to
//! [`super::lattice::lattice_frame`], and the staircase steps and the
//! dual-voxel bound would pass it by. Two triangles that share their
//! longest edge, have a right angle opposite it and close a rectangle are
//! one voxel face: the quad they make has that diagonal as its split
//! (`(v0 v1 v2)`, `(v0 v2 v3)`), so every measure and fix on the quad's
//! split triangles is one on the file's own triangles.

use super::lattice::{is_marching_cubes_lattice, lattice_frame};
use super::{Mesh, Topology, has_repeated_corner};
use glam::DVec3;
use rayon::prelude::*;

/// How far from a right angle (as a cosine), and how far the fourth corner
/// from the rectangle's (as a fraction of the diagonal), a pair of
/// triangles may be and still count as one voxel face: a file that writes
/// seven significant digits rounds a corner a thousand millimetres from the
/// origin by a thousandth of a millimetre, a fifth of a percent of a
/// half-millimetre voxel's side. As loose as the lattice test's parallel
/// edges (within 0.8 degrees): the pairs must make a voxel lattice, which
/// the triangles of no other surface do.
const RECTANGLE_TOLERANCE: f64 = 1e-2;

/// The mesh with its split voxel faces paired back into quads, its
/// topology, and how many pairs were joined.
#[derive(Debug)]
pub struct PairedFaces {
    /// Same positions; each pair's two triangles become one quad, in the
    /// place of the pair's first triangle.
    pub mesh: Mesh,
    /// The topology of `mesh`.
    pub topo: Topology,
    /// Triangle pairs joined.
    pub pairs: usize,
}

/// `mesh` with each pair of triangles that splits a rectangle joined into
/// that quad, when the result is a voxel lattice and `mesh` is neither one
/// already nor a marching-cubes mesh (whose flat runs are squares split in
/// two as well, a voxel's width from the voxel faces they follow); `None`
/// otherwise. Linear in the mesh's size.
pub fn paired_voxel_faces(mesh: &Mesh, topo: &Topology) -> Option<PairedFaces> {
    let p = mesh.positions();
    let triangles = mesh.faces().filter(|f| f.len() == 3).count();
    if triangles == 0 {
        return None;
    }
    let partner: Vec<Option<(u32, [u32; 4])>> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| split_partner(mesh, topo, f))
        .collect();
    // Mutual partners only: each triangle's diagonal is its longest edge,
    // so a rectangle's two halves name each other.
    let mutual = |f: usize| {
        partner[f].filter(|&(g, _)| {
            partner
                .get(g as usize)
                .copied()
                .flatten()
                .is_some_and(|(h, _)| h as usize == f)
        })
    };
    let pairs = (0..mesh.num_faces())
        .filter(|&f| mutual(f).is_some_and(|(g, _)| (g as usize) > f))
        .count();
    // A voxel mesh written as triangles pairs all of them; a mesh of which
    // fewer than half pair is no lattice once paired (most of its vertices
    // keep a diagonal edge), and the lattice tests below need not run.
    if 4 * pairs < triangles
        || lattice_frame(topo, p).is_some()
        || is_marching_cubes_lattice(topo, p)
    {
        return None;
    }
    let mut offsets = Vec::with_capacity(mesh.num_faces() + 1);
    let mut corners = Vec::with_capacity(mesh.face_vertices().len());
    offsets.push(0u32);
    for f in 0..mesh.num_faces() {
        match mutual(f) {
            Some((g, _)) if (g as usize) < f => continue,
            Some((_, quad)) => corners.extend(quad),
            None => corners.extend_from_slice(mesh.face(f)),
        }
        offsets.push(u32::try_from(corners.len()).ok()?);
    }
    let paired = Mesh::new(p.to_vec(), offsets, corners).ok()?;
    let paired_topo = Topology::build(&paired);
    lattice_frame(&paired_topo, p)?;
    Some(PairedFaces {
        mesh: paired,
        topo: paired_topo,
        pairs,
    })
}

/// The triangle across face `f`'s diagonal and the quad the two make, when
/// `f` is a triangle with a right angle opposite its longest edge, that
/// edge joins exactly two faces, and the other face is a triangle that
/// closes the rectangle with the same orientation. For `f = (a b c)` and
/// the other `(b a d)` the quad is `(b c a d)`, whose split along `b a`
/// gives back the two ([`crate::quality`] measures quads on that split).
fn split_partner(mesh: &Mesh, topo: &Topology, f: usize) -> Option<(u32, [u32; 4])> {
    let face = mesh.face(f);
    let [a, b, c] = diagonal_first(face, mesh.positions())?;
    let e = topo.edge(a as usize, b as usize)?;
    let [f0, f1] = topo.edge_faces(e) else {
        return None;
    };
    let g = if *f0 as usize == f { *f1 } else { *f0 };
    let other = mesh.face(g as usize);
    if other.len() != 3 || has_repeated_corner(other) {
        return None;
    }
    // The same orientation: the other face runs along the diagonal b -> a.
    let at = other.iter().position(|&v| v == b)?;
    if other[(at + 1) % 3] != a {
        return None;
    }
    let d = other[(at + 2) % 3];
    let p = mesh.positions();
    let (pa, pb, pc, pd) = (p[a as usize], p[b as usize], p[c as usize], p[d as usize]);
    let diagonal = (pb - pa).length();
    ((pd - (pa + pb - pc)).length() <= RECTANGLE_TOLERANCE * diagonal).then_some((g, [b, c, a, d]))
}

/// Triangle `face` as `[a, b, c]` in its own winding with `a -> b` its
/// longest edge, when the angle at `c` is right.
fn diagonal_first(face: &[u32], p: &[DVec3]) -> Option<[u32; 3]> {
    let &[x, y, z] = face else {
        return None;
    };
    if has_repeated_corner(face) {
        return None;
    }
    let len = |i: u32, j: u32| (p[j as usize] - p[i as usize]).length_squared();
    let rotations = [[x, y, z], [y, z, x], [z, x, y]];
    let [a, b, c] = rotations
        .into_iter()
        .max_by(|r, s| len(r[0], r[1]).total_cmp(&len(s[0], s[1])))?;
    let (ca, cb) = (p[a as usize] - p[c as usize], p[b as usize] - p[c as usize]);
    let cos = ca.dot(cb) / (ca.length() * cb.length());
    (cos.abs() <= RECTANGLE_TOLERANCE).then_some([a, b, c])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    /// `mesh` with every quad split along its `v0 v2` diagonal (`shift`
    /// 0) or its `v1 v3` one (`shift` 1), as an exporter to STL or glTF
    /// writes it.
    fn split(mesh: &Mesh, shift: usize) -> Mesh {
        let tris: Vec<[u32; 3]> = mesh
            .faces()
            .flat_map(|f| {
                let q = |i: usize| f[(i + shift) % f.len()];
                (1..f.len() - 1).map(move |j| [q(0), q(j), q(j + 1)])
            })
            .collect();
        Mesh::from_polygons(mesh.positions().to_vec(), &tris).unwrap()
    }

    #[test]
    fn a_split_voxel_mesh_pairs_back_into_its_quads() {
        let (_, quads) = shapes::voxel_sphere(6.0);
        let tris = split(&quads, 0);
        let paired = paired_voxel_faces(&tris, &Topology::build(&tris)).expect("a voxel mesh");
        assert_eq!(paired.pairs, quads.num_faces());
        assert_eq!(paired.mesh, quads);
    }

    #[test]
    fn a_quad_paired_back_splits_into_the_files_triangles() {
        // Split along the other diagonal: the quads start at another
        // corner, so that their split is still the file's.
        let (_, quads) = shapes::voxel_sphere(6.0);
        let tris = split(&quads, 1);
        let paired = paired_voxel_faces(&tris, &Topology::build(&tris)).expect("a voxel mesh");
        assert_eq!(paired.pairs, quads.num_faces());
        let canon = |f: &[u32]| {
            let i = (0..f.len()).min_by_key(|&i| f[i]).unwrap();
            let mut f = f.to_vec();
            f.rotate_left(i);
            f
        };
        let file: std::collections::HashSet<Vec<u32>> = tris.faces().map(canon).collect();
        let mut split_back = 0;
        for q in paired.mesh.faces() {
            for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                assert!(
                    file.contains(&canon(&t)),
                    "{t:?} is not a triangle of the file"
                );
                split_back += 1;
            }
        }
        assert_eq!(split_back, tris.num_faces());
    }

    #[test]
    fn a_rotated_thick_slice_mesh_far_from_the_origin_pairs_back() {
        // Voxels of 0.5 x 0.5 x 3 mm on a rotated grid a thousand
        // millimetres out, written with seven significant digits.
        let (_, quads) = shapes::voxel_sphere(6.0);
        let (s, c) = 0.5f64.sin_cos();
        let round7 = |x: f64| format!("{x:.6e}").parse::<f64>().unwrap();
        let far: Vec<DVec3> = quads
            .positions()
            .iter()
            .map(|p| {
                let q = *p * DVec3::new(0.5, 0.5, 3.0);
                let r = DVec3::new(c * q.x - s * q.y, s * q.x + c * q.y, q.z);
                let r = r + DVec3::new(-1234.5, 987.25, -765.125);
                DVec3::new(round7(r.x), round7(r.y), round7(r.z))
            })
            .collect();
        let mut tris = split(&quads, 0);
        tris.set_positions(far).unwrap();
        let paired = paired_voxel_faces(&tris, &Topology::build(&tris)).expect("a voxel mesh");
        assert_eq!(paired.pairs, quads.num_faces());
    }

    #[test]
    fn other_meshes_are_left_alone() {
        // A voxel lattice already, and triangles of no lattice.
        let (_, quads) = shapes::voxel_sphere(6.0);
        assert!(paired_voxel_faces(&quads, &Topology::build(&quads)).is_none());
        let (_, mc) = shapes::mc_sphere(6.0);
        assert!(paired_voxel_faces(&mc, &Topology::build(&mc)).is_none());
        // A box's marching cubes: squares split in two on every side, so
        // paired it would pass for a voxel lattice.
        let mask = shapes::VoxelMask::from_fn(glam::IVec3::ZERO, [24, 24, 24], |i, j, k| {
            [i, j, k].iter().all(|&c| (1..23).contains(&c))
        });
        let boxy = shapes::marching_cubes_mesh(&mask);
        let topo = Topology::build(&boxy);
        assert!((0..boxy.num_faces()).any(|f| split_partner(&boxy, &topo, f).is_some()));
        assert!(paired_voxel_faces(&boxy, &topo).is_none());
        // The split squares pushed onto a sphere: no longer rectangles.
        let (quads, projected) = crate::quality::fixtures::radially_projected_sphere(6.0);
        let mut round = split(&quads, 0);
        round.set_positions(projected).unwrap();
        assert!(paired_voxel_faces(&round, &Topology::build(&round)).is_none());
    }
}
