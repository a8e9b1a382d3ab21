//! Anisotropic GGX: pointwise against Mitsuba 3 (`tools/make_aniso_fixtures.py`), the
//! isotropic limit bit for bit against the isotropic formulas, a 90° turn swapping the
//! widths, χ² of sampling against the pdf, white furnace and reciprocity, and the term
//! frames a closure's tangent gives (`ClosureBsdf::set_term_frames`).

use crate::abi::{ClosureKind, ClosureSum, ClosureTerm, TERM_ASPECT, TERM_PARAMS, TERM_TANGENT};
use crate::render::material::bsdf::{Bsdf, BsdfSample, Frame, refract};
use crate::render::material::chi2::{Pcg32, chi2_test, dir, furnace_weights, sphere_integral};
use crate::render::material::closure::{ClosureBsdf, LayeringMode};
use crate::render::material::lobes::{Fresnel, Lobe};
use crate::render::material::microfacet::Ggx;
use glam::{DVec3, Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

const FIXTURE: &str = include_str!("../../../tests/fixtures/aniso/mitsuba_ggx.txt");

fn metal(ggx: Ggx) -> Bsdf {
    Bsdf::Metal { reflectivity: Vec3::ONE, eta: Vec3::splat(1.3), k: Vec3::splat(2.7), ggx }
}

fn glass(ggx: Ggx, eta: f32) -> Bsdf {
    Bsdf::Glass { tint: Vec3::ONE, ggx, eta }
}

/// Within `rel` relative or 1e-6 absolute (f32 arithmetic on both sides).
fn close(got: f32, want: f32, rel: f32) -> bool {
    (got - want).abs() <= rel * want.abs() + 1e-6
}

#[test]
fn anisotropic_ggx_matches_mitsuba() {
    let mut counts = std::collections::BTreeMap::new();
    let mut failures = vec![];
    for line in FIXTURE.lines().filter(|l| !l.starts_with('#') && !l.is_empty()) {
        let mut words = line.split_whitespace();
        let kind = words.next().unwrap();
        let x: Vec<f32> = words.map(|w| w.parse().unwrap()).collect();
        let ggx = Ggx::anisotropic(x[0], x[1]);
        let v = |at: usize| Vec3::new(x[at], x[at + 1], x[at + 2]);
        let want = *x.last().unwrap();
        let (got, rel) = match kind {
            "D" => (ggx.d(v(2)), 1e-4),
            "G1" => (ggx.g1(v(2)), 1e-5),
            "VNDF" => (ggx.d_visible(v(2), v(5)), 1e-4),
            "CONDUCTOR" => {
                let b = Bsdf::Metal { reflectivity: Vec3::ONE, eta: Vec3::splat(x[2]), k: Vec3::splat(x[3]), ggx };
                (b.eval(v(4), v(7)).x, 1e-3)
            }
            // Mitsuba's radiance transport scales transmission by 1/η² as strata's does.
            "DIELECTRIC" => (glass(ggx, x[2]).eval(v(3), v(6)).x, 1e-3),
            other => panic!("unknown fixture case {other}"),
        };
        *counts.entry(kind).or_insert(0) += 1;
        if !close(got, want, rel) {
            failures.push(format!("{line}: strata {got}"));
        }
    }
    eprintln!("cases per kind: {counts:?}");
    assert!(counts.values().all(|&n| n >= 10), "too few fixture cases: {counts:?}");
    assert!(failures.is_empty(), "{} of the Mitsuba cases differ:\n{}", failures.len(), failures.join("\n"));
}

/// The isotropic formulas as they were before the distribution took an aspect.
mod isotropic {
    use glam::Vec3;
    use std::f32::consts::FRAC_1_PI;
    pub fn d(alpha: f32, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = alpha * alpha;
        let t = m.x * m.x + m.y * m.y + a2 * m.z * m.z;
        if t <= 0.0 {
            return 0.0;
        }
        a2 * FRAC_1_PI / (t * t)
    }
    pub fn lambda(alpha: f32, w: Vec3) -> f32 {
        let z2 = w.z * w.z;
        if z2 <= 0.0 {
            return f32::INFINITY;
        }
        let a2tan2 = alpha * alpha * (w.x * w.x + w.y * w.y) / z2;
        a2tan2 / (2.0 * ((1.0 + a2tan2).sqrt() + 1.0))
    }
}

/// Aspect 1 is the isotropic distribution bit for bit: D, Λ and the sampled normals, so every
/// isotropic image is unchanged.
#[test]
fn aspect_one_is_the_isotropic_distribution_bit_for_bit() {
    let mut rng = Pcg32::new(5, 1);
    for alpha in [0.0011f32, 0.05, 0.3, 0.77, 1.0] {
        let g = Ggx::isotropic(alpha).with_aspect(1.0);
        assert!(!g.is_anisotropic());
        for _ in 0..2000 {
            let (v, m) = (rng.dir(), rng.dir());
            assert_eq!(g.d(m).to_bits(), isotropic::d(alpha, m).to_bits(), "α {alpha} m {m}");
            assert_eq!(g.lambda(v).to_bits(), isotropic::lambda(alpha, v).to_bits(), "α {alpha} v {v}");
            let u = rng.vec2();
            // The hemisphere warp with α on both axes, as the isotropic sampler computed it.
            let up = if v.z < 0.0 { -v } else { v };
            let wh = Vec3::new(alpha * up.x, alpha * up.y, up.z).try_normalize();
            let want = wh.and_then(|wh| {
                let phi = 2.0 * std::f32::consts::PI * u.x;
                let z = (1.0 - u.y) * (1.0 + wh.z) - wh.z;
                let s = (1.0 - z * z).clamp(0.0, 1.0).sqrt();
                let h = Vec3::new(s * phi.cos(), s * phi.sin(), z) + wh;
                Vec3::new(alpha * h.x, alpha * h.y, h.z).try_normalize().filter(|m| m.z > 0.0)
            });
            assert_eq!(
                g.sample_visible(v, u).map(|m| m.to_array().map(f32::to_bits)),
                want.map(|m| m.to_array().map(f32::to_bits))
            );
        }
    }
}

/// Turning the microsurface by 90° about the normal swaps αx and αy: the distribution with
/// aspect a at (x, y) is the one with 1/a at (−y, x).
#[test]
fn turning_by_90_degrees_swaps_the_widths() {
    let turn = |v: Vec3| Vec3::new(-v.y, v.x, v.z);
    let mut rng = Pcg32::new(9, 2);
    for (ax, ay) in [(0.1f32, 0.4f32), (0.5, 0.05), (0.02, 0.2)] {
        let (a, b) = (Ggx::anisotropic(ax, ay), Ggx::anisotropic(ay, ax));
        assert!(close(a.alpha_x(), ax, 1e-5) && close(a.alpha_y(), ay, 1e-5), "{a:?}");
        for _ in 0..500 {
            let (wo, m) = (rng.dir(), rng.dir());
            assert!(close(a.d(m), b.d(turn(m)), 1e-4), "D {ax} {ay} {m}");
            assert!(close(a.lambda(wo), b.lambda(turn(wo)), 1e-4), "Λ {ax} {ay} {wo}");
            assert!(close(a.d_visible(wo, m), b.d_visible(turn(wo), turn(m)), 1e-4), "D_wo {ax} {ay}");
            let wi = rng.dir();
            let (fa, fb) = (metal(a).eval(wo, wi).x, metal(b).eval(turn(wo), turn(wi)).x);
            assert!(close(fa, fb, 1e-3), "metal {ax} {ay}: {fa} vs {fb}");
        }
    }
    // An anisotropic lobe is not rotation-invariant (else the test above proves nothing).
    let a = Ggx::anisotropic(0.1, 0.4);
    let m = Vec3::new(0.3, 0.0, 0.95).normalize();
    assert!(a.d(turn(m)) > 2.0 * a.d(m), "{} vs {}", a.d(turn(m)), a.d(m));
}

/// ∫ D(m) cos θm dω = 1 for anisotropic widths too.
#[test]
fn anisotropic_d_is_normalised_over_projected_area() {
    for (ax, ay) in [(0.05f32, 0.3f32), (0.4, 0.1), (1.0, 0.2)] {
        let g = Ggx::anisotropic(ax, ay);
        let i = sphere_integral(|m| g.d(m) * m.z.max(0.0), &[(Vec3::Z, ax.min(ay))]);
        assert!((i - 1.0).abs() < 2e-3, "{ax} {ay}: ∫ D cos = {i}");
    }
}

/// A χ² case: name, sampler, pdf and lobe centres.
type Chi2Case = (String, Box<dyn Fn(f32, Vec2) -> Option<BsdfSample>>, Box<dyn Fn(Vec3) -> f32>, Vec<(Vec3, f32)>);

fn centres(b: &Bsdf, wo: Vec3, scale: f32) -> Vec<(Vec3, f32)> {
    let mirror = Vec3::new(-wo.x, -wo.y, wo.z);
    let mut c = vec![(mirror, scale)];
    if let Bsdf::Glass { eta, .. } = b
        && let Some((t, _)) = refract(wo, Vec3::Z, *eta)
    {
        c.push((t, scale));
    }
    c
}

/// χ² of each anisotropic lobe's sampling against its pdf: metals, glass from both sides, a
/// generalized-Schlick lobe, and a coat turned to its own tangent over a diffuse base.
#[test]
fn anisotropic_sampling_matches_the_pdf() {
    let mut cases: Vec<Chi2Case> = vec![];
    for (ax, ay) in [(0.05f32, 0.3f32), (0.4, 0.08), (0.9, 0.3)] {
        let g = Ggx::anisotropic(ax, ay);
        for (z, phi) in [(0.9, 0.3), (0.4, 1.2), (0.1, 2.0), (-0.6, 0.5)] {
            let wo = dir(z, phi);
            for (name, b) in [("metal", metal(g)), ("glass", glass(g, 1.5))] {
                let c = centres(&b, wo, ax.min(ay));
                cases.push((
                    format!("{name} α ({ax}, {ay}) wo.z {z}"),
                    Box::new(move |uc, u| b.sample(wo, uc, u)),
                    Box::new(move |wi| b.pdf(wo, wi)),
                    c,
                ));
            }
            let spec = Lobe::Specular {
                fresnel: Fresnel::Schlick {
                    color0: Vec3::splat(0.5),
                    color82: Vec3::ONE,
                    color90: Vec3::ONE,
                    exponent: 5.0,
                    film: None,
                },
                tint: Vec3::ONE,
                ggx: g,
            };
            cases.push((
                format!("schlick α ({ax}, {ay}) wo.z {z}"),
                Box::new(move |uc, u| spec.sample(wo, uc, u)),
                Box::new(move |wi| spec.pdf(wo, wi)),
                vec![(Vec3::new(-wo.x, -wo.y, wo.z), ax.min(ay))],
            ));
        }
    }
    // A coat whose tangent is turned 40° from the frame's over a diffuse base (albedo scaling).
    let wo = dir(0.6, 0.9);
    let coat = coated(Vec3::new(0.766, 0.643, 0.0), 3.0, 0.3, wo, LayeringMode::AlbedoScaling);
    cases.push((
        "turned coat over diffuse".into(),
        Box::new(move |uc, u| coat.sample(wo, uc, u)),
        Box::new(move |wi| coat.pdf(wo, wi)),
        vec![(Vec3::new(-wo.x, -wo.y, wo.z), 0.03)],
    ));
    let alpha = 1.0 - (1.0 - 0.01f64).powf(1.0 / cases.len() as f64);
    let mut failures = vec![];
    for (k, (name, sample, pdf, c)) in cases.iter().enumerate() {
        let r = chi2_test(sample, pdf, c, 300 + k as u64);
        eprintln!("chi2 {name:<36} p = {:.4} dof = {:4} ∫pdf = {:.5}", r.p, r.dof, r.integral);
        if r.p < alpha || r.integral > 1.0 + 1e-3 {
            failures.push(format!("{name}: p = {:e}, ∫pdf = {}", r.p, r.integral));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A closure of one anisotropic dielectric coat (roughness `r`, tangent `t` in world space,
/// aspect `aspect`) over a white Lambert base, decoded about world +z for `wo`; its directions
/// are in the frame the closure turned to (x along `t` projected).
fn coated(t: Vec3, aspect: f32, r: f32, wo: Vec3, mode: LayeringMode) -> ClosureBsdf {
    let mut sum = ClosureSum::default();
    sum.terms[0] = term(ClosureKind::Dielectric, &[1.0, 1.0, 1.0, 1.5, r, 0.0], t, aspect);
    sum.terms[1] = ClosureTerm { above: 1, ..term(ClosureKind::Diffuse, &[1.0, 1.0, 1.0], Vec3::ZERO, 0.0) };
    let mut b = ClosureBsdf::from_sum(&sum, mode);
    b.set_term_frames(&sum.terms, &mut Frame::from_normal(Vec3::Z), wo);
    b
}

fn term(kind: ClosureKind, params: &[f32], tangent: Vec3, aspect: f32) -> ClosureTerm {
    let mut t = ClosureTerm { kind: kind as u32, above: 0, weight: [1.0; 3], params: [0.0; TERM_PARAMS] };
    t.params[..params.len()].copy_from_slice(params);
    t.params[TERM_TANGENT..TERM_TANGENT + 3].copy_from_slice(&tangent.to_array());
    t.params[TERM_ASPECT] = aspect;
    t
}

/// A single anisotropic conductor term (`with_anisotropy`) decoded with its tangent, in a
/// shading frame about world `n`, evaluated for world directions.
fn conductor_term(tangent: Vec3, aspect: f32, n: Vec3, wo: Vec3) -> (ClosureBsdf, Frame) {
    let t = term(ClosureKind::Conductor, &[1.3, 1.3, 1.3, 2.7, 2.7, 2.7, 0.5], tangent, aspect);
    let mut sum = ClosureSum::default();
    sum.terms[0] = t;
    let mut b = ClosureBsdf::from_sum(&sum, LayeringMode::AlbedoScaling);
    let mut frame = Frame::from_normal(n);
    b.set_term_frames(&[t], &mut frame, wo);
    (b, frame)
}

/// Two random directions on the side of `n`.
fn facing(rng: &mut Pcg32, n: Vec3) -> (Vec3, Vec3) {
    let side = |v: Vec3| if v.dot(n) < 0.0 { -v } else { v };
    (side(rng.dir()), side(rng.dir()))
}

/// The tangent words orient the lobe: a term stretched by `a` along world x (projected into
/// the tangent plane) evaluates as one stretched by `1/a` along the bitangent n × x (the 90°
/// turn, of any length), and as the distribution built directly in that frame, whatever
/// tangent the shading frame had; aspect 1 leaves the frame alone.
#[test]
fn a_term_is_stretched_along_its_own_tangent() {
    let n = Vec3::new(0.1, -0.2, 1.0).normalize();
    let mut rng = Pcg32::new(3, 4);
    let ggx = Ggx::isotropic(0.25).with_aspect(2.0);
    let direct = Bsdf::Metal { reflectivity: Vec3::ONE, eta: Vec3::splat(1.3), k: Vec3::splat(2.7), ggx };
    for _ in 0..200 {
        let (wo, wi) = facing(&mut rng, n);
        let (bx, fx) = conductor_term(Vec3::X, 2.0, n, wo);
        let (by, fy) = conductor_term(n.cross(Vec3::X) * 3.0, 0.5, n, wo);
        let ex = bx.eval(fx.to_local(wo), fx.to_local(wi)).x;
        let ey = by.eval(fy.to_local(wo), fy.to_local(wi)).x;
        assert!(close(ex, ey, 1e-3), "tangent x aspect 2 {ex} vs tangent y aspect 1/2 {ey}");
        // The distribution in the frame whose x is world x projected.
        let f = Frame::from_normal(n).with_tangent(Vec3::X).unwrap();
        let want = direct.eval(f.to_local(wo), f.to_local(wi)).x;
        assert!(close(ex, want, 1e-3), "term {ex} vs the lobe in the tangent frame {want}");
    }
    // Aspect 1: the shading frame keeps its own tangent (isotropic closures are unchanged).
    let (_, f) = conductor_term(Vec3::X, 1.0, n, n);
    let plain = Frame::from_normal(n);
    assert_eq!((f.t, f.b), (plain.t, plain.b));
}

/// White furnace: a white anisotropic glass (αx 0.02, αy 0.08, the radiance compression
/// undone) conserves energy, R + T = 1 within 1 % up to 60° (at grazing incidence single
/// scattering loses what the masking removes: there E lies between the isotropic glasses of
/// widths αy and αx, as α(φ) does); a perfect anisotropic conductor loses energy to single
/// scattering but never creates it; both by quadrature of `eval` and by sampling.
#[test]
fn anisotropic_white_furnace() {
    for (name, b, at_least) in [
        ("glass", glass(Ggx::anisotropic(0.02, 0.08), 1.5), 0.99),
        (
            "mirror metal",
            Bsdf::Metal {
                reflectivity: Vec3::ONE,
                eta: Vec3::ZERO,
                k: Vec3::splat(1e4),
                ggx: Ggx::anisotropic(0.6, 0.1),
            },
            0.7,
        ),
    ] {
        for z in [0.95f64, 0.5, 0.15, -0.6] {
            if z < 0.0 && name != "glass" {
                continue;
            }
            let wo = dir(z, 0.8);
            let f = |wi: Vec3| b.eval(wo, wi).x * wi.z.abs() * b.compression(wo, wi);
            let quadrature = sphere_integral(f, &centres(&b, wo, 0.02));
            let weight = |s: &BsdfSample| DVec3::splat((s.f.x * s.wi.z.abs() / s.pdf * b.compression(wo, s.wi)) as f64);
            let [(e, se), _] = furnace_weights(|uc, u| b.sample(wo, uc, u), weight, 100_000, 7);
            eprintln!("furnace {name} wo.z {z}: quadrature {quadrature:.5}, sampled {:.5} ± {:.5}", e.x, se.x);
            assert!(quadrature <= 1.0 + 1e-3 && e.x <= 1.0 + 4.0 * se.x + 1e-3, "{name} {z}: E > 1");
            if z.abs() >= 0.5 {
                assert!(quadrature >= at_least, "{name} {z}: E {quadrature} < {at_least}");
            } else if let Bsdf::Glass { ggx, eta, .. } = b {
                let iso = |alpha: f32| {
                    let g = glass(Ggx::isotropic(alpha), eta);
                    sphere_integral(|wi| g.eval(wo, wi).x * wi.z.abs() * g.compression(wo, wi), &centres(&g, wo, 0.02))
                };
                let (wide, narrow) = (iso(ggx.alpha_x().max(ggx.alpha_y())), iso(ggx.alpha_x().min(ggx.alpha_y())));
                eprintln!("  isotropic glasses: α max {wide:.5}, α min {narrow:.5}");
                assert!(wide - 1e-3 <= quadrature && quadrature <= narrow + 1e-3, "{name} {z}: {quadrature}");
            }
            assert!(
                (quadrature - e.x).abs() < 4.0 * se.x + 2e-3,
                "{name} {z}: sampled {} vs quadrature {quadrature}",
                e.x
            );
        }
    }
}

/// Reciprocity: f(wo, wi) = f(wi, wo) for anisotropic reflection (metal, glass reflection,
/// an anisotropic coat over a diffuse base by albedo scaling), and f(wo, wi) / n(wo)² across the
/// glass interface.
#[test]
fn anisotropic_lobes_are_reciprocal() {
    let mut rng = Pcg32::new(11, 6);
    let g = Ggx::anisotropic(0.15, 0.45);
    let (m, gl) = (metal(g), glass(g, 1.5));
    let coat = coated(Vec3::new(0.6, 0.8, 0.0), 2.5, 0.4, Vec3::Z, LayeringMode::AlbedoScaling);
    for _ in 0..500 {
        let (wo, wi) = (rng.dir(), rng.dir());
        let (wo, wi) = (Vec3::new(wo.x, wo.y, wo.z.abs()), Vec3::new(wi.x, wi.y, wi.z.abs()));
        for (name, a, b) in [
            ("metal", m.eval(wo, wi), m.eval(wi, wo)),
            ("glass R", gl.eval(wo, wi), gl.eval(wi, wo)),
            ("coat", coat.eval(wo, wi), coat.eval(wi, wo)),
        ] {
            assert!((a - b).abs().max_element() <= 1e-3 * a.max_element() + 1e-5, "{name}: {a} vs {b}");
        }
        let below = Vec3::new(wi.x, wi.y, -wi.z);
        // Radiance transport: f(wo, wi) / n(wo)² = f(wi, wo) / n(wi)² (n the side's index).
        let (a, b) = (gl.eval(wo, below).x, gl.eval(below, wo).x / (1.5 * 1.5));
        assert!((a - b).abs() <= 1e-3 * a.abs().max(b.abs()) + 1e-5, "glass T: {a} vs {b}");
    }
}

/// Albedo scaling reads the layering tables at the mean width √(αx αy): the furnace gap that
/// leaves for a white anisotropic coat over a white Lambert base against the random walk (the
/// reference, which simulates the anisotropic interface), beside the same gap for the
/// isotropic coat of the same mean width; printed for the note. All ≤ 1, and the walk takes
/// the anisotropic stack (the shading frame turned to the coat's tangent) rather than falling
/// back.
#[test]
fn anisotropic_coat_furnace_gap_under_albedo_scaling() {
    for (r, aspect) in [(0.3f32, 3.0f32), (0.5, 3.0), (0.5, 6.0)] {
        for z in [0.9f64, 0.5, 0.2] {
            let wo = dir(z, 0.4);
            let energy = |aspect: f32| {
                // A tangent the shading frame must turn to (its own is +x).
                let tangent = Vec3::new(0.6, 0.8, 0.0);
                let scaled = coated(tangent, aspect, r, wo, LayeringMode::AlbedoScaling);
                let f = |wi: Vec3| scaled.eval(wo, wi).x * wi.z.max(0.0);
                let e_scaled = sphere_integral(f, &[(Vec3::new(-wo.x, -wo.y, wo.z), r * r / aspect)]);
                let walk = coated(tangent, aspect, r, wo, LayeringMode::RandomWalk);
                assert!(walk.walk.is_some(), "the walk fell back for aspect {aspect}");
                let weight = |s: &BsdfSample| DVec3::splat((s.f.x * s.wi.z.abs() / s.pdf) as f64);
                let [(e_walk, se), _] = furnace_weights(|uc, u| walk.sample(wo, uc, u), weight, 40_000, 3);
                (e_scaled, e_walk.x, se.x)
            };
            let (iso, aniso) = (energy(1.0), energy(aspect));
            eprintln!(
                "coat r {r} aspect {aspect} wo.z {z}: isotropic scaling {:.4} walk {:.4}±{:.4} gap {:+.4}; \
                 anisotropic scaling {:.4} walk {:.4}±{:.4} gap {:+.4}",
                iso.0,
                iso.1,
                iso.2,
                iso.0 - iso.1,
                aniso.0,
                aniso.1,
                aniso.2,
                aniso.0 - aniso.1
            );
            for (e, walk, se) in [iso, aniso] {
                assert!(e <= 1.0 + 1e-3 && walk <= 1.0 + 4.0 * se, "E > 1: scaling {e}, walk {walk}");
            }
        }
    }
    // The diffuse base renders under the coat (the closure decodes the words it is given).
    let b = coated(Vec3::X, 3.0, 0.3, Vec3::Z, LayeringMode::AlbedoScaling);
    assert!(b.eval(Vec3::Z, Vec3::new(0.6, 0.0, 0.8)).x > 0.5 * FRAC_1_PI);
}

/// A coat whose tangent is not the shading frame's first anisotropic tangent (here: a second
/// anisotropic term with another tangent) has a frame of its own, and the walk falls back to
/// albedo scaling for it (reported by `walk::take_fallback`).
#[test]
fn a_walked_stack_with_two_tangents_falls_back() {
    let mut sum = ClosureSum::default();
    sum.terms[0] = term(ClosureKind::Dielectric, &[1.0, 1.0, 1.0, 1.5, 0.3, 0.0], Vec3::X, 2.0);
    sum.terms[1] = ClosureTerm {
        above: 1,
        ..term(ClosureKind::Conductor, &[1.3, 1.3, 1.3, 2.7, 2.7, 2.7, 0.4], Vec3::Y + Vec3::X, 3.0)
    };
    let mut b = ClosureBsdf::from_sum(&sum, LayeringMode::RandomWalk);
    assert!(b.walk.is_some(), "the stack is walkable before its frames are set");
    b.set_term_frames(&sum.terms, &mut Frame::from_normal(Vec3::Z), Vec3::Z);
    assert!(b.walk.is_none(), "a term turned to its own tangent must not be walked");
}

/// Two anisotropic terms with different tangents: the first turns the shading frame, the
/// second turns in a frame of its own; the sum evaluates as each lobe in its own tangent frame.
#[test]
fn a_second_tangent_turns_its_term_alone() {
    let n = Vec3::new(-0.2, 0.1, 1.0).normalize();
    let (t0, t1) = (Vec3::X, Vec3::new(1.0, 1.0, 0.3));
    let mut sum = ClosureSum::default();
    let metal_words = [1.3, 1.3, 1.3, 2.7, 2.7, 2.7, 0.5];
    sum.terms[0] = ClosureTerm { weight: [0.5; 3], ..term(ClosureKind::Conductor, &metal_words, t0, 2.0) };
    sum.terms[1] = ClosureTerm { weight: [0.5; 3], ..term(ClosureKind::Conductor, &metal_words, t1, 3.0) };
    let mut rng = Pcg32::new(21, 3);
    let lobe = |aspect: f32| metal(Ggx::isotropic(0.25).with_aspect(aspect));
    let plain = Frame::from_normal(n);
    let (f0, f1) = (plain.with_tangent(t0).unwrap(), plain.with_tangent(t1).unwrap());
    for _ in 0..200 {
        let (wo, wi) = facing(&mut rng, n);
        let mut b = ClosureBsdf::from_sum(&sum, LayeringMode::AlbedoScaling);
        let mut frame = Frame::from_normal(n);
        b.set_term_frames(&sum.terms, &mut frame, wo);
        let got = b.eval(frame.to_local(wo), frame.to_local(wi)).x;
        let want = 0.5 * lobe(2.0).eval(f0.to_local(wo), f0.to_local(wi)).x
            + 0.5 * lobe(3.0).eval(f1.to_local(wo), f1.to_local(wi)).x;
        assert!(close(got, want, 1e-3), "{got} vs {want}");
    }
}
