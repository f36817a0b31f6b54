//! Writes a split in the canonical Blender format, every file atomically.

use std::path::Path;

use nerfsv_scene::io::atomic_write;
use nerfsv_scene::validate::InvalidValue;
use nerfsv_scene::Camera;
use rayon::prelude::*;
use serde_json::json;

use crate::error::DatasetError;
use nerfsv_scene::image::{DepthImage, Image};

/// One frame to write: its camera, its image and, optionally, its ground-truth depth.
pub struct FrameToWrite {
    pub camera: Camera,
    pub image: Image,
    pub depth: Option<DepthImage>,
}

/// Writes `dir/{split}/r_{i}.png` (+ `r_{i}_depth.png`) and `dir/transforms_{split}.json`.
///
/// The JSON carries the Blender keys (`camera_angle_x`, `file_path` without extension,
/// `transform_matrix`) and, for nerfstudio/instant-ngp readers, the explicit intrinsics
/// (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`) and `depth_file_path`. All frames share the
/// intrinsics of the first. The JSON is written last, so a dataset whose transforms file
/// exists is complete.
pub fn write_split(dir: &Path, split: &str, frames: &[FrameToWrite]) -> Result<(), DatasetError> {
    let first = frames
        .first()
        .ok_or_else(|| InvalidValue::new(format!("split {split}"), "must hold at least one frame", "none"))?;
    let k = first.camera.intrinsics;
    if let Some(i) = frames.iter().position(|f| f.camera.intrinsics != k) {
        return Err(InvalidValue::new(
            format!("split {split}: frame {i}: intrinsics"),
            format!("must equal frame 0's (one set per split): {k:?}"),
            format!("{:?}", frames[i].camera.intrinsics),
        )
        .into());
    }
    let img_dir = dir.join(split);
    std::fs::create_dir_all(&img_dir).map_err(|e| DatasetError::io(&img_dir, e))?;
    frames.par_iter().enumerate().try_for_each(|(i, f)| {
        let path = img_dir.join(format!("r_{i}.png"));
        atomic_write(&path, |w| f.image.write_png(w)).map_err(|e| DatasetError::io(&path, e))?;
        if let Some(d) = &f.depth {
            let path = img_dir.join(format!("r_{i}_depth.png"));
            atomic_write(&path, |w| d.write_png_mm(w)).map_err(|e| DatasetError::io(&path, e))?;
        }
        Ok::<_, DatasetError>(())
    })?;
    let json_frames: Vec<_> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let m = &f.camera.c2w;
            let rows: Vec<Vec<f32>> = (0..4).map(|r| (0..4).map(|c| m[(r, c)]).collect()).collect();
            let mut fr = json!({ "file_path": format!("./{split}/r_{i}"), "transform_matrix": rows });
            if f.depth.is_some() {
                fr["depth_file_path"] = json!(format!("./{split}/r_{i}_depth.png"));
            }
            fr
        })
        .collect();
    let doc = json!({
        "camera_angle_x": k.fov_x(),
        "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height,
        "depth_unit_scale_factor": 1e-3,
        "frames": json_frames,
    });
    let path = dir.join(format!("transforms_{split}.json"));
    atomic_write(&path, |w| serde_json::to_writer_pretty(w, &doc).map_err(std::io::Error::other))
        .map_err(|e| DatasetError::io(&path, e))
}
