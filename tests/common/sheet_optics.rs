//! The optics of a thin dielectric sheet, computed independently of strata's renderer for the
//! thin-walled tests (`render::material::thin_tests`, `tests/thin_walled.rs`): Fresnel's
//! equations and the sheet's ladder of inter-reflections summed term by term, in f64.

/// Unpolarised Fresnel reflectance of a dielectric of index `eta` from air at `cos` θ, from
/// the s and p amplitudes (Born and Wolf).
pub fn fresnel(cos: f64, eta: f64) -> f64 {
    let sin_t = (1.0 - cos * cos).sqrt() / eta;
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = (cos - eta * cos_t) / (cos + eta * cos_t);
    let rp = (eta * cos - cos_t) / (eta * cos + cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// A sheet's reflectance and transmittance when each face reflects `r`, its ladder summed
/// term by term: R, then T·R^(2k+1)·T back out, and T·R^(2k)·T through.
pub fn ladder(r: f64) -> (f64, f64) {
    let t = 1.0 - r;
    let (mut reflected, mut transmitted) = (r, 0.0);
    for k in 0..200 {
        reflected += t * r.powi(2 * k + 1) * t;
        transmitted += t * r.powi(2 * k) * t;
    }
    (reflected, transmitted)
}
