//! A shot as farm work: which frames, how each frame's samples are split into tasks, the
//! command each task runs and the merge that follows. [`slurm`] writes it as `sbatch` array
//! jobs, [`openjd`] as an Open Job Description template; the CLI writes the files and
//! submits. Every task runs `strata render --frames F --samples A..B --checkpoint N --resume`
//! into a partial file, so a requeued task resumes from its checkpoint and the merge
//! (`strata merge --frame F`) writes the EXR one process writes, bit for bit.

pub mod openjd;
pub mod slurm;

use std::path::{Path, PathBuf};

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

    /// How many frames the range renders.
    pub fn count(&self) -> u64 {
        ((self.last - self.first) / self.step) as u64 + 1
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

/// A shot split into farm tasks: one per frame × split of the samples.
#[derive(Clone, Debug)]
pub struct FarmJob {
    /// The `strata` binary the tasks run (absolute: tasks start elsewhere).
    pub strata: PathBuf,
    /// The directory tasks run in; relative paths below are relative to it.
    pub workdir: PathBuf,
    /// The scene, as the tasks name it (`None`: the embedded default scene). The name is
    /// part of the render's fingerprint, so a single run must name it the same way to
    /// compare.
    pub scene: Option<PathBuf>,
    /// The frames.
    pub frames: Frames,
    /// Samples per pixel of the whole image.
    pub spp: u32,
    /// Tasks per frame, each a contiguous range of the samples.
    pub splits: u32,
    /// Samples per checkpoint pass within a task.
    pub checkpoint: u32,
    /// The merged outputs, with a `#` run for the frame (`shot.####.exr`).
    pub output: PathBuf,
    /// Where the job files, the partial files and the logs go.
    pub dir: PathBuf,
    /// Other `strata render` arguments every task passes (`--res`, `--seed`, …).
    pub render_args: Vec<String>,
}

/// One task: a frame and a range of its samples.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Task {
    /// The frame.
    pub frame: i64,
    /// Which split of the frame's samples (`0..splits`).
    pub split: u32,
    /// The samples it renders.
    pub samples: std::ops::Range<u32>,
}

/// A value a task's command takes from its task index (the Slurm array index, the OpenJD
/// task parameters).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Var {
    /// The task's frame.
    Frame,
    /// The task's split index.
    Split,
    /// The task's sample range, `A..B`.
    Samples,
}

/// A piece of one command-line word: fixed text or a task's value.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Piece {
    /// Text, as it is.
    Text(String),
    /// A value of the task.
    Var(Var),
}

/// One command-line word, made of pieces.
pub type Word = Vec<Piece>;

fn text(s: impl Into<String>) -> Word {
    vec![Piece::Text(s.into())]
}

impl FarmJob {
    /// Refuses jobs that cannot run: no `#` run in the output, an output that is not `.exr`,
    /// more splits than samples, arguments the job sets itself, text a job file cannot hold.
    pub fn validate(&self) -> Result<(), String> {
        if !self.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
            return Err(format!("the output must be an .exr file, not `{}`", self.output.display()));
        }
        if frame_path(&self.output, 0).is_none() {
            return Err(format!(
                "the output `{}` needs a `#` run for the frame number, e.g. `shot.####.exr`",
                self.output.display()
            ));
        }
        if self.splits == 0 || self.splits > self.spp {
            return Err(format!(
                "--split-samples must be 1 to the {} samples per pixel, not {}",
                self.spp, self.splits
            ));
        }
        if self.checkpoint == 0 {
            return Err("--checkpoint must be at least 1 sample".into());
        }
        let owned =
            ["-o", "--output", "--spp", "--samples", "--frames", "--time", "--tile", "--checkpoint", "--resume"];
        if let Some(arg) = self.render_args.iter().find(|a| owned.contains(&a.split('=').next().unwrap_or(a))) {
            return Err(format!("`{arg}` is set by the farm job itself; give it to `strata farm`, not after `--`"));
        }
        let words = self.render_command().into_iter().chain(self.merge_command());
        let texts = words.flatten().filter_map(|p| if let Piece::Text(t) = p { Some(t) } else { None });
        if let Some(bad) = texts.chain([self.dir.display().to_string()]).find(|t| t.contains(['\n', '\r', '\0'])) {
            return Err(format!("`{}` holds a line break, which a job file cannot hold", bad.escape_debug()));
        }
        Ok(())
    }

    /// How many render tasks: frames × splits.
    pub fn task_count(&self) -> u64 {
        self.frames.count() * u64::from(self.splits)
    }

    /// The task at `index` (`0..task_count()`): frame `first + index / splits × step`, split
    /// `index % splits`. [`slurm`] computes the same in the shell from the array index.
    pub fn task(&self, index: u64) -> Task {
        let splits = u64::from(self.splits);
        let split = (index % splits) as u32;
        Task {
            frame: self.frames.first + (index / splits) as i64 * self.frames.step,
            split,
            samples: self.split_samples(split),
        }
    }

    /// The samples of split `k`: `k × spp / splits .. (k + 1) × spp / splits`.
    pub fn split_samples(&self, k: u32) -> std::ops::Range<u32> {
        let bound = |k: u32| (u64::from(k) * u64::from(self.spp) / u64::from(self.splits)) as u32;
        bound(k)..bound(k + 1)
    }

    /// The partial file of split `k`, with the output's `#` run
    /// (`DIR/parts/shot.####.part1.exr`); its checkpoint goes beside it.
    pub fn part_template(&self, split: Word) -> Word {
        let name = self.output.file_name().map_or_else(|| "out.exr".into(), |n| n.to_string_lossy().into_owned());
        let stem = name.strip_suffix(".exr").or_else(|| name.strip_suffix(".EXR")).unwrap_or(&name);
        let mut word = text(format!("{}/{stem}.part", self.dir.join("parts").display()));
        word.extend(split);
        word.push(Piece::Text(".exr".into()));
        word
    }

    /// The command a render task runs (the binary first).
    pub fn render_command(&self) -> Vec<Word> {
        let mut words = vec![text(self.strata.display().to_string()), text("render")];
        words.extend(self.scene.iter().map(|s| text(s.display().to_string())));
        words.push(vec![Piece::Text("--frames=".into()), Piece::Var(Var::Frame)]);
        words.push(text(format!("--spp={}", self.spp)));
        words.push(vec![Piece::Text("--samples=".into()), Piece::Var(Var::Samples)]);
        words.push(text(format!("--checkpoint={}", self.checkpoint)));
        words.push(text("--resume"));
        let mut output = text("--output=");
        output.extend(self.part_template(vec![Piece::Var(Var::Split)]));
        words.push(output);
        words.extend(self.render_args.iter().map(text));
        words
    }

    /// The command the merge of one frame runs: every split's partial file of the frame.
    pub fn merge_command(&self) -> Vec<Word> {
        let mut words = vec![
            text(self.strata.display().to_string()),
            text("merge"),
            vec![Piece::Text("--frame=".into()), Piece::Var(Var::Frame)],
            text(format!("--output={}", self.output.display())),
        ];
        words.extend((0..self.splits).map(|k| self.part_template(text(k.to_string()))));
        words
    }

    /// A one-line description for the job files' headers.
    pub fn summary(&self) -> String {
        let f = &self.frames;
        let step = if f.step == 1 { String::new() } else { format!(" every {}", f.step) };
        format!(
            "frames {}-{}{step} of {}, {} spp in {} split(s) per frame: {} render task(s), then one merge per frame",
            f.first,
            f.last,
            self.scene.as_ref().map_or_else(|| "the default scene".into(), |s| format!("`{}`", s.display())),
            self.spp,
            self.splits,
            self.task_count()
        )
    }
}

