//! Structure checks run before openusd reads a crate: the header, sections and compressed
//! blocks ([`precheck`]), then the framing of every value ([`Probe`]): no count may claim
//! more than the bytes after it hold.

use super::{CRATE_MAGIC, MAX_VERSION, MIN_VERSION};
use std::cell::Cell;

/// Reads a little-endian `u64` at `at`, if the file is long enough.
pub(super) fn u64_at(bytes: &[u8], at: u64) -> Option<u64> {
    let at = usize::try_from(at).ok()?;
    let raw = bytes.get(at..at.checked_add(8)?)?;
    Some(u64::from_le_bytes(raw.try_into().ok()?))
}

/// The length of what a `TfFastCompression` buffer (a chunk count byte, 0 for one LZ4
/// block, then the block) decompresses to, found from the block's sequence headers alone;
/// `None` when the framing is malformed or chunked (openusd reads only single blocks).
pub(super) fn lz4_decoded_len(buffer: &[u8]) -> Option<u64> {
    let Some((&chunks, block)) = buffer.split_first() else {
        return Some(0);
    };
    if chunks != 0 {
        return None;
    }
    // A length: 4 bits of the token, then bytes of 255 while they continue.
    let extended = |mut len: u64, at: &mut usize| -> Option<u64> {
        if len == 15 {
            loop {
                let byte = *block.get(*at)?;
                *at += 1;
                len += u64::from(byte);
                if byte != 255 {
                    break;
                }
            }
        }
        Some(len)
    };
    let (mut at, mut total) = (0usize, 0u64);
    while at < block.len() {
        let token = block[at];
        at += 1;
        let literals = extended(u64::from(token >> 4), &mut at)?;
        at = at.checked_add(usize::try_from(literals).ok()?).filter(|&e| e <= block.len())?;
        total += literals;
        if at == block.len() {
            break; // the last sequence has literals only
        }
        at += 2; // match offset
        total += extended(u64::from(token & 15), &mut at)? + 4;
    }
    Some(total)
}

/// At most this many table entries per byte of their section: LZ4 expands at most 255:1,
/// and integer coding packs at most four entries per byte. Anything claiming more is
/// corrupt, and would otherwise make openusd allocate (and fill) a table of that size.
pub(super) const MAX_ENTRIES_PER_BYTE: u64 = 1024;

/// Checks what openusd trusts without checking: the version (older files reach its unimplemented paths),
/// the table of contents and every section inside the file, and table counts the sections
/// can hold. Returns the version.
pub fn precheck(bytes: &[u8]) -> Result<(u8, u8, u8), String> {
    let len = bytes.len() as u64;
    if !bytes.starts_with(CRATE_MAGIC) {
        return Err("no `PXR-USDC` magic".into());
    }
    let version = match bytes.get(8..11) {
        Some(&[major, minor, patch]) => (major, minor, patch),
        _ => return Err("truncated in the header".into()),
    };
    if version < MIN_VERSION || version > MAX_VERSION {
        let (a, b, c) = version;
        let (min, max) = (MIN_VERSION, MAX_VERSION);
        return Err(format!(
            "unsupported crate version {a}.{b}.{c} (strata reads {}.{}.{} to {}.{}.{}; re-save the file with a current USD, e.g. `usdcat in.usdc -o out.usdc`)",
            min.0, min.1, min.2, max.0, max.1, max.2
        ));
    }
    let toc = u64_at(bytes, 16).ok_or("truncated in the header")?;
    let sections = u64_at(bytes, toc).ok_or("the table of contents lies outside the file")?;
    if sections > len / 32 + 1 {
        return Err(format!("the table of contents claims {sections} sections"));
    }
    for i in 0..sections {
        let entry = toc + 8 + i * 32;
        let name = bytes.get(entry as usize..(entry + 16) as usize).ok_or("truncated in the table of contents")?;
        let start = u64_at(bytes, entry + 16).ok_or("truncated in the table of contents")?;
        let size = u64_at(bytes, entry + 24).ok_or("truncated in the table of contents")?;
        let name = String::from_utf8_lossy(name.split(|&b| b == 0).next().unwrap_or_default()).into_owned();
        if start.checked_add(size).is_none_or(|end| end > len) {
            return Err(format!("section {name} lies outside the file"));
        }
        // Each table: a count, then LZ4 blocks (a u64 size and the bytes) that openusd
        // allocates by their sizes before reading them.
        let (counts, blocks) = match name.as_str() {
            "TOKENS" => (2, 1),
            "STRINGS" => (1, 0),
            "FIELDS" => (1, 2),
            "FIELDSETS" => (1, 1),
            "PATHS" => (2, 3),
            "SPECS" => (1, 3),
            _ => (0, 0),
        };
        let end = start + size;
        let truncated = || format!("section {name} is truncated");
        let mut pos = start;
        let mut table_counts = Vec::with_capacity(counts);
        for _ in 0..counts {
            let count = u64_at(bytes, pos).filter(|_| pos + 8 <= end).ok_or_else(truncated)?;
            if count > size.saturating_mul(MAX_ENTRIES_PER_BYTE) {
                return Err(format!("section {name} claims {count} entries in {size} bytes"));
            }
            if name == "STRINGS" && count.saturating_mul(4) > size {
                return Err(format!("section {name} claims {count} strings in {size} bytes"));
            }
            table_counts.push(count);
            pos += 8;
        }
        // openusd sizes its buffers by the counts before decompressing: no count may exceed
        // what the blocks decompress to (at least 2 bits of it per integer-coded entry).
        let mut decoded = 0u64;
        for _ in 0..blocks {
            let block = u64_at(bytes, pos).filter(|_| pos + 8 <= end).ok_or_else(truncated)?;
            let block_end = (pos + 8)
                .checked_add(block)
                .filter(|&e| e <= end)
                .ok_or_else(|| format!("section {name} holds a compressed block of {block} bytes past its end"))?;
            decoded += lz4_decoded_len(&bytes[(pos + 8) as usize..block_end as usize])
                .ok_or_else(|| format!("section {name} holds a malformed compressed block"))?;
            pos = block_end;
        }
        if blocks > 0
            && let Some(count) = table_counts.iter().find(|&&c| c > decoded.saturating_mul(4))
        {
            return Err(format!("section {name} claims {count} entries in {decoded} decompressed bytes"));
        }
    }
    Ok(version)
}

