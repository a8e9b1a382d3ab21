//! Slot-name lints (issue 23; the ASH paper, section 7.4): mistakes in slot names and
//! bindings that compose without an error but are almost never what the artist meant. Each
//! is a warning at the binding, with a suggestion where one exists. `strata check` runs them,
//! and `strata render` once per run.

use crate::abi::{MaterialInfo, Pruned};
use crate::compose::binding::binding_tree;
use crate::compose::scene::SceneComposition;
use crate::compose::slots::{BindingTree, Slot};
use crate::diag::{Diagnostic, Diagnostics, Span, did_you_mean};
use crate::front::ast::Product;
use crate::scene::Stage;
use std::collections::{BTreeMap, HashMap};

/// One authored, non-empty slot binding: its slot and where it is authored.
struct Bound {
    slot: Slot,
    span: Span,
}

/// Runs every slot lint on a composed stage and reports to `diags`. `compiled` holds the
/// compiled (or lowered) info of each of `scene.materials`, in order: the hidden-slot lint
/// reads the compiler's pruning from it.
pub fn lint_slots(stage: &Stage, scene: &SceneComposition, compiled: &[&MaterialInfo], diags: &mut Diagnostics) {
    // The composition has reported the tree's own diagnostics already.
    let tree = binding_tree(stage, &mut Diagnostics::new());
    let bound = bound_slots(&tree);
    numeric_lengths(&bound, diags);
    look_alikes(&bound, diags);
    unbound_bases(&bound, diags);
    hidden_everywhere(&bound, compiled, diags);
    nothing_to_show(scene, diags);
}

/// Every non-empty slot binding (direct or by collection) in scene order; the UsdShade
/// `material:binding` layer is not a slot and is left out.
fn bound_slots(tree: &BindingTree) -> Vec<Bound> {
    let mut out = Vec::new();
    for prim in &tree.prims {
        let direct = prim.bindings.iter().filter(|b| b.authored_at.is_none());
        for b in direct.chain(prim.collections.iter().map(|c| &c.binding)) {
            if b.material.is_some() && !b.slot.is_material_binding() {
                out.push(Bound { slot: b.slot.clone(), span: b.span });
            }
        }
    }
    out
}

/// The slot names in each position that sort against each other (horizontal slots; vertical
/// slots; overrides), each with the first binding that uses it, in first-use order.
fn names_by_position(bound: &[Bound]) -> [Vec<(&str, Span)>; 3] {
    let mut groups: [Vec<(&str, Span)>; 3] = Default::default();
    for b in bound {
        let names = [Some(b.slot.base.as_str()), b.slot.vertical.as_deref(), b.slot.over.as_deref()];
        for (group, name) in groups.iter_mut().zip(names) {
            if let Some(name) = name
                && !group.iter().any(|(n, _)| *n == name)
            {
                group.push((name, b.span));
            }
        }
    }
    groups
}

/// Numeric-looking names of different lengths: `9` sorts above `10` by byte order.
fn numeric_lengths(bound: &[Bound], diags: &mut Diagnostics) {
    for group in names_by_position(bound) {
        let numeric: Vec<&(&str, Span)> = group.iter().filter(|(n, _)| n.bytes().all(|c| c.is_ascii_digit())).collect();
        let Some(width) = numeric.iter().map(|(n, _)| n.len()).max() else { continue };
        for (name, span) in numeric.iter().filter(|(n, _)| n.len() < width) {
            let padded = format!("{name:0>width$}");
            // A longer name it sorts above although its value is smaller, if there is one.
            let inverted = numeric
                .iter()
                .map(|(n, _)| *n)
                .find(|other| other.len() > name.len() && *other < *name && numeric_order(name) < numeric_order(other));
            let message = match inverted {
                Some(other) => format!("slot name `{name}` sorts above `{other}` by byte order"),
                None => {
                    let other = numeric.iter().map(|(n, _)| *n).find(|n| n.len() == width).unwrap_or_default();
                    format!("numeric slot names of different lengths (`{name}`, `{other}`) sort by bytes, not by value")
                }
            };
            diags.push(
                Diagnostic::warning(message)
                    .at(*span, "first bound here")
                    .note(format!("did you mean `{padded}`? slots are layered in byte order (DESIGN.md rule 2)")),
            );
        }
    }
}

/// A key that orders digit strings by value: leading zeros dropped, then length, then bytes.
fn numeric_order(digits: &str) -> (usize, &str) {
    let significant = digits.trim_start_matches('0');
    (significant.len(), significant)
}

/// A name with case and look-alike characters folded: `O50`, `o50` and `050` are one key.
fn look_alike_key(name: &str) -> String {
    name.chars()
        .flat_map(char::to_lowercase)
        .map(|c| match c {
            'o' => '0',
            'l' | 'i' => '1',
            c => c,
        })
        .collect()
}

