//! Posed images: what a model is trained on, evaluated against and compared with. A dataset's
//! split is one (`nerfsv_dataset::Split`); the NeRF reads views only through [`PosedImages`], so
//! it does not depend on where they came from.

use std::path::Path;

use rand::{RngExt, SeedableRng};

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

/// A bootstrap resample of a set of views: as many views, drawn with replacement by a seeded
/// ChaCha8 generator (the same seed, the same draws on any machine).
pub struct Bootstrap<'a, P: PosedImages> {
    views: &'a P,
    picks: Vec<usize>,
}

impl<'a, P: PosedImages> Bootstrap<'a, P> {
    pub fn new(views: &'a P, seed: u64) -> Self {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let picks = (0..views.len()).map(|_| rng.random_range(0..views.len())).collect();
        Self { views, picks }
    }

    /// How many of the source's views were drawn at least once.
    pub fn distinct(&self) -> usize {
        let mut p = self.picks.clone();
        p.sort_unstable();
        p.dedup();
        p.len()
    }
}

impl<P: PosedImages> PosedImages for Bootstrap<'_, P> {
    fn source(&self) -> &Path {
        self.views.source()
    }

    fn len(&self) -> usize {
        self.picks.len()
    }

    fn view(&self, i: usize) -> View<'_> {
        self.views.view(self.picks[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use nalgebra::Matrix4;

    /// `n` one-pixel views named by their index.
    struct Numbered {
        names: Vec<String>,
        camera: Camera,
        image: Image,
    }

    impl PosedImages for Numbered {
        fn source(&self) -> &Path {
            Path::new("numbered")
        }

        fn len(&self) -> usize {
            self.names.len()
        }

        fn view(&self, i: usize) -> View<'_> {
            View { name: &self.names[i], camera: &self.camera, image: &self.image, depth: None }
        }
    }

    #[test]
    fn a_bootstrap_draws_as_many_views_with_replacement_the_same_for_the_same_seed() {
        let camera = Camera::new(Intrinsics::from_fov_x(1, 1, 0.8), Matrix4::identity());
        let views = Numbered { names: (0..50).map(|i| i.to_string()).collect(), camera, image: Image::new(1, 1) };
        let a = Bootstrap::new(&views, 7);
        let names = |b: &Bootstrap<Numbered>| (0..b.len()).map(|i| b.view(i).name.to_owned()).collect::<Vec<_>>();
        assert_eq!(a.len(), 50);
        assert_eq!(names(&a), names(&Bootstrap::new(&views, 7)));
        assert_ne!(names(&a), names(&Bootstrap::new(&views, 8)));
        // With replacement: about 1 − 1/e of the views appear (≈ 32 of 50), never all by chance here.
        assert!((20..50).contains(&a.distinct()), "{}", a.distinct());
        let mut seen = names(&a);
        seen.sort();
        seen.dedup();
        assert_eq!(seen.len(), a.distinct());
    }
}
