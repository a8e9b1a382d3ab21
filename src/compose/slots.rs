//! Slot bindings and their hierarchical resolution (DESIGN.md composition rules 1–3; paper
//! section 5.2 and appendix B). This module knows nothing about USD files: it works on a
//! [`BindingTree`] that the scene adapter fills from relationships.

use super::collection::Collection;
use crate::diag::{Diagnostic, Diagnostics, Span};
use std::collections::BTreeMap;

/// The relationship namespace that carries slot bindings.
pub const SLOT_BINDING_PREFIX: &str = "material:slotBinding:";

/// The name the UsdShade `material:binding` layer shows under (`strata layers`). It is the
/// slot with an empty name ([`Slot::material_binding`]), which no authored slot can have, so
/// byte order puts it below every slot: slot bindings layer over a DCC's own materials.
pub const MATERIAL_BINDING_SLOT: &str = "material:binding";

/// A parsed slot name: `050`, the override slot `050::010`, the vertical slot `000|010`
/// (DESIGN.md rule 3b) or an override of a vertical slot, `000|010::020`.
///
/// The derived order is byte order on `base`, then the slot itself before its overrides
/// (`None` first), then its vertical slots in byte order, each followed by its overrides: the
/// order in which [`resolve_stacks`] attaches them.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Slot {
    /// The substance slot (`050`).
    pub base: String,
    /// The vertical part (`010` of `000|010`), for vertical slots and their overrides.
    pub vertical: Option<String>,
    /// The override part (`010`), for override slots.
    pub over: Option<String>,
}

impl Slot {
    /// Parses the canonical form (`050`, `050::010`, `000|010`, `000|010::020`).
    pub fn parse(name: &str) -> Result<Slot, String> {
        let mut parts = name.split("::");
        let layer = parts.next().unwrap_or_default();
        let over = parts.next().map(str::to_string);
        if parts.next().is_some() {
            return Err(format!("slot `{name}` has more than one `::`; overrides of overrides are not supported"));
        }
        let mut layer_parts = layer.split('|');
        let base = layer_parts.next().unwrap_or_default().to_string();
        let vertical = layer_parts.next().map(str::to_string);
        if layer_parts.next().is_some() {
            return Err(format!(
                "slot `{name}` has more than one `|`; a vertical slot lies on a horizontal one (`000|010`), not on another vertical slot"
            ));
        }
        if base.is_empty() || over.as_deref() == Some("") || vertical.as_deref() == Some("") {
            return Err(format!("slot `{name}` has an empty element"));
        }
        Ok(Slot { base, vertical, over })
    }

    /// The base layer that UsdShade's `material:binding` resolves to (DESIGN.md,
    /// "UsdShade material:binding").
    pub fn material_binding() -> Slot {
        Slot { base: String::new(), vertical: None, over: None }
    }

    /// Whether this is the `material:binding` base layer.
    pub fn is_material_binding(&self) -> bool {
        self.base.is_empty()
    }

    /// The slot a layer of this slot lies in: itself without its override part (`000|010`
    /// for `000|010::020`).
    pub fn layer(&self) -> Slot {
        Slot { over: None, ..self.clone() }
    }

    /// The canonical name.
    pub fn name(&self) -> String {
        if self.is_material_binding() {
            return MATERIAL_BINDING_SLOT.to_string();
        }
        let mut name = self.base.clone();
        if let Some(v) = &self.vertical {
            name += "|";
            name += v;
        }
        if let Some(o) = &self.over {
            name += "::";
            name += o;
        }
        name
    }
}

/// The element that encodes the vertical separator `|` (DESIGN.md Inputs 3); it has no
/// leading `_`.
const VERTICAL_ELEMENT: &str = "vertical";

/// The element that starts the binding name of a collection-based slot binding (rule 1c); it
/// has no leading `_`.
const COLLECTION_ELEMENT: &str = "collection";

/// Encodes a slot name as a USD property name suffix: split on `:`, prefix each element with
/// `_`, join with `:` (`050::000` → `_050:_:_000`); the vertical separator `|` is the element
/// `vertical` (`000|010` → `_000:vertical:_010`).
pub fn encode_slot(slot: &str) -> String {
    let encode = |part: &str| part.split(':').map(|e| format!("_{e}")).collect::<Vec<_>>().join(":");
    slot.split('|').map(encode).collect::<Vec<_>>().join(&format!(":{VERTICAL_ELEMENT}:"))
}

