//! Generates a Blender-format dataset by rendering a ground-truth [`Scene`].

use std::f32::consts::TAU;
use std::path::{Path, PathBuf};

use nalgebra::{Point3, Vector3};
use nerfsv_scene::folder::OutputKind;
use nerfsv_scene::validate::{bytes_for, in_range, InvalidValue, MemoryBudget};
use nerfsv_scene::{Camera, Intrinsics, RenderSettings, Scene};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::DatasetError;
use crate::writer::{write_split, FrameToWrite};
use crate::SPLITS;
use nerfsv_scene::image::{DepthImage, Image};

/// Bytes per held pixel: RGBA (4 × f32) and depth (f32).
const BYTES_PER_PIXEL: u64 = 16 + 4;

/// What to render. Defaults follow the paper: 200/150/150 views of 100×100 pixels.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GenerateOptions {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Views of the training split.
    pub train: usize,
    /// Views of the validation split.
    pub val: usize,
    /// Views of the test split.
    pub test: usize,
    /// Horizontal field of view in radians.
    pub camera_angle_x: f32,
    /// Seed of the camera placement.
    pub seed: u64,
    /// Distance of hemisphere cameras from the look-at point, metres `[min, max]`.
    pub radius: [f32; 2],
    /// Elevation of hemisphere cameras above the horizon, degrees `[min, max]`.
    pub elevation_deg: [f32; 2],
    /// Fraction of views taken low and close, at drone altitude (0.15–0.5 m) inside the
    /// scene looking roughly horizontally, instead of from the hemisphere.
    pub close_up_fraction: f32,
    /// Anti-aliasing: `n` gives n×n samples per pixel.
    pub supersample: u32,
}

impl Default for GenerateOptions {
    fn default() -> Self {
        Self {
            width: 100,
            height: 100,
            train: 200,
            val: 150,
            test: 150,
            camera_angle_x: 0.8,
            seed: 0,
            radius: [3.5, 5.0],
            elevation_deg: [15.0, 70.0],
            close_up_fraction: 0.0,
            supersample: 2,
        }
    }
}

impl GenerateOptions {
    /// How the views are rendered: the default lighting with this dataset's supersampling.
    pub fn render_settings(&self) -> RenderSettings {
        RenderSettings { supersample: self.supersample, ..RenderSettings::default() }
    }

    /// Rejects every value no generation could use, and a split whose images would not fit
    /// the memory budget, before any work is done. The error names the field and the value.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("width", self.width, 1, 8192)?;
        in_range("height", self.height, 1, 8192)?;
        in_range("train", self.train, 1, 100_000)?;
        in_range("val", self.val, 1, 100_000)?;
        in_range("test", self.test, 1, 100_000)?;
        let a = self.camera_angle_x;
        if !(a > 0.01 && a < 3.1) {
            return Err(InvalidValue::new("camera_angle_x", "must be strictly between 0.01 and 3.1 radians", a));
        }
        let [r0, r1] = self.radius;
        if !(r0 > 0.0 && r0 < 100.0) {
            return Err(InvalidValue::new("radius[0]", "must be strictly between 0 and 100 m", r0));
        }
        if !(r1 >= r0 && r1 < 100.0) {
            return Err(InvalidValue::new(
                "radius[1]",
                format!("must be at least radius[0] = {r0} and below 100 m"),
                r1,
            ));
        }
        let [e0, e1] = self.elevation_deg;
        in_range("elevation_deg[0]", e0, -90.0, 90.0)?;
        in_range("elevation_deg[1]", e1, e0, 90.0)?;
        in_range("close_up_fraction", self.close_up_fraction, 0.0, 1.0)?;
        in_range("supersample", self.supersample, 1, 8)?;
        // seed: every u64 is meaningful.
        let budget = MemoryBudget::current();
        let bytes = self.held_bytes();
        if bytes <= budget.bytes {
            return Ok(());
        }
        // Name the key whose excess over its default costs the most.
        let d = GenerateOptions::default();
        let lowered = [
            ("width", GenerateOptions { width: self.width.min(d.width), ..self.clone() }),
            ("height", GenerateOptions { height: self.height.min(d.height), ..self.clone() }),
            ("train", GenerateOptions { train: self.train.min(d.train), ..self.clone() }),
            ("val", GenerateOptions { val: self.val.min(d.val), ..self.clone() }),
            ("test", GenerateOptions { test: self.test.min(d.test), ..self.clone() }),
        ];
        let key = lowered.iter().map(|(k, o)| (*k, o.held_bytes())).min_by_key(|&(_, b)| b).map_or("width", |(k, _)| k);
        budget.check(key, bytes)
    }

    /// Bytes the generator holds at once: every rendered view of the largest split (RGBA and
    /// depth, `f32`) until the split is written.
    pub fn held_bytes(&self) -> u64 {
        let views = self.train.max(self.val).max(self.test) as u64;
        let pixels = self.width as u64 * self.height as u64;
        bytes_for(views.saturating_mul(pixels), BYTES_PER_PIXEL)
    }

    fn count(&self, split: &str) -> usize {
        match split {
            "train" => self.train,
            "val" => self.val,
            _ => self.test,
        }
    }
}

