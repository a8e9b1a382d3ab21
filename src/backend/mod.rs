//! Backends: turn a lowered material ([`crate::ir::ssa::Module`]) into something the renderer
//! can call through [`abi::MaterialCode`].
//!
//! - [`clif`]: Cranelift code generation, shared by the JIT ([`jit`]) and native shader
//!   objects ([`object`]).
//! - [`interp`]: the reference interpreter over the same lowered IR.
//!
//! [`Compiler`] runs the whole pipeline for composed materials (wire → optimise → lower →
//! compile) with a cache keyed by the lowered code, so each distinct composition is compiled
//! once, and keeps the statistics `--stats` prints.

pub mod clif;
pub mod interp;
pub mod jit;
pub mod object;

use crate::abi::{Closure, ClosureSum, Globals, MAX_CLOSURE_TERMS, MaterialCode, MaterialInfo, ShaderError, Status};
use crate::compose::ComposedMaterial;
use crate::diag::Diagnostics;
use crate::front::library::Library;
use crate::ir::lower;
use crate::ir::ssa::{self, EntryKind};
use crate::ir::wired::{self, PassOptions};
use std::collections::HashMap;
use std::fmt;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::sync::Arc;
use std::time::Instant;

/// Which backend runs shader code.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum BackendKind {
    /// Cranelift-compiled native code.
    #[default]
    Jit,
    /// The reference interpreter.
    Interp,
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            BackendKind::Jit => "jit",
            BackendKind::Interp => "interp",
        })
    }
}

/// Executes the entry functions of one material.
pub trait Runner: Send + Sync {
    /// How an entry is addressed.
    type Entry: Copy + Send + Sync;
    /// Calls `entry`; `out` holds at least the words the entry writes.
    fn run(&self, entry: Self::Entry, g: &Globals, out: &mut [u32]) -> Status;
}

/// The entry points of a material, by what they compute.
#[derive(Clone, Debug)]
pub struct Entries<E> {
    mask: Vec<Option<E>>,
    displacement: Option<E>,
    surface: Vec<Option<E>>,
    normal: Vec<Option<E>>,
    channels: Vec<Option<E>>,
    emission: Vec<Option<E>>,
    /// Per layer, how many leading closure terms its surface entry writes, every word of
    /// them (`None`: not known to, so the whole value is cleared first).
    surface_terms: Vec<Option<usize>>,
}

/// The terms `f` writes, when its outputs are exactly the words of its first terms (the
/// lowering writes the terms that may be non-empty, each whole).
fn written_terms(f: &ssa::Function) -> Option<usize> {
    let term_words = ClosureSum::WORDS / MAX_CLOSURE_TERMS;
    let mut written = [false; ClosureSum::WORDS];
    for inst in f.blocks.iter().flat_map(|b| &b.insts) {
        if let ssa::Inst::Out(word, _) = inst.inst {
            *written.get_mut(word as usize)? = true;
        }
    }
    let words = written.iter().rposition(|&w| w).map_or(0, |last| last + 1);
    let terms = words.div_ceil(term_words);
    written[..terms * term_words].iter().all(|&w| w).then_some(terms)
}

impl<E: Copy> Entries<E> {
    /// Maps each function of `module` (by index) to an entry handle.
    pub fn new(module: &ssa::Module, mut handle: impl FnMut(usize) -> E) -> Entries<E> {
        let n = module.info.layers.len();
        let mut e = Entries {
            mask: vec![None; n],
            displacement: None,
            surface: vec![None; n],
            normal: vec![None; n],
            channels: vec![None; n],
            emission: vec![None; n],
            surface_terms: vec![None; n],
        };
        for (i, f) in module.functions.iter().enumerate() {
            let h = Some(handle(i));
            match f.kind {
                EntryKind::Mask(l) => e.mask[l] = h,
                EntryKind::Displacement => e.displacement = h,
                EntryKind::Surface(l) => (e.surface[l], e.surface_terms[l]) = (h, written_terms(f)),
                EntryKind::Normal(l) => e.normal[l] = h,
                EntryKind::Channels(l) => e.channels[l] = h,
                EntryKind::Emission(l) => e.emission[l] = h,
            }
        }
        e
    }
}

/// A compiled material: metadata, entries and the runner that executes them.
pub struct Material<R: Runner> {
    info: MaterialInfo,
    entries: Entries<R::Entry>,
    runner: R,
}

impl<R: Runner> Material<R> {
    /// Assembles a material.
    pub fn new(info: MaterialInfo, entries: Entries<R::Entry>, runner: R) -> Self {
        Material { info, entries, runner }
    }
}

