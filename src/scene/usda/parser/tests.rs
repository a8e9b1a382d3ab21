//! Parser tests: every statement form, list ops, spans, and error recovery.

use super::values::unquote;
use super::*;
use crate::diag::SourceMap;
use crate::scene::usda::{
    AttributeSpec, Layer, LayerOffset, ListOp, ListOpKind, PrimSpec, PropertySpec, RelationshipSpec, Specifier,
};
use crate::scene::value::Value;

fn parse_text(text: &str) -> (Layer, Diagnostics, SourceMap) {
    let mut sources = SourceMap::new();
    let file = sources.add("test.usda", text);
    let mut diags = Diagnostics::new();
    let layer = parse(file, text, Path::new("/scenes"), &mut diags);
    (layer, diags, sources)
}

fn parse_ok(text: &str) -> Layer {
    let (layer, diags, sources) = parse_text(text);
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    layer
}

fn attr<'l>(prim: &'l PrimSpec, name: &str) -> &'l AttributeSpec {
    match prim.property(name) {
        Some(PropertySpec::Attribute(a)) => a,
        other => panic!("no attribute {name}: {other:?}"),
    }
}

fn rel<'l>(prim: &'l PrimSpec, name: &str) -> &'l RelationshipSpec {
    match prim.property(name) {
        Some(PropertySpec::Relationship(r)) => r,
        other => panic!("no relationship {name}: {other:?}"),
    }
}

#[test]
fn layer_metadata() {
    let layer = parse_ok(
        r#"#usda 1.0
(
"a comment"
doc = """Multi
line"""
defaultPrim = "World"
upAxis = "Z"
metersPerUnit = 1
subLayers = [@a.usda@, @./b.usda@ (offset = 10; scale = 2)]
customLayerData = { string tool = "x" dictionary d = { int[] l = [1, 2] } }
startTimeCode = 1
)
"#,
    );
    let m = &layer.metadata;
    assert_eq!(m.comment.as_deref(), Some("a comment"));
    assert_eq!(m.doc.as_deref(), Some("Multi\nline"));
    assert_eq!(m.default_prim.as_ref().map(|d| d.0.as_str()), Some("World"));
    assert_eq!(m.up_axis.as_deref(), Some("Z"));
    assert_eq!(m.meters_per_unit, Some(1.0));
    let subs: Vec<_> = m.sub_layers.iter().map(|(a, _)| a.resolved.clone()).collect();
    assert_eq!(m.sub_layer_offsets[0], LayerOffset::default());
    assert_eq!(m.sub_layer_offsets[1], LayerOffset { offset: 10.0, scale: 2.0 });
    assert_eq!(subs, vec![PathBuf::from("/scenes/a.usda"), PathBuf::from("/scenes/b.usda")]);
    assert_eq!(m.other.len(), 2);
    let custom = m.other[0].value.as_dictionary().unwrap();
    assert_eq!(custom[0], ("tool".to_string(), Value::String("x".into())));
    assert_eq!(custom[1].1.as_dictionary().unwrap()[0].1, Value::IntArray(vec![1, 2].into()));
}

use std::path::PathBuf;

