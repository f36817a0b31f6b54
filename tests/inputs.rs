//! A user's files are never lost and a meaningless study never starts: every command and the
//! run refuse, before writing anything, an output that is, holds or lies inside an input
//! (known by identity: links followed), two outputs at one path, and a config whose flight
//! cannot be flown, naming the file and key once.

mod common;

use std::path::{Path, PathBuf};
use std::time::Instant;

use common::{nerfsv, nerfsv_with, s};
use proptest::prelude::*;

/// Every file under `root`, recursively (links followed), with its bytes.
fn snapshot(root: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Ok(bytes) = std::fs::read(&p) {
                out.push((p, bytes));
            }
        }
    }
    out.sort();
    out
}

/// A run config of the monolith world with `extra` appended (a small dataset; the refusals
/// come before any stage, so nothing of it is ever built).
fn config(dir: &Path, extra: &str) -> PathBuf {
    let cfg = dir.join("run.toml");
    std::fs::write(
        &cfg,
        format!(
            "scene = \"monolith\"\ncells_per_metre = 10.0\ntrain_steps = 2\n[dataset]\nwidth = 8\nheight = 8\n{extra}"
        ),
    )
    .unwrap();
    cfg
}

/// The stage folders a run folder holds.
fn stage_outputs(run: &Path) -> Vec<String> {
    std::fs::read_dir(run)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn a_run_refuses_a_dataset_inside_its_run_folder_and_deletes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("R");
    std::fs::create_dir(&run).unwrap();
    let ds = common::tiny_dataset(&run, "2", "1");
    assert_eq!(ds, run.join("ds"));
    // The dataset where the run's own dataset stage writes, and anywhere else inside the run.
    std::fs::rename(&ds, run.join("dataset")).unwrap();
    let before = snapshot(&run);
    let cfg = config(dir.path(), "[world]\ndataset = \"R/dataset\"\n");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&run)]);
    assert!(!ok);
    assert!(err.contains("world.dataset") && err.contains("nerfsv never writes over what it reads"), "{err}");
    assert_eq!(snapshot(&run), before, "the dataset is untouched");
}

#[test]
fn a_run_refuses_a_mesh_inside_its_run_folder_and_keeps_its_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("R");
    let mesh = run.join("collision/gt_mesh.ply");
    std::fs::create_dir_all(mesh.parent().unwrap()).unwrap();
    let field = dir.path().join("field.safetensors");
    let (ok, _, err) = nerfsv(&[
        "collision",
        "--scene",
        "monolith",
        "--cells-per-metre",
        "20",
        "--out",
        s(&field),
        "--mesh",
        s(&mesh),
    ]);
    assert!(ok, "{err}");
    let before = std::fs::read(&mesh).unwrap();
    let cfg = config(
        dir.path(),
        "[sim]\nstart = [0.6, -0.6, 0.2]\ngoal = [-0.6, 0.6, 0.2]\n[world]\nmesh = \"R/collision/gt_mesh.ply\"\n",
    );
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&run)]);
    assert!(!ok);
    assert!(err.contains("world.mesh") && err.contains("gt_mesh.ply"), "{err}");
    assert_eq!(std::fs::read(&mesh).unwrap(), before);
    assert_eq!(stage_outputs(&run), vec!["collision".to_string()], "no stage ran");
}

#[cfg(unix)]
#[test]
fn a_split_linked_into_another_dataset_is_that_datasets_input() {
    let dir = tempfile::tempdir().unwrap();
    let other = common::tiny_dataset(&dir.path().join("a"), "2", "1");
    let ds = common::tiny_dataset(&dir.path().join("b"), "2", "1");
    let model = common::tiny_model(dir.path(), &ds);
    // `sym`: its own transforms, its test split a link to the other dataset's.
    let sym = dir.path().join("sym");
    std::fs::create_dir(&sym).unwrap();
    for f in ["transforms_train.json", "transforms_val.json", "transforms_test.json"] {
        std::fs::copy(ds.join(f), sym.join(f)).unwrap();
    }
    for split in ["train", "val"] {
        std::os::unix::fs::symlink(ds.join(split), sym.join(split)).unwrap();
    }
    std::os::unix::fs::symlink(other.join("test"), sym.join("test")).unwrap();
    let before = snapshot(&other);
    let (ok, _, err) = nerfsv(&[
        "render",
        "--model",
        s(&model),
        "--data",
        s(&sym),
        "--split",
        "test",
        "--out",
        s(&other.join("test")),
    ]);
    assert!(!ok);
    assert!(err.contains("--data") && err.contains("really"), "{err}");
    assert_eq!(snapshot(&other), before, "the other dataset's ground truth is untouched");
}

