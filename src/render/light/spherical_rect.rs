//! Rect lights sampled by solid angle: the spherical rectangle a rectangle subtends from a
//! point, sampled uniformly (Ureña, Fajardo and King 2013, "An Area-Preserving
//! Parametrization for Spherical Rectangles").
//!
//! Sampling the rectangle's area gives directions the density `d² / (cos θ_l A)`, so next-event
//! estimation carries the `1/d²` and `cos θ_l` of every sampled point into its estimate: large
//! and close lights, and points near a light's plane, are noisy. Uniform solid-angle samples
//! have the constant density `1 / Ω`. What depends only on the light (its frame, extent, dual
//! edge vectors and area) is made once, at load ([`RectFrame`]); the per-point set-up is in
//! f64 and takes the solid angle as the argument of one complex product, with one polynomial
//! arctangent ([`argument`]) instead of two calls to libm's `atan2`.

use super::PlaneCoordinates;
use glam::{DVec3, Vec2, Vec3};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Below this solid angle (sr) the light subtends so little that how it is sampled hardly
/// matters, and the sampling's `b0`, `b1` (differences of nearly equal sines) lose precision:
/// area sampling.
const MIN_SOLID_ANGLE: f64 = 1e-4;
/// Above this (2π less 0.08 sr) the point almost touches the light and the spherical
/// rectangle degenerates to a hemisphere: area sampling (pbrt-v4's bound, 6.22, is similar).
const MAX_SOLID_ANGLE: f64 = TAU - 0.08;
/// Edges whose cosine exceeds this are not a rectangle (a sheared rect light): area sampling.
const MAX_EDGE_COSINE: f64 = 1e-5;

/// A rect light's geometry that does not depend on the point it is seen from, made once when
/// the light is built ([`super::LightKind::rect`]): the rectangle's frame and extent for
/// solid-angle sampling, the dual edge vectors of the hit test and the area.
#[derive(Clone, Copy, Debug)]
pub struct RectFrame {
    /// The corner `centre − ex − ey`.
    corner: DVec3,
    /// Unit vectors along `ex`, along `ey` (made perpendicular to `x` where f32 rounding left
    /// the edges a hair off square) and `x × y`.
    x: DVec3,
    y: DVec3,
    z: DVec3,
    /// The full extents `2|ex|`, `2|ey|`.
    width: f64,
    height: f64,
    /// Whether the edges are square enough ([`MAX_EDGE_COSINE`]) and not degenerate: a
    /// sheared or empty rect light is sampled by area from every point.
    rectangle: bool,
    /// A point's edge coordinates, for the hit test.
    plane: PlaneCoordinates,
    /// `4 |ex × ey|`, as the area sampling and its pdf use it.
    area: f32,
}

impl RectFrame {
    /// The frame of the parallelogram `centre ± ex ± ey` with unit emission direction `n`.
    pub(super) fn new(centre: Vec3, ex: Vec3, ey: Vec3, n: Vec3) -> RectFrame {
        let area = 4.0 * ex.cross(ey).length();
        let (ex, ey, n64) = (ex.as_dvec3(), ey.as_dvec3(), n.as_dvec3());
        let (half_w, half_h) = (ex.length(), ey.length());
        let rectangle = half_w > 0.0 && half_h > 0.0 && ex.dot(ey).abs() <= MAX_EDGE_COSINE * half_w * half_h;
        let x = ex / half_w;
        let y = (ey - x * x.dot(ey)).normalize();
        RectFrame {
            corner: centre.as_dvec3() - ex - ey,
            x,
            y,
            z: x.cross(y),
            width: 2.0 * half_w,
            height: 2.0 * half_h,
            rectangle,
            plane: PlaneCoordinates::new(ex, ey, n64),
            area,
        }
    }

    /// The coordinates `(a, b)` of `d = a ex + b ey`, a vector in the light's plane.
    pub(super) fn edge_coordinates(&self, d: Vec3) -> (f32, f32) {
        self.plane.of(d)
    }

