//! Recursive-descent parser from `.usda` tokens to a [`Layer`].
//!
//! Errors are reported into [`Diagnostics`] and the parser recovers at the next statement
//! (a token at the start of a line, outside any brackets), so one run reports several
//! problems. The result is always a layer, possibly partial.

use super::lexer::{Token, TokenKind, TokenStream, lex_errors};
use super::{
    AttributeSpec, Layer, LayerMetadata, LayerOffset, ListOp, ListOpKind, MetadataEntry, PrimMetadata, PrimSpec,
    PropertySpec, Reference, RelationshipSpec, Specifier, Target, VariantSetSpec,
};
use crate::diag::{Diagnostic, Diagnostics, FileId, Span};
use crate::scene::value::{AssetPath, Value, ValueType};
use std::cell::RefCell;
use std::collections::HashMap;
use std::collections::VecDeque;
use std::path::Path;

/// A prim body's property names → positions in its `properties`.
type PropertyIndex = HashMap<String, usize>;

/// Past this many errors in one file the parser stops: the rest is likely noise.
const MAX_ERRORS: usize = 50;
/// Bracket nesting deeper than this is rejected instead of risking the stack.
const MAX_DEPTH: usize = 200;

/// Parses `text` (the contents of `file`) into a layer. Asset paths are resolved against
/// `base_dir`, the directory of the file.
pub fn parse(file: FileId, text: &str, base_dir: &Path, diags: &mut Diagnostics) -> Layer {
    // Unrecognised text is reported first (a pass that keeps nothing else); the parser then
    // pulls tokens from a second pass through a bounded window.
    let lex_errors = lex_errors(file, text);
    let tokens = RefCell::new(TokenWindow::new(TokenStream::new(file, text)));
    let mut parser = Parser { text, file, tokens, pos: 0, base_dir, diags, errors: 0, depth: 0 };
    for span in lex_errors {
        parser.error(Diagnostic::error("unrecognised text").at(span, "not valid in a .usda file"));
    }
    parser.layer()
}

/// Marker for a reported parse error; the diagnostic is already in the sink.
struct Reported;
type PResult<T> = Result<T, Reported>;

/// A parsed metadata value: most are plain values, a few keys have their own syntax.
enum MetaValue {
    Plain(Value),
    /// `references` / `payload`; empty for `None`.
    References(Vec<Reference>),
    /// `subLayers`, each with its layer offset.
    SubLayers(Vec<(AssetPath, Span, LayerOffset)>),
    /// `inherits` / `specializes`; empty for `None`.
    Paths(Vec<Target>),
}

/// One metadata entry before it is sorted into a prim's, layer's or property's fields.
struct MetaItem {
    key: String,
    op: ListOpKind,
    value: MetaValue,
    value_span: Span,
    span: Span,
}

/// A bare string at the start of a metadata block (a comment) or a `key = value` entry.
enum MetaEntry {
    Comment(String),
    Item(MetaItem),
}

/// Tokens the parser has looked at recently (it rewinds at most one numeric tuple, never
/// more than [`TokenWindow::KEEP`] tokens) and those it has peeked ahead at, indexed by
/// their position in the file's token sequence.
struct TokenWindow<'a> {
    stream: TokenStream<'a>,
    /// Position of `buffer[0]`.
    base: usize,
    buffer: VecDeque<Token>,
    /// No more tokens: the stream is exhausted or the parser stopped.
    done: bool,
}

impl<'a> TokenWindow<'a> {
    /// Tokens kept behind the one asked for.
    const KEEP: usize = 1 << 16;

    fn new(stream: TokenStream<'a>) -> TokenWindow<'a> {
        TokenWindow { stream, base: 0, buffer: VecDeque::new(), done: false }
    }

    /// Token `at`, lexing up to it; `None` past the end or before the window.
    fn get(&mut self, at: usize) -> Option<Token> {
        while !self.done && self.base + self.buffer.len() <= at {
            match self.stream.next() {
                Some(Ok(token)) => self.buffer.push_back(token),
                Some(Err(_)) => {} // reported before parsing
                None => self.done = true,
            }
        }
        if at >= self.base + 2 * Self::KEEP {
            let drop = (at - Self::KEEP - self.base).min(self.buffer.len());
            self.buffer.drain(..drop);
            self.base += drop;
        }
        self.buffer.get(at.checked_sub(self.base)?).copied()
    }

    /// Stops: no token is read after this. Returns the position past the last one read.
    fn finish(&mut self) -> usize {
        self.done = true;
        self.base += self.buffer.len();
        self.buffer.clear();
        self.base
    }
}

struct Parser<'a, 'd> {
    text: &'a str,
    file: FileId,
    tokens: RefCell<TokenWindow<'a>>,
    pos: usize,
    base_dir: &'a Path,
    diags: &'d mut Diagnostics,
    errors: usize,
    depth: usize,
}

impl<'a> Parser<'a, '_> {
    // ---- token helpers ----

    fn peek(&self) -> Option<Token> {
        self.tokens.borrow_mut().get(self.pos)
    }

    fn peek_kind(&self) -> Option<TokenKind> {
        self.peek().map(|t| t.kind)
    }

    fn peek_at(&self, ahead: usize) -> Option<Token> {
        self.tokens.borrow_mut().get(self.pos + ahead)
    }

    /// Skips the rest of the file.
    fn skip_to_end(&mut self) {
        self.pos = self.tokens.get_mut().finish();
    }

