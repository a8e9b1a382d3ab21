//! The library's entry point to the pipeline: a [`Session`] owns the prepared state of one
//! scene — its stage, compositions, compiled materials, render scene (geometry, BVH, lights)
//! and diagnostics — and updates it after a change, redoing only what depends on it.
//!
//! Phases run on demand and are remembered, each from the one before it:
//!
//! ```text
//! open ─► stage ─► composition ─► compiled materials ─► render scene ─► render passes
//!          (layers)   (+ substance files)  (by content hash)   (geometry, BVH, lights)
//! ```
//!
//! [`Session::apply_change`] says what changed (a USD layer, a substance file, a texture, an
//! input value) and redoes, eagerly, only the phases that depend on it; ARCHITECTURE.md
//! ("The Session") lists what each change redoes and the invariants, each with its test.
//! Rendering never changes the session, so the same session renders the same pass to the
//! same image, bit for bit, whatever was updated before.

mod example;
pub mod farm;
mod fingerprint;
mod layers;
mod lints;
mod object;
mod update;

pub use example::write_split_default_scene;
pub use layers::{layers_json, layers_table};
pub use object::{ShaderObject, shader_object};

use crate::abi::{MaterialCode, ParameterInstance};
use crate::backend::{BackendKind, CompileStats, Compiler};
use crate::compose::scene::{SceneComposition, compose_stage_filtered};
use crate::compose::slots::PrimStack;
use crate::compose::slots::SlotFilter;
use crate::diag::{Diagnostic, Diagnostics, FileId, SourceMap};
use crate::front::library::Library;
use crate::input::InputLimits;
use crate::input::scenes;
use crate::ir::wired::{self, PassOptions};
use crate::render::scene::{SceneOptions, View};
use crate::render::{Image, Progress, RenderError, RenderSettings, RenderStats, Window, WindowSums};
use crate::scene::{PrimId, Stage, TimeCode, Value, ValueType};
use fingerprint::FileHashes;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;
use update::{instance_hash, material_key};

/// Which scene a session opens.
#[derive(Clone, Debug, PartialEq)]
pub enum SceneSource {
    /// The scene embedded in the binary ([`crate::input::scenes::DEFAULT_SCENE`]).
    Default,
    /// A USD file: `.usda`, `.usdc`, `.usd` or `.usdz`.
    File(PathBuf),
}

impl SceneSource {
    /// A file, or the default scene for `None` (the CLI's optional `SCENE` argument).
    pub fn from_path(path: Option<&Path>) -> SceneSource {
        path.map_or(SceneSource::Default, |p| SceneSource::File(p.to_path_buf()))
    }

    /// How the scene is named in headers and messages.
    pub fn display_name(&self) -> String {
        match self {
            SceneSource::Default => "(embedded default scene)".into(),
            SceneSource::File(p) => p.display().to_string(),
        }
    }
}

/// How a session prepares its scene.
#[derive(Clone, Copy, Debug, Default)]
pub struct SessionOptions {
    /// Which backend runs the shaders.
    pub backend: BackendKind,
    /// Constant folding and layer pruning; with `passes.live_inputs` (`strata view`, never
    /// `render`), float and colour inputs are parameters of the compiled code: one compiled
    /// class per material without those values, a parameter block per material, and a
    /// [`Change::Value`] of such an input rewrites the block without composing or compiling.
    pub passes: PassOptions,
    /// The time code the stage is read at (`None`: [`Stage::opening_time`]).
    pub time: Option<TimeCode>,
    /// Every warning is an error in [`Session::take_diagnostics`] (`--strict`).
    pub strict: bool,
    /// Input limits to set for the process before reading (`None`: leave them as they are;
    /// they are process-wide, see [`crate::input::set_limits`]).
    pub limits: Option<InputLimits>,
}

/// What changed on disk or in the session's input.
#[derive(Clone, Debug, PartialEq)]
pub enum Change {
    /// A file changed; the session works out what it is to this scene (a layer of the stage,
    /// a substance file a composition uses, a texture, or nothing).
    File(PathBuf),
    /// A USD layer of the stage changed.
    Layer(PathBuf),
    /// A substance (`.ash`) file changed.
    Substance(PathBuf),
    /// A texture or dome map changed.
    Texture(PathBuf),
    /// An attribute of a prim is set to a new value in memory (a shader's `inputs:roughness`):
    /// the stage is not read again. `type_name` declares it when the prim does not author it.
    Value {
        /// The prim holding the attribute (`/Looks/Clay/Surface`).
        prim: String,
        /// The attribute's full name (`inputs:roughness`).
        attribute: String,
        /// Its USD type when it must be declared (`float`, `color3f`).
        type_name: String,
        /// The new value (converted to the attribute's type).
        value: Value,
    },
}

