#!/usr/bin/env python3
"""Writes tests/fixtures/mtlx/node_values.txt: MaterialX standard nodes at sample points with the
values a second, independent implementation gives, for `cargo test --release --test mtlx
node_values`. Each line is one case, tab-separated:

  node id    USDA input lines (joined by ' ; ')    expected r g b [a]    tolerance    where from

The references, none of them strata's code:
  rgbtohsv, hsvtorgb, hsvadjust   Python's colorsys (the hexcone model the specification names)
  blackbody                       Planck's law integrated against the CIE 1931 2° colour-matching
                                  functions (Mitsuba 3's tables, 360-830 nm in 0.5 nm steps),
                                  normalised to Y = 1 and taken to linear Rec.709 by the matrix
                                  numpy derives from the Rec.709 primaries and D65; the tolerance
                                  is the error of Kang et al.'s (2002) fit that strata evaluates
                                  (at most 5.4e-4 in xy, 5.4e-3 in Rec.709, 1667-25000 K)
  mincomponent, maxcomponent      min/max over the type's components
  color4/vector4 variants         numpy on 4-vectors (the specification's formulas; the alpha
                                  compositing nodes Porter and Duff's operators as the
                                  specification tabulates them); the fourth expected value is
                                  the fourth channel, which the test reads through a connection
  *I, *B conditionals, switch     the comparison and the selection, exactly (integers past 2^24)
  ramp4                           numpy's bilinear interpolation of the four corners
  circle, cloverleaf, hexagon     the shapes by their geometry (the hexagon as a polygon through
  tiled*                          its six corners), tilings by brute force over every centre of
                                  the lattice within reach

Usage: /work/venv/bin/python tools/make_mtlx_node_values.py  (numpy, mitsuba)
"""

import colorsys
import math
import os

import numpy as np

OUT = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "mtlx", "node_values.txt")


def f2(x, y):
    return f"({x}, {y})"


def f3(c):
    return "(" + ", ".join(repr(float(v)) for v in c) + ")"


cases = []


def case(node, inputs, want, tol, source):
    cases.append((node, " ; ".join(inputs), " ".join(f"{float(v):.7g}" for v in want), f"{tol:g}", source))


# ---- HSV --------------------------------------------------------------------------------------
for rgb in [(0.8, 0.4, 0.2), (0.1, 0.5, 0.3), (0.2, 0.3, 0.9), (0.9, 0.1, 0.6), (0.5, 0.5, 0.5), (0.0, 0.0, 0.0)]:
    case("ND_rgbtohsv_color3", [f"color3f inputs:in = {f3(rgb)}"], colorsys.rgb_to_hsv(*rgb), 1e-5, "colorsys")
for hsv in [(0.05, 0.7, 0.9), (0.3, 0.5, 0.6), (0.55, 0.8, 0.4), (0.7, 0.3, 1.0), (0.95, 1.0, 0.5), (0.5, 0.0, 0.3),
            (1.25, 0.5, 0.8)]:
    case("ND_hsvtorgb_color3", [f"color3f inputs:in = {f3(hsv)}"], colorsys.hsv_to_rgb(*hsv), 1e-5, "colorsys")
for rgb, amount in [((0.8, 0.4, 0.2), (0.25, 0.5, 1.2)), ((0.1, 0.5, 0.3), (-0.4, 1.5, 0.5))]:
    h, s, v = colorsys.rgb_to_hsv(*rgb)
    want = colorsys.hsv_to_rgb((h + amount[0]) % 1.0, s * amount[1], v * amount[2])
    case("ND_hsvadjust_color3", [f"color3f inputs:in = {f3(rgb)}", f"float3 inputs:amount = {f3(amount)}"], want, 1e-5,
         "colorsys")

# ---- blackbody --------------------------------------------------------------------------------


def rec709_from_xyz():
    """XYZ to linear Rec.709, from the primaries and the D65 white point."""
    prim = {"r": (0.64, 0.33), "g": (0.30, 0.60), "b": (0.15, 0.06)}
    white = (0.3127, 0.3290)
    xyz = lambda x, y: np.array([x / y, 1.0, (1 - x - y) / y])
    m = np.stack([xyz(*prim[k]) for k in "rgb"], axis=1)
    scale = np.linalg.solve(m, xyz(*white))
    return np.linalg.inv(m * scale)


