//! UsdGeom transforms: xformOps in `xformOpOrder`, `!invert!` ops, `!resetXformStack!`,
//! composed down the hierarchy, plus the imageability rules (visibility, purpose) that decide
//! which prims render.
//!
//! Matrices are glam column-vector `DMat4`s (`p' = M p`). USD writes row-vector matrices
//! (`p' = p M`, translation in the last row), so an authored matrix is read transposed; and
//! USD's op order `[A, B, C]` means `M = A · B · C` (the last op applies to points first).

use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::scene::{Attribute, Prim, Stage, Value};
use glam::{DMat4, DQuat, DVec3};

/// World transform and imageability of one prim.
#[derive(Clone, Copy, Debug)]
pub struct PrimXform {
    /// Local → world.
    pub world: DMat4,
    /// Invisible (`visibility = "invisible"` here or above) or under a guide/proxy purpose.
    pub hidden: bool,
}

/// The span of an attribute's value, or of its statement.
pub(crate) fn value_span(attr: &Attribute) -> Span {
    attr.value.as_ref().map_or(attr.span, |(_, s)| *s)
}

/// World transforms of every prim of `stage`, indexed by `PrimId`.
pub fn world_transforms(stage: &Stage, diags: &mut Diagnostics) -> Vec<PrimXform> {
    let mut out = vec![PrimXform { world: DMat4::IDENTITY, hidden: false }; stage.len()];
    for (id, prim) in stage.depth_first() {
        let parent =
            prim.parent.map(|p| out[p.0 as usize]).unwrap_or(PrimXform { world: DMat4::IDENTITY, hidden: false });
        let (local, reset) = local_transform(prim, diags);
        let world = if reset { local } else { parent.world * local };
        let invisible = prim.value("visibility").and_then(Value::as_str) == Some("invisible");
        let purpose = prim.value("purpose").and_then(Value::as_str);
        let hidden = parent.hidden || invisible || matches!(purpose, Some("guide" | "proxy"));
        out[id.0 as usize] = PrimXform { world, hidden };
    }
    out
}

/// A prim's local transform from its `xformOpOrder`, and whether it resets the parent stack.
pub fn local_transform(prim: &Prim, diags: &mut Diagnostics) -> (DMat4, bool) {
    local_transform_with(prim, &|attr| attr.get().cloned(), diags)
}

/// [`local_transform`] with every op's value read at `time` (USD's `Get(time)`: samples
/// interpolated linearly, quaternions by slerp), as `ComputeLocalToWorldTransform(time)` does.
pub fn local_transform_at(prim: &Prim, time: f64, diags: &mut Diagnostics) -> (DMat4, bool) {
    local_transform_with(prim, &|attr| attr.value_at(crate::scene::TimeCode::At(time)), diags)
}

/// The local-to-world transform of prim `id` at `time` (see [`local_transform_at`]).
pub fn world_transform_at(stage: &Stage, id: crate::scene::PrimId, time: f64, diags: &mut Diagnostics) -> DMat4 {
    let prim = stage.prim(id);
    let (local, reset) = local_transform_at(prim, time, diags);
    match prim.parent {
        Some(parent) if !reset => world_transform_at(stage, parent, time, diags) * local,
        _ => local,
    }
}

/// The times at which an attribute that places prim `id` (an xformOp of it or of an
/// ancestor up to a `!resetXformStack!`) has samples, unsorted; empty when it does not move.
pub fn transform_sample_times(stage: &Stage, id: crate::scene::PrimId) -> Vec<f64> {
    let mut times = Vec::new();
    let mut at = Some(id);
    while let Some(id) = at {
        let prim = stage.prim(id);
        let order = prim.attribute("xformOpOrder").and_then(|a| a.get()).and_then(Value::as_string_array);
        let order = order.map(|o| o.to_vec()).unwrap_or_default();
        for entry in &order {
            let name = entry.strip_prefix("!invert!").unwrap_or(entry);
            if let Some(attr) = prim.attribute(name) {
                times.extend(attr.time_samples.iter().map(|(t, _)| *t));
            }
        }
        at = if order.iter().any(|e| e == "!resetXformStack!") { None } else { prim.parent };
    }
    times
}

