//! `strata bench layer`: the two modes of `layer(top, base)` against each other, the mission's
//! speed-vs-accuracy chart. For a dielectric coat (index 1.5) over a diffuse base of albedo 0.5
//! per coat roughness and angle: the directional albedo each mode renders (by sampling, as the
//! integrator does) and their gap, and the time per `sample` + `eval` pair of each mode. The
//! report adds the stacks the walk also covers (a coat over glass, fuzz over a coat, OpenPBR's coat over
//! its specular layer over the diffuse), not charted.

use crate::cli::plot::Series;
use glam::{Vec2, Vec3};
use std::fmt::Write;
use std::path::Path;
use std::time::Instant;
use strata::abi::{ClosureKind, ClosureSum, ClosureTerm, TERM_PARAMS};
use strata::render::material::closure::walk::directional_albedo;
use strata::render::material::closure::{ClosureBsdf, LayeringMode};

/// Coat roughnesses charted.
const ROUGHNESS: [f32; 5] = [0.0, 0.2, 0.5, 0.8, 1.0];
/// Albedo of the diffuse base (a grey base shows light trapped under the coat; a white one
/// would not, since it reflects everything it receives).
const BASE_ALBEDO: f32 = 0.5;

/// `layer(dielectric_bsdf(1, 1.5, r, "R"), diffuse_bsdf(base))` as compiled code returns it.
fn coated(roughness: f32, base: f32) -> ClosureSum {
    let mut sum = ClosureSum::default();
    let mut coat =
        ClosureTerm { kind: ClosureKind::Dielectric as u32, above: 0, weight: [1.0; 3], params: [0.0; TERM_PARAMS] };
    coat.params[..6].copy_from_slice(&[1.0, 1.0, 1.0, 1.5, roughness, 0.0]);
    let mut diffuse =
        ClosureTerm { kind: ClosureKind::Diffuse as u32, above: 1, weight: [1.0; 3], params: [0.0; TERM_PARAMS] };
    diffuse.params[..3].copy_from_slice(&[base; 3]);
    sum.terms[0] = coat;
    sum.terms[1] = diffuse;
    sum
}

/// Nanoseconds per `sample` + `eval` pair (median of 5 runs of `n`).
fn time_pair(b: &ClosureBsdf, n: usize) -> f64 {
    let wo = Vec3::new(0.6, 0.0, 0.8);
    let mut runs = Vec::new();
    let mut sink = 0.0f32;
    for rep in 0..5u32 {
        let start = Instant::now();
        for i in 0..n {
            let t = (i as f32 + 0.5) / n as f32;
            let u = Vec2::new(t, (t * 7.31 + rep as f32 * 0.1).fract());
            if let Some(s) = b.sample(wo, (t * 3.7).fract(), u) {
                sink += s.f.x + b.eval(wo, Vec3::new(-s.wi.y, s.wi.x, s.wi.z.abs())).x;
            }
        }
        runs.push(start.elapsed().as_secs_f64() * 1e9 / n as f64);
    }
    std::hint::black_box(sink);
    runs.sort_by(f64::total_cmp);
    runs[runs.len() / 2]
}

/// Measures both modes and draws `layer_modes.svg` into `dir`; returns the report.
pub fn bench_layer(dir: &Path, quick: bool) -> Result<String, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let samples = if quick { 4_000 } else { 200_000 };
    let cosines: Vec<f64> = (0..=12).map(|i| 10f64.powf(-1.5 + i as f64 * 0.125)).collect();
    let mut out = String::new();
    let mut series = Vec::new();
    let mut caption = vec![
        format!(
            "Directional albedo E(θo) of layer(dielectric coat, ior 1.5, roughness r; diffuse base {BASE_ALBEDO}), {samples} samples per point:"
        ),
        "albedo scaling (solid; reciprocal, tabulated coat albedo) against the random walk between the interfaces (dashed;".into(),
        "Guo et al. 2018 / pbrt-v4 LayeredBxDF, the reference). Albedo scaling ignores light the coat reflects back onto the".into(),
        "base (internal reflection, total internal reflection), so it is brighter where the base absorbs.".into(),
    ];
    for (c, &r) in ROUGHNESS.iter().enumerate() {
        let sum = coated(r, BASE_ALBEDO);
        let scaled = ClosureBsdf::from_sum(&sum, LayeringMode::AlbedoScaling);
        let walked = ClosureBsdf::from_sum(&sum, LayeringMode::RandomWalk);
        let measure = |b: &ClosureBsdf, seed: u64| -> Vec<(f64, f64)> {
            cosines.iter().map(|&mu| (mu, directional_albedo(b, mu as f32, samples, seed) as f64)).collect()
        };
        let (a, w) = (measure(&scaled, 1), measure(&walked, 2));
        let gaps: Vec<f64> = a.iter().zip(&w).map(|(p, q)| p.1 - q.1).collect();
        let worst = gaps.iter().copied().fold(0.0f64, |m, g| if g.abs() > m.abs() { g } else { m });
        let (t_scaled, t_walked) = (time_pair(&scaled, samples / 4), time_pair(&walked, samples / 4));
        let line = format!(
            "r = {r}: E at cos θo = 1: {:.4} (scaling) vs {:.4} (walk), at 0.03: {:.4} vs {:.4}; largest gap {worst:+.4}; \
             sample+eval {t_scaled:.0} ns vs {t_walked:.0} ns",
            a.last().map_or(f64::NAN, |p| p.1),
            w.last().map_or(f64::NAN, |p| p.1),
            a[0].1,
            w[0].1,
        );
        writeln!(out, "layer modes: {line}").unwrap();
        caption.push(line);
        series.push(Series { label: format!("albedo scaling r={r}"), points: a, color: c, dashed: false });
        series.push(Series { label: format!("random walk r={r}"), points: w, color: c, dashed: true });
    }
    crate::cli::plot::loglog(
        &dir.join("layer_modes.svg"),
        "layer(coat, diffuse): albedo scaling (solid) vs random walk (dashed)",
        "cos θo",
        "directional albedo E",
        &series,
        &caption,
    )?;
    writeln!(out, "wrote {}", dir.join("layer_modes.svg").display()).unwrap();
    stacks_beyond_the_chart(&mut out, samples);
    Ok(out)
}

