use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use nerfsv_dataset::{generate, GenerateOptions};
use nerfsv_scene::Scene;
use serde_json::json;

use crate::progress::bar;

#[derive(Args)]
pub struct SceneArgs {
    /// Built-in scene: stonehenge, monolith or pillars.
    #[arg(long, default_value = "stonehenge")]
    pub scene: String,
    /// Dataset folder to write (replaced if it already holds a dataset).
    #[arg(long)]
    pub out: PathBuf,
    /// Image width in pixels.
    #[arg(long, default_value_t = 100)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 100)]
    pub height: u32,
    /// Number of training views.
    #[arg(long, default_value_t = 200)]
    pub train: usize,
    /// Number of validation views.
    #[arg(long, default_value_t = 150)]
    pub val: usize,
    /// Number of test views.
    #[arg(long, default_value_t = 150)]
    pub test: usize,
    /// Horizontal field of view in radians (`camera_angle_x`).
    #[arg(long, default_value_t = 0.8)]
    pub fov: f32,
    /// Fraction of views taken low and close at drone altitude instead of from the hemisphere.
    #[arg(long, default_value_t = 0.0)]
    pub close_up: f32,
    /// Anti-aliasing: n×n samples per pixel.
    #[arg(long, default_value_t = 2)]
    pub supersample: u32,
    /// Seed of the camera placement.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print one JSON object with the figures instead of progress.
    #[arg(long)]
    pub json: bool,
}

impl SceneArgs {
    pub fn options(&self) -> GenerateOptions {
        GenerateOptions {
            width: self.width,
            height: self.height,
            train: self.train,
            val: self.val,
            test: self.test,
            camera_angle_x: self.fov,
            seed: self.seed,
            close_up_fraction: self.close_up,
            supersample: self.supersample,
            ..GenerateOptions::default()
        }
    }
}

pub fn run(args: SceneArgs) -> anyhow::Result<()> {
    let scene = Scene::builtin(&args.scene)?;
    let opts = args.options();
    let stats = write_dataset(&scene, &args.out, &opts, args.json)?;
    if args.json {
        crate::commands::print_json(&stats)?;
    } else {
        eprintln!(
            "wrote {} ({} views) in {:.1} s",
            args.out.display(),
            stats["views"],
            stats["seconds"].as_f64().unwrap_or(0.0)
        );
    }
    Ok(())
}

/// Renders the dataset with a progress bar and returns its figures.
pub fn write_dataset(
    scene: &Scene,
    out: &std::path::Path,
    opts: &GenerateOptions,
    quiet: bool,
) -> anyhow::Result<serde_json::Value> {
    let total = opts.train + opts.val + opts.test;
    let pb = bar(total as u64, "rendering", quiet);
    let start = Instant::now();
    generate(scene, out, opts, &|done, _| pb.set_position(done as u64))
        .with_context(|| format!("writing dataset {}", out.display()))?;
    pb.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    let rays = total as f64 * (opts.width * opts.height) as f64 * (opts.supersample * opts.supersample) as f64;
    Ok(json!({
        "scene": scene.name,
        "out": out,
        "views": total,
        "width": opts.width,
        "height": opts.height,
        "seconds": secs,
        "primary_rays_per_second": rays / secs,
    }))
}
