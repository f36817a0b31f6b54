//! The `nerfsv` binary: bad input stops with a message naming what is wrong, exit code non-zero,
//! and nothing half-written left behind.

mod common;

use common::nerfsv;

/// A tiny dataset with `train` training views.
fn tiny_dataset(dir: &std::path::Path, train: &str) -> std::path::PathBuf {
    common::tiny_dataset(dir, train, "1")
}

#[test]
fn unknown_scene_is_named_and_fails() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let (ok, _, err) = nerfsv(&["scene", "--scene", "atlantis", "--out", out.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("atlantis") && err.contains("stonehenge"), "{err}");
    assert!(!out.exists());
}

#[test]
fn zero_or_absurd_sizes_are_rejected_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    for (flag, value, field) in [("--width", "0", "width"), ("--height", "99999", "height"), ("--test", "0", "test")] {
        let (ok, _, err) = nerfsv(&["scene", "--out", out.to_str().unwrap(), flag, value]);
        assert!(!ok, "{flag} {value} must fail");
        assert!(err.contains(field), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}

#[test]
fn out_of_range_flags_are_named_as_flags_before_anything_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-model.safetensors");
    let out = dir.path().join("out");
    for (args, flag) in [
        (
            vec![
                "collision",
                "--model",
                missing.to_str().unwrap(),
                "--density-threshold",
                "0",
                "--out",
                out.to_str().unwrap(),
            ],
            "--density-threshold",
        ),
        (
            vec![
                "eval",
                "--model",
                missing.to_str().unwrap(),
                "--data",
                dir.path().to_str().unwrap(),
                "--max-images",
                "0",
            ],
            "--max-images",
        ),
    ] {
        let (ok, _, err) = nerfsv(&args);
        assert!(!ok, "{args:?} was accepted");
        assert!(err.contains(flag), "{flag} not named: {err}");
        assert!(!err.contains("no-model"), "the model was read before the flag was checked: {err}");
        assert!(!out.exists());
    }
}

#[test]
fn scene_writes_a_dataset_and_reports_json() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let (ok, stdout, err) = nerfsv(&[
        "scene",
        "--scene",
        "pillars",
        "--out",
        out.to_str().unwrap(),
        "--width",
        "12",
        "--height",
        "10",
        "--train",
        "2",
        "--val",
        "1",
        "--test",
        "1",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(v["views"], 4);
    // Progress as JSON lines on stderr, the last at the end of its work.
    let lines: Vec<serde_json::Value> =
        err.lines().map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l:?}"))).collect();
    let last = lines.iter().rev().find(|l| l.get("done").is_some()).unwrap_or_else(|| panic!("no progress: {err}"));
    assert!(last["stage"].is_string() && last["done"] == last["total"] && last["seconds"].is_number(), "{err}");
    for f in
        ["transforms_train.json", "transforms_val.json", "transforms_test.json", "train/r_1.png", "test/r_0_depth.png"]
    {
        assert!(out.join(f).exists(), "{f} missing");
    }
}

#[test]
fn bad_config_names_the_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("run.toml");
    std::fs::write(&cfg, "scene = \"stonehenge\"\ncells_per_metre = 0.0\n").unwrap();
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", dir.path().join("r").to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("run.toml") && err.contains("cells_per_metre"), "{err}");
    std::fs::write(&cfg, "[dataset]\nwidht = 10\n").unwrap();
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("run.toml") && err.contains("widht"), "{err}");
    // A start inside the ground disc: refused before any stage runs, naming the file and key, once.
    std::fs::write(&cfg, "scene = \"monolith\"\n[sim]\nstart = [0.3, 0.2, -0.05]\n").unwrap();
    let out = dir.path().join("inside");
    let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("run.toml") && err.contains("sim.start") && err.contains("inside"), "{err}");
    assert_eq!(err.matches("sim.start").count(), 1, "{err}");
    assert!(!out.exists(), "a stage ran before the start was checked");
}

