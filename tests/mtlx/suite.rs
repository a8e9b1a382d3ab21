//! The committed subset of MaterialX's public test suite (`tests/fixtures/mtlx/suite`): each
//! target compiles or says why, and shades with the values its document gives.

use super::*;

/// The wrapper MaterialX's render tests put around a target of `suite/verdicts.txt`: XML to
/// add to the document, and the Material it makes (`None`: the document itself is the target).
pub(crate) fn suite_wrapper(target: &[&str]) -> Option<(String, String)> {
    let material = "<surfacematerial name=\"strata_m\" type=\"material\">";
    match target {
        ["material", name] => Some((String::new(), (*name).to_string())),
        ["shade", graph, output] => Some((
            format!(
                "{material}<input name=\"surfaceshader\" type=\"surfaceshader\" nodegraph=\"{graph}\" output=\"{output}\" /></surfacematerial>"
            ),
            "strata_m".into(),
        )),
        ["emit", graph, output, ty] => {
            let source = match *graph {
                "." => format!("nodename=\"{output}\""),
                _ => format!("nodegraph=\"{graph}\" output=\"{output}\""),
            };
            Some((
                format!(
                    "<convert name=\"strata_c\" type=\"color3\"><input name=\"in\" type=\"{ty}\" {source} /></convert>\
                     <uniform_edf name=\"strata_e\" type=\"EDF\"><input name=\"color\" type=\"color3\" nodename=\"strata_c\" /></uniform_edf>\
                     <surface name=\"strata_s\" type=\"surfaceshader\"><input name=\"edf\" type=\"EDF\" nodename=\"strata_e\" /></surface>\
                     {material}<input name=\"surfaceshader\" type=\"surfaceshader\" nodename=\"strata_s\" /></surfacematerial>"
                ),
                "strata_m".into(),
            ))
        }
        _ => None,
    }
}

/// `/Ball`'s material for one target of `suite/verdicts.txt` (a wrapped copy of the document
/// is written to a temporary directory), and the rendered diagnostics.
pub(crate) fn suite_target(doc: &str, target: &[&str]) -> (Option<Arc<dyn MaterialCode>>, String) {
    let path = Path::new(DIR).join("suite").join(doc);
    let Some((extra, material)) = suite_wrapper(target) else {
        let text = format!("#usda 1.0\n(\n    subLayers = [@{}@]\n)\n", path.canonicalize().unwrap().display());
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("scene.usda", &text, Path::new(DIR), &mut sources, &mut diags).expect("parses");
        let _ = compose_stage(&stage, &mut sources, &mut diags);
        return (None, diags.render(&sources));
    };
    let file = if extra.is_empty() {
        path.canonicalize().unwrap()
    } else {
        let text = std::fs::read_to_string(&path).unwrap().replace("</materialx>", &format!("{extra}\n</materialx>"));
        // One directory per wrapped copy: tests run in parallel and wrap the same document
        // differently (a shared path let one read another's half-written copy).
        static COPIES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let copy = COPIES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("strata_mtlx_suite_{}_{copy}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join(path.file_name().unwrap());
        std::fs::write(&file, text).unwrap();
        file
    };
    compiled(&format!(
        "def Material \"M\" (prepend references = @{}@</MaterialX/Materials/{material}>) {{}}",
        file.display()
    ))
}

#[test]
fn the_public_suite_subset_compiles_or_says_why() {
    // Every target of the committed subset of MaterialX's test suite: no error, none panics,
    // each compiles, and says what verdicts.txt expects (nothing, or a named approximation).
    let verdicts = std::fs::read_to_string(format!("{DIR}/suite/verdicts.txt")).unwrap();
    let mut checked = 0;
    let mut failures = Vec::new();
    for line in verdicts.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()) {
        let (target, says) = line.split_once('|').expect("`target | says`");
        let words: Vec<&str> = target.split_whitespace().collect();
        let (code, rendered) = suite_target(words[0], &words[1..]);
        let erred = rendered.lines().any(|l| l.starts_with("error"));
        let compiles = code.is_some() || words[1] == "layer";
        let says_it = match says.trim() {
            "" => !rendered.contains("warning"),
            says => rendered.contains(says),
        };
        if erred || !compiles || !says_it {
            failures.push(format!("{line}\n{rendered}"));
        }
        checked += 1;
    }
    assert!(failures.is_empty(), "{} of {checked} targets:\n{}", failures.len(), failures.join("\n"));
    assert!(checked >= 40, "{checked} targets");
}

