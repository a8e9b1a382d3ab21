//! Texture lookups for compiled shaders: a process-wide registry of images, addressed by small
//! integer ids that code generation bakes into the call.
//!
//! **Pipeline.** A texture is registered at compile time from its header alone (size): a
//! [`TexelSource`] decodes its pixels on the first lookup that reaches it, at the file's own
//! precision ([`Texels`]: 8-bit stays 8-bit with sRGB decoded through a table at lookup, 16-bit,
//! half and float as they are; one to four channels), and a box-filtered mip chain is built
//! from it. Each mip level is a unit of residency: the levels resident at once are bounded by
//! [`set_memory_budget`], the least recently used evicted first; an evicted level is made
//! again when reached (from a resident finer level, else by decoding the source), so any
//! budget (smaller than one texture included) renders the same image. Lookups take no lock:
//! each level is an atomic pointer whose evicted images are freed once no lookup can hold
//! them ([`Slot`], epoch-based); only a miss takes the texture's decode lock and the
//! residency lock.
//!
//! **Filtering.** [`lookup_filtered`] receives the ray's footprint in texture space (the ray
//! cone's two axes mapped through the surface's st Jacobian, see `abi::Globals::st_footprint`)
//! and filters trilinearly, or anisotropically with up to [`MAX_ANISOTROPY`] trilinear probes
//! along the footprint's major axis ([`set_filter`]). A footprint below one texel reads the
//! finest level bilinearly, exactly as [`lookup`] does.
//!
//! The `channel` argument of [`lookup`] carries the wrap modes too, so the C symbol keeps its
//! four-argument signature: `channel + 16 · wrap_s + 256 · wrap_t`, with the channel in 0..=3
//! (r, g, b, a) and each wrap mode one of the `WRAP_*` constants. Old callers that pass a bare
//! channel get repeat wrapping, as before.

use crossbeam_epoch::{self as epoch, Atomic, Guard, Owned, Shared};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};

mod bands;
mod image;
use bands::{Streamed, bilinear_at, read_level, stream_levels, with_row};
#[cfg(test)]
use image::tests::grey;
pub use image::{Image, MipCascade, Texels, f16_to_f32, f32_to_f16, level_count};

/// Wrap mode: tile the image (the default).
pub const WRAP_REPEAT: i32 = 0;
/// Wrap mode: outside [0, 1] every channel is 0 (UsdUVTexture's `black`).
pub const WRAP_BLACK: i32 = 1;
/// Wrap mode: the edge texel extends outward.
pub const WRAP_CLAMP: i32 = 2;
/// Wrap mode: every other tile is mirrored.
pub const WRAP_MIRROR: i32 = 3;

/// A decoded RGBA image, linear floats, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Width in pixels (≥ 1).
    pub width: usize,
    /// Height in pixels (≥ 1).
    pub height: usize,
    /// `width * height` RGBA texels, row-major, top row first (alpha 1 for images without).
    pub texels: Vec<[f32; 4]>,
}

/// The texel index along an axis of `n` texels for integer coordinate `i`, or `None` when the
/// wrap mode says the texel is black.
#[inline]
fn wrap_index(i: i64, n: usize, mode: i32) -> Option<usize> {
    let n = n as i64;
    match mode {
        WRAP_BLACK => (0..n).contains(&i).then_some(i as usize),
        WRAP_CLAMP => Some(i.clamp(0, n - 1) as usize),
        WRAP_MIRROR => {
            let period = i.rem_euclid(2 * n);
            Some(if period < n { period } else { 2 * n - 1 - period } as usize)
        }
        _ => Some(i.rem_euclid(n) as usize),
    }
}

impl Texture {
    /// Bilinear lookup with repeat wrapping; `t = 0` is the bottom row (USD's st convention).
    pub fn sample(&self, s: f32, t: f32, channel: usize) -> f32 {
        self.sample_wrapped(s, t, channel, WRAP_REPEAT, WRAP_REPEAT)
    }

    /// Bilinear lookup with a wrap mode per axis (`WRAP_*`); `t = 0` is the bottom row.
    /// Non-finite coordinates read 0.
    pub fn sample_wrapped(&self, s: f32, t: f32, channel: usize, wrap_s: i32, wrap_t: i32) -> f32 {
        if !s.is_finite() || !t.is_finite() || channel > 3 {
            return 0.0;
        }
        // Far coordinates lose all precision in f32 anyway; keep the integer maths in range.
        let x = (s.clamp(-1e7, 1e7) * self.width as f32 - 0.5) as f64;
        let y = ((1.0 - t.clamp(-1e7, 1e7)) * self.height as f32 - 0.5) as f64;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let at = |xi: i64, yi: i64| match (wrap_index(xi, self.width, wrap_s), wrap_index(yi, self.height, wrap_t)) {
            (Some(xi), Some(yi)) => self.texels[yi * self.width + xi][channel],
            _ => 0.0,
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        let top = at(x0, y0) + (at(x0 + 1, y0) - at(x0, y0)) * fx;
        let bottom = at(x0, y0 + 1) + (at(x0 + 1, y0 + 1) - at(x0, y0 + 1)) * fx;
        top + (bottom - top) * fy
    }
}

/// Decodes a texture's pixels when a lookup first reaches them (and again after eviction).
pub trait TexelSource: Send + Sync {
    /// The finest level, at the source's precision, of the size the texture was registered
    /// with.
    fn decode(&self) -> Result<Image, String>;

