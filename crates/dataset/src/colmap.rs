//! COLMAP sparse models: a folder holding `sparse/0/cameras.{bin,txt}` and
//! `sparse/0/images.{bin,txt}` (COLMAP's documented text and binary layouts, the binary files read
//! when both are present, as COLMAP's `read_write_model.py` does; `points3D` is not needed) and
//! the images they name under `images/`.
//!
//! An image's pose is COLMAP's world-to-camera rotation (unit quaternion `QW QX QY QZ`) and
//! translation (`TX TY TZ`) in OpenCV camera axes (x right, y down, z forward):
//! `X_cam = R·X_world + t`. Its camera-to-world transform in nerfsv's OpenGL camera axes (x
//! right, y up, looking down −z) is `[Rᵀ·diag(1, −1, −1) | −Rᵀ·t]`; the world is COLMAP's,
//! units and up axis as the reconstruction left them (a run places it with the `[world]`
//! table's `dataset_scale`, `dataset_up` and `dataset_centre`). Cameras `SIMPLE_PINHOLE`,
//! `PINHOLE`, `SIMPLE_RADIAL`, `RADIAL` and `OPENCV` are read (the last three undistorted on
//! load: `SIMPLE_RADIAL` and `RADIAL` are the `OPENCV` lens with `fx = fy` and, for
//! `SIMPLE_RADIAL`, `k2 = 0`, without tangential terms); other models are refused by name.
//! Images are split by name order: every 8th (0, 8, 16, …) is `val` and `test`, the others are
//! `train`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix4, Quaternion, UnitQuaternion, Vector3};
use nerfsv_scene::validate::MemoryBudget;
use nerfsv_scene::Intrinsics;
use rayon::prelude::*;

use crate::distortion::OpenCvDistortion;
use crate::error::DatasetError;
use crate::split::{check_inside, held_bytes, in_split, read_frame_image, Frame, LoadOptions, RawFrame, Split};

/// One camera of `cameras.{txt,bin}`: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    /// COLMAP's model name (`PINHOLE`, `OPENCV`, …).
    pub model: String,
    /// Image size in pixels.
    pub width: u64,
    pub height: u64,
    /// The model's parameters, in COLMAP's order (`OPENCV`: fx, fy, cx, cy, k1, k2, p1, p2).
    pub params: Vec<f64>,
}

/// One registered image of `images.{txt,bin}`: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation as a quaternion `[w, x, y, z]`.
    pub qvec: [f64; 4],
    /// World-to-camera translation, world units.
    pub tvec: [f64; 3],
    pub camera_id: u32,
    /// The image file, relative to the `images/` folder.
    pub name: String,
}

/// A sparse model's cameras and images, with the files they were read from.
#[derive(Clone, Debug)]
pub struct ColmapModel {
    pub cameras_path: PathBuf,
    pub images_path: PathBuf,
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// In the file's order.
    pub images: Vec<ColmapImage>,
}

/// COLMAP's camera models by model id, with their parameter counts (`colmap/sensor/models.h`).
const MODELS: [(&str, usize); 12] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

/// The model files of the COLMAP folder `dir` (`sparse/0/cameras.*`, `sparse/0/images.*`), the
/// binary pair if present, else the text pair; `None` if it holds neither.
pub fn model_files(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    let sparse = dir.join("sparse").join("0");
    ["bin", "txt"].into_iter().find_map(|ext| {
        let (c, i) = (sparse.join(format!("cameras.{ext}")), sparse.join(format!("images.{ext}")));
        (c.is_file() && i.is_file()).then_some((c, i))
    })
}

