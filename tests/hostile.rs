//! Hostile input to the front end and the compiler (issue 9): each input gives a located
//! diagnostic or a correct result, quickly, and never a stack overflow, a hang or gigabytes of
//! memory. The tests run on `cargo test` threads (2 MiB stacks) in debug builds, the tightest
//! setting the limits must hold in.
//!
//! The committed inputs in `tests/in/hostile/` are seeds for fuzzing; the large ones (100 000
//! terms, 100 000 levels) are generated here instead of committed.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;
use strata::abi::{Globals, MaterialCode, ShaderError};
use strata::backend::{BackendKind, Compiler, compile_module};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap};
use strata::front::library::Library;
use strata::front::parser::MAX_NESTING;
use strata::ir::lower::{MAX_ENTRY_INSTRUCTIONS, MAX_LOCAL_ARRAY_BYTES};
use strata::ir::wired::PassOptions;

/// Wall-clock bound for one input here: a debug build on a shared, loaded machine. Release
/// builds take a small fraction of this (see the times the tests print).
const SECONDS: f64 = 10.0;

/// What compiling one input gave.
struct Outcome {
    /// Every diagnostic, rendered as `strata check` prints them.
    rendered: String,
    errors: usize,
    /// The material compiled by both backends, when there were no errors.
    code: Option<(Arc<dyn MaterialCode>, Arc<dyn MaterialCode>)>,
    /// Lowered instructions of the material.
    instructions: usize,
    seconds: f64,
}

/// Loads `text` as file `name`, then wires, lowers and compiles substance `substance` (when
/// loading found no error) with the JIT and the interpreter.
fn compile(name: &str, text: &str, substance: &str) -> Outcome {
    let start = Instant::now();
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text(name, text, &mut sources, &mut diags);
    let mut code = None;
    let mut instructions = 0;
    if !diags.has_errors() {
        let graph = lib.graph_by_name(substance).expect("the substance exists");
        let material = ComposedMaterial {
            layers: vec![ComposedLayer {
                slot: Slot::parse("000").unwrap(),
                substance: MaterialRef { path: "/Looks/A".into(), graph, values: Vec::new(), span: Default::default() },
                overrides: Vec::new(),
                vertical: Vec::new(),
            }],
            ..Default::default()
        };
        let module = Compiler::new(BackendKind::Jit, PassOptions::default()).lower(&lib, &material, &mut diags);
        instructions = module.inst_count();
        if !diags.has_errors() {
            let jit = compile_module(module.clone(), BackendKind::Jit).expect("JIT compiles");
            let interp = compile_module(module, BackendKind::Interp).expect("interpreter accepts");
            code = Some((jit, interp));
        }
    }
    let outcome = Outcome {
        rendered: diags.render(&sources),
        errors: diags.error_count(),
        code,
        instructions,
        seconds: start.elapsed().as_secs_f64(),
    };
    eprintln!("{name}: {:.3} s, {} error(s), {instructions} instruction(s)", outcome.seconds, outcome.errors);
    assert!(outcome.seconds < SECONDS, "{name} took {:.1} s", outcome.seconds);
    outcome
}

fn seed(name: &str) -> (String, String) {
    let path = format!("tests/in/hostile/{name}");
    (path.clone(), std::fs::read_to_string(&path).expect("seed file"))
}

/// Shading points with ordinary and awkward `u`, `v` and `P`.
fn points() -> Vec<Globals<'static>> {
    [0.0, 0.3, 0.99, -2.5, 1e-30, 7.0]
        .iter()
        .map(|&u| Globals { p: [u, 1.0 - u, 0.5], n: [0.0, 0.0, 1.0], u, v: 1.0 - u, ..Default::default() })
        .collect()
}

/// The mask and displacement of layer 0, as bits, or the shader error.
fn observe(code: &dyn MaterialCode, g: &Globals) -> (Result<u32, ShaderError>, Result<u32, ShaderError>) {
    let mask = code.mask(g, 0).map(f32::to_bits);
    let mut height = [0.0f32];
    let displacement = code.displacement(g, &mut height).map(|()| height[0].to_bits());
    (mask, displacement)
}

