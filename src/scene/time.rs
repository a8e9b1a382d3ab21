//! Time codes and the value of an attribute at a time: USD's `UsdTimeCode` and
//! `UsdAttribute::Get(time)` in one place.
//!
//! At [`TimeCode::Default`] an attribute has its default value (none when only samples are
//! authored). At a numeric time, authored samples take precedence over the default: the value
//! is held before the first and after the last sample and interpolated linearly between two,
//! as USD's linear interpolation does — numbers, vectors and matrices (and arrays of them of
//! equal length) component by component, quaternions by spherical interpolation along the
//! shorter arc (`GfSlerp`), and everything else (bools, integers, tokens, strings, assets,
//! arrays whose length changes) held at the earlier sample.

use crate::scene::value::Value;
use std::fmt;
use std::str::FromStr;

/// The time at which attribute values are read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeCode {
    /// USD's `UsdTimeCode::Default()`: the default (un-animated) values.
    Default,
    /// A numeric time code (a frame, in the stage's time codes).
    At(f64),
}

impl FromStr for TimeCode {
    type Err = String;

    /// `default` or a finite number.
    fn from_str(s: &str) -> Result<TimeCode, String> {
        if s.eq_ignore_ascii_case("default") {
            return Ok(TimeCode::Default);
        }
        match s.parse::<f64>() {
            Ok(t) if t.is_finite() => Ok(TimeCode::At(t)),
            _ => Err(format!("`{s}` is not a time code: give a finite number or `default`")),
        }
    }
}

impl fmt::Display for TimeCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TimeCode::Default => f.write_str("default"),
            TimeCode::At(t) => write!(f, "{t}"),
        }
    }
}

/// The value at `time` of an attribute of type `type_name` (`quatf[]`, `half3`, ...) whose
/// default is `default` and whose samples are `samples` (sorted by time, as [`sort_samples`]
/// leaves them). Quaternions interpolate spherically; half-precision types are rounded to
/// half precision, as USD stores the interpolated value in the attribute's type.
/// `None`: no value at that time (nothing authored, or a blocked sample).
pub fn value_at(default: Option<&Value>, samples: &[(f64, Value)], type_name: &str, time: TimeCode) -> Option<Value> {
    let t = match time {
        TimeCode::At(t) if !samples.is_empty() => t,
        _ => return default.cloned(),
    };
    // The first sample after `t`: samples before it bracket `t` from below.
    let upper = samples.partition_point(|(s, _)| *s <= t);
    let held = |i: usize| Some(&samples[i].1).filter(|v| !v.is_none()).cloned();
    if upper == 0 {
        return held(0);
    }
    if upper == samples.len() || samples[upper - 1].0 == t {
        return held(upper - 1);
    }
    let ((t0, v0), (t1, v1)) = (&samples[upper - 1], &samples[upper]);
    let alpha = (t - t0) / (t1 - t0);
    let base = type_name.trim_end_matches("[]");
    let quaternion = base.starts_with("quat");
    let Some(mut value) = interpolate(v0, v1, alpha, quaternion) else { return held(upper - 1) };
    if is_half(base) {
        value = map_numbers(value, to_half_precision);
    }
    Some(value)
}

/// `value` with `f` applied to each of its floating-point numbers.
fn map_numbers(value: Value, f: fn(f64) -> f64) -> Value {
    let all = |v: &[f64]| -> Vec<f64> { v.iter().map(|&x| f(x)).collect() };
    match value {
        Value::Float(x) => Value::Float(f(x)),
        Value::Tuple(v) => Value::Tuple(all(&v)),
        Value::FloatArray(v) => Value::FloatArray(all(&v).into()),
        Value::TupleArray { width, data } => Value::TupleArray { width, data: all(&data).into() },
        other => other,
    }
}

/// `half`, `half3`, `quath`, `color3h`, `point3h`, ...: types stored as 16-bit floats.
fn is_half(base: &str) -> bool {
    let mut tail = base.chars().rev();
    base.starts_with("half")
        || base == "quath"
        || (tail.next() == Some('h') && tail.next().is_some_and(|c| c.is_ascii_digit()))
}

