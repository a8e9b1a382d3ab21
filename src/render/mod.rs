//! The CPU path tracer: scene geometry and lights from a composed USD stage, rendered
//! through compiled materials that the renderer sees only through [`crate::abi`].
//!
//! Grouped by concern, each folder owning its concepts:
//! - [`geometry`]: world-space triangles and analytic shapes from the stage, with
//!   [`geometry::accel`] (BVH and ray queries), [`geometry::xform`] (xformOps and imageability),
//!   [`geometry::subdiv`], [`geometry::skel`], [`geometry::displace`] and [`geometry::primvars`];
//! - [`material`]: BSDF evaluation and sampling of the closures materials return;
//! - [`light`]: UsdLux lights and emissive geometry ([`light::emitter`]);
//! - [`camera`]; [`film`]: the driver, AOVs and statistics, with [`film::output`] (EXR and PNG)
//!   and [`film::cryptomatte`];
//! - [`sampling`]: RNG and warps, and [`sampling::sampler`], the per-decision path sampler
//!   (Owen-scrambled Sobol);
//! - [`integrator`]: path tracing with NEE + MIS and layer picking (DESIGN.md rules 5–7);
//! - [`scene`]: the render scene built from all of the above; [`support`]: what is not rendered,
//!   reported; [`testing`]: a constant `MaterialCode` for tests and benchmarks.

pub mod camera;
pub mod film;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod material;
pub mod sampling;
pub mod scene;
pub mod support;
pub mod testing;

#[cfg(test)]
mod tests;

pub use film::output::{
    ExrOptions, OutputError, PreparedOutputs, prepare_outputs, write_exr, write_outputs, write_png,
};
pub use film::{
    Channel, ChannelData, FaultKind, FaultReport, Image, MaterialLayerMode, Progress, Region, RenderError,
    RenderSettings, RenderStats, Window, WindowSums, image_from_sums, render, render_sums, render_window,
};
pub use integrator::LayerMode;
pub use scene::Scene;
