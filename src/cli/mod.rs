//! The subcommands behind `strata` (the binary crate; `main.rs` parses the arguments): each
//! drives the pipeline through the library's [`Session`], reports diagnostics to stderr and
//! prints its result to stdout. [`bench`] and [`fuzz`] are the measurement and fuzzing
//! subcommands; they use the library only, never this module.

pub mod bench;
pub mod fuzz;
pub mod plot;

use std::io::Write;
use std::path::Path;
use strata::backend::BackendKind;
use strata::diag::{Diagnostics, SourceMap};
use strata::ir::wired::PassOptions;
use strata::render::ExrOptions;
use strata::scene::TimeCode;
use strata::session::{Pass, SceneSource, Session, SessionOptions, ShaderObject, layers_json, layers_table};

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

// After the print macros, which it uses.
pub mod farm;

/// A command failed; its diagnostics were already printed.
#[derive(Debug)]
pub struct Failure;

/// Exit code of bad input: a scene, substance or setting with errors, parts that do not merge.
pub const EXIT_BAD_INPUT: u8 = 1;
/// Exit code of a resource failure: an output or checkpoint that cannot be written.
pub const EXIT_RESOURCE: u8 = 3;
/// Exit code of an interrupted run (SIGINT, SIGTERM, SIGHUP): as a shell reports SIGINT.
pub const EXIT_INTERRUPTED: u8 = 130;

/// Set when a failure was the machine's, not the input's ([`EXIT_RESOURCE`]).
static RESOURCE_FAILED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// A failure of the machine (disk, threads) rather than of the input: exits [`EXIT_RESOURCE`].
pub fn resource_failure() -> Failure {
    RESOURCE_FAILED.store(true, std::sync::atomic::Ordering::Relaxed);
    Failure
}

/// The exit code of a failed command.
pub fn exit_code() -> u8 {
    if RESOURCE_FAILED.load(std::sync::atomic::Ordering::Relaxed) { EXIT_RESOURCE } else { EXIT_BAD_INPUT }
}

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

