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

/// How 8-bit and 16-bit texels are turned into linear values (UsdUVTexture's
/// `sourceColorSpace`). Float images (EXR, HDR) are linear in every mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ColorSpace {
    /// sRGB-decode the colour channels of 8-bit RGB(A) images; everything else is raw.
    Auto,
    /// sRGB-decode the colour channels of every integer image (alpha stays linear).
    Srgb,
    /// Use texel values as they are (normalised to [0, 1]).
    Raw,
}

impl ColorSpace {
    /// Parses `auto`, `sRGB` or `raw` (UsdUVTexture's tokens; the empty string is `auto`).
    pub fn parse(name: &str) -> Option<ColorSpace> {
        match name {
            "" | "auto" => Some(ColorSpace::Auto),
            "sRGB" => Some(ColorSpace::Srgb),
            "raw" => Some(ColorSpace::Raw),
            _ => None,
        }
    }

    fn key(self) -> &'static str {
        match self {
            ColorSpace::Auto => "auto",
            ColorSpace::Srgb => "sRGB",
            ColorSpace::Raw => "raw",
        }
    }
}

/// The sRGB transfer function inverted: an encoded value in [0, 1] to linear (IEC 61966-2-1).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// Whether the bytes start like an OpenEXR file.
fn is_exr(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01])
}

/// The image formats textures and dome maps may use besides OpenEXR, as the `image` crate
/// names them: what production assets carry (PNG, JPEG, HDR; TGA and BMP from game exporters;
/// TIFF from DCCs and scanners).
const IMAGE_FORMATS: &[image::ImageFormat] = {
    use image::ImageFormat::{Bmp, Hdr, Jpeg, Png, Tga, Tiff};
    &[Png, Jpeg, Hdr, Tga, Bmp, Tiff]
};

/// A reader for `bytes`, its format told by content, else (TGA has no signature) by the
/// extension of `name`; an error when it is none of [`IMAGE_FORMATS`].
fn image_reader<'a>(bytes: &'a [u8], name: Option<&Path>) -> Result<image::ImageReader<Cursor<&'a [u8]>>, String> {
    let mut reader = image::ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| e.to_string())?;
    if reader.format().is_none()
        && let Some(format) = name.and_then(|n| image::ImageFormat::from_path(n).ok())
    {
        reader.set_format(format);
    }
    match reader.format() {
        Some(format) if IMAGE_FORMATS.contains(&format) => Ok(reader),
        _ => Err("not a supported image format (expected OpenEXR, PNG, JPEG, Radiance HDR, TGA, BMP or TIFF)".into()),
    }
}

/// The width and height an image header claims, read without decoding (the `image` crate
/// reads only the header for this). `name` tells formats without a signature (TGA).
pub fn image_dimensions(bytes: &[u8], name: Option<&Path>) -> Result<(u32, u32), String> {
    image_reader(bytes, name)?.into_dimensions().map_err(|e| e.to_string())
}

/// Decodes an image held in memory (OpenEXR or one of [`IMAGE_FORMATS`], told apart by their
/// first bytes) into linear RGBA, after checking the header's size against `max_pixels`.
/// Non-finite texels become 0.
pub fn decode_texture(bytes: &[u8], space: ColorSpace, max_pixels: u64) -> Result<Texture, String> {
    decode_texture_named(bytes, None, space, max_pixels)
}

/// [`decode_texture`] for the file `name`, whose extension tells formats without a signature.
pub fn decode_texture_named(
    bytes: &[u8],
    name: Option<&Path>,
    space: ColorSpace,
    max_pixels: u64,
) -> Result<Texture, String> {
    decode_texture_budgeted(bytes, name, space, max_pixels, 0)
}

/// Bytes per pixel of a decoded texture as strata keeps it: RGBA f32.
const TEXEL_BYTES: u64 = 16;

/// The texture's memory, checked against [`input::memory_budget`] before decoding: what the
/// decoder produces (`decoded` bytes) plus the RGBA float texels made from it, plus what the
/// caller builds from those (`extra_per_pixel`: a dome's sampling tables).
fn check_texture_memory(w: u64, h: u64, decoded: u64, extra_per_pixel: u64) -> Result<(), String> {
    let pixels = w.saturating_mul(h);
    let total = decoded.saturating_add(pixels.saturating_mul(TEXEL_BYTES + extra_per_pixel));
    input::check_memory(&format!("decoding the {w} x {h} image"), total)
}

/// Rows converted to RGBA floats at a time: the decoded image and the texels are whole, the
/// conversion's temporary is one band.
const BAND_ROWS: u32 = 64;

