// Redefines the built-in `default_substance` (which shades unbound prims): a located
// diagnostic, never a panic or a silent pick of one or the other.
substance default_substance {
    node d = diffuse(albedo: color(1, 0, 0));
    surface = d.bsdf;
}
substance plastic {
    node d = glossy();
    surface = d.bsdf;
}
