//! Stage composition: layers, sublayers, references, payloads, inherits and variants
//! composed into one prim tree.
//!
//! Each prim's opinions are gathered in a small tree of *nodes* in the spirit of USD's prim
//! index: the root node holds the specs of the root layer stack, and every composition arc
//! (inherit, variant, reference, payload) adds a child node for the arc's target site.
//! Children of a node are ordered by arc type (LIVRPS), arcs authored directly on the prim
//! before arcs inherited from its ancestors; the strength order of opinions is a pre-order
//! walk of that tree. A child prim's tree is derived from its parent's by looking up the
//! child's name in every node, which is how an ancestor's reference reaches its children.
//!
//! Every layer — the root and each sublayer, reference and payload — is read by
//! [`usdc::read_layer_file`], which tells `.usda` text, `.usdc` crates and usdz packages apart
//! by content; crates are converted to the same [`Layer`](crate::scene::usda::Layer) syntax tree the usda parser builds.
//!
//! Referenced layers are loaded lazily: a composition pass records the layers it is missing,
//! they are loaded, and the pass is redone, so layers in unselected variants are never read.
//!
//! Files: `layers` (loading, sublayers, layer stacks), `prim_index` (nodes and path mapping),
//! `pass` (the prim tree), `arcs` (inherits, references, payloads), `variants` and
//! `properties` (attributes, relationships and their list ops).

use crate::diag::{Diagnostic, Diagnostics, Failed, FileId, SourceMap, Span};
use crate::scene::time::{self, TimeCode};
use crate::scene::usda::{LayerMetadata, MetadataEntry, Target};
use crate::scene::usdc::{self, LayerSource};
use crate::scene::value::{Value, ValueType};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

mod arcs;
mod layers;
mod pass;
mod prim_index;
mod properties;
mod variants;

use layers::{Chain, Layers};
use pass::Pass;

/// Index of a prim in a [`Stage`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PrimId(pub u32);

/// A composed attribute.
#[derive(Clone, Debug)]
pub struct Attribute {
    /// Its (namespaced) name.
    pub name: String,
    /// The declared type from the strongest opinion, `[]` included (`point3f[]`).
    pub type_name: String,
    /// The classified type.
    pub value_type: ValueType,
    /// The value at the stage's time ([`Stage::time`]) with its span; `None` when declared
    /// only, blocked, or without a value at that time.
    pub value: Option<(Value, Span)>,
    /// The strongest default value (`None` when declared only, blocked or only animated):
    /// what [`TimeCode::Default`] reads.
    pub default_value: Option<(Value, Span)>,
    /// Whether the strongest value opinion is a block (`= None`).
    pub blocked: bool,
    /// The span of the strongest opinion's statement.
    pub span: Span,
    /// Declared `custom`.
    pub custom: bool,
    /// Declared `uniform`.
    pub uniform: bool,
    /// Composed connection targets (`name.connect`), mapped to stage paths.
    pub connections: Vec<Target>,
    /// Time samples in stage time, sorted: those of the strongest opinion that authors a
    /// value, when it authors samples (a stronger default or block hides weaker samples).
    pub time_samples: Vec<(f64, Value)>,
    /// Metadata, strongest opinion per key.
    pub metadata: Vec<MetadataEntry>,
    /// For `pathExpression` attributes only: the default values of the weaker opinions,
    /// strongest first, which a stronger expression's `%_` composes over (USD composes path
    /// expressions rather than replacing them). Empty for every other type.
    pub weaker_defaults: Vec<(Value, Span)>,
}

impl Attribute {
    /// The value, if any.
    pub fn get(&self) -> Option<&Value> {
        self.value.as_ref().map(|(v, _)| v)
    }

    /// A metadata value such as `interpolation`.
    pub fn meta(&self, key: &str) -> Option<&Value> {
        self.metadata.iter().find(|m| m.key == key).map(|m| &m.value)
    }

    /// The value at `time`, as USD's `UsdAttribute::Get(time)` (see [`time::value_at`]).
    pub fn value_at(&self, time: TimeCode) -> Option<Value> {
        time::value_at(self.default_value.as_ref().map(|(v, _)| v), &self.time_samples, &self.type_name, time)
    }
}

