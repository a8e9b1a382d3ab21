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
//!
//! **Per-term tangents.** An anisotropic GGX term (`with_anisotropy`, [`TERM_ASPECT`]) is
//! stretched along its own world-space tangent ([`TERM_TANGENT`]): the shading frame turns
//! about its normal so that its first tangent is the first anisotropic term's
//! ([`ClosureBsdf::set_term_frames`]), and a term whose tangent differs from it (another
//! tangent, or one tilted by the term's own normal, projected) turns about its normal in its
//! own frame. The layering tables read the mean width `√(αx αy)`.

use crate::abi::{
    ClosureKind, ClosureSum, ClosureTerm, MAX_CLOSURE_TERMS, TERM_ASPECT, TERM_DARKENING, TERM_NORMAL, TERM_TANGENT,
};
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
    /// one that differs, or a tangent that differs from the shading frame's
    /// ([`ClosureBsdf::set_term_frames`]).
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

/// The GGX aspect `√(αx / αy)` a closure term carries ([`TERM_ASPECT`]), if it is not
/// isotropic (0, 1 and non-finite words are isotropic).
#[inline]
fn term_aspect(t: &ClosureTerm) -> Option<f32> {
    let a = t.params[TERM_ASPECT];
    (a.is_finite() && a > 0.0 && a != 1.0).then_some(a)
}

/// The world-space tangent a closure term carries ([`TERM_TANGENT`]), if any (zero: none).
#[inline]
fn term_tangent(t: &ClosureTerm) -> Option<Vec3> {
    let v = Vec3::from_slice(&t.params[TERM_TANGENT..TERM_TANGENT + 3]);
    (v != Vec3::ZERO && v.is_finite()).then_some(v)
}

