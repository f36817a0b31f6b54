//! The offline study's figures: histograms and scatters of each method's rows, and the
//! per-pixel picture of one view.

use nerfsv_dataset::Frame;
use nerfsv_nerf::Nerf;
use nerfsv_plot::{Group, HistogramFigure, PointGroup, ScatterFigure};

use super::fit::fit_with_depth_uncertainty;
use super::rows::{Fit, Row, BACKGROUND};
use crate::{depth_errors, Method, UqConfig, UqError};

/// A figure of a method.
pub enum Figure {
    Histogram(HistogramFigure),
    Scatter(ScatterFigure),
}

/// Groups with fewer values than this are drawn as points, not as a histogram.
pub const FEW_FOR_A_HISTOGRAM: usize = 10;

/// Bins for histograms of at most `n` values per group.
fn bins(n: usize) -> usize {
    ((2.0 * (n as f64).sqrt()).round() as usize).clamp(5, 40)
}

/// The file stems of a method's figures, in the order [`figures`] makes them.
pub fn figure_stems(method: Method) -> &'static [&'static str] {
    match method {
        Method::Ga => &["uq_ga_sigma_d", "uq_ga_mu_sigma"],
        Method::Bla => &["uq_bla_trace", "uq_bla_rmv", "uq_bla_trace_rmv"],
    }
}

