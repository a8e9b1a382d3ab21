//! The path sampler: the uniform numbers of one camera sample, one per decision.
//!
//! Every decision a path makes (where in the pixel, where on the lens, which layer, which
//! light and where on it, which lobe and which direction, whether to stop) reads its numbers
//! from a fixed *dimension*: the vertex it is made at and a [`Slot`] naming the decision. A
//! dimension's numbers over the pixel's samples are either independent
//! ([`SamplerKind::Independent`]) or the first two dimensions of the Sobol sequence with
//! Owen scrambling and an Owen-scrambled (shuffled) sample index, seeded per pixel and
//! dimension ([`SamplerKind::Sobol`]; Burley, "Practical Hash-based Owen Scrambling", JCGT
//! 2020). The Sobol points of any power-of-two run of samples are stratified in every
//! elementary interval of 1D and 2D, so the variance of smooth integrands falls faster than
//! 1/n; the per-pixel, per-dimension seeds decorrelate pixels and dimensions.
//!
//! Both are counter based: a number is a pure function of (seed, pixel, sample index,
//! vertex, slot). An image is therefore the same whatever the thread count and the order
//! of tiles, and a range of samples renders the same alone as inside a larger range.
//! Decisions that a path makes a varying number of times (passing through transparent
//! layers) take their own slots, so they never shift the dimensions of later decisions.

use glam::Vec2;

/// How a pixel's samples are spread over each dimension.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SamplerKind {
    /// Owen-scrambled Sobol points, shuffled per pixel and dimension (the default).
    #[default]
    Sobol,
    /// Independent uniform numbers (plain Monte Carlo), for comparison.
    Independent,
}

impl SamplerKind {
    /// The name used on the command line and in EXR metadata.
    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Sobol => "sobol",
            SamplerKind::Independent => "independent",
        }
    }

    /// Parses [`SamplerKind::name`].
    pub fn from_name(name: &str) -> Option<SamplerKind> {
        match name {
            "sobol" => Some(SamplerKind::Sobol),
            "independent" => Some(SamplerKind::Independent),
            _ => None,
        }
    }
}

/// The decision a number is drawn for, at one path vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum Slot {
    /// Position in the pixel (2D, vertex 0).
    Pixel = 0,
    /// Position on the lens (2D, vertex 0).
    Lens,
    /// The layer pick at the surface a vertex's ray meets first.
    LayerPick,
    /// Which light to sample: no longer drawn (the light is chosen by [`Slot::LightPoint`]'s
    /// first coordinate, whose remainder places the point), kept so later slots keep their
    /// dimensions.
    LightChoice,
    /// Which light, and where on it (2D: the first coordinate chooses the light).
    LightPoint,
    /// Which triangle of an emissive mesh.
    EmitterTriangle,
    /// The layer pick on the sampled point of an emissive mesh.
    EmitterPick,
    /// Which BSDF lobe.
    Lobe,
    /// The sampled direction (2D).
    Direction,
    /// Russian roulette.
    Roulette,
    /// The layer pick after passing through `n` transparent picks: [`Slot::PassPick`]` + n`.
    PassPick,
    /// The camera ray's time across an open shutter (vertex 0). Numbered far above the pass
    /// picks, so adding it moved no other decision's dimension: images rendered before it
    /// are unchanged.
    Time = 1 << 30,
}

/// The numbers of one camera sample.
#[derive(Clone, Debug)]
pub struct PathSampler {
    kind: SamplerKind,
    /// Hash of (seed, pixel): every dimension's scrambles derive from it.
    pixel_key: u64,
    sample: u32,
    /// `sample.reverse_bits()`, which every Sobol number starts from (a bit reversal is some
    /// fifteen instructions on baseline x86-64; [`reversed_and_sobol_1`]'s four lookups
    /// give it).
    sample_reversed: u32,
    vertex: u32,
}

impl PathSampler {
    /// The sampler of sample `sample` of pixel `pixel` under `seed`, at vertex 0.
    pub fn new(kind: SamplerKind, seed: u64, pixel: u64, sample: u32) -> PathSampler {
        PathSampler::of_pixel(kind, PathSampler::pixel_key(seed, pixel), sample)
    }

    /// The key every dimension of pixel `pixel` under `seed` derives from: computed once per
    /// pixel by a caller that loops over its samples ([`PathSampler::of_pixel`]).
    #[inline]
    pub fn pixel_key(seed: u64, pixel: u64) -> u64 {
        mix64(mix64(seed ^ 0x5851_f42d_4c95_7f2d) ^ pixel.wrapping_mul(0xd6e8_feb8_6659_fd93))
    }

