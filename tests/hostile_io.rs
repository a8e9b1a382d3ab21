//! Hostile input files, scenes and outputs (issue 9): each gives a located diagnostic at
//! once — never a hang, an unbounded read, a crash, a flood of messages or a destroyed input.
//!
//! Small inputs live in `tests/in/hostile/` (they also seed fuzzing); FIFOs, big generated
//! scenes and output directories are made here. Every run of `strata` is killed after a
//! deadline, so a regression to blocking fails the test instead of hanging the suite.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Far more than any of these runs needs (they take well under a second each in a debug
/// build); reaching it means the run hung.
const DEADLINE: Duration = Duration::from_secs(120);

/// Runs `strata args`, killing it at [`DEADLINE`].
fn strata(args: &[&str]) -> Output {
    common::run_strata(args, DEADLINE).unwrap_or_else(|| panic!("strata {args:?} did not finish within {DEADLINE:?}"))
}

/// `strata check FILE`: exit code and stderr.
fn check(file: &Path) -> (Option<i32>, String) {
    let out = strata(&["check", file.to_str().expect("utf-8 path")]);
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// `strata check --strict FILE`: what USD composes around (an unreadable texture or dome
/// map) is a warning, so only `--strict` fails on it.
fn check_strict(file: &Path) -> (Option<i32>, String) {
    let out = strata(&["check", "--strict", file.to_str().expect("utf-8 path")]);
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// Asserts `check` fails with `message` located at `location` (`file:line:col`).
fn assert_located(file: &Path, location: &str, message: &str) {
    assert_located_with(check(file), file, location, message);
}

/// Asserts `message`, located at `location`, is a warning of `check` and an error of
/// `check --strict` (what USD composes around: an unreadable layer, texture or dome map).
fn assert_located_warning(file: &Path, location: &str, message: &str) {
    let (code, stderr) = check(file);
    assert_eq!(code, Some(0), "{}: {stderr}", file.display());
    assert!(stderr.contains("warning: ") && stderr.contains(message) && stderr.contains(location), "{stderr}");
    assert_located_with(check_strict(file), file, location, message);
}

fn assert_located_with((code, stderr): (Option<i32>, String), file: &Path, location: &str, message: &str) {
    assert_eq!(code, Some(1), "{}: {stderr}", file.display());
    assert!(stderr.contains(message), "{}: expected `{message}` in\n{stderr}", file.display());
    assert!(stderr.contains(location), "{}: expected at `{location}`:\n{stderr}", file.display());
    assert!(!stderr.contains("panicked"), "{stderr}");
}

fn hostile(name: &str) -> PathBuf {
    Path::new("tests/in/hostile").join(name)
}

fn mkfifo(path: &Path) {
    let made = Command::new("mkfifo").arg(path).status().expect("mkfifo runs");
    assert!(made.success(), "mkfifo {}", path.display());
}

/// A small valid RGB EXR.
fn write_small_exr(path: &Path) {
    use exr::prelude::*;
    let layer = Layer::new(
        (4, 2),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        SpecificChannels::rgb(|_: Vec2<usize>| (0.5f32, 0.5f32, 0.5f32)),
    );
    Image::from_layer(layer).write().to_file(path).expect("write exr");
}

#[test]
fn devices_and_directories_named_as_inputs_are_located_diagnostics() {
    assert_located_warning(
        &hostile("sublayer_dev_zero.usda"),
        "sublayer_dev_zero.usda:3:18",
        "cannot read layer `/dev/zero`: it is a device, not a regular file",
    );
    assert_located(
        &hostile("source_dev_zero.usda"),
        "source_dev_zero.usda:13:53",
        "cannot read substance file `/dev/zero`: it is a device, not a regular file",
    );
    assert_located_warning(&hostile("sublayer_directory.usda"), "sublayer_directory.usda:3:18", "it is a directory");
    // The scene itself: no location to point at but the path, and no read.
    let (code, stderr) = check(Path::new("/dev/zero"));
    assert_eq!(code, Some(1));
    assert!(stderr.contains("cannot read `/dev/zero`: it is a device"), "{stderr}");
}

#[test]
fn fifos_named_as_inputs_never_block() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pipe = d.join("pipe.usda");
    mkfifo(&pipe);
    let (code, stderr) = check(&pipe);
    assert_eq!(code, Some(1));
    assert!(stderr.contains("it is a FIFO (named pipe), not a regular file"), "{stderr}");

    let sublayer = d.join("sublayer.usda");
    std::fs::write(&sublayer, "#usda 1.0\n(\n    subLayers = [@pipe.usda@]\n)\n").unwrap();
    assert_located_warning(&sublayer, "sublayer.usda:3:18", "cannot read layer");

    let reference = d.join("reference.usda");
    std::fs::write(&reference, "#usda 1.0\ndef Xform \"A\" (\n    references = @pipe.usda@</P>\n) {}\n").unwrap();
    assert_located_warning(&reference, "reference.usda:3:18", "it is a FIFO");

    let ash = d.join("pipe.ash");
    mkfifo(&ash);
    let source = d.join("source.usda");
    std::fs::write(
        &source,
        std::fs::read_to_string(hostile("source_dev_zero.usda")).unwrap().replace("/dev/zero", "pipe.ash"),
    )
    .unwrap();
    assert_located(&source, "source.usda:13:53", "cannot read substance file");

    let exr = d.join("pipe.exr");
    mkfifo(&exr);
    let dome = d.join("dome.usda");
    std::fs::write(&dome, "#usda 1.0\ndef DomeLight \"Sky\" {\n    asset inputs:texture:file = @pipe.exr@\n}\n")
        .unwrap();
    // A warning (the dome lights with its colour), an error under --strict.
    let (code, stderr) = check(&dome);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stderr.contains("warning: cannot read dome texture") && stderr.contains("dome.usda:3:33"), "{stderr}");
    let (code, stderr) = check_strict(&dome);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("error: cannot read dome texture") && stderr.contains("--strict"), "{stderr}");

    // A texture a shader names.
    let ash_source = format!(
        "substance t {{ node tx = texture(file: {:?}); node d = diffuse(albedo: tx.out); surface = d.bsdf; }}",
        exr.to_str().unwrap()
    );
    std::fs::write(d.join("t.ash"), ash_source).unwrap();
    let textured = d.join("textured.usda");
    std::fs::write(
        &textured,
        std::fs::read_to_string(hostile("source_dev_zero.usda"))
            .unwrap()
            .replace("/dev/zero", "t.ash")
            .replace("\"zero\"", "\"t\""),
    )
    .unwrap();
    let (code, stderr) = check(&textured);
    assert_eq!(code, Some(0), "a warning: the texture reads as black: {stderr}");
    assert!(stderr.contains("warning: cannot read texture") && stderr.contains("it is a FIFO"), "{stderr}");
    let (code, stderr) = check_strict(&textured);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("cannot read texture") && stderr.contains("it is a FIFO"), "{stderr}");
    // Located where the texture node reads its file (in the built-in node library: the
    // lowering reports at the inlined node body, not yet at the node's instantiation).
    assert!(stderr.contains("texture file named here"), "{stderr}");
}

