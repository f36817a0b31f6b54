//! Grid geometry shared by every field of this crate, and the sampled scalar field.
//!
//! Convention (used by [`ScalarGrid`], [`crate::SdfGrid`] and [`crate::OccupancyGrid`]): values
//! live at grid **nodes**. Node `(i, j, k)`, `0 ≤ i < nx` etc., sits at
//! `origin + cell·(i, j, k)` metres, and its value is `data[i + nx·(j + ny·k)]` (x fastest).
//! The grid spans the closed box `[origin, origin + cell·(dims − 1)]`; between nodes, fields are
//! interpolated trilinearly, and outside that box every query answers [`GridQuery::OutOfGrid`].

use nalgebra::{Point3, Vector3};
use nerfsv_scene::validate::InvalidValue;
use nerfsv_scene::Aabb;
use rayon::prelude::*;

use crate::CollisionError;

/// The answer of a query at a point: a value, or the explicit fact that the point is off the grid.
///
/// Leaving the grid is never wrapped or clamped to the border.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GridQuery<T> {
    /// The point lies in the grid's closed box; here is the interpolated value.
    InGrid(T),
    /// The point lies outside the grid's box (or has a NaN coordinate).
    OutOfGrid,
}

impl<T> GridQuery<T> {
    /// `Some(value)` inside the grid, `None` outside.
    pub fn in_grid(self) -> Option<T> {
        match self {
            GridQuery::InGrid(v) => Some(v),
            GridQuery::OutOfGrid => None,
        }
    }

    pub fn is_out_of_grid(&self) -> bool {
        matches!(self, GridQuery::OutOfGrid)
    }

    pub fn map<U>(self, f: impl FnOnce(T) -> U) -> GridQuery<U> {
        match self {
            GridQuery::InGrid(v) => GridQuery::InGrid(f(v)),
            GridQuery::OutOfGrid => GridQuery::OutOfGrid,
        }
    }
}

/// Where a grid's nodes are: `dims` nodes per axis, spaced `cell` metres, node 0 at `origin`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GridGeometry {
    /// Position of node (0, 0, 0), metres (world frame).
    pub origin: Point3<f32>,
    /// Node spacing, metres (the same on every axis).
    pub cell: f32,
    /// Node counts `[nx, ny, nz]`; at least 2 on every axis.
    pub dims: [usize; 3],
}

impl GridGeometry {
    /// A validated geometry: `cell` finite and positive, origin finite, at least 2 nodes per
    /// axis and fewer than 2³² − 1 nodes in all (indices are stored as `u32`). A wrong value is
    /// [`CollisionError::Invalid`], naming the field (`cell`, `origin`, `dims`) and the value.
    pub fn new(origin: Point3<f32>, cell: f32, dims: [usize; 3]) -> Result<Self, CollisionError> {
        positive("cell", cell)?;
        if !origin.iter().all(|v| v.is_finite()) {
            return Err(InvalidValue::new("origin", "must be finite", format!("{:?}", <[f32; 3]>::from(origin))).into());
        }
        if dims.iter().any(|&n| n < 2) {
            return Err(
                InvalidValue::new("dims", "must have at least 2 nodes on every axis", format!("{dims:?}")).into()
            );
        }
        let total = dims.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
        if total.is_none_or(|t| t >= u32::MAX as usize) {
            return Err(InvalidValue::new("dims", "must give fewer than 2^32 - 1 nodes", format!("{dims:?}")).into());
        }
        Ok(Self { origin, cell, dims })
    }

    /// The node lattice that covers `bounds` at `cells_per_metre` (e.g. 40 → 0.025 m).
    ///
    /// `origin = bounds.min`, `cell = 1 / cells_per_metre`, and per axis
    /// `n = ceil(extent · cells_per_metre) + 1` nodes, so the last node lies on or just beyond
    /// `bounds.max` (by less than one cell). A 3.8 m extent at 40 cells/m gives 153 nodes.
    pub fn covering(bounds: &Aabb, cells_per_metre: f32) -> Result<Self, CollisionError> {
        positive("cells_per_metre", cells_per_metre)?;
        let cell = 1.0 / cells_per_metre;
        let ext = bounds.extent();
        let mut dims = [0usize; 3];
        for a in 0..3 {
            // The tolerance keeps 3.8 m · 40 = 152.00001 (float noise) at 152 intervals.
            let intervals = (ext[a] as f64 * cells_per_metre as f64 - 1e-4).ceil().max(1.0);
            dims[a] = intervals as usize + 1;
        }
        Self::new(bounds.min, cell, dims)
    }

