//! The stages of `nerfsv run`, each a thin [`Stage`] around its library function.

mod report;

use std::path::{Path, PathBuf};
use std::time::Instant;

use nerfsv_collision::{DensityFieldFigures, GroundTruthFigures, SdfGrid};
use nerfsv_dataset::{load_split, GenerateOptions, LoadOptions, Placement, Split};
use nerfsv_nerf::{Budget, EvalOptions, Nerf, TrainStats};
use nerfsv_scene::Scene;
use serde::{Deserialize, Serialize};

use crate::config::NerfSettings;
use crate::stage::{write_json, Stage, StageContext};
use crate::PipelineError;

/// Loads a split of a dataset folder, naming the folder in the error. `dir` is a dataset
/// folder ([`nerfsv_dataset::load_split`]'s formats) or a run's dataset stage folder
/// ([`Dataset::folder`]): the dataset rendered there, or the user's folder its `source.json`
/// names, with that dataset's poses placed in the world as the run's `[world]` table placed them.
pub fn load_dataset_split(dir: &Path, split: &str, downscale: u32) -> Result<Split, PipelineError> {
    let source = dir.join(Dataset::SOURCE);
    let (folder, placement) = match nerfsv_dataset::dataset_format(dir).is_none() && source.is_file() {
        true => {
            let f = DatasetFolder::read(&source)?;
            (f.folder, f.placement)
        }
        false => (dir.to_path_buf(), Placement::default()),
    };
    let mut s =
        load_split(&folder, split, LoadOptions { downscale, load_depth: true, ..Default::default() }).map_err(|e| {
            PipelineError::Dataset { context: format!("loading the {split} split of {}", folder.display()), error: e }
        })?;
    placement.place(&mut s);
    Ok(s)
}

// ---------------------------------------------------------------------------------------------
// 1. The dataset.

/// The dataset the NeRF learns from: the scene's Blender-format dataset rendered into
/// `RUN/dataset/`, or a user's folder used as is (`RUN/dataset/source.json` names it and where
/// its poses lie in the world).
pub struct Dataset<'a> {
    pub source: DatasetSource<'a>,
}

/// Where the dataset comes from.
pub enum DatasetSource<'a> {
    /// Rendered from a scene.
    Render { scene: &'a Scene, options: &'a GenerateOptions },
    /// A dataset folder (any format [`nerfsv_dataset::load_split`] reads), read where it is,
    /// its poses placed in the world by `placement`.
    Folder { folder: &'a Path, placement: Placement },
}

/// `RUN/dataset/source.json`: the folder a run's dataset is read from, and where its poses lie
/// in the world (absent: as they are).
#[derive(Serialize, Deserialize)]
struct DatasetFolder {
    folder: PathBuf,
    #[serde(default, skip_serializing_if = "Placement::is_identity")]
    placement: Placement,
}

impl DatasetFolder {
    fn read(source: &Path) -> Result<Self, PipelineError> {
        let text = std::fs::read_to_string(source).map_err(|e| PipelineError::io(source, e))?;
        serde_json::from_str(&text).map_err(|e| PipelineError::Internal(format!("{}: {e}", source.display())))
    }
}

/// What the dataset stage reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetFigures {
    pub scene: String,
    pub views: usize,
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
    pub primary_rays_per_second: f64,
}

/// Renders `scene` into the dataset folder `out`, reporting progress per view.
pub fn render_dataset(
    scene: &Scene,
    out: &Path,
    opts: &GenerateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<DatasetFigures, PipelineError> {
    let start = Instant::now();
    nerfsv_dataset::generate(scene, out, opts, progress)
        .map_err(|e| PipelineError::Dataset { context: format!("writing dataset {}", out.display()), error: e })?;
    let seconds = start.elapsed().as_secs_f64();
    let views = opts.train + opts.val + opts.test;
    let rays = views as f64 * (opts.width * opts.height) as f64 * (opts.supersample * opts.supersample) as f64;
    Ok(DatasetFigures {
        scene: scene.name.clone(),
        views,
        width: opts.width,
        height: opts.height,
        seconds,
        primary_rays_per_second: rays / seconds.max(1e-9),
    })
}

impl Dataset<'_> {
    /// The file naming a user's dataset folder.
    pub const SOURCE: &'static str = "source.json";

    /// The folder [`load_dataset_split`] reads run `root`'s dataset from: `RUN/dataset/`, which
    /// holds the rendered dataset or names the user's folder and its placement.
    pub fn folder(root: &Path) -> Result<PathBuf, PipelineError> {
        let dir = root.join(Dataset::NAME);
        let source = dir.join(Self::SOURCE);
        if source.exists() {
            // A broken record fails here, before a stage opens it.
            DatasetFolder::read(&source)?;
        }
        Ok(dir)
    }
}

