//! A [`MaterialCode`] test double with constant outputs per layer, for the renderer's tests
//! and benchmarks (no compiler needed).

use crate::abi::ChannelKind;
use crate::abi::{ChannelInfo, Closure, ClosureKind, Globals, LayerInfo, MaterialCode, MaterialInfo, ShaderError};

/// One constant layer.
#[derive(Clone, Debug)]
pub struct ConstLayer {
    /// Mask (written as is: tests may pass values outside [0, 1] or NaN on purpose).
    pub mask: f32,
    /// Surface closure.
    pub closure: Closure,
    /// Channel values, `MaterialInfo::channel_floats` long (0 for channels the layer lacks).
    pub channels: Vec<f32>,
    /// Displacement height.
    pub displacement: f32,
    /// Normal output (`None`: no normal product).
    pub normal: Option<[f32; 3]>,
    /// Emitted radiance (`None`: no emission product).
    pub emission: Option<[f32; 3]>,
}

impl ConstLayer {
    /// A diffuse layer with the given mask and albedo.
    pub fn diffuse(mask: f32, albedo: [f32; 3]) -> ConstLayer {
        let mut params = [0.0; 8];
        params[..3].copy_from_slice(&albedo);
        ConstLayer {
            mask,
            closure: Closure { kind: ClosureKind::Diffuse as u32, params },
            channels: Vec::new(),
            displacement: 0.0,
            normal: None,
            emission: None,
        }
    }
}

/// A material whose entry points return constants.
#[derive(Clone, Debug)]
pub struct ConstMaterial {
    info: MaterialInfo,
    layers: Vec<ConstLayer>,
    /// When set, every entry point fails with this error.
    pub fail: Option<ShaderError>,
}

impl ConstMaterial {
    /// Layers bottom to top; `channels` are `(name, kind)` pairs, laid out in order.
    pub fn new(mut layers: Vec<ConstLayer>, channels: &[(&str, ChannelKind)]) -> ConstMaterial {
        let mut offset = 0;
        let channels: Vec<ChannelInfo> = channels
            .iter()
            .map(|(name, kind)| {
                let c = ChannelInfo { name: name.to_string(), kind: *kind, offset };
                offset += c.width();
                c
            })
            .collect();
        for layer in &mut layers {
            layer.channels.resize(offset, 0.0);
        }
        let info = MaterialInfo {
            layers: layers
                .iter()
                .enumerate()
                .map(|(i, l)| LayerInfo {
                    slot: format!("{:03}", i * 10),
                    has_surface: true,
                    displacement: None,
                    displacement_bound: None,
                    has_normal: l.normal.is_some(),
                    constant_mask: None,
                    has_emission: l.emission.is_some(),
                    pruned: None,
                })
                .collect(),
            channels,
            channel_floats: offset,
            ..MaterialInfo::default()
        };
        ConstMaterial { info, layers, fail: None }
    }

    /// One opaque diffuse layer.
    pub fn diffuse(albedo: [f32; 3]) -> ConstMaterial {
        ConstMaterial::new(vec![ConstLayer::diffuse(1.0, albedo)], &[])
    }

    fn check(&self) -> Result<(), ShaderError> {
        self.fail.map_or(Ok(()), Err)
    }
}

impl MaterialCode for ConstMaterial {
    fn info(&self) -> &MaterialInfo {
        &self.info
    }

    fn masks(&self, _g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        self.check()?;
        for (o, l) in out.iter_mut().zip(&self.layers) {
            *o = l.mask;
        }
        Ok(())
    }

    fn mask(&self, _g: &Globals, layer: usize) -> Result<f32, ShaderError> {
        self.check()?;
        Ok(self.layers[layer].mask)
    }

    fn surface(&self, _g: &Globals, layer: usize, out: &mut Closure) -> Result<(), ShaderError> {
        self.check()?;
        *out = self.layers[layer].closure;
        Ok(())
    }

    fn displacement(&self, _g: &Globals, out: &mut [f32]) -> Result<(), ShaderError> {
        self.check()?;
        for (o, l) in out.iter_mut().zip(&self.layers) {
            *o = l.displacement;
        }
        Ok(())
    }

    fn normal(&self, g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        self.check()?;
        *out = self.layers[layer].normal.unwrap_or(g.n);
        Ok(())
    }

    fn emission(&self, _g: &Globals, layer: usize, out: &mut [f32; 3]) -> Result<(), ShaderError> {
        self.check()?;
        *out = self.layers[layer].emission.unwrap_or([0.0; 3]);
        Ok(())
    }

    fn channels(&self, _g: &Globals, layer: usize, out: &mut [f32]) -> Result<(), ShaderError> {
        self.check()?;
        out.copy_from_slice(&self.layers[layer].channels);
        Ok(())
    }
}