/// A composed relationship.
#[derive(Clone, Debug)]
pub struct Relationship {
    /// Its (namespaced) name.
    pub name: String,
    /// Composed targets, mapped to stage paths, each with the span that authored it.
    pub targets: Vec<Target>,
    /// Whether an explicit list (`= [...]` or `= None`) took part in the composition.
    pub explicit: bool,
    /// The strongest statement that authored targets; `None` when every opinion only declares
    /// the relationship (`rel r`, what `CreateRelationship` writes): USD's `HasAuthoredTargets`.
    pub authored: Option<Span>,
    /// The span of the strongest opinion's statement.
    pub span: Span,
    /// Declared `custom`.
    pub custom: bool,
    /// Metadata, strongest opinion per key.
    pub metadata: Vec<MetadataEntry>,
}

impl Relationship {
    /// Whether any opinion says something about the targets, even that there are none.
    pub fn has_authored_targets(&self) -> bool {
        self.authored.is_some()
    }

    /// Whether the relationship was explicitly set to nothing (`= None` or `= []`): for a
    /// binding, this means "bound to nothing", unlike a relationship with no opinion.
    pub fn is_explicit_empty(&self) -> bool {
        self.explicit && self.targets.is_empty()
    }
}

/// A composed prim.
#[derive(Clone, Debug)]
pub struct Prim {
    /// Absolute path, `/a/b`.
    pub path: String,
    /// Last path element.
    pub name: String,
    /// Schema type name (`Mesh`), if any opinion has one.
    pub type_name: Option<String>,
    /// `kind` metadata.
    pub kind: Option<String>,
    /// `instanceable` metadata (instancing is composed as plain copies).
    pub instanceable: bool,
    /// Composed `apiSchemas`.
    pub api_schemas: Vec<String>,
    /// Variant selections in effect, `(set, variant)`.
    pub variant_selections: Vec<(String, String)>,
    /// `doc` metadata.
    pub doc: Option<String>,
    /// The parent prim; `None` for root prims.
    pub parent: Option<PrimId>,
    /// Child prims in order.
    pub children: Vec<PrimId>,
    /// The strongest defining spec's `def Type "name"` text.
    pub span: Span,
    /// Attributes in authored order.
    pub attributes: Vec<Attribute>,
    /// Relationships in authored order.
    pub relationships: Vec<Relationship>,
}

impl Prim {
    /// The attribute named `name`.
    pub fn attribute(&self, name: &str) -> Option<&Attribute> {
        self.attributes.iter().find(|a| a.name == name)
    }

    /// The value of the attribute named `name`.
    pub fn value(&self, name: &str) -> Option<&Value> {
        self.attribute(name)?.get()
    }

    /// The relationship named `name`.
    pub fn relationship(&self, name: &str) -> Option<&Relationship> {
        self.relationships.iter().find(|r| r.name == name)
    }

    /// Relationships whose names start with `prefix`, e.g. `material:slotBinding:`.
    pub fn relationships_with_prefix<'p>(&'p self, prefix: &'p str) -> impl Iterator<Item = &'p Relationship> + 'p {
        self.relationships.iter().filter(move |r| r.name.starts_with(prefix))
    }
}

/// A composed stage: the renderable prim tree (defined, active, non-abstract prims).
#[derive(Debug)]
pub struct Stage {
    prims: Vec<Prim>,
    roots: Vec<PrimId>,
    by_path: HashMap<String, PrimId>,
    metadata: LayerMetadata,
    root_file: FileId,
    time: TimeCode,
}

impl Stage {
    /// Reads and composes the stage whose root layer is the file at `path`.
    pub fn open(path: &Path, sources: &mut SourceMap, diags: &mut Diagnostics) -> Result<Stage, Failed> {
        let errors = diags.error_count();
        // Text, crate or usdz, told by content (`usdc::read_layer_file`).
        let file = match usdc::read_layer_file(path) {
            Ok(file) => file,
            Err(e) => {
                diags.push(Diagnostic::error(format!("cannot read `{}`: {e}", path.display())));
                return Err(Failed);
            }
        };
        let dir = crate::input::layer_dir(&file.path);
        let key = Layers::key(&file.path);
        Stage::compose(&file.path.display().to_string(), file.source, dir, Some(key), sources, diags, errors)
    }