/// Decodes the suffix of a `material:slotBinding:` relationship into a slot: strips one leading
/// `_` from each `:`-separated element; the element `vertical` stands for `|`.
pub fn decode_slot(encoded: &str) -> Result<Slot, String> {
    let mut name = String::new();
    let mut after_separator = true;
    for element in encoded.split(':') {
        if element == VERTICAL_ELEMENT {
            name.push('|');
            after_separator = true;
            continue;
        }
        let Some(rest) = element.strip_prefix('_') else {
            return Err(format!(
                "slot binding element `{element}` does not start with `_` (appendix B encoding: slot `050` is `_050`)"
            ));
        };
        if !after_separator {
            name.push(':');
        }
        name += rest;
        after_separator = false;
    }
    Slot::parse(&name)
}

/// Splits the suffix of a `material:slotBinding:` relationship into the encoded slot and,
/// for a collection-based binding (`_050:collection:dirtAreas`, rule 1c), the binding name.
pub fn split_collection_binding(encoded: &str) -> (&str, Option<&str>) {
    let marker = format!(":{COLLECTION_ELEMENT}:");
    match encoded.find(&marker) {
        Some(at) => (&encoded[..at], Some(&encoded[at + marker.len()..])),
        None => (encoded, None),
    }
}

/// One authored slot binding.
#[derive(Clone, Debug)]
pub struct Binding {
    /// The slot.
    pub slot: Slot,
    /// The bound material prim path; `None` is an empty binding (removes the slot). A
    /// relationship that is only declared is no binding and never becomes one.
    pub material: Option<String>,
    /// Where it is authored.
    pub span: Span,
    /// UsdShade's `bindingStrength = "strongerThanDescendants"`: descendants cannot replace
    /// it (the outermost such binding wins). Slot bindings are always weaker.
    pub stronger: bool,
    /// A binding already resolved for this prim by UsdShade's rules (collection bindings,
    /// `compose::scene`): the prim it is authored on. It applies whatever ancestors bound.
    pub authored_at: Option<String>,
}

/// A collection-based slot binding (DESIGN.md rule 1c): `material:slotBinding:<slot>:collection:<name>
/// = [<collection>, <material>]` binds the slot on the prim that authors it and on its
/// descendants that the collection includes.
#[derive(Clone, Debug)]
pub struct CollectionSlotBinding {
    /// The slot, the material (`None`: an empty binding, which removes the slot for the
    /// members) and where it is authored.
    pub binding: Binding,
    /// The collection's path (`/Root.collection:dirty`), as `strata layers` names it.
    pub collection: String,
    /// Its membership.
    pub members: Collection,
}

/// A prim of the hierarchy, reduced to what slot resolution needs.
#[derive(Clone, Debug)]
pub struct BindingPrim {
    /// Absolute path (`/a/b`).
    pub path: String,
    /// Parent index in the tree (parents come before children).
    pub parent: Option<usize>,
    /// Bindings authored on this prim.
    pub bindings: Vec<Binding>,
    /// Collection-based slot bindings authored on this prim, in property order (for one slot,
    /// the first whose collection holds a prim binds it).
    pub collections: Vec<CollectionSlotBinding>,
    /// Whether this prim is renderable geometry (gets a composed material).
    pub renderable: bool,
}

/// The prim hierarchy as seen by slot resolution.
#[derive(Clone, Debug, Default)]
pub struct BindingTree {
    /// Prims, parents before children.
    pub prims: Vec<BindingPrim>,
}

/// A binding in effect on a prim: what is bound, and where.
#[derive(Clone, Debug, PartialEq)]
pub struct Applied {
    /// The material prim path.
    pub material: String,
    /// The prim the binding is authored on.
    pub bound_at: String,
    /// Where it is authored.
    pub span: Span,
    /// The collection that bound it (`/Root.collection:dirty`), for a collection-based binding.
    pub collection: Option<String>,
}

/// An override attached to a layer.
#[derive(Clone, Debug, PartialEq)]
pub struct OverrideBinding {
    /// The full slot (`050::010`).
    pub slot: Slot,
    /// What is bound and where.
    pub applied: Applied,
}

