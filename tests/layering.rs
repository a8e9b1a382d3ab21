//! Optimiser invariance of layered materials, as a property: random stacks of 1 to 8 layers
//! (with and without surface, mask, displacement in every mode through `bump` or through the
//! geometry-moving `displacement` node, normal and custom channel; masks absent, 0, 1,
//! constant or varying with exact 0 and 1 regions) compiled with the
//! optimiser on and off, by the JIT and the interpreter, must agree bit for bit on
//! - every entry point the renderer can call on the optimised material (masks of every layer,
//!   surface, normal and channels of layers that can be picked, heights of displacements that
//!   count), and
//! - everything the integrator derives at a shading point ([`shading_state`]): rule-5 pick
//!   weights and transparency, the rule-6 combined displacement, the bumped shading normal,
//!   and each picked layer's closure, shading normal and channels, and
//! - the stochastic pick (rule 5) as the integrator walks it, taking a layer's compile-time
//!   constant mask from its metadata instead of calling the shader: for numbers on a grid and
//!   at the top layer's mask boundary, the optimised material, the unoptimised one and the
//!   unoptimised one with every mask evaluated read the same nonzero masks, bit for bit, and
//!   pick the same layer.
//!
//! JIT and interpreter at the same optimisation level must agree on every entry point of
//! every layer.

mod common;

use proptest::prelude::*;
use std::sync::Arc;
use strata::abi::layering;
use strata::abi::{Closure, Globals, MaterialCode, ShaderError};
use strata::backend::BackendKind;
use strata::diag::{Diagnostics, SourceMap};
use strata::front::library::Library;
use strata::render::integrator::{Invalid, shading_state};

#[derive(Clone, Debug)]
enum Mask {
    Absent,
    Zero,
    One,
    Constant(f32),
    /// Noise scaled so that it saturates: exact 0 and 1 regions with a ramp between.
    Varying(f32),
}

