//! Reference tests of layered light transport: scenes whose right answer is known in closed
//! form, rendered through the whole path tracer. Every expected value below comes from an
//! analytic formula written here, independently of the renderer's own code (the rectangle's
//! irradiance from Lambert's polygon formula, the disk's and sphere's from their solid angles),
//! never from an earlier render.
//!
//! Tolerances come from the estimator's own variance: the camera sees a patch of floor a
//! few hundredths of a unit wide, over which the expected radiance is constant to better than
//! 1e-4, so the pixels are independent estimates of one value; the test allows
//! `3σ` of their mean (σ from the pixels' own spread) plus 1e-4 for the patch.

use crate::abi::MaterialCode;
use crate::render::film::{RenderSettings, render};
use crate::render::geometry::xform::tests::stage;
use crate::render::integrator::LayerMode;
use crate::render::scene::Scene;
use crate::render::testing::{ConstLayer, ConstMaterial};
use glam::DVec3;
use std::f64::consts::PI;

/// Albedo of the floor.
const FLOOR: f32 = 0.5;

/// The scenes' common start: a camera 20 units above a 2000-unit floor, looking down.
const CAMERA_OVER_FLOOR: &str = r#"#usda 1.0
def Camera "Cam" {
    float focalLength = 50
    float horizontalAperture = 0.05
    double3 xformOp:translate = (0, 20, 0)
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
}
def Mesh "Floor" {
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1000, 0, -1000), (-1000, 0, 1000), (1000, 0, 1000), (1000, 0, -1000)]
}"#;

/// A floor (y = 0, 2000 units wide) seen straight down from y = 20 through a lens 0.03° wide,
/// an optional sheet at y = 0.5 between the floor and the lights, and `lights`.
fn sheet_scene(lights: &str, sheet: bool) -> Scene {
    let sheet = if sheet {
        r#"def Mesh "Sheet" {
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1000, 0.5, -1000), (-1000, 0.5, 1000), (1000, 0.5, 1000), (1000, 0.5, -1000)]
}"#
    } else {
        ""
    };
    let text = format!(
        r#"{CAMERA_OVER_FLOOR}
{sheet}
{lights}"#
    );
    let (stage, mut diags) = stage(&text);
    let scene = Scene::from_stage(&stage, &|path| Some(usize::from(path == "/Sheet")), &mut diags).expect("scene");
    assert!(!diags.has_errors());
    scene
}

/// Mean of channel `R` and the standard error of that mean, from the pixels' spread.
fn mean_and_error(scene: &Scene, materials: &[&dyn MaterialCode], spp: u32, mode: LayerMode) -> (f64, f64) {
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp,
        seed: 7,
        threads: Some(2),
        max_depth: 32,
        mode,
        ..Default::default()
    };
    let (image, stats) = render(scene, materials, &settings, None).expect("render");
    assert_eq!(stats.invalid_samples(), 0);
    let r = image.f32_channel("R").unwrap();
    let n = r.len() as f64;
    let mean = r.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = r.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Irradiance at the origin (normal +y) from a uniformly emitting convex polygon of radiance
/// 1, by Lambert's formula: `E = ½ Σ θ_k (n · ĝ_k)`, with `θ_k` the angle each edge subtends
/// and `ĝ_k` the unit normal of the plane through the edge and the point.
fn polygon_irradiance(vertices: &[DVec3]) -> f64 {
    let n = DVec3::Y;
    let mut sum = 0.0;
    for k in 0..vertices.len() {
        let a = vertices[k].normalize();
        let b = vertices[(k + 1) % vertices.len()].normalize();
        let theta = a.dot(b).clamp(-1.0, 1.0).acos();
        sum += theta * n.dot(a.cross(b).normalize());
    }
    0.5 * sum.abs()
}

/// One light of the transparency table: its USD text and the irradiance it gives the floor at
/// the origin (radiance-weighted, so `L = albedo/π · E`).
struct LightCase {
    name: &'static str,
    usda: &'static str,
    irradiance: fn() -> f64,
}

