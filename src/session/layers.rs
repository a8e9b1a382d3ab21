//! The slot tables `strata layers` prints: per renderable prim, its layers bottom to top.

use crate::compose::slots::PrimStack;
use crate::scene::Stage;
use serde::Serialize;

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
/// on the prim itself (the paper's bright icons) rather than inherited. With the `stage`, a
/// prim with no layers says which display primvars its default substance reads.
pub fn layers_table(stacks: &[PrimStack], stage: Option<&Stage>) -> String {
    let mut out = String::new();
    // Slot names are padded to 12 columns, or to the longest (`material:binding`) when wider.
    let width = stacks
        .iter()
        .flat_map(|s| s.layers.iter().flat_map(|l| std::iter::once(&l.slot).chain(l.overrides.iter().map(|o| &o.slot))))
        .map(|s| s.name().chars().count())
        .max()
        .unwrap_or(0)
        .max(12);
    for stack in stacks {
        out += &format!("{}\n", stack.prim);
        if stack.layers.is_empty() {
            let display = stage.map(|s| crate::compose::scene::display_primvars(s, &stack.prim)).unwrap_or_default();
            out += &format!("  (default substance: {})\n", display.describe());
        }
        for layer in &stack.layers {
            let mark = if layer.applied.bound_at == stack.prim { '*' } else { ' ' };
            out += &format!(
                "  {mark} {:<width$} {:<40} bound at {}\n",
                layer.slot.name(),
                layer.applied.material,
                layer.applied.bound_at
            );
            for o in &layer.overrides {
                let mark = if o.applied.bound_at == stack.prim { '*' } else { ' ' };
                out += &format!(
                    "  {mark} {:<width$} {:<40} bound at {}\n",
                    o.slot.name(),
                    o.applied.material,
                    o.applied.bound_at
                );
            }
        }
    }
    out
}
