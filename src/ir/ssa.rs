//! The lowered IR: typed SSA over scalars, in basic blocks.
//!
//! Every composed material becomes an [`ssa::Module`](Module) of entry functions (masks,
//! per-layer surface, displacement, per-layer normal, per-layer channels). Node bodies and user
//! functions are inlined; triples and closures are split into scalars, so the only value types
//! are `f32` and `i32` and every backend lowers each instruction to one or a few machine
//! operations or one runtime call.
//!
//! Form: values are defined once, by an instruction in a block, and used by later instructions
//! of that block or of blocks it dominates. State that crosses control flow (locals, loop
//! counters) lives in typed **variables** (`get`/`set`), which Cranelift's SSA builder turns
//! into block parameters — the classic alloca-before-mem2reg shape. Fixed-size arrays live in
//! **slots** (scalar memory, indexed after an explicit bounds check). Every entry function has
//! the C signature `u32 f(const Globals *g, void *out)`, returns an [`crate::abi::Status`], and
//! writes 4-byte words at fixed offsets of `out`.
//!
//! Semantics are defined once: [`Inst`] documents each operation in terms of
//! [`crate::runtime`], and both the interpreter and Cranelift implement exactly that.

use crate::abi::MaterialInfo;
use crate::runtime::rt::RtFn;
use std::fmt::{self, Write as _};

/// A scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Ty {
    /// IEEE single.
    F32,
    /// Two's-complement 32-bit integer (also booleans 0/1 and interned string ids).
    I32,
}

impl fmt::Display for Ty {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Ty::F32 => "f32",
            Ty::I32 => "i32",
        })
    }
}

/// An SSA value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Value(pub u32);

/// A basic block; block 0 is the entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Block(pub u32);

/// A mutable scalar variable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Var(pub u32);

/// A fixed-size scalar array in function-local memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Slot(pub u32);

/// Unary operations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum UnOp {
    /// f32 negation.
    FNeg,
    /// f32 absolute value.
    FAbs,
    /// f32 square root (IEEE, correctly rounded).
    Sqrt,
    /// f32 round toward −∞.
    Floor,
    /// f32 round toward +∞.
    Ceil,
    /// i32 wrapping negation.
    INeg,
    /// f32 → i32, truncating, saturating, NaN → 0 ([`crate::runtime::math::float_to_int`]).
    FToI,
    /// i32 → f32, round to nearest.
    IToF,
}

/// Binary operations; both operands have the type the operation names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinOp {
    /// f32 `+`.
    FAdd,
    /// f32 `-`.
    FSub,
    /// f32 `*`.
    FMul,
    /// f32 `/`.
    FDiv,
    /// [`crate::runtime::math::min`].
    FMin,
    /// [`crate::runtime::math::max`].
    FMax,
    /// i32 wrapping `+`.
    IAdd,
    /// i32 wrapping `-`.
    ISub,
    /// i32 wrapping `*`.
    IMul,
    /// [`crate::runtime::math::int_div`] (never traps).
    IDiv,
    /// [`crate::runtime::math::int_rem`] (never traps).
    IRem,
    /// i32 bitwise and (of booleans).
    And,
    /// i32 bitwise or (of booleans).
    Or,
}

impl BinOp {
    /// The operand and result type.
    pub fn ty(self) -> Ty {
        use BinOp::*;
        match self {
            FAdd | FSub | FMul | FDiv | FMin | FMax => Ty::F32,
            _ => Ty::I32,
        }
    }
}

/// Comparisons; on f32 they are IEEE ordered comparisons except `Ne` (true when unordered),
/// as in Rust. The result is an i32 0 or 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CmpOp {
    /// `==`
    Eq,
    /// `!=`
    Ne,
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
}

/// An instruction. Those with a result define exactly one value.
#[derive(Clone, Debug, PartialEq)]
pub enum Inst {
    /// An f32 constant.
    FConst(f32),
    /// An i32 constant.
    IConst(i32),
    /// Reads the f32 at word `offset` of the shading globals.
    Global(u32),
    /// Reads word `index` of the shading point's primvar values (`abi::Globals::primvars`),
    /// 0 past their end.
    Primvar(u32),
    /// Reads word `index` of the material instance's parameter block (`abi::Globals::params`:
    /// a live input compiled as a parameter), 0 past its end.
    Param(u32),
    /// A unary operation.
    Unary(UnOp, Value),
    /// A binary operation.
    Binary(BinOp, Value, Value),
    /// A comparison of two values of the same type.
    Cmp(CmpOp, Value, Value),
    /// `cond != 0 ? a : b` (both already evaluated).
    Select(Value, Value, Value),
    /// A pure runtime-library function of f32 arguments returning f32.
    Call(RtFn, Vec<Value>),
    /// Reads a variable.
    Get(Var),
    /// Writes a variable (no result).
    Set(Var, Value),
    /// Reads element `index` of a slot; `index` was bounds-checked by a dominating branch.
    Load(Slot, Value),
    /// Writes element `index` of a slot (no result).
    Store(Slot, Value, Value),
    /// Writes a 4-byte word at word `offset` of the output (no result).
    Out(u32, Value),
}

/// How a block ends.
#[derive(Clone, Debug, PartialEq)]
pub enum Terminator {
    /// Unconditional jump.
    Jump(Block),
    /// `cond != 0` → first block, else the second.
    Branch(Value, Block, Block),
    /// Leaves the function with a status code.
    Return(u32),
}

