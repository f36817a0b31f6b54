//! `nerfsv stress`: the summary and files a user gets, the same bytes at any thread count, a
//! killed run resumed to the uninterrupted result, and bad input refused before anything is
//! written.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{nerfsv_with, s};

/// A small study: 16-pixel vision, a wide prior so the drone does crash, `mc` MC rollouts and a
/// 2 × 6 CEM with 6 importance samples.
fn config(dir: &Path, name: &str, mc: usize, extra: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(
        &p,
        format!(
            "[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n[stress]\nseed = 5\n[stress.disturbance]\n\
             std = [0.08, 0.08, 0.04, 0.04, 0.04, 0.04, 0.08, 0.08, 0.08, 0.04, 0.04, 0.04]\n\
             [stress.monte_carlo]\nrollouts = {mc}\n[stress.cem]\nm = 6\nm_elite = 2\nk_max = 2\nis_samples = 6\n{extra}"
        ),
    )
    .unwrap();
    p
}

fn stress(model: &Path, field: &Path, out: &Path, extra: &[&str], threads: &str) -> (bool, String, String) {
    let base = ["stress", "--scene", "monolith", "--model", s(model), "--nerf-field", s(field), "--out", s(out)];
    nerfsv_with(&[&base[..], extra].concat(), &[("RAYON_NUM_THREADS", threads)])
}

/// The files of a stress folder that a seed determines (the journal and the figures without
/// timings included).
fn results(out: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files = Vec::new();
    let mut stack = vec![out.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(out).unwrap().display().to_string();
                let mut bytes = std::fs::read(&p).unwrap();
                if rel == "stress.json" {
                    let mut v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
                    let m = v.as_object_mut().unwrap();
                    m.remove("seconds");
                    m.remove("rollouts_per_second");
                    bytes = serde_json::to_vec(&v).unwrap();
                }
                files.push((rel, bytes));
            }
        }
    }
    files.sort();
    files
}

