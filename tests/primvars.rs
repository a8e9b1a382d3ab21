//! Primvars reach shading (issue 19, items 3 and 4), on fixtures written by Pixar's USD library
//! (`tools/make_primvar_fixtures.py`, in `tests/fixtures/usd/primvars/`). References are
//! independent of strata: per-face-vertex values from usd-core's `ComputeFlattened`, colours
//! as authored in the fixtures, texels decoded from `checker.png` with the `png` crate.

mod common;

use std::path::Path;
use strata::abi::{Globals, PrimvarInfo, PrimvarValues};
use strata::backend::BackendKind;
use strata::diag::{Diagnostics, SourceMap};
use strata::render::Image;
use strata::render::geometry::primvars::PrimvarRef;
use strata::render::geometry::xform::world_transforms;
use strata::render::geometry::{GeometryOptions, build_with_primvars};
use strata::scene::Stage;

const DIR: &str = "tests/fixtures/usd/primvars";

#[derive(serde::Deserialize)]
struct Oracle {
    counts: Vec<usize>,
    cases: Vec<Case>,
}

#[derive(serde::Deserialize)]
struct Case {
    mesh: String,
    name: String,
    interpolation: String,
    indexed: bool,
    per_face_vertex: Vec<Vec<f32>>,
}

/// Every interpolation, indexed or not, of every primvar type: the values strata stores at each
/// triangle corner (read back through the hit-point path, `PrimvarTable::fill`, at each corner's
/// barycentrics) are usd-core's flattened values at that face-vertex.
#[test]
fn corner_values_are_usd_cores_flattened_primvars() {
    let oracle: Oracle =
        serde_json::from_str(&std::fs::read_to_string(format!("{DIR}/interpolation.json")).unwrap()).unwrap();
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(Path::new(&format!("{DIR}/interpolation.usda")), &mut sources, &mut diags).expect("opens");
    let xforms = world_transforms(&stage, &mut diags);
    let mut names: Vec<String> = oracle.cases.iter().map(|c| c.name.clone()).collect();
    names.sort();
    names.dedup();
    let geometry = build_with_primvars(&stage, &xforms, GeometryOptions::default(), &names, &mut diags);
    assert!(diags.items().is_empty(), "{}", diags.render(&sources));
    // The material's view: each name read with four components (a float read is its first
    // component, a triple's its first three; a color4's fourth is what `primvar_alpha` reads).
    let infos: Vec<PrimvarInfo> =
        names.iter().enumerate().map(|(i, name)| PrimvarInfo { name: name.clone(), width: 4, offset: 5 * i }).collect();
    let slots = geometry.primvars.slots(&infos);
    // Fan triangulation of the quad (face-vertices 0..4) and the triangle (4..7).
    assert_eq!(oracle.counts, [4, 3]);
    let corners_of = [[0usize, 1, 2], [0, 2, 3], [4, 5, 6]];
    let mut checked = 0;
    for case in &oracle.cases {
        let prim = geometry.prims.iter().position(|p| p.path == case.mesh).expect("mesh built") as u32;
        let triangles: Vec<_> = geometry.triangles.iter().filter(|t| t.prim == prim).collect();
        assert_eq!(triangles.len(), 3, "{}", case.mesh);
        let slot = names.iter().position(|n| *n == case.name).unwrap();
        for (t, corners) in triangles.iter().zip(corners_of) {
            assert_ne!(t.primvars, PrimvarRef::NONE, "{}", case.mesh);
            for (k, fv) in corners.into_iter().enumerate() {
                let mut bary = [0.0; 3];
                bary[k] = 1.0;
                let mut out = vec![f32::NAN; 5 * names.len()];
                geometry.primvars.fill(t.primvars, bary, &slots, &mut out);
                let got = &out[5 * slot..5 * slot + 5];
                let want = &case.per_face_vertex[fv];
                let what = format!(
                    "{} ({} {}{}), face-vertex {fv}",
                    case.mesh,
                    case.name,
                    case.interpolation,
                    if case.indexed { ", indexed" } else { "" }
                );
                assert_eq!(got[0], 1.0, "{what}: present");
                for c in 0..4 {
                    let expected = want.get(c).copied().unwrap_or(0.0);
                    assert_eq!(got[1 + c], expected, "{what}: component {c}: got {got:?}, want {want:?}");
                }
                // The other names are absent from this mesh: flag and components 0.
                for (other, _) in names.iter().enumerate().filter(|&(i, n)| i != slot && *n != case.name) {
                    assert_eq!(&out[5 * other..5 * other + 5], &[0.0; 5], "{what}: {} absent", names[other]);
                }
                checked += 1;
            }
        }
    }
    assert_eq!(checked, oracle.cases.len() * 9);
    // Every interpolation, indexed and not, is among the cases.
    for interp in ["constant", "uniform", "vertex", "varying", "faceVarying"] {
        for indexed in [false, true] {
            assert!(
                oracle.cases.iter().any(|c| c.interpolation == interp && c.indexed == indexed),
                "{interp} {indexed}"
            );
        }
    }
}

