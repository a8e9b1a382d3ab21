//! `strata bench features`: the cost of each render feature.

use super::*;

// ---- bench features ---------------------------------------------------------------------------

/// Substances of [`features_scene`]: the plain materials every variant renders, and one extra
/// substance per feature, bound only to a tiny sphere the camera never sees.
fn features_source(texture: &Path) -> String {
    format!(
        "substance plain_diffuse {{\n    node d = diffuse(albedo: color(0.6, 0.5, 0.4));\n    surface = d.bsdf;\n}}\n\
         substance plain_glossy {{\n    node g = glossy(albedo: color(0.3, 0.4, 0.6), roughness: 0.3);\n    surface = g.bsdf;\n}}\n\
         substance extra_none {{\n    node d = diffuse();\n    surface = d.bsdf;\n}}\n\
         substance extra_aov {{\n    node d = diffuse();\n    node c = customChannelFloat(name: \"extra\", value: 1.0);\n    surface = d.bsdf;\n}}\n\
         substance extra_displacement {{\n    node d = diffuse();\n    node n = noise(scale: 4.0);\n    \
         node b = bump(height: n.out, scale: 0.01, mode: \"add\");\n    surface = d.bsdf;\n    displacement = b.out;\n}}\n\
         substance extra_texture {{\n    node t = texture(file: \"{}\");\n    node d = diffuse(albedo: t.out);\n    surface = d.bsdf;\n}}\n\
         substance extra_transparency {{\n    node d = diffuse();\n    node m = mask(opacity: 0.5);\n    surface = d.bsdf;\n    mask = m.out;\n}}\n",
        texture.display()
    )
}

