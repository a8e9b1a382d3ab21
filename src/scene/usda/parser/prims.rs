//! Prims: `def`/`over`/`class` statements, prim metadata, bodies and variant sets.

use super::values::unquote;
use super::{MetaEntry, MetaValue, PResult, Parser, PropertyIndex, Reported, is_identifier, strings_of};
use crate::diag::Diagnostic;
use crate::scene::usda::lexer::TokenKind;
use crate::scene::usda::{MetadataEntry, PrimMetadata, PrimSpec, Specifier, VariantSetSpec};
use crate::scene::value::Value;

impl<'a> Parser<'a, '_> {
    /// `def|over|class [Type] "name" [( metadata )] { body }`.
    pub(super) fn prim(&mut self) -> PResult<PrimSpec> {
        let start = self.here();
        let specifier = match self.peek_ident() {
            Some("def") => Specifier::Def,
            Some("over") => Specifier::Over,
            Some("class") => Specifier::Class,
            _ => return self.expected("`def`, `over` or `class`"),
        };
        self.pos += 1;
        let type_name = match self.peek_kind() {
            Some(TokenKind::Ident) => Some(self.expect_name("a type name")?.0.to_string()),
            _ => None,
        };
        let name_token = self.expect(TokenKind::String, "a quoted prim name")?;
        let name = unquote(self.slice(name_token.span), false);
        if !is_identifier(&name) {
            self.error(
                Diagnostic::error(format!("invalid prim name {name:?}")).at(
                    name_token.span,
                    "prim names are identifiers: letters, digits and `_`, not starting with a digit",
                ),
            );
        }
        let mut prim = PrimSpec {
            specifier,
            type_name,
            name,
            span: start.to(name_token.span),
            metadata: PrimMetadata::default(),
            properties: Vec::new(),
            children: Vec::new(),
            child_index: Default::default(),
            variant_sets: Vec::new(),
        };
        if self.peek_kind() == Some(TokenKind::LParen) {
            let entries = self.metadata_block()?;
            prim.metadata = self.prim_metadata(entries);
        }
        self.prim_body(&mut prim)?;
        Ok(prim)
    }

    pub(super) fn prim_metadata(&mut self, entries: Vec<MetaEntry>) -> PrimMetadata {
        let mut meta = PrimMetadata::default();
        for entry in entries {
            let item = match entry {
                MetaEntry::Comment(c) => {
                    meta.comment = Some(c);
                    continue;
                }
                MetaEntry::Item(item) => item,
            };
            let span = item.value_span;
            match (item.key.as_str(), item.value) {
                ("references", MetaValue::References(r)) => meta.references.set(item.op, r),
                ("payload", MetaValue::References(r)) => meta.payloads.set(item.op, r),
                ("inherits", MetaValue::Paths(p)) => meta.inherits.set(item.op, p),
                ("specializes", MetaValue::Paths(p)) => meta.specializes.set(item.op, p),
                ("variants", MetaValue::Plain(Value::Dictionary(d))) => {
                    for (set, selection) in d {
                        match selection.as_str() {
                            Some(s) => meta.variant_selections.push((set, s.to_string(), span)),
                            None => self.error(
                                Diagnostic::error(format!("variant selection for `{set}` is not a string"))
                                    .at(span, "expected `string set = \"variant\"` entries"),
                            ),
                        }
                    }
                }
                ("variantSets", MetaValue::Plain(v)) => meta.variant_set_names.set(item.op, strings_of(v)),
                ("apiSchemas", MetaValue::Plain(v)) => meta.api_schemas.set(item.op, strings_of(v)),
                ("kind", MetaValue::Plain(v)) if v.as_str().is_some() => meta.kind = v.as_str().map(String::from),
                ("doc", MetaValue::Plain(v)) if v.as_str().is_some() => meta.doc = v.as_str().map(String::from),
                ("active", MetaValue::Plain(v)) if v.as_bool().is_some() => meta.active = v.as_bool(),
                ("instanceable", MetaValue::Plain(v)) if v.as_bool().is_some() => meta.instanceable = v.as_bool(),
                (key @ ("variants" | "kind" | "doc" | "active" | "instanceable"), _) => {
                    let message = format!("prim metadata `{key}` has the wrong type");
                    self.error(Diagnostic::error(message).at(span, "unexpected value"));
                }
                (_, MetaValue::Plain(value)) => {
                    meta.other.push(MetadataEntry { key: item.key, op: item.op, value, span: item.span })
                }
                _ => {}
            }
        }
        meta
    }

    /// `{ (prim | property | variantSet | reorder)* }`.
    pub(super) fn prim_body(&mut self, prim: &mut PrimSpec) -> PResult<()> {
        let open = self.expect(TokenKind::LBrace, "`{`")?;
        self.enter()?;
        // Property name → position in `prim.properties`: statements about one property are
        // merged, and searching the list for each statement was quadratic in property count.
        let mut property_index = PropertyIndex::new();
        loop {
            while self.eat(TokenKind::Semi).is_some() {}
            let Some(token) = self.peek() else {
                self.error(
                    Diagnostic::error("unclosed `{`")
                        .at(open.span, "this `{` is never closed")
                        .also(prim.span, "in this prim"),
                );
                self.leave();
                return Err(Reported);
            };
            if token.kind == TokenKind::RBrace {
                self.pos += 1;
                break;
            }
            let start = self.pos;
            let result = match self.peek_ident() {
                Some("def" | "over" | "class") => self.prim().map(|child| prim.children.push(child)),
                Some("variantSet") => self.variant_set().map(|set| prim.variant_sets.push(set)),
                Some("reorder")
                    if matches!(self.peek_at(1).map(|t| self.slice(t.span)), Some("nameChildren" | "properties")) =>
                {
                    // Only changes the order of names: parsed and ignored.
                    self.pos += 2;
                    self.expect(TokenKind::Eq, "`=`").and_then(|_| self.value()).map(|_| ())
                }
                _ => self.property(prim, &mut property_index),
            };
            if result.is_err() {
                self.recover(TokenKind::RBrace, start);
            }
        }
        self.leave();
        Ok(())
    }

    /// `variantSet "name" = { "variant" [( metadata )] { body } ... }`.
    pub(super) fn variant_set(&mut self) -> PResult<VariantSetSpec> {
        let start = self.here();
        self.pos += 1;
        let name_token = self.expect(TokenKind::String, "a quoted variant set name")?;
        let name = unquote(self.slice(name_token.span), false);
        let span = start.to(name_token.span);
        self.expect(TokenKind::Eq, "`=`")?;
        self.expect(TokenKind::LBrace, "`{`")?;
        let mut variants = Vec::new();
        while self.eat(TokenKind::RBrace).is_none() {
            let token = self.expect(TokenKind::String, "a quoted variant name or `}`")?;
            let mut body = PrimSpec {
                specifier: Specifier::Over,
                type_name: None,
                name: unquote(self.slice(token.span), false),
                span: token.span,
                metadata: PrimMetadata::default(),
                properties: Vec::new(),
                children: Vec::new(),
                child_index: Default::default(),
                variant_sets: Vec::new(),
            };
            if self.peek_kind() == Some(TokenKind::LParen) {
                let entries = self.metadata_block()?;
                body.metadata = self.prim_metadata(entries);
            }
            self.prim_body(&mut body)?;
            variants.push(body);
        }
        Ok(VariantSetSpec { name, span, variants })
    }
}
