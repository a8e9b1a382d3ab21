//! The runtime library: what shader code calls that is not a single machine instruction
//! (noise, cellular patterns, texture lookups, transcendental math). It lives in the
//! `strata-rt` crate (`crates/strata-rt`) so C programs can link it next to native shader
//! objects; the interpreter, the constant folder and JIT-compiled code all call these same
//! functions, so the backends agree.

pub use strata_rt::{math, noise, rt};
pub mod texture;
