//! Collision fields for nerfsv: the paper's pipeline from a scalar field (an analytic SDF, or a
//! NeRF density at a threshold) to a signed distance field in metres that the simulator queries
//! with the drone's body box.
//!
//! 1. [`ScalarGrid::sample`] samples a field at the nodes of a grid (default 40 cells per metre).
//! 2. [`marching_cubes`] extracts the surface as a [`Mesh`] (PLY/OBJ export).
//! 3. [`OccupancyGrid::from_field`] is the collision map: nodes inside or touched by the surface.
//! 4. [`SdfGrid::from_field`] is the signed distance (positive outside, negative inside), via an
//!    exact Felzenszwalb–Huttenlocher distance/feature transform ([`edt`]) with sub-cell surface
//!    points; [`SdfGrid::from_occupancy`] is the classic binary-map version.
//! 5. [`SdfGrid::distance`], [`SdfGrid::gradient`] and [`SdfGrid::box_query`] answer queries;
//!    leaving the grid is an explicit [`GridQuery::OutOfGrid`] / [`BoxQuery::OutOfGrid`].
//! 6. Grids are saved as safetensors (tensor `[nz, ny, nx]`, metadata described in [`io`]).
//!
//! Conventions: metres, z up. Values live at grid **nodes**: node `(i, j, k)` is at
//! `origin + cell·(i, j, k)` and stored at `data[i + nx·(j + ny·k)]` (x fastest); see [`grid`].
//!
//! ```
//! use nalgebra::{Point3, Rotation3};
//! use nerfsv_collision::{marching_cubes, drone_half_extents, BoxQuery, ScalarGrid, SdfGrid};
//! use nerfsv_scene::Aabb;
//!
//! // A ball of radius 0.2 m as an analytic SDF, sampled at 40 cells per metre.
//! let field = ScalarGrid::sample(&Aabb::cube(0.5), 40.0, |p| p.coords.norm() - 0.2);
//! let mesh = marching_cubes(&field, 0.0, true); // SDF: inside is below the iso level
//! assert!(mesh.triangles.len() > 1000);
//!
//! let sdf = SdfGrid::from_field(&field, 0.0, true);
//! let d = sdf.distance(Point3::new(0.3, 0.0, 0.0)).in_grid().unwrap();
//! assert!((d - 0.1).abs() < 0.005);
//!
//! // The drone body (0.1 × 0.1 × 0.04 m) centred 0.3 m from the ball's centre: 0.05 m clear.
//! let q = sdf.box_query(Point3::new(0.3, 0.0, 0.0), &Rotation3::identity(), drone_half_extents());
//! assert!(matches!(q, BoxQuery::Clear { clearance } if (clearance - 0.05).abs() < 0.005));
//! // Off the grid is reported, never clamped.
//! assert_eq!(sdf.box_query(Point3::new(0.48, 0.0, 0.0), &Rotation3::identity(), drone_half_extents()),
//!            BoxQuery::OutOfGrid);
//! ```

use std::path::PathBuf;

pub mod edt;
pub mod grid;
pub mod io;
pub mod mc_tables;
pub mod mesh;
pub mod occupancy;
pub mod sdf;
pub mod stats;

pub use grid::{GridGeometry, GridQuery, ScalarGrid};
pub use mesh::{marching_cubes, Mesh};
pub use occupancy::OccupancyGrid;
pub use sdf::{drone_half_extents, BoxQuery, SdfGrid, DRONE_BODY_SIZE};
pub use stats::{agreement, Agreement, GridSummary};

/// Everything that can go wrong in this crate; file errors name the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum CollisionError {
    #[error("invalid grid geometry: {0}")]
    InvalidGeometry(String),
    #[error("grid data has {found} values, expected {expected} (one per node)")]
    DataLength { expected: usize, found: usize },
    #[error("{}: {source}", .path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a valid safetensors file: {source}", .path.display())]
    SafeTensors { path: PathBuf, source: safetensors::SafeTensorError },
    #[error("{}: metadata field \"{field}\" missing", .path.display())]
    MissingField { path: PathBuf, field: &'static str },
    #[error("{}: metadata field \"{field}\" is \"{found}\", expected {expected}", .path.display())]
    BadField { path: PathBuf, field: &'static str, found: String, expected: String },
    #[error("{}: tensor \"{name}\" missing (the file holds: {found})", .path.display())]
    MissingTensor { path: PathBuf, name: &'static str, found: String },
    #[error("{}: tensor \"{name}\": {problem}", .path.display())]
    BadTensor { path: PathBuf, name: &'static str, problem: String },
}

#[cfg(test)]
pub(crate) mod testutil {
    use nalgebra::Point3;
    use nerfsv_scene::Aabb;

    /// SplitMix64: a tiny deterministic generator for test inputs.
    pub struct Rng(u64);

    impl Rng {
        pub fn new(seed: u64) -> Self {
            Self(seed)
        }

        pub fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^ (z >> 31)
        }

        /// Uniform in [0, 1).
        pub fn uniform(&mut self) -> f32 {
            (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
        }

        pub fn point_in(&mut self, b: &Aabb) -> Point3<f32> {
            let e = b.extent();
            Point3::new(b.min.x + e.x * self.uniform(), b.min.y + e.y * self.uniform(), b.min.z + e.z * self.uniform())
        }
    }
}
