//! Motion blur (issue 26 item 2) against closed forms and USD itself: a sphere sliding
//! across an open shutter covers each pixel for the fraction of the shutter its disc spends
//! over it; a scene where nothing visible moves renders bit for bit as with the shutter
//! closed; transforms at fractional times are usd-core's (`tools/make_motion_fixtures.py`);
//! a moving camera sees what a scene moving the other way shows it. Deformation blur of
//! skinned meshes (UsdSkel) and Points follows the same analytic profile, their BVH boxes hold
//! them at every time, and when they hold still the open shutter changes no bit.

mod common;

use glam::{DMat4, DVec3};
use serde_json::Value as Json;
use std::path::{Path, PathBuf};
use strata::render::Image;
use strata::render::geometry::motion::{MotionKeys, Shutter, placement_motion};
use strata::render::geometry::xform::{transform_sample_times, world_transform_at};

/// Writes `text` to a scene file of its own in the temporary directory.
fn scene(name: &str, text: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-motion-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Image size, sphere and motion of the sliding-sphere scenes: a pinhole camera at the origin
/// looking down −z (focal length 50, horizontal aperture 20: tan of the half field of view is
/// 0.2), a sphere of radius `R` at depth `DEPTH` sliding along x from `X0` to `X1` between
/// frames 0 and 1.
const W: usize = 64;
const H: usize = 8;
const R: f64 = 0.5;
const DEPTH: f64 = 10.0;
const X0: f64 = -1.5;
const X1: f64 = 1.5;
const TAN_HALF: f64 = 0.2;

/// The sliding sphere seen through a camera whose shutter is `open..close`; the camera moves
/// by `camera_ops` (xformOp lines) and the sphere by `sphere_ops`.
fn sliding(open: f64, close: f64, sphere_ops: &str, camera_ops: &str) -> String {
    format!(
        r#"#usda 1.0
(
    startTimeCode = 0
    endTimeCode = 1
)
def Camera "Cam" {{
    float focalLength = 50
    float horizontalAperture = 20
    float2 clippingRange = (0.1, 1000)
    double shutter:open = {open}
    double shutter:close = {close}
    {camera_ops}
}}
def Sphere "Ball" {{
    double radius = {R}
    {sphere_ops}
}}
"#
    )
}

/// Sphere ops that slide it from `X0` to `X1` over frames 0 to 1.
fn slide_ops() -> String {
    format!(
        "double3 xformOp:translate.timeSamples = {{ 0: ({X0}, 0, {}), 1: ({X1}, 0, {}) }}\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
        -DEPTH, -DEPTH
    )
}

fn render(path: &Path, spp: u32) -> Image {
    let mut settings = common::settings(W, H, spp, 7, 2);
    settings.threads = Some(2);
    common::render_file(path, &settings)
}

/// The fraction of the shutter `[0, shutter]` (in frames; the sphere's centre moves at
/// `X1 − X0` per frame) during which the ray from the origin in direction `d` meets the
/// sphere: the squared distance from the centre `P + s V` to the ray is a quadratic in `s`,
/// at most `R²` on one interval.
fn covered(d: DVec3, shutter: f64) -> f64 {
    let d = d.normalize();
    let p = DVec3::new(X0, 0.0, -DEPTH);
    let v = DVec3::new(X1 - X0, 0.0, 0.0);
    let (pd, vd) = (p.dot(d), v.dot(d));
    let a = v.length_squared() - vd * vd;
    let b = 2.0 * (p.dot(v) - pd * vd);
    let c = p.length_squared() - pd * pd - R * R;
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return 0.0;
    }
    let (s0, s1) = ((-b - disc.sqrt()) / (2.0 * a), (-b + disc.sqrt()) / (2.0 * a));
    (s1.min(shutter) - s0.max(0.0)).max(0.0) / shutter
}

