//! `nerfsv fly`: one rollout's files and figures; every bad input stops it with a message that
//! names the key, file, line or column, before anything is written.

mod common;

use std::path::{Path, PathBuf};

use common::{nerfsv, s};

/// A 2-step model of the 8×8 monolith dataset whose box is ±1 m, and the monolith's
/// ground-truth field (the planner's map in these tests: the tiny model has learned nothing).
fn setup(dir: &Path) -> (PathBuf, PathBuf) {
    let ds = common::tiny_dataset(dir, "2", "1");
    let nerf_cfg = dir.join("nerf.toml");
    std::fs::write(&nerf_cfg, "[nerf]\naabb_min = [-1.0, -1.0, -1.0]\naabb_max = [1.0, 1.0, 1.0]\n").unwrap();
    let nerf = dir.join("nerf");
    let (ok, _, err) =
        nerfsv(&["train", "--data", s(&ds), "--out", s(&nerf), "--steps", "2", "--config", s(&nerf_cfg)]);
    assert!(ok, "{err}");
    let field = dir.join("gt.safetensors");
    let (ok, _, err) = nerfsv(&["collision", "--scene", "monolith", "--out", s(&field)]);
    assert!(ok, "{err}");
    (nerf.join("checkpoint.safetensors"), field)
}

fn fly(model: &Path, field: &Path, out: &Path, extra: &[&str]) -> (bool, String, String) {
    let base = ["fly", "--scene", "monolith", "--model", s(model), "--nerf-field", s(field), "--out", s(out)];
    nerfsv(&[&base[..], extra].concat())
}

#[test]
fn a_flight_writes_its_files_and_prints_the_figures() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = setup(dir.path());
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "[vision]\npixels = 16\niterations = 2\n").unwrap();
    let out = dir.path().join("fly");
    let (ok, stdout, err) =
        fly(&model, &field, &out, &["--world", "gt", "--random-seed", "3", "--config", s(&cfg), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    for key in [
        "collided",
        "collision_step",
        "min_clearance_m",
        "reached_goal",
        "steps",
        "mean_position_error_m",
        "mean_rotation_error_deg",
    ] {
        assert!(v.get(key).is_some(), "{key} missing from {stdout}");
    }
    assert_eq!(v["steps"], 6);
    for f in ["trajectory.csv", "trajectory.png", "disturbances.csv", "flight.json"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(out.join("trajectory.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 6 * 9);
    // The disturbances it wrote replay the same flight.
    let again = dir.path().join("again");
    let (ok, stdout2, err) = fly(
        &model,
        &field,
        &again,
        &[
            "--world",
            "gt",
            "--disturbances",
            s(&out.join("disturbances.csv")),
            "--seed",
            "3",
            "--config",
            s(&cfg),
            "--json",
        ],
    );
    assert!(ok, "{err}");
    assert_eq!(
        std::fs::read(out.join("trajectory.csv")).unwrap(),
        std::fs::read(again.join("trajectory.csv")).unwrap()
    );
    let strip = |t: &str| {
        let mut v: serde_json::Value = serde_json::from_str(t.trim()).unwrap();
        v.as_object_mut().unwrap().remove("seconds_per_step");
        v
    };
    assert_eq!(strip(&stdout), strip(&stdout2));
}

#[test]
fn bad_flights_are_refused_by_name_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = setup(dir.path());
    let out = dir.path().join("fly");
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let row = "0,0,0,0,0,0,0,0,0,0,0,0\n";
    let cases: Vec<(PathBuf, &str, Vec<&str>)> = vec![
        // Start inside the monolith.
        (write("a.toml", "start = [0.0, 0.0, 0.3]\n"), "--config", vec!["start (0.00, 0.00, 0.30)", "inside geometry"]),
        // Goal off the field's grid.
        (write("b.toml", "goal = [3.0, 0.0, 0.2]\n"), "--config", vec!["goal", "outside"]),
        // A path outside the model's ±1 m box.
        (
            write("c.toml", "start = [1.3, -0.5, 0.2]\ngoal = [1.3, 0.5, 0.2]\n"),
            "--config",
            vec!["model's box", "does not cover"],
        ),
        // A value out of range.
        (write("d.toml", "steps = 0\n"), "--config", vec!["d.toml", "steps", "found 0"]),
        // Disturbance files: a short row, a NaN, too few rows.
        (
            write("e.csv", &format!("{row}{row}0,0,0\n{row}{row}{row}")),
            "--disturbances",
            vec!["e.csv", "line 3", "12 columns"],
        ),
        (
            write("f.csv", &format!("{row}{row}{row}{row}0,0,0,0,0,0,0,0,0,0,nan,0\n{row}")),
            "--disturbances",
            vec!["f.csv", "line 5", "column 11 (dw_y)"],
        ),
        (write("g.csv", &row.repeat(5)), "--disturbances", vec!["g.csv", "one row per step (6)", "found 5"]),
    ];
    for (file, option, expected) in cases {
        let (ok, _, err) = fly(&model, &field, &out, &[option, s(&file)]);
        assert!(!ok, "{} was accepted", file.display());
        for e in expected {
            assert!(err.contains(e), "{}: {e:?} not in {err}", file.display());
        }
        assert!(!out.exists(), "{} left output behind", file.display());
    }
}
