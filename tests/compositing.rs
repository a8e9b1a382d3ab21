//! What a compositor gets from `strata render` (issue 12): the EXR's channels, sample types
//! and header attributes read back with the `exr` crate; progress lines in a log; camera
//! choice (`--camera`, UsdRender `RenderSettings`); lights hidden from the camera.

mod common;

use common::strata;
use exr::meta::attribute::AttributeValue;
use exr::prelude::FlatSamples;
use std::path::{Path, PathBuf};

/// Renders `scene` (`None`: the default scene) into `dir/out.exr` with `extra` arguments.
fn render(dir: &Path, scene: Option<&Path>, extra: &[&str]) -> (PathBuf, String) {
    let out = dir.join("out.exr");
    let mut args = vec!["render", "-o", out.to_str().unwrap(), "--spp", "2", "--seed", "3"];
    if let Some(scene) = scene {
        args.push(scene.to_str().unwrap());
    }
    args.extend_from_slice(extra);
    let output = strata(&args);
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "{stderr}");
    (out, stderr)
}

type ExrImage = strata::render::film::output::ExrFile;

fn read(path: &Path) -> ExrImage {
    strata::render::film::output::read_exr(path).expect("the EXR reads back")
}

fn channel<'a>(image: &'a ExrImage, name: &str) -> &'a FlatSamples {
    let list = &image.layer_data.channel_data.list;
    &list.iter().find(|c| c.name.to_string() == name).unwrap_or_else(|| panic!("no channel `{name}`")).sample_data
}

fn floats(image: &ExrImage, name: &str) -> Vec<f32> {
    match channel(image, name) {
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
        FlatSamples::U32(_) => panic!("`{name}` is an integer channel"),
    }
}

fn text(image: &ExrImage, key: &str) -> String {
    match image.layer_data.attributes.other.get(&exr::meta::attribute::Text::from(key)) {
        Some(AttributeValue::Text(t)) => t.to_string(),
        other => panic!("attribute `{key}`: {other:?}"),
    }
}

/// A copy of the default scene in `dir`, edited by `edit`, so tests can add cameras, render
/// settings and light attributes to a scene known to render.
fn default_scene_with(dir: &Path, edit: impl FnOnce(String) -> String) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/default");
    std::fs::copy(root.join("default.ash"), dir.join("default.ash")).unwrap();
    let text = std::fs::read_to_string(root.join("default.usda")).unwrap();
    let path = dir.join("scene.usda");
    std::fs::write(&path, edit(text)).unwrap();
    path
}

/// Prints the channels and header attributes of a file (run with `--nocapture` to see them).
fn describe(image: &ExrImage) -> String {
    let layer = &image.layer_data;
    let mut s = String::from("channels:");
    for c in &layer.channel_data.list {
        let ty = match c.sample_data {
            FlatSamples::F16(_) => "half",
            FlatSamples::F32(_) => "float",
            FlatSamples::U32(_) => "uint",
        };
        s += &format!(" {}({ty})", c.name);
    }
    let a = &layer.attributes;
    s += &format!("\nsoftware: {:?}\nchromaticities: {:?}", a.software_name, image.attributes.chromaticities);
    s += &format!("\nworldToCamera: {:?}\nworldToNDC: {:?}", a.world_to_camera, a.world_to_normalized_device);
    s += &format!("\nnearClipPlane: {:?} farClipPlane: {:?}", a.near_clip_plane, a.far_clip_plane);
    let mut other: Vec<_> = a.other.iter().map(|(k, v)| format!("\n{k} = {v:?}")).collect();
    other.sort();
    s + &other.concat()
}

