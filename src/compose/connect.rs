//! UsdShade connections: the attribute an input takes its value from (through the inputs and
//! outputs of Materials and NodeGraphs), and the conversion of a USD value to a substance
//! input's type. Shared by strata-shader materials ([`super::scene`]) and preview networks
//! ([`super::preview`]).

use crate::diag::{Diagnostic, Diagnostics};
use crate::front::ast::BaseType;
use crate::front::types::{Type, Value};
use crate::scene::{Attribute, Prim, Stage, Value as UsdValue};

/// `/Prim.name`, the form connection targets take.
pub(super) fn attribute_path(prim: &Prim, attr: &Attribute) -> String {
    format!("{}.{}", prim.path, attr.name)
}

/// Whether a prim type encapsulates a shading network (UsdShade's containers), so that its
/// inputs and outputs pass connections on instead of computing values.
fn is_container(prim: &Prim) -> bool {
    matches!(prim.type_name.as_deref(), Some("Material" | "NodeGraph"))
}

/// The attribute whose value an input takes, as UsdShade's `GetValueProducingAttributes`
/// resolves it: connections are followed through the inputs and outputs of Materials and
/// NodeGraphs; where they lead to no value, the input's own authored value applies. `seen`
/// holds the connected attributes on the way (`/Prim.inputs:x`) to detect cycles.
pub(super) fn value_producer<'s>(
    stage: &'s Stage,
    prim: &'s Prim,
    attr: &'s Attribute,
    seen: &mut Vec<String>,
    diags: &mut Diagnostics,
) -> Option<(&'s Prim, &'s Attribute)> {
    match producer(stage, prim, attr, false, seen, diags)? {
        Producer::Value(prim, attr) => Some((prim, attr)),
        Producer::Output(..) => None, // never returned when shader outputs are not wanted
    }
}

/// What an input resolves to through its connections.
#[derive(Clone, Copy)]
pub(super) enum Producer<'s> {
    /// An attribute whose authored value the input takes.
    Value(&'s Prim, &'s Attribute),
    /// An output of a shader (not a Material or NodeGraph): a node of the network.
    Output(&'s Prim, &'s Attribute),
}

/// [`value_producer`], optionally stopping at shader outputs (`outputs`: the preview networks
/// of `compose::preview` evaluate them as nodes) instead of warning that strata cannot
/// evaluate them.
pub(super) fn producer<'s>(
    stage: &'s Stage,
    prim: &'s Prim,
    attr: &'s Attribute,
    outputs: bool,
    seen: &mut Vec<String>,
    diags: &mut Diagnostics,
) -> Option<Producer<'s>> {
    let own = attr.value.is_some().then_some(Producer::Value(prim, attr));
    let (target, span) = match attr.connections.as_slice() {
        [] => return own,
        [one] => one,
        targets => {
            let mut d = Diagnostic::error(format!(
                "`{}` connects to {} sources; a substance input takes one value",
                attribute_path(prim, attr),
                targets.len()
            ))
            .at(attr.span, "this input");
            for (_, span) in targets {
                d = d.also(*span, "source");
            }
            diags.push(d);
            return own;
        }
    };
    seen.push(attribute_path(prim, attr));
    // A prim path has no `.`; the property name follows the first one.
    let Some((source_path, name)) = target.split_once('.') else {
        diags.push(
            Diagnostic::error(format!("connection source `{target}` is not an attribute"))
                .at(*span, "expected `</Prim.inputs:name>` or `</Prim.outputs:name>`"),
        );
        return own;
    };
    let Some(source) = stage.find(source_path).map(|id| stage.prim(id)) else {
        diags.push(
            Diagnostic::error(format!("connection source `{target}` does not exist"))
                .at(*span, format!("no prim `{source_path}`")),
        );
        return own;
    };
    let Some(source_attr) = source.attribute(name) else {
        diags.push(
            Diagnostic::error(format!("connection source `{target}` does not exist"))
                .at(*span, format!("`{source_path}` has no attribute `{name}`"))
                .also(source.span, "this prim"),
        );
        return own;
    };
    if seen.contains(&attribute_path(source, source_attr)) {
        diags.push(
            Diagnostic::error(format!("connection cycle: `{target}` leads back to itself"))
                .at(*span, "this connection closes the cycle"),
        );
        return own;
    }
    let found = match (name.split_once(':').map(|(ns, _)| ns), is_container(source)) {
        (Some("inputs" | "outputs"), true) => producer(stage, source, source_attr, outputs, seen, diags),
        (Some("outputs"), false) if outputs => Some(Producer::Output(source, source_attr)),
        (Some("outputs"), false) => {
            diags.push(
                Diagnostic::warning(format!(
                    "strata cannot evaluate `{target}`, an output of the shader `{source_path}`; the connection is ignored"
                ))
                .at(*span, "connected here")
                .note("the input takes a value authored along the connection, else the substance's default"),
            );
            None
        }
        (Some("inputs"), false) => {
            diags.push(
                Diagnostic::warning(format!(
                    "`{target}` is an input of the shader `{source_path}`; UsdShade ignores such a connection"
                ))
                .at(*span, "connected here")
                .note("a shader input connects to a Material or NodeGraph input, or to a shader output"),
            );
            None
        }
        _ => {
            diags.push(
                Diagnostic::error(format!("connection source `{target}` is neither an input nor an output"))
                    .at(*span, "expected `inputs:` or `outputs:`"),
            );
            None
        }
    };
    found.or(own)
}

