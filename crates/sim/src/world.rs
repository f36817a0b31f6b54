//! The two worlds the drone flies in. They share one interface and differ only in what they are
//! made of: **NeRF-sim** renders the camera's image with the NeRF and checks collisions against
//! the NeRF's signed field; **GT-sim** renders it with the ground-truth scene and checks them
//! against the ground-truth signed field.

use nerfsv_collision::SdfGrid;
use nerfsv_nerf::{Nerf, RayInput};
use nerfsv_scene::{Camera, RenderSettings, Scene};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which world a rollout flies in.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WorldKind {
    /// Observations rendered by the NeRF, collisions from the NeRF-derived signed field.
    Nerf,
    /// Observations from the ground-truth renderer, collisions from the ground-truth field.
    Gt,
}

impl WorldKind {
    /// The other world: where a flight's disturbances are replayed.
    pub fn other(self) -> Self {
        match self {
            Self::Nerf => Self::Gt,
            Self::Gt => Self::Nerf,
        }
    }
}

/// What a simulator needs of a world: its signed field (metres, positive in free space) and
/// the camera's view of it.
pub trait World: Sync {
    fn kind(&self) -> WorldKind;

    /// The signed distance field the drone's body is checked against.
    fn field(&self) -> &SdfGrid;

    /// The colours of the pixels `pixels` (column, row) of the image `camera` takes,
    /// composited on `background`, in `[0, 1]`. Only the pixels read are rendered: an image
    /// costs what the estimator looks at.
    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]>;

    /// The world the rollout of `seed` flies in when it is not this one: for an
    /// [`EnsembleWorld`], one of its members; for a [`crate::CalibratedWorld`], a member seen
    /// through one draw of the perception error model.
    fn for_rollout(&self, _seed: u64) -> Option<Box<dyn World + '_>> {
        None
    }
}

/// NeRF-sim: the NeRF is both the camera and the world.
#[derive(Clone, Copy)]
pub struct NerfWorld<'a> {
    pub nerf: &'a Nerf,
    pub field: &'a SdfGrid,
}

impl World for NerfWorld<'_> {
    fn kind(&self) -> WorldKind {
        WorldKind::Nerf
    }

    fn field(&self) -> &SdfGrid {
        self.field
    }

    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]> {
        let rays = pixel_rays(camera, pixels, background);
        let out = self.nerf.render_rays(&rays);
        out.rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    }
}

/// GT-sim: the ground-truth scene, rendered as the dataset was (same lighting and
/// supersampling), against its own signed field.
pub struct GroundTruthWorld<'a> {
    pub scene: &'a Scene,
    pub field: &'a SdfGrid,
    pub render: RenderSettings,
}

impl World for GroundTruthWorld<'_> {
    fn kind(&self) -> WorldKind {
        WorldKind::Gt
    }

    fn field(&self) -> &SdfGrid {
        self.field
    }

    /// Parallel over pixels (each is traced on its own, so any thread count gives the same
    /// colours).
    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]> {
        pixels
            .par_iter()
            .map(|&[i, j]| {
                // The renderer's pixel (straight alpha), composited on the background.
                let (rgba, _) = self.scene.render_pixel(camera, i, j, &self.render);
                std::array::from_fn(|c| rgba[c] * rgba[3] + background[c] * (1.0 - rgba[3]))
            })
            .collect()
    }
}

/// NeRF-sim whose world is not the estimator's map: each rollout's camera images and collision
/// field come from one member of an ensemble of NeRFs trained like the map but with other
/// seeds, member `seed mod members` of the rollout's seed, while the estimator keeps localising
/// against its own NeRF. The members stand for the world's model uncertainty: the map and the
/// world disagree where the training data leaves the scene undetermined, as the map and the
/// real world do.
pub struct EnsembleWorld<'a> {
    /// At least one.
    pub members: Vec<NerfWorld<'a>>,
}

impl EnsembleWorld<'_> {
    /// The member that flies the rollout of `seed`.
    pub fn member_of(&self, seed: u64) -> usize {
        (seed % self.members.len() as u64) as usize
    }
}

/// Read directly (not through [`World::for_rollout`]), an ensemble world is its first member.
impl World for EnsembleWorld<'_> {
    fn kind(&self) -> WorldKind {
        WorldKind::Nerf
    }

    fn field(&self) -> &SdfGrid {
        self.members[0].field
    }

    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]> {
        self.members[0].observe(camera, pixels, background)
    }

    fn for_rollout(&self, seed: u64) -> Option<Box<dyn World + '_>> {
        let m = &self.members[self.member_of(seed)];
        Some(Box::new(NerfWorld { nerf: m.nerf, field: m.field }))
    }
}

/// The rays through the centres of `pixels` of `camera`.
pub fn pixel_rays(camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<RayInput> {
    pixels.iter().map(|&[i, j]| RayInput::through_pixel(camera, i, j, background)).collect()
}