#[test]
fn two_outputs_at_one_path_are_refused_before_either_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let x = dir.path().join("X");
    let (ok, _, err) = nerfsv(&["collision", "--scene", "monolith", "--out", s(&x), "--mesh-out", s(&x)]);
    assert!(!ok);
    assert!(err.contains("--out") && err.contains("--mesh-out") && err.contains("two outputs"), "{err}");
    assert!(!x.exists());
}

#[test]
fn a_goal_at_the_start_is_refused_by_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("R");
    for goal in ["[0.6, -0.6, 0.2]", "[0.6, -0.6, 0.25]"] {
        let cfg = config(dir.path(), &format!("[sim]\nstart = [0.6, -0.6, 0.2]\ngoal = {goal}\n"));
        for check in [true, false] {
            let args = [&["run", s(&cfg), "--out", s(&run)][..], if check { &["--check"] } else { &[] }].concat();
            let (ok, _, err) = nerfsv(&args);
            assert!(!ok, "{goal}");
            assert!(err.contains("run.toml") && err.contains("sim.goal") && err.contains("goal_tolerance_m"), "{err}");
            assert!(!run.exists(), "nothing written");
        }
    }
}

#[test]
fn a_start_outside_the_grid_is_refused_before_any_stage_and_named_once() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("R");
    for (sim, key) in [
        ("start = [9.0, 0.0, 0.2]", "sim.start"),
        ("goal = [0.0, 9.0, 0.2]", "sim.goal"),
        ("start = [0.6, -0.6, -0.5]", "sim.start"),
    ] {
        let cfg = config(dir.path(), &format!("[sim]\n{sim}\n"));
        let started = Instant::now();
        let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&run)]);
        let seconds = started.elapsed().as_secs_f64();
        assert!(!ok, "{sim}");
        assert!(err.contains("run.toml") && err.contains(key), "{sim}: {err}");
        assert_eq!(err.matches(key).count(), 1, "named once: {err}");
        assert!(!run.exists() || stage_outputs(&run).is_empty(), "{sim}: no stage ran ({seconds:.1} s)");
    }
    // A grid too large for the memory budget, refused before the dataset is rendered.
    let cfg = config(dir.path(), "");
    std::fs::write(
        &cfg,
        std::fs::read_to_string(&cfg).unwrap().replace("cells_per_metre = 10.0", "cells_per_metre = 400.0"),
    )
    .unwrap();
    let (ok, _, err) = nerfsv_with(&["run", s(&cfg), "--out", s(&run)], &[("NERFSV_MEMORY_BUDGET_GIB", "2")]);
    assert!(!ok);
    assert!(err.contains("run.toml") && err.contains("cells_per_metre") && err.contains("memory budget"), "{err}");
    assert!(!run.exists() || stage_outputs(&run).is_empty());
    // A sound config passes the check and writes nothing.
    let cfg = config(dir.path(), "");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&run), "--check"]);
    assert!(ok, "{err}");
    assert!(err.contains("ready to run"), "{err}");
    assert!(!run.exists());
}

#[test]
fn a_flag_is_named_as_typed() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, _, err) = nerfsv(&["scene", "--scene", "monolith", "--out", s(&dir.path().join("d")), "--fov", "nan"]);
    assert!(!ok);
    assert!(err.contains("--fov") && !err.contains("camera_angle_x"), "{err}");
}

/// The files of one layout: a tiny dataset `data`, a dataset `alt` whose test split links to
/// `data`'s, a link `ldata` to `data`, a model folder `m` and a link `lm` to it.
struct Layout {
    root: tempfile::TempDir,
}

