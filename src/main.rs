//! The `strata` command line. See `strata --help` and DESIGN.md for the contracts.

mod cli;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use strata::backend::BackendKind;
use strata::render::material::closure::LayeringMode;
use strata::render::sampling::sampler::SamplerKind;
use strata::render::{LayerMode, RenderSettings};

// `print!`/`eprintln!` panic on a closed pipe (`strata … 2>&1 | head -1`); these shadow
// them: the text is lost, the exit code is the run's.
macro_rules! print {
    ($($arg:tt)*) => {{
        let _ = std::io::Write::write_fmt(&mut std::io::stdout(), format_args!($($arg)*));
    }};
}
macro_rules! eprintln {
    ($($arg:tt)*) => {{
        let _ = std::io::Write::write_fmt(&mut std::io::stderr(), format_args!("{}\n", format_args!($($arg)*)));
    }};
}

#[derive(Parser)]
#[command(
    name = "strata",
    version,
    about = "Shading-language compiler and path tracer for binding-level layered shading"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
    /// Largest input file read (scene, layer, substance, texture), in bytes; K, M and G
    /// suffixes are binary multiples. Default 256M.
    #[arg(long, global = true, value_name = "BYTES", value_parser = parse_size)]
    max_input_size: Option<u64>,
    /// Largest texture or dome map decoded, in pixels (checked from its header first).
    /// Default 134217728 (16384 x 8192).
    #[arg(long, global = true, value_name = "PIXELS", value_parser = parse_size)]
    max_texture_pixels: Option<u64>,
    /// Largest single structure built — a decoded texture, the film, the instances and their
    /// BVHs — in bytes, estimated before it is allocated; K, M and G suffixes. Default: half
    /// the memory this process may use (RAM, `ulimit -v`, the cgroup's limit).
    #[arg(long, global = true, value_name = "BYTES", value_parser = parse_size)]
    max_memory: Option<u64>,
    /// Texels resident at once, in bytes (K, M and G suffixes): textures are decoded when a
    /// lookup first reaches them and their least recently used mip levels are evicted past
    /// this; any budget renders the same image, a small one more slowly. Default: half the
    /// memory budget (`--max-memory`).
    #[arg(long, global = true, value_name = "BYTES", value_parser = parse_size)]
    texture_memory: Option<u64>,
}

