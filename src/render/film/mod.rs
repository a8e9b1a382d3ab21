//! The rendering driver: camera samples per pixel, accumulated into AOV buffers.
//!
//! Pixel filter: box (each sample lands in its own pixel at a uniformly jittered position),
//! so every pixel depends only on its own samples. Samples use a counter-based RNG keyed by
//! (seed, pixel, sample) and are summed exactly ([`sum::ExactSum`]), which makes the image
//! bit-identical whatever the thread count and however the samples are split between passes
//! ([`Window`], [`WindowSums`]). Rows are rendered in parallel with rayon.

pub mod cryptomatte;
pub mod display;
pub mod output;
pub mod partial;
pub mod sum;

use crate::abi::ChannelKind;
use crate::abi::{MaterialCode, ShaderError};
use crate::render::integrator::{
    ChannelMap, ConstantDome, Context, EvalCounts, FaultSite, Invalid, LayerMode, MappedChannel, PathParams,
    PickStratum, SampleResult, Scratch,
};
use crate::render::material::closure::LayeringMode;
use crate::render::sampling::sampler::{PathSampler, SamplerKind, Slot};
use crate::render::scene::Scene;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::fmt;
use std::ops::Range;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
pub use sum::{ExactSum, PixelSums, WindowSums};
use sum::{add_coverage, add_each, add_fast, all_fast};

/// Bounces a path makes before Russian roulette may end it: Mitsuba 3's default. Ending
/// paths from the third bounce (strata's earlier rule) saved no measurable time under a dome,
/// where most paths escape on their own within a few bounces, and cost 1.3–1.8x the variance
/// per sample (docs/PERFORMANCE.md, "Russian roulette from the fifth bounce").
pub const DEFAULT_RR_DEPTH: u32 = 5;

/// What to render.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Camera samples per pixel.
    pub spp: u32,
    /// Seed of every random number.
    pub seed: u64,
    /// Worker threads (`None`: rayon's default, all cores).
    pub threads: Option<usize>,
    /// Maximum number of bounces.
    pub max_depth: u32,
    /// Bounces before Russian roulette may end a path ([`DEFAULT_RR_DEPTH`]).
    pub rr_depth: u32,
    /// Layer evaluation mode.
    pub mode: LayerMode,
    /// How each decision's numbers are spread over a pixel's samples.
    pub sampler: SamplerKind,
    /// How closures' `layer(top, base)` is rendered.
    pub layering: LayeringMode,
}

impl Default for RenderSettings {
    fn default() -> RenderSettings {
        RenderSettings {
            width: 640,
            height: 480,
            spp: 16,
            seed: 0,
            threads: None,
            max_depth: 8,
            rr_depth: DEFAULT_RR_DEPTH,
            mode: LayerMode::Auto,
            sampler: SamplerKind::default(),
            layering: LayeringMode::default(),
        }
    }
}

/// A rectangle of pixels of the image, `x`/`y` from the top-left corner.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Region {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

/// The part of an image one pass renders: a region of its pixels and a range of each pixel's
/// camera samples. Samples are keyed by their absolute pixel and sample index (the image's
/// `spp` still stratifies the layer pick), so a window's pixels are exactly the full render's
/// pixels over the same samples: a region of the full sample range equals that crop of the
/// full image bit for bit, and sample ranges that cover `0..spp` hold every sample once.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Window {
    /// The pixels (`None`: all of them).
    pub region: Option<Region>,
    /// The camera samples of each pixel (`None`: `0..spp`).
    pub samples: Option<Range<u32>>,
}

impl Window {
    /// The whole image, every sample.
    pub const FULL: Window = Window { region: None, samples: None };

    /// The region and sample range for `settings`, or why they do not fit its image.
    fn resolve(&self, settings: &RenderSettings) -> Result<(Region, Range<u32>), RenderError> {
        let full = Region { x: 0, y: 0, width: settings.width, height: settings.height };
        let region = self.region.unwrap_or(full);
        let inside = region.x.checked_add(region.width).is_some_and(|r| r <= settings.width)
            && region.y.checked_add(region.height).is_some_and(|b| b <= settings.height);
        if !inside || region.width == 0 || region.height == 0 {
            return Err(RenderError::BadSettings(format!(
                "region {}x{} at ({}, {}) is empty or outside the {}x{} image",
                region.width, region.height, region.x, region.y, settings.width, settings.height
            )));
        }
        let samples = self.samples.clone().unwrap_or(0..settings.spp);
        if samples.is_empty() || samples.end > settings.spp {
            return Err(RenderError::BadSettings(format!(
                "samples {}..{} are empty or outside 0..{}",
                samples.start, samples.end, settings.spp
            )));
        }
        Ok((region, samples))
    }
}

/// Pixel data of one image channel.
#[derive(Clone, Debug, PartialEq)]
pub enum ChannelData {
    /// Floats.
    F32(Vec<f32>),
    /// Unsigned integers (integer custom channels).
    U32(Vec<u32>),
}

