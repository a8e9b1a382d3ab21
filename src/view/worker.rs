//! The render thread: owns the [`Session`], applies saved edits and camera moves, and renders
//! the preview and the progressive passes between them.

use super::camera::{Move, Orbit};
use super::look::{self, LookEdits};
use super::progressive::Accumulator;
use super::watch::Watcher;
use super::{Shared, ViewOptions};
use crate::compose::slots::SlotFilter;
use crate::render::film::display::DisplayServer;
use crate::render::scene::SceneOptions;
use crate::render::{Image, RenderSettings};
use crate::session::{Change, ChangeKind, Pass, SceneSource, Session};
use serde_json::json;
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

/// Divisor of the preview's size: the first image of an edit has 1/16 of the pixels, at one
/// sample.
const PREVIEW_SCALE: usize = 4;

/// How long file events must stop before an edit is applied.
const QUIET: Duration = Duration::from_millis(15);

/// File events collected before they are applied.
#[derive(Default)]
struct Edits {
    files: BTreeSet<PathBuf>,
    first_event: Option<Instant>,
}

/// What the watcher and the page ask of the worker.
pub(crate) enum Command {
    /// Files changed on disk (canonical paths), first seen at `at`.
    Files { paths: Vec<PathBuf>, at: Instant },
    /// The page asks what is at a pixel of the full image; the answer is JSON.
    Pick { x: usize, y: usize, reply: tokio::sync::oneshot::Sender<String> },
    /// Orbit, pan or dolly the camera.
    Camera(Move),
    /// Look through a stage camera (`None`: the camera the view started with).
    SelectCamera(Option<String>),
    /// Set a material input in memory (a [`Change::Value`]), asked for at `at`.
    SetInput { change: Change, at: Instant },
    /// Mute or solo slots (in memory).
    Slots(SlotFilter),
    /// Dolly and turn nothing, so the picked prim fills the view.
    FrameSelected,
    /// Write the input edits as an override layer; the answer is JSON.
    WriteLook { reply: tokio::sync::oneshot::Sender<Result<String, String>> },
    /// Layer `layer`'s coverage matte of the selected prim as PNG bytes.
    Coverage { layer: usize, reply: tokio::sync::oneshot::Sender<Option<Vec<u8>>> },
}

impl Command {
    /// The (prim, attribute) an input edit sets.
    fn edited_input(&self) -> Option<(&str, &str)> {
        match self {
            Command::SetInput { change: Change::Value { prim, attribute, .. }, .. } => Some((prim, attribute)),
            _ => None,
        }
    }
}

/// The render thread's state. See the module documentation.
pub(crate) struct Worker {
    session: Session,
    settings: RenderSettings,
    scene_options: SceneOptions,
    shared: Arc<Shared>,
    orbit: Orbit,
    /// The last image with every band (for picking channel values).
    image: Option<Arc<Image>>,
    /// When the file event behind the coming preview happened.
    changed_at: Option<Instant>,
    /// The rendered diagnostics of the last edit (or of opening) and whether it failed.
    diagnostics: String,
    failed: bool,
    /// Edits applied so far (saved files and look edits).
    edits: u64,
    /// The input values set from the page, re-applied after a layer is read again.
    look: LookEdits,
    /// When the input edit behind the coming preview was asked for.
    input_at: Option<Instant>,
    /// The scene file (override layers are written beside it).
    scene: SceneSource,
    /// The tev viewer each full-resolution pass is sent to (`--display-server`).
    display: Option<DisplayServer>,
    /// The selected prim's per-layer coverage mattes for the current image (dropped on
    /// every restart): the prim and each layer's values at the full resolution.
    coverage: Option<(String, Vec<Vec<f32>>)>,
}