#[derive(Subcommand)]
enum Command {
    /// Print the composed slot table of every renderable prim.
    Layers {
        /// A USD scene: `.usda`, `.usdc`, `.usd` or `.usdz` (default: the embedded default scene).
        scene: Option<PathBuf>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// The time code to read animated attributes at: a number or `default` (default: the
        /// stage's startTimeCode when it has time samples, else the default time).
        #[arg(long, value_name = "TIME")]
        time: Option<strata::scene::TimeCode>,
    },
    /// Print the wired IR of one prim's composed material.
    Ir {
        /// A USD scene: `.usda`, `.usdc`, `.usd` or `.usdz`.
        scene: PathBuf,
        /// The prim path (`/World/Ball`).
        #[arg(long)]
        prim: String,
        /// Skip constant folding and layer pruning.
        #[arg(long)]
        no_optimize: bool,
        /// Print node counts per pass to stderr.
        #[arg(long)]
        stats: bool,
        /// Print the lowered IR (typed SSA, one function per entry point) instead.
        #[arg(long)]
        lowered: bool,
    },
    /// Render a scene through its compiled materials to a multi-layer EXR and a PNG preview.
    Render {
        /// A USD scene: `.usda`, `.usdc`, `.usd` or `.usdz` (default: the embedded default scene).
        scene: Option<PathBuf>,
        /// The EXR to write (the PNG preview goes beside it).
        #[arg(short, long, default_value = "strata.exr")]
        output: PathBuf,
        /// Camera samples per pixel.
        #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT (default: a UsdRender RenderSettings prim's `resolution`,
        /// else 640x480).
        #[arg(long, value_parser = parse_resolution)]
        res: Option<(usize, usize)>,
        /// The Camera prim to render through (default: the RenderSettings prim's `camera`,
        /// else the first Camera, else a camera framing the scene).
        #[arg(long, value_name = "PRIM")]
        camera: Option<String>,
        /// Catmull-Clark levels for subdivision-surface meshes (UsdGeom's default scheme); 0
        /// renders the control cage. A mesh is refined fewer times when it would pass 262 144
        /// faces, and a cage that passes it at one level is rendered as it is.
        #[arg(long, default_value_t = strata::render::geometry::DEFAULT_SUBDIV_LEVEL,
              value_parser = clap::value_parser!(u32).range(0..=6))]
        subdiv_level: u32,
        /// Displaced surfaces are diced into micro-triangles about this many pixels long (a
        /// scene past 4 194 304 micro-triangles is diced coarser, with a warning).
        #[arg(long, default_value_t = strata::render::geometry::displace::DEFAULT_DICING_RATE, value_parser = parse_dicing_rate)]
        dicing_rate: f32,
        /// Store RGBA and colour AOVs (albedo, N, colour channels) as 16-bit half floats;
        /// Z, P, scalar and integer channels stay 32-bit.
        #[arg(long)]
        half: bool,
        /// Seed of all sampling: the same seed gives the same image whatever the thread count.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Worker threads (default: all cores).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1024))]
        threads: Option<u32>,
        /// Maximum path depth (bounces).
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=1024))]
        max_depth: u32,
        /// Bounces before Russian roulette may end a path (paths shorter than this are never
        /// ended early; a larger value trades time for less noise in deep inter-reflection).
        #[arg(long, default_value_t = strata::render::film::DEFAULT_RR_DEPTH, value_parser = clap::value_parser!(u32).range(1..=1024))]
        rr_depth: u32,
        /// Shader backend.
        #[arg(long, value_enum, default_value_t = BackendKind::Jit)]
        backend: BackendKind,
        /// Evaluate every layer weighted at each vertex, for every material (default: chosen per
        /// material, weighted for 2 to 8 pickable layers, one layer picked by weight otherwise).
        #[arg(long, conflicts_with = "stochastic")]
        weighted: bool,
        /// Pick one layer per vertex by mask weights, for every material.
        #[arg(long)]
        stochastic: bool,
        /// How each decision's numbers are spread over a pixel's samples: `sobol`
        /// (Owen-scrambled, the default) or `independent` (plain Monte Carlo, for comparison).
        #[arg(long, default_value = "sobol", value_parser = parse_sampler)]
        sampler: SamplerKind,
        /// How closures' `layer(top, base)` is rendered: albedo-scaling (fast) or random-walk
        /// (the stochastic reference).
        #[arg(long, default_value = "albedo-scaling", value_parser = parse_layering)]
        layering: LayeringMode,
        /// Skip constant folding and layer pruning (for comparison).
        #[arg(long)]
        no_optimize: bool,
        /// Print compile and render statistics.
        #[arg(long)]
        stats: bool,
        /// Never light a stage that has no lights (by default it gets a light travelling with
        /// the camera and a dim dome, as usdview shows it).
        #[arg(long)]
        no_default_lights: bool,
        /// Make every warning an error (exit 1, nothing written): for farms and CI.
        #[arg(long)]
        strict: bool,
        /// The time code to read animated attributes at: a number or `default` (default: the
        /// stage's startTimeCode when it has time samples, else the default time).
        #[arg(long, value_name = "TIME", conflicts_with = "frames")]
        time: Option<strata::scene::TimeCode>,
        /// Render only samples A..B (half-open) of each pixel's `--spp`: writes a partial EXR
        /// that `strata merge` combines with the other parts, bit for bit.
        #[arg(long, value_name = "A..B", value_parser = parse_sample_range)]
        samples: Option<std::ops::Range<u32>>,
        /// Render only the pixels of a region, X,Y,W,H from the top-left corner: writes a
        /// partial EXR that `strata merge` combines with the other parts.
        #[arg(long, value_name = "X,Y,W,H", value_parser = parse_tile)]
        tile: Option<strata::render::Region>,
        /// Render in passes of this many samples per pixel and write a checkpoint
        /// (`OUT.checkpoint.exr`) after each; `--resume` continues from it.
        #[arg(long, value_name = "SAMPLES", value_parser = clap::value_parser!(u32).range(1..))]
        checkpoint: Option<u32>,
        /// Continue from the checkpoint beside the output, if there is one; the result is the
        /// image an uninterrupted run writes.
        #[arg(long)]
        resume: bool,
        /// Render frames FIRST-LAST[xSTEP] (e.g. 1001-1100x2) with one preparation; `-o`
        /// numbers each frame with its run of `#` (`shot.####.exr`).
        #[arg(long, value_name = "FIRST-LAST[xSTEP]", value_parser = cli::farm::Frames::parse)]
        frames: Option<cli::farm::Frames>,
        /// Also send the image to the tev viewer listening at HOST:PORT (its TCP protocol).
        #[arg(long, value_name = "HOST:PORT")]
        display_server: Option<String>,
    },
    /// Merge partial EXRs (`strata render --samples`/`--tile`) into the EXR and PNG one run
    /// writes, bit for bit; refuses parts of other renders, overlapping or missing parts.
    Merge {
        /// The EXR to write (the PNG preview goes beside it).
        #[arg(short, long)]
        output: PathBuf,
        /// The partial EXRs.
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        /// Number the `#` run of the output's and every part's file name with this frame
        /// (as `render --frames` names them).
        #[arg(long, allow_negative_numbers = true)]
        frame: Option<i64>,
    },
    /// Write a shot as farm jobs: one render task per frame x split of the samples (each
    /// checkpointed, resuming when rerun), then one merge per frame.
    Farm {
        #[command(subcommand)]
        scheduler: FarmCommand,
    },
    /// Serve a live, progressive render of a scene in the browser that follows every saved
    /// edit of its layers, substance files and textures, with an inspector of each pixel's
    /// slot stack.
    View {
        /// A USD scene: `.usda`, `.usdc`, `.usd` or `.usdz` (default: the embedded default scene,
        /// which has no files to follow).
        scene: Option<PathBuf>,
        /// The port to listen on (0: any free port).
        #[arg(long, default_value_t = 7878)]
        port: u16,
        /// The address to listen on. Anything but loopback exposes the view to the network.
        #[arg(long, default_value = "127.0.0.1")]
        bind: std::net::IpAddr,
        /// Camera samples per pixel the view converges to (the image `render --spp` writes).
        #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT (default: a UsdRender RenderSettings prim's `resolution`,
        /// else 640x480).
        #[arg(long, value_parser = parse_resolution)]
        res: Option<(usize, usize)>,
        /// The Camera prim to start with (default: as `render`).
        #[arg(long, value_name = "PRIM")]
        camera: Option<String>,
        /// Seed of all sampling (as `render --seed`).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// The time code to read animated attributes at (as `render --time`).
        #[arg(long, value_name = "TIME")]
        time: Option<strata::scene::TimeCode>,
        /// Also send each full-resolution pass to the tev viewer at HOST:PORT.
        #[arg(long, value_name = "HOST:PORT")]
        display_server: Option<String>,
    },
    /// Measure shading and rendering cost: JIT vs interpreter vs hand-written Rust, compile
    /// time vs graph size, render time and error vs layer count.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
    /// Compile every substance of a `.ash` file into a native object (plus a C header beside it).
    Compile {
        /// A `.ash` substance file.
        file: PathBuf,
        /// The object file to write; `OUT.h` is written beside it.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Check a substance file or a scene and report every problem.
    Check {
        /// A `.ash` substance file or a USD scene (`.usda`, `.usdc`, `.usd`, `.usdz`).
        file: PathBuf,
        /// Make every warning an error (exit 1): for farms and CI.
        #[arg(long)]
        strict: bool,
        /// The time code to read animated attributes at: a number or `default` (default: the
        /// stage's startTimeCode when it has time samples, else the default time).
        #[arg(long, value_name = "TIME")]
        time: Option<strata::scene::TimeCode>,
    },
    /// Mutation-fuzz both front ends and the check pipeline; exit 1 if any input crashes,
    /// hangs or passes the memory budget (it is saved under `--crashes`).
    Fuzz {
        /// How long to run, in seconds.
        #[arg(long, default_value_t = 60.0)]
        secs: f64,
        /// Seed of the input sequence (the same seed makes the same inputs).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Worker processes (default: the number of cores).
        #[arg(long)]
        jobs: Option<u64>,
        /// The repository whose scenes/, tests/in/, tests/fixtures/ and fuzz/corpus/ are the corpus.
        #[arg(long, default_value = env!("CARGO_MANIFEST_DIR"))]
        root: PathBuf,
        /// Where failing inputs are written.
        #[arg(long, default_value = "fuzz/crashes")]
        crashes: PathBuf,
        /// Longest one input may run, in seconds.
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
        /// Most resident memory a worker may use, in MiB.
        #[arg(long, default_value_t = 1024)]
        max_rss_mib: u64,
        /// Only read and compose scenes and parse substances (no lowering, JIT or render):
        /// many times more executions per second for the layer and package readers.
        #[arg(long)]
        quick: bool,
        /// Run as a worker of a fuzzing run (internal).
        #[arg(long, hide = true)]
        worker: bool,
        /// The worker's staged corpus (internal).
        #[arg(long, hide = true)]
        stage: Option<PathBuf>,
        /// The worker's first input (internal).
        #[arg(long, hide = true, default_value_t = 0)]
        first: u64,
        /// The worker's input stride (internal).
        #[arg(long, hide = true, default_value_t = 1)]
        stride: u64,
    },
}

