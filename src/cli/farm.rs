//! What `strata render`, `strata merge` and `strata farm` do for a render farm: renders in
//! checkpointed passes, merging partial files, and writing (and submitting) farm jobs. The
//! frame numbering and the job files are the library's (`session::farm`), the partial-file
//! format and the merge too (`render::film::partial`); this writes files and prints.

use super::{Failure, resource_failure};
use std::ops::Range;
use std::path::{Path, PathBuf};
use strata::render::film::partial::{self, Partial, Split};
use strata::render::film::{Image, RenderStats, SumsLayout, WindowSums, image_from_layout};
use strata::render::{ExrOptions, RenderSettings, Window};
use strata::session::{Pass, Session};

pub use strata::session::farm::{Frames, frame_path};

/// Where the checkpoint of the render writing `output` goes: `OUT.checkpoint.exr` beside it.
pub fn checkpoint_path(output: &Path) -> PathBuf {
    output.with_extension("checkpoint.exr")
}

/// A render split into passes of sample ranges, each finished pass written as a checkpoint.
pub struct Passes<'a> {
    /// The image's settings.
    pub settings: &'a RenderSettings,
    /// The region and sample range of the whole render (the split, or the image).
    pub window: Window,
    /// Samples per pixel of each pass; each pass ends with a checkpoint (`None`: one pass,
    /// no checkpoint).
    pub every: Option<u32>,
    /// Continue from the checkpoint when there is one.
    pub resume: bool,
    /// The checkpoint file.
    pub checkpoint: PathBuf,
    /// The split's description (for the checkpoint's header and checks).
    pub split: Split,
    /// The image's layout besides its sums.
    pub layout: &'a SumsLayout,
    /// The single run's header.
    pub options: &'a ExrOptions,
}

/// Renders `passes` (resuming from its checkpoint if asked and present) and returns the
/// image of all its samples, its stats and sums. `progress(done, total)` counts rows over
/// all passes.
pub fn render_passes(
    session: &mut Session,
    passes: &Passes,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Image, RenderStats, WindowSums), Failure> {
    let range = passes.split.samples.clone();
    let mut merged: Option<WindowSums> = None;
    if passes.resume && passes.checkpoint.exists() {
        let part = partial::read_partial(&passes.checkpoint).map_err(|e| {
            eprintln!("error: cannot resume: {e}");
            Failure
        })?;
        check_resumable(&part, &passes.split)?;
        eprintln!(
            "resuming from `{}`: samples {}..{} of {}..{} done",
            passes.checkpoint.display(),
            part.split.samples.start,
            part.split.samples.end,
            range.start,
            range.end
        );
        merged = Some(part.sums);
    } else if passes.resume {
        eprintln!("no checkpoint `{}`: starting from the first sample", passes.checkpoint.display());
    }
    let mut next = merged.as_ref().and_then(|m| m.samples.last()).map_or(range.start, |r| r.end);
    let step = passes.every.unwrap_or(range.len() as u32).max(1);
    let rows = passes.window.region.map_or(passes.settings.height, |r| r.height);
    let total_passes = (range.end - next).div_ceil(step) as usize;
    let mut stats = RenderStats::default();
    for pass_index in 0..total_passes {
        let samples = next..(next + step).min(range.end);
        let pass = Pass {
            settings: passes.settings.clone(),
            time: None,
            window: Window { region: passes.window.region, samples: Some(samples.clone()) },
        };
        let pass_progress = |done: usize, _: usize| progress(pass_index * rows + done, total_passes * rows);
        let (_, pass_stats, sums) = session.render_sums(&pass, Some(&pass_progress)).map_err(|e| {
            eprintln!("error: {e}");
            Failure
        })?;
        add_stats(&mut stats, pass_stats);
        match &mut merged {
            Some(m) => m.merge(&sums).map_err(|e| {
                eprintln!("error: {e}");
                Failure
            })?,
            None => merged = Some(sums),
        }
        next = samples.end;
        let Some(sums) = merged.as_ref() else { return Err(Failure) };
        if passes.every.is_some() && next < range.end {
            write_checkpoint(passes, sums, range.start..next)?;
        }
    }
    let sums = merged.ok_or(Failure)?;
    let image = image_from_layout(passes.layout, &sums);
    Ok((image, stats, sums))
}

/// Refuses a checkpoint of another render or another split.
fn check_resumable(part: &Partial, split: &Split) -> Result<(), Failure> {
    let s = &part.split;
    let problem = if s.fingerprint != split.fingerprint {
        Some("it was rendered from another scene or other settings".to_string())
    } else if s.region != split.region || s.samples.start != split.samples.start || s.samples.end > split.samples.end {
        Some(format!(
            "it holds samples {}..{} of another split than samples {}..{}",
            s.samples.start, s.samples.end, split.samples.start, split.samples.end
        ))
    } else {
        None
    };
    match problem {
        Some(problem) => {
            eprintln!("error: cannot resume from `{}`: {problem}; delete it to start again", part.path.display());
            Err(Failure)
        }
        None => Ok(()),
    }
}

