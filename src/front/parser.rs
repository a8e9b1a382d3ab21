//! Recursive-descent parser for substance files. It never stops at the first error: a bad
//! statement or item is reported and skipped, so one run lists many problems. The normative
//! grammar is `grammar/ash.ebnf`; `tests/grammar.rs` keeps the two in agreement.

use super::ast::*;
use super::lexer::{Tok, Token, lex};
use crate::diag::{Diagnostic, Diagnostics, FileId, Span};

/// Deepest nesting the parser accepts: parentheses, calls, indexing, member access, unary
/// operators, `?:`, blocks and statement bodies, counted together. Past it the parser reports
/// "… nests deeper than 256 levels" where the limit is crossed and skips the construct, so no
/// input can exhaust the stack of this or any later pass (which recurse at most this deep per
/// function; see [`crate::stack`]). Chains of binary operators (`x + x + …`) do not nest: they
/// are parsed in a loop and walked iteratively, however long they are.
pub const MAX_NESTING: u32 = 256;

/// Parses a whole file. Errors go to `diags`; the returned module holds everything that parsed.
pub fn parse(file: FileId, text: &str, diags: &mut Diagnostics) -> Module {
    crate::stack::on_compiler_stack(|| {
        let tokens = lex(file, text, diags);
        let mut parser = Parser { tokens, pos: 0, text, diags, depth: 0, too_deep: false };
        parser.module()
    })
}

/// Raised when a construct cannot be parsed; the diagnostic is already recorded.
struct Bail;

type PResult<T> = Result<T, Bail>;

struct Parser<'a> {
    tokens: Vec<Token>,
    pos: usize,
    text: &'a str,
    diags: &'a mut Diagnostics,
    /// Current nesting, checked against [`MAX_NESTING`].
    depth: u32,
    /// The nesting limit was crossed: unwind to the function body (or the item) and skip the
    /// rest of it, rather than recover statement by statement in code that goes on nesting
    /// (one error, not one per `else` or `}` left over).
    too_deep: bool,
}

/// Binding power of binary operators (higher binds tighter).
fn binary_op(tok: Tok) -> Option<(BinaryOp, u8)> {
    use BinaryOp::*;
    Some(match tok {
        Tok::OrOr => (Or, 1),
        Tok::AndAnd => (And, 2),
        Tok::EqEq => (Eq, 3),
        Tok::NotEq => (Ne, 3),
        Tok::Lt => (Lt, 4),
        Tok::Le => (Le, 4),
        Tok::Gt => (Gt, 4),
        Tok::Ge => (Ge, 4),
        Tok::Plus => (Add, 5),
        Tok::Minus => (Sub, 5),
        Tok::Star => (Mul, 6),
        Tok::Slash => (Div, 6),
        Tok::Percent => (Rem, 6),
        _ => return None,
    })
}

fn base_type(tok: Tok) -> Option<BaseType> {
    Some(match tok {
        Tok::Float => BaseType::Float,
        Tok::Int => BaseType::Int,
        Tok::Color => BaseType::Color,
        Tok::Point => BaseType::Point,
        Tok::Vector => BaseType::Vector,
        Tok::Normal => BaseType::Normal,
        Tok::String => BaseType::String,
        Tok::Closure => BaseType::Closure,
        Tok::Void => BaseType::Void,
        _ => return None,
    })
}

impl<'a> Parser<'a> {
    fn peek(&self) -> Tok {
        self.tokens[self.pos].kind
    }

    fn peek_at(&self, ahead: usize) -> Tok {
        self.tokens[(self.pos + ahead).min(self.tokens.len() - 1)].kind
    }

    fn span(&self) -> Span {
        self.tokens[self.pos].span
    }

    fn prev_span(&self) -> Span {
        self.tokens[self.pos.saturating_sub(1)].span
    }