/// Both backends agree bit for bit at every point; returns the JIT's observations.
fn agree(outcome: &Outcome, what: &str) -> Vec<(Result<u32, ShaderError>, Result<u32, ShaderError>)> {
    let (jit, interp) = outcome.code.as_ref().unwrap_or_else(|| panic!("{what} must compile:\n{}", outcome.rendered));
    points()
        .iter()
        .map(|g| {
            let (a, b) = (observe(jit.as_ref(), g), observe(interp.as_ref(), g));
            assert_eq!(a, b, "{what}: JIT and interpreter differ at {g:?}");
            a
        })
        .collect()
}

fn displacement_at(outcome: &Outcome, what: &str, u: f32) -> f32 {
    let (jit, _) = outcome.code.as_ref().unwrap_or_else(|| panic!("{what} must compile:\n{}", outcome.rendered));
    let g = Globals { u, v: 1.0 - u, ..Default::default() };
    let mut height = [0.0f32];
    jit.displacement(&g, &mut height).expect("runs");
    height[0]
}

/// A shader computing `o` with `body`, in a substance `a` whose displacement is `o`.
fn shader(functions: &str, body: &str) -> String {
    format!(
        "{functions}\nshader s(float x = 0.25, output float o) {{\n{body}\n}}\n\
         substance a {{ node n = s(); node d = displacement(height: n.o); displacement = d.out; }}\n"
    )
}

fn assert_nesting_diagnostic(outcome: &Outcome, file: &str, what: &str) {
    assert_eq!(outcome.errors, 1, "{file}: one error, where the limit is crossed:\n{}", outcome.rendered);
    let message = format!("{what} nests deeper than {MAX_NESTING} levels");
    assert!(outcome.rendered.contains(&message), "{file}:\n{}", outcome.rendered);
    assert!(outcome.rendered.contains(&format!("{file}:")), "located: {}", outcome.rendered);
}

// ---- row: ~6.5k nested `(`, ~6.7k nested blocks, ~5.4k nested calls --------------------------

#[test]
fn nested_parentheses_blocks_and_calls_are_located_diagnostics() {
    for (name, what) in
        [("nested_parens.ash", "expression"), ("nested_blocks.ash", "statement"), ("nested_calls.ash", "expression")]
    {
        let (path, text) = seed(name);
        let outcome = compile(&path, &text, "a");
        assert_nesting_diagnostic(&outcome, &path, what);
    }
}

/// Every construct that nests, 100 000 levels deep: one located diagnostic each, in time
/// linear in the input (the parser stops at the limit and skips the rest without recursing).
#[test]
fn every_nesting_construct_is_limited() {
    let n = 100_000;
    let cases = [
        ("parens", "expression", format!("o = {}u{};", "(".repeat(n), ")".repeat(n))),
        ("calls", "expression", format!("o = {}u{};", "sin(".repeat(n), ")".repeat(n))),
        ("casts", "expression", format!("o = {}u{};", "float(".repeat(n), ")".repeat(n))),
        ("negations", "expression", format!("o = {}u;", "- ".repeat(n))),
        ("plus signs", "expression", format!("o = {}u;", "+ ".repeat(n))),
        ("nots", "expression", format!("o = float({}1);", "!".repeat(n))),
        ("indexing", "expression", format!("float a[2] = {{0, 1}}; o = a{};", "[0]".repeat(n))),
        ("members", "expression", format!("color c = color(u); o = c{};", ".r".repeat(n))),
        ("ternaries", "expression", format!("o = {}0.5;", "u > 0.5 ? u : ".repeat(n))),
        ("blocks", "statement", format!("{} o = u; {}", "{".repeat(n), "}".repeat(n))),
        ("ifs", "statement", format!("{} o = u; {}", "if (u > 0.0) ".repeat(n), "")),
        ("else ifs", "statement", format!("if (u < 0.0) o = 0.0; {} o = 1.0;", "else if (u < 1.0) o = u; ".repeat(n))),
        ("whiles", "statement", format!("{} o = u; break; {}", "while (1) {".repeat(n), "}".repeat(n))),
        ("fors", "statement", format!("{} o = u; break; {}", "for (;;) {".repeat(n), "}".repeat(n))),
    ];
    for (what, kind, body) in cases {
        let outcome = compile(&format!("{what}.ash"), &shader("", &body), "a");
        assert_eq!(outcome.errors, 1, "{what}: {}", outcome.rendered);
        // The one counter covers both: `if (c) if (c) …` may cross it in a condition.
        let message = format!("nests deeper than {MAX_NESTING} levels");
        assert!(outcome.rendered.contains(&message), "{what} ({kind}):\n{}", outcome.rendered);
        assert!(outcome.rendered.contains(&format!("{what}.ash:3:")), "located: {}", outcome.rendered);
        assert!(outcome.rendered.len() < 64 << 10, "{what}: {} bytes of diagnostics", outcome.rendered.len());
    }
}

