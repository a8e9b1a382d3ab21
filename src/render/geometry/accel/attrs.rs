//! What a BLAS keeps of its triangles besides their positions, compactly: shading normals
//! only where they differ from the flat normal of the positions, texture coordinates only
//! where the prim has them, primvar references only when some triangle has primvars. A hit
//! reads back exactly what the triangle held ([`AttrTable::get`]).

use crate::render::geometry::primvars::PrimvarRef;
use crate::render::geometry::{Triangle, flat_normal};
use glam::{Vec2, Vec3};

/// "No entry" in [`AttrTable`]'s per-triangle slot tables.
const NONE: u32 = u32::MAX;

/// In `uv_of`: the prim has texture coordinates, and they are [`PARAMETRIC_UV`] (a hit reads
/// them as `None`, as it reads [`NONE`]; only [`Triangle::has_uv`] tells the two apart).
const PARAMETRIC_OWN: u32 = u32::MAX - 1;

/// The texture coordinates of a triangle without its own: the parametric `(0,0), (1,0), (0,1)`.
pub(in crate::render::geometry) const PARAMETRIC_UV: [Vec2; 3] = [Vec2::ZERO, Vec2::X, Vec2::Y];

/// What a triangle needs only after it was hit.
#[derive(Clone, Copy, Debug)]
pub(super) struct TriangleAttrs {
    /// The corners' shading normals; `None` when each is the triangle's flat normal (the
    /// caller has the winding normal already, and a hit then needs no interpolation).
    pub(super) n: Option<[Vec3; 3]>,
    /// The corners' texture coordinates; `None` for [`PARAMETRIC_UV`].
    pub(super) uv: Option<[Vec2; 3]>,
    /// The prim: a global prim index in the world BLAS, a prototype-local one in a prototype's.
    pub(super) prim: u32,
    pub(super) primvars: PrimvarRef,
}

/// Per-triangle attributes, stored only where they carry information. The optional columns
/// (`normal_of`, `uv_of`, `primvars`) stay empty until a triangle needs them, so a mesh
/// without normals or primvars never allocates them, not even while it is emitted.
#[derive(Clone, Debug, Default)]
pub(in crate::render::geometry) struct AttrTable {
    prims: Vec<u32>,
    /// Per triangle its entry in `normals`, or [`NONE`] (its flat normal at every corner);
    /// empty when no triangle has an entry.
    normal_of: Vec<u32>,
    normals: Vec<[Vec3; 3]>,
    /// Per triangle its entry in `uvs`, [`NONE`] (no coordinates of its own) or
    /// [`PARAMETRIC_OWN`]; empty when every triangle is [`NONE`].
    uv_of: Vec<u32>,
    uvs: Vec<[Vec2; 3]>,
    /// Per triangle its primvars; empty when no triangle has any.
    primvars: Vec<PrimvarRef>,
}

/// Appends `value` to the optional column `column`, first filling it with `absent` up to
/// `len` entries when it was left empty so far.
fn push_optional<T: Copy + PartialEq>(column: &mut Vec<T>, len: usize, value: T, absent: T) {
    if column.is_empty() {
        if value == absent {
            return;
        }
        column.resize(len, absent);
    }
    column.push(value);
}

impl AttrTable {
    /// Appends the attributes of `t` (its positions are the caller's).
    pub(in crate::render::geometry) fn push(&mut self, t: &Triangle) {
        let len = self.prims.len();
        self.prims.push(t.prim);
        push_optional(&mut self.primvars, len, t.primvars, PrimvarRef::NONE);
        let normal = if t.n == [flat_normal(t.p); 3] {
            NONE
        } else {
            self.normals.push(t.n);
            self.normals.len() as u32 - 1
        };
        push_optional(&mut self.normal_of, len, normal, NONE);
        let uv = match (t.has_uv, t.uv == PARAMETRIC_UV) {
            (false, _) => NONE,
            (true, true) => PARAMETRIC_OWN,
            (true, false) => {
                self.uvs.push(t.uv);
                self.uvs.len() as u32 - 1
            }
        };
        push_optional(&mut self.uv_of, len, uv, NONE);
    }

    /// Triangle `i` as it was pushed, given its positions `p` (without coordinates of its
    /// own, with [`PARAMETRIC_UV`]).
    pub(in crate::render::geometry) fn triangle(&self, i: usize, p: [Vec3; 3]) -> Triangle {
        let a = self.get(i);
        let uv_of = self.uv_of.get(i).copied().unwrap_or(NONE);
        Triangle {
            p,
            n: a.n.unwrap_or([flat_normal(p); 3]),
            uv: a.uv.unwrap_or(PARAMETRIC_UV),
            prim: a.prim,
            has_uv: uv_of != NONE,
            primvars: a.primvars,
        }
    }

