//! `strata bench shade`: the built-in benchmark material, its hand-written Rust twin, the
//! arithmetic and loop-budget materials, and the compile-time sweep.

use super::*;

/// The built-in benchmark material: three substances, composed bottom to top in this order.
pub const BENCH_SOURCE: &str = r#"// strata's built-in shading benchmark: three layers.

// A soft threshold: 0 below `edge`, 1 above `edge + softness`.
shader threshold(float value = 0.0, float edge = 0.5, float softness = 0.1, output float out) {
    out = smoothstep(edge, edge + max(softness, 1e-4), value);
}

// Bottom: a glossy base, always opaque.
substance bench_glossy {
    node coat = glossy(albedo: color(0.55, 0.5, 0.45), roughness: 0.35);
    surface = coat.bsdf;
}

// Middle: dirt masked by thresholded fbm, its colour a noise-driven mix.
substance bench_dirt {
    node grime = fbm(scale: 4.0, octaves: 4);
    node amount = threshold(value: grime.out, edge: 0.5, softness: 0.15);
    node opacity = mask(opacity: amount.out);
    node tint = noise(scale: 8.0);
    node colour = mix(a: color(0.25, 0.18, 0.1), b: color(0.5, 0.42, 0.3), t: tint.out);
    node base = diffuse(albedo: colour.out);
    surface = base.bsdf;
    mask = opacity.out;
}

// Top: metal flakes around the feature points of cellular noise.
substance bench_metal {
    node cells = cellular(scale: 6.0);
    node edge = threshold(value: cells.out, edge: 0.25, softness: 0.1);
    node flakes = math(a: edge.out, op: "invert");
    node opacity = mask(opacity: flakes.out);
    node conductor = metal(reflectivity: color(0.95, 0.64, 0.54), edge_tint: color(1.0, 0.9, 0.8), roughness: 0.25);
    surface = conductor.bsdf;
    mask = opacity.out;
}
"#;

/// The substances of [`BENCH_SOURCE`], bottom to top.
const BENCH_LAYERS: [&str; 3] = ["bench_glossy", "bench_dirt", "bench_metal"];

/// Shading points of `strata bench shade`.
const SHADE_POINTS: usize = 1 << 16;

/// Graph sizes of the compile-time sweep.
pub(super) const GRAPH_SIZES: [usize; 5] = [10, 50, 100, 1000, 10000];

// ---- The hand-written benchmark material ------------------------------------------------------

/// [`BENCH_SOURCE`] written by hand in Rust, instance constants folded: what the JIT should match.
pub struct HandMaterial {
    info: MaterialInfo,
}

impl Default for HandMaterial {
    fn default() -> Self {
        let layer = |slot: &str, constant_mask| LayerInfo {
            slot: slot.into(),
            has_surface: true,
            displacement: None,
            displacement_bound: None,
            has_normal: false,
            constant_mask,
            has_emission: false,
            pruned: None,
        };
        HandMaterial {
            info: MaterialInfo {
                layers: vec![layer("000", Some(1.0)), layer("010", None), layer("020", None)],
                channels: Vec::new(),
                channel_floats: 0,
                ..MaterialInfo::default()
            },
        }
    }
}

/// `threshold(value, edge, softness)` with `edge + max(softness, 1e-4)` folded to `edge1`.
#[inline(always)]
fn threshold(value: f32, edge: f32, edge1: f32) -> f32 {
    math::smoothstep(edge, edge1, value)
}

/// The `mask` node followed by the clamp of the `masks` entry.
#[inline(always)]
fn mask_out(opacity: f32) -> f32 {
    let m = math::clamp(opacity, 0.0, 1.0);
    math::min(math::max(m, 0.0), 1.0)
}

/// `fbm(scale: 4, octaves: 4)` with lacunarity 2 and gain 0.5: amplitudes and their total
/// (0.9375) folded.
#[inline(always)]
fn fbm4(p: [f32; 3]) -> f32 {
    let mut q = [p[0] * 4.0, p[1] * 4.0, p[2] * 4.0];
    let mut sum = 0.0f32;
    for amplitude in [0.5f32, 0.25, 0.125, 0.0625] {
        sum += amplitude * noise::noise3(q[0], q[1], q[2]);
        q = [q[0] * 2.0, q[1] * 2.0, q[2] * 2.0];
    }
    sum / 0.9375
}

fn closure(kind: ClosureKind, params: &[f32]) -> Closure {
    let mut c = Closure { kind: kind as u32, params: [0.0; 8] };
    c.params[..params.len()].copy_from_slice(params);
    c
}

