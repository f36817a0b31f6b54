//! A captured dataset (the COLMAP fixture of `tests/fixtures/captures/`, a y-up world) as a run's
//! `[world] dataset`: the config validates its placement by name, the dataset stage records the
//! placement, and every later reader of the run's dataset gets the placed poses.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use nerfsv_dataset::load_linked_split;
use nerfsv_dataset::{load_split, LoadOptions, Placement};
use nerfsv_pipeline::stages::{DatasetSource, DatasetStage};
use nerfsv_pipeline::{RunConfig, Validate};
use nerfsv_pipeline::{Runner, Silent};
use nerfsv_scene::mesh::UpAxis;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures")
}

fn colmap() -> PathBuf {
    fixtures().join("captures/colmap_text")
}

/// A run config in `dir` whose `[world]` table is `world`.
fn config(dir: &Path, world: &str) -> Result<RunConfig, String> {
    let path = dir.join("run.toml");
    std::fs::write(&path, format!("[world]\ndataset = {:?}\n{world}", colmap().to_str().unwrap())).unwrap();
    RunConfig::load(&path).map_err(|e| e.to_string())
}

#[test]
fn a_colmap_world_dataset_validates_and_its_placement_is_checked_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let cfg =
        config(dir.path(), "dataset_scale = 0.5\ndataset_up = \"y\"\ndataset_centre = [0.0, 0.8, 0.0]\n").unwrap();
    cfg.validate().unwrap();
    assert_eq!(cfg.world.placement(), Placement { scale: 0.5, up: UpAxis::Y, centre: [0.0, 0.8, 0.0] });
    let (scene, _) = cfg.ground_truth().unwrap();
    assert!(scene.is_none(), "a world known only by its dataset has no ground truth");
    for (bad, key) in [
        ("dataset_scale = 0.0\n", "world.dataset_scale"),
        ("dataset_scale = -2.0\n", "world.dataset_scale"),
        ("dataset_centre = [0.0, 1e39, 0.0]\n", "world.dataset_centre[1]"),
    ] {
        let e = config(dir.path(), bad).and_then(|c| c.validate().map_err(|e| e.to_string())).unwrap_err();
        assert!(e.contains(key), "{bad}: {e}");
    }
    let e = config(dir.path(), "dataset_up = \"w\"\n").unwrap_err();
    assert!(e.contains("dataset_up"), "{e}");
    for name in ["`x`", "`y`", "`z`", "`-x`", "`-y`", "`-z`"] {
        assert!(e.contains(name), "the accepted values are listed: {e}");
    }
    // Every signed axis is accepted, by its name.
    for up in UpAxis::ALL {
        let cfg = config(dir.path(), &format!("dataset_up = \"{up}\"\n")).unwrap();
        assert_eq!(cfg.world.placement().up, up);
    }
}

#[test]
fn a_mesh_world_checks_the_placed_cameras_of_its_captured_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = fixtures().join("meshes/world.ply");
    // The flight's ends of the mesh world's own test (tests/user_world.rs), clear of the mesh.
    let world = |extra: &str| {
        format!(
            "mesh = {:?}\n{extra}[sim]\nstart = [0.8, -0.7, 0.25]\ngoal = [-0.8, 0.8, 0.25]\n",
            mesh.to_str().unwrap()
        )
    };
    // The capture's cameras look at its origin, where the mesh stands.
    let cfg = config(dir.path(), &world("dataset_up = \"y\"\n")).unwrap();
    let (scene, _) = cfg.ground_truth().unwrap();
    cfg.preflight(scene.as_ref()).unwrap();
    // Centred 4 capture units away, they look past it.
    let cfg = config(dir.path(), &world("dataset_up = \"y\"\ndataset_centre = [4.0, 0.0, 0.0]\n")).unwrap();
    let (scene, _) = cfg.ground_truth().unwrap();
    let e = cfg.preflight(scene.as_ref()).unwrap_err().to_string();
    assert!(e.contains("world.dataset") && e.contains("look at the mesh"), "{e}");
}

