//! Layer participation: the one definition of DESIGN.md rules 5 and 6, shared by the
//! compile-time pruning (`ir::wired`), the lowering's layer metadata (`ir::lower`) and the
//! integrator (`render::integrator`), so that what the optimiser removes is exactly what the
//! renderer could never observe.
//!
//! - **Pick (rule 5).** Only layers with a surface take part. From the top, layer `i` is picked
//!   with `w_i = m_i Π_{j above, with surface}(1 − m_j)`; the rest, `w_T`, is transparency. A
//!   layer without a surface hides nothing below it.
//! - **Hiding.** A layer with a surface and a mask that is 1 at compile time ends the walk:
//!   no layer below it can be picked, and no shadow ray passes it.
//! - **Displacement (rule 6).** Bottom to top: `none` adds its height, `add` adds `m_i d_i`,
//!   `mix` blends `D ← lerp(D, d_i, m_i)`. Every layer's mask weights its own displacement,
//!   whether or not the layer has a surface. A mask of exactly 0 leaves `D` untouched and a
//!   `mix` mask of exactly 1 replaces it (no arithmetic with the replaced value), so removing
//!   such a contribution at compile time gives the same bits.
//!
//! Masks are clamped to [0, 1] and a NaN mask counts as 0 ([`clamp_mask`]), everywhere.

use crate::abi::DisplacementMode;
use crate::abi::LayerInfo;

/// A mask value as every rule reads it: clamped to [0, 1], NaN as 0.
pub fn clamp_mask(m: f32) -> f32 {
    if m.is_nan() { 0.0 } else { m.clamp(0.0, 1.0) }
}

impl LayerInfo {
    /// Whether the layer takes part in the pick (it has a surface).
    pub fn picks(&self) -> bool {
        self.has_surface
    }

    /// Whether no layer below can be picked and no light passes: a surface with mask ≡ 1.
    pub fn hides_below(&self) -> bool {
        self.has_surface && self.constant_mask == Some(1.0)
    }

    /// Whether the combined displacement reads this layer's mask.
    pub fn mask_weights_displacement(&self) -> bool {
        matches!(self.displacement, Some(DisplacementMode::Add | DisplacementMode::Mix))
    }
}

/// Whether a material never lets light through: one of its layers hides everything below.
pub fn is_opaque(layers: &[LayerInfo]) -> bool {
    layers.iter().any(LayerInfo::hides_below)
}

/// Whether [`pick`] gives the same answer whatever `u`: the top layer that picks hides
/// everything below ([`LayerInfo::hides_below`]), or no layer picks. Such a surface (most
/// single-layer materials) needs no pick number.
pub fn pick_is_certain(layers: &[LayerInfo]) -> bool {
    layers.iter().rev().find(|l| l.picks()).is_none_or(LayerInfo::hides_below)
}

/// The layer picked by the uniform number `u ∈ [0, 1)`, or `None` for transparency, walking
/// from the top and evaluating masks (`mask_of`) only until a layer is picked (paper 5.3).
/// One number serves every step: after a miss it is rescaled to [0, 1) within the miss.
pub fn pick<E>(
    layers: &[LayerInfo],
    u: f32,
    mut mask_of: impl FnMut(usize) -> Result<f32, E>,
) -> Result<Option<usize>, E> {
    /// The largest f32 below 1: keeps the rescaled number in [0, 1).
    const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;
    let mut u = u;
    for i in (0..layers.len()).rev() {
        if !layers[i].picks() {
            continue;
        }
        let m = clamp_mask(mask_of(i)?);
        if u < m {
            return Ok(Some(i));
        }
        u = ((u - m) / (1.0 - m)).min(ONE_MINUS_EPSILON);
    }
    Ok(None)
}

