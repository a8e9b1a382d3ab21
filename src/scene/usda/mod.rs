//! The USD ASCII (`.usda`) reader: lexer, parser and the layer syntax tree it produces.
//!
//! A [`Layer`] is one file as written, before composition: prim specs with their metadata,
//! properties, children and variant sets. Several statements about the same property in one
//! prim (`rel r`, `prepend rel r = ...`, `x.timeSamples`, `x.connect`) are merged into one
//! property spec, so composition sees one opinion per property per layer.
//! [`crate::scene::stage`] composes layers into a stage.

pub mod lexer;
pub mod parser;

pub use parser::parse;

use crate::diag::{FileId, Span};
use crate::scene::value::{AssetPath, Value, ValueType};
use std::collections::HashMap;
use std::sync::OnceLock;

/// Lists at most this long are searched by name directly; longer ones get a [`NameIndex`].
/// A handful of string compares beats hashing, and most prims have few children.
const LINEAR_SEARCH_MAX: usize = 8;

/// A lazily built name → position map over a list of prim specs (a layer's root prims or a
/// prim's children), so composition finds a child by name in constant time: composing `n`
/// siblings looks each one up in every opinion, which a linear search made O(n²) (109 000
/// siblings took minutes). Built on the first lookup, after parsing has finished the list.
#[derive(Clone, Default)]
pub struct NameIndex(OnceLock<HashMap<Box<str>, u32>>);

impl std::fmt::Debug for NameIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("NameIndex")
    }
}

impl NameIndex {
    /// The first spec in `specs` named `name`. `specs` must be the list this index serves,
    /// unchanged since the first lookup.
    pub fn find<'s>(&self, specs: &'s [PrimSpec], name: &str) -> Option<&'s PrimSpec> {
        if specs.len() <= LINEAR_SEARCH_MAX {
            return specs.iter().find(|c| c.name == name);
        }
        let map = self.0.get_or_init(|| {
            let mut map = HashMap::with_capacity(specs.len());
            for (i, spec) in specs.iter().enumerate() {
                // The first of several same-named specs wins, as the linear search did.
                map.entry(spec.name.as_str().into()).or_insert(i as u32);
            }
            map
        });
        let found = specs.get(*map.get(name)? as usize)?;
        // A list changed after indexing would make the index lie; never return a wrong spec.
        (found.name == name).then_some(found)
    }

    /// Whether the map has been built (for tests: short lists never build one).
    pub fn is_built(&self) -> bool {
        self.0.get().is_some()
    }
}

/// A scene path with the span of its text (relationship targets, connections, inherits).
pub type Target = (String, Span);

/// One parsed `.usda` file.
#[derive(Clone, Debug, Default)]
pub struct Layer {
    /// The file it was read from.
    pub file: FileId,
    /// The `( ... )` block after the header.
    pub metadata: LayerMetadata,
    /// Root prim specs in file order.
    pub prims: Vec<PrimSpec>,
    /// Finds root prims by name without a linear search.
    pub prim_index: NameIndex,
}

impl Layer {
    /// The prim spec at an absolute path such as `/World/Mesh` (not looking into variants).
    pub fn prim_at(&self, path: &str) -> Option<&PrimSpec> {
        let mut names = path.split('/').filter(|s| !s.is_empty());
        let first = names.next()?;
        let mut spec = self.root_prim(first)?;
        for name in names {
            spec = spec.child(name)?;
        }
        Some(spec)
    }

    /// The root prim spec named `name`.
    pub fn root_prim(&self, name: &str) -> Option<&PrimSpec> {
        self.prim_index.find(&self.prims, name)
    }
}

/// Layer-level metadata.
#[derive(Clone, Debug, Default)]
pub struct LayerMetadata {
    /// `doc = "..."`.
    pub doc: Option<String>,
    /// A bare string at the start of the block.
    pub comment: Option<String>,
    /// `defaultPrim = "name"` with the span of the value.
    pub default_prim: Option<(String, Span)>,
    /// `upAxis = "Y"`.
    pub up_axis: Option<String>,
    /// `metersPerUnit = 0.01`.
    pub meters_per_unit: Option<f64>,
    /// `subLayers = [@a.usda@, ...]`, strongest first, with the span of each asset path.
    pub sub_layers: Vec<(AssetPath, Span)>,
    /// The layer offset of each entry of `sub_layers` (identity where missing).
    pub sub_layer_offsets: Vec<LayerOffset>,
    /// Every other entry (`customLayerData`, `startTimeCode`, ...), kept as written.
    pub other: Vec<MetadataEntry>,
}

