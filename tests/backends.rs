//! Differential tests: the Cranelift JIT against the reference interpreter, bit for bit, on
//! every built-in node and on random well-typed graphs, over shading points that include NaN,
//! infinities, denormals and huge values; and optimised against unoptimised code (constant
//! folding must never change a result).

use proptest::prelude::*;
use std::sync::Arc;
use strata::abi::{Closure, Globals, MaterialCode, ShaderError};
use strata::backend::{BackendKind, Compiler};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap};
use strata::front::library::Library;
use strata::front::types::Type;
use strata::ir::wired::PassOptions;

/// Compiles substance `name` of `source` with one backend.
fn compile(source: &str, name: &str, backend: BackendKind, optimize: bool) -> Arc<dyn MaterialCode> {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("test.ash", source, &mut sources, &mut diags);
    assert!(!diags.has_errors(), "{}\n{source}", diags.render(&sources));
    let material = single_layer(&lib, name);
    let mut compiler = Compiler::new(backend, PassOptions { optimize, ..Default::default() });
    let code = compiler.compile(&lib, &material, &mut diags);
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    code.expect("compiled")
}

fn single_layer(lib: &Library, name: &str) -> ComposedMaterial {
    ComposedMaterial {
        layers: vec![ComposedLayer {
            slot: Slot::parse("000").unwrap(),
            substance: MaterialRef {
                path: "/Looks/T".into(),
                graph: lib.graph_by_name(name).expect("graph exists"),
                values: Vec::new(),
                span: Default::default(),
            },
            overrides: Vec::new(),
            vertical: Vec::new(),
        }],
        ..Default::default()
    }
}

/// Every output of a material at one point, as bits (NaN payloads included), with statuses.
fn outputs(code: &dyn MaterialCode, g: &Globals) -> Vec<u32> {
    let info = code.info();
    let n = info.layers.len();
    let mut out = Vec::new();
    let status = |r: Result<(), ShaderError>| match r {
        Ok(()) => 0,
        Err(ShaderError::LoopBudget) => 1,
        Err(ShaderError::OutOfBounds) => 2,
    };
    let mut masks = vec![0.0f32; n];
    out.push(status(code.masks(g, &mut masks)));
    out.extend(masks.iter().map(|m| m.to_bits()));
    let mut disp = vec![0.0f32; n];
    out.push(status(code.displacement(g, &mut disp)));
    out.extend(disp.iter().map(|m| m.to_bits()));
    for layer in 0..n {
        match code.mask(g, layer) {
            Ok(m) => out.extend([0, m.to_bits()]),
            Err(e) => out.push(status(Err(e))),
        }
        let mut c = Closure::default();
        out.push(status(code.surface(g, layer, &mut c)));
        out.push(c.kind);
        out.extend(c.params.iter().map(|p| p.to_bits()));
        let mut normal = [0.0f32; 3];
        out.push(status(code.normal(g, layer, &mut normal)));
        out.extend(normal.iter().map(|p| p.to_bits()));
        let mut channels = vec![0.0f32; info.channel_floats];
        out.push(status(code.channels(g, layer, &mut channels)));
        out.extend(channels.iter().map(|p| p.to_bits()));
        let mut emission = [0.0f32; 3];
        out.push(status(code.emission(g, layer, &mut emission)));
        out.extend(emission.iter().map(|p| p.to_bits()));
    }
    out
}

/// Floats worth testing: ordinary values plus the ones that break careless code.
const SPECIAL: [f32; 12] =
    [0.0, -0.0, 1.0, -1.0, 0.5, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e-40, -1e-40, 3.0e38, -7.5e37];

