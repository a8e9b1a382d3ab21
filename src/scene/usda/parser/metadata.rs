//! Metadata blocks: `( … )` entries, references and payloads, layer offsets, sublayers and
//! relationship targets.

use super::{MetaEntry, MetaItem, MetaValue, PResult, Parser, Reported, path_text};
use crate::diag::{Diagnostic, Span};
use crate::scene::usda::lexer::TokenKind;
use crate::scene::usda::{LayerOffset, ListOpKind, Reference, Target};
use crate::scene::value::{AssetPath, Value};

impl<'a> Parser<'a, '_> {
    /// `( entry* )` where entries are `[op] key = value` or a bare leading string.
    pub(super) fn metadata_block(&mut self) -> PResult<Vec<MetaEntry>> {
        self.expect(TokenKind::LParen, "`(`")?;
        self.enter()?;
        let mut entries = Vec::new();
        loop {
            while self.eat(TokenKind::Semi).is_some() || self.eat(TokenKind::Comma).is_some() {}
            match self.peek_kind() {
                Some(TokenKind::RParen) => {
                    self.pos += 1;
                    break;
                }
                None => {
                    self.leave();
                    return self.expected("`)` closing the metadata block");
                }
                Some(TokenKind::String | TokenKind::TripleString) => {
                    let (value, _) = self.value()?;
                    if let Value::String(s) = value {
                        entries.push(MetaEntry::Comment(s));
                    }
                }
                _ => {
                    let start = self.pos;
                    match self.metadata_item() {
                        Ok(item) => entries.push(MetaEntry::Item(item)),
                        Err(Reported) => self.recover(TokenKind::RParen, start),
                    }
                }
            }
        }
        self.leave();
        Ok(entries)
    }

    pub(super) fn metadata_item(&mut self) -> PResult<MetaItem> {
        let start = self.here();
        let mut op = ListOpKind::Explicit;
        if let Some(kind) = self.peek_ident().and_then(ListOpKind::from_keyword)
            && self.peek_at(1).is_some_and(|t| t.kind == TokenKind::Ident)
        {
            op = kind;
            self.pos += 1;
        }
        let (key, _) = self.expect_name("a metadata name")?;
        self.expect(TokenKind::Eq, "`=`")?;
        let value_start = self.here();
        let value = match key {
            "references" | "payload" => MetaValue::References(self.references()?),
            "subLayers" => MetaValue::SubLayers(self.sub_layers()?),
            "inherits" | "specializes" => MetaValue::Paths(self.targets()?.unwrap_or_default()),
            _ => MetaValue::Plain(self.value()?.0),
        };
        let value_span = value_start.to(self.prev_span());
        Ok(MetaItem { key: key.to_string(), op, value, value_span, span: start.to(self.prev_span()) })
    }

    /// `None`, one reference, or `[ reference, ... ]`.
    pub(super) fn references(&mut self) -> PResult<Vec<Reference>> {
        if self.eat_ident("None") {
            return Ok(Vec::new());
        }
        if self.eat(TokenKind::LBracket).is_none() {
            return Ok(vec![self.reference()?]);
        }
        let mut items = Vec::new();
        while self.eat(TokenKind::RBracket).is_none() {
            items.push(self.reference()?);
            if self.eat(TokenKind::Comma).is_none() {
                self.expect(TokenKind::RBracket, "`,` or `]`")?;
                break;
            }
        }
        Ok(items)
    }

    /// `@asset@</Prim> (offset = 1; scale = 2)`, `@asset@` or `</Prim>`.
    pub(super) fn reference(&mut self) -> PResult<Reference> {
        let start = self.here();
        let mut asset = None;
        if matches!(self.peek_kind(), Some(TokenKind::Asset | TokenKind::TripleAsset)) {
            let (value, _) = self.value()?;
            if let Value::Asset(a) = value {
                asset = Some(a);
            }
        }
        let mut prim_path = None;
        if let Some(t) = self.eat(TokenKind::Path) {
            prim_path = Some(path_text(self.slice(t.span)).to_string());
        }
        if asset.is_none() && prim_path.is_none() {
            return self.expected("an asset path `@...@` or a prim path `</...>`");
        }
        let span = start.to(self.prev_span());
        let mut offset = LayerOffset::default();
        if self.peek_kind() == Some(TokenKind::LParen) {
            offset = self.layer_offset()?;
        }
        Ok(Reference { asset, prim_path, span, offset })
    }

    /// `(offset = 1; scale = 2)` after a reference or sublayer (other entries, such as
    /// `customData`, are read and not used).
    pub(super) fn layer_offset(&mut self) -> PResult<LayerOffset> {
        let mut out = LayerOffset::default();
        for entry in self.metadata_block()? {
            if let MetaEntry::Item(MetaItem { key, value: MetaValue::Plain(value), value_span, .. }) = entry {
                let number = value.as_f64().filter(|x| x.is_finite());
                match (key.as_str(), number) {
                    ("offset", Some(x)) => out.offset = x,
                    ("scale", Some(x)) => out.scale = x,
                    ("offset" | "scale", None) => self.error(
                        Diagnostic::error(format!("layer offset `{key}` must be a finite number"))
                            .at(value_span, "not a finite number"),
                    ),
                    _ => {}
                }
            }
        }
        Ok(out)
    }

    /// `[ @a@ (offset = 1), @b@ ]` or a single asset.
    pub(super) fn sub_layers(&mut self) -> PResult<Vec<(AssetPath, Span, LayerOffset)>> {
        let bracketed = self.eat(TokenKind::LBracket).is_some();
        let mut layers = Vec::new();
        loop {
            if bracketed && self.eat(TokenKind::RBracket).is_some() {
                break;
            }
            let (value, span) = self.value()?;
            let Value::Asset(asset) = value else {
                self.error(Diagnostic::error("expected an asset path in `subLayers`").at(span, "not an asset path"));
                return Err(Reported);
            };
            let mut offset = LayerOffset::default();
            if self.peek_kind() == Some(TokenKind::LParen) {
                offset = self.layer_offset()?;
            }
            layers.push((asset, span, offset));
            if !bracketed {
                break;
            }
            if self.eat(TokenKind::Comma).is_none() {
                self.expect(TokenKind::RBracket, "`,` or `]`")?;
                break;
            }
        }
        Ok(layers)
    }

    /// `None` (→ `None`), `</path>` or `[ </a>, </b> ]` (→ the paths, maybe empty).
    pub(super) fn targets(&mut self) -> PResult<Option<Vec<Target>>> {
        if self.eat_ident("None") {
            return Ok(None);
        }
        if let Some(t) = self.eat(TokenKind::Path) {
            return Ok(Some(vec![(path_text(self.slice(t.span)).to_string(), t.span)]));
        }
        self.expect(TokenKind::LBracket, "a path `</...>`, `[` or `None`")?;
        let mut targets = Vec::new();
        while self.eat(TokenKind::RBracket).is_none() {
            let t = self.expect(TokenKind::Path, "a path `</...>`")?;
            targets.push((path_text(self.slice(t.span)).to_string(), t.span));
            if self.eat(TokenKind::Comma).is_none() {
                self.expect(TokenKind::RBracket, "`,` or `]`")?;
                break;
            }
        }
        Ok(Some(targets))
    }
}
