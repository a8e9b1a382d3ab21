//! `strata compile` output links from C: a C harness, built with the system C compiler against
//! the object, its header and the runtime static library, computes the same bits as the JIT.

use std::path::{Path, PathBuf};
use std::process::Command;
use strata::abi::{Closure, Globals};
use strata::backend::{BackendKind, Compiler};
use strata::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
use strata::diag::{Diagnostics, SourceMap};
use strata::front::library::Library;
use strata::ir::wired::PassOptions;

const SUBSTANCES: [&str; 4] = ["clay", "floor", "brushed_metal", "dirt"];

/// The newest runtime static library cargo built next to the strata binary.
fn runtime_staticlib() -> PathBuf {
    let deps = Path::new(env!("CARGO_BIN_EXE_strata")).parent().expect("target dir").join("deps");
    std::fs::read_dir(&deps)
        .expect("deps dir")
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("libstrata_rt-") && n.ends_with(".a"))
        })
        .max_by_key(|p| p.metadata().and_then(|m| m.modified()).ok())
        .expect("cargo builds strata-rt's staticlib with strata")
}

/// The shading point both sides evaluate for index `i`.
fn point(i: usize) -> Globals<'static> {
    let t = i as f32;
    Globals {
        p: [t * 0.37 - 3.0, (t * 0.11).sin() * 2.0, t * 0.05 - 1.0],
        n: [0.0, 1.0, 0.0],
        ng: [0.0, 1.0, 0.0],
        i: [0.0, 0.0, -1.0],
        dpdu: [1.0, 0.0, 0.0],
        dpdv: [0.0, 0.0, 1.0],
        u: (t * 0.013) % 1.0,
        v: (t * 0.029) % 1.0,
        st_footprint: [0.0; 4],
        primvars: Default::default(),
        params: Default::default(),
    }
}

const HARNESS: &str = r#"
#include <stdio.h>
#include <string.h>
#include "default.h"

static void dump_closure(const char *name, uint32_t status, const StrataClosure *c) {
    printf("%s %u %u", name, status, c->terms[0].kind);
    for (int k = 0; k < 8; k++) { uint32_t w; memcpy(&w, &c->terms[0].params[k], 4); printf(" %08x", w); }
    printf("\n");
}

int main(void) {
    /* Shading points arrive on stdin as raw StrataGlobals, so both sides see identical bits. */
    StrataGlobals g;
    while (fread(&g, sizeof g, 1, stdin) == 1) {
        StrataClosure c;
        float m; uint32_t s, w;
        memset(&c, 0, sizeof c); s = clay_surface(&g, &c); dump_closure("clay", s, &c);
        memset(&c, 0, sizeof c); s = floor_surface(&g, &c); dump_closure("floor", s, &c);
        memset(&c, 0, sizeof c); s = brushed_metal_surface(&g, &c); dump_closure("brushed_metal", s, &c);
        memset(&c, 0, sizeof c); s = dirt_surface(&g, &c); dump_closure("dirt", s, &c);
        s = dirt_mask(&g, &m); memcpy(&w, &m, 4); printf("dirt_mask %u %08x\n", s, w);
        s = clay_mask(&g, &m); memcpy(&w, &m, 4); printf("clay_mask %u %08x\n", s, w);
    }
    return 0;
}
"#;

fn jit_lines(points: &[Globals]) -> String {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let lib =
        Library::load(&[(PathBuf::from("scenes/default/default.ash"), Default::default())], &mut sources, &mut diags);
    assert!(!diags.has_errors(), "{}", diags.render(&sources));
    let mut compiler = Compiler::new(BackendKind::Jit, PassOptions::default());
    let code: Vec<_> = SUBSTANCES
        .iter()
        .map(|name| {
            let material = ComposedMaterial {
                layers: vec![ComposedLayer {
                    slot: Slot::parse("000").unwrap(),
                    substance: MaterialRef {
                        path: String::new(),
                        graph: lib.graph_by_name(name).unwrap(),
                        values: Vec::new(),
                        span: Default::default(),
                    },
                    overrides: Vec::new(),
                    vertical: Vec::new(),
                }],
                ..Default::default()
            };
            compiler.compile(&lib, &material, &mut diags).expect("compiles")
        })
        .collect();
    let mut out = String::new();
    for g in points {
        for (name, code) in SUBSTANCES.iter().zip(&code) {
            let mut c = Closure::default();
            let s = code.surface(g, 0, &mut c).map_or(1, |_| 0);
            out += &format!("{name} {s} {}", c.kind);
            for p in c.params {
                out += &format!(" {:08x}", p.to_bits());
            }
            out += "\n";
        }
        let mut m = [0.0f32];
        let s = code[3].masks(g, &mut m).map_or(1, |_| 0);
        out += &format!("dirt_mask {s} {:08x}\n", m[0].to_bits());
        let s = code[0].masks(g, &mut m).map_or(1, |_| 0);
        out += &format!("clay_mask {s} {:08x}\n", m[0].to_bits());
    }
    out
}

#[test]
fn compiled_object_links_from_c_and_matches_the_jit() {
    let dir = tempfile::tempdir().unwrap();
    let object = dir.path().join("default.o");
    let status = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["compile", "scenes/default/default.ash", "-o"])
        .arg(&object)
        .status()
        .unwrap();
    assert!(status.success());
    let header = std::fs::read_to_string(dir.path().join("default.h")).unwrap();
    assert!(header.contains("uint32_t dirt_mask(const StrataGlobals *g, float *out /* 1 */);"), "{header}");
    std::fs::write(dir.path().join("harness.c"), HARNESS).unwrap();
    let exe = dir.path().join("harness");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let out = Command::new(&cc)
        .current_dir(dir.path())
        .args(["-O1", "-o"])
        .arg(&exe)
        .arg("harness.c")
        .arg(&object)
        .arg(runtime_staticlib())
        .args(["-lm", "-lpthread", "-ldl"])
        .output()
        .expect("a C compiler (cc) is installed: Rust needs it as its linker");
    assert!(out.status.success(), "C build failed:\n{}", String::from_utf8_lossy(&out.stderr));

    let points: Vec<Globals> = (0..200).map(point).collect();
    let bytes: Vec<u8> = points
        .iter()
        .flat_map(|g| {
            let words = [g.p, g.n, g.ng, g.i, g.dpdu, g.dpdv].concat();
            let mut raw: Vec<u8> = words.into_iter().chain([g.u, g.v]).flat_map(f32::to_ne_bytes).collect();
            // The rest of the C struct: no primvars (a null pointer, length 0) and padding.
            raw.resize(std::mem::size_of::<Globals>(), 0);
            raw
        })
        .collect();
    let mut child =
        Command::new(&exe).stdin(std::process::Stdio::piped()).stdout(std::process::Stdio::piped()).spawn().unwrap();
    use std::io::Write;
    child.stdin.take().unwrap().write_all(&bytes).unwrap();
    let result = child.wait_with_output().unwrap();
    assert!(result.status.success());
    let from_c = String::from_utf8(result.stdout).unwrap();
    let from_jit = jit_lines(&points);
    assert_eq!(from_c.lines().count(), 200 * 6);
    for (k, (c, j)) in from_c.lines().zip(from_jit.lines()).enumerate() {
        assert_eq!(c, j, "line {k}: C object vs JIT");
    }
}