const LIGHTS: [LightCase; 5] = [
    LightCase {
        name: "dome",
        usda: r#"def DomeLight "Sky" { float inputs:intensity = 1 }"#,
        // A uniform sky of radiance 1 over the whole upper hemisphere: E = π.
        irradiance: || PI,
    },
    LightCase {
        name: "rect",
        usda: r#"def RectLight "Rect" { float inputs:intensity = 4  float inputs:width = 1.5  float inputs:height = 0.75
    double3 xformOp:translate = (0.2, 1, 0.1)  float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"] }"#,
        // The rectangle lies in y = 1, x ∈ 0.2 ± 0.75, z ∈ 0.1 ± 0.375 (local y maps to −z).
        irradiance: || {
            let v = |x: f64, z: f64| DVec3::new(x, 1.0, z);
            4.0 * polygon_irradiance(&[v(-0.55, -0.275), v(0.95, -0.275), v(0.95, 0.475), v(-0.55, 0.475)])
        },
    },
    LightCase {
        name: "disk",
        usda: r#"def DiskLight "Disk" { float inputs:intensity = 3  float inputs:radius = 0.6
    double3 xformOp:translate = (0, 1.2, 0)  float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"] }"#,
        // On the axis of a disk of radius r at height h: E = π L r² / (r² + h²).
        irradiance: || 3.0 * PI * 0.36 / (0.36 + 1.44),
    },
    LightCase {
        name: "sphere",
        usda: r#"def SphereLight "Ball" { float inputs:intensity = 5  float inputs:radius = 0.25
    double3 xformOp:translate = (0.8, 1, 0.3)  uniform token[] xformOpOrder = ["xformOp:translate"] }"#,
        // A sphere wholly above the horizon: E = π L (r/d)² cos θ (d to its centre).
        irradiance: || {
            let c = DVec3::new(0.8, 1.0, 0.3);
            5.0 * PI * (0.25 * 0.25 / c.length_squared()) * (c.y / c.length())
        },
    },
    LightCase {
        name: "distant",
        usda: r#"def DistantLight "Sun" { float inputs:intensity = 2  float inputs:angle = 0
    float xformOp:rotateX = -30  uniform token[] xformOpOrder = ["xformOp:rotateX"] }"#,
        // A delta sun 60° from the zenith: E = intensity · cos 60°.
        irradiance: || 2.0 * 0.5,
    },
];

/// A black sheet of constant mask `m` between the floor and every light type: the floor is
/// seen with probability `1 − m` and lit through the sheet with probability `1 − m`, so
/// `L = (1 − m)² · albedo/π · E`. Mask 0 must equal the scene without the sheet.
#[test]
fn transparent_sheet_under_every_light_type() {
    let floor = ConstMaterial::diffuse([FLOOR; 3]);
    let mut failures = Vec::new();
    for light in &LIGHTS {
        let open = (FLOOR as f64 / PI) * (light.irradiance)();
        let cases = [None, Some(0.0f32), Some(0.5), Some(1.0)];
        for mask in cases {
            let scene = sheet_scene(light.usda, mask.is_some());
            let sheet = ConstMaterial::new(vec![ConstLayer::diffuse(mask.unwrap_or(0.0), [0.0; 3])], &[]);
            let (mean, se) = mean_and_error(&scene, &[&floor, &sheet], 64, LayerMode::Stochastic);
            let m = mask.unwrap_or(0.0) as f64;
            let expected = (1.0 - m).powi(2) * open;
            let tolerance = 3.0 * se + 1e-4 * open;
            let relative = if expected > 0.0 {
                format!("{:+.2} % ± {:.2} %", 100.0 * (mean / expected - 1.0), 100.0 * tolerance / expected)
            } else {
                "must be 0".to_string()
            };
            let line = format!(
                "{:<8} sheet {:<5} measured {mean:.5} expected {expected:.5} ({relative})",
                light.name,
                mask.map_or("none".to_string(), |m| m.to_string()),
            );
            eprintln!("{line}");
            if (mean - expected).abs() > tolerance {
                failures.push(line);
            }
        }
    }
    assert!(failures.is_empty(), "transparency is biased:\n{}", failures.join("\n"));
}