/// Just inside the limit everything compiles and runs: the passes recurse on the compiler's
/// own stack, not on this 2 MiB test thread.
#[test]
fn nesting_just_inside_the_limit_compiles() {
    let n = MAX_NESTING as usize - 8;
    let cases = [
        ("parens", format!("o = {}u{};", "(".repeat(n), ")".repeat(n)), 0.3),
        ("calls", format!("o = {}u{};", "abs(".repeat(n), ")".repeat(n)), 0.3),
        ("blocks", format!("{} o = u; {}", "{".repeat(n), "}".repeat(n)), 0.3),
        ("ifs", format!("o = 1.0; {} o = u; {}", "if (u > 0.0) {".repeat(n), "}".repeat(n)), 0.3),
        // Loops nested this deep also reach Cranelift's loop analysis as deep as they nest.
        ("loops", format!("o = 0.0; {} o += u; {}", "for (int i = 0; i < 1; i++) {".repeat(n), "}".repeat(n)), 0.3),
    ];
    for (what, body, expected) in cases {
        let outcome = compile(&format!("{what}.ash"), &shader("", &body), "a");
        agree(&outcome, what);
        assert_eq!(displacement_at(&outcome, what, 0.3), expected, "{what}");
    }
    // Functions nested that deep, each calling the next from its deepest point: inlining
    // nests them inside one another, past what one function may nest.
    let mut functions = String::new();
    for i in 1..=6 {
        let inner = if i == 1 { "x".to_string() } else { format!("f{}(x)", i - 1) };
        functions += &format!("float f{i}(float x) {{ return {}{inner}{}; }}\n", "abs(".repeat(n), ")".repeat(n));
    }
    for (calls, compiles) in [(3, true), (6, false)] {
        for arg in ["u", "0.3"] {
            let outcome = compile("deep_functions.ash", &shader(&functions, &format!("o = f{calls}({arg});")), "a");
            if compiles {
                agree(&outcome, "deep functions");
                assert_eq!(displacement_at(&outcome, "deep functions", 0.3), 0.3);
            } else {
                assert_eq!(outcome.errors, 1, "{}", outcome.rendered);
                assert!(outcome.rendered.contains("code nests deeper than"), "{}", outcome.rendered);
                assert!(outcome.rendered.contains("→ `f6` → `f5`"), "names the chain: {}", outcome.rendered);
            }
        }
    }
}

// ---- row: ~8.3k chained `x + x`, and flat chains of 100 000 terms --------------------------

#[test]
fn chained_additions_compile() {
    let (path, text) = seed("chained_add.ash");
    let outcome = compile(&path, &text, "a");
    assert_eq!(outcome.errors, 0, "{}", outcome.rendered);
    agree(&outcome, "8 300 additions");
    // Left to right, as written: no reassociation.
    let y = 0.25f32 * 0.5;
    let expected = (1..8300).fold(y, |acc, _| acc + y);
    assert_eq!(displacement_at(&outcome, "8 300 additions", 0.5), expected);
}

/// The value a case should compute at `u`.
type Expected<'a> = Box<dyn Fn(f32) -> f32 + 'a>;

