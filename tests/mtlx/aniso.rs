//! Anisotropic specular end to end: Standard Surface's `specular_anisotropy` and
//! `specular_rotation`, OpenPBR's `specular_roughness_anisotropy` and pbrlib's vector2
//! `roughness` reach the closure's tangent and aspect words, and a rendered highlight
//! stretches along the tangent (a property of the image: its second moments), turning with
//! the rotation.

use super::*;
use strata::abi::{TERM_ASPECT, TERM_TANGENT};

/// A Material `/M` whose surface is an `ND_standard_surface_surfaceshader` with `inputs`.
fn standard_surface(inputs: &str) -> String {
    format!(
        "def Material \"M\" {{\n    token outputs:mtlx:surface.connect = </M/S.outputs:surface>\n    \
         def Shader \"S\" {{\n        uniform token info:id = \"ND_standard_surface_surfaceshader\"\n{inputs}\n        \
         token outputs:surface\n    }}\n}}"
    )
}

/// A 4 × 4 quad in the xy plane facing the camera at z = 4 (its `st` runs along +x and +y, so
/// dPdu is +x), lit by a small sphere light beside the camera, under `material`: the
/// luminance of a 48 × 48 render.
fn highlight(material: &str) -> (Vec<f32>, usize) {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = format!(
        "#usda 1.0\n(\n    upAxis = \"Y\"\n)\ndef Camera \"Cam\" {{\n    double3 xformOp:translate = (0, 0, 4)\n    \
         uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n\
         def SphereLight \"Lamp\" {{\n    float inputs:intensity = 3000\n    float inputs:radius = 0.05\n    \
         double3 xformOp:translate = (0, 0, 4.2)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n\
         def Mesh \"Plate\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {{\n    \
         point3f[] points = [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]\n    \
         int[] faceVertexCounts = [4]\n    int[] faceVertexIndices = [0, 1, 2, 3]\n    \
         uniform token subdivisionScheme = \"none\"\n    \
         texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = \"vertex\")\n    \
         rel material:binding = </M>\n}}\n{material}\n"
    );
    let path = dir.path().join("plate.usda");
    std::fs::write(&path, text).expect("writes");
    let image = common::render_file(&path, &common::settings(48, 48, 16, 5, 2));
    let (r, g, b) = (image.f32_channel("R").unwrap(), image.f32_channel("G").unwrap(), image.f32_channel("B").unwrap());
    ((0..r.len()).map(|i| 0.2126 * r[i] + 0.7152 * g[i] + 0.0722 * b[i]).collect(), image.width)
}

/// The luminance-weighted variances of the image's x and y pixel coordinates.
fn spread(luminance: &[f32], width: usize) -> (f64, f64) {
    let (mut sum, mut mx, mut my) = (0.0f64, 0.0f64, 0.0f64);
    for (i, &l) in luminance.iter().enumerate() {
        let (x, y) = ((i % width) as f64, (i / width) as f64);
        sum += l as f64;
        mx += l as f64 * x;
        my += l as f64 * y;
    }
    assert!(sum > 0.0, "the highlight renders");
    let (mx, my) = (mx / sum, my / sum);
    let (mut vx, mut vy) = (0.0, 0.0);
    for (i, &l) in luminance.iter().enumerate() {
        let (x, y) = ((i % width) as f64, (i / width) as f64);
        vx += l as f64 * (x - mx).powi(2);
        vy += l as f64 * (y - my).powi(2);
    }
    (vx / sum, vy / sum)
}

