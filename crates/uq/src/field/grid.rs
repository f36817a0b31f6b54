//! The field's grid: its geometry over a model's box, the positions of its nodes, and trilinear
//! values at a point.

use nalgebra::Point3;
use nerfsv_collision::GridGeometry;
use nerfsv_nerf::Nerf;
use nerfsv_scene::Aabb;

use crate::UqError;

/// The grid of a field for `nerf`: its box at `cells_per_metre`. Errors: a grid that cannot
/// be made, or whose build would exceed the memory budget
/// ([`nerfsv_scene::validate::MemoryBudget`], key `uq.field_cells_per_metre`).
pub fn field_geometry(nerf: &Nerf, cells_per_metre: f64) -> Result<GridGeometry, UqError> {
    let c = &nerf.config;
    let bounds = Aabb::new(Point3::from(c.aabb_min), Point3::from(c.aabb_max));
    let geometry = GridGeometry::covering(&bounds, cells_per_metre as f32)
        .map_err(|e| UqError::FieldGrid { message: e.to_string() })?;
    // Per node: density, variance, weight, lookup (f32), the GA sums (f64) and the position.
    let bytes = nerfsv_scene::validate::bytes_for(geometry.len() as u64, BYTES_PER_NODE);
    nerfsv_scene::validate::MemoryBudget::current().check("uq.field_cells_per_metre", bytes)?;
    Ok(geometry)
}

/// Memory a field needs per node while it is built, bytes (for the memory budget).
const BYTES_PER_NODE: u64 = 4 * 4 + 2 * 8 + 12 + 2;

pub(super) fn node_positions(g: &GridGeometry) -> Vec<Point3<f32>> {
    (0..g.len())
        .map(|n| {
            let [i, j, k] = g.coords(n);
            g.position_of(i, j, k)
        })
        .collect()
}

/// The cell of `p` (lowest node's flat index, the node strides) and its 8 trilinear
/// coefficients ordered `x + 2y + 4z`; `None` outside the grid.
#[inline]
pub(super) fn cell_of(g: &GridGeometry, p: [f32; 3]) -> Option<([usize; 8], [f32; 8])> {
    let mut base = [0usize; 3];
    let mut f = [0f32; 3];
    for a in 0..3 {
        let max = (g.dims[a] - 1) as f32;
        // A thousandth of a cell of slack: samples on the box's faces (the grid's bounds) stay in.
        let u = (p[a] - g.origin[a]) / g.cell;
        if !(u >= -1e-3 && u <= max + 1e-3) {
            return None;
        }
        let u = u.clamp(0.0, max);
        let i = (u.floor() as usize).min(g.dims[a] - 2);
        base[a] = i;
        f[a] = u - i as f32;
    }
    let (sy, sz) = (g.dims[0], g.dims[0] * g.dims[1]);
    let b = base[0] + sy * base[1] + sz * base[2];
    let mut idx = [0usize; 8];
    let mut w = [0f32; 8];
    for c in 0..8 {
        let (x, y, z) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        idx[c] = b + x + sy * y + sz * z;
        w[c] = (if x == 1 { f[0] } else { 1.0 - f[0] })
            * (if y == 1 { f[1] } else { 1.0 - f[1] })
            * (if z == 1 { f[2] } else { 1.0 - f[2] });
    }
    Some((idx, w))
}

/// Trilinear value of `data` at a cell.
#[inline]
pub(super) fn interp(data: &[f32], idx: &[usize; 8], w: &[f32; 8]) -> f32 {
    (0..8).map(|c| data[idx[c]] * w[c]).sum()
}

/// Trilinear value over the corners whose value is not NaN, renormalised; `None` when none is.
#[inline]
pub(super) fn interp_masked(data: &[f32], idx: &[usize; 8], w: &[f32; 8]) -> Option<f32> {
    let (mut s, mut ws) = (0.0f32, 0.0f32);
    for c in 0..8 {
        let v = data[idx[c]];
        if !v.is_nan() {
            s += v * w[c];
            ws += w[c];
        }
    }
    (ws > 0.0).then(|| s / ws)
}
