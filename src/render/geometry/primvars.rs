//! Primvars for shading: the values of the `primvars:NAME` the scene's materials read
//! (`abi::MaterialInfo::primvars`), stored per primitive when the geometry is built and
//! interpolated at hit points into [`crate::abi::Globals::primvars`].
//!
//! Geometry resolves USD's interpolation and indexing once, at build time: a triangle stores
//! its three corners' values (constant and uniform primvars repeat the face's value, vertex and
//! varying ones the corner's point's, faceVarying ones the face-vertex's, `:indices` resolved),
//! and an analytic shape stores one set. At a hit the corners are blended with the
//! barycentrics, which is how Hydra draws every interpolation on a triangulated mesh.
//! Only prims that have one of the read primvars store anything, and a material that reads
//! none costs nothing at a hit.

use std::borrow::Cow;

use glam::{DAffine3, DMat4};

use crate::scene::{Attribute, Prim, Value};

/// Where a primitive's primvar values are in a [`PrimvarTable`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PrimvarRef {
    /// Index in [`PrimvarTable::layouts`]; `u32::MAX`: the primitive has no stored primvars.
    pub layout: u32,
    /// Index of its first value in [`PrimvarTable::values`].
    pub offset: u32,
}

impl PrimvarRef {
    /// No primvars.
    pub const NONE: PrimvarRef = PrimvarRef { layout: u32::MAX, offset: 0 };
}

impl Default for PrimvarRef {
    fn default() -> Self {
        PrimvarRef::NONE
    }
}

/// How one prim's values are laid out: per name of [`PrimvarTable::names`], its place in a
/// corner.
#[derive(Clone, Debug, PartialEq)]
pub struct PrimvarLayout {
    /// Per name id: `(offset in a corner, components)`; 0 components: the prim lacks it.
    pub fields: Vec<(u32, u32)>,
    /// Floats per corner.
    pub stride: u32,
    /// Corners per primitive: 3 (a triangle's, blended by barycentrics) or 1 (one value for
    /// the whole primitive: analytic shapes).
    pub corners: u32,
}

/// The stored primvars of a scene.
#[derive(Clone, Debug, Default)]
pub struct PrimvarTable {
    /// The primvar names stored (without `primvars:`), by name id: those the materials read.
    pub names: Vec<String>,
    /// Layouts, one per prim that has any of `names`.
    pub layouts: Vec<PrimvarLayout>,
    /// Every primitive's corner values.
    pub values: Vec<f32>,
}

/// The primvar geometry makes of a mesh's own `points`: the shading point in the prim's object
/// space (MaterialX's default `space` for `position` and the 3D noises). The `strata:`
/// namespace keeps it apart from authored primvars. A mesh's points are vertex-interpolated,
/// so blending a triangle's corners gives the object-space point exactly; analytic shapes and
/// Points do not make it (their material then reads its fallback, world `P`, and the build says
/// so).
pub const OBJECT_POSITION: &str = "strata:Pobject";

/// The primvars that carry the hit prim's object-to-world transform to a material, one column
/// each (x, y, z axes, then the translation): MaterialX's object space for `normal`,
/// `tangent`, `bitangent` and `transformpoint`/`vector`/`normal`. Nothing stores them: the
/// integrator fills them at a hit from the prim's [`ObjectSpace`] (placed by its instance's
/// transform at the ray's time, see [`fill_object_space`]), for materials that name them only.
/// Where nothing fills them (a bare evaluation, the emitters' power estimate) they read their
/// fallback, which the library makes the identity: object space is then world space.
pub const OBJECT_TO_WORLD: [&str; 4] =
    ["strata:objectToWorld0", "strata:objectToWorld1", "strata:objectToWorld2", "strata:objectToWorld3"];

/// The columns of the inverse of [`OBJECT_TO_WORLD`], filled likewise.
pub const WORLD_TO_OBJECT: [&str; 4] =
    ["strata:worldToObject0", "strata:worldToObject1", "strata:worldToObject2", "strata:worldToObject3"];

/// [`PrimvarSlot::name`] of the first object-space column (then the other seven, in the order
/// of [`OBJECT_TO_WORLD`] and [`WORLD_TO_OBJECT`]); `u32::MAX` stays "no prim has it".
const OBJECT_SPACE_SLOT: u32 = u32::MAX - 8;