/// `x` rounded to the nearest IEEE half (ties to even), as `f64`.
fn to_half_precision(x: f64) -> f64 {
    if !x.is_finite() || x == 0.0 {
        return x;
    }
    // The exponent of `x`, clamped to half's smallest normal one (subnormals share its step).
    let exponent = (((x.abs().to_bits() >> 52) & 0x7ff) as i64 - 1023).max(-14);
    let step = 2f64.powi((exponent - 10) as i32);
    let rounded = (x / step).round_ties_even() * step;
    if rounded.abs() > 65504.0 { f64::INFINITY.copysign(x) } else { rounded }
}

/// Sorts samples by time; of samples authored at the same time the last one written is kept.
pub fn sort_samples(samples: &mut Vec<(f64, Value)>) {
    samples.retain(|(t, _)| t.is_finite());
    // Stable: equal times keep their written order, so the last of each run is the latest.
    samples.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Reversed, the latest of each run comes first, and `dedup_by` keeps the first.
    samples.reverse();
    samples.dedup_by(|a, b| a.0 == b.0);
    samples.reverse();
}

/// Linear (or spherical) interpolation of two samples; `None` when the values do not
/// interpolate (their type, or arrays of different lengths), and the earlier one is held.
fn interpolate(a: &Value, b: &Value, alpha: f64, quaternion: bool) -> Option<Value> {
    let lerp = |x: &[f64], y: &[f64]| -> Vec<f64> { x.iter().zip(y).map(|(x, y)| x + (y - x) * alpha).collect() };
    Some(match (a, b) {
        (Value::Float(x), Value::Float(y)) => Value::Float(x + (y - x) * alpha),
        (Value::Tuple(x), Value::Tuple(y)) if x.len() == y.len() => {
            if quaternion && x.len() == 4 {
                Value::Tuple(slerp(x, y, alpha).to_vec())
            } else {
                Value::Tuple(lerp(x, y))
            }
        }
        (Value::Matrix2(x), Value::Matrix2(y)) => Value::Matrix2(lerp(x, y).try_into().ok()?),
        (Value::Matrix3(x), Value::Matrix3(y)) => Value::Matrix3(lerp(x, y).try_into().ok()?),
        (Value::Matrix(x), Value::Matrix(y)) => Value::Matrix(lerp(x, y).try_into().ok()?),
        (Value::FloatArray(x), Value::FloatArray(y)) if x.len() == y.len() => Value::FloatArray(lerp(x, y).into()),
        (Value::TupleArray { width: w, data: x }, Value::TupleArray { width: v, data: y })
            if w == v && x.len() == y.len() =>
        {
            let data = if quaternion && *w == 4 {
                x.chunks_exact(4).zip(y.chunks_exact(4)).flat_map(|(p, q)| slerp(p, q, alpha)).collect()
            } else {
                lerp(x, y)
            };
            Value::TupleArray { width: *w, data: std::sync::Arc::new(data) }
        }
        _ => return None,
    })
}

