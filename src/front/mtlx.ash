// ---- MaterialX standard library (https://materialx.org/Specification.html) -----------------
// The nodes of MaterialX networks that `compose::mtlx` instantiates for `ND_<node>_<type>`
// shaders, written from the MaterialX specification. Each node has a float variant
// (`mx_<node>_float`) and a triple variant (`mx_<node>_color3`) that serves color3, vector3
// and vector2 (a vector2 travels with z = 0) and the `FA` variants (a float promotes to a
// triple). Input names follow MaterialX (`in` is `in_`: `in` is reserved here).

float mx_fmod(float a, float b) {
    return b != 0.0 ? a - b * floor(a / b) : 0.0;
}

// ---- math (float and triple variants; vector2 travels as a triple with z = 0) ----

shader mx_add_float(float in1 = 0.0, float in2 = 0.0, output float out) { out = in1 + in2; }
shader mx_add_color3(color in1 = color(0.0), color in2 = color(0.0), output color out) { out = in1 + in2; }
shader mx_subtract_float(float in1 = 0.0, float in2 = 0.0, output float out) { out = in1 - in2; }
shader mx_subtract_color3(color in1 = color(0.0), color in2 = color(0.0), output color out) { out = in1 - in2; }
shader mx_multiply_float(float in1 = 0.0, float in2 = 1.0, output float out) { out = in1 * in2; }
shader mx_multiply_color3(color in1 = color(0.0), color in2 = color(1.0), output color out) { out = in1 * in2; }
shader mx_divide_float(float in1 = 0.0, float in2 = 1.0, output float out) { out = in2 != 0.0 ? in1 / in2 : 0.0; }
shader mx_divide_color3(color in1 = color(0.0), color in2 = color(1.0), output color out) { out = color(in2.r != 0.0 ? in1.r / in2.r : 0.0, in2.g != 0.0 ? in1.g / in2.g : 0.0, in2.b != 0.0 ? in1.b / in2.b : 0.0); }
shader mx_modulo_float(float in1 = 0.0, float in2 = 1.0, output float out) { out = mx_fmod(in1, in2); }
shader mx_modulo_color3(color in1 = color(0.0), color in2 = color(1.0), output color out) { out = color(mx_fmod(in1.r, in2.r), mx_fmod(in1.g, in2.g), mx_fmod(in1.b, in2.b)); }
shader mx_power_float(float in1 = 0.0, float in2 = 1.0, output float out) { out = pow(in1, in2); }
shader mx_power_color3(color in1 = color(0.0), color in2 = color(1.0), output color out) { out = color(pow(in1.r, in2.r), pow(in1.g, in2.g), pow(in1.b, in2.b)); }
shader mx_min_float(float in1 = 0.0, float in2 = 0.0, output float out) { out = min(in1, in2); }
shader mx_min_color3(color in1 = color(0.0), color in2 = color(0.0), output color out) { out = min(in1, in2); }
shader mx_max_float(float in1 = 0.0, float in2 = 0.0, output float out) { out = max(in1, in2); }
shader mx_max_color3(color in1 = color(0.0), color in2 = color(0.0), output color out) { out = max(in1, in2); }
shader mx_absval_float(float in_ = 0.0, output float out) { out = abs(in_); }
shader mx_absval_color3(color in_ = color(0.0), output color out) { out = color(abs(in_.r), abs(in_.g), abs(in_.b)); }
shader mx_sign_float(float in_ = 0.0, output float out) { out = sign(in_); }
shader mx_sign_color3(color in_ = color(0.0), output color out) { out = color(sign(in_.r), sign(in_.g), sign(in_.b)); }
shader mx_floor_float(float in_ = 0.0, output float out) { out = floor(in_); }
shader mx_floor_color3(color in_ = color(0.0), output color out) { out = color(floor(in_.r), floor(in_.g), floor(in_.b)); }
shader mx_ceil_float(float in_ = 0.0, output float out) { out = ceil(in_); }
shader mx_ceil_color3(color in_ = color(0.0), output color out) { out = color(ceil(in_.r), ceil(in_.g), ceil(in_.b)); }
shader mx_round_float(float in_ = 0.0, output float out) { out = round(in_); }
shader mx_round_color3(color in_ = color(0.0), output color out) { out = color(round(in_.r), round(in_.g), round(in_.b)); }
shader mx_sqrt_float(float in_ = 0.0, output float out) { out = sqrt(max(in_, 0.0)); }
shader mx_sqrt_color3(color in_ = color(0.0), output color out) { out = color(sqrt(max(in_.r, 0.0)), sqrt(max(in_.g, 0.0)), sqrt(max(in_.b, 0.0))); }
shader mx_exp_float(float in_ = 0.0, output float out) { out = exp(in_); }
shader mx_exp_color3(color in_ = color(0.0), output color out) { out = color(exp(in_.r), exp(in_.g), exp(in_.b)); }
shader mx_ln_float(float in_ = 0.0, output float out) { out = in_ > 0.0 ? log(in_) : 0.0; }
shader mx_ln_color3(color in_ = color(0.0), output color out) { out = color(in_.r > 0.0 ? log(in_.r) : 0.0, in_.g > 0.0 ? log(in_.g) : 0.0, in_.b > 0.0 ? log(in_.b) : 0.0); }
shader mx_sin_float(float in_ = 0.0, output float out) { out = sin(in_); }
shader mx_sin_color3(color in_ = color(0.0), output color out) { out = color(sin(in_.r), sin(in_.g), sin(in_.b)); }
shader mx_cos_float(float in_ = 0.0, output float out) { out = cos(in_); }
shader mx_cos_color3(color in_ = color(0.0), output color out) { out = color(cos(in_.r), cos(in_.g), cos(in_.b)); }
shader mx_tan_float(float in_ = 0.0, output float out) { out = tan(in_); }
shader mx_tan_color3(color in_ = color(0.0), output color out) { out = color(tan(in_.r), tan(in_.g), tan(in_.b)); }
shader mx_asin_float(float in_ = 0.0, output float out) { out = asin(clamp(in_, -1.0, 1.0)); }
shader mx_asin_color3(color in_ = color(0.0), output color out) {
    out = color(asin(clamp(in_.r, -1.0, 1.0)), asin(clamp(in_.g, -1.0, 1.0)), asin(clamp(in_.b, -1.0, 1.0)));
}
shader mx_acos_float(float in_ = 0.0, output float out) { out = acos(clamp(in_, -1.0, 1.0)); }
shader mx_acos_color3(color in_ = color(0.0), output color out) {
    out = color(acos(clamp(in_.r, -1.0, 1.0)), acos(clamp(in_.g, -1.0, 1.0)), acos(clamp(in_.b, -1.0, 1.0)));
}
shader mx_atan2_float(float iny = 0.0, float inx = 1.0, output float out) { out = atan2(iny, inx); }
shader mx_atan2_color3(color iny = color(0.0), color inx = color(1.0), output color out) {
    out = color(atan2(iny.r, inx.r), atan2(iny.g, inx.g), atan2(iny.b, inx.b));
}
shader mx_fract_float(float in_ = 0.0, output float out) { out = in_ - floor(in_); }
shader mx_fract_color3(color in_ = color(0.0), output color out) { out = in_ - color(floor(in_.r), floor(in_.g), floor(in_.b)); }
// safepower: sign(in1) · |in1|^in2 (no NaN for a negative base).
float mx_safepower1(float a, float b) { return sign(a) * pow(abs(a), b); }
shader mx_safepower_float(float in1 = 0.0, float in2 = 1.0, output float out) { out = mx_safepower1(in1, in2); }
shader mx_safepower_color3(color in1 = color(0.0), color in2 = color(1.0), output color out) {
    out = color(mx_safepower1(in1.r, in2.r), mx_safepower1(in1.g, in2.g), mx_safepower1(in1.b, in2.b));
}

shader mx_clamp_float(float in_ = 0.0, float low = 0.0, float high = 1.0, output float out) { out = min(max(in_, low), high); }
shader mx_clamp_color3(color in_ = color(0.0), color low = color(0.0), color high = color(1.0), output color out) {
    out = color(min(max(in_.r, low.r), high.r), min(max(in_.g, low.g), high.g), min(max(in_.b, low.b), high.b));
}
shader mx_invert_float(float in_ = 0.0, float amount = 1.0, output float out) { out = amount - in_; }
shader mx_invert_color3(color in_ = color(0.0), color amount = color(1.0), output color out) { out = amount - in_; }
shader mx_dotproduct_color3(color in1 = color(0.0), color in2 = color(0.0), output float out) {
    out = in1.r * in2.r + in1.g * in2.g + in1.b * in2.b;
}
shader mx_crossproduct_color3(color in1 = color(0.0), color in2 = color(0.0), output color out) {
    out = color(cross(vector(in1), vector(in2)));
}
shader mx_distance_color3(color in1 = color(0.0), color in2 = color(0.0), output float out) {
    out = length(vector(in1) - vector(in2));
}
// rotate2d: `amount` degrees about the origin, in the sense of MaterialX's reference shaders
// ((x, y) → (x cos a + y sin a, −x sin a + y cos a)).
color mx_rotate2(color p, float degrees_) {
    float a = radians(degrees_);
    return color(cos(a) * p.r + sin(a) * p.g, -sin(a) * p.r + cos(a) * p.g, 0.0);
}
shader mx_rotate2d_color3(color in_ = color(0.0), float amount = 0.0, output color out) { out = mx_rotate2(in_, amount); }
// place2d: about `pivot`, scale (divide), rotate and offset (subtract) in that order
// (operationorder 0), or offset, rotate and scale (1).
shader mx_place2d_color3(color texcoord = color(0.0), color pivot = color(0.0), color scale = color(1.0, 1.0, 0.0),
                         float rotate = 0.0, color offset = color(0.0), int operationorder = 0, output color out) {
    color p = texcoord - pivot;
    float sx = scale.r != 0.0 ? scale.r : 1.0;
    float sy = scale.g != 0.0 ? scale.g : 1.0;
    color srt = mx_rotate2(color(p.r / sx, p.g / sy, 0.0), rotate) - offset + pivot;
    color turned = mx_rotate2(p - offset, rotate);
    color trs = color(turned.r / sx, turned.g / sy, 0.0) + pivot;
    out = operationorder == 0 ? color(srt.r, srt.g, 0.0) : color(trs.r, trs.g, 0.0);
}
shader mx_magnitude_color3(color in_ = color(0.0), output float out) { out = length(vector(in_)); }
shader mx_normalize_color3(color in_ = color(0.0), output color out) {
    out = length(vector(in_)) > 0.0 ? color(normalize(vector(in_))) : color(0.0);
}

