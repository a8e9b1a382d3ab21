//! Partial images: one split of a render (a region of its pixels over a range of each
//! pixel's samples) in a file that merges, with the other splits, into the image one run
//! writes, bit for bit.
//!
//! A partial file is an ordinary single-part EXR. Its data window is the split's region and
//! its display window the whole image, and it holds two sets of channels:
//! - the viewable channels a render writes (`R G B A …`, Cryptomatte, custom channels),
//!   averaged over the split's samples, so the file opens in any viewer;
//! - what merging needs exactly, under `strata.sum.`: each [`ExactSum`] as four 32-bit UINT
//!   limbs (`strata.sum.R.0` … `.3`, least significant first, two's complement), the sample
//!   and hit counts, the nearest hit's depth (Z merges as the minimum), the sample nearest the
//!   pixel centre (integer channels keep its value), and each pixel's Cryptomatte coverage
//!   list (`strata.sum.object.K.index`, index + 1 with 0 for none, and its sum's limbs), so
//!   the merged ranks are ranked again from the exact coverage of all samples.
//!
//! The header names the split (`strata/split/*`): the fingerprint of the scene and settings
//! ([`Split::fingerprint`]), the whole image's size and samples per pixel, the region, the
//! sample range, and the layout (custom channels and the Cryptomatte IDs the sums name). The
//! other attributes are those of the single run's EXR; [`merge`] writes them back unchanged.
//!
//! Invariants: parts of one fingerprint whose (region × samples) boxes are disjoint and cover
//! the image's pixels × `0..spp` merge, in any order, into the image a single run renders
//! (exact integer sums, associative); anything else is refused with the parts named.

use super::output::{ExrFile, ExrOptions, OutputError, read_exr, standard_attributes, write_exr_with};
use super::sum::{ExactSum, PixelSums, WindowSums};
use super::{Channel, ChannelData, Image, Region, SumsLayout, image_from_layout};
use crate::abi::ChannelKind;
use exr::meta::attribute::{AttributeValue, Text};
use exr::prelude::FlatSamples;
use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

/// The prefix of the exact channels.
const SUM: &str = "strata.sum.";

/// The prefix of the header attributes that describe the split.
const SPLIT: &str = "strata/split/";

/// The builtin sums, in [`PixelSums::builtin`]'s order.
const BUILTIN_SUMS: [&str; 13] =
    ["R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.R", "N.G", "N.B", "P.R", "P.G", "P.B"];

/// 32-bit limbs of one [`ExactSum`].
const LIMBS: usize = 4;

/// Which part of which render a partial file holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Split {
    /// Identifies the scene and every setting that changes pixels (not the split): parts
    /// merge only with parts of the same fingerprint.
    pub fingerprint: String,
    /// The whole image's width.
    pub width: usize,
    /// The whole image's height.
    pub height: usize,
    /// The whole image's samples per pixel.
    pub spp: u32,
    /// The pixels of this part.
    pub region: Region,
    /// The samples of this part.
    pub samples: Range<u32>,
}

impl Split {
    /// The header attributes naming the split (also the EXR header record of a split render).
    pub fn attributes(&self) -> Vec<(String, String)> {
        let r = self.region;
        vec![
            (format!("{SPLIT}fingerprint"), self.fingerprint.clone()),
            (format!("{SPLIT}image"), format!("{}x{}", self.width, self.height)),
            (format!("{SPLIT}spp"), self.spp.to_string()),
            (format!("{SPLIT}region"), format!("{},{},{},{}", r.x, r.y, r.width, r.height)),
            (format!("{SPLIT}samples"), format!("{}..{}", self.samples.start, self.samples.end)),
        ]
    }

    /// Pixel samples this part holds.
    fn volume(&self) -> u64 {
        self.region.width as u64 * self.region.height as u64 * self.samples.len() as u64
    }

    /// Whether both parts hold some sample of some pixel.
    fn overlaps(&self, other: &Split) -> bool {
        let (a, b) = (self.region, other.region);
        a.x < b.x + b.width
            && b.x < a.x + a.width
            && a.y < b.y + b.height
            && b.y < a.y + a.height
            && self.samples.start < other.samples.end
            && other.samples.start < self.samples.end
    }
}

