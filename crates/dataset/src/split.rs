//! The frames of a split, whichever format they were read from, and how a split is read.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use nerfsv_scene::image::{oriented_size, DepthImage, Image};
use nerfsv_scene::validate::bytes_for;
use nerfsv_scene::views::{PosedImages, View};
use nerfsv_scene::{Camera, Intrinsics};

use crate::distortion::OpenCvDistortion;

/// One posed image of a split.
#[derive(Clone, Debug)]
pub struct Frame {
    /// `file_path` exactly as the transforms file gives it (a COLMAP image's `NAME`).
    pub file_path: String,
    /// The image file it resolves to.
    pub image_path: PathBuf,
    pub camera: Camera,
    pub image: Image,
    /// Ground-truth depth, when the frame has a `depth_file_path`.
    pub depth: Option<DepthImage>,
}

/// The frames of one split (`train`, `val` or `test`).
#[derive(Clone, Debug)]
pub struct Split {
    pub name: String,
    /// The transforms file (COLMAP: the images file) the split was read from.
    pub path: PathBuf,
    pub frames: Vec<Frame>,
    /// instant-ngp's `aabb_scale`, when present.
    pub aabb_scale: Option<f32>,
}

/// How to read a split.
#[derive(Clone, Copy, Debug)]
pub struct LoadOptions {
    /// Integer downscaling factor applied to images, depths and intrinsics (1 = full size).
    pub downscale: u32,
    /// Read ground-truth depth images when frames name them.
    pub load_depth: bool,
    /// Read at most this many of the split's frames (the first ones); all when `None`.
    pub max_frames: Option<usize>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self { downscale: 1, load_depth: true, max_frames: None }
    }
}

impl Split {
    /// Total pixel count over all frames.
    pub fn pixels(&self) -> usize {
        self.frames.iter().map(|f| f.camera.intrinsics.pixels()).sum()
    }
}

impl Frame {
    /// The frame as a posed image.
    pub fn view(&self) -> View<'_> {
        View { name: &self.file_path, camera: &self.camera, image: &self.image, depth: self.depth.as_ref() }
    }
}

/// The frames in order; the source is the transforms file.
impl PosedImages for Split {
    fn source(&self) -> &Path {
        &self.path
    }

    fn len(&self) -> usize {
        self.frames.len()
    }

    fn view(&self, i: usize) -> View<'_> {
        self.frames[i].view()
    }

    fn pixels(&self) -> usize {
        Split::pixels(self)
    }
}

/// A frame's image as its capture describes it, `size` being the capture's size for the frame
/// (where it gives one). The pixels are used as stored, as COLMAP, nerfstudio and instant-ngp
/// read them (their cameras describe the stored pixels: COLMAP ignores EXIF orientation on
/// purpose), unless the image's EXIF orientation turns it to `size` while its stored size is
/// not `size`: the capture was then made from the turned pixels (a tool that honoured the tag),
/// and they are turned the same way ([`Image::oriented`]). Orientations 2 to 4 keep the size,
/// so the stored pixels stand.
pub(crate) fn read_frame_image(path: &Path, size: Option<(u32, u32)>) -> Result<Image, String> {
    let (image, orientation) = Image::read_with_orientation(path)?;
    let stored = (image.width, image.height);
    match size {
        Some(size) if stored != size && oriented_size(stored.0, stored.1, orientation) == size => {
            Ok(image.oriented(orientation))
        }
        _ => Ok(image),
    }
}

/// The rule for the files a dataset names: relative paths that stay inside the dataset
/// folder (`./train/r_0`, `a/../train/r_0`). An absolute path or one that climbs out of the
/// folder (`../other/r_0`) is refused: a dataset is one folder, and no command that writes into
/// another folder can then overwrite an image a dataset reads.
pub(crate) fn check_inside(file_path: &str) -> Result<(), String> {
    use std::path::Component;
    let mut depth = 0i64;
    for c in Path::new(file_path).components() {
        match c {
            Component::Prefix(_) | Component::RootDir => {
                return Err(format!("{file_path:?} is an absolute path; files must lie inside the dataset folder"));
            }
            Component::ParentDir => {
                depth -= 1;
                if depth < 0 {
                    return Err(format!("{file_path:?} leads out of the dataset folder; files must lie inside it"));
                }
            }
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
        }
    }
    Ok(())
}

/// Whether frame `i` of a capture that names no splits belongs to `split`: every 8th frame
/// (0, 8, 16, …) is held out as both `val` and `test`, the others are `train` (instant-ngp's
/// and nerfstudio's `eval_interval` of 8).
pub(crate) fn in_split(split: &str, i: usize) -> bool {
    i.is_multiple_of(8) != (split == "train")
}

/// Bytes a split's decoded frames hold (RGBA `f32`, plus `f32` depth where read), from their
/// sizes in pixels.
pub(crate) fn held_bytes(frames: impl Iterator<Item = (u32, u32, bool)>) -> u64 {
    frames.map(|(w, h, depth)| bytes_for(w as u64 * h as u64, if depth { 20 } else { 16 })).fold(0, u64::saturating_add)
}

/// A frame as its files give it: the camera before undistortion, at full size.
pub(crate) struct RawFrame {
    pub file_path: String,
    pub image_path: PathBuf,
    /// The camera's pinhole part (the undistorted camera keeps it).
    pub intrinsics: Intrinsics,
    pub distortion: OpenCvDistortion,
    /// Camera-to-world, OpenGL camera axes.
    pub c2w: Matrix4<f32>,
    pub image: Image,
    pub depth: Option<DepthImage>,
}

impl RawFrame {
    /// The pinhole frame: images undistorted ([`OpenCvDistortion::undistort_image`], depth by
    /// nearest neighbour), then downscaled by `downscale` with the intrinsics.
    pub(crate) fn finish(self, downscale: u32) -> Frame {
        let k = self.intrinsics;
        let image = self.distortion.undistort_image(&k, &self.image).downscaled(downscale);
        let depth = self.depth.map(|d| self.distortion.undistort_depth(&k, &d).downscaled(downscale));
        Frame {
            file_path: self.file_path,
            image_path: self.image_path,
            camera: Camera::new(k.downscaled(downscale), self.c2w),
            image,
            depth,
        }
    }
}