    /// The sampler of sample `sample` of the pixel whose [`PathSampler::pixel_key`] is
    /// `pixel_key`, at vertex 0 (the same as [`PathSampler::new`]).
    #[inline]
    pub fn of_pixel(kind: SamplerKind, pixel_key: u64, sample: u32) -> PathSampler {
        PathSampler { kind, pixel_key, sample, sample_reversed: reversed_and_sobol_1(sample).0, vertex: 0 }
    }

    /// Moves to path vertex `vertex` (0 is the camera's ray; a bounce adds one).
    #[inline]
    pub fn set_vertex(&mut self, vertex: u32) {
        self.vertex = vertex;
    }

    /// One uniform number in [0, 1) for `slot` at the current vertex.
    #[inline]
    pub fn get1(&self, slot: Slot) -> f32 {
        self.get1_at(slot as u32)
    }

    /// The layer pick after `passes` transparent picks at the current vertex.
    #[inline]
    pub fn pass_pick(&self, passes: u32) -> f32 {
        self.get1_at((Slot::PassPick as u32).saturating_add(passes))
    }

    /// Two uniform numbers in [0, 1)² for `slot` at the current vertex.
    #[inline]
    pub fn get2(&self, slot: Slot) -> Vec2 {
        let key = self.dimension_key(slot as u32);
        match self.kind {
            SamplerKind::Independent => {
                let bits = mix64(key ^ u64::from(self.sample).wrapping_mul(0x9e37_79b9_7f4a_7c15));
                Vec2::new(unit((bits >> 32) as u32), unit(bits as u32))
            }
            SamplerKind::Sobol => {
                // In the reversed-bit domain (see `owen_hash`): `index` is the shuffled
                // sample index reversed, whose Sobol dimension 0 is the index itself.
                let index = owen_hash(self.sample_reversed, key as u32);
                let (index_bits, y_bits) = reversed_and_sobol_1(index);
                let x = owen_hash(index_bits, (key >> 32) as u32);
                let y = owen_hash(y_bits, mix64(key) as u32);
                Vec2::new(unit_reversed(x), unit_reversed(y))
            }
        }
    }

    fn get1_at(&self, slot: u32) -> f32 {
        let key = self.dimension_key(slot);
        match self.kind {
            SamplerKind::Independent => {
                unit((mix64(key ^ u64::from(self.sample).wrapping_mul(0x9e37_79b9_7f4a_7c15)) >> 32) as u32)
            }
            SamplerKind::Sobol => {
                let index = owen_hash(self.sample_reversed, key as u32);
                unit_reversed(owen_hash(reversed_and_sobol_1(index).0, (key >> 32) as u32))
            }
        }
    }

    /// The seed of dimension (vertex, slot) in this pixel.
    #[inline]
    fn dimension_key(&self, slot: u32) -> u64 {
        let (vertex, slot) = (self.vertex as usize, slot as usize);
        let dimension = match DIMENSION_HASHES.get(vertex).and_then(|row| row.get(slot)) {
            Some(&hash) => hash,
            None => dimension_hash(vertex as u32, slot as u32),
        };
        mix64(self.pixel_key ^ dimension)
    }
}

/// The hash of dimension (vertex, slot), which a pixel's key is mixed with.
#[inline]
const fn dimension_hash(vertex: u32, slot: u32) -> u64 {
    mix64(((vertex as u64) << 32) | slot as u64)
}

/// [`dimension_hash`] of the first 16 vertices' first 16 slots, tabulated (2 KiB): one mix
/// per number instead of two.
const DIMENSION_HASHES: [[u64; 16]; 16] = {
    let mut table = [[0u64; 16]; 16];
    let mut vertex = 0;
    while vertex < 16 {
        let mut slot = 0;
        while slot < 16 {
            table[vertex][slot] = dimension_hash(vertex as u32, slot as u32);
            slot += 1;
        }
        vertex += 1;
    }
    table
};

