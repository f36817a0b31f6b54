use std::path::PathBuf;

use clap::Args;
use nerfsv_pipeline::stress::search_key;
use nerfsv_pipeline::{Guard, OutputKind};
use nerfsv_study::flight::Mission;
use nerfsv_study::stress::{journal_dir, search_into, OnlineSettings, Sampler, StressSetup};
use nerfsv_study::UqMode;
use nerfsv_uq::{Method, UncertaintyField};
use nerfsv_validation::Journal;

use crate::commands::fly::DroneArgs;
use crate::config_file::{one_model, Sets};

#[derive(Args)]
pub struct StressArgs {
    /// How the disturbances are drawn: Monte Carlo from the prior, the Cross-Entropy Method
    /// (the paper's failure search), or subset simulation (a calibrated failure probability).
    #[arg(long, value_enum, default_value = "cem")]
    pub sampler: Sampler,
    /// The drone (`--world`: where the search flies).
    #[command(flatten)]
    pub drone: DroneArgs,
    /// Fly the search's rollouts (MC's, or CEM's populations; not the importance batch) again
    /// in the other world and compare (confusion matrix, clearance differences).
    #[arg(long)]
    pub replay: bool,
    /// Rank CEM's samples by this method's reward (eq. 10 `log p − penalty·σ_d` for GA, eq. 11
    /// `log p − penalty·rmv·trace·n` for BLA; `[uq] reward_penalty`, `perturbations`), measuring
    /// its uncertainty at every step. Monte Carlo never ranks: it records the reward.
    #[arg(long, value_enum, conflicts_with = "measure")]
    pub reward: Option<Method>,
    /// Measure this method's uncertainty at every step without ranking by it (the rows "without
    /// reward" of Tables 1–2).
    #[arg(long, value_enum)]
    pub measure: Option<Method>,
    /// How the per-step uncertainty is measured (with --reward or --measure): `exact` fits the
    /// view's `[uq] online_rays` pixels (BLA: `online_bla_rays` of them); `field` looks them up
    /// in --field.
    #[arg(long, value_enum, default_value = "exact")]
    pub uncertainty: UqMode,
    /// The uncertainty field of --model built by the same method (`nerfsv uq field`), for
    /// `--uncertainty field`.
    #[arg(long)]
    pub field: Option<PathBuf>,
    /// Run seed (default: the config's `stress.seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Continue a killed run in --out: rollouts it finished are not flown again. Refused when
    /// --out holds another configuration's results.
    #[arg(long)]
    pub resume: bool,
    /// A run config (TOML): `[sim]` (the drone), `[stress]` (prior, MC, CEM, seed),
    /// `[dataset]` (the camera). Default: the embedded run config.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sets: Sets,
    /// Output folder: rollouts.csv, replay_*.csv, table.csv, stress.json, the most likely
    /// failure's disturbances and trajectories, and the journal a --resume reads.
    #[arg(long, default_value = "stress")]
    pub out: PathBuf,
    /// Print one JSON object with the sampler's figures.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: StressArgs) -> anyhow::Result<()> {
    let mut cfg = one_model(args.config.as_deref(), &args.sets)?;
    if let Some(seed) = args.seed {
        cfg.stress.seed = seed;
    }
    let d = &args.drone;
    let guard = d.inputs(Guard::new().folder("--out", &args.out, OutputKind::Stress));
    let guard = guard.input_opt("--field", args.field.as_deref()).input_opt("--config", args.config.as_deref());
    guard.check()?;
    let online = args
        .reward
        .map(|m| (m, true))
        .or(args.measure.map(|m| (m, false)))
        .map(|(m, reward)| OnlineSettings { method: m, mode: args.uncertainty, reward });
    match (online.map(|o| o.mode), &args.field) {
        (Some(UqMode::Field), None) => anyhow::bail!("--uncertainty field needs --field FILE (`nerfsv uq field`)"),
        (None, Some(_)) => anyhow::bail!("--field is read only with --reward or --measure and --uncertainty field"),
        (Some(UqMode::Exact), Some(_)) => anyhow::bail!("--field is read only with --uncertainty field"),
        _ => {}
    }
    if args.resume && !Journal::exists(&journal_dir(&args.out, d.world)) {
        anyhow::bail!("{}: --resume needs the folder of an interrupted stress run", args.out.display());
    }
    let (scene, worlds) = d.load()?;
    let field = args.field.as_deref().map(|p| UncertaintyField::load(p).map(|f| (p, f))).transpose()?;
    let reporter = crate::progress::Reporter::new(args.json);
    let drone = cfg.drone(Some(&scene));
    let flight = worlds.plan(drone.sim)?;
    let prior = cfg.disturbance_prior()?;
    let samplers = [args.sampler];
    let setup = StressSetup {
        world: d.world,
        estimator: d.estimator,
        replay: args.replay,
        online,
        field: field.as_ref().map(|(p, f)| (*p, f)),
        ..cfg.search(Mission { drone, inputs: &worlds, flight: &flight }, &prior, &samplers)
    };
    let key = search_key(&setup, &d.model, d.nerf_field.as_deref())?;
    let claimed = guard.claim()?;
    let figures = search_into(&setup, &args.out, args.resume, &key, &reporter)?;
    claimed.keep();
    let one = &figures.samplers[0];
    crate::commands::report(args.json, one, || figures.describe())
}
