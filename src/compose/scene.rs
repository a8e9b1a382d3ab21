//! The bridge from a composed USD stage to composition: reads slot-binding relationships into
//! a [`BindingTree`](super::slots::BindingTree), finds each bound Material's strata shader (UsdShade source-asset
//! convention) and the input values it sets (its own, or through `.connect` the Material's
//! interface inputs, as UsdShade resolves them), and assembles one [`ComposedMaterial`] per
//! renderable prim.

use super::binding::binding_tree;
use super::connect::{attribute_path, convert_input, value_producer};
use super::slots::{LayerBinding, PrimStack, SlotFilter, resolve_stacks};
use super::{ComposedLayer, ComposedMaterial, DisplayPrimvars, MaterialRef, preview};
use crate::diag::{Diagnostic, Diagnostics, OncePerKind, SourceMap, Span, did_you_mean};
use crate::front::ast::{GraphKind, Product};
use crate::front::library::{GraphId, Library};
use crate::front::types::Value;
use crate::scene::{Stage, Value as UsdValue};
use std::collections::HashMap;
use std::path::PathBuf;

/// Where a Material prim's substance lives and which inputs it sets.
#[derive(Clone, Debug)]
struct MaterialSource {
    file: PathBuf,
    file_span: Span,
    graph_name: Option<String>,
    inputs: Vec<InputValue>,
    /// Interface inputs of the Material with a value that no connection reaches: (name, USD
    /// type, span).
    unconnected: Vec<(String, String, Span)>,
}

/// The value a Material sets on one shader input.
#[derive(Clone, Debug)]
struct InputValue {
    /// The input's name, without `inputs:`.
    name: String,
    value: UsdValue,
    /// The USD type of the attribute that holds the value.
    type_name: String,
    /// The value's text.
    span: Span,
    /// The shader input's connection, when the value comes through one.
    connected: Option<Span>,
}

/// Everything composition produced for a scene.
pub struct SceneComposition {
    /// Slot stacks of the renderable prims, in scene order, as bound (a [`SlotFilter`]
    /// changes the materials, not the stacks).
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
    compose_stage_filtered(stage, &SlotFilter::default(), sources, diags)
}

