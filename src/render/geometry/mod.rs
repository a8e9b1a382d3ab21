//! World-space geometry from a composed stage.
//!
//! Meshes are fan-triangulated into world-space triangles; Cube and Plane are triangles too
//! (they are flat, so exactly). The curved implicit prims (Sphere, Cylinder, Cone, Capsule)
//! become analytic [`Shape`]s, intersected exactly in object space: nothing is tessellated.
//! Malformed meshes are diagnosed (never a panic); zero-area triangles are skipped and counted.

pub mod accel;
pub mod displace;
pub mod primvars;
pub mod shapes;
pub mod skel;
pub mod subdiv;
pub mod xform;

use crate::compose::binding::{is_bound_subset, is_renderable};
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::render::geometry::primvars::{MAX_COMPONENTS, Primvar, PrimvarLayout, PrimvarRef, PrimvarTable};
use crate::render::geometry::shapes::{Part, Shape};
use crate::render::geometry::subdiv::{PolyMesh, catmull_clark, read_tags, refined_faces};
use crate::render::geometry::xform::{PrimXform, local_transform, value_span, world_transforms};
use crate::scene::{Prim, PrimId, Stage, Value};
use glam::{DMat3, DMat4, DQuat, DVec3, Vec2, Vec3};
use std::collections::{HashMap, HashSet};

/// The largest world-space coordinate (absolute value, scene units, after every transform)
/// geometry may have: 1e7. The renderer works in f32, whose spacing at 1e7 is already one
/// unit, so detail and ray offsets break down beyond it; and far-apart geometry (1e13) made
/// the BVH builder crawl while 1e38 crashed it. A prim that reaches past it is an error.
pub const MAX_EXTENT: f64 = 1e7;

/// The shortest longest-edge a triangle may have: 1e-11 scene units (in the space its BVH
/// tests it in: the world, or an instancing prototype's own). The f32 watertight test
/// multiplies three coordinates (relative to the ray origin) and bounds their rounding with a
/// further factor of 1e-7 (`accel::RayPre::intersect`); below about 1e-11 those products
/// leave f32's normal range (1e-38), the error bounds lose their precision and then the hit
/// itself underflows. Measured (tests/scene_scale.rs): a scene scaled by 1e-12 (floor edges
/// 4e-11) renders exactly as at scale 1, by 1e-14 it is already biased, by 1e-16 the floor
/// vanishes. A prim with a smaller triangle is an error, never a silently wrong image.
pub const MIN_TRIANGLE_EDGE: f64 = 1e-11;

/// The most triangles a scene may have: 2^25 (33.5 million, about 3.5 GB of triangles plus
/// their BVH). Implicit surfaces are tessellated into 16 384 triangles each, so a 50 MB
/// scene of 137 000 spheres asked for 2.2 billion triangles and was killed by the kernel; past
/// this budget the scene is an error naming the first prim that did not fit.
pub const MAX_TRIANGLES: usize = 1 << 25;

/// The most faces subdivision may make of one mesh: 2^18 (262 144 quads, half a million
/// triangles). A mesh is refined to `--subdiv-level` levels, or fewer when that would pass
/// this, so a dense cage is not multiplied into millions of triangles it does not need; a cage
/// that passes it at one level is rendered as it is.
pub const SUBDIV_FACE_BUDGET: u64 = 1 << 18;

/// The default `--subdiv-level`: two levels put a coarse cage's limit surface within a few
/// tenths of a percent of its size (every vertex is on the limit surface; only the flat
/// facets between them deviate), and a cube becomes 96 quads.
pub const DEFAULT_SUBDIV_LEVEL: u32 = 2;

/// How geometry is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GeometryOptions {
    /// Subdivision levels for `catmullClark` (and `loop`) meshes; 0 renders every cage.
    pub subdiv_level: u32,
}

impl Default for GeometryOptions {
    fn default() -> GeometryOptions {
        GeometryOptions { subdiv_level: DEFAULT_SUBDIV_LEVEL }
    }
}

/// The most instances a scene may have: 2^22 (4.2 million, about 1.5 GB of instance table
/// and top-level BVH). A 256 MiB point-instancer file can list 25 million points; past this
/// budget the instancer is an error.
pub const MAX_INSTANCES: usize = 1 << 22;

/// What one instance costs the renderer at its peak, for the memory budget
/// ([`crate::input::check_memory`]): its placement (`InstanceDesc`, 136 bytes), the
/// traversal's copy with both transforms (208), its box (32) and obvhs' build of the
/// top-level BVH over it (Morton codes, node arrays, indices; about 250). Measured: 4 million
/// point instances peaked at 2.5 GB, their text parsed included.
pub const INSTANCE_BYTES: u64 = 640;

/// A prototype placed in the world.
#[derive(Clone, Copy, Debug)]
pub struct InstanceDesc {
    /// Object (prototype) space to world.
    pub to_world: DMat4,
    /// Index of the prototype's BLAS.
    pub prototype: u32,
    /// Where the instance's prim table starts in the instance prim table: prototype-local
    /// prim `j` of this instance is the renderable prim `instance_prims[prims + j]`.
    pub prims: u32,
}

/// One world-space triangle.
#[derive(Clone, Copy, Debug)]
pub struct Triangle {
    /// Vertex positions.
    pub p: [Vec3; 3],
    /// Vertex shading normals (unit); the geometric normal when the prim has none.
    pub n: [Vec3; 3],
    /// Vertex texture coordinates (`st`, or parametric `(0,0), (1,0), (0,1)` when absent).
    pub uv: [Vec2; 3],
    /// Index of the renderable prim in [`Geometry::prims`].
    pub prim: u32,
    /// Whether `uv` came from the prim (`primvars:st` or an implicit surface's parameterisation).
    pub has_uv: bool,
    /// Its primvar values (the three corners') in [`Geometry::primvars`].
    pub primvars: PrimvarRef,
}

impl Triangle {
    /// The unnormalised geometric normal (right-handed winding).
    pub fn cross(&self) -> Vec3 {
        (self.p[1] - self.p[0]).cross(self.p[2] - self.p[0])
    }
}

/// A renderable prim that produced triangles.
#[derive(Clone, Debug)]
pub struct GeomPrim {
    /// Its path.
    pub path: String,
    /// Where it is defined (for diagnostics about it).
    pub span: Span,
    /// For the faces of a GeomSubset with its own material binding: the mesh they belong to
    /// (displacement welds a mesh's faces across subsets only where they share a material).
    pub subset_of: Option<u32>,
}

/// Geometry that instances share: built once, in the space of its root prim.
#[derive(Clone, Debug, Default)]
pub struct Prototype {
    /// Triangles in prototype space; `prim` is prototype-local.
    pub triangles: Vec<Triangle>,
    /// Analytic surfaces in prototype space; `prim` is prototype-local.
    pub shapes: Vec<Shape>,
    /// Number of prototype-local prims.
    pub prims: u32,
    /// Prototype-space bounds `(min, max)`; `None` when empty.
    pub bounds: Option<(DVec3, DVec3)>,
}

/// The triangles of a whole stage.
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    /// World-space triangles (of prims that are not instanced).
    pub triangles: Vec<Triangle>,
    /// Analytic surfaces.
    pub shapes: Vec<Shape>,
    /// Renderable, visible prims, indexed by [`Triangle::prim`] and the instance prim table.
    pub prims: Vec<GeomPrim>,
    /// Zero-area or non-finite triangles that were skipped.
    pub degenerate: usize,
    /// Geometry shared by instances: of `instanceable` prims with the same source, and the
    /// prototypes of point instancers.
    pub prototypes: Vec<Prototype>,
    /// Placed prototypes.
    pub instances: Vec<InstanceDesc>,
    /// Per-instance prim tables: prototype-local prim `j` of an instance is the renderable
    /// prim `instance_prims[instance.prims + j]`.
    pub instance_prims: Vec<u32>,
    /// The primvars materials read, for every triangle and shape that has them (world and
    /// prototypes alike).
    pub primvars: PrimvarTable,
}