    /// Composes a stage from text (tests, embedded scenes). `name` is the display name for
    /// diagnostics; relative asset paths resolve against `base_dir`.
    pub fn from_text(
        name: &str,
        text: &str,
        base_dir: &Path,
        sources: &mut SourceMap,
        diags: &mut Diagnostics,
    ) -> Result<Stage, Failed> {
        let errors = diags.error_count();
        let source = LayerSource::Text(text.to_string());
        Stage::compose(name, source, base_dir.to_path_buf(), None, sources, diags, errors)
    }

    fn compose(
        name: &str,
        source: LayerSource,
        dir: PathBuf,
        key: Option<PathBuf>,
        sources: &mut SourceMap,
        diags: &mut Diagnostics,
        errors_before: usize,
    ) -> Result<Stage, Failed> {
        let mut layers = Layers::default();
        let mut chain = Chain::default();
        // The root layer is never dropped: its own errors are the stage's errors.
        let root = match layers.add(name, source, dir, key, None, &mut chain, sources, diags) {
            Some(opening) => {
                let index = opening.index;
                layers.load_sublayers(opening, &mut chain, sources, diags);
                index
            }
            None => 0,
        };
        // Redo the pass until it needs no layer that is not loaded yet.
        let arc_warnings;
        let mut stage = loop {
            let mut pass = Pass::new(&layers, root);
            pass.run();
            if pass.needs.is_empty() {
                diags.extend(pass.diags);
                arc_warnings = pass.warnings;
                break Stage {
                    prims: pass.prims,
                    roots: pass.roots,
                    by_path: pass.by_path,
                    metadata: layers.get(root).map(|l| l.layer.metadata.clone()).unwrap_or_default(),
                    root_file: layers.get(root).map(|l| l.layer.file).unwrap_or_default(),
                    time: TimeCode::Default,
                };
            }
            let needs = std::mem::take(&mut pass.needs);
            drop(pass);
            for (path, authored, span) in needs {
                layers.load(&path, &authored, span, &mut chain, sources, diags);
            }
        };
        layers.warnings.report(diags);
        arc_warnings.report(diags);
        stage.set_time(stage.opening_time());
        if diags.error_count() > errors_before { Err(Failed) } else { Ok(stage) }
    }

    /// The time every attribute's [`Attribute::value`] is read at.
    pub fn time(&self) -> TimeCode {
        self.time
    }

    /// Reads every attribute's [`Attribute::value`] at `time` (a stage opens at
    /// [`Stage::opening_time`]). Readers of the stage see values at that time without
    /// knowing about samples.
    pub fn set_time(&mut self, time: TimeCode) {
        self.time = time;
        for prim in &mut self.prims {
            for attr in prim.attributes.iter_mut().filter(|a| !a.time_samples.is_empty()) {
                attr.value = attr.value_at(time).map(|v| (v, attr.span));
            }
        }
    }

    /// A copy of the stage at `time` (see [`Stage::set_time`]): deformation blur poses
    /// skinned prims at the shutter's key times with it. Array values are shared, not copied.
    pub fn at_time(&self, time: TimeCode) -> Stage {
        let mut copy = Stage {
            prims: self.prims.clone(),
            roots: self.roots.clone(),
            by_path: self.by_path.clone(),
            metadata: self.metadata.clone(),
            root_file: self.root_file,
            time: self.time,
        };
        copy.set_time(time);
        copy
    }

    /// What usdview opens at: the root layer's `startTimeCode` (0 when not authored, as
    /// `UsdStage::GetStartTimeCode`) when any attribute is animated, else the default time.
    pub fn opening_time(&self) -> TimeCode {
        let animated = self.prims.iter().any(|p| p.attributes.iter().any(|a| !a.time_samples.is_empty()));
        if animated { TimeCode::At(self.start_time_code()) } else { TimeCode::Default }
    }

