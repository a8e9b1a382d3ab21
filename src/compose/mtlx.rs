//! MaterialX shader networks (`info:id = "ND_…"`, authored in USD by DCCs or translated from
//! `.mtlx` documents by `scene::mtlx`) on the road preview networks take ([`super::preview`]):
//! the surface shader is a built-in substance (`open_pbr_surface`, `standard_surface`, in
//! `front/mtlx.ash`), every other node a built-in node function `mx_<node>_<variant>`.
//!
//! This module holds what is MaterialX's own: which substance a surface id names, which node
//! function a node id names (by MaterialX's type suffixes), port names, colour spaces, and
//! what is reported (a node strata lacks, once per kind; a surface input the layered surfaces
//! do not read, when a scene sets it).

use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::front::types::Value;
use std::borrow::Cow;

/// The built-in substance for a MaterialX (or UsdPreviewSurface) surface shader id.
pub fn surface_substance(id: &str) -> Option<&'static str> {
    match id {
        "UsdPreviewSurface" | "ND_UsdPreviewSurface_surfaceshader" => Some("UsdPreviewSurface"),
        "ND_open_pbr_surface_surfaceshader" => Some("open_pbr_surface"),
        "ND_standard_surface_surfaceshader" | "ND_standard_surface_surfaceshader_100" => Some("standard_surface"),
        "ND_surface" => Some("mx_surface"),
        "ND_surface_unlit" => Some("mx_surface_unlit"),
        _ => None,
    }
}

/// The preview node a MaterialX definition of a UsdShade preview node names
/// (`ND_UsdUVTexture`, `ND_UsdPrimvarReader_vector2`, ...: MaterialX's `usd` library).
pub fn preview_node(id: &str) -> Option<&'static str> {
    Some(match id {
        "ND_UsdUVTexture" | "ND_UsdUVTexture_23" => "UsdUVTexture",
        "ND_UsdPrimvarReader_float" => "UsdPrimvarReader_float",
        "ND_UsdPrimvarReader_integer" => "UsdPrimvarReader_int",
        "ND_UsdPrimvarReader_vector2" => "UsdPrimvarReader_float2",
        "ND_UsdPrimvarReader_vector" | "ND_UsdPrimvarReader_vector3" | "ND_UsdPrimvarReader_color3" => {
            "UsdPrimvarReader_float3"
        }
        "ND_UsdTransform2d" => "UsdTransform2d",
        _ => return None,
    })
}

/// MaterialX's data types, as they end node definition names (`ND_add_color3FA`).
const TYPES: &[&str] = &[
    "float",
    "integer",
    "boolean",
    "color3",
    "color4",
    "vector2",
    "vector3",
    "vector4",
    "matrix33",
    "matrix44",
    "string",
    "filename",
    "surfaceshader",
    "displacementshader",
    "volumeshader",
    "BSDF",
    "EDF",
    "VDF",
];

/// Splits a node definition id into its node name and its type suffix:
/// `ND_multiply_color3FA` → (`multiply`, `color3FA`), `ND_convert_float_color3` →
/// (`convert`, `float_color3`), `ND_normalmap` → (`normalmap`, ``).
pub fn split_id(id: &str) -> Option<(&str, &str)> {
    let rest = id.strip_prefix("ND_")?;
    for (i, _) in rest.match_indices('_') {
        let tail = &rest[i + 1..];
        if TYPES.iter().any(|t| tail.starts_with(t)) {
            return Some((&rest[..i], tail));
        }
    }
    Some((rest, ""))
}

/// The variant a type takes in the node library: `float`, `color3` for the triples (color3,
/// vector3, vector2) or `color4` for the 4-channel types (color4, vector4: a colour and a
/// float `_a`), with or without MaterialX's `FA` float-argument suffix.
fn variant(ty: &str) -> Option<&'static str> {
    let ty = ty.strip_suffix("FA").unwrap_or(ty);
    let ty = ty.split('_').next().unwrap_or(ty);
    match ty {
        "float" => Some("float"),
        "color3" | "vector3" | "vector2" | "" => Some("color3"),
        "color4" | "vector4" => Some("color4"),
        _ => None,
    }
}

