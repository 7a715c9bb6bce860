"""Two labels of one segmentation written into one file, as 3D Slicer
exports the segments of a segmentation (one OBJ with an object per segment,
or one merged STL): the grey-matter mask of the 2 mm MNI152 maps and the
rest of the brain mask, each label's surface with its own vertices. Where
the labels touch, both surfaces run through the same faces.

    python3 eval/touching_labels.py [--data DIR] [--binary PATH] [--only NAME,...]

Meshes (VTK through pyvista, per label): `surfnets` (surface nets without
their smoothing, quads; each label's own sheets cracked where its voxels
touch along an edge), `surfnets_tri` (the same as triangles) and
`flyingedges` (marching cubes at 0.5), each as OBJ and as binary STL. Each
file is smoothed whole and the grey-matter label alone, at the defaults.

Columns: truth RMS in mm of the grey-matter label's vertices (each input
position once) against the map's threshold surface (`meshmetrics.Truth`),
whole file then the label alone; the report's `touching_bodies`; and its
`walls_parted` (mean / largest distance in mm between the two labels'
copies of a shared wall vertex after smoothing).
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
import meshmetrics as mm  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def labels(data):
    """The label volume (1: grey matter, 2: the rest of the brain mask, 0:
    outside) and its affine."""
    import nibabel as nib

    gm = nib.load(str(Path(data) / "mni152_gm_mask_2mm.nii.gz"))
    brain = np.asarray(nib.load(str(Path(data) / "mni152_brainmask_2mm.nii.gz")).dataobj) > 0
    grey = np.asarray(gm.dataobj) > 0
    lab = np.zeros(grey.shape, np.uint8)
    lab[brain] = 2
    lab[grey] = 1
    return lab, gm.affine


def label_meshes(lab, affine, kind):
    """Each label's mesh (world positions, faces) by VTK: `kind` is
    `surfnets`, `surfnets_tri` or `flyingedges`."""
    import pyvista as pv

    out = []
    for value in (1, 2):
        image = pv.ImageData(dimensions=lab.shape)
        image.point_data["m"] = (lab == value).astype(np.uint8).ravel(order="F")
        if kind == "flyingedges":
            image.point_data["m"] = image.point_data["m"].astype(np.float32)
            poly = image.contour([0.5], scalars="m", method="flying_edges")
        else:
            mesh_type = "quads" if kind == "surfnets" else "triangles"
            poly = image.contour_labels(smoothing=False, output_mesh_type=mesh_type)
        points = np.asarray(poly.points, dtype=np.float64)
        out.append((points @ affine[:3, :3].T + affine[:3, 3], poly_faces(poly)))
    return out


def poly_faces(poly):
    """A pyvista surface's faces as lists of vertex indices."""
    cells, faces, i = np.asarray(poly.faces), [], 0
    while i < len(cells):
        n = cells[i]
        faces.append(list(cells[i + 1 : i + 1 + n]))
        i += n + 1
    return faces


def together(meshes):
    """The meshes in one, each with its own vertices."""
    verts, faces, base = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.extend([[base + i for i in face] for face in f])
        base += len(v)
    return np.vstack(verts), faces


def write_stl(path, verts, faces):
    """Binary STL of the faces split into fans (f32 positions)."""
    tris = np.array([[f[0], f[k], f[k + 1]] for f in faces for k in range(1, len(f) - 1)])
    corners = verts[tris].astype(np.float32)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    record = np.zeros(len(tris), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    record["n"], record["v"] = normals, corners
    with open(path, "wb") as f:
        f.write(b"\0" * 80 + np.uint32(len(tris)).tobytes() + record.tobytes())


def read_stl(path):
    """The corners of a binary STL, three per triangle, in file order."""
    raw = open(path, "rb").read()
    n = int(np.frombuffer(raw, "<u4", 1, 80)[0])
    record = np.frombuffer(raw, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")], count=n, offset=84)
    return record["v"].reshape(-1, 3).astype(np.float64)


def smooth(binary, verts, faces, fmt):
    """Input and output positions of the file's vertices (an STL's three a
    triangle), and the report."""
    with tempfile.TemporaryDirectory() as d:
        src, out, rep = (os.path.join(d, n) for n in (f"in.{fmt}", f"out.{fmt}", "r.json"))
        if fmt == "obj":
            mm.write_obj(src, verts, faces)
        else:
            write_stl(src, verts, faces)
        subprocess.run([binary, "smooth", src, "-o", out, "-q", "--report", rep], check=True)
        report = json.load(open(rep))
        if fmt == "obj":
            return mm.read_obj(src)[0], mm.read_obj(out)[0], report
        return read_stl(src), read_stl(out), report


def grey_rms(truth, inp, out, count):
    """Truth RMS over the first `count` file vertices, each input position
    once."""
    _, first = np.unique(inp[:count], axis=0, return_index=True)
    d = truth.distances(out[:count][first])
    return float(np.sqrt(np.mean(d**2)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--only", default="", help="e.g. surfnets_obj,flyingedges_stl")
    args = ap.parse_args()
    truth = mm.Truth(str(Path(args.data) / "mni152_gm_2mm_prob.nii.gz"))
    lab, affine = labels(args.data)
    print("| mesh | vertices | GM truth RMS: whole file / label alone | touching bodies | walls parted: mean / max |")
    print("|---|---|---|---|---|")
    for kind in ("surfnets", "surfnets_tri", "flyingedges"):
        meshes = label_meshes(lab, affine, kind)
        verts, faces = together(meshes)
        for fmt in ("obj", "stl"):
            name = f"{kind}_{fmt}"
            if args.only and name not in args.only.split(","):
                continue
            # The grey-matter label comes first: its vertices, or its
            # triangles' corners in an STL.
            first = len(meshes[0][0]) if fmt == "obj" else 3 * sum(len(f) - 2 for f in meshes[0][1])
            inp, out, report = smooth(args.binary, verts, faces, fmt)
            alone_in, alone_out, _ = smooth(args.binary, *meshes[0], fmt)
            whole = grey_rms(truth, inp, out, first)
            alone = grey_rms(truth, alone_in, alone_out, len(alone_in))
            parted = report.get("walls_parted")
            parted = f"{parted['mean']:.3f} / {parted['max']:.3f}" if parted else "-"
            bodies = report["mesh"].get("touching_bodies", "-")
            print(f"| {name} | {report['mesh']['vertices']} | {whole:.4f} / {alone:.4f} | {bodies} | {parted} |", flush=True)


if __name__ == "__main__":
    main()
