//! The wired IR: one typed node graph per composed material.
//!
//! Building it instantiates every layer's substance and override graphs, sets the input values
//! the scene gives, and wires override outputs to same-named substance inputs (DESIGN.md rule 3).
//! Passes then fold constants, prune layers hidden under constant-opaque masks, and remove
//! dead nodes (products and custom channels are the roots). The text form is stable and pinned
//! by snapshot tests.

use super::eval::eval_node;
use crate::abi::layering::{self, Unpickable};
use crate::abi::{ChannelKind, DisplacementMode};
use crate::abi::{LayerInfo, Pruned};
use crate::compose::{ComposedMaterial, MaterialRef};
use crate::diag::{Diagnostic, Diagnostics, Span, did_you_mean};
use crate::front::ast::{GraphKind, Product};
use crate::front::graph::{Graph, Source};
use crate::front::hir::{ExprKind, FuncId};
use crate::front::library::Library;
use crate::front::types::{Type, Value};
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;

/// Index of a node in a [`WiredMaterial`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(pub u32);

/// What drives a node input, a product or a channel.
#[derive(Clone, Debug, PartialEq)]
pub enum Operand {
    /// A constant of the given type.
    Const(Value, Type),
    /// Output parameter `param` of a node.
    Node {
        /// The node.
        node: NodeId,
        /// Parameter index of the output in the node type.
        param: usize,
    },
    /// The node type's default for this input (which may read shading globals).
    Default,
    /// A live input (`PassOptions::live_inputs`): read at run time from word `offset` of the
    /// material instance's parameter block (`abi::Globals::params`), `ty`'s width of words.
    Param {
        /// First word in the block.
        offset: u32,
        /// The input's type.
        ty: Type,
    },
}

/// One node instance.
#[derive(Clone, Debug)]
pub struct Node {
    /// Node type.
    pub func: FuncId,
    /// `slot/instance`, e.g. `050::010/dirt_color`.
    pub label: String,
    /// Per parameter of the node type; outputs are always [`Operand::Default`].
    pub args: Vec<Operand>,
    /// The layer it belongs to.
    pub layer: usize,
}

/// A custom channel (AOV) root.
#[derive(Clone, Debug)]
pub struct Channel {
    /// Channel name (the EXR layer name).
    pub name: String,
    /// Colour, float or integer.
    pub kind: ChannelKind,
    /// Its value.
    pub value: Operand,
    /// The type of the channel node's `value` port.
    pub ty: Type,
}

/// One layer of the wired material.
#[derive(Clone, Debug)]
pub struct Layer {
    /// Slot name (`000`; `default` for the default substance).
    pub slot: String,
    /// The substance's graph name.
    pub substance: String,
    /// The material prim path.
    pub material: String,
    /// Override slots and material paths applied to it, ascending.
    pub overrides: Vec<(String, String)>,
    /// BSDF closure.
    pub surface: Option<Operand>,
    /// Height and combination mode.
    pub displacement: Option<(Operand, DisplacementMode)>,
    /// The bound of a displacement that moves geometry; `None` for a bump (see
    /// [`LayerInfo::displacement_bound`]).
    pub displacement_bound: Option<f32>,
    /// Shading normal.
    pub normal: Option<Operand>,
    /// Opacity (absent: 1).
    pub mask: Option<Operand>,
    /// Emitted radiance; `None` when absent or constant black (the common case costs nothing).
    pub emission: Option<Operand>,
    /// Custom channels of the layer (its substance's and its overrides').
    pub channels: Vec<Channel>,
    /// Why the layer's shading was removed, if it was (`hidden under slot 050`).
    pub pruned: Option<Pruned>,
}

impl Layer {
    /// What the renderer (and [`layering`]) knows about the layer.
    pub fn info(&self) -> LayerInfo {
        LayerInfo {
            slot: self.slot.clone(),
            has_surface: self.surface.is_some(),
            displacement: self.displacement.as_ref().map(|(_, mode)| *mode),
            displacement_bound: self.displacement.as_ref().and(self.displacement_bound),
            has_normal: self.normal.is_some(),
            constant_mask: self.constant_mask(),
            has_emission: self.emission.is_some(),
            pruned: self.pruned.clone(),
        }
    }

    /// The layer's mask as a compile-time constant, if it is one (absent mask = 1).
    pub fn constant_mask(&self) -> Option<f32> {
        match &self.mask {
            None => Some(1.0),
            Some(Operand::Const(v, _)) => v.as_f32().map(layering::clamp_mask),
            _ => None,
        }
    }
}

