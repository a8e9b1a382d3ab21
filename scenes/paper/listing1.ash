// Substances of the paper's listing 1: three plain colours.

substance SubstanceA {
    input color albedo = color(0.8, 0.2, 0.2);
    node bsdf = diffuse(albedo: albedo);
    surface = bsdf.bsdf;
}

substance SubstanceB {
    input color albedo = color(0.2, 0.8, 0.2);
    input float coverage = 0.5;
    node bsdf = diffuse(albedo: albedo);
    node opacity = mask(opacity: coverage);
    surface = bsdf.bsdf;
    mask = opacity.out;
}

substance SubstanceC {
    input color albedo = color(0.2, 0.2, 0.8);
    node bsdf = diffuse(albedo: albedo);
    surface = bsdf.bsdf;
}
