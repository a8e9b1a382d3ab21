//! strata: a shading-language compiler for binding-level layered shading.
//!
//! The pipeline, one module per stage. Modules stand on floors (ARCHITECTURE.md, "Floor plan"):
//! ground (`diag`, `input`, `abi`, `runtime`, `stack`), then `front`, `scene`, `compose`, `ir`,
//! `backend`, `render`, and the tools; a module imports only its own floor and those below.
//! - [`diag`]: source files, spans and diagnostics shared by every stage; [`diag::text`]:
//!   scanning loops both lexers share.
//! - [`front`]: substance files (`.ash`) → checked node types and graphs.
//! - [`input`]: bounded reads of every input file (scenes, substances, textures);
//!   [`input::scenes`]: the embedded default scene.
//! - [`scene`]: USD ASCII scenes → a composed prim hierarchy.
//! - [`compose`]: slot bindings → one composed material per renderable prim.
//! - [`ir`]: the wired IR of a composed material, its passes and text form.
//! - [`backend`]: lowered IR → Cranelift JIT, native objects, or the reference interpreter.
//! - [`abi`]: the `#[repr(C)]` contract between compiled materials and the renderer;
//!   [`abi::layering`]: which layers take part in the pick, hide, or weight displacement (rules 5, 6).
//! - [`render`]: the path tracer (geometry, BVH, lights, integrator, EXR output).
//! - [`runtime`]: noise, patterns and math semantics shared by every backend.
//! - [`session`]: the pipeline's entry point: a scene opened, composed, compiled and built
//!   for rendering, updated incrementally after a change.
//! - [`view`]: `strata view`, the live progressive render in the browser over a session.
//! - [`stack`]: the compiler thread with a known stack size that the recursive passes run on.

#![warn(missing_docs)]

pub mod abi;
pub mod backend;
pub mod compose;
pub mod diag;
pub mod front;
pub mod input;
pub mod ir;
pub mod render;
pub mod runtime;
pub mod scene;
pub mod session;
pub mod stack;
pub mod view;