#[test]
fn input_size_limit_is_enforced_and_raised_by_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("big.usda");
    let mut text = String::from("#usda 1.0\n");
    while text.len() < 4096 {
        text += "def Xform \"A\" {}\n";
    }
    std::fs::write(&scene, &text).unwrap();
    let path = scene.to_str().unwrap();
    let small = strata(&["layers", path, "--max-input-size", "1K"]);
    assert_eq!(small.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&small.stderr);
    assert!(stderr.contains("more than the input size limit of 1024 bytes"), "{stderr}");
    assert!(stderr.contains("--max-input-size"), "the message says how to raise it: {stderr}");
    let raised = strata(&["--max-input-size", "1M", "layers", path]);
    assert_eq!(raised.status.code(), Some(0), "{}", String::from_utf8_lossy(&raised.stderr));
}

#[test]
fn huge_texture_headers_are_refused_before_allocating() {
    // The header claims 2e6 x 2e6 pixels: a 48 TB allocation before this check.
    let limit = "more than the texture limit of 134217728 pixels (raise it with --max-texture-pixels)";
    assert_located_warning(&hostile("huge_dome_texture.usda"), "huge_dome_texture.usda:5:33", limit);
    // The same file as a shader's texture.
    let dir = tempfile::tempdir().unwrap();
    let exr = std::fs::canonicalize(hostile("huge_texture.exr")).unwrap();
    let ash = format!(
        "substance t {{ node tx = texture(file: {:?}); node d = diffuse(albedo: tx.out); surface = d.bsdf; }}",
        exr.to_str().unwrap()
    );
    std::fs::write(dir.path().join("t.ash"), ash).unwrap();
    let scene = dir.path().join("scene.usda");
    std::fs::write(
        &scene,
        std::fs::read_to_string(hostile("source_dev_zero.usda"))
            .unwrap()
            .replace("/dev/zero", "t.ash")
            .replace("\"zero\"", "\"t\""),
    )
    .unwrap();
    assert_located_warning(&scene, "texture file named here", limit);
    // A lower limit refuses an ordinary texture, with the flag named.
    let small = dir.path().join("small.exr");
    write_small_exr(&small);
    let dome = dir.path().join("dome.usda");
    std::fs::write(&dome, "#usda 1.0\ndef DomeLight \"Sky\" {\n    asset inputs:texture:file = @small.exr@\n}\n")
        .unwrap();
    let refused = strata(&["check", "--strict", dome.to_str().unwrap(), "--max-texture-pixels", "7"]);
    assert_eq!(refused.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("4 x 2 = 8 pixels, more than the texture limit of 7"));
    let allowed = strata(&["check", dome.to_str().unwrap(), "--max-texture-pixels", "8"]);
    assert_eq!(allowed.status.code(), Some(0), "{}", String::from_utf8_lossy(&allowed.stderr));
}