/// Views f32 output as the 4-byte words entry functions write.
fn words(out: &mut [f32]) -> &mut [u32] {
    // SAFETY: f32 and u32 have the same size and alignment, and every bit pattern is valid.
    unsafe { std::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<u32>(), out.len()) }
}

impl<R: Runner> MaterialCode for Material<R> {
    fn info(&self) -> &MaterialInfo {
        &self.info
    }

    fn masks(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        for (layer, m) in out.iter_mut().enumerate() {
            *m = self.mask(g, layer)?;
        }
        Ok(())
    }

    fn mask(&self, g: &Globals, layer: usize) -> Result<f32, ShaderError> {
        if let Some(m) = self.info.layers.get(layer).and_then(|l| l.constant_mask) {
            return Ok(m);
        }
        match self.entries.mask.get(layer).copied().flatten() {
            Some(e) => {
                let mut out = [0u32];
                ShaderError::check(self.runner.run(e, g, &mut out))?;
                Ok(f32::from_bits(out[0]))
            }
            None => Ok(1.0),
        }
    }

    fn surface(&self, g: &Globals, layer: usize, out: &mut Closure) -> Result<(), ShaderError> {
        let mut sum = ClosureSum::default();
        self.surface_sum(g, layer, &mut sum)?;
        *out = sum.first();
        Ok(())
    }

    fn surface_sum(&self, g: &Globals, layer: usize, out: &mut ClosureSum) -> Result<(), ShaderError> {
        match self.entries.surface.get(layer).copied().flatten() {
            Some(e) => {
                // The entry writes the terms that may be non-empty; the rest must read empty.
                *out = ClosureSum::default();
                // SAFETY: `ClosureSum` is repr(C) of `ClosureTerm`s, each u32 and f32 fields
                // only: `ClosureSum::WORDS` 4-byte words.
                let w = unsafe {
                    std::slice::from_raw_parts_mut((out as *mut ClosureSum).cast::<u32>(), ClosureSum::WORDS)
                };
                ShaderError::check(self.runner.run(e, g, w))
            }
            None => {
                *out = ClosureSum::default();
                Ok(())
            }
        }
    }

    fn surface_terms(&self, g: &Globals, layer: usize, out: &mut ClosureSum) -> Result<usize, ShaderError> {
        let entry = self.entries.surface.get(layer).copied().flatten();
        match (entry, self.entries.surface_terms.get(layer).copied().flatten()) {
            (Some(e), Some(terms)) => {
                // SAFETY: as in `surface_sum`.
                let w = unsafe {
                    std::slice::from_raw_parts_mut((out as *mut ClosureSum).cast::<u32>(), ClosureSum::WORDS)
                };
                ShaderError::check(self.runner.run(e, g, w))?;
                Ok(terms)
            }
            (Some(_), None) => {
                self.surface_sum(g, layer, out)?;
                Ok(MAX_CLOSURE_TERMS)
            }
            (None, _) => Ok(0),
        }
    }

    fn displacement(&self, g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        match self.entries.displacement {
            Some(e) => ShaderError::check(self.runner.run(e, g, words(out))),
            None => {
                out.fill(0.0);
                Ok(())
            }
        }
    }

    fn normal(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        match self.entries.normal.get(layer).copied().flatten() {
            Some(e) => ShaderError::check(self.runner.run(e, g, words(out))),
            None => {
                *out = g.n;
                Ok(())
            }
        }
    }

    fn emission(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        match self.entries.emission.get(layer).copied().flatten() {
            Some(e) => ShaderError::check(self.runner.run(e, g, words(out))),
            None => {
                *out = [0.0; 3];
                Ok(())
            }
        }
    }

    fn channels(&self, g: &Globals, layer: usize, out: &mut [f32]) -> Result<(), ShaderError> {
        match self.entries.channels.get(layer).copied().flatten() {
            Some(e) => ShaderError::check(self.runner.run(e, g, words(out))),
            None => {
                out.fill(0.0);
                Ok(())
            }
        }
    }
}

/// Runs lowered functions in the interpreter.
pub struct InterpRunner {
    module: ssa::Module,
}

impl Runner for InterpRunner {
    type Entry = usize;
    fn run(&self, entry: usize, g: &Globals, out: &mut [u32]) -> Status {
        interp::run(&self.module.functions[entry], g, out)
    }
}

/// Builds an interpreted material.
pub fn interpret(module: ssa::Module) -> Material<InterpRunner> {
    let entries = Entries::new(&module, |i| i);
    Material::new(module.info.clone(), entries, InterpRunner { module })
}

