//! `nerfsv uq offline`: the CSV, figures and per-split summary a user gets from GA and BLA on a
//! tiny dataset and model, skipped splits, and bad input refused before anything is written.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use common::{nerfsv, s};

/// A tiny 8×8 monolith dataset (2 train, 1 val, 1 test views) and a 2-step model of it, built
/// once per test run under the target's temporary folder: (dataset, checkpoint).
fn setup() -> &'static (PathBuf, PathBuf) {
    static SETUP: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("uq_cli_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let ds = common::tiny_dataset(&dir, "2", "1");
        let model = common::tiny_model(&dir, &ds);
        (ds, model)
    })
}

fn offline(method: &str, data: &Path, out: &Path, extra: &[&str]) -> (bool, String, String) {
    let (_, model) = setup();
    let base = ["uq", "offline", "--method", method, "--model", s(model), "--data", s(data), "--out", s(out)];
    nerfsv(&[&base[..], extra].concat())
}

/// Decodes a PNG: (width, height).
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().expect("a PNG header");
    let mut buf = vec![0; reader.output_buffer_size().expect("a sane size")];
    let info = reader.next_frame(&mut buf).expect("one frame");
    (info.width, info.height)
}

/// The figures are PNGs of a readable size and SVG documents.
fn assert_figures(out: &Path, stems: &[&str]) {
    for stem in stems {
        let (w, h) = png_size(&out.join(format!("{stem}.png")));
        assert!((800..=4000).contains(&w) && (400..=4000).contains(&h), "{stem}.png is {w}×{h}");
        let svg = std::fs::read_to_string(out.join(format!("{stem}.svg"))).unwrap();
        assert!(svg.contains("<svg"), "{stem}.svg");
    }
}

/// The CSV's header and rows (fields split at commas: these file paths have none).
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().map(|l| l.split(',').map(str::to_string).collect::<Vec<_>>());
    let header = lines.next().expect("a header");
    (header, lines.collect())
}

fn number(v: &serde_json::Value, split: &str, key: &str) -> f64 {
    v[split][key].as_f64().unwrap_or_else(|| panic!("{split}.{key} missing or not a number in {v}"))
}

#[test]
fn ga_offline_writes_a_csv_row_per_image_the_figures_and_finite_split_summaries() {
    let (ds, _) = setup();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ga");
    let (ok, stdout, err) = offline("ga", ds, &out, &["--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    for (split, images) in [("train", 2.0), ("val", 1.0), ("test", 1.0)] {
        assert_eq!(number(&v, split, "images"), images, "{split}");
        let excluded = number(&v, split, "excluded");
        assert!(excluded >= 0.0);
        if excluded < images {
            for key in ["mean_sigma_d", "mean_mu_d"] {
                let x = number(&v, split, key);
                assert!(x.is_finite(), "{split}.{key} = {x}");
            }
            assert!(number(&v, split, "mean_sigma_d") > 0.0);
        }
    }
    assert!(number(&v, "train", "images") > 0.0 && v["seconds"].as_f64().is_some_and(|t| t.is_finite() && t >= 0.0));
    assert_eq!(v["skipped_splits"], serde_json::json!([]));

    let (header, rows) = read_csv(&out.join("uq_ga.csv"));
    assert_eq!(
        header,
        [
            "split",
            "index",
            "file_path",
            "mu_d",
            "sigma_d",
            "excluded",
            "objective",
            "rays",
            "rays_without_samples",
            "floored_mu_d",
            "floored_sigma_d"
        ]
    );
    let splits: Vec<(&str, &str)> = rows.iter().map(|r| (r[0].as_str(), r[1].as_str())).collect();
    assert_eq!(splits, [("train", "0"), ("train", "1"), ("val", "0"), ("test", "0")]);
    for r in &rows {
        assert_eq!(r.len(), header.len(), "{r:?}");
        assert!(r[2].contains("r_"), "file_path {r:?}");
        let sigma: f64 = r[4].parse().unwrap();
        assert!(sigma.is_finite() && sigma >= 0.0, "{r:?}");
        let floored: f64 = r[10].parse().unwrap();
        assert!(floored.is_finite() && floored >= 0.0, "{r:?}");
        assert_eq!(r[7], "64", "all 8×8 pixels are rays: {r:?}");
        let excluded = r[5].as_str();
        assert!(["", "absolutely_certain", "absolutely_uncertain"].contains(&excluded), "{r:?}");
        assert_eq!(excluded == "absolutely_uncertain", sigma >= 3.0, "{r:?}");
    }
    assert_figures(&out, &["uq_ga_sigma_d", "uq_ga_mu_sigma"]);
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("uq_ga.json")).unwrap()).unwrap();
    assert_eq!(summary["train"], v["train"]);
    // Nothing but the outputs (no temporary files left behind).
    let mut names: Vec<String> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(
        names,
        [
            "nerfsv-folder.json",
            "uq_ga.csv",
            "uq_ga.json",
            "uq_ga_mu_sigma.png",
            "uq_ga_mu_sigma.svg",
            "uq_ga_sigma_d.png",
            "uq_ga_sigma_d.svg"
        ]
    );
}

