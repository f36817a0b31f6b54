//! `transforms_{split}.json`: the Blender/NeRF-synthetic format, plus the instant-ngp and
//! nerfstudio variants (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` at the top level or per frame,
//! `aabb_scale`, `depth_file_path`).

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use nerfsv_scene::validate::{bytes_for, InvalidValue, MemoryBudget};
use nerfsv_scene::{Camera, Intrinsics};
use rayon::prelude::*;
use serde_json::{Map, Value};

use crate::error::DatasetError;
use nerfsv_scene::image::{DepthImage, Image};
use nerfsv_scene::views::{PosedImages, View};

/// One posed image of a split.
#[derive(Clone, Debug)]
pub struct Frame {
    /// `file_path` exactly as the transforms file gives it.
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
    /// The transforms file the split was read from.
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
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self { downscale: 1, load_depth: true }
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

/// Reads `dir/transforms_{split}.json` and its images. If that file does not exist but
/// `dir/transforms.json` does (instant-ngp, nerfstudio), every 8th frame of it forms the `val`
/// and `test` splits and the rest `train`.
pub fn load_split(dir: &Path, split: &str, opts: LoadOptions) -> Result<Split, DatasetError> {
    if opts.downscale == 0 {
        return Err(InvalidValue::new("downscale", "must be at least 1", 0).into());
    }
    let mut path = dir.join(format!("transforms_{split}.json"));
    let mut keep: Option<Box<dyn Fn(usize) -> bool>> = None;
    if !path.exists() && dir.join("transforms.json").exists() {
        path = dir.join("transforms.json");
        keep = Some(if split == "train" { Box::new(|i| i % 8 != 0) } else { Box::new(|i| i % 8 == 0) });
    }
    let text = std::fs::read_to_string(&path).map_err(|e| DatasetError::io(&path, e))?;
    let root: Value = serde_json::from_str(&quote_non_finite(&text))
        .map_err(|error| DatasetError::Json { path: path.clone(), error })?;
    let ctx = Ctx { path: &path, base: path.parent().unwrap_or(Path::new(".")) };
    let root = root.as_object().ok_or_else(|| ctx.field(None, "(root)", "expected a JSON object"))?;
    let top = ctx.partial_intrinsics(None, root)?;
    let depth_scale = match ctx.opt_f32(None, root, "depth_unit_scale_factor")? {
        Some(x) if x <= 0.0 => {
            return Err(ctx.field(None, "depth_unit_scale_factor", format!("must be positive, found {x}")))
        }
        other => other.unwrap_or(1e-3),
    };
    let aabb_scale = ctx.opt_f32(None, root, "aabb_scale")?;
    let frames = root
        .get("frames")
        .ok_or_else(|| ctx.field(None, "frames", "missing"))?
        .as_array()
        .ok_or_else(|| ctx.field(None, "frames", "expected an array"))?;
    if frames.is_empty() {
        return Err(ctx.field(None, "frames", "is empty"));
    }
    let mut top = top;
    if top.w.is_none() || top.h.is_none() {
        // Blender files give no size: every image must match the first one's.
        if let Some((w, h)) = frames.first().and_then(|f| first_image_size(&ctx, f)) {
            top.w = top.w.or(Some(w as f32));
            top.h = top.h.or(Some(h as f32));
        }
    }
    let selected: Vec<(usize, &Value)> =
        frames.iter().enumerate().filter(|(i, _)| keep.as_ref().is_none_or(|k| k(*i))).collect();
    ctx.check_held_bytes(&selected, opts)?;
    let frames = selected.par_iter().map(|&(i, v)| ctx.frame(i, v, &top, depth_scale, opts)).collect::<Vec<_>>();
    // Report the first failure in frame order, whichever thread met it first.
    let frames = frames.into_iter().collect::<Result<Vec<_>, _>>()?;
    Ok(Split { name: split.to_string(), path, frames, aabb_scale })
}

/// The files a dataset folder's loader reads, as far as its transforms files can be parsed:
/// every `transforms*.json` it would open and the images and depth images their frames name
/// (resolved as [`load_split`] resolves them, not followed through symbolic links). A guard
/// against writing over an input needs them: a split folder may be a link to another folder.
/// A transforms file that cannot be read or parsed lists only itself (loading it fails later,
/// by name).
pub fn dataset_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let names = ["transforms_train.json", "transforms_val.json", "transforms_test.json", "transforms.json"];
    for path in names.iter().map(|n| dir.join(n)).filter(|p| p.exists()) {
        let base = path.parent().unwrap_or(Path::new("."));
        let root = std::fs::read_to_string(&path)
            .ok()
            .and_then(|text| serde_json::from_str::<Value>(&quote_non_finite(&text)).ok());
        let frames = root.as_ref().and_then(|r| r.get("frames")).and_then(Value::as_array);
        for frame in frames.into_iter().flatten() {
            if let Some(f) = frame.get("file_path").and_then(Value::as_str).filter(|f| check_inside(f).is_ok()) {
                files.push(resolve_image(base, f));
            }
            if let Some(d) = frame.get("depth_file_path").and_then(Value::as_str).filter(|d| check_inside(d).is_ok()) {
                files.push(base.join(d));
            }
        }
        files.push(path);
    }
    files
}