/// `def`, `over` or `class`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Specifier {
    /// `def`: defines the prim.
    Def,
    /// `over`: only adds opinions to a prim defined elsewhere.
    Over,
    /// `class`: an abstract prim other prims inherit or reference.
    Class,
}

/// The operation a list-op statement performs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ListOpKind {
    /// `x = [...]`: replaces weaker opinions.
    #[default]
    Explicit,
    /// `prepend x = [...]`.
    Prepend,
    /// `append x = [...]`.
    Append,
    /// `delete x = [...]`.
    Delete,
    /// `add x = [...]` (legacy; adds missing items at the end).
    Add,
    /// `reorder x = [...]`.
    Reorder,
}

impl ListOpKind {
    /// The keyword for a list-op prefix, if `word` is one.
    pub fn from_keyword(word: &str) -> Option<ListOpKind> {
        Some(match word {
            "prepend" => ListOpKind::Prepend,
            "append" => ListOpKind::Append,
            "delete" => ListOpKind::Delete,
            "add" => ListOpKind::Add,
            "reorder" => ListOpKind::Reorder,
            _ => return None,
        })
    }
}

/// One layer's opinion about a list (references, targets, ...), as USD's `SdfListOp`.
#[derive(Clone, Debug, PartialEq)]
pub struct ListOp<T> {
    /// Explicit items; `Some(vec![])` for an authored `= None` or `= []`.
    pub explicit: Option<Vec<T>>,
    /// `prepend` items.
    pub prepended: Vec<T>,
    /// `append` items.
    pub appended: Vec<T>,
    /// `delete` items.
    pub deleted: Vec<T>,
    /// `add` items.
    pub added: Vec<T>,
    /// `reorder` items.
    pub ordered: Vec<T>,
}

impl<T> Default for ListOp<T> {
    fn default() -> Self {
        ListOp {
            explicit: None,
            prepended: Vec::new(),
            appended: Vec::new(),
            deleted: Vec::new(),
            added: Vec::new(),
            ordered: Vec::new(),
        }
    }
}

impl<T: Clone> ListOp<T> {
    /// Records one statement. As in Sdf, a list op is either explicit or a set of edits:
    /// switching between the two (`r = [...]` then `delete r = ...`, or the reverse) drops
    /// everything recorded before.
    pub fn set(&mut self, kind: ListOpKind, items: Vec<T>) {
        if self.explicit.is_some() && kind != ListOpKind::Explicit {
            *self = ListOp::default();
        }
        match kind {
            ListOpKind::Explicit => *self = ListOp { explicit: Some(items), ..ListOp::default() },
            ListOpKind::Prepend => self.prepended = items,
            ListOpKind::Append => self.appended = items,
            ListOpKind::Delete => self.deleted = items,
            ListOpKind::Add => self.added = items,
            ListOpKind::Reorder => self.ordered = items,
        }
    }

    /// Whether no statement was recorded.
    pub fn is_empty(&self) -> bool {
        self.explicit.is_none()
            && self.prepended.is_empty()
            && self.appended.is_empty()
            && self.deleted.is_empty()
            && self.added.is_empty()
            && self.ordered.is_empty()
    }