// remap: in from [inlow, inhigh] to [outlow, outhigh], not clamped (as the specification).
float mx_remap1(float x, float inlow, float inhigh, float outlow, float outhigh) {
    return inhigh != inlow ? outlow + (x - inlow) * (outhigh - outlow) / (inhigh - inlow) : outlow;
}
shader mx_remap_float(float in_ = 0.0, float inlow = 0.0, float inhigh = 1.0, float outlow = 0.0, float outhigh = 1.0,
                      output float out) {
    out = mx_remap1(in_, inlow, inhigh, outlow, outhigh);
}
shader mx_remap_color3(color in_ = color(0.0), color inlow = color(0.0), color inhigh = color(1.0), color outlow = color(0.0),
                       color outhigh = color(1.0), output color out) {
    out = color(mx_remap1(in_.r, inlow.r, inhigh.r, outlow.r, outhigh.r), mx_remap1(in_.g, inlow.g, inhigh.g, outlow.g, outhigh.g),
                mx_remap1(in_.b, inlow.b, inhigh.b, outlow.b, outhigh.b));
}
// smoothstep: 0 below low, 1 above high, Hermite between; a step at low when high <= low.
float mx_smoothstep1(float x, float low, float high) {
    return high > low ? smoothstep(low, high, x) : (x >= low ? 1.0 : 0.0);
}
shader mx_smoothstep_float(float in_ = 0.0, float low = 0.0, float high = 1.0, output float out) {
    out = mx_smoothstep1(in_, low, high);
}
shader mx_smoothstep_color3(color in_ = color(0.0), color low = color(0.0), color high = color(1.0), output color out) {
    out = color(mx_smoothstep1(in_.r, low.r, high.r), mx_smoothstep1(in_.g, low.g, high.g), mx_smoothstep1(in_.b, low.b, high.b));
}
shader mx_luminance_color3(color in_ = color(0.0), color lumacoeffs = color(0.2722287, 0.6740818, 0.0536895), output color out) {
    out = color(in_.r * lumacoeffs.r + in_.g * lumacoeffs.g + in_.b * lumacoeffs.b);
}

// ---- compositing: mix(bg, fg, mix) = fg · mix + bg · (1 − mix), per channel -----------------

shader mx_mix_float(float fg = 0.0, float bg = 0.0, float mix = 0.0, output float out) { out = fg * mix + bg * (1.0 - mix); }
shader mx_mix_color3(color fg = color(0.0), color bg = color(0.0), color mix = color(0.0), output color out) {
    out = fg * mix + bg * (color(1.0) - mix);
}
shader mx_plus_float(float fg = 0.0, float bg = 0.0, float mix = 1.0, output float out) { out = mix * (fg + bg) + (1.0 - mix) * bg; }
shader mx_plus_color3(color fg = color(0.0), color bg = color(0.0), float mix = 1.0, output color out) {
    out = mix * (fg + bg) + (1.0 - mix) * bg;
}
shader mx_minus_float(float fg = 0.0, float bg = 0.0, float mix = 1.0, output float out) { out = mix * (bg - fg) + (1.0 - mix) * bg; }
shader mx_minus_color3(color fg = color(0.0), color bg = color(0.0), float mix = 1.0, output color out) {
    out = mix * (bg - fg) + (1.0 - mix) * bg;
}
shader mx_difference_float(float fg = 0.0, float bg = 0.0, float mix = 1.0, output float out) {
    out = mix * abs(bg - fg) + (1.0 - mix) * bg;
}
shader mx_difference_color3(color fg = color(0.0), color bg = color(0.0), float mix = 1.0, output color out) {
    out = mix * abs(bg - fg) + (1.0 - mix) * bg;
}
shader mx_screen_float(float fg = 0.0, float bg = 0.0, float mix = 1.0, output float out) {
    out = mix * (1.0 - (1.0 - fg) * (1.0 - bg)) + (1.0 - mix) * bg;
}
shader mx_screen_color3(color fg = color(0.0), color bg = color(0.0), float mix = 1.0, output color out) {
    out = mix * (color(1.0) - (color(1.0) - fg) * (color(1.0) - bg)) + (1.0 - mix) * bg;
}

// burn 1 − (1 − bg) / fg and dodge bg / (1 − fg), 0 where they divide by 0 (as MaterialX's
// reference shaders), mixed over bg by `mix`.
float mx_burn1(float fg, float bg, float m) { return abs(fg) < 1e-8 ? 0.0 : m * (1.0 - (1.0 - bg) / fg) + (1.0 - m) * bg; }
float mx_dodge1(float fg, float bg, float m) { return abs(1.0 - fg) < 1e-8 ? 0.0 : m * (bg / (1.0 - fg)) + (1.0 - m) * bg; }
shader mx_burn_float(float fg = 0.0, float bg = 0.0, float mix = 1.0, output float out) { out = mx_burn1(fg, bg, mix); }
shader mx_burn_color3(color fg = color(0.0), color bg = color(0.0), float mix = 1.0, output color out) {
    out = color(mx_burn1(fg.r, bg.r, mix), mx_burn1(fg.g, bg.g, mix), mx_burn1(fg.b, bg.b, mix));
}
shader mx_dodge_float(float fg = 0.0, float bg = 0.0, float mix = 1.0, output float out) { out = mx_dodge1(fg, bg, mix); }
shader mx_dodge_color3(color fg = color(0.0), color bg = color(0.0), float mix = 1.0, output color out) {
    out = color(mx_dodge1(fg.r, bg.r, mix), mx_dodge1(fg.g, bg.g, mix), mx_dodge1(fg.b, bg.b, mix));
}
shader mx_inside_float(float in_ = 0.0, float mask = 1.0, output float out) { out = in_ * mask; }
shader mx_inside_color3(color in_ = color(0.0), float mask = 1.0, output color out) { out = in_ * mask; }
shader mx_outside_float(float in_ = 0.0, float mask = 0.0, output float out) { out = in_ * (1.0 - mask); }
shader mx_outside_color3(color in_ = color(0.0), float mask = 0.0, output color out) { out = in_ * (1.0 - mask); }

// ---- conditionals ------------------------------------------------------------------------------

shader mx_ifgreater_float(float value1 = 1.0, float value2 = 0.0, float in1 = 0.0, float in2 = 0.0, output float out) {
    out = value1 > value2 ? in1 : in2;
}
shader mx_ifgreater_color3(float value1 = 1.0, float value2 = 0.0, color in1 = color(0.0), color in2 = color(0.0), output color out) {
    out = value1 > value2 ? in1 : in2;
}
shader mx_ifgreatereq_float(float value1 = 1.0, float value2 = 0.0, float in1 = 0.0, float in2 = 0.0, output float out) {
    out = value1 >= value2 ? in1 : in2;
}
shader mx_ifgreatereq_color3(float value1 = 1.0, float value2 = 0.0, color in1 = color(0.0), color in2 = color(0.0), output color out) {
    out = value1 >= value2 ? in1 : in2;
}
shader mx_ifequal_float(float value1 = 0.0, float value2 = 0.0, float in1 = 0.0, float in2 = 0.0, output float out) {
    out = value1 == value2 ? in1 : in2;
}
shader mx_ifequal_color3(float value1 = 0.0, float value2 = 0.0, color in1 = color(0.0), color in2 = color(0.0), output color out) {
    out = value1 == value2 ? in1 : in2;
}
// switch: input floor(which) + 1, clamped to in1..in10 (MaterialX 1.39 has ten inputs; a
// `which` below 0 reads in1, one of 9 or more in10). The float `which` is floored; the
// integer-selected variants (`…I`, mtlx_stdlib.ash) take it as it is.
float mx_pick_float(int w, float a1, float a2, float a3, float a4, float a5, float a6, float a7, float a8, float a9,
                    float a10) {
    return w <= 0 ? a1 : (w == 1 ? a2 : (w == 2 ? a3 : (w == 3 ? a4 : (w == 4 ? a5 : (w == 5 ? a6
           : (w == 6 ? a7 : (w == 7 ? a8 : (w == 8 ? a9 : a10))))))));
}
color mx_pick_color(int w, color a1, color a2, color a3, color a4, color a5, color a6, color a7, color a8, color a9,
                    color a10) {
    return w <= 0 ? a1 : (w == 1 ? a2 : (w == 2 ? a3 : (w == 3 ? a4 : (w == 4 ? a5 : (w == 5 ? a6
           : (w == 6 ? a7 : (w == 7 ? a8 : (w == 8 ? a9 : a10))))))));
}
shader mx_switch_float(float in1 = 0.0, float in2 = 0.0, float in3 = 0.0, float in4 = 0.0, float in5 = 0.0, float in6 = 0.0,
                       float in7 = 0.0, float in8 = 0.0, float in9 = 0.0, float in10 = 0.0, float which = 0.0,
                       output float out) {
    out = mx_pick_float(int(floor(which)), in1, in2, in3, in4, in5, in6, in7, in8, in9, in10);
}
shader mx_switch_color3(color in1 = color(0.0), color in2 = color(0.0), color in3 = color(0.0), color in4 = color(0.0),
                        color in5 = color(0.0), color in6 = color(0.0), color in7 = color(0.0), color in8 = color(0.0),
                        color in9 = color(0.0), color in10 = color(0.0), float which = 0.0, output color out) {
    out = mx_pick_color(int(floor(which)), in1, in2, in3, in4, in5, in6, in7, in8, in9, in10);
}

