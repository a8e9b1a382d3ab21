
// ---- MaterialX standard nodes beyond mtlx.ash's core set (MaterialX 1.39 Standard Nodes and
// pbrlib's blackbody): HSV conversion and adjustment, blackbody colour, component min/max,
// space transforms, the shape nodes and their tilings, the conditionals selected by an integer
// or a boolean, ramp4, fractal2d and the multi-channel noise. Written from the specification; where
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
// Between world ("" is the working space, world) and object (model is read as object, and
// compose reports it) by the hit's transforms (mtlx.ash, geometry); any other space reads as
// world (reported). A normal goes by the inverse transpose and comes out normalized, as
// MaterialX's generated code does.
float mx_is_object_space(string space) { return space == "object" || space == "model" ? 1.0 : 0.0; }
shader mx_transformpoint_color3(color in_ = color(0.0), string fromspace = "", string tospace = "", output color out) {
    vector p = vector(in_);
    if (mx_is_object_space(fromspace) != mx_is_object_space(tospace)) {
        p = mx_is_object_space(fromspace) > 0.0 ? mx_object_to_world_point(p) : mx_world_to_object_point(p);
    }
    out = color(p);
}
shader mx_transformvector_color3(color in_ = color(0.0), string fromspace = "", string tospace = "", output color out) {
    vector d = vector(in_);
    if (mx_is_object_space(fromspace) != mx_is_object_space(tospace)) {
        d = mx_is_object_space(fromspace) > 0.0 ? mx_object_to_world_vector(d) : mx_world_to_object_vector(d);
    }
    out = color(d);
}
shader mx_transformnormal_color3(color in_ = color(0.0, 0.0, 1.0), string fromspace = "", string tospace = "",
                                 output color out) {
    vector n = vector(in_);
    if (mx_is_object_space(fromspace) != mx_is_object_space(tospace)) {
        n = mx_is_object_space(fromspace) > 0.0 ? mx_object_to_world_normal(n) : mx_world_to_object_normal(n);
    }
    out = color(n);
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

// ---- conditionals selected by an integer or a boolean ----------------------------------------
// `ND_<node>_<type>I` compares integer `value1` and `value2` (`switch`: an integer `which`),
// `ND_ifequal_<type>B` booleans, which travel as integers 0 and 1 (`compose::mtlx` names the `I`
// variant for both). Defaults as the specification's node definitions: ifgreater and
// ifgreatereq 1 and 0, ifequal 0 and 0 (false and false).
shader mx_ifgreater_floatI(int value1 = 1, int value2 = 0, float in1 = 0.0, float in2 = 0.0, output float out) {
    out = value1 > value2 ? in1 : in2;
}
shader mx_ifgreater_color3I(int value1 = 1, int value2 = 0, color in1 = color(0.0), color in2 = color(0.0), output color out) {
    out = value1 > value2 ? in1 : in2;
}
shader mx_ifgreater_color4I(int value1 = 1, int value2 = 0, color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0),
                            float in2_a = 0.0, output color out, output float out_a) {
    out = value1 > value2 ? in1 : in2;
    out_a = value1 > value2 ? in1_a : in2_a;
}
shader mx_ifgreatereq_floatI(int value1 = 1, int value2 = 0, float in1 = 0.0, float in2 = 0.0, output float out) {
    out = value1 >= value2 ? in1 : in2;
}
shader mx_ifgreatereq_color3I(int value1 = 1, int value2 = 0, color in1 = color(0.0), color in2 = color(0.0),
                              output color out) {
    out = value1 >= value2 ? in1 : in2;
}
shader mx_ifgreatereq_color4I(int value1 = 1, int value2 = 0, color in1 = color(0.0), float in1_a = 0.0,
                              color in2 = color(0.0), float in2_a = 0.0, output color out, output float out_a) {
    out = value1 >= value2 ? in1 : in2;
    out_a = value1 >= value2 ? in1_a : in2_a;
}
shader mx_ifequal_floatI(int value1 = 0, int value2 = 0, float in1 = 0.0, float in2 = 0.0, output float out) {
    out = value1 == value2 ? in1 : in2;
}
shader mx_ifequal_color3I(int value1 = 0, int value2 = 0, color in1 = color(0.0), color in2 = color(0.0), output color out) {
    out = value1 == value2 ? in1 : in2;
}
shader mx_ifequal_color4I(int value1 = 0, int value2 = 0, color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0),
                          float in2_a = 0.0, output color out, output float out_a) {
    out = value1 == value2 ? in1 : in2;
    out_a = value1 == value2 ? in1_a : in2_a;
}
shader mx_switch_floatI(float in1 = 0.0, float in2 = 0.0, float in3 = 0.0, float in4 = 0.0, float in5 = 0.0, float in6 = 0.0,
                        float in7 = 0.0, float in8 = 0.0, float in9 = 0.0, float in10 = 0.0, int which = 0,
                        output float out) {
    out = mx_pick_float(which, in1, in2, in3, in4, in5, in6, in7, in8, in9, in10);
}
shader mx_switch_color3I(color in1 = color(0.0), color in2 = color(0.0), color in3 = color(0.0), color in4 = color(0.0),
                         color in5 = color(0.0), color in6 = color(0.0), color in7 = color(0.0), color in8 = color(0.0),
                         color in9 = color(0.0), color in10 = color(0.0), int which = 0, output color out) {
    out = mx_pick_color(which, in1, in2, in3, in4, in5, in6, in7, in8, in9, in10);
}
shader mx_switch_color4I(color in1 = color(0.0), float in1_a = 0.0, color in2 = color(0.0), float in2_a = 0.0,
                         color in3 = color(0.0), float in3_a = 0.0, color in4 = color(0.0), float in4_a = 0.0,
                         color in5 = color(0.0), float in5_a = 0.0, color in6 = color(0.0), float in6_a = 0.0,
                         color in7 = color(0.0), float in7_a = 0.0, color in8 = color(0.0), float in8_a = 0.0,
                         color in9 = color(0.0), float in9_a = 0.0, color in10 = color(0.0), float in10_a = 0.0,
                         int which = 0, output color out, output float out_a) {
    out = mx_pick_color(which, in1, in2, in3, in4, in5, in6, in7, in8, in9, in10);
    out_a = mx_pick_float(which, in1_a, in2_a, in3_a, in4_a, in5_a, in6_a, in7_a, in8_a, in9_a, in10_a);
}

