//! The trajectory figure: one flight seen from above over the signed-distance slice of the
//! world (left, about two thirds of the width) and from the side as altitude against the
//! horizontal distance travelled (right).
//!
//! Layout, top to bottom: the title; a legend row (wrapped when long); the two panels, each with
//! a caption. The top view is zoomed to the tracks, start, goal, waypoints and collision with a
//! [`ZOOM_MARGIN_M`] margin (clipped to the slice) and has equal aspect: its x or y range grows
//! to fill the panel. Sizes scale with the image (the reference design is 1200 × 680 px).

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::axes::{Axes, AxesStyle, PixelRect};
use crate::geometry;
use crate::palette::{self, Rgb};
use crate::render::{self, Canvas};
use crate::stroke::{self, DashPattern, Pen};
use crate::text::{self, Align, Text};
use crate::PlotError;

/// Margin around the flown region in the top view, metres.
pub const ZOOM_MARGIN_M: f64 = 0.3;
/// Clearance at which the free-space shade reaches white, metres.
pub const CLEARANCE_RAMP_M: f64 = 1.0;
/// Width of one shade step of free space, metres (the shade shows clearance like contour bands).
pub const CLEARANCE_STEP_M: f64 = 0.1;
/// The smallest figure laid out legibly, pixels.
pub const MIN_SIZE: (u32, u32) = (480, 320);

/// A horizontal slice of the signed distance field at one altitude.
///
/// `values`: `[dims[1], dims[0]]`, x fastest: node `(i, j)` sits at `origin + cell·(i, j)`
/// (metres, world frame) and holds the signed distance in metres (negative inside geometry).
/// NaN marks a node without data. A slice with fewer than 2 nodes along an axis draws as
/// "no data".
#[derive(Debug, Clone, PartialEq)]
pub struct FieldSlice {
    pub origin: [f64; 2],
    pub cell: f64,
    pub dims: [usize; 2],
    pub values: Vec<f32>,
    /// Altitude z of the slice, metres.
    pub altitude: f64,
}

impl FieldSlice {
    /// The span of the nodes, `[[x_min, x_max], [y_min, y_max]]`, or `None` when the slice has
    /// fewer than 2 nodes along an axis.
    pub fn extent(&self) -> Option<[[f64; 2]; 2]> {
        if self.dims[0] < 2 || self.dims[1] < 2 {
            return None;
        }
        let span = |a: usize| [self.origin[a], self.origin[a] + self.cell * (self.dims[a] - 1) as f64];
        Some([span(0), span(1)])
    }

    /// Bilinear interpolation of the signed distance at `xy`; `None` outside the nodes' span or
    /// next to a NaN node.
    pub fn value_at(&self, xy: [f64; 2]) -> Option<f64> {
        self.extent()?;
        let f = |a: usize| (xy[a] - self.origin[a]) / self.cell;
        let (fx, fy) = (f(0), f(1));
        let (nx, ny) = (self.dims[0], self.dims[1]);
        if !(fx >= 0.0 && fy >= 0.0 && fx <= (nx - 1) as f64 && fy <= (ny - 1) as f64) {
            return None;
        }
        let i = (fx.floor() as usize).min(nx - 2);
        let j = (fy.floor() as usize).min(ny - 2);
        let (tx, ty) = (fx - i as f64, fy - j as f64);
        let v = |i: usize, j: usize| self.node(i, j);
        let value = (v(i, j) * (1.0 - tx) + v(i + 1, j) * tx) * (1.0 - ty)
            + (v(i, j + 1) * (1.0 - tx) + v(i + 1, j + 1) * tx) * ty;
        value.is_finite().then_some(value)
    }

    fn node(&self, i: usize, j: usize) -> f64 {
        f64::from(self.values[i + self.dims[0] * j])
    }

    fn check(&self) -> Result<(), PlotError> {
        let n = self.dims[0].checked_mul(self.dims[1]);
        if n != Some(self.values.len()) {
            return Err(PlotError::InvalidData(format!(
                "slice: {} values for dims {:?}, expected {}",
                self.values.len(),
                self.dims,
                self.dims[0].saturating_mul(self.dims[1])
            )));
        }
        if self.extent().is_some()
            && !(self.cell > 0.0 && self.cell.is_finite() && self.origin.iter().all(|v| v.is_finite()))
        {
            return Err(PlotError::InvalidData(format!(
                "slice: cell {} and origin {:?}, expected a finite cell > 0 and a finite origin",
                self.cell, self.origin
            )));
        }
        Ok(())
    }
}

