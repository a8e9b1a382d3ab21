//! The pbrlib BSDF nodes and operators against the closure algebra written by hand, white
//! furnaces, and the lobes that translucent, subsurface and thin-film nodes approximate.

use super::*;

/// `/Ball`'s compiled material (see [`compiled`]) from `backend`.
pub(crate) fn compiled_with(rest: &str, backend: BackendKind) -> (Option<Arc<dyn MaterialCode>>, String) {
    let text = format!(
        "#usda 1.0\ndef Sphere \"Ball\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {{ rel material:binding = </M> }}\n{rest}\n"
    );
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::from_text("scene.usda", &text, Path::new(DIR), &mut sources, &mut diags).expect("parses");
    let c = compose_stage(&stage, &mut sources, &mut diags);
    let code = c
        .material_of("/Ball")
        .and_then(|material| Compiler::new(backend, PassOptions::default()).compile(&c.library, material, &mut diags));
    (code, diags.render(&sources))
}

/// The full closure value of `code` at the test's shading point.
pub(crate) fn sum_at(code: &Arc<dyn MaterialCode>) -> ClosureSum {
    let g = Globals {
        n: [0.0, 0.0, 1.0],
        ng: [0.0, 0.0, 1.0],
        u: 0.5,
        v: 0.5,
        dpdu: [1.0, 0.0, 0.0],
        ..Globals::default()
    };
    let mut sum = ClosureSum::default();
    code.surface_sum(&g, 0, &mut sum).expect("evaluates");
    sum
}

/// The closure value of a shader body that sets `bsdf`, compiled as a substance of its own.
pub(crate) fn by_hand(body: &str) -> ClosureSum {
    let lib = common::library(&format!(
        "shader s(output closure bsdf) {{\n{body}\n}}\nsubstance by_hand {{\n    node n = s();\n    surface = n.bsdf;\n}}\n"
    ));
    sum_at(&common::compile_stack(&lib, &["by_hand".to_string()], BackendKind::Jit, true))
}

/// Asserts two closure values have the same terms: kinds, layering bits, weights and
/// parameters (within `1e-6`, for roughness taken through √α).
pub(crate) fn assert_same_terms(got: &ClosureSum, want: &ClosureSum) {
    for (k, (g, w)) in got.terms.iter().zip(&want.terms).enumerate() {
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-6);
        assert!(
            g.kind == w.kind && g.above == w.above && close(&g.weight, &w.weight) && close(&g.params, &w.params),
            "term {k}: got {g:?}\nwant {w:?}"
        );
    }
}

