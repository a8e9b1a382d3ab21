//! Tokens of the USD ASCII format (`.usda`), produced with logos.
//!
//! Keywords (`def`, `rel`, `uniform`, ...) are lexed as plain identifiers and recognised by
//! the parser, because USD allows most of them as property or dictionary names too.
//! Comments (`#`, `//`, `/* */`) and whitespace are skipped; the `#usda 1.0` header is a
//! comment to the lexer and is checked by the parser on the raw text.

use crate::diag::{FileId, Span};
use logos::{Lexer, Logos};

/// The kind of one token.
#[derive(Logos, Clone, Copy, Debug, PartialEq, Eq)]
#[logos(skip r"[ \t\r\n\f]+")]
// A comment runs to the end of its line, so the greedy repetition is what we want.
#[logos(skip(r"(#|//)[^\n]*", allow_greedy = true))]
// Each variant is named after the token its `#[token]`/`#[regex]` attribute spells.
#[allow(missing_docs)]
pub enum TokenKind {
    /// `(`
    #[token("(")]
    LParen,
    /// `)`
    #[token(")")]
    RParen,
    /// `[`
    #[token("[")]
    LBracket,
    /// `]`
    #[token("]")]
    RBracket,
    /// `{`
    #[token("{")]
    LBrace,
    /// `}`
    #[token("}")]
    RBrace,
    /// `=`
    #[token("=")]
    Eq,
    /// `,`
    #[token(",")]
    Comma,
    /// `:` (time-sample keys; namespaced names are single identifiers)
    #[token(":")]
    Colon,
    /// `;` (optional statement separator in metadata)
    #[token(";")]
    Semi,
    /// `.` (as in `name.timeSamples`)
    #[token(".")]
    Dot,
    /// An identifier, possibly namespaced: `xformOp:translate`, `def`, `inf`. Identifiers are
    /// UTF-8 as in USD (`XID_Start` or `_`, then `XID_Continue`): `material:slotBinding:_é`.
    #[regex(r"[\p{XID_Start}_]\p{XID_Continue}*", namespaces)]
    Ident,
    /// A number: `1`, `-2.5e-3`, `-inf` (`inf` and `nan` alone are identifiers).
    #[regex(r"[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][-+]?[0-9]+)?")]
    #[token("-inf")]
    Number,
    /// A single-line string in `"` or `'` quotes, escapes not yet processed.
    #[token("\"", |lex| crate::diag::text::close_quoted(lex, b'"'))]
    #[token("'", |lex| crate::diag::text::close_quoted(lex, b'\''))]
    String,
    /// A block comment: skipped when closed, an error to the end of the file when not.
    #[token("/*", crate::diag::text::skip_block_comment)]
    BlockComment,
    /// A triple-quoted string (`"""` or `'''`), which may span lines.
    #[token("\"\"\"", |lex| close_triple(lex, "\"\"\""))]
    #[token("'''", |lex| close_triple(lex, "'''"))]
    TripleString,
    /// An asset path `@path@`.
    #[regex(r"@[^@\n]*@")]
    Asset,
    /// An asset path `@@@path@@@`, which may contain `@`.
    #[token("@@@", |lex| close_triple(lex, "@@@"))]
    TripleAsset,
    /// A scene path `</a/b.prop>`.
    #[regex(r"<[^<>\n]*>")]
    Path,
}

/// Extends an identifier over its `:name` namespace parts. A loop here, rather than a
/// repetition in the regex: logos turns a repeated group into one stack frame per
/// repetition in unoptimised builds, and a property name of 100 000 parts overflowed it.
fn namespaces(lex: &mut Lexer<TokenKind>) {
    let rest = lex.remainder();
    let mut end = 0;
    loop {
        let mut chars = rest[end..].chars();
        if chars.next() != Some(':') {
            break;
        }
        match chars.next() {
            Some(c) if c == '_' || unicode_ident::is_xid_start(c) => {}
            _ => break,
        }
        let part = &rest[end + 1..];
        let len = part
            .char_indices()
            .skip(1)
            .find(|&(_, c)| !unicode_ident::is_xid_continue(c))
            .map_or(part.len(), |(i, _)| i);
        end += 1 + len;
    }
    lex.bump(end);
}

/// Extends the current token to the closing delimiter, honouring backslash escapes.
/// Returns `false` (a lexing error) when the delimiter never comes.
fn close_triple(lex: &mut Lexer<TokenKind>, close: &str) -> bool {
    let rest = lex.remainder().as_bytes();
    let mut i = 0;
    while i < rest.len() {
        if rest[i] == b'\\' {
            i += 2;
            continue;
        }
        if rest[i..].starts_with(close.as_bytes()) {
            // `@@@a@@@@` closes at the last run of `@`: USD keeps extra `@` in the path.
            let mut end = i + close.len();
            if close == "@@@" {
                while rest.get(end) == Some(&b'@') {
                    end += 1;
                }
            }
            lex.bump(end);
            return true;
        }
        i += 1;
    }
    lex.bump(rest.len());
    false
}

/// One token with its location.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Token {
    /// What kind of token.
    pub kind: TokenKind,
    /// Where it is.
    pub span: Span,
    /// Whether a line break separates it from the previous token; used for error recovery.
    pub line_start: bool,
}

/// The result of lexing a whole file: tokens plus the spans of unrecognised text.
#[derive(Debug, Default)]
pub struct Lexed {
    /// Recognised tokens in order.
    pub tokens: Vec<Token>,
    /// Spans of text no token matches (including unterminated strings).
    pub errors: Vec<Span>,
}

/// Tokens of `text` one at a time, with the spans of unrecognised text between them: the
/// parser pulls from this, so a 140 MB array is never held as 70 million tokens at once.
pub struct TokenStream<'a> {
    lexer: Lexer<'a, TokenKind>,
    text: &'a str,
    file: FileId,
    prev_end: usize,
}