/// Image size of the display and st0 renders.
const RES: usize = 32;

fn channel(image: &Image, name: &str, x: usize, y: usize) -> f32 {
    image.f32_channel(name).unwrap_or_else(|| panic!("channel {name}"))[y * RES + x]
}

fn albedo(image: &Image, x: usize, y: usize) -> [f32; 3] {
    ["albedo.R", "albedo.G", "albedo.B"].map(|c| channel(image, c, x, y))
}

fn assert_close(got: [f32; 3], want: [f32; 3], tolerance: f32, at: &str) {
    let d = (0..3).map(|k| (got[k] - want[k]).abs()).fold(0.0, f32::max);
    assert!(d <= tolerance, "{at}: got {got:?}, want {want:?}");
}

/// Unbound geometry is drawn with its displayColor (uniform per face on a mesh, constant on an
/// analytic sphere) and displayOpacity, as Hydra draws it. Under a uniform white dome of
/// radiance 1 an unoccluded diffuse surface's radiance is its albedo exactly, so the beauty
/// pixels equal the authored colour within noise, and the albedo AOV equals it exactly.
#[test]
fn display_color_and_opacity_colour_unbound_geometry() {
    let image = common::render_file(Path::new(&format!("{DIR}/display.usda")), &common::settings(RES, RES, 64, 7, 4));
    // Pixel (x, y) sees (x, y) = (-1 + (2x + 1) / 32, 1 - (2y + 1) / 32) on the z = 0 plane.
    let faces = [
        ("/World/Left face 0 (bottom)", 20..30, [0.8, 0.3, 0.1]),
        ("/World/Left face 1 (top)", 2..12, [0.1, 0.6, 0.9]),
    ];
    for (what, rows, colour) in faces {
        let mut mean = [0.0f64; 3];
        let mut n = 0.0;
        for y in rows {
            for x in 2..14 {
                assert_close(albedo(&image, x, y), colour, 1e-6, &format!("{what}: albedo at ({x}, {y})"));
                for (c, name) in ["R", "G", "B"].iter().enumerate() {
                    mean[c] += channel(&image, name, x, y) as f64;
                }
                n += 1.0;
            }
        }
        let mean = mean.map(|m| (m / n) as f32);
        assert_close(mean, colour, 0.01 * 0.9, &format!("{what}: mean beauty"));
    }
    // The sphere (analytic), radius 0.4 at (0.5, 0.5, -1): its centre projects to pixel (22.7, 9.3).
    for (x, y) in [(22, 9), (23, 10), (21, 8)] {
        assert_close(albedo(&image, x, y), [0.2, 0.7, 0.3], 1e-6, &format!("/World/Ball at ({x}, {y})"));
    }
    // displayOpacity 0.25 (indexed constant): a quarter of the samples stop there, over the sky.
    let mut alpha = 0.0;
    let mut n = 0.0;
    for y in 18..30 {
        for x in 18..30 {
            alpha += channel(&image, "A", x, y);
            n += 1.0;
        }
    }
    let alpha = alpha / n;
    assert!((alpha - 0.25).abs() < 0.02, "/World/Faint: mean alpha {alpha}, want 0.25");
}

#[test]
fn layers_say_which_display_primvars_the_default_substance_reads() {
    let out = common::run_strata(&["layers", &format!("{DIR}/display.usda")], std::time::Duration::from_secs(60))
        .expect("strata finishes");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    for expected in [
        "/World/Left\n  (default substance: displayColor)\n",
        "/World/Faint\n  (default substance: white, displayOpacity)\n",
        "/World/Ball\n  (default substance: displayColor)\n",
    ] {
        assert!(text.contains(expected), "{expected:?} in\n{text}");
    }
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// The linear colour of `checker.png`'s texel under pixel (x, y), decoded with the `png`
/// crate: the pixel centre sees st = ((x + 0.5) / RES, 1 − (y + 0.5) / RES), and texture row
/// 0 is t = 1.
fn texel_under(x: usize, y: usize) -> [f32; 3] {
    let file = std::fs::File::open(format!("{DIR}/checker.png")).unwrap();
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.color_type, info.bit_depth), (png::ColorType::Rgb, png::BitDepth::Eight));
    let width = info.width as usize;
    let s = (x as f32 + 0.5) / RES as f32;
    let t = 1.0 - (y as f32 + 0.5) / RES as f32;
    let (tx, ty) = ((s * width as f32) as usize, ((1.0 - t) * width as f32) as usize);
    let at = 3 * (ty * width + tx);
    [buf[at], buf[at + 1], buf[at + 2]].map(|c| srgb_to_linear(c as f32 / 255.0))
}

