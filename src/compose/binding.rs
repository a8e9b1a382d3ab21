//! Which prims render and what binds them: UsdShade's `material:binding` (direct and
//! collection-based, with `bindMaterialAs` strength) and strata's slot bindings, read into a
//! [`BindingTree`].

use super::collection::Collection;
use super::slots::{
    Binding, BindingPrim, BindingTree, CollectionSlotBinding, SLOT_BINDING_PREFIX, Slot, decode_slot,
    split_collection_binding,
};
use crate::diag::{Diagnostic, Diagnostics, OncePerKind, Span};
use crate::scene::{Prim, PrimId, Stage, Value as UsdValue};
use std::collections::HashMap;

/// Prim types that are rendered, and so get a composed material.
pub const RENDERABLE_TYPES: &[&str] = &["Mesh", "Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane", "Points"];

/// Whether a prim is renderable geometry.
pub fn is_renderable(prim: &Prim) -> bool {
    prim.type_name.as_deref().is_some_and(|t| RENDERABLE_TYPES.contains(&t))
}

/// Whether a prim is a `UsdGeomSubset` that binds a material to some faces of its parent Mesh
/// (`familyName = "materialBind"`, `elementType = "face"`): it gets its own composed material,
/// layered like a child of the mesh, and the renderer shades those faces with it.
pub fn is_bound_subset(stage: &Stage, prim: &Prim) -> bool {
    prim.type_name.as_deref() == Some("GeomSubset")
        && prim.value("familyName").and_then(UsdValue::as_str) == Some("materialBind")
        && prim.value("elementType").and_then(UsdValue::as_str).unwrap_or("face") == "face"
        && prim.parent.is_some_and(|p| stage.prim(p).type_name.as_deref() == Some("Mesh"))
}

/// The `material:binding` relationships strata reads, strongest purpose first: `full` (the
/// final-render purpose), then the all-purpose binding, then `preview`.
const MATERIAL_BINDING_RELS: [&str; 3] = ["material:binding:full", "material:binding", "material:binding:preview"];

/// The UsdShade direct binding of a prim, as a binding of the base layer
/// ([`Slot::material_binding`]). A relationship with no target binds nothing (UsdShade's
/// `IsBound()` is false, so the ancestors' binding applies); more than one target is an error.
fn material_binding(prim: &Prim, diags: &mut Diagnostics) -> Option<Binding> {
    for name in MATERIAL_BINDING_RELS {
        let Some(rel) = prim.relationship(name) else { continue };
        let (path, span) = match rel.targets.as_slice() {
            [] => continue,
            [(path, span)] => (path.clone(), *span),
            targets => {
                let mut d = Diagnostic::error(format!(
                    "`{name}` on `{}` has {} targets; a direct binding names one material",
                    prim.path,
                    targets.len()
                ))
                .at(rel.span, "one material");
                for (_, span) in targets {
                    d = d.also(*span, "target");
                }
                diags.push(d);
                return None;
            }
        };
        let stronger = binding_strength(prim, rel, diags);
        return Some(Binding {
            slot: Slot::material_binding(),
            material: Some(path),
            span,
            stronger,
            authored_at: None,
        });
    }
    None
}

/// The strength a binding relationship's `bindMaterialAs` metadata gives it: whether it is
/// `strongerThanDescendants`.
fn binding_strength(prim: &Prim, rel: &crate::scene::Relationship, diags: &mut Diagnostics) -> bool {
    match rel.metadata.iter().find(|m| m.key == "bindMaterialAs").map(|m| (m.value.as_str(), m.span)) {
        None => false,
        Some((Some("strongerThanDescendants"), _)) => true,
        Some((Some("weakerThanDescendants" | "fallbackStrength"), _)) => false,
        Some((_, span)) => {
            diags.push(
                Diagnostic::warning(format!(
                    "`bindMaterialAs` on `{}.{}` must be \"strongerThanDescendants\" or \"weakerThanDescendants\"; read as weaker",
                    prim.path, rel.name
                ))
                .at(span, "this value"),
            );
            false
        }
    }
}

