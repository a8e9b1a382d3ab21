//! Conversion of an opened crate into the usda syntax tree ([`Layer`]), writing the outline
//! whose lines the converted layer's spans point at.

use super::guarded;
use super::precheck::{check_value_sizes, precheck};
use super::spans::{NO_FILE, retarget_layer};
use super::values::{convert_value, layer_offset};
use crate::diag::{Diagnostic, Diagnostics, SourceMap, Span};
use crate::scene::usda::{
    AttributeSpec, Layer, LayerMetadata, ListOp, MetadataEntry, PrimMetadata, PrimSpec, PropertySpec, Reference,
    RelationshipSpec, Specifier, Target, VariantSetSpec,
};
use crate::scene::value::{AssetPath, Value, ValueType};
use openusd::sdf::{self, AbstractData};
use std::collections::HashMap;
use std::path::Path;

/// A diagnostic waiting for the outline's file id.
pub(super) struct Pending {
    pub(super) error: bool,
    pub(super) message: String,
    pub(super) at: (u32, u32),
    pub(super) label: String,
    pub(super) note: Option<String>,
}

/// Converts the crate file `bytes` read from `name` into a [`Layer`]. The outline (see the
/// module documentation) is registered in `sources` under `name`; problems go to `diags`.
/// A file openusd cannot read yields an empty layer and an error.
pub fn convert(name: &str, bytes: &[u8], base_dir: &Path, sources: &mut SourceMap, diags: &mut Diagnostics) -> Layer {
    let mut converter = Converter {
        data: None,
        by_text: HashMap::new(),
        outline: String::from("# binary USD (usdc): one line per spec; diagnostics point here\n"),
        base_dir,
        pending: Vec::new(),
    };
    let mut layer = Layer::default();
    match open(bytes) {
        Ok(data) => {
            converter.by_text = data.spec_paths().into_iter().map(|p| (p.as_str().to_string(), p)).collect();
            converter.data = Some(data);
            match guarded(|| converter.layer()) {
                Ok(l) => layer = l,
                Err(panic) => converter.pending.push(Pending {
                    error: true,
                    message: format!("malformed usdc: the binary USD reader failed ({panic})"),
                    at: (0, 0),
                    label: String::new(),
                    note: None,
                }),
            }
        }
        Err(message) => converter.pending.push(Pending {
            error: true,
            message: format!("malformed usdc: {message}"),
            at: (0, 0),
            label: String::new(),
            note: None,
        }),
    }
    let file = sources.add(name, std::mem::take(&mut converter.outline));
    retarget_layer(&mut layer, file);
    layer.file = file;
    for p in converter.pending {
        let span = Span { file, start: p.at.0, end: p.at.1 };
        let mut d = if p.error { Diagnostic::error(p.message) } else { Diagnostic::warning(p.message) };
        d = if p.at == (0, 0) { d.at(span, format!("in `{name}`")) } else { d.at(span, p.label) };
        if let Some(note) = p.note {
            d = d.note(note);
        }
        diags.push(d);
    }
    layer
}

/// Opens a crate after [`precheck`], with openusd's own structural validation on and its
/// panics caught.
pub(super) fn open(bytes: &[u8]) -> Result<Box<dyn AbstractData>, String> {
    precheck(bytes)?;
    guarded(|| -> Result<Box<dyn AbstractData>, String> {
        let file = openusd::usdc::CrateFile::open(std::io::Cursor::new(bytes)).map_err(|e| format!("{e:#}"))?;
        file.validate().map_err(|e| format!("{e:#}"))?;
        check_value_sizes(bytes, &file)?;
        let data =
            openusd::usdc::CrateData::open(std::io::Cursor::new(bytes.to_vec()), true).map_err(|e| format!("{e:#}"))?;
        Ok(Box::new(data))
    })
    .map_err(|panic| format!("the binary USD reader failed ({panic})"))?
}

