//! Texel storage at the source's precision ([`Texels`], [`Image`]): sRGB and half-float
//! conversions, and the box-filtered mip chain built from it. The registry, residency and
//! lookups in the parent module read levels through these types.

use super::{Texture, wrap_index};
use std::ops::Range;
use std::sync::LazyLock;

/// Texels at the precision of their source, row-major, top row first, channels interleaved.
#[derive(Clone, Debug, PartialEq)]
pub enum Texels {
    /// 8-bit, normalised by 255 (sRGB-encoded colour channels when [`Image::srgb`]).
    U8(Vec<u8>),
    /// 16-bit, normalised by 65535 (sRGB-encoded colour channels when [`Image::srgb`]).
    U16(Vec<u16>),
    /// IEEE half floats, as their bits.
    F16(Vec<u16>),
    /// Floats.
    F32(Vec<f32>),
}

impl Texels {
    /// Bytes per stored value.
    pub fn bytes_per_value(&self) -> usize {
        match self {
            Texels::U8(_) => 1,
            Texels::U16(_) | Texels::F16(_) => 2,
            Texels::F32(_) => 4,
        }
    }

    fn len(&self) -> usize {
        match self {
            Texels::U8(v) => v.len(),
            Texels::U16(v) | Texels::F16(v) => v.len(),
            Texels::F32(v) => v.len(),
        }
    }

    /// A copy of values `range`.
    fn copy_range(&self, range: Range<usize>) -> Texels {
        match self {
            Texels::U8(v) => Texels::U8(v[range].to_vec()),
            Texels::U16(v) => Texels::U16(v[range].to_vec()),
            Texels::F16(v) => Texels::F16(v[range].to_vec()),
            Texels::F32(v) => Texels::F32(v[range].to_vec()),
        }
    }

    /// Room for `more` values without reallocating.
    fn reserve_exact(&mut self, more: usize) {
        match self {
            Texels::U8(v) => v.reserve_exact(more),
            Texels::U16(v) | Texels::F16(v) => v.reserve_exact(more),
            Texels::F32(v) => v.reserve_exact(more),
        }
    }

    /// Appends `other`'s values; false (and nothing appended) when its precision differs.
    fn extend_from(&mut self, other: &Texels) -> bool {
        match (self, other) {
            (Texels::U8(a), Texels::U8(b)) => a.extend_from_slice(b),
            (Texels::U16(a), Texels::U16(b)) | (Texels::F16(a), Texels::F16(b)) => a.extend_from_slice(b),
            (Texels::F32(a), Texels::F32(b)) => a.extend_from_slice(b),
            _ => return false,
        }
        true
    }
}

/// One image (a mip level) at its source precision.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in texels (≥ 1).
    pub width: usize,
    /// Height in texels (≥ 1).
    pub height: usize,
    /// Channels per texel, 1..=4: grey, grey + alpha, RGB, RGBA.
    pub channels: usize,
    /// Whether the colour channels (every channel but alpha) of integer texels are
    /// sRGB-encoded, decoded to linear at lookup.
    pub srgb: bool,
    /// `width * height * channels` values.
    pub texels: Texels,
}

/// sRGB-encoded 8-bit values to linear (IEC 61966-2-1), the table 8-bit lookups read.
static SRGB_U8: LazyLock<[f32; 256]> = LazyLock::new(|| std::array::from_fn(|i| srgb_decode(i as f32 / 255.0)));

