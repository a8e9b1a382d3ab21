//! The triangle test, and the triangles in the BVH's leaf order, tested 8 at a time.
//!
//! A BLAS keeps its triangles' positions once, as [`LeafTriangles`]: the slots of
//! `group_members` (the BVH's leaf order, so a leaf is a range of slots) grouped by 8 into
//! [`Block`]s, each 9 rows of 8 lanes (x, y, z of each corner), as Embree's 8-wide leaves. A
//! leaf's triangles are then adjacent, and one AVX2 pass (chosen at run time) runs the
//! watertight test on all 8 lanes of a block. A leaf of at most 8 triangles is placed so that it
//! lies in one block (the BVH build pads before it); a larger one takes several passes.
//! The AVX2 test does the scalar test's f32 operations in the same order (no FMA), so each
//! lane's hit and `(t, b1, b2)` are bit-identical to [`RayPre::intersect`] on that triangle.
//! `slot_of` maps a triangle's own index (as in `Hit::index`) to its slot, for the hit's
//! surface and the light sampler.

use super::gamma;
use glam::Vec3;

/// The axis of `d`'s largest component (the first of equals, from the last): the watertight
/// test shears along it.
#[inline]
pub(super) fn dominant_axis(d: Vec3) -> usize {
    let a = d.abs();
    if a.x > a.y {
        if a.x > a.z { 0 } else { 2 }
    } else if a.y > a.z {
        1
    } else {
        2
    }
}

/// Per-ray precomputation of the watertight test (pbrt-v4's, after Woop, Benthin & Wald
/// 2013) for a ray whose largest direction component is axis `KZ` ([`dominant_axis`]): the
/// permutation that makes that component z is in the type, so the test reads each vertex's
/// coordinates directly, and the shear that maps the ray to +z is stored. The test runs in
/// f32 on the compact positions; its rounding is bounded (see [`RayPre::intersect`]) so a
/// hit is never reported behind the origin, and hit points carry an error bound that
/// [`super::offset_ray_origin`] moves past.
pub(super) struct RayPre<const KZ: usize> {
    o: Vec3,
    /// `(−dx/dz, −dy/dz, 1/dz)` in the permuted axes.
    s: Vec3,
}

impl<const KZ: usize> RayPre<KZ> {
    /// The permuted x and y axes: the two after `KZ`, cyclically (so the permutation keeps
    /// the handedness).
    const KX: usize = (KZ + 1) % 3;
    const KY: usize = (KZ + 2) % 3;

    #[inline(always)]
    pub(super) fn new(o: Vec3, d: Vec3) -> RayPre<KZ> {
        let s = Vec3::new(-d[Self::KX] / d[KZ], -d[Self::KY] / d[KZ], 1.0 / d[KZ]);
        RayPre { o, s }
    }