impl MaterialCode for HandMaterial {
    fn info(&self) -> &MaterialInfo {
        &self.info
    }

    fn masks(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        for (layer, o) in out.iter_mut().enumerate().take(3) {
            *o = self.mask(g, layer)?;
        }
        Ok(())
    }

    fn mask(&self, g: &Globals, layer: usize) -> Result<f32, ShaderError> {
        const DIRT_EDGE1: f32 = 0.5 + 0.15;
        const FLAKE_EDGE1: f32 = 0.25 + 0.1;
        Ok(match layer {
            0 => 1.0,
            1 => mask_out(threshold(fbm4(g.p), 0.5, DIRT_EDGE1)),
            2 => {
                let [x, y, z] = g.p;
                let cells = noise::cellular3(x * 6.0, y * 6.0, z * 6.0);
                mask_out(1.0 - threshold(cells, 0.25, FLAKE_EDGE1))
            }
            _ => 0.0,
        })
    }

    fn surface(&self, g: &Globals, layer: usize, out: &mut Closure) -> Result<(), ShaderError> {
        *out = match layer {
            0 => closure(ClosureKind::Glossy, &[0.55, 0.5, 0.45, 1.0, 1.0, 1.0, 0.35, 1.5]),
            1 => {
                let [x, y, z] = g.p;
                let t = math::clamp(noise::noise3(x * 8.0, y * 8.0, z * 8.0), 0.0, 1.0);
                let (a, b) = ([0.25f32, 0.18, 0.1], [0.5f32, 0.42, 0.3]);
                let lane = |k: usize| math::clamp(a[k] + (b[k] - a[k]) * t, 0.0, 1.0);
                closure(ClosureKind::Diffuse, &[lane(0), lane(1), lane(2)])
            }
            2 => closure(ClosureKind::Metal, &[0.95, 0.64, 0.54, 1.0, 0.9, 0.8, 0.25]),
            _ => Closure::default(),
        };
        Ok(())
    }

    fn displacement(&self, _g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        out.fill(0.0);
        Ok(())
    }

    fn normal(&self, g: &Globals, _layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        *out = g.n;
        Ok(())
    }

    fn emission(&self, _g: &Globals, _layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        *out = [0.0; 3];
        Ok(())
    }

    fn channels(&self, _g: &Globals, _layer: usize, out: &mut [f32]) -> Result<(), ShaderError> {
        out.fill(0.0);
        Ok(())
    }
}

// ---- The hand-written arithmetic material -----------------------------------------------------

/// `leaf(k)` of [`arithmetic_substance`]: `P[0] * k + P[1] * (1 - k) - P[2] * 0.5`, with
/// `1 - k` folded in f32 as the compiler folds it.
#[inline(always)]
fn leaf(p: [f32; 3], k: f32) -> f32 {
    p[0] * k + p[1] * (1.0 - k) - p[2] * 0.5
}

/// [`arithmetic_substance`]`(64)` written out in Rust, node by node from the leaves (`n63`) to
/// the root (`n0`), constants folded: the arithmetic-bound contender of `bench shade`. Written
/// once from the generator's tree (node `i` reads `2i+1` and `2i+2`); checked against the JIT
/// on every point before it is timed, so a change to the generator cannot go unnoticed.
// `abs` nodes ignore their second input, which the graph's dead-code elimination removes.
#[allow(unused_variables)]
#[inline(never)]
fn arithmetic_hand(p: [f32; 3]) -> f32 {
    let n63 = leaf(p, 0.993);
    let n62 = leaf(p, 0.982);
    let n61 = leaf(p, 0.971);
    let n60 = leaf(p, 0.960);
    let n59 = leaf(p, 0.949);
    let n58 = leaf(p, 0.938);
    let n57 = leaf(p, 0.927);
    let n56 = leaf(p, 0.916);
    let n55 = leaf(p, 0.905);
    let n54 = leaf(p, 0.894);
    let n53 = leaf(p, 0.883);
    let n52 = leaf(p, 0.872);
    let n51 = leaf(p, 0.861);
    let n50 = leaf(p, 0.850);
    let n49 = leaf(p, 0.839);
    let n48 = leaf(p, 0.828);
    let n47 = leaf(p, 0.817);
    let n46 = leaf(p, 0.806);
    let n45 = leaf(p, 0.795);
    let n44 = leaf(p, 0.784);
    let n43 = leaf(p, 0.773);
    let n42 = leaf(p, 0.762);
    let n41 = leaf(p, 0.751);
    let n40 = leaf(p, 0.740);
    let n39 = leaf(p, 0.729);
    let n38 = leaf(p, 0.718);
    let n37 = leaf(p, 0.707);
    let n36 = leaf(p, 0.696);
    let n35 = leaf(p, 0.685);
    let n34 = leaf(p, 0.674);
    let n33 = leaf(p, 0.663);
    let n32 = leaf(p, 0.652);
    let n31 = n63 * 0.7;
    let n30 = n61 + n62;
    let n29 = n59.abs();
    let n28 = math::min(n57, n58);
    let n27 = n55 + (n56 - n55) * 0.3;
    let n26 = n53 - n54;
    let n25 = n51 * n52;
    let n24 = n49 + n50;
    let n23 = n47 + (n48 - n47) * 0.3;
    let n22 = math::min(n45, n46);
    let n21 = math::max(n43, n44);
    let n20 = n41 - n42;
    let n19 = n39 + (n40 - n39) * 0.3;
    let n18 = n37 + n38;
    let n17 = n35.abs();
    let n16 = math::min(n33, n34);
    let n15 = n31 + (n32 - n31) * 0.3;
    let n14 = n29 - n30;
    let n13 = n27 * n28;
    let n12 = n25 + n26;
    let n11 = n23 + (n24 - n23) * 0.3;
    let n10 = math::min(n21, n22);
    let n9 = math::max(n19, n20);
    let n8 = n17 - n18;
    let n7 = n15 + (n16 - n15) * 0.3;
    let n6 = n13 + n14;
    let n5 = n11.abs();
    let n4 = math::min(n9, n10);
    let n3 = n7 + (n8 - n7) * 0.3;
    let n2 = n5 - n6;
    let n1 = n3 * n4;
    n1 + n2 // n0
}

