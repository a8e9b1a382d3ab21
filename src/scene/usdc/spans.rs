//! Span fix-up: the converter writes spans before the outline has a file id; these point a
//! converted layer's spans at the outline once it is registered.

use crate::diag::{FileId, Span};
use crate::scene::usda::{Layer, ListOp, MetadataEntry, PrimSpec, PropertySpec};

/// Placeholder file id for spans until the outline is registered.
pub(super) const NO_FILE: FileId = FileId(u32::MAX);

pub(super) fn fix(span: &mut Span, file: FileId) {
    if span.file == NO_FILE {
        span.file = file;
    }
}

pub(super) fn fix_op<T>(op: &mut ListOp<T>, file: FileId, f: impl Fn(&mut T, FileId)) {
    let ListOp { explicit, prepended, appended, deleted, added, ordered } = op;
    for list in [prepended, appended, deleted, added, ordered].into_iter().chain(explicit.as_mut()) {
        for item in list {
            f(item, file);
        }
    }
}

pub(super) fn fix_entries(entries: &mut [MetadataEntry], file: FileId) {
    for e in entries {
        fix(&mut e.span, file);
    }
}

/// Points every span of a converted layer at the outline registered as `file`.
pub(super) fn retarget_layer(layer: &mut Layer, file: FileId) {
    if let Some((_, s)) = &mut layer.metadata.default_prim {
        fix(s, file);
    }
    for (_, s) in &mut layer.metadata.sub_layers {
        fix(s, file);
    }
    fix_entries(&mut layer.metadata.other, file);
    for prim in &mut layer.prims {
        retarget_prim(prim, file);
    }
}

pub(super) fn retarget_prim(prim: &mut PrimSpec, file: FileId) {
    fix(&mut prim.span, file);
    let m = &mut prim.metadata;
    fix_op(&mut m.references, file, |r, f| fix(&mut r.span, f));
    fix_op(&mut m.payloads, file, |r, f| fix(&mut r.span, f));
    fix_op(&mut m.inherits, file, |t, f| fix(&mut t.1, f));
    fix_op(&mut m.specializes, file, |t, f| fix(&mut t.1, f));
    for (_, _, s) in &mut m.variant_selections {
        fix(s, file);
    }
    fix_entries(&mut m.other, file);
    for property in &mut prim.properties {
        match property {
            PropertySpec::Attribute(a) => {
                fix(&mut a.span, file);
                if let Some((_, s)) = &mut a.default {
                    fix(s, file);
                }
                fix_op(&mut a.connections, file, |t, f| fix(&mut t.1, f));
                fix_entries(&mut a.metadata, file);
            }
            PropertySpec::Relationship(r) => {
                fix(&mut r.span, file);
                if let Some(s) = &mut r.authored {
                    fix(s, file);
                }
                fix_op(&mut r.targets, file, |t, f| fix(&mut t.1, f));
                fix_entries(&mut r.metadata, file);
            }
        }
    }
    for child in &mut prim.children {
        retarget_prim(child, file);
    }
    for set in &mut prim.variant_sets {
        fix(&mut set.span, file);
        for variant in &mut set.variants {
            retarget_prim(variant, file);
        }
    }
}