/// Node counts after each pass.
#[derive(Clone, Debug, Default)]
pub struct Stats {
    /// (pass name, live nodes after it).
    pub nodes: Vec<(&'static str, usize)>,
    /// Layers whose shading was pruned.
    pub layers_pruned: usize,
}

/// A composed material as a wired node graph.
#[derive(Clone, Debug)]
pub struct WiredMaterial {
    /// Layers bottom to top.
    pub layers: Vec<Layer>,
    /// Live nodes in topological order (inputs before users).
    pub nodes: Vec<Node>,
    /// Every custom channel of the material, by name (the union over layers).
    pub channels: Vec<(String, ChannelKind)>,
    /// Pass statistics.
    pub stats: Stats,
}

/// Options for the passes (the renderer's tests compare optimised and unoptimised output).
#[derive(Clone, Copy, Debug)]
pub struct PassOptions {
    /// Constant folding and pruning of hidden layers.
    pub optimize: bool,
    /// Substance and override inputs of float and triple types become parameters read from
    /// the instance's block ([`Operand::Param`], laid out as
    /// [`ComposedMaterial::parameter_block`]) instead of folded constants, so one compiled
    /// class serves every material that differs only in those values and an edit rewrites a
    /// block (`strata view`; `render` folds).
    pub live_inputs: bool,
}

impl Default for PassOptions {
    fn default() -> Self {
        PassOptions { optimize: true, live_inputs: false }
    }
}

/// Builds and optimises the wired IR of one composed material. Runs on the compiler stack
/// ([`crate::stack`]): constant folding evaluates node bodies recursively.
pub fn build(
    lib: &Library,
    material: &ComposedMaterial,
    options: PassOptions,
    diags: &mut Diagnostics,
) -> WiredMaterial {
    crate::stack::on_compiler_stack(|| build_here(lib, material, options, diags))
}

fn build_here(
    lib: &Library,
    material: &ComposedMaterial,
    options: PassOptions,
    diags: &mut Diagnostics,
) -> WiredMaterial {
    let mut b = Builder { lib, nodes: Vec::new(), diags, live: false, next_param: 0 };
    let mut layers = Vec::new();
    if material.layers.is_empty() {
        // The prelude's own graph, by its file: a user graph of the same name is rejected when
        // the library loads, and could not be picked here anyway.
        match lib.builtin_graph(material.display.default_substance()) {
            Some(graph) => {
                let substance = MaterialRef { path: String::new(), graph, values: Vec::new(), span: Span::default() };
                layers.push(b.layer(0, "default", &substance, &[]));
                b.live = false;
            }
            None => b.diags.push(Diagnostic::error(
                "internal compiler error: the built-in library has no `default_substance` to shade unbound prims",
            )),
        }
    }
    // The default substance above has no parameters; scene materials may.
    b.live = options.live_inputs;
    for (index, layer) in material.layers.iter().enumerate() {
        let overrides: Vec<(String, &MaterialRef)> = layer.overrides.iter().map(|(s, m)| (s.name(), m)).collect();
        let mut wired = b.layer(index, &layer.slot.name(), &layer.substance, &overrides);
        // Vertical layers (DESIGN.md rule 3b), the first lying directly on the surface.
        for vertical in &layer.vertical {
            let overrides: Vec<(String, &MaterialRef)> =
                vertical.overrides.iter().map(|(s, m)| (s.name(), m)).collect();
            let top = b.layer(index, &vertical.slot.name(), &vertical.substance, &overrides);
            b.lay_over(index, &mut wired, top, vertical.substance.span);
        }
        layers.push(wired);
    }
    let nodes = b.nodes;
    let mut wired = WiredMaterial { layers, nodes: Vec::new(), channels: Vec::new(), stats: Stats::default() };
    let mut live: Vec<Option<Node>> = nodes.into_iter().map(Some).collect();
    drop_black_emission(&mut wired.layers);
    wired.stats.nodes.push(("wired", live.len()));
    // Every declared channel is an image channel, even where pruning removes the only layer
    // that writes it (it then reads 0 everywhere, as it would unoptimised).
    wired.channels = collect_channels(&wired.layers, b.diags);
    if options.optimize {
        fold_constants(lib, &mut live, &mut wired.layers);
        drop_black_emission(&mut wired.layers);
        wired.stats.nodes.push(("fold", count_used(&live, &wired.layers)));
        wired.stats.layers_pruned = prune_hidden_layers(&mut wired.layers);
    } else {
        fold_masks(lib, &live, &mut wired.layers);
    }
    wired.nodes = eliminate_dead_nodes(live, &mut wired.layers);
    wired.stats.nodes.push(("dce", wired.nodes.len()));
    wired
}

struct Builder<'a> {
    lib: &'a Library,
    nodes: Vec<Node>,
    diags: &'a mut Diagnostics,
    /// Live inputs become [`Operand::Param`]s.
    live: bool,
    /// The next parameter word: references are visited in
    /// [`ComposedMaterial::references_in_order`].
    next_param: u32,
}

