//! Time codes and UsdSkel against Pixar's USD library: values at times from `attr.Get(t)` and
//! world-space skinned points from `UsdSkel.BakeSkinning`, committed by
//! `tools/make_skel_fixtures.py` in `tests/fixtures/skel/`.

use exr::meta::attribute::AttributeValue;
use exr::prelude::{FlatSamples, ReadChannels, ReadLayers};
use glam::{DMat4, DVec3};
use serde_json::Value as Json;
use std::path::Path;
use std::process::Command;
use strata::diag::{Diagnostics, SourceMap};
use strata::render::geometry::skel::skinned_world_points;
use strata::render::geometry::xform::world_transforms;
use strata::scene::{Stage, TimeCode, Value};

const DIR: &str = "tests/fixtures/skel";

fn open(name: &str) -> Stage {
    let mut sources = SourceMap::new();
    let mut diags = Diagnostics::new();
    let stage = Stage::open(&Path::new(DIR).join(name), &mut sources, &mut diags);
    let text = diags.render(&sources);
    stage.unwrap_or_else(|_| panic!("{text}"))
}

fn expected(name: &str) -> Json {
    serde_json::from_str(&std::fs::read_to_string(Path::new(DIR).join(name)).unwrap()).unwrap()
}

/// A value as USD's flattened form in the expectations: numbers, or a string.
fn flat(value: &Value) -> Json {
    let numbers = |v: &[f64]| Json::from(v.to_vec());
    match value {
        Value::Bool(b) => numbers(&[f64::from(u8::from(*b))]),
        Value::Int(i) => numbers(&[*i as f64]),
        Value::Float(x) => numbers(&[*x]),
        Value::Token(s) | Value::String(s) => Json::from(s.clone()),
        Value::Tuple(v) => numbers(v),
        Value::FloatArray(v) | Value::TupleArray { data: v, .. } => numbers(v),
        Value::Matrix(m) => numbers(m),
        Value::IntArray(v) => numbers(&v.iter().map(|&i| i as f64).collect::<Vec<_>>()),
        other => panic!("unexpected value {other:?}"),
    }
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance * b.abs().max(1.0)
}

fn same(got: &Json, want: &Json, tolerance: f64) -> bool {
    match (got, want) {
        (Json::Array(g), Json::Array(w)) => {
            g.len() == w.len()
                && g.iter().zip(w).all(|(g, w)| close(g.as_f64().unwrap(), w.as_f64().unwrap(), tolerance))
        }
        _ => got == want,
    }
}

fn time_key(t: TimeCode) -> String {
    match t {
        TimeCode::Default => "default".into(),
        // Python's repr of a float: `5.0`, `-5.0`, `12.5`.
        TimeCode::At(t) => format!("{t:?}"),
    }
}

const TIMES: [f64; 8] = [-5.0, 0.0, 2.5, 5.0, 10.0, 12.5, 20.0, 25.0];

fn check_time_samples(names: &[&str]) {
    let mut stage = open("timesamples.usda");
    let want = expected("timesamples_expected.json");
    assert_eq!(stage.time(), TimeCode::At(want["start"].as_f64().unwrap()), "the stage opens at startTimeCode");
    let times = std::iter::once(TimeCode::Default).chain(TIMES.map(TimeCode::At));
    let mut checked = 0;
    for t in times {
        stage.set_time(t);
        for entry in want["attributes"].as_array().unwrap() {
            let (path, name) = (entry["prim"].as_str().unwrap(), entry["attribute"].as_str().unwrap());
            if !names.is_empty() && !names.contains(&name) || names.is_empty() && name.ends_with("Retimed") {
                continue;
            }
            let prim = stage.prim(stage.find(path).unwrap_or_else(|| panic!("no {path}")));
            let got = prim.value(name).map_or(Json::Null, flat);
            let expect = &entry["values"][time_key(t)];
            // Half-precision values (quath) were rounded by USD.
            let tolerance = if name == "qs" { 2e-3 } else { 1e-6 };
            assert!(same(&got, expect, tolerance), "{path}.{name} at {t}: strata {got}, usd-core {expect}");
            checked += 1;
        }
        if names.is_empty() {
            let mut diags = Diagnostics::new();
            let xforms = world_transforms(&stage, &mut diags);
            for entry in want["world"].as_array().unwrap() {
                let path = entry["prim"].as_str().unwrap();
                let Some(m) = entry["matrices"].get(time_key(t)) else { continue };
                let m: Vec<f64> = m.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
                // USD's row-vector matrix, row-major, is glam's column-vector one read by columns.
                let want = DMat4::from_cols_slice(&m);
                let got = xforms[stage.find(path).unwrap().0 as usize].world;
                assert!(got.abs_diff_eq(want, 1e-5), "{path} world at {t}: strata {got}, usd-core {want}");
                checked += 1;
            }
        }
    }
    assert!(checked >= 18, "only {checked} values checked");
}

