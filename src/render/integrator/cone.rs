//! The ray cone a path carries: how bounces widen it, and the footprint it leaves in a
//! surface's texture space (what filtered texture lookups read).

use super::SurfacePoint;
use glam::Vec3;

/// The most a path's bounces widen its ray cone (radians): about a diffuse bounce's.
pub(super) const MAX_BOUNCE_SPREAD: f32 = 1.0;

/// The spread (radians) a bounce adds to the ray cone, from the pdf of the direction it
/// sampled: the cone whose solid angle is that sample's share, `1/pdf` (`π α²` for a cone of
/// half-angle α). Specular bounces (no pdf) keep the cone; a diffuse bounce opens it to about
/// a radian, a smooth glossy one barely.
pub(super) fn bounce_widening(pdf: Option<f32>) -> f32 {
    match pdf {
        Some(pdf) if pdf > 0.0 => (2.0 * (std::f32::consts::FRAC_1_PI / pdf).sqrt()).min(MAX_BOUNCE_SPREAD),
        _ => 0.0,
    }
}

/// The largest anisotropy [`st_footprint`] gives a footprint (grazing rays past it blur).
const MAX_FOOTPRINT_ELONGATION: f32 = 64.0;

/// The ray cone's footprint at `sp` in texture (st) space (`abi::Globals::st_footprint`): the
/// cone of diameter `width` arriving along `d` cuts the surface in an ellipse whose minor axis
/// (across the ray) is `width` long and whose major axis (along the ray's projection) is
/// `width / cos θ`; both are mapped to (ds, dt) through the least-squares inverse of the st
/// Jacobian `(dPdu, dPdv)`. Zeros where the Jacobian is degenerate (the lookup is unfiltered).
pub(super) fn st_footprint(sp: &SurfacePoint, d: Vec3, width: f32) -> [f32; 4] {
    let n = sp.ng;
    let across = d.cross(n).normalize_or_zero();
    let along = n.cross(across);
    let cos = d.dot(n).abs().max(1.0 / MAX_FOOTPRINT_ELONGATION);
    let (a, b, c) = (sp.dpdu.length_squared(), sp.dpdu.dot(sp.dpdv), sp.dpdv.length_squared());
    let det = a * c - b * b;
    if !(width.is_finite() && det > 1e-20 * a * c && across != Vec3::ZERO) {
        return [0.0; 4];
    }
    let to_st = |v: Vec3| {
        let (pu, pv) = (v.dot(sp.dpdu), v.dot(sp.dpdv));
        ((c * pu - b * pv) / det, (a * pv - b * pu) / det)
    };
    let (ds_x, dt_x) = to_st(across * width);
    let (ds_y, dt_y) = to_st(along * (width / cos));
    let footprint = [ds_x, dt_x, ds_y, dt_y];
    if footprint.iter().all(|v| v.is_finite()) { footprint } else { [0.0; 4] }
}