/// The analytic coverage (alpha) of pixel `(x, y)`: [`covered`] averaged over the pixel's
/// area (the film's box filter), by a 24 × 24 midpoint rule over the film.
fn coverage(x: usize, y: usize, shutter: f64) -> f64 {
    const N: usize = 24;
    let tan_h = TAN_HALF * H as f64 / W as f64;
    let mut sum = 0.0;
    for i in 0..N {
        for j in 0..N {
            let fx = (x as f64 + (i as f64 + 0.5) / N as f64) / W as f64;
            let fy = (y as f64 + (j as f64 + 0.5) / N as f64) / H as f64;
            let d = DVec3::new((2.0 * fx - 1.0) * TAN_HALF, (1.0 - 2.0 * fy) * tan_h, -1.0);
            sum += covered(d, shutter);
        }
    }
    sum / (N * N) as f64
}

/// A sphere sliding at constant speed across the open shutter covers each pixel for the
/// fraction of the shutter it spends over it: the alpha channel follows the analytic
/// profile within the noise of its sample count, and would not if time were ignored or the
/// shutter halved.
#[test]
fn a_sliding_sphere_blurs_into_the_analytic_coverage_profile() {
    const SPP: u32 = 256;
    let path = scene("slide.usda", &sliding(0.0, 1.0, &slide_ops(), ""));
    assert_follows_the_profile(&render(&path, SPP), SPP, "sliding sphere");
}

/// The sliding sphere of [`sliding`] as the one point of a point instancer whose `points`
/// attributes (`positions`, `velocities`: lines of USD) move it.
fn sliding_point(points: &str) -> String {
    format!(
        r#"#usda 1.0
(
    startTimeCode = 0
    endTimeCode = 1
    timeCodesPerSecond = 24
)
def Camera "Cam" {{
    float focalLength = 50
    float horizontalAperture = 20
    float2 clippingRange = (0.1, 1000)
    double shutter:open = 0
    double shutter:close = 1
}}
def PointInstancer "Points" {{
    rel prototypes = [</Points/Protos/Ball>]
    int[] protoIndices = [0]
    {points}
    def Scope "Protos" {{
        def Sphere "Ball" {{ double radius = {R} }}
    }}
}}
"#
    )
}

/// Point instances blur as the sliding sphere does (issue 26: transform blur of point
/// instancers): their `positions` sampled at both frames, or sampled once with `velocities`
/// (USD's rule: positions + velocities × (t − sample) / timeCodesPerSecond, here 24).
#[test]
fn a_sliding_point_instance_blurs_into_the_analytic_coverage_profile() {
    const SPP: u32 = 256;
    let sampled =
        format!("point3f[] positions.timeSamples = {{ 0: [({X0}, 0, {z})], 1: [({X1}, 0, {z})] }}", z = -DEPTH);
    let path = scene("points.usda", &sliding_point(&sampled));
    assert_follows_the_profile(&render(&path, SPP), SPP, "point instance, positions sampled");
    let velocity = (X1 - X0) * 24.0;
    let with_velocities = format!(
        "point3f[] positions.timeSamples = {{ 0: [({X0}, 0, {z})] }}\n    vector3f[] velocities.timeSamples = {{ 0: [({velocity}, 0, 0)] }}",
        z = -DEPTH
    );
    let path = scene("velocities.usda", &sliding_point(&with_velocities));
    assert_follows_the_profile(&render(&path, SPP), SPP, "point instance, velocities");
}

