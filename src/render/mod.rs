//! The CPU path tracer: scene geometry and lights from a composed USD stage, rendered
//! through compiled materials that the renderer sees only through [`crate::abi`].
//!
//! - [`xform`]: xformOps and imageability; [`geometry`]: world-space triangles;
//!   [`accel`]: BVH and ray queries; [`camera`]; [`light`]: UsdLux lights;
//!   [`shapes`]: analytic quadrics; [`skel`]: UsdSkel skinning and blend shapes; [`scene`]: the render scene; [`support`]: what is not
//!   rendered, reported.
//! - [`bsdf`]: BSDF evaluation and sampling ([`microfacet`]: GGX and Fresnel; [`frame`]: shading frames); [`sampling`]: RNG and warps; [`sampler`]: the per-decision path sampler (Owen-scrambled Sobol).
//! - [`integrator`]: path tracing with NEE + MIS and layer picking (DESIGN.md rules 5–7);
//!   [`film`]: the driver, AOVs and statistics; [`output`]: EXR and PNG files.
//! - [`testing`]: a constant `MaterialCode` for tests and benchmarks.

pub mod accel;
pub mod bsdf;
pub mod camera;
#[cfg(test)]
pub(crate) mod chi2;
pub mod cryptomatte;
pub mod displace;
pub mod emitter;
pub mod film;
pub mod frame;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod microfacet;
pub mod output;
pub mod primvars;
pub mod sampler;
pub mod sampling;
pub mod scene;
pub mod shapes;
pub mod skel;
pub mod subdiv;
pub mod support;
pub mod testing;
pub mod xform;

#[cfg(test)]
mod reference;
#[cfg(test)]
mod tests;

pub use film::{
    Channel, ChannelData, FaultKind, FaultReport, Image, MaterialLayerMode, Progress, RenderError, RenderSettings,
    RenderStats, render,
};
pub use integrator::LayerMode;
pub use output::{ExrOptions, OutputError, PreparedOutputs, prepare_outputs, write_exr, write_outputs, write_png};
pub use scene::Scene;
