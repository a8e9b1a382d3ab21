//! The measurements behind `strata bench shade` and `strata bench render`.
//!
//! Timings use [`Instant`] with a warm-up, several repetitions and the median; everything a
//! table compares is measured in the same run, with the contenders interleaved per repetition
//! so that load from other processes affects them alike.
//!
//! - [`bench_shade`]: per-shading-point cost of a composed material, hand-written Rust vs JIT vs
//!   interpreter, and compile time against graph size.
//! - [`bench_render`]: time per sample and error against a high-spp reference for 1–16 layers,
//!   stochastic vs weighted layer evaluation.

use crate::cli::plot::Series;
use std::fmt::Write as _;
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;
use strata::abi::{Closure, ClosureKind, Globals, LayerInfo, MaterialCode, MaterialInfo, ShaderError};
use strata::backend::{self, BackendKind};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap, Span};
use strata::front::library::Library;
use strata::input::generated::{MaskKind, layered_scene, layered_source, mask_stack_source};
use strata::ir::lower;
use strata::ir::wired::{self, PassOptions};
use strata::render::{LayerMode, RenderSettings, Scene};
use strata::runtime::{math, noise};
use strata::session::{SceneSource, Session, SessionOptions};

mod layer;
mod update;

pub use layer::bench_layer;
pub use update::bench_update;

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
const GRAPH_SIZES: [usize; 5] = [10, 50, 100, 1000, 10000];

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

// ---- Helpers ----------------------------------------------------------------------------------

/// SplitMix64: a small deterministic generator for benchmark inputs.
struct SplitMix(u64);

impl SplitMix {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / 16_777_216.0)
    }
}

/// `n` pseudo-random shading points: `P` in [-2, 2]³, unit `N`, `u, v` in [0, 1].
pub fn sample_points(n: usize, seed: u64) -> Vec<Globals<'static>> {
    let mut rng = SplitMix(seed);
    (0..n)
        .map(|_| {
            let p = [(); 3].map(|_| rng.unit() * 4.0 - 2.0);
            let n = loop {
                let v = [(); 3].map(|_| rng.unit() * 2.0 - 1.0);
                let l2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
                if l2 > 1e-4 && l2 <= 1.0 {
                    let l = l2.sqrt();
                    break v.map(|c| c / l);
                }
            };
            let t = if n[0].abs() < 0.9 { [0.0, -n[2], n[1]] } else { [-n[2], 0.0, n[0]] };
            Globals {
                p,
                n,
                ng: n,
                i: n.map(|c| -c),
                dpdu: t,
                dpdv: [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]],
                u: rng.unit(),
                v: rng.unit(),
                primvars: Default::default(),
            }
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn ms_since(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

fn diag_error(what: &str, diags: &Diagnostics, sources: &SourceMap) -> String {
    format!("{what}:\n{}", diags.render(sources))
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
            })
        })
        .collect::<Result<Vec<_>, String>>()?;
    Ok(ComposedMaterial { layers, ..Default::default() })
}

