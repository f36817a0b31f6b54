//! Distributions of per-image figures: histograms side by side (one panel per group, e.g. the
//! train, val and test splits, on shared bins) and a scatter plot of two figures coloured by
//! group (the paper's σ_d histograms, μ_d–σ_d scatter, trace and rmv histograms, trace–rmv
//! scatter).
//!
//! Layout, top to bottom: the title; for the scatter a legend row; the panels, each with a
//! caption (group, count, mean). Values that are not finite are left out and counted in the
//! caption. Axes whose values are all far from 1 (below 10⁻² or from 10⁴ on) are shown in units
//! of a power of ten named in the axis title (`normalised trace (×10⁻⁴)`). Sizes scale with the
//! image (reference design 1200 × 680 px), as the trajectory figure's do.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::axes::{Axes, AxesStyle, PixelRect};
use crate::palette::{self, Rgb};
use crate::render::{self, Canvas};
use crate::text::{self, Align, Text};
use crate::PlotError;

/// The smallest figure laid out legibly, pixels.
pub const MIN_SIZE: (u32, u32) = (480, 320);

/// The colour of group `i` in every distribution figure: the Okabe–Ito blue, orange, then
/// [`palette::CATEGORICAL`].
pub fn group_colour(i: usize) -> Rgb {
    match i {
        0 => palette::TRUE_TRACK,
        1 => palette::ESTIMATED,
        k => palette::CATEGORICAL[(k - 2) % palette::CATEGORICAL.len()],
    }
}

/// One group of values (a split's per-image figures).
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    pub label: String,
    pub values: Vec<f64>,
}

/// Histograms of the same quantity for several groups, one panel each, on bins shared by all.
#[derive(Debug, Clone, PartialEq)]
pub struct HistogramFigure {
    pub title: String,
    /// The quantity, with its unit if any (`σ_d`).
    pub x_title: String,
    /// What the bars count (`images`), on the first panel's axis.
    pub y_title: String,
    pub groups: Vec<Group>,
    /// Number of bins (at least 1) spanning the finite values of all groups.
    pub bins: usize,
}

/// One group of points of a scatter plot.
#[derive(Debug, Clone, PartialEq)]
pub struct PointGroup {
    pub label: String,
    /// `[x, y]` per point.
    pub points: Vec<[f64; 2]>,
}

/// A scatter plot of two quantities, one colour per group.
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterFigure {
    pub title: String,
    pub x_title: String,
    pub y_title: String,
    pub groups: Vec<PointGroup>,
}

/// The histogram figure as PNG bytes (`width × height` pixels).
pub fn histograms_png(fig: &HistogramFigure, width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    let layout = Layout::new(width, height)?;
    fig.check()?;
    render::render_png(width, height, |root| draw_histograms(root, fig, &layout))
}

/// The histogram figure as an SVG document.
pub fn histograms_svg(fig: &HistogramFigure, width: u32, height: u32) -> Result<String, PlotError> {
    let layout = Layout::new(width, height)?;
    fig.check()?;
    render::render_svg(width, height, |root| draw_histograms(root, fig, &layout))
}

/// The scatter figure as PNG bytes.
pub fn scatter_png(fig: &ScatterFigure, width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    let layout = Layout::new(width, height)?;
    render::render_png(width, height, |root| draw_scatter(root, fig, &layout))
}

/// The scatter figure as an SVG document.
pub fn scatter_svg(fig: &ScatterFigure, width: u32, height: u32) -> Result<String, PlotError> {
    let layout = Layout::new(width, height)?;
    render::render_svg(width, height, |root| draw_scatter(root, fig, &layout))
}

impl HistogramFigure {
    fn check(&self) -> Result<(), PlotError> {
        if self.bins == 0 || self.bins > 10_000 {
            return Err(PlotError::InvalidData(format!("histogram: {} bins, expected 1..=10000", self.bins)));
        }
        if self.groups.is_empty() {
            return Err(PlotError::InvalidData("histogram: no groups, expected at least one".into()));
        }
        Ok(())
    }
}

/// Sizes from the image size, as in the trajectory figure.
struct Layout {
    s: f64,
    width: i32,
    height: i32,
}

impl Layout {
    fn new(width: u32, height: u32) -> Result<Layout, PlotError> {
        render::check_size(width, height, MIN_SIZE)?;
        let s = (f64::from(width) / 1200.0).min(f64::from(height) / 680.0).max(0.75);
        Ok(Layout { s, width: width as i32, height: height as i32 })
    }

    fn px(&self, v: f64) -> i32 {
        (v * self.s).round() as i32
    }

    fn axes_style<'a>(&self, x_title: &'a str, y_title: &'a str, rect: &PixelRect) -> AxesStyle<'a> {
        AxesStyle {
            x_title,
            y_title,
            tick_size: 11.5 * self.s,
            title_size: 13.0 * self.s,
            tick_len: self.px(4.0).max(2),
            gap: self.px(4.0).max(2),
            x_title_offset: self.px(35.0),
            y_title_offset: self.px(50.0),
            max_x_ticks: (rect.width() / self.px(70.0).max(1)).clamp(2, 12) as usize,
            max_y_ticks: (rect.height() / self.px(42.0).max(1)).clamp(2, 12) as usize,
        }
    }