#[test]
fn geometry_beyond_the_scene_extent_is_an_error_before_the_bvh() {
    // 1e38 panicked inside obvhs, 1e13 took 8 s, overflowing transforms became NaN boxes.
    assert_located(&hostile("far_cylinders_1e38.usda"), "far_cylinders_1e38.usda:3:1", "`/Far` reaches (");
    assert_located(&hostile("far_cylinders_1e13.usda"), "far_cylinders_1e13.usda:3:1", "`/Far` reaches (");
    assert_located(&hostile("nan_transform.usda"), "nan_transform.usda:7:5", "`/Group/Huge` reaches (");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("far.exr");
    let render =
        strata(&["render", "tests/in/hostile/far_cylinders_1e38.usda", "--res", "8x8", "-o", out.to_str().unwrap()]);
    assert_eq!(render.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&render.stderr);
    assert!(stderr.contains("beyond the scene extent") && !stderr.contains("panicked"), "{stderr}");
    assert!(!out.exists());
}

#[test]
fn a_sublayer_cycle_is_reported_once_however_often_it_is_listed() {
    // 5 000 self-sublayers printed 563 MB of diagnostics.
    let (code, stderr) = check(&hostile("self_sublayers.usda"));
    assert_eq!(code, Some(1));
    assert_eq!(stderr.matches("sublayer cycle").count(), 1, "{stderr}");
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("many.usda");
    let list = vec!["@many.usda@"; 5000].join(", ");
    std::fs::write(&scene, format!("#usda 1.0\n(\n    subLayers = [{list}]\n)\ndef Xform \"A\" {{}}\n")).unwrap();
    let (code, stderr) = check(&scene);
    assert_eq!(code, Some(1));
    assert_eq!(stderr.matches("error: sublayer cycle").count(), 1);
    assert_eq!(stderr.matches("warning:").count(), 1, "one warning for the repeats");
    assert!(stderr.len() < 1 << 20, "{} bytes of diagnostics", stderr.len());
    assert!(stderr.contains("many.usda:3:18"), "located");
}

