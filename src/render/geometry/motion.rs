//! Motion blur: what moves while the camera's shutter is open, as keyed transforms.
//!
//! A UsdGeom camera's `shutter:open` and `shutter:close` are frames relative to the time code
//! rendered; when they differ, each camera ray carries a time `τ` in `[0, 1)` across that
//! interval (its own sampler dimension) and sees the scene as it is then. Only prims whose
//! placement changes inside the interval pay for it: each becomes an instance (its geometry
//! built once, at the frame's time, as today) whose transform is keyed over the shutter
//! ([`MotionKeys`]); the top-level BVH's box of a moving instance covers every key, and a ray
//! moves into its object space through the transform at its own time. A scene in which
//! nothing moves — and every scene with the shutter closed, the default — is built and traced
//! exactly as before, so its image is bit for bit the same.
//!
//! A mesh whose `points` are sampled inside the shutter deforms: it is emitted again at each
//! key (the shutter's ends and every sample time of its points or placement inside it), in
//! world space, and becomes a prototype of its own whose triangles move linearly between
//! those keys ([`Deformation`]); each triangle's BVH box covers it at every key, so at every
//! time between.
//!
//! Transforms at a time are USD's (`ComputeLocalToWorldTransform(time)`: every xformOp's
//! samples interpolated — linearly, quaternions by slerp — and the ops composed), evaluated at
//! the shutter's ends and at every sample time inside it. Between keys the matrices are
//! interpolated linearly, and a segment is halved until that stays within
//! [`KEY_TOLERANCE`] of USD's transform at its middle (a rotation needs a few keys, a
//! translation none), so the keys follow USD's curve and the boxes over them bound it.

use crate::diag::{Diagnostic, Diagnostics};
use crate::render::geometry::emit::{Emitter, emit_prim};
use crate::render::geometry::primvars::PrimvarTable;
use crate::render::geometry::shapes::transformed_box;
use crate::render::geometry::xform::{transform_sample_times, world_transform_at};
use crate::render::geometry::{Geometry, GeometryOptions, InstanceDesc, Prototype, Triangle, Triangles, bounds_of};
use crate::scene::{Prim, Stage, TimeCode, Value};
use glam::{DAffine3, DMat4, DVec3, Vec3};
use std::collections::HashMap;

/// How far (relative to the transform's largest entry) linear interpolation between two keys
/// may stray from USD's transform at their middle before the segment is halved: 1e-4, a
/// tenth of a pixel for an object a thousand pixels across. (Interpolated rotations shrink
/// by up to this much between keys.)
pub const KEY_TOLERANCE: f64 = 1e-4;

/// The most times a segment between authored keys is halved (256 pieces): a half turn
/// between two samples needs 128.
const MAX_HALVINGS: u32 = 8;

/// The camera's shutter interval in frames relative to the time code rendered
/// (`shutter:open`, `shutter:close`; both 0 by default: closed).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Shutter {
    /// When the shutter opens.
    pub open: f64,
    /// When it closes.
    pub close: f64,
}

impl Shutter {
    /// The shutter of a Camera prim; a warning (and a closed shutter) when it closes before
    /// it opens or is not finite.
    pub fn of_camera(prim: &Prim, diags: &mut Diagnostics) -> Shutter {
        let num = |name: &str| prim.value(name).and_then(Value::as_f64).unwrap_or(0.0);
        let (open, close) = (num("shutter:open"), num("shutter:close"));
        if !(open.is_finite() && close.is_finite() && open <= close) {
            let attr = prim.attribute("shutter:close").or_else(|| prim.attribute("shutter:open"));
            diags.push(
                Diagnostic::warning(format!(
                    "camera `{}`: shutter:open {open} to shutter:close {close} is not an interval; rendered without motion blur",
                    prim.path
                ))
                .at(attr.map_or(prim.span, crate::render::geometry::xform::value_span), "here"),
            );
            return Shutter::default();
        }
        Shutter { open, close }
    }

    /// Whether the shutter is open for a while (rays then carry a time).
    pub fn is_open(&self) -> bool {
        self.close > self.open
    }

    /// The stage time at ray time `tau` (`[0, 1]` across the shutter) of frame `frame`.
    pub fn time(&self, frame: f64, tau: f64) -> f64 {
        frame + self.open + (self.close - self.open) * tau
    }
}

/// A transform keyed over the shutter: `times` (ray times in `[0, 1]`, ascending, the first 0
/// and the last 1) and the transform at each, linearly interpolated between them.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionKeys {
    times: Vec<f32>,
    transforms: Vec<DAffine3>,
}