impl Worker {
    /// Opens and prepares the scene; the rendered diagnostics when it does not prepare.
    pub fn open(options: &ViewOptions, shared: Arc<Shared>) -> Result<Worker, String> {
        // Inputs are parameters of the compiled code here: an edit from the page rewrites a
        // parameter block instead of recompiling (`render` folds them).
        let mut session_options = options.session;
        session_options.passes.live_inputs = true;
        let mut session = Session::open(options.scene.clone(), session_options);
        let mut settings = options.settings.clone();
        let mut scene_options = options.scene_options.clone();
        let compiled = session.compile().is_some();
        if compiled {
            session.lint_slots();
        }
        let view = if compiled { session.view(scene_options.camera.as_deref()) } else { None };
        let mut prepared = false;
        if let Some(view) = view {
            if let (false, Some((w, h))) = (options.resolution_given, view.resolution) {
                (settings.width, settings.height) = (w, h);
            }
            scene_options.camera = view.camera;
            scene_options.dicing.resolution = (settings.width, settings.height);
            prepared = session.prepare(&scene_options).is_some();
        }
        let diags = session.take_diagnostics();
        let text = diags.render(session.sources());
        if !prepared || diags.has_errors() {
            return Err(text);
        }
        let display = match &options.display_server {
            Some(address) => Some(DisplayServer::connect(address, &options.scene.display_name())?),
            None => None,
        };
        let cameras = session.stage().map(crate::render::scene::camera_paths).unwrap_or_default();
        let up = session.stage().map_or("Y", |s| s.up_axis()).to_string();
        let scene = session.scene().ok_or("the scene did not prepare")?;
        let orbit = Orbit::new(&scene.camera, scene.bounds, &up);
        let camera = scene.camera_path.clone();
        shared.publish(|p| {
            p.spp = settings.spp;
            (p.width, p.height) = (settings.width, settings.height);
            p.diagnostics = text.clone();
            p.cameras = cameras;
            p.camera = camera;
        });
        Ok(Worker {
            session,
            settings,
            scene_options,
            shared,
            orbit,
            image: None,
            changed_at: None,
            diagnostics: text,
            failed: false,
            edits: 0,
            look: LookEdits::default(),
            input_at: None,
            scene: options.scene.clone(),
            display,
            coverage: None,
        })
    }

    /// Renders and answers commands until the server goes away.
    pub fn run(mut self, commands: mpsc::Receiver<Command>, mut watcher: Watcher) {
        self.watch(&mut watcher);
        self.publish_look();
        let mut passes = Accumulator::new(self.settings.clone());
        let mut preview_due = true;
        let mut stalled = false;
        // Time spent in the passes since the last restart (bands and merging into images).
        let mut pass_time = Duration::ZERO;
        loop {
            let idle = !preview_due && (passes.done() || stalled);
            let first = if idle {
                match commands.recv() {
                    Ok(command) => Some(command),
                    Err(_) => return,
                }
            } else {
                commands.try_recv().ok()
            };
            let mut edits = Edits::default();
            let mut restart = false;
            let batch: Vec<Command> =
                first.into_iter().chain(std::iter::from_fn(|| commands.try_recv().ok())).collect();
            // A dragged slider sends a value per mouse move: only the last of each input recompiles.
            let last_edit: std::collections::HashMap<(&str, &str), usize> =
                batch.iter().enumerate().filter_map(|(i, c)| c.edited_input().map(|key| (key, i))).collect();
            let keep: Vec<bool> = batch
                .iter()
                .enumerate()
                .map(|(i, c)| c.edited_input().is_none_or(|key| last_edit[&key] == i))
                .collect();
            for (command, keep) in batch.into_iter().zip(keep) {
                if keep {
                    restart |= self.handle(command, &mut edits);
                }
            }
            // One save is several events (truncate, write, close): wait until they stop.
            if !edits.files.is_empty() {
                while let Ok(command) = commands.recv_timeout(QUIET) {
                    restart |= self.handle(command, &mut edits);
                }
            }
            if !edits.files.is_empty() && self.apply(std::mem::take(&mut edits.files), &mut watcher) {
                restart = true;
                self.changed_at = edits.first_event;
            }
            if restart {
                self.coverage = None;
                passes = Accumulator::new(self.settings.clone());
                (preview_due, stalled, pass_time) = (true, false, Duration::ZERO);
            }
            if preview_due {
                self.preview();
                preview_due = false;
                continue;
            }
            if passes.done() || stalled {
                continue;
            }
            let pass_start = Instant::now();
            match passes.step(&mut self.session) {
                Ok(false) => pass_time += pass_start.elapsed(),
                Ok(true) => match passes.image(&self.session) {
                    Some(Ok(image)) => {
                        pass_time += pass_start.elapsed();
                        self.send_to_display(&image);
                        let image = Arc::new(image);
                        self.image = Some(image.clone());
                        let samples = passes.samples();
                        let pixels = (self.settings.width * self.settings.height) as f64;
                        let rate = pixels * f64::from(samples) / pass_time.as_secs_f64().max(1e-9);
                        self.shared.publish(|p| {
                            p.image = Some(image);
                            p.samples = samples;
                            p.samples_per_second = Some(rate);
                        });
                    }
                    Some(Err(e)) => stalled = self.report_render_error(&e.to_string()),
                    None => {}
                },
                Err(e) => stalled = self.report_render_error(&e.to_string()),
            }
        }
    }

