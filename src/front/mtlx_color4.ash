
// ---- MaterialX color4 and vector4 variants ----------------------------------------------------
// The language has no 4-vector: a color4 (or vector4) travels as a colour and a float, the
// fourth channel (alpha, or w). Each port `P` of a 4-channel type is the colour `P` and the
// float `P_a`; `compose::mtlx` names `mx_<node>_color4` for both types (as `_color3` serves
// color3 and vector3), sets `P_a` from a value's fourth component, and along a connection
// wires `P_a` to the producing node's `<output>_a` (a float, as MaterialX promotes it, fills
// all four channels). Written from the MaterialX specification: the fourth channel follows
// the same arithmetic as the other three, but where a node says otherwise (luminance and
// the HSV nodes pass alpha through; the alpha compositing nodes read it).

// ---- math ----------------------------------------------------------------------------------
shader mx_absval_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(abs(in_.r), abs(in_.g), abs(in_.b));
    out_a = abs(in_a);
}
shader mx_sign_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(sign(in_.r), sign(in_.g), sign(in_.b));
    out_a = sign(in_a);
}
shader mx_floor_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(floor(in_.r), floor(in_.g), floor(in_.b));
    out_a = floor(in_a);
}
shader mx_ceil_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(ceil(in_.r), ceil(in_.g), ceil(in_.b));
    out_a = ceil(in_a);
}
shader mx_round_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(round(in_.r), round(in_.g), round(in_.b));
    out_a = round(in_a);
}
shader mx_fract_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color((in_.r - floor(in_.r)), (in_.g - floor(in_.g)), (in_.b - floor(in_.b)));
    out_a = (in_a - floor(in_a));
}
shader mx_sqrt_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(sqrt(max(in_.r, 0.0)), sqrt(max(in_.g, 0.0)), sqrt(max(in_.b, 0.0)));
    out_a = sqrt(max(in_a, 0.0));
}
shader mx_exp_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(exp(in_.r), exp(in_.g), exp(in_.b));
    out_a = exp(in_a);
}
shader mx_ln_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color((in_.r > 0.0 ? log(in_.r) : 0.0), (in_.g > 0.0 ? log(in_.g) : 0.0), (in_.b > 0.0 ? log(in_.b) : 0.0));
    out_a = (in_a > 0.0 ? log(in_a) : 0.0);
}
shader mx_sin_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(sin(in_.r), sin(in_.g), sin(in_.b));
    out_a = sin(in_a);
}
shader mx_cos_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(cos(in_.r), cos(in_.g), cos(in_.b));
    out_a = cos(in_a);
}
shader mx_tan_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(tan(in_.r), tan(in_.g), tan(in_.b));
    out_a = tan(in_a);
}
shader mx_asin_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(asin(clamp(in_.r, -1.0, 1.0)), asin(clamp(in_.g, -1.0, 1.0)), asin(clamp(in_.b, -1.0, 1.0)));
    out_a = asin(clamp(in_a, -1.0, 1.0));
}
shader mx_acos_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = color(acos(clamp(in_.r, -1.0, 1.0)), acos(clamp(in_.g, -1.0, 1.0)), acos(clamp(in_.b, -1.0, 1.0)));
    out_a = acos(clamp(in_a, -1.0, 1.0));
}
shader mx_add_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0,
                      output color out, output float out_a) {
    out = color(in1.r + in2.r, in1.g + in2.g, in1.b + in2.b);
    out_a = in1_a + in2_a;
}
shader mx_subtract_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0,
                      output color out, output float out_a) {
    out = color(in1.r - in2.r, in1.g - in2.g, in1.b - in2.b);
    out_a = in1_a - in2_a;
}
shader mx_multiply_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(1.0), float in2_a = 1.0,
                      output color out, output float out_a) {
    out = color(in1.r * in2.r, in1.g * in2.g, in1.b * in2.b);
    out_a = in1_a * in2_a;
}
shader mx_divide_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(1.0), float in2_a = 1.0,
                      output color out, output float out_a) {
    out = color((in2.r != 0.0 ? in1.r / in2.r : 0.0), (in2.g != 0.0 ? in1.g / in2.g : 0.0), (in2.b != 0.0 ? in1.b / in2.b : 0.0));
    out_a = (in2_a != 0.0 ? in1_a / in2_a : 0.0);
}
shader mx_modulo_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(1.0), float in2_a = 1.0,
                      output color out, output float out_a) {
    out = color(mx_fmod(in1.r, in2.r), mx_fmod(in1.g, in2.g), mx_fmod(in1.b, in2.b));
    out_a = mx_fmod(in1_a, in2_a);
}
shader mx_power_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(1.0), float in2_a = 1.0,
                      output color out, output float out_a) {
    out = color(pow(in1.r, in2.r), pow(in1.g, in2.g), pow(in1.b, in2.b));
    out_a = pow(in1_a, in2_a);
}
shader mx_safepower_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(1.0), float in2_a = 1.0,
                      output color out, output float out_a) {
    out = color(mx_safepower1(in1.r, in2.r), mx_safepower1(in1.g, in2.g), mx_safepower1(in1.b, in2.b));
    out_a = mx_safepower1(in1_a, in2_a);
}
shader mx_min_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0,
                      output color out, output float out_a) {
    out = color(min(in1.r, in2.r), min(in1.g, in2.g), min(in1.b, in2.b));
    out_a = min(in1_a, in2_a);
}
shader mx_max_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0,
                      output color out, output float out_a) {
    out = color(max(in1.r, in2.r), max(in1.g, in2.g), max(in1.b, in2.b));
    out_a = max(in1_a, in2_a);
}
shader mx_atan2_color4(color iny = color(0.0), float iny_a = 0.0, color inx = color(1.0), float inx_a = 1.0,
                     output color out, output float out_a) {
    out = color(atan2(iny.r, inx.r), atan2(iny.g, inx.g), atan2(iny.b, inx.b));
    out_a = atan2(iny_a, inx_a);
}
shader mx_clamp_color4(color in_ = color(0.0), float in_a = 0.0, color low = color(0.0), float low_a = 0.0,
                     color high = color(1.0), float high_a = 1.0, output color out, output float out_a) {
    out = color(min(max(in_.r, low.r), high.r), min(max(in_.g, low.g), high.g), min(max(in_.b, low.b), high.b));
    out_a = min(max(in_a, low_a), high_a);
}
shader mx_invert_color4(color in_ = color(0.0), float in_a = 0.0, color amount = color(1.0), float amount_a = 1.0,
                      output color out, output float out_a) {
    out = color(amount.r - in_.r, amount.g - in_.g, amount.b - in_.b);
    out_a = amount_a - in_a;
}
shader mx_remap_color4(color in_ = color(0.0), float in_a = 0.0, color inlow = color(0.0), float inlow_a = 0.0,
                     color inhigh = color(1.0), float inhigh_a = 1.0, color outlow = color(0.0), float outlow_a = 0.0,
                     color outhigh = color(1.0), float outhigh_a = 1.0, output color out, output float out_a) {
    out = color(mx_remap1(in_.r, inlow.r, inhigh.r, outlow.r, outhigh.r), mx_remap1(in_.g, inlow.g, inhigh.g, outlow.g, outhigh.g), mx_remap1(in_.b, inlow.b, inhigh.b, outlow.b, outhigh.b));
    out_a = mx_remap1(in_a, inlow_a, inhigh_a, outlow_a, outhigh_a);
}
shader mx_smoothstep_color4(color in_ = color(0.0), float in_a = 0.0, color low = color(0.0), float low_a = 0.0,
                          color high = color(1.0), float high_a = 1.0, output color out, output float out_a) {
    out = color(mx_smoothstep1(in_.r, low.r, high.r), mx_smoothstep1(in_.g, low.g, high.g), mx_smoothstep1(in_.b, low.b, high.b));
    out_a = mx_smoothstep1(in_a, low_a, high_a);
}
shader mx_mincomponent_color4(color in_ = color(0.0), float in_a = 0.0, output float out) {
    out = min(min(in_.r, in_.g), min(in_.b, in_a));
}
shader mx_maxcomponent_color4(color in_ = color(0.0), float in_a = 0.0, output float out) {
    out = max(max(in_.r, in_.g), max(in_.b, in_a));
}
shader mx_dotproduct_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0, output float out) {
    out = in1.r * in2.r + in1.g * in2.g + in1.b * in2.b + in1_a * in2_a;
}
shader mx_magnitude_color4(color in_ = color(0.0), float in_a = 0.0, output float out) {
    out = sqrt(in_.r * in_.r + in_.g * in_.g + in_.b * in_.b + in_a * in_a);
}
shader mx_distance_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0, output float out) {
    color d = in1 - in2;
    float w = in1_a - in2_a;
    out = sqrt(d.r * d.r + d.g * d.g + d.b * d.b + w * w);
}
shader mx_normalize_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    float m = sqrt(in_.r * in_.r + in_.g * in_.g + in_.b * in_.b + in_a * in_a);
    out = m > 0.0 ? in_ * (1.0 / m) : color(0.0);
    out_a = m > 0.0 ? in_a / m : 0.0;
}

