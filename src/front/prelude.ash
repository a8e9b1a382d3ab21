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

// A vertical layer (DESIGN.md rule 3b): `top` lies over `base`, covering a fraction `coverage`
// (the vertical slot's mask). `layer(top * m, base)` is `mix(base, layer(top, base), m)`: a
// top's weight is linear in both layer modes, and the base's terms are not repeated.
// Composition instantiates it for every vertical slot; substances may call it too.
shader vertical_layer(closure base, closure top, float coverage = 1.0, output closure bsdf) {
    bsdf = layer(top * clamp(coverage, 0.0, 1.0), base);
}

shader mask(float opacity = 1.0, output float out) {
    out = clamp(opacity, 0.0, 1.0);
}

// Height along the normal in scene units: the surface moves (meshes and quadrics are diced, see
// docs/DESIGN.md rule 6). `mode` is "none", "add" or "mix"; `bound` is the largest |height| the
// layer may reach (a literal or a substance input): heights beyond it are clamped and reported.
shader displacement(float height = 0.0, float scale = 1.0, string mode = "add", float bound = 1.0, output float out) {
    out = height * scale;
}

// Bump: like displacement, but only the shading normal changes (no `bound`: nothing is diced).
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

// Primvars: the shaded prim's `primvars:NAME`, interpolated at the shading point as USD
// defines (constant, uniform, vertex, varying, faceVarying; indexed or not); `fallback` where
// the prim has none. Components a primvar lacks read 0 (a float2 is (x, y, 0)); a float read
// of a vector primvar is its first component.
shader primvar(string name = "", color fallback = 0.0, output color out) {
    out = primvar(name, fallback);
}
shader primvar_float(string name = "", float fallback = 0.0, output float out) {
    out = primvar_float(name, fallback);
}
shader primvar_vector(string name = "", vector fallback = vector(0.0, 0.0, 0.0), output vector out) {
    out = primvar_vector(name, fallback);
}

shader float_to_color(float value = 0.0, output color out) {
    out = color(value);
}

shader color_to_float(color value = 0.0, output float out) {
    out = luminance(value);
}

// ---- UsdPreviewSurface (https://openusd.org/release/spec_usdpreviewsurface.html) -----------
// The nodes of UsdShade's preview networks, which `compose::preview` instantiates from a bound
// Material's shaders. USD's float2/float3/normal3f/point3f/vector3f values all travel as
// `color` triples here (a float2 has z = 0): UsdShade connects them freely, and one triple type
// keeps every such connection well-typed.

// The BSDF of UsdPreviewSurface on strata's closures (one closure per layer, so no lobe sums):
// - metallic workflow, metallic < 0.5: GGX dielectric coat (ior) over Lambert, the base
//   darkened by (1 - metallic) and the coat tinted towards the base colour by metallic;
//   metallic >= 0.5: GGX conductor with normal-incidence reflectance mix(F0(ior), base,
//   metallic) and a white edge. The switch at 0.5 stands in for the spec's linear blend of
//   the two lobes, which one closure cannot express.
// - specular workflow: the coat's Fresnel is matched to specularColor at normal incidence
//   (ior from the largest channel, the colour as tint; ior ≤ 4 caps F0 at 0.36).
// - clearcoat: strata has one coat, so clearcoat blends its roughness towards
//   clearcoatRoughness instead of adding a second specular lobe (none on conductors).
// - roughness is perceptual (GGX alpha = roughness²), as in the spec.
shader UsdPreviewSurface_bsdf(color diffuseColor = color(0.18, 0.18, 0.18), int useSpecularWorkflow = 0,
                              color specularColor = 0.0, float metallic = 0.0, float roughness = 0.5,
                              float clearcoat = 0.0, float clearcoatRoughness = 0.01, float ior = 1.5,
                              output closure bsdf) {
    color base = clamp(diffuseColor, 0.0, 1.0);
    float r = clamp(roughness, 0.0, 1.0);
    float coat = clamp(clearcoat, 0.0, 1.0);
    float coat_r = mix(r, clamp(clearcoatRoughness, 0.0, 1.0), coat);
    float eta = clamp(ior, 1.0, 4.0);
    if (useSpecularWorkflow != 0) {
        color f0 = clamp(specularColor, 0.0, 0.36);
        float f = max(max(f0.r, f0.g), f0.b);
        float s = sqrt(f);
        float matched = f > 0.0 ? (1.0 + s) / (1.0 - s) : 1.0;
        color tint = f > 0.0 ? f0 / f : color(0.0);
        bsdf = glossy_bsdf(base, tint, coat_r, clamp(matched, 1.0, 4.0));
    } else {
        float m = clamp(metallic, 0.0, 1.0);
        float k = (eta - 1.0) / (eta + 1.0);
        if (m >= 0.5) {
            bsdf = metal_bsdf(clamp(mix(color(k * k), base, m), 0.0, 0.999), color(1.0), r);
        } else {
            bsdf = glossy_bsdf(base * (1.0 - m), mix(color(1.0), base, m), coat_r, eta);
        }
    }
}

