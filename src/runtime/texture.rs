//! Texture files for the runtime's texture registry ([`strata_rt::texture`]): registered at
//! compile time from their header alone (size, channels, precision and colour space are
//! checked there, so `strata check` never decodes a pixel), decoded at their own precision
//! when a lookup first reaches them ([`decode_image`]). Dome maps still decode to RGBA floats
//! ([`decode_texture_budgeted`]): their sampling tables need every texel.

use crate::input;
use std::io::Cursor;
use std::path::Path;
pub use strata_rt::texture::{Image, Texels, Texture, lookup, lookup_filtered, register};

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

/// Sets the bytes of texels resident at once (`--texture-memory`); `None`: half of
/// [`input::memory_budget`] (which `--max-memory` sets, else half of what the process may use).
pub fn set_memory_budget(bytes: Option<u64>) {
    strata_rt::texture::set_memory_budget(bytes.unwrap_or_else(|| input::memory_budget() / 2).max(1));
}

/// What a texture file's header says, read without decoding a pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextureHeader {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Channels kept (1..=4).
    pub channels: usize,
    /// Bytes per channel as kept: 1 (8-bit), 2 (16-bit or half), 4 (float).
    pub bytes_per_channel: usize,
    /// Whether the colour channels are sRGB-decoded at lookup.
    pub srgb: bool,
}

impl TextureHeader {
    /// Bytes of the finest level and every mip level below it (a third more).
    pub fn resident_bytes(&self) -> u64 {
        let finest = u64::from(self.width) * u64::from(self.height) * (self.channels * self.bytes_per_channel) as u64;
        finest.saturating_add(finest / 3)
    }
}

/// Whether `space` sRGB-decodes an image of this kind (UsdUVTexture's `sourceColorSpace`).
fn decodes_srgb(space: ColorSpace, float: bool, eight_bit: bool, has_color: bool) -> bool {
    match space {
        ColorSpace::Raw => false,
        ColorSpace::Srgb => !float,
        ColorSpace::Auto => eight_bit && has_color,
    }
}

/// The EXR layer strata reads (the first with R, G and B, else the first) and whether its
/// colour channels are all half floats.
fn exr_layer(meta: &exr::meta::MetaData) -> Option<(&exr::meta::header::Header, bool)> {
    let has = |h: &exr::meta::header::Header, name: &str| h.channels.list.iter().any(|c| c.name.eq(name));
    let header = meta.headers.iter().find(|h| ["R", "G", "B"].iter().all(|c| has(h, c))).or(meta.headers.first())?;
    let half = ["R", "G", "B"].iter().all(|name| {
        header.channels.list.iter().any(|c| c.name.eq(name) && c.sample_type == exr::meta::attribute::SampleType::F16)
    });
    Some((header, half))
}

/// Reads and checks a texture's header: its size against `max_pixels`, its format, its
/// channels, and the memory its texels and mip levels will take against the memory budget
/// (`--max-memory`). Nothing is decoded.
pub fn read_header(
    bytes: &[u8],
    name: Option<&Path>,
    space: ColorSpace,
    max_pixels: u64,
) -> Result<TextureHeader, String> {
    use image::ImageDecoder;
    let header = if is_exr(bytes) {
        check_exr_header(bytes, max_pixels)?;
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(|e| e.to_string())?;
        let (layer, half) = exr_layer(&meta).ok_or("the image has no layers")?;
        let size = layer.layer_size;
        let (width, height) = (u32::try_from(size.width()), u32::try_from(size.height()));
        let (Ok(width), Ok(height)) = (width, height) else { return Err("the image is too large".into()) };
        TextureHeader { width, height, channels: 3, bytes_per_channel: if half { 2 } else { 4 }, srgb: false }
    } else {
        let decoder = image_reader(bytes, name)?.into_decoder().map_err(|e| e.to_string())?;
        let (width, height) = decoder.dimensions();
        let pixels = u64::from(width) * u64::from(height);
        if pixels > max_pixels {
            return Err(format!(
                "the image is {width} x {height} = {pixels} pixels, more than the texture limit of {max_pixels} pixels \
                 (raise it with --max-texture-pixels)"
            ));
        }
        let color = decoder.color_type();
        let float = matches!(color, image::ColorType::Rgb32F | image::ColorType::Rgba32F);
        let channels = usize::from(color.channel_count());
        let bytes_per_channel = usize::from(color.bytes_per_pixel()) / channels.max(1);
        let eight_bit = bytes_per_channel == 1;
        let srgb = decodes_srgb(space, float, eight_bit, color.has_color());
        TextureHeader { width, height, channels, bytes_per_channel, srgb }
    };
    if header.width == 0 || header.height == 0 {
        return Err("the image is empty".into());
    }
    if !(1..=4).contains(&header.channels) {
        return Err(format!("the image has {} channels (textures have 1 to 4)", header.channels));
    }
    input::check_memory(&format!("decoding the {} x {} image", header.width, header.height), header.resident_bytes())?;
    Ok(header)
}

