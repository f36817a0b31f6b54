//! The NeRF's kernel widths give the same bits: a short training run's checkpoint and a render
//! of its model, and a whole tiny study (every stage: checkpoints, CSVs, pictures and the
//! figures of `summary.json`), are byte-identical with the portable kernels forced
//! (`NERFSV_KERNELS=portable`) and at every vector width this host has; a width the host lacks or
//! an unknown name is refused.

mod common;

use std::path::Path;

use common::{
    assert_same_files, files, nerfsv_with, s, summary_without_timings, tiny_dataset, tiny_ensemble_run_config_with,
};
use nerfsv_nerf::kernels::Kernels;

/// Trains 20 steps of a small model (16-wide layers, a 32³ occupancy grid, 64 rays: the
/// portable kernels call libm for each fused multiply-add) with a grid update at step 16 and
/// renders the test view at `kernels`; returns the checkpoint's and the render's bytes.
fn train_and_render(dir: &Path, ds: &Path, kernels: Kernels) -> (Vec<u8>, Vec<u8>) {
    let env = [("NERFSV_KERNELS", kernels.name())];
    let config = dir.join("small.toml");
    let small = "[nerf]\ngrid_resolution = 32\nsigma_hidden = 16\ncolor_hidden = 16\n\
                 [train]\nbatch_rays = 64\ntarget_samples_per_step = 1024\n";
    std::fs::write(&config, small).unwrap();
    let out = dir.join(kernels.name());
    let (ok, _, err) = nerfsv_with(
        &["train", "--data", s(ds), "--out", s(&out), "--steps", "20", "--config", s(&config), "--seed", "3"],
        &env,
    );
    assert!(ok, "{kernels:?}: {err}");
    let checkpoint = out.join("checkpoint.safetensors");
    let renders = dir.join(format!("{}_renders", kernels.name()));
    let (ok, _, err) = nerfsv_with(&["render", "--model", s(&checkpoint), "--data", s(ds), "--out", s(&renders)], &env);
    assert!(ok, "{kernels:?}: {err}");
    let mut views: Vec<_> = std::fs::read_dir(&renders).unwrap().flatten().map(|e| e.path()).collect();
    views.sort();
    assert!(!views.is_empty(), "{kernels:?}: no render");
    (std::fs::read(&checkpoint).unwrap(), views.iter().flat_map(|p| std::fs::read(p).unwrap()).collect())
}

#[test]
fn a_short_training_run_and_its_render_are_the_same_bytes_at_every_kernel_width() {
    let dir = tempfile::tempdir().unwrap();
    let ds = tiny_dataset(dir.path(), "6", "1");
    let portable = train_and_render(dir.path(), &ds, Kernels::Portable);
    let widths: Vec<_> = Kernels::on_this_host().filter(|k| *k != Kernels::Portable).collect();
    for k in &widths {
        let (checkpoint, render) = train_and_render(dir.path(), &ds, *k);
        assert!(checkpoint == portable.0, "{k:?}: the checkpoint differs from the portable kernels'");
        assert!(render == portable.1, "{k:?}: the render differs from the portable kernels'");
    }
    eprintln!("compared portable with {widths:?}");
}

/// The tiny ensemble study (small layers, a 32³ grid, 2 steps a rollout: the portable kernels
/// take about 80 s of it on two cores) with the portable kernels and with every width this host
/// has: the same files, byte for byte, and the same figures.
#[test]
fn a_whole_tiny_study_is_the_same_bytes_at_every_kernel_width() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = tiny_ensemble_run_config_with(
        dir.path(),
        "grid_resolution = 32\nsigma_hidden = 16\ncolor_hidden = 16\n",
        "steps = 2\n",
    );
    let run = |k: Kernels| {
        let out = dir.path().join(k.name());
        let (ok, _, err) = nerfsv_with(&["run", s(&cfg), "--out", s(&out)], &[("NERFSV_KERNELS", k.name())]);
        assert!(ok, "{k:?}: {err}");
        (files(&out), summary_without_timings(&out))
    };
    let (portable, portable_figures) = run(Kernels::Portable);
    assert!(portable.iter().any(|(n, _)| n.ends_with("rollouts.csv")), "the study flew no rollouts");
    for k in Kernels::on_this_host().filter(|k| *k != Kernels::Portable) {
        let (fast, fast_figures) = run(k);
        assert_same_files(&fast, &portable, &format!("{k:?} against the portable kernels"));
        assert!(fast_figures == portable_figures, "{k:?}: summary.json's figures differ");
    }
}

#[test]
fn a_width_the_host_lacks_or_an_unknown_name_is_refused_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    for (value, says) in [("sse9", "expected one of portable, avx2, avx512, native"), ("avx512", "avx512")] {
        if value == "avx512" && Kernels::Avx512.available() {
            continue;
        }
        let out = dir.path().join("out");
        let (ok, _, err) =
            nerfsv_with(&["scene", "--scene", "monolith", "--out", s(&out)], &[("NERFSV_KERNELS", value)]);
        assert!(!ok && err.contains("NERFSV_KERNELS") && err.contains(says), "{value}: {err}");
        assert!(!out.exists(), "{value}: wrote {}", out.display());
    }
}
