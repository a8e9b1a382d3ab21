//! Values: scalars, tuples, arrays (collected into the most compact representation) and
//! dictionaries; number and string literals.

use super::{PResult, Parser, Reported, path_text};
use crate::diag::{Diagnostic, Span};
use crate::scene::usda::lexer::TokenKind;
use crate::scene::value::{AssetPath, Value, ValueType};

impl<'a> Parser<'a, '_> {
    /// A value converted to the declared type; a mismatch is an error at the value.
    pub(super) fn typed_value(&mut self, ty: &ValueType) -> PResult<(Value, Span)> {
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
    pub(super) fn value(&mut self) -> PResult<(Value, Span)> {
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
    pub(super) fn tuple(&mut self) -> PResult<(Value, Span)> {
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
    pub(super) fn array(&mut self) -> PResult<(Value, Span)> {
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
    pub(super) fn numeric_tuple(&mut self) -> Option<(Vec<f64>, usize)> {
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
    pub(super) fn dictionary(&mut self) -> PResult<(Value, Span)> {
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
pub(super) enum ArrayAcc {
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
    pub(super) fn push(&mut self, value: Value) {
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
    pub(super) fn into_values(self) -> Vec<Value> {
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

    pub(super) fn finish(self) -> Value {
        match self {
            ArrayAcc::Empty => Value::List(Vec::new()),
            ArrayAcc::Ints(a) => Value::IntArray(a.into()),
            ArrayAcc::Floats(a) => Value::FloatArray(a.into()),
            ArrayAcc::Bools(a) => Value::BoolArray(a),
            ArrayAcc::Tuples { width, data } => Value::TupleArray { width, data: data.into() },
            ArrayAcc::Strings(a) => Value::StringArray(a),
            ArrayAcc::Assets(a) => Value::AssetArray(a),
            ArrayAcc::Paths(a) => Value::PathArray(a),
            ArrayAcc::Other(a) => Value::List(a),
        }
    }
}

/// An integer when the text has no fraction or exponent and fits, else a float.
pub(super) fn number(text: &str) -> Value {
    if !text.contains(['.', 'e', 'E', 'i', 'n'])
        && let Ok(i) = text.parse::<i64>()
    {
        return Value::Int(i);
    }
    // The lexer only produces valid numbers (or `-inf`); `parse` accepts all of them.
    Value::Float(text.parse::<f64>().unwrap_or(f64::NAN))
}

/// Strips the quotes of a string literal (`"`, `'` or triple) and processes escapes.
pub(super) fn unquote(text: &str, triple: bool) -> String {
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
