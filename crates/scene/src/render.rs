//! Sphere-tracing renderer of a [`Scene`]: diffuse + ambient light with soft shadows from one
//! directional sun, procedural textures, exact depth, transparent background.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::geometry::Ray;
use crate::scenes::Scene;
use crate::texture::albedo;

/// Lighting and tracing parameters.
#[derive(Clone, Copy, Debug)]
pub struct RenderSettings {
    /// Unit vector towards the sun.
    pub sun: Vector3<f32>,
    /// Ambient fraction of the light, in [0, 1].
    pub ambient: f32,
    /// Sharpness of the soft shadows (larger is harder).
    pub shadow_hardness: f32,
    /// Samples per pixel along each axis (1 = one ray through the pixel centre; 2 = 2×2
    /// stratified supersampling for anti-aliased edges).
    pub supersample: u32,
    /// Maximum sphere-tracing steps per ray.
    pub max_steps: u32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            sun: Vector3::new(0.45, 0.3, 0.84).normalize(),
            ambient: 0.35,
            shadow_hardness: 12.0,
            supersample: 2,
            max_steps: 256,
        }
    }
}

/// A ray's first intersection with the scene.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the (unit) ray in metres.
    pub t: f32,
    pub point: Point3<f32>,
    /// Index of the primitive hit (the triangle of a mesh scene).
    pub primitive: usize,
    /// Barycentric coordinates `(u, v)` of the hit on a mesh scene's triangle (the point
    /// `(1 − u − v)·a + u·b + v·c`); `(0, 0)` on an SDF scene.
    pub barycentric: (f32, f32),
}

/// A rendered view: straight RGBA `[h, w, 4]` and z-depth `[h, w]` in metres (0 where the
/// centre ray misses).
#[derive(Clone, Debug)]
pub struct RenderedImage {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<f32>,
    pub depth: Vec<f32>,
}

impl Scene {
    /// Sphere-traces `ray` (unit direction) and returns its first hit, if any, within the
    /// scene bounds. Termination tolerance grows slowly with distance.
    pub fn trace(&self, ray: &Ray, max_steps: u32) -> Option<Hit> {
        let (t0, t1) = self.bounds().expanded(1e-3).intersect(ray)?;
        if let Some((mesh, bvh)) = self.mesh_and_bvh() {
            let h = bvh.cast(mesh, ray, t0, t1)?;
            return Some(Hit { t: h.t, point: ray.at(h.t), primitive: h.triangle, barycentric: (h.u, h.v) });
        }
        let mut buf = [0u16; 64];
        let all: Vec<u16>;
        let candidates = match self.ray_candidates(ray, t0, t1, 1e-3, &mut buf) {
            Some(0) => return None,
            Some(n) => &buf[..n],
            None => {
                all = (0..self.len() as u16).collect();
                &all[..]
            }
        };
        let mut t = t0;
        for _ in 0..max_steps {
            let p = ray.at(t);
            let (d, i) = self.closest_among(&p, candidates);
            if d < 1e-4 + 1e-4 * t {
                return Some(Hit { t, point: p, primitive: i, barycentric: (0.0, 0.0) });
            }
            t += d;
            if t > t1 {
                return None;
            }
        }
        None
    }

    /// Soft-shadow visibility in [0, 1] of the sun from `p` (iq's penumbra estimate, over the
    /// primitives whose bounding spheres come within the penumbra margin of the shadow ray).
    fn sun_visibility(&self, p: &Point3<f32>, n: &Vector3<f32>, s: &RenderSettings) -> f32 {
        let origin = p + n * 2e-3;
        let ray = Ray { origin, direction: s.sun };
        let t1 = match self.bounds().expanded(1e-3).intersect(&ray) {
            Some((_, t1)) => t1,
            None => return 1.0,
        };
        if let Some((mesh, bvh)) = self.mesh_and_bvh() {
            return if bvh.occluded(mesh, &ray, 0.0, t1) { 0.0 } else { 1.0 };
        }
        let mut buf = [0u16; 64];
        let all: Vec<u16>;
        let candidates = match self.ray_candidates(&ray, 0.0, t1, 0.05, &mut buf) {
            Some(0) => return 1.0,
            Some(n) => &buf[..n],
            None => {
                all = (0..self.len() as u16).collect();
                &all[..]
            }
        };
        let (mut t, mut vis) = (1e-3f32, 1.0f32);
        for _ in 0..128 {
            let d = self.closest_among(&ray.at(t), candidates).0;
            if d < 1e-4 {
                return 0.0;
            }
            vis = vis.min(s.shadow_hardness * d / t);
            t += d.max(2e-3);
            if t > t1 {
                break;
            }
        }
        vis.clamp(0.0, 1.0)
    }

