//! Unidirectional path tracing with next-event estimation and multiple importance sampling
//! (power heuristic), through layered materials (DESIGN.md rules 5–7).
//!
//! At every path vertex the layer weights `w_top = m_top`, `w_i = m_i Π_{j above}(1 − m_j)`
//! and the transparency `w_T = 1 − Σ w` are computed from the masks. One uniform number
//! decides transparency (the ray continues straight on, not counted as a bounce) and, in
//! [`LayerMode::Stochastic`], which single layer is evaluated; picking with probability
//! `w_i` and weighting by `w_i` cancel, so no division is needed. [`LayerMode::Weighted`]
//! evaluates every layer instead (`f = Σ ŵ_i f_i`, `ŵ_i = w_i / (1 − w_T)`), sampling one
//! lobe by weight and using the mixture pdf; it is the reference the stochastic mode is tested
//! against. Shadow rays account for transparency by its expected value (the product of
//! `w_T` at the surfaces they cross), which matches the stochastic pass-through on average.

mod cone;
mod infinite;
mod lobes;
#[cfg(test)]
mod reference;

use crate::abi::layering::{self, Relief};
use crate::abi::{Closure, ClosureSum, ClosureTerm, Globals, MaterialCode, PrimvarValues, ShaderError};
use crate::render::geometry::accel::{Accel, Hit, SurfaceGeom, WORLD, offset_ray_origin};
use crate::render::geometry::primvars::{PrimvarSlot, fill_object_space, reads_object_space};
use crate::render::light::emitter::Emitter;
use crate::render::light::{Light, LightSample, LightSelection};
use crate::render::material::bsdf::Frame;
use crate::render::material::closure::{ClosureBsdf, LayeringMode};
use crate::render::sampling::power_heuristic;
use crate::render::sampling::sampler::{PathSampler, Slot};
use crate::render::scene::Scene;
use cone::{MAX_BOUNCE_SPREAD, bounce_widening, st_footprint};
use glam::{Vec2, Vec3};
pub use infinite::ConstantDome;
use infinite::escape_walk;
pub(crate) use lobes::{Lobe, Lobes, sample_lobes};

/// How layers are evaluated at a path vertex. Both evaluations are unbiased: they render
/// the same image in expectation and differ in noise and time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LayerMode {
    /// Pick one layer per vertex with probability equal to its weight (DESIGN.md rule 5).
    Stochastic,
    /// Evaluate every layer, weighted.
    Weighted,
    /// Per material, whichever of the two costs less for equal error by
    /// [`layering::prefers_weighted`] (weighted for 2 to 8 pickable layers); the explicit
    /// modes above override it for every material.
    #[default]
    Auto,
}

impl LayerMode {
    /// The mode `material` is rendered with: `self`, or for [`LayerMode::Auto`] the rule's
    /// choice. Never `Auto`.
    pub fn resolve(self, material: &dyn MaterialCode) -> LayerMode {
        match self {
            LayerMode::Auto if layering::prefers_weighted(&material.info().layers) => LayerMode::Weighted,
            LayerMode::Auto => LayerMode::Stochastic,
            mode => mode,
        }
    }

    /// Lower-case name, as `--stats` and the EXR header print it.
    pub fn name(self) -> &'static str {
        match self {
            LayerMode::Stochastic => "stochastic",
            LayerMode::Weighted => "weighted",
            LayerMode::Auto => "auto",
        }
    }
}

/// Most transparent surfaces one ray passes straight through before it is absorbed.
pub const MAX_PASS_THROUGH: u32 = 64;

/// Where the layer pick at a camera ray's first surface lies: sample `index` of a pixel's
/// `count` picks in `[index, index + 1) / count` (stratified over the pixel's samples,
/// which removes most of the variance of the pick where the camera sees blended layers).
#[derive(Clone, Copy, Debug)]
pub struct PickStratum {
    /// The sample's index among the pixel's samples.
    pub index: u32,
    /// The pixel's samples.
    pub count: u32,
}

impl PickStratum {
    /// The pick number, drawn only when a pick needs one (numbers are counter based:
    /// skipping it changes no other decision's).
    fn number(self, sampler: &PathSampler) -> f32 {
        ((self.index as f32 + sampler.get1(Slot::LayerPick)) / self.count as f32).min(1.0 - f32::EPSILON / 2.0)
    }
}

/// Path-tracing parameters.
#[derive(Clone, Copy, Debug)]
pub struct PathParams {
    /// Maximum number of bounces (scattering events).
    pub max_depth: u32,
    /// Bounces before Russian roulette starts.
    pub rr_depth: u32,
    /// Layer evaluation mode as requested ([`Context::layer_modes`] holds what each
    /// material gets).
    pub mode: LayerMode,
    /// How closures' `layer(top, base)` is rendered.
    pub layering: LayeringMode,
}

/// Everything one camera sample produced (AOVs are those of the first visible hit).
#[derive(Clone, Copy, Debug, Default)]
pub struct SampleResult {
    /// Radiance.
    pub radiance: Vec3,
    /// 1 when the camera ray reached a non-transparent surface.
    pub alpha: f32,
    /// Albedo of the evaluated layer(s).
    pub albedo: Vec3,
    /// World shading normal.
    pub normal: Vec3,
    /// Distance from the camera (`f32::INFINITY` on a miss).
    pub depth: f32,
    /// World position of the first visible hit (zero on a miss).
    pub position: Vec3,
    /// Index in [`Scene::prims`] of the first visible hit's prim (`None` on a miss).
    pub prim: Option<u32>,
    /// Transparent surfaces passed through that hit [`MAX_PASS_THROUGH`].
    pub pass_limit: bool,
}

/// Why a sample was thrown away.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Invalid {
    /// A shader entry point failed.
    Shader(ShaderError),
    /// A shader returned a non-finite closure parameter or normal.
    NonFiniteClosure,
}

/// Where the shader that ran last was: the prim whose material it belongs to and, when a
/// single layer's entry point ran, that layer. Kept current in [`Scratch::site`] (two stores
/// per shading point, no allocation), so a failed sample can say where it failed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultSite {
    /// Index of the prim in [`Scene::prims`].
    pub prim: u32,
    /// The layer, or `None` for entry points over every layer (masks, displacement).
    pub layer: Option<u32>,
}

