//! Random numbers and sample warps.
//!
//! The sampler is counter based: every camera sample's stream is a pure function of
//! (seed, pixel, sample index), so an image is bit-identical whatever the thread count or
//! the order in which tiles are rendered.

pub mod sampler;

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// SplitMix64 finaliser: a bijective 64-bit mix with good avalanche.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A deterministic stream of uniform numbers for one camera sample.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
}

impl Rng {
    /// The stream of sample `sample` of pixel `pixel` under `seed`.
    pub fn new(seed: u64, pixel: u64, sample: u64) -> Rng {
        let state = mix64(mix64(mix64(seed ^ 0x5851_f42d_4c95_7f2d) ^ pixel) ^ sample.wrapping_mul(0x9e37_79b9));
        Rng { state }
    }

    /// The next 64 random bits (SplitMix64).
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        mix64(self.state)
    }

    /// A uniform float in [0, 1) (24 random bits, so never 1).
    #[inline]
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Two uniform floats.
    #[inline]
    pub fn uniform2(&mut self) -> Vec2 {
        Vec2::new(self.uniform(), self.uniform())
    }
}

/// Cosine-weighted hemisphere direction around +z (pdf = cos θ / π).
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    Vec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt())
}

/// Uniform point on the unit disk (Shirley–Chiu concentric map, keeps stratification).
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) =
        if o.x.abs() > o.y.abs() { (o.x, FRAC_PI_4 * (o.y / o.x)) } else { (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y)) };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Uniform direction on the unit sphere (pdf = 1 / 4π).
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Uniform direction in the cone around +z with cosine `cos_max` (pdf = 1 / (2π(1 − cos_max))).
pub fn uniform_cone(u: Vec2, cos_max: f32) -> Vec3 {
    let cos_t = 1.0 - u.x * (1.0 - cos_max);
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)
}

/// Power heuristic (β = 2) weight of strategy `a` against `b`.
#[inline]
pub fn power_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    let a = pdf_a * pdf_a;
    let b = pdf_b * pdf_b;
    if a == 0.0 {
        0.0
    } else if b.is_infinite() || !(a + b).is_finite() {
        if a.is_infinite() { 1.0 } else { 0.0 }
    } else {
        a / (a + b)
    }
}

/// A piecewise-constant 1D distribution over [0, 1).
#[derive(Clone, Debug)]
pub struct Distribution1D {
    func: Vec<f32>,
    cdf: Vec<f32>,
    /// The function's integral over [0, 1): 0 for an all-zero function.
    integral: f32,
    /// An all-zero function, sampled uniformly so that sampling never fails.
    uniform: bool,
}

impl Distribution1D {
    /// Builds from non-negative function values (non-finite or negative entries count as 0).
    /// An all-zero function is sampled uniformly, so sampling never fails, but keeps its
    /// integral of 0: as a row of a [`Distribution2D`] (a black band of an environment map)
    /// its marginal probability is 0, and no sample is spent there.
    pub fn new(values: &[f32]) -> Distribution1D {
        let n = values.len().max(1);
        let mut func: Vec<f32> = values.iter().map(|&v| if v.is_finite() && v > 0.0 { v } else { 0.0 }).collect();
        func.resize(n, 0.0);
        let mut cdf = vec![0.0f32; n + 1];
        for i in 0..n {
            cdf[i + 1] = cdf[i] + func[i] / n as f32;
        }
        let integral = cdf[n];
        let uniform = integral <= 0.0;
        if uniform {
            for (i, c) in cdf.iter_mut().enumerate() {
                *c = i as f32 / n as f32;
            }
        } else {
            cdf.iter_mut().for_each(|c| *c /= integral);
        }
        cdf[n] = 1.0;
        Distribution1D { func, cdf, integral: if uniform { 0.0 } else { integral }, uniform }
    }

    /// Number of pieces.
    pub fn len(&self) -> usize {
        self.func.len()
    }

    /// Whether it has no pieces (never: an empty input gives one piece).
    pub fn is_empty(&self) -> bool {
        self.func.is_empty()
    }

