//! Reading input files: scenes and their sublayers, references and payloads, substance
//! sources, textures and dome maps all come through [`read_bytes`] / [`read_text`].
//!
//! A scene names its inputs, so a hostile scene can name anything: a FIFO (reading blocks
//! forever), `/dev/zero` (reading never ends), a directory, a 100 GB file. Only regular files
//! no larger than [`InputLimits::max_file_bytes`] are read; everything else is an
//! [`InputError`] that callers report as a diagnostic at the place the path was written.
//! The file is opened without blocking and checked on the open handle (no window between
//! checking a path and reading it), and never more than the limit is read even if the file
//! grows meanwhile.
//!
//! **Packages.** A path of the form `dir/a.usdz[tex/b.exr]` (USD's package-relative asset
//! path) names the member `tex/b.exr` of the zip package `dir/a.usdz`; packages nest
//! (`a.usdz[b.usdz[c.usda]]`). [`read_bytes`] reads the package under the same rules as any
//! file, then the member, itself held to the size limit, so every caller (layers, substance
//! files, textures) reads inside packages without knowing about them.
//!
//! The limits are process-wide, set once by the command line (`--max-input-size`,
//! `--max-texture-pixels`, `--max-memory`) before anything is read, because textures are
//! loaded deep inside compilation where no options are passed.
//!
//! **Memory.** A few bytes of input can ask for any amount of memory (a texture header, a
//! render resolution, an instance count), and a failed allocation aborts the process. Each
//! large structure — a decoded texture, the film, the instances and their BVHs — is estimated
//! from its sizes before it is allocated and checked against [`memory_budget`] with
//! [`check_memory`]: half the memory the process may use ([`default_memory_budget`]) unless
//! `--max-memory` says otherwise.

use std::fmt;
use std::io::Read;
use std::path::{Component, Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

pub mod generated;
pub mod scenes;

/// Default limit on the size of any one input file: 256 MiB. The largest scenes and
/// textures strata is meant for are a few tens of MB; a file beyond this is far more likely
/// a mistake (or an attack) than a scene, and reading it would cost seconds and gigabytes.
pub const DEFAULT_MAX_INPUT_BYTES: u64 = 256 << 20;

/// Default limit on a texture's or dome map's pixel count: 2^27 = 134 million pixels, a
/// 16384 × 8192 latitude-longitude map (the largest common HDRI size). Decoded, such an image
/// takes 1.5 GiB (three f32 per texel). Checked from the header, before anything is allocated:
/// an EXR header can claim any size in a few bytes.
pub const DEFAULT_MAX_TEXTURE_PIXELS: u64 = 1 << 27;

/// Limits on what input files may cost.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputLimits {
    /// Largest input file read, in bytes.
    pub max_file_bytes: u64,
    /// Largest texture read, in pixels (of its largest layer).
    pub max_texture_pixels: u64,
    /// Largest single structure built (a decoded texture, the film, the instances and their
    /// BVHs), in bytes; `None`: [`default_memory_budget`].
    pub max_memory_bytes: Option<u64>,
}

impl Default for InputLimits {
    fn default() -> Self {
        InputLimits {
            max_file_bytes: DEFAULT_MAX_INPUT_BYTES,
            max_texture_pixels: DEFAULT_MAX_TEXTURE_PIXELS,
            max_memory_bytes: None,
        }
    }
}

static MAX_FILE_BYTES: AtomicU64 = AtomicU64::new(DEFAULT_MAX_INPUT_BYTES);
static MAX_TEXTURE_PIXELS: AtomicU64 = AtomicU64::new(DEFAULT_MAX_TEXTURE_PIXELS);
/// 0: not set, the default applies.
static MAX_MEMORY_BYTES: AtomicU64 = AtomicU64::new(0);

/// Sets the process-wide limits (the command line does this once, before reading anything).
pub fn set_limits(limits: InputLimits) {
    MAX_FILE_BYTES.store(limits.max_file_bytes, Ordering::Relaxed);
    MAX_TEXTURE_PIXELS.store(limits.max_texture_pixels, Ordering::Relaxed);
    MAX_MEMORY_BYTES.store(limits.max_memory_bytes.unwrap_or(0), Ordering::Relaxed);
}

