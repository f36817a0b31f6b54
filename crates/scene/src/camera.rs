//! Pinhole cameras in the Blender/OpenGL convention used by NeRF datasets.
//!
//! Camera frame: x right, y up, the camera looks down −z. `c2w` maps camera coordinates to
//! world coordinates (metres, z up). Pixel `(u, v)` has `u` growing to the right and `v` growing
//! downwards; the centre of pixel `(i, j)` is at `(i + 0.5, j + 0.5)`.

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};

use crate::geometry::Ray;

/// Pinhole intrinsics in pixels.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
}

impl Intrinsics {
    /// Square pixels from the horizontal field of view, principal point at the image centre
    /// (the NeRF-synthetic `camera_angle_x` convention: `fx = 0.5·W / tan(0.5·angle_x)`).
    pub fn from_fov_x(width: u32, height: u32, camera_angle_x: f32) -> Self {
        let f = 0.5 * width as f32 / (0.5 * camera_angle_x).tan();
        Self { width, height, fx: f, fy: f, cx: 0.5 * width as f32, cy: 0.5 * height as f32 }
    }

    /// Horizontal field of view in radians.
    pub fn fov_x(&self) -> f32 {
        2.0 * (0.5 * self.width as f32 / self.fx).atan()
    }

    /// The same camera at `1/factor` of the resolution (pixel centres stay consistent).
    pub fn downscaled(&self, factor: u32) -> Self {
        let s = 1.0 / factor as f32;
        Self {
            width: self.width / factor,
            height: self.height / factor,
            fx: self.fx * s,
            fy: self.fy * s,
            cx: self.cx * s,
            cy: self.cy * s,
        }
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// A posed pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    /// Camera-to-world transform (OpenGL camera axes), rigid.
    pub c2w: Matrix4<f32>,
}

impl Camera {
    pub fn new(intrinsics: Intrinsics, c2w: Matrix4<f32>) -> Self {
        Self { intrinsics, c2w }
    }

    /// A camera at `eye` looking at `target`, with world `up` projected to the image's up.
    ///
    /// ```
    /// use nalgebra::{Point3, Vector3};
    /// use nerfsv_scene::camera::{Camera, Intrinsics};
    /// let cam = Camera::look_at(
    ///     Point3::new(0.0, -3.0, 0.0), Point3::origin(), Vector3::z(),
    ///     Intrinsics::from_fov_x(8, 8, 0.8),
    /// );
    /// let centre = cam.ray(4.0, 4.0);
    /// assert!((centre.direction - Vector3::y()).norm() < 1e-6);
    /// ```
    pub fn look_at(eye: Point3<f32>, target: Point3<f32>, up: Vector3<f32>, intrinsics: Intrinsics) -> Self {
        let back = (eye - target).normalize(); // camera +z points away from the target
        let mut right = up.cross(&back);
        if right.norm() < 1e-6 {
            right = Vector3::x().cross(&back);
        }
        let right = right.normalize();
        let cam_up = back.cross(&right);
        let rot = Matrix3::from_columns(&[right, cam_up, back]);
        let mut c2w = Matrix4::identity();
        c2w.fixed_view_mut::<3, 3>(0, 0).copy_from(&rot);
        c2w.fixed_view_mut::<3, 1>(0, 3).copy_from(&eye.coords);
        Self { intrinsics, c2w }
    }

    /// Camera centre in world coordinates.
    pub fn position(&self) -> Point3<f32> {
        Point3::from(self.c2w.fixed_view::<3, 1>(0, 3).into_owned())
    }

    /// Rotation part of `c2w`.
    pub fn rotation(&self) -> Matrix3<f32> {
        self.c2w.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// Viewing direction (the camera's −z axis) in world coordinates.
    pub fn forward(&self) -> Vector3<f32> {
        -self.rotation().column(2).into_owned()
    }

    /// Un-normalised camera-frame direction through the image point `(u, v)` (pixels), with
    /// unit depth along the optical axis: `((u − cx)/fx, −(v − cy)/fy, −1)`.
    pub fn camera_direction(&self, u: f32, v: f32) -> Vector3<f32> {
        let k = &self.intrinsics;
        Vector3::new((u - k.cx) / k.fx, -(v - k.cy) / k.fy, -1.0)
    }

    /// The world-space ray through image point `(u, v)` in pixels (unit direction).
    /// Pixel `(i, j)`'s centre is `(i + 0.5, j + 0.5)`.
    pub fn ray(&self, u: f32, v: f32) -> Ray {
        Ray::new(self.position(), self.rotation() * self.camera_direction(u, v))
    }

    /// The ray through the centre of pixel `(i, j)` (column, row).
    pub fn pixel_ray(&self, i: u32, j: u32) -> Ray {
        self.ray(i as f32 + 0.5, j as f32 + 0.5)
    }

    /// Converts a ray distance `t` along the unit ray through `(u, v)` to z-depth (distance along
    /// the optical axis), the quantity stored in depth images.
    pub fn z_depth_factor(&self, u: f32, v: f32) -> f32 {
        1.0 / self.camera_direction(u, v).norm()
    }
}