/// A render that would take minutes: if it fails in seconds, it failed before rendering.
const SLOW: [&str; 4] = ["--res", "4000x4000", "--spp", "10000"];

fn render_args<'a>(output: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["render", "-o", output];
    args.extend_from_slice(extra);
    args
}

fn temporaries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

#[test]
fn png_path_that_is_a_directory_fails_before_rendering_and_keeps_the_exr() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("out.exr");
    std::fs::write(&exr, "previous render").unwrap();
    std::fs::create_dir(dir.path().join("out.png")).unwrap();
    let out = strata(&render_args(exr.to_str().unwrap(), &SLOW));
    // An output that cannot be written is a resource failure (README, Rendering on a farm).
    assert_eq!(out.status.code(), Some(3));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("out.png") && stderr.contains("it is a directory"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&exr).unwrap(), "previous render", "the old EXR is intact");
    assert!(temporaries(dir.path()).is_empty(), "{:?}", temporaries(dir.path()));
}

#[test]
fn unwritable_output_directory_fails_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    // A regular file where a directory should be: unwritable even for root.
    let not_a_dir = dir.path().join("file");
    std::fs::write(&not_a_dir, "").unwrap();
    let exr = not_a_dir.join("out.exr");
    let out = strata(&render_args(exr.to_str().unwrap(), &SLOW));
    assert_eq!(out.status.code(), Some(3), "a resource failure");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("cannot create a file in"), "{stderr}");
    assert!(!stderr.contains("rendered"), "{stderr}");
}

#[test]
fn output_naming_an_input_texture_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let sky = dir.path().join("sky.exr");
    write_small_exr(&sky);
    let original = std::fs::read(&sky).unwrap();
    let scene = dir.path().join("scene.usda");
    std::fs::write(
        &scene,
        "#usda 1.0\ndef Sphere \"Ball\" {}\ndef DomeLight \"Sky\" {\n    asset inputs:texture:file = @sky.exr@\n}\n",
    )
    .unwrap();
    let tiny = ["--res", "8x8", "--spp", "1"];
    let mut args = render_args(sky.to_str().unwrap(), &tiny);
    args.insert(1, scene.to_str().unwrap());
    let out = strata(&args);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("is an input of this run; refusing to overwrite it"), "{stderr}");
    assert_eq!(std::fs::read(&sky).unwrap(), original, "the texture is untouched");
    // Through another name for the same file, too.
    let link = dir.path().join("link.exr");
    std::fs::hard_link(&sky, &link).unwrap();
    let mut args = render_args(link.to_str().unwrap(), &tiny);
    args.insert(1, scene.to_str().unwrap());
    assert_eq!(strata(&args).status.code(), Some(1));
    assert_eq!(std::fs::read(&sky).unwrap(), original);
    assert!(temporaries(dir.path()).is_empty());
    // A different output renders.
    let other = dir.path().join("render.exr");
    let mut args = render_args(other.to_str().unwrap(), &tiny);
    args.insert(1, scene.to_str().unwrap());
    let ok = strata(&args);
    assert_eq!(ok.status.code(), Some(0), "{}", String::from_utf8_lossy(&ok.stderr));
}

#[test]
fn interrupted_render_leaves_no_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("out.exr");
    let child = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(render_args(exr.to_str().unwrap(), &SLOW))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id().to_string();
    // The temporaries exist from before compilation until the end.
    let start = Instant::now();
    while temporaries(dir.path()).len() < 2 {
        assert!(start.elapsed() < DEADLINE, "no temporary files appeared");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(Command::new("kill").args(["-TERM", &pid]).status().unwrap().success());
    let status = child.wait_with_output().unwrap().status;
    assert!(!status.success());
    assert!(temporaries(dir.path()).is_empty(), "{:?}", temporaries(dir.path()));
    assert!(!exr.exists());
}

