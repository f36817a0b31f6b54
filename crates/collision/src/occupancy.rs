//! The collision map: which grid nodes are on or inside the surface.

use crate::classify::{axis_crossings, classify_nodes};
use crate::grid::{check_len, GridGeometry, ScalarGrid};
use crate::CollisionError;

/// One flag per grid node (same layout as [`ScalarGrid`]): `true` = occupied (in collision).
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    pub geometry: GridGeometry,
    /// One flag per node, x fastest.
    pub data: Vec<bool>,
}

impl OccupancyGrid {
    /// The collision map of the `iso` level set of `grid` (see [`crate::marching_cubes`] for
    /// `inside_is_below`): a node is occupied when it is **inside** (by
    /// [`classify_nodes`]: strictly below/above `iso`, exactly at `iso` with no strictly outside
    /// neighbour, or in an enclosed void), or when it is **touched** by the surface: along one of
    /// its six grid edges to an inside neighbour, the marching-cubes vertex lies within half a
    /// cell of it. So the map is the solid dilated by at most half a cell along the grid axes:
    /// every marching-cubes vertex is within half a cell of an occupied node, and no node farther
    /// than half a cell (along an axis) from the surface is marked.
    pub fn from_field(grid: &ScalarGrid, iso: f32, inside_is_below: bool) -> Self {
        let g = grid.geometry;
        let inside = classify_nodes(grid, iso, inside_is_below);
        let mut data = vec![false; g.len()];
        g.fill_par(&mut data, |i, j, k| {
            inside[g.index(i, j, k)] || axis_crossings(grid, &inside, iso, [i, j, k]).iter().any(|&(t, _)| t <= 0.5)
        });
        Self { geometry: g, data }
    }

    /// A map from existing flags; `data.len()` must equal `geometry.len()`.
    pub fn from_data(geometry: GridGeometry, data: Vec<bool>) -> Result<Self, CollisionError> {
        check_len(&geometry, data.len())?;
        Ok(Self { geometry, data })
    }

    pub fn dims(&self) -> [usize; 3] {
        self.geometry.dims
    }

    /// Whether node `(i, j, k)` is occupied.
    pub fn get(&self, i: usize, j: usize, k: usize) -> bool {
        self.data[self.geometry.index(i, j, k)]
    }

    /// Number of occupied nodes.
    pub fn occupied_count(&self) -> usize {
        self.data.iter().filter(|&&o| o).count()
    }

    /// Occupied nodes / all nodes.
    pub fn occupied_fraction(&self) -> f64 {
        self.occupied_count() as f64 / self.data.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn nodes_within_half_a_cell_of_a_plane_are_touched_and_farther_ones_are_free() {
        // Plane x = 0.3 + 0.4·cell (cell 0.1): inside below. Node x = 0.4 lies 0.6 cells
        // outside, node x = 0.3 lies 0.4 cells inside.
        let g = GridGeometry::new(Point3::origin(), 0.1, [8, 3, 3]).unwrap();
        let plane = 0.34f32;
        let field = ScalarGrid::sample_geometry(g, |p| p.x - plane);
        let occ = OccupancyGrid::from_field(&field, 0.0, true);
        let col: Vec<bool> = (0..8).map(|i| occ.get(i, 1, 1)).collect();
        assert_eq!(col, [true, true, true, true, false, false, false, false]);
        // Plane at 0.36: node 0.4 is 0.4 cells outside → touched.
        let field = ScalarGrid::sample_geometry(g, |p| p.x - 0.36);
        let occ = OccupancyGrid::from_field(&field, 0.0, true);
        let col: Vec<bool> = (0..8).map(|i| occ.get(i, 1, 1)).collect();
        assert_eq!(col, [true, true, true, true, true, false, false, false]);
        assert!((occ.occupied_fraction() - 5.0 / 8.0).abs() < 1e-12);
    }
}
