//! Rendering on a farm, through the binary: splits by samples and tiles merge into the
//! single run's EXR and PNG bit for bit, parts that do not belong together are refused, a
//! render killed with SIGKILL resumes into the uninterrupted image, frame ranges render what
//! single-frame runs render, and exit codes tell bad input from resource failures.
//!
//! The reference is always an independent single run of the binary. EXR files are compared
//! decoded (every channel's type and bits, the data and display windows, every header
//! attribute): the `exr` crate writes custom attributes in hash-map order, so two single runs
//! differ in byte order alone. PNGs are compared byte for byte.

mod common;

use common::{Decoded, decode, strata};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/in/farm/shot.usda");
const RES: &str = "24x18";
const SPP: u32 = 7;

/// Runs `strata render` on the test scene with `extra` arguments; panics unless it succeeds.
fn render(output: &Path, extra: &[&str]) {
    let spp = SPP.to_string();
    let mut args = vec!["render", SCENE, "-o", output.to_str().unwrap(), "--res", RES, "--spp", &spp, "--threads", "2"];
    args.extend(extra);
    let out = strata(&args);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// Runs `strata merge -o output parts…`.
fn merge(output: &Path, parts: &[PathBuf]) -> std::process::Output {
    let mut args = vec!["merge".to_string(), "-o".into(), output.display().to_string()];
    args.extend(parts.iter().map(|p| p.display().to_string()));
    strata(&args.iter().map(String::as_str).collect::<Vec<_>>())
}

/// The single run's EXR and PNG beside it.
fn reference(dir: &Path) -> (Decoded, Vec<u8>) {
    let path = dir.join("single.exr");
    render(&path, &[]);
    (decode(&path), std::fs::read(path.with_extension("png")).unwrap())
}

/// A split: `(tile, samples)`, either `None` for the whole.
type Part = (Option<[usize; 4]>, Option<(u32, u32)>);

/// Cuts of `0..n` into `parts` ranges, at deterministic but irregular places.
fn cuts(n: u32, parts: u32) -> Vec<(u32, u32)> {
    let bounds: Vec<u32> = (0..=parts).map(|k| (k * n + (k * 7919) % parts) / parts).map(|b| b.min(n)).collect();
    let mut bounds = bounds;
    bounds[0] = 0;
    bounds[parts as usize] = n;
    bounds.windows(2).map(|w| (w[0], w[1])).collect()
}

/// `parts` tiles: horizontal bands of irregular heights, the last band cut into columns.
fn tiles(parts: usize) -> Vec<[usize; 4]> {
    let (w, h) = (24, 18);
    if parts == 1 {
        return vec![[0, 0, w, h]];
    }
    let bands = cuts(h as u32, parts.div_ceil(2) as u32);
    let mut out = Vec::new();
    for (i, &(y0, y1)) in bands.iter().enumerate() {
        let remaining = parts - out.len();
        let columns = if i + 1 == bands.len() { remaining } else { 1 };
        for (x0, x1) in cuts(w as u32, columns as u32) {
            out.push([x0 as usize, y0 as usize, (x1 - x0) as usize, (y1 - y0) as usize]);
        }
    }
    assert_eq!(out.len(), parts);
    out
}

fn split_args(part: &Part) -> Vec<String> {
    let mut args = Vec::new();
    if let Some([x, y, w, h]) = part.0 {
        args.extend(["--tile".to_string(), format!("{x},{y},{w},{h}")]);
    }
    if let Some((a, b)) = part.1 {
        args.extend(["--samples".to_string(), format!("{a}..{b}")]);
    }
    args
}

/// Renders each part into `dir` and returns their paths.
fn render_parts(dir: &Path, name: &str, parts: &[Part]) -> Vec<PathBuf> {
    parts
        .iter()
        .enumerate()
        .map(|(k, part)| {
            let path = dir.join(format!("{name}.{k}.exr"));
            let args = split_args(part);
            render(&path, &args.iter().map(String::as_str).collect::<Vec<_>>());
            path
        })
        .collect()
}

#[test]
fn splits_of_each_kind_merge_into_the_single_run_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (single, single_png) = reference(dir.path());
    assert!(
        single.channels.contains_key("dirt_id") && single.channels.contains_key("tint.G"),
        "{:?}",
        single.channels.keys()
    );
    for n in [1usize, 2, 3, 7] {
        let samples: Vec<Part> = cuts(SPP, n as u32).into_iter().map(|s| (None, Some(s))).collect();
        let tiled: Vec<Part> = tiles(n).into_iter().map(|t| (Some(t), None)).collect();
        // A mix: tiles, and the first tile split again by samples (n parts in all).
        let mixed: Vec<Part> = if n == 1 {
            vec![(Some([0, 0, 24, 18]), Some((0, SPP)))]
        } else {
            let t = tiles(n - 1);
            let mut parts: Vec<Part> = t[1..].iter().map(|&t| (Some(t), None)).collect();
            parts.push((Some(t[0]), Some((0, 3))));
            parts.push((Some(t[0]), Some((3, SPP))));
            parts
        };
        for (kind, parts) in [("samples", samples), ("tiles", tiled), ("mixed", mixed)] {
            assert_eq!(parts.len(), n);
            let mut paths = render_parts(dir.path(), &format!("{kind}{n}"), &parts);
            // Merged in an order other than rendered.
            paths.reverse();
            let out = dir.path().join(format!("{kind}{n}.merged.exr"));
            let merged = merge(&out, &paths);
            assert!(merged.status.success(), "{kind} x{n}: {}", String::from_utf8_lossy(&merged.stderr));
            let decoded = decode(&out);
            assert_eq!(decoded.windows, single.windows, "{kind} x{n}");
            assert_eq!(decoded.attributes, single.attributes, "{kind} x{n}: header");
            for (name, data) in &single.channels {
                assert!(decoded.channels.get(name) == Some(data), "{kind} x{n}: channel {name} differs");
            }
            assert_eq!(decoded.channels.len(), single.channels.len(), "{kind} x{n}");
            assert!(std::fs::read(out.with_extension("png")).unwrap() == single_png, "{kind} x{n}: PNG differs");
        }
    }
}

