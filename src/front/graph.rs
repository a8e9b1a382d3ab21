//! Substance and override graphs after resolution: node instances refer to checked node types,
//! every port assignment is typed, and the graph is known to be acyclic.

use super::ast::{self, BaseType, ExprKind as A, GraphKind, Product};
use super::check::resolve_type;
use super::hir::{FuncId, Function};
use super::types::{Type, Value};
use crate::abi::{ChannelKind, DisplacementMode};
use crate::diag::{Diagnostic, Diagnostics, Span, did_you_mean};
use std::collections::HashMap;

/// What drives a port, an output or a product.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// A literal.
    Const(Value, Type),
    /// An exposed input of the graph (index into [`Graph::inputs`]).
    Input(usize),
    /// Output parameter `param` of node `node`.
    Node {
        /// Index into [`Graph::nodes`].
        node: usize,
        /// Parameter index of the output in the node type.
        param: usize,
    },
}

/// An exposed input: a name scenes can set, with a type and default.
#[derive(Clone, Debug)]
pub struct GraphInput {
    /// The name (also matched against override outputs).
    pub name: String,
    /// Its type.
    pub ty: Type,
    /// Its default value.
    pub default: Value,
    /// Where it is declared.
    pub span: Span,
}

/// An override output.
#[derive(Clone, Debug)]
pub struct GraphOutput {
    /// The name of the substance input it drives.
    pub name: String,
    /// Its type.
    pub ty: Type,
    /// What drives it.
    pub source: Source,
    /// Where it is declared.
    pub span: Span,
}

/// One instance of a node type.
#[derive(Clone, Debug)]
pub struct NodeInstance {
    /// Instance name.
    pub name: String,
    /// The node type.
    pub func: FuncId,
    /// For each parameter of the node type: what drives it (`None`: the default, or an output).
    pub args: Vec<Option<Source>>,
    /// Where it is declared.
    pub span: Span,
}

/// A product binding.
#[derive(Clone, Debug)]
pub struct ProductBinding {
    /// Which product.
    pub product: Product,
    /// What drives it.
    pub source: Source,
    /// For displacement: the combination mode read from the driving node.
    pub mode: Option<DisplacementMode>,
    /// For displacement that moves geometry: the driving node's `bound` (a literal or an
    /// exposed input). `None`: the node has no `bound` input, so it only bumps.
    pub bound: Option<Source>,
    /// Where it is bound.
    pub span: Span,
}

/// A resolved substance or override.
#[derive(Clone, Debug)]
pub struct Graph {
    /// Substance or override.
    pub kind: GraphKind,
    /// Its name.
    pub name: String,
    /// Exposed inputs.
    pub inputs: Vec<GraphInput>,
    /// Override outputs.
    pub outputs: Vec<GraphOutput>,
    /// Node instances.
    pub nodes: Vec<NodeInstance>,
    /// Product bindings, at most one per product.
    pub products: Vec<ProductBinding>,
    /// Nodes that are custom channels, with their kind and channel name.
    pub channels: Vec<(usize, ChannelKind, String)>,
    /// Where it is declared.
    pub span: Span,
}

impl Graph {
    /// Finds an exposed input by name.
    pub fn input(&self, name: &str) -> Option<(usize, &GraphInput)> {
        self.inputs.iter().enumerate().find(|(_, i)| i.name == name)
    }
}

/// Evaluates a literal written in a graph (`1`, `-0.5`, `"s"`, `color(1, 0, 0)`).
pub fn literal(expr: &ast::Expr) -> Option<(Value, Type)> {
    match &expr.kind {
        A::Float(x) => Some((Value::Float(*x as f32), Type::FLOAT)),
        A::Int(i) => Some((Value::Int(*i as i32), Type::INT)),
        A::Str(s) => Some((Value::Str(s.clone()), Type::STRING)),
        A::Unary(ast::UnaryOp::Neg, inner) => match literal(inner)? {
            (Value::Float(x), t) => Some((Value::Float(-x), t)),
            (Value::Int(i), t) => Some((Value::Int(i.wrapping_neg()), t)),
            (Value::Triple(v), t) => Some((Value::Triple(v.map(|c| -c)), t)),
            _ => None,
        },
        A::Call(name, args) => {
            let base = super::hir::triple_constructor(&name.name)?;
            let parts: Option<Vec<f32>> = args.iter().map(|a| literal(a).and_then(|(v, _)| v.as_f32())).collect();
            let parts = parts?;
            let v = match parts.as_slice() {
                [x] => [*x; 3],
                [x, y, z] => [*x, *y, *z],
                _ => return None,
            };
            Some((Value::Triple(v), Type::scalar(base)))
        }
        _ => None,
    }
}

