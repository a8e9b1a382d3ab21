//! The subcommands behind `strata`: each loads its input, reports diagnostics to stderr and
//! prints its result to stdout. Kept in the library so tests can run them.

use crate::abi::MaterialCode;
use crate::backend::{BackendKind, Compiler};
use crate::compose::scene::{SceneComposition, compose_stage};
use crate::compose::slots::PrimStack;
use crate::diag::{Diagnostics, SourceMap};
use crate::front::library::Library;
use crate::ir::ssa::EntryKind;
use crate::ir::wired::{self, PassOptions};
use crate::render::ExrOptions;
use crate::scene::{Stage, TimeCode};
use crate::scenes;
use serde::Serialize;
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

// `eprint!`/`eprintln!` panic when stderr is closed (`strata check … 2>&1 | head -1`). These
// shadow them in this module: the text is lost, never the run, which ends with its own exit
// code.
macro_rules! eprint {
    ($($arg:tt)*) => {{
        let _ = std::io::Write::write_fmt(&mut std::io::stderr(), format_args!($($arg)*));
    }};
}
macro_rules! eprintln {
    ($($arg:tt)*) => {{
        let _ = std::io::Write::write_fmt(&mut std::io::stderr(), format_args!("{}\n", format_args!($($arg)*)));
    }};
}
macro_rules! println {
    ($($arg:tt)*) => {{
        let _ = std::io::Write::write_fmt(&mut std::io::stdout(), format_args!("{}\n", format_args!($($arg)*)));
    }};
}

/// A command failed; its diagnostics were already printed.
#[derive(Debug)]
pub struct Failure;

/// Prints diagnostics to stderr and fails if any is an error.
fn report(diags: &Diagnostics, sources: &SourceMap) -> Result<(), Failure> {
    let text = diags.render(sources);
    if !text.is_empty() {
        eprint!("{text}");
    }
    if diags.has_errors() {
        let n = diags.error_count();
        eprintln!("error: {n} error{} found", if n == 1 { "" } else { "s" });
        Err(Failure)
    } else {
        Ok(())
    }
}

/// Opens a scene file, or the embedded default scene when `path` is `None`.
pub fn open_scene(path: Option<&Path>, sources: &mut SourceMap, diags: &mut Diagnostics) -> Option<Stage> {
    open_scene_at(path, None, sources, diags)
}

/// As [`open_scene`], read at `time` (`--time`; `None`: [`Stage::opening_time`]).
pub fn open_scene_at(
    path: Option<&Path>,
    time: Option<TimeCode>,
    sources: &mut SourceMap,
    diags: &mut Diagnostics,
) -> Option<Stage> {
    let mut stage = match path {
        Some(p) => Stage::open(p, sources, diags).ok(),
        None => {
            let (name, text) = scenes::DEFAULT_SCENE;
            Stage::from_text(name, text, Path::new(scenes::EMBEDDED_DIR), sources, diags).ok()
        }
    }?;
    if let Some(time) = time {
        stage.set_time(time);
    }
    Some(stage)
}

#[derive(Serialize)]
struct JsonOverride<'a> {
    slot: String,
    material: &'a str,
    bound_at: &'a str,
}

#[derive(Serialize)]
struct JsonLayer<'a> {
    slot: String,
    material: &'a str,
    bound_at: &'a str,
    overrides: Vec<JsonOverride<'a>>,
}

#[derive(Serialize)]
struct JsonPrim<'a> {
    prim: &'a str,
    layers: Vec<JsonLayer<'a>>,
}

/// The `strata layers --json` document (DESIGN.md).
pub fn layers_json(stacks: &[PrimStack]) -> String {
    let prims: Vec<JsonPrim> = stacks
        .iter()
        .map(|s| JsonPrim {
            prim: &s.prim,
            layers: s
                .layers
                .iter()
                .map(|l| JsonLayer {
                    slot: l.slot.name(),
                    material: &l.applied.material,
                    bound_at: &l.applied.bound_at,
                    overrides: l
                        .overrides
                        .iter()
                        .map(|o| JsonOverride {
                            slot: o.slot.name(),
                            material: &o.applied.material,
                            bound_at: &o.applied.bound_at,
                        })
                        .collect(),
                })
                .collect(),
        })
        .collect();
    serde_json::to_string_pretty(&prims).unwrap_or_default()
}

