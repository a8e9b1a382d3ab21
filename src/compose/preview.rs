//! UsdShade preview networks (UsdPreviewSurface, UsdUVTexture, UsdPrimvarReader_*,
//! UsdTransform2d) as composed instances of the built-in `UsdPreviewSurface` substance
//! (`front/prelude.ash`).
//!
//! A Material whose `outputs:surface` connects to a Shader with `info:id = "UsdPreviewSurface"`
//! (through NodeGraphs and interface inputs, as UsdShade resolves connections: the same
//! [`producer`] walk that strata's own materials use) becomes a copy of the built-in graph in
//! which every input connected to another shader's output is driven by a node of that
//! shader's type instead of the exposed input. Values (authored, or reaching the shader through
//! interface inputs) set the exposed inputs, as for any substance. Networks of the same shape
//! share one graph, so identical materials still share one compiled material (DESIGN.md rule 8).

use super::MaterialRef;
use super::connect::{Producer, convert_input, producer};
use super::mtlx;
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::front::ast::Product;
use crate::front::graph::{Graph, NodeInstance, Source};
use crate::front::library::{GraphId, Library};
use crate::front::types::{Type, Value};
use crate::runtime::texture;
use crate::scene::{Attribute, Prim, PrimId, Stage, Value as UsdValue};
use std::borrow::Cow;
use std::collections::{HashMap, HashSet};

/// The built-in substance a preview network instantiates.
pub const PREVIEW_SUBSTANCE: &str = "UsdPreviewSurface";

/// Whether a Material is shaded by a UsdShade network rather than a strata source asset: no
/// shader below it names `info:strata:sourceAsset`, and it has an `outputs:surface`.
pub fn is_preview_material(stage: &Stage, id: PrimId) -> bool {
    let prim = stage.prim(id);
    (prim.attribute("outputs:surface").is_some() || prim.attribute("outputs:mtlx:surface").is_some())
        && !stage.subtree(id).any(|(_, p)| p.attribute("info:strata:sourceAsset").is_some())
}

/// Graphs already built for a scene, by network shape.
#[derive(Default)]
pub struct Shared {
    by_shape: HashMap<String, GraphId>,
    /// Shader ids already reported as not implemented (one warning per kind).
    reported: HashSet<String>,
}

