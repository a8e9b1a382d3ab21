//! strata's own 8-wide BVH and its traversal. The tree is obvhs' compressed-wide BVH (built
//! there, or converted from a BVH2 in `convert.rs`), node for node, with each node's 8 child
//! boxes stored uncompressed as f32 lanes (SoA) instead of 8-bit offsets from a quantisation
//! frame: a ray tests them with no decode, and on CPUs with AVX2 (detected at run time, so
//! the binary still runs on baseline x86-64) all 8 in one 8-lane pass. A node is 256 bytes
//! (four cache lines) against obvhs' 80: the compressed node cost a ray ~4x Embree's
//! instructions per node (dequantisation, the octant-order bit juggling of its traversal).
//!
//! The traversal visits children nearest entry distance first (sorted per node, Embree's
//! order) and skips a stacked child whose entry lies beyond the closest hit found since it
//! was stacked; occlusion rays stop at the first hit and test a node's leaves before
//! descending. A leaf child is a range of consecutive primitives, so its primitives are
//! tested together, with no per-primitive callback from the traversal.
//!
//! The AVX2 and the scalar node test do the same f32 operations in the same order (subtract,
//! multiply, then min/max with the x86 rule "a NaN operand yields the second"), so they accept
//! the same boxes with the same entry distances, and a render is bit-identical on either path.

use glam::Vec3;
use obvhs::cwbvh::CwBvh;
use std::mem::MaybeUninit;

/// Whether the AVX2 path runs (std caches the CPUID query: one load per call).
#[inline]
pub(super) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The far distance of a box is multiplied by this before the overlap test: the f32 slab
/// distances are each within 1 + 2γ(3) of the exact ones (pbrt-v4's "Robust Ray–Bounds
/// Intersections"), so a box the exact ray meets is never rejected by rounding.
const FAR_GROWTH: f32 = 1.0 + 4.0 * f32::EPSILON;

/// One node: up to 8 children, each an inner node or a leaf (a range of primitives).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub(super) struct Node {
    /// Child boxes, one lane per child: min x, min y, min z, max x, max y, max z. An empty
    /// slot's box is (+∞, −∞), which no ray meets.
    bounds: [[f32; 8]; 6],
    /// An inner child's node index, or a leaf's first primitive.
    child: [u32; 8],
    /// A leaf's primitive count; 0 for an inner child.
    count: [u32; 8],
}

/// A BVH of [`Node`]s; node 0 is the root (its own box is never tested: its children's are).
pub(super) struct WideBvh {
    nodes: Vec<Node>,
    /// The most entries a traversal's stack can hold: on any root-to-leaf path, the sum of
    /// each node's children less the one descended into.
    stack_need: usize,
}

/// Stack entries a traversal keeps on the thread's stack (3 KiB); a deeper BVH (the
/// sum along one path exceeding it: hundreds of levels, which the builders do not produce
/// on real geometry) gets a heap stack of its own size.
const LOCAL_STACK: usize = 256;