/// Resolves one graph declaration against the node types in `shaders`.
pub fn resolve_graph(
    decl: &ast::GraphDecl,
    shaders: &HashMap<String, FuncId>,
    functions: &[Function],
    diags: &mut Diagnostics,
) -> Graph {
    let mut graph = Graph {
        kind: decl.kind,
        name: decl.name.name.clone(),
        inputs: Vec::new(),
        outputs: Vec::new(),
        nodes: Vec::new(),
        products: Vec::new(),
        channels: Vec::new(),
        span: decl.name.span,
    };
    let mut names: HashMap<String, Span> = HashMap::new();
    let mut duplicate = |diags: &mut Diagnostics, name: &ast::Ident, what: &str| {
        if let Some(first) = names.insert(name.name.clone(), name.span) {
            diags.push(
                Diagnostic::error(format!("duplicate name `{}` in `{}`", name.name, decl.name.name))
                    .at(name.span, format!("{what} declared again"))
                    .also(first, "first declared here"),
            );
            true
        } else {
            false
        }
    };

    // Pass 1: declare inputs and node instances so references can point forward.
    let mut node_decls = Vec::new();
    for item in &decl.items {
        match item {
            ast::GraphItem::Input { ty, name, default } => {
                if duplicate(diags, name, "input") {
                    continue;
                }
                let ty = resolve_type(ty);
                if ty.array.is_some() || matches!(ty.base, BaseType::Closure | BaseType::Void) {
                    diags.push(
                        Diagnostic::error(format!("an exposed input cannot be {ty}")).at(name.span, "bad input type"),
                    );
                    continue;
                }
                let value = match default {
                    None => Value::zero(ty).unwrap_or(Value::Int(0)),
                    Some(d) => match literal(d) {
                        Some((v, vt)) if vt.converts_to(ty) && v.is_finite() => v.convert(vt, ty),
                        Some((v, vt)) if vt.converts_to(ty) => {
                            diags.push(
                                Diagnostic::error(format!("default of `{}` is not finite: {v}", name.name))
                                    .at(d.span, "NaN or infinite"),
                            );
                            continue;
                        }
                        Some((_, vt)) => {
                            diags.push(
                                Diagnostic::error(format!(
                                    "mismatched types: input `{}` is {ty}, default is {vt}",
                                    name.name
                                ))
                                .at(d.span, format!("this is {vt}")),
                            );
                            continue;
                        }
                        None => {
                            diags.push(
                                Diagnostic::error("an input default must be a literal").at(d.span, "not a literal"),
                            );
                            continue;
                        }
                    },
                };
                graph.inputs.push(GraphInput { name: name.name.clone(), ty, default: value, span: name.span });
            }
            ast::GraphItem::Node { name, node_type, args } => {
                if duplicate(diags, name, "node") {
                    continue;
                }
                let Some(&func) = shaders.get(&node_type.name) else {
                    let mut d = Diagnostic::error(format!("unknown node type `{}`", node_type.name))
                        .at(node_type.span, "no shader of this name");
                    match did_you_mean(&node_type.name, shaders.keys().map(String::as_str)) {
                        Some(hint) => d = d.note(hint),
                        None => {
                            d = d.note(
                                "node types are the built-in library and `shader` declarations of this file and its imports",
                            )
                        }
                    }
                    diags.push(d);
                    continue;
                };
                let params = functions[func.0 as usize].params.len();
                node_decls.push((graph.nodes.len(), args));
                graph.nodes.push(NodeInstance {
                    name: name.name.clone(),
                    func,
                    args: vec![None; params],
                    span: name.span,
                });
            }
            _ => {}
        }
    }

    let node_index: HashMap<String, usize> = graph.nodes.iter().enumerate().map(|(i, n)| (n.name.clone(), i)).collect();

    // Resolves a value expression to a source and its type.
    let source_of = |graph: &Graph, expr: &ast::Expr, diags: &mut Diagnostics| -> Option<(Source, Type)> {
        match &expr.kind {
            A::Name(n) => match graph.input(n) {
                Some((i, input)) => Some((Source::Input(i), input.ty)),
                None => {
                    let hint = if node_index.contains_key(n) {
                        "a node: name one of its outputs, `node.port`"
                    } else {
                        "not an input of this graph"
                    };
                    let mut d = Diagnostic::error(format!("unknown input `{n}`")).at(expr.span, hint);
                    if !node_index.contains_key(n)
                        && let Some(hint) = did_you_mean(n, graph.inputs.iter().map(|i| i.name.as_str()))
                    {
                        d = d.note(hint);
                    }
                    diags.push(d);
                    None
                }
            },
            A::Member(base, port) if matches!(base.kind, A::Name(_)) => {
                let A::Name(node_name) = &base.kind else { return None };
                let Some(&node) = node_index.get(node_name) else {
                    let mut d =
                        Diagnostic::error(format!("unknown node `{node_name}`")).at(base.span, "no node of this name");
                    if let Some(hint) = did_you_mean(node_name, node_index.keys().map(String::as_str)) {
                        d = d.note(hint);
                    }
                    diags.push(d);
                    return None;
                };
                let func = &functions[graph.nodes[node].func.0 as usize];
                match func.param(&port.name) {
                    Some((param, p)) if p.output => Some((Source::Node { node, param }, p.ty)),
                    Some(_) => {
                        diags.push(
                            Diagnostic::error(format!("`{}` is an input of `{}`, not an output", port.name, func.name))
                                .at(port.span, "not an output"),
                        );
                        None
                    }
                    None => {
                        let outputs: Vec<&str> = func.outputs().map(|(_, p)| p.name.as_str()).collect();
                        let mut d =
                            Diagnostic::error(format!("node type `{}` has no output `{}`", func.name, port.name))
                                .at(port.span, "unknown port");
                        if let Some(hint) = did_you_mean(&port.name, outputs.iter().copied()) {
                            d = d.note(hint);
                        }
                        diags.push(d.note(format!(
                            "outputs: {}",
                            if outputs.is_empty() { "none".to_string() } else { outputs.join(", ") }
                        )));
                        None
                    }
                }
            }
            _ => match literal(expr) {
                Some((v, ty)) if v.is_finite() => Some((Source::Const(v, ty), ty)),
                Some((v, _)) => {
                    diags.push(Diagnostic::error(format!("value is not finite: {v}")).at(expr.span, "NaN or infinite"));
                    None
                }
                None => {
                    diags.push(
                        Diagnostic::error("expected a literal, an input name or `node.port`")
                            .at(expr.span, "not a graph value")
                            .note("graphs connect nodes; computations belong in a shader"),
                    );
                    None
                }
            },
        }
    };

    // Pass 2: node arguments.
    for (node, args) in node_decls {
        let func = &functions[graph.nodes[node].func.0 as usize];
        let mut seen: HashMap<&str, Span> = HashMap::new();
        for (port, value) in args.iter() {
            if let Some(first) = seen.insert(port.name.as_str(), port.span) {
                diags.push(
                    Diagnostic::error(format!("port `{}` is assigned twice", port.name))
                        .at(port.span, "assigned again")
                        .also(first, "first assigned here"),
                );
                continue;
            }
            let Some((param, p)) = func.param(&port.name) else {
                let inputs: Vec<&str> = func.inputs().map(|(_, p)| p.name.as_str()).collect();
                let mut d = Diagnostic::error(format!("node type `{}` has no input `{}`", func.name, port.name))
                    .at(port.span, "unknown port");
                if let Some(hint) = did_you_mean(&port.name, inputs.iter().copied()) {
                    d = d.note(hint);
                }
                diags.push(d.note(format!("inputs: {}", inputs.join(", "))));
                continue;
            };
            if p.output {
                diags.push(
                    Diagnostic::error(format!(
                        "`{}` is an output of `{}`; it cannot be assigned",
                        port.name, func.name
                    ))
                    .at(port.span, "an output"),
                );
                continue;
            }
            let Some((source, ty)) = source_of(&graph, value, diags) else { continue };
            if !ty.converts_to(p.ty) {
                diags.push(
                    Diagnostic::error(format!(
                        "mismatched types: port `{}` of `{}` is {}, connected value is {ty}",
                        port.name, func.name, p.ty
                    ))
                    .at(value.span, format!("this is {ty}")),
                );
                continue;
            }
            let source = match source {
                Source::Const(v, t) => Source::Const(v.convert(t, p.ty), p.ty),
                other => other,
            };
            graph.nodes[node].args[param] = Some(source);
        }
    }

    // Pass 3: outputs, products, channels.
    for item in &decl.items {
        match item {
            ast::GraphItem::Output { ty, name, value } => {
                if decl.kind == GraphKind::Substance {
                    diags.push(
                        Diagnostic::error("only overrides have outputs")
                            .at(name.span, "declared in a substance")
                            .note("a substance exposes `input`s; an `override` drives them with `output`s"),
                    );
                    continue;
                }
                if duplicate(diags, name, "output") {
                    continue;
                }
                let ty = resolve_type(ty);
                let Some((source, vt)) = source_of(&graph, value, diags) else { continue };
                if !vt.converts_to(ty) {
                    diags.push(
                        Diagnostic::error(format!(
                            "mismatched types: output `{}` is {ty}, its value is {vt}",
                            name.name
                        ))
                        .at(value.span, format!("this is {vt}")),
                    );
                    continue;
                }
                let source = match source {
                    Source::Const(v, t) => Source::Const(v.convert(t, ty), ty),
                    other => other,
                };
                graph.outputs.push(GraphOutput { name: name.name.clone(), ty, source, span: name.span });
            }
            ast::GraphItem::Product { product, span, value } => {
                if decl.kind == GraphKind::Override {
                    diags.push(
                        Diagnostic::error("an override cannot bind products")
                            .at(*span, "product in an override")
                            .note("overrides drive the inputs of the substance in their slot"),
                    );
                    continue;
                }
                if let Some(first) = graph.products.iter().find(|b| b.product == *product) {
                    diags.push(
                        Diagnostic::error(format!("product `{}` is bound twice", product.name()))
                            .at(*span, "bound again")
                            .also(first.span, "first bound here"),
                    );
                    continue;
                }
                let Some((source, ty)) = source_of(&graph, value, diags) else { continue };
                let expected = match product {
                    Product::Surface => Type::CLOSURE,
                    Product::Displacement | Product::Mask => Type::FLOAT,
                    Product::Normal => Type::NORMAL,
                    Product::Emission => Type::COLOR,
                };
                if !ty.converts_to(expected) {
                    diags.push(
                        Diagnostic::error(format!(
                            "wrong product type: `{}` must be {expected}, found {ty}",
                            product.name()
                        ))
                        .at(value.span, format!("this is {ty}")),
                    );
                    continue;
                }
                let (mode, bound) = if *product == Product::Displacement {
                    match displacement_mode(&graph, &source, functions)
                        .and_then(|mode| Ok((Some(mode), displacement_bound(&graph, &source, functions)?)))
                    {
                        Ok(found) => found,
                        Err(message) => {
                            diags.push(Diagnostic::error(message).at(value.span, "displacement source"));
                            continue;
                        }
                    }
                } else {
                    (None, None)
                };
                graph.products.push(ProductBinding { product: *product, source, mode, bound, span: *span });
            }
            _ => {}
        }
    }

    for (index, node) in graph.nodes.iter().enumerate() {
        let func = &functions[node.func.0 as usize];
        let Some(kind) = func.builtin.then(|| ChannelKind::from_node_type(&func.name)).flatten() else { continue };
        let name = match func.param("name").and_then(|(i, _)| node.args[i].as_ref()) {
            Some(Source::Const(Value::Str(s), _))
                if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') =>
            {
                s.clone()
            }
            _ => {
                diags.push(
                    Diagnostic::error(format!(
                        "custom channel `{}` needs a `name:` made of letters, digits and `_`",
                        node.name
                    ))
                    .at(node.span, "channel name missing or invalid"),
                );
                continue;
            }
        };
        if let Some((other, _, _)) = graph.channels.iter().find(|(_, _, n)| *n == name) {
            diags.push(
                Diagnostic::error(format!("custom channel `{name}` is declared twice"))
                    .at(node.span, "declared again")
                    .also(graph.nodes[*other].span, "first declared here"),
            );
            continue;
        }
        graph.channels.push((index, kind, name));
    }

    // Rule 5: emission shows where its layer is picked, and a layer without a surface never is.
    if let Some(emission) = graph.products.iter().find(|b| b.product == Product::Emission)
        && !graph.products.iter().any(|b| b.product == Product::Surface)
    {
        diags.push(
            Diagnostic::warning(format!(
                "substance `{}` emits but has no `surface`: its emission is never seen",
                graph.name
            ))
            .at(emission.span, "emission here")
            .note("a layer without a surface takes no part in the layer pick (DESIGN.md rule 5)"),
        );
    }
    check_acyclic(&graph, diags);
    graph
}

