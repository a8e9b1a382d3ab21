//! The BSDF of a closure value ([`ClosureSum`]): a weighted sum of lobes with vertical
//! layering, sampled and evaluated as pbrt and Cycles do a lobe list: one term is chosen for
//! sampling by its weight × estimated albedo (× the attenuation of the layers above it), and the
//! whole sum is evaluated for the sample's value and pdf, so MIS sees one BSDF.
//!
//! **Layering.** Term `i` lies under the terms whose bits are set in its `above` mask
//! (`layer(top, base)`). In the default mode, [`LayeringMode::AlbedoScaling`], the light that
//! reaches it is what the terms above did not reflect, as OpenPBR and MaterialX define `layer`:
//! with `a_i(μ) = 1 − Σ_{j above i} w_j a_j(μ) E_j(μ)` (`E_j` the directional albedo of term
//! `j`, [`Lobe::directional_albedo`]; the sum telescopes to `Π (1 − E_layer)` for nested layers),
//! term `i` contributes
//!
//! `w_i f_i(ωo, ωi) a_i(μo) a_i(μi) / N_i`,
//!
//! which is reciprocal (the one-sided OpenPBR form `a_i(μo) f_i` is not). The normalisation
//! `N_i` is the cosine-weighted average of `a_i` for diffuse bases (Kulla and Conty's form: a
//! white Lambert base under a white coat reflects exactly what the coat transmits) and its
//! maximum for the others (a glossy base then never reflects more than under the one-sided
//! form, so energy stays ≤ 1). A transmitting lobe with something under it keeps only its
//! reflection ([`Lobe::covering`]): its transmission is what reaches the base.
//!
//! [`LayeringMode::RandomWalk`] instead follows light between the top and base interfaces
//! (`walk`), the position-free stochastic reference of Guo et al. 2018 and pbrt-v4's
//! `LayeredBxDF`.
//!
//! **Per-term normals.** A term may carry its own shading normal (`with_normal`, MaterialX's
//! per-lobe `normal` inputs, OpenPBR's coat normal; [`TERM_NORMAL`]): it is then evaluated and
//! sampled in a frame about that normal ([`ClosureBsdf::set_term_normals`]), rotated from the
//! shading frame. The attenuation of the terms under it keeps using the shading frame's
//! cosines, and a walk over a stack with a tilted term falls back to albedo scaling.

use crate::abi::{ClosureKind, ClosureSum, ClosureTerm, MAX_CLOSURE_TERMS, TERM_DARKENING, TERM_NORMAL};
use crate::render::material::bsdf::{Bsdf, BsdfSample, finish};
use crate::render::material::frame::Frame;
use crate::render::material::lobes::Lobe;
use glam::{Quat, Vec2, Vec3};

/// How `layer(top, base)` is rendered.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum LayeringMode {
    /// Reciprocal albedo scaling with tabulated top albedos (fast, deterministic).
    #[default]
    AlbedoScaling,
    /// A stochastic random walk between the interfaces (the reference; noisier and slower).
    RandomWalk,
}

impl LayeringMode {
    /// The mode's name in settings (`albedo-scaling`, `random-walk`).
    pub fn name(self) -> &'static str {
        match self {
            LayeringMode::AlbedoScaling => "albedo-scaling",
            LayeringMode::RandomWalk => "random-walk",
        }
    }

    /// Parses a [`LayeringMode::name`].
    pub fn from_name(name: &str) -> Option<LayeringMode> {
        [LayeringMode::AlbedoScaling, LayeringMode::RandomWalk].into_iter().find(|m| m.name() == name)
    }
}

/// One term of a [`ClosureBsdf`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Term {
    pub(crate) lobe: Lobe,
    /// Colour weight, each channel in [0, 1].
    pub(crate) weight: Vec3,
    /// Bits of the terms above this one (indices below it).
    pub(crate) above: u8,
    /// `1 / N_i` per channel (see the module docs); unused without `above`.
    inv_norm: Vec3,
    /// Estimated albedo × weight (max channel): the term's share of samples before layering.
    importance: f32,
    /// The rotation from the shading frame to the frame of the term's own normal, if it has
    /// one that differs ([`ClosureBsdf::set_term_normals`]).
    tilt: Option<Quat>,
    /// The factor the shader multiplied the terms under this one by for its internal
    /// reflections ([`TERM_DARKENING`]; 1: none). Only the random walk reads it.
    pub(crate) darkening: Vec3,
}