#[derive(Clone, Debug)]
struct LayerSpec {
    /// 0: none, 1: diffuse with a patterned albedo, 2: glossy with a patterned roughness.
    surface: u8,
    mask: Mask,
    /// `(mode, varying height, through the geometry-moving `displacement` node rather than
    /// `bump`)`.
    displacement: Option<(&'static str, bool, bool)>,
    normal: bool,
    channel: bool,
}

fn mask_strategy() -> impl Strategy<Value = Mask> {
    prop_oneof![
        Just(Mask::Absent),
        Just(Mask::Zero),
        Just(Mask::One),
        (0.05f32..0.95).prop_map(Mask::Constant),
        (0.5f32..4.0).prop_map(Mask::Varying),
    ]
}

fn layer_strategy() -> impl Strategy<Value = LayerSpec> {
    let displacement =
        prop::option::of((prop::sample::select(vec!["none", "add", "mix"]), any::<bool>(), any::<bool>())).boxed();
    (0u8..3, mask_strategy(), displacement, any::<bool>(), any::<bool>()).prop_map(
        |(surface, mask, displacement, normal, channel)| LayerSpec { surface, mask, displacement, normal, channel },
    )
}

/// One substance per layer, `l0` … `lN`.
fn source(stack: &[LayerSpec]) -> String {
    let mut text = String::new();
    for (i, layer) in stack.iter().enumerate() {
        let scale = 1.0 + i as f32 * 0.7;
        let mut body = format!("    node pat = noise(scale: {scale:?});\n");
        match layer.surface {
            1 => {
                body += "    node tint = ramp(t: pat.out, start: color(0.1, 0.2, 0.3), end: color(0.9, 0.8, 0.7));\n";
                body += "    node s = diffuse(albedo: tint.out);\n    surface = s.bsdf;\n";
            }
            2 => body += "    node s = glossy(roughness: pat.out);\n    surface = s.bsdf;\n",
            _ => {}
        }
        let opacity = match layer.mask {
            Mask::Absent => None,
            Mask::Zero => Some("0.0".to_string()),
            Mask::One => Some("1.0".to_string()),
            Mask::Constant(c) => Some(format!("{c:?}")),
            Mask::Varying(gain) => {
                body += &format!("    node mg = math(a: pat.out, b: {gain:?}, op: \"mul\");\n");
                body += "    node mo = math(a: mg.out, b: 0.3, op: \"add\");\n";
                Some("mo.out".to_string())
            }
        };
        if let Some(opacity) = opacity {
            body += &format!("    node m = mask(opacity: {opacity});\n    mask = m.out;\n");
        }
        if let Some((mode, varying, moves_geometry)) = layer.displacement {
            let height = if varying { "pat.out".to_string() } else { format!("{:?}", 0.25 * (i + 1) as f32) };
            let node = if moves_geometry { "displacement" } else { "bump" };
            body += &format!("    node b = {node}(height: {height}, scale: 0.2, mode: \"{mode}\");\n");
            body += "    displacement = b.out;\n";
        }
        if layer.normal {
            body += "    node nm = normal_map(map: color(0.6, 0.4, 0.9));\n    normal = nm.out;\n";
        }
        if layer.channel {
            body += "    node c = customChannelFloat(name: \"aov\", value: pat.out);\n";
        }
        text += &format!("substance l{i} {{\n{body}}}\n");
    }
    text
}

fn compile(lib: &Library, n: usize, backend: BackendKind, optimize: bool) -> Arc<dyn MaterialCode> {
    let names: Vec<String> = (0..n).map(|i| format!("l{i}")).collect();
    common::compile_stack(lib, &names, backend, optimize)
}

/// Deterministic shading points with unit normals and tangents that span the surface.
fn points(count: usize, seed: u64) -> Vec<Globals<'static>> {
    let mut state = seed | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    };
    (0..count)
        .map(|_| {
            let p = glam::Vec3::new(next(), next(), next()) * 3.0;
            let n = glam::Vec3::new(next(), next(), next() + 2.5).normalize();
            let t = n.any_orthonormal_vector() * (0.5 + next().abs());
            let b = n.cross(t) * (0.5 + next().abs());
            Globals {
                p: p.to_array(),
                n: n.to_array(),
                ng: n.to_array(),
                i: (-n).to_array(),
                dpdu: t.to_array(),
                dpdv: b.to_array(),
                u: next() * 0.5 + 0.5,
                v: next() * 0.5 + 0.5,
                st_footprint: [0.0; 4],
                primvars: Default::default(),
                params: Default::default(),
            }
        })
        .collect()
}

