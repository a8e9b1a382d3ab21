// Displacement bounds dicing needs before any shading point exists.

shader relief(float height = 0.0, string mode = "add", string bound = "big", output float out) {
    out = height;
}

substance ComputedBound {
    node n = noise(scale: 2.0);
    node d = displacement(height: n.out, mode: "none", bound: n.out);
    displacement = d.out;
}

substance StringBound {
    node d = relief(height: 0.1);
    displacement = d.out;
}