impl Term {
    /// The lobe's f(wo, wi) in the term's frame.
    #[inline]
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match self.tilt {
            None => self.lobe.eval(wo, wi),
            Some(q) => self.lobe.eval(q * wo, q * wi),
        }
    }

    /// The lobe's pdf in the term's frame (a rotation keeps solid angles).
    #[inline]
    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match self.tilt {
            None => self.lobe.pdf(wo, wi),
            Some(q) => self.lobe.pdf(q * wo, q * wi),
        }
    }

    /// The lobe's sample in the term's frame, its direction rotated back.
    #[inline]
    fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        match self.tilt {
            None => self.lobe.sample(wo, uc, u),
            Some(q) => {
                let s = self.lobe.sample(q * wo, uc, u)?;
                Some(BsdfSample { wi: (q.conjugate() * s.wi).normalize(), ..s })
            }
        }
    }
}

/// Smallest cosine between `wo` and a term's own normal: a normal tilted further away from the
/// viewer is bent towards it (as shading normals are), so the term never sees `wo` from below.
const MIN_TILTED_COS: f32 = 0.01;

/// The world-space normal a closure term carries, if any (a zero vector is none; the
/// generalized Schlick lobe uses those words for its parameters).
#[inline]
fn term_normal(t: &ClosureTerm) -> Option<Vec3> {
    if t.kind == ClosureKind::GeneralizedSchlick as u32 || t.kind == ClosureKind::None as u32 {
        return None;
    }
    let n = Vec3::from_slice(&t.params[TERM_NORMAL..TERM_NORMAL + 3]);
    (n != Vec3::ZERO && n.is_finite()).then_some(n)
}

/// A term's colour weight as the renderer uses it: each channel clamped to [0, 1], NaN as 0.
#[inline]
fn clamped_weight(t: &ClosureTerm) -> Vec3 {
    Vec3::from_array(t.weight.map(|w| if w.is_nan() { 0.0 } else { w.clamp(0.0, 1.0) }))
}

/// The darkening factor a coat term records ([`TERM_DARKENING`]), each channel in [0, 1]
/// (1: none, also for other kinds and non-finite words).
#[inline]
fn darkening(t: &ClosureTerm) -> Vec3 {
    if t.kind != ClosureKind::Dielectric as u32 {
        return Vec3::ONE;
    }
    let removed = Vec3::from_slice(&t.params[TERM_DARKENING..TERM_DARKENING + 3]);
    if removed.is_finite() { (Vec3::ONE - removed).clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ONE }
}

/// Whether a term is decoded (not empty, some weight).
#[inline]
fn is_live(t: &ClosureTerm) -> bool {
    t.kind != ClosureKind::None as u32 && clamped_weight(t) != Vec3::ZERO
}

/// Points of the 8-point Gauss–Legendre rule on [0, 1] and their weights (summing to 1).
const GAUSS_X: [f32; 8] =
    [0.019_855_07, 0.101_666_76, 0.237_233_8, 0.408_282_68, 0.591_717_3, 0.762_766_2, 0.898_333_24, 0.980_144_9];
const GAUSS_W: [f32; 8] =
    [0.050_614_27, 0.111_190_52, 0.156_853_32, 0.181_341_89, 0.181_341_89, 0.156_853_32, 0.111_190_52, 0.050_614_27];

/// The BSDF of one closure value. Copy and allocation-free; a single unit-weight term behaves
/// exactly as its lobe alone.
#[derive(Clone, Copy, Debug)]
pub struct ClosureBsdf {
    pub(crate) terms: [Term; MAX_CLOSURE_TERMS],
    pub(crate) len: usize,
    /// Whether any term lies under another.
    pub(crate) layered: bool,
    pub(crate) mode: LayeringMode,
}

/// Equal when the used terms are: the unused ones are all empty, and comparing them would cost
/// the integrator's albedo memo a scan of every slot at each first hit.
impl PartialEq for ClosureBsdf {
    fn eq(&self, other: &ClosureBsdf) -> bool {
        self.len == other.len
            && self.layered == other.layered
            && self.mode == other.mode
            && self.terms() == other.terms()
    }
}