/// One named channel, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// Full EXR channel name, e.g. `R`, `albedo.G`, `N.R`, `P.B`, `Z`, `mask.R`.
    pub name: String,
    /// Pixels.
    pub data: ChannelData,
}

/// A rendered multi-channel image.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channels: `R G B A`, `albedo.R/G/B`, `N.R/G/B`, `P.R/G/B`, `Z`, Cryptomatte, then
    /// custom channels by name (see [`render`] for what each holds).
    pub channels: Vec<Channel>,
}

impl Image {
    /// The float channel named `name`.
    pub fn f32_channel(&self, name: &str) -> Option<&[f32]> {
        self.channels.iter().find(|c| c.name == name).and_then(|c| match &c.data {
            ChannelData::F32(v) => Some(v.as_slice()),
            ChannelData::U32(_) => None,
        })
    }

    /// The integer channel named `name`.
    pub fn u32_channel(&self, name: &str) -> Option<&[u32]> {
        self.channels.iter().find(|c| c.name == name).and_then(|c| match &c.data {
            ChannelData::U32(v) => Some(v.as_slice()),
            ChannelData::F32(_) => None,
        })
    }
}

/// Counters reported after a render.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderStats {
    /// Camera samples traced.
    pub samples: u64,
    /// Samples discarded (black) because a shader failed: loop budget exceeded.
    pub loop_budget_errors: u64,
    /// Samples discarded because a shader indexed out of bounds.
    pub out_of_bounds_errors: u64,
    /// Samples discarded because a shader returned non-finite closure values.
    pub nonfinite_closures: u64,
    /// Samples whose radiance was NaN or infinite (discarded, black).
    pub nonfinite_samples: u64,
    /// Rays absorbed after passing through too many transparent surfaces.
    pub pass_through_limit: u64,
    /// Shader entry points the integrator called (masks, surfaces, displacement, normals,
    /// AOVs): what the scene paid for each feature.
    pub evals: EvalCounts,
    /// Warnings about channel layout (same name, different kinds across materials).
    pub warnings: Vec<String>,
    /// For each kind of shader fault that happened, where it first happened (in pixel order,
    /// so the same whatever the thread count).
    pub first_faults: Vec<FaultReport>,
    /// How each material's layers were evaluated, in material order.
    pub layer_modes: Vec<MaterialLayerMode>,
}

impl RenderStats {
    /// Adds `other`'s sample, fault and shader-call counters (rows of a render, passes of a
    /// window); warnings, first faults and layer modes are left as they are.
    pub fn add_counts(&mut self, other: &RenderStats) {
        self.samples += other.samples;
        self.loop_budget_errors += other.loop_budget_errors;
        self.out_of_bounds_errors += other.out_of_bounds_errors;
        self.nonfinite_closures += other.nonfinite_closures;
        self.nonfinite_samples += other.nonfinite_samples;
        self.pass_through_limit += other.pass_through_limit;
        self.evals.add(&other.evals);
    }
}

/// The layer evaluation one material got (`strata render --stats` prints one line each).
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialLayerMode {
    /// The material's name (its index when the scene has no names).
    pub material: String,
    /// Layers that can be picked ([`crate::abi::layering::liveness`]).
    pub pickable: usize,
    /// The evaluation used (never `Auto`).
    pub mode: LayerMode,
    /// Whether the automatic rule chose it ([`LayerMode::Auto`]) rather than an override.
    pub automatic: bool,
}

impl fmt::Display for MaterialLayerMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let why = if self.automatic { "auto" } else { "as set" };
        write!(f, "layers: {}: {} pickable, {} ({why})", self.material, self.pickable, self.mode.name())
    }
}

/// A kind of shader fault that discards a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// A loop ran past its iteration budget.
    LoopBudget,
    /// An array index was out of bounds.
    OutOfBounds,
    /// A closure parameter or shading normal was NaN or infinite.
    NonFiniteClosure,
}

impl FaultKind {
    const ALL: [FaultKind; 3] = [FaultKind::LoopBudget, FaultKind::OutOfBounds, FaultKind::NonFiniteClosure];

    fn of(invalid: Invalid) -> FaultKind {
        match invalid {
            Invalid::Shader(ShaderError::LoopBudget) => FaultKind::LoopBudget,
            Invalid::Shader(ShaderError::OutOfBounds) => FaultKind::OutOfBounds,
            Invalid::NonFiniteClosure => FaultKind::NonFiniteClosure,
        }
    }
}

impl fmt::Display for FaultKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FaultKind::LoopBudget => "loop budget exceeded",
            FaultKind::OutOfBounds => "array index out of bounds",
            FaultKind::NonFiniteClosure => "NaN/infinite closure value",
        })
    }
}

/// The first occurrence of one kind of shader fault.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultReport {
    /// What failed.
    pub kind: FaultKind,
    /// The prim whose material failed.
    pub prim: String,
    /// Index of its material in the materials given to [`render`].
    pub material: usize,
    /// The layer's slot, when one layer's entry point failed.
    pub slot: Option<String>,
    /// The pixel `(x, y)` and camera sample.
    pub pixel: (usize, usize),
    /// The camera sample within the pixel.
    pub sample: u32,
}