#[derive(Subcommand)]
enum FarmCommand {
    /// Write `render.sbatch` (per chunk of frames, an array per split; requeued tasks
    /// resume), `merge.sbatch` (an array per chunk, each frame after its own render tasks)
    /// and `submit.sh` into the job directory.
    Slurm {
        #[command(flatten)]
        job: FarmJobArgs,
        /// Submit with sbatch (each frame's merge with --dependency=aftercorr on its render
        /// tasks) and print a `render ID` or `merge ID` line per array.
        #[arg(long)]
        submit: bool,
        /// The Slurm partition to submit to.
        #[arg(long)]
        partition: Option<String>,
        /// The site's MaxArraySize: frames go in chunks of arrays no larger (default: read
        /// from `scontrol show config` with --submit, else Slurm's default 1001).
        #[arg(long)]
        max_array_size: Option<u64>,
    },
    /// Write an Open Job Description job template (`job.template.json`): a render step over
    /// frames x splits and a merge step over frames.
    Openjd {
        #[command(flatten)]
        job: FarmJobArgs,
    },
}

/// What every farm job says: the shot, its splits, where things go.
#[derive(clap::Args)]
struct FarmJobArgs {
    /// A USD scene (default: the embedded default scene). Tasks name it as written here,
    /// relative to this directory.
    scene: Option<PathBuf>,
    /// The frames, FIRST-LAST[xSTEP].
    #[arg(long, value_name = "FIRST-LAST[xSTEP]", value_parser = cli::farm::Frames::parse)]
    frames: cli::farm::Frames,
    /// Render tasks per frame, each a contiguous range of the samples.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    split_samples: u32,
    /// The merged EXRs, with a `#` run for the frame number.
    #[arg(short, long, value_name = "shot.####.exr")]
    output: PathBuf,
    /// Camera samples per pixel of each frame.
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    spp: u32,
    /// Samples per checkpoint within a task (default: a quarter of a task's samples).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    checkpoint: Option<u32>,
    /// Where the job files, partial files and logs go (default: `OUT_DIR/STEM.farm`).
    #[arg(long)]
    dir: Option<PathBuf>,
    /// Other `strata render` options for every task, after `--` (e.g. `-- --res 1920x1080`).
    #[arg(last = true, allow_hyphen_values = true)]
    render_args: Vec<String>,
}