#[test]
fn the_dataset_stage_records_the_placement_and_later_readers_get_placed_poses() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("run");
    let placement = Placement { scale: 2.0, up: UpAxis::Y, centre: [0.5, 0.8, -0.2] };
    let folder = colmap();
    let mut runner = Runner::new(&root, &Silent).unwrap();
    runner.run(&DatasetStage { source: DatasetSource::Folder { folder: &folder, placement } }).unwrap();
    let source: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("dataset/source.json")).unwrap()).unwrap();
    assert_eq!(source["placement"]["scale"], 2.0);
    assert_eq!(source["placement"]["up"], "y");
    let raw = load_split(&folder, "train", LoadOptions::default()).unwrap();
    let placed = load_linked_split(&DatasetStage::folder(&root).unwrap(), "train", 1).unwrap();
    assert_eq!(placed.frames.len(), raw.frames.len());
    for (p, r) in placed.frames.iter().zip(&raw.frames) {
        let c = r.camera.position().coords - Vector3::new(0.5, 0.8, -0.2);
        let want = 2.0 * Vector3::new(c.x, -c.z, c.y);
        assert!((p.camera.position().coords - want).norm() < 1e-5, "{}", p.file_path);
        assert_eq!(p.image, r.image);
    }
    // Without a placement the record is as before, and the poses are the capture's own.
    let root = dir.path().join("plain");
    let mut runner = Runner::new(&root, &Silent).unwrap();
    runner
        .run(&DatasetStage { source: DatasetSource::Folder { folder: &folder, placement: Placement::default() } })
        .unwrap();
    let text = std::fs::read_to_string(root.join("dataset/source.json")).unwrap();
    assert!(!text.contains("placement"), "{text}");
    let plain = load_linked_split(&DatasetStage::folder(&root).unwrap(), "train", 1).unwrap();
    assert_eq!(plain.frames[0].camera.c2w, raw.frames[0].camera.c2w);
}

/// Copies the folder `from` into `to`.
fn copy_folder(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let target = to.join(e.file_name());
        if e.path().is_dir() {
            copy_folder(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}

#[test]
fn the_dataset_stages_key_hashes_the_files_the_loader_reads_and_no_others() {
    use nerfsv_pipeline::stage::Stage;
    let dir = tempfile::tempdir().unwrap();
    for (name, image, model) in [
        ("colmap_text", "images/img_03.jpg", "sparse/0/images.txt"),
        ("colmap_bin", "images/img_05.jpg", "sparse/0/cameras.bin"),
        ("nerfstudio", "images/frame_04.png", "transforms.json"),
    ] {
        let folder = dir.path().join(name);
        copy_folder(&fixtures().join("captures").join(name), &folder);
        let key = || {
            let stage =
                DatasetStage { source: DatasetSource::Folder { folder: &folder, placement: Placement::default() } };
            let key = serde_json::to_string(&stage.config()).unwrap();
            key
        };
        let before = key();
        // What COLMAP and nerfstudio leave beside a capture, large and not read: the key stands.
        std::fs::write(folder.join("database.db"), vec![7u8; 8 << 20]).unwrap();
        std::fs::create_dir_all(folder.join("dense/0")).unwrap();
        std::fs::write(folder.join("dense/0/x.bin"), vec![1u8; 1 << 20]).unwrap();
        std::fs::create_dir_all(folder.join("sparse/1")).unwrap();
        std::fs::write(folder.join("sparse/1/points3D.bin"), b"another model").unwrap();
        std::fs::write(folder.join("images/unregistered.jpg"), b"not named by the model").unwrap();
        assert_eq!(key(), before, "{name}: files the loader does not read changed the key");
        // A byte of an image the loader reads changes it, and so does its model file.
        let path = folder.join(image);
        let original = std::fs::read(&path).unwrap();
        let mut bytes = original.clone();
        let last = bytes.len() - 3;
        bytes[last] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        let edited = key();
        assert_ne!(edited, before, "{name}: a changed {image} kept the key");
        std::fs::write(&path, &original).unwrap();
        assert_eq!(key(), before, "{name}: the key is the files' bytes");
        let path = folder.join(model);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes.push(b'\n');
        std::fs::write(&path, &bytes).unwrap();
        assert_ne!(key(), before, "{name}: a changed {model} kept the key");
    }
}
