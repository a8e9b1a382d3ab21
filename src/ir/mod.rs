//! Intermediate representations of composed materials and the passes over them.
//!
//! [`wired`] is the node-graph IR the composition produces (pinned by snapshots);
//! [`eval`] evaluates checked node bodies at compile time for constant folding;
//! [`lower`] turns a wired material into [`ssa`], the typed scalar SSA the backends compile.
//!
//! Architecture invariant: nothing here knows about Cranelift or the renderer.

pub mod eval;
pub mod lower;
pub mod ssa;
pub mod wired;
