//! `layer(top, base)` by a stochastic random walk between the two interfaces: the
//! position-free layered BSDF of Guo et al. 2018 as pbrt-v4's `LayeredBxDF` computes it (no
//! medium between the interfaces, so no thickness or position enters).
//!
//! The walk covers the stack OpenPBR and MaterialX build: one dielectric term on top (a
//! `dielectric_bsdf` coat, weighted or not) over the terms under it, with terms beside the
//! stack added as they are. The coat becomes a rough dielectric interface (reflection from
//! outside keeps its tint; transmission and internal reflection are untinted), the base is the
//! weighted sum of the terms under it, and a weighted coat `w` is `w · walk + (1 − w) · base`
//! (what albedo scaling computes too). Other stacks (several tops, nested layers, a
//! non-dielectric top, a transmitting base) fall back to albedo scaling. A coat that
//! records a darkening factor (`with_darkening`, OpenPBR's `coat_darkening`: the shader's
//! stand-in for the internal reflections albedo scaling omits) has it divided back out of
//! the base's weights, since the walk follows those reflections itself.
//!
//! `eval` is an unbiased stochastic estimate (one walk, next-event connections at every base
//! bounce, MIS between connecting through the coat and through the base as pbrt-v4 does),
//! seeded by the directions so repeated calls agree. `sample` walks until light leaves and
//! returns its exact throughput; the pdf it reports, like `pdf`, is a proxy (the albedo-scaling
//! mixture's pdf with a tenth of cosine-weighted directions), which MIS weights may use freely.

use super::{ClosureBsdf, pick};
use crate::render::material::bsdf::{Bsdf, BsdfSample, finish, flip_z, reflect, refract};
use crate::render::material::lobes::{Fresnel, Lobe};
use crate::render::material::microfacet::{Ggx, fresnel_dielectric};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// Most bounces between the interfaces (pbrt-v4's default).
const MAX_DEPTH: u32 = 10;

/// The walk's view of a stack: the top term, its interface, and the base terms' mask.
struct Stack {
    top: usize,
    interface: Interface,
    tint: Vec3,
    base: u8,
    /// `1 / darkening` of the top ([`super::Term::darkening`]): the walk follows the
    /// coat's internal reflections itself, so the base terms get back the weight the
    /// shader's darkening (standing in for them under albedo scaling) took away.
    undarken: Vec3,
}

impl Stack {
    /// The weight of base term `t` as the walk uses it (undarkened, at most 1).
    #[inline]
    fn base_weight(&self, t: &super::Term) -> Vec3 {
        (t.weight * self.undarken).min(Vec3::ONE)
    }
}

/// A rough dielectric interface, outside above (`z > 0`), index `eta` below.
#[derive(Clone, Copy)]
struct Interface {
    ggx: Ggx,
    eta: f32,
}

/// A small deterministic random stream (PCG32) for one estimate.
struct Rng(u64);