// ---- adjustment: the colour channels as color3; alpha passes through ------------------------
shader mx_luminance_color4(color in_ = color(0.0), float in_a = 0.0, color lumacoeffs = color(0.2722287, 0.6740818, 0.0536895),
                           output color out, output float out_a) {
    out = color(in_.r * lumacoeffs.r + in_.g * lumacoeffs.g + in_.b * lumacoeffs.b);
    out_a = in_a;
}
shader mx_rgbtohsv_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = mx_rgb_to_hsv(in_);
    out_a = in_a;
}
shader mx_hsvtorgb_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = mx_hsv_to_rgb(in_);
    out_a = in_a;
}
shader mx_hsvadjust_color4(color in_ = color(0.0), float in_a = 0.0, color amount = color(0.0, 1.0, 1.0), output color out,
                           output float out_a) {
    color hsv = mx_rgb_to_hsv(in_);
    out = mx_hsv_to_rgb(color(hsv.r + amount.r, hsv.g * amount.g, hsv.b * amount.b));
    out_a = in_a;
}

// ---- compositing: mix, the blend nodes (alpha blends like a colour channel) -----------------
// mix: fg · mix + bg · (1 − mix); `mix` a float (which fills all four channels) or a color4.
shader mx_mix_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, color mix = color(0.0),
                     float mix_a = 0.0, output color out, output float out_a) {
    out = fg * mix + bg * (color(1.0) - mix);
    out_a = fg_a * mix_a + bg_a * (1.0 - mix_a);
}
shader mx_plus_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = color(mix * (fg.r + bg.r) + (1.0 - mix) * bg.r, mix * (fg.g + bg.g) + (1.0 - mix) * bg.g, mix * (fg.b + bg.b) + (1.0 - mix) * bg.b);
    out_a = mix * (fg_a + bg_a) + (1.0 - mix) * bg_a;
}
shader mx_minus_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = color(mix * (bg.r - fg.r) + (1.0 - mix) * bg.r, mix * (bg.g - fg.g) + (1.0 - mix) * bg.g, mix * (bg.b - fg.b) + (1.0 - mix) * bg.b);
    out_a = mix * (bg_a - fg_a) + (1.0 - mix) * bg_a;
}
shader mx_difference_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = color(mix * abs(bg.r - fg.r) + (1.0 - mix) * bg.r, mix * abs(bg.g - fg.g) + (1.0 - mix) * bg.g, mix * abs(bg.b - fg.b) + (1.0 - mix) * bg.b);
    out_a = mix * abs(bg_a - fg_a) + (1.0 - mix) * bg_a;
}
shader mx_screen_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = color(mix * (1.0 - (1.0 - fg.r) * (1.0 - bg.r)) + (1.0 - mix) * bg.r, mix * (1.0 - (1.0 - fg.g) * (1.0 - bg.g)) + (1.0 - mix) * bg.g, mix * (1.0 - (1.0 - fg.b) * (1.0 - bg.b)) + (1.0 - mix) * bg.b);
    out_a = mix * (1.0 - (1.0 - fg_a) * (1.0 - bg_a)) + (1.0 - mix) * bg_a;
}
shader mx_burn_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = color(mx_burn1(fg.r, bg.r, mix), mx_burn1(fg.g, bg.g, mix), mx_burn1(fg.b, bg.b, mix));
    out_a = mx_burn1(fg_a, bg_a, mix);
}
shader mx_dodge_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = color(mx_dodge1(fg.r, bg.r, mix), mx_dodge1(fg.g, bg.g, mix), mx_dodge1(fg.b, bg.b, mix));
    out_a = mx_dodge1(fg_a, bg_a, mix);
}
shader mx_inside_color4(color in_ = color(0.0), float in_a = 0.0, float mask = 1.0, output color out, output float out_a) {
    out = in_ * mask;
    out_a = in_a * mask;
}
shader mx_outside_color4(color in_ = color(0.0), float in_a = 0.0, float mask = 0.0, output color out, output float out_a) {
    out = in_ * (1.0 - mask);
    out_a = in_a * (1.0 - mask);
}