#[test]
fn a_file_that_is_not_a_nerf_checkpoint_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let grid = dir.path().join("gt.safetensors");
    let (ok, _, err) = nerfsv(&["collision", "--scene", "monolith", "--out", grid.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let ds = tiny_dataset(dir.path(), "1");
    // A collision grid is a safetensors file too, but not a NeRF checkpoint.
    let (ok, _, err) = nerfsv(&[
        "eval",
        "--model",
        grid.to_str().unwrap(),
        "--data",
        ds.to_str().unwrap(),
        "--split",
        "test",
        "--json",
    ]);
    assert!(!ok);
    assert!(err.contains("gt.safetensors") && err.contains("format"), "{err}");
    let (ok, _, err) = nerfsv(&[
        "eval",
        "--model",
        dir.path().join("none.safetensors").to_str().unwrap(),
        "--data",
        ds.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("none.safetensors"), "{err}");
}

#[test]
fn training_into_an_unwritable_folder_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ds = tiny_dataset(dir.path(), "2");
    // A regular file where the output folder should be.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let out = blocker.join("nerf");
    let (ok, _, err) =
        nerfsv(&["train", "--data", ds.to_str().unwrap(), "--out", out.to_str().unwrap(), "--steps", "2"]);
    assert!(!ok);
    assert!(err.contains("file"), "{err}");
}

#[test]
fn out_of_range_training_settings_name_the_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let ds = tiny_dataset(dir.path(), "2");
    let cfg = dir.path().join("nerf.toml");
    std::fs::write(&cfg, "[train]\nlr = -0.01\n").unwrap();
    let out = dir.path().join("nerf");
    let (ok, _, err) = nerfsv(&[
        "train",
        "--data",
        ds.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--steps",
        "2",
        "--config",
        cfg.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("nerf.toml") && err.contains("train.lr") && err.contains("-0.01"), "{err}");
    assert!(!out.exists(), "nothing may be written");
}

#[test]
fn run_redoes_only_the_stages_whose_inputs_changed_and_resumes_an_interrupted_training() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let cfg = dir.path().join("run.toml");
    let write_cfg = |steps: u32, ga_images: u32| {
        let text = format!(
            "scene = \"monolith\"\ncells_per_metre = 10.0\ntrain_steps = {steps}\n[dataset]\nwidth = 16\nheight = 16\n\
             train = 6\nval = 1\ntest = 1\nsupersample = 1\n[train]\nbatch_rays = 256\n[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n\
             [stress.monte_carlo]\nrollouts = 4\n[stress.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 4\n\
             [stress.subset]\nsamples = 10\nmax_levels = 2\n\
             [uq]\nmax_rays = 16\nperturbations = 1\nlm_iterations = 2\nonline_rays = 64\nonline_bla_rays = 16\n[uq_offline]\nbla_images_per_split = 1\nga_images_per_split = {ga_images}\n"
        );
        std::fs::write(&cfg, text).unwrap();
    };
    let run = || {
        let (ok, _, err) = nerfsv(&["run", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        assert!(ok, "{err}");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
        (err, summary)
    };
    write_cfg(3, 50);
    let (first, summary) = run();
    assert!(!first.contains("up to date"), "{first}");
    assert_eq!(summary["nerf"]["steps"], 3);
    assert_uq_stage(&out, &summary["uq"]);
    assert_online_stage(&out, &summary["online"]);
    assert_report(&out, &first);
    // The stress stage estimates P(fail) by subset simulation too, its level 0 from the MC rollouts.
    let samplers = summary["stress"]["samplers"].as_array().unwrap();
    let names: Vec<&str> = samplers.iter().map(|s| s["sampler"].as_str().unwrap()).collect();
    assert_eq!(names, ["mc", "cem", "subset"]);
    let subset = &samplers[2];
    let how = subset["p_fail_estimator"].as_str().unwrap();
    assert!(how.contains("level 0: 4 Monte Carlo rollouts and 6 more"), "{how}");
    assert!(subset["p_fail"].as_f64().is_some_and(|p| (0.0..=1.0).contains(&p)), "{subset}");

    // Every stage the summary records (its own `run` record aside), whichever stages the run has.
    let stages: Vec<String> = summary.as_object().unwrap().keys().filter(|k| *k != "run").cloned().collect();
    assert!(stages.iter().any(|s| s == "dataset") && stages.iter().any(|s| s == "online"), "{stages:?}");
    let (second, again) = run();
    for stage in &stages {
        assert!(second.contains(&format!("{stage}: up to date")), "{stage} should be cached:\n{second}");
    }
    assert_eq!(summary, again);

    // Fewer GA images: only the uncertainty stage is redone (its key holds its config slice).
    write_cfg(3, 2);
    let (fewer, changed) = run();
    for stage in stages.iter().filter(|s| *s != "uq") {
        assert!(fewer.contains(&format!("{stage}: up to date")), "{stage} should be cached:\n{fewer}");
    }
    assert!(!fewer.contains("uq: up to date"), "{fewer}");
    assert_eq!(changed["uq"]["train"]["ga_images"], 2);

    // More training steps: the dataset and the ground-truth field stay, the rest is redone.
    write_cfg(5, 50);
    let (third, changed) = run();
    assert!(third.contains("dataset: up to date") && third.contains("collision: up to date"), "{third}");
    for stage in ["nerf", "eval", "uq"] {
        assert!(!third.contains(&format!("{stage}: up to date")), "{stage} should be redone:\n{third}");
    }
    assert_eq!(changed["nerf"]["steps"], 5);

    // A run killed after its last checkpoint but before the stage completed resumes from it.
    std::fs::remove_file(out.join("nerf/stage.json")).unwrap();
    let (fourth, resumed) = run();
    assert!(fourth.contains("nerf: resuming the interrupted run"), "{fourth}");
    assert_eq!(resumed["eval"], changed["eval"], "resuming must end at the same model");
    assert_eq!(resumed["nerf"]["steps"], 5);
}

/// The files of the pictures a stage's kept section (`report.json`) names.
fn pictures_named(v: &serde_json::Value) -> Vec<String> {
    match v {
        serde_json::Value::Object(m) => match (m.get("file"), m.get("caption")) {
            (Some(serde_json::Value::String(f)), Some(_)) => vec![f.clone()],
            _ => m.values().flat_map(pictures_named).collect(),
        },
        serde_json::Value::Array(a) => a.iter().flat_map(pictures_named).collect(),
        _ => Vec::new(),
    }
}

/// The report of the tiny run above: the page has every section, every picture it shows is
/// beside it, the tables and summary are copied, and the run's last line names the page.
fn assert_report(run: &std::path::Path, stderr: &str) {
    let dir = run.join("report");
    let index = dir.join("index.html");
    assert!(stderr.contains(&format!("report: {}", index.display())), "{stderr}");
    let html = std::fs::read_to_string(&index).unwrap();
    // The answer first, then the contents, the stages' sections, the config, the timings last.
    let mut at = 0;
    for heading in [
        "The study's answer",
        "How likely does the drone crash",
        "Contents:",
        "The NeRF against the ground truth",
        "Offline uncertainty",
        "Collision fields",
        "Nominal flights",
        "Stress tests",
        "Tables 1–2",
        "Run config",
        "Stage timings",
    ] {
        let found =
            html[at..].find(heading).unwrap_or_else(|| panic!("{heading} missing from the report, or out of order"));
        at += found;
    }
    assert!(
        html.contains("<a href=\"#stress\">") && html.contains("<h2 id=\"stress\">"),
        "contents link to the sections"
    );
    assert!(!html.contains("has not run in this folder"), "a stage is missing from the report");
    let images: Vec<&str> = html.split("<img src=\"").skip(1).map(|s| s.split('"').next().unwrap()).collect();
    // The comparison, two flights and five uncertainty figures (the tiny drone does not crash,
    // so there is no most likely failure to show).
    assert!(images.len() >= 8, "{images:?}");
    for img in images {
        let bytes = std::fs::read(dir.join(img)).unwrap_or_else(|e| panic!("report/{img}: {e}"));
        assert_eq!(&bytes[1..4], b"PNG", "report/{img}");
    }
    // Every picture a stage's section names is one the stage wrote (the page would drop it
    // without a word).
    for stage in std::fs::read_dir(run).unwrap().flatten().map(|e| e.path()) {
        let Ok(text) = std::fs::read_to_string(stage.join("report.json")) else { continue };
        let section: serde_json::Value = serde_json::from_str(&text).unwrap();
        for file in pictures_named(&section) {
            assert!(stage.join(&file).is_file(), "{}'s section names {file}, which it did not write", stage.display());
        }
    }
    for f in ["summary.json", "stress_table.csv", "online_table.csv", "ause.csv", "config.toml"] {
        assert!(dir.join(f).is_file(), "report/{f} missing");
    }
    // The config shown is the run's (without the run folder) and loads as a run config.
    let config = std::fs::read_to_string(dir.join("config.toml")).unwrap();
    let back: nerfsv_pipeline::RunConfig = toml::from_str(&config).unwrap();
    assert_eq!(back.train_steps, 3);
}

/// The online stage of the tiny run above (4 MC rollouts, CEM 2 × 4): for GA and BLA, the rows
/// with and without reward of Tables 1–2 with a measured uncertainty, and the AUROC counts.
fn assert_online_stage(run: &std::path::Path, online: &serde_json::Value) {
    assert_eq!(online["mode"], "exact", "{online}");
    let studies = online["studies"].as_array().unwrap_or_else(|| panic!("online: {online}"));
    assert_eq!(studies.iter().map(|m| m["method"].as_str().unwrap()).collect::<Vec<_>>(), ["ga", "bla"]);
    for m in studies {
        let rows = m["rows"].as_array().unwrap();
        let label: Vec<(String, bool, u64)> = rows
            .iter()
            .map(|r| {
                (
                    r["sampler"].as_str().unwrap().to_owned(),
                    r["reward"].as_bool().unwrap(),
                    r["rollouts"].as_u64().unwrap(),
                )
            })
            .collect();
        assert_eq!(
            label,
            [("mc".into(), false, 4), ("mc".into(), true, 4), ("cem".into(), false, 8), ("cem".into(), true, 8)],
            "{m}"
        );
        for r in rows {
            assert!(r["avg_uncertainty"].as_f64().is_some_and(|u| u.is_finite() && u >= 0.0), "{r}");
        }
        // MC never ranks: its rows with and without reward are the same rollouts.
        assert_eq!(rows[0]["collision_rate"], rows[1]["collision_rate"]);
        assert!(rows[1]["avg_reward"].is_number() && rows[3]["avg_reward"].is_number(), "{m}");
        let d = &m["disagreement"];
        assert_eq!(d["trajectories"], 12, "every MC and CEM rollout is paired with its replay: {d}");
        assert!(d["steps"].as_u64().unwrap() >= 12, "{d}");
        assert!(
            m["views"].as_u64().unwrap() > 0 && m["milliseconds_per_view"].as_f64().is_some_and(|t| t > 0.0),
            "{m}"
        );
        // Both CEMs' populations (8 rollouts each) are replayed in GT-sim.
        let t = &m["transfer"];
        for key in ["without_reward", "with_reward"] {
            let total: u64 = ["true_positive", "false_positive", "false_negative", "true_negative"]
                .iter()
                .map(|c| t[key][c].as_u64().unwrap_or_else(|| panic!("transfer.{key}.{c}: {t}")))
                .sum();
            assert_eq!(total, 8, "{t}");
        }
        let method = m["method"].as_str().unwrap();
        let replays = std::fs::read_to_string(run.join(format!("online/{method}/reward/replay_gt.csv"))).unwrap();
        assert!(replays.lines().count() > 8, "{method}: the rewarded CEM's replays are written");
    }
    let table = std::fs::read_to_string(run.join("online/table.csv")).unwrap();
    assert!(table.starts_with("method,mode,reward,sampler,rollouts,collision_rate"), "{table}");
    assert_eq!(table.lines().count(), 1 + 8, "{table}");
    // Each measure against the baselines, GA's un-floored σ_d beside the configured floored one.
    let measures: std::collections::BTreeSet<&str> =
        online["step_auroc"].as_array().unwrap().iter().map(|r| r["measure"].as_str().unwrap()).collect();
    for m in ["ga", "ga-paper", "bla", "step_index", "clearance"] {
        assert!(measures.contains(m), "{m} missing from {measures:?}");
    }
}

/// The offline uncertainty stage of the tiny run above (6 train, 1 val, 1 test views; BLA on one
/// image per split): its figures in `summary.json` are finite and its files are there.
fn assert_uq_stage(run: &std::path::Path, uq: &serde_json::Value) {
    let number = |v: &serde_json::Value, key: &str| {
        v[key].as_f64().unwrap_or_else(|| panic!("uq: {key} missing or not a number in {v}"))
    };
    for (split, views) in [("train", 6.0), ("val", 1.0), ("test", 1.0)] {
        let s = &uq[split];
        assert_eq!(number(s, "ga_images"), views, "{split}: {s}");
        let (excluded, missed) = (number(s, "ga_excluded"), number(s, "ga_all_rays_miss"));
        assert_eq!(missed, 0.0, "{split}: {s}");
        let median = number(s, "ga_median_sigma_d");
        assert!(median.is_finite() && median >= 0.0, "{split}: {s}");
        // The mean leaves the excluded images out: it exists unless all of them are.
        if excluded < views {
            assert!(number(s, "ga_mean_sigma_d").is_finite() && number(s, "ga_mean_mu_d").is_finite(), "{split}: {s}");
        }
        assert_eq!(number(s, "bla_images"), 1.0, "{split}: {s}");
        let (trace, rmv) = (number(s, "bla_mean_normalized_trace"), number(s, "bla_mean_rmv"));
        // A weight's posterior variance is positive and at most the prior's, 1/α = 1.
        assert!(trace > 0.0 && trace <= 1.0 + 1e-9, "{split}: {s}");
        assert!((rmv - trace.sqrt()).abs() <= 1e-9, "{split}: {s}");
    }
    for method in ["ga", "bla"] {
        assert_eq!(number(uq, &format!("ause_{method}_images")), 1.0, "{uq}");
        let a = number(uq, &format!("ause_{method}"));
        assert!((0.0..=1.0).contains(&a), "ause_{method} = {a}");
    }
    assert!(number(uq, "seconds") >= 0.0);
    let dir = run.join("uq");
    let lines = |name: &str| {
        let text = std::fs::read_to_string(dir.join(name)).unwrap_or_else(|e| panic!("uq/{name}: {e}"));
        text.lines().map(str::to_string).collect::<Vec<_>>()
    };
    let ga = lines("uq_ga.csv");
    assert!(ga[0].starts_with("split,index,file_path,mu_d,sigma_d,excluded"), "{ga:?}");
    assert_eq!(ga.len(), 1 + 8, "{ga:?}");
    let bla = lines("uq_bla.csv");
    assert!(bla[0].starts_with("split,index,file_path,normalized_trace,rmv"), "{bla:?}");
    assert_eq!(bla.len(), 1 + 3, "{bla:?}");
    let ause = lines("ause.csv");
    assert_eq!(ause[0], "method,split,index,file_path,ause,pixels,unscored_pixels,skipped");
    assert!(ause[1].starts_with("ga,test,0,") && ause[2].starts_with("bla,test,0,"), "{ause:?}");
    for stem in ["uq_ga_sigma_d", "uq_ga_mu_sigma", "uq_bla_trace", "uq_bla_rmv", "uq_bla_trace_rmv"] {
        for ext in ["png", "svg"] {
            assert!(dir.join(format!("{stem}.{ext}")).is_file(), "uq/{stem}.{ext} missing");
        }
    }
}

#[test]
fn report_refuses_a_folder_without_a_summary_and_names_the_stages_a_run_lacks() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, _, err) = nerfsv(&["report", dir.path().to_str().unwrap()]);
    assert!(!ok && err.contains("not a run folder") && err.contains("summary.json"), "{err}");
    assert!(!dir.path().join("report").exists(), "a refused report wrote something");
    // A summary whose stages left no record in the folder: each one's section says so.
    std::fs::write(dir.path().join("summary.json"), r#"{"run": "partial", "dataset": {}, "stress": {}}"#).unwrap();
    let (ok, stdout, err) = nerfsv(&["report", dir.path().to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(v["pictures"], 0);
    assert_eq!(v["missing_stages"], serde_json::json!(["dataset", "stress"]), "{v}");
    let html = std::fs::read_to_string(dir.path().join("report/index.html")).unwrap();
    assert_eq!(html.matches("has not run in this folder").count(), 2, "{html}");
    assert!(html.contains("No stage that answers it has run in this folder."), "{html}");
    // A summary that is not JSON is named.
    std::fs::write(dir.path().join("summary.json"), "{").unwrap();
    let (ok, _, err) = nerfsv(&["report", dir.path().to_str().unwrap()]);
    assert!(!ok && err.contains("summary.json") && err.contains("not a run summary"), "{err}");
}

/// One config for every command: `nerfsv config` prints the default (as `--default` does), and
/// `train` trains from that very file with `--set` overrides on top; an override that names no
/// key is refused by name before anything is written.
#[test]
fn train_reads_the_printed_default_config_and_its_overrides() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, plain, err) = nerfsv(&["config"]);
    assert!(ok, "{err}");
    assert_eq!(plain, nerfsv(&["config", "--default"]).1);
    assert!(plain.contains("[stress.subset]\n") && plain.contains("\nsamples = 200\n"), "{plain}");
    // The config a file and overrides give, every key, and it reads back as that config.
    let mine = dir.path().join("mine.toml");
    std::fs::write(&mine, "train_steps = 7\n[stress.cem]\nm = 40\n").unwrap();
    let (ok, effective, err) = nerfsv(&["config", mine.to_str().unwrap(), "--set", "stress.cem.k_max=3"]);
    assert!(ok, "{err}");
    let table: toml::Table = toml::from_str(&effective).unwrap_or_else(|e| panic!("{e}\n{effective}"));
    assert_eq!(table["train_steps"].as_integer(), Some(7));
    let cem = &table["stress"]["cem"];
    assert_eq!((cem["m"].as_integer(), cem["k_max"].as_integer()), (Some(40), Some(3)), "{effective}");
    assert_eq!(table["stress"]["subset"]["samples"].as_integer(), Some(200));
    let keys = |t: &str| t.lines().filter(|l| !l.is_empty() && !l.starts_with(['#', '['])).count();
    assert_eq!(keys(&effective), keys(&plain), "every key, as the default has");
    let (ok, _, err) = nerfsv(&["config", mine.to_str().unwrap(), "--set", "stress.cem.kmax=3"]);
    assert!(!ok && err.contains("stress.cem.kmax=3"), "{err}");
    let cfg = dir.path().join("nerfsv.toml");
    std::fs::write(&cfg, &plain).unwrap();
    let ds = common::tiny_dataset(dir.path(), "6", "1");
    let out = dir.path().join("model");
    let train = |sets: &[&str]| {
        let base = ["train", "--data", ds.to_str().unwrap(), "--out", out.to_str().unwrap(), "--steps", "2"];
        nerfsv(&[&base[..], &["--config", cfg.to_str().unwrap()], sets].concat())
    };
    let (ok, _, err) = train(&["--set", "train.batch_rays=64", "--set", "train.batch_ray=64"]);
    assert!(!ok && err.contains("--set train.batch_ray=64") && err.contains("unknown field"), "{err}");
    assert!(!out.exists());
    let (ok, _, err) = train(&["--set", "nerf.grid_resolution=32", "--set", "train.batch_rays=64"]);
    assert!(ok, "{err}");
    let model = nerfsv_nerf::Nerf::load(&out.join("checkpoint.safetensors")).unwrap();
    assert_eq!(model.config.grid_resolution, 32);
}

/// `nerfsv completions SHELL` prints each shell's script naming every subcommand; bash's parses.
#[test]
fn completion_scripts_name_every_subcommand_and_bash_reads_its_own() {
    let subcommands = ["run", "replicate", "config", "report", "stress", "export", "uq", "completions"];
    for (shell, marker) in [("bash", "_nerfsv()"), ("zsh", "#compdef nerfsv"), ("fish", "complete -c nerfsv")] {
        let (ok, script, err) = nerfsv(&["completions", shell]);
        assert!(ok, "{shell}: {err}");
        assert!(script.contains(marker), "{shell}: {script}");
        for sub in subcommands {
            assert!(script.contains(sub), "{shell}: no {sub}");
        }
        if shell == "bash" {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("nerfsv.bash");
            std::fs::write(&path, &script).unwrap();
            let status = std::process::Command::new("bash").arg("-n").arg(&path).status().unwrap();
            assert!(status.success(), "bash -n refused the script");
        }
    }
    let (ok, _, err) = nerfsv(&["completions", "tcsh"]);
    assert!(!ok && err.contains("tcsh"), "{err}");
}

fn png_rgba(path: &std::path::Path) -> Vec<u8> {
    let mut reader =
        png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap())).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    buf
}

