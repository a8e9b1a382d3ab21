//! The page's images: one displayable channel group of an [`Image`] as an 8-bit PNG.
//!
//! Groups are the EXR channel names before the last dot (`albedo` for `albedo.R/G/B`); the
//! beauty (`R G B`) goes through the PNG preview's display transform, normals map `[-1, 1]`
//! to `[0, 1]`, other colours are clamped and sRGB-encoded, and single channels (Z, custom
//! scalars) are stretched from their smallest to their largest finite value.

use crate::render::film::output::tone_map;
use crate::render::{ChannelData, Image};

/// The beauty's group name.
pub const BEAUTY: &str = "beauty";

/// The displayable groups of `image`: the beauty, then each other float group in channel
/// order (Cryptomatte's ID channels are not images to look at).
pub fn groups(image: &Image) -> Vec<String> {
    let mut groups = vec![BEAUTY.to_string()];
    for channel in &image.channels {
        if !matches!(channel.data, ChannelData::F32(_)) || channel.name.starts_with("Crypto") {
            continue;
        }
        let group = group_of(&channel.name);
        if !matches!(group, "R" | "G" | "B" | "A") && !groups.iter().any(|g| g == group) {
            groups.push(group.to_string());
        }
    }
    groups
}

/// The prefix of a channel-selector entry that shows the Cryptomatte matte of the selected
/// prim (`matte:CryptoObject`) or of its material (`matte:CryptoMaterial`).
pub const MATTE: &str = "matte:";

/// The coverage of the ID of `name` in Cryptomatte layer `layer` of `image` (the sum of
/// its ranks' coverage per pixel), as grey PNG bytes; `None` when the image has no such layer.
pub fn matte(image: &Image, layer: &str, name: &str) -> Option<Vec<u8>> {
    let id = crate::render::film::cryptomatte::id_bits(name);
    let names = crate::render::film::cryptomatte::channel_names(layer);
    let planes: Vec<&[f32]> = names.iter().map(|n| image.f32_channel(n)).collect::<Option<_>>()?;
    let n = image.width * image.height;
    let mut pixels = Vec::with_capacity(n * 3);
    for i in 0..n {
        // Ranks are (ID, coverage) pairs: R/G and B/A of each group of four channels.
        let coverage: f32 = planes.chunks(2).filter(|pair| pair[0][i].to_bits() == id).map(|pair| pair[1][i]).sum();
        let byte = linear_to_byte(coverage);
        pixels.extend([byte, byte, byte]);
    }
    encode_rgb(image.width, image.height, &pixels)
}

/// The prefix of a channel-selector entry that shows a layer's coverage matte of the selected
/// prim (`coverage:INDEX:SLOT`, computed by the render thread).
pub const COVERAGE: &str = "coverage:";

/// Values in [0, 1] (a coverage matte) as grey PNG bytes.
pub fn grey(width: usize, height: usize, values: &[f32]) -> Option<Vec<u8>> {
    let pixels: Vec<u8> = values.iter().flat_map(|&v| [linear_to_byte(v); 3]).collect();
    encode_rgb(width, height, &pixels)
}

fn group_of(name: &str) -> &str {
    name.rsplit_once('.').map_or(name, |(group, _)| group)
}

/// `image`'s group `group` as PNG bytes (`None`: no such group).
pub fn png(image: &Image, group: &str) -> Option<Vec<u8>> {
    let planes: Vec<&[f32]> = if group == BEAUTY {
        ["R", "G", "B"].iter().map(|n| image.f32_channel(n)).collect::<Option<_>>()?
    } else {
        image
            .channels
            .iter()
            .filter(|c| group_of(&c.name) == group)
            .filter_map(|c| image.f32_channel(&c.name))
            .take(3)
            .collect()
    };
    if planes.is_empty() {
        return None;
    }
    let n = image.width * image.height;
    let (low, high) = if planes.len() == 1 { finite_range(planes[0]) } else { (0.0, 1.0) };
    let to_byte = |v: f32| -> u8 {
        if group == BEAUTY {
            tone_map(v, 0.0)
        } else if group == "N" {
            linear_to_byte(v * 0.5 + 0.5)
        } else if planes.len() == 1 {
            linear_to_byte(if high > low { (v - low) / (high - low) } else { 0.0 })
        } else {
            srgb_byte(v)
        }
    };
    // One plane is grey: it stands for all three.
    let plane = |k: usize| planes[k.min(planes.len() - 1)];
    let mut pixels = Vec::with_capacity(n * 3);
    for ((&r, &g), &b) in plane(0).iter().zip(plane(1)).zip(plane(2)).take(n) {
        pixels.extend([to_byte(r), to_byte(g), to_byte(b)]);
    }
    encode_rgb(image.width, image.height, &pixels)
}

fn encode_rgb(width: usize, height: usize, pixels: &[u8]) -> Option<Vec<u8>> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width as u32, height as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    // Fast settings: a frame is shown once, on the same machine.
    encoder.set_compression(png::Compression::Fast);
    let mut writer = encoder.write_header().ok()?;
    writer.write_image_data(pixels).ok()?;
    writer.finish().ok()?;
    Some(bytes)
}

fn finite_range(values: &[f32]) -> (f32, f32) {
    values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)))
}

fn linear_to_byte(v: f32) -> u8 {
    if v.is_finite() { (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8 } else { 0 }
}

fn srgb_byte(v: f32) -> u8 {
    let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
    let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}