#[test]
fn cem_with_replay_prints_the_summary_and_writes_the_same_bytes_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let cfg = config(dir.path(), "study.toml", 4, "");
    let args = ["--sampler", "cem", "--replay", "--config", s(&cfg), "--json"];
    let one = dir.path().join("one");
    let (ok, stdout, err) = stress(&model, &field, &one, &args, "1");
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    for key in [
        "rollouts",
        "collision_rate",
        "lost_rate",
        "avg_collision_step",
        "avg_log_likelihood",
        "avg_uncertainty",
        "p_fail",
        "p_fail_se",
        "most_likely_failure",
    ] {
        assert!(v.get(key).is_some(), "{key} missing from {stdout}");
    }
    for key in ["accuracy", "precision", "recall"] {
        assert!(v["confusion"].get(key).is_some(), "confusion.{key} missing from {stdout}");
    }
    assert_eq!(v["rollouts"], 2 * 6 + 6);
    assert!(v["collision_rate"].as_f64().unwrap() > 0.0, "the wide prior should crash the drone: {stdout}");
    let t = &v["confusion"]["trajectories"];
    let pairs: u64 = ["true_positive", "false_positive", "false_negative", "true_negative"]
        .iter()
        .map(|k| t[k].as_u64().unwrap())
        .sum();
    assert_eq!(pairs, 12, "the two CEM populations are replayed, the importance batch is not");

    let rollouts = std::fs::read_to_string(one.join("rollouts.csv")).unwrap();
    assert!(rollouts.starts_with("sampler,population,index,seed,step,d0,"), "{rollouts}");
    assert_eq!(rollouts.lines().count(), 1 + 18 * 6);
    assert_eq!(std::fs::read_to_string(one.join("replay_gt.csv")).unwrap().lines().count(), 1 + 12 * 6);
    let table = std::fs::read_to_string(one.join("table.csv")).unwrap();
    assert!(table.starts_with("world,sampler,rollouts,collision_rate,lost_rate,avg_collision_step,avg_log_likelihood"));
    assert_eq!(table.lines().map(|l| l.split(',').nth(1).unwrap()).collect::<Vec<_>>(), ["sampler", "cem", "cem-is"]);
    // The most likely failure: its disturbances and its flight in both worlds.
    for f in ["most_likely_failure_cem.csv", "most_likely_failure_cem_nerf.png", "most_likely_failure_cem_gt.png"] {
        assert!(one.join(f).is_file(), "{f}");
    }
    // What the drone's camera saw along it: an animated PNG with a frame per substep of the
    // longer flight, the two worlds side by side.
    let rows = |f: &str| std::fs::read_to_string(one.join(f)).unwrap().lines().count() - 1;
    let frames = rows("most_likely_failure_cem_nerf.csv").max(rows("most_likely_failure_cem_gt.csv"));
    let (w, h, view) = common::apng(&one.join("most_likely_failure_cem_view.png"));
    assert_eq!(view.len(), frames);
    assert!(w > h, "two panels side by side, {w}×{h}");

    let two = dir.path().join("two");
    let (ok, _, err) = stress(&model, &field, &two, &args, "2");
    assert!(ok, "{err}");
    assert_eq!(results(&one), results(&two), "results differ between 1 and 2 threads");

    // The most likely failure replays with `nerfsv fly` from its disturbances and seed.
    let seed = v["most_likely_failure"]["seed"].as_u64().unwrap().to_string();
    let fly = dir.path().join("fly");
    let (ok, stdout, err) = nerfsv_with(
        &[
            "fly",
            "--scene",
            "monolith",
            "--model",
            s(&model),
            "--nerf-field",
            s(&field),
            "--disturbances",
            s(&one.join("most_likely_failure_cem.csv")),
            "--seed",
            &seed,
            "--config",
            s(&cfg),
            "--out",
            s(&fly),
            "--json",
        ],
        &[],
    );
    assert!(ok, "{err}");
    let flown: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(flown["collided"], true);
    assert_eq!(
        flown["collision_step"].as_u64().unwrap() + 1,
        v["most_likely_failure"]["collision_step"].as_u64().unwrap()
    );
    assert_eq!(
        std::fs::read(fly.join("trajectory.csv")).unwrap(),
        std::fs::read(one.join("most_likely_failure_cem_nerf.csv")).unwrap()
    );
}

#[test]
fn a_killed_stress_run_resumes_without_reflying_and_ends_with_the_uninterrupted_files() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let cfg = config(dir.path(), "study.toml", 60, "");
    let args = ["--sampler", "mc", "--replay", "--config", s(&cfg)];
    let whole = dir.path().join("whole");
    let (ok, _, err) = stress(&model, &field, &whole, &args, "2");
    assert!(ok, "{err}");

    // Kill -9 once some rollouts are in the journal.
    let killed = dir.path().join("killed");
    let base = ["stress", "--scene", "monolith", "--model", s(&model), "--nerf-field", s(&field), "--out", s(&killed)];
    let mut child = Command::new(env!("CARGO_BIN_EXE_nerfsv"))
        .args([&base[..], &args[..]].concat())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let journal = killed.join("journal/nerf");
    let start = Instant::now();
    // The journal's rollout files, not the image logs beside them.
    let flown = || {
        std::fs::read_dir(&journal)
            .map_or(0, |d| d.flatten().filter(|e| nerfsv_validation::Journal::is_entry(&e.path())).count())
    };
    while flown() < 5 {
        assert!(child.try_wait().unwrap().is_none(), "the run finished before it could be killed");
        assert!(start.elapsed() < Duration::from_secs(120), "no rollout finished");
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let before = flown();
    assert!(before < 60, "killed too late");
    assert!(!killed.join("rollouts.csv").exists());

    let (ok, _, err) = stress(&model, &field, &killed, &[&args[..], &["--resume"]].concat(), "1");
    assert!(ok, "{err}");
    assert!(err.contains(&format!("{before} of 60 rollouts were already flown")), "{err}");
    assert_eq!(results(&killed), results(&whole), "a resumed run must end with the uninterrupted run's files");

    // Resuming into results of another configuration is refused, naming the journal, and
    // changes nothing.
    let before = results(&killed);
    let (ok, _, err) = stress(&model, &field, &killed, &[&args[..], &["--resume", "--seed", "6"]].concat(), "2");
    assert!(!ok);
    assert!(err.contains("journal/nerf/key") && err.contains("another configuration"), "{err}");
    assert_eq!(results(&killed), before);
}

