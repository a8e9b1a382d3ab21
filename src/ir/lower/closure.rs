//! Lowering closure values: a fixed array of [`abi::MAX_CLOSURE_TERMS`] terms laid out as
//! [`abi::ClosureTerm`] (kind, above, weight rgb, parameters), so variables, selects and entry
//! outputs treat a closure like any other bundle of scalars.
//!
//! Term positions are decided when compiling: a term whose kind is a known constant `None` is
//! empty, so `a + b` places `b`'s possibly non-empty terms right after `a`'s. A sum that could
//! need more than [`abi::MAX_CLOSURE_TERMS`] terms is a diagnostic at the operator, never a
//! silent drop. `layer(top, base)` concatenates too and marks `top`'s terms in the `above`
//! bits of each of `base`'s terms; the renderer turns those bits into energy-conserving
//! layering.

use super::{FnLower, Lv};
use crate::abi::{self, ClosureKind, MAX_CLOSURE_TERMS, TERM_PARAMS};
use crate::diag::{Diagnostic, Span};
use crate::ir::ssa::{self, BinOp, CmpOp, Ty, Var};

/// Words of one term: kind, above, weight rgb, parameters.
pub(super) const TERM_WORDS: usize = 5 + TERM_PARAMS;
/// Words of a closure value.
pub(super) const CLOSURE_WORDS: usize = TERM_WORDS * MAX_CLOSURE_TERMS;
const _: () = assert!(CLOSURE_WORDS == abi::ClosureSum::WORDS);

/// Offsets within a term.
const KIND: usize = 0;
const ABOVE: usize = 1;
const WEIGHT: usize = 2;
const PARAMS: usize = 5;

/// The scalar layout of a closure value.
pub(super) fn closure_layout() -> Vec<Ty> {
    (0..MAX_CLOSURE_TERMS).flat_map(|_| [Ty::I32, Ty::I32].into_iter().chain([Ty::F32; TERM_WORDS - 2])).collect()
}

/// The kinds of closure term a parameter-setting operator applies to.
#[derive(Clone, Copy)]
enum Kinds {
    /// Every kind but this one.
    AllBut(ClosureKind),
    /// This kind only.
    Only(ClosureKind),
}

/// What the lowering knows of a closure variable's terms: how many any assignment so far may
/// have filled, and how many a read has relied on.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct TermBound {
    filled: usize,
    read: usize,
}

