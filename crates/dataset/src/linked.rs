//! A dataset read where it lies: a folder holding [`LINK_FILE`] names a user's dataset folder
//! and where its poses lie in the world ([`Placement`]). A run's dataset stage writes one for a
//! user's folder (`nerfsv run` with `[dataset] folder`), so every later stage and command reads
//! that folder, placed, as if the run's dataset folder held it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::DatasetError;
use crate::folder::{dataset_format, load_split};
use crate::placement::Placement;
use crate::split::{LoadOptions, Split};

/// The file that names a linked dataset folder ([`LinkedFolder`]).
pub const LINK_FILE: &str = "source.json";

/// [`LINK_FILE`]'s content: the folder a dataset is read from, and where its poses lie in the
/// world (absent: as they are).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkedFolder {
    pub folder: PathBuf,
    #[serde(default, skip_serializing_if = "Placement::is_identity")]
    pub placement: Placement,
}

impl LinkedFolder {
    /// Reads a [`LINK_FILE`], naming it in the error.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
        serde_json::from_str(&text).map_err(|error| DatasetError::Json { path: path.to_path_buf(), error })
    }
}

/// Loads a split of `dir` with its depth images, naming the split and folder in the error.
/// `dir` is a dataset folder ([`load_split`]'s formats) or a folder whose [`LINK_FILE`] names
/// one: then that dataset's split, its poses placed in the world as the link says.
pub fn load_linked_split(dir: &Path, split: &str, downscale: u32) -> Result<Split, DatasetError> {
    let link = dir.join(LINK_FILE);
    let LinkedFolder { folder, placement } = match dataset_format(dir).is_none() && link.is_file() {
        true => LinkedFolder::read(&link)?,
        false => LinkedFolder { folder: dir.to_path_buf(), placement: Placement::default() },
    };
    let options = LoadOptions { downscale, load_depth: true, ..Default::default() };
    let mut s = load_split(&folder, split, options).map_err(|error| DatasetError::Split {
        split: split.to_string(),
        folder: folder.clone(),
        error: Box::new(error),
    })?;
    placement.place(&mut s);
    Ok(s)
}

/// Every frame of the dataset folder `dir`, placed by `placement`: the frames of its splits
/// (those it has: [`crate::has_split`]) once each, in split order (a frame two splits share, as
/// `val` and `test` of a `transforms.json` without split lists do, once). Without depth.
pub fn load_all_frames(dir: &Path, placement: Placement) -> Result<Vec<crate::Frame>, DatasetError> {
    let options = LoadOptions { downscale: 1, load_depth: false, ..Default::default() };
    let mut frames: Vec<crate::Frame> = Vec::new();
    for split in crate::SPLITS.into_iter().filter(|s| crate::has_split(dir, s)) {
        let mut s = load_split(dir, split, options).map_err(|error| DatasetError::Split {
            split: split.to_string(),
            folder: dir.to_path_buf(),
            error: Box::new(error),
        })?;
        placement.place(&mut s);
        for f in s.frames {
            if !frames.iter().any(|g| g.image_path == f.image_path) {
                frames.push(f);
            }
        }
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_link_reads_the_folder_it_names_placed() {
        let tmp = tempfile::tempdir().unwrap();
        let link = tmp.path().join("run");
        std::fs::create_dir(&link).unwrap();
        let missing = tmp.path().join("nowhere");
        let placement = Placement { scale: 2.0, ..Placement::default() };
        let text = serde_json::to_string(&LinkedFolder { folder: missing.clone(), placement }).unwrap();
        std::fs::write(link.join(LINK_FILE), text).unwrap();
        assert_eq!(LinkedFolder::read(&link.join(LINK_FILE)).unwrap().placement, placement);
        // The split is looked for in the named folder, and the error says which split of which.
        let e = load_linked_split(&link, "train", 1).unwrap_err().to_string();
        assert!(e.starts_with(&format!("loading the train split of {}: ", missing.display())), "{e}");
        std::fs::write(link.join(LINK_FILE), "{").unwrap();
        let e = load_linked_split(&link, "train", 1).unwrap_err().to_string();
        assert!(e.contains(LINK_FILE) && e.contains("not valid JSON"), "{e}");
    }
}