impl WideBvh {
    /// `cw`'s tree with its child boxes decoded: each quantised bound `p + q·2^e` is computed
    /// in f32, and since the encoder rounded `q` outward and f32 rounding is monotone, the
    /// decoded box still holds the box built over.
    pub(super) fn from_cwbvh(cw: &CwBvh) -> WideBvh {
        let empty = Node {
            bounds: [
                [f32::INFINITY; 8],
                [f32::INFINITY; 8],
                [f32::INFINITY; 8],
                [f32::NEG_INFINITY; 8],
                [f32::NEG_INFINITY; 8],
                [f32::NEG_INFINITY; 8],
            ],
            child: [0; 8],
            count: [0; 8],
        };
        let nodes: Vec<Node> = cw
            .nodes
            .iter()
            .map(|n| {
                let mut out = empty;
                let e = n.compute_extent();
                let p = n.p;
                for i in 0..8 {
                    if n.is_child_empty(i) {
                        continue;
                    }
                    let lo = [n.child_min_x[i], n.child_min_y[i], n.child_min_z[i]];
                    let hi = [n.child_max_x[i], n.child_max_y[i], n.child_max_z[i]];
                    for axis in 0..3 {
                        out.bounds[axis][i] = p[axis] + f32::from(lo[axis]) * e[axis];
                        out.bounds[axis + 3][i] = p[axis] + f32::from(hi[axis]) * e[axis];
                    }
                    if n.is_leaf(i) {
                        (out.child[i], out.count[i]) = n.child_primitives(i);
                    } else {
                        out.child[i] = n.child_node_index(i);
                    }
                }
                out
            })
            .collect();
        // Children follow their parents in obvhs' node order, so one backward pass sees
        // every child's need before its parent's; otherwise the bound of a stack that holds
        // every child of every node.
        let mut need = vec![0usize; nodes.len()];
        let mut ordered = true;
        for (index, node) in nodes.iter().enumerate().rev() {
            let children = (0..8).filter(|&i| node.bounds[0][i] <= node.bounds[3][i]).count();
            let mut deepest = 0;
            for i in (0..8).filter(|&i| node.count[i] == 0 && node.bounds[0][i] <= node.bounds[3][i]) {
                let c = node.child[i] as usize;
                ordered &= c > index && c < nodes.len();
                deepest = deepest.max(need.get(c).copied().unwrap_or(0));
            }
            need[index] = children.saturating_sub(1) + deepest;
        }
        let stack_need = if ordered { need.first().copied().unwrap_or(0) + 1 } else { 7 * nodes.len() + 1 };
        WideBvh { nodes, stack_need }
    }

    /// Renumbers each leaf's primitives: `(first, count)` becomes `map(first, count)`.
    pub(super) fn remap_leaves(&mut self, map: impl Fn(u32, u32) -> (u32, u32)) {
        for node in &mut self.nodes {
            for i in 0..8 {
                if node.count[i] != 0 {
                    (node.child[i], node.count[i]) = map(node.child[i], node.count[i]);
                }
            }
        }
    }

    /// Every leaf's `(first, count)`, in node order.
    pub(super) fn leaves(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.nodes.iter().flat_map(|n| (0..8).filter(|&i| n.count[i] != 0).map(|i| (n.child[i], n.count[i])))
    }

    /// Bytes held by the nodes.
    pub(super) fn bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>()
    }
}

/// A ray prepared for the node tests: `o + t d`, `t` from `tmin`, with `1/d` per axis and,
/// per axis, which bound row the ray enters through (the max row when it runs down the axis).
#[derive(Clone, Copy, Debug)]
pub(super) struct WideRay {
    o: [f32; 3],
    inv: [f32; 3],
    near: [usize; 3],
    far: [usize; 3],
    tmin: f32,
}

impl WideRay {
    /// The ray `o + t d`, `t > tmin`. A zero component of `d` gives an infinite inverse: the
    /// slab test then says inside or outside exactly, except a ray lying in the slab's plane
    /// (0·∞ = NaN), where that axis is ignored (the box is kept).
    #[inline]
    pub(super) fn new(o: Vec3, d: Vec3, tmin: f32) -> WideRay {
        let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
        let near = [0, 1, 2].map(|a| if inv[a] < 0.0 { a + 3 } else { a });
        let far = near.map(|n| (n + 3) % 6);
        WideRay { o: o.to_array(), inv, near, far, tmin }
    }
}

/// A child still to visit: its entry distance and what [`Node`] says of it.
#[derive(Clone, Copy)]
struct Entry {
    t: f32,
    child: u32,
    count: u32,
}

