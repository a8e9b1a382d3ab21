//! Thin-walled surfaces end to end: OpenPBR `geometry_thin_walled`, Standard Surface
//! `thin_walled` and MaterialX 1.38's `surface` `thin_walled` compile without the old "never
//! thin-walled" warning into the lobes their specifications describe (the transmission a
//! thin sheet, the subsurface diffuse reflection and transmission). The sheet's optics are
//! tested in `render::material::thin_tests`, its render in `tests/thin_walled.rs`.

use super::*;

/// Scatter word of a `dielectric_bsdf` term (3: "T", 4: "RT" on a thin-walled sheet).
const SCATTER: usize = 5;

/// The lobes the renderer sees of `/M` authored as `text`, and the diagnostics.
fn lobes(text: String) -> (Vec<ClosureTerm>, String) {
    let (code, rendered) = compiled(&text);
    let code = code.unwrap_or_else(|| panic!("{rendered}"));
    (lobes_at(&code, 0.5, 0.5), rendered)
}

#[test]
fn thin_walled_transmission_is_a_thin_sheet_without_a_warning() {
    use ClosureKind::*;
    let glass = "        float inputs:transmission_weight = 1\n        float inputs:specular_roughness = 0.2\n        float inputs:specular_ior = 1.33";
    for (surface, flag) in [("OpenPBR", "geometry_thin_walled"), ("Standard Surface", "thin_walled")] {
        let make = |inputs: &str| {
            let text = open_pbr(inputs, "");
            if surface == "OpenPBR" {
                text
            } else {
                text.replace("ND_open_pbr_surface_surfaceshader", "ND_standard_surface_surfaceshader")
                    .replace("transmission_weight", "transmission")
                    .replace("specular_ior", "specular_IOR")
            }
        };
        let (got, rendered) = lobes(make(&format!("{glass}\n        bool inputs:{flag} = 1")));
        assert!(!rendered.contains("thin-walled"), "{surface}: {rendered}");
        assert!(!rendered.contains("warning"), "{surface}: {rendered}");
        let glass_terms: Vec<_> = described(&got, 6).into_iter().filter(|(k, ..)| *k == Dielectric).collect();
        assert!(
            glass_terms.iter().any(|(_, _, p)| p[..5] == [1.0, 1.0, 1.0, 1.33, 0.2] && p[SCATTER] == 4.0),
            "{surface}: {glass_terms:?}"
        );
        // Not thin-walled: the refracting interface, as before.
        let (got, _) = lobes(make(glass));
        assert!(described(&got, 6).iter().all(|(_, _, p)| p[SCATTER] <= 2.0), "{surface}: {got:?}");
        // The thin-walled translucency adds a term, but the fuzz (sheen), whose weight is a
        // known 0 here, takes no place of the eight: six, as before thin walls, leaving room
        // for vertical layers over the surface.
        let code = compiled(&make(glass)).0.expect("compiles");
        let mut sum = ClosureSum::default();
        code.surface_sum(&Globals::default(), 0, &mut sum).expect("evaluates");
        let kinds: Vec<u32> = sum.terms.iter().map(|t| t.kind).filter(|&k| k != None as u32).collect();
        assert!(kinds.len() <= 6 && !kinds.contains(&(Sheen as u32)), "{surface}: {kinds:?}");
    }
}

#[test]
fn thin_walled_subsurface_reflects_and_transmits_diffusely() {
    use ClosureKind::*;
    // OpenPBR: (1 − g) / 2 of subsurface_color reflected, (1 + g) / 2 transmitted.
    let inputs = "        float inputs:subsurface_weight = 1\n        color3f inputs:subsurface_color = (0.8, 0.4, 0.2)\n        float inputs:subsurface_scatter_anisotropy = 0.5\n        float inputs:specular_weight = 0\n        bool inputs:geometry_thin_walled = 1";
    let (got, _) = lobes(open_pbr(inputs, ""));
    let d = described(&got, 3);
    assert!(d.iter().any(|(k, w, p)| *k == OrenNayar && *w == [1.0; 3] && close(p, &[0.2, 0.1, 0.05])), "{d:?}");
    assert!(d.iter().any(|(k, w, p)| *k == Translucent && close(w, &[0.75; 3]) && close(p, &[0.8, 0.4, 0.2])), "{d:?}");
    // Standard Surface: all of it transmitted (its translucent_bsdf).
    let inputs = "        float inputs:subsurface = 1\n        color3f inputs:subsurface_color = (0.8, 0.4, 0.2)\n        float inputs:specular = 0\n        bool inputs:thin_walled = 1";
    let (got, _) = lobes(standard_surface(inputs));
    let d = described(&got, 3);
    assert!(d.iter().any(|(k, w, p)| *k == Translucent && *w == [1.0; 3] && close(p, &[0.8, 0.4, 0.2])), "{d:?}");
    assert!(d.iter().all(|(k, _, p)| *k != OrenNayar || p[..3] == [0.0; 3]), "no diffuse reflection: {d:?}");
    // Not thin-walled: no transmission.
    let (got, _) = lobes(standard_surface(&inputs.replace("thin_walled = 1", "thin_walled = 0")));
    assert!(got.iter().all(|t| t.kind != Translucent as u32), "{got:?}");
}

fn close(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
}

#[test]
fn a_thin_walled_surface_node_makes_its_transmission_thin_and_keeps_its_coat() {
    let text =
        "def Material \"M\" (prepend references = @../thin/thin_walled_surface.mtlx@</MaterialX/Materials/M>) {}";
    let (got, rendered) = lobes(text.to_string());
    assert!(!rendered.contains("warning"), "{rendered}");
    let scatter: Vec<f32> = got.iter().map(|t| t.params[SCATTER]).collect();
    // The coat ("R") stays a coat; the glass under it ("RT") becomes the sheet.
    assert_eq!(scatter, [0.0, 4.0], "{got:?}");
    assert_eq!(got[1].above, 0b1);
}
