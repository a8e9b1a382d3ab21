//! The thin-walled dielectric sheet: `dielectric_bsdf` "T"/"RT" on a surface with no interior
//! (OpenPBR `geometry_thin_walled`, Standard Surface and MaterialX `thin_walled`: leaves,
//! paper, curtains, soap bubbles, single-sided window panes).
//!
//! Light meets two identical interfaces a vanishing distance apart and bounces between them.
//! Summing that ladder for an interface reflectance `R` gives the sheet's reflectance
//! `R' = R + (1 − R)² R / (1 − R²) = 2R / (1 + R)` and transmittance `T' = 1 − R'` (the
//! transmission colour tints what passes, as the specifications make it the sheet's
//! transmittance). Transmitted light leaves undeflected, in direction `−ωo`, and the path
//! never enters a medium: the lobe faces the ray like a reflection lobe (it is not
//! [`oriented`](ThinSheet::oriented)) and carries no radiance compression.
//!
//! Rough sheets follow the construction the OpenPBR specification points to (Kulla and Conty
//! 2017, after Burley 2015's thin surfaces): reflection is the GGX lobe of the interface
//! roughness with the sheet's `R'` at each microfacet, and transmission is a GGX lobe mirrored
//! to the far side (a microfacet `m` sends `ωo` to the mirror image of its reflection, so a
//! smooth sheet transmits along `−ωo`), weighted by `T'`, with the roughness scaled by
//! `0.65 η − 0.35` (the two refractions spread light less than a reflection does). Both lobes
//! are reciprocal; with equal roughness their sum is GGX's single-scattering albedo, so a
//! clear sheet loses only what single scattering loses.
//!
//! Conventions are [`crate::render::material::bsdf`]'s: local frame, `eval` without the
//! cosine. The sheet is symmetric: a viewer below (`wo.z < 0`) sees it mirrored.

use super::Film;
use crate::render::material::albedo;
use crate::render::material::bsdf::{BsdfSample, finish, flip_z, microfacet_reflection_pdf, reflect};
use crate::render::material::microfacet::{DELTA_ALPHA, Ggx, fresnel_dielectric, hemispherical_average3};
use glam::{Vec2, Vec3};

/// A thin-walled dielectric sheet (see the module docs); Copy and sanitised like the lobes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThinSheet {
    /// Colour of the transmitted light, and of the reflected light too (MaterialX's
    /// `dielectric_bsdf` tints both).
    pub tint: Vec3,
    /// Index of refraction of the sheet in [1, 4].
    pub eta: f32,
    /// Roughness of the interfaces (the reflection lobe).
    pub ggx: Ggx,
    /// The mirrored transmission lobe's roughness ([`ThinSheet::transmission_roughness`]).
    pub ggx_t: Ggx,
    /// Whether the sheet reflects (scatter mode "RT"; "T" drops the reflection).
    pub reflect: bool,
    /// Whether the sheet transmits (false where it covers other terms of a layer: what it
    /// transmits reaches them).
    pub transmit: bool,
    /// A thin film on both faces (its reflectance is each interface's `R`).
    pub film: Option<Film>,
}

/// The reflectance of a sheet whose two interfaces each reflect `r` (per channel): the
/// geometric series of inter-reflections summed, `2r / (1 + r)`.
#[inline]
pub fn sheet_reflectance(r: Vec3) -> Vec3 {
    let r = r.clamp(Vec3::ZERO, Vec3::ONE);
    2.0 * r / (Vec3::ONE + r)
}

impl ThinSheet {
    /// The sheet of a `dielectric_bsdf` term's parameters.
    pub fn new(tint: Vec3, eta: f32, ggx: Ggx, reflect: bool, film: Option<Film>) -> ThinSheet {
        ThinSheet { tint, eta, ggx, ggx_t: Self::transmission_roughness(ggx, eta), reflect, transmit: true, film }
    }

    /// The transmission lobe's distribution: perceptual roughness scaled by
    /// `clamp(0.65 η − 0.35, 0, 1)` (Burley 2015's fit, which Kulla and Conty 2017 use for thin
    /// surfaces), and never a delta where the reflection is not (a lobe is wholly smooth or
    /// wholly rough).
    pub fn transmission_roughness(ggx: Ggx, eta: f32) -> Ggx {
        if ggx.is_smooth() {
            return ggx;
        }
        let scale = (0.65 * eta - 0.35).clamp(0.0, 1.0);
        let scaled = Ggx::from_roughness(ggx.alpha.sqrt() * scale);
        if scaled.is_smooth() { Ggx::isotropic(DELTA_ALPHA) } else { scaled.with_aspect(ggx.aspect) }
    }

    /// One interface's reflectance at `cos` (from outside: both faces see air).
    #[inline]
    fn interface(&self, cos: f32) -> Vec3 {
        let cos = cos.abs().min(1.0);
        match self.film {
            Some(film) => film.on_dielectric(cos, self.eta),
            None => Vec3::splat(fresnel_dielectric(cos, self.eta)),
        }
    }

    /// The sheet's reflectance `R'` at `cos` ([`sheet_reflectance`]).
    #[inline]
    pub fn reflectance(&self, cos: f32) -> Vec3 {
        sheet_reflectance(self.interface(cos))
    }

    /// Whether the sheet is a Dirac delta (smooth): it reflects mirror-like and transmits
    /// straight through.
    #[inline]
    pub fn is_delta(&self) -> bool {
        self.ggx.is_smooth()
    }