    fn title<DB: Canvas>(&self, root: &DrawingArea<DB, Shift>, title: &str) -> Result<(), PlotError> {
        let size = 19.0 * self.s;
        let room = f64::from(self.width - 2 * self.px(12.0));
        let size = size * (room / text::width(title, size)?.max(1.0)).min(1.0);
        Text::new(size, palette::INK).align(Align::Centre).draw(root, title, (self.width / 2, self.px(22.0)))
    }

    fn caption<DB: Canvas>(
        &self,
        root: &DrawingArea<DB, Shift>,
        variants: &[&str],
        plot: &PixelRect,
    ) -> Result<(), PlotError> {
        let size = 13.0 * self.s;
        let line = text::first_that_fits(variants, size, f64::from(plot.width()))?;
        Text::new(size, palette::INK).draw(root, line, (plot.x0, plot.y0 - self.px(13.0)))
    }
}

/// A power of ten to show `values` in: `(10^k, " (×10ᵏ)")`, or `(1, "")` when their largest
/// magnitude lies in [10⁻², 10⁴) or there is none.
fn display_scale(values: impl Iterator<Item = f64>) -> (f64, String) {
    let max = values.filter(|v| v.is_finite()).fold(0.0f64, |m, v| m.max(v.abs()));
    if max == 0.0 || (1e-2..1e4).contains(&max) {
        return (1.0, String::new());
    }
    let k = max.log10().floor() as i32;
    (10f64.powi(k), format!(" (×10{})", superscript(k)))
}

fn superscript(k: i32) -> String {
    k.to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            d => ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'][d.to_digit(10).unwrap_or(0) as usize],
        })
        .collect()
}

/// `[lo, hi]` around the finite values with a margin of `pad` of the span; a unit-wide window
/// around a single value; `[0, 1]` when there is none.
fn span(values: impl Iterator<Item = f64>, pad: f64) -> [f64; 2] {
    let (lo, hi) =
        values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return [0.0, 1.0];
    }
    let w = hi - lo;
    if w <= 1e-12 * lo.abs().max(1e-300) {
        let half = if lo == 0.0 { 0.5 } else { 0.05 * lo.abs() };
        return [lo - half, hi + half];
    }
    [lo - pad * w, hi + pad * w]
}

/// A short number for captions.
fn short(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

/// Caption variants of a group, longest first: label, count (and non-finite values), mean.
fn group_caption(label: &str, values: &[f64]) -> Vec<String> {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    let dropped = values.len() - finite.len();
    let mean = (!finite.is_empty()).then(|| finite.iter().sum::<f64>() / finite.len() as f64);
    let n = if dropped > 0 {
        format!("n = {} ({dropped} not finite)", finite.len())
    } else {
        format!("n = {}", finite.len())
    };
    let mut v = vec![];
    if let Some(m) = mean {
        v.push(format!("{label} · {n} · mean {}", short(m)));
    }
    v.push(format!("{label} · {n}"));
    v.push(format!("{label} · n = {}", finite.len()));
    v.push(label.to_string());
    v
}

fn draw_histograms<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    fig: &HistogramFigure,
    layout: &Layout,
) -> Result<(), PlotError> {
    layout.title(root, &fig.title)?;
    let all = || fig.groups.iter().flat_map(|g| g.values.iter().copied());
    let (unit, suffix) = display_scale(all());
    let x_title = format!("{}{suffix}", fig.x_title);
    let [lo, hi] = span(all().map(|v| v / unit), 0.0);
    let bin_w = (hi - lo) / fig.bins as f64;
    let n = fig.groups.len() as i32;
    let (left, right, gap) = (layout.px(70.0), layout.px(16.0), layout.px(40.0));
    let panel_w = (layout.width - left - right - (n - 1) * gap) / n;
    let (top, bottom) = (layout.px(50.0) + layout.px(26.0), layout.height - layout.px(58.0));
    for (k, g) in fig.groups.iter().enumerate() {
        let x0 = left + k as i32 * (panel_w + gap);
        let rect = PixelRect { x0, y0: top, x1: x0 + panel_w, y1: bottom };
        let mut counts = vec![0usize; fig.bins];
        for v in g.values.iter().map(|v| v / unit).filter(|v| v.is_finite()) {
            let b = (((v - lo) / bin_w).floor().max(0.0) as usize).min(fig.bins - 1);
            counts[b] += 1;
        }
        let peak = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
        // The bins span the values; the axes leave a little room either side.
        let pad = 0.02 * (hi - lo);
        let axes = Axes { rect, x: [lo - pad, hi + pad], y: [0.0, 1.08 * peak] };
        let mut style = layout.axes_style(&x_title, if k == 0 { fig.y_title.as_str() } else { "" }, &rect);
        // Counts are whole: no more ticks than 0..=peak, so that their step is at least 1.
        style.max_y_ticks = style.max_y_ticks.min(peak as usize + 1);
        axes.draw_grid(root, &style, palette::GRID)?;
        let colour = RGBColor::from(group_colour(k));
        for (b, &c) in counts.iter().enumerate().filter(|(_, &c)| c > 0) {
            let (bx0, by) = axes.map([lo + b as f64 * bin_w, c as f64]);
            let (bx1, base) = axes.map([lo + (b + 1) as f64 * bin_w, 0.0]);
            // A one-pixel white seam between neighbouring bars.
            let bx1 = if bx1 - bx0 >= 3 { bx1 - 1 } else { bx1 };
            root.draw(&Rectangle::new([(bx0, by), (bx1.max(bx0 + 1), base + 1)], colour.filled()))?;
        }
        axes.draw_frame(root, &style)?;
        let captions = group_caption(&g.label, &g.values);
        let variants: Vec<&str> = captions.iter().map(String::as_str).collect();
        layout.caption(root, &variants, &rect)?;
    }
    Ok(())
}

