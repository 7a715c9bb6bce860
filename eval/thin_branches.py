"""Thin branches on a thick body: does each part keep its own volume?

A neuron, a vessel tree or an airway is one connected surface whose parts
differ in thickness: a soma with neurites, a trunk with branches. A
smoother may keep the volume of the whole while moving it from the thin
parts to the thick ones (a volume restoration with one offset for the
whole surface does exactly that when the smoothing shrank the thin parts
more). The issue asks that a neurite neither swells nor collapses.

The shape: a ball (the soma, radius 6 voxels) with straight neurites
(capsules 24 voxels long, of radius 1.5, 2 and 3 voxels unless `--radii`
says otherwise, each along its own axis of the body), voxelised at seeded
placements (a random sub-voxel offset and a random rotation per seed),
meshed as voxel quads and as marching cubes the way `real_placements.py`
meshes the real masks, and smoothed by meshsmooth and by the peers at
their defaults
(`compare_peers.defaults`).

For each part it prints, median over the placements:
- the volume change of the part's own stretch of surface, input to output
  (a slab of the neurite between 3 voxels off the soma and 3 voxels off its
  tip, or the soma's cap away from the neurites): the volume is
  `1/2 sum (p - axis) . n dA` over the faces in the slab, which the slab's
  flat ends do not add to, so no cap is needed;
- the mean signed distance of the part's vertices to the true surface
  (positive outside: a neurite of radius r whose vertices end `d` inside
  has lost about `2 d / r` of its cross-section);
- the truth RMS of all vertices (the distance to the union of the parts;
  exact outside, and inside wherever the nearest part is the only one near,
  that is away from the junctions).

    pip install numpy scipy scikit-image pyvista pymeshlab open3d trimesh
    cargo build --release
    python3 eval/thin_branches.py [--binary B] [--params FILE.json] [--placements N] [--kinds vox,mc] [--no-peers] [--radii 1.5,2,3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
import compare_peers as cp  # noqa: E402
import meshmetrics as mm  # noqa: E402
import real_placements as rp  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SOMA = 6.0
LENGTH = 24.0
# The neurites' directions in the body's frame, one per neurite in the
# order of `--radii`: distinct axes, so no two neurites meet but at the soma.
AXES = [
    np.array(a, dtype=float)
    for a in ([1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1])
]
DEFAULT_RADII = (1.5, 2.0, 3.0)
# (name, radius, direction), one per neurite: set from `--radii` by
# `set_neurites`.
NEURITES = []


def set_neurites(radii):
    NEURITES[:] = [(f"neurite r={r:g}", r, axis) for r, axis in zip(radii, AXES)]


set_neurites(DEFAULT_RADII)

# How far from the soma's surface and from a neurite's tip its measured
# stretch starts: past the junction's fillet and the tip's cap.
CLEAR = 3.0


def part_distances(points):
    """Signed distance (positive outside) of body-frame `points` to each
    part: the soma, then the neurites as capsules from the soma's centre."""
    out = [np.linalg.norm(points, axis=1) - SOMA]
    for _, r, axis in NEURITES:
        t = np.clip(points @ axis, 0.0, SOMA + LENGTH)
        out.append(np.linalg.norm(points - t[:, None] * axis, axis=1) - r)
    return np.stack(out, axis=1)


def mask_at(seed):
    """The placement's mask, and the map from its voxel coordinates to the
    body's frame."""
    rng = np.random.default_rng(seed)
    offset = rng.random(3)
    rot = Rotation.random(random_state=seed).as_matrix()
    half = SOMA + LENGTH + 4.0
    n = int(np.ceil(2 * half))
    idx = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)

    def to_body(v):
        return (v - half + offset) @ rot

    mask = (part_distances(to_body(idx.astype(float))).min(axis=1) < 0).reshape(n, n, n)
    return mask, to_body


def stretches(points):
    """Each part's measured stretch, by the body-frame `points` (face
    centroids): neurite k between CLEAR off the soma and CLEAR off its tip
    and nearest to it; the soma within SOMA - CLEAR of the centre along
    every neurite's axis (its cap away from them)."""
    d = part_distances(points)
    nearest = np.argmin(np.abs(d), axis=1)
    parts = []
    soma = nearest == 0
    for _, _, axis in NEURITES:
        soma &= np.abs(points @ axis) < SOMA - CLEAR
    parts.append(soma)
    for k, (_, _, axis) in enumerate(NEURITES, start=1):
        t = points @ axis
        parts.append((nearest == k) & (t > SOMA + CLEAR) & (t < SOMA + LENGTH - CLEAR))
    return parts