/// A UsdPrimvarReader_float2 reading `st0` (an indexed faceVarying primvar; the mesh has no
/// `st`) drives the UsdUVTexture: the albedo AOV is the texel under each pixel.
#[test]
fn a_reader_of_st0_drives_the_texture() {
    let image = common::render_file(Path::new(&format!("{DIR}/st0.usda")), &common::settings(RES, RES, 4, 3, 2));
    let mut distinct = Vec::new();
    for (x, y) in (0..4).flat_map(|cy| (0..4).map(move |cx| (cx * 8 + 3, cy * 8 + 4))) {
        let want = texel_under(x, y);
        assert_close(albedo(&image, x, y), want, 1e-4, &format!("st0.usda: pixel ({x}, {y})"));
        distinct.push(want.map(f32::to_bits));
    }
    distinct.sort();
    distinct.dedup();
    assert_eq!(distinct.len(), 16, "16 distinct cells: a wrong mapping fails");
}

/// A substance reading primvars through the `primvar` nodes: the JIT and the interpreter agree
/// bit for bit, on present, absent, short and special values (and the fallback is used
/// exactly where the flag is 0 or the values end).
#[test]
fn primvar_nodes_agree_across_backends_bit_for_bit() {
    let lib = common::library(
        "shader as_colour(vector x = vector(0.0, 0.0, 0.0), output color out) { out = color(x); }\n\
         substance pv {\n\
         node c = primvar(name: \"displayColor\", fallback: color(0.5, 0.25, 1.0));\n\
         node f = primvar_float(name: \"rough\", fallback: 0.3);\n\
         node v = primvar_vector(name: \"dir\", fallback: vector(0.0, 0.0, 1.0));\n\
         node vc = as_colour(x: v.out);\n\
         node d = glossy(albedo: c.out, roughness: f.out, specular: vc.out);\n\
         node m = mask(opacity: f.out);\n\
         node ch = customChannelColor(name: \"dir\", value: vc.out);\n\
         node cf = customChannelFloat(name: \"rough\", value: f.out);\n\
         surface = d.bsdf;\n\
         mask = m.out;\n\
         }",
    );
    let names = vec!["pv".to_string()];
    let codes = [
        common::compile_stack(&lib, &names, BackendKind::Jit, true),
        common::compile_stack(&lib, &names, BackendKind::Jit, false),
        common::compile_stack(&lib, &names, BackendKind::Interp, true),
        common::compile_stack(&lib, &names, BackendKind::Interp, false),
    ];
    let info = codes[0].info().clone();
    let mut read: Vec<(&str, usize)> = info.primvars.iter().map(|p| (p.name.as_str(), p.width)).collect();
    read.sort();
    assert_eq!(read, [("dir", 3), ("displayColor", 3), ("rough", 1)]);
    assert_eq!(info.primvar_floats, 10);
    for code in &codes {
        assert_eq!(code.info(), &info);
    }
    let offset = |name: &str| info.primvars.iter().find(|p| p.name == name).unwrap().offset;
    let flags = ["displayColor", "rough", "dir"].map(offset);
    let rough_at = offset("rough");
    let specials = [0.0, -0.0, 1.0, 0.75, f32::NAN, f32::INFINITY, -2.5, 1e-40];
    let mut value_sets: Vec<Vec<f32>> = vec![Vec::new()];
    for i in 0..40u32 {
        let mut values: Vec<f32> = (0..10).map(|k| specials[((i * 7 + k * 3) % 8) as usize]).collect();
        for (bit, &flag) in flags.iter().enumerate() {
            values[flag] = if (i >> bit) & 1 == 1 { 1.0 } else { 0.0 };
        }
        values.truncate(10 - (i % 4) as usize * 3);
        value_sets.push(values);
    }
    let mut saw_fallback = false;
    let mut saw_value = false;
    for values in &value_sets {
        let g = Globals {
            n: [0.0, 0.0, 1.0],
            ng: [0.0, 0.0, 1.0],
            i: [0.0, 0.0, -1.0],
            st_footprint: [0.0; 4],
            primvars: PrimvarValues::new(values),
            ..Globals::default()
        };
        let outputs: Vec<Vec<u32>> = codes
            .iter()
            .map(|code| {
                let mut closure = strata::abi::Closure::default();
                code.surface(&g, 0, &mut closure).expect("surface");
                let mut channels = vec![0.0f32; code.info().channel_floats];
                code.channels(&g, 0, &mut channels).expect("channels");
                let mask = code.mask(&g, 0).expect("mask");
                let mut words = vec![closure.kind];
                words.extend(closure.params.iter().map(|p| p.to_bits()));
                words.extend(channels.iter().map(|c| c.to_bits()));
                words.push(mask.to_bits());
                words
            })
            .collect();
        for (k, out) in outputs.iter().enumerate().skip(1) {
            assert_eq!(out, &outputs[0], "backend {k} vs JIT at {values:?}");
        }
        // `rough` reaches the custom channel as it is where its flag is non-zero (0 past the
        // end of the values), else the fallback 0.3.
        let rough = f32::from_bits(*outputs[0].last().unwrap());
        let channel_rough = f32::from_bits(outputs[0][1 + 8 + 3]);
        match values.get(rough_at) {
            Some(flag) if *flag != 0.0 => {
                saw_value = true;
                let value = values.get(rough_at + 1).copied().unwrap_or(0.0);
                assert_eq!(channel_rough.to_bits(), value.to_bits(), "{channel_rough} vs {value} at {values:?}");
            }
            _ => {
                saw_fallback = true;
                assert_eq!(channel_rough, 0.3, "{values:?}");
                assert_eq!(rough, 0.3);
            }
        }
    }
    assert!(saw_fallback && saw_value);
}

