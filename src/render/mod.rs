pub mod bsdf;
pub mod frame;
pub mod microfacet;
