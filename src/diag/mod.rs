//! Diagnostics shared by every stage: source files, spans, and errors rendered with
//! file:line:col and the offending source line.
//!
//! Every stage reports problems as [`Diagnostic`] values collected in a [`Diagnostics`] sink
//! instead of failing at the first one, so one run shows as many problems as it can.

use codespan_reporting::diagnostic as cs;
use codespan_reporting::files as csfiles;
use codespan_reporting::term;
use std::fmt;
use std::ops::Range;

pub mod text;

/// Diagnostics [`Diagnostics::render`] shows per file; the rest are counted in one closing
/// line, so a file that yields one error per byte cannot flood the terminal.
pub const MAX_SHOWN_PER_FILE: usize = 50;

/// Widest source line a diagnostic quotes whole; a longer one is cut to about this many
/// bytes around each label, with `…` where text was left out.
pub const MAX_EXCERPT_WIDTH: usize = 160;

/// Names (anything quoted in backticks) longer than this many characters are shown as their
/// first and last [`ELIDED_NAME_ENDS`] characters: a 22 KB prim name repeated in every
/// message would otherwise turn a small file into megabytes of diagnostics.
pub const MAX_NAME_CHARS: usize = 100;

/// Characters kept at each end of an elided name.
pub const ELIDED_NAME_ENDS: usize = 40;

/// `text` with every backtick-quoted name longer than [`MAX_NAME_CHARS`] characters cut to
/// its two ends around `…`, followed by its length: `` `abc…xyz` (22000 characters)``.
pub fn elide_long_names(text: String) -> String {
    let parts: Vec<&str> = text.split('`').collect();
    // Odd parts are quoted when a closing backtick follows them.
    let quoted_long = |i: usize, part: &str| i % 2 == 1 && i + 1 < parts.len() && part.len() > MAX_NAME_CHARS;
    if !parts.iter().enumerate().any(|(i, p)| quoted_long(i, p) && p.chars().count() > MAX_NAME_CHARS) {
        return text;
    }
    let mut out = String::new();
    let mut length_note = None;
    for (i, part) in parts.iter().enumerate() {
        if i > 0 {
            out.push('`');
        }
        if let Some(count) = length_note.take() {
            out += &format!(" ({count} characters)");
        }
        let count = part.chars().count();
        if quoted_long(i, part) && count > MAX_NAME_CHARS {
            out.extend(part.chars().take(ELIDED_NAME_ENDS));
            out.push('…');
            out.extend(part.chars().skip(count - ELIDED_NAME_ENDS));
            length_note = Some(count);
        } else {
            out += part;
        }
    }
    out
}

/// Index of a file in a [`SourceMap`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct FileId(pub u32);

/// A byte range in one source file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Span {
    /// The file the range lies in.
    pub file: FileId,
    /// First byte.
    pub start: u32,
    /// One past the last byte.
    pub end: u32,
}

impl Span {
    /// A span covering `start..end` of `file`.
    pub fn new(file: FileId, start: usize, end: usize) -> Span {
        Span { file, start: start as u32, end: end as u32 }
    }

    /// The smallest span covering both `self` and `other` (same file assumed).
    pub fn to(self, other: Span) -> Span {
        Span { file: self.file, start: self.start.min(other.start), end: self.end.max(other.end) }
    }
}

/// Every source file a run has read, so diagnostics can quote them.
#[derive(Default)]
pub struct SourceMap {
    files: Vec<SourceFile>,
}

/// One file of a [`SourceMap`].
struct SourceFile {
    name: String,
    /// The text while it is held (empty once [`SourceMap::release`]d).
    text: String,
    /// Byte offset of each line's start.
    line_starts: Vec<usize>,
    /// Set when the text was given back: where it is read again from, and what it was.
    released: Option<Released>,
}

/// A released file's text: read again from `path` on first need, and used only if it is
/// still what was parsed (same length and hash), so a quote never shows other text.
struct Released {
    path: std::path::PathBuf,
    len: usize,
    hash: u64,
    text: std::sync::OnceLock<String>,
}

/// Texts smaller than this are kept: releasing them saves little and costs a read.
const RELEASE_BYTES: usize = 1 << 20;

