//! Ray queries over the scene's triangles and analytic shapes: an obvhs compressed-wide BVH
//! (CWBVH) over both, with a watertight ray/triangle test (Woop, Benthin & Wald 2013, in f64), so rays through shared edges
//! and vertices never slip between triangles, and robust ray origins (Wächter & Binder,
//! Ray Tracing Gems ch. 6) so secondary rays do not re-hit their own surface.

use super::geometry::Triangle;
use super::shapes::Shape;
use glam::{DVec3, Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::{Boundable, BvhBuildParams};
use std::collections::HashMap;
use std::time::Duration;

/// A closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// The primitive: triangles first, then shapes ([`Accel::primitive`]).
    pub index: u32,
    /// Barycentric weight of vertex 1 (triangles only).
    pub b1: f32,
    /// Barycentric weight of vertex 2 (triangles only).
    pub b2: f32,
}

/// One primitive of the acceleration structure.
#[derive(Clone, Copy, Debug)]
pub enum Primitive<'a> {
    /// A world-space triangle.
    Triangle(&'a Triangle),
    /// An analytic shape.
    Shape(&'a Shape),
}

/// The acceleration structure and the primitives it indexes.
pub struct Accel {
    bvh: Option<CwBvh>,
    triangles: Vec<Triangle>,
    shapes: Vec<Shape>,
    /// The BVH's primitives are groups of primitives with bit-identical bounding boxes:
    /// group `g` holds `group_members[group_start[g]..group_start[g + 1]]`, primitive indices
    /// as in [`Hit::index`].
    group_start: Vec<u32>,
    group_members: Vec<u32>,
}

/// A primitive's box, padded, as exact bits (the key that groups coincident primitives);
/// `None` when it is not finite.
fn padded_box(lo: Vec3, hi: Vec3) -> Option<[u32; 6]> {
    if !lo.is_finite() || !hi.is_finite() {
        return None;
    }
    // obvhs' quantised CWBVH nodes can lose a flat (zero-thickness) box entirely, e.g. a
    // scene that is one axis-aligned plane, so every box gets a thickness. The padding is
    // relative to the primitive's own coordinates, not the scene's: padding by the scene's
    // size made every triangle of a small object far from the origin (or in a scene with
    // one distant object) the same box, on which the PLOC builder is quadratic.
    let pad = lo.abs().max(hi.abs()).max_element().max(f32::MIN_POSITIVE) * 1e-6;
    let (lo, hi) = (lo - Vec3::splat(pad), hi + Vec3::splat(pad));
    Some([lo.x, lo.y, lo.z, hi.x, hi.y, hi.z].map(f32::to_bits))
}

impl Accel {
    /// Builds a BVH over `triangles` and `shapes` (none needed when there are none).
    /// Primitives with non-finite bounds are kept (indices stay valid) but can never be hit;
    /// the geometry stage reports them before this.
    pub fn new(triangles: Vec<Triangle>, shapes: Vec<Shape>) -> Accel {
        // Primitives with bit-identical boxes (copies of one mesh at one place) become one BVH
        // primitive: PLOC merges only mutually-nearest pairs, and among n equal boxes every
        // pass merges one pair, so n coincident copies cost O(n²) to build.
        let bounds = triangles
            .iter()
            .map(|t| (t.p[0].min(t.p[1]).min(t.p[2]), t.p[0].max(t.p[1]).max(t.p[2])))
            .chain(shapes.iter().map(Shape::world_bounds));
        let mut group_of_box: HashMap<[u32; 6], u32> = HashMap::new();
        let mut boxes: Vec<Padded> = Vec::new();
        let mut group_of_primitive: Vec<u32> = Vec::with_capacity(triangles.len() + shapes.len());
        for (lo, hi) in bounds {
            let group = match padded_box(lo, hi) {
                Some(key) => *group_of_box.entry(key).or_insert_with(|| {
                    let [lx, ly, lz, hx, hy, hz] = key.map(f32::from_bits);
                    boxes.push(Padded(Aabb::new(Vec3A::new(lx, ly, lz), Vec3A::new(hx, hy, hz))));
                    boxes.len() as u32 - 1
                }),
                None => u32::MAX,
            };
            group_of_primitive.push(group);
        }
        // Counting sort of primitive indices by group: the groups' lists, back to back.
        let mut group_start = vec![0u32; boxes.len() + 1];
        for &g in group_of_primitive.iter().filter(|&&g| g != u32::MAX) {
            group_start[g as usize + 1] += 1;
        }
        for g in 0..boxes.len() {
            group_start[g + 1] += group_start[g];
        }
        let mut next = group_start.clone();
        let mut group_members = vec![0u32; group_start[boxes.len()] as usize];
        for (index, &g) in group_of_primitive.iter().enumerate() {
            if g != u32::MAX {
                group_members[next[g as usize] as usize] = index as u32;
                next[g as usize] += 1;
            }
        }
        let bvh = if boxes.is_empty() {
            None
        } else {
            Some(build_cwbvh(&boxes, BvhBuildParams::medium_build(), &mut Duration::default()))
        };
        Accel { bvh, triangles, shapes, group_start, group_members }
    }

    /// The triangles, in the order given to [`Accel::new`].
    pub fn triangles(&self) -> &[Triangle] {
        &self.triangles
    }

    /// The primitive of a [`Hit::index`].
    pub fn primitive(&self, index: u32) -> Primitive<'_> {
        let i = index as usize;
        match self.triangles.get(i) {
            Some(t) => Primitive::Triangle(t),
            None => Primitive::Shape(&self.shapes[i - self.triangles.len()]),
        }
    }

    /// The renderable prim a primitive belongs to.
    pub fn prim_of(&self, index: u32) -> u32 {
        match self.primitive(index) {
            Primitive::Triangle(t) => t.prim,
            Primitive::Shape(s) => s.prim,
        }
    }

    /// `(t, b1, b2)` of the ray against primitive `index`.
    #[inline]
    fn hit_primitive(
        &self,
        pre: &RayPre,
        o: Vec3,
        d: Vec3,
        index: u32,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, f32, f32)> {
        let i = index as usize;
        match self.triangles.get(i) {
            Some(tri) => pre.intersect(tri, tmin, tmax),
            None => self.shapes[i - self.triangles.len()].intersect(o, d, tmin, tmax).map(|t| (t, 0.0, 0.0)),
        }
    }

    /// The primitives of BVH primitive `id`.
    #[inline]
    fn group(&self, bvh: &CwBvh, id: usize) -> &[u32] {
        let g = bvh.primitive_indices[id] as usize;
        &self.group_members[self.group_start[g] as usize..self.group_start[g + 1] as usize]
    }

    /// The closest hit of the ray `o + t d`, `t` in `(tmin, tmax)`. `d` must be unit length.
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        if !o.is_finite() || !d.is_finite() || d == Vec3::ZERO {
            return None;
        }
        let pre = RayPre::new(o, d);
        // obvhs picks the traversal octant from sign bits: a -0.0 component would select the
        // wrong one and miss everything, so negative zeros become +0.0 (-0 + 0 = +0).
        let ray = Ray::new(o.into(), (d + Vec3::ZERO).into(), tmin, tmax);
        let mut best: Option<Hit> = None;
        let mut hit = RayHit::none();
        bvh.ray_traverse(ray, &mut hit, |r, id| {
            let mut closest = f32::INFINITY;
            for &index in self.group(bvh, id) {
                if let Some((t, b1, b2)) = self.hit_primitive(&pre, o, d, index, tmin, r.tmax.min(closest)) {
                    best = Some(Hit { t, index, b1, b2 });
                    closest = t;
                }
            }
            closest
        });
        best
    }

    /// Whether anything lies on the ray within `(tmin, tmax)` (shadow rays: stops at the first hit).
    pub fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        let Some(bvh) = self.bvh.as_ref() else { return false };
        if !o.is_finite() || !d.is_finite() || d == Vec3::ZERO {
            return false;
        }
        let pre = RayPre::new(o, d);
        // obvhs picks the traversal octant from sign bits: a -0.0 component would select the
        // wrong one and miss everything, so negative zeros become +0.0 (-0 + 0 = +0).
        let ray = Ray::new(o.into(), (d + Vec3::ZERO).into(), tmin, tmax);
        !bvh.ray_traverse_miss(ray, |r, id| {
            self.group(bvh, id)
                .iter()
                .find_map(|&index| self.hit_primitive(&pre, o, d, index, tmin, r.tmax))
                .map_or(f32::INFINITY, |h| h.0)
        })
    }
}