// Presence: opacity, or with opacityThreshold > 0 a cutout (opaque where opacity reaches the
// threshold, fully transparent elsewhere). It drives the layer mask (DESIGN.md rule 5).
shader UsdPreviewSurface_opacity(float opacity = 1.0, float opacityThreshold = 0.0, output float out) {
    float o = clamp(opacity, 0.0, 1.0);
    out = opacityThreshold > 0.0 ? (o >= opacityThreshold ? 1.0 : 0.0) : o;
}

// UsdPreviewSurface's `normal`: a tangent-space normal in [-1, 1] (a normal-map texture read
// with scale 2 and bias -1), applied as normal_map does with the [0, 1] encoding.
shader UsdPreviewSurface_normal(color normal_ts = color(0.0, 0.0, 1.0), output normal out) {
    vector t = dPdu - N * dot(N, dPdu);
    if (length(t) < 1e-8) {
        t = abs(N.x) < 0.9 ? cross(N, vector(1, 0, 0)) : cross(N, vector(0, 1, 0));
    }
    t = normalize(t);
    vector b = cross(N, t);
    vector m = vector(normal_ts);
    vector n = t * m.x + b * m.y + N * m.z;
    out = length(n) > 1e-8 ? normalize(n) : N;
}

// UsdPreviewSurface's `emissiveColor`: emitted radiance, as the spec's "emissive component".
shader UsdPreviewSurface_emission(color emissiveColor = color(0.0, 0.0, 0.0), output color out) {
    out = emissiveColor;
}

// The built-in UsdPreviewSurface substance, with the spec's inputs and defaults (`normal` is
// `normal_ts`: `normal` is a type name here). emissiveColor drives the `emission` product
// (radiance from the front face). occlusion is accepted and unused: it is a real-time
// approximation a path tracer computes. `displacement` is a bump
// (the shading normal moves, the surface does not: preview assets author it for real-time
// viewers, without the bound dicing needs). A composed instance drops the normal and
// displacement products when nothing sets them.
substance UsdPreviewSurface {
    input color diffuseColor = color(0.18, 0.18, 0.18);
    input color emissiveColor = color(0.0, 0.0, 0.0);
    input int useSpecularWorkflow = 0;
    input color specularColor = color(0.0, 0.0, 0.0);
    input float metallic = 0.0;
    input float roughness = 0.5;
    input float clearcoat = 0.0;
    input float clearcoatRoughness = 0.01;
    input float opacity = 1.0;
    input float opacityThreshold = 0.0;
    input float ior = 1.5;
    input color normal_ts = color(0.0, 0.0, 1.0);
    input float displacement = 0.0;
    input float occlusion = 1.0;
    node bsdf = UsdPreviewSurface_bsdf(diffuseColor: diffuseColor, useSpecularWorkflow: useSpecularWorkflow,
                                       specularColor: specularColor, metallic: metallic, roughness: roughness,
                                       clearcoat: clearcoat, clearcoatRoughness: clearcoatRoughness, ior: ior);
    node presence = UsdPreviewSurface_opacity(opacity: opacity, opacityThreshold: opacityThreshold);
    node normals = UsdPreviewSurface_normal(normal_ts: normal_ts);
    node height = bump(height: displacement, scale: 1.0, mode: "add");
    node glow = UsdPreviewSurface_emission(emissiveColor: emissiveColor);
    surface = bsdf.bsdf;
    mask = presence.out;
    normal = normals.out;
    displacement = height.out;
    emission = glow.out;
}