/// Deterministic shading points: a grid of ordinary values, then special values per field.
fn points(count: usize) -> Vec<Globals<'static>> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut pts = Vec::with_capacity(count);
    for i in 0..count {
        let mut f = || {
            let r = next();
            if i % 4 == 3 {
                SPECIAL[(r % SPECIAL.len() as u64) as usize]
            } else {
                ((r >> 40) as f32 / (1u64 << 24) as f32) * 8.0 - 4.0
            }
        };
        let v3 = |f: &mut dyn FnMut() -> f32| [f(), f(), f()];
        pts.push(Globals {
            p: v3(&mut f),
            n: v3(&mut f),
            ng: v3(&mut f),
            i: v3(&mut f),
            dpdu: v3(&mut f),
            dpdv: v3(&mut f),
            u: f(),
            v: f(),
            st_footprint: [f(), f(), f(), f()],
            primvars: Default::default(),
            params: Default::default(),
        });
    }
    pts
}

fn assert_same(a: &dyn MaterialCode, b: &dyn MaterialCode, what: &str, count: usize) {
    assert_eq!(a.info(), b.info());
    for (k, g) in points(count).iter().enumerate() {
        let (x, y) = (outputs(a, g), outputs(b, g));
        assert_eq!(x, y, "{what}: outputs differ at point {k}: {g:?}");
    }
}

/// A node type that turns the shading globals into inputs of every type, so nothing folds.
const SOURCES: &str = r#"
shader spatial_to_color(vector x = vector(0.0, 0.0, 0.0), output color out) {
    out = color(x);
}
shader src(output float x = 0.0, output float y = 0.0, output int i = 0, output color c = 0.0,
           output point p = 0.0, output vector d = 0.0, output normal n = 0.0) {
    x = P[0] * 0.37 + u;
    y = v * 2.0 - P[1];
    i = int(P[2] * 3.0);
    c = color(u, v, P[0]);
    p = P;
    d = I;
    n = N;
}
"#;

/// The port of `src` feeding an input of type `ty`, if any.
fn source_for(ty: Type, k: usize) -> Option<&'static str> {
    Some(match ty {
        t if t == Type::FLOAT => ["s.x", "s.y"][k % 2],
        t if t == Type::INT => "s.i",
        t if t == Type::COLOR => "s.c",
        t if t == Type::POINT => "s.p",
        t if t == Type::VECTOR => "s.d",
        t if t == Type::NORMAL => "s.n",
        _ => return None,
    })
}

#[test]
fn every_builtin_node_agrees() {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("probe.ash", "", &mut sources, &mut diags);
    let mut tested = 0;
    for func in lib.functions.iter().filter(|f| f.builtin && f.kind == strata::front::ast::FunctionKind::Shader) {
        if func.name.starts_with("customChannel") {
            continue;
        }
        // Wire every input from the globals; products or channels read every output.
        let args: Vec<String> =
            func.inputs().filter_map(|(k, p)| source_for(p.ty, k).map(|s| format!("{}: {s}", p.name))).collect();
        let mut body = format!("    node s = src();\n    node n = {}({});\n", func.name, args.join(", "));
        // The first colour output also drives the emission entry.
        if let Some((_, p)) = func.outputs().find(|(_, p)| p.ty == Type::COLOR) {
            body += &format!("    emission = n.{};\n", p.name);
        }
        for (_, p) in func.outputs() {
            body += &match p.ty {
                t if t == Type::CLOSURE => format!("    surface = n.{};\n", p.name),
                t if t == Type::NORMAL => format!("    normal = n.{};\n", p.name),
                t if t == Type::COLOR => {
                    format!("    node c_{0} = customChannelColor(name: \"{0}\", value: n.{0});\n", p.name)
                }
                // Vector and point outputs (`primvar_vector`) reach a colour channel through a shader.
                t if t == Type::VECTOR || t == Type::POINT => format!(
                    "    node v_{0} = spatial_to_color(x: n.{0});\n    node c_{0} = customChannelColor(name: \"{0}\", value: v_{0}.out);\n",
                    p.name
                ),
                _ => format!("    node c_{0} = customChannelFloat(name: \"{0}\", value: n.{0});\n", p.name),
            };
        }
        let source = format!("{SOURCES}\nsubstance t {{\n{body}}}\n");
        let jit = compile(&source, "t", BackendKind::Jit, true);
        let interp = compile(&source, "t", BackendKind::Interp, true);
        assert_same(jit.as_ref(), interp.as_ref(), &func.name, 400);
        tested += 1;
    }
    assert!(tested >= 19, "only {tested} built-in nodes were found");
}

