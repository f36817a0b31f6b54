//! The vision estimator on a run folder's model, away from the pipeline: how often it crashes
//! the drone under the paper's disturbances, how consistent its filter is, and what one image
//! update does from a disturbance. BENCHMARKS.md's vision-estimator figures come from it.
//!
//! ```sh
//! cargo run --release -- run     # a run folder with a trained model and both fields
//! cargo run --release --example estimator_study -- mc 100          # Monte Carlo, both worlds
//! cargo run --release --example estimator_study -- update 36       # single updates from the prior
//! cargo run --release --example estimator_study -- floor 36        # updates started at the truth
//! cargo run --release --example estimator_study -- basin 36        # fits from 5 cm / 3° off vs from the truth
//! cargo run --release --example estimator_study -- scatter 6       # fits from the truth, N pixel draws per pose
//! cargo run --release --example estimator_study -- relocalise 50   # recovery from 30 cm / 10° off, hovering
//! cargo run --release --example estimator_study -- nominal         # the undisturbed flights
//! ```
//!
//! The run folder is `runs/stonehenge` (`RUN=DIR` for another, `CONFIG=FILE` the config it was
//! run with, default the embedded one); settings override its `[sim.vision]` through the
//! environment: `IMAGES` (images per step), `ITERATIONS`, `SIGMA`
//! (photometric σ), `STOP_MM` (stop step in mm, with 0.06° per mm), `CANDIDATES`, `PIXELS`,
//! `COLLISION` (`body_box` or `centre_cell`), `WORLD` (`nerf`, `gt` or both), `RELOCALISE_AFTER`
//! (`relocalise_after`), `MODEL_M` and `MODEL_DEG` (`model_error_per_rmse`), `REFUSED`
//! (`max_refused`), `STOP_COST` (`stop_cost_decrease`), `JACOBIAN_MIN_WEIGHT`, `COARSEST` and `FINEST` (the coarsest and the
//! finest pyramid level); `CHECKPOINT` flies another model than the run folder's, `PER_STEP`
//! sets `scatter`'s poses per step (default 1). `DIAG=1` adds, for the vision
//! estimator's Monte Carlo, what the gate refused, the relocalisations and the largest accepted errors;
//! for `relocalise`, `DIAG=N` prints its first N cases image by image, `IMAGES_MAX` sets the
//! images per case (default 24) and `OFFSET_M` / `OFFSET_DEG` the start's offset (0.3 m, 10°);
//! `LOST_VF` sets `lost_variance_factor` (`inf`: never refuse a fit for its variance factor);
//! `BIAS=1` flies the filter with the shared bias the run's calibration measured (`[calibration]
//! filter_bias`). `NERF_WORLD` picks NeRF-sim's world: `deployed` (default: the estimator's own
//! NeRF), `ensemble` or `calibrated` (the study's, from the run folder's members and calibration;
//! `CHECKPOINT` then does not apply; `IMAGE_NOISE=0|1` sets `[calibration] image_noise`).
//! Disturbances come from a seeded generator of its own, so every setting is compared on the
//! same draws.

use std::path::PathBuf;
use std::time::Instant;

use nerfsv_pipeline::stages::{CollisionStage, NerfCollisionStage, NerfStage};
use nerfsv_pipeline::{stress_stage, RunConfig, Stage};
use nerfsv_scene::Scene;
use nerfsv_sim::dynamics::{so3_exp, so3_log};
use nerfsv_sim::estimator::Starts;
use nerfsv_sim::{
    Belief, Collision, Disturbance, EstimatorKind, Flight, ImageAt, ImageUpdate, NerfWorldSource, PosePrior, Rollout,
    Simulator, World, WorldKind,
};
use nerfsv_study::flight::{drone_world, FlightInputs};
use rayon::prelude::*;

fn env<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// A small seeded normal generator (SplitMix64 + Box–Muller), independent of the crates'.
struct Normal(u64);

impl Normal {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 + 0.5 / (1u64 << 53) as f64
    }

    fn sample(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }

    fn disturbance(&mut self) -> Disturbance {
        Disturbance(std::array::from_fn(|i| self.sample() * Disturbance::PAPER_STD[i]))
    }
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    nerfsv_scene::stats::quantile_sorted(v, q)
}

