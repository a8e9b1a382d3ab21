//! Analytic surfaces of the UsdGeom implicit prims (Sphere, Cylinder, Cone, Capsule), each
//! made of parts — sphere caps, open cylinders and cones, disks — intersected exactly in the
//! prim's object space (in f64), so silhouettes and normals are exact at any size and under
//! any affine transform, including non-uniform scale, and memory does not grow with
//! tessellation. A sphere's hit surface is computed in f32 where its error bound shows f32
//! suffices (a sphere seen from within about a thousand radii), in f64 elsewhere.
//!
//! Every part is built around the z axis; a prim's `axis` is a permutation folded into its
//! transform. `(u, v)` follow the tessellation strata used before: `u = φ / 2π` around the
//! axis, `v` along it (sphere: `1 − θ/π` from the +z pole; disks: `½ + ½ (x, y)/r`).

use glam::{DMat3, DMat4, DVec3, Mat3, Mat4, Vec2, Vec3};
use std::f64::consts::{PI, TAU};

/// One analytic surface part in object space (the prim's local space, axis permuted to z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Part {
    /// A sphere of radius `r` centred at `(0, 0, cz)`, kept where `zmin ≤ z ≤ zmax`.
    Sphere {
        /// Radius.
        r: f64,
        /// Centre on the z axis.
        cz: f64,
        /// Lowest z kept.
        zmin: f64,
        /// Highest z kept.
        zmax: f64,
    },
    /// An open cylinder of radius `r` from `z0` to `z1`.
    Cylinder {
        /// Radius.
        r: f64,
        /// Bottom.
        z0: f64,
        /// Top.
        z1: f64,
    },
    /// An open cone of base radius `r` at `z0`, apex at `z1`.
    Cone {
        /// Base radius.
        r: f64,
        /// Base height.
        z0: f64,
        /// Apex height.
        z1: f64,
    },
    /// A disk of radius `r` in the plane `z`, facing +z (or −z when `down`).
    Disk {
        /// Radius.
        r: f64,
        /// Height.
        z: f64,
        /// Whether its outward normal is −z.
        down: bool,
    },
}

/// Where a ray meets a part, in world space.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    /// The point on the surface.
    pub p: Vec3,
    /// A conservative bound on the absolute error of each component of `p`.
    pub p_error: Vec3,
    /// Outward unit normal.
    pub n: Vec3,
    /// Texture coordinates.
    pub uv: Vec2,
    /// ∂P/∂u.
    pub dpdu: Vec3,
    /// ∂P/∂v.
    pub dpdv: Vec3,
}

/// One part of a prim, with the prim's transforms.
#[derive(Clone, Debug)]
pub struct Shape {
    /// The surface in object space.
    pub part: Part,
    /// Object to world.
    pub to_world: DMat4,
    /// World to object.
    pub to_object: DMat4,
    /// Normals object → world (inverse transpose of the linear part).
    pub normal_to_world: DMat3,
    /// Index of the renderable prim.
    pub prim: u32,
    /// Its primvar values (one set for the whole part).
    pub primvars: crate::render::geometry::primvars::PrimvarRef,
    /// The f32 test that turns away rays that clearly miss before the exact f64 one.
    cull: Cull,
    /// The transforms in f32 for a sphere part's single-precision hit surface; `None` for
    /// other parts and where a transform does not fit f32.
    single: Option<SingleSphere>,
}

/// A sphere part and its transforms rounded to f32, for [`Shape::surface`] in single
/// precision where its error bound allows (see [`SingleSphere::surface`]).
#[derive(Clone, Copy, Debug)]
struct SingleSphere {
    /// World to object.
    to_object: Mat4,
    /// Object to world, and the absolute values of its linear part and translation (for
    /// the bound on the transform's rounding).
    to_world: Mat4,
    abs_linear: Mat3,
    abs_translation: Vec3,
    /// `|to_object|`'s linear part and translation (for the bound on the object-space ray).
    abs_object_linear: Mat3,
    abs_object_translation: Vec3,
    /// Normals object → world.
    normal_to_world: Mat3,
    /// Radius and centre height, rounded to f32.
    r: f32,
    cz: f32,
}

/// The largest error bound on the object-space hit point, relative to the radius, at which
/// the f32 surface is used: its normal then turns by at most about this many radians from
/// the f64 one (2.4e-4; the bound is a worst case, typical errors are ten times smaller),
/// far below what shading resolves; beyond it (a sphere seen from more than about a
/// thousand radii) the f64 surface is computed.
const SINGLE_SURFACE_TOLERANCE: f32 = 1.0 / 4096.0;

/// Object-space radii (2⁻⁴⁰ … 2⁴⁰) whose squares stay normal f32 numbers far from overflow,
/// so [`SingleSphere::surface`]'s `|q|` is as exact as its bound assumes.
const SINGLE_RADIUS_RANGE: (f32, f32) = (1.0 / (1u64 << 40) as f32, (1u64 << 40) as f32);

impl SingleSphere {
    /// The f32 copy of a sphere part under `to_world` (inverse `to_object`); `None` for other
    /// parts or anything not finite in f32.
    fn new(part: &Part, to_world: &DMat4, to_object: &DMat4, normal_to_world: &DMat3) -> Option<SingleSphere> {
        let Part::Sphere { r, cz, .. } = *part else { return None };
        let abs3 =
            |m: &Mat4| Mat3::from_cols(m.x_axis.truncate().abs(), m.y_axis.truncate().abs(), m.z_axis.truncate().abs());
        let (w, o) = (to_world.as_mat4(), to_object.as_mat4());
        let single = SingleSphere {
            to_object: o,
            to_world: w,
            abs_linear: abs3(&w),
            abs_translation: w.w_axis.truncate().abs(),
            abs_object_linear: abs3(&o),
            abs_object_translation: o.w_axis.truncate().abs(),
            normal_to_world: normal_to_world.as_mat3(),
            r: r as f32,
            cz: cz as f32,
        };
        let finite = w.is_finite() && o.is_finite() && single.normal_to_world.is_finite();
        // |q|² in `surface` overflows f32 for radii near 1e19 and loses bits in subnormals
        // near 1e-19, past what the bound accounts for: such spheres keep the f64 surface.
        let in_range = (SINGLE_RADIUS_RANGE.0..=SINGLE_RADIUS_RANGE.1).contains(&single.r);
        (finite && in_range && single.cz.is_finite()).then_some(single)
    }

