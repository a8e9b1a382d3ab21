use super::lobes::LobeSample;
use super::*;
use crate::abi::ClosureKind;
use crate::render::material::bsdf::BsdfSample;
use crate::render::material::chi2::{CHI2_SAMPLES, Pcg32, SIGNIFICANCE, chi2_test, dir};
use std::f64::consts::PI;

fn bsdf(kind: ClosureKind, params: &[f32]) -> ClosureBsdf {
    let mut c = Closure { kind: kind as u32, params: [0.0; 8] };
    c.params[..params.len()].copy_from_slice(params);
    crate::render::material::bsdf::Bsdf::from_closure(&c).into()
}

/// A composed three-layer stack as the weighted mode sees it: diffuse, glossy and metal
/// lobes with rule-5 weights, each with its own shading normal (as normal maps give).
fn stack() -> Vec<Lobe> {
    let lobe = |weight, bsdf, n: Vec3, layer| Lobe { weight, bsdf, frame: Frame::from_normal(n.normalize()), layer };
    vec![
        lobe(0.25, bsdf(ClosureKind::Metal, &[0.9, 0.6, 0.3, 0.5, 0.8, 1.0, 0.3]), Vec3::new(0.2, 0.0, 1.0), 2),
        lobe(0.35, bsdf(ClosureKind::Glossy, &[0.5, 0.3, 0.2, 1.0, 1.0, 1.0, 0.25, 1.5]), Vec3::Z, 1),
        lobe(0.40, bsdf(ClosureKind::Diffuse, &[0.8, 0.8, 0.8]), Vec3::new(-0.1, 0.15, 1.0), 0),
    ]
}

#[test]
fn composed_stack_sampling_matches_its_pdf() {
    let lobes = stack();
    let cases = [Vec3::new(0.3, 0.1, 0.95), Vec3::new(-0.6, 0.2, 0.4), Vec3::new(0.99, 0.0, 0.06)];
    // Šidák over this test's cases.
    let alpha = 1.0 - (1.0 - SIGNIFICANCE).powf(1.0 / cases.len() as f64);
    for (k, wo) in cases.into_iter().enumerate() {
        let wo = wo.normalize();
        let sample = |uc: f32, u: glam::Vec2| {
            sample_lobes(&lobes, wo, uc, u).map(|s| BsdfSample {
                wi: s.wi,
                f: s.weight,
                pdf: 1.0,
                delta: s.pdf.is_none(),
            })
        };
        let pdf = |wi: Vec3| Context::eval_lobes(&lobes, wo, wi).1;
        // Lobe centres for the graded binning: each lobe's mirror direction.
        let centres: Vec<(Vec3, f32)> = lobes
            .iter()
            .map(|l| {
                let n = l.frame.n;
                ((2.0 * wo.dot(n) * n - wo).normalize(), 0.1)
            })
            .collect();
        let r = chi2_test(sample, pdf, &centres, 40 + k as u64);
        // A sample fails (`None`) exactly where the chosen lobe's own sampler does (a
        // microfacet reflection below its horizon), and Σ w_k pdf_k leaves out exactly that
        // mass, so ∫pdf = 1 − P(miss). Tolerance: 4 binomial standard errors of the miss
        // fraction plus 1e-3 for the bin quadrature (the three cases agree to 1.1e-4, within
        // one standard error). A pdf scaled by 0.9 is off by 0.1.
        let n = CHI2_SAMPLES as f64;
        let miss = r.missed as f64 / n;
        let tol = 4.0 * (miss * (1.0 - miss) / n).sqrt() + 1e-3;
        assert!(
            (r.integral - (1.0 - miss)).abs() < tol,
            "wo = {wo}: ∫pdf = {} but {} of the samples succeed (tolerance {tol})",
            r.integral,
            1.0 - miss
        );
        assert!(r.p >= alpha, "wo = {wo}: p = {} (stat {}, dof {})", r.p, r.stat, r.dof);
    }
}

