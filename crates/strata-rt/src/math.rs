//! Scalar semantics of the shading language's operators and intrinsics, defined once.
//! Integer division and remainder by zero give 0 instead of trapping, so shader code can never
//! bring the renderer down.

/// `a / b` on ints: 0 when `b` is 0; wraps on `i32::MIN / -1`.
pub fn int_div(a: i32, b: i32) -> i32 {
    if b == 0 { 0 } else { a.wrapping_div(b) }
}

/// `a % b` on ints: 0 when `b` is 0; sign of `a` (C semantics).
pub fn int_rem(a: i32, b: i32) -> i32 {
    if b == 0 { 0 } else { a.wrapping_rem(b) }
}

/// `float % float` and `mod()`: `a - b * floor(a / b)` (GLSL/OSL), so the result has the sign of `b`.
pub fn float_mod(a: f32, b: f32) -> f32 {
    if b == 0.0 { 0.0 } else { a - b * (a / b).floor() }
}

/// float → int conversion: truncates toward zero, saturates, NaN gives 0.
pub fn float_to_int(x: f32) -> i32 {
    // Rust's `as` already saturates and maps NaN to 0; the JIT uses the saturating instruction too.
    x as i32
}

/// `sign(x)`: -1, 0 or 1 (NaN stays NaN).
pub fn sign(x: f32) -> f32 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        x
    }
}

/// `smoothstep(e0, e1, x)`.
pub fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    if e1 == e0 {
        return if x < e0 { 0.0 } else { 1.0 };
    }
    let t = clamp((x - e0) / (e1 - e0), 0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// `step(edge, x)`: 0 below the edge, 1 at or above it.
pub fn step(edge: f32, x: f32) -> f32 {
    if x < edge { 0.0 } else { 1.0 }
}

/// `clamp(x, lo, hi)` = `min(max(x, lo), hi)`: never panics (`f32::clamp` asserts `lo <= hi`)
/// and maps NaN to `lo`.
pub fn clamp(x: f32, lo: f32, hi: f32) -> f32 {
    min(max(x, lo), hi)
}

/// `min` with IEEE minNum semantics (a NaN operand yields the other operand). Spelled out as a
/// compare and select, not `f32::min`, because code generation emits exactly this sequence and
/// the backends must agree bit for bit, signed zeros included.
pub fn min(a: f32, b: f32) -> f32 {
    if a <= b || b.is_nan() { a } else { b }
}

/// `max` with IEEE maxNum semantics; the same compare-and-select shape as [`min`].
pub fn max(a: f32, b: f32) -> f32 {
    if a >= b || b.is_nan() { a } else { b }
}

/// `fract(x)`: `x - floor(x)`.
pub fn fract(x: f32) -> f32 {
    x - x.floor()
}

/// `round(x)`: half away from zero.
pub fn round(x: f32) -> f32 {
    x.round()
}

/// `inversesqrt(x)`.
pub fn inversesqrt(x: f32) -> f32 {
    1.0 / x.sqrt()
}

/// Rec. 709 luminance of a linear colour.
pub fn luminance(r: f32, g: f32, b: f32) -> f32 {
    0.2126 * r + 0.7152 * g + 0.0722 * b
}
