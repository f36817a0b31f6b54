//! The triangle mesh itself: positions, triangles and what the renderer needs to colour them.

use nalgebra::{Point3, Vector3};

use crate::image::Image;
use crate::Aabb;

/// A triangle mesh with what the renderer needs to colour it.
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Vertex positions, metres, world frame (z up).
    pub positions: Vec<Point3<f32>>,
    /// Vertex indices of each triangle, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex linear RGB in `[0, 1]`, when the file has them (PLY, glTF `COLOR_0`); they
    /// take precedence over the material colour.
    pub vertex_colours: Option<Vec<[f32; 3]>>,
    /// Per-vertex texture coordinates, when the file has them.
    pub uvs: Option<Vec<[f32; 2]>>,
    /// Per-triangle diffuse colour (the material's; grey without one).
    pub face_colours: Vec<[f32; 3]>,
    /// Per-triangle diffuse texture (an index into `textures`), when its material has one that
    /// could be read.
    pub face_textures: Vec<Option<u32>>,
    pub textures: Vec<Image>,
}

/// What is wrong with a mesh, naming the element.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MeshError {
    #[error("the mesh has no triangles")]
    NoTriangles,
    #[error("vertex {vertex} has a non-finite coordinate {value}")]
    NonFinite { vertex: usize, value: f32 },
    #[error("triangle {triangle} names vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange { triangle: usize, index: u32, vertices: usize },
    #[error("{what} has {found} entries, expected {expected} (one per {per})")]
    Length { what: &'static str, found: usize, expected: usize, per: &'static str },
}

/// The grey of a triangle without a material.
pub const DEFAULT_COLOUR: [f32; 3] = [0.6, 0.6, 0.6];

impl TriangleMesh {
    /// A mesh of positions and triangles, every triangle [`DEFAULT_COLOUR`].
    pub fn new(positions: Vec<Point3<f32>>, triangles: Vec<[u32; 3]>) -> Self {
        let n = triangles.len();
        Self {
            positions,
            triangles,
            vertex_colours: None,
            uvs: None,
            face_colours: vec![DEFAULT_COLOUR; n],
            face_textures: vec![None; n],
            textures: Vec::new(),
        }
    }

    /// Checks that there are triangles, every coordinate is finite, every index names a vertex
    /// and the per-vertex and per-triangle tables have their lengths.
    pub fn validate(&self) -> Result<(), MeshError> {
        if self.triangles.is_empty() {
            return Err(MeshError::NoTriangles);
        }
        for (vertex, p) in self.positions.iter().enumerate() {
            if let Some(&value) = p.iter().find(|v| !v.is_finite()) {
                return Err(MeshError::NonFinite { vertex, value });
            }
        }
        let vertices = self.positions.len();
        for (triangle, t) in self.triangles.iter().enumerate() {
            if let Some(&index) = t.iter().find(|&&i| i as usize >= vertices) {
                return Err(MeshError::IndexOutOfRange { triangle, index, vertices });
            }
        }
        let check = |what, found: usize, expected: usize, per| {
            if found == expected {
                Ok(())
            } else {
                Err(MeshError::Length { what, found, expected, per })
            }
        };
        if let Some(c) = &self.vertex_colours {
            check("vertex_colours", c.len(), vertices, "vertex")?;
        }
        if let Some(uv) = &self.uvs {
            check("uvs", uv.len(), vertices, "vertex")?;
        }
        check("face_colours", self.face_colours.len(), self.triangles.len(), "triangle")?;
        check("face_textures", self.face_textures.len(), self.triangles.len(), "triangle")
    }

    /// The box around every vertex.
    pub fn bounds(&self) -> Aabb {
        let mut min = Point3::from(Vector3::repeat(f32::INFINITY));
        let mut max = Point3::from(Vector3::repeat(f32::NEG_INFINITY));
        for p in &self.positions {
            min = min.inf(p);
            max = max.sup(p);
        }
        Aabb::new(min, max)
    }

    /// The three corners of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [Point3<f32>; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Unit normal of triangle `t` (by the right-hand rule over its vertex order); zero for a
    /// degenerate triangle.
    pub fn face_normal(&self, t: usize) -> Vector3<f32> {
        let [a, b, c] = self.corners(t);
        (b - a).cross(&(c - a)).try_normalize(0.0).unwrap_or_else(Vector3::zeros)
    }

    /// Diffuse colour of triangle `t` at barycentric coordinates `(u, v)` (the point
    /// `(1 − u − v)·a + u·b + v·c`): the vertex colours interpolated, else the texture at the
    /// interpolated coordinates (nearest texel, repeating), else the material colour.
    pub fn colour_at(&self, t: usize, u: f32, v: f32) -> [f32; 3] {
        let w = [1.0 - u - v, u, v];
        let [i, j, k] = self.triangles[t].map(|i| i as usize);
        if let Some(c) = &self.vertex_colours {
            return [0, 1, 2].map(|ch| w[0] * c[i][ch] + w[1] * c[j][ch] + w[2] * c[k][ch]);
        }
        if let (Some(tex), Some(uv)) = (self.face_textures[t], &self.uvs) {
            let img = &self.textures[tex as usize];
            let s = w[0] * uv[i][0] + w[1] * uv[j][0] + w[2] * uv[k][0];
            let r = w[0] * uv[i][1] + w[1] * uv[j][1] + w[2] * uv[k][1];
            // OBJ and glTF differ in where v = 0 is; the loaders store v upward (OBJ's).
            let x = ((s.rem_euclid(1.0) * img.width as f32) as u32).min(img.width - 1);
            let y = (((1.0 - r.rem_euclid(1.0)) * img.height as f32) as u32).min(img.height - 1);
            let p = img.pixel(x, y);
            return [p[0], p[1], p[2]];
        }
        self.face_colours[t]
    }

    /// The edges used by exactly one triangle (boundary edges) as a fraction of all edges: 0 for
    /// a closed mesh. An edge is an unordered pair of vertex positions: a seam where a reader
    /// split one position into several vertices (by texture coordinate or normal) is not open.
    pub fn open_edge_fraction(&self) -> f64 {
        let mut first_at = std::collections::HashMap::with_capacity(self.positions.len());
        let canonical: Vec<u32> = (0..self.positions.len() as u32)
            .map(|i| {
                let p = self.positions[i as usize];
                // +0.0 and −0.0 are one position.
                let key = [p.x + 0.0, p.y + 0.0, p.z + 0.0].map(f32::to_bits);
                *first_at.entry(key).or_insert(i)
            })
            .collect();
        let mut edges: Vec<(u32, u32)> = self
            .triangles
            .iter()
            .map(|t| t.map(|v| canonical[v as usize]))
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| (a.min(b), a.max(b)))
            .collect();
        edges.sort_unstable();
        let (mut distinct, mut open) = (0usize, 0usize);
        let mut i = 0;
        while i < edges.len() {
            let mut j = i + 1;
            while j < edges.len() && edges[j] == edges[i] {
                j += 1;
            }
            distinct += 1;
            open += (j - i == 1) as usize;
            i = j;
        }
        if distinct == 0 {
            0.0
        } else {
            open as f64 / distinct as f64
        }
    }
}