/// A fast 64-bit hash of `text` (a word at a time) to recognise a file read again.
fn text_hash(text: &str) -> u64 {
    let bytes = text.as_bytes();
    let mut words = bytes.chunks_exact(8);
    let mut h = bytes.len() as u64;
    for w in &mut words {
        h = (h.rotate_left(23) ^ u64::from_le_bytes(w.try_into().unwrap_or_default()))
            .wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
    for &b in words.remainder() {
        h = (h.rotate_left(23) ^ u64::from(b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
    h
}

impl SourceFile {
    /// The text, read again if it was released (empty when the file changed since).
    fn text(&self) -> &str {
        match &self.released {
            None => &self.text,
            Some(r) => r.text.get_or_init(|| {
                std::fs::read_to_string(&r.path)
                    .ok()
                    .filter(|t| t.len() == r.len && text_hash(t) == r.hash)
                    .unwrap_or_default()
            }),
        }
    }

    /// The text's length in bytes (also when released).
    fn len(&self) -> usize {
        self.released.as_ref().map_or(self.text.len(), |r| r.len)
    }

    /// The byte range of line `index` (newline included), as codespan's `SimpleFile`.
    fn line_range(&self, index: usize) -> Result<Range<usize>, csfiles::Error> {
        let start = |i: usize| match i.cmp(&self.line_starts.len()) {
            std::cmp::Ordering::Less => Ok(self.line_starts[i]),
            std::cmp::Ordering::Equal => Ok(self.len()),
            std::cmp::Ordering::Greater => {
                Err(csfiles::Error::LineTooLarge { given: i, max: self.line_starts.len().saturating_sub(1) })
            }
        };
        Ok(start(index)?..start(index + 1)?)
    }

    /// The index of the line holding byte `at`.
    fn line_index(&self, at: usize) -> usize {
        self.line_starts.binary_search(&at).unwrap_or_else(|next| next.saturating_sub(1))
    }
}

impl SourceMap {
    /// An empty map.
    pub fn new() -> SourceMap {
        SourceMap::default()
    }

    /// Registers a file's text under a display name and returns its id.
    pub fn add(&mut self, name: impl Into<String>, text: impl Into<String>) -> FileId {
        let text = text.into();
        let line_starts = csfiles::line_starts(&text).collect();
        self.files.push(SourceFile { name: name.into(), text, line_starts, released: None });
        FileId(self.files.len() as u32 - 1)
    }

    /// Gives back the memory of `file`'s text, once parsed, when it is large and is the
    /// content of the file at `path`: a diagnostic that quotes it later reads it again
    /// (and quotes nothing if the file has changed since). A 10⁶-triangle mesh's text is
    /// about 57 bytes per triangle.
    pub fn release(&mut self, file: FileId, path: &std::path::Path) {
        let Some(f) = self.files.get_mut(file.0 as usize) else { return };
        let on_disk = std::fs::metadata(path).map(|m| m.is_file() && m.len() == f.text.len() as u64);
        if f.released.is_some() || f.text.len() < RELEASE_BYTES || !on_disk.unwrap_or(false) {
            return;
        }
        let text = std::mem::take(&mut f.text);
        f.released = Some(Released {
            path: path.to_path_buf(),
            len: text.len(),
            hash: text_hash(&text),
            text: std::sync::OnceLock::new(),
        });
    }

    /// The display name of a file.
    pub fn name(&self, file: FileId) -> &str {
        self.files.get(file.0 as usize).map(|f| f.name.as_str()).unwrap_or("<unknown>")
    }

    /// The byte range of the line holding byte `at` of a file (newline excluded).
    pub fn line_bounds(&self, file: FileId, at: usize) -> Range<usize> {
        let text = self.text(file);
        let Some(f) = self.files.get(file.0 as usize) else { return at..at };
        match f.line_range(f.line_index(at)) {
            Ok(range) => {
                let end = range.end.min(text.len());
                let start = range.start.min(end);
                start..start + text[start..end].trim_end_matches(['\n', '\r']).len()
            }
            Err(_) => at..at,
        }
    }

    /// One-based number of the line holding byte `at` of a file.
    pub fn line_number(&self, file: FileId, at: usize) -> usize {
        self.files.get(file.0 as usize).map_or(1, |f| f.line_index(at) + 1)
    }

    /// The full text of a file.
    pub fn text(&self, file: FileId) -> &str {
        self.files.get(file.0 as usize).map_or("", SourceFile::text)
    }

    /// The text a span covers.
    pub fn slice(&self, span: Span) -> &str {
        self.text(span.file).get(span.start as usize..span.end as usize).unwrap_or("")
    }

    /// One-based line and column of a span's start.
    pub fn line_col(&self, span: Span) -> (usize, usize) {
        let Some(f) = self.files.get(span.file.0 as usize) else { return (1, 1) };
        let at = (span.start as usize).min(f.len());
        let line = f.line_index(at);
        let start = f.line_starts.get(line).copied().unwrap_or(0).min(at);
        // Columns count characters; bytes when the text is no longer what was parsed.
        let col = f.text().get(start..at).map_or(at - start, |t| t.chars().count()) + 1;
        (line + 1, col)
    }

    /// `name:line:col` of a span's start.
    pub fn location(&self, span: Span) -> String {
        let (line, col) = self.line_col(span);
        format!("{}:{}:{}", self.name(span.file), line, col)
    }
}

/// How bad a diagnostic is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Severity {
    /// Informational; never fails a run.
    Note,
    /// Suspicious input that still has a well-defined meaning.
    Warning,
    /// Input that cannot be given a meaning; the run fails.
    Error,
}

/// A labelled span inside a diagnostic.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Label {
    /// Where.
    pub span: Span,
    /// What to say there (may be empty).
    pub message: String,
    /// The primary label marks the cause; secondary ones give context.
    pub primary: bool,
}

/// One problem found in the user's input.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Diagnostic {
    /// Error, warning or note.
    pub severity: Severity,
    /// The one-line summary.
    pub message: String,
    /// Source locations, the primary one first.
    pub labels: Vec<Label>,
    /// Extra lines of explanation or help.
    pub notes: Vec<String>,
    /// For warnings: what kind of problem this is. A run reports each kind once, at its first
    /// location, with a count of the others ([`Diagnostics::push`]), so a missing texture
    /// named by 400 shaders is one warning, not 400.
    pub kind: Option<&'static str>,
}

impl Diagnostic {
    fn new(severity: Severity, message: impl Into<String>) -> Diagnostic {
        let message = elide_long_names(message.into());
        Diagnostic { severity, message, labels: Vec::new(), notes: Vec::new(), kind: None }
    }

    /// An error.
    pub fn error(message: impl Into<String>) -> Diagnostic {
        Diagnostic::new(Severity::Error, message)
    }

    /// Information a user should see once, that is not a problem (never fails a run, not
    /// even with `--strict`).
    pub fn info(message: impl Into<String>) -> Diagnostic {
        Diagnostic::new(Severity::Note, message)
    }

    /// A warning.
    pub fn warning(message: impl Into<String>) -> Diagnostic {
        Diagnostic::new(Severity::Warning, message)
    }

    /// Adds the primary label.
    pub fn at(mut self, span: Span, message: impl Into<String>) -> Diagnostic {
        self.labels.push(Label { span, message: elide_long_names(message.into()), primary: true });
        self
    }

    /// Adds a secondary label.
    pub fn also(mut self, span: Span, message: impl Into<String>) -> Diagnostic {
        self.labels.push(Label { span, message: elide_long_names(message.into()), primary: false });
        self
    }

    /// Adds a note line.
    pub fn note(mut self, note: impl Into<String>) -> Diagnostic {
        self.notes.push(elide_long_names(note.into()));
        self
    }

    /// Names the kind of a warning: later warnings of the same kind are counted, not shown.
    pub fn kind(mut self, kind: &'static str) -> Diagnostic {
        self.kind = Some(kind);
        self
    }

    /// Renders this diagnostic as plain text: `error: msg`, then `--> file:line:col` and the
    /// quoted source line with carets. Lines wider than [`MAX_EXCERPT_WIDTH`] are cut around
    /// the labels.
    pub fn render(&self, sources: &SourceMap) -> String {
        let wide = self.labels.iter().any(|l| {
            let line = sources.line_bounds(l.span.file, l.span.start as usize);
            line.end - line.start > MAX_EXCERPT_WIDTH
        });
        if wide {
            return self.render_excerpts(sources);
        }
        let severity = self.severity.codespan();
        let labels = self
            .labels
            .iter()
            .map(|l| {
                let style = if l.primary { cs::LabelStyle::Primary } else { cs::LabelStyle::Secondary };
                cs::Label::new(style, l.span.file.0 as usize, l.span.start as usize..l.span.end as usize)
                    .with_message(l.message.clone())
            })
            .collect();
        let diagnostic = cs::Diagnostic::new(severity)
            .with_message(self.message.clone())
            .with_labels(labels)
            .with_notes(self.notes.clone());
        let config = term::Config::default();
        term::emit_into_string(&config, sources, &diagnostic)
            .unwrap_or_else(|_| format!("{:?}: {}\n", self.severity, self.message))
    }

    /// [`Diagnostic::render`] for labels on very long lines: each label's first line, cut to
    /// a window around the label, stands in for the file, with the original line numbers and
    /// columns.
    fn render_excerpts(&self, sources: &SourceMap) -> String {
        let mut excerpts = Excerpts::default();
        // Excerpt lines in file order, whatever the order of the labels.
        let mut order: Vec<usize> = (0..self.labels.len()).collect();
        order.sort_by_key(|&i| (self.labels[i].span.file, self.labels[i].span.start));
        let mut labels = vec![None; self.labels.len()];
        for i in order {
            let label = &self.labels[i];
            let file = label.span.file;
            let index = match excerpts.files.iter().position(|e| e.file == file) {
                Some(i) => i,
                None => {
                    excerpts.files.push(Excerpt {
                        file,
                        name: sources.name(file).to_string(),
                        text: String::new(),
                        lines: Vec::new(),
                    });
                    excerpts.files.len() - 1
                }
            };
            let range = excerpts.files[index].add_label(sources, label.span);
            let style = if label.primary { cs::LabelStyle::Primary } else { cs::LabelStyle::Secondary };
            labels[i] = Some(cs::Label::new(style, index, range).with_message(label.message.clone()));
        }
        let labels: Vec<_> = labels.into_iter().flatten().collect();
        let diagnostic = cs::Diagnostic::new(self.severity.codespan())
            .with_message(self.message.clone())
            .with_labels(labels)
            .with_notes(self.notes.clone());
        term::emit_into_string(&term::Config::default(), &excerpts, &diagnostic)
            .unwrap_or_else(|_| format!("{:?}: {}\n", self.severity, self.message))
    }
}

impl Severity {
    fn codespan(self) -> cs::Severity {
        match self {
            Severity::Error => cs::Severity::Error,
            Severity::Warning => cs::Severity::Warning,
            Severity::Note => cs::Severity::Note,
        }
    }
}

/// Stand-in source files for [`Diagnostic::render_excerpts`], one per file a diagnostic
/// labels, each holding one excerpt line per label.
#[derive(Default)]
struct Excerpts {
    files: Vec<Excerpt>,
}

struct Excerpt {
    file: FileId,
    name: String,
    /// The excerpt lines, each ending in `\n`.
    text: String,
    lines: Vec<ExcerptLine>,
}

struct ExcerptLine {
    /// Bytes of the line in `Excerpt::text` (newline excluded).
    range: Range<usize>,
    /// One-based line number in the original file.
    number: usize,
    /// Where the original text starts in this line (after a leading `…`).
    content: usize,
    /// One-based column, in the original line, of the first original character shown.
    first_column: usize,
}

impl Excerpt {
    /// Adds the (cut) first line of `span` and returns where `span` lies in the excerpt.
    fn add_label(&mut self, sources: &SourceMap, span: Span) -> Range<usize> {
        let text = sources.text(span.file);
        let start = (span.start as usize).min(text.len());
        let line = sources.line_bounds(span.file, start);
        let end = (span.end as usize).clamp(start, line.end);
        // A window of about MAX_EXCERPT_WIDTH bytes around the label, the label's start first.
        let context = MAX_EXCERPT_WIDTH / 4;
        let from = floor_char(text, start.saturating_sub(context).max(line.start));
        let to = ceil_char(text, (end.min(start + MAX_EXCERPT_WIDTH / 2) + context).min(line.end));
        let at = self.text.len();
        let lead = if from > line.start { "…" } else { "" };
        self.text.push_str(lead);
        self.text.push_str(&text[from..to]);
        if to < line.end {
            self.text.push('…');
        }
        let content = at + lead.len();
        self.lines.push(ExcerptLine {
            range: at..self.text.len(),
            number: sources.line_number(span.file, start),
            content,
            first_column: text[line.start..from].chars().count() + 1,
        });
        self.text.push('\n');
        let shown_end = ceil_char(text, end.min(to));
        content + (start - from)..content + (shown_end - from)
    }
}

fn floor_char(text: &str, mut at: usize) -> usize {
    while !text.is_char_boundary(at) {
        at -= 1;
    }
    at
}

fn ceil_char(text: &str, mut at: usize) -> usize {
    while !text.is_char_boundary(at) {
        at += 1;
    }
    at
}

impl<'a> csfiles::Files<'a> for SourceMap {
    type FileId = usize;
    type Name = &'a str;
    type Source = &'a str;

    fn name(&'a self, id: usize) -> Result<&'a str, csfiles::Error> {
        self.files.get(id).map(|f| f.name.as_str()).ok_or(csfiles::Error::FileMissing)
    }

    fn source(&'a self, id: usize) -> Result<&'a str, csfiles::Error> {
        self.files.get(id).map(SourceFile::text).ok_or(csfiles::Error::FileMissing)
    }

    fn line_index(&'a self, id: usize, byte_index: usize) -> Result<usize, csfiles::Error> {
        self.files.get(id).map(|f| f.line_index(byte_index)).ok_or(csfiles::Error::FileMissing)
    }

    fn line_range(&'a self, id: usize, line_index: usize) -> Result<Range<usize>, csfiles::Error> {
        self.files.get(id).ok_or(csfiles::Error::FileMissing)?.line_range(line_index)
    }
}

impl<'a> csfiles::Files<'a> for Excerpts {
    type FileId = usize;
    type Name = &'a str;
    type Source = &'a str;

    fn name(&'a self, id: usize) -> Result<&'a str, csfiles::Error> {
        self.files.get(id).map(|e| e.name.as_str()).ok_or(csfiles::Error::FileMissing)
    }

    fn source(&'a self, id: usize) -> Result<&'a str, csfiles::Error> {
        self.files.get(id).map(|e| e.text.as_str()).ok_or(csfiles::Error::FileMissing)
    }

    fn line_index(&'a self, id: usize, byte_index: usize) -> Result<usize, csfiles::Error> {
        let excerpt = self.files.get(id).ok_or(csfiles::Error::FileMissing)?;
        Ok(excerpt.lines.iter().position(|l| byte_index <= l.range.end).unwrap_or(excerpt.lines.len().max(1) - 1))
    }

    fn line_range(&'a self, id: usize, line_index: usize) -> Result<Range<usize>, csfiles::Error> {
        let excerpt = self.files.get(id).ok_or(csfiles::Error::FileMissing)?;
        let max = excerpt.lines.len();
        let line = excerpt.lines.get(line_index).ok_or(csfiles::Error::LineTooLarge { given: line_index, max })?;
        Ok(line.range.start..line.range.end + 1)
    }

    fn line_number(&'a self, id: usize, line_index: usize) -> Result<usize, csfiles::Error> {
        let excerpt = self.files.get(id).ok_or(csfiles::Error::FileMissing)?;
        Ok(excerpt.lines.get(line_index).map_or(line_index + 1, |l| l.number))
    }

    fn column_number(&'a self, id: usize, line_index: usize, byte_index: usize) -> Result<usize, csfiles::Error> {
        let excerpt = self.files.get(id).ok_or(csfiles::Error::FileMissing)?;
        let max = excerpt.lines.len();
        let line = excerpt.lines.get(line_index).ok_or(csfiles::Error::LineTooLarge { given: line_index, max })?;
        let at = byte_index.clamp(line.content, line.range.end);
        Ok(line.first_column + excerpt.text.get(line.content..at).map_or(0, |t| t.chars().count()))
    }
}

/// A sink that collects diagnostics from every stage of a run. It keeps what
/// [`Diagnostics::render`] shows — the first [`MAX_SHOWN_PER_FILE`] of each file, and each
/// file's first error — and only counts the rest, so its memory does not grow with the
/// number of problems (4 MiB of `}` is four million errors).
#[derive(Default, Debug)]
pub struct Diagnostics {
    items: Vec<Diagnostic>,
    /// Hashes of the recorded diagnostics: the same finding reached twice (one override wired
    /// into several compositions, one material on many prims) is reported once.
    seen: std::collections::HashSet<u64>,
    /// Per warning kind, the index of its first warning in `items` and how many more came.
    kinds: std::collections::HashMap<&'static str, (usize, usize)>,
    /// Per file (of the primary label; `None`: unlocated), the diagnostics kept and whether
    /// one of them is an error.
    kept: std::collections::HashMap<Option<FileId>, (usize, bool)>,
    /// Per file, in order of first appearance, the errors and other diagnostics counted but
    /// not kept.
    dropped: Vec<(Option<FileId>, usize, usize)>,
}

/// The file a diagnostic is counted under: its primary label's.
fn file_of(d: &Diagnostic) -> Option<FileId> {
    d.labels.iter().find(|l| l.primary).or(d.labels.first()).map(|l| l.span.file)
}

impl Diagnostics {
    /// An empty sink.
    pub fn new() -> Diagnostics {
        Diagnostics::default()
    }

    /// Records one diagnostic.
    pub fn push(&mut self, diagnostic: Diagnostic) {
        use std::hash::{BuildHasher, BuildHasherDefault, DefaultHasher};
        let hash = BuildHasherDefault::<DefaultHasher>::default().hash_one(&diagnostic);
        if !self.seen.insert(hash) {
            return;
        }
        if let (Some(kind), Severity::Warning) = (diagnostic.kind, diagnostic.severity) {
            match self.kinds.entry(kind) {
                std::collections::hash_map::Entry::Occupied(mut first) => {
                    first.get_mut().1 += 1;
                    return;
                }
                std::collections::hash_map::Entry::Vacant(slot) => {
                    slot.insert((self.items.len(), 0));
                }
            }
        }
        let file = file_of(&diagnostic);
        let error = diagnostic.severity == Severity::Error;
        let (kept, has_error) = self.kept.entry(file).or_default();
        // Past the cap, only a file's first error is still kept.
        let first_error = error && !*has_error;
        if *kept >= MAX_SHOWN_PER_FILE && !first_error {
            // A first warning of its kind that is not kept leaves no first to count against.
            if let Some(kind) = diagnostic.kind
                && self.kinds.get(kind) == Some(&(self.items.len(), 0))
            {
                self.kinds.remove(kind);
            }
            // Not remembered either: the sink's memory stays bounded (a repeat of a dropped
            // diagnostic is counted again).
            self.seen.remove(&hash);
            self.count_dropped(file, usize::from(error), usize::from(!error));
            return;
        }
        *kept += 1;
        *has_error |= error;
        self.items.push(diagnostic);
    }

    /// Counts diagnostics of `file` that are not kept.
    fn count_dropped(&mut self, file: Option<FileId>, errors: usize, others: usize) {
        match self.dropped.iter_mut().find(|d| d.0 == file) {
            Some(d) => {
                d.1 += errors;
                d.2 += others;
            }
            None => self.dropped.push((file, errors, others)),
        }
    }

    /// Number of warnings found, each of a kind counted (shown once or not).
    pub fn warning_count(&self) -> usize {
        let shown = self.items.iter().filter(|d| d.severity == Severity::Warning).count();
        let dropped: usize = self.dropped.iter().map(|d| d.2).sum();
        shown + dropped + self.kinds.values().map(|(_, more)| more).sum::<usize>()
    }

    /// Makes every warning an error (`--strict`: farms and CI fail on what a person would
    /// otherwise read past).
    pub fn make_warnings_errors(&mut self) {
        for d in &mut self.items {
            if d.severity == Severity::Warning {
                d.severity = Severity::Error;
                d.notes.push("an error because of --strict".into());
            }
        }
        for dropped in &mut self.dropped {
            dropped.1 += std::mem::take(&mut dropped.2);
        }
    }

    /// Whether any error (not warning) was recorded.
    pub fn has_errors(&self) -> bool {
        self.error_count() > 0
    }

    /// Number of errors recorded.
    pub fn error_count(&self) -> usize {
        let dropped: usize = self.dropped.iter().map(|d| d.1).sum();
        self.items.iter().filter(|d| d.severity == Severity::Error).count() + dropped
    }

    /// The diagnostics kept, in the order they were found: the first
    /// [`MAX_SHOWN_PER_FILE`] of each file and each file's first error.
    pub fn items(&self) -> &[Diagnostic] {
        &self.items
    }

    /// Moves every diagnostic of `other` into `self`.
    pub fn extend(&mut self, other: Diagnostics) {
        for d in other.items {
            self.push(d);
        }
        for (file, errors, others) in other.dropped {
            self.count_dropped(file, errors, others);
        }
        // The warnings `other` counted but did not keep.
        for (kind, (_, more)) in other.kinds {
            if let Some(entry) = self.kinds.get_mut(kind) {
                entry.1 += more;
            }
        }
    }

    /// Renders the diagnostics kept, in order — at most [`MAX_SHOWN_PER_FILE`] per file (the
    /// file of the primary label; unlocated diagnostics count as one more file) and each
    /// file's first error — then one line per file saying how many were left out. Rendering
    /// costs time in proportion to what is shown, not to what was found.
    pub fn render(&self, sources: &SourceMap) -> String {
        let mut out = String::new();
        let more_of_kind: std::collections::HashMap<usize, usize> =
            self.kinds.values().filter(|(_, more)| *more > 0).copied().collect();
        for (i, d) in self.items.iter().enumerate() {
            match more_of_kind.get(&i) {
                Some(&more) => {
                    let s = if more == 1 { "" } else { "s" };
                    out += &d.clone().note(format!("and {more} more warning{s} of this kind")).render(sources);
                }
                None => out += &d.render(sources),
            }
        }
        // (file, errors left out, others left out), in order of first appearance.
        let hidden = self.dropped.iter().copied().filter(|&(_, errors, others)| errors + others > 0);
        for (file, errors, others) in hidden {
            let more = |n: usize, what: &str| format!("{n} more {what}{}", if n == 1 { "" } else { "s" });
            let what = match (errors, others) {
                (e, 0) => more(e, "error"),
                (0, w) => more(w, "warning"),
                (e, w) => format!("{} and {}", more(e, "error"), more(w, "warning")),
            };
            let place = file.map_or("without a location".to_string(), |f| format!("in {}", sources.name(f)));
            out += &format!("note: {what} {place} not shown (only the first {MAX_SHOWN_PER_FILE} per file are)\n\n");
        }
        out
    }
}

/// The error a failed stage returns: the diagnostics that explain the failure.
#[derive(Debug)]
pub struct Failed;

impl fmt::Display for Failed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("failed with errors (see diagnostics)")
    }
}

/// The candidate a misspelt `name` most likely meant: the nearest by edit distance, when it
/// is near enough to be a typo (at most a third of the name's length, at least one edit), or
/// one that differs only in case. `None` when nothing is close: a wild guess misleads more
/// than no guess.
pub fn closest_name<'c>(name: &str, candidates: impl IntoIterator<Item = &'c str>) -> Option<&'c str> {
    let limit = (name.chars().count() / 3).max(1);
    candidates
        .into_iter()
        .filter(|c| *c != name)
        .map(|c| {
            let d = if c.eq_ignore_ascii_case(name) { 0 } else { strsim::damerau_levenshtein(name, c) };
            (d, c)
        })
        .filter(|(d, _)| *d <= limit)
        .min_by_key(|(d, c)| (*d, *c))
        .map(|(_, c)| c)
}

/// `did you mean `x`?` for a note, when [`closest_name`] finds one.
pub fn did_you_mean<'c>(name: &str, candidates: impl IntoIterator<Item = &'c str>) -> Option<String> {
    closest_name(name, candidates).map(|c| format!("did you mean `{c}`?"))
}

