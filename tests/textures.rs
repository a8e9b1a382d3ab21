//! Texture filtering by the ray's footprint (issue 24 item 2), in rendered images. The
//! reference is independent of mip-mapping: the same scene supersampled at 1024 samples per
//! pixel with the footprint ignored (bilinear at the finest level), so each pixel is the
//! texture averaged over the pixel's area. A checker seen at grazing angles at 1 spp must be
//! much nearer that reference filtered than unfiltered; seen up close, where the footprint is
//! below a texel, filtering must change nothing.

mod common;

use std::path::Path;
use strata_rt::texture::{Filter, set_filter};

/// A `side × side` 8-bit grey checker of `cell`-texel cells, black and white.
fn write_checker(path: &Path, side: u32, cell: u32) {
    let data: Vec<u8> = (0..side * side)
        .map(|i| if ((i % side) / cell + (i / side) / cell).is_multiple_of(2) { 255 } else { 0 })
        .collect();
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, side, side);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(&data).unwrap();
    writer.finish().unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// A scene: the camera (50 mm, 20 mm aperture) at `camera`, pitched by `pitch` degrees, a
/// quad with corners `points` and texture coordinates `st` textured by `texture` (raw).
fn scene(texture: &Path, camera: (f32, f32, f32), pitch: f32, points: &str, st: &str) -> String {
    let (x, y, z) = camera;
    format!(
        r#"#usda 1.0
(
    upAxis = "Y"
)
def Camera "Camera"
{{
    float focalLength = 50
    float horizontalAperture = 20
    float verticalAperture = 20
    double3 xformOp:translate = ({x}, {y}, {z})
    float3 xformOp:rotateXYZ = ({pitch}, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}}
def DomeLight "Sky"
{{
    float inputs:intensity = 1
}}
def Mesh "Ground" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = {points}
    texCoord2f[] primvars:st = {st} (
        interpolation = "vertex"
    )
    rel material:binding = </Looks/Checker>
}}
def "Looks"
{{
    def Material "Checker"
    {{
        token outputs:surface.connect = </Looks/Checker/PBR.outputs:surface>
        def Shader "PBR"
        {{
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </Looks/Checker/Tex.outputs:rgb>
            token outputs:surface
        }}
        def Shader "St"
        {{
            uniform token info:id = "UsdPrimvarReader_float2"
            token inputs:varname = "st"
            float2 outputs:result
        }}
        def Shader "Tex"
        {{
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @{}@
            token inputs:sourceColorSpace = "raw"
            float2 inputs:st.connect = </Looks/Checker/St.outputs:result>
            float3 outputs:rgb
        }}
    }}
}}
"#,
        texture.display()
    )
}

/// The albedo AOV's red channel of `scene` rendered at `spp` with `filter`.
fn albedo(scene: &Path, res: usize, spp: u32, filter: Filter) -> Vec<f32> {
    set_filter(filter);
    let image = common::render_file(scene, &common::settings(res, res, spp, 7, 1));
    set_filter(Filter::Anisotropic);
    image.f32_channel("albedo.R").expect("an albedo AOV").to_vec()
}

fn rmse(a: &[f32], b: &[f32]) -> f64 {
    let sum: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
    (sum / a.len() as f64).sqrt()
}

/// One test, not several: the filter is process-wide.
#[test]
fn footprint_filtering_removes_aliasing_at_grazing_angles_and_changes_nothing_up_close() {
    let dir = tempfile::tempdir().unwrap();
    let texture = dir.path().join("checker.png");
    write_checker(&texture, 64, 8);

    // A ground plane running 400 units away from a camera 1 unit above it, st repeating
    // every 2 units: the checker's cells shrink far below a pixel towards the horizon.
    let grazing = dir.path().join("grazing.usda");
    let text = scene(
        &texture,
        (0.0, 1.0, 0.0),
        -6.0,
        "[(-100, 0, 5), (100, 0, 5), (100, 0, -400), (-100, 0, -400)]",
        "[(0, 0), (100, 0), (100, 202.5), (0, 202.5)]",
    );
    std::fs::write(&grazing, text).unwrap();
    let res = 48;
    let reference = albedo(&grazing, res, 1024, Filter::Bilinear);
    let unfiltered = rmse(&albedo(&grazing, res, 1, Filter::Bilinear), &reference);
    let trilinear = rmse(&albedo(&grazing, res, 1, Filter::Trilinear), &reference);
    let anisotropic = rmse(&albedo(&grazing, res, 1, Filter::Anisotropic), &reference);
    eprintln!(
        "grazing checker, 1 spp against 1024 spp: RMSE unfiltered {unfiltered:.4}, trilinear {trilinear:.4}, anisotropic {anisotropic:.4}"
    );
    assert!(unfiltered > 0.1, "the unfiltered image aliases: {unfiltered}");
    assert!(trilinear < 0.6 * unfiltered, "trilinear {trilinear} vs unfiltered {unfiltered}");
    assert!(anisotropic < 0.6 * unfiltered, "anisotropic {anisotropic} vs unfiltered {unfiltered}");

    // Up close: a 2 x 2 quad filling the frame at 128 pixels, 64 texels across (2 pixels a
    // texel, a footprint of half a texel): every filter gives the same image, bit for bit.
    let close = dir.path().join("close.usda");
    let text = scene(
        &texture,
        (0.0, 0.0, 5.0),
        0.0,
        "[(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]",
        "[(0, 0), (1, 0), (1, 1), (0, 1)]",
    );
    std::fs::write(&close, text).unwrap();
    let bilinear = albedo(&close, 128, 1, Filter::Bilinear);
    assert!(bilinear.iter().any(|&v| v > 0.5) && bilinear.iter().any(|&v| v < 0.5), "the checker is seen");
    for filter in [Filter::Trilinear, Filter::Anisotropic] {
        assert_eq!(albedo(&close, 128, 1, filter), bilinear, "{filter:?} changed the image where texels are large");
    }
}

