//! Traversal of obvhs' compressed wide BVH (8 children per node, child boxes quantised to
//! 8 bits against the node's box, children visited nearest-octant first) with the node test
//! run on the machine's vector units: on CPUs with AVX2 (detected at run time, so the binary
//! still runs on baseline x86-64) all 8 child boxes are tested in one 8-lane pass, their
//! 8-bit coordinates widened with one instruction per axis bound; elsewhere obvhs' own SSE
//! test (two 4-lane passes over coordinates converted one by one) runs.
//!
//! Both tests do the same f32 operations in the same order (a multiply, then an add: no
//! fused multiply-add), so they accept exactly the same boxes and a render is bit-identical
//! on either path.

use glam::{UVec2, Vec3A, uvec2};
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::faststack::FastStack;
use obvhs::ray::Ray;
use std::mem::MaybeUninit;

/// Whether the AVX2 path runs (std caches the CPUID query: one load per call).
#[inline]
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Visits the primitives whose leaf boxes `ray` meets, nearest first as far as the octant
/// order knows; `on_primitive(ray, id)` returns the hit distance in the ray's parameter, or
/// anything not below `ray.tmax` for no hit, and the ray is shortened to each hit.
#[inline]
pub(super) fn closest(bvh: &CwBvh, ray: Ray, mut on_primitive: impl FnMut(&Ray, usize) -> f32) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { avx2::closest(bvh, ray, &mut on_primitive) };
        return;
    }
    closest_with(bvh, ray, &mut on_primitive, |node, ray, oct| node.intersect_ray(ray, oct));
}

/// Whether `on_primitive(ray, id)` holds for any primitive whose leaf box `ray` meets; stops
/// at the first that does.
#[inline]
pub(super) fn any(bvh: &CwBvh, ray: Ray, mut on_primitive: impl FnMut(&Ray, usize) -> bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { avx2::any(bvh, ray, &mut on_primitive) };
    }
    any_with(bvh, ray, &mut on_primitive, |node, ray, oct| node.intersect_ray(ray, oct))
}

/// obvhs' traversal depth bound (`TRAVERSAL_STACK_SIZE`, crate-private there; its builders
/// keep compressed-wide BVHs shallower).
const STACK_SIZE: usize = 32;

/// The node groups still to visit. obvhs' own stack is an array it zeroes for every ray
/// (256 bytes, a memset per traversal that the profile showed); this one starts
/// uninitialised and reads only what it wrote.
struct Stack {
    slots: [MaybeUninit<UVec2>; STACK_SIZE],
    len: usize,
}

impl Stack {
    #[inline(always)]
    fn new() -> Stack {
        Stack { slots: [MaybeUninit::uninit(); STACK_SIZE], len: 0 }
    }
}

impl FastStack<UVec2> for Stack {
    /// Pushes `v`; when full, overwrites the top as obvhs' stack does (a depth its builders
    /// never produce).
    #[inline(always)]
    fn push(&mut self, v: UVec2) {
        self.slots[self.len] = MaybeUninit::new(v);
        self.len = (self.len + 1).min(STACK_SIZE - 1);
    }