/// What [`Change`] a file was to this scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChangeKind {
    /// A USD layer of the stage.
    Layer,
    /// A substance file that a composition uses.
    Substance,
    /// A texture the materials or lights read.
    Texture,
    /// An attribute value set in memory.
    Value,
    /// Nothing the prepared scene depends on.
    Unrelated,
}

/// What an update redid.
#[derive(Clone, Debug, PartialEq)]
pub struct UpdateReport {
    /// What the change was to this scene.
    pub kind: ChangeKind,
    /// The stage was read again (its layers).
    pub restaged: bool,
    /// The stage was composed again (slot stacks, substance files, composed materials).
    pub recomposed: bool,
    /// Compositions compiled because their content hash is new.
    pub recompiled: usize,
    /// Compositions whose compiled code was kept (content hash unchanged).
    pub reused: usize,
    /// Geometry and BVH were built again.
    pub geometry_rebuilt: bool,
    /// Only instances moved (a new time code): their transforms and the top-level BVH were
    /// computed again, every bottom-level BVH and the materials kept.
    pub instances_moved: bool,
    /// Why a new time code built the render scene again instead of moving instances.
    pub rebuild_reason: Option<String>,
    /// Texture registry entries read again.
    pub textures_reloaded: usize,
    /// The update failed (its errors are in the diagnostics); the session keeps the last
    /// materials and render scene that prepared cleanly.
    pub failed: bool,
    /// Wall time of the update, ms.
    pub ms: f64,
}

impl UpdateReport {
    /// A report of a change that redid nothing (yet).
    fn nothing(kind: ChangeKind) -> UpdateReport {
        UpdateReport {
            kind,
            restaged: false,
            recomposed: false,
            recompiled: 0,
            reused: 0,
            geometry_rebuilt: false,
            instances_moved: false,
            rebuild_reason: None,
            textures_reloaded: 0,
            failed: false,
            ms: 0.0,
        }
    }
}

/// Counters over a session's life, for tests and `--stats`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SessionStats {
    /// Times the stage was read (open, layer changes).
    pub stage_reads: usize,
    /// Times the stage was composed.
    pub compositions: usize,
    /// Compositions compiled (their content hash was not cached).
    pub materials_compiled: usize,
    /// Compositions whose compiled code came from the content-hash cache.
    pub materials_reused: usize,
    /// Times geometry, BVH and lights were built.
    pub scene_builds: usize,
    /// Bottom-level BVHs built (the world's and each prototype's at every scene build, and a
    /// deforming prim's when a new time code builds only its own).
    pub blas_builds: usize,
    /// Times a new time code only moved instances (top-level BVH built again, BLASes kept).
    pub instance_moves: usize,
    /// Times an existing render scene was rebound to new materials (BVH kept).
    pub scene_rebinds: usize,
    /// Parameter blocks rewritten by input edits with live inputs (nothing composed or
    /// compiled for them).
    pub parameter_writes: usize,
    /// Wall time of the last stage read (USD and every layer it names), ms.
    pub parse_ms: f64,
    /// Wall time of the last composition, ms.
    pub compose_ms: f64,
    /// Wall time of the last compilation of materials, ms.
    pub compile_ms: f64,
    /// Wall time of the last render-scene build or rebind, ms.
    pub scene_ms: f64,
}

/// Why a pass could not be rendered.
#[derive(Debug)]
pub enum PassError {
    /// The scene did not prepare (its errors are in the diagnostics).
    NotPrepared,
    /// The renderer refused the settings.
    Render(RenderError),
}