#[test]
fn prims_and_prim_metadata() {
    let layer = parse_ok(
        r#"#usda 1.0
def Xform "World" (
kind = "assembly"
active = false
instanceable = true
doc = "d"
prepend references = @./x.usda@</Prim>
append payload = [@p.usda@, </Internal>]
inherits = [</_class_A>, </_class_B>]
prepend apiSchemas = ["MaterialBindingAPI"]
variants = { string shading = "red" }
prepend variantSets = "shading"
hidden = true
)
{
def "Child" { }
over "O" { }
class "C" { }
reorder nameChildren = ["O", "Child"]
}
"#,
    );
    let world = &layer.prims[0];
    assert_eq!(world.specifier, Specifier::Def);
    assert_eq!(world.type_name.as_deref(), Some("Xform"));
    let m = &world.metadata;
    assert_eq!(m.kind.as_deref(), Some("assembly"));
    assert_eq!((m.active, m.instanceable), (Some(false), Some(true)));
    let r = &m.references.prepended[0];
    assert_eq!(r.asset.as_ref().unwrap().resolved, PathBuf::from("/scenes/x.usda"));
    assert_eq!(r.prim_path.as_deref(), Some("/Prim"));
    assert_eq!(m.payloads.appended.len(), 2);
    assert!(m.payloads.appended[1].asset.is_none());
    assert_eq!(m.inherits.explicit.as_ref().unwrap().len(), 2);
    assert_eq!(m.api_schemas.prepended, vec!["MaterialBindingAPI".to_string()]);
    assert_eq!(m.variant_selections[0].0, "shading");
    assert_eq!(m.variant_selections[0].1, "red");
    assert_eq!(m.variant_set_names.prepended, vec!["shading".to_string()]);
    assert_eq!(m.other[0].key, "hidden");
    let specs: Vec<_> = world.children.iter().map(|c| (c.specifier, c.name.as_str())).collect();
    assert_eq!(specs, vec![(Specifier::Def, "Child"), (Specifier::Over, "O"), (Specifier::Class, "C")]);
    assert_eq!(layer.prim_at("/World/O").map(|p| p.name.as_str()), Some("O"));
}

#[test]
fn attributes_of_every_shape() {
    let layer = parse_ok(
        r#"#usda 1.0
def Mesh "M"
{
uniform bool doubleSided = 1
int[] faceVertexCounts = [4]
point3f[] points = [(-1, 0, -1), (1, 0, -1), (1, 0, 1e2), (-1, 0, 1)]
texCoord2f[] primvars:st = [(0, 0), (1, 0)] (
    interpolation = "faceVarying"
    elementSize = 1
    doc = """long
doc"""
)
float3 xformOp:scale
custom double d = -inf
float f = nan
half h = 1
string s = 'it\'s'
token t = "tok"
asset a = @@@we@ird@@@
matrix4d xformOp:transform = ( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1, 5, 1) )
quatf q = (1, 0, 0, 0)
color3f c = (0.8, 0.1, 0.1)
float[] empty = []
token[] ops = ["xformOp:translate", "xformOp:scale"]
float blocked = None
float anim = 1
float anim.timeSamples = { 0: 2, 10: 3.5, }
token outputs:surface.connect = </Mat/Shader.outputs:surface>
int64 big = -9000000000
int2 i2 = (1, 2)
}
"#,
    );
    let m = &layer.prims[0];
    assert_eq!(attr(m, "doubleSided").default.as_ref().unwrap().0, Value::Bool(true));
    assert!(attr(m, "doubleSided").uniform);
    assert_eq!(attr(m, "faceVertexCounts").default.as_ref().unwrap().0, Value::IntArray(vec![4].into()));
    let points = &attr(m, "points").default.as_ref().unwrap().0;
    assert_eq!(points.as_tuple_array().map(|(w, d)| (w, d.len(), d[8])), Some((3, 12, 100.0)));
    let st = attr(m, "primvars:st");
    assert_eq!(st.type_name, "texCoord2f[]");
    assert_eq!(st.meta("interpolation"), Some(&Value::String("faceVarying".into())));
    assert_eq!(st.meta("elementSize"), Some(&Value::Int(1)));
    assert_eq!(st.meta("doc"), Some(&Value::String("long\ndoc".into())));
    assert!(attr(m, "xformOp:scale").default.is_none());
    assert_eq!(attr(m, "d").default.as_ref().unwrap().0, Value::Float(f64::NEG_INFINITY));
    assert!(attr(m, "f").default.as_ref().unwrap().0.as_f64().unwrap().is_nan());
    assert_eq!(attr(m, "h").default.as_ref().unwrap().0, Value::Float(1.0));
    assert_eq!(attr(m, "s").default.as_ref().unwrap().0, Value::String("it's".into()));
    assert_eq!(attr(m, "t").default.as_ref().unwrap().0, Value::Token("tok".into()));
    let a = attr(m, "a").default.as_ref().unwrap().0.as_asset().unwrap().clone();
    assert_eq!(a.authored, "we@ird");
    let xf = attr(m, "xformOp:transform").default.as_ref().unwrap().0.as_matrix4().copied();
    assert_eq!(xf.map(|x| (x[0], x[13], x[14])), Some((1.0, 1.0, 5.0)));
    assert_eq!(attr(m, "q").default.as_ref().unwrap().0.as_vec4(), Some([1.0, 0.0, 0.0, 0.0]));
    assert_eq!(attr(m, "c").default.as_ref().unwrap().0.as_vec3(), Some([0.8, 0.1, 0.1]));
    assert_eq!(attr(m, "empty").default.as_ref().unwrap().0, Value::FloatArray(Default::default()));
    assert_eq!(
        attr(m, "ops").default.as_ref().unwrap().0,
        Value::TokenArray(vec!["xformOp:translate".into(), "xformOp:scale".into()])
    );
    assert_eq!(attr(m, "blocked").default.as_ref().unwrap().0, Value::None);
    let anim = attr(m, "anim");
    assert_eq!(anim.default.as_ref().unwrap().0, Value::Float(1.0));
    assert_eq!(anim.time_samples, vec![(0.0, Value::Float(2.0)), (10.0, Value::Float(3.5))]);
    let conn = &attr(m, "outputs:surface").connections;
    assert_eq!(conn.explicit.as_ref().unwrap()[0].0, "/Mat/Shader.outputs:surface");
    assert_eq!(attr(m, "big").default.as_ref().unwrap().0, Value::Int(-9_000_000_000));
    assert_eq!(attr(m, "i2").default.as_ref().unwrap().0, Value::Tuple(vec![1.0, 2.0]));
}

