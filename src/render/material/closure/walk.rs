//! `layer(top, base)` by a stochastic random walk between the two interfaces: the
//! position-free layered BSDF of Guo et al. 2018 as pbrt-v4's `LayeredBxDF` computes it (no
//! medium between the interfaces, so no thickness or position enters).
//!
//! **The stack walked.** The innermost covering term must be a dielectric (`dielectric_bsdf`
//! "R", a coat or OpenPBR's specular layer, weighted or not): it becomes the top interface, a
//! rough dielectric (reflection from outside keeps its tint; transmission and internal
//! reflection are untinted). The terms under it are the bottom interface, their weighted sum.
//! A weighted coat `w` is `w · walk + (1 − w) · base` (what albedo scaling computes too), and
//! terms beside the stack are added as they are.
//!
//! - **A transmitting base** (glass, `dielectric_bsdf` "RT"/"T", `translucent_bsdf`): light the
//!   base transmits leaves below the stack, as transmission. A glass base sees the coat's medium
//!   above it, so its index is taken relative to the coat's (`η_base / η_coat`, as pbrt-v4's
//!   `CoatedConductor` divides the conductor's index by the coat's): a coat over glass of the
//!   same index is one interface. A glass base makes the stack oriented: a viewer below
//!   (`wo.z < 0`, inside the glass) enters through the base and leaves through either
//!   interface; other stacks are two-sided (mirrored), as the lobes are. Transmitted `f`
//!   carries the radiance compression of both interfaces (`1 / η_base²` in all), so
//!   `ClosureBsdf::compression` (the base's) stays right.
//! - **Nested stacks** (OpenPBR's fuzz over its coat, Standard Surface's sheen over the
//!   coat): covering terms over the coat that are not dielectrics (sheen, fuzz, a Schlick or
//!   metal lobe) are layered over the walked stack by albedo scaling, as OpenPBR defines
//!   them: the walked stack is weighted `a(μo) a(μi) / N` with `a` the light the outer terms
//!   let through (the coat term's albedo-scaling attenuation, [`super::ClosureBsdf`]'s module
//!   docs) and `N` its maximum, so the sum never exceeds 1. The sheen lobe has no
//!   transmission distribution to walk through (it is a volumetric fit), so walking it would
//!   invent one; the stack under it is still walked exactly.
//! - **Nested dielectrics** (OpenPBR's coat over its specular layer over the diffuse base:
//!   every coated OpenPBR material): the innermost dielectric is an *inner* interface under
//!   the top, its index relative to the coat's (a specular layer of the coat's index is no
//!   interface). The inner stack (it, over the opaque terms under it) is one term of the top's
//!   base, weighted as any base term (`w · inner walk + (1 − w) · its base`), beside the
//!   coat's other base terms (OpenPBR's metal and glass). Whenever the outer walk reaches the
//!   base it samples or evaluates it, and the inner stack's part is a walk of its own: an
//!   unbiased estimate drawn from the outer walk's stream (the nested form of Guo et al.'s
//!   position-free walk, where the layer index is the state; a walk within a walk keeps the
//!   two-interface estimator and its MIS unchanged). The inner walk has no density, so the
//!   base's pdf in the MIS weights is a proxy there (half the inner top's reflection, half
//!   its base's mixture); both strategies use the same proxy, so the weights still sum to 1.
//!   The coat's uncovered share (weight < 1) walks the inner stack from the outside. Nested
//!   stacks walk up to [`NESTED_MAX_DEPTH`] bounces.
//! - **Falling back.** Other stacks use albedo scaling: three or more nested dielectrics (or a
//!   transmitting one over another), a thin-filmed specular layer under a coat, a transmitting
//!   base under two dielectrics, a thin-walled sheet under a coat, two separate stacks side by
//!   side, a non-dielectric innermost top, a term with its own normal. The first such closure of a process is reported once
//!   ([`take_fallback`]).
//!
//! **Found once.** The stack depends on the closure only, so [`stack`] runs when the closure
//! is decoded ([`ClosureBsdf::set_lobes`], again once the darkening and the terms' normals are
//! known) and [`ClosureBsdf::walk`] keeps it: `eval`, `sample`, `pdf` and `transmits` read it.
//! It holds no lobes (a base glass's relative index is applied where a lobe is used), so it
//! stays small; albedo-scaling closures keep `None`.
//!
//! A coat that records a darkening factor (`with_darkening`, OpenPBR's `coat_darkening`: the
//! shader's stand-in for the internal reflections albedo scaling omits) has it divided back out
//! of the base's weights, since the walk follows those reflections itself.
//!
//! `eval` is an unbiased stochastic estimate (one walk, next-event connections at every
//! vertex, MIS between connecting through the exit interface and through the other as pbrt-v4
//! does; for transmission also the direct path through both interfaces, which pbrt-v4 without
//! a medium leaves out), seeded by the directions so repeated calls agree. `sample` walks until
//! light leaves and returns its exact throughput; the pdf it reports, like `pdf`, is a proxy
//! (the albedo-scaling mixture's pdf with a tenth of cosine-weighted directions, on both sides
//! for a transmitting stack), which MIS weights may use freely.

