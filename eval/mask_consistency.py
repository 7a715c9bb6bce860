"""Whether a smoothed mask mesh still says what its mask says: the voxel
centres next to the surface (those with a face neighbour on the other side
of the mask) that end on the wrong side of the output, for meshsmooth and
the peers at their defaults.

The mask is `prob > 127.5` on the map's own grid, and its truth (the
map's 127.5 surface) puts every voxel centre on its mask's side, so a
centre on the wrong side of an output is an error no information in the
mask allows: where the output crosses the segment between an inside and an
outside centre, the mask is kept; where it does not, it was smoothed
through. A count near zero says the remaining distance to the truth lies
within what the mask leaves open.

    python3 eval/mask_consistency.py [--data DIR] [--binary PATH] [--only wm,gm,wm_mc]

Inside or outside is the output's winding, by ray parity (Open3D's
occupancy, three rays per point). Needs what compare_peers.py needs; reads
../shared/data/bio.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_peers as cp  # noqa: E402
import meshmetrics as mm  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
LEVEL = 127.5

# name: (mesh, probability map)
MESHES = {
    "wm": ("mni152_wm_crop48_1mm_voxelquads.obj", "mni152_wm_crop48_1mm_prob.nii.gz"),
    "wm_mc": ("mni152_wm_crop48_1mm_marchingcubes.obj", "mni152_wm_crop48_1mm_prob.nii.gz"),
    "gm": ("mni152_gm_mask_2mm_voxelquads.obj", "mni152_gm_2mm_prob.nii.gz"),
}


def boundary_centres(mask):
    """Indices of the voxels with a face neighbour of the other value
    (outside the volume counts as outside)."""
    padded = np.pad(mask, 1)
    core = padded[1:-1, 1:-1, 1:-1]
    edge = np.zeros_like(core)
    for axis in range(3):
        for shift in (-1, 1):
            edge |= np.roll(padded, shift, axis=axis)[1:-1, 1:-1, 1:-1] != core
    return np.argwhere(edge)


def wrong_side(verts, faces, points, inside):
    """Counts of `points` whose side of the mesh (`verts`, `faces`)
    disagrees with `inside`: (inside ones outside, outside ones inside)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    tris = np.asarray(mm.triangles(faces), dtype=np.uint32)
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris))
    q = o3d.core.Tensor(points.astype(np.float32))
    occupied = scene.compute_occupancy(q, nsamples=3).numpy() > 0.5
    return int((inside & ~occupied).sum()), int((~inside & occupied).sum())


def main():
    import nibabel as nib

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--only", default="", help="comma-separated names: wm, wm_mc, gm")
    args = ap.parse_args()
    tools = {"input": lambda v, f: v, "meshsmooth": cp.meshsmooth(args.binary), **cp.reference_peers()}
    print("| mesh | tool | boundary centres | wrong side | inside left out | outside taken in |")
    print("|---|---|---|---|---|---|")
    for name, (mesh, prob) in MESHES.items():
        if args.only and name not in args.only.split(","):
            continue
        img = nib.load(str(Path(args.data) / prob))
        mask = np.asarray(img.dataobj, dtype=np.float64) > LEVEL
        idx = boundary_centres(mask)
        points = idx @ img.affine[:3, :3].T + img.affine[:3, 3]
        inside = mask[tuple(idx.T)]
        verts, faces = mm.read_obj(str(Path(args.data) / mesh))
        for tool, smooth in tools.items():
            out = smooth(verts, faces)
            lost, gained = wrong_side(out, faces, points, inside)
            share = 100.0 * (lost + gained) / len(points)
            print(f"| {name} | {tool} | {len(points)} | {lost + gained} ({share:.2f}%) | {lost} | {gained} |", flush=True)


if __name__ == "__main__":
    main()