// ---- compositing by alpha (Porter–Duff; f, b the alphas of fg and bg; each mixed over bg by
// `mix`); premult and unpremult ----------------------------------------------------------------
// over: F + B (1 − f); in: F b; out: F (1 − b); mask: B f; matte: F f + B (1 − f), alpha
// f + b (1 − f). As weights on fg and bg, alpha the same weights on f and b but for matte.
shader mx_over_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = mix * (fg + bg * (1.0 - fg_a)) + (1.0 - mix) * bg;
    out_a = mix * (fg_a + bg_a * (1.0 - fg_a)) + (1.0 - mix) * bg_a;
}
shader mx_in_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                    output color out, output float out_a) {
    out = mix * fg * bg_a + (1.0 - mix) * bg;
    out_a = mix * fg_a * bg_a + (1.0 - mix) * bg_a;
}
shader mx_out_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                     output color out, output float out_a) {
    out = mix * fg * (1.0 - bg_a) + (1.0 - mix) * bg;
    out_a = mix * fg_a * (1.0 - bg_a) + (1.0 - mix) * bg_a;
}
shader mx_mask_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                      output color out, output float out_a) {
    out = mix * bg * fg_a + (1.0 - mix) * bg;
    out_a = mix * bg_a * fg_a + (1.0 - mix) * bg_a;
}
shader mx_matte_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                       output color out, output float out_a) {
    out = mix * (fg * fg_a + bg * (1.0 - fg_a)) + (1.0 - mix) * bg;
    out_a = mix * (fg_a + bg_a * (1.0 - fg_a)) + (1.0 - mix) * bg_a;
}
// disjointover: F + B when f + b <= 1, else F + B (1 − f) / b; alpha min(f + b, 1).
shader mx_disjointover_color4(color fg = color(0.0), float fg_a = 0.0, color bg = color(0.0), float bg_a = 0.0, float mix = 1.0,
                              output color out, output float out_a) {
    float weight = fg_a + bg_a <= 1.0 ? 1.0 : (bg_a != 0.0 ? (1.0 - fg_a) / bg_a : 0.0);
    out = mix * (fg + bg * weight) + (1.0 - mix) * bg;
    out_a = mix * min(fg_a + bg_a, 1.0) + (1.0 - mix) * bg_a;
}
// premult: RGB · alpha; unpremult: RGB / alpha, `in` unchanged when alpha is 0.
shader mx_premult_color4(color in_ = color(0.0), float in_a = 1.0, output color out, output float out_a) {
    out = in_ * in_a;
    out_a = in_a;
}
shader mx_unpremult_color4(color in_ = color(0.0), float in_a = 1.0, output color out, output float out_a) {
    out = in_a != 0.0 ? in_ * (1.0 / in_a) : in_;
    out_a = in_a;
}

