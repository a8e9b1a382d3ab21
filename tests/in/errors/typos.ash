// Misspelt names: each error suggests the name that was meant.

substance misspelt {
    input color albedo = color(0.8, 0.8, 0.8);
    input float roughness = 0.4;
    node base = glosy(albedo: albedo, roughness: roughnes);
    node coat = glossy(albdo: albedo);
    node spots = noise(scale: 4.0);
    surface = coat.bdsf;
    mask = spot.out;
}