/// A partial file read back.
#[derive(Clone, Debug)]
pub struct Partial {
    /// The file it was read from (for messages).
    pub path: PathBuf,
    /// Which part of which render it holds.
    pub split: Split,
    /// The custom channels and the Cryptomatte IDs the sums name.
    pub layout: SumsLayout,
    /// The exact sums of its pixels.
    pub sums: WindowSums,
    /// The single run's header: what [`merge`] writes with the merged image.
    pub options: ExrOptions,
}

/// Writes the partial file of `split` at `path` (whole or not at all): `image` is the
/// window's viewable image, `sums` its exact sums, `options` the single run's header.
pub fn write_partial(
    path: &Path,
    image: &Image,
    sums: &WindowSums,
    layout: &SumsLayout,
    split: &Split,
    options: &ExrOptions,
) -> Result<(), OutputError> {
    let r = split.region;
    if sums.region != r || sums.pixels.len() != r.width * r.height || (image.width, image.height) != (r.width, r.height)
    {
        return Err(OutputError { path: path.to_path_buf(), message: "the sums are not the split's pixels".into() });
    }
    let mut file = image.clone();
    file.channels.extend(sum_channels(sums));
    let mut options = options.clone();
    options.placement = Some(((r.x, r.y), (split.width, split.height)));
    options.strings.extend(split.attributes());
    options.strings.push((format!("{SPLIT}layout"), layout_json(layout, sums)));
    write_exr_with(&file, path, &options)
}

/// The exact channels of `sums` (see the module documentation).
fn sum_channels(sums: &WindowSums) -> Vec<Channel> {
    let px = &sums.pixels;
    let u32s = |name: &str, f: &dyn Fn(&PixelSums) -> u32| Channel {
        name: format!("{SUM}{name}"),
        data: ChannelData::U32(px.iter().map(f).collect()),
    };
    let f32s = |name: &str, f: &dyn Fn(&PixelSums) -> f32| Channel {
        name: format!("{SUM}{name}"),
        data: ChannelData::F32(px.iter().map(f).collect()),
    };
    let limbs = |name: &str, f: &dyn Fn(&PixelSums) -> ExactSum| -> Vec<Channel> {
        (0..LIMBS).map(|k| u32s(&format!("{name}.{k}"), &|p| limb(f(p), k))).collect()
    };
    let mut out = vec![
        u32s("samples", &|p| p.samples),
        u32s("hits", &|p| p.hits),
        f32s("depth", &|p| p.depth),
        f32s("nearest.distance", &|p| p.nearest.0),
        u32s("nearest.sample", &|p| p.nearest.1),
    ];
    for (k, name) in BUILTIN_SUMS.iter().enumerate() {
        out.extend(limbs(name, &|p| p.builtin[k]));
    }
    for k in 0..sums.integer.len() {
        out.extend(limbs(&format!("channel{k}"), &|p| p.channels.get(k).copied().unwrap_or_default()));
    }
    for (layer, list) in [("object", 0), ("material", 1)] {
        let coverage = |p: &PixelSums| if list == 0 { p.objects.clone() } else { p.materials.clone() };
        let most = px.iter().map(|p| coverage(p).len()).max().unwrap_or(0);
        for j in 0..most {
            let entry = |p: &PixelSums| coverage(p).get(j).copied();
            out.push(u32s(&format!("{layer}.{j}.index"), &|p| entry(p).map_or(0, |(i, _)| i + 1)));
            out.extend(limbs(&format!("{layer}.{j}"), &|p| entry(p).map_or(ExactSum::default(), |(_, s)| s)));
        }
    }
    out
}

fn limb(sum: ExactSum, k: usize) -> u32 {
    (sum.to_bits() as u128 >> (32 * k)) as u32
}

