//! The runtime library's C ABI: the functions compiled shader code calls for what is not a
//! machine instruction. Each is `extern "C"`, pure, and wraps the same Rust function the
//! interpreter and the constant folder call, so every backend computes identical bits.
//!
//! The symbols are stable (`strata_rt_*`): JIT code links them by address, and native shader
//! objects written by `strata compile` import them by name from the runtime library.

use crate::{math, noise, texture};

macro_rules! runtime {
    ($($variant:ident = $sym:ident ($($arg:ident : $ty:ident),*) $body:block),* $(,)?) => {
        /// A runtime-library function callable from compiled code.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum RtFn {
            $(
                #[doc = concat!("`", stringify!($sym), "`")]
                $variant,
            )*
        }

        $(
            #[doc = concat!("C entry of [`RtFn::", stringify!($variant), "`].")]
            #[unsafe(no_mangle)]
            pub extern "C" fn $sym($($arg: $ty),*) -> f32 $body
        )*

        impl RtFn {
            /// Every runtime function.
            pub const ALL: &'static [RtFn] = &[$(RtFn::$variant),*];

            /// The exported symbol.
            pub fn symbol(self) -> &'static str {
                match self { $(RtFn::$variant => stringify!($sym)),* }
            }

            /// Its address, for the JIT's symbol table.
            pub fn address(self) -> *const u8 {
                match self { $(RtFn::$variant => $sym as *const u8),* }
            }

            /// Whether parameter `i` is an i32 (else f32).
            pub fn param_is_int(self, i: usize) -> bool {
                match self { $(RtFn::$variant => [$(stringify!($ty) == "i32"),*].get(i).copied().unwrap_or(false)),* }
            }

            /// Number of parameters.
            pub fn arity(self) -> usize {
                match self { $(RtFn::$variant => [$(stringify!($arg)),*].len()),* }
            }

            /// Calls it (the interpreter's path). `args` are raw 32-bit words.
            pub fn call(self, args: &[u32]) -> f32 {
                match self {
                    $(RtFn::$variant => {
                        let mut _it = args.iter().copied();
                        $(let $arg: $ty = FromWord::from_word(_it.next().unwrap_or(0));)*
                        $sym($($arg),*)
                    }),*
                }
            }
        }
    };
}

/// Decodes an argument word.
trait FromWord {
    fn from_word(w: u32) -> Self;
}
impl FromWord for f32 {
    fn from_word(w: u32) -> f32 {
        f32::from_bits(w)
    }
}
impl FromWord for i32 {
    fn from_word(w: u32) -> i32 {
        w as i32
    }
}

runtime! {
    Sin = strata_rt_sin(x: f32) { x.sin() },
    Cos = strata_rt_cos(x: f32) { x.cos() },
    Tan = strata_rt_tan(x: f32) { x.tan() },
    Asin = strata_rt_asin(x: f32) { x.asin() },
    Acos = strata_rt_acos(x: f32) { x.acos() },
    Atan = strata_rt_atan(x: f32) { x.atan() },
    Exp = strata_rt_exp(x: f32) { x.exp() },
    Exp2 = strata_rt_exp2(x: f32) { x.exp2() },
    Log = strata_rt_log(x: f32) { x.ln() },
    Log2 = strata_rt_log2(x: f32) { x.log2() },
    Round = strata_rt_round(x: f32) { math::round(x) },
    Pow = strata_rt_pow(x: f32, y: f32) { x.powf(y) },
    Atan2 = strata_rt_atan2(y: f32, x: f32) { y.atan2(x) },
    Noise = strata_rt_noise(x: f32, y: f32, z: f32) { noise::noise3(x, y, z) },
    Snoise = strata_rt_snoise(x: f32, y: f32, z: f32) { noise::snoise3(x, y, z) },
    Cellnoise = strata_rt_cellnoise(x: f32, y: f32, z: f32) { noise::cellnoise3(x, y, z) },
    Cellular = strata_rt_cellular(x: f32, y: f32, z: f32) { noise::cellular3(x, y, z) },
    Texture = strata_rt_texture(id: i32, s: f32, t: f32, mode: i32) { texture::lookup(id, s, t, mode) },
    TextureFiltered = strata_rt_texture_filtered(id: i32, s: f32, t: f32, mode: i32, dsdx: f32, dtdx: f32, dsdy: f32, dtdy: f32) {
        texture::lookup_filtered(id, s, t, mode, dsdx, dtdx, dsdy, dtdy)
    },
}
