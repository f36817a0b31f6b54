//! Heat maps of scalar fields on a regular grid: slices of a 3-D field, per-pixel maps of an
//! image. One or more panels side by side, each with its metre (or pixel) axes at equal aspect,
//! its own colour bar with labelled ticks, and a caption.
//!
//! Colour scales: sequential (a viridis-like ramp, dark = low) on a linear or a base-10 log
//! scale, or diverging (blue – white – red, symmetric about 0) for differences. Cells without a
//! value (NaN, and non-positive ones on a log scale) are drawn in [`palette::NO_DATA`].

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::axes::{Axes, AxesStyle, PixelRect};
use crate::palette::{self, Rgb};
use crate::render::{self, Canvas};
use crate::text::{Align, Text};
use crate::PlotError;

/// How values map to colours.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColourScale {
    /// Sequential, linear between the finite minimum and maximum.
    Linear,
    /// Sequential, linear in log10 between the positive minimum and maximum.
    Log,
    /// Diverging about 0, from −m to m with m the largest finite |value|.
    Diverging,
}

/// One panel: `values` on a `dims = [nx, ny]` grid, row by row (`x` fastest), the value of
/// column `i`, row `j` centred at `origin + (i·cell[0], j·cell[1])`. A negative `cell[1]` puts
/// row 0 at the top (an image).
#[derive(Debug, Clone, PartialEq)]
pub struct Heatmap {
    pub caption: String,
    pub x_title: String,
    pub y_title: String,
    /// What the colours show, with its unit.
    pub colour_title: String,
    pub origin: [f64; 2],
    pub cell: [f64; 2],
    pub dims: [usize; 2],
    pub values: Vec<f64>,
    pub scale: ColourScale,
}

/// Panels side by side under a title.
#[derive(Debug, Clone, PartialEq)]
pub struct HeatmapFigure {
    pub title: String,
    pub panels: Vec<Heatmap>,
}

/// The smallest figure, pixels.
const MIN_SIZE: (u32, u32) = (240, 200);

/// Stops of the sequential ramp (dark blue-purple → teal → yellow, as viridis).
const RAMP: [Rgb; 5] =
    [Rgb(0x44, 0x01, 0x54), Rgb(0x3b, 0x52, 0x8b), Rgb(0x21, 0x90, 0x8d), Rgb(0x5d, 0xc8, 0x63), Rgb(0xfd, 0xe7, 0x25)];
/// Ends and centre of the diverging ramp.
const COLD: Rgb = Rgb(0x21, 0x66, 0xac);
const WARM: Rgb = Rgb(0xb2, 0x18, 0x2b);

impl Heatmap {
    fn check(&self) -> Result<(), PlotError> {
        let bad = |what: String| Err(PlotError::InvalidData(format!("heat map \"{}\": {what}", self.caption)));
        if self.dims[0] == 0 || self.dims[1] == 0 {
            return bad(format!("dims {:?} must both be at least 1", self.dims));
        }
        if self.values.len() != self.dims[0] * self.dims[1] {
            return bad(format!("{} values for dims {:?}", self.values.len(), self.dims));
        }
        if !(self.cell[0].is_finite() && self.cell[0] > 0.0 && self.cell[1].is_finite() && self.cell[1] != 0.0) {
            return bad(format!("cell {:?} must be positive in x and non-zero in y", self.cell));
        }
        if !(self.origin[0].is_finite() && self.origin[1].is_finite()) {
            return bad(format!("origin {:?} must be finite", self.origin));
        }
        Ok(())
    }

    /// The value as the scale sees it (log10 on a log scale); `None` for no data.
    fn scaled(&self, v: f64) -> Option<f64> {
        match self.scale {
            ColourScale::Log => (v > 0.0 && v.is_finite()).then(|| v.log10()),
            _ => v.is_finite().then_some(v),
        }
    }

    /// The colour range in scaled units, widened when degenerate.
    fn range(&self) -> [f64; 2] {
        let (lo, hi) = self
            .values
            .iter()
            .filter_map(|&v| self.scaled(v))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
        if lo > hi {
            return [0.0, 1.0];
        }
        let [lo, hi] = match self.scale {
            ColourScale::Diverging => {
                let m = lo.abs().max(hi.abs());
                [-m, m]
            }
            _ => [lo, hi],
        };
        if hi - lo > 1e-12 * hi.abs().max(1.0) {
            [lo, hi]
        } else {
            let pad = 0.5 * lo.abs().max(1e-9);
            [lo - pad, hi + pad]
        }
    }

