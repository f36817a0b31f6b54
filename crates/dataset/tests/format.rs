//! The Blender format: rays, depth, round trips, the instant-ngp/nerfstudio variants and
//! the messages bad input gets.

use std::fs;
use std::path::Path;

use nalgebra::{Point3, Vector3};
use nerfsv_dataset::{
    generate, load_split, write_split, DepthImage, FrameToWrite, GenerateOptions, Image, LoadOptions,
};
use nerfsv_scene::{Camera, Intrinsics, RenderSettings, Scene};

/// A camera at (0, −4, 1) looking along +y: right = +x, up = +z, back = −y.
const LOOK_ALONG_Y: [[f32; 4]; 4] =
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]];

fn write_png(path: &Path, img: &Image) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    img.write_png(fs::File::create(path).unwrap()).unwrap();
}

fn write_json(path: &Path, v: &serde_json::Value) {
    fs::write(path, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

fn small_options() -> GenerateOptions {
    GenerateOptions { width: 16, height: 12, train: 3, val: 2, test: 2, supersample: 1, ..GenerateOptions::default() }
}

#[test]
fn pixel_ray_matches_hand_computed_blender_direction() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("train/r_0.png"), &Image::new(100, 100));
    let doc = serde_json::json!({
        "camera_angle_x": 0.8,
        "frames": [{ "file_path": "./train/r_0", "transform_matrix": LOOK_ALONG_Y }],
    });
    write_json(&dir.path().join("transforms_train.json"), &doc);
    let split = load_split(dir.path(), "train", LoadOptions::default()).unwrap();
    let cam = split.frames[0].camera;
    let f = 50.0 / 0.4f32.tan();
    // Pixel (0, 0) is the top-left: left (−x) and up (+z) of the optical axis (+y).
    let expected = Vector3::new(-49.5 / f, 1.0, 49.5 / f).normalize();
    let ray = cam.pixel_ray(0, 0);
    assert!((ray.direction - expected).norm() < 1e-6, "{} vs {}", ray.direction, expected);
    assert!((ray.origin - Point3::new(0.0, -4.0, 1.0)).norm() < 1e-6);
    // The principal point looks straight down the optical axis.
    assert!((cam.ray(50.0, 50.0).direction - Vector3::y()).norm() < 1e-6);
}

#[test]
fn depth_along_pixel_rays_matches_analytic_ground_plane() {
    // Camera looking down onto the empty part of the monolith scene's ground (z = 0).
    let scene = Scene::builtin("monolith").unwrap();
    let cam = Camera::look_at(
        Point3::new(0.9, -0.6, 1.2),
        Point3::new(1.0, -0.9, 0.0),
        Vector3::z(),
        Intrinsics::from_fov_x(24, 20, 0.6),
    );
    let r = scene.render(&cam, &RenderSettings { supersample: 1, ..Default::default() });
    let dir = tempfile::tempdir().unwrap();
    let frame = FrameToWrite {
        camera: cam,
        image: Image { width: 24, height: 20, rgba: r.rgba },
        depth: Some(DepthImage { width: 24, height: 20, metres: r.depth }),
    };
    write_split(dir.path(), "test", &[frame]).unwrap();
    let split = load_split(dir.path(), "test", LoadOptions::default()).unwrap();
    let f = &split.frames[0];
    let depth = f.depth.as_ref().unwrap();
    let mut checked = 0;
    for j in 0..20 {
        for i in 0..24 {
            let ray = f.camera.pixel_ray(i, j);
            let t = -ray.origin.z / ray.direction.z;
            let hit = ray.at(t);
            if ray.direction.z >= 0.0 || hit.coords.xy().norm() > 1.7 || scene.distance(&hit) < -1e-3 {
                continue;
            }
            if (scene.distance(&hit)).abs() > 1e-3 {
                continue; // something else is in front of the plane along this ray
            }
            let z_depth = t * f.camera.z_depth_factor(i as f32 + 0.5, j as f32 + 0.5);
            let got = depth.metres[(j * 24 + i) as usize];
            assert!((got - z_depth).abs() <= 1.5e-3, "pixel ({i},{j}): {got} vs {z_depth}");
            assert_eq!(f.image.pixel(i, j)[3], 1.0);
            checked += 1;
        }
    }
    assert!(checked > 300, "only {checked} pixels checked");
}

