//! Composition rules 1c (collection-based slot bindings) and 3b (vertical slots `X|Y`),
//! data-driven: each case is a small stage and the layer table derived by hand from
//! DESIGN.md, never from strata's output. Collection membership is checked against the
//! answers usd-core's `ComputeMembershipQuery` gave (`tools/make_slot_collection_fixtures.py`
//! wrote `tests/fixtures/slot_collections/`); no Python runs at test time.

use std::path::Path;
use strata::compose::binding::binding_tree;
use strata::compose::collection::Collection;
use strata::compose::scene::compose_stage;
use strata::compose::slots::{LayerBinding, PrimStack, resolve_stacks};
use strata::diag::{Diagnostics, SourceMap};
use strata::scene::Stage;

/// One layer as `slot=material@bound_at`, `~collection` when a collection bound it,
/// `[override=material]` per override and `{vertical ...}` per vertical layer.
fn layer_text(l: &LayerBinding) -> String {
    let mut t = format!("{}={}@{}", l.slot.name(), l.applied.material, l.applied.bound_at);
    if let Some(c) = &l.applied.collection {
        t += &format!("~{c}");
    }
    for o in &l.overrides {
        t += &format!("[{}={}]", o.slot.name(), o.applied.material);
    }
    for v in &l.vertical {
        t += &format!("{{{}}}", layer_text(v));
    }
    t
}

fn table(stacks: &[PrimStack]) -> Vec<String> {
    stacks
        .iter()
        .map(|s| format!("{}: {}", s.prim, s.layers.iter().map(layer_text).collect::<Vec<_>>().join(" ")))
        .collect()
}

/// The stage `text` with empty Materials `/M/A`..`/M/Z` appended (the bound materials).
fn open(text: &str) -> (Stage, SourceMap, Diagnostics) {
    let mut text = format!("#usda 1.0\n{text}\ndef Scope \"M\" {{\n");
    for name in 'A'..='Z' {
        text += &format!("    def Material \"{name}\" {{}}\n");
    }
    text += "}\n";
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::from_text("rules.usda", &text, Path::new("."), &mut sources, &mut diags)
        .unwrap_or_else(|_| panic!("{}", diags.render(&sources)));
    (stage, sources, diags)
}

/// The layer table of `text`, and the rendered warnings.
fn layers(text: &str) -> (Vec<String>, String) {
    let (stage, sources, mut diags) = open(text);
    let tree = binding_tree(&stage, &mut diags);
    let stacks = resolve_stacks(&tree, &mut diags);
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    (table(&stacks), diags.render(&sources))
}

// ---------------------------------------------------------------- rule 1c: membership

#[test]
fn collection_membership_agrees_with_usd_core() {
    let folder = Path::new("tests/fixtures/slot_collections");
    let mut cases = 0;
    for entry in std::fs::read_dir(folder).expect("fixtures") {
        let path = entry.expect("entry").path();
        if path.extension().is_none_or(|e| e != "usda") {
            continue;
        }
        cases += 1;
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::open(&path, &mut sources, &mut diags).expect("fixture opens");
        let stacks = resolve_stacks(&binding_tree(&stage, &mut diags), &mut diags);
        assert!(diags.items().is_empty(), "{}: {}", path.display(), diags.render(&sources));
        let expected = std::fs::read_to_string(path.with_extension("expected")).expect("expected");
        let mut collection = None;
        let mut members = Vec::new();
        for line in expected.lines().filter(|l| !l.starts_with('#')) {
            let words: Vec<&str> = line.split(' ').collect();
            match words.as_slice() {
                ["bound", prim, answer] => {
                    let stack =
                        stacks.iter().find(|s| s.prim == *prim).unwrap_or_else(|| panic!("{prim} is renderable"));
                    let bound = stack.layers.iter().any(|l| l.slot.name() == "050" && l.applied.material == "/M/Dirt");
                    assert_eq!(bound, *answer == "yes", "{}: {prim} (usd-core says {answer})", path.display());
                }
                ["collection", owner, name] => collection = Some((owner.to_string(), name.to_string())),
                ["member", prim] => members.push(prim.to_string()),
                _ => panic!("bad line `{line}`"),
            }
        }
        // Every prim of the stage, renderable or not: a member exactly when usd-core's
        // `ComputeIncludedPathsFromCollection` lists it.
        if let Some((owner, name)) = collection {
            let owner = stage.prim(stage.find(&owner).expect("owner"));
            let read = Collection::read(&stage, owner, &name, &mut diags);
            for (_, prim) in stage.depth_first() {
                let prim = &prim.path;
                assert_eq!(read.contains(prim), members.contains(prim), "{}: member {prim}", path.display());
            }
        }
    }
    assert_eq!(cases, 15, "every generated case is checked");
}

