//! The dataset stage: the scene's dataset rendered into the run, or a user's folder read where
//! it is.

mod report;

use std::path::{Path, PathBuf};
use std::time::Instant;

use nerfsv_dataset::{load_linked_split, GenerateOptions, LinkedFolder, Placement, LINK_FILE};
use nerfsv_scene::Scene;
use serde::Serialize;

use crate::stage::{write_json, Stage, StageContext};
use crate::PipelineError;

/// The dataset the NeRF learns from: the scene's Blender-format dataset rendered into
/// `RUN/dataset/`, or a user's folder used as is (`RUN/dataset/source.json` names it and where
/// its poses lie in the world).
pub struct DatasetStage<'a> {
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

pub use nerfsv_dataset::DatasetFigures;

/// Renders `scene` into the dataset folder `out` ([`nerfsv_dataset::render`]), naming the folder
/// in the error.
fn render_dataset(
    scene: &Scene,
    out: &Path,
    opts: &GenerateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<DatasetFigures, PipelineError> {
    nerfsv_dataset::render(scene, out, opts, progress)
        .map_err(|e| PipelineError::Dataset { context: format!("writing dataset {}", out.display()), error: e })
}

impl DatasetStage<'_> {
    /// The file naming a user's dataset folder ([`nerfsv_dataset::LinkedFolder`]).
    pub const SOURCE: &'static str = LINK_FILE;

    /// The folder [`load_linked_split`] reads run `root`'s dataset from: `RUN/dataset/`, which
    /// holds the rendered dataset or names the user's folder and its placement.
    pub fn folder(root: &Path) -> Result<PathBuf, PipelineError> {
        let dir = root.join(DatasetStage::NAME);
        let source = dir.join(Self::SOURCE);
        if source.exists() {
            // A broken record fails here, before a stage opens it.
            LinkedFolder::read(&source)?;
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

impl Stage for DatasetStage<'_> {
    const NAME: &'static str = "dataset";
    const MODULE: &'static str = module_path!();
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
            DatasetSource::Folder { folder, placement } => read_folder(folder, *placement, cx),
        }
    }
}

/// Reads every split of the dataset `folder` (so that a broken dataset stops the run before
/// training) and records where it lies and how its poses are placed ([`DatasetStage::SOURCE`]).
fn read_folder(folder: &Path, placement: Placement, cx: &StageContext) -> Result<DatasetFigures, PipelineError> {
    let start = Instant::now();
    let mut views = 0;
    let mut size = (0, 0);
    for (i, split) in ["train", "val", "test"].into_iter().enumerate() {
        let s = load_linked_split(folder, split, 1)?;
        views += s.frames.len();
        if let Some(f) = s.frames.first() {
            size = (f.image.width, f.image.height);
        }
        cx.progress(i as u64 + 1, 3, "splits read");
    }
    let absolute = std::path::absolute(folder).map_err(|e| PipelineError::io(folder, e))?;
    write_json(&cx.dir.join(DatasetStage::SOURCE), &LinkedFolder { folder: absolute, placement })?;
    Ok(DatasetFigures {
        scene: folder.display().to_string(),
        views,
        width: size.0,
        height: size.1,
        seconds: start.elapsed().as_secs_f64(),
        primary_rays_per_second: 0.0,
    })
}