/// The limits in force.
pub fn limits() -> InputLimits {
    let memory = MAX_MEMORY_BYTES.load(Ordering::Relaxed);
    InputLimits {
        max_file_bytes: MAX_FILE_BYTES.load(Ordering::Relaxed),
        max_texture_pixels: MAX_TEXTURE_PIXELS.load(Ordering::Relaxed),
        max_memory_bytes: (memory > 0).then_some(memory),
    }
}

/// The memory the process may use: the least of the machine's memory (`MemTotal`), the
/// address-space and data limits (`ulimit -v`, `ulimit -d`, `prlimit --as`) and the cgroup's
/// `memory.max` (containers); 8 GiB where none of these can be read.
pub fn available_memory() -> u64 {
    let mut least = u64::MAX;
    if let Ok(meminfo) = std::fs::read_to_string("/proc/meminfo")
        && let Some(kb) = meminfo
            .lines()
            .find_map(|l| l.strip_prefix("MemTotal:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
    {
        least = least.min(kb.saturating_mul(1024));
    }
    if let Ok(max) = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        && let Ok(bytes) = max.trim().parse::<u64>()
    {
        least = least.min(bytes);
    }
    #[cfg(unix)]
    #[allow(clippy::unnecessary_cast)] // rlim_t is u64 on Linux, not everywhere
    for resource in [libc::RLIMIT_AS, libc::RLIMIT_DATA] {
        let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
        // SAFETY: getrlimit writes one rlimit through a valid pointer.
        if unsafe { libc::getrlimit(resource, &mut limit) } == 0 && limit.rlim_cur != libc::RLIM_INFINITY {
            least = least.min(limit.rlim_cur as u64);
        }
    }
    if least == u64::MAX { 8 << 30 } else { least }
}

/// The memory budget when `--max-memory` is not given: half of [`available_memory`], which
/// leaves room for everything that is not one of the budgeted structures (the scene, the
/// compiled code, thread stacks) and for a structure being copied.
pub fn default_memory_budget() -> u64 {
    static BUDGET: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *BUDGET.get_or_init(|| available_memory() / 2)
}

/// The largest single structure strata may build, in bytes: `--max-memory`, else
/// [`default_memory_budget`].
pub fn memory_budget() -> u64 {
    limits().max_memory_bytes.unwrap_or_else(default_memory_budget)
}

/// A byte count for messages: `512 bytes`, `3.2 MiB`, `62.0 GiB`.
pub fn human_bytes(bytes: u64) -> String {
    match bytes {
        0..1024 => format!("{bytes} bytes"),
        1024..0x10_0000 => format!("{:.1} KiB", bytes as f64 / 1024.0),
        0x10_0000..0x4000_0000 => format!("{:.1} MiB", bytes as f64 / f64::from(1 << 20)),
        _ => format!("{:.1} GiB", bytes as f64 / f64::from(1 << 30)),
    }
}

/// `Ok` when `bytes` (what `what` needs, estimated before allocating it) fits the
/// [`memory_budget`]; else the message that says so, the budget and how to raise it.
pub fn check_memory(what: &str, bytes: u64) -> Result<(), String> {
    let budget = memory_budget();
    if bytes <= budget {
        return Ok(());
    }
    let whence = match limits().max_memory_bytes {
        Some(_) => "the memory limit".to_string(),
        None => format!("the memory limit (half of the {} this process may use)", human_bytes(available_memory())),
    };
    Err(format!(
        "{what} needs {}, more than {whence} of {} (raise it with --max-memory)",
        human_bytes(bytes),
        human_bytes(budget)
    ))
}

/// Why an input file was not read.
#[derive(Debug)]
pub enum InputError {
    /// The path names something other than a regular file (`what` says what).
    NotAFile {
        /// "a directory", "a FIFO (named pipe)", "a device", ...
        what: &'static str,
    },
    /// The file is larger than the limit.
    TooLarge {
        /// Its size (at least `limit + 1` when it grew while being read).
        size: u64,
        /// The limit in force.
        limit: u64,
    },
    /// The file is not UTF-8 text (for text inputs).
    NotText,
    /// A package-relative path (`a.usdz[member]`) whose package or member could not be read.
    Package(String),
    /// The operating system refused (missing file, permissions, ...).
    Io(std::io::Error),
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InputError::NotAFile { what } => write!(f, "it is {what}, not a regular file"),
            InputError::TooLarge { size, limit } => write!(
                f,
                "it is {} bytes, more than the input size limit of {limit} bytes (raise it with --max-input-size)",
                size
            ),
            InputError::NotText => f.write_str("stream did not contain valid UTF-8"),
            InputError::Package(message) => f.write_str(message),
            // Exactly the operating system's words, as before this module existed.
            InputError::Io(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for InputError {}

impl From<std::io::Error> for InputError {
    fn from(e: std::io::Error) -> Self {
        InputError::Io(e)
    }
}

/// What a non-regular file is, for messages.
fn describe(kind: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if kind.is_char_device() || kind.is_block_device() {
            return "a device";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    if kind.is_dir() { "a directory" } else { "not a regular file" }
}

/// Opens `path` for reading without blocking: opening a FIFO for reading otherwise waits for
/// a writer, possibly forever, before any check could run.
fn open_nonblocking(path: &Path) -> std::io::Result<std::fs::File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    options.open(path)
}

/// Opens `path` if it is a regular file of at most `max_bytes` bytes, with its metadata.
fn open_regular(path: &Path, max_bytes: u64) -> Result<(std::fs::File, std::fs::Metadata), InputError> {
    let file = open_nonblocking(path)?;
    // Checked on the open handle: the path cannot be swapped for a FIFO after the check.
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(InputError::NotAFile { what: describe(meta.file_type()) });
    }
    if meta.len() > max_bytes {
        return Err(InputError::TooLarge { size: meta.len(), limit: max_bytes });
    }
    Ok((file, meta))
}

/// The first `prefix` bytes of `path` (all of it when shorter) and whether they are the whole
/// file, checked and recorded as [`read_bytes`] checks and records the whole: what a header
/// reader needs without reading megabytes of pixels. A package-relative path reads its whole
/// member (a compressed member has no cheaper prefix).
pub fn read_prefix(path: &Path, prefix: u64) -> Result<(Vec<u8>, bool), InputError> {
    if split_package_path(path).is_some() {
        return read_bytes(path).map(|bytes| (bytes, true));
    }
    let max_bytes = limits().max_file_bytes;
    let (file, meta) = open_regular(path, max_bytes)?;
    let want = prefix.min(max_bytes);
    let mut bytes = Vec::with_capacity(meta.len().min(want) as usize);
    // One byte more than wanted tells whether the file goes on.
    file.take(want.saturating_add(1)).read_to_end(&mut bytes)?;
    let whole = bytes.len() as u64 <= want;
    bytes.truncate(want as usize);
    record_read(path, &meta);
    Ok((bytes, whole))
}

/// Reads the whole of `path` if it is a regular file of at most `max_bytes` bytes.
pub fn read_bytes_limited(path: &Path, max_bytes: u64) -> Result<Vec<u8>, InputError> {
    let (file, meta) = open_regular(path, max_bytes)?;
    // `len` is a hint (files under /proc report 0; a file can grow): read at most one byte
    // past the limit, so a file that grew is caught without reading all of it.
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max_bytes.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(InputError::TooLarge { size: bytes.len() as u64, limit: max_bytes });
    }
    record_read(path, &meta);
    Ok(bytes)
}

/// One file that was read: its canonical path and, on Unix, its device, inode and
/// modification time (which also catch a hard link or a second path to it; the time tells a
/// reused inode of a deleted input from the input itself).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct FileIdentity {
    path: PathBuf,
    device_inode: Option<(u64, u64, i64, i64)>,
}

impl FileIdentity {
    fn of(path: &Path, meta: &std::fs::Metadata) -> FileIdentity {
        #[cfg(unix)]
        let device_inode = {
            use std::os::unix::fs::MetadataExt;
            Some((meta.dev(), meta.ino(), meta.mtime(), meta.mtime_nsec()))
        };
        #[cfg(not(unix))]
        let device_inode = {
            let _ = meta;
            None
        };
        FileIdentity { path: std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()), device_inode }
    }

    fn same_file(&self, other: &FileIdentity) -> bool {
        self.path == other.path || self.device_inode.is_some() && self.device_inode == other.device_inode
    }
}

