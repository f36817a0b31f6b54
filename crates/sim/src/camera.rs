//! The drone's body-fixed camera.
//!
//! Body frame: x forward, y left, z up. The camera sits at the body's centre and looks along
//! body +x with its image "up" along body +z, so in the OpenGL camera convention (x right, y up,
//! looking down −z) camera x = −body y, camera y = body z, camera z = −body x.

use nalgebra::{Matrix3, Matrix4, Vector3};
use nerfsv_scene::{Camera, Intrinsics};

/// Columns: the camera's x, y, z axes in the body frame.
pub fn body_to_camera_axes() -> Matrix3<f64> {
    Matrix3::from_columns(&[-Vector3::y(), Vector3::z(), -Vector3::x()])
}

/// The camera of a drone at `position` with body-to-world `rotation`.
pub fn drone_camera(intrinsics: Intrinsics, position: &Vector3<f64>, rotation: &Matrix3<f64>) -> Camera {
    let r = rotation * body_to_camera_axes();
    let mut c2w = Matrix4::<f32>::identity();
    for i in 0..3 {
        for j in 0..3 {
            c2w[(i, j)] = r[(i, j)] as f32;
        }
        c2w[(i, 3)] = position[i] as f32;
    }
    Camera::new(intrinsics, c2w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_looks_along_body_x_with_image_up_along_body_z() {
        let k = Intrinsics::from_fov_x(8, 8, 0.8);
        // Yawed 90°: body x points along world y.
        let yaw = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let cam = drone_camera(k, &Vector3::new(1.0, 2.0, 0.3), &yaw);
        assert!((cam.forward() - nalgebra::Vector3::y()).norm() < 1e-6);
        let up = cam.rotation().column(1).into_owned();
        assert!((up - nalgebra::Vector3::z()).norm() < 1e-6);
        // A pixel right of centre looks to the drone's right (world +x when facing +y).
        let r = cam.ray(7.5, 4.0);
        assert!(r.direction.x > 0.1 && r.direction.y > 0.0);
        assert!((cam.position().coords - nalgebra::Vector3::new(1.0, 2.0, 0.3)).norm() < 1e-6);
    }
}