/// pbrlib's closure nodes by definition id, and the node function each is: BSDF nodes are
/// closures, EDFs emitted radiance as a colour (their operators are the colour nodes).
const PBRLIB: &[(&str, &str)] = &[
    ("ND_oren_nayar_diffuse_bsdf", "mx_oren_nayar_diffuse_bsdf"),
    ("ND_burley_diffuse_bsdf", "mx_burley_diffuse_bsdf"),
    ("ND_dielectric_bsdf", "mx_dielectric_bsdf"),
    ("ND_conductor_bsdf", "mx_conductor_bsdf"),
    ("ND_generalized_schlick_bsdf", "mx_generalized_schlick_bsdf"),
    ("ND_sheen_bsdf", "mx_sheen_bsdf"),
    ("ND_translucent_bsdf", "mx_translucent_bsdf"),
    ("ND_subsurface_bsdf", "mx_subsurface_bsdf"),
    ("ND_thin_film_bsdf", "mx_thin_film_bsdf"),
    ("ND_layer_bsdf", "mx_layer_bsdf"),
    ("ND_mix_bsdf", "mx_mix_bsdf"),
    ("ND_add_bsdf", "mx_add_bsdf"),
    ("ND_multiply_bsdfC", "mx_multiply_bsdfC"),
    ("ND_multiply_bsdfF", "mx_multiply_bsdfF"),
    ("ND_uniform_edf", "mx_uniform_edf"),
    ("ND_mix_edf", "mx_mix_color3"),
    ("ND_add_edf", "mx_add_color3"),
    ("ND_multiply_edfC", "mx_multiply_color3"),
    ("ND_multiply_edfF", "mx_multiply_color3"),
];

/// The node function a MaterialX node id names (`mx_image_color3` for `ND_image_vector3`),
/// if strata's library may have it; the caller checks that it does.
pub fn node_function(id: &str) -> Option<String> {
    if let Some((_, function)) = PBRLIB.iter().find(|(nd, _)| *nd == id) {
        return Some((*function).into());
    }
    let (node, types) = split_id(id)?;
    if node == "normalmap" {
        // `ND_normalmap` (1.38), `ND_normalmap_float`/`_vector2` (1.39: the type of `scale`).
        return Some(if types == "vector2" { "mx_normalmap_vector2" } else { "mx_normalmap_color3" }.into());
    }
    if matches!(node, "mincomponent" | "maxcomponent") && types == "vector2" {
        // A vector2 travels with z = 0, which is not one of its components.
        return Some(format!("mx_{node}_vector2"));
    }
    if node == "combine2" && types == "vector4VV" {
        return Some("mx_combine2_vector4VV".into());
    }
    if node == "combine2" && matches!(types, "color4CF" | "vector4VF") {
        return Some("mx_combine2_color4".into());
    }
    if matches!(node, "combine2" | "combine3") {
        // Named by the type they build; the library's variant takes floats.
        return Some(format!("mx_{node}_float"));
    }
    if matches!(node, "ifgreater" | "ifgreatereq" | "ifequal" | "switch")
        && let Some(ty) = types.strip_suffix('I').or_else(|| types.strip_suffix('B').filter(|_| node == "ifequal"))
    {
        // Selected by an integer (`…I`) or, for ifequal, a boolean (`…B`: 0 or 1): one
        // integer-selected variant serves both.
        return Some(format!("mx_{node}_{}I", variant(ty)?));
    }
    if node == "convert" {
        let (from, to) = types.split_once('_')?;
        return match (variant(from)?, to) {
            ("float", to) if variant(to)? == "color3" => Some("mx_convert_float_color3".into()),
            ("float", "color4" | "vector4") => Some("mx_convert_float_color4".into()),
            ("color3", "vector2") => Some("mx_convert_color3_vector2".into()),
            ("color3", to) if variant(to)? == "color3" => Some("mx_convert_color3_color3".into()),
            ("color3", "color4" | "vector4") => Some("mx_convert_color3_color4".into()),
            ("color4", "vector2") => Some("mx_convert_color4_vector2".into()),
            ("color4", to) if variant(to)? == "color3" => Some("mx_convert_color4_color3".into()),
            ("color4", "color4" | "vector4") => Some("mx_convert_color4_color4".into()),
            _ => None,
        };
    }
    Some(format!("mx_{node}_{}", variant(types)?))
}