/// [`decode_texture_named`] for a caller that builds `extra_per_pixel` more bytes per pixel
/// from the texels (counted in the memory check before decoding).
pub fn decode_texture_budgeted(
    bytes: &[u8],
    name: Option<&Path>,
    space: ColorSpace,
    max_pixels: u64,
    extra_per_pixel: u64,
) -> Result<Texture, String> {
    use image::ImageDecoder;
    let (width, height, mut texels) = if is_exr(bytes) {
        check_exr_header(bytes, max_pixels)?;
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(|e| e.to_string())?;
        for header in meta.headers.iter() {
            let (w, h) = (header.layer_size.width() as u64, header.layer_size.height() as u64);
            // Decoded as RGB floats, then widened to RGBA.
            check_texture_memory(w, h, w.saturating_mul(h).saturating_mul(12), extra_per_pixel)?;
        }
        let (w, h, rgb) = decode_rgb_exr(bytes, max_pixels)?;
        (w, h, rgb.into_iter().map(|[r, g, b]| [r, g, b, 1.0]).collect::<Vec<_>>())
    } else {
        let (w, h) = image_dimensions(bytes, name)?;
        let pixels = u64::from(w) * u64::from(h);
        if pixels > max_pixels {
            return Err(format!(
                "the image is {w} x {h} = {pixels} pixels, more than the texture limit of {max_pixels} pixels \
                 (raise it with --max-texture-pixels)"
            ));
        }
        if pixels == 0 {
            return Err("the image is empty".into());
        }
        let mut reader = image_reader(bytes, name)?;
        // A second guard inside the decoder: none of its own buffers may exceed what the
        // budget leaves beside the texels.
        let texel_bytes = pixels.saturating_mul(TEXEL_BYTES + extra_per_pixel);
        let mut limits = image::Limits::default();
        limits.max_alloc = Some(input::memory_budget().saturating_sub(texel_bytes).max(1 << 20));
        reader.limits(limits);
        let decoder = reader.into_decoder().map_err(|e| e.to_string())?;
        check_texture_memory(u64::from(w), u64::from(h), decoder.total_bytes(), extra_per_pixel)?;
        let image = image::DynamicImage::from_decoder(decoder).map_err(|e| e.to_string())?;
        let color = image.color();
        let float = matches!(color, image::ColorType::Rgb32F | image::ColorType::Rgba32F);
        let eight_bit = color.bytes_per_pixel() == color.channel_count();
        let srgb = match space {
            ColorSpace::Raw => false,
            ColorSpace::Srgb => !float,
            ColorSpace::Auto => eight_bit && color.has_color(),
        };
        let (w, h) = (image.width(), image.height());
        let mut texels: Vec<[f32; 4]> = Vec::new();
        texels
            .try_reserve_exact(w as usize * h as usize)
            .map_err(|_| format!("cannot allocate {} for its texels", input::human_bytes(texel_bytes)))?;
        // Band by band: converting the whole image at once would hold a third copy.
        for y in (0..h).step_by(BAND_ROWS as usize) {
            let band = image.crop_imm(0, y, w, BAND_ROWS.min(h - y)).into_rgba32f();
            texels.extend(band.pixels().map(|p| {
                let [r, g, b, a] = p.0;
                if srgb { [srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a] } else { [r, g, b, a] }
            }));
        }
        (w as usize, h as usize, texels)
    };
    for texel in &mut texels {
        for c in texel.iter_mut() {
            if !c.is_finite() {
                *c = 0.0;
            }
        }
    }
    Ok(Texture { width, height, texels })
}

/// Loads `path` (once per process and colour space) into the registry and returns its id.
/// The file is read through [`input::read_bytes`] (size limit, package paths); its header
/// is checked against [`input::limits`] before decoding.
pub fn register_file(path: &Path) -> Result<i32, String> {
    register_file_as(path, ColorSpace::Auto)
}

/// [`register_file`] with an explicit colour space.
pub fn register_file_as(path: &Path, space: ColorSpace) -> Result<i32, String> {
    // `input` canonicalizes package paths (`a.usdz[tex.png]`) too.
    let canonical =
        crate::input::canonicalize(path).map_err(|e| format!("cannot open texture `{}`: {e}", path.display()))?;
    let mut key = canonical.clone().into_os_string();
    key.push(format!("#{}", space.key()));
    let key = std::path::PathBuf::from(key);
    if let Some(id) = strata_rt::texture::find(&key) {
        return Ok(id);
    }
    let texture = input::read_bytes(&canonical)
        .map_err(|e| e.to_string())
        .and_then(|bytes| decode_texture_named(&bytes, Some(path), space, input::limits().max_texture_pixels))
        .map_err(|e| format!("cannot read texture `{}`: {e}", path.display()))?;
    register(key, texture)
}

/// Whether a texture was registered under a name starting with `prefix` (a canonical path
/// and `#`: loaded from that file in any colour space).
pub fn registered_from(prefix: &str) -> bool {
    strata_rt::texture::names().iter().any(|n| n.to_string_lossy().starts_with(prefix))
}