    /// Pops the top; the traversal calls it only when the stack is not empty.
    #[inline(always)]
    fn pop_fast(&mut self) -> UVec2 {
        self.pop().unwrap_or_default()
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<UVec2> {
        self.len = self.len.checked_sub(1)?;
        // SAFETY: slots below `len` were written by `push`.
        Some(unsafe { self.slots[self.len].assume_init() })
    }

    #[inline(always)]
    fn len(&self) -> usize {
        self.len
    }

    #[inline(always)]
    fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[inline(always)]
    fn clear(&mut self) {
        self.len = 0;
    }
}

/// obvhs' `Traversal` (the fields its `traverse!` macro reads) over [`Stack`].
struct State {
    stack: Stack,
    current_group: UVec2,
    primitive_group: UVec2,
    oct_inv4: u32,
    primitive_id: u32,
    hitmask: u32,
}

impl State {
    /// The state at the root of `bvh` for a ray along `direction` (obvhs' `new_traversal`).
    #[inline(always)]
    fn new(bvh: &CwBvh, direction: Vec3A) -> State {
        // The octant, inverted, in each byte: children are visited nearest-octant first.
        let oct_inv4 = (if direction.x < 0.0 { 0 } else { 0x0404_0404 })
            | (if direction.y < 0.0 { 0 } else { 0x0202_0202 })
            | (if direction.z < 0.0 { 0 } else { 0x0101_0101 });
        State {
            stack: Stack::new(),
            current_group: if bvh.nodes.is_empty() { UVec2::ZERO } else { uvec2(0, 0x8000_0000) },
            primitive_group: UVec2::ZERO,
            oct_inv4,
            primitive_id: 0,
            hitmask: 0,
        }
    }
}

/// `hits` (`node`'s hit mask), after asking the cache for the inner children it names.
/// Which node comes next depends on the one being tested, so the processor cannot fetch
/// ahead by itself: on a BVH larger than the cache a traversal waits on every node's first
/// load (a third of its time on 10⁵ triangles, by `perf`). The children queued here are
/// in the cache by the time the traversal comes back to them.
#[inline(always)]
fn prefetched(bvh: &CwBvh, node: &CwBvhNode, hits: u32, state: &State) -> u32 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let mut inner = hits >> 24;
        while inner != 0 {
            // As obvhs' traversal finds the child: its slot, then its place among the
            // node's inner children.
            let slot = inner.trailing_zeros() ^ (state.oct_inv4 & 0xff);
            inner &= inner - 1;
            let rank = (u32::from(node.imask) & ((1 << slot) - 1)).count_ones();
            let child = bvh.nodes.as_ptr().wrapping_add((node.child_base_idx + rank) as usize).cast::<i8>();
            // SAFETY: SSE is part of x86-64, and a prefetch never faults (the address is a
            // child of this node anyway). A node is 80 bytes: two cache lines.
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(child);
                _mm_prefetch::<_MM_HINT_T0>(child.wrapping_add(79));
            }
        }
    }
    hits
}

/// [`closest`] with the node test `node_hits` (obvhs' `ray_traverse`).
#[inline(always)]
fn closest_with<F: FnMut(&Ray, usize) -> f32>(
    bvh: &CwBvh,
    ray: Ray,
    on_primitive: &mut F,
    node_hits: impl Fn(&CwBvhNode, &Ray, u32) -> u32,
) {
    let mut ray = ray;
    let mut state = State::new(bvh, ray.direction);
    let mut node: &CwBvhNode;
    obvhs::traverse!(bvh, node, state, prefetched(bvh, node, node_hits(node, &ray, state.oct_inv4), &state), {
        let t = on_primitive(&ray, state.primitive_id as usize);
        if t < ray.tmax {
            ray.tmax = t;
        }
    });
}

