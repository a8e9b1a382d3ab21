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
//! by content; crates are converted to the same [`Layer`] syntax tree the usda parser builds.
//!
//! Referenced layers are loaded lazily: a composition pass records the layers it is missing,
//! they are loaded, and the pass is redone, so layers in unselected variants are never read.

use crate::diag::{Diagnostic, Diagnostics, Failed, FileId, OncePerKind, Severity, SourceMap, Span};
use crate::scene::time::{self, TimeCode};
use crate::scene::usda::{
    self, Layer, LayerMetadata, LayerOffset, ListOp, MetadataEntry, PrimSpec, PropertySpec, Reference, Specifier,
    Target,
};
use crate::scene::usdc::{self, LayerReadError, LayerSource};
use crate::scene::value::{AssetPath, Value, ValueType, normalize};
use std::cell::OnceCell;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

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

    /// What usdview opens at: the root layer's `startTimeCode` (0 when not authored, as
    /// `UsdStage::GetStartTimeCode`) when any attribute is animated, else the default time.
    pub fn opening_time(&self) -> TimeCode {
        let animated = self.prims.iter().any(|p| p.attributes.iter().any(|a| !a.time_samples.is_empty()));
        if animated { TimeCode::At(self.start_time_code()) } else { TimeCode::Default }
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

// ---- layers ----

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

struct LoadedLayer {
    layer: Layer,
    /// The sublayers that loaded, in authored order, each with its layer offset.
    sublayers: Vec<(usize, LayerOffset)>,
    /// The layer stack rooted at this layer, built the first time an arc or the stage needs
    /// it: building one per layer would make a chain of n sublayers cost n² (each layer's
    /// stack holds every layer below it).
    stack: OnceCell<LayerStack>,
}

/// A layer and its sublayers, recursively, strongest first (each layer once).
struct LayerStack {
    /// Indices into [`Layers::list`].
    layers: Vec<usize>,
    /// For each of `layers`, how its times map to the stack's root layer's (sublayer offsets).
    offsets: Vec<LayerOffset>,
    /// For each root prim name, the positions in `layers` of the layers that have a spec of
    /// it: a prim looks only at the layers that speak of it, so n sublayers with a prim each
    /// compose in O(n), not O(n²).
    by_root_prim: HashMap<String, Vec<u32>>,
}

/// The layers being read, root first: a sublayer chain is walked with this explicit stack,
/// not by recursion, so any depth loads without exhausting the thread's stack (a chain of
/// 4 500 sublayer files overflowed it; Pixar's library has no depth limit and opens it).
#[derive(Default)]
struct Chain {
    keys: Vec<PathBuf>,
    /// Position of each key in `keys`: the cycle check is O(1), not O(depth).
    position: HashMap<PathBuf, usize>,
}

impl Chain {
    fn push(&mut self, key: PathBuf) {
        self.position.insert(key.clone(), self.keys.len());
        self.keys.push(key);
    }

    fn pop(&mut self) {
        if let Some(key) = self.keys.pop() {
            self.position.remove(&key);
        }
    }
}

/// A registered layer whose sublayers are still to be loaded.
struct Opening {
    index: usize,
    /// Whether the layer has a key on the [`Chain`] (text composed from memory has none).
    on_chain: bool,
    sub_layers: std::iter::Enumerate<std::vec::IntoIter<(AssetPath, Span)>>,
    sub_offsets: Vec<LayerOffset>,
    /// Sublayers listed so far: listing one again adds no opinions, and reading it again
    /// would repeat its diagnostics.
    listed: HashSet<PathBuf>,
    repeats: usize,
}

/// What starting to load a layer gave.
enum Start {
    /// Known already (or failed, or a cycle): its index, if it loaded.
    Known(Option<usize>),
    /// Parsed and registered; its sublayers are still to load.
    Opened(Opening),
}

#[derive(Default)]
struct Layers {
    list: Vec<LoadedLayer>,
    /// Canonical path → index, or `None` when loading failed (reported once).
    by_key: HashMap<PathBuf, Option<usize>>,
    /// Sublayer cycles already reported, each as its sorted set of files: a cycle is one
    /// error however many paths lead into it (5 000 self-sublayers printed 563 MB).
    reported_cycles: HashSet<Vec<PathBuf>>,
    /// Layers the stage is composed without (missing, unreadable, MaterialX, malformed): USD
    /// composes around them, so they are warnings, one per kind.
    warnings: OncePerKind,
}

impl Layers {
    fn get(&self, index: usize) -> Option<&LoadedLayer> {
        self.list.get(index)
    }

    fn key(path: &Path) -> PathBuf {
        count_work(1);
        crate::input::canonicalize(path).unwrap_or_else(|_| normalize(path))
    }

    /// The layer stack rooted at layer `index`, if there is such a layer.
    fn stack(&self, index: usize) -> Option<&LayerStack> {
        let loaded = self.list.get(index)?;
        Some(loaded.stack.get_or_init(|| self.build_stack(index)))
    }

    /// Walks the sublayer graph from `root` in pre-order, strongest first, keeping each
    /// layer's first occurrence (a layer reached again adds no opinions).
    fn build_stack(&self, root: usize) -> LayerStack {
        let mut layers = Vec::new();
        let mut offsets = Vec::new();
        let mut seen = HashSet::new();
        let mut todo = vec![(root, LayerOffset::default())];
        while let Some((index, offset)) = todo.pop() {
            if !seen.insert(index) {
                continue;
            }
            let Some(loaded) = self.list.get(index) else { continue };
            count_work(1);
            layers.push(index);
            offsets.push(offset);
            todo.extend(loaded.sublayers.iter().rev().map(|&(sub, sub_offset)| (sub, offset.then(sub_offset))));
        }
        let mut by_root_prim: HashMap<String, Vec<u32>> = HashMap::new();
        for (position, &index) in layers.iter().enumerate() {
            for prim in &self.list[index].layer.prims {
                by_root_prim.entry(prim.name.clone()).or_default().push(position as u32);
            }
        }
        // A layer may list a root prim twice; each layer is looked at once per prim.
        for positions in by_root_prim.values_mut() {
            positions.dedup();
        }
        LayerStack { layers, offsets, by_root_prim }
    }

    /// Loads the layer at `path` (and its sublayers) unless known; diagnostics point at
    /// `span`, where the asset path `authored` names it. A layer that cannot be read or parsed
    /// is a warning, and the stage is composed without it, as USD does.
    fn load(
        &mut self,
        path: &Path,
        authored: &str,
        span: Span,
        chain: &mut Chain,
        sources: &mut SourceMap,
        diags: &mut Diagnostics,
    ) -> Option<usize> {
        match self.start(path, authored, span, chain, sources, diags) {
            Start::Known(index) => index,
            Start::Opened(opening) => {
                let index = opening.index;
                self.load_sublayers(opening, chain, sources, diags);
                Some(index)
            }
        }
    }

    /// Reads and registers the layer at `path`, unless it is known or a cycle; its
    /// sublayers are left to [`Layers::load_sublayers`].
    fn start(
        &mut self,
        path: &Path,
        authored: &str,
        span: Span,
        chain: &mut Chain,
        sources: &mut SourceMap,
        diags: &mut Diagnostics,
    ) -> Start {
        let key = Layers::key(path);
        if let Some(&start) = chain.position.get(&key) {
            let mut cycle = chain.keys[start..].to_vec();
            cycle.sort();
            if self.reported_cycles.insert(cycle) {
                diags.push(
                    Diagnostic::error(format!("sublayer cycle: `{}` includes itself", path.display()))
                        .at(span, "this sublayer is already being read"),
                );
            }
            return Start::Known(None);
        }
        if let Some(known) = self.by_key.get(&key) {
            return Start::Known(*known);
        }
        let file = match usdc::read_layer_file(path) {
            Ok(file) => file,
            Err(LayerReadError::MaterialX) => {
                self.warnings.push(
                    "materialx layer",
                    authored,
                    Diagnostic::warning(format!(
                        "`{authored}` is a MaterialX document; strata does not read MaterialX yet: its materials are absent"
                    ))
                    .at(span, "referenced here"),
                );
                self.by_key.insert(key, None);
                return Start::Known(None);
            }
            Err(LayerReadError::Unreadable(why)) => {
                self.warnings.push(
                    "unreadable layer",
                    authored,
                    Diagnostic::warning(format!(
                        "cannot read layer `{authored}`: {why}; the stage is composed without it"
                    ))
                    .at(span, "referenced here"),
                );
                self.by_key.insert(key, None);
                return Start::Known(None);
            }
        };
        let dir = crate::input::layer_dir(&file.path);
        // A usdz is known by its path and by its root layer's (`a.usdz[root.usdc]`).
        let file_key = Layers::key(&file.path);
        if file_key != key
            && let Some(known) = self.by_key.get(&file_key)
        {
            let known = *known;
            self.by_key.insert(key, known);
            return Start::Known(known);
        }
        let name = file.path.display().to_string();
        let opening =
            self.add(&name, file.source, dir, Some(file_key.clone()), Some((authored, span)), chain, sources, diags);
        let index = opening.as_ref().map(|o| o.index);
        if index.is_none() {
            self.by_key.insert(file_key, None);
        }
        self.by_key.insert(key, index);
        opening.map_or(Start::Known(None), Start::Opened)
    }

    /// Parses a layer's text and registers it; its sublayers are left to
    /// [`Layers::load_sublayers`]. `from` is the asset path and span that name the layer,
    /// `None` for the root layer: a root layer with syntax errors fails the stage, any other
    /// is left out with a warning (`None`), as USD does.
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        name: &str,
        source: LayerSource,
        dir: PathBuf,
        key: Option<PathBuf>,
        from: Option<(&str, Span)>,
        chain: &mut Chain,
        sources: &mut SourceMap,
        diags: &mut Diagnostics,
    ) -> Option<Opening> {
        let mut parsed = Diagnostics::new();
        let layer = match source {
            LayerSource::Text(text) => {
                let file = sources.add(name, text);
                usda::parse(file, sources.text(file), &dir, &mut parsed)
            }
            LayerSource::Crate(bytes) => usdc::convert(name, &bytes, &dir, sources, &mut parsed),
        };
        if let Some((authored, span)) = from
            && let Some(first) = parsed.items().iter().find(|d| d.severity == Severity::Error)
        {
            let mut warning = Diagnostic::warning(format!(
                "layer `{authored}` is not valid USD: {}; the stage is composed without it",
                first.message
            ))
            .at(span, "referenced here");
            if let Some(label) = first.labels.iter().find(|l| l.primary).or(first.labels.first()) {
                warning = warning.note(format!("first error at {}", sources.location(label.span)));
            }
            self.warnings.push("malformed layer", authored, warning);
            return None;
        }
        diags.extend(parsed);
        let index = self.list.len();
        let sub_layers = layer.metadata.sub_layers.clone();
        let sub_offsets = layer.metadata.sub_layer_offsets.clone();
        self.list.push(LoadedLayer { layer, sublayers: Vec::new(), stack: OnceCell::new() });
        if let Some(key) = &key {
            self.by_key.insert(key.clone(), Some(index));
            chain.push(key.clone());
        }
        Some(Opening {
            index,
            on_chain: key.is_some(),
            sub_layers: sub_layers.into_iter().enumerate(),
            sub_offsets,
            listed: HashSet::new(),
            repeats: 0,
        })
    }

    /// Loads the sublayers of `first`, and theirs, depth first, without recursion.
    fn load_sublayers(&mut self, first: Opening, chain: &mut Chain, sources: &mut SourceMap, diags: &mut Diagnostics) {
        let mut open = vec![first];
        while let Some(top) = open.last_mut() {
            let Some((i, (asset, span))) = top.sub_layers.next() else {
                if top.on_chain {
                    chain.pop();
                }
                open.pop();
                continue;
            };
            let sub_offset = top.sub_offsets.get(i).copied().unwrap_or_default();
            if !top.listed.insert(Layers::key(&asset.resolved)) {
                if top.repeats == 0 {
                    diags.push(
                        Diagnostic::warning(format!("`{}` is listed more than once in subLayers", asset.authored))
                            .at(span, "listed again here; repeats are ignored"),
                    );
                }
                top.repeats += 1;
                continue;
            }
            let parent = top.index;
            let sub = match self.start(&asset.resolved, &asset.authored, span, chain, sources, diags) {
                Start::Known(index) => index,
                Start::Opened(opening) => {
                    let index = opening.index;
                    open.push(opening);
                    Some(index)
                }
            };
            if let Some(sub) = sub
                && let Some(loaded) = self.list.get_mut(parent)
            {
                loaded.sublayers.push((sub, sub_offset));
            }
        }
    }
}

