//! Streamed decodes and bands: a miss of a level streams its source's rows through a
//! [`MipCascade`], making whole only the levels that may stay; a level over half the budget
//! is read by bands of [`BAND_ROWS`] rows, each a unit of residency.

use super::image::{self, Image, MipCascade};
use super::{
    BAND_ROWS, CLOCK, Content, DECODES, Guard, MISSES, Ordering, RESIDENCY, keep, level_size, memory_budget,
    with_level, wrap_index,
};

/// What streaming a source's rows through the mip cascade gave.
pub(super) enum Streamed {
    /// Per level, the image made whole (levels that were not wanted or could not fit: none).
    Levels(Vec<Option<Image>>),
    /// The wanted level is larger than half the budget: nothing was made.
    TooLarge,
    /// The source failed or handed rows that do not match its size.
    Failed,
}

/// Bytes per texel of `rows` (channels times bytes per value).
fn texel_bytes(rows: &Image) -> u64 {
    (rows.channels * rows.texels.bytes_per_value()) as u64
}

/// Whether `rows` may follow `seen` rows of a `width × height` texture's finest level.
fn rows_fit(rows: &Image, width: usize, height: usize, seen: usize) -> bool {
    rows.width == width && (1..=4).contains(&rows.channels) && rows.is_consistent() && seen + rows.height <= height
}

/// Streams `content`'s source through a [`MipCascade`] for a miss of level `index`, keeping
/// whole only the levels that may stay: the wanted level and the coarser ones not resident
/// (each within half the budget), and finer ones (`on the way`) within the room free now. The
/// wanted level is checked against the budget when the first rows tell the texel size.
pub(super) fn stream_levels(content: &Content, index: usize, ahead: bool, guard: &Guard) -> Streamed {
    let (width, height) = (content.width, content.height);
    let (budget, count) = (memory_budget(), content.levels.len());
    let free = budget.saturating_sub(RESIDENCY.lock().map(|r| r.resident).unwrap_or(u64::MAX));
    let mut cascade = MipCascade::new(width, height);
    let mut made: Vec<Option<Image>> = vec![None; count];
    let mut wanted: Option<Vec<bool>> = None;
    let (mut seen, mut bad, mut too_large) = (0, false, false);
    let decoded = content.source.decode_rows(&mut |rows| {
        if !rows_fit(&rows, width, height, seen) {
            bad = true;
            return false;
        }
        let wanted = wanted.get_or_insert_with(|| {
            let bytes = |l| {
                let (w, h) = level_size(width, height, l);
                (w * h) as u64 * texel_bytes(&rows)
            };
            too_large = !ahead && bytes(index) > budget / 2;
            // Coarsest first, so the coarsest on-the-way levels take the free room first.
            let mut room = free;
            let mut plan: Vec<bool> = (0..count)
                .rev()
                .map(|l| match l.cmp(&index) {
                    std::cmp::Ordering::Less => {
                        let fits = bytes(l) <= room;
                        room -= if fits { bytes(l) } else { 0 };
                        fits
                    }
                    std::cmp::Ordering::Equal => true,
                    std::cmp::Ordering::Greater => {
                        let level = &content.levels[l];
                        bytes(l) <= budget / 2
                            && level.image.get(guard).is_none()
                            && !level.banded.load(Ordering::Relaxed)
                    }
                })
                .collect();
            plan.reverse();
            plan
        });
        if too_large {
            return false;
        }
        // The finest level handed over whole (a source decoded whole) is kept, not copied.
        let whole = rows.height == height && wanted[0];
        cascade.push(seen, &rows, &mut |level, _, rows| {
            if wanted[level] && !(level == 0 && whole) {
                match &mut made[level] {
                    Some(image) => _ = image.append_rows(rows),
                    slot => {
                        // Room for the whole level at once: growing by doubling would peak
                        // at one and a half times its size.
                        let mut image = rows.clone();
                        image.reserve_rows(level_size(width, height, level).1 - rows.height);
                        *slot = Some(image);
                    }
                }
            }
        });
        seen += rows.height;
        if whole {
            made[0] = Some(rows);
        }
        true
    });
    if too_large {
        return Streamed::TooLarge;
    }
    if decoded.is_err() || bad || seen != height {
        return Streamed::Failed;
    }
    Streamed::Levels(made)
}