// ---- conditionals --------------------------------------------------------------------------
shader mx_ifgreater_color4(float value1 = 1.0, float value2 = 0.0, color in1 = color(0.0), float in1_a = 0.0,
                           color in2 = color(0.0), float in2_a = 0.0, output color out, output float out_a) {
    out = value1 > value2 ? in1 : in2;
    out_a = value1 > value2 ? in1_a : in2_a;
}
shader mx_ifgreatereq_color4(float value1 = 1.0, float value2 = 0.0, color in1 = color(0.0), float in1_a = 0.0,
                             color in2 = color(0.0), float in2_a = 0.0, output color out, output float out_a) {
    out = value1 >= value2 ? in1 : in2;
    out_a = value1 >= value2 ? in1_a : in2_a;
}
shader mx_ifequal_color4(float value1 = 0.0, float value2 = 0.0, color in1 = color(0.0), float in1_a = 0.0,
                         color in2 = color(0.0), float in2_a = 0.0, output color out, output float out_a) {
    out = value1 == value2 ? in1 : in2;
    out_a = value1 == value2 ? in1_a : in2_a;
}
shader mx_switch_color4(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0,
                        color in3 = color(0.0), float in3_a = 0.0, color in4 = color(0.0), float in4_a = 0.0,
                        color in5 = color(0.0), float in5_a = 0.0, color in6 = color(0.0), float in6_a = 0.0,
                        color in7 = color(0.0), float in7_a = 0.0, color in8 = color(0.0), float in8_a = 0.0,
                        color in9 = color(0.0), float in9_a = 0.0, color in10 = color(0.0), float in10_a = 0.0,
                        float which = 0.0, output color out, output float out_a) {
    int w = int(floor(which));
    out = mx_pick_color(w, in1, in2, in3, in4, in5, in6, in7, in8, in9, in10);
    out_a = mx_pick_float(w, in1_a, in2_a, in3_a, in4_a, in5_a, in6_a, in7_a, in8_a, in9_a, in10_a);
}

