"""Runs meshsmooth and its peers from PyPI on the same meshes and prints one
table with the same metrics for every tool (see meshmetrics.py).

    pip install numpy scipy nibabel scikit-image open3d trimesh pyvista pymeshlab
    cargo build --release
    python3 eval/compare_peers.py [--data DIR] [--sweep] [--only NAME,...]

Meshes (from the data folder, default ../shared/data/bio) with their truth:
the probability map whose trilinear level set at 127.5 is the sub-voxel
ground truth. Peers run on the triangle split of a quad mesh; the metrics are
taken on the original polygons with the peer's positions (no peer reorders
vertices). `--sweep` runs each peer over iteration counts and strengths and
prints the best truth RMS any setting reaches: the bar meshsmooth is held to
(the issue's measure, over the vertices), and the best truth surface RMS
(over the whole surface, faces included).
`--navis` adds the four hemibrain neurons that `fetch_navis.py` fetches
(no truth; no setting was tuned on them).
`--triangles` gives every tool the quad meshes as triangles (each quad split
along its first diagonal), as a voxel mesh arrives in STL or glTF.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import meshmetrics as mm  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

# name: (mesh file, probability map or None, crop margin in voxels or None)
MESHES = {
    "wm_crop_voxel_quads": ("mni152_wm_crop48_1mm_voxelquads.obj", "mni152_wm_crop48_1mm_prob.nii.gz", 3),
    "wm_crop_marching_cubes": ("mni152_wm_crop48_1mm_marchingcubes.obj", "mni152_wm_crop48_1mm_prob.nii.gz", 3),
    "gm_2mm_voxel_quads": ("mni152_gm_mask_2mm_voxelquads.obj", "mni152_gm_2mm_prob.nii.gz", None),
    "brain_2mm_voxel_quads": ("mni152_brainmask_2mm_voxelquads.obj", None, None),
    "brain_2mm_marching_cubes": ("mni152_brainmask_2mm_marchingcubes.obj", None, None),
    "neuron_722817260": ("hemibrain_neuron_722817260.obj", None, None),
    "molecule_2jho": ("gamer_2jho.obj", None, None),
}
# name: mesh file in the `--navis` folder (`fetch_navis.py`).
NAVIS_NEURONS = {
    "neuron_1734350788": "1734350788.obj",
    "neuron_1734350908": "1734350908.obj",
    "neuron_754534424": "754534424.obj",
    "neuron_754538881": "754538881.obj",
}


def meshsmooth(binary, extra=()):
    def run(verts, faces):
        with tempfile.TemporaryDirectory() as d:
            src, out = os.path.join(d, "in.obj"), os.path.join(d, "out.obj")
            mm.write_obj(src, verts, faces)
            subprocess.run([binary, "smooth", src, "-o", out, "-q", *extra], check=True)
            return mm.read_obj(out)[0]

    return run


def pymeshlab_filter(name, **kw):
    def run(verts, faces):
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=verts, face_matrix=mm.triangles(faces)))
        getattr(ms, name)(**kw)
        out = ms.current_mesh().vertex_matrix()
        assert len(out) == len(verts), "pymeshlab changed the vertex count"
        return np.asarray(out, dtype=np.float64)

    return run


def pyvista_filter(name, **kw):
    def run(verts, faces):
        import pyvista as pv

        tris = mm.triangles(faces)
        cells = np.hstack([np.full((len(tris), 1), 3), tris]).ravel()
        poly = pv.PolyData(verts.copy(), cells)
        out = getattr(poly, name)(**kw)
        assert out.n_points == len(verts), "pyvista changed the vertex count"
        return np.asarray(out.points, dtype=np.float64)

    return run


def open3d_filter(name, **kw):
    def run(verts, faces):
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(mm.triangles(faces))
        )
        out = getattr(m, name)(**kw)
        return np.asarray(out.vertices, dtype=np.float64)

    return run


def trimesh_filter(name, **kw):
    def run(verts, faces):
        import trimesh
        import trimesh.smoothing as ts

        m = trimesh.Trimesh(verts.copy(), mm.triangles(faces), process=False)
        getattr(ts, name)(m, **kw)
        return np.asarray(m.vertices, dtype=np.float64)

    return run


def defaults(binary):
    """Every tool at its documented defaults (3D Slicer's for windowed sinc)."""
    return {
        "meshsmooth": meshsmooth(binary),
        "meshsmooth taubin": meshsmooth(binary, ["--method", "taubin"]),
        "VTK windowed sinc (Slicer: 20 it, pass band 0.1)": pyvista_filter("smooth_taubin", n_iter=20, pass_band=0.1),
        "VTK Laplacian (20 it, 0.01)": pyvista_filter("smooth", n_iter=20),
        "PyMeshLab cotangent Laplacian (3 steps)": pymeshlab_filter(
            "apply_coord_laplacian_smoothing", stepsmoothnum=3, cotangentweight=True
        ),
        "PyMeshLab Taubin (10 steps)": pymeshlab_filter("apply_coord_taubin_smoothing"),
        "PyMeshLab HC Laplacian": pymeshlab_filter("apply_coord_hc_laplacian_smoothing"),
        "Open3D Laplacian (1 it, 0.5)": open3d_filter("filter_smooth_laplacian"),
        "Open3D Taubin (1 it)": open3d_filter("filter_smooth_taubin"),
        "trimesh Laplacian (10 it, 0.5)": trimesh_filter("filter_laplacian"),
        "trimesh Taubin (10 it)": trimesh_filter("filter_taubin"),
        "trimesh HC (Humphrey, 10 it)": trimesh_filter("filter_humphrey"),
    }


def reference_peers():
    """The three peers the other scripts set beside meshsmooth: VTK windowed
    sinc at 3D Slicer's defaults, two PyMeshLab cotangent Laplacian steps
    (the peer setting closest to the truth on the real masks) and
    PyMeshLab's Taubin at its defaults."""
    return {
        "VTK windowed sinc (Slicer: 20 it, pass band 0.1)": pyvista_filter("smooth_taubin", n_iter=20, pass_band=0.1),
        "PyMeshLab cotangent Laplacian (2 steps)": pymeshlab_filter(
            "apply_coord_laplacian_smoothing", stepsmoothnum=2, cotangentweight=True
        ),
        "PyMeshLab Taubin (10 steps)": pymeshlab_filter("apply_coord_taubin_smoothing"),
    }


def sweep():
    """Peer settings over iteration counts and strengths: the best truth any
    setting of any peer reaches is the bar."""
    out = {}
    for steps in (1, 2, 3, 5, 8):
        for cot in (True, False):
            kind = "cotangent" if cot else "uniform"
            out[f"PyMeshLab {kind} Laplacian {steps} steps"] = pymeshlab_filter(
                "apply_coord_laplacian_smoothing", stepsmoothnum=steps, cotangentweight=cot
            )
    for steps in (5, 10, 20, 50):
        for lam in (0.3, 0.5, 0.7):
            out[f"PyMeshLab Taubin {steps} steps lambda {lam}"] = pymeshlab_filter(
                "apply_coord_taubin_smoothing", stepsmoothnum=steps, lambda_=lam, mu=-(lam + 0.03)
            )
    for it in (1, 2, 5, 10):
        out[f"PyMeshLab HC Laplacian x{it}"] = _repeat(pymeshlab_filter("apply_coord_hc_laplacian_smoothing"), it)
    for it in (10, 20, 35, 50, 100):
        for band in (0.001, 0.005, 0.01, 0.05, 0.1, 0.2):
            out[f"VTK windowed sinc {it} it pass band {band}"] = pyvista_filter(
                "smooth_taubin", n_iter=it, pass_band=band
            )
    return out


def _repeat(f, n):
    def run(verts, faces):
        for _ in range(n):
            verts = f(verts, faces)
        return verts

    return run


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "bio"))
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--only", default="", help="comma-separated mesh names")
    ap.add_argument("--sweep", action="store_true", help="also sweep the peers' settings")
    ap.add_argument("--json", help="write all rows to this file")
    ap.add_argument(
        "--navis",
        nargs="?",
        const=str(ROOT / "eval" / ".navis"),
        help="also the four hemibrain neurons fetched by fetch_navis.py (into this folder)",
    )
    ap.add_argument(
        "--triangles",
        action="store_true",
        help="split every quad along its first diagonal first, as STL and glTF write a voxel mesh",
    )
    args = ap.parse_args()
    rows = []
    meshes = dict(MESHES)
    if args.navis:
        meshes.update({n: (os.path.join(args.navis, f), None, None) for n, f in NAVIS_NEURONS.items()})
    names = [n for n in meshes if not args.only or n in args.only.split(",")]
    for name in names:
        path, prob, margin = meshes[name]
        verts, faces = mm.read_obj(os.path.join(args.data, path))
        if args.triangles:
            faces = [list(t) for t in mm.triangles(faces)]
        truth = mm.Truth(os.path.join(args.data, prob)) if prob else None
        voxel = truth.voxel if truth else None
        tools = defaults(args.binary)
        if args.sweep and truth:
            tools.update(sweep())
        print(f"\n## {name}: {len(verts)} vertices, {len(faces)} faces")
        base = mm.measure(verts, faces, verts, voxel, truth, margin)
        print(_format("input", base, 0.0))
        best, best_surface = None, None
        for tool, f in tools.items():
            try:
                m, secs = run_measured(f, verts, faces, voxel, truth, margin)
            except Exception as e:  # a peer that refuses a mesh is a row too
                print(f"| {tool} | failed: {e} |")
                continue
            rows.append({"mesh": name, "tool": tool, "seconds": secs, **m})
            print(_format(tool, m, secs), flush=True)
            if "truth_rms" in m and not tool.startswith("meshsmooth"):
                if best is None or m["truth_rms"] < best[1]:
                    best = (tool, m["truth_rms"])
                if best_surface is None or m["truth_surface_rms"] < best_surface[1]:
                    best_surface = (tool, m["truth_surface_rms"])
        if best:
            print(f"best peer truth RMS: {best[1]:.4f} ({best[0]})")
            print(f"best peer truth surface RMS: {best_surface[1]:.4f} ({best_surface[0]})")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


def run_measured(f, verts, faces, voxel, truth, margin):
    """Runs the smoother `f` on the mesh and measures its output
    (`meshmetrics.measure`): the measures and the seconds `f` took."""
    t = time.perf_counter()
    out = f(verts, faces)
    secs = time.perf_counter() - t
    return mm.measure(verts, faces, out, voxel, truth, margin), secs


def _format(tool, m, secs):
    cells = [
        tool,
        m["flipped"],
        m["twisted"],
        m["angles_lt20"],
        f"{m['min_angle']:.1f}",
        f"{m['max_move']:.2f}",
        f"{m['curv_var']:.3f}",
        f"{100 * m['volume_change']:+.2f}%" if "volume_change" in m else "-",
        f"{m['truth_rms']:.4f}" if "truth_rms" in m else "-",
        f"{m['truth_surface_rms']:.4f}" if "truth_surface_rms" in m else "-",
        f"{secs:.2f}s",
    ]
    return "| " + " | ".join(str(c) for c in cells) + " |"


if __name__ == "__main__":
    print("| tool | flipped | twisted | angles<20 | min angle | max move | curv. var. | volume | truth RMS | truth surface RMS | time |")
    main()
