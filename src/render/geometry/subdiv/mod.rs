//! Catmull-Clark subdivision of polygon meshes (UsdGeom `subdivisionScheme`, whose default is
//! `catmullClark`: a mesh without the attribute is a subdivision surface, not its cage), with
//! the sharp features of UsdGeom's subdivision tags applied by OpenSubdiv's rules.
//!
//! Uniform refinement to a fixed level, then every vertex is moved to its limit position, so
//! the result lies on the limit surface whatever the level; shading normals are the
//! area-weighted normals of the refined mesh.
//!
//! Sharp features follow OpenSubdiv (`Sdc`, `Vtr`), with USD's options:
//! - **Creases** (`creaseIndices` / `creaseLengths` / `creaseSharpnesses`) give edges a
//!   sharpness, **corners** (`cornerIndices` / `cornerSharpnesses`) give vertices one.
//!   Sharpness ≥ 10 ([`SHARPNESS_INFINITE`]) is infinitely sharp. Semi-sharp features follow
//!   DeRose et al. 1998 with OpenSubdiv's uniform creasing (`Sdc::Options::CREASE_UNIFORM`,
//!   OpenSubdiv's default; UsdGeom has no attribute to choose Chaikin): the sharp rule while
//!   sharpness ≥ 1, sharp and smooth blended by a fractional sharpness, and each child edge
//!   (or vertex) one less sharp than its parent.
//! - A vertex's rule comes from its sharpness and how many sharp edges meet there: smooth
//!   (none), dart (one: the smooth rule), crease (two: `(a + 6p + b) / 8`, the cubic B-spline
//!   of the crease curve) and corner (more, or a sharp vertex: it stays).
//! - Boundary and non-manifold edges are infinitely sharp. `interpolateBoundary`:
//!   `edgeAndCorner` (USD's default) also pins vertices with a single face; `edgeOnly` lets
//!   them follow the boundary curve; `none` drops, as holes, every face that touches a
//!   boundary vertex with a boundary edge not authored infinitely sharp (OpenSubdiv's rule).
//! - Limit positions are exact even where a semi-sharp feature has not decayed at the
//!   rendered level: each vertex's one-ring is refined on its own (a one-ring refines into a
//!   one-ring) until its sharpness is spent, and then projected by the limit mask of its rule
//!   (smooth, crease `(a + 4p + b) / 6`, corner); at a dart, whose smooth limit mask is only
//!   an estimate, until the estimate settles. The surface thus does not depend on
//!   `--subdiv-level`, where OpenSubdiv's uniform `PrimvarRefiner::Limit` applies the rule of
//!   the last level (sharpness left there counts as sharp, darts get the estimate).
//!
//! Face-varying data (`st`) is refined linearly within each face (USD's
//! `faceVaryingLinearInterpolation = "all"`; other values are reported by [`crate::render::support`]).

use crate::diag::{Diagnostic, Diagnostics};
use crate::scene::{Prim, Value};
use glam::{DVec3, Vec2};
use std::collections::{HashMap, HashSet};

/// UsdGeom's `SHARPNESS_INFINITE` (OpenSubdiv's `Sdc::Crease::SHARPNESS_INFINITE`): edges and
/// vertices at least this sharp never soften.
pub const SHARPNESS_INFINITE: f32 = 10.0;

/// UsdGeom `interpolateBoundary`: how boundary edges and corners are subdivided.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BoundaryInterpolation {
    /// `none`: faces touching a boundary that is not authored infinitely sharp are dropped.
    None,
    /// `edgeOnly`: boundary edges are sharp curves; corner vertices follow them.
    EdgeOnly,
    /// `edgeAndCorner` (the default): boundary edges are sharp and corners stay put.
    #[default]
    EdgeAndCorner,
}

/// Sharp features of a subdivision surface (UsdGeom's subdivision tags).
#[derive(Clone, Debug, Default)]
pub struct SubdivTags {
    /// Sharp edges, by their endpoints, with their sharpness (≥ 0); a later entry for the same
    /// edge replaces an earlier one, as OpenSubdiv's factory assigns them.
    pub creases: Vec<([u32; 2], f32)>,
    /// Sharp vertices with their sharpness (≥ 0).
    pub corners: Vec<(u32, f32)>,
    /// Boundary rule.
    pub boundary: BoundaryInterpolation,
}

