//! Step 3: weighted least-squares quadric fit (algorithm notes section 3).
//!
//! Fits `h(x, y) = a x^2 + b x y + c y^2 + e x + f y + g` to neighbours in a
//! vertex's local [`Frame`] by solving the 6x6 normal equations
//! `(M^T W M) beta = M^T W z` with an LDL^T factorisation in f64. The
//! adaptive passes may add the four cubic terms `x^3, x^2 y, x y^2, y^3`
//! ([`FitModel::Cubic`], 10x10 equations); the curvature at the vertex and
//! the projection height `g` are read the same way.
//!
//! Open choices, decided here:
//! - Weights are Gaussian-like, `w_j ~ exp(-d_j^2 / (2 s^2))` ([`weight`]),
//!   `d_j` the distance from the vertex and `s^2` the mean of `d_j^2` over
//!   the neighbourhood, so the weighting is scale-free and adapts to the ring
//!   size.
//! - The vertex itself is not a fitted point (including it pulls `g` to 0
//!   and smooths less).
//! - Coordinates are divided by `s` before the fit, so pivots are comparable
//!   across scales. A pivot below [`MIN_RELATIVE_PIVOT`] times the largest
//!   diagonal entry, fewer than 6 points, or a fitted height beyond `s` (a
//!   spike) falls back to a plane `e x + f y + g`; if that is also singular
//!   the vertex stays in place ([`FitKind::Fixed`]).
//! - Why cubic terms: a ring neighbourhood
//!   is never exactly symmetric about its vertex, and where the curvature
//!   changes across it (an ellipsoid) a paraboloid absorbs the change into
//!   `g`, a bias that every pass adds again. The cubic terms take it up
//!   (`docs/tuning.md` has the ellipsoid's error with and without). They
//!   cost noise (four more unknowns), so a cubic fit
//!   needs [`MIN_CUBIC_POINTS`] points and weights its points with a
//!   narrower kernel ([`CUBIC_KERNEL`]), which also keeps the remaining
//!   (quartic) bias down.

use super::frame::Frame;
use glam::{DVec3, Vec3};

/// Relative pivot below which a normal-equation system counts as singular.
pub const MIN_RELATIVE_PIVOT: f64 = 1e-7;

/// Most points one fit accepts; neighbourhoods are thinned to this size
/// before fitting.
pub const MAX_FIT_POINTS: usize = 512;

/// Fits of up to this many points gather them on the stack.
const STACK_POINTS: usize = 64;

/// A cubic fit needs at least this many points; fewer fit the quadric.
pub const MIN_CUBIC_POINTS: usize = 14;

/// A cubic fit weights point `j` by [`weight`]`(CUBIC_KERNEL d_j^2 / s^2)`:
/// a Gaussian of width `s / 2` instead of the quadric's `s`.
pub const CUBIC_KERNEL: f64 = 4.0;

/// The richest model a fit tries; it falls back to the next simpler one
/// (cubic, quadric, plane, fixed) when the points do not support it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FitModel {
    /// A plane `e x + f y + g` only (curvature 0).
    Plane,
    /// The quadric of section 3.
    Quadric,
    /// The quadric plus the cubic terms `x^3, x^2 y, x y^2, y^3`.
    Cubic,
}

/// Which model a fit ended up using.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FitKind {
    /// The quadric plus cubic terms ([`FitModel::Cubic`]); `coeffs` hold its
    /// quadric part, which gives the height and curvature at the vertex.
    Cubic,
    /// The full quadric.
    Quadric,
    /// Fallback: a plane `e x + f y + g` (curvature 0).
    Plane,
    /// Fallback: no usable fit; the vertex does not move.
    Fixed,
}

/// Result of one fit, in the frame's units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadricFit {
    /// Coefficients `[a, b, c, e, f, g]` of `h(x, y)`.
    pub coeffs: [f64; 6],
    /// Model used.
    pub kind: FitKind,
}

impl QuadricFit {
    /// The fit that leaves the vertex where it is.
    pub const FIXED: QuadricFit = QuadricFit {
        coeffs: [0.0; 6],
        kind: FitKind::Fixed,
    };

    /// The fit in the frame's units from coefficients `beta` solved in
    /// coordinates scaled by `1 / s` (its quadric part: `a, b, c` scale by
    /// `1 / s`, `e, f` are slopes, `g` scales by `s`).
    fn from_scaled(beta: &[f64], s: f64, kind: FitKind) -> QuadricFit {
        let inv_s = 1.0 / s;
        QuadricFit {
            coeffs: [
                beta[0] * inv_s,
                beta[1] * inv_s,
                beta[2] * inv_s,
                beta[3],
                beta[4],
                beta[5] * s,
            ],
            kind,
        }
    }

    /// A fit known only by its height `g` (in the frame's units): what a
    /// cubic fit made for its linear weights solves for.
    fn height_only(g: f64, kind: FitKind) -> QuadricFit {
        QuadricFit {
            coeffs: [0.0, 0.0, 0.0, 0.0, 0.0, g],
            kind,
        }
    }

    /// Height of the fitted surface above the vertex, `h(0, 0) = g`.
    #[inline]
    pub fn height(&self) -> f64 {
        self.coeffs[5]
    }

    /// Mean and Gaussian curvature `(H, K)` of the fitted surface at
    /// `(0, 0)` (algorithm notes section 5; convex is `H < 0` with outward
    /// normals).
    #[inline]
    pub fn curvature(&self) -> (f64, f64) {
        let [a, b, c, e, f, _] = self.coeffs;
        let r = (1.0 + e * e + f * f).sqrt();
        let (ee, ff, gg) = (1.0 + e * e, e * f, 1.0 + f * f);
        let (l, m, n) = (2.0 * a / r, b / r, 2.0 * c / r);
        let det = ee * gg - ff * ff;
        let k = (l * n - m * m) / det;
        let h = (ee * n - 2.0 * ff * m + gg * l) / (2.0 * det);
        (h, k)
    }
}