/// The directional albedo (largest channel) of a closure value for outgoing `wo`, by BSDF
/// sampling: (mean, standard error).
pub(crate) fn directional_albedo(sum: &ClosureSum, cos: f32, n: usize) -> (f64, f64) {
    let b = ClosureBsdf::from_sum(sum, LayeringMode::AlbedoScaling);
    let wo = glam::Vec3::new((1.0 - cos * cos).sqrt(), 0.0, cos);
    let mut rng = Rng::new(29, (cos * 1000.0) as u64, 0);
    let (mut s1, mut s2) = (0.0f64, 0.0f64);
    for _ in 0..n {
        let uc = rng.uniform();
        if let Some(s) = b.sample(wo, uc, rng.uniform2()) {
            let w = (s.f.max_element() * s.wi.z.abs() / s.pdf) as f64;
            s1 += w;
            s2 += w * w;
        }
    }
    let mean = s1 / n as f64;
    (mean, ((s2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt())
}

#[test]
fn a_pbrlib_graph_is_the_closure_algebra_written_by_hand() {
    // layered_mat.mtlx (written by MaterialX): add(multiply(mix(fg = sheen, bg =
    // layer(dielectric, oren_nayar), 0.25), 0.6), multiply(conductor, colour)) with a uniform EDF. MaterialX names the
    // definitions and connections strata translates.
    let (_, checked) = check_against_materialx("layered_mat", &["M_layered", "M_furnace"]);
    assert_eq!(checked, 30, "every node and connection MaterialX reported was checked");
    let material = "def Material \"M\" (prepend references = @layered_mat.mtlx@</MaterialX/Materials/M_layered>) {}";
    let mut sums = Vec::new();
    for backend in [BackendKind::Jit, BackendKind::Interp] {
        let (code, rendered) = compiled_with(material, backend);
        let code = code.unwrap_or_else(|| panic!("{rendered}"));
        assert!(rendered.is_empty(), "{rendered}");
        let mut e = [0.0; 3];
        code.emission(&Globals::default(), 0, &mut e).unwrap();
        assert_eq!(e, [0.5, 0.25, 0.0], "uniform_edf is the emitted radiance");
        sums.push(sum_at(&code));
    }
    assert_eq!(sums[0], sums[1], "JIT and interpreter agree");
    // The same closure in the shading language: MaterialX's mix(fg, bg, m) is mix(bg, fg, m);
    // GGX α 0.04 is perceptual roughness 0.2, α 0.09 is 0.3; the conductor's defaults are
    // MaterialX's (gold-like ior and extinction).
    let want = by_hand(
        "bsdf = mix(layer(dielectric_bsdf(color(1.0), 1.5, 0.2, \"R\"), oren_nayar_diffuse_bsdf(color(0.8, 0.5, 0.2), 0.3, 0.0)),
                    sheen_bsdf(color(0.9, 0.9, 1.0), 0.4), 0.25) * 0.6
               + conductor_bsdf(color(0.183, 0.421, 1.373), color(3.424, 2.346, 1.770), 0.3) * color(0.2, 0.3, 0.4);",
    );
    assert_same_terms(&sums[0], &want);
    let kinds: Vec<ClosureKind> = sums[0].terms.iter().map(|t| ClosureKind::from_u32(t.kind)).collect();
    assert_eq!(
        &kinds[..5],
        [
            ClosureKind::Dielectric,
            ClosureKind::OrenNayar,
            ClosureKind::Sheen,
            ClosureKind::Conductor,
            ClosureKind::None
        ]
    );
    assert_eq!(sums[0].terms[1].above, 0b1, "the Oren-Nayar base lies under the dielectric");
}

#[test]
fn pbrlib_graphs_conserve_energy_in_a_white_furnace() {
    // A half-weight clear coat over white Lambert (Oren-Nayar, roughness 0) reflects
    // everything: what the coat does not reflect reaches the white base.
    let furnace = "def Material \"M\" (prepend references = @layered_mat.mtlx@</MaterialX/Materials/M_furnace>) {}";
    let layered = "def Material \"M\" (prepend references = @layered_mat.mtlx@</MaterialX/Materials/M_layered>) {}";
    let sum = |text: &str| {
        let (code, rendered) = compiled(text);
        sum_at(&code.unwrap_or_else(|| panic!("{rendered}")))
    };
    let (furnace, layered) = (sum(furnace), sum(layered));
    let mut failures = Vec::new();
    for cos in [0.1f32, 0.4, 0.7, 1.0] {
        let (e, se) = directional_albedo(&furnace, cos, 100_000);
        if (e - 1.0).abs() > 0.01 + 4.0 * se {
            failures.push(format!("coat over white at cos {cos}: {e} ± {se}, want 1"));
        }
        let (e, se) = directional_albedo(&layered, cos, 100_000);
        if e > 1.0 + 4.0 * se {
            failures.push(format!("layered graph at cos {cos}: {e} ± {se}, want ≤ 1"));
        }
        eprintln!("cos {cos}: furnace {:.4}, layered {e:.4}", directional_albedo(&furnace, cos, 100_000).0);
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn translucent_subsurface_and_thin_film_nodes_compile_to_what_they_approximate() {
    // surface(bsdf = add(translucent · 0.5, layer(thin_film, dielectric) · 0.5)) and a
    // subsurface_bsdf on a second material.
    let shader = |name: &str, id: &str, inputs: &str| {
        format!(
            "    def Shader \"{name}\" {{\n        uniform token info:id = \"{id}\"\n{inputs}        token outputs:out\n    }}\n"
        )
    };
    let connect = |input: &str, node: &str| format!("        token inputs:{input}.connect = </M/{node}.outputs:out>\n");
    let network = [
        shader(
            "T",
            "ND_translucent_bsdf",
            "        color3f inputs:color = (0.6, 0.7, 0.8)\n        float inputs:weight = 0.5\n",
        ),
        shader("F", "ND_thin_film_bsdf", "        float inputs:thickness = 400\n"),
        shader("D", "ND_dielectric_bsdf", "        float inputs:weight = 0.5\n"),
        shader("L", "ND_layer_bsdf", &(connect("top", "F") + &connect("base", "D"))),
        shader("A", "ND_add_bsdf", &(connect("in1", "T") + &connect("in2", "L"))),
        shader("S", "ND_surface", &connect("bsdf", "A")).replace("token outputs:out", "token outputs:surface"),
    ]
    .concat();
    let text =
        format!("def Material \"M\" {{\n    token outputs:mtlx:surface.connect = </M/S.outputs:surface>\n{network}}}");
    let (code, rendered) = compiled(&text);
    let code = code.unwrap_or_else(|| panic!("{rendered}"));
    assert_eq!(rendered.matches("thin_film_bsdf is ignored").count(), 1, "{rendered}");
    let got = described(&lobes_at(&code, 0.5, 0.5), 3);
    assert_eq!(
        got,
        [
            (ClosureKind::Translucent, [0.5; 3], vec![0.6, 0.7, 0.8]),
            (ClosureKind::Dielectric, [0.5; 3], vec![1.0, 1.0, 1.0])
        ]
    );
    let subsurface = text.replace("ND_translucent_bsdf", "ND_subsurface_bsdf");
    let (code, rendered) = compiled(&subsurface);
    assert!(rendered.contains("subsurface_bsdf is approximated by diffuse transmission"), "{rendered}");
    assert_eq!(ClosureKind::from_u32(closure_at(&code.unwrap(), 0.5, 0.5).kind), ClosureKind::Translucent);
}

#[test]
fn the_translucent_lobe_is_lambert_on_the_far_side() {
    let lobe = |albedo: [f32; 3]| {
        let mut sum = ClosureSum::default();
        sum.terms[0] = ClosureTerm::from_closure(&Closure {
            kind: ClosureKind::Translucent as u32,
            params: [albedo[0], albedo[1], albedo[2], 0.0, 0.0, 0.0, 0.0, 0.0],
        });
        ClosureBsdf::from_sum(&sum, LayeringMode::AlbedoScaling)
    };
    let b = lobe([0.6, 0.7, 0.8]);
    let wo = glam::Vec3::new(0.6, 0.0, 0.8);
    // Closed form: albedo / π through the surface, nothing reflected.
    let through = glam::Vec3::new(0.3, 0.4, -0.866).normalize();
    let back = glam::Vec3::new(0.3, 0.4, 0.866).normalize();
    assert!((b.eval(wo, through) - glam::Vec3::new(0.6, 0.7, 0.8) / std::f32::consts::PI).abs().max_element() < 1e-6);
    assert_eq!(b.eval(wo, back), glam::Vec3::ZERO);
    assert_eq!(b.pdf(wo, back), 0.0);
    // Every sample crosses the surface with the pdf `pdf` reports; a white lobe is a furnace.
    let mut rng = Rng::new(3, 7, 0);
    for _ in 0..1000 {
        let uc = rng.uniform();
        let s = b.sample(wo, uc, rng.uniform2()).expect("samples");
        assert!(s.wi.z < 0.0 && (s.pdf - b.pdf(wo, s.wi)).abs() < 1e-5 * s.pdf.max(1.0), "{s:?}");
        assert!((s.f * s.wi.z.abs() / s.pdf - glam::Vec3::new(0.6, 0.7, 0.8)).abs().max_element() < 1e-5);
    }
    let (e, se) = directional_albedo(
        &ClosureSum::single(&Closure {
            kind: ClosureKind::Translucent as u32,
            params: [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        }),
        0.3,
        10_000,
    );
    assert!((e - 1.0).abs() < 1e-5 && se < 1e-5, "{e} ± {se}");
}

/// Renders a sphere under an OpenPBR coat whose coat normal is set by `coat_normal` (USDA
/// lines, with any shaders it needs in `shaders`): the beauty channels.
pub(crate) fn coated_ball_beauty(coat_normal: &str, shaders: &str) -> Vec<f32> {
    let dir = tempfile::tempdir().expect("temp dir");
    let inputs = format!(
        "        color3f inputs:base_color = (0.2, 0.4, 0.8)\n        float inputs:coat_weight = 1\n        \
         float inputs:coat_roughness = 0.15\n{coat_normal}"
    );
    let text = format!(
        "#usda 1.0\n(\n    upAxis = \"Y\"\n)\ndef Camera \"Cam\" {{\n    double3 xformOp:translate = (0, 0, 4)\n    \
         uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}}\n\
         def Sphere \"Ball\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {{ rel material:binding = </M> }}\n{}\n",
        open_pbr(&inputs, shaders)
    );
    let path = dir.path().join("ball.usda");
    std::fs::write(&path, text).expect("writes");
    let image = common::render_file(&path, &common::settings(40, 40, 8, 3, 3));
    ["R", "G", "B"].iter().flat_map(|c| image.f32_channel(c).unwrap().to_vec()).collect()
}

#[test]
fn a_coat_normal_equal_to_the_surface_normal_renders_today_s_image_and_a_tilted_one_does_not() {
    // Unset, the coat uses the surface normal N; wired to MaterialX's `normal` node (world
    // space) it is N again: bit for bit the same image. A constant tilted normal is not.
    let unset = coated_ball_beauty("", "");
    let normal_node = "    def Shader \"Nworld\" {\n        uniform token info:id = \"ND_normal_vector3\"\n        \
                       string inputs:space = \"world\"\n        float3 outputs:out\n    }";
    let wired = coated_ball_beauty(
        "        float3 inputs:geometry_coat_normal.connect = </M/Nworld.outputs:out>\n",
        normal_node,
    );
    assert!(unset.iter().any(|x| *x > 0.0), "the ball renders");
    assert!(
        unset.iter().zip(&wired).all(|(a, b)| a.to_bits() == b.to_bits()),
        "a coat normal equal to N changed the image"
    );
    let tilted = coated_ball_beauty("        float3 inputs:geometry_coat_normal = (0.6, 0, 0.8)\n", "");
    let changed = unset.iter().zip(&tilted).filter(|(a, b)| a != b).count();
    assert!(changed > unset.len() / 4, "a tilted coat normal changed only {changed} of {} values", unset.len());
}

#[test]
fn thin_film_and_unlit_surfaces_reach_their_closures() {
    // OpenPBR's film (thickness in µm) on the specular reflection, the transmission and the
    // metal: the dielectric "R" and "RT" terms and the F82 metal each carry 300 nm of index
    // 1.33 at weight 0.75 in their film words, and nothing is reported.
    let (code, rendered) = compiled(&open_pbr(
        "        float inputs:thin_film_weight = 0.75\n        float inputs:thin_film_thickness = 0.3\n        \
         float inputs:thin_film_ior = 1.33\n        float inputs:base_metalness = 0.5\n        \
         float inputs:transmission_weight = 0.5",
        "",
    ));
    let lobes = lobes_at(&code.unwrap_or_else(|| panic!("{rendered}")), 0.5, 0.5);
    for (kind, terms) in [(ClosureKind::Dielectric, 2), (ClosureKind::GeneralizedSchlick, 1)] {
        let filmed: Vec<_> = lobes.iter().filter(|t| t.kind == kind as u32).collect();
        assert_eq!(filmed.len(), terms, "{kind:?}: {lobes:?}");
        let at = strata::abi::thin_film_words(kind).unwrap();
        for term in filmed {
            let words = &term.params[at..at + 3];
            assert!((words[0] - 300.0).abs() < 1e-3 && words[1] == 1.33 && words[2] == 0.75, "{kind:?}: {term:?}");
        }
    }
    assert!(!rendered.contains("thin_film"), "{rendered}");
    // surface_unlit: emission · emission_color is the emission product, no BSDF.
    let text = "def Material \"M\" {\n    token outputs:mtlx:surface.connect = </M/S.outputs:surface>\n    \
                def Shader \"S\" {\n        uniform token info:id = \"ND_surface_unlit\"\n        \
                float inputs:emission = 2\n        color3f inputs:emission_color = (0.5, 0.25, 1)\n        \
                token outputs:surface\n    }\n}";
    let (code, rendered) = compiled(text);
    let code = code.unwrap_or_else(|| panic!("{rendered}"));
    assert!(rendered.is_empty(), "{rendered}");
    assert!(lobes_at(&code, 0.5, 0.5).is_empty(), "an unlit surface has no lobe");
    let mut emitted = [0.0f32; 3];
    let g = Globals { n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], ..Globals::default() };
    code.emission(&g, 0, &mut emitted).expect("emits");
    assert_eq!(emitted, [1.0, 0.5, 2.0]);
}

#[test]
fn thin_film_layers_of_1_38_read_as_materialx_upgrades_them() {
    // Each target of a 1.38 document against the same target of MaterialX's own reading of it
    // (`tests/fixtures/mtlx/upgrade`): the film folded into the BSDFs below it, values and
    // connections alike.
    let graphs = (1..=8).map(|k| ("thin_film_bsdf_1_38", format!("thin_film_test{k}")));
    let bound = ["bound", "unauthored", "over_diffuse"].map(|g| ("thin_film_bindings_1_38", g.to_string()));
    let mut filmed = 0;
    for (doc, graph) in graphs.chain(bound) {
        let target = ["shade", graph.as_str(), "out"];
        let (code, rendered) = suite_target(&format!("../upgrade/{doc}.mtlx"), &target);
        let (want, _) = suite_target(&format!("../upgrade/{doc}.upgraded.mtlx"), &target);
        let (got, want) = (sum_at(&code.unwrap_or_else(|| panic!("{rendered}"))), sum_at(&want.unwrap()));
        assert_same_terms(&got, &want);
        // A document's translation warnings come with each of its materials: the bindings
        // document's film without thickness and film over a diffuse lobe; nothing else.
        let expected = match doc {
            "thin_film_bsdf_1_38" => vec![],
            _ => vec!["authors no `thickness`", "covers no dielectric, conductor or generalized Schlick BSDF"],
        };
        assert_eq!(rendered.matches("warning").count(), expected.len(), "{graph}: {rendered}");
        assert!(expected.iter().all(|w| rendered.contains(w)), "{graph}: {rendered}");
        for term in got.terms.iter().filter(|t| t.kind != 0) {
            let kind = ClosureKind::from_u32(term.kind);
            filmed += strata::abi::thin_film_words(kind).is_some_and(|at| term.params[at] > 0.0) as usize;
        }
    }
    // Not vacuous: the films are there (tests 1–8 film 10 BSDFs; `bound` its metal).
    assert!(filmed >= 11, "{filmed} filmed terms");
    let (code, rendered) = suite_target("../upgrade/thin_film_bindings_1_38.mtlx", &["material", "top_material"]);
    let (want, _) = suite_target("../upgrade/thin_film_bindings_1_38.upgraded.mtlx", &["material", "top_material"]);
    assert_same_terms(&sum_at(&code.unwrap_or_else(|| panic!("{rendered}"))), &sum_at(&want.unwrap()));
}
