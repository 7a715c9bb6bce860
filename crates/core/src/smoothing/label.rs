//! Step 6: the four-type labelling of the paper's Table 2 (algorithm notes
//! section 6), with tolerances made scale-free by the mean edge length `l`.

use serde::Serialize;

/// Surface type of a vertex.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum Label {
    /// `|H| l <= t_H` and `|K| l^2 <= t_K`.
    Flat = 0,
    /// `|H| l <= t_H` and `K l^2 < -t_K` (saddle-like).
    Minimal = 1,
    /// `H l < -t_H` (outward normals: a sphere is convex).
    Convex = 2,
    /// `H l > t_H`.
    Concave = 3,
}

impl Label {
    /// All labels, in code order.
    pub const ALL: [Label; 4] = [Label::Flat, Label::Minimal, Label::Convex, Label::Concave];
}

/// Labels a vertex from its curvature `(h, k)`, the mean edge length `l` and
/// the tolerances `t_h`, `t_k`. When `|H| l <= t_H` but `K l^2 > t_K` (only
/// possible if `t_K < t_H^2`, since `H^2 >= K`), the sign of `H` decides.
pub fn label(h: f64, k: f64, l: f64, t_h: f64, t_k: f64) -> Label {
    let hl = h * l;
    let kl = k * l * l;
    if hl.abs() <= t_h {
        if kl.abs() <= t_k {
            return Label::Flat;
        }
        if kl < -t_k {
            return Label::Minimal;
        }
    }
    if hl < 0.0 {
        Label::Convex
    } else {
        Label::Concave
    }
}

/// Whether a vertex with curvature `(h, k)` is compatible with label `of`:
/// it lies inside `of`'s region of Table 2 widened by `margin` on `H l` (and
/// by `margin * t_k / t_h` on `K l^2`). With `margin = 0` this is exactly
/// `label(h, k, l, t_h, t_k) == of`, the paper's test; a margin keeps
/// estimation noise near a tolerance from splitting a smooth region.
pub fn agrees(of: Label, h: f64, k: f64, l: f64, t_h: f64, t_k: f64, margin: f64) -> bool {
    if margin <= 0.0 {
        return label(h, k, l, t_h, t_k) == of;
    }
    let hl = h * l;
    let kl = k * l * l;
    let mk = if t_h > 0.0 {
        margin * t_k / t_h
    } else {
        margin
    };
    match of {
        Label::Flat => hl.abs() <= t_h + margin && kl.abs() <= t_k + mk,
        Label::Minimal => hl.abs() <= t_h + margin && kl < -t_k + mk,
        Label::Convex => hl < -t_h + margin,
        Label::Concave => hl > t_h - margin,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_2_cases() {
        let (th, tk) = (0.02, 0.0005);
        assert_eq!(label(0.0, 0.0, 1.0, th, tk), Label::Flat);
        assert_eq!(label(0.001, -0.01, 1.0, th, tk), Label::Minimal);
        assert_eq!(label(-1.0 / 12.0, 1.0 / 144.0, 1.0, th, tk), Label::Convex);
        assert_eq!(label(0.1, 0.01, 1.0, th, tk), Label::Concave);
        // Scale-free: the same sphere in millimetres with 0.5 mm edges.
        assert_eq!(label(-1.0 / 6.0, 1.0 / 36.0, 0.5, th, tk), Label::Convex);
    }
}