/// A polygon mesh: points and faces (`counts` vertices each, from `indices`), optional
/// per-face-vertex texture coordinates and per-face hole flags.
#[derive(Clone, Debug, Default)]
pub struct PolyMesh {
    /// Vertex positions.
    pub points: Vec<DVec3>,
    /// Vertices per face (each ≥ 3).
    pub counts: Vec<u32>,
    /// Face-vertex indices into `points`.
    pub indices: Vec<u32>,
    /// Texture coordinates per face-vertex (parallel to `indices`), if any.
    pub uv: Option<Vec<Vec2>>,
    /// Shading primvar values per face-vertex, `varying_width` each (empty when 0), refined
    /// linearly within each face as `uv` is.
    pub varying: Vec<f32>,
    /// Floats per face-vertex in `varying`.
    pub varying_width: usize,
    /// Faces that are holes (`holeIndices`): refined with the rest, never emitted.
    pub holes: Vec<bool>,
    /// Per face, the authored face it comes from (GeomSubsets name authored faces).
    pub origin: Vec<u32>,
    /// Creases, corners and the boundary rule.
    pub tags: SubdivTags,
}

/// A refined quad mesh on the limit surface.
#[derive(Clone, Debug, Default)]
pub struct QuadMesh {
    /// Limit positions.
    pub points: Vec<DVec3>,
    /// Unit vertex normals (area-weighted over incident quads).
    pub normals: Vec<DVec3>,
    /// Quads, in the winding of the faces they refine.
    pub quads: Vec<[u32; 4]>,
    /// Texture coordinates per quad corner.
    pub uv: Option<Vec<[Vec2; 4]>>,
    /// Shading primvar values per quad corner (`4 · varying_width` floats per quad).
    pub varying: Vec<f32>,
    /// Floats per quad corner in `varying`.
    pub varying_width: usize,
    /// Whether each quad lies in a hole (authored, or dropped by `interpolateBoundary = none`).
    pub holes: Vec<bool>,
    /// Per quad, the authored face it refines.
    pub origin: Vec<u32>,
}

/// Number of faces after `level` refinements of `mesh`: an n-gon becomes n quads, then
/// each quad four.
pub fn refined_faces(counts: &[u32], level: u32) -> u64 {
    if level == 0 {
        return counts.len() as u64;
    }
    let first: u64 = counts.iter().map(|&c| c as u64).sum();
    first.saturating_mul(4u64.saturating_pow(level - 1))
}

