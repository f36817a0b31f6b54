//! Figures of nerfsv, rendered to PNG bytes or SVG text with plotters and an embedded font
//! (DejaVu Sans), so a figure looks the same on every machine and needs no system libraries.
//!
//! The crate takes plain data (`f64` metres, no other nerfsv types) and returns bytes; the
//! caller decides where they go (and writes files atomically). Shared pieces: [`palette`] (the
//! colours every figure and the HTML report use), [`encode_png`] (RGB8 → PNG with the `png`
//! crate) and [`PlotError`].
//!
//! Figures:
//! - [`trajectory_png`] / [`trajectory_svg`]: one flight, top view over the signed-distance
//!   slice and side view of altitude along the track ([`trajectory`] describes the layout).
//! - [`camera_view::camera_panels_rgb`]: what a drone's camera saw in each world, one frame of a
//!   failure's animation.
//! - [`glb::glb_bytes`]: triangle meshes and polylines as a binary glTF 2.0 file (`nerfsv export`),
//!   for Blender or any glTF viewer.
//! - [`histograms_png`] / [`histograms_svg`]: histograms of one quantity per group (split) on
//!   shared bins; [`scatter_png`] / [`scatter_svg`]: two quantities coloured by group
//!   ([`distribution`]).
//!
//! ```
//! use nerfsv_plot::{trajectory_png, FieldSlice, Track, TrackKind, TrajectoryFigure};
//!
//! // A 2 × 2 m slice with a disc obstacle of radius 0.3 m at the origin, 0.1 m cells.
//! let (n, cell, origin) = (21, 0.1, [-1.0, -1.0]);
//! let values = (0..n * n)
//!     .map(|k| {
//!         let (x, y) = (origin[0] + cell * (k % n) as f64, origin[1] + cell * (k / n) as f64);
//!         (x.hypot(y) - 0.3) as f32
//!     })
//!     .collect();
//! let fig = TrajectoryFigure {
//!     title: "run 7".into(),
//!     slice: FieldSlice { origin, cell, dims: [n, n], values, altitude: 1.0 },
//!     tracks: vec![Track {
//!         label: "true".into(),
//!         points: vec![[-0.8, -0.5, 1.0], [0.0, -0.6, 1.1], [0.8, -0.5, 1.0]],
//!         kind: TrackKind::True,
//!     }],
//!     waypoints: vec![],
//!     collision: None,
//!     start: [-0.8, -0.5, 1.0],
//!     goal: [0.8, -0.5, 1.0],
//!     altitude_band: [0.5, 1.5],
//! };
//! let png = trajectory_png(&fig, 900, 500)?;
//! assert_eq!(&png[1..4], b"PNG");
//! # Ok::<(), nerfsv_plot::PlotError>(())
//! ```

mod axes;
pub mod camera_view;
pub mod distribution;
mod error;
mod font;
mod geometry;
pub mod glb;
pub mod heatmap;
pub mod palette;
mod render;
mod stroke;
mod text;
pub mod trajectory;

pub use axes::PixelRect;
pub use distribution::{
    histograms_png, histograms_svg, scatter_png, scatter_svg, Group, HistogramFigure, PointGroup, ScatterFigure,
};
pub use error::PlotError;
pub use heatmap::{heatmap_png, ColourScale, Heatmap, HeatmapFigure};
pub use render::{encode_png, MAX_SIDE};
pub use trajectory::{
    top_down_view, trajectory_png, trajectory_svg, FieldSlice, TopDownView, Track, TrackKind, TrajectoryFigure,
};
