//! The lobes a closure term can be: [`Bsdf`]'s kinds plus the MaterialX pbrlib lobes
//! (`dielectric_bsdf`, `generalized_schlick_bsdf`, `oren_nayar_diffuse_bsdf`,
//! `burley_diffuse_bsdf`, `sheen_bsdf`, `translucent_bsdf`), with what `layer` needs of a lobe on top: its
//! directional albedo `E(μ)`.
//!
//! Conventions are [`crate::render::material::bsdf`]'s: local frame, `eval` without the cosine,
//! reflection lobes two-sided, transmitting ones oriented (`wo.z < 0` is inside).

use crate::abi::{ClosureKind, ClosureTerm, thin_film_words};
use crate::render::material::albedo;
use crate::render::material::bsdf::{
    Bsdf, BsdfSample, colour, cosine_hemisphere, finish, flip_z, ior, microfacet_reflection_pdf, reflect, roughness,
    sanitize, upper,
};
use crate::render::material::microfacet::{
    Ggx, fresnel_conductor3, fresnel_dielectric, hemispherical_average, hemispherical_average3, sheen_eval,
};
use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};
use thin::ThinSheet;

/// The Fresnel curve of a [`Lobe::Specular`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fresnel {
    /// A dielectric of index `eta` (seen from outside).
    Dielectric {
        /// Index of refraction in [1, 4].
        eta: f32,
    },
    /// A dielectric of index `eta` under a thin film (Airy interference; [`thin_film`]).
    ThinFilm {
        /// Index of refraction of the substrate in [1, 4].
        eta: f32,
        /// The film.
        film: Film,
    },
    /// A conductor of complex index `eta + i k` under a thin film ([`film_on_conductor`]);
    /// without a film a conductor is a [`Bsdf::Metal`].
    Conductor {
        /// Real part of the complex index, per channel.
        eta: Vec3,
        /// Imaginary part (extinction), per channel.
        k: Vec3,
        /// The film.
        film: Film,
    },
    /// MaterialX's generalized Schlick with Hoffman's F82 tint, under a thin film if any.
    Schlick {
        /// Reflectance at normal incidence.
        color0: Vec3,
        /// The tint at cos θ = 1/7 (82°).
        color82: Vec3,
        /// Reflectance at grazing incidence.
        color90: Vec3,
        /// Exponent of the Schlick curve.
        exponent: f32,
        /// A thin film over it ([`film_on_schlick`]).
        film: Option<Film>,
    },
}

/// A thin film on a reflecting surface (OpenPBR `thin_film_*`, MaterialX `thinfilm_*`): the
/// Fresnel curve is `mix(bare, filmed, weight)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Film {
    /// Index of refraction of the film in [1, 4].
    pub eta: f32,
    /// Thickness in nanometres (> 0).
    pub thickness: f32,
    /// Coverage in (0, 1].
    pub weight: f32,
}

impl Film {
    /// Decodes a term's three film words (thickness nm, index, weight; layout in
    /// [`crate::abi::thin_film_words`]): `None` when the thickness or the weight is 0.
    pub fn from_words(p: &[f32]) -> Option<Film> {
        let thickness = sanitize(p[0], 0.0, 1e5, 0.0);
        let weight = sanitize(p[2], 0.0, 1.0, 0.0);
        (thickness > 0.0 && weight > 0.0).then(|| Film { eta: ior(p[1]), thickness, weight })
    }

    /// `mix(bare, filmed, weight)`, exactly `filmed` at weight 1 (where the bare curve is not
    /// computed).
    #[inline]
    fn cover(&self, bare: impl FnOnce() -> Vec3, filmed: Vec3) -> Vec3 {
        if self.weight >= 1.0 { filmed } else { bare().lerp(filmed, self.weight) }
    }

    /// [`Film::on_dielectric`] as the Fresnel term of a glass ([`Bsdf::eval_glass_with`]).
    #[inline]
    fn glass(self) -> impl Fn(f32, f32) -> Vec3 + Copy {
        move |cos, eta| self.on_dielectric(cos, eta)
    }

    /// The cosine-weighted hemispherical average of [`Film::on_dielectric`] seen from outside
    /// (kept out of line: the albedo estimate of plain lobes does not carry its code).
    #[inline(never)]
    fn average_on_dielectric(self, eta: f32) -> Vec3 {
        hemispherical_average3(|mu| self.on_dielectric(mu, eta))
    }

