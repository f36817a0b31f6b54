//! The offline uncertainty stage's table, `[uq_offline]`.

use nerfsv_scene::validate::in_range;
use nerfsv_scene::InvalidValue;
use serde::{Deserialize, Serialize};

/// The offline uncertainty stage of `nerfsv run`: how many images of each split GA and BLA
/// fit (an even stride through the split), the `[uq_offline]` table. The depth AUSE of each
/// method is taken over its test images.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct UqOfflineConfig {
    /// GA: images per split, at most (default 50; about 0.15 s per 100×100 image on two
    /// cores, so every image of the default dataset would add a minute and a half).
    pub ga_images_per_split: usize,
    /// BLA: images per split, at most (default 2; about 5 s per image, twice that for the
    /// test images, whose depth-uncertainty maps the AUSE needs); 0 skips BLA.
    pub bla_images_per_split: usize,
}

impl Default for UqOfflineConfig {
    fn default() -> Self {
        Self { ga_images_per_split: 50, bla_images_per_split: 2 }
    }
}

impl UqOfflineConfig {
    /// The first value out of range, named by its key in the table.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("ga_images_per_split", self.ga_images_per_split, 1, 1_000_000)?;
        in_range("bla_images_per_split", self.bla_images_per_split, 0, 1_000_000)
    }
}
