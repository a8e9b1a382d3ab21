//! UsdSkel: skinned meshes posed at the stage's time.
//!
//! A point-based prim under a `SkelRoot`, bound to a `Skeleton` through `skel:skeleton`
//! (inherited down namespace, as the skinning properties are), is posed as USD's
//! `UsdSkelSkinningQuery` and `UsdSkelBakeSkinning` pose it:
//!
//! 1. blend shapes (`skel:blendShapes` and `skel:blendShapeTargets`, weighted by the bound
//!    `SkelAnimation`'s `blendShapeWeights`; sparse `pointIndices`; in-betweens
//!    `inbetweens:NAME` with their `weight`, piecewise linear with the rest shape at 0 and
//!    the primary shape at 1) move the authored points;
//! 2. the skeleton's joint transforms at the time: the animation's `translations`,
//!    `rotations` and `scales` (joints mapped by name, `restTransforms` for the joints it
//!    does not animate), concatenated down the joint hierarchy, times the inverse
//!    `bindTransforms`;
//! 3. linear blend skinning of `geomBindTransform · point` by `primvars:skel:jointIndices` and
//!    `jointWeights` (any `elementSize`; `constant` interpolation binds every point alike),
//!    through the prim's own `skel:joints` order when it has one. Normals with `vertex`
//!    interpolation are skinned by the inverse transposes and renormalised; others are
//!    dropped so the mesh's normals are computed from the posed points.
//!
//! The result is in skeleton space, placed in the world by the Skeleton prim's transform; the
//! posed prim carries it in its own local space so geometry places it as any other prim.
//! Attribute values are already those at the stage's time ([`crate::scene::Stage::set_time`]):
//! nothing here reads samples.

use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::render::geometry::xform::{PrimXform, value_span};
use crate::scene::{Prim, PrimId, Stage, Value};
use glam::{DMat3, DMat4, DQuat, DVec3};
use std::collections::HashMap;

/// Below this, a weight or a shape weight difference is zero (`UsdSkel`'s epsilon).
const EPS: f64 = 1e-6;

/// A copy of `prim` posed by its skeleton and blend shapes (points and normals replaced, in
/// the prim's local space, whose world transform is `world`); `None` when `prim` is not
/// skinned (or cannot be, which is reported). The one hook geometry calls.
pub fn posed_prim(
    stage: &Stage,
    xforms: &[PrimXform],
    prim: &Prim,
    world: DMat4,
    diags: &mut Diagnostics,
) -> Option<Prim> {
    prim.attribute("points")?;
    let id = stage.find(&prim.path)?;
    let posed = pose(stage, xforms, id, diags)?;
    // Skeleton space → the prim's local space (its own transform is ignored by skinning).
    let det = world.determinant();
    if !det.is_finite() || det.abs() < 1e-300 {
        return None;
    }
    let to_local = world.inverse() * posed.to_world;
    let normal_to_local = DMat3::from_mat4(to_local).inverse().transpose();
    let mut out = prim.clone();
    let flat = |v: &[DVec3]| Value::TupleArray {
        width: 3,
        data: std::sync::Arc::new(v.iter().flat_map(|p| p.to_array()).collect()),
    };
    let points: Vec<DVec3> = posed.points.iter().map(|&p| to_local.transform_point3(p)).collect();
    for attr in out.attributes.iter_mut() {
        if attr.name == "points" {
            attr.value = Some((flat(&points), value_span(attr)));
        }
    }
    match &posed.normals {
        Some((name, normals)) => {
            let normals: Vec<DVec3> = normals.iter().map(|&n| (normal_to_local * n).normalize_or_zero()).collect();
            for attr in out.attributes.iter_mut().filter(|a| a.name == *name) {
                attr.value = Some((flat(&normals), value_span(attr)));
            }
        }
        None => out.attributes.retain(|a| !is_normals(&a.name)),
    }
    Some(out)
}

