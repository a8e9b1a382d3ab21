//! Tests of the thin film on a transmitting dielectric (`dielectric_bsdf` "RT"/"T" under
//! `thinfilm_*`, OpenPBR and Standard Surface glass under `thin_film_*`): the film's
//! reflectance from both sides against the characteristic matrix, white furnace (R + T = 1),
//! χ² of sampling against evaluation, generalized reciprocity, and the limits that must be
//! plain glass.

use crate::abi::{ClosureKind, ClosureTerm, TERM_PARAMS, thin_film_words};
use crate::render::material::bsdf::{Bsdf, BsdfSample, refract};
use crate::render::material::chi2::*;
use crate::render::material::lobes::{Film, Lobe};
use crate::render::material::microfacet::fresnel_dielectric;
use glam::{DVec3, Vec3};
use std::f64::consts::PI;

/// Wavelengths (nm) each channel of the renderer's film averages ([`Film`]).
const BANDS: [[f64; 3]; 3] = [[600.0, 630.0, 670.0], [500.0, 530.0, 560.0], [415.0, 445.0, 475.0]];

/// A `dielectric_bsdf` term (tint 1, index `eta`, `rough`, scatter "RT" or "T") under a film of
/// `film_eta`, `thickness` nm covering `weight` of it.
fn filmed_glass(rough: f32, eta: f32, film: [f32; 3], reflect: bool) -> Lobe {
    let mut t =
        ClosureTerm { kind: ClosureKind::Dielectric as u32, above: 0, weight: [1.0; 3], params: [0.0; TERM_PARAMS] };
    t.params[..6].copy_from_slice(&[1.0, 1.0, 1.0, eta, rough, if reflect { 2.0 } else { 1.0 }]);
    let at = thin_film_words(ClosureKind::Dielectric).unwrap();
    t.params[at..at + 3].copy_from_slice(&film);
    Lobe::from_term(&t)
}

/// Reflectance of a film (index `n2`, `d` nm) between an incident medium `n1` and an exit
/// medium `n3`, at cos θ1 = `cos1` in the incident medium, wavelength `lambda`, s and p
/// averaged, by the film's characteristic matrix with tilted admittances (η = n cos θ for s,
/// n / cos θ for p; Macleod, Thin-Film Optical Filters §2.4) in f64: a different formulation
/// from the Airy sum the renderer evaluates, and from inside the glass (`n1` the substrate)
/// computed directly rather than through the outside angle.
fn film_by_matrix(n1: f64, n2: f64, n3: f64, d: f64, lambda: f64, cos1: f64) -> f64 {
    let sin1 = (1.0 - cos1 * cos1).sqrt();
    let cos_in = |n: f64| (1.0 - (n1 * sin1 / n).powi(2)).sqrt();
    let (cos2, cos3) = (cos_in(n2), cos_in(n3));
    let (sd, cd) = (2.0 * PI * n2 * d * cos2 / lambda).sin_cos();
    // [B, C] = [[cos δ, i sin δ / η2], [i η2 sin δ, cos δ]] [1, η3]; r = (η1 B − C) / (η1 B + C).
    let r = |e1: f64, e2: f64, e3: f64| {
        let (num_re, num_im) = ((e1 - e3) * cd, (e1 * e3 / e2 - e2) * sd);
        let (den_re, den_im) = ((e1 + e3) * cd, (e1 * e3 / e2 + e2) * sd);
        (num_re * num_re + num_im * num_im) / (den_re * den_re + den_im * den_im)
    };
    0.5 * (r(n1 * cos1, n2 * cos2, n3 * cos3) + r(n1 / cos1, n2 / cos2, n3 / cos3))
}

/// The film on a glass reflects what the characteristic matrix gives from outside and from
/// inside at every angle below the critical one, all of it beyond, and `weight` of it over
/// the bare interface.
#[test]
fn a_filmed_glass_reflects_what_the_characteristic_matrix_gives_from_both_sides() {
    for (film_eta, eta) in [(1.33f32, 1.5f32), (2.0, 1.5), (1.38, 1.7), (1.4, 1.0)] {
        for d in [80.0f32, 250.0, 500.0, 1200.0] {
            let film = Film { eta: film_eta, thickness: d, weight: 1.0 };
            let (outside, inside) = ([1.0f32, 0.8, 0.5, 0.2], [1.0f32, 0.95, 0.85]);
            let cases = outside.iter().map(|&c| (c, 1.0, eta)).chain(inside.iter().map(|&c| (-c, eta, 1.0)));
            for (cos, n1, n3) in cases {
                if n1 > 1.0 && (1.0 - cos * cos) * n1 * n1 >= 1.0 {
                    continue;
                }
                let got = film.on_dielectric(cos, eta);
                for (c, band) in BANDS.iter().enumerate() {
                    let want: f64 = band
                        .iter()
                        .map(|&l| film_by_matrix(n1 as f64, film_eta as f64, n3 as f64, d as f64, l, cos.abs() as f64))
                        .sum::<f64>()
                        / 3.0;
                    assert!(
                        (got[c] as f64 - want).abs() < 2e-4,
                        "film {film_eta} ({d} nm) on {eta}, cos {cos}, channel {c}: {} vs {want}",
                        got[c]
                    );
                }
            }
        }
    }
    // Beyond the critical angle inside the glass nothing leaves: R = 1.
    let film = Film { eta: 1.33, thickness: 250.0, weight: 1.0 };
    assert_eq!(film.on_dielectric(-0.5, 1.5), Vec3::ONE);
    // A film covering a quarter: a quarter of the way from the bare interface to the film.
    let quarter = Film { weight: 0.25, ..film };
    for cos in [0.9f32, 0.4, -0.9] {
        let bare = Vec3::splat(fresnel_dielectric(cos, 1.5));
        let want = bare.lerp(film.on_dielectric(cos, 1.5), 0.25);
        assert!((quarter.on_dielectric(cos, 1.5) - want).abs().max_element() < 1e-6);
    }
}

