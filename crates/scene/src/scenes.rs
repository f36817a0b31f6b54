//! The built-in ground-truth scenes: unions of exact primitives on a textured ground disc.

use std::f32::consts::{PI, TAU};

use nalgebra::{Point3, Rotation3, Vector3};

use std::sync::Arc;

use crate::mesh::{Bvh, MeshError, TriangleMesh};
use crate::sdf::{Material, Shape};
use crate::Aabb;

/// Names accepted by [`Scene::builtin`].
pub const BUILTIN_SCENES: [&str; 3] = ["stonehenge", "monolith", "pillars"];

/// Radius of the ground disc shared by the built-in scenes (metres).
pub const GROUND_RADIUS: f32 = 1.8;
/// Thickness of the ground disc; its top face is the plane z = 0.
pub const GROUND_THICKNESS: f32 = 0.1;

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("unknown scene {0:?}: expected one of stonehenge, monolith, pillars")]
    Unknown(String),
}

/// A ground-truth world: an analytic SDF (union of exact primitives) with materials, or a
/// triangle mesh ([`Scene::from_mesh`]) whose signed distance is the distance to its closest
/// triangle, negative where its generalised winding number exceeds ½ in magnitude.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    shapes: Vec<Shape>,
    materials: Vec<Material>,
    /// Bounding spheres `[x, y, z, r]`, for culling in [`Scene::distance`].
    spheres: Vec<[f32; 4]>,
    bounds: Aabb,
    /// The mesh and its hierarchy, for a mesh scene (then `shapes` is empty).
    mesh: Option<Arc<MeshWorld>>,
}

/// FNV-1a of everything a mesh scene shows: positions, triangles, colours, texture coordinates
/// and textures.
fn mesh_digest(m: &TriangleMesh) -> u64 {
    let mut bytes = Vec::new();
    for p in &m.positions {
        bytes.extend(p.iter().flat_map(|v| v.to_le_bytes()));
    }
    for t in &m.triangles {
        bytes.extend(t.iter().flat_map(|v| v.to_le_bytes()));
    }
    for c in m.vertex_colours.iter().flatten().chain(&m.face_colours) {
        bytes.extend(c.iter().flat_map(|v| v.to_le_bytes()));
    }
    for uv in m.uvs.iter().flatten() {
        bytes.extend(uv.iter().flat_map(|v| v.to_le_bytes()));
    }
    for t in &m.face_textures {
        bytes.extend(t.map_or(u32::MAX, |i| i).to_le_bytes());
    }
    for img in &m.textures {
        bytes.extend(img.rgba.iter().flat_map(|v| v.to_le_bytes()));
    }
    crate::seed::fnv1a(&bytes)
}

/// A mesh scene's geometry.
#[derive(Debug)]
struct MeshWorld {
    mesh: TriangleMesh,
    bvh: Bvh,
    /// [`mesh_digest`] of `mesh`, for [`Scene::key`].
    digest: u64,
}

/// Deterministic pseudo-random numbers in [0, 1) for scene layout (not the run seed: a scene
/// is one fixed world).
fn jitter(i: u32, k: u32) -> f32 {
    let mut h = i.wrapping_mul(0x9E37_79B9) ^ k.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 16;
    h = h.wrapping_mul(0x7FEB_352D);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846C_A68B);
    h ^= h >> 16;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

fn yaw(angle: f32) -> Rotation3<f32> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), angle)
}

impl Scene {
    /// Builds a scene from primitives; bounds are the union of the primitives' boxes.
    pub fn from_shapes(name: &str, items: Vec<(Shape, Material)>) -> Self {
        let (shapes, materials): (Vec<_>, Vec<_>) = items.into_iter().unzip();
        let mut min = Point3::from(Vector3::repeat(f32::INFINITY));
        let mut max = Point3::from(Vector3::repeat(f32::NEG_INFINITY));
        for s in &shapes {
            let b = s.aabb();
            min = min.inf(&b.min);
            max = max.sup(&b.max);
        }
        let spheres = shapes
            .iter()
            .map(|s| {
                let (c, r) = s.bounding_sphere();
                [c.x, c.y, c.z, r]
            })
            .collect();
        Self { name: name.to_string(), shapes, materials, spheres, bounds: Aabb::new(min, max), mesh: None }
    }

