//! BSDFs of the closures that compiled materials return (see [`crate::abi::ClosureKind`]).
//!
//! Conventions, shared with the integrator:
//! - Directions are in the local shading frame ([`Frame`]; +z is the shading normal) and both
//!   `wo` (towards the viewer) and `wi` (towards the light) point away from the surface.
//! - `eval` returns `f` without the `|cos θi|` factor; `sample` returns `f` and a solid-angle
//!   pdf, so a path's throughput is multiplied by `f |cos θi| / pdf`.
//! - Reflection-only BSDFs (diffuse, glossy, metal) are two-sided: a viewer below the shading
//!   normal (`wo.z < 0`, e.g. from shading-normal interpolation or a back face) sees the
//!   mirrored BSDF in its own hemisphere, and `wi` must be on the same side as `wo`.
//! - Glass is oriented: `wo.z < 0` means the ray arrives from inside the medium. Radiance
//!   transport: transmitted `f` is scaled by `1/η²` (η = ratio of the indices, transmitted over
//!   incident), the radiance compression across the interface; importance transport (light
//!   tracing) would omit it and is not provided.
//! - Roughness is perceptual (`α = roughness²`); below [`DELTA_ALPHA`](crate::render::material::microfacet::DELTA_ALPHA) a lobe is a Dirac delta.

use crate::abi::{Closure, ClosureKind};
use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, FRAC_PI_4, PI};

pub use crate::render::material::frame::Frame;
use crate::render::material::microfacet::{
    Ggx, fresnel_conductor, fresnel_conductor3, fresnel_dielectric, gulbrandsen, hemispherical_average,
};

/// Result of sampling a BSDF. Directions are in the local shading frame (z = shading normal),
/// both `wo` (towards the viewer) and `wi` (towards the light) point away from the surface.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Sampled direction towards the light.
    pub wi: Vec3,
    /// BSDF value f(wo, wi) (NOT multiplied by |cos θi|).
    pub f: Vec3,
    /// Solid-angle pdf of wi; for a delta lobe (roughness ~0) the pdf of choosing that lobe, with `delta = true`.
    pub pdf: f32,
    /// True when the sampled lobe is a Dirac delta (specular): eval/pdf would return 0 for it.
    pub delta: bool,
}

/// A BSDF built from a compiled shader's closure value. Small, Copy, no allocation; every
/// parameter is already sanitised, so the hot-path methods never see NaN or out-of-range values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bsdf {
    /// Absorbs everything (`ClosureKind::None`).
    Black,
    /// Lambert.
    Diffuse {
        /// Reflectance in [0, 1].
        albedo: Vec3,
    },
    /// A GGX dielectric coat over a Lambert base. Energy conservation uses the simple
    /// `(1 − s F(μo)) (1 − s F(μi))` weighting of the base (s = max specular channel), which is
    /// reciprocal and keeps the white furnace below 1 (see the tests for measured figures);
    /// light reflected internally by the coat is lost rather than re-scattered.
    Glossy {
        /// Base reflectance in [0, 1].
        albedo: Vec3,
        /// Coat reflection tint in [0, 1].
        specular: Vec3,
        /// Coat roughness.
        ggx: Ggx,
        /// Coat index of refraction in [1, 4].
        eta: f32,
    },
    /// A GGX conductor.
    Metal {
        /// Normal-incidence reflectance (the artist's colour), kept for the albedo estimate.
        reflectivity: Vec3,
        /// Real part of the complex index, per channel.
        eta: Vec3,
        /// Imaginary part (extinction), per channel.
        k: Vec3,
        /// Roughness.
        ggx: Ggx,
    },
    /// A rough dielectric interface (Walter et al. 2007) with reflection and transmission.
    Glass {
        /// Transmission tint in [0, 1].
        tint: Vec3,
        /// Roughness.
        ggx: Ggx,
        /// Index of refraction of the inside (outside is 1), in [1, 4]; 1 is a null interface.
        eta: f32,
    },
}

/// Highest index of refraction accepted; beyond it Fresnel is ~1 everywhere anyway.
const MAX_IOR: f32 = 4.0;