/// Reads the sparse model of the COLMAP folder `dir` ([`model_files`]).
pub fn read_model(dir: &Path) -> Result<ColmapModel, DatasetError> {
    let (cameras_path, images_path) = model_files(dir).ok_or_else(|| DatasetError::Field {
        path: dir.join("sparse").join("0"),
        frame: None,
        field: "cameras/images".into(),
        message: "no cameras.bin and images.bin, nor cameras.txt and images.txt".into(),
    })?;
    let binary = cameras_path.extension().is_some_and(|e| e == "bin");
    let read = |p: &Path| std::fs::read(p).map_err(|e| DatasetError::io(p, e));
    let (cameras, images) = if binary {
        (
            read_cameras_binary(&cameras_path, &read(&cameras_path)?)?,
            read_images_binary(&images_path, &read(&images_path)?)?,
        )
    } else {
        let text = |p: &Path| std::fs::read_to_string(p).map_err(|e| DatasetError::io(p, e));
        (
            read_cameras_text(&cameras_path, &text(&cameras_path)?)?,
            read_images_text(&images_path, &text(&images_path)?)?,
        )
    };
    let mut by_id = BTreeMap::new();
    for c in cameras {
        let id = c.id;
        if by_id.insert(id, c).is_some() {
            return Err(field(&cameras_path, format!("camera {id}"), "appears twice"));
        }
    }
    Ok(ColmapModel { cameras_path, images_path, cameras: by_id, images })
}

fn field(path: &Path, field: impl Into<String>, message: impl Into<String>) -> DatasetError {
    DatasetError::Field { path: path.to_path_buf(), frame: None, field: field.into(), message: message.into() }
}

/// The lines of a COLMAP text file that carry data: (1-based line number, line), comments
/// (`#`) and blank lines left out.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(n, l)| (n + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// Parses token `what` of a text line.
fn parse<T: std::str::FromStr>(path: &Path, line: usize, what: &str, token: Option<&str>) -> Result<T, DatasetError> {
    let token = token.ok_or_else(|| field(path, format!("line {line}"), format!("{what}: missing")))?;
    token.parse().map_err(|_| field(path, format!("line {line}"), format!("{what}: {token:?} is not a valid value")))
}

/// `cameras.txt`: one line per camera, `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`.
pub fn read_cameras_text(path: &Path, text: &str) -> Result<Vec<ColmapCamera>, DatasetError> {
    let mut out = Vec::new();
    for (n, line) in data_lines(text) {
        let mut t = line.split_whitespace();
        let id = parse(path, n, "CAMERA_ID", t.next())?;
        let model: String = parse(path, n, "MODEL", t.next())?;
        let width = parse(path, n, "WIDTH", t.next())?;
        let height = parse(path, n, "HEIGHT", t.next())?;
        let params = t.map(|p| parse(path, n, "PARAMS", Some(p))).collect::<Result<Vec<f64>, _>>()?;
        if let Some(&(_, count)) = MODELS.iter().find(|(m, _)| *m == model) {
            if params.len() != count {
                return Err(field(
                    path,
                    format!("line {n}"),
                    format!("{model} has {count} parameters, found {}", params.len()),
                ));
            }
        }
        out.push(ColmapCamera { id, model, width, height, params });
    }
    Ok(out)
}

/// `images.txt`: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` and its
/// 2-D points (not needed here, and possibly empty).
pub fn read_images_text(path: &Path, text: &str) -> Result<Vec<ColmapImage>, DatasetError> {
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate().map(|(n, l)| (n + 1, l.trim()));
    while let Some((n, line)) = lines.next() {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let tokens: Vec<&str> = line.split_whitespace().collect();
        let mut t = tokens.iter().copied();
        let id = parse(path, n, "IMAGE_ID", t.next())?;
        let mut q = [0.0; 4];
        for (k, name) in ["QW", "QX", "QY", "QZ"].into_iter().enumerate() {
            q[k] = parse(path, n, name, t.next())?;
        }
        let mut tv = [0.0; 3];
        for (k, name) in ["TX", "TY", "TZ"].into_iter().enumerate() {
            tv[k] = parse(path, n, name, t.next())?;
        }
        let camera_id = parse(path, n, "CAMERA_ID", t.next())?;
        // The name is the rest of the line.
        let name = tokens.get(9..).filter(|r| !r.is_empty()).map(|r| r.join(" "));
        let name: String = parse(path, n, "NAME", name.as_deref())?;
        out.push(ColmapImage { id, qvec: q, tvec: tv, camera_id, name });
        // The points line follows its image line, empty or not.
        lines.next();
    }
    Ok(out)
}

