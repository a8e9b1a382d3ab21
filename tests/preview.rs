//! UsdPreviewSurface networks and `material:binding`, on fixtures written by Pixar's USD
//! library (`tools/make_preview_fixtures.py`, in `tests/fixtures/usd/preview/`). References
//! are independent of strata: texels come from decoding `checker.png` with the `png` crate
//! (strata decodes with `image`) and the sRGB formula written out here, and the pixel → st
//! mapping from the camera's geometry (see the generator: the quad fills the frame exactly).

mod common;

use std::path::Path;
use strata::backend::BackendKind;
use strata::ir::wired::PassOptions;
use strata::render::{Image, LayerMode, RenderSettings, Scene, render};
use strata::session::{SceneSource, Session, SessionOptions, check_file};

const DIR: &str = "tests/fixtures/usd/preview";
/// Image size: one pixel per texel of the 32 × 32 checker.
const RES: usize = 32;

fn render_fixture(name: &str) -> Image {
    common::render_file(Path::new(&format!("{DIR}/{name}")), &common::settings(RES, RES, 4, 3, 2))
}

/// The albedo AOV at pixel (x, y), y = 0 the top row.
fn albedo(image: &Image, x: usize, y: usize) -> [f32; 3] {
    let at = |c: &str| image.f32_channel(c).expect("albedo channel")[y * RES + x];
    [at("albedo.R"), at("albedo.G"), at("albedo.B")]
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// `checker.png` decoded with the `png` crate: (width, RGB bytes of each texel, top row first).
fn checker() -> (usize, Vec<[u8; 3]>) {
    let file = std::fs::File::open(format!("{DIR}/checker.png")).unwrap();
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.color_type, info.bit_depth), (png::ColorType::Rgb, png::BitDepth::Eight));
    let texels = buf[..info.buffer_size()].chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    (info.width as usize, texels)
}

/// The linear colour of the texel under pixel (x, y): the pixel centre sees
/// st = ((x + 0.5) / RES, 1 − (y + 0.5) / RES), and texture row 0 is t = 1.
fn texel_under(x: usize, y: usize) -> [f32; 3] {
    let (width, texels) = checker();
    let s = (x as f32 + 0.5) / RES as f32;
    let t = 1.0 - (y as f32 + 0.5) / RES as f32;
    let (tx, ty) = ((s * width as f32) as usize, ((1.0 - t) * width as f32) as usize);
    texels[ty * width + tx].map(|c| srgb_to_linear(c as f32 / 255.0))
}

fn assert_close(got: [f32; 3], want: [f32; 3], at: &str) {
    let d = (0..3).map(|k| (got[k] - want[k]).abs()).fold(0.0, f32::max);
    assert!(d < 1e-4, "{at}: got {got:?}, want {want:?}");
}

/// Pixels well inside each 8 × 8 cell (bilinear filtering and the pixel footprint stay in it).
fn cell_centres() -> impl Iterator<Item = (usize, usize)> {
    (0..4).flat_map(|cy| (0..4).map(move |cx| (cx * 8 + 3, cy * 8 + 4)))
}

/// Every fixture exists as Pixar's usd-core wrote it in both formats: text and crate.
const FORMATS: [&str; 2] = ["usda", "usdc"];

#[test]
fn albedo_aov_is_the_srgb_decoded_texel_under_each_pixel() {
    let mut distinct = Vec::new();
    for ext in FORMATS {
        let image = render_fixture(&format!("textured.{ext}"));
        for (x, y) in cell_centres() {
            let want = texel_under(x, y);
            assert_close(albedo(&image, x, y), want, &format!("textured.{ext}: pixel ({x}, {y})"));
            distinct.push(want.map(f32::to_bits));
        }
    }
    distinct.sort();
    distinct.dedup();
    assert_eq!(
        distinct.len(),
        16,
        "the checker's 16 cells have distinct colours, so a flipped or shifted mapping fails"
    );
}

/// Issue 11's acceptance case: a usd-core-written asset (text and binary crate) with a
/// textured UsdPreviewSurface bound by `material:binding`, and a slot-bound dirt layer over
/// it: the texture shows where the dirt's mask is 0.
#[test]
fn the_texture_shows_under_a_slot_bound_dirt_layer() {
    for ext in FORMATS {
        let image = render_fixture(&format!("dirt.{ext}"));
        // dirt.ash: diffuse (0.35, 0.25, 0.1) with mask 1 where u ≥ 0.5, else 0.
        for (x, y) in cell_centres() {
            let want = if x < RES / 2 { texel_under(x, y) } else { [0.35, 0.25, 0.1] };
            assert_close(albedo(&image, x, y), want, &format!("dirt.{ext}: pixel ({x}, {y})"));
        }
    }
}

#[test]
fn geom_subset_faces_show_the_subset_material() {
    for ext in FORMATS {
        let image = render_fixture(&format!("subset.{ext}"));
        for y in [2, 16, 29] {
            // The left face keeps the mesh's Blue, the right face (the subset) is Red.
            assert_close(albedo(&image, 5, y), [0.1, 0.2, 0.8], &format!("subset.{ext}: left face"));
            assert_close(albedo(&image, 26, y), [0.8, 0.1, 0.1], &format!("subset.{ext}: right face (subset)"));
        }
    }
}