/// A triangle's bounding box as the BVH builder sees it.
struct Padded(Aabb);

impl Boundable for Padded {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

/// Per-ray precomputation of the watertight test: the axis permutation and shear that map
/// the ray to +z. The test runs in f64 (scalar f64 costs the same as f32 here): with f32, the
/// hit distance on a large triangle is only accurate to ~1e-7 of the triangle's size, which
/// is more than a robust ray-origin offset, and secondary rays would re-hit their surface.
struct RayPre {
    o: DVec3,
    k: [usize; 3],
    s: DVec3,
}

impl RayPre {
    fn new(o: Vec3, d: Vec3) -> RayPre {
        let d = d.as_dvec3();
        let a = d.abs();
        let kz = if a.x > a.y {
            if a.x > a.z { 0 } else { 2 }
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let s = DVec3::new(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
        RayPre { o: o.as_dvec3(), k: [kx, ky, kz], s }
    }

    /// `(t, b1, b2)` of a hit with `t` in `(tmin, tmax)`.
    #[inline]
    fn intersect(&self, tri: &Triangle, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        let [kx, ky, kz] = self.k;
        let a = tri.p[0].as_dvec3() - self.o;
        let b = tri.p[1].as_dvec3() - self.o;
        let c = tri.p[2].as_dvec3() - self.o;
        let ax = a[kx] - self.s.x * a[kz];
        let ay = a[ky] - self.s.y * a[kz];
        let bx = b[kx] - self.s.x * b[kz];
        let by = b[ky] - self.s.y * b[kz];
        let cx = c[kx] - self.s.x * c[kz];
        let cy = c[ky] - self.s.y * c[kz];
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let t_scaled = u * self.s.z * a[kz] + v * self.s.z * b[kz] + w * self.s.z * c[kz];
        let inv = 1.0 / det;
        let t = (t_scaled * inv) as f32;
        if !(t > tmin && t < tmax) {
            return None;
        }
        Some((t, (v * inv) as f32, (w * inv) as f32))
    }
}

/// Moves `p` off its surface along the geometric normal `n` (pointing to the side the new
/// ray leaves from) by a few ULPs, scaled to `p`'s magnitude (Wächter & Binder 2019).
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let mut out = p;
    for i in 0..3 {
        let of = (INT_SCALE * n[i]) as i32;
        let bits = p[i].to_bits() as i32;
        let moved = f32::from_bits((if p[i] < 0.0 { bits - of } else { bits + of }) as u32);
        out[i] = if p[i].abs() < ORIGIN { p[i] + FLOAT_SCALE * n[i] } else { moved };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    fn tri(p: [Vec3; 3]) -> Triangle {
        Triangle { p, n: [Vec3::Z; 3], uv: [Vec2::ZERO; 3], prim: 0, has_uv: false }
    }

    #[test]
    fn closest_hit_and_barycentrics() {
        let near = tri([Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, -1.0, 1.0), Vec3::new(-1.0, 1.0, 1.0)]);
        let far = tri([Vec3::new(-5.0, -5.0, 3.0), Vec3::new(5.0, -5.0, 3.0), Vec3::new(-5.0, 5.0, 3.0)]);
        let accel = Accel::new(vec![far, near], vec![]);
        let hit = accel.intersect(Vec3::new(-0.5, -0.5, 0.0), Vec3::Z, 0.0, f32::INFINITY).unwrap();
        assert_eq!(hit.index, 1);
        assert!((hit.t - 1.0).abs() < 1e-6);
        assert!((hit.b1 - 0.25).abs() < 1e-6 && (hit.b2 - 0.25).abs() < 1e-6);
        assert!(accel.occluded(Vec3::new(-0.5, -0.5, 0.0), Vec3::Z, 0.0, 2.0));
        assert!(!accel.occluded(Vec3::new(-0.5, -0.5, 0.0), Vec3::Z, 0.0, 0.5));
        assert!(accel.intersect(Vec3::new(-0.5, -0.5, 0.0), -Vec3::Z, 0.0, f32::INFINITY).is_none());
    }

    #[test]
    fn shared_edge_is_watertight() {
        // Two triangles sharing the diagonal of a square; rays exactly on the diagonal must hit.
        let a = tri([Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)]);
        let b = tri([Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)]);
        let accel = Accel::new(vec![a, b], vec![]);
        for i in 1..100 {
            let x = i as f32 / 100.0;
            let o = Vec3::new(x, x, 1.0);
            assert!(accel.intersect(o, -Vec3::Z, 0.0, f32::INFINITY).is_some(), "leak at {x}");
        }
    }