/// The emission of `code` at (u, v).
pub(crate) fn emitted_at(code: &Arc<dyn MaterialCode>, u: f32, v: f32) -> [f32; 3] {
    let mut emitted = [0.0f32; 3];
    let g = Globals { n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], u, v, ..Globals::default() };
    code.emission(&g, 0, &mut emitted).expect("emits");
    emitted
}

#[test]
fn the_public_suite_subset_shades_with_the_values_its_documents_give() {
    // Not silently wrong: the colour each document authors (by hand from the XML) reaches the
    // lobe or the emission, wherever the shader sits (graph, definition, interface).
    let diffuse = |doc: &str, target: &[&str]| {
        let (code, rendered) = suite_target(doc, target);
        let lobes = lobes_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5);
        let base = lobes.iter().find(|t| t.kind == ClosureKind::OrenNayar as u32).expect("a diffuse base").params;
        [base[0], base[1], base[2]]
    };
    // standard_surface's diffuse is base (0.8) · base_color.
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
    let cases: [(&str, &str, [f32; 3]); 7] = [
        ("TestSuite/pbrlib/surfaceshader/surfacematerial_with_graph.mtlx", "M_Blue", [0.3, 0.3, 1.0]),
        ("TestSuite/pbrlib/surfaceshader/surfacematerial_with_graph.mtlx", "M_Magenta", [1.0, 0.0, 1.0]),
        ("TestSuite/pbrlib/surfaceshader/surfacematerial_with_graph.mtlx", "M_Orange", [1.0, 0.3, 0.0]),
        ("TestSuite/stdlib/definition/surfacematerial_definition.mtlx", "mymaterial_instance", [0.264575, 1.0, 0.0]),
        ("TestSuite/stdlib/definition/surfacematerial_definition.mtlx", "NG_mymaterial_instance", [0.264575, 0.0, 1.0]),
        (
            "TestSuite/stdlib/nodegraphs/surfacematerial_nodegraph_to_surfaceshader.mtlx",
            "green_material_graph",
            [0.3, 0.8, 0.1],
        ),
        (
            "TestSuite/stdlib/nodegraphs/surfacematerial_nodegraph_to_surfaceshader.mtlx",
            "red_material_graph2",
            [0.8, 0.1, 0.1],
        ),
    ];
    for (doc, material, color) in cases {
        let want = color.map(|c| 0.8 * c);
        let got = diffuse(doc, &["material", material]);
        assert!(close(got, want), "{material}: {got:?}, want {want:?}");
    }
    // The checkerboard graph's `texcoord` input defaults to the geometric property UV0:
    // floor(8u) + floor(8v) even is colour2 (black), odd colour1 (white).
    let (code, rendered) =
        suite_target("TestSuite/stdlib/defaultgeomprop/defaultgeomprop.mtlx", &["material", "defaultgeomprop"]);
    let code = code.unwrap_or_else(|| panic!("{rendered}"));
    let base =
        |u, v| lobes_at(&code, u, v).iter().find(|t| t.kind == ClosureKind::OrenNayar as u32).map(|t| t.params[0]);
    assert_eq!(base(0.05, 0.05).unwrap_or(0.0), 0.0, "black square");
    assert!((base(0.15, 0.05).unwrap() - 0.8).abs() < 1e-6, "white square");
    assert!((base(0.15, 0.15).unwrap_or(0.0)).abs() < 1e-6, "black again");
    // The document's top-level input drives the unlit surface: emission (0, 0, 1).
    let (code, rendered) =
        suite_target("TestSuite/stdlib/nodegraphs/top_level_input.mtlx", &["material", "surfacematerial"]);
    assert_eq!(emitted_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5), [0.0, 0.0, 1.0]);
    // A graph's colour correction: 0.5 · 0.9 + (0.379147, 0.0341412, 0.0341412).
    let doc = "TestSuite/stdlib/definition/definition_from_nodegraph.mtlx";
    let (code, rendered) = suite_target(doc, &["emit", "test_colorcorrect", "out", "color3"]);
    let got = emitted_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5);
    assert!(close(got, [0.829147, 0.4841412, 0.4841412]), "{got:?}");
    // rgbtohsv then hsvtorgb gives the document's colour back.
    let doc = "TestSuite/stdlib/adjustment/hsvtorgb.mtlx";
    let (code, rendered) =
        suite_target(doc, &["emit", "rgb_to_hsv_to_rgb_color3", "rgb_to_hsv_to_rgb_color3_out", "color3"]);
    let got = emitted_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5);
    assert!(close(got, [0.2, 0.2, 0.8]), "{got:?}");
    // color4/vector4 graphs (their colour channels; the fourth is checked in node_values):
    // the same round trip, luminance (ACEScg luma of (1, 0.75, 0.5)), combine, extract.
    let emit = |doc: &str, graph: &str, output: &str, ty: &str| {
        let (code, rendered) = suite_target(doc, &["emit", graph, output, ty]);
        emitted_at(&code.unwrap_or_else(|| panic!("{graph}: {rendered}")), 0.5, 0.5)
    };
    let got = emit(doc, "rgb_to_hsv_to_rgb_color4", "rgb_to_hsv_to_rgb_color4_out", "color4");
    assert!(close(got, [0.2, 0.2, 0.8]), "{got:?}");
    let luma = 0.2722287 + 0.75 * 0.6740818 + 0.5 * 0.0536895;
    let got = emit("TestSuite/stdlib/adjustment/luminance.mtlx", "luminance_color4", "luminance_color4_out", "color4");
    assert!(close(got, [luma; 3]), "{got:?}");
    for (graph, ty) in [
        ("combine_color4", "color4"),
        ("combine_vector4", "vector4"),
        ("combine_color4CF", "color4"),
        ("combine_vector4VF", "vector4"),
        ("combine_vector4VV", "vector4"),
    ] {
        let got = emit("TestSuite/stdlib/channel/combine.mtlx", graph, "out", ty);
        assert!(close(got, [0.5, 1.0, 0.25]), "{graph}: {got:?}");
    }
    for graph in ["extract_color4", "extract_vector4"] {
        let got = emit("TestSuite/stdlib/channel/extract.mtlx", graph, "out", "float");
        assert!(close(got, [0.25; 3]), "{graph}: {got:?}");
    }
    // ramp4 at the centre: the mean of the four corners the document authors.
    let ramp = "TestSuite/stdlib/texture/ramp.mtlx";
    assert!(close(emit(ramp, ".", "fc_ramp3", "color3"), [0.5, 0.5, 0.25]));
    assert!(close(emit(ramp, ".", "fc_ramp1", "float"), [0.4375; 3]));
    assert!(close(emit(ramp, ".", "fc_ramp4v", "vector4"), [0.5, 0.5, 0.25]));
}

/// Asserts two closure values have the same kinds, layering bits and weights, and parameters
/// within a relative `tolerance` (for values computed through divisions by small numbers).
pub(crate) fn assert_terms_within(got: &ClosureSum, want: &ClosureSum, tolerance: f32) {
    for (k, (g, w)) in got.terms.iter().zip(&want.terms).enumerate() {
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tolerance * y.abs().max(1.0));
        assert!(
            g.kind == w.kind && g.above == w.above && close(&g.weight, &w.weight) && close(&g.params, &w.params),
            "term {k}: got {g:?}\nwant {w:?}"
        );
    }
}