#[test]
fn generated_dataset_round_trips_poses_and_pixels() {
    let scene = Scene::builtin("monolith").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let opts = small_options();
    generate(&scene, &out, &opts, &|_, _| {}).unwrap();
    for (split, n) in [("train", 3), ("val", 2), ("test", 2)] {
        let s = load_split(&out, split, LoadOptions::default()).unwrap();
        assert_eq!(s.frames.len(), n);
        let cams = nerfsv_dataset::sample_cameras(&scene, &opts, split);
        for (f, cam) in s.frames.iter().zip(&cams) {
            assert_eq!(f.camera.c2w, cam.c2w, "{split}: poses must survive JSON exactly");
            let k = f.camera.intrinsics;
            assert!((k.fx - cam.intrinsics.fx).abs() < 1e-4 && k.width == 16 && k.height == 12);
            let r = scene.render(cam, &RenderSettings { supersample: 1, ..Default::default() });
            for (a, b) in f.image.rgba.iter().zip(&r.rgba) {
                assert!((a - b.clamp(0.0, 1.0)).abs() <= 0.5 / 255.0 + 1e-6);
            }
            let d = f.depth.as_ref().unwrap();
            for (a, b) in d.metres.iter().zip(&r.depth) {
                assert!((a - b).abs() <= 0.5e-3 + 1e-6);
            }
        }
    }
    // The same seed gives the same files.
    let out2 = dir.path().join("ds2");
    generate(&scene, &out2, &opts, &|_, _| {}).unwrap();
    assert_eq!(fs::read(out.join("train/r_1.png")).unwrap(), fs::read(out2.join("train/r_1.png")).unwrap());
    assert_eq!(fs::read(out.join("transforms_val.json")).unwrap(), fs::read(out2.join("transforms_val.json")).unwrap());
}

#[test]
fn reads_nerfstudio_style_transforms_with_per_frame_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    for i in 0..8 {
        write_png(&dir.path().join(format!("images/frame_{i:05}.png")), &Image::new(32, 24));
    }
    let mut frames: Vec<serde_json::Value> = (0..8)
        .map(|i| serde_json::json!({ "file_path": format!("images/frame_{i:05}.png"), "transform_matrix": LOOK_ALONG_Y }))
        .collect();
    frames[1]["fl_x"] = serde_json::json!(40.0);
    frames[1]["cx"] = serde_json::json!(15.0);
    let doc = serde_json::json!({
        "camera_model": "OPENCV", "fl_x": 30.0, "fl_y": 31.0, "cx": 16.5, "cy": 11.5, "w": 32, "h": 24,
        "aabb_scale": 4, "frames": frames,
    });
    write_json(&dir.path().join("transforms.json"), &doc);
    let train = load_split(dir.path(), "train", LoadOptions::default()).unwrap();
    let test = load_split(dir.path(), "test", LoadOptions::default()).unwrap();
    assert_eq!((train.frames.len(), test.frames.len()), (7, 1));
    assert_eq!(train.aabb_scale, Some(4.0));
    let k0 = test.frames[0].camera.intrinsics;
    assert_eq!((k0.fx, k0.fy, k0.cx, k0.cy, k0.width, k0.height), (30.0, 31.0, 16.5, 11.5, 32, 24));
    // Frame 1 is the first training frame and overrides fl_x and cx.
    let k1 = train.frames[0].camera.intrinsics;
    assert_eq!((k1.fx, k1.fy, k1.cx), (40.0, 31.0, 15.0));
    // Downscaling halves the intrinsics and the image.
    let half =
        load_split(dir.path(), "test", LoadOptions { downscale: 2, load_depth: true, ..Default::default() }).unwrap();
    let k = half.frames[0].camera.intrinsics;
    assert_eq!((k.width, k.height, k.fx, k.cx), (16, 12, 15.0, 8.25));
    assert_eq!(half.frames[0].image.rgba.len(), 16 * 12 * 4);
}

/// Writes a one-frame-per-case dataset and returns the error message of loading it.
fn load_error(doc: serde_json::Value, setup: impl FnOnce(&Path)) -> String {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("train/r_0.png"), &Image::new(8, 8));
    write_png(&dir.path().join("train/r_1.png"), &Image::new(8, 8));
    setup(dir.path());
    write_json(&dir.path().join("transforms_train.json"), &doc);
    let err = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(err.contains("transforms_train.json"), "message must name the file: {err}");
    err
}

