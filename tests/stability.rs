//! Stability where methods fail (docs/STABILITY.md), rendered through the public API: layer
//! picking with 64 thin or near-0/near-1 masks, masks that are exactly 0 or 1, NaN or
//! infinite, bump with huge and tiny amplitudes, and a dome light with a 1e4:1 dynamic range.
//! Each test checks against an independent answer: an analytic irradiance, the weighted
//! estimator of the same integral, or the render of the input the rule says is equivalent.
//! (Intersection at extreme scene scales is in `tests/scene_scale.rs`.)

mod common;

use std::path::{Path, PathBuf};
use strata::backend::BackendKind;
use strata::render::{Image, LayerMode, RenderSettings, RenderStats, render};
use strata::session::SceneSource;

/// A 40×40 plane at y = 0 seen from above by a camera at height 5 (a 10-unit window), under a
/// dome (`dome` is its extra attributes), its slots bound in order to the substances `layers`
/// of `stack.ash` (`ash`).
fn plane_scene(dir: &Path, ash: &str, layers: &[String], dome: &str) -> PathBuf {
    std::fs::write(dir.join("stack.ash"), ash).unwrap();
    let mut bindings = String::new();
    let mut looks = String::new();
    for (i, name) in layers.iter().enumerate() {
        bindings += &format!("        rel material:slotBinding:_{:03} = </Looks/{name}>\n", i * 10);
        looks += &format!(
            "    def Material \"{name}\"\n    {{\n        def Shader \"S\"\n        {{\n            \
             uniform token info:implementationSource = \"sourceAsset\"\n            \
             uniform asset info:strata:sourceAsset = @stack.ash@\n            \
             uniform token info:strata:sourceAsset:subIdentifier = \"{name}\"\n        }}\n    }}\n"
        );
    }
    let usda = format!(
        r#"#usda 1.0
(
    upAxis = "Y"
)
def Xform "World"
{{
    def Camera "Camera"
    {{
        float focalLength = 50
        float horizontalAperture = 10
        float verticalAperture = 10
        float3 xformOp:translate = (0, 5, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
    def DomeLight "Sky"
    {{
        float inputs:intensity = 1
{dome}    }}
    def Mesh "Plane"
    {{
{bindings}        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-20, 0, -20), (20, 0, -20), (20, 0, 20), (-20, 0, 20)]
        normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (
            interpolation = "vertex"
        )
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
    }}
}}
def Scope "Looks"
{{
{looks}}}
"#
    );
    let path = dir.join("stack.usda");
    std::fs::write(&path, usda).unwrap();
    path
}

fn render_file(scene: &Path, mode: LayerMode, spp: u32, res: usize, seed: u64) -> (Image, RenderStats) {
    let (session, scene) = common::stage_scene(SceneSource::File(scene.to_path_buf()), BackendKind::Jit, true);
    let refs = session.compiled().expect("compiled").refs();
    let settings = RenderSettings {
        width: res,
        height: res,
        spp,
        seed,
        threads: Some(2),
        max_depth: 8,
        mode,
        ..Default::default()
    };
    render(&scene, &refs, &settings, None).expect("renders")
}

fn channel<'a>(image: &'a Image, name: &str) -> &'a [f32] {
    image.f32_channel(name).unwrap_or_else(|| panic!("no channel {name}"))
}

