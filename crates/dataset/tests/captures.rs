//! Captures written in their tools' documented layouts (`tests/fixtures/captures/make_captures.py`:
//! a nerfstudio `transforms.json` with OpenCV distortion, split lists, JPEG and PNG frames; one
//! COLMAP model as text and as binary) load with the cameras, splits and pixels the script made,
//! computed there independently of this crate.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Point3, Vector3};
use nerfsv_dataset::{
    dataset_files, load_split, DepthImage, Frame, Image, LoadOptions, OpenCvDistortion, Placement, Split,
};
use nerfsv_scene::mesh::UpAxis;
use nerfsv_scene::{Camera, Intrinsics};
use serde_json::Value;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/captures")
}

fn expected() -> Value {
    serde_json::from_str(&std::fs::read_to_string(fixtures().join("expected.json")).unwrap()).unwrap()
}

fn vec3(v: &Value) -> Vector3<f32> {
    Vector3::new(v[0].as_f64().unwrap() as f32, v[1].as_f64().unwrap() as f32, v[2].as_f64().unwrap() as f32)
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

fn load(dir: &Path, split: &str) -> Split {
    load_split(dir, split, LoadOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
}

fn names(split: &Split) -> Vec<&str> {
    split.frames.iter().map(|f| f.file_path.as_str()).collect()
}

/// Copies a fixture folder into a temporary one, to be edited.
fn copy_of(name: &str) -> tempfile::TempDir {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap().flatten() {
            let target = to.join(e.file_name());
            if e.path().is_dir() {
                copy(&e.path(), &target);
            } else {
                std::fs::copy(e.path(), target).unwrap();
            }
        }
    }
    let dir = tempfile::tempdir().unwrap();
    copy(&fixtures().join(name), dir.path());
    dir
}

/// The frame's camera is where the script put it: centre, viewing direction, image-up
/// direction, and the ray through the point's pinhole projection passes through the point.
fn check_camera(frame: &Frame, want: &Value, point: Point3<f32>) {
    let name = &frame.file_path;
    let cam = &frame.camera;
    assert!((cam.position().coords - vec3(&want["position"])).norm() < 1e-5, "{name}: {}", cam.position());
    assert!((cam.forward() - vec3(&want["forward"])).norm() < 1e-5, "{name}: forward {}", cam.forward());
    let up: Vector3<f32> = cam.c2w.fixed_view::<3, 1>(0, 1).into();
    assert!((up - vec3(&want["up"])).norm() < 1e-5, "{name}: up {up}");
    let p = &want["pinhole"];
    let ray = cam.ray(f(&p[0]) as f32, f(&p[1]) as f32);
    let to_point = point - ray.origin;
    let miss = (to_point - ray.direction * to_point.dot(&ray.direction)).norm();
    assert!(miss < 1e-4, "{name}: the ray through the point's projection misses it by {miss} m");
}

#[test]
fn colmap_text_and_binary_load_the_cameras_the_script_posed() {
    let truth = expected();
    let point = Point3::from(vec3(&truth["point"]));
    let images = truth["colmap"]["images"].as_array().unwrap();
    let mut loaded = Vec::new();
    for form in ["colmap_text", "colmap_bin"] {
        let dir = fixtures().join(form);
        for split in ["train", "val", "test"] {
            let s = load(&dir, split);
            let list = if split == "test" { "val" } else { split };
            let want: Vec<&str> =
                truth["colmap"]["splits"][list].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
            assert_eq!(names(&s), want, "{form} {split}: every 8th image in name order is held out");
            assert!(s.path.ends_with(if form == "colmap_text" { "images.txt" } else { "images.bin" }));
            for frame in &s.frames {
                let want = images.iter().find(|im| im["name"] == frame.file_path.as_str()).unwrap();
                check_camera(frame, want, point);
                let k = frame.camera.intrinsics;
                let w = &want["intrinsics"];
                assert_eq!((k.width, k.height), (16, 12));
                for (got, key) in [(k.fx, "fx"), (k.fy, "fy"), (k.cx, "cx"), (k.cy, "cy")] {
                    assert_eq!(got as f64, f(&w[key]), "{form} {}: {key}", frame.file_path);
                }
                assert_eq!(frame.image_path, dir.join("images").join(&frame.file_path));
            }
            loaded.push(s);
        }
    }
    // Text and binary: the same cameras (to f32 rounding of the text's decimals) and pixels.
    let (text, bin) = loaded.split_at(3);
    for (t, b) in text.iter().zip(bin) {
        for (ft, fb) in t.frames.iter().zip(&b.frames) {
            assert_eq!(ft.camera.intrinsics, fb.camera.intrinsics);
            assert!((ft.camera.c2w - fb.camera.c2w).abs().max() < 1e-6, "{}", ft.file_path);
            assert_eq!(ft.image, fb.image, "{}", ft.file_path);
        }
    }
}

#[test]
fn nerfstudio_capture_honours_its_split_lists_poses_and_intrinsics() {
    let truth = expected();
    let ns = &truth["nerfstudio"];
    let point = Point3::from(vec3(&truth["point"]));
    let dir = fixtures().join("nerfstudio");
    for split in ["train", "val", "test"] {
        let s = load(&dir, split);
        let want: Vec<&str> = ns["splits"][split].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        assert_eq!(names(&s), want, "{split}");
        for frame in &s.frames {
            let want = ns["frames"].as_array().unwrap().iter().find(|w| w["file_path"] == frame.file_path.as_str());
            check_camera(frame, want.unwrap(), point);
            let k = frame.camera.intrinsics;
            let w = &ns["intrinsics"];
            assert_eq!(
                (k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64),
                (f(&w["fx"]), f(&w["fy"]), f(&w["cx"]), f(&w["cy"]))
            );
        }
    }
}

#[test]
fn undistorted_png_frame_samples_the_distorted_image_where_opencv_says() {
    let truth = expected();
    let ns = &truth["nerfstudio"];
    let test = load(&fixtures().join("nerfstudio"), "test");
    let frame = &test.frames[0];
    assert_eq!(frame.file_path, ns["png_frame"].as_str().unwrap());
    let (mut interior, mut outside) = (0, 0);
    for s in ns["png_samples"].as_array().unwrap() {
        let (i, j, u, v) = (s[0].as_u64().unwrap() as u32, s[1].as_u64().unwrap() as u32, f(&s[2]), f(&s[3]));
        let px = frame.image.pixel(i, j);
        if (0.5..=15.5).contains(&u) && (0.5..=11.5).contains(&v) {
            // The gradient red = 16 u, green = 20 v, read back at the sampled position.
            assert!((px[0] as f64 * 255.0 - 16.0 * u).abs() < 1e-3, "({i}, {j}): red {} vs 16·{u}", px[0] * 255.0);
            assert!((px[1] as f64 * 255.0 - 20.0 * v).abs() < 1e-3, "({i}, {j}): green {} vs 20·{v}", px[1] * 255.0);
            assert!((px[3] - 1.0).abs() < 1e-6, "({i}, {j}): alpha {}", px[3]);
            interior += 1;
        } else if !((0.0..=16.0).contains(&u) && (0.0..=12.0).contains(&v)) {
            assert_eq!(px[3], 0.0, "({i}, {j}) samples ({u}, {v}), outside the image: transparent");
            outside += 1;
        }
    }
    assert!(interior > 100 && outside > 0, "{interior} interior, {outside} outside");
}

#[test]
fn a_known_distorted_point_lands_at_its_pinhole_projection() {
    let truth = expected();
    let ns = &truth["nerfstudio"];
    let k = |w: &Value| Intrinsics {
        width: 16,
        height: 12,
        fx: f(&w["fx"]) as f32,
        fy: f(&w["fy"]) as f32,
        cx: f(&w["cx"]) as f32,
        cy: f(&w["cy"]) as f32,
    };
    let lens = |d: &Value| OpenCvDistortion { k1: f(&d["k1"]), k2: f(&d["k2"]), p1: f(&d["p1"]), p2: f(&d["p2"]) };
    let mut cases: Vec<(Intrinsics, OpenCvDistortion, &Value)> =
        ns["frames"].as_array().unwrap().iter().map(|fr| (k(&ns["intrinsics"]), lens(&fr["distortion"]), fr)).collect();
    for im in truth["colmap"]["images"].as_array().unwrap().iter().filter(|im| im["camera_id"] == 3) {
        let p = &truth["colmap"]["cameras"][2]["params"];
        cases.push((
            k(&im["intrinsics"]),
            OpenCvDistortion { k1: f(&p[4]), k2: f(&p[5]), p1: f(&p[6]), p2: f(&p[7]) },
            im,
        ));
    }
    for (k, d, case) in cases {
        let (p, q) = (&case["pinhole"], &case["distorted"]);
        let (pu, pv) = d.undistort_pixel(&k, f(&q[0]), f(&q[1])).unwrap();
        assert!((pu - f(&p[0])).abs() < 1e-4 && (pv - f(&p[1])).abs() < 1e-4, "{case}: undistorted to ({pu}, {pv})");
        let (qu, qv) = d.distort_pixel(&k, f(&p[0]), f(&p[1])).unwrap();
        assert!((qu - f(&q[0])).abs() < 1e-4 && (qv - f(&q[1])).abs() < 1e-4, "{case}: distorted to ({qu}, {qv})");
    }
}

#[test]
fn distort_then_undistort_round_trips_within_1e_4_pixels() {
    let k = Intrinsics { width: 640, height: 480, fx: 500.0, fy: 490.0, cx: 321.0, cy: 238.5 };
    let d = OpenCvDistortion { k1: -0.2, k2: 0.05, p1: 0.004, p2: -0.003 };
    let mut worst: f64 = 0.0;
    for j in (0..=480).step_by(20) {
        for i in (0..=640).step_by(20) {
            let (u, v) = (i as f64, j as f64);
            let (du, dv) = d.distort_pixel(&k, u, v).unwrap();
            let (uu, uv) = d.undistort_pixel(&k, du, dv).unwrap();
            worst = worst.max((uu - u).hypot(uv - v));
        }
    }
    assert!(worst < 1e-4, "worst round trip {worst} px");
}

#[test]
fn jpeg_frames_decode_to_the_gradient_the_script_wrote() {
    let dir = fixtures().join("nerfstudio/images");
    // Baseline RGB, progressive RGB, greyscale.
    for (file, grey) in [("frame_00.jpg", false), ("frame_01.jpg", false), ("frame_02.jpg", true)] {
        let img = Image::read(&dir.join(file)).unwrap();
        assert_eq!((img.width, img.height), (16, 12), "{file}");
        let (mut worst, mut sum) = (0.0f32, 0.0f32);
        for j in 0..12 {
            for i in 0..16 {
                let px = img.pixel(i, j);
                let r = 16.0 * (i as f32 + 0.5);
                let want = if grey { [r, r, r] } else { [r, 20.0 * (j as f32 + 0.5), 128.0] };
                for c in 0..3 {
                    let e = (px[c] * 255.0 - want[c]).abs();
                    worst = worst.max(e);
                    sum += e;
                }
                assert_eq!(px[3], 1.0);
            }
        }
        let mean = sum / (16.0 * 12.0 * 3.0);
        assert!(worst <= 8.0 && mean <= 2.0, "{file}: worst {worst}, mean {mean} levels off the gradient");
    }
    // Told apart by the bytes, not the name: a JPEG called .png decodes as the JPEG.
    let tmp = tempfile::tempdir().unwrap();
    std::fs::copy(dir.join("frame_00.jpg"), tmp.path().join("frame.png")).unwrap();
    assert_eq!(Image::read(&tmp.path().join("frame.png")).unwrap(), Image::read(&dir.join("frame_00.jpg")).unwrap());
}

#[test]
fn an_image_neither_png_nor_jpeg_is_refused_naming_the_file() {
    let dir = copy_of("nerfstudio");
    std::fs::write(dir.path().join("images/frame_01.jpg"), b"GIF89a not a jpeg").unwrap();
    let e = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("frame_01.jpg") && e.contains("neither a PNG nor a JPEG") && e.contains("frame 1"), "{e}");
}