impl From<Bsdf> for ClosureBsdf {
    fn from(b: Bsdf) -> ClosureBsdf {
        ClosureBsdf::from_lobes(&[(Lobe::Bsdf(b), Vec3::ONE, 0)], LayeringMode::default())
    }
}

/// An unused slot of [`ClosureBsdf::terms`].
const EMPTY_TERM: Term = Term {
    lobe: Lobe::Bsdf(Bsdf::Black),
    weight: Vec3::ZERO,
    above: 0,
    inv_norm: Vec3::ZERO,
    importance: 0.0,
    tilt: None,
    darkening: Vec3::ONE,
};

/// Attenuations `a_i(μ)` of every term (see the module docs).
type Attenuation = [Vec3; MAX_CLOSURE_TERMS];

impl ClosureBsdf {
    /// Decodes a closure value: empty terms (kind `None`, zero or non-finite weight) are
    /// skipped, weights clamped to [0, 1] per channel, parameters sanitised per lobe.
    pub fn from_sum(sum: &ClosureSum, mode: LayeringMode) -> ClosureBsdf {
        let mut b = ClosureBsdf::empty(mode);
        b.set_sum(sum, mode);
        b
    }

    /// [`ClosureBsdf::from_sum`] in place: the integrator decodes each shading point's closure
    /// into the slot it keeps, rather than moving a value of all [`MAX_CLOSURE_TERMS`] terms.
    pub fn set_sum(&mut self, sum: &ClosureSum, mode: LayeringMode) {
        self.set_terms(&sum.terms, mode);
    }

    /// [`ClosureBsdf::set_sum`] of the value whose terms are `terms` and then empty ones (a
    /// shader's leading terms: [`crate::abi::MaterialCode::surface_terms`]).
    pub fn set_terms(&mut self, terms: &[ClosureTerm], mode: LayeringMode) {
        let clamped = clamped_weight;
        // The terms that are not empty; most materials have one, decoded without the general
        // renumbering below.
        let mut live = 0u32;
        for (k, t) in terms.iter().enumerate().take(MAX_CLOSURE_TERMS) {
            if is_live(t) {
                live |= 1 << k;
            }
        }
        if live.count_ones() <= 1 {
            match terms.get(live.trailing_zeros() as usize) {
                Some(t) => self.set_lobes(&[(Lobe::from_term(t), clamped(t), 0)], mode),
                None => self.set_lobes(&[], mode),
            }
            return;
        }
        let mut lobes = [(Lobe::Bsdf(Bsdf::Black), Vec3::ZERO, 0u8); MAX_CLOSURE_TERMS];
        let mut position = [usize::MAX; MAX_CLOSURE_TERMS];
        let mut len = 0;
        for (k, t) in terms.iter().enumerate().take(MAX_CLOSURE_TERMS) {
            if live & (1 << k) == 0 {
                continue;
            }
            let weight = clamped(t);
            // Bits of terms that were skipped, or are not above, drop out when renumbering.
            let mut above = 0u8;
            for (j, &p) in position.iter().enumerate().take(k) {
                if t.above & (1 << j) != 0 && p != usize::MAX {
                    above |= 1 << p;
                }
            }
            position[k] = len;
            lobes[len] = (Lobe::from_term(t), weight, above);
            len += 1;
        }
        self.set_lobes(&lobes[..len], mode);
        if self.layered && mode == LayeringMode::RandomWalk {
            for (k, &p) in position.iter().enumerate() {
                if p < len {
                    self.terms[p].darkening = darkening(&terms[k]);
                }
            }
        }
    }

    /// The closure with no terms (black).
    pub fn empty(mode: LayeringMode) -> ClosureBsdf {
        ClosureBsdf { terms: [EMPTY_TERM; MAX_CLOSURE_TERMS], len: 0, layered: false, mode }
    }

    /// Builds the BSDF of `(lobe, weight, above)` terms (at most [`MAX_CLOSURE_TERMS`]).
    pub fn from_lobes(lobes: &[(Lobe, Vec3, u8)], mode: LayeringMode) -> ClosureBsdf {
        let mut b = ClosureBsdf::empty(mode);
        b.set_lobes(lobes, mode);
        b
    }

