//! Binary USD: crate files (`.usdc`, binary `.usd`) and usdz packages, read with the
//! `openusd` crate and converted into the same per-file syntax tree the `.usda` parser
//! produces ([`Layer`](crate::scene::usda::Layer)), so composition, slot bindings and diagnostics have one model.
//!
//! **Format detection** looks at the content, never only the extension
//! ([`read_layer_file`]): `PXR-USDC` is a crate, `PK\x03\x04` a usdz package (its root layer
//! is the first USD layer it holds), anything else is text for the usda parser.
//!
//! **Spans.** A binary layer has no text to point into, so the converter writes an
//! *outline*: one line per spec (`def Mesh </World/Mesh>`, `point3f[] </World/Mesh.points>`,
//! `references @a.usdc@</A>`, ...). That outline is the file's text in the
//! [`SourceMap`](crate::diag::SourceMap);
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
//! ([`precheck()`]), then the framing of every value (`Probe`): no count may claim more than
//! the bytes after it hold. Every call into openusd runs under `catch_unwind`: a panic
//! becomes a "malformed usdc" diagnostic, and a panic hook keeps its message off the
//! terminal. A panic never reaches the user.
//!
//! Files: this module detects formats and reads layer files; `precheck` checks a crate's
//! structure, `convert` turns it into a `Layer`, `values` converts its values and `spans` points the converted spans at the outline.

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Once;

mod convert;
mod precheck;
mod spans;
mod values;

pub use convert::convert;
pub use precheck::precheck;

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
    /// A MaterialX document's XML, translated as USD's MaterialX plugin does
    /// ([`crate::scene::mtlx`]).
    MaterialX(String),
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
        return match String::from_utf8(bytes) {
            Ok(xml) => Ok(LayerFile { path: path.to_path_buf(), source: LayerSource::MaterialX(xml) }),
            Err(_) => Err(LayerReadError::Unreadable("a MaterialX document that is not UTF-8 text".into())),
        };
    }
    read_layer_bytes(path, bytes).map_err(LayerReadError::Unreadable)
}

/// Why [`read_layer_file`] could not give a layer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LayerReadError {
    /// Missing, unreadable, or not a USD file; the text says which.
    Unreadable(String),
}

impl std::fmt::Display for LayerReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
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

#[cfg(test)]
mod tests {
    use super::precheck::lz4_decoded_len;
    use super::values::widen_f32;
    use super::*;
    use crate::diag::{Diagnostics, SourceMap};
    use crate::scene::usda::{Layer, PropertySpec};
    use crate::scene::value::Value;
    use openusd::sdf::{self, AbstractData};

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