/// One instruction with its result.
#[derive(Clone, Debug, PartialEq)]
pub struct InstData {
    /// The value it defines, if any.
    pub result: Option<Value>,
    /// The operation.
    pub inst: Inst,
}

/// A basic block.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockData {
    /// Straight-line instructions.
    pub insts: Vec<InstData>,
    /// The terminator (`None` only while building).
    pub term: Option<Terminator>,
}

/// What an entry function computes (and so what its output buffer holds).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum EntryKind {
    /// One f32: the clamped mask of one layer whose mask is not a compile-time constant.
    Mask(usize),
    /// A [`crate::abi::Closure`] of one layer.
    Surface(usize),
    /// One f32 per layer: displacement height.
    Displacement,
    /// Three f32: one layer's shading normal.
    Normal(usize),
    /// `MaterialInfo::channel_floats` f32: one layer's custom channels.
    Channels(usize),
    /// Three f32: one layer's emitted radiance.
    Emission(usize),
}

impl EntryKind {
    /// The function's symbol suffix.
    pub fn name(self) -> String {
        match self {
            EntryKind::Mask(l) => format!("mask_{l}"),
            EntryKind::Surface(l) => format!("surface_{l}"),
            EntryKind::Displacement => "displacement".into(),
            EntryKind::Normal(l) => format!("normal_{l}"),
            EntryKind::Channels(l) => format!("channels_{l}"),
            EntryKind::Emission(l) => format!("emission_{l}"),
        }
    }
}

/// One entry function.
#[derive(Clone, Debug, PartialEq)]
pub struct Function {
    /// What it computes.
    pub kind: EntryKind,
    /// Output words it writes (the buffer the caller must provide).
    pub out_words: u32,
    /// Type of each value.
    pub values: Vec<Ty>,
    /// Type of each variable.
    pub vars: Vec<Ty>,
    /// Element type and length of each slot.
    pub slots: Vec<(Ty, u32)>,
    /// Blocks; block 0 is the entry.
    pub blocks: Vec<BlockData>,
}

/// All entry functions of one composed material.
#[derive(Clone, Debug, PartialEq)]
pub struct Module {
    /// Layer and channel metadata.
    pub info: MaterialInfo,
    /// The entry functions.
    pub functions: Vec<Function>,
    /// Interned strings: an i32 string value is an index here.
    pub strings: Vec<String>,
}

impl Module {
    /// The function computing `kind`, if the material has one.
    pub fn entry(&self, kind: EntryKind) -> Option<usize> {
        self.functions.iter().position(|f| f.kind == kind)
    }

    /// Instructions over all functions.
    pub fn inst_count(&self) -> usize {
        self.functions.iter().map(|f| f.blocks.iter().map(|b| b.insts.len() + 1).sum::<usize>()).sum()
    }

    /// The stable text form pinned by snapshot tests.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        for (i, s) in self.strings.iter().enumerate() {
            let _ = writeln!(out, "string {i} = {s:?}");
        }
        for f in &self.functions {
            out += &f.to_text();
        }
        out
    }
}

impl Function {
    /// An empty function with an entry block.
    pub fn new(kind: EntryKind, out_words: u32) -> Function {
        Function {
            kind,
            out_words,
            values: Vec::new(),
            vars: Vec::new(),
            slots: Vec::new(),
            blocks: vec![BlockData { insts: Vec::new(), term: None }],
        }
    }

    /// The type of a value.
    pub fn ty(&self, v: Value) -> Ty {
        self.values[v.0 as usize]
    }

    /// The text form of this function.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        let vars: Vec<String> = self.vars.iter().map(|t| t.to_string()).collect();
        let _ = writeln!(out, "fn {}(out: {} words) vars [{}]", self.kind.name(), self.out_words, vars.join(", "));
        for (i, (ty, n)) in self.slots.iter().enumerate() {
            let _ = writeln!(out, "  slot{i}: [{ty}; {n}]");
        }
        for (b, block) in self.blocks.iter().enumerate() {
            let _ = writeln!(out, "block{b}:");
            for inst in &block.insts {
                let _ = write!(out, "  ");
                if let Some(r) = inst.result {
                    let _ = write!(out, "v{}:{} = ", r.0, self.ty(r));
                }
                let _ = writeln!(out, "{}", inst.inst);
            }
            match &block.term {
                Some(t) => {
                    let _ = writeln!(out, "  {t}");
                }
                None => out += "  <unterminated>\n",
            }
        }
        out
    }
}

