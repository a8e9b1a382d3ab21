//! A [`FarmJob`] as an Open Job Description job template (`jobtemplate-2023-09`, JSON): a
//! `Render` step whose parameter space is frames × splits (`Frame * (Split, Samples)`: each
//! split index travels with its sample range) and a `Merge` step over frames that depends
//! on it. A session runs in a working directory of its own, so every path is absolute.

use super::{FarmJob, Piece, Var, Word};
use serde_json::{Value, json};

/// The template's file name in the job directory.
pub const TEMPLATE: &str = "job.template.json";

/// A word as an OpenJD format string: fixed pieces as they are (text holding `{{` is
/// refused before), task values as `{{Task.Param.…}}`.
fn format_string(word: &Word) -> String {
    word.iter()
        .map(|piece| match piece {
            Piece::Text(t) => t.clone(),
            Piece::Var(Var::Frame) => "{{Task.Param.Frame}}".into(),
            Piece::Var(Var::Split) => "{{Task.Param.Split}}".into(),
            Piece::Var(Var::Samples) => "{{Task.Param.Samples}}".into(),
        })
        .collect()
}

fn action(words: &[Word]) -> Value {
    let args: Vec<String> = words[1..].iter().map(format_string).collect();
    json!({ "command": format_string(&words[0]), "args": args })
}

/// The frames as an INT task parameter's range: `FIRST-LAST:STEP` (a list when negative
/// frames would make the expression ambiguous).
fn frame_range(job: &FarmJob) -> Value {
    let f = &job.frames;
    if f.first >= 0 {
        let step = if f.step == 1 { String::new() } else { format!(":{}", f.step) };
        json!(format!("{}-{}{step}", f.first, f.last))
    } else {
        json!(f.list())
    }
}

/// The job template of `job` (paths made absolute against its working directory).
pub fn openjd_template(job: &FarmJob) -> Result<String, String> {
    job.validate()?;
    if job.frames.count() > 1_000_000 / u64::from(job.splits) {
        return Err("more than a million tasks".into());
    }
    let absolute = |p: &std::path::Path| job.workdir.join(p);
    let job = FarmJob {
        scene: job.scene.as_deref().map(absolute),
        output: absolute(&job.output),
        dir: absolute(&job.dir),
        ..job.clone()
    };
    // A format string has no escape for `{{`: text holding one would be read as a value.
    let words = job.render_command().into_iter().chain(job.merge_command());
    let texts = words.flatten().filter_map(|p| if let Piece::Text(t) = p { Some(t) } else { None });
    if let Some(bad) = texts.into_iter().find(|t| t.contains("{{") || t.contains("}}")) {
        return Err(format!("`{bad}`: a job template cannot hold `{{{{` or `}}}}`"));
    }
    let samples: Vec<String> =
        (0..job.splits).map(|k| job.split_samples(k)).map(|r| format!("{}..{}", r.start, r.end)).collect();
    // The parts' directory first, then the render: one bash command.
    let fixed = ["-c", "mkdir -p \"$1\" && shift && exec \"$@\"", "strata-render"].map(String::from);
    let parts = job.dir.join("parts").display().to_string();
    let render_args: Vec<String> =
        fixed.into_iter().chain([parts]).chain(job.render_command().iter().map(format_string)).collect();
    let render_script = json!({ "actions": { "onRun": { "command": "bash", "args": render_args } } });
    let template = json!({
        "specificationVersion": "jobtemplate-2023-09",
        "name": format!("strata {}", job.output.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned())),
        "description": format!("Written by `strata farm openjd`: {}.", job.summary()),
        "steps": [
            {
                "name": "Render",
                "description": "One task per frame x split of the samples; a rerun task resumes from its checkpoint.",
                "parameterSpace": {
                    "taskParameterDefinitions": [
                        { "name": "Frame", "type": "INT", "range": frame_range(&job) },
                        { "name": "Split", "type": "INT", "range": format!("0-{}", job.splits - 1) },
                        { "name": "Samples", "type": "STRING", "range": samples },
                    ],
                    "combination": "Frame * (Split, Samples)",
                },
                "script": render_script,
            },
            {
                "name": "Merge",
                "description": "One task per frame: the partial files into the EXR one process writes.",
                "dependencies": [{ "dependsOn": "Render" }],
                "parameterSpace": {
                    "taskParameterDefinitions": [{ "name": "Frame", "type": "INT", "range": frame_range(&job) }],
                },
                "script": { "actions": { "onRun": action(&job.merge_command()) } },
            },
        ],
    });
    serde_json::to_string_pretty(&template).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::super::Frames;
    use super::*;

    fn job(frames: &str) -> FarmJob {
        FarmJob {
            strata: "/bin/strata".into(),
            workdir: "/shots".into(),
            scene: Some("shot.usda".into()),
            frames: Frames::parse(frames).unwrap(),
            spp: 10,
            splits: 3,
            checkpoint: 2,
            output: "out/shot.####.exr".into(),
            dir: "farm".into(),
            render_args: vec![],
        }
    }

    /// The parameter space lists each split's samples, the paths are absolute, the merge
    /// depends on the render.
    #[test]
    fn the_template_spans_frames_by_splits_with_absolute_paths() {
        let text = openjd_template(&job("1001-1009x4")).unwrap();
        let t: Value = serde_json::from_str(&text).unwrap();
        let render = &t["steps"][0];
        let params = &render["parameterSpace"]["taskParameterDefinitions"];
        assert_eq!(params[0]["range"], json!("1001-1009:4"));
        assert_eq!(params[2]["range"], json!(["0..3", "3..6", "6..10"]));
        let args = render["script"]["actions"]["onRun"]["args"].as_array().unwrap();
        assert!(args.contains(&json!("/shots/shot.usda")), "{args:?}");
        assert!(args.contains(&json!("--output=/shots/farm/parts/shot.####.part{{Task.Param.Split}}.exr")));
        assert_eq!(t["steps"][1]["dependencies"], json!([{ "dependsOn": "Render" }]));
        assert_eq!(frame_range(&job("-3--1")), json!([-3, -2, -1]));
    }
}