/// Rule-5 weights of every layer from all masks (0 for layers that do not pick); returns the
/// transparency `w_T`.
pub fn pick_weights(layers: &[LayerInfo], masks: &[f32], weights: &mut [f32]) -> f32 {
    let mut remaining = 1.0f32;
    for i in (0..layers.len()).rev() {
        if !layers[i].picks() {
            weights[i] = 0.0;
            continue;
        }
        let m = clamp_mask(masks[i]);
        weights[i] = m * remaining;
        remaining *= 1.0 - m;
    }
    remaining.max(0.0)
}

/// The probability that a ray passes the surface, `Π (1 − m_i)` over the layers that pick,
/// evaluated from the top and stopping at the first layer that stops everything.
pub fn transmittance<E>(layers: &[LayerInfo], mut mask_of: impl FnMut(usize) -> Result<f32, E>) -> Result<f32, E> {
    let mut t = 1.0f32;
    for i in (0..layers.len()).rev() {
        if !layers[i].picks() {
            continue;
        }
        t *= 1.0 - clamp_mask(mask_of(i)?);
        if t <= 0.0 {
            return Ok(0.0);
        }
    }
    Ok(t)
}

/// The combined displacement of rule 6 from each layer's height and mask.
pub fn combine_displacement(layers: &[LayerInfo], heights: &[f32], masks: &[f32]) -> f32 {
    combine_relief(layers, heights, masks, Relief::All)
}

/// Which layers' heights a combination reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Relief {
    /// Every layer's: the whole displacement.
    All,
    /// Only the layers whose displacement moves geometry (`displacement_bound` set).
    Geometry,
    /// Only the bump layers'.
    Bump,
}

impl Relief {
    /// Whether the combination reads `layer`'s height.
    pub fn reads(self, layer: &LayerInfo) -> bool {
        match self {
            Relief::All => true,
            Relief::Geometry => layer.displacement_bound.is_some(),
            Relief::Bump => layer.displacement_bound.is_none(),
        }
    }
}

/// Rule 6 over the layers `part` reads, the others' heights taken as 0 (their masks still
/// apply: a `mix` layer hides what is below it whatever kind it is). Rule 6 is linear in the
/// heights, so `Geometry + Bump = All`: dicing moves the surface by the first and the shading
/// normal bends by the second.
pub fn combine_relief(layers: &[LayerInfo], heights: &[f32], masks: &[f32], part: Relief) -> f32 {
    let mut d = 0.0f32;
    for (i, layer) in layers.iter().enumerate() {
        let h = if part.reads(layer) { heights[i] } else { 0.0 };
        match layer.displacement {
            Some(DisplacementMode::None) => d += h,
            Some(DisplacementMode::Add) => {
                let m = clamp_mask(masks[i]);
                if m > 0.0 {
                    d += m * h;
                }
            }
            Some(DisplacementMode::Mix) => {
                let m = clamp_mask(masks[i]);
                if m >= 1.0 {
                    d = h;
                } else if m > 0.0 {
                    d += (h - d) * m;
                }
            }
            None => {}
        }
    }
    d
}

/// Most layers that can be picked for which [`prefers_weighted`] chooses weighted evaluation.
///
/// Measured with `strata bench render` (noise-masked layer stacks, 64x64, 16 spp, one thread,
/// Sobol sampler; equal-error cost = time per sample × RMSE², stochastic over weighted; two
/// runs on a loaded machine): 2.06x / 1.41x at 2 layers, 2.27x / 1.94x at 4, 1.53x / 1.33x at
/// 8, 0.71x / 0.84x at 16 — weighted evaluation removes the pick's noise (the RMSE ratio is
/// 1.2–1.4x) for a cost that grows with every layer it evaluates. The crossover lies between
/// 8 and 16.
pub const WEIGHTED_MAX_LAYERS: usize = 8;