/// The world-space points (and unit normals, when authored per vertex) of the skinned prim
/// `id` at the stage's time; `None` when it is not skinned. For tests against USD's baked
/// skinning.
pub fn skinned_world_points(
    stage: &Stage,
    xforms: &[PrimXform],
    id: PrimId,
    diags: &mut Diagnostics,
) -> Option<(Vec<DVec3>, Option<Vec<DVec3>>)> {
    let posed = pose(stage, xforms, id, diags)?;
    let m = posed.to_world;
    let nm = DMat3::from_mat4(m).inverse().transpose();
    let points = posed.points.iter().map(|&p| m.transform_point3(p)).collect();
    let normals = posed.normals.map(|(_, n)| n.iter().map(|&n| (nm * n).normalize_or_zero()).collect());
    Some((points, normals))
}

/// The times at which something that poses the skinned prim `id` has samples: its own
/// attributes (points, normals, skinning primvars), its skeleton's attributes and placement,
/// and the bound animation's (joint transforms, blend shape weights), unsorted; `None` when
/// `id` is not skinned (no `SkelRoot` above it, or no `skel:skeleton` binding to a Skeleton).
/// Deformation blur keys skinned prims at these times (`crate::render::geometry::motion`).
pub fn skinning_sample_times(stage: &Stage, id: PrimId) -> Option<Vec<f64>> {
    let prim = stage.prim(id);
    prim.attribute("points")?;
    let root = skel_root(stage, id)?;
    let (skel_path, _) = inherited(stage, id, root, |p| target(p, "skel:skeleton"))?;
    let skel = stage.find(skel_path).filter(|&s| stage.prim(s).type_name.as_deref() == Some("Skeleton"))?;
    let mut times = crate::render::geometry::xform::transform_sample_times(stage, skel);
    let anim = animation(stage, skel, &mut Diagnostics::new());
    for p in [Some(id), Some(skel), anim].into_iter().flatten() {
        times.extend(stage.prim(p).attributes.iter().flat_map(|a| a.time_samples.iter().map(|(t, _)| *t)));
    }
    Some(times)
}

/// The `SkelRoot` at or above `id`.
fn skel_root(stage: &Stage, id: PrimId) -> Option<PrimId> {
    let mut root = Some(id);
    while let Some(r) = root {
        if stage.prim(r).type_name.as_deref() == Some("SkelRoot") {
            return Some(r);
        }
        root = stage.prim(r).parent;
    }
    None
}

fn is_normals(name: &str) -> bool {
    matches!(name, "normals" | "primvars:normals" | "primvars:normals:indices")
}

/// Posed points, in the space `to_world` places in the world.
struct Posed {
    points: Vec<DVec3>,
    /// The normals attribute that was skinned, and its skinned (unnormalised) values.
    normals: Option<(String, Vec<DVec3>)>,
    to_world: DMat4,
}

/// A warning about the skinning of `prim`, at `span`.
fn warn(diags: &mut Diagnostics, prim: &Prim, span: Span, message: String) {
    diags.push(
        Diagnostic::warning(format!("`{}`: {message}", prim.path))
            .at(span, "here")
            .note("the prim renders with its authored points"),
    );
}

/// The nearest of `id` and its ancestors, up to and including `root`, for which `get` says
/// something: UsdSkel's inherited binding properties.
fn inherited<'s, T>(stage: &'s Stage, id: PrimId, root: PrimId, get: impl Fn(&'s Prim) -> Option<T>) -> Option<T> {
    let mut at = Some(id);
    while let Some(i) = at {
        let prim = stage.prim(i);
        if let Some(found) = get(prim) {
            return Some(found);
        }
        if i == root {
            return None;
        }
        at = prim.parent;
    }
    None
}

/// The first target of relationship `name`, when authored.
fn target<'p>(prim: &'p Prim, name: &str) -> Option<(&'p str, Span)> {
    let rel = prim.relationship(name)?;
    rel.targets.first().map(|(path, span)| (path.as_str(), *span))
}

/// USD's row-vector matrices as glam column-vector ones.
fn matrices(value: Option<&Value>) -> Option<Vec<DMat4>> {
    match value? {
        Value::TupleArray { width: 16, data } => {
            Some(data.chunks_exact(16).map(|m| DMat4::from_cols_slice(m)).collect())
        }
        _ => None,
    }
}