/// Decodes a texture at its source precision: 8-bit and 16-bit integers, half or float, one to
/// four channels as the file has them (EXR: its RGB channels), never through a full-size float
/// copy. Non-finite float texels become 0.
pub fn decode_image(bytes: &[u8], name: Option<&Path>, space: ColorSpace, max_pixels: u64) -> Result<Image, String> {
    use exr::prelude::{ReadChannels, ReadLayers, f16};
    let header = read_header(bytes, name, space, max_pixels)?;
    let (width, height) = (header.width as usize, header.height as usize);
    if is_exr(bytes) {
        let texels = if header.bytes_per_channel == 2 {
            type Half = (usize, Vec<u16>);
            let image = exr::prelude::read()
                .no_deep_data()
                .largest_resolution_level()
                .rgba_channels(
                    |size, _| (size.width(), vec![0u16; size.area() * 3]),
                    |(w, px): &mut Half, pos, (r, g, b, _a): (f16, f16, f16, f16)| {
                        let i = (pos.y() * *w + pos.x()) * 3;
                        px[i..i + 3].copy_from_slice(&[r.to_bits(), g.to_bits(), b.to_bits()]);
                    },
                )
                .first_valid_layer()
                .all_attributes()
                .from_buffered(Cursor::new(bytes))
                .map_err(|e| e.to_string())?;
            Texels::F16(image.layer_data.channel_data.pixels.1)
        } else {
            let (_, _, rgb) = decode_rgb_exr(bytes, max_pixels)?;
            Texels::F32(rgb.into_iter().flatten().map(|c| if c.is_finite() { c } else { 0.0 }).collect())
        };
        return Ok(Image { width, height, channels: 3, srgb: false, texels });
    }
    let mut reader = image_reader(bytes, name)?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(input::memory_budget().saturating_sub(header.resident_bytes()).max(1 << 20));
    reader.limits(limits);
    use image::DynamicImage as D;
    let decoded = reader.decode().map_err(|e| e.to_string())?;
    let (channels, texels) = match decoded {
        D::ImageLuma8(b) => (1, Texels::U8(b.into_raw())),
        D::ImageLumaA8(b) => (2, Texels::U8(b.into_raw())),
        D::ImageRgb8(b) => (3, Texels::U8(b.into_raw())),
        D::ImageRgba8(b) => (4, Texels::U8(b.into_raw())),
        D::ImageLuma16(b) => (1, Texels::U16(b.into_raw())),
        D::ImageLumaA16(b) => (2, Texels::U16(b.into_raw())),
        D::ImageRgb16(b) => (3, Texels::U16(b.into_raw())),
        D::ImageRgba16(b) => (4, Texels::U16(b.into_raw())),
        D::ImageRgb32F(b) => (3, Texels::F32(b.into_raw())),
        other => (4, Texels::F32(other.into_rgba32f().into_raw())),
    };
    let texels = match texels {
        Texels::F32(mut v) => {
            v.iter_mut().filter(|c| !c.is_finite()).for_each(|c| *c = 0.0);
            Texels::F32(v)
        }
        other => other,
    };
    let srgb = header.srgb && !matches!(texels, Texels::F32(_));
    let image = Image { width, height, channels, srgb, texels };
    Ok(image)
}