/// NaN → `default`, ±Inf and everything else clamped to [lo, hi].
pub(crate) fn sanitize(x: f32, lo: f32, hi: f32, default: f32) -> f32 {
    if x.is_nan() { default } else { x.clamp(lo, hi) }
}

/// A colour parameter: NaN channels are black (a broken shader must not look plausible), the
/// rest is clamped to [0, 1] so that no BSDF can create energy.
pub(crate) fn colour(p: &[f32]) -> Vec3 {
    Vec3::new(sanitize(p[0], 0.0, 1.0, 0.0), sanitize(p[1], 0.0, 1.0, 0.0), sanitize(p[2], 0.0, 1.0, 0.0))
}

pub(crate) fn roughness(x: f32) -> Ggx {
    Ggx::from_roughness(sanitize(x, 0.0, 1.0, 0.5))
}

pub(crate) fn ior(x: f32) -> f32 {
    sanitize(x, 1.0, MAX_IOR, 1.5)
}

/// Mirrors `v` through the xy-plane.
#[inline]
pub(crate) fn flip_z(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.y, -v.z)
}

/// Mirror reflection of `wo` about `m`.
#[inline]
pub(crate) fn reflect(wo: Vec3, m: Vec3) -> Vec3 {
    2.0 * wo.dot(m) * m - wo
}

/// Refracts `wo` through a microfacet with normal `m` (any side); `eta` is the inside index.
/// Returns the transmitted direction and the relative index η (transmitted over incident), or
/// `None` under total internal reflection.
#[inline]
pub(crate) fn refract(wo: Vec3, m: Vec3, eta: f32) -> Option<(Vec3, f32)> {
    let mut cos_i = wo.dot(m);
    let (mut eta, mut n) = (eta, m);
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
        n = -n;
    }
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    Some((-wo / eta + (cos_i / eta - cos_t) * n, eta))
}

/// Cosine-weighted hemisphere sample via Shirley–Chiu's concentric disk.
#[inline]
pub(crate) fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let o = 2.0 * u - Vec2::ONE;
    let d = if o.x == 0.0 && o.y == 0.0 {
        Vec2::ZERO
    } else if o.x.abs() > o.y.abs() {
        let phi = FRAC_PI_4 * (o.y / o.x);
        o.x * Vec2::new(phi.cos(), phi.sin())
    } else {
        let phi = PI / 2.0 - FRAC_PI_4 * (o.x / o.y);
        o.y * Vec2::new(phi.cos(), phi.sin())
    };
    Vec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt())
}

fn finite3(v: Vec3) -> bool {
    v.is_finite()
}

/// Builds the sample after the checks every lobe needs: a usable pdf and finite values.
#[inline]
pub(crate) fn finish(wi: Vec3, f: Vec3, pdf: f32, delta: bool) -> Option<BsdfSample> {
    (pdf > 0.0 && pdf.is_finite() && finite3(f) && finite3(wi) && wi.z != 0.0).then_some(BsdfSample {
        wi,
        f: f.max(Vec3::ZERO),
        pdf,
        delta,
    })
}

