//! `strata bench render`: time per camera sample and RMSE, stochastic vs weighted layers.

use super::*;

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

/// `strata bench render [SCENE]`: time per camera sample and RMSE against a high-spp weighted
/// reference, stochastic vs weighted layer evaluation. Without a scene, a generated sphere
/// with 1, 2, 4, 8 and 16 noise-masked layers. Returns the printed report.
pub fn bench_render(scene: Option<&Path>, spp: u32, res: (usize, usize)) -> Result<String, String> {
    render_report(scene, spp, res, &RENDER_LAYERS, 5)
}

pub(super) fn render_report(
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