/// What a track is; decides its colour, width and dash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TrackKind {
    /// The planner's path: thin, dashed, black.
    Planned,
    /// The simulated true state: solid blue, drawn on top.
    True,
    /// The state estimator's belief: solid orange.
    Estimated,
    /// Anything else, coloured by index from [`palette::CATEGORICAL`].
    Other(usize),
}

impl TrackKind {
    /// The colour of this kind of track in every figure.
    pub fn colour(self) -> Rgb {
        match self {
            TrackKind::Planned => palette::PLANNED,
            TrackKind::True => palette::TRUE_TRACK,
            TrackKind::Estimated => palette::ESTIMATED,
            TrackKind::Other(i) => palette::CATEGORICAL[i % palette::CATEGORICAL.len()],
        }
    }

    /// Line width at the reference size, pixels.
    fn width(self) -> f64 {
        match self {
            TrackKind::Planned => 1.6,
            TrackKind::True => 3.0,
            TrackKind::Estimated => 2.2,
            TrackKind::Other(_) => 2.0,
        }
    }

    fn dashed(self) -> bool {
        self == TrackKind::Planned
    }

    /// Drawing order: the plan at the bottom, the true track on top.
    fn layer(self) -> u8 {
        match self {
            TrackKind::Planned => 0,
            TrackKind::Other(_) => 1,
            TrackKind::Estimated => 2,
            TrackKind::True => 3,
        }
    }
}

/// One polyline of the figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// Legend text.
    pub label: String,
    /// Positions, metres (world frame, z up). Non-finite points break the line.
    pub points: Vec<[f64; 3]>,
    pub kind: TrackKind,
}

/// Everything the trajectory figure shows. Positions in metres, world frame, z up.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryFigure {
    pub title: String,
    pub slice: FieldSlice,
    pub tracks: Vec<Track>,
    pub waypoints: Vec<[f64; 3]>,
    /// Where the drone hit geometry, if it did.
    pub collision: Option<[f64; 3]>,
    pub start: [f64; 3],
    pub goal: [f64; 3],
    /// Allowed altitudes `[z_min, z_max]`, metres.
    pub altitude_band: [f64; 2],
}

impl TrajectoryFigure {
    fn check(&self) -> Result<(), PlotError> {
        self.slice.check()?;
        for (name, p) in [("start", self.start), ("goal", self.goal)] {
            if geometry::finite3(p).is_none() {
                return Err(PlotError::InvalidData(format!("{name} {p:?} is not finite")));
            }
        }
        let [lo, hi] = self.altitude_band;
        if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
            return Err(PlotError::InvalidData(format!("altitude band [{lo}, {hi}]: expected finite z_min ≤ z_max")));
        }
        Ok(())
    }

    /// Every finite point the top view must show.
    fn points_of_interest(&self) -> impl Iterator<Item = [f64; 3]> + '_ {
        self.tracks
            .iter()
            .flat_map(|t| t.points.iter().copied())
            .chain(self.waypoints.iter().copied())
            .chain(self.collision)
            .chain([self.start, self.goal])
            .filter_map(geometry::finite3)
    }

    /// The track that markers are placed along in the side view: the plan, else the first.
    fn reference_track(&self) -> Option<&Track> {
        self.tracks.iter().find(|t| t.kind == TrackKind::Planned).or_else(|| self.tracks.first())
    }
}

/// Where the top view lands in the image: its plotting rectangle and the world window it
/// shows, with equal aspect (one pixel is the same length in x and y).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TopDownView {
    /// The plotting area in image pixels (inside the frame).
    pub plot_area: PixelRect,
    /// World x shown, metres: `x_range[0]` at the left edge.
    pub x_range: [f64; 2],
    /// World y shown, metres: `y_range[0]` at the bottom edge.
    pub y_range: [f64; 2],
}

impl TopDownView {
    /// The image pixel of world point `(x, y)` (metres). Points outside the window map outside
    /// [`TopDownView::plot_area`].
    pub fn world_to_pixel(&self, xy: [f64; 2]) -> [i32; 2] {
        let (x, y) = self.axes().map(xy);
        [x, y]
    }

    /// Metres per pixel (the same along x and y).
    pub fn metres_per_pixel(&self) -> f64 {
        (self.x_range[1] - self.x_range[0]) / f64::from((self.plot_area.width() - 1).max(1))
    }