/// Reads a mesh's subdivision tags (`interpolateBoundary`, creases, corners), validated
/// against its `npoints` points and its faces (`counts`, `indices`, already validated):
/// what does not fit is reported and left out, and the mesh still renders.
pub fn read_tags(prim: &Prim, npoints: usize, counts: &[i64], indices: &[i64], diags: &mut Diagnostics) -> SubdivTags {
    let warn = |diags: &mut Diagnostics, name: &str, message: String| {
        let span = prim.attribute(name).map_or(prim.span, crate::render::geometry::xform::value_span);
        diags.push(Diagnostic::warning(format!("mesh `{}`: {message}", prim.path)).at(span, "here"));
    };
    let ints = |name: &str| prim.value(name).and_then(Value::as_int_array).unwrap_or(&[]);
    let floats = |name: &str| -> Vec<f64> {
        match prim.value(name) {
            Some(v) => v
                .as_float_array()
                .map(<[f64]>::to_vec)
                .or_else(|| v.as_int_array().map(|a| a.iter().map(|&i| i as f64).collect()))
                .unwrap_or_default(),
            None => Vec::new(),
        }
    };
    // OpenSubdiv's factory clamps negative sharpness to smooth; NaN is no sharpness either.
    let sharpness = |s: f64| if s > 0.0 { s.min(f64::from(SHARPNESS_INFINITE)) as f32 } else { 0.0 };
    let boundary = match prim.value("interpolateBoundary").and_then(Value::as_str) {
        None | Some("edgeAndCorner") => BoundaryInterpolation::EdgeAndCorner,
        Some("edgeOnly") => BoundaryInterpolation::EdgeOnly,
        Some("none") => BoundaryInterpolation::None,
        Some(other) => {
            warn(
                diags,
                "interpolateBoundary",
                format!("unknown interpolateBoundary `{other}`; `edgeAndCorner` is used"),
            );
            BoundaryInterpolation::EdgeAndCorner
        }
    };
    let mut tags = SubdivTags { boundary, ..SubdivTags::default() };

    let (crease_indices, lengths, crease_sharpness) =
        (ints("creaseIndices"), ints("creaseLengths"), floats("creaseSharpnesses"));
    if !crease_indices.is_empty() || !lengths.is_empty() {
        let edges_in_chains: i64 = lengths.iter().map(|&l| (l - 1).max(0)).sum();
        let per_crease = crease_sharpness.len() == lengths.len();
        if lengths.iter().any(|&l| l < 2) || lengths.iter().sum::<i64>() != crease_indices.len() as i64 {
            warn(
                diags,
                "creaseLengths",
                format!(
                    "creaseLengths (each at least 2, summing to {}) do not fit creaseIndices; the creases are ignored",
                    crease_indices.len()
                ),
            );
        } else if !per_crease && crease_sharpness.len() as i64 != edges_in_chains {
            warn(
                diags,
                "creaseSharpnesses",
                format!(
                    "creaseSharpnesses has {} values, neither one per crease ({}) nor one per crease edge ({edges_in_chains}); the creases are ignored",
                    crease_sharpness.len(),
                    lengths.len()
                ),
            );
        } else if let Some(bad) = crease_indices.iter().find(|&&i| i < 0 || i as usize >= npoints) {
            warn(
                diags,
                "creaseIndices",
                format!("crease vertex {bad} is out of range (the mesh has {npoints} points); the creases are ignored"),
            );
        } else {
            let mesh_edges = mesh_edges(counts, indices);
            let (mut start, mut edge) = (0usize, 0usize);
            let mut missing = Vec::new();
            for (crease, &length) in lengths.iter().enumerate() {
                let chain = &crease_indices[start..start + length as usize];
                for pair in chain.windows(2) {
                    let s = sharpness(if per_crease { crease_sharpness[crease] } else { crease_sharpness[edge] });
                    let (a, b) = (pair[0] as u32, pair[1] as u32);
                    if mesh_edges.contains(&(a.min(b), a.max(b))) {
                        tags.creases.push(([a, b], s));
                    } else {
                        missing.push((a, b));
                    }
                    edge += 1;
                }
                start += length as usize;
            }
            if let Some(&(a, b)) = missing.first() {
                warn(
                    diags,
                    "creaseIndices",
                    format!(
                        "{} crease edge(s) are not edges of the mesh (the first: {a}-{b}); they are ignored",
                        missing.len()
                    ),
                );
            }
        }
    }

    let (corner_indices, corner_sharpness) = (ints("cornerIndices"), floats("cornerSharpnesses"));
    if !corner_indices.is_empty() || !corner_sharpness.is_empty() {
        if corner_indices.len() != corner_sharpness.len() {
            warn(
                diags,
                "cornerSharpnesses",
                format!(
                    "{} cornerSharpnesses for {} cornerIndices; the corners are ignored",
                    corner_sharpness.len(),
                    corner_indices.len()
                ),
            );
        } else if let Some(bad) = corner_indices.iter().find(|&&i| i < 0 || i as usize >= npoints) {
            warn(
                diags,
                "cornerIndices",
                format!("corner vertex {bad} is out of range (the mesh has {npoints} points); the corners are ignored"),
            );
        } else {
            tags.corners =
                corner_indices.iter().zip(&corner_sharpness).map(|(&v, &s)| (v as u32, sharpness(s))).collect();
        }
    }
    tags
}

/// The edges of faces with three or more vertices, as sorted endpoint pairs.
fn mesh_edges(counts: &[i64], indices: &[i64]) -> HashSet<(u32, u32)> {
    let mut edges = HashSet::with_capacity(indices.len());
    let mut start = 0usize;
    for &count in counts {
        let count = count.max(0) as usize;
        if count >= 3 {
            let face = &indices[start..start + count];
            for k in 0..count {
                let (a, b) = (face[k] as u32, face[(k + 1) % count] as u32);
                edges.insert((a.min(b), a.max(b)));
            }
        }
        start += count;
    }
    edges
}

/// OpenSubdiv's uniform creasing: one less sharp per level; infinite stays infinite.
fn decrement(s: f32) -> f32 {
    if s >= SHARPNESS_INFINITE {
        SHARPNESS_INFINITE
    } else if s > 1.0 {
        s - 1.0
    } else {
        0.0
    }
}

fn is_semi_sharp(s: f32) -> bool {
    s > 0.0 && s < SHARPNESS_INFINITE
}

/// A vertex's subdivision rule (`Sdc::Crease::Rule`); a dart uses the smooth masks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Rule {
    Smooth,
    Crease,
    Corner,
}

/// The rule of a vertex of sharpness `vertex` whose incident edges have `edges` sharpnesses.
fn rule(vertex: f32, edges: &[f32]) -> Rule {
    if vertex > 0.0 {
        return Rule::Corner;
    }
    match edges.iter().filter(|&&s| s > 0.0).count() {
        0 | 1 => Rule::Smooth,
        2 => Rule::Crease,
        _ => Rule::Corner,
    }
}