use super::{Attenuation, ClosureBsdf, pick};
use crate::abi::MAX_CLOSURE_TERMS;
use crate::render::material::bsdf::{Bsdf, BsdfSample, finish, flip_z};
use crate::render::material::lobes::{Fresnel, Lobe};
use crate::render::material::microfacet::Ggx;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;
use std::sync::atomic::{AtomicU8, Ordering};

/// Most bounces between the interfaces (pbrt-v4's default), each a visit to the base and one
/// to the top.
const MAX_DEPTH: u32 = 10;

/// [`MAX_DEPTH`] of nested stacks and their inner walks: light stays longer between three
/// interfaces (each visit of the outer walk to its base is a whole inner walk, and a
/// high-index inner layer traps light by total internal reflection), and at 10 a white
/// furnace under a coat of 1.6 over a half-weighted specular layer lost 1.8 %.
const NESTED_MAX_DEPTH: u32 = 32;

/// The walk's view of a stack, computed once per closure ([`stack`], kept in
/// [`ClosureBsdf::walk`]): small and `Copy`, as it lives in every random-walk shading point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Stack {
    /// The term that is the top interface (the coat).
    top: usize,
    interface: Interface,
    tint: Vec3,
    /// Mask of the base terms (those under the top).
    base: u8,
    /// `1 / darkening` of the top ([`super::Term::darkening`]): the walk follows the
    /// coat's internal reflections itself, so the base terms get back the weight the
    /// shader's darkening (standing in for them under albedo scaling) took away.
    undarken: Vec3,
    /// A base term is glass: below the stack is inside it (see the module docs).
    oriented: bool,
    /// A base term transmits: light leaves below.
    transmits: bool,
    /// Every base term is a Dirac delta.
    base_specular: bool,
    /// Terms over the top, layered over the walked stack by albedo scaling.
    outer: u8,
    /// Probabilities of sampling each base term ([`base_probabilities`]); with an inner
    /// stack, the inner top's slot is the probability of walking it.
    probabilities: [f32; MAX_CLOSURE_TERMS],
    /// Index of the medium under the top interface (the coat's): a base glass's index is
    /// taken relative to it ([`inside`]).
    medium: f32,
    /// A second dielectric under the top (OpenPBR's specular layer under its coat), over base
    /// terms of its own: the bottom interface is then partly this inner stack, walked.
    inner: Option<Inner>,
    /// Most bounces ([`MAX_DEPTH`], [`NESTED_MAX_DEPTH`]).
    max_depth: u32,
}

/// The inner dielectric of a nested stack and what lies under it: the bottom interface of
/// the outer walk has it as one of its terms, a walk of its own ([`Stack::inner_stack`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Inner {
    /// The term that is the inner interface.
    top: usize,
    ggx: Ggx,
    /// Its index (relative to the outside).
    eta: f32,
    tint: Vec3,
    /// Mask of the terms under it (opaque lobes only).
    base: u8,
    /// Every term under it is a Dirac delta.
    base_specular: bool,
    /// Probabilities of sampling each term under it.
    probabilities: [f32; MAX_CLOSURE_TERMS],
}

impl Stack {
    /// Base term `i`'s lobe as seen from inside the coat ([`inside`]).
    #[inline]
    fn lobe(&self, b: &ClosureBsdf, i: usize) -> Lobe {
        inside(b.terms[i].lobe, self.medium)
    }

    /// The inner stack as a stack of its own, seen from inside the coat (its index relative
    /// to the coat's) or, for the share of the base the coat's weight leaves uncovered, from
    /// the outside (`in_air`).
    fn inner_stack(&self, in_air: bool) -> Option<Stack> {
        let inner = self.inner?;
        let eta = if in_air { inner.eta } else { inner.eta / self.interface.eta };
        Some(Stack {
            top: inner.top,
            interface: Interface { ggx: inner.ggx, eta },
            tint: inner.tint,
            base: inner.base,
            undarken: self.undarken,
            oriented: false,
            transmits: false,
            base_specular: inner.base_specular,
            outer: 0,
            probabilities: inner.probabilities,
            medium: inner.eta,
            inner: None,
            max_depth: NESTED_MAX_DEPTH,
        })
    }

    /// The coefficient of base term `i` in the bottom interface: its weight, and with an
    /// inner stack, the share `1 − w` of its base that the inner top's weight `w` leaves
    /// uncovered (the inner top itself is walked, coefficient 0 here).
    #[inline]
    fn coefficient(&self, b: &ClosureBsdf, i: usize) -> Vec3 {
        let w = self.base_weight(&b.terms[i]);
        match self.inner {
            None => w,
            Some(inner) if i == inner.top => Vec3::ZERO,
            Some(inner) if inner.base & (1 << i) != 0 => (Vec3::ONE - self.base_weight(&b.terms[inner.top])) * w,
            Some(_) => w,
        }
    }

    /// The weight of base term `t` as the walk uses it (undarkened, at most 1).
    #[inline]
    fn base_weight(&self, t: &super::Term) -> Vec3 {
        (t.weight * self.undarken).min(Vec3::ONE)
    }