impl MotionKeys {
    /// Keys of `transform_at(stage time)` over the shutter `[a, b]` of stage time, at its ends,
    /// at `inner` (authored sample times, any order; those outside `(a, b)` are ignored) and
    /// wherever a segment had to be halved (see the module documentation).
    pub fn sample(transform_at: &dyn Fn(f64) -> DMat4, a: f64, b: f64, inner: &[f64]) -> MotionKeys {
        let keys = MotionKeys::sample_all(&|t| vec![transform_at(t)], a, b, inner);
        keys.into_iter().next().expect("one transform at every time")
    }

    /// [`MotionKeys::sample`] of several transforms keyed at the same times (a point
    /// instancer's points): a segment is halved when any of them needs it. Empty when
    /// `transforms_at` returns different numbers of transforms at two times.
    pub fn sample_all(transforms_at: &dyn Fn(f64) -> Vec<DMat4>, a: f64, b: f64, inner: &[f64]) -> Vec<MotionKeys> {
        let mut at: Vec<f64> = inner.iter().copied().filter(|&t| t > a && t < b).collect();
        at.push(a);
        at.push(b);
        at.sort_by(f64::total_cmp);
        at.dedup();
        let mut keys: Vec<(f64, Vec<DMat4>)> = vec![(a, transforms_at(a))];
        for pair in at.windows(2) {
            let end = (pair[1], transforms_at(pair[1]));
            let start = keys.last().expect("a first key").clone();
            halve(transforms_at, start, end.clone(), MAX_HALVINGS, &mut keys);
            keys.push(end);
        }
        let count = keys[0].1.len();
        if keys.iter().any(|(_, k)| k.len() != count) {
            return Vec::new();
        }
        let span = b - a;
        let times: Vec<f32> = keys.iter().map(|(t, _)| (((t - a) / span) as f32).clamp(0.0, 1.0)).collect();
        (0..count)
            .map(|j| MotionKeys {
                times: times.clone(),
                transforms: keys.iter().map(|(_, m)| DAffine3::from_mat4(m[j])).collect(),
            })
            .collect()
    }

    /// Ray times of the keys.
    pub fn times(&self) -> &[f32] {
        &self.times
    }

    /// The keyed transforms.
    pub fn transforms(&self) -> &[DAffine3] {
        &self.transforms
    }

    /// Whether every key is `m` exactly.
    fn is_constant(&self, m: &DAffine3) -> bool {
        self.transforms.iter().all(|k| k == m)
    }

    /// The transform at ray time `tau` (clamped to `[0, 1]`).
    #[inline]
    pub fn at(&self, tau: f32) -> DAffine3 {
        let n = self.times.len();
        // The segment [times[k], times[k + 1]] holding tau.
        let k = self.times[1..n - 1].partition_point(|&t| t <= tau);
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let w = if t1 > t0 { ((tau - t0) / (t1 - t0)).clamp(0.0, 1.0) as f64 } else { 0.0 };
        let (m0, m1) = (&self.transforms[k], &self.transforms[k + 1]);
        DAffine3 {
            matrix3: m0.matrix3 * (1.0 - w) + m1.matrix3 * w,
            translation: m0.translation * (1.0 - w) + m1.translation * w,
        }
    }

    /// The world box `(min, max)` of the object box `(lo, hi)` over the whole shutter: each
    /// point moves linearly between keys, so the keys' boxes bound it.
    pub fn bounds(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        self.transforms
            .iter()
            .map(|m| transformed_box(&DMat4::from(*m), lo, hi))
            .reduce(|(a, b), (c, d)| (a.min(c), b.max(d)))
            .expect("at least two keys")
    }

    /// These keys applied after `m` (`key · m` at every key).
    fn then(&self, m: DAffine3) -> MotionKeys {
        MotionKeys { times: self.times.clone(), transforms: self.transforms.iter().map(|k| *k * m).collect() }
    }
}

/// Adds the keys strictly between `start` and `end` that linear interpolation needs to stay
/// within [`KEY_TOLERANCE`] of `transform_at` (depth-first, so in time order).
fn halve(
    transforms_at: &dyn Fn(f64) -> Vec<DMat4>,
    start: (f64, Vec<DMat4>),
    end: (f64, Vec<DMat4>),
    depth: u32,
    keys: &mut Vec<(f64, Vec<DMat4>)>,
) {
    if depth == 0 {
        return;
    }
    let mid_t = 0.5 * (start.0 + end.0);
    let mid = transforms_at(mid_t);
    let strays = |(m, (s, e)): (&DMat4, (&DMat4, &DMat4))| {
        let lerp = (*s + *e) * 0.5;
        let scale = m.to_cols_array().iter().fold(1e-300f64, |a, x| a.max(x.abs()));
        let error = (*m - lerp).to_cols_array().iter().fold(0.0f64, |a, x| a.max(x.abs()));
        error > KEY_TOLERANCE * scale
    };
    let same_count = mid.len() == start.1.len() && mid.len() == end.1.len();
    if !same_count || !mid.iter().zip(start.1.iter().zip(&end.1)).any(strays) {
        return;
    }
    halve(transforms_at, start, (mid_t, mid.clone()), depth - 1, keys);
    keys.push((mid_t, mid.clone()));
    halve(transforms_at, (mid_t, mid), end, depth - 1, keys);
}

