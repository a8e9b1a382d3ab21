//! True displacement (docs/DESIGN.md rule 6): the surfaces of prims whose composed material
//! has a displacement that moves geometry are diced into micro-triangles about a pixel long
//! and each micro-vertex is moved along the surface normal by the rule-6 combination of the
//! layers' heights, evaluated (masks included) at the undisplaced point.
//!
//! - **Which prims.** Those whose material has a layer with a `displacement_bound` (the
//!   built-in `displacement` node, or any node with a `bound` input). `bump` layers never move
//!   geometry; the integrator bends the shading normal by them (and by everything, on prims
//!   that were not diced). Nothing else is re-tessellated, so a scene without displacement
//!   pays nothing. Quadrics become meshes only here ([`Part::base_mesh`]).
//! - **Dicing.** Every edge is split at its midpoint while it spans more than `rate` pixels
//!   (its length over its distance to the camera, against one pixel's angle) and is longer
//!   than a scene-relative floor. The decision depends on the edge's two end points only, so
//!   the two triangles sharing an edge split it identically: no T-junctions. A triangle with
//!   one, two or three split edges becomes two, three or four and is diced again. Midpoints of
//!   quadric edges are projected back onto the exact surface. When the micro-triangles would
//!   pass the budget, the rate doubles until they fit (reported).
//! - **Watertight.** Vertices are welded by exact position within one surface and one
//!   material: a prim, or the faces of one mesh whose GeomSubsets share a material. Each
//!   welded vertex has one normal (the mean of its corners' normals, so hard edges open no
//!   crack) and one height, so shared edges stay shared after displacement. Separate prims
//!   that touch (a box on a floor) stay separate, and a mesh opens along the border of
//!   subsets with different materials: each side moves by its own material's height.
//! - **Bound.** Each layer's height is clamped to `±bound`; clamped and non-finite samples
//!   are counted and reported per layer.
//! - **Shading.** Micro-triangles carry smooth normals of the displaced mesh and the source's
//!   texture coordinates; detail finer than the dicing rate is not bumped back.
//!
//! Geometry inside instances is not diced (its prototype is shared by instances at different
//! distances); a warning says so and those prims are bumped.

use crate::abi::layering::{self, Relief};
use crate::abi::{Globals, MaterialCode, PrimvarValues};
use crate::diag::{Diagnostic, Diagnostics};
use crate::render::camera::Camera;
use crate::render::geometry::primvars::{ObjectSpace, PrimvarRef, PrimvarSlot, fill_object_space, reads_object_space};
use crate::render::geometry::shapes::Shape;
use crate::render::geometry::{Geometry, Triangle, Triangles};
use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::fmt;
use std::time::Instant;

/// The default `--dicing-rate`: micro-triangle edges of about one pixel.
pub const DEFAULT_DICING_RATE: f32 = 1.0;

/// The default micro-triangle budget of a scene: 2^22 (about a gigabyte of triangles and
/// BVH). Past it the dicing rate is coarsened until the scene fits.
pub const DEFAULT_MICRO_TRIANGLE_BUDGET: usize = 1 << 22;

/// Splits per edge at most, whatever the rate (a guard against a camera inside a surface;
/// the scene-relative edge floor normally stops dicing first).
const MAX_DEPTH: u32 = 24;

/// How displaced surfaces are diced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DicingOptions {
    /// Target micro-triangle edge length in pixels (`--dicing-rate`).
    pub rate: f32,
    /// The most micro-triangles the scene may have.
    pub budget: usize,
    /// Image width and height in pixels (dicing measures edges against one pixel).
    pub resolution: (usize, usize),
}

impl Default for DicingOptions {
    fn default() -> DicingOptions {
        DicingOptions { rate: DEFAULT_DICING_RATE, budget: DEFAULT_MICRO_TRIANGLE_BUDGET, resolution: (640, 480) }
    }
}

/// What displacement cost, for `--stats` and benchmarks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DisplacementStats {
    /// Prims diced.
    pub prims: usize,
    /// Triangles (and quadric base-mesh triangles) they had before dicing.
    pub source_triangles: usize,
    /// Micro-triangles they became.
    pub micro_triangles: usize,
    /// Displaced vertices (each evaluated once).
    pub vertices: usize,
    /// The dicing rate used, in pixels (above the requested one when the budget bound).
    pub rate: f32,
    /// Height samples clamped to their layer's bound.
    pub clamped: u64,
    /// Height samples that were NaN or infinite (taken as 0).
    pub non_finite: u64,
    /// Bytes of the micro-triangles (before the BVH).
    pub bytes: usize,
    /// Bytes of scratch held at the peak of dicing (welded vertices, faces, the midpoint
    /// table, per-vertex heights and normals; counted from capacities), all freed after.
    pub scratch_bytes: usize,
    /// Dicing and evaluation time in milliseconds.
    pub ms: f64,
}

