//! BVH2 → compressed-wide BVH conversion (Ylitie et al. 2017, "Efficient Incoherent Ray
//! Traversal on GPUs Through Compressed Wide BVHs", section 4.1), producing exactly the nodes
//! obvhs' `bvh2_to_cwbvh` produces (same cost model, same order of floating-point
//! operations, same child order), in far less memory.
//!
//! The paper's dynamic programme chooses, for every BVH2 node and every budget of 1 to 7
//! further wide children, whether the node is a leaf, a wide node, or splits the budget
//! between its two children. obvhs keeps a cost and a choice for every (node, budget) pair,
//! 56 bytes per BVH2 node (112 per triangle, the largest allocation of a 10⁶-triangle build).
//! The costs are needed only by the parent while the programme climbs, so here they are
//! returned up the recursion instead of stored, and a node keeps only its 7 choices, one byte
//! each (and a leaf none: its choice is always "leaf"): 14 bytes per triangle.

use glam::{UVec3, Vec3A};
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::node::CwBvhNode;

/// The SAH cost of testing one primitive, relative to one wide-node box test (the paper's and
/// obvhs' value).
const PRIMITIVE_COST: f32 = 0.3;

/// A wide node's children: 8 slots.
const WIDTH: usize = 8;

/// The budgets a node's choice is made for: a subtree may become up to 7 further children.
const BUDGETS: usize = 7;

/// One step of a child box's 8-bit quantisation, as a fraction of the node's extent.
const QUANT_STEP: f32 = 1.0 / 255.0;

/// What a BVH2 node becomes under a budget.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Kind {
    /// A leaf of the wide BVH (its primitives, at most the leaf limit, become one child).
    Leaf,
    /// A wide node of its own (one child of its parent, its own up to 8 children below).
    Wide,
    /// Dissolved: its two children share the budget (see [`Choice`]).
    Split,
}

/// A node's choice under one budget, packed in a byte: the kind in bits 6–7 and, for
/// [`Kind::Split`] and [`Kind::Wide`], the budgets its left and right children get in bits
/// 3–5 and 0–2 (7: none; only a wide node whose children had no finite cost has none).
#[derive(Clone, Copy, Default)]
struct Choice(u8);

impl Choice {
    const NONE: u8 = 7;

    fn new(kind: Kind, left: u8, right: u8) -> Choice {
        let kind = match kind {
            Kind::Leaf => 0,
            Kind::Wide => 1,
            Kind::Split => 2,
        };
        Choice(kind << 6 | left << 3 | right)
    }

    fn kind(self) -> Kind {
        match self.0 >> 6 {
            0 => Kind::Leaf,
            1 => Kind::Wide,
            _ => Kind::Split,
        }
    }

    fn left(self) -> usize {
        usize::from(self.0 >> 3 & 7)
    }

    fn right(self) -> usize {
        usize::from(self.0 & 7)
    }
}

/// The conversion's state: the BVH2 read, the choices made, the wide BVH written.
struct Converter<'a> {
    bvh2: &'a Bvh2,
    /// Per BVH2 node, its choice under each budget (leaves' entries are unused).
    choices: Vec<[Choice; BUDGETS]>,
    nodes: Vec<CwBvhNode>,
    primitive_indices: Vec<u32>,
}

/// Converts `bvh2` (every leaf one primitive) to a compressed-wide BVH whose leaves hold at
/// most `max_leaf` (1 to 3) primitives, children ordered by octant; the same nodes as obvhs'
/// `bvh2_to_cwbvh(bvh2, max_leaf, true, false)`.
pub(super) fn bvh2_to_cwbvh(bvh2: &Bvh2, max_leaf: u32) -> CwBvh {
    let Some(root) = bvh2.nodes.first() else { return CwBvh::default() };
    let mut converter = Converter {
        bvh2,
        choices: vec![[Choice::default(); BUDGETS]; bvh2.nodes.len()],
        nodes: vec![CwBvhNode::default()],
        primitive_indices: Vec::with_capacity(bvh2.primitive_indices.len()),
    };
    converter.choose(0, max_leaf.clamp(1, 3));
    converter.emit(0, 0);
    let Converter { mut nodes, primitive_indices, .. } = converter;
    nodes.shrink_to_fit();
    CwBvh { nodes, primitive_indices, total_aabb: *root.aabb(), exact_node_aabbs: None, uses_spatial_splits: false }
}