impl FarmJobArgs {
    /// The job (binary and working directory filled in by the CLI); the render options are
    /// checked as `strata render` would parse them.
    fn job(self) -> Result<strata::session::farm::FarmJob, String> {
        let check =
            ["strata", "render", "-o", "check.exr"].into_iter().map(String::from).chain(self.render_args.clone());
        if let Err(e) = Args::try_parse_from(check) {
            return Err(format!("the render options after `--` do not parse: {}", e.kind()));
        }
        let stem = self.output.file_stem().map_or_else(String::new, |s| s.to_string_lossy().replace('#', ""));
        let dir =
            self.dir.unwrap_or_else(|| self.output.with_file_name(format!("{}.farm", stem.trim_end_matches('.'))));
        let largest_split = self.spp.div_ceil(self.split_samples);
        Ok(strata::session::farm::FarmJob {
            strata: PathBuf::new(),
            workdir: PathBuf::new(),
            scene: self.scene,
            frames: self.frames,
            spp: self.spp,
            splits: self.split_samples,
            checkpoint: self.checkpoint.unwrap_or(largest_split.div_ceil(4)),
            output: self.output,
            dir,
            render_args: self.render_args,
        })
    }
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Per-shading-point cost of a composed material (default: the built-in 3-layer benchmark
    /// material, also hand-written in Rust), and compile time vs graph size.
    Shade {
        /// A `.usda` scene (default: the built-in benchmark material).
        scene: Option<PathBuf>,
        /// The prim whose material to measure (default: the one with the most layers).
        #[arg(long)]
        prim: Option<String>,
    },
    /// Scene file to first pixel and peak memory for 200 to 20 000 analytic spheres, and BVH
    /// build time and memory for a large triangle mesh.
    Scale,
    /// What one displaced object costs (setup, micro-triangles, memory, render time) and what
    /// the dicing rate buys (image error against fine dicing), against the undisplaced scene.
    Displacement {
        /// Samples per pixel of the renders.
        #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT (dicing is measured against its pixels).
        #[arg(long, default_value = "320x240", value_parser = parse_resolution)]
        res: (usize, usize),
    },
    /// Time per sample and error against a high-spp reference for 1 to 16 layers, stochastic
    /// vs weighted evaluation.
    Render {
        /// A `.usda` scene to measure instead of the generated layer scenes.
        scene: Option<PathBuf>,
        /// Samples per pixel of the timed renders.
        #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT.
        #[arg(long, default_value = "64x64", value_parser = parse_resolution)]
        res: (usize, usize),
    },
    /// What a scene pays for features it contains but does not use where the camera looks:
    /// time and shader calls per sample with one extra AOV, displacement, texture or
    /// transparent material on an invisible prim, against the scene without it.
    Features {
        /// Samples per pixel of the timed renders.
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=4096))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT.
        #[arg(long, default_value = "96x64", value_parser = parse_resolution)]
        res: (usize, usize),
    },
    /// What a live edit costs on the default scene: time from a file change (a substance
    /// file, a layer's material input, a layer's geometry) to the session updated, to the
    /// first new samples and to the full image, against opening a fresh session; then an
    /// input set in memory with inputs folded and live (the view's parameter blocks), and
    /// the render time of folded against live inputs.
    Update {
        /// Samples per pixel of each image.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=4096))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT.
        #[arg(long, default_value = "640x480", value_parser = parse_resolution)]
        res: (usize, usize),
        /// Edits of each kind (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
        repeats: u32,
    },
    /// Textures at their source precision: bytes per texel by source kind, setup (header and
    /// decode) time, lookup cost (nearest, trilinear, anisotropic) on one and all cores, and a
    /// render's time and cache hit rate with the texture memory at 100 %, 25 % and 5 % of the
    /// textures' size.
    Textures {
        /// Samples per pixel of the timed renders.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=4096))]
        spp: u32,
        /// Image size, WIDTHxHEIGHT.
        #[arg(long, default_value = "160x120", value_parser = parse_resolution)]
        res: (usize, usize),
    },
    /// The two modes of closures' `layer(top, base)`, albedo scaling and the random walk: the
    /// albedo each renders for a coat over a diffuse base per roughness and angle, their gap,
    /// and the time per sample of each, charted as `layer_modes.svg`.
    Layer {
        /// The directory to write the SVG into (created if missing).
        #[arg(long, value_name = "DIR", default_value = "docs/charts")]
        plot: PathBuf,
        /// Few samples: checks that everything draws, in seconds.
        #[arg(long)]
        quick: bool,
    },
    /// Measure and draw every chart of docs/PERFORMANCE.md's Charts section and docs/STABILITY.md as SVG:
    /// error vs time of stochastic vs weighted layering (1-64 layers; constant, noise and thin
    /// masks), JIT vs interpreter, strata vs Mitsuba 3 (from the committed CSV), per-point
    /// cost, compile time vs graph size, GGX and glass energy. A few minutes on 2 cores.
    Charts {
        /// The directory to write the SVGs into (created if missing).
        #[arg(long, value_name = "DIR")]
        plot: PathBuf,
        /// `tools/compare_mitsuba.py`'s CSV; the Mitsuba chart is skipped if it does not exist.
        #[arg(long, default_value = "docs/mitsuba_compare.csv")]
        mitsuba_csv: PathBuf,
        /// Tiny images and one repetition: checks that everything draws, in seconds.
        #[arg(long)]
        quick: bool,
    },
}

