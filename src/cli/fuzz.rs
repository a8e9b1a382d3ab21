//! `strata fuzz`: mutation fuzzing of both front ends and the whole `check` pipeline, on the
//! stable toolchain (no sanitizer coverage needed).
//!
//! The corpus is every `.ash`, `.usda`, `.usdc`, `.usdz` and `.mtlx` file under the
//! repository's `scenes/`, `tests/in/`, `tests/fixtures/` and `fuzz/corpus/` (where inputs
//! that once crashed are kept), plus the prelude. Input `k` of a run is a deterministic function of the
//! seed and `k`: a corpus file with 1 to 8 mutations. Text is mutated byte-level (replace,
//! delete, insert, duplicate, splice from another file) or structurally (repeat a span
//! hundreds of times, swap in an extreme number, insert a token of either language). Binary
//! crates and packages get binary mutations (bit flips, extreme little-endian integers, chunk
//! copies, truncation); a package's members are mutated inside, and their CRCs fixed after, so
//! the zip reader passes them on to the layer readers. Each input goes through `check`
//! in-process and, for substance files, through lowering and the JIT (every input) and the
//! interpreter (one in eight); for scenes, one in sixteen is also rendered at 4x4. A MaterialX
//! document is checked as a layer and through a scene that binds each of its materials (as
//! USD's MaterialX plugin names them, `/MaterialX/Materials/NAME`) to a sphere, so its
//! mutations reach translation, compilation and, one in sixteen, a render. With
//! `--quick`, inputs are only read and composed (scenes) or parsed (substances): many times
//! more executions per second, for the readers.
//!
//! Oracles: a crash (panic, abort, signal), an allocation failure (its message in the
//! worker's stderr, a class of its own), a hang past the per-input time, a peak resident
//! memory past the cap (the worker resets and reads its high-water mark around every input,
//! so a short spike between the parent's polls is caught too), and diagnostics larger than
//! [`STDERR_PER_INPUT_BYTE`] times the input plus [`STDERR_SLACK`] (what `check` would print).
//!
//! Inputs run in worker processes (this same binary, `fuzz --worker`) so that a crash, an
//! abort, a hang or a memory blow-up costs one worker, not the run: the parent watches each
//! worker's progress and resident memory, kills it past the per-input time or memory budget,
//! saves the input that did it under the crash directory, and starts a new worker after it.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};
use strata::backend::{BackendKind, Compiler};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap, Span};
use strata::front::ast::GraphKind;
use strata::front::library::Library;
use strata::ir::wired::PassOptions;

/// Folders of the repository whose files make the corpus (and are staged for each worker, so
/// that relative references between them resolve).
pub const CORPUS_DIRS: [&str; 4] = ["scenes", "tests/in", "tests/fixtures", "fuzz/corpus"];

/// The kinds of file inputs are made from; every other corpus file is staged as an asset.
const FUZZED_EXTENSIONS: [&str; 5] = ["ash", "usda", "usdc", "usdz", "mtlx"];

/// Files larger than this are neither mutated nor staged (the corpus is source text).
const MAX_CORPUS_FILE: u64 = 1 << 20;

/// One corpus file: its path relative to the repository root and its bytes.
#[derive(Clone, Debug)]
pub struct Entry {
    /// Path relative to the corpus root (`scenes/default/default.usda`).
    pub rel: PathBuf,
    /// The file's bytes.
    pub bytes: Vec<u8>,
}

impl Entry {
    fn is_substance(&self) -> bool {
        self.rel.extension().is_some_and(|e| e == "ash")
    }

    fn is_materialx(&self) -> bool {
        self.rel.extension().is_some_and(|e| e == "mtlx")
    }

    /// A crate or a package: mutated as bytes, not as text.
    fn is_binary(&self) -> bool {
        self.rel.extension().is_some_and(|e| e == "usdc" || e == "usdz") || self.bytes.starts_with(b"PXR-USDC")
    }

    fn is_package(&self) -> bool {
        self.bytes.starts_with(b"PK\x03\x04")
    }
}

/// The files inputs are made from, and the other files they may refer to.
#[derive(Clone, Debug, Default)]
pub struct Corpus {
    /// `.ash`, `.usda`, `.usdc`, `.usdz` and `.mtlx` files, sorted by path (so input `k` is the
    /// same on every machine).
    pub entries: Vec<Entry>,
    /// Every other staged file (textures and the like), relative path and bytes.
    pub assets: Vec<Entry>,
}