/// A vertex's neighbourhood for the vertex-vertex and limit masks: its position, its edge
/// neighbours with their edges' sharpness, and the centroids of its faces.
struct Neighbourhood<'a> {
    p: DVec3,
    sharpness: f32,
    neighbours: &'a [DVec3],
    edge_sharpness: &'a [f32],
    face_centroids: DVec3,
    faces: usize,
}

impl Neighbourhood<'_> {
    /// The mask of `rule` (`crease_edges`: the edge sharpnesses that pick a crease's ends).
    fn vertex_mask(&self, rule: Rule, crease_edges: &[f32]) -> DVec3 {
        let p = self.p;
        match rule {
            Rule::Smooth => {
                let valence = self.neighbours.len() as f64;
                let f = self.face_centroids / self.faces as f64;
                let r = self.neighbours.iter().map(|&e| (p + e) / 2.0).sum::<DVec3>() / valence;
                (f + r * 2.0 + p * (valence - 3.0)) / valence
            }
            Rule::Crease => {
                let mut ends = self.neighbours.iter().zip(crease_edges).filter(|(_, s)| **s > 0.0).map(|(&e, _)| e);
                match (ends.next(), ends.next()) {
                    (Some(a), Some(b)) => (a + p * 6.0 + b) / 8.0,
                    _ => p,
                }
            }
            Rule::Corner => p,
        }
    }

    /// The vertex-vertex point (`Sdc::Scheme::ComputeVertexVertexMask`): the parent rule's
    /// mask, blended with the child rule's where sharpness decays to smooth this level.
    fn vertex_point(&self, child_edges: &mut Vec<f32>) -> DVec3 {
        if self.neighbours.is_empty() || (self.sharpness <= 0.0 && self.faces == 0) {
            return self.p;
        }
        let parent = rule(self.sharpness, self.edge_sharpness);
        if parent == Rule::Smooth {
            return self.vertex_mask(Rule::Smooth, self.edge_sharpness);
        }
        let mask = self.vertex_mask(parent, self.edge_sharpness);
        child_edges.clear();
        child_edges.extend(self.edge_sharpness.iter().map(|&s| decrement(s)));
        let child_vertex = decrement(self.sharpness);
        let child = rule(child_vertex, child_edges);
        if child == parent {
            return mask;
        }
        // `Sdc::Crease::ComputeFractionalWeightAtVertex`, uniform creasing: the mean of the
        // sharpness of what becomes smooth this level, at most 1.
        let (mut sum, mut count) = (0.0f32, 0u32);
        if self.sharpness > 0.0 && child_vertex <= 0.0 {
            sum += self.sharpness;
            count += 1;
        }
        for &s in self.edge_sharpness {
            if s > 0.0 && s <= 1.0 {
                sum += s;
                count += 1;
            }
        }
        let weight = if count == 0 { 0.0 } else { f64::from((sum / count as f32).min(1.0)) };
        mask * weight + self.vertex_mask(child, child_edges) * (1.0 - weight)
    }

    /// The limit position by the rule of the vertex's (spent) sharpness, with `diagonals`
    /// the far corners of its quads (OpenSubdiv's Catmark limit masks).
    fn limit(&self, diagonals: DVec3) -> DVec3 {
        let p = self.p;
        match rule(self.sharpness, self.edge_sharpness) {
            Rule::Smooth if self.faces > 2 && self.faces == self.neighbours.len() => {
                let k = self.faces as f64;
                (p * k * k + self.neighbours.iter().sum::<DVec3>() * 4.0 + diagonals) / (k * (k + 5.0))
            }
            Rule::Crease => {
                let mut ends =
                    self.neighbours.iter().zip(self.edge_sharpness).filter(|(_, s)| **s > 0.0).map(|(&e, _)| e);
                match (ends.next(), ends.next()) {
                    (Some(a), Some(b)) => (a + p * 4.0 + b) / 6.0,
                    _ => p,
                }
            }
            _ => p,
        }
    }
}

/// The edge-vertex point (`Sdc::Scheme::ComputeEdgeVertexMask`) of edge `a`-`b` of
/// sharpness `s` between faces with centroids summing to `centroids` (`faces` of them): the
/// midpoint on a sharp edge, the smooth point on a smooth one, blended below sharpness 1.
fn edge_point(a: DVec3, b: DVec3, s: f32, centroids: DVec3, faces: usize) -> DVec3 {
    let mid = (a + b) / 2.0;
    if s >= 1.0 || faces != 2 {
        return mid;
    }
    let smooth = (mid * 2.0 + centroids) / 4.0;
    if s > 0.0 {
        let s = f64::from(s);
        mid * s + smooth * (1.0 - s)
    } else {
        smooth
    }
}

