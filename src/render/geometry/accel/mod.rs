//! Ray queries over the scene's triangles and analytic shapes, in two levels: a bottom-level
//! BVH ([`Blas`]) per unique piece of geometry — the world's un-instanced geometry, and one
//! per instancing prototype — and a top-level BVH over the instances, each a prototype under
//! an affine transform. Rays are moved into an instance's object space for its BLAS, so
//! memory grows with unique geometry, not with copies. A scene without instances has no top
//! level at all: its rays traverse the world BLAS only, as a single-level BVH would.
//!
//! Each BVH is built by obvhs as a compressed-wide BVH (CWBVH: 8 children per node) over
//! triangles and shapes alike and kept in strata's own layout (`wide.rs`): the same tree with
//! each node's 8 child boxes as f32 lanes, tested in one pass with AVX2 where the CPU has it
//! (chosen at run time), children visited nearest first, occlusion stopping at the first hit,
//! a leaf a range of primitives whose triangles are stored together in leaf order and tested
//! 8 at a time (`leaves.rs`). The ray/triangle test is watertight (Woop,
//! Benthin & Wald 2013), so rays through shared edges and vertices never slip between
//! triangles, and ray origins are robust so secondary rays do not re-hit their own surface.
//! `benches/bvh.rs` measures it against Embree.
//!
//! obvhs' own traversal culled every box whose exit distance along the ray was below an
//! absolute 1e-4 (`cwbvh::node::EPSILON`): in a scene a few 1e-4 units across every camera
//! ray missed everything. Each BVH is still built and traversed in its own space, scaled by a
//! power of two that brings its extent to 2³⁰ ([`BvhSpace`]): the scaling is exact in f32,
//! the primitive tests run unscaled, and obvhs' builder sees every scene at one scale.

use crate::render::geometry::motion::{Deformation, MotionKeys};
use crate::render::geometry::primvars::PrimvarRef;
use crate::render::geometry::shapes::Shape;
use crate::render::geometry::triangles::Triangles;
use glam::{DAffine3, DMat3, Vec2, Vec3};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::cwbvh::builder::build_cwbvh;
use std::collections::HashMap;
use std::time::Duration;

pub(in crate::render::geometry) mod attrs;
mod batched;
mod convert;
mod frames;
mod leaves;
mod wide;

use attrs::AttrTable;
pub use batched::PLOC_BATCH;
use batched::{Padded, build_batched, build_grouped};
pub(crate) use frames::tangents;
use frames::{edge_tangents, frame_or, shading_normal, winding_normal};
use leaves::{LeafTriangles, RayPre, dominant_axis};
#[cfg(test)]
pub(in crate::render::geometry) use wide::tests::generator;
use wide::{WideBvh, WideRay};

// Defined below the BVH (geometry produces instances; shapes bound their own hit points), so
// the render modules import in one direction: accel → geometry → shapes.
pub use crate::render::geometry::InstanceDesc;
pub use crate::render::geometry::shapes::{gamma, offset_ray_origin};

/// [`Hit::instance`] of a hit on the world's (un-instanced) geometry.
pub const WORLD: u32 = u32::MAX;

/// A closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// The primitive within its BLAS: triangles first, then shapes.
    pub index: u32,
    /// The instance hit, or [`WORLD`].
    pub instance: u32,
    /// Barycentric weight of vertex 1 (triangles only).
    pub b1: f32,
    /// Barycentric weight of vertex 2 (triangles only).
    pub b2: f32,
}

/// Surface geometry at a hit, in world space.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceGeom {
    /// The hit point.
    pub p: Vec3,
    /// A conservative bound on the absolute error of each component of `p`: the true surface
    /// point lies within `p ± p_error` ([`offset_ray_origin`] moves past it).
    pub p_error: Vec3,
    /// Geometric normal (unit), outward by winding (triangles) or outward (shapes).
    pub ng: Vec3,
    /// Interpolated shading normal (unit), on `ng`'s side.
    pub ns: Vec3,
    /// ∂P/∂u.
    pub dpdu: Vec3,
    /// ∂P/∂v.
    pub dpdv: Vec3,
    /// Texture coordinates.
    pub uv: Vec2,
    /// The renderable prim (index into `Scene::prims`).
    pub prim: u32,
    /// Where the primitive's primvar values are.
    pub primvars: PrimvarRef,
    /// Barycentric weights of the triangle's corners at the hit (`[1, 0, 0]` on shapes).
    pub bary: [f32; 3],
}

/// The extent (largest coordinate magnitude) a BVH's space is scaled to: 2³⁰.
const BVH_EXTENT_LOG2: i32 = 30;

/// The largest scaled ray origin traversed (see [`BvhSpace::ray`]): 2¹⁰⁰.
const MAX_SCALED_ORIGIN: f32 = 1.267_650_6e30;

/// A BVH built in a space scaled by a power of two (see the module documentation): points
/// and distances go in multiplied by `scale`, and distances come out divided by it, both
/// exactly (a power of two changes only the exponent).
pub(crate) struct BvhSpace {
    bvh: WideBvh,
    /// The primitive (box) index of each leaf primitive, in leaf order; emptied when the
    /// leaves are renumbered to the primitives' own order (a BLAS's groups).
    primitive_indices: Vec<u32>,
    scale: f32,
    /// The most boxes one PLOC build was given (see [`PLOC_BATCH`]).
    largest_batch: usize,
}

impl BvhSpace {
    /// The scale for boxes whose largest coordinate magnitude is `extent`: `2^(30 − e)`
    /// with `e` the binary exponent of `extent`, kept within f32's normal exponents.
    fn scale_for(extent: f32) -> f32 {
        pow2(BVH_EXTENT_LOG2 - exponent(extent))
    }