/// The transform keys of a prim's world placement over `shutter` at frame `frame`, relative
/// to its placement at the frame (`W(t) · W(frame)⁻¹`), or `None` when no op that places it
/// has samples or the placement is the frame's throughout.
pub fn placement_motion(stage: &Stage, id: crate::scene::PrimId, frame: f64, shutter: Shutter) -> Option<MotionKeys> {
    let samples = transform_sample_times(stage, id);
    if samples.is_empty() {
        return None;
    }
    // Problems with the ops were reported when the frame's transforms were read.
    let quiet = &mut Diagnostics::new();
    let base = world_transform_at(stage, id, frame, quiet);
    if base.determinant() == 0.0 || !base.is_finite() {
        return None;
    }
    let to_base = base.inverse();
    let relative = |t: f64| world_transform_at(stage, id, t, &mut Diagnostics::new()) * to_base;
    let (a, b) = (shutter.time(frame, 0.0), shutter.time(frame, 1.0));
    let keys = MotionKeys::sample(&relative, a, b, &samples);
    // Exactly the frame's placement at every key (bit for bit: `W · W⁻¹` is not always the
    // identity in floating point, so compare each key's world transform with the frame's).
    let still = keys.times.len() == 2
        && [a, b].iter().all(|&t| world_transform_at(stage, id, t, &mut Diagnostics::new()) == base);
    if still || keys.is_constant(&DAffine3::IDENTITY) { None } else { Some(keys) }
}

/// The camera-to-world transform of Camera prim `id` keyed over `shutter`, when the camera
/// moves while it is open (`None` otherwise, and at the default time).
pub fn camera_motion(stage: &Stage, id: crate::scene::PrimId, shutter: Shutter) -> Option<MotionKeys> {
    let TimeCode::At(frame) = stage.time() else { return None };
    if !shutter.is_open() {
        return None;
    }
    placement_motion(stage, id, frame, shutter)?;
    let world = |t: f64| world_transform_at(stage, id, t, &mut Diagnostics::new());
    let (a, b) = (shutter.time(frame, 0.0), shutter.time(frame, 1.0));
    Some(MotionKeys::sample(&world, a, b, &transform_sample_times(stage, id)))
}

/// World-space triangle positions keyed over the shutter, for a deforming prototype: each
/// triangle's vertices move linearly between keys; so does each analytic shape (a Points
/// prim's spheres), by a translation from where the frame placed it.
#[derive(Clone, Debug, PartialEq)]
pub struct Deformation {
    times: Vec<f32>,
    /// Per key, every triangle's vertices (in the prototype's order).
    positions: Vec<Vec<[Vec3; 3]>>,
    /// Per key, every shape's translation from its place at the frame (empty: no shapes).
    offsets: Vec<Vec<Vec3>>,
}

impl Deformation {
    /// Ray times of the keys.
    pub fn times(&self) -> &[f32] {
        &self.times
    }

    /// The triangles' vertices at key `k`.
    pub fn key(&self, k: usize) -> &[[Vec3; 3]] {
        &self.positions[k]
    }

    /// The segment `k` (keys `k`, `k + 1`) holding ray time `tau`, and the weight of key `k + 1`.
    #[inline]
    fn segment(&self, tau: f32) -> (usize, f32) {
        let n = self.times.len();
        let k = self.times[1..n - 1].partition_point(|&t| t <= tau);
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        (k, if t1 > t0 { ((tau - t0) / (t1 - t0)).clamp(0.0, 1.0) } else { 0.0 })
    }

    /// Triangle `i`'s vertices at ray time `tau`.
    #[inline]
    pub fn at(&self, i: usize, tau: f32) -> [Vec3; 3] {
        let (k, w) = self.segment(tau);
        let (p0, p1) = (&self.positions[k][i], &self.positions[k + 1][i]);
        [0, 1, 2].map(|v| p0[v] + (p1[v] - p0[v]) * w)
    }

    /// Shape `j`'s translation from its place at the frame, at ray time `tau`.
    #[inline]
    pub fn shape_offset(&self, j: usize, tau: f32) -> Vec3 {
        if self.offsets.is_empty() {
            return Vec3::ZERO;
        }
        let (k, w) = self.segment(tau);
        let (a, b) = (self.offsets[k][j], self.offsets[k + 1][j]);
        a + (b - a) * w
    }

