substance plastic {
    input color base_color = color(0.5, 0.5, 0.5);
    input float roughness = 0.3;
    node g = glossy(albedo: base_color, roughness: roughness);
    surface = g.bsdf;
}

override bad_types {
    output string base_color = "red";
}
