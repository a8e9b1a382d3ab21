//! The walk over a composed stage that builds [`Geometry`]: renderable prims, instanceable
//! subtrees and PointInstancers turned into prototypes and instances, GeomSubset bindings,
//! extent checks and the budgets.

use super::emit::{Emitter, emit_prim, span_of};
use super::*;
use crate::scene::TimeCode;

/// Builds the triangles of every visible renderable prim of `stage`.
pub fn build(stage: &Stage, diags: &mut Diagnostics) -> Geometry {
    let xforms = world_transforms(stage, diags);
    build_with(stage, &xforms, diags)
}

/// As [`build`], with transforms already computed.
pub fn build_with(stage: &Stage, xforms: &[PrimXform], diags: &mut Diagnostics) -> Geometry {
    build_within(stage, xforms, GeometryOptions::default(), MAX_TRIANGLES, &[], diags)
}

/// As [`build_with`], with options.
pub fn build_with_options(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    diags: &mut Diagnostics,
) -> Geometry {
    build_within(stage, xforms, options, MAX_TRIANGLES, &[], diags)
}

/// As [`build_with_options`], storing the primvars named in `primvars` (without
/// `primvars:`) for shading: those the scene's materials read.
pub fn build_with_primvars(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    primvars: &[String],
    diags: &mut Diagnostics,
) -> Geometry {
    build_within(stage, xforms, options, MAX_TRIANGLES, primvars, diags)
}

/// As [`build_with_primvars`], for a render scene: a world prim whose placement is animated
/// (its xformOps or an ancestor's have time samples) becomes an instance of its own geometry,
/// built in its object space, so another time code moves the instance and keeps its BVH; a
/// world prim that deforms ([`deforms`]) becomes one too ([`Geometry::deforming`]), so
/// another time code builds only its BVH again. Both stay in world space when
/// `stays_in_world` holds for them (their material displaces or emits: dicing and light
/// sampling work on world triangles).
pub fn build_for_render(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    primvars: &[String],
    stays_in_world: &dyn Fn(&Prim) -> bool,
    diags: &mut Diagnostics,
) -> Geometry {
    build_from(Builder::new(stage, xforms, options, MAX_TRIANGLES, primvars, Some(stays_in_world)), diags)
}

/// Whether world prim `id`'s shape changes with time: its `points` have time samples, or it
/// is skinned and something that poses it is sampled (its skeleton, its animation, its own
/// placement, which skinning ignores: its posed points in its own space change when it moves).
pub fn deforms(stage: &Stage, id: PrimId, prim: &Prim) -> bool {
    prim.attribute("points").is_some_and(|a| !a.time_samples.is_empty()) || skinned_and_animated(stage, id)
}

fn skinned_and_animated(stage: &Stage, id: PrimId) -> bool {
    crate::render::geometry::skel::skinning_sample_times(stage, id)
        .is_some_and(|t| !t.is_empty() || !transform_sample_times(stage, id).is_empty())
}

/// The prototype a render build ([`build_for_render`]) makes of deforming world prim `id`
/// ([`Geometry::deforming`]) at the stage's time, bit for bit: `move_to` builds only its BVH
/// again. `None` when it is hidden or no longer renderable. Materials must read no primvars
/// (the build stores those in one table for the whole scene).
pub fn deforming_prototype(
    stage: &Stage,
    xforms: &[PrimXform],
    id: PrimId,
    options: GeometryOptions,
    diags: &mut Diagnostics,
) -> Option<Prototype> {
    let prim = stage.prim(id);
    if xforms[id.0 as usize].hidden || !is_renderable(prim) {
        return None;
    }
    let mut b = Builder::new(stage, xforms, options, MAX_TRIANGLES, &[], None);
    let world = xforms[id.0 as usize].world;
    let posed = crate::render::geometry::skel::posed_prim(stage, xforms, prim, world, diags);
    Some(b.own_prototype(posed.as_ref().unwrap_or(prim), diags).0)
}

/// What a prim is to instancing.
#[derive(Clone, Copy, PartialEq)]
enum Role {
    /// Ordinary: rendered where it is.
    Plain,
    /// The outermost `instanceable` prim of its branch: its subtree is one instance.
    InstanceRoot,
    /// A PointInstancer outside any instance: its subtree holds prototypes, drawn only
    /// through it.
    PointInstancer,
}

/// The state of one geometry build.
struct Builder<'s> {
    stage: &'s Stage,
    /// For a render scene ([`build_for_render`]): which animated world prims keep world space.
    stays_in_world: Option<&'s dyn Fn(&Prim) -> bool>,
    xforms: &'s [PrimXform],
    geometry: Geometry,
    budget: usize,
    /// Renderable prim index by path (prototypes of several point instancers share theirs).
    prim_index: HashMap<String, u32>,
    /// Prototype index by key (see [`prototype_key`], and `pi:<prim id>` for point
    /// instancer prototypes), with the start of its prim table for shared tables.
    prototype_of: HashMap<String, (u32, u32)>,
    /// Stop: the triangle budget was exceeded (reported once).
    over_budget: bool,
    /// Instances skipped because their transform is singular (a zero scale).
    singular_instances: usize,
    /// Subdivision levels for subdivision-surface meshes.
    subdiv_level: u32,
    /// The most instances that fit: [`MAX_INSTANCES`], or fewer by the memory budget.
    max_instances: usize,
}

/// As [`build_with`], with a triangle budget other than [`MAX_TRIANGLES`] (for tests).
pub(super) fn build_within(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    budget: usize,
    primvars: &[String],
    diags: &mut Diagnostics,
) -> Geometry {
    build_from(Builder::new(stage, xforms, options, budget, primvars, None), diags)
}

