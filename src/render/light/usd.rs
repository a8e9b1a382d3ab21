//! Lights read from a composed stage: UsdLux prims and their attributes (intensity, exposure,
//! colour temperature as a blackbody, normalisation, shaping) turned into [`Light`]s, diagnosed.

use super::*;

/// Reads every visible light of `stage`.
pub fn lights_from_stage(stage: &Stage, xforms: &[PrimXform], diags: &mut Diagnostics) -> Vec<Light> {
    let mut lights = Vec::new();
    for (id, prim) in stage.depth_first() {
        let Some(ty) = prim.type_name.as_deref() else { continue };
        if !LIGHT_TYPES.contains(&ty) || xforms[id.0 as usize].hidden {
            continue;
        }
        if let Some(kind) = light_kind(prim, ty, xforms[id.0 as usize], diags) {
            let visible_to_camera = prim.value(VISIBLE_TO_CAMERA).and_then(Value::as_bool).unwrap_or(true);
            lights.push(Light { path: prim.path.clone(), kind, visible_to_camera });
        }
    }
    lights
}

fn light_kind(prim: &Prim, ty: &str, xf: PrimXform, diags: &mut Diagnostics) -> Option<LightKind> {
    let num = |name: &str, default: f64| prim.value(name).and_then(Value::as_f64).unwrap_or(default);
    let default_intensity = if ty == "DistantLight" { 50000.0 } else { 1.0 };
    let intensity = num("inputs:intensity", default_intensity) * num("inputs:exposure", 0.0).exp2();
    let mut color = prim.value("inputs:color").and_then(Value::as_vec3).map_or(DVec3::ONE, DVec3::from);
    if prim.value("inputs:enableColorTemperature").and_then(Value::as_bool).unwrap_or(false) {
        color *= color_temperature(prim, diags)?;
    }
    let normalize = prim.value("inputs:normalize").and_then(Value::as_bool).unwrap_or(false);
    let mut emission = (color * intensity).as_vec3();
    if !emission.is_finite() || emission.min_element() < 0.0 {
        let attr = prim.attribute("inputs:intensity").or_else(|| prim.attribute("inputs:color"));
        diags.push(
            Diagnostic::error(format!("light `{}` has a negative or non-finite emission", prim.path))
                .at(attr.map_or(prim.span, value_span), "here"),
        );
        return None;
    }
    let m = xf.world;
    let point = |v: DVec3| m.transform_point3(v).as_vec3();
    let vector = |v: DVec3| m.transform_vector3(v).as_vec3();
    let normal_z = || (DMat3::from_mat4(m).inverse().transpose() * -DVec3::Z).as_vec3().normalize_or_zero();
    let positive = |name: &str, default: f64, diags: &mut Diagnostics| {
        let v = num(name, default);
        if v.is_finite() && v >= 0.0 {
            Some(v)
        } else {
            diags.push(
                Diagnostic::error(format!("light `{}`: `{name}` must be a non-negative number", prim.path))
                    .at(prim.attribute(name).map_or(prim.span, value_span), "here"),
            );
            None
        }
    };
    Some(match ty {
        "DomeLight" => {
            let rot = DMat3::from_mat4(m);
            let to_world = Mat3::from_cols(
                rot.x_axis.as_vec3().normalize_or(Vec3::X),
                rot.y_axis.as_vec3().normalize_or(Vec3::Y),
                rot.z_axis.as_vec3().normalize_or(Vec3::Z),
            );
            let to_local = to_world.inverse();
            let map = match prim.attribute("inputs:texture:file").and_then(|a| Some((a, a.get()?.as_asset()?))) {
                Some((attr, asset)) if !asset.authored.is_empty() => match EnvMap::load(&asset.resolved) {
                    Ok(map) => Some(Arc::new(map)),
                    Err(e) => {
                        // USD composes around an unreadable asset: the dome lights with its
                        // colour alone, as usdview shows it.
                        diags.push(
                            Diagnostic::warning(format!(
                                "cannot read dome texture `{}`: {e}",
                                asset.resolved.display()
                            ))
                            .at(value_span(attr), "here")
                            .note("the dome lights the scene with its colour and intensity alone")
                            .kind("unreadable dome texture"),
                        );
                        None
                    }
                },
                _ => None,
            };
            LightKind::Dome { radiance: emission, map, to_local, to_world }
        }
        "RectLight" => {
            let w = positive("inputs:width", 1.0, diags)?;
            let h = positive("inputs:height", 1.0, diags)?;
            let ex = vector(DVec3::X * (w / 2.0));
            let ey = vector(DVec3::Y * (h / 2.0));
            if normalize {
                emission /= (4.0 * ex.cross(ey).length()).max(1e-12);
            }
            LightKind::rect(point(DVec3::ZERO), ex, ey, normal_z(), emission)
        }
        "DiskLight" => {
            let r = positive("inputs:radius", 0.5, diags)?;
            let ex = vector(DVec3::X * r);
            let ey = vector(DVec3::Y * r);
            if normalize {
                emission /= (PI * ex.cross(ey).length()).max(1e-12);
            }
            LightKind::disk(point(DVec3::ZERO), ex, ey, normal_z(), emission)
        }
        "SphereLight" => {
            let r = positive("inputs:radius", 0.5, diags)?;
            // Uniform scale assumed for the radius (the mean axis scale).
            let s = DMat3::from_mat4(m);
            let scale = ((s.x_axis.length() + s.y_axis.length() + s.z_axis.length()) / 3.0) as f32;
            let radius = r as f32 * scale;
            let area = 4.0 * PI * radius * radius;
            let treat_as_point = prim.value("treatAsPoint").and_then(Value::as_bool).unwrap_or(false);
            // A sphere too small for f32 has no area to sample: it is the point it tends to.
            if treat_as_point || area < f32::MIN_POSITIVE {
                let intensity = point_intensity(emission, radius, normalize);
                if intensity == Vec3::ZERO && emission != Vec3::ZERO {
                    let attr = prim.attribute("inputs:radius").or_else(|| prim.attribute("treatAsPoint"));
                    diags.push(
                        Diagnostic::warning(format!(
                            "light `{}` is a point of radius 0 without `inputs:normalize`: it emits nothing",
                            prim.path
                        ))
                        .at(attr.map_or(prim.span, value_span), "here")
                        .note(
                            "UsdLux gives a sphere light radiance `intensity`, so its power is proportional to \
                             its area; set `inputs:normalize = 1` for a point whose power is independent of its \
                             size, or give it a radius",
                        )
                        .kind("unlit point light"),
                    );
                }
                LightKind::Point { position: point(DVec3::ZERO), intensity }
            } else {
                if normalize {
                    emission /= area;
                }
                LightKind::Sphere { centre: point(DVec3::ZERO), radius, radiance: emission }
            }
        }
        "CylinderLight" => {
            let length = positive("inputs:length", 1.0, diags)?;
            let r = positive("inputs:radius", 0.5, diags)?;
            let s = DMat3::from_mat4(m);
            // The radius scales with the mean of the two cross-section axes' scales.
            let radius = (r * (s.y_axis.length() + s.z_axis.length()) / 2.0) as f32;
            let half_length = (length / 2.0 * s.x_axis.length()) as f32;
            let area = cylinder_area(half_length, radius);
            if normalize && area > 0.0 {
                emission /= area;
            }
            let axis = vector(DVec3::X).normalize_or(Vec3::X);
            LightKind::Cylinder { centre: point(DVec3::ZERO), axis, half_length, radius, radiance: emission }
        }
        "DistantLight" => {
            let angle = positive("inputs:angle", 0.53, diags)?.min(180.0);
            let half = (angle.to_radians() / 2.0) as f32;
            let dir = vector(DVec3::Z).normalize_or(Vec3::Z);
            let cos_max = half.cos();
            let radiance = if half <= 1e-6 || cos_max >= 1.0 {
                // A delta light: the irradiance is the intensity either way.
                return Some(LightKind::Distant { dir, cos_max: 1.0, radiance: emission });
            } else if normalize {
                // Irradiance E at normal incidence: E = L ∫cone cosθ dω = L π sin²(half).
                emission / (PI * half.sin().powi(2))
            } else {
                emission
            };
            LightKind::Distant { dir, cos_max, radiance }
        }
        _ => return None,
    })
}

