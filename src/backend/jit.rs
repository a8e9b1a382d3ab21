//! The JIT: lowered entry functions compiled by Cranelift into executable memory of this
//! process, linked against the runtime library by address.

use super::clif::{CodeGen, host_isa};
use super::{Entries, Material, Runner};
use crate::abi::{Globals, Status};
use crate::ir::ssa;
use crate::runtime::rt::RtFn;
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{Linkage, default_libcall_names};

/// A compiled entry: `u32 f(const Globals *, void *out)`, with the words it writes.
#[derive(Clone, Copy, Debug)]
pub struct JitEntry {
    func: unsafe extern "C" fn(*const Globals, *mut u32) -> u32,
    out_words: u32,
}

/// Owns the executable memory of one material's code.
pub struct JitRunner {
    module: Option<JITModule>,
}

// SAFETY: the module is only read after `finalize_definitions` (the code is immutable and
// calls only pure, thread-safe runtime functions); it is freed once, on drop.
unsafe impl Send for JitRunner {}
unsafe impl Sync for JitRunner {}

impl Drop for JitRunner {
    fn drop(&mut self) {
        if let Some(module) = self.module.take() {
            // SAFETY: the entries pointing into this memory live in the same `Material` and are
            // dropped with it; nothing calls them afterwards.
            unsafe { module.free_memory() };
        }
    }
}

impl Runner for JitRunner {
    type Entry = JitEntry;
    fn run(&self, entry: JitEntry, g: &Globals, out: &mut [u32]) -> Status {
        assert!(out.len() >= entry.out_words as usize, "output buffer smaller than the entry writes");
        // SAFETY: the function was compiled from validated IR whose writes stay within
        // `out_words` words of `out` (checked above) and whose reads stay within `Globals`.
        unsafe { (entry.func)(g, out.as_mut_ptr()) }
    }
}

/// A new JIT module with the runtime library's symbols.
pub fn new_module() -> Result<JITModule, String> {
    let mut builder = JITBuilder::with_isa(host_isa(false)?, default_libcall_names());
    builder.symbols(RtFn::ALL.iter().map(|f| (f.symbol(), f.address())));
    Ok(JITModule::new(builder))
}

/// JIT-compiles every entry of a lowered material.
pub fn compile(module: &ssa::Module) -> Result<Material<JitRunner>, String> {
    let mut cg = CodeGen::new(new_module()?);
    let mut ids = Vec::with_capacity(module.functions.len());
    for f in &module.functions {
        ids.push(cg.define(&f.kind.name(), f, Linkage::Local)?);
    }
    let mut jit = cg.into_module();
    jit.finalize_definitions().map_err(|e| e.to_string())?;
    let entries = Entries::new(module, |i| {
        let code = jit.get_finalized_function(ids[i]);
        // SAFETY: `define` gave every entry exactly this signature.
        let func =
            unsafe { std::mem::transmute::<*const u8, unsafe extern "C" fn(*const Globals, *mut u32) -> u32>(code) };
        JitEntry { func, out_words: module.functions[i].out_words }
    });
    Ok(Material::new(module.info.clone(), entries, JitRunner { module: Some(jit) }))
}
