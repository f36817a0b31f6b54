//! The ensemble's members as the worlds NeRF-sim flies in: what the stages that read the ensemble
//! stage's folder load (the flight's, calibration's, stress and online stages, and the
//! uncertainty stage's ensemble method).

use std::path::Path;

use nerfsv_collision::SdfGrid;
use nerfsv_nerf::Nerf;
use nerfsv_study::flight::WorldMember;

use crate::ensemble::{EnsembleStage, MemberEntry};
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
