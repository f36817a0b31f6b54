//! `nerfsv uq field`: the uncertainty field (a voxel grid of density uncertainty over the
//! model's box, built by GA or BLA from the training images) saved like the collision grids,
//! with a PNG of its horizontal slice at flight altitude next to it
//! ([`nerfsv_uq::offline::build_field`], [`nerfsv_uq::offline::save_field_with_slice`]).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::Nerf;
use nerfsv_pipeline::{Guard, Observer};
use nerfsv_uq::offline::{build_field, has_split, save_field_with_slice, Method, FIELD_SLICE_ALTITUDE};
use nerfsv_uq::{FieldMethod, UncertaintyField};
use serde::Serialize;

use crate::progress::Reporter;

#[derive(Args)]
pub struct FieldArgs {
    /// Which method's field: ga (each training ray's σ̂² splatted by compositing weight; about
    /// 30 s on the default model), bla (the linearised Var[σ(x)] under the posterior of all
    /// training images; about 90 s) or ensemble (the variance of the members' densities at
    /// each node, `--member` the other members; seconds).
    #[arg(long, value_enum)]
    pub method: FieldMethod,
    /// Checkpoint written by `nerfsv train` (with `--method ensemble`, the deployed model).
    #[arg(long)]
    pub model: PathBuf,
    /// With `--method ensemble`: another member's checkpoint, trained on the same data with
    /// another seed (repeat; `nerfsv run` keeps them in `RUN/ensemble/member_K/`).
    #[arg(long = "member")]
    pub members: Vec<PathBuf>,
    /// Dataset or capture folder (Blender, nerfstudio, COLMAP): its train split is used (GA and BLA; the ensemble checks
    /// only that its cameras see the models).
    #[arg(long)]
    pub data: PathBuf,
    /// Output file (safetensors: tensors density, variance, weight over the model's box). A PNG
    /// of the slice at z = 0.3 m is written next to it (`<stem>_z0.30.png`).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub settings: crate::config_file::UqSettings,
    /// Print one JSON object with the field's figures.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Summary {
    method: &'static str,
    file: String,
    png: Option<String>,
    /// Grid nodes, `[nx, ny, nz]`, and spacing (m).
    voxels: usize,
    dims: [usize; 3],
    cell: f32,
    build_seconds: f64,
    checkpoint_id: String,
    checkpoint: String,
    images: usize,
    rays: usize,
    nodes_with_data: usize,
    mean_variance: f64,
    max_variance: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    rank: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    density_params: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    eigenvalue_mass_kept: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    posterior_seconds: Option<f64>,
}

pub fn run(args: FieldArgs) -> anyhow::Result<()> {
    let cfg = args.settings.load()?;
    let mut guard = Guard::new().dataset("--data", &args.data).input("--model", &args.model);
    for member in &args.members {
        guard = guard.input("--member", member);
    }
    let slice = nerfsv_uq::offline::field_slice_path(&args.out);
    guard.file("--out", &args.out).file_beside("--out's slice picture", &slice, &args.out).check()?;
    if !has_split(&args.data, "train") {
        anyhow::bail!(
            "{}: no transforms_train.json, transforms.json or COLMAP model (sparse/0): not a dataset folder",
            args.data.display()
        );
    }
    let load = |path: &PathBuf| Nerf::load(path).with_context(|| format!("loading the model {}", path.display()));
    let nerf = load(&args.model)?;
    let split = load_split(&args.data, "train", LoadOptions { downscale: 1, load_depth: false, ..Default::default() })
        .with_context(|| format!("loading the train split of {}", args.data.display()))?;
    let reporter = Reporter::new(args.json);
    let method = args.method.method();
    if method.is_some() != args.members.is_empty() {
        anyhow::bail!("--member names the other members of an ensemble: give it with --method ensemble, and only then");
    }
    let stage = format!("uq field {}", method.map_or("ensemble", Method::name));
    let mut progress =
        |done: usize, total: usize| reporter.progress(&stage, done as u64, total as u64, "training images");
    let checkpoint = args.model.display().to_string();
    let field = match method {
        Some(method) => build_field(&nerf, &checkpoint, &split, method, &cfg, &mut progress)?,
        None => {
            let others = args.members.iter().map(load).collect::<anyhow::Result<Vec<_>>>()?;
            let members: Vec<&Nerf> = std::iter::once(&nerf).chain(&others).collect();
            for (m, path) in members.iter().zip(std::iter::once(&args.model).chain(&args.members)) {
                nerfsv_nerf::check_bounds(&m.config, &split)
                    .with_context(|| format!("{}: the train split of {}", path.display(), args.data.display()))?;
            }
            UncertaintyField::build_ensemble(&members, &checkpoint, &cfg)?
        }
    };
    let png_path = save_field_with_slice(&field, &args.out)?;
    if png_path.is_none() {
        reporter.note(&stage, &format!("z = {FIELD_SLICE_ALTITUDE} m is outside the grid: no slice PNG"));
    }
    let f = &field.figures;
    let summary = Summary {
        method: field.method.name(),
        file: args.out.display().to_string(),
        png: png_path.map(|p| p.display().to_string()),
        voxels: field.geometry.len(),
        dims: field.geometry.dims,
        cell: field.geometry.cell,
        build_seconds: f.seconds,
        checkpoint_id: field.checkpoint_id.clone(),
        checkpoint,
        images: f.images,
        rays: f.rays,
        nodes_with_data: f.nodes_with_data,
        mean_variance: f.mean_variance,
        max_variance: f.max_variance,
        rank: f.rank,
        density_params: f.density_params,
        eigenvalue_mass_kept: f.eigenvalue_mass_kept,
        posterior_seconds: f.posterior_seconds,
    };
    crate::commands::report(args.json, &summary, || {
        let mut s = format!(
            "{} field: {} nodes {:?} at {} m, {} images, {} rays, {} nodes with data; variance mean {:.4e}, max {:.4e}",
            summary.method,
            summary.voxels,
            summary.dims,
            summary.cell,
            summary.images,
            summary.rays,
            summary.nodes_with_data,
            summary.mean_variance,
            summary.max_variance
        );
        if let (Some(k), Some(mass)) = (summary.rank, summary.eigenvalue_mass_kept) {
            s.push_str(&format!(
                "; rank {k} of {}, eigenvalue mass kept {mass:.4}",
                summary.density_params.unwrap_or(0)
            ));
        }
        s.push_str(&format!("; {:.1} s → {}", summary.build_seconds, summary.file));
        s
    })
}
