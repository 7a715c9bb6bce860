//! One-voxel slits and sheets of a marching-cubes mesh of a mask: their
//! crossings moved toward the voxel that is one voxel thick (our addition
//! to section 2.2; the paper's meshes sample no mask).
//!
//! A marching-cubes vertex of a binary mask sits at the midpoint of the
//! lattice edge between an inside and an outside voxel centre: the mask
//! says the surface crosses between them and nothing more. Where one of
//! the two voxels is a run one voxel long along the edge's axis (the
//! surface also crosses on its far side: an outside voxel between two
//! inside ones, a slit such as a sulcus one voxel wide; or an inside voxel
//! between two outside ones, a sheet such as a cortical ribbon one voxel
//! thick), the map the mask was thresholded from only just crossed its
//! level at that voxel's centre: the structure is thinner than a voxel, and
//! its surface crosses the edge nearer that centre than the midpoint. The
//! midpoint puts every such slit and sheet a full voxel across, and no
//! smoothing step narrows it: the passes' fits and the volume restoration
//! keep a surface where its vertices are.
//!
//! [`shift_thin_runs`] moves each such vertex [`THIN_RUN_SHIFT`] of its
//! edge toward that voxel's centre. It reads the runs off the mesh alone
//! (the vertex one spacing further along the same axis is the far
//! crossing), so the mesh's orientation does not matter: a slit and a
//! sheet are both a run one voxel long, and both get narrower.

use super::fidelity::{Fidelity, in_frame_of};
use crate::mesh::lattice::MarchingCubesGrid;
use glam::DVec3;
use rayon::prelude::*;

/// How far a thin run's crossings move toward its voxel's centre, in
/// spacings of the edge's axis. On the real masks' marching cubes, where
/// the probability map they were thresholded from crosses its level along
/// such an edge lies a median 0.14-0.19 spacing beyond the midpoint toward
/// the one-voxel slit, and 0.08-0.20 toward the one-voxel sheet
/// (`docs/tuning.md`): the slit is narrower and the sheet thinner than the
/// voxel the mask gives them. Elsewhere the crossing's median is the
/// midpoint, and those vertices stay.
pub const THIN_RUN_SHIFT: f64 = 0.15;

/// Moves every `movable` vertex of a marching-cubes mesh whose lattice edge
/// (`grid`, built from `input`) has a run one voxel long on exactly one of
/// its two sides [`THIN_RUN_SHIFT`] of its spacing toward that run's voxel
/// centre, from wherever it is in `positions`, within the fidelity bound.
/// A vertex between two such runs (a voxel-wide sheet beside a voxel-wide
/// slit) stays: which of them is the thinner the mask does not say.
/// Returns how many vertices moved. `O(n log n)` (the vertices sorted by
/// grid position once), deterministic and parallel per vertex.
pub fn shift_thin_runs(
    grid: &MarchingCubesGrid,
    input: &[DVec3],
    positions: &mut [DVec3],
    movable: &[bool],
    fidelity: &Fidelity,
) -> usize {
    let keys = grid_keys(grid, input);
    let mut sorted: Vec<[i32; 3]> = keys.iter().flatten().copied().collect();
    sorted.sort_unstable();
    let has = |k: [i32; 3]| sorted.binary_search(&k).is_ok();
    let moves: Vec<Option<DVec3>> = (0..positions.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            if !movable.get(v).copied().unwrap_or(false) {
                return None;
            }
            let edge = grid.edges.get(v).copied().flatten()?;
            let key = keys.get(v).copied().flatten()?;
            let axis = usize::from(edge.axis);
            let step = |by: i32| {
                let mut k = key;
                k[axis] = k[axis].checked_add(by)?;
                Some(k)
            };
            // The neighbouring crossings along the edge's axis sit two half
            // spacings away, at the next edges of the same line of voxels.
            let ahead = step(2).is_some_and(has);
            let behind = step(-2).is_some_and(has);
            let sign = match (ahead, behind) {
                (true, false) => 1.0,
                (false, true) => -1.0,
                _ => return None,
            };
            Some(grid.direction(edge) * (sign * THIN_RUN_SHIFT * edge.spacing))
        })
        .collect();
    let mut moved = 0;
    for (p, m) in positions.iter_mut().zip(&moves) {
        if let Some(m) = m {
            *p += *m;
            moved += 1;
        }
    }
    if moved > 0 {
        fidelity.apply(positions);
    }
    moved
}