    /// `(t, b1, b2)` of a hit with `t` in `(tmin, tmax)`. Inlined into the traversal's leaf
    /// loop: a call per triangle test spilled the sheared ray around it.
    #[inline(always)]
    pub(super) fn intersect(&self, p: &[Vec3; 3], tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        // Translate to the ray origin, permute, shear.
        let shear = |v: Vec3| {
            let v = v - self.o;
            let z = v[KZ];
            (v[Self::KX] + self.s.x * z, v[Self::KY] + self.s.y * z, z)
        };
        let (x0, y0, z0) = shear(p[0]);
        let (x1, y1, z1) = shear(p[1]);
        let (x2, y2, z2) = shear(p[2]);
        // Edge functions; an exact zero may be a rounding artefact on an edge, so it is
        // decided in f64 (where the products of f32 values are exact).
        let (mut e0, mut e1, mut e2) = (x1 * y2 - y1 * x2, x2 * y0 - y2 * x0, x0 * y1 - y0 * x1);
        if e0 == 0.0 || e1 == 0.0 || e2 == 0.0 {
            e0 = edge_f64(x1, y2, y1, x2);
            e1 = edge_f64(x2, y0, y2, x0);
            e2 = edge_f64(x0, y1, y0, x1);
        }
        if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
            return None;
        }
        let det = e0 + e1 + e2;
        if det == 0.0 {
            return None;
        }
        let (z0, z1, z2) = (z0 * self.s.z, z1 * self.s.z, z2 * self.s.z);
        let t_scaled = e0 * z0 + e1 * z1 + e2 * z2;
        // Range test before the division: t in (0, tmax).
        if det < 0.0 && (t_scaled >= 0.0 || t_scaled < tmax * det) {
            return None;
        }
        if det > 0.0 && (t_scaled <= 0.0 || t_scaled > tmax * det) {
            return None;
        }
        let inv = 1.0 / det;
        let t = t_scaled * inv;
        // A conservative bound on t's rounding error (pbrt-v4, "Conservative Ray–Bounds
        // Intersections"): a t within it of zero may really be behind the origin — a ray
        // leaving the surface that re-hits it — so it is no hit.
        let max_z = z0.abs().max(z1.abs()).max(z2.abs());
        let max_x = x0.abs().max(x1.abs()).max(x2.abs());
        let max_y = y0.abs().max(y1.abs()).max(y2.abs());
        let delta_z = gamma(3) * max_z;
        let delta_x = gamma(5) * (max_x + max_z);
        let delta_y = gamma(5) * (max_y + max_z);
        let delta_e = 2.0 * (gamma(2) * max_x * max_y + delta_y * max_x + delta_x * max_y);
        let max_e = e0.abs().max(e1.abs()).max(e2.abs());
        let delta_t = 3.0 * (gamma(3) * max_e * max_z + delta_e * max_z + delta_z * max_e) * inv.abs();
        if t <= delta_t || t <= tmin || t >= tmax {
            return None;
        }
        Some((t, e1 * inv, e2 * inv))
    }
}

/// `a·b − c·e` in f64, where the products of f32 values are exact, rounded to f32: an edge
/// function that f32 rounded to exactly zero, decided again.
#[inline(always)]
fn edge_f64(a: f32, b: f32, c: f32, e: f32) -> f32 {
    (a as f64 * b as f64 - c as f64 * e as f64) as f32
}

/// Triangles per [`Block`]: the lanes of an AVX2 register.
pub(super) const LANES: usize = 8;

/// The primitive of a slot that holds none: the padding that makes a leaf start at the next
/// block rather than straddle two (`batched::build_grouped`). It lies in no leaf, and holds
/// the empty triangle.
pub(super) const NO_PRIMITIVE: u32 = u32::MAX;

/// Rows of a [`Block`]: corner 0's x, y, z, corner 1's, corner 2's.
const ROWS: usize = 9;

/// 8 consecutive slots' triangles, structure of arrays. A slot that holds no triangle (a
/// shape's, or past the last) holds three corners at the origin, which the test never hits
/// (all three edge functions are exactly zero, so the determinant is).
#[derive(Clone, Copy)]
#[repr(C, align(32))]
struct Block {
    rows: [[f32; LANES]; ROWS],
}

impl Block {
    /// The triangle in lane `l`.
    #[inline(always)]
    fn triangle(&self, l: usize) -> [Vec3; 3] {
        let r = &self.rows;
        [0, 1, 2].map(|c| Vec3::new(r[3 * c][l], r[3 * c + 1][l], r[3 * c + 2][l]))
    }
}

/// What a block test found: a bit per lane hit, and each hit lane's `(t, b1, b2)`.
#[derive(Clone, Copy, Debug)]
struct LaneHits {
    mask: u32,
    t: [f32; LANES],
    b1: [f32; LANES],
    b2: [f32; LANES],
}

/// A BLAS's triangle positions in leaf order (see the module documentation).
pub(super) struct LeafTriangles {
    blocks: Vec<Block>,
    /// Each triangle's slot, by its own index; `u32::MAX` for one in no leaf (non-finite).
    slot_of: Vec<u32>,
}