/// The operands that a graph instance's exposed inputs resolve to.
struct Instance {
    /// Node index in the graph → wired node.
    nodes: Vec<NodeId>,
    /// Exposed input index → operand.
    inputs: Vec<Operand>,
}

impl Builder<'_> {
    /// Instantiates a graph's nodes. `inputs` gives the operand of each exposed input.
    fn instantiate(&mut self, graph: &Graph, slot: &str, layer: usize, inputs: Vec<Operand>) -> Instance {
        let base = self.nodes.len() as u32;
        let ids: Vec<NodeId> = (0..graph.nodes.len() as u32).map(|i| NodeId(base + i)).collect();
        let instance = Instance { nodes: ids, inputs };
        for node in &graph.nodes {
            let args =
                node.args.iter().map(|a| a.as_ref().map_or(Operand::Default, |s| operand(&instance, s))).collect();
            self.nodes.push(Node { func: node.func, label: format!("{slot}/{}", node.name), args, layer });
        }
        instance
    }

    /// The operands of a material's exposed inputs: scene values, else defaults; live inputs
    /// are parameters, numbered on from the previous reference's.
    fn input_values(&mut self, graph: &Graph, material: &MaterialRef) -> Vec<Operand> {
        let mut operands = Vec::with_capacity(graph.inputs.len());
        for (i, input) in graph.inputs.iter().enumerate() {
            let value = material.input_value(graph, i);
            let words = if self.live { crate::compose::live_input_words(graph, i, value) } else { 0 };
            operands.push(if words > 0 {
                let offset = self.next_param;
                self.next_param += words as u32;
                Operand::Param { offset, ty: input.ty }
            } else {
                Operand::Const(value.clone(), input.ty)
            });
        }
        operands
    }

    fn layer(
        &mut self,
        index: usize,
        slot: &str,
        substance: &MaterialRef,
        overrides: &[(String, &MaterialRef)],
    ) -> Layer {
        let lib = self.lib;
        let graph = lib.get(substance.graph);
        let mut inputs = self.input_values(graph, substance);
        // Every override's inputs, numbered before any is skipped (the block's order).
        let mut all_over_inputs: Vec<Vec<Operand>> =
            overrides.iter().map(|(_, over)| self.input_values(lib.get(over.graph), over)).collect();
        let mut channels = Vec::new();
        // Overrides in ascending slot order: a later (higher) one replaces an earlier connection.
        for (k, (over_slot, over)) in overrides.iter().enumerate() {
            let og = lib.get(over.graph);
            if og.kind != GraphKind::Override {
                self.diags.push(
                    Diagnostic::error(format!(
                        "`{}` is bound to override slot `{over_slot}` but `{}` is a substance",
                        over.path, og.name
                    ))
                    .at(over.span, "bound here")
                    .also(og.span, "declared as a substance"),
                );
                continue;
            }
            let over_inputs = std::mem::take(&mut all_over_inputs[k]);
            let instance = self.instantiate(og, over_slot, index, over_inputs);
            for output in &og.outputs {
                let Some((i, input)) = graph.input(&output.name) else {
                    // An override output drives only a same-named input (DESIGN.md rule 3):
                    // one that names none does nothing, which is almost always a typo.
                    let mut d = Diagnostic::warning(format!(
                        "override `{}` output `{}` matches no input of substance `{}`: it does nothing",
                        og.name, output.name, graph.name
                    ))
                    .at(output.span, "drives nothing")
                    .also(over.span, format!("bound to slot `{over_slot}` here"));
                    if let Some(hint) = did_you_mean(&output.name, graph.inputs.iter().map(|i| i.name.as_str())) {
                        d = d.note(hint);
                    }
                    self.diags.push(d);
                    continue;
                };
                if !output.ty.converts_to(input.ty) {
                    self.diags.push(
                        Diagnostic::error(format!(
                            "override `{}` output `{}` is {}, but input `{}` of substance `{}` is {}",
                            og.name, output.name, output.ty, input.name, graph.name, input.ty
                        ))
                        .at(output.span, format!("this is {}", output.ty))
                        .also(input.span, format!("the input is {}", input.ty))
                        .also(over.span, format!("bound to slot `{over_slot}` here")),
                    );
                    continue;
                }
                inputs[i] = match operand(&instance, &output.source) {
                    Operand::Const(v, t) => Operand::Const(v.convert(t, input.ty), input.ty),
                    other => other,
                };
            }
            // Override nodes that connect nowhere (custom channels) join the layer.
            channels.extend(self.channels(og, &instance));
        }
        let instance = self.instantiate(graph, slot, index, inputs);
        let mut sub_channels = self.channels(graph, &instance);
        sub_channels.append(&mut channels);
        let product = |p: Product| graph.products.iter().find(|b| b.product == p);
        let displacement_bound = product(Product::Displacement).and_then(|b| {
            let bound = b.bound.as_ref()?;
            match operand(&instance, bound) {
                Operand::Const(v, _) if v.as_f32().is_some_and(|x| x >= 0.0 && x.is_finite()) => v.as_f32(),
                Operand::Const(v, _) => {
                    self.diags.push(
                        Diagnostic::error(format!(
                            "layer `{slot}` (`{}`): the displacement bound must be a finite number ≥ 0, found {v}",
                            substance.path
                        ))
                        .at(b.span, "displacement bound here")
                        .note("the bound is the largest |height| the layer may reach; dicing clamps heights to it"),
                    );
                    None
                }
                _ => {
                    self.diags.push(
                        Diagnostic::error(format!(
                            "layer `{slot}` (`{}`): an override drives the displacement bound with a node; \
                             it must be a constant (dicing needs it before shading)",
                            substance.path
                        ))
                        .at(b.span, "displacement bound here"),
                    );
                    None
                }
            }
        });
        Layer {
            slot: slot.to_string(),
            substance: graph.name.clone(),
            material: substance.path.clone(),
            overrides: overrides.iter().map(|(s, m)| (s.clone(), m.path.clone())).collect(),
            surface: product(Product::Surface).map(|b| operand(&instance, &b.source)),
            displacement: product(Product::Displacement)
                .map(|b| (operand(&instance, &b.source), b.mode.unwrap_or(DisplacementMode::Add))),
            displacement_bound,
            normal: product(Product::Normal).map(|b| operand(&instance, &b.source)),
            mask: product(Product::Mask).map(|b| operand(&instance, &b.source)),
            emission: product(Product::Emission).map(|b| operand(&instance, &b.source)),
            channels: sub_channels,
            pruned: None,
        }
    }

    /// Lays vertical layer `top` over horizontal layer `base` (DESIGN.md rule 3b): `base`'s
    /// surface becomes the prelude's `vertical_layer(base, top, coverage)`, which is
    /// `layer(top · m, base)` — equal to `mix(base, layer(top, base), m)` because a top's
    /// weight is linear in both layer modes, without repeating the base's closure terms. The
    /// top's channels join the layer (sampled with it, rule 7); its displacement is ignored
    /// (composition reports it); a normal or emission it has is reported and ignored.
    fn lay_over(&mut self, index: usize, base: &mut Layer, top: Layer, binding: Span) {
        base.channels.extend(top.channels);
        for (what, present) in [("normal", top.normal.is_some()), ("emission", top.emission.is_some())] {
            if present {
                self.diags.push(
                    Diagnostic::warning(format!(
                        "vertical layer `{}` (`{}`) has a {what}, which strata does not render on a vertical layer yet: ignored",
                        top.slot, top.material
                    ))
                    .kind("vertical layer product ignored")
                    .at(binding, "bound here"),
                );
            }
        }
        let Some(top_surface) = top.surface else { return };
        let Some(base_surface) = base.surface.take() else {
            self.diags.push(
                Diagnostic::warning(format!(
                    "vertical layer `{}` lies on slot `{}`, whose substance `{}` has no surface: ignored",
                    top.slot, base.slot, base.substance
                ))
                .kind("vertical layer without a surface below")
                .at(binding, "bound here"),
            );
            return;
        };
        let Some(&func) = self.lib.shaders.get("vertical_layer") else {
            self.diags.push(Diagnostic::error(
                "internal compiler error: the built-in library has no `vertical_layer` to lay vertical slots with",
            ));
            base.surface = Some(base_surface);
            return;
        };
        let function = self.lib.function(func);
        let mut args = vec![Operand::Default; function.params.len()];
        let coverage = top.mask.unwrap_or(Operand::Const(Value::Float(1.0), Type::FLOAT));
        for (name, operand) in [("base", base_surface), ("top", top_surface), ("coverage", coverage)] {
            if let Some((i, _)) = function.param(name) {
                args[i] = operand;
            }
        }
        let output = function.param("bsdf").map_or(0, |(i, _)| i);
        let id = NodeId(self.nodes.len() as u32);
        self.nodes.push(Node { func, label: format!("{}/vertical", top.slot), args, layer: index });
        base.surface = Some(Operand::Node { node: id, param: output });
    }

    fn channels(&self, graph: &Graph, instance: &Instance) -> Vec<Channel> {
        graph
            .channels
            .iter()
            .map(|(node, kind, name)| {
                let id = instance.nodes[*node];
                let wired = &self.nodes[id.0 as usize];
                let func = self.lib.function(wired.func);
                let (param, p) = func.param("value").expect("custom channel node types have a `value` input");
                Channel { name: name.clone(), kind: *kind, value: wired.args[param].clone(), ty: p.ty }
            })
            .collect()
    }
}

