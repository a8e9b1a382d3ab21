//! Composition checked against Pixar's USD library (issue 19, items 6 and 1): variants as USD
//! composes them (selections inside variants to any depth, a set split across arcs, the
//! strength order of selections) and what USD composes around (layers that do not resolve or
//! parse, arcs and bindings to prims that do not exist).
//!
//! `tools/make_variant_fixtures.py` wrote every fixture and, beside each `CASE.usda`, the
//! `CASE.expected` usd-core computed for it: the prims of `Usd.Stage.Traverse()`, some
//! attribute values and UsdShade's bound materials, plus the warnings strata must give. Here
//! strata composes the same files and must agree; no Python runs at test time.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;
use strata::compose::binding::binding_tree;
use strata::compose::slots::resolve_stacks;
use strata::diag::{Diagnostics, Severity, SourceMap};
use strata::scene::{Stage, Value};

/// What usd-core composed for one fixture.
#[derive(Default)]
struct Expected {
    prims: Vec<String>,
    values: Vec<(String, String, String)>,
    bound: Vec<(String, String)>,
    warnings: Vec<String>,
}

fn expected(path: &Path) -> Expected {
    let text = std::fs::read_to_string(path.with_extension("expected")).expect("expected file");
    let mut out = Expected::default();
    for line in text.lines().filter(|l| !l.starts_with('#')) {
        let (what, rest) = line.split_once(' ').expect("`kind rest` lines");
        match what {
            "prim" => out.prims.push(rest.to_string()),
            "value" => {
                let (attr, value) = rest.split_once(' ').expect("`value PATH.ATTR VALUE`");
                let (prim, name) = attr.split_once('.').expect("PATH.ATTR");
                out.values.push((prim.to_string(), name.to_string(), value.to_string()));
            }
            "bound" => {
                let (prim, material) = rest.split_once(' ').expect("`bound PATH MATERIAL`");
                out.bound.push((prim.to_string(), material.to_string()));
            }
            "warning" => out.warnings.push(rest.to_string()),
            other => panic!("unknown line kind `{other}`"),
        }
    }
    out
}

/// The numbers of a value as usd-core prints it (`1.0`, `(0, 0, 1)`); `None` for `None`.
fn usd_numbers(text: &str) -> Option<Vec<f64>> {
    if text == "None" {
        return None;
    }
    Some(
        text.trim_matches(|c| c == '(' || c == ')')
            .split(',')
            .map(|n| n.trim().parse::<f64>().unwrap_or_else(|_| panic!("a number: {text}")))
            .collect(),
    )
}

fn strata_numbers(value: Option<&Value>) -> Option<Vec<f64>> {
    let value = value?;
    value.as_f64().map(|v| vec![v]).or_else(|| value.as_tuple().map(<[f64]>::to_vec))
}

/// Composes `case` with strata and compares it with usd-core's answer; returns the rendered
/// diagnostics.
fn compare(folder: &str, case: &str) -> String {
    let path = PathBuf::from("tests/fixtures").join(folder).join(format!("{case}.usda"));
    let want = expected(&path);
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(&path, &mut sources, &mut diags);
    let rendered = diags.render(&sources);
    let stage = stage.unwrap_or_else(|_| panic!("{case}: strata failed where usd-core composes:\n{rendered}"));
    assert!(!diags.has_errors(), "{case}: errors where USD composes around:\n{rendered}");

    let prims: Vec<&str> = stage.depth_first().map(|(_, p)| p.path.as_str()).collect();
    assert_eq!(prims, want.prims, "{case}: composed prims differ from usd-core's\n{rendered}");
    for (prim, name, value) in &want.values {
        let got = strata_numbers(stage.find(prim).and_then(|id| stage.prim(id).value(name)));
        let want = usd_numbers(value);
        // usd-core prints a `float` widened to double (0.1 → 0.10000000149011612).
        let close = match (&got, &want) {
            (Some(g), Some(w)) => {
                g.len() == w.len() && g.iter().zip(w).all(|(g, w)| (g - w).abs() <= 1e-6 * w.abs().max(1.0))
            }
            (None, None) => true,
            _ => false,
        };
        assert!(close, "{case}: {prim}.{name} is {got:?}, usd-core: {value}");
    }
    if !want.bound.is_empty() {
        let mut binding_diags = Diagnostics::new();
        let tree = binding_tree(&stage, &mut binding_diags);
        let stacks = resolve_stacks(&tree, &mut binding_diags);
        for (prim, material) in &want.bound {
            let stack =
                stacks.iter().find(|s| &s.prim == prim).unwrap_or_else(|| panic!("{case}: no stack for {prim}"));
            // usd-core knows no slots: compare the base layer (`material:binding`), and check
            // that no slot is bound to a prim that does not exist.
            let base = stack.layers.iter().find(|l| l.slot.is_material_binding()).map(|l| l.applied.material.as_str());
            assert_eq!(base.unwrap_or("-"), material, "{case}: material bound to {prim}");
            for layer in &stack.layers {
                assert!(stage.find(&layer.applied.material).is_some(), "{case}: {prim} bound to a missing prim");
            }
        }
        assert!(!binding_diags.has_errors(), "{case}: {}", binding_diags.render(&sources));
        diags.extend(binding_diags);
    }
    let rendered = diags.render(&sources);
    for warning in &want.warnings {
        let found = diags.items().iter().any(|d| {
            d.severity == Severity::Warning
                && (d.message.contains(warning.as_str()) || d.notes.iter().any(|n| n.contains(warning.as_str())))
        });
        assert!(found, "{case}: expected a warning containing `{warning}`:\n{rendered}");
    }
    // Every warning points at the file and line that caused it.
    for d in diags.items() {
        assert!(!d.labels.is_empty(), "{case}: warning without a location: {}", d.message);
    }
    rendered
}