/// Fixes glibc's mmap threshold at 1 MiB: blocks above it are mapped and unmapped on their
/// own. Left dynamic, glibc raises the threshold to the size of each mapped block freed
/// (up to 32 MiB), and the BVH build's large temporary tables then came from the heap and
/// stayed resident as holes after they were freed: a 10⁶-triangle grid's render peaked at
/// 168 B per triangle where the same build took 142 with the threshold fixed.
fn bound_allocator_holes() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets an allocator parameter; called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

fn main() -> ExitCode {
    bound_allocator_holes();
    let args = Args::parse();
    // Interrupted (Ctrl-C, SIGTERM, SIGHUP): delete half-written outputs, then exit as a
    // signal-killed process would. ctrlc runs this on its own thread, not in the handler.
    let _ = ctrlc::set_handler(|| {
        strata::render::film::output::remove_temporary_files();
        std::process::exit(i32::from(cli::EXIT_INTERRUPTED));
    });
    let defaults = strata::input::InputLimits::default();
    strata::input::set_limits(strata::input::InputLimits {
        max_file_bytes: args.max_input_size.unwrap_or(defaults.max_file_bytes),
        max_texture_pixels: args.max_texture_pixels.unwrap_or(defaults.max_texture_pixels),
        max_memory_bytes: args.max_memory,
    });
    strata::runtime::texture::set_memory_budget(args.texture_memory);
    let result = match args.command {
        Command::Layers { scene, json, time } => cli::layers(scene.as_deref(), json, time),
        Command::Ir { scene, prim, no_optimize, stats, lowered } => {
            cli::ir(&scene, &prim, !no_optimize, stats, lowered)
        }
        Command::Render {
            scene,
            output,
            spp,
            res,
            camera,
            subdiv_level,
            dicing_rate,
            half,
            seed,
            threads,
            max_depth,
            rr_depth,
            backend,
            weighted,
            stochastic,
            sampler,
            layering,
            no_optimize,
            stats,
            no_default_lights,
            strict,
            time,
            samples,
            tile,
            checkpoint,
            resume,
            frames,
            display_server,
        } => cli::render(&cli::RenderArgs {
            scene,
            output,
            settings: RenderSettings {
                width: res.map_or(640, |r| r.0),
                height: res.map_or(480, |r| r.1),
                spp,
                seed,
                threads: threads.map(|t| t as usize),
                max_depth,
                rr_depth,
                mode: match (weighted, stochastic) {
                    (true, _) => LayerMode::Weighted,
                    (_, true) => LayerMode::Stochastic,
                    _ => LayerMode::Auto,
                },
                sampler,
                layering,
            },
            backend,
            optimize: !no_optimize,
            stats,
            half,
            camera,
            subdiv_level,
            dicing_rate,
            resolution_given: res.is_some(),
            default_lights: if no_default_lights {
                strata::render::scene::DefaultLights::Never
            } else {
                strata::render::scene::DefaultLights::WhenUnlit
            },
            strict,
            time,
            samples,
            tile,
            checkpoint,
            resume,
            frames,
            display_server,
        }),
        Command::Merge { output, parts, frame } => cli::farm::merge(&output, &parts, frame),
        Command::Farm { scheduler } => {
            let (job, slurm) = match scheduler {
                FarmCommand::Slurm { job, submit, partition, max_array_size } => {
                    let options = strata::session::farm::slurm::SlurmOptions { partition, max_array_size };
                    (job, Some((options, submit)))
                }
                FarmCommand::Openjd { job } => (job, None),
            };
            match (job.job(), slurm) {
                (Err(e), _) => {
                    eprintln!("error: {e}");
                    Err(cli::Failure)
                }
                (Ok(job), Some((options, submit))) => cli::farm::farm_slurm(job, &options, submit),
                (Ok(job), None) => cli::farm::farm_openjd(job),
            }
        }
        Command::View { scene, port, bind, spp, res, camera, seed, time, display_server } => {
            cli::view(strata::view::ViewOptions {
                scene: strata::session::SceneSource::from_path(scene.as_deref()),
                session: strata::session::SessionOptions { time, ..Default::default() },
                settings: RenderSettings {
                    width: res.map_or(640, |r| r.0),
                    height: res.map_or(480, |r| r.1),
                    spp,
                    seed,
                    ..RenderSettings::default()
                },
                resolution_given: res.is_some(),
                scene_options: strata::render::scene::SceneOptions { camera, ..Default::default() },
                bind,
                port,
                display_server,
            })
        }
        Command::Compile { file, output } => cli::compile(&file, &output),
        Command::Bench { what } => {
            let report = match what {
                BenchCommand::Shade { scene, prim } => cli::bench::bench_shade(scene.as_deref(), prim.as_deref()),
                BenchCommand::Render { scene, spp, res } => cli::bench::bench_render(scene.as_deref(), spp, res),
                BenchCommand::Scale => cli::bench::bench_scale(),
                BenchCommand::Displacement { spp, res } => cli::bench::bench_displacement(res, spp),
                BenchCommand::Features { spp, res } => cli::bench::bench_features(res, spp, 7),
                BenchCommand::Update { spp, res, repeats } => cli::bench::bench_update(res, spp, repeats as usize),
                BenchCommand::Textures { spp, res } => cli::bench::bench_textures(res, spp),
                BenchCommand::Layer { plot, quick } => cli::bench::bench_layer(&plot, quick),
                BenchCommand::Charts { plot, mitsuba_csv, quick } => {
                    let options =
                        if quick { cli::bench::ChartOptions::quick() } else { cli::bench::ChartOptions::default() };
                    cli::bench::bench_charts(&plot, Some(&mitsuba_csv), &options)
                }
            };
            match report {
                Ok(text) => {
                    print!("{text}");
                    Ok(())
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    Err(cli::Failure)
                }
            }
        }
        Command::Check { file, time, strict } => cli::check(&file, time, strict),
        Command::Fuzz {
            secs,
            seed,
            jobs,
            root,
            crashes,
            timeout,
            max_rss_mib,
            quick,
            worker,
            stage,
            first,
            stride,
        } => {
            if worker {
                let stage = stage.unwrap_or_else(std::env::temp_dir);
                return match cli::fuzz::worker(&root, &stage, seed, first, stride, quick) {
                    Ok(()) => ExitCode::SUCCESS,
                    Err(e) => {
                        eprintln!("fuzz worker: {e}");
                        ExitCode::FAILURE
                    }
                };
            }
            let jobs = jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get() as u64));
            let options = cli::fuzz::FuzzOptions {
                root,
                duration: std::time::Duration::from_secs_f64(secs.max(0.0)),
                seed,
                jobs,
                input_timeout: std::time::Duration::from_secs_f64(timeout.max(0.1)),
                max_rss: max_rss_mib.saturating_mul(1 << 20),
                crashes,
                quick,
            };
            cli::fuzz(&options)
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(cli::Failure) => ExitCode::from(cli::exit_code()),
    }
}