/// The arithmetic material by hand: one layer whose mask is [`arithmetic_hand`], clamped as the
/// `mask` node and the `masks` entry clamp it, over a constant grey diffuse surface.
pub struct HandArithmetic {
    info: MaterialInfo,
}

impl HandArithmetic {
    /// The hand material with the layer metadata of the compiled one (`info`).
    pub fn new(info: MaterialInfo) -> Self {
        HandArithmetic { info }
    }
}

impl MaterialCode for HandArithmetic {
    fn info(&self) -> &MaterialInfo {
        &self.info
    }

    fn masks(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        if let Some(o) = out.first_mut() {
            *o = self.mask(g, 0)?;
        }
        Ok(())
    }

    fn mask(&self, g: &Globals, layer: usize) -> Result<f32, ShaderError> {
        Ok(if layer == 0 { mask_out(arithmetic_hand(g.p)) } else { 0.0 })
    }

    fn surface(&self, _g: &Globals, layer: usize, out: &mut Closure) -> Result<(), ShaderError> {
        *out = if layer == 0 { closure(ClosureKind::Diffuse, &[0.5, 0.5, 0.5]) } else { Closure::default() };
        Ok(())
    }

    fn displacement(&self, _g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        out.fill(0.0);
        Ok(())
    }

    fn normal(&self, g: &Globals, _layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        *out = g.n;
        Ok(())
    }

    fn emission(&self, _g: &Globals, _layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        *out = [0.0; 3];
        Ok(())
    }

    fn channels(&self, _g: &Globals, _layer: usize, out: &mut [f32]) -> Result<(), ShaderError> {
        out.fill(0.0);
        Ok(())
    }
}

/// Masks plus every surface: what the renderer computes per path vertex in weighted mode.
/// Returns a checksum so nothing is optimised away.
fn shade_weighted(m: &dyn MaterialCode, g: &Globals, surfaces: &[usize], masks: &mut [f32]) -> f32 {
    let mut c = Closure::default();
    let _ = m.masks(g, masks);
    let mut acc: f32 = masks.iter().sum();
    for &l in surfaces {
        let _ = m.surface(g, l, &mut c);
        acc += c.params[0];
    }
    acc
}

/// Masks plus the surface of one layer picked with the layer weights (DESIGN.md rule 5).
fn shade_stochastic(m: &dyn MaterialCode, g: &Globals, xi: f32, masks: &mut [f32]) -> f32 {
    let _ = m.masks(g, masks);
    let mut xi = xi;
    let mut remaining = 1.0f32;
    for l in (0..masks.len()).rev() {
        let w = masks[l] * remaining;
        if xi < w {
            let mut c = Closure::default();
            let _ = m.surface(g, l, &mut c);
            return c.params[0];
        }
        xi -= w;
        remaining *= 1.0 - masks[l];
    }
    0.0
}

