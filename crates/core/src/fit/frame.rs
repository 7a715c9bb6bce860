//! Step 2: the local frame at a vertex (algorithm notes section 2).
//!
//! Origin `p_i`, `w = n_i`, `u` a unit vector orthogonal to `w`, `v = w x u`.

use glam::DVec3;

/// An orthonormal frame `(u, v, w)` at `origin`, `w` the vertex normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// The vertex position.
    pub origin: DVec3,
    /// First tangent.
    pub u: DVec3,
    /// Second tangent, `w x u`.
    pub v: DVec3,
    /// The unit normal.
    pub w: DVec3,
}

impl Frame {
    /// Frame at `origin` with unit normal `normal` (must be unit length).
    /// The tangent choice is deterministic (glam's `any_orthonormal_pair`).
    #[inline]
    pub fn new(origin: DVec3, normal: DVec3) -> Frame {
        let (u, _) = normal.any_orthonormal_pair();
        let v = normal.cross(u);
        Frame {
            origin,
            u,
            v,
            w: normal,
        }
    }

    /// Local coordinates `(x, y, z)` of world point `q`.
    #[inline]
    pub fn to_local(self, q: DVec3) -> DVec3 {
        let d = q - self.origin;
        DVec3::new(self.u.dot(d), self.v.dot(d), self.w.dot(d))
    }

    /// World point of local coordinates `l`.
    #[inline]
    pub fn to_world(self, l: DVec3) -> DVec3 {
        self.origin + l.x * self.u + l.y * self.v + l.z * self.w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_and_round_trips() {
        let n = DVec3::new(1.0, 2.0, -0.5).normalize();
        let f = Frame::new(DVec3::new(3.0, 1.0, 2.0), n);
        assert!(
            f.u.dot(f.w).abs() < 1e-14 && f.v.dot(f.w).abs() < 1e-14 && f.u.dot(f.v).abs() < 1e-14
        );
        assert!((f.u.cross(f.v) - f.w).length() < 1e-14, "right-handed");
        let q = DVec3::new(-1.0, 0.5, 7.0);
        assert!((f.to_world(f.to_local(q)) - q).length() < 1e-12);
    }
}