/// The automatic choice of layer evaluation for a material (`LayerMode::Auto`): weighted
/// evaluation when 2 to [`WEIGHTED_MAX_LAYERS`] of its layers can be picked ([`liveness`]:
/// with a surface, a mask not 0 at compile time, not hidden under an opaque layer), stochastic
/// picking otherwise. With one pickable layer the two do the same work; with more than the
/// bound, evaluating every surface costs more than the pick's noise. Both are unbiased, so the
/// choice changes noise and time, never the expected image.
pub fn prefers_weighted(layers: &[LayerInfo]) -> bool {
    (2..=WEIGHTED_MAX_LAYERS).contains(&pickable_count(layers))
}

/// How many layers can ever be picked, from compile-time facts ([`liveness`]).
pub fn pickable_count(layers: &[LayerInfo]) -> usize {
    liveness(layers).iter().filter(|l| l.unpickable.is_none()).count()
}

/// Why a layer can never be picked.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Unpickable {
    /// It has no surface.
    NoSurface,
    /// Its mask is 0 at compile time.
    MaskZero,
    /// A layer above (index) hides it.
    HiddenUnder(usize),
}

/// What of one layer any rule can observe, from compile-time facts alone.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Liveness {
    /// Why its surface, normal and channels are never used, if they are not.
    pub unpickable: Option<Unpickable>,
    /// Whether its displacement contributes to the combined displacement.
    pub displacement: bool,
}