/// Language features the built-in nodes do not reach: loops with break/continue, arrays with
/// computed indices, user functions with early returns, integer corner cases.
const LANGUAGE: &str = r#"
float wave(float x, int n) {
    if (n <= 0) return 0.0;
    float acc = 0.0;
    for (int k = 0; k < n; k++) {
        if (k == 3) continue;
        acc += sin(x * float(k + 1)) / float(k + 1);
        if (acc > 10.0) break;
    }
    return acc;
}

shader lang(float x = 0.0, float y = 0.0, int i = 0, output float out = 0.0, output color col = 0.0) {
    float table[4] = {0.1, 0.2, 0.3, 0.4};
    int j = i % 4;
    if (j < 0) j = -j;
    table[j] = table[j] + x;
    color c = color(x, y, 0.5);
    c[j % 3] = y;
    int q = i / (j - 1);
    int w = 0;
    while (w < 5) { w += 1; }
    out = wave(x, j + 2) + table[(j + 1) % 4] + float(q) + float(w) + (x > y ? pow(abs(x), y) : mod(x, y));
    col = c * clamp(out, -1.0, 1.0) + color(atan2(x, y), fract(x), sign(y));
}

substance t {
    node s = src();
    node l = lang(x: s.x, y: s.y, i: s.i);
    node a = customChannelFloat(name: "out", value: l.out);
    node b = customChannelColor(name: "col", value: l.col);
}
"#;

#[test]
fn language_features_agree() {
    let source = format!("{SOURCES}{LANGUAGE}");
    let jit = compile(&source, "t", BackendKind::Jit, true);
    let interp = compile(&source, "t", BackendKind::Interp, true);
    assert_same(jit.as_ref(), interp.as_ref(), "language", 2000);
}