    /// The root layer's `timeCodesPerSecond`, else its `framesPerSecond`, else 24 (as
    /// `UsdStage::GetTimeCodesPerSecond`): what velocities, authored per second, are scaled by.
    pub fn time_codes_per_second(&self) -> f64 {
        let read = |key: &str| {
            let value = self.metadata.other.iter().find(|m| m.key == key).and_then(|m| m.value.as_f64());
            value.filter(|t| t.is_finite() && *t > 0.0)
        };
        read("timeCodesPerSecond").or_else(|| read("framesPerSecond")).unwrap_or(24.0)
    }

    /// The root layer's `startTimeCode` (0 when not authored).
    pub fn start_time_code(&self) -> f64 {
        let start = self.metadata.other.iter().find(|m| m.key == "startTimeCode").and_then(|m| m.value.as_f64());
        start.filter(|t| t.is_finite()).unwrap_or(0.0)
    }

    /// Root prims in order.
    pub fn root_children(&self) -> &[PrimId] {
        &self.roots
    }

    /// The prim with id `id` (ids come from this stage).
    pub fn prim(&self, id: PrimId) -> &Prim {
        &self.prims[id.0 as usize]
    }

    /// The prim with id `id`, to edit in place (a session's input-value change,
    /// `crate::session`). Its path and place in the hierarchy must not change.
    pub fn prim_mut(&mut self, id: PrimId) -> &mut Prim {
        &mut self.prims[id.0 as usize]
    }

    /// Number of prims.
    pub fn len(&self) -> usize {
        self.prims.len()
    }

    /// Whether the stage has no prims.
    pub fn is_empty(&self) -> bool {
        self.prims.is_empty()
    }

    /// The prim at an absolute path such as `/World/Mesh`.
    pub fn find(&self, path: &str) -> Option<PrimId> {
        self.by_path.get(path).copied()
    }

    /// Every prim in depth-first pre-order (parents before children, siblings in order).
    pub fn depth_first(&self) -> DepthFirst<'_> {
        DepthFirst { stage: self, stack: self.roots.iter().rev().copied().collect() }
    }

    /// `id` and its descendants in depth-first pre-order.
    pub fn subtree(&self, id: PrimId) -> DepthFirst<'_> {
        DepthFirst { stage: self, stack: vec![id] }
    }

    /// The root layer's metadata.
    pub fn metadata(&self) -> &LayerMetadata {
        &self.metadata
    }

    /// `upAxis` of the root layer (`"Y"` when not authored, as in USD).
    pub fn up_axis(&self) -> &str {
        self.metadata.up_axis.as_deref().unwrap_or("Y")
    }

    /// `metersPerUnit` of the root layer (0.01 when not authored, as in USD).
    pub fn meters_per_unit(&self) -> f64 {
        self.metadata.meters_per_unit.unwrap_or(0.01)
    }

    /// `defaultPrim` of the root layer.
    pub fn default_prim(&self) -> Option<PrimId> {
        let (name, _) = self.metadata.default_prim.as_ref()?;
        self.find(&format!("/{name}"))
    }

    /// The root layer's file.
    pub fn root_file(&self) -> FileId {
        self.root_file
    }
}

/// Depth-first iterator over prims; see [`Stage::depth_first`].
pub struct DepthFirst<'s> {
    stage: &'s Stage,
    stack: Vec<PrimId>,
}

impl<'s> Iterator for DepthFirst<'s> {
    type Item = (PrimId, &'s Prim);

    fn next(&mut self) -> Option<Self::Item> {
        let id = self.stack.pop()?;
        let prim = self.stage.prims.get(id.0 as usize)?;
        self.stack.extend(prim.children.iter().rev());
        Some((id, prim))
    }
}

thread_local! {
    /// Units of composition work that grow with the input (path keys computed, layers looked
    /// at for a prim's specs, layers walked into a stack); see [`composition_work`].
    static WORK: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// Counts `n` units of composition work.
#[inline]
fn count_work(n: usize) {
    WORK.with(|w| w.set(w.get().saturating_add(n as u64)));
}

/// Units of composition work done on this thread so far: path keys computed (a `realpath`
/// each), layers looked at for a prim's specs and layers walked into layer stacks. Tests read
/// it before and after opening a stage to check that composition stays linear in the number
/// of layers and arcs.
pub fn composition_work() -> u64 {
    WORK.with(|w| w.get())
}

#[cfg(test)]
mod tests;