/// What every mode needs: the settings, the simulator on the planned flight, the world it
/// flies in (and which one), the number of cases and the mode's name.
struct Study<'a> {
    cfg: &'a RunConfig,
    sim: &'a Simulator<'a>,
    flight: &'a Flight,
    world: &'a dyn World,
    kind: WorldKind,
    n: usize,
    mode: &'a str,
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mode = args.first().map_or("mc", String::as_str).to_string();
    let n: usize = args.get(1).and_then(|v| v.parse().ok()).unwrap_or(40);
    let out = PathBuf::from(env("RUN", "runs/stonehenge".to_string()));
    let base = match std::env::var("CONFIG") {
        Ok(path) => RunConfig::load_with(Some(std::path::Path::new(&path)), &[])?,
        Err(_) => RunConfig::default(),
    };
    let mut cfg = RunConfig { out: Some(out.clone()), ..base };
    let v = &mut cfg.sim.vision;
    v.images_per_step = env("IMAGES", v.images_per_step);
    v.iterations = env("ITERATIONS", v.iterations);
    v.photometric_sigma = env("SIGMA", v.photometric_sigma);
    v.start_candidates = env("CANDIDATES", v.start_candidates);
    v.pixels = env("PIXELS", v.pixels);
    v.relocalise_after = env("RELOCALISE_AFTER", v.relocalise_after);
    v.lost_variance_factor = env("LOST_VF", v.lost_variance_factor);
    v.max_refused = env("REFUSED", v.max_refused);
    v.jacobian_min_weight = env("JACOBIAN_MIN_WEIGHT", v.jacobian_min_weight);
    v.stop_cost_decrease = env("STOP_COST", v.stop_cost_decrease);
    v.model_error_per_rmse = [env("MODEL_M", v.model_error_per_rmse[0]), env("MODEL_DEG", v.model_error_per_rmse[1])];
    v.levels[0] = env("COARSEST", v.levels[0]);
    v.levels[1] = env("FINEST", v.levels[1]).min(v.levels[0]);
    let stop_mm: f64 = env("STOP_MM", v.stop_step[0] * 1e3);
    v.stop_step = [stop_mm * 1e-3, stop_mm * 0.06];
    if env("BIAS", 0u8) == 1 {
        // The shared bias the run's calibration measured, as `[calibration] filter_bias` flies it.
        let calibration = nerfsv_study::calibration::CalibrationConfig { filter_bias: true, ..Default::default() };
        v.model_bias = nerfsv_pipeline::inputs::load_calibration(&out, &calibration, 0)?.model_bias;
        println!("filter bias: {:?}", v.model_bias);
    }
    if env("COLLISION", String::new()) == "centre_cell" {
        cfg.sim.collision = Collision::CentreCell;
    }
    let scene = Scene::builtin(&cfg.scene)?;
    cfg.sim.nerf_world = match env("NERF_WORLD", String::new()).as_str() {
        "ensemble" => NerfWorldSource::Ensemble,
        "calibrated" => NerfWorldSource::Calibrated,
        _ => NerfWorldSource::Deployed,
    };
    cfg.calibration.image_noise = env("IMAGE_NOISE", u8::from(cfg.calibration.image_noise)) == 1;
    let inputs = if cfg.sim.nerf_world == NerfWorldSource::Deployed {
        FlightInputs::load(
            &std::env::var("CHECKPOINT").map_or_else(|_| NerfStage::checkpoint(&out), PathBuf::from),
            &out.join(NerfCollisionStage::NAME).join(NerfCollisionStage::SDF),
            Some(&CollisionStage::sdf_path(&out)),
        )?
    } else {
        // The members (and the calibration), read from the run folder as the stress stage reads them.
        let prior = cfg.disturbance_prior()?;
        stress_stage(&cfg, Some(&scene), &prior).load_inputs(&out)?
    };
    let flight = inputs.plan(&cfg.sim)?;
    let sim = flight.simulator(&cfg.sim, &inputs.nerf, cfg.camera_intrinsics());
    let worlds = match env("WORLD", String::new()).as_str() {
        "nerf" => vec![WorldKind::Nerf],
        "gt" => vec![WorldKind::Gt],
        _ => vec![WorldKind::Nerf, WorldKind::Gt],
    };
    for kind in worlds {
        let w = drone_world(kind, cfg.sim.nerf_world, &inputs, Some(&scene), cfg.dataset.render_settings())?;
        let study = Study { cfg: &cfg, sim: &sim, flight: &flight, world: w.as_ref(), kind, n, mode: &mode };
        match mode.as_str() {
            "mc" => monte_carlo(&study),
            "scatter" => scatter(&study),
            "basin" => basin(&study),
            "update" | "floor" => single_updates(&study),
            "relocalise" => relocalise(&study),
            _ => nominal(&study),
        }
    }
    Ok(())
}

