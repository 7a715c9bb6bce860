"""One set of metrics for every smoother: meshsmooth and its peers.

Every figure compares an output mesh with the input it came from, vertex for
vertex (the smoothers never change connectivity), and optionally with a
sub-voxel ground truth: the surface where a probability map, trilinearly
interpolated, crosses a threshold.

Measures (polygons are read whole; quads are split into the triangles
(v0 v1 v2), (v2 v3 v0) for angles and twists):
- flipped: faces whose vector area points against the same face's in the input
- twisted: quads whose two triangles' normals are more than 90 degrees apart
- angles < 20 / min angle: corner angles of the triangle split, in degrees
- max move: largest vertex displacement, in voxels (or mean input edge lengths)
- curvature variation: mean over vertices of max_{j in N1(i)} |H_i - H_j|,
  H from an unweighted quadric fit to the 2-ring in the area-weighted normal
  frame, times the mean edge length (scale-free)
- volume change: of closed meshes, relative
- truth RMS / median: exact point-to-triangle distances from the output
  vertices to the truth surface (open3d's RaycastingScene)
- truth surface RMS: the same distance over the whole output surface,
  sqrt(integral of d^2 dA / A) over the triangle split, by a six-point
  quadrature rule per triangle. The vertex RMS is the issue's measure; this
  one also sees the faces between the vertices, which on a surface curved
  at the scale of a few edges lie off it by their chords' sag even where
  every vertex lies on it
"""

from __future__ import annotations

import math
import sys

import numpy as np
import scipy.sparse as sp


def read_obj(path):
    """Positions (n, 3) and faces (list of index lists, 0-based) of an OBJ."""
    verts, faces = [], []
    with open(path, "rb") as f:
        for raw in f:
            line = raw.split(b"#", 1)[0].split()
            if not line:
                continue
            if line[0] == b"v":
                verts.append([float(x) for x in line[1:4]])
            elif line[0] == b"f":
                idx = []
                for tok in line[1:]:
                    i = int(tok.split(b"/")[0])
                    idx.append(i - 1 if i > 0 else len(verts) + i)
                faces.append(idx)
    return np.asarray(verts, dtype=np.float64), faces


def write_obj(path, verts, faces):
    """Writes each coordinate in full (the shortest text that reads back to
    the same double): every tool is to smooth the file's own mesh, and on a
    mesh in large units (the neuron's coordinates, around 30,000 nm) nine
    significant digits move its vertices by up to 5e-5, which a smoother's
    thresholds can turn into other decisions. The peers called from Python
    get the arrays themselves."""
    with open(path, "w") as f:
        for v in verts:
            f.write(f"v {float(v[0])!r} {float(v[1])!r} {float(v[2])!r}\n")
        for face in faces:
            f.write("f " + " ".join(str(i + 1) for i in face) + "\n")


def triangles(faces):
    """Fan triangulation (v0 v1 v2), (v0 v2 v3), ... of every polygon, as an
    (m, 3) array; for quads the same split as (v0 v1 v2), (v2 v3 v0)."""
    tris = []
    for face in faces:
        for j in range(1, len(face) - 1):
            tris.append((face[0], face[j], face[j + 1]))
    return np.asarray(tris, dtype=np.int64)


def vector_areas(verts, faces):
    out = np.zeros((len(faces), 3))
    for fi, face in enumerate(faces):
        p = verts[face]
        out[fi] = 0.5 * np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
    return out


def edges_of(faces):
    e = set()
    for face in faces:
        for a, b in zip(face, face[1:] + face[:1]):
            e.add((min(a, b), max(a, b)))
    return np.asarray(sorted(e), dtype=np.int64)


def adjacency(n, edges):
    a = sp.coo_matrix(
        (np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])),
        shape=(n, n),
    ).tocsr()
    a.data[:] = 1
    return a


