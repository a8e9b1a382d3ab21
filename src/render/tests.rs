//! End-to-end render tests with the constant test-double material.

use super::film::{RenderSettings, RenderStats, render};
use super::integrator::LayerMode;
use super::scene::Scene;
use super::testing::{ConstLayer, ConstMaterial};
use super::{Image, xform::tests::stage};
use crate::abi::{MaterialCode, ShaderError};
use crate::front::graph::ChannelKind;

/// A 2000 × 2000 quad at y = 0 seen from straight above through a narrow lens, plus `extra`.
fn plane_scene(extra: &str) -> Scene {
    let text = format!(
        r#"#usda 1.0
def Camera "Cam" {{
    float focalLength = 50
    float horizontalAperture = 5
    double3 xformOp:translate = (0, 2, 0)
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
}}
def Mesh "Plane" {{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1000, 0, -1000), (-1000, 0, 1000), (1000, 0, 1000), (1000, 0, -1000)]
}}
{extra}"#
    );
    let (stage, mut diags) = stage(&text);
    let scene = Scene::from_stage(&stage, &|_| Some(0), &mut diags).expect("scene");
    assert!(!diags.has_errors());
    scene
}

fn settings(spp: u32) -> RenderSettings {
    RenderSettings {
        width: 8,
        height: 8,
        spp,
        seed: 1,
        threads: Some(2),
        max_depth: 6,
        mode: LayerMode::Stochastic,
        ..Default::default()
    }
}

fn run(scene: &Scene, material: &dyn MaterialCode, s: &RenderSettings) -> (Image, RenderStats) {
    render(scene, &[material], s, None).expect("render")
}

fn mean(image: &Image, name: &str) -> f32 {
    let c = image.f32_channel(name).unwrap();
    c.iter().sum::<f32>() / c.len() as f32
}

fn assert_rgb(image: &Image, expected: [f32; 3], tolerance: f32) {
    for (k, name) in ["R", "G", "B"].into_iter().enumerate() {
        let m = mean(image, name);
        assert!((m - expected[k]).abs() < tolerance, "{name}: mean {m}, expected {}", expected[k]);
        for &v in image.f32_channel(name).unwrap() {
            assert!((v - expected[k]).abs() < 6.0 * tolerance, "{name}: pixel {v}, expected {}", expected[k]);
        }
    }
}

const DOME: &str = "def DomeLight \"Sky\" { float inputs:intensity = 1 }";

#[test]
fn diffuse_plane_under_constant_dome_renders_its_albedo() {
    let scene = plane_scene(DOME);
    let a = [0.5, 0.25, 0.8];
    let (image, stats) = run(&scene, &ConstMaterial::diffuse(a), &settings(64));
    assert_rgb(&image, a, 0.02);
    assert_eq!(stats.invalid_samples(), 0);
    assert!(image.f32_channel("A").unwrap().iter().all(|&a| a == 1.0));
    assert!(image.f32_channel("albedo.R").unwrap().iter().all(|&v| (v - 0.5).abs() < 1e-6));
    assert!(image.f32_channel("N.G").unwrap().iter().all(|&v| (v - 1.0).abs() < 1e-5));
    // Z is camera-space depth: the plane is 2 units along the viewing axis at every pixel
    // (ray distance would grow off-axis).
    assert!(image.f32_channel("Z").unwrap().iter().all(|&z| (z - 2.0).abs() < 1e-3), "Z");
    // P is the first hit, on the plane 2 units below the camera.
    let (cam_y, p_y) = (scene.camera.origin().y, image.f32_channel("P.G").unwrap());
    assert!(p_y.iter().all(|&y| (y - (cam_y - 2.0)).abs() < 1e-3), "P.G");
}

#[test]
fn two_masked_layers_render_the_rule_5_weighted_sum() {
    let scene = plane_scene(DOME);
    let (top, bottom) = ([0.9, 0.1, 0.1], [0.1, 0.1, 0.9]);
    let material = ConstMaterial::new(vec![ConstLayer::diffuse(1.0, bottom), ConstLayer::diffuse(0.5, top)], &[]);
    let (image, _) = run(&scene, &material, &settings(128));
    let expected: [f32; 3] = std::array::from_fn(|k| 0.5 * top[k] + 0.5 * bottom[k]);
    assert_rgb(&image, expected, 0.03);
}

