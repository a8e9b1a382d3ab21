//! What the renderer does not render, reported.
//!
//! A DCC's USD carries far more than strata draws: curves, skeletons, volumes, light filters,
//! shaping, mesh lights. Dropping any of them in silence gives an image that looks right and
//! is not, so every visible prim, applied API schema or authored attribute that changes what
//! a production renderer would draw, and that strata ignores, gets a warning naming the prim
//! and the schema. `strata check` and `strata render` both run this audit (through
//! [`super::Scene::from_stage_with`]), so `check` lists exactly what the image will lack.
//!
//! Warnings are grouped per kind: the first prim is pointed at, the rest are counted, so a
//! scene of 100 000 curves prints one warning, not 100 000.

use crate::compose::binding::RENDERABLE_TYPES;
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::render::geometry::xform::{PrimXform, value_span};
use crate::render::light::LIGHT_TYPES;
use crate::scene::{Prim, Stage, Value};
use std::collections::BTreeMap;

/// Prim types that draw nothing themselves (grouping, shading networks, render settings) or
/// draw through other prims (a PointInstancer, through its prototypes), so passing over them
/// here loses nothing.
const NON_DRAWING_TYPES: &[&str] = &[
    "Xform",
    "PointInstancer",
    "Scope",
    "Camera",
    "Material",
    "Shader",
    "NodeGraph",
    "RenderSettings",
    "RenderProduct",
    "RenderVar",
    "RenderPass",
    "GeomSubset",
    "SpatialAudio",
    "CollectionAPI",
    "PhysicsScene",
    // UsdSkel: they pose the meshes bound to them (`skel`) and draw nothing themselves.
    "SkelRoot",
    "Skeleton",
    "SkelAnimation",
    "BlendShape",
];

/// Prim types a production renderer draws that strata does not, with what is lost.
const UNSUPPORTED_TYPES: &[(&str, &str)] = &[
    ("BasisCurves", "curves are not rendered"),
    ("NurbsCurves", "curves are not rendered"),
    ("HermiteCurves", "curves are not rendered"),
    ("NurbsPatch", "NURBS patches are not rendered"),
    ("TetMesh", "tetrahedral meshes are not rendered"),
    ("Volume", "volumes are not rendered"),
    ("OpenVDBAsset", "volume fields are not read"),
    ("Field3DAsset", "volume fields are not read"),
    ("PortalLight", "portal lights are ignored (the dome is sampled without the portal)"),
    ("GeometryLight", "geometry lights do not emit"),
    ("PluginLight", "plugin lights do not emit"),
    ("LightFilter", "light filters are not applied"),
    ("PluginLightFilter", "light filters are not applied"),
    ("GenerativeProcedural", "procedurals are not expanded"),
];

/// Applied API schemas that change the image and that strata ignores.
const UNSUPPORTED_APIS: &[(&str, &str)] = &[
    ("MeshLightAPI", "the mesh renders but does not emit light"),
    ("LightAPI", "the prim renders but does not emit light"),
    ("VolumeLightAPI", "the volume does not emit light"),
];

/// UsdLux ShapingAPI and ShadowAPI inputs at their schema defaults, which change nothing: an
/// exporter that applies the schemas to every light (most do) authors these, and a warning
/// for them would be noise. Only a value away from its default is reported.
fn is_default_shaping_or_shadow(name: &str, value: &Value) -> bool {
    let number = |default: f64| value.as_f64().is_some_and(|v| v == default);
    let black = || value.as_vec3().is_some_and(|c| c == [0.0; 3]);
    match name {
        "inputs:shaping:focus" | "inputs:shaping:cone:softness" | "inputs:shaping:ies:angleScale" => number(0.0),
        "inputs:shaping:cone:angle" => value.as_f64().is_some_and(|v| v >= 90.0),
        "inputs:shaping:focusTint" | "inputs:shadow:color" => black(),
        "inputs:shaping:ies:file" => value.as_asset().is_some_and(|a| a.authored.is_empty()),
        "inputs:shaping:ies:normalize" => value.as_bool() == Some(false),
        "inputs:shadow:enable" => value.as_bool() == Some(true),
        "inputs:shadow:distance" | "inputs:shadow:falloff" => value.as_f64().is_some_and(|v| v <= 0.0),
        "inputs:shadow:falloffGamma" => number(1.0),
        _ => false,
    }
}

/// Light inputs whose non-default values strata ignores, with their defaults.
const IGNORED_LIGHT_INPUTS: &[(&str, f64, &str)] = &[
    ("inputs:diffuse", 1.0, "per-light diffuse multipliers are not applied"),
    ("inputs:specular", 1.0, "per-light specular multipliers are not applied"),
];

/// One kind of unsupported content: where it first occurs and how often.
struct Finding {
    first_prim: String,
    span: Span,
    count: usize,
}