impl fmt::Display for DisplacementStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "displacement: {} prims, {} source triangles → {} micro-triangles at {} px ({} vertices, {:.1} MiB) \
             in {:.1} ms (scratch peak {:.1} MiB); {} samples clamped, {} non-finite",
            self.prims,
            self.source_triangles,
            self.micro_triangles,
            self.rate,
            self.vertices,
            self.bytes as f64 / (1024.0 * 1024.0),
            self.ms,
            self.scratch_bytes as f64 / (1024.0 * 1024.0),
            self.clamped,
            self.non_finite
        )
    }
}

/// The result of [`displace`]: which prims were diced, and what it cost.
#[derive(Clone, Debug, Default)]
pub struct Displaced {
    /// Per renderable prim: whether its surface was diced and moved.
    pub prims: Vec<bool>,
    /// `None` when nothing was displaced.
    pub stats: Option<DisplacementStats>,
}

/// Whether a material has a layer whose displacement moves geometry.
/// A layer counts only where rule 6 lets its displacement be seen (`layering::liveness`), so
/// optimised and unoptimised compilations of one stack dice alike.
pub fn moves_geometry(material: &dyn MaterialCode) -> bool {
    let layers = &material.info().layers;
    let live = layering::liveness(layers);
    layers
        .iter()
        .zip(&live)
        .any(|(l, live)| l.displacement.is_some() && l.displacement_bound.is_some() && live.displacement)
}

/// A welded vertex of the surface being diced (f32 like the triangles it becomes: the
/// midpoint of two vertices is computed once per edge, so neighbours agree bit for bit).
#[derive(Clone, Copy, Debug)]
struct Vertex {
    /// Undisplaced world position; displaced in place once its height is known.
    p: Vec3,
    /// Unit displacement direction (the outward surface normal, averaged where corners meet).
    n: Vec3,
    /// Where the displacement is evaluated in texture space (the creating corner's).
    uv: Vec2,
    /// The source face that created it (its prim, tangents, quadric).
    source: u32,
    /// Where it lies in that face (barycentric weights of its corners 1 and 2): where its
    /// primvars are read.
    b: Vec2,
}

/// A triangle corner: a welded vertex and where it lies in its source triangle
/// (barycentric weights of the source's corners 1 and 2), which gives its face-varying
/// texture coordinate and the source face's own normal there.
#[derive(Clone, Copy, Debug)]
struct Corner {
    v: u32,
    b: Vec2,
}

/// A triangle being diced, with the index of the source it came from.
#[derive(Clone, Copy, Debug)]
struct Face {
    c: [Corner; 3],
    source: u32,
}

/// What a source triangle contributes to its micro-triangles.
#[derive(Clone, Copy, Debug)]
struct Source {
    prim: u32,
    has_uv: bool,
    /// The quadric part it was cut from (midpoints are projected onto it), if any.
    shape: Option<u32>,
    /// Flat tangents (triangles); a quadric's come from its surface at each vertex.
    dpdu: Vec3,
    dpdv: Vec3,
    /// Its corners' texture coordinates and normals.
    uv: [Vec2; 3],
    n: [Vec3; 3],
    /// Its primvar values (re-sampled for each micro-triangle).
    primvars: PrimvarRef,
}

impl Source {
    fn uv_at(&self, b: Vec2) -> Vec2 {
        self.uv[0] * (1.0 - b.x - b.y) + self.uv[1] * b.x + self.uv[2] * b.y
    }

    fn n_at(&self, b: Vec2) -> Vec3 {
        (self.n[0] * (1.0 - b.x - b.y) + self.n[1] * b.x + self.n[2] * b.y).normalize_or_zero()
    }
}

/// The corners of a source triangle, as barycentric weights.
const SOURCE_CORNERS: [Vec2; 3] = [Vec2::ZERO, Vec2::X, Vec2::Y];

/// The key of an undirected edge.
fn edge(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The welded base mesh of every displaced prim.
struct Base {
    vertices: Vec<Vertex>,
    faces: Vec<Face>,
    sources: Vec<Source>,
    shapes: Vec<Shape>,
    /// Hard edges: edges whose faces have different normals at an end (a cube's edges, a
    /// cylinder's rims). Only along them does the displacement direction average the faces';
    /// elsewhere it is the face's own normal, so flat faces stay flat.
    creases: HashSet<(u32, u32)>,
}

/// Which corners may weld: those of one surface (a prim, or the mesh a GeomSubset's faces
/// belong to) bound to one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct WeldGroup {
    surface: u32,
    material: usize,
}