def slab_volumes(verts, tris, body, parts):
    """Each part's volume over its faces (`parts`, by face), as
    `1/2 sum (p - axis) . n dA` (a third of `p . n dA` for the soma)."""
    p = body(verts)
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    area_normal = 0.5 * np.cross(b - a, c - a)
    centre = (a + b + c) / 3.0
    out = [float((np.einsum("ij,ij->i", centre, area_normal)[parts[0]]).sum() / 3.0)]
    for k, (_, _, axis) in enumerate(NEURITES, start=1):
        perp = centre - np.outer(centre @ axis, axis)
        out.append(float((np.einsum("ij,ij->i", perp, area_normal)[parts[k]]).sum() / 2.0))
    return out


def measure(verts_in, faces, verts_out, to_body):
    """Per-part volume change and mean signed distance, and the truth RMS."""
    tris = mm.triangles(faces)
    parts = stretches(to_body(verts_in)[tris].mean(axis=1))
    before = slab_volumes(verts_in, tris, to_body, parts)
    after = slab_volumes(verts_out, tris, to_body, parts)
    body_out = to_body(verts_out)
    signed = part_distances(body_out).min(axis=1)
    means = [float(signed[p].mean()) for p in stretches(body_out)]
    changes = [a / b - 1.0 for a, b in zip(after, before)]
    return changes, means, float(np.sqrt(np.mean(signed**2)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "meshsmooth"))
    ap.add_argument("--params", help="meshsmooth parameter file")
    ap.add_argument("--placements", type=int, default=8)
    ap.add_argument("--kinds", default="vox,mc")
    ap.add_argument("--no-peers", action="store_true", help="meshsmooth alone")
    ap.add_argument(
        "--radii",
        default=",".join(f"{r:g}" for r in DEFAULT_RADII),
        help=f"the neurites' radii in voxels, at most {len(AXES)} (a radius near 0.5 is a one-voxel bridge)",
    )
    args = ap.parse_args()
    radii = [float(r) for r in args.radii.split(",")]
    if not 1 <= len(radii) <= len(AXES):
        ap.error(f"--radii takes 1 to {len(AXES)} radii")
    set_neurites(radii)
    tools = {"meshsmooth": cp.meshsmooth(args.binary, ["--params", args.params] if args.params else [])}
    if not args.no_peers:
        tools.update({k: f for k, f in cp.defaults(args.binary).items() if not k.startswith("meshsmooth")})
    names = ["soma"] + [n for n, _, _ in NEURITES]
    meshes = {kind: [] for kind in args.kinds.split(",")}
    for seed in range(args.placements):
        mask, to_body = mask_at(seed)
        quads = rp.voxel_quads(mask)
        outward = mm.signed_volume(quads[0], mm.triangles(quads[1]))
        for kind in meshes:
            verts, faces = quads if kind == "vox" else rp.marching_cubes(mask, outward)
            meshes[kind].append((verts, faces, to_body))
    for kind, placed in meshes.items():
        print(f"\n## {kind}: {args.placements} placements, median over them")
        print(
            "| tool | "
            + " | ".join(f"{n}: volume change" for n in names)
            + " | "
            + " | ".join(f"{n}: mean signed distance" for n in names)
            + " | truth RMS (worst) |"
        )
        print("|---" * (2 * len(names) + 2) + "|")
        for tool, f in tools.items():
            rows = []
            try:
                for verts, faces, to_body in placed:
                    rows.append(measure(verts, faces, f(verts, faces), to_body))
            except Exception as e:  # a peer that refuses a mesh is a row too
                print(f"| {tool} | failed: {e} |")
                continue
            change = np.median([r[0] for r in rows], axis=0)
            mean = np.median([r[1] for r in rows], axis=0)
            rms = [r[2] for r in rows]
            cells = [tool, *(f"{100 * c:+.1f}%" for c in change), *(f"{m:+.3f}" for m in mean)]
            cells.append(f"{np.median(rms):.4f} ({max(rms):.4f})")
            print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
