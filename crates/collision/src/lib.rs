//! Collision fields for nerfsv: the paper's pipeline from a scalar field (an analytic SDF, or a
//! NeRF density at a threshold) to a signed distance field in metres that the simulator queries
//! with the drone's body box.
//!
//! 1. [`ScalarGrid::sample`] samples a field at the nodes of a grid (default 40 cells per metre);
//!    [`ScalarGrid::sample_batched`] does it in parallel batches for fields such as a NeRF.
//! 2. [`classify_nodes`] decides which nodes are solid, the one rule every step below shares:
//!    strictly below `iso` (an SDF) or above it (a density); a node exactly at `iso` is inside
//!    when none of its 6 neighbours is strictly outside (where two solids touch, e.g. a stone
//!    standing on the ground); and outside regions enclosed away from the grid's border are
//!    filled (a NeRF's stones are dense only at their surface). [`crossing_parameter`] places the
//!    surface along a grid edge (midway when both nodes sit exactly at `iso`).
//! 3. [`marching_cubes`] extracts the surface as a [`Mesh`] (PLY/OBJ export): crossings exactly
//!    on a node share one vertex, and no triangle is degenerate or doubled.
//! 4. [`OccupancyGrid::from_field`] is the collision map: nodes inside or touched by the surface.
//! 5. [`SdfGrid::from_field`] is the signed distance (positive outside, negative inside), via an
//!    exact Felzenszwalb–Huttenlocher distance/feature transform ([`edt`]) with sub-cell surface
//!    points; [`SdfGrid::from_occupancy`] is the classic binary-map version.
//! 6. [`SdfGrid::distance`], [`SdfGrid::gradient`] and [`SdfGrid::box_query`] answer queries;
//!    leaving the grid is an explicit [`GridQuery::OutOfGrid`] / [`BoxQuery::OutOfGrid`].
//! 7. Grids are saved as safetensors (tensor `[nz, ny, nx]`, metadata described in [`io`]).
//!
//! The stage's builders ([`fields`]) run the whole pipeline with their input checks:
//! [`ground_truth_field`] on a scene's analytic SDF over [`field_bounds`] (with its error against
//! the analytic SDF), [`density_field`] on any batched density; both return a [`BuiltField`].
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

use nerfsv_scene::validate::InvalidValue;

// Module dependencies form a DAG: each module uses only modules listed before it in
// atomic, edt, mc_tables, grid, classify, mesh, occupancy, sdf, io, stats, fields.
mod atomic;
pub mod classify;
pub mod edt;
pub mod fields;
pub mod grid;
pub mod io;
pub mod mc_tables;
pub mod mesh;
pub mod occupancy;
pub mod sdf;
pub mod stats;

pub use classify::{classify_nodes, crossing_parameter};
pub use fields::{
    build_ground_truth, build_model_field, check_cells_per_metre, check_grid_memory, default_density_threshold,
    density_field, field_bounds, ground_truth_field, model_field, repair_contact_planes, sample_mesh, sample_scene,
    scene_field, BuiltField, DensityFieldFigures, ErrorStats, GroundTruthFigures, ERROR_BAND, FLIGHT_BAND,
};
pub use grid::{GridGeometry, GridQuery, ScalarGrid};
pub use mesh::{marching_cubes, Mesh};
pub use occupancy::OccupancyGrid;
pub use sdf::{drone_half_extents, BoxQuery, SdfGrid, DRONE_BODY_SIZE};
pub use stats::{agreement, Agreement, GridSummary};

/// Everything that can go wrong in this crate; file errors name the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum CollisionError {
    /// A value given by the user (a resolution, a threshold, a grid size) is out of range.
    #[error(transparent)]
    Invalid(#[from] InvalidValue),
    #[error("grid data has {found} values, expected {expected} (one per node)")]
    DataLength { expected: usize, found: usize },
    #[error("{}: {error}", .path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{}: not a valid safetensors file: {error}", .path.display())]
    SafeTensors { path: PathBuf, error: safetensors::SafeTensorError },
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

    use crate::grid::{GridGeometry, ScalarGrid};

    /// Two axis boxes `[2, 5] × [2, 5] × [1, 4]` and `[2, 5] × [2, 5] × [4, 7]` on a unit grid
    /// of 8 × 8 × 9 nodes, touching along the grid plane z = 4: their exact union SDF, which is
    /// exactly 0 on the contact plane (integer coordinates, so exact in f32).
    pub fn touching_boxes() -> ScalarGrid {
        let g = GridGeometry::new(Point3::origin(), 1.0, [8, 8, 9]).unwrap();
        let boxed = |p: Point3<f32>, lo: [f32; 3], hi: [f32; 3]| {
            let q: [f32; 3] = std::array::from_fn(|a| (p[a] - 0.5 * (lo[a] + hi[a])).abs() - 0.5 * (hi[a] - lo[a]));
            let out = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt();
            out + q[0].max(q[1]).max(q[2]).min(0.0)
        };
        ScalarGrid::sample_geometry(g, |p| {
            boxed(p, [2.0, 2.0, 1.0], [5.0, 5.0, 4.0]).min(boxed(p, [2.0, 2.0, 4.0], [5.0, 5.0, 7.0]))
        })
    }

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
