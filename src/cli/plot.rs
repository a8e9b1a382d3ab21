//! SVG charts for `strata bench charts --plot DIR` (plotters, SVG backend only).
//!
//! plotters is built without its font features: text is laid out with its naive metrics and
//! written as SVG `<text>` elements that the viewer renders, so drawing needs no font file, no
//! system font and no network. Every chart has a caption block under the plot area: the
//! figures docs/PERFORMANCE.md quotes (ratios at equal time and equal error) are printed into the SVG
//! itself, so a chart and its numbers cannot drift apart.

use plotters::prelude::*;
use std::path::Path;

/// One curve of a chart: points in data coordinates.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// (x, y) points, drawn in order.
    pub points: Vec<(f64, f64)>,
    /// Index into the chart palette.
    pub color: usize,
    /// Dashed line (the second method of a pair).
    pub dashed: bool,
}

/// A bar of a bar chart: group label, bar label, value, palette index.
#[derive(Clone, Debug)]
pub struct Bar {
    /// The group the bar belongs to (shown under the x axis).
    pub group: String,
    /// The bar's own label (legend).
    pub label: String,
    /// The value (drawn on a log axis, so > 0).
    pub value: f64,
    /// Index into the chart palette.
    pub color: usize,
}

/// Chart size in pixels (SVG user units).
const WIDTH: u32 = 900;
/// Height of the plot area; the caption adds [`CAPTION_LINE`] per line.
const PLOT_HEIGHT: u32 = 520;
const CAPTION_LINE: u32 = 18;

fn palette(i: usize) -> RGBColor {
    const COLORS: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(148, 103, 189),
        RGBColor(255, 127, 14),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(23, 190, 207),
    ];
    COLORS[i % COLORS.len()]
}

fn err(path: &Path, e: impl std::fmt::Display) -> String {
    format!("cannot draw {}: {e}", path.display())
}

/// Range of positive values with a margin of a fraction of a decade on each side (log axes).
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for v in values.filter(|v| v.is_finite() && *v > 0.0) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi > 0.0) {
        return 1.0..10.0;
    }
    if hi <= lo * 1.5 {
        (lo, hi) = (lo / 1.5, hi * 1.5);
    }
    lo / 1.25..hi * 1.25
}

/// Tick label of a log axis: short and exact enough to read.
fn tick(v: &f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.0e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.3}").trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').to_string()
    }
}