/// The colour of `inputs:colorTemperature` (kelvin, UsdLux default 6500) as a linear Rec.709
/// multiplier of luminance 1, for a light with `inputs:enableColorTemperature`.
fn color_temperature(prim: &Prim, diags: &mut Diagnostics) -> Option<DVec3> {
    let name = "inputs:colorTemperature";
    let kelvin = prim.value(name).and_then(Value::as_f64).unwrap_or(6500.0);
    if !kelvin.is_finite() || kelvin <= 0.0 {
        diags.push(
            Diagnostic::error(format!("light `{}`: `{name}` must be a positive temperature in kelvin", prim.path))
                .at(prim.attribute(name).map_or(prim.span, value_span), "here"),
        );
        return None;
    }
    let clamped = kelvin.clamp(MIN_COLOR_TEMPERATURE, MAX_COLOR_TEMPERATURE);
    if clamped != kelvin {
        diags.push(
            Diagnostic::warning(format!(
                "light `{}`: colour temperature {kelvin} K is outside {MIN_COLOR_TEMPERATURE}..{MAX_COLOR_TEMPERATURE} K; \
                 {clamped} K is used",
                prim.path
            ))
            .at(prim.attribute(name).map_or(prim.span, value_span), "here"),
        );
    }
    Some(blackbody_rgb(clamped))
}