/// Names of the shading language that a MaterialX port may carry (`in`, `normal`,
/// `default`): the library's ports append `_`.
const RESERVED: &[&str] = &[
    "in",
    "default",
    "normal",
    "color",
    "vector",
    "point",
    "float",
    "int",
    "string",
    "closure",
    "output",
    "input",
    "node",
    "shader",
    "substance",
    "override",
    "import",
    "if",
    "else",
    "for",
    "while",
    "break",
    "continue",
    "return",
    "void",
];

/// The library's name for MaterialX port `name`.
pub fn port_name(name: &str) -> Cow<'_, str> {
    if RESERVED.contains(&name) { Cow::Owned(format!("{name}_")) } else { Cow::Borrowed(name) }
}

/// MaterialX's name for colour space `space`: its own names, their legacy (1.38) forms and the
/// ACES OCIO configs' names of the same spaces (MaterialX's test suite uses both).
fn canonical_space(space: &str) -> &str {
    match space {
        "gamma18" => "g18_rec709",
        "gamma22" => "g22_rec709",
        "gamma24" | "Gamma 2.4 Encoded Rec.709" => "rec709_display",
        "Gamma 2.2 Encoded AdobeRGB" => "adobergb",
        "Linear Rec.2020" => "lin_rec2020",
        "CIE XYZ-D65 - Scene-referred" => "lin_ciexyzd65",
        "lin_srgb" | "Utility - Linear - sRGB" | "Linear Rec.709 (sRGB)" | "lin_rec709_scene" => "lin_rec709",
        "Utility - sRGB - Texture" | "sRGB - Texture" => "srgb_texture",
        "ACEScg" | "lin_ap1_scene" => "acescg",
        "ACES2065-1" | "lin_ap0" => "lin_ap0",
        "sRGB Encoded P3-D65" | "srgb_p3d65" => "srgb_displayp3",
        "Linear P3-D65" | "lin_p3d65" => "lin_displayp3",
        other => other,
    }
}

/// How a texture of MaterialX colour space `space` decodes (the runtime's `sRGB` or `raw`)
/// and the space the node converts its texels from (`""`: none). `None` for a space strata
/// does not know for textures.
pub fn texture_decode(space: &str) -> Option<(&'static str, &'static str)> {
    Some(match canonical_space(space) {
        "srgb_texture" => ("sRGB", "srgb_texture"),
        "" | "lin_rec709" | "raw" => ("raw", ""),
        "acescg" => ("raw", "acescg"),
        "lin_ap1" => ("raw", "lin_ap1"),
        "g22_ap1" => ("raw", "g22_ap1"),
        "g22_rec709" => ("raw", "g22_rec709"),
        _ => return None,
    })
}

