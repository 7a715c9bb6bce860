"""A multi-label complex: the surface of a label map with each wall between
two labels written once, as VTK's surface nets write it
(`vtkSurfaceNets3D`; pyvista's `contour_labels(boundary_style="all")`).
The labels are those of `touching_labels.py`: the grey-matter mask of the
2 mm MNI152 maps (1) and the rest of the brain mask (2); with `--map wm`,
the WM crop's mask (1) and the crop less its outer 4 voxels and the WM (2);
with `--map tissue`, the whole-brain 1 mm maps of `fetch_mni152.py` (run
it first): grey matter (1) and white matter (2), each `prob > 127.5`.

    python3 eval/label_complex.py [--data DIR] [--binary PATH] [--map gm|wm|tissue] [--kinds quads,triangles] [--no-peers]

Each complex is written as OBJ and smoothed at the defaults. Columns: the
truth RMS in mm (`meshmetrics.Truth`, label 1's map's threshold surface)
of the vertices of the faces that bound label 1 and over those faces'
surface (`meshmetrics.surface_rms`), on the WM crop those at least 3
voxels inside it; then
flipped faces / twisted quads / triangle-split angles under 20 degrees /
the smallest / the largest move in voxels, each label's volume change
(its faces wound outward from it), and the report's `regions`
and `walls_joined` (mean / largest distance, in mm, of a wall vertex's
copies from their mean). The peers run on the same complex (its faces
split into triangles), every setting of `compare_peers.sweep()`: the
settings closest to the truth at the vertices and over the surface are
printed with their quality, and the settings of
`compare_peers.defaults()` beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_peers as cp  # noqa: E402
import meshmetrics as mm  # noqa: E402
import touching_labels as tl  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def wm_labels(data):
    """The WM crop's label volume (1: the WM mask, 2: the crop less its
    outer 4 voxels and the WM, 0: the rest) and its affine."""
    import nibabel as nib

    wm = nib.load(str(Path(data) / "mni152_wm_crop48_1mm.nii.gz"))
    mask = np.asarray(wm.dataobj) > 0
    lab = np.zeros(mask.shape, np.uint8)
    lab[4:-4, 4:-4, 4:-4] = 2
    lab[mask] = 1
    return lab, wm.affine


def tissue_labels():
    """The whole-brain 1 mm label volume (1: grey matter, 2: white matter,
    0: the rest), its affine, and the grey-matter map's path."""
    import nibabel as nib

    gm_path = ROOT / "eval" / ".mni152" / "mni_icbm152_gm_tal_nlin_sym_09a_converted.nii.gz"
    wm_path = ROOT / "eval" / ".mni152" / "mni_icbm152_wm_tal_nlin_sym_09a_converted.nii.gz"
    gm = nib.load(str(gm_path))
    grey = np.asarray(gm.dataobj) > 127.5
    white = np.asarray(nib.load(str(wm_path)).dataobj) > 127.5
    lab = np.zeros(grey.shape, np.uint8)
    lab[white] = 2
    lab[grey] = 1
    return lab, gm.affine, gm_path


def complex_mesh(lab, affine, mesh_type):
    """The label map's surface nets, walls once (world positions, faces);
    the vertices and the triangles of the faces that bound label 1; and
    each label's triangles, wound outward from it."""
    import pyvista as pv

    image = pv.ImageData(dimensions=lab.shape)
    image.point_data["m"] = lab.ravel(order="F")
    poly = image.contour_labels(boundary_style="all", smoothing=False, output_mesh_type=mesh_type)
    labels = np.asarray(poly.cell_data["boundary_labels"])
    faces = tl.poly_faces(poly)
    ijk = np.asarray(poly.points, dtype=np.float64)
    verts = ijk @ affine[:3, :3].T + affine[:3, 3]
    first_faces = [f for f, b in zip(faces, labels) if 1 in b]
    first = np.unique(np.concatenate(first_faces))
    # Each label's faces wound outward from it: the voxel half a voxel in
    # front of a face (surface nets put faces between voxel centres).
    padded = np.pad(lab, 1)
    bounds = {}
    for value in (1, 2):
        own = []
        for f, b in zip(faces, labels):
            if value not in b:
                continue
            c = ijk[f]
            n = np.cross(c[1] - c[0], c[2] - c[0])
            p = np.rint(c.mean(axis=0) + 0.5 * n / np.linalg.norm(n)).astype(int) + 1
            own.append(f[::-1] if padded[tuple(p)] == value else f)
        bounds[value] = mm.triangles(own)
    return verts, faces, first, mm.triangles(first_faces), bounds