impl Corpus {
    /// Loads the corpus under `root` (the repository), plus the prelude as `prelude.ash`.
    pub fn load(root: &Path) -> std::io::Result<Corpus> {
        let mut corpus = Corpus::default();
        corpus.entries.push(Entry { rel: "prelude.ash".into(), bytes: strata::front::library::PRELUDE.into() });
        let mut stack: Vec<PathBuf> = CORPUS_DIRS.iter().map(|d| root.join(d)).filter(|d| d.is_dir()).collect();
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir)? {
                let entry = entry?;
                let path = entry.path();
                let kind = entry.file_type()?;
                if kind.is_dir() {
                    stack.push(path);
                } else if kind.is_file() && entry.metadata()?.len() <= MAX_CORPUS_FILE {
                    let rel = path.strip_prefix(root).unwrap_or(&path).to_path_buf();
                    let item = Entry { rel, bytes: std::fs::read(&path)? };
                    // Binary layers and packages are mutated too: the usdc and zip readers must
                    // turn every corrupt crate or package into a diagnostic.
                    if item.rel.extension().is_some_and(|e| FUZZED_EXTENSIONS.iter().any(|f| e == *f)) {
                        corpus.entries.push(item);
                    } else {
                        corpus.assets.push(item);
                    }
                }
            }
        }
        corpus.entries.sort_by(|a, b| a.rel.cmp(&b.rel));
        corpus.assets.sort_by(|a, b| a.rel.cmp(&b.rel));
        Ok(corpus)
    }

    /// Writes every file under `dir`, as the workers see them.
    pub fn stage(&self, dir: &Path) -> std::io::Result<()> {
        for e in self.entries.iter().chain(&self.assets) {
            let path = dir.join(&e.rel);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent)?;
            }
            std::fs::write(path, &e.bytes)?;
        }
        Ok(())
    }

    /// Input `k` of the run seeded `seed`: `(corpus entry, mutated bytes)`.
    pub fn input(&self, seed: u64, k: u64) -> (usize, Vec<u8>) {
        let mut rng = Rng::new(seed ^ k.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let which = rng.below(self.entries.len());
        let entry = &self.entries[which];
        let mut bytes = entry.bytes.clone();
        let mutations = 1 + rng.below(8);
        if entry.is_package() && rng.below(4) != 0 {
            // Inside one member, CRCs fixed after: what the layer readers see.
            let members = zip_members(&bytes);
            if !members.is_empty() {
                let (start, end) = members[rng.below(members.len())];
                let mut member = bytes[start..end].to_vec();
                for _ in 0..mutations {
                    mutate_binary(&mut rng, &mut member, true);
                }
                bytes[start..end].copy_from_slice(&member);
                fix_zip_crcs(&mut bytes);
                return (which, bytes);
            }
        }
        for _ in 0..mutations {
            if entry.is_binary() {
                mutate_binary(&mut rng, &mut bytes, false);
            } else {
                mutate(&mut rng, &mut bytes, self);
            }
        }
        (which, bytes)
    }
}

/// xorshift64*: small, fast and the same everywhere.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(seed | 1)
    }
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Bytes that matter to one of the two grammars.
const ALPHABET: &[u8] = b"{}()[];,.=+-*/<>!&|?:@\"'#_ \n\t0123456789abcxyzeE";

/// Numbers that break careless code.
const EXTREMES: [&str; 12] =
    ["1e38", "-1e39", "3.4e38", "nan", "inf", "-0", "0", "2147483648", "-2147483649", "1e-45", "65536", "1e300"];

/// Tokens of the languages (strata's, USD's, MaterialX's XML) worth inserting.
const TOKENS: [&str; 40] = [
    "substance s { node d = diffuse(); surface = d.bsdf; }",
    "override o { output float x = 1.0; }",
    "shader f(output float o = 0.0) { o = 1.0; }",
    "node n = noise();",
    "for (;;) { break; }",
    "while (1) {}",
    "float a[65536];",
    "return",
    "(((",
    ")))",
    "{{{",
    "}}}",
    "x + x + x + x",
    "def Xform \"X\" {}",
    "over \"X\" {}",
    "rel material:slotBinding:_000 = </Looks/X>",
    "rel material:slotBinding:_000:_:_010 = [</a>, </b>]",
    "rel material:slotBinding:_é",
    "prepend references = @./x.usda@",
    "subLayers = [@./default.usda@]",
    "@/dev/zero@",
    "double3 xformOp:translate = (1e38, 0, 0)",
    "uniform token[] xformOpOrder = [\"xformOp:translate\"]",
    "point3f[] points = [(0, 0, 0), (nan, 1, 0), (1, 1e38, 0)]",
    "int[] faceVertexIndices = [0, 1, 99999]",
    "def Sphere \"S\" { double radius = -1 }",
    "variantSet \"v\" = { \"a\" {} }",
    "asset info:strata:sourceAsset = @missing.ash@",
    "<input name=\"in\" type=\"color3\" value=\"1e38, nan, -1\" />",
    "<input name=\"in\" type=\"float\" nodename=\"self\" />",
    "<input name=\"file\" type=\"filename\" value=\"/dev/zero\" colorspace=\"acescg\" />",
    "<nodegraph name=\"g\"><output name=\"out\" type=\"color3\" nodename=\"g\" /></nodegraph>",
    "<image name=\"i\" type=\"color4\"><input name=\"uaddressmode\" type=\"string\" value=\"mirror\" /></image>",
    "<surfacematerial name=\"m\" type=\"material\"><input name=\"surfaceshader\" type=\"surfaceshader\" nodename=\"m\" /></surfacematerial>",
    "interfacename=\"missing\" ",
    "output=\"out\" nodegraph=\"nowhere\" ",
    "fileprefix=\"../../../../\" ",
    "<!DOCTYPE m [<!ENTITY a \"aaaaaaaaaa\"><!ENTITY b \"&a;&a;&a;&a;&a;&a;&a;&a;\">]>",
    "&b;&#0;&#x110000;",
    "<![CDATA[</materialx>]]>",
];

