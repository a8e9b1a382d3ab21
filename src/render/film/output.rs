//! Image files: one multi-layer EXR (single part, the channel names compositors expect) and
//! a tone-mapped sRGB PNG preview.
//!
//! Both are written atomically: into a temporary file beside the target (`.NAME.PID.tmp`),
//! fsynced, then renamed over the target, so a failed or interrupted write never leaves a
//! partial file and never replaces an existing one. [`prepare_outputs`] creates both
//! temporaries before anything is rendered, so an unwritable directory or a `OUT.png` that is
//! a directory fails at once, and [`PreparedOutputs::write`] renames only after both files
//! are written: a failure leaves the previous `OUT.exr` and `OUT.png` as they were.
//! Temporaries not yet renamed are listed so [`remove_temporary_files`] can delete them when
//! the process is interrupted (the command line calls it on SIGINT/SIGTERM/SIGHUP); those of
//! a process that was killed outright are removed by the next run writing the same target.

use crate::render::film::{ChannelData, Image};
use exr::meta::attribute::{AttributeValue, Chromaticities, Text};
use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, ImageAttributes, IntegerBounds, Layer, LayerAttributes, Vec2,
    WritableImage, f16,
};
use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

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

/// Temporary files created and not yet renamed into place or removed.
static LIVE_TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn live_temporaries() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    // A panic elsewhere while holding the lock leaves a list that is still right.
    LIVE_TEMPORARIES.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Deletes every temporary output file this process has not yet renamed into place. Called
/// when the process is interrupted; afterwards no output of this process is half-written.
pub fn remove_temporary_files() {
    for tmp in live_temporaries().drain(..) {
        let _ = std::fs::remove_file(tmp);
    }
}

/// The temporary name beside `target` for process `pid`.
fn temporary_name(target: &Path, pid: u32) -> PathBuf {
    let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    target.with_file_name(format!(".{name}.{pid}.tmp"))
}