    /// [`ClosureBsdf::from_lobes`] in place. Only the slots in use before or after are
    /// written: the unused ones stay empty.
    pub fn set_lobes(&mut self, lobes: &[(Lobe, Vec3, u8)], mode: LayeringMode) {
        let b = self;
        let old_len = b.len;
        (b.len, b.layered, b.mode) = (0, false, mode);
        let mut covered = 0u8;
        for &(_, _, above) in lobes {
            covered |= above;
        }
        for (i, &(lobe, weight, above)) in lobes.iter().take(MAX_CLOSURE_TERMS).enumerate() {
            let lobe = if covered & (1 << i) != 0 { lobe.covering() } else { lobe };
            let above = above & ((1u16 << i) - 1) as u8;
            b.layered |= above != 0;
            b.terms[i] =
                Term { lobe, weight, above, inv_norm: Vec3::ONE, importance: 0.0, tilt: None, darkening: Vec3::ONE };
            b.len = i + 1;
        }
        for t in b.terms.iter_mut().take(old_len).skip(b.len) {
            *t = EMPTY_TERM;
        }
        if b.len == 1 && b.terms[0].weight == Vec3::ONE {
            // A single lobe samples itself; its albedo is not needed.
            b.terms[0].importance = 1.0;
            return;
        }
        for i in 0..b.len {
            let t = &mut b.terms[i];
            t.importance = (t.weight * t.lobe.albedo()).max_element().max(1e-4 * t.weight.max_element());
        }
        if b.layered {
            // N_i by quadrature over μ (average) and at the nodes and μ = 1 (maximum).
            let mut average = [Vec3::ZERO; MAX_CLOSURE_TERMS];
            let mut maximum = b.attenuation(1.0);
            for (x, w) in GAUSS_X.iter().zip(GAUSS_W) {
                let a = b.attenuation(*x);
                for i in 0..b.len {
                    average[i] += 2.0 * w * x * a[i];
                    maximum[i] = maximum[i].max(a[i]);
                }
            }
            for i in 0..b.len {
                let t = &mut b.terms[i];
                let norm = if t.lobe.is_diffuse() { average[i] } else { maximum[i] };
                t.inv_norm = Vec3::select(norm.cmpgt(Vec3::splat(1e-6)), norm.recip(), Vec3::ZERO);
            }
        }
    }

    /// Gives the terms of `sum` (as [`ClosureBsdf::set_sum`] decoded them) that carry their own
    /// world-space normal a frame about it: `frame` is the shading frame and `wo` the outgoing
    /// direction in it. A normal on the far side of the frame is flipped (as the shading
    /// normal is), one tilted away from `wo` bent towards it ([`MIN_TILTED_COS`]); a normal
    /// within 1e-6 of the shading normal is none, so such a closure is today's bit for bit.
    pub fn set_term_normals(&mut self, terms: &[ClosureTerm], frame: &Frame, wo: Vec3) {
        // Most closures have none: one pass over the words before any decoding.
        if !terms.iter().any(|t| term_normal(t).is_some()) {
            return;
        }
        let mut i = 0;
        for t in terms.iter() {
            if !is_live(t) {
                continue;
            }
            if let Some(n) = term_normal(t)
                && i < self.len
            {
                let mut n = frame.to_local(n.normalize());
                if n.z < 0.0 {
                    n = -n;
                }
                if n.z < 1.0 - 1e-6 {
                    let side = if wo.z < 0.0 { -1.0 } else { 1.0 };
                    let cos = n.dot(wo) * side;
                    if cos < MIN_TILTED_COS {
                        n = (n + wo * (side * (MIN_TILTED_COS - cos))).normalize();
                    }
                    self.terms[i].tilt = Some(Quat::from_rotation_arc(n, Vec3::Z));
                }
            }
            i += 1;
        }
    }

    /// The terms.
    pub(crate) fn terms(&self) -> &[Term] {
        &self.terms[..self.len]
    }

