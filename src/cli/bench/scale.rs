//! `strata bench scale`: scene file to first pixel, BVH build memory, instancing.

use super::*;

/// `count` unit spheres on a grid, bound round-robin to `compositions` diffuse substances of
/// `file` (see [`scale_source`]), under a dome.
pub fn scale_scene(count: usize, compositions: usize, file: &str) -> String {
    let mut s = String::from("#usda 1.0\n(\n    upAxis = \"Y\"\n)\ndef Xform \"World\" {\n");
    s += "    def Camera \"Cam\" { double3 xformOp:translate = (0, 30, 160)  uniform token[] xformOpOrder = [\"xformOp:translate\"] }\n";
    s += "    def DomeLight \"Sky\" { float inputs:intensity = 1 }\n";
    let side = (count as f64).sqrt().ceil() as usize;
    for i in 0..count {
        let (x, z) = ((i % side) as f64 * 2.5, (i / side) as f64 * 2.5);
        s += &format!(
            "    def Sphere \"S{i}\" {{ double3 xformOp:translate = ({x}, 1, {z})  uniform token[] xformOpOrder = [\"xformOp:translate\"]  rel material:slotBinding:_000 = </Looks/M{}> }}\n",
            i % compositions
        );
    }
    s += "}\ndef Scope \"Looks\" {\n";
    for k in 0..compositions {
        s += &format!(
            "    def Material \"M{k}\" {{ def Shader \"S\" {{ uniform token info:implementationSource = \"sourceAsset\"  uniform asset info:strata:sourceAsset = @{file}@  uniform token info:strata:sourceAsset:subIdentifier = \"m{k}\" }} }}\n"
        );
    }
    s + "}\n"
}

/// `compositions` diffuse substances `m0 …` of distinct albedos.
pub fn scale_source(compositions: usize) -> String {
    (0..compositions)
        .map(|k| {
            let a = (k % 10) as f32 / 10.0;
            format!(
                "substance m{k} {{ node d = diffuse(albedo: color({a:?}, 0.5, {:?})); surface = d.bsdf; }}\n",
                1.0 - a
            )
        })
        .collect()
}

/// A `n × n` grid mesh in the plane y = 0 (`2 n²` triangles) with `st`.
pub fn grid_mesh_scene(n: usize) -> String {
    let mut points = String::new();
    let mut st = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
            points += &format!("({}, 0, {}), ", u * 100.0 - 50.0, v * 100.0 - 50.0);
            st += &format!("({u}, {v}), ");
        }
    }
    let mut indices = String::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            indices += &format!("{}, {}, {}, {}, ", a, a + 1, a + n + 2, a + n + 1);
        }
    }
    let counts = "4, ".repeat(n * n);
    format!(
        "#usda 1.0\ndef Mesh \"Grid\" {{\n    uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [{}]\n    int[] faceVertexIndices = [{}]\n    point3f[] points = [{}]\n    texCoord2f[] primvars:st = [{}] (\n        interpolation = \"vertex\"\n    )\n}}\ndef DomeLight \"Sky\" {{}}\n",
        counts.trim_end_matches(", "),
        indices.trim_end_matches(", "),
        points.trim_end_matches(", "),
        st.trim_end_matches(", ")
    )
}

/// Peak resident memory of this process so far (`VmHWM`), in MiB; 0 where unknown.
fn peak_rss_mib() -> f64 {
    status_mib("VmHWM:")
}

/// Resident memory of this process now (`VmRSS`), in MiB; 0 where unknown.
fn rss_mib() -> f64 {
    status_mib("VmRSS:")
}

/// A `/proc/self/status` size field, in MiB; 0 where unknown.
fn status_mib(field: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find_map(|l| l.strip_prefix(field)).map(str::to_string))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