    /// The hit surface of the world ray `o + t d` in f32, or `None` where the error bound on
    /// the object-space hit point exceeds [`SINGLE_SURFACE_TOLERANCE`] of the radius.
    ///
    /// The object-space point `o' + t d'` errs by the f32 transform's rounding, at most
    /// γ(4) (|M⁻¹| |o| + |t'|) + |t| γ(4) |M⁻¹| |d| per component (γ(3) for the three
    /// products and sums, γ(1) for M⁻¹ rounded to f32), plus γ(2) |p| for `o' + t d'`; that
    /// error moves the point along the surface (reprojection removes the rest), so it bounds
    /// how far the normal turns. The reprojected point `q r / |q|` (q from the centre) lies
    /// within γ(5) |q| of the sphere (pbrt-v4), γ(1) r more for the radius rounded to f32 and
    /// γ(1) |c| for the centre, γ(1) |p| for adding it back. To world: γ(4) (|M| |p| + |t|)
    /// for the transform (γ(1) of it for M rounded to f32) plus (1 + γ(4)) |M| e for the
    /// object-space error `e` carried through (pbrt-v4's transform of a point with error).
    #[inline]
    fn surface(&self, o: Vec3, d: Vec3, t: f32) -> Option<SurfaceHit> {
        let oo = self.to_object.transform_point3(o);
        let od = self.to_object.transform_vector3(d);
        let p = oo + od * t;
        let drift = (self.abs_object_linear * (o.abs() + d.abs() * t.abs()) + self.abs_object_translation) * gamma(4)
            + p.abs() * gamma(2);
        if drift.element_sum() > SINGLE_SURFACE_TOLERANCE * self.r || !p.is_finite() {
            return None;
        }
        let c = Vec3::new(0.0, 0.0, self.cz);
        let q = p - c;
        let len = q.length();
        if len <= 0.0 {
            return None;
        }
        let q = q * (self.r / len);
        let p = q + c;
        let object_error =
            q.abs() * gamma(5) + Vec3::splat(self.r * gamma(1)) + c.abs() * gamma(1) + p.abs() * gamma(1);
        let world = self.to_world.transform_point3(p);
        let p_error = (self.abs_linear * p.abs() + self.abs_translation) * gamma(4)
            + self.abs_linear * object_error * (1.0 + gamma(4));
        // φ's cosine and sine from q itself, not from φ: no trigonometry but the angles for
        // (u, v). At the poles (ρ = 0) φ is 0 as atan2(0, 0) says.
        let rho = (q.x * q.x + q.y * q.y).sqrt();
        let (cos_phi, sin_phi) = if rho > 0.0 { (q.x / rho, q.y / rho) } else { (1.0, 0.0) };
        let phi = q.y.atan2(q.x);
        let phi = if phi < 0.0 { phi + std::f32::consts::TAU } else { phi };
        let theta = (q.z / self.r).clamp(-1.0, 1.0).acos();
        let tau = std::f32::consts::TAU;
        let dpdu = Vec3::new(-tau * q.y, tau * q.x, 0.0);
        let sin_theta = (rho / self.r).min(1.0);
        let dpdv = Vec3::new(q.z * cos_phi, q.z * sin_phi, -self.r * sin_theta) * -std::f32::consts::PI;
        let n = (self.normal_to_world * (q / self.r)).normalize_or_zero();
        Some(SurfaceHit {
            p: world,
            p_error,
            n,
            uv: Vec2::new(phi / tau, 1.0 - theta / std::f32::consts::PI),
            dpdu: self.to_world.transform_vector3(dpdu),
            dpdv: self.to_world.transform_vector3(dpdv),
        })
    }
}

/// A conservative single-precision miss test (after pbrt-v4's f32 tests with error bounds),
/// in world space so that it costs no transform: the ray's line against a sphere around the
/// part's world image, with margins of ten times or more every rounding of the f32
/// arithmetic, so it says "miss" only where the exact f64 test ([`Part::intersect`]) finds
/// no hit either. Rays it cannot decide (near the part, or any non-finite value) go to the
/// f64 test, whose answer is then the same as without it: images are bit-identical.
#[derive(Clone, Copy, Debug)]
struct Cull {
    /// The sphere in world space: its centre rounded to f32, its radius rounded up.
    centre: Vec3,
    radius: f32,
    /// The centre's largest coordinate magnitude (its rounding is part of the margin).
    centre_size: f32,
}

/// The cull's margin on distances and squared distances, relative to the sizes they round
/// with: the f32 differences and dot products err by a few ε (6e-8) of them, 1e-6 all told.
const CULL_MARGIN: f32 = 1e-5;

/// The margin on the squared distance for the rounding of `o − centre` (at most
/// 6 ε |o − centre| (|o| + |centre|) in the largest coordinates): about ten times that.
const CULL_ORIGIN_MARGIN: f32 = 4e-6;

impl Cull {
    /// The test for `part` under `to_world`; one that never culls when anything is not
    /// finite in f32.
    fn new(part: &Part, to_world: &DMat4) -> Cull {
        let (centre, radius) = part.bounding_sphere();
        // The linear part stretches a length by at most its spectral norm, which is at most
        // the square root of the largest absolute row sum of LᵀL (exact for a rotation
        // times a uniform scale).
        let linear = DMat3::from_mat4(*to_world);
        let g = linear.transpose() * linear;
        let stretch = (0..3).map(|i| g.row(i).abs().element_sum()).fold(0.0f64, f64::max).sqrt();
        let centre = to_world.transform_point3(centre);
        let cull = Cull {
            centre: centre.as_vec3(),
            radius: (radius * stretch) as f32 * (1.0 + 1e-6),
            centre_size: centre.abs().max_element() as f32,
        };
        if cull.centre.is_finite() && cull.radius.is_finite() && cull.centre_size.is_finite() {
            cull
        } else {
            // An infinite radius never culls (the comparisons below are then false).
            Cull { radius: f32::INFINITY, ..cull }
        }
    }