#[test]
fn subset_simulation_estimates_within_bounds_replays_nothing_and_writes_the_same_bytes_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    // Levels of 8 (2 chains of 4): at most 8 + 2 × 6 rollouts.
    let cfg = config(dir.path(), "study.toml", 4, "[stress.subset]\nsamples = 8\np0 = 0.25\nmax_levels = 3\n");
    let args = ["--sampler", "subset", "--replay", "--config", s(&cfg), "--json"];
    let one = dir.path().join("one");
    let (ok, stdout, err) = stress(&model, &field, &one, &args, "1");
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    let rollouts = v["rollouts"].as_u64().unwrap();
    assert!([8, 14, 20].contains(&rollouts), "{stdout}");
    let p = v["p_fail"].as_f64().unwrap();
    let (lo, hi) = (v["p_fail_interval"][0].as_f64().unwrap(), v["p_fail_interval"][1].as_f64().unwrap());
    assert!((0.0..=1.0).contains(&p) && lo <= p && p <= hi && hi <= 1.0, "{stdout}");
    assert!(v["p_fail_estimator"].as_str().unwrap().starts_with("subset simulation"), "{stdout}");
    // An estimator, not a search: nothing replayed, no confusion.
    assert!(v["confusion"].is_null(), "{stdout}");
    assert_eq!(std::fs::read_to_string(one.join("replay_gt.csv")).unwrap().lines().count(), 1);
    let csv = std::fs::read_to_string(one.join("rollouts.csv")).unwrap();
    assert_eq!(csv.lines().count() as u64, 1 + rollouts * 6);
    assert!(csv.lines().skip(1).all(|l| l.starts_with("subset,")), "{csv}");
    let table = std::fs::read_to_string(one.join("table.csv")).unwrap();
    assert_eq!(table.lines().map(|l| l.split(',').nth(1).unwrap()).collect::<Vec<_>>(), ["sampler", "subset"]);

    let two = dir.path().join("two");
    let (ok, _, err) = stress(&model, &field, &two, &args, "2");
    assert!(ok, "{err}");
    assert_eq!(results(&one), results(&two), "results differ between 1 and 2 threads");
}

#[test]
fn bad_studies_are_refused_by_name_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let out = dir.path().join("out");
    let edit = |name: &str, from: &str, to: &str| {
        let p = config(dir.path(), name, 4, "");
        std::fs::write(&p, std::fs::read_to_string(&p).unwrap().replace(from, to)).unwrap();
        p
    };
    let cases = [
        // A covariance that is not positive definite.
        (
            edit("a.toml", "std = [", "covariance = [[1.0, 2.0], [2.0, 1.0]]\nmean = [0.0, 0.0]\nstd = ["),
            "cem",
            vec!["a.toml", "stress.disturbance.covariance", "positive definite"],
        ),
        // A population smaller than its elite count.
        (edit("b.toml", "m_elite = 2", "m_elite = 7"), "cem", vec!["b.toml", "stress.cem.m_elite", "found 7"]),
        // Zero rollouts.
        (
            edit("c.toml", "rollouts = 4", "rollouts = 0"),
            "mc",
            vec!["c.toml", "stress.monte_carlo.rollouts", "found 0"],
        ),
        // Levels that p0 does not split into whole chains.
        (
            edit("d.toml", "[stress.cem]", "[stress.subset]\nsamples = 10\np0 = 0.3\n[stress.cem]"),
            "subset",
            vec!["d.toml", "stress.subset.samples", "found 10"],
        ),
    ];
    for (cfg, sampler, expected) in cases {
        let (ok, _, err) = stress(&model, &field, &out, &["--sampler", sampler, "--config", s(&cfg)], "2");
        assert!(!ok, "{} was accepted", cfg.display());
        for e in expected {
            assert!(err.contains(e), "{}: {e:?} not in {err}", cfg.display());
        }
        assert!(!out.exists(), "{} left output behind", cfg.display());
    }
    // --resume of a folder that holds no run.
    let (ok, _, err) = stress(&model, &field, &out, &["--resume"], "2");
    assert!(!ok && err.contains("--resume") && !out.exists(), "{err}");
}

