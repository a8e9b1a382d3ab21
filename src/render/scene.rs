//! The render scene: triangles in a BVH, the material of each renderable prim, lights and
//! the camera, built once from a composed stage.

use crate::abi::MaterialCode;
use crate::diag::{Diagnostic, Diagnostics};
use crate::render::camera::Camera;
use crate::render::geometry::accel::Hit;
use crate::render::geometry::accel::{Accel, Blas};
use crate::render::geometry::displace::{DicingOptions, DisplacementStats};
use crate::render::geometry::motion::{self, MotionKeys, MotionStats, Shutter};
use crate::render::geometry::primvars::{ObjectSpace, PrimvarTable};
use crate::render::geometry::xform::{PrimXform, world_transforms};
use crate::render::geometry::{self, GeomPrim, InstanceDesc};
use crate::render::light::emitter::Emitters;
use crate::render::light::{Light, LightKind, lights_from_stage};
use crate::scene::{Prim, PrimId, Stage};
use glam::{DVec3, Vec3};

/// Everything the integrator needs about the scene, materials excepted (they are passed to
/// [`crate::render::render`] as `abi::MaterialCode`s, indexed by [`Scene::prim_material`]).
pub struct Scene {
    /// Triangles, shapes and instances in their BVHs.
    pub accel: Accel,
    /// Renderable prims, indexed by `Triangle::prim`.
    pub prims: Vec<GeomPrim>,
    /// For each entry of `prims`, its index in the caller's materials slice.
    pub prim_material: Vec<usize>,
    /// Visible lights.
    pub lights: Vec<Light>,
    /// Emissive surfaces sampled as lights (after `lights` in the light selection).
    pub emitters: Emitters,
    /// The camera (its aspect is set per render from the resolution).
    pub camera: Camera,
    /// The Camera prim it was read from (`None`: a camera framing the scene).
    pub camera_path: Option<String>,
    /// Per material index, the composed material's name for ID mattes (`CryptoMaterial`,
    /// written only when there is one name per material given to `render`). Empty unless
    /// the caller sets it.
    pub material_names: Vec<String>,
    /// World bounds of the geometry (a unit box when there is none).
    pub bounds: (Vec3, Vec3),
    /// Zero-area triangles that were skipped.
    pub degenerate_triangles: usize,
    /// Per renderable prim: whether its surface was diced and displaced (its material's
    /// geometric displacement is in the triangles; only bump layers bend its normal).
    pub displaced: Vec<bool>,
    /// What displacement cost, when anything was displaced.
    pub displacement: Option<DisplacementStats>,
    /// The primvars the materials read, per triangle and shape that has them (empty when the
    /// scene was built without its materials: every primvar then reads its fallback).
    pub primvars: PrimvarTable,
    /// Whether the stage had no light and [`default_lights`] light it.
    pub default_lights: bool,
    /// The camera's shutter (`shutter:open`, `shutter:close`); closed when there is no Camera prim.
    pub shutter: Shutter,
    /// The camera-to-world transform keyed over the shutter, when the camera moves while it
    /// is open (`None`: [`Scene::camera`] throughout).
    pub camera_motion: Option<MotionKeys>,
    /// What moves while the shutter is open.
    pub motion: MotionStats,
    /// What [`Scene::move_to`] needs to place the instances at another time code.
    placement: Placement,
}

/// How the build placed its instances, kept so that another time code moves them without
/// building any BLAS again ([`Scene::move_to`]).
struct Placement {
    /// Every instance as the build placed it (before the unplaceable were skipped).
    instances: Vec<InstanceDesc>,
    /// Per instance, the prim that places it (`PrimId(u32::MAX)`: none, it stays).
    placers: Vec<PrimId>,
    /// Bounds of each prototype in its own space.
    prototype_bounds: Vec<Option<(DVec3, DVec3)>>,
    /// Bounds of the world's own triangles and shapes.
    world_bounds: Option<(DVec3, DVec3)>,
    /// Per stage prim: its transform is baked into triangles ([`geometry::Geometry::baked`]).
    baked: Vec<bool>,
    /// A world-space renderable prim has time samples (its placement or its attributes):
    /// under an open shutter its keys or deformation change with the frame.
    world_animated: bool,
    /// Instances the build left out for a singular transform.
    singular: bool,
    /// World prims built as prototypes of their own because they deform.
    deforming: Vec<geometry::Deforming>,
    /// A world-space prim deforms: the world's BLAS changes with the time code.
    deforming_in_world: bool,
    /// The Camera prim looked through.
    camera: Option<PrimId>,
    /// The scene options it was built with.
    options: SceneOptions,
}