    /// `4 |ex × ey|`: the area of the parallelogram.
    pub(super) fn area(&self) -> f32 {
        self.area
    }
}

/// The rectangle of a [`RectFrame`] as seen from a point, ready for uniform solid-angle
/// sampling: the point's frame (`x` along `ex`, `y` along `ey`, `z` away from the light) and
/// the rectangle's extent in it, the paper's `x0 x1 y0 y1 z0 S`, and `e^{-ik}` for its `k`
/// (`b0 b1` and `k`'s unit complex number are made when sampling).
#[derive(Clone, Copy, Debug)]
pub(super) struct SphericalRect {
    x: DVec3,
    y: DVec3,
    z: DVec3,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    z0: f64,
    /// `e^{i(g2 + g3)}` = `e^{-ik}` times a positive factor.
    g23: (f64, f64),
    solid_angle: f64,
}

/// `a · b` as complex numbers `(re, im)`.
fn complex_mul(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0)
}

/// Abramowitz and Stegun 4.4.49: `atan x ≈ x P(x²)` on `[0, 1]`, absolute error below 2e-8
/// (1.36e-8 measured) and, as `P(0) = 1`, relative error below 1.8e-8 (1.77e-8 measured).
const ATAN_COEFFICIENTS: [f64; 9] = [
    1.0,
    -0.333_331_452_8,
    0.199_935_508_5,
    -0.142_088_994_4,
    0.106_562_639_3,
    -0.075_289_640_0,
    0.042_909_613_8,
    -0.016_165_736_7,
    0.002_866_225_7,
];

/// The argument of `re + i im` in `[0, 2π]` (exactly 2π where `im` is a hair below zero, which
/// the callers' 2π − 0.08 bound rejects): `atan2` without libm. The polynomial's relative
/// error (1.8e-8 on `[0, π/4]`) carries over: an angle above π/4 is π/2, π or 2π less one at
/// most π/4, whose absolute error (1.4e-8) is smaller relative to the result. So the solid
/// angle, and its f32 density, is within 2e-8 relative of the exact one, a third of f32's
/// rounding step (test `argument_is_within_its_bound`). NaN for `0 + 0i`.
fn argument(re: f64, im: f64) -> f64 {
    let (ar, ai) = (re.abs(), im.abs());
    let (x, steep) = if ai <= ar { (ai / ar, false) } else { (ar / ai, true) };
    let t = x * x;
    let p = ATAN_COEFFICIENTS.iter().rev().fold(0.0, |acc, &c| acc * t + c);
    let a = x * p;
    let a = if steep { FRAC_PI_2 - a } else { a };
    let a = if re < 0.0 { PI - a } else { a };
    if im < 0.0 { TAU - a } else { a }
}

