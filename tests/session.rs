//! The `Session`'s update invariants (ARCHITECTURE.md, "The Session"): after a change it redoes
//! only what depends on it — counted through its statistics against what the composition
//! says depends on the change — and renders the same image, bit for bit, as a session opened
//! fresh on the changed files.

use std::path::{Path, PathBuf};
use strata::compose::slots::SlotFilter;
use strata::render::scene::SceneOptions;
use strata::render::{Image, Region, RenderSettings, Window, WindowSums};
use strata::scene::Value;
use strata::session::{Change, ChangeKind, Pass, SceneSource, Session, SessionOptions};

/// The default scene in `dir` with the dirt substance in `dirt.ash`, and an `unused.ash`
/// beside it.
fn split_default_scene(dir: &Path) -> PathBuf {
    std::fs::write(dir.join("unused.ash"), "substance unused { node d = diffuse(); surface = d.bsdf; }\n").unwrap();
    strata::session::write_split_default_scene(dir).unwrap()
}

fn settings() -> RenderSettings {
    RenderSettings { width: 48, height: 36, spp: 4, seed: 11, threads: Some(2), ..Default::default() }
}

/// Opens `path` and prepares it for rendering, panicking with the diagnostics on errors.
fn prepared(path: &Path) -> Session {
    let mut session = Session::open(SceneSource::File(path.to_path_buf()), SessionOptions::default());
    let options = SceneOptions::default();
    if session.prepare(&options).is_none() {
        panic!("{}", session.diagnostics().render(session.sources()));
    }
    session
}

fn render(session: &mut Session) -> Image {
    session.render(&Pass::full(settings()), None).expect("renders").0
}

/// The number of distinct composed materials whose slot stack binds `material`: what a
/// change to it must recompile, read from the composition (not from the update's counts).
fn compositions_using(session: &Session, material: &str) -> usize {
    let c = session.composed().expect("composed");
    let mut using: Vec<usize> =
        c.stacks
            .iter()
            .zip(&c.prim_material)
            .filter(|(stack, _)| {
                stack.layers.iter().any(|l| {
                    l.applied.material == material || l.overrides.iter().any(|o| o.applied.material == material)
                })
            })
            .map(|(_, &m)| m)
            .collect();
    using.sort();
    using.dedup();
    using.len()
}

fn edit(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{from} in {}", path.display());
    std::fs::write(path, text.replacen(from, to, 1)).unwrap();
}

#[test]
fn a_substance_file_change_recompiles_only_the_compositions_that_use_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = split_default_scene(dir.path());
    let mut session = prepared(&scene);
    let before = render(&mut session);
    let materials = session.compiled().unwrap().materials.len();
    let using_dirt = compositions_using(&session, "/Looks/Dirt");
    assert!(using_dirt > 0 && using_dirt < materials, "{using_dirt} of {materials}");
    let stats = session.stats().clone();

    edit(&dir.path().join("dirt.ash"), "color(0.2, 0.15, 0.1)", "color(0.1, 0.3, 0.6)");
    let report = session.apply_change(&Change::File(dir.path().join("dirt.ash")));
    assert_eq!(report.kind, ChangeKind::Substance);
    assert!(!report.failed, "{}", session.diagnostics().render(session.sources()));
    assert_eq!(report.recompiled, using_dirt, "{report:?}");
    assert_eq!(report.reused, materials - using_dirt, "{report:?}");
    assert_eq!(session.stats().materials_compiled - stats.materials_compiled, using_dirt);
    assert!(!report.restaged && !report.geometry_rebuilt, "{report:?}");
    assert_eq!(session.stats().scene_builds, stats.scene_builds, "geometry and BVH kept");
    assert_eq!(session.stats().stage_reads, stats.stage_reads, "no layer read again");

    let updated = render(&mut session);
    assert_ne!(updated, before, "the dirt colour shows");
    let fresh = render(&mut prepared(&scene));
    assert!(updated == fresh, "an updated session renders what a fresh one does, bit for bit");
    assert!(render(&mut session) == updated, "rendering does not change the session");
}

