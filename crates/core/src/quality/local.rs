//! Per-face predicates shared by the measures and the fixes, and the local
//! acceptance test every quality move goes through.
//!
//! The triangle split is the paper's: a quad `(v1 v2 v3 v4)` splits into
//! `(v1 v2 v3)` and `(v3 v4 v1)`, a general polygon fans from its corner 0
//! (for a quad the fan `(v1 v2 v3), (v1 v3 v4)` is the same pair), and a
//! triangle is itself. Angles are compared through their cosines (cosine
//! falls as the angle grows), so no `acos` runs in the hot loops. A corner
//! with a zero-length side counts as a 0° angle (cosine 1).

use crate::mesh::{Mesh, Topology, vector_area};
use crate::smoothing::frame::Frame;
use crate::smoothing::quadric_fit::{FitKind, QuadricFit, fit_quadric};
use glam::DVec3;

/// Cosine of the angle between `a` and `b`; 1 (a 0° angle) when either is
/// zero or the quotient is not a number.
#[inline]
pub(crate) fn cos_between(a: DVec3, b: DVec3) -> f64 {
    let d = (a.length_squared() * b.length_squared()).sqrt();
    if d > 0.0 {
        let c = a.dot(b) / d;
        if c.is_nan() { 1.0 } else { c.clamp(-1.0, 1.0) }
    } else {
        1.0
    }
}

/// Cosines of the three corner angles of triangle `(a, b, c)`, in corner
/// order.
#[inline]
pub(crate) fn triangle_cosines(a: DVec3, b: DVec3, c: DVec3) -> [f64; 3] {
    let ab = b - a;
    let bc = c - b;
    let ca = a - c;
    [
        cos_between(ab, -ca),
        cos_between(bc, -ab),
        cos_between(ca, -bc),
    ]
}

/// True when a face repeats a corner index (its angles are undefined).
#[inline]
pub(crate) fn has_repeated_corner(face: &[u32]) -> bool {
    face.iter().enumerate().any(|(j, v)| face[..j].contains(v))
}

/// Calls `f(a, b, c)` for each triangle of the split of `face`, with the
/// corners' positions.
#[inline]
pub(crate) fn for_each_split_triangle(
    face: &[u32],
    positions: &[DVec3],
    mut f: impl FnMut(DVec3, DVec3, DVec3),
) {
    let o = positions[face[0] as usize];
    for j in 1..face.len().saturating_sub(1) {
        f(
            o,
            positions[face[j] as usize],
            positions[face[j + 1] as usize],
        );
    }
}

/// Cosine from a dot product and two squared lengths; 1 (a 0° angle) when
/// a length is zero or the quotient is not a number.
#[inline]
fn cos_from(dot: f64, l1: f64, l2: f64) -> f64 {
    let d = (l1 * l2).sqrt();
    if d > 0.0 {
        let c = dot / d;
        if c.is_nan() { 1.0 } else { c.clamp(-1.0, 1.0) }
    } else {
        1.0
    }
}

/// Cosine of the smallest angle of triangle `(a, b, c)`: the angle opposite
/// its shortest side.
#[inline]
pub(crate) fn min_angle_cos(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let ab = b - a;
    let bc = c - b;
    let ca = a - c;
    let (x, y, z) = (
        ab.length_squared(),
        bc.length_squared(),
        ca.length_squared(),
    );
    if x <= y && x <= z {
        cos_from(-ca.dot(bc), z, y) // at c
    } else if y <= z {
        cos_from(-ab.dot(ca), x, z) // at a
    } else {
        cos_from(-bc.dot(ab), y, x) // at b
    }
}

/// Largest cosine (that is, the smallest angle) over the split triangles'
/// corners of `face`.
#[inline]
pub(crate) fn max_split_cos(face: &[u32], positions: &[DVec3]) -> f64 {
    let mut m = -1.0f64;
    for_each_split_triangle(face, positions, |a, b, c| {
        m = m.max(min_angle_cos(a, b, c));
    });
    m
}

/// A quad is twisted when the normals of its split triangles `(v1 v2 v3)`
/// and `(v3 v4 v1)` are more than 90° apart. Other faces are never twisted.
#[inline]
pub(crate) fn is_twisted(face: &[u32], positions: &[DVec3]) -> bool {
    if face.len() != 4 {
        return false;
    }
    let [p1, p2, p3, p4] = [0, 1, 2, 3].map(|j| positions[face[j] as usize]);
    let n1 = (p2 - p1).cross(p3 - p1);
    let n2 = (p4 - p3).cross(p1 - p3);
    n1.dot(n2) < 0.0
}

