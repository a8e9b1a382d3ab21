//! Scanning helpers both lexers share. Block comments and quoted strings are scanned by these
//! loops rather than by regex repetitions: logos turns a repeated alternation (`([^*]|\*+[^*/])*`,
//! `([^"\\]|\\.)*`) into one stack frame per repetition in unoptimised builds, so a 100 KB
//! comment or string overflowed the stack of a debug build.

/// Length of a block comment's body and its closing `*/`, given the text after the opening
/// `/*`; `None` when no `*/` closes it.
pub fn block_comment_len(rest: &str) -> Option<usize> {
    rest.find("*/").map(|i| i + 2)
}

/// Length of a single-line quoted string's body and closing quote, given the text after the
/// opening `quote`; a backslash escapes the next character (but not a line break). `None`
/// when the line or the text ends first.
pub fn quoted_len(rest: &str, quote: u8) -> Option<usize> {
    let bytes = rest.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'\n' => return None,
            b'\\' if bytes.get(i + 1).is_some_and(|&c| c != b'\n') => i += 2,
            c if c == quote => return Some(i + 1),
            _ => i += 1,
        }
    }
    None
}

/// Skips a closed block comment (a logos callback on the `/*` token); an unclosed one is an
/// error spanning the rest of the file.
pub fn skip_block_comment<'s, T: logos::Logos<'s, Source = str>>(
    lex: &mut logos::Lexer<'s, T>,
) -> logos::FilterResult<(), ()> {
    let rest = lex.remainder();
    match block_comment_len(rest) {
        Some(n) => {
            lex.bump(n);
            logos::FilterResult::Skip
        }
        None => {
            lex.bump(rest.len());
            logos::FilterResult::Error(())
        }
    }
}

/// Extends a string token (a logos callback on its opening `quote`) to its closing quote,
/// or, unterminated, to the end of its line, which makes it an error.
pub fn close_quoted<'s, T: logos::Logos<'s, Source = str>>(lex: &mut logos::Lexer<'s, T>, quote: u8) -> bool {
    let rest = lex.remainder();
    let len = quoted_len(rest, quote);
    lex.bump(len.unwrap_or_else(|| line_len(rest)));
    len.is_some()
}

/// Length of the text up to (not including) the next line break, or all of it.
pub fn line_len(rest: &str) -> usize {
    rest.find('\n').unwrap_or(rest.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comments_and_strings() {
        assert_eq!(block_comment_len(" a ** b */ c"), Some(10));
        assert_eq!(block_comment_len(" a "), None);
        assert_eq!(quoted_len(r#"a\"b" c"#, b'"'), Some(5));
        assert_eq!(quoted_len("a\nb\"", b'"'), None);
        assert_eq!(quoted_len("a\\", b'"'), None);
        assert_eq!(quoted_len("it's'", b'\''), Some(3));
        // 1 MB of escapes: a loop, not a recursion.
        let long = "\\a".repeat(500_000) + "\"";
        assert_eq!(quoted_len(&long, b'"'), Some(long.len()));
    }
}