/// Prints, per estimator, the collisions, refusals, NEES and errors of `n` disturbed flights.
fn monte_carlo(study: &Study) {
    let Study { cfg, sim, world: w, kind, n, .. } = *study;
    for estimator in [EstimatorKind::Vision, EstimatorKind::Truth] {
        let start = Instant::now();
        let rollouts: Vec<Rollout> = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut rng = Normal(1000 + i as u64);
                let ds: Vec<Disturbance> = (0..cfg.sim.steps).map(|_| rng.disturbance()).collect();
                sim.fly(w, estimator, &ds, i as u64)
            })
            .collect();
        if std::env::var("DIAG").is_ok() && estimator == EstimatorKind::Vision {
            vision_diagnostics(&rollouts);
        }
        let crashed = rollouts.iter().filter(|r| r.collided()).count();
        let updates: Vec<_> = rollouts.iter().flat_map(|r| &r.updates).collect();
        let images = updates.len().max(1) as f64;
        let mut nees: Vec<f64> = updates.iter().map(|u| u.nees).collect();
        let mean_nees = nees.iter().sum::<f64>() / images;
        let median_nees = if nees.is_empty() { f64::NAN } else { percentile(&mut nees, 0.5) };
        // The images of one rollout are correlated: the interval of the mean NEES is
        // over the rollouts' own means (12 inside it for a consistent filter).
        let per_rollout: Vec<f64> = rollouts
            .iter()
            .filter(|r| !r.updates.is_empty())
            .map(|r| r.updates.iter().map(|u| u.nees).sum::<f64>() / r.updates.len() as f64)
            .collect();
        let m = per_rollout.len().max(2) as f64;
        let rollout_mean = per_rollout.iter().sum::<f64>() / m;
        let sd = (per_rollout.iter().map(|x| (x - rollout_mean).powi(2)).sum::<f64>() / (m - 1.0)).sqrt();
        println!(
            "{}-sim, {}: {crashed}/{n} collided; {} images, {:.2} renders each, {} refused ({:.2} %; by the \
             gate {}, lost fits {}), {} relocalisations; mean NEES {:.1} (median {:.1}), over rollouts {:.1} [{:.1}, {:.1}] (n {}); \
             mean error {:.1} mm / {:.2}°; {:.1} s",
            kind.name(),
            estimator.name(),
            updates.len(),
            updates.iter().map(|u| u.renders).sum::<usize>() as f64 / images,
            updates.iter().filter(|u| !u.accepted).count(),
            100.0 * updates.iter().filter(|u| !u.accepted).count() as f64 / images,
            updates.iter().filter(|u| !u.accepted && !u.lost).count(),
            updates.iter().filter(|u| u.lost).count(),
            updates.iter().filter(|u| u.relocalised).count(),
            mean_nees,
            median_nees,
            rollout_mean,
            rollout_mean - 1.96 * sd / m.sqrt(),
            rollout_mean + 1.96 * sd / m.sqrt(),
            per_rollout.len(),
            1e3 * updates.iter().map(|u| u.position_error_m).sum::<f64>() / images,
            updates.iter().map(|u| u.rotation_error_deg).sum::<f64>() / images,
            start.elapsed().as_secs_f64()
        );
        if !updates.is_empty() {
            // A consistent filter's NIS exceeds χ²₆'s 95th percentile on 5 % of images.
            let above = updates.iter().filter(|u| u.nis.is_nan() || u.nis > nerfsv_sim::filter::NIS_CHI2_95).count();
            let mut nis: Vec<f64> =
                updates.iter().map(|u| if u.nis.is_nan() { f64::INFINITY } else { u.nis }).collect();
            println!(
                "  NIS > χ²₆(0.95) on {above} of {} images ({:.1} %; 5 % if consistent); NIS median {:.2} p90 {:.2}",
                updates.len(),
                100.0 * above as f64 / images,
                percentile(&mut nis, 0.5),
                percentile(&mut nis, 0.9)
            );
        }
        let mut position: Vec<f64> = updates.iter().map(|u| 1e3 * u.position_error_m).collect();
        let mut rotation: Vec<f64> = updates.iter().map(|u| u.rotation_error_deg).collect();
        if !position.is_empty() {
            println!(
                "    error after each image: position median {:.1} mm (p90 {:.1}), rotation median {:.2}° (p90 {:.2})",
                percentile(&mut position, 0.5),
                percentile(&mut position, 0.9),
                percentile(&mut rotation, 0.5),
                percentile(&mut rotation, 0.9)
            );
        }
    }
}