impl<'a> TokenStream<'a> {
    /// A stream over `text`, the contents of `file`.
    pub fn new(file: FileId, text: &'a str) -> TokenStream<'a> {
        TokenStream { lexer: TokenKind::lexer(text), text, file, prev_end: 0 }
    }
}

impl Iterator for TokenStream<'_> {
    /// A token, or the span of text no token matches.
    type Item = Result<Token, Span>;

    fn next(&mut self) -> Option<Self::Item> {
        let result = self.lexer.next()?;
        let range = self.lexer.span();
        let gap = self.text.get(self.prev_end..range.start).unwrap_or("");
        let line_start = self.prev_end == 0 || gap.contains('\n');
        self.prev_end = range.end;
        let span = Span::new(self.file, range.start, range.end);
        Some(match result {
            Ok(kind) => Ok(Token { kind, span, line_start }),
            Err(()) => Err(span),
        })
    }
}

/// The spans of text no token matches, adjacent bad bytes merged into one span.
pub fn lex_errors(file: FileId, text: &str) -> Vec<Span> {
    let mut errors: Vec<Span> = Vec::new();
    for span in TokenStream::new(file, text).filter_map(Result::err) {
        match errors.last_mut() {
            Some(last) if last.end == span.start => last.end = span.end,
            _ => errors.push(span),
        }
    }
    errors
}

/// Splits `text` into tokens.
pub fn lex(file: FileId, text: &str) -> Lexed {
    let mut out = Lexed::default();
    for result in TokenStream::new(file, text) {
        match result {
            Ok(token) => out.tokens.push(token),
            // Merge adjacent bad bytes into one error span.
            Err(span) => match out.errors.last_mut() {
                Some(last) if last.end == span.start => last.end = span.end,
                _ => out.errors.push(span),
            },
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds(text: &str) -> Vec<(TokenKind, &str)> {
        let lexed = lex(FileId(0), text);
        assert!(lexed.errors.is_empty(), "errors: {:?}", lexed.errors);
        lexed.tokens.iter().map(|t| (t.kind, &text[t.span.start as usize..t.span.end as usize])).collect()
    }

    #[test]
    fn punctuation_idents_numbers() {
        use TokenKind::*;
        assert_eq!(
            kinds("def Xform \"a\" ( ) { } [ ] = , : ; . xformOp:translate -1.5e-3 2 .5 -inf inf nan"),
            vec![
                (Ident, "def"),
                (Ident, "Xform"),
                (String, "\"a\""),
                (LParen, "("),
                (RParen, ")"),
                (LBrace, "{"),
                (RBrace, "}"),
                (LBracket, "["),
                (RBracket, "]"),
                (Eq, "="),
                (Comma, ","),
                (Colon, ":"),
                (Semi, ";"),
                (Dot, "."),
                (Ident, "xformOp:translate"),
                (Number, "-1.5e-3"),
                (Number, "2"),
                (Number, ".5"),
                (Number, "-inf"),
                (Ident, "inf"),
                (Ident, "nan"),
            ]
        );
    }

    #[test]
    fn strings_assets_paths_comments() {
        use TokenKind::*;
        let text = "#usda 1.0\n'a\\'b' \"\" \"\"\"x\n\\\"y\"\"\" '''z''' @a b.png@ @@ @@@w@x@@@ </A/B.outputs:c> # c\n// d\n/* e\n*/ name.timeSamples";
        assert_eq!(
            kinds(text),
            vec![
                (String, "'a\\'b'"),
                (String, "\"\""),
                (TripleString, "\"\"\"x\n\\\"y\"\"\""),
                (TripleString, "'''z'''"),
                (Asset, "@a b.png@"),
                (Asset, "@@"),
                (TripleAsset, "@@@w@x@@@"),
                (Path, "</A/B.outputs:c>"),
                (Ident, "name"),
                (Dot, "."),
                (Ident, "timeSamples"),
            ]
        );
    }

    #[test]
    fn utf8_identifiers() {
        use TokenKind::*;
        assert_eq!(
            kinds("rel material:slotBinding:_é:_:_Ａ1 Grüße:名前 _"),
            vec![(Ident, "rel"), (Ident, "material:slotBinding:_é:_:_Ａ1"), (Ident, "Grüße:名前"), (Ident, "_")]
        );
        // Not identifier characters: a digit cannot start an element, `·` cannot start one.
        assert_eq!(kinds("a:b1")[0], (Ident, "a:b1"));
        assert!(!lex(FileId(0), "a:·b").errors.is_empty());
    }

    #[test]
    fn line_starts_and_errors() {
        let lexed = lex(FileId(0), "a b\nc $$ \"open\n\"\"\"never closed");
        let starts: Vec<bool> = lexed.tokens.iter().map(|t| t.line_start).collect();
        assert_eq!(starts, vec![true, false, true]);
        assert_eq!(lexed.errors.len(), 3, "{:?}", lexed.errors);
    }

    #[test]
    fn huge_tokens_lex_without_recursion() {
        // Each once overflowed a debug build's stack (one frame per repetition).
        let name = format!("a{}", ":b".repeat(200_000));
        assert_eq!(kinds(&name), vec![(TokenKind::Ident, name.as_str())]);
        let comment = format!("/*{}*/", "*a".repeat(300_000));
        assert_eq!(kinds(&comment), vec![]);
        let string = format!("'{}'", "\\a".repeat(300_000));
        assert_eq!(kinds(&string).len(), 1);
        assert!(!lex(FileId(0), &format!("/*{}", "*a".repeat(1000))).errors.is_empty());
        assert!(!lex(FileId(0), "\"unterminated\n").errors.is_empty());
    }
}