/// A grey sheet of mask `m` over a grey floor under a uniform dome of radiance 1, every
/// bounce between them included. Light reaching the floor from above is the sky through the
/// sheet, `1 − m`, plus the sheet's underside reflecting the floor, `m a_s L_f`, so
/// `L_f = a_f (1 − m) / (1 − m a_s a_f)`; the camera sees the sheet (`a_s`, lit by the sky)
/// with probability `m` and the floor otherwise. Stochastic picking and weighted evaluation
/// must both give it.
#[test]
fn grey_sheet_over_grey_floor_interreflects_analytically() {
    let (a_f, a_s) = (FLOOR as f64, 0.6f64);
    let floor = ConstMaterial::diffuse([FLOOR; 3]);
    let scene = sheet_scene(LIGHTS[0].usda, true);
    let mut failures = Vec::new();
    for m in [0.25f32, 0.5, 0.75] {
        let sheet = ConstMaterial::new(vec![ConstLayer::diffuse(m, [a_s as f32; 3])], &[]);
        let md = m as f64;
        let floor_radiance = a_f * (1.0 - md) / (1.0 - md * a_s * a_f);
        let expected = md * a_s + (1.0 - md) * floor_radiance;
        for mode in [LayerMode::Stochastic, LayerMode::Weighted] {
            let (mean, se) = mean_and_error(&scene, &[&floor, &sheet], 64, mode);
            let tolerance = 3.0 * se + 1e-4;
            let line = format!("mask {m} {mode:?}: measured {mean:.5} expected {expected:.5} (±{tolerance:.5})");
            eprintln!("{line}");
            if (mean - expected).abs() > tolerance {
                failures.push(line);
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// SphereLights as points (UsdLux, see `light::point_intensity`): a sphere of radius `r` and
/// emission `I₀` has radiance `L = I₀` (over its area `4πr²` under `normalize`), and treated as
/// a point it keeps the sphere's radiant intensity `I = L π r²`. The floor sees the sphere
/// wholly above its horizon, where the sphere's own closed form `E = π L (r/d)² cos θ` equals
/// the point's `E = I cos θ / d²`; so every case with the same `L π r²` must give the same
/// irradiance, computed here from the formulas alone: `I₀ π r²` unnormalised, `I₀ / 4`
/// normalised (whatever the radius, 0 included), and 0 for radius 0 unnormalised (a sphere
/// with no surface, which is reported).
#[test]
fn sphere_lights_and_their_points_follow_usdlux() {
    let floor = ConstMaterial::diffuse([FLOOR; 3]);
    let (i0, c) = (5.0f64, DVec3::new(0.8, 1.0, 0.3));
    let cos_over_d2 = (c.y / c.length()) / c.length_squared();
    let mut failures = Vec::new();
    for radius in [0.25f64, 0.0] {
        for treat_as_point in [false, true] {
            for normalize in [false, true] {
                let usda = format!(
                    r#"def SphereLight "Ball" {{ float inputs:intensity = {i0}  float inputs:radius = {radius}
    bool treatAsPoint = {}  bool inputs:normalize = {}
    double3 xformOp:translate = ({}, {}, {})  uniform token[] xformOpOrder = ["xformOp:translate"] }}"#,
                    u8::from(treat_as_point),
                    u8::from(normalize),
                    c.x,
                    c.y,
                    c.z
                );
                let sphere_radiance = if normalize { i0 / (4.0 * PI * radius * radius) } else { i0 };
                let irradiance = match (radius > 0.0, normalize) {
                    // The sphere's closed form (its point's is the same number).
                    (true, _) => PI * sphere_radiance * radius * radius * cos_over_d2,
                    (false, true) => i0 / 4.0 * cos_over_d2,
                    (false, false) => 0.0,
                };
                let (stage, mut diags) = stage(&format!(
                    r#"{CAMERA_OVER_FLOOR}
{usda}"#
                ));
                let scene = Scene::from_stage(&stage, &|_| Some(0), &mut diags).expect("scene");
                assert!(!diags.has_errors());
                let warned = diags.items().iter().any(|d| d.kind == Some("unlit point light"));
                let expected = FLOOR as f64 / PI * irradiance;
                let (mean, se) = mean_and_error(&scene, &[&floor], 16, LayerMode::Stochastic);
                let tolerance = 3.0 * se + 1e-4 * expected;
                let line = format!(
                    "radius {radius} treatAsPoint {treat_as_point:<5} normalize {normalize:<5}: \
                     measured {mean:.6} expected {expected:.6} (±{tolerance:.6}), warned {warned}"
                );
                eprintln!("{line}");
                if (mean - expected).abs() > tolerance || warned != (irradiance == 0.0) {
                    failures.push(line);
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
