//! Helpers shared by the integration tests: compiling a stack of substances from source, and
//! compiling and rendering a scene file.
// Each test crate uses only some of these helpers.
#![allow(dead_code)]

use std::process::{Command, Output, Stdio};
use std::sync::Arc;
use std::time::Duration;
use strata::abi::MaterialCode;
use strata::backend::{BackendKind, Compiler};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap};
use strata::front::library::Library;
use strata::ir::wired::PassOptions;

/// Runs the `strata` binary with `args`, stdin closed and stderr a pipe (as on a render farm).
pub fn strata(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .expect("strata runs")
}

/// Loads `text` (plus the prelude) as a library, or panics with the rendered diagnostics.
pub fn library(text: &str) -> Library {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("test.ash", text, &mut sources, &mut diags);
    assert!(!diags.has_errors(), "{}\n{text}", diags.render(&sources));
    lib
}

/// Compiles the substances `names` as one material, bottom to top in slots 000, 010, …
pub fn compile_stack(lib: &Library, names: &[String], backend: BackendKind, optimize: bool) -> Arc<dyn MaterialCode> {
    let layers = names
        .iter()
        .enumerate()
        .map(|(i, name)| ComposedLayer {
            slot: Slot::parse(&format!("{:03}", i * 10)).unwrap(),
            substance: MaterialRef {
                path: format!("/Looks/{name}"),
                graph: lib.graph_by_name(name).expect("graph"),
                values: Vec::new(),
                span: Default::default(),
            },
            overrides: Vec::new(),
            vertical: Vec::new(),
        })
        .collect();
    let mut diags = Diagnostics::new();
    let mut compiler = Compiler::new(backend, PassOptions { optimize, ..Default::default() });
    let code = compiler.compile(lib, &ComposedMaterial { layers, ..Default::default() }, &mut diags);
    assert!(!diags.has_errors());
    code.expect("compiled")
}

/// Runs the `strata` binary with `args`; `None` when it had to be killed at `deadline` (its
/// output is collected on another thread, so a full pipe never stalls it).
pub fn run_strata(args: &[&str], deadline: Duration) -> Option<Output> {
    let child = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("strata starts");
    let pid = child.id();
    let (send, receive) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = send.send(child.wait_with_output());
    });
    match receive.recv_timeout(deadline) {
        Ok(output) => Some(output.expect("strata runs")),
        Err(_) => {
            let _ = Command::new("kill").args(["-KILL", &pid.to_string()]).status();
            None
        }
    }
}

/// A scene file composed, compiled (JIT, optimised) and built for rendering as `strata
/// render` builds it (displaced surfaces diced for a 640x480 image), with its materials;
/// panics with the rendered diagnostics on any error.
pub fn scene_file(path: &std::path::Path) -> (strata::render::Scene, Vec<Arc<dyn MaterialCode>>) {
    scene_file_with(path, BackendKind::Jit, true, (640, 480))
}

/// [`scene_file`] with a backend, optimisation and the image size dicing measures against.
pub fn scene_file_with(
    path: &std::path::Path,
    backend: BackendKind,
    optimize: bool,
    resolution: (usize, usize),
) -> (strata::render::Scene, Vec<Arc<dyn MaterialCode>>) {
    use strata::session::{SceneSource, Session, SessionOptions};
    let options =
        SessionOptions { backend, passes: PassOptions { optimize, ..Default::default() }, ..Default::default() };
    let mut session = Session::open(SceneSource::File(path.to_path_buf()), options);
    session.compile_or_report().unwrap_or_else(|e| panic!("{e}"));
    let options = strata::render::scene::SceneOptions {
        dicing: strata::render::geometry::displace::DicingOptions { resolution, ..Default::default() },
        ..Default::default()
    };
    if session.prepare(&options).is_none() {
        panic!("{}", session.diagnostics().render(session.sources()));
    }
    assert!(!session.diagnostics().has_errors(), "{}", session.diagnostics().render(session.sources()));
    let (scene, compiled) = session.into_scene().expect("prepared");
    (scene, compiled.materials)
}