/// [`local_transform`] with each op's value given by `value_of`.
fn local_transform_with(
    prim: &Prim,
    value_of: &dyn Fn(&Attribute) -> Option<Value>,
    diags: &mut Diagnostics,
) -> (DMat4, bool) {
    let Some(order_attr) = prim.attribute("xformOpOrder") else { return (DMat4::IDENTITY, false) };
    let Some(order) = order_attr.get().and_then(Value::as_string_array) else { return (DMat4::IDENTITY, false) };
    let mut m = DMat4::IDENTITY;
    let mut reset = false;
    for entry in order {
        if entry == "!resetXformStack!" {
            // Ignore the parent's transform (and, by USD's rule, any op listed before it).
            reset = true;
            m = DMat4::IDENTITY;
            continue;
        }
        let (invert, name) = match entry.strip_prefix("!invert!") {
            Some(rest) => (true, rest),
            None => (false, entry.as_str()),
        };
        let Some(attr) = prim.attribute(name) else {
            diags.push(
                Diagnostic::error(format!("xformOpOrder names `{name}`, which `{}` does not have", prim.path))
                    .at(value_span(order_attr), "listed here"),
            );
            continue;
        };
        let Some(value) = value_of(attr) else { continue };
        match op_matrix(name, &value) {
            Ok(op) => {
                let op = if invert {
                    if op.determinant().abs() < 1e-300 {
                        diags.push(
                            Diagnostic::error(format!("`!invert!{name}` inverts a singular transform"))
                                .at(value_span(attr), "singular"),
                        );
                        continue;
                    }
                    op.inverse()
                } else {
                    op
                };
                m *= op;
            }
            Err(message) => diags.push(Diagnostic::error(message).at(value_span(attr), "this op")),
        }
    }
    if !m.is_finite() {
        diags.push(
            Diagnostic::error(format!("the transform of `{}` is not finite", prim.path))
                .at(value_span(order_attr), "here"),
        );
        m = DMat4::IDENTITY;
    }
    (m, reset)
}

