//! The lobes of a shading point: decoded in place into per-thread slots, and sampled as one
//! mixture (one-sample MIS over lobes).

use super::Context;
use crate::render::material::bsdf::Frame;
use crate::render::material::closure::{ClosureBsdf, LayeringMode};
use glam::Vec3;

#[derive(Clone, Copy, Debug)]
pub(crate) struct Lobe {
    pub(crate) weight: f32,
    pub(crate) bsdf: ClosureBsdf,
    pub(crate) frame: Frame,
    pub(crate) layer: usize,
}

/// The lobes of the current shading point, decoded in place: slots are kept between shading
/// points, so a closure of [`crate::abi::MAX_CLOSURE_TERMS`] terms is written once rather
/// than built and moved (a few hundred bytes a move). Derefs to the current lobes.
pub(crate) struct Lobes {
    slots: Vec<Lobe>,
    len: usize,
}

impl Lobes {
    pub(super) fn new() -> Lobes {
        Lobes { slots: Vec::new(), len: 0 }
    }

    pub(super) fn clear(&mut self) {
        self.len = 0;
    }

    /// A slot for one more lobe (its old contents left to overwrite), counted as current.
    #[inline]
    pub(super) fn push_slot(&mut self) -> &mut Lobe {
        if self.len == self.slots.len() {
            self.grow();
        }
        self.len += 1;
        &mut self.slots[self.len - 1]
    }

    /// One more slot: once per slot per thread (Scratch::new reserves every material's
    /// layers), so kept out of the shading point's code.
    #[cold]
    #[inline(never)]
    fn grow(&mut self) {
        self.slots.push(Lobe {
            weight: 0.0,
            bsdf: ClosureBsdf::empty(LayeringMode::default()),
            frame: Frame::from_normal(Vec3::Z),
            layer: 0,
        });
    }
}

impl std::ops::Deref for Lobes {
    type Target = [Lobe];
    fn deref(&self) -> &[Lobe] {
        &self.slots[..self.len]
    }
}

/// A direction sampled from the lobes of a shading point.
pub(crate) struct LobeSample {
    /// The new direction (world).
    pub(crate) wi: Vec3,
    /// What the path throughput is multiplied by: `f · |cos| / pdf` of the whole mixture.
    pub(crate) weight: Vec3,
    /// The mixture's solid-angle pdf for MIS, `None` after a delta lobe.
    pub(crate) pdf: Option<f32>,
    /// The radiance compression `η'²` of the sampled lobe's refraction (1 for reflection):
    /// see [`ClosureBsdf::compression`].
    pub(crate) compression: f32,
}

/// Samples the lobes of a shading point (weights summing to 1): picks lobe `k` with
/// probability `w_k` by `uc`, which is then rescaled to [0, 1) within that choice and reused
/// for the lobe's own component choice; `u` samples the direction. A delta sample or a single
/// lobe is weighted by its own `f · |cos| / pdf` (lobe choice and lobe weight cancel); otherwise
/// the whole mixture is evaluated, so its pdf is `Σ w_k pdf_k` (one-sample MIS over lobes).
/// Inlined into the path loop, its one caller on the render path: called out of line, the
/// loop's float state is spilled around the call.
#[inline]
pub(crate) fn sample_lobes(lobes: &[Lobe], wo: Vec3, uc: f32, u: glam::Vec2) -> Option<LobeSample> {
    let mut start = 0.0;
    let mut k = lobes.len().checked_sub(1)?;
    for (i, l) in lobes.iter().enumerate() {
        if uc < start + l.weight {
            k = i;
            break;
        }
        start += l.weight;
    }
    let lobe = &lobes[k];
    let uc_lobe = if lobe.weight > 0.0 { ((uc - start) / lobe.weight).clamp(0.0, 0.999_999_94) } else { 0.0 };
    let wo_local = lobe.frame.to_local(wo);
    let bs = lobe.bsdf.sample(wo_local, uc_lobe, u)?;
    let wi = lobe.frame.to_world(bs.wi).normalize();
    let compression = lobe.bsdf.compression(wo_local, bs.wi);
    if bs.delta || lobes.len() == 1 {
        if bs.pdf.is_nan() || bs.pdf <= 0.0 {
            return None;
        }
        let pdf = if bs.delta { None } else { Some(bs.pdf) };
        return Some(LobeSample { wi, weight: bs.f * (bs.wi.z.abs() / bs.pdf), pdf, compression });
    }
    let (f, pdf) = Context::eval_lobes(lobes, wo, wi);
    if pdf.is_nan() || pdf <= 0.0 {
        return None;
    }
    Some(LobeSample { wi, weight: f / pdf, pdf: Some(pdf), compression })
}
