//! World-space geometry from a composed stage.
//!
//! Meshes are fan-triangulated into world-space triangles; Cube and Plane are triangles too
//! (they are flat, so exactly). The curved implicit prims (Sphere, Cylinder, Cone, Capsule)
//! become analytic [`Shape`]s, intersected exactly in object space: nothing is tessellated.
//! Malformed meshes are diagnosed (never a panic); zero-area triangles are skipped and counted.

pub mod accel;
mod builder;
pub mod displace;
mod emit;
pub mod motion;
pub mod primvars;
pub mod shapes;
pub mod skel;
pub mod subdiv;
pub mod triangles;
pub mod xform;

pub use triangles::Triangles;

pub use builder::{
    POINT_MOTION_ATTRIBUTES, PointExtrapolation, build, build_for_render, build_with, build_with_options,
    build_with_primvars, deforming_prototype, deforms, point_extrapolation, point_instance_transforms,
    point_instance_transforms_at, prototype_key,
};

use crate::compose::binding::{is_bound_subset, is_renderable};
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::render::geometry::primvars::{
    MAX_COMPONENTS, OBJECT_POSITION, ObjectSpace, Primvar, PrimvarLayout, PrimvarRef, PrimvarTable,
};
use crate::render::geometry::shapes::{Part, Shape};
use crate::render::geometry::subdiv::{PolyMesh, catmull_clark, read_tags, refined_faces};
use crate::render::geometry::xform::{
    PrimXform, local_transform, transform_sample_times, value_span, world_transforms,
};
use crate::scene::{Prim, PrimId, Stage, Value};
use glam::{DMat3, DMat4, DQuat, DVec3, Vec2, Vec3};
use std::collections::{HashMap, HashSet};

/// The largest world-space coordinate (absolute value, scene units, after every transform)
/// geometry may have: 1e7. The renderer works in f32, whose spacing at 1e7 is already one
/// unit, so detail and ray offsets break down beyond it; and far-apart geometry (1e13) made
/// the BVH builder crawl while 1e38 crashed it. A prim that reaches past it is an error.
pub const MAX_EXTENT: f64 = 1e7;

/// The shortest longest-edge a triangle may have: 1e-11 scene units (in the space its BVH
/// tests it in: the world, or an instancing prototype's own). The f32 watertight test
/// multiplies three coordinates (relative to the ray origin) and bounds their rounding with a
/// further factor of 1e-7 (`accel::RayPre::intersect`); below about 1e-11 those products
/// leave f32's normal range (1e-38), the error bounds lose their precision and then the hit
/// itself underflows. Measured (tests/scene_scale.rs): a scene scaled by 1e-12 (floor edges
/// 4e-11) renders exactly as at scale 1, by 1e-14 it is already biased, by 1e-16 the floor
/// vanishes. A prim with a smaller triangle is an error, never a silently wrong image.
pub const MIN_TRIANGLE_EDGE: f64 = 1e-11;

/// The most triangles a scene may have: 2^25 (33.5 million, about 3.5 GB of triangles plus
/// their BVH). Implicit surfaces are tessellated into 16 384 triangles each, so a 50 MB
/// scene of 137 000 spheres asked for 2.2 billion triangles and was killed by the kernel; past
/// this budget the scene is an error naming the first prim that did not fit.
pub const MAX_TRIANGLES: usize = 1 << 25;

/// The most faces subdivision may make of one mesh: 2^18 (262 144 quads, half a million
/// triangles). A mesh is refined to `--subdiv-level` levels, or fewer when that would pass
/// this, so a dense cage is not multiplied into millions of triangles it does not need; a cage
/// that passes it at one level is rendered as it is.
pub const SUBDIV_FACE_BUDGET: u64 = 1 << 18;

/// The default `--subdiv-level`: two levels put a coarse cage's limit surface within a few
/// tenths of a percent of its size (every vertex is on the limit surface; only the flat
/// facets between them deviate), and a cube becomes 96 quads.
pub const DEFAULT_SUBDIV_LEVEL: u32 = 2;