impl fmt::Display for Inst {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Inst::FConst(x) => write!(f, "fconst {}", crate::front::types::format_f32(*x)),
            Inst::IConst(i) => write!(f, "iconst {i}"),
            Inst::Global(o) => write!(f, "global {}", global_name(*o)),
            Inst::Primvar(i) => write!(f, "primvar {i}"),
            Inst::Param(i) => write!(f, "param {i}"),
            Inst::Unary(op, a) => write!(f, "{} v{}", format!("{op:?}").to_lowercase(), a.0),
            Inst::Binary(op, a, b) => write!(f, "{} v{}, v{}", format!("{op:?}").to_lowercase(), a.0, b.0),
            Inst::Cmp(op, a, b) => write!(f, "cmp.{} v{}, v{}", format!("{op:?}").to_lowercase(), a.0, b.0),
            Inst::Select(c, a, b) => write!(f, "select v{}, v{}, v{}", c.0, a.0, b.0),
            Inst::Call(func, args) => {
                let args: Vec<String> = args.iter().map(|a| format!("v{}", a.0)).collect();
                write!(f, "call {}({})", func.symbol(), args.join(", "))
            }
            Inst::Get(v) => write!(f, "get var{}", v.0),
            Inst::Set(v, x) => write!(f, "set var{}, v{}", v.0, x.0),
            Inst::Load(s, i) => write!(f, "load slot{}[v{}]", s.0, i.0),
            Inst::Store(s, i, x) => write!(f, "store slot{}[v{}], v{}", s.0, i.0, x.0),
            Inst::Out(o, x) => write!(f, "out[{o}] = v{}", x.0),
        }
    }
}

impl fmt::Display for Terminator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Terminator::Jump(b) => write!(f, "jump block{}", b.0),
            Terminator::Branch(c, a, b) => write!(f, "branch v{}, block{}, block{}", c.0, a.0, b.0),
            Terminator::Return(s) => write!(f, "return {s}"),
        }
    }
}

/// Word offsets of the fields of [`crate::abi::Globals`].
pub mod globals {
    /// `P.x`
    pub const P: u32 = 0;
    /// `N.x`
    pub const N: u32 = 3;
    /// `Ng.x`
    pub const NG: u32 = 6;
    /// `I.x`
    pub const I: u32 = 9;
    /// `dPdu.x`
    pub const DPDU: u32 = 12;
    /// `dPdv.x`
    pub const DPDV: u32 = 15;
    /// `u`
    pub const U: u32 = 18;
    /// `v`
    pub const V: u32 = 19;
    /// `st_footprint[0]` (ds/dx, dt/dx, ds/dy, dt/dy follow in order).
    pub const ST_FOOTPRINT: u32 = 20;
    /// Words in the struct.
    pub const WORDS: u32 = 24;
}

fn global_name(offset: u32) -> String {
    const NAMES: [&str; 8] = ["P", "N", "Ng", "I", "dPdu", "dPdv", "u", "v"];
    if offset >= globals::U {
        NAMES[6 + (offset - globals::U) as usize % 2].to_string()
    } else {
        format!("{}.{}", NAMES[(offset / 3) as usize], ["x", "y", "z"][(offset % 3) as usize])
    }
}

/// A structural error found by [`validate`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Invalid(pub String);

impl fmt::Display for Invalid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "invalid lowered IR: {}", self.0)
    }
}

/// Checks a function's structure: every block terminated and every target a block; every value
/// defined once, before its uses in block order, by an instruction of its recorded type; operand
/// types as each operation requires; variables, slots and output words in range. Run after
/// lowering and after every pass (in tests and debug builds the backends run it too).
pub fn validate(f: &Function) -> Result<(), Invalid> {
    let err = |b: usize, msg: String| Err(Invalid(format!("{} block{b}: {msg}", f.kind.name())));
    let mut defined = vec![false; f.values.len()];
    let nblocks = f.blocks.len() as u32;
    for (b, block) in f.blocks.iter().enumerate() {
        for data in &block.insts {
            let ty_of = |v: &Value| -> Result<Ty, String> {
                let i = v.0 as usize;
                if i >= defined.len() || !defined[i] {
                    return Err(format!("v{} used before its definition", v.0));
                }
                Ok(f.values[i])
            };
            let want = |v: &Value, t: Ty| -> Result<(), String> {
                let got = ty_of(v)?;
                if got != t { Err(format!("v{} is {got}, expected {t}", v.0)) } else { Ok(()) }
            };
            let result: Result<Option<Ty>, String> = (|| {
                Ok(match &data.inst {
                    Inst::FConst(_) => Some(Ty::F32),
                    Inst::IConst(_) => Some(Ty::I32),
                    Inst::Global(o) => {
                        if *o >= globals::WORDS {
                            return Err(format!("global offset {o} out of range"));
                        }
                        Some(Ty::F32)
                    }
                    Inst::Primvar(_) | Inst::Param(_) => Some(Ty::F32),
                    Inst::Unary(op, a) => {
                        let (from, to) = match op {
                            UnOp::FNeg | UnOp::FAbs | UnOp::Sqrt | UnOp::Floor | UnOp::Ceil => (Ty::F32, Ty::F32),
                            UnOp::INeg => (Ty::I32, Ty::I32),
                            UnOp::FToI => (Ty::F32, Ty::I32),
                            UnOp::IToF => (Ty::I32, Ty::F32),
                        };
                        want(a, from)?;
                        Some(to)
                    }
                    Inst::Binary(op, a, b) => {
                        want(a, op.ty())?;
                        want(b, op.ty())?;
                        Some(op.ty())
                    }
                    Inst::Cmp(_, a, b) => {
                        let t = ty_of(a)?;
                        want(b, t)?;
                        Some(Ty::I32)
                    }
                    Inst::Select(c, a, b) => {
                        want(c, Ty::I32)?;
                        let t = ty_of(a)?;
                        want(b, t)?;
                        Some(t)
                    }
                    Inst::Call(func, args) => {
                        if args.len() != func.arity() {
                            return Err(format!("{} takes {} arguments", func.symbol(), func.arity()));
                        }
                        for (i, a) in args.iter().enumerate() {
                            want(a, if func.param_is_int(i) { Ty::I32 } else { Ty::F32 })?;
                        }
                        Some(Ty::F32)
                    }
                    Inst::Get(v) => Some(*f.vars.get(v.0 as usize).ok_or("unknown variable")?),
                    Inst::Set(v, x) => {
                        want(x, *f.vars.get(v.0 as usize).ok_or("unknown variable")?)?;
                        None
                    }
                    Inst::Load(s, i) => {
                        want(i, Ty::I32)?;
                        Some(f.slots.get(s.0 as usize).ok_or("unknown slot")?.0)
                    }
                    Inst::Store(s, i, x) => {
                        want(i, Ty::I32)?;
                        want(x, f.slots.get(s.0 as usize).ok_or("unknown slot")?.0)?;
                        None
                    }
                    Inst::Out(o, x) => {
                        ty_of(x)?;
                        if *o >= f.out_words {
                            return Err(format!("out[{o}] past the {} output words", f.out_words));
                        }
                        None
                    }
                })
            })();
            let result = match result {
                Ok(r) => r,
                Err(msg) => return err(b, format!("`{}`: {msg}", data.inst)),
            };
            match (result, data.result) {
                (Some(t), Some(v)) => {
                    let i = v.0 as usize;
                    if i >= defined.len() || defined[i] {
                        return err(b, format!("v{} defined twice or unknown", v.0));
                    }
                    if f.values[i] != t {
                        return err(b, format!("v{} recorded as {} but `{}` gives {t}", v.0, f.values[i], data.inst));
                    }
                    defined[i] = true;
                }
                (None, None) => {}
                _ => return err(b, format!("`{}` has the wrong number of results", data.inst)),
            }
        }
        let targets: Vec<Block> = match &block.term {
            None => return err(b, "not terminated".into()),
            Some(Terminator::Jump(t)) => vec![*t],
            Some(Terminator::Branch(c, t, e)) => {
                if c.0 as usize >= defined.len() || !defined[c.0 as usize] || f.ty(*c) != Ty::I32 {
                    return err(b, format!("branch condition v{} is not a defined i32", c.0));
                }
                vec![*t, *e]
            }
            Some(Terminator::Return(_)) => vec![],
        };
        if let Some(t) = targets.iter().find(|t| t.0 >= nblocks) {
            return err(b, format!("jump to missing block{}", t.0));
        }
    }
    Ok(())
}