/// What the renderer can observe of each layer (bottom to top), given what is known at
/// compile time. Dropping everything this reports unobservable changes no rendered bit.
pub fn liveness(layers: &[LayerInfo]) -> Vec<Liveness> {
    let mut out = vec![Liveness { unpickable: None, displacement: false }; layers.len()];
    let mut hidden_under: Option<usize> = None;
    let mut replaced_by_mix: bool = false;
    for i in (0..layers.len()).rev() {
        let layer = &layers[i];
        let unpickable = if !layer.has_surface {
            Some(Unpickable::NoSurface)
        } else if let Some(above) = hidden_under {
            Some(Unpickable::HiddenUnder(above))
        } else if layer.constant_mask == Some(0.0) {
            Some(Unpickable::MaskZero)
        } else {
            None
        };
        let displacement = match layer.displacement {
            None => false,
            Some(_) if replaced_by_mix => false,
            Some(DisplacementMode::None) => true,
            Some(DisplacementMode::Add | DisplacementMode::Mix) => layer.constant_mask != Some(0.0),
        };
        out[i] = Liveness { unpickable, displacement };
        if hidden_under.is_none() && layer.hides_below() {
            hidden_under = Some(i);
        }
        if layer.displacement == Some(DisplacementMode::Mix) && layer.constant_mask == Some(1.0) {
            replaced_by_mix = true;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use DisplacementMode as D;

    fn layer(has_surface: bool, displacement: Option<DisplacementMode>, constant_mask: Option<f32>) -> LayerInfo {
        LayerInfo {
            slot: String::new(),
            has_surface,
            displacement,
            displacement_bound: None,
            has_normal: false,
            constant_mask,
            has_emission: false,
            pruned: None,
        }
    }

    #[test]
    fn surfaceless_layers_hide_nothing_and_take_no_part_in_the_pick() {
        // Top: a bump-only layer with no mask (constant 1). It must not hide the base.
        let layers = [layer(true, None, Some(1.0)), layer(false, Some(DisplacementMode::Add), Some(1.0))];
        assert!(!layers[1].hides_below());
        assert!(layers[0].hides_below());
        let live = liveness(&layers);
        assert_eq!(live[0].unpickable, None);
        assert_eq!(live[1].unpickable, Some(Unpickable::NoSurface));
        assert!(live[1].displacement);
        let picked = pick::<()>(&layers, 0.99, |i| Ok([1.0, 1.0][i])).unwrap();
        assert_eq!(picked, Some(0));
        let mut w = [0.0; 2];
        assert_eq!(pick_weights(&layers, &[1.0, 1.0], &mut w), 0.0);
        assert_eq!(w, [1.0, 0.0]);
        assert_eq!(transmittance::<()>(&layers, |_| Ok(0.5)).unwrap(), 0.5);
    }

    /// The integrator draws no pick number where `pick_is_certain`: there every `u` (and any
    /// value of the masks not known at compile time) must pick the same.
    #[test]
    fn a_certain_pick_is_the_same_for_every_number() {
        let kinds = [(false, None), (true, None), (true, Some(1.0)), (true, Some(0.5)), (true, Some(0.0))];
        let mut certain = 0;
        for a in kinds {
            for b in kinds {
                for c in kinds {
                    let layers = [layer(a.0, None, a.1), layer(b.0, None, b.1), layer(c.0, None, c.1)];
                    let picks: Vec<_> = (0..64)
                        .flat_map(|k| [0.0, 0.3, 0.7, 1.0].map(|m| (k, m)))
                        .map(|(k, m)| {
                            let u = (k as f32 + 0.5) / 64.0;
                            pick::<()>(&layers, u, |i| Ok(layers[i].constant_mask.unwrap_or(m))).unwrap()
                        })
                        .collect();
                    let same = picks.iter().all(|p| *p == picks[0]);
                    if pick_is_certain(&layers) {
                        certain += 1;
                        assert!(same, "{layers:?}: {picks:?}");
                    }
                }
            }
        }
        // The top picking layer opaque (the top one: 25 stacks; below a surfaceless top: 5;
        // below two: 1), or nothing picks (1).
        assert_eq!(certain, 32);
    }

    #[test]
    fn pick_frequencies_follow_rule_5_weights() {
        let layers =
            [layer(true, None, None), layer(false, None, None), layer(true, None, None), layer(true, None, None)];
        let masks = [0.8, 0.9, 0.5, 0.25];
        let mut w = [0.0; 4];
        let transparency = pick_weights(&layers, &masks, &mut w);
        // w_top = 0.25, w_2 = 0.5 · 0.75, layer 1 skipped, w_0 = 0.8 · 0.75 · 0.5.
        assert_eq!(w, [0.8 * 0.375, 0.0, 0.375, 0.25]);
        assert!((transparency - 0.075).abs() < 1e-6);
        let n = 100_000;
        let mut counts = [0usize; 5];
        for k in 0..n {
            let u = (k as f32 + 0.5) / n as f32;
            let p = pick::<()>(&layers, u, |i| Ok(masks[i])).unwrap();
            counts[p.unwrap_or(4)] += 1;
        }
        for (i, &expected) in w.iter().chain([transparency].iter()).enumerate() {
            let got = counts[i] as f32 / n as f32;
            // Stratified u: the frequency is exact up to one stratum per boundary.
            assert!((got - expected).abs() < 1e-4, "layer {i}: {got} vs {expected}");
        }
    }

    #[test]
    fn geometry_and_bump_parts_add_up_to_the_whole() {
        let moving = |mode, bound| LayerInfo { displacement_bound: bound, ..layer(true, Some(mode), None) };
        let layers = [
            moving(D::None, Some(1.0)),
            moving(D::Add, None),
            moving(D::Mix, Some(0.5)),
            moving(D::Add, Some(2.0)),
            moving(D::Mix, None),
        ];
        let heights = [0.3, -0.7, 0.2, 0.9, 0.05];
        for masks in [[0.0, 0.5, 0.25, 0.6, 0.3], [1.0, 1.0, 1.0, 0.0, 1.0], [0.2, 0.0, 0.0, 1.0, 0.0]] {
            let all = combine_relief(&layers, &heights, &masks, Relief::All);
            let geometry = combine_relief(&layers, &heights, &masks, Relief::Geometry);
            let bump = combine_relief(&layers, &heights, &masks, Relief::Bump);
            assert!((geometry + bump - all).abs() < 1e-6, "{geometry} + {bump} != {all} at {masks:?}");
        }
        // By hand, masks [0, .5, .25, .6, .3]: geometry ((0.3·0.75 + 0.25·0.2) + 0.6·0.9)·0.7.
        let masks = [0.0, 0.5, 0.25, 0.6, 0.3];
        let geometry = combine_relief(&layers, &heights, &masks, Relief::Geometry);
        assert!((geometry - ((0.3 * 0.75 + 0.25 * 0.2) + 0.6 * 0.9) * 0.7).abs() < 1e-6, "{geometry}");
        // A mix bump layer of mask 1 on top leaves no geometric relief.
        assert_eq!(combine_relief(&layers, &heights, &[1.0, 1.0, 1.0, 1.0, 1.0], Relief::Geometry), 0.0);
    }

    #[test]
    fn displacement_rules_and_exact_skips() {
        let layers =
            [layer(true, Some(D::None), None), layer(false, Some(D::Add), None), layer(false, Some(D::Mix), None)];
        let h = [1.0, 2.0, 4.0];
        // 1 + 0.5·2 = 2, then lerp(2, 4, 0.25) = 2.5.
        assert_eq!(combine_displacement(&layers, &h, &[0.0, 0.5, 0.25]), 2.5);
        // A mix mask of 1 replaces whatever is below, even a non-finite value.
        assert_eq!(combine_displacement(&layers, &[f32::INFINITY, 2.0, 4.0], &[0.0, 0.5, 1.0]), 4.0);
        // A zero mask adds nothing, not even a NaN from 0 · ∞.
        assert_eq!(combine_displacement(&layers, &[1.0, f32::INFINITY, 4.0], &[0.0, 0.0, 0.0]), 1.0);
        // NaN masks count as 0.
        assert_eq!(combine_displacement(&layers, &h, &[f32::NAN, f32::NAN, f32::NAN]), 1.0);
    }

    #[test]
    fn weighted_is_preferred_for_two_to_eight_pickable_layers() {
        let varying = |n: usize| vec![layer(true, None, None); n];
        assert!(!prefers_weighted(&varying(1)));
        assert!(prefers_weighted(&varying(2)));
        assert!(prefers_weighted(&varying(WEIGHTED_MAX_LAYERS)));
        assert!(!prefers_weighted(&varying(WEIGHTED_MAX_LAYERS + 1)));
        // Layers that can never be picked do not count: surfaceless, mask 0, hidden below an
        // opaque layer.
        let mut layers = varying(1);
        layers.push(layer(false, Some(D::Add), None));
        layers.push(layer(true, None, Some(0.0)));
        assert!(!prefers_weighted(&layers));
        let hidden = [layer(true, None, None), layer(true, None, None), layer(true, None, Some(1.0))];
        assert!(!prefers_weighted(&hidden));
        assert!(prefers_weighted(&hidden[1..].iter().cloned().chain([layer(true, None, None)]).collect::<Vec<_>>()));
    }

    #[test]
    fn liveness_of_hidden_and_replaced_layers() {
        let layers = [
            layer(true, Some(D::Add), None),       // 0: hidden under 2; displacement replaced by 3
            layer(true, Some(D::None), Some(0.0)), // 1: mask 0 (hidden anyway); none-mode also replaced
            layer(true, None, Some(1.0)),          // 2: opaque surface
            layer(false, Some(D::Mix), Some(1.0)), // 3: surfaceless, replaces D
            layer(true, Some(D::Add), Some(0.0)),  // 4: mask 0 everywhere
        ];
        let live = liveness(&layers);
        assert_eq!(live[4], Liveness { unpickable: Some(Unpickable::MaskZero), displacement: false });
        assert_eq!(live[3], Liveness { unpickable: Some(Unpickable::NoSurface), displacement: true });
        assert_eq!(live[2], Liveness { unpickable: None, displacement: false });
        assert_eq!(live[1].unpickable, Some(Unpickable::HiddenUnder(2)));
        assert!(!live[1].displacement);
        assert_eq!(live[0], Liveness { unpickable: Some(Unpickable::HiddenUnder(2)), displacement: false });
        assert!(is_opaque(&layers));
        assert!(!is_opaque(&layers[3..]));
    }
}
