//! UsdLux lights.
//!
//! Emission is `inputs:intensity · 2^inputs:exposure · inputs:color`, a radiance; with
//! `inputs:normalize` area lights divide it by their world-space area. DistantLight follows
//! the UsdLux light spec: unnormalised, the intensity is the radiance of the sun disk;
//! normalised, it is the irradiance on a surface facing the light (whatever the angle).
//!
//! Area lights (rect, disk, sphere) are not in the BVH: rays test them analytically
//! ([`Light::hit`]), and lights at infinity (dome, distant) are seen by escaping rays
//! ([`Light::escape`]). Every sampleable light gives the same density from
//! [`Light::sample_li`] and [`Light::pdf_li`], which multiple importance sampling needs.

pub mod emitter;
mod spherical_rect;
mod usd;

pub use usd::{MAX_COLOR_TEMPERATURE, MIN_COLOR_TEMPERATURE, blackbody_rgb, lights_from_stage};

use crate::diag::{Diagnostic, Diagnostics};
use crate::render::geometry::xform::{PrimXform, value_span};
use crate::render::sampling::{
    Distribution1D, Distribution2D, concentric_disk, cosine_hemisphere, uniform_cone, uniform_sphere,
};
use crate::scene::{Prim, Stage, Value};
use glam::{DMat3, DVec3, Mat3, Vec2, Vec3};
pub use spherical_rect::RectFrame;
use spherical_rect::SphericalRect;
use std::f32::consts::PI;
use std::sync::Arc;

/// Light prim types this renderer understands.
pub const LIGHT_TYPES: &[&str] =
    &["DomeLight", "RectLight", "SphereLight", "DiskLight", "DistantLight", "CylinderLight"];

/// A latitude-longitude environment image, importance sampled.
#[derive(Debug)]
pub struct EnvMap {
    width: usize,
    height: usize,
    texels: Vec<Vec3>,
    distribution: Distribution2D,
}

impl EnvMap {
    /// Builds from RGB texels, row 0 at the top (latitude +π/2), OpenEXR's lat-long layout.
    pub fn new(width: usize, height: usize, texels: Vec<Vec3>) -> EnvMap {
        // Weight by luminance × sin θ: the lat-long map's area distortion.
        let weights: Vec<f32> = (0..height)
            .flat_map(|y| {
                let sin_theta = (PI * (y as f32 + 0.5) / height as f32).sin();
                let texels = &texels;
                (0..width).map(move |x| luminance(texels[y * width + x]) * sin_theta)
            })
            .collect();
        let distribution = Distribution2D::new(&weights, width, height);
        EnvMap { width, height, texels, distribution }
    }

    /// Reads a lat-long image: OpenEXR or any format textures may use (a bounded read, the
    /// header checked against the texture pixel limit before decoding: see [`crate::input`]).
    /// 8-bit colour images are sRGB-decoded, as Hydra reads them; float images are linear.
    pub fn load(path: &std::path::Path) -> Result<EnvMap, String> {
        use crate::runtime::texture::{ColorSpace, decode_texture_budgeted};
        let bytes = crate::input::read_bytes(path).map_err(|e| e.to_string())?;
        // Per pixel the map also keeps an RGB texel (12 bytes), a weight (4) and the
        // distribution's tables (about 8).
        let max_pixels = crate::input::limits().max_texture_pixels;
        let image = decode_texture_budgeted(&bytes, Some(path), ColorSpace::Auto, max_pixels, 24)?;
        let texels = image
            .texels
            .into_iter()
            .map(|[r, g, b, _]| Vec3::new(r, g, b))
            .map(|t| if t.is_finite() { t.max(Vec3::ZERO) } else { Vec3::ZERO })
            .collect();
        Ok(EnvMap::new(image.width, image.height, texels))
    }

    fn uv(d: Vec3) -> Vec2 {
        let lon = d.x.atan2(d.z);
        // atan2 rather than asin: asin loses all precision near the poles.
        let lat = d.y.atan2(Vec2::new(d.x, d.z).length());
        Vec2::new(
            ((PI - lon) / (2.0 * PI)).clamp(0.0, 1.0 - f32::EPSILON),
            ((PI / 2.0 - lat) / PI).clamp(0.0, 1.0 - f32::EPSILON),
        )
    }

    fn direction(uv: Vec2) -> (Vec3, f32) {
        let lon = PI - 2.0 * PI * uv.x;
        let theta = PI * uv.y;
        let (st, ct) = theta.sin_cos();
        (Vec3::new(st * lon.sin(), ct, st * lon.cos()), st)
    }

    fn lookup(&self, d: Vec3) -> Vec3 {
        let uv = EnvMap::uv(d);
        let x = ((uv.x * self.width as f32) as usize).min(self.width - 1);
        let y = ((uv.y * self.height as f32) as usize).min(self.height - 1);
        self.texels[y * self.width + x]
    }
}

fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// The shape and emission of one light, in world space.
#[derive(Clone, Debug)]
pub enum LightKind {
    /// Environment at infinity; `to_local` maps world directions into the dome's frame.
    Dome {
        /// Constant radiance (multiplies the map).
        radiance: Vec3,
        /// Optional lat-long map.
        map: Option<Arc<EnvMap>>,
        /// World → dome frame.
        to_local: Mat3,
        /// Dome frame → world.
        to_world: Mat3,
    },
    /// A parallelogram `centre ± ex ± ey` emitting along `n`; sampled by solid angle where it
    /// is a rectangle (`spherical_rect`), by area where it is sheared or degenerate.
    Rect {
        /// Centre.
        centre: Vec3,
        /// Half-width axis.
        ex: Vec3,
        /// Half-height axis.
        ey: Vec3,
        /// Unit emission direction (local −Z).
        n: Vec3,
        /// Radiance.
        radiance: Vec3,
        /// What of the geometry does not depend on the point it is seen from, made by
        /// [`LightKind::rect`] from the fields above: a rect light is built by that function
        /// and never changed in place (a changed field would leave this frame stale).
        frame: RectFrame,
    },
    /// An ellipse `centre + a ex + b ey`, `a² + b² ≤ 1`, emitting along `n`.
    Disk {
        /// Centre.
        centre: Vec3,
        /// Radius axis 1.
        ex: Vec3,
        /// Radius axis 2.
        ey: Vec3,
        /// Unit emission direction (local −Z).
        n: Vec3,
        /// Radiance.
        radiance: Vec3,
        /// A point's coordinates along `ex`, `ey`, made by [`LightKind::disk`] from the
        /// fields above (a disk light is built by that function and never changed in place).
        plane: PlaneCoordinates,
    },
    /// A sphere emitting outwards.
    Sphere {
        /// Centre.
        centre: Vec3,
        /// Radius.
        radius: f32,
        /// Radiance.
        radiance: Vec3,
    },
    /// The side of a cylinder (UsdLux CylinderLight: no end caps) emitting outwards.
    Cylinder {
        /// Centre.
        centre: Vec3,
        /// Unit axis (the light's local X).
        axis: Vec3,
        /// Half the length along `axis`.
        half_length: f32,
        /// Radius.
        radius: f32,
        /// Radiance.
        radiance: Vec3,
    },
    /// A point (`treatAsPoint`) of radiant intensity `intensity`.
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity.
        intensity: Vec3,
    },
    /// A distant light: a cone of directions around `dir` (towards the light).
    Distant {
        /// Unit direction towards the light (its local +Z).
        dir: Vec3,
        /// Cosine of the half angle; 1 for a delta light.
        cos_max: f32,
        /// Radiance of the disk, or the irradiance of a delta light.
        radiance: Vec3,
    },
}

