//! Exact signed distance functions of the primitives scenes are made of.
//!
//! Every primitive's SDF is exact (a true Euclidean distance outside and inside), so a union
//! by `min` is exact outside the union, which sphere tracing and the collision tests rely on.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

/// What a surface is made of; selects the procedural texture.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Material {
    Stone,
    Ground,
}

/// A primitive shape in world coordinates (metres).
#[derive(Clone, Copy, Debug)]
pub enum Shape {
    /// A box with rounded edges: centre, world→local rotation, half extents (including the
    /// rounding) and edge radius.
    RoundedBox { center: Point3<f32>, world_to_local: Matrix3<f32>, half: Vector3<f32>, radius: f32 },
    /// A capped cylinder with its axis along world z.
    Cylinder { center: Point3<f32>, radius: f32, half_height: f32 },
}

impl Shape {
    /// A box of full size `size` at `center`, rotated by `rotation`, with edges rounded by `radius`.
    pub fn rounded_box(center: Point3<f32>, rotation: Rotation3<f32>, size: Vector3<f32>, radius: f32) -> Self {
        Shape::RoundedBox { center, world_to_local: rotation.inverse().into_inner(), half: size * 0.5, radius }
    }

    /// Signed distance from `p` in metres (negative inside).
    #[inline]
    pub fn distance(&self, p: &Point3<f32>) -> f32 {
        match *self {
            Shape::RoundedBox { center, world_to_local, half, radius } => {
                let local = world_to_local * (p - center);
                let q = local.abs() - (half - Vector3::repeat(radius));
                let outside = Vector3::new(q.x.max(0.0), q.y.max(0.0), q.z.max(0.0)).norm();
                outside + q.x.max(q.y).max(q.z).min(0.0) - radius
            }
            Shape::Cylinder { center, radius, half_height } => {
                let d = p - center;
                let dr = (d.x * d.x + d.y * d.y).sqrt() - radius;
                let dz = d.z.abs() - half_height;
                dr.max(dz).min(0.0) + (dr.max(0.0).powi(2) + dz.max(0.0).powi(2)).sqrt()
            }
        }
    }

    /// Centre and radius of a sphere containing the shape, for culling.
    pub fn bounding_sphere(&self) -> (Point3<f32>, f32) {
        match *self {
            Shape::RoundedBox { center, half, .. } => (center, half.norm()),
            Shape::Cylinder { center, radius, half_height } => {
                (center, (radius * radius + half_height * half_height).sqrt())
            }
        }
    }

    /// Axis-aligned bounds of the shape.
    pub fn aabb(&self) -> crate::Aabb {
        match *self {
            Shape::RoundedBox { center, world_to_local, half, .. } => {
                // local→world is the transpose; the extent along world axis i is Σ_j |R_ij| h_j.
                let r = world_to_local.transpose();
                let e = r.abs() * half;
                crate::Aabb::new(center - e, center + e)
            }
            Shape::Cylinder { center, radius, half_height } => {
                let e = Vector3::new(radius, radius, half_height);
                crate::Aabb::new(center - e, center + e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_distance_is_exact_on_axes_and_corners() {
        let b = Shape::rounded_box(Point3::origin(), Rotation3::identity(), Vector3::new(2.0, 2.0, 2.0), 0.0);
        assert!((b.distance(&Point3::new(3.0, 0.0, 0.0)) - 2.0).abs() < 1e-6);
        assert!((b.distance(&Point3::new(0.0, 0.0, 0.0)) + 1.0).abs() < 1e-6);
        assert!((b.distance(&Point3::new(2.0, 2.0, 2.0)) - 3f32.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn rotated_box_distance_follows_its_rotation() {
        let rot = Rotation3::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_4);
        let b = Shape::rounded_box(Point3::origin(), rot, Vector3::new(2.0, 2.0, 2.0), 0.0);
        // After a 45° yaw the box's corner points along +x at distance √2.
        assert!((b.distance(&Point3::new(2.0, 0.0, 0.0)) - (2.0 - 2f32.sqrt())).abs() < 1e-5);
    }

    #[test]
    fn cylinder_distance_matches_closed_form() {
        let c = Shape::Cylinder { center: Point3::new(0.0, 0.0, 1.0), radius: 1.0, half_height: 1.0 };
        assert!((c.distance(&Point3::new(3.0, 0.0, 1.0)) - 2.0).abs() < 1e-6);
        assert!((c.distance(&Point3::new(0.0, 0.0, 4.0)) - 2.0).abs() < 1e-6);
        assert!((c.distance(&Point3::new(0.0, 0.0, 1.5)) + 0.5).abs() < 1e-6);
        assert!((c.distance(&Point3::new(4.0, 0.0, 6.0)) - 5.0).abs() < 1e-6);
    }
}