/// Why [`Scene::move_to`] could not move the instances: the scene must be built again.
#[derive(Clone, Debug, PartialEq)]
pub struct NeedsRebuild(pub String);

impl std::fmt::Display for NeedsRebuild {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Whether a stage without lights gets [`default_lights`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DefaultLights {
    /// Light a stage that has no light, as usdview does (the default).
    #[default]
    WhenUnlit,
    /// Never add lights (`--no-default-lights`): an unlit stage renders black, with a warning.
    Never,
}

/// Irradiance of the default camera light on a surface facing it: a white diffuse surface
/// facing the camera shows 0.7 from it (E / π), 0.9 with the dome.
pub const DEFAULT_CAMERA_LIGHT_IRRADIANCE: f32 = 0.7 * std::f32::consts::PI;

/// Radiance of the default dome: enough that no surface is pitch black, little enough that
/// the camera light models the shapes.
pub const DEFAULT_DOME_RADIANCE: f32 = 0.2;

/// The lights usdview gives a stage that has none: a light that travels with the camera (a
/// distant light from just above and left of the eye, so faces turned away from the view
/// darken and shapes read) and a dim uniform dome, so that nothing is pitch black. The dome
/// is hidden from camera rays: the background stays `RGB = 0, A = 0`, as an asset's
/// thumbnail shows it.
pub fn default_lights(camera: &Camera) -> Vec<Light> {
    let (forward, up, right) = (camera.forward(), camera.up(), camera.right());
    let towards_light = (-forward + up * 0.35 - right * 0.25).normalize_or(-forward);
    vec![
        Light {
            path: "(default camera light)".into(),
            kind: LightKind::Distant {
                dir: towards_light,
                cos_max: 1.0,
                radiance: Vec3::splat(DEFAULT_CAMERA_LIGHT_IRRADIANCE),
            },
            visible_to_camera: false,
        },
        Light {
            path: "(default dome)".into(),
            kind: LightKind::Dome {
                radiance: Vec3::splat(DEFAULT_DOME_RADIANCE),
                map: None,
                to_local: glam::Mat3::IDENTITY,
                to_world: glam::Mat3::IDENTITY,
            },
            visible_to_camera: false,
        },
    ]
}

/// Choices about how a stage is rendered that do not come from the stage alone.
#[derive(Clone, Debug, Default)]
pub struct SceneOptions {
    /// The Camera prim to look through (`None`: the first Camera prim, or a framing camera
    /// when there is none). Must name a Camera prim (see [`choose_view`]).
    pub camera: Option<String>,
    /// How geometry is built (subdivision level).
    pub geometry: geometry::GeometryOptions,
    /// How displaced surfaces are diced (rate, budget, the image size it is measured in).
    pub dicing: DicingOptions,
    /// Whether a stage without lights is lit by [`default_lights`].
    pub default_lights: DefaultLights,
}

/// The camera and resolution a render uses, from the command line and the stage's UsdRender
/// settings.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct View {
    /// The Camera prim to render through (`None`: the first Camera, or a framing camera).
    pub camera: Option<String>,
    /// A `RenderSettings` prim's `resolution`, when authored and valid.
    pub resolution: Option<(usize, usize)>,
}

/// Every Camera prim of `stage`, in depth-first order.
pub fn camera_paths(stage: &Stage) -> Vec<String> {
    stage.depth_first().filter(|(_, p)| p.type_name.as_deref() == Some("Camera")).map(|(_, p)| p.path.clone()).collect()
}

/// Chooses the camera and resolution: `requested` (`--camera`) if given, which must name a
/// Camera prim (an error listing the stage's cameras otherwise); else the first UsdRender
/// `RenderSettings` prim's `rel camera` when it targets a Camera; else none (the first
/// Camera). The resolution is that `RenderSettings` prim's `int2 resolution`, if any.
/// `None` when an error was reported.
pub fn choose_view(stage: &Stage, requested: Option<&str>, diags: &mut Diagnostics) -> Option<View> {
    let settings = stage.depth_first().find(|(_, p)| p.type_name.as_deref() == Some("RenderSettings")).map(|(_, p)| p);
    let is_camera =
        |path: &str| stage.find(path).is_some_and(|id| stage.prim(id).type_name.as_deref() == Some("Camera"));
    let listing = || {
        let cameras = camera_paths(stage);
        if cameras.is_empty() {
            "the stage has no Camera prim".to_string()
        } else {
            format!("cameras: {}", cameras.join(", "))
        }
    };
    let mut view = View::default();
    if let Some(path) = requested {
        if !is_camera(path) {
            let what = match stage.find(path).map(|id| stage.prim(id).type_name.clone()) {
                None => "does not exist".to_string(),
                Some(Some(ty)) => format!("is a {ty}, not a Camera"),
                Some(None) => "has no type, so is not a Camera".to_string(),
            };
            diags.push(Diagnostic::error(format!("--camera `{path}` {what}")).note(listing()));
            return None;
        }
        view.camera = Some(path.to_string());
    }
    if let Some(settings) = settings {
        if view.camera.is_none()
            && let Some(rel) = settings.relationship("camera")
            && let Some((target, span)) = rel.targets.first()
        {
            if is_camera(target) {
                view.camera = Some(target.clone());
            } else {
                diags.push(
                    Diagnostic::warning(format!(
                        "render settings `{}`: camera `{target}` is not a Camera prim; using the first camera",
                        settings.path
                    ))
                    .at(*span, "here")
                    .note(listing()),
                );
            }
        }
        if let Some(value) = settings.value("resolution") {
            match value.as_vec2() {
                Some([w, h]) if (1.0..=16384.0).contains(&w) && (1.0..=16384.0).contains(&h) => {
                    view.resolution = Some((w as usize, h as usize));
                }
                _ => diags.push(
                    Diagnostic::warning(format!(
                        "render settings `{}`: `resolution` must be two whole numbers in 1..=16384; ignored",
                        settings.path
                    ))
                    .at(settings.attribute("resolution").map_or(settings.span, |a| a.span), "here"),
                ),
            }
        }
    }
    Some(view)
}

impl Scene {
    /// Whether camera rays carry a time: the shutter is open and something in view of it
    /// (an instance, the camera) moves. A scene where nothing moves draws no time, so it
    /// renders exactly as with the shutter closed.
    #[inline]
    pub fn has_motion(&self) -> bool {
        self.camera_motion.is_some() || self.accel.has_motion()
    }

