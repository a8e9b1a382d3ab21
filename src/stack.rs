//! The compiler's own stack.
//!
//! Parsing, checking, folding and lowering recurse over the nesting of the source, so the
//! stack they need grows with it. Two things keep that bounded whatever the input:
//!
//! - every recursive pass has a documented depth limit ([`crate::front::parser::MAX_NESTING`]
//!   for source nesting, [`crate::ir::eval::MAX_INLINED_NESTING`] once function bodies are
//!   inlined into one another) and long flat chains (`x + x + …`, 100 000 terms) are walked
//!   iteratively, so depth never grows with the length of a chain;
//! - the passes run on a thread whose stack size is known ([`COMPILER_STACK_BYTES`]), not on
//!   whatever thread called the library. A debug build spends 5–12 KiB of stack per nesting
//!   level in the parser and checker and about 9 KiB per level in lowering (a release build far
//!   less): measured at the limits, parsing and checking 256 nested calls take 3 MiB and
//!   lowering code inlined 1 024 levels deep 9 MiB. That is more than a `cargo test` thread
//!   (2 MiB) or a rayon worker has, and far less than this stack.
//!
//! The public entry points of those passes call [`on_compiler_stack`]; inside it they call one
//! another directly.

use std::cell::Cell;

/// Stack size of the compiler thread. Address space only: pages are committed as they are
/// touched, and the depth limits keep the deepest legal input within a sixth of it in a debug
/// build (`tests/hostile.rs` compiles inputs at the limits from 2 MiB test threads).
pub const COMPILER_STACK_BYTES: usize = 64 << 20;

thread_local! {
    static ON_COMPILER_STACK: Cell<bool> = const { Cell::new(false) };
}

/// Runs `task` on a thread with a [`COMPILER_STACK_BYTES`] stack (or directly, when already on
/// one) and returns its result. A panic in `task` is resumed on the calling thread. If no
/// thread can be started, `task` runs on the calling thread.
pub fn on_compiler_stack<R: Send>(task: impl FnOnce() -> R + Send) -> R {
    if ON_COMPILER_STACK.with(Cell::get) {
        return task();
    }
    let mut pending = Some(task);
    let outcome = std::thread::scope(|scope| {
        let spawned = std::thread::Builder::new()
            .name("strata-compiler".into())
            .stack_size(COMPILER_STACK_BYTES)
            .spawn_scoped(scope, || {
                ON_COMPILER_STACK.with(|on| on.set(true));
                pending.take().map(|task| task())
            });
        spawned.ok().map(|handle| handle.join())
    });
    match outcome {
        Some(Ok(Some(result))) => result,
        Some(Err(panic)) => std::panic::resume_unwind(panic),
        // The thread could not be started (or ran nothing): run here rather than fail.
        Some(Ok(None)) | None => match pending.take() {
            Some(task) => task(),
            None => unreachable!("the task either ran on the compiler thread or is still pending"),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_once_and_nests_without_new_threads() {
        let outer = on_compiler_stack(|| {
            let id = std::thread::current().id();
            let inner = on_compiler_stack(|| std::thread::current().id());
            (id, inner)
        });
        assert_eq!(outer.0, outer.1, "nested calls stay on the compiler thread");
        assert_ne!(outer.0, std::thread::current().id());
    }

    #[test]
    fn panics_reach_the_caller() {
        let caught = std::panic::catch_unwind(|| on_compiler_stack(|| panic!("boom")));
        assert!(caught.is_err());
    }
}