impl LeafTriangles {
    /// `positions` (by triangle index) placed in the slots of `members` (a triangle index
    /// per slot; an index past `positions` is a shape's slot).
    pub(super) fn new(positions: &[[Vec3; 3]], members: &[u32]) -> LeafTriangles {
        let empty = Block { rows: [[0.0; LANES]; ROWS] };
        let mut blocks = vec![empty; members.len().div_ceil(LANES)];
        let mut slot_of = vec![u32::MAX; positions.len()];
        for (slot, &i) in members.iter().enumerate() {
            let Some(p) = positions.get(i as usize) else { continue };
            let (block, lane) = (&mut blocks[slot / LANES], slot % LANES);
            for (c, corner) in p.iter().enumerate() {
                for axis in 0..3 {
                    block.rows[3 * c + axis][lane] = corner[axis];
                }
            }
            slot_of[i as usize] = slot as u32;
        }
        LeafTriangles { blocks, slot_of }
    }

    /// Number of triangles (in leaves or not).
    pub(super) fn len(&self) -> usize {
        self.slot_of.len()
    }

    /// The triangle in `slot`.
    #[inline(always)]
    pub(super) fn at_slot(&self, slot: usize) -> [Vec3; 3] {
        self.blocks[slot / LANES].triangle(slot % LANES)
    }

    /// Triangle `i`'s corners (by its own index); NaN for a triangle in no leaf (one with a
    /// non-finite corner, whose position was not kept). `None` past the last triangle.
    #[inline]
    pub(super) fn triangle(&self, i: usize) -> Option<[Vec3; 3]> {
        let slot = *self.slot_of.get(i)?;
        Some(if slot == u32::MAX { [Vec3::NAN; 3] } else { self.at_slot(slot as usize) })
    }

    /// Bytes held.
    pub(super) fn bytes(&self) -> usize {
        self.blocks.len() * std::mem::size_of::<Block>() + self.slot_of.len() * 4
    }

    /// The closest hit `(slot, t, b1, b2)` among the triangles in slots `first..first +
    /// count` with `t` in `(tmin, tmax)`; the lowest slot among equal distances, as a test
    /// slot by slot would find. By AVX2 when `AVX2`, which is true only on a path that found
    /// the CPU has it, in code compiled for AVX2: the leaf loop and the block test then inline
    /// into it.
    #[inline(always)]
    pub(super) fn closest<const KZ: usize, const AVX2: bool>(
        &self,
        pre: &RayPre<KZ>,
        first: u32,
        count: u32,
        tmin: f32,
        tmax: f32,
    ) -> Option<(u32, f32, f32, f32)> {
        let mut best = None;
        let mut closest = tmax;
        for (k, lanes) in blocks_of(first, count) {
            let found = self.block_hits::<KZ, AVX2>(k, pre, lanes, tmin, closest);
            let mut mask = found.mask;
            while mask != 0 {
                let l = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if found.t[l] < closest {
                    closest = found.t[l];
                    best = Some(((k * LANES + l) as u32, found.t[l], found.b1[l], found.b2[l]));
                }
            }
        }
        best
    }

    /// Whether any triangle in slots `first..first + count` is hit with `t` in `(tmin, tmax)`
    /// (by AVX2 when `AVX2`, as [`LeafTriangles::closest`]).
    #[inline(always)]
    pub(super) fn any<const KZ: usize, const AVX2: bool>(
        &self,
        pre: &RayPre<KZ>,
        first: u32,
        count: u32,
        tmin: f32,
        tmax: f32,
    ) -> bool {
        // A loop, not `Iterator::any`: a closure would be compiled without AVX2 (see `avx2`).
        for (k, lanes) in blocks_of(first, count) {
            if self.block_hits::<KZ, AVX2>(k, pre, lanes, tmin, tmax).mask != 0 {
                return true;
            }
        }
        false
    }

    /// Block `k`'s lanes of `lanes` that the ray hits within `(tmin, tmax)`, by AVX2 when
    /// `AVX2` (see [`LeafTriangles::closest`]).
    #[inline(always)]
    fn block_hits<const KZ: usize, const AVX2: bool>(
        &self,
        k: usize,
        pre: &RayPre<KZ>,
        lanes: u32,
        tmin: f32,
        tmax: f32,
    ) -> LaneHits {
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: `AVX2` is true only where the CPU has AVX2.
            return unsafe { avx2::block_hits(&self.blocks[k], pre, lanes, tmin, tmax) };
        }
        scalar_block_hits(&self.blocks[k], pre, lanes, tmin, tmax)
    }
}

