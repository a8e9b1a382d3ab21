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
/// (a live view compiles them as parameters, `ir::wired::PassOptions::live_inputs`): 1 for a
/// float, 3 for a colour, point, vector or normal; 0 for the inputs that stay folded constants
/// — integers, strings, arrays, and an input that is a displacement's bound, which dicing
/// needs before any shading.
pub fn live_input_words(graph: &Graph, index: usize) -> usize {
    let Some(input) = graph.inputs.get(index) else { return 0 };
    let is_bound = graph.products.iter().any(|p| matches!(p.bound, Some(Source::Input(i)) if i == index));
    if is_bound || input.ty.array.is_some() {
        return 0;
    }
    match input.ty {
        t if t.is_triple() => 3,
        t if t.base == BaseType::Float => 1,
        _ => 0,
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
                if live_input_words(graph, index) == 0 {
                    continue;
                }
                let value = r.values.iter().find(|(i, _)| *i == index).map_or(&input.default, |(_, v)| v);
                live_words(value, input.ty, &mut block);
            }
        }
        block
    }

    /// The material's "class" when its inputs are live: the values of live inputs removed
    /// (they live in the parameter block), every other value kept. Materials with the same
    /// class share compiled code.
    pub fn class(&self, lib: &Library) -> ComposedMaterial {
        let mut class = self.clone();
        let strip = |r: &mut MaterialRef| {
            let graph = lib.get(r.graph);
            r.values.retain(|(i, _)| live_input_words(graph, *i) == 0);
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