    /// A scene of a triangle mesh (checked with [`TriangleMesh::validate`]); its bounds are the
    /// mesh's. The renderer ray-casts it (hard shadows), colours it by its vertex colours,
    /// texture or material ([`TriangleMesh::colour_at`]) and shades it by its face normals.
    pub fn from_mesh(name: &str, mesh: TriangleMesh) -> Result<Self, MeshError> {
        mesh.validate()?;
        let bvh = Bvh::build(&mesh);
        let digest = mesh_digest(&mesh);
        Ok(Self {
            name: name.to_string(),
            shapes: Vec::new(),
            materials: Vec::new(),
            spheres: Vec::new(),
            bounds: mesh.bounds(),
            mesh: Some(Arc::new(MeshWorld { mesh, bvh, digest })),
        })
    }

    /// The mesh scene of the file `path` ([`crate::mesh::load_mesh`]), named after the file,
    /// with the reader's warnings and, when some of its edges border one triangle only, a warning
    /// saying how much of it is open (its inside is then the generalised winding number's guess).
    pub fn load_mesh(
        path: &std::path::Path,
        options: crate::mesh::MeshOptions,
    ) -> Result<(Self, Vec<String>), crate::mesh::LoadError> {
        let crate::mesh::LoadedMesh { mesh, mut warnings } = crate::mesh::load_mesh(path, options)?;
        let open = mesh.open_edge_fraction();
        if open > 0.0 {
            warnings.push(format!(
                "{}: {:.1} % of the mesh's edges border one triangle only: it is not closed, and its inside is \
                 decided by the generalised winding number (> ½)",
                path.display(),
                100.0 * open
            ));
        }
        let name = path.file_stem().map_or_else(|| "mesh".to_string(), |s| s.to_string_lossy().into_owned());
        let scene = Self::from_mesh(&name, mesh)
            .map_err(|error| crate::mesh::LoadError::Invalid { path: path.to_path_buf(), error })?;
        Ok((scene, warnings))
    }

    /// What identifies the world in a cache key: a built-in scene's name, or a mesh scene's
    /// name with the digest of its mesh (a changed file is another world).
    pub fn key(&self) -> String {
        match &self.mesh {
            Some(m) => format!("{}-{:016x}", self.name, m.digest),
            None => self.name.clone(),
        }
    }

    /// The mesh of a mesh scene.
    pub fn mesh(&self) -> Option<&TriangleMesh> {
        self.mesh.as_deref().map(|m| &m.mesh)
    }

    /// The mesh of a mesh scene with its hierarchy.
    pub fn mesh_and_bvh(&self) -> Option<(&TriangleMesh, &Bvh)> {
        self.mesh.as_deref().map(|m| (&m.mesh, &m.bvh))
    }

    /// One of [`BUILTIN_SCENES`].
    pub fn builtin(name: &str) -> Result<Self, SceneError> {
        match name {
            "stonehenge" => Ok(Self::stonehenge()),
            "monolith" => Ok(Self::monolith()),
            "pillars" => Ok(Self::pillars()),
            other => Err(SceneError::Unknown(other.to_string())),
        }
    }

    fn ground() -> (Shape, Material) {
        let half = GROUND_THICKNESS * 0.5;
        (
            Shape::Cylinder { center: Point3::new(0.0, 0.0, -half), radius: GROUND_RADIUS, half_height: half },
            Material::Ground,
        )
    }