/// How geometry is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GeometryOptions {
    /// Subdivision levels for `catmullClark` (and `loop`) meshes; 0 renders every cage.
    pub subdiv_level: u32,
}

impl Default for GeometryOptions {
    fn default() -> GeometryOptions {
        GeometryOptions { subdiv_level: DEFAULT_SUBDIV_LEVEL }
    }
}

/// The most instances a scene may have: 2^22 (4.2 million, about 1.5 GB of instance table
/// and top-level BVH). A 256 MiB point-instancer file can list 25 million points; past this
/// budget the instancer is an error.
pub const MAX_INSTANCES: usize = 1 << 22;

/// What one instance costs the renderer at its peak, for the memory budget
/// ([`crate::input::check_memory`]): its placement (`InstanceDesc`, 136 bytes), the
/// traversal's copy with both transforms (208), its box (32) and obvhs' build of the
/// top-level BVH over it (Morton codes, node arrays, indices; about 250). Measured: 4 million
/// point instances peaked at 2.5 GB, their text parsed included.
pub const INSTANCE_BYTES: u64 = 640;

/// A prototype placed in the world.
#[derive(Clone, Copy, Debug)]
pub struct InstanceDesc {
    /// Object (prototype) space to world.
    pub to_world: DMat4,
    /// Index of the prototype's BLAS.
    pub prototype: u32,
    /// Where the instance's prim table starts in the instance prim table: prototype-local
    /// prim `j` of this instance is the renderable prim `instance_prims[prims + j]`.
    pub prims: u32,
}

/// One world-space triangle.
#[derive(Clone, Copy, Debug)]
pub struct Triangle {
    /// Vertex positions.
    pub p: [Vec3; 3],
    /// Vertex shading normals (unit); the geometric normal when the prim has none.
    pub n: [Vec3; 3],
    /// Vertex texture coordinates (`st`, or parametric `(0,0), (1,0), (0,1)` when absent).
    pub uv: [Vec2; 3],
    /// Index of the renderable prim in [`Geometry::prims`].
    pub prim: u32,
    /// Whether `uv` came from the prim (`primvars:st` or an implicit surface's parameterisation).
    pub has_uv: bool,
    /// Its primvar values (the three corners') in [`Geometry::primvars`].
    pub primvars: PrimvarRef,
}

impl Triangle {
    /// The unnormalised geometric normal (right-handed winding).
    pub fn cross(&self) -> Vec3 {
        (self.p[1] - self.p[0]).cross(self.p[2] - self.p[0])
    }
}

/// The unit normal of the triangle `p` by its winding, computed in f64 (differences and
/// products of f32 values are exact there; an f32 cross product underflows for edges below
/// ~1e-10 units): a triangle without shading normals has it at every corner. Not finite when
/// `p` is degenerate.
#[inline]
pub fn flat_normal(p: [Vec3; 3]) -> Vec3 {
    let [a, b, c] = p.map(|p| p.as_dvec3());
    let cross = (b - a).cross(c - a);
    (cross / cross.length_squared().sqrt()).as_vec3()
}

/// A renderable prim that produced triangles.
#[derive(Clone, Debug)]
pub struct GeomPrim {
    /// Its path.
    pub path: String,
    /// Where it is defined (for diagnostics about it).
    pub span: Span,
    /// For the faces of a GeomSubset with its own material binding: the mesh they belong to
    /// (displacement welds a mesh's faces across subsets only where they share a material).
    pub subset_of: Option<u32>,
    /// Its object space relative to the space its geometry is built in: the world for a prim
    /// built there, its prototype's for an instanced prim (each instance then places it).
    pub object: ObjectSpace,
}

