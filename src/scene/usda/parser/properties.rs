//! Properties: attributes (defaults, time samples, connections) and relationships, with their
//! metadata and list-op prefixes.

use super::{MetaEntry, MetaItem, MetaValue, PResult, Parser, PropertyIndex, Reported};
use crate::diag::{Diagnostic, Span};
use crate::scene::usda::lexer::TokenKind;
use crate::scene::usda::{AttributeSpec, ListOp, ListOpKind, MetadataEntry, PrimSpec, PropertySpec, RelationshipSpec};
use crate::scene::value::{Value, ValueType};

impl<'a> Parser<'a, '_> {
    /// An attribute or relationship statement, merged into `prim`'s property of that name.
    pub(super) fn property(&mut self, prim: &mut PrimSpec, index: &mut PropertyIndex) -> PResult<()> {
        let start = self.here();
        let mut op = ListOpKind::Explicit;
        if let Some(kind) = self.peek_ident().and_then(ListOpKind::from_keyword) {
            op = kind;
            self.pos += 1;
        }
        let custom = self.eat_ident("custom");
        let mut uniform = false;
        match self.peek_ident() {
            Some("uniform") => {
                uniform = true;
                self.pos += 1;
            }
            Some("varying" | "config") => self.pos += 1,
            _ => {}
        }
        if self.eat_ident("rel") {
            return self.relationship(prim, index, start, op, custom);
        }
        let (type_word, _) = self.expect_name("a property: a type name, `rel`, `def`, `over`, `class` or `}`")?;
        let mut type_name = type_word.to_string();
        let mut array = false;
        if self.eat(TokenKind::LBracket).is_some() {
            self.expect(TokenKind::RBracket, "`]` after `[` in an array type")?;
            type_name.push_str("[]");
            array = true;
        }
        let (name, name_span) = self.expect_name("an attribute name")?;
        let span = start.to(name_span);
        let suffix = self.property_suffix()?;
        if op != ListOpKind::Explicit && suffix != Some("connect") {
            self.error(
                Diagnostic::error("list operations apply only to relationships and connections")
                    .at(start, "not allowed on an attribute value"),
            );
            return Err(Reported);
        }
        let value_type = ValueType::parse(type_word, array);
        let index = match index.get(name) {
            Some(&i) => i,
            None => {
                index.insert(name.to_string(), prim.properties.len());
                prim.properties.push(PropertySpec::Attribute(Box::new(AttributeSpec::declared(
                    name,
                    span,
                    type_name.clone(),
                    custom,
                    uniform,
                ))));
                prim.properties.len() - 1
            }
        };
        let mut default = None;
        let mut time_samples = None;
        let mut connections = None;
        if self.eat(TokenKind::Eq).is_some() {
            match suffix {
                Some("timeSamples") => time_samples = Some(self.time_samples(&value_type)?),
                Some("connect") => connections = Some(self.targets()?.unwrap_or_default()),
                Some("spline") => {
                    let span = self.here();
                    self.warn(Diagnostic::warning("attribute splines are not supported; ignored").at(span, "spline"));
                    self.value()?;
                }
                _ => default = Some(self.typed_value(&value_type)?),
            }
        }
        let metadata = if self.peek_kind() == Some(TokenKind::LParen) {
            let entries = self.metadata_block()?;
            self.property_metadata(entries)
        } else {
            Vec::new()
        };
        let Some(PropertySpec::Attribute(attr)) = prim.properties.get_mut(index) else {
            self.error(
                Diagnostic::error(format!("`{name}` is both a relationship and an attribute"))
                    .at(name_span, "declared as an attribute here"),
            );
            return Err(Reported);
        };
        if attr.type_name != type_name {
            let message = format!("`{name}` was declared as `{}` and now as `{type_name}`", attr.type_name);
            self.error(Diagnostic::error(message).at(span, "conflicting type").also(attr.span, "first declared here"));
            return Err(Reported);
        }
        attr.custom |= custom;
        attr.uniform |= uniform;
        if let Some(d) = default {
            attr.default = Some(d);
        }
        if let Some(samples) = time_samples {
            attr.time_samples = samples;
        }
        if let Some(c) = connections {
            attr.connections.set(op, c);
        }
        attr.metadata.extend(metadata);
        Ok(())
    }

    /// `.timeSamples`, `.connect`, `.default`, `.spline` after a property name.
    pub(super) fn property_suffix(&mut self) -> PResult<Option<&'a str>> {
        if self.eat(TokenKind::Dot).is_none() {
            return Ok(None);
        }
        let (word, span) = self.expect_name("`timeSamples` or `connect`")?;
        match word {
            "timeSamples" | "connect" | "spline" => Ok(Some(word)),
            "default" => Ok(None),
            _ => {
                self.error(
                    Diagnostic::error(format!("unknown property field `.{word}`"))
                        .at(span, "expected `timeSamples` or `connect`"),
                );
                Err(Reported)
            }
        }
    }

    pub(super) fn relationship(
        &mut self,
        prim: &mut PrimSpec,
        index: &mut PropertyIndex,
        start: Span,
        op: ListOpKind,
        custom: bool,
    ) -> PResult<()> {
        let (name, name_span) = self.expect_name("a relationship name")?;
        let span = start.to(name_span);
        // `rel r.default = </x>` is an old spelling of `rel r = </x>`.
        if self.eat(TokenKind::Dot).is_some() {
            self.expect_name("`default`")?;
        }
        let mut targets = None;
        let mut explicit_none = false;
        if self.eat(TokenKind::Eq).is_some() {
            let parsed = self.targets()?;
            explicit_none = parsed.is_none();
            targets = Some(parsed.unwrap_or_default());
        }
        let metadata = if self.peek_kind() == Some(TokenKind::LParen) {
            let entries = self.metadata_block()?;
            self.property_metadata(entries)
        } else {
            Vec::new()
        };
        let index = match index.get(name) {
            Some(&i) => i,
            None => {
                index.insert(name.to_string(), prim.properties.len());
                prim.properties.push(PropertySpec::Relationship(Box::new(RelationshipSpec {
                    name: name.to_string(),
                    span,
                    custom,
                    targets: ListOp::default(),
                    explicit_none: false,
                    authored: None,
                    metadata: Vec::new(),
                })));
                prim.properties.len() - 1
            }
        };
        let Some(PropertySpec::Relationship(rel)) = prim.properties.get_mut(index) else {
            self.error(
                Diagnostic::error(format!("`{name}` is both an attribute and a relationship"))
                    .at(name_span, "declared as a relationship here"),
            );
            return Err(Reported);
        };
        rel.custom |= custom;
        if let Some(targets) = targets {
            if op == ListOpKind::Explicit {
                rel.explicit_none = explicit_none;
            } else if explicit_none {
                self.error(
                    Diagnostic::error("`None` is only valid without a list-op prefix")
                        .at(span, "remove the prefix or list targets"),
                );
                return Err(Reported);
            }
            rel.targets.set(op, targets);
            // Kept apart from the list op: `prepend rel r = []` authors an (empty) opinion
            // that an empty list op cannot tell from a bare declaration.
            rel.authored.get_or_insert(span);
        }
        rel.metadata.extend(metadata);
        Ok(())
    }

    pub(super) fn property_metadata(&mut self, entries: Vec<MetaEntry>) -> Vec<MetadataEntry> {
        let mut out = Vec::new();
        for entry in entries {
            match entry {
                MetaEntry::Comment(c) => out.push(MetadataEntry {
                    key: "comment".into(),
                    op: ListOpKind::Explicit,
                    value: Value::String(c),
                    span: self.prev_span(),
                }),
                MetaEntry::Item(MetaItem { key, op, value: MetaValue::Plain(value), span, .. }) => {
                    out.push(MetadataEntry { key, op, value, span })
                }
                MetaEntry::Item(_) => {}
            }
        }
        out
    }

    /// `{ time: value, ... }`.
    pub(super) fn time_samples(&mut self, ty: &ValueType) -> PResult<Vec<(f64, Value)>> {
        self.expect(TokenKind::LBrace, "`{`")?;
        let mut samples = Vec::new();
        while self.eat(TokenKind::RBrace).is_none() {
            let (time, span) = self.value()?;
            let Some(time) = time.as_f64() else {
                self.error(Diagnostic::error("expected a time").at(span, "time samples are `time: value`"));
                return Err(Reported);
            };
            self.expect(TokenKind::Colon, "`:`")?;
            let (value, _) = self.typed_value(ty)?;
            samples.push((time, value));
            if self.eat(TokenKind::Comma).is_none() {
                self.expect(TokenKind::RBrace, "`,` or `}`")?;
                break;
            }
        }
        Ok(samples)
    }
}