/// The texel of the 16384² test PNG at (x, y): three 8-bit channels of formulas (each row
/// repeats every 256 texels, so the file deflates to a few MB).
fn huge_texel(x: usize, y: usize) -> [u8; 3] {
    [((x ^ y) & 255) as u8, ((x + y) & 255) as u8, (y & 255) as u8]
}

/// A real 16384 x 16384 RGB PNG file (768 MiB of texels, 256 MiB at level 1) under a 64 MiB
/// texture budget: its rows are decoded as a band of them is reached, never the whole image,
/// and the texels read are the formula's that wrote the file. (Its peak memory, measured with
/// `/usr/bin/time -v`, is in README's Texture pipeline.)
#[test]
fn a_16384_squared_png_under_a_64_mib_budget_reads_the_texels_that_made_it() {
    const SIDE: usize = 16384;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("huge.png");
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let mut encoder = png::Encoder::new(file, SIDE as u32, SIDE as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        // zlib level 1 finds the rows' 768-byte period (fdeflate's fast modes do not).
        encoder.set_deflate_compression(png::DeflateCompression::Level(1));
        encoder.set_filter(png::Filter::NoFilter);
        let mut writer = encoder.write_header().unwrap();
        let mut stream = writer.stream_writer().unwrap();
        let mut row = vec![0u8; SIDE * 3];
        for y in 0..SIDE {
            for (x, texel) in row.chunks_exact_mut(3).enumerate() {
                texel.copy_from_slice(&huge_texel(x, y));
            }
            std::io::Write::write_all(&mut stream, &row).unwrap();
        }
        stream.finish().unwrap();
    }
    assert!(std::fs::metadata(&path).unwrap().len() < 64 << 20, "a compressible pattern");
    // 2^28 texels: twice the default limit (`--max-texture-pixels`).
    let mut limits = strata::input::limits();
    limits.max_texture_pixels = 1 << 28;
    strata::input::set_limits(limits);
    let budget = 64 << 20;
    strata::runtime::texture::set_memory_budget(Some(budget));
    let id = strata::runtime::texture::register_file_as(&path, strata::runtime::texture::ColorSpace::Raw).unwrap();
    let centre =
        |x: usize, y: usize, texels: usize| ((x as f32 + 0.5) / texels as f32, 1.0 - (y as f32 + 0.5) / texels as f32);
    // Finest-level reads at texel centres give the texel exactly: top, middle and bottom bands.
    for (x, y) in [(0, 0), (12345, 6789), (8191, 8000), (SIDE - 1, SIDE - 2), (5, SIDE - 1)] {
        let (s, t) = centre(x, y, SIDE);
        for (channel, want) in huge_texel(x, y).into_iter().enumerate() {
            let got = strata_rt::texture::lookup_with(Filter::Bilinear, id, s, t, channel as i32, [0.0; 4]);
            assert!((got - f32::from(want) / 255.0).abs() < 1e-6, "texel ({x}, {y}) channel {channel}: {got}");
        }
    }
    // A footprint of 4 texels reads level 2 (48 MiB: it fits the budget whole): at its
    // texel centres, the mean of the 4 x 4 block (two 8-bit roundings on the way).
    for (x, y) in [(1000, 2000), (4095, 17)] {
        let (s, t) = centre(x, y, SIDE / 4);
        let footprint = [4.0 / SIDE as f32, 0.0, 0.0, 4.0 / SIDE as f32];
        for channel in 0..3 {
            let block: f32 =
                (0..16).map(|k| f32::from(huge_texel(4 * x + k % 4, 4 * y + k / 4)[channel])).sum::<f32>() / 16.0;
            let got = strata_rt::texture::lookup_with(Filter::Trilinear, id, s, t, channel as i32, footprint);
            assert!((got - block / 255.0).abs() <= 1.0 / 255.0 + 1e-6, "level 2 ({x}, {y}) channel {channel}: {got}");
        }
    }
    let stats = strata_rt::texture::stats();
    assert!(stats.resident_bytes <= budget, "{stats:?}");
}
