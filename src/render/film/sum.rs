//! Exact sums of samples, so that a pixel's value does not depend on how its samples were
//! split between passes, threads or machines.
//!
//! A float sum depends on the order of its terms; a farm that renders samples `0..k` and
//! `k..n` of a pixel apart and adds the two sums gets a different last bit than one process
//! adding all `n` in order. Here each sample is rounded once, toward zero, to a multiple of
//! 2⁻⁴⁰ (9.1e-13: a sample's error is below one f32 ulp of any value above 1e-5, and a float
//! sum of a few hundred samples errs more) and summed as a 128-bit integer, which is exact and
//! associative: any split of the samples, merged in any order, gives the same sum bit for bit,
//! and the pixel is that sum divided once. [`PixelSums`] holds a pixel's, [`WindowSums`] a
//! window's. Values below 2²² in magnitude (every radiance,
//! albedo, normal and most positions) convert with one truncating conversion to i64.

use super::{DEPTH_MISS, Region};
use std::ops::Range;

/// 2⁴⁰: one unit of the sum is 2⁻⁴⁰.
const SCALE: f64 = 1_099_511_627_776.0;

/// Per-sample values are clamped to ±2⁵⁵ so that 2³² samples cannot overflow 127 bits.
const LIMIT: f64 = 36_028_797_018_963_968.0;

/// The fast range's bound: `|v| < 2²²` exactly when `|v · 2⁴⁰| < 2⁶²` (the product is exact), so
/// the sample converts through `i64`.
const FAST_VALUE: f32 = 4_194_304.0;

/// An exact sum of finite `f32` samples (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ExactSum(i128);

/// [`FAST_VALUE`]'s bits: a value's magnitude bits (`to_bits() & 0x7fff_ffff`) are below them
/// exactly when it is in the fast range, and NaN's and the infinities' are not.
const FAST_BITS: u32 = FAST_VALUE.to_bits();

/// Whether every one of `values` is in the fast range (`|v| < 2²²`, so finite too). One
/// integer maximum over the magnitudes' bits: no branch per value, and no float compare that
/// NaN would need its own care for.
#[inline]
pub fn all_fast<const N: usize>(values: &[f32; N]) -> bool {
    values.iter().fold(0, |max: u32, v| max.max(v.to_bits() & 0x7fff_ffff)) < FAST_BITS
}

/// `v` in units of 2⁻⁴⁰, rounded toward zero, for `v` in the fast range: exact in f32 as in
/// f64 (a power-of-two scale of a value below 2²² neither overflows nor rounds; a subnormal
/// value scales to a normal one), and one truncating conversion. [`ExactSum::add`] and the
/// film's groups ([`add_fast`]) both convert through it.
///
/// # Safety
/// `|v| < 2²²` (then `|v · 2⁴⁰| < 2⁶²`: finite and in i64's range after truncation).
#[inline]
unsafe fn fast_units(v: f32) -> i128 {
    // SAFETY: the caller's range makes the truncation defined (see above).
    i128::from(unsafe { (v * SCALE as f32).to_int_unchecked::<i64>() })
}

/// Adds each of `values`, all in the fast range ([`all_fast`]), to the sum in the same place,
/// exactly as [`ExactSum::add`] does one at a time: the film tests a sample's channels once and
/// adds its groups with no test of their own.
///
/// # Panics
/// In debug builds, when a value is out of the fast range (release builds do not check it).
#[inline]
pub fn add_fast<const N: usize>(sums: &mut [ExactSum; N], values: [f32; N]) {
    debug_assert!(all_fast(&values), "{values:?}");
    for (sum, v) in sums.iter_mut().zip(values) {
        // SAFETY: in the fast range (the caller's test, asserted above in debug builds).
        sum.0 += unsafe { fast_units(v) };
    }
}

/// Adds each of `values` to the sum in the same place, exactly as [`ExactSum::add`] does one at
/// a time, with one range test for the lot: the film adds a sample's channels together, and
/// they are almost always all in the fast range.
#[inline]
pub fn add_each<const N: usize>(sums: &mut [ExactSum; N], values: [f32; N]) {
    if all_fast(&values) {
        add_fast(sums, values);
    } else {
        sums.iter_mut().zip(values).for_each(|(sum, v)| sum.add(v));
    }
}

