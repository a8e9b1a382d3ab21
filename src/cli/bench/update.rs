//! `strata bench update`: what a live edit costs. The default scene (its dirt substance in a
//! file of its own) is prepared once in a [`Session`]; then, for each kind of change, a file
//! is edited and timed from the edit to the session updated, to the first row of new samples
//! and to the full image — against opening a fresh session for the same edit. Then an input
//! value set in memory (the live view's slider), with inputs folded (recompiling the
//! material) and live (`PassOptions::live_inputs`: a parameter block rewritten).

use std::path::Path;
use std::sync::OnceLock;
use std::time::Instant;
use strata::render::RenderSettings;
use strata::render::geometry::displace::DicingOptions;
use strata::render::scene::SceneOptions;
use strata::session::{Change, Pass, SceneSource, Session, SessionOptions};

/// One edit the benchmark makes, and the text it toggles.
struct Edit {
    label: &'static str,
    file: &'static str,
    from: &'static str,
    to: &'static str,
}

const EDITS: [Edit; 3] = [
    Edit { label: "substance file (dirt.ash colour)", file: "dirt.ash", from: "0.2, 0.15, 0.1", to: "0.1, 0.3, 0.6" },
    Edit {
        label: "USD layer, material input (floor tiles)",
        file: "default.usda",
        from: "float inputs:tiles = 6",
        to: "float inputs:tiles = 3",
    },
    Edit {
        label: "USD layer, geometry (a ball moved)",
        file: "default.usda",
        from: "(1.8, 0.8, 0)",
        to: "(1.5, 0.8, 0.3)",
    },
];

/// Times of one edit, ms.
struct Timing {
    update: f64,
    first_sample: f64,
    full_image: f64,
}