    /// Builds the BVH over `boxes` (unscaled; each is scaled here).
    fn build(mut boxes: Vec<Padded>) -> Option<BvhSpace> {
        let extent = boxes.iter().map(|b| b.0.min.abs().max(b.0.max.abs()).max_element()).fold(0.0, f32::max);
        let scale = BvhSpace::scale_for(extent);
        for b in &mut boxes {
            b.0 = Aabb::new(b.0.min * scale, b.0.max * scale);
        }
        if boxes.is_empty() {
            return None;
        }
        let params = BvhBuildParams::medium_build();
        let (cw, largest_batch) = if boxes.len() <= PLOC_BATCH {
            (build_cwbvh(&boxes, params, &mut Duration::default()), boxes.len())
        } else {
            let (mut bvh2, largest) = build_batched(&boxes);
            // The boxes are in the nodes now: freed before the optimiser and the conversion
            // allocate theirs (build peak memory).
            drop(boxes);
            ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
            (convert::bvh2_to_cwbvh(&bvh2, params.max_prims_per_leaf), largest)
        };
        let bvh = WideBvh::from_cwbvh(&cw);
        Some(BvhSpace { bvh, primitive_indices: cw.primitive_indices, scale, largest_batch })
    }

    /// The ray `o + t d`, `t` in `(tmin, tmax)`, in the scaled space, with the scaled `tmax`
    /// and the factor `k` that takes `t` to the scaled ray's parameter. The direction is
    /// brought to a length near 1 by a power of two too (object-space directions, under an
    /// instance's inverse scale, can be far from unit length). `None` (no hit) when the scaled
    /// origin lies beyond 2¹⁰⁰, where scaled hit distances could overflow f32: an origin 2⁷⁰
    /// times farther out than the BVH's extent, where all of its geometry is below f32's
    /// resolution at the origin.
    #[inline]
    fn ray(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<(WideRay, f32, f32)> {
        let so = o * self.scale;
        let e = exponent(d.abs().max_element());
        let k = self.scale * pow2(e);
        if !so.is_finite() || so.abs().max_element() >= MAX_SCALED_ORIGIN || !k.is_normal() {
            return None;
        }
        // Negative zeros become +0.0 (-0 + 0 = +0): the node test then enters every box
        // through its min face on that axis, as for any other zero.
        let sd = d * pow2(-e) + Vec3::ZERO;
        Some((WideRay::new(so, sd, tmin * k), tmax * k, k))
    }
}

/// The binary exponent of `x` (`x` in `[2^e, 2^(e+1))`), −126 for zero and subnormals.
#[inline]
fn exponent(x: f32) -> i32 {
    if x.is_normal() { ((x.to_bits() >> 23) & 0xff) as i32 - 127 } else { -126 }
}

/// `2^k`, `k` clamped to f32's normal exponents (exact).
#[inline]
fn pow2(k: i32) -> f32 {
    f32::from_bits(((k.clamp(-126, 127) + 127) as u32) << 23)
}

/// A scaled ray parameter back in the caller's units, never beyond `tmax` (a finite `tmax`
/// can overflow when scaled). `k_inv` is `1 / k` (`k` from [`BvhSpace::ray`]): `k` is a
/// normal power of two, so its reciprocal is exact (a subnormal at worst) and the product
/// rounds exactly as `t / k` would, without a division per leaf.
#[inline]
fn unscale(t: f32, k_inv: f32, tmax: f32) -> f32 {
    (t * k_inv).min(tmax)
}

impl BvhSpace {
    /// Bytes held by the nodes and primitive indices.
    fn bytes(&self) -> usize {
        self.bvh.bytes() + self.primitive_indices.len() * 4
    }
}

/// The most primitives a BLAS tests one by one instead of building a BVH over them: a ray
/// then meets them with no box test, traversal state or stack, so a scene of one triangle or
/// one sphere pays for its primitives only.
pub const FLAT_PRIMITIVES: usize = 8;

/// One bottom-level acceleration structure: a BVH over object-space triangles and shapes, or,
/// for at most [`FLAT_PRIMITIVES`], a list of them.
pub struct Blas {
    /// `None` when the BLAS is flat: every primitive in `group_members` is tested.
    bvh: Option<BvhSpace>,
    /// Triangle positions, the only triangle data the intersection loop reads, in the slots
    /// of `group_members` (the BVH's leaf order) and tested 8 at a time (`leaves.rs`).
    triangles: LeafTriangles,
    /// What a hit reads besides the positions.
    attrs: AttrTable,
    shapes: Vec<Shape>,
    /// The BVH's primitives are groups of primitives with bit-identical bounding boxes,
    /// stored here member by member in the BVH's leaf order (primitive indices as in
    /// [`Hit::index`]): each BVH leaf is a range of this table, its groups' members, which
    /// starts at a block boundary of `triangles` when it fits in one block and would
    /// straddle two (the slots between hold `leaves::NO_PRIMITIVE`). A flat BLAS holds its
    /// finite primitives.
    group_members: Vec<u32>,
    /// Object-space bounds `(min, max)` of the finite primitives; `None` when there are none.
    bounds: Option<(Vec3, Vec3)>,
    /// A deforming mesh's triangles keyed over the shutter (`triangles` then hold them at the
    /// frame, and the boxes cover every key).
    deformation: Option<Box<Deformation>>,
}

impl Blas {
    /// Builds a BVH over `triangles` and `shapes` (none needed when there are none).
    /// Primitives with non-finite bounds are kept (indices stay valid) but can never be hit;
    /// the geometry stage reports them before this.
    pub fn new(triangles: impl Into<Triangles>, shapes: Vec<Shape>) -> Blas {
        Blas::deforming(triangles, shapes, None)
    }