/// Diagnostics of one kind reported once: the first keeps its location, the others are
/// counted in a note that names a few of them. An asset with 40 missing layers, or 400 prims
/// bound to one missing material, gets one warning per kind, not hundreds.
#[derive(Default, Debug)]
pub struct OncePerKind {
    groups: Vec<KindGroup>,
}

#[derive(Debug)]
struct KindGroup {
    kind: &'static str,
    first: Diagnostic,
    /// Subjects (file or prim names) of the diagnostics after the first, distinct.
    others: Vec<String>,
    /// How many diagnostics after the first.
    count: usize,
}

/// How many further subjects [`OncePerKind`]'s note names before it only counts.
const NAMED_OTHERS: usize = 3;

impl OncePerKind {
    /// An empty set of groups.
    pub fn new() -> OncePerKind {
        OncePerKind::default()
    }

    /// Records `diagnostic` of `kind`, about `subject` (a file or prim path, for the note).
    pub fn push(&mut self, kind: &'static str, subject: &str, diagnostic: Diagnostic) {
        match self.groups.iter_mut().find(|g| g.kind == kind) {
            Some(group) => {
                if group.first == diagnostic {
                    return;
                }
                group.count += 1;
                if !group.others.iter().any(|o| o == subject) && group.others.len() < NAMED_OTHERS {
                    group.others.push(subject.to_string());
                }
            }
            None => self.groups.push(KindGroup { kind, first: diagnostic, others: Vec::new(), count: 0 }),
        }
    }

