//! True displacement (docs/DESIGN.md rule 6) against answers known without strata:
//!
//! - a sphere of radius r with constant displacement d has the silhouette, depth and shadow
//!   of a sphere of radius r + d (closed-form disc and ellipse areas, distances);
//! - `none`/`add`/`mix` layers with masks varying over the surface move a plane to the
//!   height rule 6 gives at each point (evaluated by hand, not by strata);
//! - heights beyond a layer's bound are clamped to it and reported;
//! - displaced closed surfaces stay closed: every micro-edge is shared by exactly two
//!   micro-triangles with bit-identical end points, and rays from inside all hit;
//! - JIT = interpreter and optimised = unoptimised, bit for bit, on a displaced layered image.

mod common;

use glam::Vec3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use strata::backend::BackendKind;
use strata::render::Scene;
use strata::session::{SceneSource, Session, SessionOptions};

/// Node types the test substances share: an affine function of the texture coordinates.
const PATTERNS: &str = r#"
shader uv_affine(float c = 0.0, float gu = 0.0, float gv = 0.0, output float out) {
    out = c + gu * u + gv * v;
}
"#;

/// Writes `ash` and a stage of `prims` (USD text) whose `material:slotBinding` targets
/// `/Looks/<name>` for each substance in `substances`, with a camera and a light.
fn stage(dir: &Path, ash: &str, substances: &[&str], prims: &str, extra: &str) -> PathBuf {
    std::fs::write(dir.join("d.ash"), format!("{PATTERNS}{ash}")).unwrap();
    let looks: String = substances
        .iter()
        .map(|name| {
            format!(
                r#"    def Material "{name}" {{
        def Shader "S" {{
            uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @d.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "{name}"
        }}
    }}
"#
            )
        })
        .collect();
    let usda = format!("#usda 1.0\n(\n    upAxis = \"Y\"\n)\n{prims}\n{extra}\ndef Scope \"Looks\" {{\n{looks}}}\n");
    let path = dir.join("d.usda");
    std::fs::write(&path, usda).unwrap();
    path
}

/// `material:slotBinding` lines binding `names` bottom to top in slots 000, 010, …
fn bindings(names: &[&str]) -> String {
    names
        .iter()
        .enumerate()
        .map(|(i, n)| format!("    rel material:slotBinding:_{:03} = </Looks/{n}>\n", i * 10))
        .collect()
}

/// A camera at `at` looking along −z after `rotate` (degrees XYZ), 50 mm over a 20.955 mm
/// aperture: `tan(half fov) = 0.20955`.
fn camera(name: &str, at: [f64; 3], rotate: [f64; 3]) -> String {
    format!(
        r#"def Camera "{name}" {{
    float focalLength = 50
    float horizontalAperture = 20.955
    float2 clippingRange = (0.01, 1000)
    double3 xformOp:translate = ({}, {}, {})
    double3 xformOp:rotateXYZ = ({}, {}, {})
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}}
"#,
        at[0], at[1], at[2], rotate[0], rotate[1], rotate[2]
    )
}

const TAN_HALF: f64 = 20.955 / 100.0;

fn channel<'a>(image: &'a strata::render::Image, name: &str) -> &'a [f32] {
    image.f32_channel(name).unwrap_or_else(|| panic!("no channel {name}"))
}

fn render(path: &Path, camera: Option<&str>, res: (usize, usize), spp: u32, depth: u32) -> strata::render::Image {
    let (scene, materials) = built(path, camera, res, BackendKind::Jit, true);
    common::render_scene(&scene, &materials, &common::settings(res.0, res.1, spp, 1, depth))
}

/// A compiled scene built as `strata render` builds it, with `options`: the scene (`None`
/// when building reported an error), its materials, the diagnostics and their rendering.
struct Built {
    scene: Option<Scene>,
    materials: Vec<std::sync::Arc<dyn strata::abi::MaterialCode>>,
    diags: strata::diag::Diagnostics,
    text: String,
}

fn build_with(
    path: &Path,
    backend: BackendKind,
    optimize: bool,
    options: &strata::render::scene::SceneOptions,
) -> Built {
    let passes = strata::ir::wired::PassOptions { optimize, ..Default::default() };
    let session_options = SessionOptions { backend, passes, ..Default::default() };
    let mut session = Session::open(SceneSource::File(path.to_path_buf()), session_options);
    let materials = session.compile_or_report().unwrap_or_else(|e| panic!("{e}")).materials.clone();
    session.prepare(options);
    let diags = session.take_diagnostics();
    let text = diags.render(session.sources());
    let scene = session.into_scene().map(|(scene, _)| scene);
    Built { scene, materials, diags, text }
}

/// Dicing options for an image of `resolution` with a micro-triangle `budget`.
fn dicing(resolution: (usize, usize), budget: usize) -> strata::render::scene::SceneOptions {
    strata::render::scene::SceneOptions {
        dicing: strata::render::geometry::displace::DicingOptions { resolution, budget, ..Default::default() },
        ..Default::default()
    }
}

/// The scene as `strata render` builds it, through `camera`; panics on any error.
fn built(
    path: &Path,
    camera: Option<&str>,
    res: (usize, usize),
    backend: BackendKind,
    optimize: bool,
) -> (Scene, Vec<std::sync::Arc<dyn strata::abi::MaterialCode>>) {
    let options = strata::render::scene::SceneOptions {
        camera: camera.map(str::to_string),
        ..dicing(res, strata::render::geometry::displace::DEFAULT_MICRO_TRIANGLE_BUDGET)
    };
    let b = build_with(path, backend, optimize, &options);
    assert!(!b.diags.has_errors(), "{}", b.text);
    (b.scene.unwrap_or_else(|| panic!("{}", b.text)), b.materials)
}

