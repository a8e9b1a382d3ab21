//! What a compiled material's closures mean to light: the BSDFs ([`bsdf`]), their GGX
//! microfacet distribution and Fresnel terms ([`microfacet`]), the shading frames they work in
//! ([`frame`]), and the χ² statistics the BSDF and layering tests share ([`chi2`]).

pub mod bsdf;
#[cfg(test)]
pub(crate) mod chi2;
pub mod frame;
pub mod microfacet;