/// Every input file this process has read, so outputs can be checked against them. A set:
/// a scene of 40 000 sublayer files spent most of a minute in a list's `contains`.
static FILES_READ: std::sync::LazyLock<Mutex<std::collections::HashSet<FileIdentity>>> =
    std::sync::LazyLock::new(Mutex::default);

fn record_read(path: &Path, meta: &std::fs::Metadata) {
    let identity = FileIdentity::of(path, meta);
    FILES_READ.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).insert(identity);
}

/// Whether `path` names a file this process has read as an input (a scene, layer, substance
/// file, texture or dome map), through any path or link: writing it would destroy an input.
pub fn was_read(path: &Path) -> bool {
    let Ok(meta) = std::fs::metadata(path) else { return false };
    let identity = FileIdentity::of(path, &meta);
    FILES_READ.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).iter().any(|f| f.same_file(&identity))
}

/// Every input file this process has read (canonical paths), for a live view to watch.
pub fn files_read() -> Vec<PathBuf> {
    let files = FILES_READ.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let mut paths: Vec<PathBuf> = files.iter().map(|f| f.path.clone()).collect();
    // A file read again after an edit is one identity per version (its mtime is part of it).
    paths.sort();
    paths.dedup();
    paths
}

/// Reads the whole of `path` under the current [`limits`]; a package-relative path
/// (`a.usdz[member]`) reads that member of the package.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, InputError> {
    let max = limits().max_file_bytes;
    match split_package_path(path) {
        Some((package, member)) => {
            let bytes = read_bytes_limited(&package, max)?;
            read_member(bytes, &member, max, &package.display().to_string(), 0)
        }
        None => read_bytes_limited(path, max),
    }
}

