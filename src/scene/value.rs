//! Typed attribute and metadata values.
//!
//! Values are stored in the widest natural Rust type (`f64` for half/float/double, `i64` for
//! every integer type) and arrays of numbers and tuples are flat, so a mesh's points are one
//! `Vec<f64>` rather than a vector of small vectors. The declared USD type name (`point3f[]`)
//! lives on the attribute; [`ValueType`] classifies it and [`Value::coerce`] turns a value
//! as written into the shape that type needs.

use std::path::{Path, PathBuf};
use std::sync::Arc;

/// An asset path as authored, plus its resolution against the authoring layer's directory.
#[derive(Clone, Debug, PartialEq)]
pub struct AssetPath {
    /// The text between the `@` delimiters.
    pub authored: String,
    /// `authored` joined to the directory of the layer that wrote it (lexically normalised;
    /// the file need not exist). Empty when `authored` is empty.
    pub resolved: PathBuf,
}

impl AssetPath {
    /// Resolves `authored` relative to `base_dir` (absolute paths are kept as they are). In a
    /// layer read from a usdz package, `base_dir` is package-relative (`a.usdz[sub]`) and
    /// relative paths resolve inside the package ([`crate::input::resolve_asset`]).
    pub fn new(authored: impl Into<String>, base_dir: &Path) -> AssetPath {
        let authored = authored.into();
        let resolved =
            if authored.is_empty() { PathBuf::new() } else { crate::input::resolve_asset(base_dir, &authored) };
        AssetPath { authored, resolved }
    }
}

/// A typed value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// `None`: a blocked value (or an explicitly empty relationship in metadata).
    None,
    /// `bool` (written `0`/`1` or `true`/`false`).
    Bool(bool),
    /// Any integer type.
    Int(i64),
    /// `half`, `float`, `double`, `timecode`.
    Float(f64),
    /// `string`.
    String(String),
    /// `token`.
    Token(String),
    /// `asset`.
    Asset(AssetPath),
    /// A scene path `</a/b>`.
    Path(String),
    /// A vector, color, point, texture coordinate or quaternion (components as written;
    /// quaternions are `(real, i, j, k)`), also integer vectors such as `int3`.
    Tuple(Vec<f64>),
    /// `matrix2d`: 2×2, row-major as USD writes it.
    Matrix2([f64; 4]),
    /// `matrix3d`: 3×3, row-major.
    Matrix3([f64; 9]),
    /// `matrix4d`: 4×4, row-major (translation in the last row, as USD writes it).
    Matrix([f64; 16]),
    /// `bool[]`.
    BoolArray(Vec<bool>),
    /// Arrays of any integer type. (The numeric arrays are shared, not copied, between a
    /// layer's opinion and the composed stage's value and default: a mesh's arrays are
    /// held once.)
    IntArray(Arc<Vec<i64>>),
    /// Arrays of `half`, `float`, `double`.
    FloatArray(Arc<Vec<f64>>),
    /// Arrays of tuples or matrices, flat: element `i` is `data[i*width..(i+1)*width]`.
    TupleArray {
        /// Components per element (3 for `point3f[]`, 16 for `matrix4d[]`).
        width: usize,
        /// All components, element after element.
        data: Arc<Vec<f64>>,
    },
    /// `string[]`.
    StringArray(Vec<String>),
    /// `token[]`.
    TokenArray(Vec<String>),
    /// `asset[]`.
    AssetArray(Vec<AssetPath>),
    /// Arrays of paths.
    PathArray(Vec<String>),
    /// Any other list (mixed metadata lists, `string` tuples).
    List(Vec<Value>),
    /// A dictionary (`customData`, `customLayerData`, variant selections).
    Dictionary(Vec<(String, Value)>),
}