/// One evaluated layer at a shading point.
/// Shader entry points the integrator called, counted per thread in [`Scratch::counts`] (plain
/// integer adds, no atomics; the film sums them per row) for `strata render --stats`: what a
/// scene pays for each feature. Mask and displacement counts are per layer evaluated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EvalCounts {
    /// Layer masks evaluated at shading points (the pick, or every layer when weighted).
    pub masks: u64,
    /// Layer masks evaluated along shadow rays through non-opaque surfaces.
    pub shadow_masks: u64,
    /// Surface closures evaluated.
    pub surfaces: u64,
    /// Displacement entry calls (three per bumped shading point: the finite differences).
    pub displacements: u64,
    /// Layer masks evaluated to weight displacement (`add`/`mix` layers).
    pub displacement_masks: u64,
    /// Normal-map entry calls.
    pub normals: u64,
    /// Custom-channel (AOV) entry calls.
    pub channels: u64,
    /// Emission entry calls (at hits on emitting layers, and at emitter light samples).
    pub emissions: u64,
}

impl EvalCounts {
    /// Adds `other` field by field.
    pub fn add(&mut self, other: &EvalCounts) {
        self.masks += other.masks;
        self.shadow_masks += other.shadow_masks;
        self.surfaces += other.surfaces;
        self.displacements += other.displacements;
        self.displacement_masks += other.displacement_masks;
        self.normals += other.normals;
        self.channels += other.channels;
        self.emissions += other.emissions;
    }
}

/// Per-thread buffers, allocated once outside the sample loop so shading allocates nothing.
pub struct Scratch {
    masks: Vec<f32>,
    masks_du: Vec<f32>,
    masks_dv: Vec<f32>,
    disp: Vec<f32>,
    weights: Vec<f32>,
    lobes: Lobes,
    /// The closure value a surface entry point writes.
    closure: ClosureSum,
    material_channels: Vec<f32>,
    /// The shading point's primvar values (`abi::Globals::primvars`).
    primvars: Vec<f32>,
    /// The sample's custom channels in the image's global layout.
    pub channels: Vec<f32>,
    /// Radiance the last [`Context::shade`] found emitted towards the ray (zero unless the
    /// picked layer emits and the ray hit the front).
    emitted: Vec3,
    /// The last BSDF whose albedo the AOV took, and that albedo.
    albedo_memo: Option<(ClosureBsdf, Vec3)>,
    /// Where the last shader ran: read after a sample fails.
    pub site: FaultSite,
    /// Entry points called so far on this thread (the film resets and collects it per row).
    pub counts: EvalCounts,
    /// The time of the sample being traced (`[0, 1)` across an open shutter; 0 when nothing
    /// moves): every ray of its path sees the scene at that time.
    pub time: f32,
}

impl Scratch {
    /// Buffers large enough for every material in `materials` and `global_channels` floats.
    pub fn new(materials: &[&dyn MaterialCode], global_channels: usize) -> Scratch {
        let layers = materials.iter().map(|m| m.info().layers.len()).max().unwrap_or(0).max(1);
        let floats = materials.iter().map(|m| m.info().channel_floats).max().unwrap_or(0);
        let primvar_floats = materials.iter().map(|m| m.info().primvar_floats).max().unwrap_or(0);
        Scratch {
            masks: vec![0.0; layers],
            masks_du: vec![0.0; layers],
            masks_dv: vec![0.0; layers],
            disp: vec![0.0; layers],
            weights: vec![0.0; layers],
            lobes: {
                let mut lobes = Lobes::new();
                (0..layers).for_each(|_| _ = lobes.push_slot());
                lobes.clear();
                lobes
            },
            closure: ClosureSum::default(),
            material_channels: vec![0.0; floats],
            primvars: vec![0.0; primvar_floats],
            channels: vec![0.0; global_channels],
            emitted: Vec3::ZERO,
            albedo_memo: None,
            site: FaultSite::default(),
            counts: EvalCounts::default(),
            time: 0.0,
        }
    }
}

/// Where one of a material's channels goes in the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MappedChannel {
    /// Offset in the material's channel output.
    pub from: usize,
    /// Offset in the image's channels.
    pub to: usize,
    /// Floats.
    pub width: usize,
    /// An integer channel: never blended (DESIGN.md rule 7), one layer's value.
    pub integer: bool,
}

/// Per material, where its channels go in the image.
pub type ChannelMap = Vec<Vec<MappedChannel>>;

/// The scene and materials a path is traced through.
pub struct Context<'a> {
    /// Geometry, lights, camera.
    pub scene: &'a Scene,
    /// Materials, indexed by `Scene::prim_material`.
    pub materials: &'a [&'a dyn MaterialCode],
    /// Channel layout per material.
    pub channel_map: &'a ChannelMap,
    /// Parameters.
    pub params: PathParams,
    /// Per material, the layer evaluation it gets (`params.mode` resolved by
    /// [`LayerMode::resolve`]; never `Auto`).
    pub layer_modes: &'a [LayerMode],
    /// Whether every material has a layer whose mask is 1 at compile time: then no surface
    /// lets light through and shadow rays can stop at their first hit, in any order.
    pub all_opaque: bool,
    /// The indices of the lights a ray can hit ([`Light::is_hittable`]), the only ones the
    /// search for crossed area lights walks: a scene lit only by a dome, distant or point
    /// lights skips the search at every ray, and one with a dome besides its area lights does
    /// not call the dome's `hit`.
    pub hittable_lights: &'a [usize],
    /// How next-event estimation chooses a light (by power; see [`LightSelection`]).
    pub light_selection: LightSelection,
    /// The scene's only light at infinity when that is a constant dome ([`ConstantDome::of`]):
    /// an escaping ray then skips the walk over the lights.
    pub constant_dome: Option<ConstantDome<'a>>,
    /// Per material, whether the layer pick at its surfaces cannot go two ways ([`certain_picks`]):
    /// such a hit draws no pick number, and the path loop reads this instead of the material's
    /// layers at every hit.
    pub certain_picks: &'a [bool],
    /// Per material, its primvar reads resolved against [`Scene::primvars`]
    /// (see [`primvar_slots`]).
    pub primvar_slots: &'a [Vec<PrimvarSlot>],
    /// The angle (radians) one pixel spans at the camera ([`crate::render::camera::Camera::pixel_angle`]):
    /// the spread of the ray cone whose width at a hit, this angle times the path's length so
    /// far, is the shading footprint bump's step is taken from (see [`bump_step`]).
    pub pixel_spread: f32,
}

/// Each material's primvar reads resolved against the scene's stored primvars.
pub fn primvar_slots(scene: &Scene, materials: &[&dyn MaterialCode]) -> Vec<Vec<PrimvarSlot>> {
    materials.iter().map(|m| scene.primvars.slots(&m.info().primvars)).collect()
}