/// The `strata layers` table: per prim, layers bottom to top, `*` marking bindings authored
/// on the prim itself (the paper's bright icons) rather than inherited. With the `stage`, a
/// prim with no layers says which display primvars its default substance reads.
pub fn layers_table(stacks: &[PrimStack], stage: Option<&crate::scene::Stage>) -> String {
    let mut out = String::new();
    // Slot names are padded to 12 columns, or to the longest (`material:binding`) when wider.
    let width = stacks
        .iter()
        .flat_map(|s| s.layers.iter().flat_map(|l| std::iter::once(&l.slot).chain(l.overrides.iter().map(|o| &o.slot))))
        .map(|s| s.name().chars().count())
        .max()
        .unwrap_or(0)
        .max(12);
    for stack in stacks {
        out += &format!("{}\n", stack.prim);
        if stack.layers.is_empty() {
            let display = stage.map(|s| crate::compose::scene::display_primvars(s, &stack.prim)).unwrap_or_default();
            out += &format!("  (default substance: {})\n", display.describe());
        }
        for layer in &stack.layers {
            let mark = if layer.applied.bound_at == stack.prim { '*' } else { ' ' };
            out += &format!(
                "  {mark} {:<width$} {:<40} bound at {}\n",
                layer.slot.name(),
                layer.applied.material,
                layer.applied.bound_at
            );
            for o in &layer.overrides {
                let mark = if o.applied.bound_at == stack.prim { '*' } else { ' ' };
                out += &format!(
                    "  {mark} {:<width$} {:<40} bound at {}\n",
                    o.slot.name(),
                    o.applied.material,
                    o.applied.bound_at
                );
            }
        }
    }
    out
}

/// `strata layers [SCENE] [--json]`
pub fn layers(scene: Option<&Path>, json: bool, time: Option<TimeCode>) -> Result<(), Failure> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = open_scene_at(scene, time, &mut sources, &mut diags);
    let stacks = match &stage {
        Some(stage) => {
            let tree = crate::compose::scene::binding_tree(stage, &mut diags);
            crate::compose::slots::resolve_stacks(&tree, &mut diags)
        }
        None => Vec::new(),
    };
    report(&diags, &sources)?;
    let text = if json { layers_json(&stacks) + "\n" } else { layers_table(&stacks, stage.as_ref()) };
    print_out(&text)
}

fn print_out(text: &str) -> Result<(), Failure> {
    let mut stdout = std::io::stdout().lock();
    match stdout.write_all(text.as_bytes()).and_then(|_| stdout.flush()) {
        Ok(()) => Ok(()),
        // A closed pipe (`strata ir … | head`) is not an error worth a message.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        Err(e) => {
            eprintln!("error: cannot write output: {e}");
            Err(Failure)
        }
    }
}

/// Composes a scene file completely, reporting every problem.
pub fn compose_file(
    scene: Option<&Path>,
    sources: &mut SourceMap,
    diags: &mut Diagnostics,
) -> Option<SceneComposition> {
    let stage = open_scene(scene, sources, diags)?;
    Some(compose_stage(&stage, sources, diags))
}