/// A collection-based binding: `material:binding:collection:NAME = [<collection>, <material>]`.
struct CollectionBinding {
    collection: Collection,
    /// `None` when the material prim does not exist.
    material: Option<String>,
    span: Span,
    stronger: bool,
}

/// The collection-based bindings authored on a prim, in property order (the first whose
/// collection holds a prim binds it). Only the all-purpose form is read; bindings with a
/// purpose, or whose collection is missing, warn.
fn collection_bindings(
    stage: &Stage,
    prim: &Prim,
    missing: &mut OncePerKind,
    diags: &mut Diagnostics,
) -> Vec<CollectionBinding> {
    let mut out = Vec::new();
    for rel in prim.relationships_with_prefix("material:binding:") {
        let rest = &rel.name["material:binding:".len()..];
        let binding_name = match rest.strip_prefix("collection:") {
            Some(name) => name,
            None if rest.contains("collection:") => "", // a purpose: `full:collection:NAME`
            None => continue,
        };
        if rel.targets.is_empty() {
            continue;
        }
        if binding_name.is_empty() || binding_name.contains(':') {
            diags.push(
                Diagnostic::warning(format!(
                    "collection-based binding `{}` on `{}` has a purpose or a namespaced name; strata reads only `material:binding:collection:NAME`",
                    rel.name, prim.path
                ))
                .at(rel.span, "ignored"),
            );
            continue;
        }
        let [(collection_path, _), (material, span)] = rel.targets.as_slice() else {
            diags.push(
                Diagnostic::error(format!(
                    "`{}` on `{}` must target a collection and a material, in that order",
                    rel.name, prim.path
                ))
                .at(rel.span, format!("{} target(s)", rel.targets.len())),
            );
            continue;
        };
        let owner_and_name = collection_path.split_once(".collection:");
        let owner = owner_and_name.and_then(|(owner, _)| stage.find(owner)).map(|id| stage.prim(id));
        let (Some(owner), Some((_, name))) = (owner, owner_and_name) else {
            diags.push(
                Diagnostic::warning(format!(
                    "`{}` on `{}`: collection `{collection_path}` does not exist; the binding is ignored",
                    rel.name, prim.path
                ))
                .at(rel.span, "this binding"),
            );
            continue;
        };
        let collection = Collection::read(stage, owner, name, diags);
        if stage.find(material).is_none() {
            missing.push(
                "missing material binding target",
                material,
                Diagnostic::warning(format!(
                    "`{}` on `{}` binds `{material}`, which does not exist: its members render as if unbound",
                    rel.name, prim.path
                ))
                .at(*span, "no such prim"),
            );
        }
        if let Some(nested) = collection.nested() {
            diags.push(
                Diagnostic::warning(format!(
                    "collection `{collection_path}` names the collection `{nested}`; strata does not expand nested collections"
                ))
                .at(rel.span, "bound here")
                .note("list the prims in `includes` instead"),
            );
        }
        out.push(CollectionBinding {
            collection,
            // A binding to nothing still wins over weaker ones, and binds nothing (UsdShade).
            material: stage.find(material).map(|_| material.clone()),
            span: *span,
            stronger: binding_strength(prim, rel, diags),
        });
    }
    out
}

/// The `material:binding` of renderable prim `at` (a tree index) when collection bindings
/// take part, by UsdShade's `ComputeBoundMaterial`: from the prim up to the root, each level
/// offers its first collection binding that holds the prim, else its direct binding; the
/// closest level's offer wins unless a farther one is `strongerThanDescendants` (the
/// farthest such wins). The result carries the prim it is authored on.
fn resolve_with_collections(
    tree: &BindingTree,
    direct: &[Option<Binding>],
    collections: &[Vec<CollectionBinding>],
    at: usize,
    path: &str,
) -> Option<Binding> {
    let mut winner: Option<Binding> = None;
    let mut level = Some(at);
    while let Some(l) = level {
        let offer = collections[l]
            .iter()
            .find(|c| c.collection.contains(path))
            .map(|c| Binding {
                slot: Slot::material_binding(),
                material: c.material.clone(),
                span: c.span,
                stronger: c.stronger,
                authored_at: None,
            })
            .or_else(|| direct[l].clone());
        if let Some(mut offer) = offer
            && (winner.is_none() || offer.stronger)
        {
            offer.authored_at = Some(tree.prims[l].path.clone());
            winner = Some(offer);
        }
        level = tree.prims[l].parent;
    }
    winner
}

