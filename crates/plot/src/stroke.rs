//! Lines and round markers. Bitmaps get them anti-aliased here (plotters' bitmap backend
//! draws thick lines without anti-aliasing, which makes diagonal tracks visibly stair-stepped);
//! SVG gets plain plotters elements and leaves anti-aliasing to the viewer.
//!
//! Coordinates are continuous image pixels: pixel `(i, j)` covers `[i, i+1) × [j, j+1)`.

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

use crate::palette::Rgb;
use crate::render::Canvas;
use crate::PlotError;

/// A dash pattern: `on` pixels drawn, then `off` pixels skipped, along the line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DashPattern {
    pub on: f64,
    pub off: f64,
}

/// How a line is stroked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Pen {
    pub colour: Rgb,
    /// Width in pixels.
    pub width: f64,
    pub dash: Option<DashPattern>,
}

/// Strokes each polyline of `lines` (round joins and caps on bitmaps). Where lines of one call
/// overlap, the colour is laid once (no darker joints).
pub(crate) fn polylines<DB: Canvas>(
    area: &DrawingArea<DB, Shift>,
    lines: &[Vec<[f64; 2]>],
    pen: Pen,
) -> Result<(), PlotError> {
    if DB::RASTER {
        let half = 0.5 * pen.width;
        let mut cov = Coverage::around(area, lines.iter().flatten().copied(), half + 1.0);
        for line in lines {
            let mut s0 = 0.0;
            for seg in line.windows(2) {
                cov.segment(seg[0], seg[1], half, s0, pen.dash);
                s0 += (seg[1][0] - seg[0][0]).hypot(seg[1][1] - seg[0][1]);
            }
            if line.len() == 1 {
                cov.segment(line[0], line[0], half, 0.0, None);
            }
        }
        cov.blend(area, pen.colour)
    } else {
        let style = RGBColor::from(pen.colour).stroke_width(pen.width.round().max(1.0) as u32);
        for line in lines.iter().filter(|l| l.len() >= 2) {
            let pts: Vec<(i32, i32)> = line.iter().map(|p| to_int(*p)).collect();
            match pen.dash {
                None => area.draw(&PathElement::new(pts, style))?,
                Some(d) => {
                    let (on, off) = (d.on.round().max(1.0) as i32, d.off.round().max(1.0) as i32);
                    area.draw(&DashedPathElement::new(pts, on, off, style))?
                }
            }
        }
        Ok(())
    }
}

/// A filled disc of radius `r` pixels, with an outline of `edge` (colour, width) if given.
pub(crate) fn disc<DB: Canvas>(
    area: &DrawingArea<DB, Shift>,
    c: [f64; 2],
    r: f64,
    fill: Rgb,
    edge: Option<(Rgb, f64)>,
) -> Result<(), PlotError> {
    if DB::RASTER {
        let outer = r + edge.map_or(0.0, |e| 0.5 * e.1);
        let mut cov = Coverage::around(area, [c], outer + 1.0);
        cov.each(|p| (r + 0.5 - dist(p, c)).clamp(0.0, 1.0));
        cov.blend(area, fill)?;
        if let Some((colour, w)) = edge {
            let mut cov = Coverage::around(area, [c], outer + 1.0);
            cov.each(|p| (0.5 * w + 0.5 - (dist(p, c) - r).abs()).clamp(0.0, 1.0));
            cov.blend(area, colour)?;
        }
        Ok(())
    } else {
        let (ci, ri) = (to_int(c), r.round() as i32);
        area.draw(&Circle::new(ci, ri, RGBColor::from(fill).filled()))?;
        if let Some((colour, w)) = edge {
            let style = RGBColor::from(colour).stroke_width(w.round().max(1.0) as u32);
            area.draw(&Circle::new(ci, ri, style))?;
        }
        Ok(())
    }
}