// ---- channels ----------------------------------------------------------------------------------

shader mx_extract_color3(color in_ = color(0.0), int index = 0, output float out) {
    out = index <= 0 ? in_.r : (index == 1 ? in_.g : in_.b);
}
shader mx_combine2_float(float in1 = 0.0, float in2 = 0.0, output color out) { out = color(in1, in2, 0.0); }
shader mx_combine3_float(float in1 = 0.0, float in2 = 0.0, float in3 = 0.0, output color out) { out = color(in1, in2, in3); }
shader mx_separate2_color3(color in_ = color(0.0), output float outx, output float outy) {
    outx = in_.r;
    outy = in_.g;
}
shader mx_separate3_color3(color in_ = color(0.0), output float outr, output float outg, output float outb, output float outx,
                           output float outy, output float outz) {
    outr = in_.r;
    outg = in_.g;
    outb = in_.b;
    outx = in_.r;
    outy = in_.g;
    outz = in_.b;
}
shader mx_convert_float_color3(float in_ = 0.0, output color out) { out = color(in_); }
shader mx_convert_color3_color3(color in_ = color(0.0), output color out) { out = in_; }
shader mx_convert_color3_vector2(color in_ = color(0.0), output color out) { out = color(in_.r, in_.g, 0.0); }
shader mx_constant_float(float value = 0.0, output float out) { out = value; }
shader mx_constant_color3(color value = color(0.0), output color out) { out = value; }
shader mx_dot_float(float in_ = 0.0, output float out) { out = in_; }
shader mx_dot_color3(color in_ = color(0.0), output color out) { out = in_; }

// ---- geometry: MaterialX's spaces. Object space (and model, read as object) is the prim's own.
// `position` there is the mesh's own points blended at the hit (`strata:Pobject`), elsewhere the
// world point carried back by the prim's world-to-object transform; normal, tangent, bitangent
// and the space transforms (mtlx_stdlib.ash) carry world-space values by the transforms the
// integrator gives the hit: `strata:objectToWorld0..3` and `strata:worldToObject0..3`, their
// columns (axes, then translation; render::geometry::primvars::OBJECT_TO_WORLD). Where nothing
// fills them they read the identity: object space is then world space.

vector mx_object_to_world_vector(vector d) {
    return primvar_vector("strata:objectToWorld0", vector(1, 0, 0)) * d.x
        + primvar_vector("strata:objectToWorld1", vector(0, 1, 0)) * d.y
        + primvar_vector("strata:objectToWorld2", vector(0, 0, 1)) * d.z;
}
vector mx_world_to_object_vector(vector d) {
    return primvar_vector("strata:worldToObject0", vector(1, 0, 0)) * d.x
        + primvar_vector("strata:worldToObject1", vector(0, 1, 0)) * d.y
        + primvar_vector("strata:worldToObject2", vector(0, 0, 1)) * d.z;
}
vector mx_object_to_world_point(vector p) {
    return mx_object_to_world_vector(p) + primvar_vector("strata:objectToWorld3", vector(0, 0, 0));
}
vector mx_world_to_object_point(vector p) {
    return mx_world_to_object_vector(p) + primvar_vector("strata:worldToObject3", vector(0, 0, 0));
}
// A normal goes by the inverse transpose of the points' transform: a row of the result is a
// column of the other direction's matrix dotted with it. Normalized (0 stays 0).
vector mx_unit_or_zero(vector d) { return length(d) > 0.0 ? normalize(d) : d; }
vector mx_world_to_object_normal(vector n) {
    return mx_unit_or_zero(vector(dot(primvar_vector("strata:objectToWorld0", vector(1, 0, 0)), n),
                                  dot(primvar_vector("strata:objectToWorld1", vector(0, 1, 0)), n),
                                  dot(primvar_vector("strata:objectToWorld2", vector(0, 0, 1)), n)));
}
vector mx_object_to_world_normal(vector n) {
    return mx_unit_or_zero(vector(dot(primvar_vector("strata:worldToObject0", vector(1, 0, 0)), n),
                                  dot(primvar_vector("strata:worldToObject1", vector(0, 1, 0)), n),
                                  dot(primvar_vector("strata:worldToObject2", vector(0, 0, 1)), n)));
}
// A world-space tangent direction in `space` (object or model: the prim's own), normalized.
vector mx_tangent_in(string space, vector t) {
    return space == "world" ? t : mx_unit_or_zero(mx_world_to_object_vector(t));
}

shader mx_texcoord_color3(int index = 0, output color out) { out = color(u, v, 0.0); }
shader mx_position_color3(string space = "object", output color out) {
    if (space == "world") {
        out = color(P);
    } else {
        out = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P))));
    }
}
shader mx_normal_color3(string space = "object", output color out) {
    out = space == "world" ? color(N) : color(mx_world_to_object_normal(vector(N)));
}
shader mx_tangent_color3(string space = "object", int index = 0, output color out) {
    vector t = dPdu - N * dot(N, dPdu);
    out = length(t) > 1e-8 ? color(mx_tangent_in(space, normalize(t))) : color(0.0);
}
// The bitangent completes the frame in the space asked for: normal × tangent there (a
// non-uniform scale does not keep world-space right angles).
shader mx_bitangent_color3(string space = "object", int index = 0, output color out) {
    vector t = dPdu - N * dot(N, dPdu);
    vector n = space == "world" ? vector(N) : mx_world_to_object_normal(vector(N));
    out = length(t) > 1e-8 ? color(cross(n, mx_tangent_in(space, normalize(t)))) : color(0.0);
}
shader mx_geompropvalue_float(string geomprop = "", float default_ = 0.0, output float out) {
    out = primvar_float(geomprop, default_);
}
shader mx_geompropvalue_color3(string geomprop = "", color default_ = color(0.0), output color out) {
    if (geomprop == "st" || geomprop == "UV0") {
        out = color(u, v, 0.0);
    } else {
        out = primvar(geomprop, default_);
    }
}

// ---- procedural --------------------------------------------------------------------------------

// noise2d/noise3d: signed Perlin noise · amplitude + pivot.
shader mx_noise2d_float(float amplitude = 1.0, float pivot = 0.0, color texcoord = color(u, v, 0.0), output float out) {
    out = snoise(point(texcoord.r, texcoord.g, 0.0)) * amplitude + pivot;
}
shader mx_noise2d_color3(color amplitude = color(1.0), float pivot = 0.0, color texcoord = color(u, v, 0.0), output color out) {
    point p = point(texcoord.r, texcoord.g, 0.0);
    out = color(snoise(p), snoise(p + point(19.1, 7.3, 0.0)), snoise(p + point(3.7, 41.9, 0.0))) * amplitude + color(pivot);
}
shader mx_noise3d_float(float amplitude = 1.0, float pivot = 0.0, color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), output float out) {
    out = snoise(point(position)) * amplitude + pivot;
}
shader mx_noise3d_color3(color amplitude = color(1.0), float pivot = 0.0, color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), output color out) {
    point p = point(position);
    out = color(snoise(p), snoise(p + point(19.1, 7.3, 5.2)), snoise(p + point(3.7, 41.9, 13.3))) * amplitude + color(pivot);
}
// fractal3d: octaves of signed noise, each `lacunarity` finer and `diminish` weaker (1 to 12
// octaves).
float mx_fractal(point p, int octaves, float lacunarity, float diminish) {
    float sum = 0.0;
    float a = 1.0;
    point q = p;
    for (int i = 0; i < clamp(octaves, 1, 12); i++) {
        sum += a * snoise(q);
        a *= diminish;
        q *= lacunarity;
    }
    return sum;
}
shader mx_fractal3d_float(float amplitude = 1.0, int octaves = 3, float lacunarity = 2.0, float diminish = 0.5,
                          color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), output float out) {
    out = mx_fractal(point(position), octaves, lacunarity, diminish) * amplitude;
}
shader mx_cellnoise2d_float(color texcoord = color(u, v, 0.0), output float out) {
    out = cellnoise(point(texcoord.r, texcoord.g, 0.0));
}
shader mx_cellnoise3d_float(color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), output float out) { out = cellnoise(point(position)); }
// worleynoise: distance to the nearest jittered feature point (F1, jitter fixed at 1).
shader mx_worleynoise2d_float(color texcoord = color(u, v, 0.0), float jitter = 1.0, output float out) {
    out = cellular(point(texcoord.r, texcoord.g, 0.0));
}
shader mx_worleynoise3d_float(color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), float jitter = 1.0, output float out) { out = cellular(point(position)); }

