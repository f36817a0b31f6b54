//! The dataset stage: the scene's dataset rendered into the run, or a user's folder read where
//! it is.

mod report;

use std::path::{Path, PathBuf};
use std::time::Instant;

use nerfsv_dataset::{load_split, GenerateOptions, LoadOptions, Placement, Split};
use nerfsv_scene::Scene;
use serde::{Deserialize, Serialize};

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
/// training) and records where it lies and how its poses are placed ([`Dataset::SOURCE`]).
fn read_folder(folder: &Path, placement: Placement, cx: &StageContext) -> Result<DatasetFigures, PipelineError> {
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
    let absolute = std::path::absolute(folder).map_err(|e| PipelineError::io(folder, e))?;
    write_json(&cx.dir.join(Dataset::SOURCE), &DatasetFolder { folder: absolute, placement })?;
    Ok(DatasetFigures {
        scene: folder.display().to_string(),
        views,
        width: size.0,
        height: size.1,
        seconds: start.elapsed().as_secs_f64(),
        primary_rays_per_second: 0.0,
    })
}
