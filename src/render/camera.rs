//! UsdGeom cameras: a pinhole or thin-lens perspective camera looking down its local −Z
//! with +Y up, or a default camera framing the scene when the stage has none.
//!
//! `focalLength` and the apertures share a unit (USD: tenths of a scene unit), so the field
//! of view depends only on their ratio. The aperture is fit horizontally, as USD's
//! `CameraUtilFit` horizontal policy: the horizontal aperture is kept and the vertical extent
//! follows the image aspect. Depth of field (when `fStop > 0` and `focusDistance > 0`) uses a
//! thin lens of diameter `focalLength / fStop`, converted from tenths of a unit to scene units.

use crate::diag::{Diagnostic, Diagnostics};
use crate::render::geometry::xform::value_span;
use crate::render::sampling::concentric_disk;
use crate::scene::{Prim, Value};
use glam::{DMat4, Mat4, Vec2, Vec3};

/// A perspective camera in world space.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    origin: Vec3,
    right: Vec3,
    up: Vec3,
    forward: Vec3,
    /// `tan` of half the horizontal and vertical field of view.
    tan_half: Vec2,
    /// Aperture offset, as a fraction of the focal length.
    shift: Vec2,
    lens_radius: f32,
    focus_distance: f32,
    near: f32,
    far: f32,
    /// For a framing camera: the bounding sphere `(centre, radius)` to keep in view.
    framed: Option<(Vec3, f32)>,
}

/// A camera ray: origin, unit direction and the clipping interval along it.
#[derive(Clone, Copy, Debug)]
pub struct CameraRay {
    /// Origin (on the lens).
    pub o: Vec3,
    /// Unit direction.
    pub d: Vec3,
    /// Near clip distance along `d`.
    pub tmin: f32,
    /// Far clip distance along `d`.
    pub tmax: f32,
}

impl Camera {
    /// Reads a `Camera` prim with its world transform, for an image of aspect `width / height`.
    pub fn from_prim(prim: &Prim, world: DMat4, aspect: f32, diags: &mut Diagnostics) -> Camera {
        let num = |name: &str, default: f64| prim.value(name).and_then(Value::as_f64).unwrap_or(default);
        let focal = num("focalLength", 50.0);
        let h_aperture = num("horizontalAperture", 20.955);
        if !(focal > 0.0 && h_aperture > 0.0 && focal.is_finite() && h_aperture.is_finite()) {
            let attr = prim.attribute("focalLength").or_else(|| prim.attribute("horizontalAperture"));
            let mut d = Diagnostic::error(format!(
                "camera `{}` needs a positive focalLength and horizontalAperture (got {focal}, {h_aperture})",
                prim.path
            ));
            d = d.at(attr.map_or(prim.span, value_span), "here");
            diags.push(d);
        }
        if prim.value("projection").and_then(Value::as_str) == Some("orthographic") {
            diags.push(
                Diagnostic::warning(format!(
                    "camera `{}`: orthographic projection is rendered as perspective",
                    prim.path
                ))
                .at(prim.attribute("projection").map_or(prim.span, value_span), "here"),
            );
        }
        let focal = if focal > 0.0 && focal.is_finite() { focal } else { 50.0 };
        let h_aperture = if h_aperture > 0.0 && h_aperture.is_finite() { h_aperture } else { 20.955 };
        let tan_w = (h_aperture / 2.0 / focal) as f32;
        let shift = Vec2::new(
            (num("horizontalApertureOffset", 0.0) / focal) as f32,
            (num("verticalApertureOffset", 0.0) / focal) as f32,
        );
        let clip = prim.value("clippingRange").and_then(Value::as_vec2).unwrap_or([1.0, 1_000_000.0]);
        let f_stop = num("fStop", 0.0);
        let focus = num("focusDistance", 0.0);
        let lens_radius = if f_stop > 0.0 && focus > 0.0 { (focal * 0.1 / f_stop / 2.0) as f32 } else { 0.0 };
        let placed = Camera {
            origin: Vec3::ZERO,
            right: Vec3::X,
            up: Vec3::Y,
            forward: -Vec3::Z,
            tan_half: Vec2::new(tan_w, tan_w / aspect.max(1e-6)),
            shift,
            lens_radius,
            focus_distance: focus as f32,
            near: clip[0].max(0.0) as f32,
            far: clip[1] as f32,
            framed: None,
        };
        placed.placed_at(world)
    }

