//! What a BLAS keeps of its triangles besides their positions, compactly: shading normals
//! only where they differ from the flat normal of the positions, texture coordinates only
//! where the prim has them, primvar references only when some triangle has primvars. A hit
//! reads back exactly what the triangle held ([`AttrTable::get`]).

use crate::render::geometry::primvars::PrimvarRef;
use crate::render::geometry::{Triangle, flat_normal};
use glam::{Vec2, Vec3};

/// "No entry" in [`AttrTable`]'s per-triangle slot tables.
const NONE: u32 = u32::MAX;

/// The texture coordinates of a triangle without its own: the parametric `(0,0), (1,0), (0,1)`.
pub(super) const PARAMETRIC_UV: [Vec2; 3] = [Vec2::ZERO, Vec2::X, Vec2::Y];

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

/// Per-triangle attributes, stored only where they carry information.
#[derive(Default)]
pub(super) struct AttrTable {
    prims: Vec<u32>,
    /// Per triangle its entry in `normals`, or [`NONE`] (its flat normal at every corner);
    /// empty when no triangle has an entry.
    normal_of: Vec<u32>,
    normals: Vec<[Vec3; 3]>,
    /// Per triangle its entry in `uvs`, or [`NONE`] ([`PARAMETRIC_UV`]); empty when none has one.
    uv_of: Vec<u32>,
    uvs: Vec<[Vec2; 3]>,
    /// Per triangle its primvars; empty when no triangle has any.
    primvars: Vec<PrimvarRef>,
}

impl AttrTable {
    /// The attributes of `triangles`, which are consumed from the back and freed as they go
    /// (so the triangles and the table are never both whole in memory: build peak), with
    /// their positions, in order.
    pub(super) fn take(mut triangles: Vec<Triangle>) -> (Vec<[Vec3; 3]>, AttrTable) {
        let count = triangles.len();
        // The vectors below are filled back to front (reversed at the end); `triangles`
        // gives its memory back each time this many have been taken.
        let step = (count / 16).max(1 << 12);
        let mut positions = Vec::with_capacity(count);
        let mut table = AttrTable {
            prims: Vec::with_capacity(count),
            normal_of: Vec::with_capacity(count),
            uv_of: Vec::with_capacity(count),
            primvars: Vec::with_capacity(count),
            ..AttrTable::default()
        };
        while let Some(t) = triangles.pop() {
            positions.push(t.p);
            table.prims.push(t.prim);
            table.primvars.push(t.primvars);
            if t.n == [flat_normal(t.p); 3] {
                table.normal_of.push(NONE);
            } else {
                table.normal_of.push(table.normals.len() as u32);
                table.normals.push(t.n);
            }
            if t.has_uv && t.uv != PARAMETRIC_UV {
                table.uv_of.push(table.uvs.len() as u32);
                table.uvs.push(t.uv);
            } else {
                table.uv_of.push(NONE);
            }
            if triangles.capacity() - triangles.len() >= step {
                triangles.shrink_to_fit();
            }
        }
        positions.reverse();
        table.finish();
        (positions, table)
    }

    /// Puts the back-to-front vectors in order and drops the tables nothing needs.
    fn finish(&mut self) {
        self.prims.reverse();
        self.primvars.reverse();
        for (of, entries) in [(&mut self.normal_of, self.normals.len()), (&mut self.uv_of, self.uvs.len())] {
            of.reverse();
            if entries == 0 {
                *of = Vec::new();
            } else {
                // Entries were numbered back to front too.
                of.iter_mut().filter(|k| **k != NONE).for_each(|k| *k = entries as u32 - 1 - *k);
            }
        }
        self.normals.reverse();
        self.uvs.reverse();
        if self.primvars.iter().all(|p| *p == PrimvarRef::NONE) {
            self.primvars = Vec::new();
        }
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
    pub(super) fn prim(&self, i: usize) -> Option<u32> {
        self.prims.get(i).copied()
    }

    /// Triangle `i`'s attributes, as the triangle held them (`None` for the flat normal and
    /// the parametric coordinates).
    #[inline]
    pub(super) fn get(&self, i: usize) -> TriangleAttrs {
        let entry = |of: &[u32]| of.get(i).copied().filter(|&k| k != NONE).map(|k| k as usize);
        TriangleAttrs {
            n: entry(&self.normal_of).map(|k| self.normals[k]),
            uv: entry(&self.uv_of).map(|k| self.uvs[k]),
            prim: self.prims[i],
            primvars: self.primvars.get(i).copied().unwrap_or(PrimvarRef::NONE),
        }
    }

    /// Bytes held.
    pub(super) fn bytes(&self) -> usize {
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
        let (positions, table) = AttrTable::take(triangles.clone());
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
        let (_, table) = AttrTable::take(flat);
        assert_eq!(table.bytes(), 4 * triangles.len());
    }
}