    /// How many diagnostics of `kind` were recorded (the first included).
    pub fn count(&self, kind: &str) -> usize {
        self.groups.iter().find(|g| g.kind == kind).map_or(0, |g| g.count + 1)
    }

    /// Moves one diagnostic per kind into `diags`, in the order the kinds first appeared.
    pub fn report(self, diags: &mut Diagnostics) {
        for group in self.groups {
            let mut d = group.first;
            if group.count > 0 {
                let named: Vec<String> = group.others.iter().map(|o| format!("`{o}`")).collect();
                let rest = group.count - named.len().min(group.count);
                let mut list = named.join(", ");
                if rest > 0 {
                    list += &format!("{}{rest} more", if list.is_empty() { "" } else { " and " });
                }
                d = d.note(format!("{} more like it: {list}", group.count));
            }
            diags.push(d);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A released text renders every diagnostic exactly as the held text does (the
    /// reference is the same map without the release), and a file changed since quotes
    /// nothing yet keeps its line numbers.
    #[test]
    fn a_released_text_is_read_again_for_diagnostics() {
        let dir = std::env::temp_dir().join(format!("strata-release-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("big.usda");
        let mut text = String::from("#usda 1.0\n");
        while text.len() < RELEASE_BYTES + 10 {
            text += "def Xform \"Ä\" { double x = 1 }\n";
        }
        let at = text.len() - 15;
        std::fs::write(&path, &text).unwrap();
        let name = path.display().to_string();
        let (mut held, mut released) = (SourceMap::new(), SourceMap::new());
        let (a, b) = (held.add(&name, text.clone()), released.add(&name, text.clone()));
        released.release(b, &path);
        assert!(released.files[0].text.is_empty(), "the text is given back");
        let span = |file| Span::new(file, at, at + 5);
        let diag = |file| Diagnostic::error("bad").at(span(file), "here");
        assert_eq!(diag(b).render(&released), diag(a).render(&held));
        assert_eq!(released.line_col(span(b)), held.line_col(span(a)));
        assert_eq!(released.slice(span(b)), held.slice(span(a)));

        // Changed on disk: no quote, the same line number.
        let mut again = SourceMap::new();
        let c = again.add(&name, text.clone());
        again.release(c, &path);
        std::fs::write(&path, text.replace('x', "y")).unwrap();
        assert_eq!(again.text(c), "");
        assert_eq!(again.line_col(span(c)).0, held.line_col(span(a)).0);
        assert!(again.location(span(c)).starts_with(&name));

        // Small texts and texts that are not the file's stay held.
        let mut small = SourceMap::new();
        let d = small.add(&name, "#usda 1.0\n");
        small.release(d, &path);
        assert_eq!(small.text(d), "#usda 1.0\n");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn closest_name_suggests_typos_only() {
        let names = ["albedo", "roughness", "ior", "specular"];
        assert_eq!(closest_name("albdo", names), Some("albedo"));
        assert_eq!(closest_name("roughnes", names), Some("roughness"));
        assert_eq!(closest_name("Roughness", names), Some("roughness"));
        assert_eq!(closest_name("iro", names), Some("ior"), "a transposition is one edit");
        assert_eq!(closest_name("metallic", names), None, "nothing close: no guess");
        assert_eq!(closest_name("albedo", names), None, "an exact name is not a typo");
    }

    #[test]
    fn the_same_diagnostic_is_recorded_once() {
        let mut d = Diagnostics::new();
        d.push(Diagnostic::warning("w"));
        d.push(Diagnostic::warning("w"));
        d.push(Diagnostic::warning("v"));
        assert_eq!(d.items().len(), 2);
    }

    #[test]
    fn warnings_of_one_kind_are_shown_once_and_counted() {
        let mut sources = SourceMap::new();
        let file = sources.add("a.usda", "one\ntwo\nthree\n");
        let mut d = Diagnostics::new();
        for (i, start) in [0, 4, 8].into_iter().enumerate() {
            let message = format!("cannot open texture `{i}.png`");
            d.push(Diagnostic::warning(message).at(Span::new(file, start, start + 3), "here").kind("texture"));
        }
        d.push(Diagnostic::warning("another kind").kind("other"));
        assert_eq!((d.items().len(), d.warning_count()), (2, 4));
        let text = d.render(&sources);
        assert!(text.contains("`0.png`") && !text.contains("`1.png`"), "the first is shown: {text}");
        assert!(text.contains("a.usda:1:1") && text.contains("and 2 more warnings of this kind"), "{text}");
        assert!(!text.contains("and 0 more"), "{text}");
        // Moved into another sink, the count goes along.
        let mut all = Diagnostics::new();
        all.push(Diagnostic::warning("cannot open texture `x.png`").kind("texture"));
        all.extend(d);
        assert_eq!((all.items().len(), all.warning_count()), (2, 5));
        // --strict: every warning an error; notes are never promoted.
        all.push(Diagnostic::info("the stage has no lights"));
        all.make_warnings_errors();
        assert_eq!(all.error_count(), 2);
        assert!(all.items().iter().any(|d| d.severity == Severity::Note));
    }

    #[test]
    fn only_what_is_shown_is_kept_and_the_rest_is_counted() {
        let mut sources = SourceMap::new();
        let file = sources.add("a.ash", "}".repeat(1000));
        let mut d = Diagnostics::new();
        for i in 0..1000 {
            d.push(Diagnostic::warning(format!("w{i}")).at(Span::new(file, i, i + 1), ""));
        }
        // Past the cap, the file's first error is still kept (it decides a layer's fate).
        d.push(Diagnostic::error("e").at(Span::new(file, 0, 1), ""));
        d.push(Diagnostic::error("f").at(Span::new(file, 1, 2), ""));
        assert_eq!(d.items().len(), MAX_SHOWN_PER_FILE + 1);
        assert_eq!((d.warning_count(), d.error_count()), (1000, 2));
        let text = d.render(&sources);
        assert!(text.contains("note: 1 more error and 950 more warnings in a.ash not shown"), "{text}");
        let mut all = Diagnostics::new();
        all.extend(d);
        assert_eq!((all.warning_count(), all.error_count()), (1000, 2));
        all.make_warnings_errors();
        assert_eq!((all.warning_count(), all.error_count()), (0, 1002));
    }

    #[test]
    fn long_names_are_elided_in_messages_labels_and_notes() {
        let name = format!("/{}", "x".repeat(5000));
        let d = Diagnostic::error(format!("`{name}` reaches far; `short` stays"))
            .at(Span::default(), format!("in `{name}`"))
            .note(format!("unbalanced ` then `{name}"));
        let elided = format!("`/{}…{}` (5001 characters)", "x".repeat(39), "x".repeat(40));
        assert_eq!(d.message, format!("{elided} reaches far; `short` stays"));
        assert_eq!(d.labels[0].message, format!("in {elided}"));
        assert!(d.notes[0].len() > 5000, "an unclosed quote is not a name");
        assert_eq!(elide_long_names("no `names` here".into()), "no `names` here");
    }

    #[test]
    fn once_per_kind_keeps_the_first_and_counts_the_rest() {
        let mut groups = OncePerKind::new();
        for name in ["a", "b", "b", "c", "d", "e"] {
            groups.push("missing", name, Diagnostic::warning(format!("`{name}` is missing")));
        }
        groups.push("other", "x", Diagnostic::warning("other kind"));
        assert_eq!(groups.count("missing"), 6);
        let mut d = Diagnostics::new();
        groups.report(&mut d);
        assert_eq!(d.items().len(), 2);
        assert_eq!(d.items()[0].message, "`a` is missing");
        assert_eq!(d.items()[0].notes, vec!["5 more like it: `b`, `c`, `d` and 2 more".to_string()]);
        assert!(d.items()[1].notes.is_empty());
    }
}