/// The geometry of every visible renderable prim of `b`'s stage, built by `b`.
fn build_from(mut b: Builder<'_>, diags: &mut Diagnostics) -> Geometry {
    let (stage, xforms) = (b.stage, b.xforms);
    // Roles: an `instanceable` prim inside another instance is part of that instance's
    // prototype (nested instancing is flattened into it).
    let mut role = vec![Role::Plain; stage.len()];
    let mut inside = vec![false; stage.len()];
    for (id, prim) in stage.depth_first() {
        let i = id.0 as usize;
        inside[i] = prim.parent.is_some_and(|p| inside[p.0 as usize] || role[p.0 as usize] != Role::Plain);
        if !inside[i] {
            if prim.type_name.as_deref() == Some("PointInstancer") {
                role[i] = Role::PointInstancer;
            } else if prim.instanceable {
                role[i] = Role::InstanceRoot;
            }
        }
    }
    // Instance roots whose prototype occurs once are flattened: an instance costs a
    // top-level traversal and a ray transform, which only sharing pays for.
    let mut key_of: HashMap<u32, String> = HashMap::new();
    let mut key_count: HashMap<String, usize> = HashMap::new();
    for (id, _) in stage.depth_first() {
        if role[id.0 as usize] == Role::InstanceRoot && !xforms[id.0 as usize].hidden {
            let key = prototype_key(stage, id);
            *key_count.entry(key.clone()).or_default() += 1;
            key_of.insert(id.0, key);
        }
    }
    for (id, prim) in stage.depth_first() {
        let i = id.0 as usize;
        if inside[i] || xforms[i].hidden {
            continue;
        }
        match role[i] {
            Role::Plain => b.world_prim(id, prim, xforms[i].world, diags),
            Role::InstanceRoot => {
                let key = &key_of[&id.0];
                if key_count[key] > 1 {
                    b.instance(id, key, diags);
                } else {
                    for (sub, p) in stage.subtree(id) {
                        let xf = xforms[sub.0 as usize];
                        if !xf.hidden && p.type_name.as_deref() != Some("PointInstancer") {
                            b.world_prim(sub, p, xf.world, diags);
                        } else if !xf.hidden {
                            nested_instancer_warning(p, diags);
                        }
                    }
                }
            }
            Role::PointInstancer => b.point_instancer(id, prim, diags),
        }
        if b.over_budget {
            break;
        }
    }
    if b.singular_instances > 0 {
        diags.push(Diagnostic::warning(format!(
            "{} instance(s) with a singular transform (a zero scale) skipped",
            b.singular_instances
        )));
    }
    let mut geometry = b.geometry;
    geometry.singular_instances = b.singular_instances;
    if geometry.degenerate > 0 {
        diags.push(Diagnostic::warning(format!(
            "{} degenerate (zero-area or non-finite) triangle(s) skipped",
            geometry.degenerate
        )));
    }
    geometry.prototypes.shrink_to_fit();
    geometry
}

fn nested_instancer_warning(prim: &Prim, diags: &mut Diagnostics) {
    diags.push(
        Diagnostic::warning(format!(
            "PointInstancer `{}` inside an instance or a point instancer's prototype is not drawn \
             (nested instancing is not supported)",
            prim.path
        ))
        .at(prim.span, "this instancer"),
    );
}

/// The key under which instances share a prototype: for every prim of the instance's
/// subtree, its path below the root, its type, and where each attribute's value was authored
/// (file and byte offset). Instances that reference one asset compose the same authored
/// values, so they share a key; any local opinion inside an instance makes it a prototype
/// of its own. The root's own transform and visibility belong to the instance, not to the
/// prototype. Values without a source position (none today) are keyed by their content.
pub fn prototype_key(stage: &Stage, root: PrimId) -> String {
    use std::fmt::Write;
    let root_len = stage.prim(root).path.len();
    let mut key = String::new();
    for (id, prim) in stage.subtree(root) {
        let _ = write!(key, "{}|{}|", &prim.path[root_len..], prim.type_name.as_deref().unwrap_or(""));
        for attr in &prim.attributes {
            let placement = attr.name.starts_with("xformOp") || attr.name == "visibility" || attr.name == "purpose";
            if id == root && placement {
                continue;
            }
            match &attr.value {
                Some((_, span)) if span.end > span.start => {
                    let _ = write!(key, "{}@{}:{}:{};", attr.name, span.file.0, span.start, span.end);
                }
                Some((value, _)) => {
                    let _ = write!(key, "{}={value:?};", attr.name);
                }
                None => {
                    let _ = write!(key, "{}!{};", attr.name, attr.blocked);
                }
            }
        }
        key.push('\n');
    }
    key
}

/// Whether a prim itself (not its ancestors) is invisible or a guide/proxy.
fn own_hidden(prim: &Prim) -> bool {
    prim.value("visibility").and_then(Value::as_str) == Some("invisible")
        || matches!(prim.value("purpose").and_then(Value::as_str), Some("guide" | "proxy"))
}

