//! Each step's uncertainty, measured while a search flies or afterwards at the poses a record keeps.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use nerfsv_scene::Camera;
use nerfsv_sim::{World, WorldKind};
use nerfsv_validation::RolloutRecord;

use crate::drone::measure_steps;
use crate::flight::world;
use crate::{online_pixels, ExactUncertainty, FieldUncertainty, Observer, StudyError, UqMode, ViewUncertainty};

use super::setup::*;

/// Times a [`ViewUncertainty`]'s views.
pub(super) struct Timed<'a> {
    pub(super) inner: &'a dyn ViewUncertainty,
    pub(super) views: AtomicU64,
    pub(super) nanos: AtomicU64,
}

impl ViewUncertainty for Timed<'_> {
    fn view_uncertainty(&self, camera: &Camera) -> f64 {
        let start = Instant::now();
        let value = self.inner.view_uncertainty(camera);
        self.nanos.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.views.fetch_add(1, Ordering::Relaxed);
        value
    }
}

/// What measures a view's uncertainty under `setup.online` (none without): exact mode compares
/// the NeRF with `gt_world`'s render of the view, field mode looks it up in `setup.field`.
pub(super) fn view_meter<'a>(
    setup: &'a StressSetup,
    gt_world: Option<&'a dyn World>,
    background: [f32; 3],
) -> Result<Option<Box<dyn ViewUncertainty + 'a>>, StudyError> {
    let pixels = online_pixels(&setup.mission.drone.intrinsics, setup.uq);
    Ok(match setup.online {
        None => None,
        Some(o) => Some(match o.mode {
            UqMode::Exact => Box::new(ExactUncertainty {
                method: o.method,
                nerf: &setup.mission.inputs.nerf,
                reference: gt_world.ok_or(StudyError::NoGroundTruth)?,
                pixels,
                background,
                cfg: setup.uq,
            }),
            UqMode::Field => {
                let (_, field) = setup.field.ok_or_else(|| {
                    StudyError::Internal("field mode needs an uncertainty field (`nerfsv uq field`)".into())
                })?;
                Box::new(FieldUncertainty { field, pixels, background })
            }
        }),
    })
}

/// Rollouts already flown in `setup.world` (a stress run's records), each step's uncertainty
/// measured under `setup.online` at the pose the record keeps for the step's end
/// (`step_positions`, `step_attitudes`): what flying them again with the measurement on gives,
/// without flying them. A step without a finite pose (not flown) gets NaN. Returns the records
/// and the views measured with their wall-clock seconds (inside the parallel loop).
///
/// Errors: a record without poses (a system that records none), naming it.
pub fn measure_recorded(
    setup: &StressSetup,
    records: Vec<RolloutRecord>,
    observer: &dyn Observer,
) -> Result<(Vec<RolloutRecord>, usize, f64), StudyError> {
    let sim = setup.mission.flight.simulator(
        setup.mission.drone.sim,
        &setup.mission.inputs.nerf,
        setup.mission.drone.intrinsics,
    );
    let gt_world = match setup.online.map(|o| o.mode) {
        Some(UqMode::Exact) => {
            Some(world(WorldKind::Gt, setup.mission.inputs, setup.mission.drone.scene, setup.mission.drone.render)?)
        }
        _ => None,
    };
    let meter = view_meter(setup, gt_world.as_deref(), sim.background)?
        .ok_or_else(|| StudyError::Internal("measure_recorded: no uncertainty to measure".into()))?;
    measure_at_poses(records, sim.intrinsics, meter.as_ref(), &|d, total, status| {
        observer.progress(setup.stage, d, total, status)
    })
}

/// Each step's uncertainty under `meter` at the pose the record keeps for the step's end, the
/// drone's camera of `intrinsics` there (NaN for a step without a finite pose): the core of
/// [`measure_recorded`]. Returns the records and the views measured with their wall-clock
/// seconds; reports (done, total, status) to `progress`.
pub fn measure_at_poses(
    records: Vec<RolloutRecord>,
    intrinsics: nerfsv_scene::Intrinsics,
    meter: &dyn ViewUncertainty,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
) -> Result<(Vec<RolloutRecord>, usize, f64), StudyError> {
    let timed = Timed { inner: meter, views: AtomicU64::new(0), nanos: AtomicU64::new(0) };
    if let Some(r) = records
        .iter()
        .find(|r| r.step_positions.len() != r.step_scores.len() || r.step_attitudes.len() != r.step_scores.len())
    {
        return Err(StudyError::Internal(format!(
            "rollout {}/{}/{} keeps no pose per step: it cannot be measured without flying it",
            r.sampler, r.population, r.index
        )));
    }
    let status = format!("measuring {} rollouts' steps", records.len());
    let done = AtomicU64::new(0);
    let total = records.len() as u64;
    let measured: Vec<RolloutRecord> = records
        .into_par_iter()
        .map(|mut r| {
            r.step_uncertainty = measure_steps(&timed, intrinsics, &r.step_positions, &r.step_attitudes);
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(d, total, &status);
            r
        })
        .collect();
    let views = timed.views.load(Ordering::Relaxed) as usize;
    Ok((measured, views, timed.nanos.load(Ordering::Relaxed) as f64 * 1e-9))
}