// Ramps and splits along u (left to right) and v (bottom to top).
shader mx_ramplr_float(float valuel = 0.0, float valuer = 0.0, color texcoord = color(u, v, 0.0), output float out) {
    out = mix(valuel, valuer, clamp(texcoord.r, 0.0, 1.0));
}
shader mx_ramplr_color3(color valuel = color(0.0), color valuer = color(0.0), color texcoord = color(u, v, 0.0), output color out) {
    out = mix(valuel, valuer, clamp(texcoord.r, 0.0, 1.0));
}
shader mx_ramptb_float(float valuet = 0.0, float valueb = 0.0, color texcoord = color(u, v, 0.0), output float out) {
    out = mix(valueb, valuet, clamp(texcoord.g, 0.0, 1.0));
}
shader mx_ramptb_color3(color valuet = color(0.0), color valueb = color(0.0), color texcoord = color(u, v, 0.0), output color out) {
    out = mix(valueb, valuet, clamp(texcoord.g, 0.0, 1.0));
}
shader mx_splitlr_float(float valuel = 0.0, float valuer = 0.0, float center = 0.5, color texcoord = color(u, v, 0.0),
                        output float out) {
    out = texcoord.r < center ? valuel : valuer;
}
shader mx_splitlr_color3(color valuel = color(0.0), color valuer = color(0.0), float center = 0.5, color texcoord = color(u, v, 0.0),
                         output color out) {
    out = texcoord.r < center ? valuel : valuer;
}
shader mx_splittb_float(float valuet = 0.0, float valueb = 0.0, float center = 0.5, color texcoord = color(u, v, 0.0),
                        output float out) {
    out = texcoord.g < center ? valueb : valuet;
}
shader mx_splittb_color3(color valuet = color(0.0), color valueb = color(0.0), float center = 0.5, color texcoord = color(u, v, 0.0),
                         output color out) {
    out = texcoord.g < center ? valueb : valuet;
}

// ---- colour management: a working-space (lin_rec709) value from `space` ----------------------

float mx_srgb_to_linear(float c) {
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}
// ACEScg (AP1 primaries, D60) to linear Rec.709 (D65, Bradford-adapted).
color mx_ap1_to_rec709(color c) {
    return color(1.70505 * c.r - 0.62179 * c.g - 0.08326 * c.b,
                 -0.13026 * c.r + 1.14080 * c.g - 0.01055 * c.b,
                 -0.02400 * c.r - 0.12897 * c.g + 1.15297 * c.b);
}
color mx_to_working_space(color c, string space) {
    if (space == "srgb_texture") {
        return color(mx_srgb_to_linear(c.r), mx_srgb_to_linear(c.g), mx_srgb_to_linear(c.b));
    } else if (space == "acescg" || space == "lin_ap1") {
        return mx_ap1_to_rec709(c);
    } else if (space == "g22_ap1") {
        return mx_ap1_to_rec709(color(pow(max(c.r, 0.0), 2.2), pow(max(c.g, 0.0), 2.2), pow(max(c.b, 0.0), 2.2)));
    } else if (space == "g22_rec709") {
        return color(pow(max(c.r, 0.0), 2.2), pow(max(c.g, 0.0), 2.2), pow(max(c.b, 0.0), 2.2));
    }
    return c;
}

// ---- textures ----------------------------------------------------------------------------------

// Address modes to the runtime's wrap codes (strata_rt::texture::WRAP_*): periodic repeats,
// clamp clamps, mirror mirrors; `constant` reads `default` outside [0, 1] (handled in
// mx_image_lookup).
int mx_address_code(string mode) {
    return mode == "clamp" ? 2 : (mode == "mirror" ? 3 : (mode == "constant" ? 1 : 0));
}
// One image lookup: `decode` is how texels decode ("sRGB" for srgb_texture, else "raw"),
// `colorspace` the file's MaterialX colour space (converted to the working space here).
color mx_image_lookup(string file, string decode, string colorspace, float s, float t, string uaddressmode, string vaddressmode,
                      color fallback) {
    int outside = (uaddressmode == "constant" && (s < 0.0 || s > 1.0)) || (vaddressmode == "constant" && (t < 0.0 || t > 1.0))
                      ? 1 : 0;
    if (file == "" || outside == 1) {
        return fallback;
    }
    int wrap = 16 * mx_address_code(uaddressmode) + 256 * mx_address_code(vaddressmode);
    color c = color(texture_channel(file, decode, s, t, wrap), texture_channel(file, decode, s, t, wrap + 1),
                    texture_channel(file, decode, s, t, wrap + 2));
    return colorspace == "srgb_texture" ? c : mx_to_working_space(c, colorspace);
}
// image: texture at `texcoord` (t = 0 is the image's bottom row, as MaterialX's UV0).
// `filtertype` closest and cubic read bilinear (compose reports it).
shader mx_image_color3(string file = "", string decode = "raw", string colorspace = "", string layer = "",
                       color default_ = color(0.0), color texcoord = color(u, v, 0.0), string uaddressmode = "periodic",
                       string vaddressmode = "periodic", string filtertype = "linear", output color out) {
    out = mx_image_lookup(file, decode, colorspace, texcoord.r, texcoord.g, uaddressmode, vaddressmode, default_);
}
shader mx_image_float(string file = "", string decode = "raw", string colorspace = "", string layer = "", float default_ = 0.0,
                      color texcoord = color(u, v, 0.0), string uaddressmode = "periodic", string vaddressmode = "periodic",
                      string filtertype = "linear", output float out) {
    out = mx_image_lookup(file, decode, colorspace, texcoord.r, texcoord.g, uaddressmode, vaddressmode, color(default_)).r;
}
// tiledimage: texcoord · uvtiling − uvoffset, repeated.
shader mx_tiledimage_color3(string file = "", string decode = "raw", string colorspace = "", color default_ = color(0.0),
                            color texcoord = color(u, v, 0.0), color uvtiling = color(1.0, 1.0, 0.0),
                            color uvoffset = color(0.0), string filtertype = "linear", output color out) {
    out = mx_image_lookup(file, decode, colorspace, texcoord.r * uvtiling.r - uvoffset.r, texcoord.g * uvtiling.g - uvoffset.g,
                          "periodic", "periodic", default_);
}
shader mx_tiledimage_float(string file = "", string decode = "raw", string colorspace = "", float default_ = 0.0,
                           color texcoord = color(u, v, 0.0), color uvtiling = color(1.0, 1.0, 0.0),
                           color uvoffset = color(0.0), string filtertype = "linear", output float out) {
    out = mx_image_lookup(file, decode, colorspace, texcoord.r * uvtiling.r - uvoffset.r, texcoord.g * uvtiling.g - uvoffset.g,
                          "periodic", "periodic", color(default_)).r;
}

// normalmap: a tangent-space normal in [0, 1] encoding, xy scaled by `scale` (a float, or a
// vector2 per axis in 1.39's ND_normalmap_vector2), to world space (MaterialX's `in`, `scale`,
// `normal`, `tangent`; the frame from dPdu when no tangent is connected).
color mx_normalmap(color in_, float scale_x, float scale_y, color normal_, color tangent) {
    vector n = normalize(vector(normal_));
    vector t = vector(tangent);
    if (length(t) < 1e-8) {
        t = dPdu;
    }
    t = t - n * dot(n, t);
    if (length(t) < 1e-8) {
        t = abs(n.x) < 0.9 ? cross(n, vector(1, 0, 0)) : cross(n, vector(0, 1, 0));
    }
    t = normalize(t);
    vector b = cross(n, t);
    vector m = vector(in_) * 2.0 - 1.0;
    vector w = t * (m.x * scale_x) + b * (m.y * scale_y) + n * m.z;
    return length(w) > 1e-8 ? color(normalize(w)) : color(n);
}
shader mx_normalmap_color3(color in_ = color(0.5, 0.5, 1.0), float scale = 1.0, color normal_ = color(N),
                           color tangent = color(0.0), output color out) {
    out = mx_normalmap(in_, scale, scale, normal_, tangent);
}
shader mx_normalmap_vector2(color in_ = color(0.5, 0.5, 1.0), color scale = color(1.0, 1.0, 0.0),
                            color normal_ = color(N), color tangent = color(0.0), output color out) {
    out = mx_normalmap(in_, scale.r, scale.g, normal_, tangent);
}

// ---- pbrlib: utility nodes (MaterialX's physically based shading nodes specification) -------

