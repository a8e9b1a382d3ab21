//! Lowering: wired IR → lowered IR ([`super::ssa`]).
//!
//! Each entry function evaluates, in the wired IR's topological order, exactly the nodes its
//! roots depend on, inlining node bodies and user functions. Triples become three f32 values,
//! closures fixed arrays of weighted terms ([`closure`]), strings interned i32 ids, arrays slots. Loops
//! spend a per-call iteration budget and array or component indexing is bounds-checked; either
//! failure returns a status code instead of hanging or corrupting memory.
//!
//! The arithmetic mirrors [`super::eval`] operation for operation (same order, same runtime
//! functions), so a folded constant and the compiled code compute the same bits.
//!
//! This module holds the entry functions, storage and budgets; `stmt`, `expr` and
//! `intrinsic` lower statements, expressions and intrinsic calls.

use super::eval::MAX_INLINED_NESTING;
use super::ssa::{self, BinOp, Block, Builder, CmpOp, EntryKind, Inst, Module, Slot, Terminator, Ty, UnOp, Var};
use super::wired::{Operand, WiredMaterial};
use crate::abi::{self, ChannelInfo, MaterialInfo, PrimvarInfo};
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::front::ast::BaseType;
use crate::front::hir::{Expr, Function, LocalId, Stmt};
use crate::front::library::Library;
use crate::front::types::{Type, Value};
use std::collections::HashMap;

mod closure;
mod expr;
mod intrinsic;
mod stmt;

/// Loop iterations one entry call may spend before it stops with
/// [`abi::STATUS_LOOP_BUDGET`]: far above any pattern's needs (fbm's 12 octaves), far below
/// a visible stall.
pub const LOOP_BUDGET: i32 = 1 << 20;

/// Deepest nesting of inlined user functions (recursion is rejected by the checker; this
/// guards a broken library).
const MAX_INLINE_DEPTH: u32 = 64;

/// Lowered instructions one entry function may reach while inlining (dead code included).
/// Real materials lower to a few thousand; the limit leaves room for generated code (a flat
/// chain of 100 000 `+` takes 200 000) and stops exponential inlining (24 functions each
/// calling the previous twice would take 2²⁴ bodies and gigabytes) within a fraction of a
/// second, with a diagnostic that names the chain of calls.
pub const MAX_ENTRY_INSTRUCTIONS: usize = 1 << 19;

/// Bytes of local arrays one entry function may hold. Arrays live in the entry's stack frame
/// (Cranelift stack slots), and entries run on render threads with 2 MiB stacks: 256 KiB keeps
/// the largest frame far from that, and fits one array of the language's largest length
/// (65 536 floats). Past it, a diagnostic at the declaration that crosses the limit.
pub const MAX_LOCAL_ARRAY_BYTES: usize = 256 << 10;

/// Words an array fill or copy moves per unit of the loop budget it spends: one, so that the
/// budget bounds a call's array traffic as it bounds its iterations (a 65 536-element fill
/// spends 6 % of it).
const WORDS_PER_BUDGET_UNIT: u32 = 1;

/// How to lower.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LowerOptions {
    /// Run [`ssa::simplify`] on each function.
    pub simplify: bool,
    /// Charge loops against [`LOOP_BUDGET`]. Off only to measure what the guard costs
    /// (`strata bench shade`); without it a runaway shader hangs its render thread.
    pub loop_budget: bool,
}

impl Default for LowerOptions {
    fn default() -> Self {
        LowerOptions { simplify: true, loop_budget: true }
    }
}

/// Lowers every entry point of a wired material. Problems (a texture file that cannot be
/// read, a non-constant texture name, code past [`MAX_ENTRY_INSTRUCTIONS`],
/// [`MAX_INLINED_NESTING`] or [`MAX_LOCAL_ARRAY_BYTES`]) are reported to `diags`. Runs on the
/// compiler stack ([`crate::stack`]): inlining recurses as deep as the code nests.
pub fn lower(lib: &Library, wired: &WiredMaterial, options: LowerOptions, diags: &mut Diagnostics) -> Module {
    crate::stack::on_compiler_stack(|| lower_here(lib, wired, options, diags))
}

