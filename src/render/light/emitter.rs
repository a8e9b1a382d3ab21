//! Emissive geometry sampled as lights.
//!
//! A surface whose picked layer has an `emission` product adds its radiance where a path hits
//! it (one-sided: from the front, the side its winding — `orientation` included — says is
//! outward). Where such a surface carries power, next-event estimation also samples it as a
//! light, so a small bright emitter does not have to be found by BSDF sampling alone.
//!
//! Each prim of the world (not instanced) geometry whose material can emit becomes one
//! [`Emitter`]: its triangles, chosen by estimated power (emitted radiance × area, the
//! material's expected emission — rule-5 weights × each layer's emission — averaged over four
//! points of the triangle at build time), and a uniform point on the chosen triangle. The
//! estimate only steers sampling: the radiance of a sample is the material's, evaluated at the
//! sampled point, and multiple importance sampling uses the true density, so a triangle the
//! estimate misses is still found (unbiased) by BSDF sampling. Emissive quadrics and instanced
//! emitters are found by BSDF sampling only (their MIS weight is then 1).
//!
//! A material with no emitting layer costs nothing here: no triangle is visited for it.

use crate::abi::layering;
use crate::abi::{Globals, MaterialCode};
use crate::render::geometry::accel::{Accel, Hit, WORLD};
use crate::render::sampling::Distribution1D;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Emitters whose power is below this fraction of all bounded lights' and emitters' power
/// are not sampled as lights (BSDF sampling still finds them): under [`crate::render::light::
/// LightSelection`]'s uniform share, thousands of faint emitters would otherwise take light
/// samples from the lights that matter.
pub const MIN_POWER_SHARE: f32 = 1e-4;

/// Barycentric points `(b1, b2)` where a triangle's emission is estimated: the centroid and
/// one point towards each vertex.
const ESTIMATE_POINTS: [(f32, f32); 4] =
    [(1.0 / 3.0, 1.0 / 3.0), (1.0 / 6.0, 1.0 / 6.0), (2.0 / 3.0, 1.0 / 6.0), (1.0 / 6.0, 2.0 / 3.0)];

/// The emissive triangles of one prim, sampled as one light.
#[derive(Clone, Debug)]
pub struct Emitter {
    /// The renderable prim (index into `Scene::prims`).
    pub prim: u32,
    /// Its triangles in the world BLAS (as [`Hit::index`]), ascending.
    triangles: Vec<u32>,
    /// Their areas.
    areas: Vec<f32>,
    /// Triangle choice by estimated power.
    choice: Distribution1D,
    /// Estimated emitted power (luminance × area × π), for choosing among lights.
    pub power: f32,
}

/// A point chosen on an emitter.
#[derive(Clone, Copy, Debug)]
pub struct EmitterSample {
    /// The world triangle (as [`Hit::index`]).
    pub triangle: u32,
    /// Barycentric weight of vertex 1.
    pub b1: f32,
    /// Barycentric weight of vertex 2.
    pub b2: f32,
    /// Density per unit area of the point within the emitter.
    pub pdf_area: f32,
}

impl Emitter {
    /// Chooses a triangle with `u_triangle` and a uniform point on it with `u`.
    pub fn sample(&self, u_triangle: f32, u: Vec2) -> Option<EmitterSample> {
        let (k, pmf) = self.choice.sample_discrete(u_triangle);
        let area = *self.areas.get(k)?;
        if pmf <= 0.0 || area <= 0.0 {
            return None;
        }
        // Uniform on the triangle (pbrt's square-root mapping).
        let s = u.x.sqrt();
        let (b1, b2) = (s * (1.0 - u.y), s * u.y);
        Some(EmitterSample { triangle: self.triangles[k], b1, b2, pdf_area: pmf / area })
    }

    /// The density per unit area with which [`Emitter::sample`] reaches a point of world
    /// triangle `triangle` (0 for a triangle that is not this emitter's).
    pub fn pdf_area(&self, triangle: u32) -> f32 {
        match self.triangles.binary_search(&triangle) {
            Ok(k) if self.areas[k] > 0.0 => self.choice.discrete_pdf(k) / self.areas[k],
            _ => 0.0,
        }
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }
}

/// The scene's emitters and which prim each belongs to.
#[derive(Clone, Debug, Default)]
pub struct Emitters {
    /// Emitters sampled as lights.
    pub list: Vec<Emitter>,
    /// Per renderable prim: its emitter's index in `list`, or `u32::MAX`.
    of_prim: Vec<u32>,
}

impl Emitters {
    /// The emitter of renderable prim `prim`, with its index.
    #[inline]
    pub fn of_prim(&self, prim: u32) -> Option<(usize, &Emitter)> {
        let i = *self.of_prim.get(prim as usize)?;
        self.list.get(i as usize).map(|e| (i as usize, e))
    }

    /// Whether no emitter is sampled as a light.
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// Removes every emitter: emissive surfaces are then found by BSDF sampling only (for
    /// tests and measurements of what light sampling gains).
    pub fn clear(&mut self) {
        self.list.clear();
        self.of_prim.clear();
    }