/// Fits a quadric to `positions[neighbours]` in `frame`. At most
/// [`MAX_FIT_POINTS`] neighbours are used (the rest are ignored).
pub fn fit_quadric(frame: &Frame, positions: &[DVec3], neighbours: &[u32]) -> QuadricFit {
    fit_neighbours(frame, positions, neighbours, FitModel::Quadric, None)
}

/// Neighbours a fit leaves out: those whose unit normal makes a cosine
/// below `min_cos` with the fitted vertex's normal. They lie on the far
/// side of a thin plate or tube (a one-voxel sheet, a neurite) or across a
/// fold, and fitting them would pull the two sides together.
#[derive(Debug, Clone, Copy)]
pub struct Facing<'a> {
    /// Unit normal of every vertex.
    pub normals: &'a [Vec3],
    /// Smallest accepted cosine between a neighbour's normal and the
    /// vertex's.
    pub min_cos: f64,
}

/// Fits `model` (or a simpler fallback) to `positions[neighbours]` in
/// `frame`. [`FitModel::Plane`] is for boundary vertices, whose one-sided
/// neighbourhood would make a quadric extrapolate. With `facing`,
/// neighbours facing away are left out.
pub fn fit_neighbours(
    frame: &Frame,
    positions: &[DVec3],
    neighbours: &[u32],
    model: FitModel,
    facing: Option<Facing>,
) -> QuadricFit {
    gather_and_fit(frame, positions, neighbours, model, facing, None)
}

/// [`fit_neighbours`], and also the fit's linear weights: `weights[j]`
/// (one per neighbour) such that the fitted height is
/// `sum_j weights[j] * (positions[neighbours[j]] - origin) . w` as long as
/// the points keep their frame coordinates `x, y` and distances (the
/// least-squares height is linear in the heights). Neighbours left out of
/// the fit weigh 0; so do all of them when the vertex is fixed. The
/// weights sum to 1 and annul `x` and `y` (the model holds the constant
/// and the linear terms), so a small tilt of the frame leaves the height
/// unchanged. Returns the model used and the fitted height only: a cubic
/// fit then solves for its height alone, as the weights' sum over the
/// heights (the same height up to rounding).
pub fn fit_neighbours_weighted(
    frame: &Frame,
    positions: &[DVec3],
    neighbours: &[u32],
    model: FitModel,
    facing: Option<Facing>,
    weights: &mut [f32],
) -> FitHeight {
    weights.fill(0.0);
    let fit = gather_and_fit(frame, positions, neighbours, model, facing, Some(weights));
    FitHeight {
        kind: fit.kind,
        height: fit.height(),
    }
}

/// The model a fit used and its height: what a smoothing pass needs of it
/// ([`fit_neighbours_weighted`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitHeight {
    /// Model used.
    pub kind: FitKind,
    /// Height of the fitted surface above the vertex, `g`.
    pub height: f64,
}

fn gather_and_fit(
    frame: &Frame,
    positions: &[DVec3],
    neighbours: &[u32],
    model: FitModel,
    facing: Option<Facing>,
    weights: Option<&mut [f32]>,
) -> QuadricFit {
    let neighbours = &neighbours[..neighbours.len().min(MAX_FIT_POINTS)];
    if neighbours.len() < 3 {
        return QuadricFit::FIXED;
    }
    // One gather of the scattered positions, in local coordinates; the
    // moments then run over a small contiguous buffer (on the stack for the
    // usual sizes: zeroing a buffer for the largest case would cost more
    // than a small fit). `source[k]` is the neighbour slot of point `k`.
    let mut stack = [DVec3::ZERO; STACK_POINTS];
    let mut stack_source = [0u16; STACK_POINTS];
    let (mut heap, mut heap_source) = (Vec::new(), Vec::new());
    let (local, source) = if neighbours.len() <= STACK_POINTS {
        (
            &mut stack[..neighbours.len()],
            &mut stack_source[..neighbours.len()],
        )
    } else {
        heap.resize(neighbours.len(), DVec3::ZERO);
        heap_source.resize(neighbours.len(), 0);
        (&mut heap[..], &mut heap_source[..])
    };
    let mut sum_d2 = 0.0;
    let mut kept = 0;
    for (slot, &j) in neighbours.iter().enumerate() {
        if let Some(f) = facing {
            let cos = f.normals[j as usize].as_dvec3().dot(frame.w);
            if cos < f.min_cos || cos.is_nan() {
                continue;
            }
        }
        let d = positions[j as usize] - frame.origin;
        sum_d2 += d.length_squared();
        local[kept] = DVec3::new(frame.u.dot(d), frame.v.dot(d), frame.w.dot(d));
        // Fits a u16: at most MAX_FIT_POINTS slots.
        source[kept] = slot as u16;
        kept += 1;
    }
    if kept < 3 || sum_d2.is_nan() || sum_d2 <= 0.0 {
        return QuadricFit::FIXED;
    }
    let s = (sum_d2 / kept as f64).sqrt();
    let Some(weights) = weights else {
        return fit_points(&local[..kept], s, model, None);
    };
    let mut stack_a = [0.0; STACK_POINTS];
    let mut heap_a = Vec::new();
    let a = if kept <= STACK_POINTS {
        &mut stack_a[..kept]
    } else {
        heap_a.resize(kept, 0.0);
        &mut heap_a[..]
    };
    let fit = fit_points(&local[..kept], s, model, Some(a));
    for (&slot, &ak) in source[..kept].iter().zip(a.iter()) {
        weights[slot as usize] = ak as f32;
    }
    fit
}

