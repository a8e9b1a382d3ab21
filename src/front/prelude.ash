// The built-in node library. Every substance file sees these node types.
// Globals: P, N, Ng, I, u, v, dPdu, dPdv.

// ---- BSDFs -----------------------------------------------------------------------------------

shader diffuse(color albedo = 0.8, output closure bsdf) {
    bsdf = diffuse_bsdf(clamp(albedo, 0.0, 1.0));
}

// Rough GGX dielectric coat over a diffuse base.
shader glossy(color albedo = 0.5, color specular = 1.0, float roughness = 0.3, float ior = 1.5,
              output closure bsdf) {
    bsdf = glossy_bsdf(clamp(albedo, 0.0, 1.0), clamp(specular, 0.0, 1.0), clamp(roughness, 0.0, 1.0),
                       clamp(ior, 1.0, 4.0));
}

// GGX conductor in the artist-friendly reflectivity / edge-tint form.
shader metal(color reflectivity = color(0.9, 0.9, 0.9), color edge_tint = 1.0, float roughness = 0.2,
             output closure bsdf) {
    bsdf = metal_bsdf(clamp(reflectivity, 0.0, 0.999), clamp(edge_tint, 0.0, 1.0), clamp(roughness, 0.0, 1.0));
}

// Rough dielectric with reflection and transmission.
shader glass(color tint = 1.0, float roughness = 0.0, float ior = 1.5, output closure bsdf) {
    bsdf = glass_bsdf(clamp(tint, 0.0, 1.0), clamp(roughness, 0.0, 1.0), clamp(ior, 1.0001, 4.0));
}

// ---- Products --------------------------------------------------------------------------------

shader mask(float opacity = 1.0, output float out) {
    out = clamp(opacity, 0.0, 1.0);
}

// Height along the normal in scene units. `mode` is "none", "add" or "mix" (see DESIGN.md rule 6).
shader displacement(float height = 0.0, float scale = 1.0, string mode = "add", output float out) {
    out = height * scale;
}

// Bump: like displacement, but only the shading normal changes.
shader bump(float height = 0.0, float scale = 0.01, string mode = "add", output float out) {
    out = height * scale;
}

// Tangent-space normal map, decoded from [0, 1] colour to [-1, 1].
shader normal_map(color map = color(0.5, 0.5, 1.0), float strength = 1.0, output normal out) {
    vector t = dPdu - N * dot(N, dPdu);
    if (length(t) < 1e-8) {
        t = abs(N.x) < 0.9 ? cross(N, vector(1, 0, 0)) : cross(N, vector(0, 1, 0));
    }
    t = normalize(t);
    vector b = cross(N, t);
    vector m = vector(map) * 2.0 - 1.0;
    out = normalize(t * (m.x * strength) + b * (m.y * strength) + N * m.z);
}

// ---- Custom channels (AOVs): no outputs, never removed ----------------------------------------

shader customChannelColor(string name = "", color value = 0.0) {}
shader customChannelFloat(string name = "", float value = 0.0) {}
shader customChannelInteger(string name = "", int value = 0) {}

// ---- Patterns --------------------------------------------------------------------------------

shader noise(point p = P, float scale = 1.0, output float out) {
    out = noise(p * scale);
}

shader fbm(point p = P, float scale = 1.0, int octaves = 4, float lacunarity = 2.0, float gain = 0.5,
           output float out) {
    float sum = 0.0;
    float amplitude = 0.5;
    float total = 0.0;
    point q = p * scale;
    for (int i = 0; i < clamp(octaves, 1, 12); i++) {
        sum += amplitude * noise(q);
        total += amplitude;
        amplitude *= gain;
        q *= lacunarity;
    }
    out = total > 0.0 ? sum / total : 0.0;
}

shader cellular(point p = P, float scale = 1.0, output float out) {
    out = cellular(p * scale);
}

shader checker(float s = u, float t = v, float scale = 8.0, color a = 0.0, color b = 1.0, output color out) {
    int parity = int(floor(s * scale) + floor(t * scale)) % 2;
    out = parity == 0 ? a : b;
}

shader ramp(float t = u, color start = 0.0, color end = 1.0, float from = 0.0, float to = 1.0,
            output color out) {
    float k = to > from ? clamp((t - from) / (to - from), 0.0, 1.0) : step(from, t);
    out = mix(start, end, k);
}

shader mix(color a = 0.0, color b = 1.0, float t = 0.5, output color out) {
    out = mix(a, b, clamp(t, 0.0, 1.0));
}

shader mix_float(float a = 0.0, float b = 1.0, float t = 0.5, output float out) {
    out = mix(a, b, clamp(t, 0.0, 1.0));
}

// op: "add", "sub", "mul", "div", "min", "max", "pow", "mod", "abs", "invert", "sin", "cos".
shader math(float a = 0.0, float b = 0.0, string op = "add", output float out) {
    if (op == "add") out = a + b;
    else if (op == "sub") out = a - b;
    else if (op == "mul") out = a * b;
    else if (op == "div") out = b != 0.0 ? a / b : 0.0;
    else if (op == "min") out = min(a, b);
    else if (op == "max") out = max(a, b);
    else if (op == "pow") out = pow(abs(a), b);
    else if (op == "mod") out = b != 0.0 ? mod(a, b) : 0.0;
    else if (op == "abs") out = abs(a);
    else if (op == "invert") out = 1.0 - a;
    else if (op == "sin") out = sin(a);
    else if (op == "cos") out = cos(a);
    else out = 0.0;
}

shader texture(string file = "", float s = u, float t = v, output color out) {
    out = texture(file, s, t);
}

shader float_to_color(float value = 0.0, output color out) {
    out = color(value);
}

shader color_to_float(color value = 0.0, output float out) {
    out = luminance(value);
}

// ---- The default substance: what a prim with no slot binding renders with (DESIGN.md rule 4) --

substance default_substance {
    node white = diffuse(albedo: color(1.0, 1.0, 1.0));
    surface = white.bsdf;
}
