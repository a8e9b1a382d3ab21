//! A thin-walled pane rendered: a smooth OpenPBR sheet (`geometry_thin_walled`, transmission 1,
//! IOR 1.5) tilted 45° in front of an emitter that fills the left half of the view. The
//! background is seen where it would be without the pane (a sheet does not bend light, as a
//! refracting volume of the same mesh would) and as bright as the closed form's T' at each
//! pixel's angle: Fresnel's equations and the sheet's inter-reflection ladder, computed here.

mod common;
#[path = "common/sheet_optics.rs"]
mod sheet_optics;

use common::{render_scene, scene_file_with, settings};
use glam::Vec3;
use strata::backend::BackendKind;

/// The sheet's transmittance at `cos` θ.
fn sheet_transmittance(cos: f64, eta: f64) -> f64 {
    sheet_optics::ladder(sheet_optics::fresnel(cos, eta)).1
}

/// USD mesh attributes of the quad with corners `p`.
fn quad(p: [Vec3; 4]) -> String {
    let points: Vec<String> = p.iter().map(|q| format!("({}, {}, {})", q.x, q.y, q.z)).collect();
    format!(
        "int[] faceVertexCounts = [4]\n    int[] faceVertexIndices = [0, 1, 2, 3]\n    point3f[] points = [{}]",
        points.join(", ")
    )
}

const EYE: Vec3 = Vec3::new(0.0, 0.0, 5.0);
/// The pane: through the origin, tilted 45° about y, half-size 3.
const PANE_U: Vec3 = Vec3::new(std::f32::consts::FRAC_1_SQRT_2, 0.0, std::f32::consts::FRAC_1_SQRT_2);
const PANE_HALF: f32 = 3.0;
/// The emitter: the plane z = −6, x in [−12, 0], |y| ≤ 12, radiance 1 (far enough behind
/// the pane that what the pane reflects misses it).
const EMITTER_Z: f32 = -6.0;
const EMITTER_HALF: f32 = 12.0;

/// Where the camera ray through image-plane point (sx, sy) (at z = 0) goes straight on: does
/// it cross the pane, and at what cosine; does it reach the emitter.
fn straight(sx: f32, sy: f32) -> (Option<f32>, bool) {
    let d = (Vec3::new(sx, sy, 0.0) - EYE).normalize();
    let n = PANE_U.cross(Vec3::Y).normalize();
    let t = -n.dot(EYE) / n.dot(d);
    let p = EYE + d * t;
    let on_pane = t > 0.0 && p.dot(PANE_U).abs() < PANE_HALF && p.y.abs() < PANE_HALF;
    let q = EYE + d * ((EMITTER_Z - EYE.z) / d.z);
    let lit = (-EMITTER_HALF..=0.0).contains(&q.x) && q.y.abs() <= EMITTER_HALF;
    (on_pane.then(|| n.dot(d).abs()), lit)
}

