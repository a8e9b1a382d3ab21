//! The contract between compiled materials and the renderer: `#[repr(C)]` shading globals and
//! closure values, the entry points every backend provides ([`MaterialCode`]), and what the
//! renderer needs to know about a material's layers ([`MaterialInfo`]).
//!
//! Architecture invariant: the renderer sees only this module — entry points, closure values
//! and layer metadata — never the IR or a backend.

use std::fmt;

pub mod layering;

/// The kind of value a custom channel carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ChannelKind {
    /// RGB.
    Color,
    /// One float.
    Float,
    /// One integer.
    Integer,
}

impl ChannelKind {
    /// The node type that declares this kind of channel.
    pub fn node_type(self) -> &'static str {
        match self {
            ChannelKind::Color => "customChannelColor",
            ChannelKind::Float => "customChannelFloat",
            ChannelKind::Integer => "customChannelInteger",
        }
    }

    /// Recognises custom-channel node types by name.
    pub fn from_node_type(name: &str) -> Option<ChannelKind> {
        [ChannelKind::Color, ChannelKind::Float, ChannelKind::Integer].into_iter().find(|k| k.node_type() == name)
    }
}

/// How a layer's displacement combines with the layers below (DESIGN.md rule 6).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DisplacementMode {
    /// Adds everywhere, ignoring masks.
    None,
    /// Adds `mask · height`.
    Add,
    /// Blends `D ← lerp(D, height, mask)`.
    Mix,
}

impl DisplacementMode {
    /// The mode's name in source.
    pub fn name(self) -> &'static str {
        match self {
            DisplacementMode::None => "none",
            DisplacementMode::Add => "add",
            DisplacementMode::Mix => "mix",
        }
    }
}

/// Inputs of one shading point, in world space. Field order is the C ABI.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Globals<'a> {
    /// Shading position `P`.
    pub p: [f32; 3],
    /// Shading normal `N` (unit, facing the incoming ray's side as the renderer decides).
    pub n: [f32; 3],
    /// Geometric normal `Ng`.
    pub ng: [f32; 3],
    /// Incident direction `I` (from the eye towards `P`, unit).
    pub i: [f32; 3],
    /// Tangent `dPdu`.
    pub dpdu: [f32; 3],
    /// Tangent `dPdv`.
    pub dpdv: [f32; 3],
    /// Texture coordinate `u` (s).
    pub u: f32,
    /// Texture coordinate `v` (t).
    pub v: f32,
    /// The ray's footprint in texture (st) space, the axes of the ray cone's ellipse on the
    /// surface as diameters: (ds, dt) across the cone and (ds, dt) along the ray's projection.
    /// Texture lookups filter over it (zeros: unfiltered, the finest level bilinearly).
    pub st_footprint: [f32; 4],
    /// The primvars the material reads, interpolated at this point, laid out as
    /// [`MaterialInfo::primvars`] says (empty: every primvar reads its fallback).
    pub primvars: PrimvarValues<'a>,
    /// The material instance's parameter block: its live inputs (a view's editable substance
    /// inputs, compiled as parameters rather than folded constants), laid out as
    /// `compose::ComposedMaterial::parameter_block` says. Empty for materials compiled
    /// with their inputs folded, which never read it; [`ParameterInstance`] sets it.
    pub params: PrimvarValues<'a>,
}

/// A borrowed `[f32]` in C layout (`const float *values; uint32_t len;`): the primvar values
/// of one shading point. Compiled code reads word `i` only when `i < len` (0 otherwise), so
/// any length is safe, the empty default included.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimvarValues<'a> {
    values: *const f32,
    len: u32,
    _borrow: std::marker::PhantomData<&'a [f32]>,
}

// SAFETY: a `PrimvarValues` is a shared borrow of `[f32]` (only ever built from one, read-only),
// which is `Send` and `Sync`.
unsafe impl Send for PrimvarValues<'_> {}
unsafe impl Sync for PrimvarValues<'_> {}

impl Default for PrimvarValues<'_> {
    fn default() -> Self {
        PrimvarValues::new(&[])
    }
}

