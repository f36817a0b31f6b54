//! The offline uncertainty stage of `nerfsv run` (`RUN/uq/`): the paper's GA and BLA on the
//! images of the dataset's splits and the depth AUSE of both, through the study library's
//! offline library ([`nerfsv_uq::offline`]), which `nerfsv uq offline` and `nerfsv uq ause`
//! call too.

use std::fmt::Write as _;
use std::time::Instant;

use nerfsv_nerf::Nerf;
use nerfsv_uq::offline::*;
use nerfsv_uq::{mean_ause, Sparsification, UqConfig};
use serde::{Deserialize, Serialize};

use crate::config::UqOfflineConfig;
use crate::stage::{Stage, StageContext};
use crate::stages::{load_dataset_split, Dataset, Train};
use crate::PipelineError;

// ---------------------------------------------------------------------------------------------
// The stage.

/// The offline uncertainty stage of `nerfsv run`: GA on the images of every split (at most
/// `ga_images_per_split` each, an even stride), BLA on `bla_images_per_split` of each, and the
/// depth AUSE of both on their test images. `RUN/uq/` holds `ga.csv` and `bla.csv` (the columns
/// of `nerfsv uq offline`), `ause.csv` (a row per test image and method) and the figures of
/// `nerfsv uq offline` (PNG and SVG).
pub struct Uncertainty<'a> {
    pub uq: &'a UqConfig,
    pub offline: &'a UqOfflineConfig,
}

/// One split's figures of the uncertainty stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UqSplitFigures {
    /// Images GA was run on, and those of them excluded (σ_d ≤ 0 or ≥ `uq.ga_sigma_max`) or
    /// whose rays all miss the model.
    pub ga_images: usize,
    pub ga_excluded: usize,
    pub ga_all_rays_miss: usize,
    /// Mean σ_d and μ_d over the images kept (the paper's statistics).
    pub ga_mean_sigma_d: Option<f64>,
    pub ga_mean_mu_d: Option<f64>,
    /// Median σ_d over every fitted image, excluded ones included (where the split sits
    /// against the exclusion bound).
    pub ga_median_sigma_d: Option<f64>,
    /// The same with the pixel noise in the model (`uq.noise_std`): images whose noise-floored
    /// σ_d is ≥ the bound, the mean over the others, the median over all.
    pub ga_floored_excluded: usize,
    pub ga_floored_mean_sigma_d: Option<f64>,
    pub ga_floored_median_sigma_d: Option<f64>,
    /// Images BLA was run on, and their mean normalised trace and rmv.
    pub bla_images: usize,
    pub bla_mean_normalized_trace: Option<f64>,
    pub bla_mean_rmv: Option<f64>,
    /// Mean information gain (nats): what an image teaches in its own directions, where the
    /// trace is mostly the prior's 1/α in the directions it does not see.
    pub bla_mean_information_gain: Option<f64>,
}

/// What the uncertainty stage reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UqFigures {
    pub train: UqSplitFigures,
    pub val: UqSplitFigures,
    pub test: UqSplitFigures,
    /// Mean depth AUSE of GA over its test images, and how many were scored.
    pub ause_ga: Option<f64>,
    pub ause_ga_images: usize,
    /// Mean depth AUSE of BLA over its test images, and how many were scored.
    pub ause_bla: Option<f64>,
    pub ause_bla_images: usize,
    pub seconds: f64,
}

impl Uncertainty<'_> {
    pub const GA_CSV: &'static str = "ga.csv";
    pub const BLA_CSV: &'static str = "bla.csv";
    pub const AUSE_CSV: &'static str = "ause.csv";
}

fn split_figures(rows: &[Row], split: &str, sigma_max: f64) -> UqSplitFigures {
    let of = |r: &&Row| r.split == split;
    let ga = summarise(rows.iter().filter(of).filter(|r| matches!(r.fit, Fit::Ga(_))), Method::Ga, sigma_max);
    let bla = summarise(rows.iter().filter(of).filter(|r| matches!(r.fit, Fit::Bla(_))), Method::Bla, sigma_max);
    UqSplitFigures {
        ga_images: ga.images,
        ga_excluded: ga.excluded.unwrap_or(0),
        ga_all_rays_miss: ga.all_rays_miss,
        ga_mean_sigma_d: ga.mean_sigma_d,
        ga_mean_mu_d: ga.mean_mu_d,
        ga_median_sigma_d: median(ga_rows(rows.iter().filter(of)).map(|g| g.sigma_d).collect()),
        ga_floored_excluded: ga.floored_excluded.unwrap_or(0),
        ga_floored_mean_sigma_d: ga.mean_floored_sigma_d,
        ga_floored_median_sigma_d: median(ga_rows(rows.iter().filter(of)).map(|g| g.floored_sigma_d).collect()),
        bla_images: bla.images,
        bla_mean_normalized_trace: bla.mean_trace,
        bla_mean_rmv: bla.mean_rmv,
        bla_mean_information_gain: bla.mean_information_gain,
    }
}