    /// Reflectance of the film on a dielectric of index `eta` at `cos` θ, seen from outside
    /// (`cos` ≥ 0) or from inside the dielectric (`cos` < 0), covering `weight` of it: a
    /// lossless stack reflects the same from both sides at Snell-corresponding angles, so from
    /// inside it is [`thin_film`] at the outside angle, and 1 beyond the critical angle (no
    /// wave leaves into the air, and the film absorbs nothing). What a filmed glass's
    /// microfacets reflect ([`Lobe::Interface`]); they transmit the rest.
    #[inline]
    pub fn on_dielectric(&self, cos: f32, eta: f32) -> Vec3 {
        let outside = if cos >= 0.0 {
            cos
        } else {
            let sin2 = eta * eta * (1.0 - cos * cos);
            if sin2 >= 1.0 {
                return Vec3::ONE;
            }
            (1.0 - sin2).sqrt()
        };
        self.cover(|| Vec3::splat(fresnel_dielectric(cos, eta)), thin_film(outside, eta, self.eta, self.thickness))
    }
}

/// cos θ where the F82 tint applies (MaterialX `mx_fresnel_hoffman_schlick`).
const COS_F82: f32 = 1.0 / 7.0;

impl Fresnel {
    /// Reflectance at `cos θ` (clamped to [0, 1]).
    #[inline]
    pub fn eval(&self, cos: f32) -> Vec3 {
        match *self {
            Fresnel::Dielectric { eta } => Vec3::splat(fresnel_dielectric(cos, eta)),
            Fresnel::ThinFilm { eta, film } => {
                film.cover(|| Vec3::splat(fresnel_dielectric(cos, eta)), thin_film(cos, eta, film.eta, film.thickness))
            }
            Fresnel::Conductor { eta, k, film } => {
                film.cover(|| fresnel_conductor3(cos, eta, k), film_on_conductor(cos, eta, k, film.eta, film.thickness))
            }
            Fresnel::Schlick { color0, color82, color90, exponent, film } => {
                let bare = || schlick_f82(cos, color0, color82, color90, exponent);
                match film {
                    None => bare(),
                    Some(film) => film.cover(
                        bare,
                        film_on_schlick(
                            cos,
                            film.eta,
                            film.thickness,
                            |c2| schlick_f82(c2, color0, color82, color90, exponent),
                            color0,
                        ),
                    ),
                }
            }
        }
    }
}

/// MaterialX's generalized Schlick curve with Hoffman's F82 tint at `cos` (clamped to [0, 1]).
#[inline]
fn schlick_f82(cos: f32, color0: Vec3, color82: Vec3, color90: Vec3, exponent: f32) -> Vec3 {
    let x = cos.clamp(0.0, 1.0);
    let factor = 1.0 / (COS_F82 * (1.0 - COS_F82).powi(6));
    let a = color0.lerp(color90, (1.0 - COS_F82).powf(exponent)) * (Vec3::ONE - color82) * factor;
    let f = color0.lerp(color90, (1.0 - x).powf(exponent)) - a * (x * (1.0 - x).powi(6));
    f.clamp(Vec3::ZERO, Vec3::ONE)
}

/// A complex number: what a conductor's amplitude reflection coefficients need.
#[derive(Clone, Copy, Debug)]
struct Complex {
    re: f32,
    im: f32,
}