/// Per material, whether its pick cannot go two ways: a stochastic pick
/// ([`layering::pick_is_certain`]) under `layer_modes` ([`Context::layer_modes`]); a weighted
/// evaluation always reads its number.
pub fn certain_picks(materials: &[&dyn MaterialCode], layer_modes: &[LayerMode]) -> Vec<bool> {
    materials
        .iter()
        .zip(layer_modes)
        .map(|(m, &mode)| mode != LayerMode::Weighted && layering::pick_is_certain(&m.info().layers))
        .collect()
}

/// Whether a material never lets light through: a layer with a surface and a mask of 1 at
/// compile time hides everything below it.
pub fn is_opaque(material: &dyn MaterialCode) -> bool {
    layering::is_opaque(&material.info().layers)
}

/// Surface geometry at a hit.
struct SurfacePoint {
    /// The hit's geometry, held as [`Accel::surface_at`] returns it (the fields read through
    /// `Deref`): copying it field by field cost moves on every hit.
    geom: SurfaceGeom,
    material: usize,
    /// The hit and the ray's time, for the prim's object space (read only by materials that
    /// name it: [`reads_object_space`]).
    hit: Hit,
    time: f32,
}

impl std::ops::Deref for SurfacePoint {
    type Target = SurfaceGeom;

    fn deref(&self) -> &SurfaceGeom {
        &self.geom
    }
}

/// Surface geometry where the ray `o + t d` hit.
fn surface_point(accel: &Accel, scene: &Scene, o: Vec3, d: Vec3, hit: &Hit, time: f32) -> SurfacePoint {
    let geom = accel.surface_at(o, d, hit, time);
    SurfacePoint { material: scene.prim_material[geom.prim as usize], geom, hit: *hit, time }
}

/// The material index of a hit's prim, without the surface geometry [`surface_point`] builds.
fn hit_material(accel: &Accel, scene: &Scene, hit: &Hit) -> usize {
    scene.prim_material[accel.prim_of(hit) as usize]
}

fn to_arr(v: Vec3) -> [f32; 3] {
    v.to_array()
}

