// Layered displacement after the paper's production example (section 6.10): a base with
// hammered surface detail, a decal band that masks the detail flat (`mix`), and dirt that adds
// crust on top (`add`). Every `displacement` node moves the surface; heights are in scene units.

// A soft threshold: 0 below `edge`, 1 above `edge + softness`.
shader relief_threshold(float value = 0.0, float edge = 0.5, float softness = 0.1, output float out) {
    out = smoothstep(edge, edge + max(softness, 1e-4), value);
}

// 1 inside the band `from..to` of `t`, with soft edges.
shader band(float t = v, float from = 0.4, float to = 0.6, float softness = 0.02, output float out) {
    out = smoothstep(from - softness, from + softness, t) * (1.0 - smoothstep(to - softness, to + softness, t));
}

// Hammered metal: cellular dents, displaced inwards up to `depth`.
substance hammered {
    input color reflectivity = color(0.9, 0.62, 0.5);
    input float depth = 0.06;
    node dents = cellular(scale: 6.0);
    node height = math(a: dents.out, b: depth, op: "mul");
    node relief = displacement(height: height.out, scale: -1.0, mode: "none", bound: 0.1);
    node conductor = metal(reflectivity: reflectivity, roughness: 0.3);
    surface = conductor.bsdf;
    displacement = relief.out;
}

// A painted band: where it covers, the relief below is replaced by a flat surface.
substance decal {
    input color paint = color(0.05, 0.2, 0.55);
    node coverage = band(from: 0.42, to: 0.58);
    node opacity = mask(opacity: coverage.out);
    node flat = displacement(height: 0.0, mode: "mix", bound: 0.1);
    node coat = glossy(albedo: paint, roughness: 0.2);
    surface = coat.bsdf;
    mask = opacity.out;
    displacement = flat.out;
}

// Dirt crust: fbm-masked, adding up to `thickness` where it lies.
substance crust {
    input color dirt_color = color(0.22, 0.17, 0.11);
    input float coverage = 0.58;
    input float thickness = 0.04;
    node grime = fbm(scale: 3.0, octaves: 5);
    node amount = relief_threshold(value: grime.out, edge: coverage, softness: 0.12);
    node opacity = mask(opacity: amount.out);
    node crust_height = displacement(height: thickness, mode: "add", bound: 0.05);
    node base = diffuse(albedo: dirt_color);
    surface = base.bsdf;
    mask = opacity.out;
    displacement = crust_height.out;
}

substance ground {
    node tiles = checker(scale: 6.0, a: color(0.2, 0.2, 0.22), b: color(0.6, 0.6, 0.58));
    node base = diffuse(albedo: tiles.out);
    surface = base.bsdf;
}