    /// [`Blas::new`] whose triangles move by `deformation` (one position per triangle and key,
    /// see [`crate::render::geometry::motion`]) when it is given.
    pub fn deforming(triangles: impl Into<Triangles>, shapes: Vec<Shape>, deformation: Option<Deformation>) -> Blas {
        // Emission stored the triangles as what the traversal reads and what a hit reads.
        let (positions, attrs) = triangles.into().into_parts();
        let tri_bounds = |(i, p): (usize, &[Vec3; 3])| match &deformation {
            Some(d) => d.bounds(i),
            None => (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2])),
        };
        let shape_bounds = |(j, s): (usize, &Shape)| match &deformation {
            Some(d) => d.shape_bounds(j, s.world_bounds()),
            None => s.world_bounds(),
        };
        let mut bounds: Option<(Vec3, Vec3)> = None;
        for (lo, hi) in positions.iter().enumerate().map(tri_bounds).chain(shapes.iter().enumerate().map(shape_bounds))
        {
            if lo.is_finite() && hi.is_finite() {
                bounds = Some(bounds.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
            }
        }
        let count = positions.len() + shapes.len();
        let all_bounds =
            positions.iter().enumerate().map(tri_bounds).chain(shapes.iter().enumerate().map(shape_bounds));
        let (bvh, group_members) = if count <= FLAT_PRIMITIVES {
            // Primitives with non-finite bounds are left out, as the BVH leaves them out.
            let finite: Vec<u32> = all_bounds
                .enumerate()
                .filter(|(_, (lo, hi))| lo.is_finite() && hi.is_finite())
                .map(|(i, _)| i as u32)
                .collect();
            (None, finite)
        } else {
            build_grouped(all_bounds, count)
        };
        let deformation = deformation.map(Box::new);
        // The positions move into leaf order; the emission-order table is freed.
        let triangles = LeafTriangles::new(&positions, &group_members);
        drop(positions);
        Blas { bvh, triangles, attrs, shapes, group_members, bounds, deformation }
    }

    /// The most primitives one PLOC build was given while building this BVH: at most
    /// [`PLOC_BATCH`] (128) whatever the geometry, which bounds the build's work.
    pub fn largest_build_batch(&self) -> usize {
        self.bvh.as_ref().map_or(0, |b| b.largest_batch)
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Number of analytic shape parts.
    pub fn shape_count(&self) -> usize {
        self.shapes.len()
    }

    /// Triangle `i`'s vertex positions, as intersected (NaN for a triangle with a non-finite
    /// corner, which is never intersected); `None` past the last triangle.
    #[inline]
    pub fn triangle(&self, i: usize) -> Option<[Vec3; 3]> {
        self.triangles.triangle(i)
    }

    /// Object-space bounds of the finite primitives.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }

    /// Bytes held: triangles, shapes, BVH nodes and indices, groups.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        let bvh = self.bvh.as_ref().map_or(0, BvhSpace::bytes);
        self.triangles.bytes()
            + self.attrs.bytes()
            + self.shapes.len() * size_of::<Shape>()
            + self.group_members.len() * 4
            + bvh
    }

    /// The prim of primitive `index` (BLAS-local numbering in a prototype).
    fn prim_of(&self, index: u32) -> u32 {
        let i = index as usize;
        match self.attrs.prim(i) {
            Some(prim) => prim,
            None => self.shapes[i - self.attrs.len()].prim,
        }
    }