/// Builds a [`Function`] block by block. Pure instructions whose operands are constants are
/// folded as they are added (with [`eval_pure`], so nothing changes), which lets lowering see
/// constant conditions and emit only the branch taken.
pub struct Builder {
    /// The function being built.
    pub func: Function,
    current: Block,
    /// The constant word of each value, where known.
    known: Vec<Option<u32>>,
    /// Instructions appended so far (dead ones included): what lowering charges its budget.
    appended: usize,
}

impl Builder {
    /// Starts a function in its entry block.
    pub fn new(kind: EntryKind, out_words: u32) -> Builder {
        Builder { func: Function::new(kind, out_words), current: Block(0), known: Vec::new(), appended: 0 }
    }

    /// Instructions appended so far, including those later found dead.
    pub fn appended(&self) -> usize {
        self.appended
    }

    /// The constant word of `v`, if it is a compile-time constant.
    pub fn known(&self, v: Value) -> Option<u32> {
        self.known.get(v.0 as usize).copied().flatten()
    }

    /// Finishes the function: the open block returns success, and blocks no path reaches
    /// (the dead code after `break`, `return` or a finished branch) are removed.
    pub fn finish(mut self) -> Function {
        if self.func.blocks[self.current.0 as usize].term.is_none() {
            self.func.blocks[self.current.0 as usize].term = Some(Terminator::Return(crate::abi::STATUS_OK));
        }
        self.finish_reachable()
    }

    /// Drops the blocks no path from the entry reaches and renumbers the rest.
    fn finish_reachable(mut self) -> Function {
        let n = self.func.blocks.len();
        let mut reached = vec![false; n];
        let mut stack = vec![0usize];
        while let Some(b) = stack.pop() {
            if std::mem::replace(&mut reached[b], true) {
                continue;
            }
            match &self.func.blocks[b].term {
                Some(Terminator::Jump(t)) => stack.push(t.0 as usize),
                Some(Terminator::Branch(_, t, e)) => stack.extend([t.0 as usize, e.0 as usize]),
                _ => {}
            }
        }
        let mut remap = vec![0u32; n];
        let mut next = 0;
        for (b, r) in reached.iter().enumerate() {
            remap[b] = next;
            next += *r as u32;
        }
        let blocks = std::mem::take(&mut self.func.blocks);
        self.func.blocks = blocks
            .into_iter()
            .zip(&reached)
            .filter(|(_, r)| **r)
            .map(|(mut block, _)| {
                block.term = block.term.map(|t| match t {
                    Terminator::Jump(b) => Terminator::Jump(Block(remap[b.0 as usize])),
                    Terminator::Branch(c, t, e) => {
                        Terminator::Branch(c, Block(remap[t.0 as usize]), Block(remap[e.0 as usize]))
                    }
                    ret => ret,
                });
                block
            })
            .collect();
        self.func
    }

