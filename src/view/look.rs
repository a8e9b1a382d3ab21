//! Look edits from the page: the picked prim's material inputs (per layer, with their current
//! values), input values set in memory through [`Change::Value`], and the override layer that
//! writes those values out as standard USD opinions without touching the scene's files.

use crate::compose::MaterialRef;
use crate::front::ast::{BaseType, GraphKind};
use crate::front::types::{Type, Value as InputValue};
use crate::scene::{Stage, Value};
use crate::session::{Change, Session};
use serde::Deserialize;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// An input edit as the page posts it (`POST /input`).
#[derive(Deserialize)]
pub(crate) struct InputEdit {
    /// The shader prim that carries the material's inputs (`/Looks/Dirt/Surface`).
    pub prim: String,
    /// The substance input's name (`coverage`).
    pub input: String,
    /// Its substance type as the inspector listed it (`float`, `color`, `int`, …).
    #[serde(rename = "type")]
    pub ty: String,
    /// A number, a three-number list or a string.
    pub value: serde_json::Value,
}

impl InputEdit {
    /// The session change that sets it: `inputs:NAME` of the shader prim, as USD types it.
    pub fn change(&self) -> Result<Change, String> {
        let number = |v: &serde_json::Value| v.as_f64().filter(|x| x.is_finite());
        let (type_name, value) = match self.ty.as_str() {
            "float" => ("float", number(&self.value).map(Value::Float)),
            "int" => ("int", self.value.as_i64().map(Value::Int)),
            "string" => ("string", self.value.as_str().map(|s| Value::String(s.to_string()))),
            "color" | "point" | "vector" | "normal" => {
                let triple = self
                    .value
                    .as_array()
                    .filter(|a| a.len() == 3)
                    .and_then(|a| a.iter().map(number).collect::<Option<Vec<f64>>>());
                let type_name = match self.ty.as_str() {
                    "color" => "color3f",
                    "point" => "point3f",
                    "vector" => "vector3f",
                    _ => "normal3f",
                };
                (type_name, triple.map(Value::Tuple))
            }
            other => return Err(format!("a `{other}` input cannot be edited from the page")),
        };
        let value = value.ok_or_else(|| format!("`{}` is not a {} value", self.value, self.ty))?;
        Ok(Change::Value {
            prim: self.prim.clone(),
            attribute: format!("inputs:{}", self.input),
            type_name: type_name.to_string(),
            value,
        })
    }
}

/// The input values set from the page so far, by (prim, attribute): what an override layer
/// writes.
#[derive(Default)]
pub(crate) struct LookEdits {
    values: BTreeMap<(String, String), (String, Value)>,
}

impl LookEdits {
    /// Remembers a [`Change::Value`] the session applied.
    pub fn record(&mut self, change: &Change) {
        if let Change::Value { prim, attribute, type_name, value } = change {
            self.values.insert((prim.clone(), attribute.clone()), (type_name.clone(), value.clone()));
        }
    }

    /// The edits as changes, to apply again after the stage is read again.
    pub fn changes(&self) -> Vec<Change> {
        let change = |((prim, attribute), (type_name, value)): (&(String, String), &(String, Value))| Change::Value {
            prim: prim.clone(),
            attribute: attribute.clone(),
            type_name: type_name.clone(),
            value: value.clone(),
        };
        self.values.iter().map(change).collect()
    }

    /// How many attributes the edits set.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// The edits as a USDA layer of `over` opinions, to be sublayered above `scene`.
    pub fn usda(&self, scene: &str) -> String {
        let mut text = format!(
            "#usda 1.0\n(\n    doc = \"\"\"Look edits made in strata view on {}. Sublayer this file above it (strongest first) to apply them.\"\"\"\n)\n",
            scene.replace('"', "'")
        );
        // Group attributes by prim, then write each prim path as nested `over`s.
        let mut by_prim: BTreeMap<&str, Vec<(&str, &str, &Value)>> = BTreeMap::new();
        for ((prim, attribute), (type_name, value)) in &self.values {
            by_prim.entry(prim).or_default().push((attribute, type_name, value));
        }
        for (prim, attributes) in by_prim {
            let names: Vec<&str> = prim.split('/').filter(|n| !n.is_empty()).collect();
            text.push('\n');
            for (depth, name) in names.iter().enumerate() {
                text += &format!("{}over \"{name}\"\n{0}{{\n", "    ".repeat(depth));
            }
            let indent = "    ".repeat(names.len());
            for (attribute, type_name, value) in attributes {
                text += &format!("{indent}{type_name} {attribute} = {}\n", usda_value(value));
            }
            for depth in (0..names.len()).rev() {
                text += &format!("{}}}\n", "    ".repeat(depth));
            }
        }
        text
    }