impl Complex {
    fn new(re: f32, im: f32) -> Complex {
        Complex { re, im }
    }
    fn add(self, o: Complex) -> Complex {
        Complex::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Complex) -> Complex {
        Complex::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Complex) -> Complex {
        Complex::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
    fn scale(self, x: f32) -> Complex {
        Complex::new(self.re * x, self.im * x)
    }
    fn div(self, o: Complex) -> Complex {
        let d = o.re * o.re + o.im * o.im;
        Complex::new((self.re * o.re + self.im * o.im) / d, (self.im * o.re - self.re * o.im) / d)
    }
    /// The principal square root (real part ≥ 0).
    fn sqrt(self) -> Complex {
        let r = self.re.hypot(self.im);
        let re = (0.5 * (r + self.re)).max(0.0).sqrt();
        let im = (0.5 * (r - self.re)).max(0.0).sqrt();
        Complex::new(re, if self.im < 0.0 { -im } else { im })
    }
}

/// The Airy reflectance of a film (index `film_eta`, `thickness` nm) seen from air at `cos`,
/// per RGB channel averaged over its band ([`FILM_WAVELENGTHS`]) and over s and p: the
/// air|film amplitudes are real, `substrate(channel, cos θ2)` gives the film|substrate ones
/// `(r_s, r_p)` at the angle inside the film, and `|r12 + r23 e^{iδ}|² / |1 + r12 r23 e^{iδ}|²`
/// with the round trip's phase δ (Belcour and Barla 2017 before their spectral integration).
fn film_over(cos: f32, film_eta: f32, thickness: f32, substrate: impl Fn(usize, f32) -> (Complex, Complex)) -> Vec3 {
    let cos1 = cos.clamp(0.0, 1.0);
    let sin2 = 1.0 - cos1 * cos1;
    let cos2 = (1.0 - sin2 / (film_eta * film_eta)).max(0.0).sqrt();
    let n2 = film_eta;
    let r12s = (cos1 - n2 * cos2) / (cos1 + n2 * cos2);
    let r12p = (n2 * cos1 - cos2) / (n2 * cos1 + cos2);
    let airy = |r12: f32, r23: Complex, (sin_d, cos_d): (f32, f32)| {
        let w = r23.mul(Complex::new(cos_d, sin_d));
        let num = (r12 + w.re) * (r12 + w.re) + w.im * w.im;
        let den = (1.0 + r12 * w.re) * (1.0 + r12 * w.re) + (r12 * w.im) * (r12 * w.im);
        (num / den).clamp(0.0, 1.0)
    };
    let path = 4.0 * PI * film_eta * thickness * cos2;
    let mut r = Vec3::ZERO;
    for (c, band) in FILM_WAVELENGTHS.iter().enumerate() {
        let (r23s, r23p) = substrate(c, cos2);
        for lambda in band {
            let phase = (path / lambda).sin_cos();
            r[c] += 0.5 * (airy(r12s, r23s, phase) + airy(r12p, r23p, phase)) / 3.0;
        }
    }
    r
}

/// Reflectance of a conductor (complex index `eta + i k` per channel) under a film (index
/// `film_eta`, `thickness` nm) seen from air at `cos` ([`film_over`]). With a film of index 1
/// (or no thickness) it is the conductor's own Fresnel reflectance.
pub fn film_on_conductor(cos: f32, eta: Vec3, k: Vec3, film_eta: f32, thickness: f32) -> Vec3 {
    let cos1 = cos.clamp(0.0, 1.0);
    let sin2 = 1.0 - cos1 * cos1;
    film_over(cos, film_eta, thickness, |c, cos2| {
        // N3 cos θ3 = √(N3² − n2² sin² θ2) = √(N3² − sin² θ1) (Snell across the film).
        let n3 = Complex::new(eta[c], k[c]);
        let n3_sq = n3.mul(n3);
        let n3_cos3 = n3_sq.sub(Complex::new(sin2, 0.0)).sqrt();
        let n2_cos2 = Complex::new(film_eta * cos2, 0.0);
        let rs = n2_cos2.sub(n3_cos3).div(n2_cos2.add(n3_cos3));
        // r_p = (N3 cos θ2 − n2 cos θ3) / (N3 cos θ2 + n2 cos θ3), both sides times N3.
        let (a, b) = (n3_sq.scale(cos2), n3_cos3.scale(film_eta));
        let rp = a.sub(b).div(a.add(b));
        (rs, rp)
    })
}

/// Reflectance of a generalized Schlick surface under a film ([`film_over`]), as MaterialX
/// approximates it: the film|surface reflectance is the Schlick curve `bare(cos θ2)` at the
/// angle inside the film, its phase 0 or π by whether the index equivalent to `color0` is
/// above the film's (an index has no imaginary part to give more).
fn film_on_schlick(cos: f32, film_eta: f32, thickness: f32, bare: impl Fn(f32) -> Vec3, color0: Vec3) -> Vec3 {
    film_over(cos, film_eta, thickness, |c, cos2| {
        let f0 = color0[c].clamp(0.0, 0.999).sqrt();
        let n3 = (1.0 + f0) / (1.0 - f0);
        let amplitude = bare(cos2)[c].sqrt();
        // The signs of the dielectric coefficients at normal incidence (r_p's convention is
        // r_s's negated there).
        let rs = if n3 > film_eta { -amplitude } else { amplitude };
        (Complex::new(rs, 0.0), Complex::new(-rs, 0.0))
    })
}

/// Wavelengths (nm) each RGB channel averages the thin-film reflectance over: three per band
/// (red 580–700, green 490–580, blue 400–490), so a thick film's fast oscillation averages out
/// rather than aliasing.
const FILM_WAVELENGTHS: [[f32; 3]; 3] = [[600.0, 630.0, 670.0], [500.0, 530.0, 560.0], [415.0, 445.0, 475.0]];

/// Reflectance of a dielectric substrate (index `eta`) under a film (index `film_eta`,
/// `thickness` nm) seen from air at `cos θ`, per RGB channel: the Airy sum of the two
/// interfaces' amplitudes with the phase the film's round trip adds, for s and p polarisation
/// averaged (as Belcour and Barla 2017 before their spectral integration). The indices are
/// ≥ 1, so neither interface totally reflects.
pub fn thin_film(cos: f32, eta: f32, film_eta: f32, thickness: f32) -> Vec3 {
    let sin2 = 1.0 - cos.clamp(0.0, 1.0).powi(2);
    let cos3 = (1.0 - sin2 / (eta * eta)).max(0.0).sqrt();
    film_over(cos, film_eta, thickness, |_, cos2| {
        // Film|substrate amplitudes, real for a dielectric.
        let rs = (film_eta * cos2 - eta * cos3) / (film_eta * cos2 + eta * cos3);
        let rp = (eta * cos2 - film_eta * cos3) / (eta * cos2 + film_eta * cos3);
        (Complex::new(rs, 0.0), Complex::new(rp, 0.0))
    })
}

/// The thin film a term carries, if its kind takes one ([`crate::abi::thin_film_words`]).
#[inline]
fn film_of(t: &ClosureTerm) -> Option<Film> {
    let at = thin_film_words(ClosureKind::from_u32(t.kind))?;
    Film::from_words(&t.params[at..at + 3])
}

/// One lobe of a closure term; Copy, sanitised, allocation-free like [`Bsdf`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lobe {
    /// Diffuse, glossy, metal, conductor or glass.
    Bsdf(Bsdf),
    /// `dielectric_bsdf` with transmission: a rough glass interface ([`Bsdf::Glass`]) whose
    /// reflection is tinted too, or dropped (`reflect == false`, scatter mode "T"). Under a
    /// thin film its microfacets reflect the film's reflectance ([`Film::on_dielectric`]) and
    /// transmit the rest, from either side.
    Interface {
        /// A [`Bsdf::Glass`].
        glass: Bsdf,
        /// Tint of the reflection.
        tint: Vec3,
        /// Whether the interface reflects.
        reflect: bool,
        /// A thin film on the interface.
        film: Option<Film>,
    },
    /// GGX reflection with a Fresnel curve: `dielectric_bsdf` "R" (a coat) and
    /// `generalized_schlick_bsdf`.
    Specular {
        /// The Fresnel curve.
        fresnel: Fresnel,
        /// Colour the reflection is multiplied by.
        tint: Vec3,
        /// Roughness.
        ggx: Ggx,
    },
    /// Oren–Nayar: MaterialX's qualitative model, or with `compensated` the energy-preserving
    /// EON model (Portsmouth et al. 2024: Fujii's Oren–Nayar plus a multiple-scattering term).
    OrenNayar {
        /// Reflectance.
        albedo: Vec3,
        /// Roughness σ in [0, 1].
        roughness: f32,
        /// EON rather than the qualitative model.
        compensated: bool,
    },
    /// Burley's (Disney) diffuse with its grazing retro-reflection.
    Burley {
        /// Reflectance.
        albedo: Vec3,
        /// Roughness in [0, 1].
        roughness: f32,
    },
    /// Diffuse transmission (`translucent_bsdf`): Lambert on the side opposite `wo`.
    Translucent {
        /// Transmittance.
        albedo: Vec3,
    },
    /// A thin-walled dielectric sheet (`dielectric_bsdf` "T"/"RT" made thin by
    /// `with_thin_walled`): no interior, transmission straight through ([`ThinSheet`]).
    Thin(ThinSheet),
    /// The Charlie sheen (Estevez and Kulla 2017) with Neubelt and Pettineo's visibility,
    /// divided by its albedo where that exceeds 1 (smooth sheen at grazing angles).
    Sheen {
        /// Colour.
        color: Vec3,
        /// Roughness in [0, 1].
        roughness: f32,
    },
}

