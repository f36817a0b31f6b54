//! Every command that takes a dataset folder takes a capture as its tools write it
//! (`tests/fixtures/captures/`: nerfstudio, COLMAP text and binary): `nerfsv train --data`, a
//! run's `[world] dataset` with its placement, `nerfsv uq offline --data`, and the guard over the
//! files a capture reads.

mod common;

use std::path::{Path, PathBuf};

use common::{nerfsv, s};

fn capture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/captures").join(name)
}

#[test]
fn train_and_uq_take_colmap_and_nerfstudio_folders() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["colmap_bin", "nerfstudio"] {
        let out = dir.path().join(name);
        let (ok, _, err) = nerfsv(&["train", "--data", s(&capture(name)), "--out", s(&out), "--steps", "2"]);
        assert!(ok, "{name}: {err}");
        assert!(out.join("checkpoint.safetensors").is_file(), "{name}");
        let stats: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("train_stats.json")).unwrap()).unwrap();
        assert_eq!(stats["steps"], 2, "{name}: {stats}");
        // The offline uncertainty study reads the same folder, every split the loader derives.
        let uq = dir.path().join(format!("{name}_uq"));
        let model = out.join("checkpoint.safetensors");
        let data = capture(name);
        let args = ["uq", "offline", "--method", "ga", "--model", s(&model), "--data", s(&data)];
        let (ok, _, err) = nerfsv(&[&args[..], &["--out", s(&uq), "--max-images", "1", "--rays", "16"]].concat());
        assert!(ok, "{name}: uq offline: {err}");
        let csv = std::fs::read_to_string(uq.join("uq_ga.csv")).unwrap();
        for split in ["train", "val", "test"] {
            assert!(csv.lines().any(|l| l.starts_with(&format!("{split},"))), "{name}: no {split} row in\n{csv}");
        }
    }
}

#[test]
fn a_run_with_a_colmap_world_dataset_checks_and_its_placement_is_named_when_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let cfg = dir.path().join("run.toml");
    let world =
        |extra: &str| format!("[world]\ndataset = {:?}\ndataset_up = \"y\"\n{extra}", s(&capture("colmap_text")));
    std::fs::write(&cfg, world("dataset_scale = 0.5\ndataset_centre = [0.0, 0.8, 0.0]\n")).unwrap();
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&run), "--check"]);
    assert!(ok, "{err}");
    assert!(!run.exists());
    std::fs::write(&cfg, world("dataset_scale = -1.0\n")).unwrap();
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&run), "--check"]);
    assert!(!ok && err.contains("world.dataset_scale"), "{err}");
}

#[test]
fn the_guard_keeps_outputs_out_of_a_colmap_folders_images() {
    let dir = tempfile::tempdir().unwrap();
    // A copy, so that a failing guard cannot write into the fixtures.
    let data = dir.path().join("capture");
    std::fs::create_dir_all(data.join("sparse/0")).unwrap();
    std::fs::create_dir_all(data.join("images")).unwrap();
    for f in ["sparse/0/cameras.bin", "sparse/0/images.bin"] {
        std::fs::copy(capture("colmap_bin").join(f), data.join(f)).unwrap();
    }
    for e in std::fs::read_dir(capture("colmap_bin").join("images")).unwrap().flatten() {
        std::fs::copy(e.path(), data.join("images").join(e.file_name())).unwrap();
    }
    let out = data.join("images/img_03.jpg");
    let (ok, _, err) = nerfsv(&["train", "--data", s(&data), "--out", s(&out), "--steps", "2"]);
    assert!(!ok && err.contains("--data") && err.contains("nerfsv never writes over what it reads"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(capture("colmap_bin/images/img_03.jpg")).unwrap());
}
