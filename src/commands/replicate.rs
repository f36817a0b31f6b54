use std::path::PathBuf;

use clap::Args;

use crate::progress::Reporter;

#[derive(Args)]
pub struct ReplicateArgs {
    /// TOML run config (as `nerfsv run` takes); without it, the embedded default.
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sets: crate::config_file::Sets,
    /// How many seeds: the config's, then (training) every 16th after it or (disturbances) the
    /// next ones.
    #[arg(long)]
    pub seeds: usize,
    /// Which seed the runs differ in: `training` (`train.seed`: other models, the same
    /// disturbances; folders `seed_S/`) or `disturbances` (`stress.seed`: the same models, other
    /// disturbances and calibration draws; folders `stress_seed_S/`).
    #[arg(long, value_enum, default_value_t = Vary::Training)]
    pub vary: Vary,
    /// The folder of the runs (`seed_S/` each) and of the figures side by side; default: the
    /// config's run folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run each seed's online uncertainty methods too (`[online] methods`). Without it each run
    /// skips them, as no replicated figure reads them (its online stage scores only the
    /// baselines and the ensemble's spread): about two minutes a seed on the default study.
    #[arg(long)]
    pub online: bool,
    /// Print one JSON object with the figures on stdout, and progress as JSON lines on stderr.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Vary {
    Training,
    Disturbances,
}

pub fn run(args: ReplicateArgs) -> anyhow::Result<()> {
    let out_name = crate::commands::run::out_name(args.out.is_some());
    let cfg = crate::commands::run::load_config(args.config.as_deref(), &args.sets, args.out)?;
    nerfsv_pipeline::replicate::replicate_guard(&cfg, out_name).check()?;
    let reporter = Reporter::new(args.json);
    let varied = match args.vary {
        Vary::Training => nerfsv_pipeline::replicate::Varied::Training,
        Vary::Disturbances => nerfsv_pipeline::replicate::Varied::Disturbances,
    };
    let r = nerfsv_pipeline::replicate::replicate(&cfg, args.seeds, varied, args.online, &reporter)?;
    crate::commands::report(args.json, &r, || {
        let mut s = String::new();
        for h in &r.headlines {
            let f = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.3}"));
            s.push_str(&format!("{}: {} ± {} ({} runs)\n", h.headline, f(h.mean), f(h.sd), h.n));
        }
        for p in &r.pooled {
            let t = &p.transfer;
            let f = |e: &Option<nerfsv_validation::Estimate>| {
                e.as_ref().map_or("–".to_string(), |e| format!("{:.2}", e.value))
            };
            s.push_str(&format!(
                "pooled, {} world ({} rollouts): NeRF-sim {:.3}, GT-sim {:.3}, recall {}, precision {}, McNemar p {:.3}\n",
                p.world,
                t.n,
                t.nerf.rate,
                t.gt.rate,
                f(&t.recall),
                f(&t.precision),
                t.mcnemar_p
            ));
        }
        s.push_str(&format!(
            "figures: {}, page: {}",
            cfg.run_folder().join(nerfsv_pipeline::replicate::CSV).display(),
            cfg.run_folder().join(nerfsv_pipeline::replicate::PAGE).display()
        ));
        s
    })
}
