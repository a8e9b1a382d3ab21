//! The bottom-up build of one large BVH2: median splits down to PLOC batches, built in
//! parallel and stitched (moved out of `accel/mod.rs` as is).

use obvhs::Boundable;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::ploc::{PlocBuilder, PlocSearchDistance, SortPrecision};

/// The most primitives one PLOC build is given. PLOC merges only mutually nearest
/// neighbours, and where the merge cost grows steadily along the sorted order (the thin
/// triangles of a fan around one vertex) a pass merges one pair per run: n primitives cost
/// O(n²) (a vertex with 10⁵ neighbours took 23 s). Larger inputs are split top-down at the
/// median centroid into batches of at most this many, each built by PLOC, so the build is
/// O(n log n) whatever the geometry.
pub const PLOC_BATCH: usize = 128;

/// How many PLOC batches are built in parallel before they are stitched into the tree.
const PARALLEL_BATCHES: usize = 256;

/// A BVH2 over `boxes`: median splits of the centroids along their widest axis down to
/// [`PLOC_BATCH`] primitives, PLOC below. Also returns the largest PLOC batch. The splits are
/// made first; the batches, independent of each other, are then built in parallel (rayon)
/// and stitched under their split nodes.
pub(super) fn build_batched(boxes: &[Padded]) -> (Bvh2, usize) {
    use rayon::prelude::*;
    let mut nodes = vec![Bvh2Node::default()];
    let mut order: Vec<u32> = (0..boxes.len() as u32).collect();
    // (node slot, range of `order`, depth of the slot) of each batch, in split order.
    let mut batches: Vec<(usize, std::ops::Range<usize>, usize)> = Vec::new();
    let mut todo = vec![(0usize, 0..order.len(), 0usize)];
    while let Some((slot, range, depth)) = todo.pop() {
        let members = &mut order[range.clone()];
        if members.len() <= PLOC_BATCH {
            batches.push((slot, range, depth));
            continue;
        }
        let mut bounds = Aabb::empty();
        let mut centres = Aabb::empty();
        for &i in members.iter() {
            let b = boxes[i as usize].0;
            bounds = bounds.union(&b);
            centres.extend(b.center());
        }
        let axis = (centres.max - centres.min).max_position();
        let half = members.len() / 2;
        members.select_nth_unstable_by(half, |&a, &b| {
            let (a, b) = (boxes[a as usize].0.center_axis(axis), boxes[b as usize].0.center_axis(axis));
            a.total_cmp(&b)
        });
        let left = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[slot] = Bvh2Node::new(bounds, 0, left as u32);
        todo.push((left, range.start..range.start + half, depth + 1));
        todo.push((left + 1, range.start + half..range.end, depth + 1));
    }
    // One primitive per PLOC leaf: the tree has exactly 2n − 1 nodes, allocated once.
    nodes.reserve_exact((2 * boxes.len()).saturating_sub(1 + nodes.len()));
    let mut primitive_indices: Vec<u32> = Vec::with_capacity(boxes.len());
    let mut largest = 0;
    // The traversal stacks obvhs sizes from it must hold the whole depth.
    let mut max_depth = 0;
    // The batches are built in parallel a window at a time and stitched as each window ends,
    // so the built-but-unstitched trees are a few MB, not a copy of the whole tree.
    let built = batches.chunks(PARALLEL_BATCHES).flat_map(|window| {
        let trees: Vec<Bvh2> = window
            .par_iter()
            .map_init(
                || PlocBuilder::with_capacity(PLOC_BATCH),
                |builder, (_, range, _)| {
                    let batch: Vec<Padded> =
                        order[range.clone()].iter().map(|&i| Padded(boxes[i as usize].0)).collect();
                    let indices = (0..batch.len() as u32).collect();
                    builder.build(PlocSearchDistance::Medium, &batch, indices, SortPrecision::U64, 3)
                },
            )
            .collect();
        window.iter().cloned().zip(trees)
    });
    for ((slot, range, depth), sub) in built {
        let members = &order[range];
        largest = largest.max(members.len());
        // The batch's root goes to `slot`, its other nodes after the nodes so far (sibling
        // pairs stay adjacent); its leaves index the shared primitive list.
        max_depth = max_depth.max(depth + sub.max_depth);
        let base = nodes.len() as u32;
        let prim_base = primitive_indices.len() as u32;
        let place = |j: u32| if j == 0 { slot as u32 } else { base + j - 1 };
        primitive_indices.extend(sub.primitive_indices.iter().map(|&p| members[p as usize]));
        let mut moved = sub.nodes.iter().map(|n| {
            let first = if n.is_leaf() { prim_base + n.first_index } else { place(n.first_index) };
            Bvh2Node::new(*n.aabb(), n.prim_count, first)
        });
        if let Some(root) = moved.next() {
            nodes[slot] = root;
        }
        nodes.extend(moved);
    }
    (Bvh2 { nodes, primitive_indices, max_depth, ..Default::default() }, largest)
}

/// A box as the BVH builder sees it.
pub(super) struct Padded(pub(super) Aabb);

impl Boundable for Padded {
    fn aabb(&self) -> Aabb {
        self.0
    }
}