fn vec3s(value: Option<&Value>) -> Option<Vec<DVec3>> {
    match value? {
        Value::TupleArray { width: 3, data } => Some(data.chunks_exact(3).map(DVec3::from_slice).collect()),
        _ => None,
    }
}

fn tokens(value: Option<&Value>) -> Option<&[String]> {
    value?.as_string_array()
}

/// Poses the prim `id`, if it is skinned.
fn pose(stage: &Stage, xforms: &[PrimXform], id: PrimId, diags: &mut Diagnostics) -> Option<Posed> {
    let prim = stage.prim(id);
    let root = skel_root(stage, id)?;
    let (skel_path, skel_span) = inherited(stage, id, root, |p| target(p, "skel:skeleton"))?;
    let indices_attr = inherited(stage, id, root, |p| p.attribute("primvars:skel:jointIndices"));
    let weights_attr = inherited(stage, id, root, |p| p.attribute("primvars:skel:jointWeights"));
    let has_shapes = prim.value("skel:blendShapes").and_then(Value::as_string_array).is_some_and(|s| !s.is_empty());
    if indices_attr.is_none() && weights_attr.is_none() && !has_shapes {
        return None;
    }
    let Some(skel_id) = stage.find(skel_path).filter(|&s| stage.prim(s).type_name.as_deref() == Some("Skeleton"))
    else {
        warn(diags, prim, skel_span, format!("`skel:skeleton` target `{skel_path}` is not a Skeleton prim"));
        return None;
    };
    let skeleton = stage.prim(skel_id);
    let anim = animation(stage, skel_id, diags);
    let mut points = vec3s(prim.value("points"))?;

    if has_shapes {
        apply_blend_shapes(stage, prim, anim.map(|a| stage.prim(a)), &mut points, diags)?;
    }
    let (Some(indices_attr), Some(weights_attr)) = (indices_attr, weights_attr) else {
        if let Some(one) = indices_attr.or(weights_attr) {
            let message = "`primvars:skel:jointIndices` and `jointWeights` go together: joints are not applied";
            warn(diags, prim, one.span, message.into());
        }
        // Blend shapes only: the points stay in the prim's own space.
        return Some(Posed { points, normals: None, to_world: xforms[id.0 as usize].world });
    };
    let joints_xf = skinning_transforms(skeleton, anim.map(|a| stage.prim(a)), diags)?;
    // The prim's own joint order, when it has one: names mapped to the skeleton's.
    let skel_joints = tokens(skeleton.value("joints")).unwrap_or(&[]);
    let joints_xf: Vec<DMat4> = match inherited(stage, id, root, |p| tokens(p.value("skel:joints"))) {
        Some(order) => {
            let by_name: HashMap<&str, usize> = skel_joints.iter().enumerate().map(|(i, j)| (j.as_str(), i)).collect();
            order.iter().map(|j| by_name.get(j.as_str()).map_or(DMat4::IDENTITY, |&i| joints_xf[i])).collect()
        }
        None => joints_xf,
    };
    let influences = Influences::read(prim, indices_attr, weights_attr, points.len(), joints_xf.len(), diags)?;
    let geom_bind = inherited(stage, id, root, |p| p.value("primvars:skel:geomBindTransform"))
        .and_then(Value::as_matrix4)
        .map_or(DMat4::IDENTITY, DMat4::from_cols_array);
    if let Some(method) = inherited(stage, id, root, |p| p.value("skel:skinningMethod")).and_then(Value::as_str)
        && method != "classicLinear"
    {
        let span = prim.attribute("skel:skinningMethod").map_or(prim.span, |a| a.span);
        diags.push(
            Diagnostic::warning(format!("`{}`: skinning method `{method}` is not supported", prim.path))
                .at(span, "here")
                .note("the prim is skinned by linear blend skinning (`classicLinear`)"),
        );
    }

    for (i, p) in points.iter_mut().enumerate() {
        let bound = geom_bind.transform_point3(*p);
        let mut skinned = DVec3::ZERO;
        for (j, w) in influences.of(i) {
            if w != 0.0 {
                skinned += joints_xf[j].transform_point3(bound) * w;
            }
        }
        *p = skinned;
    }
    let normals = skinned_normals(prim, &influences, &joints_xf, geom_bind);
    Some(Posed { points, normals, to_world: xforms[skel_id.0 as usize].world })
}