impl ExactSum {
    /// Adds `v` rounded toward zero to a multiple of 2⁻⁴⁰ (and clamped to ±2⁵⁵). NaN adds 0;
    /// the film discards non-finite samples before they get here.
    #[inline]
    pub fn add(&mut self, v: f32) {
        self.0 += if v.abs() < FAST_VALUE {
            // SAFETY: the test is the fast range (NaN fails it).
            unsafe { fast_units(v) }
        } else {
            // Exact: an f32 times a power of two is an f64 with the same significand, and the
            // float-to-integer conversion truncates (NaN converts to 0), as `fast_units` does.
            (f64::from(v) * SCALE).clamp(-LIMIT * SCALE, LIMIT * SCALE) as i128
        };
    }

    /// The sum of one sample.
    pub fn of(v: f32) -> ExactSum {
        let mut s = ExactSum::default();
        s.add(v);
        s
    }

    /// Adds another sum (exact).
    #[inline]
    pub fn merge(&mut self, other: ExactSum) {
        self.0 += other.0;
    }

    /// The sum, rounded to the nearest `f64`.
    pub fn value(self) -> f64 {
        self.0 as f64 / SCALE
    }

    /// The mean of `count` samples, rounded once to `f32` (0 when `count` is 0).
    pub fn mean(self, count: u32) -> f32 {
        if count == 0 { 0.0 } else { (self.value() / f64::from(count)) as f32 }
    }

    /// The raw fixed-point value, for files that carry sums between processes.
    pub fn to_bits(self) -> i128 {
        self.0
    }

    /// The sum whose raw value is `bits` ([`ExactSum::to_bits`]).
    pub fn from_bits(bits: i128) -> ExactSum {
        ExactSum(bits)
    }
}

/// One pixel's samples so far, summed exactly ([`ExactSum`]), so the pixel does not depend
/// on how its samples were split.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelSums {
    /// Samples traced, valid or not (invalid ones count as black): the divisor of the means.
    pub samples: u32,
    /// `R G B A albedo.RGB` over all samples, then `N.xyz P.xyz` over the hits.
    pub builtin: [ExactSum; 13],
    /// Samples that reached a non-transparent surface.
    pub hits: u32,
    /// The nearest first hit's camera-space depth ([`DEPTH_MISS`]: none).
    pub depth: f32,
    /// The valid sample nearest the pixel centre: squared distance, then sample index.
    pub nearest: (f32, u32),
    /// Custom channel floats: sums, or for integer channels the nearest sample's value.
    pub channels: Vec<ExactSum>,
    /// Cryptomatte: each prim's summed alpha.
    pub objects: Vec<(u32, ExactSum)>,
    /// Cryptomatte: each composed material's summed alpha.
    pub materials: Vec<(u32, ExactSum)>,
}

impl Default for PixelSums {
    fn default() -> PixelSums {
        PixelSums {
            samples: 0,
            builtin: [ExactSum::default(); 13],
            hits: 0,
            depth: DEPTH_MISS,
            nearest: (f32::INFINITY, u32::MAX),
            channels: Vec::new(),
            objects: Vec::new(),
            materials: Vec::new(),
        }
    }
}

impl PixelSums {
    /// Starts a pixel with `channel_floats` custom floats, keeping the allocations.
    pub fn reset(&mut self, channel_floats: usize) {
        let (mut channels, mut objects, mut materials) = (
            std::mem::take(&mut self.channels),
            std::mem::take(&mut self.objects),
            std::mem::take(&mut self.materials),
        );
        channels.clear();
        channels.resize(channel_floats, ExactSum::default());
        objects.clear();
        materials.clear();
        *self = PixelSums { channels, objects, materials, ..PixelSums::default() };
    }