/// xformOps (translate, rotateXYZ, orient slerped the short way, scale, transform), points
/// whose length changes (held), a light's intensity and colour, a camera's focal length, a
/// material input, held ints, tokens and bools, half quaternion arrays, and the strength
/// order of samples against defaults across a sublayer — before, on, between and after the
/// samples and at the default time.
#[test]
fn values_at_times_match_usd() {
    check_time_samples(&[]);
}

/// Layer offsets: samples in a reference with `(offset = 5; scale = 2)` and in a sublayer
/// with `(offset = -4; scale = 0.5)` are retimed into the stage's time.
#[test]
fn layer_offsets_retime_samples_as_usd() {
    check_time_samples(&["refRetimed", "subRetimed"]);
}

fn points(json: &Json) -> Vec<DVec3> {
    json.as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let p: Vec<f64> = p.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            DVec3::from_slice(&p)
        })
        .collect()
}

/// Linear blend skinning (elementSize 1, 2 and 4, a per-mesh joint order, a non-identity
/// geomBindTransform, a rigid constant binding), an animation of two of three joints in
/// another order (slerped quaternions, scales), a sparse blend shape with an in-between and
/// skinned normals, point by point against usd-core's baked skinning at ten times.
#[test]
fn skinned_points_match_usd_bake_skinning() {
    let mut stage = open("arm.usda");
    let want = expected("arm_expected.json");
    let mut checked = 0;
    for t in want["times"].as_array().unwrap() {
        let t = t.as_f64().unwrap();
        stage.set_time(TimeCode::At(t));
        let mut diags = Diagnostics::new();
        let xforms = world_transforms(&stage, &mut diags);
        for mesh in want["meshes"].as_array().unwrap() {
            let path = mesh["prim"].as_str().unwrap();
            let id = stage.find(path).unwrap();
            let (got, normals) =
                skinned_world_points(&stage, &xforms, id, &mut diags).unwrap_or_else(|| panic!("{path} is skinned"));
            let key = format!("{t}");
            let expect = points(&mesh["points"][&key]);
            assert_eq!(got.len(), expect.len(), "{path}");
            for (i, (g, e)) in got.iter().zip(&expect).enumerate() {
                let err = (*g - *e).length();
                assert!(err <= 1e-4 * e.length().max(1.0), "{path} point {i} at t={t}: strata {g}, usd-core {e}");
            }
            checked += got.len();
            if let Some(expect) = mesh["normals"].get(&key) {
                let normals = normals.unwrap_or_else(|| panic!("{path} has skinned normals"));
                for (i, (g, e)) in normals.iter().zip(points(expect)).enumerate() {
                    assert!((*g - e).length() <= 1e-4, "{path} normal {i} at t={t}: strata {g}, usd-core {e}");
                }
            }
        }
        assert!(diags.items().is_empty(), "{:?}", diags.items().iter().map(|d| &d.message).collect::<Vec<_>>());
    }
    assert!(checked > 500, "{checked}");
}

