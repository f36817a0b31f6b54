//! The trajectory figure, checked on its pixels: a disc obstacle, a plan around it, a true track
//! that hits it, an estimate offset a little from the truth.

use nerfsv_plot::palette::{self, Rgb};
use nerfsv_plot::{
    top_down_view, trajectory_png, trajectory_svg, FieldSlice, PlotError, Track, TrackKind, TrajectoryFigure,
};

const W: u32 = 1000;
const H: u32 = 600;
const DISC_RADIUS: f64 = 0.5;

/// Signed distance to a disc of radius 0.5 m at the origin, on 0.05 m cells over ±2 m.
fn disc_slice() -> FieldSlice {
    let (cell, n, origin) = (0.05, 81, [-2.0, -2.0]);
    let values = (0..n * n)
        .map(|k| {
            let (x, y) = (origin[0] + cell * (k % n) as f64, origin[1] + cell * (k / n) as f64);
            (x.hypot(y) - DISC_RADIUS) as f32
        })
        .collect();
    FieldSlice { origin, cell, dims: [n, n], values, altitude: 1.0 }
}

/// Polyline samples of `f(t)` for t in [0, 1].
fn curve(n: usize, f: impl Fn(f64) -> [f64; 3]) -> Vec<[f64; 3]> {
    (0..=n).map(|k| f(k as f64 / n as f64)).collect()
}

fn figure(title: &str) -> TrajectoryFigure {
    // Plan: from (−1.5, 0) over the top of the disc to (1.5, 0), 0.9 m above its centre.
    let planned = curve(60, |t| {
        let a = std::f64::consts::PI * (1.0 - t);
        [1.5 * a.cos(), 0.9 * a.sin(), 1.0]
    });
    // Truth: straight from (−1.5, −0.3) into the disc's left side, slowly descending.
    let true_track = curve(40, |t| [-1.5 + 0.98 * t, -0.3 + 0.25 * t, 1.0 - 0.1 * t]);
    let estimated = true_track.iter().map(|p| [p[0], p[1] - 0.12, p[2] + 0.02]).collect();
    TrajectoryFigure {
        title: title.to_string(),
        slice: disc_slice(),
        tracks: vec![
            Track { label: "planned".into(), points: planned, kind: TrackKind::Planned },
            Track { label: "true".into(), points: true_track, kind: TrackKind::True },
            Track { label: "estimated".into(), points: estimated, kind: TrackKind::Estimated },
        ],
        waypoints: vec![[-1.5, 0.0, 1.0], [0.0, 0.9, 1.0], [1.5, 0.0, 1.0]],
        collision: Some([-0.52, -0.05, 0.9]),
        start: [-1.5, 0.0, 1.0],
        goal: [1.5, 0.0, 1.0],
        altitude_band: [0.5, 1.5],
    }
}

struct Image {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Image {
    fn decode(png_bytes: &[u8]) -> Image {
        let decoder = png::Decoder::new(std::io::Cursor::new(png_bytes));
        let mut reader = decoder.read_info().expect("a PNG header");
        let mut rgb = vec![0; reader.output_buffer_size().expect("a sane size")];
        let info = reader.next_frame(&mut rgb).expect("one frame");
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        rgb.truncate(info.buffer_size());
        Image { width: info.width, height: info.height, rgb }
    }

    fn at(&self, [x, y]: [i32; 2]) -> Rgb {
        assert!(x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height);
        let k = 3 * (y as usize * self.width as usize + x as usize);
        Rgb(self.rgb[k], self.rgb[k + 1], self.rgb[k + 2])
    }

    /// Pixels darker than mid-grey in rows `y0..y1`.
    fn dark_pixels_in_rows(&self, y0: u32, y1: u32) -> usize {
        (y0..y1)
            .flat_map(|y| (0..self.width).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let c = self.at([x as i32, y as i32]);
                u32::from(c.0) + u32::from(c.1) + u32::from(c.2) < 3 * 100
            })
            .count()
    }
}

fn close(a: Rgb, b: Rgb, tolerance: u8) -> bool {
    a.0.abs_diff(b.0) <= tolerance && a.1.abs_diff(b.1) <= tolerance && a.2.abs_diff(b.2) <= tolerance
}

#[test]
fn png_decodes_at_the_requested_size() {
    let img = Image::decode(&trajectory_png(&figure("run 1"), W, H).unwrap());
    assert_eq!((img.width, img.height), (W, H));
    assert_eq!(img.rgb.len(), (W * H * 3) as usize);
}

#[test]
fn middle_of_the_true_track_has_the_true_track_colour() {
    let fig = figure("run 1");
    let img = Image::decode(&trajectory_png(&fig, W, H).unwrap());
    let view = top_down_view(&fig, W, H).unwrap();
    let truth = &fig.tracks[1].points;
    let mid = truth[truth.len() / 2];
    let px = view.world_to_pixel([mid[0], mid[1]]);
    assert!(view.plot_area.contains(px), "{px:?} outside {:?}", view.plot_area);
    let got = img.at(px);
    assert!(close(got, palette::TRUE_TRACK, 8), "at {px:?}: {got:?}, expected {:?}", palette::TRUE_TRACK);
    // The estimate, 0.12 m below, is drawn in its own colour and does not cover the truth.
    let est = view.world_to_pixel([mid[0], mid[1] - 0.12]);
    assert!(close(img.at(est), palette::ESTIMATED, 8), "estimate at {est:?}: {:?}", img.at(est));
}