/// Skinned vertex normals (`normals`, or `primvars:normals` without indices), when authored.
fn skinned_normals(
    prim: &Prim,
    influences: &Influences,
    joints: &[DMat4],
    geom_bind: DMat4,
) -> Option<(String, Vec<DVec3>)> {
    let (name, attr) = ["primvars:normals", "normals"].iter().find_map(|n| Some((*n, prim.attribute(n)?)))?;
    if name == "primvars:normals" && prim.attribute("primvars:normals:indices").is_some() {
        return None;
    }
    let interpolation = attr.meta("interpolation").and_then(Value::as_str).unwrap_or("vertex");
    let normals = vec3s(attr.get())?;
    if !matches!(interpolation, "vertex" | "varying") || normals.len() != influences.points {
        return None;
    }
    let inverse_transpose = |m: &DMat4| DMat3::from_mat4(*m).inverse().transpose();
    let bind = inverse_transpose(&geom_bind);
    let joints: Vec<DMat3> = joints.iter().map(inverse_transpose).collect();
    let skinned = normals
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            let bound = bind * n;
            let mut out = DVec3::ZERO;
            for (j, w) in influences.of(i) {
                if w != 0.0 {
                    out += joints[j] * bound * w;
                }
            }
            out.normalize_or_zero()
        })
        .collect();
    Some((name.to_string(), skinned))
}

/// Joint influences: `element_size` (joint, weight) pairs per point, or one set for all.
struct Influences {
    indices: Vec<usize>,
    weights: Vec<f64>,
    element_size: usize,
    rigid: bool,
    points: usize,
}

impl Influences {
    fn read(
        prim: &Prim,
        indices_attr: &crate::scene::Attribute,
        weights_attr: &crate::scene::Attribute,
        points: usize,
        joints: usize,
        diags: &mut Diagnostics,
    ) -> Option<Influences> {
        let span = value_span(indices_attr);
        let (Some(indices), Some(weights)) =
            (indices_attr.get().and_then(Value::as_int_array), weights_attr.get().and_then(Value::as_float_array))
        else {
            warn(diags, prim, span, "`primvars:skel:jointIndices` or `jointWeights` has no value".into());
            return None;
        };
        let element_size = indices_attr.meta("elementSize").and_then(Value::as_i64).unwrap_or(1);
        let element_size = usize::try_from(element_size).ok().filter(|&n| n > 0)?;
        let interpolation = indices_attr.meta("interpolation").and_then(Value::as_str).unwrap_or("vertex");
        let rigid = interpolation == "constant";
        let expected = if rigid { element_size } else { points.saturating_mul(element_size) };
        if indices.len() != weights.len() || indices.len() != expected {
            warn(
                diags,
                prim,
                span,
                format!(
                    "{} joint indices and {} weights, but {expected} are needed ({} interpolation, elementSize {element_size})",
                    indices.len(),
                    weights.len(),
                    if rigid { "constant" } else { "vertex" }
                ),
            );
            return None;
        }
        if let Some(bad) = indices.iter().find(|&&j| j < 0 || j as usize >= joints) {
            warn(diags, prim, span, format!("joint index {bad} is out of range ({joints} joints)"));
            return None;
        }
        let indices = indices.iter().map(|&j| j as usize).collect();
        Some(Influences { indices, weights: weights.to_vec(), element_size, rigid, points })
    }

    /// The (joint, weight) pairs of point `i`.
    fn of(&self, i: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let start = if self.rigid { 0 } else { i * self.element_size };
        let end = start + self.element_size;
        self.indices[start..end].iter().copied().zip(self.weights[start..end].iter().copied())
    }
}

/// The `SkelAnimation` bound to the skeleton `skel` (its `skel:animationSource`).
fn animation(stage: &Stage, skel: PrimId, diags: &mut Diagnostics) -> Option<PrimId> {
    let skeleton = stage.prim(skel);
    let (path, span) = target(skeleton, "skel:animationSource")?;
    let found = stage.find(path).filter(|&a| stage.prim(a).type_name.as_deref() == Some("SkelAnimation"));
    if found.is_none() {
        diags.push(
            Diagnostic::warning(format!(
                "`{}`: `skel:animationSource` target `{path}` is not a SkelAnimation prim",
                skeleton.path
            ))
            .at(span, "here")
            .note("the skeleton stays in its rest pose"),
        );
    }
    found
}

