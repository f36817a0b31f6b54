//! `nerfsv uq field`: the uncertainty field (a voxel grid of density uncertainty over the
//! model's box, built by GA or BLA from the training images) saved like the collision grids,
//! with a PNG of its horizontal slice at flight altitude next to it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::Nerf;
use nerfsv_pipeline::uq::{has_split, reference, Method, BACKGROUND};
use nerfsv_pipeline::{refuse_output_inside, Observer};
use nerfsv_uq::{TrainingView, UncertaintyField};
use serde::Serialize;

use crate::commands::uq::{load_uq_config, MethodArg};
use crate::progress::Reporter;

/// Altitude of the PNG slice, metres (the drone flies at 0.15–0.5 m).
pub const SLICE_ALTITUDE: f32 = 0.3;
/// The slice figure's size, pixels.
const SLICE_SIZE: (u32, u32) = (640, 520);

#[derive(Args)]
pub struct FieldArgs {
    /// Which method's field: ga (each training ray's σ̂² splatted by compositing weight; about
    /// 30 s on the default model) or bla (the linearised Var[σ(x)] under the posterior of all
    /// training images; about 90 s).
    #[arg(long, value_enum)]
    pub method: MethodArg,
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Blender-format dataset folder: its train split is used.
    #[arg(long)]
    pub data: PathBuf,
    /// Output file (safetensors: tensors density, variance, weight over the model's box). A PNG
    /// of the slice at z = 0.3 m is written next to it (`<stem>_z0.30.png`).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML file of uq settings, top-level keys (field_cells_per_metre, field_rays_per_image,
    /// field_rank, prior_precision, noise_std, …; see nerfsv_uq::UqConfig).
    #[arg(long)]
    pub config: Option<PathBuf>,
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

/// `<stem>_z0.30.png` next to `out`.
fn slice_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "field".into());
    out.with_file_name(format!("{stem}_z{SLICE_ALTITUDE:.2}.png"))
}

/// The slice at [`SLICE_ALTITUDE`] as a PNG: `√v` per node (GA σ_d, BLA relative density
/// standard deviation: the units [`UncertaintyField::view_uncertainty`] reports) on a log colour
/// scale, clipped to its 2nd–98th percentile (a few rays that composite little give GA nodes
/// huge values), metre axes, grey where there is no data. `None` when the altitude is outside
/// the grid.
fn slice_png(field: &UncertaintyField) -> anyhow::Result<Option<Vec<u8>>> {
    let g = &field.geometry;
    let [nx, ny, _] = g.dims;
    if g.bounds().min.z > SLICE_ALTITUDE || g.bounds().max.z < SLICE_ALTITUDE {
        return Ok(None);
    }
    let values: Vec<f64> = (0..nx * ny)
        .map(|n| {
            let p = g.position_of(n % nx, n / nx, 0);
            field.value_at([p.x, p.y, SLICE_ALTITUDE]).map_or(f64::NAN, |v| f64::from(v.max(0.0)).sqrt())
        })
        .collect();
    let mut positive: Vec<f64> = values.iter().copied().filter(|v| v.is_finite() && *v > 0.0).collect();
    positive.sort_by(f64::total_cmp);
    let values = match (
        positive.get(positive.len() * 2 / 100),
        positive.get((positive.len() * 98 / 100).min(positive.len().saturating_sub(1))),
    ) {
        (Some(&lo), Some(&hi)) => values.iter().map(|&v| if v > 0.0 { v.clamp(lo, hi) } else { v }).collect(),
        _ => values,
    };
    let method = field.method.name().to_uppercase();
    let quantity = match field.method {
        Method::Ga => "σ_d (relative density std)",
        Method::Bla => "relative density std √Var[σ]/σ",
    };
    let fig = nerfsv_plot::HeatmapFigure {
        title: format!("{method} uncertainty field at z = {SLICE_ALTITUDE:.2} m"),
        panels: vec![nerfsv_plot::Heatmap {
            caption: format!("{quantity}, 2nd–98th percentile"),
            x_title: "x (m)".into(),
            y_title: "y (m)".into(),
            colour_title: format!("{quantity} (log scale)"),
            origin: [f64::from(g.origin.x), f64::from(g.origin.y)],
            cell: [f64::from(g.cell); 2],
            dims: [nx, ny],
            values,
            scale: nerfsv_plot::ColourScale::Log,
        }],
    };
    Ok(Some(nerfsv_plot::heatmap_png(&fig, SLICE_SIZE.0, SLICE_SIZE.1)?))
}

pub fn run(args: FieldArgs) -> anyhow::Result<()> {
    let cfg = load_uq_config(args.config.as_deref())?;
    refuse_output_inside(&args.out, &[("--data", &args.data), ("--model", &args.model)])?;
    if !has_split(&args.data, "train") {
        anyhow::bail!(
            "{}: no transforms_train.json (or transforms.json): not a Blender-format dataset",
            args.data.display()
        );
    }
    let nerf = Nerf::load(&args.model).with_context(|| format!("loading the model {}", args.model.display()))?;
    let split = load_split(&args.data, "train", LoadOptions { downscale: 1, load_depth: false })
        .with_context(|| format!("loading the train split of {}", args.data.display()))?;
    nerfsv_nerf::check_bounds(&nerf.config, &split)?;
    let names: Vec<String> = split
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| format!("{}: frame {i} ({})", split.path.display(), f.file_path))
        .collect();
    let refs: Vec<Vec<[f32; 3]>> = split.frames.iter().map(reference).collect();
    let views: Vec<TrainingView> = split
        .frames
        .iter()
        .zip(&refs)
        .zip(&names)
        .map(|((f, r), n)| TrainingView { name: n, camera: &f.camera, reference: r })
        .collect();
    let reporter = Reporter::new(args.json);
    let stage = format!("uq field {}", Method::from(args.method).name());
    let mut progress =
        |done: usize, total: usize| reporter.progress(&stage, done as u64, total as u64, "training images");
    let checkpoint = args.model.display().to_string();
    let field = match args.method {
        MethodArg::Ga => UncertaintyField::build_ga(&nerf, &checkpoint, &views, BACKGROUND, &cfg, &mut progress)?,
        MethodArg::Bla => UncertaintyField::build_bla(&nerf, &checkpoint, &views, BACKGROUND, &cfg, &mut progress)?,
    };
    debug_assert_eq!(field.method, Method::from(args.method));
    // Both files are made before either is written.
    let png = slice_png(&field)?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    field.save(&args.out)?;
    let png_path = slice_path(&args.out);
    if let Some(bytes) = &png {
        if let Err(e) = nerfsv_scene::io::atomic_write_bytes(&png_path, bytes) {
            let _ = std::fs::remove_file(&args.out);
            return Err(anyhow::Error::new(e).context(format!("writing {}", png_path.display())));
        }
    } else {
        reporter.note(&stage, &format!("z = {SLICE_ALTITUDE} m is outside the grid: no slice PNG"));
    }
    let f = &field.figures;
    let summary = Summary {
        method: Method::from(args.method).name(),
        file: args.out.display().to_string(),
        png: png.as_ref().map(|_| png_path.display().to_string()),
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
