//! End-to-end render tests with the constant test-double material.

use super::{Image, geometry::xform::tests::stage};
use crate::abi::ChannelKind;
use crate::abi::{MaterialCode, ShaderError};
use crate::render::film::{RenderSettings, RenderStats, render};
use crate::render::integrator::LayerMode;
use crate::render::scene::Scene;
use crate::render::testing::{ConstLayer, ConstMaterial};

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

/// Asserts that channel `name`'s image mean is `expected` within 5 standard errors `se` of that
/// mean (plus 1e-5 for f32 accumulation). The callers derive `se` from their sample count and
/// the per-sample spread of the estimator, and size the render so that a 2 % bias exceeds the
/// bound.
fn assert_mean_within(image: &Image, name: &str, expected: f32, se: f32) {
    let m = mean(image, name);
    let bound = 5.0 * se + 1e-5;
    assert!((m - expected).abs() < bound, "{name}: mean {m}, expected {expected} ± {bound} (5 se)");
}

/// The standard error of the image mean when each of `samples` samples is one of two values
/// `a` (with probability `p`) or `b`: sqrt(p (1 − p) / samples) |a − b|. This is the spread
/// of an unstratified pick; the film stratifies the first pick per pixel, which only lowers it.
fn pick_standard_error(p: f32, a: f32, b: f32, samples: u32) -> f32 {
    (p * (1.0 - p) / samples as f32).sqrt() * (a - b).abs()
}

/// 32 × 32 pixels at 256 spp: 262 144 samples, enough for the pick tests below to see a 2 %
/// bias at 5 standard errors (a pick of probability 0.3 between values 1 apart has a standard
/// error of 0.0009 on the mean).
fn pick_settings() -> RenderSettings {
    RenderSettings { width: 32, height: 32, ..settings(256) }
}

#[test]
fn diffuse_plane_under_constant_dome_renders_its_albedo() {
    let scene = plane_scene(DOME);
    let a = [0.5, 0.25, 0.8];
    let (image, stats) = run(&scene, &ConstMaterial::diffuse(a), &settings(64));
    // The dome is cosine-sampled, as the diffuse lobe is: every sample is exactly the albedo,
    // so only f32 rounding is allowed.
    assert_rgb(&image, a, 1e-4);
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
    let s = pick_settings();
    let (image, _) = run(&scene, &material, &s);
    // Each sample is exactly the picked layer's albedo (a cosine-sampled dome under a diffuse
    // lobe): the only spread is the pick's, 0.5 between top and bottom.
    let samples = s.spp * (s.width * s.height) as u32;
    for (k, name) in ["R", "G", "B"].into_iter().enumerate() {
        let expected = 0.5 * top[k] + 0.5 * bottom[k];
        assert_mean_within(&image, name, expected, pick_standard_error(0.5, top[k], bottom[k], samples));
    }
}

#[test]
fn transparency_shows_the_dome_through_a_masked_layer() {
    let scene = plane_scene(DOME);
    let a = [0.2, 0.6, 0.4];
    let material = ConstMaterial::new(vec![ConstLayer::diffuse(0.3, a)], &[]);
    let s = pick_settings();
    let (image, _) = run(&scene, &material, &s);
    // A sample is the layer's albedo (probability 0.3) or the unit dome behind it.
    let samples = s.spp * (s.width * s.height) as u32;
    for (k, name) in ["R", "G", "B"].into_iter().enumerate() {
        assert_mean_within(&image, name, 0.3 * a[k] + 0.7, pick_standard_error(0.3, a[k], 1.0, samples));
    }
    // Coverage counts only camera samples that stopped on the layer.
    assert_mean_within(&image, "A", 0.3, pick_standard_error(0.3, 1.0, 0.0, samples));
}

/// An opaque grey base under masks 0.6 (red) and 0.25 (blue).
fn three_diffuse_layers() -> ConstMaterial {
    ConstMaterial::new(
        vec![
            ConstLayer::diffuse(1.0, [0.8, 0.8, 0.8]),
            ConstLayer::diffuse(0.6, [0.9, 0.2, 0.1]),
            ConstLayer::diffuse(0.25, [0.1, 0.3, 0.9]),
        ],
        &[],
    )
}