impl fmt::Display for FaultReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "first {}: prim `{}`, material {}", self.kind, self.prim, self.material)?;
        if let Some(slot) = &self.slot {
            write!(f, ", slot `{slot}`")?;
        }
        write!(f, ", pixel ({}, {}) sample {}", self.pixel.0, self.pixel.1, self.sample)
    }
}

/// The first fault of a kind in a row, before prim and slot are looked up.
#[derive(Clone, Copy, Debug)]
struct RowFault {
    site: FaultSite,
    x: usize,
    sample: u32,
}

impl RenderStats {
    /// The shader calls of the render per camera sample, one line for `strata render --stats`,
    /// then one line per material with more than one layer: how its layers were evaluated.
    pub fn evals_line(&self) -> String {
        let e = &self.evals;
        let per = |n: u64| n as f64 / self.samples.max(1) as f64;
        format!(
            "evaluated per camera sample: masks {:.3} (+ {:.3} on shadow rays), surfaces {:.3}, \
             displacement {:.3} (+ {:.3} weighting masks), normal maps {:.3}, AOV writes {:.3}, emission {:.3}",
            per(e.masks),
            per(e.shadow_masks),
            per(e.surfaces),
            per(e.displacements),
            per(e.displacement_masks),
            per(e.normals),
            per(e.channels),
            per(e.emissions)
        ) + &self.layer_modes.iter().filter(|m| m.pickable > 1).map(|m| format!("\n{m}")).collect::<String>()
    }

    /// Samples thrown away for any reason.
    pub fn invalid_samples(&self) -> u64 {
        self.loop_budget_errors + self.out_of_bounds_errors + self.nonfinite_closures + self.nonfinite_samples
    }
}

impl fmt::Display for RenderStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} samples", self.samples)?;
        let parts = [
            (self.loop_budget_errors, "discarded: a shader loop exceeded its iteration budget"),
            (self.out_of_bounds_errors, "discarded: a shader indexed an array out of bounds"),
            (self.nonfinite_closures, "discarded: a shader returned NaN/infinite closure values"),
            (self.nonfinite_samples, "discarded: NaN/infinite radiance"),
            (self.pass_through_limit, "absorbed after too many transparent surfaces"),
        ];
        for (n, what) in parts {
            if n > 0 {
                write!(f, "; {n} {what}")?;
            }
        }
        for fault in &self.first_faults {
            write!(f, "\n  {fault}")?;
        }
        Ok(())
    }
}

/// Why a render could not start.
#[derive(Debug, PartialEq)]
pub enum RenderError {
    /// Width, height or spp is 0, or the image is too large.
    BadSettings(String),
    /// A prim refers to a material index outside the slice.
    MissingMaterial {
        /// The prim.
        prim: String,
        /// Its material index.
        index: usize,
    },
    /// The thread pool could not be created.
    Threads(String),
}

impl fmt::Display for RenderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RenderError::BadSettings(s) => write!(f, "invalid render settings: {s}"),
            RenderError::MissingMaterial { prim, index } => {
                write!(f, "prim `{prim}` uses material {index}, which was not given")
            }
            RenderError::Threads(s) => write!(f, "cannot start render threads: {s}"),
        }
    }
}

impl std::error::Error for RenderError {}

/// A custom channel of the image.
#[derive(Clone, Debug)]
struct ImageChannel {
    name: String,
    kind: ChannelKind,
    offset: usize,
}

fn width(kind: ChannelKind) -> usize {
    if kind == ChannelKind::Color { 3 } else { 1 }
}

/// The union of all materials' channels, sorted by name, and where each material's go.
fn channel_layout(
    materials: &[&dyn MaterialCode],
    warnings: &mut Vec<String>,
) -> (Vec<ImageChannel>, usize, ChannelMap) {
    let mut names: Vec<(String, ChannelKind)> = Vec::new();
    for m in materials {
        for c in &m.info().channels {
            match names.iter().find(|(n, _)| *n == c.name) {
                Some((_, k)) if *k != c.kind => warnings.push(format!(
                    "custom channel `{}` is {:?} in one material and {:?} in another; the first kind is kept",
                    c.name, k, c.kind
                )),
                Some(_) => {}
                None => names.push((c.name.clone(), c.kind)),
            }
        }
    }
    names.sort_by(|a, b| a.0.cmp(&b.0));
    let mut offset = 0;
    let channels: Vec<ImageChannel> = names
        .into_iter()
        .map(|(name, kind)| {
            let c = ImageChannel { name, kind, offset };
            offset += width(kind);
            c
        })
        .collect();
    let map = materials
        .iter()
        .map(|m| {
            m.info()
                .channels
                .iter()
                .filter_map(|c| {
                    let g = channels.iter().find(|g| g.name == c.name)?;
                    let integer = g.kind == ChannelKind::Integer;
                    Some(MappedChannel { from: c.offset, to: g.offset, width: c.width().min(width(g.kind)), integer })
                })
                .collect()
        })
        .collect();
    (channels, offset, map)
}

