//! Lowering: wired IR → lowered IR ([`super::ssa`]).
//!
//! Each entry function evaluates, in the wired IR's topological order, exactly the nodes its
//! roots depend on, inlining node bodies and user functions. Triples become three f32 values,
//! closures a kind word plus eight parameters, strings interned i32 ids, arrays slots. Loops
//! spend a per-call iteration budget and array or component indexing is bounds-checked; either
//! failure returns a status code instead of hanging or corrupting memory.
//!
//! The arithmetic mirrors [`super::eval`] operation for operation (same order, same runtime
//! functions), so a folded constant and the compiled code compute the same bits.

use super::eval::MAX_INLINED_NESTING;
use super::ssa::{self, BinOp, Block, Builder, CmpOp, EntryKind, Inst, Module, Slot, Terminator, Ty, UnOp, Var};
use super::wired::{Operand, WiredMaterial};
use crate::abi::{self, ChannelInfo, MaterialInfo, PrimvarInfo};
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::front::ast::{BaseType, BinaryOp};
use crate::front::hir::{Expr, ExprKind, Function, Global, LocalId, Place, Stmt, UnaryOp};
use crate::front::intrinsics::Intrinsic;
use crate::front::library::Library;
use crate::front::types::{Type, Value};
use crate::runtime::rt::RtFn;
use crate::runtime::texture;
use std::collections::HashMap;
use std::path::Path;

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