/// Compiles a lowered material with the chosen backend.
pub fn compile_module(module: ssa::Module, backend: BackendKind) -> Result<Arc<dyn MaterialCode>, String> {
    Ok(match backend {
        BackendKind::Interp => Arc::new(interpret(module)),
        BackendKind::Jit => Arc::new(jit::compile(&module)?),
    })
}

/// What compiling a scene's materials cost.
#[derive(Clone, Debug, Default)]
pub struct CompileStats {
    /// Materials asked for.
    pub requested: usize,
    /// Materials actually compiled (the rest came from the cache).
    pub compiled: usize,
    /// Entry functions compiled.
    pub functions: usize,
    /// Lowered instructions compiled.
    pub instructions: usize,
    /// Wired nodes summed over materials, per pass (`wired`, `fold`, `dce`).
    pub nodes: Vec<(&'static str, usize)>,
    /// Layers pruned (hidden under opaque layers or masked to 0).
    pub layers_pruned: usize,
    /// Wall time in wiring, passes and lowering.
    pub lower_ms: f64,
    /// Wall time in the backend.
    pub codegen_ms: f64,
}

impl fmt::Display for CompileStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let nodes: Vec<String> = self.nodes.iter().map(|(p, n)| format!("{p} {n}")).collect();
        write!(
            f,
            "materials: {} requested, {} compiled ({} cached); nodes: {}; layers pruned: {}; \
             functions: {}; instructions: {}; lower {:.2} ms; codegen {:.2} ms",
            self.requested,
            self.compiled,
            self.requested - self.compiled,
            nodes.join(" -> "),
            self.layers_pruned,
            self.functions,
            self.instructions,
            self.lower_ms,
            self.codegen_ms
        )
    }
}

/// Compiles composed materials, each distinct one once.
pub struct Compiler {
    backend: BackendKind,
    passes: PassOptions,
    cache: HashMap<u64, Arc<dyn MaterialCode>>,
    /// Accumulated statistics.
    pub stats: CompileStats,
}

impl Compiler {
    /// A compiler for one backend and pass configuration.
    pub fn new(backend: BackendKind, passes: PassOptions) -> Compiler {
        Compiler { backend, passes, cache: HashMap::new(), stats: CompileStats::default() }
    }

    /// Lowers one composed material (wire, optimise, lower); problems go to `diags`.
    pub fn lower(&mut self, lib: &Library, material: &ComposedMaterial, diags: &mut Diagnostics) -> ssa::Module {
        let start = Instant::now();
        let passes = self.passes;
        let options = lower::LowerOptions { simplify: passes.optimize, ..Default::default() };
        // Both passes on one compiler thread (each would start its own; see `crate::stack`).
        let (wired, module) = crate::stack::on_compiler_stack(|| {
            let wired = wired::build(lib, material, passes, diags);
            let module = lower::lower(lib, &wired, options, diags);
            (wired, module)
        });
        for (i, (pass, n)) in wired.stats.nodes.iter().enumerate() {
            match self.stats.nodes.get_mut(i) {
                Some((_, total)) => *total += n,
                None => self.stats.nodes.push((pass, *n)),
            }
        }
        self.stats.layers_pruned += wired.stats.layers_pruned;
        self.stats.lower_ms += start.elapsed().as_secs_f64() * 1e3;
        module
    }

    /// Compiles one composed material, or returns the cached code of an identical one.
    /// `None` when diagnostics were reported as errors.
    pub fn compile(
        &mut self,
        lib: &Library,
        material: &ComposedMaterial,
        diags: &mut Diagnostics,
    ) -> Option<Arc<dyn MaterialCode>> {
        self.stats.requested += 1;
        let errors = diags.error_count();
        let module = self.lower(lib, material, diags);
        if diags.error_count() > errors {
            return None;
        }
        // The key is the lowered code itself: compositions that differ only in ways the
        // passes erase (a hidden layer, an override of a pruned input) share one compilation.
        let mut hasher = DefaultHasher::new();
        module.to_text().hash(&mut hasher);
        format!("{:?}", module.info).hash(&mut hasher);
        let key = hasher.finish();
        if let Some(code) = self.cache.get(&key) {
            return Some(code.clone());
        }
        let start = Instant::now();
        self.stats.functions += module.functions.len();
        self.stats.instructions += module.inst_count();
        let code = match compile_module(module, self.backend) {
            Ok(code) => code,
            Err(msg) => {
                diags.push(crate::diag::Diagnostic::error(format!("code generation failed: {msg}")));
                return None;
            }
        };
        self.stats.codegen_ms += start.elapsed().as_secs_f64() * 1e3;
        self.stats.compiled += 1;
        self.cache.insert(key, code.clone());
        Some(code)
    }
}
