//! Updates of a prepared [`Session`]: what a changed file is to the scene, and redoing only
//! the phases that depend on it (ARCHITECTURE.md, "The Session"); live input values written
//! into parameter blocks without a compile.

use super::*;

impl Session {
    /// What `path` is to this scene.
    pub fn classify(&self, path: &Path) -> ChangeKind {
        let path = canonical(path);
        if self.layers.contains(&path) {
            return ChangeKind::Layer;
        }
        let is = |ext: &[&str]| path.extension().and_then(|e| e.to_str()).is_some_and(|e| ext.contains(&e));
        match &self.composed {
            Some(c) if c.files.contains(&path) || (c.failed && is(&["ash"])) => return ChangeKind::Substance,
            _ => {}
        }
        if self.reads_texture(&path) {
            return ChangeKind::Texture;
        }
        // A stage that failed to open may have failed for want of this layer.
        if self.stage.is_none() && is(&["usd", "usda", "usdc", "usdz"]) {
            return ChangeKind::Layer;
        }
        ChangeKind::Unrelated
    }

    /// Whether a texture was loaded from `path`, or a prim outside material networks (a
    /// dome light) names it.
    fn reads_texture(&self, path: &Path) -> bool {
        let prefix = format!("{}#", path.display());
        if crate::runtime::texture::registered_from(&prefix) {
            return true;
        }
        self.stage.as_ref().is_some_and(|stage| {
            stage.depth_first().any(|(_, prim)| {
                prim.attributes.iter().any(|a| {
                    a.value
                        .as_ref()
                        .and_then(|(v, _)| v.as_asset())
                        .is_some_and(|asset| canonical(&asset.resolved) == path)
                })
            })
        })
    }

    /// Brings the prepared state up to date after `change`, redoing only what depends on
    /// it; what was never prepared stays unprepared. The diagnostics afterwards are the
    /// update's.
    pub fn apply_change(&mut self, change: &Change) -> UpdateReport {
        let start = Instant::now();
        self.diags = Diagnostics::new();
        let kind = match change {
            Change::File(path) => self.classify(path),
            Change::Layer(_) => ChangeKind::Layer,
            Change::Substance(_) => ChangeKind::Substance,
            Change::Texture(_) => ChangeKind::Texture,
            Change::Value { .. } => ChangeKind::Value,
        };
        let mut report = UpdateReport::nothing(kind);
        match (kind, change) {
            (ChangeKind::Unrelated, _) => {}
            (ChangeKind::Texture, Change::File(path) | Change::Texture(path)) => {
                match crate::runtime::texture::reload_file(path) {
                    Ok(n) => report.textures_reloaded = n,
                    Err(e) => self.diags.push(Diagnostic::warning(e).kind("unreadable texture")),
                }
                // A dome map or other asset outside the materials is read by the scene build.
                let file = canonical(path);
                let named_by_scene = self.stage.as_ref().is_some_and(|stage| {
                    fingerprint::names_asset_outside_materials(stage, &|asset| canonical(asset) == file)
                });
                if named_by_scene && let Some(options) = self.prepared.as_ref().map(|p| p.options.clone()) {
                    report.geometry_rebuilt = true;
                    report.failed = self.build_scene(options).is_none();
                }
            }
            (ChangeKind::Value, Change::Value { prim, attribute, type_name, value }) => {
                if let Err(message) = self.set_value(prim, attribute, type_name, value) {
                    self.diags.push(Diagnostic::error(message));
                    report.failed = true;
                } else if !self.write_parameters(&mut report) {
                    self.redo_from_composition_into(&mut report);
                }
            }
            (ChangeKind::Layer, _) => {
                self.read_stage();
                report.restaged = true;
                self.redo_from_composition_into(&mut report);
            }
            _ => self.redo_from_composition_into(&mut report),
        }
        report.ms = start.elapsed().as_secs_f64() * 1e3;
        report
    }

    pub(super) fn redo_from_composition(&mut self, kind: ChangeKind, start: Instant) -> UpdateReport {
        let mut report = UpdateReport::nothing(kind);
        self.redo_from_composition_into(&mut report);
        report.ms = start.elapsed().as_secs_f64() * 1e3;
        report
    }