#[test]
fn a_partial_file_is_a_viewable_crop_of_the_image_with_its_split_in_the_header() {
    let dir = tempfile::tempdir().unwrap();
    let (single, _) = reference(dir.path());
    let path = dir.path().join("tile.exr");
    render(&path, &["--tile", "5,4,11,9"]);
    let part = decode(&path);
    assert_eq!(part.attributes["strata/split/region"], "5,4,11,9");
    assert_eq!(part.attributes["strata/split/samples"], format!("0..{SPP}"));
    assert_eq!(part.attributes["strata/split/image"], RES);
    assert!(part.windows.contains("(5, 4)") && part.windows.contains("(11, 9)"), "{}", part.windows);
    // A tile over all samples holds the full image's pixels there, bit for bit.
    let (r, full) = (&part.channels["R"].1, &single.channels["R"].1);
    for y in 0..9 {
        for x in 0..11 {
            assert_eq!(r[y * 11 + x], full[(y + 4) * 24 + x + 5], "pixel ({x}, {y}) of the tile");
        }
    }
}

#[test]
fn parts_that_do_not_make_one_image_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let parts = render_parts(d, "p", &[(None, Some((0, 3))), (None, Some((3, SPP)))]);
    let overlapping = render_parts(d, "o", &[(Some([0, 0, 13, 18]), Some((2, 5)))]);
    let other_seed = d.join("seed.exr");
    render(&other_seed, &["--samples", "3..7", "--seed", "9"]);
    let cases: [(&str, Vec<PathBuf>, &str); 4] = [
        ("a missing part", vec![parts[0].clone()], "do not cover"),
        ("a part twice", vec![parts[0].clone(), parts[0].clone(), parts[1].clone()], "overlap"),
        ("an overlapping tile", vec![parts[0].clone(), parts[1].clone(), overlapping[0].clone()], "overlap"),
        ("another render's part", vec![parts[0].clone(), other_seed], "different renders"),
    ];
    for (what, paths, message) in cases {
        let out = d.join("refused.exr");
        let merged = merge(&out, &paths);
        let stderr = String::from_utf8_lossy(&merged.stderr);
        assert_eq!(merged.status.code(), Some(1), "{what}: {stderr}");
        assert!(stderr.contains(message), "{what}: {stderr}");
        assert!(!out.exists() && !out.with_extension("png").exists(), "{what}: an output was written");
    }
    // A file that is not a partial file, and a part as the output, are refused too.
    let single = d.join("single.exr");
    render(&single, &[]);
    let merged = merge(&d.join("x.exr"), &[single]);
    assert_eq!(merged.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&merged.stderr).contains("not a strata partial file"));
    let merged = merge(&parts[0], &parts);
    assert_eq!(merged.status.code(), Some(1));
}

