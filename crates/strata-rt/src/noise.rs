//! Procedural patterns: Perlin gradient noise, cell noise and Worley (cellular) noise.
//! All are pure functions of their arguments, computed in f32 with integer hashing so results
//! are identical on every platform and backend.

/// A 32-bit integer hash (lowbias32 by Chris Wellons), good avalanche for lattice hashing.
#[inline]
pub fn hash_u32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

#[inline]
fn hash3(x: i32, y: i32, z: i32) -> u32 {
    hash_u32((x as u32) ^ hash_u32((y as u32) ^ hash_u32(z as u32)))
}

/// Maps a hash to [0, 1).
#[inline]
fn unit(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Lattice cell of a coordinate; saturates for huge or non-finite inputs.
#[inline]
fn cell(x: f32) -> i32 {
    let f = x.floor();
    if f.is_nan() { 0 } else { f.clamp(i32::MIN as f32, i32::MAX as f32) as i32 }
}

#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline]
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// Dot product of the hashed gradient of a lattice point with the offset `(x, y, z)`.
#[inline]
fn gradient(h: u32, x: f32, y: f32, z: f32) -> f32 {
    // Ken Perlin's 12 edge gradients (and 4 repeats) selected by the low hash bits.
    match h & 15 {
        0 | 12 => x + y,
        1 | 14 => -x + y,
        2 => x - y,
        3 => -x - y,
        4 => x + z,
        5 => -x + z,
        6 => x - z,
        7 => -x - z,
        8 => y + z,
        9 | 13 => -y + z,
        10 => y - z,
        _ => -y - z,
    }
}

/// Signed Perlin noise in about [-1, 1]; 0 at lattice points. Non-finite input gives 0.
pub fn snoise3(x: f32, y: f32, z: f32) -> f32 {
    if !(x.is_finite() && y.is_finite() && z.is_finite()) {
        return 0.0;
    }
    let (ix, iy, iz) = (cell(x), cell(y), cell(z));
    let (fx, fy, fz) = (x - x.floor(), y - y.floor(), z - z.floor());
    let (u, v, w) = (fade(fx), fade(fy), fade(fz));
    let g = |dx: i32, dy: i32, dz: i32| {
        let h = hash3(ix.wrapping_add(dx), iy.wrapping_add(dy), iz.wrapping_add(dz));
        gradient(h, fx - dx as f32, fy - dy as f32, fz - dz as f32)
    };
    let x00 = lerp(g(0, 0, 0), g(1, 0, 0), u);
    let x10 = lerp(g(0, 1, 0), g(1, 1, 0), u);
    let x01 = lerp(g(0, 0, 1), g(1, 0, 1), u);
    let x11 = lerp(g(0, 1, 1), g(1, 1, 1), u);
    let y0 = lerp(x00, x10, v);
    let y1 = lerp(x01, x11, v);
    (lerp(y0, y1, w) * 0.97).clamp(-1.0, 1.0)
}

/// Perlin noise remapped to [0, 1] (OSL's `noise`).
pub fn noise3(x: f32, y: f32, z: f32) -> f32 {
    0.5 + 0.5 * snoise3(x, y, z)
}

/// A random value in [0, 1) constant over each unit cell (OSL's `cellnoise`).
pub fn cellnoise3(x: f32, y: f32, z: f32) -> f32 {
    unit(hash3(cell(x), cell(y), cell(z)))
}

/// Worley noise: distance to the nearest of one jittered feature point per unit cell (F1),
/// clamped to [0, 1].
pub fn cellular3(x: f32, y: f32, z: f32) -> f32 {
    if !(x.is_finite() && y.is_finite() && z.is_finite()) {
        return 0.0;
    }
    let (ix, iy, iz) = (cell(x), cell(y), cell(z));
    let mut best = f32::MAX;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (cx, cy, cz) = (ix.wrapping_add(dx), iy.wrapping_add(dy), iz.wrapping_add(dz));
                let h = hash3(cx, cy, cz);
                let px = cx as f32 + unit(h);
                let py = cy as f32 + unit(hash_u32(h ^ 0x68e3_1da4));
                let pz = cz as f32 + unit(hash_u32(h ^ 0xb529_7a4d));
                let d = (px - x) * (px - x) + (py - y) * (py - y) + (pz - z) * (pz - z);
                best = best.min(d);
            }
        }
    }
    best.sqrt().min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_and_determinism() {
        let mut lo = f32::MAX;
        let mut hi = f32::MIN;
        for i in 0..10_000 {
            let t = i as f32 * 0.173;
            let n = noise3(t, t * 0.7 + 3.1, -t * 1.3);
            assert!((0.0..=1.0).contains(&n));
            lo = lo.min(n);
            hi = hi.max(n);
            let c = cellular3(t, 0.3 * t, 1.7);
            assert!((0.0..=1.0).contains(&c));
            assert!((0.0..1.0).contains(&cellnoise3(t, t, t)));
        }
        assert!(lo < 0.25 && hi > 0.75, "noise spans its range: {lo} {hi}");
        assert_eq!(noise3(1.5, 2.5, 3.5), noise3(1.5, 2.5, 3.5));
        assert_eq!(snoise3(1.0, 2.0, 3.0), 0.0, "zero at lattice points");
    }

    #[test]
    fn non_finite_inputs_are_safe() {
        for v in [f32::NAN, f32::INFINITY, -f32::INFINITY, 1e30, -1e30] {
            assert!(noise3(v, 0.0, 0.0).is_finite());
            assert!(cellular3(v, v, v).is_finite());
            assert!(cellnoise3(v, 1.0, 2.0).is_finite());
        }
    }
}