/// A closure value of `(kind, params, weight, above)` terms.
fn closure(terms: &[(ClosureKind, &[f32], f32, u32)]) -> ClosureSum {
    let mut sum = ClosureSum::default();
    for (k, &(kind, params, weight, above)) in terms.iter().enumerate() {
        let mut t = ClosureTerm { kind: kind as u32, above, weight: [weight; 3], params: [0.0; TERM_PARAMS] };
        t.params[..params.len()].copy_from_slice(params);
        sum.terms[k] = t;
    }
    sum
}

/// Reflected and transmitted energy from `cos θo = mu` (channel 0, transmitted radiance's
/// compression given back), by sampling as the integrator does.
fn reflected_transmitted(b: &ClosureBsdf, mu: f32, n: usize) -> (f64, f64) {
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let (mut r, mut t) = (0.0f64, 0.0f64);
    for i in 0..n {
        let x = (i as f32 + 0.5) / n as f32;
        let u = Vec2::new((x * 7.31).fract(), (x * 13.17 + 0.3).fract());
        if let Some(s) = b.sample(wo, (x * 3.7 + 0.11).fract(), u) {
            let w = (s.f.x * s.wi.z.abs() / s.pdf * b.compression(wo, s.wi)) as f64;
            if s.wi.z * wo.z > 0.0 { r += w } else { t += w }
        }
    }
    (r / n as f64, t / n as f64)
}

/// The stacks the random walk also covers, albedo scaling against it (report lines, not
/// charted): a coat (index 1.5) over white glass (index 1.5 and 1.33, roughness 0.2), reflected
/// and transmitted; white fuzz (roughness 0.4) over a coat over a diffuse base of 0.5.
fn stacks_beyond_the_chart(out: &mut String, samples: usize) {
    for (glass_ior, r) in [(1.5f32, 0.0f32), (1.5, 0.3), (1.33, 0.3), (1.33, 0.8)] {
        let sum = closure(&[
            (ClosureKind::Dielectric, &[1.0, 1.0, 1.0, 1.5, r, 0.0], 1.0, 0),
            (ClosureKind::Dielectric, &[1.0, 1.0, 1.0, glass_ior, 0.2, 2.0], 1.0, 1),
        ]);
        let mut line = format!("coat r={r} over glass η={glass_ior} r=0.2, R / T:");
        for mu in [1.0f32, 0.5, 0.2] {
            let (ar, at) =
                reflected_transmitted(&ClosureBsdf::from_sum(&sum, LayeringMode::AlbedoScaling), mu, samples);
            let (wr, wt) = reflected_transmitted(&ClosureBsdf::from_sum(&sum, LayeringMode::RandomWalk), mu, samples);
            write!(line, " cos θo {mu}: scaling {ar:.4} / {at:.4}, walk {wr:.4} / {wt:.4};").unwrap();
        }
        writeln!(out, "layer modes: {line}").unwrap();
    }
    for r in [0.0f32, 0.3, 0.8] {
        let sum = closure(&[
            (ClosureKind::Sheen, &[1.0, 1.0, 1.0, 0.4], 1.0, 0),
            (ClosureKind::Dielectric, &[1.0, 1.0, 1.0, 1.5, r, 0.0], 1.0, 1),
            (ClosureKind::Diffuse, &[BASE_ALBEDO; 3], 1.0, 3),
        ]);
        albedo_line(out, &format!("fuzz over coat r={r} over diffuse {BASE_ALBEDO}"), &sum, samples);
    }
    // OpenPBR's stack: a coat (η 1.6) over its specular layer (η 1.5) over the diffuse base.
    for (coat_r, specular_r) in [(0.0f32, 0.3f32), (0.3, 0.6)] {
        let sum = closure(&[
            (ClosureKind::Dielectric, &[1.0, 1.0, 1.0, 1.6, coat_r, 0.0], 1.0, 0),
            (ClosureKind::Dielectric, &[1.0, 1.0, 1.0, 1.5, specular_r, 0.0], 1.0, 1),
            (ClosureKind::Diffuse, &[BASE_ALBEDO; 3], 1.0, 3),
        ]);
        let name = format!("coat r={coat_r} over specular r={specular_r} over diffuse {BASE_ALBEDO}");
        albedo_line(out, &name, &sum, samples);
    }
}

/// A report line: the directional albedo of `sum` in each mode at three angles.
fn albedo_line(out: &mut String, name: &str, sum: &ClosureSum, samples: usize) {
    let mut line = format!("{name}, E:");
    for mu in [1.0f32, 0.5, 0.2] {
        let a = directional_albedo(&ClosureBsdf::from_sum(sum, LayeringMode::AlbedoScaling), mu, samples, 1);
        let w = directional_albedo(&ClosureBsdf::from_sum(sum, LayeringMode::RandomWalk), mu, samples, 2);
        write!(line, " cos θo {mu}: scaling {a:.4}, walk {w:.4};").unwrap();
    }
    writeln!(out, "layer modes: {line}").unwrap();
}