impl LightKind {
    /// A [`LightKind::Rect`] `centre ± ex ± ey` emitting along the unit `n`, with its
    /// point-independent geometry made once here.
    pub fn rect(centre: Vec3, ex: Vec3, ey: Vec3, n: Vec3, radiance: Vec3) -> LightKind {
        LightKind::Rect { centre, ex, ey, n, radiance, frame: RectFrame::new(centre, ex, ey, n) }
    }

    /// A [`LightKind::Disk`] `centre + a ex + b ey` (`a² + b² ≤ 1`) emitting along the unit `n`.
    pub fn disk(centre: Vec3, ex: Vec3, ey: Vec3, n: Vec3, radiance: Vec3) -> LightKind {
        let plane = PlaneCoordinates::new(ex.as_dvec3(), ey.as_dvec3(), n.as_dvec3());
        LightKind::Disk { centre, ex, ey, n, radiance, plane }
    }
}

/// The coordinates `(a, b)` of a vector `d = a ex + b ey` in a planar light's plane (normal
/// `n`), read as `(d·dual_x, d·dual_y)` with the dual vectors `(ey × n, n × ex) / ((ex × ey)·n)`
/// made once when the light is built (in f64, then rounded). Right for sheared edges too:
/// projections `d·ex / |ex|²` are right only for perpendicular ones, and a transform that
/// scales after rotating shears a light, whose corners would then read as outside.
#[derive(Clone, Copy, Debug)]
pub struct PlaneCoordinates {
    dual_x: Vec3,
    dual_y: Vec3,
}

impl PlaneCoordinates {
    /// The dual vectors of the edges `ex`, `ey` in the plane with normal `n`.
    fn new(ex: DVec3, ey: DVec3, n: DVec3) -> PlaneCoordinates {
        let signed_area = ex.cross(ey).dot(n);
        PlaneCoordinates {
            dual_x: (ey.cross(n) / signed_area).as_vec3(),
            dual_y: (n.cross(ex) / signed_area).as_vec3(),
        }
    }

    /// `(a, b)` with `d = a ex + b ey`, for `d` in the plane.
    #[inline]
    fn of(&self, d: Vec3) -> (f32, f32) {
        (d.dot(self.dual_x), d.dot(self.dual_y))
    }
}

/// A light and the prim it came from.
#[derive(Clone, Debug)]
pub struct Light {
    /// Prim path.
    pub path: String,
    /// Geometry and emission.
    pub kind: LightKind,
    /// Whether camera rays see the light itself (`bool strata:visibleToCamera`, default
    /// true). A hidden light still lights the scene and shows in reflections.
    pub visible_to_camera: bool,
}

/// The attribute that hides a light from camera rays. UsdLux has no standard one (renderers
/// use their own: Karma's `karma:light:renderlightgeo`, RenderMan's
/// `primvars:ri:attributes:visibility:camera`), so strata reads its own namespace.
pub const VISIBLE_TO_CAMERA: &str = "strata:visibleToCamera";

/// A light sample as seen from a shading point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the point towards the light.
    pub wi: Vec3,
    /// Incident radiance (for delta lights: irradiance-like value, with `pdf = 1`).
    pub li: Vec3,
    /// Solid-angle density (1 for delta lights).
    pub pdf: f32,
    /// Distance to the sampled point (`f32::INFINITY` for lights at infinity).
    pub dist: f32,
    /// A delta light (no MIS with BSDF sampling).
    pub delta: bool,
}

impl Light {
    /// Whether a ray can hit the light (rect, disk, sphere, cylinder): the kinds for which
    /// [`Light::hit`] can return a hit.
    pub fn is_hittable(&self) -> bool {
        matches!(
            self.kind,
            LightKind::Rect { .. } | LightKind::Disk { .. } | LightKind::Sphere { .. } | LightKind::Cylinder { .. }
        )
    }

    /// Whether the light is at infinity (dome, distant).
    pub fn is_infinite(&self) -> bool {
        matches!(self.kind, LightKind::Dome { .. } | LightKind::Distant { .. })
    }