    fn axes(&self) -> Axes {
        Axes { rect: self.plot_area, x: self.x_range, y: self.y_range }
    }
}

/// Where the top view of `fig` lands in a `width × height` image (see [`TopDownView`]).
pub fn top_down_view(fig: &TrajectoryFigure, width: u32, height: u32) -> Result<TopDownView, PlotError> {
    Ok(Layout::new(fig, width, height)?.top)
}

/// Renders the trajectory figure as a `width × height` PNG.
pub fn trajectory_png(fig: &TrajectoryFigure, width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    let layout = Layout::new(fig, width, height)?;
    render::render_png(width, height, |root| draw_figure(root, fig, &layout, 1))
}

/// Renders the trajectory figure as a `width × height` SVG document.
///
/// The signed-distance map is drawn as blocks of a few pixels (merged along rows) to keep the
/// file small; the obstacle outline on top of it is exact.
pub fn trajectory_svg(fig: &TrajectoryFigure, width: u32, height: u32) -> Result<String, PlotError> {
    let layout = Layout::new(fig, width, height)?;
    let step = (layout.top.plot_area.width() / 200).max(2);
    render::render_svg(width, height, |root| draw_figure(root, fig, &layout, step))
}

// ---------------------------------------------------------------------------------------------
// Layout

#[derive(Debug, Clone, Copy, PartialEq)]
enum Marker {
    Waypoint,
    Start,
    Goal,
    Collision,
}