    /// Number of nodes, `nx·ny·nz`.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Always false: a valid geometry has at least 8 nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Flat index of node `(i, j, k)`: `i + nx·(j + ny·k)`.
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        debug_assert!(i < self.dims[0] && j < self.dims[1] && k < self.dims[2]);
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Node coordinates `(i, j, k)` of a flat index.
    #[inline]
    pub fn coords(&self, index: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [index % nx, (index / nx) % ny, index / (nx * ny)]
    }

    /// World position of node `(i, j, k)`: `origin + cell·(i, j, k)`, metres.
    #[inline]
    pub fn position_of(&self, i: usize, j: usize, k: usize) -> Point3<f32> {
        self.origin + Vector3::new(i as f32, j as f32, k as f32) * self.cell
    }

    /// [`GridGeometry::position_of`] the node of flat index `n` (x fastest).
    pub fn position_of_index(&self, n: usize) -> Point3<f32> {
        let [nx, ny, _] = self.dims;
        self.position_of(n % nx, (n / nx) % ny, n / (nx * ny))
    }

    /// The closed box spanned by the nodes, `[origin, origin + cell·(dims − 1)]`.
    pub fn bounds(&self) -> Aabb {
        let last = self.position_of(self.dims[0] - 1, self.dims[1] - 1, self.dims[2] - 1);
        Aabb::new(self.origin, last)
    }

    /// Whether `p` lies in the grid's closed box (false for NaN coordinates).
    #[inline]
    pub fn contains(&self, p: &Point3<f32>) -> bool {
        self.locate(p).is_some()
    }

    /// Length of the box diagonal, metres: an upper bound on any distance inside the grid.
    pub fn diagonal(&self) -> f32 {
        self.bounds().extent().norm()
    }

    /// The cell holding `p` (its lowest node) and `p`'s fractional position in it, in `[0, 1]`.
    /// On the far faces the last cell is used with fraction 1, so no index is ever clamped from
    /// outside the grid.
    #[inline]
    pub(crate) fn locate(&self, p: &Point3<f32>) -> Option<([usize; 3], [f32; 3])> {
        let mut base = [0usize; 3];
        let mut frac = [0f32; 3];
        for a in 0..3 {
            let u = (p[a] - self.origin[a]) / self.cell;
            let max = (self.dims[a] - 1) as f32;
            // Written so that NaN fails the test.
            if !(u >= 0.0 && u <= max) {
                return None;
            }
            let i = (u.floor() as usize).min(self.dims[a] - 2);
            base[a] = i;
            frac[a] = u - i as f32;
        }
        Some((base, frac))
    }

    /// Trilinear interpolation of node values `data` (laid out by this geometry) at `p`.
    #[inline]
    pub fn trilinear(&self, data: &[f32], p: &Point3<f32>) -> GridQuery<f32> {
        debug_assert_eq!(data.len(), self.len());
        let Some(([i, j, k], [tx, ty, tz])) = self.locate(p) else {
            return GridQuery::OutOfGrid;
        };
        let c = self.corners(data, i, j, k);
        let x00 = c[0] + (c[1] - c[0]) * tx;
        let x10 = c[2] + (c[3] - c[2]) * tx;
        let x01 = c[4] + (c[5] - c[4]) * tx;
        let x11 = c[6] + (c[7] - c[6]) * tx;
        let y0 = x00 + (x10 - x00) * ty;
        let y1 = x01 + (x11 - x01) * ty;
        GridQuery::InGrid(y0 + (y1 - y0) * tz)
    }

    /// The least of the 8 node values of the cell holding `p`.
    pub fn cell_min(&self, data: &[f32], p: &Point3<f32>) -> GridQuery<f32> {
        let Some(([i, j, k], _)) = self.locate(p) else {
            return GridQuery::OutOfGrid;
        };
        GridQuery::InGrid(self.corners(data, i, j, k).into_iter().fold(f32::INFINITY, f32::min))
    }

    /// Gradient (per metre) of the trilinear interpolant of `data` at `p`.
    pub fn trilinear_gradient(&self, data: &[f32], p: &Point3<f32>) -> GridQuery<Vector3<f32>> {
        let Some(([i, j, k], [tx, ty, tz])) = self.locate(p) else {
            return GridQuery::OutOfGrid;
        };
        let c = self.corners(data, i, j, k);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        // d/dx: x-differences of the four x-edges, blended in y and z; likewise for y and z.
        let dx = lerp(lerp(c[1] - c[0], c[3] - c[2], ty), lerp(c[5] - c[4], c[7] - c[6], ty), tz);
        let dy = lerp(lerp(c[2] - c[0], c[3] - c[1], tx), lerp(c[6] - c[4], c[7] - c[5], tx), tz);
        let dz = lerp(lerp(c[4] - c[0], c[5] - c[1], tx), lerp(c[6] - c[2], c[7] - c[3], tx), ty);
        GridQuery::InGrid(Vector3::new(dx, dy, dz) / self.cell)
    }

