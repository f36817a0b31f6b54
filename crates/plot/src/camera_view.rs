//! What a drone's camera saw, one panel per world, as a frame of a failure's animation: the
//! image enlarged, a title above it, lines of text below, a `+` at the image centre (where the
//! camera aims) and an `×` where the estimated camera believes it aims, and a red frame once the
//! drone has crashed.

use plotters::prelude::*;

use crate::palette::{self, Rgb};
use crate::render::check_size;
use crate::text::Text;
use crate::PlotError;

/// One camera's picture in a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPanel {
    pub title: String,
    /// The image, RGB8 rows from the top, `width × height` pixels.
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    /// Lines of text under the image.
    pub lines: Vec<String>,
    /// Where, in the image's pixel coordinates (`[column, row]`, from the top left corner), the
    /// estimated camera's optical axis points; `None` when that point is behind the camera.
    pub estimate_aim: Option<[f64; 2]>,
    /// Framed in red: the drone has crashed.
    pub crashed: bool,
}

const PAD: u32 = 10;
const TITLE: u32 = 30;
const LINE: u32 = 22;

/// The frame's size for `panels` enlarged `scale`× (nearest neighbour), with a footer line.
fn layout(panels: &[CameraPanel], scale: u32) -> (u32, u32, u32) {
    let lines = panels.iter().map(|p| p.lines.len() as u32).max().unwrap_or(0) + 1;
    let panel_w = panels.iter().map(|p| p.width * scale).max().unwrap_or(0);
    let image_h = panels.iter().map(|p| p.height * scale).max().unwrap_or(0);
    let width = PAD + panels.len() as u32 * (panel_w + PAD);
    (width, PAD + TITLE + image_h + PAD + lines * LINE + PAD, panel_w)
}

/// The panels side by side on white, each image enlarged `scale`× (1 to 16), and `footer` under
/// them all: an RGB8 buffer and its width and height.
pub fn camera_panels_rgb(panels: &[CameraPanel], scale: u32, footer: &str) -> Result<(Vec<u8>, u32, u32), PlotError> {
    if panels.is_empty() || !(1..=16).contains(&scale) {
        return Err(PlotError::InvalidData(format!("{} panels at {scale}×: need one or more at 1–16×", panels.len())));
    }
    for p in panels {
        if p.rgb.len() != 3 * p.width as usize * p.height as usize {
            return Err(PlotError::InvalidData(format!(
                "panel {:?}: {} bytes for a {}×{} image",
                p.title,
                p.rgb.len(),
                p.width,
                p.height
            )));
        }
    }
    let (width, height, panel_w) = layout(panels, scale);
    check_size(width, height, (1, 1))?;
    crate::font::ensure_registered()?;
    let mut rgb = vec![255u8; 3 * width as usize * height as usize];
    let origin = |i: usize| (PAD + i as u32 * (panel_w + PAD), PAD + TITLE);
    for (i, p) in panels.iter().enumerate() {
        let (x0, y0) = origin(i);
        for y in 0..p.height * scale {
            for x in 0..p.width * scale {
                let src = 3 * ((y / scale) * p.width + x / scale) as usize;
                let dst = 3 * ((y0 + y) * width + x0 + x) as usize;
                rgb[dst..dst + 3].copy_from_slice(&p.rgb[src..src + 3]);
            }
        }
    }
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        for (i, p) in panels.iter().enumerate() {
            let (x0, y0) = origin(i);
            let (x0, y0, s) = (x0 as i32, y0 as i32, scale as f64);
            let (w, h) = ((p.width * scale) as i32, (p.height * scale) as i32);
            Text::new(15.0, palette::INK).draw(&root, &p.title, (x0, y0 - TITLE as i32 / 2))?;
            for (k, line) in p.lines.iter().enumerate() {
                let y = y0 + h + PAD as i32 + (LINE as i32) * k as i32 + LINE as i32 / 2;
                Text::new(14.0, palette::INK).draw(&root, line, (x0, y))?;
            }
            let centre = (x0 + w / 2, y0 + h / 2);
            mark(&root, centre, 7, false, palette::WHITE, 3)?;
            mark(&root, centre, 7, false, palette::INK, 1)?;
            if let Some([u, v]) = p.estimate_aim {
                let at = (x0 + (u * s).round() as i32, y0 + (v * s).round() as i32);
                if (x0..x0 + w).contains(&at.0) && (y0..y0 + h).contains(&at.1) {
                    mark(&root, at, 7, true, palette::WHITE, 3)?;
                    mark(&root, at, 7, true, palette::ESTIMATED, 1)?;
                }
            }
            if p.crashed {
                for k in 0..3 {
                    root.draw(&Rectangle::new(
                        [(x0 - 1 - k, y0 - 1 - k), (x0 + w + k, y0 + h + k)],
                        RGBColor::from(palette::COLLISION).stroke_width(1),
                    ))?;
                }
            }
        }
        let footer_y = height as i32 - PAD as i32 - LINE as i32 / 2;
        Text::new(14.0, palette::INK_SOFT).draw(&root, footer, (PAD as i32, footer_y))?;
        root.present()?;
    }
    Ok((rgb, width, height))
}

