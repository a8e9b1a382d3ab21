//! Binary USD: crate files (`.usdc`, binary `.usd`) and usdz packages, read with the
//! `openusd` crate and converted into the same per-file syntax tree the `.usda` parser
//! produces ([`Layer`]), so composition, slot bindings and diagnostics have one model.
//!
//! **Format detection** looks at the content, never only the extension
//! ([`read_layer_file`]): `PXR-USDC` is a crate, `PK\x03\x04` a usdz package (its root layer
//! is the first USD layer it holds), anything else is text for the usda parser.
//!
//! **Spans.** A binary layer has no text to point into, so the converter writes an
//! *outline*: one line per spec (`def Mesh </World/Mesh>`, `point3f[] </World/Mesh.points>`,
//! `references @a.usdc@</A>`, ...). That outline is the file's text in the [`SourceMap`];
//! every span of the converted layer points at its spec's line, so diagnostics name the
//! file, a line of the outline and quote the prim or property path.
//!
//! **Values** become exactly what the usda parser produces for the same declared type:
//! numbers widen to `f64`, where a `float` or `half` is converted through its shortest
//! decimal form (the text a usda file holds for it), so a value reads the same from either
//! format; tokens in metadata become strings, as usda writes them quoted; dictionaries are
//! sorted by key, as USD writes them.
//!
//! **Hostile input.** openusd indexes its tables with values read from the file and has
//! unimplemented paths (panicking macros) for old crate versions, so it can panic on a
//! malformed file; and it allocates as many elements as a count read from the file says
//! before reading them, where a failed allocation aborts. The header, sections and compressed blocks are checked here first
//! ([`precheck`]), then the framing of every value (`Probe`): no count may claim more than
//! the bytes after it hold. Every call into openusd runs under `catch_unwind`: a panic
//! becomes a "malformed usdc" diagnostic, and a panic hook keeps its message off the
//! terminal. A panic never reaches the user.

use crate::diag::{Diagnostic, Diagnostics, FileId, SourceMap, Span};
use crate::scene::usda::{
    AttributeSpec, Layer, LayerMetadata, LayerOffset, ListOp, MetadataEntry, PrimMetadata, PrimSpec, PropertySpec,
    Reference, RelationshipSpec, Specifier, Target, VariantSetSpec,
};
use crate::scene::value::{AssetPath, Value, ValueType};
use openusd::sdf::{self, AbstractData};
use std::cell::Cell;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Once;

/// The crate magic at the start of every binary USD file.
pub const CRATE_MAGIC: &[u8] = b"PXR-USDC";
/// The zip local-file-header magic at the start of every usdz package.
pub const ZIP_MAGIC: &[u8] = b"PK\x03\x04";

/// Oldest crate version read: openusd has no reader for the tables of older files.
const MIN_VERSION: (u8, u8, u8) = (0, 4, 0);
/// Newest crate version openusd 0.6.0 reads.
const MAX_VERSION: (u8, u8, u8) = (0, 12, 0);

/// What a USD file holds, judged by its first bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `#usda` text (or anything else: the usda parser reports a missing header).
    Text,
    /// A `PXR-USDC` crate.
    Crate,
    /// A zip package (usdz).
    Package,
}

/// The format of a file from its content.
pub fn detect(bytes: &[u8]) -> Format {
    if bytes.starts_with(CRATE_MAGIC) {
        Format::Crate
    } else if bytes.starts_with(ZIP_MAGIC) {
        Format::Package
    } else {
        Format::Text
    }
}

/// A layer file's content, read and classified.
pub enum LayerSource {
    /// USD ASCII text.
    Text(String),
    /// A crate file's bytes.
    Crate(Vec<u8>),
}

/// A layer file as read: the path it is known by (for a usdz package, the package-relative
/// path of its root layer, `a.usdz[root.usdc]`, so its assets resolve inside the package) and
/// its content.
pub struct LayerFile {
    /// The layer's path.
    pub path: PathBuf,
    /// Its content.
    pub source: LayerSource,
}

/// Reads the layer at `path` through [`crate::input`], whatever its format. The error says
/// what the file is and why it cannot be a layer.
pub fn read_layer_file(path: &Path) -> Result<LayerFile, LayerReadError> {
    let bytes = crate::input::read_bytes(path).map_err(|e| match e {
        // What USD says of an asset path that does not resolve, without the OS's error code.
        crate::input::InputError::Io(io) if io.kind() == std::io::ErrorKind::NotFound => {
            LayerReadError::Unreadable("the file does not exist".into())
        }
        e => LayerReadError::Unreadable(e.to_string()),
    })?;
    if is_materialx(path, &bytes) {
        return Err(LayerReadError::MaterialX);
    }
    read_layer_bytes(path, bytes).map_err(LayerReadError::Unreadable)
}

/// Why [`read_layer_file`] could not give a layer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LayerReadError {
    /// A MaterialX document (`.mtlx`, or XML content): USD reads it through its MaterialX
    /// file-format plugin; strata does not read MaterialX yet.
    MaterialX,
    /// Missing, unreadable, or not a USD file; the text says which.
    Unreadable(String),
}

impl std::fmt::Display for LayerReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LayerReadError::MaterialX => f.write_str("a MaterialX document; strata does not read MaterialX yet"),
            LayerReadError::Unreadable(why) => f.write_str(why),
        }
    }
}

/// Whether a file is a MaterialX document: named `.mtlx`, or XML (`<?xml`, `<materialx`)
/// after any byte-order mark and white space — what USD's MaterialX plugin would read.
pub fn is_materialx(path: &Path, bytes: &[u8]) -> bool {
    let named = path
        .file_name()
        .and_then(|n| n.to_str())
        .map(|n| n.trim_end_matches(']'))
        .is_some_and(|n| n.to_ascii_lowercase().ends_with(".mtlx"));
    let body = bytes.strip_prefix(b"\xEF\xBB\xBF".as_slice()).unwrap_or(bytes);
    let start = body.iter().position(|b| !b.is_ascii_whitespace()).unwrap_or(body.len());
    let head = &body[start..body.len().min(start + 16)];
    named || head.starts_with(b"<?xml") || head.to_ascii_lowercase().starts_with(b"<materialx")
}