// ---- ramp4: bilinear between the four corners (tl at U = 0, V = 1; br at U = 1, V = 0) ------
// The texture coordinate is clamped to [0, 1], as ramplr's and ramptb's.
shader mx_ramp4_float(float valuetl = 0.0, float valuetr = 0.0, float valuebl = 0.0, float valuebr = 0.0,
                      color texcoord = color(u, v, 0.0), output float out) {
    float s = clamp(texcoord.r, 0.0, 1.0);
    out = mix(mix(valuebl, valuebr, s), mix(valuetl, valuetr, s), clamp(texcoord.g, 0.0, 1.0));
}
shader mx_ramp4_color3(color valuetl = color(0.0), color valuetr = color(0.0), color valuebl = color(0.0),
                       color valuebr = color(0.0), color texcoord = color(u, v, 0.0), output color out) {
    float s = clamp(texcoord.r, 0.0, 1.0);
    out = mix(mix(valuebl, valuebr, s), mix(valuetl, valuetr, s), clamp(texcoord.g, 0.0, 1.0));
}
shader mx_ramp4_color4(color valuetl = color(0.0), float valuetl_a = 0.0, color valuetr = color(0.0), float valuetr_a = 0.0,
                       color valuebl = color(0.0), float valuebl_a = 0.0, color valuebr = color(0.0), float valuebr_a = 0.0,
                       color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    float s = clamp(texcoord.r, 0.0, 1.0);
    float t = clamp(texcoord.g, 0.0, 1.0);
    out = mix(mix(valuebl, valuebr, s), mix(valuetl, valuetr, s), t);
    out_a = mix(mix(valuebl_a, valuebr_a, s), mix(valuetl_a, valuetr_a, s), t);
}