impl SphericalRect {
    /// The spherical rectangle of `frame` seen from `p`, or `None` where it is numerically
    /// degenerate (see [`MIN_SOLID_ANGLE`], [`MAX_SOLID_ANGLE`], [`MAX_EDGE_COSINE`]): the
    /// caller samples the area there. Which side of the light `p` is on does not matter.
    pub(super) fn new(p: Vec3, frame: &RectFrame) -> Option<SphericalRect> {
        if !frame.rectangle {
            return None;
        }
        let corner = frame.corner - p.as_dvec3();
        let (x0, y0, mut z0) = (corner.dot(frame.x), corner.dot(frame.y), corner.dot(frame.z));
        // The paper's frame has the rectangle at z0 < 0.
        let z = if z0 > 0.0 { -frame.z } else { frame.z };
        z0 = -z0.abs();
        if z0 >= 0.0 {
            return None;
        }
        let (x1, y1) = (x0 + frame.width, y0 + frame.height);
        // The interior angles g0..g3 of the spherical quadrilateral are those between the
        // planes through p and each edge. With those planes' unit normals n0..n3 (the paper's),
        // (cos g, sin g) = (−nᵢ·nⱼ, |nᵢ × nⱼ|) reduces to corner coordinates over a positive
        // common factor, and a complex product adds angles: the product of all four has the
        // argument g0 + g1 + g2 + g3 = 2π + Ω, so one arctangent gives Ω where the paper's
        // set-up takes four (or two, pairing them): the gain is cost; the precision is that of
        // two arctangents' sum, since [`argument`]'s error is relative to the angle it reduces
        // to, small near multiples of π/2, where each pair's sum lies for a small rectangle.
        // Angles do not depend on scale: lengths are divided by the farthest corner's distance
        // first, so that the products of eight of them neither overflow nor underflow.
        let z0sq = z0 * z0;
        let corner_dist = |x: f64, y: f64| (x * x + y * y + z0sq).sqrt();
        let (r00, r10, r11, r01) = (corner_dist(x0, y0), corner_dist(x1, y0), corner_dist(x1, y1), corner_dist(x0, y1));
        let s = 1.0 / r00.max(r10).max(r11).max(r01);
        let (sx0, sx1, sy0, sy1, sh) = (x0 * s, x1 * s, y0 * s, y1 * s, -z0 * s);
        let g01 = complex_mul((sy0 * sx1, sh * r10 * s), (-sx1 * sy1, sh * r11 * s));
        let g23 = complex_mul((sx0 * sy1, sh * r01 * s), (-sx0 * sy0, sh * r00 * s));
        let (re, im) = complex_mul(g01, g23);
        let solid_angle = argument(re, im);
        (MIN_SOLID_ANGLE..=MAX_SOLID_ANGLE).contains(&solid_angle).then_some(SphericalRect {
            x: frame.x,
            y: frame.y,
            z,
            x0,
            x1,
            y0,
            y1,
            z0,
            g23,
            solid_angle,
        })
    }

    /// The solid angle (sr) the rectangle subtends: every sample's density is its inverse.
    pub(super) fn solid_angle(&self) -> f64 {
        self.solid_angle
    }

    /// The unit direction to, and distance of, the point of the rectangle that uniform `u`
    /// maps to, uniformly over the solid angle. Not finite in the rare case that rounding
    /// breaks the inversion (the caller drops the sample).
    pub(super) fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let SphericalRect { x0, x1, y0, y1, z0, g23, .. } = *self;
        // Here, not in the set-up: pdf_li needs only the solid angle.
        let b0 = -y0 / (z0 * z0 + y0 * y0).sqrt();
        let b1 = y1 / (z0 * z0 + y1 * y1).sqrt();
        // The x coordinate: the area swept from the x0 edge is u.x of the solid angle. The
        // paper's angle au = u.x Ω + k with k = 2π − g2 − g3: e^{ik} is g23's conjugate over
        // its length, turned by u.x Ω.
        let g23_len = (g23.0 * g23.0 + g23.1 * g23.1).sqrt();
        let (cos_k, sin_k) = (g23.0 / g23_len, -g23.1 / g23_len);
        let (sin_a, cos_a) = (u.x as f64 * self.solid_angle).sin_cos();
        let (cos_au, sin_au) = complex_mul((cos_k, sin_k), (cos_a, sin_a));
        let fu = (cos_au * b0 - b1) / sin_au;
        let cu = (fu.signum() / (fu * fu + b0 * b0).sqrt()).clamp(-1.0, 1.0);
        let xu = (-(cu * z0) / (1.0 - cu * cu).sqrt()).clamp(x0, x1);
        // The y coordinate: uniform in the sine of the elevation along that line.
        let d2 = xu * xu + z0 * z0;
        let h0 = y0 / (d2 + y0 * y0).sqrt();
        let h1 = y1 / (d2 + y1 * y1).sqrt();
        let hv = h0 + u.y as f64 * (h1 - h0);
        let hv2 = hv * hv;
        // |hv| ≈ 1: the line runs along the light's plane; the sine's sign says which edge.
        let yv = if hv2 < 1.0 - 1e-12 {
            hv * d2.sqrt() / (1.0 - hv2).sqrt()
        } else if hv > 0.0 {
            y1
        } else {
            y0
        };
        let to = self.x * xu + self.y * yv.clamp(y0, y1) + self.z * z0;
        let dist = to.length();
        ((to / dist).as_vec3(), dist as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::material::chi2::chi2_p_value;
    use crate::render::sampling::Rng;

    /// The spherical rectangle of `centre ± ex ± ey` from `p`, through the light's frame.
    fn spherical_rect(p: Vec3, centre: Vec3, ex: Vec3, ey: Vec3) -> Option<SphericalRect> {
        SphericalRect::new(p, &RectFrame::new(centre, ex, ey, ex.cross(ey).normalize()))
    }

    /// The solid angle of the triangle `a b c` seen from the origin, by Van Oosterom and
    /// Strackee (1983): `tan(Ω/2) = a·(b×c) / (|a||b||c| + (a·b)|c| + (a·c)|b| + (b·c)|a|)`.
    fn triangle_solid_angle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let num = a.dot(b.cross(c)).abs();
        let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        2.0 * num.atan2(den)
    }