    fn slice(&self, span: Span) -> &'a str {
        &self.text[span.start as usize..span.end as usize]
    }

    fn bump(&mut self) -> Token {
        let tok = self.tokens[self.pos];
        if tok.kind != Tok::Eof {
            self.pos += 1;
        }
        tok
    }

    fn eat(&mut self, kind: Tok) -> bool {
        if self.peek() == kind {
            self.bump();
            true
        } else {
            false
        }
    }

    fn error_here(&mut self, expected: &str) -> Bail {
        let tok = self.tokens[self.pos];
        let found =
            if tok.kind == Tok::Eof { "end of file".to_string() } else { format!("`{}`", self.slice(tok.span)) };
        self.diags.push(
            Diagnostic::error(format!("expected {expected}, found {found}"))
                .at(tok.span, format!("expected {expected}")),
        );
        Bail
    }

    /// Reports that the input nests deeper than [`MAX_NESTING`] at the current token.
    fn too_deep(&mut self, what: &str) -> Bail {
        self.too_deep = true;
        let span = self.span();
        self.diags.push(
            Diagnostic::error(format!("{what} nests deeper than {MAX_NESTING} levels"))
                .at(span, "nesting limit reached here")
                .note(format!(
                    "parentheses, calls, indexing, operators, blocks and statements may nest at most \
                     {MAX_NESTING} levels; split the code into functions or local variables"
                )),
        );
        Bail
    }

    /// Parses one more level of nesting with `inner`, or reports that the input nests deeper
    /// than [`MAX_NESTING`] (`what`: "expression" or "statement").
    fn nested<T>(&mut self, what: &str, inner: impl FnOnce(&mut Self) -> PResult<T>) -> PResult<T> {
        if self.depth >= MAX_NESTING {
            return Err(self.too_deep(what));
        }
        self.depth += 1;
        let result = inner(self);
        self.depth -= 1;
        result
    }

    fn expect(&mut self, kind: Tok) -> PResult<Token> {
        if self.peek() == kind { Ok(self.bump()) } else { Err(self.error_here(kind.describe())) }
    }

    fn ident(&mut self) -> PResult<Ident> {
        let tok = self.expect(Tok::Ident)?;
        Ok(Ident { name: self.slice(tok.span).to_string(), span: tok.span })
    }

    /// Skips to just after the next `;` at this nesting depth, or to a `}` closing it.
    fn recover_statement(&mut self) {
        let mut depth = 0usize;
        loop {
            match self.peek() {
                Tok::Eof => return,
                Tok::Semi if depth == 0 => {
                    self.bump();
                    return;
                }
                Tok::LBrace | Tok::LParen | Tok::LBracket => depth += 1,
                Tok::RBrace if depth == 0 => return,
                Tok::RBrace | Tok::RParen | Tok::RBracket => depth = depth.saturating_sub(1),
                _ => {}
            }
            self.bump();
        }
    }

    /// Moves past the item (or function body) that starts at token `start`: its first `{`
    /// and the `}` matching it (or the end of the file).
    fn skip_item(&mut self, start: usize) {
        self.pos = start;
        while !matches!(self.peek(), Tok::LBrace | Tok::Eof) {
            self.bump();
        }
        let mut depth = 0usize;
        loop {
            match self.bump().kind {
                Tok::Eof => return,
                Tok::LBrace => depth += 1,
                Tok::RBrace => {
                    depth -= 1;
                    if depth == 0 {
                        return;
                    }
                }
                _ => {}
            }
        }
    }

    /// Skips to the start of the next top-level item.
    fn recover_item(&mut self) {
        let mut depth = 0usize;
        loop {
            match self.peek() {
                Tok::Eof => return,
                Tok::LBrace => depth += 1,
                Tok::RBrace => {
                    depth = depth.saturating_sub(1);
                    if depth == 0 {
                        self.bump();
                        return;
                    }
                }
                Tok::Shader | Tok::Substance | Tok::Override | Tok::Import if depth == 0 => return,
                _ => {}
            }
            self.bump();
        }
    }

    fn module(&mut self) -> Module {
        let mut module = Module::default();
        while self.peek() != Tok::Eof {
            let start = self.pos;
            match self.item() {
                Ok(item) => module.items.push(item),
                Err(Bail) if self.too_deep => {
                    self.too_deep = false;
                    self.skip_item(start);
                }
                Err(Bail) => {
                    self.recover_item();
                    if self.pos == start {
                        self.bump();
                    }
                }
            }
        }
        module
    }

    fn item(&mut self) -> PResult<Item> {
        match self.peek() {
            Tok::Import => {
                self.bump();
                let tok = self.expect(Tok::StrLit)?;
                let path = unescape(self.slice(tok.span));
                self.expect(Tok::Semi)?;
                Ok(Item::Import { path, span: tok.span })
            }
            Tok::Substance | Tok::Override => self.graph().map(Item::Graph),
            Tok::Shader => {
                let start = self.bump().span;
                let ret = TypeExpr { base: BaseType::Void, array: None, span: start };
                self.function(FunctionKind::Shader, ret, start).map(Item::Function)
            }
            tok if base_type(tok).is_some() => {
                let ret = self.type_expr()?;
                let start = ret.span;
                self.function(FunctionKind::Function, ret, start).map(Item::Function)
            }
            _ => Err(self.error_here("`shader`, `substance`, `override`, `import` or a function")),
        }
    }

    fn type_expr(&mut self) -> PResult<TypeExpr> {
        let tok = self.bump();
        match base_type(tok.kind) {
            Some(base) => Ok(TypeExpr { base, array: None, span: tok.span }),
            None => {
                self.pos -= 1;
                Err(self.error_here("a type"))
            }
        }
    }

    /// `[n]` after a declared name.
    fn array_suffix(&mut self, ty: &mut TypeExpr) -> PResult<()> {
        if self.eat(Tok::LBracket) {
            let tok = self.expect(Tok::IntLit)?;
            let len = self.slice(tok.span).parse::<u32>().unwrap_or(0);
            if len == 0 || len > 65536 {
                self.diags
                    .push(Diagnostic::error("array length must be between 1 and 65536").at(tok.span, "invalid length"));
            }
            self.expect(Tok::RBracket)?;
            ty.array = Some(len.clamp(1, 65536));
            ty.span = ty.span.to(self.prev_span());
        }
        Ok(())
    }

    fn function(&mut self, kind: FunctionKind, ret: TypeExpr, start: Span) -> PResult<FunctionDecl> {
        let name = self.ident()?;
        self.expect(Tok::LParen)?;
        let mut params = Vec::new();
        while self.peek() != Tok::RParen {
            let output = self.eat(Tok::Output);
            let mut ty = self.type_expr()?;
            let name = self.ident()?;
            self.array_suffix(&mut ty)?;
            let default = if self.eat(Tok::Assign) { Some(self.expr()?) } else { None };
            params.push(Param { output, ty, name, default });
            if !self.eat(Tok::Comma) {
                break;
            }
        }
        self.expect(Tok::RParen)?;
        let body = self.function_body()?;
        Ok(FunctionDecl { kind, ret, name, params, body, span: start.to(self.prev_span()) })
    }

    /// A function's body. Code nested past [`MAX_NESTING`] unwinds to here and the rest of
    /// the body is skipped: the function stays declared (so graphs using it raise no
    /// follow-on errors) with an empty body marked [`Block::skipped`].
    fn function_body(&mut self) -> PResult<Block> {
        let open = self.pos;
        match self.block() {
            Err(Bail) if self.too_deep => {
                self.too_deep = false;
                self.skip_item(open);
                Ok(Block { stmts: Vec::new(), skipped: true })
            }
            other => other,
        }
    }

    fn block(&mut self) -> PResult<Block> {
        self.expect(Tok::LBrace)?;
        let mut block = Block::default();
        while !matches!(self.peek(), Tok::RBrace | Tok::Eof) {
            let start = self.pos;
            match self.stmt() {
                Ok(stmt) => block.stmts.push(stmt),
                Err(Bail) if self.too_deep => return Err(Bail),
                Err(Bail) => {
                    self.recover_statement();
                    if self.pos == start {
                        self.bump();
                    }
                }
            }
        }
        self.expect(Tok::RBrace)?;
        Ok(block)
    }

    /// A statement body: a block, or a single statement wrapped in one.
    fn body(&mut self) -> PResult<Block> {
        if self.peek() == Tok::LBrace { self.block() } else { Ok(Block { stmts: vec![self.stmt()?], skipped: false }) }
    }

    fn stmt(&mut self) -> PResult<Stmt> {
        self.nested("statement", Self::stmt_inner)
    }

    fn stmt_inner(&mut self) -> PResult<Stmt> {
        let start = self.span();
        let kind = match self.peek() {
            Tok::LBrace => StmtKind::Block(self.block()?),
            Tok::If => {
                self.bump();
                self.expect(Tok::LParen)?;
                let cond = self.expr()?;
                self.expect(Tok::RParen)?;
                let then = self.body()?;
                let otherwise = if self.eat(Tok::Else) { Some(self.body()?) } else { None };
                StmtKind::If { cond, then, otherwise }
            }
            Tok::While => {
                self.bump();
                self.expect(Tok::LParen)?;
                let cond = self.expr()?;
                self.expect(Tok::RParen)?;
                let body = self.body()?;
                StmtKind::While { cond, body }
            }
            Tok::For => {
                self.bump();
                self.expect(Tok::LParen)?;
                let init = if self.peek() == Tok::Semi { None } else { Some(Box::new(self.simple_stmt()?)) };
                self.expect(Tok::Semi)?;
                let cond = if self.peek() == Tok::Semi { None } else { Some(self.expr()?) };
                self.expect(Tok::Semi)?;
                let step = if self.peek() == Tok::RParen { None } else { Some(Box::new(self.simple_stmt()?)) };
                self.expect(Tok::RParen)?;
                let body = self.body()?;
                StmtKind::For { init, cond, step, body }
            }
            Tok::Break => {
                self.bump();
                self.expect(Tok::Semi)?;
                StmtKind::Break
            }
            Tok::Continue => {
                self.bump();
                self.expect(Tok::Semi)?;
                StmtKind::Continue
            }
            Tok::Return => {
                self.bump();
                let value = if self.peek() == Tok::Semi { None } else { Some(self.expr()?) };
                self.expect(Tok::Semi)?;
                StmtKind::Return(value)
            }
            _ => {
                let stmt = self.simple_stmt()?;
                self.expect(Tok::Semi)?;
                return Ok(Stmt { kind: stmt.kind, span: start.to(self.prev_span()) });
            }
        };
        Ok(Stmt { kind, span: start.to(self.prev_span()) })
    }

    /// A declaration, assignment, increment or call, without the trailing `;`.
    fn simple_stmt(&mut self) -> PResult<Stmt> {
        let start = self.span();
        // A type keyword followed by a name declares a local; `color(…)` is a constructor call.
        let kind = if base_type(self.peek()).is_some() && self.peek_at(1) == Tok::Ident {
            let mut ty = self.type_expr()?;
            let name = self.ident()?;
            self.array_suffix(&mut ty)?;
            let init = if self.eat(Tok::Assign) { Some(self.init()?) } else { None };
            StmtKind::Local { ty, name, init }
        } else if matches!(self.peek(), Tok::PlusPlus | Tok::MinusMinus) {
            let op = if self.bump().kind == Tok::PlusPlus { AssignOp::Add } else { AssignOp::Sub };
            let target = self.postfix()?;
            let one = Expr { kind: ExprKind::Int(1), span: target.span };
            StmtKind::Assign { target, op, value: one }
        } else {
            let target = self.expr()?;
            let op = match self.peek() {
                Tok::Assign => Some(AssignOp::Set),
                Tok::PlusAssign => Some(AssignOp::Add),
                Tok::MinusAssign => Some(AssignOp::Sub),
                Tok::StarAssign => Some(AssignOp::Mul),
                Tok::SlashAssign => Some(AssignOp::Div),
                Tok::PlusPlus | Tok::MinusMinus => {
                    let op = if self.bump().kind == Tok::PlusPlus { AssignOp::Add } else { AssignOp::Sub };
                    let one = Expr { kind: ExprKind::Int(1), span: self.prev_span() };
                    return Ok(Stmt {
                        kind: StmtKind::Assign { target, op, value: one },
                        span: start.to(self.prev_span()),
                    });
                }
                _ => None,
            };
            match op {
                Some(op) => {
                    self.bump();
                    let value = self.expr()?;
                    StmtKind::Assign { target, op, value }
                }
                None => StmtKind::Expr(target),
            }
        };
        Ok(Stmt { kind, span: start.to(self.prev_span()) })
    }

    /// A variable initialiser: an expression or a `{…}` array list.
    fn init(&mut self) -> PResult<Expr> {
        if self.peek() != Tok::LBrace {
            return self.expr();
        }
        let start = self.bump().span;
        let mut items = Vec::new();
        while self.peek() != Tok::RBrace {
            items.push(self.expr()?);
            if !self.eat(Tok::Comma) {
                break;
            }
        }
        self.expect(Tok::RBrace)?;
        Ok(Expr { kind: ExprKind::List(items), span: start.to(self.prev_span()) })
    }

    /// Parses an expression (one level of nesting).
    fn expr(&mut self) -> PResult<Expr> {
        self.nested("expression", Self::expr_inner)
    }

    fn expr_inner(&mut self) -> PResult<Expr> {
        let cond = self.binary(1)?;
        if self.eat(Tok::Question) {
            let then = self.expr()?;
            self.expect(Tok::Colon)?;
            let otherwise = self.expr()?;
            let span = cond.span.to(otherwise.span);
            return Ok(Expr { kind: ExprKind::Ternary(Box::new(cond), Box::new(then), Box::new(otherwise)), span });
        }
        Ok(cond)
    }

    /// Operators of one binding power in a loop (a flat chain builds a left-deep tree without
    /// recursing per operand); only a tighter-binding right operand recurses, at most once per
    /// precedence level.
    fn binary(&mut self, min_power: u8) -> PResult<Expr> {
        let mut lhs = self.unary()?;
        while let Some((op, power)) = binary_op(self.peek()) {
            if power < min_power {
                break;
            }
            self.bump();
            let rhs = self.binary(power + 1)?;
            let span = lhs.span.to(rhs.span);
            lhs = Expr { kind: ExprKind::Binary(op, Box::new(lhs), Box::new(rhs)), span };
        }
        Ok(lhs)
    }

    fn unary(&mut self) -> PResult<Expr> {
        let start = self.span();
        let op = match self.peek() {
            Tok::Minus => UnaryOp::Neg,
            Tok::Bang => UnaryOp::Not,
            Tok::Plus => {
                self.bump();
                return self.nested("expression", Self::unary);
            }
            _ => return self.postfix(),
        };
        self.bump();
        let operand = self.nested("expression", Self::unary)?;
        let span = start.to(operand.span);
        Ok(Expr { kind: ExprKind::Unary(op, Box::new(operand)), span })
    }

    /// A primary expression and its `.name` / `[index]` suffixes. Each suffix nests the
    /// expression one level deeper (`a[0][1].x` is three levels), so suffixes count against
    /// [`MAX_NESTING`]: later passes recurse into the base of each.
    fn postfix(&mut self) -> PResult<Expr> {
        let entered = self.depth;
        let result = self.postfix_suffixes();
        self.depth = entered;
        result
    }

    fn postfix_suffixes(&mut self) -> PResult<Expr> {
        let mut expr = self.primary()?;
        loop {
            if matches!(self.peek(), Tok::Dot | Tok::LBracket) {
                if self.depth >= MAX_NESTING {
                    return Err(self.too_deep("expression"));
                }
                self.depth += 1;
            }
            match self.peek() {
                Tok::Dot => {
                    self.bump();
                    let name = self.ident()?;
                    let span = expr.span.to(name.span);
                    expr = Expr { kind: ExprKind::Member(Box::new(expr), name), span };
                }
                Tok::LBracket => {
                    self.bump();
                    let index = self.expr()?;
                    let end = self.expect(Tok::RBracket)?.span;
                    let span = expr.span.to(end);
                    expr = Expr { kind: ExprKind::Index(Box::new(expr), Box::new(index)), span };
                }
                _ => return Ok(expr),
            }
        }
    }

    fn args(&mut self) -> PResult<Vec<Expr>> {
        self.expect(Tok::LParen)?;
        let mut args = Vec::new();
        while self.peek() != Tok::RParen {
            args.push(self.expr()?);
            if !self.eat(Tok::Comma) {
                break;
            }
        }
        self.expect(Tok::RParen)?;
        Ok(args)
    }

    fn primary(&mut self) -> PResult<Expr> {
        let tok = self.tokens[self.pos];
        let text = self.slice(tok.span);
        let kind = match tok.kind {
            Tok::IntLit => {
                self.bump();
                match text.parse::<i64>() {
                    Ok(v) if v <= i32::MAX as i64 => ExprKind::Int(v),
                    _ => {
                        self.diags.push(
                            Diagnostic::error("integer literal does not fit in 32 bits").at(tok.span, "too large"),
                        );
                        ExprKind::Error
                    }
                }
            }
            Tok::FloatLit => {
                self.bump();
                ExprKind::Float(text.parse::<f64>().unwrap_or(0.0))
            }
            Tok::StrLit => {
                self.bump();
                ExprKind::Str(unescape(text))
            }
            Tok::Ident => {
                self.bump();
                if self.peek() == Tok::LParen {
                    let name = Ident { name: text.to_string(), span: tok.span };
                    ExprKind::Call(name, self.args()?)
                } else {
                    ExprKind::Name(text.to_string())
                }
            }
            // Type constructors and casts: `color(1, 0, 0)`, `float(i)`.
            Tok::Float | Tok::Int | Tok::Color | Tok::Point | Tok::Vector | Tok::Normal
                if self.peek_at(1) == Tok::LParen =>
            {
                self.bump();
                let name = Ident { name: text.to_string(), span: tok.span };
                ExprKind::Call(name, self.args()?)
            }
            Tok::LParen => {
                self.bump();
                let mut inner = self.expr()?;
                self.expect(Tok::RParen)?;
                inner.span = tok.span.to(self.prev_span());
                return Ok(inner);
            }
            _ => return Err(self.error_here("an expression")),
        };
        Ok(Expr { kind, span: tok.span.to(self.prev_span()) })
    }

    fn graph(&mut self) -> PResult<GraphDecl> {
        let start = self.span();
        let kind = if self.bump().kind == Tok::Substance { GraphKind::Substance } else { GraphKind::Override };
        let name = self.ident()?;
        self.expect(Tok::LBrace)?;
        let mut items = Vec::new();
        while !matches!(self.peek(), Tok::RBrace | Tok::Eof) {
            let at = self.pos;
            match self.graph_item() {
                Ok(item) => items.push(item),
                Err(Bail) => {
                    // Graph items do not nest: past the limit, skip just this one.
                    self.too_deep = false;
                    self.recover_statement();
                    if self.pos == at {
                        self.bump();
                    }
                }
            }
        }
        self.expect(Tok::RBrace)?;
        Ok(GraphDecl { kind, name, items, span: start.to(self.prev_span()) })
    }

    fn graph_item(&mut self) -> PResult<GraphItem> {
        let item = match self.peek() {
            Tok::Input => {
                self.bump();
                let ty = self.type_expr()?;
                let name = self.ident()?;
                let default = if self.eat(Tok::Assign) { Some(self.expr()?) } else { None };
                GraphItem::Input { ty, name, default }
            }
            Tok::Output => {
                self.bump();
                let ty = self.type_expr()?;
                let name = self.ident()?;
                self.expect(Tok::Assign)?;
                let value = self.expr()?;
                GraphItem::Output { ty, name, value }
            }
            Tok::Node => {
                self.bump();
                let name = self.ident()?;
                self.expect(Tok::Assign)?;
                let node_type = self.ident()?;
                self.expect(Tok::LParen)?;
                let mut args = Vec::new();
                while self.peek() != Tok::RParen {
                    let port = self.ident()?;
                    self.expect(Tok::Colon)?;
                    let value = self.expr()?;
                    args.push((port, value));
                    if !self.eat(Tok::Comma) {
                        break;
                    }
                }
                self.expect(Tok::RParen)?;
                GraphItem::Node { name, node_type, args }
            }
            // Product bindings; `normal` is also a type keyword, so it is matched by token.
            Tok::Ident | Tok::Normal if self.peek_at(1) == Tok::Assign => {
                let tok = self.bump();
                let Some(product) = Product::from_name(self.slice(tok.span)) else {
                    self.diags.push(
                        Diagnostic::error(format!("unknown product `{}`", self.slice(tok.span)))
                            .at(tok.span, "not a product")
                            .note("products are `surface`, `displacement`, `normal` and `mask`"),
                    );
                    return Err(Bail);
                };
                self.expect(Tok::Assign)?;
                let value = self.expr()?;
                GraphItem::Product { product, span: tok.span, value }
            }
            _ => return Err(self.error_here("`input`, `output`, `node` or a product binding")),
        };
        self.expect(Tok::Semi)?;
        Ok(item)
    }
}

