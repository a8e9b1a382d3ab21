//! Test statistics shared by the BSDF and layered-shading tests: a seedable PCG32 stream, the
//! χ² distribution's tail (regularized incomplete gamma), and a χ² goodness-of-fit test of a
//! direction sampler against its pdf over the sphere (after pbrt-v4's bsdfs_test and Mitsuba's
//! chi2.py), with graded binning around narrow lobes and Šidák-ready p-values.

use crate::render::material::bsdf::BsdfSample;
use glam::{DVec3, Vec2, Vec3};
use std::f64::consts::TAU;

/// A white furnace at one `wo`: mean and standard error, per channel, of the throughput
/// `weight` (`f |cos θi| / pdf`, or however a test reduces it) of `n` samples drawn with
/// `sample(uc, u)`, summed in f64, over all samples and over the non-delta part alone (delta
/// samples count 0 there).
pub fn furnace_weights(
    sample: impl Fn(f32, Vec2) -> Option<BsdfSample>,
    weight: impl Fn(&BsdfSample) -> DVec3,
    n: usize,
    seed: u64,
) -> [(DVec3, DVec3); 2] {
    let mut rng = Pcg32::new(seed, 3);
    let mut sums = [[DVec3::ZERO; 2]; 2];
    for _ in 0..n {
        let uc = rng.f32();
        let u = rng.vec2();
        if let Some(s) = sample(uc, u) {
            let w = weight(&s);
            for (k, sum) in sums.iter_mut().enumerate() {
                if k == 0 || !s.delta {
                    sum[0] += w;
                    sum[1] += w * w;
                }
            }
        }
    }
    sums.map(|[sum, sum2]| {
        let mean = sum / n as f64;
        let var = (sum2 / n as f64 - mean * mean).max(DVec3::ZERO);
        (mean, DVec3::from_array((var / n as f64).to_array().map(f64::sqrt)))
    })
}

/// PCG32 (O'Neill 2014, XSH-RR): a deterministic, seedable stream for the tests.
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

impl Pcg32 {
    pub fn new(seed: u64, stream: u64) -> Pcg32 {
        let mut r = Pcg32 { state: 0, inc: (stream << 1) | 1 };
        r.next_u32();
        r.state = r.state.wrapping_add(seed);
        r.next_u32();
        r
    }
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(6364136223846793005).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }
    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }
    pub fn vec2(&mut self) -> Vec2 {
        Vec2::new(self.f32(), self.f32())
    }
    /// Uniform direction on the sphere.
    pub fn dir(&mut self) -> Vec3 {
        dir(2.0 * self.f32() as f64 - 1.0, TAU * self.f32() as f64)
    }
}
pub fn dir(cos_theta: f64, phi: f64) -> Vec3 {
    let s = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    Vec3::new((s * phi.cos()) as f32, (s * phi.sin()) as f32, cos_theta as f32)
}

// ---------------------------------------------------------------- statistics

/// ln Γ(x) for x > 0 (Lanczos, g = 7, n = 9; ~1e-15 relative).
pub fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection formula.
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let mut a = C[0];
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (TAU).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised upper incomplete gamma Q(a, x) (series for x < a + 1, Lentz's continued
/// fraction otherwise; Numerical Recipes §6.2).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let prefactor = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut del) = (a, 1.0 / a);
        let mut sum = del;
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        (1.0 - sum * prefactor).max(0.0)
    } else {
        const TINY: f64 = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / TINY;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < TINY {
                d = TINY;
            }
            c = b + an / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (prefactor * h).clamp(0.0, 1.0)
    }
}

/// P(χ² ≥ stat) with `dof` degrees of freedom.
pub fn chi2_p_value(stat: f64, dof: usize) -> f64 {
    gamma_q(dof as f64 / 2.0, stat / 2.0)
}

#[test]
pub fn incomplete_gamma_known_values() {
    // Q(1, x) = e^-x; Q(1/2, x) = erfc(√x); χ² tables: P(χ²₁₀ ≥ 23.209) = 0.01, P(χ²₁₀₀ ≥ 135.807) = 0.01.
    for x in [0.01f64, 0.5, 1.0, 3.0, 10.0, 40.0] {
        assert!((gamma_q(1.0, x) - (-x).exp()).abs() < 1e-12, "Q(1, {x})");
    }
    assert!((gamma_q(0.5, 1.0) - 0.157_299_207_050_285_1).abs() < 1e-10);
    assert!((chi2_p_value(23.209, 10) - 0.01).abs() < 1e-4);
    assert!((chi2_p_value(135.807, 100) - 0.01).abs() < 1e-4);
    assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-12);
    assert!((ln_gamma(10.0) - 362_880f64.ln()).abs() < 1e-10);
}

// ---------------------------------------------------------------- chi-square harness

