//! Rendering through compiled materials, end to end: the JIT and the interpreter render
//! identical images, so do optimised and unoptimised materials, and `strata render` writes
//! whole outputs or none.

mod common;

use std::path::Path;
use std::process::Command;
use strata::backend::BackendKind;
use strata::render::{Image, LayerMode, RenderSettings, render};
use strata::session::SceneSource;

fn render_scene(path: Option<&str>, backend: BackendKind, optimize: bool, mode: LayerMode) -> Image {
    let (session, scene) = common::stage_scene(SceneSource::from_path(path.map(Path::new)), backend, optimize);
    let refs = session.compiled().expect("compiled").refs();
    let settings = RenderSettings {
        width: 40,
        height: 30,
        spp: 2,
        seed: 7,
        threads: Some(2),
        max_depth: 4,
        mode,
        ..Default::default()
    };
    let (image, stats) = render(&scene, &refs, &settings, None).expect("renders");
    assert_eq!(stats.invalid_samples(), 0, "{stats}");
    image
}

#[test]
fn jit_and_interpreter_render_identical_images() {
    let jit = render_scene(None, BackendKind::Jit, true, LayerMode::Stochastic);
    let interp = render_scene(None, BackendKind::Interp, true, LayerMode::Stochastic);
    assert_eq!(jit, interp, "the backends must agree bit for bit");
    // The image is not trivially black: the default scene is lit.
    let r = jit.f32_channel("R").unwrap();
    assert!(r.iter().sum::<f32>() / r.len() as f32 > 0.05);
}

/// Both layer modes: weighted evaluation calls every mask, stochastic picking takes a
/// compile-time constant mask from the layer's metadata instead of calling the shader (the
/// optimised material knows more constants than the unoptimised one), and uses the same
/// random numbers either way, so the same seed must give the same bits.
#[test]
fn optimiser_on_and_off_render_identical_images() {
    // layers_card: a mask from a substance input (0.3), a constant once the optimiser folds it.
    for scene in [None, Some("scenes/paper/oscilloscope.usda"), Some("scenes/compare/layers_card.usda")] {
        for mode in [LayerMode::Stochastic, LayerMode::Weighted] {
            let on = render_scene(scene, BackendKind::Jit, true, mode);
            let off = render_scene(scene, BackendKind::Jit, false, mode);
            assert_eq!(on, off, "{scene:?}, {mode:?}: constant folding and pruning must not change the image");
        }
    }
}

#[test]
fn custom_channel_of_the_default_scene_reaches_the_image() {
    // `dirt_marker` (override 050::010) adds a `dirt` AOV on the dirty balls only.
    let image = render_scene(None, BackendKind::Jit, true, LayerMode::Stochastic);
    let dirt = image.f32_channel("dirt").expect("a dirt channel");
    assert!(dirt.iter().all(|x| (0.0..=1.0).contains(x)));
    assert!(dirt.iter().any(|x| *x > 0.0), "some pixel sees the dirt layer");
}

#[test]
fn cli_renders_the_default_scene_and_refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("out.exr");
    let run = |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().unwrap();
    let ok = run(&["render", "--res", "32x24", "--spp", "1", "-o", exr.to_str().unwrap()]);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    assert!(exr.exists() && exr.with_extension("png").exists());

    let missing = dir.path().join("never.exr");
    let bad = run(&["render", "no/such/scene.usda", "-o", missing.to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("no/such/scene.usda"));
    assert!(!missing.exists(), "a failed render writes nothing");

    let bad_res = run(&["render", "--res", "0x10", "-o", missing.to_str().unwrap()]);
    assert!(!bad_res.status.success());
    assert!(String::from_utf8_lossy(&bad_res.stderr).contains("outside 1..=16384"));

    let scene_copy = dir.path().join("scene.usda");
    std::fs::write(&scene_copy, "#usda 1.0\n").unwrap();
    let clobber = run(&["render", "--res", "8x8", "-o", scene_copy.to_str().unwrap()]);
    assert_eq!(clobber.status.code(), Some(1));
    assert_eq!(std::fs::read_to_string(&scene_copy).unwrap(), "#usda 1.0\n", "the input is untouched");

    // An output that cannot be written is a resource failure (3), not bad input (1): a farm
    // retries the one and not the other (README, "Rendering on a farm").
    let unwritable = run(&["render", "--res", "8x8", "--spp", "1", "-o", "/nonexistent/dir/out.exr"]);
    assert_eq!(unwritable.status.code(), Some(3));
}

