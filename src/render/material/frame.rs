//! Orthonormal shading frames: BSDFs work in a local frame where the shading normal is +z.

use glam::Vec3;

/// An orthonormal frame around a unit normal, mapping world directions to the BSDF's local
/// frame (`n` becomes +z) and back.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// First tangent (local +x).
    pub t: Vec3,
    /// Second tangent (local +y).
    pub b: Vec3,
    /// Normal (local +z).
    pub n: Vec3,
}

impl Frame {
    /// Builds a frame around unit `n` with the branchless construction of Duff et al. 2017
    /// ("Building an Orthonormal Basis, Revisited"): continuous except across the xy-plane
    /// seam and exact for `n = ±z`, including `n.z = -0.0` (the sign comes from `copysign`).
    pub fn from_normal(n: Vec3) -> Frame {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        Frame {
            t: Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            b: Vec3::new(b, sign + n.y * n.y * a, -n.y),
            n,
        }
    }

    /// The frame about the same normal whose first tangent is `t` projected into the tangent
    /// plane (`None` when `t` is not finite or nearly along the normal).
    pub fn with_tangent(&self, t: Vec3) -> Option<Frame> {
        let projected = t - self.n * self.n.dot(t);
        if projected.length_squared() <= 1e-8 * t.length_squared() {
            return None;
        }
        // Non-finite: `None` here.
        let t = projected.try_normalize()?;
        Some(Frame { t, b: self.n.cross(t), n: self.n })
    }

    /// World direction -> local coordinates.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }

    /// Local coordinates -> world direction.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(n: Vec3) {
        let f = Frame::from_normal(n);
        for (name, v) in [("t", f.t), ("b", f.b), ("n", f.n)] {
            assert!((v.length() - 1.0).abs() < 1e-5, "{name} not unit for n = {n}: {v}");
        }
        assert!(f.t.dot(f.b).abs() < 1e-5 && f.t.dot(f.n).abs() < 1e-5 && f.b.dot(f.n).abs() < 1e-5, "n = {n}");
        // Right-handed, so local z really is the normal side.
        assert!((f.t.cross(f.b) - f.n).length() < 1e-5, "left-handed frame for n = {n}");
        let v = Vec3::new(0.3, -0.5, 0.81).normalize();
        assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        assert!((f.to_local(n) - Vec3::Z).length() < 1e-5);
    }

    #[test]
    fn orthonormal_for_any_normal() {
        for n in [Vec3::Z, -Vec3::Z, Vec3::X, -Vec3::Y, Vec3::new(1.0, 0.0, -0.0), Vec3::new(0.0, -1.0, 0.0)] {
            check(n);
        }
        // -0.0 z with a tiny tangent component: the classic failure case of Frisvad's method.
        check(Vec3::new(1e-4, 0.0, -1.0).normalize());
        let mut s = 1u32;
        for _ in 0..1000 {
            let mut r = || {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                (s >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
            };
            let v = Vec3::new(r(), r(), r());
            if v.length() > 1e-3 {
                check(v.normalize());
            }
        }
    }
}
