//! Drawing the trajectory figure: title, legend, the top view over the signed-distance map and
//! the side view of altitude along the track.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::axes::{Axes, PixelRect};
use crate::geometry;
use crate::palette::{self, Rgb};
use crate::render::Canvas;
use crate::stroke::{self, Pen};
use crate::text::{self, Align, Text};
use crate::PlotError;

use super::layout::{field_colour, Dash, Glyph, Layout, Marker, AXIS_TITLE_PX, BAND_WIDTH};
use super::types::{Track, TrackKind, TrajectoryFigure, CLEARANCE_RAMP_M};

pub(super) fn draw_figure<DB: Canvas>(
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
