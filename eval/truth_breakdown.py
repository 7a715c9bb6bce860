"""Where a voxel-quad result's distance to the truth comes from: signed
truth error per corner configuration (how many of the 8 voxels around a
lattice corner are inside the mask: 1 a convex corner, 4 a flat face, 7 a
concave corner) and at the non-manifold vertices, for meshsmooth runs and,
for reference, two full uniform umbrella steps over every vertex.

    python3 eval/truth_breakdown.py wm|gm ["CLI ARGS" ...]

Each argument is one meshsmooth run ("" = defaults). Signed errors are
positive outside the truth (the probability map's 127.5 surface); "ss" is
the class's share of the summed squared error. Needs what compare_peers.py
needs; reads ../shared/data/bio.
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
}


def main():
    name, runs = sys.argv[1], sys.argv[2:] or [""]
    mesh_file, prob_file, margin = MESHES[name]
    binary = os.environ.get("MESHSMOOTH", str(ROOT / "target" / "release" / "meshsmooth"))
    verts, faces = mm.read_obj(str(DATA / mesh_file))
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
    corner = np.rint(index(verts) + 0.5).astype(int) + 1
    inside_count = sum(
        mask[corner[:, 0] - dx, corner[:, 1] - dy, corner[:, 2] - dz]
        for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)
    )
    counts = {}
    for face in faces:
        for a, b in zip(face, face[1:] + face[:1]):
            key = (min(a, b), max(a, b))
            counts[key] = counts.get(key, 0) + 1
    non_manifold = np.zeros(len(verts), dtype=bool)
    for (a, b), c in counts.items():
        if c != 2:
            non_manifold[a] = non_manifold[b] = True
    adj = mm.adjacency(len(verts), mm.edges_of(faces))
    degree = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    sel = np.ones(len(verts), dtype=bool) if margin is None else truth.inside_crop(verts, margin)

    outputs = {}
    with tempfile.TemporaryDirectory() as d:
        for i, args in enumerate(runs):
            out = os.path.join(d, f"out{i}.obj")
            subprocess.run([binary, "smooth", str(DATA / mesh_file), "-o", out, "-q", *args.split()], check=True)
            outputs[f"meshsmooth [{args}]"] = mm.read_obj(out)[0]
    p = verts.copy()
    for _ in range(2):
        p = (adj @ p) / degree[:, None]
    outputs["umbrella, 2 full steps"] = p

    classes = [(f"{k} inside", ~non_manifold & (inside_count == k)) for k in range(1, 8)]
    classes.append(("non-manifold", non_manifold))
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
