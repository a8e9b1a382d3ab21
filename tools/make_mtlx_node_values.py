#!/usr/bin/env python3
"""Writes tests/fixtures/mtlx/node_values.txt: MaterialX standard nodes at sample points with the
values a second, independent implementation gives, for `cargo test --release --test mtlx
node_values`. Each line is one case, tab-separated:

  node id    USDA input lines (joined by ' ; ')    expected r g b    tolerance    where from

The references, none of them strata's code:
  rgbtohsv, hsvtorgb, hsvadjust   Python's colorsys (the hexcone model the specification names)
  blackbody                       Planck's law integrated against the CIE 1931 2° colour-matching
                                  functions (Mitsuba 3's tables, 360-830 nm in 0.5 nm steps),
                                  normalised to Y = 1 and taken to linear Rec.709 by the matrix
                                  numpy derives from the Rec.709 primaries and D65; the tolerance
                                  is the error of Kang et al.'s (2002) fit that strata evaluates
                                  (at most 5.4e-4 in xy, 5.4e-3 in Rec.709, 1667-25000 K)
  mincomponent, maxcomponent      min/max over the type's components
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
    f.write("# Written by tools/make_mtlx_node_values.py: node, inputs, expected r g b, tolerance, reference.\n")
    for c in cases:
        f.write("\t".join(c) + "\n")
print(f"{len(cases)} cases -> {os.path.normpath(OUT)}")
