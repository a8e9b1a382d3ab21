//! Bad input never panics: random byte mutations of every `.ash` file in the repository and
//! random programs go through parsing, checking, graph resolution and wiring. Pathological
//! programs get the diagnostic, run-time error or defined result that specifies them.

use strata::abi::{Closure, ClosureKind, Globals, ShaderError};
use strata::backend::{BackendKind, Compiler};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap, Span};
use strata::front::ast::GraphKind;
use strata::front::library::Library;
use strata::ir::wired::{self, PassOptions};

struct Rng(u64);
impl Rng {
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

/// Runs the whole front end and wires every substance (with every override) of the text.
fn run_everything(text: &str) {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("fuzz.ash", text, &mut sources, &mut diags);
    let _ = diags.render(&sources);
    let overrides: Vec<MaterialRef> = lib
        .graphs_in(GraphKind::Override)
        .map(|(id, _)| MaterialRef { path: "/o".into(), graph: id, values: vec![], span: Span::default() })
        .collect();
    for (id, _) in lib.graphs_in(GraphKind::Substance) {
        let layer = ComposedLayer {
            slot: Slot::parse("000").unwrap(),
            substance: MaterialRef { path: "/s".into(), graph: id, values: vec![], span: Span::default() },
            overrides: overrides.iter().cloned().map(|o| (Slot::parse("000::001").unwrap(), o)).collect(),
            vertical: Vec::new(),
        };
        let material = ComposedMaterial { layers: vec![layer], ..Default::default() };
        let mut diags = Diagnostics::new();
        let wired = wired::build(&lib, &material, PassOptions::default(), &mut diags);
        let _ = wired.to_text(&lib);
    }
}

#[test]
fn mutated_sources_never_panic() {
    let mut corpus = vec![strata::front::library::PRELUDE.to_string()];
    for dir in ["scenes/default", "scenes/paper", "tests/in/errors", "tests/in/hostile"] {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "ash") {
                corpus.push(std::fs::read_to_string(path).unwrap());
            }
        }
    }
    let alphabet = b"{}();,.=+-*/<>!&|?:\"[]0123456789abcxyz _\n";
    let mut rng = Rng(0xdead_beef_1234);
    for round in 0..400 {
        let source = &corpus[round % corpus.len()];
        let mut bytes = source.as_bytes().to_vec();
        for _ in 0..1 + rng.below(8) {
            if bytes.is_empty() {
                break;
            }
            let at = rng.below(bytes.len());
            match rng.below(3) {
                0 => bytes[at] = alphabet[rng.below(alphabet.len())],
                1 => {
                    bytes.remove(at);
                }
                _ => bytes.insert(at, alphabet[rng.below(alphabet.len())]),
            }
        }
        let text = String::from_utf8_lossy(&bytes);
        run_everything(&text);
    }
}