/// A colour value authored in `space`, in the working space (linear Rec.709), as MaterialX's
/// colour management defines it. `None` for a space strata does not know.
pub fn to_working_space(space: &str, c: [f32; 3]) -> Option<[f32; 3]> {
    let srgb = |x: f32| if x <= 0.04045 { x / 12.92 } else { ((x + 0.055) / 1.055).powf(2.4) };
    let gamma = |g: f32| move |x: f32| x.max(0.0).powf(g);
    // Linear primaries to linear Rec.709 (D65); AP0 and AP1 (D60) Bradford-adapted. From
    // each space's primaries and white point.
    let matrix = |m: [[f32; 3]; 3], [r, g, b]: [f32; 3]| m.map(|row| row[0] * r + row[1] * g + row[2] * b);
    const AP1: [[f32; 3]; 3] =
        [[1.70505, -0.62179, -0.08326], [-0.13026, 1.14080, -0.01055], [-0.02400, -0.12897, 1.15297]];
    const AP0: [[f32; 3]; 3] =
        [[2.52169, -1.13413, -0.38756], [-0.27648, 1.37272, -0.09624], [-0.01538, -0.15298, 1.16835]];
    const P3: [[f32; 3]; 3] = [[1.22494, -0.22494, 0.0], [-0.04206, 1.04206, 0.0], [-0.01964, -0.07864, 1.09827]];
    const ADOBE: [[f32; 3]; 3] = [[1.39836, -0.39836, 0.0], [0.0, 1.0, 0.0], [0.0, -0.04293, 1.04293]];
    const REC2020: [[f32; 3]; 3] =
        [[1.660491, -0.587641, -0.07285], [-0.12455, 1.1329, -0.008349], [-0.018151, -0.100579, 1.11873]];
    // CIE XYZ to linear Rec.709 (the D65 white of both: no adaptation).
    const XYZ: [[f32; 3]; 3] =
        [[3.24097, -1.537383, -0.498611], [-0.969244, 1.875968, 0.041555], [0.05563, -0.203977, 1.056972]];
    Some(match canonical_space(space) {
        "" | "lin_rec709" | "raw" => c,
        "srgb_texture" => c.map(srgb),
        "g18_rec709" => c.map(gamma(1.8)),
        "g22_rec709" => c.map(gamma(2.2)),
        // BT.1886 with a black level of 0: a pure 2.4 power.
        "rec709_display" => c.map(gamma(2.4)),
        "acescg" | "lin_ap1" => matrix(AP1, c),
        "g18_ap1" => matrix(AP1, c.map(gamma(1.8))),
        "g22_ap1" => matrix(AP1, c.map(gamma(2.2))),
        "lin_ap0" => matrix(AP0, c),
        "lin_displayp3" => matrix(P3, c),
        "srgb_displayp3" => matrix(P3, c.map(srgb)),
        "lin_adobergb" => matrix(ADOBE, c),
        "lin_rec2020" => matrix(REC2020, c),
        "lin_ciexyzd65" => matrix(XYZ, c),
        "adobergb" => matrix(ADOBE, c.map(gamma(2.199_218_8))),
        _ => return None,
    })
}

/// Surface inputs that the layered surfaces do not read (or read approximately), with what
/// strata does instead; reported when a scene drives them or sets them away from their default.
const UNREAD_SURFACE_INPUTS: &[(&str, &str, &str)] = &[
    ("open_pbr_surface", "transmission_depth", "transmission has no volume (a thin tinted interface)"),
    ("open_pbr_surface", "transmission_scatter", "transmission has no volume scattering"),
    ("open_pbr_surface", "transmission_dispersion_scale", "no dispersion"),
    (
        "open_pbr_surface",
        "subsurface_weight",
        "approximated by diffuse reflection of subsurface_color (no light travels under the surface; \
         thin-walled, it is the specification's diffuse reflection and transmission)",
    ),
    ("open_pbr_surface", "subsurface_radius", "no subsurface scattering: the radius is not read"),
    ("standard_surface", "transmission_depth", "transmission has no volume (a thin tinted interface)"),
    ("standard_surface", "transmission_scatter", "transmission has no volume scattering"),
    ("standard_surface", "transmission_dispersion", "no dispersion"),
    ("standard_surface", "transmission_extra_roughness", "transmission uses the specular roughness"),
    (
        "standard_surface",
        "subsurface",
        "approximated by diffuse reflection of subsurface_color (no light travels under the surface; \
         thin-walled, it is the specification's diffuse reflection and transmission)",
    ),
    ("standard_surface", "subsurface_radius", "no subsurface scattering: the radius is not read"),
    ("standard_surface", "coat_affect_color", "the coat does not saturate the base"),
    ("mx_surface_unlit", "transmission", "an unlit surface hides what lies behind it (its opacity is read)"),
];

