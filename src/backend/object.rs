//! Native shader objects: lowered entry functions compiled by Cranelift into a relocatable,
//! position-independent object file with C-callable exported symbols. Calls into the runtime
//! library are left as imports of its stable `strata_rt_*` symbols.

use super::clif::{CodeGen, host_isa};
use crate::ir::ssa;
use cranelift_module::{Linkage, default_libcall_names};
use cranelift_object::{ObjectBuilder, ObjectModule};

/// Compiles the given (symbol, function) pairs into one object file's bytes.
pub fn compile(name: &str, functions: &[(String, &ssa::Function)]) -> Result<Vec<u8>, String> {
    let builder = ObjectBuilder::new(host_isa(true)?, name, default_libcall_names()).map_err(|e| e.to_string())?;
    let mut cg = CodeGen::new(ObjectModule::new(builder));
    for (symbol, f) in functions {
        cg.define(symbol, f, Linkage::Export)?;
    }
    cg.into_module().finish().emit().map_err(|e| e.to_string())
}