impl Bsdf {
    /// Decodes a closure (param layouts in [`ClosureKind`]). Sanitises parameters: NaN colours
    /// become black, NaN roughness 0.5, NaN ior 1.5; everything is clamped to its valid range
    /// (colours [0, 1], roughness [0, 1], ior [1, 4]). `ClosureKind::None` is [`Bsdf::Black`].
    pub fn from_closure(c: &Closure) -> Bsdf {
        let p = &c.params;
        match ClosureKind::from_u32(c.kind) {
            ClosureKind::None => Bsdf::Black,
            ClosureKind::Diffuse => Bsdf::Diffuse { albedo: colour(&p[0..3]) },
            ClosureKind::Glossy => Bsdf::Glossy {
                albedo: colour(&p[0..3]),
                specular: colour(&p[3..6]),
                ggx: roughness(p[6]),
                eta: ior(p[7]),
            },
            ClosureKind::Metal => {
                let reflectivity = colour(&p[0..3]);
                let tint = colour(&p[3..6]);
                let (mut eta, mut k) = (Vec3::ZERO, Vec3::ZERO);
                for i in 0..3 {
                    (eta[i], k[i]) = gulbrandsen(reflectivity[i], tint[i]);
                }
                Bsdf::Metal { reflectivity, eta, k, ggx: roughness(p[6]) }
            }
            ClosureKind::Glass => {
                let mut eta = ior(p[4]);
                // A near-null interface makes the rough-transmission half vector ill-conditioned;
                // snap it to a null interface, which is a delta pass-through.
                if eta < 1.0 + 1e-3 {
                    eta = 1.0;
                }
                Bsdf::Glass { tint: colour(&p[0..3]), ggx: roughness(p[3]), eta }
            }
            ClosureKind::Conductor => {
                let eta = Vec3::from_array([0, 1, 2].map(|i| sanitize(p[i], 0.01, 20.0, 1.0)));
                let k = Vec3::from_array([3, 4, 5].map(|i| sanitize(p[i], 0.0, 20.0, 0.0)));
                Bsdf::Metal { reflectivity: fresnel_conductor3(1.0, eta, k), eta, k, ggx: roughness(p[6]) }
            }
            // The MaterialX lobes live in `material::lobes`, which decodes them itself.
            ClosureKind::Dielectric
            | ClosureKind::GeneralizedSchlick
            | ClosureKind::OrenNayar
            | ClosureKind::Burley
            | ClosureKind::Sheen
            | ClosureKind::Translucent => Bsdf::Black,
        }
    }