/// Intrinsics fields as far as one JSON object gives them.
#[derive(Clone, Copy, Default)]
struct PartialIntrinsics {
    w: Option<f32>,
    h: Option<f32>,
    fl_x: Option<f32>,
    fl_y: Option<f32>,
    cx: Option<f32>,
    cy: Option<f32>,
    angle_x: Option<f32>,
    angle_y: Option<f32>,
}

impl PartialIntrinsics {
    fn overridden_by(self, o: PartialIntrinsics) -> Self {
        Self {
            w: o.w.or(self.w),
            h: o.h.or(self.h),
            fl_x: o.fl_x.or(self.fl_x),
            fl_y: o.fl_y.or(self.fl_y),
            cx: o.cx.or(self.cx),
            cy: o.cy.or(self.cy),
            angle_x: o.angle_x.or(self.angle_x),
            angle_y: o.angle_y.or(self.angle_y),
        }
    }
}

struct Ctx<'a> {
    path: &'a Path,
    base: &'a Path,
}

impl Ctx<'_> {
    fn field(&self, frame: Option<usize>, field: &str, message: impl Into<String>) -> DatasetError {
        DatasetError::Field { path: self.path.to_path_buf(), frame, field: field.to_string(), message: message.into() }
    }

    fn opt_f32(&self, frame: Option<usize>, obj: &Map<String, Value>, key: &str) -> Result<Option<f32>, DatasetError> {
        match obj.get(key) {
            None | Some(Value::Null) => Ok(None),
            // Finite as an f32: 1e300 is a finite f64 but an infinite f32.
            Some(v) => match v.as_f64().map(|x| x as f32) {
                Some(x) if x.is_finite() => Ok(Some(x)),
                _ => Err(self.field(frame, key, format!("expected a finite 32-bit number, found {v}"))),
            },
        }
    }

    fn partial_intrinsics(
        &self,
        frame: Option<usize>,
        obj: &Map<String, Value>,
    ) -> Result<PartialIntrinsics, DatasetError> {
        let positive = |key: &str| -> Result<Option<f32>, DatasetError> {
            match self.opt_f32(frame, obj, key)? {
                Some(x) if x <= 0.0 => Err(self.field(frame, key, format!("must be positive, found {x}"))),
                other => Ok(other),
            }
        };
        let angle = |key: &str| -> Result<Option<f32>, DatasetError> {
            match positive(key)? {
                Some(a) if a >= std::f32::consts::PI => {
                    Err(self.field(frame, key, format!("must be below π radians, found {a}")))
                }
                other => Ok(other),
            }
        };
        Ok(PartialIntrinsics {
            w: positive("w")?,
            h: positive("h")?,
            fl_x: positive("fl_x")?,
            fl_y: positive("fl_y")?,
            cx: self.opt_f32(frame, obj, "cx")?,
            cy: self.opt_f32(frame, obj, "cy")?,
            angle_x: angle("camera_angle_x")?,
            angle_y: angle("camera_angle_y")?,
        })
    }

    fn frame(
        &self,
        i: usize,
        v: &Value,
        top: &PartialIntrinsics,
        depth_scale: f32,
        opts: LoadOptions,
    ) -> Result<Frame, DatasetError> {
        let obj = v.as_object().ok_or_else(|| self.field(Some(i), "(frame)", "expected a JSON object"))?;
        let file_path = obj
            .get("file_path")
            .ok_or_else(|| self.field(Some(i), "file_path", "missing"))?
            .as_str()
            .ok_or_else(|| self.field(Some(i), "file_path", "expected a string"))?
            .to_string();
        check_inside(&file_path).map_err(|m| self.field(Some(i), "file_path", m))?;
        let c2w = self.matrix(i, obj)?;
        let image_path = resolve_image(self.base, &file_path);
        let image_err = |field: &'static str, file: &Path, message: String| DatasetError::Image {
            path: self.path.to_path_buf(),
            frame: i,
            field,
            file: file.to_path_buf(),
            message,
        };
        let image = Image::read_png(&image_path).map_err(|m| image_err("file_path", &image_path, m))?;
        let k = top.overridden_by(self.partial_intrinsics(Some(i), obj)?);
        let intr = self.intrinsics(i, &k, image.width, image.height)?;
        if (image.width, image.height) != (intr.width, intr.height) {
            return Err(image_err(
                "file_path",
                &image_path,
                format!("image is {}×{}, transforms say {}×{}", image.width, image.height, intr.width, intr.height),
            ));
        }
        let depth = match obj.get("depth_file_path").and_then(Value::as_str) {
            Some(d) if opts.load_depth => {
                check_inside(d).map_err(|m| self.field(Some(i), "depth_file_path", m))?;
                let dpath = self.base.join(d);
                let depth =
                    DepthImage::read_png(&dpath, depth_scale).map_err(|m| image_err("depth_file_path", &dpath, m))?;
                if (depth.width, depth.height) != (intr.width, intr.height) {
                    return Err(image_err(
                        "depth_file_path",
                        &dpath,
                        format!("depth is {}×{}, image is {}×{}", depth.width, depth.height, intr.width, intr.height),
                    ));
                }
                Some(depth.downscaled(opts.downscale))
            }
            _ => None,
        };
        let f = opts.downscale;
        if intr.width / f == 0 || intr.height / f == 0 {
            return Err(self.field(Some(i), "file_path", format!("downscale {f} leaves an empty image")));
        }
        Ok(Frame {
            file_path,
            image_path,
            camera: Camera::new(intr.downscaled(f), c2w),
            image: image.downscaled(f),
            depth,
        })
    }

    fn matrix(&self, i: usize, obj: &Map<String, Value>) -> Result<Matrix4<f32>, DatasetError> {
        let field = "transform_matrix";
        let rows = obj
            .get(field)
            .ok_or_else(|| self.field(Some(i), field, "missing"))?
            .as_array()
            .ok_or_else(|| self.field(Some(i), field, "expected an array of 4 rows"))?;
        if rows.len() != 4 {
            return Err(self.field(Some(i), field, format!("has {} rows, expected 4", rows.len())));
        }
        let mut m = Matrix4::zeros();
        for (r, row) in rows.iter().enumerate() {
            let row = row.as_array().ok_or_else(|| self.field(Some(i), field, format!("row {r} is not an array")))?;
            if row.len() != 4 {
                return Err(self.field(Some(i), field, format!("row {r} has {} columns, expected 4", row.len())));
            }
            for (c, x) in row.iter().enumerate() {
                match x.as_f64().map(|x| x as f32) {
                    Some(x) if x.is_finite() => m[(r, c)] = x,
                    _ => {
                        return Err(self.field(
                            Some(i),
                            field,
                            format!("entry [{r}][{c}] is {x}, expected a finite 32-bit number"),
                        ))
                    }
                }
            }
        }
        let rot = m.fixed_view::<3, 3>(0, 0);
        let ortho = (rot.transpose() * rot - nalgebra::Matrix3::identity()).abs().max();
        // A NaN (from overflowing products) is refused too.
        if ortho.is_nan() || ortho > 1e-2 {
            return Err(self.field(Some(i), field, "rotation part is not orthonormal (scaled or sheared pose)"));
        }
        Ok(m)
    }

    fn intrinsics(&self, i: usize, k: &PartialIntrinsics, img_w: u32, img_h: u32) -> Result<Intrinsics, DatasetError> {
        let width = k.w.map_or(img_w, |w| w.round() as u32);
        let height = k.h.map_or(img_h, |h| h.round() as u32);
        // Each focal length with the key it came from, for the error.
        let (fx, fx_key) = match (k.fl_x, k.angle_x) {
            (Some(f), _) => (f, "fl_x"),
            (None, Some(a)) => (0.5 * width as f32 / (0.5 * a).tan(), "camera_angle_x"),
            (None, None) => match (k.fl_y, k.angle_y) {
                (Some(f), _) => (f, "fl_y"),
                (None, Some(a)) => (0.5 * height as f32 / (0.5 * a).tan(), "camera_angle_y"),
                (None, None) => return Err(self.field(Some(i), "camera_angle_x", "missing (and no fl_x/fl_y given)")),
            },
        };
        let (fy, fy_key) = match (k.fl_y, k.angle_y) {
            (Some(f), _) => (f, "fl_y"),
            (None, Some(a)) => (0.5 * height as f32 / (0.5 * a).tan(), "camera_angle_y"),
            (None, None) => (fx, fx_key),
        };
        let (cx, cy) = (k.cx.unwrap_or(0.5 * width as f32), k.cy.unwrap_or(0.5 * height as f32));
        // Every pixel ray must be a finite direction: the image edges at most 10^6 focal
        // lengths off the optical axis (89.99994°).
        for (key, f, c_key, c, size) in [(fx_key, fx, "cx", cx, width), (fy_key, fy, "cy", cy, height)] {
            if !(f.is_finite() && f > 0.0) {
                return Err(self.field(
                    Some(i),
                    key,
                    format!("gives a focal length of {f} pixels, expected a positive number"),
                ));
            }
            let off_axis = c.abs().max((size as f32 - c).abs()) / f;
            if off_axis.is_nan() || off_axis > 1e6 {
                return Err(self.field(
                    Some(i),
                    &format!("{key}/{c_key}"),
                    format!(
                        "gives a focal length of {f} pixels with the principal point at {c}: the image edge lies \
                         {off_axis:e} focal lengths off the optical axis, expected at most 1e6"
                    ),
                ));
            }
        }
        Ok(Intrinsics { width, height, fx, fy, cx, cy })
    }

    /// Refuses a split whose decoded images (RGBA `f32`, plus `f32` depth where read) would
    /// not fit the memory budget, from the PNG headers, before any image is decoded: each
    /// image alone may fit while all of them, held at once, do not.
    fn check_held_bytes(&self, frames: &[(usize, &Value)], opts: LoadOptions) -> Result<(), DatasetError> {
        let held = frames
            .iter()
            .filter_map(|(_, v)| {
                let (w, h) = png_size(&resolve_image(self.base, v.get("file_path")?.as_str()?))?;
                let depth = opts.load_depth && v.get("depth_file_path").and_then(Value::as_str).is_some();
                Some(bytes_for(w as u64 * h as u64, if depth { 20 } else { 16 }))
            })
            .fold(0, u64::saturating_add);
        MemoryBudget::current()
            .check("frames", held)
            .map_err(|e| self.field(None, "frames", format!("decoded images {}, found {}", e.expected, e.found)))
    }
}