    /// Whether the world ray `o + t d`, `t` > `tmin`, certainly misses the sphere (and so
    /// the part): its line passes wide of it, or it starts outside the sphere and moves
    /// away from its centre (when `tmin` ≥ 0).
    #[inline]
    fn misses(&self, o: Vec3, d: Vec3, tmin: f32) -> bool {
        let oc = o - self.centre;
        let (a, b, c2) = (d.length_squared(), oc.dot(d), oc.length_squared());
        let (o_size, oc_size) = (o.abs().max_element(), oc.abs().max_element());
        let reach = self.radius + CULL_MARGIN * (self.radius + self.centre_size + o_size);
        // |oc|² − (oc·d)²/|d|²: the squared distance of the line from the centre, which
        // rounds by about 1e-6 of |oc|², and by the rounding of oc itself.
        let slack = CULL_MARGIN * c2 + CULL_ORIGIN_MARGIN * oc_size * (o_size + self.centre_size);
        let outside = c2 > reach * reach + slack;
        // Every comparison is false on NaN: nothing non-finite culls.
        let wide_of = c2 - b * (b / a) > reach * reach + slack;
        // Outside and moving away (oc·d > 0 beyond its rounding): the distance only grows.
        let away = b > 3.0 * CULL_MARGIN * d.abs().max_element() * (oc_size + o_size + self.centre_size);
        wide_of || (outside && away && tmin >= 0.0)
    }
}

/// The smallest root of `a t² + b t + c` in `(tmin, tmax)`, computed stably (no
/// cancellation between `b` and the root of the discriminant).
fn smallest_root(a: f64, b: f64, c: f64, tmin: f64, tmax: f64, accept: impl Fn(f64) -> bool) -> Option<f64> {
    if a == 0.0 {
        let t = -c / b;
        return (b != 0.0 && t > tmin && t < tmax && accept(t)).then_some(t);
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 || !disc.is_finite() {
        return None;
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let (mut t0, mut t1) = (q / a, if q != 0.0 { c / q } else { q / a });
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    [t0, t1].into_iter().find(|&t| t > tmin && t < tmax && accept(t))
}

impl Part {
    /// The nearest `t` in `(tmin, tmax)` where `o + t d` (object space) meets the part.
    pub fn intersect(&self, o: DVec3, d: DVec3, tmin: f64, tmax: f64) -> Option<f64> {
        let at = |t: f64| o + d * t;
        match *self {
            Part::Sphere { r, cz, zmin, zmax } => {
                let oc = o - DVec3::Z * cz;
                let a = d.length_squared();
                // b' = o·d; the discriminant from the closest approach (pbrt-v4): the
                // squared distance of the line from the centre, not r² − |o|² + (o·d)²/a.
                let b = oc.dot(d);
                let closest = oc - d * (b / a);
                let disc = 4.0 * a * (r - closest.length()) * (r + closest.length());
                if disc < 0.0 {
                    return None;
                }
                let q = -(b + b.signum() * 0.5 * disc.sqrt());
                // c = |oc|² − r², factored: no cancellation for origins on the surface.
                let c = (oc.length() - r) * (oc.length() + r);
                let (mut t0, mut t1) = (q / a, if q != 0.0 { c / q } else { q / a });
                if t0 > t1 {
                    std::mem::swap(&mut t0, &mut t1);
                }
                [t0, t1].into_iter().find(|&t| t > tmin && t < tmax && (zmin..=zmax).contains(&at(t).z))
            }
            Part::Cylinder { r, z0, z1 } => {
                let a = d.x * d.x + d.y * d.y;
                let b = 2.0 * (o.x * d.x + o.y * d.y);
                let c = o.x * o.x + o.y * o.y - r * r;
                if a == 0.0 {
                    return None;
                }
                smallest_root(a, b, c, tmin, tmax, |t| (z0..=z1).contains(&at(t).z))
            }
            Part::Cone { r, z0, z1 } => {
                // x² + y² = (k (z1 − z))², k = r / (z1 − z0).
                let k = r / (z1 - z0);
                let k2 = k * k;
                let dz = z1 - o.z;
                let a = d.x * d.x + d.y * d.y - k2 * d.z * d.z;
                let b = 2.0 * (o.x * d.x + o.y * d.y + k2 * dz * d.z);
                let c = o.x * o.x + o.y * o.y - k2 * dz * dz;
                smallest_root(a, b, c, tmin, tmax, |t| {
                    let z = at(t).z;
                    z >= z0.min(z1) && z <= z0.max(z1)
                })
            }
            Part::Disk { r, z, .. } => {
                if d.z == 0.0 {
                    return None;
                }
                let t = (z - o.z) / d.z;
                let p = at(t);
                (t > tmin && t < tmax && p.x * p.x + p.y * p.y <= r * r).then_some(t)
            }
        }
    }

    /// A sphere `(centre, radius)` around the part in object space: a sphere part's own,
    /// else the one around its bounds.
    fn bounding_sphere(&self) -> (DVec3, f64) {
        match *self {
            Part::Sphere { r, cz, .. } => (DVec3::new(0.0, 0.0, cz), r.abs()),
            _ => {
                let (lo, hi) = self.bounds();
                ((lo + hi) * 0.5, (hi - lo).length() * 0.5)
            }
        }
    }

    /// Object-space bounds `(min, max)`.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        match *self {
            Part::Sphere { r, cz, zmin, zmax } => {
                (DVec3::new(-r, -r, (cz - r).max(zmin)), DVec3::new(r, r, (cz + r).min(zmax)))
            }
            Part::Cylinder { r, z0, z1 } | Part::Cone { r, z0, z1 } => {
                (DVec3::new(-r, -r, z0.min(z1)), DVec3::new(r, r, z0.max(z1)))
            }
            Part::Disk { r, z, .. } => (DVec3::new(-r, -r, z), DVec3::new(r, r, z)),
        }
    }

    /// Bounds `(min, max)` under the object-to-world transform `m`: the transformed corners
    /// of the object box, in f64 (so that a transform beyond f32's range shows as such).
    pub fn world_bounds(&self, m: &DMat4) -> (DVec3, DVec3) {
        let (lo, hi) = self.bounds();
        transformed_box(m, lo, hi)
    }

    /// Position (projected back onto the surface), outward normal, `(u, v)`, ∂P/∂u and ∂P/∂v
    /// at an object-space point on the part.
    pub(crate) fn local_geometry(&self, p: DVec3) -> (DVec3, DVec3, (f64, f64), DVec3, DVec3) {
        let phi_of = |p: DVec3| {
            let phi = p.y.atan2(p.x);
            if phi < 0.0 { phi + TAU } else { phi }
        };
        match *self {
            Part::Sphere { r, cz, .. } => {
                let c = DVec3::Z * cz;
                let mut q = p - c;
                let len = q.length();
                if len > 0.0 {
                    q *= r / len;
                }
                let phi = phi_of(q);
                let theta = (q.z / r).clamp(-1.0, 1.0).acos();
                let dpdu = DVec3::new(-TAU * q.y, TAU * q.x, 0.0);
                let dpdtheta = DVec3::new(q.z * phi.cos(), q.z * phi.sin(), -r * theta.sin());
                (q + c, q / r, (phi / TAU, 1.0 - theta / PI), dpdu, -PI * dpdtheta)
            }
            Part::Cylinder { r, z0, z1 } => {
                let radial = DVec3::new(p.x, p.y, 0.0);
                let len = radial.length();
                let radial = if len > 0.0 { radial * (r / len) } else { DVec3::new(r, 0.0, 0.0) };
                let q = DVec3::new(radial.x, radial.y, p.z);
                let phi = phi_of(q);
                let dpdu = DVec3::new(-TAU * q.y, TAU * q.x, 0.0);
                let dpdv = DVec3::Z * (z1 - z0);
                (q, radial / r, (phi / TAU, (p.z - z0) / (z1 - z0)), dpdu, dpdv)
            }
            Part::Cone { r, z0, z1 } => {
                let h = z1 - z0;
                let phi = phi_of(p);
                let v = (p.z - z0) / h;
                let rad = r * (1.0 - v);
                let q = DVec3::new(rad * phi.cos(), rad * phi.sin(), p.z);
                let dpdu = DVec3::new(-TAU * q.y, TAU * q.x, 0.0);
                let dpdv = DVec3::new(-r * phi.cos(), -r * phi.sin(), h);
                // Outward: radial out, tilted towards the apex side by the slope r / h.
                let n = DVec3::new(phi.cos() * h.abs(), phi.sin() * h.abs(), r * h.signum()).normalize();
                (q, n, (phi / TAU, v), dpdu, dpdv)
            }
            Part::Disk { r, z, down } => {
                let q = DVec3::new(p.x, p.y, z);
                let n = if down { -DVec3::Z } else { DVec3::Z };
                let uv = (0.5 + 0.5 * q.x / r, 0.5 + 0.5 * q.y / r);
                (q, n, uv, DVec3::X * (2.0 * r), DVec3::Y * (2.0 * r))
            }
        }
    }
}