/// A face is inverted relative to the input when its vector area, or the
/// normal of any of its split triangles, points against the same quantity
/// in `input` (negative dot product).
#[inline]
pub(crate) fn is_inverted(face: &[u32], positions: &[DVec3], input: &[DVec3]) -> bool {
    if vector_area(face, positions).dot(vector_area(face, input)) < 0.0 {
        return true;
    }
    if face.len() == 3 {
        return false;
    }
    let (o, o0) = (positions[face[0] as usize], input[face[0] as usize]);
    (1..face.len() - 1).any(|j| {
        let (a, b) = (face[j] as usize, face[j + 1] as usize);
        let n = (positions[a] - o).cross(positions[b] - o);
        let n0 = (input[a] - o0).cross(input[b] - o0);
        n.dot(n0) < 0.0
    })
}

/// The state of one face that moves are judged on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FaceState {
    pub inverted: bool,
    pub twisted: bool,
    /// Cosine of the face's smallest split-triangle angle.
    pub max_cos: f64,
}

/// Twice the area-weighted normals of the split triangles of `face` (fan
/// from corner 0), appended to `out`, followed by their sum (twice the
/// vector area).
#[inline]
fn push_split_normals(face: &[u32], positions: &[DVec3], out: &mut Vec<DVec3>) {
    let o = positions[face[0] as usize];
    let mut sum = DVec3::ZERO;
    for j in 1..face.len() - 1 {
        let n = (positions[face[j] as usize] - o).cross(positions[face[j + 1] as usize] - o);
        sum += n;
        out.push(n);
    }
    out.push(sum);
}

/// State of `face` given the split normals of the input (as written by
/// `push_split_normals`).
#[inline]
fn face_state_with(face: &[u32], positions: &[DVec3], input_normals: &[DVec3]) -> FaceState {
    let o = positions[face[0] as usize];
    let k = face.len();
    let mut sum = DVec3::ZERO;
    let mut first = DVec3::ZERO;
    let mut inverted = false;
    let mut twisted = false;
    let mut max_cos = -1.0f64;
    for j in 1..k - 1 {
        let a = positions[face[j] as usize];
        let b = positions[face[j + 1] as usize];
        let n = (a - o).cross(b - o);
        if k > 3 {
            inverted |= n.dot(input_normals[j - 1]) < 0.0;
        }
        if j == 1 {
            first = n;
        } else if k == 4 {
            twisted = first.dot(n) < 0.0;
        }
        sum += n;
        max_cos = max_cos.max(min_angle_cos(o, a, b));
    }
    inverted |= sum.dot(input_normals[k - 2]) < 0.0;
    FaceState {
        inverted,
        twisted,
        max_cos,
    }
}

/// State of `face` at `positions` against `input`.
#[inline]
pub(crate) fn face_state(face: &[u32], positions: &[DVec3], input: &[DVec3]) -> FaceState {
    let mut buf = [DVec3::ZERO; 8];
    if face.len() <= 7 {
        let o = input[face[0] as usize];
        let mut sum = DVec3::ZERO;
        for j in 1..face.len() - 1 {
            let n = (input[face[j] as usize] - o).cross(input[face[j + 1] as usize] - o);
            buf[j - 1] = n;
            sum += n;
        }
        buf[face.len() - 2] = sum;
        face_state_with(face, positions, &buf)
    } else {
        let mut v = Vec::with_capacity(face.len());
        push_split_normals(face, input, &mut v);
        face_state_with(face, positions, &v)
    }
}

/// What a tried move would do to the faces around it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Verdict {
    /// A face that was not inverted becomes inverted, or a quad that was not
    /// twisted becomes twisted: the move is never allowed.
    pub new_defect: bool,
    /// Inverted faces before and after, among the affected faces.
    pub inverted: (u32, u32),
    /// Twisted quads before and after, among the affected faces.
    pub twisted: (u32, u32),
    /// Cosine of the smallest split-triangle angle over the affected faces,
    /// before and after.
    pub max_cos: (f64, f64),
}