/// The key two corners weld on: their group and their position's exact bits, with −0 as +0.
fn weld_key(group: WeldGroup, p: Vec3) -> (WeldGroup, [u32; 3]) {
    (group, p.to_array().map(|x| (x + 0.0).to_bits()))
}

impl Base {
    /// Welds the corners of `triangles` and of the base meshes of `shapes`, each within the
    /// [`WeldGroup`] `group_of` gives its prim.
    fn build(triangles: Triangles, shapes: Vec<Shape>, group_of: impl Fn(u32) -> WeldGroup) -> Base {
        let mut base =
            Base { vertices: Vec::new(), faces: Vec::new(), sources: Vec::new(), shapes, creases: HashSet::new() };
        let mut index: HashMap<(WeldGroup, [u32; 3]), u32> = HashMap::new();
        let mut normal_sums: Vec<DVec3> = Vec::new();
        let mut corner = |base: &mut Base, prim: u32, p: Vec3, n: DVec3, uv: Vec2, k: usize| -> Corner {
            let source = base.sources.len() as u32;
            let v = *index.entry(weld_key(group_of(prim), p)).or_insert_with(|| {
                base.vertices.push(Vertex { p, n: n.as_vec3(), uv, source, b: SOURCE_CORNERS[k] });
                normal_sums.push(DVec3::ZERO);
                base.vertices.len() as u32 - 1
            });
            normal_sums[v as usize] += n;
            Corner { v, b: SOURCE_CORNERS[k] }
        };
        for t in &triangles {
            let (dpdu, dpdv) = crate::render::geometry::accel::tangents(t.p, t.uv, t.cross().normalize_or_zero());
            let c = [0, 1, 2].map(|k| corner(&mut base, t.prim, t.p[k], t.n[k].as_dvec3(), t.uv[k], k));
            base.faces.push(Face { c, source: base.sources.len() as u32 });
            base.sources.push(Source {
                prim: t.prim,
                has_uv: t.has_uv,
                shape: None,
                dpdu,
                dpdv,
                uv: t.uv,
                n: t.n,
                primvars: t.primvars,
            });
        }
        drop(triangles);
        for s in 0..base.shapes.len() {
            let shape = base.shapes[s].clone();
            for tri in shape.part.base_mesh() {
                let geometry = tri.map(|(local, _)| shape.part.local_geometry(local));
                let world = geometry.map(|(p, ..)| shape.to_world.transform_point3(p).as_vec3());
                let normals = geometry.map(|(_, n, ..)| (shape.normal_to_world * n).normalize_or_zero());
                let cross = (world[1] - world[0]).cross(world[2] - world[0]).as_dvec3();
                if cross.length_squared() == 0.0 || !cross.is_finite() {
                    continue;
                }
                // Wind outward: the analytic normal decides.
                let order = if cross.dot(normals[0] + normals[1] + normals[2]) < 0.0 { [0, 2, 1] } else { [0, 1, 2] };
                let c = [0, 1, 2]
                    .map(|j| corner(&mut base, shape.prim, world[order[j]], normals[order[j]], tri[order[j]].1, j));
                base.faces.push(Face { c, source: base.sources.len() as u32 });
                base.sources.push(Source {
                    prim: shape.prim,
                    has_uv: true,
                    shape: Some(s as u32),
                    dpdu: Vec3::ZERO,
                    dpdv: Vec3::ZERO,
                    uv: order.map(|k| tri[k].1),
                    n: order.map(|k| normals[k].as_vec3()),
                    primvars: shape.primvars,
                });
            }
        }
        for (v, sum) in base.vertices.iter_mut().zip(&normal_sums) {
            let n = sum.normalize_or_zero();
            if n != DVec3::ZERO && n.is_finite() {
                v.n = n.as_vec3();
            }
        }
        // An edge is hard where the faces sharing it disagree on the normal at either end.
        let mut first: HashMap<(u32, u32), [Vec3; 2]> = HashMap::new();
        for f in &base.faces {
            let source = &base.sources[f.source as usize];
            for k in 0..3 {
                let (a, b) = (f.c[k], f.c[(k + 1) % 3]);
                let key = edge(a.v, b.v);
                let (na, nb) = (source.n_at(a.b), source.n_at(b.b));
                let ends = if a.v < b.v { [na, nb] } else { [nb, na] };
                match first.get(&key) {
                    None => {
                        first.insert(key, ends);
                    }
                    Some(seen) => {
                        if seen[0].dot(ends[0]) < 1.0 - 1e-5 || seen[1].dot(ends[1]) < 1.0 - 1e-5 {
                            base.creases.insert(key);
                        }
                    }
                }
            }
        }
        base
    }