impl Shape {
    /// A part of prim `prim` under the object-to-world transform `m`; `None` when `m` cannot
    /// be inverted (the prim is then skipped as degenerate).
    pub fn new(part: Part, m: DMat4, prim: u32) -> Option<Shape> {
        let linear = DMat3::from_mat4(m);
        let det = linear.determinant();
        if det == 0.0 || !det.is_finite() || !m.is_finite() {
            return None;
        }
        let to_object = m.inverse();
        let normal_to_world = linear.inverse().transpose();
        Some(Shape {
            part,
            to_world: m,
            to_object,
            normal_to_world,
            prim,
            primvars: Default::default(),
            cull: Cull::new(&part, &m),
            single: SingleSphere::new(&part, &m, &to_object, &normal_to_world),
        })
    }

    /// World-space bounds `(min, max)`: the transformed corners of the object box.
    pub fn world_bounds(&self) -> (Vec3, Vec3) {
        let (lo, hi) = self.part.world_bounds(&self.to_world);
        (lo.as_vec3(), hi.as_vec3())
    }

    /// The nearest hit distance of the world ray `o + t d` in `(tmin, tmax)`.
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<f32> {
        if self.cull.misses(o, d, tmin) {
            return None;
        }
        self.intersect_exact(o, d, tmin, tmax)
    }

