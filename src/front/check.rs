//! Type checking of node-type and function bodies: resolves names, checks types, inserts
//! implicit conversions and produces [`hir`] functions.

use super::ast::{self, AssignOp, BaseType, BinaryOp, ExprKind as A, FunctionKind, StmtKind};
use super::hir::{self, Expr, ExprKind, FuncId, Global, LocalId, Place, Stmt};
use super::intrinsics::Intrinsic;
use super::types::{Type, Value};
use crate::diag::{Diagnostic, Diagnostics, Span};
use std::collections::HashMap;

/// What the checker needs to know about callable user functions.
pub struct Callee {
    /// Function id.
    pub id: FuncId,
    /// Shader or function.
    pub kind: FunctionKind,
    /// Parameter types.
    pub params: Vec<Type>,
    /// Result type.
    pub ret: Type,
}

/// Resolves the type written in source.
pub fn resolve_type(ty: &ast::TypeExpr) -> Type {
    Type { base: ty.base, array: ty.array }
}

/// Checks one function or shader. `callees` maps names to user functions visible from it.
/// Runs on the compiler stack ([`crate::stack`]): checking recurses as deep as the body nests.
pub fn check_function(
    decl: &ast::FunctionDecl,
    callees: &HashMap<String, Callee>,
    builtin: bool,
    diags: &mut Diagnostics,
) -> hir::Function {
    crate::stack::on_compiler_stack(|| check_function_here(decl, callees, builtin, diags))
}

fn check_function_here(
    decl: &ast::FunctionDecl,
    callees: &HashMap<String, Callee>,
    builtin: bool,
    diags: &mut Diagnostics,
) -> hir::Function {
    let mut cx = Checker {
        callees,
        diags,
        locals: Vec::new(),
        readonly: Vec::new(),
        scopes: vec![HashMap::new()],
        loop_depth: 0,
        ret: resolve_type(&decl.ret),
        kind: decl.kind,
        array_elements: 0,
    };
    let mut params = Vec::new();
    for param in &decl.params {
        let ty = resolve_type(&param.ty);
        if param.output && decl.kind == FunctionKind::Function {
            cx.diags.push(
                Diagnostic::error("output parameters are only allowed on shaders")
                    .at(param.name.span, "functions return their result"),
            );
        }
        if ty.base == BaseType::Void {
            cx.diags.push(Diagnostic::error("a parameter cannot be void").at(param.ty.span, "void"));
        }
        cx.check_array_element(ty, param.ty.span);
        cx.within_array_budget(ty, param.ty.span);
        // Shader defaults may read globals but no other parameter.
        let default = param.default.as_ref().and_then(|d| {
            let value = cx.expr(d)?;
            cx.coerce(value, ty, d.span, "default value")
        });
        if decl.kind == FunctionKind::Function && param.default.is_some() {
            cx.diags.push(
                Diagnostic::error("function parameters cannot have defaults")
                    .at(param.name.span, "only shader parameters have defaults"),
            );
        }
        cx.declare(&param.name, ty, decl.kind == FunctionKind::Shader && !param.output);
        params.push(hir::Param {
            name: param.name.name.clone(),
            ty,
            output: param.output,
            default,
            span: param.name.span,
        });
    }
    if decl.kind == FunctionKind::Shader && !builtin && !params.iter().any(|p| p.output) {
        cx.diags.push(
            Diagnostic::warning(format!("shader `{}` has no outputs", decl.name.name))
                .at(decl.name.span, "only custom channels are useful without outputs"),
        );
    }
    let body = cx.block(&decl.body);
    if cx.ret != Type::VOID && !decl.body.skipped && !always_returns(&decl.body.stmts) {
        cx.diags.push(
            Diagnostic::error(format!("function `{}` may end without returning a value", decl.name.name))
                .at(decl.name.span, format!("must return {}", cx.ret)),
        );
    }
    hir::Function {
        name: decl.name.name.clone(),
        kind: decl.kind,
        params,
        ret: cx.ret,
        locals: cx.locals,
        body,
        varying: false,
        span: decl.span,
        builtin,
    }
}

/// Whether every path through `stmts` ends in `return`.
fn always_returns(stmts: &[ast::Stmt]) -> bool {
    stmts.iter().any(|s| match &s.kind {
        StmtKind::Return(_) => true,
        StmtKind::Block(b) => always_returns(&b.stmts),
        StmtKind::If { then, otherwise: Some(otherwise), .. } => {
            always_returns(&then.stmts) && always_returns(&otherwise.stmts)
        }
        _ => false,
    })
}