/// Total χ² tests in the suite (every case of `chi2_cases` plus none else): the Šidák
/// correction keeps the family-wise false-failure rate at `SIGNIFICANCE`.
pub const SIGNIFICANCE: f64 = 0.01;
pub const CHI2_SAMPLES: usize = 200_000;
pub const MIN_EXPECTED: f64 = 5.0;

pub struct Chi2 {
    pub p: f64,
    pub stat: f64,
    pub dof: usize,
    /// ∫ pdf over the sphere.
    pub integral: f64,
    /// Samples that were `None` or delta.
    pub missed: usize,
}

/// Bin edges on [lo, hi]: a uniform coarse grid plus geometric ladders (ratio 2, from
/// scale/8 up to the coarse width) on both sides of each lobe centre, so that lobes much
/// narrower than a coarse bin are still resolved by the per-bin quadrature.
pub fn edges(lo: f64, hi: f64, coarse: usize, centres: &[(f64, f64)], periodic: bool) -> Vec<f64> {
    let width = (hi - lo) / coarse as f64;
    let mut e: Vec<f64> = (0..=coarse).map(|i| lo + width * i as f64).collect();
    if lo < 0.0 && hi > 0.0 {
        e.push(0.0); // the horizon, where reflection lobes end
    }
    for &(c, scale) in centres.iter().filter(|c| c.1 > 0.0) {
        let mut off = scale / 64.0;
        while off < width {
            for x in [c - off, c + off] {
                let x = if periodic { lo + (x - lo).rem_euclid(hi - lo) } else { x };
                if x > lo && x < hi {
                    e.push(x);
                }
            }
            off *= 2.0;
        }
    }
    e.sort_by(f64::total_cmp);
    e.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    e
}

/// 4-point Gauss–Legendre nodes and weights on [-1, 1].
pub const GL_X: [f64; 4] =
    [-0.861_136_311_594_052_6, -0.339_981_043_584_856_3, 0.339_981_043_584_856_3, 0.861_136_311_594_052_6];
pub const GL_W: [f64; 4] =
    [0.347_854_845_137_453_9, 0.652_145_154_862_546_1, 0.652_145_154_862_546_1, 0.347_854_845_137_453_9];

/// ∫ pdf over a (cos θ, φ) rectangle by tensor 4-point Gauss–Legendre, and whether the
/// rectangle straddles the pdf's support boundary (some nodes zero, some not).
pub fn gauss_legendre(pdf: &impl Fn(Vec3) -> f32, [c0, c1, p0, p1]: [f64; 4]) -> (f64, bool) {
    let (mut sum, mut zeros) = (0.0, 0);
    for (xa, wa) in GL_X.iter().zip(GL_W) {
        let c = 0.5 * (c0 + c1) + 0.5 * (c1 - c0) * xa;
        for (xb, wb) in GL_X.iter().zip(GL_W) {
            let phi = 0.5 * (p0 + p1) + 0.5 * (p1 - p0) * xb;
            let p = pdf(dir(c, phi)) as f64;
            zeros += (p == 0.0) as usize;
            sum += wa * wb * p;
        }
    }
    (sum * 0.25 * (c1 - c0) * (p1 - p0), zeros > 0 && zeros < 16)
}

/// Adaptive quadrature: a rectangle is split in four while that changes its estimate by
/// more than 0.02 samples' worth or it straddles the pdf's support boundary (where the pdf
/// drops to 0, often with an infinite slope: the edge of rough transmission, of total
/// internal reflection), where a single Gauss–Legendre rule is badly wrong. Rectangles
/// expecting under half a sample are not refined unless they straddle.
pub fn integrate(pdf: &impl Fn(Vec3) -> f32, rect: [f64; 4], depth: u32) -> f64 {
    let n = CHI2_SAMPLES as f64;
    let (whole, straddles) = gauss_legendre(pdf, rect);
    if depth == 0 || (!straddles && whole * n < 0.5) {
        return whole;
    }
    let [c0, c1, p0, p1] = rect;
    let (cm, pm) = (0.5 * (c0 + c1), 0.5 * (p0 + p1));
    let quads = [[c0, cm, p0, pm], [cm, c1, p0, pm], [c0, cm, pm, p1], [cm, c1, pm, p1]];
    let split: f64 = quads.iter().map(|&q| gauss_legendre(pdf, q).0).sum();
    if !straddles && (split - whole).abs() * n < 0.02 {
        return split;
    }
    quads.iter().map(|&q| integrate(pdf, q, depth - 1)).sum()
}

/// The (cos θ, φ) bin edges over the sphere: a coarse grid graded around each lobe centre
/// `(direction, angular scale)`.
fn grid(centres: &[(Vec3, f32)]) -> (Vec<f64>, Vec<f64>) {
    let mut cc = vec![];
    let mut pc = vec![];
    for &(d, s) in centres {
        let (s, z) = (s as f64, (d.z as f64).clamp(-1.0, 1.0));
        let sin = (1.0 - z * z).max(0.0).sqrt();
        cc.push((z, s * sin + s * s));
        if s < sin {
            pc.push(((d.y as f64).atan2(d.x as f64).rem_euclid(TAU), s / sin));
        }
    }
    (edges(-1.0, 1.0, 20, &cc, false), edges(0.0, TAU, 40, &pc, true))
}