impl FnLower<'_> {
    /// A closure value is stored in the variables starting at `first`: its live terms raise
    /// the variable's bound. Raising it inside a loop after a read relied on the lower bound
    /// would let the loop grow the closure past what was compiled: an error at the statement.
    pub(super) fn closure_stored(&mut self, first: Var, values: &[ssa::Value]) {
        let live = self.live_terms(values);
        let bound = self.closure_bounds.entry(first.0).or_default();
        if live > bound.filled {
            let grows_in_loop = self.loop_nesting > 0 && bound.read > 0 && live > bound.read;
            bound.filled = live;
            if grows_in_loop {
                self.diags.push(
                    Diagnostic::error("a closure that gains terms in a loop has no fixed number of terms")
                        .at(self.here, format!("now {live} terms")),
                );
            }
        }
    }

    /// A closure value was read from the variables starting at `first`: terms past its bound
    /// are empty (kind `None`), so sums of variables place their terms as tightly as values.
    pub(super) fn closure_loaded(&mut self, first: Var, values: &mut [ssa::Value]) {
        let bound = self.closure_bounds.entry(first.0).or_default();
        bound.read = bound.read.max(bound.filled).max(1);
        let filled = bound.filled;
        for t in filled..MAX_CLOSURE_TERMS {
            values[t * TERM_WORDS + KIND] = self.b.iconst(0);
        }
    }

    /// The empty closure: every term of kind `None`.
    pub(super) fn empty_closure(&mut self) -> Vec<ssa::Value> {
        closure_layout().into_iter().map(|t| if t == Ty::I32 { self.b.iconst(0) } else { self.b.fconst(0.0) }).collect()
    }

    /// A single lobe of unit weight with the given parameters (at most [`TERM_PARAMS`];
    /// the rest are 0).
    pub(super) fn lobe(&mut self, kind: ClosureKind, params: &[ssa::Value]) -> Lv {
        let mut c = self.empty_closure();
        c[KIND] = self.b.iconst(kind as i32);
        let one = self.b.fconst(1.0);
        c[WEIGHT..WEIGHT + 3].fill(one);
        for (k, &p) in params.iter().take(TERM_PARAMS).enumerate() {
            c[PARAMS + k] = p;
        }
        Lv::Scalars(c)
    }

    /// Terms of `c` that may be non-empty: one past the last whose kind is not a known `None`.
    pub(super) fn live_terms(&self, c: &[ssa::Value]) -> usize {
        (0..MAX_CLOSURE_TERMS).rev().find(|&t| self.b.known(c[t * TERM_WORDS + KIND]) != Some(0)).map_or(0, |t| t + 1)
    }

    /// `closure * w`, `w` one float or a colour. A term whose weight is then known to be zero
    /// becomes empty (kind `None`), so a trailing one takes no place in the closure: a
    /// zero-weight lobe a surface keeps for an input it was not given (OpenPBR's thin-walled
    /// translucency, a mix at 0) costs neither a term of the eight nor decoding per hit.
    pub(super) fn closure_scale(&mut self, c: &[ssa::Value], w: &[ssa::Value]) -> Lv {
        let mut out = c.to_vec();
        for t in 0..self.live_terms(c) {
            let mut zero = true;
            for k in 0..3 {
                let at = t * TERM_WORDS + WEIGHT + k;
                out[at] = self.b.binary(BinOp::FMul, c[at], w[if w.len() == 1 { 0 } else { k }]);
                // ±0 (the renderer clamps weights to [0, 1], so a negative zero is zero too).
                zero &= self.b.known(out[at]).is_some_and(|bits| bits & 0x7fff_ffff == 0);
            }
            if zero {
                out[t * TERM_WORDS + KIND] = self.b.iconst(ClosureKind::None as i32);
            }
        }
        Lv::Scalars(out)
    }

    /// `top` followed by `base`; with `layered`, `base`'s terms lie under every term of `top`.
    /// A result past [`MAX_CLOSURE_TERMS`] is reported at `span` (the operator).
    pub(super) fn closure_concat(&mut self, top: &[ssa::Value], base: &[ssa::Value], layered: bool, span: Span) -> Lv {
        let (nt, nb) = (self.live_terms(top), self.live_terms(base));
        if nt + nb > MAX_CLOSURE_TERMS {
            self.diags.push(
                Diagnostic::error(format!(
                    "this closure could need {} terms; a closure holds at most {MAX_CLOSURE_TERMS}",
                    nt + nb
                ))
                .at(span, format!("{nt} + {nb} terms")),
            );
            return Lv::Scalars(top.to_vec());
        }
        let mut out = top.to_vec();
        // Bits of `base`'s `above` masks move up by `nt`; `layer` adds the bits of `top`'s terms.
        let shift = self.b.iconst(1 << nt);
        let top_bits = self.b.iconst(if layered { (1 << nt) - 1 } else { 0 });
        for t in 0..nb {
            let (from, to) = (t * TERM_WORDS, (nt + t) * TERM_WORDS);
            out[to..to + TERM_WORDS].copy_from_slice(&base[from..from + TERM_WORDS]);
            let moved = self.b.binary(BinOp::IMul, base[from + ABOVE], shift);
            out[to + ABOVE] = self.b.binary(BinOp::Or, moved, top_bits);
        }
        Lv::Scalars(out)
    }

    /// `with_normal(c, n)`: `n` in the normal words ([`abi::TERM_NORMAL`]) of every term of
    /// `c`, but generalized Schlick terms' (their parameters fill those words): one known to be
    /// such a term is reported at `span`.
    pub(super) fn closure_with_normal(&mut self, c: &[ssa::Value], n: &[ssa::Value], span: Span) -> Lv {
        let (out, skipped) =
            self.closure_set_params(c, abi::TERM_NORMAL, n, Kinds::AllBut(ClosureKind::GeneralizedSchlick));
        if skipped {
            self.diags.push(
                Diagnostic::warning("generalized_schlick_bsdf has no normal of its own: it uses the shading normal")
                    .at(span, "this normal"),
            );
        }
        Lv::Scalars(out)
    }

    /// `with_thin_film(c, thickness, ior, weight)`: a thin film (thickness in nm, its index,
    /// its coverage) on every term of `c` of a kind that takes one ([`abi::thin_film_words`]:
    /// dielectrics, metals, conductors, generalized Schlick); other terms are unchanged.
    pub(super) fn closure_with_thin_film(&mut self, c: &[ssa::Value], film: &[ssa::Value]) -> Lv {
        let mut out = c.to_vec();
        for kind in abi::THIN_FILM_KINDS {
            let at = abi::thin_film_words(kind).expect("a kind that takes a film");
            out = self.closure_set_params(&out, at, film, Kinds::Only(kind)).0;
        }
        Lv::Scalars(out)
    }

    /// `with_darkening(c, factor)`: `1 − factor` in the darkening words
    /// ([`abi::TERM_DARKENING`]) of every dielectric term of `c`; other terms are unchanged.
    pub(super) fn closure_with_darkening(&mut self, c: &[ssa::Value], factor: &[ssa::Value]) -> Lv {
        let one = self.b.fconst(1.0);
        let removed: Vec<ssa::Value> = factor.iter().map(|&f| self.b.binary(BinOp::FSub, one, f)).collect();
        Lv::Scalars(self.closure_set_params(c, abi::TERM_DARKENING, &removed, Kinds::Only(ClosureKind::Dielectric)).0)
    }

    /// `with_anisotropy(c, tangent, aspect)`: `[tangent xyz, aspect]` in the tangent and aspect
    /// words ([`abi::TERM_TANGENT`], [`abi::TERM_ASPECT`], adjacent) of every term of `c`.
    pub(super) fn closure_with_anisotropy(&mut self, c: &[ssa::Value], words: &[ssa::Value; 4]) -> Lv {
        const _: () = assert!(abi::TERM_ASPECT == abi::TERM_TANGENT + 3);
        Lv::Scalars(self.closure_set_params(c, abi::TERM_TANGENT, words, Kinds::AllBut(ClosureKind::None)).0)
    }

    /// `with_thin_walled(c, flag)`: where `flag` is not 0, every transmitting dielectric term
    /// of `c` (scatter "T" or "RT") becomes a thin-walled sheet, its scatter word raised by
    /// [`abi::THIN_WALLED_SCATTER`]. Reflecting-only dielectrics (coats), sheets already and
    /// other kinds are left as they are; a term whose kind is known only when running, by a
    /// select.
    pub(super) fn closure_with_thin_walled(&mut self, c: &[ssa::Value], flag: ssa::Value) -> Lv {
        let mut out = c.to_vec();
        let zero = self.b.fconst(0.0);
        let on = self.b.cmp(CmpOp::Ne, flag, zero);
        // Scatter 1 ("T") and 2 ("RT") transmit: the words in (0.5, 2.5).
        let (low, high) = (self.b.fconst(0.5), self.b.fconst(2.5));
        let raise = self.b.fconst(abi::THIN_WALLED_SCATTER);
        for t in 0..self.live_terms(c) {
            let kind = c[t * TERM_WORDS + KIND];
            let known = self.b.known(kind).map(ClosureKind::from_u32);
            if known.is_some_and(|k| k != ClosureKind::Dielectric) {
                continue;
            }
            let word = t * TERM_WORDS + PARAMS + abi::DIELECTRIC_SCATTER;
            let scatter = c[word];
            let above_low = self.b.cmp(CmpOp::Gt, scatter, low);
            let below_high = self.b.cmp(CmpOp::Lt, scatter, high);
            let mut thin = self.b.binary(BinOp::And, above_low, below_high);
            thin = self.b.binary(BinOp::And, thin, on);
            if known.is_none() {
                let dielectric = self.b.iconst(ClosureKind::Dielectric as i32);
                let is_dielectric = self.b.cmp(CmpOp::Eq, kind, dielectric);
                thin = self.b.binary(BinOp::And, thin, is_dielectric);
            }
            let raised = self.b.binary(BinOp::FAdd, scatter, raise);
            out[word] = self.b.select(thin, raised, scatter);
        }
        Lv::Scalars(out)
    }

    /// `c` with `values` in parameter words `at..` of every term of the `kinds`: a term of a
    /// kind known when compiling is set or not, one of a kind known only when running by a
    /// select. Also whether a term of a known kind was left out.
    fn closure_set_params(
        &mut self,
        c: &[ssa::Value],
        at: usize,
        values: &[ssa::Value],
        kinds: Kinds,
    ) -> (Vec<ssa::Value>, bool) {
        let mut out = c.to_vec();
        let mut skipped = false;
        for t in 0..self.live_terms(c) {
            let kind = c[t * TERM_WORDS + KIND];
            let known = self.b.known(kind).map(ClosureKind::from_u32);
            if known == Some(ClosureKind::None) {
                continue;
            }
            // `keep`: whether the term keeps its words.
            let keep = match (known, kinds) {
                (Some(k), Kinds::AllBut(other)) if k != other => None,
                (Some(k), Kinds::Only(one)) if k == one => None,
                (Some(_), _) => {
                    skipped = true;
                    continue;
                }
                (None, Kinds::AllBut(other)) => {
                    let other = self.b.iconst(other as i32);
                    Some(self.b.cmp(CmpOp::Eq, kind, other))
                }
                (None, Kinds::Only(one)) => {
                    let one = self.b.iconst(one as i32);
                    Some(self.b.cmp(CmpOp::Ne, kind, one))
                }
            };
            for (k, &v) in values.iter().enumerate() {
                let word = t * TERM_WORDS + PARAMS + at + k;
                out[word] = match keep {
                    None => v,
                    Some(keep) => self.b.select(keep, c[word], v),
                };
            }
        }
        (out, skipped)
    }

    /// `mix(a, b, t) = a·(1 − t) + b·t`, `t` one float or a colour.
    pub(super) fn closure_mix(&mut self, a: &[ssa::Value], b: &[ssa::Value], t: &[ssa::Value], span: Span) -> Lv {
        let one = self.b.fconst(1.0);
        let rest: Vec<ssa::Value> = t.iter().map(|&x| self.b.binary(BinOp::FSub, one, x)).collect();
        let a = self.closure_scale(a, &rest).scalars();
        let b = self.closure_scale(b, t).scalars();
        self.closure_concat(&a, &b, false, span)
    }
}