fn operand(instance: &Instance, source: &Source) -> Operand {
    match source {
        Source::Const(v, t) => Operand::Const(v.clone(), *t),
        Source::Input(i) => instance.inputs[*i].clone(),
        Source::Node { node, param } => Operand::Node { node: instance.nodes[*node], param: *param },
    }
}

/// Calls `f` on every root operand of the layers.
fn for_each_root(layers: &mut [Layer], mut f: impl FnMut(&mut Operand)) {
    for layer in layers {
        for op in [&mut layer.surface, &mut layer.normal, &mut layer.mask, &mut layer.emission].into_iter().flatten() {
            f(op);
        }
        if let Some((op, _)) = &mut layer.displacement {
            f(op);
        }
        for channel in &mut layer.channels {
            f(&mut channel.value);
        }
    }
}

/// Evaluates nodes whose inputs are all constant and whose body reads no globals, and replaces
/// their outputs by constants. Nodes are visited once each, producers before their users (a
/// graph may declare a node before the nodes it reads), so a folded output reaches every
/// reader in the same pass.
fn fold_constants(lib: &Library, nodes: &mut [Option<Node>], layers: &mut [Layer]) {
    let mut folded: HashMap<(NodeId, usize), (Value, Type)> = HashMap::new();
    for index in dependency_order(nodes) {
        let Some(node) = &mut nodes[index] else { continue };
        for arg in &mut node.args {
            substitute(arg, &folded);
        }
        let func = lib.function(node.func);
        if func.varying || func.outputs().next().is_none() {
            continue;
        }
        let mut inputs = Vec::with_capacity(func.params.len());
        let mut constant = true;
        for ((_, param), arg) in func.params.iter().enumerate().zip(&node.args) {
            match arg {
                _ if param.output => inputs.push(None),
                Operand::Const(v, t) => inputs.push(Some(v.convert(*t, param.ty))),
                Operand::Default if param.default.as_ref().is_none_or(|d| matches!(d.kind, ExprKind::Const(_))) => {
                    inputs.push(None)
                }
                _ => {
                    constant = false;
                    break;
                }
            }
        }
        if !constant {
            continue;
        }
        let Some(values) = eval_node(lib, func, &inputs) else { continue };
        let id = NodeId(index as u32);
        for (param, p) in func.outputs() {
            // Closures have no constant form; non-finite results stay for run time so the
            // renderer's NaN guard sees them.
            if p.ty != Type::CLOSURE && values[param].is_finite() {
                folded.insert((id, param), (values[param].clone(), p.ty));
            }
        }
    }
    for_each_root(layers, |op| substitute(op, &folded));
}

