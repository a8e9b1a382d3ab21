//! GGX (Trowbridge–Reitz) microfacet distribution and Fresnel terms shared by the BSDFs.
//!
//! All directions are in the lobe's local frame (+z = normal, +x = tangent). The distribution
//! may be anisotropic (α along the tangent and the bitangent); microfacet normals always lie in
//! the upper hemisphere, whichever side the directions are on.

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

/// Below this GGX alpha a lobe is treated as a perfect (Dirac delta) mirror or refractor: the
/// distribution's peak `1/(π α²)` would otherwise overflow the dynamic range that f32 sampling
/// and binning can resolve, and the integrator is better served by a delta lobe.
pub const DELTA_ALPHA: f32 = 1e-3;

/// Largest ratio `√(αx / αy)` (or its inverse) a lobe takes: past it the narrow direction's
/// width falls under [`DELTA_ALPHA`] for any roughness that is not nearly 1.
pub const MAX_ASPECT: f32 = 30.0;

/// GGX distribution with the height-correlated Smith masking–shadowing term, anisotropic with
/// `αx = α·aspect` along the local x axis (the tangent) and `αy = α / aspect` along y.
///
/// `aspect == 1` is the isotropic distribution, bit for bit: every formula below multiplies
/// or divides by `aspect²` where the isotropic one has nothing, which is exact for 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    /// Geometric mean width `α = √(αx αy)`; the closures' perceptual roughness `r` maps to
    /// `α = r²`. Albedo tables, which are isotropic, read this width.
    pub alpha: f32,
    /// `√(αx / αy)`, in [1 / [`MAX_ASPECT`], [`MAX_ASPECT`]]; 1: isotropic.
    pub aspect: f32,
}

impl Ggx {
    /// Isotropic, of width `alpha`.
    pub fn isotropic(alpha: f32) -> Ggx {
        Ggx { alpha, aspect: 1.0 }
    }

    /// Widths `alpha_x` along the tangent and `alpha_y` along the bitangent (both > 0).
    pub fn anisotropic(alpha_x: f32, alpha_y: f32) -> Ggx {
        Ggx { alpha: (alpha_x * alpha_y).sqrt(), aspect: 1.0 }.with_aspect((alpha_x / alpha_y).sqrt())
    }

    /// From perceptual roughness (already clamped to [0, 1]).
    pub fn from_roughness(roughness: f32) -> Ggx {
        Ggx::isotropic(roughness * roughness)
    }

    /// The same mean width stretched by `aspect` (`√(αx / αy)`; clamped to
    /// [1 / [`MAX_ASPECT`], [`MAX_ASPECT`]], a non-finite or non-positive one is 1).
    pub fn with_aspect(self, aspect: f32) -> Ggx {
        let aspect = if aspect.is_finite() && aspect > 0.0 { aspect.clamp(1.0 / MAX_ASPECT, MAX_ASPECT) } else { 1.0 };
        Ggx { aspect, ..self }
    }

    /// Width along the tangent (local x).
    #[inline]
    pub fn alpha_x(&self) -> f32 {
        self.alpha * self.aspect
    }

    /// Width along the bitangent (local y).
    #[inline]
    pub fn alpha_y(&self) -> f32 {
        self.alpha / self.aspect
    }

    /// Whether the distribution is anisotropic.
    #[inline]
    pub fn is_anisotropic(&self) -> bool {
        self.aspect != 1.0
    }

    /// Whether the lobe should be handled as a delta lobe (its mean width is under
    /// [`DELTA_ALPHA`]).
    #[inline]
    pub fn is_smooth(&self) -> bool {
        self.alpha < DELTA_ALPHA
    }

