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
    /// Index of the primitive hit.
    pub primitive: usize,
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
        let mut t = t0;
        for _ in 0..max_steps {
            let p = ray.at(t);
            let (d, i) = self.closest(&p);
            if d < 1e-4 + 1e-4 * t {
                return Some(Hit { t, point: p, primitive: i });
            }
            t += d;
            if t > t1 {
                return None;
            }
        }
        None
    }

    /// Soft-shadow visibility in [0, 1] of the sun from `p` (iq's penumbra estimate).
    fn sun_visibility(&self, p: &Point3<f32>, n: &Vector3<f32>, s: &RenderSettings) -> f32 {
        let origin = p + n * 2e-3;
        let ray = Ray { origin, direction: s.sun };
        let t1 = match self.bounds().expanded(1e-3).intersect(&ray) {
            Some((_, t1)) => t1,
            None => return 1.0,
        };
        let (mut t, mut vis) = (1e-3f32, 1.0f32);
        for _ in 0..128 {
            let d = self.distance(&ray.at(t));
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
        let mut n = self.normal(&hit.point);
        if n.dot(&ray.direction) > 0.0 {
            n = -n;
        }
        let lambert = n.dot(&s.sun).max(0.0);
        let direct = if lambert > 0.0 { lambert * self.sun_visibility(&hit.point, &n, s) } else { 0.0 };
        let light = s.ambient + (1.0 - s.ambient) * direct;
        let a = albedo(self.material(hit.primitive), &hit.point);
        [a[0] * light, a[1] * light, a[2] * light]
    }

    /// Renders one view, parallel over rows.
    pub fn render(&self, camera: &Camera, s: &RenderSettings) -> RenderedImage {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let mut rgba = vec![0.0f32; w as usize * h as usize * 4];
        let mut depth = vec![0.0f32; w as usize * h as usize];
        let ss = s.supersample.max(1);
        let inv = 1.0 / (ss * ss) as f32;
        rgba.par_chunks_mut(4 * w as usize).zip(depth.par_chunks_mut(w as usize)).enumerate().for_each(
            |(j, (row, drow))| {
                for i in 0..w {
                    let (u, v) = (i as f32 + 0.5, j as f32 + 0.5);
                    let centre = camera.ray(u, v);
                    let centre_hit = self.trace(&centre, s.max_steps);
                    let mut acc = [0.0f32; 4];
                    for sy in 0..ss {
                        for sx in 0..ss {
                            let (ray, hit) = if ss == 1 {
                                (centre, centre_hit)
                            } else {
                                let ray = camera.ray(
                                    i as f32 + (sx as f32 + 0.5) / ss as f32,
                                    j as f32 + (sy as f32 + 0.5) / ss as f32,
                                );
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
                    // Straight alpha: colour is the mean over the samples that hit.
                    let o = 4 * i as usize;
                    if acc[3] > 0.0 {
                        for c in 0..3 {
                            row[o + c] = acc[c] / acc[3];
                        }
                    }
                    row[o + 3] = acc[3] * inv;
                    drow[i as usize] = centre_hit.map_or(0.0, |hit| hit.t * camera.z_depth_factor(u, v));
                }
            },
        );
        RenderedImage { width: w, height: h, rgba, depth }
    }
}
