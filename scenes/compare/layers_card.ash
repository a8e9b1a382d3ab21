// Substances of scenes/compare/layers_card*.usda: a ball with two diffuse layers (the top one
// masked to 0.3: rule-5 weights 0.7 and 0.3, Mitsuba's blendbsdf) and a 50 %-opacity card
// (transparency 0.5, Mitsuba's mask).

substance matte {
    input color albedo = color(0.5, 0.5, 0.5);
    node d = diffuse(albedo: albedo);
    surface = d.bsdf;
}

substance masked_matte {
    input color albedo = color(0.1, 0.3, 0.8);
    input float opacity = 0.3;
    node d = diffuse(albedo: albedo);
    node m = mask(opacity: opacity);
    surface = d.bsdf;
    mask = m.out;
}