    /// Samples incident light at `p` with uniform numbers `u`. `n` is the unit normal of the
    /// side of the surface at `p` that the light can reach (the side of the outgoing
    /// direction), or zero where there is none: a constant dome is then sampled
    /// cosine-weighted over that hemisphere instead of uniformly over the sphere, so no sample
    /// is spent below the surface. (Where the BSDF transmits, the integrator passes zero, so
    /// light through the surface is sampled too; see `integrator::light_side`.)
    pub fn sample_li(&self, p: Vec3, n: Vec3, u: Vec2) -> Option<LightSample> {
        let s = match &self.kind {
            LightKind::Dome { radiance, map, to_world, .. } => match map {
                None if n != Vec3::ZERO => {
                    let wi =
                        crate::render::material::bsdf::Frame::from_normal(n).to_world(cosine_hemisphere(u)).normalize();
                    let pdf = wi.dot(n).max(0.0) / PI;
                    LightSample { wi, li: *radiance, pdf, dist: f32::INFINITY, delta: false }
                }
                None => {
                    let wi = uniform_sphere(u);
                    LightSample { wi, li: *radiance, pdf: 1.0 / (4.0 * PI), dist: f32::INFINITY, delta: false }
                }
                Some(map) => {
                    let (uv, pdf_uv) = map.distribution.sample(u);
                    let (local, sin_theta) = EnvMap::direction(uv);
                    if pdf_uv <= 0.0 || sin_theta <= 0.0 {
                        return None;
                    }
                    let pdf = pdf_uv / (2.0 * PI * PI * sin_theta);
                    let wi = (*to_world * local).normalize();
                    LightSample { wi, li: *radiance * map.lookup(local), pdf, dist: f32::INFINITY, delta: false }
                }
            },
            LightKind::Rect { centre, ex, ey, n, radiance, frame } => {
                // One-sided: nothing reaches a point behind (or on) the light's plane.
                if (p - *centre).dot(*n) <= 0.0 {
                    return None;
                }
                match SphericalRect::new(p, frame) {
                    Some(rect) => {
                        let (wi, dist) = rect.sample(u);
                        let pdf = (1.0 / rect.solid_angle()) as f32;
                        LightSample { wi, li: *radiance, pdf, dist, delta: false }
                    }
                    None => {
                        let q = *centre + *ex * (2.0 * u.x - 1.0) + *ey * (2.0 * u.y - 1.0);
                        area_sample(p, q, *n, frame.area(), *radiance)?
                    }
                }
            }
            LightKind::Disk { centre, ex, ey, n, radiance, .. } => {
                let d = concentric_disk(u);
                let q = *centre + *ex * d.x + *ey * d.y;
                let area = PI * ex.cross(*ey).length();
                area_sample(p, q, *n, area, *radiance)?
            }
            LightKind::Cylinder { centre, axis, half_length, radius, radiance } => {
                let z = (2.0 * u.x - 1.0) * half_length;
                let (sin_phi, cos_phi) = (2.0 * PI * u.y).sin_cos();
                let frame = crate::render::material::bsdf::Frame::from_normal(*axis);
                let outward = frame.to_world(Vec3::new(cos_phi, sin_phi, 0.0));
                let q = *centre + *axis * z + outward * *radius;
                area_sample(p, q, outward, cylinder_area(*half_length, *radius), *radiance)?
            }
            LightKind::Sphere { centre, radius, radiance } => {
                let to = *centre - p;
                let d2 = to.length_squared();
                if d2 <= radius * radius {
                    return None;
                }
                let dist_c = d2.sqrt();
                let axis = to / dist_c;
                let (cos_max, one_minus_cos) = sphere_cone(*radius, d2);
                let local = uniform_cone(u, cos_max);
                let frame = crate::render::material::bsdf::Frame::from_normal(axis);
                let wi = frame.to_world(local).normalize();
                let dist = sphere_hit(p, wi, *centre, *radius).unwrap_or(dist_c - radius);
                LightSample { wi, li: *radiance, pdf: 1.0 / (2.0 * PI * one_minus_cos), dist, delta: false }
            }
            LightKind::Point { position, intensity } => {
                let to = *position - p;
                let d2 = to.length_squared();
                if d2 == 0.0 {
                    return None;
                }
                let dist = d2.sqrt();
                LightSample { wi: to / dist, li: *intensity / d2, pdf: 1.0, dist, delta: true }
            }
            LightKind::Distant { dir, cos_max, radiance } => {
                if *cos_max >= 1.0 {
                    LightSample { wi: *dir, li: *radiance, pdf: 1.0, dist: f32::INFINITY, delta: true }
                } else {
                    let frame = crate::render::material::bsdf::Frame::from_normal(*dir);
                    let wi = frame.to_world(uniform_cone(u, *cos_max)).normalize();
                    let pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
                    LightSample { wi, li: *radiance, pdf, dist: f32::INFINITY, delta: false }
                }
            }
        };
        (s.pdf > 0.0 && s.pdf.is_finite() && s.wi.is_finite()).then_some(s)
    }

    /// Solid-angle density with which [`Light::sample_li`] at `p` (with the same `n`) picks
    /// direction `wi` (0 for delta lights and directions that miss the light).
    pub fn pdf_li(&self, p: Vec3, n: Vec3, wi: Vec3) -> f32 {
        match &self.kind {
            LightKind::Dome { map: None, .. } if n != Vec3::ZERO => wi.dot(n).max(0.0) / PI,
            LightKind::Dome { map: None, .. } => 1.0 / (4.0 * PI),
            LightKind::Dome { map: Some(map), to_local, .. } => {
                let local = (*to_local * wi).normalize();
                let uv = EnvMap::uv(local);
                let sin_theta = Vec2::new(local.x, local.z).length();
                if sin_theta <= 0.0 { 0.0 } else { map.distribution.pdf(uv) / (2.0 * PI * PI * sin_theta) }
            }
            LightKind::Rect { centre, n, frame, .. } => match rect_hit(p, wi, *centre, *n, frame) {
                // The density sample_li used: by solid angle unless that is degenerate.
                Some(t) => match SphericalRect::new(p, frame) {
                    Some(rect) => (1.0 / rect.solid_angle()) as f32,
                    None => area_pdf(p, wi, t, *n, frame.area()),
                },
                None => 0.0,
            },
            LightKind::Disk { centre, ex, ey, n, plane, .. } => match disk_hit(p, wi, *centre, *n, plane) {
                Some(t) => area_pdf(p, wi, t, *n, PI * ex.cross(*ey).length()),
                None => 0.0,
            },
            LightKind::Sphere { centre, radius, .. } => {
                let to = *centre - p;
                let d2 = to.length_squared();
                if d2 <= radius * radius {
                    return 0.0;
                }
                let (cos_max, one_minus_cos) = sphere_cone(*radius, d2);
                if wi.dot(to) / d2.sqrt() >= cos_max { 1.0 / (2.0 * PI * one_minus_cos) } else { 0.0 }
            }
            LightKind::Cylinder { centre, axis, half_length, radius, .. } => {
                match cylinder_hit(p, wi, *centre, *axis, *half_length, *radius) {
                    Some((t, outward)) => area_pdf(p, wi, t, outward, cylinder_area(*half_length, *radius)),
                    None => 0.0,
                }
            }
            LightKind::Point { .. } => 0.0,
            LightKind::Distant { dir, cos_max, .. } => {
                if *cos_max < 1.0 && wi.dot(*dir) >= *cos_max {
                    1.0 / (2.0 * PI * (1.0 - cos_max))
                } else {
                    0.0
                }
            }
        }
    }

