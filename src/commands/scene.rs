use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nerfsv_dataset::GenerateOptions;
use nerfsv_pipeline::Observer;

use crate::commands::world::WorldArgs;
use crate::progress::Reporter;

#[derive(Args)]
pub struct SceneArgs {
    /// The world to render: a built-in scene or a mesh file.
    #[command(flatten)]
    pub world: WorldArgs,
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
    /// Print one JSON object with the figures on stdout, and progress as JSON lines on stderr.
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

/// The flag a user typed for each generation option the command sets.
const FLAGS: [(&str, &str); 8] = [
    ("width", "--width"),
    ("height", "--height"),
    ("train", "--train"),
    ("val", "--val"),
    ("test", "--test"),
    ("camera_angle_x", "--fov"),
    ("close_up_fraction", "--close-up"),
    ("supersample", "--supersample"),
];

pub fn run(args: SceneArgs) -> anyhow::Result<()> {
    // Before anything is read or written, each bad value named by its flag.
    args.options().validate().map_err(|mut e| {
        if let Some((_, flag)) = FLAGS.iter().find(|(field, _)| *field == e.field) {
            e.field = flag.to_string();
        }
        e
    })?;
    // The mesh's textures sit beside it: they are inputs too. The dataset's folder is replaced
    // whole, so it must be nerfsv's dataset (or absent, or empty).
    let mut guard = nerfsv_pipeline::Guard::new().folder("--out", &args.out, nerfsv_pipeline::OutputKind::Dataset);
    if let Some(mesh) = &args.world.mesh {
        guard = guard.mesh("--mesh", mesh);
    }
    guard.check()?;
    let scene = args.world.load()?;
    let reporter = Reporter::new(args.json);
    let figures = nerfsv_dataset::render(&scene, &args.out, &args.options(), &|done, total| {
        reporter.progress("scene", done as u64, total as u64, "views rendered")
    })
    .with_context(|| format!("writing dataset {}", args.out.display()))?;
    crate::commands::report(args.json, &figures, || {
        format!("wrote {} ({} views) in {:.1} s", args.out.display(), figures.views, figures.seconds)
    })
}