// ---------------------------------------------------------------- rule 1c: strength

#[test]
fn collection_beats_a_direct_binding_at_the_same_level() {
    let (lines, _) = layers(
        r#"
def Xform "W" (prepend apiSchemas = ["CollectionAPI:dirty"]) {
    rel collection:dirty:includes = </W/a>
    rel material:slotBinding:_050 = </M/A>
    rel material:slotBinding:_050:collection:dirt = [</W.collection:dirty>, </M/B>]
    def Mesh "a" {}
    def Mesh "b" {}
}
"#,
    );
    assert_eq!(lines, vec!["/W/a: 050=/M/B@/W~/W.collection:dirty", "/W/b: 050=/M/A@/W"]);
}

#[test]
fn across_levels_the_deeper_binding_replaces() {
    let (lines, _) = layers(
        r#"
def Xform "W" (prepend apiSchemas = ["CollectionAPI:dirty"]) {
    rel collection:dirty:includes = [</W/a>, </W/b>]
    rel material:slotBinding:_050:collection:dirt = [</W.collection:dirty>, </M/B>]
    def Mesh "a" {
        rel material:slotBinding:_050 = </M/C>
        def Mesh "x" {}
    }
    def Xform "b" (prepend apiSchemas = ["CollectionAPI:inner"]) {
        rel collection:inner:includes = </W/b/y>
        rel material:slotBinding:_050:collection:inner = [</W/b.collection:inner>, </M/D>]
        def Mesh "y" {}
        def Mesh "z" {}
    }
}
def Xform "V" (prepend apiSchemas = ["CollectionAPI:c"]) {
    rel collection:c:includes = </V/p/q>
    rel material:slotBinding:_050:collection:c = [</V.collection:c>, </M/E>]
    def Xform "p" {
        rel material:slotBinding:_050 = </M/F>
        def Mesh "q" {}
    }
}
"#,
    );
    assert_eq!(
        lines,
        vec![
            // /W/a's direct binding is deeper than /W's collection binding.
            "/W/a: 050=/M/C@/W/a",
            "/W/a/x: 050=/M/C@/W/a",
            // /W/b's own collection binding is deeper than /W's.
            "/W/b/y: 050=/M/D@/W/b~/W/b.collection:inner",
            "/W/b/z: 050=/M/B@/W~/W.collection:dirty",
            // A direct binding on an ancestor below the collection's level wins.
            "/V/p/q: 050=/M/F@/V/p",
        ]
    );
}

#[test]
fn an_empty_collection_binding_removes_until_bound_again() {
    let (lines, _) = layers(
        r#"
def Xform "W" (prepend apiSchemas = ["CollectionAPI:clean"]) {
    rel collection:clean:includes = </W/a>
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_050 = </M/D>
    rel material:slotBinding:_050:collection:clean = </W.collection:clean>
    def Mesh "a" {
        def Mesh "x" {}
        def Mesh "y" { rel material:slotBinding:_050 = </M/E> }
    }
    def Mesh "b" {}
}
"#,
    );
    assert_eq!(
        lines,
        vec![
            "/W/a: 000=/M/A@/W",
            "/W/a/x: 000=/M/A@/W",
            "/W/a/y: 000=/M/A@/W 050=/M/E@/W/a/y",
            "/W/b: 000=/M/A@/W 050=/M/D@/W",
        ]
    );
}

