//! A [`FarmJob`] as Slurm batch scripts. The frames go in chunks of at most the site's
//! `MaxArraySize`; per chunk, one render array per split (array index = the frame's index in
//! the chunk, `#SBATCH --requeue`: a preempted task runs again and resumes from its
//! checkpoint) and one merge array over the same frames, submitted with
//! `--dependency=aftercorr:<split 0's array>:<split 1's>…`: the merge of a frame starts as soon
//! as that frame's splits have succeeded (Slurm's `aftercorr` pairs equal task indices), not
//! when the whole shot has rendered.

use super::{FarmJob, Piece, Var, Word, shell_quote};

/// Slurm's default `MaxArraySize`: an array's task indices run below it.
pub const DEFAULT_MAX_ARRAY_SIZE: u64 = 1001;

/// Options of the batch scripts.
#[derive(Clone, Debug, Default)]
pub struct SlurmOptions {
    /// The partition to submit to (`None`: the cluster's default).
    pub partition: Option<String>,
    /// The site's `MaxArraySize` (`None`: Slurm's default, [`DEFAULT_MAX_ARRAY_SIZE`]); no
    /// array is larger.
    pub max_array_size: Option<u64>,
}

/// Which batch script a submission runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Script {
    /// [`RENDER_SCRIPT`].
    Render,
    /// [`MERGE_SCRIPT`].
    Merge,
}

/// One `sbatch` call: `sbatch --array=0-(tasks-1) [--dependency=aftercorr:…] SCRIPT ARGS…`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Submission {
    /// The script it submits.
    pub script: Script,
    /// Its array's task count (indices `0..tasks`).
    pub tasks: u64,
    /// The script's arguments: the chunk's first frame index, then (render) the split.
    pub args: Vec<u64>,
    /// Earlier submissions (indices in [`SlurmJob::submissions`]) whose task of the same
    /// index must succeed first (`aftercorr`).
    pub after: Vec<usize>,
}

/// The job files: the render and merge scripts, the submissions that run them, and a script
/// that makes those submissions.
#[derive(Clone, Debug)]
pub struct SlurmJob {
    /// `render.sbatch`: task `i` of a submission with arguments `FIRST SPLIT` renders split
    /// `SPLIT` of the frame of index `FIRST + i`.
    pub render: String,
    /// `merge.sbatch`: task `i` of a submission with argument `FIRST` merges the frame of
    /// index `FIRST + i`.
    pub merge: String,
    /// In order: per chunk of frames, a render array per split, then their merge array.
    pub submissions: Vec<Submission>,
    /// `submit.sh`: the [`SlurmJob::submissions`] with `sbatch`.
    pub submit: String,
    /// What the user should know before submitting.
    pub warnings: Vec<String>,
}

/// File names in the job directory.
pub const RENDER_SCRIPT: &str = "render.sbatch";
/// See [`RENDER_SCRIPT`].
pub const MERGE_SCRIPT: &str = "merge.sbatch";
/// See [`RENDER_SCRIPT`].
pub const SUBMIT_SCRIPT: &str = "submit.sh";

/// A word for the shell: fixed pieces single-quoted, task values as `"$frame"` etc.
fn shell_word(word: &Word) -> String {
    word.iter()
        .map(|piece| match piece {
            Piece::Text(t) => shell_quote(t),
            Piece::Var(Var::Frame) => "\"$frame\"".into(),
            Piece::Var(Var::Split) => "\"$split\"".into(),
            Piece::Var(Var::Samples) => "\"$samples\"".into(),
        })
        .collect()
}

fn shell_command(words: &[Word]) -> String {
    words.iter().map(shell_word).collect::<Vec<_>>().join(" \\\n    ")
}

/// `#SBATCH` lines every script shares; `name` names the job. (Each submission sets its
/// own `--array`.)
fn directives(job: &FarmJob, options: &SlurmOptions, name: &str) -> Result<String, String> {
    let stem = job.output.file_stem().map_or_else(|| "shot".into(), |s| s.to_string_lossy().replace('#', ""));
    let stem = stem.trim_end_matches('.');
    let mut lines = vec![
        format!("--job-name=strata-{name}-{stem}"),
        format!("--chdir={}", job.workdir.display()),
        format!("--output={}/logs/{name}-%A_%a.log", job.dir.display()),
        // A requeued task appends to its log, so the log shows where it resumed.
        "--open-mode=append".into(),
    ];
    if let Some(partition) = &options.partition {
        lines.push(format!("--partition={partition}"));
    }
    // sbatch reads a directive up to the first blank: one with a blank would be cut short.
    if let Some(bad) = lines.iter().find(|l| l.contains(char::is_whitespace)) {
        return Err(format!("`{bad}`: Slurm's #SBATCH lines cannot hold blanks; choose paths without them"));
    }
    Ok(lines.iter().map(|l| format!("#SBATCH {l}\n")).collect())
}