    /// The object space of renderable prim `prim` relative to the world where a ray at time
    /// `time` made `hit` on it: its own transform, placed by its instance's when it is instanced.
    pub fn object_space(&self, hit: &Hit, prim: u32, time: f32) -> ObjectSpace {
        let own = self.prims.get(prim as usize).map_or(ObjectSpace::IDENTITY, |p| p.object);
        match self.accel.instance_transforms(hit, time) {
            Some((to_object, to_world)) => own.placed(&to_world, &to_object),
            None => own,
        }
    }

    /// Whether renderable prim `prim`'s surface was diced and displaced.
    #[inline]
    pub fn prim_displaced(&self, prim: u32) -> bool {
        self.displaced.get(prim as usize).copied().unwrap_or(false)
    }

    /// Builds the render scene. `material_of_prim` maps a renderable prim's path to an index
    /// into the materials slice later given to `render`. Problems go to `diags`; `None` when
    /// any error was found (so a broken scene is never rendered as if it were fine).
    pub fn from_stage(
        stage: &Stage,
        material_of_prim: &dyn Fn(&str) -> Option<usize>,
        diags: &mut Diagnostics,
    ) -> Option<Scene> {
        Scene::from_stage_with(stage, material_of_prim, &SceneOptions::default(), diags)
    }

    /// [`Scene::from_stage`] with the camera chosen by `options`. Without the materials,
    /// nothing is diced (displacement bends shading normals only) and no primvar is stored
    /// (see [`Scene::build`]).
    pub fn from_stage_with(
        stage: &Stage,
        material_of_prim: &dyn Fn(&str) -> Option<usize>,
        options: &SceneOptions,
        diags: &mut Diagnostics,
    ) -> Option<Scene> {
        Scene::build(stage, material_of_prim, &[], options, diags)
    }