// Wrap tokens to the runtime's codes (strata_rt::texture::WRAP_*); `useMetadata` (and anything
// unknown, which composition reports) is repeat, since PNG, JPEG and EXR carry no wrap metadata
// strata reads.
int usd_wrap_code(string mode) {
    return mode == "black" ? 1 : (mode == "clamp" ? 2 : (mode == "mirror" ? 3 : 0));
}

// UsdUVTexture: bilinear lookup at st (t = 0 is the image's bottom row), value · scale + bias
// per channel. float4 inputs travel as colour + alpha (`scale` + `scale_a`). An empty file
// gives the fallback. Channels the image lacks read 1 for alpha, grey for colour.
shader UsdUVTexture(string file = "", color st = color(0.0, 0.0, 0.0), string wrapS = "useMetadata",
                    string wrapT = "useMetadata", string sourceColorSpace = "auto",
                    color scale = 1.0, float scale_a = 1.0, color bias = 0.0, float bias_a = 0.0,
                    color fallback = color(0.0, 0.0, 0.0), float fallback_a = 1.0,
                    output color rgb, output float r, output float g, output float b, output float a) {
    if (file == "") {
        rgb = fallback;
        a = fallback_a;
    } else {
        int wrap = 16 * usd_wrap_code(wrapS) + 256 * usd_wrap_code(wrapT);
        float s = st.r;
        float t = st.g;
        rgb = color(texture_channel(file, sourceColorSpace, s, t, wrap),
                    texture_channel(file, sourceColorSpace, s, t, wrap + 1),
                    texture_channel(file, sourceColorSpace, s, t, wrap + 2)) * scale + bias;
        a = texture_channel(file, sourceColorSpace, s, t, wrap + 3) * scale_a + bias_a;
    }
    r = rgb.r;
    g = rgb.g;
    b = rgb.b;
}

// UsdPrimvarReader_*: the shaded prim's primvar `varname` (any interpolation, indexed or not),
// or the fallback where the prim has none. float2 values read (x, y, 0). `st` is the shading
// point's texture coordinates (u, v): the mesh's `st`, or an analytic prim's parameterisation.
shader UsdPrimvarReader_float2(string varname = "", color fallback = color(0.0, 0.0, 0.0), output color result) {
    if (varname == "st") {
        result = color(u, v, 0.0);
    } else {
        result = primvar(varname, fallback);
    }
}
shader UsdPrimvarReader_float3(string varname = "", color fallback = color(0.0, 0.0, 0.0), output color result) {
    if (varname == "st") {
        result = color(u, v, 0.0);
    } else {
        result = primvar(varname, fallback);
    }
}
shader UsdPrimvarReader_float(string varname = "", float fallback = 0.0, output float result) {
    result = primvar_float(varname, fallback);
}
shader UsdPrimvarReader_int(string varname = "", int fallback = 0, output int result) {
    result = int(primvar_float(varname, float(fallback)));
}

// UsdTransform2d: in · scale, rotated by `rotation` degrees (counter-clockwise), + translation.
shader UsdTransform2d(color in_ = color(0.0, 0.0, 0.0), float rotation = 0.0, color scale = color(1.0, 1.0, 1.0),
                      color translation = color(0.0, 0.0, 0.0), output color result) {
    float x = in_.r * scale.r;
    float y = in_.g * scale.g;
    float c = cos(radians(rotation));
    float s = sin(radians(rotation));
    result = color(x * c - y * s + translation.r, x * s + y * c + translation.g, 0.0);
}

// ---- The default substance: what a prim with no slot binding renders with (DESIGN.md rule 4) --

substance default_substance {
    node white = diffuse(albedo: color(1.0, 1.0, 1.0));
    surface = white.bsdf;
}

// As Hydra draws unbound geometry with display primvars (composition picks these for prims that
// author them, so the others pay nothing): displayColor, and displayOpacity as presence.
substance default_substance_display_color {
    node display = primvar(name: "displayColor", fallback: color(1.0, 1.0, 1.0));
    node base = diffuse(albedo: display.out);
    surface = base.bsdf;
}

substance default_substance_display {
    node display = primvar(name: "displayColor", fallback: color(1.0, 1.0, 1.0));
    node opacity = primvar_float(name: "displayOpacity", fallback: 1.0);
    node base = diffuse(albedo: display.out);
    node presence = mask(opacity: opacity.out);
    surface = base.bsdf;
    mask = presence.out;
}
