// Graph errors: each one is a diagnostic, never a panic or a silent connection.
shader passthrough(float in_value = 0.0, output float out) { out = in_value; }

substance bad_graph {
    input color base = color(1.0, 0.0, 0.0);
    input float level = "high";
    node a = passthrough(in_value: b.out);
    node b = passthrough(in_value: a.out);
    node c = no_such_node();
    node d = diffuse(albedo: base, colour: base);
    node e = diffuse(albedo: base.r);
    node f = mask(out: 1.0);
    node g = passthrough(in_value: base);
    node d = diffuse();
    node n = customChannelColor(value: base);
    node disp = displacement(height: 1.0, mode: "sideways");
    surface = a.out;
    mask = d.bsdf;
    displacement = disp.out;
    output float stray = a.out;
}

override bad_override {
    output color tint = nothing.out;
    surface = x.y;
}