/// How a surface input is set in a network: a constant, or driven by a node.
pub enum Setting<'v> {
    /// An authored (or interface) value.
    Value(&'v Value),
    /// Connected to a node's output.
    Driven,
}

/// Reports what the layered `substance` does not honour of input `input` set to
/// `setting` against its `default`: each (substance, input) kind once per run.
pub fn report_surface_input(
    substance: &str,
    input: &str,
    setting: Setting,
    default: Option<&Value>,
    at: Span,
    diags: &mut Diagnostics,
) {
    let away = match setting {
        Setting::Driven => true,
        Setting::Value(v) => default.is_none_or(|d| d != v),
    };
    if !away {
        return;
    }
    if let Some((_, _, what)) = UNREAD_SURFACE_INPUTS.iter().find(|(s, i, _)| *s == substance && *i == input) {
        diags.push(
            Diagnostic::warning(format!("{substance} `{input}` is not supported: {what}"))
                .at(at, "set here")
                .kind(unread_kind(substance, input)),
        );
    }
}

/// Inputs of pbrlib's BSDF nodes that strata's lobes do not model, with what they do instead
/// (`"*"`: every BSDF node). Each kind is reported once per run.
const UNREAD_NODE_INPUTS: &[(&str, &str, &str)] = &[
    ("ND_generalized_schlick_bsdf", "normal", "generalized_schlick_bsdf uses the shading normal"),
    ("*", "retroreflective", "lobes are not retroreflective"),
    ("ND_generalized_schlick_bsdf", "scatter_mode", "generalized_schlick_bsdf reflects only"),
    ("ND_sheen_bsdf", "mode", "sheen is Conty and Kulla's Charlie sheen"),
];

/// Reports what a pbrlib BSDF node `id` does not honour of input `input` set to `setting`:
/// each (input, what) kind once per run. (A vector2 `roughness` is GGX's α along the lobe's
/// `tangent` and bitangent, read as such.)
pub fn report_node_input(id: &str, input: &str, setting: Setting, at: Span, diags: &mut Diagnostics) {
    if !PBRLIB.iter().any(|(nd, _)| *nd == id && nd.ends_with("_bsdf")) {
        return;
    }
    let Some((_, _, what)) =
        UNREAD_NODE_INPUTS.iter().find(|(node, name, _)| (*node == "*" || *node == id) && *name == input)
    else {
        return;
    };
    let away = match (input, setting) {
        (_, Setting::Driven) => true,
        ("scatter_mode", Setting::Value(Value::Str(m))) => m != "R",
        ("mode", Setting::Value(Value::Str(m))) => m != "conty_kulla",
        (_, Setting::Value(Value::Triple(v))) => v.iter().any(|c| *c != 0.0),
        (_, Setting::Value(Value::Float(x))) => *x != 0.0,
        (_, Setting::Value(Value::Int(i))) => *i != 0,
        _ => false,
    };
    if away {
        diags.push(
            Diagnostic::warning(format!("MaterialX `{id}` input `{input}` is not supported: {what}"))
                .at(at, "set here")
                .kind(what),
        );
    }
}

/// pbrlib nodes strata approximates as a whole, with what it does instead.
const APPROXIMATED_NODES: &[(&str, &str)] = &[
    (
        "ND_subsurface_bsdf",
        "subsurface_bsdf is approximated by diffuse transmission of its colour: no light travels under the surface \
         (`radius` and `anisotropy` are not read)",
    ),
    ("ND_thin_film_bsdf", "thin_film_bsdf is ignored: the layer below it has no thin-film iridescence"),
];

/// Reports a pbrlib node that strata approximates as a whole (once per kind).
pub fn report_node(id: &str, at: Span, diags: &mut Diagnostics) {
    if let Some((_, what)) = APPROXIMATED_NODES.iter().find(|(nd, _)| *nd == id) {
        diags.push(Diagnostic::warning(*what).at(at, "this node").kind(what));
    }
}

/// A `'static` kind per unread input, so each is reported once per run.
fn unread_kind(substance: &str, input: &str) -> &'static str {
    UNREAD_SURFACE_INPUTS
        .iter()
        .find(|(s, i, _)| *s == substance && *i == input)
        .map_or("unsupported MaterialX surface input", |(_, i, _)| i)
}