/// Edits the fixture's transforms.json and returns the error loading `split` gives.
fn nerfstudio_error(split: &str, edit: impl FnOnce(&mut Value)) -> String {
    let dir = copy_of("nerfstudio");
    let path = dir.path().join("transforms.json");
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut doc);
    std::fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
    load_split(dir.path(), split, LoadOptions::default()).unwrap_err().to_string()
}

#[test]
fn unsupported_camera_models_and_stray_coefficients_are_refused_by_name() {
    for model in ["OPENCV_FISHEYE", "EQUIRECTANGULAR"] {
        let e = nerfstudio_error("train", |d| d["camera_model"] = model.into());
        assert!(e.contains("transforms.json") && e.contains("frame 0") && e.contains(model), "{e}");
    }
    let e = nerfstudio_error("test", |d| d["camera_model"] = "PINHOLE".into());
    assert!(e.contains("frame 4") && e.contains("k1") && e.contains("PINHOLE"), "{e}");
    let e = nerfstudio_error("train", |d| d["k3"] = 0.1.into());
    assert!(e.contains("k3") && e.contains("OPENCV"), "{e}");
    // COLMAP, text and binary: the OPENCV camera (id 3, model id 4) made a fisheye.
    let dir = copy_of("colmap_text");
    let cams = dir.path().join("sparse/0/cameras.txt");
    std::fs::write(&cams, std::fs::read_to_string(&cams).unwrap().replace(" OPENCV ", " OPENCV_FISHEYE ")).unwrap();
    let e = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("cameras.txt") && e.contains("OPENCV_FISHEYE") && e.contains("img_02.jpg"), "{e}");
    let dir = copy_of("colmap_bin");
    let cams = dir.path().join("sparse/0/cameras.bin");
    let mut bytes = std::fs::read(&cams).unwrap();
    // Camera records: 8-byte count, then (id, model id, width, height, params) each.
    let third = 8 + (24 + 3 * 8) + (24 + 4 * 8);
    assert_eq!(bytes[third + 4], 4, "the third camera is OPENCV");
    bytes[third + 4] = 5;
    std::fs::write(&cams, bytes).unwrap();
    let e = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("cameras.bin") && e.contains("OPENCV_FISHEYE"), "{e}");
}