/// Names that differ only by case or by look-alike characters (`050`/`O50`, `010`/`01O`).
fn look_alikes(bound: &[Bound], diags: &mut Diagnostics) {
    let mut all: Vec<(&str, Span)> = Vec::new();
    for group in names_by_position(bound) {
        for (name, span) in group {
            if !all.iter().any(|(n, _)| *n == name) {
                all.push((name, span));
            }
        }
    }
    let mut by_key: BTreeMap<String, Vec<(&str, Span)>> = BTreeMap::new();
    for (name, span) in all {
        by_key.entry(look_alike_key(name)).or_default().push((name, span));
    }
    for (key, names) in by_key.into_iter().filter(|(_, names)| names.len() > 1) {
        // The spelling that is already its own key (digits, lower case) is the intended one,
        // else the first used.
        let intended = names.iter().find(|(n, _)| *n == key).unwrap_or(&names[0]).0;
        for (name, span) in names.iter().filter(|(n, _)| *n != intended) {
            diags.push(
                Diagnostic::warning(format!(
                    "slot name `{name}` differs from `{intended}` only by case or look-alike characters"
                ))
                .at(*span, "bound here")
                .note(format!("did you mean `{intended}`? they are different slots")),
            );
        }
    }
}

/// An override or vertical slot whose base slot is never bound anywhere in the stage.
fn unbound_bases(bound: &[Bound], diags: &mut Diagnostics) {
    let layers: Vec<&Slot> = bound.iter().map(|b| &b.slot).filter(|s| s.over.is_none()).collect();
    let mut reported: Vec<Slot> = Vec::new();
    for b in bound {
        let base = match (&b.slot.vertical, &b.slot.over) {
            (None, None) => continue,
            (Some(_), None) => Slot { base: b.slot.base.clone(), vertical: None, over: None },
            (_, Some(_)) => b.slot.layer(),
        };
        if layers.contains(&&base) || reported.contains(&b.slot) {
            continue;
        }
        reported.push(b.slot.clone());
        let kind = if b.slot.over.is_some() { "override" } else { "vertical" };
        let mut d = Diagnostic::warning(format!(
            "{kind} slot `{}` attaches to slot `{}`, which is never bound in this stage",
            b.slot.name(),
            base.name()
        ))
        .at(b.span, "bound here");
        let candidates: Vec<String> =
            layers.iter().filter(|s| s.vertical.is_some() == base.vertical.is_some()).map(|s| s.name()).collect();
        if let Some(hint) = did_you_mean(&base.name(), candidates.iter().map(String::as_str)) {
            d = d.note(hint);
        }
        diags.push(d);
    }
}

/// A slot hidden on every prim it reaches: on each composed material that has it, a layer
/// above it with a surface and a constant mask of 1 hides it (the layers the optimiser
/// prunes, `abi::layering`), as the compiler recorded it in [`crate::abi::LayerInfo::pruned`].
fn hidden_everywhere(bound: &[Bound], compiled: &[&MaterialInfo], diags: &mut Diagnostics) {
    // Per horizontal slot name: (materials it is in, materials where it is hidden, by what).
    let mut seen: HashMap<String, (usize, usize, String)> = HashMap::new();
    for layer in compiled.iter().flat_map(|info| &info.layers) {
        let entry = seen.entry(layer.slot.clone()).or_insert((0, 0, String::new()));
        entry.0 += 1;
        if let Some(Pruned::HiddenUnder(above)) = &layer.pruned {
            entry.1 += 1;
            entry.2 = above.clone();
        }
    }
    let mut hidden: Vec<(&String, &String)> =
        seen.iter().filter(|(_, (reach, hid, _))| *reach > 0 && reach == hid).map(|(s, (_, _, a))| (s, a)).collect();
    hidden.sort();
    for (slot, above) in hidden {
        let Some(first) = bound.iter().find(|b| b.slot.over.is_none() && b.slot.name() == *slot) else { continue };
        diags.push(
            Diagnostic::warning(format!(
                "slot `{slot}` is hidden on every prim it reaches: slot `{above}` above it is opaque (a surface with mask 1)"
            ))
            .at(first.span, "bound here")
            .note(format!("give slot `{above}` a mask below 1, or bind `{slot}` above it (a higher slot name)")),
        );
    }
}

/// A slot bound to a material whose substance has no surface and no displacement: the layer
/// shows nothing and moves nothing.
fn nothing_to_show(scene: &SceneComposition, diags: &mut Diagnostics) {
    let mut reported: Vec<&str> = Vec::new();
    for material in &scene.materials {
        for layer in material.layers.iter().flat_map(|l| std::iter::once(l).chain(&l.vertical)) {
            let graph = scene.library.get(layer.substance.graph);
            let shows = graph.products.iter().any(|p| matches!(p.product, Product::Surface | Product::Displacement));
            if shows || reported.contains(&layer.substance.path.as_str()) {
                continue;
            }
            reported.push(&layer.substance.path);
            diags.push(
                Diagnostic::warning(format!(
                    "slot `{}` is bound to `{}`, whose substance `{}` has no surface and no displacement: the layer shows nothing",
                    layer.slot.name(),
                    layer.substance.path,
                    graph.name
                ))
                .at(layer.substance.span, "bound here")
                .also(graph.span, "declared here")
                .note("bind a substance with a `surface` or a `displacement` product, or bind its overrides to a slot that has one"),
            );
        }
    }
}