    /// f(wo, wi), local frame, not multiplied by cos; 0 for delta lobes and invalid directions.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let f = match *self {
            Bsdf::Black => Vec3::ZERO,
            Bsdf::Glass { tint, ggx, eta } => glass_eval(tint, ggx, eta, wo, wi, fresnel_dielectric),
            _ => match upper(wo, wi) {
                Some((wo, wi)) => self.eval_reflection(wo, wi),
                None => Vec3::ZERO,
            },
        };
        if f.is_finite() { f.max(Vec3::ZERO) } else { Vec3::ZERO }
    }

    /// Solid-angle pdf that `sample` produces wi with (non-delta part only).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let p = match *self {
            Bsdf::Black => 0.0,
            Bsdf::Glass { ggx, eta, .. } => glass_pdf(ggx, eta, wo, wi, fresnel_dielectric),
            _ => match upper(wo, wi) {
                Some((wo, wi)) => self.pdf_reflection(wo, wi),
                None => 0.0,
            },
        };
        if p.is_finite() { p.max(0.0) } else { 0.0 }
    }

    /// Samples wi. `u` picks the direction, `uc` the lobe. `None` when nothing is reflected or
    /// the sample is invalid (e.g. a microfacet reflection below the horizon); the integrator
    /// then terminates the path, which is unbiased because `pdf` excludes such samples.
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if !(wo.z != 0.0 && wo.is_finite() && uc.is_finite() && u.is_finite()) {
            return None;
        }
        let u = u.clamp(Vec2::ZERO, Vec2::splat(1.0 - f32::EPSILON / 2.0));
        match *self {
            Bsdf::Black => None,
            Bsdf::Glass { tint, ggx, eta } => glass_sample(tint, ggx, eta, wo, uc, u, fresnel_dielectric),
            _ => {
                // Two-sided: sample in wo's hemisphere mirrored to +z, then mirror back.
                let below = wo.z < 0.0;
                let wo_up = if below { flip_z(wo) } else { wo };
                let mut s = self.sample_reflection(wo_up, uc, u)?;
                if below {
                    s.wi = flip_z(s.wi);
                }
                Some(s)
            }
        }
    }

    /// [`Bsdf::eval`] of a [`Bsdf::Glass`] whose microfacets reflect `fresnel(wo·m, η)` (a
    /// negative cosine is seen from inside) rather than the dielectric Fresnel term: a glass
    /// under a thin film ([`Reflectance`]). Other kinds are evaluated as they are. Plain glass
    /// does not come this way, so its code stays specialised for the scalar term.
    pub(crate) fn eval_glass_with<R: Reflectance>(&self, wo: Vec3, wi: Vec3, fresnel: impl Fn(f32, f32) -> R) -> Vec3 {
        let Bsdf::Glass { tint, ggx, eta } = *self else { return self.eval(wo, wi) };
        let f = glass_eval(tint, ggx, eta, wo, wi, fresnel);
        if f.is_finite() { f.max(Vec3::ZERO) } else { Vec3::ZERO }
    }

    /// [`Bsdf::pdf`] of a glass with the Fresnel term `fresnel` ([`Bsdf::eval_glass_with`]).
    pub(crate) fn pdf_glass_with<R: Reflectance>(&self, wo: Vec3, wi: Vec3, fresnel: impl Fn(f32, f32) -> R) -> f32 {
        let Bsdf::Glass { ggx, eta, .. } = *self else { return self.pdf(wo, wi) };
        let p = glass_pdf(ggx, eta, wo, wi, fresnel);
        if p.is_finite() { p.max(0.0) } else { 0.0 }
    }

    /// [`Bsdf::sample`] of a glass with the Fresnel term `fresnel` ([`Bsdf::eval_glass_with`]).
    pub(crate) fn sample_glass_with<R: Reflectance>(
        &self,
        wo: Vec3,
        uc: f32,
        u: Vec2,
        fresnel: impl Fn(f32, f32) -> R + Copy,
    ) -> Option<BsdfSample> {
        let Bsdf::Glass { tint, ggx, eta } = *self else { return self.sample(wo, uc, u) };
        if !(wo.z != 0.0 && wo.is_finite() && uc.is_finite() && u.is_finite()) {
            return None;
        }
        let u = u.clamp(Vec2::ZERO, Vec2::splat(1.0 - f32::EPSILON / 2.0));
        glass_sample(tint, ggx, eta, wo, uc, u, fresnel)
    }

    /// Approximate directional-hemispherical reflectance colour, for the "albedo" AOV: the
    /// cosine-weighted average over incident directions, with Fresnel terms averaged by
    /// quadrature and roughness ignored.
    pub fn albedo(&self) -> Vec3 {
        match *self {
            Bsdf::Black => Vec3::ZERO,
            Bsdf::Diffuse { albedo } => albedo,
            Bsdf::Glossy { albedo, specular, eta, .. } => {
                let fav = hemispherical_average(|mu| fresnel_dielectric(mu, eta));
                let s = specular.max_element();
                specular * fav + albedo * (1.0 - s * fav) * (1.0 - s * fav)
            }
            Bsdf::Metal { eta, k, .. } => {
                let mut a = Vec3::ZERO;
                for i in 0..3 {
                    a[i] = hemispherical_average(|mu| fresnel_conductor(mu, eta[i], k[i]));
                }
                a
            }
            Bsdf::Glass { tint, eta, .. } => {
                let fav = hemispherical_average(|mu| fresnel_dielectric(mu, eta));
                Vec3::splat(fav) + (1.0 - fav) * tint
            }
        }
    }

    /// Whether the BSDF has a non-delta lobe that transmits (rough glass): light sampling at
    /// such a vertex must cover both sides of the surface, not only the side of `wo`.
    pub fn transmits(&self) -> bool {
        matches!(*self, Bsdf::Glass { ggx, eta, .. } if !glass_smooth(ggx, eta))
    }

    /// The radiance compression `η'²` a sampled direction `wi` went through (η' = transmitted
    /// over incident index; 1 for reflection and for every lobe but glass's transmission):
    /// the factor by which `f` of a transmitted direction is scaled down (see the module
    /// conventions). Russian roulette multiplies it back so that a path inside glass is not
    /// played for its compressed throughput (Mitsuba 3's `path` integrator does the same).
    pub fn compression(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Glass { eta, .. } if wo.z * wi.z < 0.0 => {
                let etap = if wo.z > 0.0 { eta } else { 1.0 / eta };
                etap * etap
            }
            _ => 1.0,
        }
    }

    /// True when the BSDF has no non-delta lobe, so next-event estimation cannot contribute
    /// (also true for [`Bsdf::Black`], which reflects nothing at all).
    pub fn is_delta(&self) -> bool {
        match *self {
            Bsdf::Black => true,
            Bsdf::Diffuse { .. } => false,
            Bsdf::Glossy { albedo, ggx, .. } => ggx.is_smooth() && albedo == Vec3::ZERO,
            Bsdf::Metal { ggx, .. } => ggx.is_smooth(),
            Bsdf::Glass { ggx, eta, .. } => glass_smooth(ggx, eta),
        }
    }

    /// Reflection lobes with both directions already in the upper hemisphere.
    #[inline]
    fn eval_reflection(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match *self {
            Bsdf::Diffuse { albedo } => albedo * FRAC_1_PI,
            Bsdf::Glossy { albedo, specular, ggx, eta } => {
                let s = specular.max_element();
                let base = albedo
                    * (FRAC_1_PI
                        * (1.0 - s * fresnel_dielectric(wo.z, eta))
                        * (1.0 - s * fresnel_dielectric(wi.z, eta)));
                if ggx.is_smooth() {
                    return base;
                }
                let Some(m) = (wo + wi).try_normalize() else { return base };
                let coat = ggx.d(m) * ggx.g2(wo, wi) * fresnel_dielectric(wo.dot(m), eta) / (4.0 * wo.z * wi.z);
                base + specular * coat
            }
            Bsdf::Metal { eta, k, ggx, .. } => {
                if ggx.is_smooth() {
                    return Vec3::ZERO;
                }
                let Some(m) = (wo + wi).try_normalize() else { return Vec3::ZERO };
                fresnel_conductor3(wo.dot(m), eta, k) * (ggx.d(m) * ggx.g2(wo, wi) / (4.0 * wo.z * wi.z))
            }
            Bsdf::Black | Bsdf::Glass { .. } => Vec3::ZERO,
        }
    }

    #[inline]
    fn pdf_reflection(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } => wi.z * FRAC_1_PI,
            Bsdf::Glossy { albedo, specular, ggx, eta } => {
                let p = glossy_coat_probability(albedo, specular, eta, wo);
                let diffuse = (1.0 - p) * wi.z * FRAC_1_PI;
                if ggx.is_smooth() {
                    return diffuse;
                }
                diffuse + p * microfacet_reflection_pdf(ggx, wo, wi)
            }
            Bsdf::Metal { ggx, .. } => {
                if ggx.is_smooth() {
                    0.0
                } else {
                    microfacet_reflection_pdf(ggx, wo, wi)
                }
            }
            Bsdf::Black | Bsdf::Glass { .. } => 0.0,
        }
    }

    /// Samples a reflection lobe for `wo.z > 0`.
    #[inline]
    fn sample_reflection(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        let non_delta = |wi: Vec3| {
            if wi.z <= 0.0 {
                return None;
            }
            finish(wi, self.eval_reflection(wo, wi), self.pdf_reflection(wo, wi), false)
        };
        match *self {
            Bsdf::Diffuse { .. } => non_delta(cosine_hemisphere(u)),
            Bsdf::Glossy { albedo, specular, ggx, eta } => {
                let p = glossy_coat_probability(albedo, specular, eta, wo);
                if uc < p {
                    if ggx.is_smooth() {
                        let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                        let f = specular * (fresnel_dielectric(wo.z, eta) / wi.z);
                        finish(wi, f, p, true)
                    } else {
                        non_delta(reflect(wo, ggx.sample_visible(wo, u)?))
                    }
                } else {
                    non_delta(cosine_hemisphere(u))
                }
            }
            Bsdf::Metal { eta, k, ggx, .. } => {
                if ggx.is_smooth() {
                    let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                    finish(wi, fresnel_conductor3(wo.z, eta, k) / wi.z, 1.0, true)
                } else {
                    non_delta(reflect(wo, ggx.sample_visible(wo, u)?))
                }
            }
            Bsdf::Black | Bsdf::Glass { .. } => None,
        }
    }
}