/// The nearest integer pixel position for plotters elements.
pub(crate) fn to_int(p: [f64; 2]) -> (i32, i32) {
    (p[0].floor() as i32, p[1].floor() as i32)
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Per-pixel coverage in [0, 1] over a box of the canvas.
struct Coverage {
    x0: i32,
    y0: i32,
    w: usize,
    h: usize,
    cov: Vec<f32>,
}

impl Coverage {
    /// A box around `points` grown by `pad` pixels, clipped to the canvas.
    fn around<DB: DrawingBackend>(
        area: &DrawingArea<DB, Shift>,
        points: impl IntoIterator<Item = [f64; 2]>,
        pad: f64,
    ) -> Coverage {
        let (cw, ch) = area.dim_in_pixel();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in points {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
            return Coverage { x0: 0, y0: 0, w: 0, h: 0, cov: Vec::new() };
        }
        let clamp = |v: f64, max: u32| v.clamp(0.0, f64::from(max)) as i32;
        let (x0, x1) = (clamp((lo[0] - pad).floor(), cw), clamp((hi[0] + pad).ceil(), cw));
        let (y0, y1) = (clamp((lo[1] - pad).floor(), ch), clamp((hi[1] + pad).ceil(), ch));
        let (w, h) = ((x1 - x0).max(0) as usize, (y1 - y0).max(0) as usize);
        Coverage { x0, y0, w, h, cov: vec![0.0; w * h] }
    }

    /// Sets every pixel's coverage from its centre.
    fn each(&mut self, f: impl Fn([f64; 2]) -> f64) {
        for j in 0..self.h {
            for i in 0..self.w {
                let c = [f64::from(self.x0) + i as f64 + 0.5, f64::from(self.y0) + j as f64 + 0.5];
                let k = i + self.w * j;
                self.cov[k] = self.cov[k].max(f(c) as f32);
            }
        }
    }

    /// Adds segment `a → b` stroked `half` pixels either side (round ends); `s0` is the arc
    /// length at `a`, for the dash phase.
    fn segment(&mut self, a: [f64; 2], b: [f64; 2], half: f64, s0: f64, dash: Option<DashPattern>) {
        let d = [b[0] - a[0], b[1] - a[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        let len = len2.sqrt();
        let pad = half + 1.0;
        let range = |lo: f64, hi: f64, origin: i32, n: usize| {
            let i0 = ((lo - pad).floor() as i64 - i64::from(origin)).clamp(0, n as i64) as usize;
            let i1 = ((hi + pad).ceil() as i64 - i64::from(origin)).clamp(0, n as i64) as usize;
            i0..i1
        };
        let xs = range(a[0].min(b[0]), a[0].max(b[0]), self.x0, self.w);
        let ys = range(a[1].min(b[1]), a[1].max(b[1]), self.y0, self.h);
        for j in ys {
            for i in xs.clone() {
                let c = [f64::from(self.x0) + i as f64 + 0.5, f64::from(self.y0) + j as f64 + 0.5];
                let t = if len2 > 0.0 {
                    (((c[0] - a[0]) * d[0] + (c[1] - a[1]) * d[1]) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let q = [a[0] + d[0] * t, a[1] + d[1] * t];
                let mut v = (half + 0.5 - dist(c, q)).clamp(0.0, 1.0);
                if let Some(p) = dash {
                    // Distance along the line to the nearest "on" stretch, smoothed over a pixel.
                    let period = p.on + p.off;
                    let phase = (s0 + t * len).rem_euclid(period);
                    let outside = if phase <= p.on { 0.0 } else { (phase - p.on).min(period - phase) };
                    v *= (1.0 - outside).clamp(0.0, 1.0);
                }
                let k = i + self.w * j;
                self.cov[k] = self.cov[k].max(v as f32);
            }
        }
    }

    /// Lays `colour` over the canvas with the coverage as opacity.
    fn blend<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>, colour: Rgb) -> Result<(), PlotError> {
        let colour = RGBColor::from(colour);
        for j in 0..self.h {
            for i in 0..self.w {
                let v = self.cov[i + self.w * j];
                if v > 0.0 {
                    let at = (self.x0 + i as i32, self.y0 + j as i32);
                    area.draw_pixel(at, &colour.mix(f64::from(v)))?;
                }
            }
        }
        Ok(())
    }
}