/// The skinning transform of every joint (skeleton order): joint-to-skeleton at the time
/// times the inverse bind transform.
fn skinning_transforms(skeleton: &Prim, anim: Option<&Prim>, diags: &mut Diagnostics) -> Option<Vec<DMat4>> {
    let joints = tokens(skeleton.value("joints")).unwrap_or(&[]);
    let n = joints.len();
    let bind = matrices(skeleton.value("bindTransforms")).filter(|b| b.len() == n);
    let Some(bind) = bind else {
        let span = skeleton.attribute("bindTransforms").map_or(skeleton.span, |a| a.span);
        warn(diags, skeleton, span, format!("`bindTransforms` must hold one matrix per joint ({n})"));
        return None;
    };
    let rest = matrices(skeleton.value("restTransforms")).filter(|r| r.len() == n);
    let mut local: Vec<Option<DMat4>> = rest.map_or_else(|| vec![None; n], |r| r.into_iter().map(Some).collect());
    if let Some(anim) = anim
        && let Some(animated) = animated_locals(anim, diags)
    {
        let by_name: HashMap<&str, usize> = joints.iter().enumerate().map(|(i, j)| (j.as_str(), i)).collect();
        for (name, m) in animated {
            if let Some(&i) = by_name.get(name) {
                local[i] = Some(m);
            }
        }
    }
    let by_name: HashMap<&str, usize> = joints.iter().enumerate().map(|(i, j)| (j.as_str(), i)).collect();
    let mut skel_space: Vec<DMat4> = Vec::with_capacity(n);
    for (i, joint) in joints.iter().enumerate() {
        let Some(m) = local[i] else {
            let span = skeleton.attribute("restTransforms").map_or(skeleton.span, |a| a.span);
            warn(
                diags,
                skeleton,
                span,
                format!("joint `{joint}` is not animated and has no rest transform (`restTransforms`)"),
            );
            return None;
        };
        let parent = joint.rsplit_once('/').and_then(|(p, _)| by_name.get(p).copied());
        skel_space.push(match parent {
            Some(p) if p < i => skel_space[p] * m,
            Some(_) => {
                let span = skeleton.attribute("joints").map_or(skeleton.span, |a| a.span);
                warn(diags, skeleton, span, format!("joint `{joint}` comes before its parent in `joints`"));
                return None;
            }
            None => m,
        });
    }
    let mut out = Vec::with_capacity(n);
    for (i, (s, b)) in skel_space.iter().zip(&bind).enumerate() {
        let det = b.determinant();
        if !det.is_finite() || det.abs() < 1e-300 {
            let span = skeleton.attribute("bindTransforms").map_or(skeleton.span, |a| a.span);
            warn(diags, skeleton, span, format!("the bind transform of joint `{}` is singular", joints[i]));
            return None;
        }
        out.push(*s * b.inverse());
    }
    Some(out)
}

/// The animation's joint-local transforms, by joint name; `None` (reported) when its
/// arrays do not match its joints.
fn animated_locals<'a>(anim: &'a Prim, diags: &mut Diagnostics) -> Option<Vec<(&'a str, DMat4)>> {
    let joints = tokens(anim.value("joints")).unwrap_or(&[]);
    let n = joints.len();
    let translations = vec3s(anim.value("translations"));
    let rotations = match anim.value("rotations") {
        Some(Value::TupleArray { width: 4, data }) => Some(data.chunks_exact(4).collect::<Vec<_>>()),
        _ => None,
    };
    let scales = vec3s(anim.value("scales"));
    let (Some(t), Some(r), Some(s)) = (translations, rotations, scales) else {
        if n > 0 {
            warn(
                diags,
                anim,
                anim.span,
                "`translations`, `rotations` and `scales` must all be authored to animate joints".into(),
            );
        }
        return None;
    };
    if t.len() != n || r.len() != n || s.len() != n {
        warn(
            diags,
            anim,
            anim.span,
            format!("{n} joints but {} translations, {} rotations and {} scales", t.len(), r.len(), s.len()),
        );
        return None;
    }
    Some(
        joints
            .iter()
            .enumerate()
            .map(|(i, joint)| {
                // USD quaternions are (real, i, j, k); joint transforms are scale, then rotate,
                // then translate.
                let q = DQuat::from_xyzw(r[i][1], r[i][2], r[i][3], r[i][0]);
                let q = if q.length_squared() > 0.0 { q.normalize() } else { DQuat::IDENTITY };
                (joint.as_str(), DMat4::from_scale_rotation_translation(s[i], q, t[i]))
            })
            .collect(),
    )
}