/// Draws the caption lines under the plot.
fn draw_caption<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    caption: &[String],
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    for (i, line) in caption.iter().enumerate() {
        area.draw(&Text::new(line.clone(), (20, 4 + (i as u32 * CAPTION_LINE) as i32), ("sans-serif", 14).into_font()))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// A log–log line chart with points marked, a legend and a caption.
pub fn loglog(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    caption: &[String],
) -> Result<(), String> {
    let height = PLOT_HEIGHT + CAPTION_LINE * caption.len() as u32 + 10;
    let root = SVGBackend::new(path, (WIDTH, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (top, bottom) = root.split_vertically(PLOT_HEIGHT);
    let xs = log_range(series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
    let ys = log_range(series.iter().flat_map(|s| s.points.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(&top)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(xs.log_scale(), ys.log_scale())
        .map_err(|e| err(path, e))?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 15))
        .draw()
        .map_err(|e| err(path, e))?;
    for s in series {
        let color = palette(s.color);
        let style = ShapeStyle::from(&color).stroke_width(2);
        let points: Vec<(f64, f64)> =
            s.points.iter().copied().filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite()).collect();
        let anno = if s.dashed {
            chart.draw_series(DashedLineSeries::new(points.clone(), 6, 4, style)).map_err(|e| err(path, e))?
        } else {
            chart.draw_series(LineSeries::new(points.clone(), style)).map_err(|e| err(path, e))?
        };
        let dashed = s.dashed;
        anno.label(s.label.clone()).legend(move |(x, y)| {
            let end = if dashed { x + 10 } else { x + 20 };
            PathElement::new(vec![(x, y), (end, y)], ShapeStyle::from(&color).stroke_width(2))
        });
        if dashed {
            chart
                .draw_series(points.iter().map(|&p| TriangleMarker::new(p, 4, ShapeStyle::from(&color).filled())))
                .map_err(|e| err(path, e))?;
        } else {
            chart
                .draw_series(points.iter().map(|&p| Circle::new(p, 3, ShapeStyle::from(&color).filled())))
                .map_err(|e| err(path, e))?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| err(path, e))?;
    draw_caption(&bottom, caption).map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))
}

/// A grouped bar chart on a log y axis, with a caption.
pub fn bars(path: &Path, title: &str, y_desc: &str, bars: &[Bar], caption: &[String]) -> Result<(), String> {
    let height = PLOT_HEIGHT + CAPTION_LINE * caption.len() as u32 + 10;
    let root = SVGBackend::new(path, (WIDTH, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (top, bottom) = root.split_vertically(PLOT_HEIGHT);
    let mut groups: Vec<&str> = Vec::new();
    for b in bars {
        if !groups.contains(&b.group.as_str()) {
            groups.push(&b.group);
        }
    }
    let per_group = groups.iter().map(|g| bars.iter().filter(|b| b.group == *g).count()).max().unwrap_or(1);
    // Room below the smallest bar (so it shows) and above the tallest (labels, legend).
    let ys = log_range(bars.iter().map(|b| b.value));
    let ys = ys.start / 3.0..ys.end * 6.0;
    let mut chart = ChartBuilder::on(&top)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(0.0..groups.len() as f64, ys.clone().log_scale())
        .map_err(|e| err(path, e))?;
    let group_label = |x: &f64| {
        let i = x.floor() as usize;
        if (x - x.floor() - 0.5).abs() < 1e-9 {
            groups.get(i).map_or(String::new(), |g| g.to_string())
        } else {
            String::new()
        }
    };
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(2 * groups.len() + 1)
        .x_label_formatter(&group_label)
        .y_label_formatter(&tick)
        .y_desc(y_desc)
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 15))
        .draw()
        .map_err(|e| err(path, e))?;
    let width = 0.8 / per_group as f64;
    let mut labelled: Vec<String> = Vec::new();
    for (g, group) in groups.iter().enumerate() {
        for (k, b) in bars.iter().filter(|b| b.group == *group).enumerate() {
            let x0 = g as f64 + 0.1 + k as f64 * width;
            let color = palette(b.color);
            let rect = Rectangle::new([(x0, ys.start), (x0 + width * 0.9, b.value)], color.filled());
            let anno = chart.draw_series(std::iter::once(rect)).map_err(|e| err(path, e))?;
            if !labelled.contains(&b.label) {
                labelled.push(b.label.clone());
                anno.label(b.label.clone())
                    .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], color.filled()));
            }
            chart
                .draw_series(std::iter::once(Text::new(
                    format!("{:.1}", b.value),
                    (x0, b.value * 1.15),
                    ("sans-serif", 12).into_font(),
                )))
                .map_err(|e| err(path, e))?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| err(path, e))?;
    draw_caption(&bottom, caption).map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))
}

/// Ratios between two error-vs-time curves A and B: (equal-time error ratio A/B, equal-error
/// time ratio A/B, how they were found).
///
/// Where the curves overlap in time (error), each is interpolated linearly in log–log space at
/// nine points spread over the overlap and the ratios' geometric mean is taken. Without overlap, each curve is summarised by its
/// efficiency `t · e²` (the constant of unbiased Monte Carlo, `e ∝ t^-1/2`), geometric mean
/// over its points: then error ratio = sqrt(time ratio).
pub fn equal_ratios(a: &[(f64, f64)], b: &[(f64, f64)]) -> Option<(f64, f64, &'static str)> {
    let clean = |c: &[(f64, f64)]| -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> =
            c.iter().copied().filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite()).collect();
        v.sort_by(|p, q| p.0.total_cmp(&q.0));
        v
    };
    let (a, b) = (clean(a), clean(b));
    if a.is_empty() || b.is_empty() {
        return None;
    }
    let at_time = |c: &[(f64, f64)], t: f64| interp_loglog(c.iter().map(|p| (p.0, p.1)), t);
    let at_error = |c: &[(f64, f64)], e: f64| interp_loglog(c.iter().map(|p| (p.1, p.0)), e);
    // Nine points spread evenly (in log) over the overlap; the log ratios are averaged, so one
    // noisy measurement moves the result less than a single interpolation would.
    let overlap = |f: fn(&(f64, f64)) -> f64| {
        let lo = a.iter().map(f).fold(f64::INFINITY, f64::min).max(b.iter().map(f).fold(f64::INFINITY, f64::min));
        let hi = a.iter().map(f).fold(0.0, f64::max).min(b.iter().map(f).fold(0.0, f64::max));
        (hi > lo).then(|| (0..9).map(move |i| (lo.ln() + (hi.ln() - lo.ln()) * i as f64 / 8.0).exp()))
    };
    let mean_log_ratio = |xs: &mut dyn Iterator<Item = f64>, at: &Lookup| {
        let (mut sum, mut n) = (0.0, 0);
        for x in xs {
            if let (Some(ya), Some(yb)) = (at(&a, x), at(&b, x)) {
                sum += (ya / yb).ln();
                n += 1;
            }
        }
        (n > 0).then(|| (sum / n as f64).exp())
    };
    if let (Some(mut ts), Some(mut es)) = (overlap(|p| p.0), overlap(|p| p.1))
        && let (Some(e), Some(t)) = (mean_log_ratio(&mut ts, &at_time), mean_log_ratio(&mut es, &at_error))
    {
        return Some((e, t, "interpolated"));
    }
    let efficiency = |c: &[(f64, f64)]| (c.iter().map(|p| (p.0 * p.1 * p.1).ln()).sum::<f64>() / c.len() as f64).exp();
    let r = efficiency(&a) / efficiency(&b);
    Some((r.sqrt(), r, "from t*e^2"))
}

