"""meshsmooth against its peers on the analytic families at 8 seeded grid
placements each: the RMS distance to the true surface of every placement,
for meshsmooth at its defaults and for every peer setting of
`compare_peers.sweep()`, reported as median and worst of the 8. The bar for
a family is the smallest worst-of-8 any peer setting reaches; beside it,
the smallest among the settings whose output keeps within 2% of the input's
volume at every placement (the issue's promise for thin parts: a setting
that shrinks a thin tube can come closer to it by the vertices while its
faces lose a tenth of its volume). Every tool's largest volume change over
the placements is printed with it.

    pip install numpy scipy pyvista pymeshlab open3d trimesh
    cargo build --release
    cargo build --release -p meshsmooth-core --example shape_meshes
    python3 eval/compare_shapes.py [--only sphere,tube1.5] [--kinds vox,mc] [--params FILE.json] [--no-peers [--curvature]] [--placements N]

`--no-peers` runs meshsmooth alone (a minute, against the peers' half
hour): its median and worst of 8 and their ratio, to compare two builds or
parameter files, with its worst quality over the placements (flipped faces,
twisted quads, smallest triangle-split angle, largest move in voxels,
largest volume change); with `--curvature` also the largest curvature
variation over the input's (`meshmetrics.curvature_variation`, the
issue's measure; thin shapes are to come out below 1), a few minutes more.
`--placements N` judges on seeds 0 to N-1 instead of the 8 the bars are set
on: the placements beyond them are ones no constant was tuned on.

The meshes and the distances come from `examples/shape_meshes.rs` (the
families of `shapes::placement_families`); distances are in voxels.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_peers as cp  # noqa: E402
import meshmetrics as mm  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TOOL = ROOT / "target" / "release" / "examples" / "shape_meshes"
PLACEMENTS = 8


def rms(tmp, shape, seed, verts, faces):
    path = os.path.join(tmp, "out.obj")
    mm.write_obj(path, verts, faces)
    return float(subprocess.check_output([str(TOOL), "rms", shape, str(seed), path]))


def curvature_ratio(verts, faces, out):
    """The curvature variation of `out` (an output of a smoother run on
    (`verts`, `faces`)) over the input's, both in the input's mean edge: the
    issue asks thin shapes for less than 1."""
    adj, edge_len = mm.input_adjacency(verts, faces)
    return mm.curvature_variation(out, faces, adj, edge_len) / mm.curvature_variation(verts, faces, adj, edge_len)


# The promise for thin parts: the output's volume within 2% of the
# input's. The bar is also given among the peer settings that keep it.
VOLUME_PROMISE = 0.02


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--only", default="", help="comma-separated family names")
    ap.add_argument("--kinds", default="vox,mc")
    ap.add_argument("--params", help="meshsmooth parameter file")
    ap.add_argument("--no-peers", action="store_true", help="meshsmooth alone")
    ap.add_argument("--placements", type=int, default=PLACEMENTS, help="seeds 0 to N-1")
    ap.add_argument(
        "--curvature",
        action="store_true",
        help="with --no-peers: each placement's curvature variation over its input's, the largest",
    )
    args = ap.parse_args()
    every = subprocess.check_output([str(TOOL), "list"], text=True).split()
    families = [f for f in every if not args.only or f in args.only.split(",")]
    extra = ["--params", args.params] if args.params else []
    tools = {"meshsmooth": cp.meshsmooth(args.binary, extra)}
    if args.no_peers:
        print(
            "| family | kind | meshsmooth median / worst | worst / median | flipped | twisted | min angle | max move "
            "| largest volume change |" + (" largest curvature variation / input's |" if args.curvature else "")
        )
        print("|---|---|---|---|---|---|---|---|---|" + ("---|" if args.curvature else ""))
    else:
        tools.update(cp.sweep())
        print(
            "| family | kind | meshsmooth median / worst (largest volume change) | best peer worst (median) "
            "| setting (largest volume change) | ours / best | best within 2% volume: worst (median) | setting "
            "| ours / it |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([str(TOOL), "dump", tmp, str(args.placements)], check=True)
        for family in families:
            for kind in args.kinds.split(","):
                meshes = [
                    mm.read_obj(os.path.join(tmp, f"{family}_{s}_{kind}.obj")) for s in range(args.placements)
                ]
                results = {}
                for tool, f in tools.items():
                    try:
                        outs = [f(v, faces) for v, faces in meshes]
                        r = [rms(tmp, family, s, out, faces) for s, (out, (_, faces)) in enumerate(zip(outs, meshes))]
                    except Exception:  # a peer that refuses a mesh has no row
                        continue
                    dv = max(
                        abs(mm.volume_change(v, mm.triangles(faces), out)) for out, (v, faces) in zip(outs, meshes)
                    )
                    results[tool] = (float(np.median(r)), max(r), dv)
                    if tool == "meshsmooth" and args.no_peers:
                        # Distances are in voxels: the largest move is too.
                        q = [mm.quality(v, faces, out) for out, (v, faces) in zip(outs, meshes)]
                        worst_quality = (
                            sum(x["flipped"] for x in q),
                            sum(x["twisted"] for x in q),
                            min(x["min_angle"] for x in q),
                            max(x["max_move"] for x in q),
                        )
                        if args.curvature:
                            curvature = max(curvature_ratio(v, faces, out) for out, (v, faces) in zip(outs, meshes))
                ours = results.pop("meshsmooth")
                if args.no_peers:
                    fl, tw, ang, mv = worst_quality
                    print(
                        f"| {family} | {kind} | {ours[0]:.4f} / {ours[1]:.4f} | {ours[1] / ours[0]:.2f} "
                        f"| {fl} | {tw} | {ang:.1f} | {mv:.2f} | {100 * ours[2]:.2f}% |"
                        + (f" {curvature:.3f} |" if args.curvature else ""),
                        flush=True,
                    )
                    continue
                best = min(results.items(), key=lambda kv: kv[1][1])
                kept = {t: r for t, r in results.items() if r[2] <= VOLUME_PROMISE}
                cells = [
                    family,
                    kind,
                    f"{ours[0]:.4f} / {ours[1]:.4f} ({100 * ours[2]:.1f}%)",
                    f"{best[1][1]:.4f} ({best[1][0]:.4f})",
                    f"{best[0]} ({100 * best[1][2]:.1f}%)",
                    f"{ours[1] / best[1][1]:.2f}",
                ]
                if kept:
                    within = min(kept.items(), key=lambda kv: kv[1][1])
                    cells += [
                        f"{within[1][1]:.4f} ({within[1][0]:.4f})",
                        within[0],
                        f"{ours[1] / within[1][1]:.2f}",
                    ]
                else:
                    cells += ["none", "-", "-"]
                print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