/// The sRGB transfer function inverted: an encoded value in [0, 1] to linear.
fn srgb_decode(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// The sRGB transfer function: linear in [0, 1] to encoded.
fn srgb_encode(l: f32) -> f32 {
    if l <= 0.003_130_8 { l * 12.92 } else { 1.055 * l.powf(1.0 / 2.4) - 0.055 }
}

/// A half float's bits to f32; infinities and NaNs read 0 (texels must be finite).
pub fn f16_to_f32(bits: u16) -> f32 {
    let sign = if bits & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exponent = i32::from((bits >> 10) & 0x1f);
    let mantissa = f32::from(bits & 0x3ff);
    match exponent {
        0 => sign * mantissa * (-24f32).exp2(),
        31 => 0.0,
        e => sign * (1.0 + mantissa / 1024.0) * ((e - 15) as f32).exp2(),
    }
}

/// An f32 to half-float bits, rounded to nearest; beyond the half range it saturates to the
/// largest finite half, non-finite values become 0.
pub fn f32_to_f16(value: f32) -> u16 {
    if !value.is_finite() {
        return 0;
    }
    let sign = if value.is_sign_negative() { 0x8000u16 } else { 0 };
    let a = value.abs().min(65504.0);
    if a < (-14f32).exp2() {
        // Subnormal (or zero): units of 2^-24.
        return sign | (a * 24f32.exp2()).round() as u16;
    }
    let exponent = a.log2().floor() as i32;
    let exponent = if (exponent as f32).exp2() > a { exponent - 1 } else { exponent };
    let mantissa = (a / (exponent as f32).exp2() - 1.0) * 1024.0;
    let (mut e, mut m) = (exponent + 15, mantissa.round() as u32);
    if m == 1024 {
        (e, m) = (e + 1, 0);
    }
    if e >= 31 {
        return sign | 0x7bff;
    }
    sign | ((e as u16) << 10) | m as u16
}

impl Image {
    /// An image of `width × height` RGBA float texels (`Texture`'s layout).
    pub fn from_texture(texture: &Texture) -> Image {
        let texels = texture.texels.iter().flat_map(|t| t.map(|c| if c.is_finite() { c } else { 0.0 })).collect();
        Image { width: texture.width, height: texture.height, channels: 4, srgb: false, texels: Texels::F32(texels) }
    }

    /// Bytes its texels take.
    pub fn bytes(&self) -> u64 {
        (self.texels.len() * self.texels.bytes_per_value()) as u64
    }

    /// Whether the sizes agree with the texels (a [`TexelSource`] is trusted with no more).
    pub(super) fn is_consistent(&self) -> bool {
        self.width >= 1
            && self.height >= 1
            && (1..=4).contains(&self.channels)
            && self.width.checked_mul(self.height).and_then(|n| n.checked_mul(self.channels)) == Some(self.texels.len())
    }

    /// Rows `rows` of this image as an image of their own (a band of a level).
    pub fn rows(&self, rows: Range<usize>) -> Image {
        let row = self.width * self.channels;
        let texels = self.texels.copy_range(rows.start * row..rows.end * row);
        Image { width: self.width, height: rows.len(), channels: self.channels, srgb: self.srgb, texels }
    }

    /// Room for `rows` more rows without reallocating.
    pub fn reserve_rows(&mut self, rows: usize) {
        self.texels.reserve_exact(rows * self.width * self.channels);
    }

    /// Appends `below`'s rows under this image's; false (nothing appended) when their
    /// width, channels, colour space or precision differ.
    pub fn append_rows(&mut self, below: &Image) -> bool {
        let alike = (self.width, self.channels, self.srgb) == (below.width, below.channels, below.srgb);
        if !alike || !self.texels.extend_from(&below.texels) {
            return false;
        }
        self.height += below.height;
        true
    }

    /// Where logical channel `channel` (0..=3: r, g, b, a) is stored, or `None` when the image
    /// has no alpha (it reads 1). Grey images give their one value to r, g and b.
    #[inline]
    fn stored_channel(&self, channel: usize) -> Option<usize> {
        match (self.channels, channel) {
            (1 | 2, 0..=2) => Some(0),
            (2, _) => Some(1),
            (3, 3) | (1, _) => None,
            (_, c) => Some(c),
        }
    }

    /// Whether stored channel `stored` is a colour channel (sRGB applies) rather than alpha.
    #[inline]
    fn is_colour(&self, stored: usize) -> bool {
        !matches!((self.channels, stored), (2, 1) | (4, 3))
    }

    /// Stored value `index` (of channel `stored`) as a linear float.
    #[inline]
    fn value(&self, index: usize, stored: usize) -> f32 {
        let srgb = self.srgb && self.is_colour(stored);
        match &self.texels {
            Texels::U8(v) => {
                if srgb {
                    SRGB_U8[v[index] as usize]
                } else {
                    f32::from(v[index]) * (1.0 / 255.0)
                }
            }
            Texels::U16(v) => {
                let x = f32::from(v[index]) * (1.0 / 65535.0);
                if srgb { srgb_decode(x) } else { x }
            }
            Texels::F16(v) => f16_to_f32(v[index]),
            Texels::F32(v) => v[index],
        }
    }

    /// Nearest-texel lookup at texel coordinates (x, y) (texel centres at half integers).
    #[inline]
    pub(super) fn nearest(&self, x: f32, y: f32, channel: usize, wrap_s: i32, wrap_t: i32) -> f32 {
        match wrap_index(y.floor() as i64, self.height, wrap_t) {
            Some(row) => self.texel(row, x.floor() as i64, channel, wrap_s),
            None => 0.0,
        }
    }

    /// Channel `channel` of the texel at integer column `xi` (wrapped by `wrap_s`) of row
    /// `row`: 0 where the wrap mode makes it black, 1 for alpha the image lacks.
    #[inline]
    pub(super) fn texel(&self, row: usize, xi: i64, channel: usize, wrap_s: i32) -> f32 {
        match (wrap_index(xi, self.width, wrap_s), self.stored_channel(channel)) {
            (Some(x), Some(k)) => self.value((row * self.width + x) * self.channels + k, k),
            (Some(_), None) => 1.0,
            (None, _) => 0.0,
        }
    }

    /// Row `row` (none: a black row) interpolated between columns `x0` and `x0 + 1` at
    /// fraction `fx`: one half of [`Image::bilinear`], which a level read by bands of rows
    /// does row by row.
    #[inline]
    pub(super) fn row_lerp(&self, row: Option<usize>, x0: i64, fx: f32, channel: usize, wrap_s: i32) -> f32 {
        let Some(row) = row else { return 0.0 };
        let (a, b) = (self.texel(row, x0, channel, wrap_s), self.texel(row, x0 + 1, channel, wrap_s));
        a + (b - a) * fx
    }

    /// Bilinear lookup at texel coordinates (x, y) (texel centres at half integers).
    #[inline]
    pub(super) fn bilinear(&self, x: f32, y: f32, channel: usize, wrap_s: i32, wrap_t: i32) -> f32 {
        let ((x0, fx), (y0, fy)) = (bilinear_corner(x), bilinear_corner(y));
        let row = |yi: i64| self.row_lerp(wrap_index(yi, self.height, wrap_t), x0, fx, channel, wrap_s);
        let (top, bottom) = (row(y0), row(y0 + 1));
        top + (bottom - top) * fy
    }

    /// The next coarser mip level: each texel the mean of (up to) 2×2 texels, averaged in
    /// linear (sRGB decoded, then encoded again), stored at this image's precision (written
    /// texel by texel: no float copy of the level).
    pub fn downsample(&self) -> Image {
        match &self.texels {
            Texels::U8(source) => self.downsample_u8(source),
            _ => self.downsample_texel_by_texel(),
        }
    }

    /// [`Image::downsample`] at any precision, each texel read through [`Image::value`].
    fn downsample_texel_by_texel(&self) -> Image {
        let (w, h) = ((self.width / 2).max(1), (self.height / 2).max(1));
        let c = self.channels;
        let n = w * h * c;
        let mut texels = match &self.texels {
            Texels::U8(_) => Texels::U8(Vec::with_capacity(n)),
            Texels::U16(_) => Texels::U16(Vec::with_capacity(n)),
            Texels::F16(_) => Texels::F16(Vec::with_capacity(n)),
            Texels::F32(_) => Texels::F32(Vec::with_capacity(n)),
        };
        for y in 0..h {
            let rows = [(2 * y).min(self.height - 1), (2 * y + 1).min(self.height - 1)];
            for x in 0..w {
                let cols = [(2 * x).min(self.width - 1), (2 * x + 1).min(self.width - 1)];
                for k in 0..c {
                    let mut sum = 0.0;
                    for &yy in &rows {
                        for &xx in &cols {
                            sum += self.value((yy * self.width + xx) * c + k, k);
                        }
                    }
                    let v = 0.25 * sum;
                    let srgb = self.srgb && self.is_colour(k);
                    match &mut texels {
                        Texels::U8(out) if srgb => out.push(nearest_srgb_u8(v)),
                        Texels::U8(out) => out.push((v.clamp(0.0, 1.0) * 255.0).round() as u8),
                        Texels::U16(out) => {
                            let v = v.clamp(0.0, 1.0);
                            out.push((if srgb { srgb_encode(v) } else { v } * 65535.0).round() as u16)
                        }
                        Texels::F16(out) => out.push(f32_to_f16(v)),
                        Texels::F32(out) => out.push(v),
                    }
                }
            }
        }
        Image { width: w, height: h, channels: c, srgb: self.srgb, texels }
    }

    /// [`Image::downsample`] of 8-bit texels, bit for bit: the same sums of the same linear
    /// values in the same order, read through one table per channel instead of
    /// [`Image::value`]'s per-texel dispatch (mip chains of 8-bit textures were most of a
    /// textured scene's preparation), with the channel count a constant so the per-texel loop
    /// unrolls and indexes without bounds checks.
    fn downsample_u8(&self, source: &[u8]) -> Image {
        match self.channels {
            1 => self.downsample_u8_with::<1>(source),
            2 => self.downsample_u8_with::<2>(source),
            3 => self.downsample_u8_with::<3>(source),
            _ => self.downsample_u8_with::<4>(source),
        }
    }

    /// [`Image::downsample_u8`] for `C` channels.
    fn downsample_u8_with<const C: usize>(&self, source: &[u8]) -> Image {
        let (w, h) = ((self.width / 2).max(1), (self.height / 2).max(1));
        let raw: [f32; 256] = std::array::from_fn(|i| f32::from(i as u8) * (1.0 / 255.0));
        let srgb_of: [bool; C] = std::array::from_fn(|k| self.srgb && self.is_colour(k));
        let tables: [&[f32; 256]; C] = srgb_of.map(|srgb| if srgb { &*SRGB_U8 } else { &raw });
        let row = self.width * C;
        let buckets = &*SRGB_U8_OF_BUCKET;
        // A width of 1 repeats its one column (the 2x2 block's right half is the left).
        let right = if self.width == 1 { 0 } else { C };
        let mut out = vec![0u8; w * h * C];
        for (y, out_row) in out.chunks_exact_mut(w * C).enumerate() {
            let top = &source[(2 * y).min(self.height - 1) * row..][..row];
            let bottom = &source[(2 * y + 1).min(self.height - 1) * row..][..row];
            for (x, texel) in out_row.chunks_exact_mut(C).enumerate() {
                let (a, b) = (&top[2 * x * C..][..right + C], &bottom[2 * x * C..][..right + C]);
                for k in 0..C {
                    let table = tables[k];
                    // The order of `downsample_texel_by_texel`: top left, top right, bottom
                    // left, bottom right.
                    let sum = table[usize::from(a[k])]
                        + table[usize::from(a[right + k])]
                        + table[usize::from(b[k])]
                        + table[usize::from(b[right + k])];
                    let v = 0.25 * sum;
                    texel[k] = if srgb_of[k] { bucketed_srgb_u8(buckets, v) } else { round_unit_to_u8(v) };
                }
            }
        }
        Image { width: w, height: h, channels: C, srgb: self.srgb, texels: Texels::U8(out) }
    }
}

/// The first of the two texels a bilinear lookup at texel coordinate `x` reads along an axis,
/// and the weight of the second.
#[inline]
pub(super) fn bilinear_corner(x: f32) -> (i64, f32) {
    let x = f64::from(x) - 0.5;
    let x0 = x.floor();
    (x0 as i64, (x - x0) as f32)
}

/// Builds a mip chain from the finest level's rows as they are decoded, top to bottom,
/// without any level whole: each level holds at most the one row waiting for its pair. Each
/// row of a coarser level is [`Image::downsample`] of its two rows (one for a level one row
/// high), so the levels are those of downsampling the whole image, bit for bit.
pub struct MipCascade {
    /// Height of each level, finest first.
    heights: Vec<usize>,
    /// Per level, its last row when it still waits for the row below it.
    pending: Vec<Option<Image>>,
}

impl MipCascade {
    /// A cascade for a `width × height` image (every level down to 1×1).
    pub fn new(width: usize, height: usize) -> MipCascade {
        let levels = level_count(width, height);
        let heights = (0..levels).map(|l| (height >> l).max(1)).collect();
        MipCascade { heights, pending: vec![None; levels] }
    }

    /// Takes the finest level's next rows (`first_row` is how many came before) and hands
    /// `out(level, first_row, rows)` every run of rows of every level they complete, the
    /// finest level's own included.
    pub fn push(&mut self, first_row: usize, rows: &Image, out: &mut dyn FnMut(usize, usize, &Image)) {
        self.feed(0, first_row, rows, out);
    }

    fn feed(&mut self, level: usize, first_row: usize, rows: &Image, out: &mut dyn FnMut(usize, usize, &Image)) {
        if rows.height == 0 {
            return;
        }
        out(level, first_row, rows);
        if level + 1 >= self.heights.len() {
            return;
        }
        if self.heights[level] == 1 {
            // A level of one row halves in width only: its row pairs with itself.
            return self.feed(level + 1, 0, &rows.downsample(), out);
        }
        let merged;
        let (start, rows) = match self.pending[level].take() {
            Some(mut above) => {
                above.append_rows(rows);
                merged = above;
                (first_row - 1, &merged)
            }
            None => (first_row, rows),
        };
        // A run starts on an even row here; an odd last row waits for its pair (or, as the
        // last row of a level of odd height, has none and no part in the next level).
        if rows.height % 2 == 1 {
            self.pending[level] = Some(rows.rows(rows.height - 1..rows.height));
        }
        if rows.height >= 2 {
            // An odd height downsamples to its pairs, the last row left out.
            self.feed(level + 1, start / 2, &rows.downsample(), out);
        }
    }
}

/// `(v.clamp(0, 1) * 255).round() as u8` exactly, without a call to `roundf`: the scaled
/// value lies in `[0, 255]`, where its fraction is exact.
#[inline]
fn round_unit_to_u8(v: f32) -> u8 {
    let x = v.clamp(0.0, 1.0) * 255.0;
    let whole = x as u8;
    if x - f32::from(whole) >= 0.5 { whole + 1 } else { whole }
}

/// Buckets of linear `[0, 1]` in [`SRGB_U8_FIRST_AT_LEAST`].
const SRGB_BUCKETS: usize = 4096;

/// Per bucket `j` of linear `[0, 1]`, the first 8-bit sRGB code whose linear value is at least
/// `j / SRGB_BUCKETS`: where [`nearest_srgb_u8`]'s search starts (a step or two from its end).
static SRGB_U8_FIRST_AT_LEAST: LazyLock<[u8; SRGB_BUCKETS]> = LazyLock::new(|| {
    std::array::from_fn(|j| SRGB_U8.partition_point(|&t| t < j as f32 / SRGB_BUCKETS as f32).min(255) as u8)
});

/// Per bucket `j` of linear `[0, 1]` (as [`SRGB_U8_FIRST_AT_LEAST`]), the code
/// [`nearest_srgb_u8`] gives every value in it, or 256 where it changes inside the bucket (255
/// of the 4096 buckets). The code is monotonic in the value, so one that is equal at both ends
/// of a bucket is the code throughout.
static SRGB_U8_OF_BUCKET: LazyLock<[u16; SRGB_BUCKETS]> = LazyLock::new(|| {
    std::array::from_fn(|j| {
        let low = j as f32 / SRGB_BUCKETS as f32;
        let high = f32::from_bits(((j + 1) as f32 / SRGB_BUCKETS as f32).to_bits() - 1);
        let code = nearest_srgb_u8(low);
        if nearest_srgb_u8(high) == code { u16::from(code) } else { 256 }
    })
});

/// [`nearest_srgb_u8`] read from its bucket where the bucket has one code (`buckets` is
/// [`SRGB_U8_OF_BUCKET`], passed in so a loop dereferences it once).
#[inline]
fn bucketed_srgb_u8(buckets: &[u16; SRGB_BUCKETS], v: f32) -> u8 {
    if (0.0..1.0).contains(&v) {
        let code = buckets[(v * SRGB_BUCKETS as f32) as usize];
        if code < 256 {
            return code as u8;
        }
    }
    nearest_srgb_u8(v)
}

/// The 8-bit sRGB code whose table entry is nearest linear `v` (what the lookup reads back).
fn nearest_srgb_u8(v: f32) -> u8 {
    let table = &*SRGB_U8;
    // The first entry not below `v` (`partition_point`), searched from its bucket's.
    let above = if (0.0..1.0).contains(&v) {
        let mut i = usize::from(SRGB_U8_FIRST_AT_LEAST[(v * SRGB_BUCKETS as f32) as usize % SRGB_BUCKETS]);
        while i < 255 && table[i] < v {
            i += 1;
        }
        i
    } else {
        table.partition_point(|&t| t < v).min(255)
    };
    let below = above.saturating_sub(1);
    (if (table[above] - v).abs() < (v - table[below]).abs() { above } else { below }) as u8
}

/// The number of mip levels of a `width × height` image: down to 1×1.
pub fn level_count(width: usize, height: usize) -> usize {
    (usize::BITS - width.max(height).max(1).leading_zeros()) as usize
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn grey(w: usize, h: usize, value: impl Fn(usize, usize) -> u8) -> Image {
        let texels = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| value(x, y)).collect();
        Image { width: w, height: h, channels: 1, srgb: false, texels: Texels::U8(texels) }
    }

    #[test]
    fn half_floats_round_trip_every_finite_value() {
        // Independent values: IEEE 754 binary16 encodings.
        assert_eq!((f32_to_f16(1.0), f32_to_f16(0.5), f32_to_f16(-2.0)), (0x3c00, 0x3800, 0xc000));
        assert_eq!((f32_to_f16(65504.0), f32_to_f16(1e9), f32_to_f16(f32::NAN)), (0x7bff, 0x7bff, 0));
        assert_eq!((f16_to_f32(0x0001), f16_to_f32(0x7c00), f16_to_f32(0x7e00)), ((-24f32).exp2(), 0.0, 0.0));
        for bits in (0..=u16::MAX).filter(|b| (b >> 10) & 0x1f != 31) {
            assert_eq!(f32_to_f16(f16_to_f32(bits)), bits, "{bits:#06x}");
        }
    }

    #[test]
    fn eight_bit_textures_with_mips_take_under_1_4_bytes_per_texel_and_channel() {
        for (w, h, c) in [(1000, 600, 3), (4096, 512, 1), (33, 77, 4), (1, 1, 2)] {
            let mut level =
                Image { width: w, height: h, channels: c, srgb: true, texels: Texels::U8(vec![7; w * h * c]) };
            let mut bytes = level.bytes();
            for _ in 1..level_count(w, h) {
                level = level.downsample();
                bytes += level.bytes();
            }
            assert_eq!((level.width, level.height), (1, 1), "the chain ends at 1x1");
            let per = bytes as f64 / (w * h * c) as f64;
            assert!(per <= 1.4, "{w}x{h}x{c}: {per} bytes per texel and channel");
        }
    }

    #[test]
    fn eight_bit_mips_are_bit_identical_to_texel_by_texel_averaging() {
        let mut seed = 12345u32;
        for (w, h) in [(7, 5), (64, 33), (1, 9), (9, 1), (2, 2), (1, 1), (130, 67)] {
            for c in 1..=4 {
                for srgb in [false, true] {
                    let texels = (0..w * h * c)
                        .map(|_| {
                            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                            (seed >> 24) as u8
                        })
                        .collect();
                    let image = Image { width: w, height: h, channels: c, srgb, texels: Texels::U8(texels) };
                    assert_eq!(
                        image.downsample().texels,
                        image.downsample_texel_by_texel().texels,
                        "{w}x{h}x{c} {srgb}"
                    );
                }
            }
        }
    }

    #[test]
    fn bucketed_srgb_encoding_matches_a_full_binary_search_and_rounding() {
        let searched = |v: f32| {
            let table = &*SRGB_U8;
            let above = table.partition_point(|&t| t < v).min(255);
            let below = above.saturating_sub(1);
            (if (table[above] - v).abs() < (v - table[below]).abs() { above } else { below }) as u8
        };
        let entries = SRGB_U8
            .iter()
            .flat_map(|&t| [t, f32::from_bits(t.to_bits() + 1), f32::from_bits(t.to_bits().wrapping_sub(1))]);
        let midpoints = SRGB_U8.windows(2).map(|w| 0.5 * (w[0] + w[1]));
        let grid = (0..=100_000).map(|i| i as f32 / 100_000.0);
        for v in entries.chain(midpoints).chain(grid).chain([-0.5, 0.0, 1.0, 1.5, f32::NAN]) {
            assert_eq!(nearest_srgb_u8(v), searched(v), "{v}");
            assert_eq!(bucketed_srgb_u8(&SRGB_U8_OF_BUCKET, v), searched(v), "{v}");
        }
        // Every bucket's ends, and the floats beside them.
        for j in 0..=SRGB_BUCKETS as u32 {
            let edge = j as f32 / SRGB_BUCKETS as f32;
            for v in [f32::from_bits(edge.to_bits().wrapping_sub(1)), edge, f32::from_bits(edge.to_bits() + 1)] {
                assert_eq!(bucketed_srgb_u8(&SRGB_U8_OF_BUCKET, v), searched(v), "{v}");
            }
        }
        for v in (0..=255 * 64).map(|i| i as f32 / (255.0 * 64.0)).chain([-1.0, 2.0, f32::NAN]) {
            assert_eq!(round_unit_to_u8(v), (v.clamp(0.0, 1.0) * 255.0).round() as u8, "{v}");
        }
    }

    /// Levels a [`MipCascade`] makes from `image`'s rows handed over `chunk` rows at a time.
    fn cascaded(image: &Image, chunk: usize) -> Vec<Image> {
        let mut levels: Vec<Option<Image>> = vec![None; level_count(image.width, image.height)];
        let mut cascade = MipCascade::new(image.width, image.height);
        for first in (0..image.height).step_by(chunk) {
            let rows = image.rows(first..(first + chunk).min(image.height));
            cascade.push(first, &rows, &mut |level, first_row, rows| match &mut levels[level] {
                Some(made) => {
                    assert_eq!(made.height, first_row, "level {level}: rows in order");
                    assert!(made.append_rows(rows));
                }
                slot => {
                    assert_eq!(first_row, 0, "level {level} starts at its top row");
                    *slot = Some(rows.clone());
                }
            });
        }
        levels.into_iter().map(|l| l.expect("every level made")).collect()
    }

    #[test]
    fn a_cascade_of_row_pairs_makes_the_levels_of_downsampling_the_whole_image() {
        let mut seed = 777u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            seed >> 8
        };
        for (w, h) in [(7, 5), (5, 7), (1, 9), (9, 1), (1, 1), (13, 2), (130, 67), (33, 65), (64, 64)] {
            for c in 1..=4 {
                for kind in 0..4 {
                    let n = w * h * c;
                    let texels = match kind {
                        0 => Texels::U8((0..n).map(|_| next() as u8).collect()),
                        1 => Texels::U16((0..n).map(|_| next() as u16).collect()),
                        2 => Texels::F16((0..n).map(|_| f32_to_f16((next() % 5000) as f32 / 700.0)).collect()),
                        _ => Texels::F32((0..n).map(|_| (next() % 100_000) as f32 / 3e4).collect()),
                    };
                    let srgb = kind < 2 && next() % 2 == 0;
                    let image = Image { width: w, height: h, channels: c, srgb, texels };
                    let mut whole = vec![image.clone()];
                    while whole.len() < level_count(w, h) {
                        let coarser = whole[whole.len() - 1].downsample();
                        whole.push(coarser);
                    }
                    for chunk in [1, 2, 3, 16, h] {
                        assert_eq!(cascaded(&image, chunk), whole, "{w}x{h}x{c} kind {kind} srgb {srgb} by {chunk}");
                    }
                }
            }
        }
    }

    #[test]
    fn mip_levels_average_in_linear_light() {
        // sRGB 0 and 255 average to linear 0.5; raw 0 and 255 to 127.5 (stored 128).
        let srgb = Image { width: 2, height: 1, channels: 1, srgb: true, texels: Texels::U8(vec![0, 255]) };
        let half = srgb.downsample();
        let Texels::U8(v) = &half.texels else { panic!() };
        assert!((srgb_decode(f32::from(v[0]) / 255.0) - 0.5).abs() < 0.003, "{v:?}");
        assert_eq!(v[0], 188, "the sRGB code of linear 0.5");
        let raw = grey(2, 2, |x, _| if x == 0 { 0 } else { 255 }).downsample();
        assert_eq!(raw.texels, Texels::U8(vec![128]));
        let float =
            Image { width: 2, height: 2, channels: 1, srgb: false, texels: Texels::F32(vec![1.0, 2.0, 3.0, 6.0]) };
        assert_eq!(float.downsample().texels, Texels::F32(vec![3.0]));
    }
}