/// Checks every value the fields table points at before openusd decodes any: each count
/// read from the file (array lengths, list-op and vector lengths, dictionary sizes, time
/// sample counts, compressed sizes) must fit in the bytes that follow it, and dictionaries
/// and time samples may nest only so deep. openusd allocates a vector of whatever length it
/// reads first, so one corrupt count would ask for petabytes: an allocation failure aborts
/// the process, which `catch_unwind` cannot catch. This mirrors openusd 0.6.0's value
/// framing (`usdc/reader.rs`), as Pixar's `crateFile.cpp` lays it out.
pub(super) fn check_value_sizes(
    bytes: &[u8],
    file: &openusd::usdc::CrateFile<std::io::Cursor<&[u8]>>,
) -> Result<(), String> {
    let v = file.version();
    // Values can share storage and point back at their container: bound the total work too.
    let budget = Cell::new(bytes.len() as u64 * 4 + 4096);
    let probe = Probe { bytes, version: (v.major, v.minor, v.patch), budget };
    for field in &file.fields {
        if let Err(e) = probe.value(field.value_rep.0, 0) {
            let name = file.tokens.get(field.token_index).map(String::as_str).unwrap_or("?");
            return Err(format!("field `{name}`: {e}"));
        }
    }
    Ok(())
}

/// Dictionaries and time samples nested deeper than this are refused: openusd decodes them
/// recursively, one stack frame per level (and a value pointing at itself never ends).
pub(super) const MAX_VALUE_NESTING: usize = 32;

pub(super) struct Probe<'b> {
    pub(super) bytes: &'b [u8],
    pub(super) version: (u8, u8, u8),
    /// Values left to look at.
    pub(super) budget: Cell<u64>,
}

