//! Marching cubes (Lorensen & Cline 1987, Bourke's tables) and triangle-mesh export.

use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::atomic::write_atomically;
use crate::classify::{classify_nodes, crossing_parameter};
use crate::grid::ScalarGrid;
use crate::mc_tables::{CORNERS, EDGE_GRID, TRI_TABLE};
use crate::CollisionError;

/// An indexed triangle mesh in metres (world frame). Triangles are wound counter-clockwise seen
/// from outside, so `(b − a) × (c − a)` points from inside to outside.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// vertices: `[n_vertices]` positions, metres.
    pub vertices: Vec<Point3<f32>>,
    /// triangles: `[n_triangles]` vertex-index triples.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    fn corners(&self, t: &[u32; 3]) -> [Vector3<f64>; 3] {
        t.map(|i| self.vertices[i as usize].coords.cast::<f64>())
    }

    /// Total surface area, m². The same bits at any thread count (see `Mesh::sum_over`).
    pub fn area(&self) -> f64 {
        self.sum_over(|[a, b, c]| 0.5 * (b - a).cross(&(c - a)).norm())
    }

    /// `Σ f(corners)` over the triangles: chunks of a fixed size summed in parallel, then the
    /// chunks' sums in order, so that the additions (and the result's last bits) do not depend
    /// on how rayon splits the work (a plain parallel `sum()` differed by one ulp between 1 and
    /// 2 threads).
    fn sum_over(&self, f: impl Fn([Vector3<f64>; 3]) -> f64 + Sync) -> f64 {
        const CHUNK: usize = 4096;
        let partial: Vec<f64> =
            self.triangles.par_chunks(CHUNK).map(|ts| ts.iter().map(|t| f(self.corners(t))).sum()).collect();
        partial.iter().sum()
    }

    /// Signed enclosed volume, m³, by the divergence theorem: `Σ a·(b × c) / 6`. Positive for a
    /// closed mesh wound outward.
    pub fn signed_volume(&self) -> f64 {
        self.sum_over(|[a, b, c]| a.dot(&b.cross(&c)) / 6.0)
    }

    /// Whether the mesh is closed and consistently oriented: every directed edge occurs exactly
    /// once and its reverse occurs exactly once (so every edge is shared by exactly 2 triangles).
    pub fn is_closed(&self) -> bool {
        let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.triangles {
            for e in 0..3 {
                *directed.entry((t[e], t[(e + 1) % 3])).or_default() += 1;
            }
        }
        directed.iter().all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
    }

    /// Write a PLY file (`binary_little_endian 1.0` or `ascii 1.0`): `float x y z` per vertex and
    /// `list uchar int vertex_indices` per face. Written to a temporary file, then renamed.
    pub fn write_ply(&self, path: impl AsRef<Path>, binary: bool) -> Result<(), CollisionError> {
        write_atomically(path.as_ref(), |w| {
            let format = if binary { "binary_little_endian" } else { "ascii" };
            write!(
                w,
                "ply\nformat {format} 1.0\ncomment nerfsv-collision marching cubes, metres, z up\n\
                 element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
                 element face {}\nproperty list uchar int vertex_indices\nend_header\n",
                self.vertices.len(),
                self.triangles.len()
            )?;
            if binary {
                for v in &self.vertices {
                    for c in v.iter() {
                        w.write_all(&c.to_le_bytes())?;
                    }
                }
                for t in &self.triangles {
                    w.write_all(&[3u8])?;
                    for &i in t {
                        w.write_all(&(i as i32).to_le_bytes())?;
                    }
                }
            } else {
                for v in &self.vertices {
                    writeln!(w, "{} {} {}", v.x, v.y, v.z)?;
                }
                for t in &self.triangles {
                    writeln!(w, "3 {} {} {}", t[0], t[1], t[2])?;
                }
            }
            Ok(())
        })
    }

    /// Write a Wavefront OBJ file (`v x y z` and 1-based `f a b c`), atomically.
    pub fn write_obj(&self, path: impl AsRef<Path>) -> Result<(), CollisionError> {
        write_atomically(path.as_ref(), |w| {
            writeln!(w, "# nerfsv-collision marching cubes, metres, z up")?;
            for v in &self.vertices {
                writeln!(w, "v {} {} {}", v.x, v.y, v.z)?;
            }
            for t in &self.triangles {
                writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
            }
            Ok(())
        })
    }
}