/// Packages inside packages deeper than this are refused (a hostile path cannot recurse).
const MAX_PACKAGE_NESTING: usize = 8;

/// Splits USD's package-relative path `pkg[member]` at the outermost brackets into the
/// package file and the member (which may itself be package-relative). `None` for a plain
/// path, and for an existing file whose name merely ends in `]`.
pub fn split_package_path(path: &Path) -> Option<(PathBuf, String)> {
    let text = path.to_str()?;
    let (package, member) = split_brackets(text)?;
    if std::fs::symlink_metadata(path).is_ok() {
        return None;
    }
    Some((PathBuf::from(package), member.to_string()))
}

/// `a[b[c]]` → `("a", "b[c]")`: the text before the first `[` and inside the last `]`.
fn split_brackets(text: &str) -> Option<(&str, &str)> {
    let inner = text.strip_suffix(']')?;
    let open = inner.find('[')?;
    let (package, member) = (&inner[..open], &inner[open + 1..]);
    (!package.is_empty() && !member.is_empty()).then_some((package, member))
}

/// Reads `member` (maybe `inner.usdz[deeper]`) out of the zip package held in `bytes`.
fn read_member(bytes: Vec<u8>, member: &str, max: u64, package: &str, depth: usize) -> Result<Vec<u8>, InputError> {
    if depth >= MAX_PACKAGE_NESTING {
        return Err(InputError::Package(format!("packages nested more than {MAX_PACKAGE_NESTING} deep")));
    }
    let (name, rest) = match split_brackets(member) {
        Some((outer, inner)) => (outer, Some(inner)),
        None => (member, None),
    };
    let name = normalize_member(name);
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(bytes))
        .map_err(|e| InputError::Package(format!("`{package}` is not a readable zip package: {e}")))?;
    let mut file = archive
        .by_name(&name)
        .map_err(|_| InputError::Package(format!("the package `{package}` has no member `{name}`")))?;
    // The declared size is checked first, and the read is bounded anyway: a deflated member
    // can inflate past what its header claims.
    if file.size() > max {
        return Err(InputError::TooLarge { size: file.size(), limit: max });
    }
    let mut out = Vec::with_capacity(file.size() as usize);
    (&mut file)
        .take(max.saturating_add(1))
        .read_to_end(&mut out)
        .map_err(|e| InputError::Package(format!("cannot read `{name}` in the package `{package}`: {e}")))?;
    if out.len() as u64 > max {
        return Err(InputError::TooLarge { size: out.len() as u64, limit: max });
    }
    match rest {
        Some(inner) => read_member(out, inner, max, &format!("{package}[{name}]"), depth + 1),
        None => Ok(out),
    }
}