/// A prim's object space: the transforms from it to the space its geometry is built in (the
/// world for a prim built in world space, its prototype's for an instanced one) and back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectSpace {
    /// Object space to the outer space.
    pub to_outer: DAffine3,
    /// The outer space to object space.
    pub to_object: DAffine3,
}

impl Default for ObjectSpace {
    fn default() -> Self {
        ObjectSpace::IDENTITY
    }
}

impl ObjectSpace {
    /// Object space is the outer space.
    pub const IDENTITY: ObjectSpace = ObjectSpace { to_outer: DAffine3::IDENTITY, to_object: DAffine3::IDENTITY };

    /// The object space that `to_outer` (an affine matrix) maps from. A singular transform
    /// (a zero scale, whose prim draws nothing) inverts to non-finite values.
    pub fn new(to_outer: DMat4) -> ObjectSpace {
        let to_outer = DAffine3::from_mat4(to_outer);
        ObjectSpace { to_outer, to_object: to_outer.inverse() }
    }

    /// This object space seen from the space an instance places its prototype in:
    /// `to_world`/`to_object` are the instance's transforms.
    pub fn placed(&self, to_world: &DAffine3, to_object: &DAffine3) -> ObjectSpace {
        ObjectSpace { to_outer: *to_world * self.to_outer, to_object: self.to_object * *to_object }
    }
}

/// Whether any of `slots` is an object-space column ([`OBJECT_TO_WORLD`], [`WORLD_TO_OBJECT`]).
#[inline]
pub fn reads_object_space(slots: &[PrimvarSlot]) -> bool {
    slots.iter().any(|s| (OBJECT_SPACE_SLOT..u32::MAX).contains(&s.name))
}

/// Writes the object-space columns among `slots` into `out` (as [`PrimvarTable::fill`] writes
/// stored primvars: a presence flag of 1, then the components) from `space`, the hit prim's
/// object space relative to the world. Allocation-free.
#[inline]
pub fn fill_object_space(space: &ObjectSpace, slots: &[PrimvarSlot], out: &mut [f32]) {
    for slot in slots {
        let Some(k) = slot.name.checked_sub(OBJECT_SPACE_SLOT).filter(|&k| k < 8) else { continue };
        let o = slot.offset as usize;
        let Some(out) = out.get_mut(o..o + 1 + slot.width as usize) else { continue };
        let m = if k < 4 { &space.to_outer } else { &space.to_object };
        let column = match k % 4 {
            0 => m.matrix3.x_axis,
            1 => m.matrix3.y_axis,
            2 => m.matrix3.z_axis,
            _ => m.translation,
        };
        out[0] = 1.0;
        for (value, c) in out[1..].iter_mut().zip(column.to_array()) {
            *value = c as f32;
        }
    }
}

/// Components stored per primvar at most: the shading language reads floats, triples and a
/// 4-component primvar's fourth (`primvar_alpha`).
pub const MAX_COMPONENTS: usize = 4;

/// A primvar a material reads, resolved against a [`PrimvarTable`]: name id (`u32::MAX` when
/// no prim has it), and where [`crate::abi::PrimvarInfo`] puts it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PrimvarSlot {
    /// Index in [`PrimvarTable::names`], or `u32::MAX`; one of the eight values below it for
    /// an object-space column ([`fill_object_space`]).
    pub name: u32,
    /// Index of the presence flag in the shading point's values.
    pub offset: u32,
    /// Components the material reads.
    pub width: u32,
}

impl PrimvarTable {
    /// Appends one primitive's values in layout `layout`; `NONE` past `u32::MAX` values.
    pub fn push(&mut self, layout: u32, values: &[f32]) -> PrimvarRef {
        let offset = self.values.len();
        if offset + values.len() > u32::MAX as usize {
            return PrimvarRef::NONE;
        }
        self.values.extend_from_slice(values);
        PrimvarRef { layout, offset: offset as u32 }
    }

    /// The values of triangle `at` re-sampled at three points given by barycentrics of its
    /// corners (a triangle cut from it, as dicing makes), as a new triangle's; one-value
    /// primitives keep their values.
    pub fn resample(&mut self, at: PrimvarRef, corners: [[f32; 3]; 3]) -> PrimvarRef {
        let Some(layout) = self.layouts.get(at.layout as usize) else { return PrimvarRef::NONE };
        if layout.corners != 3 {
            return at;
        }
        let stride = layout.stride as usize;
        let base = at.offset as usize;
        let offset = self.values.len();
        if offset + 3 * stride > u32::MAX as usize || base + 3 * stride > offset {
            return PrimvarRef::NONE;
        }
        for b in corners {
            for k in 0..stride {
                let v = |c: usize| self.values[base + c * stride + k];
                let value = v(0) * b[0] + v(1) * b[1] + v(2) * b[2];
                self.values.push(value);
            }
        }
        PrimvarRef { layout: at.layout, offset: offset as u32 }
    }