/// `ause.csv`: a row per (method, test image): its AUSE and pixels, or why it was skipped.
fn ause_csv(rows: &[(Method, usize, String, AuseOutcome)]) -> String {
    let mut out = String::from("method,split,index,file_path,ause,pixels,unscored_pixels,skipped\n");
    for (method, index, file_path, outcome) in rows {
        let _ = write!(out, "{},test,{index},{},", method.name(), csv_field(file_path));
        let _ = match outcome {
            AuseOutcome::Scored(c) => writeln!(out, "{},{},{},", c.ause, c.pixels, c.unscored),
            AuseOutcome::Skipped(e) => writeln!(out, ",,,{}", csv_field(&e.to_string())),
        };
    }
    out
}

impl Stage for Uncertainty<'_> {
    const NAME: &'static str = "uq";
    const CODE: &'static [&'static str] = &["nerfsv-uq", "nerfsv-plot", "uq.rs", "stages.rs", "config.rs"];
    const OUTPUTS: &'static [&'static str] = &[
        Self::GA_CSV,
        Self::BLA_CSV,
        Self::AUSE_CSV,
        "uq_ga_sigma_d.png",
        "uq_ga_sigma_d.svg",
        "uq_ga_mu_sigma.png",
        "uq_ga_mu_sigma.svg",
        "uq_bla_trace.png",
        "uq_bla_trace.svg",
        "uq_bla_rmv.png",
        "uq_bla_rmv.svg",
        "uq_bla_trace_rmv.png",
        "uq_bla_trace_rmv.svg",
    ];
    const INPUTS: &'static [&'static str] = &[Dataset::NAME, Train::NAME];
    type Figures = UqFigures;

    fn config(&self) -> impl Serialize {
        (self.uq, self.offline)
    }

    fn run(&self, cx: &StageContext) -> Result<UqFigures, PipelineError> {
        let start = Instant::now();
        let nerf = Nerf::load(&Train::checkpoint(cx.root))?;
        let data = cx.input_dir(Dataset::NAME);
        let (ga_n, bla_n) = (self.offline.ga_images_per_split, self.offline.bla_images_per_split);
        let splits = SPLITS.map(|name| load_dataset_split(&data, name, 1));
        let mut chosen = Vec::new();
        for (name, split) in SPLITS.into_iter().zip(splits) {
            let split = split?;
            let all: Vec<usize> = (0..split.frames.len()).collect();
            let (ga_idx, bla_idx) = (stride(&all, Some(ga_n)), stride(&all, Some(bla_n)));
            chosen.push((name, split, ga_idx, bla_idx));
        }
        // Progress counts the images fitted, over all splits and both methods.
        let total = chosen.iter().map(|(_, _, g, b)| g.len() + b.len()).sum::<usize>() as u64;
        let done = std::cell::Cell::new(0u64);
        let tick = |status: &str| {
            done.set(done.get() + 1);
            cx.progress(done.get(), total, status);
        };
        let note = |message: &str| cx.observer.note(Self::NAME, message);
        let (mut ga, mut bla, mut ause) = (Vec::new(), Vec::new(), Vec::new());
        for (name, split, ga_idx, bla_idx) in &chosen {
            if *name != "test" {
                for (method, indices, rows) in [(Method::Ga, ga_idx, &mut ga), (Method::Bla, bla_idx, &mut bla)] {
                    let status = format!("{} {name}", method.name().to_uppercase());
                    let progress = |d: usize, _: usize| {
                        if d > 0 {
                            tick(&status)
                        }
                    };
                    rows.extend(offline_split(&nerf, method, split, name, indices, None, self.uq, &progress, &note)?);
                }
                continue;
            }
            // The test split: each image's fit also gives the depth-uncertainty map its AUSE
            // ranks, so GA and BLA are fitted once per image.
            nerfsv_nerf::check_bounds(&nerf.config, split)?;
            for (method, indices, rows) in [(Method::Ga, ga_idx, &mut ga), (Method::Bla, bla_idx, &mut bla)] {
                let status = format!("{} test, depth AUSE", method.name().to_uppercase());
                for &index in indices {
                    let frame = &split.frames[index];
                    let (fit, outcome) = ause_frame(&nerf, method, frame, self.uq)?;
                    let fit = match fit {
                        Some(f) => f,
                        // No ground-truth depth: fitted for its row all the same.
                        None => fit_frame(&nerf, method, &frame.file_path, frame, None, self.uq)?,
                    };
                    if let AuseOutcome::Skipped(e) = &outcome {
                        note(&format!("{} depth AUSE skipped: {e}", method.name().to_uppercase()));
                    }
                    rows.push(Row { split: name, index, file_path: frame.file_path.clone(), fit });
                    ause.push((method, index, frame.file_path.clone(), outcome));
                    tick(&status);
                }
            }
        }
        let mean_of = |method: Method| {
            let scored: Vec<Sparsification> = ause
                .iter()
                .filter(|(m, ..)| *m == method)
                .filter_map(|(.., o)| if let AuseOutcome::Scored(c) = o { Some(c.clone()) } else { None })
                .collect();
            (mean_ause(&scored), scored.len())
        };
        let ((ause_ga, ause_ga_images), (ause_bla, ause_bla_images)) = (mean_of(Method::Ga), mean_of(Method::Bla));

        let mut files = vec![
            (Self::GA_CSV.to_string(), csv(&ga, Method::Ga).into_bytes()),
            (Self::BLA_CSV.to_string(), csv(&bla, Method::Bla).into_bytes()),
            (Self::AUSE_CSV.to_string(), ause_csv(&ause).into_bytes()),
        ];
        files.extend(figure_files(&ga, &SPLITS, Method::Ga, self.uq)?);
        files.extend(figure_files(&bla, &SPLITS, Method::Bla, self.uq)?);
        // The maps of the first test image BLA fitted (else GA's first).
        if let Some((_, split, ga_idx, bla_idx)) = chosen.iter().find(|(n, ..)| *n == "test") {
            if let Some(&index) = bla_idx.first().or(ga_idx.first()) {
                cx.progress(done.get(), total, "per-pixel maps");
                if let Some(png) = maps_figure(&nerf, &split.frames[index], !bla_idx.is_empty(), self.uq)? {
                    files.push((MAPS_PNG.to_string(), png));
                }
            }
        }
        write_files(&cx.dir, &files)?;
        let rows: Vec<Row> = ga.into_iter().chain(bla).collect();
        Ok(UqFigures {
            train: split_figures(&rows, "train", self.uq.ga_sigma_max),
            val: split_figures(&rows, "val", self.uq.ga_sigma_max),
            test: split_figures(&rows, "test", self.uq.ga_sigma_max),
            ause_ga,
            ause_ga_images,
            ause_bla,
            ause_bla_images,
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    fn describe(f: &UqFigures) -> String {
        let splits = [&f.train, &f.val, &f.test];
        let ga: usize = splits.iter().map(|s| s.ga_images).sum();
        let bla: usize = splits.iter().map(|s| s.bla_images).sum();
        format!(
            "GA on {ga} images (test mean σ_d {}), BLA on {bla} (test mean trace {}); depth AUSE GA {} over {}, BLA {} over {}; {:.1} s",
            short(f.test.ga_mean_sigma_d),
            short(f.test.bla_mean_normalized_trace),
            short(f.ause_ga),
            f.ause_ga_images,
            short(f.ause_bla),
            f.ause_bla_images,
            f.seconds
        )
    }
}

/// The offline library's (`nerfsv_uq::offline`) tests of its rows, figures and CSV, beside the
/// stage's.
#[cfg(test)]
mod tests {
    use nerfsv_nerf::RayInput;
    use nerfsv_uq::GaExclusion;

    use super::*;

    /// Rays from far outside the model's box, pointing away from it.
    fn missing_rays() -> (Vec<RayInput>, Vec<[f32; 3]>) {
        let ray =
            RayInput { origin: [10.0, 10.0, 10.0], direction: [1.0, 0.0, 0.0], background: BACKGROUND, jitter: 0.0 };
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