const GROWN: &str = r#"
substance Grown {
    input float amount = 0.25;
    node bsdf = diffuse(albedo: color(0.7, 0.7, 0.7));
    node d = displacement(height: amount, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
substance Floor {
    node bsdf = diffuse(albedo: color(0.5, 0.5, 0.5));
    surface = bsdf.bsdf;
}
"#;

/// A unit sphere displaced by 0.25 is a sphere of radius 1.25: its silhouette covers the
/// disc of angular radius asin(1.25 / 10), its nearest point is 8.75 away, and its shadow
/// under a 45° sun is the ellipse of semi-axes 1.25 and 1.25·√2.
#[test]
fn sphere_with_constant_displacement_is_the_larger_sphere() {
    let dir = tempfile::tempdir().unwrap();
    let ball = format!("def Sphere \"Ball\" {{\n{}}}\n", bindings(&["Grown"]));
    let floor = format!(
        "def Mesh \"Floor\" {{\n{}    uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4]\n    \
         int[] faceVertexIndices = [0, 1, 2, 3]\n    point3f[] points = [(-30, -4, 30), (30, -4, 30), (30, -4, -30), (-30, -4, -30)]\n}}\n",
        bindings(&["Floor"])
    );
    // The sun shines down and towards −z at 45°: the ball's shadow centre is 4 units along −z.
    let sun = "def DistantLight \"Sun\" {\n    float inputs:intensity = 3\n    float inputs:angle = 0\n    \
               double3 xformOp:rotateXYZ = (-45, 0, 0)\n    uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}\n";

    // Silhouette and depth from the front, the ball alone.
    let prims = format!("{}{ball}", camera("Front", [0.0, 0.0, 10.0], [0.0, 0.0, 0.0]));
    let path = stage(dir.path(), GROWN, &["Grown"], &prims, sun);
    let (w, h) = (240, 180);
    let front = render(&path, None, (w, h), 16, 1);
    let pixel = 2.0 * TAN_HALF / w as f64;
    let disc = |r: f64| std::f64::consts::PI * ((r / 10.0f64).asin().tan() / pixel).powi(2);
    let coverage: f64 = channel(&front, "A").iter().map(|&a| a as f64).sum();
    assert!((coverage / disc(1.25) - 1.0).abs() < 0.005, "coverage {coverage} px, r + d disc {} px", disc(1.25));
    let z = channel(&front, "Z");
    let centre = z[(h / 2) * w + w / 2].min(z[(h / 2 - 1) * w + w / 2 - 1]);
    assert!((centre - 8.75).abs() < 2e-3, "depth at the centre {centre}, expected 8.75");

    // Shadow from above: floor pixels (depth ≈ 54) that the sun does not reach.
    let prims = format!("{}{ball}{floor}", camera("Top", [0.0, 50.0, 0.0], [-90.0, 0.0, 0.0]));
    let path = stage(dir.path(), GROWN, &["Grown", "Floor"], &prims, sun);
    let (w, h) = (300, 300);
    let top = render(&path, None, (w, h), 16, 1);
    let (r, z) = (channel(&top, "R"), channel(&top, "Z"));
    // The lit floor's radiance: the median floor pixel (most of the floor is lit).
    let mut floor: Vec<f32> = (0..r.len()).filter(|&i| (z[i] - 54.0).abs() < 0.5).map(|i| r[i]).collect();
    floor.sort_by(f32::total_cmp);
    let lit = floor[floor.len() / 2];
    let shadow: f64 =
        (0..r.len()).filter(|&i| (z[i] - 54.0).abs() < 0.5).map(|i| 1.0 - (r[i] / lit).clamp(0.0, 1.0) as f64).sum();
    let floor_pixel = 2.0 * TAN_HALF * 54.0 / w as f64;
    let ellipse = |radius: f64| std::f64::consts::PI * radius * radius * std::f64::consts::SQRT_2;
    let area = shadow * floor_pixel * floor_pixel;
    eprintln!(
        "coverage / (r + d) disc {:.4}; shadow / (r + d) ellipse {:.4}",
        coverage / disc(1.25),
        area / ellipse(1.25)
    );
    assert!(
        (area / ellipse(1.25) - 1.0).abs() < 0.005,
        "shadow {area:.3} units², r + d ellipse {:.3}, r ellipse {:.3}",
        ellipse(1.25),
        ellipse(1.0)
    );
}

/// Rule 6's height at texture coordinates `(u, v)` for the layer stacks below, by hand.
fn expected_height(case: &str, u: f64, v: f64) -> f64 {
    let base = 0.1;
    let added = base + 0.2 * u; // add, mask u
    match case {
        "none+add+mix" => added * (1.0 - v) + 0.05 * v, // mix 0.05, mask v
        // A bump layer mixed on top with mask v hides the relief below by v, and its own
        // height bends normals only.
        "none+add+bump mix" => added * (1.0 - v),
        _ => unreachable!(),
    }
}

const LAYERS: &str = r#"
substance Base {
    node bsdf = diffuse(albedo: 0.5);
    node d = displacement(height: 0.1, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
substance Added {
    node bsdf = diffuse(albedo: 0.3);
    node m = uv_affine(gu: 1.0);
    node opacity = mask(opacity: m.out);
    node d = displacement(height: 0.2, mode: "add");
    surface = bsdf.bsdf;
    mask = opacity.out;
    displacement = d.out;
}
substance Mixed {
    node bsdf = diffuse(albedo: 0.9);
    node m = uv_affine(gv: 1.0);
    node opacity = mask(opacity: m.out);
    node d = displacement(height: 0.05, mode: "mix");
    surface = bsdf.bsdf;
    mask = opacity.out;
    displacement = d.out;
}
substance BumpMixed {
    node bsdf = diffuse(albedo: 0.9);
    node m = uv_affine(gv: 1.0);
    node opacity = mask(opacity: m.out);
    node d = bump(height: 0.5, scale: 1.0, mode: "mix");
    surface = bsdf.bsdf;
    mask = opacity.out;
    displacement = d.out;
}
"#;

/// A 2×2 quad in the xz plane facing +y with `st = ((x + 1) / 2, (z + 1) / 2)`.
fn quad(binding: &str) -> String {
    format!(
        "def Mesh \"Quad\" {{\n{binding}    uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4]\n    \
         int[] faceVertexIndices = [0, 1, 2, 3]\n    \
         point3f[] points = [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]\n    \
         texCoord2f[] primvars:st = [(0, 1), (1, 1), (1, 0), (0, 0)] (interpolation = \"vertex\")\n}}\n"
    )
}

/// Heights of the displaced quad under rays cast straight down on a grid of points.
fn heights_on_grid(scene: &Scene) -> Vec<(f64, f64, f64)> {
    let mut out = Vec::new();
    for i in 1..8 {
        for j in 1..8 {
            let (x, z) = (-1.0 + 2.0 * i as f32 / 8.0 + 0.013, -1.0 + 2.0 * j as f32 / 8.0 - 0.007);
            let o = Vec3::new(x, 10.0, z);
            let hit = scene.accel.intersect(o, -Vec3::Y, 0.0, f32::INFINITY).expect("the quad is below");
            out.push((((x + 1.0) / 2.0) as f64, ((z + 1.0) / 2.0) as f64, (10.0 - hit.t) as f64));
        }
    }
    out
}

#[test]
fn layer_modes_with_varying_masks_move_the_surface_by_rule_6() {
    for (case, stack) in
        [("none+add+mix", ["Base", "Added", "Mixed"]), ("none+add+bump mix", ["Base", "Added", "BumpMixed"])]
    {
        let dir = tempfile::tempdir().unwrap();
        let prims = format!("{}{}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]), quad(&bindings(&stack)));
        let light = "def DomeLight \"Sky\" {}\n";
        let path = stage(dir.path(), LAYERS, &stack, &prims, light);
        let (scene, _) = built(&path, None, (128, 128), BackendKind::Jit, true);
        let stats = scene.displacement.as_ref().expect("the quad is displaced");
        assert!(stats.micro_triangles > 1000, "{case}: diced to {stats}");
        for (u, v, height) in heights_on_grid(&scene) {
            let expected = expected_height(case, u, v);
            // Micro-triangles interpolate the bilinear height linearly: well under 1e-3 at
            // about a pixel each.
            assert!(
                (height - expected).abs() < 1e-3,
                "{case}: height {height:.5} at uv ({u:.3}, {v:.3}), rule 6 gives {expected:.5}"
            );
        }
    }
}

#[test]
fn heights_beyond_the_bound_are_clamped_and_reported() {
    let dir = tempfile::tempdir().unwrap();
    let ash = r#"
substance Tall {
    node bsdf = diffuse(albedo: 0.5);
    node h = uv_affine(c: 0.1, gu: 2.0);
    node d = displacement(height: h.out, mode: "none", bound: 0.5);
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;
    let prims = format!("{}{}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]), quad(&bindings(&["Tall"])));
    let path = stage(dir.path(), ash, &["Tall"], &prims, "def DomeLight \"Sky\" {}\n");
    let Built { scene, diags, text, .. } = build_with(
        &path,
        BackendKind::Jit,
        true,
        &dicing((64, 64), strata::render::geometry::displace::DEFAULT_MICRO_TRIANGLE_BUDGET),
    );
    let scene = scene.expect("builds");
    // Height 0.1 + 2u passes 0.5 at u = 0.2: clamped there, exact below.
    for (u, v, height) in heights_on_grid(&scene) {
        let expected = (0.1 + 2.0 * u).min(0.5);
        assert!((height - expected).abs() < 2e-3, "height {height} at ({u}, {v}), expected {expected}");
    }
    let stats = scene.displacement.expect("displaced");
    assert!(stats.clamped > 0 && (stats.clamped as usize) < stats.vertices, "{stats}");
    let warning =
        diags.items().iter().find(|d| d.message.contains("passed its bound")).unwrap_or_else(|| panic!("{text}"));
    assert!(warning.message.contains("bound 0.5") && warning.message.contains("largest |height| 2.1"), "{text}");
    assert!(warning.message.contains(&format!("{} of {}", stats.clamped, stats.vertices)), "{text}");
}

const ROUGH: &str = r#"
substance Rough {
    node bsdf = diffuse(albedo: 0.6);
    node n = fbm(scale: 3.0);
    node h = math(a: n.out, b: 0.15, op: "mul");
    node d = displacement(height: h.out, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;

/// Micro-triangles of the displaced prims (the world BVH's triangles) of `path`.
fn micro_triangles(path: &Path) -> (Vec<[Vec3; 3]>, Scene) {
    let (scene, _) = built(path, Some("/Cam"), (200, 150), BackendKind::Jit, true);
    let triangles = scene.accel.world_triangles();
    (triangles, scene)
}

/// Every edge of a closed mesh is shared by exactly two triangles, end points bit-identical.
fn open_edges(triangles: &[[Vec3; 3]]) -> usize {
    let key = |p: Vec3| p.to_array().map(f32::to_bits);
    let mut edges: HashMap<([u32; 3], [u32; 3]), u32> = HashMap::new();
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
            *edges.entry(if a < b { (a, b) } else { (b, a) }).or_default() += 1;
        }
    }
    edges.values().filter(|&&n| n != 2).count()
}

/// Unit directions spread over the sphere (a Fibonacci lattice).
fn directions(n: usize) -> impl Iterator<Item = Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    (0..n).map(move |i| {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let r = (1.0 - y * y).sqrt();
        let phi = golden * i as f32;
        Vec3::new(r * phi.cos(), y, r * phi.sin())
    })
}

#[test]
fn displaced_closed_surfaces_have_no_cracks() {
    // A faceted cube mesh (hard edges: each face's own normal) and quadrics (a sphere's seam
    // and poles, rims, an apex), all with noise relief.
    let cube = "def Mesh \"Cube\" {\n    rel material:slotBinding:_000 = </Looks/Rough>\n    \
                uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n    \
                int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]\n    \
                point3f[] points = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1), (-1, -1, -1), (1, -1, -1)]\n}\n";
    let sphere = "def Sphere \"Ball\" {\n    rel material:slotBinding:_000 = </Looks/Rough>\n}\n";
    // Quadrics of several parts: rims where a side meets a cap, an apex, capsule equators.
    let can = "def Cylinder \"Can\" {\n    rel material:slotBinding:_000 = </Looks/Rough>\n}\n";
    let cone = "def Cone \"Cone\" {\n    rel material:slotBinding:_000 = </Looks/Rough>\n}\n";
    let capsule = "def Capsule \"Pill\" {\n    rel material:slotBinding:_000 = </Looks/Rough>\n}\n";
    for (name, prim) in [("cube", cube), ("sphere", sphere), ("cylinder", can), ("cone", cone), ("capsule", capsule)] {
        let prims = format!("{}{prim}", camera("Cam", [0.0, 1.0, 6.0], [-10.0, 0.0, 0.0]));
        let triangles = check_closed(name, &prims, Vec3::ZERO);
        assert!(triangles > 10_000, "{name}: {triangles} micro-triangles");
    }
}

/// Far from the origin f32 steps are coarse (1/128 at 1e5, 1/16 at 1e6): dicing stops at
/// about eight steps instead of splitting edges whose midpoints round onto their ends, and
/// the surface stays closed.
#[test]
fn displaced_surfaces_far_from_the_origin_stay_closed_and_bounded() {
    for x in [1e5f32, 1e6] {
        let prims = format!(
            "{}def Sphere \"Ball\" {{\n    rel material:slotBinding:_000 = </Looks/Rough>\n    \
             double3 xformOp:translate = ({x}, 0, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n",
            camera("Cam", [x as f64, 1.0, 6.0], [-10.0, 0.0, 0.0])
        );
        check_closed(&format!("sphere at x = {x}"), &prims, Vec3::new(x, 0.0, 0.0));
    }
}

/// Builds `prims` with the `Rough` substance and checks the micro-mesh is closed: every edge
/// shared by exactly two micro-triangles, no ray from `centre` escaping. Returns the number
/// of micro-triangles.
fn check_closed(name: &str, prims: &str, centre: Vec3) -> usize {
    let dir = tempfile::tempdir().unwrap();
    let path = stage(dir.path(), ROUGH, &["Rough"], prims, "def DomeLight \"Sky\" {}\n");
    let (triangles, scene) = micro_triangles(&path);
    assert!(scene.displacement.is_some(), "{name}: not displaced");
    assert_eq!(open_edges(&triangles), 0, "{name}: edges not shared by exactly two micro-triangles");
    // Rays from the centre: a crack anywhere would let some escape.
    let escaped =
        directions(20_000).filter(|&d| scene.accel.intersect(centre, d, 0.0, f32::INFINITY).is_none()).count();
    assert_eq!(escaped, 0, "{name}: rays from inside escaped");
    triangles.len()
}

/// The crack check can fail: the same micro-triangles with one interior vertex moved off
/// its neighbours' copy open its edges.
#[test]
fn the_crack_check_sees_a_moved_vertex() {
    let dir = tempfile::tempdir().unwrap();
    let prims = format!(
        "{}def Sphere \"Ball\" {{\n    rel material:slotBinding:_000 = </Looks/Rough>\n}}\n",
        camera("Cam", [0.0, 1.0, 6.0], [-10.0, 0.0, 0.0])
    );
    let path = stage(dir.path(), ROUGH, &["Rough"], &prims, "def DomeLight \"Sky\" {}\n");
    let (mut triangles, _) = micro_triangles(&path);
    triangles[100][0] += Vec3::splat(1e-4);
    assert!(open_edges(&triangles) >= 2);
}

#[test]
fn a_scene_without_displacement_is_not_diced() {
    let dir = tempfile::tempdir().unwrap();
    let ash = r#"
substance Bumpy {
    node bsdf = diffuse(albedo: 0.6);
    node n = noise(scale: 4.0);
    node d = bump(height: n.out, mode: "add");
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;
    let prims = format!(
        "{}def Sphere \"Ball\" {{\n    rel material:slotBinding:_000 = </Looks/Bumpy>\n}}\n",
        camera("Cam", [0.0, 0.0, 6.0], [0.0, 0.0, 0.0])
    );
    let path = stage(dir.path(), ash, &["Bumpy"], &prims, "def DomeLight \"Sky\" {}\n");
    let (scene, _) = built(&path, None, (64, 64), BackendKind::Jit, true);
    assert!(scene.displacement.is_none());
    assert_eq!(scene.accel.triangle_count(), 0, "the sphere stays analytic");
    assert!(!scene.prim_displaced(0));
}

/// Displacement heights come from the compiled material: both backends and both
/// optimisation levels must dice and move the surface identically.
#[test]
fn displaced_layers_render_identically_across_backends_and_optimisation() {
    let dir = tempfile::tempdir().unwrap();
    let prims = format!(
        "{}def Sphere \"Ball\" {{\n{}}}\n",
        camera("Cam", [0.0, 0.0, 6.0], [0.0, 0.0, 0.0]),
        bindings(&["Base", "Added", "Mixed"])
    );
    let ash = format!("{LAYERS}{ROUGH}");
    let path = stage(dir.path(), &ash, &["Base", "Added", "Mixed"], &prims, "def DomeLight \"Sky\" {}\n");
    let image = |backend, optimize| {
        let (scene, materials) = built(&path, None, (48, 48), backend, optimize);
        common::render_scene(&scene, &materials, &common::settings(48, 48, 4, 7, 3))
    };
    let reference = image(BackendKind::Jit, true);
    assert!(reference.f32_channel("A").unwrap().iter().any(|&a| a > 0.0));
    for (backend, optimize) in [(BackendKind::Interp, true), (BackendKind::Jit, false), (BackendKind::Interp, false)] {
        assert!(image(backend, optimize) == reference, "{backend:?}, optimise {optimize}");
    }
}

/// Builds `path` for a 128x128 image with a micro-triangle budget; panics on any error.
fn built_with_budget(
    path: &Path,
    budget: usize,
) -> (Scene, Vec<std::sync::Arc<dyn strata::abi::MaterialCode>>, strata::diag::Diagnostics, String) {
    let Built { scene, materials, diags, text } = build_with(path, BackendKind::Jit, true, &dicing((128, 128), budget));
    (scene.unwrap_or_else(|| panic!("{text}")), materials, diags, text)
}

#[test]
fn non_finite_heights_over_budget_and_instances_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let ash = r#"
shader broken_height(output float out) {
    out = u > 0.5 ? sqrt(u - 2.0) : 0.1;
}
substance Broken {
    node s = diffuse(albedo: 0.5);
    node h = broken_height();
    node d = displacement(height: h.out, mode: "none");
    surface = s.bsdf;
    displacement = d.out;
}
"#;
    let prims = format!("{}{}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]), quad(&bindings(&["Broken"])));
    let path = stage(dir.path(), ash, &["Broken"], &prims, "def DomeLight \"Sky\" {}\n");
    let (scene, _, diags, text) =
        built_with_budget(&path, strata::render::geometry::displace::DEFAULT_MICRO_TRIANGLE_BUDGET);
    let warning =
        diags.items().iter().find(|d| d.message.contains("NaN or infinite")).unwrap_or_else(|| panic!("{text}"));
    assert!(warning.message.contains("`/Quad`"), "{text}");
    // NaN heights are 0, the others 0.1: no non-finite position reaches the BVH.
    for (u, _, height) in heights_on_grid(&scene) {
        let expected = if u > 0.5 { 0.0 } else { 0.1 };
        assert!((height - expected).abs() < 1e-4 || (u - 0.5).abs() < 0.1, "height {height} at u {u}");
    }
    assert!(scene.accel.world_triangles().iter().flatten().all(|p| p.is_finite()));

    // A budget smaller than the dicing wants: coarser, reported, within the budget.
    let (scene, _, diags, text) = built_with_budget(&path, 3000);
    let stats = scene.displacement.as_ref().expect("displaced");
    assert!(stats.micro_triangles <= 3000 && stats.rate > 1.0, "{stats}");
    assert!(diags.items().iter().any(|d| d.message.contains("would pass the budget of 3000")), "{text}");

    // Inside instances the prototype is shared: not diced, said so, bumped.
    let prims = format!(
        "{}def Xform \"Proto\" {{\n{}}}\ndef Xform \"Copy\" (\n    instanceable = true\n    references = </Proto>\n) {{}}\n\
         def Xform \"Copy2\" (\n    instanceable = true\n    references = </Proto>\n) {{}}\n",
        camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]),
        quad(&bindings(&["Broken"]))
    );
    let path = stage(dir.path(), ash, &["Broken"], &prims, "def DomeLight \"Sky\" {}\n");
    let (scene, _, diags, text) = built_with_budget(&path, 1 << 20);
    assert!(diags.items().iter().any(|d| d.message.contains("displacement inside instances is not diced")), "{text}");
    // The un-instanced original is diced.
    assert!(scene.displacement.is_some_and(|s| s.prims == 1), "{text}");
}

/// Dicing measures edges against pixels and the scene's own size, never absolute lengths:
/// the displaced sphere's silhouette is the r + d disc at any scene scale.
#[test]
fn displacement_holds_at_any_scene_scale() {
    for scale in [1e-3f64, 1e3] {
        let dir = tempfile::tempdir().unwrap();
        let ash = format!(
            "substance Grown {{\n    node bsdf = diffuse(albedo: 0.7);\n    \
             node d = displacement(height: {}, mode: \"none\", bound: {});\n    surface = bsdf.bsdf;\n    displacement = d.out;\n}}\n",
            0.25 * scale,
            scale
        );
        let prims = format!(
            "def Camera \"Cam\" {{\n    float focalLength = 50\n    float horizontalAperture = 20.955\n    \
             float2 clippingRange = ({}, {})\n    double3 xformOp:translate = (0, 0, {})\n    \
             uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n\
             def Sphere \"Ball\" {{\n    double radius = {scale}\n{}}}\n",
            0.01 * scale,
            1000.0 * scale,
            10.0 * scale,
            bindings(&["Grown"])
        );
        let path = stage(dir.path(), &ash, &["Grown"], &prims, "def DomeLight \"Sky\" {}\n");
        let (w, h) = (160, 120);
        let image = render(&path, None, (w, h), 4, 1);
        let pixel = 2.0 * TAN_HALF / w as f64;
        let disc = std::f64::consts::PI * ((1.25f64 / 10.0).asin().tan() / pixel).powi(2);
        let coverage: f64 = channel(&image, "A").iter().map(|&a| a as f64).sum();
        assert!((coverage / disc - 1.0).abs() < 0.01, "scale {scale}: coverage {coverage}, r + d disc {disc}");
    }
}

/// A camera inside a displaced surface would dice without end near it: the scene-relative
/// edge floor and the budget stop it, and the image is still valid.
#[test]
fn a_camera_inside_a_displaced_sphere_is_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let prims = format!(
        "{}def Sphere \"Ball\" {{\n{}}}\n",
        camera("Cam", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        bindings(&["Rough"])
    );
    let path = stage(dir.path(), ROUGH, &["Rough"], &prims, "def DomeLight \"Sky\" {}\n");
    let (scene, materials, diags, text) = built_with_budget(&path, 200_000);
    let stats = scene.displacement.as_ref().expect("displaced");
    assert!(stats.micro_triangles <= 200_000, "{stats}");
    assert!(!diags.has_errors(), "{text}");
    let image = common::render_scene(&scene, &materials, &common::settings(16, 16, 1, 1, 2));
    assert!(channel(&image, "A").iter().all(|&a| a == 1.0), "every ray from inside hits the sphere");
}

/// A diced prim's shading normal is its displaced surface's, bent only by bump layers: a
/// slope of 0.1 (height 0.2u over a quad 2 wide) tilts the normal to (−0.1, 1, 0)/|·| — not
/// twice that, as it would be if its displacement were bumped again.
#[test]
fn a_diced_prim_is_not_bumped_by_its_own_displacement() {
    let dir = tempfile::tempdir().unwrap();
    let ash = r#"
substance Slope {
    node bsdf = diffuse(albedo: 0.5);
    node h = uv_affine(gu: 0.2);
    node d = displacement(height: h.out, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;
    let prims = format!("{}{}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]), quad(&bindings(&["Slope"])));
    let path = stage(dir.path(), ash, &["Slope"], &prims, "def DomeLight \"Sky\" {}\n");
    let (w, h) = (32, 32);
    let image = render(&path, None, (w, h), 1, 1);
    let centre = (h / 2) * w + w / 2;
    let n = Vec3::new(channel(&image, "N.R")[centre], channel(&image, "N.G")[centre], channel(&image, "N.B")[centre]);
    let expected = Vec3::new(-0.1, 1.0, 0.0).normalize();
    assert!((n - expected).length() < 5e-3, "shading normal {n}, the displaced surface's {expected}");
}

/// Whether a prim is diced follows rule 6's liveness, not the optimiser: a moving layer that
/// an opaque `mix` layer hides moves nothing either way.
#[test]
fn dicing_does_not_depend_on_the_optimiser() {
    let dir = tempfile::tempdir().unwrap();
    let ash = format!(
        "{GROWN}\nsubstance Flatten {{\n    node bsdf = diffuse(albedo: 0.3);\n    \
         node b = bump(height: 0.0, mode: \"mix\");\n    surface = bsdf.bsdf;\n    displacement = b.out;\n}}\n"
    );
    let prims = format!(
        "{}def Sphere \"Ball\" {{\n{}}}\n",
        camera("Cam", [0.0, 0.0, 6.0], [0.0, 0.0, 0.0]),
        bindings(&["Grown", "Flatten"])
    );
    let path = stage(dir.path(), &ash, &["Grown", "Flatten"], &prims, "def DomeLight \"Sky\" {}\n");
    let image = |optimize| {
        let (scene, materials) = built(&path, None, (48, 48), BackendKind::Jit, optimize);
        assert!(scene.displacement.is_none(), "optimise {optimize}: the hidden relief was diced");
        common::render_scene(&scene, &materials, &common::settings(48, 48, 4, 7, 3))
    };
    assert!(image(true) == image(false));
}

/// A bound large enough to throw the surface past the scene extent is an error naming the
/// prim, never an empty image.
#[test]
fn displacement_beyond_the_scene_extent_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let ash = r#"
substance Huge {
    node bsdf = diffuse(albedo: 0.5);
    node d = displacement(height: 1e20, mode: "none", bound: 1e20);
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;
    let prims = format!(
        "{}def Sphere \"Ball\" {{\n{}}}\n",
        camera("Cam", [0.0, 0.0, 6.0], [0.0, 0.0, 0.0]),
        bindings(&["Huge"])
    );
    let path = stage(dir.path(), ash, &["Huge"], &prims, "def DomeLight \"Sky\" {}\n");
    let Built { scene, text, .. } = build_with(&path, BackendKind::Jit, true, &Default::default());
    assert!(scene.is_none());
    assert!(text.contains("the displaced surface of `/Ball` reaches"), "{text}");
}

/// Constant displacement moves flat faces flat: a faceted cube's top face and a cylinder's
/// cap rise by exactly d everywhere but the one-micro-triangle band along their hard edges,
/// where the two sides meet (the direction there averages the faces', so nothing opens).
#[test]
fn flat_faces_next_to_hard_edges_stay_flat() {
    let cube = "def Mesh \"Cube\" {\n    rel material:slotBinding:_000 = </Looks/Grown>\n    \
                uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n    \
                int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]\n    \
                point3f[] points = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1), (-1, -1, -1), (1, -1, -1)]\n}\n";
    let can = "def Cylinder \"Can\" {\n    rel material:slotBinding:_000 = </Looks/Grown>\n    double radius = 1\n    \
               double height = 2\n    uniform token axis = \"Y\"\n}\n";
    for (name, prim) in [("cube", cube), ("cylinder", can)] {
        let dir = tempfile::tempdir().unwrap();
        let prims = format!("{}{prim}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]));
        let path = stage(dir.path(), GROWN, &["Grown"], &prims, "def DomeLight \"Sky\" {}\n");
        let (scene, _) = built(&path, None, (128, 128), BackendKind::Jit, true);
        for (x, z) in [(0.0f32, 0.0f32), (0.5, 0.3), (0.62, -0.2), (-0.6, 0.1), (0.1, 0.65)] {
            let hit = scene.accel.intersect(Vec3::new(x, 10.0, z), -Vec3::Y, 0.0, f32::INFINITY).expect("hit");
            let y = 10.0 - hit.t;
            assert!((y - 1.25).abs() < 1e-4, "{name}: top at ({x}, {z}) is {y}, expected 1.25");
        }
    }
}

/// Whether a prim is diced is decided from the masks known at compile time, and a literal
/// `mask(opacity: …)` is known at every optimisation level (it is a constant only once
/// folded): a moving layer under a `mix` bump layer with a literal mask 1, or an `add` layer
/// with a literal mask 0, dices nothing optimised or not; under a literal mask 0 the moving
/// layer dices alike at both levels. Images and dicing figures are identical.
#[test]
fn literal_masks_decide_dicing_alike_at_every_optimisation_level() {
    let dir = tempfile::tempdir().unwrap();
    let ash = format!(
        r#"{GROWN}
substance FlattenOpaque {{
    node bsdf = diffuse(albedo: 0.3);
    node opacity = mask(opacity: 1.0);
    node b = bump(height: 0.0, mode: "mix");
    surface = bsdf.bsdf;
    mask = opacity.out;
    displacement = b.out;
}}
substance FlattenClear {{
    node bsdf = diffuse(albedo: 0.3);
    node opacity = mask(opacity: 0.0);
    node b = bump(height: 0.0, mode: "mix");
    surface = bsdf.bsdf;
    mask = opacity.out;
    displacement = b.out;
}}
substance GrownClear {{
    node bsdf = diffuse(albedo: 0.9);
    node opacity = mask(opacity: 0.0);
    node d = displacement(height: 0.25, mode: "add");
    surface = bsdf.bsdf;
    mask = opacity.out;
    displacement = d.out;
}}
"#
    );
    for (stack, diced) in
        [(["Grown", "FlattenOpaque"], false), (["Floor", "GrownClear"], false), (["Grown", "FlattenClear"], true)]
    {
        let prims = format!(
            "{}def Sphere \"Ball\" {{\n{}}}\n",
            camera("Cam", [0.0, 0.0, 6.0], [0.0, 0.0, 0.0]),
            bindings(&stack)
        );
        let names = ["Grown", "Floor", "FlattenOpaque", "FlattenClear", "GrownClear"];
        let path = stage(dir.path(), &ash, &names, &prims, "def DomeLight \"Sky\" {}\n");
        let build = |optimize| {
            let (scene, materials) = built(&path, None, (48, 48), BackendKind::Jit, optimize);
            let figures = scene.displacement.as_ref().map(|s| (s.prims, s.micro_triangles, s.vertices, s.rate));
            let image = common::render_scene(&scene, &materials, &common::settings(48, 48, 4, 7, 3));
            (figures, image)
        };
        let (optimised, unoptimised) = (build(true), build(false));
        assert_eq!(optimised.0.is_some(), diced, "{stack:?}: optimised dicing {:?}", optimised.0);
        assert_eq!(unoptimised.0, optimised.0, "{stack:?}: unoptimised dicing differs from optimised");
        assert!(unoptimised.1 == optimised.1, "{stack:?}: unoptimised image differs from optimised");
    }
}

/// A 2×1 quad grid in the xz plane facing +y (x from −1 to 1, z from −1 to 1): face 0 is
/// x ≤ 0, face 1 x ≥ 0, each bound by a GeomSubset to `/Looks/<left>` and `/Looks/<right>`.
fn split_quad(left: &str, right: &str) -> String {
    let subset = |name: &str, face: usize, material: &str| {
        format!(
            "    def GeomSubset \"{name}\" {{\n        uniform token elementType = \"face\"\n        \
             uniform token familyName = \"materialBind\"\n        int[] indices = [{face}]\n        \
             rel material:binding = </Looks/{material}>\n    }}\n"
        )
    };
    format!(
        "def Mesh \"Split\" {{\n    uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4, 4]\n    \
         int[] faceVertexIndices = [0, 1, 4, 3, 1, 2, 5, 4]\n    \
         point3f[] points = [(-1, 0, 1), (0, 0, 1), (1, 0, 1), (-1, 0, -1), (0, 0, -1), (1, 0, -1)]\n    \
         uniform token subsetFamily:materialBind:familyType = \"partition\"\n{}{}}}\n",
        subset("Left", 0, left),
        subset("Right", 1, right)
    )
}

const LIFTS: &str = r#"
substance Low {
    node bsdf = diffuse(albedo: 0.5);
    node d = displacement(height: 0.1, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
substance High {
    node bsdf = diffuse(albedo: 0.5);
    node d = displacement(height: 0.3, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;

/// Two GeomSubsets of one mesh displace by 0.1 and 0.3: the border opens and each side moves
/// by its own material's height up to the border. Rays a quarter of a micro-triangle from
/// the border (inside the band a shared border vertex would drag to the other side's
/// height) hit each side at its own height; the faces are flat, so to f32 precision.
#[test]
fn geom_subsets_with_different_displacement_open_along_their_border() {
    let dir = tempfile::tempdir().unwrap();
    let prims = format!("{}{}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]), split_quad("Low", "High"));
    let path = stage(dir.path(), LIFTS, &["Low", "High"], &prims, "def DomeLight \"Sky\" {}\n");
    let resolution = (128, 128);
    let (scene, _) = built(&path, None, resolution, BackendKind::Jit, true);
    let stats = scene.displacement.as_ref().expect("the subsets are displaced");
    // A micro-edge is 0.7 to 1.4 times the dicing rate in pixels; a pixel is this wide on
    // the quad (about 6 units from the camera; the raised quad is nearer, so edges only shorter).
    let pixel = 2.0 * TAN_HALF as f32 * 6.0 / resolution.0 as f32;
    let probe = 0.25 * 0.7 * stats.rate * pixel;
    for k in 0..9 {
        let z = -0.8 + 0.2 * k as f32 + 0.013;
        for (x, expected) in [(-probe, 0.1f32), (probe, 0.3)] {
            let hit = scene.accel.intersect(Vec3::new(x, 10.0, z), -Vec3::Y, 0.0, f32::INFINITY).expect("hit");
            let y = 10.0 - hit.t;
            assert!(
                (y - expected).abs() < 1e-4,
                "at ({x}, {z}), {probe} from the border: height {y}, its subset's material gives {expected}"
            );
        }
    }
}

const BOX_ON_FLOOR: &str = "def Mesh \"Box\" {\n    rel material:slotBinding:_000 = </Looks/Low>\n    \
    uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n    \
    int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]\n    \
    point3f[] points = [(-0.5, 0, 0.5), (0.5, 0, 0.5), (-0.5, 1, 0.5), (0.5, 1, 0.5), (-0.5, 1, -0.5), (0.5, 1, -0.5), (-0.5, 0, -0.5), (0.5, 0, -0.5)]\n}\n";

/// A 3×3 grid of unit quads at y = 0 facing +y whose centre quad is the box's footprint, so
/// the box's bottom corners and edges coincide with the floor's.
fn grid_floor() -> String {
    let mut points = Vec::new();
    for z in [1.5, 0.5, -0.5, -1.5] {
        for x in [-1.5, -0.5, 0.5, 1.5] {
            points.push(format!("({x}, 0, {z})"));
        }
    }
    let mut indices = Vec::new();
    for row in 0..3 {
        for col in 0..3 {
            let i = row * 4 + col;
            indices.extend([i, i + 1, i + 5, i + 4].map(|v| v.to_string()));
        }
    }
    format!(
        "def Mesh \"Floor\" {{\n    rel material:slotBinding:_000 = </Looks/Low>\n    \
         uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4, 4, 4, 4]\n    \
         int[] faceVertexIndices = [{}]\n    point3f[] points = [{}]\n}}\n",
        indices.join(", "),
        points.join(", ")
    )
}

/// A displaced box standing on a displaced floor (same material, touching along the box's
/// bottom edges) is the box displaced alone: separate prims are never welded, so the floor
/// neither moves the box's bottom edge nor averages its normals with the box's. Its
/// micro-triangles are bit for bit those of the box alone, and its shading normal just above
/// the contact (within the bottom micro-triangle row, where a weld would bend it) is the one
/// it has alone.
#[test]
fn touching_prims_are_displaced_separately() {
    let dir = tempfile::tempdir().unwrap();
    let cam = camera("Cam", [0.0, 0.6, 4.0], [0.0, 0.0, 0.0]);
    let resolution = (64, 64);
    // Coarse dicing: the bottom micro-row (the band a weld would bend) is tall.
    let rate = 16.0;
    let build = |prims: &str| {
        let path = stage(dir.path(), LIFTS, &["Low"], &format!("{cam}{prims}"), "def DomeLight \"Sky\" {}\n");
        let options = strata::render::scene::SceneOptions {
            dicing: strata::render::geometry::displace::DicingOptions { rate, resolution, ..Default::default() },
            ..Default::default()
        };
        let b = build_with(&path, BackendKind::Jit, true, &options);
        assert!(!b.diags.has_errors(), "{}", b.text);
        b.scene.unwrap_or_else(|| panic!("{}", b.text))
    };
    let alone = build(BOX_ON_FLOOR);
    let together = build(&format!("{BOX_ON_FLOOR}{}", grid_floor()));
    assert_eq!(together.displacement.as_ref().map(|s| s.prims), Some(2));

    // Horizontal rays at the box's front face (z = 0.6 displaced, 3.4 from the camera), just above the
    // raised floor (y = 0.1): a micro-edge there is at least 0.7 · rate pixels, so the bottom
    // row reaches at least this high (the box's bottom edge starts at y = 0).
    let pixel = 2.0 * TAN_HALF as f32 * 3.4 / resolution.0 as f32;
    let row = 0.7 * rate * pixel;
    assert!(row > 0.2, "bottom row {row}");
    let mut compared = 0;
    for i in 0..7 {
        let x = -0.45 + 0.15 * i as f32;
        for j in 1..5 {
            let y = 0.1 + (row - 0.1) * j as f32 / 5.0;
            let (o, d) = (Vec3::new(x, y, 5.0), -Vec3::Z);
            let hits = [&alone, &together].map(|scene| {
                let hit = scene.accel.intersect(o, d, 0.0, f32::INFINITY).expect("the box is ahead");
                (hit.t, scene.accel.surface(o, d, &hit).ns)
            });
            let [(t0, n0), (t1, n1)] = hits;
            assert!(n0.z > 0.5, "({x}, {y}): the box's front face has normal {n0}");
            assert!(
                (t1 - t0).abs() < 1e-5 && (n1 - n0).length() < 1e-5,
                "({x}, {y}): on the floor the box is at t = {t1} with normal {n1}, alone at {t0} with {n0}"
            );
            compared += 1;
        }
    }
    assert_eq!(compared, 28);

    let key = |t: &[Vec3; 3]| t.map(|p| p.to_array().map(f32::to_bits));
    let mut with_floor: HashMap<_, usize> = HashMap::new();
    for t in &together.accel.world_triangles() {
        *with_floor.entry(key(t)).or_default() += 1;
    }
    let box_triangles = alone.accel.world_triangles();
    let missing = box_triangles
        .iter()
        .filter(|t| match with_floor.get_mut(&key(t)) {
            Some(n) if *n > 0 => {
                *n -= 1;
                false
            }
            _ => true,
        })
        .count();
    assert_eq!(
        missing,
        0,
        "of the box's {} micro-triangles, {missing} moved when the floor touched it",
        box_triangles.len()
    );
}

/// A displacement driven by a primvar reads the prim's values at each diced vertex, as the
/// shading does at a hit (until stop 39 dicing gave every primvar its fallback: a flat quad).
#[test]
fn a_displacement_reads_the_prim_s_primvars_where_it_dices() {
    const LIFTED: &str = r#"
substance Lifted {
    node lift = primvar_float(name: "lift", fallback: 0.0);
    node bsdf = diffuse(albedo: color(0.5, 0.5, 0.5));
    node d = displacement(height: lift.out, mode: "none");
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;
    let dir = tempfile::tempdir().unwrap();
    // lift = 0.3 + 0.1 x + 0.05 z at the corners: affine, so exact on any triangulation.
    let quad = quad(&bindings(&["Lifted"]))
        .replace("}\n", "    float[] primvars:lift = [0.25, 0.45, 0.35, 0.15] (interpolation = \"vertex\")\n}\n");
    let prims = format!("{}{quad}", camera("Top", [0.0, 6.0, 0.0], [-90.0, 0.0, 0.0]));
    let path = stage(dir.path(), LIFTED, &["Lifted"], &prims, "def DomeLight \"Sky\" {}\n");
    let (scene, _) = built(&path, None, (64, 64), BackendKind::Jit, true);
    assert!(scene.displacement.is_some(), "the quad is displaced");
    for (u, v, height) in heights_on_grid(&scene) {
        let (x, z) = (2.0 * u - 1.0, 2.0 * v - 1.0);
        let expected = 0.3 + 0.1 * x + 0.05 * z;
        assert!(
            (height - expected).abs() < 1e-4,
            "height {height:.5} at ({x:.3}, {z:.3}), the primvar gives {expected:.5}"
        );
    }
}
