"""Unseen real surfaces: level sets of the MNI152 T1-weighted template in
seeded random blocks, at a random tissue boundary and grid placement,
smoothed by meshsmooth and by the peers' sweep and measured against the same
truth. No constant of meshsmooth was tuned on them.

    python3 eval/fetch_mni152.py
    python3 -u eval/t1_levels.py [--cases 24] [--first 0] [--truth map,grid] [--no-peers] [--params FILE.json]

Case `k` draws, from a generator seeded by `k`:
- a block of `--size` voxels (40) at least 20 voxels from the template's edges;
- a level among `LEVELS` (the template's intensity between CSF, grey and white
  matter and beyond: 40.5 to 210.5) whose mask fills 15-85% of the block;
  cases where none does are skipped;
- a placement: the template's own grid for every third case, else a seeded
  offset and rotation (`real_placements.placement`).

The mask is where the block's trilinear interpolation, sampled at the
placement's voxel centres, exceeds the level (`real_placements.resampled_mask`),
meshed as voxel quads and as marching cubes. Two truths (`--truth`):
- `map`: the level of the template's own trilinear interpolation (the
  default truth of `real_placements.py`);
- `grid`: the level of the placement's own samples, trilinearly interpolated
  (`real_placements.py --grid-truth`): what a scanner placed there would call
  true. At the template's own grid both are the same.

Distances are in mm (the template's voxels are 1 mm), over the vertices at
least 3 voxels inside the block. The bar of a mesh is the best truth RMS any
setting of the peers' sweep (`real_placements.peers`) reaches on it, chosen
per mesh and per truth: stricter than any one setting for all. The summary
gives, per mesh kind and truth, the geometric mean and the worst of ours over
the bar, and how many meshes we are closer on, apart for the cases whose
level is a step of the map (`STEP_SPREAD`: the crossing spread column); `--no-peers` prints ours
alone, with the median and geometric mean of its RMS, to compare builds or
parameter files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_peers as cp  # noqa: E402
import meshmetrics as mm  # noqa: E402
import real_placements as rp  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
# The template's intensity at the boundaries the levels sample: CSF (about
# 40-70), grey matter (about 167), white matter (about 220) and between; each
# ends in .5 because the template is stored as bytes (at a whole level the
# voxels equal to it would sit on the truth itself).
LEVELS = (40.5, 60.5, 90.5, 118.5, 150.5, 180.5, 193.5, 210.5)
# The share of the block a mask must fill: a level that leaves a few specks
# or a few holes tells little about a surface.
FILL = (0.15, 0.85)
# Vertices this many voxels inside the block are measured: the block's walls
# close every mask, and their edges are not anatomy.
MARGIN = 3
# Where the map crosses the level along the template's grid edges, as a
# fraction of the edge: spread evenly over the edge (standard deviation
# 0.289) where the map varies smoothly across the boundary, bunched near one
# point where the map steps from one value to another between two voxels
# (the brain mask's edge: the template is 0 outside the brain). There
# the trilinear level set is the template's own voxel staircase, softened:
# a surface with no sub-voxel information, which the smoothers are not
# meant to reproduce. Cases under this spread are summarised apart.
STEP_SPREAD = 0.2


def crossing_spread(block, level):
    """The standard deviation of the map's crossing positions of `level`
    along the block's grid edges (0 to 1 along each edge)."""
    spread = []
    for a in range(3):
        v = np.moveaxis(block, a, 0)
        lo, hi = v[:-1], v[1:]
        crossed = (lo > level) != (hi > level)
        spread.append((level - lo[crossed]) / (hi[crossed] - lo[crossed]))
    return float(np.concatenate(spread).std())


