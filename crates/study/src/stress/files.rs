//! The files a stress run writes and reads back: their names, the journal folders, the
//! clearance differences and the Tables 1–2 CSV.

use std::path::{Path, PathBuf};

use nerfsv_sim::WorldKind;
use nerfsv_validation::Sampler;
use nerfsv_validation::TableRow;

use crate::StudyError;

use super::figures::*;

/// Files a stress run writes (besides the journal and the most likely failures).
pub const ROLLOUTS_CSV: &str = "rollouts.csv";
pub const TABLE_CSV: &str = "table.csv";
pub const STRESS_JSON: &str = "stress.json";
/// The journal's folder under the output folder.
pub const JOURNAL: &str = "journal";

/// The journal folder of the searches flown in `world` in the stress folder `out` (what a
/// resume needs to find).
pub fn journal_dir(out: &Path, world: WorldKind) -> PathBuf {
    out.join(JOURNAL).join(world.name())
}

/// The journal folder of the replays flown in `world` in the stress folder `out`.
pub fn replay_journal_dir(out: &Path, world: WorldKind) -> PathBuf {
    out.join(JOURNAL).join(format!("replay_{}", world.name()))
}
/// The name progress and notes are reported under.
pub const STAGE: &str = "stress";

/// `replay_{world}.csv`: the replays' rows.
pub fn replay_csv(world: WorldKind) -> String {
    format!("replay_{}.csv", world.name())
}

/// `clearance_difference_{sampler}.csv`: per trajectory and per step, |minimum clearance in
/// NeRF-sim − in GT-sim| on one sampler's searched disturbances (columns `per`, `abs_difference_m`;
/// written when they were replayed).
pub fn clearance_csv(sampler: Sampler) -> String {
    format!("clearance_difference_{}.csv", sampler.name())
}

/// Writes a [`clearance_csv`].
pub(super) fn write_clearance_csv(path: &Path, a: &nerfsv_validation::Agreement) -> Result<(), StudyError> {
    let mut s = String::from("per,abs_difference_m\n");
    for (per, spread) in [("trajectory", &a.clearance_difference), ("step", &a.step_clearance_difference)] {
        for v in &spread.values {
            s.push_str(&format!("{per},{v}\n"));
        }
    }
    nerfsv_scene::io::atomic_write_bytes(path, s.as_bytes()).map_err(|e| StudyError::io(path, e))
}

/// The Tables 1–2 rows as CSV: `world,` [`TableRow::CSV_HEADER`] `,uncertainty,mode,reward`
/// (empty where undefined; `uncertainty` the method measured, `reward` the method CEM ranked
/// by).
pub fn write_table(
    path: &Path,
    world: WorldKind,
    online: Option<OnlineSettings>,
    rows: &[TableRow],
) -> Result<(), StudyError> {
    let method = online.map_or("", |o| o.method.name());
    let mode = online.map_or("", |o| o.mode.name());
    let reward = online.filter(|o| o.reward).map_or("", |o| o.method.name());
    let mut s = format!("world,{},uncertainty,mode,reward\n", TableRow::CSV_HEADER);
    for r in rows {
        s.push_str(&format!("{},{},{method},{mode},{reward}\n", world.name(), r.csv()));
    }
    nerfsv_scene::io::atomic_write_bytes(path, s.as_bytes()).map_err(|e| StudyError::io(path, e))
}