/// The alpha channel of `image` (rendered at `spp`) against [`coverage`] of the sliding
/// sphere over a whole-frame shutter, pixel by pixel within 4σ of its sample count; it also
/// tells the shutter's length and the time apart.
fn assert_follows_the_profile(image: &Image, spp: u32, what: &str) {
    let alpha = image.f32_channel("A").expect("alpha");
    let mut worst: f64 = 0.0;
    let mut total = 0.0;
    let (mut partial, mut against_half, mut against_still) = (0, 0.0f64, 0.0f64);
    for y in 0..H {
        for x in 0..W {
            let want = coverage(x, y, 1.0);
            let got = alpha[y * W + x] as f64;
            // Four standard deviations of a mean of SPP Bernoulli samples (Sobol points
            // do better), plus the midpoint rule's error.
            let sd = (want * (1.0 - want) / spp as f64).sqrt();
            let err = (got - want).abs();
            assert!(err <= 4.0 * sd + 0.01, "{what}: pixel ({x}, {y}): alpha {got:.4}, analytic {want:.4}");
            worst = worst.max(err);
            total += err;
            if want > 0.1 && want < 0.9 {
                partial += 1;
            }
            against_half = against_half.max((got - coverage(x, y, 0.5)).abs());
            // Time ignored: the sphere where it is when the shutter opens.
            let still = coverage(x, y, 1e-9);
            against_still = against_still.max((got - still).abs());
        }
    }
    let mean = total / (W * H) as f64;
    assert!(mean < 0.01, "{what}: mean error {mean}");
    // The profile is a blur (many pixels partly covered), and it tells the shutter's length
    // and the time apart: the same check would fail by far against either.
    assert!(partial > W * H / 2, "{what}: {partial} partly covered pixels");
    assert!(against_half > 0.3 && against_still > 0.3, "{what}: {against_half} {against_still}");
    eprintln!("{what} at {spp} spp: worst pixel error {worst:.4}, mean {mean:.5}");
}

/// A UV sphere mesh of radius `R` around the origin (`SEGMENTS` around, half as many from
/// pole to pole): `(points, faceVertexCounts, faceVertexIndices)` as USD text. At 96 segments
/// its outline is within 0.05 % of the sphere's radius (0.004 pixel here).
fn uv_sphere() -> (String, String, String) {
    const SEGMENTS: usize = 96;
    const RINGS: usize = SEGMENTS / 2;
    let mut points = vec![DVec3::new(0.0, R, 0.0)];
    for ring in 1..RINGS {
        let theta = std::f64::consts::PI * ring as f64 / RINGS as f64;
        for k in 0..SEGMENTS {
            let phi = std::f64::consts::TAU * k as f64 / SEGMENTS as f64;
            points.push(DVec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()) * R);
        }
    }
    points.push(DVec3::new(0.0, -R, 0.0));
    let ring_vertex = |ring: usize, k: usize| 1 + (ring - 1) * SEGMENTS + k % SEGMENTS;
    let (mut counts, mut indices) = (Vec::new(), Vec::new());
    for k in 0..SEGMENTS {
        counts.push(3);
        indices.extend([0, ring_vertex(1, k + 1), ring_vertex(1, k)]);
    }
    for ring in 1..RINGS - 1 {
        for k in 0..SEGMENTS {
            counts.push(4);
            indices.extend([
                ring_vertex(ring, k),
                ring_vertex(ring, k + 1),
                ring_vertex(ring + 1, k + 1),
                ring_vertex(ring + 1, k),
            ]);
        }
    }
    let last = points.len() - 1;
    for k in 0..SEGMENTS {
        counts.push(3);
        indices.extend([last, ring_vertex(RINGS - 1, k), ring_vertex(RINGS - 1, k + 1)]);
    }
    let join = |v: Vec<String>| v.join(", ");
    (
        join(points.iter().map(|p| format!("({}, {}, {})", p.x, p.y, p.z)).collect()),
        join(counts.iter().map(usize::to_string).collect()),
        join(indices.iter().map(usize::to_string).collect()),
    )
}