    /// Applies this opinion on top of the weaker result `list`, comparing items with `same`.
    /// Returns whether the list was reset by an explicit opinion.
    pub fn apply(&self, list: &mut Vec<T>, same: impl Fn(&T, &T) -> bool) -> bool {
        if let Some(explicit) = &self.explicit {
            list.clear();
            for item in explicit {
                // Duplicates in an explicit list keep the first occurrence, as Sdf does.
                if !list.iter().any(|x| same(x, item)) {
                    list.push(item.clone());
                }
            }
            return true;
        }
        list.retain(|x| !self.deleted.iter().any(|d| same(x, d)));
        for item in &self.added {
            if !list.iter().any(|x| same(x, item)) {
                list.push(item.clone());
            }
        }
        if !self.prepended.is_empty() {
            list.retain(|x| !self.prepended.iter().any(|p| same(x, p)));
            let mut front: Vec<T> = Vec::with_capacity(self.prepended.len() + list.len());
            for item in &self.prepended {
                if !front.iter().any(|x| same(x, item)) {
                    front.push(item.clone());
                }
            }
            front.append(list);
            *list = front;
        }
        for item in &self.appended {
            list.retain(|x| !same(x, item));
            list.push(item.clone());
        }
        if !self.ordered.is_empty() {
            // Items named by `reorder` move into that order, at the position of the first
            // of them; everything else keeps its place.
            let mut ordered: Vec<T> = Vec::new();
            for item in &self.ordered {
                if let Some(found) = list.iter().find(|x| same(x, item))
                    && !ordered.iter().any(|x| same(x, found))
                {
                    ordered.push(found.clone());
                }
            }
            if let Some(at) = list.iter().position(|x| ordered.iter().any(|o| same(x, o))) {
                list.retain(|x| !ordered.iter().any(|o| same(x, o)));
                let at = at.min(list.len());
                list.splice(at..at, ordered);
            }
        }
        false
    }
}

/// A `references` or `payload` item: `@asset@</Prim>`, `@asset@` or `</Internal>`.
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// The external layer; `None` for an internal reference.
    pub asset: Option<AssetPath>,
    /// The target prim; `None` means the layer's `defaultPrim`.
    pub prim_path: Option<String>,
    /// The whole item's text.
    pub span: Span,
    /// `(offset = 5; scale = 2)`: how the referenced layer's times map to this one's.
    pub offset: LayerOffset,
}

/// A layer offset: time `t` in a referenced layer or sublayer is `offset + scale · t` in the
/// layer that names it (`SdfLayerOffset`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerOffset {
    /// Added after scaling.
    pub offset: f64,
    /// Multiplies the inner layer's times.
    pub scale: f64,
}

impl Default for LayerOffset {
    fn default() -> LayerOffset {
        LayerOffset { offset: 0.0, scale: 1.0 }
    }
}

impl LayerOffset {
    /// The time in the outer layer of time `t` in the inner one.
    pub fn apply(self, t: f64) -> f64 {
        self.offset + self.scale * t
    }

    /// `self` after `inner`: maps the innermost layer's times through `inner`, then `self`.
    pub fn then(self, inner: LayerOffset) -> LayerOffset {
        LayerOffset { offset: self.apply(inner.offset), scale: self.scale * inner.scale }
    }
}

/// Prim metadata that composition understands, plus everything else as written.
#[derive(Clone, Debug, Default)]
pub struct PrimMetadata {
    /// `references`.
    pub references: ListOp<Reference>,
    /// `payload`.
    pub payloads: ListOp<Reference>,
    /// `inherits`.
    pub inherits: ListOp<Target>,
    /// `specializes` (parsed; composed like a weak inherit is not supported).
    pub specializes: ListOp<Target>,
    /// `variants = { string set = "selection" }`, with the span of each selection.
    pub variant_selections: Vec<(String, String, Span)>,
    /// `variantSets`.
    pub variant_set_names: ListOp<String>,
    /// `apiSchemas`.
    pub api_schemas: ListOp<String>,
    /// `kind`.
    pub kind: Option<String>,
    /// `active`.
    pub active: Option<bool>,
    /// `instanceable`.
    pub instanceable: Option<bool>,
    /// `doc`.
    pub doc: Option<String>,
    /// A bare string at the start of the block.
    pub comment: Option<String>,
    /// Every other entry (`customData`, `hidden`, ...).
    pub other: Vec<MetadataEntry>,
}

