
// ---- MaterialX standard nodes beyond mtlx.ash's core set (MaterialX 1.39 Standard Nodes and
// pbrlib's blackbody): HSV conversion and adjustment, blackbody colour, component min/max,
// space transforms, the shape nodes and their tilings. Written from the specification; where
// its prose leaves a choice open, the comment says which was taken. Variants follow mtlx.ash:
// `_color3` serves color3 and vector3 (and vector2 with z = 0 where z cannot matter).

// ---- adjustment: HSV (hexcone model; H and S in [0, 1]; not affected by colour space) ------

// rgbtohsv: V = max, S = (max − min) / max (0 for black), H the hexcone angle / 360° in [0, 1)
// (0 for greys).
color mx_rgb_to_hsv(color c) {
    float hi = max(c.r, max(c.g, c.b));
    float lo = min(c.r, min(c.g, c.b));
    float range = hi - lo;
    float s = hi > 0.0 ? range / hi : 0.0;
    float h = 0.0;
    if (range > 0.0) {
        if (c.r == hi) {
            h = (c.g - c.b) / range;
        } else if (c.g == hi) {
            h = 2.0 + (c.b - c.r) / range;
        } else {
            h = 4.0 + (c.r - c.g) / range;
        }
        h = h / 6.0;
        h = h - floor(h);
    }
    return color(h, s, hi);
}
// hsvtorgb: the inverse; H wraps at the [0, 1] boundaries (as hsvadjust's hue rotation does).
color mx_hsv_to_rgb(color hsv) {
    float h = (hsv.r - floor(hsv.r)) * 6.0;
    float s = hsv.g;
    float value = hsv.b;
    float sector = floor(h);
    float f = h - sector;
    float p = value * (1.0 - s);
    float q = value * (1.0 - s * f);
    float t = value * (1.0 - s * (1.0 - f));
    int i = int(sector);
    if (i == 0) {
        return color(value, t, p);
    } else if (i == 1) {
        return color(q, value, p);
    } else if (i == 2) {
        return color(p, value, t);
    } else if (i == 3) {
        return color(p, q, value);
    } else if (i == 4) {
        return color(t, p, value);
    }
    return color(value, p, q);
}
shader mx_rgbtohsv_color3(color in_ = color(0.0), output color out) { out = mx_rgb_to_hsv(in_); }
shader mx_hsvtorgb_color3(color in_ = color(0.0), output color out) { out = mx_hsv_to_rgb(in_); }
// hsvadjust: hue + amount.x (wrapping), saturation · amount.y, value · amount.z.
shader mx_hsvadjust_color3(color in_ = color(0.0), color amount = color(0.0, 1.0, 1.0), output color out) {
    color hsv = mx_rgb_to_hsv(in_);
    out = mx_hsv_to_rgb(color(hsv.r + amount.r, hsv.g * amount.g, hsv.b * amount.b));
}

// ---- blackbody (pbrlib): the colour of a blackbody radiator at `temperature` kelvin ----------
// The specification names "the radiant emittance" without a scale; as MaterialX's renderers
// do, this is the chromaticity of Planck's law at that temperature at luminance Y = 1, in the
// working space (linear Rec.709). The chromaticity is Kang et al.'s (2002) cubic fit of the
// Planckian locus in CIE 1931 xy, defined on [1667 K, 25000 K] (the temperature is clamped to
// it); tests/fixtures/mtlx/node_values.txt holds Planck's law integrated against the CIE 1931
// tables to check it. Negative Rec.709 components (out of gamut) are 0.
color mx_blackbody(float temperature) {
    float kelvin = clamp(temperature, 1667.0, 25000.0);
    float k = 1000.0 / kelvin;
    float x = kelvin < 4000.0 ? ((-0.2661239 * k - 0.2343589) * k + 0.8776956) * k + 0.179910
                              : ((-3.0258469 * k + 2.1070379) * k + 0.2226347) * k + 0.240390;
    float y = kelvin < 2222.0 ? ((-1.1063814 * x - 1.34811020) * x + 2.18555832) * x - 0.20219683
              : (kelvin < 4000.0 ? ((-0.9549476 * x - 1.37418593) * x + 2.09137015) * x - 0.16748867
                                 : ((3.0817580 * x - 5.87338670) * x + 3.75112997) * x - 0.37001483);
    // XYZ at Y = 1 to linear Rec.709 (sRGB primaries, D65).
    float cx = x / y;
    float cz = (1.0 - x - y) / y;
    return color(max(3.2404542 * cx - 1.5371385 - 0.4985314 * cz, 0.0),
                 max(-0.9692660 * cx + 1.8760108 + 0.0415560 * cz, 0.0),
                 max(0.0556434 * cx - 0.2040259 + 1.0572252 * cz, 0.0));
}
shader mx_blackbody_color3(float temperature = 5000.0, output color out) { out = mx_blackbody(temperature); }

// ---- math: component min/max (a vector2 has its own variant: its z is not a component) -----

shader mx_mincomponent_color3(color in_ = color(0.0), output float out) { out = min(in_.r, min(in_.g, in_.b)); }
shader mx_maxcomponent_color3(color in_ = color(0.0), output float out) { out = max(in_.r, max(in_.g, in_.b)); }
shader mx_mincomponent_vector2(color in_ = color(0.0), output float out) { out = min(in_.r, in_.g); }
shader mx_maxcomponent_vector2(color in_ = color(0.0), output float out) { out = max(in_.r, in_.g); }