#[test]
fn a_change_to_an_unrelated_file_recompiles_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = split_default_scene(dir.path());
    let mut session = prepared(&scene);
    let before = render(&mut session);
    let stats = session.stats().clone();
    for file in ["unused.ash", "notes.txt"] {
        std::fs::write(dir.path().join(file), "changed").unwrap();
        let report = session.apply_change(&Change::File(dir.path().join(file)));
        assert_eq!(report.kind, ChangeKind::Unrelated, "{file}");
        assert_eq!((report.recompiled, report.recomposed, report.geometry_rebuilt), (0, false, false), "{file}");
    }
    assert_eq!(session.stats(), &stats);
    assert!(render(&mut session) == before);
}

#[test]
fn a_layer_change_keeps_geometry_unless_it_moves_something() {
    let dir = tempfile::tempdir().unwrap();
    let scene = split_default_scene(dir.path());
    let mut session = prepared(&scene);
    let using_floor = compositions_using(&session, "/Looks/Floor");
    let builds = session.stats().scene_builds;

    // A material input authored in the layer: the floor's composition only, geometry kept.
    edit(&scene, "float inputs:tiles = 6", "float inputs:tiles = 3");
    let report = session.apply_change(&Change::File(scene.clone()));
    assert_eq!(report.kind, ChangeKind::Layer);
    assert!(report.restaged && report.recomposed && !report.geometry_rebuilt, "{report:?}");
    assert_eq!(report.recompiled, using_floor, "{report:?}");
    assert_eq!(session.stats().scene_builds, builds);
    assert!(render(&mut session) == render(&mut prepared(&scene)));

    // A ball moved: geometry and BVH are built again; no material is recompiled.
    edit(&scene, "float3 xformOp:translate = (1.8, 0.8, 0)", "float3 xformOp:translate = (1.5, 0.8, 0.3)");
    let report = session.apply_change(&Change::File(scene.clone()));
    assert!(report.geometry_rebuilt && report.recompiled == 0, "{report:?}");
    assert_eq!(session.stats().scene_builds, builds + 1);
    assert!(render(&mut session) == render(&mut prepared(&scene)));
}

#[test]
fn an_input_value_set_in_memory_renders_as_if_authored() {
    let dir = tempfile::tempdir().unwrap();
    let scene = split_default_scene(dir.path());
    let mut session = prepared(&scene);
    let using_metal = compositions_using(&session, "/Looks/Metal");
    let report = session.apply_change(&Change::Value {
        prim: "/Looks/Metal/Surface".into(),
        attribute: "inputs:roughness".into(),
        type_name: "float".into(),
        value: Value::Float(0.6),
    });
    assert_eq!(report.kind, ChangeKind::Value);
    assert!(!report.restaged && !report.geometry_rebuilt, "{report:?}");
    assert_eq!(report.recompiled, using_metal, "{report:?}");
    // The oracle: the same value authored in the layer, opened fresh.
    edit(
        &scene,
        "uniform token info:strata:sourceAsset:subIdentifier = \"brushed_metal\"",
        "uniform token info:strata:sourceAsset:subIdentifier = \"brushed_metal\"\n            float inputs:roughness = 0.6",
    );
    assert!(render(&mut session) == render(&mut prepared(&scene)));
}