#[test]
fn transparency_shows_the_dome_through_a_masked_layer() {
    let scene = plane_scene(DOME);
    let a = [0.2, 0.6, 0.4];
    let material = ConstMaterial::new(vec![ConstLayer::diffuse(0.3, a)], &[]);
    let (image, _) = run(&scene, &material, &settings(128));
    let expected: [f32; 3] = std::array::from_fn(|k| 0.3 * a[k] + 0.7);
    assert_rgb(&image, expected, 0.03);
    // Coverage counts only camera samples that stopped on the layer.
    assert!((mean(&image, "A") - 0.3).abs() < 0.03);
}

#[test]
fn stochastic_and_weighted_evaluation_agree() {
    let scene = plane_scene(
        r#"def DomeLight "Sky" { float inputs:intensity = 0.5 }
def Sphere "Ball" { double radius = 0.3  double3 xformOp:translate = (0, 0.3, 0)  uniform token[] xformOpOrder = ["xformOp:translate"] }
def DistantLight "Sun" { float inputs:intensity = 2  float inputs:angle = 5  bool inputs:normalize = 1
    float3 xformOp:rotateXYZ = (-40, 20, 0)  uniform token[] xformOpOrder = ["xformOp:rotateXYZ"] }"#,
    );
    let material = ConstMaterial::new(
        vec![
            ConstLayer::diffuse(1.0, [0.8, 0.8, 0.8]),
            ConstLayer::diffuse(0.6, [0.9, 0.2, 0.1]),
            ConstLayer::diffuse(0.25, [0.1, 0.3, 0.9]),
        ],
        &[],
    );
    let mut s = settings(256);
    let (stochastic, _) = run(&scene, &material, &s);
    s.mode = LayerMode::Weighted;
    let (weighted, _) = run(&scene, &material, &s);
    for name in ["R", "G", "B", "albedo.R", "albedo.B"] {
        let (a, b) = (mean(&stochastic, name), mean(&weighted, name));
        assert!((a - b).abs() < 0.02 * a.max(b).max(0.2), "{name}: stochastic {a}, weighted {b}");
    }
}

#[test]
fn same_seed_is_bit_identical_with_one_or_two_threads() {
    let scene = plane_scene(
        r#"def DomeLight "Sky" {}
def Sphere "Ball" { double radius = 0.4 }"#,
    );
    let material = ConstMaterial::new(
        vec![ConstLayer::diffuse(1.0, [0.5, 0.5, 0.5]), ConstLayer::diffuse(0.5, [0.9, 0.1, 0.1])],
        &[],
    );
    let mut s = settings(8);
    s.threads = Some(1);
    let (one, _) = run(&scene, &material, &s);
    s.threads = Some(2);
    let (two, _) = run(&scene, &material, &s);
    assert_eq!(one, two);
    s.seed = 2;
    let (other, _) = run(&scene, &material, &s);
    assert_ne!(one, other);
}

#[test]
fn custom_channels_average_to_their_layer_coverage() {
    let scene = plane_scene(DOME);
    let mut layer = ConstLayer::diffuse(0.5, [0.5, 0.5, 0.5]);
    // Layout: id (integer), wear (float), tint (color); the layer emits id 7, wear 1, tint (0.25, 0.5, 1).
    layer.channels = vec![7.0, 1.0, 0.25, 0.5, 1.0];
    let channels = [("id", ChannelKind::Integer), ("wear", ChannelKind::Float), ("tint", ChannelKind::Color)];
    let material = ConstMaterial::new(vec![layer], &channels);
    let (image, _) = run(&scene, &material, &settings(256));
    assert!((mean(&image, "wear") - 0.5).abs() < 0.03, "{}", mean(&image, "wear"));
    assert!((mean(&image, "tint.B") - 0.5).abs() < 0.03);
    assert!((mean(&image, "tint.R") - 0.125).abs() < 0.02);
    // Integer channels are not averaged: each pixel keeps one sample's id (0 or 7).
    let ids = image.u32_channel("id").unwrap();
    assert!(ids.iter().all(|&v| v == 0 || v == 7));
    assert!(ids.contains(&7));
}

