//! Loading substance files: the built-in prelude, user files and their imports, checked
//! together into one [`Library`] of node types, functions and graphs.

use super::ast::{self, FunctionKind, GraphKind, Item};
use super::check::{Callee, check_function, resolve_type};
use super::graph::{Graph, resolve_graph};
use super::hir::{ExprKind, FuncId, Function, Stmt};
use super::parser::parse;
use crate::diag::{Diagnostic, Diagnostics, FileId, SourceMap, Span};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

/// The source of the built-in node library.
pub const PRELUDE: &str = include_str!("prelude.ash");

/// Index of a graph in a [`Library`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct GraphId(pub u32);

/// Everything loaded from substance files.
#[derive(Debug, Default)]
pub struct Library {
    /// Node types and functions, built-ins first.
    pub functions: Vec<Function>,
    /// Substances and overrides.
    pub graphs: Vec<Graph>,
    /// Node types by name.
    pub shaders: HashMap<String, FuncId>,
    /// Graphs by (canonical file path, name).
    graph_index: HashMap<(PathBuf, String), GraphId>,
    /// The file each graph was declared in.
    pub graph_files: Vec<PathBuf>,
    /// Files that could not be read (already reported).
    unreadable: HashSet<PathBuf>,
}

impl Library {
    /// Loads the prelude, `files` and everything they import. Problems are reported to `diags`;
    /// the library holds whatever checked cleanly.
    pub fn load(files: &[(PathBuf, Span)], sources: &mut SourceMap, diags: &mut Diagnostics) -> Library {
        let mut modules: Vec<(Option<PathBuf>, ast::Module)> = Vec::new();
        let prelude = sources.add("<builtins>", PRELUDE);
        modules.push((None, parse(prelude, PRELUDE, diags)));
        let mut seen = HashSet::new();
        let mut unreadable = HashSet::new();
        let mut queue: Vec<(PathBuf, Option<Span>)> = files.iter().map(|(p, s)| (p.clone(), Some(*s))).collect();
        queue.reverse();
        while let Some((path, from)) = queue.pop() {
            let canonical = path.canonicalize().unwrap_or_else(|_| path.clone());
            if !seen.insert(canonical.clone()) {
                continue;
            }
            let read = match crate::scenes::embedded(&path) {
                Some(text) => Ok(text.to_string()),
                None => crate::input::read_text(&path),
            };
            let text = match read {
                Ok(text) => text,
                Err(err) => {
                    let message = format!("cannot read substance file `{}`: {err}", path.display());
                    let d = Diagnostic::error(message);
                    diags.push(match from {
                        Some(span) if span != Span::default() => d.at(span, "referenced here"),
                        _ => d,
                    });
                    unreadable.insert(path);
                    continue;
                }
            };
            let file = sources.add(path.display().to_string(), text.clone());
            let module = parse(file, &text, diags);
            let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
            for item in &module.items {
                if let Item::Import { path: import, span } = item {
                    queue.push((dir.join(import), Some(*span)));
                }
            }
            modules.push((Some(canonical), module));
        }
        let mut lib = Library::check(modules, diags);
        lib.unreadable = unreadable;
        lib
    }

    /// Whether `file` was named but could not be read.
    pub fn failed_to_load(&self, file: &Path) -> bool {
        self.unreadable.contains(file)
    }

    /// Loads only the prelude and one in-memory file (tests, embedded scenes).
    pub fn from_text(name: &str, text: &str, sources: &mut SourceMap, diags: &mut Diagnostics) -> (Library, FileId) {
        let prelude = sources.add("<builtins>", PRELUDE);
        let prelude_module = parse(prelude, PRELUDE, diags);
        let file = sources.add(name, text);
        let module = parse(file, text, diags);
        let lib = Library::check(vec![(None, prelude_module), (Some(PathBuf::from(name)), module)], diags);
        (lib, file)
    }