/// Replaces each mask that folds to a constant by that constant, leaving every other node
/// and product as it is. Which layers can be seen and which displacement moves geometry
/// ([`layering::liveness`]) is decided from the constant masks, so an unoptimised build must
/// know the same constants as an optimised one: a literal `mask(opacity: 1.0)` is a constant
/// at every optimisation level, and optimising never changes what is diced or picked.
fn fold_masks(lib: &Library, nodes: &[Option<Node>], layers: &mut [Layer]) {
    if layers.iter().all(|l| !matches!(l.mask, Some(Operand::Node { .. }))) {
        return;
    }
    let mut scratch_nodes = nodes.to_vec();
    let mut folded = layers.to_vec();
    fold_constants(lib, &mut scratch_nodes, &mut folded);
    for (layer, folded) in layers.iter_mut().zip(folded) {
        if let Some(mask @ Operand::Const(..)) = folded.mask {
            layer.mask = Some(mask);
        }
    }
}

/// Every node index, each after the nodes its arguments read (iterative depth-first search;
/// a cycle, already reported by the graph checker, is cut where it closes).
fn dependency_order(nodes: &[Option<Node>]) -> Vec<usize> {
    let mut order = Vec::with_capacity(nodes.len());
    let mut state = vec![0u8; nodes.len()]; // 0 unseen, 1 on the stack, 2 emitted
    for root in 0..nodes.len() {
        if state[root] != 0 {
            continue;
        }
        state[root] = 1;
        let mut stack = vec![(root, 0usize)];
        while let Some((node, next)) = stack.last_mut() {
            let node = *node;
            let args = nodes[node].as_ref().map(|n| n.args.as_slice()).unwrap_or(&[]);
            match args.get(*next) {
                Some(arg) => {
                    *next += 1;
                    if let Operand::Node { node: dep, .. } = arg
                        && let Some(s) = state.get_mut(dep.0 as usize)
                        && *s == 0
                    {
                        *s = 1;
                        stack.push((dep.0 as usize, 0));
                    }
                }
                None => {
                    state[node] = 2;
                    order.push(node);
                    stack.pop();
                }
            }
        }
    }
    order
}