/// The figures of a method: (file stem, figure). GA: σ_d histograms per split and the μ_d–σ_d
/// scatter, excluded images left out (and counted in the titles); BLA: normalised trace and
/// rmv histograms and their scatter.
pub fn figures(rows: &[Row], splits: &[&'static str], method: Method, cfg: &UqConfig) -> Vec<(String, Figure)> {
    let per_split = |value: &dyn Fn(&Row) -> Option<[f64; 2]>| -> Vec<(&'static str, Vec<[f64; 2]>)> {
        splits.iter().map(|s| (*s, rows.iter().filter(|r| r.split == *s).filter_map(value).collect())).collect()
    };
    fn largest<L>(groups: &[(L, Vec<[f64; 2]>)]) -> usize {
        groups.iter().map(|(_, v)| v.len()).max().unwrap_or(0)
    }
    fn hist<L: ToString>(groups: &[(L, Vec<[f64; 2]>)], axis: usize, title: String, x_title: &str) -> Figure {
        // A histogram of a handful of values says less than the values: draw them as points,
        // each image at its value, one row per image of its split.
        if largest(groups) < FEW_FOR_A_HISTOGRAM {
            return Figure::Scatter(ScatterFigure {
                title,
                x_title: x_title.to_string(),
                y_title: "image (in its split's order)".into(),
                groups: groups
                    .iter()
                    .map(|(s, v)| PointGroup {
                        label: s.to_string(),
                        points: v.iter().enumerate().map(|(k, p)| [p[axis], (k + 1) as f64]).collect(),
                    })
                    .collect(),
            });
        }
        Figure::Histogram(HistogramFigure {
            title,
            x_title: x_title.to_string(),
            y_title: "images".into(),
            groups: groups
                .iter()
                .map(|(s, v)| Group { label: s.to_string(), values: v.iter().map(|p| p[axis]).collect() })
                .collect(),
            bins: bins(largest(groups)),
        })
    }
    let scatter = |groups: &[(&'static str, Vec<[f64; 2]>)], title: String, x: &str, y: &str| {
        Figure::Scatter(ScatterFigure {
            title,
            x_title: x.to_string(),
            y_title: y.to_string(),
            groups: groups.iter().map(|(s, v)| PointGroup { label: s.to_string(), points: v.clone() }).collect(),
        })
    };
    let stems = figure_stems(method);
    match method {
        Method::Ga => {
            // The paper's statistics leave the excluded images out.
            let kept = per_split(&|r| match &r.fit {
                Fit::Ga(Some(g)) if g.excluded.is_none() => Some([g.mu_d, g.sigma_d]),
                _ => None,
            });
            let excluded = rows.iter().filter(|r| matches!(&r.fit, Fit::Ga(Some(g)) if g.excluded.is_some())).count();
            let note = if excluded > 0 {
                format!(" ({excluded} excluded: σ_d ≤ 0 or ≥ {})", cfg.ga_sigma_max)
            } else {
                String::new()
            };
            // Histogram panels say how many of their split's images were left out.
            let labelled: Vec<(String, Vec<[f64; 2]>)> = kept
                .iter()
                .map(|(s, v)| {
                    let n = rows
                        .iter()
                        .filter(|r| r.split == *s && matches!(&r.fit, Fit::Ga(Some(g)) if g.excluded.is_some()))
                        .count();
                    let label = if n > 0 { format!("{s} ({n} excluded)") } else { s.to_string() };
                    (label, v.clone())
                })
                .collect();
            vec![
                (stems[0].into(), hist(&labelled, 1, format!("GA: σ_d per image{note}"), "σ_d")),
                (stems[1].into(), scatter(&kept, format!("GA: μ_d and σ_d per image{note}"), "μ_d", "σ_d")),
            ]
        }
        Method::Bla => {
            let fits = per_split(&|r| match &r.fit {
                Fit::Bla(Some(b)) => Some([b.normalized_trace, b.rmv]),
                _ => None,
            });
            vec![
                (stems[0].into(), hist(&fits, 0, "BLA: normalised trace per image".into(), "normalised trace tr(Σ)/P")),
                (stems[1].into(), hist(&fits, 1, "BLA: root-mean-variance per image".into(), "rmv")),
                (
                    stems[2].into(),
                    scatter(&fits, "BLA: normalised trace and rmv per image".into(), "normalised trace tr(Σ)/P", "rmv"),
                ),
            ]
        }
    }
}

/// The per-pixel figure of the first test image the stage fits with both methods (or GA
/// alone): the NeRF's depth error against the ground truth beside GA's and BLA's depth standard
/// deviations, on log scales (`uq/uq_maps.png`; written when the test split has an image with
/// ground-truth depth).
pub const MAPS_PNG: &str = "uq_maps.png";

/// See [`MAPS_PNG`]; `None` when `frame` has no ground-truth depth or every ray misses.
pub fn maps_figure(
    nerf: &Nerf,
    frame: &Frame,
    bla: bool,
    ensemble: &[&Nerf],
    cfg: &UqConfig,
) -> Result<Option<Vec<u8>>, UqError> {
    let name = frame.file_path.as_str();
    let view = nerf.render_camera(&frame.camera, BACKGROUND);
    let Ok(errors) = depth_errors(name, &view.depth, frame.depth.as_ref().map(|d| &d.metres[..])) else {
        return Ok(None);
    };
    let k = frame.camera.intrinsics;
    let panel = |caption: String, values: Vec<f64>| nerfsv_plot::Heatmap {
        caption,
        x_title: "column (px)".into(),
        y_title: "row from the bottom (px)".into(),
        colour_title: "metres (log scale)".into(),
        // Row 0 of the image is its top.
        origin: [0.0, f64::from(k.height) - 1.0],
        cell: [1.0, -1.0],
        dims: [k.width as usize, k.height as usize],
        values,
        scale: nerfsv_plot::ColourScale::Log,
    };
    let mut panels = vec![panel("|NeRF depth − ground truth|".into(), errors.iter().map(|&e| f64::from(e)).collect())];
    let methods: &[Method] = if bla { &[Method::Ga, Method::Bla] } else { &[Method::Ga] };
    for &method in methods {
        match fit_with_depth_uncertainty(nerf, method, name, frame, cfg) {
            Ok((_, std)) => panels.push(panel(
                format!("{} depth standard deviation", method.name().to_uppercase()),
                std.iter().map(|&v| f64::from(v)).collect(),
            )),
            Err(UqError::AllRaysMiss { .. }) => return Ok(None),
            Err(e) => return Err(e),
        }
    }
    if !ensemble.is_empty() {
        let members: Vec<&Nerf> = std::iter::once(nerf).chain(ensemble.iter().copied()).collect();
        let maps = crate::ensemble::maps(&members, &frame.camera, BACKGROUND);
        panels.push(panel(
            format!("Ensemble depth standard deviation ({} NeRFs)", members.len()),
            maps.depth_std.iter().map(|&v| f64::from(v)).collect(),
        ));
    }
    let fig = nerfsv_plot::HeatmapFigure { title: format!("Per-pixel depth error and uncertainty, {name}"), panels };
    let width = 500 * fig.panels.len() as u32;
    Ok(Some(nerfsv_plot::heatmap_png(&fig, width, 470)?))
}