impl<'a> PrimvarValues<'a> {
    /// Borrows `values` (at most `u32::MAX` of them are visible).
    pub fn new(values: &'a [f32]) -> PrimvarValues<'a> {
        let len = values.len().min(u32::MAX as usize) as u32;
        PrimvarValues { values: values.as_ptr(), len, _borrow: std::marker::PhantomData }
    }

    /// The values.
    pub fn as_slice(&self) -> &'a [f32] {
        // SAFETY: built from a `&'a [f32]` of at least `len` elements.
        unsafe { std::slice::from_raw_parts(self.values, self.len as usize) }
    }

    /// Word `index`, or 0 past the end: what compiled code reads.
    #[inline]
    pub fn get(&self, index: u32) -> f32 {
        self.as_slice().get(index as usize).copied().unwrap_or(0.0)
    }
}

/// Byte offsets of [`Globals::primvars`]' pointer and length, for code generation.
pub const PRIMVARS_PTR_OFFSET: usize = std::mem::offset_of!(Globals<'static>, primvars);
/// See [`PRIMVARS_PTR_OFFSET`].
pub const PRIMVARS_LEN_OFFSET: usize = PRIMVARS_PTR_OFFSET + std::mem::offset_of!(PrimvarValues<'static>, len);

/// Byte offsets of [`Globals::params`]' pointer and length, for code generation.
pub const PARAMS_PTR_OFFSET: usize = std::mem::offset_of!(Globals<'static>, params);
/// See [`PARAMS_PTR_OFFSET`].
pub const PARAMS_LEN_OFFSET: usize = PARAMS_PTR_OFFSET + std::mem::offset_of!(PrimvarValues<'static>, len);

/// A primvar a material reads: the renderer writes, at `offset` of [`Globals::primvars`], 1
/// when the shaded prim has it (0 when not: the reader's fallback is used), then `width`
/// components interpolated at the shading point (components the primvar lacks are 0).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct PrimvarInfo {
    /// The primvar's name without `primvars:` (`displayColor`, `st`).
    pub name: String,
    /// Components read: 1 (float), 3 (triples) or 4 (a 4-component primvar, whose fourth
    /// `primvar_alpha` reads).
    pub width: usize,
    /// Index of its presence flag; the components follow.
    pub offset: usize,
}

/// Which BSDF a [`Closure`] describes.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ClosureKind {
    /// No BSDF: the layer absorbs (black).
    None = 0,
    /// Lambert: `params = [albedo.r, albedo.g, albedo.b]`.
    Diffuse = 1,
    /// GGX dielectric coat over diffuse: `[albedo rgb, specular rgb, roughness, ior]`.
    Glossy = 2,
    /// GGX conductor: `[reflectivity rgb, edge_tint rgb, roughness, film thickness, film ior,
    /// film weight]` ([`thin_film_words`]).
    Metal = 3,
    /// Rough dielectric: `[tint rgb, roughness, ior]`.
    Glass = 4,
    /// GGX conductor from its complex index: `[eta rgb, k rgb, roughness, film thickness, film
    /// ior, film weight]` ([`thin_film_words`]).
    Conductor = 5,
    /// GGX dielectric interface: `[tint rgb, ior, roughness, scatter, film thickness (nm),
    /// film ior, film weight, darkening rgb]`, scatter 0 reflects only (a coat), 1 transmits
    /// only, 2 does both, 3 and 4 are 1 and 2 on a thin-walled sheet
    /// ([`THIN_WALLED_SCATTER`]); a film thickness or weight of 0 is no thin film
    /// ([`thin_film_words`]); darkening ([`TERM_DARKENING`]) is what a coat's darkening
    /// removed from the terms under it.
    Dielectric = 6,
    /// GGX reflection with the generalized Schlick Fresnel and F82 tint:
    /// `[color0 rgb, color82 rgb, color90 rgb, exponent, roughness, film thickness, film ior,
    /// film weight]` ([`thin_film_words`]).
    GeneralizedSchlick = 7,
    /// Oren–Nayar diffuse: `[albedo rgb, roughness, energy_compensation (0 or 1)]`.
    OrenNayar = 8,
    /// Burley (Disney) diffuse: `[albedo rgb, roughness]`.
    Burley = 9,
    /// Charlie sheen (Estevez and Kulla 2017): `[color rgb, roughness]`.
    Sheen = 10,
    /// Diffuse transmission (MaterialX `translucent_bsdf`): `[albedo rgb]`.
    Translucent = 11,
}

impl ClosureKind {
    /// Decodes the `kind` field; unknown values are `None`.
    pub fn from_u32(kind: u32) -> ClosureKind {
        match kind {
            1 => ClosureKind::Diffuse,
            2 => ClosureKind::Glossy,
            3 => ClosureKind::Metal,
            4 => ClosureKind::Glass,
            5 => ClosureKind::Conductor,
            6 => ClosureKind::Dielectric,
            7 => ClosureKind::GeneralizedSchlick,
            8 => ClosureKind::OrenNayar,
            9 => ClosureKind::Burley,
            10 => ClosureKind::Sheen,
            11 => ClosureKind::Translucent,
            _ => ClosureKind::None,
        }
    }
}

/// One lobe with unit weight: the closure of the kinds whose parameters fit in eight words
/// (every kind but [`ClosureKind::GeneralizedSchlick`]). What [`MaterialCode::surface`]
/// returns; a material's full closure value is a [`ClosureSum`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Closure {
    /// A [`ClosureKind`] as `u32`.
    pub kind: u32,
    /// Parameters; meaning per kind (see [`ClosureKind`]). Unused entries are 0.
    pub params: [f32; 8],
}

/// Most terms one closure value holds; a closure expression that could need more is a
/// compile-time error at the operator that overflows, never a silent drop.
pub const MAX_CLOSURE_TERMS: usize = 8;
/// Parameter words of one [`ClosureTerm`].
pub const TERM_PARAMS: usize = 19;
/// Where a term's own shading normal starts in its parameters (three words, world space; zero:
/// the layer's shading normal), set by `with_normal`. Every kind's parameters end before it
/// but [`ClosureKind::GeneralizedSchlick`]'s, which has no normal of its own.
pub const TERM_NORMAL: usize = 12;
/// Where a term's tangent starts in its parameters (three words, world space; zero: the
/// layer's shading frame picks one), set by `with_anisotropy`: the direction along which a
/// GGX lobe's width is `αx` ([`TERM_ASPECT`]). Every kind's parameters end before it.
pub const TERM_TANGENT: usize = 15;
/// Where a term's GGX aspect is in its parameters, set by `with_anisotropy`: `√(αx / αy)`,
/// the ratio of the widths along the tangent ([`TERM_TANGENT`]) and the bitangent to their
/// geometric mean `α = √(αx αy)`, which the kind's roughness word keeps (`α = r²`). 0 (or 1):
/// isotropic. Read by the GGX kinds (glossy, metal, glass, conductor, dielectric,
/// generalized Schlick); the others ignore it.
pub const TERM_ASPECT: usize = 18;
/// Where a term's thin film is in its parameters, for the kinds that take one: three words,
/// thickness in nanometres, the film's index and its weight (coverage; thickness or weight 0:
/// none), set by `with_thin_film`. Dielectrics at 6 (a transmitting one's microfacets reflect
/// the film's reflectance and transmit the rest, from either side), metals and conductors
/// at 7, generalized Schlick at 11.
pub const fn thin_film_words(kind: ClosureKind) -> Option<usize> {
    match kind {
        ClosureKind::Dielectric => Some(6),
        ClosureKind::Metal | ClosureKind::Conductor => Some(7),
        ClosureKind::GeneralizedSchlick => Some(11),
        _ => None,
    }
}
/// The kinds [`thin_film_words`] places a film in.
pub const THIN_FILM_KINDS: [ClosureKind; 4] =
    [ClosureKind::Dielectric, ClosureKind::Metal, ClosureKind::Conductor, ClosureKind::GeneralizedSchlick];
/// Where a [`ClosureKind::Dielectric`] term (a coat) records the darkening applied to the
/// terms under it: `1 − factor` per channel (0: none), set by `with_darkening`. Albedo
/// scaling ignores it (the factor stands in for the coat's internal reflections, which it
/// omits); the random walk simulates those reflections and divides the factor back out.
pub const TERM_DARKENING: usize = 9;

/// What `with_thin_walled` adds to a transmitting [`ClosureKind::Dielectric`] term's scatter
/// word (parameter 5: "T" 1 becomes 3, "RT" 2 becomes 4): the interface is then a thin-walled
/// sheet with no interior (the sheet's reflectance, transmission straight through, no medium
/// entered; `render::material::lobes::thin`). A reflecting-only term (a coat) is left as it is.
pub const THIN_WALLED_SCATTER: f32 = 2.0;
/// The scatter word of a [`ClosureKind::Dielectric`] term.
pub const DIELECTRIC_SCATTER: usize = 5;

/// One weighted lobe of a [`ClosureSum`]. Field order is the C ABI (24 words).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClosureTerm {
    /// A [`ClosureKind`] as `u32` (`None`: an empty term).
    pub kind: u32,
    /// Vertical layering: bit `j` set when term `j` lies above this one (`layer(top, base)`
    /// sets the bits of `top`'s terms in each of `base`'s). Only lower indices can be set.
    pub above: u32,
    /// Colour weight (`closure * color`, `mix`); the lobe's own parameters are unweighted.
    pub weight: [f32; 3],
    /// Parameters; meaning per kind (see [`ClosureKind`]). Unused entries are 0.
    pub params: [f32; TERM_PARAMS],
}

