//! World-space geometry from a composed stage.
//!
//! Meshes are fan-triangulated into world-space triangles; Cube and Plane are triangles too
//! (they are flat, so exactly). The curved implicit prims (Sphere, Cylinder, Cone, Capsule)
//! become analytic [`Shape`]s, intersected exactly in object space: nothing is tessellated.
//! Malformed meshes are diagnosed (never a panic); zero-area triangles are skipped and counted.

use super::shapes::{Part, Shape};
use super::subdiv::{PolyMesh, catmull_clark, refined_faces};
use super::xform::{PrimXform, value_span, world_transforms};
use crate::compose::scene::is_renderable;
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::scene::{Attribute, Prim, Stage, Value};
use glam::{DMat3, DMat4, DVec3, Vec2, Vec3};

/// The largest world-space coordinate (absolute value, scene units, after every transform)
/// geometry may have: 1e7. The renderer works in f32, whose spacing at 1e7 is already one
/// unit, so detail and ray offsets break down beyond it; and far-apart geometry (1e13) made
/// the BVH builder crawl while 1e38 crashed it. A prim that reaches past it is an error.
pub const MAX_EXTENT: f64 = 1e7;

/// The most triangles a scene may have: 2^25 (33.5 million, about 3.5 GB of triangles plus
/// their BVH). Implicit surfaces are tessellated into 16 384 triangles each, so a 50 MB
/// scene of 137 000 spheres asked for 2.2 billion triangles and was killed by the kernel; past
/// this budget the scene is an error naming the first prim that did not fit.
pub const MAX_TRIANGLES: usize = 1 << 25;

/// The most faces subdivision may make of one mesh: 2^18 (262 144 quads, half a million
/// triangles). A mesh is refined to `--subdiv-level` levels, or fewer when that would pass
/// this, so a dense cage is not multiplied into millions of triangles it does not need.
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
}

/// The triangles of a whole stage.
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    /// World-space triangles.
    pub triangles: Vec<Triangle>,
    /// Analytic surfaces.
    pub shapes: Vec<Shape>,
    /// Renderable, visible prims, indexed by [`Triangle::prim`].
    pub prims: Vec<GeomPrim>,
    /// Zero-area or non-finite triangles that were skipped.
    pub degenerate: usize,
}

impl Geometry {
    /// World-space bounds `(min, max)` of every triangle and shape; `None` when empty.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let shape_corners = self.shapes.iter().flat_map(|s| {
            let (lo, hi) = s.world_bounds();
            [lo, hi]
        });
        let mut it = self.triangles.iter().flat_map(|t| t.p).chain(shape_corners);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }
}

/// Builds the triangles of every visible renderable prim of `stage`.
pub fn build(stage: &Stage, diags: &mut Diagnostics) -> Geometry {
    let xforms = world_transforms(stage, diags);
    build_with(stage, &xforms, diags)
}

/// As [`build`], with transforms already computed.
pub fn build_with(stage: &Stage, xforms: &[PrimXform], diags: &mut Diagnostics) -> Geometry {
    build_within(stage, xforms, GeometryOptions::default(), MAX_TRIANGLES, diags)
}

/// As [`build_with`], with options.
pub fn build_with_options(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    diags: &mut Diagnostics,
) -> Geometry {
    build_within(stage, xforms, options, MAX_TRIANGLES, diags)
}

/// As [`build_with_options`], with a triangle budget other than [`MAX_TRIANGLES`] (for tests).
fn build_within(
    stage: &Stage,
    xforms: &[PrimXform],
    options: GeometryOptions,
    budget: usize,
    diags: &mut Diagnostics,
) -> Geometry {
    let mut geometry = Geometry::default();
    for (id, prim) in stage.depth_first() {
        let xf = xforms[id.0 as usize];
        if xf.hidden || !is_renderable(prim) {
            continue;
        }

        let index = geometry.prims.len() as u32;
        let mut out = Emitter {
            geometry: &mut geometry,
            m: xf.world,
            prim: index,
            beyond_extent: None,
            budget,
            over_budget: false,
            subdiv_level: options.subdiv_level,
        };
        match prim.type_name.as_deref() {
            Some("Mesh") => mesh(prim, &mut out, diags),
            Some("Sphere") => sphere(prim, &mut out, diags),
            Some("Cube") => cube(prim, &mut out, diags),
            Some("Cylinder") => cylinder(prim, &mut out, diags),
            Some("Cone") => cone(prim, &mut out, diags),
            Some("Capsule") => capsule(prim, &mut out, diags),
            Some("Plane") => plane(prim, &mut out, diags),
            Some("Points") => points(prim, &mut out, diags),
            _ => {}
        }
        if out.over_budget {
            diags.push(
                Diagnostic::error(format!(
                    "the scene has more than {budget} triangles; `{}` and the prims after it do not fit",
                    prim.path
                ))
                .at(prim.span, "the first prim past the triangle budget")
                .note("implicit surfaces (Sphere, Cylinder) are tessellated into up to 16384 triangles each"),
            );
            geometry.prims.push(GeomPrim { path: prim.path.clone(), span: prim.span });
            break;
        }
        if let Some(p) = out.beyond_extent {
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
            diags.push(d.note("strata renders in f32: coordinates must be finite and within ±1e7 after transforms"));
        }
        geometry.prims.push(GeomPrim { path: prim.path.clone(), span: prim.span });
    }
    if geometry.degenerate > 0 {
        diags.push(Diagnostic::warning(format!(
            "{} degenerate (zero-area or non-finite) triangle(s) skipped",
            geometry.degenerate
        )));
    }
    geometry
}

