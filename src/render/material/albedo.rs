//! Directional albedos `E(μ) = ∫ f(ωo, ωi) cos θi dωi` of the lobes `layer(top, base)` puts on
//! top, tabulated once per process (by deterministic stratified quadrature of the lobes' own
//! sampling, a few tens of milliseconds, on first use) and read by multilinear interpolation:
//! GGX reflection off a dielectric per roughness, index and `cos θo` (what OpenPBR and
//! MaterialX's albedo scaling specify), GGX reflection with Fresnel 1 per roughness and
//! `cos θo` (scaled by a Fresnel curve for conductors and the generalized Schlick lobe), and
//! the Charlie sheen per roughness and `cos θo`.

use crate::render::material::bsdf::reflect;
use crate::render::material::microfacet::sheen_eval;
use crate::render::material::microfacet::{Ggx, fresnel_dielectric};
use glam::{Vec2, Vec3};
use std::sync::OnceLock;

/// Grid points along `√cos θo` and `√roughness` (uniform on [0, 1]: denser at grazing angles
/// and near the smooth limit, where the albedo of a narrow lobe changes fastest) and along the
/// index (uniform on [1, 4]; uniform in F0 instead would leave common indices, 1.3 to 1.6,
/// between two points 2 % of albedo apart at grazing angles).
const N_MU: usize = 32;
const N_ROUGHNESS: usize = 32;
const N_ETA: usize = 16;
/// Stratified samples per axis of each entry's quadrature.
const STRATA: usize = 16;
/// `cos θo` used for the grid's first point (the albedo at exactly 0 is a limit).
const MIN_MU: f32 = 2e-3;
/// The highest index the BSDFs accept.
const MAX_ETA: f32 = 4.0;

/// A table over a uniform grid on [0, 1] per axis (the last axis varying fastest).
struct Table<const D: usize> {
    sizes: [usize; D],
    data: Vec<f32>,
}

impl<const D: usize> Table<D> {
    fn build(sizes: [usize; D], f: impl Fn([f32; D]) -> f32) -> Table<D> {
        let total: usize = sizes.iter().product();
        let data = (0..total)
            .map(|mut i| {
                let mut x = [0.0; D];
                for d in (0..D).rev() {
                    x[d] = (i % sizes[d]) as f32 / (sizes[d] - 1) as f32;
                    i /= sizes[d];
                }
                f(x)
            })
            .collect();
        Table { sizes, data }
    }

    /// Multilinear interpolation at `x` (clamped to [0, 1] per axis).
    fn lookup(&self, x: [f32; D]) -> f32 {
        let mut base = [0usize; D];
        let mut frac = [0.0f32; D];
        for d in 0..D {
            let t = x[d].clamp(0.0, 1.0) * (self.sizes[d] - 1) as f32;
            base[d] = (t as usize).min(self.sizes[d] - 2);
            frac[d] = t - base[d] as f32;
        }
        let mut sum = 0.0;
        for corner in 0..(1usize << D) {
            let (mut index, mut weight) = (0, 1.0);
            for d in 0..D {
                let up = (corner >> d) & 1;
                index = index * self.sizes[d] + base[d] + up;
                weight *= if up == 1 { frac[d] } else { 1.0 - frac[d] };
            }
            sum += weight * self.data[index];
        }
        sum
    }
}

/// `cos θo` at table coordinate `x`.
fn mu_of(x: f32) -> f32 {
    (x * x).max(MIN_MU)
}

/// Table coordinate of `cos θo`.
fn x_of(mu: f32) -> f32 {
    mu.clamp(0.0, 1.0).sqrt()
}

fn direction(mu: f32) -> Vec3 {
    Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu)
}

/// Stratified mean of `g(u)` over the unit square.
fn stratified(g: impl Fn(Vec2) -> f32) -> f32 {
    let mut sum = 0.0;
    for i in 0..STRATA {
        for j in 0..STRATA {
            sum += g(Vec2::new((i as f32 + 0.5) / STRATA as f32, (j as f32 + 0.5) / STRATA as f32));
        }
    }
    sum / (STRATA * STRATA) as f32
}

/// Albedo of GGX reflection with Fresnel `fresnel(cos θ on the microfacet)`, by visible-normal
/// sampling: each sample weighs `F G2 / G1(ωo)`.
fn ggx_reflection_albedo(mu: f32, roughness: f32, fresnel: impl Fn(f32) -> f32) -> f32 {
    let ggx = Ggx::from_roughness(roughness);
    if ggx.is_smooth() {
        return fresnel(mu);
    }
    let wo = direction(mu);
    stratified(|u| {
        let Some(m) = ggx.sample_visible(wo, u) else { return 0.0 };
        let wi = reflect(wo, m);
        if wi.z <= 0.0 {
            return 0.0;
        }
        fresnel(wo.dot(m)) * ggx.g2(wo, wi) / ggx.g1(wo)
    })
}