impl Context<'_> {
    /// The shading globals at `sp`, with the material's primvars interpolated into
    /// `primvars` (scratch at least as long as any material's `primvar_floats`).
    fn globals<'p>(&self, sp: &SurfacePoint, n: Vec3, d: Vec3, primvars: &'p mut [f32]) -> Globals<'p> {
        let slots = &self.primvar_slots[sp.material];
        let used = self.materials[sp.material].info().primvar_floats.min(primvars.len());
        if !slots.is_empty() {
            self.scene.primvars.fill(sp.primvars, sp.bary, slots, &mut primvars[..used]);
            if reads_object_space(slots) {
                let space = self.scene.object_space(&sp.hit, sp.prim, sp.time);
                fill_object_space(&space, slots, &mut primvars[..used]);
            }
        }
        Globals {
            p: to_arr(sp.p),
            n: to_arr(n),
            ng: to_arr(if sp.ng.dot(d) > 0.0 { -sp.ng } else { sp.ng }),
            i: to_arr(d),
            dpdu: to_arr(sp.dpdu),
            dpdv: to_arr(sp.dpdv),
            u: sp.uv.x,
            v: sp.uv.y,
            st_footprint: [0.0; 4],
            primvars: PrimvarValues::new(&primvars[..used]),
            params: PrimvarValues::default(),
        }
    }

    /// Evaluates the picked layer(s) at a hit into `s.lobes`; returns `false` on a
    /// transparent pick. `d` is the incoming ray direction, `footprint` the width of the ray
    /// cone at the hit.
    #[allow(clippy::too_many_arguments)]
    fn shade(
        &self,
        sp: &SurfacePoint,
        d: Vec3,
        u: f32,
        footprint: f32,
        s: &mut Scratch,
        first: bool,
    ) -> Result<Option<(Vec3, Vec3)>, Invalid> {
        let material = self.materials[sp.material];
        let info = material.info();
        let nl = info.layers.len();
        s.site = FaultSite { prim: sp.prim, layer: None };
        let facing = if sp.ns.dot(d) > 0.0 { -sp.ns } else { sp.ns };
        let mut g = self.globals(sp, facing, d, &mut s.primvars);
        // The footprint is that of the surface's own `st` (or parametric) coordinates: a
        // material that reads other coordinates (a `st0` primvar) is left unfiltered, and one
        // that filters no texture does not need it.
        if !info.ignores_footprint && !info.primvars.iter().any(|p| p.width > 1 && p.name != "st") {
            g.st_footprint = st_footprint(sp, d, footprint);
        }
        s.emitted = Vec3::ZERO;
        if nl == 0 {
            s.lobes.clear();
            return Ok(None);
        }
        // Emission is one-sided: only a ray arriving at the front (against the outward
        // winding normal) sees it.
        let front = sp.ng.dot(d) < 0.0;
        // Rule 5 (`layering`). Stochastic: walk down from the top, evaluating masks only until
        // a layer is picked. Weighted: every mask, every layer.
        let picked = match self.layer_modes[sp.material] {
            LayerMode::Stochastic | LayerMode::Auto => {
                let counts = &mut s.counts;
                // A mask known at compile time (an opaque layer's 1, a constant) is not a
                // shader call: a scene without varying masks pays nothing for transparency.
                let mask_of = |i: usize| match info.layers[i].constant_mask {
                    Some(m) => Ok(m),
                    None => {
                        counts.masks += 1;
                        material.mask(&g, i)
                    }
                };
                match layering::pick(&info.layers, u, mask_of).map_err(Invalid::Shader)? {
                    Some(i) => {
                        if front && info.layers[i].has_emission {
                            s.site.layer = Some(i as u32);
                            s.emitted = layer_emission(material, &g, i, &mut s.counts)?;
                        }
                        Some(i)
                    }
                    None => {
                        s.lobes.clear();
                        return Ok(None);
                    }
                }
            }
            LayerMode::Weighted => {
                s.counts.masks += nl as u64;
                material.masks(&g, &mut s.masks[..nl]).map_err(Invalid::Shader)?;
                let transparency = layering::pick_weights(&info.layers, &s.masks[..nl], &mut s.weights[..nl]);
                if u >= 1.0 - transparency || transparency >= 1.0 {
                    s.lobes.clear();
                    return Ok(None);
                }
                if front {
                    // The emission of every layer, weighted as the lobes are below.
                    let opaque = 1.0 - transparency;
                    for i in (0..nl).filter(|&i| info.layers[i].has_emission && s.weights[i] > 0.0) {
                        s.site.layer = Some(i as u32);
                        s.emitted += layer_emission(material, &g, i, &mut s.counts)? * (s.weights[i] / opaque);
                    }
                }
                None
            }
        };
        s.site.layer = None;
        // A diced prim's surface already carries the displacement that moves geometry; the
        // shading normal bends by the rest (rule 6 is linear in the heights).
        let relief = if self.scene.prim_displaced(sp.prim) { Relief::Bump } else { Relief::All };
        if bumps(&info.layers, relief) {
            // What `bump` calls: three displacement evaluations, each with the masks that
            // weight displacement.
            let weighting = info.layers.iter().filter(|l| l.displacement.is_some() && l.mask_weights_displacement());
            s.counts.displacements += 3;
            s.counts.displacement_masks += 3 * weighting.count() as u64;
            let step = bump_step(sp.p, footprint);
            let bumped = bump(material, &g, relief, step, &mut s.masks_du, &mut s.masks_dv, &mut s.disp)?;
            g.n = to_arr(bumped);
        }
        s.lobes.clear();
        match picked {
            Some(i) => {
                s.site.layer = Some(i as u32);
                s.counts.surfaces += 1;
                s.counts.normals += u64::from(info.layers[i].has_normal);
                self.lobe(material, &g, sp, d, i, 1.0, &mut s.closure, &mut s.lobes)?;
            }
            None => {
                let opaque: f32 = s.weights[..nl].iter().sum();
                for i in (0..nl).rev() {
                    if s.weights[i] > 0.0 {
                        s.site.layer = Some(i as u32);
                        s.counts.surfaces += 1;
                        s.counts.normals += u64::from(info.layers[i].has_normal);
                        let weight = s.weights[i] / opaque;
                        self.lobe(material, &g, sp, d, i, weight, &mut s.closure, &mut s.lobes)?;
                    }
                }
            }
        }
        let mut albedo = Vec3::ZERO;
        let mut normal = Vec3::ZERO;
        if first {
            // The AOVs are the first visible hit's; `albedo()` integrates a Fresnel term (8
            // to 24 Fresnel evaluations), so later bounces skip it, and a pixel's samples that
            // meet the same closure (a material with constant parameters) compute it once.
            // (`trace` has cleared `s.channels`.)
            let mut best = -1.0;
            // A diffuse lobe's albedo is its parameter: read, not memoised (comparing and
            // copying a closure costs more than that).
            for lobe in s.lobes.iter() {
                let a = match (lobe.bsdf.stored_albedo(), &s.albedo_memo) {
                    (Some(a), _) => a,
                    (None, Some((bsdf, a))) if *bsdf == lobe.bsdf => *a,
                    (None, _) => {
                        let a = lobe.bsdf.albedo();
                        s.albedo_memo = Some((lobe.bsdf, a));
                        a
                    }
                };
                albedo += a * lobe.weight;
                if lobe.weight > best {
                    best = lobe.weight;
                    normal = lobe.frame.n;
                }
            }
            let map = &self.channel_map[sp.material];
            if !map.is_empty() {
                // Integer channels are never blended (rule 7): weighted evaluation takes them
                // from one layer, chosen by its weight with the pick's own number (which lies
                // in the opaque part, [0, Σw), here), so each id keeps its layer's share.
                let integer_lobe = match picked {
                    Some(_) => 0,
                    None => {
                        let opaque: f32 = s.weights[..nl].iter().sum();
                        let mut rest = u / opaque.max(f32::MIN_POSITIVE);
                        let last = s.lobes.len().saturating_sub(1);
                        (0..s.lobes.len())
                            .find(|&k| {
                                rest -= s.lobes[k].weight;
                                rest < 0.0
                            })
                            .unwrap_or(last)
                    }
                };
                for k in 0..s.lobes.len() {
                    let (layer, weight) = (s.lobes[k].layer, s.lobes[k].weight);
                    s.site.layer = Some(layer as u32);
                    s.counts.channels += 1;
                    material
                        .channels(&g, layer, &mut s.material_channels[..info.channel_floats])
                        .map_err(Invalid::Shader)?;
                    for m in map {
                        for c in 0..m.width {
                            let value = s.material_channels[m.from + c];
                            if !m.integer {
                                s.channels[m.to + c] += weight * value;
                            } else if k == integer_lobe {
                                s.channels[m.to + c] = value;
                            }
                        }
                    }
                }
            }
        }
        Ok(Some((albedo, normal)))
    }

    /// Evaluates layer `layer`'s closure at `g` into a new lobe of `lobes` (`closure` is
    /// scratch for the entry point's output).
    #[allow(clippy::too_many_arguments)]
    fn lobe(
        &self,
        material: &dyn MaterialCode,
        g: &Globals,
        sp: &SurfacePoint,
        d: Vec3,
        layer: usize,
        weight: f32,
        closure: &mut ClosureSum,
        lobes: &mut Lobes,
    ) -> Result<(), Invalid> {
        let n = layer_normal(material, g, layer)?;
        // Only the terms the shader writes are read (the rest of `closure` may be stale).
        let written = material.surface_terms(g, layer, closure).map_err(Invalid::Shader)?;
        let terms = &closure.terms[..written.min(closure.terms.len())];
        if terms.iter().any(ClosureTerm::is_non_finite) {
            return Err(Invalid::NonFiniteClosure);
        }
        let lobe = lobes.push_slot();
        lobe.bsdf.set_terms(terms, self.params.layering);
        // Glass needs to know inside from outside, so its frame keeps the outward side
        // (wo.z < 0 means the ray travels inside); every other closure faces the ray.
        let n = if lobe.bsdf.oriented() {
            if n.dot(sp.ng) < 0.0 { -n } else { n }
        } else if n.dot(d) > 0.0 {
            -n
        } else {
            n
        };
        (lobe.weight, lobe.frame, lobe.layer) = (weight, Frame::from_normal(n), layer);
        // Terms with a normal of their own (`with_normal`) turn into its frame; anisotropic
        // ones (`with_anisotropy`) turn the frame about the normal to their tangent.
        lobe.bsdf.set_term_frames(terms, &mut lobe.frame, -d);
        Ok(())
    }

    /// `(f · |cos|, pdf)` of the evaluated lobes for directions `wo`, `wi` (world).
    pub(crate) fn eval_lobes(lobes: &[Lobe], wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let mut f = Vec3::ZERO;
        let mut pdf = 0.0;
        for l in lobes {
            let lo = l.frame.to_local(wo);
            let li = l.frame.to_local(wi);
            f += l.bsdf.eval(lo, li) * (li.z.abs() * l.weight);
            pdf += l.bsdf.pdf(lo, li) * l.weight;
        }
        (f, pdf)
    }

    /// Transmittance along a shadow segment: 0 behind an opaque surface, the product of
    /// transparencies across masked ones, at the path's ray time `time`.
    #[allow(clippy::too_many_arguments)]
    fn transmittance(
        &self,
        mut o: Vec3,
        d: Vec3,
        dist: f32,
        site: &mut FaultSite,
        counts: &mut EvalCounts,
        primvars: &mut [f32],
        time: f32,
    ) -> Result<f32, Invalid> {
        let accel = &self.scene.accel;
        if self.all_opaque {
            return Ok(if accel.occluded_at(o, d, 0.0, dist, time) { 0.0 } else { 1.0 });
        }
        let mut remaining = dist;
        let mut t_total = 1.0f32;
        for _ in 0..MAX_PASS_THROUGH {
            let Some(hit) = accel.intersect_at(o, d, 0.0, remaining, time) else { return Ok(t_total) };
            // An opaque material stops the ray before any surface geometry or shader runs: a
            // scene with one transparent prim does not make shadow rays pay at the others.
            if is_opaque(self.materials[hit_material(accel, self.scene, &hit)]) {
                return Ok(0.0);
            }
            let sp = surface_point(accel, self.scene, o, d, &hit, time);
            let material = self.materials[sp.material];
            let nl = material.info().layers.len();
            if nl > 0 {
                *site = FaultSite { prim: sp.prim, layer: None };
                let facing = if sp.ns.dot(d) > 0.0 { -sp.ns } else { sp.ns };
                let g = self.globals(&sp, facing, d, primvars);
                // Π(1 − m_i) over the layers that pick, from the top (`layering`).
                let layers = &material.info().layers;
                let mask_of = |i: usize| match layers[i].constant_mask {
                    Some(m) => Ok(m),
                    None => {
                        counts.shadow_masks += 1;
                        material.mask(&g, i)
                    }
                };
                t_total *= layering::transmittance(layers, mask_of).map_err(Invalid::Shader)?;
            }
            if t_total <= 0.0 {
                return Ok(0.0);
            }
            let side = if sp.ng.dot(d) > 0.0 { sp.ng } else { -sp.ng };
            let next = offset_ray_origin(sp.p, sp.p_error, side);
            remaining -= (next - o).dot(d);
            o = next;
            if remaining <= 0.0 {
                return Ok(t_total);
            }
        }
        Ok(0.0)
    }

    /// Direct light at a shading point by sampling one light (chosen by
    /// [`Context::light_selection`]), MIS-weighted. `p_error` bounds `p`'s rounding error;
    /// `light_n` is the lobes' [`light_side`] (the path loop keeps it for the next vertex's MIS).
    #[allow(clippy::too_many_arguments)]
    fn direct(
        &self,
        p: Vec3,
        p_error: Vec3,
        ng: Vec3,
        light_n: Vec3,
        wo: Vec3,
        sampler: &PathSampler,
        s: &mut Scratch,
    ) -> Result<Vec3, Invalid> {
        // The light and the point on it from one 2D number (the choice takes the first
        // coordinate and passes on its rescaled remainder, as Mitsuba does): choice and point
        // are stratified together, where two independent dimensions would not be.
        let u = sampler.get2(Slot::LightPoint);
        let Some((pick, select_pdf, ux)) = self.light_selection.sample_remapped(u.x) else { return Ok(Vec3::ZERO) };
        let u = Vec2::new(ux, u.y);
        let ls = match self.scene.lights.get(pick) {
            Some(light) => light.sample_li(p, light_n, u),
            None => {
                let Some(emitter) = self.scene.emitters.list.get(pick - self.scene.lights.len()) else {
                    return Ok(Vec3::ZERO);
                };
                let (u_triangle, u_pick) = (sampler.get1(Slot::EmitterTriangle), sampler.get1(Slot::EmitterPick));
                self.sample_emitter(emitter, p, u_triangle, u, u_pick, s)?
            }
        };
        let Some(ls) = ls else { return Ok(Vec3::ZERO) };
        let (f, bsdf_pdf) = Self::eval_lobes(&s.lobes, wo, ls.wi);
        if f == Vec3::ZERO || ls.li == Vec3::ZERO {
            return Ok(Vec3::ZERO);
        }
        let side = if ng.dot(ls.wi) > 0.0 { ng } else { -ng };
        let o = offset_ray_origin(p, p_error, side);
        let dist = if ls.dist.is_finite() { ls.dist * (1.0 - 1e-4) } else { f32::INFINITY };
        let tr = self.transmittance(o, ls.wi, dist, &mut s.site, &mut s.counts, &mut s.primvars, s.time)?;
        if tr <= 0.0 {
            return Ok(Vec3::ZERO);
        }
        let light_pdf = ls.pdf * select_pdf;
        let weight = if ls.delta { 1.0 } else { power_heuristic(light_pdf, bsdf_pdf) };
        Ok(f * ls.li * (tr * weight / light_pdf))
    }

    /// Samples a point on `emitter` as seen from `p` (`u_triangle` chooses the triangle, `u`
    /// the point, `u_pick` the layer there): the incident radiance, its direction and
    /// solid-angle density (the emitter's choice within the light selection excluded).
    fn sample_emitter(
        &self,
        emitter: &Emitter,
        p: Vec3,
        u_triangle: f32,
        u: Vec2,
        u_pick: f32,
        s: &mut Scratch,
    ) -> Result<Option<LightSample>, Invalid> {
        let Some(es) = emitter.sample(u_triangle, u) else { return Ok(None) };
        let accel = &self.scene.accel;
        let Some(tri) = accel.world_triangle(es.triangle as usize) else { return Ok(None) };
        let q = tri[0] * (1.0 - es.b1 - es.b2) + tri[1] * es.b1 + tri[2] * es.b2;
        let to = q - p;
        let dist2 = to.length_squared();
        let dist = dist2.sqrt();
        if !(dist > 0.0 && dist.is_finite()) {
            return Ok(None);
        }
        let wi = to / dist;
        let hit = Hit { t: dist, index: es.triangle, instance: WORLD, b1: es.b1, b2: es.b2 };
        let sp = surface_point(accel, self.scene, p, wi, &hit, s.time);
        // One-sided: the point must face `p`.
        let cos = -sp.ng.dot(wi);
        if cos <= 0.0 {
            return Ok(None);
        }
        let li = self.emitted_at(&sp, wi, u_pick, s)?;
        let pdf = es.pdf_area * dist2 / cos;
        if li == Vec3::ZERO || !(pdf > 0.0 && pdf.is_finite()) {
            return Ok(None);
        }
        Ok(Some(LightSample { wi, li, pdf, dist, delta: false }))
    }

    /// The radiance emitted towards a ray in direction `d` that hit the front of `sp`, with
    /// the layer picked by `u` (rule 5; a transparent pick emits nothing), as [`Context::shade`]
    /// finds it.
    fn emitted_at(&self, sp: &SurfacePoint, d: Vec3, u: f32, s: &mut Scratch) -> Result<Vec3, Invalid> {
        let material = self.materials[sp.material];
        let layers = &material.info().layers;
        s.site = FaultSite { prim: sp.prim, layer: None };
        let g = self.globals(sp, sp.ns, d, &mut s.primvars);
        let counts = &mut s.counts;
        let mask_of = |i: usize| match layers[i].constant_mask {
            Some(m) => Ok(m),
            None => {
                counts.masks += 1;
                material.mask(&g, i)
            }
        };
        match layering::pick(layers, u, mask_of).map_err(Invalid::Shader)? {
            Some(i) if layers[i].has_emission => {
                s.site.layer = Some(i as u32);
                layer_emission(material, &g, i, &mut s.counts)
            }
            _ => Ok(Vec3::ZERO),
        }
    }

    /// The solid-angle density with which [`Context::direct`] at `from` would have sampled
    /// the point `sp` where the ray in direction `d` made `hit` (0 where the surface is not
    /// sampled as a light).
    fn emitter_pdf(&self, from: Vec3, sp: &SurfacePoint, d: Vec3, hit: &Hit) -> f32 {
        if hit.instance != WORLD {
            return 0.0;
        }
        let Some((k, emitter)) = self.scene.emitters.of_prim(sp.prim) else { return 0.0 };
        let cos = sp.ng.dot(d).abs();
        let select = self.light_selection.pmf(self.scene.lights.len() + k);
        let pdf = select * emitter.pdf_area(hit.index) * (sp.p - from).length_squared() / cos;
        if pdf.is_finite() { pdf } else { 0.0 }
    }

    /// Emission of area lights crossed by the segment `o + t d`, `t < tmax`, MIS-weighted
    /// against the vertex that chose `d` (which transparent picks may have left behind `o`).
    /// `camera_ray`: the ray left the camera (perhaps through transparent surfaces), so lights
    /// hidden from the camera contribute nothing. Walks only [`Context::hittable_lights`]: the
    /// others' `hit` is always `None`.
    fn area_emission(&self, o: Vec3, d: Vec3, tmax: f32, from: &Scatter, camera_ray: bool) -> Vec3 {
        let mut sum = Vec3::ZERO;
        for &i in self.hittable_lights {
            let light = &self.scene.lights[i];
            if camera_ray && !light.visible_to_camera {
                continue;
            }
            if let Some((le, _)) = light.hit(o, d, tmax) {
                sum += le * from.mis(light, d, self.light_selection.pmf(i));
            }
        }
        sum
    }

    /// Emission of infinite lights reached in direction `d`, MIS-weighted against `from`
    /// (`camera_ray` as in [`Context::area_emission`]).
    fn escape_emission(&self, d: Vec3, from: &Scatter, camera_ray: bool) -> Vec3 {
        match &self.constant_dome {
            Some(dome) => dome.escape(d, from, camera_ray),
            None => escape_walk(&self.scene.lights, &self.light_selection, d, from, camera_ray),
        }
    }

    /// Traces one camera ray. Channels of the first visible hit are left in `s.channels`.
    /// `first_pick` places the number that picks the layer (or transparency) at the first
    /// surface the ray meets.
    #[allow(clippy::too_many_arguments)]
    pub fn trace(
        &self,
        mut o: Vec3,
        mut d: Vec3,
        mut tmin: f32,
        mut tmax: f32,
        first_pick: PickStratum,
        sampler: &mut PathSampler,
        s: &mut Scratch,
    ) -> Result<SampleResult, Invalid> {
        let mut out = SampleResult { depth: f32::INFINITY, ..SampleResult::default() };
        s.channels.iter_mut().for_each(|c| *c = 0.0);
        let mut throughput = Vec3::ONE;
        // The camera "scattered" the first ray; emission it sees directly takes no MIS weight.
        let mut from = Scatter { p: o, n: Vec3::ZERO, pdf: None };
        let mut bounces = 0u32;
        let mut passes = 0u32;
        // Transparent picks passed since the current vertex (each takes its own dimension).
        let mut vertex_passes = 0u32;
        let mut first = true;
        // The ray cone's length from the camera to the current ray's origin, along the path
        // (pass-throughs and bounces alike): at a hit its width is `pixel_spread` times this
        // plus the hit distance. Until the first visible hit (no bounce yet) it is the
        // distance the camera ray has travelled through transparent picks, which the depth
        // AOV adds the hit distance to.
        let mut cone_length = 0.0f32;
        // Rough bounces widen the cone (textures read there need no detail): the spread they
        // added, and the width it has grown to at the current ray's origin.
        let (mut bounce_spread, mut bounce_width) = (0.0f32, 0.0f32);
        // The product of the radiance compressions `η'²` of the refractions so far: inside
        // glass the throughput is 1/η² of what it will be once the path leaves again.
        let mut compression = 1.0f32;
        let accel = &self.scene.accel;
        loop {
            let hit = accel.intersect_at(o, d, tmin, tmax, s.time);
            let t_hit = hit.map_or(f32::INFINITY, |h| h.t);
            // Still the camera's ray until the first bounce (passing through is not one).
            let camera_ray = bounces == 0;
            // Skipped, not added as a zero, where no light can be hit: the throughput is finite
            // here (a non-finite one ends the path; roulette's boost could overflow it only for
            // a survival probability below ~1e-38, where the next bounce ends the path as
            // non-finite), so the product would be a zero, and the radiance, a sum of such
            // terms from +0, is never −0 for a +0 to change.
            if !self.hittable_lights.is_empty() {
                out.radiance += throughput * self.area_emission(o, d, t_hit, &from, camera_ray);
            }
            let Some(hit) = hit else {
                out.radiance += throughput * self.escape_emission(d, &from, camera_ray);
                break;
            };
            let sp = surface_point(accel, self.scene, o, d, &hit, s.time);
            // The pick at the vertex's first surface has a dimension of its own; each
            // pass through a transparent pick takes another, so later decisions keep theirs.
            // A stochastic pick that cannot go two ways draws no number.
            let u_layer = match (bounces, vertex_passes) {
                _ if self.certain_picks[sp.material] => 0.0,
                (0, 0) => first_pick.number(sampler),
                (_, 0) => sampler.get1(Slot::LayerPick),
                _ => sampler.pass_pick(vertex_passes),
            };
            let footprint = self.pixel_spread * (cone_length + hit.t) + bounce_width + bounce_spread * hit.t;
            let shaded = self.shade(&sp, d, u_layer, footprint, s, first)?;
            if s.emitted != Vec3::ZERO {
                let weight = match from.pdf {
                    None => 1.0,
                    Some(pdf) => power_heuristic(pdf, self.emitter_pdf(from.p, &sp, d, &hit)),
                };
                out.radiance += throughput * s.emitted * weight;
            }
            let Some((albedo, normal)) = shaded else {
                // Transparent: continue straight on, not a bounce. Only the ray moves: MIS and
                // light pdfs stay with `from`, the vertex that chose `d` (DESIGN.md rule 5).
                passes += 1;
                vertex_passes += 1;
                if passes > MAX_PASS_THROUGH {
                    out.pass_limit = true;
                    break;
                }
                let side = if sp.ng.dot(d) > 0.0 { sp.ng } else { -sp.ng };
                let next = offset_ray_origin(sp.p, sp.p_error, side);
                let advanced = (next - o).dot(d);
                cone_length += advanced;
                bounce_width += bounce_spread * advanced;
                tmax = (tmax - advanced).max(0.0);
                tmin = 0.0;
                o = next;
                continue;
            };
            if first {
                first = false;
                out.alpha = 1.0;
                out.albedo = albedo;
                out.normal = normal;
                out.depth = cone_length + hit.t;
                out.position = sp.p;
                out.prim = Some(sp.prim);
            }
            if s.lobes.is_empty() || bounces >= self.params.max_depth {
                break;
            }
            let wo = -d;
            let light_n = light_side(&s.lobes, sp.ng, wo);
            out.radiance += throughput * self.direct(sp.p, sp.p_error, sp.ng, light_n, wo, sampler, s)?;
            // Sample the next direction from the picked lobe(s). A single lobe that makes no
            // choice of its own (Lambert, metal) draws no lobe number: numbers are counter
            // based, so skipping it changes no other decision's, and the image not a bit.
            let uc = match &s.lobes[..] {
                [only] if !only.bsdf.reads_choice() => 0.5,
                _ => sampler.get1(Slot::Lobe),
            };
            let u2 = sampler.get2(Slot::Direction);
            let Some(next) = sample_lobes(&s.lobes, wo, uc, u2) else { break };
            let wi = next.wi;
            throughput *= next.weight;
            compression *= next.compression;
            from = Scatter { p: sp.p, n: light_n, pdf: next.pdf };
            if !throughput.is_finite() {
                // Reported by the caller as a non-finite sample.
                out.radiance = Vec3::NAN;
                break;
            }
            if throughput == Vec3::ZERO {
                break;
            }
            bounces += 1;
            vertex_passes = 0;
            sampler.set_vertex(bounces);
            if bounces >= self.params.rr_depth {
                // Played for the throughput the path will have outside the medium, so a path
                // is not killed (and its survivors boosted) for the 1/η² of being inside.
                let p = (throughput.max_element() * compression).min(0.95);
                if sampler.get1(Slot::Roulette) >= p {
                    break;
                }
                throughput /= p;
            }
            let side = if sp.ng.dot(wi) > 0.0 { sp.ng } else { -sp.ng };
            cone_length += hit.t;
            bounce_width += bounce_spread * hit.t;
            bounce_spread = (bounce_spread + bounce_widening(next.pdf)).min(MAX_BOUNCE_SPREAD);
            o = offset_ray_origin(sp.p, sp.p_error, side);
            d = wi;
            tmin = 0.0;
            tmax = f32::INFINITY;
        }
        Ok(out)
    }
}