    /// Triangle `i`'s box over the whole shutter: the union of its keys' boxes.
    pub fn bounds(&self, i: usize) -> (Vec3, Vec3) {
        let boxes = self.positions.iter().map(|key| {
            let p = &key[i];
            (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]))
        });
        boxes.reduce(|(a, b), (c, d)| (a.min(c), b.max(d))).expect("at least two keys")
    }

    /// The box over the whole shutter of shape `j`, whose box at the frame is `(lo, hi)`.
    pub fn shape_bounds(&self, j: usize, (lo, hi): (Vec3, Vec3)) -> (Vec3, Vec3) {
        let boxes = self.offsets.iter().map(|key| (lo + key[j], hi + key[j]));
        boxes.fold((lo, hi), |(a, b), (c, d)| (a.min(c), b.max(d)))
    }
}

/// What a prim emits at one key: its triangles' vertices and its shapes' centres.
type Emitted = (Vec<[Vec3; 3]>, Vec<Vec3>);

/// A shape's centre (its object-space origin) in the world.
fn shape_centre(shape: &crate::render::geometry::shapes::Shape) -> Vec3 {
    shape.to_world.transform_point3(DVec3::ZERO).as_vec3()
}

/// `prim`, placed by `world`, emitted as the frame's build emits it (same primvar table,
/// subdivision level).
fn emit_at(prim: &Prim, world: DMat4, options: GeometryOptions, names: &[String]) -> Emitted {
    let (mut triangles, mut shapes, mut degenerate) = (Triangles::new(), Vec::new(), 0);
    let mut table = PrimvarTable { names: names.to_vec(), ..PrimvarTable::default() };
    let mut out = Emitter::new(&mut triangles, &mut shapes, &mut degenerate, &mut table, world, 0, usize::MAX);
    out.subdiv_level = options.subdiv_level;
    emit_prim(prim, &mut out, &mut Diagnostics::new());
    (triangles.into_parts().0, shapes.iter().map(shape_centre).collect())
}

/// Copies of the stage at key times, shared by every skinned prim of one build (each copy is
/// the whole stage; a shot's keys are few).
type StagesAt = HashMap<u64, (Stage, Vec<crate::render::geometry::xform::PrimXform>)>;

/// The deformation of world prim `id` over `shutter`, given what the frame's build emitted for
/// it (`frame_emitted`): `None` when nothing that shapes it is sampled, it is not a Mesh or
/// Points, or it is the frame's shape at every key.
/// - A skinned prim (UsdSkel) is posed at each key time, as the frame's build poses it, from a
///   copy of the stage at that time: keys at the samples of its points, its skeleton's
///   placement and its animation.
/// - Otherwise its `points` (and placement) are read at each key time.
///
/// With `object_space` (a prim the build made a prototype of its own, placed by its world
/// transform, which keys its instance) the keys are in its own space: its placement is left
/// out (a skinned prim's posed points are still relative to its placement at each time).
#[allow(clippy::too_many_arguments)]
fn deformation_of(
    stage: &Stage,
    id: crate::scene::PrimId,
    frame: f64,
    shutter: Shutter,
    options: GeometryOptions,
    names: &[String],
    frame_emitted: &Emitted,
    stages: &mut StagesAt,
    object_space: bool,
    diags: &mut Diagnostics,
) -> Option<Deformation> {
    let prim = stage.prim(id);
    if !matches!(prim.type_name.as_deref(), Some("Mesh" | "Points")) {
        return None;
    }
    let points = prim.attribute("points")?;
    let skinned = crate::render::geometry::skel::skinning_sample_times(stage, id);
    let mut times: Vec<f64> = match &skinned {
        Some(times) => times.clone(),
        None => points.time_samples.iter().map(|(t, _)| *t).collect(),
    };
    if times.is_empty() {
        return None;
    }
    let (a, b) = (shutter.time(frame, 0.0), shutter.time(frame, 1.0));
    times.extend(transform_sample_times(stage, id));
    times.retain(|&t| t > a && t < b);
    times.extend([a, b]);
    times.sort_by(f64::total_cmp);
    times.dedup();
    let quiet = &mut Diagnostics::new();
    let placement_at = |t: f64, quiet: &mut Diagnostics| {
        if object_space { DMat4::IDENTITY } else { world_transform_at(stage, id, t, quiet) }
    };
    if skinned.is_none() {
        // Cheap test first: the points and placement are the frame's at every key.
        let at_frame = (points.value_at(TimeCode::At(frame)), placement_at(frame, quiet));
        if times.iter().all(|&t| (points.value_at(TimeCode::At(t)), placement_at(t, quiet)) == at_frame) {
            return None;
        }
    }
    let mut keys: Vec<Emitted> = Vec::with_capacity(times.len());
    for &t in &times {
        let emitted = if skinned.is_some() {
            let (at, xforms) = stages.entry(t.to_bits()).or_insert_with(|| {
                let at = stage.at_time(TimeCode::At(t));
                let xforms = crate::render::geometry::xform::world_transforms(&at, &mut Diagnostics::new());
                (at, xforms)
            });
            let world = xforms[id.0 as usize].world;
            let prim_at = at.prim(id);
            let posed = crate::render::geometry::skel::posed_prim(at, xforms, prim_at, world, quiet);
            let placed = if object_space { DMat4::IDENTITY } else { world };
            emit_at(posed.as_ref().unwrap_or(prim_at), placed, options, names)
        } else {
            let mut posed = prim.clone();
            if let Some(attr) = posed.attributes.iter_mut().find(|a| a.name == "points") {
                attr.value = points.value_at(TimeCode::At(t)).map(|v| (v, attr.span));
            }
            emit_at(&posed, placement_at(t, quiet), options, names)
        };
        if (emitted.0.len(), emitted.1.len()) != (frame_emitted.0.len(), frame_emitted.1.len()) {
            diags.push(
                Diagnostic::warning(format!(
                    "`{}` has {} triangles and {} points at one time inside the shutter, and {} and {} at the \
                     frame (degenerate faces, or displacement); rendered without deformation blur",
                    prim.path,
                    emitted.0.len(),
                    emitted.1.len(),
                    frame_emitted.0.len(),
                    frame_emitted.1.len()
                ))
                .at(crate::render::geometry::xform::value_span(points), "its points"),
            );
            return None;
        }
        keys.push(emitted);
    }
    if keys.iter().all(|k| k == frame_emitted) {
        return None;
    }
    let offsets = if frame_emitted.1.is_empty() {
        Vec::new()
    } else {
        keys.iter().map(|(_, centres)| centres.iter().zip(&frame_emitted.1).map(|(c, f)| *c - *f).collect()).collect()
    };
    let span = b - a;
    Some(Deformation {
        times: times.iter().map(|t| (((t - a) / span) as f32).clamp(0.0, 1.0)).collect(),
        positions: keys.into_iter().map(|(triangles, _)| triangles).collect(),
        offsets,
    })
}