fn substitute(op: &mut Operand, folded: &HashMap<(NodeId, usize), (Value, Type)>) {
    if let Operand::Node { node, param } = op
        && let Some((v, t)) = folded.get(&(*node, *param))
    {
        *op = Operand::Const(v.clone(), *t);
    }
}

fn count_used(nodes: &[Option<Node>], layers: &[Layer]) -> usize {
    let mut layers = layers.to_vec();
    let live: Vec<Option<Node>> = nodes.to_vec();
    eliminate_dead_nodes(live, &mut layers).len()
}

/// Removes emission that is a constant no brighter than black (the renderer clamps emission
/// at 0): such a layer has no emission entry and the integrator never asks it, so a material
/// that does not glow costs nothing. Literal black goes in every mode, folded black only
/// after folding; both render alike.
fn drop_black_emission(layers: &mut [Layer]) {
    for layer in layers {
        if let Some(Operand::Const(v, t)) = &layer.emission {
            let black = match v.convert(*t, Type::COLOR) {
                Value::Triple(c) => c.iter().all(|&x| x <= 0.0),
                _ => false,
            };
            if black {
                layer.emission = None;
            }
        }
    }
}

/// Removes what no rule can observe ([`layering::liveness`]): the surface, normal and channels
/// of layers that can never be picked (no surface, a constant zero mask, hidden under a
/// constant-opaque surface), displacement replaced by a constant-opaque `mix` layer above or
/// weighted by a constant zero mask. Masks stay: they are products of the ABI (a C caller of
/// a shader object may read any), and the renderer evaluates only those `layering` reads.
/// Returns the number of layers whose shading was removed.
fn prune_hidden_layers(layers: &mut [Layer]) -> usize {
    let infos: Vec<LayerInfo> = layers.iter().map(Layer::info).collect();
    let live = layering::liveness(&infos);
    let mut pruned = 0;
    for (layer, live) in layers.iter_mut().zip(live) {
        // A layer that has a surface but can never be picked loses what is read only where it
        // is picked. A layer without a surface keeps its normal and channels: the renderer
        // never reads them, but they are products of a substance compiled on its own.
        let why = match &live.unpickable {
            Some(Unpickable::HiddenUnder(above)) => Some(Pruned::HiddenUnder(infos[*above].slot.clone())),
            Some(Unpickable::MaskZero) => Some(Pruned::MaskZero),
            Some(Unpickable::NoSurface) | None => None,
        };
        if let Some(why) = why {
            pruned += 1;
            layer.surface = None;
            layer.normal = None;
            layer.emission = None;
            layer.channels.clear();
            layer.pruned = Some(why);
        }
        if !live.displacement {
            layer.displacement = None;
        }
    }
    pruned
}

