//! Cranelift code generation, written once against [`cranelift_module::Module`] so the JIT
//! ([`cranelift_jit::JITModule`]) and shader objects ([`cranelift_object::ObjectModule`]) share
//! it. Every lowered instruction maps to the Cranelift sequence that computes exactly the
//! semantics [`crate::ir::ssa::Inst`] documents (the interpreter's), so results agree bit for bit.

use crate::abi;
use crate::ir::ssa::{self, BinOp, CmpOp, Inst, Terminator, Ty, UnOp};
use crate::runtime::rt::RtFn;
use cranelift_codegen::ir::condcodes::{FloatCC, IntCC};
use cranelift_codegen::ir::{self, AbiParam, InstBuilder, MemFlagsData, StackSlotData, StackSlotKind, types};
use cranelift_codegen::settings::{self, Configurable};
use cranelift_codegen::{Context, isa};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext, Variable};
use cranelift_module::{FuncId, Linkage, Module};
use std::collections::HashMap;

/// Cranelift settings shared by the JIT and object output. The IR verifier runs in debug and
/// test builds (it costs compile time, not run time). Stack probes guard large frames.
pub fn flags(pic: bool) -> settings::Flags {
    let mut b = settings::builder();
    let set = |b: &mut settings::Builder, k: &str, v: &str| {
        b.set(k, v).unwrap_or_else(|e| panic!("cranelift flag {k}={v}: {e}"));
    };
    set(&mut b, "opt_level", "speed");
    set(&mut b, "regalloc_algorithm", "single_pass");
    set(&mut b, "enable_verifier", if cfg!(debug_assertions) { "true" } else { "false" });
    set(&mut b, "is_pic", if pic { "true" } else { "false" });
    set(&mut b, "use_colocated_libcalls", "false");
    // Frames over a page (local arrays, up to `lower::MAX_LOCAL_ARRAY_BYTES`) touch each page in
    // order, so a thread whose stack is too small faults on its guard page instead of writing
    // past it.
    set(&mut b, "enable_probestack", "true");
    set(&mut b, "probestack_strategy", "inline");
    settings::Flags::new(b)
}

/// The host ISA with [`flags`].
pub fn host_isa(pic: bool) -> Result<isa::OwnedTargetIsa, String> {
    let builder = cranelift_native::builder().map_err(|e| format!("unsupported host: {e}"))?;
    builder.finish(flags(pic)).map_err(|e| e.to_string())
}

/// Compiles lowered functions into a Cranelift module.
pub struct CodeGen<M: Module> {
    module: M,
    ctx: Context,
    fctx: FunctionBuilderContext,
    runtime: HashMap<RtFn, FuncId>,
}

impl<M: Module> CodeGen<M> {
    /// Wraps a module.
    pub fn new(module: M) -> Self {
        let ctx = module.make_context();
        CodeGen { module, ctx, fctx: FunctionBuilderContext::new(), runtime: HashMap::new() }
    }

    /// The module, to finalise or emit.
    pub fn into_module(self) -> M {
        self.module
    }

    /// The module being built.
    pub fn module(&self) -> &M {
        &self.module
    }

    /// The C signature of every entry: `u32 f(const Globals *, void *out)`.
    fn entry_signature(&self) -> ir::Signature {
        let ptr = self.module.target_config().pointer_type();
        let mut sig = self.module.make_signature();
        sig.params.push(AbiParam::new(ptr));
        sig.params.push(AbiParam::new(ptr));
        sig.returns.push(AbiParam::new(types::I32));
        sig
    }

    fn runtime_fn(&mut self, f: RtFn) -> Result<FuncId, String> {
        if let Some(id) = self.runtime.get(&f) {
            return Ok(*id);
        }
        let mut sig = self.module.make_signature();
        for i in 0..f.arity() {
            sig.params.push(AbiParam::new(if f.param_is_int(i) { types::I32 } else { types::F32 }));
        }
        sig.returns.push(AbiParam::new(types::F32));
        let id = self.module.declare_function(f.symbol(), Linkage::Import, &sig).map_err(|e| e.to_string())?;
        self.runtime.insert(f, id);
        Ok(id)
    }

    /// Declares and defines `func` under `name`.
    pub fn define(&mut self, name: &str, func: &ssa::Function, linkage: Linkage) -> Result<FuncId, String> {
        ssa::validate(func).map_err(|e| e.to_string())?;
        let sig = self.entry_signature();
        let id = self.module.declare_function(name, linkage, &sig).map_err(|e| e.to_string())?;
        let mut calls = HashMap::new();
        for block in &func.blocks {
            for inst in &block.insts {
                if let Inst::Call(f, _) = &inst.inst
                    && !calls.contains_key(f)
                {
                    let fid = self.runtime_fn(*f)?;
                    calls.insert(*f, fid);
                }
            }
        }
        self.ctx.func.signature = sig;
        let refs: HashMap<RtFn, ir::FuncRef> =
            calls.iter().map(|(f, id)| (*f, self.module.declare_func_in_func(*id, &mut self.ctx.func))).collect();
        let ptr = self.module.target_config().pointer_type();
        let mut fb = FunctionBuilder::new(&mut self.ctx.func, &mut self.fctx);
        translate(&mut fb, func, &refs, ptr);
        fb.seal_all_blocks();
        fb.finalize(self.module.target_config());
        let result = self.module.define_function(id, &mut self.ctx).map_err(|e| format!("{e:?}"));
        self.module.clear_context(&mut self.ctx);
        result.map(|_| id)
    }
}