fn lower_here(lib: &Library, wired: &WiredMaterial, options: LowerOptions, diags: &mut Diagnostics) -> Module {
    if let Err(e) = wired.validate(lib) {
        diags.push(Diagnostic::error(format!("internal compiler error: invalid wired IR: {e}")));
    }
    let mut info = material_info(wired);
    let mut strings = Vec::new();
    let mut primvars = Vec::new();
    let mut functions = Vec::new();
    let nlayers = wired.layers.len() as u32;
    let mut cx = Context { lib, wired, strings: &mut strings, primvars: &mut primvars, diags, options };

    // Masks known at compile time live in `info`; the others get one entry each, which
    // `masks` (all layers) and stochastic picking (top-down, stopping early) both call.
    for (l, layer) in info.layers.iter().enumerate() {
        if layer.constant_mask.is_none() {
            functions.push(cx.entry(EntryKind::Mask(l), 1, |f| {
                let m = f.layer_mask(l);
                f.b.effect(Inst::Out(0, m));
            }));
        }
    }
    for (l, layer) in wired.layers.iter().enumerate() {
        if let Some(surface) = &layer.surface {
            functions.push(cx.entry(EntryKind::Surface(l), closure::CLOSURE_WORDS as u32, |f| {
                // Only the terms that may be non-empty are written; the caller clears the rest
                // (`MaterialCode::surface_sum`), so a single lobe costs 20 words, not 160.
                let closure = f.operand(surface, Type::CLOSURE).scalars();
                let live = f.live_terms(&closure);
                f.out_words(0, &closure[..live * closure::TERM_WORDS]);
            }));
        }
    }
    if wired.layers.iter().any(|l| l.displacement.is_some()) {
        functions.push(cx.entry(EntryKind::Displacement, nlayers, |f| {
            for (l, layer) in wired.layers.iter().enumerate() {
                let d = match &layer.displacement {
                    Some((op, _)) => f.operand_scalar(op, Type::FLOAT),
                    None => f.b.fconst(0.0),
                };
                f.b.effect(Inst::Out(l as u32, d));
            }
        }));
    }
    for (l, layer) in wired.layers.iter().enumerate() {
        if let Some(normal) = &layer.normal {
            functions.push(cx.entry(EntryKind::Normal(l), 3, |f| {
                let n = f.operand(normal, Type::NORMAL);
                f.out_words(0, &n.scalars());
            }));
        }
    }
    for (l, layer) in wired.layers.iter().enumerate() {
        if let Some(emission) = &layer.emission {
            functions.push(cx.entry(EntryKind::Emission(l), 3, |f| {
                let e = f.operand(emission, Type::COLOR);
                f.out_words(0, &e.scalars());
            }));
        }
    }
    for (l, layer) in wired.layers.iter().enumerate() {
        if layer.channels.is_empty() {
            continue;
        }
        functions.push(cx.entry(EntryKind::Channels(l), info.channel_floats as u32, |f| {
            let zero = f.b.fconst(0.0);
            for w in 0..info.channel_floats as u32 {
                f.b.effect(Inst::Out(w, zero));
            }
            for channel in &layer.channels {
                let Some(slot) = info.channels.iter().find(|c| c.name == channel.name) else { continue };
                let value = f.operand(&channel.value, channel.ty);
                let as_float = if channel.ty.is_triple() { Type::COLOR } else { Type::FLOAT };
                let value = f.convert(value, channel.ty, as_float);
                f.out_words(slot.offset as u32, &value.scalars());
            }
        }));
    }
    info.primvar_floats = primvars.iter().map(|p: &PrimvarInfo| p.offset + 1 + p.width).max().unwrap_or(0);
    info.primvars = primvars;
    let footprint = ssa::globals::ST_FOOTPRINT..ssa::globals::ST_FOOTPRINT + 4;
    info.ignores_footprint = !functions
        .iter()
        .flat_map(|f| &f.blocks)
        .flat_map(|b| &b.insts)
        .any(|i| matches!(i.inst, Inst::Global(g) if footprint.contains(&g)));
    Module { info, functions, strings }
}

/// Layer and channel metadata of a wired material, as the renderer sees it.
pub fn material_info(wired: &WiredMaterial) -> MaterialInfo {
    let layers = wired.layers.iter().map(|l| l.info()).collect();
    let mut offset = 0;
    let channels = wired
        .channels
        .iter()
        .map(|(name, kind)| {
            let info = ChannelInfo { name: name.clone(), kind: *kind, offset };
            offset += info.width();
            info
        })
        .collect();
    MaterialInfo { layers, channels, channel_floats: offset, ..MaterialInfo::default() }
}

