//! Emission (UsdPreviewSurface `emissiveColor`, the `emission` product), against answers that
//! do not come from strata's emission code:
//! - an emissive quad lights a floor as a RectLight of the same size, place and radiance does
//!   (UsdLux's light, sampled by its own analytic code), region by region within noise;
//! - a closed box whose walls emit `Le` and reflect diffusely with albedo `a`: the radiance
//!   everywhere inside is `Le / (1 − a)` (the furnace's closed form), and `Le (1 + a + … + a^n)`
//!   for paths of at most n bounces, whichever bounce Russian roulette starts at;
//! - a glowing layer under a non-emitting layer of mask 0.5 emits half its radiance (rule 5);
//! - a camera sees the authored `emissiveColor` itself, from the front only;
//! - a small bright emitter sampled as a light has far less variance than found by BSDF
//!   sampling alone, and both agree on the mean;
//! - a material whose emission is black costs no emission call and no light entry.

mod common;

use common::{render_scene, scene_file_with, settings};
use glam::Vec3;
use std::path::PathBuf;
use std::sync::Arc;
use strata::abi::MaterialCode;
use strata::backend::BackendKind;
use strata::render::{Image, LayerMode, Scene};

/// A light that emits nothing: every scene here has a light, so none gets the default lights
/// that light a stage without any (emissive surfaces are not UsdLux lights, as in Hydra).
const OFF: &str = "def DistantLight \"Off\" {\n    float inputs:intensity = 0\n}\n";

/// A fresh directory for this test's files.
fn dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-emission-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes `files` (name, text) into a fresh directory and builds the scene in the first.
fn build(name: &str, files: &[(&str, String)], size: usize) -> (Scene, Vec<Arc<dyn MaterialCode>>) {
    let dir = dir(name);
    for (file, text) in files {
        std::fs::write(dir.join(file), text).unwrap();
    }
    scene_file_with(&dir.join(files[0].0), BackendKind::Jit, true, (size, size))
}

fn rgb(image: &Image) -> Vec<Vec3> {
    let [r, g, b] = ["R", "G", "B"].map(|c| image.f32_channel(c).expect("beauty"));
    (0..r.len()).map(|i| Vec3::new(r[i], g[i], b[i])).collect()
}

/// A quad of half-size `h` centred at `c` in the plane of constant `axis`, wound so that its
/// (right-handed) normal is `normal`: USD mesh attributes.
fn quad(c: Vec3, h: f32, normal: Vec3) -> String {
    let (u, v) = if normal.x != 0.0 {
        (Vec3::Y, Vec3::Z)
    } else if normal.y != 0.0 {
        (Vec3::Z, Vec3::X)
    } else {
        (Vec3::X, Vec3::Y)
    };
    let mut p = [c - u * h - v * h, c + u * h - v * h, c + u * h + v * h, c - u * h + v * h];
    if (p[1] - p[0]).cross(p[2] - p[0]).dot(normal) < 0.0 {
        p.reverse();
    }
    let points: Vec<String> = p.iter().map(|q| format!("({}, {}, {})", q.x, q.y, q.z)).collect();
    format!(
        "int[] faceVertexCounts = [4]\n    int[] faceVertexIndices = [0, 1, 2, 3]\n    point3f[] points = [{}]",
        points.join(", ")
    )
}

/// A UsdPreviewSurface Material `/Looks/<name>` with `inputs` (USDA lines).
fn preview(name: &str, inputs: &str) -> String {
    format!(
        "def Material \"{name}\" {{\n    token outputs:surface.connect = </Looks/{name}/S.outputs:surface>\n    \
         def Shader \"S\" {{\n        uniform token info:id = \"UsdPreviewSurface\"\n{inputs}\n        \
         token outputs:surface\n    }}\n}}\n"
    )
}

/// Lines that make a UsdPreviewSurface a pure Lambert reflector of `albedo` (no coat: the
/// specular workflow with a black specular colour has no Fresnel lobe).
fn lambert(albedo: f32) -> String {
    format!(
        "        color3f inputs:diffuseColor = ({albedo}, {albedo}, {albedo})\n        \
         int inputs:useSpecularWorkflow = 1\n        color3f inputs:specularColor = (0, 0, 0)"
    )
}