/// Each vertex's position on `grid` in half spacings from the first
/// vertex on a lattice edge (`None` off the lattice's edges, or too far to
/// count in `i32`): every vertex on an edge lies at whole half spacings
/// from every other.
fn grid_keys(grid: &MarchingCubesGrid, input: &[DVec3]) -> Vec<Option<[i32; 3]>> {
    let Some(origin) = grid
        .edges
        .iter()
        .zip(input)
        .find_map(|(e, &p)| e.map(|_| p))
    else {
        return vec![None; input.len()];
    };
    let half = grid.spacing * 0.5;
    input
        .par_iter()
        .zip(&grid.edges)
        .with_min_len(4096)
        .map(|(&p, e)| {
            e.as_ref()?;
            let k = (in_frame_of(&grid.frame, p - origin) / half).round();
            let fits = |x: f64| x.abs() < f64::from(i32::MAX);
            (fits(k.x) && fits(k.y) && fits(k.z)).then_some([k.x as i32, k.y as i32, k.z as i32])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Topology;
    use crate::mesh::lattice::marching_cubes_grid;
    use crate::shapes::{VoxelMask, marching_cubes_mesh};
    use glam::IVec3;

    /// The marching cubes of `inside` over a box of 12 voxels, and its
    /// positions after [`shift_thin_runs`] with no bound and every vertex
    /// `movable` or none: the input, the output and how many moved.
    fn shifted(
        inside: impl Fn(usize, usize, usize) -> bool + Sync,
        movable: bool,
    ) -> (Vec<DVec3>, Vec<DVec3>, usize) {
        let mask = VoxelMask::from_fn(IVec3::ZERO, [12, 12, 12], inside);
        let mesh = marching_cubes_mesh(&mask);
        let topo = Topology::build(&mesh);
        let grid = marching_cubes_grid(&topo, mesh.positions()).expect("a marching-cubes mesh");
        let input = mesh.positions().to_vec();
        let mut positions = input.clone();
        let movable = vec![movable; input.len()];
        let moved = shift_thin_runs(
            &grid,
            &input,
            &mut positions,
            &movable,
            &Fidelity::unbounded(),
        );
        (input, positions, moved)
    }

    /// Voxel `(i, j, k)` has its centre at `(i, j, k) + 0.5`.
    fn inner(i: usize, j: usize) -> bool {
        (2..10).contains(&i) && (2..10).contains(&j)
    }

    /// A sheet one voxel thick (`k` = 5) with a pillar on one corner, which
    /// gives the mesh a grid to find along z.
    fn sheet(i: usize, j: usize, k: usize) -> bool {
        inner(i, j) && (k == 5 || (i < 4 && j < 4 && (5..9).contains(&k)))
    }

    #[test]
    fn a_sheet_one_voxel_thick_gets_thinner_and_a_thick_one_stays() {
        // A sheet one voxel thick along z: away from the pillar its two
        // faces move toward its middle plane, the rim's crossings along x
        // and y stay.
        let (input, out, moved) = shifted(sheet, true);
        assert!(moved > 0);
        let mid = 5.0 + 0.5;
        let away = input
            .iter()
            .zip(&out)
            .filter(|(p, _)| p.x > 5.0 && p.y > 5.0);
        for (p, q) in away {
            let off_face = (p.z - mid).abs() < 0.25;
            if off_face {
                assert_eq!(p, q, "a rim crossing moved");
            } else {
                let expected = (p.z - mid).abs() - THIN_RUN_SHIFT;
                assert!(((q.z - mid).abs() - expected).abs() < 1e-12);
                assert_eq!((p.x, p.y), (q.x, q.y));
            }
        }
        // Three voxels thick: no run is one voxel long.
        let (input, out, moved) = shifted(|i, j, k| inner(i, j) && (4..7).contains(&k), true);
        assert_eq!(moved, 0);
        assert_eq!(input, out);
    }

    #[test]
    fn a_slit_one_voxel_wide_gets_narrower() {
        // Two blocks with a slit one voxel wide between them (x = 5): the
        // crossings on its two walls move toward its middle.
        let (input, out, _) = shifted(
            |i, j, k| inner(j, k) && (2..10).contains(&i) && i != 5,
            true,
        );
        let mid = 5.0 + 0.5;
        let mut walls = 0;
        for (p, q) in input.iter().zip(&out) {
            if ((p.x - mid).abs() - 0.5).abs() < 1e-9 && inner(p.y as usize, p.z as usize) {
                walls += 1;
                assert!(((q.x - mid).abs() - (0.5 - THIN_RUN_SHIFT)).abs() < 1e-12);
            }
        }
        assert!(walls > 0);
    }

    #[test]
    fn fixed_vertices_stay() {
        let (input, out, moved) = shifted(sheet, false);
        assert_eq!(moved, 0);
        assert_eq!(input, out);
    }
}