/// Mean and standard error, per channel, of `n` throughput weights of `sample_lobes` at
/// `wo`; `each` sees every sample first.
fn throughput(lobes: &[Lobe], wo: Vec3, n: usize, seed: u64, mut each: impl FnMut(&LobeSample)) -> (Vec3, Vec3) {
    let mut rng = Pcg32::new(seed, 5);
    let (mut sum, mut sum2) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
    for _ in 0..n {
        let (uc, u) = (rng.f32(), rng.vec2());
        let s = sample_lobes(lobes, wo, uc, u).expect("diffuse and mirror lobes always sample");
        each(&s);
        let w = s.weight.as_dvec3();
        sum += w;
        sum2 += w * w;
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean * mean).max(glam::DVec3::ZERO);
    (mean.as_vec3(), (var / n as f64).sqrt().as_vec3())
}

#[test]
fn lobe_choice_weights_are_respected() {
    const N: usize = 100_000;
    let weights = [0.2f32, 0.3, 0.5];
    let lobe = |k: usize, bsdf, n: Vec3| Lobe { weight: weights[k], bsdf, frame: Frame::from_normal(n), layer: k };
    let wo = Vec3::Z;

    // Diffuse lobes coloured red, green, blue, with normals 60° off wo on three sides (wo
    // is above every one, so each lobe reflects its whole albedo). The weight f/pdf of the
    // mixture is the same whichever lobe drew wi, so the lobe choice shows only in where
    // samples land: drawn with lobe probabilities p_k, E[weight] = ∫ f Σp_k pdf_k / Σw_k pdf_k,
    // which is Σ w_k a_k for p = w but not otherwise when the frames differ (with one
    // shared frame the ratio is 1 whatever p). By quadrature, p = (0.25, 0.3, 0.45) moves the
    // red mean by +0.019, swapping the first and last weights by +0.11: against a standard
    // error of ~8e-4, 4 SE catches both.
    let albedo = [Vec3::new(0.9, 0.1, 0.1), Vec3::new(0.1, 0.9, 0.1), Vec3::new(0.1, 0.1, 0.9)];
    let normals = [dir(0.5, 0.0), dir(0.5, PI), dir(0.5, PI / 2.0)];
    let lobes: Vec<Lobe> =
        (0..3).map(|k| lobe(k, bsdf(ClosureKind::Diffuse, &albedo[k].to_array()), normals[k])).collect();
    let want: Vec3 = (0..3).map(|k| weights[k] * albedo[k]).sum();
    let (mean, se) = throughput(&lobes, wo, N, 1, |_| {});
    assert!(
        ((mean - want).abs() - 4.0 * se).max_element() <= 0.0,
        "diffuse mixture: E[weight] = {mean} ± {se}, want Σ w_k a_k = {want}"
    );

    // Two mirror lobes (smooth metals of different colours and normals) and a diffuse one:
    // each sample's lobe is known (a mirror sample is a delta along its lobe's mirror
    // direction), so the choice frequencies can be checked directly, each within 4 binomial
    // standard errors of N w_k (±2.5 % relative for w = 0.2), and each sample's weight must be
    // its own lobe's f cos / pdf: choice probability and lobe weight cancel.
    let normals = [dir(0.8, 0.0), dir(0.8, PI), Vec3::Z];
    let lobes = [
        lobe(0, bsdf(ClosureKind::Metal, &[0.9, 0.5, 0.2, 1.0, 1.0, 1.0, 0.0]), normals[0]),
        lobe(1, bsdf(ClosureKind::Metal, &[0.2, 0.6, 0.9, 1.0, 1.0, 1.0, 0.0]), normals[1]),
        lobe(2, bsdf(ClosureKind::Diffuse, &[0.5, 0.4, 0.3]), normals[2]),
    ];
    let mirror: Vec<Vec3> = normals.iter().map(|&n| 2.0 * wo.dot(n) * n - wo).collect();
    let own: Vec<Vec3> = lobes
        .iter()
        .map(|l| {
            let s = l.bsdf.sample(l.frame.to_local(wo), 0.5, glam::Vec2::splat(0.5)).unwrap();
            s.f * s.wi.z.abs() / s.pdf
        })
        .collect();
    let mut count = [0usize; 3];
    let (mean, se) = throughput(&lobes, wo, N, 2, |s| {
        let k = match s.pdf {
            Some(_) => 2,
            None => (0..2).find(|&k| (s.wi - mirror[k]).length() < 1e-4).expect("a mirror direction"),
        };
        count[k] += 1;
        assert!((s.weight - own[k]).abs().max_element() < 1e-5 * own[k].max_element(), "lobe {k}: {}", s.weight);
    });
    for k in 0..3 {
        let w = weights[k] as f64;
        let (expected, sd) = (N as f64 * w, (N as f64 * w * (1.0 - w)).sqrt());
        assert!(
            (count[k] as f64 - expected).abs() < 4.0 * sd,
            "lobe {k} chosen {} times of {N}, want {expected} ± {sd:.0}",
            count[k]
        );
    }
    let want: Vec3 = (0..3).map(|k| weights[k] * own[k]).sum();
    assert!(
        ((mean - want).abs() - 4.0 * se).max_element() <= 0.0,
        "mirror + diffuse: E[weight] = {mean} ± {se}, want Σ w_k (f cos/pdf)_k = {want}"
    );
}

