//! `nerfsv`: uncertainty-aware safety validation of a vision-based quadcopter in a NeRF world.
//!
//! The binary only parses arguments, reads configuration and calls the stage crates.

mod cache;
mod commands;
mod config;
mod progress;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Safety validation of a vision-based quadcopter flying through a Neural Radiance Field.
///
/// Start with `nerfsv run`: it builds the default Stonehenge scene, renders its dataset and
/// computes the ground-truth collision field into `runs/stonehenge/`. The other subcommands run
/// one stage each, for your own datasets and checkpoints.
#[derive(Parser)]
#[command(name = "nerfsv", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole pipeline into a run folder (default config: the embedded Stonehenge scene).
    Run(commands::run::RunArgs),
    /// Render a built-in ground-truth scene into a Blender-format dataset.
    Scene(commands::scene::SceneArgs),
    /// Build a signed collision field (SDF grid at 40 cells/m) and its surface mesh.
    Collision(commands::collision::CollisionArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run(a) => commands::run::run(a),
        Command::Scene(a) => commands::scene::run(a),
        Command::Collision(a) => commands::collision::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