/// One layer of a prim's stack.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerBinding {
    /// The substance slot.
    pub slot: Slot,
    /// The substance bound there.
    pub applied: Applied,
    /// Overrides attached to the slot, ascending by override name (the last wins).
    pub overrides: Vec<OverrideBinding>,
    /// For a horizontal layer, its vertical layers (`000|010`, rule 3b) in byte order, the
    /// first lying directly on this layer's surface; always empty for a vertical layer.
    pub vertical: Vec<LayerBinding>,
}

/// The resolved slot stack of one renderable prim.
#[derive(Clone, Debug, PartialEq)]
pub struct PrimStack {
    /// The prim path.
    pub prim: String,
    /// Layers bottom to top; empty for the default substance.
    pub layers: Vec<LayerBinding>,
}

/// Slots a live view hides without editing the scene (`strata view`'s mute and solo), by
/// horizontal slot name (`050`), scene-wide: a muted slot's layer — with its overrides and
/// vertical layers — leaves every stack; a soloed slot is the only layer left on the prims
/// that have it, and prims without it keep their stacks. Composition applies it to the
/// materials only: [`PrimStack`]s stay as bound, so an inspector still shows what is muted.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SlotFilter {
    /// Slots left out.
    pub muted: std::collections::BTreeSet<String>,
    /// The one slot kept where a prim has it.
    pub solo: Option<String>,
}

impl SlotFilter {
    /// Whether nothing is hidden.
    pub fn is_empty(&self) -> bool {
        self.muted.is_empty() && self.solo.is_none()
    }

    /// The layers of `stack` that take part in its material.
    pub fn layers<'a>(&'a self, stack: &'a PrimStack) -> impl Iterator<Item = &'a LayerBinding> + 'a {
        let solo = self.solo.as_ref().filter(|s| stack.layers.iter().any(|l| &l.slot.name() == *s));
        stack.layers.iter().filter(move |l| {
            let name = l.slot.name();
            !self.muted.contains(&name) && solo.is_none_or(|s| *s == name)
        })
    }

    /// `stack` with only the layers that take part in its material.
    pub fn apply(&self, stack: &PrimStack) -> PrimStack {
        PrimStack { prim: stack.prim.clone(), layers: self.layers(stack).cloned().collect() }
    }
}

/// A slot in effect on a prim: the depth of the prim whose binding put it there (rule 1c
/// compares depths), and what it binds (`None`: removed).
type Effective = (usize, Option<Applied>);

/// Resolves every renderable prim's slot stack: inheritance, replacement, removal,
/// collection-based bindings, byte-order sorting, and the attachment of overrides and vertical
/// slots. Overrides and vertical slots of a slot with no substance are warned about.
pub fn resolve_stacks(tree: &BindingTree, diags: &mut Diagnostics) -> Vec<PrimStack> {
    // The direct bindings in effect at each prim, built incrementally from the parent's.
    let mut effective: Vec<BTreeMap<Slot, Effective>> = Vec::with_capacity(tree.prims.len());
    // Each prim's depth (a root is 0).
    let mut depth: Vec<usize> = Vec::with_capacity(tree.prims.len());
    // The slots an ancestor bound with `strongerThanDescendants`, which no deeper binding
    // replaces.
    let mut locked: Vec<Vec<Slot>> = Vec::with_capacity(tree.prims.len());
    let mut stacks = Vec::new();
    for prim in &tree.prims {
        let (mut slots, mut strong, here) = match prim.parent {
            Some(p) => (effective[p].clone(), locked[p].clone(), depth[p] + 1),
            None => (BTreeMap::new(), Vec::new(), 0),
        };
        for binding in &prim.bindings {
            if strong.contains(&binding.slot) && binding.authored_at.is_none() {
                continue;
            }
            if binding.stronger {
                strong.push(binding.slot.clone());
            }
            // A deeper binding replaces; an empty one removes (kept as `None` so that the
            // removal itself is inherited until a deeper prim binds the slot again).
            let applied = binding.material.as_ref().map(|m| Applied {
                material: m.clone(),
                bound_at: binding.authored_at.clone().unwrap_or_else(|| prim.path.clone()),
                span: binding.span,
                collection: None,
            });
            slots.insert(binding.slot.clone(), (here, applied));
        }
        if prim.renderable {
            let mut with_collections = slots.clone();
            apply_collections(tree, prim, here, &mut with_collections);
            stacks.push(stack_of(&prim.path, &with_collections, diags));
        }
        effective.push(slots);
        depth.push(here);
        locked.push(strong);
    }
    stacks
}