/// Adds the weighted blend shape offsets to `points`. `None` (reported) when a shape does not
/// fit the prim.
fn apply_blend_shapes(
    stage: &Stage,
    prim: &Prim,
    anim: Option<&Prim>,
    points: &mut [DVec3],
    diags: &mut Diagnostics,
) -> Option<()> {
    let names = tokens(prim.value("skel:blendShapes")).unwrap_or(&[]);
    let targets = prim.relationship("skel:blendShapeTargets").map(|r| r.targets.as_slice()).unwrap_or(&[]);
    let span = prim.attribute("skel:blendShapes").map_or(prim.span, value_span);
    if targets.len() != names.len() {
        warn(
            diags,
            prim,
            span,
            format!("{} `skel:blendShapes` but {} `skel:blendShapeTargets`", names.len(), targets.len()),
        );
        return None;
    }
    // The animation's weights, by shape name; shapes it does not name weigh 0.
    let mut weight_of: HashMap<&str, f64> = HashMap::new();
    if let Some(anim) = anim {
        let anim_names = tokens(anim.value("blendShapes")).unwrap_or(&[]);
        let weights = anim.value("blendShapeWeights").and_then(Value::as_float_array).unwrap_or(&[]);
        if anim_names.len() == weights.len() {
            weight_of = anim_names.iter().map(String::as_str).zip(weights.iter().copied()).collect();
        } else {
            warn(
                diags,
                anim,
                anim.span,
                format!("{} `blendShapes` but {} `blendShapeWeights`", anim_names.len(), weights.len()),
            );
        }
    }
    for (name, (target, target_span)) in names.iter().zip(targets) {
        let weight = weight_of.get(name.as_str()).copied().unwrap_or(0.0);
        let Some(shape) =
            stage.find(target).map(|s| stage.prim(s)).filter(|s| s.type_name.as_deref() == Some("BlendShape"))
        else {
            warn(diags, prim, *target_span, format!("blend shape target `{target}` is not a BlendShape prim"));
            return None;
        };
        let indices = shape.value("pointIndices").and_then(Value::as_int_array);
        // Sub-shapes by weight: the rest shape (no offsets) at 0, the primary at 1, in-betweens.
        let mut sub: Vec<(f64, Option<Vec<DVec3>>)> =
            vec![(1.0, Some(vec3s(shape.value("offsets")).unwrap_or_default())), (0.0, None)];
        for attr in shape.attributes.iter().filter(|a| a.name.starts_with("inbetweens:")) {
            let Some(w) = attr.meta("weight").and_then(Value::as_f64) else { continue };
            if (w - 0.0).abs() <= EPS || (w - 1.0).abs() <= EPS {
                continue;
            }
            sub.push((w, vec3s(attr.get())));
        }
        sub.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (w, offsets) in sub_shape_weights(&sub, weight) {
            let Some(offsets) = offsets else { continue };
            let fits = match indices {
                Some(ix) => ix.len() == offsets.len() && ix.iter().all(|&i| i >= 0 && (i as usize) < points.len()),
                None => offsets.len() == points.len(),
            };
            if !fits {
                let span = shape.attribute("offsets").map_or(shape.span, |a| a.span);
                warn(
                    diags,
                    shape,
                    span,
                    format!("the offsets do not fit the {} points of `{}`", points.len(), prim.path),
                );
                return None;
            }
            for (k, o) in offsets.iter().enumerate() {
                let i = indices.map_or(k, |ix| ix[k] as usize);
                points[i] += *o * w;
            }
        }
    }
    Some(())
}

