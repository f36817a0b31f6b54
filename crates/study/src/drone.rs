//! The drone as a [`System`]: one rollout of a [`Simulator`] in a [`World`] with an estimator.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use nerfsv_scene::{Camera, Intrinsics};
use nerfsv_sim::camera::drone_camera;
use nerfsv_sim::dynamics::{so3_exp, so3_log};
use nerfsv_sim::{Disturbance, EstimatorKind, ImageUpdate, Simulator, World};

use nerfsv_validation::{
    run_here, Finished, Job, Journal, Outcome, RolloutRecord, System, Trajectory, ValidationError,
};

use crate::remote::{decode_result, encode_job, RemoteRollouts, RemoteSpec};

use crate::uncertainty::ViewUncertainty;

/// The system under test of the paper: the simulator flying in one world.
pub struct DroneSystem<'a> {
    pub sim: &'a Simulator<'a>,
    pub world: &'a dyn World,
    pub estimator: EstimatorKind,
    /// Measures each flown step's uncertainty (`Outcome::step_uncertainty`), if given: the view
    /// of the camera at the step's final true pose.
    pub uncertainty: Option<&'a dyn ViewUncertainty>,
    /// Collects the estimator's error after every image update of the rollouts flown, if given.
    pub estimate_log: Option<&'a EstimateLog>,
    /// Where batches of rollouts fly ([`System::run_all`]), if not in this process. Refused
    /// with `uncertainty` (a remote rollout measures nothing).
    pub remote: Option<&'a dyn RemoteRollouts>,
    /// Rollouts this simulator flew before in this world: one asked for again (the same seed
    /// and disturbances) is taken from here, not flown, its steps measured by `uncertainty`.
    pub known: Option<&'a KnownRollouts>,
}

/// Rollouts flown before by the same simulator in the same world (another search that drew
/// some of the same rollouts: the online stage's rewarded CEMs of GA and BLA rank their
/// populations alike until a population has more failures than elites), with the filter's log
/// of each. A rollout's outcome is a function of its disturbances and seed alone, so one asked
/// for again with both equal is what flying it gives, bit for bit; its uncertainty, which
/// another search measured with its own method, is measured again ([`DroneSystem::known`]).
#[derive(Debug, Default)]
pub struct KnownRollouts {
    by_seed: HashMap<u64, Vec<KnownRollout>>,
    taken: AtomicU64,
}

#[derive(Debug)]
struct KnownRollout {
    disturbances: Trajectory,
    outcome: Outcome,
    images: Vec<ImageUpdate>,
}

impl KnownRollouts {
    /// The rollouts of `records` whose filter's log the journal folder `journal` keeps (a
    /// rollout without one, or whose log cannot be read, is left out: it is flown when asked
    /// for). `extension` names the log files beside the journal's records.
    pub fn from_journal(&mut self, records: &[RolloutRecord], journal: &Path, extension: &str) {
        for r in records {
            let path = Journal::beside_in(journal, r.sampler, r.population, r.index, extension);
            if let Ok(images) = nerfsv_sim::read_images(&path) {
                self.insert(r, images);
            }
        }
    }

    /// Adds the rollout `record` describes, with the filter's log of its images.
    pub fn insert(&mut self, record: &RolloutRecord, images: Vec<ImageUpdate>) {
        let known = KnownRollout { disturbances: record.disturbances.clone(), outcome: record.outcome(), images };
        let same = self.by_seed.entry(record.seed).or_default();
        if !same.iter().any(|k| k.disturbances == known.disturbances) {
            same.push(known);
        }
    }

    /// How many rollouts are known.
    pub fn len(&self) -> usize {
        self.by_seed.values().map(Vec::len).sum()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.by_seed.is_empty()
    }

    /// How many times a rollout was taken from here instead of flown.
    pub fn taken(&self) -> u64 {
        self.taken.load(Ordering::Relaxed)
    }

    fn get(&self, disturbances: &Trajectory, seed: u64) -> Option<&KnownRollout> {
        self.by_seed.get(&seed)?.iter().find(|k| &k.disturbances == disturbances)
    }

    /// [`KnownRollouts::get`], counted as taken.
    fn take(&self, disturbances: &Trajectory, seed: u64) -> Option<&KnownRollout> {
        let known = self.get(disturbances, seed)?;
        self.taken.fetch_add(1, Ordering::Relaxed);
        Some(known)
    }
}

/// The drone's camera at the end of a step as a rollout's record keeps it: the true position and
/// the attitude as a rotation vector. Where a flown step's uncertainty is measured, so that a
/// step measured during the flight and one measured later at its recorded pose see the same view.
pub fn step_camera(intrinsics: Intrinsics, position: &[f64; 3], attitude: &[f64; 3]) -> Camera {
    let rotation = so3_exp(&nalgebra::Vector3::from(*attitude));
    drone_camera(intrinsics, &nalgebra::Vector3::from(*position), &rotation)
}

