//! Composition: from slot bindings to one composed material per renderable prim.
//!
//! [`slots`] resolves the hierarchy (DESIGN.md rules 1–3) into per-prim slot stacks; a
//! [`ComposedMaterial`] names, for each layer bottom to top, the substance and its overrides
//! with the input values the scene sets. [`crate::ir::wired`] turns it into the wired IR.

pub mod binding;
pub mod collection;
pub mod connect;
pub mod mtlx;
pub mod path_expression;
pub mod preview;
pub mod scene;
pub mod slots;

use crate::diag::Span;
use crate::front::ast::BaseType;
use crate::front::graph::{Graph, Source};
use crate::front::library::{GraphId, Library};
use crate::front::types::{Type, Value};
pub use slots::Slot;

/// A substance or override as bound in a scene: the graph plus the input values its material
/// prim sets.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialRef {
    /// The material prim path (`/Looks/Plastic`).
    pub path: String,
    /// The graph it names.
    pub graph: GraphId,
    /// Input values set by the scene: (input index, value), converted to the input's type.
    pub values: Vec<(usize, Value)>,
    /// Where the binding that selected it is authored.
    pub span: Span,
}

/// One layer of a composed material.
#[derive(Clone, Debug, PartialEq)]
pub struct ComposedLayer {
    /// The substance slot.
    pub slot: Slot,
    /// The substance.
    pub substance: MaterialRef,
    /// Attached overrides in ascending slot order (the last wins a contested input).
    pub overrides: Vec<(Slot, MaterialRef)>,
    /// For a horizontal layer, its vertical layers (`000|010`, DESIGN.md rule 3b) in byte
    /// order, the first lying directly on this layer's surface; each one's mask is its
    /// coverage. Always empty for a vertical layer.
    pub vertical: Vec<ComposedLayer>,
}

impl ComposedLayer {
    /// A horizontal layer with no vertical layers.
    pub fn new(slot: Slot, substance: MaterialRef, overrides: Vec<(Slot, MaterialRef)>) -> ComposedLayer {
        ComposedLayer { slot, substance, overrides, vertical: Vec::new() }
    }

    /// The substance and the overrides, in key order.
    fn references(&self) -> impl Iterator<Item = &MaterialRef> {
        std::iter::once(&self.substance).chain(self.overrides.iter().map(|(_, o)| o))
    }
}

/// The material of one renderable prim: layers bottom to top. No layers means the default
/// substance (white diffuse, or the prim's display primvars: DESIGN.md rule 4).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ComposedMaterial {
    /// Layers, bottom first.
    pub layers: Vec<ComposedLayer>,
    /// With no layers: the display primvars the prim authors, which the default substance reads.
    pub display: DisplayPrimvars,
}

/// Which of Hydra's display primvars a prim authors (`primvars:displayColor`,
/// `primvars:displayOpacity`; a GeomSubset's are its mesh's). The default substance reads
/// only those, so unbound prims without them stay plain white diffuse and opaque at no cost.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub struct DisplayPrimvars {
    /// `primvars:displayColor` is authored.
    pub color: bool,
    /// `primvars:displayOpacity` is authored.
    pub opacity: bool,
}

impl DisplayPrimvars {
    /// The built-in graph that shades a prim with no layers.
    pub fn default_substance(self) -> &'static str {
        match (self.color, self.opacity) {
            (false, false) => "default_substance",
            (true, false) => "default_substance_display_color",
            (_, true) => "default_substance_display",
        }
    }

    /// How `strata layers` describes the default substance.
    pub fn describe(self) -> &'static str {
        match (self.color, self.opacity) {
            (false, false) => "white diffuse",
            (true, false) => "displayColor",
            (false, true) => "white, displayOpacity",
            (true, true) => "displayColor, displayOpacity",
        }
    }
}

impl ComposedMaterial {
    /// A key equal for compositions with the same substances, overrides and input values in
    /// the same order (DESIGN.md rule 8): where and under which slot names they were bound
    /// does not change the material.
    pub fn identity_key(&self) -> String {
        let mut key = String::new();
        if self.layers.is_empty() {
            key += self.display.default_substance();
        }
        for layer in &self.layers {
            for m in layer.references() {
                key += &format!("{}{:?};", m.graph.0, m.values);
            }
            // Vertical layers in their order: a coat over a layer makes another material.
            for vertical in &layer.vertical {
                key.push('^');
                for m in vertical.references() {
                    key += &format!("{}{:?};", m.graph.0, m.values);
                }
            }
            key.push('|');
        }
        key
    }
}