/// The sliding-sphere camera looking at a UV sphere mesh skinned to the one joint of a
/// skeleton, whose animation moves the joint from `from` to `to` over frames 0 to 1.
fn skinned(from: f64, to: f64) -> String {
    let (points, counts, indices) = uv_sphere();
    let camera = sliding(0.0, 1.0, "", "");
    // The camera of `sliding`, without its sphere.
    let camera = &camera[..camera.find("def Sphere").unwrap()];
    format!(
        r#"{camera}
def SkelRoot "Rig" (
    prepend apiSchemas = ["SkelBindingAPI"]
)
{{
    rel skel:skeleton = </Rig/Skel>
    def Skeleton "Skel" (
        prepend apiSchemas = ["SkelBindingAPI"]
    )
    {{
        uniform token[] joints = ["root"]
        uniform matrix4d[] bindTransforms = [( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1) )]
        uniform matrix4d[] restTransforms = [( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1) )]
        rel skel:animationSource = </Rig/Anim>
    }}
    def SkelAnimation "Anim"
    {{
        uniform token[] joints = ["root"]
        quatf[] rotations = [(1, 0, 0, 0)]
        half3[] scales = [(1, 1, 1)]
        float3[] translations.timeSamples = {{ 0: [({from}, 0, {depth})], 1: [({to}, 0, {depth})] }}
    }}
    def Mesh "Ball" (
        prepend apiSchemas = ["SkelBindingAPI"]
    )
    {{
        uniform token subdivisionScheme = "none"
        int[] faceVertexCounts = [{counts}]
        int[] faceVertexIndices = [{indices}]
        point3f[] points = [{points}]
        int[] primvars:skel:jointIndices = [0] (
            elementSize = 1
            interpolation = "constant"
        )
        float[] primvars:skel:jointWeights = [1] (
            elementSize = 1
            interpolation = "constant"
        )
    }}
}}
"#,
        depth = -DEPTH,
    )
}

/// A sphere mesh skinned to a joint that slides at constant speed (UsdSkel) deforms across
/// the shutter as the sliding sphere moves: its alpha follows the same analytic profile.
#[test]
fn a_skinned_sphere_on_a_sliding_joint_blurs_into_the_analytic_profile() {
    const SPP: u32 = 256;
    let path = scene("skinned.usda", &skinned(X0, X1));
    let (scene, _) = common::scene_file(&path);
    assert_eq!((scene.motion.deforming_prims, scene.motion.moving_prims), (1, 0), "{:?}", scene.motion);
    assert_follows_the_profile(&render(&path, SPP), SPP, "skinned sphere");
}

/// `count` points of `widths` `2 R` as USD text, point `k` at `at(k)`.
fn points_text(count: usize, at: impl Fn(usize) -> DVec3) -> String {
    (0..count).map(at).map(|p| format!("({}, {}, {})", p.x, p.y, p.z)).collect::<Vec<_>>().join(", ")
}

/// A Points prim whose one point slides as the sphere does (its width the sphere's diameter)
/// blurs into the same analytic profile: its sphere moves with the point across the shutter.
#[test]
fn a_sliding_point_blurs_into_the_analytic_profile() {
    const SPP: u32 = 256;
    let camera = sliding(0.0, 1.0, "", "");
    let camera = &camera[..camera.find("def Sphere").unwrap()];
    let text = format!(
        "{camera}\ndef Points \"Dot\" {{\n    float[] widths = [{}]\n    point3f[] points.timeSamples = {{ 0: [{}], 1: [{}] }}\n}}\n",
        2.0 * R,
        points_text(1, |_| DVec3::new(X0, 0.0, -DEPTH)),
        points_text(1, |_| DVec3::new(X1, 0.0, -DEPTH)),
    );
    let path = scene("dot.usda", &text);
    let (scene, _) = common::scene_file(&path);
    assert_eq!(scene.motion.deforming_prims, 1, "{:?}", scene.motion);
    assert_follows_the_profile(&render(&path, SPP), SPP, "sliding point");
}

/// Moving points' spheres are inside their BVH boxes at every time: 64 points, each moving its
/// own way (and one not at all), are met by a ray straight down through the centre each has
/// at a random time, at its radius above the centre, for 2 000 random (point, time) pairs.
#[test]
fn moving_points_bounds_contain_them_at_all_times() {
    const N: usize = 64;
    let start = |k: usize| DVec3::new((k % 8) as f64 * 3.0, (k / 8) as f64 * 3.0, 0.0);
    let end = |k: usize| {
        if k == 5 {
            return start(k);
        }
        start(k) + DVec3::new(((k * 7) % 5) as f64 - 2.0, ((k * 3) % 7) as f64 - 3.0, ((k * 5) % 3) as f64)
    };
    let text = format!(
        r#"{}
def Points "Cloud" {{
    float[] widths = [1]
    point3f[] points.timeSamples = {{ 0: [{}], 1: [{}] }}
}}
"#,
        camera_above(DVec3::new(10.0, 10.0, 40.0), 1.0),
        points_text(N, start),
        points_text(N, end)
    );
    let (scene, _) = common::scene_file(&scene("cloud.usda", &text));
    assert_eq!(scene.motion.deforming_prims, 1, "{:?}", scene.motion);
    let mut uniform = uniform_numbers(0x9e37_79b9_7f4a_7c15);
    for _ in 0..2000 {
        let (k, tau) = ((uniform() * N as f64) as usize, uniform());
        let centre = start(k).lerp(end(k), tau);
        let origin = centre + DVec3::new(0.0, 0.0, 10.0);
        assert_hit_straight_down(&scene, origin, 9.5, tau, &format!("point {k} at {centre}"));
    }
}