struct Context<'a> {
    lib: &'a Library,
    wired: &'a WiredMaterial,
    strings: &'a mut Vec<String>,
    /// The primvars read so far (by every entry: one table per material).
    primvars: &'a mut Vec<PrimvarInfo>,
    diags: &'a mut Diagnostics,
    options: LowerOptions,
}

impl Context<'_> {
    /// Builds one entry function: `body` reads operands (which pulls in their nodes) and
    /// writes outputs.
    fn entry(&mut self, kind: EntryKind, out_words: u32, body: impl FnOnce(&mut FnLower<'_>)) -> ssa::Function {
        let mut b = Builder::new(kind, out_words);
        let budget = b.var(Ty::I32);
        let start = b.iconst(LOOP_BUDGET);
        b.effect(Inst::Set(budget, start));
        let mut f = FnLower {
            lib: self.lib,
            wired: self.wired,
            strings: self.strings,
            primvars: self.primvars,
            diags: self.diags,
            b,
            node_out: HashMap::new(),
            budget: self.options.loop_budget.then_some(budget),
            fail_blocks: HashMap::new(),
            depth: 0,
            nesting: 0,
            inlining: Vec::new(),
            array_bytes: 0,
            failed: false,
            loop_nesting: 0,
            closure_bounds: HashMap::new(),
            here: Span::default(),
        };
        body(&mut f);
        if f.failed {
            // Reported; what was built is incomplete and may be huge. An empty entry keeps
            // the module well-formed for callers that look at it despite the error.
            return Builder::new(kind, out_words).finish();
        }
        let mut func = f.b.finish();
        debug_assert_eq!(ssa::validate(&func), Ok(()), "after lowering:\n{}", func.to_text());
        if self.options.simplify {
            ssa::simplify(&mut func);
            debug_assert_eq!(ssa::validate(&func), Ok(()), "after simplify:\n{}", func.to_text());
        }
        func
    }
}

/// A lowered value: scalars (1 for float/int/string, 3 for triples, a closure's terms) or an
/// array in a slot.
#[derive(Clone, Debug)]
enum Lv {
    Scalars(Vec<ssa::Value>),
    Array { slot: Slot, elem: Type, len: u32 },
}

impl Lv {
    fn scalars(&self) -> Vec<ssa::Value> {
        match self {
            Lv::Scalars(v) => v.clone(),
            Lv::Array { .. } => Vec::new(),
        }
    }

    fn one(&self) -> ssa::Value {
        match self {
            Lv::Scalars(v) if !v.is_empty() => v[0],
            _ => unreachable!("the checker gives scalar operators scalar operands"),
        }
    }
}

/// Where a local lives.
#[derive(Clone, Debug)]
enum Storage {
    /// A parameter the body never assigns, bound to compile-time constants: reads are those
    /// constants, so conditions on it (`op == "add"`) fold and only the taken branch is lowered.
    Known(Vec<ssa::Value>),
    Vars(Vec<Var>),
    Array {
        slot: Slot,
        elem: Type,
        len: u32,
    },
}

/// The scalar layout of a non-array type.
fn layout(ty: Type) -> Vec<Ty> {
    match ty.base {
        BaseType::Float => vec![Ty::F32],
        BaseType::Int | BaseType::String => vec![Ty::I32],
        BaseType::Color | BaseType::Point | BaseType::Vector | BaseType::Normal => vec![Ty::F32; 3],
        BaseType::Closure => closure::closure_layout(),
        BaseType::Void => Vec::new(),
    }
}

struct Frame {
    locals: Vec<Storage>,
    /// Where `return` jumps, and where a function's result is stored.
    ret: Block,
    ret_value: Option<Storage>,
    /// (break target, continue target) of the enclosing loops, innermost last.
    loops: Vec<(Block, Block)>,
}