    fn slice(&self, span: Span) -> &'a str {
        self.text.get(span.start as usize..span.end as usize).unwrap_or("")
    }

    /// The text of the next token if it is an identifier.
    fn peek_ident(&self) -> Option<&'a str> {
        self.peek().filter(|t| t.kind == TokenKind::Ident).map(|t| self.slice(t.span))
    }

    fn bump(&mut self) -> Option<Token> {
        let token = self.peek();
        if token.is_some() {
            self.pos += 1;
        }
        token
    }

    fn eat(&mut self, kind: TokenKind) -> Option<Token> {
        if self.peek_kind() == Some(kind) { self.bump() } else { None }
    }

    fn eat_ident(&mut self, word: &str) -> bool {
        if self.peek_ident() == Some(word) {
            self.pos += 1;
            true
        } else {
            false
        }
    }

    /// The span of the next token, or an empty span at the end of the file.
    fn here(&self) -> Span {
        match self.peek() {
            Some(t) => t.span,
            None => Span::new(self.file, self.text.len(), self.text.len()),
        }
    }

    fn prev_span(&self) -> Span {
        self.pos
            .checked_sub(1)
            .and_then(|i| self.tokens.borrow_mut().get(i))
            .map(|t| t.span)
            .unwrap_or_else(|| self.here())
    }

    fn error(&mut self, diagnostic: Diagnostic) {
        self.errors += 1;
        if self.errors <= MAX_ERRORS {
            self.diags.push(diagnostic);
        }
        if self.errors == MAX_ERRORS {
            // Stop after this one; the rest of the file is skipped.
            self.skip_to_end();
        }
    }

    fn warn(&mut self, diagnostic: Diagnostic) {
        self.diags.push(diagnostic);
    }

    /// Reports `expected ...` at the next token.
    fn expected<T>(&mut self, what: &str) -> PResult<T> {
        let span = self.here();
        let found = match self.peek() {
            Some(t) => format!("found `{}`", truncate(self.slice(t.span))),
            None => "found the end of the file".to_string(),
        };
        self.error(Diagnostic::error(format!("expected {what}, {found}")).at(span, format!("expected {what}")));
        Err(Reported)
    }

    fn expect(&mut self, kind: TokenKind, what: &str) -> PResult<Token> {
        match self.eat(kind) {
            Some(t) => Ok(t),
            None => self.expected(what),
        }
    }

    fn expect_name(&mut self, what: &str) -> PResult<(&'a str, Span)> {
        match self.peek() {
            Some(t) if t.kind == TokenKind::Ident => {
                self.pos += 1;
                Ok((self.slice(t.span), t.span))
            }
            _ => self.expected(what),
        }
    }

    /// Skips to the next statement after the failed one that began at token `start`: a
    /// token that starts a line outside any bracket opened since the error, or the `closer`
    /// of the enclosing construct (not consumed). Always makes progress past `start`.
    fn recover(&mut self, closer: TokenKind, start: usize) {
        if self.pos <= start {
            self.pos = start + 1;
        }
        let start = start + 1;
        let mut depth = 0usize;
        while let Some(t) = self.peek() {
            if self.pos >= start && depth == 0 && (t.line_start || t.kind == closer) {
                let statement_like =
                    matches!(t.kind, TokenKind::Ident | TokenKind::RBrace | TokenKind::RParen | TokenKind::String);
                if statement_like || t.kind == closer {
                    return;
                }
            }
            match t.kind {
                TokenKind::LParen | TokenKind::LBracket | TokenKind::LBrace => depth += 1,
                TokenKind::RParen | TokenKind::RBracket | TokenKind::RBrace => {
                    if depth == 0 && t.kind == closer {
                        return;
                    }
                    depth = depth.saturating_sub(1);
                }
                _ => {}
            }
            self.pos += 1;
        }
    }

    fn enter(&mut self) -> PResult<()> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            let span = self.here();
            self.error(Diagnostic::error("nesting too deep").at(span, format!("more than {MAX_DEPTH} levels")));
            self.skip_to_end();
            return Err(Reported);
        }
        Ok(())
    }

    fn leave(&mut self) {
        self.depth -= 1;
    }

    // ---- layer ----

    fn layer(&mut self) -> Layer {
        let mut layer = Layer { file: self.file, ..Layer::default() };
        if !self.text.starts_with("#usda ") {
            let end = self.text.find('\n').unwrap_or(self.text.len());
            let span = Span::new(self.file, 0, end);
            self.error(
                Diagnostic::error("not a USD ASCII file").at(span, "expected the `#usda 1.0` header on the first line"),
            );
            return layer;
        }
        if self.peek_kind() == Some(TokenKind::LParen) {
            match self.metadata_block() {
                Ok(entries) => layer.metadata = self.layer_metadata(entries),
                Err(Reported) => self.recover_to_prim(),
            }
        }
        while self.peek().is_some() {
            match self.prim() {
                Ok(prim) => layer.prims.push(prim),
                Err(Reported) => self.recover_to_prim(),
            }
        }
        layer
    }

    /// At the top level only prim statements can follow: skip to the next one.
    fn recover_to_prim(&mut self) {
        let mut depth = 0usize;
        let start = self.pos;
        while let Some(t) = self.peek() {
            if self.pos > start
                && depth == 0
                && t.line_start
                && matches!(self.peek_ident(), Some("def" | "over" | "class"))
            {
                return;
            }
            match t.kind {
                TokenKind::LParen | TokenKind::LBracket | TokenKind::LBrace => depth += 1,
                TokenKind::RParen | TokenKind::RBracket | TokenKind::RBrace => depth = depth.saturating_sub(1),
                _ => {}
            }
            self.pos += 1;
        }
    }

    fn layer_metadata(&mut self, entries: Vec<MetaEntry>) -> LayerMetadata {
        let mut meta = LayerMetadata::default();
        for entry in entries {
            let item = match entry {
                MetaEntry::Comment(c) => {
                    meta.comment = Some(c);
                    continue;
                }
                MetaEntry::Item(item) => item,
            };
            match (item.key.as_str(), item.value) {
                ("subLayers", MetaValue::SubLayers(layers)) => {
                    (meta.sub_layers, meta.sub_layer_offsets) =
                        layers.into_iter().map(|(asset, span, offset)| ((asset, span), offset)).unzip();
                }
                ("doc", MetaValue::Plain(v)) if v.as_str().is_some() => meta.doc = v.as_str().map(String::from),
                ("defaultPrim", MetaValue::Plain(v)) if v.as_str().is_some() => {
                    meta.default_prim = v.as_str().map(|s| (s.to_string(), item.value_span));
                }
                ("upAxis", MetaValue::Plain(v)) if v.as_str().is_some() => meta.up_axis = v.as_str().map(String::from),
                ("metersPerUnit", MetaValue::Plain(v)) if v.as_f64().is_some() => meta.meters_per_unit = v.as_f64(),
                (key @ ("doc" | "defaultPrim" | "upAxis" | "metersPerUnit"), _) => {
                    let message = format!("layer metadata `{key}` has the wrong type");
                    self.error(Diagnostic::error(message).at(item.value_span, "unexpected value"));
                }
                (_, MetaValue::Plain(value)) => {
                    meta.other.push(MetadataEntry { key: item.key, op: item.op, value, span: item.span })
                }
                _ => {}
            }
        }
        meta
    }

    // ---- metadata blocks ----

    /// `( entry* )` where entries are `[op] key = value` or a bare leading string.
    fn metadata_block(&mut self) -> PResult<Vec<MetaEntry>> {
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

    fn metadata_item(&mut self) -> PResult<MetaItem> {
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
    fn references(&mut self) -> PResult<Vec<Reference>> {
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
    fn reference(&mut self) -> PResult<Reference> {
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
    fn layer_offset(&mut self) -> PResult<LayerOffset> {
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
    fn sub_layers(&mut self) -> PResult<Vec<(AssetPath, Span, LayerOffset)>> {
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
    fn targets(&mut self) -> PResult<Option<Vec<Target>>> {
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

    // ---- prims ----

    /// `def|over|class [Type] "name" [( metadata )] { body }`.
    fn prim(&mut self) -> PResult<PrimSpec> {
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

    fn prim_metadata(&mut self, entries: Vec<MetaEntry>) -> PrimMetadata {
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
    fn prim_body(&mut self, prim: &mut PrimSpec) -> PResult<()> {
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
    fn variant_set(&mut self) -> PResult<VariantSetSpec> {
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

    // ---- properties ----

    /// An attribute or relationship statement, merged into `prim`'s property of that name.
    fn property(&mut self, prim: &mut PrimSpec, index: &mut PropertyIndex) -> PResult<()> {
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
    fn property_suffix(&mut self) -> PResult<Option<&'a str>> {
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

    fn relationship(
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

    fn property_metadata(&mut self, entries: Vec<MetaEntry>) -> Vec<MetadataEntry> {
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
    fn time_samples(&mut self, ty: &ValueType) -> PResult<Vec<(f64, Value)>> {
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

    // ---- values ----

    /// A value converted to the declared type; a mismatch is an error at the value.
    fn typed_value(&mut self, ty: &ValueType) -> PResult<(Value, Span)> {
        let (value, span) = self.value()?;
        match value.coerce(ty) {
            Ok(v) => Ok((v, span)),
            Err(message) => {
                self.error(Diagnostic::error("value does not match the declared type").at(span, message));
                Err(Reported)
            }
        }
    }

    /// Any value: number, string, asset, path, identifier, tuple, array or dictionary.
    fn value(&mut self) -> PResult<(Value, Span)> {
        let Some(token) = self.peek() else {
            return self.expected("a value");
        };
        let text = self.slice(token.span);
        let value = match token.kind {
            TokenKind::Number => number(text),
            TokenKind::Ident => match text {
                "None" => Value::None,
                "true" => Value::Bool(true),
                "false" => Value::Bool(false),
                "inf" => Value::Float(f64::INFINITY),
                "nan" => Value::Float(f64::NAN),
                _ => Value::Token(text.to_string()),
            },
            TokenKind::String => Value::String(unquote(text, false)),
            TokenKind::TripleString => Value::String(unquote(text, true)),
            TokenKind::Asset => Value::Asset(AssetPath::new(text.get(1..text.len() - 1).unwrap_or(""), self.base_dir)),
            TokenKind::TripleAsset => {
                let inner = text.get(3..text.len().saturating_sub(3)).unwrap_or("");
                Value::Asset(AssetPath::new(inner.replace("\\@@@", "@@@"), self.base_dir))
            }
            TokenKind::Path => Value::Path(path_text(text).to_string()),
            TokenKind::LParen => return self.tuple(),
            TokenKind::LBracket => return self.array(),
            TokenKind::LBrace => return self.dictionary(),
            _ => return self.expected("a value"),
        };
        self.pos += 1;
        Ok((value, token.span))
    }

    /// `( a, b, ... )`: a `Tuple` if every element is a number, else a `List`.
    fn tuple(&mut self) -> PResult<(Value, Span)> {
        let open = self.expect(TokenKind::LParen, "`(`")?;
        self.enter()?;
        let mut items = Vec::new();
        while self.eat(TokenKind::RParen).is_none() {
            items.push(self.value()?.0);
            if self.eat(TokenKind::Comma).is_none() {
                self.expect(TokenKind::RParen, "`,` or `)`")?;
                break;
            }
        }
        self.leave();
        let span = open.span.to(self.prev_span());
        let numeric: Option<Vec<f64>> = items
            .iter()
            .map(|v| match v {
                Value::Int(_) | Value::Float(_) => v.as_f64(),
                _ => None,
            })
            .collect();
        Ok((
            match numeric {
                Some(n) if !items.is_empty() => Value::Tuple(n),
                _ => Value::List(items),
            },
            span,
        ))
    }

    /// `[ ... ]`, accumulated straight into a typed flat array when the elements allow.
    fn array(&mut self) -> PResult<(Value, Span)> {
        let open = self.expect(TokenKind::LBracket, "`[`")?;
        self.enter()?;
        let mut acc = ArrayAcc::Empty;
        while self.eat(TokenKind::RBracket).is_none() {
            // Numeric tuples go directly into the flat buffer: no allocation per element.
            let start = self.pos;
            if let ArrayAcc::Empty | ArrayAcc::Tuples { .. } = acc
                && self.peek_kind() == Some(TokenKind::LParen)
                && let Some(values) = self.numeric_tuple()
            {
                match &mut acc {
                    ArrayAcc::Tuples { width, data } if *width == values.1 => {
                        data.extend_from_slice(&values.0);
                    }
                    ArrayAcc::Empty => acc = ArrayAcc::Tuples { width: values.1, data: values.0 },
                    _ => {
                        // Ragged tuples: fall back to the general path for this element.
                        self.pos = start;
                        let (value, _) = self.value()?;
                        acc.push(value);
                    }
                }
            } else {
                let (value, _) = self.value()?;
                acc.push(value);
            }
            if self.eat(TokenKind::Comma).is_none() {
                self.expect(TokenKind::RBracket, "`,` or `]`")?;
                break;
            }
        }
        self.leave();
        Ok((acc.finish(), open.span.to(self.prev_span())))
    }

    /// Reads `(n, n, ...)` of plain numbers, or rewinds and returns `None`.
    fn numeric_tuple(&mut self) -> Option<(Vec<f64>, usize)> {
        let start = self.pos;
        self.pos += 1;
        let mut values = Vec::with_capacity(4);
        loop {
            let token = self.peek()?;
            let number = match token.kind {
                TokenKind::Number => number(self.slice(token.span)).as_f64(),
                TokenKind::Ident => match self.slice(token.span) {
                    "inf" => Some(f64::INFINITY),
                    "nan" => Some(f64::NAN),
                    _ => None,
                },
                _ => None,
            };
            let Some(number) = number else {
                self.pos = start;
                return None;
            };
            values.push(number);
            self.pos += 1;
            if self.eat(TokenKind::Comma).is_some() {
                if self.eat(TokenKind::RParen).is_some() {
                    break;
                }
            } else if self.eat(TokenKind::RParen).is_some() {
                break;
            } else {
                self.pos = start;
                return None;
            }
        }
        let width = values.len();
        Some((values, width))
    }

    /// `{ TYPE key = value ... }` (dictionaries in metadata).
    fn dictionary(&mut self) -> PResult<(Value, Span)> {
        let open = self.expect(TokenKind::LBrace, "`{`")?;
        self.enter()?;
        let mut entries = Vec::new();
        loop {
            while self.eat(TokenKind::Semi).is_some() || self.eat(TokenKind::Comma).is_some() {}
            if self.eat(TokenKind::RBrace).is_some() {
                break;
            }
            let (type_word, _) = self.expect_name("a type name or `}`")?;
            let mut array = false;
            if self.eat(TokenKind::LBracket).is_some() {
                self.expect(TokenKind::RBracket, "`]`")?;
                array = true;
            }
            let key = match self.peek() {
                Some(t) if t.kind == TokenKind::Ident => self.slice(t.span).to_string(),
                Some(t) if t.kind == TokenKind::String => unquote(self.slice(t.span), false),
                _ => return self.expected("a dictionary key"),
            };
            self.pos += 1;
            self.expect(TokenKind::Eq, "`=`")?;
            let (value, _) = self.typed_value(&ValueType::parse(type_word, array))?;
            entries.push((key, value));
        }
        self.leave();
        Ok((Value::Dictionary(entries), open.span.to(self.prev_span())))
    }
}

/// Collects array elements into the most compact representation that holds them all.
enum ArrayAcc {
    Empty,
    Ints(Vec<i64>),
    Floats(Vec<f64>),
    Bools(Vec<bool>),
    Tuples { width: usize, data: Vec<f64> },
    Strings(Vec<String>),
    Assets(Vec<AssetPath>),
    Paths(Vec<String>),
    Other(Vec<Value>),
}

impl ArrayAcc {
    fn push(&mut self, value: Value) {
        match (&mut *self, value) {
            (ArrayAcc::Empty, Value::Int(i)) => *self = ArrayAcc::Ints(vec![i]),
            (ArrayAcc::Empty, Value::Float(f)) => *self = ArrayAcc::Floats(vec![f]),
            (ArrayAcc::Empty, Value::Bool(b)) => *self = ArrayAcc::Bools(vec![b]),
            (ArrayAcc::Empty, Value::String(s)) => *self = ArrayAcc::Strings(vec![s]),
            (ArrayAcc::Empty, Value::Asset(a)) => *self = ArrayAcc::Assets(vec![a]),
            (ArrayAcc::Empty, Value::Path(p)) => *self = ArrayAcc::Paths(vec![p]),
            (ArrayAcc::Empty, Value::Tuple(t)) => *self = ArrayAcc::Tuples { width: t.len(), data: t },
            (ArrayAcc::Empty, v) => *self = ArrayAcc::Other(vec![v]),
            (ArrayAcc::Ints(a), Value::Int(i)) => a.push(i),
            (ArrayAcc::Ints(a), Value::Float(f)) => {
                let mut floats: Vec<f64> = a.iter().map(|&i| i as f64).collect();
                floats.push(f);
                *self = ArrayAcc::Floats(floats);
            }
            (ArrayAcc::Floats(a), Value::Int(i)) => a.push(i as f64),
            (ArrayAcc::Floats(a), Value::Float(f)) => a.push(f),
            (ArrayAcc::Bools(a), Value::Bool(b)) => a.push(b),
            (ArrayAcc::Strings(a), Value::String(s)) => a.push(s),
            (ArrayAcc::Assets(a), Value::Asset(x)) => a.push(x),
            (ArrayAcc::Paths(a), Value::Path(p)) => a.push(p),
            (ArrayAcc::Tuples { width, data }, Value::Tuple(t)) if t.len() == *width => data.extend(t),
            (ArrayAcc::Other(a), v) => a.push(v),
            (_, v) => {
                let mut items = std::mem::replace(self, ArrayAcc::Empty).into_values();
                items.push(v);
                *self = ArrayAcc::Other(items);
            }
        }
    }

    /// The elements as individual values (for mixed arrays).
    fn into_values(self) -> Vec<Value> {
        match self {
            ArrayAcc::Empty => Vec::new(),
            ArrayAcc::Ints(a) => a.into_iter().map(Value::Int).collect(),
            ArrayAcc::Floats(a) => a.into_iter().map(Value::Float).collect(),
            ArrayAcc::Bools(a) => a.into_iter().map(Value::Bool).collect(),
            ArrayAcc::Tuples { width, data } => data.chunks(width.max(1)).map(|c| Value::Tuple(c.to_vec())).collect(),
            ArrayAcc::Strings(a) => a.into_iter().map(Value::String).collect(),
            ArrayAcc::Assets(a) => a.into_iter().map(Value::Asset).collect(),
            ArrayAcc::Paths(a) => a.into_iter().map(Value::Path).collect(),
            ArrayAcc::Other(a) => a,
        }
    }

    fn finish(self) -> Value {
        match self {
            ArrayAcc::Empty => Value::List(Vec::new()),
            ArrayAcc::Ints(a) => Value::IntArray(a),
            ArrayAcc::Floats(a) => Value::FloatArray(a),
            ArrayAcc::Bools(a) => Value::BoolArray(a),
            ArrayAcc::Tuples { width, data } => Value::TupleArray { width, data },
            ArrayAcc::Strings(a) => Value::StringArray(a),
            ArrayAcc::Assets(a) => Value::AssetArray(a),
            ArrayAcc::Paths(a) => Value::PathArray(a),
            ArrayAcc::Other(a) => Value::List(a),
        }
    }
}

/// An integer when the text has no fraction or exponent and fits, else a float.
fn number(text: &str) -> Value {
    if !text.contains(['.', 'e', 'E', 'i', 'n'])
        && let Ok(i) = text.parse::<i64>()
    {
        return Value::Int(i);
    }
    // The lexer only produces valid numbers (or `-inf`); `parse` accepts all of them.
    Value::Float(text.parse::<f64>().unwrap_or(f64::NAN))
}

/// The text between `<` and `>`.
fn path_text(text: &str) -> &str {
    text.get(1..text.len().saturating_sub(1)).unwrap_or("")
}

/// The strings of a string / token value or list of them (for `apiSchemas`, `variantSets`).
fn strings_of(value: Value) -> Vec<String> {
    match value {
        Value::String(s) | Value::Token(s) => vec![s],
        Value::StringArray(a) | Value::TokenArray(a) => a,
        _ => Vec::new(),
    }
}

/// Whether `name` is a valid prim name.
fn is_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(|c| c.is_alphabetic() || c == '_') && chars.all(|c| c.is_alphanumeric() || c == '_')
}

/// Shortens token text quoted in error messages.
fn truncate(text: &str) -> String {
    match text.char_indices().nth(40) {
        Some((i, _)) => format!("{}...", &text[..i]),
        None => text.to_string(),
    }
}

/// Strips the quotes of a string literal (`"`, `'` or triple) and processes escapes.
fn unquote(text: &str, triple: bool) -> String {
    let quote = if triple { 3 } else { 1 };
    let inner = text.get(quote..text.len().saturating_sub(quote)).unwrap_or("");
    if !inner.contains('\\') {
        return inner.to_string();
    }
    let mut out = String::with_capacity(inner.len());
    let mut chars = inner.chars().peekable();
    while let Some(c) = chars.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match chars.next() {
            Some('n') => out.push('\n'),
            Some('t') => out.push('\t'),
            Some('r') => out.push('\r'),
            Some('a') => out.push('\x07'),
            Some('b') => out.push('\x08'),
            Some('f') => out.push('\x0c'),
            Some('v') => out.push('\x0b'),
            Some('x') => {
                let mut code = 0u32;
                for _ in 0..2 {
                    match chars.peek().and_then(|c| c.to_digit(16)) {
                        Some(d) => {
                            code = code * 16 + d;
                            chars.next();
                        }
                        None => break,
                    }
                }
                out.push(char::from_u32(code).unwrap_or('\u{fffd}'));
            }
            Some(d @ '0'..='7') => {
                let mut code = d.to_digit(8).unwrap_or(0);
                for _ in 0..2 {
                    match chars.peek().and_then(|c| c.to_digit(8)) {
                        Some(d) => {
                            code = code * 8 + d;
                            chars.next();
                        }
                        None => break,
                    }
                }
                out.push(char::from_u32(code).unwrap_or('\u{fffd}'));
            }
            Some(other) => out.push(other),
            None => out.push('\\'),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diag::SourceMap;
    use crate::scene::usda::PropertySpec;

    fn parse_text(text: &str) -> (Layer, Diagnostics, SourceMap) {
        let mut sources = SourceMap::new();
        let file = sources.add("test.usda", text);
        let mut diags = Diagnostics::new();
        let layer = parse(file, text, Path::new("/scenes"), &mut diags);
        (layer, diags, sources)
    }

    fn parse_ok(text: &str) -> Layer {
        let (layer, diags, sources) = parse_text(text);
        assert!(!diags.has_errors(), "{}", diags.render(&sources));
        layer
    }

    fn attr<'l>(prim: &'l PrimSpec, name: &str) -> &'l AttributeSpec {
        match prim.property(name) {
            Some(PropertySpec::Attribute(a)) => a,
            other => panic!("no attribute {name}: {other:?}"),
        }
    }

    fn rel<'l>(prim: &'l PrimSpec, name: &str) -> &'l RelationshipSpec {
        match prim.property(name) {
            Some(PropertySpec::Relationship(r)) => r,
            other => panic!("no relationship {name}: {other:?}"),
        }
    }

    #[test]
    fn layer_metadata() {
        let layer = parse_ok(
            r#"#usda 1.0
(
    "a comment"
    doc = """Multi
line"""
    defaultPrim = "World"
    upAxis = "Z"
    metersPerUnit = 1
    subLayers = [@a.usda@, @./b.usda@ (offset = 10; scale = 2)]
    customLayerData = { string tool = "x" dictionary d = { int[] l = [1, 2] } }
    startTimeCode = 1
)
"#,
        );
        let m = &layer.metadata;
        assert_eq!(m.comment.as_deref(), Some("a comment"));
        assert_eq!(m.doc.as_deref(), Some("Multi\nline"));
        assert_eq!(m.default_prim.as_ref().map(|d| d.0.as_str()), Some("World"));
        assert_eq!(m.up_axis.as_deref(), Some("Z"));
        assert_eq!(m.meters_per_unit, Some(1.0));
        let subs: Vec<_> = m.sub_layers.iter().map(|(a, _)| a.resolved.clone()).collect();
        assert_eq!(m.sub_layer_offsets[0], LayerOffset::default());
        assert_eq!(m.sub_layer_offsets[1], LayerOffset { offset: 10.0, scale: 2.0 });
        assert_eq!(subs, vec![PathBuf::from("/scenes/a.usda"), PathBuf::from("/scenes/b.usda")]);
        assert_eq!(m.other.len(), 2);
        let custom = m.other[0].value.as_dictionary().unwrap();
        assert_eq!(custom[0], ("tool".to_string(), Value::String("x".into())));
        assert_eq!(custom[1].1.as_dictionary().unwrap()[0].1, Value::IntArray(vec![1, 2]));
    }

    use std::path::PathBuf;

    #[test]
    fn prims_and_prim_metadata() {
        let layer = parse_ok(
            r#"#usda 1.0
def Xform "World" (
    kind = "assembly"
    active = false
    instanceable = true
    doc = "d"
    prepend references = @./x.usda@</Prim>
    append payload = [@p.usda@, </Internal>]
    inherits = [</_class_A>, </_class_B>]
    prepend apiSchemas = ["MaterialBindingAPI"]
    variants = { string shading = "red" }
    prepend variantSets = "shading"
    hidden = true
)
{
    def "Child" { }
    over "O" { }
    class "C" { }
    reorder nameChildren = ["O", "Child"]
}
"#,
        );
        let world = &layer.prims[0];
        assert_eq!(world.specifier, Specifier::Def);
        assert_eq!(world.type_name.as_deref(), Some("Xform"));
        let m = &world.metadata;
        assert_eq!(m.kind.as_deref(), Some("assembly"));
        assert_eq!((m.active, m.instanceable), (Some(false), Some(true)));
        let r = &m.references.prepended[0];
        assert_eq!(r.asset.as_ref().unwrap().resolved, PathBuf::from("/scenes/x.usda"));
        assert_eq!(r.prim_path.as_deref(), Some("/Prim"));
        assert_eq!(m.payloads.appended.len(), 2);
        assert!(m.payloads.appended[1].asset.is_none());
        assert_eq!(m.inherits.explicit.as_ref().unwrap().len(), 2);
        assert_eq!(m.api_schemas.prepended, vec!["MaterialBindingAPI".to_string()]);
        assert_eq!(m.variant_selections[0].0, "shading");
        assert_eq!(m.variant_selections[0].1, "red");
        assert_eq!(m.variant_set_names.prepended, vec!["shading".to_string()]);
        assert_eq!(m.other[0].key, "hidden");
        let specs: Vec<_> = world.children.iter().map(|c| (c.specifier, c.name.as_str())).collect();
        assert_eq!(specs, vec![(Specifier::Def, "Child"), (Specifier::Over, "O"), (Specifier::Class, "C")]);
        assert_eq!(layer.prim_at("/World/O").map(|p| p.name.as_str()), Some("O"));
    }

    #[test]
    fn attributes_of_every_shape() {
        let layer = parse_ok(
            r#"#usda 1.0
def Mesh "M"
{
    uniform bool doubleSided = 1
    int[] faceVertexCounts = [4]
    point3f[] points = [(-1, 0, -1), (1, 0, -1), (1, 0, 1e2), (-1, 0, 1)]
    texCoord2f[] primvars:st = [(0, 0), (1, 0)] (
        interpolation = "faceVarying"
        elementSize = 1
        doc = """long
doc"""
    )
    float3 xformOp:scale
    custom double d = -inf
    float f = nan
    half h = 1
    string s = 'it\'s'
    token t = "tok"
    asset a = @@@we@ird@@@
    matrix4d xformOp:transform = ( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1, 5, 1) )
    quatf q = (1, 0, 0, 0)
    color3f c = (0.8, 0.1, 0.1)
    float[] empty = []
    token[] ops = ["xformOp:translate", "xformOp:scale"]
    float blocked = None
    float anim = 1
    float anim.timeSamples = { 0: 2, 10: 3.5, }
    token outputs:surface.connect = </Mat/Shader.outputs:surface>
    int64 big = -9000000000
    int2 i2 = (1, 2)
}
"#,
        );
        let m = &layer.prims[0];
        assert_eq!(attr(m, "doubleSided").default.as_ref().unwrap().0, Value::Bool(true));
        assert!(attr(m, "doubleSided").uniform);
        assert_eq!(attr(m, "faceVertexCounts").default.as_ref().unwrap().0, Value::IntArray(vec![4]));
        let points = &attr(m, "points").default.as_ref().unwrap().0;
        assert_eq!(points.as_tuple_array().map(|(w, d)| (w, d.len(), d[8])), Some((3, 12, 100.0)));
        let st = attr(m, "primvars:st");
        assert_eq!(st.type_name, "texCoord2f[]");
        assert_eq!(st.meta("interpolation"), Some(&Value::String("faceVarying".into())));
        assert_eq!(st.meta("elementSize"), Some(&Value::Int(1)));
        assert_eq!(st.meta("doc"), Some(&Value::String("long\ndoc".into())));
        assert!(attr(m, "xformOp:scale").default.is_none());
        assert_eq!(attr(m, "d").default.as_ref().unwrap().0, Value::Float(f64::NEG_INFINITY));
        assert!(attr(m, "f").default.as_ref().unwrap().0.as_f64().unwrap().is_nan());
        assert_eq!(attr(m, "h").default.as_ref().unwrap().0, Value::Float(1.0));
        assert_eq!(attr(m, "s").default.as_ref().unwrap().0, Value::String("it's".into()));
        assert_eq!(attr(m, "t").default.as_ref().unwrap().0, Value::Token("tok".into()));
        let a = attr(m, "a").default.as_ref().unwrap().0.as_asset().unwrap().clone();
        assert_eq!(a.authored, "we@ird");
        let xf = attr(m, "xformOp:transform").default.as_ref().unwrap().0.as_matrix4().copied();
        assert_eq!(xf.map(|x| (x[0], x[13], x[14])), Some((1.0, 1.0, 5.0)));
        assert_eq!(attr(m, "q").default.as_ref().unwrap().0.as_vec4(), Some([1.0, 0.0, 0.0, 0.0]));
        assert_eq!(attr(m, "c").default.as_ref().unwrap().0.as_vec3(), Some([0.8, 0.1, 0.1]));
        assert_eq!(attr(m, "empty").default.as_ref().unwrap().0, Value::FloatArray(vec![]));
        assert_eq!(
            attr(m, "ops").default.as_ref().unwrap().0,
            Value::TokenArray(vec!["xformOp:translate".into(), "xformOp:scale".into()])
        );
        assert_eq!(attr(m, "blocked").default.as_ref().unwrap().0, Value::None);
        let anim = attr(m, "anim");
        assert_eq!(anim.default.as_ref().unwrap().0, Value::Float(1.0));
        assert_eq!(anim.time_samples, vec![(0.0, Value::Float(2.0)), (10.0, Value::Float(3.5))]);
        let conn = &attr(m, "outputs:surface").connections;
        assert_eq!(conn.explicit.as_ref().unwrap()[0].0, "/Mat/Shader.outputs:surface");
        assert_eq!(attr(m, "big").default.as_ref().unwrap().0, Value::Int(-9_000_000_000));
        assert_eq!(attr(m, "i2").default.as_ref().unwrap().0, Value::Tuple(vec![1.0, 2.0]));
    }

    #[test]
    fn time_samples_are_read_quietly() {
        let (_, diags, sources) = parse_text("#usda 1.0\ndef \"A\" { float x.timeSamples = { 0: 1 } }\n");
        assert!(!diags.has_errors());
        assert_eq!(diags.render(&sources), "");
    }

    #[test]
    fn relationships_and_list_ops() {
        let layer = parse_ok(
            r#"#usda 1.0
def "A"
{
    custom rel material:slotBinding:_000 = </World/Looks/Plastic>
    custom rel material:slotBinding:_050 = None
    rel empty = []
    custom rel material:slotBinding:_050:_:_010 = [
        </World/Looks/Plastic>,
        </World/Looks/Plastic/Surface>,
    ]
    rel r
    delete rel r = </Gone>
    prepend rel r = </Root/Child>
    append rel r = </Other> (doc = "x")
    add rel r = [</Added>]
    reorder rel r = [</Other>, </Root/Child>]
}
"#,
        );
        let a = &layer.prims[0];
        let one = rel(a, "material:slotBinding:_000");
        assert_eq!(one.targets.explicit.as_ref().unwrap()[0].0, "/World/Looks/Plastic");
        assert!(one.custom);
        let none = rel(a, "material:slotBinding:_050");
        assert!(none.explicit_none);
        assert_eq!(none.targets.explicit, Some(vec![]));
        let empty = rel(a, "empty");
        assert!(!empty.explicit_none);
        assert_eq!(empty.targets.explicit, Some(vec![]));
        assert_eq!(rel(a, "material:slotBinding:_050:_:_010").targets.explicit.as_ref().unwrap().len(), 2);
        let r = rel(a, "r");
        assert_eq!(r.targets.deleted[0].0, "/Gone");
        assert_eq!(r.targets.prepended[0].0, "/Root/Child");
        assert_eq!(r.targets.appended[0].0, "/Other");
        assert_eq!(r.targets.added[0].0, "/Added");
        assert_eq!(r.targets.ordered.len(), 2);
        assert_eq!(r.metadata[0].key, "doc");
        // `rel r` alone authors no targets; the later list-op statements do.
        assert!(r.authored.is_some_and(|s| s != r.span));
        assert!(none.authored.is_some() && empty.authored.is_some());
    }

    #[test]
    fn declared_relationships_author_no_targets() {
        let text =
            "#usda 1.0\ndef \"A\" {\n    rel d\n    custom rel material:slotBinding:_é\n    prepend rel p = []\n}\n";
        let layer = parse_ok(text);
        assert!(rel(&layer.prims[0], "d").authored.is_none());
        assert!(rel(&layer.prims[0], "material:slotBinding:_é").authored.is_none());
        // An empty prepend is still an opinion about the targets.
        assert!(rel(&layer.prims[0], "p").authored.is_some());
    }

    #[test]
    fn target_spans_point_at_paths() {
        let text = "#usda 1.0\ndef \"A\" { rel r = [</X>, </Y/Z>] }\n";
        let layer = parse_ok(text);
        let r = rel(&layer.prims[0], "r");
        let spans: Vec<&str> =
            r.targets.explicit.as_ref().unwrap().iter().map(|(_, s)| &text[s.start as usize..s.end as usize]).collect();
        assert_eq!(spans, vec!["</X>", "</Y/Z>"]);
    }

    #[test]
    fn variant_sets() {
        let layer = parse_ok(
            r#"#usda 1.0
def "A" (
    variants = { string v = "x" }
    prepend variantSets = "v"
)
{
    variantSet "v" = {
        "x" (prepend references = </R>) {
            float a = 1
            def Sphere "S" { }
        }
        "y" {
        }
    }
}
"#,
        );
        let set = &layer.prims[0].variant_sets[0];
        assert_eq!(set.name, "v");
        assert_eq!(set.variants.len(), 2);
        assert_eq!(set.variants[0].name, "x");
        assert_eq!(set.variants[0].children[0].name, "S");
        assert_eq!(set.variants[0].metadata.references.prepended.len(), 1);
    }

    #[test]
    fn list_op_apply() {
        let mut list = vec!["a", "b", "c"];
        let mut op = ListOp::default();
        op.set(ListOpKind::Delete, vec!["b"]);
        op.set(ListOpKind::Prepend, vec!["c", "x"]);
        op.set(ListOpKind::Append, vec!["a"]);
        op.set(ListOpKind::Add, vec!["y", "c"]);
        assert!(!op.apply(&mut list, |a, b| a == b));
        assert_eq!(list, vec!["c", "x", "y", "a"]);
        let mut reorder = ListOp::default();
        reorder.set(ListOpKind::Reorder, vec!["a", "x"]);
        reorder.apply(&mut list, |a, b| a == b);
        assert_eq!(list, vec!["c", "a", "x", "y"]);
        let mut explicit = ListOp::default();
        explicit.set(ListOpKind::Explicit, vec![]);
        assert!(explicit.apply(&mut list, |a, b| a == b));
        assert!(list.is_empty());
    }

    #[test]
    fn errors_have_locations_and_recover() {
        let text = "#usda 1.0\ndef \"A\"\n{\n    float x = \"nope\"\n    float3 y = (1, 2\n    def \"B\" { int z = [1 }\n}\ndef \"C\" { }\n";
        let (layer, diags, sources) = parse_text(text);
        assert!(diags.error_count() >= 2, "{}", diags.render(&sources));
        let rendered = diags.render(&sources);
        assert!(rendered.contains("test.usda:4:15"), "{rendered}");
        assert!(rendered.contains("float x = \"nope\""), "{rendered}");
        // Recovery keeps later prims.
        assert!(layer.prims.iter().any(|p| p.name == "C"), "{layer:?}");
    }

    #[test]
    fn missing_header_is_an_error() {
        let (_, diags, sources) = parse_text("def \"A\" {}\n");
        assert!(diags.render(&sources).contains("#usda 1.0"));
    }

    #[test]
    fn unquote_escapes() {
        assert_eq!(unquote(r#""a\"b\n\x41\101\\""#, false), "a\"b\nAA\\");
        assert_eq!(unquote("'''x\\'''y'''", true), "x'''y");
    }
}