fn clif_ty(t: Ty) -> ir::Type {
    match t {
        Ty::F32 => types::F32,
        Ty::I32 => types::I32,
    }
}

fn translate(fb: &mut FunctionBuilder, func: &ssa::Function, calls: &HashMap<RtFn, ir::FuncRef>, ptr: ir::Type) {
    let blocks: Vec<ir::Block> = func.blocks.iter().map(|_| fb.create_block()).collect();
    fb.append_block_params_for_function_params(blocks[0]);
    let vars: Vec<Variable> = func.vars.iter().map(|t| fb.declare_var(clif_ty(*t))).collect();
    let slots: Vec<ir::StackSlot> = func
        .slots
        .iter()
        .map(|(_, len)| fb.create_sized_stack_slot(StackSlotData::new(StackSlotKind::ExplicitSlot, len * 4, 2)))
        .collect();
    let mut values: Vec<Option<ir::Value>> = vec![None; func.values.len()];
    fb.switch_to_block(blocks[0]);
    let params = fb.block_params(blocks[0]).to_vec();
    let (globals, out) = (params[0], params[1]);
    let flags = MemFlagsData::trusted();
    for (b, block) in func.blocks.iter().enumerate() {
        if b > 0 {
            fb.switch_to_block(blocks[b]);
        }
        for data in &block.insts {
            let v = |x: &ssa::Value| values[x.0 as usize].expect("validated: defined before use");
            let result = match &data.inst {
                Inst::FConst(x) => Some(fb.ins().f32const(*x)),
                Inst::IConst(i) => Some(fb.ins().iconst(types::I32, *i as i64)),
                Inst::Global(o) => Some(fb.ins().load(types::F32, flags, globals, (*o * 4) as i32)),
                Inst::Primvar(i) => {
                    Some(word_of(fb, ptr, globals, (abi::PRIMVARS_PTR_OFFSET, abi::PRIMVARS_LEN_OFFSET), *i))
                }
                Inst::Param(i) => Some(word_of(fb, ptr, globals, (abi::PARAMS_PTR_OFFSET, abi::PARAMS_LEN_OFFSET), *i)),
                Inst::Unary(op, a) => {
                    let a = v(a);
                    Some(match op {
                        UnOp::FNeg => fb.ins().fneg(a),
                        UnOp::FAbs => fb.ins().fabs(a),
                        UnOp::Sqrt => fb.ins().sqrt(a),
                        UnOp::Floor => fb.ins().floor(a),
                        UnOp::Ceil => fb.ins().ceil(a),
                        UnOp::INeg => fb.ins().ineg(a),
                        UnOp::FToI => fb.ins().fcvt_to_sint_sat(types::I32, a),
                        UnOp::IToF => fb.ins().fcvt_from_sint(types::F32, a),
                    })
                }
                Inst::Binary(op, a, b) => Some(binary(fb, *op, v(a), v(b))),
                Inst::Cmp(op, sa, sb) => {
                    let (a, b) = (v(sa), v(sb));
                    let flag = if func.ty(*sa) == Ty::I32 {
                        let cc = match op {
                            CmpOp::Eq => IntCC::Equal,
                            CmpOp::Ne => IntCC::NotEqual,
                            CmpOp::Lt => IntCC::SignedLessThan,
                            CmpOp::Le => IntCC::SignedLessThanOrEqual,
                            CmpOp::Gt => IntCC::SignedGreaterThan,
                            CmpOp::Ge => IntCC::SignedGreaterThanOrEqual,
                        };
                        fb.ins().icmp(cc, a, b)
                    } else {
                        let cc = match op {
                            CmpOp::Eq => FloatCC::Equal,
                            CmpOp::Ne => FloatCC::NotEqual,
                            CmpOp::Lt => FloatCC::LessThan,
                            CmpOp::Le => FloatCC::LessThanOrEqual,
                            CmpOp::Gt => FloatCC::GreaterThan,
                            CmpOp::Ge => FloatCC::GreaterThanOrEqual,
                        };
                        fb.ins().fcmp(cc, a, b)
                    };
                    Some(fb.ins().uextend(types::I32, flag))
                }
                Inst::Select(c, a, b) => Some(fb.ins().select(v(c), v(a), v(b))),
                Inst::Call(f, args) => {
                    let args: Vec<ir::Value> = args.iter().map(v).collect();
                    let call = fb.ins().call(calls[f], &args);
                    Some(fb.inst_results(call)[0])
                }
                Inst::Get(var) => Some(fb.use_var(vars[var.0 as usize])),
                Inst::Set(var, x) => {
                    fb.def_var(vars[var.0 as usize], v(x));
                    None
                }
                Inst::Load(slot, i) => {
                    let addr = element_addr(fb, slots[slot.0 as usize], v(i), ptr);
                    let ty = clif_ty(func.slots[slot.0 as usize].0);
                    Some(fb.ins().load(ty, flags, addr, 0))
                }
                Inst::Store(slot, i, x) => {
                    let addr = element_addr(fb, slots[slot.0 as usize], v(i), ptr);
                    fb.ins().store(flags, v(x), addr, 0);
                    None
                }
                Inst::Out(o, x) => {
                    fb.ins().store(flags, v(x), out, (*o * 4) as i32);
                    None
                }
            };
            if let (Some(r), Some(val)) = (data.result, result) {
                values[r.0 as usize] = Some(val);
            }
        }
        match block.term.as_ref().expect("validated: terminated") {
            Terminator::Jump(t) => {
                fb.ins().jump(blocks[t.0 as usize], &[]);
            }
            Terminator::Branch(c, t, e) => {
                let c = values[c.0 as usize].expect("validated: defined");
                fb.ins().brif(c, blocks[t.0 as usize], &[], blocks[e.0 as usize], &[]);
            }
            Terminator::Return(status) => {
                let s = fb.ins().iconst(types::I32, *status as i64);
                fb.ins().return_(&[s]);
            }
        }
    }
}