/// Reads `path` again into every registry entry loaded from it (one per colour space), so
/// materials compiled against those ids see the new texels without recompiling. Returns how
/// many entries were replaced: 0 when no texture was loaded from `path`.
pub fn reload_file(path: &Path) -> Result<usize, String> {
    let Ok(canonical) = crate::input::canonicalize(path) else { return Ok(0) };
    let mut replaced = 0;
    for (id, name) in strata_rt::texture::names().into_iter().enumerate() {
        let name = name.to_string_lossy().into_owned();
        let Some(space) = [ColorSpace::Auto, ColorSpace::Srgb, ColorSpace::Raw]
            .into_iter()
            .find(|space| name == format!("{}#{}", canonical.display(), space.key()))
        else {
            continue;
        };
        let texture = input::read_bytes(&canonical)
            .map_err(|e| e.to_string())
            .and_then(|bytes| decode_texture_named(&bytes, Some(path), space, input::limits().max_texture_pixels))
            .map_err(|e| format!("cannot read texture `{}`: {e}", path.display()))?;
        strata_rt::texture::replace(id as i32, texture)?;
        replaced += 1;
    }
    Ok(replaced)
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

    /// An 8-bit PNG in memory, written with the `png` crate (not the decoder under test).
    pub(crate) fn small_png(width: u32, height: u32, color: png::ColorType, data: &[u8]) -> Vec<u8> {
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(color);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().expect("header");
        writer.write_image_data(data).expect("data");
        writer.finish().expect("finish");
        bytes
    }

    #[test]
    fn png_decodes_with_srgb_and_alpha() {
        // 2×1 RGBA: (255, 128, 0, 64) and (0, 0, 0, 255).
        let bytes = small_png(2, 1, png::ColorType::Rgba, &[255, 128, 0, 64, 0, 0, 0, 255]);
        let srgb = |c: f32| if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
        let tex = decode_texture(&bytes, ColorSpace::Auto, 100).expect("decodes");
        assert_eq!((tex.width, tex.height), (2, 1));
        let [r, g, b, a] = tex.texels[0];
        assert_eq!((r, b), (1.0, 0.0));
        assert!((g - srgb(128.0 / 255.0)).abs() < 1e-6, "{g}");
        assert!((a - 64.0 / 255.0).abs() < 1e-6, "alpha stays linear: {a}");
        let raw = decode_texture(&bytes, ColorSpace::Raw, 100).expect("decodes");
        assert!((raw.texels[0][1] - 128.0 / 255.0).abs() < 1e-6);
        // Grey images are data (roughness, masks): auto leaves them raw, sRGB decodes them.
        let grey = small_png(1, 1, png::ColorType::Grayscale, &[128]);
        let t = decode_texture(&grey, ColorSpace::Auto, 100).unwrap();
        assert!((t.texels[0][0] - 128.0 / 255.0).abs() < 1e-6 && t.texels[0][3] == 1.0);
        let t = decode_texture(&grey, ColorSpace::Srgb, 100).unwrap();
        assert!((t.texels[0][2] - srgb(128.0 / 255.0)).abs() < 1e-6);
    }

    #[test]
    fn image_headers_are_checked_before_decoding() {
        let bytes = small_png(4, 4, png::ColorType::Rgb, &[7; 48]);
        let err = decode_texture(&bytes, ColorSpace::Auto, 15).unwrap_err();
        assert!(err.contains("4 x 4 = 16 pixels, more than the texture limit of 15"), "{err}");
        // A 60-byte file claiming 100000 × 100000 RGB pixels (30 GB decoded): refused from
        // the header alone.
        let crc32 = |data: &[u8]| {
            let mut crc = !0u32;
            for &b in data {
                crc ^= u32::from(b);
                for _ in 0..8 {
                    crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
                }
            }
            !crc
        };
        let chunk = |kind: &[u8], data: &[u8]| {
            let mut c = (data.len() as u32).to_be_bytes().to_vec();
            let body = [kind, data].concat();
            c.extend_from_slice(&body);
            c.extend_from_slice(&crc32(&body).to_be_bytes());
            c
        };
        let mut ihdr = 100_000u32.to_be_bytes().repeat(2);
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
        let huge = [
            b"\x89PNG\r\n\x1a\n".to_vec(),
            chunk(b"IHDR", &ihdr),
            chunk(b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]),
            chunk(b"IEND", &[]),
        ]
        .concat();
        assert!(huge.len() < 80);
        let err = decode_texture(&huge, ColorSpace::Auto, input::DEFAULT_MAX_TEXTURE_PIXELS).unwrap_err();
        assert!(err.contains("100000 x 100000"), "{err}");
        let err = decode_texture(b"GIF89a not supported", ColorSpace::Auto, 100).unwrap_err();
        assert!(err.contains("not a supported image format"), "{err}");
        assert!(decode_texture(&bytes[..30], ColorSpace::Auto, 100).is_err(), "truncated");
        assert!(decode_texture(&[], ColorSpace::Auto, 100).is_err());
        // EXR still goes through its own header check.
        assert!(decode_texture(&small_exr(3, 2), ColorSpace::Auto, 5).unwrap_err().contains("3 x 2 = 6"));
        assert_eq!(decode_texture(&small_exr(3, 2), ColorSpace::Srgb, 6).unwrap().texels[5], [2.0, 1.0, 0.5, 1.0]);
    }
}
