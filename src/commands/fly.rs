use std::path::PathBuf;

use clap::Args;
use nerfsv_pipeline::{Guard, OutputKind};
use nerfsv_scene::Scene;
use nerfsv_sim::{read_disturbances, EstimatorKind, WorldKind};
use nerfsv_study::drone_disturbances;
use nerfsv_study::flight::{fly_into, FlightInputs, FlightRequest};

use crate::commands::world::{load_mesh_scene, MeshArgs};
use crate::config_file::{one_model, Sets};

/// The drone, its worlds and its estimator: what `fly` and `stress` both take.
#[derive(Args)]
pub struct DroneArgs {
    /// The world the drone flies in.
    #[arg(long, value_enum, default_value = "nerf")]
    pub world: WorldKind,
    /// Built-in ground-truth scene (GT-sim's world; its grid also carries the NeRF's field).
    #[arg(long, default_value = "stonehenge", conflicts_with = "gt_mesh")]
    pub scene: String,
    /// A triangle mesh as the ground truth instead (OBJ, PLY, glTF/GLB; metres, z up unless
    /// --mesh-scale / --mesh-up say otherwise), as a run's `[world] mesh`.
    #[arg(long)]
    pub gt_mesh: Option<PathBuf>,
    #[command(flatten)]
    pub mesh_options: MeshArgs,
    /// NeRF checkpoint: the estimator's model, NeRF-sim's world, and the planner's map.
    #[arg(long)]
    pub model: PathBuf,
    /// The NeRF's signed field (e.g. RUN/nerf_collision/nerf_sdf.safetensors); default: built
    /// from --model on the scene's grid (about a second).
    #[arg(long)]
    pub nerf_field: Option<PathBuf>,
    /// What the controller believes: `vision` (the pose fitted to camera images of the NeRF,
    /// through the filter) or `truth` (the true state, for a baseline without estimation error).
    #[arg(long, value_enum, default_value = "vision")]
    pub estimator: EstimatorKind,
}

impl DroneArgs {
    /// The files read, for the guard against writing over them.
    pub fn inputs(&self, guard: Guard) -> Guard {
        let guard = guard.input("--model", &self.model).input_opt("--nerf-field", self.nerf_field.as_deref());
        match &self.gt_mesh {
            Some(p) => guard.mesh("--gt-mesh", p),
            None => guard,
        }
    }

    /// The scene and the drone's worlds ([`FlightInputs::from_files`], the ground truth at
    /// the paper's 40 cells/m).
    pub fn load(&self) -> anyhow::Result<(Scene, FlightInputs)> {
        let scene = match &self.gt_mesh {
            Some(path) => load_mesh_scene(path, &self.mesh_options)?,
            None => Scene::builtin(&self.scene)?,
        };
        let inputs = FlightInputs::from_files(&self.model, self.nerf_field.as_deref(), &scene, 40.0)?;
        Ok((scene, inputs))
    }
}

#[derive(Args)]
pub struct FlyArgs {
    #[command(flatten)]
    pub drone: DroneArgs,
    /// One disturbance per step: CSV with 12 columns (dp_x..dp_z, dv_x..dv_z, dr_x..dr_z,
    /// dw_x..dw_z), a header line optional.
    #[arg(long, conflicts_with = "random_seed")]
    pub disturbances: Option<PathBuf>,
    /// Draw the disturbances from the prior (the config's `[stress.disturbance]`) with this
    /// seed (with a Monte Carlo rollout's recorded seed, its disturbances).
    #[arg(long = "disturbance-seed", alias = "random-seed")]
    pub random_seed: Option<u64>,
    /// Seed of the vision estimator's pixel choices (default: --disturbance-seed, else 0).
    #[arg(long = "pixel-seed", alias = "seed")]
    pub seed: Option<u64>,
    /// A run config (TOML): its `[sim]` table sets the flight, `[stress.disturbance]` the
    /// prior of --disturbance-seed, `[dataset]` the camera. Default: the embedded run config.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sets: Sets,
    /// Output folder: trajectory.csv, trajectory.png, view.png (what the drone's camera saw, an
    /// animated PNG), disturbances.csv, flight.json.
    #[arg(long, default_value = "fly")]
    pub out: PathBuf,
    /// Fly the same disturbances and pixel seed in the other world too (GT-sim after NeRF-sim,
    /// NeRF-sim after GT-sim) into OUT/replay/; view.png then shows both worlds side by side.
    /// With --json the object holds `flight` and `replay`.
    #[arg(long)]
    pub replay: bool,
    /// Print one JSON object with the figures.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: FlyArgs) -> anyhow::Result<()> {
    let cfg = one_model(args.config.as_deref(), &args.sets)?;
    let guard = args.drone.inputs(Guard::new().folder("--out", &args.out, OutputKind::Flight));
    let guard =
        guard.input_opt("--disturbances", args.disturbances.as_deref()).input_opt("--config", args.config.as_deref());
    guard.check()?;

    // Everything that can be refused is checked before anything is written.
    let disturbances = match (&args.disturbances, args.random_seed) {
        (Some(path), _) => read_disturbances(path, cfg.sim.steps, &cfg.disturbance_prior()?.step().std())?,
        (None, Some(seed)) => drone_disturbances(&cfg.disturbance_prior()?.to_proposal().draw(seed)),
        (None, None) => vec![nerfsv_sim::Disturbance::ZERO; cfg.sim.steps],
    };
    let (scene, inputs) = args.drone.load()?;
    // `fly_into` plans the flight before it makes the folder: a flight that cannot be planned
    // writes nothing.
    let request = FlightRequest {
        drone: cfg.drone(Some(&scene)),
        inputs: &inputs,
        kind: args.drone.world,
        estimator: args.drone.estimator,
        disturbances: &disturbances,
        seed: args.seed.or(args.random_seed).unwrap_or(0),
    };
    let claimed = guard.claim()?;
    let (figures, replayed) = fly_into(&args.out, &request, args.replay).map_err(|e| match e {
        nerfsv_study::StudyError::Sim(_) => anyhow::Error::from(e).context("planning the flight"),
        e => e.into(),
    })?;
    claimed.keep();
    match replayed {
        None => crate::commands::report(args.json, &figures, || figures.describe()),
        Some(replay) => {
            let both = serde_json::json!({ "flight": figures, "replay": replay });
            crate::commands::report(args.json, &both, || format!("{}\n{}", figures.describe(), replay.describe()))
        }
    }
}
