//! The bridge from a composed USD stage to composition: reads slot-binding relationships into
//! a [`BindingTree`], finds each bound Material's strata shader (UsdShade source-asset
//! convention) and the input values it sets, and assembles one [`ComposedMaterial`] per
//! renderable prim.

use super::slots::{Binding, BindingPrim, BindingTree, PrimStack, SLOT_BINDING_PREFIX, decode_slot, resolve_stacks};
use super::{ComposedLayer, ComposedMaterial, MaterialRef};
use crate::diag::{Diagnostic, Diagnostics, SourceMap, Span};
use crate::front::ast::{BaseType, GraphKind};
use crate::front::library::Library;
use crate::front::types::{Type, Value};
use crate::scene::{Prim, PrimId, Stage, Value as UsdValue};
use std::collections::HashMap;
use std::path::PathBuf;

/// Prim types that are rendered, and so get a composed material.
pub const RENDERABLE_TYPES: &[&str] = &["Mesh", "Sphere", "Cube", "Cylinder"];

/// Whether a prim is renderable geometry.
pub fn is_renderable(prim: &Prim) -> bool {
    prim.type_name.as_deref().is_some_and(|t| RENDERABLE_TYPES.contains(&t))
}

/// Reads the slot bindings of every prim (depth first, parents before children).
pub fn binding_tree(stage: &Stage, diags: &mut Diagnostics) -> BindingTree {
    let mut tree = BindingTree::default();
    let mut index: HashMap<PrimId, usize> = HashMap::new();
    for (id, prim) in stage.depth_first() {
        let mut bindings = Vec::new();
        for rel in prim.relationships_with_prefix(SLOT_BINDING_PREFIX) {
            let encoded = &rel.name[SLOT_BINDING_PREFIX.len()..];
            let slot = match decode_slot(encoded) {
                Ok(slot) => slot,
                Err(message) => {
                    diags.push(
                        Diagnostic::error(format!("malformed slot binding `{}`: {message}", rel.name))
                            .at(rel.span, "here"),
                    );
                    continue;
                }
            };
            if rel.targets.len() > 1 {
                diags.push(
                    Diagnostic::warning(format!(
                        "slot binding `{}` has {} targets; the first is used",
                        rel.name,
                        rel.targets.len()
                    ))
                    .at(rel.span, "one material per slot"),
                );
            }
            let (material, span) = match rel.targets.first() {
                Some((path, span)) => (Some(path.clone()), *span),
                None => (None, rel.span),
            };
            bindings.push(Binding { slot, material, span });
        }
        let parent = prim.parent.and_then(|p| index.get(&p).copied());
        index.insert(id, tree.prims.len());
        tree.prims.push(BindingPrim { path: prim.path.clone(), parent, bindings, renderable: is_renderable(prim) });
    }
    tree
}

/// Where a Material prim's substance lives and which inputs it sets.
#[derive(Clone, Debug)]
struct MaterialSource {
    file: PathBuf,
    file_span: Span,
    graph_name: Option<String>,
    inputs: Vec<(String, UsdValue, String, Span)>,
}

/// Everything composition produced for a scene.
pub struct SceneComposition {
    /// Slot stacks of the renderable prims, in scene order.
    pub stacks: Vec<PrimStack>,
    /// Every substance file the scene uses, loaded and checked.
    pub library: Library,
    /// The distinct composed materials (DESIGN.md rule 8: identical compositions are shared).
    pub materials: Vec<ComposedMaterial>,
    /// For each entry of `stacks`, its index in `materials`.
    pub prim_material: Vec<usize>,
}

impl SceneComposition {
    /// The composed material of a renderable prim, by path.
    pub fn material_of(&self, prim: &str) -> Option<&ComposedMaterial> {
        let index = self.stacks.iter().position(|s| s.prim == prim)?;
        self.materials.get(self.prim_material[index])
    }
}