/// Whether `bump` with `relief` reads any layer's displacement.
fn bumps(layers: &[crate::abi::LayerInfo], relief: Relief) -> bool {
    layers.iter().any(|l| l.displacement.is_some() && relief.reads(l))
}

/// The bumped shading normal of rule 6: `g.n` tilted by the slope of the combined
/// displacement of the layers `relief` reads (all of them on a surface that was not diced;
/// the bump layers only on one that was), by finite differences along `g.dpdu` and `g.dpdv`
/// (masks and heights are evaluated at the points given, undisplaced by the bump), a step
/// `h` (scene units, from [`bump_step`]) apart. `masks_a`, `masks_b` and `heights` are
/// scratch, one float per layer.
pub(crate) fn bump(
    material: &dyn MaterialCode,
    g: &Globals,
    relief: Relief,
    h: f32,
    masks_a: &mut [f32],
    masks_b: &mut [f32],
    heights: &mut [f32],
) -> Result<Vec3, Invalid> {
    let layers = &material.info().layers;
    let n = Vec3::from_array(g.n);
    if !bumps(layers, relief) {
        return Ok(n);
    }
    let nl = layers.len();
    let (p, dpdu, dpdv) = (Vec3::from_array(g.p), Vec3::from_array(g.dpdu), Vec3::from_array(g.dpdv));
    let lu = dpdu.length().max(1e-12);
    let lv = dpdv.length().max(1e-12);
    let eval = |du: f32, dv: f32, masks: &mut [f32], heights: &mut [f32]| -> Result<f32, Invalid> {
        let mut gg = *g;
        gg.p = to_arr(p + dpdu * du + dpdv * dv);
        gg.u += du;
        gg.v += dv;
        // Only the masks that weight a displacement (`add`, `mix`) are read.
        for (i, layer) in layers.iter().enumerate() {
            masks[i] =
                if layer.mask_weights_displacement() { material.mask(&gg, i).map_err(Invalid::Shader)? } else { 0.0 };
        }
        material.displacement(&gg, heights).map_err(Invalid::Shader)?;
        Ok(layering::combine_relief(layers, heights, masks, relief))
    };
    let d0 = eval(0.0, 0.0, &mut masks_a[..nl], &mut heights[..nl])?;
    let du = eval(h / lu, 0.0, &mut masks_a[..nl], &mut heights[..nl])?;
    let dv = eval(0.0, h / lv, &mut masks_b[..nl], &mut heights[..nl])?;
    if du == d0 && dv == d0 {
        // No slope: the shading normal stays as it is, bit for bit (as without displacement).
        return Ok(n);
    }
    // Displaced tangents: dP'/du = dPdu + (dD/du) N (the dN/du term is neglected). The
    // tangents are first projected onto the shading normal's plane, so that a small slope
    // tilts the interpolated normal rather than replacing it with the facet's.
    let tu = (dpdu - n * n.dot(dpdu)) + n * ((du - d0) / h * lu);
    let tv = (dpdv - n * n.dot(dpdv)) + n * ((dv - d0) / h * lv);
    let nb = tu.cross(tv).normalize_or_zero();
    if !nb.is_finite() || nb == Vec3::ZERO {
        return Ok(n);
    }
    Ok(if nb.dot(n) < 0.0 { -nb } else { nb })
}