/// A camera at `z` looking down −Z at a square image spanning ±`z` at the origin's plane.
fn camera(z: f32) -> String {
    format!(
        "def Camera \"Cam\" {{\n    float focalLength = 18\n    float horizontalAperture = 36\n    \
         float verticalAperture = 36\n    float2 clippingRange = (0.01, 1000)\n    \
         double3 xformOp:translate = (0, 0, {z})\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n"
    )
}

/// Mean and standard error of `values`.
fn mean_se(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// A floor of albedo 0.5 at z = 0, seen from z = 5, lit by `light` (USDA prims).
fn floor_scene(light: &str) -> String {
    format!(
        "#usda 1.0\n(\n    upAxis = \"Z\"\n)\n{OFF}{camera}def Mesh \"Floor\" {{\n    {floor}\n    \
         rel material:binding = </Looks/Floor>\n}}\n{light}\ndef Scope \"Looks\" {{\n{floor_look}{glow}}}\n",
        camera = camera(5.0),
        floor = quad(Vec3::ZERO, 6.0, Vec3::Z),
        floor_look = preview("Floor", &lambert(0.5)),
        glow = preview("Glow", &format!("{}\n        color3f inputs:emissiveColor = (10, 10, 10)", lambert(0.0))),
    )
}

#[test]
fn an_emissive_quad_lights_a_floor_as_a_rect_light_of_the_same_size_and_radiance() {
    // A 1 × 1 emitter at z = 2 facing down, radiance 10: as a RectLight (local −Z emission,
    // width × height 1, unnormalised: the intensity is the radiance) and as a mesh quad whose
    // front faces −Z with emissiveColor 10 over a black, non-reflecting surface.
    let rect = "def RectLight \"Panel\" {\n    float inputs:width = 1\n    float inputs:height = 1\n    \
                float inputs:intensity = 10\n    double3 xformOp:translate = (0, 0, 2)\n    \
                uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}";
    let emitter = format!(
        "def Mesh \"Panel\" {{\n    {}\n    rel material:binding = </Looks/Glow>\n}}",
        quad(Vec3::new(0.0, 0.0, 2.0), 0.5, -Vec3::Z)
    );
    let size = 64;
    let s = settings(size, size, 64, 7, 8);
    let (scene_a, materials_a) = build("rect", &[("scene.usda", floor_scene(rect))], size);
    let (scene_b, materials_b) = build("quad", &[("scene.usda", floor_scene(&emitter))], size);
    assert!(scene_a.emitters.is_empty());
    assert_eq!(scene_b.emitters.list.len(), 1, "the quad is sampled as a light");
    let a = render_scene(&scene_a, &materials_a, &s);
    let b = render_scene(&scene_b, &materials_b, &s);
    let (ra, rb) = (rgb(&a), rgb(&b));
    // Compare where the camera sees the floor in both (the quad hides the middle of the floor
    // from the camera; the RectLight is not geometry). Per pixel difference, so the spatial
    // falloff cancels; per region of the image, z-scores from the differences' own spread.
    let depth = b.f32_channel("Z").unwrap();
    let mut worst = (0.0f64, 0usize, 0.0, 0.0);
    let mut total = Vec::new();
    let blocks = 4;
    for by in 0..blocks {
        for bx in 0..blocks {
            let mut diffs = Vec::new();
            let mut level = 0.0;
            for y in by * size / blocks..(by + 1) * size / blocks {
                for x in bx * size / blocks..(bx + 1) * size / blocks {
                    let i = y * size + x;
                    if depth[i] > 4.5 {
                        diffs.push((ra[i].y - rb[i].y) as f64);
                        level += ra[i].y as f64;
                    }
                }
            }
            if diffs.len() < 32 {
                continue;
            }
            total.extend_from_slice(&diffs);
            let (mean, se) = mean_se(&diffs);
            let z = mean / se;
            if z.abs() > worst.0.abs() {
                worst = (z, by * blocks + bx, mean, level / diffs.len() as f64);
            }
        }
    }
    assert!(worst.0.abs() < 4.5, "region {} differs by {} (z = {}) at level {}", worst.1, worst.2, worst.0, worst.3);
    let (mean, se) = mean_se(&total);
    let level = ra.iter().map(|c| c.y as f64).sum::<f64>() / ra.len() as f64;
    eprintln!(
        "rect vs emissive quad: worst region z = {:.2}; whole floor {mean:.2e} ± {se:.2e} at {level:.4}",
        worst.0
    );
    assert!(level > 0.02, "the floor is lit: {level}");
    assert!(mean.abs() < 4.5 * se, "floor radiance differs by {mean} ± {se} (level {level})");
}

/// A closed 2-unit box whose walls face inwards, each emitting `le` and reflecting
/// diffusely with albedo `albedo` (per channel), seen from its centre.
fn emissive_box(name: &str, le: Vec3, albedo: Vec3, size: usize) -> (Scene, Vec<Arc<dyn MaterialCode>>) {
    let mut walls = String::new();
    for (k, n) in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z].into_iter().enumerate() {
        walls += &format!(
            "def Mesh \"Wall{k}\" {{\n    {}\n    rel material:slotBinding:_000 = </Looks/Wall>\n}}\n",
            quad(-n, 1.0, n)
        );
    }
    let scene = format!(
        "#usda 1.0\n(\n    upAxis = \"Z\"\n)\n{OFF}{camera}{walls}def Scope \"Looks\" {{\n    def Material \"Wall\" {{\n        \
         def Shader \"S\" {{\n            uniform token info:implementationSource = \"sourceAsset\"\n            \
         uniform asset info:strata:sourceAsset = @glow.ash@\n            \
         uniform token info:strata:sourceAsset:subIdentifier = \"glow\"\n            \
         color3f inputs:albedo = ({}, {}, {})\n            color3f inputs:radiance = ({}, {}, {})\n        }}\n    }}\n}}\n",
        albedo.x,
        albedo.y,
        albedo.z,
        le.x,
        le.y,
        le.z,
        camera = camera(0.0),
    );
    let ash = "substance glow {\n    input color albedo = color(0.5);\n    input color radiance = color(1.0);\n    \
               node d = diffuse(albedo: albedo);\n    surface = d.bsdf;\n    emission = radiance;\n}\n";
    let built = build(name, &[("scene.usda", scene), ("glow.ash", ash.to_string())], size);
    assert_eq!(built.0.emitters.list.len(), 6);
    built
}

