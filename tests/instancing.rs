//! Instancing against references USD itself wrote: `instanceable` references render as their
//! flattened copies do, a PointInstancer as the same instances written as separate prims
//! under the matrices `UsdGeom.PointInstancer.ComputeInstanceTransformsAtTime` computed
//! (fixtures from `tools/make_instancing_fixtures.py`), and shared geometry is stored once.

mod common;

use std::path::Path;
use strata::abi::MaterialCode;
use strata::render::{Image, Scene};

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/instancing");

fn scene(name: &str) -> (Scene, Vec<std::sync::Arc<dyn MaterialCode>>) {
    common::scene_file(&Path::new(DIR).join(name))
}

fn image(name: &str) -> Image {
    let (scene, materials) = scene(name);
    common::render_scene(&scene, &materials, &common::settings(96, 72, 4, 3, 3))
}

/// Asserts two renders of the same scene agree: every pixel's albedo (the first hit's
/// material, deterministic per camera ray) except on a few silhouette pixels, and radiance
/// to within the noise that rounding-level differences can cause.
///
/// Not bit for bit: the instanced geometry is stored in object space and the ray is moved
/// there, so hit points differ from the flattened copy's by f32 rounding (~1e-7 relative);
/// a path that grazes an edge may then take another branch. Any real error — a wrong
/// transform, winding or material — changes whole objects, hundreds of pixels.
fn assert_same_render(a: &Image, b: &Image) {
    let n = a.width * a.height;
    let mut albedo_differs = 0;
    for c in ["albedo.R", "albedo.G", "albedo.B"] {
        let (x, y) = (a.f32_channel(c).unwrap(), b.f32_channel(c).unwrap());
        albedo_differs += x.iter().zip(y).filter(|(p, q)| (*p - *q).abs() > 1e-4).count();
    }
    assert!(albedo_differs <= n / 200, "{albedo_differs} albedo values differ of {n} pixels");
    let (mut diff, mut sum, mut far) = (0.0f64, 0.0f64, 0);
    for c in ["R", "G", "B"] {
        let (x, y) = (a.f32_channel(c).unwrap(), b.f32_channel(c).unwrap());
        for (p, q) in x.iter().zip(y) {
            diff += (p - q).abs() as f64;
            sum += p.abs() as f64;
            far += usize::from((p - q).abs() > 1e-3 * (1.0 + p.abs()));
        }
    }
    assert!(diff / sum < 2e-3, "mean relative difference {}", diff / sum);
    assert!(far <= n / 100, "{far} radiance values differ of {n} pixels");
}

#[test]
fn instanceable_references_render_as_their_flattened_copies() {
    assert_same_render(&image("instanced.usda"), &image("flattened.usda"));
}

#[test]
fn point_instancer_renders_as_usds_own_instance_transforms() {
    assert_same_render(&image("pointinstancer.usda"), &image("pointinstancer_flat.usda"));
}

#[test]
fn instances_share_one_copy_of_their_geometry() {
    let (flat, _) = scene("flattened.usda");
    let (inst, _) = scene("instanced.usda");
    // Floor (2 triangles) plus four copies of the box mesh and the cube (12 + 12 each);
    // the beads are analytic spheres.
    assert_eq!(flat.accel.triangle_count(), 2 + 4 * 24);
    assert_eq!(flat.accel.instance_count(), 0);
    assert_eq!(flat.accel.blas_count(), 1);
    assert_eq!(inst.accel.triangle_count(), 2 + 24, "the asset is stored once");
    assert_eq!(inst.accel.instance_count(), 4);
    assert_eq!(inst.accel.blas_count(), 2, "the world's and the asset's");
    // Every instance keeps its own prims (and so its own materials).
    let mut paths: Vec<&str> = inst.prims.iter().map(|p| p.path.as_str()).collect();
    let mut flat_paths: Vec<&str> = flat.prims.iter().map(|p| p.path.as_str()).collect();
    paths.sort_unstable();
    flat_paths.sort_unstable();
    assert_eq!(paths, flat_paths);
    // A point instancer: two prototypes, ten visible points (two ids are invisible), and the
    // prototypes are not drawn where they are defined.
    let (pi, _) = scene("pointinstancer.usda");
    assert_eq!(pi.accel.instance_count(), 10);
    assert_eq!(pi.accel.blas_count(), 3);
    assert_eq!(pi.accel.triangle_count(), 2 + 12);
}
