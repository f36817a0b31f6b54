//! What nerfsv promises, tried as a user would: the same config and seed give byte-identical
//! files at any thread count, killed or not; nothing half-written survives; every bad value
//! is refused by name; no command writes over its inputs.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use common::{assert_same_files, files, nerfsv, nerfsv_with, s, summary_without_timings};

/// A tiny run config: 16×16 monolith, a few training steps, a coarse field.
fn tiny_config(dir: &Path, steps: u32) -> PathBuf {
    let cfg = dir.join("run.toml");
    std::fs::write(
        &cfg,
        format!(
            "scene = \"monolith\"\ncells_per_metre = 10.0\ntrain_steps = {steps}\n[dataset]\nwidth = 16\nheight = 16\n\
             train = 6\nval = 1\ntest = 2\nsupersample = 1\n[train]\nbatch_rays = 256\ncheckpoint_every_steps = 1\n\
             [sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n\
             [stress.monte_carlo]\nrollouts = 4\n[stress.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 4\n[stress.subset]\nsamples = 10\nmax_levels = 2\n\
             [uq]\nmax_rays = 16\nperturbations = 1\nlm_iterations = 2\nonline_rays = 64\nonline_bla_rays = 16\n[uq_offline]\nbla_images_per_split = 1\n"
        ),
    )
    .unwrap();
    cfg
}

fn temporaries(root: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.contains(".tmp-") || name.contains(".partial-") {
                found.push(e.path());
            } else if e.path().is_dir() {
                stack.push(e.path());
            }
        }
    }
    found
}

#[test]
fn same_config_and_seed_give_byte_identical_files_at_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = tiny_config(dir.path(), 4);
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for (out, threads) in [(&a, "1"), (&b, "2")] {
        let (ok, _, err) = nerfsv_with(&["run", s(&cfg), "--out", s(out)], &[("RAYON_NUM_THREADS", threads)]);
        assert!(ok, "{err}");
    }
    let (fa, fb) = (files(&a), files(&b));
    assert!(fa.iter().any(|(p, _)| p.ends_with("checkpoint.safetensors")));
    assert!(fa.iter().any(|(p, _)| p.ends_with("nerf_sdf.safetensors")));
    assert!(fa.iter().any(|(p, _)| p.ends_with("uq/uq_bla.csv")) && fa.iter().any(|(p, _)| p.ends_with("uq/ause.csv")));
    assert_same_files(&fb, &fa, "2 threads against 1");
    assert_eq!(summary_without_timings(&a), summary_without_timings(&b));
}

#[test]
fn a_run_killed_mid_training_leaves_no_temporary_file_and_resumes_to_identical_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = tiny_config(dir.path(), 30);
    let reference = dir.path().join("reference");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&reference)]);
    assert!(ok, "{err}");

    let out = dir.path().join("killed");
    let checkpoint = out.join("nerf/checkpoint.safetensors");
    let mut child = Command::new(env!("CARGO_BIN_EXE_nerfsv"))
        .args(["run", s(&cfg), "--out", s(&out)])
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill it once training has checkpointed (a checkpoint is written after every step).
    let start = std::time::Instant::now();
    while !checkpoint.exists() && start.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    std::thread::sleep(std::time::Duration::from_millis(30));
    child.kill().unwrap();
    child.wait().unwrap();
    // Whatever the kill interrupted, plant what a writer killed mid-write leaves behind.
    std::fs::create_dir_all(out.join("nerf")).unwrap();
    std::fs::write(out.join("nerf/.checkpoint.safetensors.tmp-4194304-0"), b"truncated").unwrap();
    std::fs::create_dir_all(out.join("collision")).unwrap();
    std::fs::write(out.join("collision/.gt_sdf.safetensors.tmp-4194304-1"), b"truncated").unwrap();

    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&out)]);
    assert!(ok, "{err}");
    assert_eq!(temporaries(&out), Vec::<PathBuf>::new());
    assert_eq!(files(&out), files(&reference), "a killed and resumed run must end at the same bytes");
    assert_eq!(summary_without_timings(&out), summary_without_timings(&reference));
}