/// Per channel, the mean and standard error of an image's pixels.
fn channel_mean_se(image: &Image) -> [(f64, f64); 3] {
    let pixels = rgb(image);
    [0, 1, 2].map(|c| mean_se(&pixels.iter().map(|p| p[c] as f64).collect::<Vec<_>>()))
}

#[test]
fn inside_a_closed_emissive_box_radiance_is_le_over_one_minus_albedo() {
    // L = Le + a L everywhere, so L = Le / (1 − a).
    let le = Vec3::new(1.0, 2.0, 0.5);
    let albedo = Vec3::new(0.5, 0.25, 0.75);
    let want = le / (Vec3::ONE - albedo);
    let size = 32;
    let (scene, materials) = emissive_box("box", le, albedo, size);
    let image = render_scene(&scene, &materials, &settings(size, size, 64, 3, 96));
    for (c, (mean, se)) in channel_mean_se(&image).into_iter().enumerate() {
        let want = want[c] as f64;
        assert!((mean - want).abs() < 4.5 * se + 1e-3 * want, "channel {c}: {mean} ± {se}, want {want}");
    }
}

/// Russian roulette ends paths only from `rr_depth` bounces on, and without bias: inside the
/// emissive box, a path of at most `max_depth` bounces sees `Le (1 + a + … + a^max_depth)`
/// (every vertex emits `Le`, every bounce keeps `a`), whichever bounce roulette starts at.
/// Starting past `max_depth` plays no roulette at all (the image of a never-ending rule, bit
/// for bit), starting at `max_depth` plays on the last segment only (a different image);
/// starting at the first bounce ends paths early and boosts the rest, so it is noisier — a
/// renderer that ignored `rr_depth` would give equal images.
#[test]
fn russian_roulette_starts_at_rr_depth_and_keeps_the_truncated_series() {
    let le = Vec3::new(1.0, 2.0, 0.5);
    let albedo = Vec3::new(0.5, 0.25, 0.75);
    let max_depth = 4;
    let want = (0..=max_depth).fold(Vec3::ZERO, |sum, i| sum + le * albedo.powf(i as f32));
    let size = 24;
    let (scene, materials) = emissive_box("roulette", le, albedo, size);
    let render = |rr_depth| {
        let s = strata::render::RenderSettings { rr_depth, ..settings(size, size, 32, 5, max_depth) };
        render_scene(&scene, &materials, &s)
    };
    let (first, past, never) = (render(1), render(max_depth + 1), render(1024));
    for image in [&first, &past] {
        for (c, (mean, se)) in channel_mean_se(image).into_iter().enumerate() {
            let want = want[c] as f64;
            assert!((mean - want).abs() < 4.5 * se + 1e-3 * want, "channel {c}: {mean} ± {se}, want {want}");
        }
    }
    for c in ["R", "G", "B"] {
        assert_eq!(past.f32_channel(c), never.f32_channel(c), "{c}: roulette played before rr_depth");
    }
    // From bounce `max_depth` on, roulette plays once, on the path's last segment.
    let last = render(max_depth);
    assert_ne!(last.f32_channel("R"), never.f32_channel("R"), "roulette did not play at bounce rr_depth");
    let (se_first, se_past) = (channel_mean_se(&first), channel_mean_se(&past));
    for c in 0..3 {
        assert!(
            se_first[c].1 > 1.2 * se_past[c].1,
            "channel {c}: roulette from bounce 1 adds no noise: {se_first:?} vs {se_past:?}"
        );
    }
}