    /// The shading globals at vertex `v` before displacement: its position, normal, texture
    /// coordinates and tangents (a quadric's from its exact surface, a mesh's from its face).
    fn globals<'p>(&self, v: &Vertex, primvars: PrimvarValues<'p>) -> Globals<'p> {
        let source = &self.sources[v.source as usize];
        let (dpdu, dpdv) = match source.shape {
            Some(s) => {
                let shape = &self.shapes[s as usize];
                let (.., dpdu, dpdv) = shape.part.local_geometry(shape.to_object.transform_point3(v.p.as_dvec3()));
                (shape.to_world.transform_vector3(dpdu).as_vec3(), shape.to_world.transform_vector3(dpdv).as_vec3())
            }
            None => (source.dpdu, source.dpdv),
        };
        Globals {
            p: v.p.to_array(),
            n: v.n.to_array(),
            ng: v.n.to_array(),
            i: (-v.n).to_array(),
            dpdu: dpdu.to_array(),
            dpdv: dpdv.to_array(),
            st_footprint: [0.0; 4],
            u: v.uv.x,
            v: v.uv.y,
            primvars,
            params: Default::default(),
        }
    }
}

/// Edges whose midpoint is outside the view (by this margin, in NDC) are diced this many
/// times coarser: they are seen only in shadows and reflections.
const OFFSCREEN_SCALE: f32 = 4.0;
const VIEW_MARGIN: f32 = 1.2;

/// One dicing pass: the edge test, the vertices it creates and the faces it emits.
struct Dicer<'a> {
    base: &'a Base,
    vertices: Vec<Vertex>,
    midpoints: HashMap<(u32, u32), u32>,
    /// Hard edges, the base's and their halves.
    creases: HashSet<(u32, u32)>,
    faces: Vec<Face>,
    eye: Vec3,
    /// World to clip space, for the on-screen test.
    to_clip: glam::Mat4,
    /// The split threshold at unit distance, in radians (small-angle): √2 · rate pixels,
    /// so that diced edges end between 0.7 and 1.4 times the rate.
    angle: f32,
    /// Edges shorter than this are never split.
    floor: f32,
    budget: usize,
}