// ---- composition ----

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Arc {
    Root,
    Inherit,
    Variant,
    Reference,
    Payload,
}

/// Prefix mappings from a node's namespace to the stage's, innermost first.
type MapChain = Vec<(String, String)>;

/// Past this many nodes in one prim's index, composition gives up on further arcs.
const MAX_NODES: usize = 4096;

struct Node<'l> {
    arc: Arc,
    /// The root layer of the layer stack this node's site lives in.
    stack: usize,
    /// The prim path in that layer stack's namespace.
    site: String,
    /// Specs at the site, strongest first.
    specs: Vec<&'l PrimSpec>,
    /// For each of `specs`, how its layer's times map to the stage's.
    offsets: Vec<LayerOffset>,
    /// How times in the root layer of `stack` map to the stage's (the arcs' layer offsets).
    time: LayerOffset,
    map: MapChain,
    children: Vec<Node<'l>>,
    /// Added for this prim (not inherited from an ancestor's index).
    direct: bool,
    expanded: bool,
    /// Variant sets already applied at this node.
    variants_done: Vec<String>,
}

impl<'l> Node<'l> {
    /// The node for the same arc one level down, at child `name`; `None` if nothing is there.
    fn child(&self, name: &str) -> Option<Node<'l>> {
        let (specs, offsets): (Vec<&PrimSpec>, Vec<LayerOffset>) =
            self.specs.iter().zip(&self.offsets).filter_map(|(s, o)| Some((s.child(name)?, *o))).unzip();
        let children: Vec<Node> = self.children.iter().filter_map(|c| c.child(name)).collect();
        if specs.is_empty() && children.is_empty() {
            return None;
        }
        Some(Node {
            arc: self.arc,
            stack: self.stack,
            site: join_path(&self.site, name),
            specs,
            offsets,
            time: self.time,
            map: self.map.clone(),
            children,
            direct: false,
            expanded: false,
            variants_done: Vec::new(),
        })
    }

    fn count(&self) -> usize {
        1 + self.children.iter().map(Node::count).sum::<usize>()
    }

    /// Inserts a direct arc after the direct arcs of the same type, before ancestral ones.
    fn insert_child(&mut self, node: Node<'l>) {
        let at = self
            .children
            .iter()
            .position(|c| c.arc > node.arc || (c.arc == node.arc && !c.direct))
            .unwrap_or(self.children.len());
        self.children.insert(at, node);
    }

    /// How the times of `attr`, an attribute of one of this node's specs, map to the stage's.
    fn offset_of(&self, attr: &usda::AttributeSpec) -> LayerOffset {
        let owns = |spec: &PrimSpec| {
            spec.properties.iter().any(|p| matches!(p, PropertySpec::Attribute(a) if std::ptr::eq(&**a, attr)))
        };
        let at = self.specs.iter().position(|s| owns(s));
        at.and_then(|i| self.offsets.get(i)).copied().unwrap_or(self.time)
    }

    /// Every `(spec, node)` pair in strength order.
    fn flatten<'n>(&'n self, out: &mut Vec<(&'l PrimSpec, &'n Node<'l>)>) {
        for spec in &self.specs {
            out.push((spec, self));
        }
        for child in &self.children {
            child.flatten(out);
        }
    }
}