/// Both directions moved to the upper hemisphere for a two-sided reflection lobe, or `None`
/// when they are on different sides (or one is tangent).
#[inline]
pub(crate) fn upper(wo: Vec3, wi: Vec3) -> Option<(Vec3, Vec3)> {
    if wo.z * wi.z > 0.0 { Some(if wo.z < 0.0 { (flip_z(wo), flip_z(wi)) } else { (wo, wi) }) } else { None }
}

/// Pdf of a VNDF-sampled microfacet reflection, `D_wo(m) / (4 wo·m)`, for `wo`, `wi` up.
#[inline]
pub(crate) fn microfacet_reflection_pdf(ggx: Ggx, wo: Vec3, wi: Vec3) -> f32 {
    let Some(m) = (wo + wi).try_normalize() else { return 0.0 };
    let dot = wo.dot(m);
    if dot <= 0.0 {
        return 0.0;
    }
    ggx.d_visible(wo, m) / (4.0 * dot)
}

/// Probability of sampling the glossy coat rather than the base, from `wo` alone (so that the
/// pdf stays a fixed mixture): proportional to their normal-incidence-free weights `s F(μo)` and
/// `(1 − s F(μo)) max(albedo)`, kept within [0.1, 0.9] when both lobes exist so that neither is
/// starved (a 4 % coat at normal incidence still gets sharp highlights).
#[inline]
fn glossy_coat_probability(albedo: Vec3, specular: Vec3, eta: f32, wo: Vec3) -> f32 {
    let s = specular.max_element();
    let f = s * fresnel_dielectric(wo.z.abs(), eta);
    let base = (1.0 - f) * albedo.max_element();
    if f <= 0.0 {
        0.0
    } else if base <= 0.0 {
        1.0
    } else {
        (f / (f + base)).clamp(0.1, 0.9)
    }
}