/// One `[op] key = value` metadata entry kept as written.
#[derive(Clone, Debug, PartialEq)]
pub struct MetadataEntry {
    /// The key.
    pub key: String,
    /// Its list-op prefix, `Explicit` when none.
    pub op: ListOpKind,
    /// The value.
    pub value: Value,
    /// The whole entry.
    pub span: Span,
}

/// A prim statement (`def Xform "a" (...) { ... }`) or a variant's body.
#[derive(Clone, Debug)]
pub struct PrimSpec {
    /// `def`, `over` or `class` (variant bodies are `over`).
    pub specifier: Specifier,
    /// The schema type name (`Xform`), if written.
    pub type_name: Option<String>,
    /// The prim's name (a variant's name for variant bodies).
    pub name: String,
    /// From the specifier to the name: where diagnostics point for the prim.
    pub span: Span,
    /// The metadata block.
    pub metadata: PrimMetadata,
    /// Attributes and relationships in first-authored order.
    pub properties: Vec<PropertySpec>,
    /// Child prims in file order.
    pub children: Vec<PrimSpec>,
    /// Finds children by name without a linear search.
    pub child_index: NameIndex,
    /// `variantSet "name" = { ... }` statements.
    pub variant_sets: Vec<VariantSetSpec>,
}

impl PrimSpec {
    /// The child spec named `name`.
    pub fn child(&self, name: &str) -> Option<&PrimSpec> {
        self.child_index.find(&self.children, name)
    }

    /// The property spec named `name`.
    pub fn property(&self, name: &str) -> Option<&PropertySpec> {
        self.properties.iter().find(|p| p.name() == name)
    }
}

/// `variantSet "name" = { "a" { ... } "b" { ... } }`.
#[derive(Clone, Debug)]
pub struct VariantSetSpec {
    /// The set's name.
    pub name: String,
    /// The `variantSet "name"` text.
    pub span: Span,
    /// Each variant's body; its `name` is the variant's name.
    pub variants: Vec<PrimSpec>,
}

/// An attribute or relationship spec.
#[derive(Clone, Debug)]
pub enum PropertySpec {
    /// An attribute (boxed, as both kinds are: a prim holds many properties).
    Attribute(Box<AttributeSpec>),
    /// A relationship.
    Relationship(Box<RelationshipSpec>),
}

impl PropertySpec {
    /// The property's name.
    pub fn name(&self) -> &str {
        match self {
            PropertySpec::Attribute(a) => &a.name,
            PropertySpec::Relationship(r) => &r.name,
        }
    }

    /// The span of its first statement.
    pub fn span(&self) -> Span {
        match self {
            PropertySpec::Attribute(a) => a.span,
            PropertySpec::Relationship(r) => r.span,
        }
    }
}

/// An attribute: `[custom] [uniform] float3[] name = value ( metadata )`.
#[derive(Clone, Debug)]
pub struct AttributeSpec {
    /// Its (namespaced) name.
    pub name: String,
    /// Its first statement, from the first keyword to the name.
    pub span: Span,
    /// The declared type as written, `[]` included (`point3f[]`).
    pub type_name: String,
    /// The classified type.
    pub value_type: ValueType,
    /// `custom` was written.
    pub custom: bool,
    /// `uniform` was written.
    pub uniform: bool,
    /// The default value with its span; `Value::None` for an authored block (`= None`).
    pub default: Option<(Value, Span)>,
    /// `name.timeSamples = { time: value }`, as written.
    pub time_samples: Vec<(f64, Value)>,
    /// `name.connect = ...` statements.
    pub connections: ListOp<Target>,
    /// The metadata block entries (`interpolation`, `elementSize`, ...).
    pub metadata: Vec<MetadataEntry>,
}

impl AttributeSpec {
    /// A declared attribute with no value, connection or metadata yet: what both readers
    /// (text and crate) start from before filling in the opinions they find.
    pub fn declared(name: &str, span: Span, type_name: String, custom: bool, uniform: bool) -> AttributeSpec {
        let (base, array) = match type_name.strip_suffix("[]") {
            Some(base) => (base, true),
            None => (type_name.as_str(), false),
        };
        AttributeSpec {
            name: name.to_string(),
            span,
            value_type: ValueType::parse(base, array),
            type_name,
            custom,
            uniform,
            default: None,
            time_samples: Vec::new(),
            connections: ListOp::default(),
            metadata: Vec::new(),
        }
    }