fn join_path(parent: &str, name: &str) -> String {
    if parent == "/" || parent.is_empty() { format!("/{name}") } else { format!("{parent}/{name}") }
}

/// Maps a path authored at `site` in a node's namespace to the stage's namespace.
fn map_path(chain: &MapChain, site: &str, path: &str) -> String {
    let mut path = anchor(site, path);
    for (from, to) in chain {
        if let Some(rest) = path.strip_prefix(from.as_str())
            && (rest.is_empty() || rest.starts_with('/') || rest.starts_with('.'))
        {
            path = format!("{to}{rest}");
        }
    }
    path
}

/// Makes a relative path (`../Mat`, `Child`, `.prop`) absolute against the prim at `site`.
fn anchor(site: &str, path: &str) -> String {
    if path.starts_with('/') || path.is_empty() {
        return path.to_string();
    }
    let mut base: Vec<&str> = site.split('/').filter(|s| !s.is_empty()).collect();
    let mut rest = path;
    loop {
        if let Some(r) = rest.strip_prefix("../") {
            base.pop();
            rest = r;
        } else if rest == ".." {
            base.pop();
            rest = "";
        } else if let Some(r) = rest.strip_prefix("./") {
            rest = r;
        } else {
            break;
        }
    }
    let mut out = String::new();
    for b in &base {
        out.push('/');
        out.push_str(b);
    }
    if rest.starts_with('.') || rest.is_empty() {
        if out.is_empty() {
            out.push('/');
        }
        out.push_str(rest);
    } else {
        out.push('/');
        out.push_str(rest);
    }
    out
}

struct Pass<'l> {
    layers: &'l Layers,
    root: usize,
    diags: Diagnostics,
    /// Layers this pass wanted but that are not loaded yet: resolved path, authored asset
    /// path, and where it is named.
    needs: Vec<(PathBuf, String, Span)>,
    /// The keys of `needs`.
    needed: HashSet<PathBuf>,
    /// Resolved asset path → [`Layers::key`], computed once per pass.
    keys: HashMap<PathBuf, PathBuf>,
    /// Arcs composed around (a target prim that does not exist), one warning per kind.
    warnings: OncePerKind,
    prims: Vec<Prim>,
    roots: Vec<PrimId>,
    by_path: HashMap<String, PrimId>,
    /// Arcs whose cycle or size error was reported: each authored arc is reported once,
    /// not once per prim that reaches it (every descendant of a prim re-walks its arcs).
    reported_arcs: HashSet<Span>,
}

impl<'l> Pass<'l> {
    fn new(layers: &'l Layers, root: usize) -> Pass<'l> {
        Pass {
            layers,
            root,
            diags: Diagnostics::new(),
            needs: Vec::new(),
            needed: HashSet::new(),
            keys: HashMap::new(),
            warnings: OncePerKind::new(),
            prims: Vec::new(),
            roots: Vec::new(),
            by_path: HashMap::new(),
            reported_arcs: HashSet::new(),
        }
    }

    fn stack(&self, layer: usize) -> &'l [usize] {
        self.layers.stack(layer).map(|s| s.layers.as_slice()).unwrap_or(&[])
    }

    /// Specs at `path` in every layer of `stack`, strongest first, each with how its times
    /// map to the stage's when the stack's root layer's map through `time`.
    fn specs_at(&self, stack: usize, path: &str, time: LayerOffset) -> (Vec<&'l PrimSpec>, Vec<LayerOffset>) {
        let layers = self.layers;
        let Some(stack) = layers.stack(stack) else { return (Vec::new(), Vec::new()) };
        let Some(root_name) = path.split('/').find(|s| !s.is_empty()) else { return (Vec::new(), Vec::new()) };
        let Some(positions) = stack.by_root_prim.get(root_name) else { return (Vec::new(), Vec::new()) };
        count_work(positions.len());
        positions
            .iter()
            .filter_map(|&at| {
                let at = at as usize;
                let spec = layers.get(*stack.layers.get(at)?)?.layer.prim_at(path)?;
                Some((spec, time.then(*stack.offsets.get(at)?)))
            })
            .unzip()
    }

    fn run(&mut self) {
        let layers = self.layers;
        // Root prim names, weakest layer first so stronger layers' new names come after.
        let mut names: Vec<&str> = Vec::new();
        let mut seen: HashSet<&str> = HashSet::new();
        for &i in self.stack(self.root).iter().rev() {
            if let Some(l) = layers.get(i) {
                for p in &l.layer.prims {
                    if seen.insert(&p.name) {
                        names.push(&p.name);
                    }
                }
            }
        }
        for name in names {
            let site = format!("/{name}");
            let (specs, offsets) = self.specs_at(self.root, &site, LayerOffset::default());
            let node = Node {
                arc: Arc::Root,
                stack: self.root,
                specs,
                offsets,
                time: LayerOffset::default(),
                site,
                map: Vec::new(),
                children: Vec::new(),
                direct: true,
                expanded: false,
                variants_done: Vec::new(),
            };
            if let Some(id) = self.compose_prim(node, None, name) {
                self.roots.push(id);
            }
        }
    }