impl Probe<'_> {
    pub(super) fn len(&self) -> u64 {
        self.bytes.len() as u64
    }

    pub(super) fn u64_at(&self, at: u64) -> Result<u64, String> {
        u64_at(self.bytes, at).ok_or_else(|| format!("a value at byte {at} lies outside the file"))
    }

    pub(super) fn u32_at(&self, at: u64) -> Result<u64, String> {
        let at_usize = usize::try_from(at).map_err(|_| "offset out of range".to_string())?;
        let raw = self.bytes.get(at_usize..at_usize.saturating_add(4)).ok_or("a value lies outside the file")?;
        Ok(u64::from(u32::from_le_bytes(raw.try_into().map_err(|_| "truncated")?)))
    }

    pub(super) fn u8_at(&self, at: u64) -> Result<u8, String> {
        usize::try_from(at).ok().and_then(|i| self.bytes.get(i).copied()).ok_or_else(|| "truncated value".to_string())
    }

    /// `count` elements of `size` bytes must fit between `at` and the end of the file.
    pub(super) fn fits(&self, at: u64, count: u64, size: u64) -> Result<u64, String> {
        let need = count.checked_mul(size).ok_or("a count overflows")?;
        let end = at.checked_add(need).ok_or("a count overflows")?;
        if end > self.len() {
            return Err(format!("claims {count} elements of {size} bytes at byte {at}, past the end of the file"));
        }
        Ok(end)
    }

    /// A `u64` count at `at` followed by that many `size`-byte elements; returns the end.
    pub(super) fn counted(&self, at: u64, size: u64) -> Result<u64, String> {
        let count = self.u64_at(at)?;
        self.fits(at + 8, count, size)
    }

    pub(super) fn value(&self, rep: u64, depth: usize) -> Result<(), String> {
        if depth > MAX_VALUE_NESTING {
            return Err(format!("values nested more than {MAX_VALUE_NESTING} deep"));
        }
        let left = self.budget.get().checked_sub(1).ok_or("values refer to each other in a loop")?;
        self.budget.set(left);
        let ty = (rep >> 48) & 0xff;
        let (array, inlined, compressed) = (rep & (1 << 63) != 0, rep & (1 << 62) != 0, rep & (1 << 61) != 0);
        let at = rep & ((1 << 48) - 1);
        // Type codes of Pixar's crate format (crateDataTypes.h). openusd reads a value with
        // the array bit as an array whenever its type has arrays, whatever the inlined bit
        // says (one flipped byte set both: a petabyte `read_vec`); the other types ignore the
        // array bit, and only a payload list op ignores the inlined bit.
        let has_arrays = matches!(ty, 1..=30 | 56 | 57);
        if inlined && !(array && has_arrays) && ty != 55 {
            return Ok(());
        }
        match ty {
            10 | 12 | 57 if array => {
                // string, asset and path-expression arrays: u64 count of u32 string indices.
                self.counted(at, 4)?;
            }
            48 => self.array(at, 9, compressed)?, // DoubleVector, read like a double array
            _ if array && has_arrays => self.array(at, ty, compressed)?,
            // Token, string, path and unregistered list ops: vectors of u32 indices.
            32 | 33 | 34 | 54 => self.list_op(at, |p, at| p.counted(at, 4))?,
            36 | 38 => self.list_op(at, |p, at| p.counted(at, 4))?,
            37 | 39 => self.list_op(at, |p, at| p.counted(at, 8))?,
            35 => self.list_op(at, |p, at| {
                let count = p.u64_at(at)?;
                // Each reference: asset (u32), prim (u32), layer offset (16), custom data.
                p.fits(at + 8, count, 32)?;
                let mut pos = at + 8;
                for _ in 0..count {
                    pos = p.dictionary(pos + 24, depth + 1)?;
                }
                Ok(pos)
            })?,
            55 => {
                let size = if self.version >= (0, 8, 0) { 24 } else { 8 };
                self.list_op(at, |p, at| p.counted(at, size))?
            }
            40 | 41 | 50 => {
                self.counted(at, 4)?; // path, token and string vectors
            }
            49 => {
                self.counted(at, 16)?; // layer offsets
            }
            45 => {
                self.counted(at, 8)?; // variant selections: two u32 strings each
            }
            58 => {
                self.counted(at, 8)?; // relocates: two u32 paths each
            }
            31 => {
                self.dictionary(at, depth + 1)?;
            }
            46 => {
                // Time samples: a jump to the times' rep, then a jump to the values' reps.
                let jump = self.u64_at(at)? as i64;
                let times_at = (at as i64).checked_add(jump).filter(|&x| x >= 0).ok_or("bad offset")? as u64;
                let times = self.u64_at(times_at)?;
                self.value(times, depth + 1)?;
                let after = times_at + 8;
                let jump = self.u64_at(after)? as i64;
                let reps_at = (after as i64).checked_add(jump).filter(|&x| x >= 0).ok_or("bad offset")? as u64;
                let count = self.u64_at(reps_at)?;
                self.fits(reps_at + 8, count, 8)?;
                for i in 0..count {
                    self.value(self.u64_at(reps_at + 8 + 8 * i)?, depth + 1)?;
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// An array value at `at` of element type code `ty`.
    pub(super) fn array(&self, at: u64, ty: u64, compressed: bool) -> Result<(), String> {
        if at == 0 {
            return Ok(()); // the empty array
        }
        let mut pos = at;
        if self.version < (0, 5, 0) {
            pos += 4; // shape size
        }
        let count = if self.version < (0, 7, 0) {
            let c = self.u32_at(pos)?;
            pos += 4;
            c
        } else {
            let c = self.u64_at(pos)?;
            pos += 8;
            c
        };
        let size: u64 = match ty {
            1 | 2 => 1,
            7 => 2,
            3 | 4 | 8 | 10 | 11 | 12 | 57 => 4,
            5 | 6 | 9 | 18 | 56 => 8,
            21 => 4,
            25 => 6,
            20 | 22 | 29 => 8,
            26 | 24 => 12,
            17 | 19 | 28 | 30 => 16,
            23 => 24,
            13 | 16 | 27 => 32,
            14 => 72,
            15 => 128,
            _ => 1,
        };
        // Compressed int arrays exist from crate 0.5.0, compressed float arrays from 0.6.0;
        // before that openusd reads the flag's arrays uncompressed.
        let ints = matches!(ty, 3..=6) && self.version >= (0, 5, 0);
        let floats = matches!(ty, 7 | 8 | 9 | 56) && self.version >= (0, 6, 0);
        // openusd's threshold below which arrays are never compressed.
        let compressed = compressed && count >= 4 && (ints || floats);
        if !compressed {
            self.fits(pos, count, size)?;
            return Ok(());
        }
        // LZ4 expands at most 255:1 and integer coding packs at most 4 values per byte.
        if count > (self.len() - pos.min(self.len())).saturating_mul(MAX_ENTRIES_PER_BYTE) {
            return Err(format!("claims a compressed array of {count} elements"));
        }
        if floats {
            match self.u8_at(pos)? {
                b'i' => pos += 1,
                b't' => {
                    let lut = self.u32_at(pos + 1)?;
                    pos = self.fits(pos + 5, lut, size)?;
                }
                _ => return Ok(()), // openusd rejects the code itself
            }
        }
        // openusd allocates about 4.25 bytes per element before decompressing: bound the
        // count by what the LZ4 block decodes to (integer coding spends at least 2 bits on
        // each element), found by walking the block's sequences without decoding them.
        let compressed_size = self.u64_at(pos)?;
        let end = self.fits(pos + 8, compressed_size, 1)?;
        let block = &self.bytes[(pos + 8) as usize..end as usize];
        let decoded = lz4_decoded_len(block).ok_or("a compressed array's LZ4 block is malformed")?;
        if count > decoded.saturating_mul(4) {
            return Err(format!("claims a compressed array of {count} elements in {decoded} decompressed bytes"));
        }
        Ok(())
    }

    /// A list op at `at`: a header byte, then one vector per flag, each read by `item`
    /// (which returns where the vector ends).
    pub(super) fn list_op(&self, at: u64, item: impl Fn(&Self, u64) -> Result<u64, String>) -> Result<(), String> {
        let header = self.u8_at(at)?;
        let mut pos = at + 1;
        for bit in 1..=6 {
            if header & (1 << bit) != 0 {
                pos = item(self, pos)?;
            }
        }
        Ok(())
    }

    /// A dictionary at `at`; returns where its entries end in the stream.
    pub(super) fn dictionary(&self, at: u64, depth: usize) -> Result<u64, String> {
        if depth > MAX_VALUE_NESTING {
            return Err(format!("values nested more than {MAX_VALUE_NESTING} deep"));
        }
        let count = self.u64_at(at)?;
        // Each entry: key (u32) and a jump (i64) in the stream.
        self.fits(at + 8, count, 12)?;
        let mut pos = at + 8;
        for _ in 0..count {
            pos += 4;
            let jump = self.u64_at(pos)? as i64;
            let rep_at = (pos as i64).checked_add(jump).filter(|&x| x >= 0).ok_or("bad offset")? as u64;
            let rep = self.u64_at(rep_at)?;
            self.value(rep, depth + 1)?;
            pos = rep_at + 8;
        }
        Ok(pos)
    }
}
