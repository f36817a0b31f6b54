//! Small geometric value types shared by every stage: axis-aligned boxes and rays.

use nalgebra::{Point3, Vector3};

/// An axis-aligned box in world coordinates (metres).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    pub min: Point3<f32>,
    pub max: Point3<f32>,
}

impl Aabb {
    /// A box from its two corners; panics in debug builds if `min > max` on any axis.
    pub fn new(min: Point3<f32>, max: Point3<f32>) -> Self {
        debug_assert!(min.x <= max.x && min.y <= max.y && min.z <= max.z);
        Self { min, max }
    }

    /// The cube `[-half, half]³`.
    pub fn cube(half: f32) -> Self {
        Self::new(Point3::new(-half, -half, -half), Point3::new(half, half, half))
    }

    pub fn extent(&self) -> Vector3<f32> {
        self.max - self.min
    }

    pub fn center(&self) -> Point3<f32> {
        nalgebra::center(&self.min, &self.max)
    }

    pub fn contains(&self, p: &Point3<f32>) -> bool {
        (0..3).all(|i| p[i] >= self.min[i] && p[i] <= self.max[i])
    }

    /// The box grown by `margin` metres on every side.
    pub fn expanded(&self, margin: f32) -> Self {
        let m = Vector3::repeat(margin);
        Self::new(self.min - m, self.max + m)
    }

    /// Slab test: the parameter interval `[t_near, t_far]` (clamped to `t >= 0`) where the ray
    /// is inside the box, or `None` if it misses.
    pub fn intersect(&self, ray: &Ray) -> Option<(f32, f32)> {
        let mut t0 = 0.0f32;
        let mut t1 = f32::INFINITY;
        for i in 0..3 {
            let inv = 1.0 / ray.direction[i];
            let mut a = (self.min[i] - ray.origin[i]) * inv;
            let mut b = (self.max[i] - ray.origin[i]) * inv;
            if a > b {
                std::mem::swap(&mut a, &mut b);
            }
            // NaN (origin on a slab with a zero direction) keeps the previous bound.
            if a > t0 {
                t0 = a;
            }
            if b < t1 {
                t1 = b;
            }
            if t0 > t1 {
                return None;
            }
        }
        Some((t0, t1))
    }
}

/// A ray `origin + t·direction`; `direction` is unit length unless a constructor says otherwise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Point3<f32>,
    pub direction: Vector3<f32>,
}

impl Ray {
    /// A ray with its direction normalised.
    pub fn new(origin: Point3<f32>, direction: Vector3<f32>) -> Self {
        Self { origin, direction: direction.normalize() }
    }

    pub fn at(&self, t: f32) -> Point3<f32> {
        self.origin + self.direction * t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_test_enters_and_leaves_unit_cube_at_known_distances() {
        let b = Aabb::cube(1.0);
        let r = Ray::new(Point3::new(-3.0, 0.0, 0.0), Vector3::x());
        let (t0, t1) = b.intersect(&r).unwrap();
        assert!((t0 - 2.0).abs() < 1e-6 && (t1 - 4.0).abs() < 1e-6);
        let miss = Ray::new(Point3::new(-3.0, 2.0, 0.0), Vector3::x());
        assert!(b.intersect(&miss).is_none());
    }
}
