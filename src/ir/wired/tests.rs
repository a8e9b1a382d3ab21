//! Wiring and pruning tests.

use super::*;
use crate::compose::{ComposedLayer, Slot};
use crate::diag::SourceMap;

const SOURCE: &str = r#"
    substance plastic {
        input color base_color = color(0.8, 0.8, 0.8);
        input float roughness = 0.4;
        node unused = noise(scale: 3.0);
        node g = glossy(albedo: base_color, roughness: roughness);
        surface = g.bsdf;
    }
    substance dirt {
        input float amount = 0.5;
        node n = fbm(scale: 4.0);
        node m = mask(opacity: n.out);
        node d = diffuse(albedo: color(0.3, 0.2, 0.1));
        surface = d.bsdf;
        mask = m.out;
    }
    substance opaque {
        node d = diffuse();
        surface = d.bsdf;
    }
    substance sheet {
        node m = mask(opacity: 1.0);
        node d = diffuse();
        surface = d.bsdf;
        mask = m.out;
    }
    override red {
        output color base_color = color(1.0, 0.0, 0.0);
        node aov = customChannelColor(name: "red_marker", value: color(1.0, 1.0, 1.0));
    }
    override rough {
        input float r = 0.9;
        node half = math(a: r, b: 2.0, op: "div");
        output float roughness = half.out;
        output color base_color = color(0.0, 0.0, 1.0);
    }
    override wrong {
        output int roughness = 2;
        output string base_color = "red";
    }
"#;

fn setup() -> (Library, SourceMap) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("test.ash", SOURCE, &mut sources, &mut diags);
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    (lib, sources)
}

fn mref(lib: &Library, name: &str) -> MaterialRef {
    MaterialRef {
        path: format!("/Looks/{name}"),
        graph: lib.graph_by_name(name).unwrap(),
        values: Vec::new(),
        span: Span::default(),
    }
}

fn layer(lib: &Library, slot: &str, name: &str, overrides: &[(&str, &str)]) -> ComposedLayer {
    ComposedLayer {
        slot: Slot::parse(slot).unwrap(),
        substance: mref(lib, name),
        overrides: overrides.iter().map(|(s, n)| (Slot::parse(s).unwrap(), mref(lib, n))).collect(),
        vertical: Vec::new(),
    }
}

#[test]
fn highest_override_wins_and_channels_join() {
    let (lib, _) = setup();
    let material = ComposedMaterial {
        layers: vec![layer(&lib, "000", "plastic", &[("000::010", "red"), ("000::020", "rough")])],
        ..Default::default()
    };
    let mut diags = Diagnostics::new();
    let wired = build(&lib, &material, PassOptions::default(), &mut diags);
    assert!(!diags.has_errors());
    let text = wired.to_text(&lib);
    // 000::020 (rough) beats 000::010 (red) for base_color; roughness folds 0.9 / 2.
    assert!(text.contains("albedo: (0.0, 0.0, 1.0)"), "{text}");
    assert!(text.contains("roughness: 0.45"), "{text}");
    assert!(text.contains("channel red_marker = (1.0, 1.0, 1.0)"), "{text}");
    assert!(!text.contains("unused"), "dead pattern node removed: {text}");
    assert!(!text.contains("math"), "folded node removed: {text}");
}

#[test]
fn incompatible_override_is_an_error() {
    let (lib, _) = setup();
    let material = ComposedMaterial {
        layers: vec![layer(&lib, "000", "plastic", &[("000::010", "wrong")])],
        ..Default::default()
    };
    let mut diags = Diagnostics::new();
    build(&lib, &material, PassOptions::default(), &mut diags);
    assert_eq!(diags.error_count(), 1, "int → float converts; string → color does not");
}

#[test]
fn opaque_layer_hides_lower_layers() {
    let (lib, _) = setup();
    let material = ComposedMaterial {
        layers: vec![
            layer(&lib, "000", "plastic", &[]),
            layer(&lib, "010", "opaque", &[]),
            layer(&lib, "050", "dirt", &[]),
        ],
        ..Default::default()
    };
    let mut diags = Diagnostics::new();
    let wired = build(&lib, &material, PassOptions::default(), &mut diags);
    assert_eq!(wired.stats.layers_pruned, 1);
    assert_eq!(wired.layers[0].pruned, Some(crate::abi::Pruned::HiddenUnder("010".into())));
    assert!(wired.layers[2].surface.is_some());
    let unoptimised = build(&lib, &material, PassOptions { optimize: false, ..Default::default() }, &mut diags);
    assert_eq!(unoptimised.stats.layers_pruned, 0);
    assert!(unoptimised.nodes.len() > wired.nodes.len());
}

/// A literal mask is a constant at every optimisation level (liveness, and with it what
/// is diced and picked, must not depend on the optimiser); unoptimised, nothing else is
/// folded or pruned.
#[test]
fn literal_masks_are_constant_at_every_optimisation_level() {
    let (lib, _) = setup();
    let material = ComposedMaterial {
        layers: vec![
            layer(&lib, "000", "plastic", &[]),
            layer(&lib, "010", "sheet", &[]),
            layer(&lib, "050", "dirt", &[]),
        ],
        ..Default::default()
    };
    let mut diags = Diagnostics::new();
    for optimize in [true, false] {
        let wired = build(&lib, &material, PassOptions { optimize, ..Default::default() }, &mut diags);
        let masks: Vec<Option<f32>> = wired.layers.iter().map(Layer::constant_mask).collect();
        assert_eq!(masks, [Some(1.0), Some(1.0), None], "optimise {optimize}");
        assert_eq!(wired.layers[0].surface.is_none(), optimize, "optimise {optimize}: plastic under the sheet");
    }
}

#[test]
fn validator_rejects_broken_wiring() {
    let (lib, _) = setup();
    let material = ComposedMaterial { layers: vec![layer(&lib, "050", "dirt", &[])], ..Default::default() };
    let mut diags = Diagnostics::new();
    let wired = build(&lib, &material, PassOptions::default(), &mut diags);
    assert_eq!(wired.validate(&lib), Ok(()));
    // A node reading a later node breaks the topological order lowering relies on.
    let mut backwards = wired.clone();
    let last = NodeId(backwards.nodes.len() as u32 - 1);
    let first = &mut backwards.nodes[0];
    let input = lib.function(first.func).inputs().next().unwrap().0;
    first.args[input] = Operand::Node { node: last, param: 0 };
    assert!(backwards.validate(&lib).unwrap_err().contains("not evaluated before it"));
    // A closure where a mask belongs is a type error.
    let mut mistyped = wired.clone();
    mistyped.layers[0].mask = mistyped.layers[0].surface.clone();
    assert!(mistyped.validate(&lib).unwrap_err().contains("closure does not convert to float"));
}

#[test]
fn default_substance_when_no_layers() {
    let (lib, _) = setup();
    let mut diags = Diagnostics::new();
    let wired = build(&lib, &ComposedMaterial::default(), PassOptions::default(), &mut diags);
    let text = wired.to_text(&lib);
    assert!(text.contains("substance default_substance"), "{text}");
    assert!(text.contains("albedo: (1.0, 1.0, 1.0)"), "{text}");
}