/// Checks that two materials agree on masks and closures at `points` within `tol`.
pub fn compare_materials(
    a: &dyn MaterialCode,
    b: &dyn MaterialCode,
    points: &[Globals],
    tol: f32,
) -> Result<(), String> {
    let n = a.info().layers.len();
    if b.info().layers.len() != n {
        return Err(format!("layer counts differ: {n} vs {}", b.info().layers.len()));
    }
    let (mut ma, mut mb) = (vec![0.0; n], vec![0.0; n]);
    for (k, g) in points.iter().enumerate() {
        a.masks(g, &mut ma).map_err(|e| e.to_string())?;
        b.masks(g, &mut mb).map_err(|e| e.to_string())?;
        for l in 0..n {
            if (ma[l] - mb[l]).abs() > tol || ma[l].is_nan() != mb[l].is_nan() {
                return Err(format!("point {k} (P = {:?}): mask {l}: {} vs {}", g.p, ma[l], mb[l]));
            }
            let (mut ca, mut cb) = (Closure::default(), Closure::default());
            a.surface(g, l, &mut ca).map_err(|e| e.to_string())?;
            b.surface(g, l, &mut cb).map_err(|e| e.to_string())?;
            let close = ca.params.iter().zip(&cb.params).all(|(x, y)| (x - y).abs() <= tol);
            if ca.kind != cb.kind || !close {
                return Err(format!("point {k} (P = {:?}): surface {l}: {ca:?} vs {cb:?}", g.p));
            }
        }
    }
    Ok(())
}

/// Loads [`BENCH_SOURCE`] and composes its three substances bottom to top.
pub fn bench_material() -> Result<(Library, ComposedMaterial), String> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("bench.ash", BENCH_SOURCE, &mut sources, &mut diags);
    if diags.has_errors() {
        return Err(diag_error("the benchmark material does not compile", &diags, &sources));
    }
    let names: Vec<&str> = BENCH_LAYERS.to_vec();
    let material = single_layer_stack(&lib, &names)?;
    Ok((lib, material))
}

/// Composes the named substances as layers `000`, `010`, … bottom to top, without overrides.
fn single_layer_stack(lib: &Library, names: &[&str]) -> Result<ComposedMaterial, String> {
    let layers = names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let graph = lib.graph_by_name(name).ok_or_else(|| format!("no substance `{name}`"))?;
            Ok(ComposedLayer {
                slot: Slot::parse(&format!("{:03}", i * 10))?,
                substance: MaterialRef {
                    path: format!("/Looks/{name}"),
                    graph,
                    values: Vec::new(),
                    span: Span::default(),
                },
                overrides: Vec::new(),
                vertical: Vec::new(),
            })
        })
        .collect::<Result<Vec<_>, String>>()?;
    Ok(ComposedMaterial { layers, ..Default::default() })
}

/// Wires, optimises and lowers a composed material.
pub(super) fn lower_material(
    lib: &Library,
    material: &ComposedMaterial,
) -> Result<(strata::ir::ssa::Module, usize), String> {
    lower_material_with(lib, material, lower::LowerOptions::default())
}

/// [`lower_material`] with explicit lowering options.
fn lower_material_with(
    lib: &Library,
    material: &ComposedMaterial,
    options: lower::LowerOptions,
) -> Result<(strata::ir::ssa::Module, usize), String> {
    let mut diags = Diagnostics::new();
    let wired = wired::build(lib, material, PassOptions::default(), &mut diags);
    let module = lower::lower(lib, &wired, options, &mut diags);
    if diags.has_errors() {
        return Err(diag_error("the material does not lower", &diags, &SourceMap::new()));
    }
    let nodes = wired.nodes.len();
    Ok((module, nodes))
}

// ---- bench shade ------------------------------------------------------------------------------

/// What one `bench shade` run measures (the tests use tiny values).
#[derive(Clone, Debug)]
pub(super) struct ShadeOptions {
    pub(super) points: usize,
    pub(super) reps: usize,
    pub(super) sizes: Vec<usize>,
    pub(super) compile_reps: usize,
}

/// `strata bench shade [SCENE --prim PATH]`: per-shading-point cost of a composed material,
/// hand-written Rust (built-in material only) vs JIT vs interpreter, weighted and stochastic,
/// then compile time against graph size. Returns the printed report.
pub fn bench_shade(scene: Option<&Path>, prim: Option<&str>) -> Result<String, String> {
    let options = ShadeOptions { points: SHADE_POINTS, reps: 7, sizes: GRAPH_SIZES.to_vec(), compile_reps: 9 };
    shade_report(scene, prim, &options)
}