def planck_xyz(t):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    total = np.zeros(3)
    for lam in np.arange(360.0, 830.0 + 1e-9, 0.5):
        m = lam * 1e-9
        radiance = 2 * h * c * c / m**5 / math.expm1(h * c / (m * k * t))
        total += radiance * np.array(mi.cie1931_xyz(float(lam)))
    return total / total[1]


to709 = rec709_from_xyz()
for t in [1800.0, 2500.0, 3500.0, 5000.0, 6500.0, 10000.0, 20000.0]:
    rgb = np.maximum(to709 @ planck_xyz(t), 0.0)
    case("ND_blackbody", [f"float inputs:temperature = {t}"], rgb, 6e-3, "Planck x CIE 1931")

# ---- component min/max --------------------------------------------------------------------------
case("ND_mincomponent_vector3", ["float3 inputs:in = (0.3, 0.2, 0.7)"], [0.2] * 3, 1e-6, "min")
case("ND_maxcomponent_color3", ["color3f inputs:in = (0.3, 0.7, 0.9)"], [0.9] * 3, 1e-6, "max")
# A vector2's z (0 in strata's triple) is not a component.
case("ND_mincomponent_vector2", ["float2 inputs:in = (0.3, 0.6)"], [0.3] * 3, 1e-6, "min")
case("ND_maxcomponent_vector2", ["float2 inputs:in = (0.3, 0.6)"], [0.6] * 3, 1e-6, "max")

# ---- color4 / vector4 ---------------------------------------------------------------------------
# Four expected values: the fourth (alpha, w) is read through a connection (the test extracts
# channel 3 downstream). numpy evaluates the specification's formulas on 4-vectors; the
# compositing nodes are Porter and Duff's operators as the specification tabulates them.


def f4(c):
    return "(" + ", ".join(repr(float(v)) for v in c) + ")"


def v4(c):
    return np.array(c, dtype=np.float64)


A, B = v4([0.2, -0.5, 1.5, 0.4]), v4([0.7, 0.25, -2.0, 0.8])
P4 = v4([0.8, 0.4, 0.3, 0.6])
# No ties for round (0.5 rounds either way by the specification); ln of both signs. (The
# emission the test reads is none when no channel of it is positive: every case has one.)
R, L4 = v4([0.2, -0.7, 1.3, 0.4]), v4([0.8, 1.5, 2.0, 0.6])
for node, want in [("add", A + B), ("subtract", A - B), ("multiply", A * B), ("divide", A / B),
                   ("modulo", A - B * np.floor(A / B)), ("min", np.minimum(A, B)), ("max", np.maximum(A, B)),
                   ("safepower", np.sign(A) * np.abs(A) ** B), ("atan2", np.arctan2(A, B))]:
    for ty, usd in [("color4", "color4f"), ("vector4", "float4")]:
        names = ("iny", "inx") if node == "atan2" else ("in1", "in2")
        case(f"ND_{node}_{ty}", [f"{usd} inputs:{names[0]} = {f4(A)}", f"{usd} inputs:{names[1]} = {f4(B)}"], want, 1e-5,
             "numpy")
# FA variants: the float fills all four channels.
case("ND_add_vector4FA", [f"float4 inputs:in1 = {f4(A)}", "float inputs:in2 = 0.3"], A + 0.3, 1e-6, "numpy")
case("ND_multiply_color4FA", [f"color4f inputs:in1 = {f4(A)}", "float inputs:in2 = 2.5"], A * 2.5, 1e-6, "numpy")
case("ND_power_color4", [f"color4f inputs:in1 = {f4(P4)}", f"color4f inputs:in2 = {f4(B)}"], P4 ** B, 1e-5, "numpy")
for node, fn in [("absval", np.abs), ("sign", np.sign), ("floor", np.floor), ("ceil", np.ceil), ("round", np.round),
                 ("fract", lambda x: x - np.floor(x)), ("sqrt", lambda x: np.sqrt(np.maximum(x, 0))),
                 ("exp", np.exp), ("sin", np.sin), ("cos", np.cos), ("tan", np.tan),
                 ("asin", lambda x: np.arcsin(np.clip(x, -1, 1))), ("acos", lambda x: np.arccos(np.clip(x, -1, 1)))]:
    case(f"ND_{node}_vector4", [f"float4 inputs:in = {f4(R)}"], fn(R), 1e-5, "numpy")