impl Dicer<'_> {
    /// Whether edge `(a, b)` is split: a function of its two end points only, so every face
    /// sharing the edge decides alike.
    fn splits(&self, a: u32, b: u32) -> bool {
        let (pa, pb) = (self.vertices[a as usize].p, self.vertices[b as usize].p);
        let len = pa.distance(pb);
        // About eight f32 steps of the edge's own coordinates (far from the origin a midpoint
        // would round onto an end point), and an absolute floor; both per edge, so one large
        // or distant prim does not coarsen the others.
        let floor = (pa.abs().max(pb.abs()).max_element() * 1e-6).max(self.floor);
        if len <= floor {
            return false;
        }
        let mid = (pa + pb) * 0.5;
        let clip = self.to_clip * mid.extend(1.0);
        let on_screen = clip.w > 0.0 && clip.x.abs() <= VIEW_MARGIN * clip.w && clip.y.abs() <= VIEW_MARGIN * clip.w;
        let angle = if on_screen { self.angle } else { self.angle * OFFSCREEN_SCALE };
        len > angle * mid.distance(self.eye).max(self.floor)
    }

    /// The vertex halfway along edge `(a, b)` of a face from `source`, created once per edge.
    fn midpoint(&mut self, a: Corner, b: Corner, source: u32) -> Corner {
        let bary = (a.b + b.b) * 0.5;
        let key = edge(a.v, b.v);
        if let Some(&v) = self.midpoints.get(&key) {
            return Corner { v, b: bary };
        }
        let src = &self.base.sources[source as usize];
        let (va, vb) = (self.vertices[a.v as usize], self.vertices[b.v as usize]);
        // Along a hard edge the direction averages the faces' (as its ends do), so both sides
        // move together; elsewhere it is the face's own normal, so flat faces stay flat.
        let crease = self.creases.contains(&key);
        let face_normal = src.n_at(bary);
        let averaged = (va.n + vb.n).try_normalize().unwrap_or(va.n);
        let n = if crease || face_normal == Vec3::ZERO { averaged } else { face_normal };
        let mut vertex = Vertex { p: (va.p + vb.p) * 0.5, n, uv: src.uv_at(bary), source, b: bary };
        if let Some(s) = src.shape {
            // On a quadric, the midpoint goes back onto the exact surface.
            let shape = &self.base.shapes[s as usize];
            let (p, n, ..) = shape.part.local_geometry(shape.to_object.transform_point3(vertex.p.as_dvec3()));
            let n = (shape.normal_to_world * n).normalize_or_zero().as_vec3();
            let p = shape.to_world.transform_point3(p).as_vec3();
            if p.is_finite() && n != Vec3::ZERO {
                vertex.p = p;
                if !crease {
                    vertex.n = n;
                }
            }
        }
        let v = self.vertices.len() as u32;
        self.vertices.push(vertex);
        self.midpoints.insert(key, v);
        if crease {
            self.creases.insert(edge(a.v, v));
            self.creases.insert(edge(v, b.v));
        }
        Corner { v, b: bary }
    }

    /// Dices `face` into `self.faces`; `Err` when the budget is passed.
    fn dice(&mut self, face: Face, depth: u32) -> Result<(), ()> {
        let c = face.c;
        let split = [self.splits(c[0].v, c[1].v), self.splits(c[1].v, c[2].v), self.splits(c[2].v, c[0].v)];
        let count = split.iter().filter(|&&s| s).count();
        if count == 0 || depth >= MAX_DEPTH {
            if self.faces.len() >= self.budget {
                return Err(());
            }
            self.faces.push(face);
            return Ok(());
        }
        let source = face.source;
        let face_of = |c: [Corner; 3]| Face { c, source };
        // Rotate so the split edges come first: edge k joins corners k and k + 1.
        let first = match count {
            1 => split.iter().position(|&s| s).unwrap_or(0),
            2 => (split.iter().position(|&s| !s).unwrap_or(0) + 1) % 3,
            _ => 0,
        };
        let [a, b, cc] = [c[first], c[(first + 1) % 3], c[(first + 2) % 3]];
        match count {
            1 => {
                let m = self.midpoint(a, b, source);
                self.dice(face_of([a, m, cc]), depth + 1)?;
                self.dice(face_of([m, b, cc]), depth + 1)
            }
            2 => {
                // Edges (a, b) and (b, cc) split; the quad left is cut on its shorter diagonal.
                let mab = self.midpoint(a, b, source);
                let mbc = self.midpoint(b, cc, source);
                self.dice(face_of([mab, b, mbc]), depth + 1)?;
                let p = |c: Corner| self.vertices[c.v as usize].p;
                if p(a).distance_squared(p(mbc)) <= p(mab).distance_squared(p(cc)) {
                    self.dice(face_of([a, mab, mbc]), depth + 1)?;
                    self.dice(face_of([a, mbc, cc]), depth + 1)
                } else {
                    self.dice(face_of([a, mab, cc]), depth + 1)?;
                    self.dice(face_of([mab, mbc, cc]), depth + 1)
                }
            }
            _ => {
                let mab = self.midpoint(a, b, source);
                let mbc = self.midpoint(b, cc, source);
                let mca = self.midpoint(cc, a, source);
                self.dice(face_of([a, mab, mca]), depth + 1)?;
                self.dice(face_of([mab, b, mbc]), depth + 1)?;
                self.dice(face_of([mca, mbc, cc]), depth + 1)?;
                self.dice(face_of([mab, mbc, mca]), depth + 1)
            }
        }
    }
}

/// Heights outside the bound, per (material, layer): count and the largest |height|.
type Excess = HashMap<(usize, usize), (u64, f32)>;

/// What evaluating the displacement of a run of vertices found.
#[derive(Default)]
struct Evaluated {
    clamped: Excess,
    non_finite: Excess,
    /// The first shader fault: (prim, message).
    fault: Option<(u32, String)>,
    faults: u64,
}

impl Evaluated {
    fn merge(mut self, other: Evaluated) -> Evaluated {
        for (map, from) in [(&mut self.clamped, other.clamped), (&mut self.non_finite, other.non_finite)] {
            for (key, (count, largest)) in from {
                let entry = map.entry(key).or_insert((0, 0.0));
                entry.0 += count;
                entry.1 = entry.1.max(largest);
            }
        }
        self.fault = self.fault.or(other.fault);
        self.faults += other.faults;
        self
    }
}

/// Per-thread scratch of [`height`]: one float per layer.
struct Scratch {
    masks: Vec<f32>,
    heights: Vec<f32>,
    /// The vertex's primvar values, as the material lays them out.
    primvars: Vec<f32>,
}