    /// The closed-form solid angle of the parallelogram `centre ± ex ± ey` from `p`: two
    /// triangles. Independent of the spherical-rectangle set-up (no edge-plane angles).
    fn rect_solid_angle(p: Vec3, centre: Vec3, ex: Vec3, ey: Vec3) -> f64 {
        let c = (centre - p).as_dvec3();
        let (ex, ey) = (ex.as_dvec3(), ey.as_dvec3());
        let corners = [c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey];
        triangle_solid_angle(corners[0], corners[1], corners[2])
            + triangle_solid_angle(corners[0], corners[2], corners[3])
    }

    /// Rectangles from in front, behind, off to the side, edge-on and very close, and the
    /// points where the set-up must refuse (on the plane, sheared, too far).
    fn cases() -> Vec<(Vec3, Vec3, Vec3, Vec3)> {
        let (ex, ey) = (Vec3::new(1.5, 0.0, 0.0), Vec3::new(0.0, 0.0, 0.75));
        // Exactly perpendicular in f32 ((1, 2, 2) · (2, 1, −2) = 0): the closed form measures
        // the parallelogram, the set-up a rectangle, so a hair of shear would show.
        let tilted_x = Vec3::new(1.0, 2.0, 2.0) * 0.5;
        let tilted_y = Vec3::new(2.0, 1.0, -2.0) * 0.25;
        let c = Vec3::new(2.0, 4.0, 3.0);
        vec![
            (Vec3::ZERO, c, ex, ey),
            (Vec3::new(2.1, 3.9, 3.2), c, ex, ey),
            (Vec3::new(-3.0, 3.9, 3.2), c, ex, ey),
            (Vec3::new(2.0, 5.0, 3.0), c, ex, ey),
            (Vec3::new(9.0, 3.0, -1.0), c, tilted_x, tilted_y),
            (Vec3::new(2.5, 3.5, 3.1), c, tilted_x, tilted_y),
            (Vec3::new(0.0, 0.0, 0.0), c, tilted_x * 0.2, tilted_y * 3.0),
        ]
    }

