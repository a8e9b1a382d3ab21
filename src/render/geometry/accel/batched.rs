//! The bottom-up build of one large BVH2: coincident primitives grouped, median splits down
//! to PLOC batches, built in parallel and stitched (moved out of `accel/mod.rs` as is).

use super::BvhSpace;
use super::leaves::{LANES as BLOCK_SLOTS, NO_PRIMITIVE};
use glam::{Vec3, Vec3A};
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

/// Subtrees with more primitives than this are split in parallel (`rayon::join`): below it the
/// split is cheaper than handing it over.
const PARALLEL_SPLIT: usize = 4096;

/// A primitive's box centre beside its index: the median splits partition these, contiguous,
/// instead of indices whose centres are read from the boxes (a cache miss per comparison;
/// the splits were a fifth of a 10⁶-triangle build).
#[derive(Clone, Copy)]
struct Centred {
    centre: [f32; 3],
    index: u32,
}

/// The median splits above the PLOC batches: a split of two subtrees, or a batch (a range of
/// the split primitives).
enum Split {
    Node(Box<[Split; 2]>),
    Batch(std::ops::Range<usize>),
}

/// Splits `members` (the primitives `offset..` of the split order) at the median centre
/// along the centres' widest axis until at most [`PLOC_BATCH`] remain, large subtrees in
/// parallel. Each subtree's work depends only on its own members, so the order and the tree
/// are those of a sequential split.
fn split(members: &mut [Centred], offset: usize) -> Split {
    if members.len() <= PLOC_BATCH {
        return Split::Batch(offset..offset + members.len());
    }
    let mut centres = Aabb::empty();
    for m in members.iter() {
        centres.extend(Vec3A::from_array(m.centre));
    }
    let axis = (centres.max - centres.min).max_position();
    let half = members.len() / 2;
    members.select_nth_unstable_by(half, |a, b| a.centre[axis].total_cmp(&b.centre[axis]));
    let big = members.len() > PARALLEL_SPLIT;
    let (left, right) = members.split_at_mut(half);
    let (left, right) = if big {
        rayon::join(|| split(left, offset), || split(right, offset + half))
    } else {
        (split(left, offset), split(right, offset + half))
    };
    Split::Node(Box::new([left, right]))
}

