// Substances of the slot-lint fixtures (tests/slot_lints.rs).

substance opaque {
    input color albedo = color(0.8, 0.8, 0.8);
    node bsdf = diffuse(albedo: albedo);
    surface = bsdf.bsdf;
}

substance coat {
    input color albedo = color(0.2, 0.8, 0.2);
    input float coverage = 0.5;
    node bsdf = diffuse(albedo: albedo);
    node opacity = mask(opacity: coverage);
    surface = bsdf.bsdf;
    mask = opacity.out;
}

// A mask alone: it covers nothing, because there is no surface to show where it covers.
substance only_mask {
    input float coverage = 0.5;
    node opacity = mask(opacity: coverage);
    mask = opacity.out;
}

override tint {
    output color albedo = color(0.9, 0.1, 0.1);
}