/// `render --path` with a nerfstudio camera path made of the dataset's own test camera renders
/// exactly what `render --split test` renders there (the path's row-major matrix and vertical
/// field of view are the dataset's camera), and the animation holds every frame; a trajectory
/// CSV renders one frame per row through the config's drone camera, the estimate's poses with
/// `--estimate`; a bad path is refused by file and field.
#[test]
fn render_along_a_camera_path_or_a_trajectory_gives_frames_and_their_animation() {
    let dir = tempfile::tempdir().unwrap();
    let ds = tiny_dataset(dir.path(), "2");
    let model_dir = dir.path().join("m");
    let s = |p: &std::path::Path| p.to_str().unwrap().to_owned();
    let (ok, _, err) = nerfsv(&["train", "--data", &s(&ds), "--out", &s(&model_dir), "--steps", "60"]);
    assert!(ok, "{err}");
    let model = model_dir.join("checkpoint.safetensors");
    let split = dir.path().join("split");
    let (ok, _, err) = nerfsv(&["render", "--model", &s(&model), "--data", &s(&ds), "--out", &s(&split)]);
    assert!(ok, "{err}");

    // The test view's camera as a camera path, twice (8×8 pixels: equal fields of view).
    let test: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ds.join("transforms_test.json")).unwrap()).unwrap();
    let angle = test["camera_angle_x"].as_f64().unwrap();
    let matrix: Vec<f64> = test["frames"][0]["transform_matrix"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|row| row.as_array().unwrap().clone())
        .map(|v| v.as_f64().unwrap())
        .collect();
    let camera = serde_json::json!({"camera_to_world": matrix, "fov": angle.to_degrees(), "aspect": 1.0});
    let camera_path = dir.path().join("camera_path.json");
    let json = serde_json::json!({"render_width": 8, "render_height": 8, "fps": 5, "camera_type": "perspective",
                                  "camera_path": [camera.clone(), camera]});
    std::fs::write(&camera_path, json.to_string()).unwrap();
    let along = dir.path().join("along");
    let (ok, _, err) = nerfsv(&["render", "--model", &s(&model), "--path", &s(&camera_path), "--out", &s(&along)]);
    assert!(ok, "{err}");
    let frame = png_rgba(&along.join("frame_0000.png"));
    let spread = |f: &[u8]| f.iter().max().unwrap() - f.iter().min().unwrap();
    assert!(spread(&frame) > 40, "a flat render tests no camera");
    assert_eq!(frame, png_rgba(&split.join("r_0.png")), "the path's camera is the test view's");
    assert_eq!(common::apng(&along.join("animation.png")).2, vec![frame.clone(), frame]);
    assert!(along.join("frame_0001_depth.png").is_file());

    // A trajectory of two rows (level, facing +x: the drone camera looks along body x with
    // image up along body z), rendered through a 6×4 drone camera, is the camera path of those
    // cameras; the estimate's rows (another place) are another path.
    let (angle_x, fov_y) = (0.9f64, 2.0 * (2.0 * (0.45f64).tan() / 3.0).atan());
    let c2w = |x: f64, y: f64, z: f64| vec![0.0, 0.0, -1.0, x, -1.0, 0.0, 0.0, y, 0.0, 1.0, 0.0, z, 0.0, 0.0, 0.0, 1.0];
    let as_path = |rows: &[[f64; 3]]| {
        let cams: Vec<_> = rows
            .iter()
            .map(|p| serde_json::json!({"camera_to_world": c2w(p[0], p[1], p[2]), "fov": fov_y.to_degrees()}))
            .collect();
        serde_json::json!({"render_width": 6, "render_height": 4, "camera_path": cams}).to_string()
    };
    let (truth_at, estimate_at) = ([[-1.2, 0.0, 0.3], [-1.1, 0.0, 0.35]], [[-1.2, 0.3, 0.3], [-1.1, 0.3, 0.4]]);
    let columns = ["x", "y", "z", "qw", "qx", "qy", "qz"];
    let header: Vec<String> =
        ["true", "est"].iter().flat_map(|p| columns.iter().map(move |c| format!("{p}_{c}"))).collect();
    let mut csv = format!("step,time_s,{},collided\n", header.join(","));
    for (i, (t, e)) in truth_at.iter().zip(&estimate_at).enumerate() {
        csv +=
            &format!("0,{},{},{},{},1,0,0,0,{},{},{},1,0,0,0,0\n", 0.5 * i as f64, t[0], t[1], t[2], e[0], e[1], e[2]);
    }
    let trajectory = dir.path().join("trajectory.csv");
    std::fs::write(&trajectory, csv).unwrap();
    let cfg = dir.path().join("camera.toml");
    std::fs::write(&cfg, format!("[dataset]\nwidth = 6\nheight = 4\ncamera_angle_x = {angle_x}\n")).unwrap();
    let frames_of = |extra: &[&str], out: &str| {
        let out = dir.path().join(out);
        let mut args = vec!["render", "--model", model.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend(extra);
        let (ok, _, err) = nerfsv(&args);
        assert!(ok, "{err}");
        (err, common::apng(&out.join("animation.png")).2)
    };
    let (t, e) = (s(&trajectory), s(&cfg));
    let (said, truth) = frames_of(&["--path", &t, "--config", &e], "truth");
    assert!(said.contains("2 frames") && said.contains("2.000 frames per second"), "{said}");
    assert_eq!(truth.len(), 2);
    assert!(spread(&truth[0]) > 40, "a flat render tests no camera");
    let (said, estimate) = frames_of(&["--path", &t, "--config", &e, "--estimate"], "estimate");
    assert!(said.contains("2 frames"), "{said}");
    for (rows, frames, name) in [(&truth_at, &truth, "truth"), (&estimate_at, &estimate, "estimate")] {
        let json = dir.path().join(format!("{name}.json"));
        std::fs::write(&json, as_path(rows)).unwrap();
        assert_eq!(&frames_of(&["--path", &s(&json)], &format!("{name}_path")).1, frames, "{name}");
    }
    assert_ne!(truth, estimate);

    std::fs::write(&camera_path, r#"{"render_width": 8, "render_height": 8, "camera_path": [{"fov": 50}]}"#).unwrap();
    let (ok, _, err) = nerfsv(&["render", "--model", &s(&model), "--path", &s(&camera_path), "--out", &s(&along)]);
    assert!(!ok);
    assert!(err.contains("camera_path.json: frame 0: camera_to_world"), "{err}");
    let (ok, _, err) =
        nerfsv(&["render", "--model", &s(&model), "--path", &s(&camera_path), "--data", &s(&ds), "--out", &s(&along)]);
    assert!(!ok && err.contains("--data") && err.contains("--path"), "{err}");
}