/// The sub-shapes a shape weight blends, with their weights (`UsdSkelBlendShapeQuery`): the
/// two bracketing `w` in `sorted`, extrapolating the outermost pair.
fn sub_shape_weights(sorted: &[(f64, Option<Vec<DVec3>>)], w: f64) -> Vec<(f64, Option<&Vec<DVec3>>)> {
    if sorted.len() < 3 {
        // Only the rest and primary shapes: the primary, weighted as given.
        return sorted.iter().filter(|(s, _)| *s == 1.0).map(|(_, o)| (w, o.as_ref())).collect();
    }
    let upper = sorted.partition_point(|(s, _)| *s <= w);
    let (lo, hi) = match upper {
        0 => (0, 1),
        u if u == sorted.len() => (u - 2, u - 1),
        u => (u - 1, u),
    };
    let delta = sorted[hi].0 - sorted[lo].0;
    if delta <= EPS {
        return Vec::new();
    }
    let alpha = (w - sorted[lo].0) / delta;
    // The rest shape (no offsets) adds nothing.
    let mut out = Vec::new();
    if let Some(offsets) = sorted[lo].1.as_ref().filter(|_| (alpha - 1.0).abs() > EPS) {
        out.push((1.0 - alpha, Some(offsets)));
    }
    if let Some(offsets) = sorted[hi].1.as_ref().filter(|_| alpha.abs() > EPS) {
        out.push((alpha, Some(offsets)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::geometry::xform::{tests::stage, world_transforms};

    #[test]
    fn sub_shape_weights_match_usd() {
        // usd-core's `ComputeSubShapeWeights` for an in-between at 0.5: 0.24 → 0.48 of the
        // in-between; 0.8 → 0.4 of it and 0.6 of the primary; 1.5 extrapolates the last pair.
        let shapes = vec![(0.0, None), (0.5, Some(vec![DVec3::X])), (1.0, Some(vec![DVec3::Y]))];
        let weights = |w: f64| -> Vec<(f64, DVec3)> {
            sub_shape_weights(&shapes, w).into_iter().map(|(w, o)| (w, o.map_or(DVec3::ZERO, |o| o[0]))).collect()
        };
        let close = |got: Vec<(f64, DVec3)>, want: &[(f64, DVec3)]| {
            got.len() == want.len() && got.iter().zip(want).all(|(g, w)| (g.0 - w.0).abs() < 1e-12 && g.1 == w.1)
        };
        assert!(close(weights(0.24), &[(0.48, DVec3::X)]), "{:?}", weights(0.24));
        assert!(close(weights(0.8), &[(0.4, DVec3::X), (0.6, DVec3::Y)]), "{:?}", weights(0.8));
        assert!(close(weights(1.5), &[(-1.0, DVec3::X), (2.0, DVec3::Y)]), "{:?}", weights(1.5));
        assert!(close(weights(0.0), &[]), "{:?}", weights(0.0));
    }

    #[test]
    fn half_a_binding_is_reported_and_the_mesh_keeps_its_points() {
        let (stage, _) = stage(
            r#"#usda 1.0
def SkelRoot "R" {
    rel skel:skeleton = </R/S>
    def Skeleton "S" {
        uniform token[] joints = ["a"]
        uniform matrix4d[] bindTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1))]
    }
    def Mesh "M" {
        point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
        int[] primvars:skel:jointIndices = [0, 0, 0] (interpolation = "vertex")
    }
}
"#,
        );
        let mut diags = Diagnostics::new();
        let xforms = world_transforms(&stage, &mut diags);
        let id = stage.find("/R/M").unwrap();
        let posed = skinned_world_points(&stage, &xforms, id, &mut diags).unwrap();
        assert_eq!(posed.0, vec![DVec3::ZERO, DVec3::X, DVec3::Y]);
        let messages: Vec<&str> = diags.items().iter().map(|d| d.message.as_str()).collect();
        assert!(messages.iter().any(|m| m.contains("go together")), "{messages:?}");
    }
}