/// Reads the constant `mode` of the displacement/bump node that drives a displacement product.
fn displacement_mode(graph: &Graph, source: &Source, functions: &[Function]) -> Result<DisplacementMode, String> {
    let Source::Node { node, .. } = source else {
        return Err("`displacement` must be driven by a `displacement` or `bump` node".into());
    };
    let func = &functions[graph.nodes[*node].func.0 as usize];
    let Some((param, p)) = func.param("mode").filter(|(_, p)| p.ty == Type::STRING && !p.output) else {
        return Err(format!(
            "`displacement` must be driven by a node with a string `mode` input; `{}` has none",
            func.name
        ));
    };
    let mode = match (&graph.nodes[*node].args[param], &p.default) {
        (Some(Source::Const(Value::Str(s), _)), _) => s.clone(),
        (None, Some(default)) => match default.as_const() {
            Some(Value::Str(s)) => s.clone(),
            _ => return Err("the displacement mode must be a literal string".into()),
        },
        _ => return Err("the displacement mode must be a literal string, not a connection".into()),
    };
    match mode.as_str() {
        "none" => Ok(DisplacementMode::None),
        "add" => Ok(DisplacementMode::Add),
        "mix" => Ok(DisplacementMode::Mix),
        other => Err(format!("unknown displacement mode \"{other}\" (expected \"none\", \"add\" or \"mix\")")),
    }
}