/// Parses `A..B`, a half-open range of sample indices.
fn parse_sample_range(text: &str) -> Result<std::ops::Range<u32>, String> {
    let (a, b) = text.split_once("..").ok_or("expected A..B, e.g. 0..32")?;
    let parse = |s: &str| s.trim().parse::<u32>().map_err(|_| format!("`{s}` is not a sample index"));
    let (a, b) = (parse(a)?, parse(b)?);
    if a < b { Ok(a..b) } else { Err(format!("the range {a}..{b} is empty")) }
}

/// Parses `X,Y,W,H` (a region of pixels; width and height at least 1).
fn parse_tile(text: &str) -> Result<strata::render::Region, String> {
    let numbers: Vec<usize> = text
        .split(',')
        .map(|s| s.trim().parse::<usize>().map_err(|_| format!("`{s}` is not a whole number")))
        .collect::<Result<_, _>>()?;
    match numbers[..] {
        [x, y, width, height] if width > 0 && height > 0 => Ok(strata::render::Region { x, y, width, height }),
        [_, _, _, _] => Err("the tile is empty".into()),
        _ => Err("expected X,Y,W,H, e.g. 0,0,320,240".into()),
    }
}

/// Parses `WIDTHxHEIGHT` (each 1 to 16384).
fn parse_layering(text: &str) -> Result<LayeringMode, String> {
    LayeringMode::from_name(text)
        .ok_or_else(|| format!("`{text}` is not a layering mode (albedo-scaling, random-walk)"))
}