    #[test]
    fn coincident_copies_build_fast_and_the_first_closest_copy_is_hit() {
        // Copies of one triangle have identical boxes, on which PLOC merged one pair per pass:
        // 20 000 copies took minutes. Grouped, they are one BVH primitive.
        let t = tri([Vec3::new(-1.0, -1.0, 2.0), Vec3::new(1.0, -1.0, 2.0), Vec3::new(0.0, 1.0, 2.0)]);
        let nearer = tri([Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, -1.0, 1.0), Vec3::new(0.0, 1.0, 1.0)]);
        let mut triangles = vec![t; 20_000];
        triangles.push(nearer);
        triangles.extend(vec![nearer; 20_000]);
        let accel = Accel::new(triangles, vec![]);
        let hit = accel.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).expect("hit");
        assert_eq!(hit.index, 20_000, "the first of the coincident nearest triangles");
        assert!(accel.occluded(Vec3::ZERO, Vec3::Z, 0.0, 1.5));
        assert!(!accel.occluded(Vec3::ZERO, Vec3::Z, 0.0, 0.5));
    }

    #[test]
    fn non_finite_triangles_are_never_hit_and_never_reach_the_builder() {
        let bad = tri([Vec3::new(f32::NAN, 0.0, 1.0), Vec3::new(f32::INFINITY, 0.0, 1.0), Vec3::Y]);
        let good = tri([Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, -1.0, 1.0), Vec3::new(0.0, 1.0, 1.0)]);
        let accel = Accel::new(vec![bad, good], vec![]);
        assert_eq!(accel.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).map(|h| h.index), Some(1));
        let only_bad = Accel::new(vec![bad], vec![]);
        assert!(only_bad.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).is_none());
        assert_eq!(only_bad.triangles().len(), 1);
    }

    #[test]
    fn offset_origin_escapes_surface() {
        let t = tri([Vec3::new(-100.0, -100.0, 7.3), Vec3::new(100.0, -100.0, 7.3), Vec3::new(0.0, 100.0, 7.3)]);
        let accel = Accel::new(vec![t], vec![]);
        let p = Vec3::new(0.123, 0.456, 7.3);
        let o = offset_ray_origin(p, Vec3::Z);
        assert!(o.z > p.z);
        assert!(accel.intersect(o, Vec3::new(0.3, 0.0, 0.01).normalize(), 0.0, f32::INFINITY).is_none());
        let below = offset_ray_origin(p, -Vec3::Z);
        assert!(accel.intersect(below, Vec3::new(0.3, 0.0, 0.01).normalize(), 0.0, f32::INFINITY).is_some());
    }
}