    /// The default scene: an outer ring of 16 sarsens with lintels, an inner ring of 6 smaller
    /// bluestones, a fallen stone and a central monolith, on the ground disc. The drone's
    /// default flight (0.39, −0.67, 0.2) → (−0.4, 0.55, 0.16) has to pass the monolith.
    pub fn stonehenge() -> Self {
        let mut items = vec![Self::ground()];
        let stone =
            |c: Point3<f32>, r: Rotation3<f32>, s: Vector3<f32>| (Shape::rounded_box(c, r, s, 0.015), Material::Stone);
        // Outer ring: uprights 0.22 wide (tangential) × 0.14 deep × 0.62 tall at r = 1.25 m.
        let (n, ring_r, height) = (16u32, 1.25f32, 0.62f32);
        for i in 0..n {
            let a = TAU * i as f32 / n as f32 + 0.03 * (jitter(i, 1) - 0.5);
            let lean = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.06 * (jitter(i, 2) - 0.5));
            let h = height + 0.04 * (jitter(i, 3) - 0.5);
            let c = Point3::new(ring_r * a.cos(), ring_r * a.sin(), h * 0.5);
            // local x is tangential, y radial
            items.push(stone(c, yaw(a + PI / 2.0) * lean, Vector3::new(0.22, 0.14, h)));
        }
        // Lintels over 6 of the 8 pairs (two have fallen), resting on the uprights' tops.
        for p in [0u32, 1, 2, 4, 5, 7] {
            let a = TAU * (2 * p) as f32 / n as f32 + TAU / (2 * n) as f32;
            let r = ring_r * (PI / n as f32).cos();
            let c = Point3::new(r * a.cos(), r * a.sin(), height + 0.04);
            let len = 2.0 * ring_r * (PI / n as f32).sin() + 0.22;
            items.push(stone(c, yaw(a + PI / 2.0), Vector3::new(len, 0.13, 0.08)));
        }
        // Inner ring of bluestones at r = 0.95 m.
        for i in 0..6u32 {
            let a = TAU * (i as f32 + 0.5) / 6.0 + 0.1 * (jitter(i, 7) - 0.5);
            let h = 0.36 + 0.1 * jitter(i, 8);
            let c = Point3::new(0.95 * a.cos(), 0.95 * a.sin(), h * 0.5);
            items.push(stone(c, yaw(a + PI / 2.0 + 0.3 * (jitter(i, 9) - 0.5)), Vector3::new(0.14, 0.1, h)));
        }
        // A fallen lintel lying on the ground outside the ring.
        items.push(stone(Point3::new(-1.45, -0.55, 0.045), yaw(0.4), Vector3::new(0.55, 0.13, 0.09)));
        // The central monolith.
        items.push(stone(Point3::new(0.0, 0.0, 0.375), yaw(0.35), Vector3::new(0.18, 0.12, 0.75)));
        Self::from_shapes("stonehenge", items)
    }

    /// A single monolith on the ground disc.
    pub fn monolith() -> Self {
        let m = Shape::rounded_box(Point3::new(0.0, 0.0, 0.45), yaw(0.35), Vector3::new(0.3, 0.2, 0.9), 0.02);
        Self::from_shapes("monolith", vec![Self::ground(), (m, Material::Stone)])
    }

    /// A jittered 5 × 5 field of columns of varying height, leaving the centre free.
    pub fn pillars() -> Self {
        let mut items = vec![Self::ground()];
        for (k, (i, j)) in (0..5).flat_map(|i| (0..5).map(move |j| (i, j))).enumerate() {
            if (i, j) == (2, 2) {
                continue;
            }
            let k = k as u32;
            let x = (i as f32 - 2.0) * 0.6 + 0.12 * (jitter(k, 11) - 0.5);
            let y = (j as f32 - 2.0) * 0.6 + 0.12 * (jitter(k, 12) - 0.5);
            let h = 0.4 + 0.5 * jitter(k, 13);
            let r = 0.07 + 0.04 * jitter(k, 14);
            items.push((
                Shape::Cylinder { center: Point3::new(x, y, h * 0.5), radius: r, half_height: h * 0.5 },
                Material::Stone,
            ));
        }
        Self::from_shapes("pillars", items)
    }

    /// Axis-aligned bounds of all geometry.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Number of primitives (triangles of a mesh scene).
    pub fn len(&self) -> usize {
        self.mesh.as_ref().map_or(self.shapes.len(), |m| m.mesh.triangles.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Signed distance in metres from `p` to the scene (negative inside geometry).
    #[inline]
    pub fn distance(&self, p: &Point3<f32>) -> f32 {
        self.closest(p).0
    }

    /// Signed distance and the index of the closest primitive.
    #[inline]
    pub fn closest(&self, p: &Point3<f32>) -> (f32, usize) {
        if let Some(m) = &self.mesh {
            let (d, t) = m.bvh.closest(&m.mesh, p);
            // |w|: a mesh whose triangles all face inward (a common export slip) has w = −1 inside.
            let inside = m.bvh.winding_number(&m.mesh, p).abs() > 0.5;
            return (if inside { -d } else { d }, t);
        }
        self.closest_in(p, 0..self.shapes.len())
    }

    /// Signed distance and closest primitive among the `candidates` only.
    #[inline]
    pub(crate) fn closest_among(&self, p: &Point3<f32>, candidates: &[u16]) -> (f32, usize) {
        self.closest_in(p, candidates.iter().map(|&c| c as usize))
    }

    /// The minimum over `indices`. A primitive whose bounding sphere is farther than the best
    /// distance so far cannot be closer and is skipped.
    #[inline]
    fn closest_in(&self, p: &Point3<f32>, indices: impl Iterator<Item = usize>) -> (f32, usize) {
        let mut best = f32::INFINITY;
        let mut arg = 0;
        for i in indices {
            let s = &self.spheres[i];
            let (dx, dy, dz) = (p.x - s[0], p.y - s[1], p.z - s[2]);
            let lower = (dx * dx + dy * dy + dz * dz).sqrt() - s[3];
            if lower >= best {
                continue;
            }
            let d = self.shapes[i].distance(p);
            if d < best {
                best = d;
                arg = i;
            }
        }
        (best, arg)
    }

    /// Writes into `out` the primitives whose bounding sphere (grown by `margin`) meets the ray
    /// segment `[t0, t1]`, and returns how many. Sphere tracing against these alone is safe:
    /// the others are never crossed, so the ray cannot step through them. `None` if they do not
    /// fit in `out`.
    pub(crate) fn ray_candidates(
        &self,
        ray: &crate::Ray,
        t0: f32,
        t1: f32,
        margin: f32,
        out: &mut [u16],
    ) -> Option<usize> {
        let mut n = 0;
        for (i, s) in self.spheres.iter().enumerate() {
            let oc = ray.origin - Point3::new(s[0], s[1], s[2]);
            // Closest approach of the (unit-direction) ray to the centre, clamped to the segment.
            let t = (-oc.dot(&ray.direction)).clamp(t0, t1);
            let d2 = (oc + ray.direction * t).norm_squared();
            let r = s[3] + margin;
            if d2 <= r * r {
                if n == out.len() {
                    return None;
                }
                out[n] = i as u16;
                n += 1;
            }
        }
        Some(n)
    }

    /// The material of primitive `i` (of an SDF scene; a mesh scene's triangles carry colours,
    /// [`TriangleMesh::colour_at`], and report [`Material::Stone`]).
    pub fn material(&self, i: usize) -> Material {
        self.materials.get(i).copied().unwrap_or(Material::Stone)
    }

    /// Outward unit normal at (or near) the surface, by central differences of the SDF.
    pub fn normal(&self, p: &Point3<f32>) -> Vector3<f32> {
        let e = 2e-4;
        let d = |v: Vector3<f32>| self.distance(&(p + v)) - self.distance(&(p - v));
        Vector3::new(d(Vector3::x() * e), d(Vector3::y() * e), d(Vector3::z() * e)).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn culled_distance_equals_brute_force_minimum() {
        let s = Scene::stonehenge();
        for k in 0..2000u32 {
            let p = Point3::new(4.0 * jitter(k, 1) - 2.0, 4.0 * jitter(k, 2) - 2.0, 1.2 * jitter(k, 3) - 0.2);
            let brute = s.shapes.iter().map(|sh| sh.distance(&p)).fold(f32::INFINITY, f32::min);
            assert_eq!(s.distance(&p), brute, "at {p}");
        }
    }

    #[test]
    fn builtin_scenes_fit_the_four_metre_cube() {
        for name in BUILTIN_SCENES {
            let b = Scene::builtin(name).unwrap().bounds();
            assert!(Aabb::cube(2.0).contains(&b.min) && Aabb::cube(2.0).contains(&b.max), "{name}: {b:?}");
        }
        assert!(Scene::builtin("nowhere").is_err());
    }

    #[test]
    fn default_flight_endpoints_are_free_and_the_monolith_blocks_the_straight_line() {
        let s = Scene::stonehenge();
        let (a, b) = (Point3::new(0.39, -0.67, 0.2), Point3::new(-0.4, 0.55, 0.16));
        assert!(s.distance(&a) > 0.1 && s.distance(&b) > 0.1);
        let blocked = (0..=100).any(|i| s.distance(&(a + (b - a) * (i as f32 / 100.0))) < 0.05);
        assert!(blocked, "the straight path should pass within 5 cm of the monolith");
        assert_eq!(s.len(), 1 + 16 + 6 + 6 + 1 + 1);
    }
}