/// Transforms local-space triangles and shapes to world space and appends them.
struct Emitter<'g> {
    geometry: &'g mut Geometry,
    m: DMat4,
    prim: u32,
    /// The first world-space point past [`MAX_EXTENT`] (or non-finite), if any.
    beyond_extent: Option<DVec3>,
    /// The most triangles the scene may have ([`MAX_TRIANGLES`]).
    budget: usize,
    /// A triangle was dropped because the scene reached its budget.
    over_budget: bool,
    /// Subdivision levels for subdivision-surface meshes.
    subdiv_level: u32,
}

impl Emitter<'_> {
    /// Emits one triangle given in local space (`n` in local space, not necessarily unit).
    fn emit(&mut self, p: [DVec3; 3], n: Option<[DVec3; 3]>, uv: Option<[Vec2; 3]>) {
        let world = p.map(|p| self.m.transform_point3(p));
        // Non-finite points (NaN included) are beyond any extent too.
        if let Some(far) = world.iter().find(|w| !w.is_finite() || w.abs().max_element() > MAX_EXTENT) {
            self.beyond_extent.get_or_insert(*far);
            return;
        }
        if self.geometry.triangles.len() >= self.budget {
            // Reported by `build_with` after this prim; the memory stays bounded.
            self.over_budget = true;
            return;
        }
        let wp = world.map(|p| p.as_vec3());
        let cross = (wp[1] - wp[0]).cross(wp[2] - wp[0]);
        let len2 = cross.length_squared();
        if len2.is_nan() || len2 <= 0.0 || !len2.is_finite() {
            self.geometry.degenerate += 1;
            return;
        }
        let ng = cross / len2.sqrt();
        // Normals transform by the inverse transpose.
        let nm = DMat3::from_mat4(self.m).inverse().transpose();
        let n = match n {
            Some(n) => n.map(|n| {
                let w = (nm * n).as_vec3().normalize_or_zero();
                if w == Vec3::ZERO || !w.is_finite() { ng } else { w }
            }),
            None => [ng; 3],
        };
        let has_uv = uv.is_some();
        let uv = uv.unwrap_or([Vec2::ZERO, Vec2::X, Vec2::Y]);
        self.geometry.triangles.push(Triangle { p: wp, n, uv, prim: self.prim, has_uv });
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
            Some(shape) => self.geometry.shapes.push(shape),
            None => self.geometry.degenerate += 1,
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
struct Primvar<'a> {
    data: &'a [f64],
    width: usize,
    interpolation: &'a str,
    indices: Option<&'a [i64]>,
    attr: &'a Attribute,
}