/// The rule-6 height of the layers that move geometry at `g` (masks and heights at the
/// undisplaced point), each layer's height clamped to its bound. Every mask that weights a
/// displacement is read, a bump layer's too: a `mix` bump layer hides the relief below it.
fn height(
    material: &dyn MaterialCode,
    m: usize,
    g: &Globals,
    prim: u32,
    scratch: &mut Scratch,
    out: &mut Evaluated,
) -> f32 {
    let layers = &material.info().layers;
    let nl = layers.len();
    scratch.masks.resize(nl, 0.0);
    scratch.heights.resize(nl, 0.0);
    let (masks, heights) = (&mut scratch.masks[..nl], &mut scratch.heights[..nl]);
    let run = |masks: &mut [f32], heights: &mut [f32]| -> Result<(), crate::abi::ShaderError> {
        for (i, layer) in layers.iter().enumerate() {
            masks[i] = match (layer.mask_weights_displacement(), layer.constant_mask) {
                (false, _) => 0.0,
                (true, Some(m)) => m,
                (true, None) => material.mask(g, i)?,
            };
        }
        material.displacement(g, heights)
    };
    if let Err(e) = run(masks, heights) {
        out.faults += 1;
        out.fault.get_or_insert((prim, e.to_string()));
        return 0.0;
    }
    for (i, layer) in layers.iter().enumerate() {
        let Some(bound) = layer.displacement_bound else { continue };
        let h = heights[i];
        if !h.is_finite() {
            out.non_finite.entry((m, i)).or_insert((0, 0.0)).0 += 1;
            heights[i] = 0.0;
        } else if h.abs() > bound {
            let entry = out.clamped.entry((m, i)).or_insert((0, 0.0));
            entry.0 += 1;
            entry.1 = entry.1.max(h.abs());
            heights[i] = h.clamp(-bound, bound);
        }
    }
    layering::combine_relief(layers, heights, masks, Relief::Geometry)
}