struct Checker<'a> {
    callees: &'a HashMap<String, Callee>,
    diags: &'a mut Diagnostics,
    locals: Vec<hir::Local>,
    readonly: Vec<bool>,
    scopes: Vec<HashMap<String, LocalId>>,
    loop_depth: u32,
    ret: Type,
    kind: FunctionKind,
    /// Elements of the arrays declared so far (parameters and locals), for
    /// [`MAX_FUNCTION_ARRAY_ELEMENTS`].
    array_elements: u64,
}

/// Most array elements one function may declare, parameters and locals together: 65 536,
/// what lowering's 256 KiB of local arrays per entry holds at 4 bytes an element (so no
/// program this rejects would compile). Each declared array is a value in the checked tree:
/// without the cap, 5 000 declarations of `float a[65536]` took 10 GB to check.
pub const MAX_FUNCTION_ARRAY_ELEMENTS: u64 = 1 << 16;

impl Checker<'_> {
    fn error(&mut self, span: Span, message: impl Into<String>, label: impl Into<String>) {
        self.diags.push(Diagnostic::error(message).at(span, label));
    }

    /// Counts an array declaration against [`MAX_FUNCTION_ARRAY_ELEMENTS`]; `false` (reported
    /// once per function) past it.
    fn within_array_budget(&mut self, ty: Type, span: Span) -> bool {
        let Some(n) = ty.array else { return true };
        let before = self.array_elements;
        self.array_elements = before.saturating_add(u64::from(n));
        if self.array_elements <= MAX_FUNCTION_ARRAY_ELEMENTS {
            return true;
        }
        if before <= MAX_FUNCTION_ARRAY_ELEMENTS {
            self.error(
                span,
                format!("this function's arrays hold more than {MAX_FUNCTION_ARRAY_ELEMENTS} elements in all"),
                "past the limit here",
            );
        }
        false
    }

    fn declare(&mut self, name: &ast::Ident, ty: Type, readonly: bool) -> LocalId {
        let id = LocalId(self.locals.len() as u32);
        self.locals.push(hir::Local { name: name.name.clone(), ty, span: name.span });
        self.readonly.push(readonly);
        let scope = self.scopes.last_mut().expect("a scope is always open");
        if scope.insert(name.name.clone(), id).is_some() {
            self.diags.push(
                Diagnostic::error(format!("`{}` is already declared in this scope", name.name))
                    .at(name.span, "declared again"),
            );
        }
        if Global::from_name(&name.name).is_some() {
            self.diags.push(
                Diagnostic::warning(format!("`{}` shadows the shading global of that name", name.name))
                    .at(name.span, "shadows a global"),
            );
        }
        id
    }

    /// Arrays hold numbers, triples and strings: a closure (a kind word and eight floats)
    /// has no array layout, and would be stored with the wrong types.
    fn check_array_element(&mut self, ty: Type, span: Span) {
        if ty.array.is_some() && ty.base == BaseType::Closure {
            self.error(span, "arrays of closures are not supported", "closure array");
        }
    }

    fn lookup(&self, name: &str) -> Option<LocalId> {
        self.scopes.iter().rev().find_map(|s| s.get(name).copied())
    }

    fn block(&mut self, block: &ast::Block) -> Vec<Stmt> {
        self.scopes.push(HashMap::new());
        let mut out = Vec::new();
        for stmt in &block.stmts {
            self.stmt(stmt, &mut out);
        }
        self.scopes.pop();
        out
    }

    /// Converts `value` to `to` or reports why it cannot.
    fn coerce(&mut self, value: Expr, to: Type, span: Span, what: &str) -> Option<Expr> {
        if value.ty.converts_to(to) {
            Some(value.convert_to(to))
        } else {
            self.error(
                span,
                format!("mismatched types: {what} must be {to}, found {}", value.ty),
                format!("this is {}", value.ty),
            );
            None
        }
    }

    fn condition(&mut self, cond: &ast::Expr) -> Option<Expr> {
        let value = self.expr(cond)?;
        if value.ty.is_scalar_number() {
            Some(value)
        } else {
            self.error(cond.span, format!("a condition must be int or float, found {}", value.ty), "not a number");
            None
        }
    }

    fn stmt(&mut self, stmt: &ast::Stmt, out: &mut Vec<Stmt>) {
        match &stmt.kind {
            StmtKind::Local { ty: written, name, init } => {
                let ty = resolve_type(written);
                if matches!(ty.base, BaseType::Void) {
                    self.error(name.span, "a variable cannot be void", "void");
                }
                self.check_array_element(ty, written.span);
                let within = self.within_array_budget(ty, written.span);
                let init = match init {
                    Some(init) => {
                        self.expr_expecting(init, ty).and_then(|v| self.coerce(v, ty, init.span, "initial value"))
                    }
                    None if within => Value::zero(ty).map(|v| Expr::constant(v, ty, name.span)),
                    None => None,
                };
                let id = self.declare(name, ty, false);
                if let Some(init) = init {
                    out.push(Stmt::Assign(Place { local: id, element: None, component: None }, init));
                }
            }
            StmtKind::Assign { target, op, value } => {
                let Some((place, place_ty)) = self.place(target) else { return };
                let Some(rhs) = self.expr(value) else { return };
                let rhs = if *op == AssignOp::Set {
                    rhs
                } else {
                    let bin = match op {
                        AssignOp::Add => BinaryOp::Add,
                        AssignOp::Sub => BinaryOp::Sub,
                        AssignOp::Mul => BinaryOp::Mul,
                        _ => BinaryOp::Div,
                    };
                    let current = self.read_place(&place, place_ty, target.span);
                    let Some(combined) = self.binary(bin, current, rhs, stmt.span) else { return };
                    combined
                };
                if let Some(rhs) = self.coerce(rhs, place_ty, value.span, "assigned value") {
                    out.push(Stmt::Assign(place, rhs));
                }
            }
            StmtKind::Expr(expr) => {
                if !matches!(expr.kind, A::Call(..)) {
                    self.diags.push(Diagnostic::warning("expression result is unused").at(expr.span, "has no effect"));
                }
                if let Some(e) = self.expr(expr) {
                    out.push(Stmt::Eval(e));
                }
            }
            StmtKind::If { cond, then, otherwise } => {
                let cond = self.condition(cond);
                let then = self.block(then);
                let otherwise = otherwise.as_ref().map(|b| self.block(b)).unwrap_or_default();
                if let Some(cond) = cond {
                    out.push(Stmt::If(cond, then, otherwise));
                }
            }
            StmtKind::While { cond, body } => {
                let cond = self.condition(cond);
                self.loop_depth += 1;
                let body = self.block(body);
                self.loop_depth -= 1;
                if let Some(cond) = cond {
                    out.push(Stmt::Loop { cond: Some(cond), body, step: Vec::new(), span: stmt.span });
                }
            }
            StmtKind::For { init, cond, step, body } => {
                // The init declaration is scoped to the loop.
                self.scopes.push(HashMap::new());
                if let Some(init) = init {
                    self.stmt(init, out);
                }
                // No condition: an endless loop that only `break`, `return` or the loop budget
                // ends. A condition that failed to check is already reported: no loop.
                let cond = match cond {
                    None => Some(None),
                    Some(c) => self.condition(c).map(Some),
                };
                let mut step_out = Vec::new();
                if let Some(step) = step {
                    self.stmt(step, &mut step_out);
                }
                self.loop_depth += 1;
                let body = self.block(body);
                self.loop_depth -= 1;
                self.scopes.pop();
                if let Some(cond) = cond {
                    out.push(Stmt::Loop { cond, body, step: step_out, span: stmt.span });
                }
            }
            StmtKind::Break | StmtKind::Continue => {
                if self.loop_depth == 0 {
                    self.error(stmt.span, "`break` or `continue` outside of a loop", "not in a loop");
                } else if matches!(stmt.kind, StmtKind::Break) {
                    out.push(Stmt::Break);
                } else {
                    out.push(Stmt::Continue);
                }
            }
            StmtKind::Return(value) => match (value, self.ret == Type::VOID) {
                (None, true) => out.push(Stmt::Return(None)),
                (Some(v), false) => {
                    let ret = self.ret;
                    if let Some(v) = self.expr(v).and_then(|e| self.coerce(e, ret, v.span, "returned value")) {
                        out.push(Stmt::Return(Some(v)));
                    }
                }
                (Some(v), true) => {
                    let what = if self.kind == FunctionKind::Shader { "a shader" } else { "a void function" };
                    self.error(v.span, format!("{what} cannot return a value"), "assign an output instead");
                }
                (None, false) => {
                    let ret = self.ret;
                    self.error(stmt.span, format!("missing return value of type {ret}"), "returns nothing");
                }
            },
            StmtKind::Block(block) => {
                let inner = self.block(block);
                out.extend(inner);
            }
        }
    }

    fn read_place(&self, place: &Place, ty: Type, span: Span) -> Expr {
        let local = self.locals[place.local.0 as usize].ty;
        let mut e = Expr { kind: ExprKind::Local(place.local), ty: local, span };
        if let Some(element) = &place.element {
            e = Expr { kind: ExprKind::Index(Box::new(e), element.clone()), ty: local.element(), span };
        }
        if let Some(component) = &place.component {
            e = Expr { kind: ExprKind::Index(Box::new(e), component.clone()), ty, span };
        }
        e
    }

    /// Resolves an assignment target.
    fn place(&mut self, target: &ast::Expr) -> Option<(Place, Type)> {
        let (root, element, component) = match &target.kind {
            A::Name(_) => (target, None, None),
            A::Member(base, comp) => {
                let index = component_index(&comp.name);
                match (&base.kind, index) {
                    (A::Name(_), Some(i)) => {
                        (&**base, None, Some(Expr::constant(Value::Int(i as i32), Type::INT, comp.span)))
                    }
                    (A::Index(inner, idx), Some(i)) if matches!(inner.kind, A::Name(_)) => {
                        let idx = self.index_expr(idx)?;
                        (&**inner, Some(idx), Some(Expr::constant(Value::Int(i as i32), Type::INT, comp.span)))
                    }
                    _ => {
                        self.error(target.span, "cannot assign to this expression", "not a variable or component");
                        return None;
                    }
                }
            }
            A::Index(base, idx) if matches!(base.kind, A::Name(_)) => {
                let idx = self.index_expr(idx)?;
                (&**base, Some(idx), None)
            }
            _ => {
                self.error(target.span, "cannot assign to this expression", "not a variable, component or element");
                return None;
            }
        };
        let A::Name(name) = &root.kind else { return None };
        let Some(local) = self.lookup(name) else {
            let message = if Global::from_name(name).is_some() {
                format!("shading global `{name}` is read-only")
            } else {
                format!("unknown variable `{name}`")
            };
            self.error(root.span, message, "cannot assign here");
            return None;
        };
        if self.readonly[local.0 as usize] {
            self.error(
                root.span,
                format!("shader input `{name}` is read-only"),
                "copy it to a local variable to modify it",
            );
            return None;
        }
        let local_ty = self.locals[local.0 as usize].ty;
        let mut ty = local_ty;
        let (element, component) = match (element, component) {
            (Some(idx), comp) if local_ty.array.is_some() => {
                ty = local_ty.element();
                (Some(Box::new(idx)), comp)
            }
            // `c[i]` on a triple indexes a component.
            (Some(idx), None) if local_ty.is_triple() => (None, Some(idx)),
            (None, comp) => (None, comp),
            (Some(_), _) => {
                self.error(target.span, format!("cannot index a value of type {local_ty}"), "not an array");
                return None;
            }
        };
        if component.is_some() {
            if !ty.is_triple() {
                self.error(target.span, format!("{ty} has no components"), "not a triple");
                return None;
            }
            ty = Type::FLOAT;
        }
        Some((Place { local, element, component: component.map(Box::new) }, ty))
    }

    fn index_expr(&mut self, idx: &ast::Expr) -> Option<Expr> {
        let value = self.expr(idx)?;
        if value.ty != Type::INT {
            self.error(idx.span, format!("an index must be int, found {}", value.ty), "not an int");
            return None;
        }
        Some(value)
    }

    /// Checks an expression, using `expected` to type `{…}` array initialisers.
    fn expr_expecting(&mut self, expr: &ast::Expr, expected: Type) -> Option<Expr> {
        if let A::List(items) = &expr.kind {
            let Some(len) = expected.array else {
                self.error(expr.span, "a `{…}` list initialises arrays only", "not an array");
                return None;
            };
            if items.len() != len as usize {
                self.error(
                    expr.span,
                    format!("array of {len} initialised with {} element(s)", items.len()),
                    "wrong length",
                );
                return None;
            }
            let element = expected.element();
            let mut out = Vec::new();
            for item in items {
                let v = self.expr(item)?;
                out.push(self.coerce(v, element, item.span, "array element")?);
            }
            return Some(Expr { kind: ExprKind::Array(out), ty: expected, span: expr.span });
        }
        self.expr(expr)
    }

    fn expr(&mut self, expr: &ast::Expr) -> Option<Expr> {
        let span = expr.span;
        let (kind, ty) = match &expr.kind {
            A::Float(x) => (ExprKind::Const(Value::Float(*x as f32)), Type::FLOAT),
            A::Int(i) => (ExprKind::Const(Value::Int(*i as i32)), Type::INT),
            A::Str(s) => (ExprKind::Const(Value::Str(s.clone())), Type::STRING),
            A::Error => return None,
            A::Name(name) => {
                if let Some(local) = self.lookup(name) {
                    (ExprKind::Local(local), self.locals[local.0 as usize].ty)
                } else if let Some(global) = Global::from_name(name) {
                    (ExprKind::Global(global), global.ty())
                } else {
                    self.error(span, format!("unknown name `{name}`"), "not a variable, parameter or global");
                    return None;
                }
            }
            A::Unary(op, operand) => {
                let v = self.expr(operand)?;
                match op {
                    ast::UnaryOp::Neg if v.ty.is_numeric() => {
                        let ty = v.ty;
                        // Negative literals stay literals.
                        match v.as_const() {
                            Some(Value::Int(i)) => return Some(Expr::constant(Value::Int(i.wrapping_neg()), ty, span)),
                            Some(Value::Float(x)) => return Some(Expr::constant(Value::Float(-x), ty, span)),
                            Some(Value::Triple(t)) => {
                                return Some(Expr::constant(Value::Triple(t.map(|c| -c)), ty, span));
                            }
                            _ => {}
                        }
                        (ExprKind::Unary(hir::UnaryOp::Neg, Box::new(v)), ty)
                    }
                    ast::UnaryOp::Not if v.ty.is_scalar_number() => {
                        (ExprKind::Unary(hir::UnaryOp::Not, Box::new(v)), Type::INT)
                    }
                    _ => {
                        self.error(span, format!("cannot apply this operator to {}", v.ty), "wrong operand type");
                        return None;
                    }
                }
            }
            A::Binary(..) => return self.binary_chain(expr),
            A::Ternary(cond, then, otherwise) => {
                let c = self.condition(cond);
                let a = self.expr(then);
                let b = self.expr(otherwise);
                let (c, a, b) = (c?, a?, b?);
                let ty = if b.ty.converts_to(a.ty) {
                    a.ty
                } else if a.ty.converts_to(b.ty) {
                    b.ty
                } else {
                    self.error(
                        span,
                        format!("the branches of `?:` have different types: {} and {}", a.ty, b.ty),
                        "mismatched branches",
                    );
                    return None;
                };
                (ExprKind::Select(Box::new(c), Box::new(a.convert_to(ty)), Box::new(b.convert_to(ty))), ty)
            }
            A::Member(base, comp) => {
                let v = self.expr(base)?;
                match component_index(&comp.name) {
                    Some(i) if v.ty.is_triple() && component_matches(v.ty, &comp.name) => {
                        (ExprKind::Component(Box::new(v), i), Type::FLOAT)
                    }
                    _ => {
                        self.error(
                            comp.span,
                            format!("{} has no component `{}`", v.ty, comp.name),
                            "use .x/.y/.z on point, vector, normal and .r/.g/.b on color",
                        );
                        return None;
                    }
                }
            }
            A::Index(base, idx) => {
                let v = self.expr(base)?;
                let i = self.index_expr(idx)?;
                let ty = if v.ty.array.is_some() {
                    v.ty.element()
                } else if v.ty.is_triple() {
                    Type::FLOAT
                } else {
                    self.error(base.span, format!("cannot index a value of type {}", v.ty), "not an array");
                    return None;
                };
                (ExprKind::Index(Box::new(v), Box::new(i)), ty)
            }
            A::List(_) => {
                self.error(span, "a `{…}` list initialises arrays only", "use it in an array declaration");
                return None;
            }
            A::Call(name, args) => return self.call(name, args, span),
        };
        Some(Expr { kind, ty, span })
    }

    /// Checks a binary operator and the operators along its left operand's spine in a loop:
    /// `x + x + … + x` is a left-deep tree as deep as the chain is long, so recursing into the
    /// left operand would need stack in proportion to the chain. Operands are still checked
    /// left to right, and each operator sees the checked (converted) result of the ones
    /// before it, exactly as the recursive form would.
    fn binary_chain(&mut self, expr: &ast::Expr) -> Option<Expr> {
        let mut spine = Vec::new();
        let mut leftmost = expr;
        while let A::Binary(op, lhs, rhs) = &leftmost.kind {
            spine.push((*op, &**rhs, leftmost.span));
            leftmost = lhs;
        }
        let mut acc = self.expr(leftmost);
        for (op, rhs, span) in spine.into_iter().rev() {
            let r = self.expr(rhs);
            acc = match (acc, r) {
                (Some(l), Some(r)) => self.binary(op, l, r, span),
                _ => None,
            };
        }
        acc
    }

    fn binary(&mut self, op: BinaryOp, l: Expr, r: Expr, span: Span) -> Option<Expr> {
        use BinaryOp::*;
        let mismatch = |cx: &mut Self, l: &Expr, r: &Expr| {
            cx.error(span, format!("cannot apply `{}` to {} and {}", op.symbol(), l.ty, r.ty), "mismatched operands");
        };
        match op {
            And | Or => {
                if !l.ty.is_scalar_number() || !r.ty.is_scalar_number() {
                    mismatch(self, &l, &r);
                    return None;
                }
                Some(Expr { kind: ExprKind::Binary(op, Box::new(l), Box::new(r)), ty: Type::INT, span })
            }
            Eq | Ne if l.ty == Type::STRING && r.ty == Type::STRING => {
                Some(Expr { kind: ExprKind::Binary(op, Box::new(l), Box::new(r)), ty: Type::INT, span })
            }
            Eq | Ne | Lt | Le | Gt | Ge => {
                let Some(common) = arithmetic_type(l.ty, r.ty) else {
                    mismatch(self, &l, &r);
                    return None;
                };
                if common.is_triple() && !matches!(op, Eq | Ne) {
                    mismatch(self, &l, &r);
                    return None;
                }
                Some(Expr {
                    kind: ExprKind::Binary(op, Box::new(l.convert_to(common)), Box::new(r.convert_to(common))),
                    ty: Type::INT,
                    span,
                })
            }
            Add | Mul if l.ty == Type::CLOSURE || r.ty == Type::CLOSURE => {
                // Closure algebra: closure + closure, closure * (float|color) either way round.
                let (l, r) = match (op, l.ty == Type::CLOSURE, r.ty == Type::CLOSURE) {
                    (Add, true, true) => (l, r),
                    (Mul, true, false) if r.ty.converts_to(Type::COLOR) => (l, r.convert_to(Type::COLOR)),
                    (Mul, false, true) if l.ty.converts_to(Type::COLOR) => (r, l.convert_to(Type::COLOR)),
                    _ => {
                        mismatch(self, &l, &r);
                        return None;
                    }
                };
                Some(Expr { kind: ExprKind::Binary(op, Box::new(l), Box::new(r)), ty: Type::CLOSURE, span })
            }
            Add | Sub | Mul | Div | Rem => {
                let Some(common) = arithmetic_type(l.ty, r.ty) else {
                    mismatch(self, &l, &r);
                    return None;
                };
                Some(Expr {
                    kind: ExprKind::Binary(op, Box::new(l.convert_to(common)), Box::new(r.convert_to(common))),
                    ty: common,
                    span,
                })
            }
        }
    }

    fn call(&mut self, name: &ast::Ident, args: &[ast::Expr], span: Span) -> Option<Expr> {
        let mut checked = Vec::with_capacity(args.len());
        let mut failed = false;
        for arg in args {
            match self.expr(arg) {
                Some(e) => checked.push(e),
                None => failed = true,
            }
        }
        if failed {
            return None;
        }
        let n = name.name.as_str();
        // Casts and triple constructors.
        if let Some(base) = hir::triple_constructor(n) {
            let ty = Type::scalar(base);
            return match checked.len() {
                1 if checked[0].ty.is_numeric() => {
                    let arg = checked.pop().expect("one argument");
                    let kind = if arg.ty.is_triple() {
                        // Explicit casts between any triples are allowed.
                        ExprKind::Convert(Box::new(arg))
                    } else {
                        let mut converted = arg.convert_to(ty);
                        converted.span = span;
                        return Some(converted);
                    };
                    Some(Expr { kind, ty, span })
                }
                3 if checked.iter().all(|a| a.ty.is_scalar_number()) => {
                    let mut it = checked.into_iter().map(|a| a.convert_to(Type::FLOAT));
                    let parts = [it.next()?, it.next()?, it.next()?];
                    // Literal triples become constants so defaults such as `color(0.5, 0.5, 1)` fold.
                    if let [Some(x), Some(y), Some(z)] = parts.each_ref().map(|p| p.as_const().and_then(Value::as_f32))
                    {
                        return Some(Expr::constant(Value::Triple([x, y, z]), ty, span));
                    }
                    Some(Expr { kind: ExprKind::Construct(Box::new(parts)), ty, span })
                }
                _ => {
                    self.error(
                        span,
                        format!("`{n}(…)` takes one number or triple, or three numbers"),
                        "bad constructor",
                    );
                    None
                }
            };
        }
        if n == "float" || n == "int" {
            let ty = if n == "float" { Type::FLOAT } else { Type::INT };
            if checked.len() != 1 || !checked[0].ty.is_scalar_number() {
                self.error(span, format!("`{n}(…)` takes one int or float"), "bad cast");
                return None;
            }
            let arg = checked.pop().expect("one argument");
            if arg.ty == ty {
                return Some(arg);
            }
            if let Some(v) = arg.as_const() {
                return Some(Expr::constant(v.convert(arg.ty, ty), ty, span));
            }
            return Some(Expr { kind: ExprKind::Convert(Box::new(arg)), ty, span });
        }
        if let Some(callee) = self.callees.get(n).filter(|c| c.kind == FunctionKind::Function) {
            if callee.params.len() != checked.len() {
                self.error(
                    span,
                    format!("`{n}` takes {} argument(s), found {}", callee.params.len(), checked.len()),
                    "wrong number of arguments",
                );
                return None;
            }
            let mut out = Vec::new();
            for ((arg, &param), ast_arg) in checked.into_iter().zip(&callee.params).zip(args) {
                out.push(self.coerce(arg, param, ast_arg.span, "argument")?);
            }
            return Some(Expr { kind: ExprKind::Call(callee.id, out), ty: callee.ret, span });
        }
        if let Some(intrinsic) = Intrinsic::from_name(n) {
            let types: Vec<Type> = checked.iter().map(|a| a.ty).collect();
            return match intrinsic.resolve(&types) {
                Ok((params, ret)) => {
                    let args = checked.into_iter().zip(params).map(|(a, p)| a.convert_to(p)).collect();
                    Some(Expr { kind: ExprKind::Intrinsic(intrinsic, args), ty: ret, span })
                }
                Err(message) => {
                    self.error(span, message, "arguments do not fit");
                    None
                }
            };
        }
        if self.callees.contains_key(n) {
            self.error(
                name.span,
                format!("`{n}` is a shader (a node type); it is instantiated in graphs, not called"),
                "not callable",
            );
        } else {
            self.error(name.span, format!("unknown function `{n}`"), "not a built-in or user function");
        }
        None
    }
}

/// The result type of arithmetic between two operand types.
fn arithmetic_type(a: Type, b: Type) -> Option<Type> {
    if !a.is_numeric() || !b.is_numeric() {
        return None;
    }
    if a == b {
        return Some(a);
    }
    if a.is_triple() && b.is_triple() {
        // point - point is a vector; colours never mix with spatial triples.
        return (a.is_spatial() && b.is_spatial()).then_some(Type::VECTOR);
    }
    if a.is_triple() {
        return Some(a);
    }
    if b.is_triple() {
        return Some(b);
    }
    Some(Type::FLOAT)
}

fn component_index(name: &str) -> Option<u8> {
    match name {
        "x" | "r" => Some(0),
        "y" | "g" => Some(1),
        "z" | "b" => Some(2),
        _ => None,
    }
}

fn component_matches(ty: Type, name: &str) -> bool {
    if ty.base == BaseType::Color { matches!(name, "r" | "g" | "b") } else { matches!(name, "x" | "y" | "z") }
}