    /// Radiance and distance where the ray `p + t wi`, `t < tmax`, meets this area light from
    /// its emitting side.
    pub fn hit(&self, p: Vec3, wi: Vec3, tmax: f32) -> Option<(Vec3, f32)> {
        let (radiance, t) = match &self.kind {
            LightKind::Rect { centre, n, radiance, frame, .. } => (*radiance, rect_hit(p, wi, *centre, *n, frame)?),
            LightKind::Disk { centre, n, radiance, plane, .. } => (*radiance, disk_hit(p, wi, *centre, *n, plane)?),
            LightKind::Sphere { centre, radius, radiance } => (*radiance, sphere_hit(p, wi, *centre, *radius)?),
            LightKind::Cylinder { centre, axis, half_length, radius, radiance } => {
                (*radiance, cylinder_hit(p, wi, *centre, *axis, *half_length, *radius)?.0)
            }
            _ => return None,
        };
        (t < tmax).then_some((radiance, t))
    }

    /// Radiance reaching a ray that escapes to infinity in direction `wi`.
    pub fn escape(&self, wi: Vec3) -> Vec3 {
        match &self.kind {
            LightKind::Dome { radiance, map, to_local, .. } => match map {
                None => *radiance,
                Some(map) => *radiance * map.lookup((*to_local * wi).normalize()),
            },
            LightKind::Distant { dir, cos_max, radiance } if *cos_max < 1.0 && wi.dot(*dir) >= *cos_max => *radiance,
            _ => Vec3::ZERO,
        }
    }
}

impl Light {
    /// The light's emitted power as luminance (for choosing lights, so only its proportions
    /// matter). Lights at infinity deliver power over the scene's cross-section: a disk of
    /// `scene_radius` (pbrt-v4's convention).
    pub fn power(&self, scene_radius: f32) -> f32 {
        let disk = PI * scene_radius * scene_radius;
        match &self.kind {
            LightKind::Rect { radiance, frame, .. } => luminance(*radiance) * frame.area() * PI,
            LightKind::Disk { ex, ey, radiance, .. } => luminance(*radiance) * PI * ex.cross(*ey).length() * PI,
            LightKind::Sphere { radius, radiance, .. } => luminance(*radiance) * 4.0 * PI * radius * radius * PI,
            LightKind::Cylinder { half_length, radius, radiance, .. } => {
                luminance(*radiance) * cylinder_area(*half_length, *radius) * PI
            }
            LightKind::Point { intensity, .. } => luminance(*intensity) * 4.0 * PI,
            LightKind::Distant { cos_max, radiance, .. } => {
                // A delta light's `radiance` is its irradiance; a cone's irradiance is L π sin².
                let irradiance = if *cos_max >= 1.0 {
                    luminance(*radiance)
                } else {
                    luminance(*radiance) * PI * (1.0 - cos_max * cos_max)
                };
                irradiance * disk
            }
            LightKind::Dome { radiance, map, .. } => {
                let average = map.as_ref().map_or(1.0, |m| {
                    m.texels.iter().map(|t| luminance(*t)).sum::<f32>() / m.texels.len().max(1) as f32
                });
                luminance(*radiance) * average * 4.0 * PI * disk
            }
        }
    }
}

/// How next-event estimation chooses one light per shading point.
///
/// Lights at infinity each get an equal share, as do the bounded lights together (pbrt-v4's
/// BVH light sampler does the same: an infinite light's power says nothing about how much of
/// it reaches a point). Within the bounded lights the choice follows power, mixed with 10 %
/// uniform so that a dim light near the point is never starved by a bright one far away.
#[derive(Clone, Debug)]
pub struct LightSelection {
    distribution: Option<Distribution1D>,
    /// Each entry's probability ([`Distribution1D::discrete_pdf`]), made once: next-event
    /// estimation reads it at every shading point and MIS at every ray that meets a light.
    pmf: Box<[f32]>,
}

/// Share of the bounded lights' probability spread uniformly (see [`LightSelection`]).
const UNIFORM_SHARE: f32 = 0.1;

impl LightSelection {
    /// The selection for `lights` in a scene of bounding radius `scene_radius`.
    pub fn new(lights: &[Light], scene_radius: f32) -> LightSelection {
        LightSelection::with_emitters(lights, &[], scene_radius)
    }

    /// The selection for `lights` followed by emissive surfaces of power `emitters`
    /// (bounded lights: [`crate::render::light::emitter::Emitter::power`]); index `lights.len() + k` is
    /// emitter `k`.
    pub fn with_emitters(lights: &[Light], emitters: &[f32], scene_radius: f32) -> LightSelection {
        // (at infinity, power) of every entry.
        let entries: Vec<(bool, f32)> = lights
            .iter()
            .map(|l| (l.is_infinite(), if l.is_infinite() { 0.0 } else { l.power(scene_radius) }))
            .chain(emitters.iter().map(|&p| (false, p)))
            .collect();
        if entries.is_empty() {
            return LightSelection { distribution: None, pmf: Box::new([]) };
        }
        let infinite = entries.iter().filter(|(inf, _)| *inf).count();
        let bounded = entries.len() - infinite;
        let groups = infinite + usize::from(bounded > 0);
        let usable = |p: f32| p.is_finite() && p > 0.0;
        let bounded_power: f32 = entries.iter().filter(|(inf, p)| !inf && usable(*p)).map(|(_, p)| p).sum();
        let weights: Vec<f32> = entries
            .iter()
            .map(|&(inf, power)| {
                if inf {
                    return 1.0 / groups as f32;
                }
                let by_power = if bounded_power > 0.0 && usable(power) { power / bounded_power } else { 0.0 };
                let uniform = 1.0 / bounded as f32;
                let share = if bounded_power > 0.0 {
                    (1.0 - UNIFORM_SHARE) * by_power + UNIFORM_SHARE * uniform
                } else {
                    uniform
                };
                share / groups as f32
            })
            .collect();
        let distribution = Distribution1D::new(&weights);
        let pmf = (0..weights.len()).map(|i| distribution.discrete_pdf(i)).collect();
        LightSelection { distribution: Some(distribution), pmf }
    }

    /// Chooses a light with uniform `u`: its index, its probability and `u` rescaled to
    /// [0, 1) within the chosen light's share (see [`Distribution1D::sample_piece_remapped`]),
    /// for the point on the light.
    pub fn sample_remapped(&self, u: f32) -> Option<(usize, f32, f32)> {
        let (i, rest) = self.distribution.as_ref()?.sample_piece_remapped(u);
        let pmf = self.pmf(i);
        (pmf > 0.0).then_some((i, pmf, rest))
    }