/// A quad facing the camera (and one facing away) with the `.ash` layers `slots`.
fn layered_quads(name: &str, slots: &[(&str, &str)], ash: &str, size: usize) -> (Scene, Vec<Arc<dyn MaterialCode>>) {
    let mut looks = String::new();
    let mut bindings = String::new();
    for (slot, substance) in slots {
        bindings += &format!("    rel material:slotBinding:_{slot} = </Looks/{substance}>\n");
        looks += &format!(
            "    def Material \"{substance}\" {{\n        def Shader \"S\" {{\n            \
             uniform token info:implementationSource = \"sourceAsset\"\n            \
             uniform asset info:strata:sourceAsset = @layers.ash@\n            \
             uniform token info:strata:sourceAsset:subIdentifier = \"{substance}\"\n        }}\n    }}\n"
        );
    }
    let scene = format!(
        "#usda 1.0\n(\n    upAxis = \"Z\"\n)\n{OFF}{camera}def Mesh \"Front\" {{\n    {front}\n{bindings}}}\n\
         def Scope \"Looks\" {{\n{looks}}}\n",
        camera = camera(5.0),
        front = quad(Vec3::ZERO, 2.0, Vec3::Z),
    );
    build(name, &[("scene.usda", scene), ("layers.ash", ash.to_string())], size)
}