    /// The integral of the function over [0, 1) (0 for an all-zero function).
    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Samples a continuous position in [0, 1): `(x, pdf, piece)`.
    pub fn sample_continuous(&self, u: f32) -> (f32, f32, usize) {
        let i = self.find(u);
        let du = u - self.cdf[i];
        let width = self.cdf[i + 1] - self.cdf[i];
        let du = if width > 0.0 { du / width } else { 0.0 };
        let pdf = if self.uniform { 1.0 } else { self.func[i] / self.integral };
        let x = ((i as f32 + du) / self.len() as f32).min(1.0 - f32::EPSILON);
        (x, pdf, i)
    }

    /// Picks a piece as [`Distribution1D::sample_discrete`] does and also returns where `u`
    /// fell within it, rescaled to [0, 1): `(index, remainder)`. The remainder is uniform and
    /// independent of the choice, so one number can make both. No probability: the caller
    /// (the light selection) keeps them in a table of its own, or takes
    /// [`Distribution1D::discrete_pdf`].
    pub fn sample_piece_remapped(&self, u: f32) -> (usize, f32) {
        let i = self.find(u);
        let width = self.cdf[i + 1] - self.cdf[i];
        let rest = if width > 0.0 { ((u - self.cdf[i]) / width).clamp(0.0, 1.0 - f32::EPSILON / 2.0) } else { 0.0 };
        (i, rest)
    }

    /// Samples a piece: `(index, probability)`.
    pub fn sample_discrete(&self, u: f32) -> (usize, f32) {
        let i = self.find(u);
        (i, self.discrete_pdf(i))
    }

    /// Probability of picking piece `i` with [`Distribution1D::sample_discrete`].
    pub fn discrete_pdf(&self, i: usize) -> f32 {
        match self.func.get(i) {
            None => 0.0,
            Some(_) if self.uniform => 1.0 / self.len() as f32,
            Some(f) => f / (self.integral * self.len() as f32),
        }
    }

    /// Density of [`Distribution1D::sample_continuous`] at `x`.
    pub fn pdf(&self, x: f32) -> f32 {
        if self.uniform {
            return 1.0;
        }
        let i = ((x * self.len() as f32) as usize).min(self.len() - 1);
        self.func[i] / self.integral
    }

    fn find(&self, u: f32) -> usize {
        // One piece (a scene with one light): the search below can only give 0.
        if self.func.len() == 1 {
            return 0;
        }
        // Largest i with cdf[i] <= u, skipping zero-width pieces.
        let i = self.cdf.partition_point(|&c| c <= u).saturating_sub(1);
        let mut i = i.min(self.len() - 1);
        while i + 1 < self.len() && self.func[i] == 0.0 && self.cdf[i + 1] <= u {
            i += 1;
        }
        i
    }
}