/// Fits to points already in local coordinates; `s` is the neighbourhood
/// scale (root mean square distance).
#[cfg(test)]
pub fn fit_local(local: &[DVec3], s: f64) -> QuadricFit {
    fit_points(local, s, FitModel::Quadric, None)
}

/// The weight of a point at squared scaled distance `t = d^2 / s^2`: a
/// rational approximation of the Gaussian `exp(-t / 2)` (its Taylor
/// denominator to third order), as smooth and as local in the range that
/// matters (`t <= 4`) at a fraction of the cost.
#[inline]
pub fn weight(t: f64) -> f64 {
    let h = 0.5 * t;
    1.0 / (1.0 + h * (1.0 + h * (0.5 + h * (1.0 / 6.0))))
}

/// Independent partial sums per moment: each of the four lanes adds every
/// fourth point, and the lanes are added in a fixed order at the end, so the
/// compiler may use vector registers without changing a single bit of the
/// result.
const LANES: usize = 4;

/// Weighted moments, in scaled coordinates, of the points `local / s`. The
/// normal matrix of the monomials `[x^2, xy, y^2, x, y, 1]` only holds 15
/// distinct moments (`x^i y^j`, `i + j <= 4`); the right-hand side 6 more.
fn moments(local: &[DVec3], inv_s: f64) -> ([f64; 15], [f64; 6]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above).
        return unsafe { moments_avx2(local, inv_s) };
    }
    moments_portable(local, inv_s)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn moments_avx2(local: &[DVec3], inv_s: f64) -> ([f64; 15], [f64; 6]) {
    moments_portable(local, inv_s)
}

#[inline(always)]
fn moments_portable(local: &[DVec3], inv_s: f64) -> ([f64; 15], [f64; 6]) {
    let mut acc = [[0.0f64; LANES]; 21];
    for chunk in local.chunks(LANES) {
        let (mut x, mut y, mut z) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
        let mut present = [0.0; LANES];
        for (i, l) in chunk.iter().enumerate() {
            (x[i], y[i], z[i]) = (l.x * inv_s, l.y * inv_s, l.z * inv_s);
            present[i] = 1.0;
        }
        for i in 0..LANES {
            let w = present[i] * weight(x[i] * x[i] + y[i] * y[i] + z[i] * z[i]);
            let (wx, wy) = (w * x[i], w * y[i]);
            let (wxx, wxy, wyy) = (wx * x[i], wx * y[i], wy * y[i]);
            let (wxxx, wxxy, wxyy, wyyy) = (wxx * x[i], wxx * y[i], wxy * y[i], wyy * y[i]);
            let terms = [
                w,
                wx,
                wy,
                wxx,
                wxy,
                wyy,
                wxxx,
                wxxy,
                wxyy,
                wyyy,
                wxxx * x[i],
                wxxx * y[i],
                wxxy * y[i],
                wxyy * y[i],
                wyyy * y[i],
                wxx * z[i],
                wxy * z[i],
                wyy * z[i],
                wx * z[i],
                wy * z[i],
                w * z[i],
            ];
            for (a, t) in acc.iter_mut().zip(terms) {
                a[i] += t;
            }
        }
    }
    let total = |a: &[f64; LANES]| (a[0] + a[1]) + (a[2] + a[3]);
    let mut mo = [0.0; 15];
    let mut rz = [0.0; 6];
    for (m, a) in mo.iter_mut().zip(&acc[..15]) {
        *m = total(a);
    }
    for (r, a) in rz.iter_mut().zip(&acc[15..]) {
        *r = total(a);
    }
    (mo, rz)
}

/// Fits `model` (or a fallback) to `local`; with `weights` (one per
/// point), also writes the fit's linear weights (see
/// [`fit_neighbours_weighted`]), zero when the fit is [`FitKind::Fixed`].
fn fit_points(
    local: &[DVec3],
    s: f64,
    model: FitModel,
    mut weights: Option<&mut [f64]>,
) -> QuadricFit {
    let count = local.len();
    let inv_s = 1.0 / s;
    if model == FitModel::Cubic
        && count >= MIN_CUBIC_POINTS
        && let Some(fit) = fit_cubic(local, s, weights.as_deref_mut())
    {
        return fit;
    }
    let plane_only = model == FitModel::Plane;
    let (mo, rz) = moments(local, inv_s);
    let [
        m1,
        mx,
        my,
        mxx,
        mxy,
        myy,
        mxxx,
        mxxy,
        mxyy,
        myyy,
        m4x,
        m3x1y,
        m2x2y,
        m1x3y,
        m4y,
    ] = mo;
    // Upper triangle, row-wise, of M^T W M for [x^2, xy, y^2, x, y, 1].
    #[rustfmt::skip]
    let ata = [
        m4x, m3x1y, m2x2y, mxxx, mxxy, mxx,
             m2x2y, m1x3y, mxxy, mxyy, mxy,
                    m4y,   mxyy, myyy, myy,
                           mxx,  mxy,  mx,
                                 myy,  my,
                                       m1,
    ];
    let atz = rz;
    if count >= 6
        && !plane_only
        && let Some(ldl) = ldl_factor::<6>(&ata)
        && let Some(beta) = ldl_solve(&ldl, &atz)
        && beta[5].abs() <= 1.0
    {
        if let Some(a) = weights {
            linear_weights(local, inv_s, &CUBIC_BASIS[..6], &ldl, a);
        }
        return QuadricFit::from_scaled(&beta, s, FitKind::Quadric);
    }
    // Plane fallback: the trailing 3x3 block (x, y, 1) of the same system.
    let sub = [ata[15], ata[16], ata[17], ata[18], ata[19], ata[20]];
    let rhs = [atz[3], atz[4], atz[5]];
    if let Some(ldl) = ldl_factor::<3>(&sub)
        && let Some(beta) = ldl_solve(&ldl, &rhs)
        && beta[2].abs() <= 1.0
    {
        if let Some(a) = weights {
            linear_weights(local, inv_s, &CUBIC_BASIS[3..6], &ldl, a);
        }
        return QuadricFit {
            coeffs: [0.0, 0.0, 0.0, beta[0], beta[1], beta[2] * s],
            kind: FitKind::Plane,
        };
    }
    if let Some(a) = weights {
        a.fill(0.0);
    }
    QuadricFit::FIXED
}