/// Skinned points between the animation's samples, where deformation blur poses them (on a
/// copy of the stage at each shutter key, `Stage::at_time`): usd-core's
/// `SkinningQuery.ComputeSkinnedPoints` at fractional times
/// (`tools/make_skel_fractional_expected.py`), for the meshes without blend shapes.
#[test]
fn skinned_points_at_fractional_times_match_usd() {
    let stage = open("arm.usda");
    let want = expected("arm_fractional_expected.json");
    let mut checked = 0;
    for t in want["times"].as_array().unwrap() {
        let t = t.as_f64().unwrap();
        assert!(t.fract() != 0.0);
        let at = stage.at_time(TimeCode::At(t));
        let mut diags = Diagnostics::new();
        let xforms = world_transforms(&at, &mut diags);
        for mesh in want["meshes"].as_array().unwrap() {
            let path = mesh["prim"].as_str().unwrap();
            let (got, _) = skinned_world_points(&at, &xforms, at.find(path).unwrap(), &mut diags)
                .unwrap_or_else(|| panic!("{path} is skinned"));
            let expect = points(&mesh["points"][&format!("{t}")]);
            assert_eq!(got.len(), expect.len(), "{path}");
            for (i, (g, e)) in got.iter().zip(&expect).enumerate() {
                let err = (*g - *e).length();
                assert!(err <= 1e-4 * e.length().max(1.0), "{path} point {i} at t={t}: strata {g}, usd-core {e}");
            }
            checked += got.len();
        }
        assert!(diags.items().is_empty(), "{:?}", diags.items().iter().map(|d| &d.message).collect::<Vec<_>>());
    }
    assert!(checked > 100, "{checked}");
}

/// The geometry builder emits the posed points: every vertex of the skinned strip's
/// triangles is one of USD's baked points at that time, and the rest pose is not.
#[test]
fn rendered_triangles_are_the_posed_ones() {
    let mut stage = open("arm.usda");
    let want = expected("arm_expected.json");
    let two = want["meshes"].as_array().unwrap().iter().find(|m| m["prim"] == "/Arm/Two").unwrap();
    stage.set_time(TimeCode::At(13.0));
    let mut diags = Diagnostics::new();
    let geometry = strata::render::geometry::build(&stage, &mut diags);
    let index = geometry.prims.iter().position(|p| p.path == "/Arm/Two").unwrap() as u32;
    let expect = points(&two["points"]["13"]);
    let rest = points(&two["points"]["0"]);
    let vertices: Vec<DVec3> =
        geometry.triangles.iter().filter(|t| t.prim == index).flat_map(|t| t.p).map(|p| p.as_dvec3()).collect();
    assert!(!vertices.is_empty());
    for v in &vertices {
        assert!(expect.iter().any(|e| (*e - *v).length() < 1e-4), "{v} is not a posed point");
    }
    assert!(vertices.iter().any(|v| rest.iter().all(|r| (*r - *v).length() > 1e-2)), "posed, not at rest");
}

/// `--time` picks the frame: the animated sphere moves across the image, and the EXR header
/// records the time (`strata/time`), `default` included.
#[test]
fn cli_time_changes_the_image_and_is_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let render = |time: Option<&str>, name: &str| {
        let out = dir.path().join(name);
        let mut args = vec!["render", "tests/fixtures/skel/moving.usda", "--res", "32x16", "--spp", "2"];
        if let Some(t) = time {
            args.extend(["--time", t]);
        }
        args.extend(["-o", out.to_str().unwrap()]);
        let output = Command::new(env!("CARGO_BIN_EXE_strata")).args(&args).output().unwrap();
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_file(&out)
            .unwrap();
        let time = match image.layer_data.attributes.other.get(&exr::meta::attribute::Text::from("strata/time")) {
            Some(AttributeValue::Text(t)) => t.to_string(),
            other => panic!("strata/time: {other:?}"),
        };
        let red = image.layer_data.channel_data.list.iter().find(|c| c.name.to_string() == "R").unwrap();
        let pixels: Vec<f32> = match &red.sample_data {
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
            FlatSamples::U32(_) => panic!("R is an integer channel"),
        };
        (pixels, time)
    };
    // Brightness-weighted mean column: where the sphere is.
    let centre = |pixels: &[f32]| {
        let (mut sum, mut weight) = (0.0, 0.0);
        for (i, v) in pixels.iter().enumerate() {
            sum += (i % 32) as f32 * v;
            weight += v;
        }
        sum / weight
    };
    let (start, start_time) = render(None, "start.exr");
    let (end, end_time) = render(Some("10"), "end.exr");
    let (_, default_time) = render(Some("default"), "default.exr");
    assert_eq!((start_time.as_str(), end_time.as_str(), default_time.as_str()), ("0", "10", "default"));
    assert!(centre(&start) < 14.0 && centre(&end) > 18.0, "{} → {}", centre(&start), centre(&end));

    let bad = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["check", "tests/fixtures/skel/moving.usda", "--time", "soon"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a time code"));
}
