//! Catmull-Clark subdivision of polygon meshes (UsdGeom `subdivisionScheme`, whose default is
//! `catmullClark`: a mesh without the attribute is a subdivision surface, not its cage).
//!
//! Uniform refinement to a fixed level, then every vertex is moved to its limit position, so
//! the result lies on the limit surface whatever the level; shading normals are the
//! area-weighted normals of the refined mesh. Boundaries follow USD's default
//! `interpolateBoundary = "edgeAndCorner"`: boundary edges are cubic B-spline curves, and
//! vertices with a single incident face are corners that stay where they are. Non-manifold
//! edges (three or more faces) are treated as boundaries. Face-varying data (`st`) is
//! refined linearly within each face (USD's `faceVaryingLinearInterpolation = "all"`).
//!
//! Not applied (reported by [`super::support`]): creases and corners with sharpness.

use glam::{DVec3, Vec2};
use std::collections::HashMap;

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
    /// Whether each quad lies in a hole.
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

/// One uniform Catmull-Clark step: every face becomes quads.
fn refine(mesh: &PolyMesh) -> PolyMesh {
    let faces = mesh.counts.len();
    let mut offsets = Vec::with_capacity(faces);
    let mut start = 0usize;
    for &c in &mesh.counts {
        offsets.push(start);
        start += c as usize;
    }
    let face = |f: usize| &mesh.indices[offsets[f]..offsets[f] + mesh.counts[f] as usize];

    // Edges, keyed by their sorted endpoints, with the faces that use them.
    let mut edge_id: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.indices.len());
    let mut edges: Vec<(u32, u32)> = Vec::new();
    let mut edge_faces: Vec<Vec<u32>> = Vec::new();
    let mut face_edges: Vec<u32> = Vec::with_capacity(mesh.indices.len());
    for f in 0..faces {
        let vs = face(f);
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

    let face_points: Vec<DVec3> = (0..faces)
        .map(|f| face(f).iter().map(|&v| mesh.points[v as usize]).sum::<DVec3>() / mesh.counts[f] as f64)
        .collect();
    let is_boundary = |e: usize| edge_faces[e].len() != 2;
    let edge_points: Vec<DVec3> = edges
        .iter()
        .enumerate()
        .map(|(e, &(a, b))| {
            let mid = (mesh.points[a as usize] + mesh.points[b as usize]) / 2.0;
            if is_boundary(e) {
                mid
            } else {
                let f = &edge_faces[e];
                (mid * 2.0 + face_points[f[0] as usize] + face_points[f[1] as usize]) / 4.0
            }
        })
        .collect();

    // Per vertex: incident edges and faces.
    let n = mesh.points.len();
    let mut vertex_edges: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (e, &(a, b)) in edges.iter().enumerate() {
        vertex_edges[a as usize].push(e as u32);
        vertex_edges[b as usize].push(e as u32);
    }
    let mut vertex_faces: Vec<Vec<u32>> = vec![Vec::new(); n];
    for f in 0..faces {
        for &v in face(f) {
            vertex_faces[v as usize].push(f as u32);
        }
    }
    let other = |e: u32, v: usize| {
        let (a, b) = edges[e as usize];
        if a as usize == v { b } else { a }
    };
    let vertex_points: Vec<DVec3> = (0..n)
        .map(|v| {
            let p = mesh.points[v];
            let incident = &vertex_edges[v];
            if incident.is_empty() {
                return p;
            }
            let boundary: Vec<u32> = incident.iter().copied().filter(|&e| is_boundary(e as usize)).collect();
            match boundary.len() {
                0 => {
                    let valence = incident.len() as f64;
                    let f = vertex_faces[v].iter().map(|&f| face_points[f as usize]).sum::<DVec3>()
                        / vertex_faces[v].len() as f64;
                    let r = incident.iter().map(|&e| (p + mesh.points[other(e, v) as usize]) / 2.0).sum::<DVec3>()
                        / valence;
                    (f + r * 2.0 + p * (valence - 3.0)) / valence
                }
                // A corner (one incident face) is interpolated; other boundary vertices
                // follow the cubic B-spline of their boundary curve.
                2 if vertex_faces[v].len() > 1 => {
                    let (a, b) =
                        (mesh.points[other(boundary[0], v) as usize], mesh.points[other(boundary[1], v) as usize]);
                    (a + p * 6.0 + b) / 8.0
                }
                _ => p,
            }
        })
        .collect();

    // New points: vertices, then edges, then faces.
    let edge_base = n as u32;
    let face_base = edge_base + edges.len() as u32;
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
    for (f, &o) in offsets.iter().enumerate() {
        let vs = face(f);
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
                edge_base + face_edges[o + k],
                face_base + f as u32,
                edge_base + face_edges[o + prev],
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
    PolyMesh { points, counts, indices, uv, varying, varying_width: w, holes, origin }
}

/// Limit positions of a quad mesh's vertices (valid after at least one refinement, when
/// every face is a quad): interior vertices by the Catmull-Clark limit stencil
/// `(n² p + 4 Σ eᵢ + Σ fᵢ) / (n (n + 5))` over edge neighbours `eᵢ` and diagonal neighbours
/// `fᵢ`; boundary vertices by the B-spline curve's `(a + 4 p + b) / 6`; corners stay.
fn limit_points(mesh: &PolyMesh) -> Vec<DVec3> {
    let n = mesh.points.len();
    let mut edge_count: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.indices.len());
    for q in mesh.indices.chunks_exact(4) {
        for k in 0..4 {
            let (a, b) = (q[k], q[(k + 1) % 4]);
            *edge_count.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    let mut edge_sum = vec![DVec3::ZERO; n];
    let mut diagonal_sum = vec![DVec3::ZERO; n];
    let mut valence = vec![0u32; n];
    let mut faces = vec![0u32; n];
    let mut boundary_sum = vec![DVec3::ZERO; n];
    let mut boundary_edges = vec![0u32; n];
    for (&(a, b), &count) in &edge_count {
        let (pa, pb) = (mesh.points[a as usize], mesh.points[b as usize]);
        valence[a as usize] += 1;
        valence[b as usize] += 1;
        edge_sum[a as usize] += pb;
        edge_sum[b as usize] += pa;
        if count != 2 {
            boundary_edges[a as usize] += 1;
            boundary_edges[b as usize] += 1;
            boundary_sum[a as usize] += pb;
            boundary_sum[b as usize] += pa;
        }
    }
    for q in mesh.indices.chunks_exact(4) {
        for k in 0..4 {
            faces[q[k] as usize] += 1;
            diagonal_sum[q[k] as usize] += mesh.points[q[(k + 2) % 4] as usize];
        }
    }
    (0..n)
        .map(|v| {
            let p = mesh.points[v];
            match boundary_edges[v] {
                0 if valence[v] >= 3 && faces[v] == valence[v] => {
                    let k = valence[v] as f64;
                    (p * k * k + edge_sum[v] * 4.0 + diagonal_sum[v]) / (k * (k + 5.0))
                }
                2 if faces[v] > 1 => (boundary_sum[v] + p * 4.0) / 6.0,
                _ => p,
            }
        })
        .collect()
}

/// Refines `mesh` `level` times (at least once) and projects it to the limit surface.
pub fn catmull_clark(mesh: &PolyMesh, level: u32) -> QuadMesh {
    let mut refined = refine(mesh);
    for _ in 1..level.max(1) {
        refined = refine(&refined);
    }
    let points = limit_points(&refined);
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
mod tests {
    use super::*;

    fn cube() -> PolyMesh {
        let points = (0..8)
            .map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64) * 2.0 - 1.0)
            .collect();
        // Outward-facing quads.
        let faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        PolyMesh {
            points,
            counts: vec![4; 6],
            indices: faces.iter().flatten().copied().collect(),
            uv: None,
            holes: vec![false; 6],
            origin: (0..6).collect(),
            ..PolyMesh::default()
        }
    }

    /// The limit stencil is checked against its definition: the limit is where repeated
    /// refinement converges. A cube corner refined seven times approaches the stencil's
    /// value geometrically.
    #[test]
    fn limit_stencil_is_where_refinement_converges() {
        let limit = catmull_clark(&cube(), 1).points[0];
        let mut m = cube();
        let mut errors = Vec::new();
        for _ in 0..7 {
            m = refine(&m);
            // Vertex points keep their index: vertex 0 is the same corner at every level.
            errors.push((m.points[0] - limit).length());
        }
        assert!(errors[6] < 1e-3 && errors[6] < errors[3] / 10.0, "{errors:?}");
        // On the diagonal, strictly inside the cage.
        assert!((limit.x - limit.y).abs() < 1e-12 && (limit.y - limit.z).abs() < 1e-12, "{limit}");
        assert!(limit.x > -1.0 && limit.x < -0.4, "{limit}");
    }

    /// The limit surface of a convex cage is inside it, and its normals point outwards.
    #[test]
    fn cube_limit_is_inside_its_cage_with_outward_unit_normals() {
        let q = catmull_clark(&cube(), 3);
        for (p, n) in q.points.iter().zip(&q.normals) {
            assert!(p.abs().max_element() <= 1.0 + 1e-12, "{p}");
            assert!((n.length() - 1.0).abs() < 1e-9 && p.dot(*n) > 0.0, "{p} {n}");
        }
    }

    /// A flat grid stays flat, and its boundary corners stay put (edgeAndCorner).
    #[test]
    fn flat_quad_stays_flat_with_corners_pinned() {
        let mesh = PolyMesh {
            points: vec![
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(2.0, 0.0, 0.0),
                DVec3::new(2.0, 0.0, 2.0),
                DVec3::new(0.0, 0.0, 2.0),
            ],
            counts: vec![4],
            indices: vec![0, 1, 2, 3],
            uv: Some(vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)]),
            holes: vec![false],
            origin: vec![0],
            ..PolyMesh::default()
        };
        let q = catmull_clark(&mesh, 2);
        assert_eq!(q.quads.len(), 16);
        for p in &q.points {
            assert_eq!(p.y, 0.0);
        }
        assert_eq!(&q.points[..4], &mesh.points[..]);
        // Linear face-varying uvs: a point's uv is its position / 2 on this square.
        let uv = q.uv.as_ref().unwrap();
        for (quad, t) in q.quads.iter().zip(uv) {
            for k in 0..4 {
                let p = q.points[quad[k] as usize];
                assert!((t[k] - Vec2::new(p.x as f32, p.z as f32) / 2.0).length() < 1e-6, "{p} {:?}", t[k]);
            }
        }
    }

    #[test]
    fn refined_face_count_matches_the_rule() {
        assert_eq!(refined_faces(&[3, 4, 5], 0), 3);
        assert_eq!(refined_faces(&[3, 4, 5], 1), 12);
        assert_eq!(refined_faces(&[3, 4, 5], 3), 12 * 16);
        let q = catmull_clark(&cube(), 2);
        assert_eq!(q.quads.len() as u64, refined_faces(&[4; 6], 2));
    }

    #[test]
    fn holes_are_inherited_by_children() {
        let mut c = cube();
        c.holes[2] = true;
        let q = catmull_clark(&c, 2);
        assert_eq!(q.holes.iter().filter(|&&h| h).count(), 16);
    }
}