impl Value {
    /// A number as `f64` (`Bool` gives 0 or 1).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Float(f) => Some(*f),
            Value::Int(i) => Some(*i as f64),
            Value::Bool(b) => Some(f64::from(u8::from(*b))),
            _ => None,
        }
    }

    /// An integer (floats with no fractional part count).
    pub fn as_i64(&self) -> Option<i64> {
        match self {
            Value::Int(i) => Some(*i),
            Value::Bool(b) => Some(i64::from(*b)),
            Value::Float(f) if f.fract() == 0.0 && f.abs() < 9.0e15 => Some(*f as i64),
            _ => None,
        }
    }

    /// A boolean (`0`/`1` integers count).
    pub fn as_bool(&self) -> Option<bool> {
        match self {
            Value::Bool(b) => Some(*b),
            Value::Int(0) => Some(false),
            Value::Int(1) => Some(true),
            _ => None,
        }
    }

    /// The text of a string, token, asset (as authored) or path.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::String(s) | Value::Token(s) | Value::Path(s) => Some(s),
            Value::Asset(a) => Some(&a.authored),
            _ => None,
        }
    }

    /// An asset path.
    pub fn as_asset(&self) -> Option<&AssetPath> {
        match self {
            Value::Asset(a) => Some(a),
            _ => None,
        }
    }

    /// The components of a tuple.
    pub fn as_tuple(&self) -> Option<&[f64]> {
        match self {
            Value::Tuple(t) => Some(t),
            _ => None,
        }
    }

    /// A 2-component tuple.
    pub fn as_vec2(&self) -> Option<[f64; 2]> {
        self.as_tuple()?.try_into().ok()
    }

    /// A 3-component tuple.
    pub fn as_vec3(&self) -> Option<[f64; 3]> {
        self.as_tuple()?.try_into().ok()
    }

    /// A 4-component tuple.
    pub fn as_vec4(&self) -> Option<[f64; 4]> {
        self.as_tuple()?.try_into().ok()
    }

    /// A 4×4 matrix, row-major.
    pub fn as_matrix4(&self) -> Option<&[f64; 16]> {
        match self {
            Value::Matrix(m) => Some(m),
            _ => None,
        }
    }

    /// An integer array.
    pub fn as_int_array(&self) -> Option<&[i64]> {
        match self {
            Value::IntArray(a) => Some(a.as_slice()),
            _ => None,
        }
    }

    /// A float array.
    pub fn as_float_array(&self) -> Option<&[f64]> {
        match self {
            Value::FloatArray(a) => Some(a.as_slice()),
            _ => None,
        }
    }

    /// A flat tuple array and its element width.
    pub fn as_tuple_array(&self) -> Option<(usize, &[f64])> {
        match self {
            Value::TupleArray { width, data } => Some((*width, data.as_slice())),
            _ => None,
        }
    }

    /// A tuple array of width 3 as `[f64; 3]` elements.
    pub fn as_vec3_array(&self) -> Option<Vec<[f64; 3]>> {
        match self.as_tuple_array()? {
            (3, data) => Some(data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()),
            _ => None,
        }
    }

    /// A string or token array.
    pub fn as_string_array(&self) -> Option<&[String]> {
        match self {
            Value::StringArray(a) | Value::TokenArray(a) | Value::PathArray(a) => Some(a),
            _ => None,
        }
    }

    /// A dictionary's entries.
    pub fn as_dictionary(&self) -> Option<&[(String, Value)]> {
        match self {
            Value::Dictionary(d) => Some(d),
            _ => None,
        }
    }

    /// Whether this is `None` (a blocked value).
    pub fn is_none(&self) -> bool {
        matches!(self, Value::None)
    }

    /// A short description of the value's shape for error messages.
    pub fn describe(&self) -> &'static str {
        match self {
            Value::None => "None",
            Value::Bool(_) => "a bool",
            Value::Int(_) => "an integer",
            Value::Float(_) => "a number",
            Value::String(_) => "a string",
            Value::Token(_) => "a token",
            Value::Asset(_) => "an asset path",
            Value::Path(_) => "a path",
            Value::Tuple(_) => "a tuple",
            Value::Matrix2(_) | Value::Matrix3(_) | Value::Matrix(_) => "a matrix",
            Value::BoolArray(_)
            | Value::IntArray(_)
            | Value::FloatArray(_)
            | Value::TupleArray { .. }
            | Value::StringArray(_)
            | Value::TokenArray(_)
            | Value::AssetArray(_)
            | Value::PathArray(_)
            | Value::List(_) => "an array",
            Value::Dictionary(_) => "a dictionary",
        }
    }

    /// Converts a value as written into the representation `ty` calls for, e.g. the integer
    /// `1` for a `float` becomes `Float(1.0)` and a list of 3-tuples for `point3f[]` becomes a
    /// `TupleArray` of width 3. `None` passes through for every type. Unknown types keep
    /// the value as written. The error names what was expected.
    pub fn coerce(self, ty: &ValueType) -> Result<Value, String> {
        if self.is_none() || ty.scalar == ScalarType::Unknown {
            return Ok(self);
        }
        if ty.array { coerce_array(self, ty.scalar) } else { coerce_scalar(self, ty.scalar) }
    }
}