/// `M^-1 e` for the factorised normal matrix `ldl` of a basis, `e` selecting
/// its constant term (index 5 of the quadric and cubic bases, 2 of the
/// plane's); `None` if not finite.
fn solve_for_constant<const N: usize>(ldl: &[[f64; N]; N]) -> Option<[f64; N]> {
    let mut e = [0.0; N];
    e[if N == 3 { 2 } else { 5 }] = 1.0;
    ldl_solve(ldl, &e)
}

/// The linear weights of a solved quadric or plane fit: with `ldl` the
/// factorised normal matrix `M` of `basis`, the height is
/// `e^T M^-1 sum_k w_k phi_k z_k`, so point `k` weighs
/// `w_k phi_k . M^-1 e` ([`solve_for_constant`]). The weights are
/// dimensionless: the same in scaled and frame units. (The cubic fit
/// computes its own from the kernel weights its moments left.)
fn linear_weights<const N: usize>(
    local: &[DVec3],
    inv_s: f64,
    basis: &[(usize, usize)],
    ldl: &[[f64; N]; N],
    out: &mut [f64],
) {
    let z = solve_for_constant(ldl).unwrap_or([0.0; N]);
    for (l, a) in local.iter().zip(out.iter_mut()) {
        let (x, y, h) = (l.x * inv_s, l.y * inv_s, l.z * inv_s);
        let w = weight(x * x + y * y + h * h);
        // Powers up to 2, the highest a quadric holds.
        let xp = [1.0, x, x * x];
        let yp = [1.0, y, y * y];
        let phi: f64 = basis
            .iter()
            .zip(&z)
            .map(|(&(i, j), zk)| zk * xp[i] * yp[j])
            .sum();
        *a = w * phi;
    }
}

/// Exponents `(i, j)` of the cubic model's basis `x^i y^j`, in the order of
/// its coefficients: the quadric's six, then the four cubic terms.
const CUBIC_BASIS: [(usize, usize); 10] = [
    (2, 0),
    (1, 1),
    (0, 2),
    (1, 0),
    (0, 1),
    (0, 0),
    (3, 0),
    (2, 1),
    (1, 2),
    (0, 3),
];

/// Index of the moment of `x^i y^j` (`i + j <= 6`) in [`cubic_moments`]'s
/// first array: by total degree, then by the power of `y`.
const fn moment_index(i: usize, j: usize) -> usize {
    let d = i + j;
    d * (d + 1) / 2 + j
}

/// Weighted moments of the cubic fit's normal matrix, `sum w x^i y^j` for
/// `i + j <= 6` (indexed by [`moment_index`]), over scaled points in
/// structure-of-arrays form padded to whole lanes (`ws` is 1 for a point,
/// 0 for padding), in four fixed lanes like [`moments`]. Leaves each
/// point's kernel weight `w` in `ws` (for [`cubic_height_moments`] and the
/// linear weights).
fn cubic_moments(xs: &[f64], ys: &[f64], zs: &[f64], ws: &mut [f64]) -> [f64; 28] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { cubic_moments_avx2(xs, ys, zs, ws) };
    }
    cubic_moments_lanes(xs, ys, zs, ws)
}

/// [`cubic_moments_lanes`] compiled for AVX2 (same operations, same order:
/// identical results).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn cubic_moments_avx2(xs: &[f64], ys: &[f64], zs: &[f64], ws: &mut [f64]) -> [f64; 28] {
    cubic_moments_lanes(xs, ys, zs, ws)
}

/// The cubic fit's right-hand side, `sum w z x^i y^j` for `i + j <= 3`
/// (indexed by [`moment_index`]), with the kernel weights `ws` that
/// [`cubic_moments`] left, in the same four lanes.
fn cubic_height_moments(xs: &[f64], ys: &[f64], zs: &[f64], ws: &[f64]) -> [f64; 10] {
    let mut acc_z = [[0.0f64; LANES]; 10];
    for (((x, y), z), ws) in xs
        .chunks_exact(LANES)
        .zip(ys.chunks_exact(LANES))
        .zip(zs.chunks_exact(LANES))
        .zip(ws.chunks_exact(LANES))
    {
        let (x, y, z, w) = (lanes(x), lanes(y), lanes(z), lanes(ws));
        let (wx, yp) = powers::<4>(w, x, y);
        add(&mut acc_z[0], mul(mul(wx[0], yp[0]), z));
        add(&mut acc_z[1], mul(mul(wx[1], yp[0]), z));
        add(&mut acc_z[2], mul(mul(wx[0], yp[1]), z));
        add(&mut acc_z[3], mul(mul(wx[2], yp[0]), z));
        add(&mut acc_z[4], mul(mul(wx[1], yp[1]), z));
        add(&mut acc_z[5], mul(mul(wx[0], yp[2]), z));
        add(&mut acc_z[6], mul(mul(wx[3], yp[0]), z));
        add(&mut acc_z[7], mul(mul(wx[2], yp[1]), z));
        add(&mut acc_z[8], mul(mul(wx[1], yp[2]), z));
        add(&mut acc_z[9], mul(mul(wx[0], yp[3]), z));
    }
    acc_z.map(|a| (a[0] + a[1]) + (a[2] + a[3]))
}

/// Four lanes of one quantity.
type Lanes = [f64; LANES];

#[inline(always)]
fn mul(a: Lanes, b: Lanes) -> Lanes {
    [a[0] * b[0], a[1] * b[1], a[2] * b[2], a[3] * b[3]]
}

