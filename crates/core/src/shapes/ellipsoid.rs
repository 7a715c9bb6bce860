//! Exact point-to-ellipsoid distance by Eberly's robust 1-D root finding
//! ("Distance from a point to an ellipse, an ellipsoid, or a
//! hyperellipsoid", Geometric Tools, 2013): the closest point is
//! `x_i = e_i^2 y_i / (t + e_i^2)` where `t` is the unique root of
//! `F(t) = sum (e_i y_i / (t + e_i^2))^2 - 1` on `t > -e_min^2`, bracketed
//! and bisected in scaled variables down to adjacent doubles.

use glam::DVec3;

/// Closest point on the ellipsoid with semi-axes `e` (all > 0), centred at
/// the origin and aligned with the axes, to `y`.
pub(super) fn closest_point(e: DVec3, y: DVec3) -> DVec3 {
    // Work in the first octant with the axes sorted by decreasing length.
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| e[b].total_cmp(&e[a]));
    let es = [e[order[0]], e[order[1]], e[order[2]]];
    let ys = [y[order[0]].abs(), y[order[1]].abs(), y[order[2]].abs()];
    let xs = closest_sorted(es, ys);
    let mut x = DVec3::ZERO;
    for (slot, &axis) in order.iter().enumerate() {
        x[axis] = xs[slot].copysign(y[axis]);
    }
    x
}

/// Eberly's `DistancePointEllipsoid` for `e0 >= e1 >= e2 > 0` and `y >= 0`.
fn closest_sorted(e: [f64; 3], y: [f64; 3]) -> [f64; 3] {
    let [e0, e1, e2] = e;
    let [y0, y1, y2] = y;
    if y2 > 0.0 {
        if y1 > 0.0 {
            if y0 > 0.0 {
                let z = [y0 / e0, y1 / e1, y2 / e2];
                let g = z[0] * z[0] + z[1] * z[1] + z[2] * z[2] - 1.0;
                if g == 0.0 {
                    return y;
                }
                let r = [(e0 / e2) * (e0 / e2), (e1 / e2) * (e1 / e2), 1.0];
                let s = root(&r, &z, g);
                [
                    r[0] * y0 / (s + r[0]),
                    r[1] * y1 / (s + r[1]),
                    y2 / (s + 1.0),
                ]
            } else {
                let [x1, x2] = closest_ellipse([e1, e2], [y1, y2]);
                [0.0, x1, x2]
            }
        } else if y0 > 0.0 {
            let [x0, x2] = closest_ellipse([e0, e2], [y0, y2]);
            [x0, 0.0, x2]
        } else {
            [0.0, 0.0, e2]
        }
    } else {
        // y2 == 0: the closest point leaves the plane z = 0 only when y lies
        // inside the ellipse of centres of curvature (the evolute region).
        let denom0 = e0 * e0 - e2 * e2;
        let denom1 = e1 * e1 - e2 * e2;
        let numer0 = e0 * y0;
        let numer1 = e1 * y1;
        if numer0 < denom0 && numer1 < denom1 {
            let xde0 = numer0 / denom0;
            let xde1 = numer1 / denom1;
            let discr = 1.0 - xde0 * xde0 - xde1 * xde1;
            if discr > 0.0 {
                return [e0 * xde0, e1 * xde1, e2 * discr.sqrt()];
            }
        }
        let [x0, x1] = closest_ellipse([e0, e1], [y0, y1]);
        [x0, x1, 0.0]
    }
}

/// Eberly's `DistancePointEllipse` for `e0 >= e1 > 0` and `y >= 0`.
fn closest_ellipse(e: [f64; 2], y: [f64; 2]) -> [f64; 2] {
    let [e0, e1] = e;
    let [y0, y1] = y;
    if y1 > 0.0 {
        if y0 > 0.0 {
            let z = [y0 / e0, y1 / e1];
            let g = z[0] * z[0] + z[1] * z[1] - 1.0;
            if g == 0.0 {
                return y;
            }
            let r = [(e0 / e1) * (e0 / e1), 1.0];
            let s = root(&r, &z, g);
            [r[0] * y0 / (s + r[0]), y1 / (s + 1.0)]
        } else {
            [0.0, e1]
        }
    } else {
        let numer0 = e0 * y0;
        let denom0 = e0 * e0 - e1 * e1;
        if numer0 < denom0 {
            let xde0 = numer0 / denom0;
            [e0 * xde0, e1 * (1.0 - xde0 * xde0).max(0.0).sqrt()]
        } else {
            [e0, 0.0]
        }
    }
}

/// Root `s` of `sum (r_i z_i / (s + r_i))^2 = 1` by bisection, where the
/// last ratio is 1 (axes scaled by the smallest), `z_i = y_i / e_i > 0` and
/// `g` is the sign indicator `sum z_i^2 - 1`. Bisection stops when the
/// midpoint equals an end point: at most about 1100 steps, typically ~60.
fn root<const N: usize>(r: &[f64; N], z: &[f64; N], g: f64) -> f64 {
    let mut n = [0.0; N];
    for i in 0..N {
        n[i] = r[i] * z[i];
    }
    let last = z[N - 1];
    let mut s0 = last - 1.0;
    let mut s1 = if g < 0.0 {
        0.0
    } else {
        robust_length(&n) - 1.0
    };
    let mut s = 0.0;
    for _ in 0..2200 {
        s = 0.5 * (s0 + s1);
        if s == s0 || s == s1 {
            break;
        }
        let mut f = -1.0;
        for i in 0..N {
            let q = n[i] / (s + r[i]);
            f += q * q;
        }
        if f > 0.0 {
            s0 = s;
        } else if f < 0.0 {
            s1 = s;
        } else {
            break;
        }
    }
    s
}

/// Euclidean length without overflow or underflow.
fn robust_length<const N: usize>(v: &[f64; N]) -> f64 {
    let m = v.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
    if m == 0.0 {
        return 0.0;
    }
    let sum: f64 = v.iter().map(|&x| (x / m) * (x / m)).sum();
    m * sum.sqrt()
}