/// Edges and incidence of a polygon mesh.
struct Topology {
    offsets: Vec<usize>,
    /// Edges by sorted endpoints.
    edges: Vec<(u32, u32)>,
    edge_faces: Vec<Vec<u32>>,
    /// Per face-vertex, the edge from it to the next vertex of its face.
    face_edges: Vec<u32>,
    vertex_edges: Vec<Vec<u32>>,
    vertex_faces: Vec<Vec<u32>>,
}

impl Topology {
    fn new(mesh: &PolyMesh) -> Topology {
        let faces = mesh.counts.len();
        let mut offsets = Vec::with_capacity(faces);
        let mut start = 0usize;
        for &c in &mesh.counts {
            offsets.push(start);
            start += c as usize;
        }
        let mut edge_id: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.indices.len());
        let mut edges: Vec<(u32, u32)> = Vec::new();
        let mut edge_faces: Vec<Vec<u32>> = Vec::new();
        let mut face_edges: Vec<u32> = Vec::with_capacity(mesh.indices.len());
        for (f, &o) in offsets.iter().enumerate() {
            let vs = &mesh.indices[o..o + mesh.counts[f] as usize];
            for k in 0..vs.len() {
                let (a, b) = (vs[k], vs[(k + 1) % vs.len()]);
                let key = (a.min(b), a.max(b));
                let id = *edge_id.entry(key).or_insert_with(|| {
                    edges.push(key);
                    edge_faces.push(Vec::new());
                    edges.len() as u32 - 1
                });
                edge_faces[id as usize].push(f as u32);
                face_edges.push(id);
            }
        }
        let n = mesh.points.len();
        let mut vertex_edges: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (e, &(a, b)) in edges.iter().enumerate() {
            vertex_edges[a as usize].push(e as u32);
            if b != a {
                vertex_edges[b as usize].push(e as u32);
            }
        }
        let mut vertex_faces: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (f, &o) in offsets.iter().enumerate() {
            for &v in &mesh.indices[o..o + mesh.counts[f] as usize] {
                vertex_faces[v as usize].push(f as u32);
            }
        }
        Topology { offsets, edges, edge_faces, face_edges, vertex_edges, vertex_faces }
    }

    fn face<'m>(&self, mesh: &'m PolyMesh, f: usize) -> &'m [u32] {
        &mesh.indices[self.offsets[f]..self.offsets[f] + mesh.counts[f] as usize]
    }

    fn other(&self, e: u32, v: usize) -> u32 {
        let (a, b) = self.edges[e as usize];
        if a as usize == v { b } else { a }
    }

    /// Each edge's sharpness: boundary and non-manifold edges are infinitely sharp (OpenSubdiv
    /// sharpens them whatever `interpolateBoundary` says), others as `sharp` has them.
    fn edge_sharpness(&self, sharp: &HashMap<(u32, u32), f32>) -> Vec<f32> {
        self.edges
            .iter()
            .zip(&self.edge_faces)
            .map(
                |(key, faces)| {
                    if faces.len() != 2 { SHARPNESS_INFINITE } else { sharp.get(key).copied().unwrap_or(0.0) }
                },
            )
            .collect()
    }
}

/// Sharpness of a level's edges (nonzero only, by sorted endpoints) and vertices.
struct Sharpness {
    edges: HashMap<(u32, u32), f32>,
    vertices: Vec<f32>,
}

