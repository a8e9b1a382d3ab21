//! Lights at infinity as an escaping ray meets them: the general walk over the scene's lights,
//! and the shortcut for a constant dome that is the only one.

use super::Scatter;
use crate::render::light::{Light, LightKind, LightSelection};
use glam::Vec3;

/// A constant dome that is the scene's only light at infinity: what an escaping ray reads,
/// found once per render (the general walk over the lights, the dome's `escape` and its
/// selection probability cost about 100 instructions a ray that leaves the scene).
#[derive(Clone, Copy)]
pub struct ConstantDome<'a> {
    light: &'a Light,
    radiance: Vec3,
    /// The dome's probability in the light selection.
    select: f32,
}

impl<'a> ConstantDome<'a> {
    /// The constant dome among `lights`, if it is their only light at infinity.
    pub fn of(lights: &'a [Light], selection: &LightSelection) -> Option<ConstantDome<'a>> {
        let mut infinite = lights.iter().enumerate().filter(|(_, l)| l.is_infinite());
        let (i, light) = infinite.next()?;
        match light.kind {
            LightKind::Dome { radiance, map: None, .. } if infinite.next().is_none() => {
                Some(ConstantDome { light, radiance, select: selection.pmf(i) })
            }
            _ => None,
        }
    }

    /// [`escape_walk`] over lights whose only one at infinity is this dome: the same sum, bit
    /// for bit.
    #[inline]
    pub(super) fn escape(&self, d: Vec3, from: &Scatter, camera_ray: bool) -> Vec3 {
        let mut sum = Vec3::ZERO;
        if (self.light.visible_to_camera || !camera_ray) && self.radiance != Vec3::ZERO {
            sum += self.radiance * from.mis(self.light, d, self.select);
        }
        sum
    }
}

/// Emission of the infinite lights among `lights` (chosen by `selection`) reached in
/// direction `d`, MIS-weighted against `from`: [`super::Context::escape_emission`] without a
/// [`ConstantDome`]. Inlined into the path loop, where it was written before it moved here:
/// the default scene (a dome and a sun) takes this walk at every escaping ray.
#[inline]
pub(super) fn escape_walk(
    lights: &[Light],
    selection: &LightSelection,
    d: Vec3,
    from: &Scatter,
    camera_ray: bool,
) -> Vec3 {
    let mut sum = Vec3::ZERO;
    let infinite = lights.iter().enumerate().filter(|(_, l)| l.is_infinite() && (l.visible_to_camera || !camera_ray));
    for (i, light) in infinite {
        let le = light.escape(d);
        if le != Vec3::ZERO {
            sum += le * from.mis(light, d, selection.pmf(i));
        }
    }
    sum
}
