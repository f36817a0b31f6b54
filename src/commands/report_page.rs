//! `nerfsv report RUN_DIR`: rebuilds a run folder's report (`RUN_DIR/report/index.html`) from
//! its current stage outputs, without running anything.

use std::path::PathBuf;

use clap::Args;
use nerfsv_pipeline::report::{write_report, ReportFigures};

#[derive(Args)]
pub struct ReportArgs {
    /// A run folder (`nerfsv run`'s `--out`), holding its `summary.json`.
    pub run_dir: PathBuf,
    /// Print one JSON object: `{"index", "pictures", "tables", "missing_stages"}`.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    let summary = nerfsv_pipeline::summary_path(&args.run_dir);
    anyhow::ensure!(
        summary.is_file(),
        "{}: not a run folder (no {}; `nerfsv run --out {}` makes one)",
        args.run_dir.display(),
        nerfsv_pipeline::SUMMARY,
        args.run_dir.display()
    );
    let figures: ReportFigures = write_report(&args.run_dir, None)?;
    crate::commands::report(args.json, &figures, || {
        let mut s =
            format!("report: {} ({} pictures, {} tables)", figures.index.display(), figures.pictures, figures.tables);
        if !figures.missing_stages.is_empty() {
            s.push_str(&format!("; stages not run: {}", figures.missing_stages.join(", ")));
        }
        s
    })
}