impl Rng {
    fn seeded(a: Vec3, b: Vec3, salt: u32) -> Rng {
        let mut h = 0x9e37_79b9_7f4a_7c15u64 ^ salt as u64;
        for x in [a.x, a.y, a.z, b.x, b.y, b.z] {
            h = (h ^ x.to_bits() as u64).wrapping_mul(0x100_0000_01b3).rotate_left(29);
        }
        Rng(h)
    }
    fn f32(&mut self) -> f32 {
        let old = self.0;
        self.0 = old.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let x = (((old >> 18) ^ old) >> 27) as u32;
        let r = x.rotate_right((old >> 59) as u32);
        (r >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
    fn vec2(&mut self) -> Vec2 {
        Vec2::new(self.f32(), self.f32())
    }
}

impl Interface {
    fn glass(&self) -> Bsdf {
        Bsdf::Glass { tint: Vec3::ONE, ggx: self.ggx, eta: self.eta }
    }

    /// f of the interface (both sides; transmission with its radiance compression, which
    /// cancels between entering and leaving).
    fn f(&self, wo: Vec3, wi: Vec3) -> f32 {
        self.glass().eval(wo, wi).x
    }

    /// Pdf of [`Interface::sample`] restricted to transmission (`transmit`) or reflection.
    fn pdf(&self, wo: Vec3, wi: Vec3, transmit: bool) -> f32 {
        if (wo.z * wi.z < 0.0) != transmit || self.ggx.is_smooth() {
            return 0.0;
        }
        let etap = if !transmit {
            1.0
        } else if wo.z > 0.0 {
            self.eta
        } else {
            1.0 / self.eta
        };
        let Some(mut m) = (wi * etap + wo).try_normalize() else { return 0.0 };
        if m.z < 0.0 {
            m = -m;
        }
        let f = fresnel_dielectric(wo.dot(m), self.eta);
        let chosen = if transmit { 1.0 - f } else { f };
        if chosen <= 0.0 { 0.0 } else { self.glass().pdf(wo, wi) / chosen }
    }

    /// Samples reflection or transmission only: `(wi, f, pdf, delta)`.
    fn sample(&self, wo: Vec3, u: Vec2, transmit: bool) -> Option<(Vec3, f32, f32, bool)> {
        let smooth = self.ggx.is_smooth();
        let m = if smooth { Vec3::Z } else { self.ggx.sample_visible(wo, u)? };
        let f = fresnel_dielectric(wo.dot(m), self.eta);
        let wi = if transmit {
            let (wi, _) = refract(wo, m, self.eta)?;
            (wi.z * wo.z < 0.0).then_some(wi)?
        } else {
            let wi = reflect(wo, m);
            (wi.z * wo.z > 0.0).then_some(wi)?
        };
        if smooth {
            let etap = if wo.z > 0.0 { self.eta } else { 1.0 / self.eta };
            let value = if transmit { (1.0 - f) / (etap * etap) } else { f };
            return (value > 0.0).then_some((wi, value / wi.z.abs(), 1.0, true));
        }
        let pdf = self.pdf(wo, wi, transmit);
        (pdf > 0.0).then_some((wi, self.f(wo, wi), pdf, false))
    }

    /// Samples both reflection and transmission, choosing by Fresnel: `(wi, f, pdf, delta)`.
    fn sample_any(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<(Vec3, f32, f32, bool)> {
        let s = self.glass().sample(wo, uc, u)?;
        Some((s.wi, s.f.x, s.pdf, s.delta))
    }
}

/// The stack the walk handles in `b`, or `None` (then albedo scaling is used).
fn stack(b: &ClosureBsdf) -> Option<Stack> {
    let terms = b.terms();
    let covered: u8 = terms.iter().fold(0, |m, t| m | t.above);
    if covered.count_ones() != 1 || terms.iter().any(|t| t.tilt.is_some()) {
        return None;
    }
    let top = covered.trailing_zeros() as usize;
    let Lobe::Specular { fresnel: Fresnel::Dielectric { eta }, tint, ggx } = terms[top].lobe else { return None };
    let mut base = 0u8;
    for (i, t) in terms.iter().enumerate() {
        if t.above != 0 {
            if t.above != covered || t.lobe.transmits() || t.lobe.oriented() {
                return None;
            }
            base |= 1 << i;
        }
    }
    let darkening = terms[top].darkening;
    let undarken = Vec3::select(darkening.cmpgt(Vec3::splat(1e-3)), darkening.recip(), Vec3::ONE);
    (eta > 1.0).then_some(Stack { top, interface: Interface { ggx, eta }, tint, base, undarken })
}

/// The base: the weighted sum of the terms under the top, evaluated inside the slab.
fn base_f(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> Vec3 {
    let mut f = Vec3::ZERO;
    for (i, t) in b.terms().iter().enumerate() {
        if s.base & (1 << i) != 0 {
            f += s.base_weight(t) * t.lobe.eval(wo, wi);
        }
    }
    f
}

/// Sampling probabilities of the base terms (weight × albedo estimate).
fn base_probabilities(b: &ClosureBsdf, s: &Stack) -> [f32; 8] {
    let mut p = [0.0; 8];
    let mut total = 0.0;
    for (i, t) in b.terms().iter().enumerate() {
        if s.base & (1 << i) != 0 {
            p[i] = (s.base_weight(t) * t.lobe.albedo()).max_element().max(1e-4);
            total += p[i];
        }
    }
    p.iter_mut().for_each(|x| *x /= total);
    p
}

fn base_pdf(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> f32 {
    let p = base_probabilities(b, s);
    b.terms().iter().enumerate().filter(|&(i, _)| p[i] > 0.0).map(|(i, t)| p[i] * t.lobe.pdf(wo, wi)).sum()
}

/// Samples the base: `(wi, f, pdf, delta)` where a delta sample carries its own term only.
fn base_sample(b: &ClosureBsdf, s: &Stack, wo: Vec3, rng: &mut Rng) -> Option<(Vec3, Vec3, f32, bool)> {
    let p = base_probabilities(b, s);
    let (k, uc) = pick(&p, rng.f32())?;
    let t = &b.terms()[k];
    let bs = t.lobe.sample(wo, uc, rng.vec2())?;
    if bs.delta {
        return Some((bs.wi, bs.f * s.base_weight(t), bs.pdf * p[k], true));
    }
    let pdf = base_pdf(b, s, wo, bs.wi);
    (pdf > 0.0).then_some((bs.wi, base_f(b, s, wo, bs.wi), pdf, false))
}

fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

/// The terms beside the stack and the untouched share `(1 − w)` of the base.
fn beside(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> Vec3 {
    let w = b.terms()[s.top].weight;
    let mut f = (Vec3::ONE - w) * base_f(b, s, wo, wi);
    for (i, t) in b.terms().iter().enumerate() {
        if i != s.top && s.base & (1 << i) == 0 {
            f += t.weight * t.lobe.eval(wo, wi);
        }
    }
    f
}

/// One-sample estimate of the layered stack's f(wo, wi) (pbrt-v4 `LayeredBxDF::f`, one
/// sample, reflection: the base is opaque).
fn layered_f(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> Vec3 {
    let (wo, wi) = if wo.z < 0.0 { (flip_z(wo), flip_z(wi)) } else { (wo, wi) };
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Vec3::ZERO;
    }
    let top = s.interface;
    let mut f = s.tint * top.f(wo, wi);
    let mut rng = Rng::seeded(wo, wi, 0x51);
    let Some((wos, fos, pos, _)) = top.sample(wo, rng.vec2(), true) else { return f };
    let Some((wis, fis, pis, _)) = top.sample(wi, rng.vec2(), true) else { return f };
    let mut beta = Vec3::splat(fos * wos.z.abs() / pos);
    let mut w = wos; // travelling down, inside
    let top_specular = top.ggx.is_smooth();
    for depth in 0..MAX_DEPTH {
        if depth > 3 && beta.max_element() < 0.25 {
            let q = (1.0 - beta.max_element()).max(0.0);
            if rng.f32() < q {
                break;
            }
            beta /= 1.0 - q;
        }
        // At the base: connect to wi through the coat along the presampled `wis`.
        let up = -w;
        let fb = base_f(b, s, up, -wis);
        if fb != Vec3::ZERO {
            let weight = if top_specular { 1.0 } else { power_heuristic(pis, base_pdf(b, s, up, -wis)) };
            // `fis` was sampled from `wi`'s side; light leaving the coat gains back the η² its
            // entry took (the transmission's radiance compression, reversed).
            f += beta * fb * (wis.z.abs() * weight * fis / pis * top.eta * top.eta);
        }
        let Some((wb, fbs, pb, delta)) = base_sample(b, s, up, &mut rng) else { break };
        if pb <= 0.0 || wb.z <= 0.0 {
            break;
        }
        beta *= fbs * (wb.z.abs() / pb);
        // Connect through the coat along the base's sample.
        if !top_specular {
            let fe = top.f(-wb, wi);
            if fe > 0.0 {
                let weight = if delta { 1.0 } else { power_heuristic(pb, top.pdf(wi, -wb, true)) };
                f += beta * (fe * weight);
            }
        }
        // Reflect off the coat's underside, back down.
        let Some((wr, fr, pr, _)) = top.sample(-wb, rng.vec2(), false) else { break };
        beta *= fr * wr.z.abs() / pr;
        w = wr;
        if !beta.is_finite() {
            return Vec3::ZERO;
        }
    }
    if f.is_finite() { f } else { Vec3::ZERO }
}

pub(crate) fn eval(b: &ClosureBsdf, wo: Vec3, wi: Vec3) -> Vec3 {
    let Some(s) = stack(b) else { return b.eval_scaled(wo, wi) };
    let w = b.terms()[s.top].weight;
    w * layered_f(b, &s, wo, wi) + beside(b, &s, wo, wi)
}

/// The pdf proxy (see the module docs).
pub(crate) fn pdf(b: &ClosureBsdf, wo: Vec3, wi: Vec3) -> f32 {
    if stack(b).is_none() {
        return b.pdf_mixture(wo, wi);
    }
    let cosine = if wo.z * wi.z > 0.0 { wi.z.abs() * FRAC_1_PI } else { 0.0 };
    0.9 * b.pdf_mixture(wo, wi) + 0.1 * cosine
}

pub(crate) fn sample(b: &ClosureBsdf, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
    let Some(s) = stack(b) else { return albedo_scaling_sample(b, wo, uc, u) };
    // Choose between the stack (by its weight) and what lies beside it (by its albedo).
    let w = b.terms()[s.top].weight.max_element();
    let mut beside_importance = 0.0;
    for (i, t) in b.terms().iter().enumerate() {
        if i != s.top && s.base & (1 << i) == 0 {
            beside_importance += (t.weight * t.lobe.albedo()).max_element();
        }
    }
    let base_rest = (1.0 - w) * b.terms().iter().enumerate().filter(|(i, _)| s.base & (1 << i) != 0).count() as f32;
    let p_stack =
        if beside_importance + base_rest <= 0.0 { 1.0 } else { (w / (w + beside_importance + base_rest)).max(0.1) };
    let flip = wo.z < 0.0;
    let wo_up = if flip { flip_z(wo) } else { wo };
    let mut rng = Rng::seeded(wo, Vec3::new(uc, u.x, u.y), 0xa7);
    let walked = if uc < p_stack {
        walk(b, &s, wo_up, &mut rng)
            .map(|(wi, weight, delta)| (wi, weight * b.terms()[s.top].weight / p_stack, delta))
    } else {
        // One of the terms beside (or the base's untouched share): sample the mixture, weigh by eval.
        let bs = b.sample_scaled(wo_up, rng.f32(), rng.vec2())?;
        let p = b.pdf_mixture(wo_up, bs.wi);
        if bs.delta || p <= 0.0 {
            return None;
        }
        let weight = beside(b, &s, wo_up, bs.wi) * bs.wi.z.abs() / p;
        Some((bs.wi, weight / (1.0 - p_stack), false))
    };
    let (wi, weight, delta) = walked?;
    let wi = if flip { flip_z(wi) } else { wi };
    if delta {
        return finish(wi, weight / wi.z.abs(), 1.0, true);
    }
    let p = pdf(b, wo, wi);
    finish(wi, weight * p / wi.z.abs(), p, false)
}

/// The random walk from `wo` (up): `(wi, f |cos| / pdf, delta)` once light leaves the top.
fn walk(b: &ClosureBsdf, s: &Stack, wo: Vec3, rng: &mut Rng) -> Option<(Vec3, Vec3, bool)> {
    let top = s.interface;
    let (w0, f0, p0, mut delta) = top.sample_any(wo, rng.f32(), rng.vec2())?;
    if w0.z > 0.0 {
        return Some((w0, s.tint * (f0 * w0.z / p0), delta));
    }
    let mut beta = Vec3::splat(f0 * w0.z.abs() / p0);
    let mut w = w0;
    for depth in 0..MAX_DEPTH * 2 {
        if depth > 3 && beta.max_element() < 0.25 {
            let q = (1.0 - beta.max_element()).max(0.0);
            if rng.f32() < q {
                return None;
            }
            beta /= 1.0 - q;
        }
        if w.z < 0.0 {
            // At the base, reflect up.
            let (wb, fb, pb, d) = base_sample(b, s, -w, rng)?;
            if wb.z <= 0.0 || pb <= 0.0 {
                return None;
            }
            beta *= fb * (wb.z / pb);
            delta &= d;
            w = wb;
        } else {
            // At the coat from below: reflect down or leave.
            let (wt, ft, pt, d) = top.sample_any(-w, rng.f32(), rng.vec2())?;
            beta *= ft * wt.z.abs() / pt;
            delta &= d;
            if wt.z > 0.0 {
                return beta.is_finite().then_some((wt, beta, delta));
            }
            w = wt;
        }
    }
    None
}

/// Albedo scaling's own sampling, for stacks the walk does not handle.
fn albedo_scaling_sample(b: &ClosureBsdf, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
    b.sample_scaled(wo, uc, u)
}

/// Directional albedo of `layer(top, base)` in either mode, by sampling (for the chart and
/// the tests): mean of the throughput weights of `n` samples from `cos θo = mu`.
pub fn directional_albedo(b: &ClosureBsdf, mu: f32, n: usize, seed: u64) -> f32 {
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let mut rng = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
    let mut sum = 0.0f64;
    for _ in 0..n {
        let u = Vec2::new(rng.f32(), rng.f32());
        if let Some(s) = b.sample(wo, rng.f32(), u) {
            sum += (s.f.x * s.wi.z.abs() / s.pdf) as f64;
        }
    }
    (sum / n as f64) as f32
}