/// Camera poses of one split; deterministic in `(seed, split)`.
pub fn sample_cameras(scene: &Scene, opts: &GenerateOptions, split: &str) -> Vec<Camera> {
    let split_idx = SPLITS.iter().position(|s| *s == split).unwrap_or(0) as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ split_idx);
    let k = Intrinsics::from_fov_x(opts.width, opts.height, opts.camera_angle_x);
    let n = opts.count(split);
    let n_close = (opts.close_up_fraction * n as f32).round() as usize;
    (0..n)
        .map(
            |i| {
                if i < n - n_close {
                    hemisphere_camera(&mut rng, opts, k)
                } else {
                    close_up_camera(&mut rng, scene, k)
                }
            },
        )
        .collect()
}

fn hemisphere_camera(rng: &mut ChaCha8Rng, opts: &GenerateOptions, k: Intrinsics) -> Camera {
    let az = rng.random_range(0.0..TAU);
    // Uniform in solid angle between the two elevations.
    let (s0, s1) = (opts.elevation_deg[0].to_radians().sin(), opts.elevation_deg[1].to_radians().sin());
    let el = rng.random_range(s0..=s1).asin();
    let r = rng.random_range(opts.radius[0]..=opts.radius[1]);
    let target = Point3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), rng.random_range(0.1..0.3));
    let eye = target + Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * r;
    Camera::look_at(eye, target, Vector3::z(), k)
}

fn close_up_camera(rng: &mut ChaCha8Rng, scene: &Scene, k: Intrinsics) -> Camera {
    let eye = loop {
        let (r, a) = (rng.random_range(0.0f32..1.0).sqrt() * 1.05, rng.random_range(0.0..TAU));
        let p = Point3::new(r * a.cos(), r * a.sin(), rng.random_range(0.15..0.5));
        if scene.distance(&p) > 0.15 {
            break p;
        }
    };
    let yaw = rng.random_range(0.0..TAU);
    let pitch = rng.random_range(-25.0f32..5.0).to_radians();
    let dir = Vector3::new(pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin());
    Camera::look_at(eye, eye + dir, Vector3::z(), k)
}

/// What rendering a dataset reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetFigures {
    /// The scene's name, or the folder a dataset was read from.
    pub scene: String,
    pub views: usize,
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
    /// Primary rays (supersamples included) rendered per second; 0 for a dataset read, not rendered.
    pub primary_rays_per_second: f64,
}

/// [`generate`], timed: the dataset's figures.
pub fn render(
    scene: &Scene,
    out: &Path,
    opts: &GenerateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<DatasetFigures, DatasetError> {
    let start = std::time::Instant::now();
    generate(scene, out, opts, progress)?;
    let seconds = start.elapsed().as_secs_f64();
    let views = opts.train + opts.val + opts.test;
    let rays = views as f64 * (opts.width * opts.height) as f64 * (opts.supersample * opts.supersample) as f64;
    Ok(DatasetFigures {
        scene: scene.name.clone(),
        views,
        width: opts.width,
        height: opts.height,
        seconds,
        primary_rays_per_second: rays / seconds.max(1e-9),
    })
}

/// Renders every split of `scene` into the dataset folder `out`.
///
/// The dataset is built in a sibling temporary folder and renamed into place when complete,
/// so a failure or a kill never leaves a half-written dataset at `out`, which carries nerfsv's
/// marker ([`nerfsv_scene::folder`]). An existing `out` is replaced only if it is empty or a
/// dataset nerfsv rendered (its marker, or an earlier version's `scene.json`).
/// `progress(done, total)` is called after each rendered view.
pub fn generate(
    scene: &Scene,
    out: &Path,
    opts: &GenerateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(), DatasetError> {
    opts.validate()?;
    // Only a dataset nerfsv rendered is replaced; a user's capture or files are refused.
    nerfsv_scene::folder::check_folder("the dataset folder", out, OutputKind::Dataset)?;
    remove_stale_partials(out);
    let tmp = partial_dir(out);
    std::fs::create_dir_all(&tmp).map_err(|e| DatasetError::io(&tmp, e))?;
    let result = (|| {
        nerfsv_scene::folder::claim_folder("the dataset folder", &tmp, OutputKind::Dataset)?;
        let settings = opts.render_settings();
        let total = opts.train + opts.val + opts.test;
        let mut done = 0;
        for split in SPLITS {
            let cameras = sample_cameras(scene, opts, split);
            let frames: Vec<FrameToWrite> = cameras
                .into_iter()
                .map(|camera| {
                    let r = scene.render(&camera, &settings);
                    done += 1;
                    progress(done, total);
                    FrameToWrite {
                        camera,
                        image: Image { width: r.width, height: r.height, rgba: r.rgba },
                        depth: Some(DepthImage { width: r.width, height: r.height, metres: r.depth }),
                    }
                })
                .collect();
            write_split(&tmp, split, &frames)?;
        }
        let meta = serde_json::json!({ "scene": scene.name, "generator": "nerfsv", "options": opts });
        nerfsv_scene::io::atomic_write(&tmp.join("scene.json"), |w| {
            serde_json::to_writer_pretty(w, &meta).map_err(std::io::Error::other)
        })
        .map_err(|e| DatasetError::io(tmp.join("scene.json"), e))
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    if out.exists() {
        std::fs::remove_dir_all(out).map_err(|e| DatasetError::io(out, e))?;
    }
    std::fs::rename(&tmp, out).map_err(|e| DatasetError::io(out, e))
}

/// Removes the temporary folders of earlier generations of `out` that were killed.
fn remove_stale_partials(out: &Path) {
    let Some(name) = out.file_name().map(|n| n.to_string_lossy().into_owned()) else { return };
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let prefix = format!(".{name}.partial-");
    if let Ok(entries) = std::fs::read_dir(parent) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}

fn partial_dir(out: &Path) -> PathBuf {
    let name = out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into());
    out.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}
