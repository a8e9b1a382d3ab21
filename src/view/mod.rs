//! `strata view`: a live, progressive render in the browser that follows saved edits.
//!
//! ```text
//! watch (notify) ──► worker thread: Session::apply_change ─► progressive passes ─► Published
//!                          ▲                                                        │
//! page ◄── http (axum) ────┴── commands (pick, camera) ◄──── long-polled status, frames
//! ```
//!
//! One worker thread owns the [`Session`] and renders: first a quarter-resolution preview at
//! one sample, then sample ranges of the full image accumulated exactly
//! ([`progressive::Accumulator`]), so a view left running holds `strata render`'s image at
//! the same samples per pixel, bit for bit. Passes are cut into bands of rows short enough
//! that an edit or a camera move waits for at most one band. The HTTP server answers only
//! requests whose `Host` is the bound address (other web pages cannot reach it through DNS
//! rebinding) and serves one static page compiled into the binary.

mod camera;
mod coverage;
mod encode;
mod http;
mod look;
pub mod progressive;
mod watch;
mod worker;

use crate::render::RenderSettings;
use crate::render::scene::SceneOptions;
use crate::session::{SceneSource, SessionOptions};
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex, mpsc};

/// What `strata view` serves.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// The scene.
    pub scene: SceneSource,
    /// How the session prepares it.
    pub session: SessionOptions,
    /// Image size, samples per pixel the view converges to, seed, sampler, layer mode.
    pub settings: RenderSettings,
    /// Whether `settings`' size was given (else a UsdRender `resolution` replaces it).
    pub resolution_given: bool,
    /// Camera, geometry, dicing and default lights.
    pub scene_options: SceneOptions,
    /// The address to listen on (127.0.0.1 unless the user says otherwise).
    pub bind: IpAddr,
    /// The port (0: any free port).
    pub port: u16,
    /// Also send each full-resolution pass to the tev viewer at this `HOST:PORT`.
    pub display_server: Option<String>,
}

/// A running view: its address and the threads serving it.
pub struct Server {
    address: SocketAddr,
    http: std::thread::JoinHandle<Result<(), String>>,
}

impl Server {
    /// The page's URL.
    pub fn url(&self) -> String {
        format!("http://{}/", self.address)
    }

    /// Serves until the process is stopped (or the server fails).
    pub fn wait(self) -> Result<(), String> {
        self.http.join().map_err(|_| "the HTTP server thread panicked".to_string())?
    }
}

/// What the worker has published for the page: the latest image and the state around it.
#[derive(Default)]
pub(crate) struct Published {
    /// Bumped on every change the page should see.
    pub generation: u64,
    /// The latest image (the preview or the accumulated full image).
    pub image: Option<Arc<crate::render::Image>>,
    /// Samples per pixel in `image` (0 for the preview's single low-resolution sample).
    pub samples: u32,
    /// The samples per pixel the view converges to.
    pub spp: u32,
    /// The full image size.
    pub width: usize,
    /// See `width`.
    pub height: usize,
    /// The rendered diagnostics of the last update (empty when clean), as `check` prints them.
    pub diagnostics: String,
    /// Whether the last update failed (the image is the last good one).
    pub failed: bool,
    /// File changes applied so far.
    pub edits: u64,
    /// Time from the last file event to its first image, ms.
    pub update_ms: Option<f64>,
    /// The stage's cameras and the one in use (`None`: a framing camera).
    pub cameras: Vec<String>,
    /// See `cameras`.
    pub camera: Option<String>,
    /// Files being watched.
    pub watched: Vec<String>,
    /// Time from the last input edit to its first image, ms.
    pub input_ms: Option<f64>,
    /// Every horizontal slot the scene binds, the muted ones and the soloed one.
    pub slots: Vec<String>,
    /// See `slots`.
    pub muted: Vec<String>,
    /// See `slots`.
    pub solo: Option<String>,
    /// Inputs set from the page so far (what an override layer would write).
    pub look_inputs: usize,
    /// The last picked prim and its material's name (its Cryptomatte mattes can be shown).
    pub selected: Option<(String, String)>,
    /// The slots of the selected prim's material layers, bottom to top (each has a coverage
    /// matte, `coverage:INDEX:SLOT` in the channel selector).
    pub selected_layers: Vec<String>,
    /// Camera samples per second of the passes since the last restart (bands and merges).
    pub samples_per_second: Option<f64>,
    /// Materials the session has compiled so far, and parameter blocks input edits rewrote
    /// instead ([`crate::session::SessionStats`]): an input edit compiles nothing.
    pub materials_compiled: usize,
    /// See `materials_compiled`.
    pub parameter_writes: usize,
}

/// State shared by the worker, the watcher and the HTTP handlers.
pub(crate) struct Shared {
    pub published: Mutex<Published>,
    /// Tells long-polling requests that `published.generation` moved.
    pub generation: tokio::sync::watch::Sender<u64>,
    pub commands: mpsc::Sender<worker::Command>,
}

impl Shared {
    /// Changes the published state and wakes the page.
    pub fn publish(&self, change: impl FnOnce(&mut Published)) {
        let generation = {
            let mut p = self.published.lock().unwrap_or_else(|e| e.into_inner());
            change(&mut p);
            p.generation += 1;
            p.generation
        };
        self.generation.send_replace(generation);
    }

    pub fn snapshot<T>(&self, read: impl FnOnce(&Published) -> T) -> T {
        read(&self.published.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// Opens the scene, binds the address and starts the worker, the watcher and the server.
/// Fails (with the rendered diagnostics) when the scene does not prepare or the address is
/// taken.
pub fn start(options: ViewOptions) -> Result<Server, String> {
    let listener = std::net::TcpListener::bind((options.bind, options.port))
        .map_err(|e| format!("cannot listen on {}:{}: {e}", options.bind, options.port))?;
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    let address = listener.local_addr().map_err(|e| e.to_string())?;
    let (commands, receiver) = mpsc::channel();
    let shared = Arc::new(Shared {
        published: Mutex::new(Published::default()),
        generation: tokio::sync::watch::Sender::new(0),
        commands,
    });
    let worker = worker::Worker::open(&options, shared.clone())?;
    let events = shared.commands.clone();
    let watcher = watch::start(move |paths| {
        let _ = events.send(worker::Command::Files { paths, at: std::time::Instant::now() });
    })?;
    std::thread::Builder::new()
        .name("strata-view-render".into())
        .spawn(move || worker.run(receiver, watcher))
        .map_err(|e| e.to_string())?;
    let http = std::thread::Builder::new()
        .name("strata-view-http".into())
        .spawn(move || http::serve(listener, address, shared))
        .map_err(|e| e.to_string())?;
    Ok(Server { address, http })
}