#[test]
fn default_render_exr_has_the_compositing_channels_and_header() {
    let dir = tempfile::tempdir().unwrap();
    let (out, _) = render(dir.path(), None, &["--res", "48x32"]);
    let image = read(&out);
    println!("{}", describe(&image));
    let names: Vec<String> = image.layer_data.channel_data.list.iter().map(|c| c.name.to_string()).collect();
    for name in strata::render::film::BUILTIN_CHANNELS {
        assert!(names.contains(&name.to_string()), "{name} missing from {names:?}");
    }
    assert!(!names.iter().any(|n| n.ends_with(".X") || n.ends_with(".Y") || n.ends_with(".Z")), "{names:?}");
    for c in &image.layer_data.channel_data.list {
        assert!(!matches!(c.sample_data, FlatSamples::F16(_)), "{} is half without --half", c.name);
    }
    // Z: camera-space depth, finite everywhere, the documented miss value where nothing was hit.
    let (z, a) = (floats(&image, "Z"), floats(&image, "A"));
    assert!(z.iter().all(|v| v.is_finite()));
    assert_eq!(text(&image, "strata/Z/miss"), "1e10");
    let misses = a.iter().filter(|&&a| a == 0.0).count();
    assert!(misses > 0 && misses < a.len(), "the default view shows sky and geometry");
    for (z, a) in z.iter().zip(&a) {
        if *a == 0.0 {
            assert_eq!(*z, 1e10);
        } else {
            // The camera is 6.5 units from the balls; the floor reaches to 12.5 behind them.
            assert!(*z > 0.5 && *z < 20.0, "{z}");
        }
    }
    // N is unit length where hit; P is 0 on misses and near the scene elsewhere.
    let n: Vec<Vec<f32>> = ["N.R", "N.G", "N.B"].iter().map(|c| floats(&image, c)).collect();
    let p: Vec<Vec<f32>> = ["P.R", "P.G", "P.B"].iter().map(|c| floats(&image, c)).collect();
    for i in 0..a.len() {
        let len = (n[0][i] * n[0][i] + n[1][i] * n[1][i] + n[2][i] * n[2][i]).sqrt();
        if a[i] == 0.0 {
            assert_eq!([p[0][i], p[1][i], p[2][i]], [0.0; 3]);
        } else {
            assert!((len - 1.0).abs() < 1e-3, "|N| = {len}");
            assert!(p.iter().all(|c| c[i].abs() <= 6.01), "P outside the floor");
        }
    }
    // Header: spaces, colour space, camera, settings.
    for (key, value) in [("strata/N/space", "world"), ("strata/P/space", "world"), ("strata/spp", "2")] {
        assert_eq!(text(&image, key), value);
    }
    for key in [
        "strata/seed",
        "strata/maxDepth",
        "strata/rrDepth",
        "strata/backend",
        "strata/layerMode",
        "strata/scene",
        "strata/camera",
    ] {
        text(&image, key);
    }
    assert_eq!(text(&image, "strata/camera"), "/World/Camera");
    let attrs = &image.layer_data.attributes;
    assert!(attrs.software_name.as_ref().is_some_and(|s| s.to_string().starts_with("strata ")));
    let chroma = image.attributes.chromaticities.expect("chromaticities");
    assert_eq!((chroma.red.0, chroma.white.1), (0.64, 0.3290));
    // worldToCamera (Imath row vectors: translation in the last row) puts the camera, at
    // (0, 1.4, 6.5), at the origin.
    let m = attrs.world_to_camera.expect("worldToCamera");
    let row_vector = |m: &[f32; 16], p: [f32; 3]| -> [f32; 4] {
        let v = [p[0], p[1], p[2], 1.0];
        std::array::from_fn(|col| (0..4).map(|row| v[row] * m[row * 4 + col]).sum())
    };
    let eye = row_vector(&m, [0.0, 1.4, 6.5]);
    assert!(eye[..3].iter().all(|v| v.abs() < 1e-4), "{eye:?}");
    // OpenEXR's standard conventions (ImfStandardAttributes): camera space is left-handed
    // with +Z the viewing direction, so a hit point's camera z is its depth (`Z`); NDC runs
    // from (0, 0) at the top-left of the display window to (1, 1) at its bottom-right. Every
    // pixel's position `P`, projected back, lands on that pixel.
    let ndc = attrs.world_to_normalized_device.expect("worldToNDC");
    let (w, h) = (48, 32);
    let (mut checked, mut depth_matches) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if a[i] < 1.0 {
                continue; // an edge pixel averages positions of several surfaces
            }
            let world = [p[0][i], p[1][i], p[2][i]];
            let camera = row_vector(&m, world);
            // `Z` is the nearest sample's depth, `P` the samples' mean position: never nearer.
            assert!(camera[2] > 0.999 * z[i], "pixel ({x}, {y}): camera z {} vs Z {}", camera[2], z[i]);
            depth_matches += usize::from((camera[2] - z[i]).abs() < 0.05 * z[i]);
            let clip = row_vector(&ndc, world);
            let (u, v) = (clip[0] / clip[3], clip[1] / clip[3]);
            let (px, py) = (u * w as f32, v * h as f32);
            assert!(
                (px - (x as f32 + 0.5)).abs() < 1.0 && (py - (y as f32 + 0.5)).abs() < 1.0,
                "pixel ({x}, {y}): P projects to ({px}, {py})"
            );
            // Camera x grows to the right of the image, y upwards.
            if (u - 0.5).abs() > 0.05 {
                assert_eq!(camera[0] > 0.0, u > 0.5, "pixel ({x}, {y}): camera x {}", camera[0]);
            }
            if (v - 0.5).abs() > 0.05 {
                assert_eq!(camera[1] > 0.0, v < 0.5, "pixel ({x}, {y}): camera y {}", camera[1]);
            }
            checked += 1;
        }
    }
    assert!(checked > w * h / 3, "{checked} pixels checked");
    assert!(depth_matches > checked * 8 / 10, "camera z is Z in {depth_matches} of {checked} pixels");
}

