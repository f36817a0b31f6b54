//! `transforms_{split}.json`: the Blender/NeRF-synthetic format, plus the instant-ngp and
//! nerfstudio variants (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` at the top level or per frame,
//! `aabb_scale`, `depth_file_path`, nerfstudio's `camera_model` with OpenCV distortion and its
//! `train_filenames` / `val_filenames` / `test_filenames` split lists).

use std::path::{Component, Path, PathBuf};

use nalgebra::Matrix4;
use nerfsv_scene::image::{image_size, DepthImage};
use nerfsv_scene::validate::MemoryBudget;
use nerfsv_scene::Intrinsics;
use rayon::prelude::*;
use serde_json::{Map, Value};

use crate::distortion::OpenCvDistortion;
use crate::error::DatasetError;
use crate::split::{check_inside, held_bytes, in_split, read_frame_image, Frame, LoadOptions, RawFrame, Split};

/// Reads split `split` from the transforms file `path`: all its frames when it is a
/// `transforms_{split}.json`; when it is a single `transforms.json` (`single`), the frames its
/// `{split}_filenames` list names or, without lists, every 8th frame (0, 8, 16, …) as `val` and
/// `test` and the others as `train`.
pub(crate) fn load_transforms(
    path: &Path,
    split: &str,
    single: bool,
    opts: LoadOptions,
) -> Result<Split, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    let root: Value = serde_json::from_str(&quote_non_finite(&text))
        .map_err(|error| DatasetError::Json { path: path.to_path_buf(), error })?;
    let ctx = Ctx { path, base: path.parent().unwrap_or(Path::new(".")) };
    let root = root.as_object().ok_or_else(|| ctx.field(None, "(root)", "expected a JSON object"))?;
    let mut top = ctx.partial_intrinsics(None, root)?;
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
    if top.w.is_none() || top.h.is_none() {
        // Blender files give no size: every image must match the first one's.
        if let Some((w, h)) = frames.first().and_then(|f| first_image_size(&ctx, f)) {
            top.w = top.w.or(Some(w as f32));
            top.h = top.h.or(Some(h as f32));
        }
    }
    let keep = match single {
        true => ctx.split_selection(root, frames, split)?,
        false => vec![true; frames.len()],
    };
    let mut selected: Vec<(usize, &Value)> = frames.iter().enumerate().filter(|(i, _)| keep[*i]).collect();
    if single && selected.is_empty() {
        return Err(ctx.field(
            None,
            "frames",
            format!(
                "the {split} split has no frames: of the file's {} frame(s), every 8th from the first is held out as val \
                 and test; a capture needs at least 2 frames",
                frames.len()
            ),
        ));
    }
    selected.truncate(opts.max_frames.unwrap_or(usize::MAX));
    ctx.check_held_bytes(&selected, opts)?;
    let frames = selected.par_iter().map(|&(i, v)| ctx.frame(i, v, root, &top, depth_scale, opts)).collect::<Vec<_>>();
    // Report the first failure in frame order, whichever thread met it first.
    let frames = frames.into_iter().collect::<Result<Vec<_>, _>>()?;
    Ok(Split { name: split.to_string(), path: path.to_path_buf(), frames, aabb_scale })
}

