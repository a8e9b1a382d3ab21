use super::*;

fn cube() -> PolyMesh {
    let points =
        (0..8).map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64) * 2.0 - 1.0).collect();
    // Outward-facing quads.
    let faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    PolyMesh {
        points,
        counts: vec![4; 6],
        indices: faces.iter().flatten().copied().collect(),
        holes: vec![false; 6],
        origin: (0..6).collect(),
        ..PolyMesh::default()
    }
}

/// The cube's twelve edges.
const CUBE_EDGES: [[u32; 2]; 12] =
    [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];

/// The cube with its top face's edges (a closed loop 4-5-7-6) of sharpness `s`.
fn cube_with_top_loop(s: f32) -> PolyMesh {
    let mut c = cube();
    c.tags.creases = vec![([4, 5], s), ([5, 7], s), ([7, 6], s), ([6, 4], s)];
    c
}

/// One refinement with the cage's sharpness, as `catmull_clark` starts.
fn refine_once(mesh: &PolyMesh) -> PolyMesh {
    let mut cage = mesh.clone();
    let topo = Topology::new(&cage);
    let sharp = base_sharpness(&mut cage, &topo);
    refine(&cage, &topo, &sharp).0
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
        m = refine_once(&m);
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

/// A case of `tests/fixtures/subdiv/opensubdiv_limits.txt` (written by
/// `tools/make_subdiv_fixtures.sh` with OpenSubdiv): a cage, and the limit points of its
/// vertices at `level` as OpenSubdiv computes them refining past every semi-sharp
/// feature, good to `tolerance` (at darts OpenSubdiv's limit is an estimate).
struct Reference {
    name: String,
    mesh: PolyMesh,
    level: u32,
    limit: Vec<DVec3>,
    tolerance: f64,
    visible_faces: usize,
}

fn references() -> Vec<Reference> {
    let text = include_str!("../../../../tests/fixtures/subdiv/opensubdiv_limits.txt");
    let lines: Vec<&str> = text.lines().collect();
    let mut at = 0usize;
    let mut next = || {
        at += 1;
        lines[at - 1]
    };
    let count = |line: &str, key: &str| -> usize {
        let rest = line.strip_prefix(key).unwrap_or_else(|| panic!("expected `{key}`, got `{line}`"));
        rest.trim().parse().expect("count")
    };
    let numbers = |line: &str| -> Vec<f64> { line.split_whitespace().map(|x| x.parse().expect("number")).collect() };
    let point = |line: &str| {
        let v = numbers(line);
        DVec3::new(v[0], v[1], v[2])
    };
    let mut cases = Vec::new();
    for _ in 0..lines.iter().filter(|l| l.starts_with("case ")).count() {
        let name = next().strip_prefix("case ").expect("case").to_string();
        let boundary = match next().strip_prefix("boundary ").expect("boundary") {
            "none" => BoundaryInterpolation::None,
            "edgeOnly" => BoundaryInterpolation::EdgeOnly,
            _ => BoundaryInterpolation::EdgeAndCorner,
        };
        let level = count(next(), "level ") as u32;
        let mut mesh = PolyMesh::default();
        for _ in 0..count(next(), "points ") {
            mesh.points.push(point(next()));
        }
        for f in 0..count(next(), "faces ") {
            let v = numbers(next());
            mesh.counts.push(v[0] as u32);
            mesh.indices.extend(v[1..].iter().map(|&i| i as u32));
            mesh.holes.push(false);
            mesh.origin.push(f as u32);
        }
        mesh.tags.boundary = boundary;
        for _ in 0..count(next(), "creases ") {
            let v = numbers(next());
            mesh.tags.creases.push(([v[0] as u32, v[1] as u32], v[2] as f32));
        }
        for _ in 0..count(next(), "corners ") {
            let v = numbers(next());
            mesh.tags.corners.push((v[0] as u32, v[1] as f32));
        }
        let limit = (0..count(next(), "limit ")).map(|_| point(next())).collect();
        let tolerance = next().strip_prefix("tolerance ").expect("tolerance").parse().expect("tolerance");
        let visible_faces = count(next(), "visible_faces ");
        assert_eq!(next(), "end");
        cases.push(Reference { name, mesh, level, limit, tolerance, visible_faces });
    }
    assert!(cases.len() >= 10, "{} cases", cases.len());
    cases
}

/// The distance from `p` to the nearest of `points`.
fn nearest(p: DVec3, points: &[DVec3]) -> f64 {
    points.iter().map(|q| (*q - p).length()).fold(f64::INFINITY, f64::min)
}

/// OpenSubdiv is the reference: at the fixture's level the limit points are the same set
/// and the same faces are dropped; at coarser levels every limit point is one of
/// OpenSubdiv's (a coarse vertex persists through refinement and keeps its limit), even
/// where semi-sharp sharpness has not decayed at that level. Darts are held to the
/// distance OpenSubdiv's own estimate still moves (twice it: it shrinks geometrically).
#[test]
fn limit_points_match_opensubdiv() {
    for r in references() {
        let tolerance = if r.tolerance > 1e-9 { 2.0 * r.tolerance } else { 1e-9 };
        for level in 1..=r.level {
            let q = catmull_clark(&r.mesh, level);
            let worst = q.points.iter().map(|&p| nearest(p, &r.limit)).fold(0.0, f64::max);
            assert!(worst < tolerance, "{} at level {level}: a limit point {worst} from OpenSubdiv's", r.name);
            let visible = q.holes.iter().filter(|&&h| !h).count();
            assert_eq!(visible * 4usize.pow(r.level - level), r.visible_faces, "{} at level {level}", r.name);
            if level == r.level {
                assert_eq!(q.points.len(), r.limit.len(), "{}", r.name);
                let worst = r.limit.iter().map(|&p| nearest(p, &q.points)).fold(0.0, f64::max);
                assert!(worst < tolerance, "{}: OpenSubdiv's limit point {worst} from ours", r.name);
            }
            if std::env::var("SUBDIV_DEBUG").is_ok() {
                eprintln!("{} level {level}: worst {worst:e} (tolerance {tolerance:e})", r.name);
            }
        }
    }
}

/// (1) A cube whose twelve edges are infinitely sharp is the cube: every limit point lies
/// on a face of the cage, and the corners stay.
#[test]
fn a_cube_with_all_edges_infinitely_sharp_is_the_cube() {
    let mut c = cube();
    c.tags.creases = CUBE_EDGES.iter().map(|&e| (e, SHARPNESS_INFINITE)).collect();
    for level in 1..=3 {
        let q = catmull_clark(&c, level);
        for p in &q.points {
            assert!((p.abs().max_element() - 1.0).abs() < 1e-12, "level {level}: {p} is off the cube");
        }
        assert_eq!(&q.points[..8], &c.points[..], "level {level}");
    }
}

/// The uniform cubic B-spline of control points `p[i - 1..=i + 2]` at `u` in [0, 1].
fn b_spline(p: [DVec3; 4], u: f64) -> DVec3 {
    let w = [
        (1.0 - u).powi(3),
        3.0 * u.powi(3) - 6.0 * u * u + 4.0,
        -3.0 * u.powi(3) + 3.0 * u * u + 3.0 * u + 1.0,
        u.powi(3),
    ];
    (p[0] * w[0] + p[1] * w[1] + p[2] * w[2] + p[3] * w[3]) / 6.0
}

/// (2) The limit points along an infinitely sharp crease are the uniform cubic B-spline of
/// the crease's cage points, at parameters `k / 2^level`: a closed loop (the cube's top
/// face), and an open chain across a bumpy grid, whose ends are corners (three sharp edges
/// with the boundary) that leave the spans between its inner points a plain B-spline.
#[test]
fn infinitely_sharp_creases_are_cubic_b_splines_of_their_cage_points() {
    let level = 3;
    let steps = 1 << level;
    let loop_cube = cube_with_top_loop(SHARPNESS_INFINITE);
    let q = catmull_clark(&loop_cube, level);
    let ring = [4, 5, 7, 6].map(|i| loop_cube.points[i]);
    for span in 0..4 {
        let controls = [0, 1, 2, 3].map(|k| ring[(span + 3 + k) % 4]);
        for k in 0..steps {
            let expected = b_spline(controls, k as f64 / steps as f64);
            assert!(nearest(expected, &q.points) < 1e-12, "loop span {span} at {k}: {expected}");
        }
    }

    let mut grid = PolyMesh::default();
    for j in 0..3 {
        for i in 0..5 {
            grid.points.push(DVec3::new(i as f64, j as f64, (1.3 * i as f64 + 0.7 * j as f64).sin()));
        }
    }
    for j in 0..2u32 {
        for i in 0..4u32 {
            let v = 5 * j + i;
            grid.counts.push(4);
            grid.indices.extend([v, v + 1, v + 6, v + 5]);
        }
    }
    grid.tags.creases = (5..9).map(|v| ([v, v + 1], SHARPNESS_INFINITE)).collect();
    let q = catmull_clark(&grid, level);
    let chain: Vec<DVec3> = (5..10).map(|v| grid.points[v]).collect();
    for span in 1..=2 {
        let controls = [chain[span - 1], chain[span], chain[span + 1], chain[span + 2]];
        for k in 0..=steps {
            let expected = b_spline(controls, k as f64 / steps as f64);
            assert!(nearest(expected, &q.points) < 1e-12, "chain span {span} at {k}: {expected}");
        }
    }
    // The test can fail: the smooth surface does not pass through the crease's curve.
    let smooth = catmull_clark(&PolyMesh { tags: SubdivTags::default(), ..grid.clone() }, level);
    let mid = b_spline([chain[0], chain[1], chain[2], chain[3]], 0.5);
    assert!(nearest(mid, &smooth.points) > 1e-3);
}

/// (3) An infinitely sharp corner stays exactly where the cage has it, at every level; a
/// smooth cube's corner does not.
#[test]
fn an_infinitely_sharp_corner_stays_at_its_cage_position() {
    let mut c = cube();
    c.tags.corners = vec![(0, SHARPNESS_INFINITE)];
    for level in 1..=3 {
        assert_eq!(catmull_clark(&c, level).points[0], c.points[0], "level {level}");
    }
    assert_ne!(catmull_clark(&cube(), 2).points[0], c.points[0]);
}

/// (4) Sharpness 0 is smooth, bit for bit.
#[test]
fn sharpness_zero_is_the_smooth_surface_bit_for_bit() {
    let mut c = cube_with_top_loop(0.0);
    c.tags.corners = vec![(0, 0.0), (3, -2.0)];
    for level in 1..=3 {
        let (creased, smooth) = (catmull_clark(&c, level), catmull_clark(&cube(), level));
        assert_eq!(creased.points, smooth.points, "level {level}");
        assert_eq!(creased.normals, smooth.normals, "level {level}");
    }
}

/// (5) Sharper creases hold the surface closer to the cage: the limit of a vertex on the
/// creased loop moves monotonically from the smooth limit towards its cage position.
#[test]
fn sharper_creases_hold_the_surface_closer_to_the_cage() {
    let sharpness = [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0, SHARPNESS_INFINITE];
    let distances: Vec<f64> = sharpness
        .iter()
        .map(|&s| (catmull_clark(&cube_with_top_loop(s), 2).points[4] - cube().points[4]).length())
        .collect();
    for (w, s) in distances.windows(2).zip(sharpness.windows(2)) {
        assert!(w[1] < w[0], "sharpness {} → {}: {} → {}", s[0], s[1], w[0], w[1]);
    }
}

/// (5) One refinement by DeRose et al.'s rules, by hand, for vertex 4 = (-1, -1, 1) of the
/// cube and its edge to vertex 5 = (1, -1, 1) on a top loop of sharpness 1 and 0.5.
/// Sharpness 1: the crease rule `(a + 6p + b) / 8` (its edges decay to 0, so the rule
/// blends with weight 1) and the edge's midpoint. Sharpness 0.5: half that and half the
/// smooth rules, whose values are: vertex `(F + 2R + (n - 3) p) / n` with n = 3, face
/// centroids (0,0,1), (0,-1,0), (-1,0,0) and edge midpoints (0,-1,1), (-1,0,1), (-1,-1,0),
/// so (-5, -5, 5) / 9; edge `(a + b + f₁ + f₂) / 4` = (0, -3, 3) / 4.
#[test]
fn one_level_of_semi_sharp_refinement_matches_the_rules_by_hand() {
    let edge_45 = 8 + Topology::new(&cube()).edges.iter().position(|&e| e == (4, 5)).unwrap();
    let sharp = refine_once(&cube_with_top_loop(1.0));
    assert_eq!(sharp.points[4], DVec3::new(-0.75, -0.75, 1.0));
    assert_eq!(sharp.points[edge_45], DVec3::new(0.0, -1.0, 1.0));
    let half = refine_once(&cube_with_top_loop(0.5));
    let vertex = (DVec3::new(-0.75, -0.75, 1.0) + DVec3::new(-5.0, -5.0, 5.0) / 9.0) / 2.0;
    assert!((half.points[4] - vertex).length() < 1e-15, "{}", half.points[4]);
    let edge = (DVec3::new(0.0, -1.0, 1.0) + DVec3::new(0.0, -3.0, 3.0) / 4.0) / 2.0;
    assert!((half.points[edge_45] - edge).length() < 1e-15, "{}", half.points[edge_45]);
    // The smooth rules themselves, for the sharpness-0 reference.
    let smooth = refine_once(&cube());
    assert!((smooth.points[4] - DVec3::new(-5.0, -5.0, 5.0) / 9.0).length() < 1e-15);
}

/// Sharpness beyond the rendered level is not treated as infinite: the limit does not
/// depend on the level (cage vertices keep their index, and their limit, at every level).
#[test]
fn semi_sharp_limits_do_not_depend_on_the_level() {
    let c = cube_with_top_loop(3.5);
    let coarse = catmull_clark(&c, 1);
    let fine = catmull_clark(&c, 4);
    for v in 0..8 {
        assert!((coarse.points[v] - fine.points[v]).length() < 1e-12, "vertex {v}");
    }
    let infinite = catmull_clark(&cube_with_top_loop(SHARPNESS_INFINITE), 1);
    assert!((coarse.points[4] - infinite.points[4]).length() > 1e-3);
}

/// (6) `interpolateBoundary`: `edgeAndCorner` pins a single face's corner, `edgeOnly` puts
/// it on the boundary's B-spline `(a + 4p + b) / 6`, `none` drops every face touching the
/// boundary (of a 3×3 grid only the centre face is left).
#[test]
fn boundary_interpolation_rules() {
    let mut grid = PolyMesh::default();
    for j in 0..4 {
        for i in 0..4 {
            grid.points.push(DVec3::new(i as f64, j as f64, (1.3 * i as f64 + 0.7 * j as f64).sin()));
        }
    }
    for j in 0..3u32 {
        for i in 0..3u32 {
            let v = 4 * j + i;
            grid.counts.push(4);
            grid.indices.extend([v, v + 1, v + 5, v + 4]);
            grid.origin.push(3 * j + i);
        }
    }
    let with = |boundary| PolyMesh { tags: SubdivTags { boundary, ..SubdivTags::default() }, ..grid.clone() };
    let corner = catmull_clark(&with(BoundaryInterpolation::EdgeAndCorner), 2);
    assert_eq!(corner.points[0], grid.points[0]);
    let edge = catmull_clark(&with(BoundaryInterpolation::EdgeOnly), 2);
    let curve = (grid.points[1] + grid.points[0] * 4.0 + grid.points[4]) / 6.0;
    assert!((edge.points[0] - curve).length() < 1e-12, "{} {curve}", edge.points[0]);
    let none = catmull_clark(&with(BoundaryInterpolation::None), 2);
    let kept: Vec<u32> = none.holes.iter().zip(&none.origin).filter(|(h, _)| !**h).map(|(_, &o)| o).collect();
    assert_eq!(kept, vec![4; 16]);
}

fn tags_of(attributes: &str) -> (SubdivTags, Vec<String>) {
    let text = format!(
        "#usda 1.0\ndef Mesh \"M\" {{\n    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n    \
             int[] faceVertexIndices = [0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5]\n    \
             {attributes}\n}}\n"
    );
    let (stage, mut diags) = crate::render::geometry::xform::tests::stage(&text);
    let prim = stage.prim(stage.find("/M").unwrap());
    let c = cube();
    let indices: Vec<i64> = c.indices.iter().map(|&i| i as i64).collect();
    let tags = read_tags(prim, 8, &[4; 6], &indices, &mut diags);
    (tags, diags.items().iter().map(|d| d.message.clone()).collect())
}

/// UsdGeom's crease encoding: chains of vertices, a sharpness per chain or per chain edge;
/// what does not fit is a warning and leaves the rest.
#[test]
fn usd_creases_and_corners_are_read_per_crease_or_per_edge() {
    let (tags, warnings) = tags_of(
        "int[] creaseIndices = [0, 1, 3, 2, 4, 6]\n int[] creaseLengths = [4, 2]\n float[] creaseSharpnesses = [2, 10]\n \
             int[] cornerIndices = [7]\n float[] cornerSharpnesses = [3.5]\n uniform token interpolateBoundary = \"edgeOnly\"",
    );
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(tags.creases, vec![([0, 1], 2.0), ([1, 3], 2.0), ([3, 2], 2.0), ([4, 6], 10.0)]);
    assert_eq!(tags.corners, vec![(7, 3.5)]);
    assert_eq!(tags.boundary, BoundaryInterpolation::EdgeOnly);

    let (tags, warnings) = tags_of(
        "int[] creaseIndices = [0, 1, 3, 2]\n int[] creaseLengths = [4]\n float[] creaseSharpnesses = [1, -2, 30]",
    );
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(tags.creases, vec![([0, 1], 1.0), ([1, 3], 0.0), ([3, 2], SHARPNESS_INFINITE)]);
    assert_eq!(tags.boundary, BoundaryInterpolation::EdgeAndCorner);

    for (attributes, warning) in [
        ("int[] creaseIndices = [0, 1, 3]\n int[] creaseLengths = [2]\n float[] creaseSharpnesses = [1]", "do not fit"),
        (
            "int[] creaseIndices = [0, 1, 3]\n int[] creaseLengths = [3]\n float[] creaseSharpnesses = [1, 2, 3]",
            "neither",
        ),
        ("int[] creaseIndices = [0, 9]\n int[] creaseLengths = [2]\n float[] creaseSharpnesses = [1]", "out of range"),
        ("int[] cornerIndices = [0, 1]\n float[] cornerSharpnesses = [1]", "cornerSharpnesses for"),
        ("int[] cornerIndices = [-1]\n float[] cornerSharpnesses = [1]", "out of range"),
        ("uniform token interpolateBoundary = \"sometimes\"", "unknown interpolateBoundary"),
    ] {
        let (tags, warnings) = tags_of(attributes);
        assert!(tags.creases.is_empty() && tags.corners.is_empty(), "{attributes}");
        assert!(warnings.len() == 1 && warnings[0].contains(warning), "{attributes}: {warnings:?}");
    }
    // A diagonal (0-7) is no edge of the cube: reported, the rest kept.
    let (tags, warnings) =
        tags_of("int[] creaseIndices = [0, 1, 7]\n int[] creaseLengths = [3]\n float[] creaseSharpnesses = [5]");
    assert_eq!(tags.creases, vec![([0, 1], 5.0)]);
    assert!(warnings.len() == 1 && warnings[0].contains("not edges of the mesh"), "{warnings:?}");
}