#[test]
fn time_samples_are_read_quietly() {
    let (_, diags, sources) = parse_text("#usda 1.0\ndef \"A\" { float x.timeSamples = { 0: 1 } }\n");
    assert!(!diags.has_errors());
    assert_eq!(diags.render(&sources), "");
}

#[test]
fn relationships_and_list_ops() {
    let layer = parse_ok(
        r#"#usda 1.0
def "A"
{
custom rel material:slotBinding:_000 = </World/Looks/Plastic>
custom rel material:slotBinding:_050 = None
rel empty = []
custom rel material:slotBinding:_050:_:_010 = [
    </World/Looks/Plastic>,
    </World/Looks/Plastic/Surface>,
]
rel r
delete rel r = </Gone>
prepend rel r = </Root/Child>
append rel r = </Other> (doc = "x")
add rel r = [</Added>]
reorder rel r = [</Other>, </Root/Child>]
}
"#,
    );
    let a = &layer.prims[0];
    let one = rel(a, "material:slotBinding:_000");
    assert_eq!(one.targets.explicit.as_ref().unwrap()[0].0, "/World/Looks/Plastic");
    assert!(one.custom);
    let none = rel(a, "material:slotBinding:_050");
    assert!(none.explicit_none);
    assert_eq!(none.targets.explicit, Some(vec![]));
    let empty = rel(a, "empty");
    assert!(!empty.explicit_none);
    assert_eq!(empty.targets.explicit, Some(vec![]));
    assert_eq!(rel(a, "material:slotBinding:_050:_:_010").targets.explicit.as_ref().unwrap().len(), 2);
    let r = rel(a, "r");
    assert_eq!(r.targets.deleted[0].0, "/Gone");
    assert_eq!(r.targets.prepended[0].0, "/Root/Child");
    assert_eq!(r.targets.appended[0].0, "/Other");
    assert_eq!(r.targets.added[0].0, "/Added");
    assert_eq!(r.targets.ordered.len(), 2);
    assert_eq!(r.metadata[0].key, "doc");
    // `rel r` alone authors no targets; the later list-op statements do.
    assert!(r.authored.is_some_and(|s| s != r.span));
    assert!(none.authored.is_some() && empty.authored.is_some());
}