fn coerce_scalar(value: Value, scalar: ScalarType) -> Result<Value, String> {
    let fail = |v: &Value| Err(format!("expected {}, found {}", scalar.describe(), v.describe()));
    match scalar {
        ScalarType::Bool => match value.as_bool() {
            Some(b) => Ok(Value::Bool(b)),
            None => fail(&value),
        },
        ScalarType::Int => match value.as_i64() {
            Some(i) => Ok(Value::Int(i)),
            None => fail(&value),
        },
        ScalarType::Float => match value.as_f64() {
            Some(f) => Ok(Value::Float(f)),
            None => fail(&value),
        },
        ScalarType::String => match value {
            Value::String(_) => Ok(value),
            Value::Token(s) => Ok(Value::String(s)),
            _ => fail(&value),
        },
        ScalarType::Token => match value {
            Value::String(s) | Value::Token(s) => Ok(Value::Token(s)),
            _ => fail(&value),
        },
        ScalarType::Asset => match value {
            Value::Asset(_) => Ok(value),
            _ => fail(&value),
        },
        ScalarType::Path => match value {
            Value::Path(_) => Ok(value),
            _ => fail(&value),
        },
        ScalarType::Tuple(n) => match value {
            Value::Tuple(ref t) if t.len() == n => Ok(value),
            _ => fail(&value),
        },
        ScalarType::Matrix(n) => match (n, value) {
            // Already a matrix (read from a binary layer): keep it if the size matches.
            (2, v @ Value::Matrix2(_)) | (3, v @ Value::Matrix3(_)) | (4, v @ Value::Matrix(_)) => Ok(v),
            (_, value) => match matrix_from(&value, n) {
                Some(m) => Ok(m),
                None => fail(&value),
            },
        },
        ScalarType::Dictionary => match value {
            Value::Dictionary(_) => Ok(value),
            _ => fail(&value),
        },
        ScalarType::Unknown => Ok(value),
    }
}

/// A matrix from nested tuples `((a, b), (c, d))`, which the parser reads as `List` of `Tuple`.
fn matrix_from(value: &Value, n: usize) -> Option<Value> {
    let mut flat = Vec::with_capacity(n * n);
    match value {
        Value::List(rows) if rows.len() == n => {
            for row in rows {
                let row = row.as_tuple().filter(|r| r.len() == n)?;
                flat.extend_from_slice(row);
            }
        }
        _ => return None,
    }
    Some(match n {
        2 => Value::Matrix2(flat.try_into().ok()?),
        3 => Value::Matrix3(flat.try_into().ok()?),
        _ => Value::Matrix(flat.try_into().ok()?),
    })
}

fn coerce_array(value: Value, scalar: ScalarType) -> Result<Value, String> {
    let fail = |v: &Value| Err(format!("expected an array of {}, found {}", scalar.describe(), v.describe()));
    // An empty `[]` parses as an empty `List`; give it the right shape.
    if let Value::List(ref items) = value
        && items.is_empty()
    {
        return Ok(empty_array(scalar));
    }
    match (scalar, value) {
        (ScalarType::Bool, Value::IntArray(a)) => Ok(Value::BoolArray(a.iter().map(|&i| i != 0).collect())),
        (ScalarType::Bool, v @ Value::BoolArray(_)) => Ok(v),
        (ScalarType::Int, v @ Value::IntArray(_)) => Ok(v),
        (ScalarType::Float, Value::IntArray(a)) => {
            Ok(Value::FloatArray(Arc::new(a.iter().map(|&i| i as f64).collect())))
        }
        (ScalarType::Float, v @ Value::FloatArray(_)) => Ok(v),
        (ScalarType::Tuple(n), v @ Value::TupleArray { width, .. }) if width == n => Ok(v),
        (ScalarType::Matrix(n), v @ Value::TupleArray { width, .. }) if width == n * n => Ok(v),
        (ScalarType::Matrix(n), Value::List(items)) => {
            let mut data = Vec::with_capacity(items.len() * n * n);
            for item in &items {
                match matrix_from(item, n) {
                    Some(Value::Matrix2(m)) => data.extend_from_slice(&m),
                    Some(Value::Matrix3(m)) => data.extend_from_slice(&m),
                    Some(Value::Matrix(m)) => data.extend_from_slice(&m),
                    _ => return fail(item),
                }
            }
            Ok(Value::TupleArray { width: n * n, data: Arc::new(data) })
        }
        (ScalarType::String, v @ Value::StringArray(_)) => Ok(v),
        (ScalarType::String, Value::TokenArray(a)) => Ok(Value::StringArray(a)),
        (ScalarType::Token, Value::StringArray(a) | Value::TokenArray(a)) => Ok(Value::TokenArray(a)),
        (ScalarType::Asset, v @ Value::AssetArray(_)) => Ok(v),
        (ScalarType::Path, v @ Value::PathArray(_)) => Ok(v),
        (_, v) => fail(&v),
    }
}