/// Rows a PNG hands over at a time: 1 MiB of a 16384-wide RGBA 8-bit image.
const PNG_ROWS: usize = 16;

/// [`decode_image`]'s texels handed to `rows` a run of rows at a time, top to bottom, until it
/// returns false. A non-interlaced PNG is decoded row by row (the `png` crate's row reader,
/// with the `image` crate's transformations: the same texels), so a texture larger than the
/// memory budget is never whole in memory; other formats (and interlaced PNGs) are decoded
/// whole and handed over at once.
pub fn decode_image_rows(
    bytes: &[u8],
    name: Option<&Path>,
    space: ColorSpace,
    max_pixels: u64,
    rows: &mut dyn FnMut(Image) -> bool,
) -> Result<(), String> {
    let header = read_header(bytes, name, space, max_pixels)?;
    let reader = bytes.starts_with(b"\x89PNG\r\n\x1a\n").then(|| png_row_reader(bytes, &header)).flatten();
    let Some(mut reader) = reader else {
        rows(decode_image(bytes, name, space, max_pixels)?);
        return Ok(());
    };
    let (width, height, channels) = (header.width as usize, header.height as usize, header.channels);
    let values = PNG_ROWS * width * channels;
    let empty = || {
        let texels = if header.bytes_per_channel == 2 {
            Texels::U16(Vec::with_capacity(values))
        } else {
            Texels::U8(Vec::with_capacity(values))
        };
        Image { width, height: 0, channels, srgb: header.srgb, texels }
    };
    let mut run = empty();
    let mut decoded = 0;
    while let Some(row) = reader.next_row().map_err(|e| e.to_string())? {
        match &mut run.texels {
            Texels::U16(v) => v.extend(row.data().chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]]))),
            Texels::U8(v) => v.extend_from_slice(row.data()),
            _ => unreachable!("PNG texels are 8 or 16 bit"),
        }
        (run.height, decoded) = (run.height + 1, decoded + 1);
        if (run.height == PNG_ROWS || decoded == height) && !rows(std::mem::replace(&mut run, empty())) {
            return Ok(());
        }
    }
    if decoded != height {
        return Err(format!("the image data ends after {decoded} of {height} rows"));
    }
    Ok(())
}

/// A row reader for a non-interlaced PNG whose expanded rows have the channels and depth
/// `header` promises (as the `image` crate decodes it: palettes, low bit depths and
/// transparency chunks expanded); `None` for any other (decoded whole instead).
fn png_row_reader<'a>(bytes: &'a [u8], header: &TextureHeader) -> Option<png::Reader<Cursor<&'a [u8]>>> {
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND);
    let reader = decoder.read_info().ok()?;
    let (color, depth) = reader.output_color_type();
    let bytes_per_channel = match depth {
        png::BitDepth::Eight => 1,
        png::BitDepth::Sixteen => 2,
        _ => return None,
    };
    let info = reader.info();
    let same = (info.width, info.height) == (header.width, header.height)
        && color.samples() == header.channels
        && bytes_per_channel == header.bytes_per_channel;
    (same && !info.interlaced).then_some(reader)
}

/// A texture file decoded when a lookup first reaches it (and again after eviction).
struct FileSource {
    /// The file as read (canonical, package paths included).
    canonical: std::path::PathBuf,
    /// The name it was given (its extension tells formats without a signature).
    name: std::path::PathBuf,
    space: ColorSpace,
    max_pixels: u64,
    /// What its header says its texels and mip levels take.
    resident_bytes: u64,
}

impl strata_rt::texture::TexelSource for FileSource {
    fn decode(&self) -> Result<Image, String> {
        let bytes = input::read_bytes(&self.canonical).map_err(|e| e.to_string())?;
        decode_image(&bytes, Some(&self.name), self.space, self.max_pixels)
    }