    /// Writes the edits beside `scene` as `STEM.look.usda` (or `STEM.look.N.usda`, the first
    /// name that does not exist), whole or not at all; never over a file the scene read.
    pub fn write(&self, scene: &Path) -> Result<PathBuf, String> {
        let stem = scene.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
        let dir = scene.parent().unwrap_or(Path::new("."));
        let path = (0..1000)
            .map(|n| dir.join(if n == 0 { format!("{stem}.look.usda") } else { format!("{stem}.look.{n}.usda") }))
            .find(|p| !p.exists() && !crate::input::was_read(p))
            .ok_or("no free name for the override layer")?;
        let scene_name = scene.file_name().map_or_else(|| scene.display().to_string(), |n| n.to_string_lossy().into());
        crate::render::film::output::write_file_atomically(&path, self.usda(&scene_name).as_bytes())
            .map_err(|e| e.to_string())?;
        Ok(path)
    }
}

/// A value as USDA writes it (the types [`InputEdit::change`] makes).
fn usda_value(value: &Value) -> String {
    match value {
        Value::Float(x) => format!("{x}"),
        Value::Int(i) => i.to_string(),
        Value::Bool(b) => i32::from(*b).to_string(),
        Value::String(s) | Value::Token(s) => format!("{s:?}"),
        Value::Tuple(t) => format!("({})", t.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join(", ")),
        other => format!("{other:?}"),
    }
}

/// The picked prim's material inputs, per layer bottom to top (vertical layers after their
/// horizontal one): each substance and override with its graph, the shader prim an edit
/// sets, and each input's type and current value; a substance input an attached override
/// drives names that override (`driven_by`), since the override's value wins there.
pub(crate) fn inputs_json(session: &Session, prim: &str) -> serde_json::Value {
    let (Some(composition), Some(stage)) = (session.composed(), session.stage()) else { return json!([]) };
    let Some(material) = composition.material_of(prim) else { return json!([]) };
    let library = &composition.library;
    let reference = |slot: String, r: &MaterialRef, drivers: &[(String, &MaterialRef)]| {
        let graph = library.get(r.graph);
        let inputs: Vec<serde_json::Value> = graph
            .inputs
            .iter()
            .enumerate()
            .map(|(index, input)| {
                let authored = r.values.iter().find(|(i, _)| *i == index).map(|(_, v)| v);
                let driven_by: Vec<&str> = drivers
                    .iter()
                    .filter(|(_, o)| library.get(o.graph).outputs.iter().any(|out| out.name == input.name))
                    .map(|(_, o)| o.path.as_str())
                    .collect();
                json!({
                    "name": input.name,
                    "type": input.ty.to_string(),
                    "editable": editable(input.ty),
                    "value": value_json(authored.unwrap_or(&input.default)),
                    "authored": authored.is_some(),
                    "driven_by": driven_by.last(),
                })
            })
            .collect();
        json!({
            "slot": slot,
            "material": r.path,
            "graph": graph.name,
            "kind": if graph.kind == GraphKind::Override { "override" } else { "substance" },
            "shader": shader_prim(stage, &r.path),
            "inputs": inputs,
        })
    };
    let mut out = Vec::new();
    for layer in &material.layers {
        for part in std::iter::once(layer).chain(&layer.vertical) {
            let overrides: Vec<(String, &MaterialRef)> = part.overrides.iter().map(|(s, o)| (s.name(), o)).collect();
            out.push(reference(part.slot.name(), &part.substance, &overrides));
            out.extend(overrides.iter().map(|(slot, o)| reference(slot.clone(), o, &[])));
        }
    }
    json!(out)
}

/// The prim holding a strata material's inputs (its Shader with `info:strata:sourceAsset`);
/// `None` for a material the page cannot edit (a UsdPreviewSurface network).
fn shader_prim(stage: &Stage, material: &str) -> Option<String> {
    let id = stage.find(material)?;
    let (_, shader) = stage.subtree(id).find(|(_, p)| p.attribute("info:strata:sourceAsset").is_some())?;
    Some(shader.path.clone())
}

fn editable(ty: Type) -> bool {
    ty.array.is_none() && !matches!(ty.base, BaseType::Closure | BaseType::Void)
}

fn value_json(value: &InputValue) -> serde_json::Value {
    match value {
        InputValue::Int(i) => json!(i),
        InputValue::Float(x) => json!(x),
        InputValue::Triple(t) => json!(t),
        InputValue::Str(s) => json!(s),
        InputValue::Array(items) => json!(items.iter().map(value_json).collect::<Vec<_>>()),
    }
}
