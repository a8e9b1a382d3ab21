//! Tokens of the shading language, produced by a logos-generated lexer.

use crate::diag::{Diagnostic, Diagnostics, FileId, Span};
use logos::Logos;

/// The kind of one token. Payloads (identifier names, literal values) are read back from the
/// source text through the token's span.
#[derive(Logos, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[logos(skip r"[ \t\r\n\f]+")]
#[logos(skip(r"//[^\n]*", allow_greedy = true))]
// Each variant is named after the token its `#[token]`/`#[regex]` attribute spells.
#[allow(missing_docs)]
pub enum Tok {
    #[token("shader")]
    Shader,
    #[token("substance")]
    Substance,
    #[token("override")]
    Override,
    #[token("node")]
    Node,
    #[token("input")]
    Input,
    #[token("output")]
    Output,
    #[token("import")]
    Import,
    #[token("if")]
    If,
    #[token("else")]
    Else,
    #[token("for")]
    For,
    #[token("while")]
    While,
    #[token("break")]
    Break,
    #[token("continue")]
    Continue,
    #[token("return")]
    Return,
    #[token("float")]
    Float,
    #[token("int")]
    Int,
    #[token("color")]
    Color,
    #[token("point")]
    Point,
    #[token("vector")]
    Vector,
    #[token("normal")]
    Normal,
    #[token("string")]
    String,
    #[token("closure")]
    Closure,
    #[token("void")]
    Void,

    #[regex("[A-Za-z_][A-Za-z0-9_]*")]
    Ident,
    #[regex("[0-9]+", priority = 3)]
    IntLit,
    #[regex(r"([0-9]+\.[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?|[0-9]+[eE][+-]?[0-9]+")]
    FloatLit,
    #[token("\"", |lex| crate::diag::text::close_quoted(lex, b'"'))]
    StrLit,
    /// A block comment: skipped when closed, an error to the end of the file when not.
    #[token("/*", crate::diag::text::skip_block_comment)]
    BlockComment,

    #[token("(")]
    LParen,
    #[token(")")]
    RParen,
    #[token("{")]
    LBrace,
    #[token("}")]
    RBrace,
    #[token("[")]
    LBracket,
    #[token("]")]
    RBracket,
    #[token(",")]
    Comma,
    #[token(";")]
    Semi,
    #[token(":")]
    Colon,
    #[token(".")]
    Dot,
    #[token("?")]
    Question,
    #[token("=")]
    Assign,
    #[token("+=")]
    PlusAssign,
    #[token("-=")]
    MinusAssign,
    #[token("*=")]
    StarAssign,
    #[token("/=")]
    SlashAssign,
    #[token("++")]
    PlusPlus,
    #[token("--")]
    MinusMinus,
    #[token("+")]
    Plus,
    #[token("-")]
    Minus,
    #[token("*")]
    Star,
    #[token("/")]
    Slash,
    #[token("%")]
    Percent,
    #[token("==")]
    EqEq,
    #[token("!=")]
    NotEq,
    #[token("<")]
    Lt,
    #[token("<=")]
    Le,
    #[token(">")]
    Gt,
    #[token(">=")]
    Ge,
    #[token("&&")]
    AndAnd,
    #[token("||")]
    OrOr,
    #[token("!")]
    Bang,

    /// End of input (synthesised, never produced by logos).
    Eof,
}

impl Tok {
    /// How the token reads in a diagnostic ("expected `;`").
    pub fn describe(self) -> &'static str {
        use Tok::*;
        match self {
            Shader => "`shader`",
            Substance => "`substance`",
            Override => "`override`",
            Node => "`node`",
            Input => "`input`",
            Output => "`output`",
            Import => "`import`",
            If => "`if`",
            Else => "`else`",
            For => "`for`",
            While => "`while`",
            Break => "`break`",
            Continue => "`continue`",
            Return => "`return`",
            Float => "`float`",
            Int => "`int`",
            Color => "`color`",
            Point => "`point`",
            Vector => "`vector`",
            Normal => "`normal`",
            String => "`string`",
            Closure => "`closure`",
            Void => "`void`",
            Ident => "an identifier",
            IntLit => "an integer",
            FloatLit => "a number",
            StrLit => "a string",
            BlockComment => "a comment",
            LParen => "`(`",
            RParen => "`)`",
            LBrace => "`{`",
            RBrace => "`}`",
            LBracket => "`[`",
            RBracket => "`]`",
            Comma => "`,`",
            Semi => "`;`",
            Colon => "`:`",
            Dot => "`.`",
            Question => "`?`",
            Assign => "`=`",
            PlusAssign => "`+=`",
            MinusAssign => "`-=`",
            StarAssign => "`*=`",
            SlashAssign => "`/=`",
            PlusPlus => "`++`",
            MinusMinus => "`--`",
            Plus => "`+`",
            Minus => "`-`",
            Star => "`*`",
            Slash => "`/`",
            Percent => "`%`",
            EqEq => "`==`",
            NotEq => "`!=`",
            Lt => "`<`",
            Le => "`<=`",
            Gt => "`>`",
            Ge => "`>=`",
            AndAnd => "`&&`",
            OrOr => "`||`",
            Bang => "`!`",
            Eof => "end of file",
        }
    }
}