    fn decode_rows(&self, rows: &mut dyn FnMut(Image) -> bool) -> Result<(), String> {
        let bytes = input::read_bytes(&self.canonical).map_err(|e| e.to_string())?;
        decode_image_rows(&bytes, Some(&self.name), self.space, self.max_pixels, rows)
    }

    fn resident_bytes(&self) -> Option<u64> {
        Some(self.resident_bytes)
    }
}

/// Bytes read for a texture's header: PNG, JPEG and EXR headers end well inside them; a
/// header that does not (a TIFF whose directory follows its pixels, a JPEG behind a large
/// EXIF block) is read again from the whole file.
const HEADER_PREFIX: u64 = 256 << 10;

/// Reads `path`'s header (checked against [`input::limits`]) and a source that decodes it.
/// Only the file's first [`HEADER_PREFIX`] bytes are read when the header is within them:
/// registering 40 textures of 2K read 276 MB for their headers.
fn open_file(path: &Path, canonical: &Path, space: ColorSpace) -> Result<(TextureHeader, FileSource), String> {
    let max_pixels = input::limits().max_texture_pixels;
    let header = input::read_prefix(canonical, HEADER_PREFIX)
        .map_err(|e| e.to_string())
        .and_then(|(prefix, whole)| match read_header(&prefix, Some(path), space, max_pixels) {
            Err(_) if !whole => input::read_bytes(canonical)
                .map_err(|e| e.to_string())
                .and_then(|bytes| read_header(&bytes, Some(path), space, max_pixels)),
            header => header,
        })
        .map_err(|e| format!("cannot read texture `{}`: {e}", path.display()))?;
    let resident_bytes = header.resident_bytes();
    let source =
        FileSource { canonical: canonical.to_path_buf(), name: path.to_path_buf(), space, max_pixels, resident_bytes };
    Ok((header, source))
}

/// Registers `path` (once per process and colour space) and returns its id. Only its header
/// is read now (through [`input::read_bytes`]: size limit, package paths; checked against
/// [`input::limits`]); its pixels are decoded when a lookup first reaches them.
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
    let (header, source) = open_file(path, &canonical, space)?;
    strata_rt::texture::register_source(key, header.width as usize, header.height as usize, Box::new(source))
}

/// Textures decoded ahead of their first lookup on a thread of their own, while the caller
/// does something else (builds the render scene): every texture registered so far, in
/// registration order, each only when it fits in the room the texture budget has free
/// ([`strata_rt::texture::prefetch`]). Dropping it stops the thread after the texture it is
/// decoding; what it has not reached is decoded on first touch, as without it.
pub struct Prefetch {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl Prefetch {
    /// Starts decoding ahead (nothing when no texture is registered).
    pub fn start() -> Prefetch {
        use std::sync::atomic::{AtomicBool, Ordering};
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let count = strata_rt::texture::count();
        if count > 0 {
            let stop = std::sync::Arc::clone(&stop);
            let spawned = std::thread::Builder::new().name("texture prefetch".into()).spawn(move || {
                for id in 0..count {
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                    strata_rt::texture::prefetch(id as i32);
                }
            });
            // No thread: every texture is decoded on first touch, as without prefetching.
            drop(spawned);
        }
        Prefetch { stop }
    }
}

impl Drop for Prefetch {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

/// Whether a texture was registered under a name starting with `prefix` (a canonical path
/// and `#`: loaded from that file in any colour space).
pub fn registered_from(prefix: &str) -> bool {
    strata_rt::texture::names().iter().any(|n| n.to_string_lossy().starts_with(prefix))
}

/// Points every registry entry loaded from `path` (one per colour space) at the file as it is
/// now (its header read again), so materials compiled against those ids see the new texels
/// without recompiling. Returns how many entries were replaced: 0 when no texture was loaded
/// from `path`.
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
        let (header, source) = open_file(path, &canonical, space)?;
        strata_rt::texture::replace_source(id as i32, header.width as usize, header.height as usize, Box::new(source))?;
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

