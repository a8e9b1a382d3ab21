//! strata's shader runtime library: what compiled shader code calls that is not a machine
//! instruction (noise, cellular patterns, texture lookups, transcendental math).
//!
//! One implementation serves every consumer, so they compute identical bits: the strata
//! compiler links it as a Rust library (its JIT calls the [`rt`] functions by address, its
//! interpreter and constant folder call them directly), and C programs that load native shader
//! objects link the static library, whose `strata_rt_*` symbols the objects import.

pub mod math;
pub mod noise;
pub mod rt;
pub mod texture;
