//! The reference interpreter: executes lowered IR directly, one instruction at a time, with the
//! semantics [`crate::ir::ssa::Inst`] documents. It is the oracle the JIT is tested against, and
//! a backend the renderer can use (`--backend interp`).

use crate::abi::{self, Status};
use crate::ir::ssa::{Function, Inst, Terminator, eval_pure};
use std::cell::RefCell;

/// Per-thread scratch memory (values, variables, slots), reused across calls so shading
/// allocates nothing once warm.
struct Scratch {
    values: Vec<u32>,
    vars: Vec<u32>,
    slots: Vec<u32>,
    slot_base: Vec<usize>,
}

thread_local! {
    static SCRATCH: RefCell<Scratch> =
        const { RefCell::new(Scratch { values: Vec::new(), vars: Vec::new(), slots: Vec::new(), slot_base: Vec::new() }) };
}

/// Runs `func` with the given globals, writing its output words to `out`
/// (`out.len() >= func.out_words`).
pub fn run(func: &Function, globals: &abi::Globals, out: &mut [u32]) -> Status {
    assert!(out.len() >= func.out_words as usize, "output buffer smaller than the entry writes");
    SCRATCH.with(|s| match s.try_borrow_mut() {
        Ok(mut s) => execute(func, globals, out, &mut s),
        // Re-entered from a runtime call on the same thread (never happens today): use fresh
        // scratch rather than fail.
        Err(_) => execute(
            func,
            globals,
            out,
            &mut Scratch { values: Vec::new(), vars: Vec::new(), slots: Vec::new(), slot_base: Vec::new() },
        ),
    })
}

fn globals_words(g: &abi::Globals) -> [u32; 24] {
    let mut w = [0u32; 24];
    let fields = [g.p, g.n, g.ng, g.i, g.dpdu, g.dpdv];
    for (f, v) in fields.iter().enumerate() {
        for k in 0..3 {
            w[f * 3 + k] = v[k].to_bits();
        }
    }
    w[18] = g.u.to_bits();
    w[19] = g.v.to_bits();
    for (k, v) in g.st_footprint.iter().enumerate() {
        w[20 + k] = v.to_bits();
    }
    w
}

fn execute(func: &Function, globals: &abi::Globals, out: &mut [u32], s: &mut Scratch) -> Status {
    let g = globals_words(globals);
    s.values.clear();
    s.values.resize(func.values.len(), 0);
    s.vars.clear();
    s.vars.resize(func.vars.len(), 0);
    s.slot_base.clear();
    let mut total = 0;
    for (_, len) in &func.slots {
        s.slot_base.push(total);
        total += *len as usize;
    }
    s.slots.clear();
    s.slots.resize(total, 0);
    let mut block = 0usize;
    loop {
        let data = &func.blocks[block];
        for inst in &data.insts {
            let v = |x: &crate::ir::ssa::Value| s.values[x.0 as usize];
            let result: u32 = match &inst.inst {
                Inst::FConst(x) => x.to_bits(),
                Inst::IConst(i) => *i as u32,
                Inst::Global(o) => g[*o as usize],
                Inst::Primvar(i) => globals.primvars.get(*i).to_bits(),
                Inst::Param(i) => globals.params.get(*i).to_bits(),
                Inst::Unary(..) | Inst::Binary(..) | Inst::Cmp(..) | Inst::Select(..) | Inst::Call(..) => {
                    eval_pure(func, &inst.inst, |x| s.values[x.0 as usize]).unwrap_or(0)
                }
                Inst::Get(var) => s.vars[var.0 as usize],
                Inst::Set(var, x) => {
                    s.vars[var.0 as usize] = v(x);
                    continue;
                }
                Inst::Load(slot, i) => {
                    let at = s.slot_base[slot.0 as usize] + v(i) as usize;
                    match s.slots.get(at) {
                        Some(w) => *w,
                        None => return abi::STATUS_OUT_OF_BOUNDS,
                    }
                }
                Inst::Store(slot, i, x) => {
                    let at = s.slot_base[slot.0 as usize] + v(i) as usize;
                    let x = v(x);
                    match s.slots.get_mut(at) {
                        Some(w) => *w = x,
                        None => return abi::STATUS_OUT_OF_BOUNDS,
                    }
                    continue;
                }
                Inst::Out(o, x) => {
                    out[*o as usize] = v(x);
                    continue;
                }
            };
            if let Some(r) = inst.result {
                s.values[r.0 as usize] = result;
            }
        }
        match data.term.as_ref() {
            Some(Terminator::Jump(b)) => block = b.0 as usize,
            Some(Terminator::Branch(c, t, e)) => {
                block = if s.values[c.0 as usize] != 0 { t.0 as usize } else { e.0 as usize };
            }
            Some(Terminator::Return(status)) => return *status,
            None => return abi::STATUS_OK,
        }
    }
}