    fn check(modules: Vec<(Option<PathBuf>, ast::Module)>, diags: &mut Diagnostics) -> Library {
        let mut lib = Library::default();
        // Declare every function and shader first so bodies may call forward.
        let mut decls: Vec<(&ast::FunctionDecl, bool)> = Vec::new();
        let mut callees: HashMap<String, Callee> = HashMap::new();
        let mut first_span: HashMap<(FunctionKind, String), Span> = HashMap::new();
        for (path, module) in &modules {
            for item in &module.items {
                let Item::Function(f) = item else { continue };
                let key = (f.kind, f.name.name.clone());
                if let Some(first) = first_span.get(&key) {
                    let what = if f.kind == FunctionKind::Shader { "shader" } else { "function" };
                    diags.push(
                        Diagnostic::error(format!("{what} `{}` is defined twice", f.name.name))
                            .at(f.name.span, "defined again")
                            .also(*first, "first defined here"),
                    );
                    continue;
                }
                first_span.insert(key, f.name.span);
                let id = FuncId(decls.len() as u32);
                decls.push((f, path.is_none()));
                if f.kind == FunctionKind::Shader {
                    lib.shaders.insert(f.name.name.clone(), id);
                }
                // Functions take precedence over shaders of the same name when calling.
                if f.kind == FunctionKind::Function || !callees.contains_key(&f.name.name) {
                    callees.insert(
                        f.name.name.clone(),
                        Callee {
                            id,
                            kind: f.kind,
                            params: f.params.iter().map(|p| resolve_type(&p.ty)).collect(),
                            ret: resolve_type(&f.ret),
                        },
                    );
                }
            }
        }
        for (decl, builtin) in &decls {
            lib.functions.push(check_function(decl, &callees, *builtin, diags));
        }
        lib.check_recursion(diags);
        lib.compute_varying();

        for (path, module) in &modules {
            for item in &module.items {
                let Item::Graph(g) = item else { continue };
                let graph = resolve_graph(g, &lib.shaders, &lib.functions, diags);
                let file = path.clone().unwrap_or_default();
                let key = (file.clone(), graph.name.clone());
                if let Some(first) = lib.graph_index.get(&key) {
                    let first_span = lib.graphs[first.0 as usize].span;
                    diags.push(
                        Diagnostic::error(format!("`{}` is declared twice in this file", graph.name))
                            .at(g.name.span, "declared again")
                            .also(first_span, "first declared here"),
                    );
                    continue;
                }
                lib.graph_index.insert(key, GraphId(lib.graphs.len() as u32));
                lib.graphs.push(graph);
                lib.graph_files.push(file);
            }
        }
        lib
    }

    /// Finds a graph by file and name. `file` may be relative; it is canonicalised.
    pub fn graph(&self, file: &Path, name: &str) -> Option<GraphId> {
        let canonical = file.canonicalize().unwrap_or_else(|_| file.to_path_buf());
        self.graph_index.get(&(canonical, name.to_string())).copied()
    }

    /// Finds a graph by name alone (only when it is unique).
    pub fn graph_by_name(&self, name: &str) -> Option<GraphId> {
        let mut found = self.graphs.iter().enumerate().filter(|(_, g)| g.name == name);
        let first = found.next()?;
        found.next().is_none().then_some(GraphId(first.0 as u32))
    }

    /// The graph with this id.
    pub fn get(&self, id: GraphId) -> &Graph {
        &self.graphs[id.0 as usize]
    }

    /// Names of the graphs declared in a file, of a kind.
    pub fn graphs_in(&self, kind: GraphKind) -> impl Iterator<Item = (GraphId, &Graph)> {
        self.graphs.iter().enumerate().filter(move |(_, g)| g.kind == kind).map(|(i, g)| (GraphId(i as u32), g))
    }

    /// The function with this id.
    pub fn function(&self, id: FuncId) -> &Function {
        &self.functions[id.0 as usize]
    }

    /// Reports recursion: node bodies are inlined, so the call graph must be acyclic.
    fn check_recursion(&self, diags: &mut Diagnostics) {
        let calls: Vec<Vec<FuncId>> = self.functions.iter().map(callees_of).collect();
        let mut state = vec![0u8; self.functions.len()]; // 0 new, 1 active, 2 done
        fn visit(f: usize, calls: &[Vec<FuncId>], state: &mut [u8], lib: &Library, diags: &mut Diagnostics) {
            state[f] = 1;
            for callee in &calls[f] {
                let c = callee.0 as usize;
                if state[c] == 1 {
                    let func = &lib.functions[c];
                    diags.push(
                        Diagnostic::error(format!("`{}` is recursive", func.name))
                            .at(func.span, "calls itself, directly or indirectly")
                            .note("functions are inlined into shaders; use a loop instead"),
                    );
                } else if state[c] == 0 {
                    visit(c, calls, state, lib, diags);
                }
            }
            state[f] = 2;
        }
        for f in 0..self.functions.len() {
            if state[f] == 0 {
                visit(f, &calls, &mut state, self, diags);
            }
        }
    }