impl Layout {
    fn new(base: &Base) -> Self {
        let root = tempfile::tempdir().unwrap();
        let r = root.path();
        copy_tree(&base.data, &r.join("data"));
        copy_tree(base.model.parent().unwrap(), &r.join("m"));
        std::fs::create_dir(r.join("alt")).unwrap();
        for f in ["transforms_train.json", "transforms_val.json", "transforms_test.json"] {
            std::fs::copy(r.join("data").join(f), r.join("alt").join(f)).unwrap();
        }
        #[cfg(unix)]
        {
            for split in ["train", "val", "test"] {
                std::os::unix::fs::symlink(r.join("data").join(split), r.join("alt").join(split)).unwrap();
            }
            std::os::unix::fs::symlink(r.join("data"), r.join("ldata")).unwrap();
            std::os::unix::fs::symlink(r.join("m"), r.join("lm")).unwrap();
        }
        Self { root }
    }

    fn path(&self, rel: &str) -> PathBuf {
        self.root.path().join(rel)
    }

    /// The inputs' bytes: the dataset's files (`data`) and the model's (`model`).
    fn inputs(&self, data: bool, model: bool) -> Vec<(PathBuf, Vec<u8>)> {
        let folders = [("data", data), ("m", model)];
        folders.iter().filter(|(_, read)| *read).flat_map(|(f, _)| snapshot(&self.path(f))).collect()
    }
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        if e.path().is_dir() {
            copy_tree(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// A dataset and a model, built once and copied into each case's layout.
struct Base {
    _dir: tempfile::TempDir,
    data: PathBuf,
    model: PathBuf,
}

fn base() -> &'static Base {
    static BASE: std::sync::OnceLock<Base> = std::sync::OnceLock::new();
    BASE.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let data = common::tiny_dataset(dir.path(), "2", "1");
        let model = common::tiny_model(dir.path(), &data);
        Base { _dir: dir, data, model }
    })
}

const DATASETS: [&str; 3] = ["data", "ldata", "alt"];
const MODELS: [&str; 2] = ["m/checkpoint.safetensors", "lm/checkpoint.safetensors"];
const OUTPUTS: [&str; 14] = [
    "data",
    "data/test",
    "data/new/deeper",
    "ldata/test",
    "alt",
    "alt/test",
    "alt/new",
    "m",
    "lm",
    "m/checkpoint.safetensors",
    "data/..",
    ".",
    "fresh",
    "fresh/deeper",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, failure_persistence: None, ..ProptestConfig::default() })]

    /// Whatever the command and however its output is spelled (nested, equal, through a link),
    /// no input file's bytes change, whether the command succeeds or is refused.
    #[test]
    fn no_input_changes_whatever_the_layout(
        command in 0usize..4,
        data in 0usize..DATASETS.len(),
        model in 0usize..MODELS.len(),
        out in 0usize..OUTPUTS.len(),
        second in 0usize..OUTPUTS.len(),
    ) {
        let layout = Layout::new(base());
        // What each command reads: training reads no model, the field's builder no dataset.
        let before = layout.inputs(command != 3, command != 1);
        let (d, m, o, o2) =
            (layout.path(DATASETS[data]), layout.path(MODELS[model]), layout.path(OUTPUTS[out]), layout.path(OUTPUTS[second]));
        let args: Vec<&str> = match command {
            0 => vec!["render", "--model", s(&m), "--data", s(&d), "--split", "test", "--out", s(&o)],
            1 => vec!["train", "--data", s(&d), "--out", s(&o), "--steps", "1"],
            2 => vec!["uq", "offline", "--method", "ga", "--model", s(&m), "--data", s(&d), "--out", s(&o), "--max-images", "1"],
            _ => vec!["collision", "--model", s(&m), "--cells-per-metre", "5", "--out", s(&o), "--mesh", s(&o2)],
        };
        let (ok, _, err) = nerfsv(&args);
        // Every input file still there with its bytes (files added beside them are not inputs).
        let changed: Vec<&PathBuf> =
            before.iter().filter(|(p, bytes)| std::fs::read(p).ok().as_ref() != Some(bytes)).map(|(p, _)| p).collect();
        prop_assert!(changed.is_empty(), "{:?} (ok {}): {}: changed {:?}", args, ok, err, changed);
    }
}
