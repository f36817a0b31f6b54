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
    let ds = dir.join("ds");
    let (ok, _, err) = nerfsv(&[
        "scene",
        "--scene",
        "monolith",
        "--out",
        s(&ds),
        "--width",
        "8",
        "--height",
        "8",
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
