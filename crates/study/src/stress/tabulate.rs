//! One sampler's figures: its Tables 1–2 rows, its estimate, its confusion against the
//! other world and its most likely failure.

use std::path::Path;

use nerfsv_sim::{World, WorldKind};
use nerfsv_validation::{compare, table_row, Label, RolloutRecord, TableRow};
use nerfsv_validation::{Agreement, Sampler};

use crate::StudyError;

use super::figures::*;
use super::files::*;
use super::pictures::*;
use super::search::*;
use super::setup::*;

/// One sampler's figures from the searches' `records` and their `replays` (one for one with the
/// searched records, in order), with its comparison against the other world when replayed;
/// writes its most likely failure's files. `worlds` are the
/// search's world and the other one.
pub(super) fn sampler_figures(
    setup: &StressSetup,
    out: &Path,
    sampler: Sampler,
    estimate: Estimate,
    records: &[RolloutRecord],
    replays: Option<&[RolloutRecord]>,
    worlds: (&dyn World, Option<&dyn World>),
) -> Result<(SamplerFigures, Option<Agreement>), StudyError> {
    let mode = setup.prior.mode_step_log_pdf();
    let rows: Vec<TableRow> = match sampler {
        Sampler::Mc => vec![table_row(Label::Mc, records, mode)],
        Sampler::Cem => vec![table_row(Label::Cem, records, mode), table_row(Label::CemIs, records, mode)],
        Sampler::Subset => vec![table_row(Label::Subset, records, mode)],
    }
    .into_iter()
    .flatten()
    .collect();
    let headline = rows
        .first()
        .cloned()
        .ok_or_else(|| StudyError::Internal(format!("{}: no rollouts to tabulate", sampler.name())))?;
    let (confusion, agreement) = match replays {
        Some(rs) if sampler.searched(setup.validation) > 0 => {
            let (ours, theirs): (Vec<RolloutRecord>, Vec<RolloutRecord>) =
                searched(records).zip(rs).filter(|(r, _)| sampler.owns(r)).map(|(r, g)| (r.clone(), g.clone())).unzip();
            let (nerf, gt) = if setup.world == WorldKind::Nerf { (&ours, &theirs) } else { (&theirs, &ours) };
            let agreement = compare(nerf, gt).map_err(StudyError::Internal)?;
            write_clearance_csv(&out.join(clearance_csv(sampler)), &agreement)?;
            (Some(ConfusionFigures::new(&agreement)), Some(agreement))
        }
        _ => (None, None),
    };
    let mlf = nerfsv_validation::most_likely_failure(records.iter().filter(|r| sampler.owns(r)), setup.prior);
    let most_likely_failure = match mlf {
        Some(f) => {
            let replayed = write_failure(setup, out, sampler, f, worlds.0, worlds.1)?;
            Some(FailureFigures {
                sampler: f.sampler,
                population: f.population,
                index: f.index,
                seed: f.seed,
                log_likelihood: f.completed_log_p(setup.prior.mode_step_log_pdf()),
                collision_step: f.collision_step.map(|s| s + 1),
                min_clearance_m: f.score,
                replay_collided: replayed.as_ref().map(|r| r.collided),
                replay_min_clearance_m: replayed.as_ref().map(|r| r.min_clearance_m.map_or(f64::INFINITY, f64::from)),
            })
        }
        None => None,
    };
    let figures = SamplerFigures {
        sampler,
        world: setup.world,
        estimator: setup.estimator,
        rollouts: records.iter().filter(|r| sampler.owns(r)).count(),
        collision_rate: headline.collision_rate,
        lost_rate: headline.lost_rate,
        avg_collision_step: headline.avg_collision_step,
        avg_log_likelihood: headline.avg_log_likelihood,
        avg_uncertainty: headline.avg_uncertainty,
        p_fail: estimate.p,
        p_fail_se: estimate.se,
        p_fail_interval: estimate.interval,
        p_fail_estimator: estimate.estimator,
        p_fail_unnormalised: estimate.unnormalised,
        effective_sample_size: estimate.ess,
        effective_failures: estimate.effective_failures,
        most_likely_failure,
        confusion,
        table: rows,
    };
    Ok((figures, agreement))
}