// artistic_ior (Gulbrandsen 2014, "Artist Friendly Metallic Fresnel"): the complex IOR n + ik
// whose normal-incidence reflectance ((n − 1)² + k²) / ((n + 1)² + k²) is `reflectivity` r
// (clamped to [0, 0.99]); `edge_color` g moves n from n_max = (1 + √r) / (1 − √r) (g = 0) to
// n_min = (1 − r) / (1 + r) (g = 1), and k² = ((n + 1)² r − (n − 1)²) / (1 − r) (0 when negative).
float mx_artistic_n(float reflectivity, float edge) {
    float r = clamp(reflectivity, 0.0, 0.99);
    float n_min = (1.0 - r) / (1.0 + r);
    float n_max = (1.0 + sqrt(r)) / (1.0 - sqrt(r));
    return n_max * (1.0 - edge) + n_min * edge;
}
float mx_artistic_k(float reflectivity, float n) {
    float r = clamp(reflectivity, 0.0, 0.99);
    return sqrt(max(((n + 1.0) * (n + 1.0) * r - (n - 1.0) * (n - 1.0)) / (1.0 - r), 0.0));
}
shader mx_artistic_ior_color3(color reflectivity = color(0.944, 0.776, 0.373), color edge_color = color(0.998, 0.981, 0.751),
                              output color ior, output color extinction) {
    ior = color(mx_artistic_n(reflectivity.r, edge_color.r), mx_artistic_n(reflectivity.g, edge_color.g),
                mx_artistic_n(reflectivity.b, edge_color.b));
    extinction = color(mx_artistic_k(reflectivity.r, ior.r), mx_artistic_k(reflectivity.g, ior.g),
                       mx_artistic_k(reflectivity.b, ior.b));
}
// roughness_anisotropy: GGX α = roughness² (clamped to [1e-8, 1]) along tangent and bitangent;
// an anisotropy a > 0 stretches it to (min(α / s, 1), α s), s = √(1 − min(a, 0.98)).
color mx_anisotropic_alpha(float roughness, float anisotropy) {
    float alpha = clamp(roughness * roughness, 1e-8, 1.0);
    float s = sqrt(1.0 - clamp(anisotropy, 0.0, 0.98));
    return anisotropy > 0.0 ? color(min(alpha / s, 1.0), alpha * s, 0.0) : color(alpha, alpha, 0.0);
}
shader mx_roughness_anisotropy_color3(float roughness = 0.0, float anisotropy = 0.0, output color out) {
    out = mx_anisotropic_alpha(roughness, anisotropy);
}
// glossiness_anisotropy: roughness_anisotropy of roughness 1 − glossiness.
shader mx_glossiness_anisotropy_color3(float glossiness = 1.0, float anisotropy = 0.0, output color out) {
    out = mx_anisotropic_alpha(1.0 - glossiness, anisotropy);
}
// roughness_dual: α = roughness² per direction (clamped to [1e-8, 1]); a negative y is x.
shader mx_roughness_dual_color3(color roughness = color(0.0), output color out) {
    float y = roughness.g < 0.0 ? roughness.r : roughness.g;
    out = color(clamp(roughness.r * roughness.r, 1e-8, 1.0), clamp(y * y, 1e-8, 1.0), 0.0);
}

// ---- pbrlib: BSDF and EDF nodes on the closure built-ins ------------------------------------
// A BSDF node is its lobe times `weight`; `layer`/`mix`/`add`/`multiply` are the closure
// algebra (MaterialX's `mix(fg, bg, m)` is `bg·(1 − m) + fg·m`). MaterialX's microfacet
// `roughness` is the GGX α along tangent and bitangent (a vector2, as `roughness_anisotropy`
// makes it from a perceptual roughness): a lobe takes the perceptual roughness r = √α of the
// geometric mean α = √(αx αy) and is stretched by √(αx / αy) along its `tangent`
// (`mx_anisotropic`; unset, the zero vector: dPdu, MaterialX's default `Tworld`).
// A per-lobe `normal` (world space; unset, the zero vector: the shading normal) shades the lobe
// about it (`with_normal`), but generalized_schlick_bsdf's (compose reports it); the renderer
// projects the tangent into the plane of the lobe's normal.
// An EDF is its emitted radiance as a colour: `uniform_edf` is its colour, and the EDF
// operators are the colour nodes (`ND_add_edf` is `mx_add_color3`).
float mx_isotropic_roughness(color alpha) {
    return sqrt(sqrt(clamp(alpha.r, 0.0, 1.0) * clamp(alpha.g, 0.0, 1.0)));
}
// A lobe (whose roughness is mx_isotropic_roughness(alpha)) stretched by √(αx / αy) along
// `tangent` (world space; the zero vector: dPdu). Equal widths leave the words zero: the
// isotropic closure, bit for bit; a zero width leaves the lobe isotropic (its mean α is 0: a
// mirror).
closure mx_anisotropic(closure lobe, color alpha, color tangent) {
    float ax = clamp(alpha.r, 0.0, 1.0);
    float ay = clamp(alpha.g, 0.0, 1.0);
    float aspect = ax > 0.0 && ay > 0.0 ? sqrt(ax / ay) : 1.0;
    float stretched = aspect != 1.0 ? 1.0 : 0.0;
    vector t = length(vector(tangent)) > 1e-8 ? vector(tangent) : dPdu;
    return with_anisotropy(lobe, t * stretched, aspect * stretched);
}
// MaterialX's `rotate3d` as its reference shaders compute it (Rodrigues' formula with the
// cross product's factors swapped: v cos θ + (v × axis) sin θ + axis (axis · v)(1 − cos θ)),
// `degrees_` about unit `axis`.
vector mx_rotate3(vector in_, float degrees_, vector axis) {
    float a = radians(degrees_);
    return in_ * cos(a) + cross(in_, axis) * sin(a) + axis * dot(axis, in_) * (1.0 - cos(a));
}

// MaterialX 1.39's `thinfilm_thickness` (nm) and `thinfilm_ior` inputs of the specular lobes:
// a film over the whole lobe. No film (thickness 0) leaves the lobe's words as it wrote them.
closure mx_thinfilm(closure lobe, float thickness, float ior) {
    float filmed = thickness > 0.0 ? 1.0 : 0.0;
    return with_thin_film(lobe, max(thickness, 0.0), filmed > 0.0 ? clamp(ior, 1.0, 4.0) : 0.0, filmed);
}

shader mx_oren_nayar_diffuse_bsdf(float weight = 1.0, color color_ = color(0.18), float roughness = 0.0,
                                  color normal_ = color(0.0), int energy_compensation = 0, output closure out) {
    closure lobe = oren_nayar_diffuse_bsdf(clamp(color_, 0.0, 1.0), clamp(roughness, 0.0, 1.0), energy_compensation != 0 ? 1.0 : 0.0);
    out = with_normal(lobe, vector(normal_)) * clamp(weight, 0.0, 1.0);
}
shader mx_burley_diffuse_bsdf(float weight = 1.0, color color_ = color(0.18), float roughness = 0.0,
                              color normal_ = color(0.0), output closure out) {
    out = with_normal(burley_diffuse_bsdf(clamp(color_, 0.0, 1.0), clamp(roughness, 0.0, 1.0)), vector(normal_))
          * clamp(weight, 0.0, 1.0);
}
shader mx_dielectric_bsdf(float weight = 1.0, color tint = color(1.0), float ior = 1.5,
                          color roughness = color(0.05, 0.05, 0.0), int retroreflective = 0, float thinfilm_thickness = 0.0,
                          float thinfilm_ior = 1.5, color normal_ = color(0.0), color tangent = color(0.0),
                          string distribution = "ggx", string scatter_mode = "R", output closure out) {
    closure lobe = dielectric_bsdf(clamp(tint, 0.0, 1.0), clamp(ior, 1.0, 4.0), mx_isotropic_roughness(roughness), scatter_mode);
    out = with_normal(mx_anisotropic(mx_thinfilm(lobe, thinfilm_thickness, thinfilm_ior), roughness, tangent), vector(normal_))
          * clamp(weight, 0.0, 1.0);
}
shader mx_conductor_bsdf(float weight = 1.0, color ior = color(0.183, 0.421, 1.373), color extinction = color(3.424, 2.346, 1.770),
                         color roughness = color(0.05, 0.05, 0.0), int retroreflective = 0, float thinfilm_thickness = 0.0,
                         float thinfilm_ior = 1.5, color normal_ = color(0.0), color tangent = color(0.0),
                         string distribution = "ggx", output closure out) {
    closure lobe = conductor_bsdf(ior, extinction, mx_isotropic_roughness(roughness));
    out = with_normal(mx_anisotropic(mx_thinfilm(lobe, thinfilm_thickness, thinfilm_ior), roughness, tangent), vector(normal_))
          * clamp(weight, 0.0, 1.0);
}
shader mx_generalized_schlick_bsdf(float weight = 1.0, color color0 = color(1.0), color color82 = color(1.0),
                                   color color90 = color(1.0), float exponent = 5.0, color roughness = color(0.05, 0.05, 0.0),
                                   int retroreflective = 0, float thinfilm_thickness = 0.0, float thinfilm_ior = 1.5,
                                   color normal_ = color(0.0), color tangent = color(0.0), string distribution = "ggx",
                                   string scatter_mode = "R", output closure out) {
    closure lobe = generalized_schlick_bsdf(clamp(color0, 0.0, 1.0), clamp(color82, 0.0, 1.0), clamp(color90, 0.0, 1.0),
                                            exponent, mx_isotropic_roughness(roughness));
    out = mx_anisotropic(mx_thinfilm(lobe, thinfilm_thickness, thinfilm_ior), roughness, tangent) * clamp(weight, 0.0, 1.0);
}
shader mx_sheen_bsdf(float weight = 1.0, color color_ = color(1.0), float roughness = 0.3, color normal_ = color(0.0),
                     string mode = "conty_kulla", output closure out) {
    out = with_normal(sheen_bsdf(clamp(color_, 0.0, 1.0), clamp(roughness, 0.0, 1.0)), vector(normal_)) * clamp(weight, 0.0, 1.0);
}

shader mx_translucent_bsdf(float weight = 1.0, color color_ = color(1.0), color normal_ = color(0.0), output closure out) {
    out = with_normal(translucent_bsdf(clamp(color_, 0.0, 1.0)), vector(normal_)) * clamp(weight, 0.0, 1.0);
}
// subsurface_bsdf: diffuse transmission of `color` (compose reports the approximation: no
// light travels under the surface, `radius` and `anisotropy` are not read).
shader mx_subsurface_bsdf(float weight = 1.0, color color_ = color(0.18), color radius = color(1.0), float anisotropy = 0.0,
                          color normal_ = color(0.0), output closure out) {
    out = with_normal(translucent_bsdf(clamp(color_, 0.0, 1.0)), vector(normal_)) * clamp(weight, 0.0, 1.0);
}
// thin_film_bsdf (MaterialX 1.38, layered over a dielectric or conductor): no lobe, so
// `layer(thin_film, base)` is the base (compose reports that the film is ignored).
shader mx_thin_film_bsdf(float thickness = 550.0, float ior = 1.5, output closure out) {}