/// The channels every render writes first, in order; the Cryptomatte channels and then the
/// materials' custom channels follow.
pub const BUILTIN_CHANNELS: [&str; 14] =
    ["R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.R", "N.G", "N.B", "P.R", "P.G", "P.B", "Z"];

/// `Z` where no sample of a pixel hit a surface. Finite, because compositing tools (depth
/// of field, fog, deep merges) misbehave on infinities; far beyond any scene's extent, so a
/// `Z < 1e9` test separates geometry from background.
pub const DEPTH_MISS: f32 = 1.0e10;

/// Per-row accumulation buffers.
struct Row {
    rgba: Vec<[f32; 4]>,
    albedo: Vec<Vec3>,
    normal: Vec<Vec3>,
    position: Vec<Vec3>,
    depth: Vec<f32>,
    /// Per pixel, the Cryptomatte `(id, coverage)` pairs of its most-covering prims.
    crypto: Vec<[f32; 2 * cryptomatte::RANKS]>,
    /// The same for composed materials (empty when the scene names no materials).
    crypto_material: Vec<[f32; 2 * cryptomatte::RANKS]>,
    channels: Vec<f32>,
    /// Each pixel's sums, when the caller wants them ([`render_sums`]).
    sums: Option<Vec<PixelSums>>,
    stats: RenderStats,
    /// The row's first fault of each [`FaultKind`] (indexed like `FaultKind::ALL`).
    faults: [Option<RowFault>; 3],
}

impl Row {
    /// An empty row of `width` pixels, keeping each pixel's sums when `keep_sums`.
    fn new(width: usize, channel_floats: usize, material_crypto: bool, keep_sums: bool) -> Row {
        Row {
            rgba: vec![[0.0; 4]; width],
            albedo: vec![Vec3::ZERO; width],
            normal: vec![Vec3::ZERO; width],
            position: vec![Vec3::ZERO; width],
            depth: vec![DEPTH_MISS; width],
            crypto: vec![[0.0; 2 * cryptomatte::RANKS]; width],
            crypto_material: vec![[0.0; 2 * cryptomatte::RANKS]; if material_crypto { width } else { 0 }],
            channels: vec![0.0; width * channel_floats],
            sums: keep_sums.then(|| Vec::with_capacity(width)),
            stats: RenderStats::default(),
            faults: [None; 3],
        }
    }

    /// Writes pixel `rx` from its sums: means over the samples (over the hits for `N` and `P`).
    fn finish(&mut self, rx: usize, px: &mut PixelSums, integer: &[bool], object_ids: &[f32], material_ids: &[f32]) {
        let channel_floats = integer.len();
        // Invalid samples count in the average as black (they are reported, not hidden).
        let mean = |k: usize, n: u32| px.builtin[k].mean(n);
        let n = px.samples;
        self.rgba[rx] = [mean(0, n), mean(1, n), mean(2, n), mean(3, n)];
        self.albedo[rx] = Vec3::new(mean(4, n), mean(5, n), mean(6, n));
        self.normal[rx] = Vec3::new(mean(7, px.hits), mean(8, px.hits), mean(9, px.hits)).normalize_or_zero();
        self.position[rx] = Vec3::new(mean(10, px.hits), mean(11, px.hits), mean(12, px.hits));
        self.depth[rx] = px.depth;
        self.crypto[rx] = cryptomatte::ranked(&mut px.objects, object_ids, n);
        if let Some(out) = self.crypto_material.get_mut(rx) {
            *out = cryptomatte::ranked(&mut px.materials, material_ids, n);
        }
        for (k, (out, sum)) in self.channels[rx * channel_floats..].iter_mut().zip(&px.channels).enumerate() {
            *out = if integer[k] { sum.value() as f32 } else { sum.mean(n) };
        }
    }
}

/// The peak memory of a `w` × `h` render with `custom_floats` custom-channel floats per pixel
/// (and the material Cryptomatte layer when `material_crypto`), and its channel count. Every
/// channel is an f32 per pixel; the rows' accumulation buffers hold all of them while the
/// image is assembled from them, and writing the EXR copies the image once more (plus the
/// 8-bit PNG preview): twice the image, plus 8 bytes per pixel.
pub fn film_bytes(w: usize, h: usize, custom_floats: usize, material_crypto: bool) -> (u64, usize) {
    let crypto = 2 * cryptomatte::RANKS * (1 + usize::from(material_crypto));
    let channels = BUILTIN_CHANNELS.len() + crypto + custom_floats;
    let per_pixel = 2 * 4 * channels as u64 + 8;
    ((w as u64).saturating_mul(h as u64).saturating_mul(per_pixel), channels)
}

/// Progress callback: `(rows done, rows total)`.
pub type Progress<'a> = &'a (dyn Fn(usize, usize) + Sync);