    /// Normal distribution `D(m)`, normalised so that `∫ D(m) cos θm dm = 1`.
    #[inline]
    pub fn d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let s2 = self.aspect * self.aspect;
        // 1 / (π αx αy (x²/αx² + y²/αy² + z²)²) multiplied through by (αx αy)² = α⁴ to stay
        // finite for small α (αy/αx = 1/aspect², αx/αy = aspect²).
        let t = m.x * m.x / s2 + m.y * m.y * s2 + a2 * m.z * m.z;
        if t <= 0.0 {
            return 0.0;
        }
        a2 * FRAC_1_PI / (t * t)
    }

    /// Smith `Λ(w)`; the masking of a direction is `1 / (1 + Λ)`.
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        let z2 = w.z * w.z;
        if z2 <= 0.0 {
            return f32::INFINITY;
        }
        // α² tan² θ with α²(φ) = cos²φ αx² + sin²φ αy² (α² aspect² and α² / aspect²).
        let s2 = self.aspect * self.aspect;
        let a2tan2 = self.alpha * self.alpha * (w.x * w.x * s2 + w.y * w.y / s2) / z2;
        // (sqrt(1 + x) - 1) / 2 rewritten as x / (2 (sqrt(1 + x) + 1)) to avoid cancellation for tiny α.
        a2tan2 / (2.0 * ((1.0 + a2tan2).sqrt() + 1.0))
    }

    /// Smith masking `G1(w)`.
    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated masking–shadowing `G2(wo, wi)` (Heitz 2014), symmetric in its arguments.
    #[inline]
    pub fn g2(&self, wo: Vec3, wi: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// Density of visible normals `D_wo(m) = G1(wo) max(0, wo·m) D(m) / |wo.z|` (for `wo` on
    /// either side, the lower side seeing the mirrored microsurface).
    #[inline]
    pub fn d_visible(&self, wo: Vec3, m: Vec3) -> f32 {
        let cos_o = wo.z.abs();
        if cos_o <= 0.0 {
            return 0.0;
        }
        let wo_up = if wo.z < 0.0 { -wo } else { wo };
        let dot = wo_up.dot(m);
        if dot <= 0.0 {
            return 0.0;
        }
        self.g1(wo) * dot * self.d(m) / cos_o
    }

    /// Samples a visible normal for `wo` (either side) with the spherical-cap method of Dupuy &
    /// Benyoub 2023 ("Sampling Visible GGX Normals with Spherical Caps"); the density is
    /// [`Ggx::d_visible`]. `None` only on a numerically degenerate sample.
    #[inline]
    pub fn sample_visible(&self, wo: Vec3, u: Vec2) -> Option<Vec3> {
        let wo_up = if wo.z < 0.0 { -wo } else { wo };
        let (ax, ay) = (self.alpha_x(), self.alpha_y());
        // Warp to the hemisphere configuration (α = 1).
        let wh = Vec3::new(ax * wo_up.x, ay * wo_up.y, wo_up.z).try_normalize()?;
        let phi = 2.0 * PI * u.x;
        let z = (1.0 - u.y) * (1.0 + wh.z) - wh.z;
        let sin_theta = (1.0 - z * z).clamp(0.0, 1.0).sqrt();
        let c = Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), z);
        let h = c + wh;
        let m = Vec3::new(ax * h.x, ay * h.y, h.z).try_normalize()?;
        (m.z > 0.0).then_some(m)
    }
}

/// Unpolarised Fresnel reflectance of a dielectric interface. `cos_i` is the cosine between the
/// incident direction and the normal on the side of the medium with relative index `eta`
/// (transmitted over incident); a negative `cos_i` means incidence from the other side.
/// Returns 1 under total internal reflection.
#[inline]
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let (cos_i, eta) = if cos_i < 0.0 { (-cos_i, 1.0 / eta) } else { (cos_i, eta) };
    let cos_i = cos_i.min(1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let f = 0.5 * (r_parl * r_parl + r_perp * r_perp);
    if f.is_finite() { f.min(1.0) } else { 1.0 }
}

/// Fresnel reflectance of a conductor with complex index `eta + i k` (exact, both
/// polarisations averaged), for `cos_i` in [0, 1].
#[inline]
pub fn fresnel_conductor(cos_i: f32, eta: f32, k: f32) -> f32 {
    let c = cos_i.clamp(0.0, 1.0);
    let n = C { re: eta, im: k };
    let sin2_i = 1.0 - c * c;
    // cos θt = sqrt(1 - sin²θi / n²)
    let cos_t = (C::real(1.0) - C::real(sin2_i) / (n * n)).sqrt();
    let nc = n * C::real(c);
    let r_parl = (nc - cos_t) / (nc + cos_t);
    let r_perp = (C::real(c) - n * cos_t) / (C::real(c) + n * cos_t);
    let f = 0.5 * (r_parl.norm() + r_perp.norm());
    if f.is_finite() { f.clamp(0.0, 1.0) } else { 1.0 }
}