def case(template, k, size):
    """Case `k`'s block (the template's values), level and placement, or
    None where no level fills the block within `FILL`."""
    rng = np.random.default_rng(1000 + k)
    first = [int(rng.integers(20, s - size - 20)) for s in template.shape]
    block = template[tuple(slice(f, f + size) for f in first)]
    levels = [lv for lv in LEVELS if FILL[0] < (block > lv).mean() < FILL[1]]
    if not levels:
        return None
    level = float(rng.choice(levels))
    seed = 0 if k % 3 == 0 else int(rng.integers(1, 50))
    return block, first, level, seed


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mni152", default=str(ROOT / "eval" / ".mni152"), help="fetch_mni152.py's folder")
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--cases", type=int, default=24)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--size", type=int, default=40, help="block edge in voxels")
    ap.add_argument("--truth", default="map,grid", help="map, grid or both")
    ap.add_argument("--kinds", default="vox,mc")
    ap.add_argument("--no-peers", action="store_true", help="meshsmooth alone")
    ap.add_argument("--params", help="meshsmooth parameter file")
    args = ap.parse_args()
    import nibabel as nib

    template = np.asarray(nib.load(str(Path(args.mni152) / rp.T1)).dataobj, dtype=np.float64)
    ours = cp.meshsmooth(args.binary, ["--params", args.params] if args.params else [])
    sweep = {} if args.no_peers else rp.peers()
    truths = args.truth.split(",")
    kinds = args.kinds.split(",")
    # Per mesh kind, truth and whether the level is a step of the map (under
    # `STEP_SPREAD`): ours over the bar, or ours alone without peers.
    figures = {(kind, t, step): [] for kind in kinds for t in truths for step in (False, True)}
    print("| case | level | block | placement | crossing spread | mesh | vertices | truth | input | meshsmooth | best peer "
          "| ratio | setting | ours flipped/twisted/min angle/max move (voxels) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for k in range(args.first, args.first + args.cases):
        drawn = case(template, k, args.size)
        if drawn is None:
            print(f"| {k} | no level fills 15-85% of its block: skipped |")
            continue
        block, first, level, seed = drawn
        spread = crossing_spread(block, level)
        step = spread < STEP_SPREAD
        rot, offset = rp.placement(seed)
        mask, to_data, sampled = rp.resampled_mask(block, rot, offset, (1.0, 1.0, 1.0), level)
        # The block's voxel index is the world coordinate: distances in voxels.
        # The map's truth also says which vertices are measured (those inside
        # the block), for the grid's truth too, whose own extent is larger.
        crop = mm.Truth(data=block, affine=np.eye(4), level=level)
        here = {}
        if "map" in truths:
            here["map"] = crop
        if "grid" in truths:
            # At the template's own grid its samples are the map's: one truth.
            grid = crop
            if seed:
                grid = rp.grid_truth(sampled, to_data, np.eye(4), level)
                grid.inside_crop = crop.inside_crop
            here["grid"] = grid
        qv, qf = rp.voxel_quads(mask)
        for kind in kinds:
            v, f = (qv, qf) if kind == "vox" else rp.marching_cubes(mask, mm.signed_volume(qv, mm.triangles(qf)))
            world = to_data(v)
            out = ours(world, f)
            q = mm.quality(world, f, out)
            peers = {}
            for setting, run in sweep.items():
                try:
                    peers[setting] = run(world, f)
                except Exception:  # a peer that refuses a mesh is left out
                    continue
            measured = {}  # per truth object: the two truths are one at the own grid
            for t, truth in here.items():
                if id(truth) not in measured:
                    r_in, r_ours = (rp.truth_rms(truth, p, MARGIN) for p in (world, out))
                    best = min(((rp.truth_rms(truth, p, MARGIN), s) for s, p in peers.items()), default=None)
                    measured[id(truth)] = (r_in, r_ours, best)
                r_in, r_ours, best = measured[id(truth)]
                bar = "- | - | -"
                if best:
                    figures[(kind, t, step)].append(r_ours / best[0])
                    bar = f"{best[0]:.4f} | {r_ours / best[0]:.3f} | {best[1]}"
                else:
                    figures[(kind, t, step)].append(r_ours)
                print(
                    f"| {k} | {level} | {first} | {seed} | {spread:.3f} | {kind} | {len(world)} | {t} | {r_in:.4f} | {r_ours:.4f} "
                    f"| {bar} | {q['flipped']}/{q['twisted']}/{q['min_angle']:.1f}/{q['max_move']:.2f} |",
                    flush=True,
                )
    for (kind, t, step), r in figures.items():
        if not r:
            continue
        which = f"{kind}, {t} truth, {len(r)} meshes" + (" at a step of the map" if step else "")
        if sweep:
            print(f"{which}: ours over the best peer setting {rp.ratio_summary(r)}")
        else:
            print(f"{which}: {rp.rms_summary(r)}")


if __name__ == "__main__":
    main()
