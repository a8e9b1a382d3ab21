//! `strata bench textures`: what textures cost at their source precision. Images of each
//! source kind are written to a temporary directory, then measured: bytes per texel with the
//! mip levels, header and decode time; lookup cost per filter on one and all cores; and a
//! render of a textured ground plane seen at a grazing angle with the texture memory at
//! 100 %, 25 % and 5 % of what its textures take.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;
use strata::render::RenderSettings;
use strata::render::scene::SceneOptions;
use strata::runtime::texture::{self as files, ColorSpace};
use strata::session::{Pass, SceneSource, Session, SessionOptions};
use strata_rt::texture::{self as cache, Filter, Image};

/// Side of the measured images.
const SIDE: u32 = 2048;
/// Textures of the render scene, and their side.
const SCENE_TEXTURES: usize = 8;
const SCENE_SIDE: u32 = 1024;

/// Runs the benchmark at `res` and `spp`; returns the report.
pub fn bench_textures(res: (usize, usize), spp: u32) -> Result<String, String> {
    let dir = std::env::temp_dir().join(format!("strata-bench-textures-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let result = run(&dir, res, spp);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// A texel value with detail at every scale (a hash), as 8-bit.
fn pattern(x: u32, y: u32, c: u32) -> u8 {
    let mut h = x.wrapping_mul(0x9e37_79b1) ^ y.wrapping_mul(0x85eb_ca77) ^ c.wrapping_mul(0xc2b2_ae3d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    // Checker cells of 32 texels under the noise, so mips matter.
    let cell = if ((x / 32) + (y / 32)).is_multiple_of(2) { 160 } else { 40 };
    (cell + (h >> 26)) as u8
}

/// Writes one image of each source kind; returns (label, file name).
fn write_sources(dir: &Path) -> Result<Vec<(&'static str, std::path::PathBuf)>, String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let rgb8 = image::RgbImage::from_fn(SIDE, SIDE, |x, y| image::Rgb([0, 1, 2].map(|c| pattern(x, y, c))));
    let grey8 = image::GrayImage::from_fn(SIDE, SIDE, |x, y| image::Luma([pattern(x, y, 0)]));
    let rgb16 = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(SIDE, SIDE, |x, y| {
        image::Rgb([0, 1, 2].map(|c| u16::from(pattern(x, y, c)) * 257))
    });
    let mut out = Vec::new();
    let (rgb8, grey8, rgb16) =
        (image::DynamicImage::from(rgb8), image::DynamicImage::from(grey8), image::DynamicImage::from(rgb16));
    for (label, name, image) in [
        ("PNG RGB 8-bit", "rgb8.png", &rgb8),
        ("JPEG RGB 8-bit", "rgb8.jpg", &rgb8),
        ("PNG grey 8-bit", "grey8.png", &grey8),
        ("PNG RGB 16-bit", "rgb16.png", &rgb16),
    ] {
        let path = dir.join(name);
        image.save(&path).map_err(|e| err(&e))?;
        out.push((label, path));
    }
    for (label, name, half) in [("EXR RGB half", "half.exr", true), ("EXR RGB float", "float.exr", false)] {
        use exr::prelude::{Encoding, WritableImage, f16};
        let path = dir.join(name);
        let texel =
            |pos: exr::prelude::Vec2<usize>, c: u32| f32::from(pattern(pos.x() as u32, pos.y() as u32, c)) / 255.0;
        let size = (SIDE as usize, SIDE as usize);
        let attributes = exr::prelude::LayerAttributes::default();
        if half {
            let channels = exr::prelude::SpecificChannels::rgb(|p| {
                (f16::from_f32(texel(p, 0)), f16::from_f32(texel(p, 1)), f16::from_f32(texel(p, 2)))
            });
            let layer = exr::prelude::Layer::new(size, attributes, Encoding::FAST_LOSSLESS, channels);
            exr::prelude::Image::from_layer(layer).write().to_file(&path).map_err(|e| err(&e))?;
        } else {
            let channels = exr::prelude::SpecificChannels::rgb(|p| (texel(p, 0), texel(p, 1), texel(p, 2)));
            let layer = exr::prelude::Layer::new(size, attributes, Encoding::FAST_LOSSLESS, channels);
            exr::prelude::Image::from_layer(layer).write().to_file(&path).map_err(|e| err(&e))?;
        }
        out.push((label, path));
    }
    Ok(out)
}

/// The finest level and its mip chain's bytes.
fn chain_bytes(finest: &Image) -> u64 {
    let mut level = finest.downsample();
    let mut bytes = finest.bytes() + level.bytes();
    while level.width > 1 || level.height > 1 {
        level = level.downsample();
        bytes += level.bytes();
    }
    bytes
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// Nanoseconds per lookup of `filter` over `footprint` (in texels of `side`), on `threads`
/// threads at once (each doing `count` lookups): wall time over all lookups.
fn lookup_ns(id: i32, side: u32, filter: Filter, footprint: [f32; 4], threads: usize, count: usize) -> f64 {
    let footprint = footprint.map(|f| f / side as f32);
    let start = Instant::now();
    let sums: f32 = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|k| {
                scope.spawn(move || {
                    let mut sum = 0.0;
                    let mut s = 0.1 + k as f32 * 0.01;
                    for i in 0..count {
                        s = (s + 0.618_034).fract();
                        let t = (i as f32 * 0.000_173 + k as f32 * 0.37).fract();
                        sum += cache::lookup_with(filter, id, s, t, (i % 3) as i32, footprint);
                    }
                    sum
                })
            })
            .collect();
        workers.into_iter().map(|w| w.join().unwrap_or(0.0)).sum()
    });
    std::hint::black_box(sums);
    start.elapsed().as_nanos() as f64 / (threads * count) as f64
}

/// A ground plane of `SCENE_TEXTURES` strips, each with its own texture, seen at a grazing
/// angle, lit by a dome. Each material has a scope of its own: a layer holds one spec per
/// prim path (a second `def "Looks"` would leave every strip but the first unbound).
fn scene_text(dir: &Path) -> String {
    let mut text = String::from(
        "#usda 1.0\n(\n    upAxis = \"Y\"\n)\n\ndef Camera \"Camera\"\n{\n    float focalLength = 30\n    \
         double3 xformOp:translate = (0, 1, 12)\n    float3 xformOp:rotateXYZ = (-8, 0, 0)\n    \
         uniform token[] xformOpOrder = [\"xformOp:translate\", \"xformOp:rotateXYZ\"]\n}\n\n\
         def DomeLight \"Sky\"\n{\n    float inputs:intensity = 1\n}\n",
    );
    let n = SCENE_TEXTURES as f32;
    for k in 0..SCENE_TEXTURES {
        let (x0, x1) = (-10.0 + 20.0 * k as f32 / n, -10.0 + 20.0 * (k + 1) as f32 / n);
        let file = dir.join(format!("scene{k}.png"));
        let _ = write!(
            text,
            "\ndef Mesh \"Strip{k}\" (\n    prepend apiSchemas = [\"MaterialBindingAPI\"]\n)\n{{\n    \
             int[] faceVertexCounts = [4]\n    int[] faceVertexIndices = [0, 1, 2, 3]\n    \
             point3f[] points = [({x0}, 0, 10), ({x1}, 0, 10), ({x1}, 0, -90), ({x0}, 0, -90)]\n    \
             texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 40), (0, 40)] (\n        interpolation = \"vertex\"\n    )\n    \
             rel material:binding = </Looks{k}/M{k}>\n}}\n\
             def \"Looks{k}\"\n{{\n    def Material \"M{k}\"\n    {{\n        \
             token outputs:surface.connect = </Looks{k}/M{k}/PBR.outputs:surface>\n        \
             def Shader \"PBR\"\n        {{\n            uniform token info:id = \"UsdPreviewSurface\"\n            \
             color3f inputs:diffuseColor.connect = </Looks{k}/M{k}/Tex.outputs:rgb>\n            token outputs:surface\n        }}\n        \
             def Shader \"St\"\n        {{\n            uniform token info:id = \"UsdPrimvarReader_float2\"\n            \
             token inputs:varname = \"st\"\n            float2 outputs:result\n        }}\n        \
             def Shader \"Tex\"\n        {{\n            uniform token info:id = \"UsdUVTexture\"\n            \
             asset inputs:file = @{}@\n            float2 inputs:st.connect = </Looks{k}/M{k}/St.outputs:result>\n            \
             float3 outputs:rgb\n        }}\n    }}\n}}\n",
            file.display()
        );
    }
    text
}

fn run(dir: &Path, res: (usize, usize), spp: u32) -> Result<String, String> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut out = format!(
        "strata bench textures: {SIDE}x{SIDE} images, {threads} core(s); render {}x{} at {spp} spp\n\n",
        res.0, res.1
    );
    let _ = writeln!(
        out,
        "{:<16} {:>10} {:>12} {:>10} {:>10} {:>10} {:>12}",
        "source", "file MB", "bytes/texel", "per chan.", "header ms", "decode ms", "mip chain ms"
    );
    let max_pixels = strata::input::limits().max_texture_pixels;
    for (label, path) in write_sources(dir)? {
        let bytes = std::fs::read(&path).map_err(|e| e.to_string())?;
        let start = Instant::now();
        let header = files::read_header(&bytes, Some(&path), ColorSpace::Auto, max_pixels)?;
        let header_ms = ms(start);
        let start = Instant::now();
        let finest = files::decode_image(&bytes, Some(&path), ColorSpace::Auto, max_pixels)?;
        let decode_ms = ms(start);
        let start = Instant::now();
        let total = chain_bytes(&finest);
        let chain_ms = ms(start);
        let texels = f64::from(SIDE) * f64::from(SIDE);
        let _ = writeln!(
            out,
            "{label:<16} {:>10.2} {:>12.2} {:>10.2} {header_ms:>10.2} {decode_ms:>10.1} {chain_ms:>12.1}",
            bytes.len() as f64 / 1e6,
            total as f64 / texels,
            total as f64 / texels / header.channels as f64,
        );
    }
    out += "(bytes per texel include every mip level; the old path kept 16 bytes of RGBA floats, no mips)\n\n";

    // Lookups on a resident 8-bit RGB texture.
    let rgb8 = files::decode_image(
        &std::fs::read(dir.join("rgb8.png")).map_err(|e| e.to_string())?,
        None,
        ColorSpace::Auto,
        max_pixels,
    )?;
    let id = cache::register_image("bench:lookups".into(), rgb8)?;
    let cases: [(&str, Filter, [f32; 4]); 4] = [
        ("nearest", Filter::Nearest, [0.0; 4]),
        ("bilinear (footprint < 1 texel)", Filter::Trilinear, [0.5, 0.0, 0.0, 0.5]),
        ("trilinear (4 texels)", Filter::Trilinear, [4.0, 0.0, 0.0, 4.0]),
        ("anisotropic (16 x 2 texels)", Filter::Anisotropic, [16.0, 0.0, 0.0, 2.0]),
    ];
    let _ =
        writeln!(out, "{:<34} {:>14} {:>22}", "lookup (one channel)", "ns, 1 thread", format!("ns, {threads} threads"));
    lookup_ns(id, SIDE, Filter::Trilinear, [4.0, 0.0, 0.0, 4.0], 1, 10_000); // decodes: warm
    for (label, filter, footprint) in cases {
        let one = lookup_ns(id, SIDE, filter, footprint, 1, 2_000_000);
        let all = lookup_ns(id, SIDE, filter, footprint, threads, 2_000_000);
        let _ = writeln!(out, "{label:<34} {one:>14.1} {all:>22.1}");
    }
    out += "(all threads: wall time per lookup with every thread reading the same texture)\n\n";

    // A render against the texture memory.
    for k in 0..SCENE_TEXTURES {
        let image = image::RgbImage::from_fn(SCENE_SIDE, SCENE_SIDE, |x, y| {
            image::Rgb([0, 1, 2].map(|c| pattern(x + k as u32 * 7, y, c)))
        });
        image.save(dir.join(format!("scene{k}.png"))).map_err(|e| e.to_string())?;
    }
    let scene = dir.join("scene.usda");
    std::fs::write(&scene, scene_text(dir)).map_err(|e| e.to_string())?;
    let full = SCENE_TEXTURES as u64 * u64::from(SCENE_SIDE).pow(2) * 3 * 4 / 3;
    let _ = writeln!(
        out,
        "render: {SCENE_TEXTURES} textures of {SCENE_SIDE}x{SCENE_SIDE} 8-bit RGB ({:.1} MB with mips) on a ground plane at a grazing angle",
        full as f64 / 1e6
    );
    let _ = writeln!(
        out,
        "{:<10} {:>10} {:>12} {:>10} {:>10} {:>10} {:>12}",
        "budget", "MB", "render ms", "hit rate", "decodes", "evictions", "resident MB"
    );
    let settings = RenderSettings { width: res.0, height: res.1, spp, ..RenderSettings::default() };
    let pass = Pass::full(settings);
    let mut session = Session::open(SceneSource::File(scene), SessionOptions::default());
    if session.prepare(&SceneOptions::default()).is_none() {
        return Err(session.diagnostics().render(session.sources()));
    }
    let previous = cache::memory_budget();
    for percent in [100u64, 25, 5] {
        let budget = full * percent / 100;
        cache::set_memory_budget(budget);
        cache::evict_all();
        cache::reset_stats();
        let start = Instant::now();
        session.render(&pass, None).map_err(|e| e.to_string())?;
        let render_ms = ms(start);
        let stats = cache::stats();
        let _ = writeln!(
            out,
            "{:<10} {:>10.1} {render_ms:>12.1} {:>9.2}% {:>10} {:>10} {:>12.1}",
            format!("{percent} %"),
            budget as f64 / 1e6,
            100.0 * stats.hit_rate(),
            stats.decodes,
            stats.evictions,
            stats.resident_bytes as f64 / 1e6
        );
    }
    cache::set_memory_budget(previous);
    Ok(out)
}