/// A term's lobe, stretched by its aspect when it has one, and whether the term may want a
/// frame of its own (it carries an aspect or a normal: [`ClosureBsdf::set_term_frames`]).
#[inline]
fn decode(t: &ClosureTerm) -> (Lobe, bool) {
    let lobe = Lobe::from_term(t);
    match term_aspect(t) {
        Some(aspect) => (lobe.with_aspect(aspect), true),
        None => (lobe, term_normal(t).is_some()),
    }
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
    /// The stack the random walk follows, found once when the closure is decoded (`None` in
    /// albedo-scaling mode, without layers, or where the walk falls back to albedo scaling).
    pub(crate) walk: Option<walk::Stack>,
    /// Whether a term may want a frame of its own (an aspect or a normal), found while
    /// decoding: without one [`ClosureBsdf::set_term_frames`] has nothing to do, and most
    /// shading points skip it without scanning the terms again.
    own_frames: bool,
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
                Some(t) => {
                    let (lobe, own_frame) = decode(t);
                    self.set_single(lobe, clamped(t), mode);
                    self.own_frames = own_frame;
                }
                None => {
                    self.set_lobes_finding(&[], mode, true);
                    self.own_frames = false;
                }
            }
            return;
        }
        let mut lobes = [(Lobe::Bsdf(Bsdf::Black), Vec3::ZERO, 0u8); MAX_CLOSURE_TERMS];
        let mut position = [usize::MAX; MAX_CLOSURE_TERMS];
        let mut len = 0;
        let mut own_frames = false;
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
            let (lobe, own_frame) = decode(t);
            own_frames |= own_frame;
            lobes[len] = (lobe, weight, above);
            len += 1;
        }
        self.set_lobes_finding(&lobes[..len], mode, false);
        self.own_frames = own_frames;
        if self.layered && mode == LayeringMode::RandomWalk {
            for (k, &p) in position.iter().enumerate() {
                if p < len {
                    self.terms[p].darkening = darkening(&terms[k]);
                }
            }
            // The walk's stack reads the darkening.
            self.walk = walk::stack(self);
        }
    }

    /// The closure with no terms (black).
    pub fn empty(mode: LayeringMode) -> ClosureBsdf {
        ClosureBsdf {
            terms: [EMPTY_TERM; MAX_CLOSURE_TERMS],
            len: 0,
            layered: false,
            mode,
            walk: None,
            own_frames: false,
        }
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
        self.set_lobes_finding(lobes, mode, true);
        // Lobes carry no term words: `set_term_frames` looks at whatever it is given.
        self.own_frames = true;
    }

    /// [`ClosureBsdf::set_lobes`] of one lobe under nothing, written straight into the first
    /// slot: the general path's copies of the lobe list and scans for layers cost a Lambert
    /// shading point more than its own sampling.
    #[inline]
    fn set_single(&mut self, lobe: Lobe, weight: Vec3, mode: LayeringMode) {
        let old_len = self.len;
        // A single unit-weight lobe samples itself; its albedo is not needed.
        let importance = if weight == Vec3::ONE {
            1.0
        } else {
            (weight * lobe.albedo()).max_element().max(1e-4 * weight.max_element())
        };
        self.terms[0] =
            Term { lobe, weight, above: 0, inv_norm: Vec3::ONE, importance, tilt: None, darkening: Vec3::ONE };
        (self.len, self.layered, self.mode, self.walk) = (1, false, mode, None);
        if old_len > 1 {
            self.terms[1..old_len].fill(EMPTY_TERM);
        }
    }

    /// [`ClosureBsdf::set_lobes`], finding the walk's stack or not (`set_terms` finds it once
    /// the darkening is known).
    fn set_lobes_finding(&mut self, lobes: &[(Lobe, Vec3, u8)], mode: LayeringMode, find_walk: bool) {
        let b = self;
        let old_len = b.len;
        (b.len, b.layered, b.mode, b.walk) = (0, false, mode, None);
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
            if find_walk && mode == LayeringMode::RandomWalk {
                b.walk = walk::stack(b);
            }
        }
    }

    /// Gives the terms of `sum` (as [`ClosureBsdf::set_sum`] decoded them) their own frames:
    /// `frame` is the shading frame and `wo` the outgoing direction (world space).
    ///
    /// With an anisotropic term, `frame` first turns about its normal so that its first
    /// tangent is the first anisotropic term's ([`TERM_TANGENT`]; none: the frame keeps its
    /// own). A term with its own world-space normal gets a frame about it: a normal on the far
    /// side of the frame is flipped (as the shading normal is), one tilted away from `wo` bent
    /// towards it ([`MIN_TILTED_COS`]); a normal within 1e-6 of the shading normal is none, so
    /// such a closure is today's bit for bit. An anisotropic term whose tangent, projected into
    /// its frame, is not the frame's x axis turns about its normal to it.
    pub fn set_term_frames(&mut self, terms: &[ClosureTerm], frame: &mut Frame, wo: Vec3) {
        if !self.own_frames {
            return;
        }
        let anisotropic = self.terms().iter().any(|t| t.lobe.is_anisotropic());
        // Most closures have neither: one pass over the words before any decoding.
        if !anisotropic && !terms.iter().any(|t| term_normal(t).is_some()) {
            return;
        }
        let len = self.len;
        let live = || terms.iter().filter(|t| is_live(t)).take(len).zip(0..);
        if anisotropic {
            let first = live().find(|&(_, i)| self.terms[i].lobe.is_anisotropic());
            if let Some(turned) = first.and_then(|(t, _)| term_tangent(t)).and_then(|t| frame.with_tangent(t)) {
                *frame = turned;
            }
        }
        let wo = frame.to_local(wo);
        let mut tilted = false;
        for (t, i) in live() {
            let mut tilt = None;
            if let Some(n) = term_normal(t) {
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
                    tilt = Some(Quat::from_rotation_arc(n, Vec3::Z));
                }
            }
            if self.terms[i].lobe.is_anisotropic() {
                // The term's tangent in its frame (none: the shading frame's), projected.
                let tangent = term_tangent(t).map_or(Vec3::X, |v| frame.to_local(v));
                let tangent = tilt.map_or(tangent, |q| q * tangent);
                let turn = tangent.y.atan2(tangent.x);
                if tangent.truncate().length_squared() > 1e-12 && turn.abs() > 1e-6 {
                    tilt = Some(Quat::from_rotation_z(-turn) * tilt.unwrap_or(Quat::IDENTITY));
                }
            }
            if tilt.is_some() {
                self.terms[i].tilt = tilt;
                tilted = true;
            }
        }
        if tilted && self.walk.is_some() {
            // A term with a frame of its own is not walked ([`walk::stack`] falls back).
            self.walk = walk::stack(self);
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
        self.terms().iter().any(|t| t.lobe.transmits()) || walk::transmits(self)
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

pub mod walk;
#[cfg(test)]
mod walk_tests;