/// Per-channel [`fresnel_conductor`].
#[inline]
pub fn fresnel_conductor3(cos_i: f32, eta: Vec3, k: Vec3) -> Vec3 {
    Vec3::new(
        fresnel_conductor(cos_i, eta.x, k.x),
        fresnel_conductor(cos_i, eta.y, k.y),
        fresnel_conductor(cos_i, eta.z, k.z),
    )
}

/// Converts artist-friendly metal colours to a complex index per channel (Gulbrandsen 2014,
/// "Artist Friendly Metallic Fresnel"): `r` is the reflectance at normal incidence (exactly
/// reproduced), `g` the edge tint steering `n` between its extremes. Computed in f64 because
/// `k²` cancels catastrophically for `r → 1`. Inputs are clamped to `r ∈ [0, 0.999]`, `g ∈ [0, 1]`.
pub fn gulbrandsen(r: f32, g: f32) -> (f32, f32) {
    let r = (r as f64).clamp(0.0, 0.999);
    let g = (g as f64).clamp(0.0, 1.0);
    let n_min = (1.0 - r) / (1.0 + r);
    let sr = r.sqrt();
    let n_max = (1.0 + sr) / (1.0 - sr);
    let n = n_min * g + (1.0 - g) * n_max;
    let k2 = ((n + 1.0) * (n + 1.0) * r - (n - 1.0) * (n - 1.0)) / (1.0 - r);
    (n as f32, k2.max(0.0).sqrt() as f32)
}

/// Cosine-weighted hemispherical average `2 ∫ F(μ) μ dμ` of a Fresnel curve, by 8-point
/// Gauss–Legendre quadrature (exact enough for an albedo estimate, not for the hot path).
pub fn hemispherical_average(f: impl Fn(f32) -> f32) -> f32 {
    hemispherical_average3(|mu| Vec3::splat(f(mu))).x
}

/// [`hemispherical_average`] of a colour-valued `f`, each channel summed exactly as the scalar
/// average sums it (so `f` is evaluated once per node, not once per channel).
pub fn hemispherical_average3(f: impl Fn(f32) -> Vec3) -> Vec3 {
    const X: [f32; 4] = [0.183_434_64, 0.525_532_4, 0.796_666_5, 0.960_289_9];
    const W: [f32; 4] = [0.362_683_8, 0.313_706_65, 0.222_381_03, 0.101_228_54];
    let mut sum = Vec3::ZERO;
    for (x, w) in X.iter().zip(W) {
        for mu in [0.5 * (1.0 + x), 0.5 * (1.0 - x)] {
            sum += f(mu) * (w * 0.5) * mu;
        }
    }
    2.0 * sum
}

/// Minimal complex arithmetic for the conductor Fresnel term.
#[derive(Clone, Copy, Debug)]
struct C {
    re: f32,
    im: f32,
}