/// Address of 4-byte element `i` of a stack slot (`i` was bounds-checked, so it is ≥ 0).
fn element_addr(fb: &mut FunctionBuilder, slot: ir::StackSlot, i: ir::Value, ptr: ir::Type) -> ir::Value {
    let base = fb.ins().stack_addr(ptr, slot, 0);
    let wide = fb.ins().uextend(ptr, i);
    let offset = fb.ins().ishl_imm_u(wide, 2);
    fb.ins().iadd(base, offset)
}

fn binary(fb: &mut FunctionBuilder, op: BinOp, a: ir::Value, b: ir::Value) -> ir::Value {
    match op {
        BinOp::FAdd => fb.ins().fadd(a, b),
        BinOp::FSub => fb.ins().fsub(a, b),
        BinOp::FMul => fb.ins().fmul(a, b),
        BinOp::FDiv => fb.ins().fdiv(a, b),
        // `math::min`/`max`: `a <= b || b is NaN ? a : b` (Cranelift's fmin propagates NaN).
        BinOp::FMin | BinOp::FMax => {
            let cc = if op == BinOp::FMin { FloatCC::LessThanOrEqual } else { FloatCC::GreaterThanOrEqual };
            let keep = fb.ins().fcmp(cc, a, b);
            let nan = fb.ins().fcmp(FloatCC::Unordered, b, b);
            let take_a = fb.ins().bor(keep, nan);
            fb.ins().select(take_a, a, b)
        }
        BinOp::IAdd => fb.ins().iadd(a, b),
        BinOp::ISub => fb.ins().isub(a, b),
        BinOp::IMul => fb.ins().imul(a, b),
        // `math::int_div`/`int_rem`: divisors 0 and −1 never reach the trapping instruction.
        BinOp::IDiv | BinOp::IRem => {
            let is_zero = fb.ins().icmp_imm_s(IntCC::Equal, b, 0);
            let is_minus_one = fb.ins().icmp_imm_s(IntCC::Equal, b, -1);
            let special = fb.ins().bor(is_zero, is_minus_one);
            let one = fb.ins().iconst(types::I32, 1);
            let safe = fb.ins().select(special, one, b);
            let zero = fb.ins().iconst(types::I32, 0);
            if op == BinOp::IDiv {
                let q = fb.ins().sdiv(a, safe);
                let neg = fb.ins().ineg(a);
                let q = fb.ins().select(is_minus_one, neg, q);
                fb.ins().select(is_zero, zero, q)
            } else {
                let r = fb.ins().srem(a, safe);
                fb.ins().select(special, zero, r)
            }
        }
        BinOp::And => fb.ins().band(a, b),
        BinOp::Or => fb.ins().bor(a, b),
    }
}

/// Word `index` of a borrowed `[f32]` in the globals (its pointer and length at `at`), 0 past
/// its end. Branch-free: past the end, load from the globals themselves (always readable) and
/// select 0, as the interpreter's `PrimvarValues::get` does.
fn word_of(
    fb: &mut FunctionBuilder,
    ptr: types::Type,
    globals: ir::Value,
    at: (usize, usize),
    index: u32,
) -> ir::Value {
    let flags = MemFlagsData::trusted();
    let len = fb.ins().load(types::I32, flags, globals, at.1 as i32);
    let base = fb.ins().load(ptr, flags, globals, at.0 as i32);
    let i = fb.ins().iconst(types::I32, i64::from(index));
    let inside = fb.ins().icmp(IntCC::UnsignedLessThan, i, len);
    let address = fb.ins().iadd_imm_u(base, i64::from(index) * 4);
    let address = fb.ins().select(inside, address, globals);
    let word = fb.ins().load(types::F32, flags, address, 0);
    let zero = fb.ins().f32const(0.0);
    fb.ins().select(inside, word, zero)
}
