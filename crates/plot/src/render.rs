//! Backends: PNG bytes from plotters' in-memory bitmap, SVG text, and the small drawing helpers
//! every figure uses.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::font;
use crate::PlotError;

/// The largest width or height of a figure in pixels (a 8192² RGB buffer is 192 MiB).
pub const MAX_SIDE: u32 = 8192;

/// Encodes an RGB8 buffer (`[height, width, 3]`, rows top to bottom) as PNG.
pub fn encode_png(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    let expected = width as usize * height as usize * 3;
    if rgb.len() != expected {
        return Err(PlotError::InvalidData(format!(
            "RGB buffer for a {width}×{height} image has {} bytes, expected {expected}",
            rgb.len()
        )));
    }
    let mut out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::Balanced);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(rgb)?;
        writer.finish()?;
    }
    Ok(out)
}

/// Checks a requested figure size against the figure's minimum and [`MAX_SIDE`].
pub(crate) fn check_size(width: u32, height: u32, min: (u32, u32)) -> Result<(), PlotError> {
    let ok = |v: u32, lo: u32| (lo..=MAX_SIDE).contains(&v);
    if ok(width, min.0) && ok(height, min.1) {
        Ok(())
    } else {
        Err(PlotError::InvalidSize { width, height, min_width: min.0, min_height: min.1, max: MAX_SIDE })
    }
}

/// Draws on a white `width × height` bitmap and returns it as PNG.
pub(crate) fn render_png(
    width: u32,
    height: u32,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), PlotError>,
) -> Result<Vec<u8>, PlotError> {
    font::ensure_registered()?;
    let mut rgb = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        draw(&root)?;
        root.present()?;
    }
    encode_png(&rgb, width, height)
}

/// Draws on a white `width × height` SVG canvas and returns the document.
pub(crate) fn render_svg(
    width: u32,
    height: u32,
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Result<(), PlotError>,
) -> Result<String, PlotError> {
    font::ensure_registered()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    Ok(svg)
}

/// A plotters backend the figures draw on.
pub(crate) trait Canvas: DrawingBackend {
    /// Whether this crate rasterises text and anti-aliased strokes itself ([`crate::text`],
    /// [`crate::stroke`]; bitmaps) or leaves them to the viewer (SVG).
    const RASTER: bool;
}

impl Canvas for BitMapBackend<'_> {
    const RASTER: bool = true;
}

impl Canvas for SVGBackend<'_> {
    const RASTER: bool = false;
}