/// A skinned mesh whose animation is sampled but holds still, and Points sampled at the same
/// place, under an open shutter: nothing deforms and the image is the closed shutter's, bit
/// for bit.
#[test]
fn still_skinned_meshes_and_points_render_the_closed_image_bit_for_bit() {
    let text = |open: f64, close: f64| {
        let rig = skinned(0.5, 0.5).replace("double shutter:open = 0", &format!("double shutter:open = {open}"));
        let rig = rig.replace("double shutter:close = 1", &format!("double shutter:close = {close}"));
        format!(
            "{rig}\ndef Points \"Dot\" {{\n    float[] widths = [0.4]\n    point3f[] points.timeSamples = {{ 0: [(-1, 0, -10)], 1: [(-1, 0, -10)] }}\n}}\ndef DistantLight \"Sun\" {{}}\n"
        )
    };
    let (closed, open) = (scene("rig_closed.usda", &text(0.0, 0.0)), scene("rig_open.usda", &text(0.0, 1.0)));
    let (scene_open, _) = common::scene_file(&open);
    assert!(!scene_open.has_motion(), "{:?}", scene_open.motion);
    let settings = common::settings(48, 16, 8, 3, 4);
    let (a, b) = (common::render_file(&closed, &settings), common::render_file(&open, &settings));
    assert!(a.f32_channel("A").unwrap().iter().any(|&x| x > 0.5), "the rig is in view");
    assert_same_bits(&a, &b, "still rig, shutter open");
}

/// Every channel of two images, bit for bit.
fn assert_same_bits(a: &Image, b: &Image, what: &str) {
    assert_eq!(a.channels.len(), b.channels.len());
    for (ca, cb) in a.channels.iter().zip(&b.channels) {
        assert_eq!(ca.name, cb.name);
        assert!(ca.data == cb.data, "{what}: channel {} differs", ca.name);
    }
}

/// With nothing moving, an open shutter changes nothing: the scene draws no time and renders
/// the closed shutter's image bit for bit. With something moving where no ray can reach it
/// (inside a closed sphere), every ray draws a time and the moving prim is an instance, yet
/// the image is still bit for bit the closed one: the time has a sampler dimension of its
/// own and perturbs no other decision.
#[test]
fn an_open_shutter_on_a_still_scene_renders_the_closed_image_bit_for_bit() {
    let still = |open: f64, close: f64, inside: &str| {
        format!(
            r#"#usda 1.0
(
    startTimeCode = 0
)
def Camera "Cam" {{
    double3 xformOp:translate = (0, 1, 12)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    double shutter:open = {open}
    double shutter:close = {close}
}}
def Sphere "Shell" {{ double radius = 3 }}
def Cube "Floor" {{
    double3 xformOp:translate = (0, -4, 0)
    double3 xformOp:scale = (10, 0.1, 10)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
}}
def Cube "Inside" {{
    double size = 1
    {inside}
}}
"#
        )
    };
    let fixed = "double3 xformOp:translate = (0.5, 0, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]";
    let moving = "double3 xformOp:translate.timeSamples = { 0: (-1, 0, 0), 1: (1, 0.5, 0) }\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]";
    let settings = common::settings(48, 32, 16, 3, 4);
    let closed = common::render_file(&scene("still_closed.usda", &still(0.0, 0.0, fixed)), &settings);
    let open = common::render_file(&scene("still_open.usda", &still(-0.5, 0.5, fixed)), &settings);
    assert_same_bits(&closed, &open, "still scene, shutter open");

    let closed = scene("hidden_closed.usda", &still(0.0, 0.0, moving));
    let open = scene("hidden_open.usda", &still(0.0, 1.0, moving));
    let (scene_open, _) = common::scene_file(&open);
    assert!(scene_open.has_motion() && scene_open.motion.moving_instances == 1, "{:?}", scene_open.motion);
    let (scene_closed, _) = common::scene_file(&closed);
    assert!(!scene_closed.has_motion());
    assert_same_bits(
        &common::render_file(&closed, &settings),
        &common::render_file(&open, &settings),
        "hidden moving prim, shutter open",
    );
}