/// Resolves slot stacks, loads the bound substances and composes each renderable prim's
/// material. Errors are reported to `diags`; the result holds what could be composed.
pub fn compose_stage(stage: &Stage, sources: &mut SourceMap, diags: &mut Diagnostics) -> SceneComposition {
    let tree = binding_tree(stage, diags);
    let stacks = resolve_stacks(&tree, diags);
    // Find every material used, once.
    let mut found: HashMap<String, Option<MaterialSource>> = HashMap::new();
    for stack in &stacks {
        for layer in &stack.layers {
            let applied = std::iter::once(&layer.applied).chain(layer.overrides.iter().map(|o| &o.applied));
            for applied in applied {
                if !found.contains_key(&applied.material) {
                    let source = material_source(stage, &applied.material, applied.span, diags);
                    found.insert(applied.material.clone(), source);
                }
            }
        }
    }
    let mut files: Vec<(PathBuf, Span)> = found.values().flatten().map(|m| (m.file.clone(), m.file_span)).collect();
    files.sort_by(|a, b| a.0.cmp(&b.0));
    files.dedup_by(|a, b| a.0 == b.0);
    let library = Library::load(&files, sources, diags);

    let mut refs: HashMap<String, Option<MaterialRef>> = HashMap::new();
    let mut materials = Vec::new();
    let mut prim_material = Vec::with_capacity(stacks.len());
    let mut by_key: HashMap<String, usize> = HashMap::new();
    for stack in &stacks {
        let mut composed = ComposedMaterial::default();
        for layer in &stack.layers {
            let mut resolve = |path: &str, span: Span, kind: GraphKind, diags: &mut Diagnostics| {
                refs.entry(path.to_string())
                    .or_insert_with(|| {
                        let source = found.get(path).cloned().flatten()?;
                        material_ref(&library, path, &source, span, diags)
                    })
                    .clone()
                    .filter(|r| {
                        let graph = library.get(r.graph);
                        if graph.kind != kind {
                            let (want, got) = match kind {
                                GraphKind::Substance => ("a substance slot", "an override"),
                                GraphKind::Override => ("an override slot", "a substance"),
                            };
                            diags.push(
                                Diagnostic::error(format!("`{path}` is bound to {want} but `{}` is {got}", graph.name))
                                    .at(span, "bound here")
                                    .also(graph.span, "declared here"),
                            );
                            return false;
                        }
                        true
                    })
            };
            let Some(substance) = resolve(&layer.applied.material, layer.applied.span, GraphKind::Substance, diags)
            else {
                continue;
            };
            let mut overrides = Vec::new();
            for o in &layer.overrides {
                if let Some(r) = resolve(&o.applied.material, o.applied.span, GraphKind::Override, diags) {
                    overrides.push((o.slot.clone(), MaterialRef { span: o.applied.span, ..r }));
                }
            }
            composed.layers.push(ComposedLayer {
                slot: layer.slot.clone(),
                substance: MaterialRef { span: layer.applied.span, ..substance },
                overrides,
            });
        }
        let index = *by_key.entry(composed.identity_key()).or_insert_with(|| {
            materials.push(composed);
            materials.len() - 1
        });
        prim_material.push(index);
    }
    SceneComposition { stacks, library, materials, prim_material }
}

/// Finds the strata shader of a Material prim: a Shader (the prim itself or a descendant)
/// with `info:implementationSource = "sourceAsset"` and `info:strata:sourceAsset`.
fn material_source(stage: &Stage, path: &str, binding: Span, diags: &mut Diagnostics) -> Option<MaterialSource> {
    let Some(id) = stage.find(path) else {
        diags.push(
            Diagnostic::error(format!("slot binding targets `{path}`, which does not exist"))
                .at(binding, "no such prim"),
        );
        return None;
    };
    let material = stage.prim(id);
    let shader = stage.subtree(id).map(|(_, p)| p).find(|p| p.attribute("info:strata:sourceAsset").is_some());
    let Some(shader) = shader else {
        diags.push(
            Diagnostic::error(format!("`{path}` has no strata shader"))
                .at(material.span, "material prim")
                .also(binding, "bound here")
                .note("expected a Shader with `info:implementationSource = \"sourceAsset\"` and `asset info:strata:sourceAsset = @file.ash@`"),
        );
        return None;
    };
    let asset_attr = shader.attribute("info:strata:sourceAsset")?;
    let Some((UsdValue::Asset(asset), asset_span)) = asset_attr.value.clone() else {
        diags.push(
            Diagnostic::error("`info:strata:sourceAsset` must be an asset path (`@file.ash@`)")
                .at(asset_attr.span, "not an asset"),
        );
        return None;
    };
    if let Some(source) = shader.value("info:implementationSource").and_then(UsdValue::as_str)
        && source != "sourceAsset"
    {
        diags.push(
            Diagnostic::warning(format!(
                "`info:implementationSource` is \"{source}\"; strata reads the source asset anyway"
            ))
            .at(shader.span, "shader"),
        );
    }
    let graph_name =
        shader.value("info:strata:sourceAsset:subIdentifier").and_then(UsdValue::as_str).map(str::to_string);
    // Material-level interface inputs first, then the shader's own (which win when authored
    // with a value; a shader input connected to the material interface takes the interface value).
    let mut inputs: Vec<(String, UsdValue, String, Span)> = Vec::new();
    let mut push = |name: &str, value: UsdValue, ty: &str, span: Span| {
        inputs.retain(|(n, ..)| n != name);
        inputs.push((name.to_string(), value, ty.to_string(), span));
    };
    for prim in [material, shader] {
        for attr in &prim.attributes {
            let Some(name) = attr.name.strip_prefix("inputs:") else { continue };
            if let Some((value, span)) = &attr.value {
                push(name, value.clone(), &attr.type_name, *span);
            }
        }
    }
    Some(MaterialSource { file: asset.resolved.clone(), file_span: asset_span, graph_name, inputs })
}

