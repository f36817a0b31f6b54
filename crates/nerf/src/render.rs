//! Rendering whole views: RGB, depth (z-depth and ray distance) and opacity at any camera.

use std::path::Path;

use nerfsv_scene::image::{DepthImage, Image};
use nerfsv_scene::validate::{bytes_for, InvalidValue, MemoryBudget};
use nerfsv_scene::views::{PosedImages, View};
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
            rays.push(RayInput::through_pixel(camera, i, j, bg));
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
pub fn render_split(
    nerf: &Nerf,
    split: &impl PosedImages,
    out_dir: &Path,
    background: [f32; 3],
) -> Result<(), NerfError> {
    std::fs::create_dir_all(out_dir).map_err(|e| NerfError::io(out_dir, e))?;
    for i in 0..split.len() {
        let v = nerf.render_camera(split.view(i).camera, background);
        let p = out_dir.join(format!("r_{i}.png"));
        nerfsv_scene::io::atomic_write(&p, |w| v.to_image().write_png(w)).map_err(|e| NerfError::io(&p, e))?;
        let p = out_dir.join(format!("r_{i}_depth.png"));
        nerfsv_scene::io::atomic_write(&p, |w| v.depth_image().write_png_mm(w)).map_err(|e| NerfError::io(&p, e))?;
    }
    Ok(())
}

/// The file names [`render_path`] writes: frame `i`'s colour and depth, and the animation.
pub fn path_frame_names(i: usize) -> [String; 2] {
    [format!("frame_{i:04}.png"), format!("frame_{i:04}_depth.png")]
}

/// The animation [`render_path`] writes beside its frames.
pub const PATH_ANIMATION: &str = "animation.png";

/// Renders each of `cameras` (a path: one size) over `background` into `out_dir`: its frames
/// as `frame_NNNN.png` (RGB) and `frame_NNNN_depth.png` (16-bit z-depth, mm), and all of them as
/// an animated PNG, [`PATH_ANIMATION`], at `fps` frames per second. `progress` is told each
/// frame done. Every file is written to a temporary name and renamed into place.
pub fn render_path(
    nerf: &Nerf,
    cameras: &[Camera],
    out_dir: &Path,
    background: [f32; 3],
    fps: f64,
    mut progress: impl FnMut(usize),
) -> Result<(), NerfError> {
    let first = cameras.first().ok_or_else(|| InvalidValue::new("path", "must hold at least one camera", "none"))?;
    let (w, h) = (first.intrinsics.width, first.intrinsics.height);
    if let Some(i) = cameras.iter().position(|c| (c.intrinsics.width, c.intrinsics.height) != (w, h)) {
        return Err(InvalidValue::new(
            format!("path camera {i}"),
            format!("must be {w}×{h} pixels like camera 0"),
            "another size",
        )
        .into());
    }
    MemoryBudget::current().check("path", bytes_for((w as u64 * h as u64).saturating_mul(cameras.len() as u64), 16))?;
    std::fs::create_dir_all(out_dir).map_err(|e| NerfError::io(out_dir, e))?;
    let mut frames = Vec::with_capacity(cameras.len());
    for (i, camera) in cameras.iter().enumerate() {
        let v = nerf.render_camera(camera, background);
        let [colour, depth] = path_frame_names(i).map(|n| out_dir.join(n));
        let image = v.to_image();
        nerfsv_scene::io::atomic_write(&colour, |f| image.write_png(f)).map_err(|e| NerfError::io(&colour, e))?;
        nerfsv_scene::io::atomic_write(&depth, |f| v.depth_image().write_png_mm(f))
            .map_err(|e| NerfError::io(&depth, e))?;
        frames.push(image);
        progress(i + 1);
    }
    let p = out_dir.join(PATH_ANIMATION);
    nerfsv_scene::io::atomic_write(&p, |f| nerfsv_scene::animation::write_apng(f, &frames, fps))
        .map_err(|e| NerfError::io(&p, e))
}

/// One row per frame, `ground truth | NeRF render`, both composited on white and enlarged
/// `scale`× (nearest neighbour; 0 counts as 1). The frames must share one size, which must be
/// their cameras' size; the output (`2·w·scale` × `h·scale·frames`, RGBA f32) must fit the
/// memory budget.
pub fn comparison_image(nerf: &Nerf, frames: &[View<'_>], scale: u32) -> Result<Image, NerfError> {
    let first = frames.first().ok_or_else(|| InvalidValue::new("frames", "must hold at least one frame", "none"))?;
    let (w, h) = (first.image.width, first.image.height);
    for (i, f) in frames.iter().enumerate() {
        let k = f.camera.intrinsics;
        if (f.image.width, f.image.height) != (w, h) || (k.width, k.height) != (w, h) {
            return Err(InvalidValue::new(
                format!("frames[{i}] ({})", f.name),
                format!("must be {w}×{h} pixels like frames[0], image and camera alike"),
                format!("an image of {}×{} and a camera of {}×{}", f.image.width, f.image.height, k.width, k.height),
            )
            .into());
        }
    }
    let s = scale.max(1) as u64;
    let (out_w, out_h) = (2 * w as u64 * s, h as u64 * s * frames.len() as u64);
    MemoryBudget::current().check("scale", bytes_for(out_w.saturating_mul(out_h), 16))?;
    let (Ok(out_w), Ok(out_h)) = (u32::try_from(out_w), u32::try_from(out_h)) else {
        return Err(InvalidValue::new("scale", "must keep the image under 2^32 pixels a side", scale).into());
    };
    let s = s as u32;
    let mut out = Image::new(out_w, out_h);
    for (row, frame) in frames.iter().enumerate() {
        let view = nerf.render_camera(frame.camera, [1.0, 1.0, 1.0]).to_image();
        for (col, img) in [frame.image, &view].into_iter().enumerate() {
            for y in 0..h * s {
                for x in 0..w * s {
                    let p = img.pixel(x / s, y / s);
                    let (ox, oy) = (col * (w * s) as usize + x as usize, row * (h * s) as usize + y as usize);
                    let o = 4 * (oy * out_w as usize + ox);
                    // Straight alpha on white: rgb·a + (1 − a); renders are opaque already.
                    for c in 0..3 {
                        out.rgba[o + c] = p[c] * p[3] + (1.0 - p[3]);
                    }
                    out.rgba[o + 3] = 1.0;
                }
            }
        }
    }
    Ok(out)
}