pub(super) struct Converter<'a> {
    pub(super) data: Option<Box<dyn AbstractData>>,
    pub(super) by_text: HashMap<String, sdf::Path>,
    pub(super) outline: String,
    pub(super) base_dir: &'a Path,
    pub(super) pending: Vec<Pending>,
}

impl Converter<'_> {
    /// Appends one outline line (indented by `depth`) and returns the span of its text.
    pub(super) fn line(&mut self, depth: usize, text: &str) -> Span {
        for _ in 0..depth.min(32) {
            self.outline.push_str("    ");
        }
        let start = self.outline.len();
        // Paths and names come from the file: keep the outline one line per spec.
        for c in text.chars() {
            self.outline.push(if c == '\n' || c == '\r' { ' ' } else { c });
        }
        let end = self.outline.len();
        self.outline.push('\n');
        Span::new(NO_FILE, start, end)
    }

    pub(super) fn warn(&mut self, span: Span, message: String, label: &str, note: Option<&str>) {
        self.pending.push(Pending {
            error: false,
            message,
            at: (span.start, span.end),
            label: label.into(),
            note: note.map(str::to_string),
        });
    }

    pub(super) fn error(&mut self, span: Span, message: String, label: &str) {
        self.pending.push(Pending {
            error: true,
            message,
            at: (span.start, span.end),
            label: label.into(),
            note: None,
        });
    }

    /// The field `field` of the spec at `path`; decoding failures are reported at `span`.
    pub(super) fn field(&mut self, path: &str, field: &str, span: Span) -> Option<sdf::Value> {
        let sdf_path = self.by_text.get(path)?;
        let data = self.data.as_ref()?;
        match data.try_field(sdf_path, field) {
            Ok(v) => v.map(|v| v.into_owned()),
            Err(e) => {
                let message = format!("malformed usdc: cannot decode field `{field}` of `{path}`: {e}");
                self.error(span, message, "this spec");
                None
            }
        }
    }

    pub(super) fn fields(&self, path: &str) -> Vec<String> {
        match (self.by_text.get(path), self.data.as_ref()) {
            (Some(p), Some(data)) => data.list_fields(p).unwrap_or_default(),
            _ => Vec::new(),
        }
    }

    pub(super) fn tokens(&mut self, path: &str, field: &str, span: Span) -> Vec<String> {
        match self.field(path, field, span) {
            Some(sdf::Value::TokenVec(v)) => v.iter().map(|t| t.as_str().to_string()).collect(),
            Some(sdf::Value::StringVec(v)) => v,
            Some(other) => {
                self.unexpected(span, path, field, &other);
                Vec::new()
            }
            None => Vec::new(),
        }
    }

    pub(super) fn unexpected(&mut self, span: Span, path: &str, field: &str, value: &sdf::Value) {
        let kind: &'static str = value.into();
        self.error(span, format!("malformed usdc: field `{field}` of `{path}` holds a {kind}"), "this spec");
    }

    pub(super) fn layer(&mut self) -> Layer {
        let root = "/";
        let span = self.line(0, "layer </>");
        let mut meta = LayerMetadata::default();
        let mut sub_paths: Vec<String> = Vec::new();
        for field in self.fields(root) {
            let Some(value) = self.field(root, &field, span) else { continue };
            match (field.as_str(), value) {
                ("primChildren", _) => {}
                ("subLayers", sdf::Value::StringVec(v)) => sub_paths = v,
                ("subLayerOffsets", sdf::Value::LayerOffsetVec(v)) => {
                    meta.sub_layer_offsets = v.iter().map(layer_offset).collect();
                }
                ("subLayerOffsets", _) => {}
                ("defaultPrim", sdf::Value::Token(t)) => {
                    let s = self.line(1, &format!("defaultPrim = \"{}\"", t.as_str()));
                    meta.default_prim = Some((t.as_str().to_string(), s));
                }
                ("upAxis", sdf::Value::Token(t)) => meta.up_axis = Some(t.as_str().to_string()),
                ("metersPerUnit", sdf::Value::Double(d)) => meta.meters_per_unit = Some(d),
                ("documentation", sdf::Value::String(s)) => meta.doc = Some(s),
                ("comment", sdf::Value::String(s)) => meta.comment = Some(s),
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(root, key, &value, span) {
                        meta.other.push(entry);
                    }
                }
            }
        }
        for sub in sub_paths {
            let s = self.line(1, &format!("subLayers @{sub}@"));
            meta.sub_layers.push((AssetPath::new(sub, self.base_dir), s));
        }
        let mut prims = Vec::new();
        for child in self.tokens(root, "primChildren", span) {
            if let Some(prim) = self.prim(&format!("/{child}"), &child, 0, 0) {
                prims.push(prim);
            }
        }
        Layer { file: NO_FILE, metadata: meta, prims, prim_index: Default::default() }
    }

    /// The prim (or, with `variant`, the variant body) at `path`.
    pub(super) fn prim(&mut self, path: &str, name: &str, depth: usize, nesting: usize) -> Option<PrimSpec> {
        if !self.by_text.contains_key(path) {
            let span = self.line(depth, &format!("<{path}>"));
            self.error(span, format!("malformed usdc: `{path}` is listed as a child but has no spec"), "here");
            return None;
        }
        if nesting > 256 {
            let span = self.line(depth, &format!("<{path}>"));
            self.error(span, "malformed usdc: prims nested more than 256 deep".into(), "here");
            return None;
        }
        let fields = self.fields(path);
        let specifier = match self.field(path, "specifier", Span::default()) {
            Some(sdf::Value::Specifier(sdf::Specifier::Over)) => Specifier::Over,
            Some(sdf::Value::Specifier(sdf::Specifier::Class)) => Specifier::Class,
            Some(sdf::Value::Specifier(sdf::Specifier::Def)) => Specifier::Def,
            _ => Specifier::Over,
        };
        let type_name = match self.field(path, "typeName", Span::default()) {
            Some(sdf::Value::Token(t)) if !t.as_str().is_empty() => Some(t.as_str().to_string()),
            _ => None,
        };
        let keyword = match specifier {
            Specifier::Def => "def",
            Specifier::Over => "over",
            Specifier::Class => "class",
        };
        let text = match &type_name {
            Some(t) => format!("{keyword} {t} <{path}>"),
            None => format!("{keyword} <{path}>"),
        };
        let span = self.line(depth, &text);
        let mut prim = PrimSpec {
            specifier,
            type_name,
            name: name.to_string(),
            span,
            metadata: PrimMetadata::default(),
            properties: Vec::new(),
            children: Vec::new(),
            child_index: Default::default(),
            variant_sets: Vec::new(),
        };
        self.prim_metadata(path, &fields, &mut prim.metadata, span, depth + 1);
        for property in self.tokens(path, "propertyChildren", span) {
            if let Some(p) = self.property(&format!("{path}.{property}"), &property, depth + 1) {
                prim.properties.push(p);
            }
        }
        // Children of a variant body are written `/A{set=v}Child`, of a prim `/A/Child`.
        let sep = if path.ends_with('}') || path == "/" { "" } else { "/" };
        for child in self.tokens(path, "primChildren", span) {
            if let Some(c) = self.prim(&format!("{path}{sep}{child}"), &child, depth + 1, nesting + 1) {
                prim.children.push(c);
            }
        }
        for set in self.tokens(path, "variantSetChildren", span) {
            let set_path = format!("{path}{{{set}=}}");
            let set_span = self.line(depth + 1, &format!("variantSet \"{set}\" <{set_path}>"));
            let mut spec = VariantSetSpec { name: set.clone(), span: set_span, variants: Vec::new() };
            for variant in self.tokens(&set_path, "variantChildren", set_span) {
                let variant_path = format!("{path}{{{set}={variant}}}");
                if let Some(mut body) = self.prim(&variant_path, &variant, depth + 2, nesting + 1) {
                    body.specifier = Specifier::Over;
                    spec.variants.push(body);
                }
            }
            prim.variant_sets.push(spec);
        }
        Some(prim)
    }

    pub(super) fn prim_metadata(
        &mut self,
        path: &str,
        fields: &[String],
        meta: &mut PrimMetadata,
        span: Span,
        depth: usize,
    ) {
        for field in fields {
            let field = field.as_str();
            if matches!(
                field,
                "specifier"
                    | "typeName"
                    | "propertyChildren"
                    | "primChildren"
                    | "variantSetChildren"
                    | "variantChildren"
            ) {
                continue;
            }
            let Some(value) = self.field(path, field, span) else { continue };
            match (field, value) {
                ("references", sdf::Value::ReferenceListOp(op)) => {
                    meta.references =
                        self.references(op, depth, "references", |r| (r.asset_path, r.prim_path, r.layer_offset))
                }
                ("payload", sdf::Value::PayloadListOp(op)) => {
                    meta.payloads = self.references(op, depth, "payload", |r| {
                        (r.asset_path, r.prim_path, r.layer_offset.unwrap_or_default())
                    })
                }
                ("payload", sdf::Value::Payload(p)) => {
                    let op = sdf::ListOp { explicit: true, explicit_items: vec![p], ..Default::default() };
                    meta.payloads = self.references(op, depth, "payload", |r| {
                        (r.asset_path, r.prim_path, r.layer_offset.unwrap_or_default())
                    });
                }
                ("inheritPaths", sdf::Value::PathListOp(op)) => meta.inherits = self.targets(op, depth, "inherits"),
                ("specializes", sdf::Value::PathListOp(op)) => {
                    meta.specializes = self.targets(op, depth, "specializes")
                }
                ("variantSelection", sdf::Value::VariantSelectionMap(map)) => {
                    let mut pairs: Vec<(String, String)> = map.into_iter().collect();
                    pairs.sort();
                    for (set, selection) in pairs {
                        let s = self.line(depth, &format!("variants: {set} = \"{selection}\""));
                        meta.variant_selections.push((set, selection, s));
                    }
                }
                ("variantSetNames", sdf::Value::StringListOp(op)) => meta.variant_set_names = list_op(op, |s| s),
                ("variantSetNames", sdf::Value::TokenListOp(op)) => {
                    meta.variant_set_names = list_op(op, |t| t.as_str().to_string())
                }
                ("apiSchemas", sdf::Value::TokenListOp(op)) => {
                    meta.api_schemas = list_op(op, |t| t.as_str().to_string())
                }
                ("kind", sdf::Value::Token(t)) => meta.kind = Some(t.as_str().to_string()),
                ("active", sdf::Value::Bool(b)) => meta.active = Some(b),
                ("instanceable", sdf::Value::Bool(b)) => meta.instanceable = Some(b),
                ("documentation", sdf::Value::String(s)) => meta.doc = Some(s),
                ("comment", sdf::Value::String(s)) => meta.comment = Some(s),
                (
                    key @ ("references" | "payload" | "inheritPaths" | "specializes" | "variantSelection"
                    | "variantSetNames" | "apiSchemas" | "kind" | "active" | "instanceable"),
                    value,
                ) => self.unexpected(span, path, key, &value),
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(path, key, &value, span) {
                        meta.other.push(entry);
                    }
                }
            }
        }
    }

    /// References or payloads, one outline line per item.
    pub(super) fn references<T: Default + Clone + PartialEq>(
        &mut self,
        op: sdf::ListOp<T>,
        depth: usize,
        what: &str,
        parts: impl Fn(T) -> (String, sdf::Path, sdf::LayerOffset),
    ) -> ListOp<Reference> {
        let mut convert = |items: Vec<T>| -> Vec<Reference> {
            items
                .into_iter()
                .map(|item| {
                    let (asset, prim, offset) = parts(item);
                    let prim = (!prim.is_empty()).then(|| prim.as_str().to_string());
                    let text = format!(
                        "{what} {}{}",
                        if asset.is_empty() { String::new() } else { format!("@{asset}@") },
                        prim.as_deref().map(|p| format!("<{p}>")).unwrap_or_default()
                    );
                    let span = self.line(depth, &text);
                    let asset = (!asset.is_empty()).then(|| AssetPath::new(asset, self.base_dir));
                    Reference { asset, prim_path: prim, span, offset: layer_offset(&offset) }
                })
                .collect()
        };
        ListOp {
            explicit: if op.explicit { Some(convert(op.explicit_items)) } else { None },
            prepended: convert(op.prepended_items),
            appended: convert(op.appended_items),
            deleted: convert(op.deleted_items),
            added: convert(op.added_items),
            ordered: convert(op.ordered_items),
        }
    }

    /// Path list ops (inherits, targets, connections), one outline line per path.
    pub(super) fn targets(&mut self, op: sdf::PathListOp, depth: usize, what: &str) -> ListOp<Target> {
        let mut convert = |items: Vec<sdf::Path>| -> Vec<Target> {
            items
                .into_iter()
                .map(|p| {
                    let text = p.as_str().to_string();
                    let span = self.line(depth, &format!("{what} <{text}>"));
                    (text, span)
                })
                .collect()
        };
        ListOp {
            explicit: if op.explicit { Some(convert(op.explicit_items)) } else { None },
            prepended: convert(op.prepended_items),
            appended: convert(op.appended_items),
            deleted: convert(op.deleted_items),
            added: convert(op.added_items),
            ordered: convert(op.ordered_items),
        }
    }

    pub(super) fn property(&mut self, path: &str, name: &str, depth: usize) -> Option<PropertySpec> {
        let data = self.data.as_ref()?;
        let kind = self.by_text.get(path).and_then(|p| data.spec_type(p));
        match kind {
            Some(sdf::SpecType::Attribute) => self.attribute(path, name, depth),
            Some(sdf::SpecType::Relationship) => self.relationship(path, name, depth),
            _ => {
                let span = self.line(depth, &format!("<{path}>"));
                self.error(span, format!("malformed usdc: `{path}` is listed as a property but is not one"), "here");
                None
            }
        }
    }

    pub(super) fn attribute(&mut self, path: &str, name: &str, depth: usize) -> Option<PropertySpec> {
        let type_name = match self.field(path, "typeName", Span::default()) {
            Some(sdf::Value::Token(t)) => t.as_str().to_string(),
            _ => String::new(),
        };
        let uniform = matches!(
            self.field(path, "variability", Span::default()),
            Some(sdf::Value::Variability(sdf::Variability::Uniform))
        );
        let custom = matches!(self.field(path, "custom", Span::default()), Some(sdf::Value::Bool(true)));
        let text = format!(
            "{}{}{type_name} <{path}>",
            if custom { "custom " } else { "" },
            if uniform { "uniform " } else { "" }
        );
        let span = self.line(depth, &text);
        let mut attr = AttributeSpec::declared(name, span, type_name.clone(), custom, uniform);
        let value_type = attr.value_type;
        for field in self.fields(path) {
            let field = field.as_str();
            if matches!(field, "typeName" | "variability" | "custom") {
                continue;
            }
            let Some(value) = self.field(path, field, span) else { continue };
            match (field, value) {
                ("default", value) => {
                    if let Some(v) = self.typed(path, field, &value, &value_type, span) {
                        attr.default = Some((v, span));
                    }
                }
                ("timeSamples", sdf::Value::TimeSamples(samples)) => {
                    for (time, value) in samples {
                        if let Some(v) = self.typed(path, field, &value, &value_type, span) {
                            attr.time_samples.push((time, v));
                        }
                    }
                }
                ("connectionPaths", sdf::Value::PathListOp(op)) => {
                    attr.connections = self.targets(op, depth + 1, "connect")
                }
                (key @ ("timeSamples" | "connectionPaths"), value) => self.unexpected(span, path, key, &value),
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(path, key, &value, span) {
                        attr.metadata.push(entry);
                    }
                }
            }
        }
        Some(PropertySpec::Attribute(Box::new(attr)))
    }

    pub(super) fn relationship(&mut self, path: &str, name: &str, depth: usize) -> Option<PropertySpec> {
        let custom = matches!(self.field(path, "custom", Span::default()), Some(sdf::Value::Bool(true)));
        let span = self.line(depth, &format!("{}rel <{path}>", if custom { "custom " } else { "" }));
        let mut rel = RelationshipSpec {
            name: name.to_string(),
            span,
            custom,
            targets: ListOp::default(),
            explicit_none: false,
            authored: None,
            metadata: Vec::new(),
        };
        for field in self.fields(path) {
            let field = field.as_str();
            if matches!(field, "custom" | "variability") {
                continue;
            }
            let Some(value) = self.field(path, field, span) else { continue };
            match (field, value) {
                ("targetPaths", sdf::Value::PathListOp(op)) => {
                    // `rel r = None` is an explicit empty list in a crate, as `= []` is.
                    rel.explicit_none = op.explicit && op.explicit_items.is_empty();
                    rel.targets = self.targets(op, depth + 1, "target");
                    rel.authored = Some(span);
                }
                ("targetPaths", value) => self.unexpected(span, path, "targetPaths", &value),
                // Target specs' children: nothing strata reads.
                ("targetChildren", _) => {}
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(path, key, &value, span) {
                        rel.metadata.push(entry);
                    }
                }
            }
        }
        Some(PropertySpec::Relationship(Box::new(rel)))
    }

    /// A value of a declared type, exactly as the usda parser would hold it.
    pub(super) fn typed(
        &mut self,
        path: &str,
        field: &str,
        value: &sdf::Value,
        ty: &ValueType,
        span: Span,
    ) -> Option<Value> {
        let converted = match convert_value(value, self.base_dir, false) {
            Ok(v) => v,
            // A value strata would read but cannot convert is an error, never a silently
            // missing value (unlike metadata strata never reads, below: a warning).
            Err(kind) => {
                self.error(
                    span,
                    format!(
                        "unsupported in usdc: `{path}` field `{field}` holds a {kind}, which strata does not convert"
                    ),
                    "this property",
                );
                return None;
            }
        };
        match converted.coerce(ty) {
            Ok(v) => Some(v),
            Err(message) => {
                self.error(span, format!("`{path}`: field `{field}` does not match the declared type"), &message);
                None
            }
        }
    }

    /// Any other metadata field, kept as the usda parser keeps it (`doc` for
    /// `documentation`; tokens as the strings usda writes).
    pub(super) fn metadata_entry(
        &mut self,
        path: &str,
        key: &str,
        value: &sdf::Value,
        span: Span,
    ) -> Option<MetadataEntry> {
        let key = if key == "documentation" { "doc" } else { key };
        match convert_value(value, self.base_dir, true) {
            Ok(value) => Some(MetadataEntry { key: key.to_string(), op: Default::default(), value, span }),
            Err(kind) => {
                self.warn(
                    span,
                    format!("`{path}`: metadata `{key}` holds a {kind}, which strata does not convert; ignored"),
                    "this spec",
                    None,
                );
                None
            }
        }
    }
}

pub(super) fn list_op<T: Default + Clone + PartialEq, U>(op: sdf::ListOp<T>, f: impl Fn(T) -> U) -> ListOp<U> {
    let map = |items: Vec<T>| items.into_iter().map(&f).collect::<Vec<U>>();
    ListOp {
        explicit: if op.explicit { Some(map(op.explicit_items)) } else { None },
        prepended: map(op.prepended_items),
        appended: map(op.appended_items),
        deleted: map(op.deleted_items),
        added: map(op.added_items),
        ordered: map(op.ordered_items),
    }
}