    /// The finest level's rows, top to bottom, handed to `rows` a run at a time (images of
    /// whole rows, all of one precision, channel count and colour space), so no level need be
    /// whole in memory; `rows` returns false when it needs no more. The default hands over
    /// [`TexelSource::decode`]'s image at once (kept as it is when it may stay, not copied);
    /// a format read by rows (PNG) overrides it.
    fn decode_rows(&self, rows: &mut dyn FnMut(Image) -> bool) -> Result<(), String> {
        rows(self.decode()?);
        Ok(())
    }

    /// The bytes its finest level and mip chain will take, when known before decoding (a
    /// file's header): [`prefetch`] decodes only what fits the budget's free room.
    fn resident_bytes(&self) -> Option<u64> {
        None
    }
}

/// An image held in memory (tests, generated images): decoding copies it.
struct InMemory(Image);

impl TexelSource for InMemory {
    fn decode(&self) -> Result<Image, String> {
        Ok(self.0.clone())
    }

    fn resident_bytes(&self) -> Option<u64> {
        Some(self.0.bytes() + self.0.bytes() / 3)
    }
}

/// A value readers reach without a lock: an atomic pointer whose replaced values are freed
/// once no thread that could have read them is still pinned (crossbeam-epoch's deferred
/// reclamation). Writers are serialised by the caller (the residency lock).
struct Slot<T: Send + 'static>(Atomic<T>);

impl<T: Send + 'static> Slot<T> {
    fn new(value: Option<T>) -> Slot<T> {
        Slot(value.map_or_else(Atomic::null, Atomic::new))
    }

    /// The value, valid while both the slot and the guard are.
    #[inline]
    fn get<'a>(&'a self, guard: &'a Guard) -> Option<&'a T> {
        // SAFETY: a value leaves the slot only through `swap`, which defers its destruction
        // until every guard pinned before then is dropped, or with the slot (`Drop`, which
        // the borrow of `self` excludes).
        unsafe { self.0.load(Ordering::Acquire, guard).as_ref() }
    }

    /// Puts `value` (or nothing) in the slot and returns the old value, readable through
    /// `guard` and freed once no guard pinned now remains.
    fn swap<'a>(&'a self, value: Option<T>, guard: &'a Guard) -> Option<&'a T> {
        let new = value.map_or_else(Shared::null, |v| Owned::new(v).into_shared(guard));
        let old = self.0.swap(new, Ordering::AcqRel, guard);
        if old.is_null() {
            return None;
        }
        // SAFETY: `old` is out of the slot, so no new reader reaches it; the readers that
        // loaded it are pinned, as `guard` is, and its destruction waits for all of them.
        unsafe {
            guard.defer_destroy(old);
            Some(old.deref())
        }
    }
}

impl<T: Send + 'static> Drop for Slot<T> {
    fn drop(&mut self) {
        // SAFETY: `&mut self`: no reader holds the value (`get` borrows the slot), and a
        // slot inside a replaced `Content` is dropped only after every reader's guard.
        unsafe {
            let value = self.0.load(Ordering::Relaxed, epoch::unprotected());
            if !value.is_null() {
                drop(value.into_owned());
            }
        }
    }
}

/// One mip level's residency (or one band's of a level read by bands).
struct Level {
    image: Slot<Image>,
    /// The residency clock when last read (an epoch, advanced per miss, not per lookup, so
    /// lookups write it only when it changed).
    last_use: AtomicU64,
    /// Set once the level proved larger than half the budget: from then on it is read by
    /// bands of [`BAND_ROWS`] rows, each a unit of residency, and never made whole (a level
    /// that filled the budget would evict every band and be evicted by the next band miss,
    /// each miss a decode of the file).
    banded: AtomicBool,
    /// The level's rows by [`BAND_ROWS`] (none for a band itself).
    bands: Box<[Level]>,
}

/// Rows of a band: a level larger than the budget is decoded, kept and evicted by bands of
/// this many rows (4 MiB of a 16384-wide RGBA 8-bit level).
pub const BAND_ROWS: usize = 64;

impl Level {
    /// The image when resident (a lookup's read: counted, its last use brought up to now).
    #[inline]
    fn touch<'a>(&'a self, guard: &'a Guard) -> Option<&'a Image> {
        MY_SHARD.with(|&shard| FETCHES[shard].0.fetch_add(1, Ordering::Relaxed));
        let image = self.image.get(guard)?;
        let now = CLOCK.load(Ordering::Relaxed);
        if self.last_use.load(Ordering::Relaxed) != now {
            self.last_use.store(now, Ordering::Relaxed);
        }
        Some(image)
    }

    fn new(bands: usize) -> Level {
        Level {
            image: Slot::new(None),
            last_use: AtomicU64::new(0),
            banded: AtomicBool::new(false),
            bands: (0..bands).map(|_| Level::new(0)).collect(),
        }
    }
}

/// A texture's pixels: where they come from and which levels are resident.
struct Content {
    source: Box<dyn TexelSource>,
    width: usize,
    height: usize,
    levels: Box<[Level]>,
    /// Held while decoding, so threads that miss together decode once.
    decoding: Mutex<()>,
    /// Set when decoding failed: the texture reads 0 (no retry per lookup).
    failed: AtomicBool,
    /// Set (under the residency lock) when a new source replaced this one: a miss in flight
    /// keeps nothing.
    retired: AtomicBool,
}

impl Content {
    fn new(width: usize, height: usize, source: Box<dyn TexelSource>) -> Content {
        let levels = (0..level_count(width, height))
            .map(|l| Level::new(level_size(width, height, l).1.div_ceil(BAND_ROWS)))
            .collect();
        Content {
            source,
            width: width.max(1),
            height: height.max(1),
            levels,
            decoding: Mutex::new(()),
            failed: AtomicBool::new(false),
            retired: AtomicBool::new(false),
        }
    }
}