/// The rows of a rollouts CSV as (sampler, population, index, step) → the named columns.
fn columns(path: &Path, names: &[&str]) -> Vec<(String, Vec<String>)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let at: Vec<usize> = names.iter().map(|n| header.iter().position(|h| h == n).unwrap()).collect();
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[..5].join(","), at.iter().map(|&i| f[i].to_owned()).collect())
        })
        .collect()
}

#[test]
fn a_reward_measures_every_flown_step_changes_only_what_cem_ranks_and_a_field_drives_it_too() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let cfg = config(dir.path(), "study.toml", 4, "[uq]\nonline_rays = 16\nonline_bla_rays = 8\n");
    // Four elites of six: besides the failures, the score picks the closest calls and the
    // reward the likeliest and most certain, so the next proposals differ. A rewarded search
    // always refits to its elites: the plain one here does too (the default moves along a line).
    let elites = "m_elite = 4\nupdate = \"elites\"";
    std::fs::write(&cfg, std::fs::read_to_string(&cfg).unwrap().replace("m_elite = 2", elites)).unwrap();
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let (ok, stdout, err) = stress(&model, &field, &out, &[&["--config", s(&cfg), "--json"], extra].concat(), "2");
        assert!(ok, "{name}: {err}");
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
        (out, v)
    };
    let (plain, _) = run("plain", &["--sampler", "cem"]);
    let (measured, _) = run("measured", &["--sampler", "cem", "--measure", "ga"]);
    let (rewarded, v) = run("rewarded", &["--sampler", "cem", "--reward", "ga"]);
    let cols = ["score", "clearance", "uncertainty", "reward"];
    let (p, m, r) = (
        columns(&plain.join("rollouts.csv"), &cols),
        columns(&measured.join("rollouts.csv"), &cols),
        columns(&rewarded.join("rollouts.csv"), &cols),
    );
    // Measuring changes no flight; steps not flown have no value (NaN), and so do views whose
    // rays all miss the tiny model; the others have one.
    assert_eq!(p.len(), m.len());
    let mut finite = 0;
    for ((kp, vp), (km, vm)) in p.iter().zip(&m) {
        assert_eq!((kp, &vp[..2]), (km, &vm[..2]), "measuring changed a flight");
        assert!(vp[2].is_empty(), "plain run measured: {vp:?}");
        let u: f64 = vm[2].parse().unwrap_or_else(|e| panic!("{km}: {vm:?}: {e}"));
        if vm[1] == "NaN" {
            assert!(u.is_nan(), "{km}: a step not flown has a value: {vm:?}");
        }
        finite += usize::from(u.is_finite());
    }
    assert!(finite > m.len() / 4, "{finite} of {} steps measured", m.len());
    // Population 0 is drawn from the prior in both: the same rollouts, now with a reward; CEM's
    // later populations follow the rewards' elites.
    let pop = |rows: &[(String, Vec<String>)], k: &str| -> Vec<Vec<String>> {
        rows.iter().filter(|(key, _)| key.starts_with(&format!("cem,{k},"))).map(|(_, v)| v[..3].to_vec()).collect()
    };
    assert_eq!(pop(&m, "0"), pop(&r, "0"));
    // The reward orders the failures only (non-failures rank by clearance, as without it): it
    // changes the next proposal exactly when population 0 has more failures than the 4 elites.
    let failures = r
        .iter()
        .filter(|(key, v)| key.starts_with("cem,0,") && v[0].parse::<f64>().is_ok_and(|s| s <= 0.0))
        .map(|(key, _)| key.split(',').nth(2).unwrap_or_default().to_owned())
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    if failures > 4 {
        assert_ne!(pop(&m, "1"), pop(&r, "1"), "the reward did not change CEM's next proposal");
    } else {
        assert_eq!(pop(&m, "1"), pop(&r, "1"), "with ≤ m_elite failures the reward changed the elites");
    }
    // CEM's populations carry their reward; the importance batch is not ranked.
    for (key, v) in &r {
        assert_eq!(v[3].parse::<f64>().is_ok_and(f64::is_finite), key.starts_with("cem,"), "{key}: {v:?}");
    }
    assert!(m.iter().all(|(_, v)| v[3].is_empty()), "--measure recorded a reward");
    assert!(v["avg_uncertainty"].as_f64().is_some_and(|u| u > 0.0), "{v}");
    let table = std::fs::read_to_string(rewarded.join("table.csv")).unwrap();
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let row: Vec<&str> = table.lines().nth(1).unwrap().split(',').collect();
    let col = |n: &str| row[header.iter().position(|h| *h == n).unwrap()];
    assert_eq!((col("uncertainty"), col("mode"), col("reward")), ("ga", "exact", "ga"), "{table}");
    assert!(col("avg_reward").parse::<f64>().is_ok(), "{table}");

    // Field mode: a GA field of the same model drives the same study; a field is needed, and
    // one of another method is refused by name.
    let uq_cfg = dir.path().join("uq.toml");
    std::fs::write(&uq_cfg, "[uq]\nfield_cells_per_metre = 5.0\nfield_rays_per_image = 16\n").unwrap();
    let ga_field = dir.path().join("field_ga.safetensors");
    let bla_field = dir.path().join("field_bla.safetensors");
    let ds = dir.path().join("ds");
    for (method, path) in [("ga", &ga_field), ("bla", &bla_field)] {
        let args = ["uq", "field", "--method", method, "--model", s(&model), "--data", s(&ds)];
        let (ok, _, err) = common::nerfsv(&[&args[..], &["--out", s(path), "--config", s(&uq_cfg)]].concat());
        assert!(ok, "{err}");
    }
    let (fielded, v) =
        run("field", &["--sampler", "mc", "--reward", "ga", "--uncertainty", "field", "--field", s(&ga_field)]);
    assert!(v["avg_uncertainty"].as_f64().is_some_and(f64::is_finite), "{v}");
    assert!(fielded.join("table.csv").is_file());
    let out = dir.path().join("refused");
    let (ok, _, err) = stress(&model, &field, &out, &["--reward", "ga", "--uncertainty", "field"], "2");
    assert!(!ok && err.contains("--field") && !out.exists(), "{err}");
    let args = ["--reward", "ga", "--uncertainty", "field", "--field", s(&bla_field)];
    let (ok, _, err) = stress(&model, &field, &out, &args, "2");
    assert!(!ok && err.contains("field_bla.safetensors") && err.contains("bla") && !out.exists(), "{err}");
    // A field of another model (the same data, another seed) is refused naming the file.
    let other = dir.path().join("other");
    let nerf_cfg = dir.path().join("nerf.toml");
    let train =
        ["train", "--data", s(&ds), "--out", s(&other), "--steps", "2", "--seed", "9", "--config", s(&nerf_cfg)];
    let (ok, _, err) = common::nerfsv(&train);
    assert!(ok, "{err}");
    let other_model = other.join("checkpoint.safetensors");
    let args = ["--reward", "ga", "--uncertainty", "field", "--field", s(&ga_field)];
    let (ok, _, err) = stress(&other_model, &field, &out, &args, "2");
    assert!(!ok && err.contains("field_ga.safetensors") && !out.exists(), "{err}");
}
