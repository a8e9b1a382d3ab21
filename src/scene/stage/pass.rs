//! One composition pass: walks the root layer stack's prims, builds each prim's index from its
//! parent's, and composes the prim tree; layers it lacks are recorded for the next pass.

use super::layers::Layers;
use super::prim_index::{Arc, Node, join_path};
use super::properties::{compose_properties, selections};
use super::{Prim, PrimId, count_work};
use crate::diag::{Diagnostics, OncePerKind, Span};
use crate::scene::usda::{LayerOffset, PrimSpec, Specifier};
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;

pub(super) struct Pass<'l> {
    pub(super) layers: &'l Layers,
    pub(super) root: usize,
    pub(super) diags: Diagnostics,
    /// Layers this pass wanted but that are not loaded yet: resolved path, authored asset
    /// path, and where it is named.
    pub(super) needs: Vec<(PathBuf, String, Span)>,
    /// The keys of `needs`.
    pub(super) needed: HashSet<PathBuf>,
    /// Resolved asset path → [`Layers::key`], computed once per pass.
    pub(super) keys: HashMap<PathBuf, PathBuf>,
    /// Arcs composed around (a target prim that does not exist), one warning per kind.
    pub(super) warnings: OncePerKind,
    pub(super) prims: Vec<Prim>,
    pub(super) roots: Vec<PrimId>,
    pub(super) by_path: HashMap<String, PrimId>,
    /// Arcs whose cycle or size error was reported: each authored arc is reported once,
    /// not once per prim that reaches it (every descendant of a prim re-walks its arcs).
    pub(super) reported_arcs: HashSet<Span>,
}

impl<'l> Pass<'l> {
    pub(super) fn new(layers: &'l Layers, root: usize) -> Pass<'l> {
        Pass {
            layers,
            root,
            diags: Diagnostics::new(),
            needs: Vec::new(),
            needed: HashSet::new(),
            keys: HashMap::new(),
            warnings: OncePerKind::new(),
            prims: Vec::new(),
            roots: Vec::new(),
            by_path: HashMap::new(),
            reported_arcs: HashSet::new(),
        }
    }

    pub(super) fn stack(&self, layer: usize) -> &'l [usize] {
        self.layers.stack(layer).map(|s| s.layers.as_slice()).unwrap_or(&[])
    }

    /// Specs at `path` in every layer of `stack`, strongest first, each with how its times
    /// map to the stage's when the stack's root layer's map through `time`.
    pub(super) fn specs_at(
        &self,
        stack: usize,
        path: &str,
        time: LayerOffset,
    ) -> (Vec<&'l PrimSpec>, Vec<LayerOffset>) {
        let layers = self.layers;
        let Some(stack) = layers.stack(stack) else { return (Vec::new(), Vec::new()) };
        let Some(root_name) = path.split('/').find(|s| !s.is_empty()) else { return (Vec::new(), Vec::new()) };
        let Some(positions) = stack.by_root_prim.get(root_name) else { return (Vec::new(), Vec::new()) };
        count_work(positions.len());
        positions
            .iter()
            .filter_map(|&at| {
                let at = at as usize;
                let spec = layers.get(*stack.layers.get(at)?)?.layer.prim_at(path)?;
                Some((spec, time.then(*stack.offsets.get(at)?)))
            })
            .unzip()
    }

    pub(super) fn run(&mut self) {
        let layers = self.layers;
        // Root prim names, weakest layer first so stronger layers' new names come after.
        let mut names: Vec<&str> = Vec::new();
        let mut seen: HashSet<&str> = HashSet::new();
        for &i in self.stack(self.root).iter().rev() {
            if let Some(l) = layers.get(i) {
                for p in &l.layer.prims {
                    if seen.insert(&p.name) {
                        names.push(&p.name);
                    }
                }
            }
        }
        for name in names {
            let site = format!("/{name}");
            let (specs, offsets) = self.specs_at(self.root, &site, LayerOffset::default());
            let node = Node {
                arc: Arc::Root,
                stack: self.root,
                specs,
                offsets,
                time: LayerOffset::default(),
                site,
                map: Vec::new(),
                children: Vec::new(),
                direct: true,
                expanded: false,
                variants_done: Vec::new(),
            };
            if let Some(id) = self.compose_prim(node, None, name) {
                self.roots.push(id);
            }
        }
    }

    /// Composes one prim from its index tree, then its children. Returns `None` for prims
    /// that are not part of the renderable tree (abstract, undefined or inactive).
    pub(super) fn compose_prim(&mut self, mut tree: Node<'l>, parent: Option<PrimId>, name: &str) -> Option<PrimId> {
        let path = match parent {
            Some(p) => join_path(&self.prims[p.0 as usize].path, name),
            None => format!("/{name}"),
        };
        self.expand(&mut tree, &mut Vec::new());
        self.apply_variants(&mut tree, &path);

        let mut opinions = Vec::new();
        tree.flatten(&mut opinions);

        let specifier =
            opinions.iter().map(|(s, _)| s.specifier).find(|s| *s != Specifier::Over).unwrap_or(Specifier::Over);
        let active = opinions.iter().find_map(|(s, _)| s.metadata.active).unwrap_or(true);
        if specifier != Specifier::Def || !active {
            return None;
        }
        let span =
            opinions.iter().find(|(s, _)| s.specifier == Specifier::Def).map(|(s, _)| s.span).unwrap_or_default();
        let mut api_schemas = Vec::new();
        for (spec, _) in opinions.iter().rev() {
            spec.metadata.api_schemas.apply(&mut api_schemas, |a, b| a == b);
        }
        let (attributes, relationships) = compose_properties(&opinions);
        let prim = Prim {
            path: path.clone(),
            name: name.to_string(),
            type_name: opinions.iter().find_map(|(s, _)| s.type_name.clone()),
            kind: opinions.iter().find_map(|(s, _)| s.metadata.kind.clone()),
            instanceable: opinions.iter().find_map(|(s, _)| s.metadata.instanceable).unwrap_or(false),
            api_schemas,
            variant_selections: selections(&opinions),
            doc: opinions.iter().find_map(|(s, _)| s.metadata.doc.clone()),
            parent,
            children: Vec::new(),
            span,
            attributes,
            relationships,
        };
        let id = PrimId(self.prims.len() as u32);
        self.prims.push(prim);
        self.by_path.insert(path, id);

        // Child names, weakest opinion first, so an asset's order is kept and local
        // additions follow it.
        let mut names: Vec<&'l str> = Vec::new();
        let mut seen: HashSet<&'l str> = HashSet::new();
        for (spec, _) in opinions.iter().rev() {
            for child in &spec.children {
                if seen.insert(&child.name) {
                    names.push(&child.name);
                }
            }
        }
        drop(opinions);
        let mut children = Vec::new();
        for child_name in names {
            if let Some(child_tree) = tree.child(child_name)
                && let Some(child) = self.compose_prim(child_tree, Some(id), child_name)
            {
                children.push(child);
            }
        }
        if let Some(prim) = self.prims.get_mut(id.0 as usize) {
            prim.children = children;
        }
        Some(id)
    }

    /// Adds the inherit, reference and payload arcs authored on every node's specs.
    pub(super) fn expand(&mut self, node: &mut Node<'l>, ancestors: &mut Vec<(usize, String)>) {
        ancestors.push((node.stack, node.site.clone()));
        if !node.expanded {
            node.expanded = true;
            for arc in self.direct_arcs(node, ancestors) {
                node.insert_child(arc);
            }
        }
        for child in &mut node.children {
            self.expand(child, ancestors);
        }
        ancestors.pop();
    }
}