/// Builds the composed `UsdPreviewSurface` instance of the Material at `path` (bound at
/// `binding`). `None`, after a warning, when the network has no UsdPreviewSurface: the layer
/// then falls back to the default substance.
pub fn instantiate(
    stage: &Stage,
    lib: &mut Library,
    shared: &mut Shared,
    path: &str,
    binding: Span,
    diags: &mut Diagnostics,
) -> Option<MaterialRef> {
    let material = stage.prim(stage.find(path)?);
    // A path tracer reads the MaterialX render context when it names a surface strata has,
    // else the universal one (UsdShade's `ComputeSurfaceSource(["mtlx"])`).
    let mtlx_surface = material.attribute("outputs:mtlx:surface").filter(|t| {
        let mut seen = Vec::new();
        let mut quiet = Diagnostics::new();
        matches!(producer(stage, material, t, true, &mut seen, &mut quiet),
            Some(Producer::Output(prim, _)) if info_id(prim).and_then(mtlx::surface_substance).is_some())
    });
    let terminal =
        mtlx_surface.or(material.attribute("outputs:surface")).or(material.attribute("outputs:mtlx:surface"))?;
    let mut seen = Vec::new();
    let surface = match producer(stage, material, terminal, true, &mut seen, diags) {
        Some(Producer::Output(prim, _)) => prim,
        _ => {
            diags.push(
                Diagnostic::warning(format!(
                    "`{path}.outputs:surface` connects to no shader; the default substance is used"
                ))
                .at(terminal.span, "this output")
                .also(binding, "bound here"),
            );
            return None;
        }
    };
    let id = info_id(surface);
    let Some(substance) = id.and_then(mtlx::surface_substance) else {
        diags.push(
            Diagnostic::warning(format!(
                "shader `{}` has `info:id = \"{}\"`, which strata does not implement; `{path}` falls back to the default substance",
                surface.path,
                id.unwrap_or("")
            ))
            .at(surface.attribute("info:id").map_or(surface.span, |a| a.span), "unknown shader")
            .also(binding, "bound here")
            .note("strata implements UsdPreviewSurface, open_pbr_surface and standard_surface (README, MaterialX)"),
        );
        return None;
    };
    let preview = substance == PREVIEW_SUBSTANCE;
    let template = lib.builtin_graph(substance)?;
    let mut builder =
        Builder { stage, lib, nodes: Vec::new(), memo: HashMap::new(), diags, reported: &mut shared.reported };
    let mut graph = lib.get(template).clone();
    let mut values: Vec<(usize, Value)> = Vec::new();
    // Inputs driven by nodes, and inputs set at all (normal and displacement products stay
    // only when something sets them: a bump of 0 costs the integrator a bump per hit).
    let mut driven: Vec<(usize, Source)> = Vec::new();
    // Closure ports driven by nodes: (template node, parameter, source).
    let mut ports: Vec<(usize, usize, Source)> = Vec::new();
    let mut set: Vec<String> = Vec::new();
    for attr in &surface.attributes {
        let Some(usd_name) = attr.name.strip_prefix("inputs:") else { continue };
        let name = match usd_name {
            "normal" if preview => Cow::Borrowed("normal_ts"),
            _ if preview => Cow::Borrowed(usd_name),
            _ => mtlx::port_name(usd_name),
        };
        let name = name.as_ref();
        if let Some((node, param)) = closure_port(builder.lib, &graph, name) {
            let mut seen = Vec::new();
            if let Some(Producer::Output(prim, output)) = producer(stage, surface, attr, true, &mut seen, builder.diags)
                && let Some((source, from)) = builder.output(prim, output, attr.span)
            {
                if from == Type::CLOSURE {
                    ports.push((node, param, source));
                } else {
                    builder.diags.push(
                        Diagnostic::error(format!(
                            "`{}` is {from} and cannot drive {substance}'s closure input `{usd_name}`",
                            attribute_path(prim, output)
                        ))
                        .at(attr.span, "connected here"),
                    );
                }
            }
            continue;
        }
        let Some((index, input)) = graph.input(name) else {
            let known = graph.inputs.iter().map(|i| match i.name.as_str() {
                "normal_ts" => "normal",
                n => n.strip_suffix('_').unwrap_or(n),
            });
            if let Some(d) = unknown_input(substance, usd_name, known, surface, attr) {
                builder.diags.push(d);
            }
            continue;
        };
        let ty = input.ty;
        let default = Some(input.default.clone());
        let mut seen = Vec::new();
        match producer(stage, surface, attr, true, &mut seen, builder.diags) {
            None => continue,
            Some(Producer::Value(prim, value_attr)) => {
                let Some((value, span)) = &value_attr.value else { continue };
                match node_value(value, &value_attr.type_name, ty).and_then(|v| in_working_space(v, value_attr)) {
                    Ok(v) => {
                        if !preview {
                            let setting = mtlx::Setting::Value(&v);
                            mtlx::report_surface_input(
                                substance,
                                usd_name,
                                setting,
                                default.as_ref(),
                                attr.span,
                                builder.diags,
                            );
                        }
                        values.push((index, v));
                        set.push(name.to_string());
                    }
                    Err(message) => builder.diags.push(
                        Diagnostic::error(format!("input `{}`: {message}", attribute_path(prim, value_attr)))
                            .at(*span, "this value"),
                    ),
                }
            }
            Some(Producer::Output(prim, output)) => {
                let Some((source, from)) = builder.output(prim, output, attr.span) else { continue };
                if !from.converts_to(ty) {
                    builder.diags.push(
                        Diagnostic::error(format!(
                            "`{}` is {from} and cannot drive {substance}'s {ty} input `{usd_name}`",
                            attribute_path(prim, output)
                        ))
                        .at(attr.span, "connected here"),
                    );
                    continue;
                }
                if !preview {
                    mtlx::report_surface_input(
                        substance,
                        usd_name,
                        mtlx::Setting::Driven,
                        None,
                        attr.span,
                        builder.diags,
                    );
                }
                driven.push((index, source));
                set.push(name.to_string());
            }
        }
    }
    // The network's nodes go after the template's, so template node indices stay valid.
    let offset = graph.nodes.len();
    let shift = |s: Source| match s {
        Source::Node { node, param } => Source::Node { node: node + offset, param },
        other => other,
    };
    for node in &mut builder.nodes {
        for arg in node.args.iter_mut().flatten() {
            *arg = shift(arg.clone());
        }
    }
    for (index, source) in driven {
        let source = shift(source);
        for arg in graph.nodes.iter_mut().flat_map(|n| n.args.iter_mut()) {
            if *arg == Some(Source::Input(index)) {
                *arg = Some(source.clone());
            }
        }
    }
    for (node, param, source) in ports {
        graph.nodes[node].args[param] = Some(shift(source));
    }
    graph.nodes.append(&mut builder.nodes);
    let keep = |p: Product| match p {
        Product::Normal => set.iter().any(|s| s == "normal_ts"),
        Product::Displacement => set.iter().any(|s| s == "displacement"),
        Product::Emission => set.iter().any(|s| s == "emissiveColor"),
        _ => true,
    };
    let keep = |p: Product| if preview { keep(p) } else { mtlx::keeps_product(substance, p, &set) };
    graph.products.retain(|p| keep(p.product));
    values.sort_by_key(|(i, _)| *i);
    let shape = format!(
        "{:?}|{:?}",
        graph.nodes.iter().map(|n| (n.func, &n.args)).collect::<Vec<_>>(),
        graph.products.iter().map(|p| p.product).collect::<Vec<_>>()
    );
    let graph_id = match shared.by_shape.get(&shape) {
        Some(id) => *id,
        None => {
            graph.name = format!("{substance}<{path}>");
            let id = lib.add_graph(graph);
            shared.by_shape.insert(shape, id);
            id
        }
    };
    Some(MaterialRef { path: path.to_string(), graph: graph_id, values, span: binding })
}