/// Writes the checkpoint of `samples` (atomically: a checkpoint is whole or the previous one).
fn write_checkpoint(passes: &Passes, sums: &WindowSums, samples: Range<u32>) -> Result<(), Failure> {
    let split = Split { samples, ..passes.split.clone() };
    let image = image_from_layout(passes.layout, sums);
    partial::write_partial(&passes.checkpoint, &image, sums, passes.layout, &split, passes.options).map_err(|e| {
        eprintln!("error: checkpoint: {e}");
        resource_failure()
    })
}

fn add_stats(total: &mut RenderStats, pass: RenderStats) {
    total.add_counts(&pass);
    for fault in pass.first_faults {
        if !total.first_faults.iter().any(|f| f.kind == fault.kind) {
            total.first_faults.push(fault);
        }
    }
    total.warnings = pass.warnings;
    total.layer_modes = pass.layer_modes;
}

/// `strata merge -o OUT.exr PART…`: checks the parts belong together and writes the EXR
/// (and PNG) one run of their render writes. With `frame`, the `#` run of every name is
/// that frame's number (`shot.####.exr`), as `render --frames` names its outputs.
pub fn merge(output: &Path, parts: &[PathBuf], frame: Option<i64>) -> Result<(), Failure> {
    if let Some(frame) = frame {
        let numbered = |p: &Path| {
            frame_path(p, frame).ok_or_else(|| {
                eprintln!("error: with --frame, `{}` needs a `#` run for the frame number", p.display());
                Failure
            })
        };
        let parts = parts.iter().map(|p| numbered(p)).collect::<Result<Vec<_>, _>>()?;
        return merge(&numbered(output)?, &parts, None);
    }
    if !output.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
        eprintln!("error: the output must be an .exr file, not `{}`", output.display());
        return Err(Failure);
    }
    let same_file = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if let Some(part) = parts.iter().find(|p| same_file(p, output) || same_file(p, &output.with_extension("png"))) {
        eprintln!("error: `{}` is a part to merge; refusing to overwrite it", part.display());
        return Err(Failure);
    }
    let outputs = strata::render::prepare_outputs(output).map_err(|e| {
        eprintln!("error: {e}");
        resource_failure()
    })?;
    let start = std::time::Instant::now();
    let read: Vec<Partial> = parts.iter().map(|p| partial::read_partial(p)).collect::<Result<_, _>>().map_err(|e| {
        eprintln!("error: {e}");
        Failure
    })?;
    let merged = partial::merge(&read).map_err(|e| {
        eprintln!("error: {e}");
        Failure
    })?;
    let png = outputs.write_with(&merged.image, &merged.options).map_err(|e| {
        eprintln!("error: {e}");
        resource_failure()
    })?;
    let s = &read[0].split;
    eprintln!(
        "merged {} part(s) into {}x{} at {} spp in {:.2} s: {} and {}",
        read.len(),
        s.width,
        s.height,
        s.spp,
        start.elapsed().as_secs_f64(),
        output.display(),
        png.display()
    );
    Ok(())
}

/// The job with this binary and the working directory filled in.
fn complete(mut job: strata::session::farm::FarmJob) -> Result<strata::session::farm::FarmJob, Failure> {
    let fail = |what: &str, e: std::io::Error| {
        eprintln!("error: {what}: {e}");
        resource_failure()
    };
    job.strata = std::env::current_exe().and_then(|p| p.canonicalize()).map_err(|e| fail("the strata binary", e))?;
    job.workdir = std::env::current_dir().map_err(|e| fail("the working directory", e))?;
    job.validate().map_err(|e| {
        eprintln!("error: {e}");
        Failure
    })?;
    Ok(job)
}

/// Writes `text` to `dir/name` whole or not at all (temp + rename), executable when `exec`.
fn write_job_file(dir: &Path, name: &str, text: &str, exec: bool) -> Result<PathBuf, Failure> {
    let path = dir.join(name);
    let temp = dir.join(format!(".{name}.tmp"));
    let written = std::fs::write(&temp, text).and_then(|()| {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&temp, std::fs::Permissions::from_mode(if exec { 0o755 } else { 0o644 }))?;
        std::fs::rename(&temp, &path)
    });
    written.map_err(|e| {
        let _ = std::fs::remove_file(&temp);
        eprintln!("error: cannot write `{}`: {e}", path.display());
        resource_failure()
    })?;
    Ok(path)
}

