//! Composition arcs of a prim index node: inherits, references and payloads (their list ops,
//! targets and the layers they bring in).

use super::layers::Layers;
use super::pass::Pass;
use super::prim_index::{Arc, MAX_NODES, Node, anchor};
use crate::diag::{Diagnostic, Span};
use crate::scene::usda::{LayerOffset, Reference, Target};
use crate::scene::value::AssetPath;

impl<'l> Pass<'l> {
    pub(super) fn direct_arcs(&mut self, node: &Node<'l>, ancestors: &[(usize, String)]) -> Vec<Node<'l>> {
        let mut inherits: Vec<Target> = Vec::new();
        let mut references: Vec<Reference> = Vec::new();
        let mut payloads: Vec<Reference> = Vec::new();
        for spec in node.specs.iter().rev() {
            spec.metadata.inherits.apply(&mut inherits, |a, b| a.0 == b.0);
            spec.metadata.references.apply(&mut references, same_reference);
            spec.metadata.payloads.apply(&mut payloads, same_reference);
            if !spec.metadata.specializes.is_empty() {
                self.diags
                    .push(Diagnostic::warning("`specializes` is not supported; ignored").at(spec.span, "on this prim"));
            }
        }
        let mut arcs = Vec::new();
        for (path, span) in inherits {
            let target = anchor(&node.site, &path);
            if let Some(n) = self.arc_node(node, Arc::Inherit, node.stack, target, node.time, span, ancestors) {
                arcs.push(n);
            }
        }
        for (arc, list) in [(Arc::Reference, references), (Arc::Payload, payloads)] {
            for reference in list {
                let Some((stack, target)) = self.reference_target(node, &reference) else {
                    continue;
                };
                // The reference's offset applies within the referencing layer stack (the
                // sublayer offset of the layer that authored it is not composed in).
                let time = node.time.then(reference.offset);
                if let Some(n) = self.arc_node(node, arc, stack, target, time, reference.span, ancestors) {
                    arcs.push(n);
                }
            }
        }
        arcs
    }

    /// The layer stack and prim path a reference or payload points at.
    pub(super) fn reference_target(&mut self, node: &Node<'l>, reference: &Reference) -> Option<(usize, String)> {
        let stack = match &reference.asset {
            None => node.stack,
            Some(asset) => self.layer_for(asset, reference.span)?,
        };
        let path = match &reference.prim_path {
            Some(p) => anchor(&node.site, p),
            None => {
                let layer = &self.layers.get(stack)?.layer;
                match &layer.metadata.default_prim {
                    Some((name, _)) => format!("/{name}"),
                    None => {
                        let authored = reference.asset.as_ref().map_or("", |a| a.authored.as_str());
                        self.warnings.push(
                            "missing default prim",
                            authored,
                            Diagnostic::warning(format!(
                                "`{authored}` has no `defaultPrim` and the arc names no prim: it adds nothing"
                            ))
                            .at(reference.span, "name the prim: `@file.usda@</Prim>`"),
                        );
                        return None;
                    }
                }
            }
        };
        Some((stack, path))
    }

    /// The loaded layer for an asset, or records it as needed for the next pass.
    pub(super) fn layer_for(&mut self, asset: &AssetPath, span: Span) -> Option<usize> {
        // Every prim below a reference asks again: the key (a `realpath`) is computed once
        // per asset path and pass, and needed layers are a set, so n distinct references
        // cost O(n), not O(n²) system calls (10 000 references took 85 s).
        let key = match self.keys.get(&asset.resolved) {
            Some(key) => key.clone(),
            None => {
                let key = Layers::key(&asset.resolved);
                self.keys.insert(asset.resolved.clone(), key.clone());
                key
            }
        };
        match self.layers.by_key.get(&key) {
            Some(known) => *known,
            None => {
                if self.needed.insert(key) {
                    self.needs.push((asset.resolved.clone(), asset.authored.clone(), span));
                }
                None
            }
        }
    }

    /// The node of an arc from `from` to `site` in `stack`, whose root layer's times map to
    /// the stage's through `time`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn arc_node(
        &mut self,
        from: &Node<'l>,
        arc: Arc,
        stack: usize,
        site: String,
        time: LayerOffset,
        span: Span,
        ancestors: &[(usize, String)],
    ) -> Option<Node<'l>> {
        if ancestors.iter().any(|(s, p)| *s == stack && *p == site) {
            let what = if arc == Arc::Inherit { "inherit" } else { "reference" };
            if self.reported_arcs.insert(span) {
                self.diags.push(
                    Diagnostic::error(format!("{what} cycle: `{site}` depends on itself"))
                        .at(span, format!("this {what} leads back to a prim that is being composed")),
                );
            }
            return None;
        }
        if ancestors.len() > 64 || from.count() > MAX_NODES {
            if self.reported_arcs.insert(span) {
                self.diags.push(
                    Diagnostic::error("composition is too deep or too large").at(span, "while composing this arc"),
                );
            }
            return None;
        }
        let (specs, offsets) = self.specs_at(stack, &site, time);
        // An inherit of a class nobody defines is ordinary USD (the class is an extension
        // point); a reference or payload to nothing is composed around, as USD does.
        if specs.is_empty() && arc != Arc::Inherit {
            let what = if arc == Arc::Payload { "payload" } else { "reference" };
            if self.reported_arcs.insert(span) {
                self.warnings.push(
                    "missing arc target",
                    &site,
                    Diagnostic::warning(format!(
                        "the prim `{site}` that this {what} targets does not exist: the {what} adds nothing"
                    ))
                    .at(span, format!("{what} here")),
                );
            }
            return None;
        }
        let mut map = Vec::with_capacity(from.map.len() + 1);
        map.push((site.clone(), from.site.clone()));
        map.extend(from.map.iter().cloned());
        Some(Node {
            arc,
            stack,
            site,
            specs,
            offsets,
            time,
            map,
            children: Vec::new(),
            direct: true,
            expanded: false,
            variants_done: Vec::new(),
        })
    }
}

pub(super) fn same_reference(a: &Reference, b: &Reference) -> bool {
    a.asset.as_ref().map(|x| &x.resolved) == b.asset.as_ref().map(|x| &x.resolved) && a.prim_path == b.prim_path
}