    fn push(&mut self, mut inst: Inst, ty: Option<Ty>) -> Option<Value> {
        let word = match &inst {
            Inst::FConst(x) => Some(x.to_bits()),
            Inst::IConst(i) => Some(*i as u32),
            Inst::Call(crate::runtime::rt::RtFn::Texture | crate::runtime::rt::RtFn::TextureFiltered, _) => None,
            Inst::Unary(..) | Inst::Binary(..) | Inst::Cmp(..) | Inst::Select(..) | Inst::Call(..) => {
                let mut all = true;
                for_each_operand(&inst, |v| all &= self.known(v).is_some());
                if all { eval_pure(&self.func, &inst, |v| self.known(v).unwrap_or(0)) } else { None }
            }
            _ => None,
        };
        if let (Some(w), Some(t)) = (word, ty) {
            inst = match t {
                Ty::F32 => Inst::FConst(f32::from_bits(w)),
                Ty::I32 => Inst::IConst(w as i32),
            };
        }
        let result = ty.map(|t| {
            self.func.values.push(t);
            self.known.push(word);
            Value(self.func.values.len() as u32 - 1)
        });
        self.func.blocks[self.current.0 as usize].insts.push(InstData { result, inst });
        self.appended += 1;
        result
    }

    /// Appends an instruction with a result of type `ty`.
    pub fn value(&mut self, inst: Inst, ty: Ty) -> Value {
        self.push(inst, Some(ty)).expect("a result was requested")
    }

    /// Appends an instruction without a result.
    pub fn effect(&mut self, inst: Inst) {
        self.push(inst, None);
    }

    /// An f32 constant.
    pub fn fconst(&mut self, x: f32) -> Value {
        self.value(Inst::FConst(x), Ty::F32)
    }

    /// An i32 constant.
    pub fn iconst(&mut self, i: i32) -> Value {
        self.value(Inst::IConst(i), Ty::I32)
    }

    /// A binary operation.
    pub fn binary(&mut self, op: BinOp, a: Value, b: Value) -> Value {
        self.value(Inst::Binary(op, a, b), op.ty())
    }

    /// A unary operation.
    pub fn unary(&mut self, op: UnOp, a: Value) -> Value {
        let ty = match op {
            UnOp::INeg | UnOp::FToI => Ty::I32,
            _ => Ty::F32,
        };
        self.value(Inst::Unary(op, a), ty)
    }

    /// A comparison.
    pub fn cmp(&mut self, op: CmpOp, a: Value, b: Value) -> Value {
        self.value(Inst::Cmp(op, a, b), Ty::I32)
    }

    /// A select.
    pub fn select(&mut self, c: Value, a: Value, b: Value) -> Value {
        let ty = self.func.ty(a);
        self.value(Inst::Select(c, a, b), ty)
    }

    /// A runtime call.
    pub fn call(&mut self, func: RtFn, args: Vec<Value>) -> Value {
        self.value(Inst::Call(func, args), Ty::F32)
    }

    /// The type of a value.
    pub fn ty(&self, v: Value) -> Ty {
        self.func.ty(v)
    }

    /// A new variable.
    pub fn var(&mut self, ty: Ty) -> Var {
        self.func.vars.push(ty);
        Var(self.func.vars.len() as u32 - 1)
    }

    /// A new slot.
    pub fn slot(&mut self, ty: Ty, len: u32) -> Slot {
        self.func.slots.push((ty, len));
        Slot(self.func.slots.len() as u32 - 1)
    }

    /// A new, empty block.
    pub fn block(&mut self) -> Block {
        self.func.blocks.push(BlockData { insts: Vec::new(), term: None });
        Block(self.func.blocks.len() as u32 - 1)
    }

    /// Continues in `block`.
    pub fn switch_to(&mut self, block: Block) {
        self.current = block;
    }

    /// Whether the current block already ended (code after `break`/`return`).
    pub fn terminated(&self) -> bool {
        self.func.blocks[self.current.0 as usize].term.is_some()
    }

    /// Ends the current block. Code emitted afterwards lands in a fresh unreachable block, so
    /// callers need not track dead code after `break`, `continue` or `return`.
    pub fn terminate(&mut self, term: Terminator) {
        if self.terminated() {
            return;
        }
        self.func.blocks[self.current.0 as usize].term = Some(term);
        let dead = self.block();
        self.current = dead;
    }

    /// Ends the current block with a jump and continues in `to`.
    pub fn jump_to(&mut self, to: Block) {
        self.terminate(Terminator::Jump(to));
        self.switch_to(to);
    }
}