/// The blocks that slots `first..first + count` lie in, each with a bit per lane in range.
#[inline(always)]
fn blocks_of(first: u32, count: u32) -> impl Iterator<Item = (usize, u32)> {
    let (first, end) = (first as usize, first as usize + count as usize);
    (first / LANES..end.div_ceil(LANES)).map(move |k| {
        let lo = first.max(k * LANES) - k * LANES;
        let hi = end.min(k * LANES + LANES) - k * LANES;
        (k, (1u32 << hi) - (1u32 << lo))
    })
}

/// The lanes of `lanes` whose triangle the ray hits within `(tmin, tmax)` (other lanes'
/// bits are clear), lane by lane with [`RayPre::intersect`].
#[inline(always)]
fn scalar_block_hits<const KZ: usize>(block: &Block, pre: &RayPre<KZ>, lanes: u32, tmin: f32, tmax: f32) -> LaneHits {
    let mut hits = LaneHits { mask: 0, t: [0.0; LANES], b1: [0.0; LANES], b2: [0.0; LANES] };
    let mut todo = lanes;
    while todo != 0 {
        let l = todo.trailing_zeros() as usize;
        todo &= todo - 1;
        if let Some((t, b1, b2)) = pre.intersect(&block.triangle(l), tmin, tmax) {
            hits.mask |= 1 << l;
            (hits.t[l], hits.b1[l], hits.b2[l]) = (t, b1, b2);
        }
    }
    hits
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Block, LANES, LaneHits, RayPre, edge_f64, gamma};
    use std::arch::x86_64::*;

    /// [`super::scalar_block_hits`] on 8 lanes: [`RayPre::intersect`]'s operations in its
    /// order, its early returns as lane masks.
    ///
    /// `#[inline(always)]` and not `#[target_feature]` (rustc rejects the two together), and
    /// written without closures (a closure here would be compiled without AVX2 and keep the
    /// intrinsics out of line): it inlines into its caller, and its intrinsics inline with it
    /// where that caller is compiled for AVX2 (`Blas::intersect_avx2`, `occluded_avx2`), so a
    /// leaf's blocks are tested with no call and their lanes stay in registers.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    pub(super) unsafe fn block_hits<const KZ: usize>(
        block: &Block,
        pre: &RayPre<KZ>,
        lanes: u32,
        tmin: f32,
        tmax: f32,
    ) -> LaneHits {
        let (kx, ky) = (RayPre::<KZ>::KX, RayPre::<KZ>::KY);
        // SAFETY: the caller's: the CPU has AVX2. Each row is 8 f32, 32-byte aligned
        // (`Block`'s alignment); each store's destination holds 8 f32.
        unsafe {
            macro_rules! splat {
                ($x:expr) => {
                    _mm256_set1_ps($x)
                };
            }
            macro_rules! row {
                ($r:expr) => {
                    _mm256_load_ps(block.rows[$r].as_ptr())
                };
            }
            let (ox, oy, oz) = (splat!(pre.o[kx]), splat!(pre.o[ky]), splat!(pre.o[KZ]));
            let (sx, sy, sz) = (splat!(pre.s.x), splat!(pre.s.y), splat!(pre.s.z));
            // Translate to the ray origin, permute, shear.
            macro_rules! shear {
                ($c:expr) => {{
                    let z = _mm256_sub_ps(row!(3 * $c + KZ), oz);
                    let x = _mm256_add_ps(_mm256_sub_ps(row!(3 * $c + kx), ox), _mm256_mul_ps(sx, z));
                    let y = _mm256_add_ps(_mm256_sub_ps(row!(3 * $c + ky), oy), _mm256_mul_ps(sy, z));
                    (x, y, z)
                }};
            }
            let (x0, y0, z0) = shear!(0);
            let (x1, y1, z1) = shear!(1);
            let (x2, y2, z2) = shear!(2);
            macro_rules! edge {
                ($a:expr, $b:expr, $c:expr, $e:expr) => {
                    _mm256_sub_ps(_mm256_mul_ps($a, $b), _mm256_mul_ps($c, $e))
                };
            }
            let (mut e0, mut e1, mut e2) = (edge!(x1, y2, y1, x2), edge!(x2, y0, y2, x0), edge!(x0, y1, y0, x1));
            let zero = _mm256_setzero_ps();
            macro_rules! or {
                ($a:expr, $b:expr) => {
                    _mm256_or_ps($a, $b)
                };
            }
            macro_rules! cmp {
                ($op:ident, $a:expr, $b:expr) => {
                    _mm256_cmp_ps::<$op>($a, $b)
                };
            }
            let on_edge = or!(or!(cmp!(_CMP_EQ_OQ, e0, zero), cmp!(_CMP_EQ_OQ, e1, zero)), cmp!(_CMP_EQ_OQ, e2, zero));
            let mut redo = _mm256_movemask_ps(on_edge) as u32 & lanes;
            if redo != 0 {
                // A triangle with two equal corners (a mesh's pole) has an exactly zero edge
                // function on every ray, and its other two are exact negatives, so its
                // determinant is zero in f32 as in f64: it needs no redo, only the rejection.
                macro_rules! same {
                    ($xa:expr, $ya:expr, $xb:expr, $yb:expr) => {
                        _mm256_and_ps(cmp!(_CMP_EQ_OQ, $xa, $xb), cmp!(_CMP_EQ_OQ, $ya, $yb))
                    };
                }
                let degenerate = or!(or!(same!(x0, y0, x1, y1), same!(x1, y1, x2, y2)), same!(x0, y0, x2, y2));
                redo &= !(_mm256_movemask_ps(degenerate) as u32);
            }
            if redo != 0 {
                [e0, e1, e2] = edges_in_f64([x0, y0, x1, y1, x2, y2], [e0, e1, e2], redo);
            }
            // Rejected lanes, each test as the scalar test's early return.
            let below = or!(or!(cmp!(_CMP_LT_OQ, e0, zero), cmp!(_CMP_LT_OQ, e1, zero)), cmp!(_CMP_LT_OQ, e2, zero));
            let above = or!(or!(cmp!(_CMP_GT_OQ, e0, zero), cmp!(_CMP_GT_OQ, e1, zero)), cmp!(_CMP_GT_OQ, e2, zero));
            let mut reject = _mm256_and_ps(below, above);
            let det = _mm256_add_ps(_mm256_add_ps(e0, e1), e2);
            reject = or!(reject, cmp!(_CMP_EQ_OQ, det, zero));
            let (z0, z1, z2) = (_mm256_mul_ps(z0, sz), _mm256_mul_ps(z1, sz), _mm256_mul_ps(z2, sz));
            let t_scaled =
                _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(e0, z0), _mm256_mul_ps(e1, z1)), _mm256_mul_ps(e2, z2));
            let tmax_det = _mm256_mul_ps(splat!(tmax), det);
            let behind_neg = or!(cmp!(_CMP_GE_OQ, t_scaled, zero), cmp!(_CMP_LT_OQ, t_scaled, tmax_det));
            reject = or!(reject, _mm256_and_ps(cmp!(_CMP_LT_OQ, det, zero), behind_neg));
            let behind_pos = or!(cmp!(_CMP_LE_OQ, t_scaled, zero), cmp!(_CMP_GT_OQ, t_scaled, tmax_det));
            reject = or!(reject, _mm256_and_ps(cmp!(_CMP_GT_OQ, det, zero), behind_pos));
            // Most blocks a ray meets have no lane left here (every lane missed an edge, or
            // lies behind the origin or beyond the closest hit so far): the division and the
            // error bound below could only reject more, so they are skipped.
            if !(_mm256_movemask_ps(reject) as u32) & lanes == 0 {
                return LaneHits { mask: 0, t: [0.0; LANES], b1: [0.0; LANES], b2: [0.0; LANES] };
            }
            let inv = _mm256_div_ps(splat!(1.0), det);
            let t = _mm256_mul_ps(t_scaled, inv);
            // The conservative bound on t's rounding error (see `RayPre::intersect`).
            let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
            macro_rules! abs {
                ($v:expr) => {
                    _mm256_and_ps($v, abs_mask)
                };
            }
            macro_rules! max3 {
                ($a:expr, $b:expr, $c:expr) => {
                    _mm256_max_ps(_mm256_max_ps(abs!($a), abs!($b)), abs!($c))
                };
            }
            macro_rules! mul {
                ($a:expr, $b:expr) => {
                    _mm256_mul_ps($a, $b)
                };
            }
            macro_rules! add {
                ($a:expr, $b:expr) => {
                    _mm256_add_ps($a, $b)
                };
            }
            let (max_z, max_x, max_y) = (max3!(z0, z1, z2), max3!(x0, x1, x2), max3!(y0, y1, y2));
            let delta_z = mul!(splat!(gamma(3)), max_z);
            let delta_x = mul!(splat!(gamma(5)), add!(max_x, max_z));
            let delta_y = mul!(splat!(gamma(5)), add!(max_y, max_z));
            let delta_e = mul!(
                splat!(2.0),
                add!(add!(mul!(mul!(splat!(gamma(2)), max_x), max_y), mul!(delta_y, max_x)), mul!(delta_x, max_y))
            );
            let max_e = max3!(e0, e1, e2);
            let delta_t = mul!(
                mul!(
                    splat!(3.0),
                    add!(add!(mul!(mul!(splat!(gamma(3)), max_e), max_z), mul!(delta_e, max_z)), mul!(delta_z, max_e))
                ),
                abs!(inv)
            );
            let out_of_range = or!(
                or!(cmp!(_CMP_LE_OQ, t, delta_t), cmp!(_CMP_LE_OQ, t, splat!(tmin))),
                cmp!(_CMP_GE_OQ, t, splat!(tmax))
            );
            reject = or!(reject, out_of_range);
            let mut hits = LaneHits {
                mask: !(_mm256_movemask_ps(reject) as u32) & lanes,
                t: [0.0; LANES],
                b1: [0.0; LANES],
                b2: [0.0; LANES],
            };
            // Most blocks a ray meets hold no hit: their distances are never read.
            if hits.mask != 0 {
                _mm256_storeu_ps(hits.t.as_mut_ptr(), t);
                _mm256_storeu_ps(hits.b1.as_mut_ptr(), mul!(e1, inv));
                _mm256_storeu_ps(hits.b2.as_mut_ptr(), mul!(e2, inv));
            }
            hits
        }
    }

    /// The edge functions of the lanes in `redo` computed again in f64, as the scalar test
    /// does where one is exactly zero: rare (a ray through an edge or a vertex, or an empty
    /// slot), so kept out of line and the block test small enough to inline.
    #[cold]
    #[inline(never)]
    #[target_feature(enable = "avx2")]
    fn edges_in_f64(xy: [__m256; 6], e: [__m256; 3], redo: u32) -> [__m256; 3] {
        let lanes_of = |v: __m256| {
            let mut out = [0.0f32; LANES];
            // SAFETY: `out` holds 8 f32.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
            out
        };
        let [x0, y0, x1, y1, x2, y2] = xy.map(lanes_of);
        let mut e = e.map(lanes_of);
        let mut todo = redo;
        while todo != 0 {
            let l = todo.trailing_zeros() as usize;
            todo &= todo - 1;
            e[0][l] = edge_f64(x1[l], y2[l], y1[l], x2[l]);
            e[1][l] = edge_f64(x2[l], y0[l], y2[l], x0[l]);
            e[2][l] = edge_f64(x0[l], y1[l], y0[l], x1[l]);
        }
        // SAFETY: each holds 8 f32.
        e.map(|v| unsafe { _mm256_loadu_ps(v.as_ptr()) })
    }
}