    /// `a(μo) a(μi) / N` of the outer terms over the walked stack (1 without them).
    #[inline]
    fn outer_scale(&self, b: &ClosureBsdf, ao: &Attenuation, ai: &Attenuation) -> Vec3 {
        if self.outer == 0 { Vec3::ONE } else { ao[self.top] * ai[self.top] * b.terms[self.top].inv_norm }
    }

    /// The radiance change of light a base lobe that does not refract (`translucent_bsdf`)
    /// carries between the coat's medium and the one below, which is the outside's (index 1):
    /// `η²` from the slab out, `1 / η²` in (as a glass's transmission carries its own).
    #[inline]
    fn out_of_the_coat(&self, lobe: &Lobe, wo: Vec3, wi: Vec3) -> f32 {
        if lobe.oriented() || wo.z * wi.z >= 0.0 {
            1.0
        } else if wo.z > 0.0 {
            self.interface.eta * self.interface.eta
        } else {
            1.0 / (self.interface.eta * self.interface.eta)
        }
    }

    /// `(a(μo), a(μi))`, computed only when outer terms need them.
    #[inline]
    fn attenuations(&self, b: &ClosureBsdf, wo: Vec3, wi: Vec3) -> (Attenuation, Attenuation) {
        if self.outer == 0 {
            ([Vec3::ONE; MAX_CLOSURE_TERMS], [Vec3::ONE; MAX_CLOSURE_TERMS])
        } else {
            b.attenuations(wo, wi)
        }
    }
}

/// One of the two interfaces of the walked stack.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Side {
    /// The coat: outside above (`z > 0`), the slab below.
    Top,
    /// The base: the slab above, below it what the base transmits into.
    Bottom,
}

impl Side {
    fn other(self) -> Side {
        match self {
            Side::Top => Side::Bottom,
            Side::Bottom => Side::Top,
        }
    }
}

/// A scattering sampled at an interface: direction, `f`, pdf, whether a Dirac delta, and (for
/// a delta) the radiance compression `wi` went through ([`Lobe::compression`]).
#[derive(Clone, Copy)]
struct Scatter {
    wi: Vec3,
    f: Vec3,
    pdf: f32,
    delta: bool,
    compression: f32,
}

/// A rough dielectric interface, outside above (`z > 0`), index `eta` below.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Interface {
    ggx: Ggx,
    eta: f32,
}

impl Interface {
    fn glass(&self) -> Bsdf {
        Bsdf::Glass { tint: Vec3::ONE, ggx: self.ggx, eta: self.eta }
    }
}

/// A small deterministic random stream (PCG32) for one estimate.
struct Rng(u64);

