//! The embedded font: DejaVu Sans (Bitstream Vera licence, `assets/DejaVu-LICENSE.txt`).
//!
//! Embedding keeps figures identical on every machine and needs no system fonts. plotters gets
//! the font as its "sans-serif" family (its `ab_glyph` text support has no font of its own:
//! without one both backends fail with `FontUnavailable`); [`crate::text`] lays out and
//! rasterises bitmap text with the same face.

use std::sync::OnceLock;

use ab_glyph::{Font, FontRef, PxScale};
use plotters::style::FontStyle;

use crate::PlotError;

/// DejaVuSans.ttf as shipped by Debian's `fonts-dejavu-core`.
static DEJAVU_SANS: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// Height of a capital letter in DejaVu Sans, in em (1493 of 2048 units).
pub(crate) const CAP_HEIGHT_EM: f64 = 1493.0 / 2048.0;

/// Registers the embedded font as plotters' "sans-serif" family, once per process.
pub(crate) fn ensure_registered() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font("sans-serif", FontStyle::Normal, DEJAVU_SANS).is_ok());
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// The parsed face.
pub(crate) fn face() -> Result<&'static FontRef<'static>, PlotError> {
    static FACE: OnceLock<Option<FontRef<'static>>> = OnceLock::new();
    FACE.get_or_init(|| FontRef::try_from_slice(DEJAVU_SANS).ok()).as_ref().ok_or(PlotError::Font)
}

/// ab_glyph's scale for a font size of `em_px` pixels per em (ab_glyph scales by the
/// ascent-to-descent height, CSS and SVG by the em).
pub(crate) fn px_scale(face: &FontRef<'_>, em_px: f64) -> PxScale {
    let units_per_em = face.units_per_em().unwrap_or(2048.0);
    PxScale::from(em_px as f32 * face.height_unscaled() / units_per_em)
}
