"""The real masks at other grid placements: each probability map of the data
folder resampled on seeded shifted and rotated grids, thresholded, meshed as
voxel quads and as marching cubes, smoothed by meshsmooth and by the peers
over a sweep of their settings, and measured against the same truth.

    python3 eval/real_placements.py [--data DIR] [--placements N] [--first SEED] [--only NAME,...] [--params FILE.json] [--kinds vox,mc] [--level L]

A mask is where the trilinearly interpolated map exceeds 127.5 at a voxel
centre, and the truth is the surface where it equals 127.5 (meshmetrics.Truth),
so every placement is a mask of the same continuous surface, sampled by
another grid: what a scanner puts wherever the head lies. Placement 0 is the
map's own grid (its voxel quads are the data folder's mesh; for `gm_1mm`, the
grid that splits each of the map's voxels in eight); the others take a
random sub-voxel offset and a random rotation (`--no-rotation`: the offset
alone), seeded by the placement's number. `gm_1mm` samples the GM map on grids
of half its spacing: a mask of the same truth at a 1 mm segmentation's
resolution (about 450k vertices as voxel quads; with the peers' sweep, minutes
per placement). `wm_thick` samples the WM crop's map on voxels 2.5 times as
long along the grid's third axis: a thick-slice acquisition (1 x 1 x 2.5 mm),
which many clinical segmentations are; `gm_thick` the GM map at 1 x 1 x 2.5 mm
(half its spacing in-plane), a thin folded sheet cut in thick slices;
`wm_axial` the WM crop's map at 0.5 x 0.5 x 3 mm, a clinical axial series
(voxels six times as deep as wide); `wm_4mm` at 1 x 1 x 4 mm, whose side
walls split at 14 degrees, just above the sliver floor. The
meshes are made here the way the data folder's were: voxel quads with every
boundary face of the mask (corners shared, non-manifold where voxels touch
along an edge or at a corner), marching cubes by scikit-image at level 0.5 on
the mask. The WM crop is measured over the vertices at least 3
voxels inside its crop, the GM map over all. `--level` thresholds the map
elsewhere than at 127.5, with the truth at the same level: a segmentation
drawn thicker (64) or thinner (191) than the data folder's masks.
`wm_brain` and `gm_brain` are the whole-brain 1 mm maps the data folder's
were cut from (`python3 eval/fetch_mni152.py` puts them in `eval/.mni152`):
at placement 0 their masks are the issue's held-out 1 mm white- and
grey-matter masks (314,946 and 534,618 vertices as voxel quads).
`t1_white` and `t1_pial` are level sets of the T1-weighted template of the
same release (also from `fetch_mni152.py`), in the WM crop's 48-voxel block:
the template's intensity halfway between the medians of white and grey
matter (220 and 167: level 193.5) and between grey matter and the CSF in the
sulci (167 and 70: level 118.5), a white and a pial surface, with the
template itself as the map whose level is the truth. `t1_white_b` and
`t1_pial_b` are the same in a second block, in the other hemisphere. No
constant was tuned on them.

For each mesh the table gives meshsmooth at its defaults and the best truth
RMS any peer setting reaches on that same mesh (and which setting), then the
worst and the median over the placements. Truth RMS is over the vertices (the
issue's measure); meshsmooth's over its whole surface (`meshmetrics.surface_rms`)
is printed beside it. The bar is the best peer setting
per placement, a stricter one than a single setting for all. `--grid-truth`
measures each placement against the map sampled on its own grid instead
(the level of those samples' own trilinear interpolation): the truth a
scanner placed there would give its own map, where the default keeps the
original grid's (whose trilinear tents a rotated grid's centres miss).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_peers as cp  # noqa: E402
import meshmetrics as mm  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

# name: (probability map, crop margin in voxels or None, grid spacing in the
# map's voxels, one per grid axis[, level, block]): the level of the mask and
# its truth when the map has its own (else `--level`), and the block of the map
# to use (first voxel, size) when not all of it. `gm_1mm` has the truth of
# `gm_2mm` (a trilinear map restricted to a half cell is trilinear) with the
# cortex two or three voxels thick instead of one or two.
T1 = "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"
# The WM crop's block of the whole-brain maps, and one as large in the other
# hemisphere, further forward and up.
BLOCK_A = ((60, 100, 70), 48)
BLOCK_B = ((89, 120, 95), 48)
MAPS = {
    "wm_crop": ("mni152_wm_crop48_1mm_prob.nii.gz", 3, (1.0, 1.0, 1.0)),
    "gm_2mm": ("mni152_gm_2mm_prob.nii.gz", None, (1.0, 1.0, 1.0)),
    "gm_1mm": ("mni152_gm_2mm_prob.nii.gz", None, (0.5, 0.5, 0.5)),
    "wm_thick": ("mni152_wm_crop48_1mm_prob.nii.gz", 3, (1.0, 1.0, 2.5)),
    "gm_thick": ("mni152_gm_2mm_prob.nii.gz", None, (0.5, 0.5, 1.25)),
    "wm_axial": ("mni152_wm_crop48_1mm_prob.nii.gz", 3, (0.5, 0.5, 3.0)),
    "wm_4mm": ("mni152_wm_crop48_1mm_prob.nii.gz", 3, (1.0, 1.0, 4.0)),
    # The whole-brain maps of `fetch_mni152.py` (in `--mni152`): at placement
    # 0 their masks are the held-out 1 mm masks.
    "wm_brain": ("mni_icbm152_wm_tal_nlin_sym_09a_converted.nii.gz", None, (1.0, 1.0, 1.0)),
    "gm_brain": ("mni_icbm152_gm_tal_nlin_sym_09a_converted.nii.gz", None, (1.0, 1.0, 1.0)),
    "t1_white": (T1, 3, (1.0, 1.0, 1.0), 193.5, BLOCK_A),
    "t1_pial": (T1, 3, (1.0, 1.0, 1.0), 118.5, BLOCK_A),
    "t1_white_b": (T1, 3, (1.0, 1.0, 1.0), 193.5, BLOCK_B),
    "t1_pial_b": (T1, 3, (1.0, 1.0, 1.0), 118.5, BLOCK_B),
}
# Maps looked for in `--mni152` instead of `--data`; not run unless named in
# `--only` (the whole-brain meshes have 315k-535k vertices; the peers' sweep
# takes minutes).
FETCHED = ("wm_brain", "gm_brain", "t1_white", "t1_pial", "t1_white_b", "t1_pial_b")
LEVEL = 127.5


def placement(seed, rotate=True):
    """The rotation and the offset of placement `seed` (0: the map's grid;
    without `rotate`, the offset alone)."""
    if seed == 0:
        return np.eye(3), np.zeros(3)
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return (rot if rotate else np.eye(3)), rng.uniform(0.0, 1.0, 3)


def resampled_mask(data, rot, offset, spacing=(1.0, 1.0, 1.0), level=LEVEL):
    """The mask of `data`'s trilinear map on the grid rotated by `rot`,
    shifted by `offset` (voxels) about the volume's centre and of `spacing`
    (in `data`'s voxels, per grid axis), thresholded at `level`, and the map
    from that grid's voxel coordinates to `data`'s, and the map's values at
    that grid's voxel centres."""
    from scipy.ndimage import map_coordinates

    spacing = np.asarray(spacing, dtype=float)
    shape = np.asarray(data.shape, dtype=float)
    centre = (shape - 1) / 2
    extent = np.ceil(np.abs(rot.T) @ shape / spacing).astype(int) + 2
    new_centre = (extent - 1) / 2

    def to_data(v):
        return spacing * (v - new_centre) @ rot.T + centre + offset

    grid = np.stack(np.meshgrid(*[np.arange(n) for n in extent], indexing="ij"), -1).reshape(-1, 3)
    sampled = map_coordinates(data, to_data(grid.astype(float)).T, order=1, cval=0.0).reshape(tuple(extent))
    return sampled > level, to_data, sampled


def grid_truth(sampled, to_data, affine, level):
    """The truth of a map sampled on a placement's grid (`resampled_mask`'s
    third value): the level of their own trilinear interpolation, what a scanner
    placed there and thresholding its own map would have."""
    origin = to_data(np.zeros(3))
    linear = np.stack([to_data(np.eye(3)[k]) - origin for k in range(3)], axis=1)
    grid_affine = np.eye(4)
    grid_affine[:3, :3] = affine[:3, :3] @ linear
    grid_affine[:3, 3] = affine[:3, :3] @ origin + affine[:3, 3]
    return mm.Truth(level=level, data=sampled, affine=grid_affine)


def voxel_quads(mask):
    """Every boundary face of `mask` as an outward quad; corners shared, in
    voxel coordinates (a voxel's centre at its index)."""
    m = np.pad(mask, 1)
    dims = np.asarray(m.shape)

    def corner_id(c):
        return (c[:, 0] * (dims[1] + 1) + c[:, 1]) * (dims[2] + 1) + c[:, 2]

    quads = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[a], hi[a] = slice(0, -1), slice(1, None)
        inside, outside = m[tuple(lo)], m[tuple(hi)]
        for sign, where in ((1, inside & ~outside), (-1, ~inside & outside)):
            idx = np.argwhere(where)
            base = idx.copy()
            base[:, a] += 1
            eb, ec = np.eye(3, dtype=int)[b], np.eye(3, dtype=int)[c]
            ring = [base, base + eb, base + eb + ec, base + ec]
            if sign < 0:
                ring = ring[::-1]
            quads.append(np.stack([corner_id(r) for r in ring], 1))
    quads = np.concatenate(quads)
    used, faces = np.unique(quads, return_inverse=True)
    faces = faces.reshape(-1, 4)
    k = used % (dims[2] + 1)
    j = (used // (dims[2] + 1)) % (dims[1] + 1)
    i = used // ((dims[2] + 1) * (dims[1] + 1))
    # Corner index k of the padded grid lies at voxel coordinate k - 1.5.
    verts = np.stack([i, j, k], 1).astype(float) - 1.5
    return verts, [list(f) for f in faces]


def marching_cubes(mask, outward_like):
    """scikit-image's marching cubes of `mask` at 0.5, oriented like the
    voxel quads `outward_like` (same sign of the enclosed volume)."""
    from skimage.measure import marching_cubes as mc

    v, f, _, _ = mc(np.pad(mask.astype(np.float32), 1), 0.5)
    v -= 1.0
    if np.sign(mm.signed_volume(v, f)) != np.sign(outward_like):
        f = f[:, ::-1]
    return v, [list(t) for t in f]


def grid_move(world_in, world_out, affine, rot, spacing):
    """The largest move from `world_in` to `world_out` in the voxels of the
    grid the mesh was cut from (rotated by `rot`, of `spacing` map voxels
    per axis): a thick slice's voxel is one voxel long across it too."""
    to_map = np.linalg.inv(affine[:3, :3])
    moves = ((world_out - world_in) @ to_map.T) @ rot / np.asarray(spacing, dtype=float)
    return float(np.linalg.norm(moves, axis=1).max())


def peers():
    """The settings swept on every placement: those that reached the best
    truth on some real mask of the data folder, and their neighbours."""
    all_settings = cp.sweep()
    keep = [
        *(f"PyMeshLab {k} Laplacian {s} steps" for k in ("cotangent", "uniform") for s in (1, 2, 3, 5)),
        *(f"PyMeshLab Taubin {s} steps lambda {lam}" for s in (10, 20, 50) for lam in (0.5, 0.7)),
        "PyMeshLab HC Laplacian x1",
        "PyMeshLab HC Laplacian x2",
        *(f"VTK windowed sinc {it} it pass band {b}" for it in (20, 35, 50) for b in (0.005, 0.01, 0.05, 0.1)),
    ]
    return {k: all_settings[k] for k in keep}


def truth_rms(truth, verts, margin):
    """RMS distance of `verts` (those `margin` voxels inside the map, if
    given) to the truth: the sweep needs nothing else, and the other
    measures cost far more."""
    sel = np.ones(len(verts), bool) if margin is None else truth.inside_crop(verts, margin)
    d = truth.distances(verts[sel])
    return float(np.sqrt((d * d).mean()))


# The volume change a peer setting may make and still count for the second
# bar of `mask_rows`: the promise for neurons and thin shapes.
MASK_VOLUME_KEPT = 0.02


class Bars:
    """Ours against two bars per mesh, gathered over many meshes of a kind:
    the best setting of a peer sweep, and the best of the settings that keep
    the input's volume within `volume_kept` (the issue's promise for neurons
    and thin shapes: the settings closest to the truth on thin parts shrink
    them)."""

    def __init__(self, sweep, volume_kept):
        self.sweep = sweep
        self.volume_kept = volume_kept
        self.best = {}
        self.kept = {}

    def columns(self, kind, verts, faces, ours_rms, rms):
        """Runs every setting on the mesh (`verts`, `faces`), measures it by
        `rms`, files ours over both bars under `kind` (ours alone without a
        sweep) and returns the table's columns: the best setting's RMS,
        ours over it, its name, ours over the second bar, its name."""
        tris = mm.triangles(faces)
        in_vol = mm.signed_volume(verts, tris)
        best, kept = None, None
        for setting, run in self.sweep.items():
            try:
                p = run(verts, faces)
            except Exception:  # a peer that refuses a mesh is left out
                continue
            r = rms(p)
            if best is None or r < best[0]:
                best = (r, setting)
            keeps = abs(mm.signed_volume(p, tris) / in_vol - 1.0) <= self.volume_kept
            if keeps and (kept is None or r < kept[0]):
                kept = (r, setting)
        if not best:
            self.best.setdefault(kind, []).append(ours_rms)
            return "- | - | - | - | -"
        self.best.setdefault(kind, []).append(ours_rms / best[0])
        cells = f"{best[0]:.4f} | {ours_rms / best[0]:.3f} | {best[1]} | "
        if not kept:
            return cells + "- | none"
        self.kept.setdefault(kind, []).append(ours_rms / kept[0])
        return cells + f"{ours_rms / kept[0]:.3f} | {kept[1]}"

    def print_summary(self):
        """One line per kind and bar (ours alone without a sweep)."""
        for kind, r in self.best.items():
            if not self.sweep:
                print(f"{kind}, {len(r)} meshes: {rms_summary(r)}")
                continue
            print(f"{kind}, {len(r)} meshes: ours over the best peer setting {ratio_summary(r)}")
            k = self.kept.get(kind)
            if k:
                print(
                    f"{kind}, {len(k)} meshes: ours over the best peer setting within {self.volume_kept:.0%} of the "
                    f"input's volume {ratio_summary(k)}"
                )


# The columns of `mask_rows`' cells.
MASK_COLUMNS = (
    "vertices | input volume / truth's | input | meshsmooth | best peer | ratio | setting "
    f"| ratio within {MASK_VOLUME_KEPT:.0%} volume | setting | volume change "
    "| flipped/twisted/min angle/max move (voxels) |"
)


def mask_arguments(doc, only, placements):
    """The command line of a script that runs `mask_rows` over surfaces or
    maps `only` at `placements` seeded placements: its parsed arguments,
    meshsmooth's runner, the peers' `Bars` and the kinds of mesh."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--only", default=",".join(only))
    ap.add_argument("--placements", type=int, default=placements)
    ap.add_argument("--kinds", default="vox,mc")
    ap.add_argument("--no-peers", action="store_true", help="meshsmooth alone")
    ap.add_argument("--params", help="meshsmooth parameter file")
    args = ap.parse_args()
    ours = cp.meshsmooth(args.binary, ["--params", args.params] if args.params else [])
    bars = Bars({} if args.no_peers else peers(), MASK_VOLUME_KEPT)
    return args, ours, bars, args.kinds.split(",")


def mask_header(lead):
    """The table's header: the `lead` columns, then `MASK_COLUMNS`."""
    print(f"| {' | '.join(lead)} | {MASK_COLUMNS}")
    print("|---" * (len(lead) + MASK_COLUMNS.count("|")) + "|")


def mask_rows(mask, truth, kinds, ours, bars):
    """Smooths `mask`'s voxel quads and marching cubes (`kinds`: "vox",
    "mc") by `ours` and by `bars`' sweep, measured against `truth` (a
    closed `trimesh` surface in the mask's voxel coordinates, queried with
    exact point-to-triangle distances); yields each kind and its table
    cells: vertices, the input's volume over the truth's, the input's and
    ours' truth RMS in voxels, the bars' columns, ours' volume change and
    its flipped / twisted / smallest angle / largest move in voxels."""
    import trimesh

    def rms(points):
        _, d, _ = trimesh.proximity.closest_point(truth, points)
        return float(np.sqrt((d * d).mean()))

    truth_volume = abs(mm.signed_volume(truth.vertices, truth.faces))
    qv, qf = voxel_quads(mask)
    for kind in kinds:
        v, f = (qv, qf) if kind == "vox" else marching_cubes(mask, mm.signed_volume(qv, mm.triangles(qf)))
        tris = mm.triangles(f)
        out = ours(v, f)
        q = mm.quality(v, f, out)
        r_in, r_ours = rms(v), rms(out)
        in_vol = mm.signed_volume(v, tris)
        change = mm.signed_volume(out, tris) / in_vol - 1.0
        bar = bars.columns(kind, v, f, r_ours, rms)
        yield kind, (
            f"{len(v)} | {abs(in_vol) / truth_volume:.3f} | {r_in:.4f} | {r_ours:.4f} | {bar} | {100 * change:+.2f}% "
            f"| {q['flipped']}/{q['twisted']}/{q['min_angle']:.1f}/{q['max_move']:.2f} |"
        )


def ratio_summary(ratios):
    """Ours over a bar, over many meshes: the geometric mean, the worst and
    how many are under 1."""
    r = np.asarray(ratios, dtype=float)
    return f"geometric mean {np.exp(np.log(r).mean()):.3f}, worst {r.max():.3f}; closer on {(r < 1).sum()}"


def rms_summary(rms):
    """Ours alone over many meshes (no bar): the median, the geometric mean
    and the worst truth RMS."""
    r = np.asarray(rms, dtype=float)
    return f"meshsmooth median {np.median(r):.4f}, geometric mean {np.exp(np.log(r).mean()):.4f}, worst {r.max():.4f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--mni152", default=str(ROOT / "eval" / ".mni152"), help="fetch_mni152.py's folder")
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--placements", type=int, default=4)
    ap.add_argument(
        "--first",
        type=int,
        default=0,
        help="the first placement's seed (default 0, the map's own grid): --first 8 runs seeds no setting was tuned on",
    )
    ap.add_argument("--only", default="", help="comma-separated map names: " + ",".join(MAPS))
    ap.add_argument("--no-peers", action="store_true", help="meshsmooth alone")
    ap.add_argument("--params", help="meshsmooth parameter file (the HTTP API's params object), to compare settings")
    ap.add_argument("--kinds", default="vox,mc", help="meshes to run: vox (voxel quads), mc (marching cubes)")
    ap.add_argument(
        "--no-rotation",
        action="store_true",
        help="sub-voxel offsets only, the grid's axes kept (marching-cubes grids are recognised only so)",
    )
    ap.add_argument(
        "--level",
        type=float,
        default=LEVEL,
        help="the threshold of the mask and the level of its truth (0-255; default 127.5, the data folder's masks; the T1 maps keep their own)",
    )
    ap.add_argument("--dump", help="also write each placement's meshes to this folder, as NAME_SEED_KIND.obj")
    ap.add_argument(
        "--grid-truth",
        action="store_true",
        help="measure each placement against the level of the map sampled on its own grid (its own trilinear "
        "interpolation), not of the map's: the truth a scanner placed there would have",
    )
    args = ap.parse_args()
    import nibabel as nib

    ours = cp.meshsmooth(args.binary, ["--params", args.params] if args.params else [])
    kinds = args.kinds.split(",")
    sweep = {} if args.no_peers else peers()
    for name, (prob, margin, spacing, *own) in MAPS.items():
        if (args.only or name in FETCHED) and name not in args.only.split(","):
            continue
        level = own[0] if own else args.level
        path = os.path.join(args.mni152 if name in FETCHED else args.data, prob)
        img = nib.load(path)
        data = np.asarray(img.dataobj, dtype=np.float64)
        affine = img.affine
        if len(own) > 1:
            (first, size) = own[1]
            data = data[tuple(slice(f, f + size) for f in first)]
            affine = affine.copy()
            affine[:3, 3] = affine[:3, :3] @ np.asarray(first, dtype=float) + affine[:3, 3]
        truth = mm.Truth(data=data, affine=affine, level=level)
        rows = {"vox": [], "mc": []}
        print(f"\n## {name}: truth RMS in mm (ours, best peer setting, ratio), flipped/twisted/min angle of ours")
        print(
            "| placement | mesh | vertices | input | meshsmooth | best peer | ratio | setting "
            "| meshsmooth over its surface | ours flipped/twisted/min angle/max move (voxels of the mesh) |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        for seed in range(args.first, args.first + args.placements):
            rot, offset = placement(seed, not args.no_rotation)
            mask, to_data, sampled = resampled_mask(data, rot, offset, spacing, level)
            # Placement 0 samples the map at its own nodes: the same truth.
            here = truth
            if args.grid_truth and seed:
                here = grid_truth(sampled, to_data, affine, level)
                # The vertices measured are those inside the map's own crop.
                here.inside_crop = truth.inside_crop
            qv, qf = voxel_quads(mask)
            for kind in ("vox", "mc"):
                if kind not in kinds:
                    continue
                # Marching cubes only when asked (the 1 mm grids are large).
                v, f = (qv, qf) if kind == "vox" else marching_cubes(mask, mm.signed_volume(qv, mm.triangles(qf)))
                world = to_data(v) @ affine[:3, :3].T + affine[:3, 3]
                if args.dump:
                    os.makedirs(args.dump, exist_ok=True)
                    mm.write_obj(os.path.join(args.dump, f"{name}_{seed}_{kind}.obj"), world, f)
                inp = truth_rms(here, world, margin)
                out = ours(world, f)
                m = mm.measure(world, f, out, None, here, margin)
                m["max_move"] = grid_move(world, out, affine, rot, spacing)
                best = (float("inf"), "-")
                for setting, run in sweep.items():
                    try:
                        r = truth_rms(here, run(world, f), margin)
                    except Exception:  # a peer that refuses a mesh is left out
                        continue
                    best = min(best, (r, setting))
                rows[kind].append((m["truth_rms"], best[0]))
                # Without the peers' sweep (--no-peers) there is no bar to show.
                bar = f"{best[0]:.4f} | {m['truth_rms'] / best[0]:.3f} | {best[1]}" if sweep else "- | - | -"
                print(
                    f"| {seed} | {kind} | {len(world)} | {inp:.4f} | {m['truth_rms']:.4f} | {bar} "
                    f"| {m['truth_surface_rms']:.4f} "
                    f"| {m['flipped']}/{m['twisted']}/{m['min_angle']:.1f}/{m['max_move']:.2f} |",
                    flush=True,
                )
        for kind, r in rows.items():
            if not r:
                continue
            r = np.asarray(r)
            ours_line = (
                f"{name} {kind}: meshsmooth median {np.median(r[:, 0]):.4f} worst {r[:, 0].max():.4f} "
                f"(worst/median {r[:, 0].max() / np.median(r[:, 0]):.2f})"
            )
            if sweep:
                ours_line += (
                    f"; best peer per placement median {np.median(r[:, 1]):.4f} worst {r[:, 1].max():.4f}; "
                    f"ratio median {np.median(r[:, 0] / r[:, 1]):.3f} worst {(r[:, 0] / r[:, 1]).max():.3f}"
                )
            print(ours_line)


if __name__ == "__main__":
    main()