pub(super) fn shade_report(scene: Option<&Path>, prim: Option<&str>, o: &ShadeOptions) -> Result<String, String> {
    let mut out = String::new();
    let (lib, material, label) = match scene {
        None => {
            let (lib, material) = bench_material()?;
            (lib, material, "built-in benchmark material (3 layers: glossy, fbm-masked dirt, cellular metal)".into())
        }
        Some(path) => {
            let mut session = Session::open_default(SceneSource::File(path.to_path_buf()));
            if session.composition().is_none() || session.diagnostics().has_errors() {
                let message = format!("cannot compose {}", path.display());
                return Err(diag_error(&message, session.diagnostics(), session.sources()));
            }
            let Some(composition) = session.into_composition() else { unreachable!("composed above") };
            let (prim, material) = match prim {
                Some(p) => {
                    let m = composition
                        .material_of(p)
                        .ok_or_else(|| format!("`{p}` is not a renderable prim of {}", path.display()))?;
                    (p.to_string(), m.clone())
                }
                None => {
                    // The prim with the most layers.
                    let (i, _) = composition
                        .stacks
                        .iter()
                        .enumerate()
                        .max_by_key(|(i, _)| composition.materials[composition.prim_material[*i]].layers.len())
                        .ok_or_else(|| format!("{} has no renderable prim", path.display()))?;
                    let m = composition.materials[composition.prim_material[i]].clone();
                    (composition.stacks[i].prim.clone(), m)
                }
            };
            let label = format!("{} {prim} ({} layers)", path.display(), material.layers.len());
            (composition.library, material, label)
        }
    };

    let (module, nodes) = lower_material(&lib, &material)?;
    let insts = module.inst_count();
    let jit = backend::compile_module(module.clone(), BackendKind::Jit)?;
    let interp = backend::compile_module(module, BackendKind::Interp)?;
    let hand: Option<Arc<dyn MaterialCode>> = scene.is_none().then(|| Arc::new(HandMaterial::default()) as _);

    let points = sample_points(o.points, 0x5eed);
    compare_materials(jit.as_ref(), interp.as_ref(), &points, 1e-5)
        .map_err(|e| format!("JIT and interpreter disagree: {e}"))?;
    if let Some(hand) = &hand {
        compare_materials(hand.as_ref(), jit.as_ref(), &points, 1e-5)
            .map_err(|e| format!("hand-written Rust and JIT disagree: {e}"))?;
    }

    let nlayers = jit.info().layers.len();
    let surfaces: Vec<usize> = (0..nlayers).filter(|&l| jit.info().layers[l].has_surface).collect();
    let mut rng = SplitMix(0xfeed);
    let xis: Vec<f32> = (0..points.len()).map(|_| rng.unit()).collect();

    // Contenders in table order; measured interleaved, repetition by repetition.
    let mut contenders: Vec<(&str, &dyn MaterialCode)> = Vec::new();
    if let Some(hand) = &hand {
        contenders.push(("hand Rust", hand.as_ref()));
    }
    contenders.push(("JIT", jit.as_ref()));
    contenders.push(("interpreter", interp.as_ref()));
    let (weighted, stochastic) = time_contenders(&contenders, &points, &xis, o.reps);

    writeln!(out, "bench shade: {label}").unwrap();
    writeln!(
        out,
        "  {} wired nodes, {insts} lowered instructions, {} layers with a surface; {} points, median of {} reps",
        nodes,
        surfaces.len(),
        points.len(),
        o.reps
    )
    .unwrap();
    if hand.is_some() {
        writeln!(out, "  hand-written Rust = JIT = interpreter on every point (masks and closures within 1e-5)")
            .unwrap();
    } else {
        writeln!(out, "  JIT = interpreter on every point (masks and closures within 1e-5)").unwrap();
    }
    writeln!(out).unwrap();
    writeln!(out, "  {:<14} {:>22} {:>24}", "backend", "weighted ns/point", "stochastic ns/point").unwrap();
    writeln!(out, "  {:<14} {:>22} {:>24}", "", "(masks + all surfaces)", "(masks + one surface)").unwrap();
    for (k, (name, _)) in contenders.iter().enumerate() {
        writeln!(out, "  {:<14} {:>22.1} {:>24.1}", name, weighted[k], stochastic[k]).unwrap();
    }
    let j = contenders.iter().position(|(n, _)| *n == "JIT").unwrap_or(0);
    let i = contenders.len() - 1;
    writeln!(out).unwrap();
    if hand.is_some() {
        writeln!(
            out,
            "  JIT / hand Rust:    weighted {:.2}x, stochastic {:.2}x   (target 1.0-1.1x)",
            weighted[j] / weighted[0],
            stochastic[j] / stochastic[0]
        )
        .unwrap();
    }
    writeln!(
        out,
        "  interpreter / JIT:  weighted {:.1}x, stochastic {:.1}x   (target >= 20x)",
        weighted[i] / weighted[j],
        stochastic[i] / stochastic[j]
    )
    .unwrap();

    if scene.is_none() {
        out += &arithmetic_report(&points, o.reps)?;
        out += &loop_budget_report(&points, o.reps)?;
    }
    writeln!(out).unwrap();
    out += &compile_sweep(&o.sizes, o.compile_reps)?;
    Ok(out)
}

