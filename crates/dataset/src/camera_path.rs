//! Camera paths as nerfstudio's viewer exports them (`camera_path.json`, the input of
//! `ns-render camera-path`): `render_width`, `render_height`, `fps` and a `camera_path` list
//! whose entries hold `camera_to_world` (16 numbers, a row-major 4×4 camera-to-world matrix,
//! OpenGL camera axes) and `fov` (the vertical field of view in degrees). Only perspective
//! cameras (`camera_type` absent or `"perspective"`) are read.

use std::path::Path;

use nalgebra::Matrix4;
use nerfsv_scene::{Camera, Intrinsics};
use serde_json::Value;

use crate::DatasetError;

/// The cameras of a path and the rate its author meant them to be played at.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    pub cameras: Vec<Camera>,
    pub fps: f64,
}

/// Reads a nerfstudio camera-path JSON file.
pub fn load_camera_path(path: &Path) -> Result<CameraPath, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    parse_camera_path(&text, path)
}

/// Parses a camera-path JSON text; `path` names the file in errors.
pub fn parse_camera_path(text: &str, path: &Path) -> Result<CameraPath, DatasetError> {
    let json: Value =
        serde_json::from_str(text).map_err(|error| DatasetError::Json { path: path.to_path_buf(), error })?;
    let field = |frame: Option<usize>, field: &str, message: String| DatasetError::Field {
        path: path.to_path_buf(),
        frame,
        field: field.to_owned(),
        message,
    };
    let size = |key: &str| -> Result<u32, DatasetError> {
        let v = json.get(key).ok_or_else(|| field(None, key, "missing".into()))?;
        v.as_u64()
            .filter(|&n| (1..=16384).contains(&n))
            .map(|n| n as u32)
            .ok_or_else(|| field(None, key, format!("must be a whole number of pixels from 1 to 16384, not {v}")))
    };
    let (width, height) = (size("render_width")?, size("render_height")?);
    let fps = match json.get("fps") {
        None => 24.0,
        Some(v) => v
            .as_f64()
            .filter(|f| f.is_finite() && *f > 0.0 && *f <= 1000.0)
            .ok_or_else(|| field(None, "fps", format!("must be a number in (0, 1000], not {v}")))?,
    };
    match json.get("camera_type").and_then(Value::as_str) {
        None | Some("perspective") => {}
        Some(other) => {
            return Err(field(None, "camera_type", format!("\"{other}\": only \"perspective\" cameras are rendered")))
        }
    }
    let list = json
        .get("camera_path")
        .and_then(Value::as_array)
        .filter(|l| !l.is_empty())
        .ok_or_else(|| field(None, "camera_path", "must be a non-empty list of cameras".into()))?;
    let cameras = list
        .iter()
        .enumerate()
        .map(|(i, cam)| {
            let m: Vec<f64> = cam
                .get("camera_to_world")
                .and_then(Value::as_array)
                .map(|a| a.iter().filter_map(Value::as_f64).collect())
                .filter(|m: &Vec<f64>| m.len() == 16 && m.iter().all(|x| x.is_finite()))
                .ok_or_else(|| field(Some(i), "camera_to_world", "must be a list of 16 finite numbers".into()))?;
            let fov = cam.get("fov").and_then(Value::as_f64).filter(|f| *f > 0.0 && *f < 180.0).ok_or_else(|| {
                field(Some(i), "fov", "must be a vertical field of view in degrees, in (0, 180)".into())
            })?;
            let c2w = Matrix4::from_row_slice(&m).map(|x| x as f32);
            let rotation = c2w.fixed_view::<3, 3>(0, 0);
            let orthonormal = (rotation.transpose() * rotation - nalgebra::Matrix3::identity()).abs().max() < 1e-3
                && rotation.determinant() > 0.0;
            if !orthonormal {
                return Err(field(Some(i), "camera_to_world", "its 3×3 block must be a rotation (scale-free)".into()));
            }
            let f = 0.5 * height as f32 / (0.5 * fov.to_radians() as f32).tan();
            let k = Intrinsics { width, height, fx: f, fy: f, cx: 0.5 * width as f32, cy: 0.5 * height as f32 };
            Ok(Camera::new(k, c2w))
        })
        .collect::<Result<_, _>>()?;
    Ok(CameraPath { cameras, fps })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path as nerfstudio's viewer writes one (keys it adds that we do not read included):
    /// the matrix is read row by row, the focal length from the vertical field of view.
    #[test]
    fn a_viewer_export_reads_as_its_cameras() {
        let text = r#"{
            "keyframes": [], "camera_type": "perspective", "render_height": 48, "render_width": 64,
            "fps": 12, "seconds": 0.25, "is_cycle": false, "smoothness_value": 0.5,
            "camera_path": [
              {"camera_to_world": [1,0,0,0.5, 0,1,0,-1, 0,0,1,2, 0,0,0,1], "fov": 90, "aspect": 1.333},
              {"camera_to_world": [0,-1,0,0, 1,0,0,0, 0,0,1,3, 0,0,0,1], "fov": 60, "aspect": 1.333}
            ]}"#;
        let p = parse_camera_path(text, Path::new("camera_path.json")).unwrap();
        assert_eq!(p.fps, 12.0);
        assert_eq!(p.cameras.len(), 2);
        let [a, b] = [&p.cameras[0], &p.cameras[1]];
        assert_eq!((a.intrinsics.width, a.intrinsics.height), (64, 48));
        assert!((a.intrinsics.fy - 24.0).abs() < 1e-4, "90° over 48 rows is a focal length of 24 px");
        assert!((b.intrinsics.fy - 24.0 * 3f32.sqrt()).abs() < 1e-3);
        assert_eq!(a.position(), nalgebra::Point3::new(0.5, -1.0, 2.0));
        // Row-major: the second camera's x axis (first column) is world +y.
        assert_eq!(b.c2w.fixed_view::<3, 1>(0, 0).into_owned(), nalgebra::Vector3::new(0.0, 1.0, 0.0));
    }

    #[test]
    fn a_bad_path_names_the_camera_and_the_field() {
        let bad = |body: &str| {
            let text = format!(r#"{{"render_height": 4, "render_width": 4, {body}}}"#);
            parse_camera_path(&text, Path::new("p.json")).unwrap_err().to_string()
        };
        let e = bad(r#""camera_path": [{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], "fov": 50},
                                         {"camera_to_world": [1,0,0], "fov": 50}]"#);
        assert!(e.contains("p.json: frame 1: camera_to_world"), "{e}");
        let e = bad(r#""camera_path": [{"camera_to_world": [2,0,0,0, 0,2,0,0, 0,0,2,0, 0,0,0,1], "fov": 50}]"#);
        assert!(e.contains("must be a rotation"), "{e}");
        let e = bad(r#""camera_type": "fisheye", "camera_path": []"#);
        assert!(e.contains("camera_type"), "{e}");
        let e = bad(r#""camera_path": []"#);
        assert!(e.contains("camera_path: must be a non-empty list"), "{e}");
    }
}