#[derive(Debug, Clone, PartialEq)]
enum Glyph {
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
enum Dash {
    Solid,
    Dashed,
    Dotted,
}

#[derive(Debug, Clone)]
struct LegendEntry {
    glyph: Glyph,
    label: String,
    /// Left edge of the glyph and the row's centre line, pixels.
    at: (i32, i32),
}

/// Every position and size of the figure, from the image size and the figure's content.
#[derive(Debug)]
struct Layout {
    /// Scale against the reference design (1200 × 680 px).
    s: f64,
    title_size: f64,
    caption_size: f64,
    legend_size: f64,
    title_y: i32,
    legend: Vec<LegendEntry>,
    top: TopDownView,
    /// The side view's plotting rectangle.
    side: PixelRect,
    /// Height of the caption band above each plot.
    caption_h: i32,
}

impl Layout {
    fn new(fig: &TrajectoryFigure, width: u32, height: u32) -> Result<Layout, PlotError> {
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

    fn px(&self, v: f64) -> i32 {
        (v * self.s).round() as i32
    }

    /// A pen of `width` pixels at the reference size.
    fn pen(&self, colour: Rgb, width: f64, dash: Dash) -> Pen {
        let dash = match dash {
            Dash::Solid => None,
            Dash::Dashed => Some(DashPattern { on: 7.0 * self.s, off: 5.0 * self.s }),
            Dash::Dotted => Some(DashPattern { on: 1.5 * self.s, off: 3.0 * self.s }),
        };
        Pen { colour, width: width * self.s, dash }
    }

    fn stroke(&self, v: f64) -> u32 {
        (v * self.s).round().max(1.0) as u32
    }

    fn axes_style<'a>(&self, x_title: &'a str, y_title: &'a str, rect: &PixelRect) -> AxesStyle<'a> {
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
fn field_colour(d: Option<f64>) -> Rgb {
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

// ---------------------------------------------------------------------------------------------
// Drawing

/// Axis title size at the reference size, pixels per em.
const AXIS_TITLE_PX: f64 = 13.0;

/// Width of the altitude band lines at the reference size, pixels.
const BAND_WIDTH: f64 = 1.5;

fn draw_figure<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    fig: &TrajectoryFigure,
    layout: &Layout,
    field_step: i32,
) -> Result<(), PlotError> {
    let (w, _) = root.dim_in_pixel();
    // A title longer than the image is set smaller rather than cut.
    let room = f64::from(w) - 2.0 * f64::from(layout.px(12.0));
    let natural = text::width(&fig.title, layout.title_size)?;
    let size = layout.title_size * (room / natural).min(1.0);
    Text::new(size, palette::INK).align(Align::Centre).draw(root, &fig.title, (w as i32 / 2, layout.title_y))?;
    draw_legend(root, layout)?;
    draw_top_view(root, fig, layout, field_step)?;
    draw_side_view(root, fig, layout)?;
    Ok(())
}

fn draw_legend<DB: Canvas>(root: &DrawingArea<DB, Shift>, layout: &Layout) -> Result<(), PlotError> {
    let glyph_w = layout.px(30.0);
    for e in &layout.legend {
        let (x, y) = e.at;
        match &e.glyph {
            Glyph::Line { colour, width, dash } => {
                let yc = f64::from(y) + 0.5;
                let line = vec![[f64::from(x), yc], [f64::from(x + glyph_w), yc]];
                let pen = layout.pen(*colour, *width, *dash);
                stroke::polylines(root, &[line], pen)?;
            }
            Glyph::Marker(m) => {
                let c = [f64::from(x + glyph_w / 2) + 0.5, f64::from(y) + 0.5];
                draw_marker(root, *m, c, layout)?;
            }
            Glyph::Patch { fill, edge } => {
                let r = layout.px(7.0);
                let c = x + glyph_w / 2;
                let corners = [(c - r, y - r), (c + r + 1, y + r + 1)];
                root.draw(&Rectangle::new(corners, RGBColor::from(*fill).filled()))?;
                let edge = RGBColor::from(*edge).stroke_width(layout.stroke(1.5));
                root.draw(&Rectangle::new([(c - r, y - r), (c + r, y + r)], edge))?;
            }
            Glyph::Ramp => {
                let hh = layout.px(7.0);
                let n = 5;
                for k in 0..n {
                    let d = CLEARANCE_RAMP_M * f64::from(k) / f64::from(n - 1);
                    let (x0, x1) = (x + glyph_w * k / n, x + glyph_w * (k + 1) / n);
                    root.draw(&Rectangle::new(
                        [(x0, y - hh), (x1, y + hh + 1)],
                        RGBColor::from(field_colour(Some(d))).filled(),
                    ))?;
                }
                root.draw(&Rectangle::new(
                    [(x, y - hh), (x + glyph_w, y + hh)],
                    RGBColor::from(palette::GRID).stroke_width(1),
                ))?;
            }
        }
        Text::new(layout.legend_size, palette::INK_SOFT).draw(root, &e.label, (x + glyph_w + layout.px(6.0), y))?;
    }
    Ok(())
}

/// Draws a marker centred on image position `c`.
fn draw_marker<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    marker: Marker,
    c: [f64; 2],
    layout: &Layout,
) -> Result<(), PlotError> {
    let s = layout.s;
    let edge = Some((palette::INK, 1.3 * s));
    match marker {
        Marker::Waypoint => stroke::disc(root, c, 4.5 * s, palette::WHITE, Some((palette::INK, 1.6 * s))),
        Marker::Start => stroke::disc(root, c, 7.0 * s, palette::START, edge),
        Marker::Goal => {
            let (x, y) = stroke::to_int(c);
            let r = layout.px(6.5);
            root.draw(&Rectangle::new(
                [(x - r, y - r), (x + r + 1, y + r + 1)],
                RGBColor::from(palette::GOAL).filled(),
            ))?;
            root.draw(&Rectangle::new(
                [(x - r, y - r), (x + r, y + r)],
                RGBColor::from(palette::INK).stroke_width(layout.stroke(1.2)),
            ))?;
            Ok(())
        }
        Marker::Collision => {
            let r = 8.5 * s;
            let arms =
                [vec![[c[0] - r, c[1] - r], [c[0] + r, c[1] + r]], vec![[c[0] - r, c[1] + r], [c[0] + r, c[1] - r]]];
            for (colour, width) in [(palette::WHITE, 8.0 * s), (palette::COLLISION, 4.0 * s)] {
                let pen = Pen { colour, width, dash: None };
                stroke::polylines(root, &arms, pen)?;
            }
            Ok(())
        }
    }
}

/// The caption above `plot`: the first of `variants` (longest first) that fits `room` pixels.
fn draw_caption<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    variants: &[&str],
    plot: &PixelRect,
    room: i32,
    layout: &Layout,
) -> Result<(), PlotError> {
    let line = text::first_that_fits(variants, layout.caption_size, f64::from(room))?;
    Text::new(layout.caption_size, palette::INK).draw(root, line, (plot.x0, plot.y0 - layout.caption_h / 2))
}

fn tracks_in_layer_order(fig: &TrajectoryFigure) -> Vec<&Track> {
    let mut tracks: Vec<&Track> = fig.tracks.iter().collect();
    tracks.sort_by_key(|t| t.kind.layer()); // stable: same-kind tracks keep their order
    tracks
}

fn draw_track<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    pieces: &[Vec<[f64; 2]>],
    kind: TrackKind,
    layout: &Layout,
) -> Result<(), PlotError> {
    let dash = if kind.dashed() { Dash::Dashed } else { Dash::Solid };
    stroke::polylines(root, pieces, layout.pen(kind.colour(), kind.width(), dash))
}

fn draw_top_view<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    fig: &TrajectoryFigure,
    layout: &Layout,
    field_step: i32,
) -> Result<(), PlotError> {
    let view = &layout.top;
    let axes = view.axes();
    let plot = axes.rect;
    let win = axes.window();
    let z = fig.slice.altitude;
    let long = format!("Top view · signed distance at z = {z:.2} m");
    let short = format!("Top view · z = {z:.2} m");
    let room = layout.side.x0 - layout.px(64.0) - plot.x0;
    draw_caption(root, &[&long, &short, "Top view"], &plot, room, layout)?;

    // The signed-distance map: runs of equal colour along rows of `field_step` pixels.
    let step = field_step.max(1);
    let mut py = plot.y0;
    while py < plot.y1 {
        let y_end = (py + step).min(plot.y1);
        let mut run: Option<(i32, Rgb)> = None;
        let mut px = plot.x0;
        loop {
            let colour = (px < plot.x1).then(|| {
                let c = axes.unmap_centre(px + step / 2, py + step / 2);
                field_colour(fig.slice.value_at(c))
            });
            match (run, colour) {
                (Some((_, rc)), Some(c)) if rc == c => {}
                (Some((x0, rc)), _) => {
                    root.draw(&Rectangle::new([(x0, py), (px, y_end)], RGBColor::from(rc).filled()))?;
                    run = colour.map(|c| (px, c));
                }
                (None, _) => run = colour.map(|c| (px, c)),
            }
            if px >= plot.x1 {
                break;
            }
            px = (px + step).min(plot.x1);
        }
        py = y_end;
    }

    // The obstacle surface: the zero contour of the slice's bilinear interpolation.
    let slice = &fig.slice;
    let contour = geometry::zero_contour(slice.origin, slice.cell, slice.dims, |i, j| slice.node(i, j), &win);
    let outline: Vec<Vec<[f64; 2]>> = contour
        .into_iter()
        .filter_map(|(a, b)| geometry::clip_segment(a, b, &win))
        .map(|(a, b)| vec![axes.map_f(a), axes.map_f(b)])
        .collect();
    stroke::polylines(root, &outline, layout.pen(palette::SURFACE, 2.0, Dash::Solid))?;

    let style = layout.axes_style("x (m)", "y (m)", &plot);
    axes.draw_frame(root, &style)?;

    for track in tracks_in_layer_order(fig) {
        let xy = track.points.iter().map(|&p| geometry::finite3(p).map(|p| [p[0], p[1]]));
        let pieces: Vec<Vec<[f64; 2]>> = geometry::clip_polyline(xy, &win)
            .into_iter()
            .map(|piece| piece.into_iter().map(|p| axes.map_f(p)).collect())
            .collect();
        draw_track(root, &pieces, track.kind, layout)?;
    }
    let markers = fig
        .waypoints
        .iter()
        .map(|&p| (Marker::Waypoint, p))
        .chain([(Marker::Start, fig.start), (Marker::Goal, fig.goal)])
        .chain(fig.collision.map(|p| (Marker::Collision, p)));
    for (marker, p) in markers {
        if let Some(p) = geometry::finite3(p).filter(|p| win.contains([p[0], p[1]])) {
            draw_marker(root, marker, axes.map_f([p[0], p[1]]), layout)?;
        }
    }
    Ok(())
}