    /// Builds the render scene with the compiled `materials` (indexed as `material_of_prim`
    /// returns), so that surfaces whose material moves geometry are diced and displaced
    /// ([`crate::render::geometry::displace`]) and the primvars they read are stored ([`crate::render::geometry::primvars`]).
    pub fn build(
        stage: &Stage,
        material_of_prim: &dyn Fn(&str) -> Option<usize>,
        materials: &[&dyn MaterialCode],
        options: &SceneOptions,
        diags: &mut Diagnostics,
    ) -> Option<Scene> {
        let parts = Parts::gather(stage, material_of_prim, materials, options, diags)?;
        Some(Scene::assemble(parts, materials, options))
    }

    /// [`Scene::build`] from a stage it takes, and drops once the geometry is emitted: the
    /// stage's arrays are given back before the BVH build, where a million-triangle mesh
    /// peaks. For a render that follows no update (a one-shot `strata render`).
    pub fn build_releasing_stage(
        stage: Stage,
        material_of_prim: &dyn Fn(&str) -> Option<usize>,
        materials: &[&dyn MaterialCode],
        options: &SceneOptions,
        diags: &mut Diagnostics,
    ) -> Option<Scene> {
        let parts = Parts::gather(&stage, material_of_prim, materials, options, diags)?;
        drop(stage);
        Some(Scene::assemble(parts, materials, options))
    }

    /// The BVHs, emitters and placement of what [`Parts::gather`] read from the stage.
    fn assemble(parts: Parts, materials: &[&dyn MaterialCode], options: &SceneOptions) -> Scene {
        let Parts { geometry, motion, displaced, bounds, .. } = parts;
        // What a frame change needs to move instances; the build's vectors move in below.
        let prototype_bounds = geometry.prototypes.iter().map(|p| p.bounds).collect();
        let world_bounds = geometry.world_bounds();
        let accel = Accel::with_moving_instances(
            Blas::new(geometry.triangles, geometry.shapes),
            geometry.prototypes.into_iter().map(|p| Blas::deforming(p.triangles, p.shapes, p.deformation)).collect(),
            &geometry.instances,
            geometry.instance_prims,
            motion.instances,
        );
        let placement = Placement {
            instances: geometry.instances,
            placers: geometry.instance_placers,
            prototype_bounds,
            world_bounds,
            world_animated: parts.world_animated,
            baked: geometry.baked,
            singular: motion.singular,
            deforming: geometry.deforming,
            deforming_in_world: geometry.deforming_in_world,
            camera: parts.camera_prim,
            options: options.clone(),
        };
        let scene_radius = (bounds.1 - bounds.0).length() / 2.0;
        let light_power: f32 = parts.lights.iter().filter(|l| !l.is_infinite()).map(|l| l.power(scene_radius)).sum();
        let emitters = Emitters::build(&accel, geometry.prims.len(), &parts.prim_material, materials, light_power);
        Scene {
            displaced: displaced.prims,
            displacement: displaced.stats,
            default_lights: parts.default_lit,
            degenerate_triangles: geometry.degenerate,
            accel,
            prims: geometry.prims,
            primvars: geometry.primvars,
            prim_material: parts.prim_material,
            lights: parts.lights,
            emitters,
            camera: parts.camera,
            camera_path: parts.camera_path,
            material_names: Vec::new(),
            bounds,
            shutter: motion.shutter,
            camera_motion: motion.camera,
            motion: motion.stats,
            placement,
        }
    }