/// Moves every deforming world prim (see [`deformation_of`]) into a prototype of its own
/// with its [`Deformation`], placed once where it is (the keys are in world space); returns
/// how many. Meshes with GeomSubset materials are left to transform blur.
fn deform(
    geometry: &mut Geometry,
    stage: &Stage,
    frame: f64,
    shutter: Shutter,
    options: GeometryOptions,
    diags: &mut Diagnostics,
) -> usize {
    let mut counts = vec![(0usize, 0usize); geometry.prims.len()];
    for i in 0..geometry.triangles.len() {
        counts[geometry.triangles.prim(i) as usize].0 += 1;
    }
    for s in &geometry.shapes {
        counts[s.prim as usize].1 += 1;
    }
    let has_subsets: Vec<bool> = {
        let mut v = vec![false; geometry.prims.len()];
        for p in &geometry.prims {
            if let Some(owner) = p.subset_of {
                v[owner as usize] = true;
            }
        }
        v
    };
    let mut stages = StagesAt::new();
    let mut deformed = 0;
    for prim in 0..geometry.prims.len() {
        if counts[prim] == (0, 0) || has_subsets[prim] || geometry.prims[prim].subset_of.is_some() {
            continue;
        }
        let Some(id) = stage.find(&geometry.prims[prim].path) else { continue };
        let mine = |p: u32| p == prim as u32;
        let frame_emitted: Emitted = (
            // Positions and prims only: a whole `Triangle` is rebuilt per read (its flat normal).
            (0..geometry.triangles.len())
                .filter(|&i| mine(geometry.triangles.prim(i)))
                .map(|i| geometry.triangles.positions()[i])
                .collect(),
            geometry.shapes.iter().filter(|s| mine(s.prim)).map(shape_centre).collect(),
        );
        let names = geometry.primvars.names.clone();
        let Some(deformation) =
            deformation_of(stage, id, frame, shutter, options, &names, &frame_emitted, &mut stages, false, diags)
        else {
            continue;
        };
        let (triangles, rest): (Triangles, Triangles) =
            std::mem::take(&mut geometry.triangles).into_iter().partition(|t| mine(t.prim));
        geometry.triangles = rest;
        let (shapes, rest): (Vec<_>, Vec<_>) =
            std::mem::take(&mut geometry.shapes).into_iter().partition(|s| mine(s.prim));
        geometry.shapes = rest;
        let mut proto = Prototype { prims: 1, ..Prototype::default() };
        proto.triangles = triangles.into_iter().map(|t| Triangle { prim: 0, ..t }).collect();
        proto.shapes = shapes
            .into_iter()
            .map(|mut s| {
                s.prim = 0;
                s
            })
            .collect();
        proto.bounds = keyed_bounds(&proto, &deformation);
        proto.deformation = Some(deformation);
        geometry.prototypes.push(proto);
        let prims = geometry.instance_prims.len() as u32;
        geometry.instance_prims.push(prim as u32);
        let prototype = geometry.prototypes.len() as u32 - 1;
        geometry.instances.push(InstanceDesc { to_world: DMat4::IDENTITY, prototype, prims });
        // The keys hold its placement already: it is placed by no prim that could move it again.
        geometry.instance_placers.push(crate::scene::PrimId(u32::MAX));
        deformed += 1;
    }
    // Deforming prims the build made prototypes of their own: keyed in their own space (their
    // instance's placement keys move them).
    let deforming = geometry.deforming.clone();
    let names = geometry.primvars.names.clone();
    let own =
        geometry.prototypes.iter_mut().enumerate().filter_map(|(index, proto)| {
            deforming.iter().find(|d| d.prototype as usize == index).map(|d| (d.id, proto))
        });
    deformed + key_own_prototypes(own, stage, frame, shutter, options, &names, &mut stages, diags)
}