    /// `(t, b1, b2)` of the ray against the primitive in leaf slot `k` (an index into
    /// `group_members`).
    /// `DEFORMS`: the triangles are taken at ray time `time` from [`Blas::deformation`]
    /// (a constant, so a still BLAS's loop is the one it always was).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn hit_slot<const KZ: usize, const DEFORMS: bool>(
        &self,
        pre: &RayPre<KZ>,
        o: Vec3,
        d: Vec3,
        k: usize,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, f32, f32)> {
        let i = self.group_members[k] as usize;
        if i < self.triangles.len() {
            match (DEFORMS, &self.deformation) {
                (true, Some(keys)) => pre.intersect(&keys.at(i, time), tmin, tmax),
                _ => pre.intersect(&self.triangles.at_slot(k), tmin, tmax),
            }
        } else {
            let j = i - self.triangles.len();
            // A deforming prototype's shapes (a Points prim's spheres) move by a translation.
            let o = match (DEFORMS, &self.deformation) {
                (true, Some(keys)) => o - keys.shape_offset(j, time),
                _ => o,
            };
            self.shapes[j].intersect(o, d, tmin, tmax).map(|t| (t, 0.0, 0.0))
        }
    }

    /// Whether the BLAS holds no primitive that a ray can hit.
    fn is_empty(&self) -> bool {
        self.group_members.is_empty()
    }

    /// The closest hit `(t, index, b1, b2)` of `o + t d`, `t` in `(tmin, tmax)`; `d` need
    /// not be unit length (object-space rays are not), and `t` is in its units.
    #[inline]
    fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<(f32, u32, f32, f32)> {
        self.intersect_when::<false>(o, d, tmin, tmax, 0.0)
    }

    /// [`Blas::intersect`] at ray time `time` (matters only when the BLAS deforms).
    #[inline]
    fn intersect_at(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> Option<(f32, u32, f32, f32)> {
        if self.deformation.is_some() {
            self.intersect_when::<true>(o, d, tmin, tmax, time)
        } else {
            self.intersect_when::<false>(o, d, tmin, tmax, time)
        }
    }

    /// [`Blas::intersect_at`] with the deformation known as a constant, compiled for AVX2
    /// where the CPU has it: the whole traversal then is, so its node and leaf tests inline.
    #[inline(always)]
    fn intersect_when<const DEFORMS: bool>(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, u32, f32, f32)> {
        #[cfg(target_arch = "x86_64")]
        if wide::has_avx2() {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe { self.intersect_avx2::<DEFORMS>(o, d, tmin, tmax, time) };
        }
        out_of_line(move || self.intersect_axis::<DEFORMS, false>(o, d, tmin, tmax, time))
    }

    /// [`Blas::intersect_axis`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn intersect_avx2<const DEFORMS: bool>(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, u32, f32, f32)> {
        self.intersect_axis::<DEFORMS, true>(o, d, tmin, tmax, time)
    }

    /// [`Blas::intersect_when`] on the AVX2 path or not (`AVX2` true only where the CPU has it).
    #[inline(always)]
    fn intersect_axis<const DEFORMS: bool, const AVX2: bool>(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, u32, f32, f32)> {
        // One branch per ray on the direction's largest axis, not one per triangle test.
        match dominant_axis(d) {
            0 => self.intersect_along::<0, DEFORMS, AVX2>(o, d, tmin, tmax, time),
            1 => self.intersect_along::<1, DEFORMS, AVX2>(o, d, tmin, tmax, time),
            _ => self.intersect_along::<2, DEFORMS, AVX2>(o, d, tmin, tmax, time),
        }
    }

    /// [`Blas::intersect_when`] for a ray whose largest direction component is axis `KZ`.
    #[inline(always)]
    fn intersect_along<const KZ: usize, const DEFORMS: bool, const AVX2: bool>(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, u32, f32, f32)> {
        let pre = RayPre::<KZ>::new(o, d);
        let Some(space) = self.bvh.as_ref() else {
            return self.intersect_flat::<KZ, DEFORMS, AVX2>(&pre, o, d, tmin, tmax, time);
        };
        let (ray, scaled_tmax, k) = space.ray(o, d, tmin, tmax)?;
        let ray_in_leaves = LeafRay::<KZ, DEFORMS, AVX2> { blas: self, pre, o, d, tmin, tmax, time };
        let mut leaves = ClosestInLeaves { ray: ray_in_leaves, k, k_inv: 1.0 / k, best: None };
        wide::closest_in::<AVX2>(&space.bvh, &ray, scaled_tmax, &mut leaves);
        leaves.best
    }

    /// The closest hit `(t, index, b1, b2)` among the primitives in slots `first..first +
    /// count` of `group_members` (a leaf), `t` in `(tmin, tmax)`: a still BLAS's triangles 8
    /// at a time, then its shapes one by one.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn leaf_closest<const KZ: usize, const DEFORMS: bool, const AVX2: bool>(
        &self,
        pre: &RayPre<KZ>,
        o: Vec3,
        d: Vec3,
        first: u32,
        count: u32,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, u32, f32, f32)> {
        let slots = first as usize..(first + count) as usize;
        let mut best = None;
        let mut closest = tmax;
        if DEFORMS && self.deformation.is_some() {
            for k in slots {
                if let Some((t, b1, b2)) = self.hit_slot::<KZ, DEFORMS>(pre, o, d, k, tmin, closest, time) {
                    best = Some((t, self.group_members[k], b1, b2));
                    closest = t;
                }
            }
            return best;
        }
        if let Some((slot, t, b1, b2)) = self.triangles.closest::<KZ, AVX2>(pre, first, count, tmin, tmax) {
            best = Some((t, self.group_members[slot as usize], b1, b2));
            closest = t;
        }
        if !self.shapes.is_empty() {
            for k in slots.filter(|&k| self.group_members[k] as usize >= self.triangles.len()) {
                if let Some((t, b1, b2)) = self.hit_slot::<KZ, DEFORMS>(pre, o, d, k, tmin, closest, time) {
                    best = Some((t, self.group_members[k], b1, b2));
                    closest = t;
                }
            }
        }
        best
    }

    /// Whether any primitive in slots `first..first + count` is hit within `(tmin, tmax)`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn leaf_any<const KZ: usize, const DEFORMS: bool, const AVX2: bool>(
        &self,
        pre: &RayPre<KZ>,
        o: Vec3,
        d: Vec3,
        first: u32,
        count: u32,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> bool {
        let mut slots = first as usize..(first + count) as usize;
        if DEFORMS && self.deformation.is_some() {
            return slots.any(|k| self.hit_slot::<KZ, DEFORMS>(pre, o, d, k, tmin, tmax, time).is_some());
        }
        if self.triangles.any::<KZ, AVX2>(pre, first, count, tmin, tmax) {
            return true;
        }
        if self.shapes.is_empty() {
            return false;
        }
        // A loop, not `Iterator::any`: the closure was a call per leaf, compiled without
        // AVX2 (as `LeafTriangles::any` says), around every shape's cull.
        for k in slots {
            if self.group_members[k] as usize >= self.triangles.len()
                && self.hit_slot::<KZ, DEFORMS>(pre, o, d, k, tmin, tmax, time).is_some()
            {
                return true;
            }
        }
        false
    }

    /// [`Blas::intersect`] without a BVH: every primitive tested.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn intersect_flat<const KZ: usize, const DEFORMS: bool, const AVX2: bool>(
        &self,
        pre: &RayPre<KZ>,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> Option<(f32, u32, f32, f32)> {
        self.leaf_closest::<KZ, DEFORMS, AVX2>(pre, o, d, 0, self.group_members.len() as u32, tmin, tmax, time)
    }

    /// Whether anything lies on `o + t d` within `(tmin, tmax)`.
    #[inline]
    fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        self.occluded_when::<false>(o, d, tmin, tmax, 0.0)
    }

    /// [`Blas::occluded`] at ray time `time` (matters only when the BLAS deforms).
    #[inline]
    fn occluded_at(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> bool {
        if self.deformation.is_some() {
            self.occluded_when::<true>(o, d, tmin, tmax, time)
        } else {
            self.occluded_when::<false>(o, d, tmin, tmax, time)
        }
    }

    /// [`Blas::occluded_at`] with the deformation known as a constant, compiled for AVX2 where
    /// the CPU has it (as [`Blas::intersect_when`]).
    #[inline(always)]
    fn occluded_when<const DEFORMS: bool>(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> bool {
        #[cfg(target_arch = "x86_64")]
        if wide::has_avx2() {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe { self.occluded_avx2::<DEFORMS>(o, d, tmin, tmax, time) };
        }
        out_of_line(move || self.occluded_axis::<DEFORMS, false>(o, d, tmin, tmax, time))
    }

    /// [`Blas::occluded_axis`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn occluded_avx2<const DEFORMS: bool>(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> bool {
        self.occluded_axis::<DEFORMS, true>(o, d, tmin, tmax, time)
    }

    /// [`Blas::occluded_when`] on the AVX2 path or not (`AVX2` true only where the CPU has it).
    #[inline(always)]
    fn occluded_axis<const DEFORMS: bool, const AVX2: bool>(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> bool {
        match dominant_axis(d) {
            0 => self.occluded_along::<0, DEFORMS, AVX2>(o, d, tmin, tmax, time),
            1 => self.occluded_along::<1, DEFORMS, AVX2>(o, d, tmin, tmax, time),
            _ => self.occluded_along::<2, DEFORMS, AVX2>(o, d, tmin, tmax, time),
        }
    }

    /// [`Blas::occluded_when`] for a ray whose largest direction component is axis `KZ`.
    #[inline(always)]
    fn occluded_along<const KZ: usize, const DEFORMS: bool, const AVX2: bool>(
        &self,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
    ) -> bool {
        let pre = RayPre::<KZ>::new(o, d);
        let Some(space) = self.bvh.as_ref() else {
            let all = self.group_members.len() as u32;
            return self.leaf_any::<KZ, DEFORMS, AVX2>(&pre, o, d, 0, all, tmin, tmax, time);
        };
        let Some((ray, scaled_tmax, _)) = space.ray(o, d, tmin, tmax) else { return false };
        let mut leaves = LeafRay::<KZ, DEFORMS, AVX2> { blas: self, pre, o, d, tmin, tmax, time };
        wide::any_in::<AVX2>(&space.bvh, &ray, scaled_tmax, &mut leaves)
    }

    /// Surface geometry in this BLAS's space where `o + t d` hit primitive `index`, with the
    /// triangle's vertices (for callers that move them to another space).
    #[allow(clippy::too_many_arguments)]
    fn surface(
        &self,
        o: Vec3,
        d: Vec3,
        t: f32,
        index: u32,
        b1: f32,
        b2: f32,
        time: f32,
    ) -> (SurfaceGeom, Option<[Vec3; 3]>) {
        let i = index as usize;
        let deformed = |p: [Vec3; 3]| self.deformation.as_ref().map_or(p, |keys| keys.at(i, time));
        match self.triangles.triangle(i).map(deformed) {
            Some(p) => {
                let a = self.attrs.get(i);
                let b0 = 1.0 - b1 - b2;
                let pos = p[0] * b0 + p[1] * b1 + p[2] * b2;
                let err = (p[0] * b0).abs() + (p[1] * b1).abs() + (p[2] * b2).abs();
                let ng = winding_normal(p);
                // A flat triangle's shading normal is its winding normal: nothing to
                // interpolate and renormalise.
                let ns = match a.n {
                    Some(n) => shading_normal(n[0] * b0 + n[1] * b1 + n[2] * b2, ng),
                    None => ng,
                };
                let (uv, (dpdu, dpdv)) = match a.uv {
                    Some(uv) => (uv[0] * b0 + uv[1] * b1 + uv[2] * b2, tangents(p, uv, ns)),
                    // The parametric coordinates (0,0), (1,0), (0,1): uv is (b1, b2) and the
                    // edges from corner 0 are ∂P/∂u and ∂P/∂v, as `tangents` finds them.
                    None => (Vec2::new(b1, b2), edge_tangents(p, ns)),
                };
                let geom = SurfaceGeom {
                    p: pos,
                    p_error: err * gamma(7),
                    ng,
                    ns,
                    dpdu,
                    dpdv,
                    uv,
                    prim: a.prim,
                    primvars: a.primvars,
                    bary: [b0, b1, b2],
                };
                (geom, Some(p))
            }
            None => {
                let j = i - self.triangles.len();
                let shape = &self.shapes[j];
                let h = match &self.deformation {
                    Some(keys) => {
                        // Hit where the shape is at `time`: found moved back, then moved there.
                        let offset = keys.shape_offset(j, time);
                        let mut h = shape.surface(o - offset, d, t);
                        h.p += offset;
                        h.p_error += (h.p.abs() + offset.abs()) * f32::EPSILON;
                        h
                    }
                    None => shape.surface(o, d, t),
                };
                let n = if h.n == Vec3::ZERO || !h.n.is_finite() { -d.normalize_or_zero() } else { h.n };
                let (dpdu, dpdv) = frame_or(h.dpdu, h.dpdv, n);
                let geom = SurfaceGeom {
                    p: h.p,
                    p_error: h.p_error,
                    ng: n,
                    ns: n,
                    dpdu,
                    dpdv,
                    uv: h.uv,
                    prim: shape.prim,
                    primvars: shape.primvars,
                    bary: [1.0, 0.0, 0.0],
                };
                (geom, None)
            }
        }
    }
}

/// A ray in a BLAS's leaf tests: `o + t d` (prepared as `pre`), `t` in `(tmin, tmax)` in the
/// BLAS's units, at time `time`. As the occlusion traversal's leaf test it is a struct, not a
/// closure, so that its test inlines into the traversal compiled for AVX2 (see
/// [`wide::ClosestLeaf`]).
struct LeafRay<'a, const KZ: usize, const DEFORMS: bool, const AVX2: bool> {
    blas: &'a Blas,
    pre: RayPre<KZ>,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
    time: f32,
}

