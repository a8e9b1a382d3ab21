//! Content hashes that decide what an update redoes: a composed material's (what its code is
//! compiled from) and the stage's geometry (what the render scene's triangles and BVH are
//! built from). Equal hashes mean the cached result is reused. `DefaultHasher::new()` has
//! fixed keys, so processes of the same build agree: `Session::fingerprint` relies on it.

use crate::compose::{ComposedMaterial, MaterialRef};
use crate::front::ast::Item;
use crate::front::library::Library;
use crate::scene::{Stage, Value};
use std::collections::{HashMap, HashSet};
use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::{Path, PathBuf};

/// Hashes of substance files with everything they import, memoised for one composition.
#[derive(Default)]
pub struct FileHashes {
    closure: HashMap<PathBuf, u64>,
    visited: HashSet<PathBuf>,
}

impl FileHashes {
    /// The hash of `file`'s text and of every file it imports, transitively. A file that
    /// cannot be read hashes as its read error, so it fixed is a change.
    pub fn closure(&mut self, file: &Path) -> u64 {
        if let Some(&hash) = self.closure.get(file) {
            return hash;
        }
        let mut hasher = DefaultHasher::new();
        let mut seen = HashSet::new();
        let mut pending = vec![file.to_path_buf()];
        while let Some(path) = pending.pop() {
            let canonical = path.canonicalize().unwrap_or_else(|_| path.clone());
            if !seen.insert(canonical.clone()) {
                continue;
            }
            canonical.hash(&mut hasher);
            let text = match crate::input::scenes::embedded(&path) {
                Some(text) => text.to_string(),
                None => match crate::input::read_text(&path) {
                    Ok(text) => text,
                    Err(e) => {
                        e.to_string().hash(&mut hasher);
                        continue;
                    }
                },
            };
            text.hash(&mut hasher);
            let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
            let mut ignored = crate::diag::Diagnostics::new();
            let module = crate::front::parser::parse(Default::default(), &text, &mut ignored);
            for item in &module.items {
                if let Item::Import { path: import, .. } = item {
                    pending.push(dir.join(import));
                }
            }
        }
        self.visited.extend(seen);
        let hash = hasher.finish();
        self.closure.insert(file.to_path_buf(), hash);
        hash
    }

    /// Every file hashed (canonical paths): the substance files the materials depend on.
    pub fn visited(self) -> HashSet<PathBuf> {
        self.visited
    }
}

/// The content hash of a composed material: its slots (vertical ones included), the values bound to each substance
/// and override, and each graph's content — the text of the file that declares it and of
/// the files that file imports, or, for a graph composed from a UsdShade network, the graph
/// itself. Graph ids are left out: they shift when another file gains a graph.
pub fn material_hash(material: &ComposedMaterial, library: &Library, files: &mut FileHashes) -> u64 {
    let mut hasher = DefaultHasher::new();
    format!("{:?}", material.display).hash(&mut hasher);
    let mut reference = |r: &MaterialRef, hasher: &mut DefaultHasher| {
        r.path.hash(hasher);
        // Not the span: a layer read again gets new file ids, and spans only locate messages.
        format!("{:?}", r.values).hash(hasher);
        let index = r.graph.0 as usize;
        let graph = library.get(r.graph);
        graph.name.hash(hasher);
        match library.graph_files.get(index) {
            // `Library::add_graph` files composed graphs under `<composed>`.
            Some(file) if file != Path::new("<composed>") => {
                file.hash(hasher);
                files.closure(file).hash(hasher);
            }
            _ => format!("{graph:?}").hash(hasher),
        }
    };
    // Vertical layers (rule 3b) are hashed even while lowering leaves them out, so the
    // lowering that adds them compiles the material again.
    for layer in &material.layers {
        for part in std::iter::once(layer).chain(&layer.vertical) {
            part.slot.name().hash(&mut hasher);
            reference(&part.substance, &mut hasher);
            for (slot, o) in &part.overrides {
                slot.name().hash(&mut hasher);
                reference(o, &mut hasher);
            }
        }
        '|'.hash(&mut hasher);
    }
    hasher.finish()
}

/// Whether a prim is shading (a material network), which the render scene does not read.
fn is_shading(stage: &Stage, mut id: crate::scene::PrimId) -> bool {
    loop {
        let prim = stage.prim(id);
        if matches!(prim.type_name.as_deref(), Some("Material" | "Shader" | "NodeGraph")) {
            return true;
        }
        match prim.parent {
            Some(parent) => id = parent,
            None => return false,
        }
    }
}

