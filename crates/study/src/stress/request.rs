//! One search outside `nerfsv run` (`nerfsv stress`, the Python package): its settings checked
//! before anything is written, then the search into a folder of its own.

use std::path::Path;

use crate::{Observer, StudyError, UqMode};

use super::figures::*;
use super::files::*;
use super::run::*;
use super::setup::*;

/// Runs one search outside `nerfsv run` into `out` under `key` (everything its rollouts depend
/// on: a resume into another key's journal is refused): checks everything that can be refused
/// (the uncertainty settings against the field, a resume without a journal) before it writes
/// anything, then searches ([`stress`]) and writes `stress.json`, whose figures it returns.
pub fn search_into(
    setup: &StressSetup,
    out: &Path,
    resume: bool,
    key: &str,
    observer: &dyn Observer,
) -> Result<StressFigures, StudyError> {
    let refuse = |message: String| StudyError::Refused { key: "stress", message };
    match (setup.online, setup.field) {
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
    if let Some((path, field)) = setup.field {
        field.check_checkpoint(path, &nerfsv_uq::model_id(&setup.mission.inputs.nerf))?;
    }
    if resume && !nerfsv_validation::Journal::exists(&journal_dir(out, setup.world)) {
        return Err(refuse(format!("{}: resuming needs the folder of an interrupted stress run", out.display())));
    }
    std::fs::create_dir_all(out).map_err(|e| StudyError::io(out, e))?;
    let (figures, _) = stress(setup, out, key, resume, observer)?;
    let path = out.join(STRESS_JSON);
    nerfsv_scene::io::atomic_write(&path, |w| serde_json::to_writer_pretty(w, &figures).map_err(std::io::Error::other))
        .map_err(|e| StudyError::io(&path, e))?;
    Ok(figures)
}