/// The `bound` of the node that drives a displacement product: `None` when it has no float
/// `bound` input (a `bump`), else its literal, default or exposed input. A bound computed by
/// another node is refused: dicing needs it before any shading point exists.
fn displacement_bound(graph: &Graph, source: &Source, functions: &[Function]) -> Result<Option<Source>, String> {
    let Source::Node { node, .. } = source else { return Ok(None) };
    let func = &functions[graph.nodes[*node].func.0 as usize];
    let Some((param, p)) = func.param("bound").filter(|(_, p)| !p.output) else { return Ok(None) };
    if !p.ty.converts_to(Type::FLOAT) {
        return Err(format!("the displacement `bound` of `{}` must be a float", func.name));
    }
    match (&graph.nodes[*node].args[param], &p.default) {
        (Some(bound @ (Source::Const(..) | Source::Input(_))), _) => Ok(Some(bound.clone())),
        (None, Some(default)) => match default.as_const() {
            Some(v) => Ok(Some(Source::Const(v.clone(), p.ty))),
            None => Err("the displacement `bound` default must be a literal".into()),
        },
        (None, None) => Err(format!("`{}` needs a `bound` value: its input has no default", func.name)),
        _ => Err("the displacement `bound` must be a literal or a substance input, not a connection: \
                  dicing needs it before shading"
            .into()),
    }
}