#[cfg(test)]
mod tests {
    use crate::abi::{self, ClosureKind, ClosureSum, Globals, MaterialCode};
    use crate::backend::{BackendKind, Compiler};
    use crate::compose::{ComposedLayer, ComposedMaterial, MaterialRef, Slot};
    use crate::diag::{Diagnostics, SourceMap};
    use crate::front::library::Library;
    use crate::ir::wired::PassOptions;
    use std::sync::Arc;

    /// Compiles a shader body that sets `bsdf`, with both backends; the rendered diagnostics
    /// on failure.
    fn compile(body: &str) -> Result<Vec<Arc<dyn MaterialCode>>, String> {
        let source = format!(
            "shader s(float x = 0.25, output closure bsdf) {{\n{body}\n}}\nsubstance t {{\n    node n = s();\n    surface = n.bsdf;\n}}\n"
        );
        let mut sources = SourceMap::new();
        let mut diags = Diagnostics::new();
        let (lib, _) = Library::from_text("closures.ash", &source, &mut sources, &mut diags);
        if diags.has_errors() {
            return Err(diags.render(&sources));
        }
        let material = ComposedMaterial {
            layers: vec![ComposedLayer {
                slot: Slot::parse("000").unwrap(),
                substance: MaterialRef {
                    path: "/Looks/T".into(),
                    graph: lib.graph_by_name("t").expect("substance t"),
                    values: Vec::new(),
                    span: Default::default(),
                },
                overrides: Vec::new(),
                vertical: Vec::new(),
            }],
            ..Default::default()
        };
        let mut out = vec![];
        for backend in [BackendKind::Jit, BackendKind::Interp] {
            let mut compiler = Compiler::new(backend, PassOptions { optimize: true, ..Default::default() });
            let code = compiler.compile(&lib, &material, &mut diags);
            if diags.has_errors() {
                return Err(diags.render(&sources));
            }
            out.push(code.expect("compiled"));
        }
        Ok(out)
    }