    /// Marks functions that read globals or varying intrinsics, directly or through callees.
    fn compute_varying(&mut self) {
        let direct: Vec<bool> = self.functions.iter().map(reads_varying).collect();
        let calls: Vec<Vec<FuncId>> = self.functions.iter().map(callees_of).collect();
        let mut varying = direct;
        // Fixed point over the (acyclic or already-reported) call graph.
        loop {
            let mut changed = false;
            for f in 0..varying.len() {
                if !varying[f] && calls[f].iter().any(|c| varying[c.0 as usize]) {
                    varying[f] = true;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        for (f, v) in self.functions.iter_mut().zip(varying) {
            f.varying = v;
        }
    }
}

/// Visits every expression of a function: parameter defaults and the body.
pub fn visit_exprs(func: &Function, visit: &mut dyn FnMut(&super::hir::Expr)) {
    fn expr(e: &super::hir::Expr, visit: &mut dyn FnMut(&super::hir::Expr)) {
        visit(e);
        match &e.kind {
            ExprKind::Const(_) | ExprKind::Local(_) | ExprKind::Global(_) => {}
            ExprKind::Unary(_, a) | ExprKind::Convert(a) | ExprKind::Component(a, _) => expr(a, visit),
            ExprKind::Binary(_, a, b) | ExprKind::Index(a, b) => {
                expr(a, visit);
                expr(b, visit);
            }
            ExprKind::Select(a, b, c) => {
                expr(a, visit);
                expr(b, visit);
                expr(c, visit);
            }
            ExprKind::Construct(parts) => parts.iter().for_each(|p| expr(p, visit)),
            ExprKind::Array(items) | ExprKind::Intrinsic(_, items) | ExprKind::Call(_, items) => {
                items.iter().for_each(|p| expr(p, visit))
            }
        }
    }
    fn stmts(list: &[Stmt], visit: &mut dyn FnMut(&super::hir::Expr)) {
        for s in list {
            match s {
                Stmt::Assign(place, value) => {
                    if let Some(e) = &place.element {
                        expr(e, visit);
                    }
                    if let Some(c) = &place.component {
                        expr(c, visit);
                    }
                    expr(value, visit);
                }
                Stmt::Eval(e) | Stmt::Return(Some(e)) => expr(e, visit),
                Stmt::If(c, a, b) => {
                    expr(c, visit);
                    stmts(a, visit);
                    stmts(b, visit);
                }
                Stmt::Loop { cond, body, step, .. } => {
                    if let Some(c) = cond {
                        expr(c, visit);
                    }
                    stmts(body, visit);
                    stmts(step, visit);
                }
                Stmt::Break | Stmt::Continue | Stmt::Return(None) => {}
            }
        }
    }
    for p in &func.params {
        if let Some(d) = &p.default {
            expr(d, visit);
        }
    }
    stmts(&func.body, visit);
}

fn callees_of(func: &Function) -> Vec<FuncId> {
    let mut out = Vec::new();
    visit_exprs(func, &mut |e| {
        if let ExprKind::Call(id, _) = e.kind {
            out.push(id);
        }
    });
    out
}

/// Whether the body itself (defaults excluded: they apply only to unconnected ports) reads a
/// shading global or a varying intrinsic.
fn reads_varying(func: &Function) -> bool {
    let body_only = Function { params: Vec::new(), ..func.clone() };
    let mut varying = false;
    visit_exprs(&body_only, &mut |e| match &e.kind {
        ExprKind::Global(_) => varying = true,
        ExprKind::Intrinsic(i, _) if i.is_varying() => varying = true,
        _ => {}
    });
    varying
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str) -> (Library, Diagnostics, SourceMap) {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let (lib, _) = Library::from_text("test.ash", text, &mut sources, &mut diags);
        (lib, diags, sources)
    }

    #[test]
    fn prelude_checks_cleanly() {
        let (lib, diags, sources) = load("");
        assert!(diags.items().is_empty(), "{}", diags.render(&sources));
        for name in [
            "diffuse",
            "glossy",
            "metal",
            "glass",
            "mask",
            "displacement",
            "bump",
            "normal_map",
            "noise",
            "fbm",
            "cellular",
            "checker",
            "ramp",
            "mix",
            "math",
            "texture",
            "customChannelColor",
            "customChannelFloat",
            "customChannelInteger",
        ] {
            assert!(lib.shaders.contains_key(name), "missing built-in {name}");
        }
        let noise = lib.function(lib.shaders["noise"]);
        assert!(!noise.varying, "noise reads P only through its default");
        assert!(lib.function(lib.shaders["normal_map"]).varying, "normal_map reads N");
    }

    #[test]
    fn recursion_is_reported() {
        let (_, diags, sources) = load("float f(float x) { return g(x); } float g(float x) { return f(x); }");
        assert!(diags.render(&sources).contains("is recursive"), "{}", diags.render(&sources));
    }
}