/// Reports each cycle among node connections once.
fn check_acyclic(graph: &Graph, diags: &mut Diagnostics) {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Active,
        Done,
    }
    let mut marks = vec![Mark::New; graph.nodes.len()];
    for start in 0..graph.nodes.len() {
        if marks[start] != Mark::New {
            continue;
        }
        // Iterative DFS: (node, next argument index).
        let mut stack = vec![(start, 0usize)];
        marks[start] = Mark::Active;
        while let Some(&(node, next)) = stack.last() {
            let args = &graph.nodes[node].args;
            let mut cursor = next;
            let mut descended = false;
            while cursor < args.len() {
                let arg = &args[cursor];
                cursor += 1;
                if let Some(Source::Node { node: dep, .. }) = arg {
                    match marks[*dep] {
                        Mark::New => {
                            marks[*dep] = Mark::Active;
                            if let Some(top) = stack.last_mut() {
                                top.1 = cursor;
                            }
                            stack.push((*dep, 0));
                            descended = true;
                            break;
                        }
                        Mark::Active => {
                            let pos = stack.iter().position(|(n, _)| n == dep).unwrap_or(0);
                            let mut names: Vec<&str> =
                                stack[pos..].iter().map(|(n, _)| graph.nodes[*n].name.as_str()).collect();
                            names.push(&graph.nodes[*dep].name);
                            diags.push(
                                Diagnostic::error(format!("connection cycle: {}", names.join(" -> ")))
                                    .at(graph.nodes[node].span, "this node depends on itself")
                                    .note("a graph must be acyclic"),
                            );
                        }
                        Mark::Done => {}
                    }
                }
            }
            if !descended {
                marks[node] = Mark::Done;
                stack.pop();
            }
        }
    }
}