impl<'s> Builder<'s> {
    /// A build of `stage` (its transforms `xforms`) within `budget` triangles, storing the
    /// primvars named in `primvars`; `stays_in_world` as for [`build_for_render`].
    fn new(
        stage: &'s Stage,
        xforms: &'s [PrimXform],
        options: GeometryOptions,
        budget: usize,
        primvars: &[String],
        stays_in_world: Option<&'s dyn Fn(&Prim) -> bool>,
    ) -> Builder<'s> {
        let mut geometry = Geometry::default();
        geometry.primvars.names = primvars.to_vec();
        geometry.baked = vec![false; stage.len()];
        Builder {
            stage,
            stays_in_world,
            xforms,
            geometry,
            budget,
            prim_index: HashMap::new(),
            prototype_of: HashMap::new(),
            over_budget: false,
            singular_instances: 0,
            subdiv_level: options.subdiv_level,
            max_instances: MAX_INSTANCES
                .min(usize::try_from(crate::input::memory_budget() / INSTANCE_BYTES).unwrap_or(usize::MAX)),
        }
    }

    /// The index of the renderable prim at `prim`'s path, added when new.
    fn prim_index(&mut self, prim: &Prim) -> u32 {
        let prims = &mut self.geometry.prims;
        *self.prim_index.entry(prim.path.clone()).or_insert_with(|| {
            prims.push(GeomPrim {
                path: prim.path.clone(),
                span: prim.span,
                subset_of: None,
                object: ObjectSpace::IDENTITY,
            });
            prims.len() as u32 - 1
        })
    }

    /// Triangles in every buffer, for the budget.
    fn triangles_so_far(&self) -> usize {
        self.geometry.triangles.len() + self.geometry.prototypes.iter().map(|p| p.triangles.len()).sum::<usize>()
    }

    /// A visible renderable prim (or any other prim, which emits nothing) in world space, or
    /// as an instance of its own when its placement is animated (see [`build_for_render`]).
    fn world_prim(&mut self, id: PrimId, prim: &Prim, world: DMat4, diags: &mut Diagnostics) {
        if !is_renderable(prim) {
            return;
        }
        // UsdSkel: a skinned prim is emitted from its posed copy (in its own space).
        let posed = crate::render::geometry::skel::posed_prim(self.stage, self.xforms, prim, world, diags);
        match self.moves_as_instance(id, prim) {
            Some(deforming) => {
                let prototype = self.own_instance(id, posed.as_ref().unwrap_or(prim), world, diags);
                if deforming {
                    let skinned = posed.is_some();
                    self.geometry.deforming.push(Deforming { id, prototype, skinned });
                }
                return;
            }
            None if self.stays_in_world.is_some() && deforms(self.stage, id, prim) => {
                self.geometry.deforming_in_world = true;
            }
            None => {}
        }
        let prim = posed.as_ref().unwrap_or(prim);
        // Its world transform is in its triangles: a change of it or an ancestor's rebuilds them.
        self.bake(id, None);
        let index = self.prim_index(prim);
        let object = ObjectSpace::new(world);
        self.geometry.prims[index as usize].object = object;
        // GeomSubset material bindings: their faces are renderable prims of their own, so
        // each gets its composed material.
        let face_prims = if prim.type_name.as_deref() == Some("Mesh") {
            let stage = self.stage;
            material_subsets(
                stage,
                prim,
                index,
                &mut |subset| {
                    let subset_index = self.prim_index(subset);
                    self.geometry.prims[subset_index as usize].subset_of = Some(index);
                    self.geometry.prims[subset_index as usize].object = object;
                    subset_index
                },
                diags,
            )
        } else {
            Vec::new()
        };
        let mut buffers = (std::mem::take(&mut self.geometry.triangles), std::mem::take(&mut self.geometry.shapes));
        self.emit(prim, &mut buffers, world, index, face_prims, diags);
        (self.geometry.triangles, self.geometry.shapes) = buffers;
    }

    /// Emits `prim` into `buffers` (triangles, shapes) by `world` as prim `index` (its faces
    /// as `face_prims` say), within what the budget leaves beside the triangles stored
    /// elsewhere, and reports what went wrong.
    fn emit(
        &mut self,
        prim: &Prim,
        buffers: &mut (Triangles, Vec<Shape>),
        world: DMat4,
        index: u32,
        face_prims: Vec<u32>,
        diags: &mut Diagnostics,
    ) {
        let others = self.triangles_so_far();
        let g = &mut self.geometry;
        let mut out = Emitter::new(
            &mut buffers.0,
            &mut buffers.1,
            &mut g.degenerate,
            &mut g.primvars,
            world,
            index,
            self.budget - others.min(self.budget),
        );
        out.subdiv_level = self.subdiv_level;
        out.face_prims = face_prims;
        emit_prim(prim, &mut out, diags);
        let small = out.too_small.map(|(n, p, e)| (n, p, e, out.emitted));
        let (beyond, over) = (out.beyond_extent, out.over_budget);
        self.report(prim, beyond, over, small, diags);
    }

    /// Whether world prim `id` is built as an instance of its own (see [`build_for_render`]):
    /// `Some(true)` because it deforms, `Some(false)` because only its placement moves.
    fn moves_as_instance(&self, id: PrimId, prim: &Prim) -> Option<bool> {
        let stays_in_world = self.stays_in_world?;
        let deforming = deforms(self.stage, id, prim);
        let moves = deforming || !transform_sample_times(self.stage, id).is_empty();
        (moves && !stays_in_world(prim)).then_some(deforming)
    }

    /// Marks the prims whose transforms a BLAS holds baked in for prim `id`: it and its
    /// ancestors up to `root` (exclusive; `None`: every ancestor).
    fn bake(&mut self, id: PrimId, root: Option<PrimId>) {
        let mut at = Some(id);
        while let Some(p) = at.filter(|&p| Some(p) != root) {
            self.geometry.baked[p.0 as usize] = true;
            at = self.stage.prim(p).parent;
        }
    }

    /// World prim `id` as a prototype of its own (its GeomSubsets' prims included), built in
    /// its object space and placed by its world transform; returns the prototype's index.
    fn own_instance(&mut self, id: PrimId, prim: &Prim, world: DMat4, diags: &mut Diagnostics) -> u32 {
        let (proto, members) = self.own_prototype(prim, diags);
        self.geometry.prototypes.push(proto);
        let prototype = self.geometry.prototypes.len() as u32 - 1;
        let start = self.geometry.instance_prims.len() as u32;
        self.geometry.instance_prims.extend(members);
        self.place(id, prototype, start, world, None, diags);
        prototype
    }

    /// `prim` built in its object space as a prototype of its own (its GeomSubsets' prims
    /// included, numbered after it), and the renderable prims of its prim table.
    fn own_prototype(&mut self, prim: &Prim, diags: &mut Diagnostics) -> (Prototype, Vec<u32>) {
        let stage = self.stage;
        let index = self.prim_index(prim);
        let mut members = vec![index];
        let face_prims = if prim.type_name.as_deref() == Some("Mesh") {
            material_subsets(
                stage,
                prim,
                0,
                &mut |subset| {
                    let subset_index = self.prim_index(subset);
                    self.geometry.prims[subset_index as usize].subset_of = Some(index);
                    members.push(subset_index);
                    members.len() as u32 - 1
                },
                diags,
            )
        } else {
            Vec::new()
        };
        let mut buffers = (Triangles::new(), Vec::new());
        self.emit(prim, &mut buffers, DMat4::IDENTITY, 0, face_prims, diags);
        let mut proto = Prototype { triangles: buffers.0, shapes: buffers.1, ..Prototype::default() };
        proto.prims = members.len() as u32;
        proto.prim_spaces = vec![ObjectSpace::IDENTITY; members.len()];
        proto.bounds = bounds_of(&proto.triangles, &proto.shapes);
        (proto, members)
    }

    /// Reports a prim past the extent or the budget, or with triangles too small to intersect.
    fn report(
        &mut self,
        prim: &Prim,
        beyond: Option<DVec3>,
        over_budget: bool,
        too_small: Option<(usize, DVec3, f64, usize)>,
        diags: &mut Diagnostics,
    ) {
        if over_budget && !self.over_budget {
            self.over_budget = true;
            diags.push(
                Diagnostic::error(format!(
                    "the scene has more than {} triangles; `{}` and the prims after it do not fit",
                    self.budget, prim.path
                ))
                .at(prim.span, "the first prim past the triangle budget")
                .note("instanced geometry counts once per prototype"),
            );
        }
        if let Some(p) = beyond {
            diags.push(beyond_extent(self.stage, prim, p));
        }
        if let Some((count, p, edge, kept)) = too_small {
            // A few micro-triangles in a mesh (CAD exports have them) cannot be seen at any
            // sane camera distance: skipped with a warning. A prim made only of them would
            // vanish: that is an error.
            let message = format!(
                "`{}` has {count} triangle(s) below the f32 intersection's resolution: the first, at ({:.3e}, {:.3e}, \
                 {:.3e}), spans only {edge:.1e} units (at least {MIN_TRIANGLE_EDGE:e} needed)",
                prim.path, p.x, p.y, p.z
            );
            let d = if kept == 0 {
                Diagnostic::error(message).at(prim.span, "this prim would vanish")
            } else {
                Diagnostic::warning(message + &format!("; they are skipped, {kept} others render"))
                    .at(prim.span, "this prim")
            };
            diags.push(d.note("scale the scene up (a scale transform on its root); radiance does not depend on scale"));
        }
    }

    /// The prototype built from the subtree at `root`, its geometry relative to the root
    /// (the root's own transform excluded), prims numbered locally in subtree order; and the
    /// renderable prims of that subtree in the same order.
    fn build_prototype(&mut self, root: PrimId, diags: &mut Diagnostics) -> (Prototype, Vec<PrimId>) {
        let stage = self.stage;
        let mut proto = Prototype::default();
        let mut members = Vec::new();
        let mut rel: HashMap<u32, (DMat4, bool)> = HashMap::new();
        let root_world = self.xforms[root.0 as usize].world;
        let mut scratch = Diagnostics::new();
        for (id, prim) in stage.subtree(root) {
            let parent = prim.parent.filter(|_| id != root).and_then(|p| rel.get(&p.0).copied());
            let (m, hidden) = match parent {
                None => (DMat4::IDENTITY, own_hidden(prim)),
                Some((pm, ph)) => {
                    // Transforms already diagnosed by `world_transforms`.
                    let (local, reset) = local_transform(prim, &mut scratch);
                    // Its transform relative to the root is in the prototype's triangles.
                    self.bake(id, if reset { None } else { Some(root) });
                    let m = if reset { root_world.inverse() * self.xforms[id.0 as usize].world } else { pm * local };
                    (m, ph || own_hidden(prim))
                }
            };
            rel.insert(id.0, (m, hidden));
            if hidden {
                continue;
            }
            if id != root && prim.type_name.as_deref() == Some("PointInstancer") {
                nested_instancer_warning(prim, diags);
                continue;
            }
            if !is_renderable(prim) || rel_inside_instancer(stage, root, id) {
                continue;
            }
            if prim.children.iter().any(|&c| is_bound_subset(stage, stage.prim(c))) {
                diags.push(
                    Diagnostic::warning(format!(
                        "mesh `{}` is instanced: its GeomSubset material bindings are not applied (the mesh's own \
                         material is)",
                        prim.path
                    ))
                    .at(prim.span, "inside an instance"),
                );
            }
            let local = members.len() as u32;
            members.push(id);
            proto.prim_spaces.push(ObjectSpace::new(m));
            let others = self.triangles_so_far();
            let mut out = Emitter::new(
                &mut proto.triangles,
                &mut proto.shapes,
                &mut self.geometry.degenerate,
                &mut self.geometry.primvars,
                m,
                local,
                self.budget - others.min(self.budget),
            );
            out.subdiv_level = self.subdiv_level;
            emit_prim(prim, &mut out, diags);
            let small = out.too_small.map(|(n, p, e)| (n, p, e, out.emitted));
            let (beyond, over) = (out.beyond_extent, out.over_budget);
            self.report(prim, beyond, over, small, diags);
        }
        proto.prims = members.len() as u32;
        proto.bounds = bounds_of(&proto.triangles, &proto.shapes);
        (proto, members)
    }

    /// An instanceable prim whose prototype other instances share.
    fn instance(&mut self, root: PrimId, key: &str, diags: &mut Diagnostics) {
        let stage = self.stage;
        let (prototype, members) = match self.prototype_of.get(key) {
            Some(&(p, _)) => {
                // The same key means the same renderable prims in the same order.
                let members = renderable_members(stage, root);
                (p, members)
            }
            None => {
                let (proto, members) = self.build_prototype(root, diags);
                self.geometry.prototypes.push(proto);
                let p = self.geometry.prototypes.len() as u32 - 1;
                self.prototype_of.insert(key.to_string(), (p, u32::MAX));
                (p, members)
            }
        };
        // This instance's own prims: each composes its own materials (slots are inherited
        // down the instance's own path), while the geometry is shared.
        let start = self.geometry.instance_prims.len() as u32;
        for (j, id) in members.into_iter().enumerate() {
            let index = self.prim_index(stage.prim(id));
            self.geometry.instance_prims.push(index);
            self.geometry.prims[index as usize].object =
                self.geometry.prototypes[prototype as usize].prim_spaces.get(j).copied().unwrap_or_default();
        }
        let to_world = self.xforms[root.0 as usize].world;
        self.place(root, prototype, start, to_world, None, diags);
    }

    /// Adds an instance after checking that it lies within the extent.
    fn place(
        &mut self,
        placer: PrimId,
        prototype: u32,
        prims: u32,
        to_world: DMat4,
        which: Option<(usize, Span)>,
        diags: &mut Diagnostics,
    ) -> bool {
        let Some((lo, hi)) = self.geometry.prototypes[prototype as usize].bounds else { return true };
        let prim = self.stage.prim(placer);
        let (wlo, whi) = crate::render::geometry::shapes::transformed_box(&to_world, lo, hi);
        if let Some(far) = [wlo, whi].into_iter().find(|w| !w.is_finite() || w.abs().max_element() > MAX_EXTENT) {
            let mut d = beyond_extent(self.stage, prim, far);
            if let Some((i, span)) = which {
                d = d.also(span, format!("instance {i}"));
            }
            diags.push(d);
            return false;
        }
        let placed = self.geometry.instances.len();
        if placed >= self.max_instances {
            let why = if placed >= MAX_INSTANCES {
                format!("the scene has more than {MAX_INSTANCES} instances")
            } else {
                instance_memory(placed + 1)
                    .err()
                    .unwrap_or_else(|| format!("{placed} instances fill the memory budget"))
            };
            let mut d = Diagnostic::error(format!("{why}; `{}` and the instances after it do not fit", prim.path))
                .at(prim.span, "the first prim past the instance budget");
            if let Some((i, span)) = which {
                d = d.also(span, format!("instance {i}"));
            }
            diags.push(d);
            // Stops the build: one error, bounded memory.
            self.over_budget = true;
            return false;
        }
        let det = DMat3::from_mat4(to_world).determinant();
        if det == 0.0 || !det.is_finite() {
            // Flat in some direction: as a flattened copy's triangles would be, degenerate.
            self.singular_instances += 1;
            return true;
        }
        self.geometry.instances.push(InstanceDesc { to_world, prototype, prims });
        self.geometry.instance_placers.push(placer);
        true
    }
}