    /// The same lens under the camera-to-world transform `world` (a camera moving while the
    /// shutter is open is placed per ray).
    pub fn placed_at(&self, world: DMat4) -> Camera {
        let origin = world.transform_point3(glam::DVec3::ZERO).as_vec3();
        let right = world.transform_vector3(glam::DVec3::X).as_vec3().normalize_or(Vec3::X);
        let up = world.transform_vector3(glam::DVec3::Y).as_vec3().normalize_or(Vec3::Y);
        let forward = world.transform_vector3(-glam::DVec3::Z).as_vec3().normalize_or(-Vec3::Z);
        Camera { origin, right, up, forward, framed: None, ..*self }
    }

    /// A camera that frames the box `(lo, hi)` in a three-quarter view from the front right
    /// and above (30° azimuth, 25° elevation: the view a product shot or a DCC's default
    /// perspective shows), with `up_axis` (`"Y"` or `"Z"`) up and a 50 mm lens on a 36 mm
    /// back. A flat box (a decal, a ground plane, a card) is seen mostly face on instead of
    /// edge on: along its thin axis, tilted by the same three-quarter offset.
    pub fn framing(lo: Vec3, hi: Vec3, aspect: f32, up_axis: &str) -> Camera {
        let centre = (lo + hi) * 0.5;
        // The box's own size at any scale (a fixed floor of 1e-3 framed a scene 1e-6 across
        // as a speck); a single point gets a radius relative to its position.
        let half_diagonal = (hi - lo).length() * 0.5;
        let radius = if half_diagonal.is_normal() { half_diagonal } else { centre.abs().max_element().max(1.0) * 1e-3 };
        let tan_w = 18.0 / 50.0;
        let tan_h = tan_w / aspect.max(1e-6);
        let half = tan_w.min(tan_h).atan();
        let distance = radius / half.sin();
        // USD's front is +Z for a Y-up stage and −Y for a Z-up one; right is +X in both.
        let (up_world, front) = if up_axis == "Z" { (Vec3::Z, -Vec3::Y) } else { (Vec3::Y, Vec3::Z) };
        let (azimuth, elevation) = (30f32.to_radians(), 25f32.to_radians());
        let horizontal = front * azimuth.cos() + Vec3::X * azimuth.sin();
        let three_quarter = (horizontal * elevation.cos() + up_world * elevation.sin()).normalize();
        let extent = hi - lo;
        let thin = extent.min_element() <= 0.05 * extent.max_element() && extent.max_element() > 0.0;
        let back = if thin {
            // The thin axis, on the side the three-quarter view is on (the top of a ground
            // plane, the front of a card), with the three-quarter tilt kept.
            let axis = Vec3::AXES[extent.min_position()];
            let axis = if axis.dot(three_quarter) < 0.0 { -axis } else { axis };
            (axis * 2.0 + three_quarter).normalize()
        } else {
            three_quarter
        };
        let forward = -back;
        // Looking straight down the up axis (a ground plane): any right vector will do.
        let up_world = if forward.cross(up_world).length_squared() < 1e-6 { front } else { up_world };
        let right = forward.cross(up_world).normalize();
        let up = right.cross(forward);
        Camera {
            origin: centre + back * distance,
            right,
            up,
            forward,
            tan_half: Vec2::new(tan_w, tan_h),
            shift: Vec2::ZERO,
            lens_radius: 0.0,
            focus_distance: 0.0,
            near: 0.0,
            far: f32::INFINITY,
            framed: Some((centre, radius)),
        }
    }

    /// The same camera for an image of aspect `width / height` (horizontal aperture fit; a
    /// framing camera also moves so the scene stays in view).
    pub fn with_aspect(&self, aspect: f32) -> Camera {
        let mut c = *self;
        c.tan_half.y = c.tan_half.x / aspect.max(1e-6);
        if let Some((centre, radius)) = c.framed {
            let half = c.tan_half.x.min(c.tan_half.y).atan();
            c.origin = centre - c.forward * (radius / half.sin());
        }
        c
    }

    /// The same lens moved to `origin` looking along `forward` with `up` roughly up (a live
    /// view's orbit, pan and dolly). No longer reframes the scene when the aspect changes.
    pub fn posed(&self, origin: Vec3, forward: Vec3, up: Vec3) -> Camera {
        let forward = forward.normalize_or(self.forward);
        let right = forward.cross(up).normalize_or(self.right);
        Camera { origin, forward, right, up: right.cross(forward), framed: None, ..*self }
    }

