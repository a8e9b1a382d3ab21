//! Binary USD: crate files (`.usdc`, binary `.usd`) and usdz packages, against fixtures
//! written by Pixar's USD library (`tools/make_usd_fixtures.py`). Every binary layer there
//! has a text twin USD exported from the same in-memory layer, so the independent reference
//! for "read correctly" is the usda parser reading Pixar's text of the same data.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;
use strata::diag::{Diagnostics, SourceMap};
use strata::scene::stage::{Attribute, Relationship};
use strata::scene::{Stage, Value};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/usd/binary").join(name)
}

fn open(path: &Path) -> (Option<Stage>, String) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(path, &mut sources, &mut diags).ok();
    (stage, diags.render(&sources))
}

fn open_ok(path: &Path) -> Stage {
    let (stage, rendered) = open(path);
    stage.unwrap_or_else(|| panic!("{} does not open:\n{rendered}", path.display()))
}

/// Everything composition produces that strata reads, without spans (the two formats point
/// into different texts). Asset paths compare by what they resolve to.
fn describe_stage(stage: &Stage) -> Vec<String> {
    let mut out = Vec::new();
    let meta = stage.metadata();
    out.push(format!(
        "layer defaultPrim={:?} upAxis={:?} metersPerUnit={:?} doc={:?} subLayers={:?}",
        meta.default_prim.as_ref().map(|(n, _)| n),
        meta.up_axis,
        meta.meters_per_unit,
        meta.doc,
        meta.sub_layers.iter().map(|(a, _)| a.resolved.clone()).collect::<Vec<_>>()
    ));
    for entry in &meta.other {
        out.push(format!("layer meta {} = {:?}", entry.key, entry.value));
    }
    for (_, prim) in stage.depth_first() {
        out.push(format!(
            "prim {} type={:?} kind={:?} instanceable={} api={:?} variants={:?} doc={:?} children={:?}",
            prim.path,
            prim.type_name,
            prim.kind,
            prim.instanceable,
            prim.api_schemas,
            prim.variant_selections,
            prim.doc,
            prim.children.iter().map(|c| stage.prim(*c).name.clone()).collect::<Vec<_>>()
        ));
        // By name, as USD lists properties: Pixar's usda writer sorts them, its crate writer
        // keeps the authored order, and nothing strata does depends on that order.
        let mut properties: Vec<(String, String)> = Vec::new();
        for a in &prim.attributes {
            properties.push((a.name.clone(), describe_attribute(&prim.path, a)));
        }
        for r in &prim.relationships {
            properties.push((r.name.clone(), describe_relationship(&prim.path, r)));
        }
        properties.sort();
        out.extend(properties.into_iter().map(|(_, d)| d));
    }
    out
}

fn describe_attribute(prim: &str, a: &Attribute) -> String {
    let mut metadata: Vec<String> = a.metadata.iter().map(|m| format!("{}={:?}", m.key, m.value)).collect();
    metadata.sort();
    format!(
        "  attr {prim}.{} {} value={:?} blocked={} custom={} uniform={} connect={:?} samples={:?} meta={metadata:?}",
        a.name,
        a.type_name,
        a.get(),
        a.blocked,
        a.custom,
        a.uniform,
        a.connections.iter().map(|(p, _)| p).collect::<Vec<_>>(),
        a.time_samples,
    )
}

fn describe_relationship(prim: &str, r: &Relationship) -> String {
    format!(
        "  rel {prim}.{} targets={:?} explicit={} authored={} custom={}",
        r.name,
        r.targets.iter().map(|(p, _)| p).collect::<Vec<_>>(),
        r.explicit,
        r.authored.is_some(),
        r.custom
    )
}

fn assert_same_stage(text: &Path, binary: &Path) {
    assert_same_stage_with(text, binary, |s| s.to_string());
}

/// `map` rewrites the binary stage's description where the files differ by design (the
/// twin root names `.usda` layers where the other names `.usdc`).
fn assert_same_stage_with(text: &Path, binary: &Path, map: impl Fn(&str) -> String) {
    let a = describe_stage(&open_ok(text));
    let b: Vec<String> = describe_stage(&open_ok(binary)).iter().map(|s| map(s)).collect();
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x, y, "{} and {} differ", text.display(), binary.display());
    }
    assert_eq!(a.len(), b.len(), "{} and {} differ in length", text.display(), binary.display());
}