/// `strata ir SCENE --prim PATH [--lowered]`: the wired IR of one prim's material, or its
/// lowered IR.
pub fn ir(scene: &Path, prim: &str, optimize: bool, stats: bool, lowered: bool) -> Result<(), Failure> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let composition = compose_file(Some(scene), &mut sources, &mut diags);
    report(&diags, &sources)?;
    let Some(composition) = composition else { return Err(Failure) };
    let Some(material) = composition.material_of(prim) else {
        eprintln!("error: `{prim}` is not a renderable prim of {}", scene.display());
        let prims: Vec<&str> = composition.stacks.iter().map(|s| s.prim.as_str()).take(20).collect();
        eprintln!("  renderable prims: {}", prims.join(", "));
        return Err(Failure);
    };
    let mut diags = Diagnostics::new();
    let passes = PassOptions { optimize };
    let (text, stats_line) = if lowered {
        let mut compiler = Compiler::new(BackendKind::Jit, passes);
        let module = compiler.lower(&composition.library, material, &mut diags);
        let line = format!("lowered: {} function(s), {} instruction(s)", module.functions.len(), module.inst_count());
        (module.to_text(), line)
    } else {
        let wired = wired::build(&composition.library, material, passes, &mut diags);
        (wired.to_text(&composition.library), wired.stats_line())
    };
    report(&diags, &sources)?;
    if stats {
        eprintln!("{stats_line}");
    }
    print_out(&text)
}

/// Checks a substance file or scene: every diagnostic, and a one-line summary when it is clean.
pub fn check_file(file: &Path) -> (Diagnostics, SourceMap, String) {
    check_file_at(file, None)
}

/// As [`check_file`], with a scene read at `time` (`None`: [`Stage::opening_time`]).
pub fn check_file_at(file: &Path, time: Option<TimeCode>) -> (Diagnostics, SourceMap, String) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let is_substance = file.extension().is_some_and(|e| e == "ash");
    let summary = if is_substance {
        let lib = Library::load(&[(file.to_path_buf(), Default::default())], &mut sources, &mut diags);
        let user = lib.graphs.len().saturating_sub(1);
        format!("{}: ok ({user} graph(s))", file.display())
    } else {
        // Everything `render` would reject: composition, lowering (textures), geometry,
        // lights and camera — all without generating code or tracing a ray.
        match open_scene_at(Some(file), time, &mut sources, &mut diags) {
            Some(stage) => {
                let c = compose_stage(&stage, &mut sources, &mut diags);
                let mut compiler = Compiler::new(BackendKind::Jit, PassOptions::default());
                let mut distinct = std::collections::HashSet::new();
                for material in &c.materials {
                    distinct.insert(compiler.lower(&c.library, material, &mut diags).to_text());
                }
                crate::render::Scene::from_stage(&stage, &|_| Some(0), &mut diags);
                format!(
                    "{}: ok ({} renderable prim(s), {} distinct material(s))",
                    file.display(),
                    c.stacks.len(),
                    distinct.len()
                )
            }
            None => String::new(),
        }
    };
    (diags, sources, summary)
}

/// `strata check FILE [--time T] [--strict]`
pub fn check(file: &Path, time: Option<TimeCode>, strict: bool) -> Result<(), Failure> {
    let (mut diags, sources, summary) = check_file_at(file, time);
    if strict {
        diags.make_warnings_errors();
    }
    report(&diags, &sources)?;
    print_out(&(summary + "\n"))
}

/// What `strata render` was asked to do.
#[derive(Clone, Debug)]
pub struct RenderArgs {
    /// The scene (`None`: the embedded default scene).
    pub scene: Option<std::path::PathBuf>,
    /// The EXR to write; the PNG preview goes beside it.
    pub output: std::path::PathBuf,
    /// Image size, samples, seed, threads, depth and layer mode.
    pub settings: crate::render::RenderSettings,
    /// Which backend runs the shaders.
    pub backend: BackendKind,
    /// Constant folding and layer pruning (off only to compare).
    pub optimize: bool,
    /// Print compile and render statistics.
    pub stats: bool,
    /// Store beauty and colour channels as half floats.
    pub half: bool,
    /// The camera prim to render through (`None`: the stage's render settings camera, else
    /// the first camera).
    pub camera: Option<String>,
    /// Subdivision levels for subdivision-surface meshes (`--subdiv-level`).
    pub subdiv_level: u32,
    /// Micro-triangle edge length in pixels for displaced surfaces (`--dicing-rate`).
    pub dicing_rate: f32,
    /// Whether `settings.width`/`height` were given (`--res`); if not, a UsdRender
    /// `RenderSettings` prim's `resolution` replaces them.
    pub resolution_given: bool,
    /// Whether a stage without lights gets the default lights (`--no-default-lights`: never).
    pub default_lights: crate::render::scene::DefaultLights,
    /// Every warning is an error (`--strict`): nothing is rendered from a stage USD had to
    /// compose around.
    pub strict: bool,
    /// The time code to render (`--time`; `None`: [`Stage::opening_time`]).
    pub time: Option<TimeCode>,
}

