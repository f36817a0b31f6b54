//! The trajectory figure's layout: every position and size from the image size and the figure's
//! content, the legend's entries and the top view's window.

use crate::axes::{AxesStyle, PixelRect};
use crate::palette::{self, Rgb};
use crate::render;
use crate::stroke::{DashPattern, Pen};
use crate::text;
use crate::PlotError;

use super::types::{TopDownView, TrajectoryFigure, CLEARANCE_RAMP_M, CLEARANCE_STEP_M, MIN_SIZE, ZOOM_MARGIN_M};

/// Axis title size at the reference size, pixels per em.
pub(super) const AXIS_TITLE_PX: f64 = 13.0;

/// Width of the altitude band lines at the reference size, pixels.
pub(super) const BAND_WIDTH: f64 = 1.5;

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Marker {
    Waypoint,
    Start,
    Goal,
    Collision,
}

#[derive(Debug, Clone, PartialEq)]
pub(super) enum Glyph {
    Line {
        colour: Rgb,
        width: f64,
        dash: Dash,
    },
    Marker(Marker),
    /// A filled square with an edge.
    Patch {
        fill: Rgb,
        edge: Rgb,
    },
    /// The free-space shade from the surface to [`CLEARANCE_RAMP_M`].
    Ramp,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Dash {
    Solid,
    Dashed,
    Dotted,
}

#[derive(Debug, Clone)]
pub(super) struct LegendEntry {
    pub(super) glyph: Glyph,
    pub(super) label: String,
    /// Left edge of the glyph and the row's centre line, pixels.
    pub(super) at: (i32, i32),
}

/// Every position and size of the figure, from the image size and the figure's content.
#[derive(Debug)]
pub(super) struct Layout {
    /// Scale against the reference design (1200 × 680 px).
    pub(super) s: f64,
    pub(super) title_size: f64,
    pub(super) caption_size: f64,
    pub(super) legend_size: f64,
    pub(super) title_y: i32,
    pub(super) legend: Vec<LegendEntry>,
    pub(super) top: TopDownView,
    /// The side view's plotting rectangle.
    pub(super) side: PixelRect,
    /// Height of the caption band above each plot.
    pub(super) caption_h: i32,
}

impl Layout {
    pub(super) fn new(fig: &TrajectoryFigure, width: u32, height: u32) -> Result<Layout, PlotError> {
        render::check_size(width, height, MIN_SIZE)?;
        fig.check()?;
        let (w, h) = (width as i32, height as i32);
        // Below 0.75 text gets too small to read: small figures get relatively larger text.
        let s = (f64::from(width) / 1200.0).min(f64::from(height) / 680.0).max(0.75);
        let px = |v: f64| (v * s).round() as i32;

        let title_y = px(22.0);
        let row_h = px(24.0);
        let legend_size = 12.0 * s;
        let legend = legend(fig, s, legend_size, w, px(50.0), row_h)?;
        let rows = legend.last().map_or(1, |e| (e.at.1 - px(50.0)) / row_h.max(1) + 1);
        let caption_h = px(26.0);
        let panels_top = px(50.0) + rows * row_h - row_h / 2 + px(4.0);
        let split = (f64::from(w) * 0.635).round() as i32;
        // Plot rectangles: room left for tick labels and the y title, below for the x title.
        let (left, bottom, right) = (px(64.0), px(48.0), px(20.0));
        let top_avail = PixelRect { x0: left, y0: panels_top + caption_h, x1: split - right, y1: h - bottom };
        let side = PixelRect { x0: split + left, y0: panels_top + caption_h, x1: w - right, y1: h - bottom };
        let top = top_view(fig, top_avail);
        Ok(Layout {
            s,
            title_size: 19.0 * s,
            caption_size: 13.0 * s,
            legend_size,
            title_y,
            legend,
            top,
            side,
            caption_h,
        })
    }

    pub(super) fn px(&self, v: f64) -> i32 {
        (v * self.s).round() as i32
    }

