//! MaterialX object space beyond `position`: `normal`, `tangent`, `bitangent` and the space
//! transforms read the prim's own space through the transforms the integrator gives the hit
//! (`render::geometry::primvars::OBJECT_TO_WORLD`, `WORLD_TO_OBJECT`). The answers are closed
//! forms of the prim's transform (an object-space value carried to world space by a matrix the
//! test builds, then expected back), and in a render the authored translations themselves.

use super::*;
use glam::{DMat4, DVec3};
use strata::render::geometry::primvars::{ObjectSpace, PrimvarTable, fill_object_space};

/// A material `/M` whose unlit emission is `node`'s `out` (a vector3 node, `inputs` as USDA
/// lines), converted to a colour.
fn emitting(node: &str, inputs: &str) -> String {
    format!(
        "def Material \"M\" {{\n    token outputs:mtlx:surface.connect = </M/S.outputs:surface>\n    \
         def Shader \"S\" {{\n        uniform token info:id = \"ND_surface_unlit\"\n        \
         color3f inputs:emission_color.connect = </M/C.outputs:out>\n        token outputs:surface\n    }}\n    \
         def Shader \"N\" {{\n        uniform token info:id = \"ND_{node}_vector3\"\n{inputs}        vector3f outputs:out\n    }}\n    \
         def Shader \"C\" {{\n        uniform token info:id = \"ND_convert_vector3_color3\"\n        \
         vector3f inputs:in.connect = </M/N.outputs:out>\n        color3f outputs:out\n    }}\n}}\n"
    )
}

/// A moved, turned and non-uniformly scaled object space (translate, rotate about three axes,
/// scale, in USD's order).
fn transform() -> DMat4 {
    DMat4::from_translation(DVec3::new(5.0, -3.0, 2.0))
        * DMat4::from_rotation_z(10f64.to_radians())
        * DMat4::from_rotation_y(45f64.to_radians())
        * DMat4::from_rotation_x(30f64.to_radians())
        * DMat4::from_scale(DVec3::new(2.0, 0.5, 3.0))
}

/// What the material of [`emitting`]`(node, inputs)` emits at a shading point with world
/// position `p`, normal `n` and `dpdu`, in object space `m` (`None`: no object space given, as
/// where nothing fills it), and the rendered diagnostics.
fn emitted(node: &str, inputs: &str, m: Option<DMat4>, p: DVec3, n: DVec3, dpdu: DVec3) -> ([f32; 3], String) {
    let (code, rendered) = compiled(&emitting(node, inputs));
    let code = code.unwrap_or_else(|| panic!("{rendered}"));
    let info = code.info();
    let mut values = vec![0.0f32; info.primvar_floats];
    if let Some(m) = m {
        let slots = PrimvarTable::default().slots(&info.primvars);
        fill_object_space(&ObjectSpace::new(m), &slots, &mut values);
    }
    let f = |v: DVec3| v.as_vec3().to_array();
    let g = Globals {
        p: f(p),
        n: f(n),
        ng: f(n),
        dpdu: f(dpdu),
        primvars: strata::abi::PrimvarValues::new(&values),
        ..Globals::default()
    };
    let mut out = [0.0f32; 3];
    code.emission(&g, 0, &mut out).expect("emits");
    (out, rendered)
}

fn assert_near(got: [f32; 3], want: DVec3, what: &str) {
    let want = want.as_vec3().to_array();
    assert!(got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-4), "{what}: {got:?}, expected {want:?}");
}

