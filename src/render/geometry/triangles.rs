//! The emitted triangles, stored as the BLAS keeps them: a position table and an
//! [`AttrTable`] (shading normals only where they differ from the flat normal, texture
//! coordinates only where the prim has them, primvar references only once some triangle has
//! them). Emission appends straight into these tables, so a mesh never exists as whole
//! [`Triangle`]s (112 bytes each): a 10⁶-triangle mesh with `st` holds 68 bytes per triangle
//! here, and the BLAS takes the attribute table as it is and moves the positions into its
//! BVH's leaf order (`accel/leaves.rs`).

use crate::render::geometry::Triangle;
use crate::render::geometry::accel::attrs::AttrTable;
use glam::Vec3;

/// Triangles, in emission order; [`Triangles::get`] reads back a [`Triangle`] as it was
/// pushed (one without texture coordinates reads back with the parametric ones).
#[derive(Clone, Debug, Default)]
pub struct Triangles {
    positions: Vec<[Vec3; 3]>,
    attrs: AttrTable,
}

impl Triangles {
    /// No triangles.
    pub fn new() -> Triangles {
        Triangles::default()
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Appends `t`.
    pub fn push(&mut self, t: Triangle) {
        self.positions.push(t.p);
        self.attrs.push(&t);
    }

    /// Triangle `i`. Panics when `i` is out of range, as indexing does.
    pub fn get(&self, i: usize) -> Triangle {
        self.attrs.triangle(i, self.positions[i])
    }

    /// The triangles' vertex positions.
    pub fn positions(&self) -> &[[Vec3; 3]] {
        &self.positions
    }

    /// The prim of triangle `i`.
    pub fn prim(&self, i: usize) -> u32 {
        self.attrs.prim(i).expect("a triangle index")
    }

    /// The triangles, by value.
    pub fn iter(&self) -> Iter<'_> {
        Iter { triangles: self, indices: 0..self.len() }
    }

    /// Room for `additional` more triangles in the tables every triangle has an entry in.
    pub fn reserve_exact(&mut self, additional: usize) {
        self.positions.reserve_exact(additional);
        self.attrs.reserve_exact(additional);
    }

    /// Bytes held (spare room not counted).
    pub fn bytes(&self) -> usize {
        self.positions.len() * std::mem::size_of::<[Vec3; 3]>() + self.attrs.bytes()
    }

    /// The position table and the attributes, their spare room freed (for the BLAS).
    pub(in crate::render::geometry) fn into_parts(mut self) -> (Vec<[Vec3; 3]>, AttrTable) {
        self.positions.shrink_to_fit();
        self.attrs.shrink_to_fit();
        (self.positions, self.attrs)
    }
}

impl Extend<Triangle> for Triangles {
    fn extend<I: IntoIterator<Item = Triangle>>(&mut self, iter: I) {
        for t in iter {
            self.push(t);
        }
    }
}

impl FromIterator<Triangle> for Triangles {
    fn from_iter<I: IntoIterator<Item = Triangle>>(iter: I) -> Triangles {
        let mut triangles = Triangles::new();
        triangles.extend(iter);
        triangles
    }
}

impl From<Vec<Triangle>> for Triangles {
    fn from(triangles: Vec<Triangle>) -> Triangles {
        triangles.into_iter().collect()
    }
}

impl IntoIterator for Triangles {
    type Item = Triangle;
    type IntoIter = IntoIter;

    fn into_iter(self) -> IntoIter {
        IntoIter { triangles: self, next: 0 }
    }
}

impl<'a> IntoIterator for &'a Triangles {
    type Item = Triangle;
    type IntoIter = Iter<'a>;

    fn into_iter(self) -> Iter<'a> {
        self.iter()
    }
}

/// [`Triangles`] by value, in order, borrowing the tables.
pub struct Iter<'a> {
    triangles: &'a Triangles,
    indices: std::ops::Range<usize>,
}

impl Iterator for Iter<'_> {
    type Item = Triangle;

    fn next(&mut self) -> Option<Triangle> {
        self.indices.next().map(|i| self.triangles.get(i))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.indices.size_hint()
    }
}

impl ExactSizeIterator for Iter<'_> {}

/// [`Triangles`] by value, in order (the tables are freed with the iterator).
pub struct IntoIter {
    triangles: Triangles,
    next: usize,
}

impl Iterator for IntoIter {
    type Item = Triangle;

    fn next(&mut self) -> Option<Triangle> {
        let i = self.next;
        (i < self.triangles.len()).then(|| {
            self.next += 1;
            self.triangles.get(i)
        })
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.triangles.len() - self.next;
        (left, Some(left))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::geometry::flat_normal;
    use crate::render::geometry::primvars::PrimvarRef;
    use glam::Vec2;

    /// Every triangle reads back exactly as it was pushed, whichever attributes it had
    /// (coordinates present or not, equal to the parametric ones or not), and a partition
    /// through the iterators keeps them.
    #[test]
    fn triangles_read_back_as_pushed() {
        let p = |k: f32| [Vec3::new(k, 0.0, 0.1), Vec3::new(k + 1.0, 0.3, 0.0), Vec3::new(k, 1.0, 0.7)];
        let parametric = [Vec2::ZERO, Vec2::X, Vec2::Y];
        let given: Vec<Triangle> = (0..3000u32)
            .map(|k| {
                let pos = p(k as f32 * 0.01);
                let n = if k % 3 == 0 { [Vec3::X, Vec3::Y, Vec3::Z] } else { [flat_normal(pos); 3] };
                let has_uv = k % 5 < 2;
                let uv = if k % 5 == 0 { [Vec2::splat(k as f32), Vec2::X, Vec2::Y] } else { parametric };
                let primvars = if k % 7 == 0 { PrimvarRef { layout: 1, offset: k } } else { PrimvarRef::NONE };
                Triangle { p: pos, n, uv, prim: k / 10, has_uv, primvars }
            })
            .collect();
        let same = |a: &Triangle, b: &Triangle| {
            (a.p, a.n, a.uv, a.prim, a.has_uv, a.primvars) == (b.p, b.n, b.uv, b.prim, b.has_uv, b.primvars)
        };
        let table = Triangles::from(given.clone());
        assert_eq!(table.len(), given.len());
        for (i, t) in given.iter().enumerate() {
            assert!(same(&table.get(i), t), "{i}");
            assert_eq!(table.prim(i), t.prim);
        }
        let (odd, even): (Triangles, Triangles) = table.into_iter().partition(|t| t.prim % 2 == 1);
        let mut odd = odd.iter();
        let mut even = even.iter();
        for t in &given {
            let got = if t.prim % 2 == 1 { odd.next() } else { even.next() };
            assert!(same(&got.unwrap(), t));
        }
        assert!(odd.next().is_none() && even.next().is_none());
    }
}