    /// The slots of a material's primvar table.
    pub fn slots(&self, primvars: &[crate::abi::PrimvarInfo]) -> Vec<PrimvarSlot> {
        primvars
            .iter()
            .map(|p| PrimvarSlot {
                name: match OBJECT_TO_WORLD.iter().chain(&WORLD_TO_OBJECT).position(|n| *n == p.name) {
                    Some(k) => OBJECT_SPACE_SLOT + k as u32,
                    None => self.names.iter().position(|n| *n == p.name).map_or(u32::MAX, |i| i as u32),
                },
                offset: p.offset as u32,
                width: p.width as u32,
            })
            .collect()
    }

    /// Writes the shading point's values of `slots` into `out` (at least as long as the
    /// material's `primvar_floats`): for each, 1 and the components blended with barycentrics
    /// `bary` when the primitive has it, else 0s. Allocation-free.
    #[inline]
    pub fn fill(&self, at: PrimvarRef, bary: [f32; 3], slots: &[PrimvarSlot], out: &mut [f32]) {
        let layout = self.layouts.get(at.layout as usize);
        for slot in slots {
            let o = slot.offset as usize;
            let Some(out) = out.get_mut(o..o + 1 + slot.width as usize) else { continue };
            out.fill(0.0);
            let Some(layout) = layout else { continue };
            let Some(&(field, width)) = layout.fields.get(slot.name as usize) else { continue };
            if width == 0 {
                continue;
            }
            out[0] = 1.0;
            let base = at.offset as usize + field as usize;
            let stride = layout.stride as usize;
            for (k, value) in out[1..].iter_mut().enumerate().take(width as usize) {
                *value = if layout.corners == 1 {
                    self.values.get(base + k).copied().unwrap_or(0.0)
                } else {
                    let corner = |c: usize| self.values.get(base + c * stride + k).copied().unwrap_or(0.0);
                    corner(0) * bary[0] + corner(1) * bary[1] + corner(2) * bary[2]
                };
            }
        }
    }
}

/// One authored primvar: flattened data (any numeric type, as f64), element width,
/// interpolation and indices.
pub(crate) struct Primvar<'a> {
    pub(crate) data: Cow<'a, [f64]>,
    pub(crate) width: usize,
    pub(crate) interpolation: &'a str,
    pub(crate) indices: Option<&'a [i64]>,
    pub(crate) attr: &'a Attribute,
}

