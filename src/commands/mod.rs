pub mod collision;
pub mod completions;
pub mod config;
pub mod export;
pub mod fly;
pub mod nerf;
pub mod replicate;
pub mod report_page;
pub mod run;
pub mod scene;
pub mod stress;
pub mod uq;
pub mod uq_field;
pub mod world;

use serde::Serialize;

/// Prints a command's figures: one JSON object on stdout with `--json`, else `human` on stderr.
pub fn report(json: bool, figures: &impl Serialize, human: impl FnOnce() -> String) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string(figures)?);
    } else {
        eprintln!("{}", human());
    }
    Ok(())
}