/// `a` if it is above `b`, else `b` (a NaN `a` or `b` gives `b`), as x86's `maxps`.
#[inline(always)]
fn max_x86(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `a` if it is below `b`, else `b`, as x86's `minps`.
#[inline(always)]
fn min_x86(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// The children of `node` that the ray meets within `tmax`: a bit per child, and each
/// child's entry distance (meaningful where the bit is set).
#[inline(always)]
fn scalar_hits(node: &Node, ray: &WideRay, tmax: f32) -> (u32, [f32; 8]) {
    let mut mask = 0;
    let mut near = [0.0; 8];
    for (i, near) in near.iter_mut().enumerate() {
        let slab = |row: usize, axis: usize| (node.bounds[row][i] - ray.o[axis]) * ray.inv[axis];
        let mut t0 = ray.tmin;
        let mut t1 = f32::INFINITY;
        for axis in 0..3 {
            t0 = max_x86(slab(ray.near[axis], axis), t0);
            t1 = min_x86(slab(ray.far[axis], axis), t1);
        }
        let t1 = min_x86(t1 * FAR_GROWTH, tmax);
        *near = t0;
        mask |= u32::from(t0 <= t1) << i;
    }
    (mask, near)
}

/// Asks the cache for node `index` (all four lines), a stacked child: the traversal comes
/// back to it after the nearer children, and by then it is in the cache rather than a miss
/// on the path (the next node's address depends on the current node's test, so the processor
/// cannot fetch ahead by itself).
#[inline(always)]
fn prefetch(bvh: &WideBvh, index: u32) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let node = bvh.nodes.as_ptr().wrapping_add(index as usize).cast::<i8>();
        // SAFETY: SSE is part of x86-64, and a prefetch never faults.
        unsafe {
            for line in 0..4 {
                _mm_prefetch::<_MM_HINT_T0>(node.wrapping_add(64 * line));
            }
        }
    }
}

/// The traversal stack: on the thread's stack, or on the heap for a BVH deeper than
/// [`LOCAL_STACK`] allows.
macro_rules! stack_slots {
    ($bvh:expr, $local:ident, $heap:ident) => {{
        if $bvh.stack_need <= LOCAL_STACK {
            &mut $local[..]
        } else {
            $heap = vec![MaybeUninit::<Entry>::uninit(); $bvh.stack_need];
            &mut $heap[..]
        }
    }};
}

/// Visits the leaves whose boxes the ray meets, nearest entry first; `on_leaf(tmax, first,
/// count)` tests the leaf's primitives against the ray shortened to `tmax` and returns the
/// closest hit's distance, or anything not below `tmax` for none. The ray starts at `tmax`.
#[inline]
pub(super) fn closest(bvh: &WideBvh, ray: &WideRay, tmax: f32, mut on_leaf: impl FnMut(f32, u32, u32) -> f32) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { avx2::closest(bvh, ray, tmax, &mut on_leaf) };
        return;
    }
    closest_with(bvh, ray, tmax, &mut on_leaf, scalar_hits);
}

/// Whether `on_leaf(first, count)` holds for any leaf whose box the ray meets within `tmax`;
/// stops at the first that does.
#[inline]
pub(super) fn any(bvh: &WideBvh, ray: &WideRay, tmax: f32, mut on_leaf: impl FnMut(u32, u32) -> bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { avx2::any(bvh, ray, tmax, &mut on_leaf) };
    }
    any_with(bvh, ray, tmax, &mut on_leaf, scalar_hits)
}

/// A leaf test of the closest-hit traversal: `test(tmax, first, count)` tests the leaf's
/// primitives against the ray shortened to `tmax` and returns the closest hit's distance, or
/// anything not below `tmax` for none. A closure is one; a BLAS's leaf test is a struct whose
/// `test` is `#[inline(always)]`, so that it inlines into a traversal compiled for AVX2 (a
/// closure inlines only if the optimiser finds it cheap, and is compiled without AVX2: the
/// block test it calls then stays out of line).
pub(super) trait ClosestLeaf {
    /// See [`ClosestLeaf`].
    fn test(&mut self, tmax: f32, first: u32, count: u32) -> f32;
}