/// Runs `read` on band `band` of level `level` (a level larger than half the budget, read by
/// bands), made when not resident by streaming the source's rows through the cascade until
/// the band is complete (decoding stops there). Other bands of the level passed on the way
/// are kept in the room the budget has free, as the first to be evicted. `None` when the
/// source fails.
#[cold]
fn load_band<R>(
    content: &Content,
    level: usize,
    band: usize,
    guard: &Guard,
    read: impl FnOnce(&Image) -> R,
) -> Option<R> {
    MISSES.fetch_add(1, Ordering::Relaxed);
    let _decoding = content.decoding.lock().ok()?;
    let bands = &content.levels[level].bands;
    if let Some(image) = bands[band].image.get(guard) {
        return Some(read(image)); // another thread made it meanwhile
    }
    if content.failed.load(Ordering::Relaxed) {
        return None;
    }
    DECODES.fetch_add(1, Ordering::Relaxed);
    let (width, height) = (content.width, content.height);
    let mut room = memory_budget().saturating_sub(RESIDENCY.lock().map(|r| r.resident).unwrap_or(u64::MAX));
    let mut cascade = MipCascade::new(width, height);
    // The bands made, by band index (at most the wanted one and those fitting the room).
    let mut made: Vec<(usize, Image)> = Vec::new();
    let (mut seen, mut bad, mut done) = (0, false, false);
    let decoded = content.source.decode_rows(&mut |rows| {
        if !rows_fit(&rows, width, height, seen) {
            bad = true;
            return false;
        }
        cascade.push(seen, &rows, &mut |l, first, rows| {
            if l != level || done {
                return;
            }
            // Split the run at band boundaries; each piece appends to its band or is dropped.
            let mut y = first;
            while y < first + rows.height {
                let b = y / BAND_ROWS;
                let range = content.band_rows(level, b);
                let piece = rows.rows(y - first..range.end.min(first + rows.height) - first);
                let start = y == range.start;
                y += piece.height;
                let bytes = (range.len() * rows.width) as u64 * texel_bytes(rows);
                match made.last_mut() {
                    Some((at, image)) if *at == b => _ = image.append_rows(&piece),
                    _ if start && (b == band || (b < band && bytes <= room)) => {
                        if b != band {
                            room -= bytes;
                        }
                        made.push((b, piece));
                    }
                    _ => {}
                }
                if b == band && y == range.end {
                    done = true;
                    return;
                }
            }
        });
        seen += rows.height;
        !done
    });
    if decoded.is_err() || bad || !done {
        content.failed.store(true, Ordering::Relaxed);
        return None;
    }
    let (_, wanted) = made.pop()?;
    let result = read(&wanted);
    let Ok(mut residency) = RESIDENCY.lock() else { return Some(result) };
    if content.retired.load(Ordering::Relaxed) {
        return Some(result);
    }
    let now = CLOCK.fetch_add(1, Ordering::Relaxed) + 1;
    keep(&mut residency, &bands[band], wanted, Some(now), guard);
    for (b, image) in made.into_iter().rev() {
        keep(&mut residency, &bands[b], image, None, guard);
    }
    drop(residency);
    guard.flush();
    Some(result)
}

/// Runs `read` on band `band` of level `level` of `content` (one read by bands), loading it
/// on a miss.
#[inline]
fn with_band<R>(
    content: &Content,
    level: usize,
    band: usize,
    guard: &Guard,
    read: impl FnOnce(&Image) -> R,
) -> Option<R> {
    if let Some(image) = content.levels[level].bands[band].touch(guard) {
        return Some(read(image));
    }
    load_band(content, level, band, guard, read)
}

/// Row `row` of level `level` read through its band: `read(band, row within the band)`;
/// `None` for a black row (no row) or a source that fails.
#[inline]
pub(super) fn with_row<R>(
    content: &Content,
    level: usize,
    row: Option<usize>,
    guard: &Guard,
    read: impl FnOnce(&Image, usize) -> R,
) -> Option<R> {
    let row = row?;
    with_band(content, level, row / BAND_ROWS, guard, |band| read(band, row % BAND_ROWS))
}

/// A texel read of level `level` of `content`: `whole` on the level when it is (or can be)
/// made whole, else `banded` with the level's size, through its bands.
#[inline]
pub(super) fn read_level(
    content: &Content,
    level: usize,
    guard: &Guard,
    whole: impl FnOnce(&Image) -> f32,
    banded: impl FnOnce(usize, usize) -> f32,
) -> f32 {
    let held = &content.levels[level];
    if !held.banded.load(Ordering::Relaxed) {
        if let Some(value) = with_level(content, level, guard, whole) {
            return value;
        }
        if !held.banded.load(Ordering::Relaxed) {
            return 0.0; // the source failed
        }
    }
    let (w, h) = level_size(content.width, content.height, level);
    banded(w, h)
}

/// Bilinear lookup of level `level` at (s, t) in [0, 1]² (t down the rows), whole or by bands
/// (the same arithmetic, row by row).
#[inline]
pub(super) fn bilinear_at(
    content: &Content,
    level: usize,
    s: f32,
    t: f32,
    channel: usize,
    wrap: (i32, i32),
    guard: &Guard,
) -> f32 {
    let (wrap_s, wrap_t) = wrap;
    read_level(
        content,
        level,
        guard,
        |image| image.bilinear(s * image.width as f32, t * image.height as f32, channel, wrap_s, wrap_t),
        |w, h| {
            let ((x0, fx), (y0, fy)) = (image::bilinear_corner(s * w as f32), image::bilinear_corner(t * h as f32));
            let row = |yi: i64| {
                with_row(content, level, wrap_index(yi, h, wrap_t), guard, |band, y| {
                    band.row_lerp(Some(y), x0, fx, channel, wrap_s)
                })
                .unwrap_or(0.0)
            };
            let (top, bottom) = (row(y0), row(y0 + 1));
            top + (bottom - top) * fy
        },
    )
}