/// A slot binding's target, when it exists; a missing one binds nothing (as UsdShade resolves
/// a binding to a missing prim), reported once per kind.
fn existing_target(
    stage: &Stage,
    prim: &Prim,
    rel: &crate::scene::Relationship,
    path: &str,
    span: Span,
    missing: &mut OncePerKind,
) -> Option<String> {
    if stage.find(path).is_some() {
        return Some(path.to_string());
    }
    missing.push(
        "missing slot binding target",
        path,
        Diagnostic::warning(format!(
            "slot binding `{}` on `{}` targets `{path}`, which does not exist: the slot is not bound",
            rel.name, prim.path
        ))
        .at(span, "no such prim"),
    );
    None
}

/// A collection-based slot binding (DESIGN.md rule 1c): `material:slotBinding:<slot>:collection:NAME
/// = [<collection>, <material>]`. The empty form names only the collection, `= [<collection>]`,
/// and removes the slot for its members; a list with no collection (`= None`) says nothing
/// about whom to remove it from, so it is reported and ignored.
#[allow(clippy::too_many_arguments)]
fn collection_slot_binding(
    stage: &Stage,
    prim: &Prim,
    rel: &crate::scene::Relationship,
    slot: Slot,
    name: &str,
    authored: Span,
    missing: &mut OncePerKind,
    diags: &mut Diagnostics,
) -> Option<CollectionSlotBinding> {
    let ((collection_path, collection_span), material) = match rel.targets.as_slice() {
        [] => {
            diags.push(
                Diagnostic::warning(format!(
                    "collection slot binding `{}` on `{}` names no collection; it is ignored",
                    rel.name, prim.path
                ))
                .at(authored, "empty")
                .note("to remove the slot for a collection's members, target only the collection: `= [<collection>]`"),
            );
            return None;
        }
        [collection] => (collection, None),
        [collection, (material, span)] => (collection, Some((material, *span))),
        targets => {
            diags.push(
                Diagnostic::error(format!(
                    "collection slot binding `{}` on `{}` must target a collection and a material, in that order (or only the collection, to remove the slot for its members)",
                    rel.name, prim.path
                ))
                .at(authored, format!("{} target(s)", targets.len())),
            );
            return None;
        }
    };
    if name.is_empty() {
        diags.push(
            Diagnostic::error(format!("collection slot binding `{}` on `{}` has no binding name", rel.name, prim.path))
                .at(rel.span, "expected `...:collection:NAME`"),
        );
        return None;
    }
    let found = collection_path.split_once(".collection:").and_then(|(owner, name)| {
        let owner = stage.prim(stage.find(owner)?);
        Collection::exists(owner, name).then_some((owner, name))
    });
    let Some((owner, collection_name)) = found else {
        diags.push(
            Diagnostic::warning(format!(
                "`{}` on `{}`: collection `{collection_path}` does not exist; the binding is ignored",
                rel.name, prim.path
            ))
            .at(*collection_span, "no such collection"),
        );
        return None;
    };
    let members = Collection::read(stage, owner, collection_name, diags);
    if let Some(nested) = members.nested() {
        diags.push(
            Diagnostic::warning(format!(
                "collection `{collection_path}` names the collection `{nested}`; strata does not expand nested collections"
            ))
            .at(*collection_span, "bound here")
            .note("list the prims in `includes` instead"),
        );
    }
    let (material, span) = match material {
        Some((path, span)) => (existing_target(stage, prim, rel, path, span, missing), span),
        None => (None, authored),
    };
    Some(CollectionSlotBinding {
        binding: Binding { slot, material, span, stronger: false, authored_at: None },
        collection: collection_path.clone(),
        members,
    })
}

