//! Types and constant values of the shading language, and the implicit conversions between
//! them (int → float → triple; point, vector and normal among themselves; never triple → float).

use super::ast::BaseType;
use std::fmt;

/// A value type: a base type, optionally a fixed-length array of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Type {
    /// Element type.
    pub base: BaseType,
    /// Array length, if an array.
    pub array: Option<u32>,
}

impl Type {
    /// `float`
    pub const FLOAT: Type = Type::scalar(BaseType::Float);
    /// `int`
    pub const INT: Type = Type::scalar(BaseType::Int);
    /// `color`
    pub const COLOR: Type = Type::scalar(BaseType::Color);
    /// `point`
    pub const POINT: Type = Type::scalar(BaseType::Point);
    /// `vector`
    pub const VECTOR: Type = Type::scalar(BaseType::Vector);
    /// `normal`
    pub const NORMAL: Type = Type::scalar(BaseType::Normal);
    /// `string`
    pub const STRING: Type = Type::scalar(BaseType::String);
    /// `closure`
    pub const CLOSURE: Type = Type::scalar(BaseType::Closure);
    /// `void`
    pub const VOID: Type = Type::scalar(BaseType::Void);

    /// A non-array type.
    pub const fn scalar(base: BaseType) -> Type {
        Type { base, array: None }
    }

    /// Whether this is a three-component type (color, point, vector, normal).
    pub fn is_triple(self) -> bool {
        self.array.is_none()
            && matches!(self.base, BaseType::Color | BaseType::Point | BaseType::Vector | BaseType::Normal)
    }

    /// Whether this is point, vector or normal.
    pub fn is_spatial(self) -> bool {
        self.array.is_none() && matches!(self.base, BaseType::Point | BaseType::Vector | BaseType::Normal)
    }

    /// Whether this is int or float.
    pub fn is_scalar_number(self) -> bool {
        self.array.is_none() && matches!(self.base, BaseType::Int | BaseType::Float)
    }

    /// Whether this is int, float or a triple: something arithmetic applies to.
    pub fn is_numeric(self) -> bool {
        self.is_scalar_number() || self.is_triple()
    }

    /// The type of one element of an array, or `self` for a non-array.
    pub fn element(self) -> Type {
        Type::scalar(self.base)
    }

    /// Whether a value of type `self` may be used where `to` is expected without a cast.
    pub fn converts_to(self, to: Type) -> bool {
        if self == to {
            return true;
        }
        if self.array.is_some() || to.array.is_some() {
            return false;
        }
        match (self.base, to.base) {
            (BaseType::Int, BaseType::Float) => true,
            (BaseType::Int | BaseType::Float, _) => to.is_triple(),
            _ => self.is_spatial() && to.is_spatial(),
        }
    }

    /// The source-language spelling.
    pub fn name(self) -> String {
        self.to_string()
    }
}

impl fmt::Display for Type {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let base = match self.base {
            BaseType::Float => "float",
            BaseType::Int => "int",
            BaseType::Color => "color",
            BaseType::Point => "point",
            BaseType::Vector => "vector",
            BaseType::Normal => "normal",
            BaseType::String => "string",
            BaseType::Closure => "closure",
            BaseType::Void => "void",
        };
        match self.array {
            Some(n) => write!(f, "{base}[{n}]"),
            None => f.write_str(base),
        }
    }
}

/// A compile-time constant: literals, defaults, folded values.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// An int.
    Int(i32),
    /// A float.
    Float(f32),
    /// Any triple (its type says which).
    Triple([f32; 3]),
    /// A string.
    Str(String),
    /// An array of constants.
    Array(Vec<Value>),
}

impl Value {
    /// The zero value of a type (`""` for strings); `None` for closures and void.
    pub fn zero(ty: Type) -> Option<Value> {
        let element = match ty.base {
            BaseType::Int => Value::Int(0),
            BaseType::Float => Value::Float(0.0),
            BaseType::Color | BaseType::Point | BaseType::Vector | BaseType::Normal => Value::Triple([0.0; 3]),
            BaseType::String => Value::Str(String::new()),
            BaseType::Closure | BaseType::Void => return None,
        };
        Some(match ty.array {
            Some(n) => Value::Array(vec![element; n as usize]),
            None => element,
        })
    }

    /// Converts a constant of type `from` to type `to` (which `from` converts to).
    pub fn convert(&self, from: Type, to: Type) -> Value {
        if from == to {
            return self.clone();
        }
        match (self, to.base) {
            (Value::Int(i), BaseType::Float) => Value::Float(*i as f32),
            (Value::Int(i), _) if to.is_triple() => Value::Triple([*i as f32; 3]),
            (Value::Float(x), _) if to.is_triple() => Value::Triple([*x; 3]),
            (Value::Float(x), BaseType::Int) => Value::Int(*x as i32),
            _ => self.clone(),
        }
    }

    /// The value as a float, if it is a number.
    pub fn as_f32(&self) -> Option<f32> {
        match self {
            Value::Int(i) => Some(*i as f32),
            Value::Float(x) => Some(*x),
            _ => None,
        }
    }

    /// Whether any component is NaN or infinite.
    pub fn is_finite(&self) -> bool {
        match self {
            Value::Float(x) => x.is_finite(),
            Value::Triple(t) => t.iter().all(|x| x.is_finite()),
            Value::Array(items) => items.iter().all(Value::is_finite),
            Value::Int(_) | Value::Str(_) => true,
        }
    }
}

/// Formats a float so that it reads back as the same f32 and always looks like a float.
pub fn format_f32(x: f32) -> String {
    if x.is_nan() {
        "nan".into()
    } else if x.is_infinite() {
        if x > 0.0 { "inf".into() } else { "-inf".into() }
    } else {
        let s = format!("{x:?}");
        if s.contains('.') || s.contains('e') { s } else { format!("{s}.0") }
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Int(i) => write!(f, "{i}"),
            Value::Float(x) => f.write_str(&format_f32(*x)),
            Value::Triple([a, b, c]) => write!(f, "({}, {}, {})", format_f32(*a), format_f32(*b), format_f32(*c)),
            Value::Str(s) => write!(f, "{s:?}"),
            Value::Array(items) => {
                f.write_str("{")?;
                for (i, item) in items.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{item}")?;
                }
                f.write_str("}")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn promotions_go_one_way() {
        assert!(Type::INT.converts_to(Type::FLOAT));
        assert!(Type::FLOAT.converts_to(Type::COLOR));
        assert!(Type::POINT.converts_to(Type::NORMAL));
        assert!(!Type::COLOR.converts_to(Type::FLOAT));
        assert!(!Type::COLOR.converts_to(Type::VECTOR));
        assert!(!Type::FLOAT.converts_to(Type::INT));
        assert!(!Type::CLOSURE.converts_to(Type::COLOR));
    }

    #[test]
    fn floats_print_as_floats() {
        assert_eq!(format_f32(1.0), "1.0");
        assert_eq!(format_f32(0.1), "0.1");
        assert_eq!(Value::Triple([1.0, 0.5, 0.0]).to_string(), "(1.0, 0.5, 0.0)");
    }
}
