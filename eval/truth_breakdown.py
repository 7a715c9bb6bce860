"""Where a result's distance to the truth comes from. On voxel quads (`wm`,
`gm`): signed truth error per corner configuration (how many of the 8
voxels around a lattice corner are inside the mask: 1 a convex corner, 4 a
flat face, 7 a concave corner) and at the non-manifold vertices. On
marching cubes (`wm_mc`, `gm_mc`): per run of voxels along each vertex's
lattice edge (a slit: the edge's outside voxel has an inside one beyond
it; a sheet: its inside voxel has an outside one behind it; both; neither),
where a thresholded map's thin parts are. For meshsmooth runs and, for
reference, two full uniform umbrella steps over every vertex and, on
marching cubes, one PyMeshLab cotangent Laplacian step (the best peer
setting on the GM map's own marching cubes).

    python3 eval/truth_breakdown.py wm|gm|wm_mc|gm_mc [--mesh FILE.obj] ["CLI ARGS" ...]

Each argument is one meshsmooth run ("" = defaults). `--mesh` takes
another mesh of the same map, in its world coordinates (`gm_mc` needs one:
`eval/real_placements.py --only gm_2mm --placements 1 --dump DIR` writes
`gm_2mm_0_mc.obj`). Signed errors are positive outside the truth (the
probability map's 127.5 surface); "ss" is the class's share of the summed
squared error. Needs what compare_peers.py needs; reads ../shared/data/bio.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import nibabel as nib
import numpy as np
from scipy.ndimage import map_coordinates

sys.path.insert(0, str(Path(__file__).resolve().parent))
import meshmetrics as mm  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data" / "bio"
MESHES = {
    "wm": ("mni152_wm_crop48_1mm_voxelquads.obj", "mni152_wm_crop48_1mm_prob.nii.gz", 3),
    "gm": ("mni152_gm_mask_2mm_voxelquads.obj", "mni152_gm_2mm_prob.nii.gz", None),
    "wm_mc": ("mni152_wm_crop48_1mm_marchingcubes.obj", "mni152_wm_crop48_1mm_prob.nii.gz", 3),
    "gm_mc": (None, "mni152_gm_2mm_prob.nii.gz", None),
}


def corner_classes(mask, vox, faces):
    """Per voxel-quad vertex (`vox`: its voxel coordinates, a lattice
    corner), how many of the 8 voxels around it are inside, and whether it
    is non-manifold (an edge of its not shared by exactly two faces).
    `mask` is padded by one voxel, so index `i` is voxel `i - 1`."""
    corner = np.rint(vox + 0.5).astype(int) + 1
    inside_count = sum(
        mask[corner[:, 0] - dx, corner[:, 1] - dy, corner[:, 2] - dz]
        for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)
    )
    counts = {}
    for face in faces:
        for a, b in zip(face, face[1:] + face[:1]):
            key = (min(a, b), max(a, b))
            counts[key] = counts.get(key, 0) + 1
    non_manifold = np.zeros(len(vox), dtype=bool)
    for (a, b), c in counts.items():
        if c != 2:
            non_manifold[a] = non_manifold[b] = True
    classes = [(f"{k} inside", ~non_manifold & (inside_count == k)) for k in range(1, 8)]
    classes.append(("non-manifold", non_manifold))
    return classes


def run_classes(mask, vox):
    """Per marching-cubes vertex (`vox`: its voxel coordinates, one of them
    half way between two voxel centres), whether the run of voxels along its
    edge makes it a slit, a sheet, both or neither. `mask` is padded by one
    voxel, so index `i` is voxel `i - 1`."""
    n = len(vox)
    axis = np.argmax(np.abs(vox - np.rint(vox)), axis=1)
    lo = np.rint(vox).astype(int) + 1
    lo[np.arange(n), axis] = np.floor(vox[np.arange(n), axis]).astype(int) + 1
    hi = lo.copy()
    hi[np.arange(n), axis] += 1
    step = np.zeros_like(lo)
    step[np.arange(n), axis] = 1
    limit = np.asarray(mask.shape) - 1

    def at(c):
        return mask[tuple(np.clip(c, 0, limit).T)]

    lo_in = at(lo)
    inside = np.where(lo_in[:, None], lo, hi)
    outward = np.where(lo_in[:, None], step, -step)
    slit = at(inside + 2 * outward)
    sheet = ~at(inside - outward)
    return [
        ("slit", slit & ~sheet),
        ("sheet", sheet & ~slit),
        ("both", slit & sheet),
        ("neither", ~slit & ~sheet),
    ]


def main():
    name, runs = sys.argv[1], sys.argv[2:]
    mesh_file, prob_file, margin = MESHES[name]
    if runs[:1] == ["--mesh"]:
        mesh_path, runs = runs[1], runs[2:]
    elif mesh_file is None:
        sys.exit(f"{name} needs --mesh FILE.obj (see the module docs)")
    else:
        mesh_path = str(DATA / mesh_file)
    runs = runs or [""]
    binary = os.environ.get("MESHSMOOTH", str(ROOT / "target" / "release" / "meshsmooth"))
    verts, faces = mm.read_obj(mesh_path)
    img = nib.load(str(DATA / prob_file))
    prob = np.pad(np.asarray(img.dataobj, dtype=np.float64), 1)
    inv = np.linalg.inv(img.affine)
    truth = mm.Truth(str(DATA / prob_file))

    def index(p):
        return p @ inv[:3, :3].T + inv[:3, 3]

    def signed(p):
        d = truth.distances(p)
        inside = map_coordinates(prob, (index(p) + 1).T, order=1) > 127.5
        return np.where(inside, -d, d)

    mask = prob > 127.5
    adj = mm.adjacency(len(verts), mm.edges_of(faces))
    degree = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    sel = np.ones(len(verts), dtype=bool) if margin is None else truth.inside_crop(verts, margin)

    outputs = {}
    with tempfile.TemporaryDirectory() as d:
        for i, args in enumerate(runs):
            out = os.path.join(d, f"out{i}.obj")
            subprocess.run([binary, "smooth", mesh_path, "-o", out, "-q", *args.split()], check=True)
            outputs[f"meshsmooth [{args}]"] = mm.read_obj(out)[0]
    p = verts.copy()
    for _ in range(2):
        p = (adj @ p) / degree[:, None]
    outputs["umbrella, 2 full steps"] = p

    if name.endswith("_mc"):
        import compare_peers as cp

        setting = "PyMeshLab cotangent Laplacian 1 steps"
        outputs[setting] = cp.sweep()[setting](verts, faces)
        classes = run_classes(mask, index(verts))
    else:
        classes = corner_classes(mask, index(verts), faces)
    for label, p in outputs.items():
        s = signed(p)
        total = (s[sel] ** 2).sum()
        print(f"{label}: RMS {np.sqrt((s[sel] ** 2).mean()):.4f} mean {s[sel].mean():+.4f}")
        for cname, m in classes:
            m = m & sel
            if m.any():
                print(
                    f"  {cname:13s} n={m.sum():6d} RMS {np.sqrt((s[m] ** 2).mean()):.3f} "
                    f"mean {s[m].mean():+.3f} ss {(s[m] ** 2).sum() / total:5.1%}"
                )


if __name__ == "__main__":
    main()