/// Muting a slot in memory renders what the scene renders with that slot's bindings
/// removed from the file; soloing renders the slot alone where it is bound; clearing the
/// filter renders the original image bit for bit. The files are never touched.
#[test]
fn muted_and_soloed_slots_render_as_if_unbound() {
    let dir = tempfile::tempdir().unwrap();
    let scene = split_default_scene(dir.path());
    let text = std::fs::read_to_string(&scene).unwrap();
    let mut session = prepared(&scene);
    let original = render(&mut session);

    let muted = SlotFilter { muted: ["050".to_string()].into(), solo: None };
    let report = session.set_slot_filter(muted);
    assert!(!report.failed && !report.geometry_rebuilt && report.recompiled > 0, "{report:?}");
    let without_dirt = render(&mut session);
    assert_ne!(without_dirt, original, "muting the dirt shows");
    // The oracle: the dirt bindings (and their override) deleted from the layer, opened fresh.
    edit(&scene, "rel material:slotBinding:_050 = </Looks/Dirt>", "");
    edit(&scene, "rel material:slotBinding:_050:_:_010 = </Looks/DirtMarker>", "");
    assert!(without_dirt == render(&mut prepared(&scene)), "muted == unbound in the file");
    std::fs::write(&scene, &text).unwrap();

    // Solo the dirt: where it is bound it is the only layer.
    session.set_slot_filter(SlotFilter { muted: Default::default(), solo: Some("050".into()) });
    let solo = render(&mut session);
    edit(&scene, "rel material:slotBinding:_000 = </Looks/Metal>", "");
    edit(&scene, "rel material:slotBinding:_000:_:_010 = </Looks/RedPaint>", "");
    edit(
        &scene,
        "def Xform \"Balls\"\n    {",
        "def Xform \"Balls\"\n    {\n        rel material:slotBinding:_000 = None",
    );
    edit(
        &scene,
        "rel material:slotBinding:_050 = None",
        "rel material:slotBinding:_000 = </Looks/Clay>\n            rel material:slotBinding:_050 = None",
    );
    assert!(solo == render(&mut prepared(&scene)), "solo == the other slots unbound where the slot is");
    std::fs::write(&scene, &text).unwrap();

    let report = session.set_slot_filter(SlotFilter::default());
    assert!(!report.failed);
    assert!(render(&mut session) == original, "unmuting restores the image bit for bit");
    assert_eq!(std::fs::read_to_string(&scene).unwrap(), text);
}

/// A 4x4 RGB PNG of one colour.
fn solid_png(rgb: [u8; 3]) -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, 4, 4);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(&rgb.repeat(16)).unwrap();
    writer.finish().unwrap();
    bytes
}

#[test]
fn a_texture_change_reloads_texels_without_recompiling() {
    let dir = tempfile::tempdir().unwrap();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/usd/preview");
    std::fs::copy(fixtures.join("textured.usda"), dir.path().join("textured.usda")).unwrap();
    std::fs::copy(fixtures.join("checker.png"), dir.path().join("checker.png")).unwrap();
    let scene = dir.path().join("textured.usda");
    let mut session = prepared(&scene);
    let before = render(&mut session);
    let stats = session.stats().clone();

    std::fs::write(dir.path().join("checker.png"), solid_png([200, 30, 30])).unwrap();
    let report = session.apply_change(&Change::File(dir.path().join("checker.png")));
    assert_eq!(report.kind, ChangeKind::Texture);
    assert!(report.textures_reloaded >= 1 && report.recompiled == 0 && !report.geometry_rebuilt, "{report:?}");
    assert_eq!(session.stats(), &stats, "nothing composed, compiled or built");
    let updated = render(&mut session);
    assert_ne!(updated, before);
    assert!(updated == render(&mut prepared(&scene)));
}

/// The channel `c` of `image` cropped to `region`.
fn crop(image: &Image, c: usize, region: Region) -> strata::render::ChannelData {
    use strata::render::ChannelData::{F32, U32};
    let rows = region.y..region.y + region.height;
    let pick = |w: usize| rows.clone().flat_map(move |y| (region.x..region.x + region.width).map(move |x| y * w + x));
    match &image.channels[c].data {
        F32(v) => F32(pick(image.width).map(|i| v[i]).collect()),
        U32(v) => U32(pick(image.width).map(|i| v[i]).collect()),
    }
}