#[test]
fn ga_with_rays_fits_that_many_pixels_per_image() {
    let (ds, _) = setup();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ga");
    let (ok, _, err) = offline("ga", ds, &out, &["--rays", "10", "--max-images", "1"]);
    assert!(ok, "{err}");
    let (_, rows) = read_csv(&out.join("uq_ga.csv"));
    assert_eq!(rows.len(), 3, "one image per split: {rows:?}");
    assert!(rows.iter().all(|r| r[7] == "10"), "{rows:?}");
}

#[test]
fn bla_offline_on_one_image_per_split_reports_trace_and_rmv() {
    let (ds, _) = setup();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("uq.toml");
    std::fs::write(&cfg, "[uq]\nperturbations = 2\nlm_iterations = 2\nprior_precision = 2.0\n").unwrap();
    let out = dir.path().join("bla");
    let (ok, stdout, err) =
        offline("bla", ds, &out, &["--max-images", "1", "--rays", "16", "--config", s(&cfg), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    for split in ["train", "val", "test"] {
        assert_eq!(number(&v, split, "images"), 1.0);
        let (trace, rmv) = (number(&v, split, "mean_trace"), number(&v, split, "mean_rmv"));
        // The posterior variance of a weight is positive and at most the prior's, 1/α = 0.5.
        assert!(trace > 0.0 && trace <= 0.5 + 1e-9, "{split}: trace {trace}");
        assert!((rmv - trace.sqrt()).abs() <= 1e-9 * rmv, "{split}: rmv {rmv}, trace {trace}");
    }
    let (header, rows) = read_csv(&out.join("uq_bla.csv"));
    assert_eq!(header[..5], ["split", "index", "file_path", "normalized_trace", "rmv"]);
    assert_eq!(rows.len(), 3);
    let col = |name: &str| header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name}"));
    for r in &rows {
        assert_eq!(r[col("prior_precision")], "2");
        let (map, initial): (f64, f64) = (r[col("map_loss")].parse().unwrap(), r[col("initial_loss")].parse().unwrap());
        assert!(map <= initial, "LM never raises the loss: {r:?}");
        let p: usize = r[col("perturbation")].parse().unwrap();
        assert!(p < 2, "{r:?}");
        let rays: usize = r[col("rays")].parse().unwrap();
        assert!((1..=16).contains(&rays), "{r:?}");
        let gain: f64 = r[col("information_gain")].parse().unwrap();
        assert!(gain.is_finite() && gain > 0.0, "rays that hit the model teach something: {r:?}");
    }
    assert_figures(&out, &["uq_bla_trace", "uq_bla_rmv", "uq_bla_trace_rmv"]);
}

/// A copy of the dataset `ds` in `to` with only `splits` (transforms files and images).
fn copy_splits(ds: &Path, to: &Path, splits: &[&str]) -> PathBuf {
    for split in splits {
        let name = format!("transforms_{split}.json");
        std::fs::create_dir_all(to.join(split)).unwrap();
        std::fs::copy(ds.join(&name), to.join(&name)).unwrap();
        for e in std::fs::read_dir(ds.join(split)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), to.join(split).join(e.file_name())).unwrap();
        }
    }
    to.to_path_buf()
}

