//! A [`FarmJob`] as Slurm batch scripts: an array job with one task per frame × split
//! (`#SBATCH --requeue`: a preempted task runs again and resumes from its checkpoint) and a
//! merge array with one task per frame, submitted with `--dependency=afterok:<render job>`
//! so it starts once every render task has succeeded.

use super::{FarmJob, Piece, Var, Word, shell_quote};

/// Slurm's default `MaxArraySize`: larger arrays need the site's limit raised.
pub const DEFAULT_MAX_ARRAY_SIZE: u64 = 1001;

/// Options of the batch scripts.
#[derive(Clone, Debug, Default)]
pub struct SlurmOptions {
    /// The partition to submit to (`None`: the cluster's default).
    pub partition: Option<String>,
}

/// The job files: the render array, the merge array, and a script that submits both.
#[derive(Clone, Debug)]
pub struct SlurmJob {
    /// `render.sbatch`: one array task per frame × split.
    pub render: String,
    /// `merge.sbatch`: one array task per frame.
    pub merge: String,
    /// `submit.sh`: `sbatch render.sbatch`, then `merge.sbatch` depending on it.
    pub submit: String,
    /// What the user should know before submitting (array sizes past Slurm's default).
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

/// `#SBATCH` lines every script shares; `name` names the job, `count` its array tasks.
fn directives(job: &FarmJob, options: &SlurmOptions, name: &str, count: u64) -> Result<String, String> {
    let stem = job.output.file_stem().map_or_else(|| "shot".into(), |s| s.to_string_lossy().replace('#', ""));
    let stem = stem.trim_end_matches('.');
    let mut lines = vec![
        format!("--job-name=strata-{name}-{stem}"),
        format!("--array=0-{}", count - 1),
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

/// The batch scripts of `job`.
pub fn slurm_job(job: &FarmJob, options: &SlurmOptions) -> Result<SlurmJob, String> {
    job.validate()?;
    let (tasks, frames) = (job.task_count(), job.frames.count());
    let f = &job.frames;
    let header = |what: &str| format!("#!/bin/bash\n# {what}\n# Written by `strata farm slurm`: {}.\n", job.summary());

    let mut render = header("The render tasks: one per frame x split of the samples.");
    render += &directives(job, options, "render", tasks)?;
    render += "#SBATCH --requeue\n";
    render += &format!(
        "set -eu\n\
         # Task i renders frame {first} + (i / {splits}) * {step}, samples (i % {splits}) * {spp} / {splits} up to the\n\
         # next split's first: the same as `FarmJob::task`. A requeued task resumes from its checkpoint.\n\
         task=${{SLURM_ARRAY_TASK_ID:?run this script through sbatch}}\n\
         frame=$(( {first} + task / {splits} * {step} ))\n\
         split=$(( task % {splits} ))\n\
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

    let mut merge = header("The merges: one per frame, once every render task has succeeded.");
    merge += &directives(job, options, "merge", frames)?;
    // A failed render task makes the dependency unsatisfiable: end the merge rather than leave it pending.
    merge += "#SBATCH --kill-on-invalid-dep=yes\n";
    merge += &format!(
        "set -eu\n\
         task=${{SLURM_ARRAY_TASK_ID:?run this script through sbatch}}\n\
         frame=$(( {first} + task * {step} ))\n\
         exec {command}\n",
        first = f.first,
        step = f.step,
        command = shell_command(&job.merge_command()),
    );

    let script = |name: &str| shell_quote(&job.dir.join(name).display().to_string());
    let submit = format!(
        "#!/bin/sh\n\
         # Submits the render tasks, then the merges once every render task has succeeded.\n\
         # Written by `strata farm slurm`: {summary}.\n\
         set -eu\n\
         cd {workdir}\n\
         mkdir -p {logs}\n\
         render=$(sbatch --parsable {render})\n\
         render=${{render%%;*}}\n\
         merge=$(sbatch --parsable --dependency=afterok:\"$render\" {merge})\n\
         echo \"render job $render, merge job ${{merge%%;*}}\"\n",
        summary = job.summary(),
        workdir = shell_quote(&job.workdir.display().to_string()),
        logs = shell_quote(&job.dir.join("logs").display().to_string()),
        render = script(RENDER_SCRIPT),
        merge = script(MERGE_SCRIPT),
    );

    let mut warnings = Vec::new();
    if tasks > DEFAULT_MAX_ARRAY_SIZE {
        warnings.push(format!(
            "the render array has {tasks} tasks; Slurm's default MaxArraySize is {DEFAULT_MAX_ARRAY_SIZE} \
             (check `scontrol show config | grep MaxArraySize`)"
        ));
    }
    Ok(SlurmJob { render, merge, submit, warnings })
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

    /// The render script's arithmetic, run by bash for every array index, gives the tasks
    /// `FarmJob::task` lists; the command bash would run names each task's part.
    #[test]
    fn the_array_index_maps_to_the_task_in_bash() {
        let job = job();
        let scripts = slurm_job(&job, &SlurmOptions::default()).unwrap();
        for index in 0..job.task_count() {
            // `exec` replaced by printing each argument on its own line.
            let script = scripts.render.replace("exec ", "printf '%s\\n' ").replace("mkdir -p", "true");
            let out = std::process::Command::new("bash")
                .arg("-c")
                .arg(&script)
                .env("SLURM_ARRAY_TASK_ID", index.to_string())
                .output()
                .unwrap();
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            let args: Vec<String> = String::from_utf8(out.stdout).unwrap().lines().map(String::from).collect();
            let task = job.task(index);
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
            assert_eq!(args, expected, "task {index}");
        }
        assert_eq!(job.task_count(), 9);
        assert!(scripts.render.contains("#SBATCH --array=0-8\n") && scripts.render.contains("#SBATCH --requeue\n"));
        assert!(scripts.merge.contains("#SBATCH --array=0-2\n"));
        assert!(
            scripts.submit.contains(&format!("--dependency=afterok:\"$render\" {}", shell_quote("farm/merge.sbatch")))
        );
    }

    #[test]
    fn blanks_in_directives_are_refused() {
        let mut job = job();
        job.dir = "my farm".into();
        assert!(slurm_job(&job, &SlurmOptions::default()).unwrap_err().contains("blanks"));
    }
}
