//! Rendering whole views: RGB, depth (z-depth and ray distance) and opacity at any camera.

use std::path::Path;

use nerfsv_dataset::{DepthImage, Image, Split};
use nerfsv_scene::Camera;

use crate::fields::RayInput;
use crate::model::Nerf;
use crate::NerfError;

/// A rendered view; all arrays row-major from the top row.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedView {
    pub width: u32,
    pub height: u32,
    /// `[h, w, 3]` colour composited on the background, `[0, 1]`.
    pub rgb: Vec<f32>,
    /// `[h, w]` expected z-depth (along the optical axis), metres; 0 where opacity is 0.
    pub depth: Vec<f32>,
    /// `[h, w]` expected distance along the ray, metres; 0 where opacity is 0.
    pub distance: Vec<f32>,
    /// `[h, w]` accumulated alpha `[0, 1]`.
    pub opacity: Vec<f32>,
    /// Samples evaluated.
    pub samples: usize,
}

impl RenderedView {
    /// As an opaque RGBA image.
    pub fn to_image(&self) -> Image {
        let rgba = self.rgb.chunks_exact(3).flat_map(|c| [c[0], c[1], c[2], 1.0]).collect();
        Image { width: self.width, height: self.height, rgba }
    }

    /// Z-depth image with 0 where opacity ≤ 0.5.
    pub fn depth_image(&self) -> DepthImage {
        let metres = self.depth.iter().zip(&self.opacity).map(|(&d, &o)| if o > 0.5 { d } else { 0.0 }).collect();
        DepthImage { width: self.width, height: self.height, metres }
    }
}

/// The rays of every pixel centre of `camera` (row-major), with background `bg`.
pub fn camera_rays(camera: &Camera, bg: [f32; 3]) -> Vec<RayInput> {
    let k = camera.intrinsics;
    let mut rays = Vec::with_capacity(k.pixels());
    for j in 0..k.height {
        for i in 0..k.width {
            let r = camera.pixel_ray(i, j);
            rays.push(RayInput {
                origin: [r.origin.x, r.origin.y, r.origin.z],
                direction: [r.direction.x, r.direction.y, r.direction.z],
                background: bg,
                jitter: 0.0,
            });
        }
    }
    rays
}

impl Nerf {
    /// Renders `camera` over `background` (parallel over rays).
    pub fn render_camera(&self, camera: &Camera, background: [f32; 3]) -> RenderedView {
        let k = camera.intrinsics;
        let rays = camera_rays(camera, background);
        let out = self.render_rays(&rays);
        let mut depth = vec![0.0; rays.len()];
        for j in 0..k.height {
            for i in 0..k.width {
                let p = (j * k.width + i) as usize;
                depth[p] = out.distance[p] * camera.z_depth_factor(i as f32 + 0.5, j as f32 + 0.5);
            }
        }
        RenderedView {
            width: k.width,
            height: k.height,
            rgb: out.rgb,
            depth,
            distance: out.distance,
            opacity: out.opacity,
            samples: out.samples,
        }
    }
}

/// Renders every frame of `split` into `out_dir/r_{i}.png` (opaque RGB on `background`) and
/// `out_dir/r_{i}_depth.png` (16-bit z-depth in mm, 0 where opacity ≤ 0.5), atomically.
pub fn render_split(nerf: &Nerf, split: &Split, out_dir: &Path, background: [f32; 3]) -> Result<(), NerfError> {
    std::fs::create_dir_all(out_dir).map_err(|e| NerfError::io(out_dir, e))?;
    for (i, f) in split.frames.iter().enumerate() {
        let v = nerf.render_camera(&f.camera, background);
        let p = out_dir.join(format!("r_{i}.png"));
        nerfsv_scene::io::atomic_write(&p, |w| v.to_image().write_png(w)).map_err(|e| NerfError::io(&p, e))?;
        let p = out_dir.join(format!("r_{i}_depth.png"));
        nerfsv_scene::io::atomic_write(&p, |w| v.depth_image().write_png_mm(w)).map_err(|e| NerfError::io(&p, e))?;
    }
    Ok(())
}