/// No vertex on this grid edge (its nodes are classified alike).
const NO_VERTEX: u32 = u32::MAX;
/// The edge's crossing lies exactly on its first node: use that node's vertex.
const AT_START: u32 = u32::MAX - 1;
/// The edge's crossing lies exactly on its second node: use that node's vertex.
const AT_END: u32 = u32::MAX - 2;

/// Where the surface crosses the grid edge from node `a` (lattice coordinate `ia` along `axis`)
/// to node `a + 1` along `axis`: `None` if both are classified alike, else the lattice
/// coordinate `u ∈ [ia, ia + 1]` of the crossing along that axis ([`crossing_parameter`]).
/// Written once so that both nodes of an edge agree on whether the crossing sits exactly on one
/// of them (`u == ia` or `u == ia + 1`, which also catches a `t` that rounds onto a node).
#[inline]
fn edge_crossing(data: &[f32], inside: &[bool], iso: f32, a: usize, b: usize, ia: usize) -> Option<f32> {
    (inside[a] != inside[b]).then(|| ia as f32 + crossing_parameter(data[a], data[b], iso))
}

/// Extract the `iso` level set of `grid` by marching cubes.
///
/// `inside_is_below`: `true` for a signed distance (inside where `value < iso`), `false` for a
/// density (inside where `value > iso`, e.g. a NeRF σ at a threshold). Nodes are classified by
/// [`classify_nodes`]: a value exactly at `iso` is inside only where no neighbour is strictly
/// outside, and enclosed voids are filled, so a hollow density shell gives only its outer
/// surface. One vertex is made per grid edge whose end nodes differ, at [`crossing_parameter`]
/// along it, and shared by every triangle that uses it; a crossing that falls exactly on a node
/// gives that node's single vertex, shared by all its edges; triangles that this leaves with a
/// repeated vertex (zero area) are dropped, as are pairs on the same three vertices with opposite
/// winding (a gap of zero thickness between two solids). So no triangle is degenerate or
/// doubled; where two solids touch only at such nodes the surface is pinched there (every
/// directed edge still occurs as often as its reverse, but [`Mesh::is_closed`] is false).
/// Triangles are wound so their normals point from inside to outside. A surface that reaches
/// the grid's border is left open there.
///
/// Parallel over z-slices; the output order is deterministic.
pub fn marching_cubes(grid: &ScalarGrid, iso: f32, inside_is_below: bool) -> Mesh {
    marching_cubes_classified(grid, iso, &classify_nodes(grid, iso, inside_is_below))
}

/// [`marching_cubes`] with the node classification (from [`classify_nodes`]) at hand.
pub(crate) fn marching_cubes_classified(grid: &ScalarGrid, iso: f32, inside: &[bool]) -> Mesh {
    let placed = place_vertices(grid, iso, inside);
    let triangles = triangulate(grid, inside, &placed);
    let triangles = drop_opposite_pairs(triangles, &placed.on_node);
    Mesh { vertices: placed.vertices, triangles }
}

/// Where marching cubes put its vertices: per node, its own vertex (or [`NO_VERTEX`]); per axis
/// and node, the vertex on the grid edge leaving the node along that axis ([`AT_START`] /
/// [`AT_END`]: an end node's own vertex); the vertices, and which of them sit on a node.
struct PlacedVertices {
    node_vertex: Vec<u32>,
    edge_vertex: [Vec<u32>; 3],
    vertices: Vec<Point3<f32>>,
    on_node: Vec<bool>,
}