impl<const KZ: usize, const DEFORMS: bool, const AVX2: bool> wide::AnyLeaf for LeafRay<'_, KZ, DEFORMS, AVX2> {
    #[inline(always)]
    fn test(&mut self, first: u32, count: u32) -> bool {
        let (o, d, time) = (self.o, self.d, self.time);
        self.blas.leaf_any::<KZ, DEFORMS, AVX2>(&self.pre, o, d, first, count, self.tmin, self.tmax, time)
    }
}

/// A BLAS traversal's closest-hit leaf test (as [`LeafRay`]): the ray, `k` (its parameter in
/// the BVH's scaled space per unit of `t`), `1 / k`, and the closest hit found so far.
struct ClosestInLeaves<'a, const KZ: usize, const DEFORMS: bool, const AVX2: bool> {
    ray: LeafRay<'a, KZ, DEFORMS, AVX2>,
    k: f32,
    k_inv: f32,
    best: Option<(f32, u32, f32, f32)>,
}

impl<const KZ: usize, const DEFORMS: bool, const AVX2: bool> wide::ClosestLeaf
    for ClosestInLeaves<'_, KZ, DEFORMS, AVX2>
{
    #[inline(always)]
    fn test(&mut self, limit: f32, first: u32, count: u32) -> f32 {
        let r = &self.ray;
        let closest = unscale(limit, self.k_inv, r.tmax);
        match r.blas.leaf_closest::<KZ, DEFORMS, AVX2>(&r.pre, r.o, r.d, first, count, r.tmin, closest, r.time) {
            Some(hit) => {
                self.best = Some(hit);
                hit.0 * self.k
            }
            None => f32::INFINITY,
        }
    }
}