    /// The 8 node values of cell `(i, j, k)`, ordered `x + 2y + 4z`.
    #[inline]
    fn corners(&self, data: &[f32], i: usize, j: usize, k: usize) -> [f32; 8] {
        let sx = 1;
        let sy = self.dims[0];
        let sz = self.dims[0] * self.dims[1];
        let b = self.index(i, j, k);
        [
            data[b],
            data[b + sx],
            data[b + sy],
            data[b + sy + sx],
            data[b + sz],
            data[b + sz + sx],
            data[b + sz + sy],
            data[b + sz + sy + sx],
        ]
    }

    /// Fill `data` (one value per node) with `f(node position)`, in parallel over z-slices.
    pub(crate) fn fill_par<T: Send>(&self, data: &mut [T], f: impl Fn(usize, usize, usize) -> T + Sync) {
        let [nx, ny, _] = self.dims;
        data.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slice)| {
            for j in 0..ny {
                for i in 0..nx {
                    slice[i + nx * j] = f(i, j, k);
                }
            }
        });
    }
}

/// Nodes per batch of [`ScalarGrid::sample_batched`].
pub const SAMPLE_BATCH: usize = 4096;

/// A scalar field sampled at the nodes of a [`GridGeometry`]: an analytic SDF, a NeRF density, ...
///
/// `data[i + nx·(j + ny·k)]` is the value at `origin + cell·(i, j, k)` (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct ScalarGrid {
    pub geometry: GridGeometry,
    /// One value per node, x fastest: `[nz, ny, nx]` in row-major terms.
    pub data: Vec<f32>,
}

impl ScalarGrid {
    /// Sample `f` at every node of the lattice covering `bounds` at `cells_per_metre`
    /// (see [`GridGeometry::covering`]), in parallel over z-slices.
    ///
    /// Panics if `cells_per_metre` is not finite and positive.
    pub fn sample(bounds: &Aabb, cells_per_metre: f32, f: impl Fn(Point3<f32>) -> f32 + Sync) -> ScalarGrid {
        let geometry =
            GridGeometry::covering(bounds, cells_per_metre).unwrap_or_else(|e| panic!("ScalarGrid::sample: {e}"));
        Self::sample_geometry(geometry, f)
    }

    /// Sample `f` at every node of `geometry`, in parallel over z-slices.
    pub fn sample_geometry(geometry: GridGeometry, f: impl Fn(Point3<f32>) -> f32 + Sync) -> ScalarGrid {
        let mut data = vec![0f32; geometry.len()];
        geometry.fill_par(&mut data, |i, j, k| f(geometry.position_of(i, j, k)));
        ScalarGrid { geometry, data }
    }

    /// Sample a batched field at every node of `geometry`: `f(points, out)` fills `out[i]` with
    /// the value at `points[i]` (`[n, 3]` metres, world frame), for batches of at most
    /// [`SAMPLE_BATCH`] nodes in storage order, evaluated in parallel (rayon). A batch's points
    /// and its place in `data` do not depend on scheduling, so the result is deterministic.
    /// Suited to fields that are cheaper per batch than per point, such as a NeRF's density.
    pub fn sample_batched(geometry: GridGeometry, f: impl Fn(&[Point3<f32>], &mut [f32]) + Sync) -> ScalarGrid {
        let mut data = vec![0f32; geometry.len()];
        data.par_chunks_mut(SAMPLE_BATCH).enumerate().for_each_init(
            || Vec::with_capacity(SAMPLE_BATCH),
            |points: &mut Vec<Point3<f32>>, (b, out)| {
                points.clear();
                points.extend((b * SAMPLE_BATCH..b * SAMPLE_BATCH + out.len()).map(|idx| {
                    let [i, j, k] = geometry.coords(idx);
                    geometry.position_of(i, j, k)
                }));
                f(points, out);
            },
        );
        ScalarGrid { geometry, data }
    }

    /// A grid from existing node values; `data.len()` must equal `geometry.len()`.
    pub fn from_data(geometry: GridGeometry, data: Vec<f32>) -> Result<Self, CollisionError> {
        check_len(&geometry, data.len())?;
        Ok(Self { geometry, data })
    }

    pub fn dims(&self) -> [usize; 3] {
        self.geometry.dims
    }

    /// Flat index of node `(i, j, k)`.
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        self.geometry.index(i, j, k)
    }

    /// World position of node `(i, j, k)`, metres.
    pub fn position_of(&self, i: usize, j: usize, k: usize) -> Point3<f32> {
        self.geometry.position_of(i, j, k)
    }

    /// Value at node `(i, j, k)`.
    pub fn get(&self, i: usize, j: usize, k: usize) -> f32 {
        self.data[self.geometry.index(i, j, k)]
    }

    /// Trilinearly interpolated value at `p`.
    pub fn value_at(&self, p: Point3<f32>) -> GridQuery<f32> {
        self.geometry.trilinear(&self.data, &p)
    }
}