/// A pass over a region renders that crop of the full image bit for bit (every channel, the
/// Cryptomatte ranks included), whatever the thread count; the full sample range is the full render.
#[test]
fn a_window_renders_the_full_images_pixels() {
    let mut session = Session::open(SceneSource::Default, SessionOptions::default());
    session.prepare(&SceneOptions::default()).expect("prepares");
    let full = render(&mut session);
    for (region, threads) in [
        (Region { x: 0, y: 0, width: 48, height: 36 }, 2),
        (Region { x: 5, y: 7, width: 13, height: 11 }, 1),
        (Region { x: 47, y: 35, width: 1, height: 1 }, 2),
        (Region { x: 0, y: 20, width: 48, height: 3 }, 3),
    ] {
        let settings = RenderSettings { threads: Some(threads), ..settings() };
        let pass = Pass { window: Window { region: Some(region), samples: Some(0..4) }, ..Pass::full(settings) };
        let part = session.render(&pass, None).expect("renders").0;
        assert_eq!((part.width, part.height), (region.width, region.height));
        assert_eq!(part.channels.len(), full.channels.len());
        for (c, channel) in part.channels.iter().enumerate() {
            assert_eq!(channel.name, full.channels[c].name);
            assert!(channel.data == crop(&full, c, region), "{} differs in {region:?}", channel.name);
        }
    }
}

/// Sample ranges that cover `0..spp` hold every sample once: their average weighted by their
/// lengths is the full render's (to float rounding: each part sums its own samples), and a
/// range is the same samples whichever pass renders it.
#[test]
fn sample_ranges_split_the_full_render() {
    let mut session = Session::open(SceneSource::Default, SessionOptions::default());
    session.prepare(&SceneOptions::default()).expect("prepares");
    let spp = 8;
    let settings = RenderSettings { spp, ..settings() };
    let full = session.render(&Pass::full(settings.clone()), None).expect("renders").0;
    let parts = [0..3, 3..4, 4..8];
    let rendered: Vec<Image> = parts
        .iter()
        .map(|samples| {
            let window = Window { region: None, samples: Some(samples.clone()) };
            session.render(&Pass { window, ..Pass::full(settings.clone()) }, None).expect("renders").0
        })
        .collect();
    let beauty = |image: &Image, name: &str| image.f32_channel(name).expect("channel").to_vec();
    let mut differs = 0;
    for name in ["R", "G", "B", "A", "albedo.R"] {
        let whole = beauty(&full, name);
        let mut merged = vec![0.0f64; whole.len()];
        for (samples, image) in parts.iter().zip(&rendered) {
            for (m, v) in merged.iter_mut().zip(beauty(image, name)) {
                *m += f64::from(v) * samples.len() as f64 / f64::from(spp);
            }
        }
        for (w, m) in whole.iter().zip(&merged) {
            assert!((f64::from(*w) - m).abs() <= 1e-5 * (1.0 + m.abs()), "{name}: {w} vs {m}");
        }
        // The parts are not the whole: a range really renders only its samples.
        differs += beauty(&rendered[1], name).iter().zip(&whole).filter(|(a, b)| a != b).count();
    }
    assert!(differs > 0, "one sample of eight rendered the same image as all eight");
    // The same range again, through another pass, is the same image bit for bit.
    let again = Window { region: None, samples: Some(3..4) };
    let image = session.render(&Pass { window: again, ..Pass::full(settings.clone()) }, None).expect("renders").0;
    assert_eq!(image, rendered[1]);
}

/// A window outside the image or an empty sample range is refused, not clamped.
#[test]
fn windows_outside_the_image_are_refused() {
    let mut session = Session::open(SceneSource::Default, SessionOptions::default());
    session.prepare(&SceneOptions::default()).expect("prepares");
    for window in [
        Window { region: Some(Region { x: 40, y: 0, width: 9, height: 1 }), samples: None },
        Window { region: Some(Region { x: 0, y: 0, width: 0, height: 1 }), samples: None },
        Window { region: None, samples: Some(2..2) },
        Window { region: None, samples: Some(3..5) },
    ] {
        let pass = Pass { window: window.clone(), ..Pass::full(settings()) };
        assert!(session.render(&pass, None).is_err(), "{window:?} rendered");
    }
}