/// `query()`, in a function of its own: a BLAS's query without AVX2, which inlined into
/// `Accel::intersect_at`/`occluded_at` put its 3 KiB traversal stack and spills in their frame,
/// set up on every ray, AVX2 or not. Give it a `move` closure: one capturing by reference made
/// the AVX2 path store the arguments for it (13 instructions a ray, callgrind).
#[inline(never)]
fn out_of_line<R>(query: impl FnOnce() -> R) -> R {
    query()
}

/// Whether a ray from `o` along `d` can be traced: all six finite, `d` not zero. `0·x` is
/// ±0 for a finite `x` and NaN for ±∞ and NaN, so one sum says whether all six are finite:
/// a few arithmetic instructions per ray instead of a compare and branch per component.
#[inline(always)]
fn traceable(o: Vec3, d: Vec3) -> bool {
    let z = o * 0.0 + d * 0.0;
    z.x + z.y + z.z == 0.0 && d != Vec3::ZERO
}

/// An instance as the traversal uses it.
#[derive(Clone, Copy, Debug)]
struct Instance {
    /// World → object, in f64: the object-space ray is rounded to f32 once.
    to_object: DAffine3,
    to_world: DAffine3,
    /// Whether the transform mirrors (negative determinant): winding normals flip.
    mirrors: bool,
    prototype: u32,
    prims: u32,
    /// Index of its keyed transform in [`Accel::motions`], or [`STILL`]: `to_object` and
    /// `to_world` are then the transform at every time.
    motion: u32,
}

/// [`Instance::motion`] of an instance that does not move.
const STILL: u32 = u32::MAX;

impl Instance {
    /// `(to_object, to_world)` at ray time `time` (an instance that does not move reads its
    /// stored pair; a moving one interpolates its keys and inverts them, per ray).
    #[inline(always)]
    fn transforms_at(&self, motions: &[MotionKeys], time: f32) -> (DAffine3, DAffine3) {
        if self.motion == STILL {
            return (self.to_object, self.to_world);
        }
        let m = motions[self.motion as usize].at(time);
        (m.inverse(), m)
    }
}

/// The acceleration structure: the world's BLAS, the prototypes' BLASes and the instances.
pub struct Accel {
    world: Blas,
    prototypes: Vec<Blas>,
    instances: Vec<Instance>,
    /// Per-instance prim tables (see [`InstanceDesc::prims`]).
    instance_prims: Vec<u32>,
    /// The top-level BVH over the instances' world boxes; `None` without instances.
    tlas: Option<BvhSpace>,
    /// Instances with a singular or non-finite transform, or an empty prototype: skipped.
    pub skipped_instances: usize,
    /// The keyed transforms of moving instances (see [`crate::render::geometry::motion`]).
    motions: Vec<MotionKeys>,
    /// Whether anything moves: an instance by its keys, or a prototype that deforms.
    moves: bool,
}

impl Accel {
    /// A single-level structure over world-space `triangles` and `shapes` (no instances).
    pub fn new(triangles: impl Into<Triangles>, shapes: Vec<Shape>) -> Accel {
        Accel::with_instances(Blas::new(triangles, shapes), Vec::new(), &[], Vec::new())
    }

    /// The world BLAS plus `prototypes` placed by `instances` (prim tables in `instance_prims`).
    pub fn with_instances(
        world: Blas,
        prototypes: Vec<Blas>,
        instances: &[InstanceDesc],
        instance_prims: Vec<u32>,
    ) -> Accel {
        Accel::with_moving_instances(world, prototypes, instances, instance_prims, Vec::new())
    }

    /// [`Accel::with_instances`] where the instances named in `motion` (by index in
    /// `instances`) move by their keys instead of staying at `to_world`: their top-level
    /// boxes cover every key.
    pub fn with_moving_instances(
        world: Blas,
        prototypes: Vec<Blas>,
        instances: &[InstanceDesc],
        instance_prims: Vec<u32>,
        motion: Vec<(u32, MotionKeys)>,
    ) -> Accel {
        let (instances, tlas, skipped_instances, motions) = place_instances(&prototypes, instances, motion);
        let moves = !motions.is_empty() || prototypes.iter().any(|p| p.deformation.is_some());
        Accel { world, prototypes, instances, instance_prims, tlas, skipped_instances, motions, moves }
    }

    /// Replaces prototype `index`'s BLAS (a deforming prim's, built again at another time
    /// code); [`Accel::move_instances`] must follow to place the instances over its new box.
    pub fn replace_prototype(&mut self, index: u32, blas: Blas) {
        self.prototypes[index as usize] = blas;
    }

    /// Places the same prototypes (each instance's `prototype` and `prims` as before) by new
    /// transforms and keys: the top level is built again, every BLAS is kept. The result is
    /// the structure [`Accel::with_moving_instances`] builds from them, bit for bit.
    pub fn move_instances(&mut self, instances: &[InstanceDesc], motion: Vec<(u32, MotionKeys)>) {
        let (placed, tlas, skipped, motions) = place_instances(&self.prototypes, instances, motion);
        self.moves = !motions.is_empty() || self.prototypes.iter().any(|p| p.deformation.is_some());
        (self.instances, self.tlas, self.skipped_instances, self.motions) = (placed, tlas, skipped, motions);
    }
}

