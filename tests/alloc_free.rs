//! The per-sample path allocates nothing (issue 27 item 3): shading, the per-vertex layer pick
//! and mask evaluation, BSDF sampling, light sampling and shadow rays. A counting global
//! allocator sees every allocation of the process; a render at 1 thread allocates per row and
//! per render (film rows, stats), never per sample, so the same render at 16 times the samples
//! per pixel must make as many allocations, up to the few that rayon's scheduling makes or
//! not from run to run (0–4 measured, against 1440 more samples and several thousand more
//! shading points). One test function: nothing else runs in this binary while it counts.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use strata::abi::MaterialCode;
use strata::input::generated::{MaskKind, layered_scene, mask_stack_source};
use strata::render::{LayerMode, RenderSettings};

/// Counts allocations and reallocations, then defers to the system allocator.
struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: every call is forwarded unchanged to `System`, which upholds the contract.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded with the caller's layout.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded with the caller's layout.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: `ptr` came from this allocator, i.e. from `System`, with `layout`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator, i.e. from `System`, with `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations a render may make or not from run to run (rayon's job queues).
const SCHEDULER_JITTER: u64 = 8;

/// Allocations made by one render of `scene` at `spp` on one thread.
fn allocations(scene: &strata::render::Scene, materials: &[Arc<dyn MaterialCode>], mode: LayerMode, spp: u32) -> u64 {
    let refs: Vec<&dyn MaterialCode> = materials.iter().map(|m| m.as_ref()).collect();
    let settings = RenderSettings {
        width: 12,
        height: 8,
        spp,
        seed: 3,
        threads: Some(1),
        max_depth: 8,
        mode,
        ..Default::default()
    };
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let (_, stats) = strata::render::render(scene, &refs, &settings, None).expect("renders");
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    assert_eq!(stats.invalid_samples(), 0, "{stats}");
    drop(stats);
    after - before
}

#[test]
fn samples_allocate_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let ash = dir.path().join("stack.ash");
    let usda = dir.path().join("stack.usda");
    std::fs::write(&ash, mask_stack_source(4, MaskKind::Noise)).unwrap();
    std::fs::write(&usda, layered_scene(4, "stack.ash")).unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scenes =
        [usda, root.join("scenes/compare/metal_coat_glass.usda"), root.join("scenes/compare/layers_card.usda")];
    let mut failures = vec![];
    for path in &scenes {
        let (scene, materials) = common::scene_file(path);
        for mode in [LayerMode::Stochastic, LayerMode::Weighted, LayerMode::Auto] {
            // Warm-up: lazily initialised statics (thread pool, tables) are not the samples'.
            allocations(&scene, &materials, mode, 1);
            let one = allocations(&scene, &materials, mode, 1);
            let many = allocations(&scene, &materials, mode, 16);
            // The counter sees the render: the film's rows are allocated.
            assert!(one >= 8, "{}: only {one} allocations counted", path.display());
            // One allocation per 100 extra samples would be 14: far above the scheduler's jitter.
            if many.abs_diff(one) > SCHEDULER_JITTER {
                failures.push(format!("{} {mode:?}: {one} allocations at 1 spp, {many} at 16", path.display()));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
