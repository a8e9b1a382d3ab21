//! Per-layer coverage mattes of the selected prim: for each layer of its material, per pixel,
//! the share of the pixel's camera samples whose first-vertex pick (DESIGN.md rule 5) chose
//! that layer. Each sample contributes the pick's probability there — the rule-5 weights from
//! the layer masks, the quantity the integrator's pick counts estimate — so the mattes carry
//! no pick noise: inside an opaque stack they sum to the prim's coverage, a layer with mask 0
//! reads 0 and a constant mask `m` under nothing reads `m`.

use crate::abi::{Globals, MaterialCode, PrimvarValues, layering};
use crate::render::Scene;
use crate::render::geometry::accel::Hit;
use crate::render::geometry::primvars::{fill_object_space, reads_object_space};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Camera samples per pixel side: 2 × 2 stratified positions per pixel.
const SIDE: usize = 2;

/// The mattes of every layer (bottom to top) of `prim`'s material, each `width × height`
/// values in [0, 1], rows top first; `None` when no prim of the scene has that path.
pub(crate) fn mattes(
    scene: &Scene,
    materials: &[std::sync::Arc<dyn MaterialCode>],
    prim: &str,
    width: usize,
    height: usize,
) -> Option<Vec<Vec<f32>>> {
    let index = scene.prims.iter().position(|p| p.path == prim)?;
    let material = materials.get(*scene.prim_material.get(index)?)?.as_ref();
    let layers = material.info().layers.len();
    let camera = scene.camera.with_aspect(width as f32 / height as f32);
    let share = 1.0 / (SIDE * SIDE) as f32;
    // One row of every layer's matte per task: rows × layers, transposed below.
    let rows: Vec<Vec<f32>> = (0..height)
        .into_par_iter()
        .map(|y| {
            let mut row = vec![0.0f32; layers * width];
            let (mut masks, mut weights, mut primvars) = (vec![0.0; layers], vec![0.0; layers], Vec::new());
            for x in 0..width {
                for s in 0..SIDE * SIDE {
                    let offset =
                        Vec2::new(((s % SIDE) as f32 + 0.5) / SIDE as f32, ((s / SIDE) as f32 + 0.5) / SIDE as f32);
                    let film = Vec2::new((x as f32 + offset.x) / width as f32, (y as f32 + offset.y) / height as f32);
                    let ray = camera.ray(film, Vec2::splat(0.5));
                    let Some(hit) = scene.accel.intersect(ray.o, ray.d, ray.tmin, ray.tmax) else { continue };
                    if scene.accel.prim_of(&hit) as usize != index {
                        continue;
                    }
                    let globals = surface_globals(scene, material, ray.o, ray.d, &hit, &mut primvars);
                    if material.masks(&globals, &mut masks).is_err() {
                        continue;
                    }
                    layering::pick_weights(&material.info().layers, &masks, &mut weights);
                    for (layer, w) in weights.iter().enumerate() {
                        row[layer * width + x] += w * share;
                    }
                }
            }
            row
        })
        .collect();
    Some(
        (0..layers)
            .map(|layer| rows.iter().flat_map(|row| row[layer * width..(layer + 1) * width].iter().copied()).collect())
            .collect(),
    )
}

/// The shading globals of `material` where ray `o + t d` hits, as a camera ray's first
/// vertex sees them (normals facing the ray, primvars interpolated into `primvars`).
pub(crate) fn surface_globals<'a>(
    scene: &Scene,
    material: &dyn MaterialCode,
    o: Vec3,
    d: Vec3,
    hit: &Hit,
    primvars: &'a mut Vec<f32>,
) -> Globals<'a> {
    let g = scene.accel.surface(o, d, hit);
    let info = material.info();
    let slots = scene.primvars.slots(&info.primvars);
    primvars.clear();
    primvars.resize(info.primvar_floats, 0.0);
    if !slots.is_empty() {
        scene.primvars.fill(g.primvars, g.bary, &slots, primvars);
        if reads_object_space(&slots) {
            fill_object_space(&scene.object_space(hit, g.prim, 0.0), &slots, primvars);
        }
    }
    let facing = |n: Vec3| if n.dot(d) > 0.0 { -n } else { n };
    Globals {
        p: g.p.to_array(),
        n: facing(g.ns).to_array(),
        ng: facing(g.ng).to_array(),
        i: d.to_array(),
        dpdu: g.dpdu.to_array(),
        dpdv: g.dpdv.to_array(),
        u: g.uv.x,
        v: g.uv.y,
        st_footprint: [0.0; 4],
        primvars: PrimvarValues::new(primvars),
        params: PrimvarValues::default(),
    }
}
