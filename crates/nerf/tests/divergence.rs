//! A run that diverges stops with an error naming the step, and the last checkpoint on disk
//! stays a loadable, finite model.

mod common;

use nerfsv_nerf::{train, Budget, Nerf, NerfError, TrainConfig};

#[test]
fn a_diverging_run_stops_on_non_finite_values_and_keeps_the_last_good_checkpoint() {
    let data = common::tiny_split(8, 16, 0.0);
    let dir = tempfile::tempdir().unwrap();
    // An absurd learning rate blows the weights up within a few steps.
    let cfg =
        TrainConfig { lr: 1e30, checkpoint_every_steps: 1, checkpoint_every_s: 0.0, ..common::tiny_train_config(0) };
    let err = train(&data, dir.path(), Budget::Steps(50), false, common::tiny_config(), cfg, |_| {}).unwrap_err();
    assert!(matches!(err, NerfError::NonFinite { .. }), "expected a non-finite error, got {err}");
    let msg = err.to_string();
    assert!(msg.contains("step"), "{msg}");
    let ck = nerfsv_nerf::checkpoint_path(dir.path());
    let nerf = Nerf::load(&ck).expect("the last checkpoint must still load");
    assert!(nerf.params.iter().all(|p| p.is_finite()), "the checkpoint kept must be finite");
    let mut names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    names.sort();
    assert_eq!(names, ["checkpoint.safetensors", "train_stats.json"], "no temporary files left");
}
