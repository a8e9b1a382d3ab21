substance matte {
    input color albedo = color(0.5, 0.5, 0.5);
    node d = diffuse(albedo: albedo);
    surface = d.bsdf;
}