/// A BVH2 over `boxes`: median splits of the centroids along their widest axis down to
/// [`PLOC_BATCH`] primitives, PLOC below. Also returns the largest PLOC batch. The splits are
/// made first (large subtrees in parallel); the batches, independent of each other, are then
/// built in parallel (rayon) and stitched under their split nodes, whose boxes are last made
/// the unions of their children's.
pub(super) fn build_batched(boxes: &[Padded]) -> (Bvh2, usize) {
    use rayon::prelude::*;
    let mut centred: Vec<Centred> =
        boxes.iter().enumerate().map(|(i, b)| Centred { centre: b.0.center().to_array(), index: i as u32 }).collect();
    let tree = split(&mut centred, 0);
    let order: Vec<u32> = centred.iter().map(|c| c.index).collect();
    drop(centred);
    let mut nodes = vec![Bvh2Node::default()];
    // (node slot, range of `order`, depth of the slot) of each batch, in split order.
    let mut batches: Vec<(usize, std::ops::Range<usize>, usize)> = Vec::new();
    // The split nodes' slots: their boxes are filled in once the batches are stitched.
    let mut split_slots: Vec<usize> = Vec::new();
    let mut todo = vec![(0usize, &tree, 0usize)];
    while let Some((slot, node, depth)) = todo.pop() {
        let children = match node {
            Split::Batch(range) => {
                batches.push((slot, range.clone(), depth));
                continue;
            }
            Split::Node(children) => children,
        };
        let left = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[slot] = Bvh2Node::new(Aabb::empty(), 0, left as u32);
        split_slots.push(slot);
        todo.push((left, &children[0], depth + 1));
        todo.push((left + 1, &children[1], depth + 1));
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
    // A split node's children have larger slots than it: children before parents.
    split_slots.sort_unstable();
    for &slot in split_slots.iter().rev() {
        let first = nodes[slot].first_index as usize;
        let bounds = nodes[first].aabb().union(nodes[first + 1].aabb());
        nodes[slot].set_aabb(bounds);
    }
    (Bvh2 { nodes, primitive_indices, max_depth, ..Default::default() }, largest)
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

/// A primitive's padded box bits, its index and, first, the low half of its hash, then the
/// index of the first primitive with the same box: what a partition of the grouping holds.
#[derive(Clone, Copy)]
struct Keyed {
    key: [u32; 6],
    index: u32,
    aux: u32,
}

/// A hash of a box's bits (a folded 128-bit multiply, as wyhash's): the grouping's
/// partitions take the top bits, their tables the low half.
fn box_hash(key: &[u32; 6]) -> u64 {
    let word = |i: usize| u64::from(key[2 * i]) | u64::from(key[2 * i + 1]) << 32;
    let fold = |a: u64, b: u64| {
        let p = u128::from(a) * u128::from(b);
        p as u64 ^ (p >> 64) as u64
    };
    fold(fold(word(0) ^ 0xa076_1d64_78bd_642f, word(1) ^ 0xe703_7ed1_a0b4_28db) ^ word(2), 0x8ebc_6af0_9c88_c6e3)
}

/// The hash a partition's table uses: the low half of [`box_hash`] (the top bits chose the
/// partition), spread over 64 bits.
fn table_hash(aux: u32) -> u64 {
    u64::from(aux) | u64::from(aux) << 32
}

/// Primitives per grouping partition, about: a partition's table (5 bytes a slot) and its
/// keyed boxes stay in the cache.
const GROUPING_PARTITION: usize = 4096;

/// For each of `bounds`' primitives, the first primitive with a bit-identical padded box
/// (itself when it is the first; `u32::MAX` when its box is not finite). The boxes are
/// partitioned by hash and each partition grouped on its own (in parallel), with a table
/// that stays in the cache: one table over 10⁶ boxes missed the cache at every look-up,
/// a fifth of a 10⁶-triangle build.
fn first_with_same_box(bounds: impl Iterator<Item = (Vec3, Vec3)> + Clone, count: usize) -> Vec<u32> {
    use rayon::prelude::*;
    // `count` indexes the result, and every walk of `bounds` must yield the same boxes.
    debug_assert_eq!(bounds.clone().count(), count, "the bounds and the primitive count disagree");
    let bits = (count / GROUPING_PARTITION).max(1).ilog2().min(12);
    let partition_of = |hash: u64| if bits == 0 { 0 } else { (hash >> (64 - bits)) as usize };
    let keys = || bounds.clone().map(|(lo, hi)| padded_box(lo, hi)).enumerate();
    // A counting sort into partitions, each in primitive order; the keys are computed twice
    // rather than held (24 bytes a primitive at the build's peak).
    let mut start = vec![0usize; (1 << bits) + 1];
    for (_, key) in keys() {
        if let Some(key) = key {
            start[partition_of(box_hash(&key)) + 1] += 1;
        }
    }
    for p in 0..1 << bits {
        start[p + 1] += start[p];
    }
    let mut keyed = vec![Keyed { key: [0; 6], index: 0, aux: 0 }; start[1 << bits]];
    let mut next = start.clone();
    for (index, key) in keys() {
        if let Some(key) = key {
            let hash = box_hash(&key);
            let slot = &mut next[partition_of(hash)];
            keyed[*slot] = Keyed { key, index: index as u32, aux: hash as u32 };
            *slot += 1;
        }
    }
    drop(next);
    let mut partitions = Vec::with_capacity(1 << bits);
    let mut rest = keyed.as_mut_slice();
    for p in 0..1 << bits {
        let (part, tail) = rest.split_at_mut(start[p + 1] - start[p]);
        partitions.push(part);
        rest = tail;
    }
    partitions.into_par_iter().for_each(|part| {
        // Positions in the partition, looked up by their boxes; the first of each box stays.
        let mut table: hashbrown::HashTable<u32> = hashbrown::HashTable::with_capacity(part.len());
        let firsts: Vec<u32> = part
            .iter()
            .enumerate()
            .map(|(pos, k)| {
                let hash = table_hash(k.aux);
                match table.find(hash, |&q| part[q as usize].key == k.key) {
                    Some(&q) => part[q as usize].index,
                    None => {
                        table.insert_unique(hash, pos as u32, |&q| table_hash(part[q as usize].aux));
                        k.index
                    }
                }
            })
            .collect();
        for (k, first) in part.iter_mut().zip(firsts) {
            k.aux = first;
        }
    });
    let mut first = vec![u32::MAX; count];
    for k in &keyed {
        first[k.index as usize] = k.aux;
    }
    first
}

/// A BVH over `bounds` (`(min, max)` per primitive), grouping bit-identical boxes; returns
/// the BVH (`None` when no box is finite), its leaves ranges of the returned primitive
/// indices (the groups' members in leaf order).
pub(super) fn build_grouped(
    bounds: impl Iterator<Item = (Vec3, Vec3)> + Clone,
    count: usize,
) -> (Option<BvhSpace>, Vec<u32>) {
    // Primitives with bit-identical boxes (copies of one mesh at one place) become one BVH
    // primitive: PLOC merges only mutually-nearest pairs, and among n equal boxes every
    // pass merges one pair, so n coincident copies cost O(n²) to build. Groups are numbered
    // in the order of their first primitives.
    let mut group_of_primitive = first_with_same_box(bounds.clone(), count);
    // Allocated once at its size: a growing table copies itself and, where the allocator
    // keeps freed blocks (see `main`'s mmap threshold), leaves its smaller copies resident.
    let groups = group_of_primitive.iter().zip(0u32..).filter(|&(&first, index)| first == index).count();
    let mut boxes: Vec<Padded> = Vec::with_capacity(groups);
    for ((lo, hi), index) in bounds.zip(0u32..) {
        let first = group_of_primitive[index as usize];
        group_of_primitive[index as usize] = if first == u32::MAX {
            u32::MAX
        } else if first == index {
            let key = padded_box(lo, hi);
            debug_assert!(key.is_some(), "a group's first primitive has a finite box (the walks disagree)");
            let [lx, ly, lz, hx, hy, hz] = key.map_or([0.0; 6], |key| key.map(f32::from_bits));
            boxes.push(Padded(Aabb::new(Vec3A::new(lx, ly, lz), Vec3A::new(hx, hy, hz))));
            boxes.len() as u32 - 1
        } else {
            // The first primitive with this box came before: its group is numbered.
            group_of_primitive[first as usize]
        };
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
    // The per-primitive groups are freed before the BVH is built (build peak memory).
    drop((next, group_of_primitive));
    let Some(mut space) = BvhSpace::build(boxes) else { return (None, group_members) };
    // The groups in leaf order (obvhs' primitive ids); the id-to-group table is then unused.
    let leaf_order = std::mem::take(&mut space.primitive_indices);
    // Each leaf's groups are adjacent in leaf order: the leaf becomes its members' range,
    // `members_of[first]` for the leaf whose first primitive is `first`. A leaf of at most
    // one block's triangles that would straddle two blocks starts at the next block instead
    // (the slots between hold no triangle and lie in no leaf), so it is tested in one pass.
    let mut leaves: Vec<(u32, u32)> = space.bvh.leaves().collect();
    leaves.sort_unstable();
    let mut members_of = vec![(0u32, 0u32); leaf_order.len()];
    let mut leaf_members = Vec::with_capacity(group_members.len());
    for (first, count) in leaves {
        let groups = &leaf_order[first as usize..(first + count) as usize];
        let size = |&g: &u32| (group_start[g as usize + 1] - group_start[g as usize]) as usize;
        let members: usize = groups.iter().map(size).sum();
        let at = leaf_members.len();
        if (1..=BLOCK_SLOTS).contains(&members) && at / BLOCK_SLOTS != (at + members - 1) / BLOCK_SLOTS {
            leaf_members.resize(at.next_multiple_of(BLOCK_SLOTS), NO_PRIMITIVE);
        }
        members_of[first as usize] = (leaf_members.len() as u32, members as u32);
        for &g in groups {
            let g = g as usize;
            leaf_members.extend_from_slice(&group_members[group_start[g] as usize..group_start[g + 1] as usize]);
        }
    }
    space.bvh.remap_leaves(|first, _| members_of[first as usize]);
    (Some(space), leaf_members)
}

/// A box as the BVH builder sees it.
pub(super) struct Padded(pub(super) Aabb);

impl Boundable for Padded {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// The partitioned grouping against a plain map from each padded box to the first
    /// primitive with it: boxes drawn with repeats from 20 000 (several partitions), and
    /// non-finite boxes, which are in no group.
    #[test]
    fn groups_as_a_map_of_first_primitives_does() {
        let mut next = crate::render::geometry::accel::generator(11);
        let distinct: Vec<(Vec3, Vec3)> = (0..20_000)
            .map(|_| {
                let lo = Vec3::new(next(), next(), next()) * 100.0;
                (lo, lo + Vec3::new(next().abs(), next().abs(), 0.0))
            })
            .collect();
        let mut bounds: Vec<(Vec3, Vec3)> =
            (0..60_000).map(|_| distinct[((next() + 1.0) * 0.5 * 19_999.0) as usize]).collect();
        bounds[7] = (Vec3::splat(f32::NAN), Vec3::ONE);
        bounds[9] = (Vec3::ZERO, Vec3::splat(f32::INFINITY));
        let first = first_with_same_box(bounds.iter().copied(), bounds.len());
        let mut seen: HashMap<[u32; 6], u32> = HashMap::new();
        for (i, &(lo, hi)) in bounds.iter().enumerate() {
            let want = padded_box(lo, hi).map_or(u32::MAX, |key| *seen.entry(key).or_insert(i as u32));
            assert_eq!(first[i], want, "primitive {i}");
        }
        assert!((10_000..20_000).contains(&seen.len()), "{} distinct boxes drawn", seen.len());
    }

    /// The build is the same tree whatever the thread count: the splits and the grouping
    /// run in parallel, but each subtree and partition depends only on its own members.
    #[test]
    fn one_thread_and_four_build_the_same_tree() {
        let mut next = crate::render::geometry::accel::generator(3);
        let bounds: Vec<(Vec3, Vec3)> = (0..4 * PARALLEL_SPLIT.max(PLOC_BATCH))
            .map(|_| {
                let lo = Vec3::new(next(), next(), next()) * 50.0;
                (lo, lo + Vec3::new(next().abs(), next().abs(), next().abs()))
            })
            .collect();
        let build = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
            pool.install(|| {
                let first = first_with_same_box(bounds.iter().copied(), bounds.len());
                let boxes: Vec<Padded> =
                    bounds.iter().map(|&(lo, hi)| Padded(Aabb::new(Vec3A::from(lo), Vec3A::from(hi)))).collect();
                let (bvh, largest) = build_batched(&boxes);
                (first, format!("{:?} {:?}", bvh.nodes, bvh.primitive_indices), largest)
            })
        };
        assert!(build(1) == build(4), "the tree depends on the thread count");
    }
}