fn mutate(rng: &mut Rng, bytes: &mut Vec<u8>, corpus: &Corpus) {
    let len = bytes.len();
    let at = rng.below(len + 1);
    let span = |rng: &mut Rng| {
        let start = rng.below(len + 1);
        let end = (start + 1 + rng.below(64)).min(len);
        (start, end.max(start))
    };
    match rng.below(9) {
        0 if len > 0 => bytes[at.min(len - 1)] = ALPHABET[rng.below(ALPHABET.len())],
        1 => {
            let (s, e) = span(rng);
            bytes.drain(s..e);
        }
        2 => {
            let n = 1 + rng.below(4);
            let ins: Vec<u8> = (0..n).map(|_| ALPHABET[rng.below(ALPHABET.len())]).collect();
            bytes.splice(at..at, ins);
        }
        3 => {
            let (s, e) = span(rng);
            let chunk = bytes[s..e].to_vec();
            let to = rng.below(bytes.len() + 1);
            bytes.splice(to..to, chunk);
        }
        4 => {
            let other = &corpus.entries[rng.below(corpus.entries.len())].bytes;
            let s = rng.below(other.len() + 1);
            let e = (s + 1 + rng.below(256)).min(other.len()).max(s);
            bytes.splice(at..at, other[s..e].iter().copied());
        }
        5 => {
            // Repeat a short span many times: deep nesting, long chains, many prims.
            let (s, e) = span(rng);
            let e = e.min(s + 16);
            let times = [10, 100, 1000, 5000][rng.below(4)];
            let chunk = bytes[s..e].repeat(times);
            bytes.splice(e..e, chunk);
        }
        6 => {
            // Replace a run of digits with an extreme number.
            if let Some(start) = (0..len).map(|i| (at + i) % len.max(1)).find(|&i| bytes[i].is_ascii_digit()) {
                let mut end = start;
                while end < bytes.len() && (bytes[end].is_ascii_digit() || bytes[end] == b'.') {
                    end += 1;
                }
                bytes.splice(start..end, EXTREMES[rng.below(EXTREMES.len())].bytes());
            }
        }
        7 => {
            let t = TOKENS[rng.below(TOKENS.len())];
            bytes.splice(at..at, t.bytes());
        }
        _ => {
            // Swap two lines' worth of text.
            let (s1, e1) = span(rng);
            let chunk: Vec<u8> = bytes.drain(s1..e1).collect();
            let to = rng.below(bytes.len() + 1);
            bytes.splice(to..to, chunk);
        }
    }
}

/// Integers that break careless binary readers (counts, offsets, sizes), little-endian.
const EXTREME_INTEGERS: [u64; 10] =
    [0, 1, 0x7f, 0xff, 0x7fff_ffff, 0x8000_0000, 0xffff_ffff, 0x7fff_ffff_ffff_ffff, u64::MAX, 1 << 40];

/// One binary mutation of `bytes`; `same_length` keeps the length (inside a zip member, whose
/// size the headers state).
fn mutate_binary(rng: &mut Rng, bytes: &mut Vec<u8>, same_length: bool) {
    let len = bytes.len();
    if len == 0 {
        return;
    }
    let at = rng.below(len);
    match rng.below(if same_length { 4 } else { 7 }) {
        0 => bytes[at] ^= 1 << rng.below(8),
        1 => bytes[at] = rng.next() as u8,
        2 => {
            // An extreme integer, 4 or 8 bytes wide, where a count or offset may be.
            let value = EXTREME_INTEGERS[rng.below(EXTREME_INTEGERS.len())].to_le_bytes();
            let width = if rng.below(2) == 0 { 4 } else { 8 };
            let end = (at + width).min(len);
            bytes[at..end].copy_from_slice(&value[..end - at]);
        }
        3 => {
            // Copy a chunk over another place (tables pointing at each other's data).
            let from = rng.below(len);
            let n = (1 + rng.below(32)).min(len - from).min(len - at);
            let chunk = bytes[from..from + n].to_vec();
            bytes[at..at + n].copy_from_slice(&chunk);
        }
        4 => bytes.truncate(at),
        5 => {
            let end = (at + 1 + rng.below(64)).min(len);
            bytes.drain(at..end);
        }
        _ => {
            let from = rng.below(len);
            let end = (from + 1 + rng.below(64)).min(len);
            let chunk = bytes[from..end].to_vec();
            bytes.splice(at..at, chunk);
        }
    }
}