/// The digest of the files the loader reads from the dataset folder `folder`
/// ([`nerfsv_dataset::dataset_files`]: transforms files or COLMAP model files and the images
/// and depth images they name), by name relative to it and bytes, in sorted name order. A file
/// that cannot be read digests as its error's kind: the stage then fails naming it.
pub fn dataset_digest(folder: &Path) -> u64 {
    let mut rels: Vec<String> = nerfsv_dataset::dataset_files(folder)
        .iter()
        .map(|f| {
            let rel = f.strip_prefix(folder).unwrap_or(f);
            rel.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/")
        })
        .collect();
    rels.sort();
    rels.dedup();
    let read = |p: &Path| Ok(std::fs::read(p).unwrap_or_else(|e| format!("unreadable: {:?}", e.kind()).into_bytes()));
    crate::digest::files_digest(folder, &rels, read).unwrap_or(0)
}

impl Stage for Dataset<'_> {
    const NAME: &'static str = "dataset";
    const CODE: &'static [&'static str] = &["nerfsv-dataset", "stages.rs"];
    const OUTPUTS: &'static [&'static str] = &["transforms_train.json", "transforms_val.json", "transforms_test.json"];

    fn outputs(&self) -> &'static [&'static str] {
        match self.source {
            DatasetSource::Render { .. } => Self::OUTPUTS,
            DatasetSource::Folder { .. } => &[Self::SOURCE],
        }
    }
    type Figures = DatasetFigures;

    fn config(&self) -> impl Serialize {
        match &self.source {
            DatasetSource::Render { scene, options } => serde_json::json!([scene.key(), options]),
            // The files the loader reads: a changed image is another dataset, while what else
            // the folder holds (COLMAP's database.db, dense/, …) is not read and not hashed. An
            // identity placement keys as none.
            DatasetSource::Folder { folder, placement } => {
                let digest = dataset_digest(folder);
                let mut key = serde_json::json!({"folder": folder, "digest": format!("{digest:016x}")});
                if !placement.is_identity() {
                    key["placement"] = serde_json::json!(placement);
                }
                key
            }
        }
    }

    fn run(&self, cx: &StageContext) -> Result<DatasetFigures, PipelineError> {
        match &self.source {
            // The generator builds the dataset beside the (empty) stage folder and renames it over.
            DatasetSource::Render { scene, options } => render_dataset(scene, &cx.dir, options, &|done, total| {
                cx.progress(done as u64, total as u64, "views rendered")
            }),
            DatasetSource::Folder { folder, placement } => {
                // Every split is read now, so a broken dataset stops the run before training.
                let start = Instant::now();
                let mut views = 0;
                let mut size = (0, 0);
                for (i, split) in ["train", "val", "test"].into_iter().enumerate() {
                    let s = load_dataset_split(folder, split, 1)?;
                    views += s.frames.len();
                    if let Some(f) = s.frames.first() {
                        size = (f.image.width, f.image.height);
                    }
                    cx.progress(i as u64 + 1, 3, "splits read");
                }
                let absolute = std::path::absolute(folder).map_err(|e| PipelineError::io(*folder, e))?;
                write_json(&cx.dir.join(Self::SOURCE), &DatasetFolder { folder: absolute, placement: *placement })?;
                Ok(DatasetFigures {
                    scene: folder.display().to_string(),
                    views,
                    width: size.0,
                    height: size.1,
                    seconds: start.elapsed().as_secs_f64(),
                    primary_rays_per_second: 0.0,
                })
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 2. The ground-truth collision field.

/// The scene's signed collision field and surface: `RUN/collision/gt_sdf.safetensors`,
/// `gt_mesh.ply`.
pub struct GroundTruthField<'a> {
    pub scene: &'a Scene,
    pub cells_per_metre: f32,
}

impl GroundTruthField<'_> {
    pub const SDF: &'static str = "gt_sdf.safetensors";
    pub const MESH: &'static str = "gt_mesh.ply";

    /// The ground-truth signed field of run `root`.
    pub fn sdf_path(root: &Path) -> PathBuf {
        root.join(Self::NAME).join(Self::SDF)
    }
}

impl Stage for GroundTruthField<'_> {
    const NAME: &'static str = "collision";
    const CODE: &'static [&'static str] = &["nerfsv-collision", "stages.rs"];
    const OUTPUTS: &'static [&'static str] = &[Self::SDF, Self::MESH];
    type Figures = GroundTruthFigures;

    fn config(&self) -> impl Serialize {
        (self.scene.key(), self.cells_per_metre)
    }

    fn run(&self, cx: &StageContext) -> Result<GroundTruthFigures, PipelineError> {
        let (sdf, mesh) = (cx.dir.join(Self::SDF), cx.dir.join(Self::MESH));
        Ok(nerfsv_collision::build_ground_truth(self.scene, self.cells_per_metre, &sdf, Some(&mesh))?)
    }
}