/// The visible renderable prims of the subtree at `root` that a prototype built from it
/// holds, in subtree order (as [`Builder::build_prototype`] numbers them).
fn renderable_members(stage: &Stage, root: PrimId) -> Vec<PrimId> {
    let mut hidden: HashMap<u32, bool> = HashMap::new();
    let mut out = Vec::new();
    for (id, prim) in stage.subtree(root) {
        let parent = prim.parent.filter(|_| id != root).and_then(|p| hidden.get(&p.0).copied()).unwrap_or(false);
        let h = parent || own_hidden(prim);
        hidden.insert(id.0, h);
        if !h
            && is_renderable(prim)
            && (id == root || prim.type_name.as_deref() != Some("PointInstancer"))
            && !rel_inside_instancer(stage, root, id)
        {
            out.push(id);
        }
    }
    out
}

/// Whether `id` lies under a PointInstancer strictly between `root` and itself (a nested
/// instancer's prototypes are not drawn).
fn rel_inside_instancer(stage: &Stage, root: PrimId, id: PrimId) -> bool {
    if id == root {
        return false;
    }
    let mut p = stage.prim(id).parent;
    while let Some(pid) = p {
        if pid == root {
            return false;
        }
        let prim = stage.prim(pid);
        if prim.type_name.as_deref() == Some("PointInstancer") {
            return true;
        }
        p = prim.parent;
    }
    false
}