/// The hash of everything on the stage the render scene's geometry, lights and camera are
/// built from: every prim outside material networks with its attributes at the stage's time
/// and its relationships other than material bindings, and the stage's up axis and units.
/// Spans are left out, so an edit that moves text without changing values keeps geometry.
pub fn geometry_hash(stage: &Stage) -> u64 {
    let mut hasher = DefaultHasher::new();
    stage.up_axis().hash(&mut hasher);
    stage.meters_per_unit().to_bits().hash(&mut hasher);
    format!("{:?}", stage.time()).hash(&mut hasher);
    for (id, prim) in stage.depth_first() {
        if is_shading(stage, id) {
            continue;
        }
        prim.path.hash(&mut hasher);
        format!("{:?}{:?}{}{:?}", prim.type_name, prim.kind, prim.instanceable, prim.api_schemas).hash(&mut hasher);
        for attr in &prim.attributes {
            attr.name.hash(&mut hasher);
            attr.type_name.hash(&mut hasher);
            hash_value(attr.value.as_ref().map(|(v, _)| v), &mut hasher);
            attr.blocked.hash(&mut hasher);
            for (time, value) in &attr.time_samples {
                time.to_bits().hash(&mut hasher);
                hash_value(Some(value), &mut hasher);
            }
            for m in &attr.metadata {
                format!("{}{:?}{:?}", m.key, m.op, m.value).hash(&mut hasher);
            }
            for (target, _) in &attr.connections {
                target.hash(&mut hasher);
            }
        }
        for rel in prim.relationships.iter().filter(|r| !r.name.starts_with("material:")) {
            rel.name.hash(&mut hasher);
            for (target, _) in &rel.targets {
                target.hash(&mut hasher);
            }
        }
    }
    hasher.finish()
}

/// Hashes `value`: numeric arrays by their numbers' bits (a large mesh's points are hashed at
/// every frame, so not through their text: that took 0.3 s for 180 000 triangles), anything
/// else by its debug text.
fn hash_value(value: Option<&Value>, hasher: &mut DefaultHasher) {
    match value {
        Some(Value::IntArray(a)) => a.iter().for_each(|x| hasher.write_i64(*x)),
        Some(Value::FloatArray(a)) => a.iter().for_each(|x| hasher.write_u64(x.to_bits())),
        Some(Value::TupleArray { width, data }) => {
            hasher.write_usize(*width);
            data.iter().for_each(|x| hasher.write_u64(x.to_bits()));
        }
        other => format!("{other:?}").hash(hasher),
    }
    // The variant too: an empty array of one kind is not one of another.
    value.map(std::mem::discriminant).hash(hasher);
}

/// Whether a prim outside material networks (a dome light's texture) names an asset for
/// which `is_file` holds: the render scene reads it, so its change rebuilds the scene.
pub fn names_asset_outside_materials(stage: &Stage, is_file: &dyn Fn(&Path) -> bool) -> bool {
    stage.depth_first().any(|(id, prim)| {
        !is_shading(stage, id)
            && prim
                .attributes
                .iter()
                .any(|a| a.value.as_ref().and_then(|(v, _)| v.as_asset()).is_some_and(|asset| is_file(&asset.resolved)))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compose::scene::compose_stage;
    use crate::diag::{Diagnostics, SourceMap};

    /// The content hash of the one material of a stage that binds the paper's listing-1
    /// substances (`tests/fixtures/vertical/materials.usda`) with `bindings`.
    fn hash_of(bindings: &str) -> u64 {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/vertical");
        let text = format!("#usda 1.0\n(\n    subLayers = [@materials.usda@]\n)\n{bindings}");
        let (mut sources, mut diags) = (SourceMap::new(), Diagnostics::new());
        let stage = Stage::from_text("hash.usda", &text, &dir, &mut sources, &mut diags).expect("stage");
        let scene = compose_stage(&stage, &mut sources, &mut diags);
        assert!(!diags.has_errors(), "{}", diags.render(&sources));
        material_hash(&scene.materials[0], &scene.library, &mut FileHashes::default())
    }

    #[test]
    fn a_vertical_layer_changes_the_content_hash() {
        let plain = hash_of(r#"def Mesh "a" { rel material:slotBinding:_000 = </L/SubstanceA> }"#);
        let coated = r#"def Mesh "a" {
    rel material:slotBinding:_000 = </L/SubstanceA>
    rel material:slotBinding:_000:vertical:_010 = </L/SubstanceB>
}"#;
        assert_ne!(plain, hash_of(coated), "lowering vertical layers later must recompile");
        assert_eq!(hash_of(coated), hash_of(coated));
    }
}
