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
}

impl Accel {
    /// Builds a BVH over `triangles` and `shapes` (none needed when there are none).
    pub fn new(triangles: Vec<Triangle>, shapes: Vec<Shape>) -> Accel {
        let mut boxes: Vec<(Vec3, Vec3)> =
            triangles.iter().map(|t| (t.p[0].min(t.p[1]).min(t.p[2]), t.p[0].max(t.p[1]).max(t.p[2]))).collect();
        boxes.extend(shapes.iter().map(Shape::world_bounds));
        let bvh = if boxes.is_empty() {
            None
        } else {
            // Boxes are padded slightly: obvhs' quantised CWBVH nodes can lose a flat
            // (zero-thickness) box entirely, e.g. a scene that is one axis-aligned plane.
            let scale =
                boxes.iter().fold(1.0f32, |m, (lo, hi)| m.max(lo.abs().max_element()).max(hi.abs().max_element()));
            let pad = Vec3A::splat(scale * 1e-6);
            let boxes: Vec<Padded> =
                boxes.iter().map(|&(lo, hi)| Padded(Aabb::new(Vec3A::from(lo) - pad, Vec3A::from(hi) + pad))).collect();
            Some(build_cwbvh(&boxes, BvhBuildParams::medium_build(), &mut Duration::default()))
        };
        Accel { bvh, triangles, shapes }
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
            let index = bvh.primitive_indices[id];
            match self.hit_primitive(&pre, o, d, index, tmin, r.tmax) {
                Some((t, b1, b2)) => {
                    best = Some(Hit { t, index, b1, b2 });
                    t
                }
                None => f32::INFINITY,
            }
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
            let index = bvh.primitive_indices[id];
            self.hit_primitive(&pre, o, d, index, tmin, r.tmax).map_or(f32::INFINITY, |h| h.0)
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