/// The cage's sharpness with OpenSubdiv's boundary tagging
/// (`Far::TopologyRefinerFactoryBase::applyComponentTagsAndBoundarySharpness`); marks the
/// faces `interpolateBoundary = none` drops as holes.
fn base_sharpness(mesh: &mut PolyMesh, topo: &Topology) -> Sharpness {
    let mut edges: HashMap<(u32, u32), f32> = HashMap::new();
    for &([a, b], s) in &mesh.tags.creases {
        let key = (a.min(b), a.max(b));
        if s > 0.0 {
            edges.insert(key, s);
        } else {
            edges.remove(&key);
        }
    }
    let mut vertices = vec![0.0f32; mesh.points.len()];
    for &(v, s) in &mesh.tags.corners {
        if let Some(slot) = vertices.get_mut(v as usize) {
            *slot = s;
        }
    }
    for (v, sharpness) in vertices.iter_mut().enumerate() {
        let (vertex_edges, vertex_faces) = (&topo.vertex_edges[v], &topo.vertex_faces[v]);
        let face_counts = || vertex_edges.iter().map(|&e| topo.edge_faces[e as usize].len());
        let boundary_edges = face_counts().filter(|&c| c < 2).count();
        let non_manifold_edges = face_counts().filter(|&c| c > 2).count();
        let non_manifold = non_manifold_edges > 0
            || if boundary_edges == 0 {
                vertex_faces.len() != vertex_edges.len()
            } else {
                boundary_edges != 2 || vertex_faces.len() + 1 != vertex_edges.len()
            };
        if mesh.tags.boundary == BoundaryInterpolation::None
            && (boundary_edges > 0 || non_manifold)
            && vertex_edges.iter().any(|&e| {
                let key = topo.edges[e as usize];
                topo.edge_faces[e as usize].len() == 1 && edges.get(&key).is_none_or(|&s| s < SHARPNESS_INFINITE)
            })
        {
            for &f in vertex_faces {
                mesh.holes[f as usize] = true;
            }
        }
        let topological_corner = vertex_faces.len() == 1 && vertex_edges.len() == 2;
        // An interior non-manifold crease (two edges with extra "fins") stays a crease.
        let fin_crease = non_manifold_edges == 2 && boundary_edges == 0 && vertex_faces.len() > vertex_edges.len();
        if (topological_corner && mesh.tags.boundary == BoundaryInterpolation::EdgeAndCorner)
            || (non_manifold && !topological_corner && !fin_crease)
        {
            *sharpness = SHARPNESS_INFINITE;
        }
    }
    Sharpness { edges, vertices }
}

/// One uniform Catmull-Clark step: every face becomes quads; sharpness decays by one.
fn refine(mesh: &PolyMesh, topo: &Topology, sharp: &Sharpness) -> (PolyMesh, Sharpness) {
    let faces = mesh.counts.len();
    let face_points: Vec<DVec3> = (0..faces)
        .map(|f| topo.face(mesh, f).iter().map(|&v| mesh.points[v as usize]).sum::<DVec3>() / mesh.counts[f] as f64)
        .collect();
    let edge_sharpness = topo.edge_sharpness(&sharp.edges);
    let edge_points: Vec<DVec3> = topo
        .edges
        .iter()
        .enumerate()
        .map(|(e, &(a, b))| {
            let f = &topo.edge_faces[e];
            let centroids = f.iter().map(|&f| face_points[f as usize]).sum::<DVec3>();
            edge_point(mesh.points[a as usize], mesh.points[b as usize], edge_sharpness[e], centroids, f.len())
        })
        .collect();

    let n = mesh.points.len();
    let (mut neighbours, mut incident_sharpness, mut child_edges) = (Vec::new(), Vec::new(), Vec::new());
    let vertex_points: Vec<DVec3> = (0..n)
        .map(|v| {
            neighbours.clear();
            incident_sharpness.clear();
            for &e in &topo.vertex_edges[v] {
                neighbours.push(mesh.points[topo.other(e, v) as usize]);
                incident_sharpness.push(edge_sharpness[e as usize]);
            }
            let hood = Neighbourhood {
                p: mesh.points[v],
                sharpness: sharp.vertices[v],
                neighbours: &neighbours,
                edge_sharpness: &incident_sharpness,
                face_centroids: topo.vertex_faces[v].iter().map(|&f| face_points[f as usize]).sum(),
                faces: topo.vertex_faces[v].len(),
            };
            hood.vertex_point(&mut child_edges)
        })
        .collect();

    // New points: vertices, then edges, then faces.
    let edge_base = n as u32;
    let face_base = edge_base + topo.edges.len() as u32;
    let mut child_edge_sharpness = HashMap::new();
    for (e, &(a, b)) in topo.edges.iter().enumerate() {
        let s = decrement(edge_sharpness[e]);
        if s > 0.0 {
            let mid = edge_base + e as u32;
            child_edge_sharpness.insert((a.min(mid), a.max(mid)), s);
            child_edge_sharpness.insert((b.min(mid), b.max(mid)), s);
        }
    }
    let mut vertices: Vec<f32> = sharp.vertices.iter().map(|&s| decrement(s)).collect();
    vertices.resize(face_base as usize + faces, 0.0);
    let mut points = vertex_points;
    points.extend(edge_points);
    points.extend(face_points);

    let quads = mesh.indices.len();
    let mut counts = Vec::with_capacity(quads);
    let mut indices = Vec::with_capacity(quads * 4);
    let mut uv = mesh.uv.as_ref().map(|_| Vec::with_capacity(quads * 4));
    let w = mesh.varying_width;
    let mut varying = Vec::with_capacity(quads * 4 * w);
    let mut centre = vec![0.0f32; w];
    let mut holes = Vec::with_capacity(quads);
    let mut origin = Vec::with_capacity(quads);
    for (f, &o) in topo.offsets.iter().enumerate() {
        let vs = topo.face(mesh, f);
        let m = vs.len();
        let centre_uv = mesh.uv.as_ref().map(|t| t[o..o + m].iter().copied().sum::<Vec2>() / m as f32);
        if w > 0 {
            for (j, c) in centre.iter_mut().enumerate() {
                *c = (0..m).map(|k| mesh.varying[(o + k) * w + j]).sum::<f32>() / m as f32;
            }
        }
        for k in 0..m {
            let prev = (k + m - 1) % m;
            counts.push(4);
            indices.extend([
                vs[k],
                edge_base + topo.face_edges[o + k],
                face_base + f as u32,
                edge_base + topo.face_edges[o + prev],
            ]);
            if let (Some(out), Some(t), Some(c)) = (uv.as_mut(), mesh.uv.as_ref(), centre_uv) {
                let (here, next, before) = (t[o + k], t[o + (k + 1) % m], t[o + prev]);
                out.extend([here, (here + next) / 2.0, c, (before + here) / 2.0]);
            }
            if w > 0 {
                let at = |j: usize| &mesh.varying[(o + j) * w..(o + j + 1) * w];
                let (here, next, before) = (at(k), at((k + 1) % m), at(prev));
                varying.extend_from_slice(here);
                varying.extend(here.iter().zip(next).map(|(a, b)| (a + b) / 2.0));
                varying.extend_from_slice(&centre);
                varying.extend(before.iter().zip(here).map(|(a, b)| (a + b) / 2.0));
            }
            holes.push(mesh.holes.get(f).copied().unwrap_or(false));
            origin.push(mesh.origin.get(f).copied().unwrap_or(f as u32));
        }
    }
    let child =
        PolyMesh { points, counts, indices, uv, varying, varying_width: w, holes, origin, tags: SubdivTags::default() };
    (child, Sharpness { edges: child_edge_sharpness, vertices })
}

