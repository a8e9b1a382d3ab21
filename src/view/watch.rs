//! Following saved edits: the directories of the files the scene read are watched (editors
//! save by writing a temporary and renaming it over the file, which a watch on the file itself
//! would lose), and events on those files are reported to a callback (the worker's queue).

use notify::{RecommendedWatcher, RecursiveMode, Watcher as _};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// The file watcher and the files it reports.
pub(crate) struct Watcher {
    inner: RecommendedWatcher,
    files: Arc<Mutex<HashSet<PathBuf>>>,
    directories: HashSet<PathBuf>,
}

/// Starts a watcher that calls `changed` with the files [`Watcher::watch`] named that an
/// event touched (canonical paths).
pub(crate) fn start(changed: impl Fn(Vec<PathBuf>) + Send + 'static) -> Result<Watcher, String> {
    let files: Arc<Mutex<HashSet<PathBuf>>> = Arc::default();
    let watched = files.clone();
    let inner = notify::recommended_watcher(move |event: notify::Result<notify::Event>| {
        let Ok(event) = event else { return };
        // Reads are not edits; closing a file written is the end of one.
        let closed_written = matches!(
            event.kind,
            notify::EventKind::Access(notify::event::AccessKind::Close(notify::event::AccessMode::Write))
        );
        if event.kind.is_access() && !closed_written {
            return;
        }
        let files = watched.lock().unwrap_or_else(|e| e.into_inner());
        let paths: Vec<PathBuf> = event.paths.iter().map(|p| canonical(p)).filter(|p| files.contains(p)).collect();
        if !paths.is_empty() {
            changed(paths);
        }
    })
    .map_err(|e| format!("cannot watch files: {e}"))?;
    Ok(Watcher { inner, files, directories: HashSet::new() })
}

impl Watcher {
    /// Reports changes of `files` (and keeps reporting those named before).
    pub fn watch(&mut self, files: &[PathBuf]) {
        let mut known = self.files.lock().unwrap_or_else(|e| e.into_inner());
        for file in files {
            known.insert(canonical(file));
            if let Some(dir) = file.parent()
                && self.directories.insert(dir.to_path_buf())
            {
                // A directory that cannot be watched (removed meanwhile) only loses live updates.
                let _ = self.inner.watch(dir, RecursiveMode::NonRecursive);
            }
        }
    }
}

/// `path` canonicalised when it exists; a file being replaced may briefly not exist, and its
/// directory is then canonical instead.
fn canonical(path: &Path) -> PathBuf {
    if let Ok(p) = crate::input::canonicalize(path) {
        return p;
    }
    match (path.parent().and_then(|d| crate::input::canonicalize(d).ok()), path.file_name()) {
        (Some(dir), Some(name)) => dir.join(name),
        _ => path.to_path_buf(),
    }
}