/// Keys each `(prim, prototype)` of `prototypes` — deforming world prims the build made
/// prototypes of their own, built at the stage's time — over `shutter` in their own space,
/// as a build keys them (see [`deformation_of`]), and bounds them over every key; returns
/// how many deform. `names`: the primvar table's names. A scene moved to a new time code
/// builds those prototypes again and keys them here, since their keys are the frame's.
pub fn key_deforming_prototypes<'a>(
    prototypes: impl Iterator<Item = (crate::scene::PrimId, &'a mut Prototype)>,
    stage: &Stage,
    shutter: Shutter,
    options: GeometryOptions,
    names: &[String],
    diags: &mut Diagnostics,
) -> usize {
    let TimeCode::At(frame) = stage.time() else { return 0 };
    if !shutter.is_open() {
        return 0;
    }
    key_own_prototypes(prototypes, stage, frame, shutter, options, names, &mut StagesAt::new(), diags)
}

/// [`key_deforming_prototypes`] at `frame`, sharing the stage copies of `stages`. Those
/// with GeomSubsets (more than one prim) are left to transform blur.
#[allow(clippy::too_many_arguments)]
fn key_own_prototypes<'a>(
    prototypes: impl Iterator<Item = (crate::scene::PrimId, &'a mut Prototype)>,
    stage: &Stage,
    frame: f64,
    shutter: Shutter,
    options: GeometryOptions,
    names: &[String],
    stages: &mut StagesAt,
    diags: &mut Diagnostics,
) -> usize {
    let mut deforming = 0;
    for (id, proto) in prototypes {
        if proto.prims != 1 || proto.deformation.is_some() {
            continue;
        }
        let frame_emitted: Emitted =
            (proto.triangles.iter().map(|t| t.p).collect(), proto.shapes.iter().map(shape_centre).collect());
        let Some(deformation) =
            deformation_of(stage, id, frame, shutter, options, names, &frame_emitted, stages, true, diags)
        else {
            continue;
        };
        proto.bounds = keyed_bounds(proto, &deformation);
        proto.deformation = Some(deformation);
        deforming += 1;
    }
    deforming
}

/// The bounds of `proto` over every key of `deformation` (the frame's positions need not be
/// inside the shutter).
fn keyed_bounds(proto: &Prototype, deformation: &Deformation) -> Option<(DVec3, DVec3)> {
    let boxes = (0..proto.triangles.len())
        .map(|i| deformation.bounds(i))
        .chain(proto.shapes.iter().enumerate().map(|(j, s)| deformation.shape_bounds(j, s.world_bounds())));
    boxes.reduce(|(a, b), (c, d)| (a.min(c), b.max(d))).map(|(lo, hi)| (lo.as_dvec3(), hi.as_dvec3()))
}

/// Warns once for each light of `lights` (prim paths) that moves or changes while `shutter`
/// is open at the stage's time: lights are not motion-blurred, each shines from where it is
/// at the frame.
pub fn report_moving_lights<'a>(
    stage: &Stage,
    lights: impl Iterator<Item = &'a str>,
    shutter: Shutter,
    diags: &mut Diagnostics,
) {
    let TimeCode::At(frame) = stage.time() else { return };
    if !shutter.is_open() {
        return;
    }
    let (a, b) = (shutter.time(frame, 0.0), shutter.time(frame, 1.0));
    let mut seen = std::collections::HashSet::new();
    for path in lights {
        let Some(id) = stage.find(path) else { continue };
        if !seen.insert(id) {
            continue;
        }
        let prim = stage.prim(id);
        let changes = prim.attributes.iter().find(|attr| {
            !attr.time_samples.is_empty() && {
                let at = attr.value_at(TimeCode::At(frame));
                [a, b]
                    .iter()
                    .chain(attr.time_samples.iter().map(|(t, _)| t).filter(|&&t| t > a && t < b))
                    .any(|&t| attr.value_at(TimeCode::At(t)) != at)
            }
        });
        if placement_motion(stage, id, frame, shutter).is_some() || changes.is_some() {
            let mut warning = Diagnostic::warning(format!(
                "light `{path}` moves or changes while the shutter is open; lights are not motion-blurred: \
                 it shines as it is at the frame"
            ));
            if let Some(attr) = changes {
                warning = warning.at(crate::render::geometry::xform::value_span(attr), "sampled here");
            } else {
                warning = warning.at(prim.span, "this light");
            }
            diags.push(warning);
        }
    }
}

