//! Loading substance files: the built-in prelude, user files and their imports, checked
//! together into one [`Library`] of node types, functions and graphs.

use super::ast::{self, FunctionKind, GraphKind, Item};
use super::check::{Callee, check_function, resolve_type};
use super::graph::{Graph, resolve_graph};
use super::hir::{ExprKind, FuncId, Function, Stmt};
use super::intrinsics::Intrinsic;
use super::parser::parse;
use crate::diag::{Diagnostic, Diagnostics, FileId, SourceMap, Span};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

/// The source of the built-in node library.
pub const PRELUDE: &str = concat!(
    include_str!("prelude.ash"),
    include_str!("mtlx.ash"),
    include_str!("mtlx_stdlib.ash"),
    include_str!("mtlx_color4.ash")
);

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
        crate::stack::on_compiler_stack(|| Library::load_here(files, sources, diags))
    }

    fn load_here(files: &[(PathBuf, Span)], sources: &mut SourceMap, diags: &mut Diagnostics) -> Library {
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
            let read = match crate::input::scenes::embedded(&path) {
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
        crate::stack::on_compiler_stack(|| Library::from_text_here(name, text, sources, diags))
    }

    fn from_text_here(name: &str, text: &str, sources: &mut SourceMap, diags: &mut Diagnostics) -> (Library, FileId) {
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
        // (kind, name) → where first defined and whether that is the prelude.
        let mut first_span: HashMap<(FunctionKind, String), (Span, bool)> = HashMap::new();
        for (path, module) in &modules {
            let builtin = path.is_none();
            for item in &module.items {
                let Item::Function(f) = item else { continue };
                let key = (f.kind, f.name.name.clone());
                let what = if f.kind == FunctionKind::Shader { "shader" } else { "function" };
                if let Some(&(first, first_builtin)) = first_span.get(&key) {
                    let message = if first_builtin {
                        format!("`{}` is a built-in {what}; choose another name", f.name.name)
                    } else {
                        format!("{what} `{}` is defined twice", f.name.name)
                    };
                    diags.push(
                        Diagnostic::error(message).at(f.name.span, "defined again").also(first, "first defined here"),
                    );
                    continue;
                }
                // Calls resolve user functions before built-in functions, everywhere (the
                // prelude's node bodies included), so a user `noise` would silently replace
                // the intrinsic inside the built-in `noise` node.
                if !builtin && f.kind == FunctionKind::Function && Intrinsic::from_name(&f.name.name).is_some() {
                    diags.push(
                        Diagnostic::error(format!("`{}` is a built-in function; choose another name", f.name.name))
                            .at(f.name.span, "reserved by the language")
                            .note("user functions may not take the name of a built-in function"),
                    );
                    continue;
                }
                first_span.insert(key, (f.name.span, builtin));
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
                // Graph names are per file, but the renderer looks the prelude's graphs up by
                // name (`default_substance` shades unbound prims): a user graph may not take one.
                if path.is_some()
                    && let Some(&builtin) = lib.graph_index.get(&(PathBuf::new(), g.name.name.clone()))
                {
                    let kind = if g.kind == GraphKind::Substance { "substance" } else { "override" };
                    diags.push(
                        Diagnostic::error(format!("`{}` is a built-in graph; choose another name", g.name.name))
                            .at(g.name.span, format!("this {kind} would shadow it"))
                            .also(lib.graphs[builtin.0 as usize].span, "defined by the built-in library"),
                    );
                    continue;
                }
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

    /// Adds a graph built outside any source file (composition's instances of built-in
    /// substances, `compose::preview`) and returns its id. It belongs to no file, so it can be
    /// found only by id.
    pub fn add_graph(&mut self, graph: Graph) -> GraphId {
        self.graphs.push(graph);
        self.graph_files.push(PathBuf::from("<composed>"));
        GraphId(self.graphs.len() as u32 - 1)
    }

    /// Finds a graph of the built-in library (the prelude) by name.
    pub fn builtin_graph(&self, name: &str) -> Option<GraphId> {
        self.graph_index.get(&(PathBuf::new(), name.to_string())).copied()
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
    /// Depth-first with an explicit stack: a chain of thousands of functions, each calling
    /// the next, is legal and must not exhaust the stack.
    fn check_recursion(&self, diags: &mut Diagnostics) {
        let calls: Vec<Vec<FuncId>> = self.functions.iter().map(callees_of).collect();
        let mut state = vec![0u8; self.functions.len()]; // 0 new, 1 active, 2 done
        for root in 0..self.functions.len() {
            if state[root] != 0 {
                continue;
            }
            state[root] = 1;
            // (function, index of the next callee to look at)
            let mut stack = vec![(root, 0usize)];
            while let Some((f, next)) = stack.last_mut() {
                let f = *f;
                let Some(callee) = calls[f].get(*next) else {
                    state[f] = 2;
                    stack.pop();
                    continue;
                };
                *next += 1;
                let c = callee.0 as usize;
                if state[c] == 1 {
                    let func = &self.functions[c];
                    diags.push(
                        Diagnostic::error(format!("`{}` is recursive", func.name))
                            .at(func.span, "calls itself, directly or indirectly")
                            .note("functions are inlined into shaders; use a loop instead"),
                    );
                } else if state[c] == 0 {
                    state[c] = 1;
                    stack.push((c, 0));
                }
            }
        }
    }

    /// Marks functions that read globals or varying intrinsics, directly or through callees:
    /// varying-ness flows from each such function to its callers, each edge once.
    fn compute_varying(&mut self) {
        let mut varying: Vec<bool> = self.functions.iter().map(reads_varying).collect();
        let mut callers: Vec<Vec<usize>> = vec![Vec::new(); self.functions.len()];
        for (f, func) in self.functions.iter().enumerate() {
            for callee in callees_of(func) {
                callers[callee.0 as usize].push(f);
            }
        }
        let mut pending: Vec<usize> = (0..varying.len()).filter(|&f| varying[f]).collect();
        while let Some(f) = pending.pop() {
            for &caller in &callers[f] {
                if !varying[caller] {
                    varying[caller] = true;
                    pending.push(caller);
                }
            }
        }
        for (f, v) in self.functions.iter_mut().zip(varying) {
            f.varying = v;
        }
    }
}

/// Visits every expression of a function: parameter defaults and the body. Expressions are
/// walked with an explicit stack (a flat chain of 100 000 `+` is a tree that deep); statements
/// recurse, as deep as the parser lets blocks nest.
pub fn visit_exprs(func: &Function, visit: &mut dyn FnMut(&super::hir::Expr)) {
    for p in &func.params {
        if let Some(d) = &p.default {
            visit_tree(d, visit);
        }
    }
    visit_stmts(&func.body, &mut |e| visit_tree(e, visit));
}

/// Calls `visit` on `root` and every expression inside it, operands left to right.
fn visit_tree(root: &super::hir::Expr, visit: &mut dyn FnMut(&super::hir::Expr)) {
    let mut pending = vec![root];
    while let Some(e) = pending.pop() {
        visit(e);
        // Pushed in reverse so operands are visited left to right.
        match &e.kind {
            ExprKind::Const(_) | ExprKind::Local(_) | ExprKind::Global(_) => {}
            ExprKind::Unary(_, a) | ExprKind::Convert(a) | ExprKind::Component(a, _) => pending.push(a),
            ExprKind::Binary(_, a, b) | ExprKind::Index(a, b) => pending.extend([&**b, &**a]),
            ExprKind::Select(a, b, c) => pending.extend([&**c, &**b, &**a]),
            ExprKind::Construct(parts) => pending.extend(parts.iter().rev()),
            ExprKind::Array(items) | ExprKind::Intrinsic(_, items) | ExprKind::Call(_, items) => {
                pending.extend(items.iter().rev())
            }
        }
    }
}

/// Calls `visit` on every top-level expression of a statement list (conditions, values,
/// indices), recursing into nested statements.
fn visit_stmts(list: &[Stmt], visit: &mut dyn FnMut(&super::hir::Expr)) {
    for s in list {
        match s {
            Stmt::Assign(place, value) => {
                if let Some(e) = &place.element {
                    visit(e);
                }
                if let Some(c) = &place.component {
                    visit(c);
                }
                visit(value);
            }
            Stmt::Eval(e) | Stmt::Return(Some(e)) => visit(e),
            Stmt::If(c, a, b) => {
                visit(c);
                visit_stmts(a, visit);
                visit_stmts(b, visit);
            }
            Stmt::Loop { cond, body, step, .. } => {
                if let Some(c) = cond {
                    visit(c);
                }
                visit_stmts(body, visit);
                visit_stmts(step, visit);
            }
            Stmt::Break | Stmt::Continue | Stmt::Return(None) => {}
        }
    }
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
    let mut varying = false;
    let mut check = |e: &super::hir::Expr| match &e.kind {
        ExprKind::Global(_) => varying = true,
        ExprKind::Intrinsic(i, _) if i.is_varying() => varying = true,
        _ => {}
    };
    visit_stmts(&func.body, &mut |e| visit_tree(e, &mut check));
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