fn le16(bytes: &[u8], at: usize) -> Option<usize> {
    Some(u16::from_le_bytes(bytes.get(at..at + 2)?.try_into().ok()?) as usize)
}

fn le32(bytes: &[u8], at: usize) -> Option<usize> {
    Some(u32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?) as usize)
}

/// The central directory's entries of a zip: `(entry offset, local header offset)`.
fn zip_entries(bytes: &[u8]) -> Vec<(usize, usize)> {
    let Some(end) = (0..bytes.len().saturating_sub(21)).rev().find(|&i| bytes[i..].starts_with(b"PK\x05\x06")) else {
        return Vec::new();
    };
    let (Some(count), Some(mut at)) = (le16(bytes, end + 10), le32(bytes, end + 16)) else { return Vec::new() };
    let mut out = Vec::new();
    for _ in 0..count {
        if !bytes.get(at..).is_some_and(|b| b.starts_with(b"PK\x01\x02")) {
            break;
        }
        let (Some(name), Some(extra), Some(comment), Some(local)) =
            (le16(bytes, at + 28), le16(bytes, at + 30), le16(bytes, at + 32), le32(bytes, at + 42))
        else {
            break;
        };
        out.push((at, local));
        at += 46 + name + extra + comment;
    }
    out
}

/// The data range of each stored member of a zip (usdz members are stored, not deflated).
fn zip_members(bytes: &[u8]) -> Vec<(usize, usize)> {
    zip_entries(bytes).into_iter().filter_map(|(_, local)| member_data(bytes, local)).collect()
}

/// Rewrites every member's CRC-32, in its local header and central directory entry, to match
/// its (mutated) data.
fn fix_zip_crcs(bytes: &mut [u8]) {
    for (entry, local) in zip_entries(bytes) {
        let Some((start, end)) = member_data(bytes, local) else { continue };
        let crc = crc32(&bytes[start..end]).to_le_bytes();
        bytes[local + 14..local + 18].copy_from_slice(&crc);
        bytes[entry + 16..entry + 20].copy_from_slice(&crc);
    }
}

/// The data range of the member whose local header is at `local`.
fn member_data(bytes: &[u8], local: usize) -> Option<(usize, usize)> {
    if !bytes.get(local..)?.starts_with(b"PK\x03\x04") {
        return None;
    }
    let start = local + 30 + le16(bytes, local + 26)? + le16(bytes, local + 28)?;
    let end = start.checked_add(le32(bytes, local + 18)?)?;
    (end <= bytes.len() && start < end).then_some((start, end))
}