/// Keeps the nodes reachable from products and channels, in topological order, and renumbers.
fn eliminate_dead_nodes(mut nodes: Vec<Option<Node>>, layers: &mut [Layer]) -> Vec<Node> {
    let mut order: Vec<NodeId> = Vec::new();
    let mut state = vec![0u8; nodes.len()]; // 0 unseen, 1 on stack, 2 emitted
    let mut roots = Vec::new();
    for_each_root(layers, |op| {
        if let Operand::Node { node, .. } = op {
            roots.push(*node);
        }
    });
    for root in roots {
        // Iterative post-order DFS (graphs were checked acyclic; `1` guards anyway).
        let mut stack = vec![(root, 0usize)];
        while let Some((node, next)) = stack.pop() {
            let i = node.0 as usize;
            if next == 0 {
                if state[i] != 0 {
                    continue;
                }
                state[i] = 1;
            }
            let args = nodes[i].as_ref().map(|n| n.args.as_slice()).unwrap_or(&[]);
            let dep = args[next..]
                .iter()
                .position(|a| matches!(a, Operand::Node { node, .. } if state[node.0 as usize] == 0));
            match dep {
                Some(offset) => {
                    let Operand::Node { node: d, .. } = args[next + offset] else { unreachable!() };
                    stack.push((node, next + offset + 1));
                    stack.push((d, 0));
                }
                None => {
                    state[i] = 2;
                    order.push(node);
                }
            }
        }
    }
    let mut remap = vec![None; nodes.len()];
    let mut out = Vec::with_capacity(order.len());
    for old in order {
        remap[old.0 as usize] = Some(NodeId(out.len() as u32));
        out.push(nodes[old.0 as usize].take().expect("each node is emitted once"));
    }
    let fix = |op: &mut Operand| {
        if let Operand::Node { node, .. } = op {
            *node = remap[node.0 as usize].expect("live operands point at live nodes");
        }
    };
    for node in &mut out {
        node.args.iter_mut().for_each(fix);
    }
    for_each_root(layers, fix);
    out
}

/// The union of channel names over layers; one name must mean one kind.
fn collect_channels(layers: &[Layer], diags: &mut Diagnostics) -> Vec<(String, ChannelKind)> {
    let mut channels: BTreeMap<String, ChannelKind> = BTreeMap::new();
    for layer in layers {
        for channel in &layer.channels {
            match channels.get(&channel.name) {
                Some(kind) if *kind != channel.kind => diags.push(Diagnostic::error(format!(
                    "custom channel `{}` is {:?} in one layer and {:?} in layer `{}`",
                    channel.name, kind, channel.kind, layer.slot
                ))),
                _ => {
                    channels.insert(channel.name.clone(), channel.kind);
                }
            }
        }
    }
    channels.into_iter().collect()
}

impl WiredMaterial {
    /// Checks the invariants lowering relies on: nodes in topological order (operands point at
    /// earlier nodes, at output parameters), one operand per parameter, operand types that
    /// convert to the port types, and products and channels of the right types. Lowering runs
    /// it first; a failure is a compiler bug, reported instead of miscompiled.
    pub fn validate(&self, lib: &Library) -> Result<(), String> {
        let check = |op: &Operand, to: Type, before: usize, what: &dyn Fn() -> String| -> Result<(), String> {
            let from = match op {
                Operand::Const(_, t) | Operand::Param { ty: t, .. } => *t,
                Operand::Default => return Ok(()),
                Operand::Node { node, param } => {
                    let n = node.0 as usize;
                    if n >= before {
                        return Err(format!("{}: reads %{n}, which is not evaluated before it", what()));
                    }
                    let func = lib.function(self.nodes[n].func);
                    match func.params.get(*param) {
                        Some(p) if p.output => p.ty,
                        _ => return Err(format!("{}: reads %{n}.{param}, which is not an output", what())),
                    }
                }
            };
            if from.converts_to(to) { Ok(()) } else { Err(format!("{}: {from} does not convert to {to}", what())) }
        };
        for (i, node) in self.nodes.iter().enumerate() {
            let func = lib.function(node.func);
            if node.args.len() != func.params.len() {
                return Err(format!(
                    "%{i} `{}` has {} operands for {} parameters",
                    node.label,
                    node.args.len(),
                    func.params.len()
                ));
            }
            for (p, arg) in func.params.iter().zip(&node.args) {
                if p.output && *arg != Operand::Default {
                    return Err(format!("%{i} `{}` drives its output `{}`", node.label, p.name));
                }
                check(arg, p.ty, i, &|| format!("%{i} `{}` input `{}`", node.label, p.name))?;
            }
        }
        let n = self.nodes.len();
        for layer in &self.layers {
            let slot = &layer.slot;
            let roots = [
                (&layer.surface, Type::CLOSURE, "surface"),
                (&layer.normal, Type::NORMAL, "normal"),
                (&layer.mask, Type::FLOAT, "mask"),
                (&layer.emission, Type::COLOR, "emission"),
            ];
            for (op, ty, what) in roots {
                if let Some(op) = op {
                    check(op, ty, n, &|| format!("layer {slot} {what}"))?;
                }
            }
            if let Some((op, _)) = &layer.displacement {
                check(op, Type::FLOAT, n, &|| format!("layer {slot} displacement"))?;
            }
            for c in &layer.channels {
                check(&c.value, c.ty, n, &|| format!("layer {slot} channel {}", c.name))?;
            }
        }
        Ok(())
    }