// ---- channels --------------------------------------------------------------------------------
shader mx_constant_color4(color value = color(0.0), float value_a = 0.0, output color out, output float out_a) {
    out = value;
    out_a = value_a;
}
shader mx_dot_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = in_;
    out_a = in_a;
}
shader mx_extract_color4(color in_ = color(0.0), float in_a = 0.0, int index = 0, output float out) {
    out = index <= 0 ? in_.r : (index == 1 ? in_.g : (index == 2 ? in_.b : in_a));
}
shader mx_separate4_color4(color in_ = color(0.0), float in_a = 0.0, output float outr, output float outg, output float outb,
                           output float outa, output float outx, output float outy, output float outz, output float outw) {
    outr = in_.r;
    outg = in_.g;
    outb = in_.b;
    outa = in_a;
    outx = in_.r;
    outy = in_.g;
    outz = in_.b;
    outw = in_a;
}
shader mx_combine4_color4(float in1 = 0.0, float in2 = 0.0, float in3 = 0.0, float in4 = 0.0, output color out, output float out_a) {
    out = color(in1, in2, in3);
    out_a = in4;
}
// combine2 of a colour (or vector3) and a float (color4CF, vector4VF), or of two vector2s (VV).
shader mx_combine2_color4(color in1 = color(0.0), float in2 = 0.0, output color out, output float out_a) {
    out = in1;
    out_a = in2;
}
shader mx_combine2_vector4VV(color in1 = color(0.0), color in2 = color(0.0), output color out, output float out_a) {
    out = color(in1.r, in1.g, in2.r);
    out_a = in2.g;
}
// convert: a float fills the four channels; a triple gains alpha (w) 1 (a vector2 z 0, as its
// own conversion to a triple); a color4 drops it (to a vector2, z too); color4 ⇄ vector4 is
// the identity.
shader mx_convert_float_color4(float in_ = 0.0, output color out, output float out_a) {
    out = color(in_);
    out_a = in_;
}
shader mx_convert_color3_color4(color in_ = color(0.0), output color out, output float out_a) {
    out = in_;
    out_a = 1.0;
}
shader mx_convert_color4_color3(color in_ = color(0.0), float in_a = 0.0, output color out) { out = in_; }
shader mx_convert_color4_vector2(color in_ = color(0.0), float in_a = 0.0, output color out) { out = color(in_.r, in_.g, 0.0); }
shader mx_convert_color4_color4(color in_ = color(0.0), float in_a = 0.0, output color out, output float out_a) {
    out = in_;
    out_a = in_a;
}