/// A vertex's one-ring on a quad mesh, refined on its own: edge neighbours with their
/// edges' sharpness and face counts, and quads as (edge slot, edge slot, far corner).
#[derive(Default)]
struct Ring {
    p: DVec3,
    sharpness: f32,
    neighbours: Vec<DVec3>,
    edge_sharpness: Vec<f32>,
    edge_faces: Vec<u32>,
    quads: Vec<(usize, usize, DVec3)>,
    // Scratch space, reused.
    centroid_sums: Vec<DVec3>,
    next_neighbours: Vec<DVec3>,
    child_edges: Vec<f32>,
}

impl Ring {
    fn hood(&self) -> Neighbourhood<'_> {
        let centroids =
            self.quads.iter().map(|&(a, b, d)| (self.p + self.neighbours[a] + d + self.neighbours[b]) / 4.0);
        Neighbourhood {
            p: self.p,
            sharpness: self.sharpness,
            neighbours: &self.neighbours,
            edge_sharpness: &self.edge_sharpness,
            face_centroids: centroids.sum(),
            faces: self.quads.len(),
        }
    }

    fn limit(&self) -> DVec3 {
        self.hood().limit(self.quads.iter().map(|q| q.2).sum())
    }

    fn semi_sharp(&self) -> bool {
        is_semi_sharp(self.sharpness) || self.edge_sharpness.iter().any(|&s| is_semi_sharp(s))
    }

    /// One refinement of the ring: the vertex point, the edge points and the face points of
    /// its quads, which form the child vertex's ring.
    fn refine(&mut self) {
        let mut child_edges = std::mem::take(&mut self.child_edges);
        let centre = self.hood().vertex_point(&mut child_edges);
        self.child_edges = child_edges;
        self.centroid_sums.clear();
        self.centroid_sums.resize(self.neighbours.len(), DVec3::ZERO);
        for q in &mut self.quads {
            let centroid = (self.p + self.neighbours[q.0] + q.2 + self.neighbours[q.1]) / 4.0;
            self.centroid_sums[q.0] += centroid;
            self.centroid_sums[q.1] += centroid;
            q.2 = centroid;
        }
        self.next_neighbours.clear();
        for (i, &e) in self.neighbours.iter().enumerate() {
            let point =
                edge_point(self.p, e, self.edge_sharpness[i], self.centroid_sums[i], self.edge_faces[i] as usize);
            self.next_neighbours.push(point);
        }
        std::mem::swap(&mut self.neighbours, &mut self.next_neighbours);
        for s in &mut self.edge_sharpness {
            *s = decrement(*s);
        }
        self.sharpness = decrement(self.sharpness);
        self.p = centre;
    }
}