    /// The data window: the cells' outer edges.
    fn window(&self) -> ([f64; 2], [f64; 2]) {
        let edge = |o: f64, c: f64, n: usize| {
            let (a, b) = (o - 0.5 * c, o + (n as f64 - 0.5) * c);
            [a.min(b), a.max(b)]
        };
        (edge(self.origin[0], self.cell[0], self.dims[0]), edge(self.origin[1], self.cell[1], self.dims[1]))
    }
}

/// The colour of `t ∈ [0, 1]` on the sequential ramp, or on the diverging one.
pub fn ramp(t: f64, diverging: bool) -> Rgb {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    if diverging {
        return if t < 0.5 { COLD.lerp(palette::WHITE, t / 0.5) } else { palette::WHITE.lerp(WARM, (t - 0.5) / 0.5) };
    }
    let x = t * (RAMP.len() - 1) as f64;
    let k = (x.floor() as usize).min(RAMP.len() - 2);
    RAMP[k].lerp(RAMP[k + 1], x - k as f64)
}

/// The heat-map figure as PNG bytes (`width × height` pixels).
pub fn heatmap_png(fig: &HeatmapFigure, width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    render::check_size(width, height, MIN_SIZE)?;
    if fig.panels.is_empty() {
        return Err(PlotError::InvalidData(format!("heat-map figure \"{}\": no panels", fig.title)));
    }
    for p in &fig.panels {
        p.check()?;
    }
    render::render_png(width, height, |root| draw(root, fig, width as i32, height as i32))
}

fn draw<DB: Canvas>(root: &DrawingArea<DB, Shift>, fig: &HeatmapFigure, w: i32, h: i32) -> Result<(), PlotError> {
    root.fill(&WHITE)?;
    let s = (f64::from(w) / (500.0 * fig.panels.len() as f64)).min(f64::from(h) / 440.0).clamp(0.75, 2.0);
    let px = |v: f64| (v * s).round() as i32;
    Text::new(17.0 * s, palette::INK).align(Align::Centre).draw(root, &fig.title, (w / 2, px(20.0)))?;
    let panel_w = w / fig.panels.len() as i32;
    for (k, p) in fig.panels.iter().enumerate() {
        let x0 = k as i32 * panel_w;
        // Room: y ticks and title on the left, the colour bar and its labels on the right.
        let avail = PixelRect { x0: x0 + px(62.0), y0: px(66.0), x1: x0 + panel_w - px(92.0), y1: h - px(50.0) };
        let (xw, yw) = p.window();
        // Equal aspect: one data unit is as many pixels across as up.
        let ppu = (f64::from(avail.width()) / (xw[1] - xw[0])).min(f64::from(avail.height()) / (yw[1] - yw[0]));
        let (pw, ph) = (((xw[1] - xw[0]) * ppu).round() as i32, ((yw[1] - yw[0]) * ppu).round() as i32);
        let rect = PixelRect { x0: avail.x0, y0: avail.y0, x1: avail.x0 + pw.max(2), y1: avail.y0 + ph.max(2) };
        let axes = Axes { rect, x: xw, y: yw };
        Text::new(13.0 * s, palette::INK).align(Align::Left).draw(root, &p.caption, (rect.x0, px(50.0)))?;
        let range = p.range();
        let colour = |v: f64| match p.scaled(v) {
            Some(x) => ramp((x - range[0]) / (range[1] - range[0]), p.scale == ColourScale::Diverging),
            None => palette::NO_DATA,
        };
        for j in 0..p.dims[1] {
            for i in 0..p.dims[0] {
                let c = [p.origin[0] + i as f64 * p.cell[0], p.origin[1] + j as f64 * p.cell[1]];
                let a = axes.map([c[0] - 0.5 * p.cell[0], c[1] - 0.5 * p.cell[1]]);
                let b = axes.map([c[0] + 0.5 * p.cell[0], c[1] + 0.5 * p.cell[1]]);
                let fill = RGBColor::from(colour(p.values[j * p.dims[0] + i])).filled();
                root.draw(&Rectangle::new([(a.0.min(b.0), a.1.min(b.1)), (a.0.max(b.0), a.1.max(b.1))], fill))?;
            }
        }
        let style = AxesStyle {
            x_title: &p.x_title,
            y_title: &p.y_title,
            tick_size: 11.0 * s,
            title_size: 12.5 * s,
            tick_len: px(4.0).max(2),
            gap: px(3.0).max(2),
            x_title_offset: px(34.0),
            y_title_offset: px(46.0),
            max_x_ticks: (rect.width() / px(60.0).max(1)).clamp(2, 10) as usize,
            max_y_ticks: (rect.height() / px(40.0).max(1)).clamp(2, 10) as usize,
        };
        axes.draw_frame(root, &style)?;
        colour_bar(
            root,
            p,
            range,
            PixelRect { x0: rect.x1 + px(14.0), y0: rect.y0, x1: rect.x1 + px(28.0), y1: rect.y1 },
            s,
        )?;
    }
    Ok(())
}