impl C {
    fn real(re: f32) -> C {
        C { re, im: 0.0 }
    }
    fn norm(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    /// Principal square root.
    fn sqrt(self) -> C {
        let m = self.norm().sqrt();
        let re = (0.5 * (m + self.re)).max(0.0).sqrt();
        let im = (0.5 * (m - self.re)).max(0.0).sqrt();
        C { re, im: if self.im < 0.0 { -im } else { im } }
    }
}

impl std::ops::Add for C {
    type Output = C;
    fn add(self, o: C) -> C {
        C { re: self.re + o.re, im: self.im + o.im }
    }
}

impl std::ops::Sub for C {
    type Output = C;
    fn sub(self, o: C) -> C {
        C { re: self.re - o.re, im: self.im - o.im }
    }
}

impl std::ops::Mul for C {
    type Output = C;
    fn mul(self, o: C) -> C {
        C { re: self.re * o.re - self.im * o.im, im: self.re * o.im + self.im * o.re }
    }
}

impl std::ops::Div for C {
    type Output = C;
    fn div(self, o: C) -> C {
        let d = o.norm();
        C { re: (self.re * o.re + self.im * o.im) / d, im: (self.im * o.re - self.re * o.im) / d }
    }
}

/// Sheen roughness below this is this (the lobe's grazing peak is then already narrower than
/// its tables resolve).
pub const MIN_SHEEN_ROUGHNESS: f32 = 0.1;

/// The Charlie sheen of white colour, `f(ωo, ωi)` for both directions up, unnormalised: its
/// albedo exceeds 1 at grazing angles when smooth (`lobes::Lobe::Sheen` divides that out).
#[inline]
pub fn sheen_eval(roughness: f32, wo: Vec3, wi: Vec3) -> f32 {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return 0.0;
    }
    let Some(h) = (wo + wi).try_normalize() else { return 0.0 };
    let inv_alpha = 1.0 / roughness.clamp(MIN_SHEEN_ROUGHNESS, 1.0);
    let sin2 = (1.0 - h.z * h.z).max(0.0);
    let d = (2.0 + inv_alpha) * sin2.powf(0.5 * inv_alpha) / (2.0 * PI);
    d / (4.0 * (wi.z + wo.z - wi.z * wo.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ggx_d_is_normalised_over_projected_area() {
        // ∫ D(m) cos θm dω = 1 for every α, including the narrow ones the chi-square tests use.
        for alpha in [0.0025f32, 0.05, 0.3, 1.0] {
            let g = Ggx::isotropic(alpha);
            // Integrate in slope-space-friendly θ: substitute tan θ = α s, s ∈ [0, ∞) via s = t/(1-t).
            let n = 4000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let t = (i as f64 + 0.5) / n as f64;
                let s = t / (1.0 - t);
                let ds_dt = 1.0 / ((1.0 - t) * (1.0 - t));
                let theta = (alpha as f64 * s).atan();
                let dtheta_ds = alpha as f64 / (1.0 + (alpha as f64 * s).powi(2));
                let m = Vec3::new(theta.sin() as f32, 0.0, theta.cos() as f32);
                sum += g.d(m) as f64 * theta.cos() * theta.sin() * 2.0 * std::f64::consts::PI * dtheta_ds * ds_dt
                    / n as f64;
            }
            assert!((sum - 1.0).abs() < 2e-3, "alpha {alpha}: ∫ D cos = {sum}");
        }
    }

    #[test]
    fn dielectric_fresnel_known_values() {
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        assert!((fresnel_dielectric(-1.0, 1.5) - 0.04).abs() < 1e-6);
        assert_eq!(fresnel_dielectric(0.0, 1.5), 1.0);
        // Total internal reflection past the critical angle (41.8° for 1.5) from inside.
        assert_eq!(fresnel_dielectric(-(50f32.to_radians().cos()), 1.5), 1.0);
        assert!(fresnel_dielectric(-(40f32.to_radians().cos()), 1.5) < 1.0);
        assert_eq!(fresnel_dielectric(0.7, 1.0), 0.0);
    }

    #[test]
    fn conductor_fresnel_matches_dielectric_for_real_index_and_reproduces_artist_colours() {
        for c in [0.0f32, 0.2, 0.5, 0.9, 1.0] {
            let a = fresnel_conductor(c, 1.5, 0.0);
            let b = fresnel_dielectric(c, 1.5);
            assert!((a - b).abs() < 1e-5, "cos {c}: {a} vs {b}");
        }
        for r in [0.0f32, 0.04, 0.5, 0.91, 0.999] {
            for g in [0.0f32, 0.3, 1.0] {
                let (n, k) = gulbrandsen(r, g);
                assert!(n.is_finite() && k.is_finite() && n > 0.0 && k >= 0.0, "r {r} g {g}: n {n} k {k}");
                let f0 = fresnel_conductor(1.0, n, k);
                assert!((f0 - r).abs() < 2e-3, "r {r} g {g}: F(0°) = {f0}");
                assert!(fresnel_conductor(0.0, n, k) > 0.999, "grazing reflectance must reach 1");
            }
        }
    }

    #[test]
    fn visible_normal_samples_are_upper_hemisphere_and_facing() {
        let g = Ggx::isotropic(0.5);
        let wo = Vec3::new(0.6, 0.0, -0.8);
        for i in 0..64 {
            for j in 0..64 {
                let u = Vec2::new((i as f32 + 0.5) / 64.0, (j as f32 + 0.5) / 64.0);
                let m = g.sample_visible(wo, u).expect("regular sample");
                assert!(m.z > 0.0 && (-wo).dot(m) > -1e-6, "m {m}");
            }
        }
    }
}