/// The size of frame 0's image from its PNG header, if it can be read (errors surface later,
/// with their frame, when the frame itself is loaded).
fn first_image_size(ctx: &Ctx, frame: &Value) -> Option<(u32, u32)> {
    png_size(&resolve_image(ctx.base, frame.get("file_path")?.as_str()?))
}

/// Width and height from a PNG's header, if it can be read.
fn png_size(path: &Path) -> Option<(u32, u32)> {
    let file = std::fs::File::open(path).ok()?;
    let reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().ok()?;
    let info = reader.info();
    Some((info.width, info.height))
}

/// The rule for the files a transforms file names: relative paths that stay inside the dataset
/// folder (`./train/r_0`, `a/../train/r_0`). An absolute path or one that climbs out of the
/// folder (`../other/r_0`) is refused: a dataset is one folder, and no command that writes into
/// another folder can then overwrite an image a dataset reads.
fn check_inside(file_path: &str) -> Result<(), String> {
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

/// Blender writes `./train/r_0` without an extension; instant-ngp and nerfstudio write one.
fn resolve_image(base: &Path, file_path: &str) -> PathBuf {
    let p = base.join(file_path);
    if p.extension().is_some() && p.exists() {
        return p;
    }
    let with_png = base.join(format!("{file_path}.png"));
    if with_png.exists() || p.extension().is_none() {
        with_png
    } else {
        p
    }
}

/// Python's `json` writes non-finite floats as bare `NaN`, `Infinity` and `-Infinity`, which are
/// not JSON. Quote them (outside string literals) so the field checks can name the entry.
fn quote_non_finite(text: &str) -> std::borrow::Cow<'_, str> {
    if !(text.contains("NaN") || text.contains("Infinity")) {
        return text.into();
    }
    let mut out = String::with_capacity(text.len() + 16);
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            out.push(c);
            rest = &rest[c.len_utf8()..];
            match (escaped, c) {
                (true, _) => escaped = false,
                (false, '\\') => escaped = true,
                (false, '"') => in_string = false,
                _ => {}
            }
            continue;
        }
        if let Some(tok) = ["-Infinity", "Infinity", "NaN"].into_iter().find(|t| rest.starts_with(t)) {
            out.push('"');
            out.push_str(tok);
            out.push('"');
            rest = &rest[tok.len()..];
            continue;
        }
        if c == '"' {
            in_string = true;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out.into()
}