/// How many f32 rounding steps of the position the bump step is at least: a step nearer the
/// rounding of `P` would be mostly rounding error (at 4 ulps, the sampled points are off by at
/// most an eighth of it).
const BUMP_MIN_ULPS: f32 = 4.0;

/// The footprint [`shading_state`] assumes: a step of 1e-3 scene units (the tests that call it
/// work at unit scale).
const SHADING_STATE_FOOTPRINT: f32 = 2e-3;

/// The finite-difference step of [`bump`] at `p` for a shading footprint `footprint` (the width
/// of the pixel's ray cone there): half of it, as pbrt-v4's bump mapping takes half the
/// screen-space differential, so the bump resolves what a pixel can show and follows the
/// scene's scale and the camera's distance instead of where the object is. It never falls
/// below [`BUMP_MIN_ULPS`] rounding steps of `p` (the ulp of `x` is at most `x · 2⁻²³`) nor to 0.
pub(crate) fn bump_step(p: Vec3, footprint: f32) -> f32 {
    let floor = (BUMP_MIN_ULPS * f32::EPSILON * p.abs().max_element()).max(f32::MIN_POSITIVE);
    let h = 0.5 * footprint;
    if h > floor && h.is_finite() { h } else { floor }
}

/// Layer `layer`'s emitted radiance, clamped at 0 (negative light is no light).
fn layer_emission(
    material: &dyn MaterialCode,
    g: &Globals,
    layer: usize,
    counts: &mut EvalCounts,
) -> Result<Vec3, Invalid> {
    counts.emissions += 1;
    let mut out = [0.0f32; 3];
    material.emission(g, layer, &mut out).map_err(Invalid::Shader)?;
    let e = Vec3::from_array(out);
    if !e.is_finite() {
        return Err(Invalid::NonFiniteClosure);
    }
    Ok(e.max(Vec3::ZERO))
}