/// Words of a closure in an output buffer: kind + 8 parameters.
const CLOSURE_WORDS: u32 = 9;

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
            functions.push(cx.entry(EntryKind::Surface(l), CLOSURE_WORDS, |f| {
                let closure = f.operand(surface, Type::CLOSURE);
                f.out_words(0, &closure.scalars());
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

/// A lowered value: scalars (1 for float/int/string, 3 for triples, 9 for closures) or an
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
        BaseType::Closure => {
            let mut v = vec![Ty::I32];
            v.extend([Ty::F32; 8]);
            v
        }
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
                Lv::Scalars(vars.iter().map(|v| self.b.value(Inst::Get(*v), self.b.func.vars[v.0 as usize])).collect())
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

    // ---- statements ------------------------------------------------------------------------

    fn block(&mut self, stmts: &[Stmt], frame: &mut Frame) {
        for stmt in stmts {
            self.stmt(stmt, frame);
        }
    }

    fn stmt(&mut self, stmt: &Stmt, frame: &mut Frame) {
        if self.enter() {
            self.stmt_here(stmt, frame);
            self.nesting -= 1;
        }
    }

    fn stmt_here(&mut self, stmt: &Stmt, frame: &mut Frame) {
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
                self.block(body, frame);
                frame.loops.pop();
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

    fn assign(&mut self, place: &Place, value: Lv, frame: &mut Frame) {
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

    fn bounds_check(&mut self, i: ssa::Value, len: i32) {
        let zero = self.b.iconst(0);
        let n = self.b.iconst(len);
        let lo = self.b.cmp(CmpOp::Ge, i, zero);
        let hi = self.b.cmp(CmpOp::Lt, i, n);
        let ok = self.b.binary(BinOp::And, lo, hi);
        self.guard(ok, abi::STATUS_OUT_OF_BOUNDS);
    }

    /// A condition as an i32 that is non-zero when true (NaN is true, as in the folder).
    fn truthy(&mut self, e: &Expr, frame: &mut Frame) -> ssa::Value {
        let v = self.expr(e, frame).one();
        self.truth(v)
    }

    fn truth(&mut self, v: ssa::Value) -> ssa::Value {
        let zero = match self.b.ty(v) {
            Ty::F32 => self.b.fconst(0.0),
            Ty::I32 => self.b.iconst(0),
        };
        self.b.cmp(CmpOp::Ne, v, zero)
    }

    // ---- expressions -------------------------------------------------------------------------

    fn expr(&mut self, e: &Expr, frame: &mut Frame) -> Lv {
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
    fn spine(&mut self, e: &Expr, frame: &mut Frame) -> Lv {
        let (spine, leaf) = e.left_spine();
        let mut acc = self.expr(leaf, frame);
        let mut acc_ty = leaf.ty;
        for node in spine.into_iter().rev() {
            if self.failed {
                return self.placeholder(e.ty);
            }
            acc = match &node.kind {
                ExprKind::Binary(op, _, b) => self.binary(*op, acc, acc_ty, b, frame),
                _ => self.convert(acc, acc_ty, node.ty),
            };
            acc_ty = node.ty;
        }
        acc
    }

    fn expr_here(&mut self, e: &Expr, frame: &mut Frame) -> Lv {
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
    fn binary(&mut self, op: BinaryOp, lhs: Lv, lhs_ty: Type, b: &Expr, frame: &mut Frame) -> Lv {
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
        let x = lhs.scalars();
        let y = self.expr(b, frame).scalars();
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
    fn float_mod(&mut self, a: ssa::Value, b: ssa::Value) -> ssa::Value {
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
    fn lanes(&mut self, args: &[Vec<ssa::Value>], mut f: impl FnMut(&mut Self, &[ssa::Value]) -> ssa::Value) -> Lv {
        let width = args.iter().map(Vec::len).max().unwrap_or(1);
        let mut out = Vec::with_capacity(width);
        for k in 0..width {
            let lane: Vec<ssa::Value> = args.iter().map(|a| if a.len() == 1 { a[0] } else { a[k] }).collect();
            out.push(f(self, &lane));
        }
        Lv::Scalars(out)
    }

    fn intrinsic(&mut self, i: Intrinsic, args: &[Expr], frame: &mut Frame) -> Lv {
        use Intrinsic::*;
        if i == Texture {
            return self.texture(args, frame);
        }
        if i == TextureChannel {
            return self.texture_channel(args, frame);
        }
        if matches!(i, Primvar | PrimvarFloat | PrimvarVector) {
            return self.primvar(args, frame);
        }
        let a: Vec<Vec<ssa::Value>> = args.iter().map(|x| self.expr(x, frame).scalars()).collect();
        let rt1 = |f: RtFn| move |s: &mut Self, l: &[ssa::Value]| s.b.call(f, vec![l[0]]);
        let un = |op: UnOp| move |s: &mut Self, l: &[ssa::Value]| s.b.unary(op, l[0]);
        match i {
            Sin => self.lanes(&a, rt1(RtFn::Sin)),
            Cos => self.lanes(&a, rt1(RtFn::Cos)),
            Tan => self.lanes(&a, rt1(RtFn::Tan)),
            Asin => self.lanes(&a, rt1(RtFn::Asin)),
            Acos => self.lanes(&a, rt1(RtFn::Acos)),
            Atan => self.lanes(&a, rt1(RtFn::Atan)),
            Exp => self.lanes(&a, rt1(RtFn::Exp)),
            Exp2 => self.lanes(&a, rt1(RtFn::Exp2)),
            Log => self.lanes(&a, rt1(RtFn::Log)),
            Log2 => self.lanes(&a, rt1(RtFn::Log2)),
            Round => self.lanes(&a, rt1(RtFn::Round)),
            Sqrt => self.lanes(&a, un(UnOp::Sqrt)),
            Abs => self.lanes(&a, un(UnOp::FAbs)),
            Floor => self.lanes(&a, un(UnOp::Floor)),
            Ceil => self.lanes(&a, un(UnOp::Ceil)),
            InverseSqrt => self.lanes(&a, |s, l| {
                let r = s.b.unary(UnOp::Sqrt, l[0]);
                let one = s.b.fconst(1.0);
                s.b.binary(BinOp::FDiv, one, r)
            }),
            Fract => self.lanes(&a, |s, l| {
                let f = s.b.unary(UnOp::Floor, l[0]);
                s.b.binary(BinOp::FSub, l[0], f)
            }),
            Sign => self.lanes(&a, |s, l| {
                let (zero, one, minus) = (s.b.fconst(0.0), s.b.fconst(1.0), s.b.fconst(-1.0));
                let pos = s.b.cmp(CmpOp::Gt, l[0], zero);
                let neg = s.b.cmp(CmpOp::Lt, l[0], zero);
                let lo = s.b.select(neg, minus, l[0]);
                s.b.select(pos, one, lo)
            }),
            Radians => self.lanes(&a, |s, l| {
                let k = s.b.fconst(std::f32::consts::PI / 180.0);
                s.b.binary(BinOp::FMul, l[0], k)
            }),
            Degrees => self.lanes(&a, |s, l| {
                let k = s.b.fconst(57.295_78_f32);
                s.b.binary(BinOp::FMul, l[0], k)
            }),
            Pow => self.lanes(&a, |s, l| s.b.call(RtFn::Pow, vec![l[0], l[1]])),
            Atan2 => self.lanes(&a, |s, l| s.b.call(RtFn::Atan2, vec![l[0], l[1]])),
            Min => self.lanes(&a, |s, l| s.b.binary(BinOp::FMin, l[0], l[1])),
            Max => self.lanes(&a, |s, l| s.b.binary(BinOp::FMax, l[0], l[1])),
            Mod => self.lanes(&a, |s, l| s.float_mod(l[0], l[1])),
            Step => self.lanes(&a, |s, l| {
                let (zero, one) = (s.b.fconst(0.0), s.b.fconst(1.0));
                let below = s.b.cmp(CmpOp::Lt, l[1], l[0]);
                s.b.select(below, zero, one)
            }),
            Clamp => self.lanes(&a, |s, l| {
                let lo = s.b.binary(BinOp::FMax, l[0], l[1]);
                s.b.binary(BinOp::FMin, lo, l[2])
            }),
            Smoothstep => self.lanes(&a, |s, l| s.smoothstep(l[0], l[1], l[2])),
            Mix => self.lanes(&a, |s, l| {
                let d = s.b.binary(BinOp::FSub, l[1], l[0]);
                let m = s.b.binary(BinOp::FMul, d, l[2]);
                s.b.binary(BinOp::FAdd, l[0], m)
            }),
            Dot => {
                let d = self.dot(&a[0], &a[1]);
                Lv::Scalars(vec![d])
            }
            Cross => {
                let (x, y) = (&a[0], &a[1]);
                let c = |s: &mut Self, i: usize, j: usize| {
                    let p = s.b.binary(BinOp::FMul, x[i], y[j]);
                    let q = s.b.binary(BinOp::FMul, x[j], y[i]);
                    s.b.binary(BinOp::FSub, p, q)
                };
                Lv::Scalars(vec![c(self, 1, 2), c(self, 2, 0), c(self, 0, 1)])
            }
            Length => {
                let d = self.dot(&a[0], &a[0]);
                Lv::Scalars(vec![self.b.unary(UnOp::Sqrt, d)])
            }
            Normalize => {
                let d = self.dot(&a[0], &a[0]);
                let len = self.b.unary(UnOp::Sqrt, d);
                let zero = self.b.fconst(0.0);
                let positive = self.b.cmp(CmpOp::Gt, len, zero);
                Lv::Scalars(
                    a[0].iter()
                        .map(|&c| {
                            let q = self.b.binary(BinOp::FDiv, c, len);
                            self.b.select(positive, q, zero)
                        })
                        .collect(),
                )
            }
            Distance => {
                let diff: Vec<ssa::Value> =
                    a[0].iter().zip(&a[1]).map(|(&p, &q)| self.b.binary(BinOp::FSub, p, q)).collect();
                let d = self.dot(&diff, &diff);
                Lv::Scalars(vec![self.b.unary(UnOp::Sqrt, d)])
            }
            Luminance => {
                let c = &a[0];
                let w = [0.2126_f32, 0.7152, 0.0722];
                let mut acc = None;
                for k in 0..3 {
                    let wk = self.b.fconst(w[k]);
                    let t = self.b.binary(BinOp::FMul, wk, c[k]);
                    acc = Some(match acc {
                        None => t,
                        Some(s) => self.b.binary(BinOp::FAdd, s, t),
                    });
                }
                Lv::Scalars(vec![acc.expect("three terms")])
            }
            Noise => Lv::Scalars(vec![self.b.call(RtFn::Noise, a[0].clone())]),
            Snoise => Lv::Scalars(vec![self.b.call(RtFn::Snoise, a[0].clone())]),
            Cellnoise => Lv::Scalars(vec![self.b.call(RtFn::Cellnoise, a[0].clone())]),
            Cellular => Lv::Scalars(vec![self.b.call(RtFn::Cellular, a[0].clone())]),
            DiffuseBsdf | GlossyBsdf | MetalBsdf | GlassBsdf => {
                let kind = match i {
                    DiffuseBsdf => abi::ClosureKind::Diffuse,
                    GlossyBsdf => abi::ClosureKind::Glossy,
                    MetalBsdf => abi::ClosureKind::Metal,
                    _ => abi::ClosureKind::Glass,
                };
                let mut scalars = vec![self.b.iconst(kind as i32)];
                scalars.extend(a.iter().flatten().copied());
                while scalars.len() < CLOSURE_WORDS as usize {
                    scalars.push(self.b.fconst(0.0));
                }
                Lv::Scalars(scalars)
            }
            Texture | TextureChannel | Primvar | PrimvarFloat | PrimvarVector => unreachable!("handled above"),
        }
    }

    /// `x0*y0 + x1*y1 + x2*y2`, left to right (the folder's order).
    fn dot(&mut self, x: &[ssa::Value], y: &[ssa::Value]) -> ssa::Value {
        let mut acc = self.b.binary(BinOp::FMul, x[0], y[0]);
        for k in 1..3 {
            let t = self.b.binary(BinOp::FMul, x[k], y[k]);
            acc = self.b.binary(BinOp::FAdd, acc, t);
        }
        acc
    }

    /// [`crate::runtime::math::smoothstep`], branch-free.
    fn smoothstep(&mut self, e0: ssa::Value, e1: ssa::Value, x: ssa::Value) -> ssa::Value {
        let (zero, one, two, three) = (self.b.fconst(0.0), self.b.fconst(1.0), self.b.fconst(2.0), self.b.fconst(3.0));
        let num = self.b.binary(BinOp::FSub, x, e0);
        let den = self.b.binary(BinOp::FSub, e1, e0);
        let q = self.b.binary(BinOp::FDiv, num, den);
        let lo = self.b.binary(BinOp::FMax, q, zero);
        let t = self.b.binary(BinOp::FMin, lo, one);
        let tt = self.b.binary(BinOp::FMul, t, t);
        let t2 = self.b.binary(BinOp::FMul, two, t);
        let k = self.b.binary(BinOp::FSub, three, t2);
        let smooth = self.b.binary(BinOp::FMul, tt, k);
        let below = self.b.cmp(CmpOp::Lt, x, e0);
        let stepped = self.b.select(below, zero, one);
        let same = self.b.cmp(CmpOp::Eq, e1, e0);
        self.b.select(same, stepped, smooth)
    }

    /// A string argument that must be known when compiling (a literal or an input the scene
    /// sets), or `None` after reporting that it is not.
    fn constant_string(&mut self, arg: &Expr, frame: &mut Frame, what: &str) -> Option<String> {
        let value = self.expr(arg, frame).one();
        let known = self.b.known(value).and_then(|id| self.strings.get(id as usize).cloned());
        if known.is_none() {
            self.diags.push(
                Diagnostic::error(format!("{what} must be a constant string (a literal or an input)"))
                    .at(arg.span, "not known when compiling"),
            );
        }
        known
    }

    /// `texture_channel(file, colour space, s, t, mode)`: like [`Self::texture`], one channel,
    /// with the file decoded in the given colour space (`auto`, `sRGB`, `raw`) and the wrap
    /// modes packed into `mode` (passed on to the runtime as it is).
    fn texture_channel(&mut self, args: &[Expr], frame: &mut Frame) -> Lv {
        let file = self.constant_string(&args[0], frame, "texture_channel(): the file name");
        let space = self.constant_string(&args[1], frame, "texture_channel(): the colour space");
        let s = self.expr(&args[2], frame).one();
        let t = self.expr(&args[3], frame).one();
        let mode = self.expr(&args[4], frame).one();
        let space = match space.as_deref().map(|name| (name, texture::ColorSpace::parse(name))) {
            Some((_, Some(space))) => Some(space),
            Some((name, None)) => {
                self.diags.push(
                    Diagnostic::error(format!("unknown colour space `{name}`; expected `auto`, `sRGB` or `raw`"))
                        .at(args[1].span, "colour space named here"),
                );
                None
            }
            None => None,
        };
        let id = match (file, space) {
            (Some(f), Some(_)) if f.is_empty() => -1,
            (Some(f), Some(space)) => match texture::register_file_as(Path::new(&f), space) {
                Ok(id) => id,
                Err(msg) => {
                    self.diags.push(
                        Diagnostic::warning(msg)
                            .at(args[0].span, "texture file named here")
                            .note("the texture reads as black")
                            .kind("unreadable texture"),
                    );
                    -1
                }
            },
            _ => -1,
        };
        let id = self.b.iconst(id);
        Lv::Scalars(vec![self.b.call(RtFn::Texture, vec![id, s, t, mode])])
    }

    /// `primvar*(name, fallback)`: the name must be known when compiling; it gets a place in
    /// the material's primvar table (`abi::MaterialInfo::primvars`, one per name and width,
    /// shared by every entry) and the call reads `present ? value : fallback` per component.
    fn primvar(&mut self, args: &[Expr], frame: &mut Frame) -> Lv {
        let name = self.constant_string(&args[0], frame, "the primvar name");
        let fallback = self.expr(&args[1], frame).scalars();
        let width = fallback.len();
        let Some(name) = name.filter(|n| !n.is_empty()) else { return Lv::Scalars(fallback) };
        let offset = match self.primvars.iter().find(|p| p.name == name && p.width == width) {
            Some(p) => p.offset,
            None => {
                let offset = self.primvars.iter().map(|p| p.offset + 1 + p.width).max().unwrap_or(0);
                self.primvars.push(PrimvarInfo { name, width, offset });
                offset
            }
        } as u32;
        let present = self.b.value(Inst::Primvar(offset), Ty::F32);
        let zero = self.b.fconst(0.0);
        let present = self.b.cmp(CmpOp::Ne, present, zero);
        Lv::Scalars(
            fallback
                .iter()
                .enumerate()
                .map(|(k, &otherwise)| {
                    let value = self.b.value(Inst::Primvar(offset + 1 + k as u32), Ty::F32);
                    self.b.select(present, value, otherwise)
                })
                .collect(),
        )
    }

    /// `texture(file, s, t)`: the file must be known when compiling (a literal or an input
    /// the scene sets); it is loaded now and the call reads the decoded image by id.
    fn texture(&mut self, args: &[Expr], frame: &mut Frame) -> Lv {
        let name = self.expr(&args[0], frame).one();
        let file = self.b.known(name).and_then(|id| self.strings.get(id as usize).cloned());
        let s = self.expr(&args[1], frame).one();
        let t = self.expr(&args[2], frame).one();
        let id = match file {
            None => {
                self.diags.push(
                    Diagnostic::error("texture(): the file name must be a constant string (a literal or an input)")
                        .at(args[0].span, "not known when compiling"),
                );
                -1
            }
            Some(f) if f.is_empty() => -1, // no file: black, like an unconnected texture node
            Some(f) => match texture::register_file(Path::new(&f)) {
                Ok(id) => id,
                Err(msg) => {
                    self.diags.push(
                        Diagnostic::warning(msg)
                            .at(args[0].span, "texture file named here")
                            .note("the texture reads as black")
                            .kind("unreadable texture"),
                    );
                    -1
                }
            },
        };
        let id = self.b.iconst(id);
        Lv::Scalars(
            (0..3)
                .map(|c| {
                    let c = self.b.iconst(c);
                    self.b.call(RtFn::Texture, vec![id, s, t, c])
                })
                .collect(),
        )
    }
}

/// Whether an expression is cheap, pure and cannot fail, so a select may evaluate it even on
/// the side not taken. Walks the tree with an explicit stack (chains are as deep as long).
fn is_simple(e: &Expr) -> bool {
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

/// Whether a body assigns local `local` anywhere.
fn assigns(stmts: &[Stmt], local: u32) -> bool {
    stmts.iter().any(|s| match s {
        Stmt::Assign(p, _) => p.local.0 == local,
        Stmt::If(_, a, b) => assigns(a, local) || assigns(b, local),
        Stmt::Loop { body, step, .. } => assigns(body, local) || assigns(step, local),
        _ => false,
    })
}
