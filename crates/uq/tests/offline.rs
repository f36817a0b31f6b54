//! `offline_split`, the offline study's one loop over a split's images: with the depth AUSE,
//! each image's score is `ause_frame`'s and its row the fit made on the way (an image without
//! ground-truth depth fitted all the same); without it, each row is `fit_frame`'s.

mod common;

use std::cell::RefCell;

use nerfsv_dataset::{GenerateOptions, LoadOptions, Split};
use nerfsv_uq::offline::{ause_frame, fit_frame, offline_split, AuseOutcome, Method, SplitFitting, SplitImages};
use nerfsv_uq::{UqConfig, UqError};

/// The test split (two 8×8 views with ground-truth depth) of a monolith dataset under `dir`.
fn test_split(dir: &std::path::Path) -> Split {
    let scene = nerfsv_scene::Scene::builtin("monolith").unwrap();
    let opts = GenerateOptions { width: 8, height: 8, train: 1, val: 1, test: 2, supersample: 1, ..Default::default() };
    let ds = dir.join("ds");
    nerfsv_dataset::generate(&scene, &ds, &opts, &|_, _| {}).unwrap();
    nerfsv_dataset::load_split(&ds, "test", LoadOptions::default()).unwrap()
}

fn small_uq() -> UqConfig {
    UqConfig { max_rays: 16, perturbations: 1, lm_iterations: 2, ..UqConfig::default() }
}

#[test]
fn with_the_depth_ause_each_image_is_scored_as_ause_frame_scores_it_and_fitted_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut split = test_split(dir.path());
    // The second view without ground-truth depth: fitted for its row, its AUSE skipped.
    split.frames[1].depth = None;
    let (nerf, cfg) = (common::tiny_nerf(), small_uq());
    for method in [Method::Ga, Method::Bla] {
        let (seen, notes) = (RefCell::new(Vec::new()), RefCell::new(Vec::new()));
        let fits = offline_split(
            &nerf,
            method,
            SplitImages { split: &split, name: "test", indices: &[0, 1] },
            SplitFitting { ga_rays: Some(4), depth_ause: true },
            &cfg,
            &|d, t| seen.borrow_mut().push((d, t)),
            &|m| notes.borrow_mut().push(m.to_owned()),
        )
        .unwrap();
        assert_eq!(*seen.borrow(), [(0, 2), (1, 2), (2, 2)]);
        let indices: Vec<(usize, &str)> = fits.ause.iter().map(|(i, f, _)| (*i, f.as_str())).collect();
        assert_eq!(indices, [(0, split.frames[0].file_path.as_str()), (1, split.frames[1].file_path.as_str())]);
        assert_eq!(fits.rows.iter().map(|r| (r.split, r.index)).collect::<Vec<_>>(), [("test", 0), ("test", 1)]);

        // The first view: ause_frame's score and fit (every pixel: the AUSE ignores `ga_rays`).
        let (fit, outcome) = ause_frame(&nerf, method, &split.frames[0], &cfg).unwrap();
        assert_eq!(Some(&fits.rows[0].fit), fit.as_ref());
        match (&fits.ause[0].2, &outcome) {
            (AuseOutcome::Scored(a), AuseOutcome::Scored(b)) => assert_eq!(a, b),
            (AuseOutcome::Skipped(a), AuseOutcome::Skipped(b)) => assert_eq!(a.to_string(), b.to_string()),
            (a, b) => panic!("{a:?} against ause_frame's {b:?}"),
        }
        // The second: skipped for its depth, with a note, and fitted on every pixel all the same.
        assert!(
            matches!(fits.ause[1].2, AuseOutcome::Skipped(UqError::NoGroundTruthDepth { .. })),
            "{:?}",
            fits.ause[1]
        );
        let frame = &split.frames[1];
        assert_eq!(fits.rows[1].fit, fit_frame(&nerf, method, &frame.file_path, frame, None, &cfg).unwrap());
        let name = method.name().to_uppercase();
        assert!(notes.borrow().iter().any(|n| n.starts_with(&format!("{name} depth AUSE skipped"))), "{notes:?}");
    }
}

#[test]
fn without_the_depth_ause_each_row_is_fit_frames_on_its_rays() {
    let dir = tempfile::tempdir().unwrap();
    let split = test_split(dir.path());
    let (nerf, cfg) = (common::tiny_nerf(), small_uq());
    let fits = offline_split(
        &nerf,
        Method::Ga,
        SplitImages { split: &split, name: "test", indices: &[1] },
        SplitFitting { ga_rays: Some(4), depth_ause: false },
        &cfg,
        &|_, _| {},
        &|_| {},
    )
    .unwrap();
    assert!(fits.ause.is_empty());
    let frame = &split.frames[1];
    let name = format!("{}: frame 1 ({})", split.path.display(), frame.file_path);
    assert_eq!(fits.rows[0].fit, fit_frame(&nerf, Method::Ga, &name, frame, Some(4), &cfg).unwrap());
    match &fits.rows[0].fit {
        nerfsv_uq::offline::Fit::Ga(Some(row)) => assert_eq!(row.rays, 4),
        other => panic!("a GA fit of 4 rays, not {other:?}"),
    }
    // An index the split does not have is an error naming it, not a panic.
    let error = offline_split(
        &nerf,
        Method::Ga,
        SplitImages { split: &split, name: "test", indices: &[5] },
        SplitFitting::default(),
        &cfg,
        &|_, _| {},
        &|_| {},
    )
    .unwrap_err();
    assert!(error.to_string().contains("no frame 5"), "{error}");
}