/// [`read_layer_file`] once the bytes are read and known not to be MaterialX.
fn read_layer_bytes(path: &Path, bytes: Vec<u8>) -> Result<LayerFile, String> {
    match detect(&bytes) {
        Format::Crate => Ok(LayerFile { path: path.to_path_buf(), source: LayerSource::Crate(bytes) }),
        Format::Text => text_layer(path, bytes),
        Format::Package => {
            let root = package_root_layer(&bytes)?;
            let member = crate::input::package_member(path, &root);
            let bytes = crate::input::read_bytes(&member).map_err(|e| e.to_string())?;
            match detect(&bytes) {
                Format::Crate => Ok(LayerFile { path: member, source: LayerSource::Crate(bytes) }),
                Format::Text => text_layer(&member, bytes),
                Format::Package => Err(format!("the root layer `{root}` of the usdz package is itself a package")),
            }
        }
    }
}

fn text_layer(path: &Path, bytes: Vec<u8>) -> Result<LayerFile, String> {
    match String::from_utf8(bytes) {
        Ok(text) => Ok(LayerFile { path: path.to_path_buf(), source: LayerSource::Text(text) }),
        Err(_) => {
            Err("not a USD file: neither `#usda` text, a `PXR-USDC` binary crate nor a usdz (zip) package".into())
        }
    }
}

/// The name of a usdz package's root layer: its first USD layer (the usdz specification
/// puts it first; packages that lead with something else still open, as in openusd).
fn package_root_layer(bytes: &[u8]) -> Result<String, String> {
    let archive = zip::ZipArchive::new(std::io::Cursor::new(bytes))
        .map_err(|e| format!("a usdz package that is not a readable zip archive: {e}"))?;
    let is_layer = |name: &str| {
        let lower = name.to_ascii_lowercase();
        lower.ends_with(".usdc") || lower.ends_with(".usda") || lower.ends_with(".usd")
    };
    let first =
        (0..archive.len()).filter_map(|i| archive.name_for_index(i)).find(|name| is_layer(name)).map(str::to_string);
    first.ok_or_else(|| "a usdz package with no USD layer (`.usda`, `.usdc` or `.usd`) in it".to_string())
}

// ---- panics ----