/// Rule 7 for integer channels: a pixel holds an id one of its samples hit, never a blend,
/// and over many pixels each id's share is its layer's weight, at any sample count and in
/// weighted evaluation too. (Sample 0's id, as before, showed the top layer in every pixel:
/// its pick lies in the first stratum.)
#[test]
fn integer_channels_keep_an_id_a_sample_hit_with_each_layers_share() {
    let scene = plane_scene(DOME);
    let channels = [("layerid", ChannelKind::Integer)];
    let layer = |mask: f32, id: f32| {
        let mut l = ConstLayer::diffuse(mask, [0.5, 0.5, 0.5]);
        l.channels = vec![id];
        l
    };
    for top_mask in [0.5f32, 0.3] {
        let material = ConstMaterial::new(vec![layer(1.0, 3.0), layer(top_mask, 7.0)], &channels);
        for (spp, mode) in [
            (1, LayerMode::Stochastic),
            (16, LayerMode::Stochastic),
            (64, LayerMode::Stochastic),
            (16, LayerMode::Weighted),
        ] {
            let s = RenderSettings { width: 32, height: 32, spp, mode, ..settings(spp) };
            let (image, _) = run(&scene, &material, &s);
            let ids = image.u32_channel("layerid").unwrap();
            assert!(ids.iter().all(|&v| v == 3 || v == 7), "{spp} spp {mode:?}: an id no layer has");
            let share = ids.iter().filter(|&&v| v == 7).count() as f32 / ids.len() as f32;
            // 1024 pixels: the binomial spread of the share is at most 0.016.
            assert!(
                (share - top_mask).abs() < 0.05,
                "mask {top_mask}, {spp} spp, {mode:?}: the top id holds {share} of the pixels"
            );
        }
    }
}

#[test]
fn nan_closures_and_shader_errors_are_counted_not_rendered() {
    let scene = plane_scene(DOME);
    let mut nan = ConstLayer::diffuse(1.0, [0.5, 0.5, 0.5]);
    nan.closure.params[1] = f32::NAN;
    let (image, stats) = run(&scene, &ConstMaterial::new(vec![nan], &[]), &settings(4));
    assert_eq!(stats.nonfinite_closures, 8 * 8 * 4);
    let [fault] = &stats.first_faults[..] else { panic!("{:?}", stats.first_faults) };
    assert_eq!(fault.kind, super::FaultKind::NonFiniteClosure);
    assert!(fault.slot.is_some(), "a surface's closure belongs to one layer: {fault:?}");
    assert!(image.channels.iter().all(|c| match &c.data {
        super::ChannelData::F32(v) => v.iter().all(|x| !x.is_nan()),
        super::ChannelData::U32(_) => true,
    }));
    let mut failing = ConstMaterial::diffuse([0.5; 3]);
    failing.fail = Some(ShaderError::LoopBudget);
    let (image, stats) = run(&scene, &failing, &settings(4));
    assert_eq!(stats.loop_budget_errors, 8 * 8 * 4);
    assert!(image.f32_channel("R").unwrap().iter().all(|&v| v == 0.0));
    assert!(stats.to_string().contains("iteration budget"));
    // The first occurrence is located: prim, material and pixel (every sample fails here,
    // so the first is pixel (0, 0), sample 0, whatever the thread count).
    let [fault] = &stats.first_faults[..] else { panic!("{:?}", stats.first_faults) };
    assert_eq!(fault.kind, super::FaultKind::LoopBudget);
    assert_eq!(fault.prim, scene.prims[0].path);
    assert_eq!((fault.material, fault.pixel, fault.sample), (0, (0, 0), 0));
    let text = stats.to_string();
    assert!(text.contains(&format!("first loop budget exceeded: prim `{}`, material 0", fault.prim)), "{text}");
}

#[test]
fn distant_light_irradiance_on_a_diffuse_plane() {
    // Sun 60° from the zenith: E = intensity · cos 60° = 2 · 0.5 = 1, so L = albedo / π · E.
    // The normalised 10° sun gives the same irradiance as a delta sun (its cone is above the horizon).
    for sun in [
        r#"def DistantLight "Sun" { float inputs:intensity = 2  float inputs:angle = 0
    float xformOp:rotateX = -30  uniform token[] xformOpOrder = ["xformOp:rotateX"] }"#,
        r#"def DistantLight "Sun" { float inputs:intensity = 2  float inputs:angle = 10  bool inputs:normalize = 1
    float xformOp:rotateX = -30  uniform token[] xformOpOrder = ["xformOp:rotateX"] }"#,
    ] {
        let scene = plane_scene(sun);
        let a = [0.6, 0.3, 0.9];
        let (image, _) = run(&scene, &ConstMaterial::diffuse(a), &settings(16));
        let expected = a.map(|a| a / std::f32::consts::PI);
        assert_rgb(&image, expected, 0.01);
    }
}

#[test]
fn bad_material_index_is_an_error() {
    let scene = plane_scene(DOME);
    let err = render(&scene, &[], &settings(1), None).unwrap_err();
    assert!(err.to_string().contains("material 0"));
}