    /// The probability of choosing light `i`.
    pub fn pmf(&self, i: usize) -> f32 {
        self.pmf.get(i).copied().unwrap_or(0.0)
    }
}

fn area_sample(p: Vec3, q: Vec3, n: Vec3, area: f32, radiance: Vec3) -> Option<LightSample> {
    let to = q - p;
    let d2 = to.length_squared();
    let dist = d2.sqrt();
    let wi = to / dist;
    // One-sided: the light faces the point when its emission direction points back at it.
    let cos_l = -wi.dot(n);
    if cos_l <= 0.0 || area <= 0.0 || dist == 0.0 {
        return None;
    }
    Some(LightSample { wi, li: radiance, pdf: d2 / (cos_l * area), dist, delta: false })
}

fn area_pdf(_p: Vec3, wi: Vec3, t: f32, n: Vec3, area: f32) -> f32 {
    let cos_l = -wi.dot(n);
    if cos_l <= 0.0 || area <= 0.0 { 0.0 } else { t * t / (cos_l * area) }
}

/// Ray/parallelogram distance, front (emitting) side only.
fn rect_hit(p: Vec3, wi: Vec3, c: Vec3, n: Vec3, frame: &RectFrame) -> Option<f32> {
    let (t, q) = plane_hit(p, wi, c, n)?;
    let (a, b) = frame.edge_coordinates(q - c);
    (a.abs() <= 1.0 && b.abs() <= 1.0).then_some(t)
}

/// Ray/ellipse distance, front side only.
fn disk_hit(p: Vec3, wi: Vec3, c: Vec3, n: Vec3, plane: &PlaneCoordinates) -> Option<f32> {
    let (t, q) = plane_hit(p, wi, c, n)?;
    let (a, b) = plane.of(q - c);
    (a * a + b * b <= 1.0).then_some(t)
}

fn plane_hit(p: Vec3, wi: Vec3, c: Vec3, n: Vec3) -> Option<(f32, Vec3)> {
    let denom = wi.dot(n);
    if denom >= 0.0 {
        return None;
    }
    let t = (c - p).dot(n) / denom;
    (t > 0.0 && t.is_finite()).then(|| (t, p + wi * t))
}

fn cylinder_area(half_length: f32, radius: f32) -> f32 {
    4.0 * PI * radius * half_length
}

/// The radiant intensity of a SphereLight of world `radius` treated as a point (`treatAsPoint`,
/// or a radius of 0), for `emission = intensity · 2^exposure · color`.
///
/// UsdLux has no point lights: `treatAsPoint` only says a renderer may approximate the sphere
/// by a point, so the point must emit what the sphere does. A sphere of uniform radiance `L`
/// seen from outside has the projected area `π r²` from every direction, so its radiant
/// intensity is `I = L π r²` (and its power `4π I = L · 4πr² · π`, a Lambertian emitter's).
/// UsdLux's `L` is the emission, divided by the surface area `4π r²` under `inputs:normalize`:
/// `I = emission π r²` unnormalised — 0 for a radius of 0, which has no surface to emit
/// from — and `I = emission / 4` normalised, whatever the radius (the `r → 0` limit included).
fn point_intensity(emission: Vec3, radius: f32, normalize: bool) -> Vec3 {
    if normalize { emission / 4.0 } else { emission * (PI * radius * radius) }
}

/// Ray/cylinder-side distance and outward normal where the ray meets the emitting (outer)
/// side. The side is convex, so only the entry point can face the ray's origin: from inside
/// the infinite cylinder, or through an open end, the outer side is never seen.
fn cylinder_hit(p: Vec3, wi: Vec3, c: Vec3, axis: Vec3, half_length: f32, r: f32) -> Option<(f32, Vec3)> {
    // In f64: near the silhouette the outward normal (and so the area pdf's cosine) comes from
    // a difference of nearly equal terms.
    let (axis, wi) = (axis.as_dvec3(), wi.as_dvec3());
    let o = (p - c).as_dvec3();
    let o_perp = o - axis * o.dot(axis);
    let d_perp = wi - axis * wi.dot(axis);
    let a = d_perp.length_squared();
    let b = o_perp.dot(d_perp);
    let r = r as f64;
    let cc = o_perp.length_squared() - r * r;
    if cc <= 0.0 || a <= 0.0 || b >= 0.0 {
        return None;
    }
    let disc = b * b - a * cc;
    if disc < 0.0 {
        return None;
    }
    // The nearer root, in the cancellation-free form (b < 0 here).
    let t = cc / (-b + disc.sqrt());
    let z = (o + wi * t).dot(axis);
    if !(t > 0.0 && t.is_finite() && z.abs() <= half_length as f64) {
        return None;
    }
    let outward = (o_perp + d_perp * t).normalize_or_zero().as_vec3();
    Some((t as f32, outward))
}

/// The cosine of the half angle a sphere of `radius` subtends from a point at squared
/// distance `d2` from its centre, and one minus it without cancellation (`sin² / (1 + cos)`):
/// `1 − cos` itself rounds to 0 for a sphere under about 3e-4 radians across, which would
/// make its solid angle, and so its light, vanish.
fn sphere_cone(radius: f32, d2: f32) -> (f32, f32) {
    let sin2 = (radius * radius / d2).min(1.0);
    let cos_max = (1.0 - sin2).sqrt();
    (cos_max, sin2 / (1.0 + cos_max))
}