/// SplitMix64 finaliser: a bijective 64-bit mix with good avalanche.
#[inline]
const fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The top 24 bits of `bits` as a float in [0, 1) (never 1).
#[inline]
fn unit(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// `unit(bits.reverse_bits())`: the top 24 bits of the reversal are the low 24 bits of `bits`
/// reversed, three byte-table lookups (a 32-bit reversal is some fifteen instructions on
/// baseline x86-64, which has no instruction for it), each table holding its byte already
/// reversed into place, so the lookups are only or-ed together.
#[inline]
fn unit_reversed(bits: u32) -> f32 {
    let [low, middle, high] = &REVERSED_BYTES_IN_PLACE;
    let top = low[(bits & 0xff) as usize] | middle[(bits >> 8 & 0xff) as usize] | high[(bits >> 16 & 0xff) as usize];
    top as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Entry `[b][byte]`: `byte << 8b` reversed and shifted right by 8, the place its bits take
/// in the top 24 bits of a reversal (3 KiB).
const REVERSED_BYTES_IN_PLACE: [[u32; 256]; 3] = {
    let mut table = [[0u32; 256]; 3];
    let mut entry = 0;
    while entry < 3 * 256 {
        let (b, byte) = (entry / 256, entry % 256);
        table[b][byte] = ((byte as u32) << (8 * b)).reverse_bits() >> 8;
        entry += 1;
    }
    table
};

/// Sobol dimension 0 (van der Corput in base 2) of point `index`, as 32 bits of fraction.
#[cfg(test)]
fn sobol_0(index: u32) -> u32 {
    index.reverse_bits()
}

/// Sobol dimension 1 of point `index`, as 32 bits of fraction: the XOR of the direction
/// numbers of `index`'s set bits (the definition; the sampler uses [`sobol_1_reversed`]).
#[cfg(test)]
fn sobol_1(index: u32) -> u32 {
    (0..32).filter(|k| index >> k & 1 != 0).fold(0, |bits, k| bits ^ SOBOL_1_DIRECTIONS[k])
}

/// Direction numbers of Sobol dimension 1: primitive polynomial x + 1 (degree 1) with
/// initial m₁ = 1, so v₁ = 2⁻¹ and vₖ = vₖ₋₁ ⊕ (vₖ₋₁ >> 1) (Bratley and Fox's recurrence).
const SOBOL_1_DIRECTIONS: [u32; 32] = {
    let mut v = [0u32; 32];
    v[0] = 1 << 31;
    let mut k = 1;
    while k < 32 {
        v[k] = v[k - 1] ^ (v[k - 1] >> 1);
        k += 1;
    }
    v
};

/// `(z.reverse_bits(), sobol_1_reversed(z))` from one set of table lookups: both maps are
/// linear over GF(2), so each is the XOR of its images of `z`'s four bytes, and one 8 KiB
/// table holds the two images side by side (the sampler needs both for every 2D number).
#[inline]
fn reversed_and_sobol_1(z: u32) -> (u32, u32) {
    let t = &REVERSED_AND_SOBOL_1_BYTES;
    let both = t[0][(z & 0xff) as usize]
        ^ t[1][(z >> 8 & 0xff) as usize]
        ^ t[2][(z >> 16 & 0xff) as usize]
        ^ t[3][(z >> 24) as usize];
    (both as u32, (both >> 32) as u32)
}

/// `sobol_1` in the reversed-bit domain: `sobol_1_reversed(i.reverse_bits())` is
/// `sobol_1(i).reverse_bits()`.
#[cfg(test)]
fn sobol_1_reversed(z: u32) -> u32 {
    reversed_and_sobol_1(z).1
}

/// Entry `[b][byte]`: in the low half, `byte << 8b` reversed; in the high half, the XOR over
/// the set bits t of `byte` of the reversed direction number that bit 8b + t of a reversed
/// index selects (bit j of a reversed index is bit 31 − j of it).
const REVERSED_AND_SOBOL_1_BYTES: [[u64; 256]; 4] = {
    let mut table = [[0u64; 256]; 4];
    let mut b = 0;
    while b < 4 {
        let mut byte = 0;
        while byte < 256 {
            let mut bits = 0u32;
            let mut t = 0;
            while t < 8 {
                if byte >> t & 1 != 0 {
                    bits ^= SOBOL_1_DIRECTIONS[31 - (8 * b + t)].reverse_bits();
                }
                t += 1;
            }
            let reversed = ((byte as u32) << (8 * b)).reverse_bits();
            table[b][byte] = (bits as u64) << 32 | reversed as u64;
            byte += 1;
        }
        b += 1;
    }
    table
};

/// The Laine–Karras hash on reversed bits (Burley 2020), keyed by `seed`: bit k of the
/// result depends only on bits ≤ k of `v` (additions and multiplications by even constants
/// carry information from low bits to high ones only). On reversed bits that is an Owen
/// scramble of the fraction `v.reverse_bits()`, and as a map on reversed sample indices a
/// shuffle that keeps every aligned power-of-two run of samples together. The sampler works
/// in this reversed domain throughout and reverses each coordinate once at the end.
#[inline]
fn owen_hash(mut v: u32, seed: u32) -> u32 {
    v ^= v.wrapping_mul(0x3d20_adea);
    v = v.wrapping_add(seed);
    v = v.wrapping_mul((seed >> 16) | 1);
    v ^= v.wrapping_mul(0x0552_6c56);
    v ^= v.wrapping_mul(0x53a2_2864);
    v
}

/// Owen scrambling of a 32-bit fraction `x` keyed by `seed` (the definition the reversed
/// domain implements).
#[cfg(test)]
fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    owen_hash(x.reverse_bits(), seed).reverse_bits()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unscrambled first 2^m points of dimensions 0 and 1 form a (0, m, 2)-net: every
    /// elementary interval of area 2^-m holds exactly one point.
    #[test]
    fn sobol_pairs_are_0_m_2_nets() {
        for m in 0..=10u32 {
            let n = 1u32 << m;
            for split in 0..=m {
                // Intervals of 2^split columns by 2^(m - split) rows.
                let mut seen = vec![false; n as usize];
                for i in 0..n {
                    let top = |bits: u32, k: u32| if k == 0 { 0 } else { bits >> (32 - k) };
                    let (col, row) = (top(sobol_0(i), split), top(sobol_1(i), m - split));
                    let cell = ((row << split) | col) as usize;
                    assert!(!seen[cell], "m {m}, split {split}: two points in cell {cell}");
                    seen[cell] = true;
                }
            }
        }
    }

    /// The reversed-domain sampler draws exactly the points of the definition: scrambled
    /// index, then Sobol dimensions 0 and 1 of it, each Owen-scrambled.
    #[test]
    fn reversed_domain_matches_the_definition() {
        let mut state = 0x1234_5678_9abc_def0u64;
        for _ in 0..10_000 {
            state = mix64(state);
            let z = state as u32;
            assert_eq!(sobol_1_reversed(z.reverse_bits()), sobol_1(z).reverse_bits(), "index {z:#x}");
        }
        for (seed, pixel, sample) in [(0u64, 0u64, 0u32), (5, 11, 3), (9, 1 << 40, 255), (1, 2, 1 << 20)] {
            let s = PathSampler::new(SamplerKind::Sobol, seed, pixel, sample);
            let key = s.dimension_key(Slot::Direction as u32);
            let index = nested_uniform_scramble(sample, key as u32);
            let x = nested_uniform_scramble(sobol_0(index), (key >> 32) as u32);
            let y = nested_uniform_scramble(sobol_1(index), mix64(key) as u32);
            assert_eq!(s.get2(Slot::Direction), Vec2::new(unit(x), unit(y)));
            let key = s.dimension_key(Slot::Roulette as u32);
            let index = nested_uniform_scramble(sample, key as u32);
            assert_eq!(s.get1(Slot::Roulette), unit(nested_uniform_scramble(sobol_0(index), (key >> 32) as u32)));
        }
    }

    /// The byte tables reverse exactly: the index and the 24 bits a number keeps.
    #[test]
    fn table_reversals_match_reverse_bits() {
        let mut state = 0x0fed_cba9_8765_4321u64;
        let random = (0..10_000).map(|_| {
            state = mix64(state);
            state as u32
        });
        for z in random.chain([0u32, 1, 0x80, 0x100, 0x00ff_ffff, 0xff00_0000, u32::MAX]) {
            assert_eq!(reversed_and_sobol_1(z).0, z.reverse_bits(), "{z:#x}");
            assert_eq!(unit_reversed(z), unit(z.reverse_bits()), "{z:#x}");
            assert_eq!(PathSampler::of_pixel(SamplerKind::Sobol, 3, z).sample_reversed, z.reverse_bits(), "{z:#x}");
        }
    }

    /// Owen scrambling keeps the net property, and the shuffled index keeps every aligned
    /// power-of-two run of samples a net, for any seed.
    #[test]
    fn scrambled_runs_stay_stratified() {
        for seed in [1u64, 2, 99, 0xdead_beef] {
            let sampler = |sample| PathSampler::new(SamplerKind::Sobol, seed, 7, sample);
            for (start, m) in [(0u32, 4u32), (16, 4), (64, 6), (0, 8)] {
                let n = 1u32 << m;
                // 1D: one point per interval of width 1/n.
                let mut seen = vec![false; n as usize];
                for s in start..start + n {
                    let x = sampler(s).get1(Slot::Lobe);
                    let cell = (x * n as f32) as usize;
                    assert!(!seen[cell], "seed {seed}, run {start}+{n}: 1D cell {cell} twice");
                    seen[cell] = true;
                }
                // 2D: one point per square of a 2^(m/2) grid (m even).
                let side = 1usize << (m / 2);
                let mut seen = vec![false; n as usize];
                for s in start..start + n {
                    let p = sampler(s).get2(Slot::Direction);
                    let cell = (p.y * side as f32) as usize * side + (p.x * side as f32) as usize;
                    assert!(!seen[cell], "seed {seed}, run {start}+{n}: 2D cell {cell} twice");
                    seen[cell] = true;
                }
            }
        }
    }

    /// Numbers are uniform over many pixels, and distinct dimensions are uncorrelated.
    #[test]
    fn dimensions_are_uniform_and_independent() {
        for kind in [SamplerKind::Sobol, SamplerKind::Independent] {
            let n = 1 << 16;
            let (mut sum_a, mut sum_b, mut sum_ab) = (0.0f64, 0.0f64, 0.0f64);
            let mut bins = [0u32; 16];
            for i in 0..n {
                let mut s = PathSampler::new(kind, 3, i / 16, (i % 16) as u32);
                s.set_vertex(2);
                let a = s.get1(Slot::LightChoice) as f64;
                let b = s.get2(Slot::LightPoint).x as f64;
                bins[(a * 16.0) as usize] += 1;
                sum_a += a;
                sum_b += b;
                sum_ab += a * b;
            }
            let n = n as f64;
            let covariance = sum_ab / n - (sum_a / n) * (sum_b / n);
            // Independent uniforms: covariance has standard deviation 1/(12 sqrt(n)) ≈ 3.3e-4.
            assert!(covariance.abs() < 1.5e-3, "{kind:?}: covariance {covariance}");
            assert!((sum_a / n - 0.5).abs() < 0.005, "{kind:?}: mean {}", sum_a / n);
            let expected = n / 16.0;
            for (k, &c) in bins.iter().enumerate() {
                assert!((f64::from(c) - expected).abs() < 5.0 * expected.sqrt(), "{kind:?}: bin {k} {c}");
            }
        }
    }

    /// A number depends only on (seed, pixel, sample, vertex, slot).
    #[test]
    fn numbers_are_pure_functions_of_their_dimension() {
        let mut a = PathSampler::new(SamplerKind::Sobol, 5, 11, 3);
        let b = PathSampler::new(SamplerKind::Sobol, 5, 11, 3);
        let first = a.get2(Slot::Pixel);
        a.set_vertex(4);
        let _ = a.get1(Slot::Roulette);
        a.set_vertex(0);
        assert_eq!(a.get2(Slot::Pixel), first);
        assert_eq!(b.get2(Slot::Pixel), first);
        assert_ne!(a.pass_pick(0), a.pass_pick(1));
        assert_ne!(PathSampler::new(SamplerKind::Sobol, 5, 12, 3).get2(Slot::Pixel), first);
    }

    /// The point of it: a smooth 2D integrand converges faster than 1/n in variance.
    #[test]
    fn sobol_beats_independent_on_a_smooth_integrand() {
        let f = |p: Vec2| (p.x * 3.0).sin() * p.y * p.y + p.x;
        let exact = {
            // ∫∫ sin(3x) y² + x dx dy = (1 − cos 3)/9 + 1/2.
            (1.0 - 3.0f64.cos()) / 9.0 + 0.5
        };
        let variance = |kind| {
            let pixels = 256u64;
            let spp = 64u32;
            let mut sq = 0.0f64;
            for pixel in 0..pixels {
                let mean: f64 =
                    (0..spp).map(|s| f(PathSampler::new(kind, 1, pixel, s).get2(Slot::Direction)) as f64).sum::<f64>()
                        / f64::from(spp);
                sq += (mean - exact).powi(2);
            }
            sq / pixels as f64
        };
        let (sobol, independent) = (variance(SamplerKind::Sobol), variance(SamplerKind::Independent));
        assert!(sobol * 20.0 < independent, "sobol {sobol:e}, independent {independent:e}");
    }
}
