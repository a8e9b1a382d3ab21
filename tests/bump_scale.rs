//! Bump at every scale and place: the finite-difference step comes from the shading point's
//! footprint (the pixel's ray cone), so a bumped plane shows the same shading normals at the
//! origin, translated by 1e4 (camera moved alike) and scaled to 1e-3 across (camera and relief
//! scaled alike). The relief is a function of the texture coordinates, so the three scenes
//! are the same surface; any difference in the normal AOV is the step's.

mod common;

use std::path::Path;

/// A 2 × 2 quad (st over it) under a dome, seen straight down from 5 units, the whole scene
/// scaled by `scale` and moved by `offset`; its material bumps it by ripples 1/8 of st long and
/// `0.01 · scale` high (slopes up to about 0.25 at every scale).
fn normals(dir: &Path, scale: f64, offset: [f64; 3]) -> Vec<[f32; 3]> {
    let name = format!("bump_{scale}_{}", offset[0]);
    std::fs::write(
        dir.join(format!("{name}.ash")),
        format!(
            "shader ripples(output float out = 0.0) {{ out = sin(u * 50.265482) * sin(v * 50.265482); }}
             substance q {{ node h = ripples(); node b = bump(height: h.out, scale: {amplitude:e});
                           node d = diffuse(); surface = d.bsdf; displacement = b.out; }}",
            amplitude = 0.01 * scale
        ),
    )
    .unwrap();
    let [x, y, z] = offset;
    let usda = format!(
        r#"#usda 1.0
(
    upAxis = "Y"
)
def Xform "World"
{{
    double3 xformOp:translate = ({x}, {y}, {z})
    double3 xformOp:scale = ({scale}, {scale}, {scale})
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    def Camera "Camera"
    {{
        float focalLength = 50
        float horizontalAperture = 20
        float verticalAperture = 20
        float2 clippingRange = ({near}, {far})
        double3 xformOp:translate = (0, 5, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
    def Mesh "Quad"
    {{
        rel material:slotBinding:_000 = </Looks/Q>
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
    }}
}}
def DomeLight "Sky"
{{
    float inputs:intensity = 1
}}
def Material "Looks"
{{
    def Material "Q"
    {{
        def Shader "Surface"
        {{
            uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @{name}.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "q"
        }}
    }}
}}
"#,
        near = 0.1 * scale,
        far = 100.0 * scale,
    );
    let path = dir.join(format!("{name}.usda"));
    std::fs::write(&path, usda).unwrap();
    let image = common::render_file(&path, &common::settings(48, 48, 4, 3, 1));
    let [r, g, b] = ["N.R", "N.G", "N.B"].map(|c| image.f32_channel(c).unwrap().to_vec());
    (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect()
}

/// The mean length of the per-pixel difference of two normal images.
fn mean_difference(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let d = |p: &[f32; 3], q: &[f32; 3]| (0..3).map(|k| ((p[k] - q[k]) as f64).powi(2)).sum::<f64>().sqrt();
    a.iter().zip(b).map(|(p, q)| d(p, q)).sum::<f64>() / a.len() as f64
}

#[test]
fn bump_shows_the_same_normals_translated_by_1e4_and_scaled_to_1e_minus_3() {
    let dir = tempfile::tempdir().unwrap();
    let origin = normals(dir.path(), 1.0, [0.0; 3]);
    // The relief is there: the normals lean visibly away from the flat one.
    let flat = vec![[0.0, 1.0, 0.0]; origin.len()];
    let relief = mean_difference(&origin, &flat);
    eprintln!("mean |N - flat| at the origin: {relief:.4}");
    assert!(relief > 0.05, "the bump shows at the origin: {relief}");
    for (scale, offset) in [(1.0, [1e4, 0.0, 0.0]), (1.0, [1e4, -1e4, 1e4]), (1e-3, [0.0; 3])] {
        let other = normals(dir.path(), scale, offset);
        let difference = mean_difference(&origin, &other);
        let other_relief = mean_difference(&other, &flat);
        eprintln!("scale {scale} at {offset:?}: mean |ΔN| {difference:.2e}, mean |N - flat| {other_relief:.4}");
        assert!(difference <= 1e-3, "scale {scale} at {offset:?}: mean |ΔN| = {difference}");
    }
}
