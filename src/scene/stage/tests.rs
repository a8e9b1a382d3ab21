//! Stage composition tests: Pixar-written fixtures and the composition rules, one by one.

use super::*;
use std::fs;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/usd")
}

fn open(path: &Path) -> (Result<Stage, Failed>, String) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(path, &mut sources, &mut diags);
    (stage, diags.render(&sources))
}

fn text(text: &str) -> (Result<Stage, Failed>, String) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::from_text("scene.usda", text, Path::new("/nowhere"), &mut sources, &mut diags);
    (stage, diags.render(&sources))
}

fn ok(stage: (Result<Stage, Failed>, String)) -> Stage {
    match stage {
        (Ok(stage), _) => stage,
        (Err(_), rendered) => panic!("{rendered}"),
    }
}

/// A fresh directory under the system temp dir.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(name).tempdir().expect("temp dir")
}

fn prim<'s>(stage: &'s Stage, path: &str) -> &'s Prim {
    stage.prim(stage.find(path).unwrap_or_else(|| panic!("no prim {path}")))
}

#[test]
fn pixar_written_fixture() {
    let stage = ok(open(&fixtures().join("pixar_written.usda")));
    assert_eq!(stage.up_axis(), "Y");
    assert_eq!(stage.meters_per_unit(), 0.01);
    assert_eq!(stage.default_prim(), stage.find("/World"));
    let world = prim(&stage, "/World");
    assert_eq!(world.type_name.as_deref(), Some("Xform"));
    assert_eq!(world.value("xformOp:translate").and_then(Value::as_vec3), Some([1.0, 2.0, 3.0]));
    assert_eq!(world.value("xformOp:rotateXYZ").and_then(Value::as_vec3), Some([0.0, 90.0, 0.0]));
    assert_eq!(world.value("xformOpOrder").and_then(Value::as_string_array).map(<[String]>::len), Some(3));
    let quad = prim(&stage, "/World/Group/Quad");
    assert_eq!(quad.type_name.as_deref(), Some("Mesh"));
    assert_eq!(quad.value("faceVertexIndices").and_then(Value::as_int_array), Some(&[0, 1, 2, 3][..]));
    let points = quad.value("points").and_then(Value::as_vec3_array).unwrap();
    assert_eq!(points[0], [-1.0, 0.0, -1.0]);
    let st = quad.attribute("primvars:st").unwrap();
    assert_eq!(st.type_name, "texCoord2f[]");
    assert_eq!(st.meta("interpolation").and_then(Value::as_str), Some("faceVarying"));
    assert_eq!(st.get().and_then(Value::as_tuple_array).map(|(w, d)| (w, d.len())), Some((2, 8)));
    assert_eq!(quad.value("doubleSided"), Some(&Value::Bool(true)));
    let slot0 = quad.relationship("material:slotBinding:_000").unwrap();
    assert_eq!(slot0.targets[0].0, "/World/Looks/Plastic");
    let slot50 = quad.relationship("material:slotBinding:_050").unwrap();
    assert!(slot50.is_explicit_empty());
    let nested = quad.relationship("material:slotBinding:_050:_:_010").unwrap();
    assert_eq!(nested.targets.len(), 2);
    assert_eq!(quad.relationships_with_prefix("material:slotBinding:").count(), 3);
    let ball = prim(&stage, "/World/Ball");
    assert_eq!(ball.api_schemas, vec!["MaterialBindingAPI".to_string()]);
    assert_eq!(ball.value("radius"), Some(&Value::Float(0.5)));
    let cam = prim(&stage, "/World/Cam");
    let m = cam.value("xformOp:transform").and_then(Value::as_matrix4).unwrap();
    assert_eq!(&m[12..], &[0.0, 1.0, 5.0, 1.0]);
    let sky = prim(&stage, "/World/Sky");
    let tex = sky.value("inputs:texture:file").and_then(Value::as_asset).unwrap();
    assert_eq!(tex.resolved, fixtures().join("sky.exr"));
    assert_eq!(prim(&stage, "/World/Panel").type_name.as_deref(), Some("RectLight"));
    let shader = prim(&stage, "/World/Looks/Plastic/Surface");
    assert_eq!(shader.value("info:implementationSource").and_then(Value::as_str), Some("sourceAsset"));
    let source = shader.value("info:strata:sourceAsset").and_then(Value::as_asset).unwrap();
    assert_eq!(source.authored, "plastic.ash");
    assert_eq!(shader.value("info:strata:sourceAsset:subIdentifier"), Some(&Value::Token("plastic".into())));
    assert_eq!(shader.value("inputs:base_color").and_then(Value::as_vec3), Some([0.8, 0.1, 0.1]));
    let output = prim(&stage, "/World/Looks/Plastic").attribute("outputs:strata:surface").unwrap();
    assert_eq!(output.connections[0].0, "/World/Looks/Plastic/Surface.outputs:surface");
    // Depth-first order visits parents first and keeps file order.
    let order: Vec<&str> = stage.depth_first().map(|(_, p)| p.name.as_str()).take(4).collect();
    assert_eq!(order, vec!["World", "Group", "Quad", "Ball"]);
    assert_eq!(stage.subtree(stage.find("/World/Looks").unwrap()).count(), 3);
}