/// The traversal's instances of `instances` (the unplaceable skipped and counted), the top
/// level over their boxes, and the keys of those that move.
#[allow(clippy::type_complexity)]
fn place_instances(
    prototypes: &[Blas],
    instances: &[InstanceDesc],
    motion: Vec<(u32, MotionKeys)>,
) -> (Vec<Instance>, Option<BvhSpace>, usize, Vec<MotionKeys>) {
    let mut skipped = 0;
    let mut kept = Vec::with_capacity(instances.len());
    let mut boxes = Vec::with_capacity(instances.len());
    let mut keys_of: HashMap<u32, MotionKeys> = motion.into_iter().collect();
    let mut motions = Vec::with_capacity(keys_of.len());
    for (index, desc) in instances.iter().enumerate() {
        let keys = keys_of.remove(&(index as u32));
        let m = desc.to_world;
        let det = DMat3::from_mat4(m).determinant();
        let moving_ok = keys
            .as_ref()
            .is_none_or(|k| k.transforms().iter().all(|t| t.is_finite() && t.matrix3.determinant() != 0.0));
        let bounds = prototypes.get(desc.prototype as usize).and_then(Blas::bounds);
        let Some((lo, hi)) = bounds.filter(|_| det != 0.0 && det.is_finite() && m.is_finite() && moving_ok) else {
            skipped += 1;
            continue;
        };
        let (wlo, whi) = match &keys {
            Some(k) => k.bounds(lo.as_dvec3(), hi.as_dvec3()),
            None => crate::render::geometry::shapes::transformed_box(&m, lo.as_dvec3(), hi.as_dvec3()),
        };
        let (wlo, whi) = (wlo.as_vec3(), whi.as_vec3());
        if !wlo.is_finite() || !whi.is_finite() {
            skipped += 1;
            continue;
        }
        let to_world = DAffine3::from_mat4(m);
        let motion = match keys {
            Some(k) => {
                motions.push(k);
                motions.len() as u32 - 1
            }
            None => STILL,
        };
        kept.push(Instance {
            to_object: to_world.inverse(),
            to_world,
            mirrors: det < 0.0,
            prototype: desc.prototype,
            prims: desc.prims,
            motion,
        });
        // Padded like every other box (see `padded_box`), and outward for the f32 rounding
        // of the transformed corners.
        let pad = wlo.abs().max(whi.abs()).max_element().max(f32::MIN_POSITIVE) * 1e-6;
        boxes.push(Padded(Aabb::new((wlo - Vec3::splat(pad)).into(), (whi + Vec3::splat(pad)).into())));
    }
    let tlas = BvhSpace::build(boxes);
    (kept, tlas, skipped, motions)
}

impl Accel {
    /// Number of triangles stored (unique geometry: each prototype's once).
    pub fn triangle_count(&self) -> usize {
        self.world.triangle_count() + self.prototypes.iter().map(Blas::triangle_count).sum::<usize>()
    }

    /// Number of bottom-level structures in use: the world's (when not empty) and the prototypes'.
    pub fn blas_count(&self) -> usize {
        usize::from(!self.world.is_empty()) + self.prototypes.len()
    }

    /// Number of instances in the top level.
    pub fn instance_count(&self) -> usize {
        self.instances.len()
    }

    /// Bytes held by the geometry and its BVHs, split as (bottom levels, instance table and top level).
    pub fn bytes(&self) -> (usize, usize) {
        use std::mem::size_of;
        let blas = self.world.bytes() + self.prototypes.iter().map(Blas::bytes).sum::<usize>();
        let tlas = self.tlas.as_ref().map_or(0, BvhSpace::bytes);
        (blas, self.instances.len() * size_of::<Instance>() + self.instance_prims.len() * 4 + tlas)
    }

    /// World (not instanced) triangle `i`'s vertex positions, as intersected (see
    /// [`Blas::triangle`]); `None` past the last.
    #[inline]
    pub fn world_triangle(&self, i: usize) -> Option<[Vec3; 3]> {
        self.world.triangle(i)
    }

    /// Every world triangle's vertex positions, in their own order (a copy: the BLAS keeps
    /// them in its leaf order).
    pub fn world_triangles(&self) -> Vec<[Vec3; 3]> {
        (0..self.world.triangle_count()).filter_map(|i| self.world.triangle(i)).collect()
    }

    /// The renderable prim a hit belongs to.
    pub fn prim_of(&self, hit: &Hit) -> u32 {
        if hit.instance == WORLD {
            return self.world.prim_of(hit.index);
        }
        let inst = &self.instances[hit.instance as usize];
        let local = self.prototypes[inst.prototype as usize].prim_of(hit.index);
        self.instance_prims[(inst.prims + local) as usize]
    }

    /// The transforms `(to_object, to_world)` of the instance a hit at ray time `time` is in
    /// (as [`Accel::surface_at`] places it); `None` for a hit on the world's own geometry.
    pub fn instance_transforms(&self, hit: &Hit, time: f32) -> Option<(DAffine3, DAffine3)> {
        let inst = self.instances.get(hit.instance as usize)?;
        Some(inst.transforms_at(&self.motions, time))
    }

    /// Whether anything moves: an instance, or a prototype that deforms (rays then need a time).
    pub fn has_motion(&self) -> bool {
        self.moves
    }

    /// Number of instances that move.
    pub fn moving_instance_count(&self) -> usize {
        self.motions.len()
    }

