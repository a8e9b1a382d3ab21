//! The front end: substance files (`.ash`) from text to checked node types and graphs.
//!
//! `lexer` → `parser` (AST with spans, many errors per run) → `check` (types, names → HIR) →
//! `graph` (substance and override graphs resolved against node types) → [`library::Library`].

pub mod ast;
pub mod check;
pub mod graph;
pub mod hir;
pub mod intrinsics;
pub mod lexer;
pub mod library;
pub mod parser;
pub mod types;
