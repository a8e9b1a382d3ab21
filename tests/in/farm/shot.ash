// tests/farm.rs: the default scene's substances with integer and colour channels.
// Substances of strata's default scene: a glossy base, a brushed metal, a dirt layer masked by
// fbm noise, a checker floor, and overrides that recolour or add a custom channel.

// A soft threshold: 0 below `edge`, 1 above `edge + softness`.
shader threshold(float value = 0.0, float edge = 0.5, float softness = 0.1, output float out) {
    out = smoothstep(edge, edge + max(softness, 1e-4), value);
}

substance clay {
    input color base_color = color(0.55, 0.55, 0.55);
    input float roughness = 0.35;
    node coat = glossy(albedo: base_color, roughness: roughness);
    surface = coat.bsdf;
}

substance floor {
    input float tiles = 8.0;
    node tiles_pattern = checker(scale: tiles, a: color(0.18, 0.18, 0.2), b: color(0.7, 0.7, 0.68));
    node base = diffuse(albedo: tiles_pattern.out);
    surface = base.bsdf;
}

substance brushed_metal {
    input color reflectivity = color(0.95, 0.64, 0.54);
    input float roughness = 0.25;
    node conductor = metal(reflectivity: reflectivity, roughness: roughness);
    surface = conductor.bsdf;
}

substance dirt {
    input color dirt_color = color(0.2, 0.15, 0.1);
    input float coverage = 0.55;
    node grime = fbm(scale: 3.0, octaves: 5);
    node amount = threshold(value: grime.out, edge: coverage, softness: 0.15);
    node opacity = mask(opacity: amount.out);
    node base = diffuse(albedo: dirt_color);
    surface = base.bsdf;
    mask = opacity.out;
}

override red_paint {
    output color base_color = color(0.7, 0.05, 0.04);
    output float roughness = 0.15;
}

override dirt_marker {
    node marker = customChannelFloat(name: "dirt", value: 1.0);
    node id = customChannelInteger(name: "dirt_id", value: 7);
    node tint = customChannelColor(name: "tint", value: color(0.25, 0.5, 0.75));
}