/// Applies the collection-based slot bindings that reach `prim` (at `depth`) from it and its
/// ancestors (rule 1c): per slot, the deepest level whose collection holds the prim offers
/// (its first such binding in property order), and it replaces the direct binding in effect
/// unless that one is authored deeper; at one level the collection binding is stronger.
fn apply_collections(tree: &BindingTree, prim: &BindingPrim, depth: usize, slots: &mut BTreeMap<Slot, Effective>) {
    let mut offered: Vec<&Slot> = Vec::new();
    let mut level = Some(prim);
    let mut level_depth = depth;
    while let Some(at) = level {
        for c in &at.collections {
            let slot = &c.binding.slot;
            if offered.contains(&slot) || !c.members.contains(&prim.path) {
                continue;
            }
            offered.push(slot);
            if slots.get(slot).is_some_and(|(direct_depth, _)| *direct_depth > level_depth) {
                continue;
            }
            let applied = c.binding.material.as_ref().map(|m| Applied {
                material: m.clone(),
                bound_at: at.path.clone(),
                span: c.binding.span,
                collection: Some(c.collection.clone()),
            });
            slots.insert(slot.clone(), (level_depth, applied));
        }
        level = at.parent.map(|p| &tree.prims[p]);
        level_depth = level_depth.saturating_sub(1);
    }
}

fn stack_of(prim: &str, slots: &BTreeMap<Slot, Effective>, diags: &mut Diagnostics) -> PrimStack {
    // BTreeMap order on (base, vertical, over) is byte order on the base name; the substance
    // slot itself (`None`) comes first, then its overrides in ascending byte order, then each
    // vertical slot in byte order followed by its own overrides.
    let mut layers: Vec<LayerBinding> = Vec::new();
    for (slot, (_, applied)) in slots {
        let Some(applied) = applied else { continue };
        let layer = layers.last_mut().filter(|l| l.slot.base == slot.base);
        match (&slot.vertical, &slot.over) {
            (None, None) => layers.push(LayerBinding {
                slot: slot.clone(),
                applied: applied.clone(),
                overrides: Vec::new(),
                vertical: Vec::new(),
            }),
            (None, Some(_)) => match layer {
                Some(layer) => layer.overrides.push(OverrideBinding { slot: slot.clone(), applied: applied.clone() }),
                None => ignored(diags, prim, slot, "override", &slot.base, applied),
            },
            (Some(_), None) => match layer {
                Some(layer) => layer.vertical.push(LayerBinding {
                    slot: slot.clone(),
                    applied: applied.clone(),
                    overrides: Vec::new(),
                    vertical: Vec::new(),
                }),
                None => ignored(diags, prim, slot, "vertical", &slot.base, applied),
            },
            (Some(_), Some(_)) => {
                let vertical = layer.and_then(|l| l.vertical.last_mut()).filter(|v| v.slot == slot.layer());
                match vertical {
                    Some(v) => v.overrides.push(OverrideBinding { slot: slot.clone(), applied: applied.clone() }),
                    None => ignored(diags, prim, slot, "override", &slot.layer().name(), applied),
                }
            }
        }
    }
    PrimStack { prim: prim.to_string(), layers }
}