fn parse_sampler(text: &str) -> Result<SamplerKind, String> {
    SamplerKind::from_name(text).ok_or_else(|| format!("`{text}` is not a sampler (sobol, independent)"))
}

fn parse_dicing_rate(text: &str) -> Result<f32, String> {
    match text.trim().parse::<f32>() {
        Ok(rate) if rate.is_finite() && (0.05..=1e4).contains(&rate) => Ok(rate),
        Ok(_) => Err("the dicing rate must be between 0.05 and 10000 pixels".into()),
        Err(_) => Err(format!("`{text}` is not a number")),
    }
}

fn parse_resolution(text: &str) -> Result<(usize, usize), String> {
    let (w, h) = text.split_once(['x', 'X']).ok_or("expected WIDTHxHEIGHT, e.g. 640x480")?;
    let parse = |s: &str| -> Result<usize, String> {
        let n: usize = s.trim().parse().map_err(|_| format!("`{s}` is not a whole number"))?;
        if (1..=16384).contains(&n) { Ok(n) } else { Err(format!("{n} is outside 1..=16384")) }
    };
    Ok((parse(w)?, parse(h)?))
}

/// Parses a count with an optional binary suffix: `1000`, `64K`, `512M`, `2G`.
fn parse_size(text: &str) -> Result<u64, String> {
    let text = text.trim();
    let (digits, shift) = match text.char_indices().last() {
        Some((i, 'k' | 'K')) => (&text[..i], 10),
        Some((i, 'm' | 'M')) => (&text[..i], 20),
        Some((i, 'g' | 'G')) => (&text[..i], 30),
        _ => (text, 0),
    };
    let n: u64 = digits.parse().map_err(|_| format!("`{text}` is not a size (e.g. 1000, 64K, 512M, 2G)"))?;
    n.checked_mul(1 << shift).ok_or_else(|| format!("`{text}` is too large"))
}