#[test]
fn the_first_collection_binding_in_property_order_wins_and_overrides_and_vertical_slots_bind_too() {
    let (lines, _) = layers(
        r#"
def Xform "W" (prepend apiSchemas = ["CollectionAPI:one", "CollectionAPI:two"]) {
    rel collection:one:includes = </W/a>
    rel collection:two:includes = </W>
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_000:collection:first = [</W.collection:one>, </M/B>]
    rel material:slotBinding:_000:collection:second = [</W.collection:two>, </M/C>]
    rel material:slotBinding:_000:_:_010:collection:o = [</W.collection:one>, </M/O>]
    rel material:slotBinding:_000:vertical:_010:collection:v = [</W.collection:one>, </M/V>]
    def Mesh "a" {}
    def Mesh "b" {}
}
"#,
    );
    assert_eq!(
        lines,
        vec![
            "/W/a: 000=/M/B@/W~/W.collection:one[000::010=/M/O]{000|010=/M/V@/W~/W.collection:one}",
            "/W/b: 000=/M/C@/W~/W.collection:two",
        ]
    );
}

#[test]
fn collection_binding_mistakes_are_located_warnings() {
    let (lines, warnings) = layers(
        r#"
def Xform "W" (prepend apiSchemas = ["CollectionAPI:e"]) {
    rel collection:e:membershipExpression = None
    rel material:slotBinding:_050:collection:gone = [</W.collection:nothere>, </M/A>]
    rel material:slotBinding:_060:collection:none = None
    def Mesh "a" {}
}
"#,
    );
    assert_eq!(lines, vec!["/W/a: "]);
    assert!(warnings.contains("collection `/W.collection:nothere` does not exist"), "{warnings}");
    assert!(warnings.contains("names no collection"), "{warnings}");
}

// ---------------------------------------------------------------- rule 3b: vertical slots

#[test]
fn vertical_slots_decode_sort_by_bytes_and_attach_overrides() {
    let (lines, warnings) = layers(
        r#"
def Mesh "a" {
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_000:vertical:_020 = </M/T>
    rel material:slotBinding:_000:vertical:_010 = </M/C>
    rel material:slotBinding:_000:vertical:_010:_:_030 = </M/Z>
    rel material:slotBinding:_000:vertical:_010:_:_005 = </M/Y>
    rel material:slotBinding:_000:vertical:_9 = </M/N>
    rel material:slotBinding:_000:_:_001 = </M/O>
    rel material:slotBinding:_050 = </M/D>
}
"#,
    );
    assert_eq!(
        lines,
        vec![
            "/a: 000=/M/A@/a[000::001=/M/O]{000|010=/M/C@/a[000|010::005=/M/Y][000|010::030=/M/Z]}{000|020=/M/T@/a}{000|9=/M/N@/a} 050=/M/D@/a"
        ]
    );
    assert!(warnings.is_empty(), "{warnings}");
}

#[test]
fn vertical_slots_are_inherited_replaced_and_removed() {
    let (lines, _) = layers(
        r#"
def Xform "r" {
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_000:vertical:_010 = </M/C>
    def Mesh "inherits" {}
    def Mesh "replaces" { rel material:slotBinding:_000:vertical:_010 = </M/D> }
    def Xform "removes" {
        rel material:slotBinding:_000:vertical:_010 = None
        def Mesh "below" {}
        def Mesh "again" { rel material:slotBinding:_000:vertical:_010 = </M/E> }
    }
}
"#,
    );
    assert_eq!(
        lines,
        vec![
            "/r/inherits: 000=/M/A@/r{000|010=/M/C@/r}",
            "/r/replaces: 000=/M/A@/r{000|010=/M/D@/r/replaces}",
            "/r/removes/below: 000=/M/A@/r",
            "/r/removes/again: 000=/M/A@/r{000|010=/M/E@/r/removes/again}",
        ]
    );
}