    /// `a_i(μ)` of every term.
    #[inline]
    fn attenuation(&self, mu: f32) -> Attenuation {
        let mut a = [Vec3::ONE; MAX_CLOSURE_TERMS];
        let mu = mu.abs().min(1.0);
        for i in 0..self.len {
            let above = self.terms[i].above;
            if above == 0 {
                continue;
            }
            let mut att = Vec3::ONE;
            for (j, (t, a_j)) in self.terms[..i].iter().zip(&a[..i]).enumerate() {
                if above & (1 << j) != 0 {
                    att -= t.weight * *a_j * t.lobe.directional_albedo(mu);
                }
            }
            a[i] = att.max(Vec3::ZERO);
        }
        a
    }

    /// Whether the closure is a single unit-weight lobe (every method then delegates to it).
    #[inline]
    fn single(&self) -> Option<&Lobe> {
        let t = &self.terms[0];
        (self.len == 1 && t.weight == Vec3::ONE && t.tilt.is_none()).then_some(&t.lobe)
    }

    /// The factor `w_i a_i(μo) a_i(μi) / N_i` of term `i`.
    #[inline]
    fn factor(&self, i: usize, ao: &Attenuation, ai: &Attenuation) -> Vec3 {
        let t = &self.terms[i];
        if t.above == 0 { t.weight } else { t.weight * ao[i] * ai[i] * t.inv_norm }
    }

    /// Probabilities of sampling each term from `wo`: importance × attenuation at `μo`.
    #[inline]
    fn probabilities(&self, ao: &Attenuation) -> [f32; MAX_CLOSURE_TERMS] {
        let mut p = [0.0; MAX_CLOSURE_TERMS];
        let mut total = 0.0;
        for i in 0..self.len {
            let t = &self.terms[i];
            p[i] = if t.above == 0 { t.importance } else { t.importance * ao[i].max_element() };
            total += p[i];
        }
        if total > 0.0 {
            for x in &mut p[..self.len] {
                *x /= total;
            }
        }
        p
    }