impl<F: FnMut(f32, u32, u32) -> f32> ClosestLeaf for F {
    #[inline(always)]
    fn test(&mut self, tmax: f32, first: u32, count: u32) -> f32 {
        self(tmax, first, count)
    }
}

/// A leaf test of the occlusion traversal: whether any of the leaf's primitives is hit (as
/// [`ClosestLeaf`]).
pub(super) trait AnyLeaf {
    /// See [`AnyLeaf`].
    fn test(&mut self, first: u32, count: u32) -> bool;
}

impl<F: FnMut(u32, u32) -> bool> AnyLeaf for F {
    #[inline(always)]
    fn test(&mut self, first: u32, count: u32) -> bool {
        self(first, count)
    }
}

/// [`closest`] on the AVX2 path or not, chosen by the caller: `AVX2` is true only where the
/// CPU has AVX2, in a caller compiled for it, so that the node test and `on_leaf` inline.
#[inline(always)]
pub(super) fn closest_in<const AVX2: bool>(bvh: &WideBvh, ray: &WideRay, tmax: f32, on_leaf: &mut impl ClosestLeaf) {
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is true only where the CPU has AVX2.
        let hits = |node: &Node, ray: &WideRay, tmax: f32| unsafe { avx2::node_hits(node, ray, tmax) };
        closest_with(bvh, ray, tmax, on_leaf, hits);
        return;
    }
    closest_with(bvh, ray, tmax, on_leaf, scalar_hits);
}

/// [`any`] on the AVX2 path or not, chosen by the caller (see [`closest_in`]).
#[inline(always)]
pub(super) fn any_in<const AVX2: bool>(bvh: &WideBvh, ray: &WideRay, tmax: f32, on_leaf: &mut impl AnyLeaf) -> bool {
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is true only where the CPU has AVX2.
        let hits = |node: &Node, ray: &WideRay, tmax: f32| unsafe { avx2::node_hits(node, ray, tmax) };
        return any_with(bvh, ray, tmax, on_leaf, hits);
    }
    any_with(bvh, ray, tmax, on_leaf, scalar_hits)
}

/// [`closest`] with the node test `hits`.
#[inline(always)]
fn closest_with<F: ClosestLeaf>(
    bvh: &WideBvh,
    ray: &WideRay,
    mut tmax: f32,
    on_leaf: &mut F,
    hits: impl Fn(&Node, &WideRay, f32) -> (u32, [f32; 8]),
) {
    if bvh.nodes.is_empty() {
        return;
    }
    let mut local = [MaybeUninit::<Entry>::uninit(); LOCAL_STACK];
    let mut heap;
    let slots: &mut [MaybeUninit<Entry>] = stack_slots!(bvh, local, heap);
    let mut len = 0;
    let mut next = Entry { t: ray.tmin, child: 0, count: 0 };
    loop {
        let mut descend = false;
        if next.count == 0 {
            let node = &bvh.nodes[next.child as usize];
            let (mut mask, near) = hits(node, ray, tmax);
            if mask != 0 {
                let entry = |i: usize| Entry { t: near[i], child: node.child[i], count: node.count[i] };
                let rest = mask & (mask - 1);
                if rest == 0 {
                    next = entry(mask.trailing_zeros() as usize);
                } else if rest & (rest - 1) == 0 {
                    // Two children (the commonest case after one): the nearer is next, the
                    // other stacked, in registers; on equal distances the higher slot is next,
                    // as the insertion sort below orders them.
                    let (a, b) = (entry(mask.trailing_zeros() as usize), entry(rest.trailing_zeros() as usize));
                    let (near, far) = if a.t < b.t { (a, b) } else { (b, a) };
                    for e in [near, far] {
                        if e.count == 0 {
                            prefetch(bvh, e.child);
                        }
                    }
                    slots[len] = MaybeUninit::new(far);
                    len += 1;
                    next = near;
                } else {
                    // Insertion sort onto the stack, farthest deepest; the nearest is then
                    // taken off the top.
                    let base = len;
                    while mask != 0 {
                        let e = entry(mask.trailing_zeros() as usize);
                        mask &= mask - 1;
                        if e.count == 0 {
                            prefetch(bvh, e.child);
                        }
                        let mut j = len;
                        // SAFETY: slots below `len` were written.
                        while j > base && unsafe { slots[j - 1].assume_init() }.t < e.t {
                            slots[j] = slots[j - 1];
                            j -= 1;
                        }
                        slots[j] = MaybeUninit::new(e);
                        len += 1;
                    }
                    len -= 1;
                    // SAFETY: written just above.
                    next = unsafe { slots[len].assume_init() };
                }
                descend = true;
            }
        } else {
            let t = on_leaf.test(tmax, next.child, next.count);
            if t < tmax {
                tmax = t;
            }
        }
        if descend {
            continue;
        }
        // The next stacked child that may still hold a closer hit.
        loop {
            if len == 0 {
                return;
            }
            len -= 1;
            // SAFETY: slots below `len` were written.
            next = unsafe { slots[len].assume_init() };
            if next.t <= tmax {
                break;
            }
        }
    }
}