/// Sample ranges rendered apart and merged as exact sums make the image one pass over all
/// the samples renders, bit for bit, for 1, 2, 3 and 7 parts merged in any order: every
/// channel, the Cryptomatte ranks and the integer channels' nearest-sample ids included.
#[test]
fn sample_ranges_merge_into_the_full_image_bit_for_bit() {
    let mut session = Session::open(SceneSource::Default, SessionOptions::default());
    session.prepare(&SceneOptions::default()).expect("prepares");
    let spp = 14;
    let settings = RenderSettings { spp, width: 24, height: 18, ..settings() };
    let full = session.render(&Pass::full(settings.clone()), None).expect("renders").0;
    for cuts in [vec![], vec![7], vec![1, 9], vec![1, 2, 3, 5, 8, 13]] {
        let mut bounds = vec![0];
        bounds.extend(&cuts);
        bounds.push(spp);
        let mut parts: Vec<WindowSums> = bounds
            .windows(2)
            .map(|b| {
                let window = Window { region: None, samples: Some(b[0]..b[1]) };
                session.render_sums(&Pass { window, ..Pass::full(settings.clone()) }, None).expect("renders").2
            })
            .collect();
        // Merge in a scrambled order: the last part first.
        parts.rotate_right(1);
        let mut merged = parts[0].clone();
        for part in &parts[1..] {
            merged.merge(part).expect("disjoint samples of the same pixels");
        }
        let image = session.image_from_sums(&merged).expect("prepared");
        assert!(image == full, "{} parts merged differ from the full image", bounds.len() - 1);
        assert!(merged.merge(&parts[0]).is_err(), "samples merged twice");
    }
}

/// Opens `path` with live inputs (as `strata view` does) and prepares it.
fn prepared_live(path: &Path) -> Session {
    let passes = strata::ir::wired::PassOptions { live_inputs: true, ..Default::default() };
    let mut session =
        Session::open(SceneSource::File(path.to_path_buf()), SessionOptions { passes, ..Default::default() });
    if session.prepare(&SceneOptions::default()).is_none() {
        panic!("{}", session.diagnostics().render(session.sources()));
    }
    session
}

/// `tests/in/farm/moving.usda` opened at `time` and prepared.
fn moving_at(time: f64) -> Session {
    farm_scene_at("moving.usda", time)
}

/// `tests/in/farm/NAME` opened at `time` and prepared.
fn farm_scene_at(name: &str, time: f64) -> Session {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/in/farm").join(name);
    let options = SessionOptions { time: Some(strata::scene::TimeCode::At(time)), ..SessionOptions::default() };
    let mut session = Session::open(SceneSource::File(scene), options);
    if session.prepare(&SceneOptions::default()).is_none() {
        panic!("{}", session.diagnostics().render(session.sources()));
    }
    session
}