impl Geometry {
    /// World-space bounds `(min, max)` of every triangle, shape and instance; `None` when empty.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let world = bounds_of(&self.triangles, &self.shapes);
        let instances = self.instances.iter().filter_map(|i| {
            let (lo, hi) = self.prototypes[i.prototype as usize].bounds?;
            Some(crate::render::geometry::shapes::transformed_box(&i.to_world, lo, hi))
        });
        let (lo, hi) = world.into_iter().chain(instances).reduce(|(a, b), (c, d)| (a.min(c), b.max(d)))?;
        Some((lo.as_vec3(), hi.as_vec3()))
    }
}

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
fn build_within(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    budget: usize,
    primvars: &[String],
    diags: &mut Diagnostics,
) -> Geometry {
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
    let mut geometry = Geometry::default();
    geometry.primvars.names = primvars.to_vec();
    let mut b = Builder {
        stage,
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
    };
    for (id, prim) in stage.depth_first() {
        let i = id.0 as usize;
        if inside[i] || xforms[i].hidden {
            continue;
        }
        match role[i] {
            Role::Plain => b.world_prim(prim, xforms[i].world, diags),
            Role::InstanceRoot => {
                let key = &key_of[&id.0];
                if key_count[key] > 1 {
                    b.instance(id, key, diags);
                } else {
                    for (sub, p) in stage.subtree(id) {
                        let xf = xforms[sub.0 as usize];
                        if !xf.hidden && p.type_name.as_deref() != Some("PointInstancer") {
                            b.world_prim(p, xf.world, diags);
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

impl Builder<'_> {
    /// The index of the renderable prim at `prim`'s path, added when new.
    fn prim_index(&mut self, prim: &Prim) -> u32 {
        let prims = &mut self.geometry.prims;
        *self.prim_index.entry(prim.path.clone()).or_insert_with(|| {
            prims.push(GeomPrim { path: prim.path.clone(), span: prim.span, subset_of: None });
            prims.len() as u32 - 1
        })
    }

    /// Triangles in every buffer, for the budget.
    fn triangles_so_far(&self) -> usize {
        self.geometry.triangles.len() + self.geometry.prototypes.iter().map(|p| p.triangles.len()).sum::<usize>()
    }

    /// A visible renderable prim (or any other prim, which emits nothing) in world space.
    fn world_prim(&mut self, prim: &Prim, world: DMat4, diags: &mut Diagnostics) {
        if !is_renderable(prim) {
            return;
        }
        // UsdSkel: a skinned prim is emitted from its posed copy.
        let posed = crate::render::geometry::skel::posed_prim(self.stage, self.xforms, prim, world, diags);
        let prim = posed.as_ref().unwrap_or(prim);
        let index = self.prim_index(prim);
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
                    subset_index
                },
                diags,
            )
        } else {
            Vec::new()
        };
        let others = self.triangles_so_far() - self.geometry.triangles.len();
        let g = &mut self.geometry;
        let mut out = Emitter::new(
            &mut g.triangles,
            &mut g.shapes,
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
        for id in members {
            let index = self.prim_index(stage.prim(id));
            self.geometry.instance_prims.push(index);
        }
        let to_world = self.xforms[root.0 as usize].world;
        self.place(stage.prim(root), prototype, start, to_world, None, diags);
    }

    /// Adds an instance after checking that it lies within the extent.
    fn place(
        &mut self,
        prim: &Prim,
        prototype: u32,
        prims: u32,
        to_world: DMat4,
        which: Option<(usize, Span)>,
        diags: &mut Diagnostics,
    ) -> bool {
        let Some((lo, hi)) = self.geometry.prototypes[prototype as usize].bounds else { return true };
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

/// World-space bounds `(min, max)` of triangles and shapes; `None` when there are none.
fn bounds_of(triangles: &[Triangle], shapes: &[Shape]) -> Option<(DVec3, DVec3)> {
    let shape_corners = shapes.iter().flat_map(|s| {
        let (lo, hi) = s.world_bounds();
        [lo, hi]
    });
    let mut it = triangles.iter().flat_map(|t| t.p).chain(shape_corners);
    let first = it.next()?;
    let (lo, hi) = it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p)));
    Some((lo.as_dvec3(), hi.as_dvec3()))
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

/// Emits the geometry of one renderable prim.
fn emit_prim(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    out.corner_layout = u32::MAX;
    out.constant = PrimvarRef::NONE;
    if !matches!(prim.type_name.as_deref(), Some("Mesh" | "Points")) {
        out.constant = element_primvars(prim, 1, out.table, diags).first().copied().unwrap_or(PrimvarRef::NONE);
    }
    match prim.type_name.as_deref() {
        Some("Mesh") => mesh(prim, out, diags),
        Some("Sphere") => sphere(prim, out, diags),
        Some("Cube") => cube(prim, out, diags),
        Some("Cylinder") => cylinder(prim, out, diags),
        Some("Cone") => cone(prim, out, diags),
        Some("Capsule") => capsule(prim, out, diags),
        Some("Plane") => plane(prim, out, diags),
        Some("Points") => points(prim, out, diags),
        _ => {}
    }
}

/// Transforms local-space triangles and shapes to the target space and appends them.
struct Emitter<'g> {
    triangles: &'g mut Vec<Triangle>,
    shapes: &'g mut Vec<Shape>,
    degenerate: &'g mut usize,
    m: DMat4,
    /// Inverse transpose of `m`'s linear part, for normals.
    nm: DMat3,
    prim: u32,
    /// The first target-space point past [`MAX_EXTENT`] (or non-finite), if any.
    beyond_extent: Option<DVec3>,
    /// Triangles whose longest edge is below [`MIN_TRIANGLE_EDGE`]: their count and the
    /// first one's vertex 0 and longest edge.
    too_small: Option<(usize, DVec3, f64)>,
    /// Triangles this emitter kept.
    emitted: usize,
    /// The most triangles `triangles` may hold (what [`MAX_TRIANGLES`] leaves).
    budget: usize,
    /// A triangle was dropped because the scene reached its budget.
    over_budget: bool,
    /// Subdivision levels for subdivision-surface meshes.
    subdiv_level: u32,
    /// For meshes with GeomSubset bindings: the prim index of each face (empty: all `prim`).
    face_prims: Vec<u32>,
    /// Where primvar values go.
    table: &'g mut PrimvarTable,
    /// The current mesh's per-corner layout (`u32::MAX`: none), for [`Emitter::emit_with`].
    corner_layout: u32,
    /// One set of values for every primitive of the current prim (analytic prims, Points).
    constant: PrimvarRef,
}

impl<'g> Emitter<'g> {
    fn new(
        triangles: &'g mut Vec<Triangle>,
        shapes: &'g mut Vec<Shape>,
        degenerate: &'g mut usize,
        table: &'g mut PrimvarTable,
        m: DMat4,
        prim: u32,
        budget: usize,
    ) -> Emitter<'g> {
        let nm = DMat3::from_mat4(m).inverse().transpose();
        Emitter {
            triangles,
            shapes,
            degenerate,
            m,
            nm,
            prim,
            beyond_extent: None,
            too_small: None,
            emitted: 0,
            budget,
            over_budget: false,
            subdiv_level: DEFAULT_SUBDIV_LEVEL,
            face_prims: Vec::new(),
            table,
            corner_layout: u32::MAX,
            constant: PrimvarRef::NONE,
        }
    }

    /// Emits one triangle given in local space (`n` in local space, not necessarily unit),
    /// with the prim's constant primvars.
    fn emit(&mut self, p: [DVec3; 3], n: Option<[DVec3; 3]>, uv: Option<[Vec2; 3]>) {
        self.emit_with(p, n, uv, None);
    }

    /// As [`Emitter::emit`], with the three corners' primvar values (`corner_layout`'s stride
    /// each, in the order of `p`).
    fn emit_with(&mut self, p: [DVec3; 3], n: Option<[DVec3; 3]>, uv: Option<[Vec2; 3]>, corners: Option<&[f32]>) {
        let world = p.map(|p| self.m.transform_point3(p));
        // Non-finite points (NaN included) are beyond any extent too.
        if let Some(far) = world.iter().find(|w| !w.is_finite() || w.abs().max_element() > MAX_EXTENT) {
            self.beyond_extent.get_or_insert(*far);
            return;
        }
        if self.triangles.len() >= self.budget {
            // Reported by the builder after this prim; the memory stays bounded.
            self.over_budget = true;
            return;
        }
        let wp = world.map(|p| p.as_vec3());
        // The normal of the f32 vertices the intersection test sees, in f64: an f32 cross
        // product underflows for edges below ~1e-10 units (its square, below ~3e-20), which
        // made tiny but sound triangles "degenerate". Differences and products of f32 values
        // are exact in f64, so only truly collinear vertices give zero here.
        let [a, b, c] = wp.map(|p| p.as_dvec3());
        let cross = (b - a).cross(c - a);
        let len2 = cross.length_squared();
        if len2.is_nan() || len2 <= 0.0 || !len2.is_finite() {
            *self.degenerate += 1;
            return;
        }
        let ng = (cross / len2.sqrt()).as_vec3();
        let longest = (b - a).length().max((c - b).length()).max((a - c).length());
        if longest < MIN_TRIANGLE_EDGE {
            let entry = self.too_small.get_or_insert((0, a, longest));
            entry.0 += 1;
            return;
        }
        // Normals transform by the inverse transpose.
        let n = match n {
            Some(n) => n.map(|n| {
                let w = (self.nm * n).as_vec3().normalize_or_zero();
                if w == Vec3::ZERO || !w.is_finite() { ng } else { w }
            }),
            None => [ng; 3],
        };
        let has_uv = uv.is_some();
        let uv = uv.unwrap_or([Vec2::ZERO, Vec2::X, Vec2::Y]);
        let primvars = match corners {
            Some(values) if self.corner_layout != u32::MAX => self.table.push(self.corner_layout, values),
            _ => self.constant,
        };
        self.triangles.push(Triangle { p: wp, n, uv, prim: self.prim, has_uv, primvars });
        self.emitted += 1;
    }

    /// Adds an analytic part built around z, turned so that z is the prim's `axis`.
    fn shape(&mut self, part: Part, axis: DMat4) {
        let m = self.m * axis;
        // Its world box (the transformed corners of the object box) must lie within the extent.
        let (lo, hi) = part.world_bounds(&m);
        if let Some(far) = [lo, hi].into_iter().find(|w| !w.is_finite() || w.abs().max_element() > MAX_EXTENT) {
            self.beyond_extent.get_or_insert(far);
            return;
        }
        match Shape::new(part, m, self.prim) {
            Some(mut shape) => {
                shape.primvars = self.constant;
                self.shapes.push(shape)
            }
            None => *self.degenerate += 1,
        }
    }
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
        let tuples = |name: &str, width: usize, diags: &mut Diagnostics| -> Option<&[f64]> {
            let attr = prim.attribute(name)?;
            let Some((w, data)) = attr.get()?.as_tuple_array() else {
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
                    for m in members {
                        let index = self.prim_index(stage.prim(m));
                        self.geometry.instance_prims.push(index);
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
            let t = DVec3::from_slice(&positions[3 * k..3 * k + 3]);
            // USD writes quaternions (real, i, j, k).
            let r = orientations.map_or(DQuat::IDENTITY, |q| {
                DQuat::from_xyzw(q[4 * k + 1], q[4 * k + 2], q[4 * k + 3], q[4 * k]).normalize()
            });
            let s = scales.map_or(DVec3::ONE, |s| DVec3::from_slice(&s[3 * k..3 * k + 3]));
            // Row-vector USD: proto · scale · orient · translate; column-vector: T R S proto.
            let m = instancer * DMat4::from_scale_rotation_translation(s, r, t) * local;
            if !self.place(prim, p, prims, m, Some((k, positions_span)), diags) {
                // One extent error per instancer is enough.
                break;
            }
        }
    }
}

/// The rotation taking z to the prim's `axis` attribute (`X`, `Y` or `Z`, default `Z`), as
/// a cyclic permutation: for `X`, (x, y, z) → (z, x, y).
fn axis_matrix(prim: &Prim) -> DMat4 {
    match prim.value("axis").and_then(Value::as_str).unwrap_or("Z") {
        "X" => DMat4::from_cols(DVec3::Y.extend(0.0), DVec3::Z.extend(0.0), DVec3::X.extend(0.0), glam::DVec4::W),
        "Y" => DMat4::from_cols(DVec3::Z.extend(0.0), DVec3::X.extend(0.0), DVec3::Y.extend(0.0), glam::DVec4::W),
        _ => DMat4::IDENTITY,
    }
}

fn span_of(prim: &Prim, name: &str) -> Span {
    prim.attribute(name).map_or(prim.span, value_span)
}

/// A primvar resolved per face-vertex: its data, width, interpolation and optional indices.
fn mesh(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let error = |diags: &mut Diagnostics, name: &str, message: String| {
        diags.push(Diagnostic::error(message).at(span_of(prim, name), "here"));
    };
    let Some((3, points)) = prim.value("points").and_then(Value::as_tuple_array) else {
        if prim.attribute("points").is_some() {
            error(diags, "points", format!("mesh `{}`: `points` must be an array of 3-vectors", prim.path));
        }
        return;
    };
    let counts = prim.value("faceVertexCounts").and_then(Value::as_int_array).unwrap_or(&[]);
    let indices = prim.value("faceVertexIndices").and_then(Value::as_int_array).unwrap_or(&[]);
    let npoints = points.len() / 3;
    if points.iter().any(|c| !c.is_finite()) {
        error(diags, "points", format!("mesh `{}` has non-finite (NaN or infinite) points", prim.path));
        return;
    }
    if counts.iter().any(|&c| c < 0) || counts.iter().map(|&c| c.max(0) as usize).sum::<usize>() != indices.len() {
        error(
            diags,
            "faceVertexCounts",
            format!(
                "mesh `{}`: faceVertexCounts sum to {} but faceVertexIndices has {} entries",
                prim.path,
                counts.iter().map(|&c| c.max(0)).sum::<i64>(),
                indices.len()
            ),
        );
        return;
    }
    if let Some(bad) = indices.iter().find(|&&i| i < 0 || i as usize >= npoints) {
        error(
            diags,
            "faceVertexIndices",
            format!("mesh `{}`: vertex index {bad} is out of range (the mesh has {npoints} points)", prim.path),
        );
        return;
    }
    let faces = counts.len();
    let left = prim.value("orientation").and_then(Value::as_str) == Some("leftHanded");
    // A mirroring transform flips the winding too.
    let flip = left != (out.m.determinant() < 0.0);

    let normals =
        Primvar::get(prim, "primvars:normals", 3, "vertex").or_else(|| Primvar::get(prim, "normals", 3, "vertex"));
    let normals = normals.filter(|pv| check_primvar(prim, pv, npoints, faces, indices.len(), diags));
    let st = Primvar::get(prim, "primvars:st", 2, "faceVarying");
    let st = st.filter(|pv| check_primvar(prim, pv, npoints, faces, indices.len(), diags));
    let shading = MeshPrimvars::new(prim, out.table, (npoints, faces, indices.len()), diags);
    out.corner_layout = shading.as_ref().map_or(u32::MAX, |m| m.layout);

    let holes: std::collections::HashSet<i64> = prim
        .value("holeIndices")
        .and_then(Value::as_int_array)
        .map(|h| h.iter().copied().collect())
        .unwrap_or_default();
    let short_faces = counts.iter().filter(|&&c| c < 3).count();
    if short_faces > 0 {
        diags.push(
            Diagnostic::warning(format!(
                "mesh `{}`: {short_faces} face(s) with fewer than 3 vertices skipped",
                prim.path
            ))
            .at(span_of(prim, "faceVertexCounts"), "here"),
        );
    }
    // UsdGeom's default scheme is catmullClark: a mesh without the attribute is a smooth
    // surface, and its points are only the cage.
    let scheme_attr = prim.attribute("subdivisionScheme");
    let scheme = prim.value("subdivisionScheme").and_then(Value::as_str).unwrap_or("catmullClark");
    match scheme {
        // A cage already past the face budget at one level is dense enough to render as it is.
        "catmullClark" | "loop" if out.subdiv_level > 0 && refined_faces_of(counts, 1) <= SUBDIV_FACE_BUDGET => {
            if scheme == "loop" {
                diags.push(
                    Diagnostic::warning(format!(
                        "mesh `{}`: Loop subdivision is approximated by Catmull-Clark (a slightly different smooth surface)",
                        prim.path
                    ))
                    .at(scheme_attr.map_or(prim.span, value_span), "here"),
                );
            }
            let mut poly = poly_mesh(points, counts, indices, st.as_ref(), shading.as_ref(), &holes);
            poly.tags = read_tags(prim, npoints, counts, indices, diags);
            // Normals are not authored on subdivision surfaces (UsdGeom): the limit's are used.
            subdivided(&poly, left, flip, out);
            return;
        }
        "catmullClark" | "loop" | "none" | "bilinear" => {}
        other => diags.push(
            Diagnostic::warning(format!(
                "mesh `{}`: unknown subdivisionScheme `{other}`; the cage is rendered",
                prim.path
            ))
            .at(scheme_attr.map_or(prim.span, value_span), "here"),
        ),
    }

    let point = |i: usize| DVec3::new(points[3 * i], points[3 * i + 1], points[3 * i + 2]);
    let mut start = 0usize;
    let base = out.prim;
    let mut corner_values = Vec::new();
    for (face, &count) in counts.iter().enumerate() {
        out.prim = out.face_prims.get(face).copied().unwrap_or(base);
        let count = count as usize;
        if count < 3 || holes.contains(&(face as i64)) {
            start += count;
            continue;
        }
        let corner = |k: usize| -> (DVec3, Option<DVec3>, Option<Vec2>, (usize, usize)) {
            let c = start + k;
            let pi = indices[c] as usize;
            let n = normals.as_ref().and_then(|pv| pv.at(face, c, pi)).map(|n| DVec3::new(n[0], n[1], n[2]));
            let uv = st.as_ref().and_then(|pv| pv.at(face, c, pi)).map(|t| Vec2::new(t[0] as f32, t[1] as f32));
            (point(pi), n, uv, (c, pi))
        };
        for k in 1..count - 1 {
            let mut c = [corner(0), corner(k), corner(k + 1)];
            if flip {
                c.swap(1, 2);
            }
            let p = [c[0].0, c[1].0, c[2].0];
            let n = match (c[0].1, c[1].1, c[2].1) {
                (Some(a), Some(b), Some(d)) => Some([a, b, d]),
                _ => None,
            };
            let uv = match (c[0].2, c[1].2, c[2].2) {
                (Some(a), Some(b), Some(d)) => Some([a, b, d]),
                _ => None,
            };
            let values = shading.as_ref().map(|m| {
                corner_values.clear();
                for (_, _, _, (fv, pi)) in &c {
                    m.corner(face, *fv, *pi, &mut corner_values);
                }
                corner_values.as_slice()
            });
            out.emit_with(p, n, uv, values);
        }
        start += count;
    }
}

/// The faces of a validated mesh with three or more vertices, as a [`PolyMesh`], with `st`
/// per face-vertex when every corner has one, and the shading primvars per face-vertex.
fn poly_mesh(
    points: &[f64],
    counts: &[i64],
    indices: &[i64],
    st: Option<&Primvar>,
    shading: Option<&MeshPrimvars>,
    holes: &std::collections::HashSet<i64>,
) -> PolyMesh {
    let mut mesh = PolyMesh {
        points: points.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect(),
        ..PolyMesh::default()
    };
    let mut uv = st.map(|_| Vec::with_capacity(indices.len()));
    let mut start = 0usize;
    for (face, &count) in counts.iter().enumerate() {
        let count = count as usize;
        if count >= 3 {
            mesh.counts.push(count as u32);
            mesh.holes.push(holes.contains(&(face as i64)));
            mesh.origin.push(face as u32);
            for (c, &index) in indices.iter().enumerate().skip(start).take(count) {
                let pi = index as usize;
                mesh.indices.push(pi as u32);
                if let Some(out) = uv.as_mut() {
                    match st.and_then(|pv| pv.at(face, c, pi)) {
                        Some(t) => out.push(Vec2::new(t[0] as f32, t[1] as f32)),
                        None => uv = None,
                    }
                }
                if let Some(m) = shading {
                    m.corner(face, c, pi, &mut mesh.varying);
                }
            }
        }
        start += count;
    }
    mesh.uv = uv;
    mesh.varying_width = shading.map_or(0, |m| m.stride);
    mesh
}

/// Emits the limit surface of `poly`, refined to the emitter's level or as many levels as fit
/// [`SUBDIV_FACE_BUDGET`] (at least one).
/// [`refined_faces`] of the faces with three or more vertices of authored `counts`.
fn refined_faces_of(counts: &[i64], level: u32) -> u64 {
    let counts: Vec<u32> = counts.iter().filter(|&&c| c >= 3).map(|&c| c.min(u32::MAX as i64) as u32).collect();
    refined_faces(&counts, level)
}

fn subdivided(poly: &PolyMesh, left_handed: bool, flip: bool, out: &mut Emitter) {
    let mut level = out.subdiv_level;
    while level > 1 && refined_faces(&poly.counts, level) > SUBDIV_FACE_BUDGET {
        level -= 1;
    }
    let q = catmull_clark(poly, level);
    let base = out.prim;
    let mut corner_values = Vec::new();
    // Limit normals follow the right-hand rule of the faces' winding; a left-handed mesh
    // faces the other way.
    let sign = if left_handed { -1.0 } else { 1.0 };
    for (i, quad) in q.quads.iter().enumerate() {
        if q.holes[i] {
            continue;
        }
        out.prim = out.face_prims.get(q.origin[i] as usize).copied().unwrap_or(base);
        for mut corners in [[0, 1, 2], [0, 2, 3]] {
            if flip {
                corners.swap(1, 2);
            }
            let p = corners.map(|k| q.points[quad[k] as usize]);
            let n = corners.map(|k| q.normals[quad[k] as usize] * sign);
            let uv = q.uv.as_ref().map(|uv| corners.map(|k| uv[i][k]));
            let w = q.varying_width;
            let values = (w > 0).then(|| {
                corner_values.clear();
                for k in corners {
                    corner_values.extend_from_slice(&q.varying[(4 * i + k) * w..(4 * i + k + 1) * w]);
                }
                corner_values.as_slice()
            });
            out.emit_with(p, Some(n), uv, values);
        }
    }
}

/// Whether a primvar's length fits its interpolation; warns and drops it when not.
fn check_primvar(prim: &Prim, pv: &Primvar, points: usize, faces: usize, fv: usize, diags: &mut Diagnostics) -> bool {
    let elements = pv.elements();
    let ok = pv.expected(points, faces, fv).is_some_and(|e| e == elements) && pv.sound();
    if !ok {
        diags.push(
            Diagnostic::warning(format!(
                "mesh `{}`: `{}` ({} interpolation, {elements} elements) does not fit the mesh; ignored",
                prim.path, pv.attr.name, pv.interpolation
            ))
            .at(value_span(pv.attr), "here"),
        );
    }
    ok
}

/// The primvars (of [`PrimvarTable::names`]) a mesh has, checked against its counts, with
/// their place in a corner of its layout (registered in the table).
struct MeshPrimvars<'a> {
    /// (offset in a corner, components stored, the primvar).
    vars: Vec<(usize, usize, Primvar<'a>)>,
    stride: usize,
    layout: u32,
}

impl<'a> MeshPrimvars<'a> {
    fn new(
        prim: &'a Prim,
        table: &mut PrimvarTable,
        counts: (usize, usize, usize),
        diags: &mut Diagnostics,
    ) -> Option<MeshPrimvars<'a>> {
        let (points, faces, fv) = counts;
        let mut fields = vec![(0u32, 0u32); table.names.len()];
        let mut vars = Vec::new();
        let mut stride = 0;
        for (i, name) in table.names.iter().enumerate() {
            // `st` keeps the default its texture coordinates have always had here.
            let default = if name == "st" { "faceVarying" } else { "constant" };
            let Some(pv) = Primvar::any(prim, &format!("primvars:{name}"), default) else { continue };
            if !check_primvar(prim, &pv, points, faces, fv, diags) {
                continue;
            }
            let width = pv.width.min(MAX_COMPONENTS);
            fields[i] = (stride as u32, width as u32);
            vars.push((stride, width, pv));
            stride += width;
        }
        if vars.is_empty() || table.layouts.len() >= u32::MAX as usize {
            return None;
        }
        table.layouts.push(PrimvarLayout { fields, stride: stride as u32, corners: 3 });
        Some(MeshPrimvars { vars, stride, layout: table.layouts.len() as u32 - 1 })
    }

    /// Appends the values of face `face`'s corner at face-vertex `corner`, point `point`.
    fn corner(&self, face: usize, corner: usize, point: usize, out: &mut Vec<f32>) {
        for (_, width, pv) in &self.vars {
            match pv.at(face, corner, point) {
                Some(v) => out.extend(v[..*width].iter().map(|&x| x as f32)),
                None => out.extend(std::iter::repeat_n(0.0, *width)),
            }
        }
    }
}

/// The primvars (of [`PrimvarTable::names`]) of a prim drawn as `count` primitives with one
/// value set each: an analytic prim (1) or Points (one sphere per point). A primvar with one
/// element applies to all; on Points, a vertex or varying one gives each point its own; any
/// other is reported and ignored. Returns each primitive's values (empty: none).
fn element_primvars(prim: &Prim, count: usize, table: &mut PrimvarTable, diags: &mut Diagnostics) -> Vec<PrimvarRef> {
    if table.names.is_empty() || count == 0 {
        return Vec::new();
    }
    let mut fields = vec![(0u32, 0u32); table.names.len()];
    let mut vars = Vec::new();
    let mut stride = 0;
    for (i, name) in table.names.iter().enumerate() {
        let Some(pv) = Primvar::any(prim, &format!("primvars:{name}"), "constant") else { continue };
        let elements = pv.elements();
        let per_point = count > 1 && elements == count && matches!(pv.interpolation, "vertex" | "varying");
        if !(pv.sound() && (elements == 1 || per_point)) {
            diags.push(
                Diagnostic::warning(format!(
                    "`{}`: `{}` ({} interpolation, {elements} elements) does not fit a {} (one value{}); ignored",
                    prim.path,
                    pv.attr.name,
                    pv.interpolation,
                    prim.type_name.as_deref().unwrap_or("prim"),
                    if count > 1 { ", or one per point" } else { "" }
                ))
                .at(value_span(pv.attr), "here"),
            );
            continue;
        }
        let width = pv.width.min(MAX_COMPONENTS);
        fields[i] = (stride as u32, width as u32);
        vars.push((width, per_point, pv));
        stride += width;
    }
    if vars.is_empty() || table.layouts.len() >= u32::MAX as usize {
        return Vec::new();
    }
    table.layouts.push(PrimvarLayout { fields, stride: stride as u32, corners: 1 });
    let layout = table.layouts.len() as u32 - 1;
    let varies = vars.iter().any(|(_, per_point, _)| *per_point);
    let mut values = Vec::with_capacity(stride);
    (0..if varies { count } else { 1 })
        .map(|e| {
            values.clear();
            for (width, per_point, pv) in &vars {
                // Element lookup through indices: `at` takes the point index for vertex data.
                let element = if *per_point { pv.at(0, 0, e) } else { pv.at(0, 0, 0).or_else(|| pv.at(0, 0, e)) };
                match element {
                    Some(v) => values.extend(v[..*width].iter().map(|&x| x as f32)),
                    None => values.extend(std::iter::repeat_n(0.0, *width)),
                }
            }
            table.push(layout, &values)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .cycle()
        .take(count)
        .collect()
}

fn positive(prim: &Prim, name: &str, default: f64, diags: &mut Diagnostics) -> Option<f64> {
    let v = prim.value(name).and_then(Value::as_f64).unwrap_or(default);
    if v.is_finite() && v > 0.0 {
        Some(v)
    } else {
        diags.push(
            Diagnostic::error(format!("`{}`: `{name}` must be a positive number, not {v}", prim.path))
                .at(span_of(prim, name), "here"),
        );
        None
    }
}

/// A sphere of `radius` around the origin, its poles on z (UsdGeomSphere).
fn sphere(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some(r) = positive(prim, "radius", 1.0, diags) else { return };
    out.shape(Part::Sphere { r, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY }, DMat4::IDENTITY);
}

/// UsdGeomPoints as spheres of diameter `widths` (one per point, or one for all; 1 when
/// absent, as Hydra draws them), each an analytic sphere.
fn points(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some((3, points)) = prim.value("points").and_then(Value::as_tuple_array) else {
        if prim.attribute("points").is_some() {
            diags.push(
                Diagnostic::error(format!("points `{}`: `points` must be an array of 3-vectors", prim.path))
                    .at(span_of(prim, "points"), "here"),
            );
        }
        return;
    };
    let count = points.len() / 3;
    let widths = prim.value("widths").and_then(Value::as_float_array).unwrap_or(&[1.0]);
    if widths.len() != 1 && widths.len() != count {
        diags.push(
            Diagnostic::error(format!(
                "points `{}`: {} widths for {count} points (give one, or one per point)",
                prim.path,
                widths.len()
            ))
            .at(span_of(prim, "widths"), "here"),
        );
        return;
    }
    let primvars = element_primvars(prim, count, out.table, diags);
    for (i, p) in points.chunks_exact(3).enumerate() {
        out.constant = primvars.get(i).copied().unwrap_or(PrimvarRef::NONE);
        let width = widths[if widths.len() == 1 { 0 } else { i }];
        let centre = DVec3::new(p[0], p[1], p[2]);
        if !(width.is_finite() && width > 0.0 && centre.is_finite()) {
            *out.degenerate += 1;
            continue;
        }
        let part = Part::Sphere { r: width / 2.0, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY };
        out.shape(part, DMat4::from_translation(centre));
    }
}

fn cube(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some(size) = positive(prim, "size", 2.0, diags) else { return };
    let h = size / 2.0;
    for axis in 0..3 {
        for sign in [-1.0, 1.0] {
            let n = DVec3::from_array(std::array::from_fn(|k| if k == axis { sign } else { 0.0 }));
            let u = DVec3::from_array(std::array::from_fn(|k| if k == (axis + 1) % 3 { 1.0 } else { 0.0 }));
            let v = n.cross(u);
            let corner = |a: f64, b: f64| {
                (n * h + u * (a * h) + v * (b * h), Vec2::new((a as f32 + 1.0) / 2.0, (b as f32 + 1.0) / 2.0))
            };
            let q = [corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0)];
            for [i, j, k] in [[0, 1, 2], [0, 2, 3]] {
                out.emit([q[i].0, q[j].0, q[k].0], Some([n; 3]), Some([q[i].1, q[j].1, q[k].1]));
            }
        }
    }
}

/// A capped cylinder of `radius` and `height` along `axis`, centred (UsdGeomCylinder).
fn cylinder(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some(r) = positive(prim, "radius", 1.0, diags) else { return };
    let Some(height) = positive(prim, "height", 2.0, diags) else { return };
    let (h, axis) = (height / 2.0, axis_matrix(prim));
    out.shape(Part::Cylinder { r, z0: -h, z1: h }, axis);
    out.shape(Part::Disk { r, z: h, down: false }, axis);
    out.shape(Part::Disk { r, z: -h, down: true }, axis);
}

/// A cone of base `radius` at `−height/2`, apex at `+height/2` along `axis`, with its base
/// capped (UsdGeomCone).
fn cone(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some(r) = positive(prim, "radius", 1.0, diags) else { return };
    let Some(height) = positive(prim, "height", 2.0, diags) else { return };
    let (h, axis) = (height / 2.0, axis_matrix(prim));
    out.shape(Part::Cone { r, z0: -h, z1: h }, axis);
    out.shape(Part::Disk { r, z: -h, down: true }, axis);
}

/// A cylinder of `radius` and `height` along `axis` closed by two hemispheres beyond it
/// (UsdGeomCapsule: `height` excludes the caps).
fn capsule(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some(r) = positive(prim, "radius", 0.5, diags) else { return };
    let Some(height) = positive(prim, "height", 1.0, diags) else { return };
    let (h, axis) = (height / 2.0, axis_matrix(prim));
    out.shape(Part::Cylinder { r, z0: -h, z1: h }, axis);
    out.shape(Part::Sphere { r, cz: h, zmin: h, zmax: f64::INFINITY }, axis);
    out.shape(Part::Sphere { r, cz: -h, zmin: f64::NEG_INFINITY, zmax: -h }, axis);
}

/// A `width` × `length` rectangle through the origin whose normal is `axis` (UsdGeomPlane):
/// two triangles, `st` over the rectangle.
fn plane(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
    let Some(w) = positive(prim, "width", 2.0, diags) else { return };
    let Some(l) = positive(prim, "length", 2.0, diags) else { return };
    let axis = axis_matrix(prim);
    let corner = |a: f64, b: f64| {
        let p = axis.transform_point3(DVec3::new(a * w / 2.0, b * l / 2.0, 0.0));
        (p, Vec2::new((a as f32 + 1.0) / 2.0, (b as f32 + 1.0) / 2.0))
    };
    let n = axis.transform_vector3(DVec3::Z);
    let q = [corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0)];
    for [i, j, k] in [[0, 1, 2], [0, 2, 3]] {
        out.emit([q[i].0, q[j].0, q[k].0], Some([n; 3]), Some([q[i].1, q[j].1, q[k].1]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::geometry::xform::tests::stage;

    /// Two cylinders, the second moved by `xform_ops` (USD text) through its parent.
    fn far_apart(ops: &str) -> (Geometry, Vec<String>) {
        let text = format!(
            r#"#usda 1.0
def Cylinder "Near" {{}}
def Xform "Far" {{
    {ops}
    def Cylinder "C" {{}}
}}"#
        );
        let (stage, mut diags) = stage(&text);
        let g = build(&stage, &mut diags);
        let messages = diags
            .items()
            .iter()
            .filter(|d| d.severity == crate::diag::Severity::Error)
            .map(|d| d.message.clone())
            .collect();
        (g, messages)
    }

    #[test]
    fn geometry_beyond_the_extent_is_an_error_before_any_bvh() {
        // 1e38 crashed the BVH builder; 1e13 took it 8 s; 1e300 was silently dropped as
        // "degenerate" (infinite in f32).
        for ops in [
            "double3 xformOp:translate = (1e38, 0, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
            "double3 xformOp:translate = (0, -1e13, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
            // Finite in f64, infinite as the renderer's f32.
            "double3 xformOp:scale = (1e300, 1e300, 1e300)\n    uniform token[] xformOpOrder = [\"xformOp:scale\"]",
        ] {
            let (g, errors) = far_apart(ops);
            assert_eq!(errors.len(), 1, "{ops}: {errors:?}");
            assert!(
                errors[0].starts_with("`/Far/C` reaches (") && errors[0].contains("beyond the scene extent"),
                "{errors:?}"
            );
            assert!(g.triangles.iter().all(|t| t.p.iter().all(|p| p.abs().max_element() <= MAX_EXTENT as f32)));
        }
        let (_, errors) = far_apart(
            "double3 xformOp:translate = (0, 9e6, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
        );
        assert!(errors.is_empty(), "within the extent: {errors:?}");
        // A huge implicit surface without any transform.
        let (stage, mut diags) = stage("#usda 1.0\ndef Sphere \"S\" { double radius = 1e30 }");
        build(&stage, &mut diags);
        assert!(
            diags
                .items()
                .iter()
                .any(|d| d.severity == crate::diag::Severity::Error && d.message.contains("beyond the scene extent"))
        );
    }

    #[test]
    fn triangles_past_the_budget_are_an_error_not_an_allocation() {
        // 137 000 implicit spheres (16 384 triangles each, before spheres were analytic) were
        // killed by the kernel at 24 GB. Cubes stand in for any triangle-making prim.
        let mut text = String::from("#usda 1.0\n");
        for i in 0..5 {
            text += &format!("def Cube \"S{i}\" {{}}\n");
        }
        let (stage, mut diags) = stage(&text);
        let xforms = world_transforms(&stage, &mut diags);
        let per_sphere =
            build_within(&stage, &xforms, GeometryOptions::default(), usize::MAX, &[], &mut diags).triangles.len() / 5;
        let g = build_within(&stage, &xforms, GeometryOptions::default(), 2 * per_sphere + 10, &[], &mut diags);
        assert_eq!(g.triangles.len(), 2 * per_sphere + 10, "bounded by the budget");
        let errors: Vec<&Diagnostic> =
            diags.items().iter().filter(|d| d.severity == crate::diag::Severity::Error).collect();
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(errors[0].message.contains("`/S2` and the prims after it do not fit"), "{}", errors[0].message);
    }

    #[test]
    fn quad_is_two_triangles_with_normals_and_st() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Mesh "M" { uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]
    normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (interpolation = "vertex")
    texCoord2f[] primvars:st = [(0, 0), (0, 1), (1, 1), (1, 0)] (interpolation = "faceVarying")
    double3 xformOp:translate = (0, 2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(diags.items().is_empty(), "{diags:?}");
        assert_eq!(g.triangles.len(), 2);
        for t in &g.triangles {
            assert!(t.has_uv);
            assert!(t.p.iter().all(|p| p.y == 2.0));
            // Winding (-1,0,-1), (-1,0,1), (1,0,1) is right-handed about +Y.
            assert!(t.cross().normalize().dot(Vec3::Y) > 0.99);
            assert_eq!(t.n[0], Vec3::Y);
        }
        assert_eq!(g.triangles[0].uv[1], Vec2::new(0.0, 1.0));
    }

    #[test]
    fn bad_index_is_an_error_not_a_panic() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Mesh "M" {
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 7]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(diags.has_errors());
        assert!(diags.items()[0].message.contains("out of range"), "{:?}", diags.items());
        assert!(g.triangles.is_empty());
    }

    #[test]
    fn counts_not_summing_and_nan_points_are_errors() {
        for body in [
            "int[] faceVertexCounts = [3, 3]\n int[] faceVertexIndices = [0, 1, 2]\n point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]",
            "int[] faceVertexCounts = [3]\n int[] faceVertexIndices = [0, 1, 2]\n point3f[] points = [(0,0,0), (nan,0,0), (0,1,0)]",
        ] {
            let (stage, mut diags) = stage(&format!("#usda 1.0\ndef Mesh \"M\" {{\n{body}\n}}"));
            let g = build(&stage, &mut diags);
            assert!(diags.has_errors(), "{body}");
            assert!(g.triangles.is_empty());
        }
    }

    #[test]
    fn degenerate_triangles_are_skipped_and_counted() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Mesh "M" { uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [3, 3]
    int[] faceVertexIndices = [0, 1, 2, 0, 1, 3]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (2, 0, 0)]
}"#,
        );
        let g = build(&stage, &mut diags);
        assert_eq!(g.triangles.len(), 1);
        assert_eq!(g.degenerate, 1);
        assert!(!diags.has_errors());
        assert_eq!(diags.items().len(), 1);
    }

    #[test]
    fn implicit_prims_invisible_and_guides() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Sphere "S" { double radius = 2 }
def Cube "C" { double size = 1 }
def Cylinder "Y" { token axis = "Y" }
def Sphere "Hidden" { token visibility = "invisible" }
def Xform "G" {
    uniform token purpose = "guide"
    def Sphere "Child" {}
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(!diags.has_errors());
        let paths: Vec<_> = g.prims.iter().map(|p| p.path.as_str()).collect();
        assert_eq!(paths, ["/S", "/C", "/Y"]);
        // The sphere and the cylinder are analytic: no triangles; the cylinder has its side
        // and two caps, turned to y.
        assert!(g.triangles.iter().all(|t| t.prim == 1));
        assert_eq!(g.shapes.iter().filter(|s| s.prim == 0).count(), 1);
        assert_eq!(g.shapes.iter().filter(|s| s.prim == 2).count(), 3);
        let (lo, hi) = g.bounds().unwrap();
        assert!(
            (lo - Vec3::splat(-2.0)).abs().max_element() < 1e-4 && (hi - Vec3::splat(2.0)).abs().max_element() < 1e-4
        );
        let top = g.shapes.iter().filter(|s| s.prim == 2).map(|s| s.world_bounds().1.y).fold(f32::MIN, f32::max);
        assert!((top - 1.0).abs() < 1e-5);
        // A ray down the y axis meets the top cap.
        let down = |s: &&Shape| s.intersect(Vec3::new(0.0, 5.0, 0.2), -Vec3::Y, 0.0, f32::INFINITY).is_some();
        assert!(g.shapes.iter().filter(|s| s.prim == 2).any(|s| down(&s)));
        let cube = g.triangles.iter().filter(|t| t.prim == 1).count();
        assert_eq!(cube, 12);
    }

    /// A point instancer of a unit cube with the given attribute lines.
    fn instancer(attrs: &str) -> (Geometry, Diagnostics, crate::diag::SourceMap) {
        let text = format!(
            "#usda 1.0\ndef PointInstancer \"P\" {{\n    rel prototypes = [</P/Protos/C>]\n{attrs}\n    def Scope \"Protos\" {{\n        def Cube \"C\" {{ double size = 1 }}\n    }}\n}}\n"
        );
        let mut sources = crate::diag::SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("pi.usda", &text, std::path::Path::new("."), &mut sources, &mut diags).unwrap();
        let g = build(&stage, &mut diags);
        (g, diags, sources)
    }

    #[test]
    fn point_instancer_places_points_and_hides_its_prototypes() {
        let (g, diags, _) = instancer(
            "    int[] protoIndices = [0, 0, 0]\n    point3f[] positions = [(0, 0, 0), (5, 0, 0), (0, 5, 0)]\n    quath[] orientations = [(1, 0, 0, 0), (0.70710677, 0, 0, 0.70710677), (1, 0, 0, 0)]\n    float3[] scales = [(1, 1, 1), (2, 1, 1), (1, 1, 1)]\n    int64[] invisibleIds = [2]",
        );
        assert!(!diags.has_errors(), "{diags:?}");
        assert!(g.triangles.is_empty(), "the prototype is drawn only through the instancer");
        assert_eq!(g.prototypes.len(), 1);
        assert_eq!(g.instances.len(), 2, "id 2 (no ids: the index) is invisible");
        // (real, i, j, k) = (cos 45°, 0, 0, sin 45°): 90° about z, applied after the scale:
        // x scaled by 2, then turned onto y.
        let m = g.instances[1].to_world;
        let x = m.transform_vector3(DVec3::X);
        assert!((x - DVec3::new(0.0, 2.0, 0.0)).length() < 1e-6, "{x}");
        assert!((m.transform_point3(DVec3::ZERO) - DVec3::new(5.0, 0.0, 0.0)).length() < 1e-12);
        assert_eq!(g.prims.len(), 1);
        assert_eq!(g.prims[0].path, "/P/Protos/C");
    }

    #[test]
    fn point_instancer_mismatches_are_errors_at_the_attribute() {
        for (attrs, want, line) in [
            (
                "    int[] protoIndices = [0, 0]\n    point3f[] positions = [(0, 0, 0)]",
                "`positions` has 1 entries but `protoIndices` has 2",
                5,
            ),
            (
                "    int[] protoIndices = [0, 3]\n    point3f[] positions = [(0, 0, 0), (1, 1, 1)]",
                "`protoIndices`[1] = 3 is out of range (1 prototypes)",
                4,
            ),
            (
                "    int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n    quath[] orientations = [(0, 0, 0, 0)]",
                "`orientations`[0] is a zero quaternion",
                6,
            ),
            (
                "    int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n    float3[] scales = [(1, 1, 1), (2, 2, 2)]",
                "`scales` has 2 entries",
                6,
            ),
            (
                "    int[] protoIndices = [0]\n    point3f[] positions = [(0, nan, 0)]",
                "`positions`[0] is not finite",
                5,
            ),
            ("    int[] protoIndices = [0]", "1 instances but no `positions`", 4),
            ("    int[] protoIndices = [0]\n    point3f[] positions = [(2e7, 0, 0)]", "beyond the scene extent", 2),
        ] {
            let (g, diags, sources) = instancer(attrs);
            assert!(g.instances.is_empty(), "{attrs}");
            let errors: Vec<_> = diags.items().iter().filter(|d| d.severity == crate::diag::Severity::Error).collect();
            assert_eq!(errors.len(), 1, "{attrs}: {errors:?}");
            assert!(errors[0].message.contains(want), "{}", errors[0].message);
            let rendered = diags.render(&sources);
            assert!(rendered.contains(&format!("pi.usda:{line}:")), "{rendered}");
        }
        // A target that does not exist.
        let (stage, mut diags) = stage(
            "#usda 1.0\ndef PointInstancer \"P\" {\n    rel prototypes = [</Nowhere>]\n    int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n}",
        );
        let g = build(&stage, &mut diags);
        assert!(g.instances.is_empty() && diags.items()[0].message.contains("`/Nowhere` does not exist"));
    }

    #[test]
    fn instanceable_references_share_a_prototype_unless_edited() {
        // Three instances of /Proto, one of them with a local opinion inside it: two share.
        let (stage, mut diags) = stage(
            r#"#usda 1.0
class Xform "Proto" {
    def Mesh "M" { uniform token subdivisionScheme = "none"
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
}
def Xform "A" (instanceable = true references = </Proto>) { double3 xformOp:translate = (5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def Xform "B" (instanceable = true references = </Proto>) { }
def Xform "C" (instanceable = true references = </Proto>) {
    over "M" { point3f[] points = [(0, 0, 0), (2, 0, 0), (0, 2, 0)] }
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        assert_eq!(g.prototypes.len(), 1, "A and B share; C is flattened (its prototype occurs once)");
        assert_eq!(g.instances.len(), 2);
        assert_eq!(g.triangles.len(), 1, "C's own triangle");
        let paths: Vec<_> = g.prims.iter().map(|p| p.path.as_str()).collect();
        assert_eq!(paths, ["/A/M", "/B/M", "/C/M"]);
        assert_eq!(g.instance_prims, [0, 1], "each instance's own prim");
        assert_eq!(g.instances[0].to_world.transform_point3(DVec3::ZERO), DVec3::new(5.0, 0.0, 0.0));
    }

    const CUBE_MESH: &str = r#"
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5]
    point3f[] points = [(-1, -1, -1), (1, -1, -1), (-1, 1, -1), (1, 1, -1),
                        (-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1)]"#;

    /// UsdGeom's default scheme is catmullClark: a cube mesh without `subdivisionScheme` is a
    /// rounded surface inside its cage, with outward normals; `none` and level 0 keep the
    /// cage; holes are skipped; a left-handed mesh's normals face the other way.
    #[test]
    fn meshes_subdivide_by_default_and_the_cage_on_request() {
        let build = |extra: &str, level: u32| {
            let text = format!("#usda 1.0\ndef Mesh \"M\" {{ {extra} {CUBE_MESH} }}\n");
            let (stage, mut diags) = stage(&text);
            let xforms = world_transforms(&stage, &mut diags);
            let g = build_with_options(&stage, &xforms, GeometryOptions { subdiv_level: level }, &mut diags);
            assert!(!diags.has_errors(), "{diags:?}");
            g
        };
        let smooth = build("", 2);
        assert_eq!(smooth.triangles.len(), 6 * 16 * 2);
        for t in &smooth.triangles {
            let centre = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
            assert!(t.p.iter().all(|p| p.abs().max_element() <= 1.0 + 1e-6), "inside the cage");
            assert!(t.cross().dot(centre) > 0.0 && t.n.iter().all(|n| n.dot(centre) > 0.0), "faces outwards");
        }
        let nearest = smooth.triangles.iter().flat_map(|t| t.p).map(|p| p.length()).fold(f32::MAX, f32::min);
        assert!(nearest < 0.9, "rounded: the face centres move in ({nearest})");
        assert_eq!(build(r#"uniform token subdivisionScheme = "none""#, 2).triangles.len(), 12);
        assert_eq!(build("", 0).triangles.len(), 12);
        assert_eq!(build("int[] holeIndices = [0]", 2).triangles.len(), 5 * 16 * 2);
        assert_eq!(build("int[] holeIndices = [0]", 0).triangles.len(), 10);
        let left = build(r#"uniform token orientation = "leftHanded""#, 1);
        for t in &left.triangles {
            let centre = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
            assert!(t.n.iter().all(|n| n.dot(centre) < 0.0), "left-handed winding faces inwards");
        }
    }

    /// Points are spheres of diameter `widths`: a ray down the z axis meets the first at
    /// z = r, exactly; a widths array of the wrong length is an error.
    #[test]
    fn points_render_as_spheres_of_their_widths() {
        let (good, mut diags) = stage(
            "#usda 1.0\ndef Points \"P\" { point3f[] points = [(0, 0, 0), (3, 0, 0)]  float[] widths = [0.5, 1] }\n",
        );
        let xforms = world_transforms(&good, &mut diags);
        let g = build_with(&good, &xforms, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        assert_eq!(g.shapes.len(), 2);
        let accel = crate::render::geometry::accel::Accel::new(g.triangles, g.shapes);
        let hit = accel.intersect(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z, 0.0, f32::INFINITY).expect("hit");
        assert!((hit.t - 4.75).abs() < 1e-5, "{}", hit.t);
        let hit = accel.intersect(Vec3::new(3.0, 0.0, 5.0), -Vec3::Z, 0.0, f32::INFINITY).expect("hit");
        assert!((hit.t - 4.5).abs() < 1e-5, "{}", hit.t);
        let (bad, mut diags) = stage(
            "#usda 1.0\ndef Points \"P\" { point3f[] points = [(0, 0, 0), (3, 0, 0)]  float[] widths = [1, 2, 3] }\n",
        );
        let xforms = world_transforms(&bad, &mut diags);
        build_with(&bad, &xforms, &mut diags);
        assert!(diags.has_errors());
    }

    /// A micro-triangle below f32's resolution inside an ordinary mesh is skipped with a
    /// warning; a prim made only of them is an error (it would vanish).
    #[test]
    fn micro_triangles_are_skipped_unless_they_are_the_whole_prim() {
        let mesh = |points: &str| {
            format!(
                "#usda 1.0\ndef Mesh \"M\" {{ uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [3, 3]\n    \
                 int[] faceVertexIndices = [0, 1, 2, 3, 4, 5]\n    point3f[] points = [{points}] }}\n"
            )
        };
        let (mixed, mut diags) =
            stage(&mesh("(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1e-3), (1e-12, 0, 1e-3), (0, 1e-12, 1e-3)"));
        let xforms = world_transforms(&mixed, &mut diags);
        let g = build_with(&mixed, &xforms, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        assert_eq!(g.triangles.len(), 1);
        assert!(diags.items().iter().any(|d| d.message.contains("they are skipped, 1 others render")), "{diags:?}");
        let (tiny, mut diags) =
            stage(&mesh("(0, 0, 0), (1e-12, 0, 0), (0, 1e-12, 0), (0, 0, 0), (0, 1e-12, 0), (0, 0, 1e-12)"));
        let xforms = world_transforms(&tiny, &mut diags);
        build_with(&tiny, &xforms, &mut diags);
        assert!(diags.has_errors());
    }
}
