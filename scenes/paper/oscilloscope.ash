// Substances and overrides of the paper's section 6 production example (the ALab oscilloscope),
// rebuilt with strata's built-in nodes.

// 6.2: a typical glossy library substance; mid-grey by default.
substance generic01 {
    input color base_color = color(0.18, 0.18, 0.18);
    input float roughness = 0.4;
    node coat = glossy(albedo: base_color, roughness: roughness);
    surface = coat.bsdf;
}

// 6.3: colour and roughness patterns for generic01, kept apart from the library substance.
override generic01_override01 {
    input float pattern_scale = 12.0;
    node speckle = fbm(scale: pattern_scale, octaves: 3);
    node tint = ramp(t: speckle.out, start: color(0.35, 0.36, 0.33), end: color(0.5, 0.5, 0.46));
    node rough = math(a: speckle.out, b: 0.5, op: "mul");
    output color base_color = tint.out;
    output float roughness = rough.out;
}

// 6.3/6.4: a second, metal substance and its override.
substance metal_stainless01 {
    input color reflectivity = color(0.62, 0.62, 0.6);
    input float roughness = 0.3;
    node conductor = metal(reflectivity: reflectivity, roughness: roughness);
    surface = conductor.bsdf;
}

override metal_stainless01_override {
    node brushed = noise(scale: 40.0);
    node rough = mix_float(a: 0.15, b: 0.35, t: brushed.out);
    output float roughness = rough.out;
}

// 6.5: one override shared by every knob: only the colour changes.
override plastic_opaque01_red {
    output color base_color = color(0.6, 0.03, 0.02);
}

// 6.5/6.6: dirt with built-in masking, and two overrides of its colour.
substance dirt01 {
    input color dirt_color = color(0.25, 0.2, 0.14);
    input float amount = 0.6;
    node grime = cellular(scale: 8.0);
    node coverage = math(a: grime.out, b: amount, op: "mul");
    node opacity = mask(opacity: coverage.out);
    node base = diffuse(albedo: dirt_color);
    surface = base.bsdf;
    mask = opacity.out;
}

// 6.8: the dirt override also adds a custom AOV marking where dirt is.
override dirt01_override {
    output color dirt_color = color(0.3, 0.24, 0.16);
    node dirt_aov = customChannelColor(name: "dirt", value: color(1.0, 1.0, 1.0));
}

override dirt01_casing_override {
    output color dirt_color = color(0.45, 0.4, 0.33);
}

// A planar projection mask: 1 inside a box in object-space x/y, soft at its edges.
shader projected_box(float u_min = 0.2, float u_max = 0.45, float v_min = 0.25, float v_max = 0.75,
                     float s = u, float t = v, output float out) {
    float soft = 0.01;
    out = smoothstep(u_min - soft, u_min, s) * (1.0 - smoothstep(u_max, u_max + soft, s))
        * smoothstep(v_min - soft, v_min, t) * (1.0 - smoothstep(v_max, v_max + soft, t));
}

// 6.9: a decal: a coated paper sticker with a projected mask, and bump (6.10, mix mode).
substance sticker01 {
    input color paper_color = color(0.9, 0.88, 0.8);
    input float u_min = 0.2;
    node print = checker(scale: 20.0, a: paper_color, b: color(0.1, 0.1, 0.1));
    node coat = glossy(albedo: print.out, roughness: 0.5);
    node inside = projected_box(u_min: u_min);
    node opacity = mask(opacity: inside.out);
    node edge = bump(height: inside.out, scale: 0.002, mode: "mix");
    surface = coat.bsdf;
    mask = opacity.out;
    displacement = edge.out;
}
