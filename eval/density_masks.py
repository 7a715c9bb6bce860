"""Segmentations of a blurred image whose continuous field is known: a real
protein's density map, thresholded at seeded grid placements; the truth is
the field's own level surface.

The MNI152 probability maps are known only at their voxels, so their truth
is the trilinear level of the samples; the voxelised meshes of
`mesh_masks.py` come from an exact inside test, with no blur at all. A
microscope or an electron cryo-microscope images a structure through a
point-spread function: the image is a smooth field, and the segmentation
thresholds its samples. Here that field is known everywhere: the data
folder's myoglobin (PDB 2JHO, every atom but the waters) as a sum of
Gaussians, one per atom, weighted by its atomic number and as wide as a
map of a given resolution (ChimeraX's `molmap`: sigma = 0.225 x the
resolution), thresholded at the level whose enclosed volume is that of the
data folder's molecular surface of the same protein (`gamer_2jho.obj`). A
voxel is inside where the field at its centre is above the level; the mask
is meshed as voxel quads and as marching cubes, smoothed by meshsmooth and
by the peers' sweep, and measured against the level surface. No constant
of meshsmooth was tuned on these meshes.

    python3 -u eval/density_masks.py [--only 4A_0.7,4A_1.0,4A_1.5,6A_1.5] [--placements 2] [--kinds vox,mc] [--no-peers] [--params FILE.json]

With the peers' sweep a placement takes minutes (the 0.7 A map's, about
ten on two cores); `--no-peers` takes under a minute.

Per mesh (a map at one resolution and voxel size, at one placement: seed 0
the PDB's axes, other seeds a random rotation and sub-voxel offset, as in
`real_placements.placement`):
- the truth RMS in voxels: the RMS exact distance of the output's vertices
  to the level surface (marching cubes of the field evaluated on a grid
  `TRUTH_REFINE` times finer, each vertex then taken onto the level by
  Newton steps along the field's gradient; `trimesh`'s closest point on its
  triangles), for the input, meshsmooth and the best setting of the peers'
  sweep (`real_placements.peers`), and the best of the settings that keep
  the input's volume within 2%;
- the volume change of meshsmooth's output from its input, and the input's
  volume against the level surface's;
- flipped faces, twisted quads, the smallest angle and the largest move (in
  voxels) of meshsmooth's output.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import meshmetrics as mm  # noqa: E402
import real_placements as rp  # noqa: E402

# Maps: (resolution in angstrom, voxel size in angstrom). Electron
# cryo-microscopy maps are sampled at a sixth to a half of their
# resolution, so the protein's helices and loops (a resolution or two
# across) are two to ten voxels.
MAPS = {
    "4A_0.7": (4.0, 0.7),
    "4A_1.0": (4.0, 1.0),
    "4A_1.5": (4.0, 1.5),
    "6A_1.5": (6.0, 1.5),
}
# ChimeraX's `molmap`: each atom's Gaussian has this width per angstrom of
# resolution (1 / (pi sqrt 2)).
SIGMA_PER_RESOLUTION = 0.225
# Each atom's Gaussian is cut off this many widths out (exp(-12.5) of its
# peak): the mask, the truth and its Newton steps use the same field.
CUTOFF_SIGMAS = 5.0
# The truth surface's grid is this many times finer than the mask's.
TRUTH_REFINE = 4
# Newton steps that take the truth surface's vertices onto the level.
NEWTON_STEPS = 3
# Atomic numbers of the elements in the PDB file.
ATOMIC_NUMBER = {"C": 6, "N": 7, "O": 8, "P": 15, "S": 16, "FE": 26, "ZN": 30}
# The atoms gathered per point for the Newton steps (checked: none beyond
# the cut-off is left out), and the points taken at once.
NEAR_ATOMS = 256
NEWTON_CHUNK = 4096
# Empty voxels beyond the reach of the atoms' Gaussians.
PAD = 3


def read_atoms(path):
    """The positions (angstrom) and atomic numbers of the PDB file's atoms,
    leaving out the waters."""
    pos, z = [], []
    for line in Path(path).read_text().splitlines():
        if not line.startswith(("ATOM", "HETATM")) or line[17:20] == "HOH":
            continue
        element = line[76:78].strip().upper() or line[12:14].strip().upper()
        pos.append([float(line[30:38]), float(line[38:46]), float(line[46:54])])
        z.append(ATOMIC_NUMBER[element])
    return np.asarray(pos), np.asarray(z, dtype=float)


def splat(centres, weights, sigma, shape, step):
    """The field on the grid of `shape` whose node (i, j, k) lies at
    `step * (i, j, k)` (all in voxels): each atom's Gaussian added over the
    nodes within its cut-off."""
    field = np.zeros(shape)
    reach = CUTOFF_SIGMAS * sigma
    for c, w in zip(centres, weights):
        lo = np.maximum(np.ceil((c - reach) / step).astype(int), 0)
        hi = np.minimum(np.floor((c + reach) / step).astype(int) + 1, shape)
        axes = [np.arange(lo[a], hi[a]) * step - c[a] for a in range(3)]
        d2 = axes[0][:, None, None] ** 2 + axes[1][None, :, None] ** 2 + axes[2][None, None, :] ** 2
        g = w * np.exp(-0.5 * d2 / sigma**2)
        g[d2 > reach * reach] = 0.0
        field[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] += g
    return field


def field_at(points, tree, centres, weights, sigma):
    """The field and its gradient at `points` (voxels), from the atoms
    within the cut-off (a `scipy` k-d tree over `centres`)."""
    value = np.zeros(len(points))
    grad = np.zeros_like(points)
    reach = CUTOFF_SIGMAS * sigma
    for start in range(0, len(points), NEWTON_CHUNK):
        p = points[start : start + NEWTON_CHUNK]
        dist, near = tree.query(p, k=NEAR_ATOMS, distance_upper_bound=reach)
        if np.isfinite(dist[:, -1]).any():
            raise SystemExit(f"more than {NEAR_ATOMS} atoms within the cut-off: raise NEAR_ATOMS")
        found = np.isfinite(dist)
        near = np.where(found, near, 0)
        d = p[:, None, :] - centres[near]
        g = np.where(found, weights[near] * np.exp(-0.5 * dist**2 / sigma**2), 0.0)
        value[start : start + len(p)] = g.sum(axis=1)
        grad[start : start + len(p)] = -(g[:, :, None] * d).sum(axis=1) / sigma**2
    return value, grad


def truth_surface(centres, weights, sigma, volume, shape):
    """The level whose super-level set holds `volume` (voxels cubed), and
    its level surface (vertices in voxels, triangles): both from the field
    on a grid `TRUTH_REFINE` times finer than the mask's, the surface's
    vertices then moved onto the level by Newton steps."""
    from scipy.spatial import cKDTree
    from skimage.measure import marching_cubes

    step = 1.0 / TRUTH_REFINE
    field = splat(centres, weights, sigma, tuple(int(n) * TRUTH_REFINE for n in shape), step)
    level = float(np.sort(field.ravel())[::-1][int(round(volume / step**3))])
    v, f, _, _ = marching_cubes(field, level)
    del field
    v = v.astype(np.float64) * step
    tree = cKDTree(centres)
    for _ in range(NEWTON_STEPS):
        value, grad = field_at(v, tree, centres, weights, sigma)
        v -= ((value - level) / (grad * grad).sum(axis=1))[:, None] * grad
    return level, v, f


def main():
    import trimesh

    args, ours, bars, kinds = rp.mask_arguments(__doc__, MAPS, 2)
    atoms, weights = read_atoms(Path(args.data) / "gamer_2jho.pdb")
    ses_v, ses_f = mm.read_obj(str(Path(args.data) / "gamer_2jho.obj"))
    ses_volume = abs(mm.signed_volume(ses_v, mm.triangles(ses_f)))
    rp.mask_header(["map", "placement", "mesh"])
    for name in args.only.split(","):
        resolution, voxel = MAPS[name]
        sigma = SIGMA_PER_RESOLUTION * resolution / voxel
        for seed in range(args.placements):
            rot, offset = rp.placement(seed)
            g = (atoms @ rot) / voxel
            g = g - np.floor(g.min(axis=0)) + np.ceil(CUTOFF_SIGMAS * sigma) + PAD + offset
            shape = tuple(int(n) for n in np.ceil(g.max(axis=0) + CUTOFF_SIGMAS * sigma) + PAD + 1)
            level, tv, tf = truth_surface(g, weights, sigma, ses_volume / voxel**3, shape)
            truth = trimesh.Trimesh(tv, tf, process=False)
            mask = splat(g, weights, sigma, shape, 1.0) > level
            for kind, cells in rp.mask_rows(mask, truth, kinds, ours, bars):
                print(f"| {name} | {seed} | {kind} | {cells}", flush=True)
    bars.print_summary()


if __name__ == "__main__":
    main()
