// Substances of scenes/compare/metal_coat_glass.usda: one per closure kind that has a close
// Mitsuba 3 counterpart (tools/compare_mitsuba.py states the mapping and its known differences).

substance matte {
    input color albedo = color(0.5, 0.5, 0.5);
    node d = diffuse(albedo: albedo);
    surface = d.bsdf;
}

substance rough_metal {
    input color reflectivity = color(0.95, 0.64, 0.54);
    input color edge_tint = color(1.0, 0.85, 0.7);
    input float roughness = 0.35;
    node m = metal(reflectivity: reflectivity, edge_tint: edge_tint, roughness: roughness);
    surface = m.bsdf;
}

substance coated {
    input color albedo = color(0.15, 0.3, 0.6);
    input float roughness = 0.3;
    input float ior = 1.5;
    node g = glossy(albedo: albedo, roughness: roughness, ior: ior);
    surface = g.bsdf;
}

substance rough_glass {
    input float roughness = 0.2;
    input float ior = 1.5;
    node g = glass(roughness: roughness, ior: ior);
    surface = g.bsdf;
}