    /// Composes one prim from its index tree, then its children. Returns `None` for prims
    /// that are not part of the renderable tree (abstract, undefined or inactive).
    fn compose_prim(&mut self, mut tree: Node<'l>, parent: Option<PrimId>, name: &str) -> Option<PrimId> {
        let path = match parent {
            Some(p) => join_path(&self.prims[p.0 as usize].path, name),
            None => format!("/{name}"),
        };
        self.expand(&mut tree, &mut Vec::new());
        self.apply_variants(&mut tree, &path);

        let mut opinions = Vec::new();
        tree.flatten(&mut opinions);

        let specifier =
            opinions.iter().map(|(s, _)| s.specifier).find(|s| *s != Specifier::Over).unwrap_or(Specifier::Over);
        let active = opinions.iter().find_map(|(s, _)| s.metadata.active).unwrap_or(true);
        if specifier != Specifier::Def || !active {
            return None;
        }
        let span =
            opinions.iter().find(|(s, _)| s.specifier == Specifier::Def).map(|(s, _)| s.span).unwrap_or_default();
        let mut api_schemas = Vec::new();
        for (spec, _) in opinions.iter().rev() {
            spec.metadata.api_schemas.apply(&mut api_schemas, |a, b| a == b);
        }
        let (attributes, relationships) = compose_properties(&opinions);
        let prim = Prim {
            path: path.clone(),
            name: name.to_string(),
            type_name: opinions.iter().find_map(|(s, _)| s.type_name.clone()),
            kind: opinions.iter().find_map(|(s, _)| s.metadata.kind.clone()),
            instanceable: opinions.iter().find_map(|(s, _)| s.metadata.instanceable).unwrap_or(false),
            api_schemas,
            variant_selections: selections(&opinions),
            doc: opinions.iter().find_map(|(s, _)| s.metadata.doc.clone()),
            parent,
            children: Vec::new(),
            span,
            attributes,
            relationships,
        };
        let id = PrimId(self.prims.len() as u32);
        self.prims.push(prim);
        self.by_path.insert(path, id);

        // Child names, weakest opinion first, so an asset's order is kept and local
        // additions follow it.
        let mut names: Vec<&'l str> = Vec::new();
        let mut seen: HashSet<&'l str> = HashSet::new();
        for (spec, _) in opinions.iter().rev() {
            for child in &spec.children {
                if seen.insert(&child.name) {
                    names.push(&child.name);
                }
            }
        }
        drop(opinions);
        let mut children = Vec::new();
        for child_name in names {
            if let Some(child_tree) = tree.child(child_name)
                && let Some(child) = self.compose_prim(child_tree, Some(id), child_name)
            {
                children.push(child);
            }
        }
        if let Some(prim) = self.prims.get_mut(id.0 as usize) {
            prim.children = children;
        }
        Some(id)
    }

    /// Adds the inherit, reference and payload arcs authored on every node's specs.
    fn expand(&mut self, node: &mut Node<'l>, ancestors: &mut Vec<(usize, String)>) {
        ancestors.push((node.stack, node.site.clone()));
        if !node.expanded {
            node.expanded = true;
            for arc in self.direct_arcs(node, ancestors) {
                node.insert_child(arc);
            }
        }
        for child in &mut node.children {
            self.expand(child, ancestors);
        }
        ancestors.pop();
    }

    fn direct_arcs(&mut self, node: &Node<'l>, ancestors: &[(usize, String)]) -> Vec<Node<'l>> {
        let mut inherits: Vec<Target> = Vec::new();
        let mut references: Vec<Reference> = Vec::new();
        let mut payloads: Vec<Reference> = Vec::new();
        for spec in node.specs.iter().rev() {
            spec.metadata.inherits.apply(&mut inherits, |a, b| a.0 == b.0);
            spec.metadata.references.apply(&mut references, same_reference);
            spec.metadata.payloads.apply(&mut payloads, same_reference);
            if !spec.metadata.specializes.is_empty() {
                self.diags
                    .push(Diagnostic::warning("`specializes` is not supported; ignored").at(spec.span, "on this prim"));
            }
        }
        let mut arcs = Vec::new();
        for (path, span) in inherits {
            let target = anchor(&node.site, &path);
            if let Some(n) = self.arc_node(node, Arc::Inherit, node.stack, target, node.time, span, ancestors) {
                arcs.push(n);
            }
        }
        for (arc, list) in [(Arc::Reference, references), (Arc::Payload, payloads)] {
            for reference in list {
                let Some((stack, target)) = self.reference_target(node, &reference) else {
                    continue;
                };
                // The reference's offset applies within the referencing layer stack (the
                // sublayer offset of the layer that authored it is not composed in).
                let time = node.time.then(reference.offset);
                if let Some(n) = self.arc_node(node, arc, stack, target, time, reference.span, ancestors) {
                    arcs.push(n);
                }
            }
        }
        arcs
    }

    /// The layer stack and prim path a reference or payload points at.
    fn reference_target(&mut self, node: &Node<'l>, reference: &Reference) -> Option<(usize, String)> {
        let stack = match &reference.asset {
            None => node.stack,
            Some(asset) => self.layer_for(asset, reference.span)?,
        };
        let path = match &reference.prim_path {
            Some(p) => anchor(&node.site, p),
            None => {
                let layer = &self.layers.get(stack)?.layer;
                match &layer.metadata.default_prim {
                    Some((name, _)) => format!("/{name}"),
                    None => {
                        let authored = reference.asset.as_ref().map_or("", |a| a.authored.as_str());
                        self.warnings.push(
                            "missing default prim",
                            authored,
                            Diagnostic::warning(format!(
                                "`{authored}` has no `defaultPrim` and the arc names no prim: it adds nothing"
                            ))
                            .at(reference.span, "name the prim: `@file.usda@</Prim>`"),
                        );
                        return None;
                    }
                }
            }
        };
        Some((stack, path))
    }

    /// The loaded layer for an asset, or records it as needed for the next pass.
    fn layer_for(&mut self, asset: &AssetPath, span: Span) -> Option<usize> {
        // Every prim below a reference asks again: the key (a `realpath`) is computed once
        // per asset path and pass, and needed layers are a set, so n distinct references
        // cost O(n), not O(n²) system calls (10 000 references took 85 s).
        let key = match self.keys.get(&asset.resolved) {
            Some(key) => key.clone(),
            None => {
                let key = Layers::key(&asset.resolved);
                self.keys.insert(asset.resolved.clone(), key.clone());
                key
            }
        };
        match self.layers.by_key.get(&key) {
            Some(known) => *known,
            None => {
                if self.needed.insert(key) {
                    self.needs.push((asset.resolved.clone(), asset.authored.clone(), span));
                }
                None
            }
        }
    }

    /// The node of an arc from `from` to `site` in `stack`, whose root layer's times map to
    /// the stage's through `time`.
    #[allow(clippy::too_many_arguments)]
    fn arc_node(
        &mut self,
        from: &Node<'l>,
        arc: Arc,
        stack: usize,
        site: String,
        time: LayerOffset,
        span: Span,
        ancestors: &[(usize, String)],
    ) -> Option<Node<'l>> {
        if ancestors.iter().any(|(s, p)| *s == stack && *p == site) {
            let what = if arc == Arc::Inherit { "inherit" } else { "reference" };
            if self.reported_arcs.insert(span) {
                self.diags.push(
                    Diagnostic::error(format!("{what} cycle: `{site}` depends on itself"))
                        .at(span, format!("this {what} leads back to a prim that is being composed")),
                );
            }
            return None;
        }
        if ancestors.len() > 64 || from.count() > MAX_NODES {
            if self.reported_arcs.insert(span) {
                self.diags.push(
                    Diagnostic::error("composition is too deep or too large").at(span, "while composing this arc"),
                );
            }
            return None;
        }
        let (specs, offsets) = self.specs_at(stack, &site, time);
        // An inherit of a class nobody defines is ordinary USD (the class is an extension
        // point); a reference or payload to nothing is composed around, as USD does.
        if specs.is_empty() && arc != Arc::Inherit {
            let what = if arc == Arc::Payload { "payload" } else { "reference" };
            if self.reported_arcs.insert(span) {
                self.warnings.push(
                    "missing arc target",
                    &site,
                    Diagnostic::warning(format!(
                        "the prim `{site}` that this {what} targets does not exist: the {what} adds nothing"
                    ))
                    .at(span, format!("{what} here")),
                );
            }
            return None;
        }
        let mut map = Vec::with_capacity(from.map.len() + 1);
        map.push((site.clone(), from.site.clone()));
        map.extend(from.map.iter().cloned());
        Some(Node {
            arc,
            stack,
            site,
            specs,
            offsets,
            time,
            map,
            children: Vec::new(),
            direct: true,
            expanded: false,
            variants_done: Vec::new(),
        })
    }