/// Whether glass is a pure delta interface: smooth, or a null interface (η = 1) through which
/// light passes straight on.
#[inline]
fn glass_smooth(ggx: Ggx, eta: f32) -> bool {
    ggx.is_smooth() || eta == 1.0
}

/// Shared setup of rough-glass eval and pdf: the generalised half vector (Walter et al. 2007,
/// eq. 16) and the relative index η' (1 for reflection). `None` for configurations no sample
/// produces: tangent directions or back-facing microfacets.
#[inline]
fn glass_half_vector(eta: f32, wo: Vec3, wi: Vec3) -> Option<(Vec3, f32, bool)> {
    let (co, ci) = (wo.z, wi.z);
    if co == 0.0 || ci == 0.0 {
        return None;
    }
    let reflect = co * ci > 0.0;
    let etap = if reflect {
        1.0
    } else if co > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    let mut m = (wi * etap + wo).try_normalize()?;
    if m.z < 0.0 {
        m = -m;
    }
    if m.dot(wi) * ci <= 0.0 || m.dot(wo) * co <= 0.0 {
        return None;
    }
    Some((m, etap, reflect))
}

/// What a glass interface's microfacet reflects, `R(wo·m)`: plain glass's scalar Fresnel term,
/// or a colour (a thin film's, [`crate::render::material::lobes::Film`]). Transmission carries
/// `1 − R` per channel, and sampling picks reflection with probability [`Reflectance::mean`].
/// The scalar methods do plain glass's arithmetic in its original order, so that its images
/// stay the same bit for bit.
pub(crate) trait Reflectance: Copy {
    /// The probability of choosing reflection.
    fn mean(self) -> f32;
    /// Reflection's `f`: `R · scale / denom`.
    fn reflected(self, scale: f32, denom: f32) -> Vec3;
    /// Transmission's `f`: `tint (1 − R) · scale · factor / denom`.
    fn transmitted(self, tint: Vec3, scale: f32, factor: f32, denom: f32) -> Vec3;
}

impl Reflectance for f32 {
    #[inline]
    fn mean(self) -> f32 {
        self
    }
    #[inline]
    fn reflected(self, scale: f32, denom: f32) -> Vec3 {
        Vec3::splat(scale * self / denom)
    }
    #[inline]
    fn transmitted(self, tint: Vec3, scale: f32, factor: f32, denom: f32) -> Vec3 {
        tint * (scale * (1.0 - self) * factor / denom)
    }
}