    /// A 16-bit PNG in memory (big-endian samples, as PNG stores them).
    fn png16(width: u32, height: u32, color: png::ColorType, samples: &[u16]) -> Vec<u8> {
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(color);
        encoder.set_depth(png::BitDepth::Sixteen);
        let mut writer = encoder.write_header().expect("header");
        writer.write_image_data(&samples.iter().flat_map(|s| s.to_be_bytes()).collect::<Vec<_>>()).expect("data");
        writer.finish().expect("finish");
        bytes
    }

    #[test]
    fn textures_keep_their_source_precision_and_channels() {
        let rgb8 = small_png(2, 1, png::ColorType::Rgb, &[255, 128, 0, 1, 2, 3]);
        let image = decode_image(&rgb8, None, ColorSpace::Auto, 100).unwrap();
        assert_eq!((image.channels, image.srgb), (3, true));
        assert_eq!(image.texels, Texels::U8(vec![255, 128, 0, 1, 2, 3]));
        let grey =
            decode_image(&small_png(1, 1, png::ColorType::Grayscale, &[9]), None, ColorSpace::Auto, 100).unwrap();
        assert_eq!((grey.channels, grey.srgb, grey.texels), (1, false, Texels::U8(vec![9])), "grey is data");
        let deep =
            decode_image(&png16(1, 1, png::ColorType::Rgba, &[1, 2, 65535, 3]), None, ColorSpace::Raw, 100).unwrap();
        assert_eq!((deep.channels, deep.texels), (4, Texels::U16(vec![1, 2, 65535, 3])));
        // EXR half stays half (the writer's RGB channels are f32 here: float stays float).
        let exr = decode_image(&small_exr(3, 2), None, ColorSpace::Auto, 100).unwrap();
        assert_eq!((exr.channels, &exr.texels.bytes_per_value()), (3, &4));
    }

    #[test]
    fn half_exr_textures_stay_half() {
        let layer = exr::prelude::Layer::new(
            (2, 1),
            exr::prelude::LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            exr::prelude::SpecificChannels::rgb(|pos: exr::prelude::Vec2<usize>| {
                let v = exr::prelude::f16::from_f32(pos.x() as f32 + 0.5);
                (v, v, exr::prelude::f16::from_f32(f32::NAN))
            }),
        );
        let mut bytes = Cursor::new(Vec::new());
        exr::prelude::Image::from_layer(layer).write().to_buffered(&mut bytes).unwrap();
        let bytes = bytes.into_inner();
        let header = read_header(&bytes, None, ColorSpace::Auto, 100).unwrap();
        assert_eq!((header.channels, header.bytes_per_channel), (3, 2));
        let image = decode_image(&bytes, None, ColorSpace::Auto, 100).unwrap();
        let Texels::F16(v) = &image.texels else { panic!("{:?}", image.texels) };
        assert_eq!((v[3], v[4]), (0x3e00, 0x3e00), "1.5 in binary16");
        let id = strata_rt::texture::register_image("test:half-exr".into(), image).unwrap();
        assert_eq!(lookup(id, 0.75, 0.5, 0), 1.5);
        assert_eq!(lookup(id, 0.75, 0.5, 2), 0.0, "NaN reads 0");
    }

    /// A PNG of `color` at `depth` bits whose samples are `sample(index)` (big-endian at 16).
    fn png_of(w: u32, h: u32, color: png::ColorType, depth: png::BitDepth, sample: impl Fn(usize) -> u16) -> Vec<u8> {
        let n = w as usize * h as usize * color.samples();
        let data: Vec<u8> = match depth {
            png::BitDepth::Sixteen => (0..n).flat_map(|i| sample(i).to_be_bytes()).collect(),
            _ => (0..n).map(|i| sample(i) as u8).collect(),
        };
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, w, h);
        encoder.set_color(color);
        encoder.set_depth(depth);
        let mut writer = encoder.write_header().expect("header");
        writer.write_image_data(&data).expect("data");
        writer.finish().expect("finish");
        bytes
    }