impl Rng {
    fn seeded(a: Vec3, b: Vec3, salt: u32) -> Rng {
        let mut h = 0x9e37_79b9_7f4a_7c15u64 ^ salt as u64;
        for x in [a.x, a.y, a.z, b.x, b.y, b.z] {
            h = (h ^ x.to_bits() as u64).wrapping_mul(0x100_0000_01b3).rotate_left(29);
        }
        // SplitMix64's finaliser: neighbouring directions (a quadrature grid, a pixel's
        // neighbours) must not start correlated streams, or their estimates err alike.
        h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        Rng(h ^ (h >> 31))
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

/// Why a layered closure was not walked (bits of [`FALLBACK`]).
const FALLBACK_TILTED: u8 = 1;
const FALLBACK_TOP: u8 = 2;
const FALLBACK_NESTED_DIELECTRIC: u8 = 4;
const FALLBACK_SHAPE: u8 = 8;
const FALLBACK_FILMED_BASE: u8 = 16;
const FALLBACK_FILMED_INNER: u8 = 32;
const FALLBACK_INNER_BASE: u8 = 64;
const FALLBACK_THIN_BASE: u8 = 128;

/// The fallbacks seen in this process and not yet taken ([`take_fallback`]).
static FALLBACK: AtomicU8 = AtomicU8::new(0);

/// Records a fallback once per kind (one relaxed load on the hot path after the first).
#[cold]
fn fell_back(kind: u8) -> Option<Stack> {
    if FALLBACK.load(Ordering::Relaxed) & kind == 0 {
        FALLBACK.fetch_or(kind, Ordering::Relaxed);
    }
    None
}

/// The kinds of layered stacks the walk rendered by albedo scaling since the last call, named
/// (empty if none): the renderer reports them once per render, so a `random-walk` image is
/// never silently partly albedo-scaled.
pub fn take_fallback() -> Vec<&'static str> {
    let bits = FALLBACK.swap(0, Ordering::Relaxed);
    [
        (FALLBACK_TILTED, "a layered term with its own normal, or an anisotropic one whose tangent is not the first's"),
        (FALLBACK_TOP, "a layer whose innermost top is not a dielectric"),
        (FALLBACK_NESTED_DIELECTRIC, "three or more nested dielectric layers, or a transmitting one over another"),
        (FALLBACK_SHAPE, "layers that are not one stack (separate stacks side by side)"),
        (FALLBACK_FILMED_BASE, "a thin-filmed glass under a coat"),
        (FALLBACK_FILMED_INNER, "a thin-filmed dielectric under a coat (e.g. OpenPBR's filmed specular)"),
        (FALLBACK_INNER_BASE, "a transmitting base under two dielectric layers"),
        (FALLBACK_THIN_BASE, "a thin-walled sheet under a coat"),
    ]
    .into_iter()
    .filter(|(bit, _)| bits & bit != 0)
    .map(|(_, name)| name)
    .collect()
}

/// A lobe of the base as seen from inside a coat of index `eta`: a glass's index becomes
/// relative to the coat's.
fn inside(lobe: Lobe, eta: f32) -> Lobe {
    let relative = |g: Bsdf| match g {
        Bsdf::Glass { tint, ggx, eta: e } => Bsdf::Glass { tint, ggx, eta: e / eta },
        other => other,
    };
    match lobe {
        Lobe::Bsdf(g) => Lobe::Bsdf(relative(g)),
        Lobe::Interface { glass, tint, reflect, film } => {
            Lobe::Interface { glass: relative(glass), tint, reflect, film }
        }
        other => other,
    }
}

/// The stack the walk handles in `b`, or `None` (then albedo scaling is used): what
/// [`ClosureBsdf`] keeps for a layered closure in random-walk mode, computed when it is decoded
/// (it depends on the terms only, not on directions).
pub(crate) fn stack(b: &ClosureBsdf) -> Option<Stack> {
    let terms = b.terms();
    let covered: u8 = terms.iter().fold(0, |m, t| m | t.above);
    if covered == 0 {
        return None;
    }
    if terms.iter().any(|t| t.tilt.is_some()) {
        return fell_back(FALLBACK_TILTED);
    }
    // The innermost covering term: the last one, as terms lie under earlier ones.
    let innermost = 7 - covered.leading_zeros() as usize;
    let dielectric = |t: &super::Term| {
        t.lobe.transmits()
            || t.lobe.oriented()
            || matches!(t.lobe, Lobe::Specular { fresnel: Fresnel::Dielectric { .. } | Fresnel::ThinFilm { .. }, .. })
    };
    // A dielectric over the innermost one (OpenPBR's coat over its specular layer) is the
    // top, the innermost one an inner interface under it.
    let over: u8 = (0..terms.len())
        .filter(|&i| terms[innermost].above & (1 << i) != 0 && dielectric(&terms[i]))
        .fold(0, |m, i| m | 1 << i);
    let top = if over == 0 { innermost } else { 7 - over.leading_zeros() as usize };
    if over != 0 && over != 1 << top {
        return fell_back(FALLBACK_NESTED_DIELECTRIC);
    }
    let Lobe::Specular { fresnel: Fresnel::Dielectric { eta }, tint, ggx } = terms[top].lobe else {
        return fell_back(if over == 0 { FALLBACK_TOP } else { FALLBACK_NESTED_DIELECTRIC });
    };
    if eta <= 1.0 {
        return fell_back(FALLBACK_TOP);
    }
    let outer = terms[top].above;
    let under = outer | (1 << top);
    let mut inner = None;
    if over != 0 {
        let Lobe::Specular { fresnel: Fresnel::Dielectric { eta: inner_eta }, tint, ggx } = terms[innermost].lobe
        else {
            return fell_back(FALLBACK_FILMED_INNER);
        };
        if terms[innermost].above != under {
            return fell_back(FALLBACK_SHAPE);
        }
        inner = Some(Inner {
            top: innermost,
            ggx,
            eta: inner_eta,
            tint,
            base: 0,
            base_specular: true,
            probabilities: [0.0; MAX_CLOSURE_TERMS],
        });
    }
    let inner_bit = inner.map_or(0, |n| 1 << n.top);
    if covered != under | inner_bit {
        return fell_back(FALLBACK_SHAPE);
    }
    let mut s = Stack {
        top,
        interface: Interface { ggx, eta },
        tint,
        base: 0,
        undarken: Vec3::ONE,
        oriented: false,
        transmits: false,
        base_specular: inner.is_none(),
        outer,
        probabilities: [0.0; MAX_CLOSURE_TERMS],
        medium: eta,
        inner,
        max_depth: if inner.is_some() { NESTED_MAX_DEPTH } else { MAX_DEPTH },
    };
    for (i, t) in terms.iter().enumerate() {
        if t.above & (1 << top) == 0 {
            continue;
        }
        s.base |= 1 << i;
        // A sheet under a coat sits in the coat's medium, where its inter-reflections would
        // need the index relative to the coat's on both faces: not walked.
        if matches!(t.lobe, Lobe::Thin(_)) {
            return fell_back(FALLBACK_THIN_BASE);
        }
        if let Some(n) = &mut s.inner
            && t.above & inner_bit != 0
        {
            // Under both dielectrics: opaque lobes only (light leaving below both would need
            // the radiance compression of each).
            if t.above != under | inner_bit {
                return fell_back(FALLBACK_SHAPE);
            }
            if t.lobe.transmits() || t.lobe.oriented() {
                return fell_back(FALLBACK_INNER_BASE);
            }
            n.base |= 1 << i;
            n.base_specular &= t.lobe.is_delta();
            continue;
        }
        if t.above != under {
            return fell_back(FALLBACK_SHAPE);
        }
        if i == innermost && inner.is_some() {
            continue;
        }
        // A film's Airy sum assumes air outside it; under a coat it would need the coat's
        // medium (and, past the film's critical angle, evanescent waves): not walked.
        if matches!(t.lobe, Lobe::Interface { film: Some(_), .. }) {
            return fell_back(FALLBACK_FILMED_BASE);
        }
        s.oriented |= t.lobe.oriented();
        s.transmits |= t.lobe.oriented() || t.lobe.transmits();
        s.base_specular &= t.lobe.is_delta();
    }
    let darkening = terms[top].darkening;
    s.undarken = Vec3::select(darkening.cmpgt(Vec3::splat(1e-3)), darkening.recip(), Vec3::ONE);
    if s.base == 0 {
        return None;
    }
    if let Some(view) = s.inner_stack(false) {
        let p = base_probabilities(b, &view);
        s.inner.as_mut().unwrap().probabilities = p;
    }
    s.probabilities = base_probabilities(b, &s);
    Some(s)
}

/// Whether the walk transmits light through `b`'s base (light sampling must cover both sides).
pub(crate) fn transmits(b: &ClosureBsdf) -> bool {
    b.walk.is_some_and(|s| s.transmits)
}

/// The base seen from inside the slab: the weighted sum of the terms under the top, and with
/// an inner stack, its walk (one estimate, drawn from `rng`).
fn base_f(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3, rng: &mut Rng) -> Vec3 {
    let mut f = s.lobes_f(b, wo, wi);
    if let Some(inner) = s.inner_stack(false) {
        f += s.base_weight(&b.terms[inner.top]) * estimate(b, &inner, wo, wi, rng);
    }
    f
}

/// Sampling probabilities of the base terms (weight × albedo estimate), kept in the [`Stack`];
/// an inner stack is walked by its top's weight.
fn base_probabilities(b: &ClosureBsdf, s: &Stack) -> [f32; MAX_CLOSURE_TERMS] {
    let mut p = [0.0; MAX_CLOSURE_TERMS];
    let mut total = 0.0;
    for (i, t) in b.terms().iter().enumerate() {
        if s.base & (1 << i) != 0 {
            p[i] = if s.inner.is_some_and(|n| n.top == i) {
                s.base_weight(t).max_element().max(1e-4)
            } else {
                (s.coefficient(b, i) * s.lobe(b, i).albedo()).max_element().max(1e-4)
            };
            total += p[i];
        }
    }
    p.iter_mut().for_each(|x| *x /= total);
    p
}

/// The pdf of sampling the base's lobes (not the inner stack's walk).
fn lobes_pdf(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> f32 {
    let p = &s.probabilities;
    let inner = s.inner.map_or(usize::MAX, |n| n.top);
    (0..MAX_CLOSURE_TERMS).filter(|&i| p[i] > 0.0 && i != inner).map(|i| p[i] * s.lobe(b, i).pdf(wo, wi)).sum()
}

/// The base's pdf as MIS weights see it: its lobes' mixture and, for an inner stack (whose
/// walk has no density to evaluate), a proxy: half its top's reflection, half its base's
/// mixture. The weights of both strategies use the same function, so they still sum to 1.
fn base_pdf(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> f32 {
    let lobes = lobes_pdf(b, s, wo, wi);
    match s.inner_stack(false) {
        None => lobes,
        Some(inner) => {
            let proxy = 0.5 * inner.interface.glass().pdf(wo, wi) + 0.5 * lobes_pdf(b, &inner, wo, wi);
            lobes + s.probabilities[inner.top] * proxy
        }
    }
}

impl Stack {
    /// f of an interface (both directions on either side of it); an inner stack's part is
    /// an estimate drawn from `rng`.
    fn f(&self, b: &ClosureBsdf, side: Side, wo: Vec3, wi: Vec3, rng: &mut Rng) -> Vec3 {
        match side {
            Side::Top => {
                let f = Vec3::splat(self.interface.glass().eval(wo, wi).x);
                if wo.z > 0.0 && wi.z > 0.0 { f * self.tint } else { f }
            }
            Side::Bottom => base_f(b, self, wo, wi, rng),
        }
    }

    /// Pdf of [`Stack::sample`] at an interface (a proxy for an inner stack: [`base_pdf`]).
    fn pdf(&self, b: &ClosureBsdf, side: Side, wo: Vec3, wi: Vec3) -> f32 {
        match side {
            Side::Top => self.interface.glass().pdf(wo, wi),
            Side::Bottom => base_pdf(b, self, wo, wi),
        }
    }

    /// Whether an interface is all Dirac deltas (nothing to connect to by evaluation).
    fn specular(&self, side: Side) -> bool {
        match side {
            Side::Top => self.interface.glass().is_delta(),
            Side::Bottom => self.base_specular,
        }
    }

    /// Samples an interface (reflection or transmission); a delta sample carries its own
    /// term only, a non-delta one the whole interface's f and pdf. With an inner stack, the
    /// bottom is the inner walk (chosen by its probability) or the mixture of the other
    /// lobes, each weighted by its own estimator; the pdf reported is [`base_pdf`].
    fn sample(&self, b: &ClosureBsdf, side: Side, wo: Vec3, rng: &mut Rng) -> Option<Scatter> {
        match side {
            Side::Top => {
                let glass = self.interface.glass();
                let s = glass.sample(wo, rng.f32(), rng.vec2())?;
                let f = if wo.z > 0.0 && s.wi.z > 0.0 { s.f * self.tint } else { s.f };
                let compression = glass.compression(wo, s.wi);
                Some(Scatter { wi: s.wi, f, pdf: s.pdf, delta: s.delta, compression })
            }
            Side::Bottom => {
                let p = &self.probabilities;
                let (k, uc) = pick(p, rng.f32())?;
                if let Some(inner) = self.inner_stack(false)
                    && k == inner.top
                {
                    // The inner stack, two-sided as its opaque base is.
                    let flip = wo.z < 0.0;
                    let (wi, beta, delta) = walk(b, &inner, if flip { flip_z(wo) } else { wo }, rng)?;
                    let wi = if flip { flip_z(wi) } else { wi };
                    let weight = beta * self.base_weight(&b.terms[k]) / p[k];
                    return self.scatter(b, wo, wi, weight, delta);
                }
                let lobe = self.lobe(b, k);
                let s = lobe.sample(wo, uc, rng.vec2())?;
                if s.delta {
                    let f = s.f * self.coefficient(b, k) * self.out_of_the_coat(&lobe, wo, s.wi);
                    let compression = lobe.compression(wo, s.wi);
                    return Some(Scatter { wi: s.wi, f, pdf: s.pdf * p[k], delta: true, compression });
                }
                if self.inner.is_some() {
                    // The lobes' mixture alone: its f over its pdf.
                    let pdf = lobes_pdf(b, self, wo, s.wi);
                    let f = self.lobes_f(b, wo, s.wi);
                    if pdf <= 0.0 {
                        return None;
                    }
                    return self.scatter(b, wo, s.wi, f * (s.wi.z.abs() / pdf), false);
                }
                let pdf = base_pdf(b, self, wo, s.wi);
                let f = base_f(b, self, wo, s.wi, rng);
                (pdf > 0.0).then_some(Scatter { wi: s.wi, f, pdf, delta: false, compression: 1.0 })
            }
        }
    }

    /// The base's lobes without the inner stack: [`base_f`]'s deterministic part.
    fn lobes_f(&self, b: &ClosureBsdf, wo: Vec3, wi: Vec3) -> Vec3 {
        let mut f = Vec3::ZERO;
        let inner = self.inner.map_or(usize::MAX, |n| n.top);
        for i in 0..b.len {
            if self.base & (1 << i) != 0 && i != inner {
                let lobe = self.lobe(b, i);
                f += self.coefficient(b, i) * lobe.eval(wo, wi) * self.out_of_the_coat(&lobe, wo, wi);
            }
        }
        f
    }

    /// A base scattering of throughput `weight` (`f |cos| / pdf`) as a [`Scatter`] whose pdf
    /// is [`base_pdf`] (what the MIS weights compare), so that `f |cos| / pdf` is `weight`.
    fn scatter(&self, b: &ClosureBsdf, wo: Vec3, wi: Vec3, weight: Vec3, delta: bool) -> Option<Scatter> {
        let cos = wi.z.abs();
        if delta {
            return Some(Scatter { wi, f: weight / cos, pdf: 1.0, delta, compression: 1.0 });
        }
        let pdf = base_pdf(b, self, wo, wi);
        (pdf > 0.0 && cos > 0.0).then_some(Scatter { wi, f: weight * (pdf / cos), pdf, delta, compression: 1.0 })
    }
}

fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

/// Coefficient of term `k` in [`beside`]: 0 for the top, the untouched share `(1 − w)` of a
/// base term (under the outer terms only), and the albedo-scaling factor of the others.
fn beside_factor(b: &ClosureBsdf, s: &Stack, k: usize, ao: &Attenuation, ai: &Attenuation) -> Vec3 {
    if k == s.top {
        Vec3::ZERO
    } else if s.base & (1 << k) != 0 {
        // An inner top's share is its uncovered stack's (walked in [`beside`]).
        let c = if s.inner.is_some_and(|n| n.top == k) { s.base_weight(&b.terms[k]) } else { s.coefficient(b, k) };
        (Vec3::ONE - b.terms[s.top].weight) * c * s.outer_scale(b, ao, ai)
    } else {
        b.factor(k, ao, ai)
    }
}

/// Everything but the walk: the terms beside the stack (and the outer ones) and the
/// untouched share `(1 − w)` of the base (an inner stack there walked from the outside).
fn beside(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3, ao: &Attenuation, ai: &Attenuation) -> Vec3 {
    let mut f = Vec3::ZERO;
    let inner = s.inner.map_or(usize::MAX, |n| n.top);
    for (k, t) in b.terms().iter().enumerate() {
        if k != s.top && k != inner {
            f += beside_factor(b, s, k, ao, ai) * t.lobe.eval(wo, wi);
        }
    }
    if let Some(uncovered) = s.inner_stack(true) {
        let share = beside_factor(b, s, inner, ao, ai);
        if share != Vec3::ZERO {
            f += share * layered_f(b, &uncovered, wo, wi, 0x53);
        }
    }
    f
}

/// One-sample estimate of the walked stack's f(wo, wi): pbrt-v4's `LayeredBxDF::f` with one
/// sample, for reflection and transmission, seeded by the directions.
fn layered_f(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3, salt: u32) -> Vec3 {
    let (wo, wi) = if !s.oriented && wo.z < 0.0 { (flip_z(wo), flip_z(wi)) } else { (wo, wi) };
    estimate(b, s, wo, wi, &mut Rng::seeded(wo, wi, salt))
}

/// [`layered_f`] drawing from `rng` (an inner stack's estimate continues its outer walk's
/// stream).
fn estimate(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3, rng: &mut Rng) -> Vec3 {
    let (wo, wi) = if !s.oriented && wo.z < 0.0 { (flip_z(wo), flip_z(wi)) } else { (wo, wi) };
    let same = wo.z * wi.z > 0.0;
    if wo.z == 0.0 || wi.z == 0.0 || (!same && !s.transmits) {
        return Vec3::ZERO;
    }
    let enter = if wo.z > 0.0 { Side::Top } else { Side::Bottom };
    let exit = if same { enter } else { enter.other() };
    let non_exit = exit.other();
    let mut f = if same { s.f(b, enter, wo, wi, rng) } else { Vec3::ZERO };
    // The virtual light: into the slab from `wi` through the exit, and what the exit passes on
    // towards `wi` along it, per unit pdf (the reverse direction's f: the compression
    // the sample went through is given back).
    let wis = s.sample(b, exit, wi, rng).filter(|x| x.wi.z * wi.z < 0.0).map(|x| {
        let through = if x.delta { x.f * x.compression } else { s.f(b, exit, x.wi, wi, rng) };
        (x, through / x.pdf)
    });
    // Straight through both interfaces along `wis`, evaluating the entrance (MIS with the
    // same path along `wos` below). This strategy does not depend on `wos`.
    if !same
        && let Some((x, through)) = wis
        && !s.specular(enter)
    {
        let fe = s.f(b, enter, wo, -x.wi, rng);
        if fe != Vec3::ZERO {
            let weight = if x.delta { 1.0 } else { power_heuristic(x.pdf, s.pdf(b, enter, wo, -x.wi)) };
            f += fe * through * (x.wi.z.abs() * weight);
        }
    }
    // Into the slab through the entrance (a reflection there was counted above).
    let Some(wos) = s.sample(b, enter, wo, rng).filter(|x| x.wi.z * wo.z < 0.0) else { return f };
    let mut beta = wos.f * (wos.wi.z.abs() / wos.pdf);
    if !same && !s.specular(exit) {
        // Straight through along `wos`, evaluating the exit.
        let fe = s.f(b, exit, -wos.wi, wi, rng);
        if fe != Vec3::ZERO {
            let weight = if wos.delta { 1.0 } else { power_heuristic(wos.pdf, s.pdf(b, exit, wi, -wos.wi)) };
            f += beta * fe * weight;
        }
    }
    let mut w = wos.wi;
    let mut at = enter;
    for depth in 0..2 * s.max_depth {
        if depth > 3 && beta.max_element() < 0.25 {
            let q = (1.0 - beta.max_element()).max(0.0);
            if rng.f32() < q {
                break;
            }
            beta /= 1.0 - q;
        }
        at = at.other();
        if at == exit {
            // Reflect off the exit back into the slab (light it transmits is counted by the
            // connections at the other interface).
            let Some(r) = s.sample(b, exit, -w, rng) else { break };
            if r.wi.z * w.z >= 0.0 {
                break;
            }
            beta *= r.f * (r.wi.z.abs() / r.pdf);
            w = r.wi;
        } else {
            // At the other interface: connect through the exit along the presampled `wis`.
            if let Some((x, through)) = wis
                && !s.specular(non_exit)
            {
                let fn_ = s.f(b, non_exit, -w, -x.wi, rng);
                if fn_ != Vec3::ZERO {
                    let weight = if x.delta { 1.0 } else { power_heuristic(x.pdf, s.pdf(b, non_exit, -w, -x.wi)) };
                    f += beta * fn_ * through * (x.wi.z.abs() * weight);
                }
            }
            let Some(r) = s.sample(b, non_exit, -w, rng) else { break };
            if r.wi.z * w.z >= 0.0 {
                break;
            }
            beta *= r.f * (r.wi.z.abs() / r.pdf);
            w = r.wi;
            // Connect through the exit along the sampled direction.
            if !s.specular(exit) {
                let fe = s.f(b, exit, -w, wi, rng);
                if fe != Vec3::ZERO {
                    let weight = if r.delta { 1.0 } else { power_heuristic(r.pdf, s.pdf(b, exit, wi, -w)) };
                    f += beta * fe * weight;
                }
            }
        }
        if !beta.is_finite() {
            return Vec3::ZERO;
        }
    }
    if f.is_finite() { f } else { Vec3::ZERO }
}

pub(crate) fn eval(b: &ClosureBsdf, wo: Vec3, wi: Vec3) -> Vec3 {
    let Some(s) = &b.walk else { return b.eval_scaled(wo, wi) };
    let (ao, ai) = s.attenuations(b, wo, wi);
    let w = b.terms()[s.top].weight * s.outer_scale(b, &ao, &ai);
    w * layered_f(b, s, wo, wi, 0x51) + beside(b, s, wo, wi, &ao, &ai)
}

/// The pdf proxy (see the module docs).
pub(crate) fn pdf(b: &ClosureBsdf, wo: Vec3, wi: Vec3) -> f32 {
    let Some(s) = &b.walk else { return b.pdf_mixture(wo, wi) };
    proxy_pdf(b, s, wo, wi)
}

fn proxy_pdf(b: &ClosureBsdf, s: &Stack, wo: Vec3, wi: Vec3) -> f32 {
    let cosine = if s.transmits {
        0.5 * wi.z.abs() * FRAC_1_PI
    } else if wo.z * wi.z > 0.0 {
        wi.z.abs() * FRAC_1_PI
    } else {
        0.0
    };
    0.9 * b.pdf_mixture(wo, wi) + 0.1 * cosine
}

pub(crate) fn sample(b: &ClosureBsdf, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
    let Some(s) = &b.walk else { return b.sample_scaled(wo, uc, u) };
    // Choose between the stack (by its weight, under the outer terms) and what lies beside it
    // (by its albedo).
    let ao = if s.outer == 0 { [Vec3::ONE; MAX_CLOSURE_TERMS] } else { b.attenuation(wo.z) };
    let w = (b.terms()[s.top].weight * ao[s.top]).max_element();
    let mut beside_importance = 0.0;
    for (i, t) in b.terms().iter().enumerate() {
        if i != s.top && s.base & (1 << i) == 0 {
            beside_importance += (t.weight * t.lobe.albedo()).max_element();
        }
    }
    let base_rest = (1.0 - b.terms()[s.top].weight.max_element()) * s.base.count_ones() as f32;
    let p_stack =
        if beside_importance + base_rest <= 0.0 { 1.0 } else { (w / (w + beside_importance + base_rest)).max(0.1) };
    let mut rng = Rng::seeded(wo, Vec3::new(uc, u.x, u.y), 0xa7);
    let (wi, weight, delta) = if uc < p_stack {
        let flip = !s.oriented && wo.z < 0.0;
        let (wi, beta, delta) = walk(b, s, if flip { flip_z(wo) } else { wo }, &mut rng)?;
        let wi = if flip { flip_z(wi) } else { wi };
        let (ao, ai) = s.attenuations(b, wo, wi);
        (wi, beta * b.terms()[s.top].weight * s.outer_scale(b, &ao, &ai) / p_stack, delta)
    } else {
        let (wi, weight, delta) = beside_sample(b, s, wo, &mut rng)?;
        (wi, weight / (1.0 - p_stack), delta)
    };
    if delta {
        return finish(wi, weight / wi.z.abs(), 1.0, true);
    }
    let p = proxy_pdf(b, s, wo, wi);
    finish(wi, weight * p / wi.z.abs(), p, false)
}

/// Samples [`beside`] from the albedo-scaling mixture: `(wi, f |cos| / pdf, delta)`.
fn beside_sample(b: &ClosureBsdf, s: &Stack, wo: Vec3, rng: &mut Rng) -> Option<(Vec3, Vec3, bool)> {
    let ao = b.attenuation(wo.z);
    let p = b.probabilities(&ao);
    let (k, uc) = pick(&p[..b.len], rng.f32())?;
    let bs = b.terms[k].sample(wo, uc, rng.vec2())?;
    let (ao, ai) = s.attenuations(b, wo, bs.wi);
    if bs.delta {
        let weight = bs.f * beside_factor(b, s, k, &ao, &ai) * (bs.wi.z.abs() / (bs.pdf * p[k]));
        return Some((bs.wi, weight, true));
    }
    let pm = b.pdf_mixture(wo, bs.wi);
    (pm > 0.0).then(|| (bs.wi, beside(b, s, wo, bs.wi, &ao, &ai) * (bs.wi.z.abs() / pm), false))
}

/// The random walk from `wo`: `(wi, f |cos| / pdf, delta)` once light leaves the stack
/// (pbrt-v4's `LayeredBxDF::Sample_f`).
fn walk(b: &ClosureBsdf, s: &Stack, wo: Vec3, rng: &mut Rng) -> Option<(Vec3, Vec3, bool)> {
    let mut at = if wo.z > 0.0 { Side::Top } else { Side::Bottom };
    let first = s.sample(b, at, wo, rng)?;
    let mut beta = first.f * (first.wi.z.abs() / first.pdf);
    let mut delta = first.delta;
    if first.wi.z * wo.z > 0.0 {
        return Some((first.wi, beta, delta));
    }
    let mut w = first.wi;
    for depth in 0..2 * s.max_depth {
        if depth > 3 && beta.max_element() < 0.25 {
            let q = (1.0 - beta.max_element()).max(0.0);
            if rng.f32() < q {
                return None;
            }
            beta /= 1.0 - q;
        }
        at = at.other();
        let r = s.sample(b, at, -w, rng)?;
        beta *= r.f * (r.wi.z.abs() / r.pdf);
        delta &= r.delta;
        if r.wi.z * w.z > 0.0 {
            // Transmitted on along its way: out of the stack.
            return beta.is_finite().then_some((r.wi, beta, delta));
        }
        w = r.wi;
    }
    None
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