#[cfg(test)]
mod tests {
    use super::super::wide::tests::generator;
    use super::*;

    /// 64 triangles: a fan of 8 around the origin sharing edges and a vertex (rays through
    /// those take the f64 edge path), then random ones of every size and orientation, four
    /// of them one triangle, three with two equal corners.
    fn triangles() -> Vec<[Vec3; 3]> {
        let mut next = generator(3);
        let ring = |k: usize| {
            let a = std::f32::consts::TAU * k as f32 / 8.0;
            Vec3::new(a.cos(), a.sin(), 0.0)
        };
        let mut out: Vec<[Vec3; 3]> = (0..8).map(|k| [Vec3::ZERO, ring(k), ring(k + 1)]).collect();
        while out.len() < 64 {
            let c = Vec3::new(next(), next(), next()) * 2.0;
            let size = 10f32.powf(2.0 * next());
            out.push([0, 1, 2].map(|_| c + Vec3::new(next(), next(), next()) * size));
        }
        // Coincident copies: the first slot among equal distances must win.
        let copied = out[32];
        out[33..36].fill(copied);
        // Triangles with two equal corners, as at a tessellated sphere's poles.
        out[40][1] = out[40][0];
        out[41][2] = out[41][1];
        out[42][2] = out[42][0];
        out
    }