/// The matrix of one xformOp named `xformOp:<type>[:suffix]`.
fn op_matrix(name: &str, value: &Value) -> Result<DMat4, String> {
    let mut parts = name.split(':');
    let op = match (parts.next(), parts.next()) {
        (Some("xformOp"), Some(op)) => op,
        _ => return Err(format!("`{name}` is not an xformOp")),
    };
    let vec3 = || value.as_vec3().map(DVec3::from).ok_or_else(|| format!("`{name}` needs 3 components"));
    let scalar = || value.as_f64().ok_or_else(|| format!("`{name}` needs a number"));
    Ok(match op {
        "translate" => DMat4::from_translation(vec3()?),
        "scale" => DMat4::from_scale(vec3()?),
        "rotateX" => DMat4::from_rotation_x(scalar()?.to_radians()),
        "rotateY" => DMat4::from_rotation_y(scalar()?.to_radians()),
        "rotateZ" => DMat4::from_rotation_z(scalar()?.to_radians()),
        // rotateABC: rotate about A first, then B, then C, angles given as (x, y, z):
        // M = R_C · R_B · R_A.
        "rotateXYZ" | "rotateXZY" | "rotateYXZ" | "rotateYZX" | "rotateZXY" | "rotateZYX" => {
            let v = vec3()?;
            let angle = |axis: u8| match axis {
                b'X' => v.x,
                b'Y' => v.y,
                _ => v.z,
            };
            let axes = op.as_bytes();
            let (a, b, c) = (axes[6], axes[7], axes[8]);
            let single = |axis: u8| match axis {
                b'X' => DMat4::from_rotation_x(angle(axis).to_radians()),
                b'Y' => DMat4::from_rotation_y(angle(axis).to_radians()),
                _ => DMat4::from_rotation_z(angle(axis).to_radians()),
            };
            single(c) * single(b) * single(a)
        }
        "orient" => {
            let q = value.as_vec4().ok_or_else(|| format!("`{name}` needs a quaternion"))?;
            // USD quaternions are written (real, i, j, k).
            let q = DQuat::from_xyzw(q[1], q[2], q[3], q[0]);
            if q.length_squared() == 0.0 {
                return Err(format!("`{name}` is a zero quaternion"));
            }
            DMat4::from_quat(q.normalize())
        }
        "transform" => {
            let m = value.as_matrix4().ok_or_else(|| format!("`{name}` needs a matrix4d"))?;
            // Row-major row-vector → column-major column-vector: the same array read by columns.
            DMat4::from_cols_array(m)
        }
        other => return Err(format!("unsupported xformOp type `{other}` in `{name}`")),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::diag::SourceMap;
    use std::path::Path;

    pub(crate) fn stage(text: &str) -> (Stage, Diagnostics) {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("test.usda", text, Path::new("."), &mut sources, &mut diags).expect("stage");
        (stage, diags)
    }

    fn world_of(text: &str, path: &str) -> DMat4 {
        let (stage, mut diags) = stage(text);
        let xf = world_transforms(&stage, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        xf[stage.find(path).unwrap().0 as usize].world
    }

    #[test]
    fn trs_order_and_hierarchy() {
        let m = world_of(
            r#"#usda 1.0
def Xform "A" {
    double3 xformOp:translate = (10, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Xform "B" {
        double3 xformOp:translate = (1, 2, 3)
        float xformOp:rotateZ = 90
        float3 xformOp:scale = (2, 2, 2)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateZ", "xformOp:scale"]
    }
}"#,
            "/A/B",
        );
        // (1,0,0) → scale (2,0,0) → rotateZ 90 (0,2,0) → translate (1,4,3) → parent (11,4,3).
        let p = m.transform_point3(DVec3::X);
        assert!((p - DVec3::new(11.0, 4.0, 3.0)).length() < 1e-9, "{p}");
    }

    #[test]
    fn rotate_xyz_applies_x_first() {
        let m = world_of(
            r#"#usda 1.0
def Xform "A" {
    float3 xformOp:rotateXYZ = (90, 90, 0)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
}"#,
            "/A",
        );
        // Y → rotX 90 → Z → rotY 90 → X.
        let p = m.transform_vector3(DVec3::Y);
        assert!((p - DVec3::X).length() < 1e-9, "{p}");
    }

    #[test]
    fn matrix_invert_orient_and_reset() {
        let m = world_of(
            r#"#usda 1.0
def Xform "A" {
    double3 xformOp:translate = (5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Xform "B" {
        matrix4d xformOp:transform = ( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1, 5, 1) )
        quatf xformOp:orient = (0.70710678, 0, 0.70710678, 0)
        double3 xformOp:translate:pivot = (0, 0, 1)
        uniform token[] xformOpOrder = ["!resetXformStack!", "xformOp:transform", "xformOp:orient", "!invert!xformOp:translate:pivot"]
    }
}"#,
            "/A/B",
        );
        // (0,0,0) → invert pivot (0,0,-1) → orient: 90° about Y maps -Z to -X → (-1,0,0) → +(0,1,5).
        let p = m.transform_point3(DVec3::ZERO);
        assert!((p - DVec3::new(-1.0, 1.0, 5.0)).length() < 1e-6, "{p}");
    }

    #[test]
    fn missing_op_is_diagnosed() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Xform "A" {
    uniform token[] xformOpOrder = ["xformOp:translate"]
}"#,
        );
        world_transforms(&stage, &mut diags);
        assert!(diags.has_errors());
    }
}