/// Dices and displaces, in place, every world prim of `geometry` whose material (by
/// `prim_material`, into `materials`) moves geometry. `camera` must have the image's aspect.
pub fn displace(
    geometry: &mut Geometry,
    prim_material: &[usize],
    materials: &[&dyn MaterialCode],
    camera: &Camera,
    options: &DicingOptions,
    diags: &mut Diagnostics,
) -> Displaced {
    let start = Instant::now();
    let nprims = geometry.prims.len();
    // Once per material (liveness allocates), then per prim.
    let material_moves: Vec<bool> = materials.iter().map(|m| moves_geometry(*m)).collect();
    let mut moves: Vec<bool> = (0..nprims)
        .map(|p| prim_material.get(p).and_then(|&m| material_moves.get(m)).copied().unwrap_or(false))
        .collect();
    if !moves.iter().any(|&m| m) {
        return Displaced { prims: vec![false; nprims], stats: None };
    }
    let mut instanced: Vec<u32> = geometry.instance_prims.iter().copied().filter(|&p| moves[p as usize]).collect();
    instanced.sort_unstable();
    instanced.dedup();
    if let Some(&first) = instanced.first() {
        let more = if instanced.len() > 1 { format!(" (and {} more)", instanced.len() - 1) } else { String::new() };
        diags.push(
            Diagnostic::warning(format!(
                "displacement inside instances is not diced: `{}`{more} renders with its displacement as a bump",
                geometry.prims[first as usize].path
            ))
            .at(geometry.prims[first as usize].span, "instanced here")
            .note("the prototype is shared by instances at different distances; make the prim not instanceable to displace it"),
        );
        for p in instanced {
            moves[p as usize] = false;
        }
    }
    let (diced, kept): (Triangles, Triangles) =
        std::mem::take(&mut geometry.triangles).into_iter().partition(|t| moves[t.prim as usize]);
    let (diced_shapes, kept_shapes): (Vec<Shape>, Vec<Shape>) =
        std::mem::take(&mut geometry.shapes).into_iter().partition(|s| moves[s.prim as usize]);
    geometry.triangles = kept;
    geometry.shapes = kept_shapes;
    let mut displaced = vec![false; nprims];
    for prim in diced.iter().map(|t| t.prim).chain(diced_shapes.iter().map(|s| s.prim)) {
        displaced[prim as usize] = true;
    }
    let mut base = Base::build(diced, diced_shapes, |prim| {
        let of = geometry.prims.get(prim as usize).and_then(|p| p.subset_of).unwrap_or(prim);
        WeldGroup { surface: of, material: prim_material.get(prim as usize).copied().unwrap_or(usize::MAX) }
    });
    let (lo, hi) =
        base.vertices.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), v| (lo.min(v.p), hi.max(v.p)));
    let extent = if base.vertices.is_empty() { 1.0 } else { (hi - lo).length().max(f32::MIN_POSITIVE) };
    // Edges are never split below a billionth of the diced geometry's size (a camera inside
    // a surface); `Dicer::splits` adds each edge's own f32 floor.
    let floor = (extent * 1e-9).max(f32::MIN_POSITIVE);
    let (width, height_px) = options.resolution;
    let camera = camera.with_aspect(width as f32 / height_px.max(1) as f32);
    let pixel = camera.pixel_angle(width.max(1));
    let requested = if options.rate.is_finite() && options.rate > 0.0 { options.rate } else { DEFAULT_DICING_RATE };
    let mut rate = requested;
    let base_vertices = std::mem::take(&mut base.vertices);
    let base_count = base_vertices.len();
    let mut vertices = base_vertices;
    // Dice; past the budget, coarsen and dice again (each doubling roughly quarters the count).
    let (mut vertices, faces) = loop {
        vertices.truncate(base_count);
        let mut dicer = Dicer {
            base: &base,
            vertices,
            midpoints: HashMap::new(),
            creases: base.creases.clone(),
            faces: Vec::with_capacity(base.faces.len()),
            eye: camera.origin(),
            to_clip: camera.camera_to_ndc() * camera.world_to_camera(),
            angle: pixel * rate * std::f32::consts::SQRT_2,
            floor,
            budget: options.budget.max(base.faces.len()),
        };
        let fits = base.faces.iter().try_for_each(|&f| dicer.dice(f, 0)).is_ok();
        let Dicer { vertices: diced_vertices, faces, .. } = dicer;
        if fits {
            break (diced_vertices, faces);
        }
        vertices = diced_vertices;
        rate *= 2.0;
    };
    if rate != requested {
        diags.push(Diagnostic::warning(format!(
            "displacement: dicing at {requested} px would pass the budget of {} micro-triangles; diced at {rate} px",
            options.budget
        )));
    }
    // One height per welded vertex, in parallel; then each vertex moves along its normal.
    let primvar_slots: Vec<Vec<PrimvarSlot>> =
        materials.iter().map(|m| geometry.primvars.slots(&m.info().primvars)).collect();
    let material_of =
        |v: &Vertex| prim_material.get(base.sources[v.source as usize].prim as usize).copied().unwrap_or(0);
    let (heights, evaluated): (Vec<f32>, Evaluated) = vertices
        .par_chunks(4096)
        .map(|chunk| {
            let mut found = Evaluated::default();
            let mut scratch = Scratch { masks: Vec::new(), heights: Vec::new(), primvars: Vec::new() };
            let heights: Vec<f32> = chunk
                .iter()
                .map(|v| {
                    let m = material_of(v);
                    let source = &base.sources[v.source as usize];
                    let Some(material) = materials.get(m) else { return 0.0 };
                    // The primvars the material reads, as the integrator fills them at a hit
                    // (dicing is in world space: a prim's own object space).
                    let slots = &primvar_slots[m];
                    let used = material.info().primvar_floats;
                    let mut primvars = std::mem::take(&mut scratch.primvars);
                    primvars.clear();
                    primvars.resize(used, 0.0);
                    if !slots.is_empty() {
                        geometry.primvars.fill(
                            source.primvars,
                            [1.0 - v.b.x - v.b.y, v.b.x, v.b.y],
                            slots,
                            &mut primvars,
                        );
                        if reads_object_space(slots) {
                            let space =
                                geometry.prims.get(source.prim as usize).map_or(ObjectSpace::IDENTITY, |p| p.object);
                            fill_object_space(&space, slots, &mut primvars);
                        }
                    }
                    let g = base.globals(v, PrimvarValues::new(&primvars));
                    let h = height(*material, m, &g, source.prim, &mut scratch, &mut found);
                    scratch.primvars = primvars;
                    h
                })
                .collect();
            (heights, found)
        })
        .reduce(
            || (Vec::new(), Evaluated::default()),
            |(mut a, fa), (b, fb)| {
                a.extend(b);
                (a, fa.merge(fb))
            },
        );
    for (v, &h) in vertices.iter_mut().zip(&heights) {
        v.p += v.n * h;
    }
    // Displaced geometry is held to the extent every other prim is (a huge bound allows it).
    if let Some(v) = vertices
        .iter()
        .find(|v| !v.p.is_finite() || v.p.abs().max_element() as f64 > crate::render::geometry::MAX_EXTENT)
    {
        let prim = &geometry.prims[base.sources[v.source as usize].prim as usize];
        diags.push(
            Diagnostic::error(format!(
                "the displaced surface of `{}` reaches {}, beyond ±{:e} scene units",
                prim.path,
                v.p,
                crate::render::geometry::MAX_EXTENT
            ))
            .at(prim.span, "displaced here")
            .note("lower the displacement node's `bound` (heights are clamped to it)"),
        );
    }
    // Smooth normals of the displaced mesh: area-weighted face normals per welded vertex.
    let mut normals = vec![Vec3::ZERO; vertices.len()];
    for f in &faces {
        let [a, b, c] = f.c.map(|c| vertices[c.v as usize].p);
        let cross = (b - a).cross(c - a);
        for corner in f.c {
            normals[corner.v as usize] += cross;
        }
    }
    for (n, v) in normals.iter_mut().zip(&vertices) {
        *n = n.try_normalize().filter(|n| n.is_finite()).unwrap_or(v.n);
    }
    let scratch_bytes = {
        use std::mem::size_of;
        base.faces.capacity() * size_of::<Face>()
            + base.sources.capacity() * size_of::<Source>()
            + vertices.capacity() * (size_of::<Vertex>() + size_of::<f32>() + size_of::<Vec3>())
            + faces.capacity() * size_of::<Face>()
    };
    let (before, bytes_before) = (geometry.triangles.len(), geometry.triangles.bytes());
    geometry.triangles.reserve_exact(faces.len());
    let table = &mut geometry.primvars;
    geometry.triangles.extend(faces.iter().map(|f| {
        let source = &base.sources[f.source as usize];
        Triangle {
            p: f.c.map(|c| vertices[c.v as usize].p),
            n: f.c.map(|c| normals[c.v as usize]),
            uv: f.c.map(|c| source.uv_at(c.b)),
            prim: source.prim,
            has_uv: source.has_uv,
            primvars: table.resample(source.primvars, f.c.map(|c| [1.0 - c.b.x - c.b.y, c.b.x, c.b.y])),
        }
    }));
    let micro = geometry.triangles.len() - before;
    report(&evaluated, geometry, prim_material, materials, &base, &vertices, diags);
    let stats = DisplacementStats {
        prims: displaced.iter().filter(|&&d| d).count(),
        source_triangles: base.faces.len(),
        micro_triangles: micro,
        vertices: vertices.len(),
        rate,
        clamped: evaluated.clamped.values().map(|(c, _)| c).sum(),
        non_finite: evaluated.non_finite.values().map(|(c, _)| c).sum(),
        bytes: geometry.triangles.bytes() - bytes_before,
        scratch_bytes,
        ms: start.elapsed().as_secs_f64() * 1e3,
    };
    Displaced { prims: displaced, stats: Some(stats) }
}

