//! One line of text, placed by the centre line of its capitals.
//!
//! Bitmaps: laid out with the font's advances and kerning and rasterised with anti-aliasing
//! straight onto the canvas (each glyph at its own side bearing and sub-pixel pen position).
//! SVG: a `<text>` element in the family "sans-serif", shifted so the capitals centre on the
//! anchor as well.

use ab_glyph::{point, Font, ScaleFont};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{FontDesc, FontFamily, FontStyle, FontTransform};

use crate::font::{self, CAP_HEIGHT_EM};
use crate::palette::Rgb;
use crate::render::Canvas;
use crate::PlotError;

/// Which end (or the middle) of a line sits on its anchor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Align {
    Left,
    Centre,
    Right,
}

/// Which way a line of text runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Direction {
    /// Left to right.
    Across,
    /// Bottom to top (a y-axis title).
    Up,
}

/// How a line of text is set.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Text {
    /// Font size, pixels per em.
    pub size: f64,
    pub colour: Rgb,
    /// Which end (or the middle) of the line sits on the anchor.
    pub align: Align,
    pub direction: Direction,
}

impl Text {
    pub fn new(size: f64, colour: Rgb) -> Text {
        Text { size, colour, align: Align::Left, direction: Direction::Across }
    }

    pub fn align(self, align: Align) -> Text {
        Text { align, ..self }
    }

    pub fn up(self) -> Text {
        Text { direction: Direction::Up, ..self }
    }

    /// Draws `line` with its capitals centred on the anchor, across the line.
    pub fn draw<DB: Canvas>(
        &self,
        area: &DrawingArea<DB, Shift>,
        line: &str,
        anchor: (i32, i32),
    ) -> Result<(), PlotError> {
        if DB::RASTER {
            self.rasterise(area, line, anchor)
        } else {
            self.svg_text(area, line, anchor)
        }
    }

    fn rasterise<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        line: &str,
        (x, y): (i32, i32),
    ) -> Result<(), PlotError> {
        let face = font::face()?;
        let scaled = face.as_scaled(font::px_scale(face, self.size));
        let width = width_of(&scaled, line);
        // Text frame: u along the line from the anchor, v down across it, baseline at v = b.
        let u0 = match self.align {
            Align::Left => 0.0,
            Align::Centre => -0.5 * width,
            Align::Right => -width,
        };
        let baseline = (0.5 * CAP_HEIGHT_EM * self.size) as f32;
        let colour = RGBColor::from(self.colour);
        let mut pen = u0 as f32;
        let mut prev = None;
        let mut result = Ok(());
        for c in line.chars() {
            let id = scaled.glyph_id(c);
            if let Some(p) = prev {
                pen += scaled.kern(p, id);
            }
            let glyph = id.with_scale_and_position(scaled.scale(), point(pen, baseline));
            if let Some(outlined) = face.outline_glyph(glyph) {
                let b = outlined.px_bounds();
                outlined.draw(|gx, gy, coverage| {
                    if result.is_err() || coverage <= 0.0 {
                        return;
                    }
                    let u = b.min.x as i32 + gx as i32;
                    let v = b.min.y as i32 + gy as i32;
                    let at = match self.direction {
                        Direction::Across => (x + u, y + v),
                        Direction::Up => (x + v, y - u),
                    };
                    result = area.draw_pixel(at, &colour.mix(f64::from(coverage.min(1.0))));
                });
            }
            pen += scaled.h_advance(id);
            prev = Some(id);
        }
        result?;
        Ok(())
    }

    fn svg_text<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        line: &str,
        (x, y): (i32, i32),
    ) -> Result<(), PlotError> {
        // plotters writes font-size = size / 1.24 and dy = 0.5ex (DejaVu: x-height 0.547 em),
        // which puts the baseline 0.27 em below the anchor; capitals centre at 0.36 em.
        let nudge = ((0.5 * CAP_HEIGHT_EM - 0.5 * 0.547) * self.size).round() as i32;
        let (transform, at) = match self.direction {
            Direction::Across => (FontTransform::None, (x, y + nudge)),
            Direction::Up => (FontTransform::Rotate270, (x + nudge, y)),
        };
        let style = TextStyle {
            font: FontDesc::new(FontFamily::SansSerif, self.size * 1.24, FontStyle::Normal).transform(transform),
            color: RGBColor::from(self.colour).to_backend_color(),
            pos: Pos::new(
                match self.align {
                    Align::Left => HPos::Left,
                    Align::Centre => HPos::Center,
                    Align::Right => HPos::Right,
                },
                VPos::Center,
            ),
        };
        area.draw_text(line, &style, at)?;
        Ok(())
    }
}

fn width_of<F: Font, S: ScaleFont<F>>(scaled: &S, line: &str) -> f64 {
    let mut pen = 0.0_f32;
    let mut prev = None;
    for c in line.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            pen += scaled.kern(p, id);
        }
        pen += scaled.h_advance(id);
        prev = Some(id);
    }
    f64::from(pen)
}

/// The advance width of `line` at `size` pixels per em.
pub(crate) fn width(line: &str, size: f64) -> Result<f64, PlotError> {
    let face = font::face()?;
    Ok(width_of(&face.as_scaled(font::px_scale(face, size)), line))
}

/// The first of `variants` no wider than `room` pixels at `size`, else the last.
pub(crate) fn first_that_fits<'a>(variants: &[&'a str], size: f64, room: f64) -> Result<&'a str, PlotError> {
    for v in variants {
        if width(v, size)? <= room {
            return Ok(v);
        }
    }
    Ok(variants.last().copied().unwrap_or(""))
}
