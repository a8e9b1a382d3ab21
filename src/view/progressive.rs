//! Progressive accumulation: the image of `settings` rendered as bands of rows over growing
//! sample ranges (`0..1`, `1..2`, `2..4`, … up to `spp`), each band's exact sums merged
//! ([`WindowSums::merge`]), so the image after the last range is the one `strata render`
//! writes at that `spp`, bit for bit, however the work was cut.

use crate::render::{Channel, ChannelData, Image, Region, RenderSettings, Window, WindowSums};
use crate::session::{Pass, PassError, Session};
use std::ops::Range;

/// About this many camera samples per [`Accumulator::step`]: some tens of milliseconds on
/// two cores, the longest an edit waits for the pass in flight.
pub const SAMPLES_PER_STEP: usize = 40_000;

/// Rows per band (the last band may be shorter).
const BAND_ROWS: usize = 16;

/// The sample ranges of the progressive passes: `0..1`, `1..2`, `2..4`, `4..8`, …, ending at
/// `spp`. After range `k` the image holds `2^k` samples per pixel (or `spp`).
pub fn sample_ranges(spp: u32) -> Vec<Range<u32>> {
    let mut ranges = Vec::new();
    let mut start = 0;
    while start < spp {
        let end = if start == 0 { 1 } else { (start * 2).min(spp) };
        ranges.push(start..end);
        start = end;
    }
    ranges
}

/// One band of rows and the sums of its samples so far.
struct Band {
    region: Region,
    sums: Option<WindowSums>,
}

/// The progressive render of one image. See the module documentation.
pub struct Accumulator {
    settings: RenderSettings,
    ranges: Vec<Range<u32>>,
    bands: Vec<Band>,
    /// The range being rendered, the band within it, and the next sample of that band.
    range: usize,
    band: usize,
    next_sample: u32,
}

impl Accumulator {
    /// An accumulation of `settings`' image, nothing rendered yet.
    pub fn new(settings: RenderSettings) -> Accumulator {
        let bands = (0..settings.height)
            .step_by(BAND_ROWS)
            .map(|y| Band {
                region: Region { x: 0, y, width: settings.width, height: BAND_ROWS.min(settings.height - y) },
                sums: None,
            })
            .collect();
        let ranges = sample_ranges(settings.spp);
        let next_sample = ranges.first().map_or(0, |r| r.start);
        Accumulator { settings, ranges, bands, range: 0, band: 0, next_sample }
    }

    /// The settings being rendered.
    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }

    /// Whether every sample of every pixel is in.
    pub fn done(&self) -> bool {
        self.range >= self.ranges.len()
    }

    /// Samples per pixel of the image [`Accumulator::image`] makes now (every band has them).
    pub fn samples(&self) -> u32 {
        if self.range == 0 { 0 } else { self.ranges[self.range - 1].end }
    }

    /// Renders the next piece (one band over part of the current range); returns whether it
    /// completed a range, so that a new image with more samples is ready.
    pub fn step(&mut self, session: &mut Session) -> Result<bool, PassError> {
        let Some(range) = self.ranges.get(self.range).cloned() else { return Ok(false) };
        let band = &mut self.bands[self.band];
        let pixels = band.region.width * band.region.height;
        let count = (SAMPLES_PER_STEP / pixels.max(1)).clamp(1, u32::MAX as usize) as u32;
        let samples = self.next_sample..(self.next_sample.saturating_add(count)).min(range.end);
        let window = Window { region: Some(band.region), samples: Some(samples.clone()) };
        let pass = Pass { settings: self.settings.clone(), time: None, window };
        let (_, _, sums) = session.render_sums(&pass, None)?;
        match &mut band.sums {
            Some(all) => all.merge(&sums).map_err(|e| PassError::Render(crate::render::RenderError::BadSettings(e)))?,
            None => band.sums = Some(sums),
        }
        self.next_sample = samples.end;
        if self.next_sample < range.end {
            return Ok(false);
        }
        self.band += 1;
        self.next_sample = range.start;
        if self.band < self.bands.len() {
            return Ok(false);
        }
        self.band = 0;
        self.range += 1;
        self.next_sample = self.ranges.get(self.range).map_or(0, |r| r.start);
        Ok(true)
    }

    /// The image of the samples so far, the bands' images stacked top to bottom: after a
    /// [`Accumulator::step`] that completed a range every band holds [`Accumulator::samples`]
    /// samples per pixel. `None` before the first range completes.
    pub fn image(&self, session: &Session) -> Option<Result<Image, PassError>> {
        if self.range == 0 {
            return None;
        }
        let (width, height) = (self.settings.width, self.settings.height);
        let mut image: Option<Image> = None;
        for band in &self.bands {
            let sums = band.sums.as_ref()?;
            let part = match session.image_from_sums(sums) {
                Ok(part) => part,
                Err(e) => return Some(Err(e)),
            };
            match &mut image {
                None => image = Some(Image { width, height, channels: part.channels }),
                Some(image) => {
                    for (all, piece) in image.channels.iter_mut().zip(part.channels) {
                        append(all, piece);
                    }
                }
            }
        }
        image.map(Ok)
    }
}

/// Appends the rows of `piece` to `all` (the same channel of the band below).
fn append(all: &mut Channel, piece: Channel) {
    match (&mut all.data, piece.data) {
        (ChannelData::F32(a), ChannelData::F32(b)) => a.extend(b),
        (ChannelData::U32(a), ChannelData::U32(b)) => a.extend(b),
        // Bands of one scene have the same channels; nothing else can arrive here.
        _ => {}
    }
}