/// Runs `repeats` edits of each kind at `res` and `spp`; returns the report.
pub fn bench_update(res: (usize, usize), spp: u32, repeats: usize) -> Result<String, String> {
    let dir = std::env::temp_dir().join(format!("strata-bench-update-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let result = run(&dir, res, spp, repeats.max(1));
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn run(dir: &Path, res: (usize, usize), spp: u32, repeats: usize) -> Result<String, String> {
    let scene = strata::session::write_split_default_scene(dir).map_err(|e| e.to_string())?;
    let settings = RenderSettings { width: res.0, height: res.1, spp, ..RenderSettings::default() };
    let options = SceneOptions {
        dicing: DicingOptions { resolution: res, ..DicingOptions::default() },
        ..SceneOptions::default()
    };
    let pass = Pass::full(settings);
    let open_with = |live_inputs: bool| -> Result<Session, String> {
        let passes = strata::ir::wired::PassOptions { live_inputs, ..Default::default() };
        let mut session =
            Session::open(SceneSource::File(scene.clone()), SessionOptions { passes, ..Default::default() });
        if session.prepare(&options).is_none() {
            return Err(session.diagnostics().render(session.sources()));
        }
        Ok(session)
    };
    let open = || open_with(false);
    let threads = rayon::current_num_threads();
    let mut out = format!(
        "strata bench update: the default scene at {}x{}, {spp} spp, {threads} thread(s), {repeats} edit(s) per kind \
         (median ms; first sample = the first row of new samples done)\n\n",
        res.0, res.1
    );
    out += &format!(
        "{:<42} {:>9} {:>11} {:>10} {:>10} {:>14}\n",
        "change", "update", "1st sample", "full image", "recompiled", "fresh session"
    );
    let mut session = open()?;
    for edit in &EDITS {
        let path = dir.join(edit.file);
        let mut timings = Vec::new();
        let mut fresh = Vec::new();
        let mut recompiled = 0;
        for k in 0..repeats * 2 {
            let (from, to) = if k % 2 == 0 { (edit.from, edit.to) } else { (edit.to, edit.from) };
            let text = std::fs::read_to_string(&path).map_err(|e| e.to_string())?;
            if !text.contains(from) {
                return Err(format!("{} does not contain `{from}`", path.display()));
            }
            std::fs::write(&path, text.replacen(from, to, 1)).map_err(|e| e.to_string())?;
            let (timing, report) = timed(&mut session, &Change::File(path.clone()), &pass)?;
            recompiled = report;
            timings.push(timing);
            // The same edit from nothing: open, compose, compile, build, render.
            if k < 2 {
                let start = Instant::now();
                let mut cold = open()?;
                cold.render(&pass, None).map_err(|e| e.to_string())?;
                fresh.push(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        fresh.sort_by(f64::total_cmp);
        out += &row(edit.label, &timings, recompiled, &format!("{:.1}", fresh[fresh.len() / 2]));
    }
    for (label, live) in [("input in memory, folded (dirt coverage)", false), ("input in memory, live inputs", true)] {
        let mut session = open_with(live)?;
        let mut timings = Vec::new();
        let mut recompiled = 0;
        for k in 0..repeats * 2 {
            let change = Change::Value {
                prim: "/Looks/Dirt/Surface".into(),
                attribute: "inputs:coverage".into(),
                type_name: "float".into(),
                value: strata::scene::Value::Float(if k % 2 == 0 { 0.3 } else { 0.55 }),
            };
            let (timing, report) = timed(&mut session, &change, &pass)?;
            recompiled = report;
            timings.push(timing);
        }
        out += &row(label, &timings, recompiled, "-");
    }
    out += "\nlive inputs: what `strata view` compiles (float and colour inputs read from a parameter block)\n";
    // What reading inputs from the block costs the render: the same image both ways.
    let (mut folded, mut live) = (open_with(false)?, open_with(true)?);
    let (mut folded_ms, mut live_ms) = (Vec::new(), Vec::new());
    for _ in 0..repeats {
        let start = Instant::now();
        let a = render_folded(&mut folded, &pass)?;
        folded_ms.push(start.elapsed().as_secs_f64() * 1e3);
        let start = Instant::now();
        let b = render_live(&mut live, &pass)?;
        live_ms.push(start.elapsed().as_secs_f64() * 1e3);
        if a != b {
            return Err("live inputs render another image than folded ones".into());
        }
    }
    folded_ms.sort_by(f64::total_cmp);
    live_ms.sort_by(f64::total_cmp);
    let (f, l) = (folded_ms[folded_ms.len() / 2], live_ms[live_ms.len() / 2]);
    out += &format!(
        "render with inputs folded {f:.1} ms, live {l:.1} ms: {:.3}x (median of {repeats}, alternating; the same image)\n",
        l / f
    );
    out += "\ntarget: first sample within 100 ms of the edit on 2 cores (issue 21)\n";
    Ok(out)
}

/// Applies `change` and renders `pass`: the timings from the change, and how many
/// compositions the update compiled.
fn timed(session: &mut Session, change: &Change, pass: &Pass) -> Result<(Timing, usize), String> {
    let start = Instant::now();
    let report = session.apply_change(change);
    if report.failed {
        return Err(session.diagnostics().render(session.sources()));
    }
    let update = start.elapsed().as_secs_f64() * 1e3;
    let first = OnceLock::new();
    let progress = |_: usize, _: usize| {
        first.get_or_init(Instant::now);
    };
    session.render(pass, Some(&progress)).map_err(|e| e.to_string())?;
    let full_image = start.elapsed().as_secs_f64() * 1e3;
    let first_sample = first.get().map_or(full_image, |t| t.duration_since(start).as_secs_f64() * 1e3);
    Ok((Timing { update, first_sample, full_image }, report.recompiled))
}

/// One row of the table: the medians of `timings`.
fn row(label: &str, timings: &[Timing], recompiled: usize, fresh: &str) -> String {
    let median = |pick: fn(&Timing) -> f64| {
        let mut v: Vec<f64> = timings.iter().map(pick).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    format!(
        "{:<42} {:>9.1} {:>11.1} {:>10.1} {:>10} {:>14}\n",
        label,
        median(|t| t.update),
        median(|t| t.first_sample),
        median(|t| t.full_image),
        recompiled,
        fresh
    )
}

/// The pass rendered by a session with folded inputs (a function of its own, so a profiler
/// — `valgrind --tool=callgrind`, inclusive cost — tells it from [`render_live`]).
#[inline(never)]
fn render_folded(session: &mut Session, pass: &Pass) -> Result<strata::render::Image, String> {
    session.render(pass, None).map(|(image, _)| image).map_err(|e| e.to_string())
}

/// The pass rendered by a session with live inputs; see [`render_folded`].
#[inline(never)]
fn render_live(session: &mut Session, pass: &Pass) -> Result<strata::render::Image, String> {
    session.render(pass, None).map(|(image, _)| image).map_err(|e| e.to_string())
}