/// A closure port of a surface substance's template graph: the unset closure parameter `name`
/// of one of its nodes (a substance input cannot carry a closure: `mx_surface`'s `bsdf` is
/// its shell node's parameter).
fn closure_port(lib: &Library, graph: &Graph, name: &str) -> Option<(usize, usize)> {
    graph.nodes.iter().enumerate().find_map(|(n, node)| {
        let (param, p) = lib.function(node.func).param(name)?;
        (p.ty == Type::CLOSURE && !p.output && node.args[param].is_none()).then_some((n, param))
    })
}

/// A shader's `info:id`.
fn info_id(prim: &Prim) -> Option<&str> {
    prim.value("info:id").and_then(UsdValue::as_str)
}

/// `/Prim.name`.
fn attribute_path(prim: &Prim, attr: &Attribute) -> String {
    format!("{}.{}", prim.path, attr.name)
}

/// Converts a USD value for a node or substance input. USD's shading triples (color3f,
/// normal3f, float3, ...) all set `color` inputs, a float2 sets one with z = 0 and a float4
/// its first three components (the fourth goes to the `_a` input, see [`Builder::node`]).
fn node_value(value: &UsdValue, type_name: &str, to: Type) -> Result<Value, String> {
    if let UsdValue::Tuple(t) = value
        && to.is_triple()
    {
        let finite = |x: f64| {
            let y = x as f32;
            if y.is_finite() { Ok(y) } else { Err(format!("value {x} is not finite")) }
        };
        return match t.as_slice() {
            [x, y] => Ok(Value::Triple([finite(*x)?, finite(*y)?, 0.0])),
            [x, y, z] | [x, y, z, _] => Ok(Value::Triple([finite(*x)?, finite(*y)?, finite(*z)?])),
            _ => Err(format!("a {}-component value cannot set a {to} input", t.len())),
        };
    }
    convert_input(value, type_name, to)
}

/// A colour value authored with `colorSpace` metadata (MaterialX's `colorspace`), in the
/// working space (linear Rec.709).
fn in_working_space(value: Value, attr: &Attribute) -> Result<Value, String> {
    let Some(space) = attr.meta("colorSpace").and_then(UsdValue::as_str) else { return Ok(value) };
    match value {
        Value::Triple(c) if attr.type_name.starts_with("color") => {
            mtlx::to_working_space(space, c).map(Value::Triple).ok_or_else(|| format!("unknown colour space `{space}`"))
        }
        other => Ok(other),
    }
}

/// Builds the nodes of one network, each shader once.
struct Builder<'a, 's> {
    stage: &'s Stage,
    lib: &'a Library,
    /// Nodes in dependency order (indices local to this list).
    nodes: Vec<NodeInstance>,
    /// Shader prim path → its node (`None` while it is being built: a cycle).
    memo: HashMap<String, Option<usize>>,
    diags: &'a mut Diagnostics,
    /// Shader ids reported as not implemented, across the scene's networks.
    reported: &'a mut HashSet<String>,
}

/// Whether strata reads MaterialX space `space` (of a geometry node's `space`, a transform's
/// `fromspace`/`tospace`) as the document means it: world space (and "", the working space),
/// and object space, the prim's own (`render::geometry::primvars::OBJECT_TO_WORLD`). `model`
/// is read as object space, any other name as world space.
fn reads_space_as_authored(space: &str) -> bool {
    matches!(space, "" | "world" | "object")
}