/// A scene with every distinct material compiled.
pub struct CompiledScene {
    /// The composed stage.
    pub stage: Stage,
    /// Compiled materials.
    pub materials: Vec<Arc<dyn MaterialCode>>,
    /// Per renderable prim path, its index in `materials`.
    pub prim_material: HashMap<String, usize>,
    /// Per material, a name for its slot stack (see [`material_name`]), for ID mattes.
    pub material_names: Vec<String>,
    /// The compiler, with its statistics.
    pub compiler: Compiler,
    /// Wall time reading the scene (USD and every file it names) and composing it, ms.
    pub parse_ms: f64,
    /// Wall time composing slot stacks into materials, ms.
    pub compose_ms: f64,
    /// Wall time compiling the materials (wire, passes, lowering, codegen), ms.
    pub compile_ms: f64,
}

/// Composes a scene and compiles every distinct material once.
pub fn compile_scene(
    scene: Option<&Path>,
    backend: BackendKind,
    passes: PassOptions,
    sources: &mut SourceMap,
    diags: &mut Diagnostics,
) -> Option<CompiledScene> {
    compile_scene_at(scene, None, backend, passes, sources, diags)
}

/// As [`compile_scene`], with the scene read at `time` (`None`: [`Stage::opening_time`]).
pub fn compile_scene_at(
    scene: Option<&Path>,
    time: Option<TimeCode>,
    backend: BackendKind,
    passes: PassOptions,
    sources: &mut SourceMap,
    diags: &mut Diagnostics,
) -> Option<CompiledScene> {
    let start = std::time::Instant::now();
    let stage = open_scene_at(scene, time, sources, diags)?;
    let parse_ms = start.elapsed().as_secs_f64() * 1e3;
    let start = std::time::Instant::now();
    let composition = compose_stage(&stage, sources, diags);
    let compose_ms = start.elapsed().as_secs_f64() * 1e3;
    if diags.has_errors() {
        return None;
    }
    let start = std::time::Instant::now();
    let mut compiler = Compiler::new(backend, passes);
    let mut materials = Vec::with_capacity(composition.materials.len());
    for material in &composition.materials {
        materials.push(compiler.compile(&composition.library, material, diags)?);
    }
    let compile_ms = start.elapsed().as_secs_f64() * 1e3;
    let prim_material =
        composition.stacks.iter().zip(&composition.prim_material).map(|(s, m)| (s.prim.clone(), *m)).collect();
    // Each material is named after the first prim stack composing it: identical compositions
    // are shared (DESIGN.md rule 8), so that stack stands for all of them.
    let material_names = (0..materials.len())
        .map(|m| {
            let first = composition.prim_material.iter().position(|&pm| pm == m);
            first.and_then(|i| composition.stacks.get(i)).map_or_else(|| format!("material {m}"), material_name)
        })
        .collect();
    Some(CompiledScene { stage, materials, prim_material, material_names, compiler, parse_ms, compose_ms, compile_ms })
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

/// `strata render [SCENE] -o OUT.exr …`
pub fn render(args: &RenderArgs) -> Result<(), Failure> {
    // Only ever write `.exr` (and its `.png` beside it), so a slip of `-o` cannot replace the
    // scene or a substance file.
    if !args.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
        eprintln!("error: the output must be an .exr file, not `{}`", args.output.display());
        return Err(Failure);
    }
    // Both outputs' temporaries are created before anything else: an unwritable directory,
    // or an `OUT.png` that is a directory, fails now rather than after the render.
    let outputs = match crate::render::prepare_outputs(&args.output) {
        Ok(outputs) => outputs,
        Err(e) => {
            eprintln!("error: {e}");
            return Err(Failure);
        }
    };
    let compile_start = std::time::Instant::now();
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let compiled = compile_scene_at(
        args.scene.as_deref(),
        args.time,
        args.backend,
        PassOptions { optimize: args.optimize },
        &mut sources,
        &mut diags,
    );
    let mut settings = args.settings.clone();
    let scene_start = std::time::Instant::now();
    let scene = compiled.as_ref().and_then(|c| {
        let view = crate::render::scene::choose_view(&c.stage, args.camera.as_deref(), &mut diags)?;
        if let (false, Some((w, h))) = (args.resolution_given, view.resolution) {
            (settings.width, settings.height) = (w, h);
        }
        let options = crate::render::scene::SceneOptions {
            camera: view.camera,
            geometry: crate::render::geometry::GeometryOptions { subdiv_level: args.subdiv_level },
            dicing: crate::render::displace::DicingOptions {
                rate: args.dicing_rate,
                resolution: (settings.width, settings.height),
                ..Default::default()
            },
            default_lights: args.default_lights,
        };
        let refs: Vec<&dyn MaterialCode> = c.materials.iter().map(|m| m.as_ref()).collect();
        crate::render::Scene::build(&c.stage, &|p| c.prim_material.get(p).copied(), &refs, &options, &mut diags)
    });
    let scene_ms = scene_start.elapsed().as_secs_f64() * 1e3;
    if args.strict {
        diags.make_warnings_errors();
    }
    let time = compiled.as_ref().map_or(TimeCode::Default, |c| c.stage.time());
    report(&diags, &sources)?;
    let warnings = diags.warning_count();
    let (
        Some(CompiledScene { materials, compiler, material_names, parse_ms, compose_ms, compile_ms, .. }),
        Some(mut scene),
    ) = (compiled, scene)
    else {
        return Err(Failure);
    };
    scene.material_names = material_names;
    let compile_seconds = compile_start.elapsed().as_secs_f64();
    // Every input (layers, substance files, textures, dome maps) has been read by now.
    refuse_to_overwrite_inputs(&[outputs.exr_path(), outputs.png_path()])?;
    if args.stats {
        eprintln!("compile ({}): {}", args.backend, compiler.stats);
        if let Some(displacement) = &scene.displacement {
            let (world, _) = scene.accel.bytes();
            eprintln!("{displacement}; BVHs and triangles {:.1} MiB", world as f64 / (1024.0 * 1024.0));
        }
    }
    let refs: Vec<&dyn MaterialCode> = materials.iter().map(|m| m.as_ref()).collect();
    let bar = progress_bar(settings.height as u64);
    let start = std::time::Instant::now();
    let log = LogProgress::new(start);
    let progress = |done: usize, total: usize| match &bar {
        Some(bar) => bar.set_position(done as u64),
        None => log.update(done, total),
    };
    let (image, stats) = match crate::render::render(&scene, &refs, &settings, Some(&progress)) {
        Ok(result) => result,
        Err(e) => {
            eprintln!("error: {e}");
            return Err(Failure);
        }
    };
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let seconds = start.elapsed().as_secs_f64();
    let exr_options = exr_options(args, &settings, &scene, warnings, time);
    let write_start = std::time::Instant::now();
    let png = match outputs.write_with(&image, &exr_options) {
        Ok(png) => png,
        Err(e) => {
            eprintln!("error: {e}");
            return Err(Failure);
        }
    };
    let write_ms = write_start.elapsed().as_secs_f64() * 1e3;
    let s = &settings;
    // One line that always reaches the log, whatever stderr is.
    eprintln!(
        "rendered {}x{} at {} spp in {seconds:.2} s ({} backend; compile {compile_seconds:.2} s, render {seconds:.2} s, \
         {} samples/s): {} and {}",
        s.width,
        s.height,
        s.spp,
        args.backend,
        samples_per_second(stats.samples, seconds),
        args.output.display(),
        png.display()
    );
    if args.stats || stats.invalid_samples() > 0 {
        eprintln!("{stats}");
    }
    if args.stats {
        eprintln!("{}", stats.evals_line());
        eprintln!(
            "time: parse {parse_ms:.1} ms, compose {compose_ms:.1} ms, compile {compile_ms:.1} ms, \
             geometry + BVH {scene_ms:.1} ms, render {:.1} ms, write EXR + PNG {write_ms:.1} ms",
            seconds * 1e3
        );
    }
    Ok(())
}

