//! Keeps `grammar/ash.ebnf` and the parser in agreement: the grammar's terminals are exactly
//! the lexer's tokens, every rule is defined and used, every `.ash` file in the repository is a
//! sentence the parser accepts, and thousands of random sentences generated from the grammar
//! parse without a syntax error.

use std::collections::{BTreeSet, HashMap};
use strata::diag::{Diagnostics, FileId};
use strata::front::parser::parse;

/// A grammar expression.
#[derive(Debug, Clone)]
enum G {
    Terminal(String),
    Class(String),
    Rule(String),
    Seq(Vec<G>),
    Alt(Vec<G>),
    Opt(Box<G>),
    Many(Box<G>),
}

/// A tiny parser for the EBNF dialect of `grammar/ash.ebnf`.
struct EbnfParser<'a> {
    tokens: Vec<&'a str>,
    pos: usize,
}

fn ebnf_tokens(text: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i];
        if c.is_ascii_whitespace() {
            i += 1;
        } else if text[i..].starts_with("(*") {
            i += text[i..].find("*)").expect("closed comment") + 2;
        } else if c == b'"' {
            let end = i + 1 + text[i + 1..].find('"').expect("closed terminal");
            out.push(&text[i..=end]);
            i = end + 1;
        } else if c.is_ascii_alphabetic() || c == b'_' {
            let start = i;
            while i < bytes.len() && (bytes[i].is_ascii_alphanumeric() || bytes[i] == b'_') {
                i += 1;
            }
            out.push(&text[start..i]);
        } else {
            out.push(&text[i..i + 1]);
            i += 1;
        }
    }
    out
}

impl EbnfParser<'_> {
    fn peek(&self) -> &str {
        self.tokens.get(self.pos).copied().unwrap_or("")
    }
    fn next(&mut self) -> &str {
        self.pos += 1;
        self.tokens[self.pos - 1]
    }
    fn rules(&mut self) -> Vec<(String, G)> {
        let mut rules = Vec::new();
        while self.pos < self.tokens.len() {
            let name = self.next().to_string();
            assert_eq!(self.next(), "=", "rule {name}");
            let body = self.alt();
            assert_eq!(self.next(), ";", "rule {name} ends with ;");
            rules.push((name, body));
        }
        rules
    }
    fn alt(&mut self) -> G {
        let mut alts = vec![self.seq()];
        while self.peek() == "|" {
            self.next();
            alts.push(self.seq());
        }
        if alts.len() == 1 { alts.pop().unwrap() } else { G::Alt(alts) }
    }
    fn seq(&mut self) -> G {
        let mut items = Vec::new();
        loop {
            let t = self.peek().to_string();
            let item = match t.as_str() {
                "(" => {
                    self.next();
                    let g = self.alt();
                    assert_eq!(self.next(), ")");
                    g
                }
                "[" => {
                    self.next();
                    let g = self.alt();
                    assert_eq!(self.next(), "]");
                    G::Opt(Box::new(g))
                }
                "{" => {
                    self.next();
                    let g = self.alt();
                    assert_eq!(self.next(), "}");
                    G::Many(Box::new(g))
                }
                _ if t.starts_with('"') => {
                    self.next();
                    G::Terminal(t.trim_matches('"').to_string())
                }
                _ if t.chars().next().is_some_and(|c| c.is_ascii_uppercase()) => {
                    self.next();
                    G::Class(t)
                }
                _ if t.chars().next().is_some_and(|c| c.is_ascii_lowercase()) => {
                    self.next();
                    G::Rule(t)
                }
                _ => break,
            };
            items.push(item);
        }
        if items.len() == 1 { items.pop().unwrap() } else { G::Seq(items) }
    }
}

fn grammar() -> HashMap<String, G> {
    let text = std::fs::read_to_string("grammar/ash.ebnf").expect("grammar file");
    let mut parser = EbnfParser { tokens: ebnf_tokens(&text), pos: 0 };
    parser.rules().into_iter().collect()
}

fn visit(g: &G, f: &mut dyn FnMut(&G)) {
    f(g);
    match g {
        G::Seq(items) | G::Alt(items) => items.iter().for_each(|i| visit(i, f)),
        G::Opt(inner) | G::Many(inner) => visit(inner, f),
        _ => {}
    }
}

/// Terminals the lexer knows, read from its plain `#[token("…")]` attributes (a token with a
/// callback opens a lexical class, a string or a comment, not a terminal of the grammar).
fn lexer_tokens() -> BTreeSet<String> {
    let source = include_str!("../src/front/lexer.rs");
    source
        .lines()
        .filter_map(|l| l.trim().strip_prefix("#[token(\"").and_then(|r| r.strip_suffix("\")]")))
        .map(str::to_string)
        .collect()
}