    /// Composes again (if composed before), compiles the materials whose content hash is
    /// new (if compiled before), and rebinds or rebuilds the render scene (if built before).
    fn redo_from_composition_into(&mut self, report: &mut UpdateReport) {
        if self.composed.is_none() {
            return;
        }
        self.compose();
        report.recomposed = true;
        if self.compiled.is_none() {
            return;
        }
        match self.compile_now() {
            Some((compiled, reused)) => (report.recompiled, report.reused) = (compiled, reused),
            None => {
                report.failed = true;
                return;
            }
        }
        self.rebind_or_rebuild(report);
    }

    /// After new materials: rebinds the render scene (if built before) when its geometry and
    /// what its build read from the materials are unchanged, else builds it again.
    fn rebind_or_rebuild(&mut self, report: &mut UpdateReport) {
        let (Some(prepared), Some(stage), Some(compiled)) = (&self.prepared, &self.stage, &self.compiled) else {
            return;
        };
        let old_geometry = prepared.geometry;
        let old_key = &prepared.material_key;
        let refs = compiled.refs();
        let geometry = fingerprint::geometry_hash(stage);
        // Prims keep their order and paths when the geometry hash is unchanged.
        let prim_material: Option<Vec<usize>> =
            prepared.scene.prims.iter().map(|p| compiled.prim_material.get(&p.path).copied()).collect();
        let keep = geometry == old_geometry
            && prim_material.as_ref().is_some_and(|pm| material_key_of(pm, &refs, &self.compiled_hashes) == *old_key);
        if keep && let (Some(prim_material), Some(prepared)) = (prim_material, self.prepared.as_mut()) {
            let start = Instant::now();
            rebind(&mut prepared.scene, prim_material, &refs, compiled.material_names.clone());
            self.stats.scene_rebinds += 1;
            self.stats.scene_ms = start.elapsed().as_secs_f64() * 1e3;
        } else if let Some(options) = self.prepared.as_ref().map(|p| p.options.clone()) {
            report.geometry_rebuilt = true;
            report.failed = self.build_scene(options).is_none();
        }
    }

    /// With live inputs, the fast road of an input edit already set on the stage: reads every
    /// strata material's values again (no composition, no substance file) and, when only live
    /// inputs changed, rewrites the changed materials' parameter blocks over their compiled
    /// classes and rebinds the render scene (rebuilt only if a changed material moves
    /// geometry). `false` when it does not apply (no live inputs, a value that is not a live
    /// input, nothing a material reads changed): the caller composes again.
    fn write_parameters(&mut self, report: &mut UpdateReport) -> bool {
        let (Some(stage), Some(composed), Some(compiled)) = (&self.stage, &mut self.composed, &mut self.compiled)
        else {
            return false;
        };
        if !self.options.passes.live_inputs || composed.failed || self.compiled_hashes != composed.hashes {
            return false;
        }
        let lib = &composed.scene.library;
        let mut fresh: HashMap<String, Option<Vec<(usize, crate::front::types::Value)>>> = HashMap::new();
        let mut updated = Vec::new();
        for (i, material) in composed.scene.materials.iter().enumerate() {
            let mut edited = material.clone();
            let mut changed = false;
            for r in edited.references_mut() {
                let values = fresh
                    .entry(r.path.clone())
                    .or_insert_with(|| crate::compose::scene::material_values(stage, lib, &r.path, r.graph));
                let Some(values) = values else { continue };
                if *values == r.values {
                    continue;
                }
                // Only parameters may differ: anything else changes the compiled class.
                let graph = lib.get(r.graph);
                let after = crate::compose::MaterialRef { values: values.clone(), ..r.clone() };
                if after.folded_inputs(graph) != r.folded_inputs(graph) {
                    return false;
                }
                r.values = values.clone();
                changed = true;
            }
            if changed {
                updated.push((i, edited));
            }
        }
        if updated.is_empty() {
            return false;
        }
        for (i, material) in updated {
            let block = material.parameter_block(lib);
            let Some(class) = self.code.get(&composed.classes[i]) else { return false };
            compiled.materials[i] = Arc::new(ParameterInstance::new(class.clone(), block.clone()));
            composed.hashes[i] = instance_hash(composed.classes[i], &block);
            composed.blocks[i] = block;
            composed.scene.materials[i] = material;
            self.stats.parameter_writes += 1;
        }
        self.compiled_hashes = composed.hashes.clone();
        self.rebind_or_rebuild(report);
        true
    }