/// `strata layers [SCENE] [--json]`
pub fn layers(scene: Option<&Path>, json: bool, time: Option<TimeCode>) -> Result<(), Failure> {
    let mut session = Session::open(SceneSource::from_path(scene), SessionOptions { time, ..Default::default() });
    let stacks = session.layer_stacks();
    report(&session.take_diagnostics(), session.sources())?;
    let text = if json { layers_json(&stacks) + "\n" } else { layers_table(&stacks, session.stage()) };
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

/// `strata ir SCENE --prim PATH [--lowered]`: the wired IR of one prim's material, or its
/// lowered IR.
pub fn ir(scene: &Path, prim: &str, optimize: bool, stats: bool, lowered: bool) -> Result<(), Failure> {
    let options = SessionOptions { passes: PassOptions { optimize, ..Default::default() }, ..Default::default() };
    let mut session = Session::open(SceneSource::File(scene.to_path_buf()), options);
    if session.composition().is_none() || session.diagnostics().has_errors() {
        report(&session.take_diagnostics(), session.sources())?;
        return Err(Failure);
    }
    report(&session.take_diagnostics(), session.sources())?;
    let (text, stats_line) = match session.ir(prim, lowered) {
        Some(Ok(ir)) => ir,
        Some(Err(prims)) => {
            eprintln!("error: `{prim}` is not a renderable prim of {}", scene.display());
            eprintln!("  renderable prims: {}", prims.join(", "));
            return Err(Failure);
        }
        None => return Err(Failure),
    };
    report(&session.take_diagnostics(), session.sources())?;
    if stats {
        eprintln!("{stats_line}");
    }
    print_out(&text)
}

/// `strata check FILE [--time T] [--strict]`
pub fn check(file: &Path, time: Option<TimeCode>, strict: bool) -> Result<(), Failure> {
    let (mut diags, sources, summary) = strata::session::check_file_at(file, time);
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
    pub settings: strata::render::RenderSettings,
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
    pub default_lights: strata::render::scene::DefaultLights,
    /// Every warning is an error (`--strict`): nothing is rendered from a stage USD had to
    /// compose around.
    pub strict: bool,
    /// The time code to render (`--time`; `None`: [`Stage::opening_time`]).
    pub time: Option<TimeCode>,
    /// Render only these samples of each pixel (`--samples A..B`): a partial file.
    pub samples: Option<std::ops::Range<u32>>,
    /// Render only this region (`--tile X,Y,W,H`): a partial file.
    pub tile: Option<strata::render::Region>,
    /// Render in passes of this many samples, each followed by a checkpoint (`--checkpoint`).
    pub checkpoint: Option<u32>,
    /// Continue from the checkpoint beside the output (`--resume`).
    pub resume: bool,
    /// Render these frames (`--frames`), the output's `#` run numbering each.
    pub frames: Option<farm::Frames>,
    /// Send each image to the tev viewer at this `HOST:PORT` (`--display-server`).
    pub display_server: Option<String>,
}

/// `strata render [SCENE] -o OUT.exr …`: one image, a split of it (`--samples`, `--tile`:
/// a partial file), in checkpointed passes (`--checkpoint`, `--resume`), or a frame range
/// (`--frames`, one session for every frame).
pub fn render(args: &RenderArgs) -> Result<(), Failure> {
    // Only ever write `.exr` (and its `.png` beside it), so a slip of `-o` cannot replace the
    // scene or a substance file.
    if !args.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
        eprintln!("error: the output must be an .exr file, not `{}`", args.output.display());
        return Err(Failure);
    }
    let frames: Vec<Option<i64>> = match &args.frames {
        Some(frames) => frames.list().into_iter().map(Some).collect(),
        None => vec![None],
    };
    let output_of = |frame: Option<i64>| match frame {
        Some(frame) => farm::frame_path(&args.output, frame),
        None => Some(args.output.clone()),
    };
    let Some(first_output) = output_of(frames[0]) else {
        eprintln!("error: with --frames the output needs a `#` run for the frame number, e.g. `shot.####.exr`");
        return Err(Failure);
    };
    // Both outputs' temporaries are created before anything else: an unwritable directory,
    // or an `OUT.png` that is a directory, fails now rather than after the render.
    let mut first_outputs = Some(prepare(&first_output)?);
    let compile_start = std::time::Instant::now();
    let time = frames[0].map(|f| TimeCode::At(f as f64)).or(args.time);
    let options = SessionOptions {
        backend: args.backend,
        passes: PassOptions { optimize: args.optimize, ..Default::default() },
        time,
        strict: args.strict,
        limits: None,
    };
    let mut session = Session::open(SceneSource::from_path(args.scene.as_deref()), options);
    if session.compile().is_some() {
        session.lint_slots();
    }
    let start = std::time::Instant::now();
    let before = session.stats().clone();
    for (k, &frame) in frames.iter().enumerate() {
        let output = output_of(frame).unwrap_or_else(|| args.output.clone());
        let outputs = match first_outputs.take() {
            Some(outputs) => outputs,
            None => prepare(&output)?,
        };
        let frame_start = std::time::Instant::now();
        let update = frame.map(|f| session.set_time(TimeCode::At(f as f64)));
        // A later frame's "compile" is its update: new time, recompiled materials, rebuilt scene.
        let prepare_start = if k == 0 { compile_start } else { frame_start };
        // One frame: no update follows, so the stage goes before the BVH build (memory peak).
        let last = frames.len() == 1;
        let rendered = render_frame(args, &mut session, outputs, frame, prepare_start, last)?;
        if let (Some(frame), Some(update)) = (frame, update) {
            let what = if k == 0 {
                "first frame: everything built".to_string()
            } else if update.instances_moved && !rendered.rebuilt {
                "instances moved: top-level BVH built again, geometry and materials kept".to_string()
            } else if !update.recomposed && !rendered.rebuilt {
                "nothing animated changed".to_string()
            } else {
                let scene = match (&update.rebuild_reason, update.geometry_rebuilt || rendered.rebuilt) {
                    (Some(why), _) if !why.is_empty() => format!("rebuilt (geometry, BVH): {why}"),
                    (_, true) => "rebuilt (geometry, BVH)".to_string(),
                    (_, false) => "kept".to_string(),
                };
                format!("{} material(s) recompiled, scene {scene}", update.recompiled)
            };
            eprintln!(
                "frame {frame} ({}/{}): {} in {:.2} s ({what})",
                k + 1,
                frames.len(),
                output.display(),
                frame_start.elapsed().as_secs_f64()
            );
        }
    }
    if frames.len() > 1 {
        let after = session.stats();
        let seconds = start.elapsed().as_secs_f64();
        eprintln!(
            "rendered {} frames in {seconds:.2} s ({:.2} s a frame): stage read {} time(s), {} material(s) compiled, \
             render scene built {} time(s), rebound {} time(s) and its instances moved {} time(s)",
            frames.len(),
            seconds / frames.len() as f64,
            after.stage_reads,
            after.materials_compiled,
            after.scene_builds - before.scene_builds,
            after.scene_rebinds - before.scene_rebinds,
            after.instance_moves - before.instance_moves
        );
    }
    Ok(())
}