/// `text` quoted for a POSIX shell: as it is when it is safe, else in single quotes.
pub fn shell_quote(text: &str) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || "-_./=:,+%@^#".contains(c);
    if !text.is_empty() && text.chars().all(safe) {
        text.to_string()
    } else {
        format!("'{}'", text.replace('\'', r"'\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(frames: &str, spp: u32, splits: u32) -> FarmJob {
        FarmJob {
            strata: "/bin/strata".into(),
            workdir: "/shots".into(),
            scene: Some("shot.usda".into()),
            frames: Frames::parse(frames).unwrap(),
            spp,
            splits,
            checkpoint: 4,
            output: "out/shot.####.exr".into(),
            dir: "farm".into(),
            render_args: vec!["--res".into(), "64x48".into()],
        }
    }

    /// Every (frame, sample) of the shot belongs to exactly one task.
    #[test]
    fn tasks_cover_each_frames_samples_once() {
        for (frames, spp, splits) in [("1-3", 16, 2), ("1001-1010x3", 7, 7), ("-4--1", 5, 3), ("7", 64, 1)] {
            let job = job(frames, spp, splits);
            let mut seen = std::collections::BTreeMap::<i64, Vec<u32>>::new();
            for i in 0..job.task_count() {
                let task = job.task(i);
                seen.entry(task.frame).or_default().extend(task.samples);
            }
            let expected: Vec<i64> = job.frames.list();
            assert_eq!(seen.keys().copied().collect::<Vec<_>>(), expected, "{frames}");
            for (frame, samples) in seen {
                assert_eq!(samples, (0..spp).collect::<Vec<_>>(), "{frames}: frame {frame}");
            }
        }
    }

    #[test]
    fn jobs_that_cannot_run_are_refused() {
        let mut bad = job("1-3", 4, 5);
        assert!(bad.validate().unwrap_err().contains("--split-samples"));
        bad = job("1-3", 4, 2);
        bad.output = "shot.exr".into();
        assert!(bad.validate().unwrap_err().contains("`#` run"));
        bad = job("1-3", 4, 2);
        bad.render_args.push("--samples=0..2".into());
        assert!(bad.validate().unwrap_err().contains("set by the farm job"));
        bad = job("1-3", 4, 2);
        bad.scene = Some("a\nb.usda".into());
        assert!(bad.validate().unwrap_err().contains("line break"));
        assert!(job("1-3", 4, 2).validate().is_ok());
    }

    /// The quoted word reads back as the word through a real shell.
    #[test]
    fn shell_quoting_survives_sh() {
        let words = ["plain", "with space", "it's", "$HOME", "`x`", "a\"b", "", "*"];
        let script = words.iter().map(|w| format!("printf '%s\\n' {}", shell_quote(w))).collect::<Vec<_>>().join("\n");
        let out = std::process::Command::new("sh").arg("-c").arg(script).output().unwrap();
        let lines: Vec<&str> = std::str::from_utf8(&out.stdout).unwrap().split('\n').collect();
        assert_eq!(&lines[..words.len()], &words[..]);
    }
}