/// A little-endian reader over a binary model file whose errors name the file and the offset.
struct Bin<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
}

impl Bin<'_> {
    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N], DatasetError> {
        let end = self.at.checked_add(N).filter(|&e| e <= self.bytes.len()).ok_or_else(|| {
            field(self.path, format!("byte {}", self.at), format!("{what}: the file ends ({} bytes)", self.bytes.len()))
        })?;
        let mut out = [0; N];
        out.copy_from_slice(&self.bytes[self.at..end]);
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self, what: &str) -> Result<u32, DatasetError> {
        self.take::<4>(what).map(u32::from_le_bytes)
    }

    fn u64(&mut self, what: &str) -> Result<u64, DatasetError> {
        self.take::<8>(what).map(u64::from_le_bytes)
    }

    fn f64(&mut self, what: &str) -> Result<f64, DatasetError> {
        self.take::<8>(what).map(f64::from_le_bytes)
    }

    /// A count of records of at least `min_bytes` each, refused if the rest of the file
    /// cannot hold them (a corrupt count must not allocate gigabytes).
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize, DatasetError> {
        let at = self.at;
        let n = self.u64(what)?;
        let room = (self.bytes.len() - self.at) / min_bytes.max(1);
        if n > room as u64 {
            return Err(field(
                self.path,
                format!("byte {at}"),
                format!("{what} is {n}, but the rest of the file holds at most {room}"),
            ));
        }
        Ok(n as usize)
    }

    /// A NUL-terminated UTF-8 string.
    fn name(&mut self, what: &str) -> Result<String, DatasetError> {
        let rest = &self.bytes[self.at..];
        let len = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| field(self.path, format!("byte {}", self.at), format!("{what}: no terminating NUL")))?;
        let s = std::str::from_utf8(&rest[..len])
            .map_err(|_| field(self.path, format!("byte {}", self.at), format!("{what}: not UTF-8")))?;
        self.at += len + 1;
        Ok(s.to_string())
    }
}

/// `cameras.bin`: a `u64` count, then per camera `u32 camera_id`, `i32 model_id`, `u64 width`,
/// `u64 height` and the model's `f64` parameters, little-endian.
pub fn read_cameras_binary(path: &Path, bytes: &[u8]) -> Result<Vec<ColmapCamera>, DatasetError> {
    let mut b = Bin { path, bytes, at: 0 };
    let n = b.count("number of cameras", 24)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = b.u32("camera_id")?;
        let at = b.at;
        let model_id = b.u32("model_id")? as i32;
        let &(model, count) = usize::try_from(model_id)
            .ok()
            .and_then(|m| MODELS.get(m))
            .ok_or_else(|| field(path, format!("byte {at}"), format!("camera {id}: unknown model id {model_id}")))?;
        let width = b.u64("width")?;
        let height = b.u64("height")?;
        let params = (0..count).map(|_| b.f64("params")).collect::<Result<Vec<_>, _>>()?;
        out.push(ColmapCamera { id, model: model.to_string(), width, height, params });
    }
    Ok(out)
}

/// `images.bin`: a `u64` count, then per image `u32 image_id`, `f64 qw qx qy qz`, `f64 tx ty tz`,
/// `u32 camera_id`, the NUL-terminated name, a `u64` count of 2-D points and that many
/// `(f64 x, f64 y, i64 point3D_id)`, little-endian.
pub fn read_images_binary(path: &Path, bytes: &[u8]) -> Result<Vec<ColmapImage>, DatasetError> {
    let mut b = Bin { path, bytes, at: 0 };
    let n = b.count("number of images", 64 + 1 + 8)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = b.u32("image_id")?;
        let mut q = [0.0; 4];
        for v in &mut q {
            *v = b.f64("qvec")?;
        }
        let mut t = [0.0; 3];
        for v in &mut t {
            *v = b.f64("tvec")?;
        }
        let camera_id = b.u32("camera_id")?;
        let name = b.name("name")?;
        let points = b.count("number of 2-D points", 24)?;
        b.at += 24 * points;
        out.push(ColmapImage { id, qvec: q, tvec: t, camera_id, name });
    }
    Ok(out)
}