/// Pass 1 of [`marching_cubes_classified`].
fn place_vertices(grid: &ScalarGrid, iso: f32, inside: &[bool]) -> PlacedVertices {
    let g = &grid.geometry;
    let [nx, ny, nz] = g.dims;
    let slice = nx * ny;
    let data = &grid.data;
    let strides = [1, nx, slice];
    let crossing = |a: usize, axis: usize, ia: usize| edge_crossing(data, inside, iso, a, a + strides[axis], ia);

    // Pass 1, per z-slice: each node's own vertex (if a crossing on one of its 6 edges lies
    // exactly on it), then per axis the vertex on the grid edge leaving the node (if it
    // crosses): a new vertex strictly between the nodes, or a reference to an end node's vertex.
    // Vertices are numbered within the node's z-slice.
    let n = g.len();
    let mut node_vertex = vec![NO_VERTEX; n];
    let mut edge_vertex = [vec![NO_VERTEX; n], vec![NO_VERTEX; n], vec![NO_VERTEX; n]];
    let [ex, ey, ez] = &mut edge_vertex;
    let per_slice: Vec<Vec<Point3<f32>>> = node_vertex
        .par_chunks_mut(slice)
        .zip(ex.par_chunks_mut(slice))
        .zip(ey.par_chunks_mut(slice))
        .zip(ez.par_chunks_mut(slice))
        .enumerate()
        .map(|(k, (((sn, sx), sy), sz))| {
            let mut verts = Vec::new();
            let out = [sx, sy, sz];
            for j in 0..ny {
                for i in 0..nx {
                    let idx = g.index(i, j, k);
                    let ijk = [i, j, k];
                    // Crossing (lattice coordinate) on each edge leaving the node.
                    let leaving: [Option<f32>; 3] = std::array::from_fn(|axis| {
                        let c = ijk[axis];
                        (c + 1 < g.dims[axis]).then(|| crossing(idx, axis, c)).flatten()
                    });
                    let on_node = (0..3).any(|axis| {
                        let c = ijk[axis];
                        leaving[axis] == Some(c as f32)
                            || (c > 0 && crossing(idx - strides[axis], axis, c - 1) == Some(c as f32))
                    });
                    if on_node {
                        sn[i + nx * j] = verts.len() as u32;
                        verts.push(g.position_of(i, j, k));
                    }
                    for axis in 0..3 {
                        let c = ijk[axis];
                        let Some(u_axis) = leaving[axis] else { continue };
                        out[axis][i + nx * j] = if u_axis == c as f32 {
                            AT_START
                        } else if u_axis == (c + 1) as f32 {
                            AT_END
                        } else {
                            let mut u = Vector3::new(i as f32, j as f32, k as f32);
                            u[axis] = u_axis;
                            verts.push(g.origin + u * g.cell);
                            verts.len() as u32 - 1
                        };
                    }
                }
            }
            verts
        })
        .collect();
    let mut offsets = Vec::with_capacity(nz);
    let mut total = 0u32;
    for v in &per_slice {
        offsets.push(total);
        total += v.len() as u32;
    }
    for arr in std::iter::once(&mut node_vertex).chain(edge_vertex.iter_mut()) {
        arr.par_chunks_mut(slice).zip(offsets.par_iter()).for_each(|(s, &off)| {
            for v in s.iter_mut().filter(|v| **v < AT_END) {
                *v += off;
            }
        });
    }
    let vertices: Vec<Point3<f32>> = per_slice.into_iter().flatten().collect();
    let mut on_node = vec![false; vertices.len()];
    for &v in node_vertex.iter().filter(|&&v| v != NO_VERTEX) {
        on_node[v as usize] = true;
    }
    PlacedVertices { node_vertex, edge_vertex, vertices, on_node }
}