#[test]
fn terminals_are_the_lexers_tokens() {
    let rules = grammar();
    let mut terminals = BTreeSet::new();
    let mut classes = BTreeSet::new();
    for body in rules.values() {
        visit(body, &mut |g| match g {
            G::Terminal(t) => {
                terminals.insert(t.clone());
            }
            G::Class(c) => {
                classes.insert(c.clone());
            }
            G::Rule(r) => assert!(rules.contains_key(r), "rule `{r}` is used but not defined"),
            _ => {}
        });
    }
    // Product names are contextual identifiers, not reserved words.
    let contextual: BTreeSet<String> =
        ["surface", "displacement", "mask", "emission"].iter().map(|s| s.to_string()).collect();
    let grammar_tokens: BTreeSet<String> = terminals.difference(&contextual).cloned().collect();
    assert_eq!(grammar_tokens, lexer_tokens(), "grammar terminals vs lexer tokens");
    assert_eq!(classes, ["FLOAT", "IDENT", "INT", "STRING"].iter().map(|s| s.to_string()).collect());
    // Every rule but the start rule is used somewhere.
    let mut used = BTreeSet::new();
    for body in rules.values() {
        visit(body, &mut |g| {
            if let G::Rule(r) = g {
                used.insert(r.clone());
            }
        });
    }
    for name in rules.keys().filter(|n| *n != "module") {
        assert!(used.contains(name), "rule `{name}` is never used");
    }
}

/// A deterministic xorshift generator, so failures reproduce.
struct Rng(u64);
impl Rng {
    fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 % n as u64) as usize
    }
}

/// The least nesting depth at which each rule can produce a sentence.
fn min_depths(rules: &HashMap<String, G>) -> HashMap<String, usize> {
    fn cost(g: &G, depths: &HashMap<String, usize>) -> Option<usize> {
        match g {
            G::Terminal(_) | G::Class(_) => Some(0),
            G::Rule(r) => depths.get(r).map(|d| d + 1),
            G::Seq(items) => items.iter().map(|i| cost(i, depths)).try_fold(0, |m, c| c.map(|c| m.max(c))),
            G::Alt(items) => items.iter().filter_map(|i| cost(i, depths)).min(),
            G::Opt(_) | G::Many(_) => Some(0),
        }
    }
    let mut depths = HashMap::new();
    loop {
        let mut changed = false;
        for (name, body) in rules {
            if let Some(c) = cost(body, &depths)
                && depths.get(name).is_none_or(|&d| c < d)
            {
                depths.insert(name.clone(), c);
                changed = true;
            }
        }
        if !changed {
            return depths;
        }
    }
}

struct Generator<'a> {
    rules: &'a HashMap<String, G>,
    depths: HashMap<String, usize>,
    rng: Rng,
    out: Vec<String>,
}

impl Generator<'_> {
    fn cost(&self, g: &G) -> usize {
        match g {
            G::Terminal(_) | G::Class(_) | G::Opt(_) | G::Many(_) => 0,
            G::Rule(r) => self.depths[r] + 1,
            G::Seq(items) => items.iter().map(|i| self.cost(i)).max().unwrap_or(0),
            G::Alt(items) => items.iter().map(|i| self.cost(i)).min().unwrap_or(0),
        }
    }

    fn emit(&mut self, g: &G, budget: usize) {
        match g {
            G::Terminal(t) => self.out.push(t.clone()),
            G::Class(c) => {
                let names = ["a", "b2", "node_x", "P", "u", "surface_", "value"];
                let text = match c.as_str() {
                    "IDENT" => names[self.rng.below(names.len())].to_string(),
                    "INT" => self.rng.below(1000).to_string(),
                    "FLOAT" => ["1.5", ".25", "3.", "2e3", "1.0e-2"][self.rng.below(5)].to_string(),
                    _ => ["\"s\"", "\"a\\\"b\"", "\"\""][self.rng.below(3)].to_string(),
                };
                self.out.push(text);
            }
            G::Rule(r) => {
                let body = self.rules[r].clone();
                self.emit(&body, budget.saturating_sub(1));
            }
            G::Seq(items) => items.iter().for_each(|i| self.emit(i, budget)),
            G::Alt(items) => {
                let fitting: Vec<&G> = items.iter().filter(|i| self.cost(i) <= budget).collect();
                let choice = if fitting.is_empty() {
                    items.iter().min_by_key(|i| self.cost(i)).unwrap()
                } else {
                    fitting[self.rng.below(fitting.len())]
                };
                self.emit(choice, budget);
            }
            G::Opt(inner) => {
                if budget > 0 && self.rng.below(2) == 0 {
                    self.emit(inner, budget - 1);
                }
            }
            G::Many(inner) => {
                if budget > 0 {
                    for _ in 0..self.rng.below(3) {
                        self.emit(inner, budget - 1);
                    }
                }
            }
        }
    }
}