/// EON's constants (Portsmouth et al. 2024, listing 1).
const FON_1: f32 = 0.5 - 2.0 / (3.0 * PI);
const FON_2: f32 = 2.0 / 3.0 - 28.0 / (15.0 * PI);

/// Fujii's Oren–Nayar coefficients `(A, B)` for roughness σ.
#[inline]
fn fon_coefficients(sigma: f32) -> (f32, f32) {
    let a = 1.0 / (1.0 + FON_1 * sigma);
    (a, sigma * a)
}

/// Exact directional albedo of Fujii's Oren–Nayar lobe (white).
#[inline]
pub fn fon_albedo(mu: f32, sigma: f32) -> f32 {
    let (a, b) = fon_coefficients(sigma);
    let mu = mu.clamp(1e-4, 1.0);
    let si = (1.0 - mu * mu).max(0.0).sqrt();
    let g = si * (mu.acos() - si * mu) + (2.0 / 3.0) * ((si / mu) * (1.0 - si * si * si) - si);
    a + b * FRAC_1_PI * g
}

impl Lobe {
    /// Decodes a closure term's kind and parameters (layouts in [`ClosureKind`]), sanitised as
    /// [`Bsdf::from_closure`] does.
    pub fn from_term(t: &ClosureTerm) -> Lobe {
        let p = &t.params;
        let kind = ClosureKind::from_u32(t.kind);
        match kind {
            ClosureKind::Dielectric => {
                let (tint, eta, ggx) = (colour(&p[0..3]), ior(p[3]), roughness(p[4]));
                let film = film_of(t);
                match sanitize(p[5], 0.0, 4.0, 2.0).round() as u32 {
                    0 => {
                        let fresnel = match film {
                            Some(film) => Fresnel::ThinFilm { eta, film },
                            None => Fresnel::Dielectric { eta },
                        };
                        Lobe::Specular { fresnel, tint, ggx }
                    }
                    // Thin-walled ([`crate::abi::THIN_WALLED_SCATTER`]): 3 "T", 4 "RT".
                    mode @ 3.. => Lobe::Thin(ThinSheet::new(tint, eta, ggx, mode == 4, film)),
                    mode => {
                        let mut closure = crate::abi::Closure { kind: ClosureKind::Glass as u32, params: [0.0; 8] };
                        closure.params[..3].copy_from_slice(&p[0..3]);
                        (closure.params[3], closure.params[4]) = (p[4], p[3]);
                        Lobe::Interface { glass: Bsdf::from_closure(&closure), tint, reflect: mode == 2, film }
                    }
                }
            }
            ClosureKind::GeneralizedSchlick => Lobe::Specular {
                fresnel: Fresnel::Schlick {
                    color0: colour(&p[0..3]),
                    color82: colour(&p[3..6]),
                    color90: colour(&p[6..9]),
                    exponent: sanitize(p[9], 0.0, 100.0, 5.0),
                    film: film_of(t),
                },
                tint: Vec3::ONE,
                ggx: roughness(p[10]),
            },
            ClosureKind::OrenNayar => Lobe::OrenNayar {
                albedo: colour(&p[0..3]),
                roughness: sanitize(p[3], 0.0, 1.0, 0.0),
                compensated: sanitize(p[4], 0.0, 1.0, 0.0) >= 0.5,
            },
            ClosureKind::Burley => Lobe::Burley { albedo: colour(&p[0..3]), roughness: sanitize(p[3], 0.0, 1.0, 0.0) },
            ClosureKind::Sheen => Lobe::Sheen { color: colour(&p[0..3]), roughness: sanitize(p[3], 0.0, 1.0, 0.3) },
            ClosureKind::Translucent => Lobe::Translucent { albedo: colour(&p[0..3]) },
            _ => {
                let mut closure = crate::abi::Closure { kind: t.kind, params: [0.0; 8] };
                closure.params.copy_from_slice(&p[..8]);
                let bsdf = Bsdf::from_closure(&closure);
                // A metal under a thin film: its Fresnel curve becomes the film's.
                match (bsdf, film_of(t)) {
                    (Bsdf::Metal { eta, k, ggx, .. }, Some(film)) => {
                        Lobe::Specular { fresnel: Fresnel::Conductor { eta, k, film }, tint: Vec3::ONE, ggx }
                    }
                    _ => Lobe::Bsdf(bsdf),
                }
            }
        }
    }