/// Whether the substance's `product`-driving input is set, so the product stays (a normal
/// or emission nobody sets costs the integrator work per hit).
pub fn keeps_product(substance: &str, product: crate::front::ast::Product, set: &[String]) -> bool {
    use crate::front::ast::Product;
    let is_set = |name: &str| set.iter().any(|s| s == name);
    match (substance, product) {
        ("open_pbr_surface", Product::Normal) => is_set("geometry_normal"),
        ("open_pbr_surface", Product::Emission) => is_set("emission_luminance"),
        ("standard_surface", Product::Normal) => is_set("normal_"),
        ("standard_surface", Product::Emission) => is_set("emission"),
        ("mx_surface", Product::Emission) => is_set("edf"),
        _ => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_name_library_functions_by_type_suffix() {
        assert_eq!(split_id("ND_multiply_color3FA"), Some(("multiply", "color3FA")));
        assert_eq!(split_id("ND_open_pbr_surface_surfaceshader"), Some(("open_pbr_surface", "surfaceshader")));
        assert_eq!(split_id("ND_normalmap"), Some(("normalmap", "")));
        assert_eq!(node_function("ND_image_vector3").as_deref(), Some("mx_image_color3"));
        assert_eq!(node_function("ND_add_float").as_deref(), Some("mx_add_float"));
        assert_eq!(node_function("ND_multiply_vector2FA").as_deref(), Some("mx_multiply_color3"));
        assert_eq!(node_function("ND_convert_float_color3").as_deref(), Some("mx_convert_float_color3"));
        assert_eq!(node_function("ND_convert_vector3_vector2").as_deref(), Some("mx_convert_color3_vector2"));
        assert_eq!(node_function("ND_normalmap").as_deref(), Some("mx_normalmap_color3"));
        // color4 and vector4: one `_color4` variant (a colour and a float `_a`).
        for (id, function) in [
            ("ND_add_color4", "mx_add_color4"),
            ("ND_multiply_vector4FA", "mx_multiply_color4"),
            ("ND_mix_color4_color4", "mx_mix_color4"),
            ("ND_convert_color4_vector3", "mx_convert_color4_color3"),
            ("ND_convert_vector2_vector4", "mx_convert_color3_color4"),
            ("ND_convert_vector4_color4", "mx_convert_color4_color4"),
            ("ND_convert_color4_vector2", "mx_convert_color4_vector2"),
            ("ND_convert_float_vector4", "mx_convert_float_color4"),
            ("ND_combine2_vector4VF", "mx_combine2_color4"),
            ("ND_combine2_vector4VV", "mx_combine2_vector4VV"),
            ("ND_combine4_color4", "mx_combine4_color4"),
        ] {
            assert_eq!(node_function(id).as_deref(), Some(function), "{id}");
        }
        // Integer- and boolean-selected conditionals: one integer-selected variant.
        for (id, function) in [
            ("ND_ifgreater_color4I", Some("mx_ifgreater_color4I")),
            ("ND_ifgreatereq_vector2I", Some("mx_ifgreatereq_color3I")),
            ("ND_ifequal_floatB", Some("mx_ifequal_floatI")),
            ("ND_ifequal_vector4B", Some("mx_ifequal_color4I")),
            ("ND_switch_vector3I", Some("mx_switch_color3I")),
            // No boolean-selected ifgreater; no boolean or integer outputs.
            ("ND_ifgreater_floatB", None),
            ("ND_ifgreater_booleanI", None),
            ("ND_ifequal_integerB", None),
        ] {
            assert_eq!(node_function(id).as_deref(), function, "{id}");
        }
        assert_eq!(node_function("ND_mincomponent_vector2").as_deref(), Some("mx_mincomponent_vector2"));
        assert_eq!(node_function("ND_maxcomponent_vector3").as_deref(), Some("mx_maxcomponent_color3"));
        assert_eq!(node_function("ND_blackbody").as_deref(), Some("mx_blackbody_color3"));
        // pbrlib: closures by definition id, EDFs as colours.
        assert_eq!(node_function("ND_layer_bsdf").as_deref(), Some("mx_layer_bsdf"));
        assert_eq!(node_function("ND_multiply_bsdfF").as_deref(), Some("mx_multiply_bsdfF"));
        assert_eq!(node_function("ND_add_edf").as_deref(), Some("mx_add_color3"));
        assert_eq!(node_function("UsdUVTexture"), None);
    }

    #[test]
    fn colour_spaces_match_their_definitions() {
        // sRGB's transfer function at 0.5 and at the linear segment.
        let c = to_working_space("srgb_texture", [0.5, 0.04, 1.0]).unwrap();
        assert!((c[0] - 0.214_041).abs() < 1e-5 && (c[1] - 0.04 / 12.92).abs() < 1e-7 && (c[2] - 1.0).abs() < 1e-6);
        // AP1 white is Rec.709 white (each matrix row sums to 1 within rounding).
        let w = to_working_space("acescg", [1.0, 1.0, 1.0]).unwrap();
        assert!(w.iter().all(|x| (x - 1.0).abs() < 1e-3), "{w:?}");
        assert_eq!(to_working_space("g22_rec709", [0.5, 0.0, 1.0]).unwrap()[0], 0.5f32.powf(2.2));
        assert_eq!(to_working_space("no_such_space", [0.0; 3]), None);
        // Every space with other primaries maps its white to Rec.709 white (same or adapted
        // white point); the legacy and OCIO names are the same spaces.
        for space in ["lin_ap0", "lin_displayp3", "srgb_displayp3", "lin_adobergb", "adobergb", "g18_ap1", "ACES2065-1"]
        {
            let w = to_working_space(space, [1.0, 1.0, 1.0]).unwrap();
            assert!(w.iter().all(|x| (x - 1.0).abs() < 1e-3), "{space}: {w:?}");
        }
        // Display P3's red is outside Rec.709 (published matrix row: 1.2249, -0.2249, 0).
        let red = to_working_space("lin_displayp3", [1.0, 0.0, 0.0]).unwrap();
        assert!((red[0] - 1.2249).abs() < 1e-3 && (red[1] + 0.0421).abs() < 1e-3, "{red:?}");
        assert_eq!(to_working_space("gamma22", [0.5; 3]), to_working_space("g22_rec709", [0.5; 3]));
        assert_eq!(to_working_space("rec709_display", [0.5; 3]).unwrap()[0], 0.5f32.powf(2.4));
        assert_eq!(texture_decode("Utility - sRGB - Texture"), texture_decode("srgb_texture"));
        // The ACES 2 OCIO config's alias of linear Rec.709 (MaterialX's color_management.mtlx).
        assert_eq!(to_working_space("lin_rec709_scene", [0.5, 0.25, 2.0]), Some([0.5, 0.25, 2.0]));
        // The ACES studio config's names in ocio_color_management.mtlx: D65's XYZ is Rec.709
        // white; Rec.2020's red by ITU-R BT.2087's published matrix (1.6605, -0.1246, -0.0182).
        let white = to_working_space("CIE XYZ-D65 - Scene-referred", [0.95047, 1.0, 1.08883]).unwrap();
        assert!(white.iter().all(|x| (x - 1.0).abs() < 1e-3), "{white:?}");
        let red = to_working_space("Linear Rec.2020", [1.0, 0.0, 0.0]).unwrap();
        assert!((red[0] - 1.6605).abs() < 1e-3 && (red[1] + 0.1246).abs() < 1e-3 && (red[2] + 0.0182).abs() < 1e-3);
        assert_eq!(
            to_working_space("Gamma 2.4 Encoded Rec.709", [0.5; 3]),
            to_working_space("rec709_display", [0.5; 3])
        );
        assert_eq!(to_working_space("Gamma 2.2 Encoded AdobeRGB", [0.5; 3]), to_working_space("adobergb", [0.5; 3]));
    }
}
