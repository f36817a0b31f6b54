//! The trajectory figure's public types and constants: the signed-distance slice, the tracks,
//! the figure itself and where its top view lands.

use crate::axes::{Axes, PixelRect};
use crate::geometry;
use crate::palette::{self, Rgb};
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

    pub(super) fn node(&self, i: usize, j: usize) -> f64 {
        f64::from(self.values[i + self.dims[0] * j])
    }

    pub(super) fn check(&self) -> Result<(), PlotError> {
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
    pub(super) fn width(self) -> f64 {
        match self {
            TrackKind::Planned => 1.6,
            TrackKind::True => 3.0,
            TrackKind::Estimated => 2.2,
            TrackKind::Other(_) => 2.0,
        }
    }

    pub(super) fn dashed(self) -> bool {
        self == TrackKind::Planned
    }

    /// Drawing order: the plan at the bottom, the true track on top.
    pub(super) fn layer(self) -> u8 {
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
    pub(super) fn check(&self) -> Result<(), PlotError> {
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
    pub(super) fn points_of_interest(&self) -> impl Iterator<Item = [f64; 3]> + '_ {
        self.tracks
            .iter()
            .flat_map(|t| t.points.iter().copied())
            .chain(self.waypoints.iter().copied())
            .chain(self.collision)
            .chain([self.start, self.goal])
            .filter_map(geometry::finite3)
    }

    /// The track that markers are placed along in the side view: the plan, else the first.
    pub(super) fn reference_track(&self) -> Option<&Track> {
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

    pub(super) fn axes(&self) -> Axes {
        Axes { rect: self.plot_area, x: self.x_range, y: self.y_range }
    }
}
