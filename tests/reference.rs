//! Reference tests of the composition rules through compiled materials, one family per
//! DESIGN.md rule, each a table of case → expected value. Every expected value is analytic
//! (worked out by hand in the table, from the rule's formula) or an independent estimator's;
//! none comes from an earlier strata output. The transport families under each light type
//! live in `src/render/integrator/reference.rs`.
//!
//! - Rule 6: the shading normal of stacked `none`/`add`/`mix` displacements with spatially
//!   varying masks, including surfaceless and hidden layers, against the analytic gradient.
//! - Rule 5: surfaceless and mask-only layers hide nothing (radiance, alpha); stochastic
//!   picking against weighted evaluation with spatially varying masks, 16 and 64 layers.
//! - Rule 7: a custom channel's pixel mean equals its layer's coverage.

mod common;

use glam::Vec3;
use std::path::{Path, PathBuf};
use strata::abi::Globals;
use strata::backend::BackendKind;
use strata::render::integrator::shading_state;
use strata::render::{Image, LayerMode, RenderSettings, render};
use strata::session::SceneSource;

/// A node type whose outputs are affine in the shading position, so every height and mask
/// below has a gradient known in closed form: `out = c + gx·x + gz·z`.
const AFFINE: &str = "shader affine(float c = 0.0, float gx = 0.0, float gz = 0.0, output float out = 0.0) {
    out = c + gx * P[0] + gz * P[2];
}
";