/// Each step's uncertainty under `meter` at the pose an outcome keeps for the step's end (NaN
/// for a step without a finite pose: not flown).
pub(crate) fn measure_steps(
    meter: &dyn ViewUncertainty,
    intrinsics: Intrinsics,
    positions: &[[f64; 3]],
    attitudes: &[[f64; 3]],
) -> Vec<f64> {
    positions
        .iter()
        .zip(attitudes)
        .map(|(p, a)| match p.iter().chain(a).all(|v| v.is_finite()) {
            true => meter.view_uncertainty(&step_camera(intrinsics, p, a)),
            false => f64::NAN,
        })
        .collect()
}

/// The filter's log: its record of every camera image ([`ImageUpdate`]: the estimate's errors,
/// the innovation, whether the gate took the image, relocalised or lost track), per rollout (by
/// its seed), over the rollouts a system flew.
///
/// A rollout's log can be kept in a file ([`EstimateLog::save`], an image log CSV) and read back
/// ([`EstimateLog::load`]) bit-identical, so a run that recalls rollouts from a journal instead
/// of flying them still knows their images.
#[derive(Debug, Default)]
pub struct EstimateLog(Mutex<BTreeMap<u64, Vec<ImageUpdate>>>);

impl EstimateLog {
    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<u64, Vec<ImageUpdate>>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Sets the images of the rollout flown with `seed`.
    pub fn insert(&self, seed: u64, images: Vec<ImageUpdate>) {
        self.lock().insert(seed, images);
    }

    /// The images of the rollout flown with `seed` (none if it was not logged).
    pub fn images(&self, seed: u64) -> Vec<ImageUpdate> {
        self.lock().get(&seed).cloned().unwrap_or_default()
    }

    /// Every image recorded, rollout by rollout in the order of their seeds, so the result does
    /// not depend on the order rollouts finished in.
    pub fn all(&self) -> Vec<ImageUpdate> {
        self.lock().values().flatten().copied().collect()
    }

    /// Writes the images of the rollout `seed` to `path` (an image log, written atomically;
    /// only the header for a rollout not logged).
    pub fn save(&self, seed: u64, path: &Path) -> Result<(), ValidationError> {
        let text = nerfsv_sim::images_csv(self.lock().get(&seed).map_or(&[], |v| v.as_slice()));
        nerfsv_scene::io::atomic_write_bytes(path, text.as_bytes()).map_err(|e| ValidationError::io(path, e))
    }

    /// Reads a file [`EstimateLog::save`] wrote as the images of the rollout `seed`.
    pub fn load(&self, seed: u64, path: &Path) -> Result<(), ValidationError> {
        use nerfsv_sim::{ImageLogError as E, IMAGE_COLUMNS};
        let images = nerfsv_sim::read_images(path).map_err(|e| match e {
            E::Io { path, error } => ValidationError::io(&path, error),
            E::Header { path } => ValidationError::Csv {
                path,
                line: 1,
                message: format!("expected the header {}", IMAGE_COLUMNS.join(",")),
            },
            E::Columns { path, line, found } => ValidationError::Csv {
                path,
                line,
                message: format!("expected {} columns, found {found}", IMAGE_COLUMNS.len()),
            },
            E::Value { path, line, column, found } => ValidationError::Csv {
                path,
                line,
                message: format!("{column}: {found:?} is not a value of the column"),
            },
        })?;
        self.insert(seed, images);
        Ok(())
    }
}

/// A rollout's disturbances, one row per step, as the simulator takes them (components beyond
/// the trajectory's dimension are zero).
pub fn drone_disturbances(x: &Trajectory) -> Vec<Disturbance> {
    x.rows().map(|d| Disturbance(std::array::from_fn(|i| d.get(i).copied().unwrap_or(0.0)))).collect()
}

