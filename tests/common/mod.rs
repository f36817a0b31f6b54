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

/// Asserts that two [`files`] listings name the same files with the same bytes; `what` says
/// what was compared, in the messages.
pub fn assert_same_files(got: &[(PathBuf, Vec<u8>)], expected: &[(PathBuf, Vec<u8>)], what: &str) {
    let names = |f: &[(PathBuf, Vec<u8>)]| f.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names(got), names(expected), "{what}: other files");
    for ((name, a), (_, b)) in got.iter().zip(expected) {
        assert!(a == b, "{what}: {} differs", name.display());
    }
}

/// A run's `summary.json` without what depends on the machine or the folder: timings, rates per
/// second and the run's path.
pub fn summary_without_timings(root: &Path) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(m) => {
                m.retain(|k, _| !k.contains("seconds") && !k.contains("per_second") && k != "run");
                m.values_mut().for_each(strip);
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("summary.json")).unwrap()).unwrap();
    strip(&mut v);
    v
}

/// The tiny study's `[train]` table (shared with the `nerfsv train` config).
pub const TINY_MODEL: &str = "[train]\nbatch_rays = 256\ncheckpoint_every_steps = 1\n";

/// A tiny run config (16×16 monolith, a few steps) with an ensemble of three members (two
/// beside the deployed model) and the ensemble as NeRF-sim's world.
pub fn tiny_ensemble_run_config(dir: &Path) -> PathBuf {
    tiny_ensemble_run_config_with(dir, "", "")
}

/// [`tiny_ensemble_run_config`] with `nerf` as the `[nerf]` table's lines and `sim` added to the
/// `[sim]` table's.
pub fn tiny_ensemble_run_config_with(dir: &Path, nerf: &str, sim: &str) -> PathBuf {
    let cfg = dir.join("run.toml");
    std::fs::write(
        &cfg,
        format!(
            "scene = \"monolith\"\ncells_per_metre = 10.0\ntrain_steps = 4\n[nerf]\n{nerf}[dataset]\nwidth = 16\nheight = 16\n\
             train = 6\nval = 1\ntest = 2\nsupersample = 1\n{TINY_MODEL}\
             [sim]\nnerf_world = \"ensemble\"\n{sim}[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n\
             [stress.monte_carlo]\nrollouts = 6\n[stress.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 4\n\
             [stress.subset]\nsamples = 10\nmax_levels = 2\n\
             [uq]\nmax_rays = 16\nperturbations = 1\nlm_iterations = 2\nonline_rays = 64\nonline_bla_rays = 16\n\
             [uq_offline]\nbla_images_per_split = 1\n[online]\nmethods = [\"ga\"]\nmc_rollouts = 4\n\
             [ensemble]\nmembers = 3\nsteps = 3\n"
        ),
    )
    .unwrap();
    cfg
}

/// An animated PNG read with the `png` crate: its width and height, and each of the frames its
/// animation control chunk declares, decoded to 8-bit samples.
pub fn apng(path: &Path) -> (u32, u32, Vec<Vec<u8>>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
    let n = reader.info().animation_control.expect("an animated PNG").num_frames;
    let (w, h) = reader.info().size();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let frames = (0..n)
        .map(|_| {
            let size = reader.next_frame(&mut buf).unwrap().buffer_size();
            buf[..size].to_vec()
        })
        .collect();
    (w, h, frames)
}