    /// The angle (radians, small-angle) one pixel spans across an image `width` pixels wide:
    /// a length `l` at distance `d` from the camera covers about `l / (d · pixel_angle)` pixels.
    pub fn pixel_angle(&self, width: usize) -> f32 {
        2.0 * self.tan_half.x / width.max(1) as f32
    }

    /// The camera position.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// The viewing direction.
    pub fn forward(&self) -> Vec3 {
        self.forward
    }

    /// The image's up direction in the world.
    pub fn up(&self) -> Vec3 {
        self.up
    }

    /// The image's right direction in the world.
    pub fn right(&self) -> Vec3 {
        self.right
    }

    /// The world-to-camera transform (column vectors), camera space as in USD and OpenEXR:
    /// right-handed, looking down −Z with +Y up.
    pub fn world_to_camera(&self) -> Mat4 {
        let camera_to_world = Mat4::from_cols(
            self.right.extend(0.0),
            self.up.extend(0.0),
            (-self.forward).extend(0.0),
            self.origin.extend(1.0),
        );
        camera_to_world.inverse()
    }

    /// The camera-to-NDC projection (column vectors, OpenGL-style clip space): after the
    /// divide by `w`, x and y run over −1..1 across the image (x right, y up, aperture offsets
    /// included) and z runs from −1 at the near clipping plane to 1 at the far one (a far
    /// plane at infinity maps to 1 in the limit).
    pub fn camera_to_ndc(&self) -> Mat4 {
        let near = if self.near > 0.0 { self.near } else { 1e-3 };
        let (c, d) = if self.far.is_finite() && self.far > near {
            let (n, f) = (near, self.far);
            (-(f + n) / (f - n), -2.0 * f * n / (f - n))
        } else {
            (-1.0, -2.0 * near)
        };
        // x_ndc = (x / tan_x + shift_x · z) / −z: the inverse of `ray`'s film mapping.
        Mat4::from_cols(
            glam::Vec4::new(1.0 / self.tan_half.x, 0.0, 0.0, 0.0),
            glam::Vec4::new(0.0, 1.0 / self.tan_half.y, 0.0, 0.0),
            glam::Vec4::new(self.shift.x, self.shift.y, c, -1.0),
            glam::Vec4::new(0.0, 0.0, d, 0.0),
        )
    }

    /// OpenEXR's standard `worldToCamera` (column vectors; ImfStandardAttributes): camera
    /// space left-handed, +X right, +Y up and +Z the viewing direction, so a point in view
    /// has a positive z equal to its depth (the `Z` channel).
    pub fn world_to_camera_exr(&self) -> Mat4 {
        let camera_to_world = Mat4::from_cols(
            self.right.extend(0.0),
            self.up.extend(0.0),
            self.forward.extend(0.0),
            self.origin.extend(1.0),
        );
        camera_to_world.inverse()
    }

    /// OpenEXR's standard `worldToNDC` (column vectors): after the divide by `w`, (0, 0) is
    /// the display window's top-left corner and (1, 1) its bottom-right, y down, whatever the
    /// aspect; z runs from 0 at the near clipping plane to 1 at the far one.
    pub fn world_to_ndc_exr(&self) -> Mat4 {
        // From OpenGL clip space (x right and y up over −1..1): x' = (x + w)/2, y' = (w − y)/2.
        let to_exr = Mat4::from_cols(
            glam::Vec4::new(0.5, 0.0, 0.0, 0.0),
            glam::Vec4::new(0.0, -0.5, 0.0, 0.0),
            glam::Vec4::new(0.0, 0.0, 0.5, 0.0),
            glam::Vec4::new(0.5, 0.5, 0.5, 1.0),
        );
        to_exr * self.camera_to_ndc() * self.world_to_camera()
    }

    /// The near and far clipping distances along the viewing axis (far may be infinite).
    pub fn clipping_range(&self) -> (f32, f32) {
        (self.near, self.far)
    }

    /// Whether rays start across a lens (depth of field), so [`Camera::ray`] reads its `lens`
    /// sample; a pinhole camera ignores it and its caller need not draw one.
    pub fn has_lens(&self) -> bool {
        self.lens_radius > 0.0
    }