fn empty_array(scalar: ScalarType) -> Value {
    match scalar {
        ScalarType::Bool => Value::BoolArray(Vec::new()),
        ScalarType::Int => Value::IntArray(Arc::default()),
        ScalarType::Float => Value::FloatArray(Arc::default()),
        ScalarType::Tuple(n) => Value::TupleArray { width: n, data: Arc::default() },
        ScalarType::Matrix(n) => Value::TupleArray { width: n * n, data: Arc::default() },
        ScalarType::String => Value::StringArray(Vec::new()),
        ScalarType::Token => Value::TokenArray(Vec::new()),
        ScalarType::Asset => Value::AssetArray(Vec::new()),
        ScalarType::Path => Value::PathArray(Vec::new()),
        ScalarType::Dictionary | ScalarType::Unknown => Value::List(Vec::new()),
    }
}

/// The shape of one element of a USD value type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarType {
    /// `bool`
    Bool,
    /// `int`, `uint`, `int64`, `uint64`, `uchar`
    Int,
    /// `half`, `float`, `double`, `timecode`
    Float,
    /// `string`
    String,
    /// `token`
    Token,
    /// `asset`
    Asset,
    /// Scene paths (relationship targets, connections).
    Path,
    /// A fixed-size tuple of numbers: vectors, colors, points, quaternions.
    Tuple(usize),
    /// A square matrix of the given dimension.
    Matrix(usize),
    /// `dictionary`
    Dictionary,
    /// A type this reader does not know (`opaque`, custom types): values kept as written.
    Unknown,
}

impl ScalarType {
    fn describe(self) -> String {
        match self {
            ScalarType::Bool => "a bool".into(),
            ScalarType::Int => "an integer".into(),
            ScalarType::Float => "a number".into(),
            ScalarType::String => "a string".into(),
            ScalarType::Token => "a token".into(),
            ScalarType::Asset => "an asset path".into(),
            ScalarType::Path => "a path".into(),
            ScalarType::Tuple(n) => format!("a {n}-tuple"),
            ScalarType::Matrix(n) => format!("a {n}x{n} matrix"),
            ScalarType::Dictionary => "a dictionary".into(),
            ScalarType::Unknown => "a value".into(),
        }
    }
}

/// A classified USD value type name such as `point3f[]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ValueType {
    /// The element type.
    pub scalar: ScalarType,
    /// Whether the name ended in `[]`.
    pub array: bool,
}

impl ValueType {
    /// Classifies a type name; `array` says whether `[]` followed it.
    pub fn parse(name: &str, array: bool) -> ValueType {
        let scalar = match name {
            "bool" => ScalarType::Bool,
            "int" | "uint" | "int64" | "uint64" | "uchar" => ScalarType::Int,
            "half" | "float" | "double" | "timecode" => ScalarType::Float,
            "string" => ScalarType::String,
            "token" => ScalarType::Token,
            "asset" => ScalarType::Asset,
            "dictionary" => ScalarType::Dictionary,
            "matrix2d" => ScalarType::Matrix(2),
            "matrix3d" => ScalarType::Matrix(3),
            "matrix4d" | "frame4d" => ScalarType::Matrix(4),
            "quath" | "quatf" | "quatd" => ScalarType::Tuple(4),
            _ => match tuple_width(name) {
                Some(n) => ScalarType::Tuple(n),
                None => ScalarType::Unknown,
            },
        };
        ValueType { scalar, array }
    }
}