/// How many words of a parameter block input `index` of `graph` takes when inputs are live
/// (a live view compiles them as parameters, `ir::wired::PassOptions::live_inputs`) and its
/// value is `value`: 1 for a float, 3 for a colour, point, vector or normal; 0 for the inputs
/// that stay folded constants — integers, strings, arrays, an input that is a displacement's
/// bound (dicing needs it before any shading), and the values the folder turns into
/// compile-time facts: a float of exactly 0 or 1 (a mask that prunes a layer or hides the ones
/// below, which also chooses the layer mode) and a black triple (emission that is dropped).
/// So a live material renders `render`'s folded image bit for bit; an edit that crosses one
/// of those values changes the class and compiles.
pub fn live_input_words(graph: &Graph, index: usize, value: &Value) -> usize {
    let Some(input) = graph.inputs.get(index) else { return 0 };
    let is_bound = graph.products.iter().any(|p| matches!(p.bound, Some(Source::Input(i)) if i == index));
    if is_bound || input.ty.array.is_some() {
        return 0;
    }
    match (input.ty, value) {
        (_, Value::Float(x)) if *x == 0.0 || *x == 1.0 => 0,
        (_, Value::Triple(t)) if t.iter().all(|x| *x == 0.0) => 0,
        (t, _) if t.is_triple() => 3,
        (t, _) if t.base == BaseType::Float => 1,
        _ => 0,
    }
}

impl MaterialRef {
    /// The value of input `index` of `graph` (this reference's graph): the scene's, else the
    /// input's default.
    pub fn input_value<'a>(&'a self, graph: &'a Graph, index: usize) -> &'a Value {
        self.values.iter().find(|(i, _)| *i == index).map_or(&graph.inputs[index].default, |(_, v)| v)
    }

    /// Per input of `graph`, its value when it is folded into the compiled class with live
    /// inputs, `None` when it is a parameter ([`live_input_words`]): what must not change for
    /// a parameter block to stand for an edit.
    pub fn folded_inputs(&self, graph: &Graph) -> Vec<Option<Value>> {
        (0..graph.inputs.len())
            .map(|i| {
                let value = self.input_value(graph, i);
                (live_input_words(graph, i, value) == 0).then(|| value.clone())
            })
            .collect()
    }
}

/// The words of `value` as a parameter of type `ty` ([`live_input_words`] of them), as the
/// lowering writes the same value as a constant (a float fills a triple).
fn live_words(value: &Value, ty: Type, out: &mut Vec<f32>) {
    let width = if ty.is_triple() { 3 } else { 1 };
    match value {
        Value::Triple(t) if width == 3 => out.extend_from_slice(t),
        Value::Float(x) => out.extend(std::iter::repeat_n(*x, width)),
        Value::Int(i) => out.extend(std::iter::repeat_n(*i as f32, width)),
        _ => out.extend(std::iter::repeat_n(0.0, width)),
    }
}

impl ComposedMaterial {
    /// The substances and overrides in parameter-block order: per layer bottom to top, its
    /// substance, its overrides, then each vertical layer's substance and overrides. The wired
    /// IR's builder numbers live inputs in the same order.
    pub fn references_in_order(&self) -> Vec<&MaterialRef> {
        let mut out = Vec::new();
        for layer in &self.layers {
            for part in std::iter::once(layer).chain(&layer.vertical) {
                out.extend(part.references());
            }
        }
        out
    }

    /// [`ComposedMaterial::references_in_order`], mutable.
    pub fn references_mut(&mut self) -> Vec<&mut MaterialRef> {
        let mut out = Vec::new();
        for layer in &mut self.layers {
            out.push(&mut layer.substance);
            out.extend(layer.overrides.iter_mut().map(|(_, o)| o));
            for vertical in &mut layer.vertical {
                out.push(&mut vertical.substance);
                out.extend(vertical.overrides.iter_mut().map(|(_, o)| o));
            }
        }
        out
    }

    /// The parameter block of this material when its inputs are live: each reference's live
    /// inputs ([`live_input_words`]) in [`ComposedMaterial::references_in_order`], each the
    /// value the scene sets, else the input's default. The default substance (no layers) has
    /// none.
    pub fn parameter_block(&self, lib: &Library) -> Vec<f32> {
        let mut block = Vec::new();
        for r in self.references_in_order() {
            let graph = lib.get(r.graph);
            for (index, input) in graph.inputs.iter().enumerate() {
                let value = r.input_value(graph, index);
                if live_input_words(graph, index, value) > 0 {
                    live_words(value, input.ty, &mut block);
                }
            }
        }
        block
    }

    /// The material's "class" when its inputs are live, for hashing: every input's folded
    /// value, the parameters marked as such (their values live in the parameter block).
    /// Materials with the same class share compiled code.
    pub fn class(&self, lib: &Library) -> ComposedMaterial {
        let mut class = self.clone();
        let strip = |r: &mut MaterialRef| {
            let graph = lib.get(r.graph);
            let folded = r.folded_inputs(graph);
            r.values = folded
                .into_iter()
                .enumerate()
                .map(|(i, v)| (i, v.unwrap_or_else(|| Value::Str("<parameter>".into()))))
                .collect();
        };
        for layer in &mut class.layers {
            strip(&mut layer.substance);
            layer.overrides.iter_mut().for_each(|(_, o)| strip(o));
            for vertical in &mut layer.vertical {
                strip(&mut vertical.substance);
                vertical.overrides.iter_mut().for_each(|(_, o)| strip(o));
            }
        }
        class
    }
}