/// Geometry that instances share: built once, in the space of its root prim.
#[derive(Clone, Debug, Default)]
pub struct Prototype {
    /// Triangles in prototype space; `prim` is prototype-local.
    pub triangles: Triangles,
    /// Analytic surfaces in prototype space; `prim` is prototype-local.
    pub shapes: Vec<Shape>,
    /// Number of prototype-local prims.
    pub prims: u32,
    /// Prototype-space bounds `(min, max)`; `None` when empty.
    pub bounds: Option<(DVec3, DVec3)>,
    /// For a mesh that deforms while the shutter is open: its triangles' positions keyed
    /// over the shutter (`triangles` holds them at the frame).
    pub deformation: Option<motion::Deformation>,
    /// Per prototype-local prim, its object space relative to the prototype's.
    pub prim_spaces: Vec<ObjectSpace>,
}

/// The triangles of a whole stage.
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    /// World-space triangles (of prims that are not instanced).
    pub triangles: Triangles,
    /// Analytic surfaces.
    pub shapes: Vec<Shape>,
    /// Renderable, visible prims, indexed by [`Triangle::prim`] and the instance prim table.
    pub prims: Vec<GeomPrim>,
    /// Zero-area or non-finite triangles that were skipped.
    pub degenerate: usize,
    /// Geometry shared by instances: of `instanceable` prims with the same source, and the
    /// prototypes of point instancers.
    pub prototypes: Vec<Prototype>,
    /// Placed prototypes.
    pub instances: Vec<InstanceDesc>,
    /// Per-instance prim tables: prototype-local prim `j` of an instance is the renderable
    /// prim `instance_prims[instance.prims + j]`.
    pub instance_prims: Vec<u32>,
    /// Per instance, the prim that places it (the instanceable root, the point instancer):
    /// the instance moves as that prim does ([`motion::apply`]).
    pub instance_placers: Vec<PrimId>,
    /// The primvars materials read, for every triangle and shape that has them (world and
    /// prototypes alike).
    pub primvars: PrimvarTable,
    /// Per prim of the stage (by id): whether its transform is baked into triangles — a
    /// world-space prim's and its ancestors', a prototype's inner prims' relative to its
    /// root. Any other transform places instances only, so it can change without building a
    /// BLAS again (`render::Scene::move_to`).
    pub baked: Vec<bool>,
    /// Instances left out for a singular transform (a zero scale).
    pub singular_instances: usize,
    /// World prims whose shape changes with time, each built as a prototype of its own
    /// (by index in `prototypes`), so that another time code builds that BLAS again and
    /// keeps the others ([`deforming_prototype`], `render::Scene::move_to`).
    pub deforming: Vec<Deforming>,
    /// A world-space prim deforms (its material displaces or emits):
    /// another time code must build the world's BLAS again.
    pub deforming_in_world: bool,
}

/// A world prim built as a prototype of its own because its shape changes with time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deforming {
    /// The prim.
    pub id: PrimId,
    /// Its prototype.
    pub prototype: u32,
    /// Posed by a skeleton: its shape follows its skeleton, its animation and its own placement.
    pub skinned: bool,
}

impl Geometry {
    /// World-space bounds `(min, max)` of every triangle, shape and instance; `None` when empty.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let prototypes: Vec<_> = self.prototypes.iter().map(|p| p.bounds).collect();
        placed_bounds(self.world_bounds(), &prototypes, &self.instances)
    }

    /// Bounds `(min, max)` of the world triangles and shapes; `None` when there are none.
    pub fn world_bounds(&self) -> Option<(DVec3, DVec3)> {
        bounds_of(&self.triangles, &self.shapes)
    }
}

/// World-space bounds of `world` (the world's own geometry) and of `instances` of prototypes
/// bounded by `prototypes`; `None` when all are empty.
pub fn placed_bounds(
    world: Option<(DVec3, DVec3)>,
    prototypes: &[Option<(DVec3, DVec3)>],
    instances: &[InstanceDesc],
) -> Option<(Vec3, Vec3)> {
    let instances = instances.iter().filter_map(|i| {
        let (lo, hi) = prototypes[i.prototype as usize]?;
        Some(crate::render::geometry::shapes::transformed_box(&i.to_world, lo, hi))
    });
    let (lo, hi) = world.into_iter().chain(instances).reduce(|(a, b), (c, d)| (a.min(c), b.max(d)))?;
    Some((lo.as_vec3(), hi.as_vec3()))
}