    /// Adds the samples of `other` (the same pixel, other samples). `integer[k]` says which
    /// custom floats are integer channels: those keep the nearest sample's value. The result
    /// is the same whatever the split and the order of merging.
    pub fn merge(&mut self, other: &PixelSums, integer: &[bool]) {
        self.samples += other.samples;
        for (a, b) in self.builtin.iter_mut().zip(&other.builtin) {
            a.merge(*b);
        }
        self.hits += other.hits;
        self.depth = self.depth.min(other.depth);
        let nearer = other.nearest < self.nearest;
        for (k, (a, b)) in self.channels.iter_mut().zip(&other.channels).enumerate() {
            if !integer.get(k).copied().unwrap_or(false) {
                a.merge(*b);
            } else if nearer {
                *a = *b;
            }
        }
        if nearer {
            self.nearest = other.nearest;
        }
        for (list, more) in [(&mut self.objects, &other.objects), (&mut self.materials, &other.materials)] {
            for &(index, alpha) in more {
                match list.iter_mut().find(|(i, _)| *i == index) {
                    Some((_, sum)) => sum.merge(alpha),
                    None => list.push((index, alpha)),
                }
            }
        }
    }
}

/// Adds `alpha` to the coverage of ID `index`.
pub(super) fn add_coverage(list: &mut Vec<(u32, ExactSum)>, index: u32, alpha: f32) {
    match list.iter_mut().find(|(i, _)| *i == index) {
        Some((_, sum)) => sum.add(alpha),
        None => list.push((index, ExactSum::of(alpha))),
    }
}

/// Each pixel's exact sums over a window's samples ([`super::render_sums`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WindowSums {
    /// The pixels, in the whole image.
    pub region: Region,
    /// The samples summed: the ranges merged so far, in order.
    pub samples: Vec<Range<u32>>,
    /// Row-major, top row first.
    pub pixels: Vec<PixelSums>,
    /// Which custom-channel floats are integer channels.
    pub integer: Vec<bool>,
}

impl WindowSums {
    /// Adds the sums of `other`, the same pixels over other samples. The result is the same
    /// whatever the split of the samples and the order of merging.
    pub fn merge(&mut self, other: &WindowSums) -> Result<(), String> {
        if other.region != self.region || other.integer != self.integer || other.pixels.len() != self.pixels.len() {
            return Err(format!(
                "windows {:?} and {:?} do not cover the same pixels and channels",
                self.region, other.region
            ));
        }
        let overlaps = |a: &Range<u32>, b: &Range<u32>| a.start < b.end && b.start < a.end;
        if let Some(r) = other.samples.iter().find(|r| self.samples.iter().any(|s| overlaps(r, s))) {
            return Err(format!("samples {}..{} are in both windows", r.start, r.end));
        }
        for (a, b) in self.pixels.iter_mut().zip(&other.pixels) {
            a.merge(b, &self.integer);
        }
        self.samples.extend(other.samples.iter().cloned());
        self.samples.sort_by_key(|r| r.start);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic stream of awkward values: tiny, huge, negative, subnormal, and the
    /// ordinary values in between.
    fn values() -> Vec<f32> {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        (0..4000)
            .map(|i| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let unit = (state >> 40) as f32 / (1u64 << 24) as f32;
                match i % 7 {
                    0 => unit * 1e6,
                    1 => unit * 1e-7,
                    2 => -unit,
                    3 => f32::from_bits((state >> 41) as u32 & 0x007f_ffff),
                    4 => 1.0 + unit * f32::EPSILON,
                    _ => unit,
                }
            })
            .collect()
    }

    #[test]
    fn any_split_merged_in_any_order_is_the_same_sum() {
        let v = values();
        let mut whole = ExactSum::default();
        v.iter().for_each(|&x| whole.add(x));
        for cuts in [vec![1], vec![1000, 1001], vec![3, 999, 2000, 3999], vec![571, 1142, 1713, 2284, 2855, 3426]] {
            let mut bounds = vec![0];
            bounds.extend(&cuts);
            bounds.push(v.len());
            let parts: Vec<ExactSum> = bounds
                .windows(2)
                .map(|w| {
                    let mut s = ExactSum::default();
                    v[w[0]..w[1]].iter().for_each(|&x| s.add(x));
                    s
                })
                .collect();
            let mut forward = ExactSum::default();
            parts.iter().for_each(|&p| forward.merge(p));
            let mut backward = ExactSum::default();
            parts.iter().rev().for_each(|&p| backward.merge(p));
            assert_eq!(forward, whole, "{cuts:?}");
            assert_eq!(backward, whole, "{cuts:?}");
        }
        // A float sum in two halves does differ from the sum in order: the property is not free.
        let sequential: f32 = v.iter().sum();
        let halves: f32 = v[..1234].iter().sum::<f32>() + v[1234..].iter().sum::<f32>();
        assert_ne!(sequential.to_bits(), halves.to_bits());
    }