    /// The stable text form pinned by snapshot tests.
    pub fn to_text(&self, lib: &Library) -> String {
        let mut out = String::new();
        let op = |o: &Operand| match o {
            Operand::Const(v, _) => v.to_string(),
            Operand::Node { node, param } => {
                let func = lib.function(self.nodes[node.0 as usize].func);
                format!("%{}.{}", node.0, func.params[*param].name)
            }
            Operand::Default => "default".to_string(),
            Operand::Param { offset, .. } => format!("param {offset}"),
        };
        let _ = writeln!(out, "material: {} layer(s), {} node(s)", self.layers.len(), self.nodes.len());
        for (name, kind) in &self.channels {
            let _ = writeln!(out, "channel {name}: {kind:?}");
        }
        for (index, layer) in self.layers.iter().enumerate() {
            let _ = writeln!(
                out,
                "layer {index} slot {} substance {} from {}",
                layer.slot,
                layer.substance,
                show_path(&layer.material)
            );
            for (slot, path) in &layer.overrides {
                let _ = writeln!(out, "  override {slot} from {path}");
            }
            if let Some(reason) = &layer.pruned {
                let _ = writeln!(out, "  pruned: {reason}");
            }
            for (id, node) in self.nodes.iter().enumerate().filter(|(_, n)| n.layer == index) {
                let func = lib.function(node.func);
                let args: Vec<String> = func
                    .params
                    .iter()
                    .zip(&node.args)
                    .filter(|(p, a)| !p.output && !matches!(a, Operand::Default))
                    .map(|(p, a)| format!("{}: {}", p.name, op(a)))
                    .collect();
                let _ = writeln!(out, "  %{id} = {} \"{}\" ({})", func.name, node.label, args.join(", "));
            }
            if let Some(s) = &layer.surface {
                let _ = writeln!(out, "  surface = {}", op(s));
            }
            if let Some((d, mode)) = &layer.displacement {
                match layer.displacement_bound {
                    Some(bound) => {
                        let _ = writeln!(out, "  displacement({}, bound {bound}) = {}", mode.name(), op(d));
                    }
                    None => {
                        let _ = writeln!(out, "  bump({}) = {}", mode.name(), op(d));
                    }
                }
            }
            if let Some(n) = &layer.normal {
                let _ = writeln!(out, "  normal = {}", op(n));
            }
            if let Some(m) = &layer.mask {
                let _ = writeln!(out, "  mask = {}", op(m));
            }
            if let Some(e) = &layer.emission {
                let _ = writeln!(out, "  emission = {}", op(e));
            }
            for c in &layer.channels {
                let _ = writeln!(out, "  channel {} = {}", c.name, op(&c.value));
            }
        }
        out
    }

    /// A one-line summary of the pass statistics.
    pub fn stats_line(&self) -> String {
        let passes: Vec<String> = self.stats.nodes.iter().map(|(p, n)| format!("{p} {n}")).collect();
        format!("nodes: {}; layers pruned: {}", passes.join(" -> "), self.stats.layers_pruned)
    }
}

fn show_path(path: &str) -> &str {
    if path.is_empty() { "<builtin>" } else { path }
}

#[cfg(test)]
mod tests;