/// Ray/sphere distance to the outside surface, from outside.
fn sphere_hit(p: Vec3, wi: Vec3, c: Vec3, r: f32) -> Option<f32> {
    let oc = p - c;
    let b = oc.dot(wi);
    let cc = oc.length_squared() - r * r;
    if cc <= 0.0 {
        return None;
    }
    // Numerically stable discriminant (Ray Tracing Gems ch. 7).
    let f = oc - b * wi;
    let disc = r * r - f.length_squared();
    if disc < 0.0 {
        return None;
    }
    let q = -b - b.signum() * disc.sqrt();
    let t0 = cc / q;
    let t1 = q;
    let t = t0.min(t1);
    (t > 0.0 && b < 0.0).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::usd::blackbody_xyz;
    use super::*;
    use crate::render::geometry::xform::{tests::stage, world_transforms};
    use crate::render::sampling::Rng;

    pub(crate) fn lights(text: &str) -> Vec<Light> {
        let (stage, mut diags) = stage(text);
        let xf = world_transforms(&stage, &mut diags);
        let l = lights_from_stage(&stage, &xf, &mut diags);
        assert!(!diags.has_errors(), "{diags:?}");
        l
    }

    #[test]
    fn sample_pdf_matches_pdf_li_and_integrates() {
        let map = EnvMap::new(8, 4, (0..32).map(|i| Vec3::splat(1.0 + (i % 5) as f32)).collect());
        let mut all = lights(
            r#"#usda 1.0
def RectLight "R" { float inputs:width = 2  float inputs:height = 0.5
    double3 xformOp:translate = (0, 3, 0)  float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"] }
def DiskLight "D" { float inputs:radius = 0.7  double3 xformOp:translate = (1, 0, 4)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def SphereLight "S" { float inputs:radius = 0.5  double3 xformOp:translate = (-2, 1, 1)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def DistantLight "Sun" { float inputs:angle = 10  float3 xformOp:rotateXYZ = (-60, 20, 0)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ"] }
def DomeLight "Dome" {}
def Xform "X" { float xformOp:rotateY = 30  uniform token[] xformOpOrder = ["xformOp:rotateY"]
    def DomeLight "Textured" {} }
def CylinderLight "C" { float inputs:length = 3  float inputs:radius = 0.4
    double3 xformOp:translate = (0.5, -1.5, 0.2)  float xformOp:rotateZ = 30
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateZ"] }"#,
        );
        if let LightKind::Dome { map: m, .. } = &mut all[5].kind {
            *m = Some(Arc::new(map));
        }
        let p = Vec3::new(0.1, 0.2, 0.3);
        for light in &all {
            let mut rng = Rng::new(7, 0, 0);
            // The cylinder's estimate has 1.2 % standard deviation at 20 000 samples (its 1/pdf
            // spans 0 at the silhouette to its peak facing p): ten times as many keep 2 % at 5σ.
            let n = if matches!(light.kind, LightKind::Cylinder { .. }) { 200_000 } else { 20_000 };
            let mut inv_pdf_sum = 0.0f64;
            let mut samples = 0;
            for _ in 0..n {
                let Some(s) = light.sample_li(p, Vec3::ZERO, rng.uniform2()) else { continue };
                samples += 1;
                inv_pdf_sum += 1.0 / s.pdf as f64;
                // A cylinder has a silhouette: there the light's cosine (in the area pdf) is
                // tiny, f32 rounding of the sampled point dominates it, and the two pdfs may
                // differ by any factor — harmlessly, as such samples carry almost no weight.
                if let LightKind::Cylinder { centre, axis, .. } = &light.kind {
                    let q = p + s.wi * s.dist - *centre;
                    let outward = (q - *axis * q.dot(*axis)).normalize();
                    if -s.wi.dot(outward) < 0.05 {
                        continue;
                    }
                }
                let pdf = light.pdf_li(p, Vec3::ZERO, s.wi);
                assert!((pdf - s.pdf).abs() <= 2e-3 * s.pdf, "{}: {pdf} vs {}", light.path, s.pdf);
                if !light.is_infinite() {
                    let (_, t) = light.hit(p, s.wi, f32::INFINITY).expect("sampled direction hits the light");
                    assert!((t - s.dist).abs() < 1e-3 * s.dist, "{}", light.path);
                }
            }
            // At least the half of the cylinder that faces p.
            assert!(samples > n * 2 / 5, "{}", light.path);
            // E[1/pdf] is the solid angle the light subtends from p.
            let solid_angle = inv_pdf_sum / n as f64;
            let expected = match &light.kind {
                LightKind::Dome { .. } => 4.0 * std::f64::consts::PI,
                LightKind::Distant { cos_max, .. } => 2.0 * std::f64::consts::PI * (1.0 - *cos_max as f64),
                LightKind::Sphere { centre, radius, .. } => {
                    let d = (*centre - p).length() as f64;
                    2.0 * std::f64::consts::PI * (1.0 - (1.0 - (*radius as f64 / d).powi(2)).sqrt())
                }
                LightKind::Rect { centre, ex, ey, n, .. } | LightKind::Disk { centre, ex, ey, n, .. } => {
                    // Reference: midpoint quadrature of ∫ cos_l / d² dA over the shape.
                    let disk = matches!(light.kind, LightKind::Disk { .. });
                    let m = 400;
                    let da = 4.0 * ex.cross(*ey).length() as f64 / (m * m) as f64;
                    let mut sum = 0.0f64;
                    for i in 0..m {
                        for j in 0..m {
                            let a = -1.0 + 2.0 * (i as f32 + 0.5) / m as f32;
                            let b = -1.0 + 2.0 * (j as f32 + 0.5) / m as f32;
                            if disk && a * a + b * b > 1.0 {
                                continue;
                            }
                            let to = (*centre + *ex * a + *ey * b - p).as_dvec3();
                            let cos_l = (-to.normalize().dot(n.as_dvec3())).max(0.0);
                            sum += cos_l / to.length_squared() * da;
                        }
                    }
                    sum
                }
                LightKind::Cylinder { centre, axis, half_length, radius, .. } => {
                    // Reference: midpoint quadrature over the side, (z, φ) in m × m cells.
                    let m = 600;
                    let frame = crate::render::material::bsdf::Frame::from_normal(*axis);
                    let (hl, r) = (*half_length as f64, *radius as f64);
                    let da = (2.0 * hl / m as f64) * (2.0 * std::f64::consts::PI * r / m as f64);
                    let mut sum = 0.0f64;
                    for i in 0..m {
                        for j in 0..m {
                            let z = -hl + 2.0 * hl * (i as f64 + 0.5) / m as f64;
                            let phi = 2.0 * std::f64::consts::PI * (j as f64 + 0.5) / m as f64;
                            let outward = frame.to_world(Vec3::new(phi.cos() as f32, phi.sin() as f32, 0.0)).as_dvec3();
                            let q = centre.as_dvec3() + axis.as_dvec3() * z + outward * r;
                            let to = q - p.as_dvec3();
                            let cos_l = (-to.normalize().dot(outward)).max(0.0);
                            sum += cos_l / to.length_squared() * da;
                        }
                    }
                    sum
                }
                LightKind::Point { .. } => unreachable!(),
            };
            assert!((solid_angle - expected).abs() < 0.02 * expected, "{}: {solid_angle} vs {expected}", light.path);
        }
    }

    /// A sphere 2e-5 radians across (a bulb seen from afar) still subtends its solid angle
    /// `π (r/d)²`: `1 − cos` of its cone must not round to 0, which would make it black.
    /// The integrator looks for crossed lights only when one `is_hittable`: a ray must be
    /// able to hit exactly those (a light with area seen from outside it covers some of the
    /// 4096 directions).
    /// A planar light is hit where a point's coordinates along its edges are inside the shape
    /// and missed just outside, sheared edges too (a transform that scales after rotating):
    /// coordinates along the edges decide, not projections onto them.
    #[test]
    fn planar_lights_are_hit_inside_their_edges_and_missed_outside() {
        let (centre, ex, ey) = (Vec3::new(0.0, 0.0, 3.0), Vec3::X, Vec3::new(0.3, 0.4, 0.0));
        let n = -ex.cross(ey).normalize();
        let p = Vec3::new(0.2, -0.1, 0.0);
        type Inside = fn(f32, f32) -> bool;
        let in_rect: Inside = |a, b| a.abs() < 1.0 && b.abs() < 1.0;
        let in_disk: Inside = |a, b| a * a + b * b < 1.0;
        let cases = [
            (LightKind::rect(centre, ex, ey, n, Vec3::ONE), in_rect),
            (LightKind::disk(centre, ex, ey, n, Vec3::ONE), in_disk),
        ];
        for (kind, inside) in cases {
            let light = Light { path: "/L".into(), kind, visible_to_camera: true };
            for (a, b) in
                [(0.97, 0.97), (-0.97, 0.5), (1.03, 0.0), (0.0, -1.03), (1.03, 1.03), (0.69, 0.69), (0.73, -0.73)]
            {
                let wi = (centre + ex * a + ey * b - p).normalize();
                let hit = light.hit(p, wi, f32::INFINITY).is_some();
                assert_eq!(hit, inside(a, b), "{:?} at ({a}, {b})", light.kind);
            }
        }
    }

    #[test]
    fn exactly_the_hittable_lights_are_hit_by_rays() {
        let all = lights(
            r#"#usda 1.0
def RectLight "R" { float inputs:width = 2  float inputs:height = 2  double3 xformOp:translate = (0, 0, 3)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def DiskLight "D" { float inputs:radius = 1  double3 xformOp:translate = (0, 0, 3)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def SphereLight "S" { float inputs:radius = 0.5  double3 xformOp:translate = (-2, 1, 1)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def SphereLight "P" { bool treatAsPoint = true  double3 xformOp:translate = (1, 1, 1)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def CylinderLight "C" { float inputs:length = 3  float inputs:radius = 0.4  double3 xformOp:translate = (0, -2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"] }
def DistantLight "Sun" { float inputs:angle = 10 }
def DomeLight "Dome" {}"#,
        );
        assert_eq!(all.len(), 7);
        let mut rng = Rng::new(3, 0, 0);
        let directions: Vec<Vec3> = (0..4096).map(|_| uniform_sphere(rng.uniform2())).collect();
        for light in &all {
            let hits = directions.iter().filter(|&&d| light.hit(Vec3::ZERO, d, f32::INFINITY).is_some()).count();
            assert_eq!(hits > 0, light.is_hittable(), "{:?}: {hits} of 4096 rays hit it", light.kind);
        }
        assert_eq!(all.iter().filter(|l| l.is_hittable()).count(), 4);
    }

    #[test]
    fn a_far_small_sphere_keeps_its_solid_angle() {
        let l = lights("#usda 1.0\ndef SphereLight \"Bulb\" { float inputs:radius = 1e-4 }\n");
        let p = Vec3::new(0.0, 10.0, 0.0);
        let s = l[0].sample_li(p, Vec3::ZERO, Vec2::new(0.3, 0.6)).expect("a sample");
        let solid_angle = PI * (1e-4f32 / 10.0).powi(2);
        assert!((1.0 / s.pdf - solid_angle).abs() < 1e-3 * solid_angle, "{} vs {solid_angle}", 1.0 / s.pdf);
        assert!((l[0].pdf_li(p, Vec3::ZERO, -Vec3::Y) - s.pdf).abs() < 1e-3 * s.pdf);
    }

    #[test]
    fn invisible_lights_are_dropped_and_camera_visibility_is_read() {
        let l = lights(
            r#"#usda 1.0
def DomeLight "Hidden" { token visibility = "invisible" }
def Xform "Off" { token visibility = "invisible"
    def SphereLight "Child" { float inputs:radius = 0.5 } }
def DomeLight "Sky" { bool strata:visibleToCamera = false }
def SphereLight "Lamp" { float inputs:radius = 0.5 }"#,
        );
        let seen: Vec<(&str, bool)> = l.iter().map(|l| (l.path.as_str(), l.visible_to_camera)).collect();
        assert_eq!(seen, [("/Sky", false), ("/Lamp", true)]);
    }

    #[test]
    fn intensity_exposure_color_and_normalize() {
        let l = lights(
            r#"#usda 1.0
def RectLight "R" { float inputs:intensity = 3  float inputs:exposure = 2  color3f inputs:color = (1, 0.5, 0)
    float inputs:width = 2  float inputs:height = 4  bool inputs:normalize = 1 }
def DistantLight "Sun" { float inputs:intensity = 2  float inputs:angle = 0 }"#,
        );
        let LightKind::Rect { radiance, n, .. } = &l[0].kind else { panic!() };
        assert!((*radiance - Vec3::new(12.0, 6.0, 0.0) / 8.0).length() < 1e-5);
        assert!((*n - -Vec3::Z).length() < 1e-6, "rect lights emit along -Z");
        let LightKind::Distant { dir, cos_max, radiance } = &l[1].kind else { panic!() };
        assert_eq!((*dir, *cos_max, *radiance), (Vec3::Z, 1.0, Vec3::splat(2.0)));
    }

    #[test]
    fn cylinder_light_emits_from_its_side_along_local_x_only() {
        let l = lights(
            r#"#usda 1.0
def CylinderLight "C" { float inputs:length = 4  float inputs:radius = 0.5  bool inputs:normalize = 1
    float inputs:intensity = 2 }"#,
        );
        let LightKind::Cylinder { axis, half_length, radius, radiance, .. } = &l[0].kind else { panic!() };
        assert_eq!((*axis, *half_length, *radius), (Vec3::X, 2.0, 0.5));
        // Normalised: the radiance is the intensity over the side's area 2πrL.
        assert!((radiance.x - 2.0 / (2.0 * PI * 0.5 * 4.0)).abs() < 1e-6);
        let light = &l[0];
        // Seen from the side it is hit at distance 3 - r; along its axis, through an open end,
        // nothing emits towards the viewer.
        let (_, t) = light.hit(Vec3::new(0.0, 3.0, 0.0), -Vec3::Y, f32::INFINITY).expect("side is hit");
        assert!((t - 2.5).abs() < 1e-5);
        assert!(light.hit(Vec3::new(10.0, 0.0, 0.0), -Vec3::X, f32::INFINITY).is_none());
        assert!(light.hit(Vec3::new(0.0, 0.2, 0.0), Vec3::Y, f32::INFINITY).is_none(), "inside sees no emission");
        assert!(light.hit(Vec3::new(3.0, 3.0, 0.0), -Vec3::Y, f32::INFINITY).is_none(), "beyond its length");
    }

    /// The chromaticity of a blackbody is known independently of this code: CIE standard
    /// illuminant A *is* a Planckian radiator at 2856 K, x = 0.44757, y = 0.40745; D65 is
    /// close to (not on) the Planckian locus at 6504 K, x = 0.3127, y = 0.3290.
    #[test]
    fn blackbody_matches_illuminant_a_and_has_unit_luminance() {
        let chromaticity = |k: f64| {
            let xyz = blackbody_xyz(k);
            let sum = xyz.x + xyz.y + xyz.z;
            (xyz.x / sum, xyz.y / sum)
        };
        let (x, y) = chromaticity(2856.0);
        assert!((x - 0.44757).abs() < 2e-3 && (y - 0.40745).abs() < 2e-3, "({x}, {y})");
        let (x, y) = chromaticity(6504.0);
        assert!((x - 0.3127).abs() < 3e-3 && (y - 0.3290).abs() < 8e-3, "({x}, {y})");
        for k in [1000.0, 1900.0, 2856.0, 4000.0, 6500.0, 10000.0, 40000.0] {
            let rgb = blackbody_rgb(k);
            let y = DVec3::new(0.2126, 0.7152, 0.0722).dot(rgb);
            assert!(rgb.is_finite() && rgb.min_element() >= 0.0 && (y - 1.0).abs() < 1e-9, "{k}: {rgb}");
        }
        // Warmer is redder: red over blue falls as the temperature rises.
        let ratio = |k: f64| blackbody_rgb(k).x / blackbody_rgb(k).z.max(1e-12);
        assert!(ratio(2000.0) > ratio(3000.0) && ratio(3000.0) > ratio(6500.0) && ratio(6500.0) > ratio(10000.0));
        // 6500 K is near white: no channel is more than 15 % from the others' mean.
        let w = blackbody_rgb(6500.0);
        assert!((w - DVec3::ONE).abs().max_element() < 0.15, "{w}");
    }

    #[test]
    fn color_temperature_multiplies_color_only_when_enabled() {
        let l = lights(
            r#"#usda 1.0
def SphereLight "Warm" { float inputs:radius = 0.5  bool inputs:enableColorTemperature = 1
    float inputs:colorTemperature = 2856  color3f inputs:color = (1, 1, 0.5) }
def SphereLight "Off" { float inputs:radius = 0.5  float inputs:colorTemperature = 2856 }"#,
        );
        let LightKind::Sphere { radiance, .. } = &l[0].kind else { panic!() };
        let expected = (blackbody_rgb(2856.0) * DVec3::new(1.0, 1.0, 0.5)).as_vec3();
        assert!((*radiance - expected).length() < 1e-5, "{radiance} vs {expected}");
        let LightKind::Sphere { radiance, .. } = &l[1].kind else { panic!() };
        assert_eq!(*radiance, Vec3::ONE);
    }

    /// With a surface normal the constant dome is sampled cosine-weighted over that
    /// hemisphere: the pdf matches, nothing is sampled below, and E[1/pdf] is the
    /// hemisphere's solid angle 2π.
    #[test]
    fn constant_dome_is_sampled_over_the_hemisphere_of_the_normal() {
        let l = lights("#usda 1.0\ndef DomeLight \"D\" {}\n");
        let n = Vec3::new(0.3, 0.8, -0.2).normalize();
        let p = Vec3::ZERO;
        let mut rng = Rng::new(3, 0, 0);
        let count = 100_000;
        let mut inv_pdf = 0.0f64;
        for _ in 0..count {
            let s = l[0].sample_li(p, n, rng.uniform2()).expect("a sample");
            assert!(s.wi.dot(n) >= 0.0);
            assert!((l[0].pdf_li(p, n, s.wi) - s.pdf).abs() <= 1e-4 * s.pdf.max(1.0));
            inv_pdf += 1.0 / s.pdf as f64;
        }
        let solid_angle = inv_pdf / count as f64;
        // 1/pdf = π/cosθ has infinite variance at the horizon; the mean still converges.
        assert!((solid_angle - 2.0 * std::f64::consts::PI).abs() < 0.05 * 2.0 * std::f64::consts::PI, "{solid_angle}");
        assert_eq!(l[0].pdf_li(p, n, -n), 0.0);
    }

    /// Bounded lights are chosen by power (with a 10 % uniform floor); each light at infinity
    /// gets the same share as all bounded lights together; the probabilities sum to one.
    #[test]
    fn lights_are_selected_by_power_and_infinite_lights_by_share() {
        let l = lights(
            r#"#usda 1.0
def SphereLight "Bright" { float inputs:radius = 1  float inputs:intensity = 90 }
def SphereLight "Dim" { float inputs:radius = 1  float inputs:intensity = 10 }
def DomeLight "Sky" { float inputs:intensity = 1000 }"#,
        );
        let sel = LightSelection::new(&l, 10.0);
        let p: Vec<f32> = (0..3).map(|i| sel.pmf(i)).collect();
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-6, "{p:?}");
        assert!((p[2] - 0.5).abs() < 1e-6, "the dome: one of two groups ({p:?})");
        let bright = 0.5 * (0.9 * 0.9 + 0.1 * 0.5);
        let dim = 0.5 * (0.9 * 0.1 + 0.1 * 0.5);
        assert!((p[0] - bright).abs() < 1e-5 && (p[1] - dim).abs() < 1e-5, "{p:?}");
        let mut counts = [0usize; 3];
        for i in 0..10_000 {
            let (k, pmf, _) = sel.sample_remapped((i as f32 + 0.5) / 10_000.0).unwrap();
            assert_eq!(pmf, p[k]);
            counts[k] += 1;
        }
        for k in 0..3 {
            assert!((counts[k] as f32 / 10_000.0 - p[k]).abs() < 1e-3, "{counts:?} vs {p:?}");
        }
        assert!(LightSelection::new(&[], 1.0).sample_remapped(0.5).is_none());
    }
}
