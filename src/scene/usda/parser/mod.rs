//! Recursive-descent parser from `.usda` tokens to a [`Layer`].
//!
//! Errors are reported into [`Diagnostics`] and the parser recovers at the next statement
//! (a token at the start of a line, outside any brackets), so one run reports several
//! problems. The result is always a layer, possibly partial.
//!
//! This module holds the token window, recovery and the layer; `metadata`, `prims`,
//! `properties` and `values` parse those parts of the grammar.

use super::lexer::{Token, TokenKind, TokenStream, lex_errors};
use super::{Layer, LayerMetadata, LayerOffset, ListOpKind, MetadataEntry, Reference, Target};
use crate::diag::{Diagnostic, Diagnostics, FileId, Span};
use crate::scene::value::{AssetPath, Value};
use std::cell::RefCell;
use std::collections::HashMap;
use std::collections::VecDeque;
use std::path::Path;

mod metadata;
mod prims;
mod properties;
mod values;

/// A prim body's property names → positions in its `properties`.
type PropertyIndex = HashMap<String, usize>;

/// Past this many errors in one file the parser stops: the rest is likely noise.
const MAX_ERRORS: usize = 50;
/// Bracket nesting deeper than this is rejected instead of risking the stack.
const MAX_DEPTH: usize = 200;

/// Parses `text` (the contents of `file`) into a layer. Asset paths are resolved against
/// `base_dir`, the directory of the file.
pub fn parse(file: FileId, text: &str, base_dir: &Path, diags: &mut Diagnostics) -> Layer {
    // Unrecognised text is reported before any parse error. Most files have none: they are
    // lexed once, as the parser pulls tokens through a bounded window. A file with some (or
    // one the parser gave up on before its end, whose rest is unknown) is parsed again, its
    // unrecognised text found by a pass that keeps nothing else and reported first.
    let mut first = Diagnostics::new();
    let (layer, lexed_clean) = parse_pass(file, text, base_dir, &mut first, Vec::new());
    if lexed_clean {
        diags.extend(first);
        return layer;
    }
    drop(layer);
    parse_pass(file, text, base_dir, diags, lex_errors(file, text)).0
}

/// Parses `text` after reporting `lex_errors`; also whether every token was lexed and none
/// was unrecognised.
fn parse_pass(
    file: FileId,
    text: &str,
    base_dir: &Path,
    diags: &mut Diagnostics,
    lex_errors: Vec<Span>,
) -> (Layer, bool) {
    let tokens = RefCell::new(TokenWindow::new(TokenStream::new(file, text)));
    let mut parser = Parser { text, file, tokens, pos: 0, base_dir, diags, errors: 0, depth: 0 };
    for span in lex_errors {
        parser.error(Diagnostic::error("unrecognised text").at(span, "not valid in a .usda file"));
    }
    let layer = parser.layer();
    let window = parser.tokens.borrow();
    (layer, window.exhausted && !window.unrecognised)
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
    /// The stream ended (every token was lexed).
    exhausted: bool,
    /// Some text matched no token.
    unrecognised: bool,
}

impl<'a> TokenWindow<'a> {
    /// Tokens kept behind the one asked for.
    const KEEP: usize = 1 << 16;

    fn new(stream: TokenStream<'a>) -> TokenWindow<'a> {
        TokenWindow { stream, base: 0, buffer: VecDeque::new(), done: false, exhausted: false, unrecognised: false }
    }

    /// Token `at`, lexing up to it; `None` past the end or before the window.
    fn get(&mut self, at: usize) -> Option<Token> {
        while !self.done && self.base + self.buffer.len() <= at {
            match self.stream.next() {
                Some(Ok(token)) => self.buffer.push_back(token),
                Some(Err(_)) => self.unrecognised = true, // reported before parsing
                None => (self.done, self.exhausted) = (true, true),
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

#[cfg(test)]
mod tests;