/// CRC-32 (IEEE, as zip uses it), bit by bit: inputs are small.
fn crc32(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xedb8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// Diagnostics may be this many bytes per input byte, plus [`STDERR_SLACK`]: more is a flood
/// (a long name repeated in every message: 22 KB in, 1 MB out).
pub const STDERR_PER_INPUT_BYTE: usize = 16;

/// Diagnostics any input may print: 50 messages with their excerpts.
pub const STDERR_SLACK: usize = 64 << 10;

/// Runs one input in this process: writes it over its corpus file inside the staged `dir`,
/// checks it as `strata check` would (only reads and composes it when `quick`), compiles and
/// runs what compiles, and restores the file. Returns the bytes of diagnostics `check` would
/// print.
pub fn execute(dir: &Path, corpus: &Corpus, which: usize, bytes: &[u8], k: u64, quick: bool) -> std::io::Result<usize> {
    let entry = &corpus.entries[which];
    let path = dir.join(&entry.rel);
    std::fs::write(&path, bytes)?;
    let printed = if quick {
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        if entry.is_substance() {
            let _ = Library::from_text("fuzz.ash", &String::from_utf8_lossy(bytes), &mut sources, &mut diags);
        } else {
            let _ = strata::scene::Stage::open(&path, &mut sources, &mut diags);
        }
        diags.render(&sources).len()
    } else {
        let (diags, sources, summary) = strata::session::check_file(&path);
        let mut printed = diags.render(&sources).len() + summary.len();
        if entry.is_substance() {
            run_substances(bytes, k.is_multiple_of(8));
        } else if entry.is_materialx() {
            // Its materials as a scene binds them: the mutation reaches translation and code.
            let scene = path.with_extension("fuzz.usda");
            std::fs::write(&scene, materialx_wrapper(&entry.bytes, &path))?;
            let (diags, sources, summary) = strata::session::check_file(&scene);
            printed += diags.render(&sources).len() + summary.len();
            if k.is_multiple_of(16) && !diags.has_errors() {
                render_tiny(&scene);
            }
        } else if k.is_multiple_of(16) && !diags.has_errors() {
            render_tiny(&path);
        }
        printed
    };
    std::fs::write(&path, &entry.bytes)?;
    Ok(printed)
}

/// Most materials of one MaterialX document a fuzzing scene binds.
const MATERIALX_MATERIALS: usize = 4;

/// A scene that references the first [`MATERIALX_MATERIALS`] materials of the MaterialX
/// document `original` (named from the unmutated text, so a mutation that renames or breaks
/// one leaves a reference to resolve) from `document`, each bound to a sphere of its own.
fn materialx_wrapper(original: &[u8], document: &Path) -> String {
    let text = String::from_utf8_lossy(original);
    let names = ["<surfacematerial ", "<material "].iter().flat_map(|tag| {
        text.match_indices(tag).filter_map(|(at, _)| {
            let rest = &text[at..];
            let name = rest[..rest.find('>')?].split("name=\"").nth(1)?;
            Some(name[..name.find('"')?].to_string())
        })
    });
    let file = document.file_name().map_or_else(String::new, |f| f.to_string_lossy().into_owned());
    let mut scene = String::from("#usda 1.0\n");
    for (i, name) in names.take(MATERIALX_MATERIALS).enumerate() {
        scene += &format!(
            "def Material \"M{i}\" (prepend references = @./{file}@</MaterialX/Materials/{name}>) {{}}\n\
             def Sphere \"S{i}\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {{\n\
             \x20   double3 xformOp:translate = ({i}, 0, 0)\n\
             \x20   uniform token[] xformOpOrder = [\"xformOp:translate\"]\n\
             \x20   rel material:binding = </M{i}>\n}}\n"
        );
    }
    scene
}

/// This process's peak resident memory since [`reset_peak_memory`] (bytes; 0 where `/proc`
/// does not say).
fn peak_memory() -> u64 {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else { return 0 };
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// Resets the peak resident memory to the current (Linux: `5` to `/proc/self/clear_refs`).
fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Compiles every substance of `text` with its file's overrides and evaluates its entry points.
fn run_substances(text: &[u8], interp: bool) {
    let text = String::from_utf8_lossy(text);
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let (lib, _) = Library::from_text("fuzz.ash", &text, &mut sources, &mut diags);
    if diags.has_errors() {
        return;
    }
    let overrides: Vec<MaterialRef> = lib
        .graphs_in(GraphKind::Override)
        .map(|(id, _)| MaterialRef { path: "/o".into(), graph: id, values: vec![], span: Span::default() })
        .collect();
    // The JIT's code is fast in any build; the interpreter spends a runaway loop's whole
    // budget slowly in a debug build, so it runs on one input in eight.
    let backends: &[BackendKind] = if interp { &[BackendKind::Jit, BackendKind::Interp] } else { &[BackendKind::Jit] };
    for (id, _) in lib.graphs_in(GraphKind::Substance).take(8) {
        let layer = ComposedLayer {
            slot: Slot::parse("000").expect("a valid slot"),
            substance: MaterialRef { path: "/s".into(), graph: id, values: vec![], span: Span::default() },
            overrides: overrides
                .iter()
                .take(4)
                .cloned()
                .map(|o| (Slot::parse("000::001").expect("valid"), o))
                .collect(),
            vertical: Vec::new(),
        };
        let material = ComposedMaterial { layers: vec![layer], ..Default::default() };
        for &backend in backends {
            let mut diags = Diagnostics::new();
            let Some(code) = Compiler::new(backend, PassOptions::default()).compile(&lib, &material, &mut diags) else {
                continue;
            };
            let g = strata::abi::Globals {
                p: [0.3, -1.2, 2.5],
                n: [0.0, 1.0, 0.0],
                u: 0.25,
                v: 0.75,
                ..Default::default()
            };
            let _ = strata::render::integrator::shading_state(code.as_ref(), &g);
        }
    }
}

fn render_tiny(scene: &Path) {
    let mut session = strata::session::Session::open_default(strata::session::SceneSource::File(scene.to_path_buf()));
    session.compile();
    let (Some(stage), Some(compiled)) = (session.stage(), session.compiled()) else {
        return;
    };
    let mut diags = Diagnostics::new();
    let materials: Vec<&dyn strata::abi::MaterialCode> = compiled.materials.iter().map(|m| m.as_ref()).collect();
    // Displaced surfaces are diced as for a 4x4 image, under a small budget.
    let options = strata::render::scene::SceneOptions {
        dicing: strata::render::geometry::displace::DicingOptions {
            resolution: (4, 4),
            budget: 1 << 16,
            ..Default::default()
        },
        ..Default::default()
    };
    let Some(scene) = strata::render::Scene::build(
        stage,
        &|p| compiled.prim_material.get(p).copied(),
        &materials,
        &options,
        &mut diags,
    ) else {
        return;
    };
    let settings = strata::render::RenderSettings {
        width: 4,
        height: 4,
        spp: 1,
        seed: 1,
        threads: Some(1),
        max_depth: 4,
        mode: strata::render::LayerMode::Stochastic,
        ..Default::default()
    };
    let _ = strata::render::render(&scene, &materials, &settings, None);
}

/// The worker loop: inputs `first`, `first + stride`, … until killed. Before each input it
/// prints `run K` and after it `done K PEAK PRINTED INPUT` (peak resident bytes while it ran,
/// bytes of diagnostics, bytes of input), so the parent knows which input was in flight and
/// what it cost.
pub fn worker(root: &Path, dir: &Path, seed: u64, first: u64, stride: u64, quick: bool) -> std::io::Result<()> {
    let corpus = Corpus::load(root)?;
    let stdout = std::io::stdout();
    let mut k = first;
    loop {
        let (which, bytes) = corpus.input(seed, k);
        writeln!(stdout.lock(), "run {k}")?;
        reset_peak_memory();
        let printed = execute(dir, &corpus, which, &bytes, k, quick)?;
        writeln!(stdout.lock(), "done {k} {} {printed} {}", peak_memory(), bytes.len())?;
        k += stride.max(1);
    }
}

/// What made an input a finding.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Failure {
    /// The worker died (panic, abort, signal) while running it.
    Crash(String),
    /// It ran longer than the per-input budget.
    Hang,
    /// The worker's resident memory passed the budget while running it (peak bytes).
    Memory(u64),
    /// An allocation failed (`memory allocation of N bytes failed`, `capacity overflow`): the
    /// message.
    OutOfMemory(String),
    /// Its diagnostics were larger than [`STDERR_PER_INPUT_BYTE`] per input byte plus
    /// [`STDERR_SLACK`].
    StderrFlood {
        /// Bytes of diagnostics.
        printed: u64,
        /// Bytes of input.
        input: u64,
    },
}

/// One input that failed, saved to the crash directory.
#[derive(Clone, Debug)]
pub struct Finding {
    /// Input number.
    pub k: u64,
    /// The corpus file it was made from.
    pub base: PathBuf,
    /// What happened.
    pub failure: Failure,
    /// Where the input was saved.
    pub saved: PathBuf,
}

/// Settings of a fuzzing run.
#[derive(Clone, Debug)]
pub struct FuzzOptions {
    /// The repository root (the corpus folders are under it).
    pub root: PathBuf,
    /// Wall-clock length of the run.
    pub duration: Duration,
    /// Seed of the input sequence.
    pub seed: u64,
    /// Worker processes.
    pub jobs: u64,
    /// Longest one input may run.
    pub input_timeout: Duration,
    /// Most resident memory a worker may use.
    pub max_rss: u64,
    /// Where failing inputs are written.
    pub crashes: PathBuf,
    /// Only read and compose scenes, parse substances (the readers, many times faster).
    pub quick: bool,
}

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct FuzzReport {
    /// Inputs that ran to the end.
    pub executions: u64,
    /// Inputs that failed.
    pub findings: Vec<Finding>,
    /// Largest resident memory seen in a worker (bytes).
    pub peak_rss: u64,
}

enum Event {
    Started(u64),
    /// Input, peak resident bytes, bytes of diagnostics, bytes of input.
    Finished(u64, u64, u64, u64),
    Exited,
}

struct Worker {
    child: Child,
    events: mpsc::Receiver<Event>,
    stderr: std::sync::Arc<std::sync::Mutex<Vec<u8>>>,
    in_flight: Option<(u64, Instant)>,
    next: u64,
}

fn spawn_worker(options: &FuzzOptions, dir: &Path, first: u64) -> std::io::Result<Worker> {
    let mut child = Command::new(std::env::current_exe()?)
        .args(["fuzz", "--worker"])
        .arg("--root")
        .arg(&options.root)
        .arg("--stage")
        .arg(dir)
        .args(["--seed", &options.seed.to_string(), "--first", &first.to_string()])
        .args(["--stride", &options.jobs.to_string()])
        // Budgeted structures (textures, film, instances) must be refused below the memory
        // oracle's line: a refused structure is the answer, a worker past the line a finding.
        .args(["--max-memory", &(options.max_rss / 2).to_string()])
        .args(if options.quick { &["--quick"][..] } else { &[] })
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()?;
    let (tx, events) = mpsc::channel();
    let stdout = child.stdout.take().expect("piped");
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let numbers =
                |p: &str| -> Option<Vec<u64>> { line.strip_prefix(p)?.split(' ').map(|n| n.parse().ok()).collect() };
            let event = match (numbers("run ").as_deref(), numbers("done ").as_deref()) {
                (Some(&[k]), _) => Event::Started(k),
                (_, Some(&[k, peak, printed, input])) => Event::Finished(k, peak, printed, input),
                _ => continue,
            };
            if tx.send(event).is_err() {
                return;
            }
        }
        let _ = tx.send(Event::Exited);
    });
    // Keep the last few KiB of the worker's stderr for the report (a panic message).
    let stderr = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let mut pipe = child.stderr.take().expect("piped");
    let sink = stderr.clone();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while let Ok(n) = std::io::Read::read(&mut pipe, &mut buf) {
            if n == 0 {
                break;
            }
            let mut s = sink.lock().unwrap_or_else(|e| e.into_inner());
            s.extend_from_slice(&buf[..n]);
            let excess = s.len().saturating_sub(8192);
            s.drain(..excess);
        }
    });
    Ok(Worker { child, events, stderr, in_flight: None, next: first })
}