case("ND_ln_vector4", [f"float4 inputs:in = {f4(L4)}"], np.log(L4), 1e-5, "numpy")
LOW, HIGH = v4([0.0, -0.2, 0.5, 0.5]), v4([0.5, 0.0, 1.0, 1.0])
case("ND_clamp_color4", [f"color4f inputs:in = {f4(A)}", f"color4f inputs:low = {f4(LOW)}", f"color4f inputs:high = {f4(HIGH)}"],
     np.minimum(np.maximum(A, LOW), HIGH), 1e-6, "numpy")
case("ND_clamp_vector4FA", [f"float4 inputs:in = {f4(A)}", "float inputs:low = 0.3", "float inputs:high = 0.6"],
     np.clip(A, 0.3, 0.6), 1e-6, "numpy")
case("ND_invert_vector4", [f"float4 inputs:in = {f4(A)}"], 1.0 - A, 1e-6, "numpy")
case("ND_invert_color4FA", [f"color4f inputs:in = {f4(A)}", "float inputs:amount = 2.0"], 2.0 - A, 1e-6, "numpy")
OL, OH = v4([1.0, 0.0, -1.0, 2.0]), v4([2.0, 4.0, 1.0, 3.0])
case("ND_remap_color4", [f"color4f inputs:in = {f4(A)}", f"color4f inputs:inlow = {f4(LOW)}", f"color4f inputs:inhigh = {f4(HIGH)}",
                         f"color4f inputs:outlow = {f4(OL)}", f"color4f inputs:outhigh = {f4(OH)}"],
     OL + (A - LOW) * (OH - OL) / (HIGH - LOW), 1e-5, "numpy")


def smoothstep(x, lo, hi):
    t = np.clip((x - lo) / (hi - lo), 0, 1)
    return t * t * (3 - 2 * t)


X = v4([0.1, 0.3, 0.45, 0.9])
case("ND_smoothstep_vector4", [f"float4 inputs:in = {f4(X)}", "float4 inputs:low = (0.0, 0.2, 0.4, 0.6)",
                               "float4 inputs:high = (0.5, 0.6, 0.5, 1.0)"],
     smoothstep(X, v4([0, 0.2, 0.4, 0.6]), v4([0.5, 0.6, 0.5, 1.0])), 1e-5, "numpy")
case("ND_smoothstep_color4FA", [f"color4f inputs:in = {f4(X)}", "float inputs:low = 0.2", "float inputs:high = 0.8"],
     smoothstep(X, 0.2, 0.8), 1e-5, "numpy")
case("ND_mincomponent_color4", ["color4f inputs:in = (0.5, 0.3, 0.9, 0.1)"], [0.1] * 3, 1e-6, "min")
case("ND_maxcomponent_vector4", ["float4 inputs:in = (0.5, 0.3, 0.2, 0.7)"], [0.7] * 3, 1e-6, "max")
case("ND_dotproduct_vector4", [f"float4 inputs:in1 = {f4(A)}", f"float4 inputs:in2 = {f4(P4)}"], [A @ P4] * 3, 1e-5, "numpy")
case("ND_magnitude_vector4", [f"float4 inputs:in = {f4(A)}"], [np.linalg.norm(A)] * 3, 1e-5, "numpy")
case("ND_distance_vector4", [f"float4 inputs:in1 = {f4(A)}", f"float4 inputs:in2 = {f4(B)}"], [np.linalg.norm(A - B)] * 3, 1e-5,
     "numpy")
case("ND_normalize_vector4", [f"float4 inputs:in = {f4(A)}"], A / np.linalg.norm(A), 1e-6, "numpy")

# Compositing: mix and the blend nodes (alpha blends like a colour channel).
FG, BG = v4([0.9, 0.2, 0.4, 0.6]), v4([0.1, 0.5, 0.8, 0.7])
M4 = v4([0.25, 0.5, 0.75, 0.3])
case("ND_mix_color4", [f"color4f inputs:fg = {f4(FG)}", f"color4f inputs:bg = {f4(BG)}", "float inputs:mix = 0.3"],
     FG * 0.3 + BG * 0.7, 1e-6, "numpy")