#[inline(always)]
fn add(acc: &mut Lanes, a: Lanes) {
    for (s, v) in acc.iter_mut().zip(a) {
        *s += v;
    }
}

#[inline(always)]
fn lanes(a: &[f64]) -> Lanes {
    [a[0], a[1], a[2], a[3]]
}

/// `w x^q` and `y^q` for `q < N`, lane by lane, each power one product
/// from the one before (the order every moment sweep uses).
#[inline(always)]
fn powers<const N: usize>(w: Lanes, x: Lanes, y: Lanes) -> ([Lanes; N], [Lanes; N]) {
    let mut wx = [[0.0; LANES]; N];
    let mut yp = [[0.0; LANES]; N];
    wx[0] = w;
    yp[0] = [1.0; LANES];
    for q in 1..N {
        wx[q] = mul(wx[q - 1], x);
        yp[q] = mul(yp[q - 1], y);
    }
    (wx, yp)
}

/// The moments over padded coordinate arrays (see [`cubic_moments`]);
/// every line of the loop is one vector operation.
#[inline(always)]
fn cubic_moments_lanes(xs: &[f64], ys: &[f64], zs: &[f64], ws: &mut [f64]) -> [f64; 28] {
    let mut acc = [[0.0f64; LANES]; 28];
    // Three sweeps over the (small, cached) points, each with few enough
    // sums to stay in vector registers: the kernel weights and the moments
    // of degree up to 3, then degrees 4 and 5, then degree 6. Each sum
    // still adds its points in order. The terms are written out: a loop
    // over `moment_index` is not unrolled and made these moments 65%
    // slower.
    for (((x, y), z), ws) in xs
        .chunks_exact(LANES)
        .zip(ys.chunks_exact(LANES))
        .zip(zs.chunks_exact(LANES))
        .zip(ws.chunks_exact_mut(LANES))
    {
        let (x, y, z, p) = (lanes(x), lanes(y), lanes(z), lanes(ws));
        let mut w = [0.0; LANES];
        for i in 0..LANES {
            let t = CUBIC_KERNEL * (x[i] * x[i] + y[i] * y[i] + z[i] * z[i]);
            w[i] = p[i] * weight(t);
        }
        ws.copy_from_slice(&w);
        let (wx1, y1) = (mul(w, x), y);
        let (wx2, y2) = (mul(wx1, x), mul(y1, y));
        let (wx3, y3) = (mul(wx2, x), mul(y2, y));
        let one = [1.0; LANES];
        add(&mut acc[0], mul(w, one));
        add(&mut acc[1], mul(wx1, one));
        add(&mut acc[2], mul(w, y1));
        add(&mut acc[3], mul(wx2, one));
        add(&mut acc[4], mul(wx1, y1));
        add(&mut acc[5], mul(w, y2));
        add(&mut acc[6], mul(wx3, one));
        add(&mut acc[7], mul(wx2, y1));
        add(&mut acc[8], mul(wx1, y2));
        add(&mut acc[9], mul(w, y3));
    }
    for ((x, y), ws) in xs
        .chunks_exact(LANES)
        .zip(ys.chunks_exact(LANES))
        .zip(ws.chunks_exact(LANES))
    {
        let (x, y, w) = (lanes(x), lanes(y), lanes(ws));
        let (wx, yp) = powers::<6>(w, x, y);
        add(&mut acc[10], mul(wx[4], yp[0]));
        add(&mut acc[11], mul(wx[3], yp[1]));
        add(&mut acc[12], mul(wx[2], yp[2]));
        add(&mut acc[13], mul(wx[1], yp[3]));
        add(&mut acc[14], mul(wx[0], yp[4]));
        add(&mut acc[15], mul(wx[5], yp[0]));
        add(&mut acc[16], mul(wx[4], yp[1]));
        add(&mut acc[17], mul(wx[3], yp[2]));
        add(&mut acc[18], mul(wx[2], yp[3]));
        add(&mut acc[19], mul(wx[1], yp[4]));
        add(&mut acc[20], mul(wx[0], yp[5]));
    }
    for ((x, y), ws) in xs
        .chunks_exact(LANES)
        .zip(ys.chunks_exact(LANES))
        .zip(ws.chunks_exact(LANES))
    {
        let (x, y, w) = (lanes(x), lanes(y), lanes(ws));
        let (wx, yp) = powers::<7>(w, x, y);
        add(&mut acc[21], mul(wx[6], yp[0]));
        add(&mut acc[22], mul(wx[5], yp[1]));
        add(&mut acc[23], mul(wx[4], yp[2]));
        add(&mut acc[24], mul(wx[3], yp[3]));
        add(&mut acc[25], mul(wx[2], yp[4]));
        add(&mut acc[26], mul(wx[1], yp[5]));
        add(&mut acc[27], mul(wx[0], yp[6]));
    }
    acc.map(|a| (a[0] + a[1]) + (a[2] + a[3]))
}

