//! A user's own world: a mesh (written by trimesh, `tests/fixtures/meshes/`) as the ground
//! truth, with the dataset rendered from it or a dataset folder used as is; `nerfsv run` trains,
//! flies, stress-tests and reports on it. Bad worlds are refused by name before anything is
//! written.

mod common;

use std::path::{Path, PathBuf};

use common::nerfsv;

const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/meshes");

/// A tiny study of the fixture world in `dir` (the mesh copied beside the config), its
/// `[world]` table `mesh = "world.ply"` and `world`; returns the config's path.
fn config(dir: &Path, world: &str) -> PathBuf {
    std::fs::copy(Path::new(FIXTURES).join("world.ply"), dir.join("world.ply")).unwrap();
    let cfg = dir.join("run.toml");
    std::fs::write(
        &cfg,
        format!(
            "cells_per_metre = 10.0\ntrain_steps = 30\n[dataset]\nwidth = 16\nheight = 16\n\
             train = 6\nval = 1\ntest = 2\nsupersample = 1\n[train]\nbatch_rays = 256\n\
             [sim]\nstart = [0.8, -0.7, 0.25]\ngoal = [-0.8, 0.8, 0.25]\n\
             [sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n\
             [stress.monte_carlo]\nrollouts = 4\n[stress.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 4\n\
             [stress.subset]\nsamples = 10\nmax_levels = 2\n\
             [uq]\nmax_rays = 16\nperturbations = 1\nlm_iterations = 2\nonline_rays = 64\nonline_bla_rays = 16\n\
             [uq_offline]\nbla_images_per_split = 1\n[world]\n{world}"
        ),
    )
    .unwrap();
    cfg
}

/// `nerfsv scene WORLD --out out` at the tiny study's size (16×16, 6 + 1 + 2 views).
fn tiny_dataset(world: &[&str], out: &Path) {
    let size = ["--width", "16", "--height", "16", "--train", "6", "--val", "1", "--test", "2", "--supersample", "1"];
    let args: Vec<&str> = ["scene"]
        .into_iter()
        .chain(world.iter().copied())
        .chain(["--out", out.to_str().unwrap()])
        .chain(size)
        .collect();
    let (ok, _, err) = nerfsv(&args);
    assert!(ok, "{err}");
}

fn summary(run: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn a_mesh_world_runs_end_to_end_with_its_dataset_rendered_or_given() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), MESH);
    let run = dir.path().join("run");
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", run.to_str().unwrap()]);
    assert!(ok, "{err}");
    let s = summary(&run);
    assert_eq!(s["dataset"]["scene"], "world", "the dataset is rendered from the mesh");
    assert_eq!(s["collision"]["scene"], "world", "the ground-truth field is the mesh's");
    assert_eq!(s["flight"]["flights"].as_array().unwrap().len(), 4, "both worlds, both estimators");
    assert!(run.join("stress/replay_gt.csv").exists(), "the searches are replayed in the mesh's GT-sim");
    assert!(run.join("report/index.html").exists());
    // One flight in the mesh's GT-sim with the run's model, as `nerfsv fly` does it.
    let fly = dir.path().join("fly");
    let model = run.join("nerf/checkpoint.safetensors");
    let mesh = dir.path().join("world.ply");
    let (ok, out, err) = nerfsv(&[
        "fly",
        "--world",
        "gt",
        "--gt-mesh",
        mesh.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        fly.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let f: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(f["world"], "gt", "{f}");
    assert!(fly.join("trajectory.png").exists());

    // The same world with a dataset folder used as is (rendered here by `nerfsv scene --mesh`).
    let data = dir.path().join("data");
    tiny_dataset(&["--mesh", dir.path().join("world.ply").to_str().unwrap()], &data);
    let cfg = config(dir.path(), "mesh = \"world.ply\"\ndataset = \"data\"\n");
    let given = dir.path().join("given");
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", given.to_str().unwrap()]);
    assert!(ok, "{err}");
    let s = summary(&given);
    assert_eq!(s["dataset"]["views"], 9);
    assert!(given.join("dataset/source.json").exists(), "the folder is read where it is");
    assert!(!given.join("dataset/transforms_train.json").exists(), "nothing is rendered");
    assert_eq!(s["flight"]["flights"].as_array().unwrap().len(), 4);

    // The dataset alone: whatever needs the ground truth is skipped, and the report says so.
    let cfg = config(dir.path(), "dataset = \"data\"\n");
    let alone = dir.path().join("alone");
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", alone.to_str().unwrap()]);
    assert!(ok, "{err}");
    let s = summary(&alone);
    for stage in ["collision", "online"] {
        assert!(s[stage]["skipped"].as_str().unwrap().contains("no ground truth"), "{stage}: {}", s[stage]);
    }
    assert!(s["nerf_collision"]["agreement_with_ground_truth"].is_null());
    let flights = s["flight"]["flights"].as_array().unwrap();
    assert_eq!(flights.len(), 2);
    assert!(flights.iter().all(|f| f["world"] == "nerf"), "{flights:?}");
    assert!(s["stress"]["replay_world"].is_null());
    assert!(!alone.join("stress/replay_gt.csv").exists());
    let page = std::fs::read_to_string(alone.join("report/index.html")).unwrap();
    assert!(page.contains("Skipped: the world has no ground truth"), "the report does not say what was skipped");
}

const MESH: &str = "mesh = \"world.ply\"\n";

#[test]
fn a_world_that_does_not_fit_is_refused_by_name_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    for (extra, needle) in
        [("mesh_scale = 3.0\n", "outside the NeRF's box"), ("mesh_scale = -1.0\n", "world.mesh_scale")]
    {
        let cfg = config(dir.path(), &format!("{MESH}{extra}"));
        let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", run.to_str().unwrap()]);
        assert!(!ok, "{extra}");
        assert!(err.contains(needle), "{extra}: {err}");
        assert!(!run.exists(), "{extra}: the run folder was made");
    }
    let cfg = config(dir.path(), MESH);
    std::fs::remove_file(dir.path().join("world.ply")).unwrap();
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", run.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("world.mesh") && err.contains("world.ply"), "{err}");
    assert!(!run.exists());
    // A dataset of another world: its cameras look elsewhere.
    std::fs::copy(Path::new(FIXTURES).join("world.ply"), dir.path().join("world.ply")).unwrap();
    let data = dir.path().join("far");
    tiny_dataset(&["--scene", "monolith"], &data);
    let cfg = config(dir.path(), "mesh = \"world.ply\"\ndataset = \"far\"\nmesh_scale = 0.05\n");
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", run.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("world.dataset") && err.contains("look at the mesh"), "{err}");
    assert!(!run.exists());
}
