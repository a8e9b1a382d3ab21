//! Subdivision creases and corners read from USD (`tests/in/subdiv/creased_cubes.usda`): the
//! attributes reach the subdivision (`src/render/geometry/subdiv/tests.rs` holds the rule-by-rule tests).

use std::path::Path;
use strata::diag::{Diagnostics, SourceMap};
use strata::render::geometry::build;
use strata::scene::Stage;

#[test]
fn creases_and_corners_authored_in_usd_shape_the_surface() {
    let path = Path::new("tests/in/subdiv/creased_cubes.usda");
    let text = std::fs::read_to_string(path).expect("fixture");
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::from_text("creased_cubes.usda", &text, Path::new("tests/in/subdiv"), &mut sources, &mut diags)
        .expect("stage");
    let geometry = build(&stage, &mut diags);
    assert!(diags.items().is_empty(), "{}", diags.render(&sources));
    let prim_of = |name: &str| geometry.prims.iter().position(|p| p.path.ends_with(name)).expect("prim") as u32;
    let (sharp, per_edge) = (prim_of("SharpCube"), prim_of("PerEdge"));

    // The infinitely sharp cube is the cube: every vertex on a face, the corners present.
    let sharp_points: Vec<_> = geometry.triangles.iter().filter(|t| t.prim == sharp).flat_map(|t| t.p).collect();
    assert_eq!(sharp_points.len(), 6 * 16 * 2 * 3);
    for p in &sharp_points {
        assert!((p.abs().max_element() - 1.0).abs() < 1e-6, "{p} is off the cube");
    }
    assert!(sharp_points.iter().any(|p| (p.abs() - 1.0).abs().max_element() < 1e-6), "a corner of the cube");

    // The second cube (moved +4 in x): its sharp corner 0 stays at its cage position; corner 3,
    // smooth, is rounded off.
    let points: Vec<_> = geometry.triangles.iter().filter(|t| t.prim == per_edge).flat_map(|t| t.p).collect();
    let has = |x: f32, y: f32, z: f32| points.iter().any(|p| (*p - glam::Vec3::new(x, y, z)).length() < 1e-5);
    assert!(has(3.0, -1.0, -1.0), "the sharp corner stays");
    assert!(!has(5.0, 1.0, -1.0), "a smooth corner moves");
}