    /// f(wo, wi), local frame, not multiplied by cos; 0 for delta lobes.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if let Some(lobe) = self.single() {
            return lobe.eval(wo, wi);
        }
        if self.layered && self.mode == LayeringMode::RandomWalk {
            return walk::eval(self, wo, wi);
        }
        self.eval_scaled(wo, wi)
    }

    /// The albedo-scaling sum (see the module docs).
    pub(crate) fn eval_scaled(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let (ao, ai) = self.attenuations(wo, wi);
        let mut f = Vec3::ZERO;
        for i in 0..self.len {
            f += self.terms[i].eval(wo, wi) * self.factor(i, &ao, &ai);
        }
        f
    }

    #[inline]
    fn attenuations(&self, wo: Vec3, wi: Vec3) -> (Attenuation, Attenuation) {
        if self.layered {
            (self.attenuation(wo.z), self.attenuation(wi.z))
        } else {
            ([Vec3::ONE; MAX_CLOSURE_TERMS], [Vec3::ONE; MAX_CLOSURE_TERMS])
        }
    }

    /// Solid-angle pdf of [`ClosureBsdf::sample`] (non-delta part).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if let Some(lobe) = self.single() {
            return lobe.pdf(wo, wi);
        }
        if self.layered && self.mode == LayeringMode::RandomWalk {
            return walk::pdf(self, wo, wi);
        }
        self.pdf_mixture(wo, wi)
    }

    /// `Σ p_i pdf_i`: the pdf of choosing a term and sampling it.
    pub(crate) fn pdf_mixture(&self, wo: Vec3, wi: Vec3) -> f32 {
        let ao = if self.layered { self.attenuation(wo.z) } else { [Vec3::ONE; MAX_CLOSURE_TERMS] };
        let p = self.probabilities(&ao);
        (0..self.len).filter(|&i| p[i] > 0.0).map(|i| p[i] * self.terms[i].pdf(wo, wi)).sum()
    }

    /// Samples wi: `uc` picks the term (then, rescaled, the term's own component), `u` the
    /// direction. A delta term's sample carries that term alone; otherwise the whole sum is
    /// evaluated.
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if let Some(lobe) = self.single() {
            return lobe.sample(wo, uc, u);
        }
        if !(uc.is_finite() && wo.is_finite() && wo.z != 0.0) {
            return None;
        }
        if self.layered && self.mode == LayeringMode::RandomWalk {
            return walk::sample(self, wo, uc, u);
        }
        self.sample_scaled(wo, uc, u)
    }

    /// Albedo scaling's sampling: a term by [`ClosureBsdf::probabilities`], then the sum.
    pub(crate) fn sample_scaled(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        let ao = if self.layered { self.attenuation(wo.z) } else { [Vec3::ONE; MAX_CLOSURE_TERMS] };
        let p = self.probabilities(&ao);
        let (k, uc) = pick(&p[..self.len], uc)?;
        let s = self.terms[k].sample(wo, uc, u)?;
        if s.delta {
            let ai = if self.layered { self.attenuation(s.wi.z) } else { [Vec3::ONE; MAX_CLOSURE_TERMS] };
            return finish(s.wi, s.f * self.factor(k, &ao, &ai), s.pdf * p[k], true);
        }
        finish(s.wi, self.eval_scaled(wo, s.wi), self.pdf_mixture(wo, s.wi), false)
    }

    /// Approximate hemispherical albedo colour (the "albedo" AOV): the weighted sum of the
    /// terms' albedos, layered terms scaled by their average attenuation.
    pub fn albedo(&self) -> Vec3 {
        if let Some(lobe) = self.single() {
            return lobe.albedo();
        }
        let mut average = [Vec3::ZERO; MAX_CLOSURE_TERMS];
        if self.layered {
            for (x, w) in GAUSS_X.iter().zip(GAUSS_W) {
                let a = self.attenuation(*x);
                for i in 0..self.len {
                    average[i] += 2.0 * w * x * a[i];
                }
            }
        }
        let mut albedo = Vec3::ZERO;
        for (i, t) in self.terms().iter().enumerate() {
            let scale = if t.above == 0 { Vec3::ONE } else { average[i] };
            albedo += t.weight * scale * t.lobe.albedo();
        }
        albedo.clamp(Vec3::ZERO, Vec3::ONE)
    }

    /// [`ClosureBsdf::albedo`] when it costs nothing to compute: a single unit-weight lobe
    /// whose albedo is a parameter ([`Lobe::stored_albedo`]).
    pub fn stored_albedo(&self) -> Option<Vec3> {
        self.single().and_then(Lobe::stored_albedo)
    }

    /// Whether [`ClosureBsdf::sample`] reads `uc`: to choose between terms, or for the one
    /// term's own choice ([`Lobe::reads_choice`]). A caller may pass any number in [0, 1) where
    /// it does not (a Lambert surface draws no lobe number).
    pub fn reads_choice(&self) -> bool {
        self.len != 1 || self.terms[0].lobe.reads_choice()
    }

    /// Whether a non-delta term transmits (light sampling must then cover both sides).
    pub fn transmits(&self) -> bool {
        self.terms().iter().any(|t| t.lobe.transmits())
    }

    /// Whether a term tells inside from outside, so the shading frame keeps the outward side.
    pub fn oriented(&self) -> bool {
        self.terms().iter().any(|t| t.lobe.oriented())
    }

    /// The radiance compression of `wi` (see [`Bsdf::compression`]): the first transmitting
    /// term's for a transmitted direction, 1 for reflection.
    pub fn compression(&self, wo: Vec3, wi: Vec3) -> f32 {
        match self.terms().iter().find(|t| t.lobe.oriented()) {
            Some(t) => t.lobe.compression(wo, wi),
            None => 1.0,
        }
    }

    /// True when no term has a non-delta part (NEE cannot contribute).
    pub fn is_delta(&self) -> bool {
        self.terms().iter().all(|t| t.lobe.is_delta())
    }
}

/// Picks an index by the probabilities `p` with `uc`, and rescales `uc` to [0, 1) within it.
#[inline]
pub(crate) fn pick(p: &[f32], uc: f32) -> Option<(usize, f32)> {
    let mut start = 0.0;
    let last = p.iter().rposition(|&x| x > 0.0)?;
    for (i, &x) in p.iter().enumerate() {
        if x > 0.0 && (uc < start + x || i == last) {
            return Some((i, ((uc - start) / x).clamp(0.0, 1.0 - f32::EPSILON / 2.0)));
        }
        start += x;
    }
    None
}

pub mod walk {
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
}