/// The scalar semantics of one pure instruction on constant operand words, shared by the
/// interpreter and [`simplify`]'s constant folding. `None` for instructions that are not pure
/// arithmetic (memory, variables, globals, output).
pub fn eval_pure(f: &Function, inst: &Inst, operand: impl Fn(Value) -> u32) -> Option<u32> {
    use crate::runtime::math;
    let fl = f32::from_bits;
    Some(match inst {
        Inst::FConst(x) => x.to_bits(),
        Inst::IConst(i) => *i as u32,
        Inst::Unary(op, a) => {
            let a = operand(*a);
            match op {
                UnOp::FNeg => (-fl(a)).to_bits(),
                UnOp::FAbs => fl(a).abs().to_bits(),
                UnOp::Sqrt => fl(a).sqrt().to_bits(),
                UnOp::Floor => fl(a).floor().to_bits(),
                UnOp::Ceil => fl(a).ceil().to_bits(),
                UnOp::INeg => (a as i32).wrapping_neg() as u32,
                UnOp::FToI => math::float_to_int(fl(a)) as u32,
                UnOp::IToF => (a as i32 as f32).to_bits(),
            }
        }
        Inst::Binary(op, a, b) => {
            let (a, b) = (operand(*a), operand(*b));
            let (x, y, i, j) = (fl(a), fl(b), a as i32, b as i32);
            match op {
                BinOp::FAdd => (x + y).to_bits(),
                BinOp::FSub => (x - y).to_bits(),
                BinOp::FMul => (x * y).to_bits(),
                BinOp::FDiv => (x / y).to_bits(),
                BinOp::FMin => math::min(x, y).to_bits(),
                BinOp::FMax => math::max(x, y).to_bits(),
                BinOp::IAdd => i.wrapping_add(j) as u32,
                BinOp::ISub => i.wrapping_sub(j) as u32,
                BinOp::IMul => i.wrapping_mul(j) as u32,
                BinOp::IDiv => math::int_div(i, j) as u32,
                BinOp::IRem => math::int_rem(i, j) as u32,
                BinOp::And => a & b,
                BinOp::Or => a | b,
            }
        }
        Inst::Cmp(op, a, b) => {
            let int = f.ty(*a) == Ty::I32;
            let (a, b) = (operand(*a), operand(*b));
            let ord = if int { (a as i32).partial_cmp(&(b as i32)) } else { fl(a).partial_cmp(&fl(b)) };
            use std::cmp::Ordering::*;
            (match op {
                CmpOp::Eq => ord == Some(Equal),
                CmpOp::Ne => ord != Some(Equal),
                CmpOp::Lt => ord == Some(Less),
                CmpOp::Le => matches!(ord, Some(Less | Equal)),
                CmpOp::Gt => ord == Some(Greater),
                CmpOp::Ge => matches!(ord, Some(Greater | Equal)),
            }) as u32
        }
        Inst::Select(c, a, b) => {
            if operand(*c) != 0 {
                operand(*a)
            } else {
                operand(*b)
            }
        }
        Inst::Call(func, args) => {
            let mut words = [0u32; 8];
            for (w, a) in words.iter_mut().zip(args) {
                *w = operand(*a);
            }
            func.call(&words[..args.len()]).to_bits()
        }
        _ => return None,
    })
}

/// The one cleanup pass over lowered IR: within each block, a `get` of a variable set earlier
/// in the block becomes that value; instructions whose operands are all constants become
/// constants (with [`eval_pure`], the interpreter's own semantics, so nothing changes); branches
/// on constants become jumps; then unused pure instructions, variables never read and
/// unreachable blocks are removed. Texture calls are not folded: they read the registry.
pub fn simplify(f: &mut Function) {
    // A variable set exactly once, to a constant, holds that constant wherever it is read
    // (lowering initialises every local where it is declared, so no read precedes the set):
    // node inputs and `op` strings become constants across blocks, which folds their
    // branches away. Each round can expose more, so repeat while it does.
    let mut constant_vars: std::collections::HashMap<Var, u32> = std::collections::HashMap::new();
    for _ in 0..8 {
        simplify_round(f, &constant_vars);
        let merged = merge_straight_lines(f);
        let mut sets: Vec<(u32, Option<Value>)> = vec![(0, None); f.vars.len()];
        let mut word: Vec<Option<u32>> = vec![None; f.values.len()];
        for block in &f.blocks {
            for data in &block.insts {
                match (&data.inst, data.result) {
                    (Inst::Set(var, x), _) => {
                        let s = &mut sets[var.0 as usize];
                        s.0 += 1;
                        s.1 = Some(*x);
                    }
                    (Inst::FConst(x), Some(r)) => word[r.0 as usize] = Some(x.to_bits()),
                    (Inst::IConst(i), Some(r)) => word[r.0 as usize] = Some(*i as u32),
                    _ => {}
                }
            }
        }
        let before = constant_vars.len();
        for (v, (count, value)) in sets.iter().enumerate() {
            if let (1, Some(x)) = (count, value)
                && let Some(w) = word[x.0 as usize]
            {
                constant_vars.insert(Var(v as u32), w);
            }
        }
        if constant_vars.len() == before && !merged {
            break;
        }
    }
    compact(f);
}

/// Renumbers values and variables densely in definition order, dropping the ones no longer
/// defined or used, so the text form reads `v0, v1, …` and the interpreter's scratch is small.
fn compact(f: &mut Function) {
    let mut value_map: Vec<Option<Value>> = vec![None; f.values.len()];
    let mut values = Vec::new();
    let mut var_map: Vec<Option<Var>> = vec![None; f.vars.len()];
    let mut vars = Vec::new();
    for block in &f.blocks {
        for data in &block.insts {
            if let Some(r) = data.result {
                value_map[r.0 as usize] = Some(Value(values.len() as u32));
                values.push(f.values[r.0 as usize]);
            }
            if let Inst::Get(v) | Inst::Set(v, _) = &data.inst
                && var_map[v.0 as usize].is_none()
            {
                var_map[v.0 as usize] = Some(Var(vars.len() as u32));
                vars.push(f.vars[v.0 as usize]);
            }
        }
    }
    let value = |v: Value| value_map[v.0 as usize].expect("validated: every operand is defined");
    for block in &mut f.blocks {
        for data in &mut block.insts {
            rename(&mut data.inst, value);
            data.result = data.result.map(value);
            if let Inst::Get(v) | Inst::Set(v, _) = &mut data.inst {
                *v = var_map[v.0 as usize].expect("mapped above");
            }
        }
        if let Some(Terminator::Branch(c, ..)) = &mut block.term {
            *c = value(*c);
        }
    }
    f.values = values;
    f.vars = vars;
}

