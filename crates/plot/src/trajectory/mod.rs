//! The trajectory figure: one flight seen from above over the signed-distance slice of the
//! world (left, about two thirds of the width) and from the side as altitude against the
//! horizontal distance travelled (right).
//!
//! Layout, top to bottom: the title; a legend row (wrapped when long); the two panels, each with
//! a caption. The top view is zoomed to the tracks, start, goal, waypoints and collision with a
//! [`ZOOM_MARGIN_M`] margin (clipped to the slice) and has equal aspect: its x or y range grows
//! to fill the panel. Sizes scale with the image (the reference design is 1200 × 680 px).

use crate::render;
use crate::PlotError;

mod draw;
mod layout;
mod types;

pub use self::types::{
    FieldSlice, TopDownView, Track, TrackKind, TrajectoryFigure, CLEARANCE_RAMP_M, CLEARANCE_STEP_M, MIN_SIZE,
    ZOOM_MARGIN_M,
};

use self::draw::draw_figure;
use self::layout::Layout;

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