/// The width and height of level `level` of a `width × height` texture.
fn level_size(width: usize, height: usize, level: usize) -> (usize, usize) {
    ((width >> level).max(1), (height >> level).max(1))
}

impl Content {
    /// Every unit of residency: each level and each band of a level.
    fn held(&self) -> impl Iterator<Item = &Level> {
        self.levels.iter().flat_map(|level| std::iter::once(level).chain(level.bands.iter()))
    }

    /// The rows of band `band` of level `level`.
    fn band_rows(&self, level: usize, band: usize) -> std::ops::Range<usize> {
        let height = level_size(self.width, self.height, level).1;
        band * BAND_ROWS..((band + 1) * BAND_ROWS).min(height)
    }
}

struct Entry {
    name: PathBuf,
    /// Never empty; replaced when the file changes.
    content: Slot<Content>,
}

/// Registry slots: an append-only table of segments, so a lookup finds its entry without a
/// lock (a `OnceLock` read per level).
const SEGMENT: usize = 1024;
const SEGMENTS: usize = 1024;
static SLOTS: [OnceLock<Box<[OnceLock<Entry>]>>; SEGMENTS] = [const { OnceLock::new() }; SEGMENTS];
/// Registered entries (their slots are filled in order).
static COUNT: AtomicUsize = AtomicUsize::new(0);
/// Serialises registration.
static REGISTER: Mutex<()> = Mutex::new(());

fn entry(id: i32) -> Option<&'static Entry> {
    let i = usize::try_from(id).ok()?;
    SLOTS.get(i / SEGMENT)?.get()?.get(i % SEGMENT)?.get()
}

/// Every registered entry, by id.
fn entries() -> impl Iterator<Item = &'static Entry> {
    (0..COUNT.load(Ordering::Acquire)).filter_map(|i| entry(i as i32))
}

/// Residency bookkeeping, touched only on a miss.
struct Residency {
    resident: u64,
}

static RESIDENCY: Mutex<Residency> = Mutex::new(Residency { resident: 0 });
/// `--texture-memory`: the bytes of texels resident at once (0: the default, 1 GiB).
static BUDGET: AtomicU64 = AtomicU64::new(0);
/// The residency clock (see [`Level::last_use`]).
static CLOCK: AtomicU64 = AtomicU64::new(1);
static MISSES: AtomicU64 = AtomicU64::new(0);
static DECODES: AtomicU64 = AtomicU64::new(0);
static EVICTIONS: AtomicU64 = AtomicU64::new(0);

/// Level reads, counted in per-thread shards (one cache line each) so counting does not make
/// threads contend.
#[repr(align(128))]
struct Shard(AtomicU64);
const SHARDS: usize = 64;
static FETCHES: [Shard; SHARDS] = [const { Shard(AtomicU64::new(0)) }; SHARDS];
static NEXT_SHARD: AtomicUsize = AtomicUsize::new(0);
thread_local! {
    static MY_SHARD: usize = NEXT_SHARD.fetch_add(1, Ordering::Relaxed) % SHARDS;
}

/// The budget when none was set: 1 GiB.
pub const DEFAULT_MEMORY_BUDGET: u64 = 1 << 30;

/// Bounds the bytes of texels resident at once (`--texture-memory`); 0 restores the default.
/// Levels beyond it are evicted on the next miss.
pub fn set_memory_budget(bytes: u64) {
    BUDGET.store(bytes, Ordering::Relaxed);
}

/// The residency budget in bytes.
pub fn memory_budget() -> u64 {
    match BUDGET.load(Ordering::Relaxed) {
        0 => DEFAULT_MEMORY_BUDGET,
        b => b,
    }
}

/// The texture cache's counters since the last [`reset_stats`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Bytes of texels resident now.
    pub resident_bytes: u64,
    /// Mip-level reads by lookups.
    pub fetches: u64,
    /// Reads that found their level not resident.
    pub misses: u64,
    /// Source decodes (a miss decodes unless another thread just did).
    pub decodes: u64,
    /// Levels evicted to stay within the budget.
    pub evictions: u64,
}

impl CacheStats {
    /// The fraction of level reads served from resident texels (1 with no reads).
    pub fn hit_rate(&self) -> f64 {
        if self.fetches == 0 { 1.0 } else { 1.0 - self.misses as f64 / self.fetches as f64 }
    }
}

/// The cache's counters.
pub fn stats() -> CacheStats {
    CacheStats {
        resident_bytes: RESIDENCY.lock().map(|r| r.resident).unwrap_or(0),
        fetches: FETCHES.iter().map(|s| s.0.load(Ordering::Relaxed)).sum(),
        misses: MISSES.load(Ordering::Relaxed),
        decodes: DECODES.load(Ordering::Relaxed),
        evictions: EVICTIONS.load(Ordering::Relaxed),
    }
}

/// Zeroes the counters of [`stats`] (not the residency).
pub fn reset_stats() {
    for shard in &FETCHES {
        shard.0.store(0, Ordering::Relaxed);
    }
    for counter in [&MISSES, &DECODES, &EVICTIONS] {
        counter.store(0, Ordering::Relaxed);
    }
}

/// Drops every resident level (benchmarks start cold with it).
pub fn evict_all() {
    let Ok(mut residency) = RESIDENCY.lock() else { return };
    let guard = &epoch::pin();
    for content in entries().filter_map(|entry| entry.content.get(guard)) {
        for level in content.held() {
            if let Some(old) = level.image.swap(None, guard) {
                residency.resident = residency.resident.saturating_sub(old.bytes());
            }
        }
    }
    guard.flush();
}

