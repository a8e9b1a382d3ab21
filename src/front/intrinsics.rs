//! Built-in functions of the shading language: their names, overload rules and result types.
//! What they compute lives in [`crate::runtime`] (shared by the interpreter, the constant
//! folder and JIT-compiled code).

use super::ast::BaseType;
use super::types::Type;

/// How an intrinsic's argument and result types relate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Signature {
    /// `T f(T)` for T = float or any triple (ints promote to float).
    Generic1,
    /// `T f(T, T)`; a float argument promotes to the other argument's triple type.
    Generic2,
    /// `T f(T, T, T)`.
    Generic3,
    /// `T mix(T a, T b, float|T t)`.
    Mix,
    /// Fixed parameter types and result.
    Fixed(&'static [Type], Type),
}

macro_rules! intrinsics {
    ($($variant:ident = $name:literal : $sig:expr),* $(,)?) => {
        /// A built-in function.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum Intrinsic {
            $(
                #[doc = concat!("`", $name, "`")]
                $variant,
            )*
        }

        impl Intrinsic {
            /// Every intrinsic.
            pub const ALL: &'static [Intrinsic] = &[$(Intrinsic::$variant),*];

            /// The source name.
            pub fn name(self) -> &'static str {
                match self { $(Intrinsic::$variant => $name),* }
            }

            /// The overload rule.
            pub fn signature(self) -> Signature {
                match self { $(Intrinsic::$variant => $sig),* }
            }
        }
    };
}

use Signature::*;
const F: Type = Type::FLOAT;
const C: Type = Type::COLOR;
const P: Type = Type::POINT;
const V: Type = Type::VECTOR;
const S: Type = Type::STRING;
const CL: Type = Type::CLOSURE;
const I: Type = Type::INT;

