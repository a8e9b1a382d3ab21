//! Grouping of primitives whose padded boxes are bit-identical (copies of one mesh at one
//! place), which become one BVH primitive: PLOC merges only mutually-nearest pairs, and
//! among n equal boxes every pass merges one pair, so n coincident copies cost O(n²) to build.

use super::batched::Padded;
use super::padded_box;
use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;

/// "Not in any group": a primitive whose box is not finite.
pub(super) const NO_GROUP: u32 = u32::MAX;

/// The groups' boxes, numbered by their first primitive, and each primitive's group
/// ([`NO_GROUP`] when its box is not finite), for `bounds` (`(min, max)` per primitive,
/// `count` of them).
///
/// Found by sorting primitive indices by their boxes' bits, in place of a hash map keyed by
/// box: the map was the build's largest allocation (62 bytes per primitive at a million,
/// its buckets rounded up to a power of two), this holds 40 (the boxes, which the BVH is
/// built from anyway, and two index tables).
pub(super) fn group_identical(bounds: impl Iterator<Item = (Vec3, Vec3)>, count: usize) -> (Vec<Padded>, Vec<u32>) {
    let bits = |b: &Padded| {
        let (lo, hi) = (b.0.min, b.0.max);
        [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z].map(f32::to_bits)
    };
    // One box per primitive first (a placeholder where it is not finite), so a primitive's
    // index is its box's, and `group_of` maps both.
    let mut boxes: Vec<Padded> = Vec::with_capacity(count);
    let mut group_of: Vec<u32> = Vec::with_capacity(count);
    for (lo, hi) in bounds {
        let key = padded_box(lo, hi);
        group_of.push(if key.is_some() { boxes.len() as u32 } else { NO_GROUP });
        let [lx, ly, lz, hx, hy, hz] = key.unwrap_or_default().map(f32::from_bits);
        boxes.push(Padded(Aabb::new(Vec3A::new(lx, ly, lz), Vec3A::new(hx, hy, hz))));
    }
    // Equal boxes become adjacent, each run led by its lowest index.
    let mut order: Vec<u32> = (0..boxes.len() as u32).filter(|&i| group_of[i as usize] != NO_GROUP).collect();
    order.sort_unstable_by(|&a, &b| bits(&boxes[a as usize]).cmp(&bits(&boxes[b as usize])).then(a.cmp(&b)));
    for run in order.chunk_by(|&a, &b| bits(&boxes[a as usize]) == bits(&boxes[b as usize])) {
        for &i in run {
            group_of[i as usize] = run[0];
        }
    }
    drop(order);
    // Groups numbered in order of their first primitive; a group's box moves down to its
    // number (never above the index it is read from).
    let mut groups = 0u32;
    for i in 0..group_of.len() {
        let leader = group_of[i];
        if leader == NO_GROUP {
            continue;
        }
        if leader as usize == i {
            boxes.swap(groups as usize, i);
            group_of[i] = groups;
            groups += 1;
        } else {
            group_of[i] = group_of[leader as usize];
        }
    }
    boxes.truncate(groups as usize);
    boxes.shrink_to_fit();
    (boxes, group_of)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// The groups are those of a hash map keyed by the padded box's bits, numbered by first
    /// occurrence (what the BVH was built from before), on boxes with many repeats and some
    /// non-finite ones.
    #[test]
    fn groups_as_a_map_by_first_occurrence() {
        let mut state = 0x9e37_79b9_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let bounds: Vec<(Vec3, Vec3)> = (0..5000)
            .map(|_| {
                let k = (next() % 700) as f32;
                match next() % 50 {
                    0 => (Vec3::splat(f32::NAN), Vec3::ONE),
                    1 => (Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 0.0)),
                    _ => (Vec3::new(k, -k, 0.5 * k), Vec3::new(k + 1.0, 2.0, k * k)),
                }
            })
            .collect();
        let (boxes, group_of) = group_identical(bounds.iter().copied(), bounds.len());
        let mut map: HashMap<[u32; 6], u32> = HashMap::new();
        let mut want_boxes = Vec::new();
        for (i, &(lo, hi)) in bounds.iter().enumerate() {
            let want = padded_box(lo, hi).map(|key| {
                *map.entry(key).or_insert_with(|| {
                    want_boxes.push(key);
                    want_boxes.len() as u32 - 1
                })
            });
            assert_eq!(group_of[i], want.unwrap_or(NO_GROUP), "{i}");
        }
        let got: Vec<[u32; 6]> = boxes
            .iter()
            .map(|b| [b.0.min.x, b.0.min.y, b.0.min.z, b.0.max.x, b.0.max.y, b.0.max.z].map(f32::to_bits))
            .collect();
        assert_eq!(got, want_boxes);
        assert!(want_boxes.len() > 100 && want_boxes.len() < 1000, "repeats and distinct boxes both");
    }
}
