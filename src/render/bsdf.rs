//! Placeholder BSDFs: every closure kind is Lambert with albedo = its first three params.
//! Replaced wholesale at merge by the real implementation (same API).

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

/// A sampled direction. Local frame, z = shading normal; `f` is not multiplied by cos.
pub struct BsdfSample {
    /// Incident direction (away from the surface).
    pub wi: Vec3,
    /// BSDF value.
    pub f: Vec3,
    /// Solid-angle pdf.
    pub pdf: f32,
    /// Whether the lobe is a delta distribution.
    pub delta: bool,
}

/// A BSDF built from a closure value.
#[derive(Clone, Copy, Debug)]
pub enum Bsdf {
    /// Black.
    None,
    /// Lambert.
    Lambert {
        /// Reflectance.
        albedo: Vec3,
    },
}

impl Bsdf {
    /// Builds the BSDF a closure describes.
    pub fn from_closure(c: &crate::abi::Closure) -> Bsdf {
        match crate::abi::ClosureKind::from_u32(c.kind) {
            crate::abi::ClosureKind::None => Bsdf::None,
            _ => Bsdf::Lambert { albedo: Vec3::new(c.params[0], c.params[1], c.params[2]) },
        }
    }

    /// Evaluates the BSDF.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match self {
            Bsdf::Lambert { albedo } if wo.z > 0.0 && wi.z > 0.0 => *albedo * FRAC_1_PI,
            _ => Vec3::ZERO,
        }
    }

    /// Solid-angle pdf of [`Bsdf::sample`].
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match self {
            Bsdf::Lambert { .. } if wo.z > 0.0 && wi.z > 0.0 => wi.z * FRAC_1_PI,
            _ => 0.0,
        }
    }

    /// Samples an incident direction.
    pub fn sample(&self, wo: Vec3, _uc: f32, u: Vec2) -> Option<BsdfSample> {
        match self {
            Bsdf::Lambert { albedo } if wo.z > 0.0 => {
                let r = u.x.sqrt();
                let phi = 2.0 * PI * u.y;
                let wi = Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt());
                if wi.z <= 0.0 {
                    return None;
                }
                Some(BsdfSample { wi, f: *albedo * FRAC_1_PI, pdf: wi.z * FRAC_1_PI, delta: false })
            }
            _ => None,
        }
    }

    /// Directional-hemispherical reflectance estimate (the albedo AOV).
    pub fn albedo(&self) -> Vec3 {
        match self {
            Bsdf::Lambert { albedo } => *albedo,
            Bsdf::None => Vec3::ZERO,
        }
    }

    /// Whether every lobe is a delta distribution.
    pub fn is_delta(&self) -> bool {
        false
    }
}

/// An orthonormal shading frame.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Tangent.
    pub t: Vec3,
    /// Bitangent.
    pub b: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// A frame around a unit normal (Duff et al. 2017).
    pub fn from_normal(n: Vec3) -> Frame {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let t = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let bt = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { t, b: bt, n }
    }

    /// World → local.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }

    /// Local → world.
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }
}