/// An escaping ray reads a constant dome that is the only light at infinity directly
/// ([`ConstantDome`]); everywhere else the lights are walked. Whichever is taken, the sum must
/// be the walk's, bit for bit: visibility to camera rays, the dome's share of the light
/// selection and the MIS weight included, and any other light at infinity must rule the
/// shortcut out.
#[test]
fn constant_dome_escape_is_the_walk_bit_for_bit() {
    use crate::render::light::LightKind;
    use crate::render::sampling::uniform_sphere;
    let light = |kind, visible_to_camera| Light { path: "/L".into(), kind, visible_to_camera };
    let dome = |visible| {
        let (to_local, to_world) = (glam::Mat3::IDENTITY, glam::Mat3::IDENTITY);
        light(LightKind::Dome { radiance: Vec3::new(0.8, 0.5, 0.3), map: None, to_local, to_world }, visible)
    };
    let rect = light(LightKind::rect(Vec3::new(0.0, 0.0, 3.0), Vec3::X, Vec3::Y, -Vec3::Z, Vec3::splat(4.0)), true);
    let sun = |cos_max| light(LightKind::Distant { dir: Vec3::Z, cos_max, radiance: Vec3::splat(2.0) }, true);
    // (lights, whether the shortcut applies)
    let scenes = [
        (vec![dome(true)], true),
        (vec![rect.clone(), dome(false)], true),
        (vec![dome(true), sun(0.9)], false),
        (vec![rect.clone(), dome(true), sun(1.0)], false),
        (vec![rect], false),
    ];
    let p = Vec3::new(0.1, -0.2, 0.3);
    let froms = [
        Scatter { p, n: Vec3::ZERO, pdf: None },
        Scatter { p, n: Vec3::new(0.0, 0.6, 0.8), pdf: Some(0.3) },
        Scatter { p, n: Vec3::ZERO, pdf: Some(1.7) },
    ];
    for (lights, shortcut) in &scenes {
        let selection = LightSelection::new(lights, 5.0);
        let dome = ConstantDome::of(lights, &selection);
        assert_eq!(dome.is_some(), *shortcut, "{} lights", lights.len());
        for (k, from) in froms.iter().enumerate() {
            for i in 0..256 {
                let d = uniform_sphere(glam::Vec2::new((i % 16) as f32 / 16.0 + 0.03, (i / 16) as f32 / 16.0 + 0.03));
                for camera_ray in [true, false] {
                    let walk = escape_walk(lights, &selection, d, from, camera_ray);
                    let read = dome.map_or(walk, |dome| dome.escape(d, from, camera_ray));
                    assert_eq!(
                        read.to_array().map(f32::to_bits),
                        walk.to_array().map(f32::to_bits),
                        "{} lights, from {k}, d {d}, camera ray {camera_ray}",
                        lights.len()
                    );
                }
            }
        }
    }
}