    /// `(kind, above, weight)` of each non-empty term, identical from both backends.
    fn terms(body: &str) -> Vec<(ClosureKind, u32, [f32; 3])> {
        let codes = compile(body).unwrap_or_else(|e| panic!("{e}"));
        let read = |code: &Arc<dyn MaterialCode>| {
            let mut sum = ClosureSum::default();
            code.surface_sum(&Globals::default(), 0, &mut sum).expect("runs");
            sum
        };
        let sums: Vec<ClosureSum> = codes.iter().map(read).collect();
        assert_eq!(sums[0], sums[1], "JIT and interpreter disagree");
        // `surface_terms` writes the same leading terms over a stale buffer, and every term
        // past them is empty in the whole value (so the renderer, reading only those, sees it).
        for (code, sum) in codes.iter().zip(&sums) {
            let mut stale = ClosureSum::default();
            stale.terms.iter_mut().for_each(|t| (t.kind, t.weight) = (u32::MAX, [f32::NAN; 3]));
            let written = code.surface_terms(&Globals::default(), 0, &mut stale).expect("runs");
            assert!(written < abi::MAX_CLOSURE_TERMS, "{written} terms: the entry's writes were not recognised");
            assert_eq!(stale.terms[..written], sum.terms[..written]);
            assert!(sum.terms[written..].iter().all(|t| *t == abi::ClosureTerm::default()), "{written}: {sum:?}");
        }
        sums[0]
            .terms
            .iter()
            .filter(|t| t.kind != 0)
            .map(|t| (ClosureKind::from_u32(t.kind), t.above, t.weight))
            .collect()
    }