/// With live inputs (the view's option) a float or colour input is a parameter of the
/// compiled code: the session renders what `render`'s folded constants render; an edit
/// rewrites the material's parameter block — nothing composed, nothing compiled (the
/// compile counter stays) — and renders as the same value authored in the file and compiled
/// with folding, bit for bit (the parameter loads feed the same operations with the same
/// bits the folder would have evaluated with `runtime::math`'s semantics).
#[test]
fn a_live_input_edit_rewrites_a_parameter_block_and_renders_as_if_authored_and_folded() {
    let dir = tempfile::tempdir().unwrap();
    let scene = split_default_scene(dir.path());
    let mut live = prepared_live(&scene);
    assert!(render(&mut live) == render(&mut prepared(&scene)), "live inputs render as folded constants");

    let (compiled, compositions) = (live.stats().materials_compiled, live.stats().compositions);
    let edits = [
        ("/Looks/Metal/Surface", "inputs:roughness", "float", Value::Float(0.6)),
        ("/Looks/Dirt/Surface", "inputs:coverage", "float", Value::Float(0.3)),
        ("/Looks/Dirt/Surface", "inputs:dirt_color", "color3f", Value::Tuple(vec![0.1, 0.3, 0.2])),
    ];
    let before = render(&mut live);
    for (prim, attribute, type_name, value) in &edits {
        let report = live.apply_change(&Change::Value {
            prim: prim.to_string(),
            attribute: attribute.to_string(),
            type_name: type_name.to_string(),
            value: value.clone(),
        });
        assert!(!report.failed && !report.recomposed && report.recompiled == 0, "{report:?}");
        assert!(!report.geometry_rebuilt, "{report:?}");
    }
    assert_eq!(live.stats().materials_compiled, compiled, "no material was compiled");
    assert_eq!(live.stats().compositions, compositions, "the stage was not composed again");
    assert!(live.stats().parameter_writes >= 3, "{:?}", live.stats());
    let edited = render(&mut live);
    assert!(edited != before, "the edits show");

    // The oracle: the same values authored in the layer, opened fresh, folded as `render` does.
    edit(
        &scene,
        "uniform token info:strata:sourceAsset:subIdentifier = \"brushed_metal\"",
        "uniform token info:strata:sourceAsset:subIdentifier = \"brushed_metal\"\n            float inputs:roughness = 0.6",
    );
    edit(
        &scene,
        "uniform token info:strata:sourceAsset:subIdentifier = \"dirt\"",
        "uniform token info:strata:sourceAsset:subIdentifier = \"dirt\"\n            float inputs:coverage = 0.3\n            color3f inputs:dirt_color = (0.1, 0.3, 0.2)",
    );
    assert!(edited == render(&mut prepared(&scene)), "the edited block renders as the authored, folded values");

    // A float input of exactly 0 or 1 stays folded (as a mask it is a compile-time fact: a
    // pruned layer, one that hides the layers below, and the layer mode that follows):
    // crossing it changes the class and compiles, and still renders as folded.
    let report = live.apply_change(&Change::Value {
        prim: "/Looks/Dirt/Surface".into(),
        attribute: "inputs:coverage".into(),
        type_name: "float".into(),
        value: Value::Float(1.0),
    });
    assert!(!report.failed && report.recompiled > 0, "{report:?}");
    edit(&scene, "float inputs:coverage = 0.3", "float inputs:coverage = 1");
    assert!(render(&mut live) == render(&mut prepared(&scene)), "a folded fact renders as folded");

    // An edit that is not a live input (an int, a string) still composes and compiles.
    let report = live.apply_change(&Change::Value {
        prim: "/Looks/Metal/Surface".into(),
        attribute: "info:strata:sourceAsset:subIdentifier".into(),
        type_name: "token".into(),
        value: Value::Token("clay".into()),
    });
    assert!(report.recomposed && report.recompiled > 0, "{report:?}");
}

#[test]
fn a_new_time_code_moves_instances_and_renders_what_a_fresh_session_renders() {
    // Frame 2: the camera, a parent (with a cube, a sphere that also moves on its own, an
    // instanceable reference, a point instancer whose points move too and a light under it)
    // move: instances only.
    // Frame 3: a ball's visibility changes: built again, and says why. Frame 4: moves again.
    let mut session = moving_at(1.0);
    let first = render(&mut session);
    let blas = session.stats().blas_builds;
    assert!(blas >= 5, "world, the moving prims' own, the shared reference, the pebble: {blas}");
    let mut images = vec![first];
    for (time, moved) in [(2.0, true), (3.0, false), (4.0, true)] {
        let before = session.stats().clone();
        let report = session.set_time(strata::scene::TimeCode::At(time));
        assert_eq!(report.instances_moved, moved, "{time}: {report:?}");
        assert_eq!(report.recompiled, 0, "{time}: {report:?}");
        let after = session.stats();
        if moved {
            assert!(!report.geometry_rebuilt && !report.recomposed, "{time}: {report:?}");
            assert_eq!(after.blas_builds, before.blas_builds, "{time}: no bottom-level BVH is built again");
            assert_eq!(after.scene_builds, before.scene_builds);
            assert_eq!(after.compositions, before.compositions, "materials are not composed again");
            assert_eq!(after.instance_moves, before.instance_moves + 1);
        } else {
            assert!(report.geometry_rebuilt, "{time}: {report:?}");
            let why = report.rebuild_reason.as_deref().unwrap_or("");
            assert!(why.contains("/Blink.visibility"), "{why}");
            assert!(after.blas_builds > before.blas_builds);
        }
        let image = render(&mut session);
        assert!(image == render(&mut moving_at(time)), "frame {time} differs from a fresh session's");
        assert!(!images.contains(&image), "frame {time} looks like an earlier one: the test proves nothing");
        images.push(image);
    }
}