/// Resident memory of a process now, from `/proc` (0 where that is not available).
fn resident_bytes(pid: u32) -> u64 {
    let Ok(status) = std::fs::read_to_string(format!("/proc/{pid}/status")) else { return 0 };
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// The oracles on an input that ran to the end: its peak resident memory and the size of its
/// diagnostics against the input's size.
pub fn judge_finished(peak: u64, printed: u64, input: u64, max_rss: u64) -> Option<Failure> {
    if peak > max_rss {
        Some(Failure::Memory(peak))
    } else if printed > (STDERR_PER_INPUT_BYTE as u64).saturating_mul(input).saturating_add(STDERR_SLACK as u64) {
        Some(Failure::StderrFlood { printed, input })
    } else {
        None
    }
}

/// What a worker's death was, from the end of its stderr: an allocation failure is a class of
/// its own (Rust's `memory allocation of N bytes failed`, `capacity overflow`).
pub fn judge_exit(stderr_tail: &str, message: String) -> Failure {
    if stderr_tail.contains("memory allocation of") || stderr_tail.contains("capacity overflow") {
        Failure::OutOfMemory(message)
    } else {
        Failure::Crash(message)
    }
}

/// Writes input `k` to the crash directory and logs it.
fn save_finding(
    options: &FuzzOptions,
    corpus: &Corpus,
    k: u64,
    failure: Failure,
    log: &mut dyn FnMut(&str),
) -> std::io::Result<Finding> {
    let (which, bytes) = corpus.input(options.seed, k);
    let entry = &corpus.entries[which];
    let ext = entry.rel.extension().and_then(|e| e.to_str()).unwrap_or("txt");
    let saved = options.crashes.join(format!("input-{}-{k}.{ext}", options.seed));
    std::fs::write(&saved, &bytes)?;
    let finding = Finding { k, base: entry.rel.clone(), failure, saved };
    log(&format!(
        "finding: input {k} (from {}): {:?}, saved to {}",
        finding.base.display(),
        finding.failure,
        finding.saved.display()
    ));
    Ok(finding)
}

/// Runs the fuzzer for `options.duration`; `log` receives a line per finding and progress.
pub fn run(options: &FuzzOptions, log: &mut dyn FnMut(&str)) -> std::io::Result<FuzzReport> {
    let corpus = Corpus::load(&options.root)?;
    std::fs::create_dir_all(&options.crashes)?;
    let base = std::env::temp_dir().join(format!("strata-fuzz-{}", std::process::id()));
    let mut report = FuzzReport::default();
    let mut workers = Vec::new();
    for j in 0..options.jobs.max(1) {
        let dir = base.join(format!("worker{j}"));
        corpus.stage(&dir)?;
        workers.push((dir.clone(), spawn_worker(options, &dir, j)?));
    }
    let start = Instant::now();
    let mut last_log = Instant::now();
    while start.elapsed() < options.duration {
        for (dir, w) in &mut workers {
            let mut failure = None;
            while let Ok(event) = w.events.try_recv() {
                match event {
                    Event::Started(k) => w.in_flight = Some((k, Instant::now())),
                    Event::Finished(k, peak, printed, input) => {
                        report.executions += 1;
                        report.peak_rss = report.peak_rss.max(peak);
                        w.in_flight = None;
                        w.next = k + options.jobs;
                        // Findings the worker survived: it goes on with the next input.
                        if let Some(failure) = judge_finished(peak, printed, input, options.max_rss) {
                            report.findings.push(save_finding(options, &corpus, k, failure, log)?);
                        }
                    }
                    Event::Exited => {
                        let status = w.child.wait().map(|s| s.to_string()).unwrap_or_default();
                        let tail =
                            String::from_utf8_lossy(&w.stderr.lock().unwrap_or_else(|e| e.into_inner())).into_owned();
                        let last: Vec<&str> = tail.lines().rev().take(6).collect();
                        let message = format!("{status}: {}", last.into_iter().rev().collect::<Vec<_>>().join(" | "));
                        failure = Some(judge_exit(&tail, message));
                        break;
                    }
                }
            }
            let rss = resident_bytes(w.child.id());
            report.peak_rss = report.peak_rss.max(rss);
            if failure.is_none() {
                if rss > options.max_rss {
                    failure = Some(Failure::Memory(rss));
                } else if w.in_flight.is_some_and(|(_, t)| t.elapsed() > options.input_timeout) {
                    failure = Some(Failure::Hang);
                }
            }
            if let Some(failure) = failure {
                let _ = w.child.kill();
                let _ = w.child.wait();
                let k = w.in_flight.map_or(w.next, |(k, _)| k);
                report.findings.push(save_finding(options, &corpus, k, failure, log)?);
                // The staged file may hold the failing input: restore it, then go on after it.
                let entry = &corpus.entries[corpus.input(options.seed, k).0];
                std::fs::write(dir.join(&entry.rel), &entry.bytes)?;
                *w = spawn_worker(options, dir, k + options.jobs)?;
            }
        }
        if last_log.elapsed() > Duration::from_secs(10) {
            last_log = Instant::now();
            log(&format!(
                "{:.0} s: {} executions, {} findings",
                start.elapsed().as_secs_f64(),
                report.executions,
                report.findings.len()
            ));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    for (_, w) in &mut workers {
        let _ = w.child.kill();
        let _ = w.child.wait();
    }
    let _ = std::fs::remove_dir_all(&base);
    Ok(report)
}

// Moved from tests/hostile_struct.rs when the fuzzer left the library for the binary crate
// (integration tests see the library only); the assertions are unchanged.
#[cfg(test)]
mod tests {
    use super::*;

    fn corpus() -> Corpus {
        Corpus::load(Path::new(env!("CARGO_MANIFEST_DIR"))).unwrap()
    }

    /// The fuzzer mutates a package inside its members and fixes their CRCs: the zip reader
    /// passes the mutated bytes on to the layer readers.
    #[test]
    fn fuzzed_packages_stay_readable_zips() {
        let corpus = corpus();
        let is_package = |i: usize| corpus.entries[i].bytes.starts_with(b"PK\x03\x04");
        assert!((0..corpus.entries.len()).any(is_package), "usdz seeds in the corpus");
        let mut readable_and_changed = 0;
        for k in 0..20_000 {
            let (which, bytes) = corpus.input(5, k);
            if !is_package(which) || bytes == corpus.entries[which].bytes {
                continue;
            }
            let Ok(mut zip) = zip::ZipArchive::new(std::io::Cursor::new(&bytes)) else { continue };
            // Every member reads to its end: the CRCs match the mutated data.
            let all_read = (0..zip.len()).all(|i| {
                let Ok(mut member) = zip.by_index(i) else { return false };
                std::io::copy(&mut member, &mut std::io::sink()).is_ok()
            });
            readable_and_changed += usize::from(all_read);
        }
        assert!(readable_and_changed > 20, "only {readable_and_changed} mutated packages pass the zip reader");
    }

    /// Crates get binary mutations (never grammar tokens), which mostly keep the header.
    #[test]
    fn fuzzed_crates_are_mutated_as_bytes() {
        let corpus = corpus();
        let is_crate = |i: usize| corpus.entries[i].bytes.starts_with(b"PXR-USDC");
        let (mut total, mut kept_magic) = (0, 0);
        for k in 0..20_000 {
            let (which, bytes) = corpus.input(9, k);
            if is_crate(which) {
                total += 1;
                kept_magic += usize::from(bytes.starts_with(b"PXR-USDC"));
                assert!(!bytes.windows(13).any(|w| w == b"def Xform \"X\""), "a text token in a crate");
            }
        }
        assert!(total > 0 && kept_magic * 10 > total * 8, "{kept_magic} of {total} kept the magic");
    }

    /// A MaterialX document is fuzzed through a scene that binds its materials: each one
    /// composes, compiles and reaches a prim, so mutations get past the reader.
    #[test]
    fn fuzzed_materialx_documents_reach_their_prims() {
        let corpus = corpus();
        let documents: Vec<&Entry> = corpus.entries.iter().filter(|e| e.is_materialx()).collect();
        assert!(documents.len() > 10, "only {} MaterialX seeds in the corpus", documents.len());
        let chess = documents.iter().find(|e| e.rel.ends_with("chess_mat.mtlx")).expect("the chess document");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("chess_mat.mtlx");
        std::fs::write(&path, &chess.bytes).unwrap();
        let scene = path.with_extension("fuzz.usda");
        std::fs::write(&scene, materialx_wrapper(&chess.bytes, &path)).unwrap();
        let (diags, sources, summary) = strata::session::check_file(&scene);
        assert!(!diags.has_errors(), "{}", diags.render(&sources));
        assert!(summary.contains("ok (1 renderable prim(s), 1 distinct material(s))"), "{summary}");
    }

    #[test]
    fn fuzz_oracles_tell_memory_floods_and_allocation_failures() {
        let mib = 1 << 20;
        assert_eq!(judge_finished(2048 * mib, 0, 10, 1024 * mib), Some(Failure::Memory(2048 * mib)));
        assert_eq!(judge_finished(10 * mib, 64 << 10, 10, 1024 * mib), None);
        // 22 KB of input, 1 MB of diagnostics: the long-name flood.
        assert_eq!(
            judge_finished(10 * mib, 1 << 20, 22_000, 1024 * mib),
            Some(Failure::StderrFlood { printed: 1 << 20, input: 22_000 })
        );
        assert_eq!(judge_finished(10 * mib, 400_000, 22_000, 1024 * mib), None);
        let oom = "memory allocation of 936205475788011600 bytes failed\n";
        assert!(matches!(judge_exit(oom, "abort".into()), Failure::OutOfMemory(_)));
        assert!(matches!(judge_exit("thread 'main' panicked at src/x.rs", "101".into()), Failure::Crash(_)));
    }
}