fn status<T>(r: &Result<T, ShaderError>) -> u32 {
    match r {
        Ok(_) => 0,
        Err(ShaderError::LoopBudget) => 1,
        Err(ShaderError::OutOfBounds) => 2,
    }
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn closure_bits(c: &Closure) -> Vec<u32> {
    std::iter::once(c.kind).chain(c.params.iter().map(|p| p.to_bits())).collect()
}

/// The entry points of `code` at `g` that the renderer may call on a material described by
/// `shape` (the optimised one): every mask, and the rest only where it can be observed.
fn entry_points(code: &dyn MaterialCode, shape: &dyn MaterialCode, g: &Globals) -> Vec<u32> {
    let info = shape.info();
    let n = info.layers.len();
    let mut out = Vec::new();
    for layer in 0..n {
        let m = code.mask(g, layer);
        out.push(status(&m));
        out.push(m.map_or(0, f32::to_bits));
    }
    let mut heights = vec![0.0; n];
    out.push(status(&code.displacement(g, &mut heights)));
    for (layer, l) in info.layers.iter().enumerate() {
        if l.displacement.is_some() {
            out.push(heights[layer].to_bits());
        }
        if !l.has_surface {
            continue;
        }
        let mut c = Closure::default();
        out.push(status(&code.surface(g, layer, &mut c)));
        out.extend(closure_bits(&c));
        let mut normal = [0.0; 3];
        out.push(status(&code.normal(g, layer, &mut normal)));
        out.extend(bits(&normal));
        let mut channels = vec![0.0; info.channel_floats];
        out.push(status(&code.channels(g, layer, &mut channels)));
        out.extend(bits(&channels));
    }
    out
}

/// What the integrator derives at `g`, as bits.
fn integrator_view(code: &dyn MaterialCode, g: &Globals) -> Vec<u32> {
    match shading_state(code, g) {
        Err(Invalid::Shader(e)) => vec![u32::MAX, status::<()>(&Err(e))],
        Err(Invalid::NonFiniteClosure) => vec![u32::MAX, 99],
        Ok(s) => {
            let mut out = bits(&s.weights);
            out.extend(bits(&[s.transparency, s.displacement]));
            out.extend(bits(&s.normal.to_array()));
            for (layer, closure, n, channels) in &s.picked {
                out.push(*layer as u32);
                out.extend(closure_bits(closure));
                out.extend(bits(&n.to_array()));
                out.extend(bits(channels));
            }
            out
        }
    }
}

/// The stochastic pick as the integrator walks it: masks known at compile time come from the
/// layer's metadata (`constant_mask`), the others from the shader; or, with `shortcut` off,
/// every mask from the shader. Per number of `us`: the bits of each nonzero mask the walk
/// read, then the picked layer (`u32::MAX` for transparency, `u32::MAX - 1` for a shader
/// error). The masks are compared too because a constant one bit off changes the pick only
/// for numbers within a bit of a boundary, which a grid rarely hits below the top layer.
fn pick_view(code: &dyn MaterialCode, g: &Globals, us: &[f32], shortcut: bool) -> Vec<u32> {
    let info = code.info();
    let mut out = Vec::new();
    for &u in us {
        let mask_of = |i: usize| {
            let m = match info.layers[i].constant_mask {
                Some(m) if shortcut => Ok(m),
                _ => code.mask(g, i),
            };
            // A mask of 0 leaves the walk's number untouched (the optimiser may drop such a
            // layer from the pick), so only the others are compared.
            if let Ok(m) = m.map(layering::clamp_mask)
                && m != 0.0
            {
                out.push(m.to_bits());
            }
            m
        };
        let picked = match layering::pick(&info.layers, u, mask_of) {
            Ok(Some(i)) => i as u32,
            Ok(None) => u32::MAX,
            Err(_) => u32::MAX - 1,
        };
        out.push(picked);
    }
    out
}

/// Numbers for [`pick_view`]: a grid over [0, 1), and the top picking layer's mask of the
/// unoptimised material at `g` with its neighbours below and above, where a mask that differs
/// in its last bit between the two materials changes the pick.
fn pick_numbers(raw: &dyn MaterialCode, g: &Globals) -> Vec<f32> {
    let mut us: Vec<f32> = (0..64).map(|k| (k as f32 + 0.5) / 64.0).collect();
    if let Some(top) = raw.info().layers.iter().rposition(|l| l.picks())
        && let Ok(m) = raw.mask(g, top)
    {
        let m = layering::clamp_mask(m);
        for u in [m, f32::from_bits(m.to_bits().saturating_sub(1)), f32::from_bits(m.to_bits() + 1)] {
            if (0.0..1.0).contains(&u) {
                us.push(u);
            }
        }
    }
    us
}

fn check_stack(stack: &[LayerSpec], seed: u64) -> Result<(), TestCaseError> {
    let text = source(stack);
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("stack.ash", &text, &mut sources, &mut diags);
    prop_assert!(!diags.has_errors(), "{}\n{text}", diags.render(&sources));
    let n = stack.len();
    let jit_opt = compile(&lib, n, BackendKind::Jit, true);
    let jit_raw = compile(&lib, n, BackendKind::Jit, false);
    let int_opt = compile(&lib, n, BackendKind::Interp, true);
    let int_raw = compile(&lib, n, BackendKind::Interp, false);
    prop_assert_eq!(jit_opt.info(), int_opt.info());
    prop_assert_eq!(jit_raw.info(), int_raw.info());
    let shape = jit_opt.as_ref();
    for (k, g) in points(48, seed).iter().enumerate() {
        // The stochastic pick with constant-mask shortcuts, against every mask evaluated.
        let us = pick_numbers(jit_raw.as_ref(), g);
        let picks = pick_view(jit_raw.as_ref(), g, &us, false);
        for (name, code) in [("jit optimised", &jit_opt), ("interpreter optimised", &int_opt), ("jit", &jit_raw)] {
            prop_assert_eq!(&pick_view(code.as_ref(), g, &us, true), &picks, "{} picks, point {}\n{}", name, k, text);
        }
        let reference = entry_points(jit_raw.as_ref(), shape, g);
        let view = integrator_view(jit_raw.as_ref(), g);
        for (name, code) in
            [("jit optimised", &jit_opt), ("interpreter optimised", &int_opt), ("interpreter", &int_raw)]
        {
            prop_assert_eq!(
                &entry_points(code.as_ref(), shape, g),
                &reference,
                "{} entry points, point {}\n{}",
                name,
                k,
                text
            );
            prop_assert_eq!(
                &integrator_view(code.as_ref(), g),
                &view,
                "{} integrator view, point {}\n{}",
                name,
                k,
                text
            );
        }
        // Same optimisation level: every entry point of every layer.
        for (a, b) in [(&jit_opt, &int_opt), (&jit_raw, &int_raw)] {
            prop_assert_eq!(entry_points(a.as_ref(), a.as_ref(), g), entry_points(b.as_ref(), a.as_ref(), g));
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn optimiser_changes_no_observable_bit(stack in prop::collection::vec(layer_strategy(), 1..=8), seed in any::<u64>()) {
        check_stack(&stack, seed)?;
    }
}

/// The stacks that motivated the property, pinned so they always run: a bump-only layer on
/// top, an add-mode displacement under an opaque layer, a mix-mode displacement under an
/// opaque surface-only layer, a mix layer of mask 1 that replaces what is below; and the same
/// through geometry-moving `displacement`, with literal masks 1, 0 and 0.4 that only the
/// optimiser folds to constants, over a varying mask, for the stochastic pick's shortcuts.
#[test]
fn known_stacks_are_invariant() {
    let base = LayerSpec { surface: 1, mask: Mask::Absent, displacement: None, normal: false, channel: true };
    let stacks = [
        vec![base.clone(), LayerSpec { surface: 0, displacement: Some(("add", true, false)), ..base.clone() }],
        vec![
            LayerSpec { displacement: Some(("add", true, false)), mask: Mask::Varying(2.0), ..base.clone() },
            base.clone(),
        ],
        vec![
            LayerSpec { displacement: Some(("mix", true, false)), mask: Mask::Varying(2.0), ..base.clone() },
            base.clone(),
        ],
        vec![
            LayerSpec { displacement: Some(("none", true, false)), ..base.clone() },
            LayerSpec { surface: 0, mask: Mask::One, displacement: Some(("mix", true, false)), ..base.clone() },
            LayerSpec { surface: 2, mask: Mask::Zero, displacement: Some(("add", true, false)), ..base.clone() },
        ],
        vec![
            LayerSpec { displacement: Some(("none", true, true)), ..base.clone() },
            LayerSpec { mask: Mask::Varying(2.0), displacement: Some(("add", true, true)), ..base.clone() },
            LayerSpec { surface: 0, mask: Mask::One, displacement: Some(("mix", true, true)), ..base.clone() },
        ],
        vec![
            LayerSpec { mask: Mask::Varying(3.0), displacement: Some(("add", false, true)), ..base.clone() },
            LayerSpec {
                surface: 2,
                mask: Mask::Constant(0.4),
                displacement: Some(("mix", true, true)),
                ..base.clone()
            },
            LayerSpec { mask: Mask::Zero, displacement: Some(("add", true, true)), ..base.clone() },
            LayerSpec { mask: Mask::Varying(1.5), ..base.clone() },
        ],
        vec![
            LayerSpec { displacement: Some(("add", true, true)), ..base.clone() },
            LayerSpec { surface: 2, mask: Mask::One, ..base.clone() },
            LayerSpec { mask: Mask::Constant(0.4), ..base.clone() },
        ],
    ];
    for stack in &stacks {
        check_stack(stack, 11).unwrap();
    }
}
