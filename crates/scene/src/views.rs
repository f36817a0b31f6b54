//! Posed images: what a model is trained on, evaluated against and compared with. A dataset's
//! split is one (`nerfsv_dataset::Split`); the NeRF reads views only through [`PosedImages`], so
//! it does not depend on where they came from.

use std::path::Path;

use crate::camera::Camera;
use crate::image::{DepthImage, Image};

/// One posed image.
#[derive(Clone, Copy, Debug)]
pub struct View<'a> {
    /// How its source names it (a dataset's `file_path`), for messages.
    pub name: &'a str,
    pub camera: &'a Camera,
    /// Straight-alpha RGBA of the camera's size.
    pub image: &'a Image,
    /// Ground-truth z-depth, when known.
    pub depth: Option<&'a DepthImage>,
}

/// A numbered set of posed images.
pub trait PosedImages: Sync {
    /// The file the views were read from (errors name it).
    fn source(&self) -> &Path;
    /// Number of views.
    fn len(&self) -> usize;
    /// View `i < len()`.
    fn view(&self, i: usize) -> View<'_>;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pixels over all views.
    fn pixels(&self) -> usize {
        (0..self.len()).map(|i| self.view(i).image.rgba.len() / 4).sum()
    }
}