/// The error for a prim whose geometry reaches `p`, beyond [`MAX_EXTENT`].
fn beyond_extent(stage: &Stage, prim: &Prim, p: DVec3) -> Diagnostic {
    // 1e38 reads better than its 39 digits.
    let coordinate = |x: f64| if x.abs() < 1e6 { format!("{x}") } else { format!("{x:e}") };
    let mut d = Diagnostic::error(format!(
        "`{}` reaches ({}, {}, {}), beyond the scene extent of ±{MAX_EXTENT:e} units",
        prim.path,
        coordinate(p.x),
        coordinate(p.y),
        coordinate(p.z)
    ))
    .at(prim.span, "this prim");
    // Point at the nearest transform that placed it, when one did.
    let mut placed_by = Some(prim);
    while let Some(p) = placed_by {
        if let Some(order) = p.attribute("xformOpOrder") {
            d = d.also(value_span(order), "placed by this transform (with its ancestors')");
            break;
        }
        placed_by = p.parent.map(|id| stage.prim(id));
    }
    d.note("strata renders in f32: coordinates must be finite and within ±1e7 after transforms")
}

/// The GeomSubsets of `mesh` that bind materials to faces ([`is_bound_subset`]): the prim
/// index of every face (`base`, the mesh's own, or the subset's from `index_of`), empty when
/// there are none. Indices outside the mesh's faces are errors; a face in two subsets (the
/// `materialBind` family must not overlap) warns and keeps the first.
fn material_subsets(
    stage: &Stage,
    mesh: &Prim,
    base: u32,
    index_of: &mut dyn FnMut(&Prim) -> u32,
    diags: &mut Diagnostics,
) -> Vec<u32> {
    let subsets: Vec<&Prim> =
        mesh.children.iter().map(|&c| stage.prim(c)).filter(|p| is_bound_subset(stage, p)).collect();
    if subsets.is_empty() {
        return Vec::new();
    }
    let faces = mesh.value("faceVertexCounts").and_then(Value::as_int_array).map_or(0, <[i64]>::len);
    let mut face_prims = vec![base; faces];
    for subset in &subsets {
        let index = index_of(subset);
        let indices = subset.value("indices").and_then(Value::as_int_array).unwrap_or(&[]);
        let span = span_of(subset, "indices");
        if let Some(bad) = indices.iter().find(|&&i| i < 0 || i as usize >= faces) {
            diags.push(
                Diagnostic::error(format!(
                    "GeomSubset `{}`: face index {bad} is outside the mesh's {faces} face(s)",
                    subset.path
                ))
                .at(span, "these indices"),
            );
        }
        let mut shared = 0usize;
        for &i in indices.iter().filter(|&&i| i >= 0 && (i as usize) < faces) {
            let slot = &mut face_prims[i as usize];
            if *slot == base {
                *slot = index;
            } else if *slot != index {
                shared += 1;
            }
        }
        if shared > 0 {
            diags.push(
                Diagnostic::warning(format!(
                    "GeomSubset `{}`: {shared} face(s) are already in an earlier materialBind subset, which keeps them",
                    subset.path
                ))
                .at(span, "overlapping indices")
                .note("the materialBind family of a mesh must not overlap (familyType nonOverlapping or partition)"),
            );
        }
    }
    face_prims
}