#[test]
fn half_flag_stores_colour_as_half_and_data_as_float() {
    let dir = tempfile::tempdir().unwrap();
    let (out, _) = render(dir.path(), None, &["--res", "16x12", "--half"]);
    let image = read(&out);
    for c in &image.layer_data.channel_data.list {
        let name = c.name.to_string();
        let half = matches!(c.sample_data, FlatSamples::F16(_));
        let expect_half = strata::render::film::output::is_half_channel(&name);
        assert_eq!(half, expect_half, "{name}");
    }
    for name in ["R", "G", "B", "A", "albedo.R", "N.G"] {
        assert!(matches!(channel(&image, name), FlatSamples::F16(_)), "{name}");
    }
    for name in ["Z", "P.R", "P.G", "P.B"] {
        assert!(matches!(channel(&image, name), FlatSamples::F32(_)), "{name}");
    }
}

#[test]
fn a_log_gets_plain_progress_lines_and_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let (_, stderr) = render(dir.path(), None, &["--res", "20x40"]);
    let progress: Vec<&str> = stderr.lines().filter(|l| l.starts_with("render: ")).collect();
    // 40 rows: every 5 % step (2 rows) is reached, each printed once, in order.
    assert_eq!(progress.len(), 20, "{stderr}");
    assert!(progress.iter().all(|l| l.contains("s elapsed, about ") && l.ends_with(" s left")), "{stderr}");
    assert!(progress[19].contains("100% (40/40 rows)"), "{stderr}");
    assert!(!stderr.contains('\r') && !stderr.contains('\u{1b}'), "no terminal control in a log");
    let summary = stderr.lines().last().unwrap();
    assert!(summary.starts_with("rendered 20x40 at 2 spp"), "{summary}");
    assert!(summary.contains("compile ") && summary.contains("samples/s"), "{summary}");
}