/// A piecewise-constant 2D distribution over [0, 1)²: a marginal over rows, a conditional per row.
#[derive(Clone, Debug)]
pub struct Distribution2D {
    rows: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl Distribution2D {
    /// Builds from `width × height` values, row-major (row = v).
    pub fn new(values: &[f32], width: usize, height: usize) -> Distribution2D {
        let rows: Vec<Distribution1D> =
            (0..height).map(|y| Distribution1D::new(&values[y * width..(y + 1) * width])).collect();
        let marginal = Distribution1D::new(&rows.iter().map(|r| r.integral()).collect::<Vec<_>>());
        Distribution2D { rows, marginal }
    }

    /// Samples `(u, v)` and its density with respect to area in [0, 1)².
    pub fn sample(&self, u: Vec2) -> (Vec2, f32) {
        let (v, pdf_v, row) = self.marginal.sample_continuous(u.y);
        let (x, pdf_u, _) = self.rows[row].sample_continuous(u.x);
        (Vec2::new(x, v), pdf_v * pdf_u)
    }

    /// Density at `(u, v)`.
    pub fn pdf(&self, p: Vec2) -> f32 {
        if self.marginal.uniform {
            // An all-black map, sampled uniformly.
            return 1.0;
        }
        let row = ((p.y * self.rows.len() as f32) as usize).min(self.rows.len() - 1);
        let r = &self.rows[row];
        let col = ((p.x * r.len() as f32) as usize).min(r.len() - 1);
        r.func[col] / self.marginal.integral
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The light choice hands its remainder to the point on the light: the piece must be the
    /// one `sample_discrete` picks, and the remainder place `u` within it, so that over a
    /// stratified `u` each piece's remainders are stratified over [0, 1) too.
    #[test]
    fn a_remapped_choice_is_the_choice_and_its_remainder_is_uniform() {
        let d = Distribution1D::new(&[0.5, 0.0, 2.0, 1.5]);
        let n = 4000;
        let mut rests: Vec<Vec<f32>> = vec![Vec::new(); 4];
        for k in 0..n {
            let u = (k as f32 + 0.5) / n as f32;
            let (i, rest) = d.sample_piece_remapped(u);
            assert_eq!((i, d.discrete_pdf(i)), d.sample_discrete(u));
            assert!((0.0..1.0).contains(&rest), "{rest}");
            let back = d.cdf[i] + rest * (d.cdf[i + 1] - d.cdf[i]);
            assert!((back - u).abs() < 1e-5, "{u} -> piece {i}, {rest} -> {back}");
            rests[i].push(rest);
        }
        assert!(rests[1].is_empty());
        for (i, r) in rests.iter().enumerate().filter(|(_, r)| !r.is_empty()) {
            // Stratified: the sorted remainders are evenly spaced over [0, 1).
            let m = r.len() as f32;
            for (j, x) in r.iter().enumerate() {
                assert!((x - (j as f32 + 0.5) / m).abs() < 1.5 / m, "piece {i}: {j}th remainder {x} of {m}");
            }
        }
    }

    #[test]
    fn rng_is_deterministic_and_uniform() {
        let mut a = Rng::new(1, 2, 3);
        let mut b = Rng::new(1, 2, 3);
        let mut c = Rng::new(1, 2, 4);
        let mut sum = 0.0;
        let mut differs = false;
        for _ in 0..10000 {
            let x = a.uniform();
            assert_eq!(x, b.uniform());
            assert!((0.0..1.0).contains(&x));
            differs |= x != c.uniform();
            sum += x as f64;
        }
        assert!(differs);
        assert!((sum / 10000.0 - 0.5).abs() < 0.01);
    }

    #[test]
    fn black_rows_of_a_map_are_never_sampled() {
        // A sky whose lower half is black (rows 2 and 3 of 4): before, each black row was
        // made uniform with integral 1 and outweighed the sky, taking most of the samples.
        let (w, h) = (4, 4);
        let values: Vec<f32> = (0..w * h).map(|i| if i / w < 2 { 0.01 } else { 0.0 }).collect();
        let d = Distribution2D::new(&values, w, h);
        let mut rng = Rng::new(0, 0, 1);
        let n = 20000;
        let below = (0..n).filter(|_| d.sample(rng.uniform2()).0.y >= 0.5).count();
        assert_eq!(below, 0, "{below} of {n} samples in black rows");
        assert_eq!(d.pdf(Vec2::new(0.3, 0.8)), 0.0);
        assert!((d.pdf(Vec2::new(0.3, 0.2)) - 2.0).abs() < 1e-5, "half the square holds all the density");
        // An all-black map is sampled uniformly (density 1), never NaN.
        let black = Distribution2D::new(&[0.0; 6], 3, 2);
        let (p, pdf) = black.sample(Vec2::new(0.4, 0.7));
        assert!(pdf == 1.0 && black.pdf(p) == 1.0 && p.is_finite());
        // A single all-zero 1D distribution still samples every piece uniformly.
        let flat = Distribution1D::new(&[0.0, 0.0]);
        assert_eq!((flat.integral(), flat.discrete_pdf(1), flat.pdf(0.7)), (0.0, 0.5, 1.0));
    }

    #[test]
    fn distribution_2d_pdf_matches_sampling() {
        let values = [1.0, 3.0, 0.0, 4.0, 2.0, 2.0];
        let d = Distribution2D::new(&values, 3, 2);
        let mut rng = Rng::new(0, 0, 0);
        let mut counts = [0usize; 6];
        let n = 60000;
        for _ in 0..n {
            let (p, pdf) = d.sample(rng.uniform2());
            assert!((pdf - d.pdf(p)).abs() < 1e-4);
            let i = ((p.y * 2.0) as usize) * 3 + (p.x * 3.0) as usize;
            counts[i] += 1;
        }
        let total: f32 = values.iter().sum();
        for (i, &c) in counts.iter().enumerate() {
            let expected = values[i] / total;
            assert!((c as f32 / n as f32 - expected).abs() < 0.01, "cell {i}");
        }
    }
}
