// Indexes out of bounds on the upper half of whatever it shades: one fault per sample there.
shader risky(output color out = color(0.0)) {
    float a[2] = {0.25, 0.75};
    int i = 0;
    if (P[1] > 0.0) { i = 5; }
    out = color(a[i]);
}

substance bad {
    node r = risky();
    node d = diffuse(albedo: r.out);
    surface = d.bsdf;
}

substance good {
    node d = diffuse();
    surface = d.bsdf;
}
