//! Cryptomatte ID mattes (the Psyop / ASWF specification, version 1.2): every prim path is
//! hashed to a 32-bit ID with MurmurHash3_x86_32 (seed 0), the ID is stored bit for bit as a
//! float32 with its exponent kept off 0 and 255 (so it is never a denormal, an infinity or a
//! NaN that a tool would flush or mangle), and each pixel lists its [`RANKS`] most-covering IDs
//! with their coverage in `CryptoObject00.R/G/B/A`, `CryptoObject01.R/G/B/A`, ... (ID,
//! coverage, ID, coverage). The header names the layer and carries a manifest mapping each
//! name to its ID as 8 hex digits, so a compositor can pick any prim by name.

use super::sum::ExactSum;
use std::collections::BTreeMap;

/// The object layer's name (the channel prefix).
pub const OBJECT_LAYER: &str = "CryptoObject";

/// The composed-material layer's name.
pub const MATERIAL_LAYER: &str = "CryptoMaterial";

/// ID/coverage pairs per pixel: two channel groups of four channels each.
pub const RANKS: usize = 4;

/// MurmurHash3_x86_32 of `data` with `seed` (Austin Appleby's reference algorithm).
pub fn murmur3_x86_32(data: &[u8], seed: u32) -> u32 {
    const C1: u32 = 0xcc9e_2d51;
    const C2: u32 = 0x1b87_3593;
    let mut h = seed;
    let mut blocks = data.chunks_exact(4);
    for block in &mut blocks {
        let mut k = u32::from_le_bytes([block[0], block[1], block[2], block[3]]);
        k = k.wrapping_mul(C1).rotate_left(15).wrapping_mul(C2);
        h ^= k;
        h = h.rotate_left(13).wrapping_mul(5).wrapping_add(0xe654_6b64);
    }
    let tail = blocks.remainder();
    if !tail.is_empty() {
        let mut k = 0u32;
        for (i, &byte) in tail.iter().enumerate() {
            k |= u32::from(byte) << (8 * i);
        }
        h ^= k.wrapping_mul(C1).rotate_left(15).wrapping_mul(C2);
    }
    h ^= data.len() as u32;
    h ^= h >> 16;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^ (h >> 16)
}

/// The ID of `name` as the bits of the float stored in the image: its MurmurHash3 with the
/// exponent clamped to 1..=254 (the specification's `uint32_to_float32` conversion; the
/// reference flips bit 23 when the exponent is 0 or 255, which is the same). The manifest
/// holds these bits, so a reader can compare them with the pixel's float directly.
pub fn id_bits(name: &str) -> u32 {
    float_bits(murmur3_x86_32(name.as_bytes(), 0))
}

/// `hash` with its float32 exponent kept in 1..=254 (never denormal, infinite or NaN).
fn float_bits(hash: u32) -> u32 {
    let exponent = ((hash >> 23) & 0xff).clamp(1, 254);
    (hash & 0x8000_0000) | (exponent << 23) | (hash & 0x007f_ffff)
}

/// The ID of `name` as stored in a pixel.
pub fn id(name: &str) -> f32 {
    f32::from_bits(id_bits(name))
}

/// The channel names of `layer`: `layer00.R`, `layer00.G`, ... for [`RANKS`] ranks.
pub fn channel_names(layer: &str) -> Vec<String> {
    (0..RANKS.div_ceil(2)).flat_map(|group| ["R", "G", "B", "A"].map(|c| format!("{layer}{group:02}.{c}"))).collect()
}

/// The header key of `layer`: the first 7 hex digits of its name's ID (the float-converted
/// hash), as the reference implementation (Psyop's `layer_hash`) writes it.
pub fn layer_key(layer: &str) -> String {
    format!("{:08x}", id_bits(layer))[..7].to_string()
}

/// The header attributes (`cryptomatte/<key>/name|hash|conversion|manifest`) of a layer whose
/// IDs are the hashes of `names`.
pub fn header_attributes<'a>(layer: &str, names: impl IntoIterator<Item = &'a str>) -> Vec<(String, String)> {
    let manifest: BTreeMap<&str, String> = names.into_iter().map(|n| (n, format!("{:08x}", id_bits(n)))).collect();
    let json = serde_json::to_string(&manifest).unwrap_or_else(|_| "{}".into());
    let key = layer_key(layer);
    vec![
        (format!("cryptomatte/{key}/name"), layer.to_string()),
        (format!("cryptomatte/{key}/hash"), "MurmurHash3_32".into()),
        (format!("cryptomatte/{key}/conversion"), "uint32_to_float32".into()),
        (format!("cryptomatte/{key}/manifest"), ascii_json(&json)),
    ]
}