impl<'s> Builder<'_, 's> {
    /// The source for output `output` of shader `prim`, and its type.
    fn output(&mut self, prim: &'s Prim, output: &Attribute, at: Span) -> Option<(Source, Type)> {
        let name = output.name.strip_prefix("outputs:").unwrap_or(&output.name);
        if info_id(prim) == Some("UsdPrimvarReader_string") {
            // Strings are constants when compiling: the reader gives its fallback.
            let fallback = prim.value("inputs:fallback").and_then(UsdValue::as_str).unwrap_or("");
            return Some((Source::Const(Value::Str(fallback.to_string()), Type::STRING), Type::STRING));
        }
        let node = self.node(prim, at)?;
        let func = self.lib.function(self.nodes[node].func);
        match func.param(name) {
            Some((param, p)) if p.output => Some((Source::Node { node, param }, p.ty)),
            _ => {
                self.diags.push(
                    Diagnostic::error(format!("`{}` has no output `{name}`", prim.path))
                        .at(output.span, "this output")
                        .also(at, "connected here"),
                );
                None
            }
        }
    }

    /// The node for shader `prim`, built on first use.
    fn node(&mut self, prim: &'s Prim, at: Span) -> Option<usize> {
        match self.memo.get(&prim.path) {
            Some(Some(node)) => return Some(*node),
            Some(None) => {
                self.diags.push(
                    Diagnostic::error(format!("connection cycle through shader `{}`", prim.path))
                        .at(at, "this connection closes the cycle"),
                );
                return None;
            }
            None => {}
        }
        let id = info_id(prim).unwrap_or("");
        let node_type = match id {
            "UsdUVTexture"
            | "UsdTransform2d"
            | "UsdPrimvarReader_float2"
            | "UsdPrimvarReader_float3"
            | "UsdPrimvarReader_float"
            | "UsdPrimvarReader_int" => id,
            "UsdPrimvarReader_normal" | "UsdPrimvarReader_point" | "UsdPrimvarReader_vector" => {
                "UsdPrimvarReader_float3"
            }
            _ if mtlx::preview_node(id).is_some() => {
                let node_type = mtlx::preview_node(id).unwrap_or(id);
                return self.instance(prim, id, node_type);
            }
            _ if id.starts_with("ND_") => {
                let function = mtlx::node_function(id).filter(|f| self.lib.shaders.contains_key(f.as_str()));
                let Some(function) = function else {
                    if self.reported.insert(id.to_string()) {
                        let mut d = Diagnostic::warning(format!(
                            "MaterialX node `{id}` is not implemented by strata; the inputs it drives take their own value or default"
                        ))
                        .at(prim.attribute("info:id").map_or(prim.span, |a| a.span), "unsupported node")
                        .also(at, "connected here");
                        if let Some(why) = why_unsupported(id) {
                            d = d.note(why);
                        }
                        self.diags.push(d.note("README, MaterialX, lists the nodes strata implements"));
                    }
                    return None;
                };
                mtlx::report_node(id, prim.attribute("info:id").map_or(prim.span, |a| a.span), self.diags);
                return self.instance(prim, id, &function);
            }
            _ => {
                self.diags.push(
                    Diagnostic::warning(format!(
                        "shader `{}` has `info:id = \"{id}\"`, which strata does not implement; its output is not connected",
                        prim.path
                    ))
                    .at(prim.attribute("info:id").map_or(prim.span, |a| a.span), "unknown shader")
                    .also(at, "connected here")
                    .note("the input takes its own authored value, else the default"),
                );
                return None;
            }
        };
        self.instance(prim, id, node_type)
    }

    /// The node of library function `node_type` for shader `prim` (of `info:id` `id`).
    fn instance(&mut self, prim: &'s Prim, id: &str, node_type: &str) -> Option<usize> {
        let func_id = *self.lib.shaders.get(node_type)?;
        self.memo.insert(prim.path.clone(), None);
        let func = self.lib.function(func_id);
        let mut args: Vec<Option<Source>> = vec![None; func.params.len()];
        for attr in &prim.attributes {
            let Some(usd_name) = attr.name.strip_prefix("inputs:") else { continue };
            let name = mtlx::port_name(usd_name);
            let name = name.as_ref();
            let func = self.lib.function(func_id);
            let Some((index, param)) = func.param(name).filter(|(_, p)| !p.output) else {
                let known = func.params.iter().filter(|p| !p.output).map(|p| p.name.as_str());
                let known = known.map(|n| n.strip_suffix('_').unwrap_or(n));
                if let Some(d) = unknown_input(id, usd_name, known, prim, attr) {
                    self.diags.push(d);
                }
                continue;
            };
            let ty = param.ty;
            // A 4-channel input's fourth channel (see `front/mtlx_color4.ash`).
            let alpha =
                func.param(&mtlx::port_name(&format!("{usd_name}_a"))).filter(|(_, p)| !p.output).map(|(i, _)| i);
            let image_file = name == "file" && func.param("decode").is_some();
            let mut seen = Vec::new();
            match producer(self.stage, prim, attr, true, &mut seen, self.diags) {
                None => {}
                Some(Producer::Value(vprim, vattr)) => {
                    let Some((value, span)) = &vattr.value else { continue };
                    if image_file {
                        self.image_colour_space(func_id, vattr, *span, &mut args);
                    }
                    match node_value(value, &vattr.type_name, ty).and_then(|v| in_working_space(v, vattr)) {
                        Ok(v) => {
                            self.check_token(id, name, &v, *span);
                            mtlx::report_node_input(id, usd_name, mtlx::Setting::Value(&v), attr.span, self.diags);
                            if let (Some(a), UsdValue::Float(x)) = (alpha, value)
                                && (*x as f32).is_finite()
                            {
                                // A float promotes to all four channels.
                                args[a] = Some(Source::Const(Value::Float(*x as f32), Type::FLOAT));
                            }
                            args[index] = Some(Source::Const(v, ty));
                            if let (Some(a), UsdValue::Tuple(t)) = (alpha, value)
                                && let [_, _, _, w] = t.as_slice()
                                && (*w as f32).is_finite()
                            {
                                args[a] = Some(Source::Const(Value::Float(*w as f32), Type::FLOAT));
                            }
                        }
                        Err(message) => self.diags.push(
                            Diagnostic::error(format!("input `{}`: {message}", attribute_path(vprim, vattr)))
                                .at(*span, "this value"),
                        ),
                    }
                }
                Some(Producer::Output(oprim, output)) => {
                    let Some((source, from)) = self.output(oprim, output, attr.span) else { continue };
                    if !from.converts_to(ty) {
                        self.diags.push(
                            Diagnostic::error(format!(
                                "`{}` is {from} and cannot drive the {ty} input `{}`",
                                attribute_path(oprim, output),
                                attribute_path(prim, attr)
                            ))
                            .at(attr.span, "connected here"),
                        );
                        continue;
                    }
                    mtlx::report_node_input(id, usd_name, mtlx::Setting::Driven, attr.span, self.diags);
                    if let Some(a) = alpha {
                        args[a] = self.alpha_of(&source, from, output);
                    }
                    args[index] = Some(source);
                }
            }
        }
        if id == "UsdUVTexture" || self.lib.function(func_id).param("decode").is_some() {
            self.load_texture(prim, func_id, &mut args);
        }
        let node = self.nodes.len();
        self.nodes.push(NodeInstance {
            name: prim.path.rsplit('/').next().unwrap_or("shader").to_string(),
            func: func_id,
            args,
            span: prim.span,
        });
        self.memo.insert(prim.path.clone(), Some(node));
        Some(node)
    }

    /// What drives the fourth channel of a 4-channel input connected to `source` (of type
    /// `from`, output `output`): a float fills all four channels; a 4-channel output carries
    /// its own in its `_a` output; any other output leaves the input's default.
    fn alpha_of(&self, source: &Source, from: Type, output: &Attribute) -> Option<Source> {
        if from == Type::FLOAT {
            return Some(source.clone());
        }
        let Source::Node { node, .. } = source else { return None };
        let name = output.name.strip_prefix("outputs:").unwrap_or(&output.name);
        let func = self.lib.function(self.nodes[*node].func);
        let (param, _) = func.param(&format!("{name}_a")).filter(|(_, p)| p.output && p.ty == Type::FLOAT)?;
        Some(Source::Node { node: *node, param })
    }

    /// Loads a UsdUVTexture's file now, so that a missing or broken image is reported at the
    /// USD attribute that names it (lowering would point into the built-in node, once per
    /// channel). The file is decoded once per process either way; after an error the node
    /// reads its fallback.
    fn load_texture(&mut self, prim: &Prim, func: crate::front::hir::FuncId, args: &mut [Option<Source>]) {
        let f = self.lib.function(func);
        let space = f.param("sourceColorSpace").or(f.param("decode"));
        let (Some((file_index, _)), Some((space_index, _))) = (f.param("file"), space) else {
            return;
        };
        let Some(Source::Const(Value::Str(file), _)) = &args[file_index] else { return };
        if file.is_empty() {
            return;
        }
        let space = match &args[space_index] {
            Some(Source::Const(Value::Str(s), _)) => texture::ColorSpace::parse(s),
            _ => Some(texture::ColorSpace::Auto),
        };
        let Some(space) = space else { return }; // reported by `check_token`
        if let Err(message) = texture::register_file_as(std::path::Path::new(file), space) {
            let span = prim.attribute("inputs:file").map_or(prim.span, |a| a.value.as_ref().map_or(a.span, |v| v.1));
            // USD composes around an unreadable texture: the reader's fallback, as usdview shows it.
            self.diags.push(
                Diagnostic::warning(message)
                    .at(span, "texture file named here")
                    .note("the texture reads its `fallback` value")
                    .kind("unreadable texture"),
            );
            args[file_index] = Some(Source::Const(Value::Str(String::new()), Type::STRING));
        }
    }

    /// Sets a MaterialX image node's `decode` and `colorspace` from the `colorSpace` of the
    /// attribute its file name comes from (MaterialX's `colorspace`; none is the working space).
    fn image_colour_space(
        &mut self,
        func: crate::front::hir::FuncId,
        file: &Attribute,
        span: Span,
        args: &mut [Option<Source>],
    ) {
        let space = file.meta("colorSpace").and_then(UsdValue::as_str).unwrap_or("");
        let f = self.lib.function(func);
        let (Some((decode, _)), Some((colorspace, _))) = (f.param("decode"), f.param("colorspace")) else { return };
        let Some((how, from)) = mtlx::texture_decode(space) else {
            self.diags.push(
                Diagnostic::warning(format!("unknown colour space `{space}`; the texture is read as linear"))
                    .at(span, "this texture")
                    .note("strata knows srgb_texture, lin_rec709, acescg, lin_ap1, g22_ap1, g22_rec709 and raw")
                    .kind("unknown MaterialX colour space"),
            );
            return;
        };
        args[decode] = Some(Source::Const(Value::Str(how.into()), Type::STRING));
        args[colorspace] = Some(Source::Const(Value::Str(from.into()), Type::STRING));
    }

    /// Checks the tokens whose meaning strata must know: colour spaces (an error: the texture
    /// would decode wrongly) and wrap modes (a warning: a documented fallback).
    fn check_token(&mut self, id: &str, input: &str, value: &Value, span: Span) {
        let Value::Str(token) = value else { return };
        match (id, input) {
            ("UsdUVTexture", "sourceColorSpace") if !matches!(token.as_str(), "auto" | "sRGB" | "raw") => {
                self.diags.push(
                    Diagnostic::error(format!("unknown sourceColorSpace `{token}`; expected `auto`, `sRGB` or `raw`"))
                        .at(span, "this value"),
                );
            }
            ("UsdUVTexture", "wrapS" | "wrapT")
                if !matches!(token.as_str(), "black" | "clamp" | "repeat" | "mirror" | "useMetadata") =>
            {
                self.diags.push(
                    Diagnostic::warning(format!("unknown wrap mode `{token}`; strata repeats"))
                        .at(span, "this value")
                        .note("UsdUVTexture's wrap modes: black, clamp, repeat, mirror, useMetadata"),
                );
            }
            (_, "filtertype") if token != "linear" => {
                self.diags.push(
                    Diagnostic::warning(format!("image `filtertype` `{token}` is read bilinear (as `linear`)"))
                        .at(span, "this value")
                        .kind("MaterialX filtertype approximated"),
                );
            }
            (_, "space" | "fromspace" | "tospace") if token == "model" => {
                self.diags.push(
                    Diagnostic::warning(format!("`{input}` `model` is read as object space"))
                        .at(span, "this value")
                        .note("model and object space agree for a prim that is its own model")
                        .kind("MaterialX space approximated"),
                );
            }
            (_, "space" | "fromspace" | "tospace") if !reads_space_as_authored(token) => {
                self.diags.push(
                    Diagnostic::warning(format!("`{input}` `{token}` is read as world space"))
                        .at(span, "this value")
                        .note("strata knows world, object and model (read as object) space")
                        .kind("MaterialX space approximated"),
                );
            }
            ("UsdUVTexture", "file") if token.contains("<UDIM>") => {
                self.diags.push(Diagnostic::error("UDIM texture sets are not supported").at(span, "a `<UDIM>` path"));
            }
            _ => {}
        }
    }
}