impl Reflectance for Vec3 {
    #[inline]
    fn mean(self) -> f32 {
        (self.x + self.y + self.z) / 3.0
    }
    #[inline]
    fn reflected(self, scale: f32, denom: f32) -> Vec3 {
        self * (scale / denom)
    }
    #[inline]
    fn transmitted(self, tint: Vec3, scale: f32, factor: f32, denom: f32) -> Vec3 {
        tint * (Vec3::ONE - self) * (scale * factor / denom)
    }
}

/// Rough-glass `f` with microfacets reflecting `fresnel(wo·m, eta)` ([`Reflectance`]).
fn glass_eval<R: Reflectance>(
    tint: Vec3,
    ggx: Ggx,
    eta: f32,
    wo: Vec3,
    wi: Vec3,
    fresnel: impl Fn(f32, f32) -> R,
) -> Vec3 {
    if glass_smooth(ggx, eta) {
        return Vec3::ZERO;
    }
    let Some((m, etap, reflect)) = glass_half_vector(eta, wo, wi) else { return Vec3::ZERO };
    let f = fresnel(wo.dot(m), eta);
    let dg = ggx.d(m) * ggx.g2(wo, wi);
    if reflect {
        f.reflected(dg, (4.0 * wo.z * wi.z).abs())
    } else {
        let denom = wi.dot(m) + wo.dot(m) / etap;
        f.transmitted(tint, dg, (wi.dot(m) * wo.dot(m) / (wi.z * wo.z * denom * denom)).abs(), etap * etap)
    }
}

/// Pdf of [`glass_sample`] (non-delta part).
fn glass_pdf<R: Reflectance>(ggx: Ggx, eta: f32, wo: Vec3, wi: Vec3, fresnel: impl Fn(f32, f32) -> R) -> f32 {
    if glass_smooth(ggx, eta) {
        return 0.0;
    }
    let Some((m, etap, reflect)) = glass_half_vector(eta, wo, wi) else { return 0.0 };
    let f = fresnel(wo.dot(m), eta).mean();
    let dv = ggx.d_visible(wo, m);
    if reflect {
        dv / (4.0 * wo.dot(m).abs()) * f
    } else {
        let denom = wi.dot(m) + wo.dot(m) / etap;
        dv * wi.dot(m).abs() / (denom * denom) * (1.0 - f)
    }
}

fn glass_sample<R: Reflectance>(
    tint: Vec3,
    ggx: Ggx,
    eta: f32,
    wo: Vec3,
    uc: f32,
    u: Vec2,
    fresnel: impl Fn(f32, f32) -> R + Copy,
) -> Option<BsdfSample> {
    if glass_smooth(ggx, eta) {
        // Fresnel picks reflection or transmission, so the weight f |cos| / pdf is 1 (times tint
        // and the 1/η² radiance compression for transmission; R over its mean for a colour).
        let f = fresnel(wo.z, eta);
        let r = f.mean();
        if uc < r {
            let wi = Vec3::new(-wo.x, -wo.y, wo.z);
            return finish(wi, f.reflected(1.0, wi.z.abs()), r, true);
        }
        let (wi, etap) = refract(wo, Vec3::Z, eta)?;
        let t = 1.0 - r;
        return finish(wi, f.transmitted(tint, 1.0, 1.0, wi.z.abs() * etap * etap), t, true);
    }
    let m = ggx.sample_visible(wo, u)?;
    let r = fresnel(wo.dot(m), eta).mean();
    let wi = if uc < r {
        let wi = reflect(wo, m);
        if wi.z * wo.z <= 0.0 {
            return None;
        }
        wi
    } else {
        let (wi, _) = refract(wo, m, eta)?;
        if wi.z * wo.z >= 0.0 {
            return None;
        }
        wi
    };
    // Re-deriving f and pdf from (wo, wi) keeps sample, eval and pdf consistent by construction;
    // the half vector recomputed from wi equals m up to rounding.
    finish(wi, glass_eval(tint, ggx, eta, wo, wi, fresnel), glass_pdf(ggx, eta, wo, wi, fresnel), false)
}

#[cfg(test)]
mod tests;