impl ClosureTerm {
    /// Whether the term is not empty (kind not `None`) and has a NaN or infinite weight or
    /// parameter.
    #[inline]
    pub fn is_non_finite(&self) -> bool {
        // A magnitude's bits at or above the exponent's all-ones: infinite or NaN. Compared as
        // i32 (the magnitude is never negative) and or-ed without branches, the test runs four
        // words at a time in SSE2, which has no unsigned 32-bit max.
        let non_finite = |x: &f32| (x.to_bits() & 0x7fff_ffff) as i32 >= 0x7f80_0000;
        let any = |words: &[f32]| words.iter().fold(false, |m, x| m | non_finite(x));
        self.kind != ClosureKind::None as u32 && (any(&self.weight) | any(&self.params))
    }

    /// A single closure with unit weight.
    pub fn from_closure(c: &Closure) -> ClosureTerm {
        let mut params = [0.0; TERM_PARAMS];
        params[..8].copy_from_slice(&c.params);
        ClosureTerm { kind: c.kind, above: 0, weight: [1.0; 3], params }
    }
}

/// A material's closure value as compiled code returns it: a weighted sum of lobes with
/// vertical layering (OSL-style closure algebra: `closure * color`, `closure + closure`,
/// `mix(a, b, t)`, `layer(top, base)`). Term positions are fixed when compiling, so a term
/// of kind `None` (empty) may sit between others. Field order is the C ABI.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClosureSum {
    /// The terms, top layers first.
    pub terms: [ClosureTerm; MAX_CLOSURE_TERMS],
}