#[test]
fn usdc_composes_like_its_usda_twin() {
    let text = fixture("kitchen.usda");
    let binary = fixture("kitchen.usdc");
    assert_eq!(&std::fs::read(&binary).unwrap()[..8], b"PXR-USDC", "the fixture is a crate");
    assert_same_stage(&text, &binary);

    // The comparison is only as good as what it covers: spot-check values the twin
    // comparison holds equal, against the values the generator authored.
    let stage = open_ok(&binary);
    let values = stage.prim(stage.find("/World/Values").unwrap());
    let v = |name: &str| values.value(name).cloned().unwrap_or_else(|| panic!("{name}"));
    assert_eq!(v("aColor"), Value::Tuple(vec![0.8, 0.1, 0.05]));
    assert_eq!(v("aFloat"), Value::Float(0.1), "a float reads as the decimal USD wrote for it");
    assert_eq!(v("aToken"), Value::Token("faceVarying".into()));
    assert_eq!(v("aInts"), Value::IntArray(vec![1, -2, 3, 2147483647].into()));
    assert_eq!(v("aUint"), Value::Int(4000000000));
    assert_eq!(v("aInt64"), Value::Int(-9007199254740993));
    assert_eq!(
        v("aMatrix"),
        Value::Matrix([2.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 4.0, 0.0, 1.0, 2.0, 3.0, 1.0])
    );
    assert_eq!(v("aQuats"), Value::TupleArray { width: 4, data: vec![1.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.5].into() });
    assert_eq!(v("aQuatd"), Value::Tuple(vec![0.25, 0.5, 0.75, 1.0]), "quaternions are (real, i, j, k)");
    assert_eq!(v("aTexCoords"), Value::TupleArray { width: 2, data: vec![0.0, 0.5, 0.25, 1.0].into() });
    assert_eq!(v("aEmpty"), Value::TupleArray { width: 3, data: Default::default() });
    let asset = v("aAsset");
    let asset = asset.as_asset().unwrap();
    assert_eq!(asset.authored, "tex/checker.exr");
    assert_eq!(asset.resolved, fixture("tex/checker.exr"));
    let blocked = values.attribute("aBlocked").unwrap();
    assert!(blocked.blocked && blocked.get().is_none(), "SdfValueBlock is a block");
    assert_eq!(v("aAnimated"), Value::Float(1.5), "no default: the first time sample");
    let uniform = values.attribute("aUniform").unwrap();
    assert!(uniform.uniform && uniform.custom);

    let quad = stage.prim(stage.find("/World/Quad").unwrap());
    let rel = |name: &str| quad.relationship(name).unwrap_or_else(|| panic!("{name}"));
    assert_eq!(rel("material:slotBinding:_000").targets[0].0, "/Looks/Red");
    assert_eq!(rel("material:slotBinding:_000:_:_010").targets[0].0, "/Looks/RedPaint");
    assert!(rel("material:slotBinding:_050").is_explicit_empty(), "`= None` removes the slot");
    assert!(!rel("material:slotBinding:_070").has_authored_targets(), "declared only: no binding");
    let normals = quad.attribute("normals").unwrap();
    assert_eq!(normals.meta("interpolation").and_then(Value::as_str), Some("vertex"));

    let shader = stage.prim(stage.find("/Looks/Red/Surface").unwrap());
    let albedo = shader.attribute("inputs:albedo").unwrap();
    assert_eq!(albedo.connections.iter().map(|(p, _)| p.as_str()).collect::<Vec<_>>(), ["/Looks/Red.inputs:albedo"]);
    let shape = stage.prim(stage.find("/World/Variants/Shape").unwrap());
    assert_eq!(shape.value("radius"), Some(&Value::Float(2.0)), "the selected variant `large`");
    let ball = stage.prim(stage.find("/World/Ball").unwrap());
    assert!(ball.relationship("material:slotBinding:_020").is_some(), "inherited from /_Shared");
    let internal = stage.prim(stage.find("/World/Internal").unwrap());
    assert_eq!(internal.value("sharedValue"), Some(&Value::Float(7.0)), "internal reference");
}

#[test]
fn binary_dot_usd_is_told_by_content() {
    assert_same_stage(&fixture("kitchen.usda"), &fixture("kitchen_binary.usd"));
    // A text `.usd` still reads as text.
    let dir = tempfile::tempdir().unwrap();
    let text_usd = dir.path().join("text.usd");
    std::fs::write(&text_usd, "#usda 1.0\ndef Xform \"A\" { double3 xformOp:translate = (1, 2, 3) }\n").unwrap();
    let stage = open_ok(&text_usd);
    assert!(stage.find("/A").is_some());
}

