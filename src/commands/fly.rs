use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, ValueEnum};
use nerfsv_collision::SdfGrid;
use nerfsv_dataset::GenerateOptions;
use nerfsv_nerf::Nerf;
use nerfsv_pipeline::flight::{fly_and_write, world, FlightInputs};
use nerfsv_pipeline::stages::nerf_density_field;
use nerfsv_pipeline::{load_toml, refuse_output_inside, Validate};
use nerfsv_scene::{InvalidValue, Scene};
use nerfsv_sim::{random_disturbances, read_disturbances, EstimatorKind, SimConfig, WorldKind};
use serde::Deserialize;

#[derive(Clone, Copy, ValueEnum)]
pub enum WorldArg {
    /// NeRF-sim: images rendered by the NeRF, collisions against the NeRF's signed field.
    Nerf,
    /// GT-sim: images from the ground-truth renderer, collisions against its signed field.
    Gt,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum EstimatorArg {
    /// The controller sees the true state.
    Truth,
    /// Dynamics prediction refined by photometric alignment of the camera image to the NeRF.
    Vision,
}

#[derive(Args)]
pub struct FlyArgs {
    /// The world the drone flies in.
    #[arg(long, value_enum, default_value = "nerf")]
    pub world: WorldArg,
    /// Built-in ground-truth scene (GT-sim's world; its grid also carries the NeRF's field).
    #[arg(long, default_value = "stonehenge")]
    pub scene: String,
    /// NeRF checkpoint: the estimator's model, NeRF-sim's world, and the planner's map.
    #[arg(long)]
    pub model: PathBuf,
    /// The NeRF's signed field (e.g. RUN/nerf_collision/nerf_sdf.safetensors); default: built
    /// from --model on the scene's grid (about a second).
    #[arg(long)]
    pub nerf_field: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "vision")]
    pub estimator: EstimatorArg,
    /// One disturbance per step: CSV with 12 columns (dp_x..dp_z, dv_x..dv_z, dr_x..dr_z,
    /// dw_x..dw_z), a header line optional.
    #[arg(long, conflicts_with = "random_seed")]
    pub disturbances: Option<PathBuf>,
    /// Draw the disturbances from N(0, diag(sim.disturbance_std²)) with this seed.
    #[arg(long)]
    pub random_seed: Option<u64>,
    /// Seed of the estimator's pixel choices (default: --random-seed, else 0).
    #[arg(long)]
    pub seed: Option<u64>,
    /// TOML file with the flight settings: the keys of a run config's `[sim]` table.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder: trajectory.csv, trajectory.png, disturbances.csv, flight.json.
    #[arg(long, default_value = "fly")]
    pub out: PathBuf,
    /// Print one JSON object with the figures.
    #[arg(long)]
    pub json: bool,
}

/// A `--config` file: the `[sim]` table's keys at the top level.
#[derive(Deserialize)]
#[serde(transparent)]
struct FlyConfig(SimConfig);

impl Validate for FlyConfig {
    fn validate(&self) -> Result<(), InvalidValue> {
        self.0.validate()
    }
}

pub fn run(args: FlyArgs) -> anyhow::Result<()> {
    let cfg = match &args.config {
        Some(path) => load_toml::<FlyConfig>(path)?.0,
        None => SimConfig::default(),
    };
    let mut inputs: Vec<(&str, &std::path::Path)> = vec![("--model", &args.model)];
    if let Some(p) = &args.nerf_field {
        inputs.push(("--nerf-field", p));
    }
    if let Some(p) = &args.disturbances {
        inputs.push(("--disturbances", p));
    }
    refuse_output_inside(&args.out, &inputs)?;

    // Everything that can be refused is checked before anything is written.
    let disturbances = match (&args.disturbances, args.random_seed) {
        (Some(path), _) => read_disturbances(path, cfg.steps)?,
        (None, Some(seed)) => random_disturbances(&cfg.disturbance_std, cfg.steps, seed),
        (None, None) => vec![nerfsv_sim::Disturbance::ZERO; cfg.steps],
    };
    let scene = Scene::builtin(&args.scene)?;
    let nerf = Nerf::load(&args.model)?;
    let (gt, _) = nerfsv_collision::ground_truth_field(&scene, 40.0)?;
    let nerf_field = match &args.nerf_field {
        Some(path) => SdfGrid::load(path)?,
        None => {
            // On the ground-truth field's grid, as `nerfsv run` builds it.
            nerf_density_field(&nerf, gt.sdf.geometry, None)?.1.sdf
        }
    };
    let inputs = FlightInputs { nerf, nerf_field, gt_field: gt.sdf };
    let flight = inputs.plan(&cfg).context("planning the flight")?;
    let kind = match args.world {
        WorldArg::Nerf => WorldKind::Nerf,
        WorldArg::Gt => WorldKind::Gt,
    };
    let estimator = match args.estimator {
        EstimatorArg::Truth => EstimatorKind::Truth,
        EstimatorArg::Vision => EstimatorKind::Vision,
    };
    let dataset = GenerateOptions::default();
    let intrinsics = nerfsv_scene::Intrinsics::from_fov_x(dataset.width, dataset.height, dataset.camera_angle_x);
    let w = world(kind, &inputs, &scene, dataset.render_settings());

    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let seed = args.seed.or(args.random_seed).unwrap_or(0);
    let (figures, _) = fly_and_write(
        &flight,
        &cfg,
        &inputs.nerf,
        intrinsics,
        w.as_ref(),
        estimator,
        &disturbances,
        seed,
        &args.out.join("trajectory.csv"),
        &args.out.join("trajectory.png"),
    )?;
    let path = args.out.join("disturbances.csv");
    nerfsv_scene::io::atomic_write_bytes(&path, nerfsv_sim::io::disturbances_csv(&disturbances).as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    nerfsv_pipeline::stage::write_json(&args.out.join("flight.json"), &figures)?;
    crate::commands::report(args.json, &figures, || figures.describe())
}