    /// Whether the sheet has a non-delta part that transmits.
    #[inline]
    pub fn transmits(&self) -> bool {
        self.transmit && !self.is_delta()
    }

    /// The sheet as the top of a layer: it keeps its reflection only.
    pub fn covering(self) -> ThinSheet {
        ThinSheet { transmit: false, ..self }
    }

    /// Probability of sampling reflection from `wo` (up): the sheet's reflectance at `wo`,
    /// kept within [0.05, 0.95] for a rough sheet so neither lobe is starved.
    #[inline]
    fn reflect_probability(&self, wo: Vec3) -> f32 {
        match (self.reflect, self.transmit) {
            (false, _) => 0.0,
            (true, false) => 1.0,
            (true, true) => {
                let r = self.reflectance(wo.z);
                let p = (r.x + r.y + r.z) / 3.0;
                if self.is_delta() { p } else { p.clamp(0.05, 0.95) }
            }
        }
    }

    /// f(wo, wi), local frame, without the cosine; 0 for a smooth sheet.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if self.is_delta() || wo.z == 0.0 || wi.z == 0.0 {
            return Vec3::ZERO;
        }
        let (wo, wi) = if wo.z < 0.0 { (flip_z(wo), flip_z(wi)) } else { (wo, wi) };
        let f = if wi.z > 0.0 {
            if !self.reflect {
                return Vec3::ZERO;
            }
            let Some(m) = (wo + wi).try_normalize() else { return Vec3::ZERO };
            self.reflectance(wo.dot(m)) * (self.ggx.d(m) * self.ggx.g2(wo, wi) / (4.0 * wo.z * wi.z))
        } else {
            if !self.transmit {
                return Vec3::ZERO;
            }
            let wt = flip_z(wi);
            let Some(m) = (wo + wt).try_normalize() else { return Vec3::ZERO };
            (Vec3::ONE - self.reflectance(wo.dot(m))) * (self.ggx_t.d(m) * self.ggx_t.g2(wo, wt) / (4.0 * wo.z * wt.z))
        };
        let f = f * self.tint;
        if f.is_finite() { f.max(Vec3::ZERO) } else { Vec3::ZERO }
    }

    /// Solid-angle pdf of [`ThinSheet::sample`] (non-delta part).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if self.is_delta() || wo.z == 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        let (wo, wi) = if wo.z < 0.0 { (flip_z(wo), flip_z(wi)) } else { (wo, wi) };
        let p_r = self.reflect_probability(wo);
        let p = if wi.z > 0.0 {
            p_r * microfacet_reflection_pdf(self.ggx, wo, wi)
        } else {
            (1.0 - p_r) * microfacet_reflection_pdf(self.ggx_t, wo, flip_z(wi))
        };
        if p.is_finite() { p.max(0.0) } else { 0.0 }
    }

    /// Samples wi: `uc` chooses reflection or transmission, `u` the microfacet.
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if !(wo.z != 0.0 && wo.is_finite() && uc.is_finite() && u.is_finite()) || !(self.reflect || self.transmit) {
            return None;
        }
        let below = wo.z < 0.0;
        let wo_up = if below { flip_z(wo) } else { wo };
        let p_r = self.reflect_probability(wo_up);
        let reflected = uc < p_r;
        let mut s = if self.is_delta() {
            let r = self.reflectance(wo_up.z);
            if reflected {
                let wi = Vec3::new(-wo_up.x, -wo_up.y, wo_up.z);
                finish(wi, self.tint * r / wi.z, p_r, true)?
            } else {
                let wi = -wo_up;
                finish(wi, self.tint * (Vec3::ONE - r) / wo_up.z, 1.0 - p_r, true)?
            }
        } else {
            let u = u.clamp(Vec2::ZERO, Vec2::splat(1.0 - f32::EPSILON / 2.0));
            let ggx = if reflected { self.ggx } else { self.ggx_t };
            let wr = reflect(wo_up, ggx.sample_visible(wo_up, u)?);
            if wr.z <= 0.0 {
                return None;
            }
            let wi = if reflected { wr } else { flip_z(wr) };
            finish(wi, self.eval(wo_up, wi), self.pdf(wo_up, wi), false)?
        };
        if below {
            s.wi = flip_z(s.wi);
        }
        Some(s)
    }

    /// Directional albedo `E(μ)` of what the sheet reflects (its transmission leaves the
    /// layer): the sheet's reflectance times GGX's single-scattering albedo.
    pub fn directional_albedo(&self, mu: f32) -> Vec3 {
        if !self.reflect {
            return Vec3::ZERO;
        }
        let e = if self.is_delta() { 1.0 } else { albedo::ggx_reflection(mu, self.ggx.alpha.sqrt()) };
        self.tint * self.reflectance(mu) * e
    }

    /// Approximate hemispherical albedo colour (reflection and transmission, roughness
    /// ignored): the "albedo" AOV and the sheet's share of samples.
    pub fn albedo(&self) -> Vec3 {
        let r = hemispherical_average3(|mu| self.reflectance(mu));
        let reflected = if self.reflect { r } else { Vec3::ZERO };
        let transmitted = if self.transmit { Vec3::ONE - r } else { Vec3::ZERO };
        (self.tint * (reflected + transmitted)).min(Vec3::ONE)
    }
}