#[test]
fn a_glowing_layer_under_half_dirt_emits_half_its_radiance() {
    let ash = "substance glow {\n    node d = diffuse(albedo: 0.0);\n    surface = d.bsdf;\n    \
               emission = color(2.0, 1.0, 0.5);\n}\n\
               substance dirt {\n    node d = diffuse(albedo: 0.0);\n    node m = mask(opacity: 0.5);\n    \
               surface = d.bsdf;\n    mask = m.out;\n}\n";
    let size = 16;
    let (scene, materials) = layered_quads("pick", &[("000", "glow"), ("010", "dirt")], ash, size);
    let covered = |image: &Image| {
        let pixels = rgb(image);
        // The quad spans ±2 of the ±5 view: the middle pixels.
        let (lo, hi) = (size * 3 / 10 + 1, size * 7 / 10 - 1);
        let inner: Vec<Vec3> =
            (lo..hi).flat_map(|y| (lo..hi).map(move |x| (x, y))).map(|(x, y)| pixels[y * size + x]).collect();
        inner.iter().copied().sum::<Vec3>() / inner.len() as f32
    };
    let want = Vec3::new(1.0, 0.5, 0.25);
    // The first pick is stratified over a pixel's samples: half of them pick the dirt.
    let stochastic = covered(&render_scene(&scene, &materials, &settings(size, size, 16, 1, 4)));
    assert!((stochastic - want).abs().max_element() < 0.02, "stochastic: {stochastic}, want {want}");
    let mut weighted = settings(size, size, 4, 1, 4);
    weighted.mode = LayerMode::Weighted;
    let weighted = covered(&render_scene(&scene, &materials, &weighted));
    assert!((weighted - want).abs().max_element() < 1e-4, "weighted: {weighted}, want {want}");
    // Without the dirt the layer glows fully; dirt alone emits nothing.
    let (scene, materials) = layered_quads("bare", &[("000", "glow")], ash, size);
    let bare = covered(&render_scene(&scene, &materials, &settings(size, size, 4, 1, 4)));
    assert!((bare - want * 2.0).abs().max_element() < 1e-4, "bare: {bare}");
}

#[test]
fn the_camera_sees_the_authored_emissive_color_from_the_front_only() {
    let size = 20;
    let text = format!(
        "#usda 1.0\n(\n    upAxis = \"Z\"\n)\n{OFF}{camera}def Mesh \"Front\" {{\n    {front}\n    \
         rel material:binding = </Looks/Screen>\n}}\ndef Mesh \"Back\" {{\n    {back}\n    \
         rel material:binding = </Looks/Screen>\n}}\ndef Scope \"Looks\" {{\n{look}}}\n",
        camera = camera(5.0),
        front = quad(Vec3::new(-2.5, 0.0, 0.0), 2.0, Vec3::Z),
        back = quad(Vec3::new(2.5, 0.0, 0.0), 2.0, -Vec3::Z),
        look = preview("Screen", &format!("{}\n        color3f inputs:emissiveColor = (0.2, 0.5, 1.5)", lambert(0.0))),
    );
    let (scene, materials) = build("screen", &[("scene.usda", text)], size);
    let pixels = rgb(&render_scene(&scene, &materials, &settings(size, size, 4, 1, 4)));
    let want = Vec3::new(0.2, 0.5, 1.5);
    // Pixel centres at x = ±2.5 (columns 2..8 and 12..18 are well inside each quad).
    for y in 6..14 {
        for x in 2..8 {
            let p = pixels[y * size + x];
            assert!((p - want).abs().max_element() < 1e-5, "front pixel ({x}, {y}) = {p}, want {want}");
        }
        for x in 12..18 {
            assert_eq!(pixels[y * size + x], Vec3::ZERO, "back pixel ({x}, {y}) emits");
        }
    }
}