fn frames2() -> serde_json::Value {
    serde_json::json!([
        { "file_path": "./train/r_0", "transform_matrix": LOOK_ALONG_Y },
        { "file_path": "./train/r_1", "transform_matrix": LOOK_ALONG_Y },
    ])
}

#[test]
fn bad_transforms_get_messages_naming_file_frame_and_field() {
    let e = load_error(serde_json::json!({ "frames": frames2() }), |_| {});
    assert!(e.contains("camera_angle_x") && e.contains("missing"), "{e}");

    let mut frames = frames2();
    frames[1]["transform_matrix"] = serde_json::json!(&LOOK_ALONG_Y[..3]);
    let e = load_error(serde_json::json!({ "camera_angle_x": 0.8, "frames": frames }), |_| {});
    assert!(e.contains("frame 1") && e.contains("transform_matrix") && e.contains("3 rows, expected 4"), "{e}");

    let mut frames = frames2();
    frames[0].as_object_mut().unwrap().remove("file_path");
    let e = load_error(serde_json::json!({ "camera_angle_x": 0.8, "frames": frames }), |_| {});
    assert!(e.contains("frame 0") && e.contains("file_path") && e.contains("missing"), "{e}");

    let e = load_error(serde_json::json!({ "camera_angle_x": 0.8 }), |_| {});
    assert!(e.contains("frames") && e.contains("missing"), "{e}");
}

#[test]
fn nan_in_a_matrix_is_reported_with_its_entry() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("train/r_0.png"), &Image::new(8, 8));
    // As Python's json.dump writes a NaN.
    let text = r#"{"camera_angle_x": 0.8, "frames": [{"file_path": "./train/r_0",
        "transform_matrix": [[1, 0, 0, 0], [0, 0, -1, NaN], [0, 1, 0, 1], [0, 0, 0, 1]]}]}"#;
    fs::write(dir.path().join("transforms_train.json"), text).unwrap();
    let e = load_split(dir.path(), "train", LoadOptions::default()).unwrap_err().to_string();
    assert!(
        e.contains("frame 0") && e.contains("transform_matrix") && e.contains("[1][3]") && e.contains("NaN"),
        "{e}"
    );
}

#[test]
fn missing_truncated_and_missized_images_are_reported() {
    let doc = serde_json::json!({ "camera_angle_x": 0.8, "frames": frames2() });
    let e = load_error(doc.clone(), |d| fs::remove_file(d.join("train/r_1.png")).unwrap());
    assert!(e.contains("frame 1") && e.contains("r_1.png"), "{e}");

    let e = load_error(doc.clone(), |d| {
        let p = d.join("train/r_0.png");
        let bytes = fs::read(&p).unwrap();
        fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    });
    assert!(e.contains("frame 0") && e.contains("r_0.png"), "{e}");

    let e = load_error(doc.clone(), |d| write_png(&d.join("train/r_1.png"), &Image::new(6, 8)));
    assert!(e.contains("frame 1") && e.contains("6×8"), "{e}");

    let mut with_size = doc;
    with_size["w"] = serde_json::json!(16);
    with_size["h"] = serde_json::json!(16);
    let e = load_error(with_size, |_| {});
    assert!(e.contains("frame 0") && e.contains("image is 8×8, transforms say 16×16"), "{e}");
}

#[test]
fn invalid_options_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let scene = Scene::builtin("monolith").unwrap();
    for bad in [
        GenerateOptions { width: 0, ..small_options() },
        GenerateOptions { height: 100_000, ..small_options() },
        GenerateOptions { train: 0, ..small_options() },
        GenerateOptions { camera_angle_x: f32::NAN, ..small_options() },
    ] {
        let e = generate(&scene, &out, &bad, &|_, _| {}).unwrap_err().to_string();
        assert!(
            e.contains("width") || e.contains("height") || e.contains("train") || e.contains("camera_angle_x"),
            "{e}"
        );
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0, "nothing may be left behind");
    }
}

#[test]
fn refuses_to_overwrite_a_folder_that_is_not_a_dataset() {
    let dir = tempfile::tempdir().unwrap();
    fs::write(dir.path().join("precious.txt"), "keep me").unwrap();
    let scene = Scene::builtin("monolith").unwrap();
    let e = generate(&scene, dir.path(), &small_options(), &|_, _| {}).unwrap_err().to_string();
    assert!(
        e.contains("the dataset folder") && e.contains("precious.txt") && e.contains("nerfsv did not write"),
        "{e}"
    );
    assert!(dir.path().join("precious.txt").exists());
}