/// Flat chains of 100 000 terms of every operator family parse, check, fold, lower and compile
/// (the trees are 100 000 levels deep; every pass walks their left spine in a loop), and
/// compute what the recursive definition computes, left to right.
#[test]
fn chains_of_100_000_terms_compile() {
    let n = 100_000;
    let y = |u: f32| 0.25f32 * u;
    let sum = |u: f32| (1..n).fold(y(u), |acc, _| acc + y(u));
    let cases: Vec<(&str, String, String, Expected<'_>)> = vec![
        ("sum", String::new(), format!("float y = x * u; o = y{};", " + y".repeat(n - 1)), Box::new(sum)),
        (
            "difference and product",
            String::new(),
            format!("float y = x * u; o = 1.0{};", " - y * 0.5".repeat(n - 1)),
            Box::new(move |u| (1..n).fold(1.0f32, |acc, _| acc - y(u) * 0.5)),
        ),
        (
            "int then float",
            String::new(),
            format!("int i = int(u * 4.0); o = float(i{}) + 0.5{};", " + i".repeat(n / 2), " + x".repeat(n / 2)),
            Box::new(move |u| {
                let i = (u * 4.0) as i32;
                let ints = (0..n / 2).fold(i, |acc, _| acc.wrapping_add(i));
                (0..n / 2).fold(ints as f32 + 0.5, |acc, _| acc + 0.25)
            }),
        ),
        (
            "logic",
            String::new(),
            format!("o = float(u > 2.0{} || u > 0.5);", " || u > 3.0".repeat(n / 2)),
            Box::new(|u| if u > 0.5 { 1.0 } else { 0.0 }),
        ),
        (
            "folded at compile time",
            String::new(),
            format!("o = x{};", " + x".repeat(n - 1)),
            Box::new(move |_| (1..n).fold(0.25f32, |acc, _| acc + 0.25)),
        ),
        (
            "dead",
            String::new(),
            format!("float y = x * u; float unused = y{}; o = y;", " + y".repeat(n - 1)),
            Box::new(y),
        ),
        (
            "compound assignment to a computed element",
            String::new(),
            format!(
                "float a[3] = {{0, 0, 0}}; int i = int(u); a[i - i{} + 1] += x; o = a[1] * u;",
                " + i - i".repeat(n / 2)
            ),
            Box::new(|u| 0.25 * u),
        ),
        (
            "inside a function",
            format!("float f(float y) {{ return y{}; }}", " + y".repeat(n - 1)),
            "o = f(x * u);".to_string(),
            Box::new(sum),
        ),
    ];
    for (what, functions, body, expected) in cases {
        let outcome = compile(&format!("{what}.ash"), &shader(&functions, &body), "a");
        assert_eq!(outcome.errors, 0, "{what}: {}", outcome.rendered);
        agree(&outcome, what);
        for u in [0.3, 0.75] {
            assert_eq!(displacement_at(&outcome, what, u), expected(u), "{what} at u = {u}");
        }
    }
}

// ---- row: 24 functions each calling the previous twice -----------------------------------------

#[test]
fn exponential_inlining_is_a_diagnostic_naming_the_chain() {
    let (path, text) = seed("exponential_inlining.ash");
    assert!(text.len() < 2048, "1.4 KB of source");
    // `u` keeps the calls for run time; a constant argument makes folding try (and give up) first.
    for argument in ["u", "0.5"] {
        let text = text.replace("f24(u)", &format!("f24({argument})"));
        let outcome = compile(&path, &text, "a");
        assert_eq!(outcome.errors, 1, "{}", outcome.rendered);
        let message = "inlining `s` (node `000/n`) → `f24` → `f23` → `f22`";
        assert!(outcome.rendered.contains(message), "{}", outcome.rendered);
        assert!(outcome.rendered.contains(&format!("exceeds {MAX_ENTRY_INSTRUCTIONS} lowered instructions")));
        assert!(outcome.rendered.contains(&format!("{path}:")), "located: {}", outcome.rendered);
    }
    let peak = peak_memory_bytes();
    eprintln!("peak resident memory of the test process: {:?} MiB", peak.map(|b| b >> 20));
    assert!(peak.is_none_or(|b| b < 1 << 30), "peak memory {peak:?}");
}

/// The process's peak resident memory, where the platform reports it.
fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

// ---- row: eight `float a[65536]` -------------------------------------------------------------