/// The colour temperatures [`blackbody_rgb`] is used for; outside them a light's temperature
/// is clamped (with a warning). Below 1000 K a blackbody is a dim deep red whose visible
/// spectrum is all in the tail of the colour matching functions.
pub const MIN_COLOR_TEMPERATURE: f64 = 1000.0;
/// See [`MIN_COLOR_TEMPERATURE`].
pub const MAX_COLOR_TEMPERATURE: f64 = 40000.0;

/// The CIE 1931 colour matching functions, in the multi-lobe Gaussian fit of Wyman, Sloan and
/// Shirley (JCGT 2013), at wavelength `nm`.
fn cie_xyz(nm: f64) -> DVec3 {
    let g = |mu: f64, s1: f64, s2: f64| {
        let t = (nm - mu) / if nm < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    };
    DVec3::new(
        1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7) - 0.065 * g(501.1, 20.4, 26.2),
        0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1),
        1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8),
    )
}

/// CIE XYZ of a blackbody at `kelvin` (Planck's law integrated against [`cie_xyz`], 360–830 nm
/// in 1 nm steps), in arbitrary units.
pub(super) fn blackbody_xyz(kelvin: f64) -> DVec3 {
    // Second radiation constant c2 = hc/k, in nm·K.
    const C2: f64 = 1.438_776_877e7;
    (360..=830)
        .map(|nm| {
            let l = nm as f64;
            let planck = l.powi(-5) / ((C2 / (l * kelvin)).exp() - 1.0);
            cie_xyz(l) * planck
        })
        .sum()
}

/// A blackbody's colour in linear Rec.709 / sRGB primaries, normalised to luminance 1 (what
/// UsdLux's `colorTemperature` multiplies `color` by). Out-of-gamut negative components (deep
/// reds at low temperatures) are clipped before normalising.
pub fn blackbody_rgb(kelvin: f64) -> DVec3 {
    let xyz = blackbody_xyz(kelvin);
    let rgb = DMat3::from_cols(
        DVec3::new(3.2404542, -0.9692660, 0.0556434),
        DVec3::new(-1.5371385, 1.8760108, -0.2040259),
        DVec3::new(-0.4985314, 0.0415560, 1.0572252),
    ) * xyz;
    let rgb = rgb.max(DVec3::ZERO);
    let y = DVec3::new(0.2126, 0.7152, 0.0722).dot(rgb);
    if y > 0.0 && y.is_finite() { rgb / y } else { DVec3::ONE }
}