/// Reads the slot bindings of every prim (depth first, parents before children), with
/// UsdShade's `material:binding` as the base layer below every slot.
pub fn binding_tree(stage: &Stage, diags: &mut Diagnostics) -> BindingTree {
    let mut tree = BindingTree::default();
    let mut index: HashMap<PrimId, usize> = HashMap::new();
    // Per tree index: the direct `material:binding`, the collection bindings, and whether any
    // prim from the root to it has collection bindings.
    let mut direct: Vec<Option<Binding>> = Vec::new();
    let mut collections: Vec<Vec<CollectionBinding>> = Vec::new();
    let mut under_collections: Vec<bool> = Vec::new();
    // Bindings to prims that do not exist: UsdShade resolves them to no material, so the
    // binding is empty (the prim renders as if unbound); one warning per kind.
    let mut missing = OncePerKind::new();
    for (id, prim) in stage.depth_first() {
        let mut bindings = Vec::new();
        let mut slot_collections = Vec::new();
        for rel in prim.relationships_with_prefix(SLOT_BINDING_PREFIX) {
            // Declared only (`rel material:slotBinding:_050`, no target opinion in any layer):
            // no binding at all, as in USD. An authored empty list is an empty binding.
            let Some(authored) = rel.authored else { continue };
            let (encoded, collection_name) = split_collection_binding(&rel.name[SLOT_BINDING_PREFIX.len()..]);
            let slot = match decode_slot(encoded) {
                Ok(slot) => slot,
                Err(message) => {
                    diags.push(
                        Diagnostic::error(format!("malformed slot binding `{}`: {message}", rel.name))
                            .at(rel.span, "here"),
                    );
                    continue;
                }
            };
            if let Some(name) = collection_name {
                slot_collections.extend(collection_slot_binding(
                    stage,
                    prim,
                    rel,
                    slot,
                    name,
                    authored,
                    &mut missing,
                    diags,
                ));
                continue;
            }
            let (material, span) = match rel.targets.as_slice() {
                [] => (None, authored),
                [(path, span)] => (existing_target(stage, prim, rel, path, *span, &mut missing), *span),
                targets => {
                    let mut d = Diagnostic::error(format!(
                        "slot binding `{}` has {} targets; a slot binds one material",
                        rel.name,
                        targets.len()
                    ))
                    .at(authored, "one material per slot");
                    for (_, span) in targets {
                        d = d.also(*span, "target");
                    }
                    diags.push(d);
                    continue;
                }
            };
            bindings.push(Binding { slot, material, span, stronger: false, authored_at: None });
        }
        let parent = prim.parent.and_then(|p| index.get(&p).copied());
        let here = tree.prims.len();
        index.insert(id, here);
        let renderable = is_renderable(prim) || is_bound_subset(stage, prim);
        let mut own = material_binding(prim, diags);
        if let Some(binding) = &mut own
            && let Some(path) = binding.material.as_deref()
            && stage.find(path).is_none()
        {
            missing.push(
                "missing material binding target",
                path,
                Diagnostic::warning(format!(
                    "`material:binding` on `{}` targets `{path}`, which does not exist: the prim renders as if unbound",
                    prim.path
                ))
                .at(binding.span, "no such prim"),
            );
            binding.material = None;
        }
        collections.push(collection_bindings(stage, prim, &mut missing, diags));
        under_collections.push(!collections[here].is_empty() || parent.is_some_and(|p| under_collections[p]));
        direct.push(own.clone());
        let resolve = renderable && under_collections[here];
        if !resolve {
            bindings.extend(own);
        }
        tree.prims.push(BindingPrim {
            path: prim.path.clone(),
            parent,
            bindings,
            collections: slot_collections,
            renderable,
        });
        if resolve {
            // Collections take part: this prim's binding is resolved whole, by UsdShade's
            // rules (it may differ from what inheriting direct bindings gives).
            // No binding at all must hide what a renderable ancestor (a mesh above a subset,
            // a collection member above a non-member) resolved for itself.
            let resolved =
                resolve_with_collections(&tree, &direct, &collections, here, &prim.path).unwrap_or(Binding {
                    slot: Slot::material_binding(),
                    material: None,
                    span: prim.span,
                    stronger: false,
                    authored_at: Some(prim.path.clone()),
                });
            tree.prims[here].bindings.push(resolved);
        }
    }
    missing.report(diags);
    tree
}
