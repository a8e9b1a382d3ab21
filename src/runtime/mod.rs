//! The runtime library: what shader code calls that is not a single machine instruction
//! (noise, cellular patterns, texture lookups, transcendental math). The interpreter, the
//! constant folder and JIT-compiled code all call these same functions, so the backends agree.

pub mod math;
pub mod noise;
pub mod rt;
pub mod texture;