/// The keys of every instance whose placing prim (`placers`, per instance) moves within
/// `shutter` at the stage's time, by index in `instances` (empty when the shutter is closed).
pub fn instance_motion(
    stage: &Stage,
    placers: &[crate::scene::PrimId],
    instances: &[InstanceDesc],
    shutter: Shutter,
) -> Vec<(u32, MotionKeys)> {
    let TimeCode::At(frame) = stage.time() else { return Vec::new() };
    if !shutter.is_open() {
        return Vec::new();
    }
    let mut memo: HashMap<u32, Option<MotionKeys>> = HashMap::new();
    let mut motion = Vec::new();
    let mut points_keyed: Option<crate::scene::PrimId> = None;
    for (i, placer) in placers.iter().enumerate() {
        if placer.0 as usize >= stage.len() || points_keyed == Some(*placer) {
            continue;
        }
        if let Some(keys) = point_motion(stage, *placer, frame, shutter) {
            // A point instancer's instances are consecutive, in point order.
            let run = placers[i..].iter().take_while(|&p| p == placer).count();
            if keys.len() == run {
                // A point that stays put keeps its frame transform (and draws no time).
                let moving = keys.into_iter().enumerate().filter(|(_, k)| !k.is_constant(&k.transforms[0]));
                motion.extend(moving.map(|(j, k)| ((i + j) as u32, k)));
            }
            points_keyed = Some(*placer);
            continue;
        }
        let keys = memo.entry(placer.0).or_insert_with(|| placement_motion(stage, *placer, frame, shutter));
        if let Some(keys) = keys {
            motion.push((i as u32, keys.then(DAffine3::from_mat4(instances[i].to_world))));
        }
    }
    motion
}

/// The keys of each visible point of point instancer `id` over `shutter` at frame `frame`
/// (USD's instance transforms at every key: positions interpolated or moved by their
/// velocities, orientations slerped, the instancer's own placement), when any point
/// attribute is sampled; `None` otherwise (the instancer's placement keys its instances then).
fn point_motion(stage: &Stage, id: crate::scene::PrimId, frame: f64, shutter: Shutter) -> Option<Vec<MotionKeys>> {
    let prim = stage.prim(id);
    if prim.type_name.as_deref() != Some("PointInstancer") {
        return None;
    }
    let mut times = transform_sample_times(stage, id);
    let mut sampled = false;
    for name in crate::render::geometry::builder::POINT_MOTION_ATTRIBUTES {
        if let Some(attr) = prim.attribute(name).filter(|a| !a.time_samples.is_empty()) {
            sampled = true;
            times.extend(attr.time_samples.iter().map(|(t, _)| *t));
        }
    }
    if !sampled {
        return None;
    }
    let at = |t: f64| {
        let instancer = world_transform_at(stage, id, t, &mut Diagnostics::new());
        crate::render::geometry::point_instance_transforms_at(stage, id, instancer, t).unwrap_or_default()
    };
    let (a, b) = (shutter.time(frame, 0.0), shutter.time(frame, 1.0));
    Some(MotionKeys::sample_all(&at, a, b, &times))
}

/// What [`apply`] made move.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MotionStats {
    /// Renderable prims of the world moved into instances of their own.
    pub moving_prims: usize,
    /// Of those, meshes that deform (their points are sampled inside the shutter).
    pub deforming_prims: usize,
    /// Instances (of those and of instancing) with keyed transforms.
    pub moving_instances: usize,
}