#[test]
fn pixar_sublayer_and_reference_fixture() {
    let stage = ok(open(&fixtures().join("sub_root.usda")));
    // The weak sublayer's root prim is there, after nothing stronger reorders it.
    assert!(stage.find("/Weak").is_some());
    let body = prim(&stage, "/Scene/Thing/Body");
    assert_eq!(body.type_name.as_deref(), Some("Cube"));
    // The sublayer is local, so it beats the reference.
    assert_eq!(body.value("size"), Some(&Value::Float(5.0)));
    // Targets inside the referenced asset are mapped to where it is referenced.
    let slot = body.relationship("material:slotBinding:_000").unwrap();
    assert_eq!(slot.targets[0].0, "/Scene/Thing/Mat");
    assert!(stage.find("/Scene/Thing/Mat").is_some());
}

#[test]
fn pixar_kitchen_fixture() {
    let (stage, rendered) = open(&fixtures().join("pixar_kitchen.usda"));
    let stage = stage.unwrap_or_else(|_| panic!("{rendered}"));
    assert!(!rendered.contains("timeSamples"), "{rendered}");
    let root = prim(&stage, "/Root");
    assert_eq!(root.kind.as_deref(), Some("component"));
    assert_eq!(root.value("inherited"), Some(&Value::Float(7.0)));
    assert_eq!(root.value("color").and_then(Value::as_vec3), Some([1.0, 0.0, 0.0]));
    assert!(stage.find("/Root/RedOnly").is_some());
    assert!(stage.find("/Root/Off").is_none());
    assert!(stage.find("/_class_Base").is_none());
    assert!(stage.find("/OverOnly").is_none());
    // usd-core: `anim.Get(stage.GetStartTimeCode())` is 2 (samples beat the default), `Get()` 1.
    assert_eq!(root.value("anim"), Some(&Value::Float(2.0)));
    assert_eq!(root.attribute("anim").and_then(|a| a.value_at(TimeCode::Default)), Some(Value::Float(1.0)));
    assert_eq!(root.value("only_ts").and_then(Value::as_vec3), Some([1.0, 1.0, 1.0]));
    assert!(root.attribute("blocked").unwrap().blocked);
    assert_eq!(root.value("f"), Some(&Value::Float(f64::INFINITY)));
    assert_eq!(root.value("s").and_then(Value::as_str), Some("it's \"quoted\"\nnewline\ttab \\ back"));
    assert_eq!(root.value("s3").and_then(Value::as_str), Some("multi\nline with \"\"\" inside"));
    assert_eq!(root.value("ast_at").and_then(Value::as_str), Some("weird@name.png"));
    assert_eq!(root.value("m3"), Some(&Value::Matrix3([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])));
    assert_eq!(root.value("m4a").and_then(Value::as_tuple_array).map(|(w, d)| (w, d.len())), Some((16, 32)));
    assert_eq!(root.value("ba"), Some(&Value::BoolArray(vec![true, false])));
    assert_eq!(root.value("i64"), Some(&Value::Int(-9_000_000_000)));
    let r = root.relationship("r").unwrap();
    let targets: Vec<&str> = r.targets.iter().map(|t| t.0.as_str()).collect();
    assert_eq!(targets, vec!["/Root/Child", "/Other"]);
    assert!(!r.explicit);
    assert!(root.relationship("explicit_empty_list").unwrap().is_explicit_empty());
    assert!(!root.relationship("declared_rel").unwrap().is_explicit_empty());
    // Declared only is no target opinion at all; an authored empty list is one.
    assert!(!root.relationship("declared_rel").unwrap().has_authored_targets());
    assert!(root.relationship("explicit_empty_list").unwrap().has_authored_targets());
    assert!(r.has_authored_targets());
    let dst = root.attribute("dst").unwrap();
    assert_eq!(dst.connections.len(), 2);
    let inst = prim(&stage, "/Root/Inst");
    assert!(inst.instanceable);
    assert_eq!(inst.value("from_payload"), Some(&Value::Int(1)));
    assert_eq!(inst.value("from_other"), Some(&Value::Int(2)));
    assert_eq!(inst.value("inherited"), Some(&Value::Float(7.0)));
    let meta = stage.metadata();
    assert_eq!(meta.doc.as_deref(), Some("Kitchen \"sink\"\nsecond line"));
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    fs::write(&path, text).expect("write fixture");
    path
}