/// The pinhole part and the lens of a camera, by COLMAP's model (`colmap/sensor/models.h`):
/// `SIMPLE_PINHOLE` (f, cx, cy), `PINHOLE` (fx, fy, cx, cy), `SIMPLE_RADIAL` (f, cx, cy, k),
/// `RADIAL` (f, cx, cy, k1, k2) and `OPENCV` (fx, fy, cx, cy, k1, k2, p1, p2). COLMAP distorts
/// `SIMPLE_RADIAL` and `RADIAL` points as `OPENCV` does with the missing coefficients 0, so they
/// are read as that lens. Any other model is refused by name.
pub fn camera_lens(cam: &ColmapCamera) -> Result<(Intrinsics, OpenCvDistortion), String> {
    let p = &cam.params;
    let lens = |k1, k2, p1, p2| OpenCvDistortion { k1, k2, p1, p2 };
    let (fx, fy, cx, cy, d) = match (cam.model.as_str(), p.len()) {
        ("SIMPLE_PINHOLE", 3) => (p[0], p[0], p[1], p[2], OpenCvDistortion::default()),
        ("PINHOLE", 4) => (p[0], p[1], p[2], p[3], OpenCvDistortion::default()),
        ("SIMPLE_RADIAL", 4) => (p[0], p[0], p[1], p[2], lens(p[3], 0.0, 0.0, 0.0)),
        ("RADIAL", 5) => (p[0], p[0], p[1], p[2], lens(p[3], p[4], 0.0, 0.0)),
        ("OPENCV", 8) => (p[0], p[1], p[2], p[3], lens(p[4], p[5], p[6], p[7])),
        (m @ ("SIMPLE_PINHOLE" | "PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" | "OPENCV"), n) => {
            return Err(format!("{m} with {n} parameters"))
        }
        (m, _) => {
            return Err(format!(
                "model {m} is not supported: nerfsv reads SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV \
                 cameras"
            ))
        }
    };
    if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0 && cx.is_finite() && cy.is_finite()) {
        return Err(format!("focal lengths ({fx}, {fy}) must be positive and the principal point ({cx}, {cy}) finite"));
    }
    if ![d.k1, d.k2, d.p1, d.p2].iter().all(|c| c.is_finite()) {
        return Err(format!("distortion coefficients {:?} must be finite", [d.k1, d.k2, d.p1, d.p2]));
    }
    let size = |s: u64| u32::try_from(s).ok().filter(|&s| s > 0);
    let (Some(width), Some(height)) = (size(cam.width), size(cam.height)) else {
        return Err(format!("size {}×{} is not a positive 32-bit size", cam.width, cam.height));
    };
    let k = Intrinsics { width, height, fx: fx as f32, fy: fy as f32, cx: cx as f32, cy: cy as f32 };
    Ok((k, d))
}

/// An image's camera-to-world transform in OpenGL camera axes (module docs).
pub fn camera_to_world(image: &ColmapImage) -> Result<Matrix4<f32>, String> {
    let [w, x, y, z] = image.qvec;
    let norm = (w * w + x * x + y * y + z * z).sqrt();
    if !(norm.is_finite() && norm > 1e-12 && image.tvec.iter().all(|t| t.is_finite())) {
        return Err(format!("pose {:?} {:?} is not a finite rotation and translation", image.qvec, image.tvec));
    }
    let r: Matrix3<f64> =
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)).to_rotation_matrix().into_inner();
    let rt = r.transpose();
    let centre = -(rt * Vector3::from(image.tvec));
    let rot = rt * Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&rot.cast::<f32>());
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&centre.cast::<f32>());
    Ok(m)
}