/// Renders `scene` through `materials` (indexed by `scene.prim_material`): the whole image,
/// every sample ([`render_window`] renders part of it).
///
/// The image's channels ([`BUILTIN_CHANNELS`], Cryptomatte, then custom channels):
/// - `R G B A`: linear Rec.709 radiance, premultiplied by `A`, the fraction of samples that
///   reached a non-transparent surface. Where the camera sees a visible dome, `RGB` holds the
///   dome's radiance with `A = 0` (additive emission, valid in premultiplied alpha: a comp
///   *over* a plate adds the sky); a dome with `strata:visibleToCamera = false` leaves `RGB`
///   at 0 there.
/// - `albedo.R/G/B`: albedo of the first hit, averaged over all samples (0 on misses).
/// - `N.R/G/B`: world-space shading normal of the first hit, averaged over the samples that
///   hit and renormalised (0 where none hit).
/// - `P.R/G/B`: world-space position of the first hit, averaged over the samples that hit
///   (0 where none hit).
/// - `Z`: camera-space depth (distance along the viewing axis, positive) of the nearest first
///   hit among the pixel's samples; [`DEPTH_MISS`] where none hit.
/// - `CryptoObject00.R/G/B/A`, `CryptoObject01.R/G/B/A`: Cryptomatte of the first hit's prim
///   path (see [`cryptomatte`]); coverages sum to `A`.
/// - `CryptoMaterial00/01.R/G/B/A`: the same for the composed material, when
///   `scene.material_names` names every material.
pub fn render(
    scene: &Scene,
    materials: &[&dyn MaterialCode],
    settings: &RenderSettings,
    progress: Option<Progress>,
) -> Result<(Image, RenderStats), RenderError> {
    render_window(scene, materials, settings, &Window::FULL, progress)
}

/// Renders the pixels and samples of `window` (see [`render`] for the channels): an image of
/// the region's size whose pixels average the window's samples. Progress counts the region's rows.
pub fn render_window(
    scene: &Scene,
    materials: &[&dyn MaterialCode],
    settings: &RenderSettings,
    window: &Window,
    progress: Option<Progress>,
) -> Result<(Image, RenderStats), RenderError> {
    render_impl(scene, materials, settings, window, progress, false).map(|(image, stats, _)| (image, stats))
}

/// [`render_window`], also returning each pixel's exact sums: windows of the same pixels over
/// other samples merge into them ([`WindowSums::merge`]), and [`image_from_sums`] makes the
/// image a single render of all their samples writes, bit for bit.
pub fn render_sums(
    scene: &Scene,
    materials: &[&dyn MaterialCode],
    settings: &RenderSettings,
    window: &Window,
    progress: Option<Progress>,
) -> Result<(Image, RenderStats, WindowSums), RenderError> {
    let (image, stats, sums) = render_impl(scene, materials, settings, window, progress, true)?;
    Ok((image, stats, sums.unwrap_or_default()))
}

/// The image of merged window sums (see [`render`] for the channels): `scene` and `materials`
/// must be those the sums were rendered with.
pub fn image_from_sums(scene: &Scene, materials: &[&dyn MaterialCode], sums: &WindowSums) -> Image {
    image_from_layout(&sums_layout(scene, materials), sums)
}

/// What turns a window's sums into its image besides the sums themselves: the custom
/// channels and the Cryptomatte IDs. A farm's partial files carry it, so merging them needs
/// no scene ([`partial`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SumsLayout {
    /// The custom channels, sorted by name, as the image lists them.
    pub channels: Vec<(String, ChannelKind)>,
    /// Each prim index's Cryptomatte ID (only the indices the sums name need be right).
    pub object_ids: Vec<f32>,
    /// Each material index's ID, when the image has a material Cryptomatte layer.
    pub material_ids: Option<Vec<f32>>,
}

impl SumsLayout {
    /// Custom-channel floats per pixel.
    pub fn channel_floats(&self) -> usize {
        self.channels.iter().map(|(_, kind)| width(*kind)).sum()
    }

    /// Which custom-channel floats belong to integer channels.
    pub fn integer(&self) -> Vec<bool> {
        self.channels.iter().flat_map(|(_, kind)| vec![*kind == ChannelKind::Integer; width(*kind)]).collect()
    }
}

/// The layout of the images `scene` renders through `materials`.
pub fn sums_layout(scene: &Scene, materials: &[&dyn MaterialCode]) -> SumsLayout {
    let (channels, _, _) = channel_layout(materials, &mut Vec::new());
    let (object_ids, material_ids) = crypto_ids(scene, materials);
    SumsLayout {
        channels: channels.into_iter().map(|c| (c.name, c.kind)).collect(),
        object_ids,
        material_ids: (!material_ids.is_empty()).then_some(material_ids),
    }
}

/// The image of merged window sums with `layout`'s channels and IDs.
pub fn image_from_layout(layout: &SumsLayout, sums: &WindowSums) -> Image {
    let mut offset = 0;
    let channels: Vec<ImageChannel> = layout
        .channels
        .iter()
        .map(|(name, kind)| {
            let c = ImageChannel { name: name.clone(), kind: *kind, offset };
            offset += width(*kind);
            c
        })
        .collect();
    let channel_floats = offset;
    let material_ids = layout.material_ids.as_deref().unwrap_or(&[]);
    let material_crypto = layout.material_ids.is_some();
    let region = sums.region;
    let rows: Vec<Row> = sums
        .pixels
        .chunks(region.width.max(1))
        .map(|pixels| {
            let mut row = Row::new(region.width, channel_floats, material_crypto, false);
            for (rx, px) in pixels.iter().enumerate() {
                row.finish(rx, &mut px.clone(), &sums.integer, &layout.object_ids, material_ids);
            }
            row
        })
        .collect();
    assemble(&rows, region.width, region.height, &channels, channel_floats, material_crypto)
}