    /// Applies variant selections as USD's prim indexing does: one variant set at a time,
    /// the strongest node's first, each selected by the strongest opinion in the index as it
    /// stands then. A selection authored inside a variant is an opinion like any other once
    /// that variant is applied, so nested selections apply to any depth; a set that has no
    /// selection yet waits until every other set is applied, as a later variant may select
    /// it. A set defined on several arcs gets the selected variant from each arc that has it.
    fn apply_variants(&mut self, tree: &mut Node<'l>, path: &str) {
        let mut pending = VariantReport::default();
        for _ in 0..MAX_NODES {
            let chosen = {
                let mut opinions = Vec::new();
                tree.flatten(&mut opinions);
                selections(&opinions)
            };
            if !self.apply_next_variant(tree, &chosen, &mut pending) {
                break;
            }
            self.expand(tree, &mut Vec::new());
        }
        // What is left: sets nobody selects, and selections no arc offers.
        let mut unselected: Vec<(&'l str, Span)> = Vec::new();
        tree.unapplied_sets(&mut unselected);
        let mut warned: Vec<&str> = Vec::new();
        for (set_name, span) in unselected {
            if !warned.contains(&set_name) {
                warned.push(set_name);
                self.diags.push(
                    Diagnostic::warning(format!("no variant selected for variant set `{set_name}` on `{path}`"))
                        .at(span, "no variant of this set is applied"),
                );
            }
        }
        for (set_name, selection, span) in pending.missing {
            if !pending.found.iter().any(|(s, v)| *s == set_name && *v == selection) {
                self.diags.push(
                    Diagnostic::warning(format!(
                        "variant `{selection}` selected for `{set_name}` on `{path}` does not exist"
                    ))
                    .at(span, "this set has no such variant"),
                );
            }
        }
    }

    /// Applies the first variant set, in strength order, that is not applied yet and has a
    /// selection in `chosen`. Returns whether one was.
    fn apply_next_variant(
        &mut self,
        node: &mut Node<'l>,
        chosen: &[(String, String)],
        report: &mut VariantReport<'l>,
    ) -> bool {
        let mut next: Option<(&'l str, &str)> = None;
        'specs: for spec in &node.specs {
            for set in &spec.variant_sets {
                if node.variants_done.contains(&set.name) {
                    continue;
                }
                if let Some((_, selection)) = chosen.iter().find(|(s, _)| *s == set.name) {
                    next = Some((&set.name, selection));
                    break 'specs;
                }
            }
        }
        if let Some((set_name, selection)) = next {
            node.variants_done.push(set_name.to_string());
            let sets = node
                .specs
                .iter()
                .zip(&node.offsets)
                .filter_map(|(s, o)| Some((s.variant_sets.iter().find(|v| v.name == set_name)?, *o)));
            let mut bodies: Vec<&'l PrimSpec> = Vec::new();
            let mut offsets: Vec<LayerOffset> = Vec::new();
            let mut first_set = None;
            for (set, offset) in sets {
                first_set.get_or_insert(set.span);
                if let Some(body) = set.variants.iter().find(|v| v.name == *selection) {
                    bodies.push(body);
                    offsets.push(offset);
                }
            }
            if bodies.is_empty() {
                if let Some(span) = first_set
                    && !report.missing.iter().any(|(s, v, _)| *s == set_name && v == selection)
                {
                    report.missing.push((set_name, selection.to_string(), span));
                }
            } else {
                if !report.found.iter().any(|(s, v)| *s == set_name && v == selection) {
                    report.found.push((set_name, selection.to_string()));
                }
                node.insert_child(Node {
                    arc: Arc::Variant,
                    stack: node.stack,
                    site: node.site.clone(),
                    specs: bodies,
                    offsets,
                    time: node.time,
                    map: node.map.clone(),
                    children: Vec::new(),
                    direct: true,
                    expanded: false,
                    variants_done: Vec::new(),
                });
            }
            return true;
        }
        node.children.iter_mut().any(|child| self.apply_next_variant(child, chosen, report))
    }
}

/// Variant selections seen while composing one prim: which (set, variant) pairs some arc
/// offered, and which selections an arc's set lacked, with that set's span. A selection is
/// reported missing only when no arc offers it: a set may be split across arcs.
#[derive(Default)]
struct VariantReport<'l> {
    found: Vec<(&'l str, String)>,
    missing: Vec<(&'l str, String, Span)>,
}

impl<'l> Node<'l> {
    /// Variant sets of this node and its descendants that no selection applied, with the
    /// span of their first `variantSet` statement.
    fn unapplied_sets(&self, out: &mut Vec<(&'l str, Span)>) {
        for spec in &self.specs {
            for set in &spec.variant_sets {
                if !self.variants_done.contains(&set.name) && !out.iter().any(|(s, _)| *s == set.name) {
                    out.push((&set.name, set.span));
                }
            }
        }
        for child in &self.children {
            child.unapplied_sets(out);
        }
    }
}

fn same_reference(a: &Reference, b: &Reference) -> bool {
    a.asset.as_ref().map(|x| &x.resolved) == b.asset.as_ref().map(|x| &x.resolved) && a.prim_path == b.prim_path
}

/// Variant selections, strongest opinion per set.
fn selections(opinions: &[(&PrimSpec, &Node)]) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    for (spec, _) in opinions {
        for (set, selection, _) in &spec.metadata.variant_selections {
            if !out.iter().any(|(s, _)| s == set) {
                out.push((set.clone(), selection.clone()));
            }
        }
    }
    out
}

/// Composes properties from opinions in strength order.
fn compose_properties(opinions: &[(&PrimSpec, &Node)]) -> (Vec<Attribute>, Vec<Relationship>) {
    // Group each property's opinions, strongest first, in first-seen order.
    let mut order: Vec<&str> = Vec::new();
    let mut groups: HashMap<&str, Vec<(&PropertySpec, &Node)>> = HashMap::new();
    for (spec, node) in opinions {
        for property in &spec.properties {
            let name = property.name();
            let group = groups.entry(name).or_insert_with(|| {
                order.push(name);
                Vec::new()
            });
            group.push((property, *node));
        }
    }
    let mut attributes = Vec::new();
    let mut relationships = Vec::new();
    for name in order {
        let Some(group) = groups.get(name) else {
            continue;
        };
        match group.first() {
            Some((PropertySpec::Attribute(_), _)) => {
                let specs: Vec<_> = group
                    .iter()
                    .filter_map(|(p, n)| match p {
                        PropertySpec::Attribute(a) => Some((&**a, *n)),
                        PropertySpec::Relationship(_) => None,
                    })
                    .collect();
                attributes.push(compose_attribute(&specs));
            }
            Some((PropertySpec::Relationship(_), _)) => {
                let specs: Vec<_> = group
                    .iter()
                    .filter_map(|(p, n)| match p {
                        PropertySpec::Relationship(r) => Some((&**r, *n)),
                        PropertySpec::Attribute(_) => None,
                    })
                    .collect();
                relationships.push(compose_relationship(&specs));
            }
            None => {}
        }
    }
    (attributes, relationships)
}

/// Targets of one opinion mapped into the stage's namespace.
fn mapped(op: &ListOp<Target>, node: &Node) -> ListOp<Target> {
    let map = |items: &Vec<Target>| -> Vec<Target> {
        items.iter().map(|(p, s)| (map_path(&node.map, &node.site, p), *s)).collect()
    };
    ListOp {
        explicit: op.explicit.as_ref().map(map),
        prepended: map(&op.prepended),
        appended: map(&op.appended),
        deleted: map(&op.deleted),
        added: map(&op.added),
        ordered: map(&op.ordered),
    }
}

fn merge_metadata(out: &mut Vec<MetadataEntry>, entries: &[MetadataEntry]) {
    for entry in entries {
        if !out.iter().any(|m| m.key == entry.key) {
            out.push(entry.clone());
        }
    }
}

fn compose_attribute(specs: &[(&usda::AttributeSpec, &Node)]) -> Attribute {
    let (strongest, _) = specs[0];
    let mut default_value = None;
    let mut blocked = false;
    // The strongest default wins; a block (`= None`) hides every weaker value.
    if let Some((v, span)) = specs.iter().find_map(|(a, _)| a.default.as_ref()) {
        if v.is_none() {
            blocked = true;
        } else {
            default_value = Some((v.clone(), *span));
        }
    }
    // At a numeric time the strongest opinion with a value decides: its samples if it has
    // any (they beat its own default), else its default or block.
    // Sample times are the authoring layer's, mapped to the stage's by the layer offsets.
    let mut time_samples = specs
        .iter()
        .find(|(a, _)| !a.time_samples.is_empty() || a.default.is_some())
        .map(|(a, node)| {
            let offset = if a.time_samples.is_empty() { LayerOffset::default() } else { node.offset_of(a) };
            a.time_samples.iter().map(|(t, v)| (offset.apply(*t), v.clone())).collect()
        })
        .unwrap_or_default();
    time::sort_samples(&mut time_samples);
    let mut connections = Vec::new();
    let mut metadata = Vec::new();
    for (a, node) in specs.iter().rev() {
        mapped(&a.connections, node).apply(&mut connections, |x, y| x.0 == y.0);
    }
    for (a, _) in specs {
        merge_metadata(&mut metadata, &a.metadata);
    }
    Attribute {
        name: strongest.name.clone(),
        type_name: strongest.type_name.clone(),
        value_type: strongest.value_type,
        // Read at the stage's time once the stage is composed (`Stage::set_time`).
        value: default_value.clone(),
        default_value,
        blocked,
        span: strongest.span,
        custom: specs.iter().any(|(a, _)| a.custom),
        uniform: specs.iter().any(|(a, _)| a.uniform),
        connections,
        time_samples,
        metadata,
    }
}

fn compose_relationship(specs: &[(&usda::RelationshipSpec, &Node)]) -> Relationship {
    let (strongest, _) = specs[0];
    let mut targets = Vec::new();
    let mut explicit = false;
    for (r, node) in specs.iter().rev() {
        explicit |= mapped(&r.targets, node).apply(&mut targets, |x, y| x.0 == y.0);
    }
    let mut metadata = Vec::new();
    for (r, _) in specs {
        merge_metadata(&mut metadata, &r.metadata);
    }
    Relationship {
        name: strongest.name.clone(),
        targets,
        explicit,
        authored: specs.iter().find_map(|(r, _)| r.authored),
        span: strongest.span,
        custom: specs.iter().any(|(r, _)| r.custom),
        metadata,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    fn fixtures() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/usd")
    }

    fn open(path: &Path) -> (Result<Stage, Failed>, String) {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::open(path, &mut sources, &mut diags);
        (stage, diags.render(&sources))
    }

    fn text(text: &str) -> (Result<Stage, Failed>, String) {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("scene.usda", text, Path::new("/nowhere"), &mut sources, &mut diags);
        (stage, diags.render(&sources))
    }

    fn ok(stage: (Result<Stage, Failed>, String)) -> Stage {
        match stage {
            (Ok(stage), _) => stage,
            (Err(_), rendered) => panic!("{rendered}"),
        }
    }

    /// A fresh directory under the system temp dir.
    fn temp_dir(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new().prefix(name).tempdir().expect("temp dir")
    }

    fn prim<'s>(stage: &'s Stage, path: &str) -> &'s Prim {
        stage.prim(stage.find(path).unwrap_or_else(|| panic!("no prim {path}")))
    }