#[test]
fn split_lists_must_name_frames_and_cover_every_split() {
    let e = nerfstudio_error("val", |d| d["val_filenames"] = serde_json::json!(["images/nowhere.jpg"]));
    assert!(e.contains("val_filenames") && e.contains("images/nowhere.jpg"), "{e}");
    let e = nerfstudio_error("test", |d| {
        d.as_object_mut().unwrap().remove("test_filenames");
    });
    assert!(e.contains("test_filenames") && e.contains("missing"), "{e}");
    // Without lists, every 8th frame (here frame 0) is val and test.
    let dir = copy_of("nerfstudio");
    let path = dir.path().join("transforms.json");
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for key in ["train_filenames", "val_filenames", "test_filenames"] {
        doc.as_object_mut().unwrap().remove(key);
    }
    std::fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
    assert_eq!(names(&load(dir.path(), "val")), ["images/frame_00.jpg"]);
    assert_eq!(names(&load(dir.path(), "test")), ["images/frame_00.jpg"]);
    assert_eq!(names(&load(dir.path(), "train")).len(), 4);
}

#[test]
fn placement_centres_turns_and_scales_a_known_camera() {
    // A camera at capture point (1, 2, 3) with the capture's axes; the capture is y-up.
    let mut c2w = Matrix4::identity();
    c2w[(0, 3)] = 1.0;
    c2w[(1, 3)] = 2.0;
    c2w[(2, 3)] = 3.0;
    let placement = Placement { scale: 2.0, up: UpAxis::Y, centre: [1.0, 0.0, 0.0] };
    let placed = placement.camera_to_world(&c2w);
    // Centre: (0, 2, 3); y up to z up: (0, −3, 2); scale: (0, −6, 4).
    let pos: Vector3<f32> = placed.fixed_view::<3, 1>(0, 3).into();
    assert!((pos - Vector3::new(0.0, -6.0, 4.0)).norm() < 1e-6, "{pos}");
    // The camera's axes turn with the capture and keep unit length: its up (capture +y) is +z.
    let cols: Vec<Vector3<f32>> = (0..3).map(|c| placed.fixed_view::<3, 1>(0, c).into()).collect();
    assert!((cols[0] - Vector3::x()).norm() < 1e-6 && (cols[1] - Vector3::z()).norm() < 1e-6);
    assert!((cols[2] + Vector3::y()).norm() < 1e-6);
    // Depths scale with the capture.
    let intr = Intrinsics::from_fov_x(2, 1, 1.0);
    let mut split = Split {
        name: "train".into(),
        path: "t.json".into(),
        frames: vec![Frame {
            file_path: "a".into(),
            image_path: "a.png".into(),
            camera: Camera::new(intr, c2w),
            image: Image::new(2, 1),
            depth: Some(DepthImage { width: 2, height: 1, metres: vec![0.0, 1.5] }),
        }],
        aabb_scale: None,
    };
    placement.place(&mut split);
    assert_eq!(split.frames[0].depth.as_ref().unwrap().metres, [0.0, 3.0]);
    assert!((split.frames[0].camera.position().coords - Vector3::new(0.0, -6.0, 4.0)).norm() < 1e-6);
    assert!(Placement { scale: 0.0, ..Placement::default() }
        .validate()
        .unwrap_err()
        .to_string()
        .contains("dataset_scale"));
    assert!(Placement { scale: f32::NAN, ..Placement::default() }.validate().is_err());
    let e = Placement { centre: [0.0, f32::INFINITY, 0.0], ..Placement::default() }.validate().unwrap_err();
    assert!(e.to_string().contains("dataset_centre[1]"), "{e}");
}

