use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, ValueEnum};
use nerfsv_pipeline::refuse_output_inside;
use nerfsv_pipeline::stress::{stress, Sampler, StressSetup, JOURNAL, STRESS_JSON};
use nerfsv_scene::seed::fnv1a;
use nerfsv_sim::WorldKind;
use nerfsv_validation::Journal;

use crate::commands::fly::{load_config, DroneArgs};

#[derive(Clone, Copy, ValueEnum)]
pub enum SamplerArg {
    /// Monte Carlo: `validation.monte_carlo.rollouts` rollouts from the prior.
    Mc,
    /// Cross-Entropy Method (`validation.cem`), then importance sampling from its final proposal.
    Cem,
}

#[derive(Args)]
pub struct StressArgs {
    #[arg(long, value_enum, default_value = "cem")]
    pub sampler: SamplerArg,
    /// The drone (`--world`: where the search flies).
    #[command(flatten)]
    pub drone: DroneArgs,
    /// Fly the search's rollouts (MC's, or CEM's populations; not the importance batch) again
    /// in the other world and compare (confusion matrix, clearance differences).
    #[arg(long)]
    pub replay: bool,
    /// Run seed (default: the config's `validation.seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Continue a killed run in --out: rollouts it finished are not flown again. Refused when
    /// --out holds another configuration's results.
    #[arg(long)]
    pub resume: bool,
    /// A run config (TOML): `[sim]` (the drone), `[validation]` (prior, MC, CEM, seed),
    /// `[dataset]` (the camera). Default: the embedded run config.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder: rollouts.csv, replay_*.csv, table.csv, stress.json, the most likely
    /// failure's disturbances and trajectories, and the journal a --resume reads.
    #[arg(long, default_value = "stress")]
    pub out: PathBuf,
    /// Print one JSON object with the sampler's figures.
    #[arg(long)]
    pub json: bool,
}

/// FNV-1a of a file's bytes, for the run's key.
fn file_hash(path: &Path) -> anyhow::Result<u64> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(fnv1a(&bytes))
}

pub fn run(args: StressArgs) -> anyhow::Result<()> {
    let mut cfg = load_config(args.config.as_deref())?;
    if let Some(seed) = args.seed {
        cfg.validation.seed = seed;
    }
    let d = &args.drone;
    refuse_output_inside(&args.out, &d.inputs())?;
    let journal = args.out.join(JOURNAL).join(WorldKind::from(d.world).name());
    if args.resume && !Journal::exists(&journal) {
        anyhow::bail!("{}: --resume needs the folder of an interrupted stress run", args.out.display());
    }
    // Everything that can be refused is checked before anything is written.
    let prior = cfg.disturbance_prior()?;
    let sampler = match args.sampler {
        SamplerArg::Mc => Sampler::Mc,
        SamplerArg::Cem => Sampler::Cem,
    };
    let (scene, worlds) = d.load()?;
    let flight = worlds.plan(&cfg.sim).context("planning the flight")?;
    let setup = StressSetup {
        inputs: &worlds,
        flight: &flight,
        scene: &scene,
        sim: &cfg.sim,
        validation: &cfg.validation,
        prior: &prior,
        intrinsics: cfg.camera_intrinsics(),
        render: cfg.dataset.render_settings(),
        world: d.world.into(),
        estimator: d.estimator.into(),
        samplers: &[sampler],
        replay: args.replay,
    };
    // Everything the rollouts depend on: a --resume into results of anything else is refused.
    let key = format!(
        "{:016x}",
        fnv1a(
            serde_json::to_string(&(
                &cfg.sim,
                &cfg.validation,
                setup.intrinsics,
                setup.render.supersample,
                &d.scene,
                setup.world,
                setup.estimator,
                sampler,
                file_hash(&d.model)?,
                d.nerf_field.as_deref().map(file_hash).transpose()?,
            ))?
            .as_bytes()
        )
    );

    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let reporter = crate::progress::Reporter::new(args.json);
    let figures = stress(&setup, &args.out, &key, args.resume, &reporter)?;
    nerfsv_pipeline::stage::write_json(&args.out.join(STRESS_JSON), &figures)?;
    let one = &figures.samplers[0];
    crate::commands::report(args.json, one, || figures.describe())
}