impl Verdict {
    /// No new defect and the smallest angle did not shrink.
    pub fn keeps_quality(&self) -> bool {
        !self.new_defect
            && self.inverted.1 <= self.inverted.0
            && self.twisted.1 <= self.twisted.0
            && self.max_cos.1 <= self.max_cos.0
    }

    /// No new defect and either fewer defects or a strictly larger smallest
    /// angle, with no more defects than before.
    pub fn improves(&self) -> bool {
        if self.new_defect || self.inverted.1 > self.inverted.0 || self.twisted.1 > self.twisted.0 {
            return false;
        }
        self.inverted.1 < self.inverted.0
            || self.twisted.1 < self.twisted.0
            || self.max_cos.1 < self.max_cos.0
    }
}

/// Tries moves of a few vertices and undoes them unless they pass a test.
/// Holds scratch buffers so that a try allocates nothing once warmed up.
#[derive(Debug, Default)]
pub(crate) struct MoveTester {
    faces: Vec<u32>,
    /// Start of each face's input split normals in `input_normals`.
    starts: Vec<u32>,
    input_normals: Vec<DVec3>,
    before: Vec<FaceState>,
    saved: Vec<(usize, DVec3)>,
}

impl MoveTester {
    /// Collects the faces around `vertices` (each once, skipping faces with
    /// a repeated corner) and records their state.
    pub fn begin(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        vertices: &[usize],
        positions: &[DVec3],
        input: &[DVec3],
    ) {
        self.faces.clear();
        for &v in vertices {
            for &f in topo.vertex_faces(v) {
                if !self.faces.contains(&f) && !has_repeated_corner(mesh.face(f as usize)) {
                    self.faces.push(f);
                }
            }
        }
        self.starts.clear();
        self.input_normals.clear();
        self.before.clear();
        for &f in &self.faces {
            let face = mesh.face(f as usize);
            let start = self.input_normals.len();
            self.starts.push(start as u32);
            push_split_normals(face, input, &mut self.input_normals);
            self.before.push(face_state_with(
                face,
                positions,
                &self.input_normals[start..],
            ));
        }
    }

    /// Applies `moves` (vertex, new position), judges the affected faces
    /// recorded by [`MoveTester::begin`], and leaves the moves applied.
    /// Call [`MoveTester::undo`] to revert them.
    pub fn apply(
        &mut self,
        mesh: &Mesh,
        moves: &[(usize, DVec3)],
        positions: &mut [DVec3],
    ) -> Verdict {
        self.saved.clear();
        for &(v, _) in moves {
            self.saved.push((v, positions[v]));
        }
        for &(v, p) in moves {
            positions[v] = p;
        }
        let mut verdict = Verdict {
            new_defect: false,
            inverted: (0, 0),
            twisted: (0, 0),
            max_cos: (-1.0, -1.0),
        };
        for ((&f, b), &start) in self.faces.iter().zip(&self.before).zip(&self.starts) {
            let normals = &self.input_normals[start as usize..];
            let a = face_state_with(mesh.face(f as usize), positions, normals);
            verdict.new_defect |= (a.inverted && !b.inverted) || (a.twisted && !b.twisted);
            verdict.inverted.0 += b.inverted as u32;
            verdict.inverted.1 += a.inverted as u32;
            verdict.twisted.0 += b.twisted as u32;
            verdict.twisted.1 += a.twisted as u32;
            verdict.max_cos.0 = verdict.max_cos.0.max(b.max_cos);
            verdict.max_cos.1 = verdict.max_cos.1.max(a.max_cos);
        }
        verdict
    }

    /// Reverts the moves of the last [`MoveTester::apply`].
    pub fn undo(&mut self, positions: &mut [DVec3]) {
        for &(v, p) in self.saved.iter().rev() {
            positions[v] = p;
        }
        self.saved.clear();
    }
}

/// Unit normal at `v` from the vector areas of its faces (zero when they
/// cancel).
pub(crate) fn vertex_normal(mesh: &Mesh, topo: &Topology, v: usize, positions: &[DVec3]) -> DVec3 {
    topo.vertex_faces(v)
        .iter()
        .map(|&f| vector_area(mesh.face(f as usize), positions))
        .sum::<DVec3>()
        .normalize_or_zero()
}

