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