#[test]
fn a_malformed_last_split_is_refused_naming_its_file_after_the_others_ran_and_nothing_is_written() {
    let (ds, _) = setup();
    let dir = tempfile::tempdir().unwrap();
    let copy = copy_splits(ds, &dir.path().join("ds"), &["train", "val", "test"]);
    std::fs::write(copy.join("transforms_test.json"), "{\"camera_angle_x\": 0.7, \"frames\": 3}").unwrap();
    let out = dir.path().join("out");
    let (ok, _, err) = offline("ga", &copy, &out, &[]);
    assert!(!ok, "accepted a malformed test split");
    assert!(err.contains("transforms_test.json") && err.contains("frames"), "{err}");
    assert!(!out.exists(), "{} was created", out.display());
}

#[test]
fn a_split_without_its_transforms_file_is_skipped_and_reported() {
    let (ds, _) = setup();
    let dir = tempfile::tempdir().unwrap();
    let copy = copy_splits(ds, &dir.path().join("ds"), &["train", "test"]);
    let out = dir.path().join("ga");
    let (ok, stdout, err) = offline("ga", &copy, &out, &["--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(v["skipped_splits"], serde_json::json!(["val"]));
    assert!(v.get("val").is_none() && v.get("train").is_some() && v.get("test").is_some(), "{v}");
    let (_, rows) = read_csv(&out.join("uq_ga.csv"));
    assert!(rows.iter().all(|r| r[0] != "val") && rows.len() == 3, "{rows:?}");
    // Without --json the skip is said on stderr.
    let (ok, _, err) = offline("ga", &copy, &dir.path().join("ga2"), &[]);
    assert!(ok && err.contains("transforms_val.json") && err.contains("skipped"), "{err}");
}

#[test]
fn non_positive_prior_precision_is_refused_naming_the_key_and_nothing_is_written() {
    let (ds, _) = setup();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("uq.toml");
    // The run config's [uq] table; a file of bare uq keys is refused with the fix; an override
    // names itself.
    let cases = [
        ("[uq]\nprior_precision = -1.0\n", vec![], vec!["uq.prior_precision", "uq.toml"]),
        ("[uq]\nnoise_std = 0.0\n", vec![], vec!["uq.noise_std", "uq.toml"]),
        ("noise_std = 0.1\n", vec![], vec!["uq.toml", "`noise_std` is a key of the [uq] table", "[uq] header"]),
        ("[uq]\nnoise_std = 0.1\n", vec!["--set", "uq.prior_precision=-1"], vec!["--set uq.prior_precision=-1"]),
    ];
    for (text, extra, says) in cases {
        std::fs::write(&cfg, text).unwrap();
        let out = dir.path().join("out");
        for method in ["ga", "bla"] {
            let args = [&["--config", s(&cfg), "--json"][..], &extra[..]].concat();
            let (ok, stdout, err) = offline(method, ds, &out, &args);
            assert!(!ok, "{method} {text}: accepted");
            assert!(says.iter().all(|w| err.contains(w)), "{method}, {text}: {err}");
            assert!(stdout.is_empty(), "{stdout}");
            assert!(!out.exists(), "{method}: {} was created", out.display());
        }
    }
}

#[test]
fn missing_data_folder_or_model_is_refused_and_nothing_is_written() {
    let (ds, model) = setup();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let missing = dir.path().join("no_such_dataset");
    let (ok, _, err) = offline("ga", &missing, &out, &[]);
    assert!(!ok && err.contains("no_such_dataset"), "{err}");
    assert!(!out.exists());

    // A folder without any transforms file is named as not a dataset.
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let (ok, _, err) = offline("ga", &empty, &out, &[]);
    assert!(!ok && err.contains("empty") && err.contains("transforms_train.json"), "{err}");
    assert!(!out.exists());

    let no_model = dir.path().join("no_model.safetensors");
    let (ok, _, err) =
        nerfsv(&["uq", "offline", "--method", "ga", "--model", s(&no_model), "--data", s(ds), "--out", s(&out)]);
    assert!(!ok && err.contains("no_model.safetensors"), "{err}");
    assert!(!out.exists());
    assert!(model.exists());
}

/// A 24×24 monolith dataset (2 train, 1 val, 2 test views, ground-truth depth) and a 2-step
/// model of it: enough pixels per image for the 100-step sparsification curve.
fn ause_setup() -> &'static (PathBuf, PathBuf) {
    static SETUP: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("uq_ause_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let ds = common::monolith_dataset(&dir, "24", "2", "2");
        let model = common::tiny_model(&dir, &ds);
        (ds, model)
    })
}