/// An error about a PointInstancer attribute (at its value).
/// `Err` with the message when `count` instances do not fit the memory budget.
fn instance_memory(count: usize) -> Result<(), String> {
    let what = format!("{count} instances (about {INSTANCE_BYTES} bytes each with their BVH)");
    crate::input::check_memory(&what, (count as u64).saturating_mul(INSTANCE_BYTES))
}

fn instancer_error(prim: &Prim, name: &str, message: String) -> Diagnostic {
    Diagnostic::error(format!("point instancer `{}`: {message}", prim.path)).at(span_of(prim, name), "here")
}

impl Builder<'_> {
    /// A UsdGeomPointInstancer: each point places one of the `prototypes` targets (with the
    /// prototype root's own transform) by `positions`, `orientations` and `scales`, under the
    /// instancer's transform. Points listed in `invisibleIds` are not drawn.
    fn point_instancer(&mut self, id: PrimId, prim: &Prim, diags: &mut Diagnostics) {
        let stage = self.stage;
        let errors = diags.error_count();
        let targets: Vec<(String, Span)> = prim
            .relationship("prototypes")
            .map(|r| r.targets.iter().map(|(p, s)| (p.clone(), *s)).collect())
            .unwrap_or_default();
        let mut protos = Vec::with_capacity(targets.len());
        for (path, span) in &targets {
            match stage.find(path) {
                Some(p) => protos.push(p),
                None => diags.push(
                    Diagnostic::error(format!("point instancer `{}`: prototype `{path}` does not exist", prim.path))
                        .at(*span, "this target"),
                ),
            }
        }
        let indices = prim.value("protoIndices").and_then(Value::as_int_array).unwrap_or(&[]);
        let n = indices.len();
        let moved = match stage.time() {
            TimeCode::At(t) => point_extrapolation(stage, prim, t),
            TimeCode::Default => PointExtrapolation::default(),
        };
        let tuples = |name: &str, width: usize, diags: &mut Diagnostics| -> Option<&[f64]> {
            let attr = prim.attribute(name)?;
            let value = moved.of(name).or(attr.get());
            let Some((w, data)) = value?.as_tuple_array() else {
                diags.push(instancer_error(prim, name, format!("`{name}` must be an array of {width}-tuples")));
                return None;
            };
            if w != width {
                diags.push(instancer_error(prim, name, format!("`{name}` must be an array of {width}-tuples")));
                return None;
            }
            if data.len() / width != n {
                diags.push(instancer_error(
                    prim,
                    name,
                    format!("`{name}` has {} entries but `protoIndices` has {n}", data.len() / width),
                ));
                return None;
            }
            if let Some(k) = data.iter().position(|x| !x.is_finite()) {
                diags.push(instancer_error(prim, name, format!("`{name}`[{}] is not finite", k / width)));
                return None;
            }
            Some(data)
        };
        let positions = tuples("positions", 3, diags);
        if positions.is_none() && prim.attribute("positions").is_none() && n > 0 {
            diags.push(instancer_error(prim, "protoIndices", format!("{n} instances but no `positions`")));
        }
        // USD reads `orientations` (quath) or, when authored, `orientationsf` (quatf).
        let orient_name = if prim.attribute("orientationsf").is_some() { "orientationsf" } else { "orientations" };
        let orientations = tuples(orient_name, 4, diags);
        let scales = tuples("scales", 3, diags);
        let ids = prim.value("ids").and_then(Value::as_int_array);
        if let Some(ids) = ids
            && ids.len() != n
        {
            diags.push(instancer_error(
                prim,
                "ids",
                format!("`ids` has {} entries but `protoIndices` has {n}", ids.len()),
            ));
        }
        if let Some((k, bad)) = indices.iter().enumerate().find(|&(_, &i)| i < 0 || i as usize >= targets.len()) {
            diags.push(instancer_error(
                prim,
                "protoIndices",
                format!("`protoIndices`[{k}] = {bad} is out of range ({} prototypes)", targets.len()),
            ));
        }
        if let Some(k) = orientations.and_then(|q| q.chunks(4).position(|q| q.iter().all(|&c| c == 0.0))) {
            diags.push(instancer_error(prim, orient_name, format!("`{orient_name}`[{k}] is a zero quaternion")));
        }
        if diags.error_count() > errors || protos.len() != targets.len() {
            return;
        }
        let Some(positions) = positions else { return };
        // Known before any is placed: one error with the whole count, nothing allocated.
        let total = self.geometry.instances.len() + n;
        if total > self.max_instances {
            let message = match instance_memory(total) {
                _ if total > MAX_INSTANCES => {
                    format!("the scene would have {total} instances, more than {MAX_INSTANCES}")
                }
                Err(message) => message,
                Ok(()) => format!("the scene would have {total} instances"),
            };
            diags.push(instancer_error(prim, "protoIndices", message));
            self.over_budget = true;
            return;
        }
        let invisible: HashSet<i64> = prim
            .value("invisibleIds")
            .and_then(Value::as_int_array)
            .map(|v| v.iter().copied().collect())
            .unwrap_or_default();

        // One prototype per target prim, shared by every instancer that targets it; its
        // prims are the prototype's own (all its instances share their materials).
        let mut placed: Vec<(u32, u32, DMat4)> = Vec::with_capacity(protos.len());
        for &proto in &protos {
            let key = format!("pi:{}", proto.0);
            let (p, prims) = match self.prototype_of.get(&key) {
                Some(&entry) => entry,
                None => {
                    let (built, members) = self.build_prototype(proto, diags);
                    self.geometry.prototypes.push(built);
                    let p = self.geometry.prototypes.len() as u32 - 1;
                    let start = self.geometry.instance_prims.len() as u32;
                    for (j, m) in members.into_iter().enumerate() {
                        let index = self.prim_index(stage.prim(m));
                        self.geometry.instance_prims.push(index);
                        self.geometry.prims[index as usize].object =
                            self.geometry.prototypes[p as usize].prim_spaces.get(j).copied().unwrap_or_default();
                    }
                    self.prototype_of.insert(key, (p, start));
                    (p, start)
                }
            };
            // The prototype root's own transform applies under each instance's.
            let (local, _) = local_transform(stage.prim(proto), &mut Diagnostics::new());
            placed.push((p, prims, local));
        }
        let instancer = self.xforms[id.0 as usize].world;
        let positions_span = span_of(prim, "positions");
        for k in 0..n {
            let instance_id = ids.map_or(k as i64, |ids| ids[k]);
            if invisible.contains(&instance_id) {
                continue;
            }
            let (p, prims, local) = placed[indices[k] as usize];
            let m = point_matrix(instancer, positions, orientations, scales, k, local);
            if !self.place(id, p, prims, m, Some((k, positions_span)), diags) {
                // One extent error per instancer is enough.
                break;
            }
        }
    }
}