/// A `+` (or an `×` when `diagonal`) of half-size `r` at `at`, `thickness` pixels wide.
fn mark<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    (x, y): (i32, i32),
    r: i32,
    diagonal: bool,
    colour: Rgb,
    thickness: u32,
) -> Result<(), PlotError> {
    let style = RGBColor::from(colour).stroke_width(thickness);
    let arms = if diagonal { [[(-r, -r), (r, r)], [(-r, r), (r, -r)]] } else { [[(-r, 0), (r, 0)], [(0, -r), (0, r)]] };
    for [(ax, ay), (bx, by)] in arms {
        root.draw(&PathElement::new(vec![(x + ax, y + ay), (x + bx, y + by)], style))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn panel(colour: u8, crashed: bool) -> CameraPanel {
        CameraPanel {
            title: "NeRF-sim".into(),
            width: 20,
            height: 10,
            rgb: vec![colour; 600],
            lines: vec!["step 3.2".into(), "estimate off by 12 mm, 0.4°".into()],
            estimate_aim: Some([15.0, 2.0]),
            crashed,
        }
    }

    /// The image lands enlarged where the layout puts it, the crash frame is red, the estimate's
    /// mark is drawn where it aims, and the title and lines are inked.
    #[test]
    fn panels_are_laid_out_side_by_side_with_their_marks() {
        let (rgb, w, h) = camera_panels_rgb(&[panel(40, false), panel(200, true)], 4, "+ aim").unwrap();
        let (_, expected_h, panel_w) = layout(&[panel(0, false)], 4);
        assert_eq!(panel_w, 80);
        assert_eq!((w, h), (PAD + 2 * (80 + PAD), expected_h));
        let at = |x: u32, y: u32| {
            let i = 3 * (y * w + x) as usize;
            [rgb[i], rgb[i + 1], rgb[i + 2]]
        };
        let (x1, y0) = (PAD + 80 + PAD, PAD + TITLE);
        // Inside each image, away from the marks: the image's own grey.
        assert_eq!(at(PAD + 3, y0 + 30), [40; 3]);
        assert_eq!(at(x1 + 3, y0 + 30), [200; 3]);
        // The second panel's crash frame, just outside its image.
        assert_eq!(at(x1 - 2, y0 + 20), palette::COLLISION.to_array());
        assert_eq!(at(PAD - 2, y0 + 20), [255; 3], "the first panel has no frame");
        // The estimate's × at (15, 2)·4 + (2, 2), its orange core.
        let (ux, uy) = (PAD + 60 + 2, y0 + 8 + 2);
        assert_eq!(at(ux, uy), palette::ESTIMATED.to_array());
        // Text above and below the image: some dark pixels in each band.
        let dark =
            |ys: std::ops::Range<u32>| ys.flat_map(|y| (0..w).map(move |x| (x, y))).any(|(x, y)| at(x, y)[0] < 100);
        assert!(dark(PAD..y0), "the title");
        assert!(dark(y0 + 40 + PAD..h), "the lines");
    }

    #[test]
    fn a_buffer_of_the_wrong_size_is_refused() {
        let mut p = panel(0, false);
        p.rgb.pop();
        assert!(camera_panels_rgb(&[p], 2, "").is_err());
        assert!(camera_panels_rgb(&[], 2, "").is_err());
        assert!(camera_panels_rgb(&[panel(0, false)], 0, "").is_err());
    }
}