/// [`any`] with the node test `hits`.
#[inline(always)]
fn any_with<F: AnyLeaf>(
    bvh: &WideBvh,
    ray: &WideRay,
    tmax: f32,
    on_leaf: &mut F,
    hits: impl Fn(&Node, &WideRay, f32) -> (u32, [f32; 8]),
) -> bool {
    if bvh.nodes.is_empty() {
        return false;
    }
    let mut local = [MaybeUninit::<u32>::uninit(); LOCAL_STACK];
    let mut heap;
    let slots: &mut [MaybeUninit<u32>] = if bvh.stack_need <= LOCAL_STACK {
        &mut local[..]
    } else {
        heap = vec![MaybeUninit::<u32>::uninit(); bvh.stack_need];
        &mut heap[..]
    };
    let mut len = 0;
    let mut node = 0u32;
    loop {
        let n = &bvh.nodes[node as usize];
        let (mut mask, _) = hits(n, ray, tmax);
        // The node's leaves first: any hit ends the ray.
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if n.count[i] != 0 {
                if on_leaf.test(n.child[i], n.count[i]) {
                    return true;
                }
            } else {
                prefetch(bvh, n.child[i]);
                slots[len] = MaybeUninit::new(n.child[i]);
                len += 1;
            }
        }
        if len == 0 {
            return false;
        }
        len -= 1;
        // SAFETY: slots below `len` were written.
        node = unsafe { slots[len].assume_init() };
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{FAR_GROWTH, Node, WideBvh, WideRay};
    use std::arch::x86_64::*;

    /// [`super::closest`] with the AVX2 node test.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn closest<F: FnMut(f32, u32, u32) -> f32>(
        bvh: &WideBvh,
        ray: &WideRay,
        tmax: f32,
        on_leaf: &mut F,
    ) {
        super::closest_with(bvh, ray, tmax, on_leaf, |node, ray, tmax| node_hits(node, ray, tmax));
    }

    /// [`super::any`] with the AVX2 node test.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn any<F: FnMut(u32, u32) -> bool>(
        bvh: &WideBvh,
        ray: &WideRay,
        tmax: f32,
        on_leaf: &mut F,
    ) -> bool {
        super::any_with(bvh, ray, tmax, on_leaf, |node, ray, tmax| node_hits(node, ray, tmax))
    }

    /// [`super::scalar_hits`] on 8 lanes (the same operations in the same order).
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn node_hits(node: &Node, ray: &WideRay, tmax: f32) -> (u32, [f32; 8]) {
        // SAFETY: each row is 8 f32 (unaligned loads: the rows are 32-byte aligned anyway).
        let row = |r: usize| unsafe { _mm256_loadu_ps(node.bounds[r].as_ptr()) };
        let slab = |r: usize, axis: usize| {
            _mm256_mul_ps(_mm256_sub_ps(row(r), _mm256_set1_ps(ray.o[axis])), _mm256_set1_ps(ray.inv[axis]))
        };
        let mut t0 = _mm256_set1_ps(ray.tmin);
        let mut t1 = _mm256_set1_ps(f32::INFINITY);
        for axis in 0..3 {
            t0 = _mm256_max_ps(slab(ray.near[axis], axis), t0);
            t1 = _mm256_min_ps(slab(ray.far[axis], axis), t1);
        }
        let t1 = _mm256_min_ps(_mm256_mul_ps(t1, _mm256_set1_ps(FAR_GROWTH)), _mm256_set1_ps(tmax));
        let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(t0, t1)) as u32;
        let mut near = [0.0f32; 8];
        // SAFETY: `near` holds 8 f32.
        unsafe { _mm256_storeu_ps(near.as_mut_ptr(), t0) };
        (mask, near)
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use glam::Vec3A;
    use obvhs::aabb::Aabb;
    use obvhs::cwbvh::builder::build_cwbvh;

    /// A small deterministic generator (xorshift) in [-1, 1] (the leaf and shape tests' too).
    pub(in crate::render::geometry) fn generator(mut seed: u32) -> impl FnMut() -> f32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as f32 / u32::MAX as f32 * 2.0 - 1.0
        }
    }

    /// Boxes, the wide BVH over them, and a ray generator (some rays axis-parallel).
    fn scene() -> (Vec<Aabb>, WideBvh, CwBvh) {
        let mut next = generator(1);
        let boxes: Vec<Aabb> = (0..500)
            .map(|_| {
                let c = Vec3A::new(next(), next(), next()) * 100.0;
                let h = Vec3A::new(next().abs(), next().abs(), next().abs()) * 3.0;
                Aabb::new(c - h, c + h)
            })
            .collect();
        let cw = build_cwbvh(&boxes, obvhs::BvhBuildParams::medium_build(), &mut Default::default());
        (boxes, WideBvh::from_cwbvh(&cw), cw)
    }

    /// Rays from around the boxes: half aimed near a box's centre, the rest anywhere.
    fn rays(boxes: &[Aabb]) -> Vec<(Vec3, Vec3, f32)> {
        let mut next = generator(9);
        (0..400)
            .map(|r| {
                let o = Vec3::new(next(), next(), next()) * 150.0;
                let jitter = Vec3::new(next(), next(), next());
                let target = if r % 2 == 0 {
                    let b = &boxes[r * 7 % boxes.len()];
                    Vec3::from(b.min + b.max) * 0.5 + jitter * 2.0
                } else {
                    jitter * 1e4
                };
                let mut d = target - o;
                if r % 7 == 0 {
                    d.y = 0.0;
                }
                if r % 11 == 0 {
                    d.x = 0.0;
                }
                (o, d.normalize(), 150.0 + 300.0 * next().abs())
            })
            .collect()
    }

    /// The slab test in f64 against the box built over: where the segment enters it, if it
    /// meets it.
    fn entry(b: &Aabb, o: Vec3, d: Vec3, tmax: f32) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, tmax as f64);
        for a in 0..3 {
            let (lo, hi, o, d) = (b.min[a] as f64, b.max[a] as f64, o[a] as f64, d[a] as f64);
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
                continue;
            }
            let (x, y) = ((lo - o) / d, (hi - o) / d);
            t0 = t0.max(x.min(y));
            t1 = t1.min(x.max(y));
        }
        (t0 <= t1).then_some(t0)
    }

    /// The AVX2 node test accepts exactly the boxes the scalar test accepts, with the same
    /// entry distances, node by node, for rays in every octant (including axis-parallel ones).
    #[test]
    fn avx2_node_test_matches_the_scalar_test_on_every_node() {
        #[cfg(target_arch = "x86_64")]
        {
            if !has_avx2() {
                return;
            }
            let (boxes, bvh, _) = scene();
            let mut met = 0;
            for (r, (o, d, tmax)) in rays(&boxes).into_iter().enumerate() {
                let ray = WideRay::new(o, d, 0.0);
                for node in &bvh.nodes {
                    let (mask, near) = scalar_hits(node, &ray, tmax);
                    // SAFETY: AVX2 is present (checked above).
                    let (wide_mask, wide_near) = unsafe { avx2_node_hits(node, &ray, tmax) };
                    assert_eq!(mask, wide_mask, "ray {r}");
                    for i in (0..8).filter(|i| mask >> i & 1 == 1) {
                        assert_eq!(near[i].to_bits(), wide_near[i].to_bits(), "ray {r}");
                    }
                    met += mask.count_ones();
                }
            }
            assert!(met > 100, "the rays must meet some boxes ({met})");
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx2_node_hits(node: &Node, ray: &WideRay, tmax: f32) -> (u32, [f32; 8]) {
        avx2::node_hits(node, ray, tmax)
    }

    /// Every primitive whose box the segment meets (by an f64 slab test on the box built
    /// over) is handed to the leaf callback, by both traversals, and each primitive at most
    /// once; the decoded node boxes hold the boxes built over.
    #[test]
    fn traversals_reach_every_box_the_ray_meets() {
        let (boxes, bvh, cw) = scene();
        assert!(bvh.stack_need > 1 && bvh.stack_need <= LOCAL_STACK, "{}", bvh.stack_need);
        for (r, (o, d, tmax)) in rays(&boxes).into_iter().enumerate() {
            let ray = WideRay::new(o, d, 0.0);
            let mut seen = vec![0u32; boxes.len()];
            // With the ray never shortened, the closest-hit traversal visits every leaf met.
            closest(&bvh, &ray, tmax, |_, first, count| {
                for id in first..first + count {
                    seen[cw.primitive_indices[id as usize] as usize] += 1;
                }
                f32::INFINITY
            });
            let mut any_seen = vec![0u32; boxes.len()];
            let stopped = any(&bvh, &ray, tmax, |first, count| {
                for id in first..first + count {
                    any_seen[cw.primitive_indices[id as usize] as usize] += 1;
                }
                false
            });
            assert!(!stopped);
            for (i, b) in boxes.iter().enumerate() {
                assert!(seen[i] <= 1 && any_seen[i] <= 1, "ray {r}, box {i} visited twice");
                if entry(b, o, d, tmax).is_some() {
                    assert_eq!(seen[i], 1, "ray {r} meets box {i}: closest traversal missed it");
                    assert_eq!(any_seen[i], 1, "ray {r} meets box {i}: any traversal missed it");
                }
            }
        }
    }

    /// The closest-hit traversal, told each box's entry distance as its hit, finds the
    /// brute-force nearest entry: the nearest-first order and the cull of stacked children
    /// beyond the hit never drop a nearer box (boxes holding the origin, entered at 0, left out).
    #[test]
    fn closest_hit_finds_the_nearest_box() {
        let (boxes, bvh, cw) = scene();
        let mut checked = 0;
        for (o, d, tmax) in rays(&boxes) {
            let ray = WideRay::new(o, d, 0.0);
            let nearest = boxes.iter().filter_map(|b| entry(b, o, d, tmax)).filter(|&t| t > 0.0).reduce(f64::min);
            let mut best: Option<f64> = None;
            closest(&bvh, &ray, tmax, |_, first, count| {
                let mut found = None;
                for id in first..first + count {
                    let b = &boxes[cw.primitive_indices[id as usize] as usize];
                    if let Some(t) = entry(b, o, d, tmax).filter(|&t| t > 0.0 && best.is_none_or(|x| t < x)) {
                        best = Some(t);
                        found = Some(t as f32);
                    }
                }
                found.unwrap_or(f32::INFINITY)
            });
            assert_eq!(best, nearest);
            checked += usize::from(nearest.is_some());
        }
        assert!(checked > 80, "{checked}");
    }
}
