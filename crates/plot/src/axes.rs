//! A chart's plotting rectangle, the data window it shows, and its axes: frame, ticks at
//! plotters' "nice" key points, tick labels, axis titles and an optional grid.

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::geometry::Window;
use crate::palette::{self, Rgb};
use crate::render::Canvas;
use crate::text::{Align, Text};
use crate::PlotError;

/// A rectangle of pixels, half-open: `x0 ≤ x < x1`, `y0 ≤ y < y1` (y down).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRect {
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
}

impl PixelRect {
    pub fn width(&self) -> i32 {
        self.x1 - self.x0
    }

    pub fn height(&self) -> i32 {
        self.y1 - self.y0
    }

    pub fn contains(&self, [x, y]: [i32; 2]) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }
}

/// Data window `x × y` shown in the pixel rectangle `rect` (`x[0]` at the left edge, `y[0]`
/// at the bottom edge).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Axes {
    pub rect: PixelRect,
    pub x: [f64; 2],
    pub y: [f64; 2],
}

/// What the axes say and how big.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AxesStyle<'a> {
    pub x_title: &'a str,
    pub y_title: &'a str,
    /// Tick label size and axis title size, pixels per em.
    pub tick_size: f64,
    pub title_size: f64,
    /// Tick mark length and the gap between tick and label, pixels.
    pub tick_len: i32,
    pub gap: i32,
    /// Distance from the plot edge to the centre of the axis titles, pixels.
    pub x_title_offset: i32,
    pub y_title_offset: i32,
    /// At most this many ticks (plotters picks round numbers).
    pub max_x_ticks: usize,
    pub max_y_ticks: usize,
}

impl Axes {
    /// The pixel of data point `p`, exactly as a plotters chart on `rect` maps it (onto
    /// `x0..=x1-1` and `y1-1..=y0`). Points outside the window map outside `rect`.
    pub fn map(&self, p: [f64; 2]) -> (i32, i32) {
        let r = &self.rect;
        Cartesian2d::<RangedCoordf64, RangedCoordf64>::new(
            self.x[0]..self.x[1],
            self.y[0]..self.y[1],
            (r.x0..r.x1 - 1, r.y1 - 1..r.y0),
        )
        .translate(&(p[0], p[1]))
    }

    /// The continuous image position of data point `p` (pixel `(i, j)` covers
    /// `[i, i+1) × [j, j+1)`); [`Axes::map`] is the pixel that contains it (plotters floors
    /// `x0 + (w−1)·t` and `y1 − (h−1)·t` to a pixel, up to its 1e-3 px nudge).
    pub fn map_f(&self, p: [f64; 2]) -> [f64; 2] {
        let r = &self.rect;
        let tx = (p[0] - self.x[0]) / (self.x[1] - self.x[0]);
        let ty = (p[1] - self.y[0]) / (self.y[1] - self.y[0]);
        [f64::from(r.x0) + f64::from(r.width() - 1) * tx, f64::from(r.y1) - f64::from(r.height() - 1) * ty]
    }

    /// The data point at the centre of pixel `(px, py)`.
    pub fn unmap_centre(&self, px: i32, py: i32) -> [f64; 2] {
        let r = &self.rect;
        let tx = (f64::from(px - r.x0) + 0.5) / f64::from((r.width() - 1).max(1));
        let ty = (f64::from(r.y1 - 1 - py) + 0.5) / f64::from((r.height() - 1).max(1));
        [self.x[0] + tx * (self.x[1] - self.x[0]), self.y[0] + ty * (self.y[1] - self.y[0])]
    }

    pub fn window(&self) -> Window {
        Window { x: self.x, y: self.y }
    }

    fn x_ticks(&self, max: usize) -> Vec<f64> {
        RangedCoordf64::from(self.x[0]..self.x[1]).key_points(max)
    }

    fn y_ticks(&self, max: usize) -> Vec<f64> {
        RangedCoordf64::from(self.y[0]..self.y[1]).key_points(max)
    }

    /// Grid lines at the ticks (draw under the data).
    pub fn draw_grid<DB: Canvas>(
        &self,
        area: &DrawingArea<DB, Shift>,
        style: &AxesStyle<'_>,
        colour: Rgb,
    ) -> Result<(), PlotError> {
        let r = &self.rect;
        let line = RGBColor::from(colour).stroke_width(1);
        for x in self.x_ticks(style.max_x_ticks) {
            let (px, _) = self.map([x, self.y[0]]);
            area.draw(&PathElement::new(vec![(px, r.y0), (px, r.y1 - 1)], line))?;
        }
        for y in self.y_ticks(style.max_y_ticks) {
            let (_, py) = self.map([self.x[0], y]);
            area.draw(&PathElement::new(vec![(r.x0, py), (r.x1 - 1, py)], line))?;
        }
        Ok(())
    }

