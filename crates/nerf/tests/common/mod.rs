//! A tiny analytic scene: a coloured sphere on a chequered slab, ray cast into Blender-style
//! frames (RGBA with transparent background, z-depth).
#![allow(dead_code)]

use nalgebra::{Point3, Vector3};
use nerfsv_dataset::{DepthImage, Frame, Image, Split};
use nerfsv_nerf::{NerfConfig, TrainConfig};
use nerfsv_scene::{Camera, Intrinsics, Ray};

fn hit(ray: &Ray) -> Option<(f32, [f32; 3])> {
    let mut best: Option<(f32, [f32; 3])> = None;
    // Sphere at (0, 0, 0.3), r = 0.45; colour from the normal.
    let c = Vector3::new(0.0, 0.0, 0.3);
    let oc = ray.origin.coords - c;
    let b = oc.dot(&ray.direction);
    let disc = b * b - (oc.norm_squared() - 0.45 * 0.45);
    if disc > 0.0 {
        let t = -b - disc.sqrt();
        if t > 0.0 {
            let n = (ray.at(t).coords - c).normalize();
            best = Some((t, [0.5 + 0.4 * n.x, 0.5 + 0.4 * n.y, 0.3 + 0.5 * n.z.abs()]));
        }
    }
    // Slab |x|,|y| ≤ 0.9, z ∈ [-0.2, -0.1], chequered top.
    if let Some((t0, _)) =
        nerfsv_scene::Aabb::new(Point3::new(-0.9, -0.9, -0.2), Point3::new(0.9, 0.9, -0.1)).intersect(ray)
    {
        if t0 > 0.0 && best.is_none_or(|(tb, _)| t0 < tb) {
            let p = ray.at(t0);
            let k = ((p.x * 3.0).floor() + (p.y * 3.0).floor()) as i32 & 1;
            best = Some((t0, if k == 0 { [0.9, 0.8, 0.3] } else { [0.2, 0.3, 0.6] }));
        }
    }
    best
}

/// `n` frames of `size²` pixels on a ring of cameras 3 m away, 20–60° above the horizon.
pub fn tiny_split(n: usize, size: u32, offset: f32) -> Split {
    let k = Intrinsics::from_fov_x(size, size, 0.9);
    let frames = (0..n)
        .map(|i| {
            let az = (i as f32 + offset) * 2.399;
            let el = 0.35 + 0.7 * (((i as f32 + offset) * 0.618).fract());
            let eye = Point3::new(3.0 * el.cos() * az.cos(), 3.0 * el.cos() * az.sin(), 3.0 * el.sin());
            let cam = Camera::look_at(eye, Point3::new(0.0, 0.0, 0.1), Vector3::z(), k);
            let mut img = Image::new(size, size);
            let mut depth = DepthImage { width: size, height: size, metres: vec![0.0; (size * size) as usize] };
            for j in 0..size {
                for i in 0..size {
                    let r = cam.pixel_ray(i, j);
                    let p = (j * size + i) as usize;
                    if let Some((t, c)) = hit(&r) {
                        img.rgba[4 * p..4 * p + 4].copy_from_slice(&[c[0], c[1], c[2], 1.0]);
                        depth.metres[p] = t * cam.z_depth_factor(i as f32 + 0.5, j as f32 + 0.5);
                    }
                }
            }
            Frame {
                file_path: format!("./train/r_{i}"),
                image_path: format!("r_{i}.png").into(),
                camera: cam,
                image: img,
                depth: Some(depth),
            }
        })
        .collect();
    Split { name: "train".into(), path: "tiny/transforms_train.json".into(), frames, aabb_scale: None }
}

/// A small, fast model for the tiny scene (box [-1.2, 1.2]³).
pub fn tiny_config() -> NerfConfig {
    NerfConfig {
        aabb_min: [-1.2; 3],
        aabb_max: [1.2; 3],
        hash_levels: 8,
        log2_hashmap_size: 13,
        base_resolution: 8,
        finest_resolution: 128,
        step_size: 2.4 * 1.732 / 128.0,
        grid_resolution: 32,
        grid_warmup_updates: 16,
        grid_partial_fraction: 4,
        ..NerfConfig::default()
    }
}

pub fn tiny_train_config(seed: u64) -> TrainConfig {
    TrainConfig { batch_rays: 1024, target_samples_per_step: 0, lr_decay_steps: 800, seed, ..TrainConfig::default() }
}