/// The layout as the header's JSON: the custom channels, and the ID of every object and
/// material index the sums name.
fn layout_json(layout: &SumsLayout, sums: &WindowSums) -> String {
    let named = |ids: &[f32], material: bool| -> BTreeMap<String, String> {
        let mut used: Vec<u32> = sums
            .pixels
            .iter()
            .flat_map(|p| if material { &p.materials } else { &p.objects })
            .map(|(i, _)| *i)
            .collect();
        used.sort_unstable();
        used.dedup();
        used.into_iter()
            .map(|i| (i.to_string(), format!("{:08x}", ids.get(i as usize).copied().unwrap_or(0.0).to_bits())))
            .collect()
    };
    let channels: Vec<(String, &str)> = layout.channels.iter().map(|(n, k)| (n.clone(), kind_name(*k))).collect();
    serde_json::json!({
        "channels": channels,
        "objects": named(&layout.object_ids, false),
        "materials": layout.material_ids.as_ref().map(|ids| named(ids, true)),
    })
    .to_string()
}

fn kind_name(kind: ChannelKind) -> &'static str {
    match kind {
        ChannelKind::Color => "color",
        ChannelKind::Float => "float",
        ChannelKind::Integer => "integer",
    }
}

/// Parses [`layout_json`]'s text.
fn parse_layout(text: &str) -> Result<SumsLayout, String> {
    let json: serde_json::Value = serde_json::from_str(text).map_err(|e| format!("bad layout attribute: {e}"))?;
    let mut channels = Vec::new();
    for c in json["channels"].as_array().ok_or("the layout lists no channels")? {
        let (Some(name), Some(kind)) = (c[0].as_str(), c[1].as_str()) else {
            return Err(format!("bad channel in the layout: {c}"));
        };
        let kind = match kind {
            "color" => ChannelKind::Color,
            "float" => ChannelKind::Float,
            "integer" => ChannelKind::Integer,
            other => return Err(format!("unknown channel kind `{other}`")),
        };
        channels.push((name.to_string(), kind));
    }
    let ids = |value: &serde_json::Value| -> Result<Vec<f32>, String> {
        let mut ids = Vec::new();
        for (index, bits) in value.as_object().ok_or("bad ID table in the layout")? {
            let index: usize = index.parse().map_err(|_| format!("bad ID index `{index}`"))?;
            let bits = bits.as_str().and_then(|b| u32::from_str_radix(b, 16).ok()).ok_or("bad ID in the layout")?;
            if index >= 1 << 24 {
                return Err(format!("ID index {index} is out of range"));
            }
            if ids.len() <= index {
                ids.resize(index + 1, 0.0);
            }
            ids[index] = f32::from_bits(bits);
        }
        Ok(ids)
    };
    let material_ids = if json["materials"].is_null() { None } else { Some(ids(&json["materials"])?) };
    Ok(SumsLayout { channels, object_ids: ids(&json["objects"])?, material_ids })
}

/// Per coverage-list entry, the channel of indices and the four of the sum's limbs.
type CoverageColumns<'a> = Vec<(&'a [u32], Vec<&'a [u32]>)>;

