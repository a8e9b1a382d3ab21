//! Production assets as their authors see them (issue 19): a stage without lights is lit as
//! usdview lights it, what USD composes around is a warning (an error only with `--strict`)
//! and the EXR records both, and textures in every format exporters write are read.

mod common;

use common::strata;

use exr::meta::attribute::AttributeValue;
use std::path::{Path, PathBuf};
use strata::render::scene::{DEFAULT_CAMERA_LIGHT_IRRADIANCE, DEFAULT_DOME_RADIANCE, DefaultLights, SceneOptions};
use strata::session::{SceneSource, Session, SessionOptions};

/// A large white quad (no material: the default white diffuse) facing a camera on its axis,
/// and no light.
const UNLIT_QUAD: &str = r#"#usda 1.0
def Camera "Cam" {
    double3 xformOp:translate = (0, 0, 5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Mesh "Quad" {
    uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-10, -10, 0), (10, -10, 0), (10, 10, 0), (-10, 10, 0)]
}
"#;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn build(
    path: &Path,
    lights: DefaultLights,
) -> (strata::render::Scene, Vec<std::sync::Arc<dyn strata::abi::MaterialCode>>, String) {
    let passes = strata::ir::wired::PassOptions { optimize: true, ..Default::default() };
    let options = SessionOptions { backend: strata::backend::BackendKind::Jit, passes, ..Default::default() };
    let mut session = Session::open(SceneSource::File(path.to_path_buf()), options);
    session.compile_or_report().unwrap_or_else(|e| panic!("{e}"));
    let options = SceneOptions { default_lights: lights, ..Default::default() };
    if session.prepare(&options).is_none() {
        panic!("{}", session.diagnostics().render(session.sources()));
    }
    let said = session.diagnostics().render(session.sources());
    let (scene, compiled) = session.into_scene().expect("prepared");
    (scene, compiled.materials, said)
}

#[test]
fn an_unlit_stage_is_lit_by_a_camera_light_and_a_dim_dome() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "unlit.usda", UNLIT_QUAD);
    let (scene, materials, said) = build(&path, DefaultLights::WhenUnlit);
    assert!(scene.default_lights);
    assert_eq!(scene.lights.len(), 2);
    assert!(said.contains("the stage has no lights: it is lit by a light that travels with the camera"), "{said}");
    assert!(!said.contains("warning"), "{said}");
    let image = common::render_scene(&scene, &materials, &common::settings(16, 16, 64, 1, 8));
    // Closed form for a white Lambert plane facing the camera: the camera light's
    // irradiance E·cosθ / π, θ between the normal (+Z) and the light's direction from the
    // camera frame (−forward + 0.35·up − 0.25·right), plus the unoccluded dome's radiance.
    // (A light straight from the eye would give 0.9: the test tells them apart.)
    let cos = 1.0 / (1.0f64 + 0.35 * 0.35 + 0.25 * 0.25).sqrt();
    let want =
        f64::from(DEFAULT_CAMERA_LIGHT_IRRADIANCE) * cos / std::f64::consts::PI + f64::from(DEFAULT_DOME_RADIANCE);
    for channel in ["R", "G", "B"] {
        // Each sample picks one of the two lights: the pixels are noisy, their mean is not.
        let pixels: Vec<f64> = image.f32_channel(channel).unwrap().iter().map(|&v| f64::from(v)).collect();
        let n = pixels.len() as f64;
        let mean = pixels.iter().sum::<f64>() / n;
        let spread = (pixels.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
        assert!((mean - want).abs() < 4.0 * spread + 1e-3, "{channel}: mean {mean} ± {spread}, want {want}");
    }
    assert!(image.f32_channel("A").unwrap().iter().all(|&a| a == 1.0));

    // Turned off: black, with the old warning.
    let (scene, materials, said) = build(&path, DefaultLights::Never);
    assert!(!scene.default_lights && scene.lights.is_empty());
    assert!(said.contains("warning: the scene has no lights: the image will be black"), "{said}");
    let image = common::render_scene(&scene, &materials, &common::settings(4, 4, 4, 1, 8));
    assert!(image.f32_channel("R").unwrap().iter().all(|&v| v == 0.0));

    // A stage with any light gets nothing added.
    let lit = write(dir.path(), "lit.usda", &format!("{UNLIT_QUAD}def DistantLight \"Sun\" {{}}\n"));
    let (scene, _, said) = build(&lit, DefaultLights::WhenUnlit);
    assert!(!scene.default_lights && scene.lights.len() == 1, "{said}");
    assert!(!said.contains("no lights"), "{said}");
}

fn header_text(path: &Path, key: &str) -> String {
    let image = strata::render::film::output::read_exr(path).expect("the EXR reads back");
    match image.layer_data.attributes.other.get(&exr::meta::attribute::Text::from(key)) {
        Some(AttributeValue::Text(t)) => t.to_string(),
        other => panic!("attribute `{key}`: {other:?}"),
    }
}

