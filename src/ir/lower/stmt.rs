//! Lowering statements: blocks, assignments, conditionals and budgeted loops.

use super::{FnLower, Frame, Lv, Storage, layout};
use crate::abi;
use crate::front::hir::{Expr, ExprKind, Place, Stmt};
use crate::front::types::Value;
use crate::ir::ssa::{self, BinOp, CmpOp, Inst, Terminator, Ty};

impl FnLower<'_> {
    pub(super) fn block(&mut self, stmts: &[Stmt], frame: &mut Frame) {
        for stmt in stmts {
            self.stmt(stmt, frame);
        }
    }

    pub(super) fn stmt(&mut self, stmt: &Stmt, frame: &mut Frame) {
        if self.enter() {
            self.stmt_here(stmt, frame);
            self.nesting -= 1;
        }
    }

    pub(super) fn stmt_here(&mut self, stmt: &Stmt, frame: &mut Frame) {
        match stmt {
            Stmt::Assign(place, value) => {
                // An array initialised where it is declared is written in place (no temporary
                // slot, which would double its stack).
                if place.element.is_none()
                    && place.component.is_none()
                    && let Storage::Array { slot, elem, len } = frame.locals[place.local.0 as usize].clone()
                {
                    match &value.kind {
                        ExprKind::Const(Value::Array(items)) => {
                            return self.store_constant_array(slot, elem, len, items);
                        }
                        ExprKind::Array(items) => return self.store_array_items(slot, elem, items, frame),
                        _ => {}
                    }
                }
                let v = self.expr(value, frame);
                self.assign(place, v, frame);
            }
            Stmt::Eval(e) => {
                self.expr(e, frame);
            }
            Stmt::If(cond, then, otherwise) => {
                let c = self.truthy(cond, frame);
                if let Some(k) = self.b.known(c) {
                    return self.block(if k != 0 { then } else { otherwise }, frame);
                }
                let (then_b, else_b, join) = (self.b.block(), self.b.block(), self.b.block());
                self.b.terminate(Terminator::Branch(c, then_b, else_b));
                self.b.switch_to(then_b);
                self.block(then, frame);
                self.b.terminate(Terminator::Jump(join));
                self.b.switch_to(else_b);
                self.block(otherwise, frame);
                self.b.jump_to(join);
            }
            Stmt::Loop { cond, body, step, .. } => {
                let (header, body_b, step_b, exit) = (self.b.block(), self.b.block(), self.b.block(), self.b.block());
                self.b.jump_to(header);
                match cond {
                    Some(cond) => {
                        let c = self.truthy(cond, frame);
                        match self.b.known(c) {
                            Some(0) => self.b.terminate(Terminator::Jump(exit)),
                            Some(_) => self.b.terminate(Terminator::Jump(body_b)),
                            None => self.b.terminate(Terminator::Branch(c, body_b, exit)),
                        }
                        self.b.switch_to(body_b);
                    }
                    None => self.b.jump_to(body_b),
                }
                // The iteration budget: a runaway loop returns a status instead of hanging.
                self.spend_budget(1);
                frame.loops.push((exit, step_b));
                self.loop_nesting += 1;
                self.block(body, frame);
                frame.loops.pop();
                self.loop_nesting -= 1;
                self.b.jump_to(step_b);
                self.block(step, frame);
                self.b.terminate(Terminator::Jump(header));
                self.b.switch_to(exit);
            }
            Stmt::Break => {
                if let Some((exit, _)) = frame.loops.last() {
                    self.b.terminate(Terminator::Jump(*exit));
                }
            }
            Stmt::Continue => {
                if let Some((_, step)) = frame.loops.last() {
                    self.b.terminate(Terminator::Jump(*step));
                }
            }
            Stmt::Return(value) => {
                if let (Some(e), Some(storage)) = (value, frame.ret_value.clone()) {
                    let v = self.expr(e, frame);
                    self.store(&storage, v);
                }
                self.b.terminate(Terminator::Jump(frame.ret));
            }
        }
    }

    pub(super) fn assign(&mut self, place: &Place, value: Lv, frame: &mut Frame) {
        let storage = frame.locals[place.local.0 as usize].clone();
        match (&storage, &place.element) {
            (Storage::Array { slot, elem, len }, Some(index)) => {
                let width = layout(*elem).len() as i32;
                let i = self.expr(index, frame).one();
                self.bounds_check(i, *len as i32);
                let w = self.b.iconst(width);
                let base = self.b.binary(BinOp::IMul, i, w);
                let scalars = value.scalars();
                match &place.component {
                    Some(c) => {
                        let c = self.expr(c, frame).one();
                        self.bounds_check(c, 3);
                        let at = self.b.binary(BinOp::IAdd, base, c);
                        self.b.effect(Inst::Store(*slot, at, scalars[0]));
                    }
                    None => {
                        for (k, s) in scalars.into_iter().enumerate() {
                            let k = self.b.iconst(k as i32);
                            let at = self.b.binary(BinOp::IAdd, base, k);
                            self.b.effect(Inst::Store(*slot, at, s));
                        }
                    }
                }
            }
            (Storage::Vars(vars), None) => match &place.component {
                None => self.store(&storage, value),
                Some(c) => {
                    let x = value.one();
                    if let Some(Value::Int(k)) = c.as_const()
                        && (0..3).contains(k)
                    {
                        self.b.effect(Inst::Set(vars[*k as usize], x));
                        return;
                    }
                    let c = self.expr(c, frame).one();
                    self.bounds_check(c, 3);
                    for (k, var) in vars.iter().enumerate() {
                        let old = self.b.value(Inst::Get(*var), Ty::F32);
                        let kk = self.b.iconst(k as i32);
                        let hit = self.b.cmp(CmpOp::Eq, c, kk);
                        let new = self.b.select(hit, x, old);
                        self.b.effect(Inst::Set(*var, new));
                    }
                }
            },
            _ => self.store(&storage, value),
        }
    }

    pub(super) fn bounds_check(&mut self, i: ssa::Value, len: i32) {
        let zero = self.b.iconst(0);
        let n = self.b.iconst(len);
        let lo = self.b.cmp(CmpOp::Ge, i, zero);
        let hi = self.b.cmp(CmpOp::Lt, i, n);
        let ok = self.b.binary(BinOp::And, lo, hi);
        self.guard(ok, abi::STATUS_OUT_OF_BOUNDS);
    }

    /// A condition as an i32 that is non-zero when true (NaN is true, as in the folder).
    pub(super) fn truthy(&mut self, e: &Expr, frame: &mut Frame) -> ssa::Value {
        let v = self.expr(e, frame).one();
        self.truth(v)
    }

    pub(super) fn truth(&mut self, v: ssa::Value) -> ssa::Value {
        let zero = match self.b.ty(v) {
            Ty::F32 => self.b.fconst(0.0),
            Ty::I32 => self.b.iconst(0),
        };
        self.b.cmp(CmpOp::Ne, v, zero)
    }
}
