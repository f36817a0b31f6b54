//! `nerfsv replicate`, tried as a user would: the tiny study with two training seeds writes both
//! runs, their headline rows and each headline's mean and standard deviation; the second run
//! takes the first's dataset and ground truth instead of computing them again; the online methods
//! run only when asked.

mod common;

use common::{nerfsv, s, tiny_ensemble_run_config as config};

#[test]
fn replicate_with_two_seeds_writes_both_rows_and_the_spread() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path());
    let out = dir.path().join("replicate");
    let (ok, _, err) = nerfsv(&["replicate", s(&cfg), "--seeds", "2", "--out", s(&out)]);
    assert!(ok, "{err}");
    // The config's training seed (the default 0), then 16 later: no ensemble member shared.
    for seed in [0, 16] {
        let summary = out.join(format!("seed_{seed}/summary.json"));
        assert!(summary.exists(), "{}", summary.display());
        assert!(out.join(format!("seed_{seed}/report/index.html")).exists());
    }
    let second = std::fs::read_to_string(out.join("seed_16/summary.json")).unwrap();
    let second: serde_json::Value = serde_json::from_str(&second).unwrap();
    assert_eq!(second["ensemble"]["trained"][0]["seed"], 17, "{second:#}");
    assert!(err.contains("dataset: up to date"), "the second run must take the first's dataset: {err}");
    // Without --online no run studies the config's online method (GA); the stage still scores
    // the baselines.
    assert!(!out.join("seed_0/online/ga").exists() && second["online"]["studies"].as_array().unwrap().is_empty());
    assert!(second["online"]["step_auroc"].as_array().is_some_and(|a| !a.is_empty()), "{second:#}");

    let csv = std::fs::read_to_string(out.join("replicate.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 1 + 2 + 2, "{csv}");
    assert!(rows[0].starts_with("row,train_seed,\"test PSNR (dB)\""), "{csv}");
    assert!(rows[1].starts_with("seed,0,") && rows[2].starts_with("seed,16,"), "{csv}");
    assert!(rows[3].starts_with("mean,,") && rows[4].starts_with("sd,,"), "{csv}");

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("replicate.json")).unwrap()).unwrap();
    let psnr = &json["headlines"][0];
    let values: Vec<f64> = json["seeds"].as_array().unwrap().iter().map(|r| r["values"][0].as_f64().unwrap()).collect();
    assert_eq!(psnr["n"], 2);
    let mean = (values[0] + values[1]) / 2.0;
    assert!((psnr["mean"].as_f64().unwrap() - mean).abs() < 1e-12, "{json:#}");
    let sd = (values[0] - values[1]).abs() / 2f64.sqrt();
    assert!((psnr["sd"].as_f64().unwrap() - sd).abs() < 1e-9, "{json:#}");
    assert!(values[0] != values[1], "different training seeds must train different models");
    // The stress stage's comparison reaches the rows: each run's NeRF-sim and GT-sim rates.
    let label = |h: usize| json["headlines"][h]["headline"].as_str().unwrap().to_owned();
    for h in [1, 2, 4] {
        assert!(label(h).contains("failure rate"), "{json:#}");
        for row in json["seeds"].as_array().unwrap() {
            assert!(row["values"][h].is_number(), "{}: {json:#}", label(h));
        }
    }
    let page = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(page.contains("test PSNR (dB)") && page.contains("seed 16"), "{page}");
}

/// Replicated over disturbance seeds, every run takes the first's models (so every figure of
/// training is the same) and flies other disturbances; the worlds' comparisons are pooled over
/// the runs' rollouts.
#[test]
fn replicate_over_disturbance_seeds_shares_the_models_and_pools_the_transfer() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path());
    let out = dir.path().join("replicate");
    let (ok, _, err) = nerfsv(&[
        "replicate",
        s(&cfg),
        "--seeds",
        "2",
        "--vary",
        "disturbances",
        "--out",
        s(&out),
        "--set",
        "stress.seed=5",
        "--online",
    ]);
    assert!(ok, "{err}");
    for seed in [5, 6] {
        assert!(out.join(format!("stress_seed_{seed}/summary.json")).exists(), "{seed}: {err}");
        // --online: each run studies the config's online method too.
        assert!(out.join(format!("stress_seed_{seed}/online/ga/reward")).is_dir(), "{seed}");
    }
    for stage in ["nerf", "ensemble"] {
        assert!(err.contains(&format!("{stage}: up to date")), "the second run must take the first's {stage}: {err}");
    }
    let csv = std::fs::read_to_string(out.join("replicate.csv")).unwrap();
    assert!(csv.starts_with("row,stress_seed,") && csv.contains("\nseed,5,") && csv.contains("\nseed,6,"), "{csv}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("replicate.json")).unwrap()).unwrap();
    assert_eq!(json["varied"], "disturbances");
    assert_eq!(json["headlines"][0]["sd"].as_f64(), Some(0.0), "the same model in both runs: {json:#}");
    // Each run's comparison, summed: the pooled counts are the runs' counts together.
    let run = |seed: u64| -> serde_json::Value {
        let text = std::fs::read_to_string(out.join(format!("stress_seed_{seed}/summary.json"))).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    let pooled = json["pooled"].as_array().unwrap();
    assert!(!pooled.is_empty(), "{json:#}");
    for p in pooled {
        let world = p["world"].as_str().unwrap();
        assert_eq!(p["runs"], 2, "{world}");
        for cell in ["true_positive", "false_positive", "false_negative", "true_negative"] {
            let each: u64 =
                [5, 6].iter().map(|&s| run(s)["stress"]["transfer"][world]["confusion"][cell].as_u64().unwrap()).sum();
            assert_eq!(p["transfer"]["confusion"][cell].as_u64(), Some(each), "{world} {cell}");
        }
    }
    let page = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(page.contains("disturbance seeds") && page.contains("all runs' rollouts together"), "{page}");
}