/// Why strata cannot implement MaterialX node `id`, where one reason covers a family of nodes.
fn why_unsupported(id: &str) -> Option<&'static str> {
    let (node, types) = mtlx::split_id(id)?;
    if types.contains("matrix") || types.ends_with("M3") || types.ends_with("M4") || node.contains("matrix") {
        return Some("matrices (matrix33, matrix44) are not a strata type: no value or connection can carry one");
    }
    (node == "heighttonormal")
        .then_some("it needs the screen-space derivatives of its height input, which strata's shading does not compute")
}

/// Inputs of the UsdPreviewSurface specification that strata reads no value from: authored,
/// they change what other renderers show, so they are worth a warning.
const UNSUPPORTED_SPEC_INPUTS: &[(&str, &str)] =
    &[("opacityMode", "opacity always acts as presence (opacityMode `presence`), never as transmission")];

/// What to say of an input a preview shader does not have. UsdShade's readers ignore inputs
/// outside a shader's definition, and exporters author plenty (`isSRGB`, `rgba`, ...), so
/// they raise nothing; a name one edit from a real input is likely a typo, and a spec input
/// strata does not implement changes the image: those are warnings, each kind once per run.
fn unknown_input<'a>(
    id: &str,
    usd_name: &str,
    known: impl IntoIterator<Item = &'a str>,
    prim: &Prim,
    attr: &Attribute,
) -> Option<Diagnostic> {
    if let Some((_, what)) = UNSUPPORTED_SPEC_INPUTS.iter().find(|(name, _)| *name == usd_name) {
        let message = format!("`{}` is not implemented: {what}", attribute_path(prim, attr));
        return Some(Diagnostic::warning(message).at(attr.span, "ignored input").kind("unsupported preview input"));
    }
    let suggestion = crate::diag::did_you_mean(usd_name, known)?;
    let message = format!("{id} has no input `{usd_name}`; `{}` is ignored", attribute_path(prim, attr));
    Some(Diagnostic::warning(message).at(attr.span, "unknown input").note(suggestion))
}