#[test]
fn a_small_bright_emitter_sampled_as_a_light_has_far_less_variance() {
    // A 0.1 × 0.1 emitter of radiance 10⁴ at z = 1 over the floor: BSDF sampling alone rarely
    // finds it.
    let emitter = format!(
        "def Mesh \"Bulb\" {{\n    {}\n    rel material:binding = </Looks/Bulb>\n}}",
        quad(Vec3::new(0.0, 0.0, 1.0), 0.05, -Vec3::Z)
    );
    let bulb = preview("Bulb", &format!("{}\n        color3f inputs:emissiveColor = (1e4, 1e4, 1e4)", lambert(0.0)));
    let text = floor_scene(&emitter).replace("def Scope \"Looks\" {\n", &format!("def Scope \"Looks\" {{\n{bulb}"));
    let size = 32;
    let (scene, materials) = build("bulb", &[("scene.usda", text.clone())], size);
    assert_eq!(scene.emitters.list.len(), 1);
    let (mut bsdf_only, bsdf_materials) = build("bulb-bsdf", &[("scene.usda", text)], size);
    bsdf_only.emitters.clear();
    // Per-pixel variance from two renders with different seeds (the spatial falloff cancels).
    let stats = |scene: &Scene, materials: &[Arc<dyn MaterialCode>]| {
        let a = rgb(&render_scene(scene, materials, &settings(size, size, 16, 11, 6)));
        let b = rgb(&render_scene(scene, materials, &settings(size, size, 16, 12, 6)));
        let diff: Vec<f64> = a.iter().zip(&b).map(|(p, q)| (p.y - q.y) as f64).collect();
        let var = diff.iter().map(|d| d * d).sum::<f64>() / (2.0 * diff.len() as f64);
        let means: Vec<f64> = a.iter().zip(&b).map(|(p, q)| 0.5 * (p.y + q.y) as f64).collect();
        (var, means)
    };
    let (var_light, mean_light) = stats(&scene, &materials);
    let (var_bsdf, mean_bsdf) = stats(&bsdf_only, &bsdf_materials);
    let ratio = var_bsdf / var_light;
    eprintln!("pixel variance: light sampling {var_light:.4e}, BSDF only {var_bsdf:.4e}: ratio {ratio:.1}");
    assert!(ratio > 20.0, "light sampling should cut variance: ratio {ratio}");
    // Both estimate the same image: the mean floor radiance agrees.
    let diff: Vec<f64> = mean_light.iter().zip(&mean_bsdf).map(|(a, b)| a - b).collect();
    let (mean, se) = mean_se(&diff);
    assert!(mean.abs() < 4.5 * se, "means differ by {mean} ± {se}");
}

#[test]
fn black_emission_costs_no_call_and_no_light() {
    let text = floor_scene("").replace("(10, 10, 10)", "(0, 0, 0)").replace(
        "def Scope \"Looks\"",
        "def DistantLight \"Sun\" {}\ndef Mesh \"Panel\" {\n    int[] faceVertexCounts = [3]\n    \
         int[] faceVertexIndices = [0, 1, 2]\n    point3f[] points = [(0, 0, 1), (1, 0, 1), (0, 1, 1)]\n    \
         rel material:binding = </Looks/Glow>\n}\ndef Scope \"Looks\"",
    );
    let (scene, materials) = build("black", &[("scene.usda", text)], 8);
    assert!(scene.emitters.is_empty());
    assert!(materials.iter().all(|m| m.info().layers.iter().all(|l| !l.has_emission)));
    let refs: Vec<&dyn MaterialCode> = materials.iter().map(|m| m.as_ref()).collect();
    let (_, stats) = strata::render::render(&scene, &refs, &settings(8, 8, 4, 1, 4), None).unwrap();
    assert_eq!(stats.evals.emissions, 0);
}

#[test]
fn emission_without_a_surface_is_reported_and_must_be_a_colour() {
    use strata::diag::{Diagnostics, SourceMap};
    let load = |text: &str| {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        strata::front::library::Library::from_text("t.ash", text, &mut sources, &mut diags);
        diags.render(&sources)
    };
    let rendered = load("substance lamp {\n    emission = color(1.0);\n}\n");
    assert!(rendered.contains("emits but has no `surface`: its emission is never seen"), "{rendered}");
    let rendered =
        load("substance lamp {\n    node d = diffuse();\n    surface = d.bsdf;\n    emission = d.bsdf;\n}\n");
    assert!(rendered.contains("wrong product type: `emission` must be color"), "{rendered}");
    let clean = load("substance lamp {\n    node d = diffuse();\n    surface = d.bsdf;\n    emission = 2.0;\n}\n");
    assert!(!clean.contains("warning") && !clean.contains("error"), "{clean}");
}