/// The outputs of `path`, or the failure to create them (a resource failure).
fn prepare(path: &Path) -> Result<strata::render::PreparedOutputs, Failure> {
    strata::render::prepare_outputs(path).map_err(|e| {
        eprintln!("error: {e}");
        resource_failure()
    })
}

/// What one frame's render did.
struct Rendered {
    /// The render scene was built again because the view (an animated camera) changed.
    rebuilt: bool,
}

/// Renders the session's current time into `outputs` (a partial file for a split). With
/// `last`, no update follows: the session gives its stage up before the BVH build.
fn render_frame(
    args: &RenderArgs,
    session: &mut Session,
    outputs: strata::render::PreparedOutputs,
    frame: Option<i64>,
    compile_start: std::time::Instant,
    last: bool,
) -> Result<Rendered, Failure> {
    let mut settings = args.settings.clone();
    let mut prepared = false;
    let builds = session.stats().scene_builds;
    if session.compile().is_some()
        && let Some(view) = session.view(args.camera.as_deref())
    {
        if let (false, Some((w, h))) = (args.resolution_given, view.resolution) {
            (settings.width, settings.height) = (w, h);
        }
        let options = strata::render::scene::SceneOptions {
            camera: view.camera,
            geometry: strata::render::geometry::GeometryOptions { subdiv_level: args.subdiv_level },
            dicing: strata::render::geometry::displace::DicingOptions {
                rate: args.dicing_rate,
                resolution: (settings.width, settings.height),
                ..Default::default()
            },
            default_lights: args.default_lights,
        };
        // Textures decode on a core the scene build leaves idle; stopped when the render
        // starts, so it never competes with the render's threads.
        let cores = settings.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
        let ahead = (cores > 1).then(strata::runtime::texture::Prefetch::start);
        prepared = if last { session.prepare_releasing_stage(&options) } else { session.prepare(&options) }.is_some();
        drop(ahead);
    }
    let rebuilt = session.stats().scene_builds > builds && builds > 0;
    let time = session.time();
    let diags = session.take_diagnostics();
    report(&diags, session.sources())?;
    let warnings = diags.warning_count();
    let (true, Some(scene)) = (prepared, session.scene()) else {
        return Err(Failure);
    };
    let compile_seconds = compile_start.elapsed().as_secs_f64();
    // Every input (layers, substance files, textures, dome maps) has been read by now.
    refuse_to_overwrite_inputs(&[outputs.exr_path(), outputs.png_path()])?;
    if args.stats {
        eprintln!("compile ({}): {}", args.backend, session.compile_stats());
        if let Some(displacement) = &scene.displacement {
            let (world, _) = scene.accel.bytes();
            eprintln!("{displacement}; BVHs and triangles {:.1} MiB", world as f64 / (1024.0 * 1024.0));
        }
    }
    let mut exr_options = exr_options(args, &settings, scene, warnings, time);
    if let Some(frame) = frame {
        exr_options.strings.push(("strata/frame".into(), frame.to_string()));
    }
    let bar = progress_bar(settings.height as u64);
    let start = std::time::Instant::now();
    let log = LogProgress::new(start);
    let progress = |done: usize, total: usize| match &bar {
        Some(bar) => bar.set_position((done * settings.height / total.max(1)) as u64),
        None => log.update(done, total),
    };
    let window = strata::render::Window { region: args.tile, samples: args.samples.clone() };
    let split = window != strata::render::Window::FULL;
    let exr_path = outputs.exr_path().to_path_buf();
    let (image, stats, sums) = if split || args.checkpoint.is_some() || args.resume {
        let fingerprint = session.fingerprint(&settings).ok_or(Failure)?;
        let layout = session.sums_layout().ok_or(Failure)?;
        let full = strata::render::Region { x: 0, y: 0, width: settings.width, height: settings.height };
        let split = strata::render::film::partial::Split {
            fingerprint: strata::render::film::partial::split_fingerprint(fingerprint, &exr_options),
            width: settings.width,
            height: settings.height,
            spp: settings.spp,
            region: args.tile.unwrap_or(full),
            samples: args.samples.clone().unwrap_or(0..settings.spp),
        };
        if split.region.x + split.region.width > settings.width
            || split.region.y + split.region.height > settings.height
            || split.region.width == 0
            || split.region.height == 0
            || split.samples.is_empty()
            || split.samples.end > settings.spp
        {
            let r = split.region;
            eprintln!(
                "error: the split (tile {},{},{},{}, samples {}..{}) is empty or outside the {}x{} image at {} spp",
                r.x,
                r.y,
                r.width,
                r.height,
                split.samples.start,
                split.samples.end,
                settings.width,
                settings.height,
                settings.spp
            );
            return Err(Failure);
        }
        let passes = farm::Passes {
            settings: &settings,
            window,
            every: args.checkpoint,
            resume: args.resume,
            checkpoint: farm::checkpoint_path(outputs.exr_path()),
            split,
            layout: &layout,
            options: &exr_options,
        };
        let (image, stats, sums) = farm::render_passes(session, &passes, &progress)?;
        (image, stats, Some((sums, passes.split.clone(), layout.clone(), passes.checkpoint.clone())))
    } else {
        let pass = Pass::full(settings.clone());
        let (image, stats) = match session.render(&pass, Some(&progress)) {
            Ok(result) => result,
            Err(e) => {
                eprintln!("error: {e}");
                return Err(Failure);
            }
        };
        (image, stats, None)
    };
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    // Stacks the random walk does not cover render by albedo scaling: said once per kind.
    for kind in strata::render::material::closure::walk::take_fallback() {
        eprintln!("warning: --layering random-walk: {kind} is rendered by albedo scaling");
    }
    let seconds = start.elapsed().as_secs_f64();
    let write_start = std::time::Instant::now();
    let written = match &sums {
        Some((sums, split_info, layout, _)) if split => {
            // A partial file only: the PNG of a split would be a fragment.
            drop(outputs);
            strata::render::film::partial::write_partial(&exr_path, &image, sums, layout, split_info, &exr_options)
                .map(|()| "no PNG for a split".to_string())
        }
        _ => outputs.write_with(&image, &exr_options).map(|png| png.display().to_string()),
    };
    let png = written.map_err(|e| {
        eprintln!("error: {e}");
        resource_failure()
    })?;
    if let Some(address) = &args.display_server {
        // The files are written: a viewer that cannot be reached is only a warning.
        let name = exr_path.file_name().map_or_else(|| "strata".into(), |n| n.to_string_lossy().into_owned());
        let sent =
            strata::render::film::display::DisplayServer::connect(address, &name).and_then(|mut d| d.send(&image));
        if let Err(e) = sent {
            eprintln!("warning: {e}");
        }
    }
    if let Some((_, _, _, checkpoint)) = &sums {
        // The output is whole: its checkpoint is no longer needed.
        let _ = std::fs::remove_file(checkpoint);
    }
    let write_ms = write_start.elapsed().as_secs_f64() * 1e3;
    let s = &settings;
    let what = match (&args.tile, &args.samples) {
        (None, None) => String::new(),
        (tile, samples) => format!(
            " (split: {}samples {}..{})",
            tile.map_or(String::new(), |r| format!("tile {},{},{},{}, ", r.x, r.y, r.width, r.height)),
            samples.as_ref().map_or(0, |r| r.start),
            samples.as_ref().map_or(s.spp, |r| r.end)
        ),
    };
    // One line that always reaches the log, whatever stderr is.
    eprintln!(
        "rendered {}x{} at {} spp{what} in {seconds:.2} s ({} backend; compile {compile_seconds:.2} s, render \
         {seconds:.2} s, {} samples/s): {} and {png}",
        s.width,
        s.height,
        s.spp,
        args.backend,
        samples_per_second(stats.samples, seconds),
        exr_path.display(),
    );
    if args.stats || stats.invalid_samples() > 0 {
        eprintln!("{stats}");
    }
    if args.stats {
        eprintln!("{}", stats.evals_line());
        let t = session.stats();
        eprintln!(
            "time: parse {:.1} ms, compose {:.1} ms, compile {:.1} ms, geometry + BVH {:.1} ms, render {:.1} ms, \
             write EXR + PNG {write_ms:.1} ms",
            t.parse_ms,
            t.compose_ms,
            t.compile_ms,
            t.scene_ms,
            seconds * 1e3
        );
    }
    Ok(Rendered { rebuilt })
}