fn draw_scatter<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    fig: &ScatterFigure,
    layout: &Layout,
) -> Result<(), PlotError> {
    layout.title(root, &fig.title)?;
    let finite = |p: &&[f64; 2]| p[0].is_finite() && p[1].is_finite();
    let pts = || fig.groups.iter().flat_map(|g| g.points.iter().filter(finite));
    let (ux, sx) = display_scale(pts().map(|p| p[0]));
    let (uy, sy) = display_scale(pts().map(|p| p[1]));
    let (x_title, y_title) = (format!("{}{sx}", fig.x_title), format!("{}{sy}", fig.y_title));
    let x = span(pts().map(|p| p[0] / ux), 0.06);
    let y = span(pts().map(|p| p[1] / uy), 0.08);

    // Legend: one centred row of "● label (n)" entries.
    let legend_size = 12.0 * layout.s;
    let r = 5.0 * layout.s;
    let labels: Vec<String> = fig
        .groups
        .iter()
        .map(|g| {
            let n = g.points.iter().filter(finite).count();
            let bad = g.points.len() - n;
            if bad > 0 {
                format!("{} ({n}, {bad} not finite)", g.label)
            } else {
                format!("{} ({n})", g.label)
            }
        })
        .collect();
    let widths = labels.iter().map(|l| text::width(l, legend_size)).collect::<Result<Vec<_>, _>>()?;
    let entry = |w: f64| 2.0 * r + f64::from(layout.px(6.0)) + w + f64::from(layout.px(24.0));
    let total: f64 = widths.iter().map(|&w| entry(w)).sum();
    let mut cx = (f64::from(layout.width) - total).max(0.0) / 2.0;
    let ly = f64::from(layout.px(50.0)) + 0.5;
    for (k, (label, w)) in labels.iter().zip(&widths).enumerate() {
        crate::stroke::disc(root, [cx + r, ly], r, group_colour(k), Some((palette::WHITE, 0.8 * layout.s)))?;
        let tx = (cx + 2.0 * r) as i32 + layout.px(6.0);
        Text::new(legend_size, palette::INK_SOFT).draw(root, label, (tx, ly as i32))?;
        cx += entry(*w);
    }

    let rect = PixelRect {
        x0: layout.px(80.0),
        y0: layout.px(74.0),
        x1: layout.width - layout.px(24.0),
        y1: layout.height - layout.px(58.0),
    };
    let axes = Axes { rect, x, y };
    let style = layout.axes_style(&x_title, &y_title, &rect);
    axes.draw_grid(root, &style, palette::GRID)?;
    for (k, g) in fig.groups.iter().enumerate() {
        for p in g.points.iter().filter(finite) {
            let c = axes.map_f([p[0] / ux, p[1] / uy]);
            crate::stroke::disc(root, c, 3.5 * layout.s, group_colour(k), Some((palette::WHITE, 0.6 * layout.s)))?;
        }
    }
    axes.draw_frame(root, &style)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_scale_names_the_power_of_ten_only_far_from_one() {
        assert_eq!(display_scale([0.5, 2.0].into_iter()), (1.0, String::new()));
        let (u, s) = display_scale([3.2e-4, 1.0e-4].into_iter());
        assert!((u - 1e-4).abs() < 1e-18, "{u}");
        assert_eq!(s, " (×10⁻⁴)");
        assert_eq!(display_scale([f64::NAN].into_iter()).0, 1.0);
        assert_eq!(display_scale([2.0e5].into_iter()).1, " (×10⁵)");
    }

    #[test]
    fn span_pads_and_widens_a_single_value() {
        assert_eq!(span([1.0, 3.0].into_iter(), 0.0), [1.0, 3.0]);
        let [a, b] = span([2.0, 2.0].into_iter(), 0.1);
        assert!(a < 2.0 && b > 2.0);
        assert_eq!(span([f64::NAN].into_iter(), 0.1), [0.0, 1.0]);
    }
}