/// An unlit sphere whose UsdPreviewSurface reads a texture that is not there, twice.
const MISSING_TEXTURE: &str = r#"#usda 1.0
def Sphere "Ball" ( prepend apiSchemas = ["MaterialBindingAPI"] ) {
    rel material:binding = </Looks/Mat>
}
def Sphere "Other" ( prepend apiSchemas = ["MaterialBindingAPI"] ) {
    double3 xformOp:translate = (3, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    rel material:binding = </Looks/Mat2>
}
def Scope "Looks" {
    def Material "Mat" {
        token outputs:surface.connect = </Looks/Mat/Surface.outputs:surface>
        def Shader "Surface" {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </Looks/Mat/Tex.outputs:rgb>
            token outputs:surface
        }
        def Shader "Tex" {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @missing.png@
            float4 inputs:fallback = (0.5, 0.25, 0.125, 1)
            int inputs:isSRGB = 1
            float3 outputs:rgb
        }
    }
    def Material "Mat2" {
        token outputs:surface.connect = </Looks/Mat2/Surface.outputs:surface>
        def Shader "Surface" {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </Looks/Mat2/Tex.outputs:rgb>
            token outputs:surface
        }
        def Shader "Tex" {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @also_missing.png@
            float3 outputs:rgb
        }
    }
}
"#;

#[test]
fn what_usd_composes_around_is_one_warning_per_kind_and_strict_makes_it_fatal() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write(dir.path(), "scene.usda", MISSING_TEXTURE);
    let out = dir.path().join("out.exr");
    let args = ["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--res", "16x12", "--spp", "2"];
    let run = strata(&args);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    // Two missing textures: one warning, located at the first, counting the second.
    assert_eq!(stderr.matches("warning: cannot open texture").count(), 1, "{stderr}");
    assert!(stderr.contains("scene.usda:20:") && stderr.contains("and 1 more warning of this kind"), "{stderr}");
    // The exporter extra `isSRGB` (UsdShade's readers ignore it) raises nothing.
    assert!(!stderr.contains("isSRGB"), "{stderr}");
    assert!(stderr.contains("the stage has no lights"), "{stderr}");
    assert_eq!(header_text(&out, "strata/warnings"), "2");
    assert!(header_text(&out, "strata/defaultLights").starts_with("camera light + dome"));

    // --strict: an error, exit 1, and nothing written.
    let strict_out = dir.path().join("strict.exr");
    let mut strict = args.to_vec();
    strict[3] = strict_out.to_str().unwrap();
    strict.push("--strict");
    let run = strata(&strict);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("error: cannot open texture") && stderr.contains("--strict"), "{stderr}");
    assert!(!strict_out.exists() && !strict_out.with_extension("png").exists());
    let run = strata(&["check", "--strict", scene.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(1));
    let run = strata(&["check", scene.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(0));
}

#[test]
fn textures_in_every_exporter_format_decode_to_the_written_texels() {
    use image::{ImageFormat, Rgb, RgbImage};
    use strata::runtime::texture::{ColorSpace, decode_texture, decode_texture_named, srgb_to_linear};
    // 2×1: pure red and a mid grey, written by the `image` crate's encoders.
    let written = RgbImage::from_fn(2, 1, |x, _| if x == 0 { Rgb([255, 0, 0]) } else { Rgb([128, 128, 128]) });
    for (format, name) in [(ImageFormat::Tga, "a.tga"), (ImageFormat::Bmp, "a.bmp"), (ImageFormat::Tiff, "a.tif")] {
        let mut bytes = std::io::Cursor::new(Vec::new());
        written.write_to(&mut bytes, format).unwrap();
        let bytes = bytes.into_inner();
        let texture = decode_texture_named(&bytes, Some(Path::new(name)), ColorSpace::Auto, 100)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((texture.width, texture.height), (2, 1), "{name}");
        assert_eq!(texture.texels[0], [1.0, 0.0, 0.0, 1.0], "{name}");
        let grey = srgb_to_linear(128.0 / 255.0);
        assert!(texture.texels[1][..3].iter().all(|&c| (c - grey).abs() < 1e-6), "{name}: {:?}", texture.texels[1]);
        let raw = decode_texture_named(&bytes, Some(Path::new(name)), ColorSpace::Raw, 100).unwrap();
        assert!((raw.texels[1][0] - 128.0 / 255.0).abs() < 1e-6, "{name}");
    }
    // TGA has no signature: without a name it is not guessed.
    let mut tga = std::io::Cursor::new(Vec::new());
    written.write_to(&mut tga, ImageFormat::Tga).unwrap();
    assert!(decode_texture(tga.get_ref(), ColorSpace::Auto, 100).unwrap_err().contains("not a supported image format"));
    // 16-bit PNG: raw under `auto` (only 8-bit colour is sRGB), full precision.
    let deep = image::ImageBuffer::<Rgb<u16>, _>::from_fn(1, 1, |_, _| Rgb([65535, 32768, 1]));
    let mut png = std::io::Cursor::new(Vec::new());
    deep.write_to(&mut png, ImageFormat::Png).unwrap();
    let texture = decode_texture(png.get_ref(), ColorSpace::Auto, 100).unwrap();
    assert_eq!(texture.texels[0][0], 1.0);
    assert!((texture.texels[0][1] - 32768.0 / 65535.0).abs() < 1e-6, "{:?}", texture.texels[0]);
}