/// Pass 2 of [`marching_cubes_classified`]: the triangles of every cube, by slabs of cubes.
fn triangulate(grid: &ScalarGrid, inside: &[bool], placed: &PlacedVertices) -> Vec<[u32; 3]> {
    let g = &grid.geometry;
    let [nx, ny, nz] = g.dims;
    let slice = nx * ny;
    let strides = [1, nx, slice];
    let (node_vertex, edge_vertex) = (&placed.node_vertex, &placed.edge_vertex);
    // Pass 2: triangles per slab of cubes between z-slices k and k+1.
    (0..nz - 1)
        .into_par_iter()
        .map(|k| {
            let mut tris = Vec::new();
            for j in 0..ny - 1 {
                for i in 0..nx - 1 {
                    let base = g.index(i, j, k);
                    let mut case = 0usize;
                    for (c, o) in CORNERS.iter().enumerate() {
                        if inside[base + o[0] + nx * o[1] + slice * o[2]] {
                            case |= 1 << c;
                        }
                    }
                    if case == 0 || case == 255 {
                        continue;
                    }
                    let vertex_of = |e: i8| {
                        let (o, axis) = EDGE_GRID[e as usize];
                        let a = base + o[0] + nx * o[1] + slice * o[2];
                        let v = match edge_vertex[axis][a] {
                            AT_START => node_vertex[a],
                            AT_END => node_vertex[a + strides[axis]],
                            v => v,
                        };
                        debug_assert!(v < AT_END);
                        v
                    };
                    for t in TRI_TABLE[case].chunks_exact(3).take_while(|t| t[0] >= 0) {
                        let tri = [vertex_of(t[0]), vertex_of(t[1]), vertex_of(t[2])];
                        // Two corners welded onto one node: the triangle has no area.
                        if tri[0] != tri[1] && tri[1] != tri[2] && tri[0] != tri[2] {
                            tris.push(tri);
                        }
                    }
                }
            }
            tris
        })
        .flatten()
        .collect()
}