impl ClosureSum {
    /// 4-byte words of a closure value (what compiled code writes).
    pub const WORDS: usize = std::mem::size_of::<ClosureSum>() / 4;

    /// The sum holding `c` alone with unit weight.
    pub fn single(c: &Closure) -> ClosureSum {
        let mut sum = ClosureSum::default();
        sum.terms[0] = ClosureTerm::from_closure(c);
        sum
    }

    /// Whether a non-empty term (kind not `None`) has a NaN or infinite weight or parameter.
    /// Empty terms are skipped, as every reader skips them (most of a material's are empty).
    #[inline]
    pub fn has_non_finite(&self) -> bool {
        self.terms.iter().any(ClosureTerm::is_non_finite)
    }

    /// The first non-empty term as a single closure (parameters past the eighth dropped), or
    /// the default (`None`) closure.
    pub fn first(&self) -> Closure {
        let Some(t) = self.terms.iter().find(|t| t.kind != ClosureKind::None as u32) else { return Closure::default() };
        let mut params = [0.0; 8];
        params.copy_from_slice(&t.params[..8]);
        Closure { kind: t.kind, params }
    }
}

/// Status returned by every entry point.
pub type Status = u32;
/// Success.
pub const STATUS_OK: Status = 0;
/// A loop exceeded its iteration budget.
pub const STATUS_LOOP_BUDGET: Status = 1;
/// An array index was out of bounds.
pub const STATUS_OUT_OF_BOUNDS: Status = 2;

/// A shader failed at run time (the renderer reports it once and treats the sample as invalid).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShaderError {
    /// A loop ran past its iteration budget.
    LoopBudget,
    /// An array index was out of bounds.
    OutOfBounds,
}