/// Three balls on a floor under a dome and a sun, all opaque plain materials, plus a sphere of
/// radius 0.01 fifty units below the floor bound to `extra_<feature>`: the scene contains the
/// feature, but nothing the camera sees uses it.
fn features_scene(feature: &str, file: &str) -> String {
    let mut s = String::from(
        r#"#usda 1.0
(
    upAxis = "Y"
)
def Xform "World"
{
    def Camera "Camera"
    {
        float focalLength = 35
        float horizontalAperture = 36
        float verticalAperture = 24
        float3 xformOp:translate = (0, 2, 7)
        float3 xformOp:rotateXYZ = (-12, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
    def DomeLight "Sky"
    {
        float inputs:intensity = 0.8
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 2
        float inputs:angle = 3
        float3 xformOp:rotateXYZ = (-50, 30, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }
    def Mesh "Floor"
    {
        rel material:slotBinding:_000 = </Looks/plain_diffuse>
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-20, 0, -20), (20, 0, -20), (20, 0, 20), (-20, 0, 20)]
    }
"#,
    );
    for (i, x) in [-2.2f32, 0.0, 2.2].iter().enumerate() {
        let look = if i == 1 { "plain_glossy" } else { "plain_diffuse" };
        writeln!(
            s,
            "    def Sphere \"Ball{i}\"\n    {{\n        rel material:slotBinding:_000 = </Looks/{look}>\n        \
             double radius = 1\n        float3 xformOp:translate = ({x}, 1, 0)\n        \
             uniform token[] xformOpOrder = [\"xformOp:translate\"]\n    }}"
        )
        .unwrap();
    }
    writeln!(
        s,
        "    def Sphere \"Extra\"\n    {{\n        rel material:slotBinding:_000 = </Looks/extra_{feature}>\n        \
         double radius = 0.01\n        float3 xformOp:translate = (0, -50, 0)\n        \
         uniform token[] xformOpOrder = [\"xformOp:translate\"]\n    }}\n}}\n\ndef Scope \"Looks\"\n{{"
    )
    .unwrap();
    for name in ["plain_diffuse", "plain_glossy", &format!("extra_{feature}")] {
        writeln!(
            s,
            "    def Material \"{name}\"\n    {{\n        def Shader \"Surface\"\n        {{\n            \
             uniform token info:implementationSource = \"sourceAsset\"\n            \
             uniform asset info:strata:sourceAsset = @{file}@\n            \
             uniform token info:strata:sourceAsset:subIdentifier = \"{name}\"\n        }}\n    }}"
        )
        .unwrap();
    }
    s += "}\n";
    s
}

/// Features of `bench features`, the first being the baseline without any.
pub const FEATURES: [&str; 5] = ["none", "aov", "displacement", "texture", "transparency"];

/// `strata bench features`: what a scene pays for features it contains but does not use where
/// the camera looks. Each variant adds one material with the feature (AOV, displacement,
/// texture, transparency) on an invisible sphere; the time per sample and the shader calls per
/// sample must match the baseline's within noise. Returns the printed report.
pub fn bench_features(res: (usize, usize), spp: u32, reps: usize) -> Result<String, String> {
    let rows = measure_features(res, spp, reps)?;
    let mut out = String::new();
    writeln!(
        out,
        "bench features: {}x{} at {spp} spp, JIT, 1 thread (median of {reps}, variants interleaved); each variant adds one \
         material with the feature on an invisible sphere",
        res.0, res.1
    )
    .unwrap();
    writeln!(
        out,
        "  {:<14} {:>10} {:>9} {:>8} {:>8} {:>9} {:>8} {:>8} {:>8}",
        "feature", "ns/sample", "vs none", "masks", "shadow", "surfaces", "displ", "normals", "AOVs"
    )
    .unwrap();
    for r in &rows {
        let e = &r.evals;
        let per = |n: u64| n as f64 / r.samples.max(1) as f64;
        writeln!(
            out,
            "  {:<14} {:>10.0} {:>8.2}x {:>8.3} {:>8.3} {:>9.3} {:>8.3} {:>8.3} {:>8.3}",
            r.feature,
            r.ns,
            r.ns / rows[0].ns,
            per(e.masks),
            per(e.shadow_masks),
            per(e.surfaces),
            per(e.displacements),
            per(e.normals),
            per(e.channels)
        )
        .unwrap();
    }
    Ok(out)
}

/// One variant of `bench features`.
pub(super) struct FeatureRow {
    pub(super) feature: &'static str,
    /// Median ns per camera sample.
    pub(super) ns: f64,
    pub(super) evals: strata::render::integrator::EvalCounts,
    pub(super) samples: u64,
}

pub(super) fn measure_features(res: (usize, usize), spp: u32, reps: usize) -> Result<Vec<FeatureRow>, String> {
    let dir = TempDir::new()?;
    let texture = dir.0.join("texture.exr");
    exr::prelude::write_rgb_file(&texture, 4, 4, |x, y| (x as f32 / 4.0, y as f32 / 4.0, 0.5))
        .map_err(|e| format!("cannot write {}: {e}", texture.display()))?;
    std::fs::write(dir.0.join("features.ash"), features_source(&texture))
        .map_err(|e| format!("cannot write the benchmark substances: {e}"))?;
    let mut scenes = Vec::new();
    for feature in FEATURES {
        let usda = dir.0.join(format!("{feature}.usda"));
        std::fs::write(&usda, features_scene(feature, "features.ash"))
            .map_err(|e| format!("cannot write {}: {e}", usda.display()))?;
        scenes.push((feature, load_scene(&usda)?));
    }
    let settings = RenderSettings {
        width: res.0,
        height: res.1,
        spp,
        seed: 1,
        threads: Some(1),
        max_depth: 6,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    let mut times = vec![Vec::new(); scenes.len()];
    let mut evals = vec![strata::render::integrator::EvalCounts::default(); scenes.len()];
    let mut samples = vec![0u64; scenes.len()];
    for rep in 0..=reps {
        for (k, (_, l)) in scenes.iter().enumerate() {
            let materials: Vec<&dyn MaterialCode> = l.materials.iter().map(|m| m.as_ref()).collect();
            let start = Instant::now();
            let (_, stats) =
                strata::render::render(&l.scene, &materials, &settings, None).map_err(|e| e.to_string())?;
            let ns = start.elapsed().as_secs_f64() * 1e9 / stats.samples.max(1) as f64;
            // Repetition 0 is the warm-up.
            if rep > 0 {
                times[k].push(ns);
            }
            (evals[k], samples[k]) = (stats.evals, stats.samples);
        }
    }
    Ok(scenes
        .iter()
        .enumerate()
        .map(|(k, (feature, _))| FeatureRow {
            feature,
            ns: median(std::mem::take(&mut times[k])),
            evals: evals[k],
            samples: samples[k],
        })
        .collect())
}
