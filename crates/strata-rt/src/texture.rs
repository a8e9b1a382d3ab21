//! Texture lookups for compiled shaders: a process-wide registry of decoded images, addressed
//! by small integer ids that code generation bakes into the call. Images are registered once,
//! at compile time; a lookup only reads (no allocation, no I/O on the shading path).

use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};

/// A decoded RGB image, linear floats, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Width in pixels (≥ 1).
    pub width: usize,
    /// Height in pixels (≥ 1).
    pub height: usize,
    /// `width * height` RGB texels, row-major, top row first.
    pub texels: Vec<[f32; 3]>,
}

impl Texture {
    /// Bilinear lookup with repeat wrapping; `t = 0` is the bottom row (USD's st convention).
    pub fn sample(&self, s: f32, t: f32, channel: usize) -> f32 {
        if !s.is_finite() || !t.is_finite() {
            return 0.0;
        }
        let x = s * self.width as f32 - 0.5;
        let y = (1.0 - t) * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |i: f32, n: usize| (i as i64).rem_euclid(n as i64) as usize;
        let at = |xi: f32, yi: f32| self.texels[wrap(yi, self.height) * self.width + wrap(xi, self.width)][channel];
        let top = at(x0, y0) + (at(x0 + 1.0, y0) - at(x0, y0)) * fx;
        let bottom = at(x0, y0 + 1.0) + (at(x0 + 1.0, y0 + 1.0) - at(x0, y0 + 1.0)) * fx;
        top + (bottom - top) * fy
    }
}

struct Registry {
    /// Loaded textures by id, with the file each came from.
    textures: Vec<(PathBuf, Arc<Texture>)>,
}

static REGISTRY: RwLock<Registry> = RwLock::new(Registry { textures: Vec::new() });

/// The id of the texture registered under `name`, if any.
pub fn find(name: &Path) -> Option<i32> {
    REGISTRY.read().ok().and_then(|r| r.textures.iter().position(|(p, _)| p == name)).map(|i| i as i32)
}

/// Registers an in-memory texture under a name (tests, generated images).
pub fn register(name: PathBuf, texture: Texture) -> Result<i32, String> {
    let mut registry = REGISTRY.write().map_err(|_| "texture registry poisoned".to_string())?;
    registry.textures.push((name, Arc::new(texture)));
    Ok(registry.textures.len() as i32 - 1)
}

/// Channel `channel` (0..3) of texture `id` at (s, t); 0 for an unknown id or channel.
pub fn lookup(id: i32, s: f32, t: f32, channel: i32) -> f32 {
    let Ok(registry) = REGISTRY.read() else { return 0.0 };
    match (usize::try_from(id).ok().and_then(|i| registry.textures.get(i)), channel) {
        (Some((_, tex)), 0..=2) => tex.sample(s, t, channel as usize),
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_wraps_and_flips_t() {
        // 2×1: left texel red 1, right texel red 0.
        let tex = Texture { width: 2, height: 1, texels: vec![[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]] };
        assert_eq!(tex.sample(0.25, 0.5, 0), 1.0);
        assert_eq!(tex.sample(0.75, 0.5, 0), 0.0);
        assert_eq!(tex.sample(0.5, 0.5, 0), 0.5);
        assert_eq!(tex.sample(1.25, 0.5, 0), 1.0, "repeat wrap");
        assert_eq!(tex.sample(f32::NAN, 0.5, 0), 0.0);
        let id = register("test:bilinear".into(), tex).unwrap();
        assert_eq!(lookup(id, 0.25, 0.5, 0), 1.0);
        assert_eq!(lookup(id, 0.25, 0.5, 7), 0.0);
        assert_eq!(lookup(-3, 0.25, 0.5, 0), 0.0);
    }
}
