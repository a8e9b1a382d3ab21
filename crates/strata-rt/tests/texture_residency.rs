//! Texture residency under a budget (issue 24): what a miss decodes and what stays. A process
//! of its own, its tests run one at a time: the budget and the counters are process-wide.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use strata_rt::texture::{self, Filter, Image, TexelSource, Texels, lookup_with, register_source};

/// Serialises the tests: each sets the process-wide budget.
static SERIAL: Mutex<()> = Mutex::new(());

/// A one-channel 8-bit texture made on decode, `(x * 7 + y * 13) ^ seed` per texel, counting
/// its decodes.
struct Counted {
    side: usize,
    seed: u8,
    decodes: Arc<AtomicUsize>,
}

impl TexelSource for Counted {
    fn decode(&self) -> Result<Image, String> {
        self.decodes.fetch_add(1, Ordering::Relaxed);
        let n = self.side;
        let texels = (0..n * n).map(|i| ((i % n * 7 + i / n * 13) as u8) ^ self.seed).collect();
        Ok(Image { width: n, height: n, channels: 1, srgb: false, texels: Texels::U8(texels) })
    }
}

fn counted(name: &str, side: usize, seed: u8) -> (i32, Arc<AtomicUsize>) {
    let decodes = Arc::new(AtomicUsize::new(0));
    let source = Counted { side, seed, decodes: Arc::clone(&decodes) };
    (register_source(name.into(), side, side, Box::new(source)).unwrap(), decodes)
}

/// `count` lookups spread over the texture with a footprint of `texels` texels of `side`.
fn spread(id: i32, side: usize, texels: f32, count: usize) -> Vec<f32> {
    let f = texels / side as f32;
    (0..count)
        .map(|k| {
            let (s, t) = ((k as f32 * 0.618_034).fract(), (k as f32 * 0.414_214).fract());
            lookup_with(Filter::Trilinear, id, s, t, 0, [f, 0.0, 0.0, f])
        })
        .collect()
}

#[test]
fn a_budget_that_holds_the_coarse_levels_decodes_them_once() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    // 2048² grey: level 0 is 4 MiB, level 1 1 MiB, the rest 0.33 MiB; the budget holds
    // level 1 and coarser, never level 0 (over half of it: read by bands).
    let budget = 5 << 19;
    texture::set_memory_budget(budget);
    let (id, decodes) = counted("residency:coarse", 2048, 0);
    let coarse = spread(id, 2048, 3.0, 2000);
    assert_eq!(decodes.load(Ordering::Relaxed), 1, "lookups at levels 1 and 2 decode once");
    assert!(texture::stats().resident_bytes <= budget);
    // Level 0 does not fit: one decode finds that out, then it is read by bands of rows
    // (128 KiB each), a decode per band missed (two rows per bilinear read).
    let fine = spread(id, 2048, 0.5, 3);
    let after = decodes.load(Ordering::Relaxed);
    assert!((3..=1 + 1 + 6).contains(&after), "{after} decodes");
    assert!(texture::stats().resident_bytes <= budget);
    assert_eq!(spread(id, 2048, 0.5, 3), fine, "the same texels");
    assert_eq!(decodes.load(Ordering::Relaxed), after, "read from the resident bands");
    assert_eq!(spread(id, 2048, 3.0, 2000), coarse, "the coarse levels read the same");
    // The values are the texels: level 0 bilinear at the sample points.
    assert!(fine.iter().all(|v| (0.0..=1.0).contains(v)));
    assert!(texture::stats().resident_bytes <= budget);
    texture::evict_all();
}

#[test]
fn sixty_four_threads_under_a_tiny_budget_read_what_one_thread_reads() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    // Two 256² textures: 64 KiB at level 0, 21 KiB from level 1 down. The budget holds one
    // texture's coarse levels, never level 0, so threads keep evicting each other's levels
    // while others read them.
    let budget = 30 << 10;
    texture::set_memory_budget(budget);
    let ids = [counted("residency:a", 256, 0).0, counted("residency:b", 256, 0x5a).0];
    let footprints: [[f32; 4]; 4] =
        [[0.0; 4], [0.01, 0.0, 0.0, 0.01], [0.3, 0.1, -0.002, 0.004], [50.0, 0.0, 0.0, 50.0]];
    let coords: Vec<(i32, f32, f32, [f32; 4])> = (0..400)
        .map(|k| {
            let (s, t) = ((k as f32 * 0.618_034).fract() * 3.0, (k as f32 * 0.414_214).fract());
            (ids[k % 2], s, t, footprints[k / 2 % 4])
        })
        .collect();
    let read = |&(id, s, t, footprint): &(i32, f32, f32, [f32; 4])| {
        texture::lookup_with(Filter::Anisotropic, id, s, t, 0, footprint)
    };
    let want: Vec<f32> = coords.iter().map(read).collect();
    texture::reset_stats();
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..64)
            .map(|k| {
                let (coords, want) = (&coords, &want);
                scope.spawn(move || {
                    // Each thread starts elsewhere in the list, so threads miss different levels.
                    let n = coords.len();
                    (0..n).all(|i| read(&coords[(i + k * 37) % n]) == want[(i + k * 37) % n])
                })
            })
            .collect();
        assert!(handles.into_iter().all(|h| h.join().unwrap()), "a thread read other values");
    });
    let stats = texture::stats();
    assert!(stats.evictions > 0, "the budget made levels leave: {stats:?}");
    assert!(stats.resident_bytes <= budget, "{stats:?}");
    texture::evict_all();
}