/// A member name as zip stores it: `/`-separated, no `./`, `..` applied.
fn normalize_member(name: &str) -> String {
    let mut parts: Vec<&str> = Vec::new();
    for part in name.split(['/', '\\']) {
        match part {
            "" | "." => {}
            ".." => {
                if parts.pop().is_none() {
                    parts.push("..");
                }
            }
            other => parts.push(other),
        }
    }
    parts.join("/")
}

/// Resolves an asset path authored in a layer whose directory is `base_dir`. Inside a
/// package (`base_dir` = `pkg.usdz[sub]`) a relative path stays inside it, as USD resolves
/// package-relative assets: `tex/a.exr` → `pkg.usdz[sub/tex/a.exr]`.
pub fn resolve_asset(base_dir: &Path, authored: &str) -> PathBuf {
    if let Some(text) = base_dir.to_str()
        && let Some((package, dir)) = split_brackets_allow_empty(text)
        && !Path::new(authored).is_absolute()
    {
        return PathBuf::from(format!("{package}[{}]", resolve_member(dir, authored)));
    }
    normalize(&base_dir.join(authored))
}

/// Removes `.` and resolves `..` components without touching the file system.
pub(crate) fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// `authored` resolved against the directory `dir` of a package, which may itself be inside
/// a nested package (`inner.usdz[sub]` → `inner.usdz[sub/authored]`): a relative path stays
/// inside the innermost package, as USD resolves it.
fn resolve_member(dir: &str, authored: &str) -> String {
    match split_brackets_allow_empty(dir) {
        Some((package, inner)) => format!("{package}[{}]", resolve_member(inner, authored)),
        None => normalize_member(&format!("{dir}/{authored}")),
    }
}

/// The package-relative path of `member` inside `package`, which may itself be a member of a
/// package: `a.usdz[b.usdz]` and `root.usda` give `a.usdz[b.usdz[root.usda]]`, USD's form
/// (`a.usdz[b.usdz][root.usda]` names no member of `a.usdz`).
pub fn package_member(package: &Path, member: &str) -> PathBuf {
    fn nest(package: &str, member: &str) -> String {
        match split_brackets(package) {
            Some((outer, inner)) => format!("{outer}[{}]", nest(inner, member)),
            None => format!("{package}[{member}]"),
        }
    }
    match package.to_str() {
        Some(text) if split_package_path(package).is_some() => PathBuf::from(nest(text, member)),
        _ => PathBuf::from(format!("{}[{member}]", package.display())),
    }
}

/// Like [`split_brackets`], but `pkg[]` (a package's top directory) is allowed.
fn split_brackets_allow_empty(text: &str) -> Option<(&str, &str)> {
    let inner = text.strip_suffix(']')?;
    let open = inner.find('[')?;
    let package = &inner[..open];
    (!package.is_empty()).then_some((package, &inner[open + 1..]))
}