#[test]
fn local_arrays_past_the_stack_limit_are_a_diagnostic() {
    // One function's arrays: the checker stops at the declaration that crosses 65 536
    // elements (the second 256 KiB array), before anything is built for them.
    let (path, text) = seed("large_arrays.ash");
    let outcome = compile(&path, &text, "a");
    assert_eq!(outcome.errors, 1, "{}", outcome.rendered);
    assert!(outcome.rendered.contains("arrays hold more than 65536 elements"), "{}", outcome.rendered);
    assert!(outcome.rendered.contains(&format!("{path}:4:5")), "{}", outcome.rendered);
    // Arrays of several functions inlined into one entry: lowering's per-entry limit.
    let inlined = "float f(float x) { float a[40000]; a[1] = x; return a[1]; }
float g(float x) { float b[40000]; b[2] = x; return b[2]; }
shader s(output float o) { o = f(u) + g(v); }
substance a { node n = s(); node d = displacement(height: n.o); displacement = d.out; }
";
    let outcome = compile("inlined_arrays.ash", inlined, "a");
    assert_eq!(outcome.errors, 1, "{}", outcome.rendered);
    let message = format!("more than the {} KiB limit", MAX_LOCAL_ARRAY_BYTES / 1024);
    assert!(outcome.rendered.contains(&message), "{}", outcome.rendered);
}

/// 5 000 declarations of `float a[65536]` in one shader (found by `strata fuzz`) took 10 GB to
/// check: each was a 65 536-element constant in the checked tree. One diagnostic now.
#[test]
fn thousands_of_large_local_arrays_are_one_diagnostic() {
    let body = "float a[65536];\n".repeat(5000);
    let text = format!("shader s(output float o) {{\n{body}o = 1.0;\n}}\n");
    let outcome = compile("many_arrays.ash", &text, "");
    assert!(outcome.rendered.matches("arrays hold more than 65536 elements").count() == 1, "{}", outcome.rendered);
    let peak = peak_memory_bytes();
    assert!(peak.is_none_or(|b| b < 1 << 30), "peak memory {peak:?}");
}

#[test]
fn the_largest_array_compiles_to_code_independent_of_its_length() {
    let (path, text) = seed("large_array.ash");
    let outcome = compile(&path, &text, "a");
    assert_eq!(outcome.errors, 0, "{}", outcome.rendered);
    assert!(outcome.instructions < 200, "{} instructions for a 65 536-element array", outcome.instructions);
    agree(&outcome, "largest array");
    assert_eq!(displacement_at(&outcome, "largest array", 0.5), (4097.0f32 * 3.0) / 65536.0);
    // Array copies and constant initialisers are loops too, for floats and triples.
    let body = "color a[5000]; color b[5000]; a[7] = color(u, 2, 3); b = a; float c[3] = {1, 2, u}; o = b[7].r + b[7].b + c[2];";
    let outcome = compile("array_copy.ash", &shader("", body), "a");
    assert!(outcome.instructions < 300, "{} instructions", outcome.instructions);
    agree(&outcome, "array copy");
    assert_eq!(displacement_at(&outcome, "array copy", 0.5), 0.5 + 3.0 + 0.5);
}

// ---- row: `for (;;)` ---------------------------------------------------------------------------

#[test]
fn for_without_a_condition_loops_until_break_or_the_budget() {
    let (path, text) = seed("for_ever.ash");
    let once = compile(&path, &text, "a");
    for (mask, _) in agree(&once, "for (;;) with break") {
        assert_eq!(mask, Ok(0.75f32.to_bits()));
    }
    let forever = compile(&path, &text, "b");
    for (mask, _) in agree(&forever, "for (;;) without break") {
        assert_eq!(mask, Err(ShaderError::LoopBudget));
    }
    // An array declared in an endless loop is filled on every iteration; the fill spends the
    // budget too, so this ends as quickly (found by `strata fuzz`: it ran for minutes).
    let filling =
        text.replace("        o = u;\n    }\n}\nsubstance a", "        float a[65536]; o = u;\n    }\n}\nsubstance a");
    assert_ne!(filling, text, "the seed changed: update the replacement");
    let filling = compile(&path, &filling, "b");
    for (mask, _) in agree(&filling, "for (;;) filling an array") {
        assert_eq!(mask, Err(ShaderError::LoopBudget));
    }
}

// ---- row: a user `substance default_substance` -----------------------------------------------