    /// Rays from all around, aimed at the fan's shared vertex and edges and at the random
    /// triangles' corners and insides; some axis-parallel, so each permutation `KZ` is met.
    fn rays(triangles: &[[Vec3; 3]]) -> Vec<(Vec3, Vec3)> {
        let mut next = generator(7);
        (0..3000)
            .map(|r| {
                let tri = triangles[r % triangles.len()];
                let (b1, b2) = match r % 4 {
                    0 => (0.0, 0.0),
                    1 => (0.5, 0.0),
                    _ => (next().abs() * 0.5, next().abs() * 0.5),
                };
                let target = tri[0] * (1.0 - b1 - b2) + tri[1] * b1 + tri[2] * b2;
                let mut o = Vec3::new(next(), next(), next()) * 5.0;
                if r % 9 == 0 {
                    o = target + Vec3::Z * 3.0;
                }
                (o, (target - o).normalize())
            })
            .collect()
    }

    /// [`LeafTriangles::closest`] and [`LeafTriangles::any`] for the ray `o + t d` on the
    /// scalar path and, where the CPU has it, the AVX2 path.
    #[allow(clippy::type_complexity)]
    fn leaf_tests(
        leaves: &LeafTriangles,
        o: Vec3,
        d: Vec3,
        first: u32,
        count: u32,
    ) -> Vec<(Option<(u32, f32, f32, f32)>, bool)> {
        fn both<const KZ: usize>(
            l: &LeafTriangles,
            pre: &RayPre<KZ>,
            first: u32,
            count: u32,
        ) -> Vec<(Option<(u32, f32, f32, f32)>, bool)> {
            let mut out = vec![(
                l.closest::<KZ, false>(pre, first, count, 0.0, f32::INFINITY),
                l.any::<KZ, false>(pre, first, count, 0.0, f32::INFINITY),
            )];
            if super::super::wide::has_avx2() {
                out.push((
                    l.closest::<KZ, true>(pre, first, count, 0.0, f32::INFINITY),
                    l.any::<KZ, true>(pre, first, count, 0.0, f32::INFINITY),
                ));
            }
            out
        }
        match dominant_axis(d) {
            0 => both(leaves, &RayPre::<0>::new(o, d), first, count),
            1 => both(leaves, &RayPre::<1>::new(o, d), first, count),
            _ => both(leaves, &RayPre::<2>::new(o, d), first, count),
        }
    }

