//! What a stress run draws: the estimator's error histograms and each sampler's most likely
//! failure flown and plotted in each world, and what the drone's camera saw along it.

use std::path::Path;

use nerfsv_sim::{ImageUpdate, World, WorldKind};
use nerfsv_validation::RolloutRecord;
use nerfsv_validation::{Agreement, Sampler};

use crate::flight::{fly_and_write, write_view, FlightFigures, Sortie};
use crate::{drone_disturbances, EstimateLog, StudyError};

use super::figures::*;
use super::setup::*;

/// The file of the estimate-error histograms.
pub const ESTIMATE_ERRORS_PNG: &str = "estimate_errors.png";

/// Histograms of the estimator's position errors after its image updates, one panel per world,
/// up to the 99th percentile of all of them (the rest, a crashed rollout's last images, would
/// squeeze the bulk into one bar; the title says how many are left out).
pub(super) fn estimate_error_png(logs: &[(WorldKind, Vec<ImageUpdate>)]) -> Result<Vec<u8>, StudyError> {
    let mut all: Vec<f64> = logs.iter().flat_map(|(_, e)| e.iter().map(|e| 1e3 * e.position_error_m)).collect();
    all.sort_by(f64::total_cmp);
    let cut = if all.is_empty() { f64::INFINITY } else { nerfsv_scene::stats::quantile_sorted(&all, 0.99) };
    let left_out = all.iter().filter(|&&v| v > cut).count();
    let groups = logs
        .iter()
        .map(|(w, e)| nerfsv_plot::Group {
            label: format!("{}-sim", w.name()),
            values: e.iter().map(|e| 1e3 * e.position_error_m).filter(|&v| v <= cut).collect(),
        })
        .collect();
    let fig = nerfsv_plot::HistogramFigure {
        title: format!(
            "Position error of the estimate after each image update, both worlds ({left_out} above {cut:.0} mm, the 99th \
             percentile, left out)"
        ),
        x_title: "position error (mm)".into(),
        y_title: "images".into(),
        groups,
        bins: 40,
    };
    nerfsv_plot::histograms_png(&fig, 1100, 560).map_err(|e| StudyError::Internal(format!("plotting: {e}")))
}

/// The estimator's errors and the filter's counts of each world's log (worlds without any left out): their figures,
/// and their histograms in [`ESTIMATE_ERRORS_PNG`] under `out` when there are any.
pub(super) fn write_estimate_errors(
    out: &Path,
    logs: [(WorldKind, &EstimateLog); 2],
) -> Result<Vec<EstimateErrorFigures>, StudyError> {
    let logs: Vec<(WorldKind, Vec<ImageUpdate>)> =
        logs.into_iter().map(|(w, log)| (w, log.all())).filter(|(_, e)| !e.is_empty()).collect();
    if !logs.is_empty() {
        let path = out.join(ESTIMATE_ERRORS_PNG);
        nerfsv_scene::io::atomic_write_bytes(&path, &estimate_error_png(&logs)?)
            .map_err(|e| StudyError::io(&path, e))?;
    }
    Ok(logs.iter().filter_map(|(w, e)| EstimateErrorFigures::new(*w, e)).collect())
}

/// The stem of a sampler's most likely failure's files: `most_likely_failure_{sampler}`.
pub fn most_likely_failure_stem(sampler: Sampler) -> String {
    format!("most_likely_failure_{}", sampler.name())
}

/// The plot of a sampler's most likely failure flown in `world`.
pub fn most_likely_failure_png(sampler: Sampler, world: WorldKind) -> String {
    format!("{}_{}.png", most_likely_failure_stem(sampler), world.name())
}

/// The most likely failure's disturbances, and its flight in the search's world (and, when
/// replaying, in the other), as trajectory CSV and plot; the other world's flight's figures.
pub(super) fn write_failure(
    setup: &StressSetup,
    out: &Path,
    sampler: Sampler,
    f: &RolloutRecord,
    search: &dyn World,
    other: Option<&dyn World>,
) -> Result<Option<FlightFigures>, StudyError> {
    let ds = drone_disturbances(&f.disturbances);
    let name = most_likely_failure_stem(sampler);
    let path = out.join(format!("{name}.csv"));
    nerfsv_scene::io::atomic_write_bytes(&path, nerfsv_sim::io::disturbances_csv(&ds).as_bytes())
        .map_err(|e| StudyError::io(&path, e))?;
    let mut replayed = None;
    let mut flown = Vec::new();
    for w in std::iter::once(search).chain(other.filter(|_| setup.replay)) {
        let png = out.join(most_likely_failure_png(sampler, w.kind()));
        let sortie = Sortie { world: w, estimator: setup.estimator, disturbances: &ds, seed: f.seed };
        let (figures, rollout) = fly_and_write(&setup.mission, &sortie, &png.with_extension("csv"), &png)?;
        if w.kind() != setup.world {
            replayed = Some(figures);
        }
        flown.push((w, rollout));
    }
    write_view(&out.join(most_likely_failure_view(sampler)), &setup.mission, &flown, f.seed)?;
    Ok(replayed)
}

/// The animation of what the drone's camera saw along a sampler's most likely failure, in each
/// world it was flown in ([`crate::flight_view`]).
pub fn most_likely_failure_view(sampler: Sampler) -> String {
    format!("{}_view.png", most_likely_failure_stem(sampler))
}

/// The histograms of |clearance in NeRF-sim − in GT-sim| on the same disturbances.
pub const CLEARANCE_PNG: &str = "clearance_difference.png";

/// [`CLEARANCE_PNG`] under `out`: per replayed sampler, the |clearance difference| (mm) per
/// trajectory and per step (what [`clearance_csv`](crate::stress::clearance_csv) holds). Returns whether it was drawn: not
/// without a difference to show.
pub(super) fn write_clearance_png(out: &Path, agreements: &[(Sampler, Agreement)]) -> Result<bool, StudyError> {
    let mut groups = Vec::new();
    for (sampler, a) in agreements {
        let mm = |v: &[f64]| v.iter().map(|x| 1e3 * x).collect::<Vec<f64>>();
        let name = sampler.name().to_uppercase();
        let (trajectories, steps) = (&a.clearance_difference.values, &a.step_clearance_difference.values);
        groups.push(nerfsv_plot::Group { label: format!("{name}, per trajectory"), values: mm(trajectories) });
        groups.push(nerfsv_plot::Group { label: format!("{name}, per step"), values: mm(steps) });
    }
    groups.retain(|g| !g.values.is_empty());
    if groups.is_empty() {
        return Ok(false);
    }
    let fig = nerfsv_plot::HistogramFigure {
        title: "NeRF-sim against GT-sim: |Δ minimum clearance| on the same disturbances".into(),
        x_title: "|clearance difference| (mm)".into(),
        y_title: "count".into(),
        groups,
        bins: 30,
    };
    let png =
        nerfsv_plot::histograms_png(&fig, 1100, 700).map_err(|e| StudyError::Internal(format!("plotting: {e}")))?;
    let path = out.join(CLEARANCE_PNG);
    nerfsv_scene::io::atomic_write_bytes(&path, &png).map_err(|e| StudyError::io(&path, e))?;
    Ok(true)
}
