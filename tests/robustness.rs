//! Bad input never panics: random byte mutations of every `.ash` file in the repository and
//! random programs go through parsing, checking, graph resolution and wiring.

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
        };
        let material = ComposedMaterial { layers: vec![layer] };
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

#[test]
fn pathological_programs_are_diagnosed() {
    for text in [
        "float f(float x) { return f(x); } shader s(output float o) { o = f(1.0); } substance a { node n = s(); node d = diffuse(albedo: n.o); surface = d.bsdf; }",
        "shader s(output float o) { while (1) { o += 1.0; } } substance a { node n = s(); node m = mask(opacity: n.o); mask = m.out; }",
        "shader s(output float o) { float a[2] = {1, 2}; o = a[5]; } substance a { node n = s(); node m = mask(opacity: n.o); mask = m.out; }",
        "shader s(output int o) { o = 7 / 0 + 7 % 0; } substance a { node n = s(); node m = mask(opacity: n.o); mask = m.out; }",
        "substance a { node d = diffuse(albedo: color(1e39)); surface = d.bsdf; }",
        "",
        "substance",
        "/* unterminated",
        "\"unterminated",
    ] {
        run_everything(text);
    }
}