#[test]
fn a_killed_generation_leaves_only_a_hidden_partial_folder_that_the_next_run_removes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let stale = dir.path().join(".ds.partial-999999");
    fs::create_dir_all(stale.join("train")).unwrap();
    generate(&Scene::builtin("monolith").unwrap(), &out, &small_options(), &|_, _| {}).unwrap();
    assert!(!stale.exists());
    let names: Vec<_> = fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("ds")]);
}

#[test]
fn generate_options_refuse_nan_and_infinity_in_every_float_naming_the_field() {
    type Set = fn(&mut GenerateOptions, f32);
    let floats: [(&str, Set); 6] = [
        ("camera_angle_x", |o, v| o.camera_angle_x = v),
        ("radius[0]", |o, v| o.radius[0] = v),
        ("radius[1]", |o, v| o.radius[1] = v),
        ("elevation_deg[0]", |o, v| o.elevation_deg[0] = v),
        ("elevation_deg[1]", |o, v| o.elevation_deg[1] = v),
        ("close_up_fraction", |o, v| o.close_up_fraction = v),
    ];
    small_options().validate().unwrap();
    for v in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        for (name, set) in floats {
            let mut o = small_options();
            set(&mut o, v);
            let e = o.validate().expect_err(name);
            assert_eq!((e.field.as_str(), e.found.as_str()), (name, v.to_string().as_str()), "{e}");
        }
    }
    let e = GenerateOptions { supersample: 9, ..small_options() }.validate().unwrap_err();
    assert_eq!(e.to_string(), "supersample: must be between 1 and 8, found 9");
    let e = GenerateOptions { radius: [4.0, 3.0], ..small_options() }.validate().unwrap_err();
    assert_eq!(e.field, "radius[1]");
}

#[test]
fn generate_options_whose_images_cannot_fit_in_memory_are_refused_naming_the_key() {
    // 100000 views of 8192² pixels: each value in range, together ~125 TiB held at once.
    let o = GenerateOptions { width: 8192, height: 8192, train: 100_000, ..small_options() };
    assert!(o.held_bytes() > 100 << 40);
    let e = o.validate().unwrap_err();
    assert_eq!(e.field, "train", "{e}");
    assert!(e.expected.contains("memory budget") && e.found.contains("TiB"), "{e}");
    // Through `generate` it is a typed DatasetError naming the key, and nothing is written.
    let dir = tempfile::tempdir().unwrap();
    let err = generate(&Scene::builtin("monolith").unwrap(), &dir.path().join("ds"), &o, &|_, _| {}).unwrap_err();
    assert!(matches!(&err, nerfsv_dataset::DatasetError::Invalid(e) if e.field == "train"), "{err}");
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn a_zero_downscale_is_a_typed_error_naming_downscale() {
    let dir = tempfile::tempdir().unwrap();
    let err = load_split(dir.path(), "train", LoadOptions { downscale: 0, load_depth: true, ..Default::default() })
        .unwrap_err();
    assert_eq!(err.to_string(), "downscale: must be at least 1, found 0");
}

/// The rule for the files a dataset names: inside its folder, however written, or refused.
#[test]
fn files_outside_the_dataset_folder_are_refused_and_inside_ones_load_however_written() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    write_png(&data.join("train/r_0.png"), &Image::new(8, 8));
    write_png(&dir.path().join("elsewhere/r_1.png"), &Image::new(8, 8));
    let doc = |paths: &[&str]| {
        let frames: Vec<_> =
            paths.iter().map(|p| serde_json::json!({ "file_path": p, "transform_matrix": LOOK_ALONG_Y })).collect();
        serde_json::json!({ "camera_angle_x": 0.8, "frames": frames })
    };
    write_json(&data.join("transforms_train.json"), &doc(&["./train/r_0", "train/../train/r_0.png"]));
    assert_eq!(load_split(&data, "train", LoadOptions::default()).unwrap().frames.len(), 2);
    let absolute = dir.path().join("elsewhere/r_1.png");
    for (bad, says) in [
        ("../elsewhere/r_1", "leads out of"),
        ("train/../../elsewhere/r_1", "leads out of"),
        (absolute.to_str().unwrap(), "absolute"),
    ] {
        write_json(&data.join("transforms_train.json"), &doc(&["./train/r_0", bad]));
        let e = load_split(&data, "train", LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("frame 1") && e.contains("file_path") && e.contains(says), "{bad}: {e}");
    }
}