/// The Cryptomatte IDs of the scene's prims and, when the scene names every material, of its
/// materials (else empty).
fn crypto_ids(scene: &Scene, materials: &[&dyn MaterialCode]) -> (Vec<f32>, Vec<f32>) {
    let objects = scene.prims.iter().map(|p| cryptomatte::id(&p.path)).collect();
    let materials = if scene.material_names.len() == materials.len() {
        scene.material_names.iter().map(|n| cryptomatte::id(n)).collect()
    } else {
        Vec::new()
    };
    (objects, materials)
}

fn render_impl(
    scene: &Scene,
    materials: &[&dyn MaterialCode],
    settings: &RenderSettings,
    window: &Window,
    progress: Option<Progress>,
    keep_sums: bool,
) -> Result<(Image, RenderStats, Option<WindowSums>), RenderError> {
    let (w, h) = (settings.width, settings.height);
    if w == 0 || h == 0 || settings.spp == 0 {
        return Err(RenderError::BadSettings(format!("{w}x{h} at {} spp", settings.spp)));
    }
    if w.checked_mul(h).is_none_or(|n| n > 1 << 28) {
        return Err(RenderError::BadSettings(format!("{w}x{h} is too large")));
    }
    for (prim, &index) in scene.prims.iter().zip(&scene.prim_material) {
        if index >= materials.len() {
            return Err(RenderError::MissingMaterial { prim: prim.path.clone(), index });
        }
    }
    let (region, samples) = window.resolve(settings)?;
    let mut warnings = Vec::new();
    let (channels, channel_floats, channel_map) = channel_layout(materials, &mut warnings);
    let material_crypto = scene.material_names.len() == materials.len();
    let (rw, rh) = (region.width, region.height);
    let film = film_bytes(rw, rh, channel_floats, material_crypto);
    crate::input::check_memory(&format!("a {rw} x {rh} film of {} channels", film.1), film.0)
        .map_err(RenderError::BadSettings)?;
    let camera = scene.camera.with_aspect(w as f32 / h as f32);
    let moving = scene.has_motion();
    let primvar_slots = crate::render::integrator::primvar_slots(scene, materials);
    let layer_modes: Vec<LayerMode> = materials.iter().map(|m| settings.mode.resolve(*m)).collect();
    let certain_picks = crate::render::integrator::certain_picks(materials, &layer_modes);
    let hittable_lights: Vec<usize> = (0..scene.lights.len()).filter(|&i| scene.lights[i].is_hittable()).collect();
    let light_selection = crate::render::light::LightSelection::with_emitters(
        &scene.lights,
        &scene.emitters.list.iter().map(|e| e.power).collect::<Vec<_>>(),
        (scene.bounds.1 - scene.bounds.0).length() / 2.0,
    );
    let ctx = Context {
        layer_modes: &layer_modes,
        scene,
        materials,
        channel_map: &channel_map,
        params: PathParams {
            max_depth: settings.max_depth,
            rr_depth: settings.rr_depth,
            mode: settings.mode,
            layering: settings.layering,
        },
        all_opaque: materials.iter().all(|m| crate::render::integrator::is_opaque(*m)),
        hittable_lights: &hittable_lights,
        constant_dome: ConstantDome::of(&scene.lights, &light_selection),
        light_selection,
        primvar_slots: &primvar_slots,
        certain_picks: &certain_picks,
        pixel_spread: camera.pixel_angle(w),
    };
    let done = AtomicUsize::new(0);
    let progress_lock = Mutex::new(());
    let (object_ids, material_ids) = crypto_ids(scene, materials);
    let integer: Vec<bool> =
        (0..channel_floats).map(|k| channels.iter().any(|c| c.kind == ChannelKind::Integer && c.offset == k)).collect();
    let render_row = |y: usize, scratch: &mut Scratch| -> Row {
        // Counted per row on this thread's scratch, no atomics in the sample loop.
        scratch.counts = EvalCounts::default();
        let mut px = PixelSums::default();
        let mut row = Row::new(rw, channel_floats, !material_ids.is_empty(), keep_sums);
        for (rx, x) in (region.x..region.x + rw).enumerate() {
            // Keyed by the pixel's place in the whole image, so a window's numbers are the
            // full render's.
            let pixel = (y * w + x) as u64;
            px.reset(channel_floats);
            let pixel_key = PathSampler::pixel_key(settings.seed, pixel);
            // The pixel's corner and the image's size in floats, converted once per pixel.
            let (corner, size) = (Vec2::new(x as f32, y as f32), Vec2::new(w as f32, h as f32));
            for sample in samples.clone() {
                let mut sampler = PathSampler::of_pixel(settings.sampler, pixel_key, sample);
                let jitter = sampler.get2(Slot::Pixel);
                let film = (corner + jitter) / size;
                // Numbers are counter based: skipping the lens draw of a pinhole camera
                // changes no other decision's numbers.
                let lens = if camera.has_lens() { sampler.get2(Slot::Lens) } else { Vec2::ZERO };
                // Likewise the time: drawn only where something moves while the shutter is open.
                let ray = if moving {
                    scratch.time = sampler.get1(Slot::Time);
                    match &scene.camera_motion {
                        Some(keys) => camera.placed_at(keys.at(scratch.time).into()).ray(film, lens),
                        None => camera.ray(film, lens),
                    }
                } else {
                    camera.ray(film, lens)
                };
                // Stratified over the pixel's samples: sample k picks in [k, k + 1) / spp.
                let first_pick = PickStratum { index: sample, count: settings.spp };
                row.stats.samples += 1;
                px.samples += 1;
                let traced = ctx.trace(ray.o, ray.d, ray.tmin, ray.tmax, first_pick, &mut sampler, scratch);
                // The 13 values the exact sums take: colour (radiance, alpha, albedo) over all
                // samples, geometry (normal, position) over the hits.
                let colour_of = |r: &SampleResult| {
                    let (c, a) = (r.radiance, r.albedo);
                    [c.x, c.y, c.z, r.alpha, a.x, a.y, a.z]
                };
                let geometry_of = |r: &SampleResult| {
                    let (n, p) = (r.normal, r.position);
                    [n.x, n.y, n.z, p.x, p.y, p.z]
                };
                // Almost every sample's values are all in the exact sums' fast range, which
                // holds finite values only: one test of the 13 then stands for the finite check
                // and both groups' range tests (`add_fast`); any other sample takes the tests
                // one by one.
                let fast = traced.as_ref().is_ok_and(|r| all_fast(&colour_of(r)) & all_fast(&geometry_of(r)));
                match traced {
                    Ok(r) if fast || (r.radiance.is_finite() && r.albedo.is_finite() && r.normal.is_finite()) => {
                        row.stats.pass_through_limit += u64::from(r.pass_limit);
                        // Fixed-size arrays, not chained iterators: the adds unroll (a chain of
                        // three iterators cost about 100 instructions a sample).
                        let sums = &mut px.builtin;
                        if let Some(colour) = sums.first_chunk_mut::<7>() {
                            if fast { add_fast(colour, colour_of(&r)) } else { add_each(colour, colour_of(&r)) }
                        }
                        if r.alpha > 0.0 {
                            if let Some(geometry) = sums.last_chunk_mut::<6>() {
                                if fast {
                                    add_fast(geometry, geometry_of(&r))
                                } else {
                                    add_each(geometry, geometry_of(&r))
                                }
                            }
                            px.hits += 1;
                            if let Some(prim) = r.prim {
                                add_coverage(&mut px.objects, prim, r.alpha);
                                if let Some(&m) = scene.prim_material.get(prim as usize) {
                                    add_coverage(&mut px.materials, m as u32, r.alpha);
                                }
                            }
                            // Depth along the viewing axis, not along the ray; the lens
                            // origin of a depth-of-field ray lies in the plane of the camera.
                            let z = (r.position - camera.origin()).dot(camera.forward());
                            if z.is_finite() {
                                px.depth = px.depth.min(z.max(0.0));
                            }
                        }
                        // Integer channels take the sample nearest the pixel centre (a
                        // production renderer's "closest" filter): an id a sample really hit,
                        // never a blend, and since a sample's position says nothing about its
                        // layer pick, each id's share over many pixels is its layer's weight.
                        // (The most frequent id would not do: at 16 spp a layer of weight 0.3
                        // is the majority of almost no pixel.) Ties go to the earlier sample.
                        let nearest = ((jitter - Vec2::splat(0.5)).length_squared(), sample);
                        let is_nearest = nearest < px.nearest;
                        if is_nearest {
                            px.nearest = nearest;
                        }
                        for (k, sum) in px.channels.iter_mut().enumerate() {
                            let v = scratch.channels[k];
                            let v = if v.is_finite() { v } else { 0.0 };
                            if !integer[k] {
                                sum.add(v);
                            } else if is_nearest {
                                *sum = ExactSum::of(v);
                            }
                        }
                    }
                    Ok(_) => row.stats.nonfinite_samples += 1,
                    Err(invalid) => {
                        let kind = FaultKind::of(invalid);
                        match kind {
                            FaultKind::LoopBudget => row.stats.loop_budget_errors += 1,
                            FaultKind::OutOfBounds => row.stats.out_of_bounds_errors += 1,
                            FaultKind::NonFiniteClosure => row.stats.nonfinite_closures += 1,
                        }
                        // Where the failing shader ran: the integrator keeps `site` current.
                        let first = &mut row.faults[kind as usize];
                        if first.is_none() {
                            *first = Some(RowFault { site: scratch.site, x, sample });
                        }
                    }
                }
            }
            row.finish(rx, &mut px, &integer, &object_ids, &material_ids);
            if let Some(sums) = &mut row.sums {
                sums.push(px.clone());
            }
        }
        row.stats.evals = scratch.counts;
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        if let Some(progress) = progress {
            let _guard = progress_lock.lock();
            progress(n, rh);
        }
        row
    };
    let run = || -> Vec<Row> {
        (region.y..region.y + rh)
            .into_par_iter()
            .map_init(|| Scratch::new(materials, channel_floats), |scratch, y| render_row(y, scratch))
            .collect()
    };
    let rows = match settings.threads {
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build()
            .map_err(|e| RenderError::Threads(e.to_string()))?
            .install(run),
        None => run(),
    };
    // Assemble channels and stats in row order.
    let layer_modes = materials
        .iter()
        .zip(&layer_modes)
        .enumerate()
        .map(|(k, (m, &mode))| MaterialLayerMode {
            material: scene.material_names.get(k).cloned().unwrap_or_else(|| format!("#{k}")),
            pickable: crate::abi::layering::pickable_count(&m.info().layers),
            mode,
            automatic: settings.mode == LayerMode::Auto,
        })
        .collect();
    let mut stats = RenderStats { warnings, layer_modes, ..RenderStats::default() };
    for (y, row) in (region.y..).zip(&rows) {
        for (kind, fault) in FaultKind::ALL.into_iter().zip(row.faults) {
            if let Some(fault) = fault
                && !stats.first_faults.iter().any(|f| f.kind == kind)
            {
                let prim = fault.site.prim as usize;
                let material = scene.prim_material.get(prim).copied().unwrap_or(0);
                let slot = fault
                    .site
                    .layer
                    .and_then(|l| Some(materials.get(material)?.info().layers.get(l as usize)?.slot.clone()));
                stats.first_faults.push(FaultReport {
                    kind,
                    prim: scene.prims.get(prim).map(|p| p.path.clone()).unwrap_or_default(),
                    material,
                    slot,
                    pixel: (fault.x, y),
                    sample: fault.sample,
                });
            }
        }
        stats.add_counts(&row.stats);
    }
    let image = assemble(&rows, rw, rh, &channels, channel_floats, !material_ids.is_empty());
    let sums = keep_sums.then(|| WindowSums {
        region,
        samples: vec![samples],
        pixels: rows.into_iter().flat_map(|row| row.sums.unwrap_or_default()).collect(),
        integer,
    });
    Ok((image, stats, sums))
}

