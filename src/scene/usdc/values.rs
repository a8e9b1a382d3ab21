//! Crate values as the usda parser would read them: floats widened through their shortest
//! decimal form, tuples and arrays flattened, layer offsets made finite.

use crate::scene::usda::LayerOffset;
use crate::scene::value::{AssetPath, Value};
use openusd::sdf;
use std::fmt::Write as _;
use std::path::Path;

/// A `float` as the `f64` its shortest decimal form parses to: the value a usda file
/// written from the same data holds, so both formats read the same.
pub(super) fn widen_f32(x: f32) -> f64 {
    if !x.is_finite() || x == 0.0 {
        return f64::from(x);
    }
    let mut buf = StackText::default();
    if write!(buf, "{x:e}").is_ok()
        && let Ok(s) = std::str::from_utf8(&buf.bytes[..buf.len])
        && let Ok(v) = s.parse::<f64>()
    {
        return v;
    }
    f64::from(x)
}

pub(super) fn widen_f16(x: openusd::gf::f16) -> f64 {
    widen_f32(x.to_f32())
}

/// A small fixed buffer for formatting a number without allocating.
pub(super) struct StackText {
    pub(super) bytes: [u8; 48],
    pub(super) len: usize,
}

impl Default for StackText {
    fn default() -> Self {
        StackText { bytes: [0; 48], len: 0 }
    }
}