case("ND_mix_vector4_vector4", [f"float4 inputs:fg = {f4(FG)}", f"float4 inputs:bg = {f4(BG)}", f"float4 inputs:mix = {f4(M4)}"],
     FG * M4 + BG * (1 - M4), 1e-6, "numpy")
blends = {
    "plus": FG + BG, "minus": BG - FG, "difference": np.abs(BG - FG), "screen": 1 - (1 - FG) * (1 - BG),
    "burn": 1 - (1 - BG) / FG, "dodge": BG / (1 - FG),
}
for node, result in blends.items():
    case(f"ND_{node}_color4", [f"color4f inputs:fg = {f4(FG)}", f"color4f inputs:bg = {f4(BG)}", "float inputs:mix = 0.6"],
         0.6 * result + 0.4 * BG, 1e-5, "numpy")
case("ND_inside_color4", [f"color4f inputs:in = {f4(FG)}", "float inputs:mask = 0.4"], FG * 0.4, 1e-6, "numpy")
case("ND_outside_color4", [f"color4f inputs:in = {f4(FG)}", "float inputs:mask = 0.4"], FG * 0.6, 1e-6, "numpy")


def porter_duff(node, F, B):
    """The specification's table: RGB and alpha of fg F over/in/... bg B (f, b their alphas)."""
    f, b = F[3], B[3]
    rgb, a = {
        "over": (F[:3] + B[:3] * (1 - f), f + b * (1 - f)),
        "in": (F[:3] * b, f * b),
        "out": (F[:3] * (1 - b), f * (1 - b)),
        "mask": (B[:3] * f, b * f),
        "matte": (F[:3] * f + B[:3] * (1 - f), f + b * (1 - f)),
        "disjointover": (F[:3] + B[:3] if f + b <= 1 else F[:3] + B[:3] * (1 - f) / b, min(f + b, 1.0)),
    }[node]
    return np.append(rgb, a)


for node in ["over", "in", "out", "mask", "matte", "disjointover"]:
    for fg, bg, mix in [(FG, BG, 1.0), (v4([0.3, 0.6, 0.2, 0.25]), v4([0.5, 0.1, 0.9, 0.5]), 0.7)]:
        want = mix * porter_duff(node, fg, bg) + (1 - mix) * bg
        case(f"ND_{node}_color4", [f"color4f inputs:fg = {f4(fg)}", f"color4f inputs:bg = {f4(bg)}", f"float inputs:mix = {mix}"],
             want, 1e-6, "Porter-Duff")
case("ND_premult_color4", [f"color4f inputs:in = {f4(FG)}"], np.append(FG[:3] * FG[3], FG[3]), 1e-6, "numpy")
case("ND_unpremult_color4", [f"color4f inputs:in = {f4(FG)}"], np.append(FG[:3] / FG[3], FG[3]), 1e-6, "numpy")
case("ND_unpremult_color4", ["color4f inputs:in = (0.3, 0.2, 0.1, 0.0)"], [0.3, 0.2, 0.1, 0.0], 1e-6,
     "specification (alpha 0: unchanged)")

# Adjustment: the colour channels as color3 (colorsys for HSV); alpha passes through.
case("ND_luminance_color4", ["color4f inputs:in = (0.8, 0.4, 0.2, 0.35)"],
     [0.8 * 0.2722287 + 0.4 * 0.6740818 + 0.2 * 0.0536895] * 3 + [0.35], 1e-6, "ACEScg luma")
case("ND_rgbtohsv_color4", ["color4f inputs:in = (0.8, 0.4, 0.2, 0.35)"], list(colorsys.rgb_to_hsv(0.8, 0.4, 0.2)) + [0.35], 1e-5,
     "colorsys")
case("ND_hsvtorgb_color4", ["color4f inputs:in = (0.3, 0.5, 0.6, 0.9)"], list(colorsys.hsv_to_rgb(0.3, 0.5, 0.6)) + [0.9], 1e-5,
     "colorsys")