intrinsics! {
    Sin = "sin": Generic1,
    Cos = "cos": Generic1,
    Tan = "tan": Generic1,
    Asin = "asin": Generic1,
    Acos = "acos": Generic1,
    Atan = "atan": Generic1,
    Sqrt = "sqrt": Generic1,
    InverseSqrt = "inversesqrt": Generic1,
    Exp = "exp": Generic1,
    Exp2 = "exp2": Generic1,
    Log = "log": Generic1,
    Log2 = "log2": Generic1,
    Abs = "abs": Generic1,
    Floor = "floor": Generic1,
    Ceil = "ceil": Generic1,
    Round = "round": Generic1,
    Fract = "fract": Generic1,
    Sign = "sign": Generic1,
    Radians = "radians": Generic1,
    Degrees = "degrees": Generic1,
    Pow = "pow": Generic2,
    Atan2 = "atan2": Generic2,
    Min = "min": Generic2,
    Max = "max": Generic2,
    Mod = "mod": Generic2,
    Step = "step": Generic2,
    Clamp = "clamp": Generic3,
    Smoothstep = "smoothstep": Generic3,
    Mix = "mix": Mix,
    Dot = "dot": Fixed(&[V, V], F),
    Cross = "cross": Fixed(&[V, V], V),
    Length = "length": Fixed(&[V], F),
    Normalize = "normalize": Fixed(&[V], V),
    Distance = "distance": Fixed(&[P, P], F),
    Luminance = "luminance": Fixed(&[C], F),
    Noise = "noise": Fixed(&[P], F),
    Snoise = "snoise": Fixed(&[P], F),
    Cellnoise = "cellnoise": Fixed(&[P], F),
    Cellular = "cellular": Fixed(&[P], F),
    Texture = "texture": Fixed(&[S, F, F], C),
    // texture_channel(file, colour space, s, t, mode): one channel (mode % 16: r, g, b, a) with
    // wrap modes (mode / 16 % 16 along s, mode / 256 along t; see `strata_rt::texture`).
    TextureChannel = "texture_channel": Fixed(&[S, S, F, F, I], F),
    // primvar*(name, fallback): the shaded prim's primvar `name` at the shading point, or the
    // fallback where the prim has none; `name` must be known when compiling.
    Primvar = "primvar": Fixed(&[S, C], C),
    PrimvarFloat = "primvar_float": Fixed(&[S, F], F),
    PrimvarVector = "primvar_vector": Fixed(&[S, V], V),
    // primvar_alpha(name, fallback): the fourth component of a 4-component primvar (a color4's
    // alpha, a float4's w), or the fallback where the prim has none.
    PrimvarAlpha = "primvar_alpha": Fixed(&[S, F], F),
    DiffuseBsdf = "diffuse_bsdf": Fixed(&[C], CL),
    GlossyBsdf = "glossy_bsdf": Fixed(&[C, C, F, F], CL),
    MetalBsdf = "metal_bsdf": Fixed(&[C, C, F], CL),
    GlassBsdf = "glass_bsdf": Fixed(&[C, F, F], CL),
    // The MaterialX pbrlib lobes (README, "Closures"); `weight` inputs are `closure * w`.
    ConductorBsdf = "conductor_bsdf": Fixed(&[C, C, F], CL),
    // dielectric_bsdf(tint, ior, roughness, scatter_mode): scatter_mode "R", "T" or "RT",
    // known when compiling.
    DielectricBsdf = "dielectric_bsdf": Fixed(&[C, F, F, S], CL),
    GeneralizedSchlickBsdf = "generalized_schlick_bsdf": Fixed(&[C, C, C, F, F], CL),
    OrenNayarDiffuseBsdf = "oren_nayar_diffuse_bsdf": Fixed(&[C, F, F], CL),
    BurleyDiffuseBsdf = "burley_diffuse_bsdf": Fixed(&[C, F], CL),
    SheenBsdf = "sheen_bsdf": Fixed(&[C, F], CL),
    TranslucentBsdf = "translucent_bsdf": Fixed(&[C], CL),
    // layer(top, base): `top` over `base`, energy-conserving (the renderer's layering mode).
    Layer = "layer": Fixed(&[CL, CL], CL),
    // with_normal(c, n): every term of `c` shaded about its own world-space normal `n` (zero:
    // the layer's shading normal); generalized_schlick_bsdf terms have no room for one.
    WithNormal = "with_normal": Fixed(&[CL, V], CL),
    // with_thin_film(c, thickness_nm, ior, weight): a thin film on every dielectric, metal,
    // conductor and generalized Schlick term of `c` (Airy interference in its reflection's
    // Fresnel, mixed in by `weight`; thickness or weight 0: none).
    WithThinFilm = "with_thin_film": Fixed(&[CL, F, F, F], CL),
    // with_darkening(coat, factor): records on every dielectric_bsdf term of `coat` that the
    // terms under it were multiplied by `factor` for the coat's internal reflections (OpenPBR's
    // coat_darkening), so the random-walk layering, which simulates them, divides it back out.
    WithDarkening = "with_darkening": Fixed(&[CL, C], CL),
    // with_anisotropy(c, tangent, aspect): every term of `c` stretched along its own
    // world-space `tangent` (zero: the shading frame's) with GGX widths α·aspect along it and
    // α / aspect across (α the term's mean width; aspect 1: isotropic). Lobes that are not
    // GGX ignore it.
    WithAnisotropy = "with_anisotropy": Fixed(&[CL, V, F], CL),
    // with_thin_walled(c, thin): where `thin` is not 0, every transmitting dielectric_bsdf term
    // of `c` ("T", "RT") is a thin-walled sheet: no interior, the sheet's inter-reflected
    // reflectance, transmission straight through (OpenPBR geometry_thin_walled).
    WithThinWalled = "with_thin_walled": Fixed(&[CL, F], CL),
}

impl Intrinsic {
    /// Looks an intrinsic up by name.
    pub fn from_name(name: &str) -> Option<Intrinsic> {
        Intrinsic::ALL.iter().copied().find(|i| i.name() == name)
    }

    /// Whether the result depends on something other than the arguments (files on disk, the
    /// shaded prim's primvars), so it must not be folded at compile time.
    pub fn is_varying(self) -> bool {
        matches!(
            self,
            Intrinsic::Texture
                | Intrinsic::TextureChannel
                | Intrinsic::Primvar
                | Intrinsic::PrimvarFloat
                | Intrinsic::PrimvarVector
                | Intrinsic::PrimvarAlpha
        )
    }

    /// Whether this builds or combines BSDF closures.
    pub fn is_closure(self) -> bool {
        self.closure_kind().is_some()
            || matches!(
                self,
                Intrinsic::Layer
                    | Intrinsic::WithNormal
                    | Intrinsic::WithThinFilm
                    | Intrinsic::WithDarkening
                    | Intrinsic::WithAnisotropy
                    | Intrinsic::WithThinWalled
            )
    }