    #[test]
    fn solid_angle_matches_the_closed_form() {
        let (c, ex, ey) = (Vec3::new(0.0, 2.0, 0.0), Vec3::X, Vec3::Z);
        // Besides the sampled cases: a speck near the smallest solid angle sampled (2e-4 sr,
        // head-on and oblique) and a point almost touching (2π − 0.28), the two ends of the
        // range sampled by solid angle.
        let extremes = [(Vec3::new(0.0, -139.0, 0.0), c, ex, ey), (Vec3::new(60.0, -90.0, 40.0), c, ex, ey)];
        let touching = [(Vec3::new(0.1, 1.95, 0.2), c, ex, ey)];
        for (p, c, ex, ey) in cases().into_iter().chain(extremes).chain(touching) {
            let sr = spherical_rect(p, c, ex, ey).expect("a regular case");
            let expected = rect_solid_angle(p, c, ex, ey);
            // The bound of `argument` (2e-8 relative) and f64 rounding.
            let error = (sr.solid_angle() - expected).abs() / expected;
            assert!(error < 2e-8, "{p}: {} vs {expected} ({error:e} relative)", sr.solid_angle());
        }
        assert!(spherical_rect(Vec3::new(5.0, 2.0, 0.0), c, ex, ey).is_none(), "on the light's plane");
        assert!(spherical_rect(Vec3::new(0.0, 1.999, 0.0), c, ex, ey).is_none(), "touching it");
        assert!(spherical_rect(Vec3::ZERO, c, ex, ey + Vec3::X * 0.1).is_none(), "sheared");
        assert!(spherical_rect(Vec3::new(0.0, -300.0, 0.0), c, ex, ey).is_none(), "a speck");
    }

    /// The polynomial `atan2` against libm's over the whole circle, the tiny angles of small
    /// solid angles and the turns just short of 2π included: within 1.8e-8 relative.
    #[test]
    fn argument_is_within_its_bound() {
        let tiny = (0..200).map(|i| 10f64.powf(-12.0 + 11.0 * i as f64 / 200.0));
        let circle = (1..200_000).map(|i| TAU * i as f64 / 200_000.0);
        let mut worst = 0.0f64;
        for theta in tiny.clone().chain(circle).chain(tiny.map(|t| TAU - t)) {
            for scale in [1e-30, 0.7, 3e25] {
                let (re, im) = (theta.cos() * scale, theta.sin() * scale);
                let exact = im.atan2(re).rem_euclid(TAU);
                let got = argument(re, im);
                let error = (got - exact).abs() / exact;
                worst = worst.max(error);
                assert!(error < 1.8e-8, "θ = {theta}: {got} vs {exact} ({error:e} relative)");
            }
        }
        assert!(worst > 1.7e-8, "the bound is tight: {worst:e}");
        assert_eq!(argument(1.0, 0.0), 0.0);
        assert_eq!(argument(-2.0, 0.0), PI);
        assert!(argument(0.0, 0.0).is_nan(), "no direction: refused by the solid-angle range");
    }

    /// χ² of the sampled points over an 8 × 8 grid of cells of the rectangle against the
    /// cells' closed-form solid angles over the whole one: the samples are uniform in solid
    /// angle, and every sample lies on the rectangle.
    #[test]
    fn samples_are_uniform_in_solid_angle() {
        const CELLS: usize = 8;
        const SAMPLES: usize = 200_000;
        let all = cases();
        // Šidák: 1 % over all cases.
        let alpha = 1.0 - 0.99f64.powf(1.0 / all.len() as f64);
        for (case, &(p, c, ex, ey)) in all.iter().enumerate() {
            let sr = spherical_rect(p, c, ex, ey).unwrap();
            let mut observed = [0usize; CELLS * CELLS];
            let mut rng = Rng::new(11, case as u64, 0);
            let normal = ex.cross(ey).as_dvec3().normalize();
            for _ in 0..SAMPLES {
                let (wi, dist) = sr.sample(rng.uniform2());
                assert!((wi.length() - 1.0).abs() < 1e-5 && dist > 0.0, "{p}: {wi} {dist}");
                let q = (p + wi * dist - c).as_dvec3();
                assert!(q.dot(normal).abs() < 1e-4 * (1.0 + dist as f64), "{p}: off the plane");
                let a = q.dot(ex.as_dvec3()) / ex.length_squared() as f64;
                let b = q.dot(ey.as_dvec3()) / ey.length_squared() as f64;
                assert!(a.abs() <= 1.0 + 1e-4 && b.abs() <= 1.0 + 1e-4, "{p}: outside ({a}, {b})");
                let cell = |t: f64| (((t + 1.0) / 2.0 * CELLS as f64) as usize).min(CELLS - 1);
                observed[cell(a) * CELLS + cell(b)] += 1;
            }
            let mut stat = 0.0;
            for i in 0..CELLS {
                for j in 0..CELLS {
                    let centre_of = |k: usize| -1.0 + (2 * k + 1) as f32 / CELLS as f32;
                    let cell_centre = c + ex * centre_of(i) + ey * centre_of(j);
                    let share = rect_solid_angle(p, cell_centre, ex / CELLS as f32, ey / CELLS as f32)
                        / rect_solid_angle(p, c, ex, ey);
                    let expected = share * SAMPLES as f64;
                    let o = observed[i * CELLS + j] as f64;
                    stat += (o - expected).powi(2) / expected;
                }
            }
            let pv = chi2_p_value(stat, CELLS * CELLS - 1);
            assert!(pv > alpha, "case {case} from {p}: chi2 = {stat:.1}, p = {pv:e}");
        }
    }