#[test]
fn sublayers_references_and_payloads_to_usdc_compose_like_usda() {
    let binary = fixture("root.usda");
    assert_same_stage_with(&fixture("root_twin.usda"), &binary, |s| s.replace(".usdc", ".usda"));
    let stage = open_ok(&binary);
    let world = stage.prim(stage.find("/World").unwrap());
    assert_eq!(world.value("fromSub"), Some(&Value::Int(1)), "from the usdc sublayer");
    assert!(stage.find("/World/Ref/Body").is_some(), "referenced from asset.usdc");
    assert!(stage.find("/World/Heavy/Box").is_some(), "payload from payload.usdc");
}

#[test]
fn usdz_composes_like_the_unpacked_files() {
    let packed = open_ok(&fixture("package.usdz"));
    let unpacked = open_ok(&fixture("package/scene.usda"));
    let a = describe_stage(&unpacked);
    let b = describe_stage(&packed);
    assert_eq!(a.len(), b.len());
    let package = fixture("package.usdz").display().to_string();
    let dir = fixture("package").display().to_string();
    for (x, y) in a.iter().zip(&b) {
        // The same files, inside the package: `package/tex/a.exr` ↔ `package.usdz[tex/a.exr]`.
        let mut y = y.clone();
        while let Some(at) = y.find(&format!("{package}[")) {
            let close = at + y[at..].find(']').expect("closing bracket");
            let member = y[at + package.len() + 1..close].to_string();
            y.replace_range(at..=close, &format!("{dir}/{member}"));
        }
        assert_eq!(*x, y);
    }
    let checker = packed.prim(packed.find("/Looks/Checker/Surface").unwrap());
    let file = checker.value("inputs:file").and_then(Value::as_asset).unwrap();
    assert_eq!(file.resolved, PathBuf::from(format!("{package}[tex/checker.exr]")));
    // Any reader of `input::read_bytes` reads package members.
    let png = strata::input::read_bytes(&PathBuf::from(format!("{package}[tex/checker.png]"))).unwrap();
    assert_eq!(png, std::fs::read(fixture("package/tex/checker.png")).unwrap());
}