/// Median ns per point of each contender, weighted (masks + every surface) and stochastic
/// (masks + one picked surface), measured interleaved repetition by repetition after a warm-up.
pub(super) fn time_contenders(
    contenders: &[(&str, &dyn MaterialCode)],
    points: &[Globals],
    xis: &[f32],
    reps: usize,
) -> (Vec<f64>, Vec<f64>) {
    let Some((_, first)) = contenders.first() else { return (Vec::new(), Vec::new()) };
    let nlayers = first.info().layers.len();
    let surfaces: Vec<usize> = (0..nlayers).filter(|&l| first.info().layers[l].has_surface).collect();
    let mut weighted = vec![Vec::new(); contenders.len()];
    let mut stochastic = vec![Vec::new(); contenders.len()];
    let mut masks = vec![0.0f32; nlayers];
    let mut checksum = 0.0f32;
    for rep in 0..=reps {
        for (k, (_, m)) in contenders.iter().enumerate() {
            let start = Instant::now();
            for g in points {
                checksum += shade_weighted(*m, black_box(g), &surfaces, &mut masks);
            }
            let w = start.elapsed().as_secs_f64() * 1e9 / points.len() as f64;
            let start = Instant::now();
            for (g, &xi) in points.iter().zip(xis) {
                checksum += shade_stochastic(*m, black_box(g), xi, &mut masks);
            }
            let s = start.elapsed().as_secs_f64() * 1e9 / points.len() as f64;
            // Repetition 0 is the warm-up.
            if rep > 0 {
                weighted[k].push(w);
                stochastic[k].push(s);
            }
        }
    }
    black_box(checksum);
    (weighted.into_iter().map(median).collect(), stochastic.into_iter().map(median).collect())
}

/// Nodes of the arithmetic-only material.
pub(super) const ARITHMETIC_NODES: usize = 64;

/// A mask computed by `n` arithmetic nodes (`math` and `mix_float` over expressions of `P`,
/// no runtime-library calls): where the interpreter's own dispatch cost shows, which the
/// noise calls of the benchmark material (identical in every backend) hide.
pub fn arithmetic_substance(n: usize) -> String {
    let ops = ["add", "mul", "sub", "max", "min", "abs"];
    let header = "shader leaf(float k = 1.0, output float out = 0.0) {\n    \
                  out = P[0] * k + P[1] * (1.0 - k) - P[2] * 0.5;\n}\n";
    header.to_string()
        + &tree_substance("arithmetic", n, |i, children| match children {
            None => format!("leaf(k: {:.3})", 0.3 + i as f64 * 0.011),
            Some((a, None)) => format!("math(a: n{a}.out, b: 0.7, op: \"mul\")"),
            Some((a, Some(b))) if i % 4 == 3 => format!("mix_float(a: n{a}.out, b: n{b}.out, t: 0.3)"),
            Some((a, Some(b))) => format!("math(a: n{a}.out, b: n{b}.out, op: \"{}\")", ops[i % ops.len()]),
        })
}

/// A substance whose `n` pattern nodes form a binary tree (node `i` reads nodes `2i+1` and
/// `2i+2` where they exist) and whose mask reads the root. `node(i, children)` writes node
/// `i`'s expression: `None` for a leaf, `Some((a, b))` with its one or two children.
fn tree_substance(name: &str, n: usize, node: impl Fn(usize, Option<(usize, Option<usize>)>) -> String) -> String {
    let mut s = format!("substance {name} {{\n");
    for i in 0..n.max(1) {
        let (a, b) = (2 * i + 1, 2 * i + 2);
        let children = (a < n).then_some((a, (b < n).then_some(b)));
        writeln!(s, "    node n{i} = {};", node(i, children)).unwrap();
    }
    s += "    node opacity = mask(opacity: n0.out);\n";
    s += "    node base = diffuse(albedo: color(0.5, 0.5, 0.5));\n";
    s += "    surface = base.bsdf;\n    mask = opacity.out;\n}\n";
    s
}