/// The fixture's expected transforms: prim → time → row-major USD matrix.
fn expected() -> Json {
    let text = std::fs::read_to_string("tests/fixtures/motion/xforms_expected.json").unwrap();
    serde_json::from_str(&text).unwrap()
}

/// A row-major, row-vector USD matrix as glam's column-vector one (the same array by columns).
fn usd_matrix(json: &Json) -> DMat4 {
    let v: Vec<f64> = json.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    DMat4::from_cols_slice(&v)
}

fn max_diff(a: DMat4, b: DMat4) -> f64 {
    (a - b).to_cols_array().iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// World transforms at fractional times are usd-core's `ComputeLocalToWorldTransform(t)`
/// (translate, rotateXYZ, orient slerp, scale, a matrix, an animated parent, a reset stack),
/// and the keys a render interpolates between stay within `KEY_TOLERANCE` of them.
#[test]
fn transforms_at_fractional_times_are_usds() {
    let path = Path::new("tests/fixtures/motion/xforms.usda");
    let mut sources = strata::diag::SourceMap::new();
    let mut diags = strata::diag::Diagnostics::new();
    let text = std::fs::read_to_string(path).unwrap();
    let stage = strata::scene::Stage::from_text(
        "xforms.usda",
        &text,
        Path::new("tests/fixtures/motion"),
        &mut sources,
        &mut diags,
    )
    .expect("stage");
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    let want = expected();
    let mut checked = 0;
    for (prim, times) in want.as_object().unwrap().iter().filter(|(k, _)| k.starts_with('/')) {
        let id = stage.find(prim).unwrap_or_else(|| panic!("{prim}"));
        for (time, matrix) in times.as_object().unwrap() {
            let t: f64 = time.parse().unwrap();
            let got = world_transform_at(&stage, id, t, &mut diags);
            let want = usd_matrix(matrix);
            // USD composes in double from float-valued ops (rotations, scales, quatf).
            assert!(max_diff(got, want) < 1e-5, "{prim} at {t}: {got} vs usd {want}");
            checked += 1;
        }
        // The keys over a shutter spanning every sample follow USD's curve between them.
        let world = |t: f64| world_transform_at(&stage, id, t, &mut strata::diag::Diagnostics::new());
        let keys = MotionKeys::sample(&world, -0.5, 2.6, &transform_sample_times(&stage, id));
        for (time, matrix) in times.as_object().unwrap() {
            let t: f64 = time.parse().unwrap();
            let tau = ((t + 0.5) / 3.1) as f32;
            let got = DMat4::from(keys.at(tau));
            let want = usd_matrix(matrix);
            let scale = want.to_cols_array().iter().fold(1.0f64, |m, x| m.max(x.abs()));
            let tolerance = 2.0 * strata::render::geometry::motion::KEY_TOLERANCE * scale;
            assert!(max_diff(got, want) < tolerance, "{prim} keyed at {t}: {got} vs usd {want}");
        }
    }
    assert_eq!(checked, 6 * 13);
    // The camera's shutter as USD reads it, and what moves within it at frame 0.
    let shutter = want["shutter"].as_array().unwrap();
    let cam = stage.prim(stage.find("/Cam").unwrap());
    let s = Shutter::of_camera(cam, &mut diags);
    assert_eq!([s.open, s.close], [shutter[0].as_f64().unwrap(), shutter[1].as_f64().unwrap()]);
    let moves = |p: &str| placement_motion(&stage, stage.find(p).unwrap(), 0.0, s).is_some();
    assert!(moves("/Parent/Slide/Ball") && moves("/Matrix") && !moves("/Cam"));
}

/// A camera sliding one way past a still sphere sees what a still camera sees of the sphere
/// sliding the other way: the two blurred images agree within their noise.
#[test]
fn a_moving_camera_blurs_as_the_scene_moving_the_other_way() {
    const SPP: u32 = 128;
    let still_sphere = format!(
        "double3 xformOp:translate = (0, 0, {})\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
        -DEPTH
    );
    // The camera moves by −(X1 − X0) while the shutter is open, starting at −X0 so that the
    // sphere starts where the sliding one does.
    let camera = format!(
        "double3 xformOp:translate.timeSamples = {{ 0: ({}, 0, 0), 1: ({}, 0, 0) }}\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
        -X0, -X1
    );
    let moving_camera = render(&scene("camera.usda", &sliding(0.0, 1.0, &still_sphere, &camera)), SPP);
    let moving_sphere = render(&scene("sphere.usda", &sliding(0.0, 1.0, &slide_ops(), "")), SPP);
    let (a, b) = (moving_camera.f32_channel("A").unwrap(), moving_sphere.f32_channel("A").unwrap());
    let mean = a.iter().zip(b).map(|(x, y)| (x - y).abs() as f64).sum::<f64>() / a.len() as f64;
    assert!(mean < 0.01, "mean alpha difference {mean}");
    let partial = a.iter().filter(|&&x| x > 0.1 && x < 0.9).count();
    assert!(partial > a.len() / 2, "the moving camera blurs ({partial} partly covered pixels)");
}

/// A stage at frame 0 with a camera at `at` looking down −z, its shutter open from 0 to `close`.
fn camera_above(at: DVec3, close: f64) -> String {
    format!(
        "#usda 1.0\n(\n    startTimeCode = 0\n)\ndef Camera \"Cam\" {{\n    double3 xformOp:translate = ({}, {}, {})\n    \
         uniform token[] xformOpOrder = [\"xformOp:translate\"]\n    double shutter:open = 0\n    double shutter:close = {close}\n}}",
        at.x, at.y, at.z
    )
}

/// Uniform numbers in `[0, 1)` from a xorshift generator seeded with `seed` (not 0).
fn uniform_numbers(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A ray straight down from `origin` at ray time `tau` hits `scene` at `distance` (within
/// 1e-4), and a shadow ray a little longer is occluded: the BVH boxes hold `what` there.
fn assert_hit_straight_down(scene: &strata::render::Scene, origin: DVec3, distance: f64, tau: f64, what: &str) {
    let (o, down, tau) = (origin.as_vec3(), -glam::Vec3::Z, tau as f32);
    let hit = scene
        .accel
        .intersect_at(o, down, 0.0, f32::INFINITY, tau)
        .unwrap_or_else(|| panic!("no hit on {what} at time {tau}"));
    assert!((hit.t as f64 - distance).abs() < 1e-4, "hit at {} instead of {distance} ({what}, time {tau})", hit.t);
    assert!(scene.accel.occluded_at(o, down, 0.0, distance as f32 + 0.1, tau));
}

/// A deforming mesh's BVH bounds contain it at every time: a height field whose vertices
/// rise by different amounts while the whole sheet slides along x, sampled at frames 0 and
/// 1, is met by a ray straight down at random points of it at random times exactly where
/// USD's linearly interpolated points put it (a box that missed the triangle there would
/// lose the hit).
#[test]
fn a_deforming_meshs_bounds_contain_it_at_all_times() {
    const N: usize = 6;
    let height = |i: usize, j: usize| ((i * 7 + j * 3) % 5) as f64 * 0.4;
    let mut p0 = Vec::new();
    let mut p1 = Vec::new();
    for j in 0..=N {
        for i in 0..=N {
            p0.push(DVec3::new(i as f64, j as f64, 0.0));
            p1.push(DVec3::new(i as f64 + 0.5, j as f64, height(i, j)));
        }
    }
    let (mut counts, mut indices) = (Vec::new(), Vec::new());
    for j in 0..N {
        for i in 0..N {
            let v = j * (N + 1) + i;
            counts.push("4".to_string());
            indices.extend([v, v + 1, v + N + 2, v + N + 1].map(|x| x.to_string()));
        }
    }
    let list = |ps: &[DVec3]| ps.iter().map(|p| format!("({}, {}, {})", p.x, p.y, p.z)).collect::<Vec<_>>().join(", ");
    let text = format!(
        r#"{}
def Mesh "Sheet" {{
    uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [{}]
    int[] faceVertexIndices = [{}]
    point3f[] points.timeSamples = {{ 0: [{}], 1: [{}] }}
}}
"#,
        camera_above(DVec3::new(3.0, 3.0, 20.0), 1.0),
        counts.join(", "),
        indices.join(", "),
        list(&p0),
        list(&p1)
    );
    let (scene, _) = common::scene_file(&scene("sheet.usda", &text));
    assert_eq!(scene.motion.deforming_prims, 1, "{:?}", scene.motion);
    assert!(scene.has_motion());
    let mut uniform = uniform_numbers(0x2545_f491_4f6c_dd1d);
    for _ in 0..2000 {
        let tau = uniform();
        // A point of the sheet at tau: bilinear in its quad's interpolated corners, on one of
        // the two triangles the quad is split into (fan from its first corner).
        let (i, j) = ((uniform() * N as f64) as usize, (uniform() * N as f64) as usize);
        let corner = |di: usize, dj: usize| {
            let v = (j + dj) * (N + 1) + i + di;
            p0[v].lerp(p1[v], tau)
        };
        let (a, b, c, d) = (corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1));
        let (u, w) = (uniform(), uniform());
        let (u, w) = if u + w > 1.0 { (1.0 - u, 1.0 - w) } else { (u, w) };
        let (e, f) = if uniform() < 0.5 { (b, c) } else { (c, d) };
        let target = a + (e - a) * u + (f - a) * w;
        let origin = target + DVec3::new(0.0, 0.0, 10.0);
        assert_hit_straight_down(&scene, origin, 10.0, tau, &format!("the sheet at {target}"));
    }
}

/// Lights are not motion-blurred: a light that moves inside the open shutter, and one whose
/// intensity changes, are each named by one warning; a light that holds still is not, and
/// with the shutter closed none is.
#[test]
fn lights_that_move_inside_the_shutter_are_named_by_a_warning() {
    let text = |close: f64| {
        format!(
            r#"{}
def Sphere "Ball" {{}}
def SphereLight "Moving" {{
    double3 xformOp:translate.timeSamples = {{ 0: (-2, 3, 0), 1: (2, 3, 0) }}
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def DistantLight "Dimming" {{
    float inputs:intensity.timeSamples = {{ 0: 2, 1: 1 }}
}}
def DistantLight "Still" {{
    float inputs:intensity.timeSamples = {{ 0: 2, 1: 2 }}
}}
"#,
            camera_above(DVec3::new(0.0, 0.0, 10.0), close)
        )
    };
    let warnings = |close: f64| {
        let path = scene(&format!("lights_{close}.usda"), &text(close));
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_strata"))
            .args(["render", path.to_str().unwrap(), "--res", "8x8", "--spp", "1", "-o"])
            .arg(path.with_extension("exr"))
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        stderr.lines().filter(|l| l.contains("while the shutter is open")).map(String::from).collect::<Vec<_>>()
    };
    let open = warnings(1.0);
    assert_eq!(open.len(), 2, "{open:?}");
    assert!(open.iter().any(|l| l.contains("`/Moving`")) && open.iter().any(|l| l.contains("`/Dimming`")), "{open:?}");
    assert!(warnings(0.0).is_empty());
}