impl std::fmt::Display for PassError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PassError::NotPrepared => write!(f, "the scene has errors and was not prepared"),
            PassError::Render(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for PassError {}

/// One render of a prepared scene: the image of `settings`, or a window of it — a region
/// of its pixels over a range of each pixel's samples, as a farm split or a progressive
/// view renders it ([`Window`]: a window's pixels are the full render's, bit for bit).
#[derive(Clone, Debug, Default)]
pub struct Pass {
    /// Image size, samples per pixel, seed, threads, depth, layer mode and sampler.
    pub settings: RenderSettings,
    /// The time code to render at (`None`: the session's). A different time re-reads
    /// animated values and redoes what depends on them, as a change would.
    pub time: Option<TimeCode>,
    /// The part of the image to render (`Window::FULL`: all of it).
    pub window: Window,
}

impl Pass {
    /// The whole image of `settings` at the session's time.
    pub fn full(settings: RenderSettings) -> Pass {
        Pass { settings, time: None, window: Window::FULL }
    }
}

/// The compiled materials of a session.
pub struct Compiled {
    /// One compiled material per distinct composition.
    pub materials: Vec<Arc<dyn MaterialCode>>,
    /// Per renderable prim path, its index in `materials`.
    pub prim_material: HashMap<String, usize>,
    /// Per material, a name for its slot stack (see [`material_name`]), for ID mattes.
    pub material_names: Vec<String>,
}

impl Compiled {
    /// The materials as the renderer takes them.
    pub fn refs(&self) -> Vec<&dyn MaterialCode> {
        self.materials.iter().map(|m| m.as_ref()).collect()
    }
}

/// A composition with the content hash of each of its materials.
struct Composed {
    scene: SceneComposition,
    /// Per material, what its image depends on: its content hash, or with live inputs its
    /// class's and its parameter block's.
    hashes: Vec<u64>,
    /// Per material, the content hash of its compiled code: its class's with live inputs,
    /// else `hashes`'.
    classes: Vec<u64>,
    /// Per material, its parameter block (live inputs only; else empty).
    blocks: Vec<Vec<f32>>,
    /// Canonical paths of the substance files (and their imports) the materials use.
    files: HashSet<PathBuf>,
    /// Composition reported errors: a change to any substance file may fix it.
    failed: bool,
}

/// The render scene with what it was built from.
struct Prepared {
    scene: crate::render::Scene,
    options: SceneOptions,
    /// [`fingerprint::geometry_hash`] of the stage it was built from.
    geometry: u64,
    /// What the materials made the build depend on: the primvars they read, and per prim
    /// the hash of its material when that material moves geometry (0 otherwise).
    material_key: (Vec<String>, Vec<u64>),
}

/// The prepared state of one scene. See the module documentation.
pub struct Session {
    source: SceneSource,
    options: SessionOptions,
    sources: SourceMap,
    diags: Diagnostics,
    stage: Option<Stage>,
    /// Canonical paths of the stage's layers.
    layers: HashSet<PathBuf>,
    composed: Option<Composed>,
    compiled: Option<Compiled>,
    /// The content hash of each of `compiled`'s materials.
    compiled_hashes: Vec<u64>,
    compiler: Compiler,
    /// Compiled code by material content hash (the current materials').
    code: HashMap<u64, Arc<dyn MaterialCode>>,
    prepared: Option<Prepared>,
    /// The stage's time when [`Session::prepare_releasing_stage`] gave it up.
    released_time: Option<TimeCode>,
    stats: SessionStats,
    /// Slots muted or soloed in memory (a live view's look edits).
    slot_filter: SlotFilter,
}

impl Session {
    /// Opens a scene: reads its stage (at `options.time`). Composition, compilation and the
    /// render scene follow on demand. Problems go to the session's diagnostics; a stage that
    /// fails to open leaves a session with no stage.
    pub fn open(source: SceneSource, options: SessionOptions) -> Session {
        if let Some(limits) = options.limits {
            crate::input::set_limits(limits);
        }
        let mut session = Session {
            source,
            options,
            sources: SourceMap::new(),
            diags: Diagnostics::new(),
            stage: None,
            layers: HashSet::new(),
            composed: None,
            compiled: None,
            compiled_hashes: Vec::new(),
            compiler: Compiler::new(options.backend, options.passes),
            code: HashMap::new(),
            prepared: None,
            released_time: None,
            stats: SessionStats::default(),
            slot_filter: SlotFilter::default(),
        };
        session.read_stage();
        session
    }

    /// Opens `source` with default options (JIT, optimised, opening time).
    pub fn open_default(source: SceneSource) -> Session {
        Session::open(source, SessionOptions::default())
    }

    fn read_stage(&mut self) {
        let start = Instant::now();
        let first = file_count(&self.sources);
        let mut stage = match &self.source {
            SceneSource::File(p) => Stage::open(p, &mut self.sources, &mut self.diags).ok(),
            SceneSource::Default => {
                let (name, text) = scenes::DEFAULT_SCENE;
                Stage::from_text(name, text, Path::new(scenes::EMBEDDED_DIR), &mut self.sources, &mut self.diags).ok()
            }
        };
        if let (Some(stage), Some(time)) = (&mut stage, self.options.time) {
            stage.set_time(time);
        }
        self.layers =
            (first..file_count(&self.sources)).map(|i| canonical(Path::new(self.sources.name(FileId(i))))).collect();
        if let SceneSource::File(p) = &self.source {
            self.layers.insert(canonical(p));
        }
        self.stage = stage;
        self.stats.stage_reads += 1;
        self.stats.parse_ms = start.elapsed().as_secs_f64() * 1e3;
    }

    /// The scene this session opened.
    pub fn source(&self) -> &SceneSource {
        &self.source
    }

    /// The options the session was opened with.
    pub fn options(&self) -> &SessionOptions {
        &self.options
    }

    /// The composed stage, if it opened.
    pub fn stage(&self) -> Option<&Stage> {
        self.stage.as_ref()
    }

    /// Every file read so far, for rendering diagnostics.
    pub fn sources(&self) -> &SourceMap {
        &self.sources
    }

    /// Diagnostics of the work done since they were last taken (open, or the last update).
    pub fn diagnostics(&self) -> &Diagnostics {
        &self.diags
    }

    /// Takes the diagnostics (leaving none), with warnings made errors if the session is
    /// strict.
    pub fn take_diagnostics(&mut self) -> Diagnostics {
        let mut diags = std::mem::take(&mut self.diags);
        if self.options.strict {
            diags.make_warnings_errors();
        }
        diags
    }

    /// Counters and timings.
    pub fn stats(&self) -> &SessionStats {
        &self.stats
    }

    /// What compiling the materials cost, summed over the session's life.
    pub fn compile_stats(&self) -> &CompileStats {
        &self.compiler.stats
    }

    /// The slot stack of every renderable prim (`strata layers`): bindings only, no
    /// substance file is read.
    pub fn layer_stacks(&mut self) -> Vec<PrimStack> {
        if let Some(c) = &self.composed {
            return c.scene.stacks.clone();
        }
        let Some(stage) = &self.stage else { return Vec::new() };
        let tree = crate::compose::binding::binding_tree(stage, &mut self.diags);
        crate::compose::slots::resolve_stacks(&tree, &mut self.diags)
    }

    /// The composition: slot stacks, the substance library and the distinct composed
    /// materials. `None` when the stage did not open.
    pub fn composition(&mut self) -> Option<&SceneComposition> {
        if self.composed.is_none() {
            self.compose();
        }
        self.composed.as_ref().map(|c| &c.scene)
    }

    fn compose(&mut self) {
        let Some(stage) = &self.stage else {
            self.composed = None;
            return;
        };
        let start = Instant::now();
        let errors = self.diags.error_count();
        let scene = compose_stage_filtered(stage, &self.slot_filter, &mut self.sources, &mut self.diags);
        let mut files = FileHashes::default();
        let (mut hashes, mut classes, mut blocks) = (Vec::new(), Vec::new(), Vec::new());
        for m in &scene.materials {
            if self.options.passes.live_inputs {
                let class = fingerprint::material_hash(&m.class(&scene.library), &scene.library, &mut files);
                let block = m.parameter_block(&scene.library);
                hashes.push(instance_hash(class, &block));
                classes.push(class);
                blocks.push(block);
            } else {
                let hash = fingerprint::material_hash(m, &scene.library, &mut files);
                hashes.push(hash);
                classes.push(hash);
                blocks.push(Vec::new());
            }
        }
        let failed = self.diags.error_count() > errors;
        self.composed = Some(Composed { scene, hashes, classes, blocks, files: files.visited(), failed });
        self.stats.compositions += 1;
        self.stats.compose_ms = start.elapsed().as_secs_f64() * 1e3;
    }

    /// Compiles every distinct composed material, reusing the code of any whose content
    /// hash was compiled before. `None` when the scene has errors (so far in the
    /// diagnostics) or a material failed to compile; the last good materials stay.
    pub fn compile(&mut self) -> Option<&Compiled> {
        if self.compiled.is_none() || self.needs_compile() {
            self.compile_now()?;
        }
        self.compiled.as_ref()
    }

    /// [`Session::compile`], or the rendered diagnostics when it fails (tests, tools).
    pub fn compile_or_report(&mut self) -> Result<&Compiled, String> {
        if self.compile().is_none() {
            return Err(self.diags.render(&self.sources));
        }
        self.compiled.as_ref().ok_or_else(String::new)
    }

    /// Whether the composition's materials differ from the compiled ones.
    fn needs_compile(&self) -> bool {
        self.composed.as_ref().is_some_and(|c| c.hashes != self.compiled_hashes)
    }

    /// Compiles the current composition; counts compiled and reused materials.
    fn compile_now(&mut self) -> Option<(usize, usize)> {
        self.composition()?;
        if self.diags.has_errors() {
            return None;
        }
        let composed = self.composed.as_ref()?;
        let start = Instant::now();
        let (mut compiled, mut reused) = (0, 0);
        let mut materials: Vec<Arc<dyn MaterialCode>> = Vec::with_capacity(composed.scene.materials.len());
        // Keep the code of the current materials only: the cache does not grow with edits.
        let mut code: HashMap<u64, Arc<dyn MaterialCode>> = HashMap::new();
        for (i, material) in composed.scene.materials.iter().enumerate() {
            let class = composed.classes[i];
            let class_code = match code.get(&class).or_else(|| self.code.get(&class)) {
                Some(c) => {
                    reused += 1;
                    c.clone()
                }
                None => {
                    compiled += 1;
                    self.compiler.compile(&composed.scene.library, material, &mut self.diags)?
                }
            };
            code.insert(class, class_code.clone());
            materials.push(if self.options.passes.live_inputs {
                Arc::new(ParameterInstance::new(class_code, composed.blocks[i].clone()))
            } else {
                class_code
            });
        }
        self.code = code;
        let scene = &composed.scene;
        let prim_material = scene.stacks.iter().zip(&scene.prim_material).map(|(s, m)| (s.prim.clone(), *m)).collect();
        // Each material is named after the first prim stack composing it: identical
        // compositions are shared (DESIGN.md rule 8), so that stack stands for all of them.
        let material_names = (0..materials.len())
            .map(|m| {
                let first = scene.prim_material.iter().position(|&pm| pm == m);
                let stack = first.and_then(|i| scene.stacks.get(i));
                stack.map_or_else(|| format!("material {m}"), |s| material_name(&self.slot_filter.apply(s)))
            })
            .collect();
        self.compiled_hashes = composed.hashes.clone();
        self.compiled = Some(Compiled { materials, prim_material, material_names });
        self.stats.materials_compiled += compiled;
        self.stats.materials_reused += reused;
        self.stats.compile_ms = start.elapsed().as_secs_f64() * 1e3;
        Some((compiled, reused))
    }

    /// The camera and resolution to render through: `camera`, else the stage's render
    /// settings camera, else the first camera ([`crate::render::scene::choose_view`]).
    pub fn view(&mut self, camera: Option<&str>) -> Option<View> {
        let stage = self.stage.as_ref()?;
        crate::render::scene::choose_view(stage, camera, &mut self.diags)
    }

    /// Builds the render scene (geometry, BVH, lights, camera) with the compiled materials,
    /// or returns the one built with the same `options`. `None` when anything so far failed.
    pub fn prepare(&mut self, options: &SceneOptions) -> Option<&crate::render::Scene> {
        self.prepare_with(options, false)
    }

    /// [`Session::prepare`] for a render that no update follows (a one-shot `strata render`):
    /// the session gives its stage up once the geometry is emitted, before the BVH build, so
    /// a large mesh's stage arrays and its BVH build are not held at once. The image is the
    /// same. Afterwards the session renders and fingerprints the prepared scene, but has no
    /// stage: [`Session::stage`] is `None`, [`Session::set_time`] finds nothing to do, a
    /// `prepare` with other options fails, and a change has no stage to redo from unless it
    /// is a layer's (which reads the stage again).
    pub fn prepare_releasing_stage(&mut self, options: &SceneOptions) -> Option<&crate::render::Scene> {
        self.prepare_with(options, true)
    }

    /// Compiles, then builds the scene unless one was prepared with the same options; with
    /// `release`, from the stage taken out of the session.
    fn prepare_with(&mut self, options: &SceneOptions, release: bool) -> Option<&crate::render::Scene> {
        self.compile()?;
        let fresh = self.prepared.as_ref().is_some_and(|p| format!("{:?}", p.options) == format!("{options:?}"));
        if !fresh {
            self.build_scene_with(options.clone(), release)?;
        }
        self.prepared.as_ref().map(|p| &p.scene)
    }

    fn build_scene(&mut self, options: SceneOptions) -> Option<()> {
        self.build_scene_with(options, false)
    }

    /// Builds the render scene; with `release`, from the stage taken out of the session.
    fn build_scene_with(&mut self, options: SceneOptions, release: bool) -> Option<()> {
        let (Some(stage), Some(compiled)) = (self.stage.as_ref(), self.compiled.as_ref()) else { return None };
        let start = Instant::now();
        let refs = compiled.refs();
        let material_of_prim = |p: &str| compiled.prim_material.get(p).copied();
        let geometry = fingerprint::geometry_hash(stage);
        let mut scene = if release {
            let stage = self.stage.take()?;
            self.released_time = Some(stage.time());
            crate::render::Scene::build_releasing_stage(stage, &material_of_prim, &refs, &options, &mut self.diags)
        } else {
            crate::render::Scene::build(stage, &material_of_prim, &refs, &options, &mut self.diags)
        };
        self.stats.scene_builds += 1;
        self.stats.blas_builds += scene.as_ref().map_or(0, |s| s.accel.blas_count());
        self.stats.scene_ms = start.elapsed().as_secs_f64() * 1e3;
        if let Some(scene) = &mut scene {
            scene.material_names = compiled.material_names.clone();
        }
        self.prepared = scene.map(|scene| {
            let material_key = material_key(&scene, &refs, &self.compiled_hashes);
            Prepared { scene, options, geometry, material_key }
        });
        self.prepared.as_ref().map(|_| ())
    }

    /// The stage's time; once [`Session::prepare_releasing_stage`] gave the stage up, the
    /// time it was at.
    pub fn time(&self) -> TimeCode {
        self.stage.as_ref().map(Stage::time).or(self.released_time).unwrap_or(TimeCode::Default)
    }

    /// The prepared render scene, if [`Session::prepare`] succeeded.
    pub fn scene(&self) -> Option<&crate::render::Scene> {
        self.prepared.as_ref().map(|p| &p.scene)
    }

    /// Moves the prepared scene's camera (a live view's orbit): geometry and materials are
    /// kept; the default camera light, when the stage has no lights, travels with it.
    pub fn set_camera(&mut self, camera: crate::render::camera::Camera) {
        if let Some(prepared) = &mut self.prepared {
            let scene = &mut prepared.scene;
            scene.camera = camera;
            // The viewer's pose replaces the stage camera's, its motion under the shutter too.
            scene.camera_motion = None;
            if scene.default_lights {
                scene.lights = crate::render::scene::default_lights(&camera);
            }
        }
    }

    /// The composition, if [`Session::composition`] ran.
    pub fn composed(&self) -> Option<&SceneComposition> {
        self.composed.as_ref().map(|c| &c.scene)
    }

    /// The composition, taken out of the session (benchmarks that measure its materials).
    pub fn into_composition(mut self) -> Option<SceneComposition> {
        self.composition()?;
        self.composed.map(|c| c.scene)
    }

    /// The render scene and its materials, taken out of the session.
    pub fn into_scene(self) -> Option<(crate::render::Scene, Compiled)> {
        Some((self.prepared?.scene, self.compiled?))
    }

    /// The compiled materials, if [`Session::compile`] succeeded.
    pub fn compiled(&self) -> Option<&Compiled> {
        self.compiled.as_ref()
    }

    /// Renders a pass of the prepared scene. The session is not changed (unless the pass
    /// asks for another time), so equal passes give equal images.
    pub fn render(&mut self, pass: &Pass, progress: Option<Progress>) -> Result<(Image, RenderStats), PassError> {
        self.render_at(pass.time);
        let (Some(prepared), Some(compiled)) = (&self.prepared, &self.compiled) else {
            return Err(PassError::NotPrepared);
        };
        crate::render::render_window(&prepared.scene, &compiled.refs(), &pass.settings, &pass.window, progress)
            .map_err(PassError::Render)
    }

    /// [`Session::render`], also returning each pixel's exact sums: passes over other samples
    /// of the same pixels merge into them ([`WindowSums::merge`]), and
    /// [`Session::image_from_sums`] makes the image one pass over all their samples renders,
    /// bit for bit, however the samples were split (a farm's splits, a view's progressive passes).
    pub fn render_sums(
        &mut self,
        pass: &Pass,
        progress: Option<Progress>,
    ) -> Result<(Image, RenderStats, WindowSums), PassError> {
        self.render_at(pass.time);
        let (Some(prepared), Some(compiled)) = (&self.prepared, &self.compiled) else {
            return Err(PassError::NotPrepared);
        };
        crate::render::render_sums(&prepared.scene, &compiled.refs(), &pass.settings, &pass.window, progress)
            .map_err(PassError::Render)
    }

    /// The image of merged sums from [`Session::render_sums`] of this session's prepared scene.
    pub fn image_from_sums(&self, sums: &WindowSums) -> Result<Image, PassError> {
        let (Some(prepared), Some(compiled)) = (&self.prepared, &self.compiled) else {
            return Err(PassError::NotPrepared);
        };
        Ok(crate::render::image_from_sums(&prepared.scene, &compiled.refs(), sums))
    }

    /// The layout of this session's images besides their sums (custom channels, Cryptomatte
    /// IDs): with it, sums become an image without the scene ([`crate::render::film::partial`]).
    pub fn sums_layout(&self) -> Option<crate::render::film::SumsLayout> {
        let (prepared, compiled) = (self.prepared.as_ref()?, self.compiled.as_ref()?);
        Some(crate::render::film::sums_layout(&prepared.scene, &compiled.refs()))
    }

    /// A hash of what the pixels of `settings`' image depend on: the stage's geometry,
    /// lights and camera at its time, every material's content, the scene options, the
    /// backend and passes, and the settings but for threads. Equal in every process of the
    /// same build that renders the same image, so a farm's parts can be checked to belong
    /// together. Texture texels are not hashed (only the files' names, in the materials).
    pub fn fingerprint(&self, settings: &RenderSettings) -> Option<u64> {
        use std::hash::{DefaultHasher, Hash, Hasher};
        let (prepared, compiled) = (self.prepared.as_ref()?, self.compiled.as_ref()?);
        let mut hasher = DefaultHasher::new();
        prepared.geometry.hash(&mut hasher);
        self.compiled_hashes.hash(&mut hasher);
        compiled.material_names.hash(&mut hasher);
        let settings = RenderSettings { threads: None, ..settings.clone() };
        format!("{:?}{settings:?}{:?}{:?}", prepared.options, self.options.backend, self.options.passes)
            .hash(&mut hasher);
        Some(hasher.finish())
    }

    /// Moves the stage to `time` (if given and different), redoing what depends on it.
    fn render_at(&mut self, time: Option<TimeCode>) {
        if let Some(time) = time {
            self.set_time(time);
        }
    }

    /// Moves the stage to `time` (a frame of a shot), redoing only what depends on it. When
    /// only xformOps changed value, and none of them is baked into triangles, the render
    /// scene's instances move ([`crate::render::Scene::move_to`]: top-level BVH only) and
    /// nothing is recomposed or recompiled. Otherwise it is as a change: animated values are
    /// read again, compositions whose content changed are recompiled, and the render scene is
    /// rebound when no geometry, light or camera moved, rebuilt (BVH included) when one did;
    /// the report says why. Nothing happens when the stage is at `time`.
    pub fn set_time(&mut self, time: TimeCode) -> UpdateReport {
        let start = Instant::now();
        let Some(stage) = self.stage.as_mut().filter(|s| s.time() != time) else {
            return UpdateReport::nothing(ChangeKind::Value);
        };
        self.options.time = Some(time);
        let changed = changed_at(stage, time);
        stage.set_time(time);
        let other = |(id, name): &&(PrimId, String)| !places_instances(stage, *id, name) && !reshapes(stage, *id, name);
        let reason = match changed.iter().find(other) {
            Some((id, name)) => format!("`{}.{name}` changed", stage.prim(*id).path),
            None => {
                let (moved, reshaped): (Vec<_>, Vec<_>) =
                    changed.into_iter().partition(|(id, name)| places_instances(stage, *id, name));
                let mut prims: Vec<PrimId> = moved.iter().map(|(id, _)| *id).collect();
                prims.dedup();
                match self.move_instances(&prims, &reshaped) {
                    Ok(true) => {
                        let mut report = UpdateReport::nothing(ChangeKind::Value);
                        report.instances_moved = !prims.is_empty() || !reshaped.is_empty();
                        report.ms = start.elapsed().as_secs_f64() * 1e3;
                        return report;
                    }
                    Ok(false) => String::new(),
                    Err(why) => why,
                }
            }
        };
        let mut report = self.redo_from_composition(ChangeKind::Value, start);
        if report.geometry_rebuilt {
            report.rebuild_reason = Some(reason);
        }
        report
    }

    /// Moves the prepared scene's instances to the stage's time after the xformOps of
    /// `changed` changed value and the shapes of `reshaped` (nothing else did), building
    /// the BLASes of deforming prims again. `Ok(false)`: there is no prepared scene (nothing
    /// to move); `Err`: why the scene must be built again.
    fn move_instances(&mut self, changed: &[PrimId], reshaped: &[(PrimId, String)]) -> Result<bool, String> {
        let (Some(prepared), Some(compiled), Some(stage)) = (&mut self.prepared, &self.compiled, &self.stage) else {
            return Ok(false);
        };
        if self.composed.as_ref().is_none_or(|c| c.hashes != self.compiled_hashes) {
            return Ok(false);
        }
        let start = Instant::now();
        let built = prepared
            .scene
            .move_to(stage, changed, reshaped, &compiled.refs(), &mut self.diags)
            .map_err(|e| e.to_string())?;
        prepared.geometry = fingerprint::geometry_hash(stage);
        self.stats.instance_moves += usize::from(!changed.is_empty() || !reshaped.is_empty());
        self.stats.blas_builds += built;
        self.stats.scene_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(true)
    }

    /// The wired IR of renderable prim `prim`'s material (`strata ir`), or with `lowered`
    /// its lowered IR, with a statistics line. `Err` lists some renderable prims when
    /// `prim` is not one; `None` when the scene did not compose.
    pub fn ir(&mut self, prim: &str, lowered: bool) -> Option<Result<(String, String), Vec<String>>> {
        self.composition()?;
        let composed = &self.composed.as_ref()?.scene;
        let Some(material) = composed.material_of(prim) else {
            return Some(Err(composed.stacks.iter().map(|s| s.prim.clone()).take(20).collect()));
        };
        let passes = self.options.passes;
        Some(Ok(if lowered {
            let mut compiler = Compiler::new(BackendKind::Jit, passes);
            let module = compiler.lower(&composed.library, material, &mut self.diags);
            let line =
                format!("lowered: {} function(s), {} instruction(s)", module.functions.len(), module.inst_count());
            (module.to_text(), line)
        } else {
            let wired = wired::build(&composed.library, material, passes, &mut self.diags);
            (wired.to_text(&composed.library), wired.stats_line())
        }))
    }

    /// Everything `render` would reject — composition, lowering (textures), geometry, lights
    /// and camera — without generating code or tracing a ray (`strata check`). Returns the
    /// number of renderable prims and of distinct lowered materials.
    pub fn check(&mut self) -> Option<(usize, usize)> {
        self.composition()?;
        let (stage, composed) = (self.stage.as_ref()?, &self.composed.as_ref()?.scene);
        let mut compiler = Compiler::new(BackendKind::Jit, PassOptions::default());
        let mut distinct = HashSet::new();
        let mut infos = Vec::with_capacity(composed.materials.len());
        for material in &composed.materials {
            let module = compiler.lower(&composed.library, material, &mut self.diags);
            distinct.insert(module.to_text());
            infos.push(module.info);
        }
        lints::lint_slots(stage, composed, &infos.iter().collect::<Vec<_>>(), &mut self.diags);
        // Geometry, lights and camera are validated; no BVH is built (it reports nothing).
        crate::render::Scene::validate(stage, &|_| Some(0), &mut self.diags);
        Some((composed.stacks.len(), distinct.len()))
    }

    /// The slot-name lints (issue 23: numeric names of different lengths, look-alike
    /// names, overrides and vertical slots of slots never bound, slots hidden everywhere,
    /// substances that show nothing) on the current composition, as warnings. `check` runs
    /// them; `strata render` calls this once per run, after [`Session::compile`] (the
    /// hidden-slot lint reads the compiled layers' pruning; before a compile it has none).
    pub fn lint_slots(&mut self) {
        if let (Some(stage), Some(composed)) = (&self.stage, &self.composed) {
            let infos: Vec<&crate::abi::MaterialInfo> = match &self.compiled {
                Some(c) if self.compiled_hashes == composed.hashes => c.materials.iter().map(|m| m.info()).collect(),
                _ => Vec::new(),
            };
            lints::lint_slots(stage, &composed.scene, &infos, &mut self.diags);
        }
    }
}

/// The name of a composed material in ID mattes: its slot stack, bottom first, as
/// `slot=/Material/Path` entries (overrides as `slot:_:override=/Path`) joined by ` | `.
pub fn material_name(stack: &PrimStack) -> String {
    if stack.layers.is_empty() {
        return "(default substance)".into();
    }
    let mut parts = Vec::new();
    for layer in &stack.layers {
        parts.push(format!("{}={}", layer.slot.name(), layer.applied.material));
        for o in &layer.overrides {
            parts.push(format!("{}={}", o.slot.name(), o.applied.material));
        }
    }
    parts.join(" | ")
}

/// Checks a substance file or a scene (`strata check`): every diagnostic, and a one-line
/// summary when it is clean.
pub fn check_file(file: &Path) -> (Diagnostics, SourceMap, String) {
    check_file_at(file, None)
}

/// As [`check_file`], with a scene read at `time` (`None`: [`Stage::opening_time`]).
pub fn check_file_at(file: &Path, time: Option<TimeCode>) -> (Diagnostics, SourceMap, String) {
    if file.extension().is_some_and(|e| e == "ash") {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let lib = Library::load(&[(file.to_path_buf(), Default::default())], &mut sources, &mut diags);
        let user = lib.graphs.len().saturating_sub(1);
        return (diags, sources, format!("{}: ok ({user} graph(s))", file.display()));
    }
    let options = SessionOptions { time, ..SessionOptions::default() };
    let mut session = Session::open(SceneSource::File(file.to_path_buf()), options);
    let summary = match session.check() {
        Some((prims, distinct)) => {
            format!("{}: ok ({prims} renderable prim(s), {distinct} distinct material(s))", file.display())
        }
        None => String::new(),
    };
    let diags = std::mem::take(&mut session.diags);
    (diags, session.sources, summary)
}

/// Whether attribute `name` of prim `id` only places instances (or a light, or the camera):
/// an xformOp, or a point instancer's points.
fn places_instances(stage: &Stage, id: PrimId, name: &str) -> bool {
    name.starts_with("xformOp:")
        || (stage.prim(id).type_name.as_deref() == Some("PointInstancer")
            && crate::render::geometry::POINT_MOTION_ATTRIBUTES.contains(&name))
}

/// Whether attribute `name` of prim `id` only shapes a prim that may deform (its points or
/// normals, or a skeleton's animation): the render scene may build that prim's BLAS alone
/// again ([`crate::render::Scene::move_to`] decides).
fn reshapes(stage: &Stage, id: PrimId, name: &str) -> bool {
    matches!(name, "points" | "normals" | "primvars:normals" | "primvars:normals:indices")
        || stage.prim(id).type_name.as_deref() == Some("SkelAnimation")
}

/// The attributes whose value at `time` differs from their value now (only those with time
/// samples can), by prim and name, in stage order.
fn changed_at(stage: &Stage, time: TimeCode) -> Vec<(PrimId, String)> {
    let mut changed = Vec::new();
    for (id, prim) in stage.depth_first() {
        for attr in prim.attributes.iter().filter(|a| !a.time_samples.is_empty()) {
            if attr.value_at(time).as_ref() != attr.value.as_ref().map(|(v, _)| v) {
                changed.push((id, attr.name.clone()));
            }
        }
    }
    changed
}

/// The number of files in `sources` (names past the end read `<unknown>`).
fn file_count(sources: &SourceMap) -> u32 {
    let (mut low, mut high) = (0u32, 1u32);
    while sources.name(FileId(high - 1)) != "<unknown>" {
        low = high;
        high = high.saturating_mul(2);
    }
    // The first unknown index lies in [low, high).
    while low < high {
        let mid = low + (high - low) / 2;
        if sources.name(FileId(mid)) == "<unknown>" { high = mid } else { low = mid + 1 }
    }
    low
}

/// `path` canonicalised when it exists (so two spellings of one file compare equal).
fn canonical(path: &Path) -> PathBuf {
    crate::input::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}