/// Directional albedo of GGX reflection off a dielectric of index `eta` (from outside), at
/// `cos θo = mu` and perceptual roughness `roughness`.
pub fn dielectric_reflection(mu: f32, roughness: f32, eta: f32) -> f32 {
    static TABLE: OnceLock<Table<3>> = OnceLock::new();
    let table = TABLE.get_or_init(|| {
        Table::build([N_ETA, N_ROUGHNESS, N_MU], |[e, r, mu]| {
            let eta = 1.0 + e * (MAX_ETA - 1.0);
            ggx_reflection_albedo(mu_of(mu), r * r, |c| fresnel_dielectric(c, eta))
        })
    });
    table.lookup([(eta - 1.0) / (MAX_ETA - 1.0), x_of(roughness), x_of(mu)])
}

/// Directional albedo of GGX reflection with Fresnel 1 (what single scattering keeps).
pub fn ggx_reflection(mu: f32, roughness: f32) -> f32 {
    static TABLE: OnceLock<Table<2>> = OnceLock::new();
    let table = TABLE
        .get_or_init(|| Table::build([N_ROUGHNESS, N_MU], |[r, mu]| ggx_reflection_albedo(mu_of(mu), r * r, |_| 1.0)));
    table.lookup([x_of(roughness), x_of(mu)])
}

/// Quadrature steps per axis of the sheen table.
const SHEEN_STEPS: usize = 64;

/// Directional albedo of the unnormalised Charlie sheen lobe of white colour
/// ([`sheen_eval`]; it exceeds 1 at grazing angles when smooth).
pub fn sheen(mu: f32, roughness: f32) -> f32 {
    static TABLE: OnceLock<Table<2>> = OnceLock::new();
    let table = TABLE.get_or_init(|| {
        Table::build([N_ROUGHNESS, N_MU], |[r, mu]| {
            let wo = direction(mu_of(mu));
            // Midpoint rule in (cos θi, φ): the lobe peaks at grazing ωi, which cosine-weighted
            // strata reach too sparsely (5 % low at cos θo = 0.1).
            let mut sum = 0.0;
            for i in 0..SHEEN_STEPS {
                let mu_i = (i as f32 + 0.5) / SHEEN_STEPS as f32;
                let s = (1.0 - mu_i * mu_i).max(0.0).sqrt();
                for j in 0..SHEEN_STEPS {
                    let phi = std::f32::consts::TAU * (j as f32 + 0.5) / SHEEN_STEPS as f32;
                    sum += sheen_eval(r, wo, Vec3::new(s * phi.cos(), s * phi.sin(), mu_i)) * mu_i;
                }
            }
            sum * std::f32::consts::TAU / (SHEEN_STEPS * SHEEN_STEPS) as f32
        })
    });
    table.lookup([roughness, x_of(mu)])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::material::microfacet::hemispherical_average;

    /// The tables against closed forms: a smooth dielectric reflects exactly Fresnel, GGX with
    /// Fresnel 1 loses nothing when smooth, and interpolation between grid points stays within
    /// 1 % (absolute, of an albedo ≤ 1) of a direct quadrature from cos θo = 0.1 up, 3 % below.
    /// Measured worst cases are printed.
    #[test]
    fn tables_match_closed_forms_and_direct_quadrature() {
        let mut worst = [0.0f32; 2];
        for mu in [0.03f32, 0.05, 0.08, 0.1, 0.13, 0.3, 0.52, 0.77, 0.95, 1.0] {
            let want = fresnel_dielectric(mu, 1.5);
            assert!((dielectric_reflection(mu, 0.0, 1.5) - want).abs() < 3e-3, "smooth F({mu})");
            assert!((ggx_reflection(mu, 0.0) - 1.0).abs() < 1e-6);
            for r in [0.05f32, 0.11, 0.17, 0.29, 0.5, 0.71, 0.93] {
                for eta in [1.33f32, 1.5, 1.77, 2.2] {
                    let direct = ggx_reflection_albedo(mu, r, |c| fresnel_dielectric(c, eta));
                    let got = dielectric_reflection(mu, r, eta);
                    let k = usize::from(mu >= 0.1);
                    worst[k] = worst[k].max((got - direct).abs());
                    let tolerance = if mu >= 0.1 { 0.01 } else { 0.03 };
                    assert!((got - direct).abs() < tolerance, "μ={mu} r={r} η={eta}: {got} vs {direct}");
                }
                let (got, direct) = (ggx_reflection(mu, r), ggx_reflection_albedo(mu, r, |_| 1.0));
                assert!((got - direct).abs() < if mu >= 0.1 { 0.01 } else { 0.03 }, "F=1 μ={mu} r={r}");
            }
        }
        eprintln!("dielectric albedo table: worst error {:.4} below cos θo = 0.1, {:.4} above", worst[0], worst[1]);
        // The hemispherical average of a smooth coat's albedo is F̄.
        let avg = hemispherical_average(|mu| dielectric_reflection(mu, 0.0, 1.5));
        let want = hemispherical_average(|mu| fresnel_dielectric(mu, 1.5));
        assert!((avg - want).abs() < 2e-3, "{avg} vs {want}");
    }
}