    /// The lobe with its GGX distribution (if it has one) stretched by `aspect` (`√(αx / αy)`,
    /// [`Ggx::with_aspect`]) along its frame's x axis, the mean width kept; other lobes are
    /// unchanged.
    pub fn with_aspect(self, aspect: f32) -> Lobe {
        let bsdf = |b: Bsdf| match b {
            Bsdf::Glossy { albedo, specular, ggx, eta } => {
                Bsdf::Glossy { albedo, specular, ggx: ggx.with_aspect(aspect), eta }
            }
            Bsdf::Metal { reflectivity, eta, k, ggx } => {
                Bsdf::Metal { reflectivity, eta, k, ggx: ggx.with_aspect(aspect) }
            }
            Bsdf::Glass { tint, ggx, eta } => Bsdf::Glass { tint, ggx: ggx.with_aspect(aspect), eta },
            other => other,
        };
        match self {
            Lobe::Bsdf(b) => Lobe::Bsdf(bsdf(b)),
            Lobe::Interface { glass, tint, reflect, film } => {
                Lobe::Interface { glass: bsdf(glass), tint, reflect, film }
            }
            Lobe::Specular { fresnel, tint, ggx } => Lobe::Specular { fresnel, tint, ggx: ggx.with_aspect(aspect) },
            // Both faces' lobes stretch alike: the transmission mirrors the reflection's
            // microfacets through the tangent plane, which keeps the frame's x axis.
            Lobe::Thin(sheet) => Lobe::Thin(ThinSheet {
                ggx: sheet.ggx.with_aspect(aspect),
                ggx_t: sheet.ggx_t.with_aspect(aspect),
                ..sheet
            }),
            other => other,
        }
    }