impl ShaderError {
    /// Converts a status code.
    pub fn check(status: Status) -> Result<(), ShaderError> {
        match status {
            STATUS_OK => Ok(()),
            STATUS_LOOP_BUDGET => Err(ShaderError::LoopBudget),
            _ => Err(ShaderError::OutOfBounds),
        }
    }
}

impl fmt::Display for ShaderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ShaderError::LoopBudget => f.write_str("a shader loop exceeded its iteration budget"),
            ShaderError::OutOfBounds => f.write_str("a shader indexed an array out of bounds"),
        }
    }
}

/// Why a layer's shading was removed at compile time: it can never be picked.
#[derive(Clone, Debug, PartialEq)]
pub enum Pruned {
    /// Under the constant-opaque surface of the named slot.
    HiddenUnder(String),
    /// Its mask is the constant 0.
    MaskZero,
}

impl std::fmt::Display for Pruned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Pruned::HiddenUnder(slot) => write!(f, "hidden under slot {slot}"),
            Pruned::MaskZero => f.write_str("mask is 0"),
        }
    }
}

/// What the renderer knows about one layer.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerInfo {
    /// Slot name.
    pub slot: String,
    /// Whether the layer has a surface product (a layer without one is never picked).
    pub has_surface: bool,
    /// Displacement combination mode, if the layer displaces.
    pub displacement: Option<DisplacementMode>,
    /// `Some(bound)` when the layer's displacement moves geometry (its driving node has a
    /// `bound` input, as the built-in `displacement` does): heights are clamped to `±bound`
    /// when meshes are diced. `None` when it only bends the shading normal (`bump`).
    pub displacement_bound: Option<f32>,
    /// Whether the layer has a normal product.
    pub has_normal: bool,
    /// The layer's mask when it is known at compile time (clamped; absent mask: 1).
    pub constant_mask: Option<f32>,
    /// Whether the layer may emit light (it has an emission product that is not constant
    /// black): the renderer calls [`MaterialCode::emission`] only for such layers.
    pub has_emission: bool,
    /// Why the compiler removed the layer's shading, when it did (the optimising passes
    /// only); the slot lints read it rather than wiring the material again.
    pub pruned: Option<Pruned>,
}

/// A custom channel of a material: its name, kind and offset in the channel output array.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelInfo {
    /// Channel (EXR layer) name.
    pub name: String,
    /// Colour (3 floats), float or integer (1 float each).
    pub kind: ChannelKind,
    /// Index of its first float in the `channels` output.
    pub offset: usize,
}

impl ChannelInfo {
    /// Floats this channel occupies.
    pub fn width(&self) -> usize {
        if self.kind == ChannelKind::Color { 3 } else { 1 }
    }
}

/// Layer and channel metadata of a compiled material.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialInfo {
    /// Layers bottom to top.
    pub layers: Vec<LayerInfo>,
    /// Channels of the material, sorted by name.
    pub channels: Vec<ChannelInfo>,
    /// Total floats of the `channels` output.
    pub channel_floats: usize,
    /// The primvars the material reads, in the order they were first read.
    pub primvars: Vec<PrimvarInfo>,
    /// Floats of [`Globals::primvars`] the material reads (flags and components).
    pub primvar_floats: usize,
    /// No entry point reads [`Globals::st_footprint`] (no filtered texture lookup): the
    /// renderer may leave it at zero. `false`, the default, is always safe.
    pub ignores_footprint: bool,
}