/// `strata bench scale`: time from scene file to first pixel and peak memory for sphere
/// scenes of growing size (every Sphere is analytic: nothing is tessellated), and BVH build
/// time and memory for a large triangle mesh. Sizes run in ascending order so that the peak
/// resident memory after each row is that row's.
pub fn bench_scale() -> Result<String, String> {
    let dir = TempDir::new()?;
    let write = |name: &str, text: &str| {
        let path = dir.0.join(name);
        std::fs::write(&path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        Ok::<PathBuf, String>(path)
    };
    let mut out = String::from(
        "bench scale: scene file to first pixel (to scene: parse, compose, JIT, geometry and BVH; then a 16x16 1-spp render)\n",
    );
    out += &format!(
        "  {:<34} {:>9} {:>12} {:>10} {:>10} {:>9}\n",
        "scene", "prims", "to scene ms", "render ms", "total ms", "peak MiB"
    );
    let compositions = 50;
    write("m.ash", &scale_source(compositions))?;
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 1,
        seed: 1,
        threads: None,
        max_depth: 4,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    // Composition alone (parse, stage, bindings), per prim, for the linearity line.
    let mut compose_us_per_prim = Vec::new();
    for count in [200usize, 2000, 20000] {
        let path = write(&format!("spheres{count}.usda"), &scale_scene(count, compositions, "m.ash"))?;
        let start = Instant::now();
        let mut session = Session::open_default(SceneSource::File(path.clone()));
        if session.composition().is_none() {
            return Err(diag_error("cannot compose the spheres", session.diagnostics(), session.sources()));
        }
        compose_us_per_prim.push(ms_since(start) * 1e3 / count as f64);
        drop(session);
        let start = Instant::now();
        let loaded = load_scene(&path)?;
        let load_ms = ms_since(start);
        let (render_s, _) = render_rgb(&loaded, &settings)?;
        out += &format!(
            "  {:<34} {:>9} {:>12.1} {:>10.1} {:>10.1} {:>9.0}\n",
            format!("{count} spheres, {compositions} compositions"),
            count,
            load_ms,
            render_s * 1e3,
            ms_since(start),
            peak_rss_mib()
        );
    }
    if let [_, two_thousand, twenty_thousand] = compose_us_per_prim[..] {
        let _ = writeln!(
            out,
            "  composition (parse, stage, bindings) per prim: {two_thousand:.1} us at 2000, {twenty_thousand:.1} us at 20000 (ratio {:.2}; 1 is linear)",
            twenty_thousand / two_thousand
        );
    }
    let n = 700;
    let path = write("grid.usda", &grid_mesh_scene(n))?;
    // The peak so far is the sphere rows': the mesh's growth is measured from what is
    // resident now, with the peak reset (Linux: `clear_refs` 5), not from that peak.
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let before = rss_mib();
    let start = Instant::now();
    let session = Session::open_default(SceneSource::File(path.clone()));
    let stage =
        session.stage().ok_or_else(|| diag_error("cannot load the grid", session.diagnostics(), session.sources()))?;
    let parse_ms = ms_since(start);
    let build_start = Instant::now();
    let mut diags = Diagnostics::new();
    let scene = Scene::from_stage(stage, &|_| Some(0), &mut diags)
        .ok_or_else(|| diag_error("cannot build the grid", &diags, session.sources()))?;
    let build_ms = ms_since(build_start);
    let triangles = scene.accel.triangle_count();
    let grown = (peak_rss_mib() - before).max(0.0);
    out += &format!(
        "\n  {triangles} triangles ({n}x{n} grid mesh): parse {parse_ms:.0} ms, triangles + BVH {build_ms:.0} ms, peak memory +{grown:.0} MiB ({:.0} B per triangle, parsed text included)\n",
        grown * 1048576.0 / triangles.max(1) as f64
    );
    out += &instancing_report(&dir.0)?;
    Ok(out)
}

/// `bench scale`'s instancing section: 10 000 point-instancer instances of a 100 352-triangle
/// grid against one copy of it (build time, bytes held by the BVHs and the instance table,
/// peak memory, a first render), and 2000 instanceable references to a sphere asset.
fn instancing_report(dir: &Path) -> Result<String, String> {
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        Ok::<PathBuf, String>(path)
    };
    let settings = RenderSettings {
        width: 64,
        height: 64,
        spp: 1,
        seed: 1,
        threads: None,
        max_depth: 2,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    let mib = |b: usize| b as f64 / 1048576.0;
    let n = 224;
    let one = grid_mesh_scene(n);
    let mesh = one.split("def DomeLight").next().unwrap_or_default().trim_end();
    let side = 100usize;
    let count = side * side;
    let mut positions = String::with_capacity(count * 24);
    for k in 0..count {
        let _ = write!(
            positions,
            "({}, {}, {}), ",
            (k % side) as f64 * 120.0 - 6000.0,
            (k % 7) as f64,
            (k / side) as f64 * 120.0 - 6000.0
        );
    }
    let field = format!(
        "#usda 1.0\ndef PointInstancer \"Field\" {{\n    rel prototypes = [</Field/Protos/Grid>]\n    int[] protoIndices = [{}]\n    point3f[] positions = [{}]\n    def Scope \"Protos\" {{\n{mesh}\n    }}\n}}\ndef DomeLight \"Sky\" {{}}\n",
        "0, ".repeat(count).trim_end_matches(", "),
        positions.trim_end_matches(", ")
    );
    let mut out = String::from(
        "\n  instancing: scene file to first pixel (64x64, 1 spp); bytes held by the BVHs (bottom levels | instance table and top level);\n  resident memory grown while the scene is loaded (stage, materials, geometry)\n",
    );
    let _ = writeln!(
        out,
        "  {:<44} {:>9} {:>10} {:>9} {:>12} {:>10} {:>9}",
        "scene", "triangles", "load ms", "render ms", "BLAS MiB", "TLAS MiB", "+RSS MiB"
    );
    let mut row = |label: &str, path: &Path| -> Result<(usize, usize), String> {
        let before = rss_mib();
        let start = Instant::now();
        let loaded = load_scene(path)?;
        let load_ms = ms_since(start);
        let (render_s, _) = render_rgb(&loaded, &settings)?;
        let (blas, tlas) = loaded.scene.accel.bytes();
        let _ = writeln!(
            out,
            "  {:<44} {:>9} {:>10.0} {:>9.1} {:>12.2} {:>10.2} {:>9.0}",
            label,
            loaded.scene.accel.triangle_count(),
            load_ms,
            render_s * 1e3,
            mib(blas),
            mib(tlas),
            rss_mib() - before
        );
        Ok((blas, tlas))
    };
    let (one_copy, _) = row(&format!("one {}-triangle grid", 2 * n * n), &write("grid_once.usda", &one)?)?;
    let (blas, tlas) = row(&format!("{count} instances of it (PointInstancer)"), &write("grid_field.usda", &field)?)?;
    // Two thousand references to one sphere asset, each instanceable.
    let mut spheres =
        String::from("#usda 1.0\nclass Xform \"Ball\" {\n    def Sphere \"S\" { double radius = 0.4 }\n}\n");
    for k in 0..2000 {
        let _ = write!(
            spheres,
            "def Xform \"B{k}\" (instanceable = true references = </Ball>) {{\n    double3 xformOp:translate = ({}, 0, {})\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n",
            (k % 50) as f64 - 25.0,
            (k / 50) as f64 - 20.0
        );
    }
    spheres += "def DomeLight \"Sky\" {}\n";
    row("2000 instanceable spheres", &write("instanced_spheres.usda", &spheres)?)?;
    let _ = writeln!(
        out,
        "  {count} instances hold {:.3}x one copy plus the instance table and top level ({:.1} MiB + {:.1} MiB)",
        (blas + tlas) as f64 / (one_copy + tlas) as f64,
        mib(one_copy),
        mib(tlas)
    );
    Ok(out)
}

// ---- bench charts -----------------------------------------------------------------------------

/// Writes `source` and [`layered_scene`] into `dir` as `name.ash`/`name.usda` and loads them.
pub(super) fn load_generated(
    dir: &Path,
    name: &str,
    n: usize,
    source: &str,
    backend: BackendKind,
) -> Result<Loaded, String> {
    let ash = dir.join(format!("{name}.ash"));
    let usda = dir.join(format!("{name}.usda"));
    std::fs::write(&ash, source).map_err(|e| format!("cannot write {}: {e}", ash.display()))?;
    std::fs::write(&usda, layered_scene(n, &format!("{name}.ash")))
        .map_err(|e| format!("cannot write {}: {e}", usda.display()))?;
    load_scene_with(Some(&usda), backend)
}