    /// Handles one command; whether the image must be rendered again. File events are
    /// collected in `edits` for [`Worker::apply`].
    fn handle(&mut self, command: Command, edits: &mut Edits) -> bool {
        match command {
            Command::Files { paths, at } => {
                edits.files.extend(paths);
                edits.first_event = Some(edits.first_event.map_or(at, |e| e.min(at)));
                false
            }
            Command::Pick { x, y, reply } => {
                let _ = reply.send(self.pick(x, y));
                false
            }
            Command::Camera(m) => {
                let Some(camera) = self.session.scene().map(|s| self.orbit.apply(&s.camera, m)) else { return false };
                self.session.set_camera(camera);
                true
            }
            Command::SelectCamera(path) => self.select_camera(path),
            Command::SetInput { change, at } => {
                let applied = self.look_edit(|session| session.apply_change(&change).failed);
                if applied {
                    self.look.record(&change);
                    self.input_at = Some(at);
                }
                applied
            }
            Command::Slots(filter) => self.look_edit(|session| session.set_slot_filter(filter).failed),
            Command::FrameSelected => self.frame_selected(),
            Command::WriteLook { reply } => {
                let _ = reply.send(self.write_look());
                false
            }
            Command::Coverage { layer, reply } => {
                let _ = reply.send(self.coverage(layer));
                false
            }
        }
    }

    /// Applies a look edit (an input value, mute or solo) to the session; whether it applied.
    /// A failed one shows its diagnostics and keeps the image.
    fn look_edit(&mut self, edit: impl FnOnce(&mut Session) -> bool) -> bool {
        let failed = edit(&mut self.session) || self.session.diagnostics().has_errors();
        self.settle_edit(failed)
    }

    /// Counts an applied edit and publishes its diagnostics; a failed one is shown at once
    /// over the last good image, a good one with its first image ([`Worker::preview`]).
    /// Whether the image must be rendered again.
    fn settle_edit(&mut self, failed: bool) -> bool {
        let diags = self.session.take_diagnostics();
        self.diagnostics = diags.render(self.session.sources());
        self.failed = failed;
        self.edits += 1;
        self.publish_look();
        if failed {
            let (text, edits) = (self.diagnostics.clone(), self.edits);
            self.shared.publish(|p| {
                p.diagnostics = text;
                p.failed = true;
                p.edits = edits;
            });
        }
        !failed
    }