    /// [`Shape::intersect`] without the f32 cull: in f64 in object space.
    #[inline]
    fn intersect_exact(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<f32> {
        // The object-space direction is not unit: its `t` is the world ray's `t`.
        let oo = self.to_object.transform_point3(o.as_dvec3());
        let od = self.to_object.transform_vector3(d.as_dvec3());
        let t = self.part.intersect(oo, od, tmin as f64, tmax as f64)?;
        let t32 = t as f32;
        (t32 > tmin && t32 < tmax).then_some(t32)
    }

    /// Surface geometry where the world ray `o + t d` meets this part: in f32 for a sphere
    /// where the error bound allows (see [`SingleSphere::surface`]), else in f64.
    pub fn surface(&self, o: Vec3, d: Vec3, t: f32) -> SurfaceHit {
        if let Some(hit) = self.single.as_ref().and_then(|s| s.surface(o, d, t)) {
            return hit;
        }
        self.surface_exact(o, d, t)
    }

    /// [`Shape::surface`] in f64 in object space.
    fn surface_exact(&self, o: Vec3, d: Vec3, t: f32) -> SurfaceHit {
        let oo = self.to_object.transform_point3(o.as_dvec3());
        let od = self.to_object.transform_vector3(d.as_dvec3());
        let (p, n, (u, v), dpdu, dpdv) = self.part.local_geometry(oo + od * t as f64);
        let n = (self.normal_to_world * n).normalize_or_zero();
        let world = self.to_world.transform_point3(p);
        // The point is on the surface to f64 precision (projected onto it in object space);
        // what remains is the f64 transform's rounding, bounded by 1e-14 of the terms it
        // sums (|M| |p| + |t|), and the rounding to f32, half an f32 ULP (γ(2) is generous).
        let m = &self.to_world;
        let abs_m = DMat3::from_cols(m.x_axis.truncate().abs(), m.y_axis.truncate().abs(), m.z_axis.truncate().abs());
        let (lo, hi) = self.part.bounds();
        let f64_error = (abs_m * (p.abs() + lo.abs().max(hi.abs())) + m.w_axis.truncate().abs()) * 1e-14;
        let p32 = world.as_vec3();
        SurfaceHit {
            p: p32,
            p_error: p32.abs() * gamma(2) + f64_error.as_vec3(),
            n: n.as_vec3(),
            uv: Vec2::new(u as f32, v as f32),
            dpdu: self.to_world.transform_vector3(dpdu).as_vec3(),
            dpdv: self.to_world.transform_vector3(dpdv).as_vec3(),
        }
    }
}

/// Segments around the axis of a part's base mesh (see [`Part::base_mesh`]).
pub const BASE_SEGMENTS: usize = 32;

impl Part {
    /// A coarse triangle mesh of the part in object space, for dicing (displacement is the
    /// only reason a part becomes triangles): `(position, uv)` per corner, winding not
    /// oriented. Every ring point is computed from one table of `(cos, sin)` and an exact
    /// `(radius, z)`, so the rims parts of one prim share (a capsule's equators, a cylinder's
    /// caps) have bit-identical points and weld.
    pub fn base_mesh(&self) -> Vec<[(DVec3, Vec2); 3]> {
        let n = BASE_SEGMENTS;
        let ring: Vec<(f64, f64)> =
            (0..n).map(|j| (TAU * j as f64 / n as f64).sin_cos()).map(|(s, c)| (c, s)).collect();
        let at = |j: usize, radius: f64, z: f64| {
            let (c, s) = ring[j % n];
            DVec3::new(radius * c, radius * s, z)
        };
        // Rings `(radius, z, v)` from one end to the other; a radius of 0 is a pole.
        let rings: Vec<(f64, f64, f64)> = match *self {
            Part::Sphere { r, cz, zmin, zmax } => {
                // A whole sphere is cut at ±infinity.
                let (zmin, zmax) = (zmin.max(cz - r), zmax.min(cz + r));
                let (top, bottom) =
                    (((zmax - cz) / r).clamp(-1.0, 1.0).acos(), ((zmin - cz) / r).clamp(-1.0, 1.0).acos());
                let rows = ((16.0 * (bottom - top) / PI).ceil() as usize).max(1);
                (0..=rows)
                    .map(|i| {
                        // The end rings at the exact cut heights, so they meet a neighbour's rim.
                        let z = match i {
                            0 => zmax,
                            i if i == rows => zmin,
                            _ => cz + r * (top + (bottom - top) * i as f64 / rows as f64).cos(),
                        };
                        let radius = (r * r - (z - cz) * (z - cz)).max(0.0).sqrt();
                        (radius, z, 1.0 - ((z - cz) / r).clamp(-1.0, 1.0).acos() / PI)
                    })
                    .collect()
            }
            Part::Cylinder { r, z0, z1 } => vec![(r, z0, 0.0), (r, z1, 1.0)],
            Part::Cone { r, z0, z1 } => vec![(r, z0, 0.0), (0.0, z1, 1.0)],
            Part::Disk { r, z, .. } => vec![(r, z, 0.0), (0.0, z, 1.0)],
        };
        let uv = |j: usize, v: f64, p: DVec3| match self {
            Part::Disk { .. } => {
                let (_, _, (u, v), _, _) = self.local_geometry(p);
                Vec2::new(u as f32, v as f32)
            }
            _ => Vec2::new(j as f32 / n as f32, v as f32),
        };
        let mut out = Vec::new();
        for pair in rings.windows(2) {
            let ((ra, za, va), (rb, zb, vb)) = (pair[0], pair[1]);
            for j in 0..n {
                let corner = |k: usize, radius: f64, z: f64, v: f64| {
                    let p = at(k, radius, z);
                    (p, uv(k, v, p))
                };
                let (a0, a1) = (corner(j, ra, za, va), corner(j + 1, ra, za, va));
                let (b0, b1) = (corner(j, rb, zb, vb), corner(j + 1, rb, zb, vb));
                if ra > 0.0 {
                    out.push([a0, a1, b1]);
                }
                if rb > 0.0 {
                    out.push([a0, b1, b0]);
                }
            }
        }
        out
    }
}

/// The box of the 8 corners of `(lo, hi)` transformed by `m`, in f64 (so that a transform
/// beyond f32's range shows as such). Geometry, instances and the BVH all bound this way.
pub fn transformed_box(m: &DMat4, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
    let mut min = DVec3::splat(f64::INFINITY);
    let mut max = DVec3::splat(f64::NEG_INFINITY);
    for k in 0..8 {
        let c = DVec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let w = m.transform_point3(c);
        min = min.min(w);
        max = max.max(w);
    }
    (min, max)
}

/// `γ(n) = n ε / (1 − n ε)`, ε = 2⁻²⁴ (half an f32 ULP at 1): the bound on the relative
/// error of `n` successive f32 operations (Higham; pbrt-v4 `gamma`).
#[inline]
pub fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5;
    (n as f32 * e) / (1.0 - n as f32 * e)
}

