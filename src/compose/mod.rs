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
use crate::front::library::GraphId;
use crate::front::types::Value;
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