struct FnLower<'a> {
    lib: &'a Library,
    wired: &'a WiredMaterial,
    strings: &'a mut Vec<String>,
    primvars: &'a mut Vec<PrimvarInfo>,
    diags: &'a mut Diagnostics,
    b: Builder,
    /// Lowered outputs of the nodes evaluated so far: (node, param) → value.
    node_out: HashMap<(usize, usize), Lv>,
    /// The iteration budget's variable (`None` when loops are not charged).
    budget: Option<Var>,
    /// Shared blocks that return a failure status, by status.
    fail_blocks: HashMap<u32, Block>,
    /// User functions being inlined (for [`MAX_INLINE_DEPTH`]).
    depth: u32,
    /// Statement and expression nesting across inlined bodies (for [`MAX_INLINED_NESTING`]).
    nesting: u32,
    /// The node body and user functions being inlined, outermost first: what a budget
    /// diagnostic names.
    inlining: Vec<Inlined>,
    /// Bytes of slots allocated so far (for [`MAX_LOCAL_ARRAY_BYTES`]).
    array_bytes: usize,
    /// Loops the statement being lowered is in (across inlined bodies).
    loop_nesting: u32,
    /// Per closure variable (by its first `Var`), the terms any assignment so far may have
    /// filled: reads see the terms past it as empty (see `closure`).
    closure_bounds: HashMap<u32, closure::TermBound>,
    /// A budget was exceeded and reported: stop emitting code (the entry is discarded).
    failed: bool,
    /// The expression being lowered (where arrays without a declaration are reported).
    here: Span,
}

/// One level of inlining: a node instance's body or a user function called from it.
struct Inlined {
    /// `` `s` (node `000/n`) `` for a node of type `s`, `` `f` `` for a call of `f`.
    name: String,
    /// The node type's declaration or the call.
    span: Span,
}

