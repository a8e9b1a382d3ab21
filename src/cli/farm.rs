//! What `strata render` and `strata merge` do for a render farm: frame ranges, output names
//! per frame, renders in checkpointed passes, and merging partial files. The partial-file
//! format and the merge are the library's (`render::film::partial`); this parses and prints.

use super::{Failure, resource_failure};
use std::ops::Range;
use std::path::{Path, PathBuf};
use strata::render::film::partial::{self, Partial, Split};
use strata::render::film::{Image, RenderStats, SumsLayout, WindowSums, image_from_layout};
use strata::render::{ExrOptions, RenderSettings, Window};
use strata::session::{Pass, Session};

/// A frame range: `FIRST-LAST[xSTEP]` (`1001-1100`, `1-99x2`), or one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frames {
    /// The first frame.
    pub first: i64,
    /// The last frame (inclusive; rendered when the step lands on it).
    pub last: i64,
    /// Frames between renders.
    pub step: i64,
}

impl Frames {
    /// Parses `FIRST-LAST[xSTEP]` or `FRAME`. Negative frames are written with a leading
    /// minus (`-10--1`).
    pub fn parse(text: &str) -> Result<Frames, String> {
        let text = text.trim();
        let (range, step) = match text.split_once(['x', 'X']) {
            Some((range, step)) => {
                (range, step.trim().parse::<i64>().map_err(|_| format!("`{step}` is not a whole step"))?)
            }
            None => (text, 1),
        };
        // The separating minus is the first one after the first character.
        let split = range.char_indices().skip(1).find(|&(_, c)| c == '-').map(|(i, _)| i);
        let number = |s: &str| s.trim().parse::<i64>().map_err(|_| format!("`{s}` is not a frame number"));
        let (first, last) = match split {
            Some(i) => (number(&range[..i])?, number(&range[i + 1..])?),
            None => (number(range)?, number(range)?),
        };
        if step < 1 {
            return Err(format!("the step must be at least 1, not {step}"));
        }
        if last < first {
            return Err(format!("the range {first}-{last} runs backwards"));
        }
        if (last - first) / step >= 1_000_000 {
            return Err("more than a million frames".into());
        }
        Ok(Frames { first, last, step })
    }

    /// The frames, in order.
    pub fn list(&self) -> Vec<i64> {
        (self.first..=self.last).step_by(self.step as usize).collect()
    }
}

/// `template` with its run of `#` replaced by `frame`, zero-padded to the run's length
/// (`shot.####.exr`, 1001 → `shot.1001.exr`). `None` when the file name has no `#` run.
pub fn frame_path(template: &Path, frame: i64) -> Option<PathBuf> {
    let name = template.file_name()?.to_str()?;
    let start = name.find('#')?;
    let run = name[start..].chars().take_while(|&c| c == '#').count();
    let number = if frame < 0 { format!("-{:0run$}", -frame) } else { format!("{frame:0run$}") };
    Some(template.with_file_name(format!("{}{number}{}", &name[..start], &name[start + run..])))
}

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
/// (and PNG) one run of their render writes.
pub fn merge(output: &Path, parts: &[PathBuf]) -> Result<(), Failure> {
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