    #[test]
    fn pixar_written_fixture() {
        let stage = ok(open(&fixtures().join("pixar_written.usda")));
        assert_eq!(stage.up_axis(), "Y");
        assert_eq!(stage.meters_per_unit(), 0.01);
        assert_eq!(stage.default_prim(), stage.find("/World"));
        let world = prim(&stage, "/World");
        assert_eq!(world.type_name.as_deref(), Some("Xform"));
        assert_eq!(world.value("xformOp:translate").and_then(Value::as_vec3), Some([1.0, 2.0, 3.0]));
        assert_eq!(world.value("xformOp:rotateXYZ").and_then(Value::as_vec3), Some([0.0, 90.0, 0.0]));
        assert_eq!(world.value("xformOpOrder").and_then(Value::as_string_array).map(<[String]>::len), Some(3));
        let quad = prim(&stage, "/World/Group/Quad");
        assert_eq!(quad.type_name.as_deref(), Some("Mesh"));
        assert_eq!(quad.value("faceVertexIndices").and_then(Value::as_int_array), Some(&[0, 1, 2, 3][..]));
        let points = quad.value("points").and_then(Value::as_vec3_array).unwrap();
        assert_eq!(points[0], [-1.0, 0.0, -1.0]);
        let st = quad.attribute("primvars:st").unwrap();
        assert_eq!(st.type_name, "texCoord2f[]");
        assert_eq!(st.meta("interpolation").and_then(Value::as_str), Some("faceVarying"));
        assert_eq!(st.get().and_then(Value::as_tuple_array).map(|(w, d)| (w, d.len())), Some((2, 8)));
        assert_eq!(quad.value("doubleSided"), Some(&Value::Bool(true)));
        let slot0 = quad.relationship("material:slotBinding:_000").unwrap();
        assert_eq!(slot0.targets[0].0, "/World/Looks/Plastic");
        let slot50 = quad.relationship("material:slotBinding:_050").unwrap();
        assert!(slot50.is_explicit_empty());
        let nested = quad.relationship("material:slotBinding:_050:_:_010").unwrap();
        assert_eq!(nested.targets.len(), 2);
        assert_eq!(quad.relationships_with_prefix("material:slotBinding:").count(), 3);
        let ball = prim(&stage, "/World/Ball");
        assert_eq!(ball.api_schemas, vec!["MaterialBindingAPI".to_string()]);
        assert_eq!(ball.value("radius"), Some(&Value::Float(0.5)));
        let cam = prim(&stage, "/World/Cam");
        let m = cam.value("xformOp:transform").and_then(Value::as_matrix4).unwrap();
        assert_eq!(&m[12..], &[0.0, 1.0, 5.0, 1.0]);
        let sky = prim(&stage, "/World/Sky");
        let tex = sky.value("inputs:texture:file").and_then(Value::as_asset).unwrap();
        assert_eq!(tex.resolved, fixtures().join("sky.exr"));
        assert_eq!(prim(&stage, "/World/Panel").type_name.as_deref(), Some("RectLight"));
        let shader = prim(&stage, "/World/Looks/Plastic/Surface");
        assert_eq!(shader.value("info:implementationSource").and_then(Value::as_str), Some("sourceAsset"));
        let source = shader.value("info:strata:sourceAsset").and_then(Value::as_asset).unwrap();
        assert_eq!(source.authored, "plastic.ash");
        assert_eq!(shader.value("info:strata:sourceAsset:subIdentifier"), Some(&Value::Token("plastic".into())));
        assert_eq!(shader.value("inputs:base_color").and_then(Value::as_vec3), Some([0.8, 0.1, 0.1]));
        let output = prim(&stage, "/World/Looks/Plastic").attribute("outputs:strata:surface").unwrap();
        assert_eq!(output.connections[0].0, "/World/Looks/Plastic/Surface.outputs:surface");
        // Depth-first order visits parents first and keeps file order.
        let order: Vec<&str> = stage.depth_first().map(|(_, p)| p.name.as_str()).take(4).collect();
        assert_eq!(order, vec!["World", "Group", "Quad", "Ball"]);
        assert_eq!(stage.subtree(stage.find("/World/Looks").unwrap()).count(), 3);
    }