fn draw_side_view<DB: Canvas>(
    root: &DrawingArea<DB, Shift>,
    fig: &TrajectoryFigure,
    layout: &Layout,
) -> Result<(), PlotError> {
    let plot = layout.side;
    let (image_w, _) = root.dim_in_pixel();
    let room = image_w as i32 - layout.px(8.0) - plot.x0;
    let captions = ["Side view · altitude along the track", "Side view"];
    draw_caption(root, &captions, &plot, room, layout)?;

    // (s, z) polylines: s is the horizontal distance travelled along each track.
    let profiles: Vec<(&Track, Vec<Option<[f64; 2]>>)> = tracks_in_layer_order(fig)
        .into_iter()
        .map(|t| {
            let s = geometry::xy_arc_length(&t.points);
            let sz = t.points.iter().zip(s).map(|(p, s)| Some([s?, p[2]])).collect();
            (t, sz)
        })
        .collect();
    // Markers sit where they project onto the plan (the collision: onto the true track).
    let reference = fig.reference_track();
    let true_track = fig.tracks.iter().find(|t| t.kind == TrackKind::True).or(reference);
    let along = |track: Option<&Track>, p: [f64; 3]| -> Option<[f64; 2]> {
        let p = geometry::finite3(p)?;
        let (s, _) = geometry::project_onto_track(&track?.points, p)?;
        Some([s, p[2]])
    };
    let mut markers: Vec<(Marker, [f64; 2])> =
        fig.waypoints.iter().filter_map(|&p| Some((Marker::Waypoint, along(reference, p)?))).collect();
    markers.push((Marker::Start, [0.0, fig.start[2]]));
    if let Some(g) = along(reference, fig.goal) {
        markers.push((Marker::Goal, g));
    }
    if let Some(c) = fig.collision.and_then(|c| along(true_track, c)) {
        markers.push((Marker::Collision, c));
    }

    // Ranges: every profile and marker, the band and the ground.
    let [band_lo, band_hi] = fig.altitude_band;
    let mut s_max: f64 = 0.0;
    let (mut z_lo, mut z_hi) = (band_lo.min(0.0), band_hi.max(0.0));
    let all = profiles.iter().flat_map(|(_, sz)| sz.iter().flatten().copied()).chain(markers.iter().map(|m| m.1));
    for [s, z] in all {
        s_max = s_max.max(s);
        z_lo = z_lo.min(z);
        z_hi = z_hi.max(z);
    }
    let s_max = s_max.max(0.5);
    let z_span = (z_hi - z_lo).max(0.5);
    let axes = Axes { rect: plot, x: [-0.03 * s_max, 1.03 * s_max], y: [z_lo - 0.1 * z_span, z_hi + 0.12 * z_span] };
    let win = axes.window();
    let x_titles = ["horizontal distance along the track (m)", "distance along the track (m)", "distance (m)"];
    let room = f64::from(plot.width());
    let x_title = text::first_that_fits(&x_titles, AXIS_TITLE_PX * layout.s, room)?;
    let style = layout.axes_style(x_title, "altitude z (m)", &plot);
    let (x0, x1) = (plot.x0, plot.x1);

    // Under the data: ground, the band's tint, the grid.
    let (_, ground) = axes.map([0.0, 0.0]);
    root.draw(&Rectangle::new([(x0, ground), (x1, plot.y1)], RGBColor::from(palette::GROUND).filled()))?;
    let (_, band_top) = axes.map([0.0, band_hi]);
    let (_, band_bottom) = axes.map([0.0, band_lo]);
    root.draw(&Rectangle::new([(x0, band_top), (x1, band_bottom)], RGBColor::from(palette::BAND_TINT).filled()))?;
    axes.draw_grid(root, &style, palette::GRID)?;
    let across = |y: i32| {
        let y = f64::from(y) + 0.5;
        vec![vec![[f64::from(x0), y], [f64::from(x1), y]]]
    };
    stroke::polylines(root, &across(ground), layout.pen(palette::SOLID, 1.5, Dash::Solid))?;
    Text::new(style.tick_size * 0.95, palette::SOLID).align(Align::Right).draw(
        root,
        "ground",
        (x1 - layout.px(6.0), ground + layout.px(10.0)),
    )?;
    for y in [band_top, band_bottom] {
        stroke::polylines(root, &across(y), layout.pen(palette::BAND, BAND_WIDTH, Dash::Dashed))?;
    }
    let slice_z = fig.slice.altitude;
    if slice_z.is_finite() && win.contains([0.0, slice_z]) {
        let (_, y) = axes.map([0.0, slice_z]);
        stroke::polylines(root, &across(y), layout.pen(palette::SOLID, 1.0, Dash::Dotted))?;
    }

    for (track, sz) in &profiles {
        let pieces: Vec<Vec<[f64; 2]>> = geometry::clip_polyline(sz.iter().copied(), &win)
            .into_iter()
            .map(|piece| piece.into_iter().map(|p| axes.map_f(p)).collect())
            .collect();
        draw_track(root, &pieces, track.kind, layout)?;
    }
    for (marker, p) in markers {
        if win.contains(p) {
            draw_marker(root, marker, axes.map_f(p), layout)?;
        }
    }
    axes.draw_frame(root, &style)?;
    Ok(())
}