/// Wires, optimises and lowers a composed material.
fn lower_material(lib: &Library, material: &ComposedMaterial) -> Result<(strata::ir::ssa::Module, usize), String> {
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
struct ShadeOptions {
    points: usize,
    reps: usize,
    sizes: Vec<usize>,
    compile_reps: usize,
}

/// `strata bench shade [SCENE --prim PATH]`: per-shading-point cost of a composed material,
/// hand-written Rust (built-in material only) vs JIT vs interpreter, weighted and stochastic,
/// then compile time against graph size. Returns the printed report.
pub fn bench_shade(scene: Option<&Path>, prim: Option<&str>) -> Result<String, String> {
    let options = ShadeOptions { points: SHADE_POINTS, reps: 7, sizes: GRAPH_SIZES.to_vec(), compile_reps: 9 };
    shade_report(scene, prim, &options)
}

fn shade_report(scene: Option<&Path>, prim: Option<&str>, o: &ShadeOptions) -> Result<String, String> {
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
fn time_contenders(
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
const ARITHMETIC_NODES: usize = 64;

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
fn arithmetic_costs(points: &[Globals], reps: usize) -> Result<(usize, [f64; 3]), String> {
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
fn single_substance(source: &str, name: &str) -> Result<(Library, ComposedMaterial), String> {
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
struct CompileRow {
    nodes: usize,
    insts: usize,
    parse: f64,
    compose: f64,
    codegen: f64,
}

/// [`compile_sweep`]'s report and its rows.
fn compile_sweep_rows(sizes: &[usize], reps: usize) -> Result<(String, Vec<CompileRow>), String> {
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

// ---- bench render -----------------------------------------------------------------------------

/// Layer counts of the `bench render` sweep.
const RENDER_LAYERS: [usize; 5] = [1, 2, 4, 8, 16];

/// A scene loaded, composed, compiled with the JIT and ready to render.
struct Loaded {
    scene: Scene,
    materials: Vec<Arc<dyn MaterialCode>>,
    max_layers: usize,
}

fn load_scene(path: &Path) -> Result<Loaded, String> {
    load_scene_with(Some(path), BackendKind::Jit)
}

/// Loads a scene (`None`: the embedded default scene) and compiles it with `backend`.
fn load_scene_with(path: Option<&Path>, backend: BackendKind) -> Result<Loaded, String> {
    let shown = path.map_or_else(|| "the default scene".to_string(), |p| p.display().to_string());
    let options = SessionOptions { backend, ..Default::default() };
    let mut session = Session::open(SceneSource::from_path(path), options);
    let fail =
        |session: &Session| diag_error(&format!("cannot load {shown}"), session.diagnostics(), session.sources());
    let max_layers = match session.composition() {
        Some(c) => c.materials.iter().map(|m| m.layers.len()).max().unwrap_or(0),
        None => return Err(fail(&session)),
    };
    // As `strata render` builds it: displaced surfaces diced (for a 640x480 image).
    if session.prepare(&Default::default()).is_none() || session.diagnostics().has_errors() {
        return Err(fail(&session));
    }
    let Some((scene, compiled)) = session.into_scene() else { unreachable!("prepared above") };
    Ok(Loaded { scene, materials: compiled.materials, max_layers })
}

/// Renders and returns (seconds, RGB pixels).
fn render_rgb(l: &Loaded, settings: &RenderSettings) -> Result<(f64, Vec<[f32; 3]>), String> {
    let materials: Vec<&dyn MaterialCode> = l.materials.iter().map(|m| m.as_ref()).collect();
    let start = Instant::now();
    let (image, _) = strata::render::render(&l.scene, &materials, settings, None).map_err(|e| e.to_string())?;
    let secs = start.elapsed().as_secs_f64();
    let channel = |name: &str| image.f32_channel(name).map(<[f32]>::to_vec).ok_or_else(|| format!("no {name} channel"));
    let (r, g, b) = (channel("R")?, channel("G")?, channel("B")?);
    Ok((secs, (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect()))
}

fn rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let sum: f64 = a.iter().zip(b).map(|(x, y)| (0..3).map(|k| f64::from(x[k] - y[k]).powi(2)).sum::<f64>()).sum();
    (sum / (3 * a.len().max(1)) as f64).sqrt()
}

/// One measured row of `bench render`.
struct RenderRow {
    label: String,
    layers: usize,
    /// ns per camera sample (single thread), stochastic and weighted.
    ns: [f64; 2],
    /// RMSE against the reference at equal spp, stochastic and weighted.
    rmse: [f64; 2],
}

/// Times both layer modes of every scene on one thread, interleaved repetition by repetition
/// (median of `reps` after a warm-up) so that outside load affects all rows alike, and
/// measures their error against a weighted reference at `16 × spp` with another seed.
fn measure_scenes(
    scenes: &[(String, Loaded)],
    spp: u32,
    res: (usize, usize),
    reps: usize,
) -> Result<Vec<RenderRow>, String> {
    let base = RenderSettings {
        width: res.0,
        height: res.1,
        spp,
        seed: 1,
        threads: Some(1),
        max_depth: 6,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    let reference = RenderSettings {
        spp: reference_spp(spp),
        seed: 0x5eed_0001,
        threads: None,
        mode: LayerMode::Weighted,
        ..base.clone()
    };
    let references =
        scenes.iter().map(|(_, l)| render_rgb(l, &reference).map(|r| r.1)).collect::<Result<Vec<_>, String>>()?;
    let modes = [LayerMode::Stochastic, LayerMode::Weighted];
    let mut times = vec![[Vec::new(), Vec::new()]; scenes.len()];
    let mut errors = vec![[0.0; 2]; scenes.len()];
    for rep in 0..=reps {
        for (i, (_, l)) in scenes.iter().enumerate() {
            for (k, &mode) in modes.iter().enumerate() {
                let settings = RenderSettings { mode, spp: if rep == 0 { 1 } else { spp }, ..base.clone() };
                let (secs, rgb) = render_rgb(l, &settings)?;
                if rep > 0 {
                    times[i][k].push(secs * 1e9 / (res.0 * res.1) as f64 / spp as f64);
                    errors[i][k] = rmse(&rgb, &references[i]);
                }
            }
        }
    }
    Ok(scenes
        .iter()
        .zip(times)
        .zip(errors)
        .map(|(((label, l), [s, w]), rmse)| RenderRow {
            label: label.clone(),
            layers: l.max_layers,
            ns: [median(s), median(w)],
            rmse,
        })
        .collect())
}

/// Samples per pixel of the reference image.
fn reference_spp(spp: u32) -> u32 {
    spp.saturating_mul(16).max(64)
}

/// A directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Result<TempDir, String> {
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!("strata-bench-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        Ok(TempDir(dir))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `strata bench render [SCENE]`: time per camera sample and RMSE against a high-spp weighted
/// reference, stochastic vs weighted layer evaluation. Without a scene, a generated sphere
/// with 1, 2, 4, 8 and 16 noise-masked layers. Returns the printed report.
pub fn bench_render(scene: Option<&Path>, spp: u32, res: (usize, usize)) -> Result<String, String> {
    render_report(scene, spp, res, &RENDER_LAYERS, 5)
}

fn render_report(
    scene: Option<&Path>,
    spp: u32,
    res: (usize, usize),
    layer_counts: &[usize],
    reps: usize,
) -> Result<String, String> {
    if spp == 0 || res.0 == 0 || res.1 == 0 {
        return Err(format!(
            "bench render needs spp > 0 and a non-empty resolution, got {spp} spp at {}x{}",
            res.0, res.1
        ));
    }
    let mut scenes = Vec::new();
    match scene {
        Some(path) => scenes.push((path.display().to_string(), load_scene(path)?)),
        None => {
            let dir = TempDir::new()?;
            for &n in layer_counts {
                let ash = dir.0.join(format!("layers{n}.ash"));
                let usda = dir.0.join(format!("layers{n}.usda"));
                let file = ash.file_name().and_then(|f| f.to_str()).unwrap_or_default().to_string();
                std::fs::write(&ash, layered_source(n)).map_err(|e| format!("cannot write {}: {e}", ash.display()))?;
                std::fs::write(&usda, layered_scene(n, &file))
                    .map_err(|e| format!("cannot write {}: {e}", usda.display()))?;
                scenes.push((format!("{n} layer{}", if n == 1 { "" } else { "s" }), load_scene(&usda)?));
            }
        }
    }
    let rows = measure_scenes(&scenes, spp, res, reps)?;
    let mut out = String::new();
    writeln!(
        out,
        "bench render: {}x{} at {spp} spp, JIT, 1 thread timed (median of {reps}); reference: weighted at {} spp, other seed",
        res.0,
        res.1,
        reference_spp(spp)
    )
    .unwrap();
    writeln!(
        out,
        "  {:<28} {:>6} {:>13} {:>13} {:>11} {:>11} {:>10} {:>10} {:>9}",
        "scene",
        "layers",
        "stoch ns/smp",
        "wtd ns/smp",
        "stoch/1lay",
        "wtd/1lay",
        "stoch RMSE",
        "wtd RMSE",
        "wtd/stoch"
    )
    .unwrap();
    let first = rows.first().map_or([1.0; 2], |r| r.ns);
    for r in &rows {
        writeln!(
            out,
            "  {:<28} {:>6} {:>13.0} {:>13.0} {:>10.2}x {:>10.2}x {:>10.5} {:>10.5} {:>8.2}x",
            r.label,
            r.layers,
            r.ns[0],
            r.ns[1],
            r.ns[0] / first[0],
            r.ns[1] / first[1],
            r.rmse[0],
            r.rmse[1],
            r.ns[1] / r.ns[0]
        )
        .unwrap();
    }
    if scene.is_none()
        && let (Some(one), Some(eight)) = (rows.iter().find(|r| r.layers == 1), rows.iter().find(|r| r.layers == 8))
    {
        writeln!(
            out,
            "  8 layers / 1 layer, stochastic: {:.2}x (target <= 1.25x); ms per spp at 8 layers: {:.2} stochastic, {:.2} weighted",
            eight.ns[0] / one.ns[0],
            eight.ns[0] * (res.0 * res.1) as f64 * 1e-6,
            eight.ns[1] * (res.0 * res.1) as f64 * 1e-6
        )
        .unwrap();
    }
    Ok(out)
}

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
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find_map(|l| l.strip_prefix("VmHWM:")).map(str::to_string))
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
    for count in [200usize, 2000, 20000] {
        let path = write(&format!("spheres{count}.usda"), &scale_scene(count, compositions, "m.ash"))?;
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
    let n = 700;
    let path = write("grid.usda", &grid_mesh_scene(n))?;
    let before = peak_rss_mib();
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
    // Resident memory (`VmRSS`) now, in MiB: the peak is the earlier million-triangle row's.
    let rss_mib = || {
        std::fs::read_to_string("/proc/self/status")
            .ok()
            .and_then(|s| s.lines().find_map(|l| l.strip_prefix("VmRSS:")).map(str::to_string))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
            .map_or(0.0, |kb| kb / 1024.0)
    };
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
fn load_generated(dir: &Path, name: &str, n: usize, source: &str, backend: BackendKind) -> Result<Loaded, String> {
    let ash = dir.join(format!("{name}.ash"));
    let usda = dir.join(format!("{name}.usda"));
    std::fs::write(&ash, source).map_err(|e| format!("cannot write {}: {e}", ash.display()))?;
    std::fs::write(&usda, layered_scene(n, &format!("{name}.ash")))
        .map_err(|e| format!("cannot write {}: {e}", usda.display()))?;
    load_scene_with(Some(&usda), backend)
}

/// What one `bench charts` run measures (the tests use tiny values).
#[derive(Clone, Debug)]
pub struct ChartOptions {
    /// Layer counts of the layering charts.
    pub layers: Vec<usize>,
    /// Samples per pixel along each error-vs-time curve.
    pub spp: Vec<u32>,
    /// Image size of the layering charts.
    pub res: (usize, usize),
    /// Image size of the JIT-vs-interpreter chart (default scene).
    pub default_res: (usize, usize),
    /// Samples per pixel of every reference image.
    pub reference_spp: u32,
    /// Timed repetitions per point (median).
    pub reps: usize,
    /// Shading points and repetitions of the per-point cost chart.
    pub shade_points: usize,
    /// Graph sizes of the compile-time chart.
    pub sizes: Vec<usize>,
}

impl Default for ChartOptions {
    fn default() -> Self {
        ChartOptions {
            layers: vec![1, 4, 16, 64],
            spp: vec![1, 2, 4, 8, 16, 32],
            res: (56, 56),
            default_res: (64, 48),
            reference_spp: 1024,
            reps: 7,
            shade_points: 1 << 14,
            sizes: GRAPH_SIZES.to_vec(),
        }
    }
}

impl ChartOptions {
    /// Tiny images, short ladders, one repetition: every chart drawn in seconds (tests, smoke
    /// runs); the figures are noise.
    pub fn quick() -> Self {
        ChartOptions {
            layers: vec![1, 4],
            spp: vec![1, 2, 4],
            res: (8, 8),
            default_res: (8, 6),
            reference_spp: 16,
            reps: 1,
            shade_points: 256,
            sizes: vec![10, 50],
        }
    }
}

/// Error-vs-time curves of several contenders (a scene and its settings each): per spp of the
/// ladder, (ms per image on one thread, RMSE against `reference`). The contenders are measured
/// interleaved, spp by spp and repetition by repetition, so that load from other processes
/// affects them alike; the time is the fastest of `reps` (the least disturbed by that load)
/// and the RMSE the root of the mean squared error over the repetitions, each with its own
/// seed (one image's RMSE is itself noisy).
fn error_curves(
    contenders: &[(&Loaded, RenderSettings)],
    spp: &[u32],
    reference: &[[f32; 3]],
    reps: usize,
) -> Result<Vec<Vec<(f64, f64)>>, String> {
    let mut curves = vec![Vec::new(); contenders.len()];
    for &n in spp {
        let mut times = vec![f64::INFINITY; contenders.len()];
        let mut mse = vec![0.0; contenders.len()];
        // Repetition 0 is the warm-up.
        for rep in 0..=reps {
            for (k, (l, base)) in contenders.iter().enumerate() {
                let settings = RenderSettings { spp: n, seed: base.seed + rep as u64, ..base.clone() };
                let (secs, rgb) = render_rgb(l, &settings)?;
                if rep > 0 {
                    times[k] = times[k].min(secs * 1e3);
                    mse[k] += rmse(&rgb, reference).powi(2) / reps as f64;
                }
            }
        }
        for (k, curve) in curves.iter_mut().enumerate() {
            curve.push((times[k], mse[k].sqrt()));
        }
    }
    Ok(curves)
}

/// Formats a ratio pair of [`crate::cli::plot::equal_ratios`] for a caption.
fn ratio_text(a: &[(f64, f64)], b: &[(f64, f64)]) -> String {
    match crate::cli::plot::equal_ratios(a, b) {
        Some((e, t, how)) => format!("equal-time RMSE ratio {e:.2}, equal-RMSE time ratio {t:.2} ({how})"),
        None => "no ratio (empty curve)".into(),
    }
}

/// `strata bench charts --plot DIR`: measures and draws every chart of README's Charts section
/// into `dir` as SVG, and returns the printed report (the same ratios as the captions).
/// `mitsuba_csv`, when it exists, is `tools/compare_mitsuba.py`'s CSV (optional).
pub fn bench_charts(dir: &Path, mitsuba_csv: Option<&Path>, o: &ChartOptions) -> Result<String, String> {
    use crate::cli::plot::{Bar, bars, loglog};
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let mut out = String::new();
    let svg = |name: &str| dir.join(name);
    let tmp = TempDir::new()?;

    // (a) Stochastic picking vs weighted evaluation per layer count and mask kind.
    let base = RenderSettings {
        width: o.res.0,
        height: o.res.1,
        spp: 1,
        seed: 1,
        threads: Some(1),
        max_depth: 6,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    let reference_settings = RenderSettings {
        spp: o.reference_spp,
        seed: 0x5eed_0001,
        threads: None,
        mode: LayerMode::Weighted,
        ..base.clone()
    };
    let mut crossover = Vec::new();
    for (kc, kind) in MaskKind::ALL.into_iter().enumerate() {
        let mut cross = Vec::new();
        let mut series = Vec::new();
        let mut caption = vec![format!(
            "{}x{} px, spp {:?}, 1 thread, fastest of {} interleaved, RMSE over {} seeds; reference: weighted, {} spp. Ratios stochastic / weighted:",
            o.res.0, o.res.1, o.spp, o.reps, o.reps, o.reference_spp
        )];
        writeln!(out, "layering, {} masks ({}x{}; stochastic / weighted):", kind.name(), o.res.0, o.res.1).unwrap();
        for (c, &n) in o.layers.iter().enumerate() {
            let name = format!("{}{n}", kind.name());
            let l = load_generated(&tmp.0, &name, n, &mask_stack_source(n, kind), BackendKind::Jit)?;
            let (_, reference) = render_rgb(&l, &reference_settings)?;
            let modes = [(LayerMode::Stochastic, "stochastic"), (LayerMode::Weighted, "weighted")];
            let contenders: Vec<(&Loaded, RenderSettings)> =
                modes.iter().map(|&(mode, _)| (&l, RenderSettings { mode, ..base.clone() })).collect();
            let curves = error_curves(&contenders, &o.spp, &reference, o.reps)?;
            for ((mode, label), points) in modes.iter().zip(&curves) {
                series.push(Series {
                    label: format!("{n} layer{}, {label}", if n == 1 { "" } else { "s" }),
                    points: points.clone(),
                    color: c,
                    dashed: *mode == LayerMode::Weighted,
                });
            }
            let ratios = ratio_text(&curves[0], &curves[1]);
            if let Some((_, t, _)) = crate::cli::plot::equal_ratios(&curves[0], &curves[1]) {
                cross.push((n as f64, t));
            }
            writeln!(out, "  {n:>3} layers: {ratios}").unwrap();
            caption.push(format!("{n} layers: {ratios}"));
        }
        let file = format!("layering_{}.svg", kind.name());
        loglog(
            &svg(&file),
            &format!("Stochastic picking (solid) vs weighted evaluation (dashed), {} masks", kind.name()),
            "render time per image (ms, 1 thread)",
            "RMSE vs reference",
            &series,
            &caption,
        )?;
        crossover.push(Series { label: format!("{} masks", kind.name()), points: cross, color: kc, dashed: false });
    }
    let mut caption = vec![
        "Time stochastic picking needs for the RMSE weighted evaluation reaches in the same time, over weighted's (from the charts".into(),
        "above). Below 1 stochastic wins; above 1 weighted wins. The dashed line is 1.".into(),
    ];
    for s in &crossover {
        let pts: Vec<String> = s.points.iter().map(|(n, t)| format!("{n}: {t:.2}")).collect();
        caption.push(format!("{}: {}", s.label, pts.join(", ")));
    }
    let xs: Vec<f64> = crossover.iter().flat_map(|s| s.points.iter().map(|p| p.0)).collect();
    let (lo, hi) = (xs.iter().copied().fold(f64::INFINITY, f64::min), xs.iter().copied().fold(0.0, f64::max));
    crossover.push(Series {
        label: "1 (break-even)".into(),
        points: vec![(lo, 1.0), (hi, 1.0)],
        color: 7,
        dashed: true,
    });
    for line in &caption[2..] {
        writeln!(out, "equal-RMSE time, stochastic / weighted, by layers: {line}").unwrap();
    }
    loglog(
        &svg("layering_crossover.svg"),
        "Which layering method wins: equal-RMSE time ratio, stochastic / weighted",
        "layers",
        "time ratio at equal RMSE (stochastic / weighted)",
        &crossover,
        &caption,
    )?;

    // (b) JIT vs interpreter on the default scene; strata vs Mitsuba 3 from the CSV.
    let default_base = RenderSettings { width: o.default_res.0, height: o.default_res.1, max_depth: 8, ..base.clone() };
    let jit = load_scene_with(None, BackendKind::Jit)?;
    let interp = load_scene_with(None, BackendKind::Interp)?;
    let reference_settings =
        RenderSettings { spp: o.reference_spp, seed: 0x5eed_0001, threads: None, ..default_base.clone() };
    let (_, reference) = render_rgb(&jit, &reference_settings)?;
    let curves =
        error_curves(&[(&jit, default_base.clone()), (&interp, default_base.clone())], &o.spp, &reference, o.reps)?;
    let (jit_curve, interp_curve) = (curves[0].clone(), curves[1].clone());
    let ratios = ratio_text(&jit_curve, &interp_curve);
    writeln!(out, "default scene, JIT / interpreter: {ratios}").unwrap();
    loglog(
        &svg("backends.svg"),
        "JIT (solid) vs interpreter (dashed), default scene",
        "render time per image (ms, 1 thread)",
        "RMSE vs reference",
        &[
            Series { label: "JIT".into(), points: jit_curve, color: 0, dashed: false },
            Series { label: "interpreter".into(), points: interp_curve, color: 1, dashed: true },
        ],
        &[
            format!(
                "{}x{} px, spp {:?}, 1 thread, fastest of {} interleaved, RMSE over {} seeds; reference: JIT, {} spp, other seed.",
                o.default_res.0, o.default_res.1, o.spp, o.reps, o.reps, o.reference_spp
            ),
            "Both backends compute the same bits, so equal spp gives equal RMSE: only time differs.".into(),
            format!("JIT / interpreter: {ratios}"),
        ],
    )?;
    match mitsuba_csv.filter(|p| p.is_file()) {
        Some(csv) => out += &mitsuba_chart(csv, &svg("mitsuba.svg"))?,
        None => {
            writeln!(out, "strata vs Mitsuba 3: no CSV, chart skipped (tools/compare_mitsuba.py writes it)").unwrap()
        }
    }

    // (c) Per-shading-point cost: hand-written Rust, JIT, interpreter.
    let points = sample_points(o.shade_points, 0x5eed);
    let (lib, material) = bench_material()?;
    let (module, _) = lower_material(&lib, &material)?;
    let bench_jit = backend::compile_module(module.clone(), BackendKind::Jit)?;
    let bench_interp = backend::compile_module(module, BackendKind::Interp)?;
    let hand = HandMaterial::default();
    compare_materials(&hand, bench_jit.as_ref(), &points, 1e-5)
        .map_err(|e| format!("hand-written Rust and JIT disagree: {e}"))?;
    let mut rng = SplitMix(0xfeed);
    let xis: Vec<f32> = (0..points.len()).map(|_| rng.unit()).collect();
    let contenders: [(&str, &dyn MaterialCode); 3] =
        [("hand Rust", &hand), ("JIT", bench_jit.as_ref()), ("interpreter", bench_interp.as_ref())];
    let (noise_ns, _) = time_contenders(&contenders, &points, &xis, o.reps.max(3));
    let (insts, arith_ns) = arithmetic_costs(&points, o.reps.max(3))?;
    let mut shade_bars = Vec::new();
    for (group, ns) in [
        ("noise-bound: 3-layer benchmark, weighted", &noise_ns[..]),
        ("arithmetic-bound: 64 math nodes", &arith_ns[..]),
    ] {
        for (k, name) in ["hand Rust", "JIT", "interpreter"].iter().enumerate() {
            shade_bars.push(Bar { group: group.into(), label: (*name).into(), value: ns[k], color: k });
        }
    }
    let cost_line = |what: &str, ns: &[f64]| {
        format!(
            "{what}: JIT / hand Rust {:.2}x, interpreter / JIT {:.1}x (equal-RMSE time ratios; equal-time RMSE ratio = sqrt: {:.2}, {:.2})",
            ns[1] / ns[0],
            ns[2] / ns[1],
            (ns[1] / ns[0]).sqrt(),
            (ns[2] / ns[1]).sqrt()
        )
    };
    let shade_caption = vec![
        format!(
            "{} points, median of {}; every backend computes the same values (checked first), so cost ratios are",
            points.len(),
            o.reps.max(3)
        ),
        "the equal-RMSE time ratios of a render whose time is all shading.".into(),
        cost_line("noise-bound", &noise_ns),
        cost_line(&format!("arithmetic-bound ({insts} instructions)"), &arith_ns),
    ];
    for line in &shade_caption[2..] {
        writeln!(out, "{line}").unwrap();
    }
    bars(&svg("shade_cost.svg"), "Per-shading-point cost", "ns per shading point", &shade_bars, &shade_caption)?;

    // (d) Compile time vs graph size.
    let (_, rows) = compile_sweep_rows(&o.sizes, o.reps.max(1))?;
    let line = |f: fn(&CompileRow) -> f64| rows.iter().map(|r| (r.nodes as f64, f(r))).collect::<Vec<_>>();
    // Between the two largest graphs, where fixed per-compile costs no longer dominate.
    let slope = {
        let (a, b) = (rows.len().checked_sub(2).and_then(|i| rows.get(i)), rows.last());
        match (a, b) {
            (Some(a), Some(b)) if b.nodes > a.nodes => {
                let t = |r: &CompileRow| r.compose + r.codegen;
                (t(b) / t(a)).ln() / (b.nodes as f64 / a.nodes as f64).ln()
            }
            _ => f64::NAN,
        }
    };
    let compile_caption = vec![
        "Tree of noise/math/mix_float nodes reading P; median of runs; compose = wire + fold + lower; codegen = Cranelift JIT.".into(),
        format!(
            "log-log slope of compose + codegen from {} to {} nodes: {slope:.2} (1 = linear); {} instructions at the largest size.",
            rows.len().checked_sub(2).and_then(|i| rows.get(i)).map_or(0, |r| r.nodes),
            rows.last().map_or(0, |r| r.nodes),
            rows.last().map_or(0, |r| r.insts)
        ),
        "No accuracy axis here: compile time does not change the image, so no RMSE ratio applies.".into(),
    ];
    writeln!(out, "compile time: {}", compile_caption[1]).unwrap();
    loglog(
        &svg("compile_time.svg"),
        "Compile time vs graph size",
        "nodes in the material graph",
        "milliseconds",
        &[
            Series { label: "parse + check".into(), points: line(|r| r.parse), color: 2, dashed: true },
            Series { label: "compose".into(), points: line(|r| r.compose), color: 3, dashed: true },
            Series { label: "codegen (JIT)".into(), points: line(|r| r.codegen), color: 4, dashed: true },
            Series {
                label: "compose + codegen".into(),
                points: line(|r| r.compose + r.codegen),
                color: 0,
                dashed: false,
            },
        ],
        &compile_caption,
    )?;
    out += &stability_charts(dir)?;
    out += &scale_chart(dir)?;
    writeln!(out, "charts written to {}", dir.display()).unwrap();
    Ok(out)
}

/// strata vs Mitsuba 3 per scene from `tools/compare_mitsuba.py`'s CSV: one point per
/// renderer at (CPU seconds, noise). The noise of one render is the relative mean absolute
/// difference between two renders of the same renderer with different seeds, divided by √2;
/// at equal spp both renderers converge to the same image where their models agree (README).
fn mitsuba_chart(csv: &Path, file: &Path) -> Result<String, String> {
    let text = std::fs::read_to_string(csv).map_err(|e| format!("cannot read {}: {e}", csv.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| {
        header.iter().position(|h| *h == name).ok_or_else(|| format!("{}: no `{name}` column", csv.display()))
    };
    let (scene, region, s_cpu, m_cpu, ss, mm) = (
        col("scene")?,
        col("region")?,
        col("strata_cpu_s")?,
        col("mitsuba_cpu_s")?,
        col("rel_mae_ss")?,
        col("rel_mae_mm")?,
    );
    let mut series = Vec::new();
    let mut caption =
        vec!["Per scene (whole image): CPU seconds at 1024 spp and relative MAE between two seeds / sqrt(2). Ratios strata / Mitsuba:".into()];
    let mut out = String::from("strata vs Mitsuba 3 (from the CSV; strata / Mitsuba):\n");
    for (k, row) in lines.enumerate() {
        let f: Vec<&str> = row.split(',').collect();
        if f.get(region) != Some(&"image") {
            continue;
        }
        let num = |i: usize| {
            f.get(i)
                .and_then(|v| v.parse::<f64>().ok())
                .ok_or_else(|| format!("{}:{}: bad number", csv.display(), k + 2))
        };
        let name = f.get(scene).copied().unwrap_or_default().to_string();
        let c = series.len() / 2;
        let s = vec![(num(s_cpu)?, num(ss)? / 2f64.sqrt())];
        let m = vec![(num(m_cpu)?, num(mm)? / 2f64.sqrt())];
        let ratios = ratio_text(&s, &m);
        writeln!(out, "  {name}: {ratios}").unwrap();
        caption.push(format!("{name}: {ratios}"));
        series.push(Series { label: format!("{name}, strata"), points: s, color: c, dashed: false });
        series.push(Series { label: format!("{name}, Mitsuba 3"), points: m, color: c, dashed: true });
    }
    crate::cli::plot::loglog(
        file,
        "strata (circles) vs Mitsuba 3 (triangles), docs/mitsuba_compare.csv",
        "CPU seconds per render (1024 spp, 320x240)",
        "relative noise (MAE between seeds / sqrt 2)",
        &series,
        &caption,
    )?;
    Ok(out)
}

/// Directional albedo `E(wo) = ∫ f |cos θi| dωi` of `bsdf` by sampling (`n` samples), with the
/// radiance compression of transmission undone (× η²) so glass reads R + T.
fn sampled_albedo(bsdf: &strata::render::material::bsdf::Bsdf, wo: glam::Vec3, n: usize, seed: u64) -> f64 {
    use strata::render::material::bsdf::Bsdf;
    let mut rng = SplitMix(seed);
    let mut sum = 0.0f64;
    for _ in 0..n {
        let (uc, u) = (rng.unit(), glam::Vec2::new(rng.unit(), rng.unit()));
        if let Some(s) = bsdf.sample(wo, uc, u) {
            let compression = match *bsdf {
                Bsdf::Glass { eta, .. } if s.wi.z * wo.z < 0.0 => {
                    f64::from(if wo.z > 0.0 { eta } else { 1.0 / eta }).powi(2)
                }
                _ => 1.0,
            };
            sum += f64::from(s.f.max_element() * s.wi.z.abs() / s.pdf) * compression;
        }
    }
    sum / n as f64
}

/// The direction at `cos_theta` from the normal, in the xz-plane.
fn direction(cos_theta: f64) -> glam::Vec3 {
    let sin = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    glam::Vec3::new(sin as f32, 0.0, cos_theta as f32)
}

/// The figures of docs/STABILITY.md that need no render: energy of the GGX lobes against
/// incidence down to cos θo = 1e-4 around the delta switch, and of rough glass as its index
/// approaches 1. Returns the report lines.
pub fn stability_charts(dir: &Path) -> Result<String, String> {
    use strata::abi::{Closure, ClosureKind};
    use strata::render::material::bsdf::Bsdf;
    let make = |kind: ClosureKind, params: &[f32]| {
        let mut c = Closure { kind: kind as u32, params: [0.0; 8] };
        c.params[..params.len()].copy_from_slice(params);
        Bsdf::from_closure(&c)
    };
    let cosines: Vec<f64> = (0..=16).map(|i| 10f64.powf(-4.0 + i as f64 * 0.25)).collect();
    let mut out = String::new();
    let mut series = Vec::new();
    let mut caption = vec![
        "White furnace E(wo) (40k samples per point) of a white conductor and of glass (R + T, from outside), against cos θo.".into(),
        "Roughness 0.01 is below the delta switch (α = r² < 1e-3): E is Fresnel's exactly; above it single scattering loses the".into(),
        "light GGX reflects below the horizon, most at grazing incidence. E > 1 nowhere; no NaN anywhere (cargo test: render::bsdf stability).".into(),
    ];
    for (c, r) in [0.01f32, 0.032, 0.1, 0.3, 1.0].into_iter().enumerate() {
        let metal = make(ClosureKind::Metal, &[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, r]);
        let glass = make(ClosureKind::Glass, &[1.0, 1.0, 1.0, r, 1.5]);
        let m: Vec<(f64, f64)> =
            cosines.iter().map(|&z| (z, sampled_albedo(&metal, direction(z), 40_000, 1))).collect();
        let g: Vec<(f64, f64)> =
            cosines.iter().map(|&z| (z, sampled_albedo(&glass, direction(z), 40_000, 2))).collect();
        let low = |v: &[(f64, f64)]| v.first().map_or(f64::NAN, |p| p.1);
        caption.push(format!(
            "roughness {r}: E at cos θo = 1e-4: metal {:.3}, glass {:.3}; at 1: metal {:.3}, glass {:.3}",
            low(&m),
            low(&g),
            m.last().map_or(f64::NAN, |p| p.1),
            g.last().map_or(f64::NAN, |p| p.1)
        ));
        series.push(Series { label: format!("metal r={r}"), points: m, color: c, dashed: false });
        series.push(Series { label: format!("glass r={r}"), points: g, color: c, dashed: true });
    }
    for line in &caption[3..] {
        writeln!(out, "stability, GGX: {line}").unwrap();
    }
    crate::cli::plot::loglog(
        &dir.join("stability_ggx.svg"),
        "GGX energy vs incidence: conductor (solid), glass (dashed)",
        "cos θo",
        "directional albedo E",
        &series,
        &caption,
    )?;

    let offsets: Vec<f64> = (0..=12).map(|i| 10f64.powf(-4.0 + i as f64 * 0.25)).collect();
    let mut series = Vec::new();
    let mut caption = vec![
        "R + T of rough glass (40k samples) against η − 1. Below η − 1 = 1e-3 strata switches to a null interface (a delta".into(),
        "pass-through, E = 1 exactly): the rough half vector ωi η + ωo vanishes as η → 1. Above it single-scattering GGX keeps".into(),
        "losing what masking removes, most at grazing incidence, so E jumps to 1 at the switch (an inherent limit, STABILITY.md).".into(),
    ];
    for (c, (r, cos)) in [(0.05f32, 0.5), (0.3, 0.5), (1.0, 0.5), (0.3, 0.01)].into_iter().enumerate() {
        let points: Vec<(f64, f64)> = offsets
            .iter()
            .map(|&d| {
                (
                    d,
                    sampled_albedo(
                        &make(ClosureKind::Glass, &[1.0, 1.0, 1.0, r, 1.0 + d as f32]),
                        direction(cos),
                        40_000,
                        3,
                    ),
                )
            })
            .collect();
        let at = |target: f64| {
            points
                .iter()
                .min_by(|a, b| (a.0 / target).ln().abs().total_cmp(&(b.0 / target).ln().abs()))
                .map_or(f64::NAN, |p| p.1)
        };
        caption.push(format!(
            "roughness {r}, cos θo = {cos}: E = {:.4} at η − 1 = 1e-4 (null), {:.4} at 1e-3, {:.4} at 1e-2, {:.4} at 1",
            at(1e-4),
            at(1e-3),
            at(1e-2),
            at(1.0)
        ));
        series.push(Series { label: format!("r={r}, cos θo={cos}"), points, color: c, dashed: false });
    }
    for line in &caption[3..] {
        writeln!(out, "stability, glass near index 1: {line}").unwrap();
    }
    crate::cli::plot::loglog(
        &dir.join("stability_glass.svg"),
        "Rough glass energy as the index approaches 1",
        "η − 1",
        "R + T",
        &series,
        &caption,
    )?;
    Ok(out)
}

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
struct FeatureRow {
    feature: &'static str,
    /// Median ns per camera sample.
    ns: f64,
    evals: strata::render::integrator::EvalCounts,
    samples: u64,
}

fn measure_features(res: (usize, usize), spp: u32, reps: usize) -> Result<Vec<FeatureRow>, String> {
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

/// The scene of `tests/scene_scale.rs` at scale `s`: a unit analytic sphere on a 40×40 mesh
/// floor under a white dome, camera, clipping range and geometry all multiplied by `s`.
pub fn scaled_scene(s: f64) -> String {
    let v = |x: f64| format!("{:e}", x * s);
    format!(
        "#usda 1.0\n(\n    upAxis = \"Y\"\n)\ndef Xform \"World\"\n{{\n    def Camera \"Camera\"\n    {{\n        \
         float focalLength = 35\n        float horizontalAperture = 36\n        float verticalAperture = 36\n        \
         float2 clippingRange = ({}, {})\n        float3 xformOp:translate = (0, {}, {})\n        \
         float3 xformOp:rotateXYZ = (-20, 0, 0)\n        uniform token[] xformOpOrder = [\"xformOp:translate\", \"xformOp:rotateXYZ\"]\n    }}\n    \
         def DomeLight \"Sky\"\n    {{\n        float inputs:intensity = 1\n    }}\n    \
         def Sphere \"Ball\"\n    {{\n        double radius = {r}\n        float3 xformOp:translate = (0, {r}, 0)\n        \
         uniform token[] xformOpOrder = [\"xformOp:translate\"]\n    }}\n    \
         def Mesh \"Floor\"\n    {{\n        int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]\n        \
         point3f[] points = [({m}, 0, {m}), ({p}, 0, {m}), ({p}, 0, {p}), ({m}, 0, {p})]\n    }}\n}}\n",
        v(0.01),
        v(1000.0),
        v(2.0),
        v(5.0),
        r = v(1.0),
        m = v(-20.0),
        p = v(20.0),
    )
}

/// The scale figure of docs/STABILITY.md: pixel coverage and mean radiance of [`scaled_scene`]
/// from 1e-6 to 3e5, relative to scale 1.
fn scale_chart(dir: &Path) -> Result<String, String> {
    let tmp = TempDir::new()?;
    let settings = RenderSettings {
        width: 24,
        height: 24,
        spp: 16,
        seed: 9,
        threads: None,
        max_depth: 6,
        mode: LayerMode::Stochastic,
        ..Default::default()
    };
    let measure = |s: f64| -> Result<(f64, f64), String> {
        let usda = tmp.0.join("scale.usda");
        std::fs::write(&usda, scaled_scene(s)).map_err(|e| format!("cannot write {}: {e}", usda.display()))?;
        let l = load_scene(&usda)?;
        let materials: Vec<&dyn MaterialCode> = l.materials.iter().map(|m| m.as_ref()).collect();
        let (image, _) = strata::render::render(&l.scene, &materials, &settings, None).map_err(|e| e.to_string())?;
        let mean = |name: &str| {
            image.f32_channel(name).map_or(f64::NAN, |v| v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64)
        };
        Ok((mean("A"), mean("R")))
    };
    let (a1, r1) = measure(1.0)?;
    // Below 1e-12 the floor's triangles fall under geometry::MIN_TRIANGLE_EDGE: an error.
    let scales = [1e-12, 1e-10, 1e-8, 1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 1e-3, 1e-2, 1.0, 1e2, 1e4, 1e5, 3e5];
    let mut coverage = Vec::new();
    let mut radiance = Vec::new();
    for &s in &scales {
        let (a, r) = measure(s)?;
        coverage.push((s, a / a1));
        radiance.push((s, r / r1));
    }
    let fmt = |v: &[(f64, f64)]| v.iter().map(|(s, x)| format!("{s:.0e}: {x:.3}")).collect::<Vec<_>>().join(", ");
    let caption = vec![
        "Sphere on a mesh floor, camera and clipping range scaled alike, 24x24 px at 16 spp; values relative to scale 1.".into(),
        format!("coverage (mean alpha) {}", fmt(&coverage)),
        format!("mean radiance {}", fmt(&radiance)),
        "Holds from 1e-12 to 3e5 (each BVH traversed in a power-of-two-scaled space, past obvhs' absolute 1e-4 cull).".into(),
        "Refused with a located error: triangles under 1e-11 units (geometry::MIN_TRIANGLE_EDGE), coordinates beyond 1e7 (MAX_EXTENT). tests/scene_scale.rs.".into(),
    ];
    crate::cli::plot::loglog(
        &dir.join("stability_scale.svg"),
        "Intersection against scene scale",
        "scene scale",
        "relative to scale 1",
        &[
            Series { label: "pixel coverage".into(), points: coverage.clone(), color: 0, dashed: false },
            Series { label: "mean radiance".into(), points: radiance.clone(), color: 1, dashed: true },
        ],
        &caption,
    )?;
    Ok(format!("stability, scene scale: coverage relative to scale 1: {}\n", fmt(&coverage)))
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_material_matches_jit_and_interpreter() {
        let (lib, material) = bench_material().unwrap();
        let (module, _) = lower_material(&lib, &material).unwrap();
        let jit = backend::compile_module(module.clone(), BackendKind::Jit).unwrap();
        let interp = backend::compile_module(module, BackendKind::Interp).unwrap();
        let hand = HandMaterial::default();
        let points = sample_points(400, 7);
        compare_materials(&hand, jit.as_ref(), &points, 1e-5).unwrap();
        compare_materials(&hand, interp.as_ref(), &points, 1e-5).unwrap();
        // The masks are not trivially constant: both mask layers take 0, 1 and in-between values.
        let mut m = [0.0; 3];
        let (mut lo, mut hi, mut mid) = ([false; 3], [false; 3], [false; 3]);
        for g in &points {
            hand.masks(g, &mut m).unwrap();
            for l in 1..3 {
                lo[l] |= m[l] == 0.0;
                hi[l] |= m[l] == 1.0;
                mid[l] |= m[l] > 0.0 && m[l] < 1.0;
            }
        }
        assert!(lo[1..].iter().chain(&hi[1..]).chain(&mid[1..]).all(|&b| b), "{lo:?} {hi:?} {mid:?}");
    }

    #[test]
    fn bench_shade_runs_small() {
        let options = ShadeOptions { points: 64, reps: 1, sizes: vec![3, 10], compile_reps: 1 };
        let report = shade_report(None, None, &options).unwrap();
        assert!(report.contains("hand Rust") && report.contains("interpreter / JIT"), "{report}");
        assert!(report.contains("compile time vs graph size"), "{report}");
    }

    #[test]
    fn bench_render_runs_small() {
        let report = render_report(None, 1, (4, 4), &[1, 2], 1).unwrap();
        assert!(report.contains("2 layers"), "{report}");
    }

    #[test]
    fn bench_charts_draws_every_chart() {
        let dir = TempDir::new().unwrap();
        let csv = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/mitsuba_compare.csv");
        let report = bench_charts(&dir.0, Some(&csv), &ChartOptions::quick()).unwrap();
        for name in [
            "layering_constant",
            "layering_noise",
            "layering_thin",
            "layering_crossover",
            "backends",
            "mitsuba",
            "shade_cost",
            "compile_time",
            "stability_ggx",
            "stability_glass",
            "stability_scale",
        ] {
            let svg = std::fs::read_to_string(dir.0.join(format!("{name}.svg"))).unwrap();
            assert!(svg.starts_with("<svg") && svg.contains("<text"), "{name}.svg");
        }
        assert!(report.contains("equal-time RMSE ratio"), "{report}");
    }

    #[test]
    fn hand_arithmetic_matches_jit() {
        let points = sample_points(4096, 3);
        let (lib, material) = single_substance(&arithmetic_substance(ARITHMETIC_NODES), "arithmetic").unwrap();
        let (module, _) = lower_material(&lib, &material).unwrap();
        let jit = backend::compile_module(module, BackendKind::Jit).unwrap();
        let hand = HandArithmetic::new(jit.info().clone());
        compare_materials(&hand, jit.as_ref(), &points, 1e-5).unwrap();
        // Masks are not all clamped to one value: the comparison sees the arithmetic.
        let masks: Vec<f32> = points.iter().map(|g| hand.mask(g, 0).unwrap()).collect();
        assert!(masks.iter().any(|&m| m > 0.0 && m < 1.0), "every mask clamped");
    }

    #[test]
    fn unused_features_cost_no_shader_calls() {
        let rows = measure_features((8, 8), 2, 1).unwrap();
        assert_eq!(rows.len(), FEATURES.len());
        // Every variant calls exactly the baseline's shader entry points: the extra material
        // is never shaded, and opaque layers' constant masks are not shader calls.
        for r in &rows {
            assert_eq!((r.evals, r.samples), (rows[0].evals, rows[0].samples), "{}", r.feature);
        }
        assert_eq!(rows[0].evals.masks + rows[0].evals.shadow_masks, 0);
        assert!(rows[0].evals.surfaces > 0);
    }

    #[test]
    fn generated_sources_compile() {
        for n in [1, 2, 7] {
            let mut sources = SourceMap::new();
            let mut diags = Diagnostics::new();
            Library::from_text("g.ash", &generated_substance(n), &mut sources, &mut diags);
            assert!(!diags.has_errors(), "{}", diags.render(&sources));
            Library::from_text("l.ash", &layered_source(n), &mut sources, &mut diags);
            assert!(!diags.has_errors(), "{}", diags.render(&sources));
        }
    }
}