    /// The lobe a BSDF constructor builds (its arguments, flattened, are the lobe's
    /// parameters in order; see [`crate::abi::ClosureKind`]).
    pub fn closure_kind(self) -> Option<crate::abi::ClosureKind> {
        use crate::abi::ClosureKind as K;
        Some(match self {
            Intrinsic::DiffuseBsdf => K::Diffuse,
            Intrinsic::GlossyBsdf => K::Glossy,
            Intrinsic::MetalBsdf => K::Metal,
            Intrinsic::GlassBsdf => K::Glass,
            Intrinsic::ConductorBsdf => K::Conductor,
            Intrinsic::DielectricBsdf => K::Dielectric,
            Intrinsic::GeneralizedSchlickBsdf => K::GeneralizedSchlick,
            Intrinsic::OrenNayarDiffuseBsdf => K::OrenNayar,
            Intrinsic::BurleyDiffuseBsdf => K::Burley,
            Intrinsic::SheenBsdf => K::Sheen,
            Intrinsic::TranslucentBsdf => K::Translucent,
            _ => return None,
        })
    }

    /// Resolves the parameter types and result type for the given argument types, or explains
    /// why the call does not type-check.
    pub fn resolve(self, args: &[Type]) -> Result<(Vec<Type>, Type), String> {
        let arity = match self.signature() {
            Generic1 => 1,
            Generic2 => 2,
            Generic3 | Mix => 3,
            Fixed(params, _) => params.len(),
        };
        if args.len() != arity {
            return Err(format!("`{}` takes {arity} argument(s), found {}", self.name(), args.len()));
        }
        match self.signature() {
            Fixed(params, ret) => {
                for (i, (&arg, &param)) in args.iter().zip(params).enumerate() {
                    if !arg.converts_to(param) {
                        return Err(format!("argument {} of `{}` must be {param}, found {arg}", i + 1, self.name()));
                    }
                }
                Ok((params.to_vec(), ret))
            }
            Generic1 | Generic2 | Generic3 => {
                let common = common_generic(args).ok_or_else(|| self.generic_error(args))?;
                Ok((vec![common; arity], common))
            }
            Mix if args[..2].iter().any(|a| a.base == BaseType::Closure) => {
                // mix(a, b, t) of closures: a·(1 − t) + b·t, t a float or colour.
                if args[0] != Type::CLOSURE || args[1] != Type::CLOSURE {
                    return Err(self.generic_error(args));
                }
                let t = if args[2].converts_to(Type::FLOAT) {
                    Type::FLOAT
                } else if args[2].converts_to(Type::COLOR) {
                    Type::COLOR
                } else {
                    return Err(self.generic_error(args));
                };
                Ok((vec![Type::CLOSURE, Type::CLOSURE, t], Type::CLOSURE))
            }
            Mix => {
                let common = common_generic(&args[..2]).ok_or_else(|| self.generic_error(args))?;
                let t = if args[2].converts_to(Type::FLOAT) {
                    Type::FLOAT
                } else if args[2].converts_to(common) {
                    common
                } else {
                    return Err(self.generic_error(args));
                };
                Ok((vec![common, common, t], common))
            }
        }
    }

    fn generic_error(self, args: &[Type]) -> String {
        let found: Vec<String> = args.iter().map(|t| t.to_string()).collect();
        let what = if self == Intrinsic::Mix {
            "float or triple arguments of one type, or two closures and a float or colour"
        } else {
            "float or triple arguments of one type"
        };
        format!("`{}` takes {what}, found ({})", self.name(), found.join(", "))
    }
}

/// The common type of generic arguments: float, or the one triple type they share.
fn common_generic(args: &[Type]) -> Option<Type> {
    let mut common = Type::FLOAT;
    for &arg in args {
        if arg.array.is_some() {
            return None;
        }
        match arg.base {
            BaseType::Int | BaseType::Float => {}
            _ if arg.is_triple() => {
                if common == Type::FLOAT {
                    common = arg;
                } else if common != arg {
                    if common.is_spatial() && arg.is_spatial() {
                        common = Type::VECTOR;
                    } else {
                        return None;
                    }
                }
            }
            _ => return None,
        }
    }
    Some(common)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generic_promotion() {
        let (params, ret) = Intrinsic::Mix.resolve(&[Type::COLOR, Type::FLOAT, Type::FLOAT]).unwrap();
        assert_eq!(params, vec![Type::COLOR, Type::COLOR, Type::FLOAT]);
        assert_eq!(ret, Type::COLOR);
        assert!(Intrinsic::Min.resolve(&[Type::COLOR, Type::POINT]).is_err());
        assert_eq!(Intrinsic::Sin.resolve(&[Type::INT]).unwrap().1, Type::FLOAT);
        assert!(Intrinsic::Dot.resolve(&[Type::COLOR, Type::VECTOR]).is_err());
        assert!(Intrinsic::Noise.resolve(&[Type::FLOAT]).is_ok());
    }
}