fn strata(args: &[&str]) -> (Option<i32>, String, String) {
    let out = common::run_strata(args, Duration::from_secs(120)).expect("strata finishes");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn usdz_renders_the_same_image_as_the_unpacked_scene() {
    let dir = tempfile::tempdir().unwrap();
    let mut images = Vec::new();
    for (name, scene) in [("packed", fixture("package.usdz")), ("unpacked", fixture("package/scene.usda"))] {
        let out = dir.path().join(format!("{name}.exr"));
        let (code, _, stderr) = strata(&[
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--res",
            "48x36",
            "--spp",
            "4",
            "--seed",
            "7",
        ]);
        assert_eq!(code, Some(0), "{stderr}");
        images.push(std::fs::read(out.with_extension("png")).unwrap());
    }
    let decode = |bytes: &[u8]| {
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        buf
    };
    let (a, b) = (decode(&images[0]), decode(&images[1]));
    assert_eq!(a, b, "rendering is deterministic per seed: the package must render identically");
    // The texture is really used: the floor shows both checker colours (orange and blue).
    let orange = a.chunks(3).any(|p| i32::from(p[0]) > i32::from(p[2]) + 40);
    let blue = a.chunks(3).any(|p| i32::from(p[2]) > i32::from(p[0]) + 40);
    assert!(orange && blue, "the checker texture from inside the package is visible");
}

#[test]
fn check_and_layers_on_binary_scenes() {
    let kitchen = fixture("kitchen.usdc");
    let (code, stdout, stderr) = strata(&["layers", kitchen.to_str().unwrap(), "--json"]);
    assert_eq!(code, Some(0), "{stderr}");
    let (code_t, stdout_t, _) = strata(&["layers", fixture("kitchen.usda").to_str().unwrap(), "--json"]);
    assert_eq!(code_t, Some(0));
    assert_eq!(stdout, stdout_t, "the slot table does not depend on the format");
    let table: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let quad = table.as_array().unwrap().iter().find(|p| p["prim"] == "/World/Quad").expect("quad");
    let slots: Vec<_> = quad["layers"].as_array().unwrap().iter().map(|l| l["slot"].as_str().unwrap()).collect();
    assert_eq!(slots, ["000"], "050 removed by `= None`, 070 only declared");
    assert_eq!(quad["layers"][0]["material"], "/Looks/Red");
    assert_eq!(quad["layers"][0]["overrides"][0]["material"], "/Looks/RedPaint");

    let (code, stdout, stderr) = strata(&["check", fixture("package.usdz").to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stdout.contains("ok (2 renderable prim(s)"), "{stdout}");
}

/// A crate cut short or with bytes flipped: a diagnostic naming the file and a non-zero
/// exit, never a panic. Every openusd panic is caught at the boundary (src/scene/usdc.rs).
#[test]
fn hostile_usdc_is_a_diagnostic_never_a_panic() {
    let good = std::fs::read(fixture("kitchen.usdc")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    for cut in [0usize, 7, 8, 16, 24, 88, 100, 500, 1000, 2000, good.len() / 2, good.len() - 200, good.len() - 1] {
        cases.push((format!("truncated at {cut}"), good[..cut.min(good.len())].to_vec()));
    }
    // Deterministic flips across the whole file, the table of contents and sections included.
    let mut state = 0x9e3779b97f4a7c15u64;
    for i in 0..48 {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let mut bad = good.clone();
        let at = (state as usize) % bad.len();
        bad[at] ^= 1 << (i % 8) | 0x40;
        cases.push((format!("byte {at} flipped"), bad));
    }
    let mut version = good.clone();
    version[9] = 3; // crate version 0.3.0
    cases.push(("old version".into(), version));
    let mut panics = 0;
    let mut rejected = 0;
    for (what, bytes) in &cases {
        let path = dir.path().join("hostile.usdc");
        std::fs::write(&path, bytes).unwrap();
        let result = std::panic::catch_unwind(|| open(&path));
        let Ok((stage, rendered)) = result else {
            panics += 1;
            continue;
        };
        if stage.is_none() {
            rejected += 1;
            assert!(rendered.contains("hostile.usdc"), "{what}: the diagnostic names the file:\n{rendered}");
        }
        assert!(!rendered.contains("panicked"), "{what}:\n{rendered}");
    }
    assert_eq!(panics, 0);
    assert!(rejected >= 14, "truncations are all rejected ({rejected} of {})", cases.len());

    // Through the command line: exit 1 and words that say what is wrong.
    let path = dir.path().join("cut.usdc");
    std::fs::write(&path, &good[..good.len() / 2]).unwrap();
    let (code, _, stderr) = strata(&["check", path.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("malformed usdc") && stderr.contains("cut.usdc"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let old = dir.path().join("old.usdc");
    std::fs::write(&old, &cases.last().unwrap().1).unwrap();
    let (code, _, stderr) = strata(&["check", old.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(stderr.contains("unsupported crate version 0.3.0"), "{stderr}");
}

#[test]
fn broken_packages_and_unknown_files_say_what_they_are() {
    let dir = tempfile::tempdir().unwrap();
    // A zip with no USD layer.
    let zip_path = dir.path().join("empty.usdz");
    {
        let file = std::fs::File::create(&zip_path).unwrap();
        let mut zip = zip::ZipWriter::new(file);
        zip.start_file("readme.txt", zip::write::SimpleFileOptions::default()).unwrap();
        std::io::Write::write_all(&mut zip, b"no layer here").unwrap();
        zip.finish().unwrap();
    }
    let (code, _, stderr) = strata(&["check", zip_path.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(stderr.contains("usdz package with no USD layer") && stderr.contains("empty.usdz"), "{stderr}");
    // A truncated zip.
    let cut = dir.path().join("cut.usdz");
    let package = std::fs::read(fixture("package.usdz")).unwrap();
    std::fs::write(&cut, &package[..package.len() - 30]).unwrap();
    let (code, _, stderr) = strata(&["check", cut.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("zip"), "{stderr}");
    // Binary garbage that is none of the three formats.
    let junk = dir.path().join("junk.usd");
    std::fs::write(&junk, [0xffu8, 0xfe, 0x00, 0x12]).unwrap();
    let (code, _, stderr) = strata(&["check", junk.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(stderr.contains("not a USD file"), "{stderr}");
    // A missing member of a package, as a sublayer names it.
    let root = dir.path().join("root.usda");
    std::fs::write(
        &root,
        format!("#usda 1.0\n(\n    subLayers = [@{}[nope.usda]@]\n)\n", fixture("package.usdz").display()),
    )
    .unwrap();
    // USD composes around a sublayer it cannot find: a warning, an error only with --strict.
    let (code, _, stderr) = strata(&["check", root.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stderr.contains("has no member `nope.usda`") && stderr.contains("root.usda:3:"), "{stderr}");
    let (code, _, stderr) = strata(&["check", "--strict", root.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
}
