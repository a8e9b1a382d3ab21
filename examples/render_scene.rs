//! The library behind `strata render`, end to end: compose a USD scene, compile each distinct
//! material once with the JIT, build the render scene, path-trace it and write the EXR + PNG.
//!
//! `cargo run --release --example render_scene [SCENE.usda] [OUT.exr]`
//! (no scene: the embedded default scene; no output: `example.exr`).

use std::path::PathBuf;
use strata::abi::MaterialCode;
use strata::backend::BackendKind;
use strata::cli::{CompiledScene, compile_scene};
use strata::diag::{Diagnostics, SourceMap};
use strata::ir::wired::PassOptions;
use strata::render::displace::DicingOptions;
use strata::render::scene::SceneOptions;
use strata::render::{RenderSettings, Scene, render, write_outputs};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let scene_path = args.next().map(PathBuf::from);
    let output = PathBuf::from(args.next().unwrap_or_else(|| "example.exr".into()));

    // Every stage reports into one diagnostics sink; render them with the sources.
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let compiled =
        compile_scene(scene_path.as_deref(), BackendKind::Jit, PassOptions::default(), &mut sources, &mut diags);
    let settings = RenderSettings { width: 320, height: 240, spp: 16, ..RenderSettings::default() };
    // The scene is built with the compiled materials, so that displaced surfaces are diced for
    // this image size.
    let options = SceneOptions {
        dicing: DicingOptions { resolution: (settings.width, settings.height), ..DicingOptions::default() },
        ..SceneOptions::default()
    };
    let scene = compiled.as_ref().and_then(|c| {
        let materials: Vec<&dyn MaterialCode> = c.materials.iter().map(|m| m.as_ref()).collect();
        Scene::build(&c.stage, &|prim| c.prim_material.get(prim).copied(), &materials, &options, &mut diags)
    });
    eprint!("{}", diags.render(&sources));
    let (Some(CompiledScene { materials, compiler, .. }), Some(scene)) = (compiled, scene) else {
        return Err("the scene has errors".into());
    };
    eprintln!("{}", compiler.stats);

    // The renderer sees only `MaterialCode`: compiled entry points and closure values.
    let materials: Vec<&dyn MaterialCode> = materials.iter().map(|m| m.as_ref()).collect();
    let (image, stats) = render(&scene, &materials, &settings, None)?;
    let png = write_outputs(&image, &output)?;
    eprintln!("{stats}\nwrote {} and {}", output.display(), png.display());
    Ok(())
}
