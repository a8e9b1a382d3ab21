// An override whose output is misspelt, and a scene value for a misspelt input.

substance plastic {
    input color albedo = color(0.8, 0.8, 0.8);
    input float roughness = 0.4;
    node bsdf = glossy(albedo: albedo, roughness: roughness);
    surface = bsdf.bsdf;
}

override tint {
    output color albedoo = color(0.9, 0.1, 0.1);
}
