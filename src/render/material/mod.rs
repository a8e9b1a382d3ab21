//! What a compiled material's closures mean to light: the BSDFs ([`bsdf`]) and the MaterialX
//! lobes ([`lobes`]), a closure value's weighted, layered sum of them ([`closure`], layered by
//! albedo scaling with the tables of [`albedo`] or by the random walk of `closure::walk`), their GGX
//! microfacet distribution and Fresnel terms ([`microfacet`]), the thin-walled sheet ([`lobes::thin`]),
//! the shading frames they work in
//! ([`frame`]), and the χ² statistics the BSDF, layering and thin-film tests share ([`chi2`]).

pub mod albedo;
#[cfg(test)]
mod aniso_tests;
pub mod bsdf;
#[cfg(test)]
pub(crate) mod chi2;
pub mod closure;
#[cfg(test)]
mod closure_tests;
#[cfg(test)]
mod film_tests;
pub mod frame;
pub mod lobes;
pub mod microfacet;
#[cfg(test)]
mod thin_tests;