// ---- noise: fractal2d and the multi-channel variants ------------------------------------------
// Each channel is the float node's noise (signed Perlin `snoise`) at an offset point: the
// colour channels at the offsets noise2d_color3 and noise3d_color3 use, the fourth channel of
// a color4/vector4 where MaterialX's definitions put it: noise2d at (19, 73), noise3d at
// (19, 73, 29), fractal2d at (19, 193), fractal3d at (19, 193, 17). A fractal channel is the
// float fractal (`mx_fractal`, mtlx.ash) at the offset point.
shader mx_noise2d_color4(color amplitude = color(1.0), float amplitude_a = 1.0, float pivot = 0.0,
                         color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    point p = point(texcoord.r, texcoord.g, 0.0);
    out = color(snoise(p), snoise(p + point(19.1, 7.3, 0.0)), snoise(p + point(3.7, 41.9, 0.0))) * amplitude + color(pivot);
    out_a = snoise(p + point(19.0, 73.0, 0.0)) * amplitude_a + pivot;
}
shader mx_noise3d_color4(color amplitude = color(1.0), float amplitude_a = 1.0, float pivot = 0.0, color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))),
                         output color out, output float out_a) {
    point p = point(position);
    out = color(snoise(p), snoise(p + point(19.1, 7.3, 5.2)), snoise(p + point(3.7, 41.9, 13.3))) * amplitude + color(pivot);
    out_a = snoise(p + point(19.0, 73.0, 29.0)) * amplitude_a + pivot;
}
shader mx_fractal2d_float(float amplitude = 1.0, int octaves = 3, float lacunarity = 2.0, float diminish = 0.5,
                          color texcoord = color(u, v, 0.0), output float out) {
    out = mx_fractal(point(texcoord.r, texcoord.g, 0.0), octaves, lacunarity, diminish) * amplitude;
}
color mx_fractal2d(color texcoord, int octaves, float lacunarity, float diminish) {
    point p = point(texcoord.r, texcoord.g, 0.0);
    return color(mx_fractal(p, octaves, lacunarity, diminish), mx_fractal(p + point(19.1, 7.3, 0.0), octaves, lacunarity, diminish),
                 mx_fractal(p + point(3.7, 41.9, 0.0), octaves, lacunarity, diminish));
}
shader mx_fractal2d_color3(color amplitude = color(1.0), int octaves = 3, float lacunarity = 2.0, float diminish = 0.5,
                           color texcoord = color(u, v, 0.0), output color out) {
    out = mx_fractal2d(texcoord, octaves, lacunarity, diminish) * amplitude;
}
shader mx_fractal2d_color4(color amplitude = color(1.0), float amplitude_a = 1.0, int octaves = 3, float lacunarity = 2.0,
                           float diminish = 0.5, color texcoord = color(u, v, 0.0), output color out, output float out_a) {
    out = mx_fractal2d(texcoord, octaves, lacunarity, diminish) * amplitude;
    out_a = mx_fractal(point(texcoord.r + 19.0, texcoord.g + 193.0, 0.0), octaves, lacunarity, diminish) * amplitude_a;
}
color mx_fractal3d(color position, int octaves, float lacunarity, float diminish) {
    point p = point(position);
    return color(mx_fractal(p, octaves, lacunarity, diminish), mx_fractal(p + point(19.1, 7.3, 5.2), octaves, lacunarity, diminish),
                 mx_fractal(p + point(3.7, 41.9, 13.3), octaves, lacunarity, diminish));
}
shader mx_fractal3d_color3(color amplitude = color(1.0), int octaves = 3, float lacunarity = 2.0, float diminish = 0.5,
                           color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), output color out) {
    out = mx_fractal3d(position, octaves, lacunarity, diminish) * amplitude;
}
shader mx_fractal3d_color4(color amplitude = color(1.0), float amplitude_a = 1.0, int octaves = 3, float lacunarity = 2.0,
                           float diminish = 0.5, color position = primvar("strata:Pobject", color(mx_world_to_object_point(vector(P)))), output color out, output float out_a) {
    out = mx_fractal3d(position, octaves, lacunarity, diminish) * amplitude;
    out_a = mx_fractal(point(position) + point(19.0, 193.0, 17.0), octaves, lacunarity, diminish) * amplitude_a;
}