/// Drops pairs of triangles made of the same three vertices with opposite winding. They arise
/// only where a node exactly at iso lies between solid above and below it (a gap of zero
/// thickness, e.g. float noise of 1e-9 m between a stone's bottom and the ground): the cube on
/// each side emits the same face through the node's welded vertices, and together they bound
/// no volume. Only triangles with a vertex on a node (`on_node`) can pair. Of `m` matching
/// pairs, the first `m` triangles of each winding (in output order) go, so the result is
/// deterministic.
fn drop_opposite_pairs(triangles: Vec<[u32; 3]>, on_node: &[bool]) -> Vec<[u32; 3]> {
    // Per candidate: its vertex set (sorted), its winding relative to that order, its index.
    let mut faces: Vec<([u32; 3], bool, u32)> = triangles
        .par_iter()
        .enumerate()
        .filter(|(_, t)| t.iter().any(|&v| on_node[v as usize]))
        .map(|(n, t)| {
            // Rotate so the smallest index leads; the winding is whether the other two ascend.
            let r = (0..3).min_by_key(|&i| t[i]).unwrap_or(0);
            let (a, b, c) = (t[r], t[(r + 1) % 3], t[(r + 2) % 3]);
            ([a, b.min(c), b.max(c)], b < c, n as u32)
        })
        .collect();
    faces.par_sort_unstable();
    let mut dropped = vec![false; triangles.len()];
    let mut any = false;
    for group in faces.chunk_by(|x, y| x.0 == y.0) {
        // Sorted by winding, then index: `false` windings first.
        let neg = group.iter().take_while(|f| !f.1).count();
        let m = neg.min(group.len() - neg);
        for f in group[..m].iter().chain(&group[neg..neg + m]) {
            dropped[f.2 as usize] = true;
            any = true;
        }
    }
    if !any {
        return triangles;
    }
    triangles.into_iter().zip(dropped).filter(|&(_, d)| !d).map(|(t, _)| t).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerfsv_scene::Aabb;
    use std::f64::consts::PI;

    fn sphere_grid(r: f32, cpm: f32) -> ScalarGrid {
        let c = Point3::new(0.1, -0.05, 0.3);
        ScalarGrid::sample(&Aabb::new(c - Vector3::repeat(0.5), c + Vector3::repeat(0.5)), cpm, |p| (p - c).norm() - r)
    }

    #[test]
    fn area_and_volume_are_the_same_bits_on_one_and_two_threads() {
        // A fine sphere: tens of thousands of triangles, several chunks of the reduction.
        let mesh = marching_cubes(&sphere_grid(0.3, 150.0), 0.0, true);
        assert!(mesh.triangles.len() > 3 * 4096, "{}", mesh.triangles.len());
        let on = |threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| (mesh.area().to_bits(), mesh.signed_volume().to_bits()))
        };
        assert_eq!(on(1), on(2));
        assert_eq!(on(1), on(3));
    }

    #[test]
    fn sphere_mesh_is_closed_on_the_surface_with_the_right_area_and_outward_volume() {
        let r = 0.3f32;
        let grid = sphere_grid(r, 40.0);
        let mesh = marching_cubes(&grid, 0.0, true);
        let c = Point3::new(0.1, -0.05, 0.3);
        // Vertices are linear interpolations of an exact SDF along grid edges: the chordal
        // error is below cell²/(2r) ≈ 0.001 m.
        let worst = mesh.vertices.iter().map(|v| ((v - c).norm() - r).abs()).fold(0f32, f32::max);
        assert!(worst < 1.2e-3, "vertex off the sphere by {worst} m");
        assert!(mesh.is_closed(), "mesh has a boundary or inconsistent winding");
        let area = mesh.area();
        let exact_area = 4.0 * PI * (r as f64).powi(2);
        assert!((area / exact_area - 1.0).abs() < 0.02, "area {area} vs {exact_area}");
        let vol = mesh.signed_volume();
        let exact_vol = 4.0 / 3.0 * PI * (r as f64).powi(3);
        assert!((vol / exact_vol - 1.0).abs() < 0.02, "volume {vol} vs {exact_vol}");
    }

    #[test]
    fn density_field_with_inside_above_gives_the_same_outward_surface() {
        // A "density" that is high inside the sphere: flipping the flag must keep normals outward.
        let sdf = sphere_grid(0.25, 30.0);
        let density = ScalarGrid { geometry: sdf.geometry, data: sdf.data.iter().map(|v| -v).collect() };
        let m = marching_cubes(&density, 0.0, false);
        assert!(m.is_closed());
        assert!(m.signed_volume() > 0.0);
        // A plane z = 0.3 (a flipped sphere would be an enclosed void, filled): the flag picks
        // the solid side and the normals point away from it.
        let g = crate::GridGeometry::new(Point3::origin(), 0.1, [5, 5, 7]).unwrap();
        let plane = ScalarGrid::sample_geometry(g, |p| p.z - 0.33);
        for (below, up) in [(true, 1.0), (false, -1.0)] {
            let m = marching_cubes(&plane, 0.0, below);
            assert_eq!(m.triangles.len(), 32);
            for t in &m.triangles {
                let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                assert_eq!((b - a).cross(&(c - a)).z.signum(), up, "inside_is_below={below}");
            }
        }
    }

    /// A 14 × 13 × 12 grid of noise `value(rng)` inside a one-node border of value `border`.
    fn noise_grid(seed: u64, border: f32, value: impl Fn(f32) -> f32) -> ScalarGrid {
        let mut rng = crate::testutil::Rng::new(seed);
        let g = crate::GridGeometry::new(Point3::origin(), 0.1, [14, 13, 12]).unwrap();
        let mut data = vec![border; g.len()];
        for k in 1..11 {
            for j in 1..12 {
                for i in 1..13 {
                    data[g.index(i, j, k)] = value(rng.uniform());
                }
            }
        }
        ScalarGrid::from_data(g, data).unwrap()
    }

    #[test]
    fn random_fields_give_closed_meshes_so_the_tables_are_watertight() {
        // Noise with every ambiguous face and cube case, padded by an outside border.
        for (below, border) in [(true, 1.0), (false, -1.0)] {
            let m = marching_cubes(&noise_grid(7, border, |u| u - 0.5), 0.0, below);
            assert!(m.triangles.len() > 500);
            assert!(m.is_closed(), "inside_is_below={below}");
        }
    }

    #[test]
    fn random_fields_with_many_nodes_exactly_at_iso_give_watertight_meshes_without_degenerate_faces() {
        // Values in {−2, −1, 0, 1, 2}: a fifth of the nodes sit exactly at iso, so crossings
        // fall on nodes (welded) and edges join two iso nodes classified differently (0/0).
        // Where two solids touch at such nodes the welded surface is pinched (an edge shared by
        // 4 triangles), so the mesh is watertight but not `is_closed`: every directed edge
        // occurs as often as its reverse.
        for seed in [3, 11, 12345] {
            for (below, border) in [(true, 2.0), (false, -2.0)] {
                let grid = noise_grid(seed, border, |u| (u * 5.0).floor() - 2.0);
                let m = marching_cubes(&grid, 0.0, below);
                assert!(m.triangles.len() > 300, "{}", m.triangles.len());
                let mut directed: HashMap<(u32, u32), i32> = HashMap::new();
                let mut faces = std::collections::HashSet::new();
                for t in &m.triangles {
                    let [a, b, c] = t.map(|i| m.vertices[i as usize].coords.cast::<f64>());
                    assert!((b - a).cross(&(c - a)).norm() > 0.0, "seed {seed}: zero-area triangle {t:?}");
                    let mut f = *t;
                    f.sort_unstable();
                    assert!(faces.insert(f), "seed {seed}: face {t:?} occurs twice");
                    for e in 0..3 {
                        *directed.entry((t[e], t[(e + 1) % 3])).or_default() += 1;
                        *directed.entry((t[(e + 1) % 3], t[e])).or_default() -= 1;
                    }
                }
                assert!(directed.values().all(|&n| n == 0), "seed {seed}, inside_is_below={below}: not watertight");
            }
        }
    }

    #[test]
    fn touching_boxes_give_one_closed_surface_without_inner_or_degenerate_faces() {
        // Every face of both boxes lies on a grid plane, so every crossing is exactly on a node.
        let grid = crate::testutil::touching_boxes();
        let m = marching_cubes(&grid, 0.0, true);
        assert!(m.is_closed());
        // Crossings on a node share that node's one vertex: no two vertices coincide.
        let mut positions: Vec<[u32; 3]> = m.vertices.iter().map(|v| v.coords.map(f32::to_bits).into()).collect();
        positions.sort_unstable();
        positions.dedup();
        assert_eq!(positions.len(), m.vertices.len(), "vertices at the same node were not welded");
        for t in &m.triangles {
            let [p, q, r] = t.map(|i| m.vertices[i as usize]);
            assert!((q - p).cross(&(r - p)).norm() > 0.0, "zero-area triangle {t:?}");
        }
        // No face on the contact plane z = 4 inside the boxes' common footprint.
        let inner = |v: &Point3<f32>| v.z == 4.0 && v.x > 2.0 && v.x < 5.0 && v.y > 2.0 && v.y < 5.0;
        assert!(!m.triangles.iter().any(|t| t.iter().all(|&i| inner(&m.vertices[i as usize]))));
        // The same solid as the box [2, 5]² × [1, 7] alone, but for the 0/0 crossings on the rim
        // of the contact plane, put midway between its inside and outside nodes.
        let vol = m.signed_volume();
        let one_box = ScalarGrid::sample_geometry(grid.geometry, |p| {
            let q: [f32; 3] = std::array::from_fn(|a| (p[a] - [3.5, 3.5, 4.0][a]).abs() - [1.5, 1.5, 3.0][a]);
            q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt() + q[0].max(q[1]).max(q[2]).min(0.0)
        });
        let single = marching_cubes(&one_box, 0.0, true).signed_volume();
        assert!(vol < single && vol > single - 6.0, "volume {vol}, one box {single}");
    }

    #[test]
    fn a_crossing_on_a_node_is_one_vertex_shared_by_all_its_edges() {
        // A plane through the node layer i = 3 (values i − 3, exactly 0 there), cell 0.125 m.
        let g = crate::GridGeometry::new(Point3::origin(), 0.125, [7, 4, 4]).unwrap();
        let data = (0..g.len()).map(|idx| g.coords(idx)[0] as f32 - 3.0).collect();
        let grid = ScalarGrid::from_data(g, data).unwrap();
        let m = marching_cubes(&grid, 0.0, true);
        // The surface is the plane x = 3 cells through the 4 × 4 nodes there: one vertex each,
        // two triangles per 3 × 3 square, none degenerate.
        assert_eq!(m.vertices.len(), 16);
        assert!(m.vertices.iter().all(|v| v.x == 0.375));
        assert_eq!(m.triangles.len(), 18);
        assert_eq!(m.area(), 0.375 * 0.375);
    }

    fn parse_ply_header(bytes: &[u8]) -> (String, usize, usize, usize) {
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let header = std::str::from_utf8(&bytes[..end]).unwrap();
        let mut lines = header.lines();
        assert_eq!(lines.next(), Some("ply"));
        let format = lines.next().unwrap().split_whitespace().nth(1).unwrap().to_string();
        let count = |name: &str| {
            header.lines().find_map(|l| l.strip_prefix(&format!("element {name} "))).unwrap().parse::<usize>().unwrap()
        };
        (format, count("vertex"), count("face"), end)
    }

    #[test]
    fn ply_files_round_trip_through_a_hand_parser() {
        let mesh = marching_cubes(&sphere_grid(0.2, 20.0), 0.0, true);
        let dir = tempfile::tempdir().unwrap();
        // Binary: header counts, then exact body size and the first vertex and face.
        let path = dir.path().join("m.ply");
        mesh.write_ply(&path, true).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let (format, nv, nf, off) = parse_ply_header(&bytes);
        assert_eq!(format, "binary_little_endian");
        assert_eq!((nv, nf), (mesh.vertices.len(), mesh.triangles.len()));
        assert_eq!(bytes.len(), off + 12 * nv + 13 * nf);
        let f = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
        assert_eq!([f(off), f(off + 4), f(off + 8)], [mesh.vertices[0].x, mesh.vertices[0].y, mesh.vertices[0].z]);
        let face = off + 12 * nv;
        assert_eq!(bytes[face], 3);
        let i = |o: usize| i32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()) as u32;
        assert_eq!([i(face + 1), i(face + 5), i(face + 9)], mesh.triangles[0]);
        // ASCII: every vertex parses back to the same f32.
        mesh.write_ply(&path, false).unwrap();
        let text = std::fs::read(&path).unwrap();
        let (format, nv2, nf2, off) = parse_ply_header(&text);
        assert_eq!((format.as_str(), nv2, nf2), ("ascii", nv, nf));
        let body = std::str::from_utf8(&text[off..]).unwrap();
        let lines: Vec<&str> = body.lines().collect();
        assert_eq!(lines.len(), nv + nf);
        for (l, v) in lines.iter().zip(&mesh.vertices) {
            let p: Vec<f32> = l.split_whitespace().map(|s| s.parse().unwrap()).collect();
            assert_eq!(p, vec![v.x, v.y, v.z]);
        }
        assert_eq!(lines[nv], format!("3 {} {} {}", mesh.triangles[0][0], mesh.triangles[0][1], mesh.triangles[0][2]));
        // OBJ: counts of v and f lines; no temporary files left behind.
        let obj = dir.path().join("m.obj");
        mesh.write_obj(&obj).unwrap();
        let text = std::fs::read_to_string(&obj).unwrap();
        assert_eq!(text.lines().filter(|l| l.starts_with("v ")).count(), nv);
        assert_eq!(text.lines().filter(|l| l.starts_with("f ")).count(), nf);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }
}
