//! `strata bench displacement`: true displacement's setup, memory and image error.

use super::*;

/// The scene of `bench displacement`: a unit sphere over a ground plane under a dome and a
/// sun, its material `ball` (`Plain` or `Rough`: fbm relief of ±0.12 moving the surface).
fn displacement_scene(ball: &str) -> String {
    format!(
        r#"#usda 1.0
(
    upAxis = "Y"
)
def Camera "Cam" {{
    float focalLength = 35
    float horizontalAperture = 20.955
    double3 xformOp:translate = (0, 1.6, 4.2)
    double3 xformOp:rotateXYZ = (-12, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}}
def Sphere "Ball" {{
    rel material:slotBinding:_000 = </Looks/{ball}>
    double3 xformOp:translate = (0, 1, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def Mesh "Ground" {{
    rel material:slotBinding:_000 = </Looks/Plain>
    uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-10, 0, 10), (10, 0, 10), (10, 0, -10), (-10, 0, -10)]
}}
def DomeLight "Sky" {{
    float inputs:intensity = 0.4
}}
def DistantLight "Sun" {{
    float inputs:intensity = 2.5
    double3 xformOp:rotateXYZ = (-50, 30, 0)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
}}
def Scope "Looks" {{
    def Material "Plain" {{
        def Shader "S" {{
            uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @d.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "Plain"
        }}
    }}
    def Material "Rough" {{
        def Shader "S" {{
            uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @d.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "Rough"
        }}
    }}
}}
"#
    )
}

const DISPLACEMENT_ASH: &str = r#"
substance Plain {
    node bsdf = diffuse(albedo: color(0.6, 0.6, 0.6));
    surface = bsdf.bsdf;
}
substance Rough {
    node bsdf = diffuse(albedo: color(0.7, 0.5, 0.3));
    node n = fbm(scale: 4.0, octaves: 5);
    node h = math(a: n.out, b: 0.24, op: "mul");
    node d = displacement(height: h.out, mode: "none", bound: 0.25);
    surface = bsdf.bsdf;
    displacement = d.out;
}
"#;

/// `strata bench displacement`: what one displaced object costs, and what the dicing rate
/// buys. A sphere with fbm relief over a plane, against the same sphere undisplaced: scene
/// setup time (median of 3), micro-triangles, the object's bytes of triangles and BVH and
/// the peak with dicing's scratch, render time, and the image's RMSE against a 0.5-pixel
/// dicing at the same seed (next to the noise floor: two seeds of that reference). Also the scene without displacement built
/// with and without its materials (dicing's check on a scene that has none).
pub fn bench_displacement(res: (usize, usize), spp: u32) -> Result<String, String> {
    let dir = TempDir::new()?;
    let write = |name: &str, text: &str| {
        let path = dir.0.join(name);
        std::fs::write(&path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        Ok::<PathBuf, String>(path)
    };
    write("d.ash", DISPLACEMENT_ASH)?;
    let plain = write("plain.usda", &displacement_scene("Plain"))?;
    let rough = write("rough.usda", &displacement_scene("Rough"))?;
    let settings = |seed| RenderSettings {
        width: res.0,
        height: res.1,
        spp,
        seed,
        threads: None,
        max_depth: 4,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    // Compiles once, builds `reps` times (median time), renders once.
    struct Row {
        setup_ms: f64,
        stats: Option<strata::render::geometry::displace::DisplacementStats>,
        bytes: usize,
        render_ms: f64,
        rgb: Vec<[f32; 3]>,
    }
    let measure = |path: &Path, rate: Option<f32>, seed: u64| -> Result<Row, String> {
        let mut session = Session::open_default(SceneSource::File(path.to_path_buf()));
        session.compile();
        let (Some(stage), Some(compiled)) = (session.stage(), session.compiled()) else {
            return Err(diag_error("cannot compile", session.diagnostics(), session.sources()));
        };
        let (sources, mut diags) = (session.sources(), Diagnostics::new());
        let refs: Vec<&dyn MaterialCode> = compiled.materials.iter().map(|m| m.as_ref()).collect();
        let options = strata::render::scene::SceneOptions {
            dicing: strata::render::geometry::displace::DicingOptions {
                rate: rate.unwrap_or(1.0),
                resolution: res,
                ..Default::default()
            },
            ..Default::default()
        };
        let lookup = |p: &str| compiled.prim_material.get(p).copied();
        let mut times = Vec::new();
        let mut scene = None;
        for _ in 0..3 {
            let start = Instant::now();
            let built = match rate {
                Some(_) => Scene::build(stage, &lookup, &refs, &options, &mut diags),
                None => Scene::from_stage_with(stage, &lookup, &options, &mut diags),
            };
            times.push(ms_since(start));
            scene = built;
        }
        let scene = scene.ok_or_else(|| diag_error("cannot build", &diags, sources))?;
        times.sort_by(f64::total_cmp);
        let loaded = Loaded { scene, materials: compiled.materials.clone(), max_layers: 1 };
        let (render_s, rgb) = render_rgb(&loaded, &settings(seed))?;
        Ok(Row {
            setup_ms: times[1],
            stats: loaded.scene.displacement.clone(),
            bytes: loaded.scene.accel.bytes().0,
            render_ms: render_s * 1e3,
            rgb,
        })
    };
    let mib = |b: usize| b as f64 / 1048576.0;
    let reference = measure(&rough, Some(0.5), 1)?;
    let other_seed = measure(&rough, Some(0.5), 2)?;
    let mut out = format!(
        "bench displacement: a unit sphere with fbm relief (±0.12) over a plane, {}x{} at {spp} spp, all cores; \
         RMSE against dicing at 0.5 px, same seed (noise floor, two seeds at 0.5 px: {:.4})\n",
        res.0,
        res.1,
        rmse(&reference.rgb, &other_seed.rgb)
    );
    out += &format!(
        "  {:<30} {:>10} {:>9} {:>8} {:>12} {:>9} {:>10} {:>8}\n",
        "scene", "micro-tris", "setup ms", "dice ms", "object MiB", "peak/obj", "render ms", "RMSE"
    );
    let base = measure(&plain, Some(1.0), 1)?;
    let mut line = |name: &str, row: &Row| {
        let (micro, dice_ms, scratch) =
            row.stats.as_ref().map_or((0, 0.0, 0), |s| (s.micro_triangles, s.ms, s.scratch_bytes));
        // The displaced object's own triangles and BVH: what the scene holds beyond the
        // undisplaced one; at its peak, displacement also held its scratch.
        let own = row.bytes.saturating_sub(base.bytes);
        let peak = if own > 0 { format!("{:.2}x", (own + scratch) as f64 / own as f64) } else { "-".into() };
        out += &format!(
            "  {:<30} {:>10} {:>9.1} {:>8.1} {:>12.2} {:>9} {:>10.1} {:>8.4}\n",
            name,
            micro,
            row.setup_ms,
            dice_ms,
            mib(own),
            peak,
            row.render_ms,
            rmse(&row.rgb, &reference.rgb)
        );
    };
    line("undisplaced (analytic sphere)", &base);
    for rate in [8.0f32, 4.0, 2.0, 1.0] {
        let row = measure(&rough, Some(rate), 1)?;
        line(&format!("displaced, dicing rate {rate} px"), &row);
    }
    line("displaced, dicing rate 0.5 px", &reference);
    out += "  (object MiB: the displaced sphere's triangles and BVH, all the memory displacement adds once built; \
            peak/obj: with dicing's scratch at its peak, over that)\n";
    // A scene without displacement: built with its materials (the dicing check runs) and
    // without them (it does not).
    let with = measure(&plain, Some(1.0), 1)?;
    let without = measure(&plain, None, 1)?;
    out += &format!(
        "  no displacement in the scene: setup {:.2} ms with materials vs {:.2} ms without ({:.3}x), render {:.1} vs \
         {:.1} ms, images identical: {}\n",
        with.setup_ms,
        without.setup_ms,
        with.setup_ms / without.setup_ms.max(1e-9),
        with.render_ms,
        without.render_ms,
        with.rgb == without.rgb
    );
    Ok(out)
}