/// A deterministic stream of numbers in `0..1` (xorshift).
fn unit_stream(seed: u64) -> impl Iterator<Item = f64> {
    let mut state = seed.max(1);
    std::iter::repeat_with(move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    })
}

#[test]
fn a_render_killed_at_random_points_resumes_into_the_uninterrupted_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Large enough to take a few seconds on one thread, in 16 passes of 4 samples.
    let args = |out: &Path| -> Vec<String> {
        ["render", SCENE, "-o", out.to_str().unwrap(), "--res", "96x72", "--spp", "64", "--threads", "1"]
            .iter()
            .map(|s| s.to_string())
            .collect()
    };
    let reference = d.join("reference.exr");
    let start = std::time::Instant::now();
    let out = strata(&args(&reference).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let seconds = start.elapsed().as_secs_f64();
    let expected = decode(&reference);
    let expected_png = std::fs::read(reference.with_extension("png")).unwrap();
    let output = d.join("resumed.exr");
    let checkpoint = d.join("resumed.checkpoint.exr");
    let mut resumed_from_a_checkpoint = 0;
    for (kill, fraction) in unit_stream(26).take(3).enumerate() {
        let _ = std::fs::remove_file(&checkpoint);
        let mut run = args(&output);
        run.extend(["--checkpoint".into(), "4".into()]);
        let mut child = Command::new(env!("CARGO_BIN_EXE_strata"))
            .args(&run)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // Somewhere between a quarter and all of an uninterrupted run's time.
        std::thread::sleep(std::time::Duration::from_secs_f64(seconds * (0.25 + 0.75 * fraction)));
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
        let _ = child.wait();
        let had_checkpoint = checkpoint.exists();
        run.push("--resume".into());
        let out = strata(&run.iter().map(String::as_str).collect::<Vec<_>>());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "kill {kill}: {stderr}");
        if had_checkpoint {
            assert!(stderr.contains("resuming from"), "kill {kill}: {stderr}");
            resumed_from_a_checkpoint += 1;
        }
        assert!(decode(&output) == expected, "kill {kill}: the resumed image differs");
        assert!(std::fs::read(output.with_extension("png")).unwrap() == expected_png, "kill {kill}: PNG differs");
        assert!(!checkpoint.exists(), "kill {kill}: the checkpoint outlived the output");
    }
    assert!(resumed_from_a_checkpoint > 0, "no kill landed after a checkpoint: the test proved nothing");
}