#[test]
fn a_placed_y_up_colmap_world_stands_z_up_at_scale() {
    let truth = expected();
    let placement = Placement { scale: 2.0, up: UpAxis::Y, centre: [0.5, 0.8, -0.2] };
    let mut split = load(&fixtures().join("colmap_text"), "train");
    placement.place(&mut split);
    let turn = |v: Vector3<f32>| Vector3::new(v.x, -v.z, v.y);
    for frame in &split.frames {
        let want =
            truth["colmap"]["images"].as_array().unwrap().iter().find(|im| im["name"] == frame.file_path.as_str());
        let want = want.unwrap();
        let pos = 2.0 * turn(vec3(&want["position"]) - Vector3::new(0.5, 0.8, -0.2));
        assert!((frame.camera.position().coords - pos).norm() < 1e-4, "{}", frame.file_path);
        assert!((frame.camera.forward() - turn(vec3(&want["forward"]))).norm() < 1e-5);
        // The capture's up (+y) is the world's +z: the cameras' image-up leans up.
        assert!(frame.camera.c2w[(2, 1)] > 0.5, "{}", frame.file_path);
    }
}

#[test]
fn downscaling_a_colmap_split_halves_its_intrinsics() {
    let full = load(&fixtures().join("colmap_text"), "val");
    let half = load_split(
        &fixtures().join("colmap_text"),
        "val",
        LoadOptions { downscale: 2, load_depth: true, ..Default::default() },
    )
    .unwrap();
    let (a, b) = (full.frames[0].camera.intrinsics, half.frames[0].camera.intrinsics);
    assert_eq!((b.width, b.height, b.fx, b.cx), (8, 6, a.fx / 2.0, a.cx / 2.0));
    assert_eq!((half.frames[0].image.width, half.frames[0].image.height), (8, 6));
}