thread_local! {
    /// Set while this thread is inside openusd: its panics are caught and reported.
    static IN_OPENUSD: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` (a call into openusd) with panics caught: `Err` carries the panic message.
/// The process's panic hook is wrapped once so a caught panic prints nothing; every other
/// panic still reaches the previous hook.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !IN_OPENUSD.with(Cell::get) {
                previous(info);
            }
        }));
    });
    let was = IN_OPENUSD.with(|c| c.replace(true));
    let result = catch_unwind(AssertUnwindSafe(f));
    IN_OPENUSD.with(|c| c.set(was));
    result.map_err(|payload| {
        payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "internal error".into())
    })
}

// ---- structure checks ----

/// Reads a little-endian `u64` at `at`, if the file is long enough.
fn u64_at(bytes: &[u8], at: u64) -> Option<u64> {
    let at = usize::try_from(at).ok()?;
    let raw = bytes.get(at..at.checked_add(8)?)?;
    Some(u64::from_le_bytes(raw.try_into().ok()?))
}

/// The length of what a `TfFastCompression` buffer (a chunk count byte, 0 for one LZ4
/// block, then the block) decompresses to, found from the block's sequence headers alone;
/// `None` when the framing is malformed or chunked (openusd reads only single blocks).
fn lz4_decoded_len(buffer: &[u8]) -> Option<u64> {
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
const MAX_ENTRIES_PER_BYTE: u64 = 1024;

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
fn check_value_sizes(bytes: &[u8], file: &openusd::usdc::CrateFile<std::io::Cursor<&[u8]>>) -> Result<(), String> {
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
const MAX_VALUE_NESTING: usize = 32;

struct Probe<'b> {
    bytes: &'b [u8],
    version: (u8, u8, u8),
    /// Values left to look at.
    budget: Cell<u64>,
}

impl Probe<'_> {
    fn len(&self) -> u64 {
        self.bytes.len() as u64
    }

    fn u64_at(&self, at: u64) -> Result<u64, String> {
        u64_at(self.bytes, at).ok_or_else(|| format!("a value at byte {at} lies outside the file"))
    }

    fn u32_at(&self, at: u64) -> Result<u64, String> {
        let at_usize = usize::try_from(at).map_err(|_| "offset out of range".to_string())?;
        let raw = self.bytes.get(at_usize..at_usize.saturating_add(4)).ok_or("a value lies outside the file")?;
        Ok(u64::from(u32::from_le_bytes(raw.try_into().map_err(|_| "truncated")?)))
    }

    fn u8_at(&self, at: u64) -> Result<u8, String> {
        usize::try_from(at).ok().and_then(|i| self.bytes.get(i).copied()).ok_or_else(|| "truncated value".to_string())
    }

    /// `count` elements of `size` bytes must fit between `at` and the end of the file.
    fn fits(&self, at: u64, count: u64, size: u64) -> Result<u64, String> {
        let need = count.checked_mul(size).ok_or("a count overflows")?;
        let end = at.checked_add(need).ok_or("a count overflows")?;
        if end > self.len() {
            return Err(format!("claims {count} elements of {size} bytes at byte {at}, past the end of the file"));
        }
        Ok(end)
    }

    /// A `u64` count at `at` followed by that many `size`-byte elements; returns the end.
    fn counted(&self, at: u64, size: u64) -> Result<u64, String> {
        let count = self.u64_at(at)?;
        self.fits(at + 8, count, size)
    }

    fn value(&self, rep: u64, depth: usize) -> Result<(), String> {
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
    fn array(&self, at: u64, ty: u64, compressed: bool) -> Result<(), String> {
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
    fn list_op(&self, at: u64, item: impl Fn(&Self, u64) -> Result<u64, String>) -> Result<(), String> {
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
    fn dictionary(&self, at: u64, depth: usize) -> Result<u64, String> {
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

// ---- conversion ----

/// A diagnostic waiting for the outline's file id.
struct Pending {
    error: bool,
    message: String,
    at: (u32, u32),
    label: String,
    note: Option<String>,
}

/// Converts the crate file `bytes` read from `name` into a [`Layer`]. The outline (see the
/// module documentation) is registered in `sources` under `name`; problems go to `diags`.
/// A file openusd cannot read yields an empty layer and an error.
pub fn convert(name: &str, bytes: &[u8], base_dir: &Path, sources: &mut SourceMap, diags: &mut Diagnostics) -> Layer {
    let mut converter = Converter {
        data: None,
        by_text: HashMap::new(),
        outline: String::from("# binary USD (usdc): one line per spec; diagnostics point here\n"),
        base_dir,
        pending: Vec::new(),
    };
    let mut layer = Layer::default();
    match open(bytes) {
        Ok(data) => {
            converter.by_text = data.spec_paths().into_iter().map(|p| (p.as_str().to_string(), p)).collect();
            converter.data = Some(data);
            match guarded(|| converter.layer()) {
                Ok(l) => layer = l,
                Err(panic) => converter.pending.push(Pending {
                    error: true,
                    message: format!("malformed usdc: the binary USD reader failed ({panic})"),
                    at: (0, 0),
                    label: String::new(),
                    note: None,
                }),
            }
        }
        Err(message) => converter.pending.push(Pending {
            error: true,
            message: format!("malformed usdc: {message}"),
            at: (0, 0),
            label: String::new(),
            note: None,
        }),
    }
    let file = sources.add(name, std::mem::take(&mut converter.outline));
    retarget_layer(&mut layer, file);
    layer.file = file;
    for p in converter.pending {
        let span = Span { file, start: p.at.0, end: p.at.1 };
        let mut d = if p.error { Diagnostic::error(p.message) } else { Diagnostic::warning(p.message) };
        d = if p.at == (0, 0) { d.at(span, format!("in `{name}`")) } else { d.at(span, p.label) };
        if let Some(note) = p.note {
            d = d.note(note);
        }
        diags.push(d);
    }
    layer
}

/// Opens a crate after [`precheck`], with openusd's own structural validation on and its
/// panics caught.
fn open(bytes: &[u8]) -> Result<Box<dyn AbstractData>, String> {
    precheck(bytes)?;
    guarded(|| -> Result<Box<dyn AbstractData>, String> {
        let file = openusd::usdc::CrateFile::open(std::io::Cursor::new(bytes)).map_err(|e| format!("{e:#}"))?;
        file.validate().map_err(|e| format!("{e:#}"))?;
        check_value_sizes(bytes, &file)?;
        let data =
            openusd::usdc::CrateData::open(std::io::Cursor::new(bytes.to_vec()), true).map_err(|e| format!("{e:#}"))?;
        Ok(Box::new(data))
    })
    .map_err(|panic| format!("the binary USD reader failed ({panic})"))?
}

struct Converter<'a> {
    data: Option<Box<dyn AbstractData>>,
    by_text: HashMap<String, sdf::Path>,
    outline: String,
    base_dir: &'a Path,
    pending: Vec<Pending>,
}

/// Placeholder file id for spans until the outline is registered.
const NO_FILE: FileId = FileId(u32::MAX);

impl Converter<'_> {
    /// Appends one outline line (indented by `depth`) and returns the span of its text.
    fn line(&mut self, depth: usize, text: &str) -> Span {
        for _ in 0..depth.min(32) {
            self.outline.push_str("    ");
        }
        let start = self.outline.len();
        // Paths and names come from the file: keep the outline one line per spec.
        for c in text.chars() {
            self.outline.push(if c == '\n' || c == '\r' { ' ' } else { c });
        }
        let end = self.outline.len();
        self.outline.push('\n');
        Span::new(NO_FILE, start, end)
    }

    fn warn(&mut self, span: Span, message: String, label: &str, note: Option<&str>) {
        self.pending.push(Pending {
            error: false,
            message,
            at: (span.start, span.end),
            label: label.into(),
            note: note.map(str::to_string),
        });
    }

    fn error(&mut self, span: Span, message: String, label: &str) {
        self.pending.push(Pending {
            error: true,
            message,
            at: (span.start, span.end),
            label: label.into(),
            note: None,
        });
    }

    /// The field `field` of the spec at `path`; decoding failures are reported at `span`.
    fn field(&mut self, path: &str, field: &str, span: Span) -> Option<sdf::Value> {
        let sdf_path = self.by_text.get(path)?;
        let data = self.data.as_ref()?;
        match data.try_field(sdf_path, field) {
            Ok(v) => v.map(|v| v.into_owned()),
            Err(e) => {
                let message = format!("malformed usdc: cannot decode field `{field}` of `{path}`: {e}");
                self.error(span, message, "this spec");
                None
            }
        }
    }

    fn fields(&self, path: &str) -> Vec<String> {
        match (self.by_text.get(path), self.data.as_ref()) {
            (Some(p), Some(data)) => data.list_fields(p).unwrap_or_default(),
            _ => Vec::new(),
        }
    }

    fn tokens(&mut self, path: &str, field: &str, span: Span) -> Vec<String> {
        match self.field(path, field, span) {
            Some(sdf::Value::TokenVec(v)) => v.iter().map(|t| t.as_str().to_string()).collect(),
            Some(sdf::Value::StringVec(v)) => v,
            Some(other) => {
                self.unexpected(span, path, field, &other);
                Vec::new()
            }
            None => Vec::new(),
        }
    }

    fn unexpected(&mut self, span: Span, path: &str, field: &str, value: &sdf::Value) {
        let kind: &'static str = value.into();
        self.error(span, format!("malformed usdc: field `{field}` of `{path}` holds a {kind}"), "this spec");
    }

    fn layer(&mut self) -> Layer {
        let root = "/";
        let span = self.line(0, "layer </>");
        let mut meta = LayerMetadata::default();
        let mut sub_paths: Vec<String> = Vec::new();
        for field in self.fields(root) {
            let Some(value) = self.field(root, &field, span) else { continue };
            match (field.as_str(), value) {
                ("primChildren", _) => {}
                ("subLayers", sdf::Value::StringVec(v)) => sub_paths = v,
                ("subLayerOffsets", sdf::Value::LayerOffsetVec(v)) => {
                    meta.sub_layer_offsets = v.iter().map(layer_offset).collect();
                }
                ("subLayerOffsets", _) => {}
                ("defaultPrim", sdf::Value::Token(t)) => {
                    let s = self.line(1, &format!("defaultPrim = \"{}\"", t.as_str()));
                    meta.default_prim = Some((t.as_str().to_string(), s));
                }
                ("upAxis", sdf::Value::Token(t)) => meta.up_axis = Some(t.as_str().to_string()),
                ("metersPerUnit", sdf::Value::Double(d)) => meta.meters_per_unit = Some(d),
                ("documentation", sdf::Value::String(s)) => meta.doc = Some(s),
                ("comment", sdf::Value::String(s)) => meta.comment = Some(s),
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(root, key, &value, span) {
                        meta.other.push(entry);
                    }
                }
            }
        }
        for sub in sub_paths {
            let s = self.line(1, &format!("subLayers @{sub}@"));
            meta.sub_layers.push((AssetPath::new(sub, self.base_dir), s));
        }
        let mut prims = Vec::new();
        for child in self.tokens(root, "primChildren", span) {
            if let Some(prim) = self.prim(&format!("/{child}"), &child, 0, 0) {
                prims.push(prim);
            }
        }
        Layer { file: NO_FILE, metadata: meta, prims, prim_index: Default::default() }
    }

    /// The prim (or, with `variant`, the variant body) at `path`.
    fn prim(&mut self, path: &str, name: &str, depth: usize, nesting: usize) -> Option<PrimSpec> {
        if !self.by_text.contains_key(path) {
            let span = self.line(depth, &format!("<{path}>"));
            self.error(span, format!("malformed usdc: `{path}` is listed as a child but has no spec"), "here");
            return None;
        }
        if nesting > 256 {
            let span = self.line(depth, &format!("<{path}>"));
            self.error(span, "malformed usdc: prims nested more than 256 deep".into(), "here");
            return None;
        }
        let fields = self.fields(path);
        let specifier = match self.field(path, "specifier", Span::default()) {
            Some(sdf::Value::Specifier(sdf::Specifier::Over)) => Specifier::Over,
            Some(sdf::Value::Specifier(sdf::Specifier::Class)) => Specifier::Class,
            Some(sdf::Value::Specifier(sdf::Specifier::Def)) => Specifier::Def,
            _ => Specifier::Over,
        };
        let type_name = match self.field(path, "typeName", Span::default()) {
            Some(sdf::Value::Token(t)) if !t.as_str().is_empty() => Some(t.as_str().to_string()),
            _ => None,
        };
        let keyword = match specifier {
            Specifier::Def => "def",
            Specifier::Over => "over",
            Specifier::Class => "class",
        };
        let text = match &type_name {
            Some(t) => format!("{keyword} {t} <{path}>"),
            None => format!("{keyword} <{path}>"),
        };
        let span = self.line(depth, &text);
        let mut prim = PrimSpec {
            specifier,
            type_name,
            name: name.to_string(),
            span,
            metadata: PrimMetadata::default(),
            properties: Vec::new(),
            children: Vec::new(),
            child_index: Default::default(),
            variant_sets: Vec::new(),
        };
        self.prim_metadata(path, &fields, &mut prim.metadata, span, depth + 1);
        for property in self.tokens(path, "propertyChildren", span) {
            if let Some(p) = self.property(&format!("{path}.{property}"), &property, depth + 1) {
                prim.properties.push(p);
            }
        }
        // Children of a variant body are written `/A{set=v}Child`, of a prim `/A/Child`.
        let sep = if path.ends_with('}') || path == "/" { "" } else { "/" };
        for child in self.tokens(path, "primChildren", span) {
            if let Some(c) = self.prim(&format!("{path}{sep}{child}"), &child, depth + 1, nesting + 1) {
                prim.children.push(c);
            }
        }
        for set in self.tokens(path, "variantSetChildren", span) {
            let set_path = format!("{path}{{{set}=}}");
            let set_span = self.line(depth + 1, &format!("variantSet \"{set}\" <{set_path}>"));
            let mut spec = VariantSetSpec { name: set.clone(), span: set_span, variants: Vec::new() };
            for variant in self.tokens(&set_path, "variantChildren", set_span) {
                let variant_path = format!("{path}{{{set}={variant}}}");
                if let Some(mut body) = self.prim(&variant_path, &variant, depth + 2, nesting + 1) {
                    body.specifier = Specifier::Over;
                    spec.variants.push(body);
                }
            }
            prim.variant_sets.push(spec);
        }
        Some(prim)
    }

    fn prim_metadata(&mut self, path: &str, fields: &[String], meta: &mut PrimMetadata, span: Span, depth: usize) {
        for field in fields {
            let field = field.as_str();
            if matches!(
                field,
                "specifier"
                    | "typeName"
                    | "propertyChildren"
                    | "primChildren"
                    | "variantSetChildren"
                    | "variantChildren"
            ) {
                continue;
            }
            let Some(value) = self.field(path, field, span) else { continue };
            match (field, value) {
                ("references", sdf::Value::ReferenceListOp(op)) => {
                    meta.references =
                        self.references(op, depth, "references", |r| (r.asset_path, r.prim_path, r.layer_offset))
                }
                ("payload", sdf::Value::PayloadListOp(op)) => {
                    meta.payloads = self.references(op, depth, "payload", |r| {
                        (r.asset_path, r.prim_path, r.layer_offset.unwrap_or_default())
                    })
                }
                ("payload", sdf::Value::Payload(p)) => {
                    let op = sdf::ListOp { explicit: true, explicit_items: vec![p], ..Default::default() };
                    meta.payloads = self.references(op, depth, "payload", |r| {
                        (r.asset_path, r.prim_path, r.layer_offset.unwrap_or_default())
                    });
                }
                ("inheritPaths", sdf::Value::PathListOp(op)) => meta.inherits = self.targets(op, depth, "inherits"),
                ("specializes", sdf::Value::PathListOp(op)) => {
                    meta.specializes = self.targets(op, depth, "specializes")
                }
                ("variantSelection", sdf::Value::VariantSelectionMap(map)) => {
                    let mut pairs: Vec<(String, String)> = map.into_iter().collect();
                    pairs.sort();
                    for (set, selection) in pairs {
                        let s = self.line(depth, &format!("variants: {set} = \"{selection}\""));
                        meta.variant_selections.push((set, selection, s));
                    }
                }
                ("variantSetNames", sdf::Value::StringListOp(op)) => meta.variant_set_names = list_op(op, |s| s),
                ("variantSetNames", sdf::Value::TokenListOp(op)) => {
                    meta.variant_set_names = list_op(op, |t| t.as_str().to_string())
                }
                ("apiSchemas", sdf::Value::TokenListOp(op)) => {
                    meta.api_schemas = list_op(op, |t| t.as_str().to_string())
                }
                ("kind", sdf::Value::Token(t)) => meta.kind = Some(t.as_str().to_string()),
                ("active", sdf::Value::Bool(b)) => meta.active = Some(b),
                ("instanceable", sdf::Value::Bool(b)) => meta.instanceable = Some(b),
                ("documentation", sdf::Value::String(s)) => meta.doc = Some(s),
                ("comment", sdf::Value::String(s)) => meta.comment = Some(s),
                (
                    key @ ("references" | "payload" | "inheritPaths" | "specializes" | "variantSelection"
                    | "variantSetNames" | "apiSchemas" | "kind" | "active" | "instanceable"),
                    value,
                ) => self.unexpected(span, path, key, &value),
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(path, key, &value, span) {
                        meta.other.push(entry);
                    }
                }
            }
        }
    }

    /// References or payloads, one outline line per item.
    fn references<T: Default + Clone + PartialEq>(
        &mut self,
        op: sdf::ListOp<T>,
        depth: usize,
        what: &str,
        parts: impl Fn(T) -> (String, sdf::Path, sdf::LayerOffset),
    ) -> ListOp<Reference> {
        let mut convert = |items: Vec<T>| -> Vec<Reference> {
            items
                .into_iter()
                .map(|item| {
                    let (asset, prim, offset) = parts(item);
                    let prim = (!prim.is_empty()).then(|| prim.as_str().to_string());
                    let text = format!(
                        "{what} {}{}",
                        if asset.is_empty() { String::new() } else { format!("@{asset}@") },
                        prim.as_deref().map(|p| format!("<{p}>")).unwrap_or_default()
                    );
                    let span = self.line(depth, &text);
                    let asset = (!asset.is_empty()).then(|| AssetPath::new(asset, self.base_dir));
                    Reference { asset, prim_path: prim, span, offset: layer_offset(&offset) }
                })
                .collect()
        };
        ListOp {
            explicit: if op.explicit { Some(convert(op.explicit_items)) } else { None },
            prepended: convert(op.prepended_items),
            appended: convert(op.appended_items),
            deleted: convert(op.deleted_items),
            added: convert(op.added_items),
            ordered: convert(op.ordered_items),
        }
    }

    /// Path list ops (inherits, targets, connections), one outline line per path.
    fn targets(&mut self, op: sdf::PathListOp, depth: usize, what: &str) -> ListOp<Target> {
        let mut convert = |items: Vec<sdf::Path>| -> Vec<Target> {
            items
                .into_iter()
                .map(|p| {
                    let text = p.as_str().to_string();
                    let span = self.line(depth, &format!("{what} <{text}>"));
                    (text, span)
                })
                .collect()
        };
        ListOp {
            explicit: if op.explicit { Some(convert(op.explicit_items)) } else { None },
            prepended: convert(op.prepended_items),
            appended: convert(op.appended_items),
            deleted: convert(op.deleted_items),
            added: convert(op.added_items),
            ordered: convert(op.ordered_items),
        }
    }

    fn property(&mut self, path: &str, name: &str, depth: usize) -> Option<PropertySpec> {
        let data = self.data.as_ref()?;
        let kind = self.by_text.get(path).and_then(|p| data.spec_type(p));
        match kind {
            Some(sdf::SpecType::Attribute) => self.attribute(path, name, depth),
            Some(sdf::SpecType::Relationship) => self.relationship(path, name, depth),
            _ => {
                let span = self.line(depth, &format!("<{path}>"));
                self.error(span, format!("malformed usdc: `{path}` is listed as a property but is not one"), "here");
                None
            }
        }
    }

    fn attribute(&mut self, path: &str, name: &str, depth: usize) -> Option<PropertySpec> {
        let type_name = match self.field(path, "typeName", Span::default()) {
            Some(sdf::Value::Token(t)) => t.as_str().to_string(),
            _ => String::new(),
        };
        let uniform = matches!(
            self.field(path, "variability", Span::default()),
            Some(sdf::Value::Variability(sdf::Variability::Uniform))
        );
        let custom = matches!(self.field(path, "custom", Span::default()), Some(sdf::Value::Bool(true)));
        let text = format!(
            "{}{}{type_name} <{path}>",
            if custom { "custom " } else { "" },
            if uniform { "uniform " } else { "" }
        );
        let span = self.line(depth, &text);
        let mut attr = AttributeSpec::declared(name, span, type_name.clone(), custom, uniform);
        let value_type = attr.value_type;
        for field in self.fields(path) {
            let field = field.as_str();
            if matches!(field, "typeName" | "variability" | "custom") {
                continue;
            }
            let Some(value) = self.field(path, field, span) else { continue };
            match (field, value) {
                ("default", value) => {
                    if let Some(v) = self.typed(path, field, &value, &value_type, span) {
                        attr.default = Some((v, span));
                    }
                }
                ("timeSamples", sdf::Value::TimeSamples(samples)) => {
                    for (time, value) in samples {
                        if let Some(v) = self.typed(path, field, &value, &value_type, span) {
                            attr.time_samples.push((time, v));
                        }
                    }
                }
                ("connectionPaths", sdf::Value::PathListOp(op)) => {
                    attr.connections = self.targets(op, depth + 1, "connect")
                }
                (key @ ("timeSamples" | "connectionPaths"), value) => self.unexpected(span, path, key, &value),
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(path, key, &value, span) {
                        attr.metadata.push(entry);
                    }
                }
            }
        }
        Some(PropertySpec::Attribute(Box::new(attr)))
    }

    fn relationship(&mut self, path: &str, name: &str, depth: usize) -> Option<PropertySpec> {
        let custom = matches!(self.field(path, "custom", Span::default()), Some(sdf::Value::Bool(true)));
        let span = self.line(depth, &format!("{}rel <{path}>", if custom { "custom " } else { "" }));
        let mut rel = RelationshipSpec {
            name: name.to_string(),
            span,
            custom,
            targets: ListOp::default(),
            explicit_none: false,
            authored: None,
            metadata: Vec::new(),
        };
        for field in self.fields(path) {
            let field = field.as_str();
            if matches!(field, "custom" | "variability") {
                continue;
            }
            let Some(value) = self.field(path, field, span) else { continue };
            match (field, value) {
                ("targetPaths", sdf::Value::PathListOp(op)) => {
                    // `rel r = None` is an explicit empty list in a crate, as `= []` is.
                    rel.explicit_none = op.explicit && op.explicit_items.is_empty();
                    rel.targets = self.targets(op, depth + 1, "target");
                    rel.authored = Some(span);
                }
                ("targetPaths", value) => self.unexpected(span, path, "targetPaths", &value),
                // Target specs' children: nothing strata reads.
                ("targetChildren", _) => {}
                (key, value) => {
                    if let Some(entry) = self.metadata_entry(path, key, &value, span) {
                        rel.metadata.push(entry);
                    }
                }
            }
        }
        Some(PropertySpec::Relationship(Box::new(rel)))
    }

    /// A value of a declared type, exactly as the usda parser would hold it.
    fn typed(&mut self, path: &str, field: &str, value: &sdf::Value, ty: &ValueType, span: Span) -> Option<Value> {
        let converted = match convert_value(value, self.base_dir, false) {
            Ok(v) => v,
            // A value strata would read but cannot convert is an error, never a silently
            // missing value (unlike metadata strata never reads, below: a warning).
            Err(kind) => {
                self.error(
                    span,
                    format!(
                        "unsupported in usdc: `{path}` field `{field}` holds a {kind}, which strata does not convert"
                    ),
                    "this property",
                );
                return None;
            }
        };
        match converted.coerce(ty) {
            Ok(v) => Some(v),
            Err(message) => {
                self.error(span, format!("`{path}`: field `{field}` does not match the declared type"), &message);
                None
            }
        }
    }

    /// Any other metadata field, kept as the usda parser keeps it (`doc` for
    /// `documentation`; tokens as the strings usda writes).
    fn metadata_entry(&mut self, path: &str, key: &str, value: &sdf::Value, span: Span) -> Option<MetadataEntry> {
        let key = if key == "documentation" { "doc" } else { key };
        match convert_value(value, self.base_dir, true) {
            Ok(value) => Some(MetadataEntry { key: key.to_string(), op: Default::default(), value, span }),
            Err(kind) => {
                self.warn(
                    span,
                    format!("`{path}`: metadata `{key}` holds a {kind}, which strata does not convert; ignored"),
                    "this spec",
                    None,
                );
                None
            }
        }
    }
}

fn list_op<T: Default + Clone + PartialEq, U>(op: sdf::ListOp<T>, f: impl Fn(T) -> U) -> ListOp<U> {
    let map = |items: Vec<T>| items.into_iter().map(&f).collect::<Vec<U>>();
    ListOp {
        explicit: if op.explicit { Some(map(op.explicit_items)) } else { None },
        prepended: map(op.prepended_items),
        appended: map(op.appended_items),
        deleted: map(op.deleted_items),
        added: map(op.added_items),
        ordered: map(op.ordered_items),
    }
}

/// A `float` as the `f64` its shortest decimal form parses to: the value a usda file
/// written from the same data holds, so both formats read the same.
fn widen_f32(x: f32) -> f64 {
    if !x.is_finite() || x == 0.0 {
        return f64::from(x);
    }
    let mut buf = StackText::default();
    if write!(buf, "{x:e}").is_ok()
        && let Ok(s) = std::str::from_utf8(&buf.bytes[..buf.len])
        && let Ok(v) = s.parse::<f64>()
    {
        return v;
    }
    f64::from(x)
}

fn widen_f16(x: openusd::gf::f16) -> f64 {
    widen_f32(x.to_f32())
}

/// A small fixed buffer for formatting a number without allocating.
struct StackText {
    bytes: [u8; 48],
    len: usize,
}

impl Default for StackText {
    fn default() -> Self {
        StackText { bytes: [0; 48], len: 0 }
    }
}

impl std::fmt::Write for StackText {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        let end = self.len + s.len();
        let slot = self.bytes.get_mut(self.len..end).ok_or(std::fmt::Error)?;
        slot.copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

fn flat<E: Copy, const N: usize, T: Into<[E; N]> + Copy>(items: &[T], f: impl Fn(E) -> f64) -> Value {
    let mut data = Vec::with_capacity(items.len() * N);
    for item in items {
        let parts: [E; N] = (*item).into();
        data.extend(parts.iter().map(|&e| f(e)));
    }
    Value::TupleArray { width: N, data }
}

fn tuple<E: Copy, const N: usize, T: Into<[E; N]> + Copy>(item: &T, f: impl Fn(E) -> f64) -> Value {
    let parts: [E; N] = (*item).into();
    Value::Tuple(parts.iter().map(|&e| f(e)).collect())
}

/// Converts one openusd value. `metadata`: top-level metadata, where usda writes tokens as
/// strings. `Err` names the value kind strata does not convert.
fn convert_value(value: &sdf::Value, base_dir: &Path, metadata: bool) -> Result<Value, &'static str> {
    use sdf::Value as S;
    let d = |x: f64| x;
    let f = widen_f32;
    let h = widen_f16;
    let int = |x: i64| Value::Int(x);
    Ok(match value {
        S::None | S::ValueBlock => Value::None,
        S::Bool(b) => Value::Bool(*b),
        S::BoolVec(v) => Value::BoolArray(v.clone()),
        S::Uchar(x) => int(i64::from(*x)),
        S::Int(x) => int(i64::from(*x)),
        S::Uint(x) => int(i64::from(*x)),
        S::Int64(x) => int(*x),
        S::Uint64(x) => int(i64::try_from(*x).map_err(|_| "uint64 beyond the int64 range")?),
        S::UcharVec(v) => Value::IntArray(v.iter().map(|&x| i64::from(x)).collect()),
        S::IntVec(v) => Value::IntArray(v.iter().map(|&x| i64::from(x)).collect()),
        S::UintVec(v) => Value::IntArray(v.iter().map(|&x| i64::from(x)).collect()),
        S::Int64Vec(v) => Value::IntArray(v.clone()),
        S::Uint64Vec(v) => Value::IntArray(
            v.iter()
                .map(|&x| i64::try_from(x))
                .collect::<Result<_, _>>()
                .map_err(|_| "uint64 beyond the int64 range")?,
        ),
        S::Half(x) => Value::Float(h(*x)),
        S::Float(x) => Value::Float(f(*x)),
        S::Double(x) => Value::Float(*x),
        S::HalfVec(v) => Value::FloatArray(v.iter().map(|&x| h(x)).collect()),
        S::FloatVec(v) => Value::FloatArray(v.iter().map(|&x| f(x)).collect()),
        S::DoubleVec(v) => Value::FloatArray(v.clone()),
        S::TimeCode(t) => Value::Float(t.0),
        S::TimeCodeVec(v) => Value::FloatArray(v.iter().map(|t| t.0).collect()),
        S::String(s) => Value::String(s.clone()),
        S::StringVec(v) => Value::StringArray(v.clone()),
        S::Token(t) if metadata => Value::String(t.as_str().to_string()),
        S::Token(t) => Value::Token(t.as_str().to_string()),
        S::TokenVec(v) if metadata => Value::StringArray(v.iter().map(|t| t.as_str().to_string()).collect()),
        S::TokenVec(v) => Value::TokenArray(v.iter().map(|t| t.as_str().to_string()).collect()),
        S::AssetPath(a) => Value::Asset(AssetPath::new(a.authored_path.clone(), base_dir)),
        S::AssetPathVec(v) => {
            Value::AssetArray(v.iter().map(|a| AssetPath::new(a.authored_path.clone(), base_dir)).collect())
        }
        S::PathVec(v) => Value::PathArray(v.iter().map(|p| p.as_str().to_string()).collect()),
        S::Quath(q) => tuple::<_, 4, _>(q, h),
        S::Quatf(q) => tuple::<_, 4, _>(q, f),
        S::Quatd(q) => tuple::<_, 4, _>(q, d),
        S::QuathVec(v) => flat::<_, 4, _>(v, h),
        S::QuatfVec(v) => flat::<_, 4, _>(v, f),
        S::QuatdVec(v) => flat::<_, 4, _>(v, d),
        S::Vec2h(x) => tuple::<_, 2, _>(x, h),
        S::Vec2f(x) => tuple::<_, 2, _>(x, f),
        S::Vec2d(x) => tuple::<_, 2, _>(x, d),
        S::Vec2i(x) => tuple::<_, 2, _>(x, |i: i32| f64::from(i)),
        S::Vec3h(x) => tuple::<_, 3, _>(x, h),
        S::Vec3f(x) => tuple::<_, 3, _>(x, f),
        S::Vec3d(x) => tuple::<_, 3, _>(x, d),
        S::Vec3i(x) => tuple::<_, 3, _>(x, |i: i32| f64::from(i)),
        S::Vec4h(x) => tuple::<_, 4, _>(x, h),
        S::Vec4f(x) => tuple::<_, 4, _>(x, f),
        S::Vec4d(x) => tuple::<_, 4, _>(x, d),
        S::Vec4i(x) => tuple::<_, 4, _>(x, |i: i32| f64::from(i)),
        S::Vec2hVec(v) => flat::<_, 2, _>(v, h),
        S::Vec2fVec(v) => flat::<_, 2, _>(v, f),
        S::Vec2dVec(v) => flat::<_, 2, _>(v, d),
        S::Vec2iVec(v) => flat::<_, 2, _>(v, |i: i32| f64::from(i)),
        S::Vec3hVec(v) => flat::<_, 3, _>(v, h),
        S::Vec3fVec(v) => flat::<_, 3, _>(v, f),
        S::Vec3dVec(v) => flat::<_, 3, _>(v, d),
        S::Vec3iVec(v) => flat::<_, 3, _>(v, |i: i32| f64::from(i)),
        S::Vec4hVec(v) => flat::<_, 4, _>(v, h),
        S::Vec4fVec(v) => flat::<_, 4, _>(v, f),
        S::Vec4dVec(v) => flat::<_, 4, _>(v, d),
        S::Vec4iVec(v) => flat::<_, 4, _>(v, |i: i32| f64::from(i)),
        S::Matrix2d(m) => Value::Matrix2(m.0),
        S::Matrix3d(m) => Value::Matrix3(m.0),
        S::Matrix4d(m) => Value::Matrix(m.0),
        S::Matrix2dVec(v) => Value::TupleArray { width: 4, data: v.iter().flat_map(|m| m.0).collect() },
        S::Matrix3dVec(v) => Value::TupleArray { width: 9, data: v.iter().flat_map(|m| m.0).collect() },
        S::Matrix4dVec(v) => Value::TupleArray { width: 16, data: v.iter().flat_map(|m| m.0).collect() },
        S::Dictionary(map) => {
            // Sorted by key: USD's dictionaries are ordered maps, and usda lists them so.
            let mut entries: Vec<(String, Value)> = Vec::with_capacity(map.len());
            for (k, v) in map {
                entries.push((k.clone(), convert_value(v, base_dir, false)?));
            }
            entries.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Dictionary(entries)
        }
        S::VariantSelectionMap(map) => {
            let mut entries: Vec<(String, Value)> =
                map.iter().map(|(k, v)| (k.clone(), Value::String(v.clone()))).collect();
            entries.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Dictionary(entries)
        }
        S::ValueVec(v) => {
            Value::List(v.iter().map(|x| convert_value(x, base_dir, false)).collect::<Result<Vec<_>, _>>()?)
        }
        S::Specifier(s) => Value::Token(
            match s {
                sdf::Specifier::Def => "def",
                sdf::Specifier::Over => "over",
                sdf::Specifier::Class => "class",
            }
            .into(),
        ),
        S::Permission(p) => Value::Token(
            match p {
                sdf::Permission::Public => "public",
                sdf::Permission::Private => "private",
            }
            .into(),
        ),
        S::PathExpression(e) => Value::String(e.clone()),
        S::Variability(v) => Value::Token(
            match v {
                sdf::Variability::Varying => "varying",
                sdf::Variability::Uniform => "uniform",
            }
            .into(),
        ),
        other => return Err(other.into()),
    })
}

// ---- span fix-up ----

fn fix(span: &mut Span, file: FileId) {
    if span.file == NO_FILE {
        span.file = file;
    }
}

fn fix_op<T>(op: &mut ListOp<T>, file: FileId, f: impl Fn(&mut T, FileId)) {
    let ListOp { explicit, prepended, appended, deleted, added, ordered } = op;
    for list in [prepended, appended, deleted, added, ordered].into_iter().chain(explicit.as_mut()) {
        for item in list {
            f(item, file);
        }
    }
}

fn fix_entries(entries: &mut [MetadataEntry], file: FileId) {
    for e in entries {
        fix(&mut e.span, file);
    }
}

/// Points every span of a converted layer at the outline registered as `file`.
fn retarget_layer(layer: &mut Layer, file: FileId) {
    if let Some((_, s)) = &mut layer.metadata.default_prim {
        fix(s, file);
    }
    for (_, s) in &mut layer.metadata.sub_layers {
        fix(s, file);
    }
    fix_entries(&mut layer.metadata.other, file);
    for prim in &mut layer.prims {
        retarget_prim(prim, file);
    }
}

fn retarget_prim(prim: &mut PrimSpec, file: FileId) {
    fix(&mut prim.span, file);
    let m = &mut prim.metadata;
    fix_op(&mut m.references, file, |r, f| fix(&mut r.span, f));
    fix_op(&mut m.payloads, file, |r, f| fix(&mut r.span, f));
    fix_op(&mut m.inherits, file, |t, f| fix(&mut t.1, f));
    fix_op(&mut m.specializes, file, |t, f| fix(&mut t.1, f));
    for (_, _, s) in &mut m.variant_selections {
        fix(s, file);
    }
    fix_entries(&mut m.other, file);
    for property in &mut prim.properties {
        match property {
            PropertySpec::Attribute(a) => {
                fix(&mut a.span, file);
                if let Some((_, s)) = &mut a.default {
                    fix(s, file);
                }
                fix_op(&mut a.connections, file, |t, f| fix(&mut t.1, f));
                fix_entries(&mut a.metadata, file);
            }
            PropertySpec::Relationship(r) => {
                fix(&mut r.span, file);
                if let Some(s) = &mut r.authored {
                    fix(s, file);
                }
                fix_op(&mut r.targets, file, |t, f| fix(&mut t.1, f));
                fix_entries(&mut r.metadata, file);
            }
        }
    }
    for child in &mut prim.children {
        retarget_prim(child, file);
    }
    for set in &mut prim.variant_sets {
        fix(&mut set.span, file);
        for variant in &mut set.variants {
            retarget_prim(variant, file);
        }
    }
}

/// A crate file's layer offset; non-finite parts are the identity's.
fn layer_offset(o: &sdf::LayerOffset) -> LayerOffset {
    let identity = LayerOffset::default();
    LayerOffset {
        offset: if o.offset.is_finite() { o.offset } else { identity.offset },
        scale: if o.scale.is_finite() { o.scale } else { identity.scale },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_are_told_by_content() {
        assert_eq!(detect(b"PXR-USDC\0\0"), Format::Crate);
        assert_eq!(detect(b"PK\x03\x04rest"), Format::Package);
        assert_eq!(detect(b"#usda 1.0\n"), Format::Text);
        assert_eq!(detect(b""), Format::Text);
    }

    #[test]
    fn materialx_documents_are_told_by_name_or_content() {
        let usda = Path::new("look.usda");
        assert!(is_materialx(Path::new("X_mat.mtlx"), b"anything"));
        assert!(is_materialx(Path::new("pkg.usdz[mat/X.MTLX]"), b""));
        assert!(is_materialx(usda, b"\xEF\xBB\xBF  <?xml version=\"1.0\"?>"));
        assert!(is_materialx(usda, b"\n<materialx version=\"1.38\">"));
        assert!(!is_materialx(usda, b"#usda 1.0\n"));
        assert!(!is_materialx(usda, b"<"));
    }

    #[test]
    fn floats_widen_through_their_shortest_decimal() {
        // What a usda file holds for 0.1f is "0.1": both formats must read 0.1.
        assert_eq!(widen_f32(0.1), 0.1);
        assert_eq!(widen_f32(-2.5e-7), -2.5e-7);
        assert_eq!(widen_f32(3.4028235e38), 3.4028235e38);
        assert_eq!(widen_f32(1e-45), 1e-45);
        assert_eq!(widen_f32(0.0), 0.0);
        assert!(widen_f32(f32::NAN).is_nan());
        assert_eq!(widen_f32(f32::INFINITY), f64::INFINITY);
        // Still the same f32 when narrowed again.
        for x in [0.1f32, 1.0 / 3.0, 123456.79, 7e-39] {
            assert_eq!(widen_f32(x) as f32, x);
        }
    }

    /// A crate written by openusd's own writer, with a prim `/A` holding attribute `x`.
    fn crate_with(default: sdf::Value, metadata: Option<(&str, sdf::Value)>) -> Vec<u8> {
        let mut data = sdf::Data::new();
        let root = sdf::Path::abs_root();
        let a = sdf::path("/A").unwrap();
        let x = sdf::path("/A.x").unwrap();
        data.create_spec(root.clone(), sdf::SpecType::PseudoRoot);
        data.set_field(&root, "primChildren", sdf::Value::TokenVec(vec!["A".into()]));
        data.create_spec(a.clone(), sdf::SpecType::Prim);
        data.set_field(&a, "specifier", sdf::Value::Specifier(sdf::Specifier::Def));
        data.set_field(&a, "propertyChildren", sdf::Value::TokenVec(vec!["x".into()]));
        data.create_spec(x.clone(), sdf::SpecType::Attribute);
        data.set_field(&x, "typeName", sdf::Value::Token("int".into()));
        data.set_field(&x, "default", default);
        if let Some((key, value)) = metadata {
            data.set_field(&x, key, value);
        }
        let mut out = std::io::Cursor::new(Vec::new());
        openusd::usdc::CrateWriter::write(&data, &mut out).unwrap();
        out.into_inner()
    }

    fn convert_text(bytes: &[u8]) -> (Layer, Diagnostics, SourceMap) {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let layer = convert("t.usdc", bytes, Path::new("/d"), &mut sources, &mut diags);
        (layer, diags, sources)
    }

    #[test]
    fn values_strata_cannot_convert_are_errors_and_metadata_a_warning() {
        let (layer, diags, _) = convert_text(&crate_with(sdf::Value::Int(3), None));
        assert!(!diags.has_errors());
        let Some(PropertySpec::Attribute(x)) = layer.prims[0].property("x") else { panic!("x") };
        assert_eq!(x.default.as_ref().map(|(v, _)| v.clone()), Some(Value::Int(3)));

        let op = sdf::IntListOp { explicit: true, explicit_items: vec![1], ..Default::default() };
        let (_, diags, sources) = convert_text(&crate_with(sdf::Value::IntListOp(op.clone()), None));
        let text = diags.render(&sources);
        assert!(diags.has_errors(), "{text}");
        assert!(text.contains("`/A.x` field `default` holds a IntListOp") && text.contains("t.usdc:"), "{text}");
        assert!(text.contains("int </A.x>"), "the outline line names the property: {text}");

        let (_, diags, sources) =
            convert_text(&crate_with(sdf::Value::Int(3), Some(("weird", sdf::Value::IntListOp(op)))));
        let text = diags.render(&sources);
        assert!(!diags.has_errors() && text.contains("metadata `weird`"), "{text}");
    }

    #[test]
    fn lz4_lengths_come_from_sequence_headers() {
        assert_eq!(lz4_decoded_len(&[0, 0x50, b'a', b'b', b'c', b'd', b'e']), Some(5));
        // One literal, a match of 15 + 10 + 4 bytes, then a last literal.
        assert_eq!(lz4_decoded_len(&[0, 0x1f, b'a', 1, 0, 10, 0x10, b'b']), Some(31));
        assert_eq!(lz4_decoded_len(&[]), Some(0));
        assert_eq!(lz4_decoded_len(&[0, 0x50, b'a']), None, "literals past the end");
        assert_eq!(lz4_decoded_len(&[0, 0xf0]), None, "a length extension past the end");
        assert_eq!(lz4_decoded_len(&[2, 0x10, b'a']), None, "chunked: openusd cannot read it");
    }

    #[test]
    fn precheck_names_what_is_wrong() {
        let mut header = b"PXR-USDC".to_vec();
        header.extend_from_slice(&[0, 3, 0, 0, 0, 0, 0, 0]);
        header.extend_from_slice(&88u64.to_le_bytes());
        let err = precheck(&header).unwrap_err();
        assert!(err.contains("unsupported crate version 0.3.0"), "{err}");
        header[9] = 8;
        let err = precheck(&header).unwrap_err();
        assert!(err.contains("table of contents lies outside"), "{err}");
        assert!(precheck(b"PXR-USDC").unwrap_err().contains("truncated"));
    }
}