    #[test]
    fn sums_weights_mixes_and_layers() {
        use ClosureKind::*;
        let got = terms(
            "bsdf = layer(dielectric_bsdf(color(1.0), 1.5, 0.2, \"R\"),
                          diffuse_bsdf(color(0.5)) * 0.5 + color(0.2, 0.3, 0.4) * metal_bsdf(color(0.9), color(1.0), 0.3));",
        );
        assert_eq!(got, vec![(Dielectric, 0, [1.0; 3]), (Diffuse, 0b1, [0.5; 3]), (Metal, 0b1, [0.2, 0.3, 0.4])]);
        let got = terms("bsdf = mix(diffuse_bsdf(color(1.0)), sheen_bsdf(color(1.0), 0.3), x);");
        assert_eq!(got, vec![(Diffuse, 0, [0.75; 3]), (Sheen, 0, [0.25; 3])]);
        // Compound assignment, and layering a layered stack: bits move with their terms.
        let got = terms(
            "closure c = diffuse_bsdf(color(1.0));
             c += oren_nayar_diffuse_bsdf(color(1.0), 0.5, 1.0);
             c *= 0.5;
             closure coated = layer(generalized_schlick_bsdf(color(1.0), color(1.0), color(1.0), 5.0, 0.1), c);
             bsdf = layer(sheen_bsdf(color(1.0), 0.4), coated) + burley_diffuse_bsdf(color(0.5), 0.5);",
        );
        assert_eq!(
            got,
            vec![
                (Sheen, 0, [1.0; 3]),
                (GeneralizedSchlick, 0b1, [1.0; 3]),
                (Diffuse, 0b11, [0.5; 3]),
                (OrenNayar, 0b11, [0.5; 3]),
                (Burley, 0, [1.0; 3]),
            ]
        );
        // A branch keeps both sides' terms in place.
        let got = terms(
            "closure c = diffuse_bsdf(color(1.0));
             if (x > 0.5) { c = c + conductor_bsdf(color(0.2), color(3.9), 0.1); }
             bsdf = c + dielectric_bsdf(color(1.0), 1.5, 0.0, \"RT\");",
        );
        assert_eq!(got, vec![(Diffuse, 0, [1.0; 3]), (Dielectric, 0, [1.0; 3])]);
    }