/// A mask computed by a 64-iteration loop with a tiny body: the worst case for the loop
/// budget's per-iteration check.
const LOOP_SOURCE: &str = "
shader orbit(float k = 0.97, output float out = 0.0) {
    float x = P[0];
    float acc = 0.0;
    for (int i = 0; i < 64; i++) {
        x = x * k + 0.1;
        acc += x * x;
    }
    out = acc / 64.0;
}
substance looping {
    node o = orbit();
    node opacity = mask(opacity: o.out);
    node base = diffuse();
    surface = base.bsdf;
    mask = opacity.out;
}
";

/// What the loop budget (DESIGN: shaders cannot hang the renderer) costs: JIT with and without
/// it on [`LOOP_SOURCE`].
fn loop_budget_report(points: &[Globals], reps: usize) -> Result<String, String> {
    let (lib, material) = single_substance(LOOP_SOURCE, "looping")?;
    let mut codes = Vec::new();
    for loop_budget in [true, false] {
        let options = lower::LowerOptions { loop_budget, ..Default::default() };
        let (module, _) = lower_material_with(&lib, &material, options)?;
        codes.push(backend::compile_module(module, BackendKind::Jit)?);
    }
    compare_materials(codes[0].as_ref(), codes[1].as_ref(), points, 0.0)
        .map_err(|e| format!("the loop budget changed a result: {e}"))?;
    let [with, without] = time_first_mask([codes[0].as_ref(), codes[1].as_ref()], points, reps);
    Ok(format!(
        "\n  loop budget (64-iteration loop, 3-instruction body): JIT {with:.1} ns/point with the budget, \
         {without:.1} without: {:.2}x\n",
        with / without
    ))
}

/// Hand-written Rust vs JIT vs interpreter on [`arithmetic_substance`]`(64)`: lowered
/// instruction count and median ns per mask evaluation, after checking all three agree.
pub(super) fn arithmetic_costs(points: &[Globals], reps: usize) -> Result<(usize, [f64; 3]), String> {
    let (lib, material) = single_substance(&arithmetic_substance(ARITHMETIC_NODES), "arithmetic")?;
    let (module, _) = lower_material(&lib, &material)?;
    let insts = module.inst_count();
    let jit = backend::compile_module(module.clone(), BackendKind::Jit)?;
    let interp = backend::compile_module(module, BackendKind::Interp)?;
    compare_materials(jit.as_ref(), interp.as_ref(), points, 0.0)
        .map_err(|e| format!("JIT and interpreter disagree on the arithmetic material: {e}"))?;
    let hand = HandArithmetic::new(jit.info().clone());
    compare_materials(&hand, jit.as_ref(), points, 1e-5)
        .map_err(|e| format!("hand-written Rust and JIT disagree on the arithmetic material: {e}"))?;
    Ok((insts, time_first_mask([&hand as &dyn MaterialCode, jit.as_ref(), interp.as_ref()], points, reps)))
}

/// The arithmetic lines of `bench shade`.
fn arithmetic_report(points: &[Globals], reps: usize) -> Result<String, String> {
    let (insts, [hand_ns, jit_ns, interp_ns]) = arithmetic_costs(points, reps)?;
    Ok(format!(
        "\n  arithmetic only ({ARITHMETIC_NODES} math/mix nodes over P, {insts} instructions, no runtime calls):\n  \
         hand Rust {hand_ns:.1} ns/point, JIT {jit_ns:.1} ns/point, interpreter {interp_ns:.1} ns/point: \
         JIT / hand Rust {:.2}x, interpreter / JIT {:.1}x   (target >= 20x)\n",
        jit_ns / hand_ns,
        interp_ns / jit_ns
    ))
}

/// Loads `source` and composes its substance `name` as a one-layer material.
pub(super) fn single_substance(source: &str, name: &str) -> Result<(Library, ComposedMaterial), String> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text(&format!("{name}.ash"), source, &mut sources, &mut diags);
    if diags.has_errors() {
        return Err(diag_error(&format!("`{name}` does not compile"), &diags, &sources));
    }
    let material = single_layer_stack(&lib, &[name])?;
    Ok((lib, material))
}

/// Median ns per evaluation of layer 0's mask for each material, measured interleaved.
fn time_first_mask<const N: usize>(codes: [&dyn MaterialCode; N], points: &[Globals], reps: usize) -> [f64; N] {
    let mut times: [Vec<f64>; N] = std::array::from_fn(|_| Vec::new());
    let mut checksum = 0.0f32;
    for rep in 0..=reps {
        for (k, m) in codes.iter().enumerate() {
            let start = Instant::now();
            for g in points {
                checksum += m.mask(black_box(g), 0).unwrap_or(0.0);
            }
            // Repetition 0 is the warm-up.
            if rep > 0 {
                times[k].push(start.elapsed().as_secs_f64() * 1e9 / points.len() as f64);
            }
        }
    }
    black_box(checksum);
    times.map(median)
}

