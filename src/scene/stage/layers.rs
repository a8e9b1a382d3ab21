//! The layers a stage reads: loading each once (by canonical path), sublayer chains walked
//! without recursion, cycles and unreadable layers reported once, and layer stacks (a layer
//! and its sublayers, strongest first, with their time offsets).

use super::count_work;
use crate::diag::{Diagnostic, Diagnostics, OncePerKind, Severity, SourceMap, Span};
use crate::input::normalize;
use crate::scene::mtlx;
use crate::scene::usda::{self, Layer, LayerOffset};
use crate::scene::usdc::{self, LayerReadError, LayerSource};
use crate::scene::value::AssetPath;
use std::cell::OnceCell;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

pub(super) struct LoadedLayer {
    pub(super) layer: Layer,
    /// The sublayers that loaded, in authored order, each with its layer offset.
    pub(super) sublayers: Vec<(usize, LayerOffset)>,
    /// The layer stack rooted at this layer, built the first time an arc or the stage needs
    /// it: building one per layer would make a chain of n sublayers cost n² (each layer's
    /// stack holds every layer below it).
    pub(super) stack: OnceCell<LayerStack>,
}

/// A layer and its sublayers, recursively, strongest first (each layer once).
pub(super) struct LayerStack {
    /// Indices into [`Layers::list`].
    pub(super) layers: Vec<usize>,
    /// For each of `layers`, how its times map to the stack's root layer's (sublayer offsets).
    pub(super) offsets: Vec<LayerOffset>,
    /// For each root prim name, the positions in `layers` of the layers that have a spec of
    /// it: a prim looks only at the layers that speak of it, so n sublayers with a prim each
    /// compose in O(n), not O(n²).
    pub(super) by_root_prim: HashMap<String, Vec<u32>>,
}

/// The layers being read, root first: a sublayer chain is walked with this explicit stack,
/// not by recursion, so any depth loads without exhausting the thread's stack (a chain of
/// 4 500 sublayer files overflowed it; Pixar's library has no depth limit and opens it).
#[derive(Default)]
pub(super) struct Chain {
    pub(super) keys: Vec<PathBuf>,
    /// Position of each key in `keys`: the cycle check is O(1), not O(depth).
    pub(super) position: HashMap<PathBuf, usize>,
}

impl Chain {
    pub(super) fn push(&mut self, key: PathBuf) {
        self.position.insert(key.clone(), self.keys.len());
        self.keys.push(key);
    }

    pub(super) fn pop(&mut self) {
        if let Some(key) = self.keys.pop() {
            self.position.remove(&key);
        }
    }
}

/// A registered layer whose sublayers are still to be loaded.
pub(super) struct Opening {
    pub(super) index: usize,
    /// Whether the layer has a key on the [`Chain`] (text composed from memory has none).
    pub(super) on_chain: bool,
    pub(super) sub_layers: std::iter::Enumerate<std::vec::IntoIter<(AssetPath, Span)>>,
    pub(super) sub_offsets: Vec<LayerOffset>,
    /// Sublayers listed so far: listing one again adds no opinions, and reading it again
    /// would repeat its diagnostics.
    pub(super) listed: HashSet<PathBuf>,
    pub(super) repeats: usize,
}

/// What starting to load a layer gave.
pub(super) enum Start {
    /// Known already (or failed, or a cycle): its index, if it loaded.
    Known(Option<usize>),
    /// Parsed and registered; its sublayers are still to load.
    Opened(Opening),
}

#[derive(Default)]
pub(super) struct Layers {
    pub(super) list: Vec<LoadedLayer>,
    /// Canonical path → index, or `None` when loading failed (reported once).
    pub(super) by_key: HashMap<PathBuf, Option<usize>>,
    /// Sublayer cycles already reported, each as its sorted set of files: a cycle is one
    /// error however many paths lead into it (5 000 self-sublayers printed 563 MB).
    pub(super) reported_cycles: HashSet<Vec<PathBuf>>,
    /// Layers the stage is composed without (missing, unreadable, MaterialX, malformed): USD
    /// composes around them, so they are warnings, one per kind.
    pub(super) warnings: OncePerKind,
}

impl Layers {
    pub(super) fn get(&self, index: usize) -> Option<&LoadedLayer> {
        self.list.get(index)
    }

    pub(super) fn key(path: &Path) -> PathBuf {
        count_work(1);
        crate::input::canonicalize(path).unwrap_or_else(|_| normalize(path))
    }

    /// The layer stack rooted at layer `index`, if there is such a layer.
    pub(super) fn stack(&self, index: usize) -> Option<&LayerStack> {
        let loaded = self.list.get(index)?;
        Some(loaded.stack.get_or_init(|| self.build_stack(index)))
    }

    /// Walks the sublayer graph from `root` in pre-order, strongest first, keeping each
    /// layer's first occurrence (a layer reached again adds no opinions).
    pub(super) fn build_stack(&self, root: usize) -> LayerStack {
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
    pub(super) fn load(
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
    pub(super) fn start(
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
            Err(error) => {
                let (kind, message) = match error {
                    LayerReadError::Unreadable(why) => (
                        "unreadable layer",
                        format!("cannot read layer `{authored}`: {why}; the stage is composed without it"),
                    ),
                };
                self.warnings.push(kind, authored, Diagnostic::warning(message).at(span, "referenced here"));
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
    pub(super) fn add(
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
                let layer = usda::parse(file, sources.text(file), &dir, &mut parsed);
                // The layer holds what it needs; a diagnostic reads the file again.
                sources.release(file, Path::new(name));
                layer
            }
            LayerSource::Crate(bytes) => usdc::convert(name, &bytes, &dir, sources, &mut parsed),
            LayerSource::MaterialX(xml) => materialx_layer(name, xml, &dir, sources, &mut parsed),
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
    pub(super) fn load_sublayers(
        &mut self,
        first: Opening,
        chain: &mut Chain,
        sources: &mut SourceMap,
        diags: &mut Diagnostics,
    ) {
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

/// A MaterialX document as a layer: the XML is in the source map (its problems point at it),
/// the USDA translation beside it as `NAME (as USD)`. A document that is not well-formed
/// MaterialX is one error at its line and column, and an empty layer.
fn materialx_layer(name: &str, xml: String, dir: &Path, sources: &mut SourceMap, diags: &mut Diagnostics) -> Layer {
    let xml_file = sources.add(name, xml);
    let at = |range: std::ops::Range<usize>| Span::new(xml_file, range.start, range.end);
    match mtlx::translate(sources.text(xml_file)) {
        Ok(translation) => {
            for problem in translation.warnings {
                diags.push(Diagnostic::warning(problem.message).at(at(problem.range), "in this element"));
            }
            let file = sources.add(format!("{name} (as USD)"), translation.usda);
            usda::parse(file, sources.text(file), dir, diags)
        }
        Err(problem) => {
            diags.push(Diagnostic::error(problem.message).at(at(problem.range), "here"));
            Layer::default()
        }
    }
}
