//! The ensemble as NeRF-sim's world, tried as a user would: a tiny run with two members writes
//! the transfer table into `summary.json` and the report, a killed run resumes to the same bytes
//! (every rollout flies in the same member again), and a member is the model `nerfsv train`
//! gives with its seed.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};

use common::{assert_same_files, files, nerfsv, s, tiny_ensemble_run_config as config, TINY_MODEL as MODEL};

fn summary(root: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(root.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn a_tiny_run_with_an_ensemble_writes_the_transfer_table_and_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path());
    let reference = dir.path().join("reference");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&reference)]);
    assert!(ok, "{err}");

    let sum = summary(&reference);
    let members = &sum["ensemble"]["trained"];
    assert_eq!(members.as_array().unwrap().len(), 2, "{sum:#}");
    assert_eq!(members[1]["seed"], 2, "member k trains with seed train.seed + k");
    let t = &sum["stress"]["transfer"];
    for world in ["nerf_deployed", "nerf_ensemble", "gt"] {
        let rate = t[world]["rate"].as_f64().unwrap();
        let ci = t[world]["ci95"].as_array().unwrap();
        assert!(ci[0].as_f64().unwrap() <= rate && rate <= ci[1].as_f64().unwrap(), "{world}: {t:#}");
        assert_eq!(t[world]["rollouts"], 6);
    }
    for key in ["mcnemar_p_deployed", "mcnemar_p_ensemble"] {
        let p = t[key].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&p), "{key}: {t:#}");
    }
    for key in [
        "recall_deployed",
        "recall_ensemble",
        "precision_deployed",
        "precision_ensemble",
        "mcc_deployed",
        "mcc_ensemble",
    ] {
        assert!(t.get(key).is_some(), "{key} missing: {t:#}");
    }
    // The ensemble's per-step uncertainty against the steps where the worlds disagree, per sampler.
    let samplers: Vec<&str> =
        t["step_auroc"].as_array().unwrap().iter().map(|a| a["sampler"].as_str().unwrap()).collect();
    assert_eq!(samplers, ["mc", "cem"], "{t:#}");
    assert!(t["step_auroc"][0]["auroc"]["steps"].as_u64().unwrap() > 0, "{t:#}");
    assert!(reference.join("stress/ensemble_step_uncertainty.csv").exists());
    // The ensemble's depth AUSE beside a random ordering's, on GA's and BLA's test images.
    let e = &sum["uq"]["ensemble_ause"];
    assert_eq!(e["members"], 3, "{e:#}");
    assert!(e["on_bla_images"].as_f64().is_some() && e["random_on_bla_images"].as_f64().is_some(), "{e:#}");
    let ause = std::fs::read_to_string(reference.join("uq/ause.csv")).unwrap();
    assert!(ause.lines().any(|l| l.starts_with("ensemble,")) && ause.lines().any(|l| l.starts_with("random,")));
    // The ensemble's uncertainty field, its slice in the report, and its panel in the maps.
    let field = nerfsv_uq::UncertaintyField::load(&reference.join("uq/ensemble_field.safetensors")).unwrap();
    assert_eq!(field.method, nerfsv_uq::FieldMethod::Ensemble);
    assert!(sum["uq"]["ensemble_field"]["mean_variance"].as_f64().is_some(), "{:#}", sum["uq"]);
    // The search flew in the ensemble; Monte Carlo flew again in the deployed NeRF's world.
    assert!(reference.join("stress/nerf_deployed/rollouts.csv").exists());
    let page = std::fs::read_to_string(reference.join("report/index.html")).unwrap();
    let answer = page.find("Do failures found in a NeRF predict failures in the world?").expect("the transfer answer");
    assert!(answer < page.find("How likely does the drone crash").unwrap(), "the transfer table opens the answer");
    assert!(page.contains("ensemble_field_z0.30.png"), "the ensemble field's slice in the report");

    // Killed during its stress stage and run again: the same rollouts in the same members.
    let out = dir.path().join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_nerfsv"))
        .args(["run", s(&cfg), "--out", s(&out)])
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let journal = out.join("stress/journal");
    let start = std::time::Instant::now();
    while !journal.exists() && start.elapsed().as_secs() < 300 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    child.kill().unwrap();
    child.wait().unwrap();
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&out)]);
    assert!(ok, "{err}");
    assert_same_files(&files(&out), &files(&reference), "a killed and resumed run against a whole one");
    assert_eq!(summary(&out)["stress"]["transfer"], sum["stress"]["transfer"]);

    // Member 1 is what `nerfsv train` makes of the run's dataset with seed 1.
    let train_cfg = dir.path().join("train.toml");
    std::fs::write(&train_cfg, format!("{MODEL}seed = 1\n")).unwrap();
    let alone = dir.path().join("alone");
    let (ok, _, err) = nerfsv(&[
        "train",
        "--data",
        s(&reference.join("dataset")),
        "--out",
        s(&alone),
        "--steps",
        "3",
        "--config",
        s(&train_cfg),
    ]);
    assert!(ok, "{err}");
    let member = nerfsv_nerf::Nerf::load(&reference.join("ensemble/member_1/checkpoint.safetensors")).unwrap();
    let trained = nerfsv_nerf::Nerf::load(&alone.join("checkpoint.safetensors")).unwrap();
    assert_eq!((member.seed, member.step), (1, 3));
    assert!(member.params == trained.params, "member 1's weights are `nerfsv train --seed 1`'s bit for bit");
    assert!(member.grid.density == trained.grid.density);

    // Another threshold for the members' fields (NeRF-sim's geometry) changes theirs, not the map
    // the drone plans on: the deployed field and the flight stage's plan stay as they were.
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&out), "--set", "ensemble.density_threshold=0.001"]);
    assert!(ok, "{err}");
    assert!(err.contains("nerf_collision: up to date") && err.contains("flight: up to date"), "{err}");
    assert!(!err.contains("ensemble: up to date"), "{err}");
    let bytes = |run: &std::path::Path, file: &str| std::fs::read(run.join(file)).unwrap();
    let sdf = "ensemble/member_1/nerf_sdf.safetensors";
    assert!(bytes(&out, sdf) != bytes(&reference, sdf), "member 1's field at the members' own threshold");
    let map = "nerf_collision/nerf_sdf.safetensors";
    assert!(bytes(&out, map) == bytes(&reference, map));
}