/// Reads a partial file written by [`write_partial`].
pub fn read_partial(path: &Path) -> Result<Partial, String> {
    let fail = |message: String| format!("`{}`: {message}", path.display());
    let image = read_exr(path).map_err(|e| fail(format!("not a readable EXR: {e}")))?;
    let layer = &image.layer_data;
    let text = |key: &str| -> Option<String> {
        match layer.attributes.other.get(&Text::from(key)).or_else(|| image.attributes.other.get(&Text::from(key))) {
            Some(AttributeValue::Text(t)) => Some(t.to_string()),
            _ => None,
        }
    };
    let split_text = |name: &str| {
        text(&format!("{SPLIT}{name}"))
            .ok_or_else(|| fail(format!("not a strata partial file (no `{SPLIT}{name}` attribute)")))
    };
    let bad = |name: &str, value: &str| fail(format!("bad `{SPLIT}{name}` attribute `{value}`"));
    let numbers = |name: &str, separator: &str| -> Result<Vec<u64>, String> {
        let value = split_text(name)?;
        value.split(separator).map(|n| n.trim().parse::<u64>().map_err(|_| bad(name, &value))).collect()
    };
    let (size, spp, region, samples) =
        (numbers("image", "x")?, numbers("spp", ",")?, numbers("region", ",")?, numbers("samples", "..")?);
    let ([w, h], [spp], [x, y, rw, rh], [s0, s1]) =
        (size.as_slice(), spp.as_slice(), region.as_slice(), samples.as_slice())
    else {
        return Err(fail("malformed split attributes".into()));
    };
    let as_usize = |n: u64| usize::try_from(n).unwrap_or(usize::MAX);
    let as_u32 = |n: u64| u32::try_from(n).unwrap_or(u32::MAX);
    let split = Split {
        fingerprint: split_text("fingerprint")?,
        width: as_usize(*w),
        height: as_usize(*h),
        spp: as_u32(*spp),
        region: Region { x: as_usize(*x), y: as_usize(*y), width: as_usize(*rw), height: as_usize(*rh) },
        samples: as_u32(*s0)..as_u32(*s1),
    };
    let r = split.region;
    let data_origin = layer.attributes.layer_position;
    if (layer.size.0, layer.size.1) != (r.width, r.height)
        || (data_origin.0 as i64, data_origin.1 as i64) != (r.x as i64, r.y as i64)
        || r.x + r.width > split.width
        || r.y + r.height > split.height
        || split.samples.is_empty()
        || split.samples.end > split.spp
    {
        return Err(fail(format!(
            "its region {}x{} at ({}, {}) over samples {}..{} does not fit its data window or its {}x{} image at {} spp",
            r.width, r.height, r.x, r.y, split.samples.start, split.samples.end, split.width, split.height, split.spp
        )));
    }
    let layout = parse_layout(&split_text("layout")?).map_err(fail)?;
    let channels = &layer.channel_data.list;
    let find = |name: &str| channels.iter().find(|c| c.name.to_string() == format!("{SUM}{name}"));
    let u32s = |name: &str| -> Result<&[u32], String> {
        match find(name).map(|c| &c.sample_data) {
            Some(FlatSamples::U32(v)) => Ok(v.as_slice()),
            _ => Err(fail(format!("no UINT channel `{SUM}{name}`"))),
        }
    };
    let f32s = |name: &str| -> Result<&[f32], String> {
        match find(name).map(|c| &c.sample_data) {
            Some(FlatSamples::F32(v)) => Ok(v.as_slice()),
            _ => Err(fail(format!("no FLOAT channel `{SUM}{name}`"))),
        }
    };
    let limbs =
        |name: &str| -> Result<Vec<&[u32]>, String> { (0..LIMBS).map(|k| u32s(&format!("{name}.{k}"))).collect() };
    let sum_at = |limbs: &[&[u32]], i: usize| {
        ExactSum::from_bits(
            limbs.iter().enumerate().fold(0u128, |acc, (k, l)| acc | (u128::from(l[i]) << (32 * k))) as i128
        )
    };
    let (counts, hits, depth) = (u32s("samples")?, u32s("hits")?, f32s("depth")?);
    let (distance, nearest_sample) = (f32s("nearest.distance")?, u32s("nearest.sample")?);
    let builtin: Vec<Vec<&[u32]>> = BUILTIN_SUMS.iter().map(|n| limbs(n)).collect::<Result<_, _>>()?;
    let integer = layout.integer();
    let custom: Vec<Vec<&[u32]>> =
        (0..integer.len()).map(|k| limbs(&format!("channel{k}"))).collect::<Result<_, _>>()?;
    let coverage_lists = |layer: &str| -> Result<CoverageColumns, String> {
        let mut lists = Vec::new();
        while find(&format!("{layer}.{}.index", lists.len())).is_some() {
            let j = lists.len();
            lists.push((u32s(&format!("{layer}.{j}.index"))?, limbs(&format!("{layer}.{j}"))?));
        }
        Ok(lists)
    };
    let (objects, materials) = (coverage_lists("object")?, coverage_lists("material")?);
    let pixels = (0..r.width * r.height)
        .map(|i| {
            let coverage = |lists: &CoverageColumns| -> Vec<(u32, ExactSum)> {
                lists.iter().filter(|(index, _)| index[i] > 0).map(|(index, l)| (index[i] - 1, sum_at(l, i))).collect()
            };
            PixelSums {
                samples: counts[i],
                builtin: std::array::from_fn(|k| sum_at(&builtin[k], i)),
                hits: hits[i],
                depth: depth[i],
                nearest: (distance[i], nearest_sample[i]),
                channels: custom.iter().map(|l| sum_at(l, i)).collect(),
                objects: coverage(&objects),
                materials: coverage(&materials),
            }
        })
        .collect();
    let sums = WindowSums { region: r, samples: vec![split.samples.clone()], pixels, integer };
    let options = single_run_options(&image, &text);
    Ok(Partial { path: path.to_path_buf(), split, layout, sums, options })
}