# Conditionals and channels.
case("ND_ifgreater_color4", ["float inputs:value1 = 2.0", "float inputs:value2 = 1.0", f"color4f inputs:in1 = {f4(FG)}",
                             f"color4f inputs:in2 = {f4(BG)}"], FG, 0.0, "value1 > value2")
case("ND_ifgreatereq_vector4", ["float inputs:value1 = 0.5", "float inputs:value2 = 1.0", f"float4 inputs:in1 = {f4(FG)}",
                                f"float4 inputs:in2 = {f4(BG)}"], BG, 0.0, "value1 < value2")
case("ND_ifequal_color4", ["float inputs:value1 = 1.0", "float inputs:value2 = 1.0", f"color4f inputs:in1 = {f4(FG)}",
                           f"color4f inputs:in2 = {f4(BG)}"], FG, 0.0, "value1 = value2")
case("ND_switch_vector4", [f"float4 inputs:in{k + 1} = {f4(A + k)}" for k in range(5)] + ["float inputs:which = 3"], A + 3, 1e-6,
     "in4")
case("ND_constant_color4", [f"color4f inputs:value = {f4(FG)}"], FG, 0.0, "value")
case("ND_dot_vector4", [f"float4 inputs:in = {f4(A)}"], A, 0.0, "in")
for k in range(4):
    case("ND_extract_vector4", [f"float4 inputs:in = {f4(P4)}", f"int inputs:index = {k}"], [P4[k]] * 3, 0.0, f"channel {k}")
case("ND_combine4_color4", ["float inputs:in1 = 0.1", "float inputs:in2 = 0.2", "float inputs:in3 = 0.3", "float inputs:in4 = 0.4"],
     [0.1, 0.2, 0.3, 0.4], 1e-7, "channels")
case("ND_combine2_color4CF", ["color3f inputs:in1 = (0.1, 0.2, 0.3)", "float inputs:in2 = 0.4"], [0.1, 0.2, 0.3, 0.4], 1e-7,
     "channels")
case("ND_combine2_vector4VV", ["float2 inputs:in1 = (0.1, 0.2)", "float2 inputs:in2 = (0.3, 0.4)"], [0.1, 0.2, 0.3, 0.4], 1e-7,
     "channels")
case("ND_convert_float_vector4", ["float inputs:in = 0.6"], [0.6] * 4, 1e-7, "every channel")
case("ND_convert_color3_color4", ["color3f inputs:in = (0.1, 0.2, 0.3)"], [0.1, 0.2, 0.3, 1.0], 1e-7, "alpha 1")
case("ND_convert_vector2_vector4", ["float2 inputs:in = (0.1, 0.2)"], [0.1, 0.2, 0.0, 1.0], 1e-7, "z 0, w 1")
case("ND_convert_vector4_color4", [f"float4 inputs:in = {f4(A)}"], A, 1e-7, "the same channels")
case("ND_convert_color4_color3", [f"color4f inputs:in = {f4(FG)}"], FG[:3], 1e-7, "alpha dropped")
case("ND_convert_vector4_vector2", [f"float4 inputs:in = {f4(A)}"], [A[0], A[1], 0.0], 1e-7, "z and w dropped")
case("ND_ramplr_color4", [f"color4f inputs:valuel = {f4(FG)}", f"color4f inputs:valuer = {f4(BG)}",
                          "float2 inputs:texcoord = (0.3, 0.9)"], FG * 0.7 + BG * 0.3, 1e-6, "linear in u")
case("ND_splittb_vector4", [f"float4 inputs:valuet = {f4(FG)}", f"float4 inputs:valueb = {f4(BG)}",
                            "float2 inputs:texcoord = (0.3, 0.4)"], BG, 0.0, "v below the centre")

# ---- conditionals selected by an integer or a boolean; the ten-input switch; ramp4 -------------
# Integers compare exactly: 2^24 + 1 and 2^24 are one float apart from nothing, so a
# float-selected implementation gets these cases wrong.
IN1 = {"float": ("float", 0.3), "color3": ("color3f", (0.1, 0.2, 0.3)), "vector2": ("float2", (0.4, 0.5)),
       "color4": ("color4f", (0.1, 0.2, 0.3, 0.4))}
