//! Histograms and scatter plots, checked on their pixels: each group is drawn in its own colour
//! in its own panel, values that are not finite are left out, bad sizes and bins are refused.

use nerfsv_plot::distribution::group_colour;
use nerfsv_plot::palette::Rgb;
use nerfsv_plot::{
    histograms_png, histograms_svg, scatter_png, scatter_svg, Group, HistogramFigure, PlotError, PointGroup,
    ScatterFigure,
};

const W: u32 = 900;
const H: u32 = 420;

/// (width, height, RGB8 pixels).
fn decode(png_bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::Cursor::new(png_bytes));
    let mut reader = decoder.read_info().expect("a PNG header");
    let mut rgb = vec![0; reader.output_buffer_size().expect("a sane size")];
    let info = reader.next_frame(&mut rgb).expect("one frame");
    rgb.truncate(info.buffer_size());
    (info.width, info.height, rgb)
}

/// Columns (x) of the pixels that have exactly colour `c`.
fn columns_of(width: u32, rgb: &[u8], c: Rgb) -> Vec<u32> {
    rgb.chunks_exact(3).enumerate().filter(|(_, p)| p == &c.to_array()).map(|(k, _)| k as u32 % width).collect()
}

fn three_splits() -> HistogramFigure {
    let spread = |n: usize, lo: f64| (0..n).map(|k| lo + k as f64 * 0.1).collect::<Vec<_>>();
    let mut val = spread(10, 1.2);
    val.push(f64::NAN);
    HistogramFigure {
        title: "σ_d per image".into(),
        x_title: "σ_d".into(),
        y_title: "images".into(),
        groups: vec![
            Group { label: "train".into(), values: spread(20, 1.0) },
            Group { label: "val".into(), values: val },
            Group { label: "test".into(), values: spread(10, 1.5) },
        ],
        bins: 8,
    }
}

#[test]
fn each_group_is_drawn_in_its_colour_in_its_own_panel_left_to_right() {
    let (w, h, rgb) = decode(&histograms_png(&three_splits(), W, H).unwrap());
    assert_eq!((w, h), (W, H));
    let spans: Vec<(u32, u32)> = (0..3)
        .map(|k| {
            let cols = columns_of(w, &rgb, group_colour(k));
            assert!(cols.len() > 500, "group {k}: {} pixels of its colour", cols.len());
            (*cols.iter().min().unwrap(), *cols.iter().max().unwrap())
        })
        .collect();
    // The panels do not overlap and run train, val, test from left to right.
    assert!(spans[0].1 < spans[1].0 && spans[1].1 < spans[2].0, "{spans:?}");
}

#[test]
fn a_group_without_finite_values_draws_no_bars() {
    let mut fig = three_splits();
    fig.groups[1].values = vec![f64::NAN, f64::INFINITY];
    let (w, _, rgb) = decode(&histograms_png(&fig, W, H).unwrap());
    assert!(columns_of(w, &rgb, group_colour(1)).is_empty());
    assert!(!columns_of(w, &rgb, group_colour(0)).is_empty());
}

#[test]
fn scatter_points_take_their_group_colour_and_svg_is_a_document() {
    let fig = ScatterFigure {
        title: "μ_d and σ_d".into(),
        x_title: "μ_d".into(),
        y_title: "σ_d".into(),
        groups: vec![
            PointGroup { label: "train".into(), points: vec![[1.0, 2.0], [1.1, 2.5], [f64::NAN, 1.0]] },
            PointGroup { label: "test".into(), points: vec![[1.3, 1.5]] },
        ],
    };
    let (w, _, rgb) = decode(&scatter_png(&fig, W, H).unwrap());
    let train = columns_of(w, &rgb, group_colour(0));
    let test = columns_of(w, &rgb, group_colour(1));
    assert!(!train.is_empty() && !test.is_empty());
    // The test point has the largest μ_d: its disc lies right of every train disc (legend aside,
    // which sits above the plot, the rightmost test pixels belong to it).
    assert!(test.iter().max() > train.iter().max(), "{:?} vs {:?}", test.iter().max(), train.iter().max());
    let svg = scatter_svg(&fig, W, H).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("μ_d"));
    assert!(histograms_svg(&three_splits(), W, H).unwrap().contains("train"));
}

#[test]
fn tiny_sizes_and_zero_bins_are_refused() {
    assert!(matches!(histograms_png(&three_splits(), 100, 100), Err(PlotError::InvalidSize { .. })));
    let mut fig = three_splits();
    fig.bins = 0;
    assert!(matches!(histograms_png(&fig, W, H), Err(PlotError::InvalidData(_))));
}