shader mx_layer_bsdf(closure top, closure base, output closure out) { out = layer(top, base); }
shader mx_mix_bsdf(closure fg, closure bg, float mix = 0.0, output closure out) {
    float m = clamp(mix, 0.0, 1.0);
    out = bg * (1.0 - m) + fg * m;
}
shader mx_add_bsdf(closure in1, closure in2, output closure out) { out = in1 + in2; }
shader mx_multiply_bsdfC(closure in1, color in2 = color(1.0), output closure out) { out = in1 * clamp(in2, 0.0, 1.0); }
shader mx_multiply_bsdfF(closure in1, float in2 = 1.0, output closure out) { out = in1 * clamp(in2, 0.0, 1.0); }

shader mx_uniform_edf(color color_ = color(1.0), output color out) { out = color_; }

// MaterialX's `surface`: a BSDF, an EDF (emitted radiance) and opacity. The BSDF reaches the
// shell node's closure port `bsdf` (a substance input cannot carry a closure), wired by
// compose; unconnected it is black. `thin_walled` makes its transmitting dielectrics
// thin-walled sheets (its translucent and subsurface lobes already transmit diffusely).
shader mx_surface_shell(closure bsdf, int thin_walled = 0, output closure out) {
    out = with_thin_walled(bsdf, thin_walled != 0 ? 1.0 : 0.0);
}
substance mx_surface {
    input color edf = color(0.0, 0.0, 0.0);
    input float opacity = 1.0;
    input int thin_walled = 0;
    node shell = mx_surface_shell(thin_walled: thin_walled);
    node presence = mask(opacity: opacity);
    node glow = mx_emission(amount: 1.0, tint: edf);
    surface = shell.out;
    mask = presence.out;
    emission = glow.out;
}

// ---- open_pbr_surface (OpenPBR 1.1) and standard_surface (Autodesk Standard Surface 1.0) -----
// Both surfaces are the closure algebra's layer stacks, as their specifications layer them:
//
//   OpenPBR:          layer(fuzz, layer(coat, mix(dielectric, metal, base_metalness)))
//   Standard Surface: layer(coat, mix(dielectric, metal, metalness)), sheen under the specular
//   dielectric:       mix(layer(specular reflection, opaque base), rough glass (R and T), transmission)
//   opaque base:      diffuse (Oren–Nayar; EON in OpenPBR) of mix(base colour, subsurface colour, subsurface)
//
// at most 6 terms of the 8 a closure holds. A layer's weight (coat, fuzz/sheen, specular) is
// its top's weight (`layer(top · w, base)` = `mix(base, layer(top, base), w)`), so weight 0
// terms vanish and a single lobe remains in the limiting cases. Per parameter:
// - metal: GGX with the F82-tint Fresnel (generalized Schlick: F0 base_weight · base_color,
//   F82 tint specular_color, exponent 5), weighted by specular_weight in OpenPBR;
// - specular: a GGX dielectric reflection (specular_color tint, specular_ior); OpenPBR 1.1's
//   specular_weight modulates the IOR (mx_modulated_ior), Standard Surface's `specular`
//   weights the lobe;
// - transmission: the rough dielectric with reflection and transmission, transmission_color
//   as its tint, no volume (depth, scatter and dispersion are reported);
// - subsurface: diffuse reflection of subsurface_color (no light travels under the surface;
//   reported);
// - thin-walled (OpenPBR geometry_thin_walled, Standard Surface thin_walled): the transmission
//   is a thin sheet (`with_thin_walled`: the sheet's reflectance, transmission straight
//   through, no medium entered); the subsurface becomes diffuse reflection and transmission of
//   subsurface_color, in OpenPBR split (1 − g) / 2 and (1 + g) / 2 by the scatter anisotropy g,
//   in Standard Surface all transmission (its translucent_bsdf);
// - coat: a GGX dielectric reflection (coat_ior, coat_roughness) over the base tinted by
//   mix(1, coat_color, coat_weight); in OpenPBR the coat roughens the specular lobes below
//   (r' = mix(r, min(1, (r⁴ + 2 r_c⁴)^¼), coat_weight)), in Standard Surface by
//   coat_affect_roughness · coat · coat_roughness towards 1; in OpenPBR the coat darkens the
//   base by its internal reflections (coat_darkening, below; the random walk undoes it);
// - thin film: an Airy film on the specular reflection, the transmission (its microfacets
//   reflect the film's reflectance and transmit the rest) and the metal (mx_film);
// - fuzz (OpenPBR, over the coat) and sheen (Standard Surface, over the diffuse): Charlie sheen;
// - emission: the `emission` product; opacity: the layer mask.
// Roughness is perceptual (GGX alpha = roughness²), as both specifications define it.

// The thin film both surfaces put on their specular reflection, transmission and metal: `weight` of it
// (`thickness` nm, index `ior`; weight 0: none) mixed into the Fresnel curve, as OpenPBR
// mixes its film in.
closure mx_film(closure lobe, float weight, float thickness, float ior) {
    return with_thin_film(lobe, max(thickness, 0.0), clamp(ior, 1.0, 4.0), clamp(weight, 0.0, 1.0));
}

// The dielectric base both surfaces share (see above), its specular reflection and its
// transmission under the film (`mx_film`).
closure mx_dielectric_base(closure opaque, float specular_weight, color specular_color, float roughness, float ior,
                           float transmission, color transmission_color, float film_weight, float film_thickness,
                           float film_ior, float thin_walled) {
    closure bare = dielectric_bsdf(clamp(specular_color, 0.0, 1.0), clamp(ior, 1.0, 4.0), roughness, "R");
    closure specular = mx_film(bare, film_weight, film_thickness, film_ior) * clamp(specular_weight, 0.0, 1.0);
    closure refracting = dielectric_bsdf(clamp(transmission_color, 0.0, 1.0), clamp(ior, 1.0001, 4.0), roughness, "RT");
    closure glass = mx_film(with_thin_walled(refracting, thin_walled), film_weight, film_thickness, film_ior);
    return mix(layer(specular, opaque), glass, clamp(transmission, 0.0, 1.0));
}

// A metal with the F82-tint Fresnel: normal-incidence colour `f0`, `tint` at 82°.
closure mx_f82_metal(color f0, color tint, float roughness) {
    return generalized_schlick_bsdf(clamp(f0, 0.0, 1.0), clamp(tint, 0.0, 1.0), color(1.0), 5.0, roughness);
}

// OpenPBR's coat darkening (specification, "Coat: Darkening"): of the light the base
// reflects, the fraction K returns to it by internal reflection at the coat, so the base is
// seen darkened by Δ = (1 − K) / (1 − E_b K), E_b its albedo at normal incidence (exact for a
// Lambert base under a smooth coat, the interfaced Lambertian). K blends the smooth-base value
// (the coat's F0) and the rough-base value 1 − (1 − E_F(η)) / η² by the base's roughness
// estimate; the factor is mix(1, Δ, coat_weight · coat_darkening).
float mx_fresnel_hemispherical_albedo(float eta) {
    // d'Eon 2021's fit (within 0.2 % for η in [1, 3]), as the specification quotes it.
    return log((10893.0 * eta - 1438.2) / (-774.4 * eta * eta + 10212.0 * eta + 1.0));
}
float mx_dielectric_f0(float eta) {
    float r = (eta - 1.0) / (eta + 1.0);
    return r * r;
}
// OpenPBR 1.1's specular weight ξ (specification, "Specular", equation modulated_ior): the
// IOR ratio η' = (1 + ε) / (1 − ε), ε = sgn(η − 1) √(ξ F_s), F_s = ((1 − η) / (1 + η))², so
// the reflectance at normal incidence is ξ F_s (ξ clamped to [0, 1 / F_s]); ξ = 0 is η' = 1,
// no reflection. The ratio is taken against the ambient medium (the coat is not in it).
float mx_modulated_ior(float ior, float weight) {
    float eta = clamp(ior, 1.0, 4.0);
    float fs = mx_dielectric_f0(eta);
    float e = fs > 0.0 ? sqrt(clamp(weight, 0.0, 1.0 / fs) * fs) : 0.0;
    // ξ = 1 is η itself, exactly (the round trip through ε rounds in the last bit).
    return weight == 1.0 ? eta : (1.0 + e) / max(1.0 - e, 1e-6);
}
color mx_coat_darkening(color base_albedo, float base_roughness, float coat_ior, float amount) {
    float eta = clamp(coat_ior, 1.0, 4.0);
    float k_rough = 1.0 - (1.0 - mx_fresnel_hemispherical_albedo(eta)) / (eta * eta);
    float k = clamp(mix(mx_dielectric_f0(eta), k_rough, clamp(base_roughness, 0.0, 1.0)), 0.0, 0.999);
    color e = clamp(base_albedo, 0.0, 1.0);
    color delta = color((1.0 - k) / (1.0 - e.r * k), (1.0 - k) / (1.0 - e.g * k), (1.0 - k) / (1.0 - e.b * k));
    return mix(color(1.0), delta, clamp(amount, 0.0, 1.0));
}

// OpenPBR's anisotropic widths (specification, "Specular": α_t = r² √(2 / (1 + (1 − a)²)),
// α_b = (1 − a) α_t along tangent and bitangent), the anisotropy a clamped to [0, 0.998] (at 1
// the bitangent width vanishes; 0.998 stretches the lobe 22-fold).
color mx_open_pbr_alpha(float roughness, float anisotropy) {
    float rest = 1.0 - clamp(anisotropy, 0.0, 0.998);
    float alpha_t = roughness * roughness * sqrt(2.0 / (1.0 + rest * rest));
    return color(alpha_t, rest * alpha_t, 0.0);
}