/// Warns that an override or vertical slot is ignored on `prim` because `base` has no
/// substance there.
fn ignored(diags: &mut Diagnostics, prim: &str, slot: &Slot, kind: &str, base: &str, applied: &Applied) {
    diags.push(
        Diagnostic::warning(format!(
            "{kind} slot `{}` on `{prim}` is ignored: slot `{base}` has no substance there",
            slot.name()
        ))
        .at(applied.span, "bound here"),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (path, parent, bindings as (slot, material), renderable)
    type PrimSpec<'a> = (&'a str, Option<usize>, &'a [(&'a str, Option<&'a str>)], bool);

    fn tree(prims: &[PrimSpec]) -> BindingTree {
        BindingTree {
            prims: prims
                .iter()
                .map(|(path, parent, bindings, renderable)| BindingPrim {
                    path: path.to_string(),
                    parent: *parent,
                    bindings: bindings
                        .iter()
                        .map(|(slot, material)| {
                            // `!` marks a strongerThanDescendants binding; `material:binding`
                            // names the base layer.
                            let (slot, stronger) = match slot.strip_suffix('!') {
                                Some(s) => (s, true),
                                None => (*slot, false),
                            };
                            Binding {
                                slot: if slot == MATERIAL_BINDING_SLOT {
                                    Slot::material_binding()
                                } else {
                                    Slot::parse(slot).unwrap()
                                },
                                material: material.map(str::to_string),
                                span: Span::default(),
                                stronger,
                                authored_at: None,
                            }
                        })
                        .collect(),
                    collections: Vec::new(),
                    renderable: *renderable,
                })
                .collect(),
        }
    }

    fn summary(stacks: &[PrimStack]) -> Vec<String> {
        stacks
            .iter()
            .map(|s| {
                let layers: Vec<String> = s
                    .layers
                    .iter()
                    .map(|l| {
                        let mut t = format!("{}={}@{}", l.slot.name(), l.applied.material, l.applied.bound_at);
                        for o in &l.overrides {
                            t += &format!("[{}={}@{}]", o.slot.name(), o.applied.material, o.applied.bound_at);
                        }
                        t
                    })
                    .collect();
                format!("{}: {}", s.prim, layers.join(" "))
            })
            .collect()
    }

    fn resolve(t: &BindingTree) -> (Vec<String>, Diagnostics) {
        let mut diags = Diagnostics::new();
        let stacks = resolve_stacks(t, &mut diags);
        (summary(&stacks), diags)
    }

    #[test]
    fn encoding_round_trips() {
        assert_eq!(encode_slot("000"), "_000");
        assert_eq!(encode_slot("050::000"), "_050:_:_000");
        assert_eq!(decode_slot("_050:_:_000").unwrap(), Slot::parse("050::000").unwrap());
        assert_eq!(decode_slot("_000").unwrap().name(), "000");
        assert_eq!(decode_slot("__x").unwrap().name(), "_x", "only one underscore is stripped");
        for slot in ["000", "050::010", "dirt", "a:b"] {
            assert_eq!(decode_slot(&encode_slot(slot)).unwrap().name(), slot);
        }
        assert!(decode_slot("050").is_err());
        assert!(decode_slot("_a:_:_b:_:_c").is_err());
        assert!(decode_slot("_a:_:_").is_err());
    }

    #[test]
    fn inheritance_and_new_layers() {
        let t = tree(&[("/a", None, &[("000", Some("/A"))], false), ("/a/b", Some(0), &[("010", Some("/B"))], true)]);
        assert_eq!(resolve(&t).0, vec!["/a/b: 000=/A@/a 010=/B@/a/b"]);
    }

    #[test]
    fn deeper_binding_replaces() {
        let t = tree(&[("/a", None, &[("000", Some("/A"))], false), ("/a/b", Some(0), &[("000", Some("/C"))], true)]);
        assert_eq!(resolve(&t).0, vec!["/a/b: 000=/C@/a/b"]);
    }

    #[test]
    fn empty_binding_removes_until_rebound() {
        let t = tree(&[
            ("/a", None, &[("000", Some("/A")), ("050", Some("/D"))], false),
            ("/a/b", Some(0), &[("050", None)], true),
            ("/a/b/c", Some(1), &[], true),
            ("/a/b/d", Some(1), &[("050", Some("/E"))], true),
        ]);
        assert_eq!(resolve(&t).0, vec!["/a/b: 000=/A@/a", "/a/b/c: 000=/A@/a", "/a/b/d: 000=/A@/a 050=/E@/a/b/d"]);
    }

    #[test]
    fn byte_order_sort() {
        let t = tree(&[(
            "/a",
            None,
            &[("b", Some("/B")), ("B", Some("/U")), ("10", Some("/T")), ("010", Some("/Z"))],
            true,
        )]);
        assert_eq!(resolve(&t).0, vec!["/a: 010=/Z@/a 10=/T@/a B=/U@/a b=/B@/a"]);
    }

    #[test]
    fn utf8_slots_decode_and_sort_byte_by_byte() {
        assert_eq!(decode_slot("_é:_:_ü").unwrap(), Slot { base: "é".into(), vertical: None, over: Some("ü".into()) });
        assert_eq!(encode_slot("é::ü"), "_é:_:_ü");
        // U+FF21 (EF BC A1) before U+10400 (F0 90 90 80): UTF-8 byte order is code point
        // order, where UTF-16 order would swap them.
        let t = tree(&[(
            "/a",
            None,
            &[("\u{10400}", Some("/D")), ("\u{FF21}", Some("/W")), ("é", Some("/E")), ("z", Some("/Z"))],
            true,
        )]);
        assert_eq!(resolve(&t).0, vec!["/a: z=/Z@/a é=/E@/a \u{FF21}=/W@/a \u{10400}=/D@/a"]);
    }

    #[test]
    fn overrides_attach_sorted_and_replace_and_remove() {
        let t = tree(&[
            ("/a", None, &[("050", Some("/Dirt")), ("050::020", Some("/O2")), ("050::010", Some("/O1"))], false),
            ("/a/b", Some(0), &[("050::020", Some("/O3"))], true),
            ("/a/c", Some(0), &[("050::010", None)], true),
        ]);
        assert_eq!(
            resolve(&t).0,
            vec!["/a/b: 050=/Dirt@/a[050::010=/O1@/a][050::020=/O3@/a/b]", "/a/c: 050=/Dirt@/a[050::020=/O2@/a]"]
        );
    }

    #[test]
    fn orphan_overrides_warn() {
        let t = tree(&[("/a", None, &[("000", Some("/A")), ("050::010", Some("/O"))], true)]);
        let (stacks, diags) = resolve(&t);
        assert_eq!(stacks, vec!["/a: 000=/A@/a"]);
        assert_eq!(diags.items().len(), 1);
        assert!(!diags.has_errors());
        assert!(diags.items()[0].message.contains("050::010"));
    }

    #[test]
    fn no_bindings_means_default_substance() {
        let t = tree(&[("/a", None, &[], true)]);
        assert_eq!(resolve(&t).0, vec!["/a: "]);
    }

    #[test]
    fn no_layer_limit() {
        let slots: Vec<String> = (0..64).map(|i| format!("{i:03}")).collect();
        let bindings: Vec<(&str, Option<&str>)> = slots.iter().map(|s| (s.as_str(), Some("/M"))).rev().collect();
        let t = tree(&[("/a", None, &bindings, true)]);
        let mut diags = Diagnostics::new();
        let stacks = resolve_stacks(&t, &mut diags);
        assert_eq!(stacks[0].layers.len(), 64);
        assert!(stacks[0].layers.windows(2).all(|w| w[0].slot.base < w[1].slot.base));
    }

    #[test]
    fn material_binding_is_the_bottom_layer_and_strength_locks_it() {
        let t = tree(&[
            ("/Root", None, &[("material:binding", Some("/M/Dcc")), ("000", Some("/M/Dirt"))], false),
            // The mesh's own binding replaces the inherited one, and still sorts below `000`.
            ("/Root/Mesh", Some(0), &[("material:binding", Some("/M/Own"))], true),
            ("/Strong", None, &[("material:binding!", Some("/M/Strong"))], false),
            // An ancestor's strongerThanDescendants binding beats the descendant's own.
            ("/Strong/Mesh", Some(2), &[("material:binding", Some("/M/Weak")), ("010", Some("/M/A"))], true),
            ("/Strong/Mesh/Sub", Some(3), &[("material:binding!", Some("/M/Sub"))], true),
        ]);
        let (lines, diags) = resolve(&t);
        assert_eq!(diags.error_count(), 0);
        assert_eq!(
            lines,
            vec![
                "/Root/Mesh: material:binding=/M/Own@/Root/Mesh 000=/M/Dirt@/Root",
                "/Strong/Mesh: material:binding=/M/Strong@/Strong 010=/M/A@/Strong/Mesh",
                // The outermost strong binding wins over a deeper strong one too.
                "/Strong/Mesh/Sub: material:binding=/M/Strong@/Strong 010=/M/A@/Strong/Mesh",
            ]
        );
    }
}
