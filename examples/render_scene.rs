//! The library behind `strata render`, end to end, through a `Session`: open a USD scene,
//! compose it, compile each distinct material once with the JIT, build the render scene,
//! path-trace it and write the EXR + PNG.
//!
//! `cargo run --release --example render_scene [SCENE.usda] [OUT.exr]`
//! (no scene: the embedded default scene; no output: `example.exr`).

use std::path::PathBuf;
use strata::render::geometry::displace::DicingOptions;
use strata::render::scene::SceneOptions;
use strata::render::{RenderSettings, write_outputs};
use strata::session::{Pass, SceneSource, Session, SessionOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let scene_path = args.next().map(PathBuf::from);
    let output = PathBuf::from(args.next().unwrap_or_else(|| "example.exr".into()));

    // The session reads, composes and compiles on demand; every phase reports into its
    // diagnostics, rendered with the sources it read.
    let mut session = Session::open(SceneSource::from_path(scene_path.as_deref()), SessionOptions::default());
    let settings = RenderSettings { width: 320, height: 240, spp: 16, ..RenderSettings::default() };
    // The scene is built with the compiled materials, so that displaced surfaces are diced for
    // this image size.
    let options = SceneOptions {
        dicing: DicingOptions { resolution: (settings.width, settings.height), ..DicingOptions::default() },
        ..SceneOptions::default()
    };
    let prepared = session.prepare(&options).is_some();
    eprint!("{}", session.diagnostics().render(session.sources()));
    if !prepared {
        return Err("the scene has errors".into());
    }
    eprintln!("{}", session.compile_stats());

    // The renderer sees only `MaterialCode`: compiled entry points and closure values.
    let (image, stats) = session.render(&Pass::full(settings), None)?;
    let png = write_outputs(&image, &output)?;
    eprintln!("{stats}\nwrote {} and {}", output.display(), png.display());
    Ok(())
}
