//! Structural hostile input (issue 20, item 10): deep sublayer chains, many distinct layers
//! and arcs, a vertex with very many neighbours, nested usdz packages, and the fuzzer's binary
//! mutations and oracles. Inputs made of thousands of files are generated here; the nested
//! packages are in `tests/in/hostile/nested_usdz/` (made by `tools/make_nested_usdz_fixtures.py`).

use glam::{Vec2, Vec3};
use std::fs;
use std::path::{Path, PathBuf};
use strata::diag::{Diagnostics, SourceMap};
use strata::render::geometry::Triangle;
use strata::render::geometry::accel::{Accel, Blas, PLOC_BATCH};
use strata::scene::Stage;
use strata::scene::stage::composition_work;

fn open(path: &Path) -> Result<Stage, String> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(path, &mut sources, &mut diags);
    let rendered = diags.render(&sources);
    stage.map_err(|_| rendered)
}

/// Opens the stage at `path`: its prim count and the units of composition work it took.
fn work_to_open(path: &Path) -> (usize, u64) {
    let before = composition_work();
    let stage = open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (stage.len(), composition_work() - before)
}

/// 10 000 prims each referencing a distinct file, and 10 000 sublayers each with a prim: the
/// work is linear (a few units per layer). Before, every reference compared its key with
/// every layer needed so far (a `realpath` each: 10 000 references took 85 s) and every prim
/// looked in every sublayer (40 000 sublayers: 106 s), n²/2 units or more.
#[test]
fn distinct_references_and_sublayers_compose_in_linear_work() {
    let n = 10_000;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut references = String::from("#usda 1.0\n");
    let mut sublayers = String::from("#usda 1.0\n(\n    subLayers = [\n");
    for i in 0..n {
        fs::write(d.join(format!("r{i}.usda")), "#usda 1.0\ndef Xform \"R\" {}\n").unwrap();
        fs::write(d.join(format!("s{i}.usda")), format!("#usda 1.0\ndef Xform \"S{i}\" {{}}\n")).unwrap();
        references += &format!("def Xform \"P{i}\" (\n    references = @r{i}.usda@</R>\n) {{}}\n");
        sublayers += &format!("        @s{i}.usda@,\n");
    }
    sublayers += "    ]\n)\n";
    fs::write(d.join("references.usda"), references).unwrap();
    fs::write(d.join("sublayers.usda"), sublayers).unwrap();
    for name in ["references.usda", "sublayers.usda"] {
        let start = std::time::Instant::now();
        let (prims, work) = work_to_open(&d.join(name));
        eprintln!("{name}: {prims} prims, {work} units of work, {:.2} s", start.elapsed().as_secs_f64());
        assert_eq!(prims, n, "{name}");
        assert!(work <= 16 * n as u64, "{name}: {work} units of work for {n} layers");
    }
}

/// A chain of 4 500 sublayer files (each the only sublayer of the one before) overflowed the
/// stack. Pixar's library opens it (no depth limit); loading is iterative now, and only the
/// root's layer stack is built (one per layer made a chain quadratic).
#[test]
fn a_deep_sublayer_chain_loads_without_recursion() {
    let n = 4_500;
    let dir = tempfile::tempdir().unwrap();
    for i in 0..n {
        let text = if i + 1 < n {
            format!("#usda 1.0\n(\n    subLayers = [@c{}.usda@]\n)\n", i + 1)
        } else {
            "#usda 1.0\ndef Xform \"Leaf\" {}\n".to_string()
        };
        fs::write(dir.path().join(format!("c{i}.usda")), text).unwrap();
    }
    // On a 256 KiB stack: the depth must cost no stack.
    let root = dir.path().join("c0.usda");
    let (prims, work) = std::thread::Builder::new()
        .stack_size(256 << 10)
        .spawn(move || work_to_open(&root))
        .unwrap()
        .join()
        .expect("no stack overflow");
    assert_eq!(prims, 1);
    assert!(work <= 16 * n as u64, "{work} units of work for a chain of {n}");
}

fn triangle(p: [Vec3; 3]) -> Triangle {
    Triangle { p, n: [Vec3::Z; 3], uv: [Vec2::ZERO; 3], prim: 0, has_uv: false, primvars: Default::default() }
}

/// A fan of 10⁵ thin triangles around one vertex: obvhs' PLOC builder alone took 23 s on it
/// (a pass merges one pair per run of growing merge cost, O(n²)). No PLOC build gets more than
/// `PLOC_BATCH` boxes now (the work is O(n · batch)), and rays find the right triangle.
#[test]
fn a_vertex_with_many_neighbours_builds_in_bounded_batches() {
    let n = 100_000;
    let corner = |i: usize| {
        let a = std::f32::consts::TAU * (i % n) as f32 / n as f32;
        Vec3::new(a.cos(), a.sin(), 0.0)
    };
    let fan = || (0..n).map(|i| triangle([Vec3::ZERO, corner(i), corner(i + 1)])).collect::<Vec<_>>();
    let start = std::time::Instant::now();
    let blas = Blas::new(fan(), vec![]);
    eprintln!("fan of {n}: BVH in {:.2} s", start.elapsed().as_secs_f64());
    assert!(blas.largest_build_batch() <= PLOC_BATCH, "a PLOC batch of {}", blas.largest_build_batch());
    let accel = Accel::new(fan(), vec![]);
    for i in [0usize, 1, 12_345, 49_999, 77_777, n - 1] {
        let inside = (corner(i) + corner(i + 1)) * 0.45;
        let hit = accel.intersect(inside + Vec3::Z, -Vec3::Z, 0.0, f32::INFINITY).expect("a hit");
        assert_eq!(hit.index, i as u32);
    }
}

fn hostile(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/in/hostile").join(name)
}

/// Nested usdz packages, made and opened by Pixar's library (`expected.txt` is what it
/// composes): a reference to an inner package names no member (its root layer is implied;
/// strata looked for `inner.usdz][scene.usda`), and sublayers three packages deep, each
/// package's root layer named `root.usda`.
#[test]
fn nested_packages_open_as_pixars_library_opens_them() {
    let dir = hostile("nested_usdz");
    let expected = fs::read_to_string(dir.join("expected.txt")).unwrap();
    let mut checked = 0;
    for line in expected.lines() {
        let (name, prims) = line.split_once(": ").expect("`name: prims`");
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::open(&dir.join(name), &mut sources, &mut diags);
        let rendered = diags.render(&sources);
        let stage = stage.unwrap_or_else(|_| panic!("{name} does not open:\n{rendered}"));
        assert!(!rendered.contains("warning") && !rendered.contains("cycle"), "{name}:\n{rendered}");
        let mut composed: Vec<String> =
            stage.depth_first().map(|(_, p)| format!("{}:{}", p.path, p.type_name.as_deref().unwrap_or(""))).collect();
        composed.sort();
        let mut want: Vec<&str> = prims.split(' ').collect();
        want.sort();
        assert_eq!(composed, want, "{name}");
        checked += 1;
    }
    assert_eq!(checked, 2);
}