/// Resolves the grammar's ordered-choice notes in generated text: a statement that starts with
/// `{` is a block, and `type IDENT` declares a variable.
fn ambiguous(tokens: &[String]) -> bool {
    tokens.windows(2).any(|w| w[0] == ";" && w[1] == "{")
}

#[test]
fn generated_sentences_parse() {
    let rules = grammar();
    let depths = min_depths(&rules);
    let mut generator = Generator { rules: &rules, depths, rng: Rng(0x5eed_1234_abcd), out: Vec::new() };
    let mut checked = 0;
    for round in 0..3000 {
        generator.out.clear();
        let budget = 4 + round % 10;
        generator.emit(&G::Rule("module".into()), budget);
        if ambiguous(&generator.out) {
            continue;
        }
        let text = generator.out.join(" ");
        let mut diags = Diagnostics::new();
        parse(FileId(0), &text, &mut diags);
        assert!(!diags.has_errors(), "generated sentence does not parse:\n{text}\n{diags:?}");
        checked += 1;
    }
    assert!(checked > 2000, "only {checked} sentences checked");
}

#[test]
fn repository_ash_files_parse() {
    let mut files =
        vec![std::path::PathBuf::from("src/front/prelude.ash"), std::path::PathBuf::from("src/front/mtlx.ash")];
    for dir in ["scenes/default", "scenes/paper"] {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "ash") {
                files.push(path);
            }
        }
    }
    assert!(files.len() >= 4);
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        let mut diags = Diagnostics::new();
        parse(FileId(0), &text, &mut diags);
        assert!(!diags.has_errors(), "{}: {diags:?}", file.display());
    }
}

/// The three optional parts of `for` (init, condition, step), in every combination: the
/// grammar makes each optional, and the parser, the checker and both backends agree that each
/// combination is the loop it reads as. Without a condition the loop is endless until `break`
/// (it once compiled to no loop at all).
#[test]
fn every_optional_part_of_for() {
    use strata::abi::Globals;
    use strata::backend::{BackendKind, Compiler};
    use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
    use strata::diag::SourceMap;
    use strata::front::library::Library;
    use strata::ir::wired::PassOptions;

    let rules = grammar();
    let G::Alt(statements) = &rules["stmt"] else { panic!("stmt is a choice") };
    let for_rule = statements
        .iter()
        .find_map(|s| match s {
            G::Seq(items) if matches!(items.first(), Some(G::Terminal(t)) if t == "for") => Some(items),
            _ => None,
        })
        .expect("a `for` statement");
    let optional: Vec<String> = for_rule
        .iter()
        .filter_map(|g| match g {
            G::Opt(inner) => match &**inner {
                G::Rule(r) => Some(r.clone()),
                _ => None,
            },
            _ => None,
        })
        .collect();
    assert_eq!(optional, ["simple", "expr", "simple"], "init, condition and step are optional");

    for parts in 0..8 {
        let (init, cond, step) = (parts & 1 != 0, parts & 2 != 0, parts & 4 != 0);
        // Counts to 5 whichever parts the header has; the body does the rest.
        let header = format!(
            "for ({}; {}; {})",
            if init { "i = 0" } else { "" },
            if cond { "i < 5" } else { "" },
            if step { "i += 1" } else { "" }
        );
        let body = format!(
            "{} {} count += 1.0; {}",
            if cond { "" } else { "if (i >= 5) break;" },
            "if (u < -1000.0) continue;",
            if step { "" } else { "i += 1;" }
        );
        let source = format!(
            "shader s(output float o) {{\n    int i = {};\n    float count = 0.0;\n    {header} {{ {body} }}\n    o = count + u * 0.0;\n}}\n\
             substance a {{ node n = s(); node d = displacement(height: n.o); displacement = d.out; }}\n",
            if init { 9 } else { 0 }
        );
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let (lib, _) = Library::from_text("for.ash", &source, &mut sources, &mut diags);
        assert!(!diags.has_errors(), "{header}: {}", diags.render(&sources));
        let material = ComposedMaterial {
            layers: vec![ComposedLayer {
                slot: Slot::parse("000").unwrap(),
                substance: MaterialRef {
                    path: "/A".into(),
                    graph: lib.graph_by_name("a").unwrap(),
                    values: Vec::new(),
                    span: Default::default(),
                },
                overrides: Vec::new(),
                vertical: Vec::new(),
            }],
            ..Default::default()
        };
        for backend in [BackendKind::Jit, BackendKind::Interp] {
            let code = Compiler::new(backend, PassOptions::default()).compile(&lib, &material, &mut diags);
            let code = code.unwrap_or_else(|| panic!("{header}: {}", diags.render(&sources)));
            let mut height = [0.0f32];
            code.displacement(&Globals { u: 0.5, ..Default::default() }, &mut height).expect("runs");
            assert_eq!(height[0], 5.0, "{header} on {backend}:\n{source}");
        }
    }
}