/// A 2×2 quad at y = 0 (st along +x and +z), a camera looking straight down at its centre and a
/// white dome; `substance` is bound to the quad.
fn quad_scene(dir: &Path, ash: &str) -> std::path::PathBuf {
    std::fs::write(dir.join("quad.ash"), ash).unwrap();
    let usda = r#"#usda 1.0
(
    upAxis = "Y"
)
def Xform "World"
{
    def Camera "Camera"
    {
        float focalLength = 200
        float horizontalAperture = 20
        float verticalAperture = 20
        float3 xformOp:translate = (0, 5, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
    def DomeLight "Sky"
    {
        float inputs:intensity = 1
    }
    def Mesh "Quad"
    {
        rel material:slotBinding:_000 = </Looks/Q>
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
    }
}
def Material "Looks"
{
    def Material "Q"
    {
        def Shader "Surface"
        {
            uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @quad.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "q"
        }
    }
}
"#;
    let path = dir.join("quad.usda");
    std::fs::write(&path, usda).unwrap();
    path
}

/// The mean of the `N` AOV over the image.
fn mean_normal(scene: &Path) -> [f32; 3] {
    let image = render_scene(Some(scene.to_str().unwrap()), BackendKind::Jit, true, LayerMode::Stochastic);
    let mean = |c: &str| {
        let v = image.f32_channel(c).unwrap();
        v.iter().sum::<f32>() / v.len() as f32
    };
    [mean("N.R"), mean("N.G"), mean("N.B")]
}

fn assert_close(got: [f32; 3], want: [f32; 3]) {
    let d = (0..3).map(|k| (got[k] - want[k]).abs()).fold(0.0, f32::max);
    assert!(d < 2e-3, "got {got:?}, want {want:?}");
}

#[test]
fn bump_from_displacement_tilts_the_shading_normal() {
    // Height 0.5·x: the surface rises along +x, so the normal leans to −x by atan(0.5).
    let dir = tempfile::tempdir().unwrap();
    let scene = quad_scene(
        dir.path(),
        "shader slope(output float out = 0.0) { out = P[0] * 0.5; }
         substance q { node h = slope(); node b = bump(height: h.out, scale: 1.0); node d = diffuse();
                       surface = d.bsdf; displacement = b.out; }",
    );
    let k = 1.0 / 1.25f32.sqrt();
    assert_close(mean_normal(&scene), [-0.5 * k, k, 0.0]);
    // Without the displacement product the normal is the geometric one.
    let flat = quad_scene(dir.path(), "substance q { node d = diffuse(); surface = d.bsdf; }");
    assert_close(mean_normal(&flat), [0.0, 1.0, 0.0]);
}

#[test]
fn normal_map_applies_in_the_tangent_frame() {
    // Tangent-space (0.5, 0, 1) with the tangent along +x (dPdu): world (0.5, 1, 0), normalised.
    let dir = tempfile::tempdir().unwrap();
    let scene = quad_scene(
        dir.path(),
        "substance q { node m = normal_map(map: color(0.75, 0.5, 1.0)); node d = diffuse();
                       surface = d.bsdf; normal = m.out; }",
    );
    let k = 1.0 / 1.25f32.sqrt();
    assert_close(mean_normal(&scene), [0.5 * k, k, 0.0]);
}

/// A sample whose radiance overflows f32 is counted and left out of the pixel, never summed:
/// two domes of 3e38 each add up to more than an f32 holds wherever a path escapes. (The film
/// tests a sample's values once against its exact sums' fast range; whatever fails it must
/// still meet the finite check.)
#[test]
fn overflowing_samples_are_counted_and_left_out() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy("scenes/compare/matte.ash", dir.path().join("matte.ash")).unwrap();
    let usda = std::fs::read_to_string("scenes/compare/matte_ball.usda").unwrap();
    let dome = "    def DomeLight \"Sky\"\n    {\n        float inputs:intensity = 1\n    }\n";
    assert!(usda.contains(dome), "the matte ball's dome moved");
    let hot = dome.replace("= 1", "= 3e38");
    let path = dir.path().join("overflow.usda");
    std::fs::write(&path, usda.replace(dome, &format!("{hot}{}", hot.replace("\"Sky\"", "\"Sky2\"")))).unwrap();
    let (session, scene) = common::stage_scene(SceneSource::from_path(Some(path.as_path())), BackendKind::Jit, true);
    let refs = session.compiled().expect("compiled").refs();
    let settings = RenderSettings { width: 16, height: 12, spp: 2, seed: 7, threads: Some(2), ..Default::default() };
    let (image, stats) = render(&scene, &refs, &settings, None).expect("renders");
    // Most paths escape to the domes (every one from the floor or the ball does, in the end).
    assert!(
        stats.nonfinite_samples > stats.samples / 2,
        "{} of {} samples discarded",
        stats.nonfinite_samples,
        stats.samples
    );
    for name in ["R", "G", "B", "A"] {
        assert!(image.f32_channel(name).unwrap().iter().all(|v| v.is_finite()), "{name} is not finite");
    }
}