    /// The closest hit of the ray `o + t d`, `t` in `(tmin, tmax)`. `d` must be unit length.
    /// Moving instances are where they are at the shutter's opening (see [`Accel::intersect_at`]).
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        self.intersect_at(o, d, tmin, tmax, 0.0)
    }

    /// [`Accel::intersect`] at ray time `time` (`[0, 1)` across the shutter; see
    /// [`crate::render::geometry::motion`]).
    pub fn intersect_at(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> Option<Hit> {
        if !traceable(o, d) {
            return None;
        }
        let best =
            self.world.intersect(o, d, tmin, tmax).map(|(t, index, b1, b2)| Hit { t, index, instance: WORLD, b1, b2 });
        match &self.tlas {
            None => best,
            Some(space) => self.intersect_instances(space, o, d, tmin, tmax, time, best),
        }
    }

    /// The instances' part of [`Accel::intersect_at`]: the closest hit among the instances
    /// and `best` (the world BLAS's). Out of line, so that a scene without instances does not
    /// set up the instance traversal's stack frame for every ray.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn intersect_instances(
        &self,
        space: &BvhSpace,
        o: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        time: f32,
        mut best: Option<Hit>,
    ) -> Option<Hit> {
        let tmax = best.map_or(tmax, |h| h.t);
        let Some((ray, scaled_tmax, k)) = space.ray(o, d, tmin, tmax) else { return best };
        let k_inv = 1.0 / k;
        let (od, dd) = (o.as_dvec3(), d.as_dvec3());
        wide::closest(&space.bvh, &ray, scaled_tmax, |limit, first, count| {
            let mut limit = limit;
            let mut found = false;
            for &i in &space.primitive_indices[first as usize..(first + count) as usize] {
                let inst = &self.instances[i as usize];
                let (to_object, _) = inst.transforms_at(&self.motions, time);
                let oo = to_object.transform_point3(od).as_vec3();
                let ob = to_object.transform_vector3(dd).as_vec3();
                // A nearly singular instance can overflow f32 in object space: no hit there.
                if !traceable(oo, ob) {
                    continue;
                }
                let prototype = &self.prototypes[inst.prototype as usize];
                if let Some((t, index, b1, b2)) =
                    prototype.intersect_at(oo, ob, tmin, unscale(limit, k_inv, tmax), time)
                {
                    best = Some(Hit { t, index, instance: i, b1, b2 });
                    limit = t * k;
                    found = true;
                }
            }
            if found { limit } else { f32::INFINITY }
        });
        best
    }

    /// Whether anything lies on the ray within `(tmin, tmax)` (shadow rays: stops at the first hit).
    pub fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        self.occluded_at(o, d, tmin, tmax, 0.0)
    }

    /// [`Accel::occluded`] at ray time `time`.
    pub fn occluded_at(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> bool {
        if !traceable(o, d) {
            return false;
        }
        if self.world.occluded(o, d, tmin, tmax) {
            return true;
        }
        match &self.tlas {
            None => false,
            Some(space) => self.occluded_instances(space, o, d, tmin, tmax, time),
        }
    }

    /// The instances' part of [`Accel::occluded_at`], out of line as
    /// [`Accel::intersect_instances`] is.
    #[inline(never)]
    fn occluded_instances(&self, space: &BvhSpace, o: Vec3, d: Vec3, tmin: f32, tmax: f32, time: f32) -> bool {
        let Some((ray, scaled_tmax, _)) = space.ray(o, d, tmin, tmax) else { return false };
        let (od, dd) = (o.as_dvec3(), d.as_dvec3());
        wide::any(&space.bvh, &ray, scaled_tmax, |first, count| {
            space.primitive_indices[first as usize..(first + count) as usize].iter().any(|&i| {
                let inst = &self.instances[i as usize];
                let (to_object, _) = inst.transforms_at(&self.motions, time);
                let oo = to_object.transform_point3(od).as_vec3();
                let ob = to_object.transform_vector3(dd).as_vec3();
                traceable(oo, ob) && self.prototypes[inst.prototype as usize].occluded_at(oo, ob, tmin, tmax, time)
            })
        })
    }

    /// World-space surface geometry where the ray `o + t d` made `hit`.
    pub fn surface(&self, o: Vec3, d: Vec3, hit: &Hit) -> SurfaceGeom {
        self.surface_at(o, d, hit, 0.0)
    }

    /// [`Accel::surface`] for a hit of a ray at time `time` (as given to [`Accel::intersect_at`]).
    pub fn surface_at(&self, o: Vec3, d: Vec3, hit: &Hit, time: f32) -> SurfaceGeom {
        if hit.instance == WORLD {
            return self.world.surface(o, d, hit.t, hit.index, hit.b1, hit.b2, time).0;
        }
        let inst = &self.instances[hit.instance as usize];
        let (to_object, to_world) = inst.transforms_at(&self.motions, time);
        let oo = to_object.transform_point3(o.as_dvec3()).as_vec3();
        let ob = to_object.transform_vector3(d.as_dvec3()).as_vec3();
        let blas = &self.prototypes[inst.prototype as usize];
        let (local, vertices) = blas.surface(oo, ob, hit.t, hit.index, hit.b1, hit.b2, time);
        let m = &to_world;
        let mirrors = if inst.motion == STILL { inst.mirrors } else { to_world.matrix3.determinant() < 0.0 };
        let point = |p: Vec3| m.transform_point3(p.as_dvec3()).as_vec3();
        let vector = |v: Vec3| m.transform_vector3(v.as_dvec3()).as_vec3();
        // Normals transform by the inverse transpose.
        let normal_matrix = to_object.matrix3.transpose();
        let normal = |n: Vec3| (normal_matrix * n.as_dvec3()).as_vec3().normalize_or_zero();
        let p = point(local.p);
        // The object-space error carried to world space (|M| p_error), plus the rounding of
        // the object-space point and of its world image to f32: the next ray's origin is
        // rounded to f32 again when it is moved into object space.
        let abs_m = DMat3::from_cols(m.matrix3.x_axis.abs(), m.matrix3.y_axis.abs(), m.matrix3.z_axis.abs());
        let local_err = local.p_error.as_dvec3() + local.p.abs().as_dvec3() * gamma(2) as f64;
        let p_error = (abs_m * local_err).as_vec3() + p.abs() * gamma(2);
        let mut geom = match vertices {
            Some(v) => {
                // The winding normal of the world-space vertices, as a flattened copy has it.
                let w = v.map(point);
                let ng = winding_normal(w);
                let ng = if ng == Vec3::ZERO || !ng.is_finite() {
                    let n = normal(local.ng);
                    if mirrors { -n } else { n }
                } else {
                    ng
                };
                let a = blas.attrs.get(hit.index as usize);
                let b0 = 1.0 - hit.b1 - hit.b2;
                let ns = match a.n {
                    Some(n) => shading_normal(normal(n[0] * b0 + n[1] * hit.b1 + n[2] * hit.b2), ng),
                    None => ng,
                };
                let (dpdu, dpdv) = match a.uv {
                    Some(uv) => tangents(w, uv, ns),
                    None => edge_tangents(w, ns),
                };
                SurfaceGeom { p, p_error, ng, ns, dpdu, dpdv, ..local }
            }
            None => {
                let n = normal(local.ng);
                let n = if n == Vec3::ZERO || !n.is_finite() { -d } else { n };
                let (dpdu, dpdv) = frame_or(vector(local.dpdu), vector(local.dpdv), n);
                SurfaceGeom { p, p_error, ng: n, ns: n, dpdu, dpdv, ..local }
            }
        };
        geom.prim = self.instance_prims[(inst.prims + local.prim) as usize];
        geom
    }
}

#[cfg(test)]
mod tests;