/// One layer of a rule-6 case: surface or not, mask `(c, gx, gz)` (absent: `None`), and
/// displacement mode with height `(c, gx, gz)`.
struct Disp {
    surface: bool,
    mask: Option<(f32, f32, f32)>,
    displacement: Option<(&'static str, (f32, f32, f32))>,
}

/// A rule-6 case: layers bottom to top, the point `(x, z)` on the plane y = 0 (normal +y,
/// dPdu = +x, dPdv = +z), and the gradient `(∂D/∂x, ∂D/∂z)` of the combined displacement
/// there, worked out by hand. The expected normal is then `normalize(−∂D/∂x, 1, −∂D/∂z)`.
struct DispCase {
    name: &'static str,
    layers: Vec<Disp>,
    at: (f32, f32),
    gradient: (f32, f32),
}

fn disp_cases() -> Vec<DispCase> {
    let surface = |mask, displacement| Disp { surface: true, mask, displacement };
    let bare = |mask, displacement| Disp { surface: false, mask, displacement };
    vec![
        DispCase {
            name: "none: the height's own slope",
            layers: vec![surface(None, Some(("none", (0.0, 0.5, 0.0))))],
            at: (0.3, 0.2),
            gradient: (0.5, 0.0),
        },
        DispCase {
            // D = 0.5x + m·0.2z with m = 0.25 + 0.25x: ∂x = 0.5 + 0.05z, ∂z = 0.2m.
            name: "add on a surfaceless layer with a varying mask",
            layers: vec![
                surface(None, Some(("none", (0.0, 0.5, 0.0)))),
                bare(Some((0.25, 0.25, 0.0)), Some(("add", (0.0, 0.0, 0.2)))),
            ],
            at: (1.0, 0.5),
            gradient: (0.525, 0.1),
        },
        DispCase {
            // D = (1 − m)·0.5x + m·(−0.4z), m = 0.25 + 0.25x; at x = 1, z = 0.5 (m = 0.5):
            // ∂x = −0.25·0.5 + 0.5·0.5 + 0.25·(−0.2) = 0.075, ∂z = −0.4m = −0.2.
            name: "mix with a varying mask blends heights",
            layers: vec![
                surface(None, Some(("none", (0.0, 0.5, 0.0)))),
                surface(Some((0.25, 0.25, 0.0)), Some(("mix", (0.0, 0.0, -0.4)))),
            ],
            at: (1.0, 0.5),
            gradient: (0.075, -0.2),
        },
        DispCase {
            name: "mix with mask 1 on a surfaceless layer replaces everything below",
            layers: vec![
                surface(None, Some(("none", (0.0, 0.5, 0.0)))),
                surface(Some((0.5, 0.0, 0.0)), Some(("add", (0.0, 0.7, 0.7)))),
                bare(None, Some(("mix", (0.0, 0.0, 0.3)))),
            ],
            at: (0.4, -0.6),
            gradient: (0.0, 0.3),
        },
        DispCase {
            name: "add with mask 0 adds nothing",
            layers: vec![
                surface(None, Some(("none", (0.0, 0.2, 0.0)))),
                surface(Some((0.0, 0.0, 0.0)), Some(("add", (0.0, 5.0, 5.0)))),
            ],
            at: (0.1, 0.1),
            gradient: (0.2, 0.0),
        },
        DispCase {
            // The base's surface is hidden by the opaque top, its displacement is not:
            // D = m·0.4x with m = 0.5 + 0.5z: ∂x = 0.4m, ∂z = 0.2x.
            name: "a hidden layer still displaces, weighted by its own mask",
            layers: vec![surface(Some((0.5, 0.0, 0.5)), Some(("add", (0.0, 0.4, 0.0)))), surface(None, None)],
            at: (0.5, 0.2),
            gradient: (0.24, 0.1),
        },
        DispCase {
            // none ignores masks: D = 0.3z whatever the (zero) mask.
            name: "none ignores its mask",
            layers: vec![surface(None, None), bare(Some((0.0, 0.0, 0.0)), Some(("none", (0.0, 0.0, 0.3))))],
            at: (0.0, 0.0),
            gradient: (0.0, 0.3),
        },
    ]
}

fn disp_source(case: &DispCase) -> (String, Vec<String>) {
    let mut text = AFFINE.to_string();
    let mut names = Vec::new();
    for (i, layer) in case.layers.iter().enumerate() {
        let mut body = String::new();
        if layer.surface {
            body += "    node s = diffuse(albedo: 0.5);\n    surface = s.bsdf;\n";
        }
        if let Some((c, gx, gz)) = layer.mask {
            body += &format!("    node ma = affine(c: {c:?}, gx: {gx:?}, gz: {gz:?});\n");
            body += "    node m = mask(opacity: ma.out);\n    mask = m.out;\n";
        }
        if let Some((mode, (c, gx, gz))) = layer.displacement {
            body += &format!("    node ha = affine(c: {c:?}, gx: {gx:?}, gz: {gz:?});\n");
            body +=
                &format!("    node d = displacement(height: ha.out, mode: \"{mode}\");\n    displacement = d.out;\n");
        }
        let name = format!("layer{i}");
        text += &format!("substance {name} {{\n{body}}}\n");
        names.push(name);
    }
    (text, names)
}

/// Rule 6 against hand-derived gradients. The bump's forward difference (step 1e-3) errs by
/// `h/2 · ∂²D` ≤ 1e-4 for these heights (at most quadratic), so 5e-4 on each normal
/// component is generous and still far below any rule mistake (≥ 0.02 in every case).
#[test]
fn displacement_rules_give_the_analytic_normal() {
    let mut failures = Vec::new();
    for case in disp_cases() {
        let (text, names) = disp_source(&case);
        let lib = common::library(&text);
        for (backend, optimize) in [(BackendKind::Jit, true), (BackendKind::Jit, false), (BackendKind::Interp, true)] {
            let code = common::compile_stack(&lib, &names, backend, optimize);
            let g = Globals {
                p: [case.at.0, 0.0, case.at.1],
                n: [0.0, 1.0, 0.0],
                ng: [0.0, 1.0, 0.0],
                i: [0.0, -1.0, 0.0],
                dpdu: [1.0, 0.0, 0.0],
                dpdv: [0.0, 0.0, 1.0],
                u: 0.5,
                v: 0.5,
                st_footprint: [0.0; 4],
                primvars: Default::default(),
                params: Default::default(),
            };
            let state = shading_state(code.as_ref(), &g).expect("shades");
            let want = Vec3::new(-case.gradient.0, 1.0, -case.gradient.1).normalize();
            let err = (state.normal - want).abs().max_element();
            if err > 5e-4 {
                failures.push(format!(
                    "{} ({backend}, optimise {optimize}): normal {} want {want}",
                    case.name, state.normal
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A plane (y = 0, 40 units wide, st = x/40 + ½, z/40 + ½) under a uniform white dome, seen
/// straight down from y = 5 over a window 1 unit wide; `layers` are substance names of `ash`
/// bound bottom to top.
fn plane_scene(dir: &Path, ash: &str, layers: &[String]) -> PathBuf {
    std::fs::write(dir.join("stack.ash"), ash).unwrap();
    let mut bindings = String::new();
    let mut looks = String::new();
    for (i, name) in layers.iter().enumerate() {
        bindings += &format!("        rel material:slotBinding:_{:03} = </Looks/{name}>\n", i * 10);
        looks += &format!(
            r#"    def Material "{name}"
    {{
        def Shader "S"
        {{
            uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @stack.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "{name}"
        }}
    }}
"#
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
    }}
    def Mesh "Plane"
    {{
{bindings}        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-20, 0, -20), (20, 0, -20), (20, 0, 20), (-20, 0, 20)]
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

fn render_file(scene: &Path, mode: LayerMode, spp: u32, res: usize) -> Image {
    let (session, scene) = common::stage_scene(SceneSource::File(scene.to_path_buf()), BackendKind::Jit, true);
    let refs = session.compiled().expect("compiled").refs();
    let settings = RenderSettings {
        width: res,
        height: res,
        spp,
        seed: 3,
        threads: Some(2),
        max_depth: 8,
        mode,
        ..Default::default()
    };
    let (image, stats) = render(&scene, &refs, &settings, None).expect("renders");
    assert_eq!(stats.invalid_samples(), 0, "{stats}");
    image
}

fn channel_mean(image: &Image, name: &str) -> f64 {
    let v = image.f32_channel(name).unwrap_or_else(|| panic!("no channel {name}"));
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

/// Mean of a channel over the pixels and the standard error of that mean (pixels are
/// independent estimates of one value).
fn mean_and_error(image: &Image, name: &str) -> (f64, f64) {
    let v = image.f32_channel(name).unwrap();
    let n = v.len() as f64;
    let mean = v.iter().map(|&x| x as f64).sum::<f64>() / n;
    let var = v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Rule 5 for layers without a surface, rendered: a diffuse base of albedo 0.5 under a white
/// dome reads 0.5 (`L = albedo · L_dome`), with alpha 1,
/// whatever surfaceless layer sits on top — a bump-only layer with no mask (before the fix
/// it hid the base: alpha 0), or a mask-only layer (it must hide nothing).
#[test]
fn surfaceless_layers_hide_nothing() {
    let cases: [(&str, &str); 3] = [
        ("no top layer", ""),
        ("bump-only top", "    node b = bump(height: 0.0, mode: \"add\");\n    displacement = b.out;\n"),
        ("mask-only top", "    node m = mask(opacity: 0.7);\n    mask = m.out;\n"),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (name, top) in cases {
        let mut layers = vec!["base".to_string()];
        let mut ash = "substance base {\n    node d = diffuse(albedo: 0.5);\n    surface = d.bsdf;\n}\n".to_string();
        if !top.is_empty() {
            ash += &format!("substance top {{\n{top}}}\n");
            layers.push("top".to_string());
        }
        let image = render_file(&plane_scene(dir.path(), &ash, &layers), LayerMode::Stochastic, 16, 16);
        // A diffuse plane under a uniform unit dome reflects L = albedo; 3 standard errors.
        // The dome is sampled cosine-weighted, as the diffuse lobe is, so the estimate has no
        // variance at all: then f32 rounding (1e-5) is the tolerance.
        for c in ["R", "G", "B"] {
            let (m, se) = mean_and_error(&image, c);
            assert!((m - 0.5).abs() < (3.0 * se).max(1e-5), "{name}: {c} = {m} ± {se}");
        }
        assert_eq!(channel_mean(&image, "A"), 1.0, "{name}: alpha");
    }
}

/// Rule 7 with a strongly varying, asymmetric mask: the top layer's mask is `(x + ½)²`, read
/// through the texture coordinate u = x/40 + ½, so 0 at the window's left edge (x = −½) and 1
/// at its right; both layers write a channel (top `cov`, base `under`, each 1). A pixel's `cov`
/// is then the mask's mean over the pixel and `under` its complement. Per quadrant the expected
/// coverage is the mean of `(x + ½)²` over it: 1/12 on the left half, 7/12 on the right, in the
/// top and the bottom rows alike. A mask evaluated at the wrong point moves some quadrant by at
/// least 1/4: mirrored (7/12 on the left), u and v swapped (1/12 top right), a fixed point such
/// as the origin (1/4 everywhere). Tolerance: 5 standard errors of a Bernoulli mean over the
/// quadrant's samples (the stratified first pick only lowers the spread), at most 0.039.
#[test]
fn custom_channels_average_to_their_layers_coverage() {
    let ash = "shader ramp_squared(output float out = 0.0) {
    out = ((u - 0.5) * 40.0 + 0.5) * ((u - 0.5) * 40.0 + 0.5);
}
substance base {
    node d = diffuse(albedo: 0.2);
    node c = customChannelFloat(name: \"under\", value: 1.0);
    surface = d.bsdf;
}
substance top {
    node d = diffuse(albedo: 0.8);
    node s = ramp_squared();
    node m = mask(opacity: s.out);
    node c = customChannelFloat(name: \"cov\", value: 1.0);
    surface = d.bsdf;
    mask = m.out;
}
";
    let dir = tempfile::tempdir().unwrap();
    let (spp, res) = (64, 16);
    let image =
        render_file(&plane_scene(dir.path(), ash, &["base".into(), "top".into()]), LayerMode::Stochastic, spp, res);
    let half = res / 2;
    let samples = spp as f64 * (half * half) as f64;
    // The camera looks down −y with image right = +x and image up = −z: columns run along x.
    let quadrant_mean = |channel: &str, rows: std::ops::Range<usize>, cols: std::ops::Range<usize>| {
        let v = image.f32_channel(channel).unwrap();
        let sum: f64 = rows.flat_map(|r| cols.clone().map(move |c| r * res + c)).map(|i| v[i] as f64).sum();
        sum / (half * half) as f64
    };
    let mut failures = Vec::new();
    for (rows, row_name) in [(0..half, "top"), (half..res, "bottom")] {
        for (cols, col_name, coverage) in [(0..half, "left", 1.0 / 12.0), (half..res, "right", 7.0 / 12.0)] {
            let tolerance = 5.0 * (coverage * (1.0 - coverage) / samples).sqrt();
            for (channel, want) in [("cov", coverage), ("under", 1.0 - coverage)] {
                let got = quadrant_mean(channel, rows.clone(), cols.clone());
                if (got - want).abs() >= tolerance {
                    failures.push(format!("{channel} {row_name} {col_name}: {got:.4} vs {want:.4} ± {tolerance:.4}"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Rule 5, stochastic against weighted with spatially varying masks: `n` diffuse layers of
/// distinct albedos, each masked by its own noise. The weighted mode evaluates every layer
/// (an independent estimator of the same integral); the mean per-pixel difference must be 0
/// within 3 standard errors of that difference (pixels are independent).
#[test]
fn stochastic_matches_weighted_with_varying_masks() {
    for n in [16usize, 64] {
        let mut ash = String::new();
        let mut layers = Vec::new();
        for i in 0..n {
            let a = |k: usize| 0.1 + 0.8 * (((i * 7 + k * 3) % 11) as f32 / 10.0);
            ash += &format!(
                "substance l{i} {{
    node d = diffuse(albedo: color({:?}, {:?}, {:?}));
    node p = noise(scale: {:?});
    node m = mask(opacity: p.out);
    surface = d.bsdf;
    mask = m.out;
}}
",
                a(0),
                a(1),
                a(2),
                0.5 + i as f32 * 0.37
            );
            layers.push(format!("l{i}"));
        }
        let dir = tempfile::tempdir().unwrap();
        let scene = plane_scene(dir.path(), &ash, &layers);
        let stochastic = render_file(&scene, LayerMode::Stochastic, 32, 16);
        let weighted = render_file(&scene, LayerMode::Weighted, 32, 16);
        for c in ["R", "G", "B", "albedo.R"] {
            let a = stochastic.f32_channel(c).unwrap();
            let b = weighted.f32_channel(c).unwrap();
            let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| (*x - *y) as f64).collect();
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (d.len() - 1) as f64;
            let se = (var / d.len() as f64).sqrt();
            assert!(
                mean.abs() < 3.0 * se + 1e-6,
                "{n} layers, {c}: stochastic − weighted = {mean} (3σ = {})",
                3.0 * se
            );
        }
    }
}
