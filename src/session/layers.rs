//! The slot tables `strata layers` prints: per renderable prim, its layers bottom to top.

use crate::compose::slots::{Applied, LayerBinding, PrimStack};
use crate::scene::Stage;
use serde::Serialize;

#[derive(Serialize)]
struct JsonOverride<'a> {
    slot: String,
    material: &'a str,
    bound_at: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    collection: Option<&'a str>,
}

#[derive(Serialize)]
struct JsonLayer<'a> {
    slot: String,
    material: &'a str,
    bound_at: &'a str,
    /// The collection of a collection-based binding (rule 1c); absent for a direct one.
    #[serde(skip_serializing_if = "Option::is_none")]
    collection: Option<&'a str>,
    overrides: Vec<JsonOverride<'a>>,
    /// Vertical layers (rule 3b), first on the surface; absent when there are none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    vertical: Vec<JsonLayer<'a>>,
}

#[derive(Serialize)]
struct JsonPrim<'a> {
    prim: &'a str,
    layers: Vec<JsonLayer<'a>>,
}

fn json_layer(l: &LayerBinding) -> JsonLayer<'_> {
    JsonLayer {
        slot: l.slot.name(),
        material: &l.applied.material,
        bound_at: &l.applied.bound_at,
        collection: l.applied.collection.as_deref(),
        overrides: l
            .overrides
            .iter()
            .map(|o| JsonOverride {
                slot: o.slot.name(),
                material: &o.applied.material,
                bound_at: &o.applied.bound_at,
                collection: o.applied.collection.as_deref(),
            })
            .collect(),
        vertical: l.vertical.iter().map(json_layer).collect(),
    }
}

/// The `strata layers --json` document (DESIGN.md; README documents the optional
/// `collection` and `vertical` members).
pub fn layers_json(stacks: &[PrimStack]) -> String {
    let prims: Vec<JsonPrim> =
        stacks.iter().map(|s| JsonPrim { prim: &s.prim, layers: s.layers.iter().map(json_layer).collect() }).collect();
    serde_json::to_string_pretty(&prims).unwrap_or_default()
}

/// The `strata layers` table: per prim, layers bottom to top, `*` marking bindings authored
/// on the prim itself (the paper's bright icons) rather than inherited. Vertical layers
/// follow their slot's overrides, indented; a collection-based binding names its
/// collection. With the `stage`, a prim with no layers says which display primvars its
/// default substance reads.
pub fn layers_table(stacks: &[PrimStack], stage: Option<&Stage>) -> String {
    let mut out = String::new();
    // Slot names are padded to 12 columns, or to the longest (`material:binding`) when wider.
    // Vertical rows are indented by two more columns.
    let width = stacks
        .iter()
        .flat_map(|s| s.layers.iter().flat_map(|l| std::iter::once(l).chain(&l.vertical)))
        .flat_map(|l| std::iter::once(&l.slot).chain(l.overrides.iter().map(|o| &o.slot)))
        .map(|s| s.name().chars().count() + if s.vertical.is_some() { 2 } else { 0 })
        .max()
        .unwrap_or(0)
        .max(12);
    for stack in stacks {
        out += &format!("{}\n", stack.prim);
        if stack.layers.is_empty() {
            let display = stage.map(|s| crate::compose::scene::display_primvars(s, &stack.prim)).unwrap_or_default();
            out += &format!("  (default substance: {})\n", display.describe());
        }
        let mut row = |indent: &str, slot: String, applied: &Applied| {
            let mark = if applied.bound_at == stack.prim { '*' } else { ' ' };
            let width = width - indent.len();
            out += &format!("  {mark} {indent}{slot:<width$} {:<40} bound at {}", applied.material, applied.bound_at);
            if let Some(collection) = &applied.collection {
                out += &format!(" by {collection}");
            }
            out.push('\n');
        };
        for layer in &stack.layers {
            row("", layer.slot.name(), &layer.applied);
            for o in &layer.overrides {
                row("", o.slot.name(), &o.applied);
            }
            for vertical in &layer.vertical {
                row("  ", vertical.slot.name(), &vertical.applied);
                for o in &vertical.overrides {
                    row("  ", o.slot.name(), &o.applied);
                }
            }
        }
    }
    out
}
