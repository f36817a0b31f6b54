//! The `nerfsv` binary: bad input stops with a message naming what is wrong, exit code non-zero,
//! and nothing half-written left behind.

mod common;

use common::nerfsv;

/// A tiny dataset with `train` training views.
fn tiny_dataset(dir: &std::path::Path, train: &str) -> std::path::PathBuf {
    common::tiny_dataset(dir, train, "1")
}

#[test]
fn unknown_scene_is_named_and_fails() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let (ok, _, err) = nerfsv(&["scene", "--scene", "atlantis", "--out", out.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("atlantis") && err.contains("stonehenge"), "{err}");
    assert!(!out.exists());
}

#[test]
fn zero_or_absurd_sizes_are_rejected_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    for (flag, value, field) in [("--width", "0", "width"), ("--height", "99999", "height"), ("--test", "0", "test")] {
        let (ok, _, err) = nerfsv(&["scene", "--out", out.to_str().unwrap(), flag, value]);
        assert!(!ok, "{flag} {value} must fail");
        assert!(err.contains(field), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}

#[test]
fn scene_writes_a_dataset_and_reports_json() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let (ok, stdout, err) = nerfsv(&[
        "scene",
        "--scene",
        "pillars",
        "--out",
        out.to_str().unwrap(),
        "--width",
        "12",
        "--height",
        "10",
        "--train",
        "2",
        "--val",
        "1",
        "--test",
        "1",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(v["views"], 4);
    for f in
        ["transforms_train.json", "transforms_val.json", "transforms_test.json", "train/r_1.png", "test/r_0_depth.png"]
    {
        assert!(out.join(f).exists(), "{f} missing");
    }
}

#[test]
fn bad_config_names_the_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("run.toml");
    std::fs::write(&cfg, "scene = \"stonehenge\"\ncells_per_metre = 0.0\n").unwrap();
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", dir.path().join("r").to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("run.toml") && err.contains("cells_per_metre"), "{err}");
    std::fs::write(&cfg, "[dataset]\nwidht = 10\n").unwrap();
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("run.toml") && err.contains("widht"), "{err}");
}

#[test]
fn a_file_that_is_not_a_nerf_checkpoint_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let grid = dir.path().join("gt.safetensors");
    let (ok, _, err) = nerfsv(&["collision", "--scene", "monolith", "--out", grid.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let ds = tiny_dataset(dir.path(), "1");
    // A collision grid is a safetensors file too, but not a NeRF checkpoint.
    let (ok, _, err) = nerfsv(&[
        "eval",
        "--model",
        grid.to_str().unwrap(),
        "--data",
        ds.to_str().unwrap(),
        "--split",
        "test",
        "--json",
    ]);
    assert!(!ok);
    assert!(err.contains("gt.safetensors") && err.contains("format"), "{err}");
    let (ok, _, err) = nerfsv(&[
        "eval",
        "--model",
        dir.path().join("none.safetensors").to_str().unwrap(),
        "--data",
        ds.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("none.safetensors"), "{err}");
}

#[test]
fn training_into_an_unwritable_folder_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ds = tiny_dataset(dir.path(), "2");
    // A regular file where the output folder should be.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let out = blocker.join("nerf");
    let (ok, _, err) =
        nerfsv(&["train", "--data", ds.to_str().unwrap(), "--out", out.to_str().unwrap(), "--steps", "2"]);
    assert!(!ok);
    assert!(err.contains("file"), "{err}");
}

#[test]
fn out_of_range_training_settings_name_the_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let ds = tiny_dataset(dir.path(), "2");
    let cfg = dir.path().join("nerf.toml");
    std::fs::write(&cfg, "[train]\nlr = -0.01\n").unwrap();
    let out = dir.path().join("nerf");
    let (ok, _, err) = nerfsv(&[
        "train",
        "--data",
        ds.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--steps",
        "2",
        "--config",
        cfg.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("nerf.toml") && err.contains("train.lr") && err.contains("-0.01"), "{err}");
    assert!(!out.exists(), "nothing may be written");
}

#[test]
fn run_redoes_only_the_stages_whose_inputs_changed_and_resumes_an_interrupted_training() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let cfg = dir.path().join("run.toml");
    let write_cfg = |steps: u32| {
        let text = format!(
            "scene = \"monolith\"\ncells_per_metre = 10.0\ntrain_steps = {steps}\n[dataset]\nwidth = 16\nheight = 16\n\
             train = 6\nval = 1\ntest = 1\nsupersample = 1\n[train]\nbatch_rays = 256\n[sim.vision]\npixels = 16\niterations = 2\n\
             [validation.monte_carlo]\nrollouts = 4\n[validation.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 4\n"
        );
        std::fs::write(&cfg, text).unwrap();
    };
    let run = || {
        let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        assert!(ok, "{err}");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
        (err, summary)
    };
    write_cfg(3);
    let (first, summary) = run();
    assert!(!first.contains("up to date"), "{first}");
    assert_eq!(summary["nerf"]["steps"], 3);

    let (second, again) = run();
    for stage in ["dataset", "collision", "nerf", "eval", "nerf_collision", "flight", "stress"] {
        assert!(second.contains(&format!("{stage}: up to date")), "{stage} should be cached:\n{second}");
    }
    assert_eq!(summary, again);

    // More training steps: the dataset and the ground-truth field stay, the rest is redone.
    write_cfg(5);
    let (third, changed) = run();
    assert!(third.contains("dataset: up to date") && third.contains("collision: up to date"), "{third}");
    assert!(!third.contains("nerf: up to date") && !third.contains("eval: up to date"), "{third}");
    assert_eq!(changed["nerf"]["steps"], 5);

    // A run killed after its last checkpoint but before the stage completed resumes from it.
    std::fs::remove_file(out.join("nerf/stage.json")).unwrap();
    let (fourth, resumed) = run();
    assert!(fourth.contains("nerf: resuming the interrupted run"), "{fourth}");
    assert_eq!(resumed["eval"], changed["eval"], "resuming must end at the same model");
    assert_eq!(resumed["nerf"]["steps"], 5);
}