/// Object-space values carried to world space by the prim's transform come back as they were:
/// a point by the matrix, a normal by its inverse transpose, a tangent by its linear part. The
/// same nodes with `space = "world"` read the world values, and no space is reported.
#[test]
fn geometry_nodes_read_the_prims_own_space() {
    let m = transform();
    let (p_object, n_object, t_object) =
        (DVec3::new(0.3, -0.7, 1.1), DVec3::new(1.0, 2.0, -0.5).normalize(), DVec3::ZERO);
    // A tangent perpendicular to the normal in object space.
    let t_object = t_object + n_object.cross(DVec3::new(0.2, 1.0, 0.4)).normalize();
    let p = m.transform_point3(p_object);
    let n = m.inverse().transpose().transform_vector3(n_object).normalize();
    let dpdu = m.transform_vector3(t_object) * 3.0;
    let at = |node: &str, inputs: &str| emitted(node, inputs, Some(m), p, n, dpdu);
    let world = "        string inputs:space = \"world\"\n";
    for (node, object, in_world) in [
        ("position", p_object, p),
        ("normal", n_object, n),
        ("tangent", t_object, dpdu.normalize()),
        ("bitangent", n_object.cross(t_object), n.cross(dpdu.normalize())),
    ] {
        let (got, rendered) = at(node, "");
        assert_near(got, object, &format!("{node}, default space"));
        assert!(!rendered.contains("space"), "{node}: {rendered}");
        assert_near(at(node, "        string inputs:space = \"object\"\n").0, object, node);
        assert_near(at(node, world).0, in_world, &format!("{node}, world"));
        // Model space is read as object space, and said.
        let (got, rendered) = at(node, "        string inputs:space = \"model\"\n");
        assert_near(got, object, &format!("{node}, model"));
        assert!(rendered.contains("`space` `model` is read as object space"), "{rendered}");
    }
    // Where nothing gives the hit an object space, it is world space.
    assert_near(emitted("normal", "", None, p, n, dpdu).0, n, "no object space");
}

/// transformpoint/vector/normal between world ("" too) and object (model) space, against the
/// matrix: a point by it, a vector by its linear part, a normal by the inverse transpose
/// (normalized); within one space, the identity.
#[test]
fn space_transforms_go_by_the_prims_transform() {
    let m = transform();
    let inv = m.inverse();
    let v = DVec3::new(0.4, -1.3, 0.9);
    let spaces = |from: &str, to: &str| {
        format!(
            "        vector3f inputs:in = ({}, {}, {})\n        string inputs:fromspace = \"{from}\"\n        \
             string inputs:tospace = \"{to}\"\n",
            v.x, v.y, v.z
        )
    };
    let at =
        |node: &str, from: &str, to: &str| emitted(node, &spaces(from, to), Some(m), DVec3::ZERO, DVec3::Z, DVec3::X);
    let cases = [
        ("transformpoint", "object", "world", m.transform_point3(v)),
        ("transformpoint", "world", "object", inv.transform_point3(v)),
        ("transformpoint", "", "model", inv.transform_point3(v)),
        ("transformpoint", "object", "model", v),
        ("transformpoint", "world", "", v),
        ("transformvector", "object", "world", m.transform_vector3(v)),
        ("transformvector", "world", "object", inv.transform_vector3(v)),
        ("transformnormal", "object", "world", inv.transpose().transform_vector3(v).normalize()),
        ("transformnormal", "world", "object", m.transpose().transform_vector3(v).normalize()),
    ];
    for (node, from, to, want) in cases {
        let (got, rendered) = at(node, from, to);
        assert_near(got, want, &format!("{node} {from:?} -> {to:?}"));
        assert!(!rendered.contains("read as world"), "{rendered}");
    }
    // A space strata does not know is read as world space, and said.
    let (got, rendered) = at("transformpoint", "camera", "world");
    assert_near(got, v, "camera");
    assert!(rendered.contains("`fromspace` `camera` is read as world space"), "{rendered}");
}