/// [`compose_stage`] with the layers `filter` hides left out of the materials (a live view's
/// mute and solo); the stacks stay as bound.
pub fn compose_stage_filtered(
    stage: &Stage,
    filter: &SlotFilter,
    sources: &mut SourceMap,
    diags: &mut Diagnostics,
) -> SceneComposition {
    let tree = binding_tree(stage, diags);
    let stacks = resolve_stacks(&tree, diags);
    // Find every material used, once.
    let mut found: HashMap<String, Option<MaterialSource>> = HashMap::new();
    // Materials shaded by a UsdShade preview network (`compose::preview`), with the first
    // binding that uses each.
    let mut previews: Vec<(String, Span)> = Vec::new();
    let mut preview_paths: std::collections::HashSet<String> = std::collections::HashSet::new();
    for stack in &stacks {
        for layer in stack.layers.iter().flat_map(|l| std::iter::once(l).chain(&l.vertical)) {
            let applied = std::iter::once(&layer.applied).chain(layer.overrides.iter().map(|o| &o.applied));
            for applied in applied {
                if stage.find(&applied.material).is_some_and(|id| preview::is_preview_material(stage, id)) {
                    if preview_paths.insert(applied.material.clone()) {
                        previews.push((applied.material.clone(), applied.span));
                    }
                    continue;
                }
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
    let mut library = Library::load(&files, sources, diags);

    let mut refs: HashMap<String, Option<MaterialRef>> = HashMap::new();
    let mut shared = preview::Shared::default();
    for (path, span) in previews {
        let instance = preview::instantiate(stage, &mut library, &mut shared, &path, span, diags);
        refs.insert(path, instance);
    }
    let mut materials = Vec::new();
    let mut prim_material = Vec::with_capacity(stacks.len());
    let mut by_key: HashMap<String, usize> = HashMap::new();
    let mut displaced_vertical = OncePerKind::new();
    // Vertical layers are composed but not lowered yet: each slot reported once, at its first
    // binding, with the number of prims it reaches.
    for stack in &stacks {
        let mut composed = ComposedMaterial::default();
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
        for layer in filter.layers(stack) {
            let Some(mut horizontal) = compose_layer(layer, &mut resolve, diags) else { continue };
            for vertical in &layer.vertical {
                let Some(vertical) = compose_layer(vertical, &mut resolve, diags) else { continue };
                let graph = library.get(vertical.substance.graph);
                if let Some(product) = graph.products.iter().find(|p| p.product == Product::Displacement) {
                    displaced_vertical.push(
                        "displacement on a vertical layer",
                        &vertical.substance.path,
                        Diagnostic::warning(format!(
                            "`{}` has a displacement product; on vertical slot `{}` it is ignored (a vertical layer only coats the surface below it)",
                            graph.name,
                            vertical.slot.name()
                        ))
                        .at(vertical.substance.span, "bound here")
                        .also(product.span, "displacement"),
                    );
                }
                horizontal.vertical.push(vertical);
            }
            composed.layers.push(horizontal);
        }
        if composed.layers.is_empty() {
            composed.display = display_primvars(stage, &stack.prim);
        }
        let index = *by_key.entry(composed.identity_key()).or_insert_with(|| {
            materials.push(composed);
            materials.len() - 1
        });
        prim_material.push(index);
    }
    displaced_vertical.report(diags);
    SceneComposition { stacks, library, materials, prim_material }
}

/// A resolved layer (horizontal or vertical) with its substance and overrides looked up;
/// `None` when the substance could not be (already reported).
fn compose_layer(
    layer: &LayerBinding,
    resolve: &mut impl FnMut(&str, Span, GraphKind, &mut Diagnostics) -> Option<MaterialRef>,
    diags: &mut Diagnostics,
) -> Option<ComposedLayer> {
    let substance = resolve(&layer.applied.material, layer.applied.span, GraphKind::Substance, diags)?;
    let mut overrides = Vec::new();
    for o in &layer.overrides {
        if let Some(r) = resolve(&o.applied.material, o.applied.span, GraphKind::Override, diags) {
            overrides.push((o.slot.clone(), MaterialRef { span: o.applied.span, ..r }));
        }
    }
    Some(ComposedLayer::new(layer.slot.clone(), MaterialRef { span: layer.applied.span, ..substance }, overrides))
}

/// The display primvars renderable prim `path` authors (a GeomSubset: its mesh's).
pub fn display_primvars(stage: &Stage, path: &str) -> DisplayPrimvars {
    let Some(mut id) = stage.find(path) else { return DisplayPrimvars::default() };
    if stage.prim(id).type_name.as_deref() == Some("GeomSubset")
        && let Some(parent) = stage.prim(id).parent
    {
        id = parent;
    }
    let prim = stage.prim(id);
    let authored = |name: &str| prim.attribute(name).is_some_and(|a| a.value.is_some());
    DisplayPrimvars { color: authored("primvars:displayColor"), opacity: authored("primvars:displayOpacity") }
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
    // Each shader input takes the value UsdShade resolves for it: through `.connect` to the
    // Material's interface inputs, else its own. Interface inputs reach the shader only through
    // connections; the ones nothing reaches are kept to warn about if the substance has them.
    let mut inputs = Vec::new();
    let mut reached: Vec<String> = Vec::new();
    for attr in &shader.attributes {
        let Some(name) = attr.name.strip_prefix("inputs:") else { continue };
        let mut seen = Vec::new();
        let producer = value_producer(stage, shader, attr, &mut seen, diags);
        reached.append(&mut seen);
        let Some((prim, producer)) = producer else { continue };
        let Some((value, span)) = &producer.value else { continue };
        reached.push(attribute_path(prim, producer));
        let connected = if std::ptr::eq(producer, attr) { None } else { attr.connections.first().map(|(_, s)| *s) };
        inputs.push(InputValue {
            name: name.to_string(),
            value: value.clone(),
            type_name: producer.type_name.clone(),
            span: *span,
            connected,
        });
    }
    let unconnected = if std::ptr::eq(material, shader) {
        Vec::new()
    } else {
        material
            .attributes
            .iter()
            .filter(|a| a.name.starts_with("inputs:") && a.value.is_some())
            .filter(|a| !reached.contains(&attribute_path(material, a)))
            .map(|a| (a.name.clone(), a.type_name.clone(), a.span))
            .collect()
    };
    Some(MaterialSource { file: asset.resolved.clone(), file_span: asset_span, graph_name, inputs, unconnected })
}

/// The input values Material prim `path` sets on its strata substance or override `graph`, read
/// again from the stage as composition reads them (a live view's input edit, which rewrites a
/// parameter block without composing the stage again). `None` for a UsdShade preview network,
/// a material whose shader or graph changed, or values composition would report.
pub fn material_values(stage: &Stage, lib: &Library, path: &str, graph: GraphId) -> Option<Vec<(usize, Value)>> {
    let id = stage.find(path)?;
    if preview::is_preview_material(stage, id) {
        return None;
    }
    let mut diags = Diagnostics::new();
    let source = material_source(stage, path, Span::default(), &mut diags)?;
    let r = material_ref(lib, path, &source, Span::default(), &mut diags)?;
    (r.graph == graph && !diags.has_errors()).then_some(r.values)
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
    for InputValue { name, value, type_name, span, connected } in &source.inputs {
        let Some((index, input)) = g.input(name) else {
            let mut d =
                Diagnostic::warning(format!("`{}` has no input `{name}`; the value set on `{path}` is unused", g.name))
                    .at(connected.unwrap_or(*span), "unused");
            if let Some(hint) = did_you_mean(name, g.inputs.iter().map(|i| i.name.as_str())) {
                d = d.note(hint);
            }
            diags.push(d);
            continue;
        };
        match convert_input(value, type_name, input.ty) {
            Ok(v) => values.push((index, v)),
            Err(message) => {
                let mut d = Diagnostic::error(format!("input `{name}` of `{path}`: {message}")).at(*span, "this value");
                if let Some(c) = connected {
                    d = d.also(*c, "connected here");
                }
                diags.push(d.also(input.span, format!("declared as {}", input.ty)));
            }
        }
    }
    for (attr, type_name, span) in &source.unconnected {
        let name = &attr["inputs:".len()..];
        if g.input(name).is_some() && !source.inputs.iter().any(|i| i.name == name) {
            diags.push(
                Diagnostic::warning(format!(
                    "`{path}` sets `{attr}`, but no shader input connects to it; the value is unused"
                ))
                .at(*span, "not connected")
                .note(format!(
                    "UsdShade passes a Material's inputs to its shader only through connections: \
                     `{type_name} {attr}.connect = <{path}.{attr}>` on the Shader"
                )),
            );
        }
    }
    Some(MaterialRef { path: path.to_string(), graph, values, span: binding })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compose::slots::resolve_stacks;
    use crate::front::types::Value;
    use std::path::Path;

    /// The paper's listing-1 substances (`SubstanceB`: `color albedo`, `float coverage`).
    fn paper_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/paper")
    }

    fn stage(text: &str, dir: &Path) -> (Stage, SourceMap, Diagnostics) {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("scene.usda", text, dir, &mut sources, &mut diags)
            .unwrap_or_else(|_| panic!("{}", diags.render(&sources)));
        (stage, sources, diags)
    }

    /// Each renderable prim's stack as `prim: slot=material@bound_at ...`, and the diagnostics.
    /// Unless the scene defines `/M`, the materials it binds are defined there (empty
    /// Materials named `A`..`Z` and every `</M/Name>` the text targets): a binding to a prim
    /// that does not exist binds nothing.
    fn stacks(text: &str, dir: &Path) -> (Vec<String>, String, bool) {
        let mut text = text.to_string();
        if !text.contains("def Scope \"M\"") {
            let mut names: Vec<String> = ('A'..='Z').map(String::from).collect();
            for target in text.split("</M/").skip(1) {
                let name: String = target.chars().take_while(|c| *c != '>' && *c != '/').collect();
                if !names.contains(&name) {
                    names.push(name);
                }
            }
            text += "\ndef Scope \"M\" {\n";
            for name in names {
                text += &format!("    def Material \"{name}\" {{}}\n");
            }
            text += "}\n";
        }
        let (stage, sources, mut diags) = stage(&text, dir);
        let tree = binding_tree(&stage, &mut diags);
        let stacks = resolve_stacks(&tree, &mut diags);
        let lines = stacks
            .iter()
            .map(|s| {
                let layers: Vec<String> = s
                    .layers
                    .iter()
                    .map(|l| {
                        let mut t = format!("{}={}@{}", l.slot.name(), l.applied.material, l.applied.bound_at);
                        for o in &l.overrides {
                            t += &format!("[{}={}]", o.slot.name(), o.applied.material);
                        }
                        t
                    })
                    .collect();
                format!("{}: {}", s.prim, layers.join(" "))
            })
            .collect();
        (lines, diags.render(&sources), diags.has_errors())
    }

    #[test]
    fn declared_only_is_no_binding_and_authored_empty_removes() {
        let (lines, rendered, errors) = stacks(
            r#"#usda 1.0
def Xform "Root" {
    rel material:slotBinding:_000 = </M/A>
    rel material:slotBinding:_050 = </M/B>
    def Sphere "Declared" {
        rel material:slotBinding:_050
        custom rel material:slotBinding:_070
        rel material:slotBinding:not_encoded
    }
    def Sphere "None" { rel material:slotBinding:_050 = None }
    def Sphere "EmptyList" { rel material:slotBinding:_050 = [] }
    def Sphere "DeleteOnly" { delete rel material:slotBinding:_050 = </M/B> }
    def Sphere "DeletedAway" {
        # As in Sdf, the edit replaces the explicit list; `delete` over nothing is empty.
        rel material:slotBinding:_050 = </M/C>
        delete rel material:slotBinding:_050 = </M/C>
    }
    def Sphere "PrependNothing" { prepend rel material:slotBinding:_050 = [] }
    def Xform "Removed" {
        rel material:slotBinding:_050 = None
        def Sphere "DeclaredBelow" { rel material:slotBinding:_050 }
    }
}
"#,
            &paper_dir(),
        );
        // Not even the malformed name is reported: a declaration binds nothing.
        assert!(!errors && rendered.is_empty(), "{rendered}");
        assert_eq!(
            lines,
            vec![
                "/Root/Declared: 000=/M/A@/Root 050=/M/B@/Root",
                "/Root/None: 000=/M/A@/Root",
                "/Root/EmptyList: 000=/M/A@/Root",
                "/Root/DeleteOnly: 000=/M/A@/Root",
                "/Root/DeletedAway: 000=/M/A@/Root",
                "/Root/PrependNothing: 000=/M/A@/Root",
                // A declaration does not undo an inherited removal either.
                "/Root/Removed/DeclaredBelow: 000=/M/A@/Root",
            ]
        );
    }

    fn write(dir: &Path, name: &str, text: &str) {
        std::fs::write(dir.join(name), text).expect("write fixture");
    }

    #[test]
    fn declared_only_in_a_stronger_layer_keeps_the_weaker_opinion() {
        let dir = tempfile::Builder::new().prefix("strata-declared").tempdir().expect("temp dir");
        let d = dir.path();
        write(
            d,
            "weak.usda",
            "#usda 1.0\ndef Xform \"Root\" {\n    rel material:slotBinding:_000 = </M/A>\n    \
             def Sphere \"Ball\" {\n        rel material:slotBinding:_050 = </M/B>\n        \
             rel material:slotBinding:_060 = </M/C>\n    }\n    \
             def Sphere \"Deleted\" {\n        rel material:slotBinding:_000 = </M/X>\n    }\n}\n",
        );
        write(
            d,
            "asset.usda",
            "#usda 1.0\n(defaultPrim = \"Thing\")\ndef Sphere \"Thing\" {\n    \
             rel material:slotBinding:_010 = </Thing/Mat>\n    def Material \"Mat\" {}\n}\n",
        );
        let (lines, rendered, errors) = stacks(
            r#"#usda 1.0
(subLayers = [@weak.usda@])
over "Root" {
    over "Ball" {
        rel material:slotBinding:_050
        rel material:slotBinding:_060 = None
    }
    over "Deleted" {
        delete rel material:slotBinding:_000 = </M/X>
    }
    def "Ref" (references = @asset.usda@) {
        custom rel material:slotBinding:_010
    }
}
"#,
            d,
        );
        assert!(!errors, "{rendered}");
        assert_eq!(
            lines,
            vec![
                // The stronger layer's declaration is no opinion; its `= None` is one.
                "/Root/Ball: 000=/M/A@/Root 050=/M/B@/Root/Ball",
                // Deleting the weaker layer's only target leaves an empty binding: it removes
                // the inherited slot.
                "/Root/Deleted: ",
                // The reference's binding applies, mapped to where it is referenced.
                "/Root/Ref: 000=/M/A@/Root 010=/Root/Ref/Mat@/Root/Ref",
            ]
        );
    }

    #[test]
    fn utf8_slots_parse_and_sort_byte_by_byte() {
        let (lines, rendered, errors) = stacks(
            "#usda 1.0\ndef Sphere \"Ball\" {\n    rel material:slotBinding:_é = </M/E>\n    \
             rel material:slotBinding:_é:_:_ü = </M/O>\n    rel material:slotBinding:_z = </M/Z>\n    \
             rel material:slotBinding:_Ａ = </M/W>\n    rel material:slotBinding:_𐐀 = </M/D>\n    \
             rel material:slotBinding:_Z = </M/U>\n    rel material:slotBinding:_e\u{301} = </M/C>\n}\n",
            &paper_dir(),
        );
        assert!(!errors, "{rendered}");
        // Byte order (= code point order), not case- or locale-aware, not UTF-16 order (which
        // would put U+10400 before U+FF21), no normalisation (`e` + U+0301 is not `é`).
        assert_eq!(
            lines,
            vec![
                "/Ball: Z=/M/U@/Ball e\u{301}=/M/C@/Ball z=/M/Z@/Ball é=/M/E@/Ball[é::ü=/M/O] Ａ=/M/W@/Ball 𐐀=/M/D@/Ball"
            ]
        );
    }

    #[test]
    fn more_than_one_target_is_an_error() {
        let (lines, rendered, errors) = stacks(
            "#usda 1.0\ndef Xform \"Root\" {\n    rel material:slotBinding:_000 = </M/A>\n    \
             def Sphere \"Ball\" {\n        rel material:slotBinding:_000 = [</M/B>, </M/C>]\n    }\n}\n",
            &paper_dir(),
        );
        assert!(errors);
        assert!(rendered.contains("slot binding `material:slotBinding:_000` has 2 targets"), "{rendered}");
        assert!(rendered.contains("scene.usda:5:9"), "{rendered}");
        // The bad binding is not applied, not even its first target.
        assert_eq!(lines, vec!["/Root/Ball: 000=/M/A@/Root"]);
    }

    /// Composes a scene whose `/Ball` binds `/M/B` (listing 1's `SubstanceB`) and returns the
    /// values it sets by input name, with the rendered diagnostics.
    fn ball_inputs(material: &str) -> (Vec<(String, Value)>, String, bool) {
        let (values, _, rendered, errors) = ball(material);
        (values, rendered, errors)
    }

    /// [`ball_inputs`] plus the wired IR of `/Ball`'s material.
    fn ball(material: &str) -> (Vec<(String, Value)>, String, String, bool) {
        let text = format!(
            "#usda 1.0\ndef Sphere \"Ball\" {{ rel material:slotBinding:_000 = </M/B> }}\ndef Scope \"M\" {{\n{material}\n}}\n"
        );
        let (stage, mut sources, mut diags) = stage(&text, &paper_dir());
        let c = compose_stage(&stage, &mut sources, &mut diags);
        let values = c
            .material_of("/Ball")
            .and_then(|m| m.layers.first())
            .map(|l| {
                let g = c.library.get(l.substance.graph);
                l.substance.values.iter().map(|(i, v)| (g.inputs[*i].name.clone(), v.clone())).collect()
            })
            .unwrap_or_default();
        let ir = c
            .material_of("/Ball")
            .map(|m| {
                let options = crate::ir::wired::PassOptions::default();
                crate::ir::wired::build(&c.library, m, options, &mut diags).to_text(&c.library)
            })
            .unwrap_or_default();
        (values, ir, diags.render(&sources), diags.has_errors())
    }

    const SHADER: &str = r#"uniform token info:implementationSource = "sourceAsset"
            uniform asset info:strata:sourceAsset = @listing1.ash@
            uniform token info:strata:sourceAsset:subIdentifier = "SubstanceB""#;

    #[test]
    fn connect_delivers_material_interface_inputs() {
        let (values, ir, rendered, errors) = ball(&format!(
            r#"    def Material "B" {{
        color3f inputs:tint = (0.1, 0.2, 0.3)
        float inputs:cov = 0.25
        float inputs:cov.connect = </M/B.inputs:base_cov>
        float inputs:base_cov = 0.75
        def Shader "S" {{
            {SHADER}
            color3f inputs:albedo = (1, 1, 1)
            color3f inputs:albedo.connect = </M/B.inputs:tint>
            float inputs:coverage.connect = </M/B.inputs:cov>
        }}
    }}"#
        ));
        assert!(!errors, "{rendered}");
        assert!(rendered.is_empty(), "{rendered}");
        // The connection beats the shader's own value; `cov` passes `base_cov` on.
        assert_eq!(
            values,
            vec![("albedo".to_string(), Value::Triple([0.1, 0.2, 0.3])), ("coverage".to_string(), Value::Float(0.75))]
        );
        // And they reach the compiled material.
        assert!(ir.contains("(albedo: (0.1, 0.2, 0.3))") && ir.contains("mask = 0.75"), "{ir}");
    }

    #[test]
    fn connect_falls_back_to_authored_values_as_usdshade_does() {
        let (values, rendered, errors) = ball_inputs(&format!(
            r#"    def Material "B" {{
        color3f inputs:tint
        float inputs:cov
        def Shader "S" {{
            {SHADER}
            color3f inputs:albedo = (0.5, 0.5, 0.5)
            color3f inputs:albedo.connect = </M/B.inputs:tint>
            float inputs:coverage.connect = </M/B.inputs:cov>
        }}
    }}"#
        ));
        assert!(!errors && rendered.is_empty(), "{rendered}");
        // The interface inputs have no value: the shader's own applies, else the default.
        assert_eq!(values, vec![("albedo".to_string(), Value::Triple([0.5, 0.5, 0.5]))]);
    }

    #[test]
    fn material_inputs_reach_the_shader_only_through_connections() {
        let (values, rendered, errors) = ball_inputs(&format!(
            r#"    def Material "B" {{
        float inputs:coverage = 0.1
        float inputs:unrelated = 2
        def Shader "S" {{
            {SHADER}
        }}
    }}"#
        ));
        assert!(!errors, "{rendered}");
        assert!(values.is_empty(), "{values:?}");
        assert!(
            rendered.contains("`/M/B` sets `inputs:coverage`, but no shader input connects to it")
                && rendered.contains("float inputs:coverage.connect = </M/B.inputs:coverage>")
                && !rendered.contains("unrelated"),
            "{rendered}"
        );
    }

    #[test]
    fn bad_connections_are_located_diagnostics() {
        let (values, rendered, errors) = ball_inputs(&format!(
            r#"    def Material "B" {{
        float inputs:a.connect = </M/B.inputs:b>
        float inputs:b = 0.5
        float inputs:b.connect = </M/B.inputs:a>
        def Shader "S" {{
            {SHADER}
            float inputs:coverage.connect = </M/B.inputs:a>
            color3f inputs:albedo.connect = </M/B.inputs:nope>
        }}
    }}"#
        ));
        assert!(errors);
        for expected in [
            "error: connection cycle: `/M/B.inputs:a` leads back to itself",
            "scene.usda:7:34",
            "error: connection source `/M/B.inputs:nope` does not exist",
            "scene.usda:13:45",
        ] {
            assert!(rendered.contains(expected), "{expected}\n{rendered}");
        }
        // `b`'s own value ends the search the cycle broke off, as in UsdShade.
        assert_eq!(values, vec![("coverage".to_string(), Value::Float(0.5))]);

        let (values, rendered, errors) = ball_inputs(&format!(
            r#"    def Material "B" {{
        float inputs:x = 1
        float inputs:y = 0
        def Shader "S" {{
            {SHADER}
            color3f inputs:albedo = (1, 0, 0)
            color3f inputs:albedo.connect = </M/B/Noise.outputs:out>
            float inputs:coverage.connect = [</M/B.inputs:x>, </M/B.inputs:y>]
        }}
        def Shader "Noise" {{ color3f outputs:out }}
    }}"#
        ));
        assert!(errors);
        assert!(rendered.contains("warning: strata cannot evaluate `/M/B/Noise.outputs:out`"), "{rendered}");
        assert!(rendered.contains("error: `/M/B/S.inputs:coverage` connects to 2 sources"), "{rendered}");
        assert_eq!(values, vec![("albedo".to_string(), Value::Triple([1.0, 0.0, 0.0]))]);
    }

    #[test]
    fn collection_bindings_resolve_as_usdshade() {
        let (lines, rendered, errors) = stacks(
            r#"#usda 1.0
def Xform "Root" {
    rel material:binding = </M/Strong> ( bindMaterialAs = "strongerThanDescendants" )
    rel material:binding:collection:c = [</Root.collection:c>, </M/Coll>]
    rel collection:c:includes = [</Root/Mid/In>, </Root/Mid/Explicit>]
    uniform token collection:c:expansionRule = "expandPrims"
    def Xform "Mid" {
        rel material:binding = </M/Mid>
        def Sphere "In" { }
        def Sphere "Out" { }
        def Sphere "Explicit" { def Sphere "Child" { } }
    }
}
def Xform "Only" {
    rel material:binding:collection:e = [</Only.collection:e>, </M/E>]
    rel collection:e:includes = </Only/A>
    uniform token collection:e:expansionRule = "explicitOnly"
    def Sphere "A" { def Sphere "B" { } }
}
"#,
            &paper_dir(),
        );
        assert!(!errors, "{rendered}");
        assert_eq!(
            lines,
            vec![
                // At /Root the collection holds In: it is /Root's offer, so /Root's strong direct
                // binding does not apply to In; Mid's direct binding is closer and wins.
                "/Root/Mid/In: material:binding=/M/Mid@/Root/Mid",
                // Out is not in the collection: /Root offers its strong direct binding.
                "/Root/Mid/Out: material:binding=/M/Strong@/Root",
                "/Root/Mid/Explicit: material:binding=/M/Mid@/Root/Mid",
                "/Root/Mid/Explicit/Child: material:binding=/M/Mid@/Root/Mid",
                // explicitOnly: the named prim, not its descendants.
                "/Only/A: material:binding=/M/E@/Only",
                "/Only/A/B: ",
            ]
        );
    }
}
