//! The one error type of the crate.

use plotters::drawing::DrawingAreaErrorKind;

/// Why a figure could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The requested image size is outside what the figures lay out legibly.
    #[error("figure size {width}×{height} px is out of range: expected {min_width}..={max}×{min_height}..={max} px")]
    InvalidSize { width: u32, height: u32, min_width: u32, min_height: u32, max: u32 },
    /// The figure's data is inconsistent (says what was expected and what was found).
    #[error("invalid figure data: {0}")]
    InvalidData(String),
    /// The embedded font could not be parsed or registered with plotters.
    #[error("the embedded font DejaVuSans.ttf could not be registered with plotters")]
    Font,
    /// plotters failed while drawing (its error, as text: plotters' error type is generic over
    /// the backend).
    #[error("drawing failed: {0}")]
    Draw(String),
    /// The PNG encoder failed.
    #[error("PNG encoding failed: {0}")]
    Png(png::EncodingError),
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        PlotError::Draw(e.to_string())
    }
}

/// The encoder's error is the message, not a source, so a report of the chain names it once.
impl From<png::EncodingError> for PlotError {
    fn from(e: png::EncodingError) -> Self {
        Self::Png(e)
    }
}