// A clear coat of `weight` over `base`, which it tints by `coat_color` and darkens by
// `darkening` (OpenPBR's coat darkening; color(1.0): none), shaded about `coat_normal` (world
// space; unset, the zero vector: the surface's unperturbed normal N, as both specifications
// default it to Nworld, so a bumped base keeps a smooth coat). The coat records the darkening
// (`with_darkening`): the random-walk layering simulates the internal reflections it stands
// for and divides it back out, so the base is not darkened twice. The coat's GGX widths are
// `alpha` (its `roughness` their mean's, mx_anisotropic) along `tangent`.
closure mx_coated(closure base, float weight, color coat_color, float roughness, float ior, color coat_normal,
                  color darkening, color alpha, color tangent) {
    float c = clamp(weight, 0.0, 1.0);
    vector n = length(vector(coat_normal)) > 1e-8 ? normalize(vector(coat_normal)) : vector(N);
    closure isotropic_coat = dielectric_bsdf(color(1.0), clamp(ior, 1.0, 4.0), clamp(roughness, 0.0, 1.0), "R");
    closure coat = with_normal(mx_anisotropic(isotropic_coat, alpha, tangent), n);
    return layer(with_darkening(coat, darkening) * c, base * darkening * mix(color(1.0), clamp(coat_color, 0.0, 1.0), c));
}

shader mx_open_pbr_bsdf(float base_weight = 1.0, color base_color = color(0.8, 0.8, 0.8), float base_diffuse_roughness = 0.0,
                        float base_metalness = 0.0, float specular_weight = 1.0, color specular_color = color(1.0),
                        float specular_roughness = 0.3, float specular_ior = 1.5, float transmission_weight = 0.0,
                        color transmission_color = color(1.0), float subsurface_weight = 0.0,
                        color subsurface_color = color(0.8, 0.8, 0.8), float fuzz_weight = 0.0, color fuzz_color = color(1.0),
                        float fuzz_roughness = 0.5, float coat_weight = 0.0, color coat_color = color(1.0),
                        float coat_roughness = 0.0, float coat_ior = 1.6, float coat_darkening = 1.0,
                        color coat_normal = color(0.0), float thin_film_weight = 0.0, float thin_film_thickness = 0.5,
                        float thin_film_ior = 1.4, float specular_roughness_anisotropy = 0.0,
                        float coat_roughness_anisotropy = 0.0, color geometry_tangent = color(0.0),
                        color geometry_coat_tangent = color(0.0), float subsurface_scatter_anisotropy = 0.0,
                        int thin_walled = 0, output closure bsdf) {
    float c = clamp(coat_weight, 0.0, 1.0);
    float rc_in = clamp(coat_roughness, 0.0, 1.0);
    float r0 = clamp(specular_roughness, 0.0, 1.0);
    float r_in = mix(r0, min(1.0, pow(r0 * r0 * r0 * r0 + 2.0 * rc_in * rc_in * rc_in * rc_in, 0.25)), c);
    // The specular and coat widths along their tangents (isotropic: r itself, bit for bit).
    color alpha = mx_open_pbr_alpha(r_in, specular_roughness_anisotropy);
    float r = specular_roughness_anisotropy > 0.0 ? mx_isotropic_roughness(alpha) : r_in;
    color coat_alpha = mx_open_pbr_alpha(rc_in, coat_roughness_anisotropy);
    float rc = coat_roughness_anisotropy > 0.0 ? mx_isotropic_roughness(coat_alpha) : rc_in;
    color base = clamp(base_color * base_weight, 0.0, 1.0);
    // Thin-walled, the subsurface reflects (1 − g) / 2 and transmits (1 + g) / 2 of
    // subsurface_color diffusely (OpenPBR, "Thin-walled": a thin translucent sheet).
    float thin = thin_walled != 0 ? 1.0 : 0.0;
    float s = clamp(subsurface_weight, 0.0, 1.0);
    float g = clamp(subsurface_scatter_anisotropy, -1.0, 1.0);
    color subsurface = clamp(subsurface_color, 0.0, 1.0);
    color diffuse_colour = mix(base, subsurface * mix(1.0, 0.5 * (1.0 - g), thin), s);
    closure diffuse = oren_nayar_diffuse_bsdf(diffuse_colour, clamp(base_diffuse_roughness, 0.0, 1.0), 1.0)
                      + translucent_bsdf(subsurface) * (s * thin * 0.5 * (1.0 + g));
    // The modulated IOR serves reflection and transmission alike; a weight of 0 (η' = 1,
    // no reflection) drops the specular lobe, so the limiting cases stay single lobes.
    float ior = mx_modulated_ior(specular_ior, specular_weight);
    closure dielectric = mx_dielectric_base(diffuse, specular_weight > 0.0 ? 1.0 : 0.0, specular_color, r, ior,
                                            transmission_weight, transmission_color, thin_film_weight,
                                            thin_film_thickness * 1000.0, thin_film_ior, thin);
    closure metal = mx_film(mx_f82_metal(base, specular_color, r), thin_film_weight, thin_film_thickness * 1000.0, thin_film_ior)
                    * clamp(specular_weight, 0.0, 1.0);
    // The base's albedo at normal incidence and roughness estimate, for the coat's darkening:
    // its slabs' albedos mixed by their weights (the glass returns only its reflection).
    float m = clamp(base_metalness, 0.0, 1.0);
    float fs = mx_dielectric_f0(clamp(ior, 1.0, 4.0));
    color e_specular = clamp(specular_color, 0.0, 1.0) * fs;
    color e_opaque = e_specular + diffuse_colour * (color(1.0) - e_specular);
    color e_dielectric = mix(e_opaque, e_specular, clamp(transmission_weight, 0.0, 1.0));
    color e_base = mix(e_dielectric, base * clamp(specular_weight, 0.0, 1.0), m);
    float base_roughness = mix(mix(1.0, r0, fs), r0, m);
    color darkening = mx_coat_darkening(e_base, base_roughness, coat_ior, c * clamp(coat_darkening, 0.0, 1.0));
    closure base_slab = mx_anisotropic(mix(dielectric, metal, m), alpha, geometry_tangent);
    closure coated = mx_coated(base_slab, c, coat_color, rc, coat_ior, coat_normal, darkening, coat_alpha, geometry_coat_tangent);
    bsdf = layer(sheen_bsdf(clamp(fuzz_color, 0.0, 1.0), clamp(fuzz_roughness, 0.0, 1.0)) * clamp(fuzz_weight, 0.0, 1.0), coated);
}

shader mx_standard_surface_bsdf(float base = 0.8, color base_color = color(1.0), float diffuse_roughness = 0.0,
                                float metalness = 0.0, float specular = 1.0, color specular_color = color(1.0),
                                float specular_roughness = 0.2, float specular_IOR = 1.5, float transmission = 0.0,
                                color transmission_color = color(1.0), float subsurface = 0.0,
                                color subsurface_color = color(1.0), float sheen = 0.0, color sheen_color = color(1.0),
                                float sheen_roughness = 0.3, float coat = 0.0, color coat_color = color(1.0),
                                float coat_roughness = 0.1, float coat_IOR = 1.5, float coat_affect_roughness = 0.0,
                                color coat_normal = color(0.0), float thin_film_thickness = 0.0, float thin_film_IOR = 1.5,
                                float specular_anisotropy = 0.0, float specular_rotation = 0.0, float coat_anisotropy = 0.0,
                                float coat_rotation = 0.0, color tangent = color(0.0), int thin_walled = 0,
                                output closure bsdf) {
    float c = clamp(coat, 0.0, 1.0);
    float rc_in = clamp(coat_roughness, 0.0, 1.0);
    float r_in = mix(clamp(specular_roughness, 0.0, 1.0), 1.0, clamp(coat_affect_roughness, 0.0, 1.0) * c * rc_in);
    // `roughness_anisotropy`'s widths (isotropic: r itself, bit for bit), along the tangent
    // (unset: dPdu) turned by `*_rotation` turns about the normal (the coat's about its own).
    color alpha = mx_anisotropic_alpha(r_in, specular_anisotropy);
    float r = specular_anisotropy > 0.0 ? mx_isotropic_roughness(alpha) : r_in;
    color coat_alpha = mx_anisotropic_alpha(rc_in, coat_anisotropy);
    float rc = coat_anisotropy > 0.0 ? mx_isotropic_roughness(coat_alpha) : rc_in;
    vector t = length(vector(tangent)) > 1e-8 ? vector(tangent) : dPdu;
    vector coat_n = length(vector(coat_normal)) > 1e-8 ? normalize(vector(coat_normal)) : vector(N);
    color main_tangent = color(mx_rotate3(t, specular_rotation * 360.0, vector(N)));
    color coat_tangent = color(mx_rotate3(t, coat_rotation * 360.0, coat_n));
    color albedo = clamp(base_color * base, 0.0, 1.0);
    // Thin-walled, the subsurface is diffuse transmission of subsurface_color (the
    // specification's translucent_bsdf); otherwise diffuse reflection of it (reported).
    float thin = thin_walled != 0 ? 1.0 : 0.0;
    float s = clamp(subsurface, 0.0, 1.0);
    color subsurface_colour = clamp(subsurface_color, 0.0, 1.0);
    color diffuse_colour = mix(albedo, subsurface_colour, s * (1.0 - thin)) * (1.0 - s * thin);
    closure diffuse = oren_nayar_diffuse_bsdf(diffuse_colour, clamp(diffuse_roughness, 0.0, 1.0), 0.0)
                      + translucent_bsdf(subsurface_colour) * (s * thin);
    closure opaque = layer(sheen_bsdf(clamp(sheen_color, 0.0, 1.0), clamp(sheen_roughness, 0.0, 1.0)) * clamp(sheen, 0.0, 1.0),
                           diffuse);
    closure dielectric = mx_dielectric_base(opaque, specular, specular_color, r, specular_IOR, transmission, transmission_color,
                                            thin_film_thickness > 0.0 ? 1.0 : 0.0, thin_film_thickness, thin_film_IOR, thin);
    closure metal = mx_film(mx_f82_metal(albedo, specular_color, r), thin_film_thickness > 0.0 ? 1.0 : 0.0, thin_film_thickness,
                            thin_film_IOR);
    closure base_slab = mx_anisotropic(mix(dielectric, metal, clamp(metalness, 0.0, 1.0)), alpha, main_tangent);
    bsdf = mx_coated(base_slab, c, coat_color, rc, coat_IOR, coat_normal, color(1.0), coat_alpha, coat_tangent);
}

