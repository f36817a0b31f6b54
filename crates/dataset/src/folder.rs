//! A dataset folder, whichever format it holds: Blender (`transforms_{split}.json`), instant-ngp
//! and nerfstudio (`transforms.json`) or COLMAP (`sparse/0/`), told apart by the files it holds.

use std::path::{Path, PathBuf};

use nerfsv_scene::validate::InvalidValue;

use crate::colmap::{colmap_files, load_colmap, model_files};
use crate::error::DatasetError;
use crate::split::{LoadOptions, Split};
use crate::transforms::{load_transforms, transforms_files};

/// The formats a dataset folder can hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DatasetFormat {
    /// `transforms_{train,val,test}.json`, one per split.
    Blender,
    /// A single `transforms.json` (instant-ngp, nerfstudio).
    Transforms,
    /// A COLMAP sparse model, `sparse/0/{cameras,images}.{bin,txt}`, and `images/`.
    Colmap,
}

/// The format of the folder `dir`, from the files it holds, in this order: a
/// `transforms_{split}.json` of any split, `transforms.json`, a COLMAP model; `None` if none.
pub fn dataset_format(dir: &Path) -> Option<DatasetFormat> {
    if ["train", "val", "test"].iter().any(|s| dir.join(format!("transforms_{s}.json")).is_file()) {
        Some(DatasetFormat::Blender)
    } else if dir.join("transforms.json").is_file() {
        Some(DatasetFormat::Transforms)
    } else if model_files(dir).is_some() {
        Some(DatasetFormat::Colmap)
    } else {
        None
    }
}

/// Reads split `split` (`train`, `val` or `test`) of the dataset folder `dir` and its images,
/// from the first of these the folder holds:
///
/// - Blender: `dir/transforms_{split}.json`, all its frames.
/// - instant-ngp / nerfstudio: `dir/transforms.json`, the frames its `{split}_filenames` names,
///   or without split lists every 8th frame (0, 8, 16, …) as `val` and `test` and the others as
///   `train`.
/// - COLMAP ([`crate::colmap`]): the images in name order, every 8th as `val` and `test`.
///
/// Images are PNG or JPEG (told apart by their first bytes), their pixels as stored unless their
/// EXIF orientation turns them to the size the capture gives for the frame (then turned, as the
/// capture was made from the turned pixels); cameras with OpenCV distortion are undistorted into
/// the pinhole camera with the same intrinsics
/// ([`crate::distortion::OpenCvDistortion::undistort_image`]). A folder with none of these fails
/// naming `transforms_{split}.json`.
pub fn load_split(dir: &Path, split: &str, opts: LoadOptions) -> Result<Split, DatasetError> {
    if opts.downscale == 0 {
        return Err(InvalidValue::new("downscale", "must be at least 1", 0).into());
    }
    let own = dir.join(format!("transforms_{split}.json"));
    if !own.exists() && dir.join("transforms.json").exists() {
        load_transforms(&dir.join("transforms.json"), split, true, opts)
    } else if !own.exists() && model_files(dir).is_some() {
        load_colmap(dir, split, opts)
    } else {
        load_transforms(&own, split, false, opts)
    }
}

/// Opens the dataset folder `dir` as a run would, reading one frame: the folder exists, its
/// format is recognised, its train split is not empty and its first frame decodes. The error
/// says what is wrong with the folder and what to do, for the caller to prefix with the key or
/// flag and the path as the user gave it.
pub fn probe(dir: &Path) -> Result<DatasetFormat, String> {
    const FORMATS: &str = "transforms_train.json (Blender), transforms.json (instant-ngp, nerfstudio) or a COLMAP \
                           model (sparse/0/cameras and images, .bin or .txt)";
    match std::fs::metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!("no such file or folder; give the folder of a capture holding {FORMATS}"));
        }
        Err(e) => return Err(format!("cannot be read ({e})")),
        Ok(m) if !m.is_dir() => {
            return Err(format!("is a file, not a dataset folder; give the folder holding {FORMATS}"))
        }
        Ok(_) => {}
    }
    let format = dataset_format(dir)
        .ok_or_else(|| format!("is not a dataset folder: it holds none of {FORMATS}; give the folder of a capture"))?;
    let opts = LoadOptions { downscale: 1, load_depth: false, max_frames: Some(1) };
    let split = load_split(dir, "train", opts).map_err(|e| format!("cannot be read as a dataset: {e}"))?;
    if split.frames.is_empty() {
        return Err("its train split has no frames; a capture needs frames to train on".into());
    }
    Ok(format)
}

/// Whether [`load_split`] finds split `split` in `dir`: its own `transforms_{split}.json`, or a
/// `transforms.json` or a COLMAP model, whose splits the loader derives.
pub fn has_split(dir: &Path, split: &str) -> bool {
    dir.join(format!("transforms_{split}.json")).exists()
        || dir.join("transforms.json").exists()
        || model_files(dir).is_some()
}

/// The files a dataset folder's loader reads, as far as its transforms files or COLMAP model
/// can be parsed: every `transforms*.json` it would open and the images and depth images their
/// frames name, or the COLMAP model files and the images they name (resolved as [`load_split`]
/// resolves them, not followed through symbolic links). A guard against writing over an input
/// needs them: a split folder may be a link to another folder. A file that cannot be read or
/// parsed lists only itself (loading it fails later, by name).
pub fn dataset_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = transforms_files(dir);
    files.extend(colmap_files(dir));
    files
}