/// A spawn point for a ray leaving a surface point `p` whose components are uncertain by
/// `p_error`, towards the side of the geometric normal `n` (pointing to where the ray goes):
/// `p` moved along `n` past the error box, then rounded away from the surface (pbrt-v4's
/// `OffsetRayOrigin`). The offset is as small as the error bound allows, at any scale.
pub fn offset_ray_origin(p: Vec3, p_error: Vec3, n: Vec3) -> Vec3 {
    let d = n.abs().dot(p_error);
    let offset = n * d;
    let mut po = p + offset;
    for i in 0..3 {
        if offset[i] > 0.0 {
            po[i] = po[i].next_up();
        } else if offset[i] < 0.0 {
            po[i] = po[i].next_down();
        }
    }
    po
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere(m: DMat4) -> Shape {
        Shape::new(Part::Sphere { r: 1.0, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY }, m, 0).unwrap()
    }

    #[test]
    fn sphere_hits_from_outside_and_inside() {
        let s = sphere(DMat4::from_translation(DVec3::new(0.0, 0.0, 5.0)));
        let t = s.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).unwrap();
        assert!((t - 4.0).abs() < 1e-6);
        let h = s.surface(Vec3::ZERO, Vec3::Z, t);
        assert!((h.n - -Vec3::Z).length() < 1e-6 && (h.p - Vec3::new(0.0, 0.0, 4.0)).length() < 1e-6);
        // From the centre, the far side at distance 1, normal still outward.
        let c = Vec3::new(0.0, 0.0, 5.0);
        let t = s.intersect(c, Vec3::X, 0.0, f32::INFINITY).unwrap();
        assert!((t - 1.0).abs() < 1e-6);
        assert!((s.surface(c, Vec3::X, t).n - Vec3::X).length() < 1e-6);
        assert!(s.intersect(Vec3::ZERO, -Vec3::Z, 0.0, f32::INFINITY).is_none());
        assert!(s.intersect(Vec3::ZERO, Vec3::Z, 0.0, 3.9).is_none());
    }

    #[test]
    fn ellipsoid_under_non_uniform_scale_has_the_analytic_normal() {
        // x²/4 + y² + z²/9 = 1: the normal at (2 cos a, sin a, 0) is ∝ (cos a / 2, sin a, 0).
        let s = sphere(DMat4::from_scale(DVec3::new(2.0, 1.0, 3.0)));
        let a = 0.7f32;
        let target = Vec3::new(2.0 * a.cos(), a.sin(), 0.0);
        let o = target * 3.0;
        let d = (target - o).normalize();
        let t = s.intersect(o, d, 0.0, f32::INFINITY).unwrap();
        let h = s.surface(o, d, t);
        assert!((h.p - target).length() < 1e-5, "{} vs {target}", h.p);
        let want = Vec3::new(a.cos() / 2.0, a.sin(), 0.0).normalize();
        assert!((h.n - want).length() < 1e-5, "{} vs {want}", h.n);
        // dP/du and dP/dv span the tangent plane.
        assert!(h.dpdu.dot(h.n).abs() < 1e-4 && h.dpdv.dot(h.n).abs() < 1e-4);
    }

    #[test]
    fn rays_leaving_a_sphere_never_hit_it_again() {
        // 2000 rays from points all over a sphere far from the origin, leaving at angles down
        // to grazing, from origins offset as the integrator offsets them.
        let s = sphere(DMat4::from_scale_rotation_translation(
            DVec3::splat(0.37),
            glam::DQuat::from_rotation_y(0.3),
            DVec3::new(12.0, -7.0, 30.0),
        ));
        let mut misses = 0;
        for i in 0..2000 {
            let (a, b) = (i as f32 * 0.618_034 * TAU as f32, ((i as f32 + 0.5) / 2000.0) * 2.0 - 1.0);
            let dir = Vec3::new((1.0 - b * b).sqrt() * a.cos(), (1.0 - b * b).sqrt() * a.sin(), b);
            let centre = Vec3::new(12.0, -7.0, 30.0);
            let o = centre - dir * 5.0;
            let t = s.intersect(o, dir, 0.0, f32::INFINITY).unwrap();
            let h = s.surface(o, dir, t);
            // A direction leaving the surface, cos from 1 down to 1e-4 against the normal.
            let tangent = h.n.any_orthonormal_vector();
            let cos = 10f32.powf(-4.0 * (i % 50) as f32 / 49.0);
            let out = (h.n * cos + tangent * (1.0 - cos * cos).sqrt()).normalize();
            let start = offset_ray_origin(h.p, h.p_error, h.n);
            if s.intersect(start, out, 0.0, f32::INFINITY).is_some() {
                misses += 1;
            }
        }
        assert_eq!(misses, 0, "rays re-hit the surface they leave");
    }

    #[test]
    fn rays_entering_a_sphere_reach_its_far_side() {
        // Refraction: from an origin offset inside, the next hit is across the sphere, not the
        // point just left.
        let s = sphere(DMat4::from_translation(DVec3::new(3.0, 0.0, 0.0)));
        for i in 0..200 {
            let a = i as f32 * 0.1;
            let n = Vec3::new(a.cos(), a.sin(), 0.0);
            let p = Vec3::new(3.0, 0.0, 0.0) + n;
            let inward = (-n + n.any_orthonormal_vector() * 0.5).normalize();
            let start = offset_ray_origin(p, p.abs() * gamma(3), -n);
            let t = s.intersect(start, inward, 0.0, f32::INFINITY).expect("far side");
            // The chord at this angle: 2 cos(angle to the normal).
            assert!((t - 2.0 * inward.dot(-n)).abs() < 1e-4, "{t}");
        }
        // UsdGeom parameterisation: u = φ/2π, v = 1 − θ/π, from the +z pole.
        let h = s.surface(Vec3::new(3.0, -5.0, 0.0), Vec3::Y, 4.0);
        assert!((h.uv - Vec2::new(0.75, 0.5)).length() < 1e-6, "{}", h.uv);
    }

    /// The f32 cull turns a ray away only where the exact f64 test finds no hit, for every
    /// part under rotation, non-uniform scale and far translation, for rays aimed at points
    /// just inside and outside the part's bounding sphere (grazing), from near and far
    /// origins, with ray segments ending before and starting after the part; and it does turn
    /// clear misses away.
    #[test]
    fn the_f32_cull_never_turns_away_a_hit() {
        let parts = [
            Part::Sphere { r: 1.0, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY },
            Part::Sphere { r: 0.5, cz: 2.0, zmin: 2.0, zmax: f64::INFINITY },
            Part::Cylinder { r: 1.0, z0: -1.0, z1: 2.0 },
            Part::Cone { r: 1.5, z0: 1.0, z1: -1.0 },
            Part::Disk { r: 2.0, z: 0.5, down: true },
        ];
        let transforms = [
            DMat4::IDENTITY,
            DMat4::from_scale_rotation_translation(
                DVec3::new(0.01, 3.0, 0.5),
                glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0),
                DVec3::new(1e4, -3e3, 7.0),
            ),
            DMat4::from_scale_rotation_translation(
                DVec3::splat(1e-3),
                glam::DQuat::from_rotation_z(0.7),
                DVec3::new(0.2, 0.1, -0.3),
            ),
        ];
        let mut next = uniform(0x9e37_79b9);
        let (mut culled, mut clear, mut hits) = (0, 0, 0);
        for part in parts {
            for m in transforms {
                let shape = Shape::new(part, m, 0).unwrap();
                let (centre, radius) = part.bounding_sphere();
                let to_object = m.inverse();
                for i in 0..4000 {
                    // A target near the bounding sphere (0.5 to 1.1 of its radius from the
                    // centre), in object space, seen from a world origin near or far.
                    let dir = DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
                    let target = centre + dir * radius * (0.5 + 0.6 * next());
                    let target = m.transform_point3(target);
                    let far = [1.0, 10.0, 1e4][i % 3];
                    let scale = m.transform_vector3(DVec3::splat(radius)).length();
                    let from = DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
                    let o = (target + from * scale * far).as_vec3();
                    let d = (target.as_vec3() - o).normalize();
                    let dist = (target.as_vec3() - o).length();
                    let (tmin, tmax) = match i % 4 {
                        0 => (0.0, f32::INFINITY),
                        1 => (0.0, dist * 0.5),
                        2 => (dist * 1.5, f32::INFINITY),
                        _ => (0.0, dist),
                    };
                    let exact = shape.intersect_exact(o, d, tmin, tmax);
                    let cull = shape.cull.misses(o, d, tmin);
                    assert!(!(cull && exact.is_some()), "{part:?} under {m:?}: ray {o} {d} culled but hits");
                    hits += usize::from(exact.is_some());
                    // A whole ray from near by whose line passes 5 % outside the sphere (in
                    // f64, in object space: the same ratio in world space under a rotation
                    // and uniform scale): the margins are far below that, so the cull must
                    // take it. (Under the non-uniform scale the world sphere is looser.)
                    let (oo, od) =
                        (to_object.transform_point3(o.as_dvec3()), to_object.transform_vector3(d.as_dvec3()));
                    let oc = oo - centre;
                    let line = (oc - od * (oc.dot(od) / od.length_squared())).length();
                    if i % 4 == 0 && i % 3 != 2 && m != transforms[1] && line > 1.05 * radius {
                        clear += 1;
                        culled += usize::from(cull);
                    }
                }
            }
        }
        assert!(hits > 5000, "the rays must hit ({hits})");
        assert!(clear > 100 && culled == clear, "the cull must take every clear miss ({culled} of {clear})");
    }

    /// Uniform numbers in [0, 1], from the BVH tests' generator.
    fn uniform(seed: u32) -> impl FnMut() -> f64 {
        let mut next = crate::render::geometry::accel::generator(seed);
        move || (f64::from(next()) + 1.0) * 0.5
    }

    /// Random spheres of radius 1e-3 … 1e4 (as the part's radius or as a uniform scale,
    /// rotated) centred up to 1e4 from the origin, and rays from a few radii to 1e4 away
    /// aimed at a point of each (every third sphere is within ten radii of the origin): `(shape, world centre, world radius, origin, direction)`.
    fn random_sphere_rays(count: usize, seed: u32) -> Vec<(Shape, DVec3, f64, Vec3, Vec3)> {
        let mut next = uniform(seed);
        (0..count)
            .map(|i| {
                let radius = 10f64.powf(-3.0 + 7.0 * next());
                // Every third near the origin for its size (where f32 suffices), the others
                // up to 1e4 away.
                let reach = if i % 3 == 0 { radius.min(1e4) * 10.0 } else { 1e4 };
                let centre = DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 2.0 * reach * next();
                let (part_r, scale) = if i % 2 == 0 { (radius, 1.0) } else { (1.0, radius) };
                let rotation = glam::DQuat::from_euler(glam::EulerRot::XYZ, next() * 6.0, next() * 6.0, next() * 6.0);
                let m = DMat4::from_scale_rotation_translation(DVec3::splat(scale), rotation, centre);
                let part = Part::Sphere { r: part_r, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY };
                let shape = Shape::new(part, m, 0).unwrap();
                let dir = DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
                // Up to 0.99 of the radius off the centre line: grazing rays too.
                let side = dir.any_orthonormal_vector();
                let aim = centre + side * radius * 0.99 * next().sqrt();
                let o = (aim - dir * radius * 10f64.powf(0.3 + 4.0 * next())).as_vec3();
                let d = (aim.as_vec3() - o).normalize();
                (shape, centre, radius, o, d)
            })
            .collect()
    }

    /// The f32 hit surface of a sphere against the f64 one on random spheres and rays: the
    /// same normal and (u, v) to within the tolerance it is used at, a point whose distance
    /// from the exact surface (in f64) is within the error bound along the normal, and the
    /// f64 path taken where the bound is too wide (small spheres far from the ray).
    #[test]
    fn the_f32_sphere_surface_matches_the_f64_one_within_its_bound() {
        let (mut single, mut exact) = (0, 0);
        let mut worst = 0.0f64;
        for (shape, centre, radius, o, d) in random_sphere_rays(20_000, 0x1234_5678) {
            let Some(t) = shape.intersect(o, d, 0.0, f32::INFINITY) else { continue };
            let Some(h) = shape.single.unwrap().surface(o, d, t) else {
                exact += 1;
                continue;
            };
            single += 1;
            let want = shape.surface_exact(o, d, t);
            assert!((h.n - want.n).length() < 4.0 * SINGLE_SURFACE_TOLERANCE, "{} vs {}", h.n, want.n);
            let du = (h.uv.x - want.uv.x).abs();
            assert!(du.min(1.0 - du) < 1e-4 && (h.uv.y - want.uv.y).abs() < 1e-4, "{} vs {}", h.uv, want.uv);
            let scale = (radius * 1e-5) as f32;
            assert!((h.dpdu - want.dpdu).length() < scale * 100.0 + want.dpdu.length() * 1e-4);
            assert!((h.dpdv - want.dpdv).length() < scale * 100.0 + want.dpdv.length() * 1e-4);
            // The distance of the f32 point from the exact sphere, in f64.
            let off = (h.p.as_dvec3() - centre).length() - radius;
            let bound = h.n.abs().dot(h.p_error) as f64;
            worst = worst.max(off.abs() / bound);
            assert!(off.abs() <= bound, "{off} off the surface, bound {bound} (radius {radius}, centre {centre})");
        }
        // The bound is a worst case, but not a loose one: random rays come within a few
        // times of it (0.34 of it at this seed).
        assert!(worst > 0.1, "the bound is needlessly loose ({worst} of it used at most)");
        assert!(single > 5000 && exact > 500, "both paths must be taken ({single} f32, {exact} f64)");
    }

    /// Rays spawned from f32 hit surfaces with the error-bound offset, on random spheres:
    /// leaving at any angle down to grazing they never hit the sphere again, entering they
    /// reach its far side (never the point they leave, never tunnelling out).
    #[test]
    fn rays_spawned_from_f32_sphere_surfaces_neither_re_hit_nor_tunnel() {
        let mut next = uniform(0x0bad_cafe);
        let (mut left, mut entered) = (0, 0);
        for (shape, _, radius, o, d) in random_sphere_rays(20_000, 0x5eed_0001) {
            let Some(t) = shape.intersect(o, d, 0.0, f32::INFINITY) else { continue };
            let Some(h) = shape.single.unwrap().surface(o, d, t) else { continue };
            let tangent = h.n.any_orthonormal_vector().normalize();
            let cos = 10f32.powf(-4.0 * next() as f32);
            let sin = (1.0 - cos * cos).max(0.0).sqrt();
            let out = (h.n * cos + tangent * sin).normalize();
            let start = offset_ray_origin(h.p, h.p_error, h.n);
            assert!(shape.intersect(start, out, 0.0, f32::INFINITY).is_none(), "re-hit leaving (radius {radius})");
            left += 1;
            // Inward at an angle that keeps the chord well above the f32 resolution.
            let cos = 0.05 + 0.95 * next() as f32;
            let inward = (-h.n * cos + tangent * (1.0 - cos * cos).sqrt()).normalize();
            let start = offset_ray_origin(h.p, h.p_error, -h.n);
            let t = shape.intersect(start, inward, 0.0, f32::INFINITY).expect("far side");
            let chord = 2.0 * radius as f32 * inward.dot(-h.n);
            assert!(t > 0.5 * chord, "t {t} for a chord of {chord}: re-hit the point left");
            entered += 1;
        }
        assert!(left > 5000 && entered > 5000, "{left} {entered}");
    }

    /// Spheres whose radius squared leaves f32's normal range (a 1e20 sky sphere seen from
    /// its centre, a 1e-20 grain) keep the f64 surface: the f32 one put the sky's hit point
    /// at its centre (|q| overflowed) and the grain's off the sphere by 12x its bound.
    #[test]
    fn spheres_too_large_or_small_for_f32_squares_keep_the_f64_surface() {
        for radius in [1e20, 1e-20, 2e12, 1e-13] {
            let part = Part::Sphere { r: radius, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY };
            let shape = Shape::new(part, DMat4::IDENTITY, 0).unwrap();
            assert!(shape.single.is_none(), "radius {radius} takes the f32 surface");
            let (o, d) = (Vec3::ZERO, Vec3::new(0.6, 0.0, 0.8));
            let t = shape.intersect(o, d, 0.0, f32::INFINITY).expect("hit from the centre");
            let h = shape.surface(o, d, t);
            let off = (h.p.as_dvec3().length() - radius).abs() / radius;
            assert!(off < 1e-6 && h.n.dot(d) > 0.999, "radius {radius}: point {} normal {}", h.p, h.n);
        }
        for radius in [1e9, 1e-9] {
            let part = Part::Sphere { r: radius, cz: 0.0, zmin: f64::NEG_INFINITY, zmax: f64::INFINITY };
            assert!(Shape::new(part, DMat4::IDENTITY, 0).unwrap().single.is_some(), "radius {radius}");
        }
    }

    #[test]
    fn cylinder_cone_and_disk() {
        let m = DMat4::IDENTITY;
        let cyl = Shape::new(Part::Cylinder { r: 1.0, z0: -1.0, z1: 1.0 }, m, 0).unwrap();
        let o = Vec3::new(-5.0, 0.0, 0.5);
        let t = cyl.intersect(o, Vec3::X, 0.0, f32::INFINITY).unwrap();
        assert!((t - 4.0).abs() < 1e-6);
        let h = cyl.surface(o, Vec3::X, t);
        assert!((h.n - -Vec3::X).length() < 1e-6 && (h.uv.y - 0.75).abs() < 1e-6);
        assert!(cyl.intersect(Vec3::new(-5.0, 0.0, 1.5), Vec3::X, 0.0, f32::INFINITY).is_none());
        // Open: a ray along the axis passes through.
        assert!(cyl.intersect(Vec3::new(0.0, 0.0, -5.0), Vec3::Z, 0.0, f32::INFINITY).is_none());
        let cone = Shape::new(Part::Cone { r: 1.0, z0: -1.0, z1: 1.0 }, m, 0).unwrap();
        // At z = 0 the cone's radius is 0.5; its normal leans up by atan(r/h) = atan(0.5).
        let t = cone.intersect(Vec3::new(-5.0, 0.0, 0.0), Vec3::X, 0.0, f32::INFINITY).unwrap();
        assert!((t - 4.5).abs() < 1e-6);
        let n = cone.surface(Vec3::new(-5.0, 0.0, 0.0), Vec3::X, t).n;
        assert!((n - Vec3::new(-2.0, 0.0, 1.0).normalize()).length() < 1e-6, "{n}");
        // Above the apex: no hit on the mirrored nappe.
        assert!(cone.intersect(Vec3::new(-5.0, 0.0, 1.5), Vec3::X, 0.0, f32::INFINITY).is_none());
        let disk = Shape::new(Part::Disk { r: 1.0, z: 1.0, down: false }, m, 0).unwrap();
        let t = disk.intersect(Vec3::new(0.5, 0.0, 3.0), -Vec3::Z, 0.0, f32::INFINITY).unwrap();
        assert!((t - 2.0).abs() < 1e-6);
        assert!(disk.intersect(Vec3::new(1.5, 0.0, 3.0), -Vec3::Z, 0.0, f32::INFINITY).is_none());
        assert!(Shape::new(Part::Disk { r: 1.0, z: 0.0, down: false }, DMat4::ZERO, 0).is_none());
    }
}