#[test]
fn dataset_files_lists_a_colmap_models_files_and_images() {
    let dir = fixtures().join("colmap_bin");
    let files = dataset_files(&dir);
    for f in ["sparse/0/cameras.bin", "sparse/0/images.bin", "images/img_00.jpg", "images/img_08.jpg"] {
        assert!(files.contains(&dir.join(f)), "{f} in {files:?}");
    }
    assert_eq!(files.len(), 11);
    let ns = fixtures().join("nerfstudio");
    assert!(dataset_files(&ns).contains(&ns.join("images/frame_04.png")));
}

#[test]
fn every_truncation_of_a_binary_model_or_a_jpeg_is_an_error_not_a_panic() {
    use nerfsv_dataset::colmap::{read_cameras_binary, read_images_binary};
    let sparse = fixtures().join("colmap_bin/sparse/0");
    let cameras = std::fs::read(sparse.join("cameras.bin")).unwrap();
    let images = std::fs::read(sparse.join("images.bin")).unwrap();
    for n in 0..cameras.len() {
        let e = read_cameras_binary(Path::new("cameras.bin"), &cameras[..n]).unwrap_err().to_string();
        assert!(e.starts_with("cameras.bin: byte "), "{n}: {e}");
    }
    for n in 0..images.len() {
        let e = read_images_binary(Path::new("images.bin"), &images[..n]).unwrap_err().to_string();
        assert!(e.starts_with("images.bin: byte "), "{n}: {e}");
    }
    assert_eq!(read_images_binary(Path::new("images.bin"), &images).unwrap().len(), 9);
    // A count the file cannot hold is refused before anything is allocated for it.
    let mut huge = images.clone();
    huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(read_images_binary(Path::new("images.bin"), &huge).unwrap_err().to_string().contains("at most"));
    let jpeg = std::fs::read(fixtures().join("nerfstudio/images/frame_01.jpg")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("cut.jpg");
    for n in (0..jpeg.len()).step_by(7) {
        std::fs::write(&path, &jpeg[..n]).unwrap();
        let _ = Image::read(&path);
    }
}

#[test]
fn a_frames_own_distortion_overrides_the_top_level_one() {
    let truth = expected();
    let ns = &truth["nerfstudio"];
    let train = load(&fixtures().join("nerfstudio"), "train");
    let frame = train.frames.iter().find(|f| f.file_path == "images/frame_03.jpg").unwrap();
    let lens = |d: &Value| OpenCvDistortion { k1: f(&d["k1"]), k2: f(&d["k2"]), p1: f(&d["p1"]), p2: f(&d["p2"]) };
    let own = lens(&ns["frames"][3]["distortion"]);
    let top = lens(&ns["frames"][0]["distortion"]);
    assert_ne!(own, top);
    let k = frame.camera.intrinsics;
    // Mean red error, in levels, of the undistorted JPEG against the gradient sampled through a lens,
    // over pixels far enough out for the two lenses to differ.
    let error = |d: &OpenCvDistortion| {
        let (mut sum, mut n) = (0.0, 0);
        for j in 0..k.height {
            for i in 0..k.width {
                let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
                let r2 = ((u - k.cx as f64) / k.fx as f64).powi(2) + ((v - k.cy as f64) / k.fy as f64).powi(2);
                let (su, sv) = d.distort_pixel(&k, u, v).unwrap();
                if r2 > 0.15 && (0.5..=15.5).contains(&su) && (0.5..=11.5).contains(&sv) {
                    sum += (frame.image.pixel(i, j)[0] as f64 * 255.0 - 16.0 * su).abs();
                    n += 1;
                }
            }
        }
        assert!(n >= 10, "{n} pixels");
        sum / n as f64
    };
    let (with_own, with_top) = (error(&own), error(&top));
    assert!(with_own < 2.0 && with_top > 2.5 * with_own, "own lens {with_own} levels, top-level lens {with_top}");
}

/// The fixture's COLMAP folder `form` (`colmap_text` or `colmap_bin`) copied, its camera 3 (the
/// OPENCV one, the last in both files) made camera `model` (`model_id`) with `params`.
fn with_camera_3(form: &str, model: &str, model_id: u32, params: &[f64]) -> tempfile::TempDir {
    let dir = copy_of(form);
    if form == "colmap_text" {
        let path = dir.path().join("sparse/0/cameras.txt");
        let text = std::fs::read_to_string(&path).unwrap();
        let line = text.lines().find(|l| l.starts_with("3 OPENCV ")).unwrap();
        let shown: Vec<String> = params.iter().map(|p| format!("{p:?}")).collect();
        std::fs::write(&path, text.replace(line, &format!("3 {model} 16 12 {}", shown.join(" ")))).unwrap();
    } else {
        let path = dir.path().join("sparse/0/cameras.bin");
        let mut bytes = std::fs::read(&path).unwrap();
        // Camera records: 8-byte count, then (id, model id, width, height, params) each.
        let third = 8 + (24 + 3 * 8) + (24 + 4 * 8);
        assert_eq!(bytes[third..third + 8], [3, 0, 0, 0, 4, 0, 0, 0], "the third camera is OPENCV");
        bytes.truncate(third);
        bytes.extend(3u32.to_le_bytes());
        bytes.extend(model_id.to_le_bytes());
        bytes.extend(16u64.to_le_bytes());
        bytes.extend(12u64.to_le_bytes());
        params.iter().for_each(|p| bytes.extend(p.to_le_bytes()));
        std::fs::write(&path, bytes).unwrap();
    }
    dir
}

#[test]
fn simple_radial_and_radial_cameras_load_as_the_opencv_lens_they_are() {
    // COLMAP's SIMPLE_RADIAL (f, cx, cy, k) and RADIAL (f, cx, cy, k1, k2) are OPENCV with
    // fx = fy = f and the missing coefficients 0.
    let cases: [(&str, u32, &[f64], [f64; 8]); 2] = [
        ("SIMPLE_RADIAL", 2, &[14.0, 8.0, 6.0, -0.2], [14.0, 14.0, 8.0, 6.0, -0.2, 0.0, 0.0, 0.0]),
        ("RADIAL", 3, &[14.0, 8.0, 6.0, -0.2, 0.05], [14.0, 14.0, 8.0, 6.0, -0.2, 0.05, 0.0, 0.0]),
    ];
    for form in ["colmap_text", "colmap_bin"] {
        let pinhole = with_camera_3(form, "PINHOLE", 1, &[14.0, 14.0, 8.0, 6.0]);
        let pinhole = load(pinhole.path(), "train");
        for (model, id, params, opencv) in cases {
            let radial = with_camera_3(form, model, id, params);
            let equivalent = with_camera_3(form, "OPENCV", 4, &opencv);
            let (a, b) = (load(radial.path(), "train"), load(equivalent.path(), "train"));
            assert_eq!(names(&a), names(&b));
            let mut distorted = 0;
            for ((fa, fb), fp) in a.frames.iter().zip(&b.frames).zip(&pinhole.frames) {
                assert_eq!(fa.camera, fb.camera, "{form} {model} {}", fa.file_path);
                assert_eq!(fa.image, fb.image, "{form} {model} {}: undistorted as OPENCV", fa.file_path);
                distorted += usize::from(fa.image != fp.image);
            }
            // The lens is applied: camera 3's frames differ from a pinhole camera's.
            assert!(distorted > 0, "{form} {model}: no frame was undistorted");
        }
    }
}

#[test]
fn an_unknown_camera_model_is_a_typed_error_naming_the_file_and_the_model() {
    use nerfsv_dataset::DatasetError;
    let dir =
        with_camera_3("colmap_text", "FULL_OPENCV", 6, &[14.0, 14.0, 8.0, 6.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    match load_split(dir.path(), "train", LoadOptions::default()).unwrap_err() {
        DatasetError::Field { path, message, .. } => {
            assert!(path.ends_with("sparse/0/cameras.txt"), "{}", path.display());
            assert!(message.contains("FULL_OPENCV") && message.contains("SIMPLE_RADIAL, RADIAL"), "{message}");
        }
        e => panic!("not a field error: {e}"),
    }
    let dir = with_camera_3("colmap_bin", "", 99, &[]);
    match load_split(dir.path(), "train", LoadOptions::default()).unwrap_err() {
        DatasetError::Field { path, message, .. } => {
            assert!(path.ends_with("sparse/0/cameras.bin"), "{}", path.display());
            assert!(message.contains("unknown model id 99"), "{message}");
        }
        e => panic!("not a field error: {e}"),
    }
    // A known model with the wrong number of parameters names the model and the count.
    let dir = with_camera_3("colmap_text", "RADIAL", 3, &[14.0, 8.0, 6.0, -0.2]);
    let e = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("cameras.txt") && e.contains("RADIAL has 5 parameters, found 4"), "{e}");
}

#[test]
fn a_capture_expressed_with_any_signed_up_axis_places_to_the_same_world_poses() {
    // A capture point's coordinates for each up axis, from the world's (z-up) ones, written out
    // here rather than taken from `UpAxis::rotation`: the capture's up axis is the world's +z.
    let to_capture = |up: UpAxis, [x, y, z]: [f64; 3]| -> [f64; 3] {
        match up {
            UpAxis::Z => [x, y, z],
            UpAxis::Y => [x, z, -y],
            UpAxis::X => [z, y, -x],
            UpAxis::NegZ => [x, -y, -z],
            UpAxis::NegY => [x, -z, y],
            UpAxis::NegX => [-z, y, x],
        }
    };
    let centre_world = [0.3, -0.2, 0.1];
    let world = Placement { scale: 2.0, up: UpAxis::Z, centre: centre_world.map(|c| c as f32) };
    let mut want = load(&fixtures().join("nerfstudio"), "train");
    world.place(&mut want);
    assert_eq!(UpAxis::ALL.len(), 6);
    for up in UpAxis::ALL {
        let dir = copy_of("nerfstudio");
        let path = dir.path().join("transforms.json");
        let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        for frame in doc["frames"].as_array_mut().unwrap() {
            let m = frame["transform_matrix"].clone();
            let at = |r: usize, c: usize| f(&m[r][c]);
            // Each column of the 3×4 camera-to-world (axes and position) in capture coordinates.
            let cols: Vec<[f64; 3]> = (0..4).map(|c| to_capture(up, [at(0, c), at(1, c), at(2, c)])).collect();
            for (r, row) in frame["transform_matrix"].as_array_mut().unwrap().iter_mut().take(3).enumerate() {
                *row = serde_json::json!([cols[0][r], cols[1][r], cols[2][r], cols[3][r]]);
            }
        }
        std::fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
        let centre = to_capture(up, centre_world).map(|c| c as f32);
        let mut got = load(dir.path(), "train");
        Placement { scale: 2.0, up, centre }.place(&mut got);
        assert_eq!(names(&got), names(&want));
        for (g, w) in got.frames.iter().zip(&want.frames) {
            let err = (g.camera.c2w - w.camera.c2w).abs().max();
            assert!(err < 1e-5, "up {up}: {} is {err} off\n{}{}", g.file_path, g.camera.c2w, w.camera.c2w);
            assert_eq!(g.image, w.image);
        }
    }
}

/// `jpeg` with an APP1 `Exif` segment after its SOI marker whose IFD0 holds orientation `value`
/// (big-endian TIFF, as many cameras write it).
fn with_exif_orientation(jpeg: &[u8], value: u16) -> Vec<u8> {
    let mut tiff = b"MM\0\x2a\0\0\0\x08\0\x01".to_vec();
    tiff.extend(0x0112u16.to_be_bytes());
    tiff.extend(3u16.to_be_bytes());
    tiff.extend(1u32.to_be_bytes());
    tiff.extend(value.to_be_bytes());
    tiff.extend([0, 0, 0, 0, 0, 0]);
    let mut out = jpeg[..2].to_vec();
    out.extend([0xFF, 0xE1]);
    out.extend(((2 + 6 + tiff.len()) as u16).to_be_bytes());
    out.extend(b"Exif\0\0");
    out.extend(tiff);
    out.extend(&jpeg[2..]);
    out
}

#[test]
fn a_colmap_frames_exif_orientation_is_applied_where_its_camera_has_the_turned_size() {
    // img_00.jpg (16×12 stored) gets a camera of its own, SIMPLE_PINHOLE (nothing to undistort).
    let stored = Image::read(&fixtures().join("colmap_text/images/img_00.jpg")).unwrap();
    let jpeg = std::fs::read(fixtures().join("colmap_text/images/img_00.jpg")).unwrap();
    for orientation in 1..=8u16 {
        let turned = (5..=8).contains(&orientation);
        let shown = stored.oriented(orientation as u8);
        // The camera as a tool honouring the tag saw the image, and as COLMAP sees it (stored).
        for (w, h) in [(shown.width, shown.height), (16, 12)] {
            let dir = copy_of("colmap_text");
            std::fs::write(dir.path().join("images/img_00.jpg"), with_exif_orientation(&jpeg, orientation)).unwrap();
            let cams = dir.path().join("sparse/0/cameras.txt");
            let mut text = std::fs::read_to_string(&cams).unwrap();
            text.push_str(&format!("4 SIMPLE_PINHOLE {w} {h} 14.0 {} {}\n", w as f32 / 2.0, h as f32 / 2.0));
            std::fs::write(&cams, text).unwrap();
            let images = dir.path().join("sparse/0/images.txt");
            let text = std::fs::read_to_string(&images).unwrap();
            let line = text.lines().find(|l| l.ends_with(" img_00.jpg")).unwrap();
            let mut tokens: Vec<&str> = line.split_whitespace().collect();
            tokens[8] = "4";
            std::fs::write(&images, text.replace(line, &tokens.join(" "))).unwrap();
            // img_00 is the first image by name: val and test.
            let frame = &load(dir.path(), "val").frames[0];
            assert_eq!(frame.file_path, "img_00.jpg");
            let want = if (w, h) == (16, 12) { &stored } else { &shown };
            assert_eq!(&frame.image, want, "orientation {orientation}, camera {w}×{h}");
            assert_eq!((frame.camera.intrinsics.width, frame.camera.intrinsics.height), (w, h));
            if turned && (w, h) == (shown.width, shown.height) {
                assert_ne!(frame.image, stored, "orientation {orientation} turns the pixels");
            }
        }
    }
}

#[test]
fn a_nerfstudio_frames_exif_orientation_is_applied_where_the_frame_has_the_turned_size() {
    // frame_00.jpg (16×12 stored) tagged 6, a quarter turn clockwise, and given the turned size:
    // it loads as the turned pixels written out as they are, through the same lens.
    let jpeg = std::fs::read(fixtures().join("nerfstudio/images/frame_00.jpg")).unwrap();
    let shown = Image::read(&fixtures().join("nerfstudio/images/frame_00.jpg")).unwrap().oriented(6);
    assert_eq!((shown.width, shown.height), (12, 16));
    let capture = |image: Vec<u8>| {
        let dir = copy_of("nerfstudio");
        std::fs::write(dir.path().join("images/frame_00.jpg"), image).unwrap();
        let path = dir.path().join("transforms.json");
        let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        doc["frames"][0]["w"] = 12.into();
        doc["frames"][0]["h"] = 16.into();
        doc["frames"][0]["cx"] = 6.0.into();
        doc["frames"][0]["cy"] = 8.0.into();
        std::fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
        dir
    };
    let tagged = capture(with_exif_orientation(&jpeg, 6));
    let mut png = Vec::new();
    shown.write_png(&mut png).unwrap();
    let turned = capture(png);
    let (a, b) = (load(tagged.path(), "train"), load(turned.path(), "train"));
    assert_eq!(a.frames[0].file_path, "images/frame_00.jpg");
    assert_eq!((a.frames[0].image.width, a.frames[0].image.height), (12, 16));
    assert_eq!(a.frames[0].image, b.frames[0].image);
    // Without the tag, the stored 16×12 pixels do not fit the frame's 12×16: refused by name.
    let untagged = capture(jpeg);
    let e = load_split(untagged.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("frame_00.jpg") && e.contains("image is 16×12, transforms say 12×16"), "{e}");
}

#[test]
fn every_frame_of_a_capture_loads_once_whatever_its_splits() {
    let truth = expected();
    // Split lists: each frame in one split.
    let frames = nerfsv_dataset::load_all_frames(&fixtures().join("nerfstudio"), Placement::default()).unwrap();
    let mut names: Vec<&str> = frames.iter().map(|f| f.file_path.as_str()).collect();
    names.sort_unstable();
    let mut want: Vec<&str> =
        truth["nerfstudio"]["frames"].as_array().unwrap().iter().map(|v| v["file_path"].as_str().unwrap()).collect();
    want.sort_unstable();
    assert_eq!(names, want);
    // COLMAP without lists: val and test are the same every-8th frames, read once.
    for model in ["colmap_text", "colmap_bin"] {
        let frames = nerfsv_dataset::load_all_frames(&fixtures().join(model), Placement::default()).unwrap();
        assert_eq!(frames.len(), truth["colmap"]["images"].as_array().unwrap().len(), "{model}");
    }
    // Placed as the placement says.
    let placement = Placement { scale: 2.0, ..Placement::default() };
    let placed = nerfsv_dataset::load_all_frames(&fixtures().join("nerfstudio"), placement).unwrap();
    let unplaced = nerfsv_dataset::load_all_frames(&fixtures().join("nerfstudio"), Placement::default()).unwrap();
    let (a, b) = (placed[0].camera.position(), unplaced[0].camera.position());
    assert!((a.coords - 2.0 * b.coords).norm() < 1e-5, "{a} against 2 × {b}");
}