    /// Finds the emissive world triangles of `accel` and estimates their power through the
    /// `materials` (indexed by `prim_material`). `light_power` is the power of the scene's
    /// bounded lights ([`crate::render::light::Light::power`]), against which faint emitters are
    /// dropped (see [`MIN_POWER_SHARE`]). Materials that cannot emit cost one check each.
    pub fn build(
        accel: &Accel,
        prim_count: usize,
        prim_material: &[usize],
        materials: &[&dyn MaterialCode],
        light_power: f32,
    ) -> Emitters {
        let can_emit = |prim: usize| {
            prim_material
                .get(prim)
                .and_then(|&m| materials.get(m))
                .is_some_and(|m| m.info().layers.iter().any(|l| l.has_emission && l.picks()))
        };
        let emissive: Vec<bool> = (0..prim_count).map(can_emit).collect();
        if !emissive.contains(&true) {
            return Emitters::default();
        }
        let mut found: Vec<Option<Found>> = vec![None; prim_count];
        let layers = materials.iter().map(|m| m.info().layers.len()).max().unwrap_or(0);
        let (mut masks, mut weights) = (vec![0.0f32; layers], vec![0.0f32; layers]);
        for (index, tri) in (0..).map_while(|i| accel.world_triangle(i)).enumerate() {
            let centroid = Hit { t: 1.0, index: index as u32, instance: WORLD, b1: 1.0 / 3.0, b2: 1.0 / 3.0 };
            let prim = accel.prim_of(&centroid) as usize;
            if !emissive.get(prim).copied().unwrap_or(false) {
                continue;
            }
            let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length();
            if !(area > 0.0 && area.is_finite()) {
                continue;
            }
            let material = materials[prim_material[prim]];
            let mut sum = Vec3::ZERO;
            for (b1, b2) in ESTIMATE_POINTS {
                let hit = Hit { b1, b2, ..centroid };
                let geom = accel.surface(Vec3::ZERO, Vec3::Z, &hit);
                let g = Globals {
                    p: geom.p.to_array(),
                    n: geom.ns.to_array(),
                    ng: geom.ng.to_array(),
                    i: (-geom.ng).to_array(),
                    dpdu: geom.dpdu.to_array(),
                    dpdv: geom.dpdv.to_array(),
                    st_footprint: [0.0; 4],
                    u: geom.uv.x,
                    v: geom.uv.y,
                    // The power estimate reads primvars at their fallbacks.
                    primvars: crate::abi::PrimvarValues::new(&[]),
                    params: Default::default(),
                };
                sum += expected_emission(material, &g, &mut masks, &mut weights);
            }
            let radiance = luminance(sum / ESTIMATE_POINTS.len() as f32);
            let entry = found[prim].get_or_insert_with(Found::default);
            entry.triangles.push(index as u32);
            entry.areas.push(area);
            entry.power.push(radiance * area);
        }
        let mut list = Vec::new();
        for (prim, entry) in found.into_iter().enumerate() {
            let Some(Found { triangles, areas, power }) = entry else { continue };
            let total: f32 = power.iter().sum::<f32>() * PI;
            if total > 0.0 && total.is_finite() {
                let choice = Distribution1D::new(&power);
                list.push(Emitter { prim: prim as u32, triangles, areas, choice, power: total });
            }
        }
        let bounded: f32 = light_power + list.iter().map(|e| e.power).sum::<f32>();
        list.retain(|e| e.power >= MIN_POWER_SHARE * bounded);
        let mut of_prim = vec![u32::MAX; prim_count];
        for (i, e) in list.iter().enumerate() {
            of_prim[e.prim as usize] = i as u32;
        }
        Emitters { list, of_prim }
    }
}

/// One emissive prim's triangles while they are collected.
#[derive(Clone, Default)]
struct Found {
    triangles: Vec<u32>,
    areas: Vec<f32>,
    /// Estimated luminance × area per triangle.
    power: Vec<f32>,
}

/// The expected emitted radiance of `material` at `g` over the rule-5 pick: `Σ w_i L_i` over
/// the layers that emit, each clamped at 0. A shader fault counts as no emission.
fn expected_emission(material: &dyn MaterialCode, g: &Globals, masks: &mut [f32], weights: &mut [f32]) -> Vec3 {
    let layers = &material.info().layers;
    let n = layers.len();
    if material.masks(g, &mut masks[..n]).is_err() {
        return Vec3::ZERO;
    }
    layering::pick_weights(layers, &masks[..n], &mut weights[..n]);
    let mut sum = Vec3::ZERO;
    for (i, layer) in layers.iter().enumerate() {
        if layer.has_emission && weights[i] > 0.0 {
            let mut out = [0.0; 3];
            if material.emission(g, i, &mut out).is_ok() {
                let e = Vec3::from_array(out);
                if e.is_finite() {
                    sum += weights[i] * e.max(Vec3::ZERO);
                }
            }
        }
    }
    sum
}

/// Rec. 709 luminance (as [`crate::render::light`] chooses lights by).
fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}
