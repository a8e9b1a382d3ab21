//! Lowering expressions: operators, selects, constructors, indexing and calls.

use super::{FnLower, Frame, Inlined, Lv, MAX_INLINE_DEPTH, layout};
use crate::diag::Diagnostic;
use crate::front::ast::{BaseType, BinaryOp};
use crate::front::hir::{Expr, ExprKind, Global, UnaryOp};
use crate::front::types::Type;
use crate::ir::ssa::{self, BinOp, CmpOp, Inst, Terminator, Ty, UnOp};

impl FnLower<'_> {
    pub(super) fn expr(&mut self, e: &Expr, frame: &mut Frame) -> Lv {
        if !self.enter() {
            return self.placeholder(e.ty);
        }
        self.here = e.span;
        let value = self.expr_here(e, frame);
        self.nesting -= 1;
        value
    }

    /// Lowers a chain of binary operators and conversions along its left spine in a loop (see
    /// `check::binary_chain`): innermost first, each step applied to the value so far, in the
    /// order the recursive form would emit.
    pub(super) fn spine(&mut self, e: &Expr, frame: &mut Frame) -> Lv {
        let (spine, leaf) = e.left_spine();
        let mut acc = self.expr(leaf, frame);
        let mut acc_ty = leaf.ty;
        for node in spine.into_iter().rev() {
            if self.failed {
                return self.placeholder(e.ty);
            }
            acc = match &node.kind {
                ExprKind::Binary(op, _, b) => {
                    // Where a closure sum past its capacity is reported.
                    self.here = node.span;
                    self.binary(*op, acc, acc_ty, b, frame)
                }
                _ => self.convert(acc, acc_ty, node.ty),
            };
            acc_ty = node.ty;
        }
        acc
    }

    pub(super) fn expr_here(&mut self, e: &Expr, frame: &mut Frame) -> Lv {
        match &e.kind {
            ExprKind::Const(v) => self.constant(v, e.ty),
            ExprKind::Local(id) => self.load_local(frame, *id),
            ExprKind::Global(g) => {
                let (offset, n) = match g {
                    Global::P => (ssa::globals::P, 3),
                    Global::N => (ssa::globals::N, 3),
                    Global::Ng => (ssa::globals::NG, 3),
                    Global::I => (ssa::globals::I, 3),
                    Global::DPdu => (ssa::globals::DPDU, 3),
                    Global::DPdv => (ssa::globals::DPDV, 3),
                    Global::U => (ssa::globals::U, 1),
                    Global::V => (ssa::globals::V, 1),
                };
                Lv::Scalars((0..n).map(|k| self.b.value(Inst::Global(offset + k), Ty::F32)).collect())
            }
            ExprKind::Unary(op, a) => {
                let v = self.expr(a, frame).scalars();
                Lv::Scalars(match op {
                    UnaryOp::Neg if a.ty.base == BaseType::Int => vec![self.b.unary(UnOp::INeg, v[0])],
                    UnaryOp::Neg => v.into_iter().map(|x| self.b.unary(UnOp::FNeg, x)).collect(),
                    UnaryOp::Not => {
                        let t = self.truth(v[0]);
                        let zero = self.b.iconst(0);
                        vec![self.b.cmp(CmpOp::Eq, t, zero)]
                    }
                })
            }
            ExprKind::Binary(..) | ExprKind::Convert(_) => self.spine(e, frame),
            ExprKind::Select(c, a, b) => {
                let cond = self.truthy(c, frame);
                if let Some(k) = self.b.known(cond) {
                    return self.expr(if k != 0 { a } else { b }, frame);
                }
                if is_simple(a) && is_simple(b) {
                    let x = self.expr(a, frame).scalars();
                    let y = self.expr(b, frame).scalars();
                    if !x.is_empty() && x.len() == y.len() {
                        return Lv::Scalars(x.iter().zip(&y).map(|(x, y)| self.b.select(cond, *x, *y)).collect());
                    }
                }
                let result = self.storage(e.ty, e.span);
                let (then_b, else_b, join) = (self.b.block(), self.b.block(), self.b.block());
                self.b.terminate(Terminator::Branch(cond, then_b, else_b));
                self.b.switch_to(then_b);
                let x = self.expr(a, frame);
                self.store(&result, x);
                self.b.terminate(Terminator::Jump(join));
                self.b.switch_to(else_b);
                let y = self.expr(b, frame);
                self.store(&result, y);
                self.b.jump_to(join);
                self.load(&result)
            }
            ExprKind::Construct(parts) => {
                Lv::Scalars(parts.iter().map(|p| self.expr(p, frame).one()).collect::<Vec<_>>())
            }
            ExprKind::Component(a, c) => {
                let v = self.expr(a, frame).scalars();
                Lv::Scalars(vec![v[*c as usize]])
            }
            ExprKind::Index(a, i) => {
                let base = self.expr(a, frame);
                let i = self.expr(i, frame).one();
                match base {
                    Lv::Array { slot, elem, len } => {
                        self.bounds_check(i, len as i32);
                        let width = layout(elem).len() as i32;
                        let ty = self.b.func.slots[slot.0 as usize].0;
                        let w = self.b.iconst(width);
                        let at = self.b.binary(BinOp::IMul, i, w);
                        Lv::Scalars(
                            (0..width)
                                .map(|k| {
                                    let k = self.b.iconst(k);
                                    let idx = self.b.binary(BinOp::IAdd, at, k);
                                    self.b.value(Inst::Load(slot, idx), ty)
                                })
                                .collect(),
                        )
                    }
                    Lv::Scalars(t) => {
                        self.bounds_check(i, 3);
                        let (one, two) = (self.b.iconst(1), self.b.iconst(2));
                        let is1 = self.b.cmp(CmpOp::Eq, i, one);
                        let is2 = self.b.cmp(CmpOp::Eq, i, two);
                        let hi = self.b.select(is2, t[2], t[1]);
                        let any = self.b.binary(BinOp::Or, is1, is2);
                        Lv::Scalars(vec![self.b.select(any, hi, t[0])])
                    }
                }
            }
            ExprKind::Array(items) => {
                let len = items.len() as u32;
                let elem = e.ty.element();
                let width = layout(elem).len() as u32;
                let slot = self.array_slot(layout(elem)[0], len * width, e.span);
                self.store_array_items(slot, elem, items, frame);
                Lv::Array { slot, elem, len }
            }
            ExprKind::Intrinsic(intrinsic, args) => self.intrinsic(*intrinsic, args, frame),
            ExprKind::Call(id, args) => {
                let func = self.lib.function(*id);
                if self.depth >= MAX_INLINE_DEPTH {
                    self.diags.push(
                        Diagnostic::error(format!("`{}` nests calls too deeply to inline", func.name))
                            .at(e.span, "called here"),
                    );
                    return self.zero(e.ty);
                }
                let values: Vec<Lv> = args.iter().map(|a| self.expr(a, frame)).collect();
                let mut callee = self.frame(func);
                if let Some(storage) = callee.ret_value.clone() {
                    let zero = self.zero(func.ret);
                    self.store(&storage, zero);
                }
                for (i, v) in values.into_iter().enumerate() {
                    self.bind_param(&mut callee, func, i, v);
                }
                // Locals start at zero, as the folder's frames do once assigned; the checker
                // requires initialisers, so this only matters for robustness.
                self.depth += 1;
                self.inlining.push(Inlined { name: format!("`{}`", func.name), span: e.span });
                self.block(&func.body, &mut callee);
                self.inlining.pop();
                self.depth -= 1;
                self.b.jump_to(callee.ret);
                match &callee.ret_value {
                    Some(storage) => self.load(storage),
                    None => Lv::Scalars(Vec::new()),
                }
            }
        }
    }

    /// `lhs op b`, where `lhs` (of type `lhs_ty`) is already lowered.
    pub(super) fn binary(&mut self, op: BinaryOp, lhs: Lv, lhs_ty: Type, b: &Expr, frame: &mut Frame) -> Lv {
        use BinaryOp::*;
        if matches!(op, And | Or) {
            let l = self.truth(lhs.one());
            if let Some(k) = self.b.known(l) {
                // The left side decides, or the right side is the answer.
                if (k != 0) == (op == Or) {
                    return Lv::Scalars(vec![self.b.iconst((k != 0) as i32)]);
                }
                let r = self.truthy(b, frame);
                return Lv::Scalars(vec![r]);
            }
            if is_simple(b) {
                let r = self.truthy(b, frame);
                let bop = if op == And { BinOp::And } else { BinOp::Or };
                return Lv::Scalars(vec![self.b.binary(bop, l, r)]);
            }
            // Short-circuit: evaluate `b` only when it decides.
            let result = self.b.var(Ty::I32);
            self.b.effect(Inst::Set(result, l));
            let (rhs, join) = (self.b.block(), self.b.block());
            let (t, f) = if op == And { (rhs, join) } else { (join, rhs) };
            self.b.terminate(Terminator::Branch(l, t, f));
            self.b.switch_to(rhs);
            let r = self.truthy(b, frame);
            self.b.effect(Inst::Set(result, r));
            self.b.jump_to(join);
            return Lv::Scalars(vec![self.b.value(Inst::Get(result), Ty::I32)]);
        }
        let at = self.here;
        let x = lhs.scalars();
        let y = self.expr(b, frame).scalars();
        if lhs_ty == Type::CLOSURE {
            // The checker puts the closure on the left: `c + d` or `c * weight`.
            return if op == Add { self.closure_concat(&x, &y, false, at) } else { self.closure_scale(&x, &y) };
        }
        let int = lhs_ty.base == BaseType::Int || lhs_ty.base == BaseType::String;
        if matches!(op, Eq | Ne | Lt | Le | Gt | Ge) {
            let cmp = match op {
                Eq | Ne => CmpOp::Eq,
                Lt => CmpOp::Lt,
                Le => CmpOp::Le,
                Gt => CmpOp::Gt,
                _ => CmpOp::Ge,
            };
            // Triples compare all components (the folder's `cmp`): `!=` is "not all equal".
            let mut all = self.b.cmp(cmp, x[0], y[0]);
            for k in 1..x.len() {
                let c = self.b.cmp(cmp, x[k], y[k]);
                all = self.b.binary(BinOp::And, all, c);
            }
            if op == Ne {
                let zero = self.b.iconst(0);
                all = self.b.cmp(CmpOp::Eq, all, zero);
            }
            return Lv::Scalars(vec![all]);
        }
        if int {
            let bop = match op {
                Add => BinOp::IAdd,
                Sub => BinOp::ISub,
                Mul => BinOp::IMul,
                Div => BinOp::IDiv,
                _ => BinOp::IRem,
            };
            return Lv::Scalars(vec![self.b.binary(bop, x[0], y[0])]);
        }
        Lv::Scalars(
            x.iter()
                .zip(&y)
                .map(|(&p, &q)| match op {
                    Add => self.b.binary(BinOp::FAdd, p, q),
                    Sub => self.b.binary(BinOp::FSub, p, q),
                    Mul => self.b.binary(BinOp::FMul, p, q),
                    Div => self.b.binary(BinOp::FDiv, p, q),
                    _ => self.float_mod(p, q),
                })
                .collect(),
        )
    }

    /// [`crate::runtime::math::float_mod`]: `b == 0 ? 0 : a - b * floor(a / b)`.
    pub(super) fn float_mod(&mut self, a: ssa::Value, b: ssa::Value) -> ssa::Value {
        let q = self.b.binary(BinOp::FDiv, a, b);
        let fl = self.b.unary(UnOp::Floor, q);
        let m = self.b.binary(BinOp::FMul, b, fl);
        let r = self.b.binary(BinOp::FSub, a, m);
        let zero = self.b.fconst(0.0);
        let is_zero = self.b.cmp(CmpOp::Eq, b, zero);
        self.b.select(is_zero, zero, r)
    }

    /// Applies `f` per lane over arguments that are floats or triples of one width (a float
    /// argument broadcasts, as the folder's `map_n` does).
    pub(super) fn lanes(
        &mut self,
        args: &[Vec<ssa::Value>],
        mut f: impl FnMut(&mut Self, &[ssa::Value]) -> ssa::Value,
    ) -> Lv {
        let width = args.iter().map(Vec::len).max().unwrap_or(1);
        let mut out = Vec::with_capacity(width);
        for k in 0..width {
            let lane: Vec<ssa::Value> = args.iter().map(|a| if a.len() == 1 { a[0] } else { a[k] }).collect();
            out.push(f(self, &lane));
        }
        Lv::Scalars(out)
    }
}

/// Whether an expression is cheap, pure and cannot fail, so a select may evaluate it even on
/// the side not taken. Walks the tree with an explicit stack (chains are as deep as long).
pub(super) fn is_simple(e: &Expr) -> bool {
    let mut pending = vec![e];
    while let Some(e) = pending.pop() {
        match &e.kind {
            ExprKind::Const(_) | ExprKind::Local(_) | ExprKind::Global(_) => {}
            ExprKind::Unary(_, a) | ExprKind::Convert(a) | ExprKind::Component(a, _) => pending.push(a),
            ExprKind::Binary(_, a, b) => pending.extend([&**a, &**b]),
            ExprKind::Select(c, a, b) => pending.extend([&**c, &**a, &**b]),
            ExprKind::Construct(parts) => pending.extend(parts.iter()),
            ExprKind::Intrinsic(i, args) if !i.is_varying() => pending.extend(args.iter()),
            ExprKind::Intrinsic(..) | ExprKind::Index(..) | ExprKind::Array(_) | ExprKind::Call(..) => return false,
        }
    }
    true
}