/// The shading-language type a USD value type name corresponds to (`None`: any triple).
fn usd_type(name: &str) -> Result<Option<Type>, ()> {
    let base = name.trim_end_matches("[]");
    Ok(Some(match base {
        "float" | "double" | "half" => Type::FLOAT,
        "int" | "uint" | "int64" | "uint64" | "uchar" | "bool" => Type::INT,
        "string" | "token" | "asset" => Type::STRING,
        "color3f" | "color3d" | "color3h" => Type::COLOR,
        "point3f" | "point3d" | "point3h" => Type::POINT,
        "normal3f" | "normal3d" | "normal3h" => Type::NORMAL,
        "vector3f" | "vector3d" | "vector3h" => Type::VECTOR,
        "float3" | "double3" | "half3" => return Ok(None),
        _ => return Err(()),
    }))
}

/// Converts a scene value to a substance input's type, rejecting NaN, infinities and
/// incompatible types.
pub(super) fn convert_input(value: &UsdValue, type_name: &str, to: Type) -> Result<Value, String> {
    let from = usd_type(type_name).map_err(|_| format!("USD type `{type_name}` cannot set a {to} input"))?;
    let compatible = match from {
        Some(from) => {
            from.converts_to(to)
                || (from.is_triple() && to.is_triple() && from.base != BaseType::Color && to.base != BaseType::Color)
        }
        None => to.is_triple(),
    };
    if !compatible {
        return Err(format!("a `{type_name}` value cannot set a {to} input"));
    }
    let finite = |x: f64| -> Result<f32, String> {
        let y = x as f32;
        if y.is_finite() { Ok(y) } else { Err(format!("value {x} is not finite")) }
    };
    let v = match value {
        UsdValue::Float(x) => Value::Float(finite(*x)?),
        UsdValue::Int(i) => Value::Int(i32::try_from(*i).map_err(|_| format!("{i} does not fit in 32 bits"))?),
        UsdValue::Bool(b) => Value::Int(*b as i32),
        UsdValue::String(s) | UsdValue::Token(s) => Value::Str(s.clone()),
        UsdValue::Asset(a) => Value::Str(a.resolved.display().to_string()),
        UsdValue::Tuple(t) if t.len() == 3 => Value::Triple([finite(t[0])?, finite(t[1])?, finite(t[2])?]),
        other => return Err(format!("expected a single {to}, found {}", other.describe())),
    };
    let from = match (&v, from) {
        (Value::Triple(_), None) => to,
        (Value::Float(_), _) => Type::FLOAT,
        (Value::Int(_), _) => Type::INT,
        (_, Some(t)) => t,
        (_, None) => to,
    };
    if from.is_triple() && to.is_triple() {
        return Ok(v);
    }
    if !from.converts_to(to) {
        return Err(format!("a {from} value cannot set a {to} input"));
    }
    Ok(v.convert(from, to))
}