/// The colour bar of `p` in `bar`, ticks on its right, the colour title along it.
fn colour_bar<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    p: &Heatmap,
    range: [f64; 2],
    bar: PixelRect,
    s: f64,
) -> Result<(), PlotError> {
    let diverging = p.scale == ColourScale::Diverging;
    for y in bar.y0..bar.y1 {
        let t = f64::from(bar.y1 - 1 - y) / f64::from((bar.height() - 1).max(1));
        root.draw(&PathElement::new(vec![(bar.x0, y), (bar.x1 - 1, y)], RGBColor::from(ramp(t, diverging))))?;
    }
    let ink = RGBColor::from(palette::INK);
    root.draw(&Rectangle::new([(bar.x0, bar.y0), (bar.x1 - 1, bar.y1 - 1)], ink.stroke_width(1)))?;
    // Ticks: plotters' round numbers in scaled units (decades on a log scale).
    let axes = Axes { rect: bar, x: [0.0, 1.0], y: range };
    let key_points = |n| plotters::coord::types::RangedCoordf64::from(range[0]..range[1]).key_points(n);
    let decades: Vec<f64> = (range[0].ceil() as i64..=range[1].floor() as i64).map(|e| e as f64).collect();
    // A log scale ticks its decades, or, spanning fewer than two, 1-2-5 multiples of them.
    let log_decades = p.scale == ColourScale::Log && decades.len() >= 2;
    let ticks: Vec<f64> = match p.scale {
        ColourScale::Log if log_decades => decades,
        ColourScale::Log => (range[0].floor() as i64..=range[1].ceil() as i64)
            .flat_map(|e| [1.0, 2.0, 5.0].map(|m: f64| (m * 10f64.powi(e as i32)).log10()))
            .filter(|t| (range[0]..=range[1]).contains(t))
            .collect(),
        _ => key_points(6),
    };
    let label = Text::new(10.5 * s, palette::INK_SOFT).align(Align::Left);
    for t in ticks {
        // Round-off of a tick at zero (`6.9e-18`) is zero.
        let t = if t.abs() < 1e-9 * (range[1] - range[0]) { 0.0 } else { t };
        let (_, py) = axes.map([0.0, t]);
        root.draw(&PathElement::new(vec![(bar.x1 - 1, py), (bar.x1 + 3, py)], ink))?;
        let text = match p.scale {
            ColourScale::Log if log_decades => format!("1e{}", t as i64),
            ColourScale::Log => short(10f64.powf(t)),
            _ => short(t),
        };
        label.draw(root, &text, (bar.x1 + 6, py))?;
    }
    Text::new(11.5 * s, palette::INK).align(Align::Centre).up().draw(
        root,
        &p.colour_title,
        (bar.x1 + (58.0 * s) as i32, (bar.y0 + bar.y1) / 2),
    )?;
    Ok(())
}

/// A tick value in few characters.
fn short(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.1e}")
    } else {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.').to_owned();
        if s == "-0" {
            "0".into()
        } else {
            s.replace('-', "−")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ramps_run_dark_to_light_and_cold_to_warm_through_white() {
        let lum = |c: Rgb| 0.299 * c.0 as f64 + 0.587 * c.1 as f64 + 0.114 * c.2 as f64;
        let l: Vec<f64> = (0..=10).map(|k| lum(ramp(k as f64 / 10.0, false))).collect();
        assert!(l.windows(2).all(|w| w[1] > w[0]), "{l:?}");
        assert_eq!(ramp(0.5, true), palette::WHITE);
        assert_eq!((ramp(0.0, true), ramp(1.0, true)), (COLD, WARM));
        assert_eq!(ramp(f64::NAN, false), RAMP[0]);
    }

    #[test]
    fn short_labels() {
        assert_eq!(short(0.25), "0.25");
        assert_eq!(short(-2.0), "−2");
        assert_eq!(short(123456.0), "1.2e5");
    }
}