#[test]
fn values_that_would_exhaust_memory_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("run.toml");
    for (text, key) in [
        ("[nerf]\ncolor_hidden = 100000000\n", "color_hidden"),
        ("[nerf]\nsigma_hidden = 4000000000\n", "sigma_hidden"),
        ("[nerf]\nstep_size = inf\n", "step_size"),
        ("[nerf]\ngrid_threshold = nan\n", "grid_threshold"),
        ("[nerf]\nearly_stop_transmittance = nan\n", "early_stop_transmittance"),
        ("train_steps = 1000000000000\n", "train_steps"),
    ] {
        std::fs::write(&cfg, text).unwrap();
        let out = dir.path().join("r");
        let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&out)]);
        assert!(!ok, "{text} must be refused");
        assert!(err.contains("run.toml") && err.contains(key), "{text}: {err}");
        assert!(!out.exists(), "{text}: nothing may be written");
    }
    // Inside the allowed resolution range, but 400 cells/m over the scene is far too large.
    let field = dir.path().join("gt.safetensors");
    let (ok, _, err) = nerfsv_with(
        &["collision", "--scene", "stonehenge", "--cells-per-metre", "400", "--out", s(&field)],
        &[("NERFSV_MEMORY_BUDGET_GIB", "2")],
    );
    assert!(!ok);
    assert!(err.contains("cells-per-metre") && err.contains("memory budget of 2.0 GiB"), "{err}");
    assert!(!field.exists());
    // The budget is the user's to set: 100 cells/m (≈ 1.3 GiB) fits 2 GiB but not 0.5 GiB.
    let args = ["collision", "--scene", "monolith", "--cells-per-metre", "100", "--out", s(&field)];
    let (ok, _, err) = nerfsv(&[&args[..], &["--memory-budget-gib", "0.5"]].concat());
    assert!(!ok && err.contains("memory budget of 512.0 MiB"), "{err}");
    assert!(!field.exists());
}

/// An 8×8 monolith dataset and a 2-step model trained on it.
fn tiny_model(dir: &Path) -> (PathBuf, PathBuf) {
    let ds = common::tiny_dataset(dir, "2", "2");
    let nerf = dir.join("nerf");
    let (ok, _, err) = nerfsv(&["train", "--data", s(&ds), "--out", s(&nerf), "--steps", "2"]);
    assert!(ok, "{err}");
    (ds, nerf.join("checkpoint.safetensors"))
}

#[test]
fn nonsense_options_are_refused_and_no_command_writes_over_its_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let (ds, model) = tiny_model(dir.path());

    // Rendering into the dataset's own test folder would overwrite its ground truth.
    let before = std::fs::read(ds.join("test/r_0.png")).unwrap();
    let (ok, _, err) =
        nerfsv(&["render", "--model", s(&model), "--data", s(&ds), "--split", "test", "--out", s(&ds.join("test"))]);
    assert!(!ok);
    assert!(err.contains("nerfsv never writes over what it reads") && err.contains("--data"), "{err}");
    assert_eq!(std::fs::read(ds.join("test/r_0.png")).unwrap(), before);

    let out = dir.path().join("other");
    for (args, needle) in [
        (vec!["train", "--data", s(&ds), "--out", s(&out), "--steps", "0"], "--steps"),
        (vec!["train", "--data", s(&ds), "--out", s(&out), "--seconds", "-1"], "--seconds"),
        (vec!["eval", "--model", s(&model), "--data", s(&ds), "--max-images", "0"], "--max-images"),
    ] {
        let (ok, _, err) = nerfsv(&args);
        assert!(!ok, "{args:?} must fail");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?}: nothing may be written");
    }

    // A mesh path that cannot be written: neither the field nor the mesh is left behind.
    let field = dir.path().join("c/x.safetensors");
    let (ok, _, _) = nerfsv(&[
        "collision",
        "--scene",
        "monolith",
        "--cells-per-metre",
        "10",
        "--out",
        s(&field),
        "--mesh",
        s(dir.path()),
    ]);
    assert!(!ok);
    assert!(!field.exists());
}

#[test]
fn os_errors_are_reported_once_and_progress_reaches_a_log() {
    let dir = tempfile::tempdir().unwrap();
    let (ds, _) = tiny_model(dir.path());
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let (ok, _, err) = nerfsv(&["train", "--data", s(&ds), "--out", s(&blocker.join("nerf")), "--steps", "2"]);
    assert!(!ok);
    assert_eq!(err.matches("os error").count(), 1, "{err}");

    // stderr is a pipe here, not a terminal: progress comes as plain lines.
    let (ok, _, err) = nerfsv(&["train", "--data", s(&ds), "--out", s(&dir.path().join("n2")), "--steps", "3"]);
    assert!(ok, "{err}");
    assert!(err.contains("training: 3/3"), "{err}");
}
