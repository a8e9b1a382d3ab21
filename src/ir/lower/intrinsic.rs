//! Lowering intrinsics: math, noise and patterns (runtime calls), texture reads and primvars.

use super::{FnLower, Frame, Lv};
use crate::abi::{self, PrimvarInfo};
use crate::diag::Diagnostic;
use crate::front::hir::Expr;
use crate::front::intrinsics::Intrinsic;
use crate::front::types::Type;
use crate::ir::ssa::{self, BinOp, CmpOp, Inst, Ty, UnOp};
use crate::runtime::rt::RtFn;
use crate::runtime::texture;
use std::path::Path;

impl FnLower<'_> {
    pub(super) fn intrinsic(&mut self, i: Intrinsic, args: &[Expr], frame: &mut Frame) -> Lv {
        use Intrinsic::*;
        if i == Texture {
            return self.texture(args, frame);
        }
        if i == TextureChannel {
            return self.texture_channel(args, frame);
        }
        if matches!(i, Primvar | PrimvarFloat | PrimvarVector) {
            return self.primvar(args, frame, 0);
        }
        if i == PrimvarAlpha {
            return self.primvar(args, frame, 3);
        }
        // The call, where a closure past its capacity is reported (lowering arguments moves `here`).
        let at = self.here;
        let a: Vec<Vec<ssa::Value>> = args.iter().map(|x| self.expr(x, frame).scalars()).collect();
        if i == Mix && args[0].ty == Type::CLOSURE {
            return self.closure_mix(&a[0], &a[1], &a[2], at);
        }
        let rt1 = |f: RtFn| move |s: &mut Self, l: &[ssa::Value]| s.b.call(f, vec![l[0]]);
        let un = |op: UnOp| move |s: &mut Self, l: &[ssa::Value]| s.b.unary(op, l[0]);
        match i {
            Sin => self.lanes(&a, rt1(RtFn::Sin)),
            Cos => self.lanes(&a, rt1(RtFn::Cos)),
            Tan => self.lanes(&a, rt1(RtFn::Tan)),
            Asin => self.lanes(&a, rt1(RtFn::Asin)),
            Acos => self.lanes(&a, rt1(RtFn::Acos)),
            Atan => self.lanes(&a, rt1(RtFn::Atan)),
            Exp => self.lanes(&a, rt1(RtFn::Exp)),
            Exp2 => self.lanes(&a, rt1(RtFn::Exp2)),
            Log => self.lanes(&a, rt1(RtFn::Log)),
            Log2 => self.lanes(&a, rt1(RtFn::Log2)),
            Round => self.lanes(&a, rt1(RtFn::Round)),
            Sqrt => self.lanes(&a, un(UnOp::Sqrt)),
            Abs => self.lanes(&a, un(UnOp::FAbs)),
            Floor => self.lanes(&a, un(UnOp::Floor)),
            Ceil => self.lanes(&a, un(UnOp::Ceil)),
            InverseSqrt => self.lanes(&a, |s, l| {
                let r = s.b.unary(UnOp::Sqrt, l[0]);
                let one = s.b.fconst(1.0);
                s.b.binary(BinOp::FDiv, one, r)
            }),
            Fract => self.lanes(&a, |s, l| {
                let f = s.b.unary(UnOp::Floor, l[0]);
                s.b.binary(BinOp::FSub, l[0], f)
            }),
            Sign => self.lanes(&a, |s, l| {
                let (zero, one, minus) = (s.b.fconst(0.0), s.b.fconst(1.0), s.b.fconst(-1.0));
                let pos = s.b.cmp(CmpOp::Gt, l[0], zero);
                let neg = s.b.cmp(CmpOp::Lt, l[0], zero);
                let lo = s.b.select(neg, minus, l[0]);
                s.b.select(pos, one, lo)
            }),
            Radians => self.lanes(&a, |s, l| {
                let k = s.b.fconst(std::f32::consts::PI / 180.0);
                s.b.binary(BinOp::FMul, l[0], k)
            }),
            Degrees => self.lanes(&a, |s, l| {
                let k = s.b.fconst(57.295_78_f32);
                s.b.binary(BinOp::FMul, l[0], k)
            }),
            Pow => self.lanes(&a, |s, l| s.b.call(RtFn::Pow, vec![l[0], l[1]])),
            Atan2 => self.lanes(&a, |s, l| s.b.call(RtFn::Atan2, vec![l[0], l[1]])),
            Min => self.lanes(&a, |s, l| s.b.binary(BinOp::FMin, l[0], l[1])),
            Max => self.lanes(&a, |s, l| s.b.binary(BinOp::FMax, l[0], l[1])),
            Mod => self.lanes(&a, |s, l| s.float_mod(l[0], l[1])),
            Step => self.lanes(&a, |s, l| {
                let (zero, one) = (s.b.fconst(0.0), s.b.fconst(1.0));
                let below = s.b.cmp(CmpOp::Lt, l[1], l[0]);
                s.b.select(below, zero, one)
            }),
            Clamp => self.lanes(&a, |s, l| {
                let lo = s.b.binary(BinOp::FMax, l[0], l[1]);
                s.b.binary(BinOp::FMin, lo, l[2])
            }),
            Smoothstep => self.lanes(&a, |s, l| s.smoothstep(l[0], l[1], l[2])),
            Mix => self.lanes(&a, |s, l| {
                let d = s.b.binary(BinOp::FSub, l[1], l[0]);
                let m = s.b.binary(BinOp::FMul, d, l[2]);
                s.b.binary(BinOp::FAdd, l[0], m)
            }),
            Dot => {
                let d = self.dot(&a[0], &a[1]);
                Lv::Scalars(vec![d])
            }
            Cross => {
                let (x, y) = (&a[0], &a[1]);
                let c = |s: &mut Self, i: usize, j: usize| {
                    let p = s.b.binary(BinOp::FMul, x[i], y[j]);
                    let q = s.b.binary(BinOp::FMul, x[j], y[i]);
                    s.b.binary(BinOp::FSub, p, q)
                };
                Lv::Scalars(vec![c(self, 1, 2), c(self, 2, 0), c(self, 0, 1)])
            }
            Length => {
                let d = self.dot(&a[0], &a[0]);
                Lv::Scalars(vec![self.b.unary(UnOp::Sqrt, d)])
            }
            Normalize => {
                let d = self.dot(&a[0], &a[0]);
                let len = self.b.unary(UnOp::Sqrt, d);
                let zero = self.b.fconst(0.0);
                let positive = self.b.cmp(CmpOp::Gt, len, zero);
                Lv::Scalars(
                    a[0].iter()
                        .map(|&c| {
                            let q = self.b.binary(BinOp::FDiv, c, len);
                            self.b.select(positive, q, zero)
                        })
                        .collect(),
                )
            }
            Distance => {
                let diff: Vec<ssa::Value> =
                    a[0].iter().zip(&a[1]).map(|(&p, &q)| self.b.binary(BinOp::FSub, p, q)).collect();
                let d = self.dot(&diff, &diff);
                Lv::Scalars(vec![self.b.unary(UnOp::Sqrt, d)])
            }
            Luminance => {
                let c = &a[0];
                let w = [0.2126_f32, 0.7152, 0.0722];
                let mut acc = None;
                for k in 0..3 {
                    let wk = self.b.fconst(w[k]);
                    let t = self.b.binary(BinOp::FMul, wk, c[k]);
                    acc = Some(match acc {
                        None => t,
                        Some(s) => self.b.binary(BinOp::FAdd, s, t),
                    });
                }
                Lv::Scalars(vec![acc.expect("three terms")])
            }
            Noise => Lv::Scalars(vec![self.b.call(RtFn::Noise, a[0].clone())]),
            Snoise => Lv::Scalars(vec![self.b.call(RtFn::Snoise, a[0].clone())]),
            Cellnoise => Lv::Scalars(vec![self.b.call(RtFn::Cellnoise, a[0].clone())]),
            Cellular => Lv::Scalars(vec![self.b.call(RtFn::Cellular, a[0].clone())]),
            Layer => self.closure_concat(&a[0], &a[1], true, at),
            WithNormal => self.closure_with_normal(&a[0], &a[1], at),
            WithThinFilm => {
                let film = [a[1][0], a[2][0], a[3][0]];
                self.closure_with_thin_film(&a[0], &film)
            }
            WithDarkening => self.closure_with_darkening(&a[0], &a[1]),
            WithAnisotropy => {
                let words = [a[1][0], a[1][1], a[1][2], a[2][0]];
                self.closure_with_anisotropy(&a[0], &words)
            }
            WithThinWalled => self.closure_with_thin_walled(&a[0], a[1][0]),
            DielectricBsdf => {
                // The scatter mode string becomes the lobe's last parameter: 0 R, 1 T, 2 RT.
                let Some(mode) = self.constant_string(&args[3], frame, "the scatter mode") else {
                    return self.lobe(abi::ClosureKind::None, &[]);
                };
                let Some(code) = ["R", "T", "RT"].iter().position(|m| *m == mode) else {
                    self.diags.push(
                        Diagnostic::error(format!("unknown scatter mode `{mode}`"))
                            .at(args[3].span, "expected \"R\", \"T\" or \"RT\""),
                    );
                    return self.lobe(abi::ClosureKind::None, &[]);
                };
                let mut params: Vec<ssa::Value> = a[..3].iter().flatten().copied().collect();
                params.push(self.b.fconst(code as f32));
                self.lobe(abi::ClosureKind::Dielectric, &params)
            }
            DiffuseBsdf
            | GlossyBsdf
            | MetalBsdf
            | GlassBsdf
            | ConductorBsdf
            | GeneralizedSchlickBsdf
            | OrenNayarDiffuseBsdf
            | BurleyDiffuseBsdf
            | SheenBsdf
            | TranslucentBsdf => {
                let kind = i.closure_kind().expect("a BSDF constructor");
                let params: Vec<ssa::Value> = a.iter().flatten().copied().collect();
                self.lobe(kind, &params)
            }
            Texture | TextureChannel | Primvar | PrimvarFloat | PrimvarVector | PrimvarAlpha => {
                unreachable!("handled above")
            }
        }
    }

    /// `x0*y0 + x1*y1 + x2*y2`, left to right (the folder's order).
    pub(super) fn dot(&mut self, x: &[ssa::Value], y: &[ssa::Value]) -> ssa::Value {
        let mut acc = self.b.binary(BinOp::FMul, x[0], y[0]);
        for k in 1..3 {
            let t = self.b.binary(BinOp::FMul, x[k], y[k]);
            acc = self.b.binary(BinOp::FAdd, acc, t);
        }
        acc
    }

    /// [`crate::runtime::math::smoothstep`], branch-free.
    pub(super) fn smoothstep(&mut self, e0: ssa::Value, e1: ssa::Value, x: ssa::Value) -> ssa::Value {
        let (zero, one, two, three) = (self.b.fconst(0.0), self.b.fconst(1.0), self.b.fconst(2.0), self.b.fconst(3.0));
        let num = self.b.binary(BinOp::FSub, x, e0);
        let den = self.b.binary(BinOp::FSub, e1, e0);
        let q = self.b.binary(BinOp::FDiv, num, den);
        let lo = self.b.binary(BinOp::FMax, q, zero);
        let t = self.b.binary(BinOp::FMin, lo, one);
        let tt = self.b.binary(BinOp::FMul, t, t);
        let t2 = self.b.binary(BinOp::FMul, two, t);
        let k = self.b.binary(BinOp::FSub, three, t2);
        let smooth = self.b.binary(BinOp::FMul, tt, k);
        let below = self.b.cmp(CmpOp::Lt, x, e0);
        let stepped = self.b.select(below, zero, one);
        let same = self.b.cmp(CmpOp::Eq, e1, e0);
        self.b.select(same, stepped, smooth)
    }

    /// A string argument that must be known when compiling (a literal or an input the scene
    /// sets), or `None` after reporting that it is not.
    pub(super) fn constant_string(&mut self, arg: &Expr, frame: &mut Frame, what: &str) -> Option<String> {
        let value = self.expr(arg, frame).one();
        let known = self.b.known(value).and_then(|id| self.strings.get(id as usize).cloned());
        if known.is_none() {
            self.diags.push(
                Diagnostic::error(format!("{what} must be a constant string (a literal or an input)"))
                    .at(arg.span, "not known when compiling"),
            );
        }
        known
    }

    /// `texture_channel(file, colour space, s, t, mode)`: like [`Self::texture`], one channel,
    /// with the file decoded in the given colour space (`auto`, `sRGB`, `raw`) and the wrap
    /// modes packed into `mode` (passed on to the runtime as it is).
    pub(super) fn texture_channel(&mut self, args: &[Expr], frame: &mut Frame) -> Lv {
        let file = self.constant_string(&args[0], frame, "texture_channel(): the file name");
        let space = self.constant_string(&args[1], frame, "texture_channel(): the colour space");
        let s = self.expr(&args[2], frame).one();
        let t = self.expr(&args[3], frame).one();
        let mode = self.expr(&args[4], frame).one();
        let space = match space.as_deref().map(|name| (name, texture::ColorSpace::parse(name))) {
            Some((_, Some(space))) => Some(space),
            Some((name, None)) => {
                self.diags.push(
                    Diagnostic::error(format!("unknown colour space `{name}`; expected `auto`, `sRGB` or `raw`"))
                        .at(args[1].span, "colour space named here"),
                );
                None
            }
            None => None,
        };
        let id = match (file, space) {
            (Some(f), Some(_)) if f.is_empty() => -1,
            (Some(f), Some(space)) => match texture::register_file_as(Path::new(&f), space) {
                Ok(id) => id,
                Err(msg) => {
                    self.diags.push(
                        Diagnostic::warning(msg)
                            .at(args[0].span, "texture file named here")
                            .note("the texture reads as black")
                            .kind("unreadable texture"),
                    );
                    -1
                }
            },
            _ => -1,
        };
        let id = self.b.iconst(id);
        let footprint = self.st_footprint();
        Lv::Scalars(vec![self.b.call(RtFn::TextureFiltered, [vec![id, s, t, mode], footprint].concat())])
    }

    /// The four words of `abi::Globals::st_footprint`: what texture lookups filter over.
    fn st_footprint(&mut self) -> Vec<ssa::Value> {
        (0..4).map(|k| self.b.value(Inst::Global(ssa::globals::ST_FOOTPRINT + k), Ty::F32)).collect()
    }

    /// `primvar*(name, fallback)`: the name must be known when compiling; it gets a place in
    /// the material's primvar table (`abi::MaterialInfo::primvars`, one per name and width,
    /// shared by every entry) and the call reads `present ? value : fallback` per component,
    /// the fallback's components from component `first` on (`primvar_alpha`: the fourth alone).
    pub(super) fn primvar(&mut self, args: &[Expr], frame: &mut Frame, first: usize) -> Lv {
        let name = self.constant_string(&args[0], frame, "the primvar name");
        let fallback = self.expr(&args[1], frame).scalars();
        let width = first + fallback.len();
        let Some(name) = name.filter(|n| !n.is_empty()) else { return Lv::Scalars(fallback) };
        let offset = match self.primvars.iter().find(|p| p.name == name && p.width == width) {
            Some(p) => p.offset,
            None => {
                let offset = self.primvars.iter().map(|p| p.offset + 1 + p.width).max().unwrap_or(0);
                self.primvars.push(PrimvarInfo { name, width, offset });
                offset
            }
        } as u32;
        let present = self.b.value(Inst::Primvar(offset), Ty::F32);
        let zero = self.b.fconst(0.0);
        let present = self.b.cmp(CmpOp::Ne, present, zero);
        Lv::Scalars(
            fallback
                .iter()
                .enumerate()
                .map(|(k, &otherwise)| {
                    let value = self.b.value(Inst::Primvar(offset + 1 + (first + k) as u32), Ty::F32);
                    self.b.select(present, value, otherwise)
                })
                .collect(),
        )
    }

    /// `texture(file, s, t)`: the file must be known when compiling (a literal or an input
    /// the scene sets); it is loaded now and the call reads the decoded image by id.
    pub(super) fn texture(&mut self, args: &[Expr], frame: &mut Frame) -> Lv {
        let name = self.expr(&args[0], frame).one();
        let file = self.b.known(name).and_then(|id| self.strings.get(id as usize).cloned());
        let s = self.expr(&args[1], frame).one();
        let t = self.expr(&args[2], frame).one();
        let id = match file {
            None => {
                self.diags.push(
                    Diagnostic::error("texture(): the file name must be a constant string (a literal or an input)")
                        .at(args[0].span, "not known when compiling"),
                );
                -1
            }
            Some(f) if f.is_empty() => -1, // no file: black, like an unconnected texture node
            Some(f) => match texture::register_file(Path::new(&f)) {
                Ok(id) => id,
                Err(msg) => {
                    self.diags.push(
                        Diagnostic::warning(msg)
                            .at(args[0].span, "texture file named here")
                            .note("the texture reads as black")
                            .kind("unreadable texture"),
                    );
                    -1
                }
            },
        };
        let id = self.b.iconst(id);
        let footprint = self.st_footprint();
        Lv::Scalars(
            (0..3)
                .map(|c| {
                    let c = self.b.iconst(c);
                    self.b.call(RtFn::TextureFiltered, [vec![id, s, t, c], footprint.clone()].concat())
                })
                .collect(),
        )
    }
}