/// `v` is finite and strictly positive (as [`nerfsv_scene::validate::positive`], with the value
/// shown as the `f32` it is).
pub(crate) fn positive(field: &str, v: f32) -> Result<(), InvalidValue> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(InvalidValue::new(field, "must be a positive number", v))
    }
}

pub(crate) fn check_len(geometry: &GridGeometry, len: usize) -> Result<(), CollisionError> {
    if len != geometry.len() {
        return Err(CollisionError::DataLength { expected: geometry.len(), found: len });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covering_lattice_has_one_node_more_than_intervals_and_reaches_the_far_corner() {
        let b = Aabb::new(Point3::new(-1.9, -1.9, 0.0), Point3::new(1.9, 1.9, 1.2));
        let g = GridGeometry::covering(&b, 40.0).unwrap();
        assert_eq!(g.dims, [153, 153, 49]);
        let far = g.position_of(152, 152, 48);
        assert!((far - b.max).norm() < 1e-4, "{far:?}");
    }

    #[test]
    fn trilinear_reproduces_an_affine_field_and_its_gradient_exactly() {
        let b = Aabb::new(Point3::new(-0.3, 0.1, -0.2), Point3::new(0.4, 0.5, 0.3));
        let f = |p: Point3<f32>| 0.5 * p.x - 2.0 * p.y + 3.0 * p.z + 1.0;
        let g = ScalarGrid::sample(&b, 20.0, f);
        for p in [Point3::new(0.013, 0.333, 0.07), Point3::new(-0.3, 0.1, -0.2)] {
            let v = g.value_at(p).in_grid().unwrap();
            assert!((v - f(p)).abs() < 1e-5, "{v} vs {}", f(p));
            let d = g.geometry.trilinear_gradient(&g.data, &p).in_grid().unwrap();
            assert!((d - Vector3::new(0.5, -2.0, 3.0)).norm() < 1e-3, "{d:?}");
        }
    }

    #[test]
    fn points_off_the_grid_are_reported_not_clamped() {
        let g = ScalarGrid::sample(&Aabb::cube(0.5), 10.0, |p| p.x);
        let far = g.geometry.bounds().max;
        assert!(g.value_at(far).in_grid().is_some());
        assert!(g.value_at(far + Vector3::new(1e-3, 0.0, 0.0)).is_out_of_grid());
        assert!(g.value_at(Point3::new(0.0, -0.5001, 0.0)).is_out_of_grid());
        assert!(g.value_at(Point3::new(f32::NAN, 0.0, 0.0)).is_out_of_grid());
    }

    #[test]
    fn batched_sampling_equals_per_point_sampling_across_batch_boundaries() {
        // 23 × 19 × 21 = 9177 nodes: two full batches and a partial one.
        let g = GridGeometry::new(Point3::new(-0.3, 0.2, 0.1), 0.05, [23, 19, 21]).unwrap();
        let f = |p: Point3<f32>| p.x * 3.0 - p.y * p.z + 0.25;
        let batched = ScalarGrid::sample_batched(g, |pts, out| {
            assert!(pts.len() <= SAMPLE_BATCH && pts.len() == out.len());
            for (o, p) in out.iter_mut().zip(pts) {
                *o = f(Point3::from(*p));
            }
        });
        assert_eq!(batched, ScalarGrid::sample_geometry(g, f));
    }

    #[test]
    fn invalid_geometry_names_the_field_and_the_value() {
        let e = GridGeometry::new(Point3::origin(), -0.1, [2, 2, 2]).unwrap_err();
        assert_eq!(e.to_string(), "cell: must be a positive number, found -0.1");
        let e = GridGeometry::new(Point3::origin(), 0.1, [2, 1, 2]).unwrap_err();
        assert_eq!(e.to_string(), "dims: must have at least 2 nodes on every axis, found [2, 1, 2]");
        let e = GridGeometry::covering(&Aabb::cube(1.0), f32::NAN).unwrap_err();
        assert!(matches!(&e, CollisionError::Invalid(v) if v.field == "cells_per_metre"), "{e:?}");
    }

    #[test]
    fn node_index_is_x_fastest() {
        let g = GridGeometry::new(Point3::origin(), 1.0, [4, 3, 2]).unwrap();
        assert_eq!(g.index(1, 0, 0), 1);
        assert_eq!(g.index(0, 1, 0), 4);
        assert_eq!(g.index(0, 0, 1), 12);
        assert_eq!(g.coords(g.index(3, 2, 1)), [3, 2, 1]);
    }
}