#[cfg(test)]
mod tests {
    use crate::abi::{Closure, ClosureKind, Globals};
    use crate::backend::{BackendKind, Compiler};
    use crate::compose::scene::compose_stage;
    use crate::diag::{Diagnostics, SourceMap};
    use crate::ir::wired::PassOptions;
    use crate::render::material::bsdf::Bsdf;
    use crate::render::sampling::Rng;
    use crate::scene::Stage;
    use glam::Vec3;
    use std::path::Path;

    /// The closure `/Ball`'s material (a UsdPreviewSurface with `inputs`, as USDA lines)
    /// evaluates to, and the rendered diagnostics.
    fn closure_of(inputs: &str) -> (Closure, String) {
        let (code, rendered) = compiled(inputs, "");
        let g = Globals { n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], ..Globals::default() };
        let mut closure = Closure::default();
        code.surface(&g, 0, &mut closure).expect("evaluates");
        (closure, rendered)
    }

    /// `/Ball`'s compiled material: a UsdPreviewSurface with `inputs` and more shaders
    /// (`shaders`, USDA) in the Material `/M`; and the rendered diagnostics.
    fn compiled(inputs: &str, shaders: &str) -> (std::sync::Arc<dyn crate::abi::MaterialCode>, String) {
        let text = format!(
            "#usda 1.0\ndef Sphere \"Ball\" {{ rel material:binding = </M> }}\n\
             def Material \"M\" {{\n    token outputs:surface.connect = </M/S.outputs:surface>\n    \
             def Shader \"S\" {{\n        uniform token info:id = \"UsdPreviewSurface\"\n{inputs}\n        \
             token outputs:surface\n    }}\n{shaders}\n}}\n"
        );
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("scene.usda", &text, Path::new("."), &mut sources, &mut diags).expect("parses");
        let c = compose_stage(&stage, &mut sources, &mut diags);
        let material = c.material_of("/Ball").expect("composed").clone();
        assert_eq!(material.layers.len(), 1, "{}", diags.render(&sources));
        let code = Compiler::new(BackendKind::Jit, PassOptions::default())
            .compile(&c.library, &material, &mut diags)
            .unwrap_or_else(|| panic!("{}", diags.render(&sources)));
        (code, diags.render(&sources))
    }

    #[test]
    fn opacity_is_the_layer_mask_and_a_threshold_cuts_out() {
        let g = Globals::default();
        let mask = |inputs: &str| compiled(inputs, "").0.mask(&g, 0).unwrap();
        assert_eq!(mask(""), 1.0);
        assert_eq!(mask("        float inputs:opacity = 0.25"), 0.25);
        assert_eq!(mask("        float inputs:opacity = 0.4\n        float inputs:opacityThreshold = 0.5"), 0.0);
        assert_eq!(mask("        float inputs:opacity = 0.6\n        float inputs:opacityThreshold = 0.5"), 1.0);
    }

    #[test]
    fn texture_alpha_scale_bias_and_wrap_reach_the_surface() {
        // checker.png's top-left cell is (255, 0, 0); alpha is 1 (RGB image). Opacity from
        // `a` · 0.5 + 0.25 = 0.75; roughness from `g` of the top-left cell (0) · 1 + 0.3.
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/usd/preview/checker.png");
        let shaders = format!(
            "    def Shader \"T\" {{\n        uniform token info:id = \"UsdUVTexture\"\n        \
             asset inputs:file = @{}@\n        float2 inputs:st.connect = </M/X.outputs:result>\n        \
             token inputs:wrapS = \"clamp\"\n        float4 inputs:scale = (1, 1, 1, 0.5)\n        \
             float4 inputs:bias = (0, 0.3, 0, 0.25)\n        float outputs:a\n        float outputs:g\n    }}\n    \
             def Shader \"X\" {{\n        uniform token info:id = \"UsdTransform2d\"\n        \
             float2 inputs:in = (0.35, 0.9)\n        float2 inputs:translation = (-3, 0)\n        \
             float2 outputs:result\n    }}",
            file.display()
        );
        let inputs = "        float inputs:opacity.connect = </M/T.outputs:a>\n        \
                      float inputs:roughness.connect = </M/T.outputs:g>\n        float inputs:metallic = 1";
        let (code, rendered) = compiled(inputs, &shaders);
        assert!(rendered.is_empty(), "{rendered}");
        let g = Globals::default();
        assert_eq!(code.mask(&g, 0).unwrap(), 0.75);
        let mut closure = Closure::default();
        code.surface(&g, 0, &mut closure).unwrap();
        // st = (0.35 − 3, 0.9): clamped along s to the left column, the red cell (g = 0); repeat
        // would read 0.35, the green cell (g = 1, roughness 1).
        assert_eq!(ClosureKind::from_u32(closure.kind), ClosureKind::Metal);
        assert!((closure.params[6] - 0.3).abs() < 1e-6, "{closure:?}");
    }

    /// The directional albedo ∫ f cos dωi of the largest channel for outgoing `wo`, estimated
    /// by BSDF sampling: (mean, standard error).
    fn albedo(b: &Bsdf, wo: Vec3, n: usize) -> (f64, f64) {
        let mut rng = Rng::new(17, (wo.z * 1000.0) as u64, 0);
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let uc = rng.uniform();
            let u = rng.uniform2();
            if let Some(s) = b.sample(wo, uc, u) {
                let w = (s.f.max_element() * s.wi.z.abs() / s.pdf) as f64;
                sum += w;
                sum2 += w * w;
            }
        }
        let mean = sum / n as f64;
        (mean, ((sum2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt())
    }

    #[test]
    fn white_furnace_metallic_clearcoat_and_specular_never_gain_energy() {
        let white = "        color3f inputs:diffuseColor = (1, 1, 1)\n";
        let cases = [
            (
                "metallic 1, smooth",
                format!("{white}        float inputs:metallic = 1\n        float inputs:roughness = 0.05"),
                ClosureKind::Metal,
            ),
            (
                "metallic 1, rough",
                format!("{white}        float inputs:metallic = 1\n        float inputs:roughness = 1"),
                ClosureKind::Metal,
            ),
            (
                "metallic 0.6",
                format!("{white}        float inputs:metallic = 0.6\n        float inputs:roughness = 0.4"),
                ClosureKind::Metal,
            ),
            (
                "clearcoat 1",
                format!("{white}        float inputs:clearcoat = 1\n        float inputs:roughness = 0.8"),
                ClosureKind::Glossy,
            ),
            (
                "clearcoat 1, ior 4",
                format!("{white}        float inputs:clearcoat = 1\n        float inputs:ior = 4"),
                ClosureKind::Glossy,
            ),
            (
                "specular workflow",
                format!(
                    "{white}        int inputs:useSpecularWorkflow = 1\n        color3f inputs:specularColor = (1, 1, 1)"
                ),
                ClosureKind::Glossy,
            ),
        ];
        let mut failures = Vec::new();
        for (name, inputs, kind) in &cases {
            let (closure, rendered) = closure_of(inputs);
            assert!(rendered.is_empty(), "{name}: {rendered}");
            assert_eq!(ClosureKind::from_u32(closure.kind), *kind, "{name}: {closure:?}");
            let b = Bsdf::from_closure(&closure);
            for cos in [0.05f32, 0.3, 0.7, 1.0] {
                let wo = Vec3::new((1.0 - cos * cos).sqrt(), 0.0, cos);
                let (e, se) = albedo(&b, wo, 40_000);
                if e > 1.0 + 4.0 * se + 1e-3 {
                    failures.push(format!("{name} at cos {cos}: reflects {e} ± {se} of what it receives"));
                }
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
    }

    #[test]
    fn preview_surface_maps_onto_strata_closures() {
        // Defaults: diffuseColor 0.18, roughness 0.5, ior 1.5, metallic 0 → coat over Lambert.
        let (c, rendered) = closure_of("");
        assert!(rendered.is_empty(), "{rendered}");
        assert_eq!(ClosureKind::from_u32(c.kind), ClosureKind::Glossy);
        assert_eq!(&c.params[..8], &[0.18, 0.18, 0.18, 1.0, 1.0, 1.0, 0.5, 1.5]);
        // Metallic 1: a conductor with the base colour at normal incidence.
        let (c, _) =
            closure_of("        color3f inputs:diffuseColor = (0.9, 0.6, 0.2)\n        float inputs:metallic = 1");
        assert_eq!(ClosureKind::from_u32(c.kind), ClosureKind::Metal);
        assert_eq!(&c.params[..7], &[0.9, 0.6, 0.2, 1.0, 1.0, 1.0, 0.5]);
        // Specular workflow: F0 = 0.04 is ior 1.5, untinted.
        let (c, _) = closure_of(
            "        int inputs:useSpecularWorkflow = 1\n        color3f inputs:specularColor = (0.04, 0.04, 0.04)",
        );
        assert_eq!(ClosureKind::from_u32(c.kind), ClosureKind::Glossy);
        assert!((c.params[7] - 1.5).abs() < 1e-5 && c.params[3] == 1.0, "{c:?}");
        // Clearcoat 1 moves the coat roughness to clearcoatRoughness.
        let (c, _) = closure_of("        float inputs:clearcoat = 1\n        float inputs:clearcoatRoughness = 0.1");
        assert!((c.params[6] - 0.1).abs() < 1e-6, "{c:?}");
    }

    #[test]
    fn emissive_color_drives_the_emission_product_and_black_costs_nothing() {
        let g = Globals { n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], ..Globals::default() };
        let (code, rendered) = compiled("        color3f inputs:emissiveColor = (1.5, 0.25, 0)", "");
        assert!(!rendered.contains("emissiveColor"), "emission is read, not warned about: {rendered}");
        assert!(code.info().layers[0].has_emission);
        let mut e = [0.0; 3];
        code.emission(&g, 0, &mut e).unwrap();
        assert_eq!(e, [1.5, 0.25, 0.0]);
        // Black, authored or not, leaves no emission entry: the integrator never asks.
        for inputs in ["", "        color3f inputs:emissiveColor = (0, 0, 0)"] {
            assert!(!compiled(inputs, "").0.info().layers[0].has_emission, "{inputs:?}");
        }
        // A texture drives it through the network like any input.
        let texture = "        color3f inputs:emissiveColor.connect = </M/T.outputs:rgb>";
        let shaders = "    def Shader \"T\" {\n        uniform token info:id = \"UsdUVTexture\"\n        \
                       float4 inputs:fallback = (0.5, 0.75, 1, 1)\n        float3 outputs:rgb\n    }";
        let (code, rendered) = compiled(texture, shaders);
        assert!(code.info().layers[0].has_emission, "{rendered}");
        code.emission(&g, 0, &mut e).unwrap();
        assert_eq!(e, [0.5, 0.75, 1.0], "{rendered}");
    }
}