/// Prints the vision estimator's refused images, relocalisations and largest errors (`DIAG`).
fn vision_diagnostics(rollouts: &[Rollout]) {
    let rej: Vec<_> = rollouts.iter().flat_map(|r| &r.updates).filter(|u| !u.accepted).collect();
    let mut e: Vec<f64> = rej.iter().map(|u| 1e3 * u.predicted_position_error_m).collect();
    let mut sp: Vec<f64> = rej.iter().map(|u| 1e3 * u.position_spread_m).collect();
    let mut rm: Vec<f64> = rej.iter().map(|u| u.photometric_rmse).collect();
    let first = rej.iter().filter(|u| u.substep == 0).count();
    let mut vf: Vec<f64> = rej.iter().map(|u| u.variance_factor).collect();
    let mut vfa: Vec<f64> =
        rollouts.iter().flat_map(|r| &r.updates).filter(|u| u.accepted).map(|u| u.variance_factor).collect();
    let rec = rollouts.iter().flat_map(|r| &r.updates).filter(|u| u.relocalised).count();
    if !vfa.is_empty() {
        println!(
            "relocalised {rec}; vf accepted median {:.3} p90 {:.3} p99 {:.3}",
            percentile(&mut vfa, 0.5),
            percentile(&mut vfa, 0.9),
            percentile(&mut vfa, 0.99)
        );
    }
    if !vf.is_empty() {
        println!(
            "vf rejected median {:.3} p10 {:.3} p90 {:.3}",
            percentile(&mut vf, 0.5),
            percentile(&mut vf, 0.1),
            percentile(&mut vf, 0.9)
        );
    }
    if !rej.is_empty() {
        println!(
            "rejected: {} ({} first of step); predicted error median {:.1} mm p90 {:.1}; spread after median {:.2} mm; rmse median {:.3}",
            rej.len(), first, percentile(&mut e, 0.5), percentile(&mut e, 0.9), percentile(&mut sp, 0.5), percentile(&mut rm, 0.5)
        );
    }
    let acc: Vec<_> = rollouts.iter().flat_map(|r| &r.updates).filter(|u| u.accepted).collect();
    for u in acc.iter().filter(|u| u.position_error_m > 0.01).take(25) {
        println!(
            "  big: step {} sub {} pred {:.1} mm -> {:.1} mm, {:.2}° -> {:.2}°, nis {:.1}, vf {:.3}, spread {:.2} mm, reloc {}, renders {}",
            u.step, u.substep, 1e3 * u.predicted_position_error_m, 1e3 * u.position_error_m,
            u.predicted_rotation_error_deg, u.rotation_error_deg, u.nis, u.variance_factor,
            1e3 * u.position_spread_m, u.relocalised, u.renders
        );
    }
    let mut ratio: Vec<f64> = acc.iter().map(|u| u.position_error_m / u.position_spread_m.max(1e-12)).collect();
    let mut e: Vec<f64> = acc.iter().map(|u| 1e3 * u.position_error_m).collect();
    let mut sp: Vec<f64> = acc.iter().map(|u| 1e3 * u.position_spread_m).collect();
    println!(
        "accepted: error median {:.2} mm p90 {:.2} p99 {:.2}; spread median {:.2} mm; error/spread median {:.2} p90 {:.2} p99 {:.2}",
        percentile(&mut e, 0.5), percentile(&mut e, 0.9), percentile(&mut e, 0.99), percentile(&mut sp, 0.5),
        percentile(&mut ratio, 0.5), percentile(&mut ratio, 0.9), percentile(&mut ratio, 0.99)
    );
}