/// Fails if any of `outputs` is a file this process read as an input: `-o` naming the
/// scene's texture (or any other input) would destroy it.
fn refuse_to_overwrite_inputs(outputs: &[&Path]) -> Result<(), Failure> {
    for output in outputs {
        if crate::input::was_read(output) {
            eprintln!("error: `{}` is an input of this run; refusing to overwrite it", output.display());
            return Err(Failure);
        }
    }
    Ok(())
}

/// `samples / seconds`, readable: `1.23M`, `45.6K` or a plain number.
fn samples_per_second(samples: u64, seconds: f64) -> String {
    let rate = samples as f64 / seconds.max(1e-9);
    match rate {
        r if r >= 1e6 => format!("{:.2}M", r / 1e6),
        r if r >= 1e3 => format!("{:.1}K", r / 1e3),
        r => format!("{r:.0}"),
    }
}

/// The EXR header of a render: the camera's matrices and the settings that made the image,
/// so a compositor (or a person reading `exrheader`) can tell how it was made, and how many
/// warnings the run reported (a farm can reject an image made from a stage with problems).
fn exr_options(
    args: &RenderArgs,
    settings: &crate::render::RenderSettings,
    scene: &crate::render::Scene,
    warnings: usize,
    time: TimeCode,
) -> ExrOptions {
    let camera = scene.camera.with_aspect(settings.width as f32 / settings.height as f32);
    let mode = match settings.mode {
        crate::render::LayerMode::Stochastic => "stochastic",
        crate::render::LayerMode::Weighted => "weighted",
        crate::render::LayerMode::Auto => "auto",
    };
    let scene_name = args.scene.as_ref().map_or("(embedded default scene)".to_string(), |p| p.display().to_string());
    ExrOptions {
        half: args.half,
        world_to_camera: Some(camera.world_to_camera_exr()),
        world_to_ndc: Some(camera.world_to_ndc_exr()),
        clipping: Some(camera.clipping_range()),
        strings: vec![
            ("strata/scene".into(), scene_name),
            ("strata/camera".into(), scene.camera_path.clone().unwrap_or_else(|| "(framing camera)".into())),
            ("strata/spp".into(), settings.spp.to_string()),
            ("strata/seed".into(), settings.seed.to_string()),
            ("strata/sampler".into(), settings.sampler.name().into()),
            ("strata/maxDepth".into(), settings.max_depth.to_string()),
            ("strata/backend".into(), args.backend.to_string()),
            ("strata/layerMode".into(), mode.into()),
            ("strata/optimize".into(), args.optimize.to_string()),
            ("strata/warnings".into(), warnings.to_string()),
            (
                "strata/defaultLights".into(),
                if scene.default_lights { "camera light + dome (the stage has no lights)" } else { "none" }.into(),
            ),
            ("strata/time".into(), time.to_string()),
        ]
        .into_iter()
        .chain(crate::render::cryptomatte::header_attributes(
            crate::render::cryptomatte::OBJECT_LAYER,
            scene.prims.iter().map(|p| p.path.as_str()),
        ))
        .chain(crate::render::cryptomatte::header_attributes(
            crate::render::cryptomatte::MATERIAL_LAYER,
            scene.material_names.iter().map(String::as_str),
        ))
        .collect(),
    }
}