    /// A pen of `width` pixels at the reference size.
    pub(super) fn pen(&self, colour: Rgb, width: f64, dash: Dash) -> Pen {
        let dash = match dash {
            Dash::Solid => None,
            Dash::Dashed => Some(DashPattern { on: 7.0 * self.s, off: 5.0 * self.s }),
            Dash::Dotted => Some(DashPattern { on: 1.5 * self.s, off: 3.0 * self.s }),
        };
        Pen { colour, width: width * self.s, dash }
    }

    pub(super) fn stroke(&self, v: f64) -> u32 {
        (v * self.s).round().max(1.0) as u32
    }

    pub(super) fn axes_style<'a>(&self, x_title: &'a str, y_title: &'a str, rect: &PixelRect) -> AxesStyle<'a> {
        AxesStyle {
            x_title,
            y_title,
            tick_size: 11.5 * self.s,
            title_size: AXIS_TITLE_PX * self.s,
            tick_len: self.px(4.0).max(2),
            gap: self.px(4.0).max(2),
            x_title_offset: self.px(35.0),
            y_title_offset: self.px(50.0),
            max_x_ticks: (rect.width() / self.px(70.0).max(1)).clamp(2, 12) as usize,
            max_y_ticks: (rect.height() / self.px(42.0).max(1)).clamp(2, 12) as usize,
        }
    }
}

/// The legend entries, placed in centred rows that wrap at the image width.
fn legend(
    fig: &TrajectoryFigure,
    s: f64,
    size: f64,
    width: i32,
    first_row_y: i32,
    row_h: i32,
) -> Result<Vec<LegendEntry>, PlotError> {
    let mut entries: Vec<(Glyph, String)> = Vec::new();
    let mut seen = Vec::new();
    for t in &fig.tracks {
        if !seen.contains(&(t.kind, &t.label)) {
            seen.push((t.kind, &t.label));
            let dash = if t.kind.dashed() { Dash::Dashed } else { Dash::Solid };
            entries.push((Glyph::Line { colour: t.kind.colour(), width: t.kind.width(), dash }, t.label.clone()));
        }
    }
    if !fig.waypoints.is_empty() {
        entries.push((Glyph::Marker(Marker::Waypoint), "waypoint".into()));
    }
    entries.push((Glyph::Marker(Marker::Start), "start".into()));
    entries.push((Glyph::Marker(Marker::Goal), "goal".into()));
    if fig.collision.is_some() {
        entries.push((Glyph::Marker(Marker::Collision), "collision".into()));
    }
    entries.push((Glyph::Patch { fill: palette::SOLID, edge: palette::SURFACE }, "obstacle".into()));
    entries.push((Glyph::Ramp, format!("clearance 0–{CLEARANCE_RAMP_M} m")));
    entries
        .push((Glyph::Line { colour: palette::BAND, width: BAND_WIDTH, dash: Dash::Dashed }, "altitude band".into()));
    entries.push((Glyph::Line { colour: palette::SOLID, width: 1.0, dash: Dash::Dotted }, "top-view slice".into()));

    let glyph_w = (30.0 * s).round() as i32;
    let gap = (6.0 * s).round() as i32;
    let spacing = (20.0 * s).round() as i32;
    let usable = width - (32.0 * s).round() as i32;
    let mut sized = Vec::with_capacity(entries.len());
    for (glyph, label) in entries {
        let w = glyph_w + gap + text::width(&label, size)?.ceil() as i32;
        sized.push((glyph, label, w));
    }
    // Greedy rows no wider than `limit`; as many rows as the image width needs, balanced.
    let wrap = |limit: i32| {
        let mut rows: Vec<Vec<(Glyph, String, i32)>> = vec![Vec::new()];
        let mut row_w = 0;
        for e in &sized {
            if row_w > 0 && row_w + spacing + e.2 > limit {
                rows.push(Vec::new());
                row_w = e.2;
            } else {
                row_w += if row_w == 0 { e.2 } else { spacing + e.2 };
            }
            if let Some(row) = rows.last_mut() {
                row.push(e.clone());
            }
        }
        rows
    };
    let n_rows = wrap(usable).len();
    let total: i32 = sized.iter().map(|e| e.2 + spacing).sum();
    let mut limit = total / n_rows as i32;
    let rows = loop {
        let rows = wrap(limit);
        if rows.len() <= n_rows || limit >= usable {
            break rows;
        }
        limit += (4.0 * s).ceil() as i32;
    };
    let mut placed = Vec::new();
    for (r, row) in rows.into_iter().enumerate() {
        let total = row.iter().map(|e| e.2).sum::<i32>() + spacing * (row.len() as i32 - 1);
        let mut x = (width - total) / 2;
        let y = first_row_y + r as i32 * row_h;
        for (glyph, label, w) in row {
            placed.push(LegendEntry { glyph, label, at: (x, y) });
            x += w + spacing;
        }
    }
    Ok(placed)
}

/// The top view: everything of interest plus [`ZOOM_MARGIN_M`], clipped to the slice; then at
/// equal aspect either grown to fill `avail` or, where the slice ends first, `avail` narrowed
/// (and centred) instead, so the map shows no empty margins.
fn top_view(fig: &TrajectoryFigure, avail: PixelRect) -> TopDownView {
    let extent = fig.slice.extent();
    // Start and goal are finite (checked), so the box is never empty.
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in fig.points_of_interest() {
        for a in 0..2 {
            lo[a] = lo[a].min(p[a] - ZOOM_MARGIN_M);
            hi[a] = hi[a].max(p[a] + ZOOM_MARGIN_M);
        }
    }
    if let Some(ext) = extent {
        let clipped_lo = [lo[0].max(ext[0][0]), lo[1].max(ext[1][0])];
        let clipped_hi = [hi[0].min(ext[0][1]), hi[1].min(ext[1][1])];
        // A flight entirely outside the slice is shown anyway (on "no data").
        if clipped_lo[0] < clipped_hi[0] && clipped_lo[1] < clipped_hi[1] {
            (lo, hi) = (clipped_lo, clipped_hi);
        }
    }
    // At least 1 m across, so that a hover or a single point still has a sensible scale.
    for a in 0..2 {
        if hi[a] - lo[a] < 1.0 {
            let c = 0.5 * (lo[a] + hi[a]);
            (lo[a], hi[a]) = (c - 0.5, c + 0.5);
        }
    }
    // plotters maps a range onto (pixels − 1).
    let avail_px = [avail.width() - 1, avail.height() - 1].map(|p| p.max(1));
    let m = ((hi[0] - lo[0]) / f64::from(avail_px[0])).max((hi[1] - lo[1]) / f64::from(avail_px[1]));
    let mut range = [[0.0; 2]; 2];
    let mut px = avail_px;
    for a in 0..2 {
        let want = m * f64::from(avail_px[a]);
        let c = 0.5 * (lo[a] + hi[a]);
        let (l, h) = match extent {
            Some(ext) => {
                let (el, eh) = (ext[a][0], ext[a][1]);
                let len = want.min((eh - el).max(hi[a] - lo[a]));
                px[a] = ((len / m).floor() as i32).clamp(1, avail_px[a]);
                let len = m * f64::from(px[a]);
                let (mut l, mut h) = (c - 0.5 * len, c + 0.5 * len);
                if len <= eh - el {
                    if l < el {
                        (l, h) = (el, el + len);
                    } else if h > eh {
                        (l, h) = (eh - len, eh);
                    }
                }
                (l, h)
            }
            None => (c - 0.5 * want, c + 0.5 * want),
        };
        range[a] = [l, h];
    }
    let (dx, dy) = ((avail_px[0] - px[0]) / 2, (avail_px[1] - px[1]) / 2);
    TopDownView {
        plot_area: PixelRect {
            x0: avail.x0 + dx,
            y0: avail.y0 + dy,
            x1: avail.x0 + dx + px[0] + 1,
            y1: avail.y0 + dy + px[1] + 1,
        },
        x_range: range[0],
        y_range: range[1],
    }
}

/// The colour of the signed-distance map at distance `d` (`None`: no data).
pub(super) fn field_colour(d: Option<f64>) -> Rgb {
    match d {
        None => palette::NO_DATA,
        Some(d) if d < 0.0 => palette::SOLID,
        Some(d) => {
            let steps = (CLEARANCE_RAMP_M / CLEARANCE_STEP_M).round();
            let band = (d / CLEARANCE_STEP_M).floor().min(steps);
            palette::CLEARANCE_NEAR.lerp(palette::WHITE, band / steps)
        }
    }
}