// ---- geometry ----------------------------------------------------------------------------------
// geompropvalue: a 4-component primvar (color4f, float4), its fourth component the alpha (a
// primvar with fewer components reads 0 there); `default` with its fourth where the prim has
// none.
shader mx_geompropvalue_color4(string geomprop = "", color default_ = color(0.0), float default_a = 0.0, output color out,
                               output float out_a) {
    out = primvar(geomprop, default_);
    out_a = primvar_alpha(geomprop, default_a);
}

// ---- textures and ramps ----------------------------------------------------------------------
// image and tiledimage: the fourth channel is the file's alpha (1 for a file without one);
// `default` (with its fourth channel) outside the image in `constant` mode and for no file.
float mx_image_alpha(string file, string decode, float s, float t, string uaddressmode, string vaddressmode, float fallback) {
    int outside = (uaddressmode == "constant" && (s < 0.0 || s > 1.0)) || (vaddressmode == "constant" && (t < 0.0 || t > 1.0))
                      ? 1 : 0;
    if (file == "" || outside == 1) {
        return fallback;
    }
    return texture_channel(file, decode, s, t, 16 * mx_address_code(uaddressmode) + 256 * mx_address_code(vaddressmode) + 3);
}
shader mx_image_color4(string file = "", string decode = "raw", string colorspace = "", string layer = "",
                       color default_ = color(0.0), float default_a = 0.0, color texcoord = color(u, v, 0.0),
                       string uaddressmode = "periodic", string vaddressmode = "periodic", string filtertype = "linear",
                       output color out, output float out_a) {
    out = mx_image_lookup(file, decode, colorspace, texcoord.r, texcoord.g, uaddressmode, vaddressmode, default_);
    out_a = mx_image_alpha(file, decode, texcoord.r, texcoord.g, uaddressmode, vaddressmode, default_a);
}
shader mx_tiledimage_color4(string file = "", string decode = "raw", string colorspace = "", color default_ = color(0.0),
                            float default_a = 0.0, color texcoord = color(u, v, 0.0), color uvtiling = color(1.0, 1.0, 0.0),
                            color uvoffset = color(0.0), string filtertype = "linear", output color out, output float out_a) {
    float s = texcoord.r * uvtiling.r - uvoffset.r;
    float t = texcoord.g * uvtiling.g - uvoffset.g;
    out = mx_image_lookup(file, decode, colorspace, s, t, "periodic", "periodic", default_);
    out_a = mx_image_alpha(file, decode, s, t, "periodic", "periodic", default_a);
}
shader mx_ramplr_color4(color valuel = color(0.0), float valuel_a = 0.0, color valuer = color(0.0), float valuer_a = 0.0,
                        color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    out = mix(valuel, valuer, clamp(texcoord.r, 0.0, 1.0));
    out_a = mix(valuel_a, valuer_a, clamp(texcoord.r, 0.0, 1.0));
}
shader mx_ramptb_color4(color valuet = color(0.0), float valuet_a = 0.0, color valueb = color(0.0), float valueb_a = 0.0,
                        color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    out = mix(valueb, valuet, clamp(texcoord.g, 0.0, 1.0));
    out_a = mix(valueb_a, valuet_a, clamp(texcoord.g, 0.0, 1.0));
}
shader mx_splitlr_color4(color valuel = color(0.0), float valuel_a = 0.0, color valuer = color(0.0), float valuer_a = 0.0,
                         float center = 0.5, color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    out = texcoord.r < center ? valuel : valuer;
    out_a = texcoord.r < center ? valuel_a : valuer_a;
}
shader mx_splittb_color4(color valuet = color(0.0), float valuet_a = 0.0, color valueb = color(0.0), float valueb_a = 0.0,
                         float center = 0.5, color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    out = texcoord.g < center ? valueb : valuet;
    out_a = texcoord.g < center ? valueb_a : valuet_a;
}