/// What a pathological program must do.
enum Expect {
    /// The front end reports exactly one error: this message, at this `line:col` of the file.
    Error(&'static str, &'static str),
    /// Compiles without a diagnostic; at the default shading point, substance `a`'s channel
    /// `o` comes out as given (or the entry fails) in both backends, optimised or not; its
    /// surface, when it has one, is a diffuse closure with this albedo.
    Runs(Result<&'static [f32], ShaderError>, Option<[f32; 3]>),
    /// Declares nothing, without a diagnostic.
    Nothing,
}

/// Substance `a` exporting output `o` of the shader `s` defined before it as channel `o`.
macro_rules! channel {
    ($shader:literal) => {
        concat!($shader, r#" substance a { node n = s(); node c = customChannelFloat(name: "o", value: n.o); }"#)
    };
}

#[test]
fn pathological_programs_are_diagnosed() {
    use Expect::*;
    let cases: [(&str, Expect); 15] = [
        // Node bodies are inlined, so recursion is rejected by the checker, before any lowering.
        (
            "float f(float x) { return f(x); } shader s(output float o) { o = f(1.0); } \
             substance a { node n = s(); node d = diffuse(albedo: n.o); surface = d.bsdf; }",
            Error("`f` is recursive", "1:1"),
        ),
        // A runaway loop compiles and stops at its iteration budget at run time.
        (channel!("shader s(output float o) { while (1) { o += 1.0; } }"), Runs(Err(ShaderError::LoopBudget), None)),
        // Indices are checked at run time, even constant ones (folding must not hide them).
        (
            channel!("shader s(output float o) { float a[2] = {1, 2}; o = a[5]; }"),
            Runs(Err(ShaderError::OutOfBounds), None),
        ),
        (
            channel!("shader s(output float o) { float a[2] = {1, 2}; o = a[int(u) - 1]; }"),
            Runs(Err(ShaderError::OutOfBounds), None),
        ),
        (channel!("shader s(output float o) { float a[2] = {1, 2}; o = a[int(u) + 1]; }"), Runs(Ok(&[2.0]), None)),
        // Integer division and remainder by zero are 0 (strata-rt `int_div`, `int_rem`), folded
        // or computed (u = 0 at the default point), never a trap.
        (channel!("shader s(output int o) { o = 7 / 0 * 10 + 7 % 0 + 3; }"), Runs(Ok(&[3.0]), None)),
        (channel!("shader s(output int o) { int z = int(u); o = 7 / z * 10 + 7 % z + 3; }"), Runs(Ok(&[3.0]), None)),
        // An overflowing literal bound to a node input is caught when the graph is resolved…
        (
            "substance a { node d = diffuse(albedo: color(1e39)); surface = d.bsdf; }",
            Error("value is not finite: (inf, inf, inf)", "1:40"),
        ),
        // …inside a shader body it is IEEE +inf, which a custom channel passes on and the diffuse
        // node clamps to a white albedo, so the closure stays finite.
        (
            r#"shader s(output float o) { o = 1e39; } substance a { node n = s();
               node c = customChannelFloat(name: "o", value: n.o); node d = diffuse(albedo: n.o); surface = d.bsdf; }"#,
            Runs(Ok(&[f32::INFINITY]), Some([1.0; 3])),
        ),
        // Empty and truncated files.
        ("", Nothing),
        ("  // just a comment\n", Nothing),
        ("substance", Error("expected an identifier, found end of file", "1:10")),
        ("shader s(output float o) { o = 1.0;", Error("expected `}`, found end of file", "1:36")),
        ("substance a { }\n  /* unterminated", Error("unterminated block comment", "2:3")),
        ("substance a { } \"unterminated", Error("unterminated string literal", "1:17")),
    ];
    for (text, expect) in cases {
        run_everything(text);
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let (lib, _) = Library::from_text("p.ash", text, &mut sources, &mut diags);
        let found: Vec<(String, String)> = diags
            .items()
            .iter()
            .map(|d| (d.message.clone(), d.labels.first().map_or(String::new(), |l| sources.location(l.span))))
            .collect();
        let (want, closure) = match expect {
            Error(message, at) => {
                assert_eq!(found, [(message.to_string(), format!("p.ash:{at}"))], "{text}");
                continue;
            }
            Nothing => {
                assert!(found.is_empty(), "{text}: {found:?}");
                let user = lib.functions.iter().filter(|f| !f.builtin).count();
                assert_eq!((user, lib.graph_by_name("a")), (0, None), "{text}");
                continue;
            }
            Runs(want, closure) => (want, closure),
        };
        assert!(found.is_empty(), "{text}: {found:?}");
        let graph = lib.graph_by_name("a").expect("substance `a`");
        let material = ComposedMaterial {
            layers: vec![ComposedLayer {
                slot: Slot::parse("000").unwrap(),
                substance: MaterialRef { path: "/a".into(), graph, values: vec![], span: Span::default() },
                overrides: vec![],
                vertical: Vec::new(),
            }],
            ..Default::default()
        };
        for backend in [BackendKind::Jit, BackendKind::Interp] {
            for optimize in [true, false] {
                let mut compiler = Compiler::new(backend, PassOptions { optimize, ..Default::default() });
                let code = compiler.compile(&lib, &material, &mut diags).expect("compiles");
                assert!(diags.items().is_empty(), "{text}: {}", diags.render(&sources));
                let g = Globals::default();
                let mut out = vec![0.0; code.info().channel_floats];
                let got = code.channels(&g, 0, &mut out).map(|()| out.as_slice());
                assert_eq!(got, want, "{text} ({backend}, optimize {optimize})");
                let mut c = Closure::default();
                code.surface(&g, 0, &mut c).unwrap();
                let surface = (c.kind != ClosureKind::None as u32).then(|| {
                    assert_eq!(c.kind, ClosureKind::Diffuse as u32, "{text}");
                    [c.params[0], c.params[1], c.params[2]]
                });
                assert_eq!(surface, closure, "{text} ({backend}, optimize {optimize})");
            }
        }
    }
}