/// Settings for a small stochastic test render on two threads.
pub fn settings(width: usize, height: usize, spp: u32, seed: u64, max_depth: u32) -> strata::render::RenderSettings {
    strata::render::RenderSettings {
        width,
        height,
        spp,
        seed,
        threads: Some(2),
        max_depth,
        mode: strata::render::LayerMode::Stochastic,
        ..Default::default()
    }
}

/// Renders `scene`, asserting that no sample was invalid.
pub fn render_scene(
    scene: &strata::render::Scene,
    materials: &[Arc<dyn MaterialCode>],
    settings: &strata::render::RenderSettings,
) -> strata::render::Image {
    let refs: Vec<&dyn MaterialCode> = materials.iter().map(|m| m.as_ref()).collect();
    let (image, stats) = strata::render::render(scene, &refs, settings, None).expect("renders");
    assert_eq!(stats.invalid_samples(), 0, "{stats}");
    image
}

/// [`scene_file`] rendered with `settings`.
pub fn render_file(path: &std::path::Path, settings: &strata::render::RenderSettings) -> strata::render::Image {
    let (scene, materials) = scene_file_with(path, BackendKind::Jit, true, (settings.width, settings.height));
    render_scene(&scene, &materials, settings)
}

/// A scene opened and compiled in a session, with its render scene built from the stage alone
/// (`Scene::from_stage`: nothing diced, no primvars stored); panics with the rendered
/// diagnostics on any error.
pub fn stage_scene(
    source: strata::session::SceneSource,
    backend: BackendKind,
    optimize: bool,
) -> (strata::session::Session, strata::render::Scene) {
    let options = strata::session::SessionOptions {
        backend,
        passes: PassOptions { optimize, ..Default::default() },
        ..Default::default()
    };
    let mut session = strata::session::Session::open(source, options);
    session.compile_or_report().unwrap_or_else(|e| panic!("{e}"));
    let mut diags = session.take_diagnostics();
    let (stage, compiled) = (session.stage().expect("opened"), session.compiled().expect("compiled"));
    let scene = strata::render::Scene::from_stage(stage, &|p| compiled.prim_material.get(p).copied(), &mut diags)
        .unwrap_or_else(|| panic!("{}", diags.render(session.sources())));
    assert!(!diags.has_errors(), "{}", diags.render(session.sources()));
    (session, scene)
}

/// An EXR decoded: windows, attributes (as text), channels (type and bits). Two runs' EXR
/// bytes differ in attribute order alone (the `exr` crate keeps them in a `HashMap`), so
/// farm tests compare these.
#[derive(Debug, PartialEq)]
pub struct Decoded {
    pub windows: String,
    pub attributes: std::collections::BTreeMap<String, String>,
    pub channels: std::collections::BTreeMap<String, (&'static str, Vec<u32>)>,
}

pub fn decode(path: &std::path::Path) -> Decoded {
    let image = strata::render::film::output::read_exr(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let layer = &image.layer_data;
    let mut attributes = std::collections::BTreeMap::new();
    for (k, v) in layer.attributes.other.iter().chain(&image.attributes.other) {
        let text = match v {
            exr::meta::attribute::AttributeValue::Text(t) => t.to_string(),
            other => format!("{other:?}"),
        };
        attributes.insert(k.to_string(), text);
    }
    let a = &layer.attributes;
    attributes.insert(
        "(layer)".into(),
        format!(
            "{:?} {:?} {:?} {:?} {:?} {:?}",
            a.world_to_camera,
            a.world_to_normalized_device,
            a.near_clip_plane,
            a.far_clip_plane,
            a.software_name,
            image.attributes.chromaticities
        ),
    );
    let channels = layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            let samples = match &c.sample_data {
                exr::prelude::FlatSamples::F16(v) => ("half", v.iter().map(|x| u32::from(x.to_bits())).collect()),
                exr::prelude::FlatSamples::F32(v) => ("float", v.iter().map(|x| x.to_bits()).collect()),
                exr::prelude::FlatSamples::U32(v) => ("uint", v.clone()),
            };
            (c.name.to_string(), samples)
        })
        .collect();
    Decoded {
        windows: format!("{:?} {:?} {:?}", image.attributes.display_window, a.layer_position, layer.size),
        attributes,
        channels,
    }
}
