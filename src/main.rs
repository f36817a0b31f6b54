//! `nerfsv`: uncertainty-aware safety validation of a vision-based quadcopter in a NeRF world.
//!
//! The binary only parses arguments, reads configuration and calls the stage crates.

mod commands;
mod config_file;
mod progress;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Safety validation of a vision-based quadcopter flying through a Neural Radiance Field.
///
/// Start with `nerfsv run`: on the default Stonehenge scene it renders the dataset, builds the
/// ground-truth collision field, trains and evaluates the NeRF, measures its uncertainty image
/// by image (GA, BLA, depth AUSE), builds the NeRF's collision field, flies the drone along its
/// planned path in NeRF-sim and GT-sim, trains an ensemble of three more NeRFs and calibrates
/// NeRF-sim against views the NeRF never saw, stress-tests the drone (Monte Carlo, the
/// Cross-Entropy Method and subset simulation in NeRF-sim's calibrated world, replayed in
/// GT-sim), and repeats the search measuring every step's uncertainty and ranking by the paper's
/// rewards, into `runs/stonehenge/` (figures in `summary.json`, an HTML report). The other
/// subcommands run one stage each, for your own datasets and checkpoints.
#[derive(Parser)]
#[command(name = "nerfsv", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Most memory (GiB) one grid, network or batch may need; larger settings are refused
    /// before anything is allocated. Default: NERFSV_MEMORY_BUDGET_GIB, else half the RAM.
    #[arg(long, global = true, value_name = "GIB")]
    memory_budget_gib: Option<f64>,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole pipeline into a run folder (default config: the embedded Stonehenge scene).
    Run(commands::run::RunArgs),
    /// Run the study with several training seeds (dataset, ground truth and disturbances shared)
    /// or disturbance seeds (models shared) and write each headline's mean ± standard deviation
    /// beside every seed's value, and NeRF-sim's comparison with GT-sim over all runs' rollouts.
    Replicate(commands::replicate::ReplicateArgs),
    /// Print the default run config as TOML, every key with its documentation
    /// (`nerfsv config --default > my.toml`, then `nerfsv run my.toml`).
    Config(commands::config::ConfigArgs),
    /// Rebuild a run folder's HTML report (`RUN_DIR/report/index.html`) from its stage outputs.
    Report(commands::report_page::ReportArgs),
    /// Render a built-in ground-truth scene (or a mesh, --mesh) into a Blender-format dataset.
    Scene(commands::scene::SceneArgs),
    /// Train a NeRF on a dataset: Blender, nerfstudio / instant-ngp or COLMAP (checkpoints in
    /// safetensors; --resume continues).
    Train(commands::nerf::TrainArgs),
    /// Report PSNR, SSIM and depth error of a NeRF on a dataset split.
    Eval(commands::nerf::EvalArgs),
    /// Render with a NeRF: a split's cameras, or frames and an animation along a flight's
    /// trajectory CSV or a nerfstudio camera path (--path).
    Render(commands::nerf::RenderArgs),
    /// Build a signed collision field (SDF grid at 40 cells/m) and its surface mesh.
    Collision(commands::collision::CollisionArgs),
    /// Fly the drone once along the planned path in NeRF-sim or GT-sim (trajectory CSV + plot).
    Fly(commands::fly::FlyArgs),
    /// Search for the disturbances that crash the drone (Monte Carlo, the Cross-Entropy Method or
    /// subset simulation), estimate the failure probability, and replay the rollouts in the other
    /// world.
    Stress(commands::stress::StressArgs),
    /// Write a run folder's ground-truth and NeRF meshes, planned route and failures (each
    /// sampler's most likely failure, true and estimated tracks, and the failing rollouts) as one
    /// binary glTF 2.0 file (.glb), metres, y up; Blender (File > Import > glTF 2.0) or any glTF
    /// viewer opens it.
    Export(commands::export::ExportArgs),
    /// Uncertainty of a trained NeRF: `uq offline` runs GA or BLA on every image of a dataset
    /// (CSV and figures), `uq ause` scores them against ground-truth depth, `uq field` builds the
    /// uncertainty field.
    Uq(commands::uq::UqArgs),
    /// Print the completion script of a shell (bash, zsh, fish, elvish, powershell) for every
    /// subcommand and flag: `nerfsv completions bash > ~/.local/share/bash-completion/completions/nerfsv`.
    Completions(commands::completions::CompletionsArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Environment variables are checked like flags: a bad value is refused, never ignored.
    if let Err(e) = nerfsv_scene::MemoryBudget::from_env() {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    if let Some(gib) = cli.memory_budget_gib {
        if let Err(e) = nerfsv_scene::validate::positive("--memory-budget-gib", gib) {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
        nerfsv_scene::MemoryBudget::set((gib * (1u64 << 30) as f64) as u64);
    }
    // The NeRF's kernel width: NERFSV_KERNELS=portable|avx2|avx512|native (the widest, as when
    // unset); every width gives the same bits, so this only changes the speed.
    if let Err(e) = nerfsv_nerf::kernels::Kernels::from_env().and_then(nerfsv_nerf::kernels::set_active) {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    let result = match cli.command {
        Command::Run(a) => commands::run::run(a),
        Command::Replicate(a) => commands::replicate::run(a),
        Command::Config(a) => commands::config::run(a),
        Command::Report(a) => commands::report_page::run(a),
        Command::Scene(a) => commands::scene::run(a),
        Command::Collision(a) => commands::collision::run(a),
        Command::Fly(a) => commands::fly::run(a),
        Command::Stress(a) => commands::stress::run(a),
        Command::Export(a) => commands::export::run(a),
        Command::Uq(a) => commands::uq::run(a),
        Command::Train(a) => commands::nerf::run_train(a),
        Command::Eval(a) => commands::nerf::run_eval(a),
        Command::Render(a) => commands::nerf::run_render(a),
        Command::Completions(a) => commands::completions::run::<Cli>(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
