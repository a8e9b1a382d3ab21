//! Image files: one multi-layer EXR (single part, the channel names compositors expect) and
//! a tone-mapped sRGB PNG preview. Both are written atomically: to a temporary file in the
//! target's directory, then renamed over the target, so a failed write never leaves a
//! partial file and never replaces an existing one.

use super::film::{ChannelData, Image};
use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, WritableImage};
use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A failed write.
#[derive(Debug)]
pub struct OutputError {
    /// The file that was being written.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

impl fmt::Display for OutputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "cannot write `{}`: {}", self.path.display(), self.message)
    }
}

impl std::error::Error for OutputError {}

/// A temporary sibling of `path` that is removed unless committed.
struct TempFile {
    tmp: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl TempFile {
    fn new(target: &Path) -> TempFile {
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let tmp = target.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
        TempFile { tmp, target: target.to_path_buf(), committed: false }
    }

    fn commit(mut self) -> std::io::Result<()> {
        std::fs::rename(&self.tmp, &self.target)?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

fn error(path: &Path, message: impl ToString) -> OutputError {
    OutputError { path: path.to_path_buf(), message: message.to_string() }
}

/// Writes every channel of `image` into one single-part EXR at `path` (float channels as
/// 32-bit float, integer channels as UINT, ZIP compression).
pub fn write_exr(image: &Image, path: &Path) -> Result<(), OutputError> {
    let channels: Vec<AnyChannel<FlatSamples>> = image
        .channels
        .iter()
        .map(|c| {
            let samples = match &c.data {
                ChannelData::F32(v) => FlatSamples::F32(v.clone()),
                ChannelData::U32(v) => FlatSamples::U32(v.clone()),
            };
            AnyChannel::new(c.name.as_str(), samples)
        })
        .collect();
    let layer = Layer::new(
        (image.width, image.height),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(channels.into_iter().collect()),
    );
    let exr_image = exr::image::Image::from_layer(layer);
    let tmp = TempFile::new(path);
    exr_image.write().to_file(&tmp.tmp).map_err(|e| error(path, e))?;
    tmp.commit().map_err(|e| error(path, e))
}

/// The preview's display transform: exposure (in stops), the ACES filmic fit of Narkowicz
/// (2015), then the sRGB transfer function.
pub fn tone_map(linear: f32, exposure: f32) -> u8 {
    let x = (linear * exposure.exp2()).max(0.0);
    let x = if x.is_finite() { x } else { 0.0 };
    let (a, b, c, d, e) = (2.51, 0.03, 2.43, 0.59, 0.14);
    let mapped = ((x * (a * x + b)) / (x * (c * x + d) + e)).clamp(0.0, 1.0);
    let srgb = if mapped <= 0.003_130_8 { 12.92 * mapped } else { 1.055 * mapped.powf(1.0 / 2.4) - 0.055 };
    (srgb * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// Writes the beauty (`R`, `G`, `B`) as an 8-bit sRGB PNG.
pub fn write_png(image: &Image, path: &Path, exposure: f32) -> Result<(), OutputError> {
    let planes: Vec<&[f32]> = ["R", "G", "B"]
        .iter()
        .map(|n| image.f32_channel(n).ok_or_else(|| error(path, format!("the image has no `{n}` channel"))))
        .collect::<Result<_, _>>()?;
    let mut pixels = Vec::with_capacity(image.width * image.height * 3);
    for i in 0..image.width * image.height {
        for plane in &planes {
            pixels.push(tone_map(plane[i], exposure));
        }
    }
    let mut encoded = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut encoded, image.width as u32, image.height as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header().map_err(|e| error(path, e))?;
        writer.write_image_data(&pixels).map_err(|e| error(path, e))?;
        writer.finish().map_err(|e| error(path, e))?;
    }
    let tmp = TempFile::new(path);
    let mut file = std::fs::File::create(&tmp.tmp).map_err(|e| error(path, e))?;
    file.write_all(&encoded).and_then(|()| file.sync_all()).map_err(|e| error(path, e))?;
    drop(file);
    tmp.commit().map_err(|e| error(path, e))
}

/// Writes `OUT.exr` and the preview `OUT.png` beside it (same stem).
pub fn write_outputs(image: &Image, exr_path: &Path) -> Result<PathBuf, OutputError> {
    write_exr(image, exr_path)?;
    let png_path = exr_path.with_extension("png");
    write_png(image, &png_path, 0.0)?;
    Ok(png_path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::film::Channel;
    use exr::prelude::ReadChannels;
    use exr::prelude::ReadLayers;

    fn sample_image() -> Image {
        let (w, h) = (4, 3);
        let ramp = |k: f32| (0..w * h).map(|i| i as f32 * k).collect::<Vec<f32>>();
        let mut channels = Vec::new();
        for (i, name) in ["R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.X", "N.Y", "N.Z", "Z", "wear"]
            .iter()
            .enumerate()
        {
            channels.push(Channel { name: name.to_string(), data: ChannelData::F32(ramp(i as f32 + 0.5)) });
        }
        channels.push(Channel { name: "id".into(), data: ChannelData::U32((0..(w * h) as u32).collect()) });
        Image { width: w, height: h, channels }
    }

    #[test]
    fn exr_round_trip_names_and_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.exr");
        let image = sample_image();
        let png = write_outputs(&image, &path).unwrap();
        assert!(png.exists());
        let read = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_file(&path)
            .unwrap();
        let layer = read.layer_data;
        assert_eq!(layer.size.width(), 4);
        let mut names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        names.sort();
        let mut expected: Vec<String> = image.channels.iter().map(|c| c.name.clone()).collect();
        expected.sort();
        assert_eq!(names, expected);
        for c in &layer.channel_data.list {
            let original = image.channels.iter().find(|o| o.name == c.name.to_string()).unwrap();
            match (&original.data, &c.sample_data) {
                (ChannelData::F32(a), FlatSamples::F32(b)) => assert_eq!(a, b),
                (ChannelData::U32(a), FlatSamples::U32(b)) => assert_eq!(a, b),
                other => panic!("type changed for {}: {other:?}", c.name),
            }
        }
        // No temporary files are left behind.
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left.len(), 2, "{left:?}");
    }

    #[test]
    fn failed_write_creates_nothing_and_keeps_existing_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no/such/dir/out.exr");
        assert!(write_exr(&sample_image(), &missing).is_err());
        assert!(!missing.exists());
        // An image with a channel of the wrong length fails; an existing file stays untouched.
        let path = dir.path().join("keep.exr");
        std::fs::write(&path, b"previous").unwrap();
        let mut bad = sample_image();
        bad.channels[0].data = ChannelData::F32(vec![0.0; 2]);
        let result = std::panic::catch_unwind(|| write_exr(&bad, &path));
        assert!(!matches!(result, Ok(Ok(()))));
        assert_eq!(std::fs::read(&path).unwrap(), b"previous");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left.len(), 1, "{left:?}");
    }

    #[test]
    fn tone_curve_is_monotonic_and_bounded() {
        assert_eq!(tone_map(0.0, 0.0), 0);
        assert_eq!(tone_map(1e9, 0.0), 255);
        assert_eq!(tone_map(f32::NAN, 0.0), 0);
        let mut last = 0;
        for i in 0..1000 {
            let v = tone_map(i as f32 / 100.0, 0.0);
            assert!(v >= last);
            last = v;
        }
    }
}
