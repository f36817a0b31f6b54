//! Triangle meshes as ground truth: a user's world exported from Blender or scanned, loaded
//! from OBJ (with MTL diffuse colours and PNG diffuse textures), PLY (with vertex colours) or
//! glTF 2.0 / GLB ([`load_mesh`]), indexed by a bounding volume hierarchy ([`Bvh`]) for ray
//! casting, closest points and the generalised winding number, which decides inside and outside
//! robustly for meshes that are not watertight.
//!
//! Units are metres, z up; [`MeshOptions`] scales a file and turns a y-up file (Blender's glTF
//! export, most scans) to z up.

mod bvh;
mod load;
mod triangle;

pub use bvh::{Bvh, RayHit};
pub use load::{load_mesh, ply_bytes, LoadError, LoadedMesh, MeshOptions, UpAxis};
pub use triangle::{MeshError, TriangleMesh, DEFAULT_COLOUR};

#[cfg(test)]
pub(crate) mod tests {
    use nalgebra::{Point3, Vector3};

    use super::*;

    /// The unit cube `[lo, hi]³` with outward-facing triangles; `open` drops the top face's two.
    pub fn cube(lo: f32, hi: f32, open: bool) -> TriangleMesh {
        let p = |x: u32, y: u32, z: u32| Point3::new([lo, hi][x as usize], [lo, hi][y as usize], [lo, hi][z as usize]);
        let mut positions = Vec::new();
        for z in 0..2 {
            for y in 0..2 {
                for x in 0..2 {
                    positions.push(p(x, y, z));
                }
            }
        }
        let v = |x: u32, y: u32, z: u32| x + 2 * y + 4 * z;
        let quads = [
            [v(0, 0, 0), v(0, 1, 0), v(1, 1, 0), v(1, 0, 0)], // bottom (−z)
            [v(0, 0, 1), v(1, 0, 1), v(1, 1, 1), v(0, 1, 1)], // top (+z)
            [v(0, 0, 0), v(1, 0, 0), v(1, 0, 1), v(0, 0, 1)], // −y
            [v(0, 1, 0), v(0, 1, 1), v(1, 1, 1), v(1, 1, 0)], // +y
            [v(0, 0, 0), v(0, 0, 1), v(0, 1, 1), v(0, 1, 0)], // −x
            [v(1, 0, 0), v(1, 1, 0), v(1, 1, 1), v(1, 0, 1)], // +x
        ];
        let mut triangles = Vec::new();
        for (f, q) in quads.iter().enumerate() {
            if open && f == 1 {
                continue;
            }
            triangles.push([q[0], q[1], q[2]]);
            triangles.push([q[0], q[2], q[3]]);
        }
        TriangleMesh::new(positions, triangles)
    }

    #[test]
    fn the_cube_faces_outward_and_is_closed_unless_opened() {
        let c = cube(0.0, 1.0, false);
        c.validate().unwrap();
        for t in 0..c.triangles.len() {
            let centroid = c.corners(t).iter().fold(Vector3::zeros(), |s, p| s + p.coords) / 3.0;
            assert!(c.face_normal(t).dot(&(centroid - Vector3::repeat(0.5))) > 0.0, "triangle {t} faces inward");
        }
        assert_eq!(c.open_edge_fraction(), 0.0);
        assert!((cube(0.0, 1.0, true).open_edge_fraction() - 4.0 / 17.0).abs() < 1e-12);
    }

    #[test]
    fn a_closed_mesh_split_at_its_seams_is_closed() {
        // Each triangle with vertices of its own, as a reader splits vertices by texture
        // coordinate: every vertex index pair borders one triangle, every position pair two.
        let c = cube(0.0, 1.0, false);
        let positions: Vec<_> = c.triangles.iter().flat_map(|t| t.map(|v| c.positions[v as usize])).collect();
        let triangles: Vec<[u32; 3]> = (0..c.triangles.len() as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let split = TriangleMesh::new(positions, triangles);
        assert_eq!(split.open_edge_fraction(), 0.0);
        let mut open = split.clone();
        open.triangles.pop();
        assert!(open.open_edge_fraction() > 0.0);
    }

    #[test]
    fn bad_meshes_are_named() {
        assert_eq!(TriangleMesh::new(vec![Point3::origin()], vec![]).validate(), Err(MeshError::NoTriangles));
        let mut c = cube(0.0, 1.0, false);
        c.positions[3].y = f32::NAN;
        assert!(matches!(c.validate(), Err(MeshError::NonFinite { vertex: 3, .. })));
        let mut c = cube(0.0, 1.0, false);
        c.triangles[5][1] = 8;
        assert_eq!(c.validate(), Err(MeshError::IndexOutOfRange { triangle: 5, index: 8, vertices: 8 }));
        let mut c = cube(0.0, 1.0, false);
        c.vertex_colours = Some(vec![[0.0; 3]; 7]);
        assert!(matches!(c.validate(), Err(MeshError::Length { what: "vertex_colours", found: 7, .. })));
    }
}