    /// Moves the scene to the stage's time when, since it was built, only transforms that
    /// place instances changed (`changed`: the prims whose xformOps did) and the shapes of
    /// deforming prims built as prototypes of their own (`reshaped`: the prims and attributes
    /// that changed; see [`geometry::Geometry::deforming`]): those prototypes' BLASes are
    /// built again (under an open shutter every deforming prototype's, keyed over the new
    /// frame's shutter), instance transforms (and their keys under an open shutter), the top-level
    /// BVH, the camera, the lights and the emitters' light power are computed again, exactly
    /// as a build at this time computes them, and every other BLAS is kept. Returns the
    /// number of BLASes built. The scene is untouched and the reason returned when that would
    /// not be what a build makes (a transform baked into triangles changed, displaced
    /// geometry is diced for a camera, an instance became singular, …).
    pub fn move_to(
        &mut self,
        stage: &Stage,
        changed: &[PrimId],
        reshaped: &[(PrimId, String)],
        materials: &[&dyn MaterialCode],
        diags: &mut Diagnostics,
    ) -> Result<usize, NeedsRebuild> {
        let why = |s: String| Err(NeedsRebuild(s));
        let p = &self.placement;
        if let Some(&id) = changed.iter().find(|id| p.baked.get(id.0 as usize).copied().unwrap_or(true)) {
            return why(format!("`{}` moved geometry built in world space", stage.prim(id).path));
        }
        let skinned = p.deforming.iter().any(|d| d.skinned);
        let reshapes_prototype = |id: PrimId| {
            p.deforming.iter().any(|d| d.id == id)
                || (skinned && stage.prim(id).type_name.as_deref() == Some("SkelAnimation"))
        };
        if let Some((id, name)) = reshaped.iter().find(|(id, _)| !reshapes_prototype(*id)) {
            return why(format!("`{}.{name}` changed", stage.prim(*id).path));
        }
        if p.deforming_in_world && (self.shutter.is_open() || !(changed.is_empty() && reshaped.is_empty())) {
            return why("a prim built in world space deforms (its material displaces or emits)".into());
        }
        if self.shutter.is_open() && p.world_animated {
            return why("a world-space prim is animated under an open shutter".into());
        }
        if self.displacement.is_some() && !changed.is_empty() {
            return why("displaced geometry is diced for the camera".into());
        }
        if p.singular {
            return why("an instance had a singular transform".into());
        }
        if changed.is_empty() && reshaped.is_empty() && !self.shutter.is_open() {
            return Ok(0);
        }
        let xforms = world_transforms(stage, diags);
        // The deforming prototypes whose shape may have changed: a skinned one's follows its
        // placement, its skeleton's and its animation, which any change may be. Under an open
        // shutter every one: its deformation keys are the frame's.
        let anything = !changed.is_empty() || !reshaped.is_empty();
        let open = self.shutter.is_open();
        let reshapes =
            |d: &&geometry::Deforming| open || (d.skinned && anything) || reshaped.iter().any(|(id, _)| *id == d.id);
        if p.deforming.iter().any(|d| reshapes(&d)) && !self.primvars.names.is_empty() {
            return why("a deforming prim's primvars are stored in one table with every other prim's".into());
        }
        let mut rebuilt = Vec::new();
        for d in p.deforming.iter().filter(reshapes) {
            let proto = geometry::deforming_prototype(stage, &xforms, d.id, p.options.geometry, diags);
            let bounds = proto.as_ref().and_then(|proto| proto.bounds);
            if bounds.is_none() || p.prototype_bounds[d.prototype as usize].is_none() {
                return why(format!("`{}` became or was empty or hidden", stage.prim(d.id).path));
            }
            rebuilt.push((d.prototype, d.id, proto.expect("bounds are some")));
        }
        let own = rebuilt.iter_mut().map(|(_, id, proto)| (*id, proto));
        let names = &self.primvars.names;
        self.motion.deforming_prims =
            motion::key_deforming_prototypes(own, stage, self.shutter, p.options.geometry, names, diags);
        let mut prototype_bounds = p.prototype_bounds.clone();
        for (index, _, proto) in &rebuilt {
            prototype_bounds[*index as usize] = proto.bounds;
        }
        let Some(instances) = instances_at(stage, &xforms, p, &prototype_bounds) else {
            return why("a point instancer's points or an instance's transform cannot be placed".into());
        };
        let bounds = geometry::placed_bounds(p.world_bounds, &prototype_bounds, &instances)
            .unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
        crate::render::support::report_unsupported(stage, &xforms, diags);
        let chosen = p.camera.map(|id| (id, stage.prim(id)));
        let (lights, camera, default_lit) = lights_and_camera(stage, &xforms, chosen, bounds, &p.options, diags);
        let motion = motion::instance_motion(stage, &p.placers, &instances, self.shutter);
        self.camera_motion = chosen.and_then(|(id, _)| motion::camera_motion(stage, id, self.shutter));
        self.motion.moving_instances = motion.len();
        let blas_builds = rebuilt.len();
        for (index, _, proto) in rebuilt {
            self.accel.replace_prototype(index, Blas::deforming(proto.triangles, proto.shapes, proto.deformation));
        }
        self.accel.move_instances(&instances, motion);
        let scene_radius = (bounds.1 - bounds.0).length() / 2.0;
        let light_power: f32 = lights.iter().filter(|l| !l.is_infinite()).map(|l| l.power(scene_radius)).sum();
        self.emitters = Emitters::build(&self.accel, self.prims.len(), &self.prim_material, materials, light_power);
        (self.lights, self.camera, self.default_lights, self.bounds) = (lights, camera, default_lit, bounds);
        self.placement.instances = instances;
        self.placement.prototype_bounds = prototype_bounds;
        Ok(blas_builds)
    }