/// The directory asset paths in the layer at `path` resolve against: the parent directory,
/// or for a package member `pkg.usdz[sub/a.usdc]`, `pkg.usdz[sub]`.
pub fn layer_dir(path: &Path) -> PathBuf {
    if let Some(text) = path.to_str()
        && let Some((package, member)) = split_brackets(text)
        && split_package_path(path).is_some()
    {
        // In a nested package (`a.usdz[b.usdz[sub/x.usda]]`), the innermost member's folder.
        fn member_dir(member: &str) -> String {
            match split_brackets(member) {
                Some((package, inner)) => format!("{package}[{}]", member_dir(inner)),
                None => member.rsplit_once('/').map(|(d, _)| d).unwrap_or("").to_string(),
            }
        }
        return PathBuf::from(format!("{package}[{}]", member_dir(member)));
    }
    path.parent().unwrap_or(Path::new("")).to_path_buf()
}

/// A canonical identity for `path` (symlinks and `..` resolved), package members included:
/// `pkg.usdz[m]` → `<canonical pkg.usdz>[m]`. Falls back to a lexical normalisation when the
/// file does not exist.
pub fn canonicalize(path: &Path) -> std::io::Result<PathBuf> {
    match split_package_path(path) {
        Some((package, member)) => {
            let package = std::fs::canonicalize(package)?;
            Ok(PathBuf::from(format!("{}[{}]", package.display(), normalize_member(&member))))
        }
        None => std::fs::canonicalize(path),
    }
}