    /// Whether the lobe's GGX distribution is anisotropic (its frame's x axis matters).
    pub fn is_anisotropic(&self) -> bool {
        let bsdf = |b: &Bsdf| match b {
            Bsdf::Glossy { ggx, .. } | Bsdf::Metal { ggx, .. } | Bsdf::Glass { ggx, .. } => ggx.is_anisotropic(),
            _ => false,
        };
        match self {
            Lobe::Bsdf(b) | Lobe::Interface { glass: b, .. } => bsdf(b),
            Lobe::Specular { ggx, .. } | Lobe::Thin(ThinSheet { ggx, .. }) => ggx.is_anisotropic(),
            _ => false,
        }
    }

    /// The lobe as a layer on top of others: its transmission is what reaches them, so a
    /// transmitting dielectric keeps only its reflection.
    pub fn covering(self) -> Lobe {
        match self {
            Lobe::Bsdf(Bsdf::Glass { ggx, eta, .. }) => {
                Lobe::Specular { fresnel: Fresnel::Dielectric { eta }, tint: Vec3::ONE, ggx }
            }
            Lobe::Interface { glass: Bsdf::Glass { ggx, eta, .. }, tint, reflect, film } => Lobe::Specular {
                fresnel: match film {
                    Some(film) => Fresnel::ThinFilm { eta, film },
                    None => Fresnel::Dielectric { eta },
                },
                tint: if reflect { tint } else { Vec3::ZERO },
                ggx,
            },
            Lobe::Thin(sheet) => Lobe::Thin(sheet.covering()),
            other => other,
        }
    }

