//! Texture files: decoding images for the runtime's texture registry
//! ([`strata_rt::texture`]), once per file, at compile time.

use crate::input;
use std::io::Cursor;
use std::path::Path;
pub use strata_rt::texture::{Texture, lookup, register};

/// An RGB image decoded from an EXR file: width, height and row-major texels, top row first.
pub type RgbImage = (usize, usize, Vec<[f32; 3]>);

/// Checks every layer an EXR header describes against `max_pixels` before anything is
/// decoded: the decoder allocates from the header's sizes, and a header of a few bytes can
/// claim 2e6 × 2e6 pixels (a 48 TB allocation). Also bounds the decoded bytes of all
/// channels (16 bytes per pixel: RGBA f32), since a layer with thousands of channels decodes
/// blocks of all of them.
pub fn check_exr_header(bytes: &[u8], max_pixels: u64) -> Result<(), String> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(|e| e.to_string())?;
    for header in meta.headers.iter() {
        let (w, h) = (header.layer_size.width() as u64, header.layer_size.height() as u64);
        let pixels = w.saturating_mul(h);
        if pixels > max_pixels {
            return Err(format!(
                "the image is {w} x {h} = {pixels} pixels, more than the texture limit of {max_pixels} pixels \
                 (raise it with --max-texture-pixels)"
            ));
        }
        let mut block_pixels = pixels;
        if let exr::meta::BlockDescription::Tiles(tiles) = &header.blocks {
            let tile = (tiles.tile_size.width() as u64).saturating_mul(tiles.tile_size.height() as u64);
            block_pixels = block_pixels.max(tile);
        }
        let bytes_per_pixel = header.channels.bytes_per_pixel as u64;
        if block_pixels.saturating_mul(bytes_per_pixel) > max_pixels.saturating_mul(16) {
            return Err(format!(
                "the image's {} channel(s) of {w} x {h} pixels (tiles of {block_pixels}) decode to more than \
                 {} bytes, the texture limit of {max_pixels} RGBA float pixels (raise it with --max-texture-pixels)",
                header.channels.list.len(),
                max_pixels.saturating_mul(16)
            ));
        }
    }
    Ok(())
}

/// Decodes the first RGB(A) layer of an EXR held in memory, after [`check_exr_header`].
pub fn decode_rgb_exr(bytes: &[u8], max_pixels: u64) -> Result<RgbImage, String> {
    use exr::prelude::{ReadChannels, ReadLayers};
    check_exr_header(bytes, max_pixels)?;
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |size, _| (size.width(), size.height(), vec![[0.0f32; 3]; size.area()]),
            |(w, _, px): &mut RgbImage, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| e.to_string())?;
    let (w, h, texels) = image.layer_data.channel_data.pixels;
    if w == 0 || h == 0 {
        return Err("the image is empty".into());
    }
    Ok((w, h, texels))
}

/// Reads the first RGB(A) layer of an EXR file: a bounded read ([`input::read_bytes`]), the
/// header checked against [`input::limits`], then decoded.
pub fn read_rgb_exr(path: &Path) -> Result<RgbImage, String> {
    let bytes = input::read_bytes(path).map_err(|e| e.to_string())?;
    decode_rgb_exr(&bytes, input::limits().max_texture_pixels)
}

/// Loads an OpenEXR file (its first RGBA layer). Non-finite texels become 0, so a broken
/// pixel cannot put NaN into every render that samples it.
pub fn load_exr(path: &Path) -> Result<Texture, String> {
    let (width, height, mut texels) = read_rgb_exr(path)?;
    for texel in &mut texels {
        for c in texel.iter_mut() {
            if !c.is_finite() {
                *c = 0.0;
            }
        }
    }
    Ok(Texture { width, height, texels })
}

/// Loads `path` (once per process) into the registry and returns its id.
pub fn register_file(path: &Path) -> Result<i32, String> {
    let canonical =
        crate::input::canonicalize(path).map_err(|e| format!("cannot open texture `{}`: {e}", path.display()))?;
    if let Some(id) = strata_rt::texture::find(&canonical) {
        return Ok(id);
    }
    let texture = load_exr(&canonical).map_err(|e| format!("cannot read texture `{}`: {e}", path.display()))?;
    register(canonical, texture)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use exr::prelude::{Encoding, WritableImage};

    /// A small valid RGB EXR in memory.
    pub(crate) fn small_exr(width: usize, height: usize) -> Vec<u8> {
        let layer = exr::prelude::Layer::new(
            (width, height),
            exr::prelude::LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            exr::prelude::SpecificChannels::rgb(|pos: exr::prelude::Vec2<usize>| {
                (pos.x() as f32, pos.y() as f32, 0.5f32)
            }),
        );
        let image = exr::prelude::Image::from_layer(layer);
        let mut bytes = Cursor::new(Vec::new());
        image.write().to_buffered(&mut bytes).expect("write exr");
        bytes.into_inner()
    }

    /// `bytes` with the `dataWindow` attribute's max corner set to (x, y): a header that
    /// claims a huge image while the file stays tiny.
    pub(crate) fn with_data_window_max(mut bytes: Vec<u8>, x: i32, y: i32) -> Vec<u8> {
        let name = b"dataWindow\0box2i\0";
        let at = bytes.windows(name.len()).position(|w| w == name).expect("a dataWindow attribute");
        // name, type, i32 size (16), then xMin, yMin, xMax, yMax.
        let max = at + name.len() + 4 + 8;
        bytes[max..max + 4].copy_from_slice(&x.to_le_bytes());
        bytes[max + 4..max + 8].copy_from_slice(&y.to_le_bytes());
        bytes
    }

    #[test]
    fn small_exr_decodes() {
        let (w, h, texels) = decode_rgb_exr(&small_exr(3, 2), 6).expect("decodes");
        assert_eq!((w, h), (3, 2));
        assert_eq!(texels[5], [2.0, 1.0, 0.5]);
        let err = decode_rgb_exr(&small_exr(3, 2), 5).unwrap_err();
        assert!(err.contains("3 x 2 = 6 pixels, more than the texture limit of 5"), "{err}");
    }

    #[test]
    fn huge_header_is_refused_before_allocating() {
        // 2e6 x 2e6 RGB f32 pixels would be 48 TB: the header alone must stop it.
        let bytes = with_data_window_max(small_exr(2, 2), 1_999_999, 1_999_999);
        assert!(bytes.len() < 1000);
        let err = decode_rgb_exr(&bytes, input::DEFAULT_MAX_TEXTURE_PIXELS).unwrap_err();
        assert!(err.contains("2000000 x 2000000 = 4000000000000 pixels"), "{err}");
        // Garbage is an error too, never a panic.
        assert!(decode_rgb_exr(b"v/1\x01garbage", 100).is_err());
        assert!(decode_rgb_exr(&[], 100).is_err());
    }
}
