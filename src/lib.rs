//! strata: a shading-language compiler for binding-level layered shading.
//!
//! The pipeline, one module per stage (dependencies point down this list only):
//! - [`diag`]: source files, spans and diagnostics shared by every stage.
//! - [`front`]: substance files (`.ash`) → checked node types and graphs.
//! - [`scene`]: USD ASCII scenes → a composed prim hierarchy.
//! - [`compose`]: slot bindings → one composed material per renderable prim.
//! - [`ir`]: the wired IR of a composed material, its passes and text form.

pub mod compose;
pub mod diag;
pub mod front;
pub mod ir;
pub mod runtime;