    /// The ray through film position `film` (`[0,1]²`, x to the right, y downwards) using
    /// lens sample `lens` (`[0,1)²`, unused for a pinhole).
    pub fn ray(&self, film: Vec2, lens: Vec2) -> CameraRay {
        let x = (2.0 * film.x - 1.0 + self.shift.x) * self.tan_half.x;
        let y = (1.0 - 2.0 * film.y + self.shift.y) * self.tan_half.y;
        // Direction in camera space with unit depth along forward.
        let local = Vec3::new(x, y, 1.0);
        let (o_local, d_local) = if self.lens_radius > 0.0 {
            let l = concentric_disk(lens) * self.lens_radius;
            let focus = local * self.focus_distance;
            (Vec3::new(l.x, l.y, 0.0), focus - Vec3::new(l.x, l.y, 0.0))
        } else {
            (Vec3::ZERO, local)
        };
        let to_world = |v: Vec3| self.right * v.x + self.up * v.y + self.forward * v.z;
        let len = d_local.length();
        let d = to_world(d_local / len);
        // Clipping planes are depths along the view axis.
        let cos = d_local.z / len;
        CameraRay { o: self.origin + to_world(o_local), d, tmin: self.near / cos, tmax: self.far / cos }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::geometry::xform::{tests::stage, world_transforms};

    /// Whether `p` projects inside the image of `camera`.
    fn in_view(camera: &Camera, p: Vec3) -> bool {
        let q = camera.world_to_camera().transform_point3(p);
        q.z < 0.0
            && (q.x / -q.z).abs() <= camera.tan_half.x * 1.0001
            && (q.y / -q.z).abs() <= camera.tan_half.y * 1.0001
    }

    #[test]
    fn framing_camera_shows_a_three_quarter_view_from_above_with_the_stage_up() {
        let (lo, hi) = (Vec3::new(-1.0, 0.0, -2.0), Vec3::new(3.0, 2.0, 1.0));
        let centre = (lo + hi) * 0.5;
        for aspect in [0.5, 1.0, 16.0 / 9.0] {
            // Y up: the eye is right of, above and in front of (+Z) the box.
            let y_up = Camera::framing(lo, hi, aspect, "Y").with_aspect(aspect);
            let eye = y_up.origin() - centre;
            assert!(eye.x > 0.0 && eye.y > 0.0 && eye.z > 0.0, "{eye}");
            assert!(eye.z > eye.x, "more from the front than the side: {eye}");
            assert!(y_up.up().y > 0.8, "the image's up is the stage's: {}", y_up.up());
            // Z up: front is −Y.
            let z_up = Camera::framing(lo, hi, aspect, "Z").with_aspect(aspect);
            let eye = z_up.origin() - centre;
            assert!(eye.x > 0.0 && eye.z > 0.0 && eye.y < 0.0, "{eye}");
            assert!(z_up.up().z > 0.8, "{}", z_up.up());
            for camera in [y_up, z_up] {
                for corner in 0..8 {
                    let p = Vec3::select(glam::BVec3::new(corner & 1 != 0, corner & 2 != 0, corner & 4 != 0), hi, lo);
                    assert!(in_view(&camera, p), "corner {p} out of view at aspect {aspect}");
                }
            }
        }
    }

    #[test]
    fn flat_boxes_are_framed_face_on_not_edge_on() {
        // A card in the XY plane (a decal): seen along Z, from the front.
        let card = Camera::framing(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.001), 1.0, "Y");
        assert!(card.forward().z < -0.8, "{}", card.forward());
        // A ground plane: seen from above, with a well-defined frame.
        let ground = Camera::framing(Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, 5.0), 1.0, "Y");
        assert!(ground.forward().y < -0.8, "{}", ground.forward());
        assert!(ground.right().is_finite() && ground.up().is_finite());
        // A Z-up ground plane likewise.
        let ground = Camera::framing(Vec3::new(-5.0, -5.0, 0.0), Vec3::new(5.0, 5.0, 0.0), 1.0, "Z");
        assert!(ground.forward().z < -0.8 && ground.up().is_finite(), "{}", ground.forward());
    }

    #[test]
    fn fov_follows_focal_length_over_aperture_and_horizontal_fit() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Camera "C" {
    float focalLength = 18
    float horizontalAperture = 36
    float verticalAperture = 10
    double3 xformOp:translate = (0, 0, 5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}"#,
        );
        let xf = world_transforms(&stage, &mut diags);
        let id = stage.find("/C").unwrap();
        let cam = Camera::from_prim(stage.prim(id), xf[id.0 as usize].world, 2.0, &mut diags);
        assert!(!diags.has_errors());
        // Right edge of the film: tan = 18/18 = 1 → 45°.
        let r = cam.ray(Vec2::new(1.0, 0.5), Vec2::ZERO);
        assert!((r.d - Vec3::new(1.0, 0.0, -1.0).normalize()).length() < 1e-6);
        // Top edge: aspect 2 → tan 0.5 (the authored verticalAperture does not matter).
        let t = cam.ray(Vec2::new(0.5, 0.0), Vec2::ZERO);
        assert!((t.d - Vec3::new(0.0, 0.5, -1.0).normalize()).length() < 1e-6);
        assert_eq!(r.o, Vec3::new(0.0, 0.0, 5.0));
        // Near clip 1 along the axis is 1/cos along an oblique ray.
        assert!((r.tmin - 2f32.sqrt()).abs() < 1e-5);
    }

    /// The framing camera scales with the scene: the same view of a box 2e-6 or 2e4 across
    /// as of one 2 across (a fixed minimum radius of 1e-3 made the small one a speck).
    #[test]
    fn framing_is_scale_free() {
        let unit = Camera::framing(Vec3::splat(-1.0), Vec3::splat(1.0), 1.5, "Y");
        for s in [1e-6f32, 1e4] {
            let c = Camera::framing(Vec3::splat(-s), Vec3::splat(s), 1.5, "Y");
            assert!((c.origin / s - unit.origin).length() < 1e-5 * unit.origin.length(), "{s}: {}", c.origin);
            assert!((c.forward - unit.forward).length() < 1e-6, "{s}");
        }
        // A single point still gets a camera that is finite and off the point.
        let point = Camera::framing(Vec3::ONE, Vec3::ONE, 1.0, "Z");
        assert!(point.origin.is_finite() && point.origin != Vec3::ONE);
    }

    #[test]
    fn camera_matrices_map_film_positions_back_to_ndc() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Camera "C" {
    float focalLength = 35
    float horizontalAperture = 36
    float horizontalApertureOffset = 3
    double3 xformOp:rotateXYZ = (10, 30, 0)
    double3 xformOp:translate = (1, 2, 5)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}"#,
        );
        let xf = world_transforms(&stage, &mut diags);
        let id = stage.find("/C").unwrap();
        let cam = Camera::from_prim(stage.prim(id), xf[id.0 as usize].world, 1.5, &mut diags);
        let to_ndc = cam.camera_to_ndc() * cam.world_to_camera();
        for film in [Vec2::new(0.5, 0.5), Vec2::new(0.1, 0.9), Vec2::new(0.95, 0.2)] {
            let r = cam.ray(film, Vec2::ZERO);
            let p = r.o + r.d * 7.0;
            // In camera space the point is in front: negative z.
            assert!(cam.world_to_camera().transform_point3(p).z < 0.0);
            let ndc = to_ndc.project_point3(p);
            let expected = Vec2::new(2.0 * film.x - 1.0, 1.0 - 2.0 * film.y);
            assert!((ndc.truncate() - expected).length() < 1e-4, "{film}: {ndc}");
            assert!((-1.0..=1.0).contains(&ndc.z), "{ndc}");
        }
    }

    #[test]
    fn depth_of_field_focuses_at_focus_distance() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Camera "C" {
    float focalLength = 50
    float horizontalAperture = 36
    float fStop = 1
    float focusDistance = 4
}"#,
        );
        let id = stage.find("/C").unwrap();
        let cam = Camera::from_prim(stage.prim(id), DMat4::IDENTITY, 1.0, &mut diags);
        let film = Vec2::new(0.3, 0.6);
        let pin = cam.ray(film, Vec2::splat(0.5));
        let mut spread = 0.0f32;
        for lens in [Vec2::new(0.1, 0.2), Vec2::new(0.9, 0.5), Vec2::new(0.4, 0.95)] {
            let r = cam.ray(film, lens);
            spread = spread.max((r.o - pin.o).length());
            // Every lens position reaches the same point on the plane of focus (z = -4).
            let t = -4.0 / r.d.z;
            let q = r.o + r.d * t;
            let tp = -4.0 / pin.d.z;
            assert!((q - (pin.o + pin.d * tp)).length() < 1e-4, "{q}");
        }
        assert!(spread > 0.5, "lens radius 2.5 units expected, spread {spread}");
    }
}