IN2 = {"float": 0.7, "color3": (0.9, 0.8, 0.7), "vector2": (0.6, 0.75), "color4": (0.9, 0.8, 0.7, 0.6)}


def usd(v):
    return repr(float(v)) if np.isscalar(v) else "(" + ", ".join(repr(float(x)) for x in v) + ")"


def rgb(v):
    """The emitted channels of a value (a float fills three; a vector2 has z = 0)."""
    if np.isscalar(v):
        return [v] * 3
    return list(v) + [0.0] if len(v) == 2 else list(v)


BIG = 1 << 24
for node, test in [("ifgreater", lambda a, b: a > b), ("ifgreatereq", lambda a, b: a >= b), ("ifequal", lambda a, b: a == b)]:
    for ty, (usd_ty, in1) in IN1.items():
        for v1, v2 in [(3, 2), (2, 2), (-1, 4), (BIG + 1, BIG)]:
            want = in1 if test(v1, v2) else IN2[ty]
            case(f"ND_{node}_{ty}I", [f"int inputs:value1 = {v1}", f"int inputs:value2 = {v2}",
                                      f"{usd_ty} inputs:in1 = {usd(in1)}", f"{usd_ty} inputs:in2 = {usd(IN2[ty])}"],
                 rgb(want), 0.0, f"{v1} vs {v2}")
for ty, (usd_ty, in1) in IN1.items():
    for b1, b2 in [(True, True), (True, False), (False, False), (False, True)]:
        want = in1 if b1 == b2 else IN2[ty]
        case(f"ND_ifequal_{ty}B", [f"bool inputs:value1 = {str(b1).lower()}", f"bool inputs:value2 = {str(b2).lower()}",
                                   f"{usd_ty} inputs:in1 = {usd(in1)}", f"{usd_ty} inputs:in2 = {usd(IN2[ty])}"],
             rgb(want), 0.0, f"{b1} vs {b2}")
# switch: input floor(which) + 1, clamped to in1..in10.
SW = {"float": ("float", lambda k: 0.05 * k), "color3": ("color3f", lambda k: (0.05 * k, 0.5, 1.0 - 0.05 * k)),
      "vector4": ("float4", lambda k: (0.05 * k, 0.25, 0.5, 0.75 - 0.05 * k))}
for ty, (usd_ty, value) in SW.items():
    inputs = [f"{usd_ty} inputs:in{k} = {usd(value(k))}" for k in range(1, 11)]
    for which in [0, 4, 7, 9, -2, 12]:
        pick = min(max(which, 0), 9) + 1
        case(f"ND_switch_{ty}I", inputs + [f"int inputs:which = {which}"], rgb(value(pick)), 1e-7, f"in{pick}")
    for which in [6.6, 9.5, -0.5]:
        pick = min(max(math.floor(which), 0), 9) + 1
        case(f"ND_switch_{ty}", inputs + [f"float inputs:which = {which}"], rgb(value(pick)), 1e-7, f"in{pick}")
# ramp4: bilinear between the corners (tl at (0, 1), tr (1, 1), bl (0, 0), br (1, 0)), the
# coordinate clamped to [0, 1].
CORNERS = {"tl": (0.9, 0.1, 0.2, 0.3), "tr": (0.2, 0.8, 0.1, 0.6), "bl": (0.1, 0.3, 0.9, 0.2), "br": (0.5, 0.5, 0.4, 1.0)}
for ty, usd_ty, n in [("float", "float", 1), ("color3", "color3f", 3), ("vector2", "float2", 2), ("vector4", "float4", 4)]:
    corner = {k: np.array(v[:n]) for k, v in CORNERS.items()}
    for uv in [(0.3, 0.8), (0.75, 0.1), (1.4, -0.2)]:
        s, t = np.clip(uv, 0.0, 1.0)
        want = (corner["bl"] * (1 - s) + corner["br"] * s) * (1 - t) + (corner["tl"] * (1 - s) + corner["tr"] * s) * t
        want = float(want[0]) if n == 1 else want
        values = [f"{usd_ty} inputs:value{k} = {usd(v[0] if n == 1 else v)}" for k, v in corner.items()]
        case(f"ND_ramp4_{ty}", values + [f"float2 inputs:texcoord = {f2(*uv)}"], rgb(want), 1e-6, "bilinear")