/// ∫ f dω over the sphere by the χ² test's quadrature: adaptive Gauss–Legendre on each bin of
/// the grid graded around `centres`. A deterministic reference, independent of any sampler.
pub fn sphere_integral(f: impl Fn(Vec3) -> f32, centres: &[(Vec3, f32)]) -> f64 {
    let (ce, pe) = grid(centres);
    let mut sum = 0.0;
    for c in ce.windows(2) {
        for p in pe.windows(2) {
            sum += integrate(&f, [c[0], c[1], p[0], p[1]], 6);
        }
    }
    sum
}

/// χ² goodness of fit of `sample` against `pdf` over the sphere, binned in (cos θ, φ) (an
/// equal-area parametrisation: dω = d cos θ dφ), as pbrt-v4's bsdfs_test and Mitsuba's
/// chi2.py do. Cells expecting fewer than `MIN_EXPECTED` samples are pooled; samples that are
/// `None` or delta form one extra cell expecting `N (1 − ∫ pdf)`.
pub fn chi2_test(
    sample: impl Fn(f32, Vec2) -> Option<BsdfSample>,
    pdf: impl Fn(Vec3) -> f32,
    centres: &[(Vec3, f32)],
    seed: u64,
) -> Chi2 {
    let (ce, pe) = grid(centres);
    let (nc, np) = (ce.len() - 1, pe.len() - 1);

    let mut observed = vec![0usize; nc * np];
    let mut missed = 0;
    let mut rng = Pcg32::new(seed, 7);
    for _ in 0..CHI2_SAMPLES {
        let uc = rng.f32();
        let u = rng.vec2();
        match sample(uc, u) {
            Some(s) if !s.delta => {
                assert!((s.wi.length() - 1.0).abs() < 1e-3, "sampled direction not unit: {}", s.wi);
                let z = (s.wi.z as f64).clamp(-1.0, 1.0);
                let phi = (s.wi.y as f64).atan2(s.wi.x as f64).rem_euclid(TAU);
                let i = ce.partition_point(|&e| e <= z).clamp(1, nc) - 1;
                let j = pe.partition_point(|&e| e <= phi).clamp(1, np) - 1;
                observed[i * np + j] += 1;
            }
            _ => missed += 1,
        }
    }

    let mut expected = vec![0.0f64; nc * np];
    for i in 0..nc {
        for j in 0..np {
            let bin = [ce[i], ce[i + 1], pe[j], pe[j + 1]];
            expected[i * np + j] = integrate(&pdf, bin, 6) * CHI2_SAMPLES as f64;
        }
    }
    let integral = expected.iter().sum::<f64>() / CHI2_SAMPLES as f64;

    if std::env::var("CHI2_DEBUG").is_ok() {
        let mut worst: Vec<(f64, usize)> =
            (0..nc * np).map(|k| ((observed[k] as f64 - expected[k]).powi(2) / expected[k].max(1.0), k)).collect();
        worst.sort_by(|a, b| b.0.total_cmp(&a.0));
        for &(w, k) in &worst[..8] {
            let (i, j) = (k / np, k % np);
            eprintln!(
                "  c [{:.5},{:.5}] phi [{:.5},{:.5}] exp {:.1} obs {} contrib {w:.1}",
                ce[i],
                ce[i + 1],
                pe[j],
                pe[j + 1],
                expected[k],
                observed[k]
            );
        }
    }
    let mut cells: Vec<(f64, usize)> = expected.into_iter().zip(observed).collect();
    cells.push(((1.0 - integral).max(0.0) * CHI2_SAMPLES as f64, missed));
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut stat, mut dof) = (0.0, 0usize);
    let (mut pool_exp, mut pool_obs) = (0.0, 0usize);
    for (exp, obs) in cells {
        if exp < MIN_EXPECTED || (pool_exp > 0.0 && pool_exp < MIN_EXPECTED) {
            pool_exp += exp;
            pool_obs += obs;
        } else {
            stat += (obs as f64 - exp).powi(2) / exp;
            dof += 1;
        }
    }
    if pool_exp > 0.0 || pool_obs > 0 {
        // A pool expecting ~nothing yet observing samples means sampling outside the pdf's support.
        stat += (pool_obs as f64 - pool_exp).powi(2) / pool_exp.max(1.0);
        dof += 1;
    }
    let dof = dof.saturating_sub(1).max(1);
    Chi2 { p: chi2_p_value(stat, dof), stat, dof, integral, missed }
}