/// Progress for a log (stderr not a terminal, e.g. a render farm): one plain line per 5 % of
/// rows, with elapsed and estimated remaining time.
struct LogProgress {
    start: std::time::Instant,
    /// The last 5 % step printed.
    printed: std::sync::atomic::AtomicUsize,
}

impl LogProgress {
    fn new(start: std::time::Instant) -> LogProgress {
        LogProgress { start, printed: std::sync::atomic::AtomicUsize::new(0) }
    }

    /// Prints a line when `done` of `total` rows reaches a new 5 % step.
    fn update(&self, done: usize, total: usize) {
        let step = done.saturating_mul(20) / total.max(1);
        if step <= self.printed.fetch_max(step, std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        let elapsed = self.start.elapsed().as_secs_f64();
        let left = elapsed * (total - done.min(total)) as f64 / done.max(1) as f64;
        eprintln!("render: {:3}% ({done}/{total} rows), {elapsed:.1} s elapsed, about {left:.1} s left", step * 5);
    }
}

/// A progress bar on stderr when it is a terminal (and not in CI logs).
fn progress_bar(rows: u64) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return None;
    }
    let bar = indicatif::ProgressBar::new(rows);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} rendering [{bar:40}] {percent}% {eta} left") {
        bar.set_style(style.progress_chars("=> "));
    }
    Some(bar)
}