    /// Mutes or solos slots in memory (the files are untouched) and redoes what depends on
    /// the materials, as a change of input value does.
    pub fn set_slot_filter(&mut self, filter: SlotFilter) -> UpdateReport {
        let start = Instant::now();
        self.diags = Diagnostics::new();
        self.slot_filter = filter;
        self.redo_from_composition(ChangeKind::Value, start)
    }

    /// The slots muted or soloed by [`Session::set_slot_filter`].
    pub fn slot_filter(&self) -> &SlotFilter {
        &self.slot_filter
    }

    /// Sets attribute `attribute` of prim `prim` (declaring it as `type_name` when the prim
    /// does not author it) to `value` at every time.
    fn set_value(&mut self, prim: &str, attribute: &str, type_name: &str, value: &Value) -> Result<(), String> {
        let stage = self.stage.as_mut().ok_or("the stage did not open")?;
        let id = stage.find(prim).ok_or_else(|| format!("no prim `{prim}` on the stage"))?;
        let prim = stage.prim_mut(id);
        let index = match prim.attributes.iter().position(|a| a.name == attribute) {
            Some(i) => i,
            None => {
                prim.attributes.push(crate::scene::Attribute {
                    name: attribute.to_string(),
                    type_name: type_name.to_string(),
                    value_type: ValueType::parse(type_name.trim_end_matches("[]"), type_name.ends_with("[]")),
                    value: None,
                    default_value: None,
                    blocked: false,
                    span: Default::default(),
                    custom: false,
                    uniform: false,
                    connections: Vec::new(),
                    time_samples: Vec::new(),
                    metadata: Vec::new(),
                    weaker_defaults: Vec::new(),
                });
                prim.attributes.len() - 1
            }
        };
        let attr = &mut prim.attributes[index];
        let value = value.clone().coerce(&attr.value_type).map_err(|e| format!("`{attribute}`: {e}"))?;
        attr.value = Some((value.clone(), attr.span));
        attr.default_value = Some((value, attr.span));
        attr.time_samples.clear();
        attr.blocked = false;
        Ok(())
    }
}

/// The hash of a material instance: its compiled class and its parameter block's bits.
pub(super) fn instance_hash(class: u64, block: &[f32]) -> u64 {
    use std::hash::{DefaultHasher, Hash, Hasher};
    let mut hasher = DefaultHasher::new();
    class.hash(&mut hasher);
    block.iter().map(|x| x.to_bits()).for_each(|bits| bits.hash(&mut hasher));
    hasher.finish()
}

/// What a render scene's build read from its materials: the primvars they read, and per
/// prim the content hash of its material when that material moves geometry (0 otherwise).
pub(super) fn material_key(
    scene: &crate::render::Scene,
    refs: &[&dyn MaterialCode],
    hashes: &[u64],
) -> (Vec<String>, Vec<u64>) {
    material_key_of(&scene.prim_material, refs, hashes)
}

pub(super) fn material_key_of(
    prim_material: &[usize],
    refs: &[&dyn MaterialCode],
    hashes: &[u64],
) -> (Vec<String>, Vec<u64>) {
    let mut primvars: Vec<String> =
        refs.iter().flat_map(|m| m.info().primvars.iter().map(|p| p.name.clone())).collect();
    primvars.sort();
    primvars.dedup();
    let moves =
        |m: usize| refs.get(m).is_some_and(|code| code.info().layers.iter().any(|l| l.displacement_bound.is_some()));
    let displacing =
        prim_material.iter().map(|&m| if moves(m) { hashes.get(m).copied().unwrap_or(0) } else { 0 }).collect();
    (primvars, displacing)
}

/// Points a built render scene at new materials, keeping geometry, BVH and lights: only the
/// emissive triangles are found again, since which materials emit may have changed.
pub(super) fn rebind(
    scene: &mut crate::render::Scene,
    prim_material: Vec<usize>,
    refs: &[&dyn MaterialCode],
    names: Vec<String>,
) {
    let radius = (scene.bounds.1 - scene.bounds.0).length() / 2.0;
    let light_power: f32 = scene.lights.iter().filter(|l| !l.is_infinite()).map(|l| l.power(radius)).sum();
    scene.emitters = crate::render::light::emitter::Emitters::build(
        &scene.accel,
        scene.prims.len(),
        &prim_material,
        refs,
        light_power,
    );
    scene.prim_material = prim_material;
    scene.material_names = names;
}
