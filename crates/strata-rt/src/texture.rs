//! Texture lookups for compiled shaders: a process-wide registry of decoded images, addressed
//! by small integer ids that code generation bakes into the call. Images are registered once,
//! at compile time; a lookup only reads (no allocation, no I/O on the shading path).
//!
//! The `channel` argument of [`lookup`] carries the wrap modes too, so the C symbol keeps its
//! four-argument signature: `channel + 16 · wrap_s + 256 · wrap_t`, with the channel in 0..=3
//! (r, g, b, a) and each wrap mode one of the `WRAP_*` constants. Old callers that pass a bare
//! channel get repeat wrapping, as before.

use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};

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

struct Registry {
    /// Loaded textures by id, with the name each was registered under.
    textures: Vec<(PathBuf, Arc<Texture>)>,
}

static REGISTRY: RwLock<Registry> = RwLock::new(Registry { textures: Vec::new() });

/// The id of the texture registered under `name`, if any.
pub fn find(name: &Path) -> Option<i32> {
    REGISTRY.read().ok().and_then(|r| r.textures.iter().position(|(p, _)| p == name)).map(|i| i as i32)
}

/// The names of every registered texture, by id.
pub fn names() -> Vec<PathBuf> {
    REGISTRY.read().map(|r| r.textures.iter().map(|(p, _)| p.clone()).collect()).unwrap_or_default()
}

/// Replaces the texels of texture `id` (its file changed): code compiled against the id reads
/// the new texels from the next lookup on. Lookups already running keep the old texels.
pub fn replace(id: i32, texture: Texture) -> Result<(), String> {
    let mut registry = REGISTRY.write().map_err(|_| "texture registry poisoned".to_string())?;
    let entry = usize::try_from(id).ok().and_then(|i| registry.textures.get_mut(i)).ok_or("no such texture")?;
    entry.1 = Arc::new(texture);
    Ok(())
}

/// Registers an in-memory texture under a name (tests, generated images).
pub fn register(name: PathBuf, texture: Texture) -> Result<i32, String> {
    let mut registry = REGISTRY.write().map_err(|_| "texture registry poisoned".to_string())?;
    registry.textures.push((name, Arc::new(texture)));
    Ok(registry.textures.len() as i32 - 1)
}

/// Channel `mode % 16` (0..=3: r, g, b, a) of texture `id` at (s, t), wrapped by
/// `(mode / 16) % 16` along s and `mode / 256` along t (`WRAP_*`); 0 for an unknown id or
/// channel.
pub fn lookup(id: i32, s: f32, t: f32, mode: i32) -> f32 {
    let Ok(registry) = REGISTRY.read() else { return 0.0 };
    let (channel, wrap_s, wrap_t) = (mode & 15, (mode >> 4) & 15, (mode >> 8) & 15);
    match (usize::try_from(id).ok().and_then(|i| registry.textures.get(i)), channel) {
        (Some((_, tex)), 0..=3) if (0..4096).contains(&mode) => {
            tex.sample_wrapped(s, t, channel as usize, wrap_s, wrap_t)
        }
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