// ---------------------------------------------------------------------------------------------
// 3. The NeRF.

/// Trains the NeRF on the dataset's train split to a step count: `RUN/nerf/checkpoint.safetensors`.
/// Resumable: a killed run continues from its last checkpoint and ends at the same weights.
pub struct Train<'a> {
    pub settings: &'a NerfSettings,
    pub steps: u64,
}

impl Train<'_> {
    pub const CHECKPOINT: &'static str = "checkpoint.safetensors";

    /// The trained model's checkpoint in run `root`.
    pub fn checkpoint(root: &Path) -> PathBuf {
        root.join(Self::NAME).join(Self::CHECKPOINT)
    }
}

/// The status line of a training step, as the progress bars show it.
pub fn train_status(p: &nerfsv_nerf::Progress) -> String {
    format!(
        "step {:>5} loss {:.5} psnr {:5.2} dB {:>6.0} rays/s {:>4.1} spr{}",
        p.step,
        p.loss,
        p.psnr,
        p.rays_per_s,
        p.samples_per_ray,
        if p.checkpointed { " [saved]" } else { "" }
    )
}

impl Stage for Train<'_> {
    const NAME: &'static str = "nerf";
    const CODE: &'static [&'static str] = &["nerfsv-nerf", "stages.rs", "config.rs"];
    const OUTPUTS: &'static [&'static str] = &[Self::CHECKPOINT];
    const RESUMABLE: bool = true;
    const INPUTS: &'static [&'static str] = &[Dataset::NAME];
    type Figures = TrainStats;

    fn config(&self) -> impl Serialize {
        (self.settings, self.steps)
    }

    fn run(&self, cx: &StageContext) -> Result<TrainStats, PipelineError> {
        let data = load_dataset_split(&Dataset::folder(cx.root)?, "train", 1)?;
        let steps = self.steps;
        let mut report = |p: &nerfsv_nerf::Progress| cx.progress(p.step, steps, &train_status(p));
        let (nerf, train) = (self.settings.nerf.clone(), self.settings.train.clone());
        let (_, stats) = nerfsv_nerf::train(&data, &cx.dir, Budget::Steps(steps), cx.resume, nerf, train, &mut report)?;
        Ok(stats)
    }
}

// ---------------------------------------------------------------------------------------------
// 4. Evaluation.

/// Evaluates the NeRF on the test split: `RUN/eval/metrics.json` (overall and per image) and
/// `compare.png` (ground truth | NeRF for the first four test views).
pub struct Eval;

/// What an evaluation reports (the per-image figures are in `metrics.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalFigures {
    pub psnr: f64,
    pub ssim: f64,
    pub depth_median_abs_err_m: Option<f64>,
    pub images: usize,
    pub background: [f32; 3],
}

impl From<&nerfsv_nerf::EvalReport> for EvalFigures {
    fn from(r: &nerfsv_nerf::EvalReport) -> Self {
        Self {
            psnr: r.psnr,
            ssim: r.ssim,
            depth_median_abs_err_m: r.depth_median_abs_err_m,
            images: r.images,
            background: r.background,
        }
    }
}

impl Eval {
    pub const METRICS: &'static str = "metrics.json";
    pub const COMPARE: &'static str = "compare.png";
    /// Test views shown in `compare.png`, and their enlargement.
    const SHOWN: usize = 4;
    const SCALE: u32 = 2;
}