#[test]
fn removing_the_base_slot_keeps_its_vertical_slots_for_where_it_is_bound_again() {
    let (lines, warnings) = layers(
        r#"
def Xform "r" {
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_000:vertical:_010 = </M/C>
    rel material:slotBinding:_000:vertical:_010:_:_020 = </M/Z>
    def Xform "bare" {
        rel material:slotBinding:_000 = None
        def Mesh "m" {}
        def Mesh "rebound" { rel material:slotBinding:_000 = </M/B> }
    }
}
"#,
    );
    assert_eq!(
        lines,
        vec!["/r/bare/m: ", "/r/bare/rebound: 000=/M/B@/r/bare/rebound{000|010=/M/C@/r[000|010::020=/M/Z]}"]
    );
    assert!(
        warnings.contains("vertical slot `000|010` on `/r/bare/m` is ignored: slot `000` has no substance there"),
        "{warnings}"
    );
    assert!(warnings.contains("override slot `000|010::020` on `/r/bare/m` is ignored"), "{warnings}");
    assert!(!warnings.contains("/r/bare/rebound"), "{warnings}");
}

#[test]
fn layers_json_nests_vertical_layers_and_names_collections() {
    let (stage, _, mut diags) = open(
        r#"
def Xform "W" (prepend apiSchemas = ["CollectionAPI:c"]) {
    rel collection:c:includes = </W/a>
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_000:vertical:_010:collection:wet = [</W.collection:c>, </M/C>]
    def Mesh "a" { rel material:slotBinding:_000:vertical:_010:_:_020 = </M/Z> }
}
"#,
    );
    let stacks = resolve_stacks(&binding_tree(&stage, &mut diags), &mut diags);
    let json: serde_json::Value = serde_json::from_str(&strata::session::layers_json(&stacks)).unwrap();
    let expected = serde_json::json!([{
        "prim": "/W/a",
        "layers": [{
            "slot": "000", "material": "/M/A", "bound_at": "/W", "overrides": [],
            "vertical": [{
                "slot": "000|010", "material": "/M/C", "bound_at": "/W", "collection": "/W.collection:c",
                "overrides": [{"slot": "000|010::020", "material": "/M/Z", "bound_at": "/W/a"}]
            }]
        }]
    }]);
    assert_eq!(json, expected);
}

// ---------------------------------------------------------------- rule 3b: composed material

/// A stage that binds the paper's listing-1 substances (`tests/fixtures/vertical/materials.usda`
/// defines them as `/L/SubstanceA`..`C`) with `bindings`, composed.
fn composed(bindings: &str) -> (strata::compose::scene::SceneComposition, String, Diagnostics) {
    let text = format!("#usda 1.0\n(\n    subLayers = [@materials.usda@]\n)\n{bindings}");
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let dir = Path::new("tests/fixtures/vertical");
    let stage = Stage::from_text("vertical.usda", &text, dir, &mut sources, &mut diags).expect("stage");
    let scene = compose_stage(&stage, &mut sources, &mut diags);
    (scene, diags.render(&sources), diags)
}

#[test]
fn composed_materials_carry_vertical_layers() {
    let (scene, rendered, diags) = composed(
        r#"
def Mesh "a" {
    rel material:slotBinding:_000 = </L/SubstanceA>
    rel material:slotBinding:_000:vertical:_010 = </L/SubstanceB>
}
def Mesh "b" {
    rel material:slotBinding:_000 = </L/SubstanceA>
    rel material:slotBinding:_000:vertical:_010 = </L/SubstanceC>
}
def Mesh "c" { rel material:slotBinding:_000 = </L/SubstanceA> }
"#,
    );
    assert!(!diags.has_errors(), "{rendered}");
    let a = scene.material_of("/a").unwrap();
    assert_eq!(a.layers.len(), 1);
    assert_eq!(a.layers[0].vertical.len(), 1);
    assert_eq!(a.layers[0].vertical[0].slot.name(), "000|010");
    // The coat makes a different material: three prims, three materials.
    assert_eq!(scene.materials.len(), 3);
    assert!(!rendered.contains("not yet rendered"), "{rendered}");
}