    /// Frames the picked prim: the bounds of the positions (`P`) of the pixels of the last
    /// full image whose most-covering prim (Cryptomatte rank 0) it is, the visible part of it.
    fn frame_selected(&mut self) -> bool {
        let (Some((prim, _)), Some(image)) = (self.shared.snapshot(|p| p.selected.clone()), &self.image) else {
            return false;
        };
        let id = crate::render::film::cryptomatte::id_bits(&prim);
        let rank0 = crate::render::film::cryptomatte::channel_names("CryptoObject");
        let planes = ["P.R", "P.G", "P.B", &rank0[0]].map(|n| image.f32_channel(n));
        let [Some(x), Some(y), Some(z), Some(ids)] = planes else { return false };
        let mut bounds = (glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY));
        for i in (0..ids.len()).filter(|&i| ids[i].to_bits() == id) {
            let p = glam::Vec3::new(x[i], y[i], z[i]);
            if p.is_finite() {
                bounds = (bounds.0.min(p), bounds.1.max(p));
            }
        }
        let Some(camera) = self.session.scene().map(|s| s.camera) else { return false };
        if bounds.0.cmpgt(bounds.1).any() {
            return false;
        }
        let (centre, radius) = ((bounds.0 + bounds.1) * 0.5, ((bounds.1 - bounds.0).length() * 0.5).max(1e-4));
        let aspect = self.settings.width as f32 / self.settings.height as f32;
        let framed = self.orbit.frame(&camera, centre, radius, aspect);
        self.session.set_camera(framed);
        true
    }

    /// Publishes the slots that can be muted, the filter and the number of input edits.
    fn publish_look(&self) {
        let mut slots: Vec<String> = self
            .session
            .composed()
            .map(|c| c.stacks.iter().flat_map(|s| s.layers.iter().map(|l| l.slot.name())).collect())
            .unwrap_or_default();
        slots.sort();
        slots.dedup();
        let filter = self.session.slot_filter().clone();
        let inputs = self.look.len();
        self.shared.publish(|p| {
            p.slots = slots;
            p.muted = filter.muted.into_iter().collect();
            p.solo = filter.solo;
            p.look_inputs = inputs;
        });
    }

    /// Writes the input edits as an override layer beside the scene: its path as JSON.
    fn write_look(&self) -> Result<String, String> {
        let SceneSource::File(scene) = &self.scene else {
            return Err("the embedded default scene has no file to sublayer the edits under".into());
        };
        if self.look.len() == 0 {
            return Err("no input has been edited".into());
        }
        let path = self.look.write(scene)?;
        Ok(json!({ "path": path.display().to_string(), "attributes": self.look.len() }).to_string())
    }

    /// Sends a full-resolution pass to tev; a viewer that went away is reported once and
    /// dropped.
    fn send_to_display(&mut self, image: &Image) {
        if let Some(Err(e)) = self.display.as_mut().map(|d| d.send(image)) {
            self.display = None;
            let message = format!("warning: {e}\n");
            self.shared.publish(|p| p.diagnostics = message);
        }
    }

    fn report_render_error(&self, message: &str) -> bool {
        let message = format!("error: {message}\n");
        self.shared.publish(|p| {
            p.diagnostics = message;
            p.failed = true;
        });
        true
    }

    /// Watches every file the process has read (layers, substance files, textures).
    fn watch(&self, watcher: &mut Watcher) {
        let files = crate::input::files_read();
        watcher.watch(&files);
        let watched = files.iter().map(|f| f.display().to_string()).collect();
        self.shared.publish(|p| p.watched = watched);
    }

    /// Applies saved edits; whether the image must be rendered again. A failed edit is shown
    /// at once over the last good image; a good one with its first image ([`Worker::preview`]).
    fn apply(&mut self, files: BTreeSet<PathBuf>, watcher: &mut Watcher) -> bool {
        let (mut related, mut failed) = (false, false);
        for file in files {
            let report = self.session.apply_change(&Change::File(file));
            related |= report.kind != ChangeKind::Unrelated;
            failed |= report.failed || self.session.diagnostics().has_errors();
            if failed {
                break;
            }
            // The stage was read again: the input values set from the page apply on top.
            if report.restaged {
                for change in self.look.changes() {
                    failed |= self.session.apply_change(&change).failed;
                }
            }
        }
        if !related {
            return false;
        }
        // An edit may have made the scene read new files (an import, a sublayer, a texture).
        self.watch(watcher);
        self.settle_edit(failed)
    }

    /// Looks through `path` (a Camera prim, or the starting camera for `None`).
    fn select_camera(&mut self, path: Option<String>) -> bool {
        let options = SceneOptions { camera: path, ..self.scene_options.clone() };
        if self.session.prepare(&options).is_none() {
            let diags = self.session.take_diagnostics();
            let text = diags.render(self.session.sources());
            self.shared.publish(|p| p.diagnostics = text);
            return false;
        }
        let Some(scene) = self.session.scene() else { return false };
        let up = self.session.stage().map_or("Y", |s| s.up_axis()).to_string();
        self.orbit = Orbit::new(&scene.camera, scene.bounds, &up);
        let camera = scene.camera_path.clone();
        self.shared.publish(|p| p.camera = camera);
        true
    }

    /// The first image after a change: a fraction of the pixels at one sample.
    fn preview(&mut self) {
        let settings = RenderSettings {
            width: self.settings.width.div_ceil(PREVIEW_SCALE),
            height: self.settings.height.div_ceil(PREVIEW_SCALE),
            spp: 1,
            ..self.settings.clone()
        };
        match self.session.render(&Pass::full(settings), None) {
            Ok((image, _)) => {
                let update_ms = self.changed_at.take().map(|t| t.elapsed().as_secs_f64() * 1e3);
                let input_ms = self.input_at.take().map(|t| t.elapsed().as_secs_f64() * 1e3);
                let (text, failed, edits) = (self.diagnostics.clone(), self.failed, self.edits);
                let stats = self.session.stats();
                let (compiled, writes) = (stats.materials_compiled, stats.parameter_writes);
                self.shared.publish(|p| {
                    p.image = Some(Arc::new(image));
                    p.samples = 0;
                    (p.materials_compiled, p.parameter_writes) = (compiled, writes);
                    if update_ms.is_some() {
                        p.update_ms = update_ms;
                    }
                    if input_ms.is_some() {
                        p.input_ms = input_ms;
                    }
                    (p.diagnostics, p.failed, p.edits) = (text, failed, edits);
                });
            }
            Err(e) => {
                self.report_render_error(&e.to_string());
            }
        }
    }

    /// What is at pixel `(x, y)` of the full image: the prim, its slot stack, and the
    /// channel values of the last image.
    fn pick(&self, x: usize, y: usize) -> String {
        let (w, h) = (self.settings.width, self.settings.height);
        let mut shares = None;
        let prim = self.session.scene().and_then(|scene| {
            let camera = scene.camera.with_aspect(w as f32 / h as f32);
            let film = glam::Vec2::new((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            let ray = camera.ray(film, glam::Vec2::splat(0.5));
            let hit = scene.accel.intersect(ray.o, ray.d, ray.tmin, ray.tmax)?;
            let prim = scene.accel.prim_of(&hit) as usize;
            shares = self.pick_shares(scene, ray.o, ray.d, &hit);
            scene.prims.get(prim).map(|p| p.path.clone())
        });
        let stack = prim.as_ref().and_then(|prim| {
            let stacks = &self.session.composed()?.stacks;
            let stack = stacks.iter().find(|s| &s.prim == prim)?;
            serde_json::from_str::<serde_json::Value>(&crate::session::layers_json(std::slice::from_ref(stack))).ok()
        });
        let mut channels = serde_json::Map::new();
        if let Some(image) = &self.image
            && x < image.width
            && y < image.height
        {
            let i = y * image.width + x;
            for channel in image.channels.iter().filter(|c| !c.name.starts_with("Crypto")) {
                let value = match &channel.data {
                    crate::render::ChannelData::F32(v) => json!(v[i]),
                    crate::render::ChannelData::U32(v) => json!(v[i]),
                };
                channels.insert(channel.name.clone(), value);
            }
        }
        let layers = stack.and_then(|s| s.get(0).and_then(|p| p.get("layers")).cloned());
        let selected = prim.as_ref().map(|prim| {
            let compiled = self.session.compiled();
            let material = compiled.and_then(|c| c.material_names.get(*c.prim_material.get(prim)?)).cloned();
            (prim.clone(), material.unwrap_or_default())
        });
        let slots = prim.as_deref().and_then(|prim| {
            let compiled = self.session.compiled()?;
            let material = compiled.materials.get(*compiled.prim_material.get(prim)?)?;
            Some(material.info().layers.iter().map(|l| l.slot.clone()).collect::<Vec<_>>())
        });
        self.shared.publish(|p| {
            p.selected = selected;
            p.selected_layers = slots.unwrap_or_default();
        });
        let inputs = prim.as_deref().map(|prim| look::inputs_json(&self.session, prim));
        json!({ "x": x, "y": y, "prim": prim, "layers": layers, "inputs": inputs, "shares": shares, "channels": channels })
            .to_string()
    }

    /// Layer `layer`'s coverage matte of the selected prim, as PNG bytes; computed once per
    /// selection and image ([`super::coverage`]).
    fn coverage(&mut self, layer: usize) -> Option<Vec<u8>> {
        let prim = self.shared.snapshot(|p| p.selected.as_ref().map(|(prim, _)| prim.clone()))?;
        let (w, h) = (self.settings.width, self.settings.height);
        if self.coverage.as_ref().is_none_or(|(p, _)| *p != prim) {
            let (scene, compiled) = (self.session.scene()?, self.session.compiled()?);
            self.coverage = Some((prim.clone(), super::coverage::mattes(scene, &compiled.materials, &prim, w, h)?));
        }
        let mattes = &self.coverage.as_ref()?.1;
        super::encode::grey(w, h, mattes.get(layer)?)
    }

    /// Each layer's share of the pick (DESIGN.md rule 5) at the surface under the pixel's
    /// centre — the probability the sample counts there estimate — and the transparency:
    /// through the integrator's own [`crate::render::integrator::shading_state`].
    fn pick_shares(
        &self,
        scene: &crate::render::Scene,
        o: glam::Vec3,
        d: glam::Vec3,
        hit: &crate::render::geometry::accel::Hit,
    ) -> Option<serde_json::Value> {
        let g = scene.accel.surface(o, d, hit);
        let material = self.session.compiled()?.materials.get(*scene.prim_material.get(g.prim as usize)?)?.clone();
        let info = material.info();
        let mut primvars = Vec::new();
        let globals = super::coverage::surface_globals(scene, material.as_ref(), o, d, hit, &mut primvars);
        let state = crate::render::integrator::shading_state(material.as_ref(), &globals).ok()?;
        let layers: Vec<serde_json::Value> =
            info.layers.iter().zip(&state.weights).map(|(l, w)| json!({ "slot": l.slot, "share": w })).collect();
        Some(json!({ "layers": layers, "transparent": state.transparency }))
    }
}