/// Sampled `f |cos| / pdf`, with the radiance compression undone, per channel: mean and
/// standard error (delta samples included), and the non-delta part alone (summed in f64).
fn furnace(l: &Lobe, wo: Vec3, n: usize, seed: u64) -> [(DVec3, DVec3); 2] {
    let weight = |s: &BsdfSample| (s.f * (s.wi.z.abs() / s.pdf * l.compression(wo, s.wi))).as_dvec3();
    furnace_weights(|uc, u| l.sample(wo, uc, u), weight, n, seed)
}

/// The mirror and refracted directions of `wo` with the lobe width α, for graded grids.
fn centres(wo: Vec3, eta: f32, rough: f32) -> Vec<(Vec3, f32)> {
    let a = (rough * rough).max(1e-3);
    let mut c = vec![(Vec3::new(-wo.x, -wo.y, wo.z), a)];
    if let Some((t, _)) = refract(wo, Vec3::Z, eta) {
        c.push((t, a));
    }
    c
}

/// Directions of the furnace and χ²: from outside, and from inside below and beyond the
/// critical angle (cos 0.745 at η 1.5).
const COS: [f32; 6] = [1.0, 0.7, 0.3, 0.1, -0.9, -0.6];

/// A lossless film over a lossless interface: every microfacet reflects R and transmits
/// 1 − R, so a smooth filmed glass conserves energy in each channel from both sides (total
/// internal reflection included), a nearly smooth one to the tolerance of plain glass's
/// furnace, and a rough one loses only what single-scattering microfacets lose (its sampled
/// albedo is the quadrature of its `eval`, and ≤ 1).
#[test]
fn a_filmed_glass_conserves_energy_from_both_sides() {
    let film = [380.0, 1.33, 1.0];
    let mut failures = vec![];
    for (i, rough) in [0.0f32, 0.05, 0.3, 0.7].into_iter().enumerate() {
        let l = filmed_glass(rough, 1.5, film, true);
        for (j, z) in COS.into_iter().enumerate() {
            let wo = dir(z as f64, 0.4);
            let [(e, se), (e_nd, se_nd)] = furnace(&l, wo, 50_000, (i * 10 + j) as u64);
            let at = format!("r={rough} wo.z={z}");
            eprintln!("furnace filmed glass {at:<16} E = {e:.4} ± {se:.4}");
            let tolerance = match rough {
                0.0 => Some(1e-4),
                0.05 => Some(5e-3),
                _ => None,
            };
            for c in 0..3 {
                if e[c] > 1.0 + 4.0 * se[c] + 1e-4 {
                    failures.push(format!("{at} channel {c}: E = {} > 1", e[c]));
                }
                if let Some(tol) = tolerance
                    && (e[c] - 1.0).abs() > 4.0 * se[c] + tol
                {
                    failures.push(format!("{at} channel {c}: E = {} ± {}, not 1", e[c], se[c]));
                }
                if rough >= 0.3 {
                    let q = sphere_integral(
                        |wi| l.eval(wo, wi)[c] * wi.z.abs() * l.compression(wo, wi),
                        &centres(wo, 1.5, rough),
                    );
                    if (e_nd[c] - q).abs() > 4.0 * se_nd[c] + 1e-3 * q {
                        failures.push(format!("{at} channel {c}: sampled {} vs quadrature {q}", e_nd[c]));
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Weight 0 or thickness 0 is no film (plain glass's lobe, bit for bit); a film of the
/// substrate's index or of air's changes nothing but rounding.
#[test]
fn a_film_that_is_not_there_leaves_plain_glass() {
    for rough in [0.0f32, 0.3] {
        let plain = filmed_glass(rough, 1.5, [0.0; 3], true);
        assert!(matches!(plain, Lobe::Interface { film: None, .. }));
        assert_eq!(filmed_glass(rough, 1.5, [300.0, 1.33, 0.0], true), plain);
        assert_eq!(filmed_glass(rough, 1.5, [0.0, 1.33, 1.0], true), plain);
        let mut rng = Pcg32::new(7, 1);
        for film in [[333.0, 1.5, 1.0], [333.0, 1.0, 1.0]] {
            let l = filmed_glass(rough, 1.5, film, true);
            for _ in 0..2000 {
                let (wo, wi) = (rng.dir(), rng.dir());
                let (f, g) = (l.eval(wo, wi), plain.eval(wo, wi));
                assert!((f - g).abs().max_element() <= 1e-4 * g.max_element() + 1e-6, "{film:?} {wo} {wi}: {f} vs {g}");
                let (p, q) = (l.pdf(wo, wi), plain.pdf(wo, wi));
                assert!((p - q).abs() <= 1e-4 * q + 1e-6, "{film:?} {wo} {wi}: pdf {p} vs {q}");
            }
        }
    }
}

/// Sampling a rough filmed glass (both scatter modes) follows its pdf, from outside and inside.
#[test]
fn chi2_filmed_glass() {
    let mut cases = vec![];
    for rough in [0.2f32, 0.5] {
        for reflect in [true, false] {
            for z in [0.8f32, 0.3, -0.9, -0.6] {
                cases.push((rough, reflect, z));
            }
        }
    }
    let alpha = 1.0 - (1.0 - SIGNIFICANCE).powf(1.0 / cases.len() as f64);
    let mut failures = vec![];
    for (k, &(rough, reflect, z)) in cases.iter().enumerate() {
        let l = filmed_glass(rough, 1.5, [450.0, 1.8, 0.9], reflect);
        let wo = dir(z as f64, 0.7);
        let r = chi2_test(|uc, u| l.sample(wo, uc, u), |wi| l.pdf(wo, wi), &centres(wo, 1.5, rough), 700 + k as u64);
        eprintln!("chi2 filmed glass r={rough} reflect={reflect} wo.z={z}: p = {:.4} ∫pdf = {:.5}", r.p, r.integral);
        if r.p < alpha || r.integral > 1.0 + 1e-3 {
            failures.push(format!("r={rough} reflect={reflect} wo.z={z}: p = {:e}, ∫pdf = {}", r.p, r.integral));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// f(wo, wi) / n(wo)² = f(wi, wo) / n(wi)² (radiance transport across the interface; plain
/// reciprocity for reflection), and sample, eval and pdf agree.
#[test]
fn a_filmed_glass_is_reciprocal_and_consistent() {
    let mut rng = Pcg32::new(19, 4);
    let mut transmitted = 0;
    for rough in [0.1f32, 0.4, 0.9] {
        let l = filmed_glass(rough, 1.5, [520.0, 1.3, 1.0], true);
        let Lobe::Interface { glass: Bsdf::Glass { eta, .. }, .. } = l else { unreachable!() };
        let n2 = |w: Vec3| if w.z < 0.0 { eta * eta } else { 1.0 };
        for _ in 0..3000 {
            let (wo, wi) = (rng.dir(), rng.dir());
            let (f, g) = (l.eval(wo, wi) / n2(wo), l.eval(wi, wo) / n2(wi));
            assert!(
                (f - g).abs().max_element() <= 1e-3 * f.max(g).max_element() + 1e-6,
                "r={rough} {wo} {wi}: {f} vs {g}"
            );
            transmitted += (wo.z * wi.z < 0.0 && f.max_element() > 0.0) as usize;
            if let Some(s) = l.sample(wo, rng.f32(), rng.vec2())
                && !s.delta
            {
                let (e, p) = (l.eval(wo, s.wi), l.pdf(wo, s.wi));
                assert!((s.f - e).abs().max_element() <= 1e-3 * e.max_element() + 1e-6, "f {} vs {e}", s.f);
                assert!((s.pdf - p).abs() <= 1e-3 * p, "pdf {} vs {p}", s.pdf);
            }
        }
    }
    assert!(transmitted > 500, "{transmitted} transmitted pairs");
}

/// A "RT" or "T" dielectric term's film words reach its interface, and as the top of a layer
/// it reflects through the film.
#[test]
fn a_transmitting_dielectric_term_carries_its_film() {
    use crate::render::material::lobes::Fresnel;
    let want = Film { eta: 1.33, thickness: 250.0, weight: 0.6 };
    for reflect in [true, false] {
        let l = filmed_glass(0.2, 1.5, [250.0, 1.33, 0.6], reflect);
        assert!(matches!(l, Lobe::Interface { film: Some(f), reflect: r, .. } if f == want && r == reflect), "{l:?}");
        assert!(
            matches!(l.covering(), Lobe::Specular { fresnel: Fresnel::ThinFilm { film, .. }, .. } if film == want),
            "{:?}",
            l.covering()
        );
    }
}