impl Converter<'_> {
    /// Fills the choices of `node`'s subtree; returns the node's primitive count and its cost
    /// under each budget.
    fn choose(&mut self, node: usize, max_leaf: u32) -> (u32, [f32; BUDGETS]) {
        let n = &self.bvh2.nodes[node];
        let half_area = n.aabb().half_area();
        if n.is_leaf() {
            debug_assert_eq!(n.prim_count, 1, "the conversion takes one primitive per BVH2 leaf");
            return (n.prim_count, [half_area * n.prim_count as f32 * PRIMITIVE_COST; BUDGETS]);
        }
        let first = n.first_index as usize;
        let (left_count, left) = self.choose(first, max_leaf);
        let (right_count, right) = self.choose(first + 1, max_leaf);
        let count = left_count + right_count;
        let mut choices = [Choice::default(); BUDGETS];
        let mut costs = [0.0; BUDGETS];

        // Budget 1: a leaf, or a wide node whose 8 children the two sides share.
        let as_leaf = if count <= max_leaf { count as f32 * half_area * PRIMITIVE_COST } else { f32::INFINITY };
        let (mut shared, mut split) = (f32::INFINITY, (Choice::NONE, Choice::NONE));
        for k in 0..BUDGETS {
            let c = left[k] + right[BUDGETS - 1 - k];
            if c < shared {
                shared = c;
                split = (k as u8, (BUDGETS - 1 - k) as u8);
            }
        }
        let as_wide = shared + half_area;
        let (kind, cost) = if as_leaf < as_wide { (Kind::Leaf, as_leaf) } else { (Kind::Wide, as_wide) };
        choices[0] = Choice::new(kind, split.0, split.1);
        costs[0] = cost;

        // Budgets 2 to 7: the cheaper of the smaller budget's choice and a split of this one.
        for i in 1..BUDGETS {
            let mut best = costs[i - 1];
            let mut split = None;
            for k in 0..i {
                let c = left[k] + right[i - k - 1];
                if c < best {
                    best = c;
                    split = Some((k as u8, (i - k - 1) as u8));
                }
            }
            costs[i] = best;
            choices[i] = match split {
                Some((l, r)) => Choice::new(Kind::Split, l, r),
                None => choices[i - 1],
            };
        }
        self.choices[node] = choices;
        (count, costs)
    }

    /// The kind `node` takes under `budget`.
    fn kind(&self, node: usize, budget: usize) -> Kind {
        if self.bvh2.nodes[node].is_leaf() { Kind::Leaf } else { self.choices[node][budget].kind() }
    }

    /// Appends to `children` the BVH2 nodes that become children of a wide node made from
    /// `node` under `budget`: split nodes are dissolved into theirs.
    fn gather(&self, node: usize, budget: usize, children: &mut Vec<u32>) {
        let n = &self.bvh2.nodes[node];
        if n.is_leaf() {
            children.push(node as u32);
            return;
        }
        let choice = self.choices[node][budget];
        let first = n.first_index as usize;
        for (child, child_budget) in [(first, choice.left()), (first + 1, choice.right())] {
            if self.kind(child, child_budget) == Kind::Split {
                self.gather(child, child_budget, children);
            } else {
                children.push(child as u32);
            }
        }
    }

    /// Sorts `children` (at most 8) into slots so that a ray's octant gives the near-to-far
    /// order: greedily, the child furthest along each octant's diagonal takes that slot.
    fn order(&self, node: usize, children: &[u32]) -> [u32; WIDTH] {
        let centre = self.bvh2.nodes[node].aabb().center();
        let mut cost = [[f32::MAX; WIDTH]; WIDTH];
        for (c, &child) in children.iter().enumerate() {
            let v = self.bvh2.nodes[child as usize].aabb().center() - centre;
            for (s, slot) in cost[c].iter_mut().enumerate() {
                let sign = |bit: usize| if s & bit != 0 { -1.0 } else { 1.0 };
                *slot = Vec3A::new(sign(4), sign(2), sign(1)).dot(v);
            }
        }
        let mut slot_of = [usize::MAX; WIDTH];
        let mut taken = [false; WIDTH];
        loop {
            let mut best = (f32::MAX, usize::MAX, usize::MAX);
            for c in (0..children.len()).filter(|&c| slot_of[c] == usize::MAX) {
                for s in (0..WIDTH).filter(|&s| !taken[s]) {
                    if cost[c][s] < best.0 {
                        best = (cost[c][s], c, s);
                    }
                }
            }
            let (_, c, s) = best;
            if s == usize::MAX {
                break;
            }
            taken[s] = true;
            slot_of[c] = s;
        }
        let mut slots = [u32::MAX; WIDTH];
        for (c, &child) in children.iter().enumerate() {
            slots[slot_of[c]] = child;
        }
        slots
    }

    /// Appends `node`'s primitives (left subtree first) to the wide BVH's list; returns how many.
    fn append_primitives(&mut self, node: usize) -> u32 {
        let n = &self.bvh2.nodes[node];
        if n.is_leaf() {
            self.primitive_indices.push(self.bvh2.primitive_indices[n.first_index as usize]);
            return 1;
        }
        let first = n.first_index as usize;
        self.append_primitives(first) + self.append_primitives(first + 1)
    }

    /// Writes wide node `wide` from BVH2 node `node` (a wide node under budget 0), then its
    /// wide children, depth first.
    fn emit(&mut self, wide: usize, node: usize) {
        let aabb = *self.bvh2.nodes[node].aabb();
        let mut out = CwBvhNode { p: aabb.min.into(), ..Default::default() };
        // Child boxes are stored in steps of a power of two per axis, the smallest that
        // spans the node in 255 steps.
        let step = ((aabb.max - aabb.min).max(Vec3A::splat(1e-20)) * QUANT_STEP).log2().ceil().exp2();
        let inverse_step = 1.0 / step;
        let exponent: UVec3 = UVec3::new(step.x.to_bits(), step.y.to_bits(), step.z.to_bits()) >> 23u32;
        out.e = [exponent.x as u8, exponent.y as u8, exponent.z as u8];

        let mut gathered = Vec::with_capacity(WIDTH);
        self.gather(node, 0, &mut gathered);
        let slots = self.order(node, &gathered);
        out.primitive_base_idx = self.primitive_indices.len() as u32;
        out.child_base_idx = self.nodes.len() as u32;
        let (mut wide_children, mut primitives) = (0, 0u32);
        for (i, &child) in slots.iter().enumerate() {
            if child == u32::MAX {
                continue;
            }
            let child_box = self.bvh2.nodes[child as usize].aabb();
            let lo = ((child_box.min - aabb.min) * inverse_step).floor().clamp(Vec3A::ZERO, Vec3A::splat(255.0));
            let hi = ((child_box.max - aabb.min) * inverse_step).ceil().clamp(Vec3A::ZERO, Vec3A::splat(255.0));
            (out.child_min_x[i], out.child_min_y[i], out.child_min_z[i]) = (lo.x as u8, lo.y as u8, lo.z as u8);
            (out.child_max_x[i], out.child_max_y[i], out.child_max_z[i]) = (hi.x as u8, hi.y as u8, hi.z as u8);
            if self.kind(child as usize, 0) == Kind::Leaf {
                let count = self.append_primitives(child as usize);
                debug_assert!((1..=3).contains(&count));
                // The count in unary in the top 3 bits, the offset in the low 5.
                out.child_meta[i] = primitives as u8 | ((1u8 << count) - 1) << 5;
                primitives += count;
            } else {
                out.imask |= 1 << i;
                out.child_meta[i] = (24 + i as u8) | 0b0010_0000;
                wide_children += 1;
            }
        }
        self.nodes.resize(self.nodes.len() + wide_children, CwBvhNode::default());
        self.nodes[wide] = out;
        let mut next = out.child_base_idx as usize;
        for (i, &child) in slots.iter().enumerate() {
            if out.imask & (1 << i) != 0 {
                self.emit(next, child as usize);
                next += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use obvhs::aabb::Aabb;
    use obvhs::ploc::{PlocBuilder, PlocSearchDistance, SortPrecision};

    /// A small deterministic generator (xorshift) for test boxes.
    fn boxes(count: usize, seed: u64) -> Vec<Aabb> {
        let mut state = seed;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..count)
            .map(|_| {
                let lo = Vec3A::new(next(), next(), next()) * 1000.0;
                let size = Vec3A::new(next(), next(), next()) * [1.0f32, 30.0, 0.0][count % 3];
                Aabb::new(lo, lo + size)
            })
            .collect()
    }

    /// The reference is obvhs' own converter: the nodes and primitive lists must be equal,
    /// for every leaf limit, on boxes of random sizes, thin boxes and one box.
    #[test]
    fn converts_exactly_as_obvhs() {
        for (count, seed) in [(1, 1), (2, 2), (9, 3), (100, 4), (1000, 5), (3001, 6), (5000, 7)] {
            let boxes = boxes(count, seed);
            let indices = (0..count as u32).collect();
            let bvh2 = PlocBuilder::with_capacity(count).build(
                PlocSearchDistance::Medium,
                &boxes,
                indices,
                SortPrecision::U64,
                1,
            );
            for max_leaf in 1..=3 {
                let ours = bvh2_to_cwbvh(&bvh2, max_leaf);
                let theirs = obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh(&bvh2, max_leaf, true, false);
                assert_eq!(ours.nodes, theirs.nodes, "{count} boxes, leaves of {max_leaf}");
                assert_eq!(ours.primitive_indices, theirs.primitive_indices, "{count} boxes, leaves of {max_leaf}");
                assert_eq!(ours.total_aabb, theirs.total_aabb);
            }
        }
    }

    #[test]
    fn choices_pack_and_unpack() {
        for kind in [Kind::Leaf, Kind::Wide, Kind::Split] {
            for (l, r) in [(0, 6), (6, 0), (3, 2), (Choice::NONE, Choice::NONE)] {
                let c = Choice::new(kind, l, r);
                assert_eq!((c.kind(), c.left(), c.right()), (kind, usize::from(l), usize::from(r)));
            }
        }
    }
}