/// Strips the quotes of a string literal and resolves `\"`, `\\`, `\n` and `\t`.
fn unescape(quoted: &str) -> String {
    let inner = quoted.strip_prefix('"').and_then(|s| s.strip_suffix('"')).unwrap_or(quoted);
    let mut out = String::with_capacity(inner.len());
    let mut chars = inner.chars();
    while let Some(c) = chars.next() {
        if c == '\\' {
            match chars.next() {
                Some('n') => out.push('\n'),
                Some('t') => out.push('\t'),
                Some(other) => out.push(other),
                None => {}
            }
        } else {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diag::SourceMap;

    fn parse_ok(text: &str) -> Module {
        let mut diags = Diagnostics::new();
        let module = parse(FileId(0), text, &mut diags);
        assert!(!diags.has_errors(), "{:?}", diags);
        module
    }

    #[test]
    fn shader_with_control_flow() {
        let m = parse_ok(
            "shader s(float a = 1, output color c = 0) {
                 float acc[3] = {1, 2, 3};
                 for (int i = 0; i < 3; i++) { if (i == 1) continue; acc[i] += a; }
                 while (a > 0) { a -= 1; if (a < 0.5) break; }
                 c = a > 0 ? color(1, 0, 0) : color(acc[0]);
                 c.r = -c.g * 2 + 1;
             }
             float sq(float x) { return x * x; }",
        );
        assert_eq!(m.items.len(), 2);
    }

    #[test]
    fn precedence() {
        let m = parse_ok("float f() { return 1 + 2 * 3 < 4 && 1 || 0; }");
        let Item::Function(f) = &m.items[0] else { panic!() };
        let StmtKind::Return(Some(e)) = &f.body.stmts[0].kind else { panic!() };
        assert!(matches!(e.kind, ExprKind::Binary(BinaryOp::Or, _, _)));
    }

    #[test]
    fn graphs() {
        let m = parse_ok(
            "substance s { input color base = color(1); node g = diffuse(albedo: base); surface = g.bsdf; normal = n.out; }
             override o { output color base = color(1, 0, 0); }",
        );
        let Item::Graph(g) = &m.items[0] else { panic!() };
        assert_eq!(g.items.len(), 4);
        assert!(matches!(g.items[3], GraphItem::Product { product: Product::Normal, .. }));
    }

    #[test]
    fn many_errors_in_one_run() {
        let mut sources = SourceMap::new();
        let text = "shader a() { float x = ; x = 1 }\nshader b() { y = = 2; }\nsubstance s { node = ; }";
        let file = sources.add("bad.ash", text);
        let mut diags = Diagnostics::new();
        let _ = parse(file, text, &mut diags);
        assert!(diags.error_count() >= 3, "{}", diags.render(&sources));
        assert!(diags.render(&sources).contains("bad.ash:1:"));
    }
}