/// Layer `layer`'s shading normal: its normal product (rule 6: after bump, which `g.n`
/// carries), or `g.n` without one or where it is zero.
pub(crate) fn layer_normal(material: &dyn MaterialCode, g: &Globals, layer: usize) -> Result<Vec3, Invalid> {
    let n = Vec3::from_array(g.n);
    if !material.info().layers[layer].has_normal {
        return Ok(n);
    }
    let mut out = [0.0f32; 3];
    material.normal(g, layer, &mut out).map_err(Invalid::Shader)?;
    let v = Vec3::from_array(out);
    if !v.is_finite() {
        return Err(Invalid::NonFiniteClosure);
    }
    let v = v.normalize_or_zero();
    Ok(if v == Vec3::ZERO { n } else { v })
}

/// Everything the integrator derives from a material at one shading point, through the same
/// functions the path loop calls. Tests compare it across backends and optimisation levels;
/// it allocates, so it is not for the hot path.
#[derive(Clone, Debug, PartialEq)]
pub struct ShadingState {
    /// Rule-5 pick weights, bottom to top.
    pub weights: Vec<f32>,
    /// The transparency `w_T`.
    pub transparency: f32,
    /// The combined displacement of rule 6.
    pub displacement: f32,
    /// The bumped shading normal.
    pub normal: Vec3,
    /// Per layer with a positive weight: `(layer, closure, shading normal, channels)`.
    pub picked: Vec<(usize, Closure, Vec3, Vec<f32>)>,
}

