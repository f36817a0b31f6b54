//! Helpers shared by the binary's tests: run `nerfsv`, make a tiny dataset.
#![allow(dead_code)] // each test file uses its own subset

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `nerfsv args` with extra environment variables: (success, stdout, stderr).
pub fn nerfsv_with(args: &[&str], env: &[(&str, &str)]) -> (bool, String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_nerfsv"));
    cmd.args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("run nerfsv");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// Runs `nerfsv args`: (success, stdout, stderr).
pub fn nerfsv(args: &[&str]) -> (bool, String, String) {
    nerfsv_with(args, &[])
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Writes a tiny 8×8 monolith dataset (`train` training views, one validation view, `test`
/// test views) into `dir/ds`.
pub fn tiny_dataset(dir: &Path, train: &str, test: &str) -> PathBuf {
    monolith_dataset(dir, "8", train, test)
}

/// Writes a `size`×`size` monolith dataset (`train` training views, one validation view, `test`
/// test views, ground-truth depth) into `dir/ds`.
pub fn monolith_dataset(dir: &Path, size: &str, train: &str, test: &str) -> PathBuf {
    let ds = dir.join("ds");
    let (ok, _, err) = nerfsv(&[
        "scene",
        "--scene",
        "monolith",
        "--out",
        s(&ds),
        "--width",
        size,
        "--height",
        size,
        "--train",
        train,
        "--val",
        "1",
        "--test",
        test,
        "--supersample",
        "1",
    ]);
    assert!(ok, "{err}");
    ds
}

/// A 2-step model of the 8×8 monolith dataset whose box is ±1 m, and the monolith's
/// ground-truth field (the planner's map in these tests: the tiny model has learned nothing).
pub fn tiny_model_and_field(dir: &Path) -> (PathBuf, PathBuf) {
    let ds = tiny_dataset(dir, "2", "1");
    let model = tiny_model(dir, &ds);
    let field = dir.join("gt.safetensors");
    let (ok, _, err) = nerfsv(&["collision", "--scene", "monolith", "--out", s(&field)]);
    assert!(ok, "{err}");
    (model, field)
}

/// A 2-step model of the monolith dataset `ds` in a ±1 m box, trained into `dir/nerf`: its
/// checkpoint.
pub fn tiny_model(dir: &Path, ds: &Path) -> PathBuf {
    let nerf_cfg = dir.join("nerf.toml");
    std::fs::write(&nerf_cfg, "[nerf]\naabb_min = [-1.0, -1.0, -1.0]\naabb_max = [1.0, 1.0, 1.0]\n").unwrap();
    let nerf = dir.join("nerf");
    let (ok, _, err) = nerfsv(&["train", "--data", s(ds), "--out", s(&nerf), "--steps", "2", "--config", s(&nerf_cfg)]);
    assert!(ok, "{err}");
    nerf.join("checkpoint.safetensors")
}

/// Every file under `root` (relative path → bytes), skipping the records, the summary and the
/// report's page, which hold timings.
pub fn files(root: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if !["stage.json", "summary.json", "train_stats.json", "index.html"]
                .contains(&e.file_name().to_str().unwrap())
            {
                out.push((p.strip_prefix(root).unwrap().to_path_buf(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}
