//! One search outside `nerfsv run` (`nerfsv stress`, the Python package): its settings, checked
//! before anything is written.

use std::path::Path;

use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_uq::{UncertaintyField, UqConfig};
use nerfsv_validation::Sampler;
use nerfsv_validation::{Prior, ValidationConfig};

use crate::flight::{Drone, FlightInputs, Mission};
use crate::remote::RemoteRollouts;
use crate::{Observer, StudyError, UqMode};

use super::figures::*;
use super::files::*;
use super::run::*;
use super::setup::*;

/// What one search outside `nerfsv run` does (`nerfsv stress`, the Python package), whatever
/// describes its drone: one sampler in one world, into a folder of its own.
#[derive(Clone, Copy)]
pub struct SearchSettings<'a> {
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    pub sampler: Sampler,
    /// Fly the search's rollouts again in the other world and compare.
    pub replay: bool,
    /// Measure each step's uncertainty (and rank CEM by its reward), or not.
    pub online: Option<OnlineSettings>,
    /// The uncertainty field `UqMode::Field` reads, with the file it came from. Refused unless
    /// its method is the online measurement's and it was built from the drone's model.
    pub field: Option<(&'a Path, &'a UncertaintyField)>,
    /// Output folder: rollouts.csv, replay_*.csv, table.csv, stress.json, the most likely
    /// failure's files, the journal.
    pub out: &'a Path,
    /// Continue a killed search in `out` (its journal must be there and be this key's).
    pub resume: bool,
    /// Where the rollouts fly, if not in this process (the Python package's Ray executor); the
    /// results are the same bytes either way.
    pub remote: Option<&'a dyn RemoteRollouts>,
}

/// A [`SearchSettings`] search of a drone: its description, its worlds, the prior and the settings.
pub struct SearchRequest<'a> {
    pub drone: Drone<'a>,
    /// The drone's worlds: its model, the model's field, the ground truth's field.
    pub inputs: &'a FlightInputs,
    pub validation: &'a ValidationConfig,
    pub prior: &'a Prior,
    /// The online measurement's settings (used with `online`).
    pub uq: &'a UqConfig,
    pub search: SearchSettings<'a>,
}

/// Runs one [`SearchRequest`] under `key` (everything its rollouts depend on: a resume into
/// another key's journal is refused): checks everything that can be refused (the uncertainty
/// settings against the field, a resume without a journal, the flight's plan) before it writes
/// anything, then searches ([`stress`]) and writes `stress.json`, whose figures it returns.
pub fn search_into(req: &SearchRequest, key: &str, observer: &dyn Observer) -> Result<StressFigures, StudyError> {
    let s = &req.search;
    let refuse = |message: String| StudyError::Refused { key: "stress", message };
    match (s.online, s.field) {
        (Some(o), Some((path, field))) if o.mode == UqMode::Field && field.method != o.method.into() => {
            return Err(refuse(format!(
                "{}: a {} uncertainty field, but the search measures {}",
                path.display(),
                field.method.name(),
                o.method.name()
            )))
        }
        (Some(o), None) if o.mode == UqMode::Field => {
            return Err(refuse("field mode needs an uncertainty field (`nerfsv uq field`)".into()))
        }
        (Some(o), Some(_)) if o.mode == UqMode::Exact => {
            return Err(refuse("an uncertainty field is read only in field mode".into()))
        }
        (None, Some(_)) => return Err(refuse("an uncertainty field is read only when the search measures one".into())),
        _ => {}
    }
    if let Some((path, field)) = s.field {
        field.check_checkpoint(path, &nerfsv_uq::model_id(&req.inputs.nerf))?;
    }
    if s.resume && !nerfsv_validation::Journal::exists(&journal_dir(s.out, s.world)) {
        return Err(refuse(format!("{}: resuming needs the folder of an interrupted stress run", s.out.display())));
    }
    let flight = req.inputs.plan(req.drone.sim)?;
    let mission = Mission { drone: req.drone, inputs: req.inputs, flight: &flight };
    let samplers = [s.sampler];
    let setup = StressSetup {
        world: s.world,
        estimator: s.estimator,
        replay: s.replay,
        online: s.online,
        field: s.field.map(|(_, f)| f),
        remote: s.remote,
        ..StressSetup::new(mission, req.validation, req.prior, &samplers, req.uq)
    };
    std::fs::create_dir_all(s.out).map_err(|e| StudyError::io(s.out, e))?;
    let (figures, _) = stress(&setup, s.out, key, s.resume, observer)?;
    let path = s.out.join(STRESS_JSON);
    nerfsv_scene::io::atomic_write(&path, |w| serde_json::to_writer_pretty(w, &figures).map_err(std::io::Error::other))
        .map_err(|e| StudyError::io(&path, e))?;
    Ok(figures)
}