impl Stage for Eval {
    const NAME: &'static str = "eval";
    const CODE: &'static [&'static str] = &["nerfsv-nerf", "nerfsv-collision", "stages.rs"];
    const OUTPUTS: &'static [&'static str] = &[Self::METRICS, Self::COMPARE];
    const INPUTS: &'static [&'static str] = &[Dataset::NAME, Train::NAME];
    type Figures = EvalFigures;

    fn config(&self) -> impl Serialize {}

    fn run(&self, cx: &StageContext) -> Result<EvalFigures, PipelineError> {
        let nerf = Nerf::load(&Train::checkpoint(cx.root))?;
        let test = load_dataset_split(&Dataset::folder(cx.root)?, "test", 1)?;
        let report = nerfsv_nerf::evaluate_with_progress(&nerf, &test, EvalOptions::default(), &|done, total| {
            cx.progress(done as u64, total as u64, "test views evaluated")
        })?;
        write_json(&cx.dir.join(Self::METRICS), &report)?;
        let shown: Vec<_> = test.frames.iter().take(Self::SHOWN).map(|f| f.view()).collect();
        let image = nerfsv_nerf::comparison_image(&nerf, &shown, Self::SCALE)?;
        let path = cx.dir.join(Self::COMPARE);
        nerfsv_scene::io::atomic_write(&path, |w| image.write_png(w)).map_err(|e| PipelineError::io(&path, e))?;
        Ok(EvalFigures::from(&report))
    }
}

// ---------------------------------------------------------------------------------------------
// 5. The NeRF's collision field.

/// The NeRF's signed collision field on the ground-truth field's grid, and its agreement with
/// it: `RUN/nerf_collision/nerf_sdf.safetensors`, `nerf_mesh.ply`.
pub struct NerfField {
    /// Density (1/m) above which the NeRF is solid; `None`: ln 2 / cell.
    pub density_threshold: Option<f32>,
    /// `None`: on the ground truth's grid, compared with it. `Some(cells per metre)`: over the
    /// model's box at that resolution, for a world without a ground truth.
    pub own_grid: Option<f32>,
}

impl NerfField {
    pub const SDF: &'static str = "nerf_sdf.safetensors";
    pub const MESH: &'static str = "nerf_mesh.ply";
}

/// The NeRF's collision field on `geometry` ([`nerfsv_collision::build_model_field`] of its
/// density), with its agreement with `reference` when given; written to `sdf_path` (and the mesh
/// to `mesh_path`).
pub fn build_nerf_field(
    nerf: &Nerf,
    geometry: nerfsv_collision::GridGeometry,
    density_threshold: Option<f32>,
    reference: Option<&SdfGrid>,
    sdf_path: &Path,
    mesh_path: Option<&Path>,
) -> Result<DensityFieldFigures, PipelineError> {
    let density = |points: &[nalgebra::Point3<f32>], out: &mut [f32]| nerf.density_into(points, out);
    Ok(nerfsv_collision::build_model_field(geometry, density_threshold, density, reference, sdf_path, mesh_path)?)
}

/// The grid a NeRF's field of run `root` is built on, and the ground truth's field it is
/// compared with: with `own_grid` `None`, the ground-truth field's own grid (read back from its
/// stage); with `Some(cells per metre)`, the model's box at that resolution and no comparison.
pub fn nerf_field_geometry(
    root: &Path,
    own_grid: Option<f32>,
    nerf: &Nerf,
) -> Result<(nerfsv_collision::GridGeometry, Option<SdfGrid>), PipelineError> {
    Ok(match own_grid {
        None => {
            let reference = SdfGrid::load(GroundTruthField::sdf_path(root))?;
            (reference.geometry, Some(reference))
        }
        Some(cells_per_metre) => {
            let bounds = nerfsv_scene::Aabb::new(nerf.config.aabb_min.into(), nerf.config.aabb_max.into());
            let geometry = nerfsv_collision::GridGeometry::covering(&bounds, cells_per_metre)?;
            nerfsv_collision::check_grid_memory("cells_per_metre", &geometry)?;
            (geometry, None)
        }
    })
}

impl Stage for NerfField {
    const NAME: &'static str = "nerf_collision";
    const CODE: &'static [&'static str] = &["nerfsv-nerf", "nerfsv-collision", "stages.rs"];
    const OUTPUTS: &'static [&'static str] = &[Self::SDF, Self::MESH];
    const INPUTS: &'static [&'static str] = &[Train::NAME, GroundTruthField::NAME];
    type Figures = DensityFieldFigures;

    fn inputs(&self) -> &'static [&'static str] {
        match self.own_grid {
            None => Self::INPUTS,
            Some(_) => &[Train::NAME],
        }
    }

    fn config(&self) -> impl Serialize {
        (self.density_threshold, self.own_grid)
    }

    fn run(&self, cx: &StageContext) -> Result<DensityFieldFigures, PipelineError> {
        let nerf = Nerf::load(&Train::checkpoint(cx.root))?;
        let (geometry, reference) = nerf_field_geometry(cx.root, self.own_grid, &nerf)?;
        build_nerf_field(
            &nerf,
            geometry,
            self.density_threshold,
            reference.as_ref(),
            &cx.dir.join(Self::SDF),
            Some(&cx.dir.join(Self::MESH)),
        )
    }
}