#[test]
fn sublayers_strongest_first_and_nested_references() {
    let dir = temp_dir("strata-compose");
    let d = dir.path();
    fs::create_dir(d.join("sub")).unwrap();
    write(d, "sub/leaf.usda", "#usda 1.0\n(defaultPrim = \"Leaf\")\ndef Sphere \"Leaf\" { double radius = 3 }\n");
    write(
        d,
        "sub/mid.usda",
        "#usda 1.0\n(defaultPrim = \"Mid\")\ndef Xform \"Mid\" { def \"L\" (references = @./leaf.usda@) { double radius = 2 } }\n",
    );
    write(d, "strong.usda", "#usda 1.0\nover \"A\" { float x = 1 }\n");
    write(d, "weak.usda", "#usda 1.0\ndef \"A\" { float x = 2\n float y = 2 }\n");
    let root = write(
        d,
        "root.usda",
        "#usda 1.0\n(subLayers = [@strong.usda@, @weak.usda@])\ndef \"R\" (prepend references = @sub/mid.usda@) { }\n",
    );
    let stage = ok(open(&root));
    let a = prim(&stage, "/A");
    assert_eq!(a.value("x"), Some(&Value::Float(1.0)));
    assert_eq!(a.value("y"), Some(&Value::Float(2.0)));
    let leaf = prim(&stage, "/R/L");
    assert_eq!(leaf.type_name.as_deref(), Some("Sphere"));
    assert_eq!(leaf.value("radius"), Some(&Value::Float(2.0)));
}