#[test]
fn temporaries_of_killed_processes_are_removed_by_the_next_run() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("out.exr");
    // Larger than any pid_max, so no live process has it.
    let stale = dir.path().join(".out.exr.2147483646.tmp");
    std::fs::write(&stale, "half a render").unwrap();
    let unrelated = dir.path().join(".other.exr.2147483646.tmp");
    std::fs::write(&unrelated, "not ours").unwrap();
    let out = strata(&render_args(exr.to_str().unwrap(), &["--res", "8x8", "--spp", "1"]));
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!stale.exists() && unrelated.exists());
    assert!(exr.exists() && exr.with_extension("png").exists());
}

/// The scene `shader_fault.usda` binds the substances of `shader_fault.ash`.
#[test]
fn shader_faults_are_counted_and_located_never_fatal() {
    // `/Bad`'s material indexes out of bounds on its upper half; `/Good` renders normally.
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("fault.exr");
    for backend in ["jit", "interp"] {
        let out = strata(&[
            "render",
            "tests/in/hostile/shader_fault.usda",
            "--res",
            "16x16",
            "--spp",
            "2",
            "--threads",
            "2",
            "--backend",
            backend,
            "-o",
            exr.to_str().unwrap(),
        ]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(0), "{stderr}");
        assert!(stderr.contains("discarded: a shader indexed an array out of bounds"), "{stderr}");
        assert!(
            stderr.contains(
                "first array index out of bounds: prim `/Bad`, material 1, slot `010`, pixel (9, 6) sample 0"
            ),
            "the same first occurrence from either backend, whatever the threads: {stderr}"
        );
        assert!(!stderr.contains("/Good"), "{stderr}");
        assert!(exr.exists());
    }
}

#[test]
fn compile_output_naming_its_source_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let ash = dir.path().join("m.ash");
    let source = "substance m { node d = diffuse(); surface = d.bsdf; }\n";
    std::fs::write(&ash, source).unwrap();
    let out = strata(&["compile", ash.to_str().unwrap(), "-o", ash.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("refusing to overwrite it"));
    assert_eq!(std::fs::read_to_string(&ash).unwrap(), source);
    assert!(temporaries(dir.path()).is_empty());
}