/// Most refinements of a dart's ring: its limit estimate gains about a factor of two per
/// level, so this reaches f64 precision from any cage.
const DART_REFINEMENTS: usize = 64;

/// Limit positions of a quad mesh's vertices (after at least one refinement, when every face
/// is a quad). Where semi-sharp sharpness is left, the vertex's ring is refined until it is
/// spent (at most nine times, since sharpness below 10 loses one per level).
fn limit_points(mesh: &PolyMesh, topo: &Topology, sharp: &Sharpness) -> Vec<DVec3> {
    let edge_sharpness = topo.edge_sharpness(&sharp.edges);
    let mut ring = Ring::default();
    (0..mesh.points.len())
        .map(|v| {
            ring.p = mesh.points[v];
            ring.sharpness = sharp.vertices[v];
            ring.neighbours.clear();
            ring.edge_sharpness.clear();
            ring.edge_faces.clear();
            ring.quads.clear();
            let incident = &topo.vertex_edges[v];
            for &e in incident {
                ring.neighbours.push(mesh.points[topo.other(e, v) as usize]);
                ring.edge_sharpness.push(edge_sharpness[e as usize]);
                ring.edge_faces.push(topo.edge_faces[e as usize].len() as u32);
            }
            for &f in &topo.vertex_faces[v] {
                let o = topo.offsets[f as usize];
                let q = &mesh.indices[o..o + 4];
                let Some(k) = q.iter().position(|&i| i as usize == v) else { continue };
                let slot = |e: u32| incident.iter().position(|&i| i == e);
                if let (Some(a), Some(b)) = (slot(topo.face_edges[o + k]), slot(topo.face_edges[o + (k + 3) % 4])) {
                    ring.quads.push((a, b, mesh.points[q[(k + 2) % 4] as usize]));
                }
            }
            for _ in 0..SHARPNESS_INFINITE as usize {
                if !ring.semi_sharp() {
                    break;
                }
                ring.refine();
            }
            let mut limit = ring.limit();
            // At a dart the smooth limit mask is only an estimate (its subdivision matrix is
            // not the smooth one), closer at every level: refine until it settles, so the
            // limit does not depend on the level (OpenSubdiv applies the mask at the last level).
            if ring.sharpness <= 0.0 && ring.edge_sharpness.iter().filter(|&&s| s > 0.0).count() == 1 {
                for _ in 0..DART_REFINEMENTS {
                    ring.refine();
                    let next = ring.limit();
                    let settled = (next - limit).length() <= 1e-14 * (1.0 + next.length());
                    limit = next;
                    if settled {
                        break;
                    }
                }
            }
            limit
        })
        .collect()
}

/// Refines `mesh` `level` times (at least once) and projects it to the limit surface.
pub fn catmull_clark(mesh: &PolyMesh, level: u32) -> QuadMesh {
    let mut cage = mesh.clone();
    cage.holes.resize(cage.counts.len(), false);
    let topo = Topology::new(&cage);
    let sharp = base_sharpness(&mut cage, &topo);
    let (mut refined, mut sharp) = refine(&cage, &topo, &sharp);
    let mut topo = Topology::new(&refined);
    for _ in 1..level.max(1) {
        (refined, sharp) = refine(&refined, &topo, &sharp);
        topo = Topology::new(&refined);
    }
    let points = limit_points(&refined, &topo, &sharp);
    let quads: Vec<[u32; 4]> = refined.indices.chunks_exact(4).map(|q| [q[0], q[1], q[2], q[3]]).collect();
    let mut normals = vec![DVec3::ZERO; points.len()];
    for q in &quads {
        let [a, b, c, d] = q.map(|i| points[i as usize]);
        // Twice the quad's vector area: the cross product of its diagonals.
        let area_normal = (c - a).cross(d - b);
        for &i in q {
            normals[i as usize] += area_normal;
        }
    }
    for n in &mut normals {
        *n = n.normalize_or_zero();
    }
    let uv = refined.uv.map(|t| t.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect());
    QuadMesh {
        points,
        normals,
        quads,
        uv,
        varying: refined.varying,
        varying_width: refined.varying_width,
        holes: refined.holes,
        origin: refined.origin,
    }
}

#[cfg(test)]
mod tests;
