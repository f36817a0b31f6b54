//! The paper's offline uncertainty: GA and BLA on the images of a dataset's splits, a CSV row
//! per image, per-split summaries and the paper's figures, the depth AUSE of either method's
//! per-pixel depth uncertainty, and the per-pixel picture of one view. `nerfsv uq offline`,
//! `nerfsv uq ause` and the `uq` stage of `nerfsv run` all call these functions; and the
//! uncertainty field of a dataset's training split saved beside its slice picture (`nerfsv uq
//! field`).

pub use crate::Method;

mod csv;
mod field;
mod figures;
mod files;
mod fit;
mod rows;
mod summary;

pub use self::csv::{columns, csv, csv_field, csv_name, exclusion_name, Cell, Column, ALL_RAYS_MISS};
pub use self::field::{build_field, field_slice_path, field_slice_png, save_field_with_slice, FIELD_SLICE_ALTITUDE};
pub use self::figures::{figure_stems, figures, maps_figure, Figure, FEW_FOR_A_HISTOGRAM, MAPS_PNG};
pub use self::files::{figure_files, method_files, write_files};
pub use self::fit::{
    ause_frame, ause_frames, fit_frame, fit_image, fit_with_depth_uncertainty, offline_split, AuseOutcome, AuseResult,
    ImageAuse, ImageAuseOutcome, SplitFits, SplitFitting, SplitImages,
};
pub use self::rows::{reference, stride, BlaRow, Fit, GaRow, Row, BACKGROUND, FIGURE, SPLITS};
pub use self::summary::{
    bla_rows, floored_kept, ga_rows, mean, short, split_figures, summarise, OfflineSummary, SplitSummary,
    UqSplitFigures,
};

/// Whether the dataset loader finds a split in a folder (the uq commands skip the splits it
/// does not).
pub use nerfsv_dataset::has_split;

#[cfg(test)]
mod tests {
    use super::*;
    use nerfsv_nerf::{Nerf, RayInput};
    use nerfsv_scene::stats::median;

    use crate::{GaExclusion, UqConfig};

