//! Where a captured dataset lies in the study's world (metres, z up): a capture's units, up axis
//! and centre are whatever its reconstruction left them.

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use nerfsv_scene::mesh::UpAxis;
use nerfsv_scene::validate::{finite, positive, InvalidValue};
use serde::{Deserialize, Serialize};

use crate::split::Split;

/// How a capture's coordinates become the world's, applied in this order: subtract `centre`,
/// turn `up` to +z, multiply by `scale`. A world point is
/// `p_world = scale · R_up · (p_capture − centre)`; a camera keeps its orientation relative to
/// the capture (its rotation becomes `R_up · R`), and ground-truth depths are multiplied by
/// `scale`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Metres per capture unit: finite, greater than 0 (default 1).
    pub scale: f32,
    /// Which capture axis points up: `z` (default), `y` (`(x, y, z)` becomes `(x, −z, y)`), `x`,
    /// `-x`, `-y` or `-z`, turned to +z by a proper rotation ([`UpAxis::rotation`]).
    pub up: UpAxis,
    /// The capture-unit point that becomes the world origin (default `[0, 0, 0]`).
    pub centre: [f32; 3],
}

impl Default for Placement {
    fn default() -> Self {
        Self { scale: 1.0, up: UpAxis::Z, centre: [0.0; 3] }
    }
}

impl Placement {
    /// Whether it leaves every pose as it is.
    pub fn is_identity(&self) -> bool {
        *self == Self::default()
    }

    /// Refuses a scale that is not a finite number above 0 and a centre that is not finite,
    /// naming `dataset_scale` or `dataset_centre`.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        positive("dataset_scale", self.scale as f64)?;
        for (k, c) in self.centre.iter().enumerate() {
            finite(&format!("dataset_centre[{k}]"), *c as f64)?;
        }
        Ok(())
    }

    /// `R_up`: the rotation turning the capture's up axis to +z (determinant +1), as the mesh
    /// loader turns a file with the same up axis.
    pub fn rotation(&self) -> Matrix3<f32> {
        self.up.rotation()
    }

    /// A capture point in the world (metres).
    pub fn point(&self, p: Point3<f32>) -> Point3<f32> {
        Point3::from(self.scale * (self.rotation() * (p - Point3::from(Vector3::from(self.centre)))))
    }

    /// A camera-to-world transform of the capture as one of the world.
    pub fn camera_to_world(&self, c2w: &Matrix4<f32>) -> Matrix4<f32> {
        let r = self.rotation();
        let rot = r * c2w.fixed_view::<3, 3>(0, 0);
        let pos = self.point(Point3::new(c2w[(0, 3)], c2w[(1, 3)], c2w[(2, 3)]));
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&rot);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&pos.coords);
        m
    }

    /// Places every camera of `split` in the world and scales its depths (metres).
    pub fn place(&self, split: &mut Split) {
        if self.is_identity() {
            return;
        }
        for f in &mut split.frames {
            f.camera.c2w = self.camera_to_world(&f.camera.c2w);
            if let Some(d) = &mut f.depth {
                d.metres.iter_mut().for_each(|m| *m *= self.scale);
            }
        }
    }
}