// MaterialX's `surface_unlit`: emission · emission_color as emitted radiance and no BSDF
// (black to light), opacity the mask; `transmission` is reported (compose).
shader mx_unlit_shell(output closure out) {}
substance mx_surface_unlit {
    input float emission = 1.0;
    input color emission_color = color(1.0, 1.0, 1.0);
    input float transmission = 0.0;
    input color transmission_color = color(1.0, 1.0, 1.0);
    input float opacity = 1.0;
    node shell = mx_unlit_shell();
    node presence = mask(opacity: opacity);
    node glow = mx_emission(amount: emission, tint: emission_color);
    surface = shell.out;
    mask = presence.out;
    emission = glow.out;
}

// emission_luminance (nits) · emission_color as radiance: UsdLux intensities are nits too.
shader mx_emission(float amount = 0.0, color tint = color(1.0), output color out) {
    out = tint * amount;
}
// A world-space shading normal input (unset: the zero vector) as the normal product.
shader mx_surface_normal(color n = color(0.0), output normal out) {
    out = length(vector(n)) > 1e-8 ? normalize(vector(n)) : N;
}
shader mx_opacity(color opacity = color(1.0), output float out) {
    out = clamp((opacity.r + opacity.g + opacity.b) / 3.0, 0.0, 1.0);
}

// Every input of the OpenPBR 1.1 specification with its default; `compose::mtlx` reports
// those the closure does not read (or reads approximately) when a scene sets them away from
// the default.
substance open_pbr_surface {
    input float base_weight = 1.0;
    input color base_color = color(0.8, 0.8, 0.8);
    input float base_diffuse_roughness = 0.0;
    input float base_metalness = 0.0;
    input float specular_weight = 1.0;
    input color specular_color = color(1.0, 1.0, 1.0);
    input float specular_roughness = 0.3;
    input float specular_ior = 1.5;
    input float specular_roughness_anisotropy = 0.0;
    input float transmission_weight = 0.0;
    input color transmission_color = color(1.0, 1.0, 1.0);
    input float transmission_depth = 0.0;
    input color transmission_scatter = color(0.0, 0.0, 0.0);
    input float transmission_scatter_anisotropy = 0.0;
    input float transmission_dispersion_scale = 0.0;
    input float transmission_dispersion_abbe_number = 20.0;
    input float subsurface_weight = 0.0;
    input color subsurface_color = color(0.8, 0.8, 0.8);
    input float subsurface_radius = 1.0;
    input color subsurface_radius_scale = color(1.0, 0.5, 0.25);
    input float subsurface_scatter_anisotropy = 0.0;
    input float fuzz_weight = 0.0;
    input color fuzz_color = color(1.0, 1.0, 1.0);
    input float fuzz_roughness = 0.5;
    input float coat_weight = 0.0;
    input color coat_color = color(1.0, 1.0, 1.0);
    input float coat_roughness = 0.0;
    input float coat_roughness_anisotropy = 0.0;
    input float coat_ior = 1.6;
    input float coat_darkening = 1.0;
    input float thin_film_weight = 0.0;
    input float thin_film_thickness = 0.5;
    input float thin_film_ior = 1.4;
    input float emission_luminance = 0.0;
    input color emission_color = color(1.0, 1.0, 1.0);
    input float geometry_opacity = 1.0;
    input int geometry_thin_walled = 0;
    input color geometry_normal = color(0.0, 0.0, 0.0);
    input color geometry_coat_normal = color(0.0, 0.0, 0.0);
    input color geometry_tangent = color(0.0, 0.0, 0.0);
    input color geometry_coat_tangent = color(0.0, 0.0, 0.0);
    node bsdf = mx_open_pbr_bsdf(base_weight: base_weight, base_color: base_color, base_diffuse_roughness: base_diffuse_roughness,
                                 base_metalness: base_metalness, specular_weight: specular_weight,
                                 specular_color: specular_color, specular_roughness: specular_roughness,
                                 specular_ior: specular_ior, transmission_weight: transmission_weight,
                                 transmission_color: transmission_color, subsurface_weight: subsurface_weight,
                                 subsurface_color: subsurface_color, fuzz_weight: fuzz_weight, fuzz_color: fuzz_color,
                                 fuzz_roughness: fuzz_roughness, coat_weight: coat_weight, coat_color: coat_color,
                                 coat_roughness: coat_roughness, coat_ior: coat_ior, coat_darkening: coat_darkening,
                                 coat_normal: geometry_coat_normal, thin_film_weight: thin_film_weight,
                                 thin_film_thickness: thin_film_thickness, thin_film_ior: thin_film_ior,
                                 specular_roughness_anisotropy: specular_roughness_anisotropy,
                                 coat_roughness_anisotropy: coat_roughness_anisotropy, geometry_tangent: geometry_tangent,
                                 geometry_coat_tangent: geometry_coat_tangent,
                                 subsurface_scatter_anisotropy: subsurface_scatter_anisotropy,
                                 thin_walled: geometry_thin_walled);
    node presence = mask(opacity: geometry_opacity);
    node normals = mx_surface_normal(n: geometry_normal);
    node glow = mx_emission(amount: emission_luminance, tint: emission_color);
    surface = bsdf.bsdf;
    mask = presence.out;
    normal = normals.out;
    emission = glow.out;
}

// Every input of Autodesk Standard Surface 1.0 with its default (`normal` is `normal_`).
substance standard_surface {
    input float base = 0.8;
    input color base_color = color(1.0, 1.0, 1.0);
    input float diffuse_roughness = 0.0;
    input float metalness = 0.0;
    input float specular = 1.0;
    input color specular_color = color(1.0, 1.0, 1.0);
    input float specular_roughness = 0.2;
    input float specular_IOR = 1.5;
    input float specular_anisotropy = 0.0;
    input float specular_rotation = 0.0;
    input float transmission = 0.0;
    input color transmission_color = color(1.0, 1.0, 1.0);
    input float transmission_depth = 0.0;
    input color transmission_scatter = color(0.0, 0.0, 0.0);
    input float transmission_scatter_anisotropy = 0.0;
    input float transmission_dispersion = 0.0;
    input float transmission_extra_roughness = 0.0;
    input float subsurface = 0.0;
    input color subsurface_color = color(1.0, 1.0, 1.0);
    input color subsurface_radius = color(1.0, 1.0, 1.0);
    input float subsurface_scale = 1.0;
    input float subsurface_anisotropy = 0.0;
    input float sheen = 0.0;
    input color sheen_color = color(1.0, 1.0, 1.0);
    input float sheen_roughness = 0.3;
    input float coat = 0.0;
    input color coat_color = color(1.0, 1.0, 1.0);
    input float coat_roughness = 0.1;
    input float coat_anisotropy = 0.0;
    input float coat_rotation = 0.0;
    input float coat_IOR = 1.5;
    input color coat_normal = color(0.0, 0.0, 0.0);
    input float coat_affect_color = 0.0;
    input float coat_affect_roughness = 0.0;
    input float thin_film_thickness = 0.0;
    input float thin_film_IOR = 1.5;
    input float emission = 0.0;
    input color emission_color = color(1.0, 1.0, 1.0);
    input color opacity = color(1.0, 1.0, 1.0);
    input int thin_walled = 0;
    input color normal_ = color(0.0, 0.0, 0.0);
    input color tangent = color(0.0, 0.0, 0.0);
    node bsdf = mx_standard_surface_bsdf(base: base, base_color: base_color, diffuse_roughness: diffuse_roughness,
                                         metalness: metalness, specular: specular, specular_color: specular_color,
                                         specular_roughness: specular_roughness, specular_IOR: specular_IOR,
                                         transmission: transmission, transmission_color: transmission_color,
                                         subsurface: subsurface, subsurface_color: subsurface_color, sheen: sheen,
                                         sheen_color: sheen_color, sheen_roughness: sheen_roughness, coat: coat,
                                         coat_color: coat_color, coat_roughness: coat_roughness, coat_IOR: coat_IOR,
                                         coat_affect_roughness: coat_affect_roughness, coat_normal: coat_normal,
                                         thin_film_thickness: thin_film_thickness, thin_film_IOR: thin_film_IOR,
                                         specular_anisotropy: specular_anisotropy, specular_rotation: specular_rotation,
                                         coat_anisotropy: coat_anisotropy, coat_rotation: coat_rotation, tangent: tangent,
                                         thin_walled: thin_walled);
    node presence = mx_opacity(opacity: opacity);
    node normals = mx_surface_normal(n: normal_);
    node glow = mx_emission(amount: emission, tint: emission_color);
    surface = bsdf.bsdf;
    mask = presence.out;
    normal = normals.out;
    emission = glow.out;
}
