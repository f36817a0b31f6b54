//! Atomic file writes with this crate's error: the one low-level helper behind every file the
//! crate writes (meshes and grids).

use std::fs::File;
use std::io::{self, BufWriter};
use std::path::Path;

use crate::CollisionError;

/// [`nerfsv_scene::io::atomic_write`] with this crate's error, naming the file.
pub(crate) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> Result<(), CollisionError> {
    nerfsv_scene::io::atomic_write(path, write).map_err(|error| CollisionError::Io { path: path.to_path_buf(), error })
}
