//! Intermediate representations of composed materials and the passes over them.
//!
//! [`wired`] is the node-graph IR the composition produces (pinned by snapshots);
//! [`eval`] evaluates checked node bodies at compile time for constant folding.

pub mod eval;
pub mod wired;