/// A substance whose pattern nodes form a binary tree `n` nodes large, read by its mask: noise
/// leaves (reading `P`, so nothing folds) combined by `math` and `mix_float` nodes.
pub fn generated_substance(n: usize) -> String {
    tree_substance("generated", n, |i, children| match children {
        None => format!("noise(scale: {:.3})", 1.0 + i as f64 * 0.013),
        Some((a, None)) => format!("math(a: n{a}.out, op: \"sin\")"),
        Some((a, Some(b))) => match i % 3 {
            0 => format!("math(a: n{a}.out, b: n{b}.out, op: \"add\")"),
            1 => format!("math(a: n{a}.out, b: n{b}.out, op: \"mul\")"),
            _ => format!("mix_float(a: n{a}.out, b: n{b}.out, t: 0.3)"),
        },
    })
}

/// Compile time against graph size: parse + check, compose (wire + fold + lower), JIT codegen.
fn compile_sweep(sizes: &[usize], reps: usize) -> Result<String, String> {
    compile_sweep_rows(sizes, reps).map(|(text, _)| text)
}

/// One size of the compile sweep: nodes, lowered instructions, median parse, compose and
/// codegen ms.
#[derive(Clone, Copy, Debug)]
pub(super) struct CompileRow {
    pub(super) nodes: usize,
    pub(super) insts: usize,
    pub(super) parse: f64,
    pub(super) compose: f64,
    pub(super) codegen: f64,
}

/// [`compile_sweep`]'s report and its rows.
pub(super) fn compile_sweep_rows(sizes: &[usize], reps: usize) -> Result<(String, Vec<CompileRow>), String> {
    let mut rows = Vec::new();
    let mut out = String::new();
    writeln!(out, "compile time vs graph size (tree of noise/math/mix_float nodes reading P; median of runs)").unwrap();
    writeln!(
        out,
        "  {:>6} {:>6} {:>7} {:>10} {:>11} {:>11} {:>11} {:>10} {:>10}",
        "nodes", "runs", "insts", "parse ms", "compose ms", "codegen ms", "total ms", "compose", "codegen"
    )
    .unwrap();
    writeln!(
        out,
        "  {:>6} {:>6} {:>7} {:>10} {:>11} {:>11} {:>11} {:>10} {:>10}",
        "", "", "", "", "", "", "(c+j)", "us/node", "us/node"
    )
    .unwrap();
    let mut fifty = None;
    for &n in sizes {
        let source = generated_substance(n);
        let runs = if n >= 10_000 {
            1
        } else if n >= 1000 {
            reps.clamp(1, 3)
        } else {
            reps.max(1)
        };
        let (mut parse, mut compose, mut codegen, mut total) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut insts = 0;
        for _ in 0..runs {
            let start = Instant::now();
            let mut sources = SourceMap::new();
            let mut diags = Diagnostics::new();
            let (lib, _) = Library::from_text("generated.ash", &source, &mut sources, &mut diags);
            if diags.has_errors() {
                return Err(diag_error("the generated substance does not compile", &diags, &sources));
            }
            parse.push(ms_since(start));
            let material = single_layer_stack(&lib, &["generated"])?;
            let start = Instant::now();
            let (module, _) = lower_material(&lib, &material)?;
            let c = ms_since(start);
            insts = module.inst_count();
            let start = Instant::now();
            let code = backend::jit::compile(&module)?;
            let j = ms_since(start);
            drop(black_box(code));
            compose.push(c);
            codegen.push(j);
            total.push(c + j);
        }
        let (p, c, j, t) = (median(parse), median(compose), median(codegen), median(total));
        rows.push(CompileRow { nodes: n, insts, parse: p, compose: c, codegen: j });
        if n == 50 {
            fifty = Some(t);
        }
        writeln!(
            out,
            "  {n:>6} {runs:>6} {insts:>7} {p:>10.3} {c:>11.3} {j:>11.3} {t:>11.3} {:>10.2} {:>10.2}",
            c * 1e3 / n as f64,
            j * 1e3 / n as f64
        )
        .unwrap();
    }
    if let Some(t) = fifty {
        writeln!(out, "  compose + JIT of the 50-node material: {t:.3} ms median (target <= 1 ms)").unwrap();
    }
    Ok((out, rows))
}