/// World-space bounds `(min, max)` of triangles and shapes; `None` when there are none.
fn bounds_of(triangles: &Triangles, shapes: &[Shape]) -> Option<(DVec3, DVec3)> {
    let shape_corners = shapes.iter().flat_map(|s| {
        let (lo, hi) = s.world_bounds();
        [lo, hi]
    });
    let mut it = triangles.positions().iter().flatten().copied().chain(shape_corners);
    let first = it.next()?;
    let (lo, hi) = it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p)));
    Some((lo.as_dvec3(), hi.as_dvec3()))
}

#[cfg(test)]
mod tests {
    use super::builder::build_within;
    use super::*;
    use crate::render::geometry::xform::tests::stage;

    /// Two cylinders, the second moved by `xform_ops` (USD text) through its parent.
    fn far_apart(ops: &str) -> (Geometry, Vec<String>) {
        let text = format!(
            r#"#usda 1.0
def Cylinder "Near" {{}}
def Xform "Far" {{
    {ops}
    def Cylinder "C" {{}}
}}"#
        );
        let (stage, mut diags) = stage(&text);
        let g = build(&stage, &mut diags);
        let messages = diags
            .items()
            .iter()
            .filter(|d| d.severity == crate::diag::Severity::Error)
            .map(|d| d.message.clone())
            .collect();
        (g, messages)
    }

    #[test]
    fn geometry_beyond_the_extent_is_an_error_before_any_bvh() {
        // 1e38 crashed the BVH builder; 1e13 took it 8 s; 1e300 was silently dropped as
        // "degenerate" (infinite in f32).
        for ops in [
            "double3 xformOp:translate = (1e38, 0, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
            "double3 xformOp:translate = (0, -1e13, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
            // Finite in f64, infinite as the renderer's f32.
            "double3 xformOp:scale = (1e300, 1e300, 1e300)\n    uniform token[] xformOpOrder = [\"xformOp:scale\"]",
        ] {
            let (g, errors) = far_apart(ops);
            assert_eq!(errors.len(), 1, "{ops}: {errors:?}");
            assert!(
                errors[0].starts_with("`/Far/C` reaches (") && errors[0].contains("beyond the scene extent"),
                "{errors:?}"
            );
            assert!(g.triangles.iter().all(|t| t.p.iter().all(|p| p.abs().max_element() <= MAX_EXTENT as f32)));
        }
        let (_, errors) = far_apart(
            "double3 xformOp:translate = (0, 9e6, 0)\n    uniform token[] xformOpOrder = [\"xformOp:translate\"]",
        );
        assert!(errors.is_empty(), "within the extent: {errors:?}");
        // A huge implicit surface without any transform.
        let (stage, mut diags) = stage("#usda 1.0\ndef Sphere \"S\" { double radius = 1e30 }");
        build(&stage, &mut diags);
        assert!(
            diags
                .items()
                .iter()
                .any(|d| d.severity == crate::diag::Severity::Error && d.message.contains("beyond the scene extent"))
        );
    }

    #[test]
    fn triangles_past_the_budget_are_an_error_not_an_allocation() {
        // 137 000 implicit spheres (16 384 triangles each, before spheres were analytic) were
        // killed by the kernel at 24 GB. Cubes stand in for any triangle-making prim.
        let mut text = String::from("#usda 1.0\n");
        for i in 0..5 {
            text += &format!("def Cube \"S{i}\" {{}}\n");
        }
        let (stage, mut diags) = stage(&text);
        let xforms = world_transforms(&stage, &mut diags);
        let per_sphere =
            build_within(&stage, &xforms, GeometryOptions::default(), usize::MAX, &[], &mut diags).triangles.len() / 5;
        let g = build_within(&stage, &xforms, GeometryOptions::default(), 2 * per_sphere + 10, &[], &mut diags);
        assert_eq!(g.triangles.len(), 2 * per_sphere + 10, "bounded by the budget");
        let errors: Vec<&Diagnostic> =
            diags.items().iter().filter(|d| d.severity == crate::diag::Severity::Error).collect();
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(errors[0].message.contains("`/S2` and the prims after it do not fit"), "{}", errors[0].message);
    }