/// The object-space position (`strata:Pobject`, what MaterialX's `position` and 3D noises read
/// by default) at each corner of a moved, turned and scaled mesh is the point as authored in
/// the layer, while the corner itself is in world space: the transform is undone exactly,
/// whatever it is. The reference is the USDA text's own `points`, not strata's transforms.
#[test]
fn the_object_space_position_is_the_authored_point() {
    let points = [[0.0f32, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.5], [0.0, 1.0, 0.5]];
    let text = format!(
        "#usda 1.0\ndef Mesh \"Quad\" {{\n    uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [4]\n    int[] faceVertexIndices = [0, 1, 2, 3]\n    \
         point3f[] points = [{}]\n    double3 xformOp:translate = (5, -3, 2)\n    float3 xformOp:rotateXYZ = (30, 45, 10)\n    \
         float3 xformOp:scale = (2, 0.5, 3)\n    uniform token[] xformOpOrder = [\"xformOp:translate\", \"xformOp:rotateXYZ\", \"xformOp:scale\"]\n}}\n",
        points.iter().map(|p| format!("({}, {}, {})", p[0], p[1], p[2])).collect::<Vec<_>>().join(", ")
    );
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::from_text("quad.usda", &text, Path::new("."), &mut sources, &mut diags).expect("parses");
    let xforms = world_transforms(&stage, &mut diags);
    let names = vec![strata::render::geometry::primvars::OBJECT_POSITION.to_string()];
    let geometry = build_with_primvars(&stage, &xforms, GeometryOptions::default(), &names, &mut diags);
    assert!(diags.items().is_empty(), "{}", diags.render(&sources));
    let infos = [PrimvarInfo { name: names[0].clone(), width: 3, offset: 0 }];
    let slots = geometry.primvars.slots(&infos);
    let mut corners = 0;
    // Each authored point lands on one world position, on both triangles that share it.
    let mut world_of: Vec<([f32; 3], glam::Vec3)> = Vec::new();
    for t in geometry.triangles.iter() {
        for k in 0..3 {
            let mut bary = [0.0; 3];
            bary[k] = 1.0;
            let mut out = [f32::NAN; 4];
            geometry.primvars.fill(t.primvars, bary, &slots, &mut out);
            assert_eq!(out[0], 1.0, "present");
            let object = [out[1], out[2], out[3]];
            assert!(points.contains(&object), "corner {k}: {object:?} is not an authored point");
            // The corner itself moved: world space is not object space here.
            assert!((t.p[k] - glam::Vec3::from(object)).length() > 1.0, "{:?} vs {object:?}", t.p[k]);
            match world_of.iter().find(|(o, _)| *o == object) {
                Some((_, world)) => assert!((*world - t.p[k]).length() < 1e-5, "{object:?}: {world} and {}", t.p[k]),
                None => world_of.push((object, t.p[k])),
            }
            corners += 1;
        }
    }
    assert_eq!((corners, world_of.len()), (6, 4));
}
