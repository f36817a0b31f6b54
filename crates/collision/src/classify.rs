//! Which grid nodes are inside the solid, and where the surface crosses a grid edge: the one rule
//! that marching cubes, the collision map and the signed field share, so that their surfaces agree.
//!
//! A node is **inside** when its value lies strictly on the solid side of `iso` (below it for a
//! signed distance, `inside_is_below = true`; above it for a density, `false`), with two
//! refinements:
//!
//! 1. **Exact iso.** A node whose value equals `iso` is inside when none of its 6 neighbours is
//!    strictly outside, else outside (it is on the surface). Where two solids touch along a grid
//!    plane — a stone standing on the ground, whose bottom face coincides with the ground's top
//!    face — the analytic distance of the union is exactly 0 on the whole contact plane although
//!    there is solid above and below; such nodes are inside.
//! 2. **Enclosed voids.** Outside nodes that are not 6-connected through outside nodes to the
//!    grid's border are inside. A NeRF's density is high only in a shell at an object's surface
//!    (nothing is seen inside a stone), so without this a stone would be hollow; on an analytic
//!    SDF of solids without cavities it changes nothing. The connected set is unique, so the
//!    result does not depend on the order of the flood fill.
//!
//! NaN values are outside.

use rayon::prelude::*;

use crate::grid::{GridGeometry, ScalarGrid};

/// Where a single value lies relative to `iso`.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Side {
    Inside,
    AtIso,
    /// Strictly outside (NaN included).
    Outside,
}

#[inline]
fn side(v: f32, iso: f32, inside_is_below: bool) -> Side {
    if v == iso {
        Side::AtIso
    } else if (inside_is_below && v < iso) || (!inside_is_below && v > iso) {
        Side::Inside
    } else {
        Side::Outside
    }
}

/// Calls `f` with the flat index of each of the (up to 6) axis neighbours of node `ijk`.
#[inline]
fn for_each_neighbour(g: &GridGeometry, ijk: [usize; 3], mut f: impl FnMut(usize)) {
    let idx = g.index(ijk[0], ijk[1], ijk[2]);
    let strides = [1, g.dims[0], g.dims[0] * g.dims[1]];
    for a in 0..3 {
        if ijk[a] > 0 {
            f(idx - strides[a]);
        }
        if ijk[a] + 1 < g.dims[a] {
            f(idx + strides[a]);
        }
    }
}

/// Inside (`true`) or outside for every node of `grid` (same layout), by the rule of the
/// [module docs](self): strictly on the solid side of `iso`; at exactly `iso` with no strictly
/// outside neighbour; or in an outside region enclosed away from the grid's border.
///
/// Parallel over z-slices, then one flood fill from the border (O(nodes)); deterministic.
pub fn classify_nodes(grid: &ScalarGrid, iso: f32, inside_is_below: bool) -> Vec<bool> {
    let g = grid.geometry;
    let data = &grid.data;
    let mut inside = vec![false; g.len()];
    g.fill_par(&mut inside, |i, j, k| match side(data[g.index(i, j, k)], iso, inside_is_below) {
        Side::Inside => true,
        Side::Outside => false,
        Side::AtIso => {
            let mut touches_outside = false;
            for_each_neighbour(&g, [i, j, k], |nb| {
                touches_outside |= side(data[nb], iso, inside_is_below) == Side::Outside;
            });
            !touches_outside
        }
    });
    fill_enclosed_voids(&g, &mut inside);
    inside
}

/// Marks as inside every outside node that no path of outside nodes (6-connected) joins to the
/// grid's border.
fn fill_enclosed_voids(g: &GridGeometry, inside: &mut [bool]) {
    let [nx, ny, nz] = g.dims;
    // Outside nodes reached from the border; they stay outside, every other node is inside.
    let mut reached = vec![false; g.len()];
    let mut stack: Vec<u32> = Vec::new();
    let mut seed = |idx: usize, reached: &mut [bool]| {
        if !inside[idx] && !reached[idx] {
            reached[idx] = true;
            stack.push(idx as u32);
        }
    };
    for k in 0..nz {
        for j in 0..ny {
            if k == 0 || k + 1 == nz || j == 0 || j + 1 == ny {
                for i in 0..nx {
                    seed(g.index(i, j, k), &mut reached);
                }
            } else {
                seed(g.index(0, j, k), &mut reached);
                seed(g.index(nx - 1, j, k), &mut reached);
            }
        }
    }
    while let Some(idx) = stack.pop() {
        for_each_neighbour(g, g.coords(idx as usize), |nb| {
            if !inside[nb] && !reached[nb] {
                reached[nb] = true;
                stack.push(nb as u32);
            }
        });
    }
    inside.par_iter_mut().zip(reached.par_iter()).for_each(|(v, &r)| *v = !r);
}

/// Where the `iso` level crosses the grid edge from a node of value `va` to one of value `vb`,
/// as a fraction `t ∈ [0, 1]` of the way from the first: the linear interpolation
/// `(iso − va) / (vb − va)`, clamped. When both values equal `iso` (two nodes on the surface
/// classified differently by the exact-iso rule) or are NaN, nothing locates the crossing and it
/// is put midway, `t = 0.5`. Marching cubes places its vertices, and the signed field its
/// surface points, by this one function.
#[inline]
pub fn crossing_parameter(va: f32, vb: f32, iso: f32) -> f32 {
    let t = (iso - va) / (vb - va);
    if t.is_nan() {
        0.5
    } else {
        t.clamp(0.0, 1.0)
    }
}