impl<'a> Primvar<'a> {
    fn get(prim: &'a Prim, name: &str, width: usize, default_interp: &'a str) -> Option<Primvar<'a>> {
        let attr = prim.attribute(name)?;
        let (w, data) = attr.get()?.as_tuple_array()?;
        if w != width {
            return None;
        }
        let interpolation = attr.meta("interpolation").and_then(Value::as_str).unwrap_or(default_interp);
        let indices = prim.value(&format!("{name}:indices")).and_then(Value::as_int_array);
        Some(Primvar { data, width, interpolation, indices, attr })
    }

    /// Number of elements the interpolation needs, given the mesh's counts.
    fn expected(&self, points: usize, faces: usize, face_vertices: usize) -> Option<usize> {
        match self.interpolation {
            "vertex" | "varying" => Some(points),
            "faceVarying" => Some(face_vertices),
            "uniform" => Some(faces),
            "constant" => Some(1),
            _ => None,
        }
    }

    /// The element for (face, face-vertex ordinal, point index).
    fn at(&self, face: usize, corner: usize, point: usize) -> Option<&'a [f64]> {
        let slot = match self.interpolation {
            "vertex" | "varying" => point,
            "faceVarying" => corner,
            "uniform" => face,
            _ => 0,
        };
        let element = match self.indices {
            Some(ix) => usize::try_from(*ix.get(slot)?).ok()?,
            None => slot,
        };
        self.data.get(element * self.width..(element + 1) * self.width)
    }
}

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
        "catmullClark" | "loop" if out.subdiv_level > 0 => {
            if scheme == "loop" {
                diags.push(
                    Diagnostic::warning(format!(
                        "mesh `{}`: Loop subdivision is approximated by Catmull-Clark (a slightly different smooth surface)",
                        prim.path
                    ))
                    .at(scheme_attr.map_or(prim.span, value_span), "here"),
                );
            }
            let poly = poly_mesh(points, counts, indices, st.as_ref(), &holes);
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
    for (face, &count) in counts.iter().enumerate() {
        let count = count as usize;
        if count < 3 || holes.contains(&(face as i64)) {
            start += count;
            continue;
        }
        let corner = |k: usize| -> (DVec3, Option<DVec3>, Option<Vec2>) {
            let c = start + k;
            let pi = indices[c] as usize;
            let n = normals.as_ref().and_then(|pv| pv.at(face, c, pi)).map(|n| DVec3::new(n[0], n[1], n[2]));
            let uv = st.as_ref().and_then(|pv| pv.at(face, c, pi)).map(|t| Vec2::new(t[0] as f32, t[1] as f32));
            (point(pi), n, uv)
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
            out.emit(p, n, uv);
        }
        start += count;
    }
}

/// The faces of a validated mesh with three or more vertices, as a [`PolyMesh`], with `st`
/// per face-vertex when every corner has one.
fn poly_mesh(
    points: &[f64],
    counts: &[i64],
    indices: &[i64],
    st: Option<&Primvar>,
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
            for (c, &index) in indices.iter().enumerate().skip(start).take(count) {
                let pi = index as usize;
                mesh.indices.push(pi as u32);
                if let Some(out) = uv.as_mut() {
                    match st.and_then(|pv| pv.at(face, c, pi)) {
                        Some(t) => out.push(Vec2::new(t[0] as f32, t[1] as f32)),
                        None => uv = None,
                    }
                }
            }
        }
        start += count;
    }
    mesh.uv = uv;
    mesh
}

/// Emits the limit surface of `poly`, refined to the emitter's level or as many levels as fit
/// [`SUBDIV_FACE_BUDGET`] (at least one).
fn subdivided(poly: &PolyMesh, left_handed: bool, flip: bool, out: &mut Emitter) {
    let mut level = out.subdiv_level;
    while level > 1 && refined_faces(&poly.counts, level) > SUBDIV_FACE_BUDGET {
        level -= 1;
    }
    let q = catmull_clark(poly, level);
    // Limit normals follow the right-hand rule of the faces' winding; a left-handed mesh
    // faces the other way.
    let sign = if left_handed { -1.0 } else { 1.0 };
    for (i, quad) in q.quads.iter().enumerate() {
        if q.holes[i] {
            continue;
        }
        for mut corners in [[0, 1, 2], [0, 2, 3]] {
            if flip {
                corners.swap(1, 2);
            }
            let p = corners.map(|k| q.points[quad[k] as usize]);
            let n = corners.map(|k| q.normals[quad[k] as usize] * sign);
            let uv = q.uv.as_ref().map(|uv| corners.map(|k| uv[i][k]));
            out.emit(p, Some(n), uv);
        }
    }
}

/// Whether a primvar's length fits its interpolation; warns and drops it when not.
fn check_primvar(prim: &Prim, pv: &Primvar, points: usize, faces: usize, fv: usize, diags: &mut Diagnostics) -> bool {
    let elements = pv.indices.map_or(pv.data.len() / pv.width, <[i64]>::len);
    let ok = pv.expected(points, faces, fv).is_some_and(|e| e == elements)
        && pv.indices.is_none_or(|ix| ix.iter().all(|&i| i >= 0 && (i as usize) < pv.data.len() / pv.width))
        && pv.data.iter().all(|c| c.is_finite());
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
    for (i, p) in points.chunks_exact(3).enumerate() {
        let width = widths[if widths.len() == 1 { 0 } else { i }];
        let centre = DVec3::new(p[0], p[1], p[2]);
        if !(width.is_finite() && width > 0.0 && centre.is_finite()) {
            out.geometry.degenerate += 1;
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
    use crate::render::xform::tests::stage;

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
            build_within(&stage, &xforms, GeometryOptions::default(), usize::MAX, &mut diags).triangles.len() / 5;
        let g = build_within(&stage, &xforms, GeometryOptions::default(), 2 * per_sphere + 10, &mut diags);
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
        let accel = super::super::accel::Accel::new(g.triangles, g.shapes);
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
}