def triangle_angles(verts, tris):
    p = verts[tris]
    angles = []
    for i in range(3):
        a = p[:, (i + 1) % 3] - p[:, i]
        b = p[:, (i + 2) % 3] - p[:, i]
        cos = (a * b).sum(1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.concatenate(angles)


def twisted_quads(verts, faces):
    n = 0
    for face in faces:
        if len(face) != 4:
            continue
        p = verts[face]
        n1 = np.cross(p[1] - p[0], p[2] - p[0])
        n2 = np.cross(p[3] - p[2], p[0] - p[2])
        if np.dot(n1, n2) < 0:
            n += 1
    return n


def mean_curvature(verts, faces, adj):
    """H per vertex from an unweighted quadric fit to the 2-ring, in the frame
    of the area-weighted vertex normal (outward normals: convex < 0)."""
    n = len(verts)
    va = vector_areas(verts, faces)
    normals = np.zeros((n, 3))
    for fi, face in enumerate(faces):
        normals[face] += va[fi]
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    valid = norm[:, 0] > 1e-12
    normals /= np.maximum(norm, 1e-300)
    ring2 = adj + adj @ adj
    ring2 = ring2.tocsr()
    h = np.zeros(n)
    for i in range(n):
        nb = ring2.indices[ring2.indptr[i] : ring2.indptr[i + 1]]
        nb = nb[nb != i]
        if len(nb) < 6 or not valid[i]:
            continue
        w = normals[i]
        u = np.cross(w, [1.0, 0, 0] if abs(w[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(w, u)
        d = verts[nb] - verts[i]
        x, y, z = d @ u, d @ v, d @ w
        m = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
        beta, *_ = np.linalg.lstsq(m, z, rcond=None)
        a, b, c, e, f = beta[:5]
        ee, ff, gg = 1 + e * e, e * f, 1 + f * f
        r2 = 1 + e * e + f * f
        r = math.sqrt(r2)
        l, mm, nn = 2 * a / r, b / r, 2 * c / r
        # E G - F^2 = 1 + e^2 + f^2, written so: the product form cancels to
        # zero when a near-degenerate ring makes the slopes huge.
        hi = (ee * nn - 2 * ff * mm + gg * l) / (2 * r2)
        h[i] = hi if math.isfinite(hi) else 0.0
    return h


def curvature_variation(verts, faces, adj, edge_len):
    """Mean over vertices of the largest 1-ring difference of H, times the
    mean edge length. |H| is capped at that of a sphere of a tenth of an
    edge's radius, far tighter than any surface a mesh of this edge length
    shows: a ring whose points nearly coincide (a sheet collapsed onto
    itself) fits an arbitrarily large H, and one such vertex would decide
    the mean. Only rings close to degenerate reach the cap (it moves the
    WM crop results' figures by 0.002 at most)."""
    h = np.clip(mean_curvature(verts, faces, adj), -10.0 / edge_len, 10.0 / edge_len)
    a = adj.tocoo()
    diff = np.abs(h[a.row] - h[a.col])
    mx = np.zeros(len(verts))
    np.maximum.at(mx, a.row, diff)
    return float(mx.mean() * edge_len)


def signed_volume(verts, tris):
    p = verts[tris]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


def volume_change(input_verts, tris, verts):
    """The relative change of the volume `tris` enclose, `input_verts` to
    `verts`."""
    v0 = signed_volume(input_verts, tris)
    return (signed_volume(verts, tris) - v0) / abs(v0)


def is_closed(edges_count):
    return all(c % 2 == 0 for c in edges_count.values())


class Truth:
    """The surface where a probability map, trilinearly interpolated, equals
    `level`: marching cubes of the map resampled `upsample` times finer,
    queried with exact point-to-triangle distances. The fine map is made and
    meshed in slabs of `SLAB` voxels along the first axis, so a whole-brain
    map at 1 mm needs no more memory than a slab of it (the slabs share
    their boundary planes, and marching cubes meshes each cell once)."""

    SLAB = 16

    def __init__(self, nifti_path=None, level=127.5, upsample=4, data=None, affine=None):
        """The truth of the map in `nifti_path`, or of the array `data`
        whose voxel index maps to world coordinates by `affine`."""
        import open3d as o3d
        from scipy.ndimage import map_coordinates
        from skimage.measure import marching_cubes

        if nifti_path is not None:
            import nibabel as nib

            img = nib.load(nifti_path)
            data, affine = np.asarray(img.dataobj, dtype=np.float64), img.affine
        self.affine = np.asarray(affine, dtype=np.float64)
        self.shape = data.shape
        axes = [np.arange(0, s - 1 + 1e-9, 1.0 / upsample) for s in data.shape]
        verts, faces, count = [], [], 0
        # At least one slab: a map one voxel deep is one plane.
        starts = list(range(0, max(len(axes[0]) - 1, 1), self.SLAB * upsample))
        for k, start in enumerate(starts):
            stop = min(start + self.SLAB * upsample, len(axes[0]) - 1)
            grid = np.meshgrid(axes[0][start : stop + 1], axes[1], axes[2], indexing="ij")
            fine = map_coordinates(data, [g.ravel() for g in grid], order=1).reshape(grid[0].shape)
            # Pad with the outside value so the truth closes at the volume's
            # edge: every side of the first axis's end slabs, the others'
            # always.
            first, last = k == 0, k == len(starts) - 1
            fine = np.pad(fine, ((int(first), int(last)), (1, 1), (1, 1)), constant_values=0.0)
            if fine.max() <= level or fine.min() > level:
                continue
            v, f, _, _ = marching_cubes(fine, level)
            v = (v - [int(first) - start, 1.0, 1.0]) / upsample
            verts.append(v)
            faces.append(f + count)
            count += len(v)
        v, f = np.concatenate(verts), np.concatenate(faces)
        world = v @ self.affine[:3, :3].T + self.affine[:3, 3]
        self.voxel = float(abs(np.linalg.det(self.affine[:3, :3])) ** (1 / 3))
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor(world.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32))
        )
        self.scene = scene

    def index_of(self, points):
        inv = np.linalg.inv(self.affine)
        return points @ inv[:3, :3].T + inv[:3, 3]

    def inside_crop(self, points, margin):
        """Points at least `margin` voxels inside the map's volume."""
        idx = self.index_of(points)
        hi = np.asarray(self.shape) - 1 - margin
        return np.all((idx >= margin) & (idx <= hi), axis=1)

    def distances(self, points):
        import open3d as o3d

        q = o3d.core.Tensor(points.astype(np.float32))
        return self.scene.compute_distance(q).numpy().astype(np.float64)


def quality(input_verts, faces, verts):
    """The cheap measures of `verts` against `input_verts`: faces flipped
    against the same input face, twisted quads, triangle-split angles under
    20 degrees, the smallest one, and the largest move (in the mesh's units)."""
    va_in = vector_areas(input_verts, faces)
    va_out = vector_areas(verts, faces)
    angles = triangle_angles(verts, triangles(faces))
    return {
        "flipped": int(((va_in * va_out).sum(1) < 0).sum()),
        "twisted": twisted_quads(verts, faces),
        "angles_lt20": int((angles < 20).sum()),
        "min_angle": float(angles.min()),
        "max_move": float(np.linalg.norm(verts - input_verts, axis=1).max()),
    }


def input_adjacency(input_verts, faces):
    """The vertex adjacency of `faces` and the input's mean edge length: the
    unit the curvature variation is measured in, for the input and every
    output alike."""
    edges = edges_of(faces)
    adj = adjacency(len(input_verts), edges)
    edge_len = float(np.linalg.norm(input_verts[edges[:, 0]] - input_verts[edges[:, 1]], axis=1).mean())
    return adj, edge_len


def measure(input_verts, faces, verts, voxel=None, truth=None, truth_margin=None):
    """All measures of `verts` (an output of a smoother run on
    (`input_verts`, `faces`)) as a dict."""
    n = len(verts)
    adj, edge_len = input_adjacency(input_verts, faces)
    unit = voxel if voxel else edge_len
    tris = triangles(faces)
    counts = {}
    for face in faces:
        for a, b in zip(face, face[1:] + face[:1]):
            k = (min(a, b), max(a, b))
            counts[k] = counts.get(k, 0) + 1
    out = quality(input_verts, faces, verts)
    out["max_move"] /= unit
    out["curv_var"] = curvature_variation(verts, faces, adj, edge_len)
    if is_closed(counts):
        out["volume_change"] = volume_change(input_verts, tris, verts)
    if truth is not None:
        sel = np.ones(n, dtype=bool) if truth_margin is None else truth.inside_crop(verts, truth_margin)
        d = truth.distances(verts[sel])
        out["truth_rms"] = float(np.sqrt((d * d).mean()))
        out["truth_median"] = float(np.median(d))
        out["truth_surface_rms"] = surface_rms(truth, verts, tris, truth_margin)
    return out


# The six-point quadrature rule of degree 4 on a triangle (Strang and Fix):
# barycentric (a, a, 1 - 2a) and its permutations, for the two values of a,
# with these weights (they sum to 1).
QUADRATURE = [(0.445948490915965, 0.223381589678011), (0.091576213509771, 0.109951743655322)]


def surface_rms(truth, verts, tris, margin=None):
    """RMS distance to the truth over the surface of `tris` (of `verts`):
    sqrt(integral of d^2 dA / A), the integral per triangle by the six-point
    rule. With `margin`, over the quadrature points at least `margin` voxels
    inside the map's volume."""
    tris = np.asarray(tris)
    corners = verts[tris]  # (T, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    points, weights = [], []
    for a, w in QUADRATURE:
        b = 1.0 - 2.0 * a
        for bary in ((a, a, b), (a, b, a), (b, a, a)):
            points.append(np.einsum("k,tkd->td", np.asarray(bary), corners))
            weights.append(w * area)
    points, weights = np.concatenate(points), np.concatenate(weights)
    if margin is not None:
        keep = truth.inside_crop(points, margin)
        points, weights = points[keep], weights[keep]
    d = truth.distances(points)
    return float(np.sqrt((weights * d * d).sum() / weights.sum()))


if __name__ == "__main__":
    # meshmetrics.py INPUT.obj OUTPUT.obj [PROB.nii.gz [MARGIN]]
    vin, faces = read_obj(sys.argv[1])
    vout, faces_out = read_obj(sys.argv[2])
    truth = Truth(sys.argv[3]) if len(sys.argv) > 3 else None
    margin = float(sys.argv[4]) if len(sys.argv) > 4 else None
    print(measure(vin, faces, vout, voxel=truth.voxel if truth else None, truth=truth, truth_margin=margin))