#[test]
fn a_checkpoint_of_other_settings_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A checkpoint is a partial file of the first samples: make one with another seed.
    let checkpoint = d.join("out.checkpoint.exr");
    render(&checkpoint, &["--samples", "0..3", "--seed", "5"]);
    let out = strata(&[
        "render",
        SCENE,
        "-o",
        d.join("out.exr").to_str().unwrap(),
        "--res",
        RES,
        "--spp",
        "7",
        "--checkpoint",
        "2",
        "--resume",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot resume") && stderr.contains("another scene or other settings"), "{stderr}");
}

#[test]
fn a_frame_range_renders_what_single_frame_runs_render_with_one_preparation() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let template = d.join("shot.####.exr");
    let out =
        strata(&["render", SCENE, "-o", template.to_str().unwrap(), "--res", RES, "--spp", "7", "--frames", "1-4x3"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("frame 1 (1/2)") && stderr.contains("frame 4 (2/2)"), "{stderr}");
    // The moving ball moves its instance: nothing is recompiled or built but the top level.
    assert!(stderr.contains("frame 4 (2/2)") && stderr.contains("instances moved"), "{stderr}");
    assert!(stderr.contains("rendered 2 frames") && stderr.contains("stage read 1 time(s)"), "{stderr}");
    let mut images = Vec::new();
    for frame in [1, 4] {
        let single = d.join(format!("single.{frame}.exr"));
        render(&single, &["--time", &frame.to_string()]);
        let mut framed = decode(&d.join(format!("shot.{frame:04}.exr")));
        assert_eq!(framed.attributes.remove("strata/frame"), Some(frame.to_string()));
        assert_eq!(framed.attributes["strata/time"], frame.to_string());
        let single = decode(&single);
        assert!(framed == single, "frame {frame} differs from a single-frame run");
        images.push(single.channels["R"].clone());
    }
    assert_ne!(images[0], images[1], "the ball did not move: the comparison proves nothing");
    // Without a `#` run the frames would overwrite one file: refused.
    let out = strata(&["render", SCENE, "-o", d.join("shot.exr").to_str().unwrap(), "--frames", "1-2"]);
    assert_eq!(out.status.code(), Some(1));
}

/// `tests/in/farm/moving.usda` over frames 1 to 4 in one process: a moving camera, a parent
/// moving a cube, a sphere moving on its own too, an instanceable reference, a point
/// instancer and a light; a ball that disappears at frame 3. Every frame equals a
/// single-frame run of a fresh process, and the per-frame lines say what was redone.
#[test]
fn moving_instances_over_a_frame_range_render_what_single_frame_runs_render() {
    const MOVING: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/in/farm/moving.usda");
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let template = d.join("moving.####.exr");
    let args = ["--res", RES, "--spp", "7", "--threads", "2"];
    let mut frames = vec!["render", MOVING, "-o", template.to_str().unwrap(), "--frames", "1-4"];
    frames.extend(args);
    let out = strata(&frames);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let line = |frame: usize| stderr.lines().find(|l| l.starts_with(&format!("frame {frame} "))).unwrap_or("");
    assert!(line(2).contains("instances moved") && line(4).contains("instances moved"), "{stderr}");
    assert!(line(3).contains("rebuilt (geometry, BVH): `/Blink.visibility` changed"), "{stderr}");
    assert!(stderr.contains("built 2 time(s), rebound 0 time(s) and its instances moved 2 time(s)"), "{stderr}");
    let mut images = Vec::new();
    for frame in 1..=4 {
        let single = d.join(format!("single.{frame}.exr"));
        let time = frame.to_string();
        let mut one = vec!["render", MOVING, "-o", single.to_str().unwrap(), "--time", &time];
        one.extend(args);
        let out = strata(&one);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let mut framed = decode(&d.join(format!("moving.{frame:04}.exr")));
        assert_eq!(framed.attributes.remove("strata/frame"), Some(frame.to_string()));
        let single = decode(&single);
        assert!(framed == single, "frame {frame} differs from a single-frame run");
        assert!(!images.contains(&single.channels["R"]), "frame {frame} repeats an earlier one");
        images.push(single.channels["R"].clone());
    }
}

#[test]
fn exit_codes_tell_bad_input_from_resource_failures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bad = d.join("bad.usda");
    std::fs::write(&bad, "#usda 1.0\ndef Sphere \"S\" {\n  double radius = \n}\n").unwrap();
    let out = strata(&["render", bad.to_str().unwrap(), "-o", d.join("o.exr").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1), "{}", String::from_utf8_lossy(&out.stderr));
    // An output directory that does not exist: the machine's problem, not the scene's.
    let out = strata(&["render", SCENE, "-o", d.join("missing/dir/o.exr").to_str().unwrap(), "--res", RES]);
    assert_eq!(out.status.code(), Some(3), "{}", String::from_utf8_lossy(&out.stderr));
    let out = strata(&["merge", "-o", d.join("missing/m.exr").to_str().unwrap(), bad.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(3), "{}", String::from_utf8_lossy(&out.stderr));
    // Interrupted (SIGTERM, as a scheduler preempts): 130, and no output, whole or half.
    let long = d.join("long.exr");
    let mut child = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["render", SCENE, "-o", long.to_str().unwrap(), "--res", "96x72", "--spp", "512", "--threads", "1"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(700));
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    assert_eq!(child.wait().unwrap().code(), Some(130));
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(!left.iter().any(|n| n.to_string_lossy().contains("long")), "{left:?}");
}
