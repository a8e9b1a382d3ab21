//! The fuzzing harness in the test suite: every input kept in `fuzz/corpus/` (each once
//! crashed, hung or flooded the terminal) is checked by `strata check` within a time and
//! output budget, and a short fuzzing session with a fixed seed finds nothing.

mod common;

use std::path::Path;
use std::time::Duration;

/// Runs `strata ARGS`, killing it after `limit`; returns (exit code, stdout, stderr), `None` for
/// the code when it was killed or died of a signal.
fn strata(args: &[&str], limit: Duration) -> (Option<i32>, Vec<u8>, Vec<u8>) {
    match common::run_strata(args, limit) {
        Some(out) => (out.status.code(), out.stdout, out.stderr),
        None => (None, Vec::new(), Vec::new()),
    }
}

#[test]
fn every_kept_failure_is_now_a_diagnostic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let mut failures = Vec::new();
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if !path.extension().is_some_and(|e| e == "ash" || e == "usda" || e == "mtlx") {
            continue;
        }
        checked += 1;
        let (code, _, stderr) = strata(&["check", path.to_str().unwrap()], Duration::from_secs(20));
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        match code {
            Some(0 | 1) => {}
            other => failures.push(format!(
                "{name}: exit {other:?} (killed or crashed): {}",
                String::from_utf8_lossy(&stderr[stderr.len().saturating_sub(400)..])
            )),
        }
        // Diagnostics are capped: a flood of errors on one long line stays readable.
        if stderr.len() > 256 << 10 {
            failures.push(format!("{name}: {} bytes of diagnostics", stderr.len()));
        }
    }
    assert!(checked > 0, "no corpus in {}", dir.display());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_short_fuzzing_session_finds_nothing() {
    let crashes = tempfile::tempdir().unwrap();
    let (code, stdout, stderr) = strata(
        // A debug build on a loaded CI machine: a lenient per-input budget (the documented
        // long run uses 10 s).
        &[
            "fuzz",
            "--secs",
            "20",
            "--jobs",
            "2",
            "--seed",
            "1",
            "--timeout",
            "30",
            "--crashes",
            crashes.path().to_str().unwrap(),
        ],
        Duration::from_secs(120),
    );
    let stdout = String::from_utf8_lossy(&stdout);
    eprintln!("{stdout}");
    assert_eq!(code, Some(0), "{stdout}\n{}", String::from_utf8_lossy(&stderr));
    let executions: u64 = stdout
        .split_whitespace()
        .nth(1)
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no execution count in {stdout:?}"));
    assert!(executions > 50, "only {executions} inputs ran");
}
