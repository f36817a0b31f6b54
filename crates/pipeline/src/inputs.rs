//! The run folder as the drone's stages read it beyond the flight's inputs
//! ([`flight_inputs`]: the model and the collision fields): the ensemble's members and the
//! calibrated world's error model, each from the folder of the stage that wrote it. A stage
//! gets its inputs here, never from another stage's methods. (The flight stage reads only
//! [`flight_inputs`], so that a change here or in the ensemble stage does not redo it.)

use std::path::Path;

use nerfsv_collision::SdfGrid;
use nerfsv_nerf::Nerf;
use nerfsv_study::calibration::{CalibrationConfig, ErrorModels, MODEL_JSON, STAGE as CALIBRATION};
use nerfsv_study::flight::{Calibration, FlightInputs, WorldMember};

use crate::ensemble::{EnsembleStage, MemberEntry};
use crate::flight::flight_inputs;
use crate::stage::Stage;
use crate::PipelineError;

/// The members 1..K the ensemble stage left in run `root` (none when it trained none).
pub fn load_members(root: &Path) -> Result<Vec<WorldMember>, PipelineError> {
    let list = root.join(<EnsembleStage as Stage>::NAME).join(EnsembleStage::MEMBERS);
    if !list.exists() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(&list).map_err(|e| PipelineError::io(&list, e))?;
    let members: Vec<MemberEntry> =
        serde_json::from_str(&text).map_err(|e| PipelineError::Internal(format!("{}: {e}", list.display())))?;
    members
        .iter()
        .map(|m| {
            let dir = EnsembleStage::member_dir(root, m.member);
            Ok(WorldMember {
                nerf: Nerf::load(&dir.join(EnsembleStage::CHECKPOINT))?,
                field: SdfGrid::load(dir.join(EnsembleStage::SDF))?,
            })
        })
        .collect()
}

/// The calibrated world's draws from the error model the calibration stage wrote into `root`.
pub fn load_calibration(root: &Path, calibration: &CalibrationConfig, seed: u64) -> Result<Calibration, PipelineError> {
    let path = root.join(CALIBRATION).join(MODEL_JSON);
    let text = std::fs::read_to_string(&path).map_err(|e| PipelineError::io(&path, e))?;
    let models: ErrorModels = serde_json::from_str(&text)
        .map_err(|e| PipelineError::Internal(format!("{}: not error models: {e}", path.display())))?;
    let model_error = models.model_error_per_rmse.filter(|_| calibration.filter_model_error);
    Ok(Calibration {
        model_bias: calibration.filter_bias.then(|| models.real.shared_bias()),
        models: models.members,
        draws_per_member: calibration.draws_per_member,
        seed,
        model_error_per_rmse: model_error.map(|m| m.per_rmse),
        image_noise: if calibration.image_noise { models.image_noise } else { Vec::new() },
    })
}

/// The worlds the drone flies in: [`flight_inputs`], with the ensemble's other members
/// (`ensemble`) and the calibrated world's draws (`calibration`: its settings and seed).
pub fn drone_worlds(
    root: &Path,
    ground_truth: bool,
    ensemble: bool,
    calibration: Option<(&CalibrationConfig, u64)>,
) -> Result<FlightInputs, PipelineError> {
    let mut inputs = flight_inputs(root, ground_truth)?;
    if ensemble {
        inputs.members = load_members(root)?;
    }
    if let Some((config, seed)) = calibration {
        inputs.calibration = Some(load_calibration(root, config, seed)?);
    }
    Ok(inputs)
}