/// Creates the job directory with its `logs` and `parts`, and the outputs' directory.
fn job_dirs(job: &strata::session::farm::FarmJob) -> Result<(), Failure> {
    let output_dir = job.output.parent().unwrap_or(Path::new(""));
    for dir in [job.dir.join("logs"), job.dir.join("parts"), output_dir.to_path_buf()] {
        let dir = job.workdir.join(dir);
        std::fs::create_dir_all(&dir).map_err(|e| {
            eprintln!("error: cannot create `{}`: {e}", dir.display());
            resource_failure()
        })?;
    }
    Ok(())
}

/// `strata farm slurm`: writes `render.sbatch`, `merge.sbatch` and `submit.sh` into the job
/// directory; with `submit`, makes the submissions itself (the site's array limit read from
/// `scontrol show config` unless `--max-array-size` gave it) and prints `render ID` / `merge ID`
/// lines, as `submit.sh` does.
pub fn farm_slurm(
    job: strata::session::farm::FarmJob,
    options: &strata::session::farm::slurm::SlurmOptions,
    submit: bool,
) -> Result<(), Failure> {
    use strata::session::farm::slurm::{
        MERGE_SCRIPT, RENDER_SCRIPT, SUBMIT_SCRIPT, Script, array_limit_from_config, array_option, slurm_job,
    };
    let job = complete(job)?;
    let mut options = options.clone();
    if submit && options.max_array_size.is_none() {
        options.max_array_size = site_config().as_deref().and_then(array_limit_from_config);
    }
    let scripts = slurm_job(&job, &options).map_err(|e| {
        eprintln!("error: {e}");
        Failure
    })?;
    job_dirs(&job)?;
    let dir = job.workdir.join(&job.dir);
    let render = write_job_file(&dir, RENDER_SCRIPT, &scripts.render, true)?;
    let merge = write_job_file(&dir, MERGE_SCRIPT, &scripts.merge, true)?;
    let submit_script = write_job_file(&dir, SUBMIT_SCRIPT, &scripts.submit, true)?;
    for warning in &scripts.warnings {
        eprintln!("warning: {warning}");
    }
    eprintln!("{}", job.summary());
    if !submit {
        println!("{}", submit_script.display());
        eprintln!(
            "wrote {}, {} and {}; run the last to submit",
            render.display(),
            merge.display(),
            submit_script.display()
        );
        return Ok(());
    }
    let mut ids: Vec<String> = Vec::with_capacity(scripts.submissions.len());
    for s in &scripts.submissions {
        let mut args = vec![array_option(s.tasks)];
        if !s.after.is_empty() {
            let after: String = s.after.iter().map(|&a| format!(":{}", ids[a])).collect();
            args.push(format!("--dependency=aftercorr{after}"));
        }
        let (name, script) = match s.script {
            Script::Render => ("render", &render),
            Script::Merge => ("merge", &merge),
        };
        args.push(script.display().to_string());
        args.extend(s.args.iter().map(u64::to_string));
        let id = sbatch(&args.iter().map(std::ffi::OsStr::new).collect::<Vec<_>>())?;
        println!("{name} {id}");
        ids.push(id);
    }
    eprintln!("submitted {} arrays (each frame's merge after its own render tasks)", ids.len());
    Ok(())
}

/// `scontrol show config`'s text, `None` (with a note) when it cannot be read.
fn site_config() -> Option<String> {
    match std::process::Command::new("scontrol").args(["show", "config"]).output() {
        Ok(out) if out.status.success() => Some(String::from_utf8_lossy(&out.stdout).into_owned()),
        _ => {
            eprintln!("note: `scontrol show config` failed; assuming Slurm's default MaxArraySize (1001)");
            None
        }
    }
}

/// Runs `sbatch --parsable ARGS…` and returns the job ID it prints (`ID` or `ID;CLUSTER`).
fn sbatch(args: &[&std::ffi::OsStr]) -> Result<String, Failure> {
    let out = std::process::Command::new("sbatch").arg("--parsable").args(args).output().map_err(|e| {
        eprintln!("error: cannot run sbatch: {e}");
        resource_failure()
    })?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let id = stdout.trim().split(';').next().unwrap_or("").to_string();
    if !out.status.success() || id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        eprintln!(
            "error: sbatch failed ({}): {}{}",
            out.status,
            stdout.trim(),
            String::from_utf8_lossy(&out.stderr).trim()
        );
        return Err(resource_failure());
    }
    Ok(id)
}

/// `strata farm openjd`: writes the job template into the job directory and prints its path.
pub fn farm_openjd(job: strata::session::farm::FarmJob) -> Result<(), Failure> {
    use strata::session::farm::openjd::{TEMPLATE, openjd_template};
    let job = complete(job)?;
    let template = openjd_template(&job).map_err(|e| {
        eprintln!("error: {e}");
        Failure
    })?;
    job_dirs(&job)?;
    let path = write_job_file(&job.workdir.join(&job.dir), TEMPLATE, &template, false)?;
    eprintln!("{}", job.summary());
    println!("{}", path.display());
    eprintln!("wrote {}; `openjd run {}` runs it here", path.display(), path.display());
    Ok(())
}