// ---- math: space transforms -------------------------------------------------------------------
// strata shades in world space and every space reads as world (compose reports a `fromspace`
// or `tospace` other than world or the working space ""), so a transform between the spaces it
// knows is the identity.
shader mx_transformpoint_color3(color in_ = color(0.0), string fromspace = "", string tospace = "", output color out) {
    out = in_;
}
shader mx_transformvector_color3(color in_ = color(0.0), string fromspace = "", string tospace = "", output color out) {
    out = in_;
}
shader mx_transformnormal_color3(color in_ = color(0.0, 0.0, 1.0), string fromspace = "", string tospace = "",
                                 output color out) {
    out = in_;
}

// ---- shapes: 1 inside, 0 outside (boundaries inside) --------------------------------------------

float mx_inside_circle(float dx, float dy, float radius) { return dx * dx + dy * dy <= radius * radius ? 1.0 : 0.0; }
// cloverleaf: four semicircles on the edges of a square, the whole inside the circle of
// `radius`: the square's side is `radius`, each semicircle a disc of radius / 2 about the
// middle of an edge (the discs cover the square).
float mx_inside_cloverleaf(float dx, float dy, float radius) {
    float h = 0.5 * radius;
    return max(max(mx_inside_circle(dx - h, dy, h), mx_inside_circle(dx + h, dy, h)),
               max(mx_inside_circle(dx, dy - h, h), mx_inside_circle(dx, dy + h, h)));
}
// hexagon: the regular hexagon about the circle of `radius` (its inner radius: tiledhexagons'
// `size` is the inner diameter, and hexagons of size 1 touch along U, so two edges are
// perpendicular to U and the corners point along V).
float mx_inside_hexagon(float dx, float dy, float radius) {
    float ax = abs(dx);
    return ax <= radius && 0.5 * ax + 0.8660254 * abs(dy) <= radius ? 1.0 : 0.0;
}
// Shape `shape` (0 circle, 1 cloverleaf, 2 hexagon) of `radius` about the origin at (dx, dy).
float mx_inside_shape(int shape, float dx, float dy, float radius) {
    return shape == 0 ? mx_inside_circle(dx, dy, radius)
                      : (shape == 1 ? mx_inside_cloverleaf(dx, dy, radius) : mx_inside_hexagon(dx, dy, radius));
}
shader mx_circle_float(color texcoord = color(u, v, 0.0), color center = color(0.0), float radius = 0.5, output float out) {
    out = mx_inside_circle(texcoord.r - center.r, texcoord.g - center.g, radius);
}
shader mx_cloverleaf_float(color texcoord = color(u, v, 0.0), color center = color(0.0), float radius = 0.5,
                           output float out) {
    out = mx_inside_cloverleaf(texcoord.r - center.r, texcoord.g - center.g, radius);
}
shader mx_hexagon_float(color texcoord = color(u, v, 0.0), color center = color(0.0), float radius = 0.5, output float out) {
    out = mx_inside_hexagon(texcoord.r - center.r, texcoord.g - center.g, radius);
}

// Whether p is inside the shape about the nearest centre of triangle-grid row `row` (rows
// √3/2 apart, odd rows offset by ½).
float mx_inside_row_shape(int shape, float px, float py, float row, float radius) {
    float shift = 0.5 * (row - 2.0 * floor(0.5 * row));
    float cx = floor(px - shift + 0.5) + shift;
    return mx_inside_shape(shape, px - cx, py - row * 0.8660254, radius);
}

// Tiled shapes of diameter `size` at p = texcoord · uvtiling − uvoffset. Regular: one per unit
// cell, about its centre. Staggered circles and hexagons: about the vertices of an equilateral
// triangle grid of side 1 (rows √3/2 apart, every other row offset by ½, row 0 on v = 0: the
// specification does not fix the phase; this is MaterialX's); staggered cloverleafs: the
// regular ones and as many again offset by ½ in u and v. For size ≤ 1 the nearest centres
// checked here are every centre whose shape can reach p.
float mx_tiled_shape(int shape, color texcoord, color uvtiling, color uvoffset, float size, int staggered) {
    float px = texcoord.r * uvtiling.r - uvoffset.r;
    float py = texcoord.g * uvtiling.g - uvoffset.g;
    float radius = 0.5 * size;
    if (staggered == 0) {
        return mx_inside_shape(shape, px - floor(px) - 0.5, py - floor(py) - 0.5, radius);
    }
    if (shape == 1) {
        float centred = mx_inside_shape(shape, px - floor(px) - 0.5, py - floor(py) - 0.5, radius);
        return max(centred, mx_inside_shape(shape, px - round(px), py - round(py), radius));
    }
    float row = floor(py / 0.8660254);
    return max(mx_inside_row_shape(shape, px, py, row, radius), mx_inside_row_shape(shape, px, py, row + 1.0, radius));
}
shader mx_tiledcircles_color3(color texcoord = color(u, v, 0.0), color uvtiling = color(1.0, 1.0, 0.0),
                              color uvoffset = color(0.0), float size = 0.5, int staggered = 0, output color out) {
    out = color(mx_tiled_shape(0, texcoord, uvtiling, uvoffset, size, staggered));
}
shader mx_tiledcloverleafs_color3(color texcoord = color(u, v, 0.0), color uvtiling = color(1.0, 1.0, 0.0),
                                  color uvoffset = color(0.0), float size = 0.5, int staggered = 0, output color out) {
    out = color(mx_tiled_shape(1, texcoord, uvtiling, uvoffset, size, staggered));
}
shader mx_tiledhexagons_color3(color texcoord = color(u, v, 0.0), color uvtiling = color(1.0, 1.0, 0.0),
                               color uvoffset = color(0.0), float size = 0.5, int staggered = 0, output color out) {
    out = color(mx_tiled_shape(2, texcoord, uvtiling, uvoffset, size, staggered));
}
