// A substance whose displacement bound is an input the scene sets.

substance Reaching {
    input float reach = 0.2;
    node s = diffuse(albedo: 0.5);
    node d = displacement(height: 0.1, mode: "none", bound: reach);
    surface = s.bsdf;
    displacement = d.out;
}