#[test]
fn obstacle_inside_is_solid_and_free_space_lightens_with_clearance() {
    let fig = figure("run 1");
    let img = Image::decode(&trajectory_png(&fig, W, H).unwrap());
    let view = top_down_view(&fig, W, H).unwrap();
    for p in [[0.0, 0.0], [0.2, -0.25], [-0.3, 0.1]] {
        assert_eq!(img.at(view.world_to_pixel(p)), palette::SOLID, "inside the disc at {p:?}");
    }
    // 5 cm outside the surface: the shade next to geometry; 1.2 m out: white.
    let near = img.at(view.world_to_pixel([DISC_RADIUS + 0.05, 0.0]));
    assert_eq!(near, palette::CLEARANCE_NEAR);
    let far = img.at(view.world_to_pixel([1.2, -1.2]));
    assert_eq!(far, palette::WHITE, "free space 1.2 m from the disc");
}

#[test]
fn collision_point_is_marked_in_red() {
    let fig = figure("run 1");
    let img = Image::decode(&trajectory_png(&fig, W, H).unwrap());
    let view = top_down_view(&fig, W, H).unwrap();
    let c = fig.collision.unwrap();
    let got = img.at(view.world_to_pixel([c[0], c[1]]));
    assert!(close(got, palette::COLLISION, 8), "{got:?}");
}

#[test]
fn title_band_holds_dark_text_pixels_only_when_there_is_a_title() {
    let band = H / 18; // the title's row, above the legend
    let titled = Image::decode(&trajectory_png(&figure("Run 0042 · collision"), W, H).unwrap());
    let untitled = Image::decode(&trajectory_png(&figure(""), W, H).unwrap());
    let (with, without) = (titled.dark_pixels_in_rows(0, band), untitled.dark_pixels_in_rows(0, band));
    assert!(with > 150, "{with} dark pixels in the title band");
    assert_eq!(without, 0);
}

#[test]
fn top_view_has_equal_aspect_and_shows_every_track() {
    let fig = figure("run 1");
    let view = top_down_view(&fig, W, H).unwrap();
    let mx = (view.x_range[1] - view.x_range[0]) / f64::from(view.plot_area.width() - 1);
    let my = (view.y_range[1] - view.y_range[0]) / f64::from(view.plot_area.height() - 1);
    assert!((mx / my - 1.0).abs() < 1e-9, "{mx} vs {my} m/px");
    assert!((view.metres_per_pixel() - mx).abs() < 1e-15);
    for p in fig.tracks.iter().flat_map(|t| &t.points) {
        assert!(view.plot_area.contains(view.world_to_pixel([p[0], p[1]])), "{p:?}");
    }
    // Zoomed: the flight spans about 3.6 × 1.6 m of the 4 × 4 m slice, and the view stays inside it.
    assert!(view.x_range[0] >= -2.0 - 1e-9 && view.x_range[1] <= 2.0 + 1e-9, "{view:?}");
    assert!(view.y_range[0] >= -2.0 - 1e-9 && view.y_range[1] <= 2.0 + 1e-9, "{view:?}");
    assert!(view.y_range[1] - view.y_range[0] < 3.0, "{view:?}");
}

#[test]
fn svg_is_a_document_holding_the_escaped_title() {
    let svg = trajectory_svg(&figure("Run <7> & friends"), W, H).unwrap();
    assert!(svg.starts_with("<svg"), "{}", &svg[..80.min(svg.len())]);
    assert!(svg.trim_end().ends_with("</svg>"));
    assert!(svg.contains("Run &lt;7&gt; &amp; friends"));
    assert_eq!(svg.matches("<text").count(), svg.matches("</text>").count());
    assert!(svg.contains(&palette::TRUE_TRACK.hex().to_uppercase()[1..]));
}

#[test]
fn diverged_tracks_with_non_finite_points_still_render() {
    let mut fig = figure("run 1");
    fig.tracks[1].points.push([f64::NAN, 1e300, f64::INFINITY]);
    fig.tracks[1].points.push([0.0, 0.0, 1.0]);
    fig.waypoints.push([f64::NAN; 3]);
    assert!(trajectory_png(&fig, W, H).is_ok());
    assert!(trajectory_svg(&fig, W, H).is_ok());
}

#[test]
fn a_figure_without_slice_data_or_with_huge_coordinates_still_renders() {
    let mut fig = figure("no slice");
    fig.slice = FieldSlice { origin: [0.0, 0.0], cell: 0.1, dims: [0, 0], values: Vec::new(), altitude: 1.0 };
    let img = Image::decode(&trajectory_png(&fig, W, H).unwrap());
    let view = top_down_view(&fig, W, H).unwrap();
    assert_eq!(img.at(view.world_to_pixel([0.0, 0.0])), palette::NO_DATA);
    fig.tracks[1].points.push([1e300, -1e300, 1e300]);
    assert!(trajectory_png(&fig, W, H).is_ok());
    assert!(trajectory_svg(&fig, W, H).is_ok());
}

#[test]
fn inconsistent_input_is_rejected_with_a_reason() {
    let mut fig = figure("run 1");
    fig.slice.values.pop();
    let err = trajectory_png(&fig, W, H).unwrap_err();
    assert!(matches!(err, PlotError::InvalidData(_)), "{err}");
    assert!(err.to_string().contains("6560 values"), "{err}");

    let mut fig = figure("run 1");
    fig.altitude_band = [1.5, 0.5];
    assert!(matches!(trajectory_png(&fig, W, H), Err(PlotError::InvalidData(_))));

    let fig = figure("run 1");
    assert!(matches!(trajectory_png(&fig, 100, 80), Err(PlotError::InvalidSize { .. })));
    assert!(matches!(trajectory_svg(&fig, 0, 600), Err(PlotError::InvalidSize { .. })));
}
