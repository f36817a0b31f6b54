//! Heat maps as a person reads them: decoded PNGs of known fields.

use nerfsv_plot::heatmap::ramp;
use nerfsv_plot::palette::{self, Rgb};
use nerfsv_plot::{heatmap_png, ColourScale, Heatmap, HeatmapFigure};

fn panel(values: Vec<f64>, dims: [usize; 2], scale: ColourScale) -> Heatmap {
    Heatmap {
        caption: "field".into(),
        x_title: "x (m)".into(),
        y_title: "y (m)".into(),
        colour_title: "value".into(),
        origin: [-1.0, -1.0],
        cell: [0.1, 0.1],
        dims,
        values,
        scale,
    }
}

fn decode(png: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn pixel(rgb: &[u8], w: u32, x: u32, y: u32) -> Rgb {
    let k = 3 * (y * w + x) as usize;
    Rgb(rgb[k], rgb[k + 1], rgb[k + 2])
}

/// Whether `c` is (nearly) a colour of the sequential ramp, and where on it.
fn on_ramp(c: Rgb) -> Option<f64> {
    (0..=200).map(|k| k as f64 / 200.0).find(|&t| {
        let r = ramp(t, false);
        (r.0 as i32 - c.0 as i32).abs() + (r.1 as i32 - c.1 as i32).abs() + (r.2 as i32 - c.2 as i32).abs() <= 6
    })
}

#[test]
fn a_field_increasing_in_x_is_dark_on_the_left_and_light_on_the_right() {
    let (nx, ny) = (21, 21);
    let values: Vec<f64> = (0..nx * ny).map(|k| (k % nx) as f64).collect();
    let fig = HeatmapFigure { title: "ramp".into(), panels: vec![panel(values, [nx, ny], ColourScale::Linear)] };
    let (w, h, rgb) = decode(&heatmap_png(&fig, 600, 500).unwrap());
    assert_eq!((w, h), (600, 500));
    // Along the middle row, the ramp-coloured pixels of the plot run from low to high.
    let ts: Vec<f64> = (0..w / 2 + 150).filter_map(|x| on_ramp(pixel(&rgb, w, x, h / 2))).collect();
    assert!(ts.len() > 100, "{} ramp pixels", ts.len());
    assert!(ts[0] < 0.1 && ts[ts.len() / 2] > 0.3, "{:?} … {:?}", &ts[..3], &ts[ts.len() / 2]);
    assert!(ts.windows(2).filter(|p| p[1] + 1e-9 < p[0]).count() < 3, "not increasing left to right");
}

#[test]
fn cells_without_a_value_are_grey_and_a_constant_field_draws() {
    let values = vec![f64::NAN; 100];
    let fig = HeatmapFigure { title: "empty".into(), panels: vec![panel(values, [10, 10], ColourScale::Log)] };
    let (w, h, rgb) = decode(&heatmap_png(&fig, 500, 400).unwrap());
    let grey = (0..w * h).filter(|&k| pixel(&rgb, w, k % w, k / w) == palette::NO_DATA).count();
    assert!(grey > 20_000, "{grey} no-data pixels");
    // Non-positive values are no data on a log scale; a constant field still has a range.
    let fig = HeatmapFigure {
        title: "constant".into(),
        panels: vec![
            panel(vec![2.0; 100], [10, 10], ColourScale::Linear),
            panel(vec![-1.0; 100], [10, 10], ColourScale::Log),
        ],
    };
    assert!(heatmap_png(&fig, 800, 400).is_ok());
}

#[test]
fn bad_panels_are_refused_by_name() {
    let cases = [
        (panel(vec![1.0; 5], [2, 3], ColourScale::Linear), "5 values"),
        (panel(vec![], [0, 3], ColourScale::Linear), "dims"),
        (Heatmap { cell: [0.0, 0.1], ..panel(vec![1.0; 4], [2, 2], ColourScale::Linear) }, "cell"),
        (Heatmap { origin: [f64::NAN, 0.0], ..panel(vec![1.0; 4], [2, 2], ColourScale::Linear) }, "origin"),
    ];
    for (p, what) in cases {
        let e = heatmap_png(&HeatmapFigure { title: "t".into(), panels: vec![p] }, 500, 400).unwrap_err().to_string();
        assert!(e.contains("\"field\"") && e.contains(what), "{what}: {e}");
    }
    let e = heatmap_png(&HeatmapFigure { title: "none".into(), panels: vec![] }, 500, 400).unwrap_err().to_string();
    assert!(e.contains("no panels"), "{e}");
}