/// Prints the mean and spread of `n` fits from the true pose at each pose of the nominal path.
fn scatter(study: &Study) {
    let Study { cfg, sim, flight, world: w, kind, n, .. } = *study;
    // Fits from the true pose (under the 5 cm / 3° prior) on the nominal path, with n
    // pixel draws per pose: the mean of their errors is the image's bias, their spread
    // what a different set of pixels moves the optimum by. Body frame: x forward,
    // y left, z up; roll, pitch, yaw about those axes.
    let per_step: usize = env("PER_STEP", 1).max(1);
    let n = n.max(2);
    println!("{}-sim, fits from the true pose, {n} pixel draws each (body frame; mean ± sd):", kind.name());
    for i in 0..cfg.sim.steps * per_step {
        let t = i as f64 * sim.step_duration() / per_step as f64;
        let at = flight.reference.at_rest(t);
        let r = at.rotation;
        let rows: Vec<[f64; 7]> = (0..n as u64)
            .map(|seed| {
                let prior = PosePrior::isotropic(at.position, at.rotation, 0.05, 3.0);
                let f = sim.observe_and_refine(w, &at, &prior, 100 + seed, Starts::NONE);
                let dp = r.transpose() * (f.position - at.position) * 1e3;
                let dr = (r.transpose() * so3_log(&(f.rotation * r.transpose()))).map(f64::to_degrees);
                [dp.x, dp.y, dp.z, dr.x, dr.y, dr.z, f.rmse]
            })
            .collect();
        let mean = |c: usize| rows.iter().map(|x| x[c]).sum::<f64>() / n as f64;
        let sd = |c: usize| {
            let m = mean(c);
            (rows.iter().map(|x| (x[c] - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        };
        println!(
            "t {t:4.1} s: position mm x {:6.1} ± {:4.1}, y {:6.1} ± {:4.1}, z {:6.1} ± {:4.1}; \
             roll {:5.2} ± {:4.2}°, pitch {:5.2} ± {:4.2}°, yaw {:5.2} ± {:4.2}°; rmse {:.3}",
            mean(0),
            sd(0),
            mean(1),
            sd(1),
            mean(2),
            sd(2),
            mean(3),
            sd(3),
            mean(4),
            sd(4),
            mean(5),
            sd(5),
            mean(6)
        );
    }
}

/// Prints where fits from 5 cm / 3° off and from the true pose land, over `n` poses.
fn basin(study: &Study) {
    let Study { cfg, sim, flight, world: w, kind, n, .. } = *study;
    // From 5 cm / 3° off in a random direction, and from the true pose (the bias
    // floor), under the same 5 cm / 3° prior: where does each fit land?
    let mut rng = Normal(11);
    let (mut to_truth, mut to_floor) = (0, 0);
    let (mut floor_err, mut start_err) = (Vec::new(), Vec::new());
    for case in 0..n {
        let k = case % cfg.sim.steps;
        let at = flight.reference.at_rest(k as f64 * sim.step_duration());
        let unit = |rng: &mut Normal| {
            let v = nalgebra::Vector3::new(rng.sample(), rng.sample(), rng.sample());
            v / v.norm()
        };
        let start_p = at.position + unit(&mut rng) * 0.05;
        let start_r = so3_exp(&(unit(&mut rng) * 3f64.to_radians())) * at.rotation;
        let seed = case as u64;
        let floor = sim.observe_and_refine(
            w,
            &at,
            &PosePrior::isotropic(at.position, at.rotation, 0.05, 3.0),
            seed,
            Starts::one_sigma(sim.vision.start_candidates),
        );
        let fit = sim.observe_and_refine(
            w,
            &at,
            &PosePrior::isotropic(start_p, start_r, 0.05, 3.0),
            seed,
            Starts::one_sigma(sim.vision.start_candidates),
        );
        let angle =
            |a: &nalgebra::Matrix3<f64>, b: &nalgebra::Matrix3<f64>| so3_log(&(a * b.transpose())).norm().to_degrees();
        let (tp, tr) = ((fit.position - at.position).norm(), angle(&fit.rotation, &at.rotation));
        let (fp, fr) = ((fit.position - floor.position).norm(), angle(&fit.rotation, &floor.rotation));
        to_truth += usize::from(tp <= 0.01 && tr <= 0.5);
        to_floor += usize::from(fp <= 0.005 && fr <= 0.3);
        floor_err.push(1e3 * (floor.position - at.position).norm());
        start_err.push(1e3 * fp);
    }
    println!(
        "{}-sim, basin from 5 cm / 3° off: {to_truth}/{n} within 1 cm / 0.5° of the truth, {to_floor}/{n} \
         within 5 mm / 0.3° of the fit from the true pose; that fit (the floor) is {:.1} mm from the truth \
         (median, p90 {:.1}); from the offset start, {:.1} mm from the floor (median, p90 {:.1})",
        kind.name(),
        percentile(&mut floor_err.clone(), 0.5),
        percentile(&mut floor_err, 0.9),
        percentile(&mut start_err.clone(), 0.5),
        percentile(&mut start_err, 0.9),
    );
}

/// Prints the errors after one image update from the prior (`update`) or from the truth (`floor`).
fn single_updates(study: &Study) {
    let Study { cfg, sim, flight, world: w, kind, n, mode } = *study;
    let mut rng = Normal(7);
    let (mut within, mut pos, mut rot, mut ms) = (0, Vec::new(), Vec::new(), 0.0);
    for case in 0..n {
        let k = case % cfg.sim.steps;
        let at = flight.reference.at_rest(k as f64 * sim.step_duration());
        let mut belief = Belief::new(at, &cfg.sim.vision.initial_std);
        belief.disturb(&cfg.sim.vision.disturbance_std);
        let d = rng.disturbance();
        let truth = if mode == "floor" { at } else { d.apply(&at) };
        let t = Instant::now();
        let u = sim.image_update(w, &truth, &mut belief, case as u64, ImageAt { step: k, substep: 0, time: 0.0 });
        ms += 1e3 * t.elapsed().as_secs_f64();
        if u.position_error_m <= 0.01 && u.rotation_error_deg <= 0.5 {
            within += 1;
        }
        pos.push(1e3 * u.position_error_m);
        rot.push(u.rotation_error_deg);
    }
    println!(
        "{}-sim, {mode}: {within}/{n} within 1 cm / 0.5° after one image; median {:.1} mm / {:.2}°, p90 \
         {:.1} mm / {:.2}°; {:.1} ms per update",
        kind.name(),
        percentile(&mut pos, 0.5),
        percentile(&mut rot, 0.5),
        percentile(&mut pos, 0.9),
        percentile(&mut rot, 0.9),
        ms / n as f64
    );
}

/// Prints how often a lost, confident filter recovers while hovering, over `n` cases.
fn relocalise(study: &Study) {
    let Study { cfg, sim, flight, world: w, kind, n, .. } = *study;
    // A lost, confident filter: the truth at rest on the nominal path, the belief
    // exactly 30 cm / 10° off it (random direction and axis) under the prior and
    // disturbance covariance of a step's first image; the truth hovers while up to
    // `IMAGES_MAX` images (3 steps × 8 by default) come in.
    let images: usize = env("IMAGES_MAX", 24);
    let per_step = cfg.sim.vision.images_per_step.max(1);
    let (tol_m, tol_deg) = (0.02, 1.0);
    let (off_m, off_deg) = (env("OFFSET_M", 0.3), env("OFFSET_DEG", 10.0));
    let start = Instant::now();
    let cases: Vec<Vec<ImageUpdate>> = (0..n)
        .into_par_iter()
        .map(|k| {
            let mut rng = Normal(k as u64);
            let unit = |rng: &mut Normal| {
                let v = nalgebra::Vector3::new(rng.sample(), rng.sample(), rng.sample());
                v / v.norm()
            };
            // Poses spread along the flight (not its end points twice).
            let t = sim.step_duration() * cfg.sim.steps as f64 * (k as f64 + 0.5) / n as f64;
            let truth = flight.reference.at_rest(t);
            let mut mean = truth;
            mean.position += unit(&mut rng) * off_m;
            mean.rotation = so3_exp(&(unit(&mut rng) * f64::to_radians(off_deg))) * truth.rotation;
            let mut belief = Belief::new(mean, &sim.vision.initial_std);
            belief.disturb(&sim.vision.disturbance_std);
            (0..images)
                .map(|j| {
                    let (step, substep) = (j / per_step, j % per_step);
                    let seed = nerfsv_scene::seed::mix(k as u64, step as u64 + 1, substep as u64);
                    sim.image_update(w, &truth, &mut belief, seed, ImageAt { step, substep, time: t })
                })
                .collect()
        })
        .collect();
    let within = |u: &ImageUpdate| u.position_error_m <= tol_m && u.rotation_error_deg <= tol_deg;
    let ok = cases.iter().filter(|c| c.last().is_some_and(within)).count();
    let (lo, hi) = nerfsv_validation::wilson_interval(ok, n);
    let mut to_recover: Vec<f64> =
        cases.iter().map(|c| c.iter().position(within).map_or(f64::INFINITY, |i| (i + 1) as f64)).collect();
    let recovered = to_recover.iter().filter(|x| x.is_finite()).count();
    let relocs: Vec<usize> = cases.iter().map(|c| c.iter().filter(|u| u.relocalised).count()).collect();
    let mut fp: Vec<f64> = cases.iter().filter_map(|c| c.last()).map(|u| 1e3 * u.position_error_m).collect();
    let mut fr: Vec<f64> = cases.iter().filter_map(|c| c.last()).map(|u| u.rotation_error_deg).collect();
    let median_images = percentile(&mut to_recover, 0.5);
    println!(
        "{}-sim, relocalise from {:.0} cm / {off_deg}° off: {ok}/{n} within 2 cm / 1° after {images} images \
         (Wilson 95 % [{:.1}, {:.1}] %); {recovered}/{n} ever within, median images to recover {}; \
         relocalisations per case mean {:.2} (max {}); final error median {:.1} mm / {:.2}°, p90 {:.1} mm / \
         {:.2}°; {:.1} s",
        kind.name(),
        off_m * 1e2,
        1e2 * lo,
        1e2 * hi,
        if median_images.is_finite() { format!("{median_images:.0}") } else { "never".to_string() },
        relocs.iter().sum::<usize>() as f64 / n.max(1) as f64,
        relocs.iter().max().copied().unwrap_or(0),
        percentile(&mut fp, 0.5),
        percentile(&mut fr, 0.5),
        percentile(&mut fp, 0.9),
        percentile(&mut fr, 0.9),
        start.elapsed().as_secs_f64()
    );
    if std::env::var("DIAG").is_ok() {
        relocalise_diagnostics(&cases, n, tol_m, tol_deg);
    }
    // `DIAG=N`: the first N cases image by image.
    print_case_images(&cases);
}

/// Prints `relocalise`'s fits taken while lost or on track, refused, and relocalised (`DIAG`).
fn relocalise_diagnostics(cases: &[Vec<ImageUpdate>], n: usize, tol_m: f64, tol_deg: f64) {
    // Where the gate goes wrong: fits taken while lost, fits taken while on track,
    // the refused ones, and what each relocalisation gave.
    let within = |u: &ImageUpdate| u.position_error_m <= tol_m && u.rotation_error_deg <= tol_deg;
    let all: Vec<&ImageUpdate> = cases.iter().flatten().collect();
    let summary = |label: &str, set: Vec<&&ImageUpdate>| {
        if set.is_empty() {
            println!("  {label}: none");
            return;
        }
        let mut vf: Vec<f64> = set.iter().map(|u| u.variance_factor).collect();
        let mut rm: Vec<f64> = set.iter().map(|u| u.photometric_rmse).collect();
        let mut nis: Vec<f64> = set.iter().map(|u| u.nis).collect();
        println!(
            "  {label}: {} images; variance factor p10 {:.3} median {:.3} p90 {:.3}; rmse p10 {:.4} median \
             {:.4} p90 {:.4}; nis median {:.1} p90 {:.1}",
            set.len(),
            percentile(&mut vf, 0.1),
            percentile(&mut vf, 0.5),
            percentile(&mut vf, 0.9),
            percentile(&mut rm, 0.1),
            percentile(&mut rm, 0.5),
            percentile(&mut rm, 0.9),
            percentile(&mut nis, 0.5),
            percentile(&mut nis, 0.9)
        );
    };
    summary(
        "taken while lost (> 5 cm after, no relocalisation)",
        all.iter().filter(|u| u.accepted && !u.relocalised && u.position_error_m > 0.05).collect(),
    );
    summary(
        "taken on track (≤ 2 cm / 1° before and after)",
        all.iter()
            .filter(|u| {
                u.accepted
                    && !u.relocalised
                    && within(u)
                    && u.predicted_position_error_m <= tol_m
                    && u.predicted_rotation_error_deg <= tol_deg
            })
            .collect(),
    );
    summary("refused", all.iter().filter(|u| !u.accepted).collect());
    let refused_cases = cases.iter().filter(|c| c.iter().any(|u| !u.accepted)).count();
    let reloc_cases = cases.iter().filter(|c| c.iter().any(|u| u.relocalised)).count();
    let relocs: Vec<&&ImageUpdate> = all.iter().filter(|u| u.relocalised).collect();
    println!(
        "  {refused_cases}/{n} cases had a refusal, {reloc_cases}/{n} relocalised; {} relocalisations, {} \
         of them within 2 cm / 1° after",
        relocs.len(),
        relocs.iter().filter(|u| within(u)).count()
    );
    summary("relocalisations", relocs);
}

/// Prints the first `DIAG` cases of `relocalise` image by image.
fn print_case_images(cases: &[Vec<ImageUpdate>]) {
    for (k, c) in cases.iter().enumerate().take(env("DIAG", 0)) {
        println!("  case {k}:");
        for (j, u) in c.iter().enumerate() {
            println!(
                "    image {j:2} (step {} sub {}): {:7.1} mm / {:5.2}° -> {:7.1} mm / {:5.2}°, nis {:9.1}, \
                 accepted {}, relocalised {}, vf {:.3}, rmse {:.4}, spread {:.1} mm / {:.2}°, renders {}",
                u.step,
                u.substep,
                1e3 * u.predicted_position_error_m,
                u.predicted_rotation_error_deg,
                1e3 * u.position_error_m,
                u.rotation_error_deg,
                u.nis,
                u.accepted,
                u.relocalised,
                u.variance_factor,
                u.photometric_rmse,
                1e3 * u.position_spread_m,
                u.rotation_spread_deg,
                u.renders
            );
        }
    }
}

/// Prints the undisturbed flights of both estimators and, for the vision one, its estimate's errors.
fn nominal(study: &Study) {
    let Study { cfg, sim, world: w, kind, .. } = *study;
    for estimator in [EstimatorKind::Vision, EstimatorKind::Truth] {
        let t = Instant::now();
        let r = sim.fly(w, estimator, &[], cfg.flight_seed);
        println!(
            "{}-sim, {}, undisturbed: collided {}, min clearance {:.3} m, {:.3} m from the goal, {} images \
             ({:.1} ms each)",
            kind.name(),
            estimator.name(),
            r.collided(),
            r.min_clearance.unwrap_or(f32::NAN),
            r.goal_distance_m,
            r.updates.len(),
            1e3 * t.elapsed().as_secs_f64() / r.updates.len().max(1) as f64
        );
        if let (EstimatorKind::Vision, Some(last)) = (estimator, r.updates.last()) {
            let max_p = r.updates.iter().map(|u| u.position_error_m).fold(0.0, f64::max);
            let max_r = r.updates.iter().map(|u| u.rotation_error_deg).fold(0.0, f64::max);
            println!(
                "{}-sim, {}, undisturbed estimate: final error {:.1} mm / {:.2}° (step {} substep {}), max \
                 {:.1} mm / {:.2}° over the flight; {} refused images, {} relocalisations; final error {} 5 cm",
                kind.name(),
                estimator.name(),
                1e3 * last.position_error_m,
                last.rotation_error_deg,
                last.step,
                last.substep,
                1e3 * max_p,
                max_r,
                r.updates.iter().filter(|u| !u.accepted).count(),
                r.updates.iter().filter(|u| u.relocalised).count(),
                if last.position_error_m > 0.05 { "ABOVE" } else { "within" }
            );
        }
    }
}