/// `GfSlerp` of two quaternions `(real, i, j, k)`: along the shorter arc, linear when they
/// are nearly parallel.
fn slerp(q0: &[f64], q1: &[f64], alpha: f64) -> [f64; 4] {
    let mut cos_theta: f64 = q0.iter().zip(q1).map(|(a, b)| a * b).sum();
    let flip = cos_theta < 0.0;
    if flip {
        cos_theta = -cos_theta;
    }
    let (s0, mut s1) = if 1.0 - cos_theta > 1e-5 {
        let theta = cos_theta.min(1.0).acos();
        let sin_theta = theta.sin();
        (((1.0 - alpha) * theta).sin() / sin_theta, (alpha * theta).sin() / sin_theta)
    } else {
        (1.0 - alpha, alpha)
    };
    if flip {
        s1 = -s1;
    }
    std::array::from_fn(|i| s0 * q0[i] + s1 * q1[i])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples() -> Vec<(f64, Value)> {
        vec![(10.0, Value::Float(1.0)), (20.0, Value::Float(3.0))]
    }

    #[test]
    fn held_outside_interpolated_between_default_at_default() {
        let s = samples();
        let d = Value::Float(-1.0);
        let at = |t| value_at(Some(&d), &s, "float", TimeCode::At(t));
        assert_eq!(at(0.0), Some(Value::Float(1.0)));
        assert_eq!(at(15.0), Some(Value::Float(2.0)));
        assert_eq!(at(20.0), Some(Value::Float(3.0)));
        assert_eq!(at(99.0), Some(Value::Float(3.0)));
        assert_eq!(value_at(Some(&d), &s, "float", TimeCode::Default), Some(d.clone()));
        assert_eq!(value_at(None, &s, "float", TimeCode::Default), None);
        assert_eq!(value_at(Some(&d), &[], "float", TimeCode::At(5.0)), Some(d));
    }

    #[test]
    fn non_interpolating_values_are_held() {
        let s = vec![(0.0, Value::Int(1)), (10.0, Value::Int(5))];
        assert_eq!(value_at(None, &s, "int", TimeCode::At(9.0)), Some(Value::Int(1)));
        let a = vec![(0.0, Value::FloatArray(vec![0.0].into())), (10.0, Value::FloatArray(vec![1.0, 2.0].into()))];
        assert_eq!(value_at(None, &a, "float[]", TimeCode::At(5.0)), Some(Value::FloatArray(vec![0.0].into())));
    }

    #[test]
    fn quaternions_take_the_short_arc() {
        // Identity to 90° about z, the latter written negated: halfway is 45° about z.
        let (c, s) = (std::f64::consts::FRAC_PI_4.cos(), std::f64::consts::FRAC_PI_4.sin());
        let samples = vec![(0.0, Value::Tuple(vec![1.0, 0.0, 0.0, 0.0])), (1.0, Value::Tuple(vec![-c, 0.0, 0.0, -s]))];
        let Some(Value::Tuple(q)) = value_at(None, &samples, "quatd", TimeCode::At(0.5)) else { panic!() };
        let (c, s) = ((std::f64::consts::PI / 8.0).cos(), (std::f64::consts::PI / 8.0).sin());
        assert!((q[0] - c).abs() < 1e-12 && (q[3] - s).abs() < 1e-12, "{q:?}");
    }

    #[test]
    fn half_types_round_to_half_precision() {
        // 1 + 0.3 · 0.25 = 1.075 is 1.0751953125 in half precision (steps of 2^-10 near 1).
        let s = vec![(0.0, Value::Tuple(vec![1.0, 1.0, 1.0])), (10.0, Value::Tuple(vec![1.25, 1.0, 1.0]))];
        let Some(Value::Tuple(v)) = value_at(None, &s, "half3", TimeCode::At(3.0)) else { panic!() };
        assert_eq!(v[0], 1.0751953125);
        let Some(Value::Tuple(v)) = value_at(None, &s, "float3", TimeCode::At(3.0)) else { panic!() };
        assert!((v[0] - 1.075).abs() < 1e-15);
        assert!(is_half("quath") && is_half("color3h") && is_half("half") && !is_half("quatf") && !is_half("path"));
        assert_eq!(to_half_precision(70000.0), f64::INFINITY);
    }

    #[test]
    fn parses_time_codes() {
        assert_eq!("default".parse::<TimeCode>(), Ok(TimeCode::Default));
        assert_eq!("12.5".parse::<TimeCode>(), Ok(TimeCode::At(12.5)));
        assert!("nan".parse::<TimeCode>().is_err());
        assert!("x".parse::<TimeCode>().is_err());
    }

    #[test]
    fn sorting_keeps_the_last_duplicate() {
        let mut s = vec![(5.0, Value::Int(1)), (1.0, Value::Int(2)), (5.0, Value::Int(3))];
        sort_samples(&mut s);
        assert_eq!(s, vec![(1.0, Value::Int(2)), (5.0, Value::Int(3))]);
    }
}