#[test]
fn layers_list_material_binding_below_slots() {
    let run = |file: &str| {
        let out = common::run_strata(&["layers", &format!("{DIR}/{file}")], std::time::Duration::from_secs(60))
            .expect("strata finishes");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };
    let dirt = run("dirt.usda");
    let (base, slot) = (dirt.find("material:binding").unwrap(), dirt.find("/Looks/Dirt").unwrap());
    assert!(base < slot, "bottom to top: material:binding first\n{dirt}");
    insta::assert_snapshot!("preview_dirt_layers", dirt);
    assert_eq!(run("dirt.usdc"), dirt, "the crate composes the same stacks as the text");
    // Strength and purposes: /World/Strong's strongerThanDescendants Green beats the ball's
    // own Red, /World/Weak's does not; `full` beats `preview`.
    insta::assert_snapshot!("preview_strength_layers", run("strength.usda"));
    insta::assert_snapshot!("preview_subset_layers", run("subset.usda"));
}

#[test]
fn a_materialx_surface_id_is_read_as_its_substance() {
    // `unknown_shader.usda` was written when strata had no MaterialX: its
    // ND_standard_surface_surfaceshader is now the built-in standard_surface (tests/mtlx.rs
    // checks unknown ids and nodes), so no warning names it.
    let (diags, sources, _) = check_file(Path::new(&format!("{DIR}/unknown_shader.usda")));
    assert!(!diags.has_errors());
    let text = diags.render(&sources);
    assert!(!text.contains("ND_standard_surface_surfaceshader"), "{text}");
}

#[test]
fn the_texture_node_reads_png() {
    // strata's own texture() node: PNG decodes (it used to fail with "file identifier missing").
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join(DIR).join("checker.png");
    let lib = common::library(&format!(
        "substance t {{ node tx = texture(file: {:?}); node c = customChannelColor(name: \"tex\", value: tx.out); }}",
        file.to_str().unwrap()
    ));
    let code = common::compile_stack(&lib, &["t".to_string()], BackendKind::Jit, true);
    let mut out = vec![0.0; 3];
    for (x, y) in cell_centres() {
        let g = strata::abi::Globals {
            u: (x as f32 + 0.5) / RES as f32,
            v: 1.0 - (y as f32 + 0.5) / RES as f32,
            ..Default::default()
        };
        code.channels(&g, 0, &mut out).unwrap();
        assert_close([out[0], out[1], out[2]], texel_under(x, y), &format!("texel ({x}, {y})"));
    }
}

#[test]
fn jit_and_interpreter_agree_on_a_preview_network() {
    let path = format!("{DIR}/dirt.usda");
    let image = |backend| {
        let options = SessionOptions { backend, passes: PassOptions::default(), ..Default::default() };
        let mut session = Session::open(SceneSource::File(Path::new(&path).to_path_buf()), options);
        session.compile().expect("compiles");
        let mut diags = session.take_diagnostics();
        let (stage, compiled) = (session.stage().expect("opened"), session.compiled().expect("compiled"));
        let scene =
            Scene::from_stage(stage, &|p| compiled.prim_material.get(p).copied(), &mut diags).expect("scene builds");
        let refs = compiled.refs();
        let settings = RenderSettings {
            width: 16,
            height: 16,
            spp: 2,
            seed: 5,
            threads: Some(2),
            max_depth: 3,
            mode: LayerMode::Stochastic,
            ..Default::default()
        };
        render(&scene, &refs, &settings, None).expect("renders").0
    };
    let (jit, interp) = (image(BackendKind::Jit), image(BackendKind::Interp));
    for c in ["R", "G", "B", "albedo.R", "albedo.G", "albedo.B"] {
        assert_eq!(jit.f32_channel(c), interp.f32_channel(c), "channel {c}");
    }
}

#[test]
fn a_missing_or_broken_texture_is_one_warning_at_the_usd_attribute() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(format!("{DIR}/textured.usda")).unwrap();
    std::fs::write(dir.path().join("missing.usda"), text.replace("@checker.png@", "@missing.png@")).unwrap();
    std::fs::write(dir.path().join("broken.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
    std::fs::write(dir.path().join("broken.usda"), text.replace("@checker.png@", "@broken.png@")).unwrap();
    let line = text.lines().position(|l| l.contains("@checker.png@")).unwrap() + 1;
    for (file, message) in [("missing.usda", "cannot open texture"), ("broken.usda", "cannot read texture")] {
        let path = dir.path().join(file);
        let (diags, sources, _) = check_file(&path);
        let text = diags.render(&sources);
        // USD composes around it: the reader's fallback, and one warning.
        assert_eq!(diags.error_count(), 0, "{text}");
        assert_eq!(diags.items().iter().filter(|d| d.message.contains(message)).count(), 1, "{text}");
        assert!(text.contains(&format!("warning: {message}")), "{text}");
        assert!(text.contains(&format!("{file}:{line}:")), "located at the asset path: {text}");
    }
}