/// The header of the single run's EXR, recovered from a partial file's: the attributes the
/// writer adds itself and the split's are left out; `--half` shows in `R`'s sample type.
fn single_run_options(image: &ExrFile, text: &dyn Fn(&str) -> Option<String>) -> ExrOptions {
    let layer = &image.layer_data;
    let standard: Vec<&str> = standard_attributes().iter().map(|(k, _)| *k).collect();
    let mut strings: Vec<(String, String)> = layer
        .attributes
        .other
        .keys()
        .chain(image.attributes.other.keys())
        .map(|k| k.to_string())
        .filter(|k| !k.starts_with(SPLIT) && !standard.contains(&k.as_str()))
        .filter_map(|k| text(&k).map(|v| (k, v)))
        .collect();
    strings.sort();
    let half = layer
        .channel_data
        .list
        .iter()
        .any(|c| c.name.to_string() == "R" && matches!(c.sample_data, FlatSamples::F16(_)));
    let a = &layer.attributes;
    ExrOptions {
        half,
        world_to_camera: a.world_to_camera.map(|m| glam::Mat4::from_cols_array(&m)),
        world_to_ndc: a.world_to_normalized_device.map(|m| glam::Mat4::from_cols_array(&m)),
        clipping: a.near_clip_plane.map(|near| (near, a.far_clip_plane.unwrap_or(f32::INFINITY))),
        strings,
        placement: None,
    }
}

/// The fingerprint of a split render: `scene` (the session's [`crate::session::Session::fingerprint`]
/// of the scene and settings) with the single run's header, so parts of renders that would
/// write different files never merge. Compared between processes of the same strata build.
pub fn split_fingerprint(scene: u64, options: &ExrOptions) -> String {
    use std::hash::{DefaultHasher, Hash, Hasher};
    // `DefaultHasher::new()` has fixed keys: the same build hashes the same everywhere.
    let mut hasher = DefaultHasher::new();
    env!("CARGO_PKG_VERSION").hash(&mut hasher);
    scene.hash(&mut hasher);
    let mut strings = options.strings.clone();
    strings.sort();
    strings.hash(&mut hasher);
    options.half.hash(&mut hasher);
    format!("{:?}{:?}{:?}", options.world_to_camera, options.world_to_ndc, options.clipping).hash(&mut hasher);
    format!("{:016x}", hasher.finish())
}

/// Parts merged into the whole image.
#[derive(Clone, Debug)]
pub struct Merged {
    /// The image a single run renders.
    pub image: Image,
    /// The single run's header.
    pub options: ExrOptions,
    /// The merged sums (all pixels, all samples).
    pub sums: WindowSums,
}