    /// A metadata value by key.
    pub fn meta(&self, key: &str) -> Option<&Value> {
        self.metadata.iter().find(|m| m.key == key).map(|m| &m.value)
    }
}

/// A relationship: `[custom] [op] rel name [= targets]`.
#[derive(Clone, Debug)]
pub struct RelationshipSpec {
    /// Its (namespaced) name.
    pub name: String,
    /// Its first statement, from the first keyword to the name.
    pub span: Span,
    /// `custom` was written.
    pub custom: bool,
    /// Target statements; an `= None` or `= []` is `explicit: Some(vec![])`.
    pub targets: ListOp<Target>,
    /// `= None` was written.
    pub explicit_none: bool,
    /// The first statement that authored targets (`= ...`, with or without a list-op prefix);
    /// `None` when the relationship is only declared (`rel r`), which is no target opinion.
    pub authored: Option<Span>,
    /// The metadata block entries.
    pub metadata: Vec<MetadataEntry>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diag::{Diagnostics, SourceMap};
    use std::path::Path;

    fn layer(text: &str) -> Layer {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let file = sources.add("test.usda", text.to_string());
        let layer = parse(file, sources.text(file), Path::new("."), &mut diags);
        assert!(!diags.has_errors(), "{}", diags.render(&sources));
        layer
    }

    #[test]
    fn long_sibling_lists_are_looked_up_through_a_map() {
        // Composition looks every child up by name in every opinion: with a linear search
        // that is quadratic in the number of siblings (109 000 siblings took minutes).
        let mut text = String::from("#usda 1.0\n");
        for i in 0..100 {
            text += &format!("def \"R{i}\" {{}}\n");
        }
        text += "def \"Parent\" {\n";
        for i in 0..100 {
            text += &format!("    def \"C{i}\" {{ float which = {i} }}\n");
        }
        // A second spec of an existing name: the first keeps winning, as with a search.
        text += "    def \"C7\" { float which = -1 }\n}\n";
        let layer = layer(&text);
        assert!(!layer.prim_index.is_built());
        assert_eq!(layer.prim_at("/R42").map(|p| p.name.as_str()), Some("R42"));
        assert!(layer.prim_index.is_built(), "a long root list gets a map on first lookup");
        let parent = layer.root_prim("Parent").expect("parent");
        for i in [0, 7, 99] {
            let child = parent.child(&format!("C{i}")).expect("child");
            assert_eq!(child.properties[0].name(), "which");
        }
        assert!(parent.child_index.is_built());
        assert!(parent.child("C100").is_none() && layer.root_prim("Nope").is_none());
        let first_c7 = parent.child("C7").expect("C7");
        assert!(std::ptr::eq(first_c7, &parent.children[7]), "the first of two same-named specs");
        // Short lists are searched directly and never pay for a map.
        let small = layer.prim_at("/R1").expect("R1");
        assert!(small.child("x").is_none() && !small.child_index.is_built());
    }

    #[test]
    fn many_properties_on_one_prim_are_merged_by_name() {
        // Statements about one property merge into one spec; finding the spec used to be a
        // search of every property so far.
        let mut text = String::from("#usda 1.0\ndef \"P\" {\n");
        for i in 0..2000 {
            text += &format!("    float a{i} = {i}\n");
        }
        text += "    float a5.connect = </P.a6>\n    rel r\n    rel r = </P>\n}\n";
        let layer = layer(&text);
        let p = &layer.prims[0];
        assert_eq!(p.properties.len(), 2001);
        let Some(PropertySpec::Attribute(a5)) = p.property("a5") else { panic!("a5") };
        assert_eq!(a5.default.as_ref().map(|(v, _)| v.clone()), Some(Value::Float(5.0)));
        assert_eq!(a5.connections.explicit.as_ref().map(Vec::len), Some(1));
        let Some(PropertySpec::Relationship(r)) = p.property("r") else { panic!("r") };
        assert!(r.authored.is_some());
    }
}