/// The width of `int3`, `float2`, `color3f`, `texCoord2d`, ... types.
fn tuple_width(name: &str) -> Option<usize> {
    const PREFIXES: [&str; 10] =
        ["int", "half", "float", "double", "point", "normal", "vector", "color", "texCoord", "uint"];
    let prefix = PREFIXES.iter().find(|p| name.starts_with(**p))?;
    let rest = &name[prefix.len()..];
    let mut chars = rest.chars();
    let n = chars.next()?.to_digit(10)? as usize;
    let suffix = chars.as_str();
    let ok_suffix = match *prefix {
        "int" | "half" | "float" | "double" | "uint" => suffix.is_empty(),
        _ => matches!(suffix, "f" | "d" | "h"),
    };
    ((2..=4).contains(&n) && ok_suffix).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classifies_type_names() {
        let t = |n: &str| ValueType::parse(n, false).scalar;
        assert_eq!(t("point3f"), ScalarType::Tuple(3));
        assert_eq!(t("color4f"), ScalarType::Tuple(4));
        assert_eq!(t("texCoord2d"), ScalarType::Tuple(2));
        assert_eq!(t("int3"), ScalarType::Tuple(3));
        assert_eq!(t("half2"), ScalarType::Tuple(2));
        assert_eq!(t("quath"), ScalarType::Tuple(4));
        assert_eq!(t("matrix3d"), ScalarType::Matrix(3));
        assert_eq!(t("int64"), ScalarType::Int);
        assert_eq!(t("float5"), ScalarType::Unknown);
        assert_eq!(t("opaque"), ScalarType::Unknown);
        assert!(ValueType::parse("float", true).array);
    }

    #[test]
    fn coerces_numbers_and_arrays() {
        let ty = |n: &str, a: bool| ValueType::parse(n, a);
        assert_eq!(Value::Int(1).coerce(&ty("float", false)), Ok(Value::Float(1.0)));
        assert_eq!(Value::Int(0).coerce(&ty("bool", false)), Ok(Value::Bool(false)));
        assert_eq!(
            Value::IntArray(vec![1, 2].into()).coerce(&ty("float", true)),
            Ok(Value::FloatArray(vec![1.0, 2.0].into()))
        );
        assert_eq!(
            Value::List(vec![]).coerce(&ty("point3f", true)),
            Ok(Value::TupleArray { width: 3, data: Arc::default() })
        );
        assert_eq!(Value::String("a".into()).coerce(&ty("token", false)), Ok(Value::Token("a".into())));
        assert!(Value::String("a".into()).coerce(&ty("float", false)).is_err());
        assert!(Value::Tuple(vec![1.0, 2.0]).coerce(&ty("float3", false)).is_err());
        assert_eq!(Value::None.coerce(&ty("float3", false)), Ok(Value::None));
    }

    #[test]
    fn coerces_matrices() {
        let rows = Value::List(vec![Value::Tuple(vec![1.0, 2.0]), Value::Tuple(vec![3.0, 4.0])]);
        assert_eq!(rows.coerce(&ValueType::parse("matrix2d", false)), Ok(Value::Matrix2([1.0, 2.0, 3.0, 4.0])));
    }

    #[test]
    fn accessors_and_assets() {
        assert_eq!(Value::Tuple(vec![1.0, 2.0, 3.0]).as_vec3(), Some([1.0, 2.0, 3.0]));
        assert_eq!(Value::Tuple(vec![1.0, 2.0]).as_vec3(), None);
        assert_eq!(Value::Int(3).as_f64(), Some(3.0));
        let a = AssetPath::new("./tex/../a.png", Path::new("/scenes/x"));
        assert_eq!(a.resolved, PathBuf::from("/scenes/x/a.png"));
        assert_eq!(AssetPath::new("/abs.usda", Path::new("/d")).resolved, PathBuf::from("/abs.usda"));
        let arr = Value::TupleArray { width: 3, data: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0].into() };
        assert_eq!(arr.as_vec3_array(), Some(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]));
    }
}