    /// f(wo, wi), local frame, without the cosine; 0 for delta lobes.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let f = match *self {
            Lobe::Bsdf(b) => return b.eval(wo, wi),
            Lobe::Thin(sheet) => return sheet.eval(wo, wi),
            Lobe::Interface { glass, tint, reflect, film } => {
                let f = match film {
                    Some(film) => glass.eval_glass_with(wo, wi, film.glass()),
                    None => glass.eval(wo, wi),
                };
                match (wo.z * wi.z > 0.0, reflect) {
                    (false, _) => f,
                    (true, true) => f * tint,
                    (true, false) => Vec3::ZERO,
                }
            }
            Lobe::Translucent { albedo } => {
                if wo.z * wi.z < 0.0 {
                    albedo * FRAC_1_PI
                } else {
                    Vec3::ZERO
                }
            }
            _ => match upper(wo, wi) {
                Some((wo, wi)) => self.eval_up(wo, wi),
                None => Vec3::ZERO,
            },
        };
        if f.is_finite() { f.max(Vec3::ZERO) } else { Vec3::ZERO }
    }

    /// Solid-angle pdf of [`Lobe::sample`] (non-delta part).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let p = match *self {
            Lobe::Bsdf(b) => return b.pdf(wo, wi),
            Lobe::Thin(sheet) => return sheet.pdf(wo, wi),
            Lobe::Interface { glass, reflect, film, .. } => {
                if wo.z * wi.z > 0.0 && !reflect {
                    0.0
                } else if let Some(film) = film {
                    glass.pdf_glass_with(wo, wi, film.glass())
                } else {
                    glass.pdf(wo, wi)
                }
            }
            Lobe::Specular { ggx, .. } => match upper(wo, wi) {
                Some((wo, wi)) if !ggx.is_smooth() => microfacet_reflection_pdf(ggx, wo, wi),
                _ => 0.0,
            },
            Lobe::Translucent { .. } => {
                if wo.z * wi.z < 0.0 {
                    wi.z.abs() * FRAC_1_PI
                } else {
                    0.0
                }
            }
            _ => match upper(wo, wi) {
                Some((_, wi)) => wi.z * FRAC_1_PI,
                None => 0.0,
            },
        };
        if p.is_finite() { p.max(0.0) } else { 0.0 }
    }

    /// Samples wi (`uc` picks a component, `u` the direction); `None` when nothing is
    /// scattered or the sample is invalid.
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        match *self {
            Lobe::Bsdf(b) => b.sample(wo, uc, u),
            Lobe::Thin(sheet) => sheet.sample(wo, uc, u),
            Lobe::Interface { glass, tint, reflect, film } => {
                let mut s = match film {
                    Some(film) => glass.sample_glass_with(wo, uc, u, film.glass())?,
                    None => glass.sample(wo, uc, u)?,
                };
                if s.wi.z * wo.z > 0.0 {
                    if !reflect {
                        return None;
                    }
                    s.f *= tint;
                }
                Some(s)
            }
            Lobe::Translucent { albedo } => {
                if !(wo.z != 0.0 && wo.is_finite() && u.is_finite()) {
                    return None;
                }
                let wi = cosine_hemisphere(u.clamp(Vec2::ZERO, Vec2::splat(1.0 - f32::EPSILON / 2.0)));
                let wi = if wo.z > 0.0 { flip_z(wi) } else { wi };
                finish(wi, albedo * FRAC_1_PI, wi.z.abs() * FRAC_1_PI, false)
            }
            _ => {
                if !(wo.z != 0.0 && wo.is_finite() && u.is_finite()) {
                    return None;
                }
                let u = u.clamp(Vec2::ZERO, Vec2::splat(1.0 - f32::EPSILON / 2.0));
                let below = wo.z < 0.0;
                let wo_up = if below { flip_z(wo) } else { wo };
                let mut s = self.sample_up(wo_up, u)?;
                if below {
                    s.wi = flip_z(s.wi);
                }
                Some(s)
            }
        }
    }

    /// The reflection lobes (not `Bsdf`, not `Interface`) with both directions up.
    #[inline]
    fn eval_up(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match *self {
            Lobe::Specular { fresnel, tint, ggx } => {
                if ggx.is_smooth() {
                    return Vec3::ZERO;
                }
                let Some(m) = (wo + wi).try_normalize() else { return Vec3::ZERO };
                fresnel.eval(wo.dot(m)) * tint * (ggx.d(m) * ggx.g2(wo, wi) / (4.0 * wo.z * wi.z))
            }
            Lobe::OrenNayar { albedo, roughness, compensated } => {
                let s = wi.dot(wo) - wi.z * wo.z;
                if compensated {
                    let (a, b) = fon_coefficients(roughness);
                    let t = if s > 0.0 { wi.z.max(wo.z) } else { 1.0 };
                    let single = albedo * (FRAC_1_PI * (a + b * s / t));
                    let avg = a * (1.0 + FON_2 * roughness);
                    let multiple_albedo = albedo * albedo * avg / (Vec3::ONE - albedo * (1.0 - avg));
                    let (eo, ei) = (fon_albedo(wo.z, roughness), fon_albedo(wi.z, roughness));
                    let eps = 1e-7;
                    let ms = (1.0 - eo).max(eps) * (1.0 - ei).max(eps) / (1.0 - avg).max(eps);
                    single + multiple_albedo * (FRAC_1_PI * ms)
                } else {
                    let sigma2 = roughness * roughness;
                    let a = 1.0 - 0.5 * sigma2 / (sigma2 + 0.33);
                    let b = 0.45 * sigma2 / (sigma2 + 0.09);
                    let stinv = if s > 0.0 { s / wi.z.max(wo.z) } else { 0.0 };
                    albedo * (FRAC_1_PI * (a + b * stinv))
                }
            }
            Lobe::Burley { albedo, roughness } => {
                let Some(h) = (wo + wi).try_normalize() else { return Vec3::ZERO };
                let cos_d = wi.dot(h);
                let f90 = 0.5 + 2.0 * roughness * cos_d * cos_d;
                let schlick = |mu: f32| 1.0 + (f90 - 1.0) * (1.0 - mu).powi(5);
                albedo * (FRAC_1_PI * schlick(wi.z) * schlick(wo.z))
            }
            Lobe::Sheen { color, roughness } => {
                // Dividing by the larger albedo of the two directions (when above 1) keeps the
                // lobe reciprocal and its albedo ≤ 1.
                let excess = albedo::sheen(wo.z, roughness).max(albedo::sheen(wi.z, roughness)).max(1.0);
                color * (sheen_eval(roughness, wo, wi) / excess)
            }
            Lobe::Bsdf(_) | Lobe::Interface { .. } | Lobe::Translucent { .. } | Lobe::Thin(_) => Vec3::ZERO,
        }
    }

    #[inline]
    fn sample_up(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        let non_delta = |wi: Vec3| {
            if wi.z <= 0.0 {
                return None;
            }
            finish(wi, self.eval_up(wo, wi), self.pdf(wo, wi), false)
        };
        match *self {
            Lobe::Specular { fresnel, tint, ggx } => {
                if ggx.is_smooth() {
                    let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                    finish(wi, fresnel.eval(wo.z) * tint / wi.z, 1.0, true)
                } else {
                    non_delta(reflect(wo, ggx.sample_visible(wo, u)?))
                }
            }
            _ => non_delta(cosine_hemisphere(u)),
        }
    }

    /// Directional albedo `E(μ)` (cos θo = μ ≥ 0) of the lobe as a layer on top: tabulated for
    /// GGX reflection and sheen, exact for Lambert and Fujii's Oren–Nayar, the albedo estimate
    /// of [`Lobe::albedo`] for the rest.
    pub fn directional_albedo(&self, mu: f32) -> Vec3 {
        match *self {
            Lobe::Specular { fresnel, tint, ggx } => {
                let r = ggx.alpha.sqrt();
                tint * match fresnel {
                    Fresnel::Dielectric { eta } => Vec3::splat(albedo::dielectric_reflection(mu, r, eta)),
                    Fresnel::Schlick { .. } | Fresnel::ThinFilm { .. } | Fresnel::Conductor { .. } => {
                        fresnel.eval(mu) * albedo::ggx_reflection(mu, r)
                    }
                }
            }
            Lobe::Bsdf(Bsdf::Metal { eta, k, ggx, .. }) => {
                fresnel_conductor3(mu, eta, k) * albedo::ggx_reflection(mu, ggx.alpha.sqrt())
            }
            Lobe::Bsdf(Bsdf::Diffuse { albedo }) => albedo,
            Lobe::OrenNayar { albedo, roughness: 0.0, compensated: false } => albedo,
            Lobe::Sheen { color, roughness } => color * albedo::sheen(mu, roughness).min(1.0),
            Lobe::Thin(sheet) => sheet.directional_albedo(mu),
            _ => self.albedo(),
        }
    }

    /// Approximate hemispherical albedo colour (the "albedo" AOV; sampling weights).
    pub fn albedo(&self) -> Vec3 {
        match *self {
            Lobe::Bsdf(b) => b.albedo(),
            Lobe::Thin(sheet) => sheet.albedo(),
            Lobe::Interface { glass, tint, reflect, film } => {
                let Bsdf::Glass { eta, tint: transmitted, .. } = glass else { return Vec3::ZERO };
                let fav = match film {
                    Some(film) => film.average_on_dielectric(eta),
                    None => Vec3::splat(hemispherical_average(|mu| fresnel_dielectric(mu, eta))),
                };
                let r = if reflect { tint * fav } else { Vec3::ZERO };
                (r + (Vec3::ONE - fav) * transmitted).min(Vec3::ONE)
            }
            Lobe::Specular { .. } | Lobe::Sheen { .. } => {
                // Each node's directional albedo once for all three channels (it is a table
                // lookup or two), the same sums per channel as a scalar average of each.
                hemispherical_average3(|mu| self.directional_albedo(mu)).min(Vec3::ONE)
            }
            Lobe::OrenNayar { albedo, .. } | Lobe::Burley { albedo, .. } | Lobe::Translucent { albedo } => albedo,
        }
    }

    /// [`Lobe::albedo`] where it is a parameter of the lobe rather than an integral (diffuse
    /// lobes): callers that memoise the integral skip the memo for these.
    pub fn stored_albedo(&self) -> Option<Vec3> {
        match *self {
            Lobe::Bsdf(Bsdf::Black) => Some(Vec3::ZERO),
            Lobe::Bsdf(Bsdf::Diffuse { albedo })
            | Lobe::OrenNayar { albedo, .. }
            | Lobe::Burley { albedo, .. }
            | Lobe::Translucent { albedo } => Some(albedo),
            _ => None,
        }
    }

    /// Whether the lobe has a non-delta part that transmits.
    pub fn transmits(&self) -> bool {
        match *self {
            Lobe::Bsdf(b) | Lobe::Interface { glass: b, .. } => b.transmits(),
            Lobe::Translucent { .. } => true,
            Lobe::Thin(sheet) => sheet.transmits(),
            _ => false,
        }
    }

    /// Whether [`Lobe::sample`] reads its component number `uc` (coat or base, reflection or
    /// transmission): a lobe that does not can be sampled without drawing one.
    pub fn reads_choice(&self) -> bool {
        matches!(self, Lobe::Bsdf(Bsdf::Glossy { .. } | Bsdf::Glass { .. }) | Lobe::Interface { .. } | Lobe::Thin(_))
    }

    /// Whether the lobe tells inside from outside (its frame keeps the outward side).
    pub fn oriented(&self) -> bool {
        matches!(self, Lobe::Bsdf(Bsdf::Glass { .. }) | Lobe::Interface { .. })
    }

    /// The radiance compression of a transmitted direction ([`Bsdf::compression`]).
    pub fn compression(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Lobe::Bsdf(b) | Lobe::Interface { glass: b, .. } => b.compression(wo, wi),
            _ => 1.0,
        }
    }

    /// Whether the lobe has no non-delta part.
    pub fn is_delta(&self) -> bool {
        match *self {
            Lobe::Bsdf(b) | Lobe::Interface { glass: b, .. } => b.is_delta(),
            Lobe::Specular { ggx, .. } => ggx.is_smooth(),
            Lobe::Thin(sheet) => sheet.is_delta(),
            _ => false,
        }
    }

    /// Whether the lobe scatters like a diffuse surface (its layering normalisation is the
    /// cosine-weighted average attenuation; see `closure`).
    pub fn is_diffuse(&self) -> bool {
        matches!(
            self,
            Lobe::Bsdf(Bsdf::Diffuse { .. }) | Lobe::OrenNayar { .. } | Lobe::Burley { .. } | Lobe::Translucent { .. }
        )
    }
}

pub mod thin;