#[test]
fn prelude_names_are_reserved() {
    let (path, text) = seed("default_substance.ash");
    let outcome = compile(&path, &text, "plastic");
    assert_eq!(outcome.errors, 1, "{}", outcome.rendered);
    assert!(outcome.rendered.contains("`default_substance` is a built-in graph"), "{}", outcome.rendered);
    assert!(outcome.rendered.contains(&format!("{path}:3:11")), "{}", outcome.rendered);

    // The scene with an unbound prim (shaded by the built-in default_substance) that panicked.
    let (diags, sources, _) = strata::session::check_file(Path::new("tests/in/hostile/default_substance.usda"));
    let rendered = diags.render(&sources);
    assert!(rendered.contains("`default_substance` is a built-in graph"), "{rendered}");

    // Node types and functions of the prelude, and built-in function names.
    for (source, message) in [
        ("shader diffuse(output closure bsdf) {}", "`diffuse` is a built-in shader"),
        ("float noise(point p) { return 0.0; }", "`noise` is a built-in function"),
        ("float mix(float a, float b, float t) { return a; }", "`mix` is a built-in function"),
        ("override default_substance { output float x = 1.0; }", "`default_substance` is a built-in graph"),
    ] {
        let outcome = compile("names.ash", source, "a");
        assert_eq!(outcome.errors, 1, "{source}: {}", outcome.rendered);
        assert!(outcome.rendered.contains(message), "{source}: {}", outcome.rendered);
        assert!(outcome.rendered.contains("names.ash:1:"), "{source}: {}", outcome.rendered);
    }
    // Functions and node types are separate namespaces: a function may share a node type's name.
    let outcome = compile("names.ash", &shader("float checker(float x) { return x; }", "o = checker(u);"), "a");
    assert_eq!(outcome.errors, 0, "{}", outcome.rendered);
}

// ---- row: a 16 KB line of `}` ----------------------------------------------------------------

#[test]
fn diagnostics_are_capped_per_file_and_in_width() {
    let (path, text) = seed("closing_braces.ash");
    let outcome = compile(&path, &text, "a");
    assert_eq!(outcome.errors, 16384);
    assert!(outcome.rendered.len() < 32 << 10, "{} bytes of diagnostics", outcome.rendered.len());
    assert!(outcome.rendered.contains("note: 16334 more errors in tests/in/hostile/closing_braces.ash not shown"));
    assert!(outcome.rendered.lines().all(|l| l.chars().count() < 200), "excerpts are cut");
    assert!(outcome.rendered.contains(&format!("{path}:1:50")), "columns stay those of the file");
}

/// Every seed file has a test, here or in `tests/hostile_io.rs` or `tests/hostile_struct.rs`
/// (a fuzzing harness takes the directory as its corpus).
#[test]
fn every_seed_is_tested() {
    let tests = [include_str!("hostile.rs"), include_str!("hostile_io.rs"), include_str!("hostile_struct.rs")];
    let mut untested = Vec::new();
    for entry in std::fs::read_dir("tests/in/hostile").unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        if !tests.iter().any(|t| t.contains(name.as_str())) {
            untested.push(name);
        }
    }
    assert!(untested.is_empty(), "seed files no test names: {untested:?}");
}

/// Arrays of closures have no layout (a kind word and eight floats in one typed slot): the
/// checker rejects them, where lowering used to emit invalid code.
#[test]
fn closure_arrays_are_rejected_other_arrays_work() {
    let outcome = compile("closures.ash", &shader("", "closure c[20]; c[1] = diffuse_bsdf(color(u)); o = u;"), "a");
    assert_eq!(outcome.errors, 1, "{}", outcome.rendered);
    assert!(outcome.rendered.contains("arrays of closures are not supported"), "{}", outcome.rendered);
    assert!(outcome.rendered.contains("closures.ash:3:1"), "{}", outcome.rendered);
    let body = "string s[20]; s[2] = \"x\"; int k[40]; k[3] = 2; o = float(k[3]) * u + float(s[2] == \"x\");";
    let outcome = compile("arrays.ash", &shader("", body), "a");
    agree(&outcome, "int and string arrays");
    assert_eq!(displacement_at(&outcome, "int and string arrays", 0.5), 2.0);
}