    #[test]
    fn sums_are_accurate_to_the_fixed_point_step() {
        let v = values();
        let mut sum = ExactSum::default();
        v.iter().for_each(|&x| sum.add(x));
        // Compensated f64 reference: every f32 is exact in f64, so a Neumaier sum is accurate
        // to about one f64 ulp of the total.
        let (mut s, mut c) = (0.0f64, 0.0f64);
        for &x in &v {
            let x = f64::from(x);
            let t = s + x;
            c += if s.abs() >= x.abs() { (s - t) + x } else { (x - t) + s };
            s = t;
        }
        let reference = s + c;
        assert!((sum.value() - reference).abs() <= reference.abs() * 1e-15 + v.len() as f64 / SCALE);
        assert_eq!(ExactSum::default().mean(0), 0.0);
        let mut one = ExactSum::default();
        one.add(0.75);
        one.add(0.25);
        assert_eq!(one.mean(2), 0.5);
        assert_eq!(ExactSum::from_bits(one.to_bits()), one);
    }

    #[test]
    fn adding_a_group_at_once_is_adding_each_value() {
        // The fast range's edges, huge and non-finite values, among the ordinary ones.
        let edges = [4_194_303.5, 4_194_304.0, -4_194_304.0, 1e30, -f32::MAX, f32::INFINITY, f32::NAN, -0.0];
        let v: Vec<f32> = values().into_iter().chain(edges).collect();
        for group in v.chunks_exact(7).chain(edges.windows(7)) {
            let group: [f32; 7] = group.try_into().unwrap();
            let mut each = [ExactSum::of(1.5); 7];
            each.iter_mut().zip(group).for_each(|(s, x)| s.add(x));
            let mut at_once = [ExactSum::of(1.5); 7];
            add_each(&mut at_once, group);
            assert_eq!(at_once, each, "{group:?}");
        }
    }

    /// `add` against the definition, computed in f64 and i128 alone: the value times 2⁴⁰,
    /// truncated, clamped to ±2⁵⁵ · 2⁴⁰, NaN as 0; and `all_fast` against the float test.
    #[test]
    fn add_is_the_truncated_fixed_point_value() {
        let below = f32::from_bits(FAST_VALUE.to_bits() - 1);
        let edges = [FAST_VALUE, -FAST_VALUE, below, -below, 1e30, -f32::MAX, f32::INFINITY, -f32::INFINITY];
        let subnormal = f32::from_bits(1);
        let more = [f32::NAN, -f32::NAN, 0.0, -0.0, subnormal, -subnormal, f32::MIN_POSITIVE, 0.1, -2.5e-13];
        for v in values().into_iter().chain(edges).chain(more) {
            let expected = if v.is_nan() {
                0
            } else {
                (f64::from(v) * SCALE).trunc().clamp(-LIMIT * SCALE, LIMIT * SCALE) as i128
            };
            let mut sum = ExactSum::from_bits(7);
            sum.add(v);
            assert_eq!(sum.to_bits(), 7 + expected, "{v:e}");
            assert_eq!(all_fast(&[0.5, v, -1.0]), v.abs() < FAST_VALUE, "{v:e}");
        }
    }

    #[test]
    fn huge_and_non_finite_values_clamp_instead_of_overflowing() {
        let mut s = ExactSum::default();
        for _ in 0..1000 {
            s.add(f32::MAX);
        }
        assert_eq!(s.value(), 1000.0 * LIMIT);
        let mut n = ExactSum::default();
        n.add(f32::NAN);
        assert_eq!(n, ExactSum::default());
    }
}
