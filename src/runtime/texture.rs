//! Texture files: decoding images for the runtime's texture registry
//! ([`strata_rt::texture`]), once per file, at compile time.

use std::path::Path;
pub use strata_rt::texture::{Texture, lookup, register};

/// Loads an OpenEXR file (its first RGBA layer). Non-finite texels become 0, so a broken
/// pixel cannot put NaN into every render that samples it.
pub fn load_exr(path: &Path) -> Result<Texture, String> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| Texture { width: size.width(), height: size.height(), texels: vec![[0.0; 3]; size.area()] },
        |tex: &mut Texture, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let clean = |x: f32| if x.is_finite() { x } else { 0.0 };
            tex.texels[pos.y() * tex.width + pos.x()] = [clean(r), clean(g), clean(b)];
        },
    )
    .map_err(|e| e.to_string())?;
    let tex = image.layer_data.channel_data.pixels;
    if tex.width == 0 || tex.height == 0 {
        return Err("the image is empty".into());
    }
    Ok(tex)
}

/// Loads `path` (once per process) into the registry and returns its id.
pub fn register_file(path: &Path) -> Result<i32, String> {
    let canonical = path.canonicalize().map_err(|e| format!("cannot open texture `{}`: {e}", path.display()))?;
    if let Some(id) = strata_rt::texture::find(&canonical) {
        return Ok(id);
    }
    let texture = load_exr(&canonical).map_err(|e| format!("cannot read texture `{}`: {e}", path.display()))?;
    register(canonical, texture)
}
