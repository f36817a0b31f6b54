use std::path::PathBuf;

use clap::Args;

use crate::progress::Reporter;

#[derive(Args)]
pub struct ReplicateArgs {
    /// TOML run config (as `nerfsv run` takes); without it, the embedded default.
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sets: crate::config_file::Sets,
    /// How many training seeds: the config's `train.seed`, then every 16th after it.
    #[arg(long)]
    pub seeds: usize,
    /// The folder of the runs (`seed_S/` each) and of the figures side by side; default: the
    /// config's run folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print one JSON object with the figures on stdout, and progress as JSON lines on stderr.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: ReplicateArgs) -> anyhow::Result<()> {
    let out_name = crate::commands::run::out_name(args.out.is_some());
    let cfg = crate::commands::run::load_config(args.config.as_deref(), &args.sets, args.out)?;
    nerfsv_pipeline::replicate::replicate_guard(&cfg, out_name).check()?;
    let reporter = Reporter::new(args.json);
    let r = nerfsv_pipeline::replicate::replicate(&cfg, args.seeds, &reporter)?;
    crate::commands::report(args.json, &r, || {
        let mut s = String::new();
        for h in &r.headlines {
            let f = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.3}"));
            s.push_str(&format!("{}: {} ± {} ({} runs)\n", h.headline, f(h.mean), f(h.sd), h.n));
        }
        s.push_str(&format!(
            "figures: {}, page: {}",
            cfg.run_folder().join(nerfsv_pipeline::replicate::CSV).display(),
            cfg.run_folder().join(nerfsv_pipeline::replicate::PAGE).display()
        ));
        s
    })
}