/// The image of finished rows: its channels in [`render`]'s order.
fn assemble(
    rows: &[Row],
    rw: usize,
    rh: usize,
    channels: &[ImageChannel],
    channel_floats: usize,
    material_crypto: bool,
) -> Image {
    let n = rw * rh;
    let mut planes: Vec<Vec<f32>> = vec![Vec::with_capacity(n); BUILTIN_CHANNELS.len() + channel_floats];
    for row in rows {
        for x in 0..rw {
            let values = [
                row.rgba[x][0],
                row.rgba[x][1],
                row.rgba[x][2],
                row.rgba[x][3],
                row.albedo[x].x,
                row.albedo[x].y,
                row.albedo[x].z,
                row.normal[x].x,
                row.normal[x].y,
                row.normal[x].z,
                row.position[x].x,
                row.position[x].y,
                row.position[x].z,
                row.depth[x],
            ];
            for (plane, v) in planes.iter_mut().zip(values) {
                plane.push(v);
            }
            for k in 0..channel_floats {
                planes[BUILTIN_CHANNELS.len() + k].push(row.channels[x * channel_floats + k]);
            }
        }
    }
    let mut planes = planes.into_iter();
    let mut out = Vec::new();
    for name in BUILTIN_CHANNELS {
        out.push(Channel { name: name.into(), data: ChannelData::F32(planes.next().unwrap_or_default()) });
    }
    for (k, name) in cryptomatte::channel_names(cryptomatte::OBJECT_LAYER).into_iter().enumerate() {
        let plane = rows.iter().flat_map(|row| row.crypto.iter().map(move |px| px[k])).collect();
        out.push(Channel { name, data: ChannelData::F32(plane) });
    }
    if material_crypto {
        for (k, name) in cryptomatte::channel_names(cryptomatte::MATERIAL_LAYER).into_iter().enumerate() {
            let plane = rows.iter().flat_map(|row| row.crypto_material.iter().map(move |px| px[k])).collect();
            out.push(Channel { name, data: ChannelData::F32(plane) });
        }
    }
    for c in channels {
        let suffixes: &[&str] = if c.kind == ChannelKind::Color { &[".R", ".G", ".B"] } else { &[""] };
        for suffix in suffixes {
            let plane = planes.next().unwrap_or_default();
            let data = if c.kind == ChannelKind::Integer {
                ChannelData::U32(plane.iter().map(|&v| v.round().clamp(0.0, u32::MAX as f32) as u32).collect())
            } else {
                ChannelData::F32(plane)
            };
            out.push(Channel { name: format!("{}{suffix}", c.name), data });
        }
    }
    Image { width: rw, height: rh, channels: out }
}