/// Warnings for clamped and non-finite heights (one per material layer) and shader faults.
fn report(
    evaluated: &Evaluated,
    geometry: &Geometry,
    prim_material: &[usize],
    materials: &[&dyn MaterialCode],
    base: &Base,
    vertices: &[Vertex],
    diags: &mut Diagnostics,
) {
    // A prim of each material, to point at.
    let prim_of = |m: usize| {
        let p = base.sources.iter().map(|s| s.prim).find(|&p| prim_material.get(p as usize) == Some(&m)).unwrap_or(0);
        &geometry.prims[p as usize]
    };
    let mut keys: Vec<_> = evaluated.clamped.keys().chain(evaluated.non_finite.keys()).copied().collect();
    keys.sort_unstable();
    keys.dedup();
    for (m, layer) in keys {
        let info = &materials[m].info().layers[layer];
        let prim = prim_of(m);
        if let Some(&(count, largest)) = evaluated.clamped.get(&(m, layer)) {
            diags.push(
                Diagnostic::warning(format!(
                    "displacement of layer `{}` on `{}`: {count} of {} heights passed its bound {} (largest |height| \
                     {largest}) and were clamped",
                    info.slot,
                    prim.path,
                    vertices.len(),
                    info.displacement_bound.unwrap_or(f32::INFINITY)
                ))
                .at(prim.span, "displaced here")
                .note("raise the displacement node's `bound` to at least the largest height"),
            );
        }
        if let Some(&(count, _)) = evaluated.non_finite.get(&(m, layer)) {
            diags.push(
                Diagnostic::warning(format!(
                    "displacement of layer `{}` on `{}`: {count} heights were NaN or infinite and were taken as 0",
                    info.slot, prim.path
                ))
                .at(prim.span, "displaced here"),
            );
        }
    }
    if let Some((prim, message)) = &evaluated.fault {
        let prim = &geometry.prims[*prim as usize];
        diags.push(
            Diagnostic::warning(format!(
                "displacement on `{}`: {message} at {} vertices; they were not moved",
                prim.path, evaluated.faults
            ))
            .at(prim.span, "displaced here"),
        );
    }
}
