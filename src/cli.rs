//! The subcommands behind `strata`: each loads its input, reports diagnostics to stderr and
//! prints its result to stdout. Kept in the library so tests can run them.

use crate::compose::scene::{SceneComposition, compose_stage};
use crate::compose::slots::PrimStack;
use crate::diag::{Diagnostics, SourceMap};
use crate::front::library::Library;
use crate::ir::wired::{self, PassOptions};
use crate::scene::Stage;
use crate::scenes;
use serde::Serialize;
use std::io::Write;
use std::path::Path;

/// A command failed; its diagnostics were already printed.
#[derive(Debug)]
pub struct Failure;

/// Prints diagnostics to stderr and fails if any is an error.
fn report(diags: &Diagnostics, sources: &SourceMap) -> Result<(), Failure> {
    let text = diags.render(sources);
    if !text.is_empty() {
        eprint!("{text}");
    }
    if diags.has_errors() {
        let n = diags.error_count();
        eprintln!("error: {n} error{} found", if n == 1 { "" } else { "s" });
        Err(Failure)
    } else {
        Ok(())
    }
}

/// Opens a scene file, or the embedded default scene when `path` is `None`.
pub fn open_scene(path: Option<&Path>, sources: &mut SourceMap, diags: &mut Diagnostics) -> Option<Stage> {
    match path {
        Some(p) => Stage::open(p, sources, diags).ok(),
        None => {
            let (name, text) = scenes::DEFAULT_SCENE;
            Stage::from_text(name, text, Path::new(scenes::EMBEDDED_DIR), sources, diags).ok()
        }
    }
}

#[derive(Serialize)]
struct JsonOverride<'a> {
    slot: String,
    material: &'a str,
    bound_at: &'a str,
}

#[derive(Serialize)]
struct JsonLayer<'a> {
    slot: String,
    material: &'a str,
    bound_at: &'a str,
    overrides: Vec<JsonOverride<'a>>,
}

#[derive(Serialize)]
struct JsonPrim<'a> {
    prim: &'a str,
    layers: Vec<JsonLayer<'a>>,
}

/// The `strata layers --json` document (DESIGN.md).
pub fn layers_json(stacks: &[PrimStack]) -> String {
    let prims: Vec<JsonPrim> = stacks
        .iter()
        .map(|s| JsonPrim {
            prim: &s.prim,
            layers: s
                .layers
                .iter()
                .map(|l| JsonLayer {
                    slot: l.slot.name(),
                    material: &l.applied.material,
                    bound_at: &l.applied.bound_at,
                    overrides: l
                        .overrides
                        .iter()
                        .map(|o| JsonOverride {
                            slot: o.slot.name(),
                            material: &o.applied.material,
                            bound_at: &o.applied.bound_at,
                        })
                        .collect(),
                })
                .collect(),
        })
        .collect();
    serde_json::to_string_pretty(&prims).unwrap_or_default()
}

/// The `strata layers` table: per prim, layers bottom to top, `*` marking bindings authored
/// on the prim itself (the paper's bright icons) rather than inherited.
pub fn layers_table(stacks: &[PrimStack]) -> String {
    let mut out = String::new();
    for stack in stacks {
        out += &format!("{}\n", stack.prim);
        if stack.layers.is_empty() {
            out += "  (default substance: white diffuse)\n";
        }
        for layer in &stack.layers {
            let mark = if layer.applied.bound_at == stack.prim { '*' } else { ' ' };
            out += &format!(
                "  {mark} {:<12} {:<40} bound at {}\n",
                layer.slot.name(),
                layer.applied.material,
                layer.applied.bound_at
            );
            for o in &layer.overrides {
                let mark = if o.applied.bound_at == stack.prim { '*' } else { ' ' };
                out += &format!(
                    "  {mark} {:<12} {:<40} bound at {}\n",
                    o.slot.name(),
                    o.applied.material,
                    o.applied.bound_at
                );
            }
        }
    }
    out
}

/// `strata layers [SCENE] [--json]`
pub fn layers(scene: Option<&Path>, json: bool) -> Result<(), Failure> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = open_scene(scene, &mut sources, &mut diags);
    let stacks = match &stage {
        Some(stage) => {
            let tree = crate::compose::scene::binding_tree(stage, &mut diags);
            crate::compose::slots::resolve_stacks(&tree, &mut diags)
        }
        None => Vec::new(),
    };
    report(&diags, &sources)?;
    let text = if json { layers_json(&stacks) + "\n" } else { layers_table(&stacks) };
    print_out(&text)
}

fn print_out(text: &str) -> Result<(), Failure> {
    let mut stdout = std::io::stdout().lock();
    match stdout.write_all(text.as_bytes()).and_then(|_| stdout.flush()) {
        Ok(()) => Ok(()),
        // A closed pipe (`strata ir … | head`) is not an error worth a message.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        Err(e) => {
            eprintln!("error: cannot write output: {e}");
            Err(Failure)
        }
    }
}

/// Composes a scene file completely, reporting every problem.
pub fn compose_file(
    scene: Option<&Path>,
    sources: &mut SourceMap,
    diags: &mut Diagnostics,
) -> Option<SceneComposition> {
    let stage = open_scene(scene, sources, diags)?;
    Some(compose_stage(&stage, sources, diags))
}

/// `strata ir SCENE --prim PATH`
pub fn ir(scene: &Path, prim: &str, optimize: bool, stats: bool) -> Result<(), Failure> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let composition = compose_file(Some(scene), &mut sources, &mut diags);
    report(&diags, &sources)?;
    let Some(composition) = composition else { return Err(Failure) };
    let Some(material) = composition.material_of(prim) else {
        eprintln!("error: `{prim}` is not a renderable prim of {}", scene.display());
        let prims: Vec<&str> = composition.stacks.iter().map(|s| s.prim.as_str()).take(20).collect();
        eprintln!("  renderable prims: {}", prims.join(", "));
        return Err(Failure);
    };
    let mut diags = Diagnostics::new();
    let wired = wired::build(&composition.library, material, PassOptions { optimize }, &mut diags);
    report(&diags, &sources)?;
    if stats {
        eprintln!("{}", wired.stats_line());
    }
    print_out(&wired.to_text(&composition.library))
}

/// Checks a substance file or scene: every diagnostic, and a one-line summary when it is clean.
pub fn check_file(file: &Path) -> (Diagnostics, SourceMap, String) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let is_substance = file.extension().is_some_and(|e| e == "ash");
    let summary = if is_substance {
        let lib = Library::load(&[(file.to_path_buf(), Default::default())], &mut sources, &mut diags);
        let user = lib.graphs.len().saturating_sub(1);
        format!("{}: ok ({user} graph(s))", file.display())
    } else {
        match compose_file(Some(file), &mut sources, &mut diags) {
            Some(c) => {
                let mut distinct = std::collections::HashSet::new();
                for material in &c.materials {
                    let wired = wired::build(&c.library, material, PassOptions::default(), &mut diags);
                    distinct.insert(wired.to_text(&c.library));
                }
                format!(
                    "{}: ok ({} renderable prim(s), {} distinct material(s))",
                    file.display(),
                    c.stacks.len(),
                    distinct.len()
                )
            }
            None => String::new(),
        }
    };
    (diags, sources, summary)
}

/// `strata check FILE`
pub fn check(file: &Path) -> Result<(), Failure> {
    let (diags, sources, summary) = check_file(file);
    report(&diags, &sources)?;
    print_out(&(summary + "\n"))
}
