//! A prim's index: the tree of nodes that hold its opinions, one node per composition arc
//! (LIVRPS order), and the path mapping from a node's namespace to the stage's.

use crate::scene::usda::{self, LayerOffset, PrimSpec, PropertySpec};

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Arc {
    Root,
    Inherit,
    Variant,
    Reference,
    Payload,
}

/// Prefix mappings from a node's namespace to the stage's, innermost first.
pub(super) type MapChain = Vec<(String, String)>;

/// Past this many nodes in one prim's index, composition gives up on further arcs.
pub(super) const MAX_NODES: usize = 4096;

pub(super) struct Node<'l> {
    pub(super) arc: Arc,
    /// The root layer of the layer stack this node's site lives in.
    pub(super) stack: usize,
    /// The prim path in that layer stack's namespace.
    pub(super) site: String,
    /// Specs at the site, strongest first.
    pub(super) specs: Vec<&'l PrimSpec>,
    /// For each of `specs`, how its layer's times map to the stage's.
    pub(super) offsets: Vec<LayerOffset>,
    /// How times in the root layer of `stack` map to the stage's (the arcs' layer offsets).
    pub(super) time: LayerOffset,
    pub(super) map: MapChain,
    pub(super) children: Vec<Node<'l>>,
    /// Added for this prim (not inherited from an ancestor's index).
    pub(super) direct: bool,
    pub(super) expanded: bool,
    /// Variant sets already applied at this node.
    pub(super) variants_done: Vec<String>,
}

impl<'l> Node<'l> {
    /// The node for the same arc one level down, at child `name`; `None` if nothing is there.
    pub(super) fn child(&self, name: &str) -> Option<Node<'l>> {
        let (specs, offsets): (Vec<&PrimSpec>, Vec<LayerOffset>) =
            self.specs.iter().zip(&self.offsets).filter_map(|(s, o)| Some((s.child(name)?, *o))).unzip();
        let children: Vec<Node> = self.children.iter().filter_map(|c| c.child(name)).collect();
        if specs.is_empty() && children.is_empty() {
            return None;
        }
        Some(Node {
            arc: self.arc,
            stack: self.stack,
            site: join_path(&self.site, name),
            specs,
            offsets,
            time: self.time,
            map: self.map.clone(),
            children,
            direct: false,
            expanded: false,
            variants_done: Vec::new(),
        })
    }

    pub(super) fn count(&self) -> usize {
        1 + self.children.iter().map(Node::count).sum::<usize>()
    }

    /// Inserts a direct arc after the direct arcs of the same type, before ancestral ones.
    pub(super) fn insert_child(&mut self, node: Node<'l>) {
        let at = self
            .children
            .iter()
            .position(|c| c.arc > node.arc || (c.arc == node.arc && !c.direct))
            .unwrap_or(self.children.len());
        self.children.insert(at, node);
    }

    /// How the times of `attr`, an attribute of one of this node's specs, map to the stage's.
    pub(super) fn offset_of(&self, attr: &usda::AttributeSpec) -> LayerOffset {
        let owns = |spec: &PrimSpec| {
            spec.properties.iter().any(|p| matches!(p, PropertySpec::Attribute(a) if std::ptr::eq(&**a, attr)))
        };
        let at = self.specs.iter().position(|s| owns(s));
        at.and_then(|i| self.offsets.get(i)).copied().unwrap_or(self.time)
    }

    /// Every `(spec, node)` pair in strength order.
    pub(super) fn flatten<'n>(&'n self, out: &mut Vec<(&'l PrimSpec, &'n Node<'l>)>) {
        for spec in &self.specs {
            out.push((spec, self));
        }
        for child in &self.children {
            child.flatten(out);
        }
    }
}

pub(super) fn join_path(parent: &str, name: &str) -> String {
    if parent == "/" || parent.is_empty() { format!("/{name}") } else { format!("{parent}/{name}") }
}

/// Maps a path authored at `site` in a node's namespace to the stage's namespace.
pub(super) fn map_path(chain: &MapChain, site: &str, path: &str) -> String {
    let mut path = anchor(site, path);
    for (from, to) in chain {
        if let Some(rest) = path.strip_prefix(from.as_str())
            && (rest.is_empty() || rest.starts_with('/') || rest.starts_with('.'))
        {
            path = format!("{to}{rest}");
        }
    }
    path
}

/// Makes a relative path (`../Mat`, `Child`, `.prop`) absolute against the prim at `site`.
pub(super) fn anchor(site: &str, path: &str) -> String {
    if path.starts_with('/') || path.is_empty() {
        return path.to_string();
    }
    let mut base: Vec<&str> = site.split('/').filter(|s| !s.is_empty()).collect();
    let mut rest = path;
    loop {
        if let Some(r) = rest.strip_prefix("../") {
            base.pop();
            rest = r;
        } else if rest == ".." {
            base.pop();
            rest = "";
        } else if let Some(r) = rest.strip_prefix("./") {
            rest = r;
        } else {
            break;
        }
    }
    let mut out = String::new();
    for b in &base {
        out.push('/');
        out.push_str(b);
    }
    if rest.starts_with('.') || rest.is_empty() {
        if out.is_empty() {
            out.push('/');
        }
        out.push_str(rest);
    } else {
        out.push('/');
        out.push_str(rest);
    }
    out
}