/// Per axis, the distance in cells from node `ijk` to the nearest surface crossing on its two
/// grid edges along that axis (`∞` if neither crosses) and the direction (±1) to it. An edge
/// crosses where the classification (`inside`, from [`classify_nodes`]) of its two nodes
/// differs; the crossing is placed by [`crossing_parameter`], as marching cubes places its vertex.
pub(crate) fn axis_crossings(grid: &ScalarGrid, inside: &[bool], iso: f32, ijk: [usize; 3]) -> [(f32, f32); 3] {
    let g = &grid.geometry;
    let idx = g.index(ijk[0], ijk[1], ijk[2]);
    let v0 = grid.data[idx];
    let in0 = inside[idx];
    let strides = [1, g.dims[0], g.dims[0] * g.dims[1]];
    let mut out = [(f32::INFINITY, 0.0); 3];
    for a in 0..3 {
        let mut consider = |nb: usize, dir: f32| {
            if inside[nb] != in0 {
                let t = crossing_parameter(v0, grid.data[nb], iso);
                if t < out[a].0 {
                    out[a] = (t, dir);
                }
            }
        };
        if ijk[a] > 0 {
            consider(idx - strides[a], -1.0);
        }
        if ijk[a] + 1 < g.dims[a] {
            consider(idx + strides[a], 1.0);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn contact_plane_of_two_touching_boxes_is_inside_and_their_outer_faces_are_outside() {
        let grid = crate::testutil::touching_boxes();
        let g = grid.geometry;
        let inside = classify_nodes(&grid, 0.0, true);
        let at = |i, j, k| inside[g.index(i, j, k)];
        // The contact plane z = 4 has value 0 everywhere on the boxes' common face.
        for (i, j) in [(3, 3), (3, 4), (4, 3), (4, 4)] {
            assert_eq!(grid.get(i, j, 4), 0.0);
            assert!(at(i, j, 4), "contact node ({i}, {j}, 4) must be inside");
        }
        // Nodes on the outer faces (value 0, a strictly outside neighbour) stay outside.
        for (i, j, k) in [(2, 3, 4), (5, 4, 4), (3, 2, 2), (3, 3, 1), (4, 4, 7)] {
            assert_eq!(grid.get(i, j, k), 0.0);
            assert!(!at(i, j, k), "surface node ({i}, {j}, {k}) must be outside");
        }
        assert!(at(3, 3, 2) && at(4, 4, 6) && !at(0, 0, 0));
        // Inside is exactly the interior lattice {3, 4}² × {2..6}.
        assert_eq!(inside.iter().filter(|&&v| v).count(), 2 * 2 * 5);
    }

    #[test]
    fn crossing_between_two_nodes_exactly_at_iso_is_midway() {
        assert_eq!(crossing_parameter(0.0, 0.0, 0.0), 0.5);
        assert_eq!(crossing_parameter(f32::NAN, 1.0, 0.0), 0.5);
        assert_eq!(crossing_parameter(0.0, -1.0, 0.0), 0.0);
        assert_eq!(crossing_parameter(-1.0, 0.0, 0.0), 1.0);
        assert_eq!(crossing_parameter(-1.0, 3.0, 0.0), 0.25);
        assert_eq!(crossing_parameter(2.0, 4.0, 3.0), 0.5);
    }

    #[test]
    fn an_enclosed_void_is_inside_and_a_void_open_to_the_border_is_not() {
        // A hollow cube shell (density 1 on the shell, 0 elsewhere) with a 1-node cavity.
        let g = GridGeometry::new(Point3::origin(), 1.0, [7, 7, 7]).unwrap();
        let shell = |i: usize, j: usize, k: usize| {
            let r = [i, j, k].map(|c| (c as i32 - 3).abs()).into_iter().max().unwrap();
            (r == 1 || r == 2) as u8 as f32
        };
        let mut data = vec![0f32; g.len()];
        for k in 0..7 {
            for j in 0..7 {
                for i in 0..7 {
                    data[g.index(i, j, k)] = shell(i, j, k);
                }
            }
        }
        let closed = ScalarGrid::from_data(g, data.clone()).unwrap();
        let inside = classify_nodes(&closed, 0.5, false);
        assert!(inside[g.index(3, 3, 3)], "the cavity is enclosed");
        assert_eq!(inside.iter().filter(|&&v| v).count(), 5 * 5 * 5);
        // A hole through the shell to the border (along +x) opens the cavity.
        for i in 4..7 {
            data[g.index(i, 3, 3)] = 0.0;
        }
        let open = ScalarGrid::from_data(g, data).unwrap();
        let inside = classify_nodes(&open, 0.5, false);
        assert!(!inside[g.index(3, 3, 3)]);
        assert_eq!(inside.iter().filter(|&&v| v).count(), 5 * 5 * 5 - 3);
    }
}