/// Rendered: a transformed analytic Sphere and two point instances of another, each emitting
/// its object-space origin carried to world space (`transformpoint` from object of (0, 0, 0)):
/// the pixels inside each show the translation authored for it (the instancer's placement
/// composed with each instance's position), so the object space at a hit is the prim's own,
/// placed by its instance.
#[test]
fn a_render_reads_each_prims_and_each_instances_object_space() {
    let origin = "        vector3f inputs:in = (0, 0, 0)\n        string inputs:fromspace = \"object\"\n        \
                  string inputs:tospace = \"world\"\n";
    let text = format!(
        "#usda 1.0\n(\n    upAxis = \"Y\"\n)\n\
         def Sphere \"Ball\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {{\n    rel material:binding = </M>\n    \
         double radius = 0.5\n    double3 xformOp:translate = (0.25, 0.5, 0.75)\n    float3 xformOp:rotateXYZ = (30, 45, 10)\n    \
         float3 xformOp:scale = (1.5, 0.5, 1)\n    \
         uniform token[] xformOpOrder = [\"xformOp:translate\", \"xformOp:rotateXYZ\", \"xformOp:scale\"]\n}}\n\
         def PointInstancer \"PI\" {{\n    double3 xformOp:translate = (0.5, 0.25, 0)\n    \
         uniform token[] xformOpOrder = [\"xformOp:translate\"]\n    int[] protoIndices = [0, 0]\n    \
         point3f[] positions = [(1.25, 0, 0.25), (-0.25, 1.5, 0)]\n    rel prototypes = [</PI/Protos/S>]\n    \
         def Scope \"Protos\" {{\n        def Sphere \"S\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {{\n            \
         rel material:binding = </M>\n            double radius = 0.3\n        }}\n    }}\n}}\n{}",
        emitting("transformpoint", origin)
    );
    let dir = std::env::temp_dir().join(format!("strata-object-space-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("scene.usda");
    std::fs::write(&path, text).expect("writes");
    let (scene, materials) = common::scene_file(&path);
    let image = common::render_scene(&scene, &materials, &common::settings(48, 36, 4, 1, 2));
    let channel = |c: &str| image.f32_channel(c).expect("rgb");
    let (r, g, b) = (channel("R"), channel("G"), channel("B"));
    let count = |want: [f32; 3]| {
        (0..r.len()).filter(|&i| [r[i], g[i], b[i]].iter().zip(want).all(|(x, w)| (x - w).abs() < 1e-4)).count()
    };
    // The ball's translation; each instance's position moved by the instancer's.
    let wants = [[0.25, 0.5, 0.75], [1.75, 0.25, 0.25], [0.25, 1.75, 0.0]];
    let missing: Vec<_> = wants.iter().filter(|&&want| count(want) < 4).collect();
    assert!(missing.is_empty(), "fewer than 4 pixels show {missing:?}");
    std::fs::remove_dir_all(&dir).ok();
}

/// transformmatrix needs a matrix input, and matrices are not a strata type; heighttonormal
/// needs screen-space derivatives: each is one warning naming the node and why, and what it
/// drives keeps its default (the emission here is 0), never a panic or a made-up value.
#[test]
fn matrix_and_derivative_nodes_are_reported_as_unsupported() {
    for (id, why) in [
        ("ND_transformmatrix_vector3M3", "matrices (matrix33, matrix44) are not a strata type"),
        ("ND_transformmatrix_vector3M4", "matrices (matrix33, matrix44) are not a strata type"),
        ("ND_heighttonormal_vector3", "screen-space derivatives"),
    ] {
        let node = id.strip_prefix("ND_").and_then(|n| n.strip_suffix("_vector3M3").or(n.strip_suffix("_vector3M4")));
        let node = node.unwrap_or("heighttonormal");
        let text =
            emitting(node, "        vector3f inputs:in = (1, 2, 3)\n").replace(&format!("ND_{node}_vector3"), id);
        let (code, rendered) = compiled(&text);
        let code = code.unwrap_or_else(|| panic!("{id}: {rendered}"));
        assert!(rendered.contains(&format!("MaterialX node `{id}` is not implemented")), "{id}: {rendered}");
        assert!(rendered.contains(why), "{id}: {rendered}");
        assert_eq!(rendered.matches("warning").count(), 1, "{id}: {rendered}");
        let g = Globals { n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], ..Globals::default() };
        let mut out = [f32::NAN; 3];
        code.emission(&g, 0, &mut out).expect("emits");
        assert_eq!(out, [0.0; 3], "{id}");
    }
}