#[test]
fn declared_relationships_author_no_targets() {
    let text = "#usda 1.0\ndef \"A\" {\n    rel d\n    custom rel material:slotBinding:_é\n    prepend rel p = []\n}\n";
    let layer = parse_ok(text);
    assert!(rel(&layer.prims[0], "d").authored.is_none());
    assert!(rel(&layer.prims[0], "material:slotBinding:_é").authored.is_none());
    // An empty prepend is still an opinion about the targets.
    assert!(rel(&layer.prims[0], "p").authored.is_some());
}

#[test]
fn target_spans_point_at_paths() {
    let text = "#usda 1.0\ndef \"A\" { rel r = [</X>, </Y/Z>] }\n";
    let layer = parse_ok(text);
    let r = rel(&layer.prims[0], "r");
    let spans: Vec<&str> =
        r.targets.explicit.as_ref().unwrap().iter().map(|(_, s)| &text[s.start as usize..s.end as usize]).collect();
    assert_eq!(spans, vec!["</X>", "</Y/Z>"]);
}

#[test]
fn variant_sets() {
    let layer = parse_ok(
        r#"#usda 1.0
def "A" (
variants = { string v = "x" }
prepend variantSets = "v"
)
{
variantSet "v" = {
    "x" (prepend references = </R>) {
        float a = 1
        def Sphere "S" { }
    }
    "y" {
    }
}
}
"#,
    );
    let set = &layer.prims[0].variant_sets[0];
    assert_eq!(set.name, "v");
    assert_eq!(set.variants.len(), 2);
    assert_eq!(set.variants[0].name, "x");
    assert_eq!(set.variants[0].children[0].name, "S");
    assert_eq!(set.variants[0].metadata.references.prepended.len(), 1);
}

#[test]
fn list_op_apply() {
    let mut list = vec!["a", "b", "c"];
    let mut op = ListOp::default();
    op.set(ListOpKind::Delete, vec!["b"]);
    op.set(ListOpKind::Prepend, vec!["c", "x"]);
    op.set(ListOpKind::Append, vec!["a"]);
    op.set(ListOpKind::Add, vec!["y", "c"]);
    assert!(!op.apply(&mut list, |a, b| a == b));
    assert_eq!(list, vec!["c", "x", "y", "a"]);
    let mut reorder = ListOp::default();
    reorder.set(ListOpKind::Reorder, vec!["a", "x"]);
    reorder.apply(&mut list, |a, b| a == b);
    assert_eq!(list, vec!["c", "a", "x", "y"]);
    let mut explicit = ListOp::default();
    explicit.set(ListOpKind::Explicit, vec![]);
    assert!(explicit.apply(&mut list, |a, b| a == b));
    assert!(list.is_empty());
}

#[test]
fn errors_have_locations_and_recover() {
    let text = "#usda 1.0\ndef \"A\"\n{\n    float x = \"nope\"\n    float3 y = (1, 2\n    def \"B\" { int z = [1 }\n}\ndef \"C\" { }\n";
    let (layer, diags, sources) = parse_text(text);
    assert!(diags.error_count() >= 2, "{}", diags.render(&sources));
    let rendered = diags.render(&sources);
    assert!(rendered.contains("test.usda:4:15"), "{rendered}");
    assert!(rendered.contains("float x = \"nope\""), "{rendered}");
    // Recovery keeps later prims.
    assert!(layer.prims.iter().any(|p| p.name == "C"), "{layer:?}");
}

#[test]
fn missing_header_is_an_error() {
    let (_, diags, sources) = parse_text("def \"A\" {}\n");
    assert!(diags.render(&sources).contains("#usda 1.0"));
}

#[test]
fn unquote_escapes() {
    assert_eq!(unquote(r#""a\"b\n\x41\101\\""#, false), "a\"b\nAA\\");
    assert_eq!(unquote("'''x\\'''y'''", true), "x'''y");
}