/// Merges `parts` into the image a single run of their render writes, bit for bit, or says
/// why they do not make one image: no parts, different fingerprints (scene or settings),
/// overlapping parts, or missing pixel samples.
pub fn merge(parts: &[Partial]) -> Result<Merged, String> {
    let first = parts.first().ok_or("no parts to merge")?;
    let whole = &first.split;
    let mut layout = first.layout.clone();
    for part in parts {
        let s = &part.split;
        if s.fingerprint != whole.fingerprint || (s.width, s.height, s.spp) != (whole.width, whole.height, whole.spp) {
            return Err(format!(
                "`{}` and `{}` are parts of different renders (another scene or other settings: fingerprints {} and {})",
                first.path.display(),
                part.path.display(),
                whole.fingerprint,
                s.fingerprint
            ));
        }
        if part.layout.channels != layout.channels
            || part.layout.material_ids.is_some() != layout.material_ids.is_some()
        {
            return Err(format!("`{}` has other channels than `{}`", part.path.display(), first.path.display()));
        }
        join_ids(&mut layout.object_ids, &part.layout.object_ids)
            .map_err(|index| format!("`{}` names object {index} with another ID", part.path.display()))?;
        if let (Some(ids), Some(more)) = (layout.material_ids.as_mut(), part.layout.material_ids.as_ref()) {
            join_ids(ids, more)
                .map_err(|index| format!("`{}` names material {index} with another ID", part.path.display()))?;
        }
    }
    for (i, a) in parts.iter().enumerate() {
        if let Some(b) = parts[i + 1..].iter().find(|b| a.split.overlaps(&b.split)) {
            return Err(format!(
                "`{}` and `{}` overlap: both render some samples of some pixels ({} and {})",
                a.path.display(),
                b.path.display(),
                describe(&a.split),
                describe(&b.split)
            ));
        }
    }
    let (w, h, spp) = (whole.width, whole.height, whole.spp);
    let volume: u64 = parts.iter().map(|p| p.split.volume()).sum();
    if volume != w as u64 * h as u64 * u64::from(spp) {
        // Disjoint parts: some pixel has fewer samples than `spp`. Name the first.
        let mut covered = vec![0u32; w * h];
        for p in parts {
            let r = p.split.region;
            for y in r.y..r.y + r.height {
                for c in &mut covered[y * w + r.x..y * w + r.x + r.width] {
                    *c += p.split.samples.len() as u32;
                }
            }
        }
        let missing = covered.iter().position(|&c| c != spp).unwrap_or(0);
        return Err(format!(
            "the parts do not cover the {w}x{h} image at {spp} spp: pixel ({}, {}) has {} of its samples \
             ({} of {} pixel samples in all)",
            missing % w,
            missing / w,
            covered.get(missing).copied().unwrap_or(0),
            volume,
            w as u64 * h as u64 * u64::from(spp)
        ));
    }
    let integer = layout.integer();
    let mut pixels = vec![PixelSums::default(); w * h];
    pixels.iter_mut().for_each(|p| p.reset(integer.len()));
    for part in parts {
        let r = part.split.region;
        for (i, px) in part.sums.pixels.iter().enumerate() {
            pixels[(r.y + i / r.width) * w + r.x + i % r.width].merge(px, &integer);
        }
    }
    let region = Region { x: 0, y: 0, width: w, height: h };
    let sums = WindowSums { region, samples: std::iter::once(0..spp).collect(), pixels, integer };
    let image = image_from_layout(&layout, &sums);
    Ok(Merged { image, options: first.options.clone(), sums })
}

/// Adds `more`'s IDs to `ids`; `Err(index)` where both name an index with different IDs.
fn join_ids(ids: &mut Vec<f32>, more: &[f32]) -> Result<(), usize> {
    if ids.len() < more.len() {
        ids.resize(more.len(), 0.0);
    }
    for (index, (a, &b)) in ids.iter_mut().zip(more).enumerate() {
        if b.to_bits() == 0 {
            continue;
        }
        if a.to_bits() != 0 && a.to_bits() != b.to_bits() {
            return Err(index);
        }
        *a = b;
    }
    Ok(())
}

/// `region WxH at (X, Y), samples A..B`.
fn describe(s: &Split) -> String {
    let r = s.region;
    format!("region {}x{} at ({}, {}), samples {}..{}", r.width, r.height, r.x, r.y, s.samples.start, s.samples.end)
}