    #[test]
    fn several_files_are_written_all_or_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let files = vec![("a.txt".to_owned(), b"a".to_vec()), ("b.txt".to_owned(), b"b".to_vec())];
        write_files(dir.path(), &files).unwrap();
        assert_eq!(std::fs::read(dir.path().join("b.txt")).unwrap(), b"b");
        // A name that cannot be written (a folder is in its way): the files before it go again.
        let out = dir.path().join("out");
        std::fs::create_dir_all(out.join("c.txt")).unwrap();
        let files = vec![("a.txt".to_owned(), b"a".to_vec()), ("c.txt".to_owned(), b"c".to_vec())];
        let e = write_files(&out, &files).unwrap_err().to_string();
        assert!(e.contains("c.txt"), "{e}");
        assert!(!out.join("a.txt").exists());
    }

    /// Rays from far outside the model's box, pointing away from it.
    fn missing_rays() -> (Vec<RayInput>, Vec<[f32; 3]>) {
        let ray = RayInput {
            origin: [10.0, 10.0, 10.0].into(),
            direction: [1.0, 0.0, 0.0].into(),
            background: BACKGROUND,
            jitter: 0.0,
        };
        (vec![ray; 6], vec![[0.5; 3]; 6])
    }

    #[test]
    fn an_image_whose_rays_all_miss_gets_an_empty_row_and_a_count_not_an_error() {
        let nerf = Nerf::new(nerfsv_nerf::NerfConfig::default(), 0).unwrap();
        let (rays, refs) = missing_rays();
        let cfg = UqConfig::default();
        for method in [Method::Ga, Method::Bla] {
            let fit = fit_image(&nerf, method, "r_3", &rays, &refs, &cfg).unwrap();
            assert!(fit.all_rays_miss());
            let rows = vec![Row { split: "test", index: 3, file_path: "./test/r_3".into(), fit }];
            let text = csv(&rows, method);
            let line = text.lines().nth(1).unwrap();
            assert!(line.starts_with("test,3,./test/r_3,") && line.contains("all_rays_miss"), "{line}");
            assert_eq!(line.split(',').count(), text.lines().next().unwrap().split(',').count(), "{line}");
            let s = summarise(rows.iter(), method, 3.0);
            assert_eq!((s.images, s.all_rays_miss), (1, 1));
            assert!(s.mean_sigma_d.is_none() && s.mean_trace.is_none());
        }
    }

    #[test]
    fn a_handful_of_values_is_drawn_as_points_and_many_as_a_histogram() {
        let cfg = UqConfig::default();
        let few: Vec<Row> = (0..3).map(|k| ga("test", 0.5 + k as f64, false)).collect();
        match &figures(&few, &["test"], Method::Ga, &cfg)[0].1 {
            Figure::Scatter(s) => {
                assert_eq!(s.groups[0].points, [[0.5, 1.0], [1.5, 2.0], [2.5, 3.0]]);
                assert_eq!(s.x_title, "σ_d");
            }
            Figure::Histogram(_) => panic!("3 values drawn as a histogram"),
        }
        let many: Vec<Row> = (0..FEW_FOR_A_HISTOGRAM).map(|k| ga("test", 0.1 * k as f64, false)).collect();
        assert!(matches!(&figures(&many, &["test"], Method::Ga, &cfg)[0].1, Figure::Histogram(_)));
    }

    #[test]
    fn every_row_has_a_value_for_each_column_and_the_header_names_them() {
        let ga = ga("test", 0.5, false);
        let bla = Fit::Bla(Some(BlaRow {
            normalized_trace: 1.0,
            rmv: 2.0,
            information_gain: 3.0,
            map_loss: 4.0,
            initial_loss: 5.0,
            perturbation: 1,
            prior_precision: 6.0,
            log_evidence: 7.0,
            rays: 256,
        }));
        for (method, fits) in [(Method::Ga, [ga.fit.clone(), Fit::Ga(None)]), (Method::Bla, [bla, Fit::Bla(None)])] {
            for fit in &fits {
                let cells = fit.cells();
                assert_eq!(cells.len(), columns(method).len(), "{method}");
                for (cell, column) in cells.iter().zip(columns(method)) {
                    assert_eq!(matches!(cell, Cell::Text(_)), column.text, "{method} {}", column.name);
                }
            }
            let rows: Vec<Row> = fits.into_iter().map(|fit| Row { fit, ..ga.clone() }).collect();
            let text = csv(&rows, method);
            let widths: Vec<usize> = text.lines().map(|l| l.split(',').count()).collect();
            assert_eq!(widths, [3 + columns(method).len(); 3], "{text}");
        }
        let text = csv(&[Row { fit: Fit::Ga(None), ..ga }], Method::Ga);
        assert_eq!(text.lines().nth(1), Some("test,0,r_0,,,all_rays_miss,,,,,"), "{text}");
    }

    #[test]
    fn csv_fields_with_commas_or_quotes_are_quoted() {
        assert_eq!(csv_field("./train/r_0"), "./train/r_0");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"x\""), "\"say \"\"x\"\"\"");
    }

    #[test]
    fn stride_takes_an_even_spread_of_at_most_n() {
        let v: Vec<usize> = (0..10).collect();
        assert_eq!(stride(&v, Some(5)), [0, 2, 4, 6, 8]);
        assert_eq!(stride(&v, Some(2)), [0, 5]);
        assert_eq!(stride(&v, Some(20)), v);
        assert_eq!(stride(&v, None), v);
        assert_eq!(stride(&v, Some(0)), Vec::<usize>::new());
    }

    fn ga(split: &'static str, sigma_d: f64, excluded: bool) -> Row {
        let excluded = excluded.then_some(GaExclusion::AbsolutelyUncertain);
        let g = GaRow {
            mu_d: 1.0,
            sigma_d,
            excluded,
            objective: 0.0,
            rays: 4,
            rays_without_samples: 0,
            floored_mu_d: 1.0,
            floored_sigma_d: 0.1 * sigma_d,
        };
        Row { split, index: 0, file_path: "r_0".into(), fit: Fit::Ga(Some(g)) }
    }

    #[test]
    fn split_figures_leave_exclusions_out_of_the_mean_but_not_the_median() {
        let rows = [ga("test", 1.0, false), ga("test", 2.0, false), ga("test", 4.0, true), ga("val", 9.0, true)];
        let f = split_figures(&rows, "test", 3.0);
        assert_eq!((f.ga_images, f.ga_excluded, f.ga_all_rays_miss, f.bla_images), (3, 1, 0, 0));
        assert_eq!(f.ga_mean_sigma_d, Some(1.5));
        assert_eq!(f.ga_median_sigma_d, Some(2.0));
        // The noise-floored σ_d (0.1, 0.2, 0.4): none at the bound, all kept.
        assert_eq!(f.ga_floored_excluded, 0);
        assert!((f.ga_floored_mean_sigma_d.unwrap() - 0.7 / 3.0).abs() < 1e-12);
        assert_eq!(f.ga_floored_median_sigma_d, Some(0.2));
        assert_eq!(f.bla_mean_rmv, None);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), Some(2.5));
    }
}
