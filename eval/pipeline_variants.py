"""Meshes that other segmentation pipelines make from the same probability
maps, smoothed by meshsmooth and by the peers at their defaults, with the
metrics of `compare_peers.py`:

- `softmc`: marching cubes of the probability map itself at the threshold
  (a soft segmentation meshed directly). Its vertices interpolate the map
  along the grid's edges, so it is not a marching-cubes mesh of a mask and
  gets no slabs. The truth is the same surface built finer, so the input
  already sits on it (a few thousandths of a voxel): the truth column shows
  how much of it a smoother gives up, the quality columns what it does to
  the slivers such a mesh is full of.
- `blurmc`: marching cubes at 0.5 of the mask blurred by a Gaussian of one
  voxel (a common way to soften a binary mask before meshing); the blur
  itself moves thin parts off the truth.
- `decimc`: the mask's marching cubes decimated to 30% of its faces by
  PyMeshLab's quadric edge collapse (what a viewer or a mesh export often
  does); its edges are several voxels long where the surface is flat.
- `softnoisy`: `softmc` with noise along its vertex normals, normal with a
  standard deviation of a tenth of its mean edge (seeded): an isosurface
  of a noisy image, whose noise a smoother should take out while it keeps
  the surface.
- `surfnets`: VTK's surface nets of the mask without their smoothing
  (`pyvista.ImageData.contour_labels(smoothing=False)`, quads): the voxel
  faces, but split into separate sheets where voxels touch along an edge,
  so the file has open edges with a twin vertex at the same place (a
  crack) there.
- `surfnets_smooth`: the same with VTK's own constrained smoothing (its
  defaults, triangles), as 3D Slicer's surface-nets conversion makes it;
  its cracks pull apart.
- `flyingedges`: VTK's flying edges of the mask at 0.5 (triangles; another
  marching-cubes table than scikit-image's).

    python3 eval/pipeline_variants.py [--data DIR] [--binary PATH] [--only wm_softmc,...]

Truth RMS in mm against the map's threshold surface (`meshmetrics.Truth`;
the WM crop over the vertices at least 3 voxels inside it), the largest move
in the map's voxels.
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

# map: (probability map, crop margin in voxels or None)
MAPS = {
    "wm": ("mni152_wm_crop48_1mm_prob.nii.gz", 3),
    "gm": ("mni152_gm_2mm_prob.nii.gz", None),
}


def variants(data, affine):
    """The meshes of one map (`data`, its `affine`) listed above, in world
    coordinates: name -> (vertices, faces)."""
    import pymeshlab
    from scipy.ndimage import gaussian_filter
    from skimage.measure import marching_cubes

    def world(v):
        return v @ affine[:3, :3].T + affine[:3, 3]

    def mc(volume, level):
        v, f, _, _ = marching_cubes(np.pad(volume, 1), level)
        return world(v - 1.0), f

    mask = (data > LEVEL).astype(np.float64)
    out = {"softmc": mc(data, LEVEL), "blurmc": mc(gaussian_filter(mask, 1.0), 0.5)}
    out["softnoisy"] = with_normal_noise(*out["softmc"], 0.1)
    v, f = mc(mask, 0.5)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(v, f))
    ms.meshing_decimation_quadric_edge_collapse(targetperc=0.3, preservetopology=True)
    m = ms.current_mesh()
    out["decimc"] = (np.asarray(m.vertex_matrix()), np.asarray(m.face_matrix()))
    out.update(vtk_variants(mask, world))
    return {k: (v, [list(t) for t in f]) for k, (v, f) in out.items()}


def vtk_variants(mask, world):
    """VTK's meshes of `mask` (index space, mapped by `world`): surface nets
    without and with their smoothing, flying edges at 0.5."""
    import pyvista as pv

    image = pv.ImageData(dimensions=mask.shape)
    image.point_data["mask"] = mask.astype(np.uint8).ravel(order="F")

    def mesh(poly):
        cells, faces, i = np.asarray(poly.faces), [], 0
        while i < len(cells):
            n = cells[i]
            faces.append(cells[i + 1 : i + 1 + n])
            i += n + 1
        return world(np.asarray(poly.points, dtype=np.float64)), faces

    return {
        "surfnets": mesh(image.contour_labels(smoothing=False, output_mesh_type="quads")),
        "surfnets_smooth": mesh(image.contour_labels(output_mesh_type="triangles")),
        "flyingedges": mesh(image.contour([0.5], scalars="mask", method="flying_edges")),
    }


def with_normal_noise(verts, faces, sigma, seed=1):
    """`verts` moved along their area-weighted normals by normal noise of
    `sigma` mean edge lengths (seeded, so the same mesh every run)."""
    faces = np.asarray(faces)
    a, b, c = (verts[faces[:, k]] for k in range(3))
    normals = np.zeros_like(verts)
    for k in range(3):
        np.add.at(normals, faces[:, k], np.cross(b - a, c - a))
    normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
    edge = np.mean([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1)])
    noise = np.random.default_rng(seed).normal(0.0, sigma * edge, len(verts))
    return verts + normals * noise[:, None], faces


def main():
    import nibabel as nib

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--only", default="", help="comma-separated names, e.g. wm_softmc,gm_decimc")
    args = ap.parse_args()
    tools = {"meshsmooth": cp.meshsmooth(args.binary), **cp.reference_peers()}
    print("| tool | flipped | twisted | angles<20 | min angle | max move | curv. var. | volume | truth RMS | time |")
    for key, (prob, margin) in MAPS.items():
        names = ("softmc", "softnoisy", "blurmc", "decimc", "surfnets", "surfnets_smooth", "flyingedges")
        wanted = [n for n in names if not args.only or f"{key}_{n}" in args.only.split(",")]
        if not wanted:
            continue
        img = nib.load(str(Path(args.data) / prob))
        truth = mm.Truth(str(Path(args.data) / prob))
        meshes = variants(np.asarray(img.dataobj, dtype=np.float64), img.affine)
        for name in wanted:
            verts, faces = meshes[name]
            print(f"\n## {key}_{name}: {len(verts)} vertices, {len(faces)} faces")
            print(cp._format("input", mm.measure(verts, faces, verts, truth.voxel, truth, margin), 0.0))
            for tool, f in tools.items():
                try:
                    m, secs = cp.run_measured(f, verts, faces, truth.voxel, truth, margin)
                except Exception as e:  # a peer that refuses a mesh is a row too
                    print(f"| {tool} | failed: {e} |")
                    continue
                print(cp._format(tool, m, secs), flush=True)


if __name__ == "__main__":
    main()