/// Rule 3b through the compiler: a vertical slot lays its substance over the slot below by
/// `layer(top, base)` with its mask as coverage, so a prim with `000` = paint and
/// `000|010` = a half-covering clear coat compiles to the closure a single substance writes
/// by hand as `layer(coat * 0.5, paint)` — term for term, at every shading point — and
/// differs from the prim without the coat.
#[test]
fn a_vertical_slot_compiles_to_the_layer_operator_over_its_base() {
    use strata::abi::{ClosureSum, Globals};
    use strata::session::{SceneSource, Session, SessionOptions};
    let dir = std::env::temp_dir().join(format!("strata-vertical-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("coat.ash"),
        r#"
shader clear(float roughness = 0.2, output closure bsdf) { bsdf = dielectric_bsdf(color(1.0), roughness, 1.5, "R"); }
substance paint { node d = diffuse(albedo: color(0.6, 0.4, 0.2)); surface = d.bsdf; }
substance coat {
    input float cover = 0.5;
    node c = clear();
    node m = mask(opacity: cover);
    surface = c.bsdf;
    mask = m.out;
}
substance by_hand {
    node d = diffuse(albedo: color(0.6, 0.4, 0.2));
    node c = clear();
    node v = vertical_layer(base: d.bsdf, top: c.bsdf, coverage: 0.5);
    surface = v.bsdf;
}
"#,
    )
    .unwrap();
    let material = |name: &str| {
        format!(
            "def Material \"{name}\" {{ def Shader \"S\" {{ uniform token info:implementationSource = \"sourceAsset\"\n\
             uniform asset info:strata:sourceAsset = @coat.ash@\n uniform token info:strata:sourceAsset:subIdentifier = \"{name}\" }} }}\n"
        )
    };
    let scene = format!(
        "#usda 1.0\ndef Scope \"L\" {{\n{}{}{}}}\n\
         def Sphere \"coated\" {{ rel material:slotBinding:_000 = </L/paint>\n rel material:slotBinding:_000:vertical:_010 = </L/coat> }}\n\
         def Sphere \"by_hand\" {{ rel material:slotBinding:_000 = </L/by_hand> }}\n\
         def Sphere \"bare\" {{ rel material:slotBinding:_000 = </L/paint> }}\n",
        material("paint"),
        material("coat"),
        material("by_hand")
    );
    let path = dir.join("vertical.usda");
    std::fs::write(&path, scene).unwrap();
    let mut session = Session::open(SceneSource::File(path), SessionOptions::default());
    let compiled = match session.compile_or_report() {
        Ok(c) => c,
        Err(report) => panic!("{report}"),
    };
    let closure = |prim: &str, g: &Globals| {
        let material = &compiled.materials[compiled.prim_material[prim]];
        let mut out = ClosureSum::default();
        material.surface_sum(g, 0, &mut out).expect("shades");
        out
    };
    for (u, v) in [(0.1, 0.2), (0.5, 0.5), (0.9, 0.3)] {
        let g = Globals { u, v, n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], ..Globals::default() };
        let coated = closure("/coated", &g);
        assert_eq!(coated, closure("/by_hand", &g), "at ({u}, {v})");
        assert_ne!(coated, closure("/bare", &g), "the coat changed nothing");
    }
    let rendered = session.diagnostics().render(session.sources());
    assert!(!rendered.contains("vertical"), "{rendered}");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------- rule 1c: membership expressions

/// The shop stage of the expression tests: `worn` is an expression-based collection;
/// `extra` adds prims under `/Shop`.
fn shop(expression: &str, extra: &str) -> String {
    format!(
        r#"
def Xform "Shop" (prepend apiSchemas = ["CollectionAPI:worn"]) {{
    uniform pathExpression collection:worn:membershipExpression = "{expression}"
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_050:collection:wear = [</Shop.collection:worn>, </M/B>]
    def Xform "Shelf" {{
        rel material:slotBinding:_060 = </M/C>
        def Mesh "Bolt1" {{}}
        def Sphere "Bolt2" {{}}
        def Mesh "Nut" {{}}
    }}
    def Mesh "Crate" {{}}
    {extra}
}}
"#
    )
}

#[test]
fn an_expression_collection_binds_a_slot() {
    // Implied union binds tighter than `&`: the expression is
    // `/Shop//Bolt* & (//{isa:Mesh} + /Shop/Crate)`, which holds Bolt1 alone (Bolt2 is a
    // Sphere; Crate is no Bolt). Slot 050 reaches Bolt1 only; 000 and 060 bind directly.
    let (lines, warnings) = layers(&shop("/Shop//Bolt* & //{isa:Mesh} /Shop/Crate", ""));
    assert_eq!(
        lines,
        vec![
            "/Shop/Shelf/Bolt1: 000=/M/A@/Shop 050=/M/B@/Shop~/Shop.collection:worn 060=/M/C@/Shop/Shelf",
            "/Shop/Shelf/Bolt2: 000=/M/A@/Shop 060=/M/C@/Shop/Shelf",
            "/Shop/Shelf/Nut: 000=/M/A@/Shop 060=/M/C@/Shop/Shelf",
            "/Shop/Crate: 000=/M/A@/Shop",
        ]
    );
    assert_eq!(warnings, "", "nothing to warn about");
}

#[test]
fn an_unevaluated_predicate_is_one_warning_and_matches_nothing() {
    // strata does not know what the studio's `FogVolume` schema derives from: `{isa:Gprim}`
    // cannot be answered for Fog, which is treated as not matching (so its Mesh child is
    // not reached either); every other prim's answer is known.
    let (lines, warnings) = layers(&shop(
        "/Shop/*{isa:Gprim} /Shop/Shelf/Nut /Shop/*{isa:Gprim}/*",
        r#"def FogVolume "Fog" { def Mesh "Wisp" {} }"#,
    ));
    assert_eq!(
        lines,
        vec![
            "/Shop/Shelf/Bolt1: 000=/M/A@/Shop 060=/M/C@/Shop/Shelf",
            "/Shop/Shelf/Bolt2: 000=/M/A@/Shop 060=/M/C@/Shop/Shelf",
            "/Shop/Shelf/Nut: 000=/M/A@/Shop 050=/M/B@/Shop~/Shop.collection:worn 060=/M/C@/Shop/Shelf",
            "/Shop/Crate: 000=/M/A@/Shop 050=/M/B@/Shop~/Shop.collection:worn",
            "/Shop/Fog/Wisp: 000=/M/A@/Shop",
        ]
    );
    assert_eq!(warnings.matches("warning").count(), 1, "{warnings}");
    insta::assert_snapshot!("unevaluated_predicate", warnings);
}

#[test]
fn a_malformed_expression_is_a_located_error() {
    for (name, expression) in
        [("unclosed_class", "/Shop//[Bb]olt* + /Shop/[Cc"), ("dangling_operator", "/Shop//Bolt* &")]
    {
        let (stage, sources, mut diags) = open(&shop(expression, ""));
        let stacks = resolve_stacks(&binding_tree(&stage, &mut diags), &mut diags);
        assert!(diags.has_errors(), "{name}");
        // The collection holds nothing; the direct bindings still resolve.
        assert!(stacks.iter().all(|s| s.layers.iter().all(|l| l.slot.name() != "050")), "{name}");
        insta::assert_snapshot!(format!("malformed_expression_{name}"), diags.render(&sources));
    }
}
