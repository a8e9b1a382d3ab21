//! Texture cache stability (issue 24): a 1x1 texture, one channel, NaN texels, 64 threads
//! reading one texture at once, and a 16384 x 16384 texture under a budget far smaller than
//! it. A process of its own: the budget is process-wide.

use strata_rt::texture::{
    self, Filter, Image, TexelSource, Texels, lookup, lookup_with, register_image, register_source,
};

fn grey(w: usize, h: usize, value: impl Fn(usize, usize) -> u8) -> Image {
    let texels = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| value(x, y)).collect();
    Image { width: w, height: h, channels: 1, srgb: false, texels: Texels::U8(texels) }
}

const FOOTPRINTS: [[f32; 4]; 4] = [[0.0; 4], [0.01, 0.0, 0.0, 0.01], [0.3, 0.1, -0.002, 0.004], [50.0, 0.0, 0.0, 50.0]];

#[test]
fn a_one_by_one_texture_reads_its_texel_at_any_footprint() {
    let image = Image { width: 1, height: 1, channels: 4, srgb: false, texels: Texels::F32(vec![0.1, 0.2, 0.3, 0.4]) };
    let id = register_image("stability:1x1".into(), image).unwrap();
    for footprint in FOOTPRINTS {
        for filter in [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Anisotropic] {
            for (channel, want) in [0.1, 0.2, 0.3, 0.4].into_iter().enumerate() {
                let got = lookup_with(filter, id, 7.3, -2.1, channel as i32, footprint);
                assert!((got - want).abs() < 1e-6, "{filter:?} {footprint:?} channel {channel}: {got}");
            }
        }
    }
}

#[test]
fn a_one_channel_texture_is_grey_with_opaque_alpha() {
    let id = register_image("stability:grey".into(), grey(3, 2, |x, y| (x * 50 + y * 100) as u8)).unwrap();
    // Texel (1, 0) is 50: its centre is s = 0.5, t = 0.75 (row 0 is t = 1).
    for channel in 0..3 {
        assert!((lookup(id, 0.5, 0.75, channel) - 50.0 / 255.0).abs() < 1e-6);
    }
    assert_eq!(lookup(id, 0.5, 0.75, 3), 1.0);
    // Two channels: grey and alpha.
    let la = Image { width: 1, height: 1, channels: 2, srgb: true, texels: Texels::U8(vec![255, 51]) };
    let id = register_image("stability:grey-alpha".into(), la).unwrap();
    assert_eq!(lookup(id, 0.5, 0.5, 1), 1.0);
    assert!((lookup(id, 0.5, 0.5, 3) - 0.2).abs() < 1e-6, "alpha stays linear");
}

#[test]
fn nan_and_infinite_texels_read_as_zero() {
    let image =
        Image { width: 2, height: 1, channels: 1, srgb: false, texels: Texels::F32(vec![f32::NAN, f32::INFINITY]) };
    let id = register_image("stability:nan".into(), image).unwrap();
    let half = Image { width: 2, height: 1, channels: 1, srgb: false, texels: Texels::F16(vec![0x7e00, 0x7c00]) };
    let half = register_image("stability:nan-half".into(), half).unwrap();
    for id in [id, half] {
        for footprint in FOOTPRINTS {
            assert_eq!(lookup_with(Filter::Anisotropic, id, 0.3, 0.5, 0, footprint), 0.0, "{footprint:?}");
        }
    }
}

#[test]
fn sixty_four_threads_read_one_texture_as_one_does() {
    let id = register_image("stability:threads".into(), grey(256, 256, |x, y| ((x ^ y) * 7 % 256) as u8)).unwrap();
    let coords: Vec<(f32, f32, [f32; 4])> = (0..4000)
        .map(|k| ((k as f32 * 0.618_034).fract() * 3.0, (k as f32 * 0.414_214).fract(), FOOTPRINTS[k % 4]))
        .collect();
    let read = |&(s, t, footprint): &(f32, f32, [f32; 4])| lookup_with(Filter::Anisotropic, id, s, t, 0, footprint);
    let want: Vec<f32> = coords.iter().map(read).collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> =
            (0..64).map(|_| scope.spawn(|| (0..5).all(|_| coords.iter().map(read).eq(want.iter().copied())))).collect();
        assert!(handles.into_iter().all(|h| h.join().unwrap()), "a thread read other values");
    });
}

/// A 16384 x 16384 one-channel texture made on decode: texel (x, y) is `(x ^ y) & 255`.
struct Huge;
const HUGE: usize = 16384;

impl TexelSource for Huge {
    fn decode(&self) -> Result<Image, String> {
        Ok(grey(HUGE, HUGE, |x, y| ((x ^ y) & 255) as u8))
    }
}

#[test]
fn a_16384_squared_texture_under_a_small_budget_reads_correctly() {
    let budget = 8 << 20; // 8 MiB against 256 MiB of texels
    texture::set_memory_budget(budget);
    let id = register_source("stability:huge".into(), HUGE, HUGE, Box::new(Huge)).unwrap();
    // Texel centres at the finest level: exact values.
    for (x, y) in [(12345usize, 6789usize), (HUGE - 1, HUGE - 1)] {
        let (s, t) = ((x as f32 + 0.5) / HUGE as f32, 1.0 - (y as f32 + 0.5) / HUGE as f32);
        let got = lookup(id, s, t, 0);
        assert_eq!(got, ((x ^ y) & 255) as f32 / 255.0, "texel ({x}, {y})");
    }
    // Level 0 is read by bands of rows: the band of a texel just read stays, no decode.
    let decodes = texture::stats().decodes;
    let (x, y) = (12345usize, 6789usize);
    let (s, t) = ((x as f32 + 0.5) / HUGE as f32, 1.0 - (y as f32 + 0.5) / HUGE as f32);
    assert_eq!(lookup(id, s, t, 0), ((x ^ y) & 255) as f32 / 255.0);
    assert_eq!(texture::stats().decodes, decodes, "its band is resident");
    // Between the last row and the first (repeat wrap): two bands, half of each texel.
    let (x, s) = (777usize, (777.0 + 0.5) / HUGE as f32);
    let seam = lookup(id, s, 1.0, 0);
    let want = (((x ^ (HUGE - 1)) & 255) + (x & 255)) as f32 / 2.0 / 255.0;
    assert!((seam - want).abs() < 1e-6, "{seam} against {want}");
    // The whole texture in one footprint: the mean of (x ^ y) & 255 over all texels, 127.5.
    let mean = lookup_with(Filter::Trilinear, id, 0.5, 0.5, 0, [2.0, 0.0, 0.0, 2.0]);
    assert!((mean - 0.5).abs() < 2.0 / 255.0, "{mean}");
    let stats = texture::stats();
    assert!(stats.resident_bytes <= budget, "{stats:?}");
    assert!(stats.decodes >= 2, "the finest level never stays: {stats:?}");
}
