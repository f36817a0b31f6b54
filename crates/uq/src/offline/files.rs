//! A method's offline files in memory (CSV, figures as PNG and SVG), and writing files all or
//! nothing.

use std::path::Path;

use super::csv::{csv, csv_name};
use super::figures::{figures, Figure};
use super::rows::{Row, FIGURE};
use crate::{Method, UqConfig, UqError};

/// A method's offline files, in memory: its rows ([`csv_name`]) and its figures
/// ([`figure_files`]).
pub fn method_files(
    rows: &[Row],
    splits: &[&'static str],
    method: Method,
    cfg: &UqConfig,
) -> Result<Vec<(String, Vec<u8>)>, UqError> {
    let mut files = vec![(csv_name(method).to_string(), csv(rows, method).into_bytes())];
    files.extend(figure_files(rows, splits, method, cfg)?);
    Ok(files)
}

/// The figures of a method as files: `STEM.png` and `STEM.svg` for each, in memory.
pub fn figure_files(
    rows: &[Row],
    splits: &[&'static str],
    method: Method,
    cfg: &UqConfig,
) -> Result<Vec<(String, Vec<u8>)>, UqError> {
    let mut files = Vec::new();
    for (stem, fig) in figures(rows, splits, method, cfg) {
        let (png, svg) = match &fig {
            Figure::Histogram(h) => (
                nerfsv_plot::histograms_png(h, FIGURE.0, FIGURE.1)?,
                nerfsv_plot::histograms_svg(h, FIGURE.0, FIGURE.1)?,
            ),
            Figure::Scatter(s) => {
                (nerfsv_plot::scatter_png(s, FIGURE.0, FIGURE.1)?, nerfsv_plot::scatter_svg(s, FIGURE.0, FIGURE.1)?)
            }
        };
        files.push((format!("{stem}.png"), png));
        files.push((format!("{stem}.svg"), svg.into_bytes()));
    }
    Ok(files)
}

/// Writes `files` (name, bytes) into `dir` (created if needed), each atomically, all or
/// nothing: if one cannot be written, those already written are removed again.
pub fn write_files(dir: &Path, files: &[(String, Vec<u8>)]) -> Result<(), UqError> {
    std::fs::create_dir_all(dir).map_err(|e| UqError::io(dir, e))?;
    nerfsv_scene::io::remove_stale_temporaries_in(dir);
    for (k, (name, bytes)) in files.iter().enumerate() {
        let path = dir.join(name);
        if let Err(e) = nerfsv_scene::io::atomic_write_bytes(&path, bytes) {
            for (done, _) in &files[..k] {
                let _ = std::fs::remove_file(dir.join(done));
            }
            return Err(UqError::io(path, e));
        }
    }
    Ok(())
}
