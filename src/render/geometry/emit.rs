//! One renderable prim's geometry: meshes (fan-triangulated, or subdivided to the limit
//! surface), Cube and Plane as triangles, the curved implicit prims and Points as analytic
//! shapes, their primvars, moved to the target space by an [`Emitter`].

use super::*;

/// Emits the geometry of one renderable prim.
pub(super) fn emit_prim(prim: &Prim, out: &mut Emitter, diags: &mut Diagnostics) {
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
pub(super) struct Emitter<'g> {
    pub(super) triangles: &'g mut Triangles,
    pub(super) shapes: &'g mut Vec<Shape>,
    pub(super) degenerate: &'g mut usize,
    pub(super) m: DMat4,
    /// Inverse transpose of `m`'s linear part, for normals.
    pub(super) nm: DMat3,
    pub(super) prim: u32,
    /// The first target-space point past [`MAX_EXTENT`] (or non-finite), if any.
    pub(super) beyond_extent: Option<DVec3>,
    /// Triangles whose longest edge is below [`MIN_TRIANGLE_EDGE`]: their count and the
    /// first one's vertex 0 and longest edge.
    pub(super) too_small: Option<(usize, DVec3, f64)>,
    /// Triangles this emitter kept.
    pub(super) emitted: usize,
    /// The most triangles `triangles` may hold (what [`MAX_TRIANGLES`] leaves).
    pub(super) budget: usize,
    /// A triangle was dropped because the scene reached its budget.
    pub(super) over_budget: bool,
    /// Subdivision levels for subdivision-surface meshes.
    pub(super) subdiv_level: u32,
    /// For meshes with GeomSubset bindings: the prim index of each face (empty: all `prim`).
    pub(super) face_prims: Vec<u32>,
    /// Where primvar values go.
    pub(super) table: &'g mut PrimvarTable,
    /// The current mesh's per-corner layout (`u32::MAX`: none), for [`Emitter::emit_with`].
    pub(super) corner_layout: u32,
    /// One set of values for every primitive of the current prim (analytic prims, Points).
    pub(super) constant: PrimvarRef,
}

impl<'g> Emitter<'g> {
    pub(super) fn new(
        triangles: &'g mut Triangles,
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
        let ng = flat_normal(wp);
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

/// The rotation taking z to the prim's `axis` attribute (`X`, `Y` or `Z`, default `Z`), as
/// a cyclic permutation: for `X`, (x, y, z) → (z, x, y).
fn axis_matrix(prim: &Prim) -> DMat4 {
    match prim.value("axis").and_then(Value::as_str).unwrap_or("Z") {
        "X" => DMat4::from_cols(DVec3::Y.extend(0.0), DVec3::Z.extend(0.0), DVec3::X.extend(0.0), glam::DVec4::W),
        "Y" => DMat4::from_cols(DVec3::Z.extend(0.0), DVec3::X.extend(0.0), DVec3::Y.extend(0.0), glam::DVec4::W),
        _ => DMat4::IDENTITY,
    }
}

pub(super) fn span_of(prim: &Prim, name: &str) -> Span {
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
            let pv = if name == OBJECT_POSITION {
                Primvar::get(prim, "points", 3, "vertex")
            } else {
                Primvar::any(prim, &format!("primvars:{name}"), default)
            };
            let Some(pv) = pv else { continue };
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