fn ause(method: &str, data: &Path) -> (bool, String, String) {
    let (_, model) = ause_setup();
    nerfsv(&["uq", "ause", "--method", method, "--model", s(model), "--data", s(data), "--json"])
}

/// Both methods score every test image that has ground-truth depth: an AUSE in [0, 1] per image
/// over at least the curve's 100 pixels, and their mean.
#[test]
fn ause_scores_every_test_image_with_ground_truth_depth() {
    let (ds, _) = ause_setup();
    for method in ["ga", "bla"] {
        let (ok, out, err) = ause(method, ds);
        assert!(ok, "{method}: {err}");
        let v: serde_json::Value = serde_json::from_str(&out).expect("one JSON object");
        assert_eq!(v["method"], method);
        assert_eq!(v["split"], "test");
        assert_eq!(v["images"], 2, "{method}: {v}");
        assert_eq!(v["skipped"].as_array().map(Vec::len), Some(0));
        let per_image = v["per_image"].as_array().expect("per_image");
        assert_eq!(per_image.len(), 2);
        for im in per_image {
            let a = im["ause"].as_f64().expect("ause");
            assert!((0.0..=1.0).contains(&a), "{method}: {im}");
            assert!(im["pixels"].as_u64().expect("pixels") >= 100, "{method}: {im}");
        }
        let mean = v["mean_ause"].as_f64().expect("mean_ause");
        let expected = per_image.iter().map(|im| im["ause"].as_f64().unwrap()).sum::<f64>() / 2.0;
        assert!((mean - expected).abs() < 1e-12, "{method}: mean {mean} vs {expected}");
    }
}

/// A split whose frames carry no ground-truth depth is not scored on zeros: every image is
/// skipped with a message naming it, and there is no mean.
#[test]
fn ause_skips_images_without_ground_truth_depth_naming_them() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("uq_ause_nodepth_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let copy = common::monolith_dataset(&dir, "24", "1", "2");
    let transforms = copy.join("transforms_test.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&transforms).unwrap()).unwrap();
    for f in t["frames"].as_array_mut().unwrap() {
        f.as_object_mut().unwrap().remove("depth_file_path");
    }
    std::fs::write(&transforms, serde_json::to_string(&t).unwrap()).unwrap();
    let (ok, out, err) = ause("ga", &copy);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["images"], 0);
    assert!(v["mean_ause"].is_null(), "{v}");
    let skipped = v["skipped"].as_array().unwrap();
    assert_eq!(skipped.len(), 2);
    assert!(skipped.iter().all(|m| m.as_str().unwrap().contains("r_")), "{skipped:?}");
}

/// A dataset whose test cameras all look past the model's box (each moved 100 m along x) is
/// refused by `uq ause` as by `uq offline`, naming the transforms file, before any fit.
#[test]
fn ause_and_offline_refuse_a_model_whose_box_the_cameras_miss() {
    let (ds, model) = ause_setup();
    let dir = tempfile::tempdir().unwrap();
    let copy = copy_splits(ds, &dir.path().join("ds"), &["train", "val", "test"]);
    let transforms = copy.join("transforms_test.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&transforms).unwrap()).unwrap();
    for f in t["frames"].as_array_mut().unwrap() {
        let x = f["transform_matrix"][0][3].as_f64().unwrap();
        f["transform_matrix"][0][3] = serde_json::json!(x + 100.0);
    }
    std::fs::write(&transforms, serde_json::to_string(&t).unwrap()).unwrap();
    for method in ["ga", "bla"] {
        let (ok, stdout, err) = ause(method, &copy);
        assert!(!ok, "{method}: accepted cameras that miss the model: {stdout}");
        assert!(err.contains("transforms_test.json") && err.contains("scene box"), "{method}: {err}");
    }
    let out = dir.path().join("out");
    let base = ["uq", "offline", "--method", "ga", "--model", s(model), "--data", s(&copy), "--out", s(&out)];
    let (ok, _, err) = nerfsv(&base);
    assert!(!ok && err.contains("transforms_test.json") && err.contains("scene box"), "{err}");
    assert!(!out.exists());
}