    /// Everything [`Scene::from_stage`] reports — geometry, materials of prims, lights,
    /// camera — without building the BVHs or the emitters, which report nothing (`strata
    /// check`). Returns the number of renderable prims, `None` when an error was found.
    pub fn validate(
        stage: &Stage,
        material_of_prim: &dyn Fn(&str) -> Option<usize>,
        diags: &mut Diagnostics,
    ) -> Option<usize> {
        Parts::gather(stage, material_of_prim, &[], &SceneOptions::default(), diags).map(|p| p.geometry.prims.len())
    }
}

/// What a render scene is built from, before its BVHs: gathered and checked by
/// [`Parts::gather`].
struct Parts {
    geometry: geometry::Geometry,
    prim_material: Vec<usize>,
    lights: Vec<Light>,
    camera: Camera,
    camera_path: Option<String>,
    /// The stage's prim at `camera_path`.
    camera_prim: Option<PrimId>,
    default_lit: bool,
    displaced: crate::render::geometry::displace::Displaced,
    bounds: (Vec3, Vec3),
    motion: Motion,
    /// Whether a prim built in world space has time-varying values.
    world_animated: bool,
}

/// What moves while the shutter is open (see [`crate::render::geometry::motion`]).
#[derive(Default)]
struct Motion {
    shutter: Shutter,
    /// Keys of moving instances, by index in the geometry's instances.
    instances: Vec<(u32, MotionKeys)>,
    camera: Option<MotionKeys>,
    stats: MotionStats,
    /// The build left out instances with a singular transform.
    singular: bool,
}

/// The lights (the default ones when the stage has none and `options` allow them) and the
/// camera (`chosen`, or one framing `bounds`) at the stage's time; and whether the default
/// lights light it.
fn lights_and_camera(
    stage: &Stage,
    xforms: &[PrimXform],
    chosen: Option<(PrimId, &Prim)>,
    bounds: (Vec3, Vec3),
    options: &SceneOptions,
    diags: &mut Diagnostics,
) -> (Vec<Light>, Camera, bool) {
    let mut lights = lights_from_stage(stage, xforms, diags);
    let camera = chosen
        .map(|(id, prim)| Camera::from_prim(prim, xforms[id.0 as usize].world, 1.0, diags))
        .unwrap_or_else(|| Camera::framing(bounds.0, bounds.1, 1.0, stage.up_axis()));
    let default_lit = lights.is_empty() && options.default_lights == DefaultLights::WhenUnlit;
    if default_lit {
        lights = default_lights(&camera);
        diags.push(Diagnostic::info(
            "the stage has no lights: it is lit by a light that travels with the camera and a dim dome, \
             as usdview shows it (--no-default-lights turns them off)",
        ));
    } else if lights.is_empty() {
        diags.push(Diagnostic::warning("the scene has no lights: the image will be black"));
    }
    (lights, camera, default_lit)
}

/// Whether prim `id` has an attribute with time samples, or its placement does.
fn time_varying(stage: &Stage, id: PrimId) -> bool {
    stage.prim(id).attributes.iter().any(|a| !a.time_samples.is_empty())
        || !crate::render::geometry::xform::transform_sample_times(stage, id).is_empty()
}

/// The instances of `placement` at the stage's time: each placed by its prim's world
/// transform, or by its point instancer's point, as a build computes them; `None` when one
/// cannot be placed as before (a point instancer's points changed in number or became
/// invalid, a transform became singular or left the extent).
fn instances_at(
    stage: &Stage,
    xforms: &[PrimXform],
    placement: &Placement,
    prototype_bounds: &[Option<(DVec3, DVec3)>],
) -> Option<Vec<InstanceDesc>> {
    let mut out = placement.instances.clone();
    let mut i = 0;
    while i < out.len() {
        let placer = placement.placers[i];
        // The instances of one placer are consecutive (a point instancer's in point order).
        let run = placement.placers[i..].iter().take_while(|&&p| p == placer).count();
        if placer.0 as usize >= stage.len() {
            i += run;
            continue;
        }
        if stage.prim(placer).type_name.as_deref() == Some("PointInstancer") {
            let points = geometry::point_instance_transforms(stage, xforms, placer)?;
            if points.len() != run {
                return None;
            }
            for (desc, m) in out[i..i + run].iter_mut().zip(points) {
                desc.to_world = m;
            }
        } else {
            for desc in &mut out[i..i + run] {
                desc.to_world = xforms[placer.0 as usize].world;
            }
        }
        i += run;
    }
    let placeable = out.iter().all(|desc| {
        let det = glam::DMat3::from_mat4(desc.to_world).determinant();
        let Some((lo, hi)) = prototype_bounds[desc.prototype as usize] else { return true };
        let (wlo, whi) = crate::render::geometry::shapes::transformed_box(&desc.to_world, lo, hi);
        det != 0.0
            && det.is_finite()
            && [wlo, whi].iter().all(|w| w.is_finite() && w.abs().max_element() <= geometry::MAX_EXTENT)
    });
    placeable.then_some(out)
}

impl Parts {
    /// The geometry (diced and displaced where `materials` move it), the prims' materials,
    /// the lights and the camera of `stage`; `None` when any error was reported.
    fn gather(
        stage: &Stage,
        material_of_prim: &dyn Fn(&str) -> Option<usize>,
        materials: &[&dyn MaterialCode],
        options: &SceneOptions,
        diags: &mut Diagnostics,
    ) -> Option<Parts> {
        let errors = diags.error_count();
        let xforms = world_transforms(stage, diags);
        let mut read: Vec<String> =
            materials.iter().flat_map(|m| m.info().primvars.iter().map(|p| p.name.clone())).collect();
        read.sort();
        read.dedup();
        // Dicing and light sampling work on world triangles: prims whose material displaces
        // or emits keep world space even when they move.
        let stays_in_world = |prim: &Prim| {
            material_of_prim(&prim.path)
                .and_then(|m| materials.get(m))
                .is_some_and(|code| code.info().layers.iter().any(|l| l.displacement_bound.is_some() || l.has_emission))
        };
        let chosen = match &options.camera {
            Some(path) => stage.find(path).map(|id| (id, stage.prim(id))),
            None => stage.depth_first().find(|(_, p)| p.type_name.as_deref() == Some("Camera")),
        };
        let mut geometry = geometry::build_for_render(stage, &xforms, options.geometry, &read, &stays_in_world, diags);
        let mut prim_material = Vec::with_capacity(geometry.prims.len());
        for prim in &geometry.prims {
            match material_of_prim(&prim.path) {
                Some(m) => prim_material.push(m),
                None => {
                    diags.push(
                        Diagnostic::error(format!("renderable prim `{}` has no compiled material", prim.path))
                            .at(prim.span, "this prim"),
                    );
                    prim_material.push(0);
                }
            }
        }
        crate::render::support::report_unsupported(stage, &xforms, diags);
        let bounds = geometry.bounds().unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
        let camera_path = chosen.map(|(_, prim)| prim.path.clone());
        let (lights, camera, default_lit) = lights_and_camera(stage, &xforms, chosen, bounds, options, diags);
        if diags.error_count() > errors {
            return None;
        }
        let displaced = crate::render::geometry::displace::displace(
            &mut geometry,
            &prim_material,
            materials,
            &camera,
            &options.dicing,
            diags,
        );
        if diags.error_count() > errors {
            return None;
        }
        // Displaced surfaces may reach past the undisplaced bounds (the camera stays framed on those).
        let bounds = geometry.bounds().unwrap_or(bounds);
        let shutter = chosen.map_or(Shutter::default(), |(_, prim)| Shutter::of_camera(prim, diags));
        let singular = geometry.singular_instances > 0;
        let (instances, stats) = motion::apply(&mut geometry, stage, shutter, options.geometry, diags);
        motion::report_moving_lights(stage, lights.iter().map(|l| l.path.as_str()), shutter, diags);
        let camera_motion = chosen.and_then(|(id, _)| motion::camera_motion(stage, id, shutter));
        let motion = Motion { shutter, instances, camera: camera_motion, stats, singular };
        let world_animated = geometry.prims.iter().any(|p| {
            stage.find(&p.path).is_some_and(|id| {
                geometry.baked.get(id.0 as usize).copied().unwrap_or(false) && time_varying(stage, id)
            })
        });
        let camera_prim = camera_path.as_deref().and_then(|p| stage.find(p));
        Some(Parts {
            geometry,
            prim_material,
            lights,
            camera,
            camera_path,
            camera_prim,
            default_lit,
            displaced,
            bounds,
            motion,
            world_animated,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::geometry::xform::tests::stage;
    use glam::Vec2;

    #[test]
    fn camera_ray_through_centre_hits_prim_ahead() {
        let (stage, mut diags) = stage(
            r#"#usda 1.0
def Camera "Cam" {
    double3 xformOp:translate = (0, 1, 10)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Sphere "Left" { double3 xformOp:translate = (-4, 1, 0)  uniform token[] xformOpOrder = ["xformOp:translate"] }
def Sphere "Ahead" { double3 xformOp:translate = (0, 1, 0)  uniform token[] xformOpOrder = ["xformOp:translate"] }
def DomeLight "Sky" {}"#,
        );
        let scene = Scene::from_stage(&stage, &|_| Some(0), &mut diags).expect("scene");
        let r = scene.camera.ray(Vec2::splat(0.5), Vec2::ZERO);
        let hit = scene.accel.intersect(r.o, r.d, r.tmin, r.tmax).expect("hit");
        assert_eq!(scene.prims[scene.accel.prim_of(&hit) as usize].path, "/Ahead");
        assert!((hit.t - 9.0).abs() < 1e-2, "{}", hit.t);
    }

    #[test]
    fn render_settings_choose_camera_and_resolution_unless_overridden() {
        let text = r#"#usda 1.0
def Camera "A" {}
def Camera "B" {}
def Sphere "S" {}
def RenderSettings "Settings" {
    rel camera = </B>
    uniform int2 resolution = (320, 200)
}"#;
        let (two, mut diags) = stage(text);
        let view = choose_view(&two, None, &mut diags).expect("view");
        assert_eq!(view, View { camera: Some("/B".into()), resolution: Some((320, 200)) });
        let view = choose_view(&two, Some("/A"), &mut diags).expect("view");
        assert_eq!(view.camera.as_deref(), Some("/A"));
        assert!(!diags.has_errors());
        let scene = Scene::from_stage_with(
            &two,
            &|_| Some(0),
            &SceneOptions { camera: view.camera, ..Default::default() },
            &mut diags,
        )
        .unwrap();
        assert_eq!(scene.camera_path.as_deref(), Some("/A"));
        // Not a camera: an error naming what it is and listing the cameras.
        assert!(choose_view(&two, Some("/S"), &mut diags).is_none());
        let error = diags.items().last().expect("an error");
        assert!(error.message.contains("is a Sphere, not a Camera"), "{}", error.message);
        assert_eq!(error.notes, ["cameras: /A, /B"]);
        // Settings pointing at a non-camera, with a bad resolution: warnings, first camera, default size.
        let (bad, mut diags) = stage(&text_with(
            r#"rel camera = </S>
    uniform int2 resolution = (0, 200)"#,
        ));
        let view = choose_view(&bad, None, &mut diags).expect("view");
        assert_eq!(view, View::default());
        assert!(!diags.has_errors());
        assert_eq!(diags.items().len(), 2, "{:?}", diags.items());
    }

    fn text_with(settings: &str) -> String {
        format!(
            "#usda 1.0\ndef Camera \"A\" {{}}\ndef Sphere \"S\" {{}}\ndef RenderSettings \"R\" {{\n    {settings}\n}}"
        )
    }

    #[test]
    fn default_camera_frames_the_scene_and_missing_material_is_an_error() {
        let (stage, mut diags) = stage("#usda 1.0\ndef Cube \"C\" { double size = 3 }\ndef DomeLight \"D\" {}");
        let scene = Scene::from_stage(&stage, &|_| Some(0), &mut diags).expect("scene");
        let r = scene.camera.ray(Vec2::splat(0.5), Vec2::ZERO);
        assert!(scene.accel.intersect(r.o, r.d, r.tmin, r.tmax).is_some());
        // The corners of the bounds are inside the view.
        let corner = scene.camera.ray(Vec2::new(0.02, 0.02), Vec2::ZERO);
        assert!(scene.accel.intersect(corner.o, corner.d, 0.0, f32::INFINITY).is_none());
        let mut diags = Diagnostics::new();
        assert!(Scene::from_stage(&stage, &|_| None, &mut diags).is_none());
        assert!(diags.has_errors());
    }
}