/// The default scene with a second camera `/World/Top` and, if `settings`, a
/// `RenderSettings` prim choosing it at 64x16.
fn two_camera_scene(dir: &Path, settings: bool) -> PathBuf {
    default_scene_with(dir, |text| {
        let top = r#"
def Camera "Top" {
    float focalLength = 20
    float horizontalAperture = 36
    float3 xformOp:translate = (0, 15, 0)
    float3 xformOp:rotateXYZ = (-90, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}
"#;
        let mut text = text.replacen("def DomeLight \"Sky\"", &format!("{top}\n    def DomeLight \"Sky\""), 1);
        if settings {
            text += "\ndef Scope \"Render\" {\n    def RenderSettings \"Settings\" {\n        rel camera = </World/Top>\n        uniform int2 resolution = (64, 16)\n    }\n}\n";
        }
        text
    })
}

fn camera_height(image: &ExrImage) -> f32 {
    // Camera position = −Rᵀt; for these cameras the world-to-camera of a point at the camera is
    // 0, so solve for y from the translation row of the (orthonormal) matrix.
    let m = image.layer_data.attributes.world_to_camera.expect("worldToCamera");
    let t = [m[12], m[13], m[14]];
    -(0..3).map(|k| m[4 + k] * t[k]).sum::<f32>()
}

#[test]
fn camera_flag_and_render_settings_choose_the_camera_and_resolution() {
    let dir = tempfile::tempdir().unwrap();
    let plain = two_camera_scene(dir.path(), false);
    // Without settings: the first camera, and --camera picks another.
    let (out, _) = render(dir.path(), Some(&plain), &["--res", "16x12"]);
    let first = read(&out);
    assert_eq!(text(&first, "strata/camera"), "/World/Camera");
    assert!((camera_height(&first) - 1.4).abs() < 1e-4, "{}", camera_height(&first));
    let (out, _) = render(dir.path(), Some(&plain), &["--res", "16x12", "--camera", "/World/Top"]);
    let top = read(&out);
    assert_eq!(text(&top, "strata/camera"), "/World/Top");
    assert!((camera_height(&top) - 15.0).abs() < 1e-3, "{}", camera_height(&top));
    // A RenderSettings prim: its camera and resolution, unless --res / --camera say otherwise.
    let with_settings = two_camera_scene(dir.path(), true);
    let (out, _) = render(dir.path(), Some(&with_settings), &[]);
    let chosen = read(&out);
    assert_eq!(text(&chosen, "strata/camera"), "/World/Top");
    assert_eq!((chosen.layer_data.size.0, chosen.layer_data.size.1), (64, 16));
    let (out, _) = render(dir.path(), Some(&with_settings), &["--res", "8x8", "--camera", "/World/Camera"]);
    let overridden = read(&out);
    assert_eq!(text(&overridden, "strata/camera"), "/World/Camera");
    assert_eq!((overridden.layer_data.size.0, overridden.layer_data.size.1), (8, 8));
}

#[test]
fn a_camera_that_is_missing_or_not_a_camera_is_an_error_listing_the_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let scene = two_camera_scene(dir.path(), false);
    let out = dir.path().join("out.exr");
    for (camera, why) in [("/World/Nope", "does not exist"), ("/World/Floor", "is a Mesh, not a Camera")] {
        let output = strata(&["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--camera", camera]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success());
        assert!(stderr.contains(why), "{stderr}");
        assert!(stderr.contains("cameras: /World/Camera, /World/Top"), "{stderr}");
        assert!(!out.exists(), "no output on error");
    }
}

#[test]
fn a_dome_hidden_from_the_camera_leaves_the_background_empty_but_still_lights() {
    let dir = tempfile::tempdir().unwrap();
    let args = ["--res", "32x24", "--max-depth", "2"];
    let (out, _) = render(dir.path(), None, &args);
    let seen = read(&out);
    let hidden_scene = default_scene_with(dir.path(), |text| {
        text.replacen(
            "float inputs:intensity = 0.6",
            "float inputs:intensity = 0.6\n        bool strata:visibleToCamera = false",
            1,
        )
    });
    let (out, _) = render(dir.path(), Some(&hidden_scene), &args);
    let hidden = read(&out);
    let (a, a_seen) = (floats(&hidden, "A"), floats(&seen, "A"));
    assert_eq!(a, a_seen, "coverage does not change");
    let (r, r_seen) = (floats(&hidden, "R"), floats(&seen, "R"));
    let (b, b_seen) = (floats(&hidden, "B"), floats(&seen, "B"));
    let mut background = 0;
    for i in 0..a.len() {
        if a[i] == 0.0 {
            background += 1;
            assert!(b_seen[i] > 0.0, "the visible dome is in RGB with A = 0");
            assert_eq!((r[i], b[i]), (0.0, 0.0), "a hidden dome leaves RGB at 0");
        }
    }
    assert!(background > 0);
    // Surfaces are still lit by the (hidden) dome: fully covered pixels render identically.
    let covered: Vec<usize> = (0..a.len()).filter(|&i| a[i] == 1.0).collect();
    assert!(!covered.is_empty());
    assert!(covered.iter().all(|&i| r[i] == r_seen[i]), "the dome still lights what the camera sees");
}