    /// Shaded linear RGB of a hit.
    pub fn shade(&self, ray: &Ray, hit: &Hit, s: &RenderSettings) -> [f32; 3] {
        let mesh = self.mesh();
        let mut n = match mesh {
            Some(m) => m.face_normal(hit.primitive),
            None => self.normal(&hit.point),
        };
        if n.dot(&ray.direction) > 0.0 {
            n = -n;
        }
        let lambert = n.dot(&s.sun).max(0.0);
        let direct = if lambert > 0.0 { lambert * self.sun_visibility(&hit.point, &n, s) } else { 0.0 };
        let light = s.ambient + (1.0 - s.ambient) * direct;
        let a = match mesh {
            Some(m) => m.colour_at(hit.primitive, hit.barycentric.0, hit.barycentric.1),
            None => albedo(self.material(hit.primitive), &hit.point),
        };
        [a[0] * light, a[1] * light, a[2] * light]
    }

    /// Pixel `(i, j)` of `camera`'s view: straight RGBA (colour the mean over the
    /// `supersample²` stratified samples that hit, alpha the fraction that hit), and the hit of
    /// the ray through the pixel's centre.
    pub fn render_pixel(&self, camera: &Camera, i: u32, j: u32, s: &RenderSettings) -> ([f32; 4], Option<Hit>) {
        let ss = s.supersample.max(1);
        let centre = camera.ray(i as f32 + 0.5, j as f32 + 0.5);
        let centre_hit = self.trace(&centre, s.max_steps);
        let mut acc = [0.0f32; 4];
        for sy in 0..ss {
            for sx in 0..ss {
                let (ray, hit) = if ss == 1 {
                    (centre, centre_hit)
                } else {
                    let ray =
                        camera.ray(i as f32 + (sx as f32 + 0.5) / ss as f32, j as f32 + (sy as f32 + 0.5) / ss as f32);
                    (ray, self.trace(&ray, s.max_steps))
                };
                if let Some(hit) = hit {
                    let c = self.shade(&ray, &hit, s);
                    acc[0] += c[0];
                    acc[1] += c[1];
                    acc[2] += c[2];
                    acc[3] += 1.0;
                }
            }
        }
        let mut rgba = [0.0f32; 4];
        if acc[3] > 0.0 {
            for c in 0..3 {
                rgba[c] = acc[c] / acc[3];
            }
        }
        rgba[3] = acc[3] * (1.0 / (ss * ss) as f32);
        (rgba, centre_hit)
    }

    /// Renders one view, parallel over rows.
    pub fn render(&self, camera: &Camera, s: &RenderSettings) -> RenderedImage {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let mut rgba = vec![0.0f32; w as usize * h as usize * 4];
        let mut depth = vec![0.0f32; w as usize * h as usize];
        rgba.par_chunks_mut(4 * w as usize).zip(depth.par_chunks_mut(w as usize)).enumerate().for_each(
            |(j, (row, drow))| {
                for i in 0..w {
                    let (pixel, centre_hit) = self.render_pixel(camera, i, j as u32, s);
                    row[4 * i as usize..4 * i as usize + 4].copy_from_slice(&pixel);
                    drow[i as usize] =
                        centre_hit.map_or(0.0, |hit| hit.t * camera.z_depth_factor(i as f32 + 0.5, j as f32 + 0.5));
                }
            },
        );
        RenderedImage { width: w, height: h, rgba, depth }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plain sphere tracing over the whole scene, for reference.
    fn naive_trace(scene: &Scene, ray: &Ray) -> Option<f32> {
        let (t0, t1) = scene.bounds().expanded(1e-3).intersect(ray)?;
        let mut t = t0;
        for _ in 0..2048 {
            let d = scene.distance(&ray.at(t));
            if d < 1e-4 + 1e-4 * t {
                return Some(t);
            }
            t += d;
            if t > t1 {
                return None;
            }
        }
        None
    }

    #[test]
    fn culled_trace_finds_the_same_hits_as_naive_sphere_tracing() {
        let scene = Scene::stonehenge();
        let mut hits = 0;
        for k in 0..3000u32 {
            let h = |m: u32| crate::texture::value_noise(k as f32 * 0.731 + m as f32 * 13.1, 0.5, 0.25 * m as f32);
            let origin = Point3::new(6.0 * h(1) - 3.0, 6.0 * h(2) - 3.0, 0.2 + 2.5 * h(3));
            let target = Point3::new(2.0 * h(4) - 1.0, 2.0 * h(5) - 1.0, 0.6 * h(6));
            let ray = Ray::new(origin, target - origin);
            let a = scene.trace(&ray, 2048).map(|hit| hit.t);
            let b = naive_trace(&scene, &ray);
            match (a, b) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 2e-3, "ray {k}: {a} vs {b}");
                    hits += 1;
                }
                (None, None) => {}
                other => panic!("ray {k}: {other:?}"),
            }
        }
        assert!(hits > 1000, "only {hits} rays hit");
    }

    #[test]
    fn rays_that_miss_everything_are_transparent() {
        let scene = Scene::monolith();
        let up = Camera::look_at(
            Point3::new(0.0, 0.0, 3.0),
            Point3::new(0.0, 0.0, 10.0),
            Vector3::y(),
            crate::Intrinsics::from_fov_x(8, 8, 0.5),
        );
        let img = scene.render(&up, &RenderSettings::default());
        assert!(img.rgba.chunks(4).all(|p| p[3] == 0.0) && img.depth.iter().all(|&d| d == 0.0));
    }
}