    #[test]
    fn pixar_sublayer_and_reference_fixture() {
        let stage = ok(open(&fixtures().join("sub_root.usda")));
        // The weak sublayer's root prim is there, after nothing stronger reorders it.
        assert!(stage.find("/Weak").is_some());
        let body = prim(&stage, "/Scene/Thing/Body");
        assert_eq!(body.type_name.as_deref(), Some("Cube"));
        // The sublayer is local, so it beats the reference.
        assert_eq!(body.value("size"), Some(&Value::Float(5.0)));
        // Targets inside the referenced asset are mapped to where it is referenced.
        let slot = body.relationship("material:slotBinding:_000").unwrap();
        assert_eq!(slot.targets[0].0, "/Scene/Thing/Mat");
        assert!(stage.find("/Scene/Thing/Mat").is_some());
    }

    #[test]
    fn pixar_kitchen_fixture() {
        let (stage, rendered) = open(&fixtures().join("pixar_kitchen.usda"));
        let stage = stage.unwrap_or_else(|_| panic!("{rendered}"));
        assert!(!rendered.contains("timeSamples"), "{rendered}");
        let root = prim(&stage, "/Root");
        assert_eq!(root.kind.as_deref(), Some("component"));
        assert_eq!(root.value("inherited"), Some(&Value::Float(7.0)));
        assert_eq!(root.value("color").and_then(Value::as_vec3), Some([1.0, 0.0, 0.0]));
        assert!(stage.find("/Root/RedOnly").is_some());
        assert!(stage.find("/Root/Off").is_none());
        assert!(stage.find("/_class_Base").is_none());
        assert!(stage.find("/OverOnly").is_none());
        // usd-core: `anim.Get(stage.GetStartTimeCode())` is 2 (samples beat the default), `Get()` 1.
        assert_eq!(root.value("anim"), Some(&Value::Float(2.0)));
        assert_eq!(root.attribute("anim").and_then(|a| a.value_at(TimeCode::Default)), Some(Value::Float(1.0)));
        assert_eq!(root.value("only_ts").and_then(Value::as_vec3), Some([1.0, 1.0, 1.0]));
        assert!(root.attribute("blocked").unwrap().blocked);
        assert_eq!(root.value("f"), Some(&Value::Float(f64::INFINITY)));
        assert_eq!(root.value("s").and_then(Value::as_str), Some("it's \"quoted\"\nnewline\ttab \\ back"));
        assert_eq!(root.value("s3").and_then(Value::as_str), Some("multi\nline with \"\"\" inside"));
        assert_eq!(root.value("ast_at").and_then(Value::as_str), Some("weird@name.png"));
        assert_eq!(root.value("m3"), Some(&Value::Matrix3([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])));
        assert_eq!(root.value("m4a").and_then(Value::as_tuple_array).map(|(w, d)| (w, d.len())), Some((16, 32)));
        assert_eq!(root.value("ba"), Some(&Value::BoolArray(vec![true, false])));
        assert_eq!(root.value("i64"), Some(&Value::Int(-9_000_000_000)));
        let r = root.relationship("r").unwrap();
        let targets: Vec<&str> = r.targets.iter().map(|t| t.0.as_str()).collect();
        assert_eq!(targets, vec!["/Root/Child", "/Other"]);
        assert!(!r.explicit);
        assert!(root.relationship("explicit_empty_list").unwrap().is_explicit_empty());
        assert!(!root.relationship("declared_rel").unwrap().is_explicit_empty());
        // Declared only is no target opinion at all; an authored empty list is one.
        assert!(!root.relationship("declared_rel").unwrap().has_authored_targets());
        assert!(root.relationship("explicit_empty_list").unwrap().has_authored_targets());
        assert!(r.has_authored_targets());
        let dst = root.attribute("dst").unwrap();
        assert_eq!(dst.connections.len(), 2);
        let inst = prim(&stage, "/Root/Inst");
        assert!(inst.instanceable);
        assert_eq!(inst.value("from_payload"), Some(&Value::Int(1)));
        assert_eq!(inst.value("from_other"), Some(&Value::Int(2)));
        assert_eq!(inst.value("inherited"), Some(&Value::Float(7.0)));
        let meta = stage.metadata();
        assert_eq!(meta.doc.as_deref(), Some("Kitchen \"sink\"\nsecond line"));
    }

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        fs::write(&path, text).expect("write fixture");
        path
    }

    #[test]
    fn sublayers_strongest_first_and_nested_references() {
        let dir = temp_dir("strata-compose");
        let d = dir.path();
        fs::create_dir(d.join("sub")).unwrap();
        write(d, "sub/leaf.usda", "#usda 1.0\n(defaultPrim = \"Leaf\")\ndef Sphere \"Leaf\" { double radius = 3 }\n");
        write(
            d,
            "sub/mid.usda",
            "#usda 1.0\n(defaultPrim = \"Mid\")\ndef Xform \"Mid\" { def \"L\" (references = @./leaf.usda@) { double radius = 2 } }\n",
        );
        write(d, "strong.usda", "#usda 1.0\nover \"A\" { float x = 1 }\n");
        write(d, "weak.usda", "#usda 1.0\ndef \"A\" { float x = 2\n float y = 2 }\n");
        let root = write(
            d,
            "root.usda",
            "#usda 1.0\n(subLayers = [@strong.usda@, @weak.usda@])\ndef \"R\" (prepend references = @sub/mid.usda@) { }\n",
        );
        let stage = ok(open(&root));
        let a = prim(&stage, "/A");
        assert_eq!(a.value("x"), Some(&Value::Float(1.0)));
        assert_eq!(a.value("y"), Some(&Value::Float(2.0)));
        let leaf = prim(&stage, "/R/L");
        assert_eq!(leaf.type_name.as_deref(), Some("Sphere"));
        assert_eq!(leaf.value("radius"), Some(&Value::Float(2.0)));
    }

    #[test]
    fn cycles_are_errors_and_missing_files_warnings() {
        let dir = temp_dir("strata-cycle");
        let d = dir.path();
        write(d, "a.usda", "#usda 1.0\n(subLayers = [@b.usda@])\n");
        write(d, "b.usda", "#usda 1.0\n(subLayers = [@a.usda@])\n");
        let (stage, rendered) = open(&d.join("a.usda"));
        assert!(stage.is_err());
        assert!(rendered.contains("cycle") && rendered.contains("b.usda:2:15"), "{rendered}");

        write(d, "r1.usda", "#usda 1.0\n(defaultPrim = \"P\")\ndef \"P\" (references = @r2.usda@) {}\n");
        write(d, "r2.usda", "#usda 1.0\n(defaultPrim = \"P\")\ndef \"P\" (references = @r1.usda@) {}\n");
        let (stage, rendered) = open(&d.join("r1.usda"));
        assert!(stage.is_err());
        assert!(rendered.contains("reference cycle"), "{rendered}");

        // A layer that does not resolve is composed around, with a located warning.
        let missing = write(d, "m.usda", "#usda 1.0\ndef \"P\" (\n    references = @gone.usda@\n) {}\n");
        let (stage, rendered) = open(&missing);
        assert!(stage.is_ok_and(|s| s.find("/P").is_some()), "{rendered}");
        assert!(rendered.starts_with("warning: cannot read layer `gone.usda`"), "{rendered}");
        assert!(rendered.contains("m.usda:3:18") && rendered.contains("@gone.usda@"), "{rendered}");

        let (stage, rendered) = text("#usda 1.0\ndef \"A\" (references = </A>) {}\n");
        assert!(stage.is_err() && rendered.contains("cycle"), "{rendered}");
    }

    #[test]
    fn internal_references_inherits_classes_and_variants() {
        let stage = ok(text(
            r#"#usda 1.0
class "_base" { float k = 1
    def "Part" { float p = 1 } }
def "Proto" { float r = 5
    rel mat = </Proto/M>
    def "M" {} }
def "A" (
    inherits = </_base>
    references = </Proto>
    variants = { string look = "b" }
    variantSets = "look"
) {
    float r = 6
    variantSet "look" = {
        "a" { float v = 1 }
        "b" { float v = 2
              def "FromVariant" {} }
    }
}
def "Inactive" (active = false) { def "Kid" {} }
"#,
        ));
        let a = prim(&stage, "/A");
        assert_eq!(a.value("k"), Some(&Value::Float(1.0)));
        assert_eq!(a.value("r"), Some(&Value::Float(6.0)));
        assert_eq!(a.value("v"), Some(&Value::Float(2.0)));
        assert_eq!(a.relationship("mat").unwrap().targets[0].0, "/A/M");
        assert_eq!(a.variant_selections, vec![("look".to_string(), "b".to_string())]);
        // A `def` inside a class is inherited as a defined child, as in USD.
        assert_eq!(prim(&stage, "/A/Part").value("p"), Some(&Value::Float(1.0)));
        assert!(stage.find("/A/FromVariant").is_some());
        assert!(stage.find("/A/M").is_some());
        assert!(stage.find("/_base").is_none());
        assert!(stage.find("/Inactive").is_none() && stage.find("/Inactive/Kid").is_none());
        let roots: Vec<&str> = stage.root_children().iter().map(|&id| stage.prim(id).path.as_str()).collect();
        assert_eq!(roots, vec!["/Proto", "/A"]);
    }

    #[test]
    fn relationship_list_ops_compose_weakest_to_strongest() {
        let dir = temp_dir("strata-rel");
        let d = dir.path();
        write(d, "weak.usda", "#usda 1.0\ndef \"P\" { rel r = [</a>, </b>]\n rel s = [</x>] }\n");
        let root = write(
            d,
            "root.usda",
            "#usda 1.0\n(subLayers = [@weak.usda@])\nover \"P\" { delete rel r = </a>\n append rel r = </c>\n rel s = None\n custom rel material:slotBinding:_050 = None }\n",
        );
        let stage = ok(open(&root));
        let p = prim(&stage, "/P");
        let r: Vec<&str> = p.relationship("r").unwrap().targets.iter().map(|t| t.0.as_str()).collect();
        assert_eq!(r, vec!["/b", "/c"]);
        assert!(p.relationship("s").unwrap().is_explicit_empty());
        assert!(p.relationship("material:slotBinding:_050").unwrap().is_explicit_empty());
        // The span is the strongest opinion's.
        let span = p.relationship("s").unwrap().span;
        assert_eq!(span.file, stage.root_file());
    }

    #[test]
    fn warnings_for_missing_variant_selection() {
        let (stage, rendered) = text("#usda 1.0\ndef \"A\" { variantSet \"v\" = { \"x\" { float a = 1 } } }\n");
        assert!(stage.is_ok());
        assert!(rendered.contains("no variant selected"), "{rendered}");
    }

    #[test]
    fn diagnostics_render_file_line_col() {
        let (stage, rendered) = text("#usda 1.0\ndef \"A\"\n{\n    float3 x = (1, 2, \"a\")\n}\n");
        assert!(stage.is_err());
        assert!(rendered.contains("scene.usda:4:16"), "{rendered}");
        assert!(rendered.contains("float3 x = (1, 2, \"a\")"), "{rendered}");
    }

    #[test]
    fn fifty_thousand_siblings_compose() {
        // Composition was quadratic in the number of siblings (109 000 took 89 s); with the
        // name lookups hashed this is a fraction of a second, and a regression to quadratic
        // would take minutes here — long past any test timeout.
        let n = 50_000;
        let mut scene = String::from("#usda 1.0\ndef Xform \"World\" {\n");
        for i in 0..n {
            scene += &format!("    def Xform \"S{i}\" {{ double x = {i} }}\n");
        }
        scene += "}\n";
        for i in 0..n {
            scene += &format!("def Xform \"R{i}\" {{}}\n");
        }
        let stage = ok(text(&scene));
        assert_eq!(stage.len(), 2 * n + 1);
        let world = prim(&stage, "/World");
        assert_eq!(world.children.len(), n);
        assert_eq!(prim(&stage, "/World/S49999").value("x"), Some(&Value::Float(49999.0)));
        assert_eq!(prim(&stage, "/World/S123").value("x"), Some(&Value::Float(123.0)));
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_stack_overflow() {
        let deep = format!("#usda 1.0\ndef \"A\" {{ float[] x = {} }}\n", "[".repeat(100_000));
        assert!(text(&deep).0.is_err());
        let prims = format!("#usda 1.0\n{}{}", "def \"A\" {\n".repeat(5000), "}\n".repeat(5000));
        assert!(text(&prims).0.is_err());
    }

    /// Tiny deterministic PRNG so the fuzz test needs no dependency.
    struct XorShift(u64);
    impl XorShift {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n.max(1) as u64) as usize
        }
    }

    #[test]
    fn mutation_fuzz_never_panics() {
        let seeds = [
            include_str!("../../tests/fixtures/usd/pixar_written.usda"),
            include_str!("../../tests/fixtures/usd/pixar_kitchen.usda"),
            include_str!("../../tests/fixtures/usd/sub_root.usda"),
        ];
        let alphabet = b"()[]{}<>@\"'#=,.:;/\\ \n0123456789-eEinfNoneadefoverclassrelpathuniform_";
        let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
        let dir = fixtures();
        for round in 0..1500 {
            let seed = seeds[round % seeds.len()];
            let mut bytes = seed.as_bytes().to_vec();
            for _ in 0..1 + rng.below(8) {
                let at = rng.below(bytes.len());
                match rng.below(4) {
                    0 => bytes[at] = alphabet[rng.below(alphabet.len())],
                    1 => {
                        bytes.remove(at);
                    }
                    2 => bytes.insert(at, alphabet[rng.below(alphabet.len())]),
                    _ => {
                        let len = rng.below(40).min(bytes.len() - at);
                        let chunk: Vec<u8> = bytes[at..at + len].to_vec();
                        let to = rng.below(bytes.len());
                        bytes.splice(to..to, chunk);
                    }
                }
            }
            let text = String::from_utf8_lossy(&bytes);
            let mut sources = SourceMap::new();
            let mut diags = Diagnostics::new();
            let _ = Stage::from_text("fuzz.usda", &text, &dir, &mut sources, &mut diags);
            let _ = diags.render(&sources);
        }
    }
}