    /// The frame, tick marks, tick labels and axis titles (draw over the data).
    pub fn draw_frame<DB: Canvas>(
        &self,
        area: &DrawingArea<DB, Shift>,
        style: &AxesStyle<'_>,
    ) -> Result<(), PlotError> {
        let r = &self.rect;
        let ink = RGBColor::from(palette::INK);
        area.draw(&Rectangle::new([(r.x0, r.y0), (r.x1 - 1, r.y1 - 1)], ink.stroke_width(1)))?;
        let label = Text::new(style.tick_size, palette::INK_SOFT);
        let x_ticks = self.x_ticks(style.max_x_ticks);
        let y_ticks = self.y_ticks(style.max_y_ticks);
        let x_fmt = tick_format(&x_ticks);
        let y_fmt = tick_format(&y_ticks);
        let cap = (0.5 * crate::font::CAP_HEIGHT_EM * style.tick_size).round() as i32;
        for x in x_ticks {
            let (px, _) = self.map([x, self.y[0]]);
            let y = r.y1 - 1;
            area.draw(&PathElement::new(vec![(px, y), (px, y + style.tick_len)], ink))?;
            label.align(Align::Centre).draw(area, &x_fmt(x), (px, y + style.tick_len + style.gap + cap))?;
        }
        for y in y_ticks {
            let (_, py) = self.map([self.x[0], y]);
            let x = r.x0;
            area.draw(&PathElement::new(vec![(x - style.tick_len, py), (x, py)], ink))?;
            label.align(Align::Right).draw(area, &y_fmt(y), (x - style.tick_len - style.gap, py))?;
        }
        let title = Text::new(style.title_size, palette::INK).align(Align::Centre);
        title.draw(area, style.x_title, ((r.x0 + r.x1) / 2, r.y1 + style.x_title_offset))?;
        title.up().draw(area, style.y_title, (r.x0 - style.y_title_offset, (r.y0 + r.y1) / 2))?;
        Ok(())
    }
}

/// Formats tick values with as many decimals as their spacing needs, and a true minus sign.
fn tick_format(ticks: &[f64]) -> impl Fn(f64) -> String {
    // The fewest decimals (up to 6) that show every tick exactly.
    let exact = |d: i32| {
        let k = 10f64.powi(d);
        ticks.iter().all(|t| ((t * k).round() / k - t).abs() <= 1e-9 * t.abs().max(1.0))
    };
    let decimals = (0..=6).find(|&d| exact(d)).unwrap_or(6) as usize;
    move |v: f64| {
        let s = format!("{v:.decimals$}");
        // "-0.0" → "0.0"; then U+2212 MINUS SIGN, as typeset figures use.
        match s.strip_prefix('-') {
            Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
            Some(rest) => format!("\u{2212}{rest}"),
            None => s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_format_uses_the_decimals_of_the_step_and_a_minus_sign() {
        let f = tick_format(&[-0.5, 0.0, 0.5, 1.0]);
        assert_eq!(f(-0.5), "\u{2212}0.5");
        assert_eq!(f(1.0), "1.0");
        let f = tick_format(&[0.0, 2.0, 4.0]);
        assert_eq!(f(4.0), "4");
        let f = tick_format(&[0.0, 0.25, 0.5]);
        assert_eq!(f(0.25), "0.25");
        assert_eq!(f(-1e-12), "0.00");
        let f = tick_format(&[1.2, 1.4, 1.6]);
        assert_eq!(f(1.4), "1.4");
    }

    #[test]
    fn map_matches_plotters_corners() {
        let axes = Axes { rect: PixelRect { x0: 10, y0: 20, x1: 110, y1: 70 }, x: [0.0, 1.0], y: [0.0, 1.0] };
        assert_eq!(axes.map([0.0, 0.0]), (10, 69));
        assert_eq!(axes.map([1.0, 1.0]), (109, 20));
        let c = axes.unmap_centre(59, 44);
        assert_eq!(axes.map(c), (59, 44));
        for p in [[0.0, 0.0], [0.31, 0.77], [0.5, 0.5], [1.0, 1.0]] {
            let f = axes.map_f(p);
            let (x, y) = axes.map(p);
            assert_eq!((f[0].floor() as i32, (f[1] - 1e-9).floor() as i32), (x, y), "{p:?}");
        }
    }
}