    #[test]
    fn quad_is_two_triangles_with_normals_and_st() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Mesh "M" { uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]
    normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (interpolation = "vertex")
    texCoord2f[] primvars:st = [(0, 0), (0, 1), (1, 1), (1, 0)] (interpolation = "faceVarying")
    double3 xformOp:translate = (0, 2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(diags.items().is_empty(), "{diags:?}");
        assert_eq!(g.triangles.len(), 2);
        for t in &g.triangles {
            assert!(t.has_uv);
            assert!(t.p.iter().all(|p| p.y == 2.0));
            // Winding (-1,0,-1), (-1,0,1), (1,0,1) is right-handed about +Y.
            assert!(t.cross().normalize().dot(Vec3::Y) > 0.99);
            assert_eq!(t.n[0], Vec3::Y);
        }
        assert_eq!(g.triangles.get(0).uv[1], Vec2::new(0.0, 1.0));
    }

    #[test]
    fn bad_index_is_an_error_not_a_panic() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Mesh "M" {
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 7]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(diags.has_errors());
        assert!(diags.items()[0].message.contains("out of range"), "{:?}", diags.items());
        assert!(g.triangles.is_empty());
    }

    #[test]
    fn counts_not_summing_and_nan_points_are_errors() {
        for body in [
            "int[] faceVertexCounts = [3, 3]\n int[] faceVertexIndices = [0, 1, 2]\n point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]",
            "int[] faceVertexCounts = [3]\n int[] faceVertexIndices = [0, 1, 2]\n point3f[] points = [(0,0,0), (nan,0,0), (0,1,0)]",
        ] {
            let (stage, mut diags) = stage(&format!("#usda 1.0\ndef Mesh \"M\" {{\n{body}\n}}"));
            let g = build(&stage, &mut diags);
            assert!(diags.has_errors(), "{body}");
            assert!(g.triangles.is_empty());
        }
    }

    #[test]
    fn degenerate_triangles_are_skipped_and_counted() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Mesh "M" { uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [3, 3]
    int[] faceVertexIndices = [0, 1, 2, 0, 1, 3]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (2, 0, 0)]
}"#,
        );
        let g = build(&stage, &mut diags);
        assert_eq!(g.triangles.len(), 1);
        assert_eq!(g.degenerate, 1);
        assert!(!diags.has_errors());
        assert_eq!(diags.items().len(), 1);
    }

    #[test]
    fn implicit_prims_invisible_and_guides() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Sphere "S" { double radius = 2 }
