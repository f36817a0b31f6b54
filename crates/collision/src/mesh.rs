//! Marching cubes (Lorensen & Cline 1987, Bourke's tables) and triangle-mesh export.

use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::grid::ScalarGrid;
use crate::io::write_atomically;
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

    /// Total surface area, m².
    pub fn area(&self) -> f64 {
        self.triangles
            .par_iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }

    /// Signed enclosed volume, m³, by the divergence theorem: `Σ a·(b × c) / 6`. Positive for a
    /// closed mesh wound outward.
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .par_iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
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

/// Whether a node value counts as inside. Values equal to `iso` (and NaN) are outside.
#[inline]
pub(crate) fn is_inside(v: f32, iso: f32, inside_is_below: bool) -> bool {
    if inside_is_below {
        v < iso
    } else {
        v > iso
    }
}

const NO_VERTEX: u32 = u32::MAX;

/// Extract the `iso` level set of `grid` by marching cubes.
///
/// `inside_is_below`: `true` for a signed distance (inside where `value < iso`), `false` for a
/// density (inside where `value > iso`, e.g. a NeRF σ at a threshold). Values equal to `iso`
/// count as outside. One vertex is made per grid edge whose end nodes differ (at the linear
/// interpolation of the crossing) and shared by every triangle that uses it. Triangles are wound
/// so their normals point from inside to outside. A surface that reaches the grid's border is
/// left open there.
///
/// Parallel over z-slices; the output order is deterministic.
pub fn marching_cubes(grid: &ScalarGrid, iso: f32, inside_is_below: bool) -> Mesh {
    let g = &grid.geometry;
    let [nx, ny, nz] = g.dims;
    let slice = nx * ny;
    let data = &grid.data;
    let inside = |idx: usize| is_inside(data[idx], iso, inside_is_below);
    let strides = [1, nx, slice];

    // Pass 1: per node and axis, the vertex on the grid edge leaving the node (if it crosses),
    // numbered within the node's z-slice.
    let n = g.len();
    let mut edge_vertex = [vec![NO_VERTEX; n], vec![NO_VERTEX; n], vec![NO_VERTEX; n]];
    let [ex, ey, ez] = &mut edge_vertex;
    let per_slice: Vec<Vec<Point3<f32>>> = ex
        .par_chunks_mut(slice)
        .zip(ey.par_chunks_mut(slice))
        .zip(ez.par_chunks_mut(slice))
        .enumerate()
        .map(|(k, ((sx, sy), sz))| {
            let mut verts = Vec::new();
            let out = [sx, sy, sz];
            for j in 0..ny {
                for i in 0..nx {
                    let idx = g.index(i, j, k);
                    let a_in = inside(idx);
                    let ijk = [i, j, k];
                    for axis in 0..3 {
                        if ijk[axis] + 1 >= g.dims[axis] {
                            continue;
                        }
                        let nb = idx + strides[axis];
                        if inside(nb) == a_in {
                            continue;
                        }
                        let (va, vb) = (data[idx], data[nb]);
                        let t = ((iso - va) / (vb - va)).clamp(0.0, 1.0);
                        let mut u = Vector3::new(i as f32, j as f32, k as f32);
                        u[axis] += t;
                        out[axis][i + nx * j] = verts.len() as u32;
                        verts.push(g.origin + u * g.cell);
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
    for arr in edge_vertex.iter_mut() {
        arr.par_chunks_mut(slice).zip(offsets.par_iter()).for_each(|(s, &off)| {
            for v in s.iter_mut().filter(|v| **v != NO_VERTEX) {
                *v += off;
            }
        });
    }
    let vertices: Vec<Point3<f32>> = per_slice.into_iter().flatten().collect();

    // Pass 2: triangles per slab of cubes between z-slices k and k+1.
    let triangles: Vec<[u32; 3]> = (0..nz - 1)
        .into_par_iter()
        .map(|k| {
            let mut tris = Vec::new();
            for j in 0..ny - 1 {
                for i in 0..nx - 1 {
                    let base = g.index(i, j, k);
                    let mut case = 0usize;
                    for (c, o) in CORNERS.iter().enumerate() {
                        if inside(base + o[0] + nx * o[1] + slice * o[2]) {
                            case |= 1 << c;
                        }
                    }
                    if case == 0 || case == 255 {
                        continue;
                    }
                    let vertex_of = |e: i8| {
                        let (o, axis) = EDGE_GRID[e as usize];
                        let v = edge_vertex[axis][base + o[0] + nx * o[1] + slice * o[2]];
                        debug_assert_ne!(v, NO_VERTEX);
                        v
                    };
                    for t in TRI_TABLE[case].chunks_exact(3).take_while(|t| t[0] >= 0) {
                        tris.push([vertex_of(t[0]), vertex_of(t[1]), vertex_of(t[2])]);
                    }
                }
            }
            tris
        })
        .flatten()
        .collect();

    Mesh { vertices, triangles }
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
        let flipped = marching_cubes(&sdf, 0.0, false);
        assert!(flipped.signed_volume() < 0.0, "inverted inside must invert the winding");
    }

    #[test]
    fn random_fields_give_closed_meshes_so_the_tables_are_watertight() {
        // Noise with every ambiguous face and cube case, padded by an outside border.
        let mut rng = crate::testutil::Rng::new(7);
        let g = crate::GridGeometry::new(Point3::origin(), 0.1, [14, 13, 12]).unwrap();
        let mut data = vec![1.0f32; g.len()];
        for k in 1..11 {
            for j in 1..12 {
                for i in 1..13 {
                    data[g.index(i, j, k)] = rng.uniform() - 0.5;
                }
            }
        }
        let grid = ScalarGrid::from_data(g, data).unwrap();
        for below in [true, false] {
            let m = marching_cubes(&grid, 0.0, below);
            assert!(m.triangles.len() > 500);
            // With inside_is_below=false the border (1.0) is inside, so the surface is still closed.
            assert!(m.is_closed(), "inside_is_below={below}");
        }
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