#[test]
fn cycles_are_errors_and_missing_files_warnings() {
    let dir = temp_dir("strata-cycle");
    let d = dir.path();
    write(d, "a.usda", "#usda 1.0\n(subLayers = [@b.usda@])\n");
    write(d, "b.usda", "#usda 1.0\n(subLayers = [@a.usda@])\n");
    let (stage, rendered) = open(&d.join("a.usda"));
    assert!(stage.is_err());
    assert!(rendered.contains("cycle") && rendered.contains("b.usda:2:15"), "{rendered}");

    write(d, "r1.usda", "#usda 1.0\n(defaultPrim = \"P\")\ndef \"P\" (references = @r2.usda@) {}\n");
    write(d, "r2.usda", "#usda 1.0\n(defaultPrim = \"P\")\ndef \"P\" (references = @r1.usda@) {}\n");
    let (stage, rendered) = open(&d.join("r1.usda"));
    assert!(stage.is_err());
    assert!(rendered.contains("reference cycle"), "{rendered}");

    // A layer that does not resolve is composed around, with a located warning.
    let missing = write(d, "m.usda", "#usda 1.0\ndef \"P\" (\n    references = @gone.usda@\n) {}\n");
    let (stage, rendered) = open(&missing);
    assert!(stage.is_ok_and(|s| s.find("/P").is_some()), "{rendered}");
    assert!(rendered.starts_with("warning: cannot read layer `gone.usda`"), "{rendered}");
    assert!(rendered.contains("m.usda:3:18") && rendered.contains("@gone.usda@"), "{rendered}");

    let (stage, rendered) = text("#usda 1.0\ndef \"A\" (references = </A>) {}\n");
    assert!(stage.is_err() && rendered.contains("cycle"), "{rendered}");
}

#[test]
fn internal_references_inherits_classes_and_variants() {
    let stage = ok(text(
        r#"#usda 1.0
class "_base" { float k = 1
def "Part" { float p = 1 } }
def "Proto" { float r = 5
rel mat = </Proto/M>
def "M" {} }
def "A" (
inherits = </_base>
references = </Proto>
variants = { string look = "b" }
variantSets = "look"
) {
float r = 6
variantSet "look" = {
    "a" { float v = 1 }
    "b" { float v = 2
          def "FromVariant" {} }
}
}
def "Inactive" (active = false) { def "Kid" {} }
"#,
    ));
    let a = prim(&stage, "/A");
    assert_eq!(a.value("k"), Some(&Value::Float(1.0)));
    assert_eq!(a.value("r"), Some(&Value::Float(6.0)));
    assert_eq!(a.value("v"), Some(&Value::Float(2.0)));
    assert_eq!(a.relationship("mat").unwrap().targets[0].0, "/A/M");
    assert_eq!(a.variant_selections, vec![("look".to_string(), "b".to_string())]);
    // A `def` inside a class is inherited as a defined child, as in USD.
    assert_eq!(prim(&stage, "/A/Part").value("p"), Some(&Value::Float(1.0)));
    assert!(stage.find("/A/FromVariant").is_some());
    assert!(stage.find("/A/M").is_some());
    assert!(stage.find("/_base").is_none());
    assert!(stage.find("/Inactive").is_none() && stage.find("/Inactive/Kid").is_none());
    let roots: Vec<&str> = stage.root_children().iter().map(|&id| stage.prim(id).path.as_str()).collect();
    assert_eq!(roots, vec!["/Proto", "/A"]);
}

#[test]
fn relationship_list_ops_compose_weakest_to_strongest() {
    let dir = temp_dir("strata-rel");
    let d = dir.path();
    write(d, "weak.usda", "#usda 1.0\ndef \"P\" { rel r = [</a>, </b>]\n rel s = [</x>] }\n");
    let root = write(
        d,
        "root.usda",
        "#usda 1.0\n(subLayers = [@weak.usda@])\nover \"P\" { delete rel r = </a>\n append rel r = </c>\n rel s = None\n custom rel material:slotBinding:_050 = None }\n",
    );
    let stage = ok(open(&root));
    let p = prim(&stage, "/P");
    let r: Vec<&str> = p.relationship("r").unwrap().targets.iter().map(|t| t.0.as_str()).collect();
    assert_eq!(r, vec!["/b", "/c"]);
    assert!(p.relationship("s").unwrap().is_explicit_empty());
    assert!(p.relationship("material:slotBinding:_050").unwrap().is_explicit_empty());
    // The span is the strongest opinion's.
    let span = p.relationship("s").unwrap().span;
    assert_eq!(span.file, stage.root_file());
}