/// `json` with every non-ASCII character written as a `\uXXXX` escape (surrogate pairs beyond
/// the BMP): EXR strings are 8-bit, and JSON readers decode the escapes to the same names that
/// were hashed. Non-ASCII characters only occur inside JSON strings, where escapes are valid.
fn ascii_json(json: &str) -> String {
    let mut out = String::with_capacity(json.len());
    for c in json.chars() {
        if c.is_ascii() {
            out.push(c);
        } else {
            let mut units = [0u16; 2];
            for unit in c.encode_utf16(&mut units) {
                out.push_str(&format!("\\u{unit:04x}"));
            }
        }
    }
    out
}

/// The [`RANKS`] most-covering IDs of a pixel as interleaved `(id, coverage)` floats, from each
/// ID index's summed alpha over `samples` samples; `ids[index]` gives each index's ID and
/// unused ranks are 0. Ranked by the exact sums, ties to the lower index, so the result does
/// not depend on sample order or on how the samples were split.
pub fn ranked(coverage: &mut [(u32, ExactSum)], ids: &[f32], samples: u32) -> [f32; 2 * RANKS] {
    coverage.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut out = [0.0; 2 * RANKS];
    for (rank, &(index, sum)) in coverage.iter().take(RANKS).enumerate() {
        out[2 * rank] = ids.get(index as usize).copied().unwrap_or(0.0);
        out[2 * rank + 1] = sum.mean(samples);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn murmur3_matches_reference_vectors() {
        // From the reference implementation's test suite (and Python's mmh3).
        assert_eq!(murmur3_x86_32(b"", 0), 0);
        assert_eq!(murmur3_x86_32(b"", 1), 0x514e_28b7);
        assert_eq!(murmur3_x86_32(b"hello", 0), 0x248b_fa47);
        assert_eq!(murmur3_x86_32(b"Hello, world!", 1234), 0xfaf6_cdb3);
        assert_eq!(murmur3_x86_32(b"The quick brown fox jumps over the lazy dog", 0x9747_b28c), 0x2fa8_26cd);
    }

    #[test]
    fn ids_are_finite_normal_floats_and_match_the_manifest() {
        for name in ["/World/Balls/Center", "/a", "", "/ünïcödé/🙂", "bunny"] {
            let f = id(name);
            assert!(f.is_normal() || f == 0.0 && id_bits(name) & 0x7fff_ffff == 0, "{name}: {f}");
            assert!(f.is_finite());
        }
        let attrs = header_attributes(OBJECT_LAYER, ["/World/Balls/Center", "/ünï"]);
        let manifest = &attrs.iter().find(|(k, _)| k.ends_with("/manifest")).unwrap().1;
        assert!(manifest.is_ascii());
        let parsed: BTreeMap<String, String> = serde_json::from_str(manifest).unwrap();
        assert_eq!(parsed["/ünï"], format!("{:08x}", id("/ünï").to_bits()));
        assert_eq!(attrs[0].0, format!("cryptomatte/{}/name", layer_key(OBJECT_LAYER)));
        assert_eq!(layer_key(OBJECT_LAYER).len(), 7);
    }

    #[test]
    fn conversion_flips_bit_23_only_for_exponents_0_and_255() {
        for (hash, expected) in [
            (0x0000_0000, 0x0080_0000),
            (0x807f_ffff, 0x80ff_ffff),
            (0x7f80_0000, 0x7f00_0000),
            (0xffff_ffff, 0xff7f_ffff),
            (0x3f80_0001, 0x3f80_0001),
        ] {
            assert_eq!(float_bits(hash), expected, "{hash:08x}");
            let exponent = (hash >> 23) & 0xff;
            let reference = if exponent == 0 || exponent == 255 { hash ^ (1 << 23) } else { hash };
            assert_eq!(float_bits(hash), reference);
        }
    }

    #[test]
    fn coverage_ranks_by_weight_then_index() {
        let ids = [10.0, 20.0, 30.0];
        let mut px: Vec<(u32, ExactSum)> = [(2, 0.25), (0, 0.25), (1, 0.5)].map(|(i, w)| (i, ExactSum::of(w))).into();
        assert_eq!(ranked(&mut px, &ids, 1), [20.0, 0.5, 10.0, 0.25, 30.0, 0.25, 0.0, 0.0]);
        assert_eq!(ranked(&mut px, &ids, 2), [20.0, 0.25, 10.0, 0.125, 30.0, 0.125, 0.0, 0.0]);
    }
}