#[test]
fn bad_instances_and_degenerate_geometry_are_diagnosed_or_rendered_never_a_panic() {
    // Instances 1e30 away (an instanceable reference and a point of a PointInstancer): the
    // extent error, at the prim, before any BVH.
    let (code, stderr) = check(&hostile("far_instances.usda"));
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("`/Far` reaches (1e30, 0, 0), beyond the scene extent"), "{stderr}");
    assert!(stderr.contains("far_instances.usda:12:1"), "{stderr}");
    assert!(stderr.contains("`/Points` reaches (1e30, "), "{stderr}");
    assert!(stderr.contains("instance 1"), "the point is named: {stderr}");
    // Non-finite instance data: a NaN scale on an instanceable prim, an infinite
    // point-instancer scale.
    let (code, stderr) = check(&hostile("nonfinite_instances.usda"));
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("the transform of `/Bad` is not finite"), "{stderr}");
    assert!(
        stderr.contains("`scales`[1] is not finite") && stderr.contains("nonfinite_instances.usda:7:23"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"));
    // Zero-area triangles (a repeated index, collinear points), 3000 coincident copies of
    // one triangle and a zero-scale instance: warnings, and an image of what remains.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("degenerate.exr");
    let start = std::time::Instant::now();
    let render = strata(&[
        "render",
        "tests/in/hostile/degenerate_coincident.usda",
        "--res",
        "32x24",
        "--spp",
        "2",
        "-o",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&render.stderr);
    assert_eq!(render.status.code(), Some(0), "{stderr}");
    assert!(start.elapsed().as_secs() < 60, "coincident triangles must not make the build quadratic");
    assert!(stderr.contains("100 degenerate (zero-area or non-finite) triangle(s) skipped"), "{stderr}");
    assert!(stderr.contains("1 instance(s) with a singular transform (a zero scale) skipped"), "{stderr}");
    assert!(out.exists());
}

// ---- inputs that exhaust memory or output (issue 20) ------------------------------------------

/// The address-space cap the memory tests run `strata` under, as `prlimit --as=2147483648`
/// does: every input here asked for more before its fix and aborted (or panicked) under it.
const MEMORY_CAP: u64 = 2 << 30;

/// Runs `strata args` with its address space capped at `bytes`: an allocation past it fails,
/// and the run must report that as a diagnostic, never abort. Killed at [`DEADLINE`].
fn strata_capped(args: &[&str], bytes: u64) -> Output {
    use std::os::unix::process::CommandExt;
    let mut command = Command::new(env!("CARGO_BIN_EXE_strata"));
    command.args(args).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    // SAFETY: only setrlimit, async-signal-safe, runs between fork and exec.
    unsafe {
        command.pre_exec(move || {
            let limit = libc::rlimit { rlim_cur: bytes, rlim_max: bytes };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let child = command.spawn().expect("strata starts");
    let pid = child.id();
    let (send, receive) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = send.send(child.wait_with_output());
    });
    receive.recv_timeout(DEADLINE).map(|o| o.expect("strata runs")).unwrap_or_else(|_| {
        let _ = Command::new("kill").args(["-KILL", &pid.to_string()]).status();
        panic!("strata {args:?} did not finish within {DEADLINE:?}")
    })
}

/// Exit code and stderr of [`strata_capped`] under [`MEMORY_CAP`], asserting that nothing
/// aborted or panicked.
fn capped(args: &[&str]) -> (Option<i32>, String) {
    let out = strata_capped(args, MEMORY_CAP);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("memory allocation of") && !stderr.contains("panicked"), "{args:?}: {stderr}");
    (out.status.code(), stderr)
}

#[test]
fn a_corrupt_count_in_a_crate_is_a_located_error_never_an_abort() {
    // Byte 4041 of tests/fixtures/usd/binary/kitchen.usdc set to 0xff: a token value rep gets
    // both the array and the inlined bit, and openusd read an array of 2.3e17 elements.
    let file = hostile("kitchen_byte_4041.usdc");
    let (code, stderr) = capped(&["check", file.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("malformed usdc") && stderr.contains("past the end of the file"), "{stderr}");
    assert!(stderr.contains("kitchen_byte_4041.usdc:"), "located: {stderr}");
    // As a sublayer: a warning, the stage composes without it.
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root.usda");
    let sub = std::fs::canonicalize(&file).unwrap();
    std::fs::write(&root, format!("#usda 1.0\n(\n    subLayers = [@{}@]\n)\n", sub.display())).unwrap();
    assert_located_warning(&root, "root.usda:3:18", "is not valid USD: malformed usdc");
    // Every value of that byte, and 0xff at every byte of the file, in process: an abort
    // here ends the test binary.
    let good = std::fs::read("tests/fixtures/usd/binary/kitchen.usdc").unwrap();
    let convert = |bytes: &[u8]| {
        let mut sources = strata::diag::SourceMap::new();
        let mut diags = strata::diag::Diagnostics::new();
        strata::scene::usdc::convert("k.usdc", bytes, Path::new("."), &mut sources, &mut diags);
    };
    for value in 0..=255u8 {
        let mut bytes = good.clone();
        bytes[4041] = value;
        convert(&bytes);
    }
    for at in 0..good.len() {
        let mut bytes = good.clone();
        bytes[at] = 0xff;
        convert(&bytes);
    }
}

/// A 16 x 16 JPEG written by `image`, its frame header then made to claim 16384 x 8192
/// (2^27 pixels, the pixel limit): what the 1.4 KB JPEG of the issue did.
fn jpeg_claiming_2_to_the_27_pixels() -> Vec<u8> {
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut bytes)
        .encode(&[128u8; 16 * 16 * 3], 16, 16, image::ExtendedColorType::Rgb8)
        .expect("encodes");
    let sof = bytes.windows(2).position(|w| w == [0xff, 0xc0]).expect("a baseline frame header");
    // Marker, length (2), precision (1), height (2), width (2).
    bytes[sof + 5..sof + 7].copy_from_slice(&8192u16.to_be_bytes());
    bytes[sof + 7..sof + 9].copy_from_slice(&16384u16.to_be_bytes());
    bytes
}

#[test]
fn textures_past_the_memory_budget_are_their_fallback_with_a_located_warning() {
    // A 130 KB PNG of 16384 x 8192 grey pixels: 128 MiB decoded, 2 GiB as float texels. It
    // peaked at 4.2 GB and panicked inside `image` under a 2 GiB cap.
    let message = "decoding the 16384 x 8192 image needs";
    let (code, stderr) = capped(&["check", hostile("huge_grey_dome.usda").to_str().unwrap()]);
    assert_eq!(code, Some(0), "a warning: the dome lights with its colour: {stderr}");
    assert!(stderr.contains("warning: cannot read dome texture") && stderr.contains(message), "{stderr}");
    assert!(stderr.contains("huge_grey_dome.usda:6:33") && stderr.contains("--max-memory"), "{stderr}");
    // The same budget set by the flag, as a shader's texture; and the JPEG.
    let dir = tempfile::tempdir().unwrap();
    let jpeg = dir.path().join("claim.jpg");
    std::fs::write(&jpeg, jpeg_claiming_2_to_the_27_pixels()).unwrap();
    for texture in [std::fs::canonicalize(hostile("huge_grey.png")).unwrap(), jpeg] {
        let ash = format!(
            "substance t {{ node tx = texture(file: {:?}); node d = diffuse(albedo: tx.out); surface = d.bsdf; }}",
            texture.to_str().unwrap()
        );
        std::fs::write(dir.path().join("t.ash"), ash).unwrap();
        let scene = dir.path().join("scene.usda");
        let source = std::fs::read_to_string(hostile("source_dev_zero.usda")).unwrap();
        std::fs::write(&scene, source.replace("/dev/zero", "t.ash").replace("\"zero\"", "\"t\"")).unwrap();
        // A shader's texture is kept at its source precision (8-bit, with mips: 171 MiB for
        // the PNG, 512 MiB for the JPEG), which the cap's budget holds; a smaller budget
        // refuses it from the header.
        let (code, stderr) = capped(&["check", scene.to_str().unwrap()]);
        assert_eq!(code, Some(0), "{stderr}");
        assert!(!stderr.contains("cannot read texture"), "{stderr}");
        let (code, stderr) = capped(&["check", scene.to_str().unwrap(), "--max-memory", "100M"]);
        assert_eq!(code, Some(0), "{stderr}");
        assert!(stderr.contains("warning: cannot read texture") && stderr.contains(message), "{stderr}");
        assert!(stderr.contains("texture file named here"), "located: {stderr}");
        assert!(stderr.contains("more than the memory limit of 100.0 MiB (raise it with --max-memory)"), "{stderr}");
    }
}

#[test]
fn a_film_past_the_memory_budget_is_an_error_naming_its_size_before_rendering() {
    // RenderSettings asking for 16384 x 16384: about 250 bytes per pixel, 62 GiB. It aborted.
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("film.exr");
    let exr = exr.to_str().unwrap();
    let (code, stderr) = capped(&["render", hostile("film_16384.usda").to_str().unwrap(), "-o", exr]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("a 16384 x 16384 film of 30 channels needs 62.0 GiB"), "{stderr}");
    assert!(stderr.contains("--max-memory"), "the flag is named: {stderr}");
    // 8192 x 8192 aborted too.
    let (code, stderr) =
        capped(&["render", hostile("film_16384.usda").to_str().unwrap(), "--res", "8192x8192", "-o", exr]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("a 8192 x 8192 film"), "{stderr}");
    assert!(!Path::new(exr).exists());
    // The flag sets the budget either way.
    let small = ["render", "--res", "100x100", "--spp", "1", "-o", exr];
    let out = strata(&[&small[..], &["--max-memory", "1M"]].concat());
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("a 100 x 100 film"));
    let out = strata(&[&small[..], &["--max-memory", "64M"]].concat());
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
}

/// A PointInstancer of `n` spheres, as usda text.
fn point_instancer_text(n: usize) -> String {
    use std::fmt::Write;
    let mut text = String::from("#usda 1.0\ndef Sphere \"Ball\" { double radius = 0.1 }\n");
    text += "def PointInstancer \"Points\" {\n    rel prototypes = [</Ball>]\n    int[] protoIndices = [";
    text += &"0, ".repeat(n);
    text += "]\n    point3f[] positions = [";
    for i in 0..n {
        write!(text, "({}, {}, {}), ", i % 1000, i / 1000 % 1000, i / 1_000_000).unwrap();
    }
    text + "]\n}\n"
}

#[test]
fn instances_past_the_memory_budget_are_one_error_and_big_arrays_parse_in_bounded_memory() {
    // A committed instancer over the budget the flag sets.
    let file = hostile("instances_budget.usda");
    let out = strata(&["check", file.to_str().unwrap(), "--max-memory", "256K"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("point instancer `/Points`: 1000 instances (about"), "{stderr}");
    assert!(stderr.contains("instances_budget.usda:5:") && stderr.contains("--max-memory"), "{stderr}");
    assert_eq!(strata(&["check", file.to_str().unwrap()]).status.code(), Some(0));
    // 4 million instances (under the 2^22 limit) peaked at 2.5 GB and panicked in obvhs'
    // builder under a 2 GiB cap; 10 million points (180 MB of text) grew a 2 GiB token buffer.
    let dir = tempfile::tempdir().unwrap();
    for (n, message) in
        [(4_000_000, "4000000 instances (about"), (10_000_000, "would have 10000000 instances, more than 4194304")]
    {
        let scene = dir.path().join("points.usda");
        std::fs::write(&scene, point_instancer_text(n)).unwrap();
        let (code, stderr) = capped(&["check", scene.to_str().unwrap()]);
        assert_eq!(code, Some(1), "{stderr}");
        assert!(stderr.contains(message) && stderr.contains("points.usda:"), "{n}: {stderr}");
    }
}

#[test]
fn diagnostics_keep_only_what_is_shown_and_elide_long_names() {
    // 4 MiB of `}`: four million errors, 2.1 GB when every one was kept.
    let dir = tempfile::tempdir().unwrap();
    let braces = dir.path().join("braces.ash");
    std::fs::write(&braces, "}".repeat(4 << 20)).unwrap();
    let (code, stderr) = capped(&["check", braces.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("more errors in") && stderr.len() < 64 << 10, "{} bytes", stderr.len());
    // A 22 000-character prim name in every one of 50 messages: 1 MB of stderr.
    let (code, stderr) = check(&hostile("long_name.usda"));
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains(&format!("`/N{}…{}/S0` (22004 characters)", "a".repeat(38), "a".repeat(37))), "{stderr}");
    assert!(stderr.len() < 64 << 10, "{} bytes of diagnostics", stderr.len());
}

#[test]
fn a_closed_stderr_ends_the_run_with_its_exit_code_not_a_panic() {
    // `strata check … 2>&1 | head -1`: the pipe closes after the first line and every later
    // write fails with EPIPE; it panicked (exit 101).
    let mut fds = [0; 2];
    // SAFETY: pipe writes two descriptors into the array.
    assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
    // SAFETY: the read end is ours and closed once.
    unsafe { libc::close(fds[0]) };
    // SAFETY: the write end is ours; the Stdio owns it from here.
    let closed = unsafe { <std::fs::File as std::os::fd::FromRawFd>::from_raw_fd(fds[1]) };
    let status = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["check", hostile("long_name.usda").to_str().unwrap()])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::from(closed))
        .status()
        .unwrap();
    assert_eq!(status.code(), Some(1), "the check's own exit code");
}