/// The entry points of one compiled material. The JIT and the interpreter both implement it;
/// the renderer calls only these. Every method is allocation-free.
pub trait MaterialCode: Send + Sync {
    /// Layer and channel metadata.
    fn info(&self) -> &MaterialInfo;
    /// Writes each layer's mask, clamped to [0, 1] (absent mask: 1), whether or not the layer
    /// has a surface: which masks weigh what is `layering`'s to say. `out.len()` is the layer count.
    fn masks(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError>;
    /// One layer's mask, as [`MaterialCode::masks`] writes it. Stochastic layer picking walks
    /// the stack from the top and stops at the picked layer (paper 5.3), so its cost does not
    /// grow with the layers below.
    fn mask(&self, g: &Globals, layer: usize) -> Result<f32, ShaderError>;
    /// Evaluates one layer's surface closure, or its first term when it is a sum of several.
    fn surface(&self, g: &Globals, layer: usize, out: &mut Closure) -> Result<(), ShaderError>;
    /// Evaluates one layer's full closure value (what the renderer shades with; every term
    /// past those the shader may fill is empty). The default wraps [`MaterialCode::surface`]:
    /// a single lobe of unit weight.
    fn surface_sum(&self, g: &Globals, layer: usize, out: &mut ClosureSum) -> Result<(), ShaderError> {
        let mut single = Closure::default();
        self.surface(g, layer, &mut single)?;
        *out = ClosureSum::single(&single);
        Ok(())
    }
    /// [`MaterialCode::surface_sum`] for a caller that reads only the leading terms it says:
    /// writes the terms the shader may fill and returns how many (every later term is empty
    /// in the value, but `out` keeps whatever it held there). The renderer's shading points
    /// skip clearing and scanning the unused terms (most closures have one of
    /// [`MAX_CLOSURE_TERMS`]). The default writes the whole value.
    fn surface_terms(&self, g: &Globals, layer: usize, out: &mut ClosureSum) -> Result<usize, ShaderError> {
        self.surface_sum(g, layer, out)?;
        Ok(MAX_CLOSURE_TERMS)
    }
    /// Writes each layer's displacement height (0 without a displacement product).
    fn displacement(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError>;
    /// Writes one layer's shading normal (`g.n` without a normal product).
    fn normal(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError>;
    /// Writes one layer's emitted radiance (unclamped, as the shader computed it; black without
    /// an emission product). The renderer asks only layers with [`LayerInfo::has_emission`].
    fn emission(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError>;
    /// Writes one layer's custom channels at their offsets (0 for channels the layer lacks).
    /// `out.len()` is `info().channel_floats`.
    fn channels(&self, g: &Globals, layer: usize, out: &mut [f32]) -> Result<(), ShaderError>;
}

/// One material instance of a compiled material "class" whose live inputs are parameters:
/// the class's code with this instance's parameter block. Every entry point passes the
/// caller's globals on with [`Globals::params`] pointing at the block (a copy of the globals
/// on the stack, nothing allocated), so many instances share one compiled class and an input
/// edit rewrites a block instead of recompiling.
pub struct ParameterInstance {
    class: std::sync::Arc<dyn MaterialCode>,
    block: Box<[f32]>,
}

impl ParameterInstance {
    /// The instance of `class` with parameter `block`.
    pub fn new(class: std::sync::Arc<dyn MaterialCode>, block: Vec<f32>) -> ParameterInstance {
        ParameterInstance { class, block: block.into_boxed_slice() }
    }

    /// The parameter block.
    pub fn block(&self) -> &[f32] {
        &self.block
    }

    /// The compiled class.
    pub fn class(&self) -> &std::sync::Arc<dyn MaterialCode> {
        &self.class
    }

    #[inline]
    fn with_block<'g>(&'g self, g: &Globals<'g>) -> Globals<'g> {
        Globals { params: PrimvarValues::new(&self.block), ..*g }
    }
}

impl MaterialCode for ParameterInstance {
    fn info(&self) -> &MaterialInfo {
        self.class.info()
    }
    fn masks(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        self.class.masks(&self.with_block(g), out)
    }
    fn mask(&self, g: &Globals, layer: usize) -> Result<f32, ShaderError> {
        self.class.mask(&self.with_block(g), layer)
    }
    fn surface(&self, g: &Globals, layer: usize, out: &mut Closure) -> Result<(), ShaderError> {
        self.class.surface(&self.with_block(g), layer, out)
    }
    fn surface_sum(&self, g: &Globals, layer: usize, out: &mut ClosureSum) -> Result<(), ShaderError> {
        self.class.surface_sum(&self.with_block(g), layer, out)
    }
    fn surface_terms(&self, g: &Globals, layer: usize, out: &mut ClosureSum) -> Result<usize, ShaderError> {
        self.class.surface_terms(&self.with_block(g), layer, out)
    }
    fn displacement(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        self.class.displacement(&self.with_block(g), out)
    }
    fn normal(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        self.class.normal(&self.with_block(g), layer, out)
    }
    fn emission(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        self.class.emission(&self.with_block(g), layer, out)
    }
    fn channels(&self, g: &Globals, layer: usize, out: &mut [f32]) -> Result<(), ShaderError> {
        self.class.channels(&self.with_block(g), layer, out)
    }
}
