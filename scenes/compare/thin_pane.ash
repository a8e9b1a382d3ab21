// Substances of scenes/compare/thin_pane.usda (tools/compare_mitsuba.py maps the pane to
// Mitsuba 3's `thindielectric`).

substance matte {
    input color albedo = color(0.5, 0.5, 0.5);
    node d = diffuse(albedo: albedo);
    surface = d.bsdf;
}

// A smooth thin-walled sheet: the sheet's reflectance, transmission straight through.
shader thin_sheet(float ior = 1.5, output closure bsdf) {
    bsdf = with_thin_walled(dielectric_bsdf(color(1.0), ior, 0.0, "RT"), 1.0);
}

substance thin_pane {
    input float ior = 1.5;
    node s = thin_sheet(ior: ior);
    surface = s.bsdf;
}