/// Removes temporaries of `target` left by processes that no longer exist (killed outright,
/// which no handler can catch). Only names of the exact `.NAME.PID.tmp` form are touched.
fn remove_stale_temporaries(target: &Path) {
    #[cfg(unix)]
    {
        let (Some(dir), Some(name)) = (target.parent(), target.file_name()) else { return };
        let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
        let prefix = format!(".{}.", name.to_string_lossy());
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for entry in entries.flatten() {
            let file_name = entry.file_name();
            let file_name = file_name.to_string_lossy();
            let Some(pid) = file_name.strip_prefix(&prefix).and_then(|rest| rest.strip_suffix(".tmp")) else {
                continue;
            };
            let Ok(pid) = pid.parse::<i32>() else { continue };
            if pid <= 0 || pid as u32 == std::process::id() {
                continue;
            }
            // Signal 0 checks existence only; EPERM means it exists under another user.
            // SAFETY: kill with signal 0 sends nothing and touches no memory.
            let alive = unsafe { libc::kill(pid, 0) } == 0
                || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
            if !alive {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
    #[cfg(not(unix))]
    let _ = target;
}

/// An open temporary sibling of a target file; removed unless committed.
struct TempFile {
    tmp: PathBuf,
    target: PathBuf,
    file: Option<File>,
    committed: bool,
}

impl TempFile {
    /// Checks that `target` can be replaced by a regular file (it is not a directory, a
    /// device, ...) and creates the temporary beside it, which proves the directory writable.
    fn create(target: &Path) -> Result<TempFile, OutputError> {
        match std::fs::metadata(target) {
            Ok(meta) if meta.is_dir() => return Err(error(target, "it is a directory")),
            Ok(meta) if !meta.is_file() => return Err(error(target, "it exists and is not a regular file")),
            _ => {}
        }
        if target.file_name().is_none() {
            return Err(error(target, "not a file path"));
        }
        remove_stale_temporaries(target);
        let tmp = temporary_name(target, std::process::id());
        // A leftover of this very pid (an earlier run, long dead) is ours to replace.
        let _ = std::fs::remove_file(&tmp);
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp).map_err(|e| {
            let dir = target.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
            error(target, format!("cannot create a file in `{}`: {e}", dir.display()))
        })?;
        live_temporaries().push(tmp.clone());
        Ok(TempFile { tmp, target: target.to_path_buf(), file: Some(file), committed: false })
    }

    /// Writes `bytes` with `write` and makes them durable (fsync) before any rename.
    fn fill(&mut self, write: impl FnOnce(&mut BufWriter<&File>) -> Result<(), String>) -> Result<(), OutputError> {
        let Some(file) = self.file.as_ref() else { return Err(error(&self.target, "already written")) };
        let mut buffered = BufWriter::new(file);
        write(&mut buffered).map_err(|e| error(&self.target, e))?;
        buffered.flush().map_err(|e| error(&self.target, e))?;
        drop(buffered);
        file.sync_all().map_err(|e| error(&self.target, e))
    }

    /// Renames the (filled) temporary over the target, then syncs the directory so the
    /// rename itself survives a crash.
    fn commit(mut self) -> Result<(), OutputError> {
        drop(self.file.take());
        std::fs::rename(&self.tmp, &self.target).map_err(|e| error(&self.target, e))?;
        self.committed = true;
        live_temporaries().retain(|t| *t != self.tmp);
        #[cfg(unix)]
        if let Some(dir) = self.target.parent() {
            let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
            if let Ok(dir) = File::open(dir) {
                let _ = dir.sync_all();
            }
        }
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.committed {
            drop(self.file.take());
            let _ = std::fs::remove_file(&self.tmp);
            live_temporaries().retain(|t| *t != self.tmp);
        }
    }
}

fn error(path: &Path, message: impl ToString) -> OutputError {
    OutputError { path: path.to_path_buf(), message: message.to_string() }
}

/// What goes into the EXR besides the pixels.
#[derive(Clone, Debug, Default)]
pub struct ExrOptions {
    /// Store beauty and colour-like channels as 16-bit half floats (see [`is_half_channel`]).
    pub half: bool,
    /// The render camera's `worldToCamera` in OpenEXR's convention (column vectors; written
    /// in OpenEXR's row-vector layout): see [`crate::render::camera::Camera::world_to_camera_exr`].
    pub world_to_camera: Option<glam::Mat4>,
    /// The render camera's `worldToNDC` in OpenEXR's convention (column vectors): see
    /// [`crate::render::camera::Camera::world_to_ndc_exr`].
    pub world_to_ndc: Option<glam::Mat4>,
    /// Near and far clipping planes (a non-finite far plane is not written).
    pub clipping: Option<(f32, f32)>,
    /// Extra string attributes (render settings), written as given.
    pub strings: Vec<(String, String)>,
    /// Where the pixels sit when they are a region of a larger image: the region's top-left
    /// corner (the data window's) and the whole image's size (the display window). `None`:
    /// the pixels are the whole image.
    pub placement: Option<((usize, usize), (usize, usize))>,
}

/// Whether a channel is stored as half under `--half`: `R G B A`, `albedo.*`, `N.*` and custom
/// colour channels (`name.R/G/B`). Depth (`Z`), position (`P.*`), Cryptomatte, custom scalar
/// channels (any range, so kept exact) and integer channels stay 32-bit.
pub fn is_half_channel(name: &str) -> bool {
    // A partial file's exact sums (`strata.sum.*`, see `partial`) are integers and floats
    // that must survive bit for bit.
    if name.starts_with("strata.") {
        return false;
    }
    if matches!(name, "R" | "G" | "B" | "A") || name.starts_with("albedo.") || name.starts_with("N.") {
        return true;
    }
    // Cryptomatte IDs are hash bits: half would destroy them.
    !name.starts_with("P.")
        && !name.starts_with("Crypto")
        && [".R", ".G", ".B"].iter().any(|suffix| name.ends_with(suffix))
}

/// The EXR text for `s`: OpenEXR strings are 8-bit, so characters beyond Latin-1 (a scene
/// path in another script) are written as `\u{…}` escapes rather than refused.
fn exr_text(s: &str) -> Text {
    Text::new_or_none(s).unwrap_or_else(|| {
        let escaped: String = s
            .chars()
            .map(|c| if (c as u32) < 256 { c.to_string() } else { format!("\\u{{{:x}}}", c as u32) })
            .collect();
        Text::new_or_none(&escaped).unwrap_or_else(|| Text::from("?"))
    })
}

/// `m` (column vectors) in OpenEXR/Imath's layout: row vectors, translation in the last row,
/// which is `m`'s column-major array.
fn imath_matrix(m: glam::Mat4) -> [f32; 16] {
    m.to_cols_array()
}

/// The attributes every strata EXR carries, whatever the render: colour space, software, and
/// what the vector and depth channels mean.
pub(super) fn standard_attributes() -> Vec<(&'static str, String)> {
    vec![
        ("strata/colorSpace", "lin_rec709 (linear Rec.709 primaries, D65 white)".into()),
        (
            "strata/alpha",
            "premultiplied; A is surface coverage, RGB may be non-zero where A = 0 (a visible dome)".into(),
        ),
        ("strata/N/space", "world".into()),
        ("strata/P/space", "world".into()),
        ("strata/albedo/space", "lin_rec709".into()),
        ("strata/Z/space", "camera (depth along the viewing axis, positive)".into()),
        ("strata/Z/miss", format!("{:e}", crate::render::film::DEPTH_MISS)),
    ]
}

/// Encodes every channel of `image` as one single-part EXR (float channels as 32-bit float or,
/// with `options.half`, half where [`is_half_channel`]; integer channels as UINT; ZIP
/// compression), with the standard and strata header attributes.
fn encode_exr(image: &Image, options: &ExrOptions, out: &mut BufWriter<&File>) -> Result<(), String> {
    let channels: Vec<AnyChannel<FlatSamples>> = image
        .channels
        .iter()
        .map(|c| {
            let samples = match &c.data {
                ChannelData::F32(v) if options.half && is_half_channel(&c.name) => {
                    FlatSamples::F16(v.iter().map(|&x| f16::from_f32(x)).collect())
                }
                ChannelData::F32(v) => FlatSamples::F32(v.clone()),
                ChannelData::U32(v) => FlatSamples::U32(v.clone()),
            };
            let mut channel = AnyChannel::new(exr_text(&c.name), samples);
            // OpenEXR's own default (what Nuke and OIIO write): the exr crate guesses from the
            // bare name and would mark `albedo.R` perceptually linear but `Z` not. The flag
            // only steers lossy compression; ours is lossless.
            channel.quantize_linearly = false;
            channel
        })
        .collect();
    let ((x, y), (display_width, display_height)) = options.placement.unwrap_or(((0, 0), (image.width, image.height)));
    let mut layer_attributes = LayerAttributes {
        layer_position: Vec2(x as i32, y as i32),
        software_name: Some(exr_text(&format!("strata {}", env!("CARGO_PKG_VERSION")))),
        world_to_camera: options.world_to_camera.map(imath_matrix),
        world_to_normalized_device: options.world_to_ndc.map(imath_matrix),
        ..LayerAttributes::default()
    };
    if let Some((near, far)) = options.clipping {
        layer_attributes.near_clip_plane = Some(near);
        layer_attributes.far_clip_plane = far.is_finite().then_some(far);
    }
    let strings = standard_attributes().into_iter().map(|(k, v)| (k.to_string(), v));
    for (key, value) in strings.chain(options.strings.iter().cloned()) {
        layer_attributes.other.insert(exr_text(&key), AttributeValue::Text(exr_text(&value)));
    }
    let layer = Layer::new(
        (image.width, image.height),
        layer_attributes,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(channels.into_iter().collect()),
    );
    let mut image_attributes =
        ImageAttributes::new(IntegerBounds::new(Vec2(0, 0), Vec2(display_width, display_height)));
    // Rec.709 / sRGB primaries with a D65 white point: what strata's linear radiance is in.
    image_attributes.chromaticities = Some(Chromaticities {
        red: Vec2(0.64, 0.33),
        green: Vec2(0.30, 0.60),
        blue: Vec2(0.15, 0.06),
        white: Vec2(0.3127, 0.3290),
    });
    exr::image::Image::new(image_attributes, layer).write().to_buffered(out).map_err(|e| e.to_string())
}

/// Writes every channel of `image` into one single-part EXR at `path`, atomically, with the
/// standard attributes only.
pub fn write_exr(image: &Image, path: &Path) -> Result<(), OutputError> {
    let mut tmp = TempFile::create(path)?;
    tmp.fill(|out| encode_exr(image, &ExrOptions::default(), out))?;
    tmp.commit()
}

/// [`write_exr`] with `options`' header attributes, sample types and placement, and no PNG.
pub fn write_exr_with(image: &Image, path: &Path, options: &ExrOptions) -> Result<(), OutputError> {
    let mut tmp = TempFile::create(path)?;
    tmp.fill(|out| encode_exr(image, options, out))?;
    tmp.commit()
}

/// A single-part EXR as read back: every channel and attribute of its first layer.
pub type ExrFile = exr::image::Image<exr::image::Layer<exr::image::AnyChannels<exr::image::FlatSamples>>>;

/// Reads every channel and attribute of the first valid layer of the EXR at `path`.
pub fn read_exr(path: &Path) -> Result<ExrFile, exr::error::Error> {
    use exr::prelude::{ReadChannels, ReadLayers};
    exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
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

/// Encodes the beauty (`R`, `G`, `B`) as an 8-bit sRGB PNG.
fn encode_png(image: &Image, exposure: f32) -> Result<Vec<u8>, String> {
    let planes: Vec<&[f32]> = ["R", "G", "B"]
        .iter()
        .map(|n| image.f32_channel(n).ok_or_else(|| format!("the image has no `{n}` channel")))
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
        let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
        writer.write_image_data(&pixels).map_err(|e| e.to_string())?;
        writer.finish().map_err(|e| e.to_string())?;
    }
    Ok(encoded)
}

/// Writes the beauty (`R`, `G`, `B`) as an 8-bit sRGB PNG at `path`, atomically.
pub fn write_png(image: &Image, path: &Path, exposure: f32) -> Result<(), OutputError> {
    let encoded = encode_png(image, exposure).map_err(|e| error(path, e))?;
    let mut tmp = TempFile::create(path)?;
    tmp.fill(|out| out.write_all(&encoded).map_err(|e| e.to_string()))?;
    tmp.commit()
}

/// `OUT.exr` and its preview `OUT.png`, opened as temporaries beside them before rendering.
pub struct PreparedOutputs {
    exr: TempFile,
    png: TempFile,
}

/// Checks both outputs of a render can be written (neither is a directory, the directory
/// takes new files) by creating their temporaries now, before any time is spent rendering.
pub fn prepare_outputs(exr_path: &Path) -> Result<PreparedOutputs, OutputError> {
    let png_path = exr_path.with_extension("png");
    let exr = TempFile::create(exr_path)?;
    let png = TempFile::create(&png_path)?;
    Ok(PreparedOutputs { exr, png })
}

impl PreparedOutputs {
    /// The EXR's path.
    pub fn exr_path(&self) -> &Path {
        &self.exr.target
    }

    /// The PNG preview's path.
    pub fn png_path(&self) -> &Path {
        &self.png.target
    }

    /// Writes both files and only then renames them into place, EXR first. Returns the PNG's
    /// path. On failure neither target has changed (short of a rename failing between the
    /// two, in a directory both temporaries were just created in).
    pub fn write(self, image: &Image) -> Result<PathBuf, OutputError> {
        self.write_with(image, &ExrOptions::default())
    }

    /// [`PreparedOutputs::write`] with header attributes and sample types from `options`.
    pub fn write_with(mut self, image: &Image, options: &ExrOptions) -> Result<PathBuf, OutputError> {
        // The two encodings are independent; the PNG's deflate runs beside the EXR's.
        let (exr, png) = (&mut self.exr, &mut self.png);
        let png_target = png.target.clone();
        let (exr_written, png_written) = std::thread::scope(|scope| {
            let png_thread = scope.spawn(move || {
                let encoded = encode_png(image, 0.0).map_err(|e| error(&png.target, e))?;
                png.fill(|out| out.write_all(&encoded).map_err(|e| e.to_string()))
            });
            let exr_written = exr.fill(|out| encode_exr(image, options, out));
            let png_written = png_thread.join().unwrap_or_else(|_| Err(error(&png_target, "the PNG encoder panicked")));
            (exr_written, png_written)
        });
        exr_written?;
        png_written?;
        let png_path = self.png.target.clone();
        self.exr.commit()?;
        self.png.commit()?;
        Ok(png_path)
    }
}

/// Writes `OUT.exr` and the preview `OUT.png` beside it (same stem), both or neither.
pub fn write_outputs(image: &Image, exr_path: &Path) -> Result<PathBuf, OutputError> {
    prepare_outputs(exr_path)?.write(image)
}

/// Writes a file whole or not at all (a fsynced temporary beside it, then a rename).
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let mut tmp = TempFile::create(path)?;
    tmp.fill(|out| out.write_all(bytes).map_err(|e| e.to_string()))?;
    tmp.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The written EXR, every channel and attribute.
    fn read_back(path: &Path) -> ExrFile {
        read_exr(path).unwrap()
    }
    use crate::render::film::Channel;

    fn sample_image() -> Image {
        let (w, h) = (4, 3);
        let ramp = |k: f32| (0..w * h).map(|i| i as f32 * k).collect::<Vec<f32>>();
        let mut channels = Vec::new();
        for (i, name) in [
            "R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.R", "N.G", "N.B", "P.R", "P.G", "P.B", "Z",
            "wear",
        ]
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
        let read = read_back(&path);
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
    fn text_beyond_latin1_is_escaped_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.exr");
        let mut image = sample_image();
        image.channels.push(Channel { name: "温度".into(), data: ChannelData::F32(vec![1.0; 12]) });
        let options = ExrOptions {
            half: true,
            strings: vec![("strata/scene".into(), "/場面.usda".into())],
            ..ExrOptions::default()
        };
        prepare_outputs(&path).unwrap().write_with(&image, &options).unwrap();
        let read = read_back(&path);
        let names: Vec<String> = read.layer_data.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        assert!(names.contains(&"\\u{6e29}\\u{5ea6}".to_string()), "{names:?}");
        let scene = &read.layer_data.attributes.other[&Text::from("strata/scene")];
        assert!(matches!(scene, AttributeValue::Text(t) if *t == *"/\\u{5834}\\u{9762}.usda"), "{scene:?}");
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