/// Appends each block reached only by a jump from one predecessor to that predecessor (and
/// says whether it merged any), so
/// folded branches leave straight-line code that forwarding and Cranelift see whole. Blocks
/// left empty and unreachable are dropped by the next round.
fn merge_straight_lines(f: &mut Function) -> bool {
    let mut merged = false;
    let mut preds = vec![0u32; f.blocks.len()];
    preds[0] = 1; // the entry has an implicit predecessor
    for block in &f.blocks {
        match &block.term {
            Some(Terminator::Jump(t)) => preds[t.0 as usize] += 1,
            Some(Terminator::Branch(_, t, e)) => {
                preds[t.0 as usize] += 1;
                preds[e.0 as usize] += 1;
            }
            _ => {}
        }
    }
    for b in 0..f.blocks.len() {
        while let Some(Terminator::Jump(t)) = f.blocks[b].term.clone() {
            let t = t.0 as usize;
            if t == b || preds[t] != 1 {
                break;
            }
            let moved = std::mem::replace(&mut f.blocks[t], BlockData { insts: Vec::new(), term: None });
            preds[t] = 0;
            merged = true;
            let block = &mut f.blocks[b];
            block.insts.extend(moved.insts);
            block.term = moved.term;
        }
    }
    // Emptied blocks are unreachable now; give them a terminator so the structure stays valid
    // until `remove_dead` drops them.
    for block in &mut f.blocks {
        if block.term.is_none() {
            block.term = Some(Terminator::Return(crate::abi::STATUS_OK));
        }
    }
    remove_dead(f);
    merged
}

fn simplify_round(f: &mut Function, constant_vars: &std::collections::HashMap<Var, u32>) {
    use crate::runtime::rt::RtFn;
    let mut replace: Vec<Value> = (0..f.values.len() as u32).map(Value).collect();
    let mut constant: Vec<Option<u32>> = vec![None; f.values.len()];
    let resolve = |replace: &Vec<Value>, v: Value| replace[v.0 as usize];
    for b in 0..f.blocks.len() {
        let mut known: std::collections::HashMap<Var, Value> = std::collections::HashMap::new();
        let insts = std::mem::take(&mut f.blocks[b].insts);
        let mut kept = Vec::with_capacity(insts.len());
        for mut data in insts {
            rename(&mut data.inst, |v| resolve(&replace, v));
            match &data.inst {
                Inst::Set(var, x) => {
                    known.insert(*var, *x);
                }
                Inst::Get(var) => {
                    if let (Some(x), Some(r)) = (known.get(var), data.result) {
                        replace[r.0 as usize] = *x;
                        continue;
                    }
                    if let Some(&w) = constant_vars.get(var) {
                        data.inst = match f.vars[var.0 as usize] {
                            Ty::F32 => Inst::FConst(f32::from_bits(w)),
                            Ty::I32 => Inst::IConst(w as i32),
                        };
                    }
                }
                _ => {}
            }
            let foldable = match &data.inst {
                Inst::Call(RtFn::Texture | RtFn::TextureFiltered, _) => false,
                Inst::Unary(_, a) => constant[a.0 as usize].is_some(),
                Inst::Binary(_, a, b) | Inst::Cmp(_, a, b) => {
                    constant[a.0 as usize].is_some() && constant[b.0 as usize].is_some()
                }
                Inst::Select(c, a, b) => match constant[c.0 as usize] {
                    Some(cv) => {
                        // A known condition picks its side even when the sides are not constant.
                        if let Some(r) = data.result {
                            replace[r.0 as usize] = if cv != 0 { *a } else { *b };
                            continue;
                        }
                        false
                    }
                    None => constant[a.0 as usize].is_some() && constant[b.0 as usize].is_some() && a == b,
                },
                Inst::Call(_, args) => args.iter().all(|a| constant[a.0 as usize].is_some()),
                _ => false,
            };
            if let Some(r) = data.result {
                if let Inst::FConst(x) = data.inst {
                    constant[r.0 as usize] = Some(x.to_bits());
                } else if let Inst::IConst(i) = data.inst {
                    constant[r.0 as usize] = Some(i as u32);
                } else if foldable && let Some(word) = eval_pure(f, &data.inst, |v| constant[v.0 as usize].unwrap_or(0))
                {
                    constant[r.0 as usize] = Some(word);
                    data.inst = match f.ty(r) {
                        Ty::F32 => Inst::FConst(f32::from_bits(word)),
                        Ty::I32 => Inst::IConst(word as i32),
                    };
                }
            }
            kept.push(data);
        }
        let block = &mut f.blocks[b];
        block.insts = kept;
        if let Some(Terminator::Branch(c, t, e)) = block.term.clone() {
            let c = resolve(&replace, c);
            block.term = Some(match constant[c.0 as usize] {
                Some(cv) => Terminator::Jump(if cv != 0 { t } else { e }),
                None => Terminator::Branch(c, t, e),
            });
        }
    }
    remove_dead(f);
}