fn scene(thin: bool) -> String {
    let pane = [-1.0f32, 1.0, 1.0, -1.0]
        .iter()
        .zip([-1.0f32, -1.0, 1.0, 1.0])
        .map(|(a, b)| PANE_U * (a * PANE_HALF) + Vec3::Y * (b * PANE_HALF))
        .collect::<Vec<_>>();
    let h = EMITTER_HALF;
    let emitter = [
        Vec3::new(-h, -h, EMITTER_Z),
        Vec3::new(0.0, -h, EMITTER_Z),
        Vec3::new(0.0, h, EMITTER_Z),
        Vec3::new(-h, h, EMITTER_Z),
    ];
    format!(
        "#usda 1.0\n(\n    upAxis = \"Z\"\n)\ndef DistantLight \"Off\" {{\n    float inputs:intensity = 0\n}}\n\
         def Camera \"Cam\" {{\n    float focalLength = 18\n    float horizontalAperture = 36\n    \
         float verticalAperture = 36\n    float2 clippingRange = (0.01, 1000)\n    \
         double3 xformOp:translate = (0, 0, 5)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n\
         def Mesh \"Pane\" {{\n    {pane}\n    rel material:binding = </Looks/Pane>\n}}\n\
         def Mesh \"Glow\" {{\n    {emitter}\n    rel material:binding = </Looks/Glow>\n}}\n\
         def Scope \"Looks\" {{\n\
         def Material \"Pane\" {{\n    token outputs:mtlx:surface.connect = </Looks/Pane/S.outputs:surface>\n    \
         def Shader \"S\" {{\n        uniform token info:id = \"ND_open_pbr_surface_surfaceshader\"\n        \
         float inputs:transmission_weight = 1\n        float inputs:specular_roughness = 0\n        \
         float inputs:specular_ior = 1.5\n        bool inputs:geometry_thin_walled = {thin}\n        token outputs:surface\n    }}\n}}\n\
         def Material \"Glow\" {{\n    token outputs:surface.connect = </Looks/Glow/S.outputs:surface>\n    \
         def Shader \"S\" {{\n        uniform token info:id = \"UsdPreviewSurface\"\n        \
         color3f inputs:diffuseColor = (0, 0, 0)\n        int inputs:useSpecularWorkflow = 1\n        \
         color3f inputs:specularColor = (0, 0, 0)\n        color3f inputs:emissiveColor = (1, 1, 1)\n        \
         token outputs:surface\n    }}\n}}\n}}\n",
        pane = quad([pane[0], pane[1], pane[2], pane[3]]),
        emitter = quad(emitter),
        thin = thin as i32,
    )
}

/// (mean of pixel / T' over the pane's lit pixels, its standard error, largest pane pixel
/// where the emitter is not behind it, worst pixel off the pane) for the scene.
fn measure(thin: bool) -> (f64, f64, f32, f32) {
    let size = 40;
    let dir = std::env::temp_dir().join(format!("strata-thin-walled-{thin}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.usda");
    std::fs::write(&path, scene(thin)).unwrap();
    let (scene, materials) = scene_file_with(&path, BackendKind::Jit, true, (size, size));
    let image = render_scene(&scene, &materials, &settings(size, size, 64, 7, 4));
    let red = image.f32_channel("R").expect("beauty");
    let (mut ratios, mut dark, mut off) = (Vec::new(), 0.0f32, 0.0f32);
    let step = 10.0 / size as f32;
    for y in 0..size {
        for x in 0..size {
            // Pixel (x, y) spans image-plane x in [x, x + 1]·step − 5 (left to right), y
            // likewise from the top; the scene is symmetric in y.
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)]
                .map(|(a, b)| straight((x as f32 + a) * step - 5.0, 5.0 - (y as f32 + b) * step));
            let classes = corners.map(|(pane, lit)| (pane.is_some(), lit));
            if classes.iter().any(|c| *c != classes[0]) {
                continue;
            }
            let pixel = red[y * size + x];
            match corners[4] {
                (Some(cos), true) => ratios.push(pixel as f64 / sheet_transmittance(cos as f64, 1.5)),
                (Some(_), false) => dark = dark.max(pixel),
                (None, lit) => off = off.max((pixel - lit as i32 as f32).abs()),
            }
        }
    }
    let n = ratios.len() as f64;
    assert!(n > 80.0, "{n} lit pane pixels");
    let mean = ratios.iter().sum::<f64>() / n;
    let var = ratios.iter().map(|r| (r - mean) * (r - mean)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt(), dark, off)
}

#[test]
fn a_thin_walled_pane_shows_the_background_unbent_and_dimmed_by_the_sheet_transmittance() {
    let (mean, se, dark, off) = measure(true);
    eprintln!("thin pane: lit pixels / T' = {mean:.4} ± {se:.4}; darkest-region max {dark}; off-pane error {off}");
    assert!(off < 1e-4, "off the pane the emitter is seen as it is: error {off}");
    assert!((mean - 1.0).abs() < 4.0 * se + 0.002, "through the pane: pixel / T' = {mean} ± {se}");
    assert!(dark < 1e-4, "where no emitter lies behind the pane it stays black: {dark}");
}