#[test]
fn runaway_loop_and_bad_index_return_errors() {
    let source = format!(
        "{SOURCES}
shader spin(float x = 0.0, output float out = 0.0) {{ while (1) {{ out += x; }} }}
shader poke(int i = 0, output float out = 0.0) {{ float a[2] = {{1.0, 2.0}}; out = a[i]; }}
substance looping {{ node s = src(); node l = spin(x: s.x); node c = customChannelFloat(name: \"o\", value: l.out); }}
substance indexing {{ node s = src(); node l = poke(i: s.i); node c = customChannelFloat(name: \"o\", value: l.out); }}
"
    );
    let g = Globals { p: [1.0, 0.0, 5.0], ..Globals::default() }; // i = int(5 * 3) = 15: out of bounds
    for backend in [BackendKind::Jit, BackendKind::Interp] {
        let looping = compile(&source, "looping", backend, true);
        let mut out = vec![0.0; looping.info().channel_floats];
        assert_eq!(looping.channels(&g, 0, &mut out), Err(ShaderError::LoopBudget), "{backend}");
        let indexing = compile(&source, "indexing", backend, true);
        assert_eq!(indexing.channels(&g, 0, &mut out), Err(ShaderError::OutOfBounds), "{backend}");
        let inside = Globals { p: [0.0, 0.0, 0.2], ..Globals::default() }; // i = 0
        assert_eq!(indexing.channels(&inside, 0, &mut out), Ok(()), "{backend}");
        assert_eq!(out, vec![1.0]);
    }
}

/// A random well-typed float graph: each node reads earlier nodes, the globals or constants.
fn graph_strategy() -> impl Strategy<Value = String> {
    let op = prop::sample::select(vec![
        "add", "sub", "mul", "div", "min", "max", "pow", "mod", "abs", "invert", "sin", "cos",
    ]);
    let node = (0usize..6, op, any::<u16>(), any::<u16>(), -4.0f32..4.0);
    prop::collection::vec(node, 1..12).prop_map(|nodes| {
        let mut body = String::from("    node s = src();\n");
        for (i, (kind, op, a, b, k)) in nodes.iter().enumerate() {
            let pick = |r: u16| -> String {
                match r as usize % (i + 3) {
                    0 => "s.x".into(),
                    1 => format!("{k:?}"),
                    2 => "s.y".into(),
                    j => format!("n{}.out", j - 3),
                }
            };
            let (a, b) = (pick(*a), pick(*b));
            body += &match kind {
                0 | 1 => format!("    node n{i} = math(a: {a}, b: {b}, op: \"{op}\");\n"),
                2 => format!("    node n{i} = mix_float(a: {a}, b: {b}, t: {k:?});\n"),
                3 => format!("    node n{i} = ramp_float(t: {a}, from: {b});\n"),
                4 => format!("    node n{i} = smoothstep_node(x: {a}, e: {b});\n"),
                _ => format!("    node n{i} = math(a: {a}, b: {k:?}, op: \"{op}\");\n"),
            };
        }
        body += &format!("    node out = customChannelFloat(name: \"o\", value: n{}.out);\n", nodes.len() - 1);
        body
    })
}

const HELPERS: &str = r#"
shader ramp_float(float t = 0.0, float from = 0.0, output float out = 0.0) {
    out = color_to_float_fn(ramp_value(t, from));
}
float ramp_value(float t, float from) { return from < 1.0 ? clamp((t - from) / 2.0, 0.0, 1.0) : floor(t); }
float color_to_float_fn(float x) { return luminance(color(x, x * 0.5, 1.0 - x)); }
shader smoothstep_node(float x = 0.0, float e = 0.0, output float out = 0.0) {
    out = smoothstep(e, e + 1.0, x) + step(e, x) * 0.25;
}
"#;

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, .. ProptestConfig::default() })]

    #[test]
    fn random_graphs_agree(body in graph_strategy()) {
        let source = format!("{SOURCES}{HELPERS}\nsubstance t {{\n{body}}}\n");
        let jit = compile(&source, "t", BackendKind::Jit, true);
        let interp = compile(&source, "t", BackendKind::Interp, true);
        assert_same(jit.as_ref(), interp.as_ref(), &body, 64);
        // Folding must not change a result: unoptimised code computes the same bits.
        let unoptimised = compile(&source, "t", BackendKind::Jit, false);
        assert_same(jit.as_ref(), unoptimised.as_ref(), &body, 64);
    }
}

#[test]
fn texture_lookups_read_the_file_in_both_backends() {
    use strata::render::{Channel, ChannelData, Image, write_exr};
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("two_texels.exr");
    // 2×1: left texel (1, 0, 0.25), right texel (0, 1, 0.75).
    let channel = |name: &str, v: [f32; 2]| Channel { name: name.into(), data: ChannelData::F32(v.to_vec()) };
    let image = Image {
        width: 2,
        height: 1,
        channels: vec![channel("R", [1.0, 0.0]), channel("G", [0.0, 1.0]), channel("B", [0.25, 0.75])],
    };
    write_exr(&image, &file).unwrap();
    let source = format!(
        "substance t {{ node tx = texture(file: {:?}); node c = customChannelColor(name: \"tex\", value: tx.out); }}",
        file.to_str().unwrap()
    );
    let jit = compile(&source, "t", BackendKind::Jit, true);
    let interp = compile(&source, "t", BackendKind::Interp, true);
    assert_same(jit.as_ref(), interp.as_ref(), "texture", 400);
    let mut out = vec![0.0; 3];
    for (u, want) in [(0.25, [1.0, 0.0, 0.25]), (0.75, [0.0, 1.0, 0.75]), (0.5, [0.5, 0.5, 0.5])] {
        let g = Globals { u, v: 0.5, ..Globals::default() };
        jit.channels(&g, 0, &mut out).unwrap();
        assert_eq!(out, want, "bilinear lookup at u = {u}");
    }

    // A file that is not there is a located warning (an error under --strict) and a black
    // texture: a render composes around it, as USD does around a missing asset.
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let missing = source.replace("two_texels.exr", "missing.exr");
    let (lib, _) = Library::from_text("test.ash", &missing, &mut sources, &mut diags);
    let mut compiler = Compiler::new(BackendKind::Jit, PassOptions::default());
    let black = compiler.compile(&lib, &single_layer(&lib, "t"), &mut diags).expect("compiles");
    assert!(!diags.has_errors() && diags.warning_count() == 1, "{}", diags.render(&sources));
    assert!(diags.render(&sources).contains("warning: cannot open texture"), "{}", diags.render(&sources));
    black.channels(&Globals { u: 0.25, v: 0.5, ..Globals::default() }, 0, &mut out).unwrap();
    assert_eq!(out, [0.0; 3]);
}

/// A substance whose float, colour and vector inputs reach a mask, a closure, a noise, a
/// user shader (with float → colour conversions) and a custom channel; the int stays folded.
const LIVE: &str = r#"
shader blend(float a = 0.0, color c = 0.0, vector d = 0.0, output color out) {
    out = c * a + color(d) * sin(a * P[0]);
}
substance live {
    input float rough = 0.3;
    input color tint = color(0.5, 0.4, 0.3);
    input float cover = 0.45;
    input vector dir = vector(0.0, 1.0, 0.5);
    input int octaves = 3;
    node grain = fbm(scale: rough, octaves: octaves);
    node mixed = blend(a: cover, c: tint, d: dir);
    node coat = glossy(albedo: mixed.out, roughness: rough);
    node opacity = mask(opacity: cover);
    node tag = customChannelColor(name: "mixed", value: mixed.out);
    node grit = customChannelFloat(name: "grain", value: grain.out);
    surface = coat.bsdf;
    mask = opacity.out;
}
"#;

/// Live inputs (the view's parameters): JIT and interpreter agree bit for bit on any
/// parameter block — special values, and a block too short (missing words read 0) — and an
/// instance with ordinary values computes exactly what the same values set in the scene and
/// folded as constants compute.
#[test]
fn live_inputs_agree_across_backends_and_with_folded_constants() {
    use strata::abi::ParameterInstance;
    use strata::front::types::Value;
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("live.ash", LIVE, &mut sources, &mut diags);
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    let class = single_layer(&lib, "live");
    let live = PassOptions { live_inputs: true, ..Default::default() };
    let jit = Compiler::new(BackendKind::Jit, live).compile(&lib, &class, &mut diags).expect("jit");
    let interp = Compiler::new(BackendKind::Interp, live).compile(&lib, &class, &mut diags).expect("interp");
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    assert_eq!(class.parameter_block(&lib).len(), 1 + 3 + 1 + 3, "rough, tint, cover, dir; the int folds");

    let mut blocks: Vec<Vec<f32>> = vec![Vec::new(), vec![0.7], class.parameter_block(&lib)];
    for k in 0..SPECIAL.len() {
        blocks.push((0..8).map(|i| SPECIAL[(k + i * 5) % SPECIAL.len()]).collect());
    }
    for block in &blocks {
        let a = ParameterInstance::new(jit.clone(), block.clone());
        let b = ParameterInstance::new(interp.clone(), block.clone());
        assert_same(&a, &b, &format!("block {block:?}"), 64);
    }

    // Ordinary values: the instance against the values folded into a class of its own.
    let values = [
        ("rough", Value::Float(0.62)),
        ("tint", Value::Triple([0.9, 0.2, 0.1])),
        ("cover", Value::Float(0.3)),
        ("dir", Value::Triple([0.25, -1.5, 2.0])),
    ];
    let mut set = class.clone();
    let graph = lib.get(set.layers[0].substance.graph);
    set.layers[0].substance.values =
        values.iter().map(|(name, v)| (graph.input(name).expect("input").0, v.clone())).collect();
    let folded = Compiler::new(BackendKind::Jit, PassOptions::default()).compile(&lib, &set, &mut diags).unwrap();
    let instance = ParameterInstance::new(jit.clone(), set.parameter_block(&lib));
    // Folding knows the mask is the constant 0.3; the instance computes it: the layer info
    // differs only there, every output is the same.
    let ordinary: Vec<Globals> = points(256).into_iter().step_by(4).collect();
    for (k, g) in ordinary.iter().enumerate() {
        assert_eq!(outputs(&instance, g), outputs(folded.as_ref(), g), "point {k}: {g:?}");
    }
}
