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
//!
//! One file per bench family (`shade`, `render`, `scale`, `charts`, `features`,
//! `displacement`, `update`); this file keeps what they share: sample points, medians, the
//! temporary directory and scene loading.

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

mod charts;
mod displacement;
mod features;
mod layer;
mod render;
mod scale;
mod shade;
mod textures;
mod update;
pub use charts::*;
pub use displacement::*;
pub use features::*;
pub use layer::bench_layer;
pub use render::*;
pub use scale::*;
pub use shade::*;
pub use textures::bench_textures;
pub use update::bench_update;

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
                st_footprint: [0.0; 4],
                primvars: Default::default(),
                params: Default::default(),
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