impl FnLower<'_> {
    fn out_words(&mut self, at: u32, values: &[ssa::Value]) {
        for (k, v) in values.iter().enumerate() {
            self.b.effect(Inst::Out(at + k as u32, *v));
        }
    }

    /// Layer `l`'s mask clamped to [0, 1]; 1 without a mask.
    fn layer_mask(&mut self, l: usize) -> ssa::Value {
        let layer = &self.wired.layers[l];
        match &layer.mask {
            None => self.b.fconst(1.0),
            Some(mask) => {
                let m = self.operand_scalar(mask, Type::FLOAT);
                let (zero, one) = (self.b.fconst(0.0), self.b.fconst(1.0));
                let m = self.b.binary(BinOp::FMax, m, zero);
                self.b.binary(BinOp::FMin, m, one)
            }
        }
    }

    fn fail_block(&mut self, status: u32) -> Block {
        if let Some(b) = self.fail_blocks.get(&status) {
            return *b;
        }
        let block = self.b.block();
        self.b.func.blocks[block.0 as usize].term = Some(Terminator::Return(status));
        self.fail_blocks.insert(status, block);
        block
    }

    /// Continues only if `ok` is non-zero; otherwise the function returns `status`.
    fn guard(&mut self, ok: ssa::Value, status: u32) {
        let fail = self.fail_block(status);
        let cont = self.b.block();
        self.b.terminate(Terminator::Branch(ok, cont, fail));
        self.b.switch_to(cont);
    }

    // ---- operands and nodes ---------------------------------------------------------------

    fn operand_scalar(&mut self, op: &Operand, ty: Type) -> ssa::Value {
        self.operand(op, ty).one()
    }

    /// The value of a root or node argument, converted to `ty`.
    fn operand(&mut self, op: &Operand, ty: Type) -> Lv {
        match op {
            Operand::Const(v, t) => self.constant(&v.convert(*t, ty), ty),
            Operand::Node { node, param } => {
                let node = node.0 as usize;
                self.ensure_node(node);
                let from = self.lib.function(self.wired.nodes[node].func).params[*param].ty;
                let lv = self.node_out[&(node, *param)].clone();
                self.convert(lv, from, ty)
            }
            Operand::Default => self.zero(ty),
            Operand::Param { offset, ty: from } => {
                let width = if from.is_triple() { 3 } else { 1 };
                let words = (0..width).map(|k| self.b.value(Inst::Param(offset + k), Ty::F32)).collect();
                self.convert(Lv::Scalars(words), *from, ty)
            }
        }
    }

    /// Evaluates a node (and, first, the nodes it reads) unless this function already did.
    fn ensure_node(&mut self, id: usize) {
        // Iterative: a long chain of nodes must not overflow the compiler's stack.
        let mut stack = vec![id];
        while let Some(&top) = stack.last() {
            if self.node_done(top) {
                stack.pop();
                continue;
            }
            let pending: Vec<usize> = self.wired.nodes[top]
                .args
                .iter()
                .filter_map(|a| match a {
                    Operand::Node { node, .. } if !self.node_done(node.0 as usize) => Some(node.0 as usize),
                    _ => None,
                })
                .collect();
            if pending.is_empty() {
                stack.pop();
                self.node(top);
            } else {
                stack.extend(pending);
            }
        }
    }

    fn node_done(&self, id: usize) -> bool {
        let func = self.lib.function(self.wired.nodes[id].func);
        match func.outputs().next() {
            Some((param, _)) => self.node_out.contains_key(&(id, param)),
            None => true, // channel nodes have no outputs: nothing to evaluate
        }
    }

    /// Inlines one node instance.
    fn node(&mut self, id: usize) {
        let lib = self.lib;
        let node = &self.wired.nodes[id];
        let func = lib.function(node.func);
        self.inlining.push(Inlined { name: format!("`{}` (node `{}`)", func.name, node.label), span: func.span });
        let mut frame = self.frame(func);
        for (i, param) in func.params.iter().enumerate() {
            let value = if param.output {
                self.zero(param.ty)
            } else {
                match &node.args[i] {
                    Operand::Default => match &param.default {
                        Some(e) => self.expr(e, &mut frame),
                        None => self.zero(param.ty),
                    },
                    other => self.operand(other, param.ty),
                }
            };
            self.bind_param(&mut frame, func, i, value);
        }
        self.block(&func.body, &mut frame);
        self.b.jump_to(frame.ret);
        for (i, _) in func.outputs() {
            let value = self.load_local(&frame, LocalId(i as u32));
            self.node_out.insert((id, i), value);
        }
        self.inlining.pop();
    }

    /// Storage for every local of a function, and its return block.
    fn frame(&mut self, func: &Function) -> Frame {
        let locals = func.locals.iter().map(|l| self.storage(l.ty, l.span)).collect();
        let ret = self.b.block();
        let ret_value = (func.ret != Type::VOID).then(|| self.storage(func.ret, func.span));
        Frame { locals, ret, ret_value, loops: Vec::new() }
    }

    /// Variables for a scalar or triple, a slot for an array (declared at `span`).
    fn storage(&mut self, ty: Type, span: Span) -> Storage {
        match ty.array {
            Some(len) => {
                let elem = ty.element();
                let width = layout(elem).len() as u32;
                let slot = self.array_slot(layout(elem)[0], len * width, span);
                Storage::Array { slot, elem, len }
            }
            None => Storage::Vars(layout(ty).into_iter().map(|t| self.b.var(t)).collect()),
        }
    }

    /// A slot of `words` words for an array declared (or written) at `span`, charged against
    /// [`MAX_LOCAL_ARRAY_BYTES`].
    fn array_slot(&mut self, ty: Ty, words: u32, span: Span) -> Slot {
        if !self.failed {
            self.array_bytes += words as usize * 4;
            if self.array_bytes > MAX_LOCAL_ARRAY_BYTES {
                let kind = self.b.func.kind.name();
                self.give_up(
                    format!(
                        "local arrays of entry `{kind}` need {} KiB, more than the {} KiB limit",
                        self.array_bytes.div_ceil(1024),
                        MAX_LOCAL_ARRAY_BYTES / 1024
                    ),
                    span,
                    format!("this array ({} KiB) crosses the limit", (words as usize * 4).div_ceil(1024)),
                    "arrays live in the stack frame of the compiled shader, on a render thread's stack; \
                     use fewer or shorter arrays (the arrays of every node and inlined function an entry \
                     evaluates count together)"
                        .to_string(),
                );
            }
        }
        // After a failure the code is discarded: a one-word slot stands in.
        self.b.slot(ty, if self.failed { 1 } else { words })
    }

    fn store(&mut self, storage: &Storage, value: Lv) {
        match (storage, value) {
            (Storage::Vars(vars), Lv::Scalars(values)) => {
                if values.len() == closure::CLOSURE_WORDS {
                    self.closure_stored(vars[0], &values);
                }
                for (var, v) in vars.iter().zip(values) {
                    self.b.effect(Inst::Set(*var, v));
                }
            }
            (Storage::Array { slot, elem, len }, Lv::Array { slot: from, .. }) => {
                if *slot != from {
                    self.copy_slot(from, *slot, len * layout(*elem).len() as u32);
                }
            }
            _ => unreachable!("the checker matches array and scalar assignments"),
        }
    }

    /// Takes `amount` from the loop budget, or returns [`abi::STATUS_LOOP_BUDGET`] when less
    /// than that is left (nothing when loops are not charged).
    fn spend_budget(&mut self, amount: i32) {
        if let Some(budget) = self.budget {
            let left = self.b.value(Inst::Get(budget), Ty::I32);
            let need = self.b.iconst(amount - 1);
            let ok = self.b.cmp(CmpOp::Gt, left, need);
            self.guard(ok, abi::STATUS_LOOP_BUDGET);
            let amount = self.b.iconst(amount);
            let next = self.b.binary(BinOp::ISub, left, amount);
            self.b.effect(Inst::Set(budget, next));
        }
    }

    // ---- arrays ------------------------------------------------------------------------------

    /// Emits `body(at)` for `at` in `0, step, 2·step, … < end`: unrolled for short arrays (as
    /// straight-line stores they fold and read best), as a counted loop otherwise, so code
    /// size never grows with an array's length. The loop is the compiler's own and bounded,
    /// but it may run inside a user loop: it spends one unit of the loop budget per
    /// [`WORDS_PER_BUDGET_UNIT`] words, so that `for (;;) { float a[65536]; }` ends in
    /// milliseconds (it ran for minutes: 2^20 iterations of a 65 536-word fill).
    fn for_each_word(&mut self, end: u32, step: u32, mut body: impl FnMut(&mut Self, ssa::Value)) {
        /// Words up to which initialisation and copies are unrolled.
        const UNROLL_WORDS: u32 = 16;
        if end <= UNROLL_WORDS {
            for at in (0..end).step_by(step.max(1) as usize) {
                let at = self.b.iconst(at as i32);
                body(self, at);
            }
            return;
        }
        self.spend_budget(end.div_ceil(WORDS_PER_BUDGET_UNIT) as i32);
        let counter = self.b.var(Ty::I32);
        let start = self.b.iconst(0);
        self.b.effect(Inst::Set(counter, start));
        let (header, looped, exit) = (self.b.block(), self.b.block(), self.b.block());
        self.b.jump_to(header);
        let at = self.b.value(Inst::Get(counter), Ty::I32);
        let limit = self.b.iconst(end as i32);
        let more = self.b.cmp(CmpOp::Lt, at, limit);
        self.b.terminate(Terminator::Branch(more, looped, exit));
        self.b.switch_to(looped);
        body(self, at);
        let step = self.b.iconst(step as i32);
        let next = self.b.binary(BinOp::IAdd, at, step);
        self.b.effect(Inst::Set(counter, next));
        self.b.terminate(Terminator::Jump(header));
        self.b.switch_to(exit);
    }

    /// Stores one element's words into every element of a slot of `len` elements.
    fn fill_slot(&mut self, slot: Slot, len: u32, element: &[ssa::Value]) {
        let width = element.len() as u32;
        self.for_each_word(len * width, width, |f, at| {
            for (k, v) in element.iter().enumerate() {
                let k = f.b.iconst(k as i32);
                let i = f.b.binary(BinOp::IAdd, at, k);
                f.b.effect(Inst::Store(slot, i, *v));
            }
        });
    }

    /// Copies the first `words` words of `from` into `to`.
    fn copy_slot(&mut self, from: Slot, to: Slot, words: u32) {
        let ty = self.b.func.slots[from.0 as usize].0;
        self.for_each_word(words, 1, |f, at| {
            let v = f.b.value(Inst::Load(from, at), ty);
            f.b.effect(Inst::Store(to, at, v));
        });
    }

    /// Writes a constant array into a slot: one loop when every element is the same (zero
    /// initialisation), element by element otherwise (a literal list, as long as its source).
    fn store_constant_array(&mut self, slot: Slot, elem: Type, len: u32, items: &[Value]) {
        if let Some(first) = items.first()
            && items.len() == len as usize
            && items.iter().all(|item| item == first)
        {
            let element = self.constant(first, elem).scalars();
            self.fill_slot(slot, len, &element);
            return;
        }
        if items.len() != len as usize {
            // Never from the checker; zeros keep the backends in agreement on the rest.
            let zero = self.zero(elem).scalars();
            self.fill_slot(slot, len, &zero);
        }
        let width = layout(elem).len() as u32;
        for (i, item) in items.iter().enumerate().take(len as usize) {
            let scalars = self.constant(item, elem).scalars();
            for (k, s) in scalars.into_iter().enumerate() {
                let index = self.b.iconst((i as u32 * width + k as u32) as i32);
                self.b.effect(Inst::Store(slot, index, s));
            }
        }
    }

    /// Evaluates `{a, b, …}` into a slot, element by element.
    fn store_array_items(&mut self, slot: Slot, elem: Type, items: &[Expr], frame: &mut Frame) {
        let width = layout(elem).len() as u32;
        for (i, item) in items.iter().enumerate() {
            let scalars = self.expr(item, frame).scalars();
            for (k, s) in scalars.into_iter().enumerate() {
                let index = self.b.iconst((i as u32 * width + k as u32) as i32);
                self.b.effect(Inst::Store(slot, index, s));
            }
        }
    }

    fn load(&mut self, storage: &Storage) -> Lv {
        match storage {
            Storage::Vars(vars) => {
                let mut values: Vec<ssa::Value> =
                    vars.iter().map(|v| self.b.value(Inst::Get(*v), self.b.func.vars[v.0 as usize])).collect();
                if values.len() == closure::CLOSURE_WORDS {
                    self.closure_loaded(vars[0], &mut values);
                }
                Lv::Scalars(values)
            }
            Storage::Array { slot, elem, len } => Lv::Array { slot: *slot, elem: *elem, len: *len },
            Storage::Known(values) => Lv::Scalars(values.clone()),
        }
    }

    /// Binds parameter `i` to its value: as known constants when the value is constant and
    /// the body never assigns the parameter, else through its variables.
    fn bind_param(&mut self, frame: &mut Frame, func: &Function, i: usize, value: Lv) {
        if let Lv::Scalars(values) = &value
            && !values.is_empty()
            && values.iter().all(|v| self.b.known(*v).is_some())
            && !assigns(&func.body, i as u32)
        {
            frame.locals[i] = Storage::Known(values.clone());
            return;
        }
        self.store_local(frame, LocalId(i as u32), value);
    }

    fn store_local(&mut self, frame: &Frame, local: LocalId, value: Lv) {
        let storage = frame.locals[local.0 as usize].clone();
        self.store(&storage, value);
    }

    fn load_local(&mut self, frame: &Frame, local: LocalId) -> Lv {
        let storage = frame.locals[local.0 as usize].clone();
        self.load(&storage)
    }

    // ---- constants and conversions -----------------------------------------------------------

    fn intern(&mut self, s: &str) -> i32 {
        match self.strings.iter().position(|x| x == s) {
            Some(i) => i as i32,
            None => {
                self.strings.push(s.to_string());
                self.strings.len() as i32 - 1
            }
        }
    }

    fn constant(&mut self, v: &Value, ty: Type) -> Lv {
        if let (Some(len), Value::Array(items)) = (ty.array, v) {
            let elem = ty.element();
            let width = layout(elem).len() as u32;
            let slot = self.array_slot(layout(elem)[0], len * width, self.here);
            self.store_constant_array(slot, elem, len, items);
            return Lv::Array { slot, elem, len };
        }
        Lv::Scalars(match v {
            Value::Int(i) if ty.base == BaseType::Float => vec![self.b.fconst(*i as f32)],
            Value::Int(i) => vec![self.b.iconst(*i)],
            Value::Float(x) if ty.base == BaseType::Int => vec![self.b.iconst(*x as i32)],
            Value::Float(x) if ty.is_triple() => vec![self.b.fconst(*x); 3],
            Value::Float(x) => vec![self.b.fconst(*x)],
            Value::Triple(t) => t.iter().map(|x| self.b.fconst(*x)).collect(),
            Value::Str(s) => {
                let id = self.intern(s);
                vec![self.b.iconst(id)]
            }
            Value::Array(_) => return self.zero(ty),
        })
    }

    fn zero(&mut self, ty: Type) -> Lv {
        if let Some(len) = ty.array {
            // Filled in a loop, without building a constant of `len` elements first.
            let elem = ty.element();
            let width = layout(elem).len() as u32;
            let slot = self.array_slot(layout(elem)[0], len * width, self.here);
            if !self.failed {
                let element = self.zero(elem).scalars();
                self.fill_slot(slot, len, &element);
            }
            return Lv::Array { slot, elem, len };
        }
        match Value::zero(ty) {
            Some(v) => self.constant(&v, ty),
            None => {
                // A closure nobody assigned: kind None, zero parameters.
                let scalars = layout(ty)
                    .into_iter()
                    .map(|t| if t == Ty::I32 { self.b.iconst(0) } else { self.b.fconst(0.0) })
                    .collect();
                Lv::Scalars(scalars)
            }
        }
    }

    /// Converts between types as [`Value::convert`] (and `eval::convert`) do.
    fn convert(&mut self, lv: Lv, from: Type, to: Type) -> Lv {
        if from == to || from.array.is_some() {
            return lv;
        }
        let Lv::Scalars(s) = lv else { return lv };
        Lv::Scalars(match (from.base, to.base) {
            (BaseType::Int, BaseType::Float) => vec![self.b.unary(UnOp::IToF, s[0])],
            (BaseType::Float, BaseType::Int) => vec![self.b.unary(UnOp::FToI, s[0])],
            (BaseType::Int, _) if to.is_triple() => vec![self.b.unary(UnOp::IToF, s[0]); 3],
            (BaseType::Float, _) if to.is_triple() => vec![s[0]; 3],
            _ => s,
        })
    }

    // ---- budgets -----------------------------------------------------------------------------

    /// The inlining chain, outermost first: `` `s` (node `000/n`) → `f24` → … → `f3` ``.
    fn inlining_chain(&self) -> String {
        let names: Vec<&str> = self.inlining.iter().map(|i| i.name.as_str()).collect();
        if names.len() <= 12 {
            names.join(" → ")
        } else {
            format!("{} → … → {}", names[..6].join(" → "), names[names.len() - 5..].join(" → "))
        }
    }

    /// Reports a budget crossed and stops lowering this entry (only the first is reported).
    fn give_up(&mut self, message: String, span: Span, label: String, note: String) {
        if self.failed {
            return;
        }
        self.failed = true;
        let mut diagnostic = Diagnostic::error(message).at(span, label);
        if self.inlining.len() > 1
            && let Some(innermost) = self.inlining.last()
            && innermost.span != span
        {
            diagnostic = diagnostic.also(innermost.span, "innermost call being inlined");
        }
        self.diags.push(diagnostic.note(note));
    }

    /// Checks the instruction budget and takes one more level of nesting; `false` once
    /// lowering has given up (the caller then emits nothing).
    fn enter(&mut self) -> bool {
        if self.failed {
            return false;
        }
        if self.b.appended() > MAX_ENTRY_INSTRUCTIONS {
            let kind = self.b.func.kind.name();
            // The outermost call of the chain is where the code can be changed.
            let span = self.inlining.get(1).or(self.inlining.first()).map(|i| i.span).unwrap_or(self.here);
            let chain = self.inlining_chain();
            let message = if self.inlining.len() > 1 {
                format!("inlining {chain} exceeds {MAX_ENTRY_INSTRUCTIONS} lowered instructions")
            } else {
                format!("{chain} lowers to more than {MAX_ENTRY_INSTRUCTIONS} instructions")
            };
            self.give_up(
                message,
                span,
                "expands to too much code".into(),
                format!(
                    "while compiling entry `{kind}`: every call is inlined, so a function that calls \
                     another twice is twice its size; call functions fewer times, or call them in a loop"
                ),
            );
            return false;
        }
        if self.nesting >= MAX_INLINED_NESTING {
            let span = self.here;
            let chain = self.inlining_chain();
            self.give_up(
                format!("code nests deeper than {MAX_INLINED_NESTING} levels once {chain} is inlined"),
                span,
                "nesting limit reached here".into(),
                "statements and expressions of inlined functions nest inside their callers'; \
                 flatten the code or use local variables"
                    .into(),
            );
            return false;
        }
        self.nesting += 1;
        true
    }

    /// A stand-in value of type `ty` after lowering gave up.
    fn placeholder(&mut self, ty: Type) -> Lv {
        match ty.array {
            Some(len) => {
                let elem = ty.element();
                Lv::Array { slot: self.b.slot(layout(elem)[0], 1), elem, len }
            }
            None => self.zero(ty),
        }
    }
}

/// Whether a body assigns local `local` anywhere.
fn assigns(stmts: &[Stmt], local: u32) -> bool {
    stmts.iter().any(|s| match s {
        Stmt::Assign(p, _) => p.local.0 == local,
        Stmt::If(_, a, b) => assigns(a, local) || assigns(b, local),
        Stmt::Loop { body, step, .. } => assigns(body, local) || assigns(step, local),
        _ => false,
    })
}