impl System for DroneSystem<'_> {
    fn steps(&self) -> usize {
        self.sim.steps
    }

    fn dim(&self) -> usize {
        Disturbance::DIM
    }

    /// The score is the minimum clearance of the body box over every checked substep (≤ 0 is
    /// a collision); a step's score is its own minimum, its position the true one at its end.
    /// Substeps whose box left the field's grid have no clearance and do not count; a step with
    /// none scores +∞. Steps not flown (after a crash that ended the rollout) score NaN and
    /// have NaN positions (and, when measured, NaN uncertainty).
    /// In this process, in parallel; or, with [`DroneSystem::remote`], wherever it flies them,
    /// each result put in the estimate log as [`run`](System::run) would have.
    fn run_all(&self, jobs: &[Job<'_>], finished: Finished<'_>) -> Result<(), ValidationError> {
        let Some(remote) = self.remote else {
            return run_here(self, jobs, finished);
        };
        if self.uncertainty.is_some() {
            return Err(ValidationError::Executor("rollouts flown elsewhere cannot measure uncertainty".into()));
        }
        // Known rollouts are taken here; only the others fly elsewhere.
        let (here, away): (Vec<usize>, Vec<usize>) =
            (0..jobs.len()).partition(|&i| self.known.is_some_and(|k| k.get(jobs[i].0, jobs[i].1).is_some()));
        for &i in &here {
            finished(i, self.run(jobs[i].0, jobs[i].1))?;
        }
        let spec = RemoteSpec { world: self.world.kind(), estimator: self.estimator };
        let encoded: Vec<Vec<u8>> = away.iter().map(|&i| encode_job(&jobs[i])).collect();
        remote.run(spec, &encoded, &mut |k, bytes| {
            let &i = away
                .get(k)
                .ok_or_else(|| ValidationError::Executor(format!("a result for job {k} of {}", away.len())))?;
            let (outcome, images) = decode_result(bytes)?;
            if let Some(log) = self.estimate_log {
                log.insert(jobs[i].1, images);
            }
            finished(i, outcome)
        })
    }

    fn run(&self, disturbances: &Trajectory, seed: u64) -> Outcome {
        if let Some(known) = self.known.and_then(|k| k.take(disturbances, seed)) {
            if let Some(log) = self.estimate_log {
                log.insert(seed, known.images.clone());
            }
            let o = &known.outcome;
            let step_uncertainty = match self.uncertainty {
                None => Vec::new(),
                Some(u) => measure_steps(u, self.sim.intrinsics, &o.step_positions, &o.step_attitudes),
            };
            return Outcome { step_uncertainty, ..o.clone() };
        }
        let r = self.sim.fly(self.world, self.estimator, &drone_disturbances(disturbances), seed);
        if let Some(log) = self.estimate_log {
            log.insert(seed, r.updates.clone());
        }
        let mut step_scores = vec![f64::NAN; self.sim.steps];
        // The substeps come in order: the last one of a step is its end, where the camera takes
        // the step's image.
        let mut step_ends = vec![None; self.sim.steps];
        for s in &r.substeps {
            if step_scores[s.step].is_nan() {
                step_scores[s.step] = f64::INFINITY;
            }
            if let Some(c) = s.clearance {
                step_scores[s.step] = step_scores[s.step].min(c as f64);
            }
            step_ends[s.step] = Some(&s.truth);
        }
        let step_positions: Vec<[f64; 3]> =
            step_ends.iter().map(|t| t.map_or([f64::NAN; 3], |t| t.position.into())).collect();
        let step_attitudes: Vec<[f64; 3]> =
            step_ends.iter().map(|t| t.map_or([f64::NAN; 3], |t| so3_log(&t.rotation).into())).collect();
        // Measured at the pose the record keeps, as a known rollout's and a recorded one's are.
        let step_uncertainty = match self.uncertainty {
            None => Vec::new(),
            Some(u) => measure_steps(u, self.sim.intrinsics, &step_positions, &step_attitudes),
        };
        let lost_step = [r.diverged, r.left_grid].into_iter().flatten().map(|e| e.step).min();
        Outcome {
            lost_step,
            score: r.min_clearance.map_or(f64::INFINITY, f64::from),
            collision_step: r.first_collision.map(|e| e.step),
            step_scores,
            step_positions,
            step_attitudes,
            step_uncertainty,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(step: usize, position_error_m: f64, nis: f64) -> ImageUpdate {
        ImageUpdate {
            step,
            substep: 0,
            time: 0.1 + 0.2 * step as f64,
            predicted_position_error_m: 1.0 / 3.0,
            predicted_rotation_error_deg: f64::MIN_POSITIVE,
            position_error_m,
            rotation_error_deg: 123456.789e-7,
            nees: f64::MAX,
            nis,
            accepted: nis < 12.6,
            relocalised: false,
            lost: false,
            variance_factor: 1.5,
            position_spread_m: 0.02,
            rotation_spread_deg: 0.5,
            renders: 4,
            relocalisation_undone: false,
            photometric_rmse: 0.01,
        }
    }

    #[test]
    fn image_logs_read_back_bit_identical_and_a_damaged_file_is_refused_by_line() {
        let dir = tempfile::tempdir().unwrap();
        let log = EstimateLog::default();
        let images = vec![image(0, 0.1 + 0.2, 3.0), image(1, 0.0, f64::INFINITY), image(2, 1e-9, f64::NAN)];
        log.insert(7, images.clone());
        log.insert(8, Vec::new());
        let (a, b) = (dir.path().join("7.images.csv"), dir.path().join("8.images.csv"));
        log.save(7, &a).unwrap();
        log.save(8, &b).unwrap();

        let back = EstimateLog::default();
        back.load(7, &a).unwrap();
        back.load(8, &b).unwrap();
        let bits = |l: &[ImageUpdate]| -> Vec<u64> { l.iter().flat_map(|u| u.to_row()).map(f64::to_bits).collect() };
        assert_eq!(bits(&back.all()), bits(&images));
        assert!(back.images(8).is_empty() && back.images(9).is_empty());

        let text = std::fs::read_to_string(&a).unwrap();
        std::fs::write(&a, text.replacen(",4,", ",4.5,", 1)).unwrap();
        let e = back.load(7, &a).unwrap_err().to_string();
        assert!(e.contains("7.images.csv: line 2: renders: \"4.5\""), "{e}");
        std::fs::write(&a, "0.1,0.2\n").unwrap();
        let e = back.load(7, &a).unwrap_err().to_string();
        assert!(e.contains("7.images.csv: line 1: expected the header step,substep,"), "{e}");
    }
}