def Cube "C" { double size = 1 }
def Cylinder "Y" { token axis = "Y" }
def Sphere "Hidden" { token visibility = "invisible" }
def Xform "G" {
    uniform token purpose = "guide"
    def Sphere "Child" {}
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(!diags.has_errors());
        let paths: Vec<_> = g.prims.iter().map(|p| p.path.as_str()).collect();
        assert_eq!(paths, ["/S", "/C", "/Y"]);
        // The sphere and the cylinder are analytic: no triangles; the cylinder has its side
        // and two caps, turned to y.
        assert!(g.triangles.iter().all(|t| t.prim == 1));
        assert_eq!(g.shapes.iter().filter(|s| s.prim == 0).count(), 1);
        assert_eq!(g.shapes.iter().filter(|s| s.prim == 2).count(), 3);
        let (lo, hi) = g.bounds().unwrap();
        assert!(
            (lo - Vec3::splat(-2.0)).abs().max_element() < 1e-4 && (hi - Vec3::splat(2.0)).abs().max_element() < 1e-4
        );
        let top = g.shapes.iter().filter(|s| s.prim == 2).map(|s| s.world_bounds().1.y).fold(f32::MIN, f32::max);
        assert!((top - 1.0).abs() < 1e-5);
        // A ray down the y axis meets the top cap.
        let down = |s: &&Shape| s.intersect(Vec3::new(0.0, 5.0, 0.2), -Vec3::Y, 0.0, f32::INFINITY).is_some();
        assert!(g.shapes.iter().filter(|s| s.prim == 2).any(|s| down(&s)));
        let cube = g.triangles.iter().filter(|t| t.prim == 1).count();
        assert_eq!(cube, 12);
    }

    /// A point instancer of a unit cube with the given attribute lines.
    fn instancer(attrs: &str) -> (Geometry, Diagnostics, crate::diag::SourceMap) {
        let text = format!(
            "#usda 1.0\ndef PointInstancer \"P\" {{\n    rel prototypes = [</P/Protos/C>]\n{attrs}\n    def Scope \"Protos\" {{\n        def Cube \"C\" {{ double size = 1 }}\n    }}\n}}\n"
        );
        let mut sources = crate::diag::SourceMap::new();
        let mut diags = Diagnostics::new();
        let stage = Stage::from_text("pi.usda", &text, std::path::Path::new("."), &mut sources, &mut diags).unwrap();
        let g = build(&stage, &mut diags);
        (g, diags, sources)
    }

    #[test]
    fn point_instancer_places_points_and_hides_its_prototypes() {
        let (g, diags, _) = instancer(
            "    int[] protoIndices = [0, 0, 0]\n    point3f[] positions = [(0, 0, 0), (5, 0, 0), (0, 5, 0)]\n    quath[] orientations = [(1, 0, 0, 0), (0.70710677, 0, 0, 0.70710677), (1, 0, 0, 0)]\n    float3[] scales = [(1, 1, 1), (2, 1, 1), (1, 1, 1)]\n    int64[] invisibleIds = [2]",
        );
        assert!(!diags.has_errors(), "{diags:?}");
        assert!(g.triangles.is_empty(), "the prototype is drawn only through the instancer");
        assert_eq!(g.prototypes.len(), 1);
        assert_eq!(g.instances.len(), 2, "id 2 (no ids: the index) is invisible");
        // (real, i, j, k) = (cos 45°, 0, 0, sin 45°): 90° about z, applied after the scale:
        // x scaled by 2, then turned onto y.
        let m = g.instances[1].to_world;
        let x = m.transform_vector3(DVec3::X);
        assert!((x - DVec3::new(0.0, 2.0, 0.0)).length() < 1e-6, "{x}");
        assert!((m.transform_point3(DVec3::ZERO) - DVec3::new(5.0, 0.0, 0.0)).length() < 1e-12);
        assert_eq!(g.prims.len(), 1);
        assert_eq!(g.prims[0].path, "/P/Protos/C");
    }

    #[test]
    fn point_instancer_mismatches_are_errors_at_the_attribute() {
        for (attrs, want, line) in [
            (
                "    int[] protoIndices = [0, 0]\n    point3f[] positions = [(0, 0, 0)]",
                "`positions` has 1 entries but `protoIndices` has 2",
                5,
            ),
            (
                "    int[] protoIndices = [0, 3]\n    point3f[] positions = [(0, 0, 0), (1, 1, 1)]",
                "`protoIndices`[1] = 3 is out of range (1 prototypes)",
                4,
            ),
            (
                "    int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n    quath[] orientations = [(0, 0, 0, 0)]",
                "`orientations`[0] is a zero quaternion",
                6,
            ),
            (
                "    int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n    float3[] scales = [(1, 1, 1), (2, 2, 2)]",
                "`scales` has 2 entries",
                6,
            ),
            (
                "    int[] protoIndices = [0]\n    point3f[] positions = [(0, nan, 0)]",
                "`positions`[0] is not finite",
                5,
            ),
            ("    int[] protoIndices = [0]", "1 instances but no `positions`", 4),
            ("    int[] protoIndices = [0]\n    point3f[] positions = [(2e7, 0, 0)]", "beyond the scene extent", 2),
        ] {
            let (g, diags, sources) = instancer(attrs);
            assert!(g.instances.is_empty(), "{attrs}");
            let errors: Vec<_> = diags.items().iter().filter(|d| d.severity == crate::diag::Severity::Error).collect();
            assert_eq!(errors.len(), 1, "{attrs}: {errors:?}");
            assert!(errors[0].message.contains(want), "{}", errors[0].message);
            let rendered = diags.render(&sources);
            assert!(rendered.contains(&format!("pi.usda:{line}:")), "{rendered}");
        }
        // A target that does not exist.
        let (stage, mut diags) = stage(
            "#usda 1.0\ndef PointInstancer \"P\" {\n    rel prototypes = [</Nowhere>]\n    int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n}",
        );
        let g = build(&stage, &mut diags);
        assert!(g.instances.is_empty() && diags.items()[0].message.contains("`/Nowhere` does not exist"));
    }

    #[test]
    fn instanceable_references_share_a_prototype_unless_edited() {
        // Three instances of /Proto, one of them with a local opinion inside it: two share.
        let (stage, mut diags) = stage(
            r#"#usda 1.0
class Xform "Proto" {
    def Mesh "M" { uniform token subdivisionScheme = "none"
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
}
def Xform "A" (instanceable = true references = </Proto>) { double3 xformOp:translate = (5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def Xform "B" (instanceable = true references = </Proto>) { }
def Xform "C" (instanceable = true references = </Proto>) {
    over "M" { point3f[] points = [(0, 0, 0), (2, 0, 0), (0, 2, 0)] }
}"#,
        );
        let g = build(&stage, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        assert_eq!(g.prototypes.len(), 1, "A and B share; C is flattened (its prototype occurs once)");
        assert_eq!(g.instances.len(), 2);
        assert_eq!(g.triangles.len(), 1, "C's own triangle");
        let paths: Vec<_> = g.prims.iter().map(|p| p.path.as_str()).collect();
        assert_eq!(paths, ["/A/M", "/B/M", "/C/M"]);
        assert_eq!(g.instance_prims, [0, 1], "each instance's own prim");
        assert_eq!(g.instances[0].to_world.transform_point3(DVec3::ZERO), DVec3::new(5.0, 0.0, 0.0));
    }

    const CUBE_MESH: &str = r#"
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5]
    point3f[] points = [(-1, -1, -1), (1, -1, -1), (-1, 1, -1), (1, 1, -1),
                        (-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1)]"#;

    /// UsdGeom's default scheme is catmullClark: a cube mesh without `subdivisionScheme` is a
    /// rounded surface inside its cage, with outward normals; `none` and level 0 keep the
    /// cage; holes are skipped; a left-handed mesh's normals face the other way.
    #[test]
    fn meshes_subdivide_by_default_and_the_cage_on_request() {
        let build = |extra: &str, level: u32| {
            let text = format!("#usda 1.0\ndef Mesh \"M\" {{ {extra} {CUBE_MESH} }}\n");
            let (stage, mut diags) = stage(&text);
            let xforms = world_transforms(&stage, &mut diags);
            let g = build_with_options(&stage, &xforms, GeometryOptions { subdiv_level: level }, &mut diags);
            assert!(!diags.has_errors(), "{diags:?}");
            g
        };
        let smooth = build("", 2);
        assert_eq!(smooth.triangles.len(), 6 * 16 * 2);
        for t in &smooth.triangles {
            let centre = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
            assert!(t.p.iter().all(|p| p.abs().max_element() <= 1.0 + 1e-6), "inside the cage");
            assert!(t.cross().dot(centre) > 0.0 && t.n.iter().all(|n| n.dot(centre) > 0.0), "faces outwards");
        }
        let nearest = smooth.triangles.iter().flat_map(|t| t.p).map(|p| p.length()).fold(f32::MAX, f32::min);
        assert!(nearest < 0.9, "rounded: the face centres move in ({nearest})");
        assert_eq!(build(r#"uniform token subdivisionScheme = "none""#, 2).triangles.len(), 12);
        assert_eq!(build("", 0).triangles.len(), 12);
        assert_eq!(build("int[] holeIndices = [0]", 2).triangles.len(), 5 * 16 * 2);
        assert_eq!(build("int[] holeIndices = [0]", 0).triangles.len(), 10);
        let left = build(r#"uniform token orientation = "leftHanded""#, 1);
        for t in &left.triangles {
            let centre = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
            assert!(t.n.iter().all(|n| n.dot(centre) < 0.0), "left-handed winding faces inwards");
        }
    }

    /// Points are spheres of diameter `widths`: a ray down the z axis meets the first at
    /// z = r, exactly; a widths array of the wrong length is an error.
    #[test]
    fn points_render_as_spheres_of_their_widths() {
        let (good, mut diags) = stage(
            "#usda 1.0\ndef Points \"P\" { point3f[] points = [(0, 0, 0), (3, 0, 0)]  float[] widths = [0.5, 1] }\n",
        );
        let xforms = world_transforms(&good, &mut diags);
        let g = build_with(&good, &xforms, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        assert_eq!(g.shapes.len(), 2);
        let accel = crate::render::geometry::accel::Accel::new(g.triangles, g.shapes);
        let hit = accel.intersect(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z, 0.0, f32::INFINITY).expect("hit");
        assert!((hit.t - 4.75).abs() < 1e-5, "{}", hit.t);
        let hit = accel.intersect(Vec3::new(3.0, 0.0, 5.0), -Vec3::Z, 0.0, f32::INFINITY).expect("hit");
        assert!((hit.t - 4.5).abs() < 1e-5, "{}", hit.t);
        let (bad, mut diags) = stage(
            "#usda 1.0\ndef Points \"P\" { point3f[] points = [(0, 0, 0), (3, 0, 0)]  float[] widths = [1, 2, 3] }\n",
        );
        let xforms = world_transforms(&bad, &mut diags);
        build_with(&bad, &xforms, &mut diags);
        assert!(diags.has_errors());
    }

    /// A micro-triangle below f32's resolution inside an ordinary mesh is skipped with a
    /// warning; a prim made only of them is an error (it would vanish).
    #[test]
    fn micro_triangles_are_skipped_unless_they_are_the_whole_prim() {
        let mesh = |points: &str| {
            format!(
                "#usda 1.0\ndef Mesh \"M\" {{ uniform token subdivisionScheme = \"none\"\n    int[] faceVertexCounts = [3, 3]\n    \
                 int[] faceVertexIndices = [0, 1, 2, 3, 4, 5]\n    point3f[] points = [{points}] }}\n"
            )
        };
        let (mixed, mut diags) =
            stage(&mesh("(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1e-3), (1e-12, 0, 1e-3), (0, 1e-12, 1e-3)"));
        let xforms = world_transforms(&mixed, &mut diags);
        let g = build_with(&mixed, &xforms, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        assert_eq!(g.triangles.len(), 1);
        assert!(diags.items().iter().any(|d| d.message.contains("they are skipped, 1 others render")), "{diags:?}");
        let (tiny, mut diags) =
            stage(&mesh("(0, 0, 0), (1e-12, 0, 0), (0, 1e-12, 0), (0, 0, 0), (0, 1e-12, 0), (0, 0, 1e-12)"));
        let xforms = world_transforms(&tiny, &mut diags);
        build_with(&tiny, &xforms, &mut diags);
        assert!(diags.has_errors());
    }
}