    /// The AVX2 block test finds exactly the scalar test's hits, with bit-identical
    /// `(t, b1, b2)`, lane by lane, for rays of each dominant axis, through shared edges and
    /// vertices (the f64 path) and past them, at shortened `tmax`.
    #[test]
    fn avx2_block_test_matches_the_scalar_test_lane_by_lane() {
        #[cfg(target_arch = "x86_64")]
        {
            if !super::super::wide::has_avx2() {
                return;
            }
            let tris = triangles();
            let members: Vec<u32> = (0..tris.len() as u32).collect();
            let leaves = LeafTriangles::new(&tris, &members);
            let (mut hits, mut redone, mut axes) = (0, 0, [0; 3]);
            for (r, (o, d)) in rays(&tris).into_iter().enumerate() {
                let tmax = if r % 3 == 0 { 2.5 } else { f32::INFINITY };
                let lanes = if r % 5 == 0 { 0b0110_1101 } else { 0xff };
                axes[dominant_axis(d)] += 1;
                macro_rules! both {
                    ($kz:literal) => {{
                        let pre = RayPre::<$kz>::new(o, d);
                        for block in &leaves.blocks {
                            let scalar = scalar_block_hits(block, &pre, lanes, 0.0, tmax);
                            // SAFETY: AVX2 is present (checked above).
                            let wide = unsafe { avx2_hits(block, &pre, lanes, tmax) };
                            assert_eq!(scalar.mask, wide.mask, "ray {r}");
                            for l in (0..LANES).filter(|l| scalar.mask >> l & 1 == 1) {
                                let bits = |h: &LaneHits| [h.t[l], h.b1[l], h.b2[l]].map(f32::to_bits);
                                assert_eq!(bits(&scalar), bits(&wide), "ray {r}, lane {l}");
                            }
                            hits += scalar.mask.count_ones();
                            // Lanes whose f32 edge functions have an exact zero: the f64 path.
                            redone += (0..LANES)
                                .filter(|&l| {
                                    let [(x0, y0), (x1, y1), (x2, y2)] = block.triangle(l).map(|v| {
                                        let v = v - pre.o;
                                        let z = v[$kz];
                                        (v[($kz + 1) % 3] + pre.s.x * z, v[($kz + 2) % 3] + pre.s.y * z)
                                    });
                                    let e = [x1 * y2 - y1 * x2, x2 * y0 - y2 * x0, x0 * y1 - y0 * x1];
                                    e.contains(&0.0) && e != [0.0; 3]
                                })
                                .count();
                        }
                    }};
                }
                match dominant_axis(d) {
                    0 => both!(0),
                    1 => both!(1),
                    _ => both!(2),
                }
            }
            assert!(hits > 1000, "the rays must hit ({hits})");
            assert!(redone > 50, "rays through edges and vertices ({redone})");
            assert!(axes.iter().all(|&n| n > 100), "every dominant axis ({axes:?})");
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx2_hits<const KZ: usize>(b: &Block, pre: &RayPre<KZ>, lanes: u32, tmax: f32) -> LaneHits {
        // SAFETY: compiled for AVX2, so called only where the CPU has it.
        unsafe { avx2::block_hits(b, pre, lanes, 0.0, tmax) }
    }

    /// A leaf's closest hit over its blocks, on either path, for leaves of every length at
    /// every offset (straddling blocks or not), equals the scalar test's slot by slot, first
    /// of equals; the occlusion test agrees.
    #[test]
    fn leaf_closest_is_the_nearest_of_the_slot_by_slot_test() {
        let tris = triangles();
        // A permuted slot order, as the BVH's leaf order is.
        let members: Vec<u32> = (0..tris.len() as u32).map(|s| (s * 37) % tris.len() as u32).collect();
        let leaves = LeafTriangles::new(&tris, &members);
        for (i, t) in tris.iter().enumerate() {
            assert_eq!(leaves.triangle(i), Some(*t));
        }
        let mut found = 0;
        for (r, (o, d)) in rays(&tris).into_iter().enumerate() {
            let (first, count) = match r % 3 {
                0 => (0, tris.len() as u32),
                _ => ((r * 13 % 60) as u32, 1 + (r % 11) as u32),
            };
            let count = count.min(tris.len() as u32 - first);
            let mut expected = None;
            let mut closest = f32::INFINITY;
            for slot in first..first + count {
                let p = tris[members[slot as usize] as usize];
                let hit = match dominant_axis(d) {
                    0 => RayPre::<0>::new(o, d).intersect(&p, 0.0, closest),
                    1 => RayPre::<1>::new(o, d).intersect(&p, 0.0, closest),
                    _ => RayPre::<2>::new(o, d).intersect(&p, 0.0, closest),
                };
                if let Some((t, b1, b2)) = hit {
                    expected = Some((slot, t, b1, b2));
                    closest = t;
                }
            }
            for (closest, any) in leaf_tests(&leaves, o, d, first, count) {
                assert_eq!(closest, expected, "ray {r}");
                assert_eq!(any, expected.is_some(), "ray {r}");
            }
            found += usize::from(expected.is_some());
        }
        assert!(found > 50, "{found}");
    }
}