/// Mean and standard error of the mean of per-pixel values.
fn mean_se(v: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = v.clone().count() as f64;
    let mean = v.clone().sum::<f64>() / n;
    let var = v.map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// `n` diffuse layers of distinct albedos; layer 0 (the bottom) is opaque, the others are
/// masked by `mask(i)`: a literal, or a `stripes(...)` node instance.
fn stack_source(n: usize, mask: impl Fn(usize) -> String) -> (String, Vec<String>) {
    let mut ash = String::from(
        "shader stripes(float dx = 1.0, float dy = 0.0, float phase = 0.0, float width = 0.03, output float out) {\n    \
         float f = (P[0] * dx + P[2] * dy) * 0.8 + phase;\n    out = f - floor(f) < width ? 1.0 : 0.0;\n}\n",
    );
    let mut layers = Vec::new();
    for i in 0..n {
        let a = |k: usize| 0.1 + 0.8 * (((i * 7 + k * 3) % 11) as f32 / 10.0);
        ash += &format!(
            "substance l{i} {{\n    node d = diffuse(albedo: color({:?}, {:?}, {:?}));\n    surface = d.bsdf;\n",
            a(0),
            a(1),
            a(2)
        );
        if i > 0 {
            let m = mask(i);
            if m.starts_with("stripes") {
                ash += &format!("    node t = {m};\n    node m = mask(opacity: t.out);\n    mask = m.out;\n");
            } else {
                ash += &format!("    node m = mask(opacity: {m});\n    mask = m.out;\n");
            }
        }
        ash += "}\n";
        layers.push(format!("l{i}"));
    }
    (ash, layers)
}

/// Stochastic picking with 64 layers whose masks are thin (3 % stripes), near 0 (1e-3) or near
/// 1 (1 − 1e-3) stays unbiased: its per-pixel mean equals weighted evaluation's within 3
/// standard errors of the difference. The per-pixel spread of both is printed (docs/STABILITY.md).
#[test]
fn stochastic_picking_unbiased_with_64_thin_or_extreme_masks() {
    type Mask = Box<dyn Fn(usize) -> String>;
    let cases: [(&str, Mask); 3] = [
        (
            "thin stripes",
            Box::new(|i| {
                let a = i as f64 * 2.399_963;
                format!("stripes(dx: {:.4}, dy: {:.4}, phase: {:.4})", a.cos(), a.sin(), (i as f64 * 0.618_034).fract())
            }),
        ),
        ("1e-3", Box::new(|_| "0.001".into())),
        ("1 - 1e-3", Box::new(|_| "0.999".into())),
    ];
    for (name, mask) in cases {
        let dir = tempfile::tempdir().unwrap();
        let (ash, layers) = stack_source(64, mask);
        let scene = plane_scene(dir.path(), &ash, &layers, "");
        let (s, s_stats) = render_file(&scene, LayerMode::Stochastic, 32, 16, 3);
        let (w, w_stats) = render_file(&scene, LayerMode::Weighted, 32, 16, 4);
        assert_eq!(s_stats.invalid_samples() + w_stats.invalid_samples(), 0);
        for c in ["R", "G", "B"] {
            let (a, b) = (channel(&s, c), channel(&w, c));
            let (mean, se) = mean_se(a.iter().zip(b).map(|(x, y)| f64::from(*x) - f64::from(*y)));
            let (_, se_s) = mean_se(a.iter().map(|&x| f64::from(x)));
            let (_, se_w) = mean_se(b.iter().map(|&x| f64::from(x)));
            let spread = |se: f64| se * (a.len() as f64).sqrt();
            eprintln!(
                "64 layers, {name}, {c}: stochastic − weighted = {mean:+.5} ± {se:.5}; per-pixel standard deviation \
                 stochastic {:.5}, weighted {:.5}",
                spread(se_s),
                spread(se_w)
            );
            assert!(mean.abs() < 3.0 * se + 1e-6, "{name}, {c}: stochastic − weighted = {mean} (3σ = {})", 3.0 * se);
        }
    }
}

/// Masks exactly 0 and 1, NaN and ±inf. DESIGN.md rule 5 clamps masks to [0, 1]; the clamp is
/// IEEE maxNum/minNum (`runtime::math::clamp`), so NaN reads 0 (the layer is absent), +inf 1
/// and −inf 0. Each must render bit for bit as the equivalent finite mask, with no NaN pixel
/// and no discarded sample. The non-finite values come from `0/0` and `±1/0` of a runtime
/// expression, so no compile-time folding can remove them.
#[test]
fn masks_zero_one_nan_and_infinite_render_as_defined() {
    let top = |expr: &str| {
        format!(
            "shader value(float k = 0.0, float s = 1.0, output float out = 0.0) {{\n    out = {expr};\n}}\n\
             substance base {{\n    node d = diffuse(albedo: color(0.8, 0.2, 0.1));\n    surface = d.bsdf;\n}}\n\
             substance top {{\n    node v = value();\n    node d = diffuse(albedo: color(0.1, 0.3, 0.9));\n    \
             node m = mask(opacity: v.out);\n    surface = d.bsdf;\n    mask = m.out;\n}}\n"
        )
    };
    // `k` is 0 at run time; `P[1]` is 0 on the plane, so `P[1] * k` is a runtime zero.
    let cases = [
        ("NaN (0/0)", "(P[1] * k) / (P[1] * k)", "0.0"),
        ("+inf (1/0)", "s / (P[1] * k)", "1.0"),
        ("-inf (-1/0)", "-s / (P[1] * k)", "0.0"),
        ("exactly 0", "P[1] * k", "0.0"),
        ("exactly 1", "s + P[1] * k", "1.0"),
    ];
    let layers = vec!["base".to_string(), "top".to_string()];
    for (name, expr, equivalent) in cases {
        let dir = tempfile::tempdir().unwrap();
        let (got, stats) =
            render_file(&plane_scene(dir.path(), &top(expr), &layers, ""), LayerMode::Stochastic, 4, 8, 1);
        let dir2 = tempfile::tempdir().unwrap();
        let (want, _) =
            render_file(&plane_scene(dir2.path(), &top(equivalent), &layers, ""), LayerMode::Stochastic, 4, 8, 1);
        assert_eq!(stats.invalid_samples(), 0, "{name}: {stats}");
        for c in ["R", "G", "B", "A"] {
            let v = channel(&got, c);
            assert!(v.iter().all(|x| x.is_finite()), "{name}: non-finite {c}");
            assert_eq!(v, channel(&want, c), "{name}: {c} differs from mask {equivalent}");
        }
        // And the equivalent is what it claims: mask 1 shows only the top (blue > red).
        let (r, b) = (channel(&got, "R")[0], channel(&got, "B")[0]);
        assert_eq!(b > r, equivalent == "1.0", "{name}: R {r} B {b}");
    }
}

/// Bump with huge (1e6) and tiny (1e-9) amplitudes over a diffuse plane of albedo 0.5 under a
/// unit white dome. Tiny: the flat answer `L = 0.5` within 3 standard errors. Huge: shading
/// normals nearly tangent to the surface; no NaN, no discarded sample, full alpha, and the
/// radiance stays within [0, 0.5] (a shading normal may darken, never brighten, a surface under
/// a uniform dome; measured in docs/STABILITY.md).
#[test]
fn bump_with_huge_and_tiny_amplitudes() {
    for (name, scale) in [("tiny", 1e-9f64), ("huge", 1e6)] {
        let ash = format!(
            "substance base {{\n    node d = diffuse(albedo: 0.5);\n    node n = noise(scale: 3.0);\n    \
             node b = bump(height: n.out, scale: {scale:e}, mode: \"add\");\n    surface = d.bsdf;\n    displacement = b.out;\n}}\n"
        );
        let dir = tempfile::tempdir().unwrap();
        let scene = plane_scene(dir.path(), &ash, &["base".to_string()], "");
        let (image, stats) = render_file(&scene, LayerMode::Stochastic, 16, 16, 2);
        assert_eq!(stats.invalid_samples(), 0, "{name}: {stats}");
        assert!(channel(&image, "A").iter().all(|&a| a == 1.0), "{name}: alpha");
        for c in ["R", "G", "B"] {
            let v = channel(&image, c);
            assert!(v.iter().all(|x| x.is_finite()), "{name}: non-finite {c}");
            let (mean, se) = mean_se(v.iter().map(|&x| f64::from(x)));
            eprintln!("bump {name}: {c} = {mean:.4} ± {se:.4} (flat: 0.5)");
            if name == "tiny" {
                assert!((mean - 0.5).abs() < 3.0 * se + 1e-6, "{name}: {c} = {mean} ± {se}");
            } else {
                assert!(mean <= 0.5 + 3.0 * se && mean >= 0.0, "{name}: {c} = {mean} ± {se}");
            }
        }
    }
}

/// A latitude–longitude dome map with a 1e4:1 dynamic range: radiance 1 everywhere except one
/// ring of rows at 1e4. A diffuse plane facing up reads `albedo / π · E`, with `E` integrated
/// from the map row by row here (`∫ cos θ sin θ dθ` in closed form per row). Importance
/// sampling must find the ring: the mean within 3 standard errors and a relative standard
/// error under 2 % at 16 spp on 16×16 pixels.
#[test]
fn dome_with_1e4_to_1_dynamic_range() {
    let (w, h) = (64usize, 32usize);
    let hot_row = 5;
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("dome.exr");
    let radiance = |y: usize| if y == hot_row { 1e4f32 } else { 1.0 };
    exr::prelude::write_rgb_file(&map, w, h, |_, y| (radiance(y), radiance(y), radiance(y))).unwrap();
    // Row y spans polar angles [y, y + 1] π / h from +Y (strata's latlong: row 0 is up).
    let e: f64 = (0..h / 2)
        .map(|y| {
            let (t0, t1) =
                (y as f64 * std::f64::consts::PI / h as f64, (y + 1) as f64 * std::f64::consts::PI / h as f64);
            f64::from(radiance(y)) * std::f64::consts::PI * (t1.sin().powi(2) - t0.sin().powi(2))
        })
        .sum();
    let albedo = 0.5;
    let want = albedo * e / std::f64::consts::PI;
    let ash = "substance base {\n    node d = diffuse(albedo: 0.5);\n    surface = d.bsdf;\n}\n";
    let scene = plane_scene(dir.path(), ash, &["base".to_string()], "        asset inputs:texture:file = @dome.exr@\n");
    let (image, stats) = render_file(&scene, LayerMode::Stochastic, 16, 16, 5);
    assert_eq!(stats.invalid_samples(), 0, "{stats}");
    let (mean, se) = mean_se(channel(&image, "R").iter().map(|&x| f64::from(x)));
    eprintln!("dome 1e4:1: {mean:.3} ± {se:.3} (analytic {want:.3}); relative standard error {:.4}", se / mean);
    assert!((mean - want).abs() < 3.0 * se, "{mean} ± {se} vs {want}");
    assert!(se / mean < 0.02, "relative standard error {}", se / mean);
}

/// `strata render --stats` reports what was compiled, the shader calls per sample and the time
/// split (docs/PERFORMANCE.md).
#[test]
fn render_stats_report_calls_and_time_split() {
    let dir = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["render", "--res", "16x12", "--spp", "2", "--stats", "-o"])
        .arg(dir.path().join("s.exr"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    for needle in ["layers pruned:", "instructions:", "evaluated per camera sample: masks", "AOV writes", "time: parse"]
    {
        assert!(err.contains(needle), "`{needle}` missing from:\n{err}");
    }
}