# ---- shapes -------------------------------------------------------------------------------------


def in_circle(d, r):
    return d[0] ** 2 + d[1] ** 2 <= r * r


def in_cloverleaf(d, r):
    # Four semicircles on the edges of the square of side r (the shape's outer radius is r).
    return any(in_circle((d[0] - cx, d[1] - cy), r / 2) for cx, cy in [(r / 2, 0), (-r / 2, 0), (0, r / 2), (0, -r / 2)]) \
        or (abs(d[0]) <= r / 2 and abs(d[1]) <= r / 2)


def in_hexagon(d, r):
    # Inner radius r, corners on the circle of radius 2r/√3 at 90° + 60° k (edges across u).
    corners = [(2 * r / math.sqrt(3) * math.cos(math.radians(90 + 60 * k)),
                2 * r / math.sqrt(3) * math.sin(math.radians(90 + 60 * k))) for k in range(6)]
    for k in range(6):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 6]
        if (bx - ax) * (d[1] - ay) - (by - ay) * (d[0] - ax) < 0:
            return False
    return True


SHAPES = {"circle": in_circle, "cloverleaf": in_cloverleaf, "hexagon": in_hexagon}


def shape_case(name, p, center, radius):
    d = (p[0] - center[0], p[1] - center[1])
    want = 1.0 if SHAPES[name](d, radius) else 0.0
    case(f"ND_{name}_float",
         [f"float2 inputs:texcoord = {f2(*p)}", f"float2 inputs:center = {f2(*center)}", f"float inputs:radius = {radius}"],
         [want] * 3, 0.0, "geometry")


for p in [(0.5, 0.5), (0.62, 0.55), (0.75, 0.5), (0.5, 0.82), (0.82, 0.5), (0.66, 0.66), (0.7, 0.6), (0.65, 0.75), (0.7, 0.75), (0.9, 0.9)]:
    for name in SHAPES:
        shape_case(name, p, (0.5, 0.5), 0.3)


def lattice(shape, staggered):
    """Shape centres of a tiling near the origin (a generous window)."""
    if not staggered:
        return [(i + 0.5, j + 0.5) for i in range(-4, 5) for j in range(-4, 5)]
    if shape == "cloverleaf":
        return [(i + 0.5, j + 0.5) for i in range(-4, 5) for j in range(-4, 5)] + \
            [(i, j) for i in range(-4, 5) for j in range(-4, 5)]
    h = math.sqrt(3) / 2
    return [(i + 0.5 * (k % 2), k * h) for i in range(-4, 5) for k in range(-6, 7)]


def tiled_case(name, texcoord, tiling, offset, size, staggered):
    p = (texcoord[0] * tiling[0] - offset[0], texcoord[1] * tiling[1] - offset[1])
    inside = any(SHAPES[name]((p[0] - cx, p[1] - cy), size / 2) for cx, cy in lattice(name, staggered))
    want = 1.0 if inside else 0.0
    case(f"ND_tiled{name}s_color3",
         [f"float2 inputs:texcoord = {f2(*texcoord)}", f"float2 inputs:uvtiling = {f2(*tiling)}",
          f"float2 inputs:uvoffset = {f2(*offset)}", f"float inputs:size = {size}",
          f"bool inputs:staggered = {'true' if staggered else 'false'}"],
         [want] * 3, 0.0, "brute force over the lattice")


for texcoord in [(0.3, 0.4), (0.1, 0.12), (0.47, 0.2), (0.8, 0.95), (0.55, 0.43), (0.02, 0.5), (0.37, 0.71), (0.64, 0.33)]:
    for name in SHAPES:
        for staggered in [False, True]:
            tiled_case(name, texcoord, (3.0, 2.0), (0.1, -0.2), 0.8, staggered)

with open(OUT, "w") as f:
    f.write("# Written by tools/make_mtlx_node_values.py: node, inputs, expected r g b [a], tolerance, reference.\n")
    for c in cases:
        f.write("\t".join(c) + "\n")
print(f"{len(cases)} cases -> {os.path.normpath(OUT)}")