/// Reads split `split` of the COLMAP folder `dir` (module docs).
pub(crate) fn load_colmap(dir: &Path, split: &str, opts: LoadOptions) -> Result<Split, DatasetError> {
    let model = read_model(dir)?;
    let mut images: Vec<&ColmapImage> = model.images.iter().collect();
    if images.is_empty() {
        return Err(field(&model.images_path, "images", "no registered images"));
    }
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let registered = images.len();
    let mut selected: Vec<(usize, &ColmapImage)> =
        images.into_iter().enumerate().filter(|(i, _)| in_split(split, *i)).collect();
    if selected.is_empty() {
        return Err(field(
            &model.images_path,
            "images",
            format!(
                "the {split} split has no frames: of the model's {registered} registered image(s), every 8th from the \
                 first is held out as val and test; a capture needs at least 2 images"
            ),
        ));
    }
    selected.truncate(opts.max_frames.unwrap_or(usize::MAX));
    let held = held_bytes(selected.iter().filter_map(|(_, im)| {
        let c = model.cameras.get(&im.camera_id)?;
        Some((c.width.min(u32::MAX as u64) as u32, c.height.min(u32::MAX as u64) as u32, false))
    }));
    MemoryBudget::current().check("images", held).map_err(|e| {
        field(&model.images_path, "images", format!("decoded images {}, found {}", e.expected, e.found))
    })?;
    let frames = selected.par_iter().map(|&(i, im)| colmap_frame(dir, &model, i, im, opts)).collect::<Vec<_>>();
    let frames = frames.into_iter().collect::<Result<Vec<_>, _>>()?;
    Ok(Split { name: split.to_string(), path: model.images_path.clone(), frames, aabb_scale: None })
}

/// Frame `i` (in name order) of a model: its camera, pose and undistorted image.
fn colmap_frame(
    dir: &Path,
    model: &ColmapModel,
    i: usize,
    im: &ColmapImage,
    opts: LoadOptions,
) -> Result<Frame, DatasetError> {
    let frame_field = |f: &str, message: String| DatasetError::Field {
        path: model.images_path.clone(),
        frame: Some(i),
        field: format!("image {:?}: {f}", im.name),
        message,
    };
    check_inside(&im.name).map_err(|m| frame_field("NAME", m))?;
    let cam = model.cameras.get(&im.camera_id).ok_or_else(|| {
        frame_field("CAMERA_ID", format!("camera {} is not in {}", im.camera_id, model.cameras_path.display()))
    })?;
    let (k, distortion) = camera_lens(cam).map_err(|m| DatasetError::Field {
        path: model.cameras_path.clone(),
        frame: Some(i),
        field: format!("image {:?}: camera {}", im.name, cam.id),
        message: m,
    })?;
    let c2w = camera_to_world(im).map_err(|m| frame_field("QW…TZ", m))?;
    let image_path = dir.join("images").join(&im.name);
    let image_err = |message: String| DatasetError::Image {
        path: model.images_path.clone(),
        frame: i,
        field: "NAME",
        file: image_path.clone(),
        message,
    };
    let image = read_frame_image(&image_path, Some((k.width, k.height))).map_err(image_err)?;
    if (image.width, image.height) != (k.width, k.height) {
        return Err(image_err(format!(
            "image is {}×{}, camera {} says {}×{}",
            image.width, image.height, cam.id, k.width, k.height
        )));
    }
    let f = opts.downscale;
    if k.width / f == 0 || k.height / f == 0 {
        return Err(frame_field("NAME", format!("downscale {f} leaves an empty image")));
    }
    let raw = RawFrame { file_path: im.name.clone(), image_path, intrinsics: k, distortion, c2w, image, depth: None };
    Ok(raw.finish(f))
}

/// The files a COLMAP folder's loader reads: the model files and, as far as the images file
/// can be read, the images it names (`images/NAME`).
pub(crate) fn colmap_files(dir: &Path) -> Vec<PathBuf> {
    let Some((cameras, images)) = model_files(dir) else { return Vec::new() };
    let mut files: Vec<PathBuf> = read_model(dir)
        .map(|m| {
            m.images
                .iter()
                .filter(|im| check_inside(&im.name).is_ok())
                .map(|im| dir.join("images").join(&im.name))
                .collect()
        })
        .unwrap_or_default();
    files.extend([cameras, images]);
    files
}
