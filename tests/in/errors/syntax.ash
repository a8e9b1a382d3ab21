// Several syntax errors: the parser reports each and goes on.
shader broken(float a = 1.0, output float out) {
    float x = ;
    out = a * 2 $ 3;
    if (a > 1 { out = 0.0; }
}

substance s {
    node = diffuse();
    surface g.bsdf;
}

shader fine(output float out) { out = 1.0; }