impl<'a> Primvar<'a> {
    /// The attribute `name` of `prim` if it is an array of `width`-tuples.
    pub(crate) fn get(prim: &'a Prim, name: &str, width: usize, default_interp: &'a str) -> Option<Primvar<'a>> {
        Primvar::any(prim, name, default_interp).filter(|pv| pv.width == width)
    }

    /// The attribute `name` of `prim` as a primvar of any numeric type: arrays of scalars
    /// (width 1) or tuples, or one value (then constant). `None` when it has no such value.
    pub(crate) fn any(prim: &'a Prim, name: &str, default_interp: &'a str) -> Option<Primvar<'a>> {
        let attr = prim.attribute(name)?;
        let value = attr.get()?;
        let (width, data, single) = match value {
            Value::TupleArray { width, data } => (*width, Cow::Borrowed(data.as_slice()), false),
            Value::FloatArray(data) => (1, Cow::Borrowed(data.as_slice()), false),
            Value::IntArray(data) => (1, Cow::Owned(data.iter().map(|&i| i as f64).collect()), false),
            Value::Tuple(t) => (t.len(), Cow::Owned(t.clone()), true),
            other => (1, Cow::Owned(vec![other.as_f64()?]), true),
        };
        if width == 0 {
            return None;
        }
        let interpolation = if single {
            "constant"
        } else {
            attr.meta("interpolation").and_then(Value::as_str).unwrap_or(default_interp)
        };
        let indices = if single { None } else { prim.value(&format!("{name}:indices")).and_then(Value::as_int_array) };
        Some(Primvar { data, width, interpolation, indices, attr })
    }

    /// Number of elements the interpolation needs, given the mesh's counts.
    pub(crate) fn expected(&self, points: usize, faces: usize, face_vertices: usize) -> Option<usize> {
        match self.interpolation {
            "vertex" | "varying" => Some(points),
            "faceVarying" => Some(face_vertices),
            "uniform" => Some(faces),
            "constant" => Some(1),
            _ => None,
        }
    }

    /// The element for (face, face-vertex ordinal, point index).
    pub(crate) fn at(&self, face: usize, corner: usize, point: usize) -> Option<&[f64]> {
        let slot = match self.interpolation {
            "vertex" | "varying" => point,
            "faceVarying" => corner,
            "uniform" => face,
            _ => 0,
        };
        let element = match self.indices {
            Some(ix) => usize::try_from(*ix.get(slot)?).ok()?,
            None => slot,
        };
        self.data.get(element * self.width..(element + 1) * self.width)
    }

    /// Elements after indexing.
    pub(crate) fn elements(&self) -> usize {
        self.indices.map_or(self.data.len() / self.width, <[i64]>::len)
    }

    /// Whether the indices (if any) stay within the data and the data is finite.
    pub(crate) fn sound(&self) -> bool {
        self.indices.is_none_or(|ix| ix.iter().all(|&i| i >= 0 && (i as usize) < self.data.len() / self.width))
            && self.data.iter().all(|c| c.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_blends_corners_and_flags_presence() {
        let table = PrimvarTable {
            names: vec!["a".into(), "b".into()],
            layouts: vec![
                PrimvarLayout { fields: vec![(0, 1), (0, 0)], stride: 1, corners: 3 },
                PrimvarLayout { fields: vec![(0, 0), (0, 2)], stride: 2, corners: 1 },
            ],
            values: vec![1.0, 2.0, 4.0, 0.5, 0.25],
        };
        let info = |name: &str, width, offset| crate::abi::PrimvarInfo { name: name.into(), width, offset };
        let slots = table.slots(&[info("a", 1, 0), info("b", 3, 2), info("c", 1, 6)]);
        assert_eq!(slots[2].name, u32::MAX);
        let mut out = [9.0; 8];
        table.fill(PrimvarRef { layout: 0, offset: 0 }, [0.5, 0.25, 0.25], &slots, &mut out);
        assert_eq!(out, [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        table.fill(PrimvarRef { layout: 1, offset: 3 }, [0.0, 0.0, 1.0], &slots, &mut out);
        assert_eq!(out, [0.0, 0.0, 1.0, 0.5, 0.25, 0.0, 0.0, 0.0]);
        table.fill(PrimvarRef::NONE, [1.0, 0.0, 0.0], &slots, &mut out);
        assert_eq!(out, [0.0; 8]);
    }

    #[test]
    fn object_space_columns_come_from_the_hit_not_the_table() {
        // A table that happens to store a primvar of the reserved name is not read for it.
        let table = PrimvarTable {
            names: vec![OBJECT_TO_WORLD[3].into()],
            layouts: vec![PrimvarLayout { fields: vec![(0, 3)], stride: 3, corners: 1 }],
            values: vec![7.0, 7.0, 7.0],
        };
        let info = |name: &str, offset| crate::abi::PrimvarInfo { name: name.into(), width: 3, offset };
        let slots = table.slots(&[info(OBJECT_TO_WORLD[3], 0), info(WORLD_TO_OBJECT[0], 4), info("st", 8)]);
        assert!(reads_object_space(&slots) && !reads_object_space(&slots[2..]));
        let m = DMat4::from_scale_rotation_translation(
            glam::DVec3::new(2.0, 1.0, 4.0),
            glam::DQuat::IDENTITY,
            glam::DVec3::new(1.0, 2.0, 3.0),
        );
        let mut out = [9.0; 12];
        table.fill(PrimvarRef { layout: 0, offset: 0 }, [1.0, 0.0, 0.0], &slots, &mut out);
        assert_eq!(out[..8], [0.0; 8], "not stored values");
        fill_object_space(&ObjectSpace::new(m), &slots, &mut out);
        // The translation column, then the inverse's x axis (1/2, 0, 0).
        assert_eq!(out[..8], [1.0, 1.0, 2.0, 3.0, 1.0, 0.5, 0.0, 0.0]);
        let placed = ObjectSpace::new(m).placed(&DAffine3::from_translation(glam::DVec3::X), &DAffine3::IDENTITY);
        assert_eq!(placed.to_outer.translation, glam::DVec3::new(2.0, 2.0, 3.0));
    }
}