/// Computes the [`ShadingState`] of `material` at `g` (`g.n` is the unbumped shading normal),
/// bumped as at a shading point whose footprint is 2e-3 scene units (a step of 1e-3).
pub fn shading_state(material: &dyn MaterialCode, g: &Globals) -> Result<ShadingState, Invalid> {
    let info = material.info();
    let nl = info.layers.len();
    let mut masks = vec![0.0; nl];
    let mut weights = vec![0.0; nl];
    let mut heights = vec![0.0; nl];
    material.masks(g, &mut masks).map_err(Invalid::Shader)?;
    let transparency = layering::pick_weights(&info.layers, &masks, &mut weights);
    material.displacement(g, &mut heights).map_err(Invalid::Shader)?;
    let displacement = layering::combine_displacement(&info.layers, &heights, &masks);
    let (mut a, mut b) = (vec![0.0; nl], vec![0.0; nl]);
    let step = bump_step(Vec3::from_array(g.p), SHADING_STATE_FOOTPRINT);
    let normal = bump(material, g, Relief::All, step, &mut a, &mut b, &mut heights)?;
    let mut bumped = *g;
    bumped.n = to_arr(normal);
    let mut picked = Vec::new();
    for layer in (0..nl).filter(|&l| weights[l] > 0.0) {
        let mut closure = Closure::default();
        material.surface(&bumped, layer, &mut closure).map_err(Invalid::Shader)?;
        let n = layer_normal(material, &bumped, layer)?;
        let mut channels = vec![0.0; info.channel_floats];
        material.channels(&bumped, layer, &mut channels).map_err(Invalid::Shader)?;
        picked.push((layer, closure, n, channels));
    }
    Ok(ShadingState { weights, transparency, displacement, normal, picked })
}

/// `ng` turned to the side of `w`.
fn facing(ng: Vec3, w: Vec3) -> Vec3 {
    if ng.dot(w) >= 0.0 { ng } else { -ng }
}

/// The normal that light sampling at a vertex with `lobes` is given (see [`Light::sample_li`]):
/// `ng` turned to `wo`'s side, or zero where a lobe transmits (rough glass), so that a
/// constant dome is sampled over the whole sphere and light through the surface gets its
/// share of next-event estimation, MIS-weighted against the transmission lobe.
fn light_side(lobes: &[Lobe], ng: Vec3, wo: Vec3) -> Vec3 {
    if lobes.iter().any(|l| l.bsdf.transmits()) { Vec3::ZERO } else { facing(ng, wo) }
}

/// The path vertex that chose the current ray direction (pbrt-v4's previous interaction).
struct Scatter {
    /// Where it scattered (the camera for primary rays).
    p: Vec3,
    /// The geometric normal on the side it scattered from (zero for the camera): light
    /// sampling there used it (see [`Light::sample_li`]), so its pdf does too.
    n: Vec3,
    /// The BSDF's solid-angle pdf of the direction; `None` for camera rays and delta lobes,
    /// which light sampling cannot reach.
    pdf: Option<f32>,
}

impl Scatter {
    /// MIS weight (power heuristic) of emission from `light` in direction `d`: the light pdf
    /// is that of sampling the light from this vertex, as [`Context::direct`] would have.
    fn mis(&self, light: &Light, d: Vec3, select: f32) -> f32 {
        match self.pdf {
            None => 1.0,
            Some(pdf) => power_heuristic(pdf, light.pdf_li(self.p, self.n, d) * select),
        }
    }
}

#[cfg(test)]
mod tests;
