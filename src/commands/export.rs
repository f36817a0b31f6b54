//! `nerfsv export RUN_DIR --out FILE.glb`: a run folder's ground-truth and NeRF meshes, planned
//! route and failures as one binary glTF 2.0 file ([`nerfsv_pipeline::export`]).

use std::path::PathBuf;

use clap::Args;
use nerfsv_pipeline::export::{failures_scene, ExportOptions};
use nerfsv_pipeline::Guard;

#[derive(Args)]
pub struct ExportArgs {
    /// A run folder (`nerfsv run`'s `--out`), holding its `summary.json`.
    pub run_dir: PathBuf,
    /// Output file, binary glTF 2.0 (`.glb`): a file nerfsv wrote is replaced, any other refused.
    #[arg(long)]
    pub out: PathBuf,
    /// Most failing rollouts exported besides each sampler's most likely failure, taken in turn
    /// from each sampler and world.
    #[arg(long, default_value_t = 50)]
    pub max_tracks: usize,
    /// Print one JSON object with what the file holds.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    Guard::new().input("RUN_DIR", &args.run_dir).file("--out", &args.out).check()?;
    let (scene, figures) = failures_scene(&args.run_dir, ExportOptions { max_tracks: args.max_tracks })?;
    let bytes = nerfsv_plot::glb::glb_bytes(&scene)?;
    nerfsv_scene::io::atomic_write_bytes(&args.out, &bytes)
        .map_err(|e| anyhow::anyhow!("{}: cannot be written: {e}", args.out.display()))?;
    crate::commands::report(args.json, &figures, || {
        let meshes: Vec<String> = figures.meshes.iter().map(|(m, t)| format!("{m} ({t} triangles)")).collect();
        let mut s = format!(
            "export: {} ({} bytes, {} nodes): {}; route of {} points; {} most likely failure flights \
             (true and estimated tracks); {} of {} failing rollouts (true tracks)",
            args.out.display(),
            bytes.len(),
            figures.nodes,
            if meshes.is_empty() { "no meshes".to_owned() } else { meshes.join(", ") },
            figures.route_points,
            figures.most_likely_failure_flights,
            figures.failing_rollouts_exported,
            figures.failing_rollouts,
        );
        for note in &figures.notes {
            s.push_str(&format!("\n  note: {note}"));
        }
        s
    })
}