/// Reads `path` as UTF-8 text under the current [`limits`].
pub fn read_text(path: &Path) -> Result<String, InputError> {
    String::from_utf8(read_bytes(path)?).map_err(|_| InputError::NotText)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_files_are_read_up_to_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        std::fs::write(&path, "hello").unwrap();
        assert_eq!(read_bytes_limited(&path, 5).unwrap(), b"hello");
        let err = read_bytes_limited(&path, 4).unwrap_err();
        assert!(matches!(err, InputError::TooLarge { size: 5, limit: 4 }), "{err:?}");
        assert!(err.to_string().contains("--max-input-size"), "{err}");
        std::fs::write(&path, [0xff, 0xfe]).unwrap();
        assert!(matches!(read_text(&path), Err(InputError::NotText)));
        let missing = read_bytes(&dir.path().join("missing")).unwrap_err();
        assert_eq!(missing.to_string(), "No such file or directory (os error 2)");
    }

    #[test]
    fn a_prefix_is_read_checked_and_recorded_like_the_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("image.bin");
        std::fs::write(&path, b"0123456789").unwrap();
        assert_eq!(read_prefix(&path, 4).unwrap(), (b"0123".to_vec(), false));
        assert_eq!(read_prefix(&path, 10).unwrap(), (b"0123456789".to_vec(), true), "exactly the file");
        assert_eq!(read_prefix(&path, 64).unwrap(), (b"0123456789".to_vec(), true));
        assert!(was_read(&path), "a prefix read is an input read");
        assert!(matches!(read_prefix(dir.path(), 4), Err(InputError::NotAFile { .. })));
    }

    #[test]
    fn files_read_are_remembered_through_any_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("input.usda");
        std::fs::write(&path, "#usda 1.0\n").unwrap();
        let other = dir.path().join("other.exr");
        std::fs::write(&other, "x").unwrap();
        assert!(!was_read(&path));
        read_text(&path).unwrap();
        assert!(was_read(&path) && !was_read(&other));
        assert!(was_read(&dir.path().join(".").join("input.usda")));
        #[cfg(unix)]
        {
            let link = dir.path().join("link.exr");
            std::os::unix::fs::symlink(&path, &link).unwrap();
            let hard = dir.path().join("hard.exr");
            std::fs::hard_link(&path, &hard).unwrap();
            assert!(was_read(&link) && was_read(&hard));
        }
        assert!(!was_read(&dir.path().join("missing.exr")));
    }

    fn write_zip(path: &Path, members: &[(&str, &[u8])]) {
        let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
        for (name, bytes) in members {
            let options = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
            zip.start_file(*name, options).unwrap();
            std::io::Write::write_all(&mut zip, bytes).unwrap();
        }
        zip.finish().unwrap();
    }

    #[test]
    fn package_members_are_read_under_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("inner.usdz");
        write_zip(&inner, &[("deep/c.txt", b"nested")]);
        let outer = dir.path().join("a.usdz");
        let inner_bytes = std::fs::read(&inner).unwrap();
        write_zip(&outer, &[("root.usda", b"#usda 1.0\n"), ("tex/b.txt", &[7u8; 1000]), ("in.usdz", &inner_bytes)]);
        let member = |m: &str| PathBuf::from(format!("{}[{m}]", outer.display()));
        assert_eq!(read_bytes(&member("tex/b.txt")).unwrap(), vec![7u8; 1000]);
        assert_eq!(read_bytes(&member("./tex/../tex/b.txt")).unwrap().len(), 1000, "member names are normalised");
        assert_eq!(read_bytes(&member("in.usdz[deep/c.txt]")).unwrap(), b"nested", "packages nest");
        let err = read_bytes(&member("nope.png")).unwrap_err().to_string();
        assert!(err.contains("has no member `nope.png`"), "{err}");
        // The member's own size is held to the limit, however small the package is.
        let err = read_member(std::fs::read(&outer).unwrap(), "tex/b.txt", 999, "a.usdz", 0).unwrap_err();
        assert!(matches!(err, InputError::TooLarge { size: 1000, limit: 999 }), "{err:?}");
        let err = read_bytes(&PathBuf::from(format!("{}[x]", dir.path().join("missing.usdz").display()))).unwrap_err();
        assert!(matches!(err, InputError::Io(_)), "{err:?}");
        std::fs::write(dir.path().join("text.usdz"), "not a zip").unwrap();
        let err = read_bytes(&PathBuf::from(format!("{}[x]", dir.path().join("text.usdz").display()))).unwrap_err();
        assert!(err.to_string().contains("not a readable zip package"), "{err}");
        assert!(was_read(&outer), "the package counts as an input");
    }

    #[test]
    fn asset_paths_resolve_inside_packages() {
        let dir = tempfile::tempdir().unwrap();
        let pkg = dir.path().join("a.usdz");
        write_zip(&pkg, &[("sub/root.usdc", b"x")]);
        let root = PathBuf::from(format!("{}[sub/root.usdc]", pkg.display()));
        let base = layer_dir(&root);
        assert_eq!(base, PathBuf::from(format!("{}[sub]", pkg.display())));
        assert_eq!(resolve_asset(&base, "tex/a.exr"), PathBuf::from(format!("{}[sub/tex/a.exr]", pkg.display())));
        assert_eq!(resolve_asset(&base, "../b.usda"), PathBuf::from(format!("{}[b.usda]", pkg.display())));
        assert_eq!(resolve_asset(&base, "/abs/c.exr"), PathBuf::from("/abs/c.exr"), "absolute paths leave the package");
        assert_eq!(resolve_asset(Path::new("/d/x"), "./y/../z.usda"), PathBuf::from("/d/x/z.usda"));
        assert_eq!(layer_dir(Path::new("/d/x/s.usda")), PathBuf::from("/d/x"));
        // An existing file whose name merely ends in `]` is a file, not a package member.
        let odd = dir.path().join("shot[1]");
        std::fs::write(&odd, "plain").unwrap();
        assert!(split_package_path(&odd).is_none());
        assert_eq!(read_bytes(&odd).unwrap(), b"plain");
        assert_eq!(
            canonicalize(&root).unwrap(),
            PathBuf::from(format!("{}[sub/root.usdc]", pkg.canonicalize().unwrap().display()))
        );
    }

    #[test]
    fn directories_devices_and_fifos_are_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let err = read_bytes(dir.path()).unwrap_err();
        assert_eq!(err.to_string(), "it is a directory, not a regular file");
        #[cfg(unix)]
        {
            let err = read_bytes(Path::new("/dev/zero")).unwrap_err();
            assert_eq!(err.to_string(), "it is a device, not a regular file");
            let fifo = dir.path().join("pipe");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
            assert!(made.success());
            // No writer: a blocking open would wait forever.
            let err = read_bytes(&fifo).unwrap_err();
            assert_eq!(err.to_string(), "it is a FIFO (named pipe), not a regular file");
        }
    }
}
