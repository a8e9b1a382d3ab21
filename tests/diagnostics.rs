//! Rendered diagnostics (syntax, types, graphs, bindings, geometry and lights), compared whole (like naga's `tests/wgsl_errors.rs`): every bad input in
//! `tests/in/errors/` gets messages with file:line:col and the source line, and `strata check`
//! exits non-zero without panicking.

use std::path::Path;
use std::process::Command;
use strata::session::check_file;

fn diagnostics(path: &str) -> String {
    let (diags, sources, _) = check_file(Path::new(path));
    assert!(diags.has_errors(), "{path} must fail");
    diags.render(&sources)
}

macro_rules! error_snapshots {
    ($($name:ident => $path:literal),* $(,)?) => {
        $(
            #[test]
            fn $name() {
                let text = diagnostics($path);
                assert!(text.contains(concat!($path, ":")), "locations name the file: {text}");
                insta::assert_snapshot!(stringify!($name), text);
            }
        )*
    };
}

error_snapshots! {
    ash_syntax => "tests/in/errors/syntax.ash",
    ash_types => "tests/in/errors/types.ash",
    ash_graphs => "tests/in/errors/graphs.ash",
    ash_long_lines => "tests/in/errors/long_lines.ash",
    usda_syntax => "tests/in/errors/syntax.usda",
    usda_bindings => "tests/in/errors/bindings.usda",
    usda_connections => "tests/in/errors/connections.usda",
    usda_geometry => "tests/in/errors/geometry.usda",
    ash_typos => "tests/in/errors/typos.ash",
    ash_displacement => "tests/in/errors/displacement.ash",
    usda_displacement => "tests/in/errors/displacement.usda",
}

fn strata(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().expect("strata runs")
}

#[test]
fn check_exits_non_zero_on_errors_and_zero_when_clean() {
    let bad = strata(&["check", "tests/in/errors/graphs.ash"]);
    assert_eq!(bad.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(stderr.contains("tests/in/errors/graphs.ash:6:25"), "{stderr}");
    assert!(stderr.contains("errors found"), "{stderr}");
    let good = strata(&["check", "scenes/paper/listing1.usda"]);
    assert_eq!(good.status.code(), Some(0), "{}", String::from_utf8_lossy(&good.stderr));
}

#[test]
fn missing_inputs_are_errors_not_panics() {
    for args in [
        &["check", "no/such/file.ash"][..],
        &["check", "no/such/scene.usda"],
        &["layers", "no/such/scene.usda"],
        &["ir", "scenes/paper/listing1.usda", "--prim", "/No/Such/Prim"],
    ] {
        let out = strata(args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains("error"), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
}

#[test]
fn layers_json_contract_on_listing1() {
    let out = strata(&["layers", "scenes/paper/listing1.usda", "--json"]);
    assert_eq!(out.status.code(), Some(0));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("valid JSON");
    let prims = json.as_array().expect("an array of prims");
    assert_eq!(prims.len(), 4);
    let first = &prims[0];
    assert_eq!(first["prim"], "/Root/ObjectA");
    assert_eq!(first["layers"][0]["slot"], "000");
    assert_eq!(first["layers"][0]["material"], "/Materials/SubstanceA");
    assert_eq!(first["layers"][0]["bound_at"], "/Root");
    assert_eq!(first["layers"][0]["overrides"], serde_json::json!([]));
}

/// Everything a production renderer would draw and strata does not is reported, once per
/// kind, naming the first prim: the independent list below is what the fixture authors.
#[test]
fn unsupported_content_is_reported_not_dropped() {
    let path = "tests/in/warnings/unsupported.usda";
    let (diags, sources, _) = check_file(Path::new(path));
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    let text = diags.render(&sources);
    for expected in [
        "`BasisCurves` prims are not supported",
        "skinning `Sphere` prims is not supported",
        "`PortalLight` prims are not supported",
        "prim type `Frobnicator` is not a schema strata knows",
        "API schema `MeshLightAPI` is not supported",
        "light shaping (`inputs:shaping:*` away from its defaults) is not applied",
        "light `inputs:diffuse`",
        "mesh `faceVaryingLinearInterpolation` `cornersPlus1`",
    ] {
        assert_eq!(text.matches(expected).count(), 1, "`{expected}` reported once in:\n{text}");
    }
    assert!(text.contains("1 more prim(s)"), "the second curve is counted, the hidden one is not:\n{text}");
    assert!(!text.contains("HiddenHair"), "{text}");
    // An exporter's ShapingAPI and ShadowAPI at their schema defaults change nothing: no noise.
    assert!(!text.contains("ExportedFill") && !text.contains("ShapingAPI"), "{text}");
    assert!(!text.contains("shadow controls"), "{text}");
    insta::assert_snapshot!("unsupported_content", text);
}

/// A misspelt override output or scene input is a warning (the scene still has a meaning) that
/// names the input that was meant; the same finding in two prims is reported once.
#[test]
fn misspelt_override_output_and_input_suggest_the_name_meant() {
    let path = "tests/in/warnings/typo.usda";
    let (diags, sources, _) = check_file(Path::new(path));
    let text = diags.render(&sources);
    assert!(!diags.has_errors(), "{text}");
    assert_eq!(text.matches("override `tint` output `albedoo` matches no input").count(), 1, "{text}");
    assert_eq!(text.matches("did you mean `albedo`?").count(), 1, "{text}");
    assert_eq!(text.matches("did you mean `roughness`?").count(), 1, "{text}");
    insta::assert_snapshot!("misspelt_names", text);
}