/// Warns about every visible prim, API schema and attribute of `stage` that the renderer
/// ignores. `xforms` gives visibility (hidden prims draw nothing anyway).
pub fn report_unsupported(stage: &Stage, xforms: &[PrimXform], diags: &mut Diagnostics) {
    let mut findings: BTreeMap<String, Finding> = BTreeMap::new();
    let mut note = |what: String, prim: &Prim, span: Span| {
        findings.entry(what).and_modify(|f| f.count += 1).or_insert_with(|| Finding {
            first_prim: prim.path.clone(),
            span,
            count: 1,
        });
    };
    for (id, prim) in stage.depth_first() {
        if xforms[id.0 as usize].hidden {
            continue;
        }
        if let Some(ty) = prim.type_name.as_deref() {
            if let Some((_, lost)) = UNSUPPORTED_TYPES.iter().find(|(t, _)| *t == ty) {
                note(format!("`{ty}` prims are not supported: {lost}"), prim, prim.span);
            } else if !RENDERABLE_TYPES.contains(&ty) && !LIGHT_TYPES.contains(&ty) && !NON_DRAWING_TYPES.contains(&ty)
            {
                note(format!("prim type `{ty}` is not a schema strata knows: the prim is ignored"), prim, prim.span);
            }
        }
        for api in &prim.api_schemas {
            // Multiple-apply schemas carry an instance name: `ShapingAPI` has none, but
            // `CollectionAPI:name` does.
            let base = api.split(':').next().unwrap_or(api);
            if let Some((_, lost)) = UNSUPPORTED_APIS.iter().find(|(a, _)| *a == base) {
                // LightAPI on a light prim is the light itself.
                let is_light = prim.type_name.as_deref().is_some_and(|t| LIGHT_TYPES.contains(&t));
                if !(base == "LightAPI" && is_light) {
                    note(format!("API schema `{base}` is not supported: {lost}"), prim, prim.span);
                }
            }
        }
        let is_light = prim.type_name.as_deref().is_some_and(|t| LIGHT_TYPES.contains(&t));
        if is_light {
            light_attributes(prim, &mut note);
        }
        // UsdSkel poses point-based prims (`skel`); other gprims would move rigidly.
        if let Some(ty) =
            prim.type_name.as_deref().filter(|t| RENDERABLE_TYPES.contains(t) && !matches!(*t, "Mesh" | "Points"))
            && let Some(attr) = prim.attribute("primvars:skel:jointIndices")
        {
            note(
                format!("skinning `{ty}` prims is not supported: only meshes and points follow their skeleton"),
                prim,
                value_span(attr),
            );
        }
        if prim.type_name.as_deref() == Some("Mesh") {
            face_varying_interpolation(prim, &mut note);
        }
    }
    for (what, f) in findings {
        let mut d = Diagnostic::warning(format!("{what} (`{}`)", f.first_prim)).at(f.span, "first here");
        if f.count > 1 {
            d = d.note(format!("{} more prim(s) or attribute(s) like it", f.count - 1));
        }
        diags.push(d);
    }
}

/// Subdivision surfaces refine face-varying `st` linearly (`faceVaryingLinearInterpolation =
/// "all"`); the other rules, USD's default `cornersPlus1` among them, smooth it where faces
/// share values. Unindexed values belong each to one face, so OpenSubdiv's face-varying
/// patches are single faces, pinned at their corners by every rule but `none`: on quads that is
/// bilinear, what strata does, so only shared (indexed) values or `none` are reported.
fn face_varying_interpolation(prim: &Prim, note: &mut impl FnMut(String, &Prim, Span)) {
    let scheme = prim.value("subdivisionScheme").and_then(Value::as_str).unwrap_or("catmullClark");
    let Some(st) = prim.attribute("primvars:st").filter(|a| a.get().is_some()) else { return };
    let face_varying = st.meta("interpolation").and_then(Value::as_str).unwrap_or("faceVarying") == "faceVarying";
    if !matches!(scheme, "catmullClark" | "loop") || !face_varying {
        return;
    }
    let attr = prim.attribute("faceVaryingLinearInterpolation").filter(|a| a.get().is_some());
    let mode = attr.and_then(|a| a.get()).and_then(Value::as_str).unwrap_or("cornersPlus1");
    let indexed = prim.value("primvars:st:indices").is_some_and(|v| !is_empty_array(v));
    if mode != "all" && (indexed || mode == "none") {
        note(
            format!(
                "mesh `faceVaryingLinearInterpolation` `{mode}`: face-varying `primvars:st` on subdivision surfaces is \
                 interpolated linearly (as `all`), not smoothed"
            ),
            prim,
            value_span(attr.unwrap_or(st)),
        );
    }
}

fn light_attributes(prim: &Prim, note: &mut impl FnMut(String, &Prim, Span)) {
    for (name, default, lost) in IGNORED_LIGHT_INPUTS {
        if let Some(attr) = prim.attribute(name)
            && attr.get().and_then(Value::as_f64).is_some_and(|v| v != *default)
        {
            note(format!("light `{name}`: {lost}"), prim, value_span(attr));
        }
    }
    for attr in &prim.attributes {
        if attr.get().is_none_or(|v| is_default_shaping_or_shadow(&attr.name, v)) {
            continue;
        }
        if attr.name.starts_with("inputs:shaping:") {
            let message = "light shaping (`inputs:shaping:*` away from its defaults) is not applied";
            note(message.to_string(), prim, value_span(attr));
        } else if attr.name.starts_with("inputs:shadow:") {
            let message = "light shadow controls (`inputs:shadow:*` away from their defaults) are not applied";
            note(message.to_string(), prim, value_span(attr));
        }
    }
    let ty = prim.type_name.as_deref().unwrap_or("");
    if ty != "DomeLight"
        && let Some(attr) = prim
            .attribute("inputs:texture:file")
            .filter(|a| a.get().and_then(Value::as_asset).is_some_and(|asset| !asset.authored.is_empty()))
    {
        note(
            format!("`{ty}` `inputs:texture:file` is not applied: the light emits its colour"),
            prim,
            value_span(attr),
        );
    }
    if ty == "DomeLight"
        && let Some(attr) = prim.attribute("inputs:texture:format")
        && let Some(format) = attr.get().and_then(Value::as_str)
        && !matches!(format, "automatic" | "latlong")
    {
        note(
            format!("dome texture format `{format}` is not supported: the map is read as latlong"),
            prim,
            value_span(attr),
        );
    }
}

fn is_empty_array(v: &Value) -> bool {
    v.as_int_array().is_some_and(<[i64]>::is_empty) || v.as_float_array().is_some_and(<[f64]>::is_empty)
}