#[test]
fn a_standard_surface_highlight_stretches_along_its_tangent_and_turns_with_the_rotation() {
    let metal = "        float inputs:base = 1\n        color3f inputs:base_color = (1, 1, 1)\n        \
                 float inputs:metalness = 1\n        float inputs:specular_roughness = 0.35\n";
    let (iso, w) = highlight(&standard_surface(metal));
    let (along, _) = highlight(&standard_surface(&format!("{metal}        float inputs:specular_anisotropy = 0.8\n")));
    let (turned, _) = highlight(&standard_surface(&format!(
        "{metal}        float inputs:specular_anisotropy = 0.8\n        float inputs:specular_rotation = 0.25\n"
    )));
    let (iso, along, turned) = (spread(&iso, w), spread(&along, w), spread(&turned, w));
    eprintln!("variances (x, y): isotropic {iso:?}, tangent +x {along:?}, turned 90° {turned:?}");
    // Isotropic: round (within noise). Anisotropic: wider along the tangent (αx > αy: +x,
    // the image's x), and along y once the tangent is turned a quarter turn about the normal.
    assert!((iso.0 / iso.1 - 1.0).abs() < 0.15, "isotropic highlight not round: {iso:?}");
    assert!(along.0 > 1.5 * along.1, "highlight not stretched along the tangent: {along:?}");
    assert!(turned.1 > 1.5 * turned.0, "highlight did not turn with specular_rotation: {turned:?}");
}

#[test]
fn anisotropic_inputs_reach_the_closure_words() {
    // Standard Surface: roughness_anisotropy(0.4, 0.5) is α (0.16 / √0.5, 0.16 √0.5): aspect
    // √(αx / αy) = √2, mean α 0.16 (roughness 0.4 again), tangent dPdu turned by 0.
    let (code, rendered) = compiled(&standard_surface(
        "        float inputs:metalness = 1\n        float inputs:specular_roughness = 0.4\n        \
         float inputs:specular_anisotropy = 0.5\n",
    ));
    assert!(!rendered.contains("warning"), "{rendered}");
    let terms = lobes_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5);
    let metal = terms.iter().find(|t| t.kind == ClosureKind::GeneralizedSchlick as u32).expect("a metal term");
    assert!((metal.params[TERM_ASPECT] - 2f32.sqrt()).abs() < 1e-5, "{:?}", metal.params);
    assert!((metal.params[10] - 0.4).abs() < 1e-5, "roughness word {}", metal.params[10]);
    assert!(metal.params[TERM_TANGENT..TERM_TANGENT + 3].iter().any(|&x| x != 0.0), "no tangent: {:?}", metal.params);
    // OpenPBR: α_t = r² √(2 / (1 + (1 − a)²)), α_b = (1 − a) α_t; aspect 1 / √(1 − a).
    let (code, rendered) = compiled(&open_pbr(
        "        float inputs:base_metalness = 1\n        float inputs:specular_roughness = 0.5\n        \
         float inputs:specular_roughness_anisotropy = 0.75\n        float3 inputs:geometry_tangent = (0, 1, 0)\n",
        "",
    ));
    assert!(!rendered.contains("warning"), "{rendered}");
    let terms = lobes_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5);
    let metal = terms.iter().find(|t| t.kind == ClosureKind::GeneralizedSchlick as u32).expect("a metal term");
    let alpha_t = 0.25f32 * (2.0f32 / (1.0 + 0.0625)).sqrt();
    let mean = (alpha_t * 0.25 * alpha_t).sqrt();
    assert!((metal.params[TERM_ASPECT] - 2.0).abs() < 1e-5, "aspect {}", metal.params[TERM_ASPECT]);
    assert!((metal.params[10] - mean.sqrt()).abs() < 1e-5, "roughness word {} vs {}", metal.params[10], mean.sqrt());
    assert_eq!(&metal.params[TERM_TANGENT..TERM_TANGENT + 3], &[0.0, 1.0, 0.0]);
    // Isotropic inputs leave the words zero (the closure without anisotropy, bit for bit).
    let (code, rendered) = compiled(&open_pbr("        float inputs:base_metalness = 0.5\n", ""));
    for t in lobes_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5) {
        assert!(t.params[TERM_TANGENT..].iter().all(|&x| x == 0.0), "{t:?}");
    }
}