/// Makes what moves within `shutter` at the stage's time move: world prims whose placement
/// changes become instances of their own geometry (built at the frame, so the keys are
/// relative to it), and instances whose placing prim moves get keys. Returns the keys of each
/// moving instance (by index in `geometry.instances`). Nothing changes when the shutter is
/// closed, the stage is not at a numeric time, or nothing moves.
pub fn apply(
    geometry: &mut Geometry,
    stage: &Stage,
    shutter: Shutter,
    options: GeometryOptions,
    diags: &mut Diagnostics,
) -> (Vec<(u32, MotionKeys)>, MotionStats) {
    let mut stats = MotionStats::default();
    let TimeCode::At(frame) = stage.time() else { return (Vec::new(), stats) };
    if !shutter.is_open() {
        return (Vec::new(), stats);
    }
    stats.deforming_prims = deform(geometry, stage, frame, shutter, options, diags);
    let mut motion = instance_motion(stage, &geometry.instance_placers, &geometry.instances, shutter);
    let mut memo: HashMap<u32, Option<MotionKeys>> = HashMap::new();
    let mut keys_of = |id: crate::scene::PrimId| {
        memo.entry(id.0).or_insert_with(|| placement_motion(stage, id, frame, shutter)).clone()
    };
    // World prims that move: each prim's triangles and shapes become a prototype of one prim.
    let moving: Vec<Option<MotionKeys>> = geometry
        .prims
        .iter()
        .map(|p| {
            // A prim made of triangles outside the world (only instanced) moves with its
            // instance; a deforming one has left the world with its placement in its keys.
            stage.find(&p.path).and_then(&mut keys_of)
        })
        .collect();
    if moving.iter().all(Option::is_none) {
        stats.moving_instances = motion.len();
        return (motion, stats);
    }
    let mut prototype_of: Vec<Option<u32>> = vec![None; moving.len()];
    let first_new = geometry.prototypes.len();
    let mut claim = |prim: u32, geometry: &mut Geometry| -> Option<usize> {
        moving[prim as usize].as_ref()?;
        let p = *prototype_of[prim as usize].get_or_insert_with(|| {
            geometry.prototypes.push(Prototype { prims: 1, ..Prototype::default() });
            geometry.prototypes.len() as u32 - 1
        });
        Some(p as usize)
    };
    let triangles = std::mem::take(&mut geometry.triangles);
    for mut t in triangles {
        match claim(t.prim, geometry) {
            Some(p) => {
                t.prim = 0;
                geometry.prototypes[p].triangles.push(t);
            }
            None => geometry.triangles.push(t),
        }
    }
    let shapes = std::mem::take(&mut geometry.shapes);
    for mut s in shapes {
        match claim(s.prim, geometry) {
            Some(p) => {
                s.prim = 0;
                geometry.prototypes[p].shapes.push(s);
            }
            None => geometry.shapes.push(s),
        }
    }
    for (prim, p) in prototype_of.iter().enumerate() {
        let Some(p) = *p else { continue };
        let proto = &mut geometry.prototypes[p as usize];
        proto.bounds = bounds_of(&proto.triangles, &proto.shapes);
        let prims = geometry.instance_prims.len() as u32;
        geometry.instance_prims.push(prim as u32);
        let keys = moving[prim].clone().expect("only moving prims have prototypes");
        motion.push((geometry.instances.len() as u32, keys));
        geometry.instances.push(InstanceDesc { to_world: DMat4::IDENTITY, prototype: p, prims });
        // Their placer is the prim itself (read again by a later `apply` of the same build).
        geometry.instance_placers.push(stage.find(&geometry.prims[prim].path).expect("found above"));
        stats.moving_prims += 1;
    }
    debug_assert!(geometry.prototypes.len() >= first_new);
    stats.moving_instances = motion.len();
    (motion, stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_follow_a_rotation_and_not_a_translation() {
        let slide = |t: f64| DMat4::from_translation(DVec3::new(t, 0.0, 0.0));
        let keys = MotionKeys::sample(&slide, 0.0, 1.0, &[]);
        assert_eq!(keys.times(), [0.0, 1.0], "a translation is linear: no key between the ends");
        let turn = |t: f64| DMat4::from_rotation_z(t * std::f64::consts::FRAC_PI_2);
        let keys = MotionKeys::sample(&turn, 0.0, 1.0, &[]);
        assert!(keys.times().len() > 8, "{}", keys.times().len());
        for k in 0..=100 {
            let tau = k as f32 / 100.0;
            let got = DMat4::from(keys.at(tau));
            let want = turn(tau as f64);
            let err = (got - want).to_cols_array().iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(err < 1e-4, "{tau}: {err}");
        }
        // Authored sample times inside the interval are keys; those outside are not.
        let keys = MotionKeys::sample(&slide, 0.0, 2.0, &[-1.0, 0.5, 3.0]);
        assert_eq!(keys.times(), [0.0, 0.25, 1.0]);
    }

    #[test]
    fn bounds_cover_every_time() {
        let turn = |t: f64| DMat4::from_translation(DVec3::new(3.0 * t, 0.0, 0.0)) * DMat4::from_rotation_y(t * 2.0);
        let keys = MotionKeys::sample(&turn, 0.0, 1.0, &[]);
        let (lo, hi) = keys.bounds(DVec3::splat(-1.0), DVec3::splat(1.0));
        for k in 0..=1000 {
            let m = keys.at(k as f32 / 1000.0);
            for corner in 0..8 {
                let c = DVec3::new(
                    if corner & 1 == 0 { -1.0 } else { 1.0 },
                    if corner & 2 == 0 { -1.0 } else { 1.0 },
                    if corner & 4 == 0 { -1.0 } else { 1.0 },
                );
                let p = m.transform_point3(c);
                assert!(p.cmpge(lo - 1e-12).all() && p.cmple(hi + 1e-12).all(), "{p} outside {lo}..{hi}");
            }
        }
    }
}