/// Evicts least recently used levels until `incoming` more bytes fit the budget (or nothing
/// is left to evict). Evicted levels are freed once no lookup can still be reading them.
fn make_room(residency: &mut Residency, incoming: u64, guard: &Guard) {
    let budget = memory_budget();
    while residency.resident.saturating_add(incoming) > budget {
        // The oldest level; among equally old ones the largest (so a texture that does not
        // fit keeps its coarse levels).
        let mut victim: Option<(u64, u64, &Level)> = None;
        for content in entries().filter_map(|entry| entry.content.get(guard)) {
            for level in content.held() {
                let Some(image) = level.image.get(guard) else { continue };
                let key = (level.last_use.load(Ordering::Relaxed), u64::MAX - image.bytes());
                if victim.is_none_or(|(t, b, _)| key < (t, b)) {
                    victim = Some((key.0, key.1, level));
                }
            }
        }
        let Some((_, _, level)) = victim else { return };
        if let Some(old) = level.image.swap(None, guard) {
            residency.resident = residency.resident.saturating_sub(old.bytes());
            EVICTIONS.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Runs `read` on level `index` of `content`, made when it is not resident: downsampled from
/// the nearest resident finer level, or, when none is, from the source's rows streamed through
/// a [`MipCascade`] (no level is made whole that could not stay). `None` when the source
/// fails, or when the level proved larger than half the budget: it is marked
/// [`Level::banded`] and read by bands from then on ([`load_band`]).
///
/// What is kept: the wanted level and the coarser ones made with it (a third of its size;
/// trilinear reads the next coarser level) are made room for; finer levels a decode made on
/// the way are kept only in room the budget has free, as the first to be evicted. So a miss
/// of a coarse level never decodes the file while a finer level is resident, and a budget
/// smaller than the textures keeps the levels lookups reach instead of whole chains.
///
/// `ahead` (a [`prefetch`], no lookup waiting): no level is requested, so every level made is
/// kept only in free room, as the first to be evicted.
#[cold]
fn load_level<R>(
    content: &Content,
    index: usize,
    guard: &Guard,
    ahead: bool,
    read: impl FnOnce(&Image) -> R,
) -> Option<R> {
    if !ahead {
        MISSES.fetch_add(1, Ordering::Relaxed);
    }
    let _decoding = content.decoding.lock().ok()?;
    if let Some(image) = content.levels[index].image.get(guard) {
        return Some(read(image)); // another thread made it meanwhile
    }
    if content.failed.load(Ordering::Relaxed) || content.levels[index].banded.load(Ordering::Relaxed) {
        return None;
    }
    let finer = (0..index).rev().find_map(|j| content.levels[j].image.get(guard).map(|image| (j, image)));
    let (first, result, mut owned) = match finer {
        Some((first, base)) => {
            // Levels first + 1 on, each from the one above: down to the wanted level, then on
            // through the coarser levels that are not resident.
            let mut made: Vec<Image> = Vec::new();
            loop {
                let next = first + 1 + made.len();
                if next >= content.levels.len() || (next > index && content.levels[next].image.get(guard).is_some()) {
                    break;
                }
                let image = made.last().unwrap_or(base).downsample();
                made.push(image);
            }
            let result = read(if index == first { base } else { &made[index - first - 1] });
            // Owned images by level - first (the resident base is already in place).
            (first, result, std::iter::once(None).chain(made.into_iter().map(Some)).collect::<Vec<_>>())
        }
        None => {
            DECODES.fetch_add(1, Ordering::Relaxed);
            let owned = match stream_levels(content, index, ahead, guard) {
                Streamed::Levels(owned) => owned,
                Streamed::TooLarge => {
                    content.levels[index].banded.store(true, Ordering::Relaxed);
                    return None;
                }
                Streamed::Failed => {
                    content.failed.store(true, Ordering::Relaxed);
                    return None;
                }
            };
            (0, read(owned[index].as_ref()?), owned)
        }
    };
    let Ok(mut residency) = RESIDENCY.lock() else { return Some(result) };
    if content.retired.load(Ordering::Relaxed) {
        return Some(result); // its file changed meanwhile: these texels are stale
    }
    let now = CLOCK.fetch_add(1, Ordering::Relaxed) + 1;
    // The wanted level and coarser, coarsest first: when the budget is small the coarse
    // levels stay. Then the finer levels made on the way, coarsest first, into free room.
    let requested = (index..first + owned.len()).rev().map(|l| (l, !ahead));
    let on_the_way = (first..index).rev().map(|l| (l, false));
    for (l, requested) in requested.chain(on_the_way) {
        if let Some(image) = owned[l - first].take() {
            keep(&mut residency, &content.levels[l], image, requested.then_some(now), guard);
        }
    }
    drop(residency);
    guard.flush(); // what was evicted is freed as soon as no lookup can hold it
    Some(result)
}

/// Puts `image` in `level` (a level or a band) when it fits the budget: a requested one
/// (`now`: the clock of the miss) evicts what it needs; one nobody asked for goes only into
/// free room, as the first candidate for eviction. A level already resident is left as is.
fn keep(residency: &mut Residency, level: &Level, image: Image, now: Option<u64>, guard: &Guard) {
    let bytes = image.bytes();
    // A level larger than the whole budget evicts nothing: it could not stay anyway.
    if now.is_some() && bytes <= memory_budget() {
        make_room(residency, bytes, guard);
    }
    if residency.resident.saturating_add(bytes) > memory_budget() || level.image.get(guard).is_some() {
        return; // does not fit: used for this lookup, not kept
    }
    residency.resident += bytes;
    level.last_use.store(now.unwrap_or(0), Ordering::Relaxed);
    level.image.swap(Some(image), guard);
}

/// Runs `read` on level `index` of `content`, loading it on a miss; `None` when it cannot be
/// loaded.
#[inline]
fn with_level<R>(content: &Content, index: usize, guard: &Guard, read: impl FnOnce(&Image) -> R) -> Option<R> {
    if let Some(image) = content.levels[index].touch(guard) {
        return Some(read(image));
    }
    load_level(content, index, guard, false, read)
}

/// Decodes texture `id` and makes its mip chain ahead of its first lookup (on a thread that
/// would otherwise idle while the render scene is built), when nothing of it is resident and
/// its levels fit in the room the budget has free; they are kept as the first to be evicted,
/// as levels nobody asked for. Returns whether it decoded. A texture whose size is not known
/// before decoding is left to its first lookup.
pub fn prefetch(id: i32) -> bool {
    let Some(entry) = entry(id) else { return false };
    let guard = &epoch::pin();
    entry.content.get(guard).is_some_and(|content| prefetch_content(content, guard))
}

/// [`prefetch`] of one texture's content.
fn prefetch_content(content: &Content, guard: &Guard) -> bool {
    if content.failed.load(Ordering::Relaxed) || content.held().any(|l| l.image.get(guard).is_some()) {
        return false;
    }
    let Some(bytes) = content.source.resident_bytes() else { return false };
    let resident = RESIDENCY.lock().map(|r| r.resident).unwrap_or(u64::MAX);
    if resident.saturating_add(bytes) > memory_budget() {
        return false;
    }
    load_level(content, 0, guard, true, |_| ()).is_some()
}

/// The number of textures registered so far (ids `0..count`).
pub fn count() -> usize {
    COUNT.load(Ordering::Acquire)
}

/// The id of the texture registered under `name`, if any.
pub fn find(name: &Path) -> Option<i32> {
    let _registering = REGISTER.lock().ok()?;
    entries().position(|e| e.name == name).map(|i| i as i32)
}

/// The names of every registered texture, by id.
pub fn names() -> Vec<PathBuf> {
    entries().map(|e| e.name.clone()).collect()
}

/// Registers a `width × height` texture whose pixels `source` decodes when first reached.
pub fn register_source(
    name: PathBuf,
    width: usize,
    height: usize,
    source: Box<dyn TexelSource>,
) -> Result<i32, String> {
    let _registering = REGISTER.lock().map_err(|_| "texture registry poisoned".to_string())?;
    let id = COUNT.load(Ordering::Acquire);
    let segment = SLOTS.get(id / SEGMENT).ok_or("too many textures")?;
    let segment = segment.get_or_init(|| (0..SEGMENT).map(|_| OnceLock::new()).collect());
    let content = Slot::new(Some(Content::new(width, height, source)));
    segment[id % SEGMENT].set(Entry { name, content }).map_err(|_| "texture slot taken".to_string())?;
    COUNT.store(id + 1, Ordering::Release);
    Ok(id as i32)
}

/// Registers an in-memory texture under a name (tests, generated images).
pub fn register(name: PathBuf, texture: Texture) -> Result<i32, String> {
    register_image(name, Image::from_texture(&texture))
}

/// Registers an in-memory image at its own precision under a name.
pub fn register_image(name: PathBuf, mut image: Image) -> Result<i32, String> {
    if !image.is_consistent() {
        return Err("the image's sizes do not match its texels".into());
    }
    if let Texels::F32(values) = &mut image.texels {
        values.iter_mut().filter(|v| !v.is_finite()).for_each(|v| *v = 0.0);
    }
    let (w, h) = (image.width, image.height);
    register_source(name, w, h, Box::new(InMemory(image)))
}

/// Points texture `id` at a new source (its file changed): code compiled against the id reads
/// the new texels from the next lookup on; its old levels leave the cache. Lookups already
/// running keep the old texels.
pub fn replace_source(id: i32, width: usize, height: usize, source: Box<dyn TexelSource>) -> Result<(), String> {
    let entry = entry(id).ok_or("no such texture")?;
    let fresh = Content::new(width, height, source);
    // Under the residency lock, so a miss of the old source in flight keeps nothing.
    let mut residency = RESIDENCY.lock().map_err(|_| "texture registry poisoned")?;
    let guard = &epoch::pin();
    if let Some(old) = entry.content.swap(Some(fresh), guard) {
        old.retired.store(true, Ordering::Relaxed);
        for level in old.held() {
            if let Some(image) = level.image.swap(None, guard) {
                residency.resident = residency.resident.saturating_sub(image.bytes());
            }
        }
    }
    Ok(())
}

/// Replaces the texels of texture `id` with an in-memory image (see [`replace_source`]).
pub fn replace(id: i32, texture: Texture) -> Result<(), String> {
    let image = Image::from_texture(&texture);
    replace_source(id, image.width, image.height, Box::new(InMemory(image)))
}

/// How [`lookup_filtered`] filters a footprint wider than a texel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// The nearest texel of the finest level, footprint ignored (benchmarks' baseline).
    Nearest,
    /// Bilinear at the finest level, footprint ignored (the lookup before mip-maps).
    Bilinear,
    /// Trilinear: the mip level whose texels match the footprint's major axis.
    Trilinear,
    /// Up to [`MAX_ANISOTROPY`] trilinear probes along the major axis, each at the level of
    /// the minor axis.
    Anisotropic,
}

/// The most probes an anisotropic lookup takes.
pub const MAX_ANISOTROPY: usize = 8;

static FILTER: AtomicU8 = AtomicU8::new(3);

/// Sets the filter every [`lookup_filtered`] uses (default [`Filter::Anisotropic`]).
pub fn set_filter(filter: Filter) {
    FILTER.store(filter as u8, Ordering::Relaxed);
}

/// The filter [`lookup_filtered`] uses.
pub fn filter() -> Filter {
    match FILTER.load(Ordering::Relaxed) {
        0 => Filter::Nearest,
        1 => Filter::Bilinear,
        2 => Filter::Trilinear,
        _ => Filter::Anisotropic,
    }
}

/// Channel `mode % 16` (0..=3: r, g, b, a) of texture `id` at (s, t), wrapped by
/// `(mode / 16) % 16` along s and `mode / 256` along t (`WRAP_*`), bilinear at the finest
/// level; 0 for an unknown id or channel.
pub fn lookup(id: i32, s: f32, t: f32, mode: i32) -> f32 {
    lookup_filtered(id, s, t, mode, 0.0, 0.0, 0.0, 0.0)
}

/// [`lookup`] filtered over a footprint: its two axes (ds/dx, dt/dx) and (ds/dy, dt/dy) in
/// texture coordinates (the ray cone's width across the surface, as diameters). A footprint
/// under one texel reads like [`lookup`]; non-finite axes count as 0.
#[allow(clippy::too_many_arguments)]
pub fn lookup_filtered(id: i32, s: f32, t: f32, mode: i32, dsdx: f32, dtdx: f32, dsdy: f32, dtdy: f32) -> f32 {
    lookup_with(filter(), id, s, t, mode, [dsdx, dtdx, dsdy, dtdy])
}

/// [`lookup_filtered`] with a given filter and the footprint as `[ds/dx, dt/dx, ds/dy, dt/dy]`.
pub fn lookup_with(filter: Filter, id: i32, s: f32, t: f32, mode: i32, footprint: [f32; 4]) -> f32 {
    let [dsdx, dtdx, dsdy, dtdy] = footprint;
    let (channel, wrap_s, wrap_t) = ((mode & 15) as usize, (mode >> 4) & 15, (mode >> 8) & 15);
    if !(0..4096).contains(&mode) || channel > 3 || !s.is_finite() || !t.is_finite() {
        return 0.0;
    }
    let Some(entry) = entry(id) else { return 0.0 };
    // Pinned once per lookup: what it reads cannot be freed until it returns.
    let guard = &epoch::pin();
    let Some(content) = entry.content.get(guard) else { return 0.0 };
    // Far coordinates lose all precision in f32 anyway; keep the integer maths in range.
    let (s, t) = (s.clamp(-1e7, 1e7), 1.0 - t.clamp(-1e7, 1e7));
    let (w, h) = (content.width as f32, content.height as f32);
    let finite = |v: f32| if v.is_finite() { v } else { 0.0 };
    // The axes in texels of the finest level (t runs down the rows: its sign is irrelevant).
    let (ax, ay) = ((finite(dsdx) * w, finite(dtdx) * h), (finite(dsdy) * w, finite(dtdy) * h));
    let (la, lb) = (ax.0.hypot(ax.1), ay.0.hypot(ay.1));
    let (major_axis, major, minor) = if la >= lb { (ax, la, lb) } else { (ay, lb, la) };
    let sample_level =
        |level: usize, s: f32, t: f32| bilinear_at(content, level, s, t, channel, (wrap_s, wrap_t), guard);
    let last = content.levels.len() - 1;
    let trilinear = |lod: f32, s: f32, t: f32| {
        if lod <= 0.0 {
            return sample_level(0, s, t);
        }
        let lod = lod.min(last as f32);
        let fine = lod.floor() as usize;
        let frac = lod - fine as f32;
        let a = sample_level(fine, s, t);
        if frac <= 0.0 || fine >= last { a } else { a + (sample_level(fine + 1, s, t) - a) * frac }
    };
    match filter {
        Filter::Nearest => read_level(
            content,
            0,
            guard,
            |image| image.nearest(s * w, t * h, channel, wrap_s, wrap_t),
            |_, height| {
                let row = wrap_index((t * h).floor() as i64, height, wrap_t);
                with_row(content, 0, row, guard, |band, y| band.texel(y, (s * w).floor() as i64, channel, wrap_s))
                    .unwrap_or(0.0)
            },
        ),
        Filter::Bilinear => sample_level(0, s, t),
        Filter::Trilinear => trilinear(major.max(1.0).log2(), s, t),
        Filter::Anisotropic => {
            // Probes enough that each covers at most the minor axis (up to the maximum), at
            // the level of the width each probe covers.
            let probes =
                if major <= 1.0 { 1.0 } else { (major / minor.max(1e-6)).ceil().clamp(1.0, MAX_ANISOTROPY as f32) };
            let width = major / probes;
            let lod = width.max(minor).max(1.0).log2();
            if probes <= 1.0 {
                return trilinear(lod, s, t);
            }
            let n = probes as usize;
            // The major axis in st units, t flipped to run down the rows as `t` above.
            let (ds, dt) = (major_axis.0 / w, -major_axis.1 / h);
            let mut sum = 0.0;
            for k in 0..n {
                let offset = (k as f32 + 0.5) / probes - 0.5;
                sum += trilinear(lod, s + ds * offset, t + dt * offset);
            }
            sum / probes
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn bilinear_wraps_and_flips_t() {
        // 2×1: left texel red 1, right texel red 0.
        let tex = Texture { width: 2, height: 1, texels: vec![[1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.5]] };
        assert_eq!(tex.sample(0.25, 0.5, 0), 1.0);
        assert_eq!(tex.sample(0.75, 0.5, 0), 0.0);
        assert_eq!(tex.sample(0.5, 0.5, 0), 0.5);
        assert_eq!(tex.sample(1.25, 0.5, 0), 1.0, "repeat wrap");
        assert_eq!(tex.sample(f32::NAN, 0.5, 0), 0.0);
        assert_eq!(tex.sample(0.75, 0.5, 3), 0.5, "alpha");
        let id = register("test:bilinear".into(), tex).unwrap();
        assert_eq!(lookup(id, 0.25, 0.5, 0), 1.0);
        assert_eq!(lookup(id, 0.25, 0.5, 7), 0.0);
        assert_eq!(lookup(-3, 0.25, 0.5, 0), 0.0);
        assert_eq!(lookup(id, 0.25, 0.5, -1), 0.0);
    }

    #[test]
    fn wrap_modes() {
        // 2×1: red 1 then 0. At s = 1.25 (texel coordinate 2.0): repeat → texel 0 (1),
        // clamp → texel 1 (0), mirror → texel 1 (0), black → 0.
        let tex = Texture { width: 2, height: 1, texels: vec![[1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]] };
        assert_eq!(tex.sample_wrapped(1.25, 0.5, 0, WRAP_REPEAT, WRAP_REPEAT), 1.0);
        assert_eq!(tex.sample_wrapped(1.25, 0.5, 0, WRAP_CLAMP, WRAP_CLAMP), 0.0);
        assert_eq!(tex.sample_wrapped(-0.75, 0.5, 0, WRAP_CLAMP, WRAP_CLAMP), 1.0);
        assert_eq!(tex.sample_wrapped(1.25, 0.5, 0, WRAP_MIRROR, WRAP_MIRROR), 0.0);
        assert_eq!(tex.sample_wrapped(1.75, 0.5, 0, WRAP_MIRROR, WRAP_MIRROR), 1.0);
        assert_eq!(tex.sample_wrapped(-0.25, 0.5, 0, WRAP_MIRROR, WRAP_MIRROR), 1.0);
        assert_eq!(tex.sample_wrapped(1.75, 0.5, 3, WRAP_BLACK, WRAP_REPEAT), 0.0);
        assert_eq!(tex.sample_wrapped(0.25, 0.5, 3, WRAP_BLACK, WRAP_REPEAT), 1.0);
        let id = register("test:wrap".into(), tex).unwrap();
        assert_eq!(lookup(id, 1.25, 0.5, 16 * WRAP_CLAMP), 0.0);
        assert_eq!(lookup(id, 1.25, 0.5, 0), 1.0);
    }

    /// A `w × h` image of one 8-bit channel with `value(x, y)` per texel (raw, not sRGB).
    #[test]
    fn a_footprint_below_a_texel_reads_like_bilinear() {
        let id = register_image("test:sub-texel".into(), grey(64, 64, |x, y| ((x * 37 + y * 91) % 256) as u8)).unwrap();
        for k in 0..200 {
            let (s, t) = ((k as f32 * 0.618).fract(), (k as f32 * 0.377).fract());
            let bilinear = lookup(id, s, t, 0);
            // Axes of 0.9 texels, any orientation.
            let f = 0.9 / 64.0;
            let footprint = [f * 0.6, f * 0.8, -f * 0.8, f * 0.6];
            for filter in [Filter::Trilinear, Filter::Anisotropic] {
                assert_eq!(lookup_with(filter, id, s, t, 0, footprint), bilinear, "{filter:?} at ({s}, {t})");
            }
        }
    }

    #[test]
    fn wide_footprints_average_and_anisotropy_keeps_the_minor_axis_sharp() {
        // Rows alternate 0 and 255 (stripes along s): a footprint 8 texels along s and one
        // across keeps the row's value anisotropically; trilinear blurs it to the mean.
        let id = register_image("test:stripes".into(), grey(64, 64, |_, y| if y % 2 == 0 { 255 } else { 0 })).unwrap();
        let (s, t) = (0.3, 1.0 - 10.5 / 64.0); // row 10: 255
        let footprint = [8.0 / 64.0, 0.0, 0.0, 1.0 / 64.0];
        let aniso = lookup_with(Filter::Anisotropic, id, s, t, 0, footprint);
        let tri = lookup_with(Filter::Trilinear, id, s, t, 0, footprint);
        assert!((aniso - 1.0).abs() < 1e-6, "anisotropic: {aniso}");
        // 8-bit levels: the mean is stored as 128 / 255.
        assert!((tri - 0.5).abs() < 1.0 / 255.0, "trilinear: {tri}");
        // A footprint wider than the image reads its mean from the 1x1 level.
        let whole = lookup_with(Filter::Trilinear, id, s, t, 0, [4.0, 0.0, 0.0, 4.0]);
        assert!((whole - 0.5).abs() < 1.0 / 255.0, "{whole}");
        assert_eq!(lookup_with(Filter::Nearest, id, s, t, 0, footprint), 1.0);
        // Non-finite axes read as no footprint.
        assert_eq!(
            lookup_with(Filter::Trilinear, id, s, t, 0, [f32::NAN, f32::INFINITY, 0.0, 0.0]),
            lookup(id, s, t, 0)
        );
    }

    /// A source that counts its decodes.
    struct Counting(Image, Arc<AtomicUsize>);

    impl TexelSource for Counting {
        fn decode(&self) -> Result<Image, String> {
            self.1.fetch_add(1, Ordering::Relaxed);
            Ok(self.0.clone())
        }

        fn resident_bytes(&self) -> Option<u64> {
            Some(self.0.bytes() + self.0.bytes() / 3)
        }
    }

    /// An unregistered texture of `image` (no other test's eviction reaches it), its decode
    /// counter, and its mip chain built independently of the cache.
    fn counted(image: Image) -> (Content, Arc<AtomicUsize>, Vec<Image>) {
        let decodes = Arc::new(AtomicUsize::new(0));
        let (w, h) = (image.width, image.height);
        let mut chain = vec![image.clone()];
        while chain.len() < level_count(w, h) {
            let next = chain[chain.len() - 1].downsample();
            chain.push(next);
        }
        (Content::new(w, h, Box::new(Counting(image, Arc::clone(&decodes)))), decodes, chain)
    }

    /// Evicts `content`'s levels `range` as the budget would.
    fn evict(content: &Content, range: std::ops::RangeFrom<usize>) {
        let mut residency = RESIDENCY.lock().unwrap();
        let guard = &epoch::pin();
        for level in &content.levels[range] {
            if let Some(image) = level.image.swap(None, guard) {
                residency.resident -= image.bytes();
            }
        }
    }

    /// Level `index` of `content` as a lookup reaches it (loaded on a miss).
    fn level(content: &Content, index: usize) -> Image {
        with_level(content, index, &epoch::pin(), Image::clone).unwrap()
    }

    /// Whether every level of `content` is resident and equals `chain`'s.
    fn all_resident(content: &Content, chain: &[Image]) -> bool {
        let guard = &epoch::pin();
        content.levels.iter().zip(chain).all(|(level, want)| level.image.get(guard) == Some(want))
    }

    #[test]
    fn a_coarse_miss_is_made_from_a_resident_finer_level_without_decoding() {
        let (content, decodes, chain) = counted(grey(64, 48, |x, y| ((x * 37 + y * 91) % 256) as u8));
        assert_eq!(level(&content, 0), chain[0]);
        assert_eq!(decodes.load(Ordering::Relaxed), 1);
        evict(&content, 3..);
        assert_eq!(level(&content, 4), chain[4]);
        assert_eq!(decodes.load(Ordering::Relaxed), 1, "level 4 is made from the resident level 2");
        assert!(all_resident(&content, &chain));
        evict(&content, 0..);
    }

    #[test]
    fn a_decode_for_a_coarse_level_keeps_the_finer_ones_in_free_room_as_first_to_go() {
        let (content, decodes, chain) = counted(grey(40, 40, |x, y| (x * y % 256) as u8));
        assert_eq!(level(&content, 3), chain[3]);
        assert!(all_resident(&content, &chain));
        for (k, level) in content.levels.iter().enumerate() {
            let last_use = level.last_use.load(Ordering::Relaxed);
            assert_eq!(last_use == 0, k < 3, "level {k}: only the levels nobody asked for are oldest");
        }
        assert_eq!(level(&content, 0), chain[0], "resident");
        assert_eq!(decodes.load(Ordering::Relaxed), 1);
        evict(&content, 0..);
    }

    #[test]
    fn a_prefetched_texture_is_read_without_another_decode() {
        let (content, decodes, chain) = counted(grey(64, 48, |x, y| ((x * 13 + y * 7) % 256) as u8));
        let guard = &epoch::pin();
        assert!(prefetch_content(&content, guard));
        assert!(all_resident(&content, &chain), "the whole chain is made ahead");
        assert!(content.levels.iter().all(|l| l.last_use.load(Ordering::Relaxed) == 0), "kept as first to go");
        assert!(!prefetch_content(&content, guard), "a resident texture is not decoded again");
        for (k, want) in chain.iter().enumerate() {
            assert_eq!(&level(&content, k), want);
        }
        assert_eq!(decodes.load(Ordering::Relaxed), 1);
        assert!(content.levels.iter().all(|l| l.last_use.load(Ordering::Relaxed) > 0), "read since");
        evict(&content, 0..);
    }

    #[test]
    fn a_texture_larger_than_the_free_room_is_not_prefetched() {
        // 2^16 x 2^15 texels of one byte: 2.7 GiB with its chain, over the default budget
        // (tests never raise it). Never decoded.
        struct Huge(Arc<AtomicUsize>);
        impl TexelSource for Huge {
            fn decode(&self) -> Result<Image, String> {
                self.0.fetch_add(1, Ordering::Relaxed);
                Err("not decoded in this test".into())
            }
            fn resident_bytes(&self) -> Option<u64> {
                Some((1 << 31) + (1 << 31) / 3)
            }
        }
        let decodes = Arc::new(AtomicUsize::new(0));
        let content = Content::new(1 << 16, 1 << 15, Box::new(Huge(Arc::clone(&decodes))));
        assert!(!prefetch_content(&content, &epoch::pin()));
        assert_eq!(decodes.load(Ordering::Relaxed), 0);
        // Nor one whose size is unknown before decoding.
        struct Unsized;
        impl TexelSource for Unsized {
            fn decode(&self) -> Result<Image, String> {
                panic!("decoded ahead without a known size")
            }
        }
        assert!(!prefetch_content(&Content::new(4, 4, Box::new(Unsized)), &epoch::pin()));
    }

    #[test]
    fn replacing_a_source_reads_the_new_texels() {
        let id = register_image("test:replace".into(), grey(4, 4, |_, _| 0)).unwrap();
        assert_eq!(lookup(id, 0.5, 0.5, 0), 0.0);
        replace(id, Texture { width: 1, height: 1, texels: vec![[0.25, 0.5, 0.75, 1.0]] }).unwrap();
        assert_eq!(lookup(id, 0.5, 0.5, 2), 0.75);
        assert!(replace(1 << 30, Texture { width: 1, height: 1, texels: vec![[0.0; 4]] }).is_err());
    }
}
