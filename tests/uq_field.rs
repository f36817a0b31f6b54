//! `nerfsv uq field`: the field file, its slice PNG and JSON figures from GA and BLA on a tiny
//! dataset and model, and a field of another model refused by name.

mod common;

use std::path::Path;

use common::{nerfsv, s};
use nerfsv_nerf::Nerf;
use nerfsv_uq::{model_id, FieldMethod, UncertaintyField, UqError};

/// A coarse grid (5 cells/m: 11³ nodes over the ±1 m box) and a low rank keep BLA quick.
fn config(dir: &Path) -> std::path::PathBuf {
    let path = dir.join("uq.toml");
    std::fs::write(&path, "[uq]\nfield_cells_per_metre = 5.0\nfield_rank = 32\nfield_rays_per_image = 16\n").unwrap();
    path
}

#[test]
fn uq_field_writes_the_field_its_slice_and_figures_and_a_field_of_another_model_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let ds = common::tiny_dataset(dir.path(), "2", "1");
    let model = common::tiny_model(dir.path(), &ds);
    let cfg = config(dir.path());
    for method in ["ga", "bla"] {
        let out = dir.path().join("fields").join(format!("field_{method}.safetensors"));
        let (ok, stdout, err) = nerfsv(&[
            "uq",
            "field",
            "--method",
            method,
            "--model",
            s(&model),
            "--data",
            s(&ds),
            "--out",
            s(&out),
            "--config",
            s(&cfg),
            "--json",
        ]);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"));
        for key in ["method", "voxels", "build_seconds", "checkpoint_id", "mean_variance", "max_variance", "images"] {
            assert!(!v[key].is_null(), "{key} missing in {v}");
        }
        assert_eq!(v["method"], method);
        assert_eq!(v["voxels"], 11 * 11 * 11);
        assert_eq!(v["images"], 2);
        if method == "bla" {
            assert_eq!(v["rank"], 32);
            let mass = v["eigenvalue_mass_kept"].as_f64().unwrap();
            assert!(mass > 0.0 && mass <= 1.0, "{v}");
        } else {
            assert!(v["rank"].is_null());
        }
        let field = UncertaintyField::load(&out).unwrap();
        let expected = if method == "ga" { FieldMethod::Ga } else { FieldMethod::Bla };
        assert_eq!(field.method, expected);
        assert_eq!(field.geometry.dims, [11, 11, 11]);
        assert_eq!(v["checkpoint_id"], field.checkpoint_id.as_str());
        let nerf = nerfsv_nerf::Nerf::load(&model).unwrap();
        field.check_checkpoint(&out, &model_id(&nerf)).unwrap();
        assert!(field.variance.iter().all(|x| x.is_finite() && *x >= 0.0));
        let png = dir.path().join("fields").join(format!("field_{method}_z0.30.png"));
        assert_eq!(v["png"], s(&png));
        assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
    }
    // No temporaries left: two fields and two slices.
    assert_eq!(std::fs::read_dir(dir.path().join("fields")).unwrap().count(), 4);

    // Another checkpoint (one weight changed, saved and loaded back): the field is refused,
    // naming the field file and both checkpoints.
    let mut nerf = nerfsv_nerf::Nerf::load(&model).unwrap();
    nerf.params[0] += 1e-3;
    let other = dir.path().join("other.safetensors");
    nerf.save(&other).unwrap();
    let nerf = nerfsv_nerf::Nerf::load(&other).unwrap();
    let field_path = dir.path().join("fields").join("field_ga.safetensors");
    let field = UncertaintyField::load(&field_path).unwrap();
    let err = field.check_checkpoint(&field_path, &model_id(&nerf)).unwrap_err();
    assert!(matches!(err, UqError::FieldCheckpoint { .. }));
    let msg = err.to_string();
    assert!(msg.contains("field_ga.safetensors") && msg.contains(&field.checkpoint_id), "{msg}");
    assert!(msg.contains(&model_id(&nerf)) && msg.contains("checkpoint.safetensors"), "{msg}");

    // The ensemble's field: the deployed model and the other checkpoint as its members; with a
    // member identical to the deployed model, no spread anywhere. `--member` needs the method.
    let field_of = |members: &[&Path], name: &str| {
        let out = dir.path().join("fields").join(name);
        let mut args = vec!["uq", "field", "--method", "ensemble", "--model", s(&model), "--data", s(&ds)];
        for m in members {
            args.extend(["--member", s(m)]);
        }
        args.extend(["--out", s(&out), "--config", s(&cfg), "--json"]);
        let (ok, stdout, err) = nerfsv(&args);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"));
        assert_eq!(v["method"], "ensemble");
        UncertaintyField::load(&out).unwrap()
    };
    let spread = field_of(&[&other], "ensemble.safetensors");
    assert_eq!(spread.method, FieldMethod::Ensemble);
    assert!(spread.variance.iter().all(|x| x.is_finite() && *x >= 0.0) && spread.variance.iter().any(|&x| x > 0.0));
    spread
        .check_checkpoint(&dir.path().join("fields/ensemble.safetensors"), &model_id(&Nerf::load(&model).unwrap()))
        .unwrap();
    let same = field_of(&[&model], "same.safetensors");
    assert!(same.variance.iter().all(|&x| x == 0.0));
    let (ok, _, err) = nerfsv(&[
        "uq",
        "field",
        "--method",
        "ga",
        "--model",
        s(&model),
        "--member",
        s(&other),
        "--data",
        s(&ds),
        "--out",
        s(&dir.path().join("y.safetensors")),
    ]);
    assert!(!ok && err.contains("--member"), "{err}");

    // Bad input: a dataset folder without a train split.
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let (ok, _, err) = nerfsv(&[
        "uq",
        "field",
        "--method",
        "ga",
        "--model",
        s(&model),
        "--data",
        s(&empty),
        "--out",
        s(&dir.path().join("x.safetensors")),
    ]);
    assert!(!ok && err.contains("transforms_train.json"), "{err}");
    assert!(!dir.path().join("x.safetensors").exists());
}