#[test]
fn stochastic_and_weighted_evaluation_agree() {
    let scene = plane_scene(
        r#"def DomeLight "Sky" { float inputs:intensity = 0.5 }
def Sphere "Ball" { double radius = 0.3  double3 xformOp:translate = (0, 0.3, 0)  uniform token[] xformOpOrder = ["xformOp:translate"] }
def DistantLight "Sun" { float inputs:intensity = 2  float inputs:angle = 5  bool inputs:normalize = 1
    float3 xformOp:rotateXYZ = (-40, 20, 0)  uniform token[] xformOpOrder = ["xformOp:rotateXYZ"] }"#,
    );
    let material = three_diffuse_layers();
    let mut s = pick_settings();
    let (stochastic, _) = run(&scene, &material, &s);
    s.mode = LayerMode::Weighted;
    let (weighted, _) = run(&scene, &material, &s);
    // Two independent estimators of one image: the mean per-pixel difference is 0 within 5
    // standard errors of that difference (pixels are independent). At this sample count the
    // bound is below 0.5 % of each channel, so a 2 % bias of either mode fails.
    for name in ["R", "G", "B", "albedo.R", "albedo.B"] {
        let (a, b) = (stochastic.f32_channel(name).unwrap(), weighted.f32_channel(name).unwrap());
        let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| f64::from(*x) - f64::from(*y)).collect();
        let n = d.len() as f64;
        let mean_d = d.iter().sum::<f64>() / n;
        let var = d.iter().map(|x| (x - mean_d).powi(2)).sum::<f64>() / (n - 1.0);
        let bound = 5.0 * (var / n).sqrt() + 1e-6;
        let level = f64::from(mean(&weighted, name));
        assert!(bound < 0.005 * level, "{name}: the bound {bound} is too loose to see a 2 % bias of {level}");
        assert!(mean_d.abs() < bound, "{name}: stochastic − weighted = {mean_d}, 5 se = {bound}");
    }
}

/// `LayerMode::Auto` resolves per material (weighted for a 3-layer stack, stochastic for one
/// layer), says so in the stats, and renders exactly what the forced mode renders; the two
/// forced modes agree in expectation (`stochastic_and_weighted_evaluation_agree`).
#[test]
fn auto_layer_mode_chooses_per_material_and_reports_it() {
    let scene = plane_scene(r#"def DomeLight "Sky" { float inputs:intensity = 0.5 }"#);
    let stack = three_diffuse_layers();
    let single = ConstMaterial::new(vec![ConstLayer::diffuse(1.0, [0.5, 0.5, 0.5])], &[]);
    for (material, pickable, chosen) in [(&stack, 3, LayerMode::Weighted), (&single, 1, LayerMode::Stochastic)] {
        let mut s = settings(4);
        s.mode = LayerMode::Auto;
        let (auto, stats) = run(&scene, material, &s);
        let [m] = stats.layer_modes.as_slice() else { panic!("one material: {:?}", stats.layer_modes) };
        assert_eq!((m.pickable, m.mode, m.automatic), (pickable, chosen, true));
        assert_eq!(stats.evals_line().contains("(auto)"), pickable > 1, "{}", stats.evals_line());
        s.mode = chosen;
        let (forced, stats) = run(&scene, material, &s);
        assert_eq!(auto, forced, "auto must render what {chosen:?} renders");
        assert!(!stats.layer_modes[0].automatic);
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
    let s = pick_settings();
    let (image, _) = run(&scene, &material, &s);
    // Each sample's channel is the layer's value (probability 0.5) or 0.
    let samples = s.spp * (s.width * s.height) as u32;
    for (name, value) in [("wear", 1.0), ("tint.R", 0.25), ("tint.G", 0.5), ("tint.B", 1.0)] {
        assert_mean_within(&image, name, 0.5 * value, pick_standard_error(0.5, value, 0.0, samples));
    }
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

/// Farm splits and progressive passes: sample ranges rendered apart and merged as exact sums
/// give the image of one render, bit for bit, whatever the split and merge order — integer
/// channels (the nearest sample's id), float and colour channels, and Cryptomatte included.
#[test]
fn sample_ranges_merged_as_sums_are_the_full_render() {
    use crate::render::film::{Window, WindowSums, image_from_sums, render_sums};
    let scene = plane_scene(DOME);
    let mut layer = ConstLayer::diffuse(0.5, [0.5, 0.5, 0.5]);
    layer.channels = vec![7.0, 1.0, 0.25, 0.5, 1.0];
    let channels = [("id", ChannelKind::Integer), ("wear", ChannelKind::Float), ("tint", ChannelKind::Color)];
    let material = ConstMaterial::new(vec![layer], &channels);
    let s = RenderSettings { spp: 11, ..pick_settings() };
    let (full, _) = run(&scene, &material, &s);
    for bounds in [vec![0, 11], vec![0, 5, 11], vec![0, 1, 2, 4, 6, 9, 10, 11]] {
        let mut parts: Vec<WindowSums> = bounds
            .windows(2)
            .map(|b| {
                let window = Window { region: None, samples: Some(b[0]..b[1]) };
                render_sums(&scene, &[&material], &s, &window, None).expect("render").2
            })
            .collect();
        parts.reverse();
        let mut merged = parts[0].clone();
        for part in &parts[1..] {
            merged.merge(part).expect("disjoint");
        }
        assert!(image_from_sums(&scene, &[&material], &merged) == full, "{bounds:?}");
    }
}