    /// A term whose weight is a known zero is empty, and a trailing one takes no place: a
    /// surface's unused lobe (OpenPBR's thin-walled translucency when not thin-walled) leaves
    /// room for vertical layers over it.
    #[test]
    fn a_known_zero_weight_term_is_empty_and_takes_no_place() {
        use ClosureKind::*;
        let got = terms("bsdf = diffuse_bsdf(color(1.0)) + translucent_bsdf(color(1.0)) * 0.0;");
        assert_eq!(got, vec![(Diffuse, 0, [1.0; 3])]);
        let got = terms("bsdf = translucent_bsdf(color(1.0)) * color(0.0, -0.0, 0.0) + diffuse_bsdf(color(1.0));");
        assert_eq!(got, vec![(Diffuse, 0, [1.0; 3])]);
        // Six terms and a zero one under two: eight, not nine.
        let eight = "closure d = diffuse_bsdf(color(1.0));
             closure base = d + d + d + d + d + d + translucent_bsdf(color(1.0)) * 0.0;
             bsdf = layer(d + d, base);";
        assert!(compile(eight).is_ok(), "{:?}", compile(eight).err());
        assert!(compile(&eight.replace("* 0.0", "* 0.5")).is_err(), "nine terms must not compile");
        // A weight not known when compiling (zero here, at u = 0) keeps its term.
        let got = terms("bsdf = diffuse_bsdf(color(1.0)) + translucent_bsdf(color(1.0)) * u;");
        assert_eq!(got.iter().map(|t| t.0).collect::<Vec<_>>(), vec![Diffuse, Translucent]);
    }

    #[test]
    fn too_many_terms_and_misuse_are_located_errors() {
        let err = compile(
            "closure d = diffuse_bsdf(color(1.0));
             bsdf = d + d + d + d + d + d + d + d + d;",
        )
        .err()
        .expect("nine terms must not compile");
        assert!(err.contains("could need 9 terms") && err.contains("closures.ash:3"), "{err}");
        let err = compile("bsdf = layer(diffuse_bsdf(color(1.0)) * 0.5 + diffuse_bsdf(color(1.0)) + diffuse_bsdf(color(1.0)) + diffuse_bsdf(color(1.0)) + diffuse_bsdf(color(1.0)), diffuse_bsdf(color(1.0)) + diffuse_bsdf(color(1.0)) + diffuse_bsdf(color(1.0)) + diffuse_bsdf(color(1.0)));")
            .err()
            .expect("layer past 8 terms");
        assert!(err.contains("could need 9 terms"), "{err}");
        let err = compile("bsdf = dielectric_bsdf(color(1.0), 1.5, 0.1, \"TR\");").err().expect("bad mode");
        assert!(err.contains("unknown scatter mode `TR`"), "{err}");
        for bad in [
            "bsdf = diffuse_bsdf(color(1.0)) * diffuse_bsdf(color(1.0));",
            "bsdf = diffuse_bsdf(color(1.0)) + 1.0;",
            "bsdf = diffuse_bsdf(color(1.0)) - diffuse_bsdf(color(1.0));",
            "bsdf = mix(diffuse_bsdf(color(1.0)), color(1.0), 0.5);",
            "bsdf = layer(diffuse_bsdf(color(1.0)), color(1.0));",
        ] {
            assert!(compile(bad).is_err(), "{bad} compiled");
        }
    }
}
