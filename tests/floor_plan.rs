//! The floor plan (ARCHITECTURE.md): every `crate::` path in the library's non-test code names a
//! module on its own floor or a lower one. Floors, from the ground up: diag, input, abi,
//! runtime, stack; front; scene; compose; ir; backend; render; session; view; the tools (cli, bench, fuzz).
//! `tools/floor_plan.py` prints the same check per file, with import cycles.

use std::path::{Path, PathBuf};

/// Top-level modules by floor, lowest first.
const FLOORS: &[&[&str]] = &[
    &["diag", "input", "abi", "runtime", "stack"],
    &["front"],
    &["scene"],
    &["compose"],
    &["ir"],
    &["backend"],
    &["render"],
    &["session"],
    &["view"],
    &["cli", "bench", "fuzz", "main"],
];

fn floor_of(module: &str) -> Option<usize> {
    FLOORS.iter().position(|floor| floor.contains(&module))
}

/// Blanks comments, string and char literals (keeping newlines) so paths in them do not count.
fn strip_comments_and_strings(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let blank = |out: &mut String, s: &[u8]| out.extend(s.iter().map(|&c| if c == b'\n' { '\n' } else { ' ' }));
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            let end = b[i..].iter().position(|&c| c == b'\n').map_or(b.len(), |n| i + n);
            blank(&mut out, &b[i..end]);
            i = end;
        } else if b[i..].starts_with(b"/*") {
            let (mut depth, mut j) = (1, i + 2);
            while j < b.len() && depth > 0 {
                if b[j..].starts_with(b"/*") {
                    depth += 1;
                    j += 2;
                } else if b[j..].starts_with(b"*/") {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            blank(&mut out, &b[i..j]);
            i = j;
        } else if b[i] == b'r' && (b[i + 1..].starts_with(b"\"") || b[i + 1..].starts_with(b"#")) {
            // A raw string r"…" / r#"…"#; anything else starting with r is an identifier.
            let hashes = b[i + 1..].iter().take_while(|&&c| c == b'#').count();
            if b.get(i + 1 + hashes) != Some(&b'"') || (i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'))
            {
                out.push('r');
                i += 1;
                continue;
            }
            let close: Vec<u8> = std::iter::once(b'"').chain(std::iter::repeat_n(b'#', hashes)).collect();
            let start = i + 2 + hashes;
            let end = b[start..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(b.len(), |n| start + n + close.len());
            blank(&mut out, &b[i..end]);
            i = end;
        } else if b[i] == b'"' {
            let mut j = i + 1;
            while j < b.len() && b[j] != b'"' {
                j += if b[j] == b'\\' { 2 } else { 1 };
            }
            let end = (j + 1).min(b.len());
            blank(&mut out, &b[i..end]);
            i = end;
        } else if b[i] == b'\'' && b.get(i + 2) == Some(&b'\'') {
            blank(&mut out, &b[i..i + 3]);
            i += 3;
        } else if b[i] == b'\'' && b.get(i + 1) == Some(&b'\\') {
            let end = b[i + 2..].iter().position(|&c| c == b'\'').map_or(b.len(), |n| i + 3 + n);
            blank(&mut out, &b[i..end]);
            i = end;
        } else {
            out.push(b[i] as char);
            i += 1;
        }
    }
    out
}

/// Blanks every `#[cfg(test)]` item: a unit test may drive its stage from above.
fn strip_test_items(code: &str) -> String {
    let mut out = code.to_string();
    let mut search = 0;
    while let Some(at) = out[search..].find("#[cfg(test)]").map(|n| search + n) {
        let bytes = out.as_bytes();
        let (mut depth, mut end) = (0i32, at + "#[cfg(test)]".len());
        while end < bytes.len() {
            match bytes[end] {
                b'{' => depth += 1,
                b'}' => {
                    depth -= 1;
                    if depth == 0 {
                        end += 1;
                        break;
                    }
                }
                b';' if depth == 0 => {
                    end += 1;
                    break;
                }
                _ => {}
            }
            end += 1;
        }
        let blanked: String = out[at..end].chars().map(|c| if c == '\n' { '\n' } else { ' ' }).collect();
        out.replace_range(at..end, &blanked);
        search = end;
    }
    out
}

/// The top-level modules a file's code names through `crate::`, with the line of each.
fn crate_paths(code: &str) -> Vec<(String, usize)> {
    let mut found = Vec::new();
    let ident = |s: &str| s.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect::<String>();
    for (at, _) in code.match_indices("crate::") {
        if at > 0 && code.as_bytes()[at - 1].is_ascii_alphanumeric() {
            continue; // `strata_crate::…` and the like
        }
        let line = code[..at].matches('\n').count() + 1;
        let rest = &code[at + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            // `use crate::{a, b::c, d::{e, f}}`: the first segment of each top-level entry.
            let mut depth = 0;
            let mut entry_start = true;
            for (i, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => entry_start = true,
                    c if entry_start && (c.is_ascii_alphabetic() || c == '_') => {
                        found.push((ident(&group[i..]), line));
                        entry_start = false;
                    }
                    _ => {}
                }
            }
        } else {
            found.push((ident(rest), line));
        }
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("src/ is readable") {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Files declared as `#[cfg(test)] mod name;` (test-only modules in their own file).
fn test_only_files(files: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for file in files {
        let code = strip_comments_and_strings(&std::fs::read_to_string(file).expect("readable source"));
        let dir = if file.file_name().is_some_and(|n| n == "mod.rs" || n == "lib.rs") {
            file.parent().expect("parent").to_path_buf()
        } else {
            file.with_extension("")
        };
        let mut rest = code.as_str();
        while let Some(at) = rest.find("#[cfg(test)]") {
            rest = &rest[at + "#[cfg(test)]".len()..];
            let item = rest.trim_start();
            let item = item.strip_prefix("pub ").unwrap_or(item).trim_start();
            if let Some(decl) = item.strip_prefix("mod ") {
                let name: String = decl.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                if decl[name.len()..].trim_start().starts_with(';') {
                    out.push(dir.join(format!("{name}.rs")));
                    out.push(dir.join(&name).join("mod.rs"));
                }
            }
        }
    }
    out
}

/// Every `crate::` path in `src` that names a module on a higher floor than its file's, as
/// `file:line: from (floor) -> to (floor)`; and top-level modules with no floor.
fn upward_imports(src: &Path) -> (Vec<String>, Vec<String>) {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    files.sort();
    let test_only = test_only_files(&files);
    let (mut upward, mut unplaced) = (Vec::new(), Vec::new());
    for file in &files {
        let rel = file.strip_prefix(src).expect("under src");
        let top = rel.components().next().expect("a path").as_os_str().to_string_lossy();
        let module = top.trim_end_matches(".rs").to_string();
        if module == "lib" || test_only.iter().any(|t| t == file) {
            continue;
        }
        let Some(from) = floor_of(&module) else {
            unplaced.push(module);
            continue;
        };
        let text = std::fs::read_to_string(file).expect("readable source");
        let code = strip_test_items(&strip_comments_and_strings(&text));
        for (target, line) in crate_paths(&code) {
            match floor_of(&target) {
                Some(to) if to > from => upward.push(format!(
                    "src/{}:{line}: {module} (floor {from}) imports crate::{target} (floor {to})",
                    rel.display()
                )),
                Some(_) => {}
                None => unplaced.push(target),
            }
        }
    }
    unplaced.sort();
    unplaced.dedup();
    (upward, unplaced)
}

#[test]
fn no_import_runs_up_the_floors() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let (upward, unplaced) = upward_imports(&src);
    assert!(
        unplaced.is_empty(),
        "top-level modules with no floor (add them to FLOORS in tests/floor_plan.rs and ARCHITECTURE.md): {unplaced:?}"
    );
    assert!(upward.is_empty(), "imports up the floors:\n{}", upward.join("\n"));
}

#[test]
fn the_scanner_sees_every_form_of_crate_path() {
    let code = "use crate::render::film;\nuse crate::{abi, diag::Span, ir::{lower, ssa}};\n\
                fn f() { crate::compose::scene::compose_stage(); let s = \"crate::cli\"; }\n\
                // crate::bench in a comment\n#[cfg(test)]\nmod tests { use crate::fuzz; }\n";
    let code = strip_test_items(&strip_comments_and_strings(code));
    let names: Vec<String> = crate_paths(&code).into_iter().map(|(name, _)| name).collect();
    assert_eq!(names, ["render", "abi", "diag", "ir", "compose"]);
}