#[test]
fn a_new_time_code_builds_only_the_deforming_prims_bvhs() {
    // A ground and a prop stay; a cloth's points change and a skinned arm bends every frame.
    // The oracle: a fresh session opened at that frame; the counters show the static props
    // built once.
    frames_build_only_the_deforming_prims_bvhs("deforming.usda");
}

#[test]
fn under_an_open_shutter_a_new_time_code_keys_only_the_deforming_prims_again() {
    // The same under an open shutter: the cloth's and the arm's deformation keys are the
    // frame's (its shutter interval), so a new frame builds their BVHs again with keys at its
    // own times, and still not the ground's and the prop's. The cloth's points are the same
    // at every whole frame (only inside the shutters do they differ): it is built again for
    // the shutter alone.
    frames_build_only_the_deforming_prims_bvhs("deforming_blur.usda");
    let deforming = |session: &Session| session.scene().expect("prepared").motion.deforming_prims;
    let mut session = farm_scene_at("deforming_blur.usda", 1.0);
    assert_eq!(deforming(&session), 2, "the cloth and the arm deform inside every frame's shutter");
    session.set_time(strata::scene::TimeCode::At(2.0));
    assert_eq!(deforming(&session), 2, "moved to frame 2: they still deform");
}

/// Frames 2 and 3 of `tests/in/farm/NAME` (a cloth and a skinned arm that deform, a ground
/// and a prop that stay) move the scene: only the two deforming prims' BVHs are built again,
/// and each frame renders what a fresh session opened at it renders, bit for bit.
fn frames_build_only_the_deforming_prims_bvhs(name: &str) {
    let mut session = farm_scene_at(name, 1.0);
    let mut images = vec![render(&mut session)];
    assert_eq!(session.stats().blas_builds, 3, "the world's (ground, prop), the cloth's, the arm's");
    for time in [2.0, 3.0] {
        let before = session.stats().clone();
        let report = session.set_time(strata::scene::TimeCode::At(time));
        assert!(report.instances_moved && !report.geometry_rebuilt && !report.recomposed, "{time}: {report:?}");
        let after = session.stats();
        assert_eq!(after.scene_builds, before.scene_builds, "{time}: the ground and the prop are built once");
        assert_eq!(after.blas_builds, before.blas_builds + 2, "{time}: the cloth's and the arm's BVHs only");
        let image = render(&mut session);
        assert!(image == render(&mut farm_scene_at(name, time)), "{name}: frame {time} differs from a fresh one");
        assert!(!images.contains(&image), "{name}: frame {time} looks like an earlier one: the test proves nothing");
        images.push(image);
    }
}

/// A one-shot render's session gives its stage up before the BVH build (the memory peak of a
/// large mesh): the scene it prepares renders what a session keeping its stage renders, bit
/// for bit, at the stage's time (an animated scene at frame 3, whose moved camera and
/// instances make a wrong time visible); the time stays known (the EXR's metadata), and
/// updates find no stage.
#[test]
fn a_session_that_releases_its_stage_renders_the_same_image() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/in/farm/moving.usda");
    let time = strata::scene::TimeCode::At(3.0);
    let options = SessionOptions { time: Some(time), ..SessionOptions::default() };
    let mut released = Session::open(SceneSource::File(scene), options);
    if released.prepare_releasing_stage(&SceneOptions::default()).is_none() {
        panic!("{}", released.diagnostics().render(released.sources()));
    }
    assert!(released.stage().is_none(), "the stage is given up");
    assert_eq!(released.time(), time);
    let image = render(&mut released);
    assert!(image == render(&mut moving_at(3.0)), "differs from a session that keeps its stage");
    assert!(image != render(&mut moving_at(1.0)), "frame 1 looks like frame 3: the test proves nothing");
    let report = released.set_time(strata::scene::TimeCode::At(4.0));
    assert!(!report.instances_moved && !report.geometry_rebuilt && report.recompiled == 0, "{report:?}");
    assert!(released.fingerprint(&settings()).is_some(), "a released session still fingerprints its scene");
}