/// Point `k`'s world transform: `instancer · T R S · local` (column vectors; USD's row
/// vectors read proto · scale · orient · translate), `local` being its prototype root's own.
fn point_matrix(
    instancer: DMat4,
    positions: &[f64],
    orientations: Option<&[f64]>,
    scales: Option<&[f64]>,
    k: usize,
    local: DMat4,
) -> DMat4 {
    let t = DVec3::from_slice(&positions[3 * k..3 * k + 3]);
    // USD writes quaternions (real, i, j, k).
    let r = orientations
        .map_or(DQuat::IDENTITY, |q| DQuat::from_xyzw(q[4 * k + 1], q[4 * k + 2], q[4 * k + 3], q[4 * k]).normalize());
    let s = scales.map_or(DVec3::ONE, |s| DVec3::from_slice(&s[3 * k..3 * k + 3]));
    instancer * DMat4::from_scale_rotation_translation(s, r, t) * local
}

/// The world transform of every visible point of point instancer `id` at the stage's time,
/// in the order a build places them, computed as the build computes them (bit for bit);
/// `None` when its attributes do not make a valid instancer (the build reports why).
pub fn point_instance_transforms(stage: &Stage, xforms: &[PrimXform], id: PrimId) -> Option<Vec<DMat4>> {
    let moved = match stage.time() {
        TimeCode::At(t) => point_extrapolation(stage, stage.prim(id), t),
        TimeCode::Default => PointExtrapolation::default(),
    };
    let read = |attr: &crate::scene::Attribute| moved.of(&attr.name).or(attr.get()).cloned();
    points_placed(stage, id, xforms[id.0 as usize].world, &read)
}

/// [`point_instance_transforms`] at stage time `t` (inside a shutter) with the instancer at
/// `instancer`: every point attribute as USD reads it at `t` (the prototype roots' own
/// transforms are the frame's).
pub fn point_instance_transforms_at(stage: &Stage, id: PrimId, instancer: DMat4, t: f64) -> Option<Vec<DMat4>> {
    let moved = point_extrapolation(stage, stage.prim(id), t);
    let read =
        |attr: &crate::scene::Attribute| moved.of(&attr.name).cloned().or_else(|| attr.value_at(TimeCode::At(t)));
    points_placed(stage, id, instancer, &read)
}

/// The point attributes of a point instancer that can move its instances over time.
pub const POINT_MOTION_ATTRIBUTES: [&str; 7] =
    ["positions", "orientations", "orientationsf", "scales", "velocities", "accelerations", "angularVelocities"];