/// Appends the 2-ring of `v` (every vertex within two edges, not `v`) to
/// `out`, sorted and without duplicates.
pub(crate) fn two_ring(topo: &Topology, v: usize, out: &mut Vec<u32>) {
    out.clear();
    for &a in topo.neighbors(v) {
        out.push(a);
        out.extend(topo.neighbors(a as usize).iter().copied());
    }
    out.sort_unstable();
    out.dedup();
    out.retain(|&w| w as usize != v);
}

/// The link of interior vertex `v`: the corners of its faces other than
/// `v`, in order around `v` (counter-clockwise seen from the side its faces'
/// normals point to), each once. Returns false (and leaves `out` in an
/// unspecified state) when the faces do not chain into one closed fan.
pub(crate) fn ordered_link(mesh: &Mesh, topo: &Topology, v: usize, out: &mut Vec<u32>) -> bool {
    out.clear();
    let faces = topo.vertex_faces(v);
    if faces
        .iter()
        .any(|&f| has_repeated_corner(mesh.face(f as usize)))
    {
        return false;
    }
    let Some((&first, rest)) = faces.split_first() else {
        return false;
    };
    // Corners after `v` up to the one before `v`, cyclically.
    let segment = |f: u32| -> Option<(usize, &[u32])> {
        let face = mesh.face(f as usize);
        let at = face.iter().position(|&w| w as usize == v)?;
        Some((at, face))
    };
    let Some((at, face)) = segment(first) else {
        return false;
    };
    let k = face.len();
    for j in 1..k {
        out.push(face[(at + j) % k]);
    }
    let mut used = 1usize;
    let mut pending_mask: u64 = 0; // bit i set = rest[i] used (fans of <= 64 faces)
    if rest.len() > 64 {
        return false;
    }
    while used < faces.len() {
        let last = *out.last().unwrap_or(&u32::MAX);
        let mut found = false;
        for (i, &f) in rest.iter().enumerate() {
            if pending_mask & (1 << i) != 0 {
                continue;
            }
            let Some((at, face)) = segment(f) else {
                return false;
            };
            let k = face.len();
            if face[(at + 1) % k] == last {
                for j in 2..k {
                    out.push(face[(at + j) % k]);
                }
                pending_mask |= 1 << i;
                used += 1;
                found = true;
                break;
            }
        }
        if !found {
            return false;
        }
    }
    // A closed fan ends where it started.
    if out.len() < 3 || out.last() != out.first() {
        return false;
    }
    out.pop();
    true
}

/// The fitted surface around a vertex: its quadric (section 3) in the frame
/// at its current position and normal, fitted to its 2-ring.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LocalSurface {
    pub frame: Frame,
    pub fit: QuadricFit,
}

impl LocalSurface {
    /// Fits the surface at `v`; `None` when `v` has no usable normal.
    pub fn at(
        mesh: &Mesh,
        topo: &Topology,
        v: usize,
        positions: &[DVec3],
        ring: &mut Vec<u32>,
    ) -> Option<LocalSurface> {
        let n = vertex_normal(mesh, topo, v, positions);
        if n == DVec3::ZERO {
            return None;
        }
        let frame = Frame::new(positions[v], n);
        two_ring(topo, v, ring);
        let fit = fit_quadric(&frame, positions, ring);
        Some(LocalSurface { frame, fit })
    }

    /// The point of the fitted surface above the tangent-plane point `(x,
    /// y)` (local coordinates). Without a usable fit the point stays in the
    /// tangent plane.
    pub fn point(&self, x: f64, y: f64) -> DVec3 {
        let z = match self.fit.kind {
            FitKind::Fixed => 0.0,
            FitKind::Quadric | FitKind::Plane => {
                let [a, b, c, e, f, g] = self.fit.coeffs;
                a * x * x + b * x * y + c * y * y + e * x + f * y + g
            }
        };
        self.frame.to_world(DVec3::new(x, y, z))
    }

    /// Tangent-plane coordinates `(x, y)` of a world point.
    pub fn tangent(&self, q: DVec3) -> (f64, f64) {
        let l = self.frame.to_local(q);
        (l.x, l.y)
    }
}