/// The C declarations describing a shader object's ABI.
const C_HEADER_PRELUDE: &str = "\
/* Generated by `strata compile`. Link with the strata runtime library (strata_rt_* symbols). */
#include <stdint.h>

/* Shading globals, world space (abi::Globals). */
typedef struct StrataGlobals {
    float p[3], n[3], ng[3], i[3], dpdu[3], dpdv[3];
    float u, v;
    /* The primvars the material reads (see the material's primvar table); NULL, 0: none. */
    const float *primvars;
    uint32_t primvar_len;
} StrataGlobals;

/* A BSDF closure (abi::Closure): kind 0 none, 1 diffuse, 2 glossy, 3 metal, 4 glass. */
typedef struct StrataClosure {
    uint32_t kind;
    float params[8];
} StrataClosure;

/* Every function returns a status: 0 ok, 1 loop budget exceeded, 2 index out of bounds. */
enum { STRATA_OK = 0, STRATA_LOOP_BUDGET = 1, STRATA_OUT_OF_BOUNDS = 2 };
";

/// `strata compile FILE.ash -o OUT.o`: a native object with one C function per product of each
/// substance (inputs at their defaults), plus `OUT.h` declaring them.
pub fn compile(file: &Path, output: &Path) -> Result<(), Failure> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let lib = Library::load(&[(file.to_path_buf(), Default::default())], &mut sources, &mut diags);
    report(&diags, &sources)?;
    let canonical = file.canonicalize().ok();
    let substances: Vec<_> = lib
        .graphs
        .iter()
        .enumerate()
        .filter(|(i, g)| {
            g.kind == crate::front::ast::GraphKind::Substance
                && canonical.is_some()
                && lib.graph_files.get(*i).and_then(|p| p.canonicalize().ok()) == canonical
        })
        .map(|(i, g)| (crate::front::library::GraphId(i as u32), g.name.clone()))
        .collect();
    if substances.is_empty() {
        eprintln!("error: {} declares no substance", file.display());
        return Err(Failure);
    }
    let mut compiler = Compiler::new(BackendKind::Jit, PassOptions::default());
    let mut modules = Vec::new();
    for (graph, name) in &substances {
        let material = crate::compose::ComposedMaterial {
            layers: vec![crate::compose::ComposedLayer {
                slot: crate::compose::Slot::parse("000").expect("a valid slot name"),
                substance: crate::compose::MaterialRef {
                    path: String::new(),
                    graph: *graph,
                    values: Vec::new(),
                    span: Default::default(),
                },
                overrides: Vec::new(),
            }],
            ..Default::default()
        };
        modules.push((name.clone(), compiler.lower(&lib, &material, &mut diags)));
    }
    report(&diags, &sources)?;
    let mut header = C_HEADER_PRELUDE.to_string();
    let mut functions = Vec::new();
    for (name, module) in &modules {
        header += &format!("\n/* substance {name} */\n");
        if !module.info.primvars.is_empty() {
            let read: Vec<String> = module
                .info
                .primvars
                .iter()
                .map(|p| format!("{} ({} float(s)) flag at {}", p.name, p.width, p.offset))
                .collect();
            header += &format!(
                "/* primvars (g->primvars, {} floats; flag 1 = present, components follow): {} */\n",
                module.info.primvar_floats,
                read.join(", ")
            );
        }
        if let Some(m) = module.info.layers.first().and_then(|l| l.constant_mask) {
            // A mask known at compile time needs no code: define it in the header.
            header += &format!(
                "static inline uint32_t {name}_mask(const StrataGlobals *g, float *out) {{ (void)g; *out = {}f; return 0; }}\n",
                crate::front::types::format_f32(m)
            );
        }
        for f in &module.functions {
            let (product, out_ty) = match f.kind {
                EntryKind::Mask(_) => ("mask", "float *out /* 1 */"),
                EntryKind::Surface(_) => ("surface", "StrataClosure *out"),
                EntryKind::Displacement => ("displacement", "float *out /* 1 */"),
                EntryKind::Normal(_) => ("normal", "float out[3]"),
                EntryKind::Channels(_) => ("channels", "float *out"),
                EntryKind::Emission(_) => ("emission", "float out[3]"),
            };
            if let EntryKind::Channels(_) = f.kind {
                let names: Vec<String> =
                    module.info.channels.iter().map(|c| format!("{} at {}", c.name, c.offset)).collect();
                header += &format!("/* channels: {} ({} floats) */\n", names.join(", "), f.out_words);
            }
            let symbol = format!("{name}_{product}");
            header += &format!("uint32_t {symbol}(const StrataGlobals *g, {out_ty});\n");
            functions.push((symbol, f));
        }
    }
    let object = match crate::backend::object::compile(&file.display().to_string(), &functions) {
        Ok(bytes) => bytes,
        Err(e) => {
            eprintln!("error: code generation failed: {e}");
            return Err(Failure);
        }
    };
    let header_path = output.with_extension("h");
    refuse_to_overwrite_inputs(&[output, &header_path])?;
    for (path, bytes) in [(output, object.as_slice()), (header_path.as_path(), header.as_bytes())] {
        if let Err(e) = write_atomically(path, bytes) {
            eprintln!("error: cannot write {}: {e}", path.display());
            return Err(Failure);
        }
    }
    eprintln!(
        "wrote {} ({} function(s) for {} substance(s)) and {}",
        output.display(),
        functions.len(),
        modules.len(),
        header_path.display()
    );
    Ok(())
}

/// Writes a file whole or not at all: a fsynced temporary file beside it, then a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    crate::render::output::write_file_atomically(path, bytes).map_err(|e| std::io::Error::other(e.message))
}

/// `strata fuzz`: runs the fuzzer and prints its report; fails if any input failed.
pub fn fuzz(options: &crate::fuzz::FuzzOptions) -> Result<(), Failure> {
    let start = std::time::Instant::now();
    let report = match crate::fuzz::run(options, &mut |line| eprintln!("{line}")) {
        Ok(report) => report,
        Err(e) => {
            eprintln!("error: fuzzing failed: {e}");
            return Err(Failure);
        }
    };
    let secs = start.elapsed().as_secs_f64();
    println!(
        "fuzz: {} executions in {secs:.1} s ({:.0}/s, {} jobs, seed {}), {} finding(s), peak worker RSS {} MiB",
        report.executions,
        report.executions as f64 / secs.max(1e-9),
        options.jobs,
        options.seed,
        report.findings.len(),
        report.peak_rss >> 20
    );
    for f in &report.findings {
        println!("  input {} from {}: {:?} -> {}", f.k, f.base.display(), f.failure, f.saved.display());
    }
    if report.findings.is_empty() { Ok(()) } else { Err(Failure) }
}