/// [`any`] with the node test `node_hits` (obvhs' `ray_traverse_miss`).
#[inline(always)]
fn any_with<F: FnMut(&Ray, usize) -> bool>(
    bvh: &CwBvh,
    ray: Ray,
    on_primitive: &mut F,
    node_hits: impl Fn(&CwBvhNode, &Ray, u32) -> u32,
) -> bool {
    let mut state = State::new(bvh, ray.direction);
    let mut node: &CwBvhNode;
    obvhs::traverse!(bvh, node, state, prefetched(bvh, node, node_hits(node, &ray, state.oct_inv4), &state), {
        if on_primitive(&ray, state.primitive_id as usize) {
            return true;
        }
    });
    false
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use glam::Vec3A;
    use obvhs::cwbvh::CwBvh;
    use obvhs::cwbvh::node::CwBvhNode;
    use obvhs::ray::Ray;
    use std::arch::x86_64::*;

    /// obvhs' cull of boxes whose exit distance is below this (`cwbvh::node::EPSILON`,
    /// crate-private there), applied instead of the ray's `tmin` (see `BvhSpace`).
    const EPSILON: f32 = 1e-4;

    /// [`super::closest`] with the AVX2 node test.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn closest<F: FnMut(&Ray, usize) -> f32>(bvh: &CwBvh, ray: Ray, on_primitive: &mut F) {
        super::closest_with(bvh, ray, on_primitive, |node, ray, oct| node_hits(node, ray, oct));
    }

    /// [`super::any`] with the AVX2 node test.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn any<F: FnMut(&Ray, usize) -> bool>(bvh: &CwBvh, ray: Ray, on_primitive: &mut F) -> bool {
        super::any_with(bvh, ray, on_primitive, |node, ray, oct| node_hits(node, ray, oct))
    }

    /// The 8 quantised coordinates `q` as f32 lanes (exact).
    #[target_feature(enable = "avx2")]
    #[inline]
    fn widen(q: &[u8; 8]) -> __m256 {
        // SAFETY: reads the 8 bytes of `q`.
        let bytes = unsafe { _mm_loadl_epi64(q.as_ptr().cast()) };
        _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(bytes))
    }

    /// obvhs' `CwBvhNode::intersect_ray` on 8 lanes: the node's hit mask (children to
    /// visit in the high byte, leaf primitives in the low 24 bits).
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn node_hits(node: &CwBvhNode, ray: &Ray, oct_inv4: u32) -> u32 {
        let scale = node.compute_extent() * ray.inv_direction;
        let origin = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
        // Entry and exit distances along one axis: a ray going down that axis enters
        // through the boxes' upper faces.
        let slabs = |lo: &[u8; 8], hi: &[u8; 8], negative: bool, scale: f32, origin: f32| {
            let (near, far) = if negative { (widen(hi), widen(lo)) } else { (widen(lo), widen(hi)) };
            let (s, o) = (_mm256_set1_ps(scale), _mm256_set1_ps(origin));
            (_mm256_add_ps(_mm256_mul_ps(near, s), o), _mm256_add_ps(_mm256_mul_ps(far, s), o))
        };
        let (x0, x1) = slabs(&node.child_min_x, &node.child_max_x, ray.direction.x < 0.0, scale.x, origin.x);
        let (y0, y1) = slabs(&node.child_min_y, &node.child_max_y, ray.direction.y < 0.0, scale.y, origin.y);
        let (z0, z1) = slabs(&node.child_min_z, &node.child_max_z, ray.direction.z < 0.0, scale.z, origin.z);
        let tmin = _mm256_max_ps(_mm256_max_ps(x0, _mm256_max_ps(y0, z0)), _mm256_set1_ps(EPSILON));
        let tmax = _mm256_min_ps(_mm256_min_ps(x1, _mm256_min_ps(y1, z1)), _mm256_set1_ps(ray.tmax));
        let met = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(tmin, tmax));
        // Each child met contributes its bits shifted to its place (obvhs' loop over the
        // met children, here in the lanes: no branch per child).
        let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
        let lanes = |bytes: u64| _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(bytes as i64));
        let bits = _mm256_and_si256(_mm256_sllv_epi32(lanes(child_bits8), lanes(bit_index8)), met);
        let half = _mm_or_si128(_mm256_castsi256_si128(bits), _mm256_extracti128_si256::<1>(bits));
        let pair = _mm_or_si128(half, _mm_unpackhi_epi64(half, half));
        _mm_cvtsi128_si32(_mm_or_si128(pair, _mm_srli_epi64::<32>(pair))) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3A;
    use obvhs::aabb::Aabb;
    use obvhs::cwbvh::builder::build_cwbvh;
    use obvhs::ray::Ray;

    /// The AVX2 node test accepts exactly the boxes obvhs' SSE test accepts, node by node,
    /// for rays in every octant (including axis-parallel ones).
    #[test]
    fn avx2_node_test_matches_obvhs_on_every_node() {
        #[cfg(target_arch = "x86_64")]
        {
            if !has_avx2() {
                return;
            }
            let mut seed = 1u32;
            let mut next = move || {
                seed ^= seed << 13;
                seed ^= seed >> 17;
                seed ^= seed << 5;
                seed as f32 / u32::MAX as f32 * 2.0 - 1.0
            };
            let boxes: Vec<Aabb> = (0..500)
                .map(|_| {
                    let c = Vec3A::new(next(), next(), next()) * 100.0;
                    let h = Vec3A::new(next().abs(), next().abs(), next().abs()) * 3.0;
                    Aabb::new(c - h, c + h)
                })
                .collect();
            let bvh = build_cwbvh(&boxes, obvhs::BvhBuildParams::medium_build(), &mut Default::default());
            let mut compared = 0;
            for r in 0..400 {
                let mut d = Vec3A::new(next(), next(), next());
                if r % 7 == 0 {
                    d.y = 0.0;
                }
                let ray = Ray::new(
                    Vec3A::new(next(), next(), next()) * 150.0,
                    d.normalize(),
                    0.0,
                    50.0 + 200.0 * next().abs(),
                );
                let oct = bvh.new_traversal(ray.direction).oct_inv4;
                for node in &bvh.nodes {
                    // SAFETY: AVX2 is present (checked above).
                    let wide = unsafe { avx2_node_hits(node, &ray, oct) };
                    assert_eq!(wide, node.intersect_ray(&ray, oct), "ray {r}");
                    compared += u32::from(wide != 0);
                }
            }
            assert!(compared > 100, "the rays must meet some boxes ({compared})");
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx2_node_hits(node: &obvhs::cwbvh::node::CwBvhNode, ray: &Ray, oct: u32) -> u32 {
        avx2::node_hits(node, ray, oct)
    }
}