#[test]
fn a_selection_inside_a_variant_applies() {
    compare("variants", "nested2");
}

#[test]
fn selections_three_variants_deep_compose_with_usd_strength() {
    compare("variants", "nested3");
}

#[test]
fn a_variant_set_split_across_two_references_composes_without_false_warnings() {
    let rendered = compare("variants", "split_refs");
    assert!(!rendered.contains("does not exist"), "{rendered}");
}

#[test]
fn a_variant_set_split_between_an_asset_and_the_local_layer_composes() {
    let rendered = compare("variants", "split_local");
    assert!(!rendered.contains("does not exist"), "{rendered}");
}

#[test]
fn selection_strength_follows_livrps() {
    compare("variants", "strength");
}

#[test]
fn variants_reached_through_references_inherits_and_child_prims() {
    compare("variants", "through_arcs");
}

#[test]
fn a_variant_that_no_arc_offers_is_still_reported() {
    compare("variants", "missing");
}

#[test]
fn a_sublayer_that_does_not_resolve_is_composed_around() {
    compare("compose_around", "missing_sublayer");
}

#[test]
fn references_and_payloads_to_missing_files_are_composed_around() {
    compare("compose_around", "missing_reference");
}

#[test]
fn arcs_to_missing_prims_are_composed_around_and_counted_once() {
    let rendered = compare("compose_around", "missing_prim");
    assert_eq!(rendered.matches("that this reference targets does not exist").count(), 1, "{rendered}");
}

#[test]
fn bindings_to_missing_prims_are_unbound_with_a_warning() {
    compare("compose_around", "binding_missing");
}

#[test]
fn a_malformed_referenced_layer_is_composed_around() {
    compare("compose_around", "malformed");
}

#[test]
fn a_malformed_root_layer_stays_an_error() {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(Path::new("tests/fixtures/compose_around/broken.usda"), &mut sources, &mut diags);
    assert!(stage.is_err() && diags.has_errors(), "{}", diags.render(&sources));
    let stage = Stage::open(Path::new("tests/fixtures/mtlx/odd/unclosed.mtlx"), &mut sources, &mut diags);
    let rendered = diags.render(&sources);
    assert!(stage.is_err() && rendered.contains("MaterialX"), "{rendered}");
}

/// `strata check` output on the scenes above: warnings, located, one per kind, exit 0.
fn check_warnings(case: &str) -> String {
    let path = format!("tests/fixtures/compose_around/{case}.usda");
    let (diags, sources, _) = strata::session::check_file(Path::new(&path));
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    diags.render(&sources)
}

macro_rules! warning_snapshots {
    ($($name:ident => $case:literal),* $(,)?) => {
        $(
            #[test]
            fn $name() {
                let text = check_warnings($case);
                assert!(text.contains(concat!("compose_around/", $case, ".usda:")), "located: {text}");
                insta::assert_snapshot!(stringify!($name), text);
            }
        )*
    };
}

warning_snapshots! {
    missing_sublayer_warnings => "missing_sublayer",
    missing_reference_warnings => "missing_reference",
    missing_prim_warnings => "missing_prim",
    binding_missing_warnings => "binding_missing",
    malformed_warnings => "malformed",
}

#[test]
fn render_goes_on_past_what_usd_composes_around() {
    let dir = tempfile::tempdir().expect("temp dir");
    for case in ["missing_reference", "binding_missing", "malformed"] {
        let out = dir.path().join(format!("{case}.exr"));
        let scene = format!("tests/fixtures/compose_around/{case}.usda");
        let args = [
            "render",
            scene.as_str(),
            "-o",
            out.to_str().expect("utf-8"),
            "--res",
            "32x24",
            "--spp",
            "1",
            "--camera",
            "/World/Cam",
        ];
        let output = common::run_strata(&args, Duration::from_secs(300)).expect("render finishes");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(0), "{case}: {stderr}");
        assert!(stderr.contains("warning:"), "{case}: the warning is shown: {stderr}");
        assert!(out.is_file() && out.with_extension("png").is_file(), "{case}: image written");
    }
}