/// The cubic model's fit (coordinates scaled by `1 / s`), or `None`
/// when its equations are singular or its height is a spike (the caller
/// falls back to the quadric).
fn fit_cubic(local: &[DVec3], s: f64, weights: Option<&mut [f64]>) -> Option<QuadricFit> {
    // Coordinates one array each (structure of arrays), padded to whole
    // lanes with points of weight 0: the moments are then plain vector
    // arithmetic, with no shuffles and no partial chunk.
    let n = local.len();
    let padded = n.div_ceil(LANES) * LANES;
    let mut stack = [[0.0f64; STACK_POINTS]; 4];
    let mut heap = Vec::new();
    let [xs, ys, zs, ws] = if padded <= STACK_POINTS {
        stack.each_mut().map(|a| &mut a[..padded])
    } else {
        heap.resize(4 * padded, 0.0);
        let (a, rest) = heap.split_at_mut(padded);
        let (b, rest) = rest.split_at_mut(padded);
        let (c, d) = rest.split_at_mut(padded);
        [a, b, c, d]
    };
    let inv_s = 1.0 / s;
    for (i, l) in local.iter().enumerate() {
        (xs[i], ys[i], zs[i]) = (l.x * inv_s, l.y * inv_s, l.z * inv_s);
        ws[i] = 1.0;
    }
    let mo = cubic_moments(xs, ys, zs, ws);
    let mut ata = [0.0; 55];
    let mut k = 0;
    for (r, &(ri, rj)) in CUBIC_BASIS.iter().enumerate() {
        for &(ci, cj) in &CUBIC_BASIS[r..] {
            ata[k] = mo[moment_index(ri + ci, rj + cj)];
            k += 1;
        }
    }
    let ldl = ldl_factor::<10>(&ata)?;
    let Some(a) = weights else {
        let rz = cubic_height_moments(xs, ys, zs, ws);
        let atz = CUBIC_BASIS.map(|(i, j)| rz[moment_index(i, j)]);
        let beta = ldl_solve(&ldl, &atz)?;
        if beta[5].abs() > 1.0 {
            return None;
        }
        return Some(QuadricFit::from_scaled(&beta, s, FitKind::Cubic));
    };
    // With the linear weights only the height is wanted, and it is their
    // sum over the heights: no right-hand side, one solve instead of two.
    // The weights as `linear_weights` makes them, with the kernel weights
    // the moments left.
    let z = solve_for_constant(&ldl)?;
    let g = cubic_linear_weights(xs, ys, zs, ws, &z);
    a.copy_from_slice(&ws[..a.len()]);
    if g.is_nan() || g.abs() > 1.0 {
        return None;
    }
    Some(QuadricFit::height_only(g * s, FitKind::Cubic))
}

/// Replaces the kernel weights `ws` (padded like [`cubic_moments`]'s
/// points, 0 for padding) by the cubic fit's linear weights
/// `w_k phi_k . M^-1 e` (as `linear_weights` makes them, `z = M^-1 e`), and
/// returns the height they give, their sum over the heights `zs`, added in
/// four fixed lanes.
fn cubic_linear_weights(xs: &[f64], ys: &[f64], zs: &[f64], ws: &mut [f64], z: &[f64; 10]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { cubic_linear_weights_avx2(xs, ys, zs, ws, z) };
    }
    cubic_linear_weights_lanes(xs, ys, zs, ws, z)
}

/// [`cubic_linear_weights_lanes`] compiled for AVX2 (same operations, same
/// order: identical results).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn cubic_linear_weights_avx2(
    xs: &[f64],
    ys: &[f64],
    zs: &[f64],
    ws: &mut [f64],
    z: &[f64; 10],
) -> f64 {
    cubic_linear_weights_lanes(xs, ys, zs, ws, z)
}

#[inline(always)]
fn cubic_linear_weights_lanes(
    xs: &[f64],
    ys: &[f64],
    zs: &[f64],
    ws: &mut [f64],
    z: &[f64; 10],
) -> f64 {
    let mut g = [0.0f64; LANES];
    for (((x, y), h), ws) in xs
        .chunks_exact(LANES)
        .zip(ys.chunks_exact(LANES))
        .zip(zs.chunks_exact(LANES))
        .zip(ws.chunks_exact_mut(LANES))
    {
        for i in 0..LANES {
            let (x, y) = (x[i], y[i]);
            let (xx, yy) = (x * x, y * y);
            let phi = z[0] * xx
                + z[1] * x * y
                + z[2] * yy
                + z[3] * x
                + z[4] * y
                + z[5]
                + z[6] * xx * x
                + z[7] * xx * y
                + z[8] * x * yy
                + z[9] * yy * y;
            ws[i] *= phi;
            g[i] += ws[i] * h[i];
        }
    }
    (g[0] + g[1]) + (g[2] + g[3])
}

/// Solves the symmetric system whose upper triangle is packed row-wise in
/// `a` ([`ldl_factor`], [`ldl_solve`]).
#[cfg(test)]
fn solve_packed<const N: usize>(a: &[f64], b: &[f64; N]) -> Option<[f64; N]> {
    ldl_solve(&ldl_factor::<N>(a)?, b)
}

/// Factorises the symmetric matrix whose upper triangle is packed row-wise
/// in `a` as L D L^T without pivoting (L strictly below the diagonal, D on
/// it); `None` when a pivot is below [`MIN_RELATIVE_PIVOT`] times the
/// largest diagonal entry or not finite.
#[allow(clippy::needless_range_loop)] // index arithmetic mirrors the maths
fn ldl_factor<const N: usize>(a: &[f64]) -> Option<[[f64; N]; N]> {
    // Unpack into a full matrix (small and on the stack).
    let mut m = [[0.0f64; N]; N];
    let mut k = 0;
    for i in 0..N {
        for j in i..N {
            m[i][j] = a[k];
            m[j][i] = a[k];
            k += 1;
        }
    }
    let max_diag = (0..N).map(|i| m[i][i]).fold(0.0f64, f64::max);
    if max_diag.is_nan() || max_diag <= 0.0 || !max_diag.is_finite() {
        return None;
    }
    let tol = MIN_RELATIVE_PIVOT * max_diag;
    for j in 0..N {
        let mut d = m[j][j];
        for p in 0..j {
            d -= m[j][p] * m[j][p] * m[p][p];
        }
        if d.is_nan() || d <= tol {
            return None;
        }
        m[j][j] = d;
        for i in j + 1..N {
            let mut s = m[i][j];
            for p in 0..j {
                s -= m[i][p] * m[j][p] * m[p][p];
            }
            m[i][j] = s / d;
        }
    }
    Some(m)
}