/// One token with its location.
#[derive(Clone, Copy, Debug)]
pub struct Token {
    /// What it is.
    pub kind: Tok,
    /// Where it is.
    pub span: Span,
}

/// Splits `text` into tokens, ending with [`Tok::Eof`]. Unrecognised characters are reported
/// and skipped so parsing can go on.
pub fn lex(file: FileId, text: &str, diags: &mut Diagnostics) -> Vec<Token> {
    let mut tokens = Vec::new();
    let mut lexer = Tok::lexer(text);
    while let Some(result) = lexer.next() {
        let range = lexer.span();
        let span = Span::new(file, range.start, range.end);
        match result {
            // An unclosed `/*` runs to the end of the file.
            Err(()) if text[range.clone()].starts_with("/*") => {
                let span = Span::new(file, range.start, range.start + 2);
                diags.push(Diagnostic::error("unterminated block comment").at(span, "no `*/` closes this comment"));
                break;
            }
            Ok(kind) => tokens.push(Token { kind, span }),
            Err(()) => {
                let what = &text[range.clone()];
                let message = if what.starts_with('"') {
                    "unterminated string literal".to_string()
                } else {
                    format!("unexpected character `{}`", what.escape_debug())
                };
                diags.push(Diagnostic::error(message).at(span, "not part of the language"));
            }
        }
    }
    let end = text.len();
    tokens.push(Token { kind: Tok::Eof, span: Span::new(file, end, end) });
    tokens
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds(text: &str) -> Vec<Tok> {
        let mut diags = Diagnostics::new();
        let toks = lex(FileId(0), text, &mut diags);
        assert!(!diags.has_errors(), "{:?}", diags);
        toks.into_iter().map(|t| t.kind).collect()
    }

    #[test]
    fn numbers_keywords_and_comments() {
        use Tok::*;
        assert_eq!(
            kinds("float x = 1.5e3 + 2 // c\n /* block */ .5 3."),
            vec![Float, Ident, Assign, FloatLit, Plus, IntLit, FloatLit, FloatLit, Eof]
        );
        assert_eq!(kinds("a+=b++<=c"), vec![Ident, PlusAssign, Ident, PlusPlus, Le, Ident, Eof]);
        assert_eq!(kinds("\"a\\\"b\""), vec![StrLit, Eof]);
    }

    #[test]
    fn bad_characters_are_reported_not_fatal() {
        let mut diags = Diagnostics::new();
        let toks = lex(FileId(0), "a $ b", &mut diags);
        assert_eq!(diags.error_count(), 1);
        assert_eq!(toks.len(), 3);
    }

    #[test]
    fn unterminated_comments_and_strings_are_named() {
        for (text, message, start) in [
            ("a /* b", "unterminated block comment", 2),
            ("a /* b * / c", "unterminated block comment", 2),
            ("a \"b", "unterminated string literal", 2),
        ] {
            let mut diags = Diagnostics::new();
            let toks = lex(FileId(0), text, &mut diags);
            assert_eq!(diags.error_count(), 1, "{text}: {diags:?}");
            let d = &diags.items()[0];
            assert_eq!((d.message.as_str(), d.labels[0].span.start), (message, start), "{text}");
            assert_eq!(toks.first().map(|t| t.kind), Some(Tok::Ident), "{text}");
        }
        // Only an adjacent `/*` opens a comment.
        assert_eq!(kinds("a / * b"), vec![Tok::Ident, Tok::Slash, Tok::Star, Tok::Ident, Tok::Eof]);
    }

    #[test]
    fn huge_comments_and_strings_lex_without_recursion() {
        // Each once overflowed a debug build's stack (one frame per repetition).
        let comment = format!("/*{}*/ x", "*a".repeat(300_000));
        assert_eq!(kinds(&comment), vec![Tok::Ident, Tok::Eof]);
        let string = format!("\"{}\"", "\\a".repeat(300_000));
        assert_eq!(kinds(&string), vec![Tok::StrLit, Tok::Eof]);
        let mut diags = Diagnostics::new();
        lex(FileId(0), &format!("x /*{}", "*a".repeat(300_000)), &mut diags);
        assert!(diags.has_errors());
    }
}