BOUNDS = {}


def row(name, truth, grey, verts, faces, out, extra="", voxel=2.0, tris=None, margin=None):
    d = truth.distances(out[grey])
    q = mm.quality(verts, faces, out)
    surface = mm.surface_rms(truth, out, tris, margin)
    volumes = " / ".join(f"{100 * mm.volume_change(verts, t, out):+.2f}%" for t in BOUNDS.values())
    print(
        f"| {name} | {np.sqrt(np.mean(d**2)):.4f} / {surface:.4f} | {q['flipped']} / {q['twisted']} / {q['angles_lt20']} / "
        f"{q['min_angle']:.1f} / {q['max_move'] / voxel:.2f} | {volumes} | {extra} |",
        flush=True,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--map", default="gm", choices=["gm", "wm", "tissue"])
    ap.add_argument("--kinds", default="quads,triangles")
    ap.add_argument("--no-peers", action="store_true")
    args = ap.parse_args()
    if args.map == "gm":
        truth = mm.Truth(str(Path(args.data) / "mni152_gm_2mm_prob.nii.gz"))
        lab, affine = tl.labels(args.data)
    elif args.map == "wm":
        truth = mm.Truth(str(Path(args.data) / "mni152_wm_crop48_1mm_prob.nii.gz"))
        lab, affine = wm_labels(args.data)
    else:
        lab, affine, gm_path = tissue_labels()
        truth = mm.Truth(str(gm_path))
    voxel = float(abs(affine[0, 0]))
    # The WM crop's figures, as everywhere, over the vertices at least 3
    # voxels inside the crop: its walls are where the crop cut the mask.
    margin = 3 if args.map == "wm" else None
    for kind in args.kinds.split(","):
        verts, faces, grey, tris, bounds = complex_mesh(lab, affine, kind)
        BOUNDS.clear()
        BOUNDS.update(bounds)
        if margin is not None:
            grey = grey[truth.inside_crop(verts[grey], margin)]
        print(f"\n{kind}: {len(verts)} vertices, {len(faces)} faces, {len(grey)} bound label 1\n")
        print(
            "| tool | label 1's truth RMS, vertices / surface | flipped / twisted / angles < 20 / smallest / "
            "largest move | volume change, label 1 / 2 | regions, walls joined |"
        )
        print("|---|---|---|---|---|---|")
        row("input", truth, grey, verts, faces, verts, voxel=voxel, tris=tris, margin=margin)
        with tempfile.TemporaryDirectory() as d:
            src, out, rep = (os.path.join(d, n) for n in ("in.obj", "out.obj", "r.json"))
            mm.write_obj(src, verts, faces)
            subprocess.run([args.binary, "smooth", src, "-o", out, "-q", "--report", rep], check=True)
            report = json.load(open(rep))
            joined = report.get("walls_joined")
            extra = f"{report['mesh'].get('regions', '-')}, " + (
                f"{joined['mean']:.3f} / {joined['max']:.3f}" if joined else "-"
            )
            row("meshsmooth", truth, grey, verts, faces, mm.read_obj(out)[0], extra, voxel, tris, margin)
        if args.no_peers:
            continue
        for name, run in cp.defaults(args.binary).items():
            if name.startswith("meshsmooth"):
                continue
            row(name, truth, grey, verts, faces, run(verts, faces), voxel=voxel, tris=tris, margin=margin)
        best, best_surface = None, None
        for name, run in cp.sweep().items():
            out = run(verts, faces)
            d = truth.distances(out[grey])
            r = float(np.sqrt(np.mean(d**2)))
            if best is None or r < best[0]:
                best = (r, name, out)
            r = mm.surface_rms(truth, out, tris, margin)
            if best_surface is None or r < best_surface[0]:
                best_surface = (r, name, out)
        row(f"best peer setting: {best[1]}", truth, grey, verts, faces, best[2], voxel=voxel, tris=tris, margin=margin)
        row(
            f"best peer setting over the surface: {best_surface[1]}",
            truth,
            grey,
            verts,
            faces,
            best_surface[2],
            voxel=voxel,
            tris=tris,
            margin=margin,
        )


if __name__ == "__main__":
    main()
