//! Slot bindings and their hierarchical resolution (DESIGN.md composition rules 1–3; paper
//! section 5.2 and appendix B). This module knows nothing about USD files: it works on a
//! [`BindingTree`] that the scene adapter fills from relationships.

use crate::diag::{Diagnostic, Diagnostics, Span};
use std::collections::BTreeMap;

/// The relationship namespace that carries slot bindings.
pub const SLOT_BINDING_PREFIX: &str = "material:slotBinding:";

/// The name the UsdShade `material:binding` layer shows under (`strata layers`). It is the
/// slot with an empty name ([`Slot::material_binding`]), which no authored slot can have, so
/// byte order puts it below every slot: slot bindings layer over a DCC's own materials.
pub const MATERIAL_BINDING_SLOT: &str = "material:binding";

/// A parsed slot name: `050` or the override slot `050::010`.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Slot {
    /// The substance slot (`050`).
    pub base: String,
    /// The override part (`010`), for override slots.
    pub over: Option<String>,
}

impl Slot {
    /// Parses the canonical form (`050`, `050::010`).
    pub fn parse(name: &str) -> Result<Slot, String> {
        let mut parts = name.split("::");
        let base = parts.next().unwrap_or_default().to_string();
        let over = parts.next().map(str::to_string);
        if parts.next().is_some() {
            return Err(format!("slot `{name}` has more than one `::`; overrides of overrides are not supported"));
        }
        if base.is_empty() || over.as_deref() == Some("") {
            return Err(format!("slot `{name}` has an empty element"));
        }
        Ok(Slot { base, over })
    }

    /// The base layer that UsdShade's `material:binding` resolves to (DESIGN.md,
    /// "UsdShade material:binding").
    pub fn material_binding() -> Slot {
        Slot { base: String::new(), over: None }
    }

    /// Whether this is the `material:binding` base layer.
    pub fn is_material_binding(&self) -> bool {
        self.base.is_empty()
    }

    /// The canonical name.
    pub fn name(&self) -> String {
        if self.is_material_binding() {
            return MATERIAL_BINDING_SLOT.to_string();
        }
        match &self.over {
            Some(o) => format!("{}::{o}", self.base),
            None => self.base.clone(),
        }
    }
}

/// Encodes a slot name as a USD property name suffix: split on `:`, prefix each element with
/// `_`, join with `:` (`050::000` → `_050:_:_000`).
pub fn encode_slot(slot: &str) -> String {
    slot.split(':').map(|e| format!("_{e}")).collect::<Vec<_>>().join(":")
}

/// Decodes the suffix of a `material:slotBinding:` relationship into a slot: strips one leading
/// `_` from each `:`-separated element.
pub fn decode_slot(encoded: &str) -> Result<Slot, String> {
    let mut elements = Vec::new();
    for element in encoded.split(':') {
        match element.strip_prefix('_') {
            Some(rest) => elements.push(rest),
            None => {
                return Err(format!(
                    "slot binding element `{element}` does not start with `_` (appendix B encoding: slot `050` is `_050`)"
                ));
            }
        }
    }
    Slot::parse(&elements.join(":"))
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

/// A prim of the hierarchy, reduced to what slot resolution needs.
#[derive(Clone, Debug)]
pub struct BindingPrim {
    /// Absolute path (`/a/b`).
    pub path: String,
    /// Parent index in the tree (parents come before children).
    pub parent: Option<usize>,
    /// Bindings authored on this prim.
    pub bindings: Vec<Binding>,
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
}

/// The resolved slot stack of one renderable prim.
#[derive(Clone, Debug, PartialEq)]
pub struct PrimStack {
    /// The prim path.
    pub prim: String,
    /// Layers bottom to top; empty for the default substance.
    pub layers: Vec<LayerBinding>,
}

/// Resolves every renderable prim's slot stack: inheritance, replacement, removal, byte-order
/// sorting and override attachment. Overrides of a slot with no substance are warned about.
pub fn resolve_stacks(tree: &BindingTree, diags: &mut Diagnostics) -> Vec<PrimStack> {
    // The slots in effect at each prim, built incrementally from the parent's.
    let mut effective: Vec<BTreeMap<Slot, Option<Applied>>> = Vec::with_capacity(tree.prims.len());
    // The slots an ancestor bound with `strongerThanDescendants`, which no deeper binding
    // replaces.
    let mut locked: Vec<Vec<Slot>> = Vec::with_capacity(tree.prims.len());
    let mut stacks = Vec::new();
    for prim in &tree.prims {
        let (mut slots, mut strong) = match prim.parent {
            Some(p) => (effective[p].clone(), locked[p].clone()),
            None => (BTreeMap::new(), Vec::new()),
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
            });
            slots.insert(binding.slot.clone(), applied);
        }
        if prim.renderable {
            stacks.push(stack_of(&prim.path, &slots, diags));
        }
        effective.push(slots);
        locked.push(strong);
    }
    stacks
}

fn stack_of(prim: &str, slots: &BTreeMap<Slot, Option<Applied>>, diags: &mut Diagnostics) -> PrimStack {
    // BTreeMap order on (base, over) is byte order on the base name, and `None` (the substance
    // slot itself) sorts before its overrides, which come in ascending byte order.
    let mut layers: Vec<LayerBinding> = Vec::new();
    for (slot, applied) in slots {
        let Some(applied) = applied else { continue };
        match &slot.over {
            None => layers.push(LayerBinding { slot: slot.clone(), applied: applied.clone(), overrides: Vec::new() }),
            Some(_) => match layers.last_mut().filter(|l| l.slot.base == slot.base) {
                Some(layer) => layer.overrides.push(OverrideBinding { slot: slot.clone(), applied: applied.clone() }),
                None => diags.push(
                    Diagnostic::warning(format!(
                        "override slot `{}` on `{prim}` is ignored: slot `{}` has no substance there",
                        slot.name(),
                        slot.base
                    ))
                    .at(applied.span, "bound here"),
                ),
            },
        }
    }
    PrimStack { prim: prim.to_string(), layers }
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
        assert_eq!(decode_slot("_é:_:_ü").unwrap(), Slot { base: "é".into(), over: Some("ü".into()) });
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