    /// A receiver a hair above the light's plane and just past an edge: a line of samples runs
    /// along the plane (|sine of elevation| ≈ 1), and `u.y = 0` must reach the far edge, not
    /// the near one (the density stays 1/Ω, so a wrong end would be a silent bias).
    #[test]
    fn a_sample_along_the_plane_reaches_the_far_edge() {
        let (c, ex, ey) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let p = Vec3::new(0.0, 1.0 + 1e-7, 1e-7);
        let sr = spherical_rect(p, c, ex, ey).expect("Ω ≈ π/2 is sampled by solid angle");
        let (wi, dist) = sr.sample(Vec2::new(0.5, 0.0));
        let q = p + wi * dist;
        assert!((q.y + 1.0).abs() < 1e-3, "u.y = 0 lands at y = {} (the far edge is -1)", q.y);
    }

    /// Where the spherical rectangle is refused (a sheared light; a point almost touching a
    /// large light) the light samples its area, and pdf_li returns that same density.
    #[test]
    fn refused_rectangles_are_sampled_by_area_with_the_same_density() {
        use crate::render::light::{Light, LightKind};
        let cases = [
            // Sheared (edges 8.5° off square), from 1 above: E[1/pdf] against the closed form.
            (Vec3::new(0.0, 0.0, 1.0), Vec3::X * 2.0, Vec3::new(0.3, 2.0, 0.0), true),
            // 0.01 above a 4 x 4 light: Ω within 0.08 sr of 2π. 1/pdf is too heavy-tailed
            // here for its mean to be tested at this sample count.
            (Vec3::new(0.3, 0.2, 0.01), Vec3::X * 2.0, Vec3::Y * 2.0, false),
        ];
        for (p, ex, ey, check_mean) in cases {
            let (centre, n) = (Vec3::ZERO, Vec3::Z);
            assert!(spherical_rect(p, centre, ex, ey).is_none(), "{p}: the area branch");
            let light = Light {
                path: "/R".into(),
                kind: LightKind::rect(centre, ex, ey, n, Vec3::ONE),
                visible_to_camera: true,
            };
            let mut rng = Rng::new(5, 0, 0);
            let samples = 200_000;
            let mut inv_pdf_sum = 0.0f64;
            for _ in 0..samples {
                let s = light.sample_li(p, Vec3::ZERO, rng.uniform2()).expect("the light faces p");
                let pdf = light.pdf_li(p, Vec3::ZERO, s.wi);
                assert!((pdf - s.pdf).abs() <= 1e-3 * s.pdf, "{p}: pdf_li {pdf} vs the sample's {}", s.pdf);
                inv_pdf_sum += 1.0 / s.pdf as f64;
            }
            if check_mean {
                let expected = rect_solid_angle(p, centre, ex, ey);
                let mean = inv_pdf_sum / samples as f64;
                assert!((mean - expected).abs() < 0.01 * expected, "{p}: E[1/pdf] {mean} vs Ω {expected}");
            }
        }
    }
}
