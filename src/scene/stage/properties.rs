//! Property composition: attributes (values, time samples, metadata) and relationships
//! (target list ops) from a prim's opinions in strength order; and its variant selections.

use super::prim_index::{Node, map_path};
use super::{Attribute, Relationship};
use crate::scene::time;
use crate::scene::usda::{self, LayerOffset, ListOp, MetadataEntry, PrimSpec, PropertySpec, Target};
use std::collections::HashMap;

/// Composes properties from opinions in strength order.
pub(super) fn compose_properties(opinions: &[(&PrimSpec, &Node)]) -> (Vec<Attribute>, Vec<Relationship>) {
    // Group each property's opinions, strongest first, in first-seen order.
    let mut order: Vec<&str> = Vec::new();
    let mut groups: HashMap<&str, Vec<(&PropertySpec, &Node)>> = HashMap::new();
    for (spec, node) in opinions {
        for property in &spec.properties {
            let name = property.name();
            let group = groups.entry(name).or_insert_with(|| {
                order.push(name);
                Vec::new()
            });
            group.push((property, *node));
        }
    }
    let mut attributes = Vec::new();
    let mut relationships = Vec::new();
    for name in order {
        let Some(group) = groups.get(name) else {
            continue;
        };
        match group.first() {
            Some((PropertySpec::Attribute(_), _)) => {
                let specs: Vec<_> = group
                    .iter()
                    .filter_map(|(p, n)| match p {
                        PropertySpec::Attribute(a) => Some((&**a, *n)),
                        PropertySpec::Relationship(_) => None,
                    })
                    .collect();
                attributes.push(compose_attribute(&specs));
            }
            Some((PropertySpec::Relationship(_), _)) => {
                let specs: Vec<_> = group
                    .iter()
                    .filter_map(|(p, n)| match p {
                        PropertySpec::Relationship(r) => Some((&**r, *n)),
                        PropertySpec::Attribute(_) => None,
                    })
                    .collect();
                relationships.push(compose_relationship(&specs));
            }
            None => {}
        }
    }
    (attributes, relationships)
}

/// Targets of one opinion mapped into the stage's namespace.
pub(super) fn mapped(op: &ListOp<Target>, node: &Node) -> ListOp<Target> {
    let map = |items: &Vec<Target>| -> Vec<Target> {
        items.iter().map(|(p, s)| (map_path(&node.map, &node.site, p), *s)).collect()
    };
    ListOp {
        explicit: op.explicit.as_ref().map(map),
        prepended: map(&op.prepended),
        appended: map(&op.appended),
        deleted: map(&op.deleted),
        added: map(&op.added),
        ordered: map(&op.ordered),
    }
}

pub(super) fn merge_metadata(out: &mut Vec<MetadataEntry>, entries: &[MetadataEntry]) {
    for entry in entries {
        if !out.iter().any(|m| m.key == entry.key) {
            out.push(entry.clone());
        }
    }
}

pub(super) fn compose_attribute(specs: &[(&usda::AttributeSpec, &Node)]) -> Attribute {
    let (strongest, _) = specs[0];
    let mut default_value = None;
    let mut blocked = false;
    // The strongest default wins; a block (`= None`) hides every weaker value.
    if let Some((v, span)) = specs.iter().find_map(|(a, _)| a.default.as_ref()) {
        if v.is_none() {
            blocked = true;
        } else {
            default_value = Some((v.clone(), *span));
        }
    }
    // At a numeric time the strongest opinion with a value decides: its samples if it has
    // any (they beat its own default), else its default or block.
    // Sample times are the authoring layer's, mapped to the stage's by the layer offsets.
    let mut time_samples = specs
        .iter()
        .find(|(a, _)| !a.time_samples.is_empty() || a.default.is_some())
        .map(|(a, node)| {
            let offset = if a.time_samples.is_empty() { LayerOffset::default() } else { node.offset_of(a) };
            a.time_samples.iter().map(|(t, v)| (offset.apply(*t), v.clone())).collect()
        })
        .unwrap_or_default();
    time::sort_samples(&mut time_samples);
    let mut connections = Vec::new();
    let mut metadata = Vec::new();
    for (a, node) in specs.iter().rev() {
        mapped(&a.connections, node).apply(&mut connections, |x, y| x.0 == y.0);
    }
    for (a, _) in specs {
        merge_metadata(&mut metadata, &a.metadata);
    }
    // Path expressions compose: a stronger one's `%_` stands for the next weaker value.
    let weaker_defaults = if strongest.type_name == "pathExpression" {
        // A weaker block (`= None`) ends the chain.
        specs.iter().filter_map(|(a, _)| a.default.clone()).skip(1).take_while(|(v, _)| !v.is_none()).collect()
    } else {
        Vec::new()
    };
    Attribute {
        name: strongest.name.clone(),
        type_name: strongest.type_name.clone(),
        value_type: strongest.value_type,
        // Read at the stage's time once the stage is composed (`Stage::set_time`).
        value: default_value.clone(),
        default_value,
        blocked,
        span: strongest.span,
        custom: specs.iter().any(|(a, _)| a.custom),
        uniform: specs.iter().any(|(a, _)| a.uniform),
        connections,
        time_samples,
        metadata,
        weaker_defaults,
    }
}

pub(super) fn compose_relationship(specs: &[(&usda::RelationshipSpec, &Node)]) -> Relationship {
    let (strongest, _) = specs[0];
    let mut targets = Vec::new();
    let mut explicit = false;
    for (r, node) in specs.iter().rev() {
        explicit |= mapped(&r.targets, node).apply(&mut targets, |x, y| x.0 == y.0);
    }
    let mut metadata = Vec::new();
    for (r, _) in specs {
        merge_metadata(&mut metadata, &r.metadata);
    }
    Relationship {
        name: strongest.name.clone(),
        targets,
        explicit,
        authored: specs.iter().find_map(|(r, _)| r.authored),
        span: strongest.span,
        custom: specs.iter().any(|(r, _)| r.custom),
        metadata,
    }
}

/// Variant selections, strongest opinion per set.
pub(super) fn selections(opinions: &[(&PrimSpec, &Node)]) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    for (spec, _) in opinions {
        for (set, selection, _) in &spec.metadata.variant_selections {
            if !out.iter().any(|(s, _)| s == set) {
                out.push((set.clone(), selection.clone()));
            }
        }
    }
    out
}
