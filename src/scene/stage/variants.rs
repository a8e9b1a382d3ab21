//! Variant sets: applying selections (nested ones too) to a prim index, and reporting the
//! selections no arc offers.

use super::pass::Pass;
use super::prim_index::{Arc, MAX_NODES, Node};
use super::properties::selections;
use crate::diag::{Diagnostic, Span};
use crate::scene::usda::{LayerOffset, PrimSpec};

impl<'l> Pass<'l> {
    /// Applies variant selections as USD's prim indexing does: one variant set at a time,
    /// the strongest node's first, each selected by the strongest opinion in the index as it
    /// stands then. A selection authored inside a variant is an opinion like any other once
    /// that variant is applied, so nested selections apply to any depth; a set that has no
    /// selection yet waits until every other set is applied, as a later variant may select
    /// it. A set defined on several arcs gets the selected variant from each arc that has it.
    pub(super) fn apply_variants(&mut self, tree: &mut Node<'l>, path: &str) {
        let mut pending = VariantReport::default();
        for _ in 0..MAX_NODES {
            let chosen = {
                let mut opinions = Vec::new();
                tree.flatten(&mut opinions);
                selections(&opinions)
            };
            if !self.apply_next_variant(tree, &chosen, &mut pending) {
                break;
            }
            self.expand(tree, &mut Vec::new());
        }
        // What is left: sets nobody selects, and selections no arc offers.
        let mut unselected: Vec<(&'l str, Span)> = Vec::new();
        tree.unapplied_sets(&mut unselected);
        let mut warned: Vec<&str> = Vec::new();
        for (set_name, span) in unselected {
            if !warned.contains(&set_name) {
                warned.push(set_name);
                self.diags.push(
                    Diagnostic::warning(format!("no variant selected for variant set `{set_name}` on `{path}`"))
                        .at(span, "no variant of this set is applied"),
                );
            }
        }
        for (set_name, selection, span) in pending.missing {
            if !pending.found.iter().any(|(s, v)| *s == set_name && *v == selection) {
                self.diags.push(
                    Diagnostic::warning(format!(
                        "variant `{selection}` selected for `{set_name}` on `{path}` does not exist"
                    ))
                    .at(span, "this set has no such variant"),
                );
            }
        }
    }

    /// Applies the first variant set, in strength order, that is not applied yet and has a
    /// selection in `chosen`. Returns whether one was.
    pub(super) fn apply_next_variant(
        &mut self,
        node: &mut Node<'l>,
        chosen: &[(String, String)],
        report: &mut VariantReport<'l>,
    ) -> bool {
        let mut next: Option<(&'l str, &str)> = None;
        'specs: for spec in &node.specs {
            for set in &spec.variant_sets {
                if node.variants_done.contains(&set.name) {
                    continue;
                }
                if let Some((_, selection)) = chosen.iter().find(|(s, _)| *s == set.name) {
                    next = Some((&set.name, selection));
                    break 'specs;
                }
            }
        }
        if let Some((set_name, selection)) = next {
            node.variants_done.push(set_name.to_string());
            let sets = node
                .specs
                .iter()
                .zip(&node.offsets)
                .filter_map(|(s, o)| Some((s.variant_sets.iter().find(|v| v.name == set_name)?, *o)));
            let mut bodies: Vec<&'l PrimSpec> = Vec::new();
            let mut offsets: Vec<LayerOffset> = Vec::new();
            let mut first_set = None;
            for (set, offset) in sets {
                first_set.get_or_insert(set.span);
                if let Some(body) = set.variants.iter().find(|v| v.name == *selection) {
                    bodies.push(body);
                    offsets.push(offset);
                }
            }
            if bodies.is_empty() {
                if let Some(span) = first_set
                    && !report.missing.iter().any(|(s, v, _)| *s == set_name && v == selection)
                {
                    report.missing.push((set_name, selection.to_string(), span));
                }
            } else {
                if !report.found.iter().any(|(s, v)| *s == set_name && v == selection) {
                    report.found.push((set_name, selection.to_string()));
                }
                node.insert_child(Node {
                    arc: Arc::Variant,
                    stack: node.stack,
                    site: node.site.clone(),
                    specs: bodies,
                    offsets,
                    time: node.time,
                    map: node.map.clone(),
                    children: Vec::new(),
                    direct: true,
                    expanded: false,
                    variants_done: Vec::new(),
                });
            }
            return true;
        }
        node.children.iter_mut().any(|child| self.apply_next_variant(child, chosen, report))
    }
}

/// Variant selections seen while composing one prim: which (set, variant) pairs some arc
/// offered, and which selections an arc's set lacked, with that set's span. A selection is
/// reported missing only when no arc offers it: a set may be split across arcs.
#[derive(Default)]
pub(super) struct VariantReport<'l> {
    pub(super) found: Vec<(&'l str, String)>,
    pub(super) missing: Vec<(&'l str, String, Span)>,
}

impl<'l> Node<'l> {
    /// Variant sets of this node and its descendants that no selection applied, with the
    /// span of their first `variantSet` statement.
    pub(super) fn unapplied_sets(&self, out: &mut Vec<(&'l str, Span)>) {
        for spec in &self.specs {
            for set in &spec.variant_sets {
                if !self.variants_done.contains(&set.name) && !out.iter().any(|(s, _)| *s == set.name) {
                    out.push((&set.name, set.span));
                }
            }
        }
        for child in &self.children {
            child.unapplied_sets(out);
        }
    }
}