/// Solves `L D L^T x = b` with a factorisation from [`ldl_factor`]; `None`
/// when the solution is not finite.
#[allow(clippy::needless_range_loop)] // index arithmetic mirrors the maths
fn ldl_solve<const N: usize>(m: &[[f64; N]; N], b: &[f64; N]) -> Option<[f64; N]> {
    let mut x = *b;
    for i in 0..N {
        for p in 0..i {
            x[i] -= m[i][p] * x[p];
        }
    }
    for i in 0..N {
        x[i] /= m[i][i];
    }
    for i in (0..N).rev() {
        for p in i + 1..N {
            x[i] -= m[p][i] * x[p];
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_points(h: impl Fn(f64, f64) -> f64) -> Vec<DVec3> {
        let mut pts = Vec::new();
        for j in -2i32..=2 {
            for i in -2i32..=2 {
                if i != 0 || j != 0 {
                    let (x, y) = (i as f64 * 0.7, j as f64 * 0.7);
                    pts.push(DVec3::new(x, y, h(x, y)));
                }
            }
        }
        pts
    }

    /// Deterministic pseudo-random numbers in `[-0.5, 0.5)` (xorshift).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut x = seed;
        move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    #[test]
    fn recovers_an_exact_quadric() {
        let q =
            |x: f64, y: f64| 0.3 * x * x - 0.2 * x * y + 0.1 * y * y + 0.05 * x - 0.07 * y + 0.4;
        let pts = grid_points(q);
        let s = (pts.iter().map(|p| p.length_squared()).sum::<f64>() / pts.len() as f64).sqrt();
        let fit = fit_local(&pts, s);
        assert_eq!(fit.kind, FitKind::Quadric);
        let want = [0.3, -0.2, 0.1, 0.05, -0.07, 0.4];
        for (got, want) in fit.coeffs.iter().zip(want) {
            assert!((got - want).abs() < 1e-10, "{:?}", fit.coeffs);
        }
    }

    #[test]
    fn sphere_cap_curvature_matches_radius() {
        // Points on a sphere of radius 10 below the tangent plane at the top.
        let r = 10.0;
        let pts = grid_points(|x, y| (r * r - x * x - y * y).sqrt() - r);
        let s = (pts.iter().map(|p| p.length_squared()).sum::<f64>() / pts.len() as f64).sqrt();
        let fit = fit_local(&pts, s);
        let (h, k) = fit.curvature();
        assert!((h + 1.0 / r).abs() < 2e-3, "H = {h}");
        assert!((k - 1.0 / (r * r)).abs() < 5e-4, "K = {k}");
    }

    #[test]
    fn collinear_points_fall_back_without_nan() {
        let pts: Vec<DVec3> = (1..8)
            .map(|i| DVec3::new(i as f64, 0.0, 0.1 * i as f64))
            .collect();
        let fit = fit_local(&pts, 3.0);
        assert_ne!(fit.kind, FitKind::Quadric);
        assert!(fit.coeffs.iter().all(|c| c.is_finite()));
        let two = [DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, 1.0, 0.0)];
        assert_eq!(fit_local(&two, 1.0).kind, FitKind::Fixed);
    }

    #[test]
    fn spike_does_not_jump() {
        // A vertex far above a flat ring: the fitted height must stay within
        // the neighbourhood scale.
        let pts = grid_points(|_, _| -50.0);
        let s = (pts.iter().map(|p| p.length_squared()).sum::<f64>() / pts.len() as f64).sqrt();
        let fit = fit_local(&pts, s);
        assert!(fit.height().abs() <= s + 1e-9);
    }

    #[test]
    fn vector_and_portable_moments_agree_to_the_bit() {
        // Deterministic pseudo-random points, counts not a multiple of the
        // lane width included.
        let mut next = uniform(0x9e37_79b9_7f4a_7c15);
        for n in [1usize, 5, 12, 40, 41, 130] {
            let pts: Vec<DVec3> = (0..n)
                .map(|_| DVec3::new(3.0 * next(), 3.0 * next(), 0.3 * next()))
                .collect();
            let a = moments(&pts, 0.7);
            let b = moments_portable(&pts, 0.7);
            let bits = |m: &([f64; 15], [f64; 6])| -> Vec<u64> {
                m.0.iter().chain(&m.1).map(|v| v.to_bits()).collect()
            };
            assert_eq!(bits(&a), bits(&b), "{n} points");
        }
    }

    #[test]
    fn cubic_model_removes_the_height_bias_of_a_one_sided_neighbourhood() {
        // A surface whose curvature changes along x, sampled on a grid
        // shifted to one side of the vertex (as ring neighbourhoods are
        // where the mesh is uneven): the quadric turns the cubic term into
        // a height error, the cubic model recovers the surface exactly.
        let h =
            |x: f64, y: f64| 0.2 * x * x + 0.1 * y * y + 0.03 * x * x * x - 0.02 * x * y * y + 0.5;
        let mut pts = Vec::new();
        for j in -2i32..=2 {
            for i in -1i32..=3 {
                if i != 0 || j != 0 {
                    let (x, y) = (i as f64 * 0.7, j as f64 * 0.7);
                    pts.push(DVec3::new(x, y, h(x, y)));
                }
            }
        }
        let frame = Frame::new(DVec3::ZERO, DVec3::Z);
        let ids: Vec<u32> = (0..pts.len() as u32).collect();
        let cubic = fit_neighbours(&frame, &pts, &ids, FitModel::Cubic, None);
        let quadric = fit_neighbours(&frame, &pts, &ids, FitModel::Quadric, None);
        assert_eq!(cubic.kind, FitKind::Cubic);
        assert_eq!(quadric.kind, FitKind::Quadric);
        assert!((cubic.height() - 0.5).abs() < 1e-9, "{:?}", cubic.coeffs);
        let (hm, k) = cubic.curvature();
        assert!(
            (hm - 0.3).abs() < 1e-9 && (k - 0.08).abs() < 1e-9,
            "{hm} {k}"
        );
        assert!(
            (quadric.height() - 0.5).abs() > 1e-3,
            "the quadric should be biased here: {}",
            quadric.height()
        );
    }

    #[test]
    fn cubic_model_needs_enough_points() {
        let pts: Vec<DVec3> = (0..MIN_CUBIC_POINTS - 1)
            .map(|i| {
                let a = i as f64;
                DVec3::new(
                    a.cos() * (1.0 + 0.1 * a),
                    a.sin() * (1.0 + 0.1 * a),
                    0.1 * a.cos(),
                )
            })
            .collect();
        let frame = Frame::new(DVec3::ZERO, DVec3::Z);
        let ids: Vec<u32> = (0..pts.len() as u32).collect();
        let fit = fit_neighbours(&frame, &pts, &ids, FitModel::Cubic, None);
        assert_eq!(fit.kind, FitKind::Quadric);
    }

    #[test]
    fn linear_weights_give_the_fitted_height_and_ignore_a_tilt() {
        // A bumpy, tilted patch around a vertex at the origin, with two
        // neighbours facing away (left out of the fit, weight 0).
        let mut next = uniform(0x9e37_79b9_7f4a_7c15);
        let mut pts: Vec<DVec3> = (0..40)
            .map(|_| {
                let (x, y) = (3.0 * next(), 3.0 * next());
                DVec3::new(x, y, 0.2 * x - 0.1 * y + 0.3 * x * x + 0.05 * next())
            })
            .collect();
        pts.push(DVec3::new(0.4, 0.1, -0.3));
        pts.push(DVec3::new(-0.2, 0.5, -0.2));
        let mut normals = vec![glam::Vec3::Z; pts.len()];
        normals[40] = -glam::Vec3::Z;
        normals[41] = -glam::Vec3::Z;
        let facing = Facing {
            normals: &normals,
            min_cos: 0.0,
        };
        let frame = Frame::new(DVec3::ZERO, DVec3::Z);
        let ids: Vec<u32> = (0..pts.len() as u32).collect();
        let mut w = vec![1.0f32; pts.len()];
        for (model, kind) in [
            (FitModel::Cubic, FitKind::Cubic),
            (FitModel::Quadric, FitKind::Quadric),
            (FitModel::Plane, FitKind::Plane),
        ] {
            let fit = fit_neighbours_weighted(&frame, &pts, &ids, model, Some(facing), &mut w);
            let plain = fit_neighbours(&frame, &pts, &ids, model, Some(facing));
            assert_eq!(fit.kind, kind);
            assert_eq!(plain.kind, kind);
            assert!(
                (fit.height - plain.height()).abs() <= 1e-12,
                "{kind:?}: {} vs {}",
                fit.height,
                plain.height()
            );
            let a: Vec<f64> = w.iter().map(|&x| f64::from(x)).collect();
            assert_eq!((a[40], a[41]), (0.0, 0.0), "{kind:?}: left-out points");
            let height: f64 = a.iter().zip(&pts).map(|(a, p)| a * p.z).sum();
            // Single-precision weights.
            assert!(
                (height - fit.height).abs() < 1e-5,
                "{kind:?}: {height} vs {}",
                fit.height
            );
            let sum: f64 = a.iter().sum();
            let (mx, my): (f64, f64) = (
                a.iter().zip(&pts).map(|(a, p)| a * p.x).sum(),
                a.iter().zip(&pts).map(|(a, p)| a * p.y).sum(),
            );
            assert!((sum - 1.0).abs() < 1e-5, "{kind:?}: weights sum to {sum}");
            assert!(mx.abs() < 1e-5 && my.abs() < 1e-5, "{kind:?}: {mx} {my}");
        }
        // No usable fit: every weight 0.
        let fit =
            fit_neighbours_weighted(&frame, &pts, &ids[..2], FitModel::Cubic, None, &mut w[..2]);
        assert_eq!(fit.kind, FitKind::Fixed);
        assert!(w[..2].iter().all(|&x| x == 0.0));
    }

    #[test]
    fn vector_and_portable_cubic_moments_agree_to_the_bit() {
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        for n in [4usize, 16, 56, 64, 132] {
            let mut cols = [vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![1.0; n]];
            for (col, scale) in cols.iter_mut().zip([3.0, 3.0, 0.3]) {
                col.iter_mut().for_each(|c| *c = scale * next());
            }
            cols[3][n - 1] = 0.0;
            let [xs, ys, zs, present] = &cols;
            let mut ws_a = present.clone();
            let a = cubic_moments_lanes(xs, ys, zs, &mut ws_a);
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut ws_b = present.clone();
                // SAFETY: AVX2 is present (checked just above).
                let b = unsafe { cubic_moments_avx2(xs, ys, zs, &mut ws_b) };
                assert_eq!(ws_a, ws_b, "{n} points: kernel weights");
                let bits = |m: &[f64; 28]| -> Vec<u64> { m.iter().map(|v| v.to_bits()).collect() };
                assert_eq!(bits(&a), bits(&b), "{n} points");
            }
            assert!(a.iter().all(|v| v.is_finite()));
            assert!(
                cubic_height_moments(xs, ys, zs, &ws_a)
                    .iter()
                    .all(|v| v.is_finite())
            );
        }
    }

    #[test]
    fn ldl_matches_direct_solution() {
        let a = [4.0, 1.0, 0.5, 3.0, 0.2, 2.0];
        let x = solve_packed::<3>(&a, &[1.0, 2.0, 3.0]).unwrap();
        let m = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        for i in 0..3 {
            let r: f64 = (0..3).map(|j| m[i][j] * x[j]).sum();
            assert!((r - [1.0, 2.0, 3.0][i]).abs() < 1e-12);
        }
    }
}