/// Angle-based smoothing target of Zhou & Shimada (2000) in the tangent
/// plane of `surface`, for a vertex whose ordered link is `link`: the mean
/// over link vertices `l_j` of the vertex rotated about `l_j` onto the
/// bisector of the link's interior angle at `l_j`. Returns the tangent
/// coordinates, or `None` when no link corner is usable.
pub(crate) fn angle_based_target(
    surface: &LocalSurface,
    link: &[u32],
    positions: &[DVec3],
) -> Option<(f64, f64)> {
    let m = link.len();
    if m < 3 {
        return None;
    }
    let pt = |j: usize| -> (f64, f64) { surface.tangent(positions[link[j % m] as usize]) };
    let (mut sx, mut sy, mut count) = (0.0, 0.0, 0u32);
    for j in 0..m {
        let cur = pt(j);
        let next = pt(j + 1);
        let prev = pt(j + m - 1);
        let a = (next.0 - cur.0, next.1 - cur.1);
        let b = (prev.0 - cur.0, prev.1 - cur.1);
        let la = (a.0 * a.0 + a.1 * a.1).sqrt();
        let r = (cur.0 * cur.0 + cur.1 * cur.1).sqrt();
        if la == 0.0 || b == (0.0, 0.0) || r == 0.0 {
            continue;
        }
        // Bisector of the interior angle, counter-clockwise from `a` to `b`
        // (the link runs counter-clockwise, its interior on the left).
        let lb = (b.0 * b.0 + b.1 * b.1).sqrt();
        let (ua, ub) = ((a.0 / la, a.1 / la), (b.0 / lb, b.1 / lb));
        let (hx, hy) = (ua.0 + ub.0, ua.1 + ub.1);
        let lh = (hx * hx + hy * hy).sqrt();
        let cross = ua.0 * ub.1 - ua.1 * ub.0;
        let dir = if lh < 1e-9 {
            (-ua.1, ua.0) // a straight angle: the left normal of `a`
        } else if cross >= 0.0 {
            (hx / lh, hy / lh)
        } else {
            (-hx / lh, -hy / lh) // a reflex angle
        };
        sx += cur.0 + r * dir.0;
        sy += cur.1 + r * dir.1;
        count += 1;
    }
    (count > 0).then(|| (sx / count as f64, sy / count as f64))
}

/// Mean of the link vertices in the tangent plane of `surface`.
pub(crate) fn link_centroid(
    surface: &LocalSurface,
    link: &[u32],
    positions: &[DVec3],
) -> Option<(f64, f64)> {
    if link.is_empty() {
        return None;
    }
    let (mut sx, mut sy) = (0.0, 0.0);
    for &w in link {
        let (x, y) = surface.tangent(positions[w as usize]);
        sx += x;
        sy += y;
    }
    let k = link.len() as f64;
    Some((sx / k, sy / k))
}

/// Tangent-plane steps (local coordinates of `surface`) that turn each
/// split triangle at `v` that is inverted relative to `input` the right
/// way round: a triangle `(v, a, b)`'s normal dotted with its input normal
/// `m` is affine in `v`, `(a x b).m + v.((a - b) x m)`, so the step along
/// the tangent part of `(a - b) x m` that makes it positive is exact up to
/// the lift onto the surface. Two steps per triangle (1.5 and 3 times the
/// step that reaches zero), at most four triangles.
pub(crate) fn uninvert_steps(
    mesh: &Mesh,
    topo: &Topology,
    v: usize,
    positions: &[DVec3],
    input: &[DVec3],
    surface: &LocalSurface,
    out: &mut Vec<(f64, f64)>,
) {
    let mut found = 0;
    for &f in topo.vertex_faces(v) {
        let face = mesh.face(f as usize);
        for j in 1..face.len() - 1 {
            let tri = [face[0], face[j], face[j + 1]];
            let Some(at) = tri.iter().position(|&w| w as usize == v) else {
                continue;
            };
            let (a, b) = (tri[(at + 1) % 3] as usize, tri[(at + 2) % 3] as usize);
            let m = (input[a] - input[v]).cross(input[b] - input[v]);
            let n = (positions[a] - positions[v]).cross(positions[b] - positions[v]);
            let s = n.dot(m);
            if s >= 0.0 {
                continue;
            }
            let g = (positions[a] - positions[b]).cross(m);
            let (gx, gy) = (g.dot(surface.frame.u), g.dot(surface.frame.v));
            let gg = gx * gx + gy * gy;
            if gg.is_nan() || gg <= 0.0 {
                continue;
            }
            let t = -s / gg;
            out.extend([1.5, 3.0].map(|k| (k * t * gx, k * t * gy)));
            found += 1;
            if found == 4 {
                return;
            }
        }
    }
}