/// Applies `map` to every operand of an instruction.
fn rename(inst: &mut Inst, mut map: impl FnMut(Value) -> Value) {
    match inst {
        Inst::Unary(_, a) | Inst::Set(_, a) | Inst::Out(_, a) | Inst::Load(_, a) => *a = map(*a),
        Inst::Binary(_, a, b) | Inst::Cmp(_, a, b) | Inst::Store(_, a, b) => {
            *a = map(*a);
            *b = map(*b);
        }
        Inst::Select(c, a, b) => {
            *c = map(*c);
            *a = map(*a);
            *b = map(*b);
        }
        Inst::Call(_, args) => args.iter_mut().for_each(|a| *a = map(*a)),
        Inst::FConst(_) | Inst::IConst(_) | Inst::Global(_) | Inst::Primvar(_) | Inst::Param(_) | Inst::Get(_) => {}
    }
}

/// Calls `f` on every operand of an instruction.
fn for_each_operand(inst: &Inst, mut f: impl FnMut(Value)) {
    match inst {
        Inst::Unary(_, a) | Inst::Set(_, a) | Inst::Out(_, a) | Inst::Load(_, a) => f(*a),
        Inst::Binary(_, a, b) | Inst::Cmp(_, a, b) | Inst::Store(_, a, b) => {
            f(*a);
            f(*b);
        }
        Inst::Select(c, a, b) => {
            f(*c);
            f(*a);
            f(*b);
        }
        Inst::Call(_, args) => args.iter().copied().for_each(f),
        Inst::FConst(_) | Inst::IConst(_) | Inst::Global(_) | Inst::Primvar(_) | Inst::Param(_) | Inst::Get(_) => {}
    }
}

/// Removes unreachable blocks, sets of variables nobody reads, and unused pure instructions,
/// until nothing changes. Removal cascades through use counts (an instruction whose last user
/// goes becomes a candidate itself), so a dead chain of any length costs time linear in its
/// size, not one sweep over the function per link.
fn remove_dead(f: &mut Function) {
    let builder = Builder {
        func: std::mem::replace(f, Function::new(EntryKind::Displacement, 0)),
        current: Block(0),
        known: Vec::new(),
        appended: 0,
    };
    *f = builder.finish_reachable();
    let mut uses = vec![0u32; f.values.len()];
    let mut reads = vec![0u32; f.vars.len()];
    let mut def: Vec<Option<(u32, u32)>> = vec![None; f.values.len()];
    let mut sets: Vec<Vec<(u32, u32)>> = vec![Vec::new(); f.vars.len()];
    for (b, block) in f.blocks.iter().enumerate() {
        for (i, data) in block.insts.iter().enumerate() {
            let at = (b as u32, i as u32);
            for_each_operand(&data.inst, |v| uses[v.0 as usize] += 1);
            match data.inst {
                Inst::Get(var) => reads[var.0 as usize] += 1,
                Inst::Set(var, _) => sets[var.0 as usize].push(at),
                _ => {}
            }
            if let Some(r) = data.result {
                def[r.0 as usize] = Some(at);
            }
        }
        if let Some(Terminator::Branch(c, ..)) = &block.term {
            uses[c.0 as usize] += 1;
        }
    }
    let mut dead: Vec<Vec<bool>> = f.blocks.iter().map(|b| vec![false; b.insts.len()]).collect();
    let removable = |data: &InstData, uses: &[u32], reads: &[u32]| match &data.inst {
        Inst::Set(var, _) => reads[var.0 as usize] == 0,
        Inst::Store(..) | Inst::Out(..) => false,
        _ => data.result.is_some_and(|r| uses[r.0 as usize] == 0),
    };
    let mut pending: Vec<(u32, u32)> = Vec::new();
    for (b, block) in f.blocks.iter().enumerate() {
        for (i, data) in block.insts.iter().enumerate() {
            if removable(data, &uses, &reads) {
                pending.push((b as u32, i as u32));
            }
        }
    }
    while let Some((b, i)) = pending.pop() {
        let (bu, iu) = (b as usize, i as usize);
        if dead[bu][iu] {
            continue;
        }
        let data = &f.blocks[bu].insts[iu];
        if !removable(data, &uses, &reads) {
            continue;
        }
        dead[bu][iu] = true;
        for_each_operand(&data.inst, |v| {
            uses[v.0 as usize] -= 1;
            if uses[v.0 as usize] == 0
                && let Some(at) = def[v.0 as usize]
            {
                pending.push(at);
            }
        });
        if let Inst::Get(var) = data.inst {
            reads[var.0 as usize] -= 1;
            if reads[var.0 as usize] == 0 {
                pending.extend(sets[var.0 as usize].iter().copied());
            }
        }
    }
    for (block, dead) in f.blocks.iter_mut().zip(dead) {
        let mut index = 0;
        block.insts.retain(|_| {
            index += 1;
            !dead[index - 1]
        });
    }
}