    /// Room for `additional` more triangles in the column every triangle has an entry in.
    pub(in crate::render::geometry) fn reserve_exact(&mut self, additional: usize) {
        self.prims.reserve_exact(additional);
    }

    /// Frees the columns' spare room.
    pub(in crate::render::geometry) fn shrink_to_fit(&mut self) {
        for v in [&mut self.prims, &mut self.normal_of, &mut self.uv_of] {
            v.shrink_to_fit();
        }
        self.primvars.shrink_to_fit();
        self.normals.shrink_to_fit();
        self.uvs.shrink_to_fit();
    }

    /// Number of triangles.
    pub(super) fn len(&self) -> usize {
        self.prims.len()
    }

    /// The prim of triangle `i`, if there is one.
    #[inline]
    pub(in crate::render::geometry) fn prim(&self, i: usize) -> Option<u32> {
        self.prims.get(i).copied()
    }

    /// Triangle `i`'s attributes, as the triangle held them (`None` for the flat normal and
    /// the parametric coordinates).
    #[inline]
    pub(super) fn get(&self, i: usize) -> TriangleAttrs {
        let entry = |of: &[u32]| of.get(i).copied().filter(|&k| k < PARAMETRIC_OWN).map(|k| k as usize);
        TriangleAttrs {
            n: entry(&self.normal_of).map(|k| self.normals[k]),
            uv: entry(&self.uv_of).map(|k| self.uvs[k]),
            prim: self.prims[i],
            primvars: self.primvars.get(i).copied().unwrap_or(PrimvarRef::NONE),
        }
    }

    /// Bytes held.
    pub(in crate::render::geometry) fn bytes(&self) -> usize {
        use std::mem::size_of;
        (self.prims.len() + self.normal_of.len() + self.uv_of.len()) * 4
            + self.normals.len() * size_of::<[Vec3; 3]>()
            + self.uvs.len() * size_of::<[Vec2; 3]>()
            + self.primvars.len() * size_of::<PrimvarRef>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table_of(triangles: &[Triangle]) -> AttrTable {
        let mut table = AttrTable::default();
        triangles.iter().for_each(|t| table.push(t));
        table
    }

    /// Every triangle reads back exactly as it was given, whichever attributes it had, and
    /// what carries no information is not stored.
    #[test]
    fn triangles_read_back_exactly_and_flat_ones_store_no_normals() {
        let p = |k: f32| [Vec3::new(k, 0.0, 0.1), Vec3::new(k + 1.0, 0.3, 0.0), Vec3::new(k, 1.0, 0.7)];
        let bent = [Vec3::X, Vec3::Y, Vec3::Z];
        let mut triangles = Vec::new();
        for k in 0..20_000u32 {
            let pos = p(k as f32 * 0.01);
            let n = if k % 3 == 0 { bent } else { [flat_normal(pos); 3] };
            let has_uv = k % 5 == 0;
            let uv = if has_uv { [Vec2::splat(k as f32), Vec2::X, Vec2::Y] } else { [Vec2::ZERO; 3] };
            let primvars = if k % 7 == 0 { PrimvarRef { layout: 1, offset: k } } else { PrimvarRef::NONE };
            triangles.push(Triangle { p: pos, n, uv, prim: k / 10, has_uv, primvars });
        }
        let positions: Vec<[Vec3; 3]> = triangles.iter().map(|t| t.p).collect();
        let table = table_of(&triangles);
        assert_eq!(table.len(), triangles.len());
        for (i, t) in triangles.iter().enumerate() {
            assert_eq!(positions[i], t.p);
            let a = table.get(i);
            assert_eq!(a.n.unwrap_or([flat_normal(positions[i]); 3]), t.n, "{i}");
            assert_eq!(a.uv.unwrap_or(PARAMETRIC_UV), if t.has_uv { t.uv } else { PARAMETRIC_UV }, "{i}");
            assert_eq!((a.prim, a.primvars), (t.prim, t.primvars), "{i}");
        }
        assert_eq!(table.normals.len(), triangles.len().div_ceil(3));
        assert_eq!(table.uvs.len(), triangles.len().div_ceil(5) - 1, "the first has the parametric coordinates");
        // Flat, without coordinates or primvars: prims alone.
        let flat: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle { n: [flat_normal(t.p); 3], has_uv: false, primvars: PrimvarRef::NONE, ..*t })
            .collect();
        let mut table = table_of(&flat);
        table.shrink_to_fit();
        assert_eq!(table.bytes(), 4 * triangles.len());
    }
}