/// A curve's y at an x (`None` outside its range).
type Lookup = dyn Fn(&[(f64, f64)], f64) -> Option<f64>;

/// Linear interpolation in log–log space of y at x over points that may be in any order along
/// x (sorted here); `None` outside their range.
fn interp_loglog(points: impl Iterator<Item = (f64, f64)>, x: f64) -> Option<f64> {
    let mut p: Vec<(f64, f64)> = points.collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    for w in p.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        if x0 <= x && x <= x1 {
            if x1 <= x0 {
                return Some(y0);
            }
            let f = (x.ln() - x0.ln()) / (x1.ln() - x0.ln());
            return Some((y0.ln() + f * (y1.ln() - y0.ln())).exp());
        }
    }
    p.iter().find(|q| q.0 == x).map(|q| q.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratios_of_monte_carlo_curves() {
        // B needs 4x the time of A for the same error: e = sqrt(k / t).
        let curve = |k: f64| (0..6).map(|i| 2f64.powi(i)).map(|t| (t, (k / t).sqrt())).collect::<Vec<_>>();
        let (a, b) = (curve(1.0), curve(4.0));
        let (e, t, _) = equal_ratios(&a, &b).unwrap();
        assert!((e - 0.5).abs() < 1e-9 && (t - 0.25).abs() < 1e-9, "{e} {t}");
        // No overlap in time: the efficiency fallback gives the same answer.
        let far: Vec<_> = b.iter().map(|p| (p.0 * 1000.0, (4.0 / (p.0 * 1000.0)).sqrt())).collect();
        let (e, t, how) = equal_ratios(&a, &far).unwrap();
        assert_eq!(how, "from t*e^2");
        assert!((e - 0.5).abs() < 1e-9 && (t - 0.25).abs() < 1e-9, "{e} {t}");
    }

    /// The contents of every `<text>` element, trimmed.
    fn svg_texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| Some(t.split_once('>')?.1.split_once("</text>")?.0.trim().to_string()))
            .collect()
    }

    #[test]
    fn svg_has_axis_labels_without_fonts() {
        let dir = std::env::temp_dir().join(format!("strata-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.svg");
        let s = Series { label: "curve".into(), points: vec![(1.0, 1.0), (10.0, 0.3)], color: 0, dashed: false };
        loglog(&path, "title", "time (ms)", "RMSE", &[s], &["caption line".into()]).unwrap();
        let texts = svg_texts(&std::fs::read_to_string(&path).unwrap());
        for text in ["time (ms)", "RMSE", "title", "caption line", "curve", "10"] {
            assert!(texts.iter().any(|t| t == text), "{text} missing from the SVG's text: {texts:?}");
        }
        let b = Bar { group: "g".into(), label: "JIT".into(), value: 40.0, color: 0 };
        bars(&path, "bars", "ns", &[b], &[]).unwrap();
        let texts = svg_texts(&std::fs::read_to_string(&path).unwrap());
        assert!(texts.iter().any(|t| t == "JIT") && texts.iter().any(|t| t == "g"), "{texts:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