#[test]
fn warnings_for_missing_variant_selection() {
    let (stage, rendered) = text("#usda 1.0\ndef \"A\" { variantSet \"v\" = { \"x\" { float a = 1 } } }\n");
    assert!(stage.is_ok());
    assert!(rendered.contains("no variant selected"), "{rendered}");
}

#[test]
fn diagnostics_render_file_line_col() {
    let (stage, rendered) = text("#usda 1.0\ndef \"A\"\n{\n    float3 x = (1, 2, \"a\")\n}\n");
    assert!(stage.is_err());
    assert!(rendered.contains("scene.usda:4:16"), "{rendered}");
    assert!(rendered.contains("float3 x = (1, 2, \"a\")"), "{rendered}");
}

#[test]
fn fifty_thousand_siblings_compose() {
    // Composition was quadratic in the number of siblings (109 000 took 89 s); with the
    // name lookups hashed this is a fraction of a second, and a regression to quadratic
    // would take minutes here — long past any test timeout.
    let n = 50_000;
    let mut scene = String::from("#usda 1.0\ndef Xform \"World\" {\n");
    for i in 0..n {
        scene += &format!("    def Xform \"S{i}\" {{ double x = {i} }}\n");
    }
    scene += "}\n";
    for i in 0..n {
        scene += &format!("def Xform \"R{i}\" {{}}\n");
    }
    let stage = ok(text(&scene));
    assert_eq!(stage.len(), 2 * n + 1);
    let world = prim(&stage, "/World");
    assert_eq!(world.children.len(), n);
    assert_eq!(prim(&stage, "/World/S49999").value("x"), Some(&Value::Float(49999.0)));
    assert_eq!(prim(&stage, "/World/S123").value("x"), Some(&Value::Float(123.0)));
}

#[test]
fn deep_nesting_is_an_error_not_a_stack_overflow() {
    let deep = format!("#usda 1.0\ndef \"A\" {{ float[] x = {} }}\n", "[".repeat(100_000));
    assert!(text(&deep).0.is_err());
    let prims = format!("#usda 1.0\n{}{}", "def \"A\" {\n".repeat(5000), "}\n".repeat(5000));
    assert!(text(&prims).0.is_err());
}

/// Tiny deterministic PRNG so the fuzz test needs no dependency.
struct XorShift(u64);
impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

#[test]
fn mutation_fuzz_never_panics() {
    let seeds = [
        include_str!("../../../tests/fixtures/usd/pixar_written.usda"),
        include_str!("../../../tests/fixtures/usd/pixar_kitchen.usda"),
        include_str!("../../../tests/fixtures/usd/sub_root.usda"),
    ];
    let alphabet = b"()[]{}<>@\"'#=,.:;/\\ \n0123456789-eEinfNoneadefoverclassrelpathuniform_";
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    let dir = fixtures();
    for round in 0..1500 {
        let seed = seeds[round % seeds.len()];
        let mut bytes = seed.as_bytes().to_vec();
        for _ in 0..1 + rng.below(8) {
            let at = rng.below(bytes.len());
            match rng.below(4) {
                0 => bytes[at] = alphabet[rng.below(alphabet.len())],
                1 => {
                    bytes.remove(at);
                }
                2 => bytes.insert(at, alphabet[rng.below(alphabet.len())]),
                _ => {
                    let len = rng.below(40).min(bytes.len() - at);
                    let chunk: Vec<u8> = bytes[at..at + len].to_vec();
                    let to = rng.below(bytes.len());
                    bytes.splice(to..to, chunk);
                }
            }
        }
        let text = String::from_utf8_lossy(&bytes);
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let _ = Stage::from_text("fuzz.usda", &text, &dir, &mut sources, &mut diags);
        let _ = diags.render(&sources);
    }
}