/// A point instancer's `positions`, orientations and `scales` at a time by USD's rules for
/// velocities ([`point_extrapolation`]); `None` where the authored values are read as any
/// value (interpolated).
#[derive(Debug, Default)]
pub struct PointExtrapolation {
    /// The positions.
    pub positions: Option<Value>,
    /// The orientations, of the attribute USD reads (`orientationsf` when authored).
    pub orientations: Option<(&'static str, Value)>,
    /// The scales.
    pub scales: Option<Value>,
}

impl PointExtrapolation {
    /// The value of attribute `name` this extrapolation replaces, if it does.
    pub fn of(&self, name: &str) -> Option<&Value> {
        match (name, &self.orientations) {
            ("positions", _) => self.positions.as_ref(),
            ("scales", _) => self.scales.as_ref(),
            (name, Some((n, v))) if *n == name => Some(v),
            _ => None,
        }
    }
}

/// An attribute's time samples around `t` as USD brackets them for velocities: the last
/// sample at or before `t` (the first when `t` precedes it), the first after `t` (or that
/// same sample when none follows), and the lower sample's value; `None` without samples.
fn bracket(attr: &crate::scene::Attribute, t: f64) -> Option<(f64, f64, &Value)> {
    let samples = &attr.time_samples;
    let after = samples.partition_point(|(s, _)| *s <= t);
    let (lower, value) = samples.get(after.saturating_sub(1))?;
    let upper = samples.get(after).map_or(*lower, |(s, _)| *s);
    Some((*lower, upper, value))
}

/// The data of `value` when it is an array of `width`-tuples.
fn tuples_of(value: &Value, width: usize) -> Option<&[f64]> {
    value.as_tuple_array().filter(|(w, _)| *w == width).map(|(_, d)| d)
}

/// `positions`, orientations and `scales` of point instancer `prim` at stage time `t` by
/// `UsdGeomPointInstancer::ComputeInstanceTransformsAtTime`'s rules, `t` being also its base
/// time. `velocities` apply when their samples bracket `t` as `positions`' do, with as many
/// entries: the positions of the lower sample move by `v·dt + a·dt²/2`, `a` being
/// `accelerations` bracketed as the velocities are (else 0), `dt = (t − sample) /
/// timeCodesPerSecond`. `angularVelocities` (degrees per second) apply likewise with the
/// orientations: each turns by `|ω|·dt` degrees about `ω`, after its orientation. When either
/// applies, USD reads positions, orientations and scales at their lower sample, not
/// interpolated. All `None` when neither applies.
pub fn point_extrapolation(stage: &Stage, prim: &Prim, t: f64) -> PointExtrapolation {
    let sampled = |name: &str| prim.attribute(name).and_then(|a| bracket(a, t));
    // `name`'s 3-tuples when its samples bracket `t` as `base`'s do, with `count` of them.
    let aligned = |name: &str, base: Option<(f64, f64, &Value)>, count: usize| {
        let (lower, upper, _) = base?;
        let (l, u, value) = sampled(name)?;
        tuples_of(value, 3).filter(|d| (l, u) == (lower, upper) && d.len() == 3 * count)
    };
    let orient_name = if prim.attribute("orientationsf").is_some() { "orientationsf" } else { "orientations" };
    let (positions, orientations) = (sampled("positions"), sampled(orient_name));
    let count = |base: Option<(f64, f64, &Value)>, width| {
        base.and_then(|(_, _, v)| tuples_of(v, width)).map_or(0, <[f64]>::len) / width
    };
    let velocities = aligned("velocities", positions, count(positions, 3));
    let angular = aligned("angularVelocities", orientations, count(orientations, 4));
    if velocities.is_none() && angular.is_none() {
        return PointExtrapolation::default();
    }
    let dt = |sample: f64| (t - sample) / stage.time_codes_per_second();
    let tuples = |data: Vec<f64>, width: usize| Value::TupleArray { width, data: data.into() };
    let positions = positions.map(|(sample, _, value)| {
        let (Some(p), Some(v)) = (tuples_of(value, 3), velocities) else { return value.clone() };
        let a = aligned("accelerations", sampled("velocities"), p.len() / 3);
        let dt = dt(sample);
        tuples((0..p.len()).map(|i| p[i] + dt * (v[i] + a.map_or(0.0, |a| dt * a[i] * 0.5))).collect(), 3)
    });
    let orientations = orientations.map(|(sample, _, value)| {
        let (Some(q), Some(w)) = (tuples_of(value, 4), angular) else { return (orient_name, value.clone()) };
        let dt = dt(sample);
        let turned = q.chunks(4).zip(w.chunks(3)).flat_map(|(q, w)| {
            let w = DVec3::from_slice(w);
            let turn = match w.try_normalize() {
                Some(axis) => DQuat::from_axis_angle(axis, (dt * w.length()).to_radians()),
                None => DQuat::IDENTITY,
            };
            // USD writes quaternions (real, i, j, k).
            let r = turn * DQuat::from_xyzw(q[1], q[2], q[3], q[0]);
            [r.w, r.x, r.y, r.z]
        });
        (orient_name, tuples(turned.collect(), 4))
    });
    let scales = sampled("scales").map(|(_, _, value)| value.clone());
    PointExtrapolation { positions, orientations, scales }
}

/// The world transforms of the visible points of point instancer `id` placed under
/// `instancer`, reading each attribute through `read`.
fn points_placed(
    stage: &Stage,
    id: PrimId,
    instancer: DMat4,
    read: &dyn Fn(&crate::scene::Attribute) -> Option<Value>,
) -> Option<Vec<DMat4>> {
    let prim = stage.prim(id);
    let targets: Vec<PrimId> =
        prim.relationship("prototypes")?.targets.iter().map(|(path, _)| stage.find(path)).collect::<Option<_>>()?;
    let value = |name: &str| prim.attribute(name).and_then(read);
    let indices = value("protoIndices");
    let indices = indices.as_ref().and_then(Value::as_int_array).unwrap_or(&[]);
    let n = indices.len();
    let tuples = |name: &str, width: usize| -> Result<Option<Value>, ()> {
        let Some(value) = value(name) else { return Ok(None) };
        let (w, data) = value.as_tuple_array().ok_or(())?;
        let ok = w == width && data.len() / width == n && data.iter().all(|x| x.is_finite());
        if ok { Ok(Some(value)) } else { Err(()) }
    };
    let positions = tuples("positions", 3).ok()??;
    let orient_name = if prim.attribute("orientationsf").is_some() { "orientationsf" } else { "orientations" };
    let orientations = tuples(orient_name, 4).ok()?;
    let scales = tuples("scales", 3).ok()?;
    fn data(v: &Option<Value>) -> Option<&[f64]> {
        v.as_ref().and_then(Value::as_tuple_array).map(|(_, d)| d)
    }
    let positions = Some(positions);
    let (positions, orientations_data, scales) = (data(&positions)?, data(&orientations), data(&scales));
    let ids = value("ids");
    let ids = ids.as_ref().and_then(Value::as_int_array);
    let bad_index = indices.iter().any(|&i| i < 0 || i as usize >= targets.len());
    let zero_quaternion = orientations_data.is_some_and(|q| q.chunks(4).any(|q| q.iter().all(|&c| c == 0.0)));
    if bad_index || zero_quaternion || ids.is_some_and(|ids| ids.len() != n) {
        return None;
    }
    let invisible = value("invisibleIds");
    let invisible: HashSet<i64> =
        invisible.as_ref().and_then(Value::as_int_array).map(|v| v.iter().copied().collect()).unwrap_or_default();
    let locals: Vec<DMat4> =
        targets.iter().map(|&p| local_transform(stage.prim(p), &mut Diagnostics::new()).0).collect();
    let visible = (0..n).filter(|&k| !invisible.contains(&ids.map_or(k as i64, |ids| ids[k])));
    Some(
        visible
            .map(|k| point_matrix(instancer, positions, orientations_data, scales, k, locals[indices[k] as usize]))
            .collect(),
    )
}