/// The frame chunks of `job` under `limit` tasks an array: `(first frame index, frames)`.
fn chunks(job: &FarmJob, limit: u64) -> Vec<(u64, u64)> {
    let frames = job.frames.count();
    (0..frames.div_ceil(limit)).map(|c| (c * limit, limit.min(frames - c * limit))).collect()
}

/// The site's array limit from `scontrol show config`'s text: the smaller of `MaxArraySize`
/// (indices run below it) and `SchedulerParameters`' `max_array_tasks`; `None` when it names
/// neither.
pub fn array_limit_from_config(config: &str) -> Option<u64> {
    let value = |key: &str| {
        config.lines().find_map(|l| {
            let (k, v) = l.split_once('=')?;
            (k.trim() == key).then(|| v.trim().to_string())
        })
    };
    let size = value("MaxArraySize").and_then(|v| v.parse::<u64>().ok());
    let tasks = value("SchedulerParameters").and_then(|v| {
        v.split(',').find_map(|p| p.trim().strip_prefix("max_array_tasks=").and_then(|n| n.parse::<u64>().ok()))
    });
    match (size, tasks) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// The batch scripts of `job` and their submissions.
pub fn slurm_job(job: &FarmJob, options: &SlurmOptions) -> Result<SlurmJob, String> {
    job.validate()?;
    let limit = options.max_array_size.unwrap_or(DEFAULT_MAX_ARRAY_SIZE);
    if limit == 0 {
        return Err("the site's MaxArraySize is 0: job arrays are disabled".into());
    }
    let f = &job.frames;
    let header = |what: &str| format!("#!/bin/bash\n# {what}\n# Written by `strata farm slurm`: {}.\n", job.summary());

    let mut render = header("The render tasks: one per frame x split of the samples.");
    render += &directives(job, options, "render")?;
    render += "#SBATCH --requeue\n";
    render += &format!(
        "set -eu\n\
         # Task i of `sbatch --array=... render.sbatch FIRST SPLIT` renders the frame of index FIRST + i,\n\
         # {first} + (FIRST + i) * {step}, samples SPLIT * {spp} / {splits} up to the next split's first: the same as\n\
         # `FarmJob::task((FIRST + i) * {splits} + SPLIT)`. A requeued task resumes from its checkpoint.\n\
         task=${{SLURM_ARRAY_TASK_ID:?run this script through sbatch}}\n\
         index=$(( ${{1:?the first frame index of the chunk}} + task ))\n\
         split=$(( ${{2:?the split}} ))\n\
         frame=$(( {first} + index * {step} ))\n\
         samples=$(( split * {spp} / {splits} ))..$(( (split + 1) * {spp} / {splits} ))\n\
         mkdir -p {parts}\n\
         exec {command}\n",
        first = f.first,
        step = f.step,
        splits = job.splits,
        spp = job.spp,
        parts = shell_quote(&job.dir.join("parts").display().to_string()),
        command = shell_command(&job.render_command()),
    );

    let mut merge = header("The merges: one per frame, once that frame's render tasks have succeeded.");
    merge += &directives(job, options, "merge")?;
    // A failed render task makes the dependency unsatisfiable: end the merge rather than leave it pending.
    merge += "#SBATCH --kill-on-invalid-dep=yes\n";
    merge += &format!(
        "set -eu\n\
         task=${{SLURM_ARRAY_TASK_ID:?run this script through sbatch}}\n\
         frame=$(( {first} + (${{1:?the first frame index of the chunk}} + task) * {step} ))\n\
         exec {command}\n",
        first = f.first,
        step = f.step,
        command = shell_command(&job.merge_command()),
    );

    let mut submissions = Vec::new();
    for (first, frames) in chunks(job, limit) {
        let renders: Vec<usize> = (0..u64::from(job.splits))
            .map(|split| {
                submissions.push(Submission {
                    script: Script::Render,
                    tasks: frames,
                    args: vec![first, split],
                    after: Vec::new(),
                });
                submissions.len() - 1
            })
            .collect();
        submissions.push(Submission { script: Script::Merge, tasks: frames, args: vec![first], after: renders });
    }

    let script = |name: &str| shell_quote(&job.dir.join(name).display().to_string());
    let mut submit = format!(
        "#!/bin/sh\n\
         # Submits the render arrays (per chunk of frames, one per split), and each chunk's merges,\n\
         # each frame's once its own render tasks have succeeded. Prints `render ID` / `merge ID` lines.\n\
         # Written by `strata farm slurm`: {summary}.\n\
         set -eu\n\
         cd {workdir}\n\
         mkdir -p {logs}\n",
        summary = job.summary(),
        workdir = shell_quote(&job.workdir.display().to_string()),
        logs = shell_quote(&job.dir.join("logs").display().to_string()),
    );
    for (k, s) in submissions.iter().enumerate() {
        let dependency: String = if s.after.is_empty() {
            String::new()
        } else {
            let ids: String = s.after.iter().map(|a| format!(":\"$job{a}\"")).collect();
            format!(" --dependency=aftercorr{ids}")
        };
        let (name, file) = match s.script {
            Script::Render => ("render", RENDER_SCRIPT),
            Script::Merge => ("merge", MERGE_SCRIPT),
        };
        let args: String = s.args.iter().map(|a| format!(" {a}")).collect();
        submit += &format!(
            "job{k}=$(sbatch --parsable {array}{dependency} {script}{args})\n\
             job{k}=${{job{k}%%;*}}\n\
             echo \"{name} $job{k}\"\n",
            array = array_option(s.tasks),
            script = script(file),
        );
    }

    let mut warnings = Vec::new();
    let chunk_count = job.frames.count().div_ceil(limit);
    if chunk_count > 1 {
        warnings.push(format!(
            "{} frames pass the array limit of {limit}: submitted in {chunk_count} chunks of frames, \
             {} arrays in all",
            job.frames.count(),
            submissions.len()
        ));
    }
    Ok(SlurmJob { render, merge, submissions, submit, warnings })
}

/// The `sbatch` option of an array of `tasks` tasks.
pub fn array_option(tasks: u64) -> String {
    format!("--array=0-{}", tasks.saturating_sub(1))
}

#[cfg(test)]
mod tests {
    use super::super::{Frames, shell_quote};
    use super::*;

    fn job() -> FarmJob {
        FarmJob {
            strata: "/opt/strata bin/strata".into(),
            workdir: "/shots".into(),
            scene: Some("shot's.usda".into()),
            frames: Frames::parse("1001-1009x4").unwrap(),
            spp: 10,
            splits: 3,
            checkpoint: 2,
            output: "out/shot.####.exr".into(),
            dir: "farm".into(),
            render_args: vec!["--res".into(), "64x48".into()],
        }
    }

    /// `script` run by bash as task `index` of a submission with `args`, `exec` replaced by
    /// printing each argument on its own line.
    fn run_task(script: &str, index: u64, args: &[u64]) -> Vec<String> {
        let script = script.replace("exec ", "printf '%s\\n' ").replace("mkdir -p", "true");
        let out = std::process::Command::new("bash")
            .arg("-c")
            .arg(&script)
            .arg("task")
            .args(args.iter().map(u64::to_string))
            .env("SLURM_ARRAY_TASK_ID", index.to_string())
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap().lines().map(String::from).collect()
    }

    /// The scripts' arithmetic, run by bash for every task of every submission, with and
    /// without chunking: each of `FarmJob::task`'s tasks is rendered by exactly one array task
    /// (the command names its part), and each frame merged by one, after exactly the render
    /// arrays of its chunk.
    #[test]
    fn every_task_is_in_one_array_and_maps_in_bash() {
        let job = job();
        assert_eq!(job.task_count(), 9);
        let frames = job.frames.list();
        for (limit, arrays) in [(None, 4), (Some(2), 8), (Some(1), 12)] {
            let scripts = slurm_job(&job, &SlurmOptions { max_array_size: limit, ..SlurmOptions::default() }).unwrap();
            assert_eq!(scripts.submissions.len(), arrays, "limit {limit:?}");
            assert_eq!(scripts.warnings.is_empty(), limit.is_none());
            let mut rendered = vec![0; job.task_count() as usize];
            let mut merged = vec![0; frames.len()];
            for (k, s) in scripts.submissions.iter().enumerate() {
                assert!(s.tasks >= 1 && s.tasks <= limit.unwrap_or(DEFAULT_MAX_ARRAY_SIZE));
                for i in 0..s.tasks {
                    let index = s.args[0] + i;
                    match s.script {
                        Script::Render => {
                            let global = index * u64::from(job.splits) + s.args[1];
                            let task = job.task(global);
                            rendered[global as usize] += 1;
                            let expected = [
                                "/opt/strata bin/strata".to_string(),
                                "render".into(),
                                "shot's.usda".into(),
                                format!("--frames={}", task.frame),
                                "--spp=10".into(),
                                format!("--samples={}..{}", task.samples.start, task.samples.end),
                                "--checkpoint=2".into(),
                                "--resume".into(),
                                format!("--output=farm/parts/shot.####.part{}.exr", task.split),
                                "--res".into(),
                                "64x48".into(),
                            ];
                            assert_eq!(run_task(&scripts.render, i, &s.args), expected, "array {k} task {i}");
                        }
                        Script::Merge => {
                            merged[index as usize] += 1;
                            let args = run_task(&scripts.merge, i, &s.args);
                            assert!(args.contains(&format!("--frame={}", frames[index as usize])), "{args:?}");
                        }
                    }
                }
                if s.script == Script::Merge {
                    // After the render arrays of the same frames, one per split.
                    let mut splits: Vec<u64> = s.after.iter().map(|&a| scripts.submissions[a].args[1]).collect();
                    splits.sort_unstable();
                    assert_eq!(splits, (0..u64::from(job.splits)).collect::<Vec<_>>());
                    for &a in &s.after {
                        let r = &scripts.submissions[a];
                        assert!(a < k && r.script == Script::Render && r.args[0] == s.args[0] && r.tasks == s.tasks);
                    }
                } else {
                    assert!(s.after.is_empty());
                }
            }
            assert!(rendered.iter().all(|&n| n == 1), "{rendered:?}");
            assert!(merged.iter().all(|&n| n == 1), "{merged:?}");
        }
        let scripts = slurm_job(&job, &SlurmOptions::default()).unwrap();
        assert!(scripts.render.contains("#SBATCH --requeue\n") && !scripts.render.contains("#SBATCH --array"));
        let zero = SlurmOptions { max_array_size: Some(0), ..SlurmOptions::default() };
        assert!(slurm_job(&job, &zero).unwrap_err().contains("disabled"));
    }

    /// `submit.sh` run against a fake `sbatch` that logs its arguments and answers IDs from
    /// 101: each merge array depends (`aftercorr`) on the IDs of its chunk's render arrays.
    #[test]
    fn submit_sh_makes_the_submissions() {
        let dir = tempfile::tempdir().unwrap();
        let mut job = job();
        job.workdir = dir.path().to_path_buf();
        let options = SlurmOptions { max_array_size: Some(2), ..SlurmOptions::default() };
        let scripts = slurm_job(&job, &options).unwrap();
        let bin = dir.path().join("bin");
        std::fs::create_dir(&bin).unwrap();
        let log = dir.path().join("sbatch.log");
        std::fs::write(
            bin.join("sbatch"),
            format!(
                "#!/bin/sh\necho \"$*\" >> {log}\necho \"$(( $(wc -l < {log}) + 100 ));cluster\"\n",
                log = shell_quote(&log.display().to_string())
            ),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(bin.join("sbatch"), std::fs::Permissions::from_mode(0o755)).unwrap();
        let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
        let out = std::process::Command::new("sh").arg("-c").arg(&scripts.submit).env("PATH", path).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let printed = String::from_utf8(out.stdout).unwrap();
        assert_eq!(
            printed,
            "render 101\nrender 102\nrender 103\nmerge 104\nrender 105\nrender 106\nrender 107\nmerge 108\n"
        );
        let calls = std::fs::read_to_string(&log).unwrap();
        let calls: Vec<&str> = calls.lines().collect();
        assert_eq!(calls[0], "--parsable --array=0-1 farm/render.sbatch 0 0");
        assert_eq!(calls[3], "--parsable --array=0-1 --dependency=aftercorr:101:102:103 farm/merge.sbatch 0");
        assert_eq!(calls[6], "--parsable --array=0-0 farm/render.sbatch 2 2");
        assert_eq!(calls[7], "--parsable --array=0-0 --dependency=aftercorr:105:106:107 farm/merge.sbatch 2");
        assert!(dir.path().join("farm/logs").is_dir());
    }

    #[test]
    fn the_array_limit_is_read_from_slurms_config() {
        let config =
            "Configuration data as of 2026-01-01T00:00:00\nMaxArraySize            = 1001\nMaxJobCount = 10000\n";
        assert_eq!(array_limit_from_config(config), Some(1001));
        let tasks = format!("{config}SchedulerParameters     = bf_continue,max_array_tasks=500\n");
        assert_eq!(array_limit_from_config(&tasks), Some(500));
        assert_eq!(array_limit_from_config("nothing = here\n"), None);
    }

    #[test]
    fn blanks_in_directives_are_refused() {
        let mut job = job();
        job.dir = "my farm".into();
        assert!(slurm_job(&job, &SlurmOptions::default()).unwrap_err().contains("blanks"));
    }
}