/// Fails if any of `outputs` is a file this process read as an input: `-o` naming the
/// scene's texture (or any other input) would destroy it.
fn refuse_to_overwrite_inputs(outputs: &[&Path]) -> Result<(), Failure> {
    for output in outputs {
        if strata::input::was_read(output) {
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
    settings: &strata::render::RenderSettings,
    scene: &strata::render::Scene,
    warnings: usize,
    time: TimeCode,
) -> ExrOptions {
    let camera = scene.camera.with_aspect(settings.width as f32 / settings.height as f32);
    let mode = match settings.mode {
        strata::render::LayerMode::Stochastic => "stochastic",
        strata::render::LayerMode::Weighted => "weighted",
        strata::render::LayerMode::Auto => "auto",
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
            ("strata/rrDepth".into(), settings.rr_depth.to_string()),
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
        .chain(strata::render::film::cryptomatte::header_attributes(
            strata::render::film::cryptomatte::OBJECT_LAYER,
            scene.prims.iter().map(|p| p.path.as_str()),
        ))
        .chain(strata::render::film::cryptomatte::header_attributes(
            strata::render::film::cryptomatte::MATERIAL_LAYER,
            scene.material_names.iter().map(String::as_str),
        ))
        .collect(),
        placement: None,
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

/// `strata compile FILE.ash -o OUT.o`: a native object with one C function per product of each
/// substance (inputs at their defaults), plus `OUT.h` declaring them.
pub fn compile(file: &Path, output: &Path) -> Result<(), Failure> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let compiled = strata::session::shader_object(file, &mut sources, &mut diags);
    report(&diags, &sources)?;
    let Some(ShaderObject { object, header, functions, substances }) = compiled else {
        return Err(Failure);
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
        "wrote {} ({functions} function(s) for {substances} substance(s)) and {}",
        output.display(),
        header_path.display()
    );
    Ok(())
}

/// Writes a file whole or not at all: a fsynced temporary file beside it, then a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    strata::render::film::output::write_file_atomically(path, bytes).map_err(|e| std::io::Error::other(e.message))
}

/// `strata fuzz`: runs the fuzzer and prints its report; fails if any input failed.
pub fn fuzz(options: &fuzz::FuzzOptions) -> Result<(), Failure> {
    let start = std::time::Instant::now();
    let report = match fuzz::run(options, &mut |line| eprintln!("{line}")) {
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

/// `strata view [SCENE] [--port P] [--bind ADDR] …`: starts the server, prints its URL and
/// serves until interrupted.
pub fn view(options: strata::view::ViewOptions) -> Result<(), Failure> {
    let follows = !matches!(options.scene, SceneSource::Default);
    let server = strata::view::start(options).map_err(|e| {
        eprint!("{e}");
        eprintln!("error: strata view did not start");
        Failure
    })?;
    println!("strata view: {}", server.url());
    if !follows {
        eprintln!(
            "note: the embedded default scene has no files to follow; `strata view SCENE.usda` follows saved edits"
        );
    }
    server.wait().map_err(|e| {
        eprintln!("error: {e}");
        Failure
    })
}