/// The files the transforms files of `dir` name, as far as they can be parsed: every
/// `transforms*.json` and the images and depth images their frames name (resolved as the loader
/// resolves them). A transforms file that cannot be read or parsed lists only itself.
pub(crate) fn transforms_files(dir: &Path) -> Vec<PathBuf> {
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
        root: &Map<String, Value>,
        top: &PartialIntrinsics,
        depth_scale: f32,
        opts: LoadOptions,
    ) -> Result<Frame, DatasetError> {
        let obj = v.as_object().ok_or_else(|| self.field(Some(i), "(frame)", "expected a JSON object"))?;
        let file_path = frame_file_path(obj).map_err(|m| self.field(Some(i), "file_path", m))?.to_string();
        check_inside(&file_path).map_err(|m| self.field(Some(i), "file_path", m))?;
        let c2w = self.matrix(i, obj)?;
        let distortion = self.distortion(i, root, obj)?;
        let image_path = resolve_image(self.base, &file_path);
        let image_err = |field: &'static str, file: &Path, message: String| DatasetError::Image {
            path: self.path.to_path_buf(),
            frame: i,
            field,
            file: file.to_path_buf(),
            message,
        };
        let k = top.overridden_by(self.partial_intrinsics(Some(i), obj)?);
        let size = k.w.zip(k.h).map(|(w, h)| (w.round() as u32, h.round() as u32));
        let image = read_frame_image(&image_path, size).map_err(|m| image_err("file_path", &image_path, m))?;
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
                Some(depth)
            }
            _ => None,
        };
        let f = opts.downscale;
        if intr.width / f == 0 || intr.height / f == 0 {
            return Err(self.field(Some(i), "file_path", format!("downscale {f} leaves an empty image")));
        }
        Ok(RawFrame { file_path, image_path, intrinsics: intr, distortion, c2w, image, depth }.finish(f))
    }

    /// The frame's lens: nerfstudio's `camera_model` (`"PINHOLE"` or absent: none; `"OPENCV"`:
    /// `k1`, `k2`, `p1`, `p2`), each key at the top level or overridden by the frame. Any other
    /// model is refused by name, and so is a nonzero coefficient the model does not have.
    fn distortion(
        &self,
        i: usize,
        root: &Map<String, Value>,
        obj: &Map<String, Value>,
    ) -> Result<OpenCvDistortion, DatasetError> {
        let model = match obj.get("camera_model").or_else(|| root.get("camera_model")) {
            None | Some(Value::Null) => "PINHOLE",
            Some(Value::String(m)) => m.as_str(),
            Some(other) => {
                return Err(self.field(Some(i), "camera_model", format!("expected a string, found {other}")))
            }
        };
        let supported: &[&str] = match model {
            "PINHOLE" | "SIMPLE_PINHOLE" => &[],
            "OPENCV" => &["k1", "k2", "p1", "p2"],
            other => {
                return Err(self.field(
                    Some(i),
                    "camera_model",
                    format!("{other:?} is not supported: nerfsv reads \"PINHOLE\" and \"OPENCV\" cameras"),
                ))
            }
        };
        let mut c = [0.0f64; 4];
        for (n, key) in ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"].into_iter().enumerate() {
            let value = match self.opt_f32(Some(i), obj, key)? {
                Some(x) => Some(x),
                None => self.opt_f32(None, root, key)?,
            };
            match value {
                Some(x) if x != 0.0 && !supported.contains(&key) => {
                    return Err(self.field(
                        Some(i),
                        key,
                        format!(
                            "is {x}, but camera_model {model:?} has no such coefficient{}",
                            if supported.is_empty() {
                                " (set camera_model to \"OPENCV\")".to_string()
                            } else {
                                String::new()
                            }
                        ),
                    ))
                }
                Some(x) if n < 4 => c[n] = x as f64,
                _ => {}
            }
        }
        Ok(OpenCvDistortion { k1: c[0], k2: c[1], p1: c[2], p2: c[3] })
    }

    /// Which frames form split `split` of a single `transforms.json`: those its
    /// `{split}_filenames` names (matched on the files the names and the frames' `file_path`s
    /// resolve to, as nerfstudio matches them), or without any split list every 8th frame as
    /// `val` and `test`. Once one list is given every split needs its own, as in nerfstudio.
    fn split_selection(
        &self,
        root: &Map<String, Value>,
        frames: &[Value],
        split: &str,
    ) -> Result<Vec<bool>, DatasetError> {
        let has_lists = ["train", "val", "test"].iter().any(|s| root.contains_key(&format!("{s}_filenames")));
        if !has_lists {
            return Ok((0..frames.len()).map(|i| in_split(split, i)).collect());
        }
        let key = format!("{split}_filenames");
        let names = root
            .get(&key)
            .ok_or_else(|| {
                self.field(
                    None,
                    &key,
                    "missing: the file lists the files of other splits, so every split needs its list",
                )
            })?
            .as_array()
            .ok_or_else(|| self.field(None, &key, "expected an array of file paths"))?;
        let resolved: Vec<Option<PathBuf>> = frames
            .iter()
            .map(|f| {
                f.as_object().and_then(|o| frame_file_path(o).ok()).map(|p| normalised(&resolve_image(self.base, p)))
            })
            .collect();
        let mut keep = vec![false; frames.len()];
        for (n, name) in names.iter().enumerate() {
            let name = name
                .as_str()
                .ok_or_else(|| self.field(None, &key, format!("entry {n} is {name}, expected a string")))?;
            let want = normalised(&resolve_image(self.base, name));
            let mut found = false;
            for (i, r) in resolved.iter().enumerate() {
                if r.as_ref() == Some(&want) {
                    keep[i] = true;
                    found = true;
                }
            }
            if !found {
                return Err(self.field(None, &key, format!("{name:?} is not the file_path of any frame")));
            }
        }
        if !keep.contains(&true) {
            return Err(self.field(None, &key, "is empty"));
        }
        Ok(keep)
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
    /// not fit the memory budget, from the image headers, before any image is decoded: each
    /// image alone may fit while all of them, held at once, do not.
    fn check_held_bytes(&self, frames: &[(usize, &Value)], opts: LoadOptions) -> Result<(), DatasetError> {
        let held = held_bytes(frames.iter().filter_map(|(_, v)| {
            let (w, h) = image_size(&resolve_image(self.base, v.get("file_path")?.as_str()?)).ok()?;
            Some((w, h, opts.load_depth && v.get("depth_file_path").and_then(Value::as_str).is_some()))
        }));
        MemoryBudget::current()
            .check("frames", held)
            .map_err(|e| self.field(None, "frames", format!("decoded images {}, found {}", e.expected, e.found)))
    }
}

/// A frame's `file_path`, or what is wrong with it.
fn frame_file_path(obj: &Map<String, Value>) -> Result<&str, &'static str> {
    obj.get("file_path").ok_or("missing")?.as_str().ok_or("expected a string")
}

/// `path` with its `.` components dropped and each `..` taken back with the component before it
/// (lexically: nothing is resolved on disk).
fn normalised(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if out.file_name().is_some() => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// The size of frame 0's image from its header, if it can be read (errors surface later,
/// with their frame, when the frame itself is loaded).
fn first_image_size(ctx: &Ctx, frame: &Value) -> Option<(u32, u32)> {
    image_size(&resolve_image(ctx.base, frame.get("file_path")?.as_str()?)).ok()
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