#[test]
fn a_cryptomatte_pixel_decodes_to_its_prim_path_through_the_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let (out, _) = render(dir.path(), None, &["--res", "48x32", "--half"]);
    let image = read(&out);
    // The header: one layer, named, with the specification's hash and conversion.
    let other = &image.layer_data.attributes.other;
    let key = other
        .iter()
        .find_map(|(k, v)| {
            let k = k.to_string();
            (k.starts_with("cryptomatte/")
                && k.ends_with("/name")
                && matches!(v, AttributeValue::Text(t) if *t == *"CryptoObject"))
            .then(|| k.split('/').nth(1).unwrap().to_string())
        })
        .expect("a CryptoObject layer in the header");
    assert_eq!(text(&image, &format!("cryptomatte/{key}/hash")), "MurmurHash3_32");
    assert_eq!(text(&image, &format!("cryptomatte/{key}/conversion")), "uint32_to_float32");
    let manifest: std::collections::HashMap<String, String> =
        serde_json::from_str(&text(&image, &format!("cryptomatte/{key}/manifest"))).expect("JSON manifest");
    let by_id: std::collections::HashMap<&str, &str> = manifest.iter().map(|(k, v)| (v.as_str(), k.as_str())).collect();
    // IDs stay float even with --half.
    for c in ["CryptoObject00.R", "CryptoObject00.G", "CryptoObject01.A"] {
        assert!(matches!(channel(&image, c), FlatSamples::F32(_)), "{c}");
    }
    let (w, h) = (48, 32);
    let decode = |x: usize, y: usize| -> (String, f32) {
        let id = floats(&image, "CryptoObject00.R")[y * w + x];
        let coverage = floats(&image, "CryptoObject00.G")[y * w + x];
        let hex = format!("{:08x}", id.to_bits());
        (by_id.get(hex.as_str()).map_or(format!("<unknown {hex}>"), |s| s.to_string()), coverage)
    };
    // The image centre sees the centre ball; low on the left, the floor; the top, only sky.
    assert_eq!(decode(w / 2, h / 2), ("/World/Balls/Center".to_string(), 1.0));
    assert_eq!(decode(1, h - 2).0, "/World/Floor");
    assert_eq!(floats(&image, "CryptoObject00.G")[w / 2], 0.0, "sky has no coverage");
    // The composed material (the slot stack) decodes the same way through its own layer.
    let material_key = strata::render::film::cryptomatte::layer_key("CryptoMaterial");
    assert_eq!(text(&image, &format!("cryptomatte/{material_key}/name")), "CryptoMaterial");
    let materials: std::collections::HashMap<String, String> =
        serde_json::from_str(&text(&image, &format!("cryptomatte/{material_key}/manifest"))).expect("JSON manifest");
    let centre = floats(&image, "CryptoMaterial00.R")[(h / 2) * w + w / 2];
    let hex = format!("{:08x}", centre.to_bits());
    let name = materials.iter().find(|(_, v)| **v == hex).map(|(k, _)| k.as_str());
    assert_eq!(name, Some("000=/Looks/Clay | 000::010=/Looks/RedPaint | 050=/Looks/Dirt | 050::010=/Looks/DirtMarker"));
    // Coverage over the ranks sums to alpha where at most four prims share a pixel.
    let a = floats(&image, "A");
    let ranks: Vec<Vec<f32>> = ["CryptoObject00.G", "CryptoObject00.A", "CryptoObject01.G", "CryptoObject01.A"]
        .iter()
        .map(|c| floats(&image, c))
        .collect();
    for i in 0..a.len() {
        let sum: f32 = ranks.iter().map(|r| r[i]).sum();
        assert!((sum - a[i]).abs() < 2e-3, "pixel {i}: coverage {sum} vs A {}", a[i]);
    }
}