    #[test]
    fn png_rows_and_their_cascade_give_the_texels_and_levels_of_the_whole_image_path() {
        use png::{BitDepth, ColorType};
        let colors = [ColorType::Grayscale, ColorType::GrayscaleAlpha, ColorType::Rgb, ColorType::Rgba];
        let mut checked = 0;
        for (w, h) in [(37, 21), (1, 40), (40, 1), (17, 16), (64, 33)] {
            for color in colors {
                for depth in [BitDepth::Eight, BitDepth::Sixteen] {
                    let bytes = png_of(w, h, color, depth, |i| (i as u16).wrapping_mul(40_503) ^ 0x5a5a);
                    for space in [ColorSpace::Auto, ColorSpace::Srgb, ColorSpace::Raw] {
                        let whole = decode_image(&bytes, None, space, 1 << 20).unwrap();
                        let mut chain = vec![whole.clone()];
                        while chain.len() < strata_rt::texture::level_count(whole.width, whole.height) {
                            let next = chain[chain.len() - 1].downsample();
                            chain.push(next);
                        }
                        let mut levels: Vec<Option<Image>> = vec![None; chain.len()];
                        let mut cascade = strata_rt::texture::MipCascade::new(whole.width, whole.height);
                        let (mut seen, mut runs) = (0, 0);
                        decode_image_rows(&bytes, None, space, 1 << 20, &mut |rows| {
                            cascade.push(seen, &rows, &mut |level, _, rows| match &mut levels[level] {
                                Some(made) => assert!(made.append_rows(rows)),
                                slot => *slot = Some(rows.clone()),
                            });
                            (seen, runs) = (seen + rows.height, runs + 1);
                            true
                        })
                        .unwrap();
                        assert_eq!(runs, (h as usize).div_ceil(PNG_ROWS), "read by runs of rows");
                        let levels: Vec<Image> = levels.into_iter().map(Option::unwrap).collect();
                        assert_eq!(levels, chain, "{w}x{h} {color:?} {depth:?} {space:?}");
                        checked += 1;
                    }
                }
            }
        }
        assert_eq!(checked, 5 * 4 * 2 * 3);
        // A palette image expands to RGB as the whole-image path decodes it; reading stops
        // when asked.
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, 3, 40);
        encoder.set_color(ColorType::Indexed);
        encoder.set_palette(vec![255, 0, 0, 0, 128, 255]);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&(0..120).map(|i| (i % 2) as u8).collect::<Vec<_>>()).unwrap();
        writer.finish().unwrap();
        let whole = decode_image(&bytes, None, ColorSpace::Auto, 1 << 20).unwrap();
        let mut first = None;
        decode_image_rows(&bytes, None, ColorSpace::Auto, 1 << 20, &mut |rows| {
            first = Some(rows);
            false
        })
        .unwrap();
        assert_eq!(first, Some(whole.rows(0..PNG_ROWS)));
    }

    #[test]
    fn headers_are_read_without_decoding_pixels() {
        // A PNG cut inside its pixel data: the header reads, the pixels do not.
        let png = small_png(64, 32, png::ColorType::Rgba, &[200; 64 * 32 * 4]);
        let cut = &png[..png.len() - 20];
        let header = read_header(cut, None, ColorSpace::Auto, 1 << 20).unwrap();
        assert_eq!(header, TextureHeader { width: 64, height: 32, channels: 4, bytes_per_channel: 1, srgb: true });
        assert!(decode_image(cut, None, ColorSpace::Auto, 1 << 20).is_err());
        // Registering reads the header only: the cut file registers, and its lookups read 0.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cut.png");
        std::fs::write(&path, cut).unwrap();
        let id = register_file(&path).expect("the header is valid");
        assert_eq!(lookup(id, 0.5, 0.5, 0), 0.0);
        // A whole file reads its texels once reached, and reloads under the same id.
        std::fs::write(&path, &png).unwrap();
        assert_eq!(reload_file(&path), Ok(1));
        assert!((lookup(id, 0.5, 0.5, 3) - 200.0 / 255.0).abs() < 1e-6);
    }
}