impl std::fmt::Write for StackText {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        let end = self.len + s.len();
        let slot = self.bytes.get_mut(self.len..end).ok_or(std::fmt::Error)?;
        slot.copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

/// Arrays at least this long are converted on every core: the shortest decimal form of each
/// `float` ([`widen_f32`]) was a tenth of a 400k-face asset's preparation.
const PARALLEL_ITEMS: usize = 1 << 14;

pub(super) fn flat<E: Copy, const N: usize, T: Into<[E; N]> + Copy + Sync>(
    items: &[T],
    f: impl Fn(E) -> f64 + Sync,
) -> Value {
    use rayon::prelude::*;
    let mut data = vec![0.0; items.len() * N];
    let convert = |(out, item): (&mut [f64], &T)| {
        let parts: [E; N] = (*item).into();
        out.iter_mut().zip(parts).for_each(|(o, e)| *o = f(e));
    };
    if items.len() >= PARALLEL_ITEMS {
        data.par_chunks_mut(N).zip(items.par_iter()).for_each(convert);
    } else {
        data.chunks_mut(N).zip(items).for_each(convert);
    }
    Value::TupleArray { width: N, data: data.into() }
}

/// `items` widened by `f`, on every core when the array is long ([`PARALLEL_ITEMS`]).
fn widened<E: Copy + Sync>(items: &[E], f: impl Fn(E) -> f64 + Sync) -> Value {
    use rayon::prelude::*;
    let data = if items.len() >= PARALLEL_ITEMS {
        items.par_iter().map(|&x| f(x)).collect()
    } else {
        items.iter().map(|&x| f(x)).collect()
    };
    Value::FloatArray(std::sync::Arc::new(data))
}

pub(super) fn tuple<E: Copy, const N: usize, T: Into<[E; N]> + Copy>(item: &T, f: impl Fn(E) -> f64) -> Value {
    let parts: [E; N] = (*item).into();
    Value::Tuple(parts.iter().map(|&e| f(e)).collect())
}

/// Converts one openusd value. `metadata`: top-level metadata, where usda writes tokens as
/// strings. `Err` names the value kind strata does not convert.
pub(super) fn convert_value(value: &sdf::Value, base_dir: &Path, metadata: bool) -> Result<Value, &'static str> {
    use sdf::Value as S;
    let d = |x: f64| x;
    let f = widen_f32;
    let h = widen_f16;
    let int = |x: i64| Value::Int(x);
    Ok(match value {
        S::None | S::ValueBlock => Value::None,
        S::Bool(b) => Value::Bool(*b),
        S::BoolVec(v) => Value::BoolArray(v.clone()),
        S::Uchar(x) => int(i64::from(*x)),
        S::Int(x) => int(i64::from(*x)),
        S::Uint(x) => int(i64::from(*x)),
        S::Int64(x) => int(*x),
        S::Uint64(x) => int(i64::try_from(*x).map_err(|_| "uint64 beyond the int64 range")?),
        S::UcharVec(v) => Value::IntArray(std::sync::Arc::new(v.iter().map(|&x| i64::from(x)).collect())),
        S::IntVec(v) => Value::IntArray(std::sync::Arc::new(v.iter().map(|&x| i64::from(x)).collect())),
        S::UintVec(v) => Value::IntArray(std::sync::Arc::new(v.iter().map(|&x| i64::from(x)).collect())),
        S::Int64Vec(v) => Value::IntArray(std::sync::Arc::new(v.clone())),
        S::Uint64Vec(v) => Value::IntArray(std::sync::Arc::new(
            v.iter()
                .map(|&x| i64::try_from(x))
                .collect::<Result<_, _>>()
                .map_err(|_| "uint64 beyond the int64 range")?,
        )),
        S::Half(x) => Value::Float(h(*x)),
        S::Float(x) => Value::Float(f(*x)),
        S::Double(x) => Value::Float(*x),
        S::HalfVec(v) => widened(v, h),
        S::FloatVec(v) => widened(v, f),
        S::DoubleVec(v) => Value::FloatArray(std::sync::Arc::new(v.clone())),
        S::TimeCode(t) => Value::Float(t.0),
        S::TimeCodeVec(v) => Value::FloatArray(std::sync::Arc::new(v.iter().map(|t| t.0).collect())),
        S::String(s) => Value::String(s.clone()),
        S::StringVec(v) => Value::StringArray(v.clone()),
        S::Token(t) if metadata => Value::String(t.as_str().to_string()),
        S::Token(t) => Value::Token(t.as_str().to_string()),
        S::TokenVec(v) if metadata => Value::StringArray(v.iter().map(|t| t.as_str().to_string()).collect()),
        S::TokenVec(v) => Value::TokenArray(v.iter().map(|t| t.as_str().to_string()).collect()),
        S::AssetPath(a) => Value::Asset(AssetPath::new(a.authored_path.clone(), base_dir)),
        S::AssetPathVec(v) => {
            Value::AssetArray(v.iter().map(|a| AssetPath::new(a.authored_path.clone(), base_dir)).collect())
        }
        S::PathVec(v) => Value::PathArray(v.iter().map(|p| p.as_str().to_string()).collect()),
        S::Quath(q) => tuple::<_, 4, _>(q, h),
        S::Quatf(q) => tuple::<_, 4, _>(q, f),
        S::Quatd(q) => tuple::<_, 4, _>(q, d),
        S::QuathVec(v) => flat::<_, 4, _>(v, h),
        S::QuatfVec(v) => flat::<_, 4, _>(v, f),
        S::QuatdVec(v) => flat::<_, 4, _>(v, d),
        S::Vec2h(x) => tuple::<_, 2, _>(x, h),
        S::Vec2f(x) => tuple::<_, 2, _>(x, f),
        S::Vec2d(x) => tuple::<_, 2, _>(x, d),
        S::Vec2i(x) => tuple::<_, 2, _>(x, |i: i32| f64::from(i)),
        S::Vec3h(x) => tuple::<_, 3, _>(x, h),
        S::Vec3f(x) => tuple::<_, 3, _>(x, f),
        S::Vec3d(x) => tuple::<_, 3, _>(x, d),
        S::Vec3i(x) => tuple::<_, 3, _>(x, |i: i32| f64::from(i)),
        S::Vec4h(x) => tuple::<_, 4, _>(x, h),
        S::Vec4f(x) => tuple::<_, 4, _>(x, f),
        S::Vec4d(x) => tuple::<_, 4, _>(x, d),
        S::Vec4i(x) => tuple::<_, 4, _>(x, |i: i32| f64::from(i)),
        S::Vec2hVec(v) => flat::<_, 2, _>(v, h),
        S::Vec2fVec(v) => flat::<_, 2, _>(v, f),
        S::Vec2dVec(v) => flat::<_, 2, _>(v, d),
        S::Vec2iVec(v) => flat::<_, 2, _>(v, |i: i32| f64::from(i)),
        S::Vec3hVec(v) => flat::<_, 3, _>(v, h),
        S::Vec3fVec(v) => flat::<_, 3, _>(v, f),
        S::Vec3dVec(v) => flat::<_, 3, _>(v, d),
        S::Vec3iVec(v) => flat::<_, 3, _>(v, |i: i32| f64::from(i)),
        S::Vec4hVec(v) => flat::<_, 4, _>(v, h),
        S::Vec4fVec(v) => flat::<_, 4, _>(v, f),
        S::Vec4dVec(v) => flat::<_, 4, _>(v, d),
        S::Vec4iVec(v) => flat::<_, 4, _>(v, |i: i32| f64::from(i)),
        S::Matrix2d(m) => Value::Matrix2(m.0),
        S::Matrix3d(m) => Value::Matrix3(m.0),
        S::Matrix4d(m) => Value::Matrix(m.0),
        S::Matrix2dVec(v) => {
            Value::TupleArray { width: 4, data: std::sync::Arc::new(v.iter().flat_map(|m| m.0).collect()) }
        }
        S::Matrix3dVec(v) => {
            Value::TupleArray { width: 9, data: std::sync::Arc::new(v.iter().flat_map(|m| m.0).collect()) }
        }
        S::Matrix4dVec(v) => {
            Value::TupleArray { width: 16, data: std::sync::Arc::new(v.iter().flat_map(|m| m.0).collect()) }
        }
        S::Dictionary(map) => {
            // Sorted by key: USD's dictionaries are ordered maps, and usda lists them so.
            let mut entries: Vec<(String, Value)> = Vec::with_capacity(map.len());
            for (k, v) in map {
                entries.push((k.clone(), convert_value(v, base_dir, false)?));
            }
            entries.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Dictionary(entries)
        }
        S::VariantSelectionMap(map) => {
            let mut entries: Vec<(String, Value)> =
                map.iter().map(|(k, v)| (k.clone(), Value::String(v.clone()))).collect();
            entries.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Dictionary(entries)
        }
        S::ValueVec(v) => {
            Value::List(v.iter().map(|x| convert_value(x, base_dir, false)).collect::<Result<Vec<_>, _>>()?)
        }
        S::Specifier(s) => Value::Token(
            match s {
                sdf::Specifier::Def => "def",
                sdf::Specifier::Over => "over",
                sdf::Specifier::Class => "class",
            }
            .into(),
        ),
        S::Permission(p) => Value::Token(
            match p {
                sdf::Permission::Public => "public",
                sdf::Permission::Private => "private",
            }
            .into(),
        ),
        S::PathExpression(e) => Value::String(e.clone()),
        S::Variability(v) => Value::Token(
            match v {
                sdf::Variability::Varying => "varying",
                sdf::Variability::Uniform => "uniform",
            }
            .into(),
        ),
        other => return Err(other.into()),
    })
}

/// A crate file's layer offset; non-finite parts are the identity's.
pub(super) fn layer_offset(o: &sdf::LayerOffset) -> LayerOffset {
    let identity = LayerOffset::default();
    LayerOffset {
        offset: if o.offset.is_finite() { o.offset } else { identity.offset },
        scale: if o.scale.is_finite() { o.scale } else { identity.scale },
    }
}