#[test]
fn a_recorded_route_capture_joins_the_calibration_and_a_missing_one_is_refused_by_its_key() {
    let dir = tempfile::tempdir().unwrap();
    // Four views at known poses (two training, one validation, one test view of the world).
    common::tiny_dataset(&dir.path().join("route"), "2", "1");
    let cfg = config(dir.path());
    let calibrated =
        std::fs::read_to_string(&cfg).unwrap().replace("nerf_world = \"ensemble\"", "nerf_world = \"calibrated\"");
    let with_route = |folder: &str| {
        std::fs::write(
            &cfg,
            format!("{calibrated}[calibration]\nroute_views = 2\nfits_per_view = 1\nroute_dataset = \"{folder}\"\n"),
        )
        .unwrap()
    };
    with_route("route/ds");
    let out = dir.path().join("run");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&out)]);
    assert!(ok, "{err}");
    let c = &summary(&out)["calibration"];
    assert_eq!((c["route_views"].as_u64(), c["route_dataset_views"].as_u64()), (Some(2), Some(4)), "{c:#}");
    // The deployed field's and each member's along the route against the ground truth's, in
    // the summary and on the page.
    let g = &c["route_geometry"];
    let fields: Vec<&str> = g["fields"].as_array().unwrap().iter().map(|f| f["field"].as_str().unwrap()).collect();
    assert_eq!(fields, ["deployed", "member 1", "member 2"], "{g:#}");
    assert!(g["points"].as_u64().unwrap() > 10 && g["gt_min_distance_m"].as_f64().is_some_and(f64::is_finite), "{g:#}");
    let split = g["near_points"].as_u64().unwrap() + g["ground_points"].as_u64().unwrap();
    assert!(split <= g["points"].as_u64().unwrap(), "{g:#}");
    assert!(g["fields"].as_array().unwrap().iter().all(|f| f["error_at_tight_pass_m"].as_f64().is_some()), "{g:#}");
    let page = std::fs::read_to_string(out.join("report/index.html")).unwrap();
    assert!(page.contains("What the error model cannot see"));
    let fits = std::fs::read_to_string(out.join("calibration/calibration_fits.csv")).unwrap();
    let recorded: Vec<&str> = fits.lines().filter(|l| l.starts_with("route_dataset,")).collect();
    assert_eq!(recorded.len(), 4, "{fits}");
    // Each found along the route.
    for l in recorded {
        let fraction: f64 = l.split(',').nth(3).unwrap().parse().unwrap();
        assert!((0.0..=1.0).contains(&fraction), "{l}");
    }
    // The filter's model error rests on the fits it would take (a tiny NeRF's may all be lost).
    let header: Vec<&str> = fits.lines().next().unwrap().split(',').collect();
    let vf = header.iter().position(|h| *h == "variance_factor").unwrap();
    let taken = fits.lines().skip(1).filter(|l| l.split(',').nth(vf).unwrap().parse::<f64>().unwrap() <= 5.0).count();
    match taken {
        0 => assert!(c["model_error"].is_null(), "{c:#}"),
        n => assert_eq!(c["model_error"]["fits"].as_u64(), Some(n as u64), "{c:#}"),
    }

    with_route("nowhere");
    let fresh = dir.path().join("fresh");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&fresh)]);
    assert!(!ok);
    assert!(err.contains("calibration.route_dataset") && err.contains("nowhere"), "{err}");
    assert!(!fresh.join("dataset").exists(), "refused before any stage");
}