fn material_ref(
    lib: &Library,
    path: &str,
    source: &MaterialSource,
    binding: Span,
    diags: &mut Diagnostics,
) -> Option<MaterialRef> {
    if lib.failed_to_load(&source.file) {
        return None; // already reported where the file is named
    }
    let graph = match &source.graph_name {
        Some(name) => lib.graph(&source.file, name).or_else(|| {
            diags.push(
                Diagnostic::error(format!("`{}` declares no substance or override `{name}`", source.file.display()))
                    .at(source.file_span, "named by this material")
                    .also(binding, "bound here"),
            );
            None
        })?,
        None => {
            let in_file: Vec<_> = lib
                .graphs
                .iter()
                .enumerate()
                .filter(|(i, _)| lib.graph_files[*i] == source.file.canonicalize().unwrap_or_default())
                .collect();
            match in_file.as_slice() {
                [(i, _)] => crate::front::library::GraphId(*i as u32),
                _ => {
                    diags.push(
                        Diagnostic::error(format!(
                            "`{path}` must name its graph with `info:strata:sourceAsset:subIdentifier`"
                        ))
                        .at(source.file_span, "the file declares several graphs (or none)"),
                    );
                    return None;
                }
            }
        }
    };
    let g = lib.get(graph);
    let mut values = Vec::new();
    for (name, value, usd_type, span) in &source.inputs {
        let Some((index, input)) = g.input(name) else {
            diags.push(
                Diagnostic::warning(format!("`{}` has no input `{name}`; the value set on `{path}` is unused", g.name))
                    .at(*span, "unused"),
            );
            continue;
        };
        match convert_input(value, usd_type, input.ty) {
            Ok(v) => values.push((index, v)),
            Err(message) => diags.push(
                Diagnostic::error(format!("input `{name}` of `{path}`: {message}"))
                    .at(*span, "this value")
                    .also(input.span, format!("declared as {}", input.ty)),
            ),
        }
    }
    Some(MaterialRef { path: path.to_string(), graph, values, span: binding })
}

/// The shading-language type a USD value type name corresponds to (`None`: any triple).
fn usd_type(name: &str) -> Result<Option<Type>, ()> {
    let base = name.trim_end_matches("[]");
    Ok(Some(match base {
        "float" | "double" | "half" => Type::FLOAT,
        "int" | "uint" | "int64" | "uint64" | "uchar" | "bool" => Type::INT,
        "string" | "token" | "asset" => Type::STRING,
        "color3f" | "color3d" | "color3h" => Type::COLOR,
        "point3f" | "point3d" | "point3h" => Type::POINT,
        "normal3f" | "normal3d" | "normal3h" => Type::NORMAL,
        "vector3f" | "vector3d" | "vector3h" => Type::VECTOR,
        "float3" | "double3" | "half3" => return Ok(None),
        _ => return Err(()),
    }))
}

/// Converts a scene value to a substance input's type, rejecting NaN, infinities and
/// incompatible types.
fn convert_input(value: &UsdValue, type_name: &str, to: Type) -> Result<Value, String> {
    let from = usd_type(type_name).map_err(|_| format!("USD type `{type_name}` cannot set a {to} input"))?;
    let compatible = match from {
        Some(from) => {
            from.converts_to(to)
                || (from.is_triple() && to.is_triple() && from.base != BaseType::Color && to.base != BaseType::Color)
        }
        None => to.is_triple(),
    };
    if !compatible {
        return Err(format!("a `{type_name}` value cannot set a {to} input"));
    }
    let finite = |x: f64| -> Result<f32, String> {
        let y = x as f32;
        if y.is_finite() { Ok(y) } else { Err(format!("value {x} is not finite")) }
    };
    let v = match value {
        UsdValue::Float(x) => Value::Float(finite(*x)?),
        UsdValue::Int(i) => Value::Int(i32::try_from(*i).map_err(|_| format!("{i} does not fit in 32 bits"))?),
        UsdValue::Bool(b) => Value::Int(*b as i32),
        UsdValue::String(s) | UsdValue::Token(s) => Value::Str(s.clone()),
        UsdValue::Asset(a) => Value::Str(a.resolved.display().to_string()),
        UsdValue::Tuple(t) if t.len() == 3 => Value::Triple([finite(t[0])?, finite(t[1])?, finite(t[2])?]),
        other => return Err(format!("expected a single {to}, found {}", other.describe())),
    };
    let from = match (&v, from) {
        (Value::Triple(_), None) => to,
        (Value::Float(_), _) => Type::FLOAT,
        (Value::Int(_), _) => Type::INT,
        (_, Some(t)) => t,
        (_, None) => to,
    };
    if from.is_triple() && to.is_triple() {
        return Ok(v);
    }
    if !from.converts_to(to) {
        return Err(format!("a {from} value cannot set a {to} input"));
    }
    Ok(v.convert(from, to))
}
