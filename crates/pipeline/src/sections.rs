//! Each built-in stage's section of the report ([`Report`]), built from its typed figures.
//!
//! Kept apart from the stages' modules on purpose: a stage's key digests its code
//! ([`crate::Stage::CODE`]), and no stage lists this file, so changing how a table looks reruns
//! nothing. The page around the sections is [`crate::report`]'s.

use std::path::Path;

use nerfsv_sim::WorldKind;

use crate::flight::{FlightStage, FlightStageFigures};
use crate::online::{OnlineFigures, OnlineStage};
use crate::report::{esc, Section, Table};
use crate::stages::{Eval, EvalFigures, GroundTruthField, NerfField, NerfFieldFigures};
use crate::stress::StressStage;
use crate::uq::{Uncertainty, UqFigures};
use crate::{Report, ReportContext, Stage};
use nerfsv_study::stress::{Sampler, SamplerFigures, StressFigures};

/// A number for a table: `digits` decimals, or "–" when absent.
fn num(v: impl Into<Option<f64>>, digits: usize) -> String {
    v.into().map_or("–".into(), |x| format!("{x:.digits$}"))
}

/// Metres as millimetres, one decimal.
fn mm(v: f64) -> String {
    format!("{:.1}", 1e3 * v)
}

/// A percentage of a fraction.
fn pct(v: f64) -> String {
    format!("{:.1} %", 100.0 * v)
}

fn yes_no(v: bool) -> String {
    if v { "yes" } else { "no" }.into()
}

/// Writes a picture the section drew into the stage's folder; `false` if it could not.
fn draw(cx: &ReportContext, file: &str, png: Option<Vec<u8>>) -> bool {
    png.is_some_and(|png| nerfsv_scene::io::atomic_write_bytes(&cx.dir.join(file), &png).is_ok())
}

impl Report for crate::stages::Dataset<'_> {
    const ABOUT: &'static str = "ground-truth renders of the scene (train, val, test)";
}

impl Report for GroundTruthField<'_> {
    const ABOUT: &'static str = "ground-truth signed collision field";
}

impl Report for crate::stages::Train<'_> {
    const ABOUT: &'static str = "NeRF training";
}

impl Report for crate::ensemble::EnsembleStage<'_> {
    const ABOUT: &'static str = "the ensemble's other NeRFs and their collision fields";

    fn report(f: &crate::ensemble::EnsembleFigures, _: &ReportContext) -> Option<Section> {
        if f.trained.is_empty() {
            return None;
        }
        let mut s = Section::new("ensemble", "The ensemble: the NeRFs the same data could have given", "ensemble");
        s.paragraph(format!(
            "{} NeRFs: the deployed model (member 0) and {} more trained like it for {} steps with seeds of their own{}. \
             Their disagreement stands for what the training views leave undetermined; with sim.nerf_world = \
             \"ensemble\" NeRF-sim's camera and collisions come from member 1 + (seed mod {}) of each rollout while the \
             estimator keeps the deployed model.",
            f.members,
            f.trained.len(),
            f.steps,
            if f.bootstrap { ", each on a bootstrap of the training views" } else { "" },
            f.trained.len()
        ));
        s.table(
            Table::new(&[
                "member",
                "seed",
                "distinct training views",
                "test PSNR (dB, first 20 views)",
                "IoU with the GT field in the flight band",
            ])
            .rows(f.trained.iter().map(|m| {
                vec![
                    m.member.to_string(),
                    m.seed.to_string(),
                    m.distinct_views.to_string(),
                    num(m.test_psnr, 2),
                    num(m.band_iou, 3),
                ]
            })),
        );
        Some(s)
    }
}

impl Report for Eval {
    const ABOUT: &'static str = "test-split PSNR, SSIM, depth error";

    fn report(e: &EvalFigures, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new("eval", "The NeRF against the ground truth", "NeRF");
        s.table(Table::new(&["test images", "PSNR (dB)", "SSIM", "median depth error (m)"]).row(vec![
            e.images.to_string(),
            num(e.psnr, 2),
            num(e.ssim, 3),
            num(e.depth_median_abs_err_m, 4),
        ]));
        s.picture("compare.png", "Test views: ground truth (left) beside the NeRF (right)");
        Some(s)
    }
}

impl Report for Uncertainty<'_> {
    const ABOUT: &'static str = "offline uncertainty: GA, BLA, depth AUSE";

    fn report(u: &UqFigures, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new("uq", "Offline uncertainty per image, and its calibration", "offline uncertainty");
        let t = &u.test;
        s.answer(
            40,
            format!(
                "<b>How far can the NeRF be trusted?</b> On its test images GA's noise-floored σ_d has median {} (the \
                 paper's σ_d: {}, {} of {} images excluded at σ_d ≥ 3); BLA's information gain averages {} nats; depth \
                 AUSE GA {}, BLA {} (lower ranks errors better).",
                num(t.ga_floored_median_sigma_d, 3),
                num(t.ga_median_sigma_d, 2),
                t.ga_excluded,
                t.ga_images,
                num(t.bla_mean_information_gain, 1),
                num(u.ause_ga, 3),
                num(u.ause_bla, 3),
            ),
        );
        let splits = [("train", &u.train), ("val", &u.val), ("test", &u.test)];
        s.table(
            Table::new(&[
                "split",
                "GA images",
                "excluded (σ_d ≥ 3)",
                "mean σ_d",
                "median σ_d",
                "noise-floored: excluded (≥ 3)",
                "mean σ_d",
                "median σ_d",
            ])
            .rows(splits.iter().map(|(name, x)| {
                vec![
                    name.to_string(),
                    x.ga_images.to_string(),
                    x.ga_excluded.to_string(),
                    num(x.ga_mean_sigma_d, 3),
                    num(x.ga_median_sigma_d, 3),
                    x.ga_floored_excluded.to_string(),
                    num(x.ga_floored_mean_sigma_d, 3),
                    num(x.ga_floored_median_sigma_d, 3),
                ]
            })),
        );
        s.table(
            Table::new(&["split", "BLA images", "mean normalised trace", "mean rmv", "mean information gain (nats)"])
                .rows(splits.iter().map(|(name, x)| {
                    vec![
                        name.to_string(),
                        x.bla_images.to_string(),
                        num(x.bla_mean_normalized_trace, 4),
                        num(x.bla_mean_rmv, 4),
                        num(x.bla_mean_information_gain, 1),
                    ]
                })),
        );
        s.paragraph(
            "GA's σ_d is the paper's eq. 2, which has no pixel-noise term: a nearly transparent ray (tiny \
             s = Σ c²d²) turns any noise in its colour into a huge (r − μm)²/s and drives σ_d, which is why the \
             paper's σ_d ≥ 3 exclusion removes many images. The noise-floored σ_d fits r ~ N(μm, σ_d²s + σ_n²) with \
             σ_n the pixel noise (uq.noise_std): 0 when the model explains the image up to its noise; it is shown \
             beside the paper's, and the online measure and reward use it by default (uq.ga_measure). GA's \
             per-pixel maps keep the paper's σ_d: a map is σ_d times a per-pixel factor, so its ranking, which the \
             AUSE measures, does not depend on it. Over the white background, colours are taken relative to it \
             (c − bg, r = reference − bg): scaling the weights by μ scales the opacity too, so μ = 0.8 is exactly the \
             render with every weight scaled by 0.8 (the paper writes eq. 2 without a background).",
        );
        s.paragraph(
            "BLA's prior is centred at the trained weights. The normalised trace tr(Σ)/P and rmv are the \
             paper's (its eq. 11 reward uses their product); in the directions an image's rays do not see, Σ is the \
             prior's 1/α, so with m residuals and P weights the trace cannot fall below (P − m)/(P·α): it mostly \
             measures the prior. The information gain ½ Σ<sub>k</sub> ln(1 + e<sub>k</sub>/(σ<sub>n</sub>²α)) \
             counts only the data's directions: 0 for an image that constrains nothing.",
        );
        s.table(Table::new(&["method", "test images", "depth AUSE (0 is perfect)"]).rows([
            vec!["GA".into(), u.ause_ga_images.to_string(), num(u.ause_ga, 3)],
            vec!["BLA".into(), u.ause_bla_images.to_string(), num(u.ause_bla, 3)],
        ]));
        if let Some(e) = &u.ensemble_ause {
            s.paragraph(format!(
                "The ensemble ({} NeRFs) ranks the deployed model's depth error by the members' depth standard \
                 deviation; a random ordering of the same errors is the baseline any uncertainty must beat. On the \
                 same test images as each method:",
                e.members
            ));
            let rows = [
                ("GA's", e.ga_images, u.ause_ga, e.on_ga_images, e.random_on_ga_images),
                ("BLA's", e.bla_images, u.ause_bla, e.on_bla_images, e.random_on_bla_images),
            ];
            s.table(Table::new(&["images", "images scored", "method's depth AUSE", "ensemble", "random order"]).rows(
                rows.map(|(name, n, method, ensemble, random)| {
                    vec![name.into(), n.to_string(), num(method, 3), num(ensemble, 3), num(random, 3)]
                }),
            ));
        }
        if let Some(c) = &u.ause_on_common_images {
            s.paragraph(format!(
                "Every method on the same {} test images (those all of them scored), mean ± bootstrap standard error \
                 over the images. A perfect ranking scores 0 (the oracle's); the oracle's own curve encloses {} on \
                 these images, the scale to read an AUSE against; a random order of the same errors is the baseline \
                 an uncertainty must beat.",
                c.images,
                num(c.oracle_area, 3)
            ));
            s.table(
                Table::new(&["method", "depth AUSE", "± SE"]).rows(
                    c.methods.iter().map(|m| vec![m.method.to_uppercase(), num(m.mean, 3), num(m.bootstrap_se, 3)]),
                ),
            );
        }
        s.paragraph(
            "Depth AUSE protocol: every test pixel with a ground-truth depth counts; a pixel whose ray composites \
             no sample has no uncertainty and ranks as the most uncertain (removed first), not dropped. Bayes' Rays \
             score only the pixels their method gives a value, so where many pixels are unscored the figures are not \
             directly comparable (ause.csv counts them per image).",
        );
        for (file, caption) in [
            (
                "uq_maps.png",
                "Per pixel, on one test view: the NeRF's depth error and GA's and BLA's depth standard deviations \
                 (and the ensemble's, with one)",
            ),
            ("uq_ga_sigma_d.png", "GA: σ_d per image and split"),
            ("uq_ga_mu_sigma.png", "GA: μ_d against σ_d"),
            ("uq_bla_trace.png", "BLA: normalised trace per image and split"),
            ("uq_bla_rmv.png", "BLA: rmv per image and split"),
            ("uq_bla_trace_rmv.png", "BLA: normalised trace against rmv"),
        ] {
            s.picture(file, caption);
        }
        if u.ensemble_field.is_some() {
            let slice = nerfsv_uq::offline::field_slice_path(Path::new(Uncertainty::ENSEMBLE_FIELD));
            s.picture(
                &slice.to_string_lossy(),
                &format!(
                    "The ensemble's uncertainty field at z = {:.2} m: the members' density standard deviation ({}, with `nerfsv uq field --method ensemble`'s format)",
                    nerfsv_uq::offline::FIELD_SLICE_ALTITUDE,
                    Uncertainty::ENSEMBLE_FIELD
                ),
            );
        }
        s.csv(Uncertainty::AUSE_CSV, "ause.csv");
        s.csv(Uncertainty::GA_CSV, "uq_ga.csv");
        s.csv(Uncertainty::BLA_CSV, "uq_bla.csv");
        Some(s)
    }
}

impl Report for NerfField {
    const ABOUT: &'static str = "the NeRF's collision field";

    fn report(f: &NerfFieldFigures, _: &ReportContext) -> Option<Section> {
        let title = match f.agreement_with_ground_truth {
            Some(_) => "Collision fields: the NeRF's against the ground truth",
            None => "The NeRF's collision field (no ground truth to compare it with)",
        };
        let mut s = Section::new("nerf_collision", title, "collision fields");
        let header = ["occupancy IoU", "IoU in the flight band", "|SDF diff| mean (m)", "|SDF diff| p95 (m)"];
        match &f.agreement_with_ground_truth {
            Some(a) => s.table(Table::new(&header).row(vec![
                num(a.iou, 3),
                num(a.band_iou, 3),
                num(a.band_mean_abs_diff, 4),
                num(a.band_p95_abs_diff.map(f64::from), 4),
            ])),
            None => s.paragraph("The field was built without a ground-truth field to compare it with."),
        }
        s.paragraph("Slices of both fields at the flight's altitude are in the nominal flights' section.");
        Some(s)
    }
}

/// The flight stage's drawing of both collision fields.
const FIELDS_PNG: &str = "field_slices.png";
/// The difference panel's colours saturate at this many metres.
const FIELD_DIFFERENCE_CLIP_M: f64 = 0.05;

/// Slices of the ground-truth and the NeRF's signed fields at altitude `z`, sampled at the
/// ground-truth grid's nodes in x and y, and their difference NeRF − GT, clipped at
/// ±[`FIELD_DIFFERENCE_CLIP_M`]; `None` without both fields.
fn field_slices_figure(root: &Path, z: f64) -> Option<Vec<u8>> {
    let gt = nerfsv_collision::SdfGrid::load(GroundTruthField::sdf_path(root)).ok()?;
    let nerf = nerfsv_collision::SdfGrid::load(root.join(NerfField::NAME).join(NerfField::SDF)).ok()?;
    let g = gt.geometry;
    let [nx, ny, _] = g.dims;
    let sample = |f: &nerfsv_collision::SdfGrid, i: usize, j: usize| -> f64 {
        let mut q = g.position_of(i, j, 0);
        q.z = z as f32;
        f.geometry.trilinear(&f.data, &q).in_grid().map_or(f64::NAN, f64::from)
    };
    let mut values = [Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny)];
    for j in 0..ny {
        for i in 0..nx {
            let (a, b) = (sample(&gt, i, j), sample(&nerf, i, j));
            values[0].push(a);
            values[1].push(b);
            values[2].push((b - a).clamp(-FIELD_DIFFERENCE_CLIP_M, FIELD_DIFFERENCE_CLIP_M));
        }
    }
    let [gt_v, nerf_v, diff_v] = values;
    let panel = |caption: String, colour_title: &str, values: Vec<f64>, scale| nerfsv_plot::Heatmap {
        caption,
        x_title: "x (m)".into(),
        y_title: "y (m)".into(),
        colour_title: colour_title.into(),
        origin: [f64::from(g.origin.x), f64::from(g.origin.y)],
        cell: [f64::from(g.cell); 2],
        dims: [nx, ny],
        values,
        scale,
    };
    let fig = nerfsv_plot::HeatmapFigure {
        title: format!("Signed distance at z = {z:.2} m"),
        panels: vec![
            panel("ground truth".into(), "signed distance (m)", gt_v, nerfsv_plot::ColourScale::Linear),
            panel("NeRF".into(), "signed distance (m)", nerf_v, nerfsv_plot::ColourScale::Linear),
            panel(
                format!("NeRF − ground truth (clipped at ±{:.0} cm)", 100.0 * FIELD_DIFFERENCE_CLIP_M),
                "difference (m)",
                diff_v,
                nerfsv_plot::ColourScale::Diverging,
            ),
        ],
    };
    nerfsv_plot::heatmap_png(&fig, 1500, 500).ok()
}

impl Report for FlightStage<'_> {
    const ABOUT: &'static str = "nominal flights in both worlds";

    fn report(f: &FlightStageFigures, cx: &ReportContext) -> Option<Section> {
        let mut s = Section::new("flight", "Nominal flights", "nominal flights");
        s.table(
            Table::new(&[
                "flight",
                "collided",
                "min clearance (m)",
                "reached goal",
                "mean position error (m)",
                "mean rotation error (°)",
                "images / refused by the gate / relocalisations",
                "mean NEES (12 if consistent)",
            ])
            .rows(f.flights.iter().map(|fl| {
                vec![
                    format!("{}-sim, {}", fl.world.name(), fl.estimator.name()),
                    yes_no(fl.collided),
                    num(fl.min_clearance_m.map(f64::from), 3),
                    yes_no(fl.reached_goal),
                    num(fl.mean_position_error_m, 4),
                    num(fl.mean_rotation_error_deg, 2),
                    format!("{} / {} / {}", fl.images, fl.rejected_images, fl.relocalisations),
                    num(fl.mean_nees, 1),
                ]
            })),
        );
        s.paragraph(
            "The vision estimator is a filter on the 12-D state whose measurement is the camera image aligned \
             against the NeRF; errors are after each image's update, NEES is the normalised estimation error squared \
             of the whole state (χ²(12) when the filter's covariance is honest).",
        );
        for (file, caption) in [
            ("trajectory_gt_vision.png", "Nominal flight in GT-sim, vision estimator"),
            ("trajectory_nerf_vision.png", "Nominal flight in NeRF-sim, vision estimator"),
            (
                "trajectory_gt_vision_position_error.png",
                "GT-sim, vision estimator: position error of the estimate and the filter's 2σ",
            ),
            (
                "trajectory_gt_vision_attitude_error.png",
                "GT-sim, vision estimator: attitude error of the estimate and the filter's 2σ",
            ),
            (
                "trajectory_nerf_vision_position_error.png",
                "NeRF-sim, vision estimator: position error of the estimate and the filter's 2σ",
            ),
        ] {
            s.picture(file, caption);
        }
        // Both collision fields at the planned path's mean altitude.
        let z = if f.waypoints.is_empty() {
            0.18
        } else {
            f.waypoints.iter().map(|w| w[2]).sum::<f64>() / f.waypoints.len() as f64
        };
        if draw(cx, FIELDS_PNG, field_slices_figure(cx.root, z)) {
            s.picture(FIELDS_PNG, "Signed distance at flight altitude: ground truth, NeRF, and their difference");
        }
        Some(s)
    }
}

/// The stress stage's histograms of clearance differences.
const CLEARANCE_PNG: &str = "clearance_difference.png";

/// Histograms of |clearance in NeRF-sim − in GT-sim| (mm) per sampler, per trajectory and per
/// step, from the stress stage's rollouts and their replays in `dir`; `None` without them.
fn clearance_figure(dir: &Path) -> Option<Vec<u8>> {
    let records = nerfsv_validation::read_csv_file(&dir.join(nerfsv_study::stress::ROLLOUTS_CSV)).ok()?;
    let replays = nerfsv_validation::read_csv_file(&dir.join(nerfsv_study::stress::replay_csv(WorldKind::Gt))).ok()?;
    let mut groups = Vec::new();
    for sampler in [nerfsv_validation::Label::Mc, nerfsv_validation::Label::Cem] {
        let ours: Vec<_> = records.iter().filter(|r| r.sampler == sampler).cloned().collect();
        let theirs: Vec<_> = replays.iter().filter(|r| r.sampler == sampler).cloned().collect();
        let Ok(a) = nerfsv_validation::compare(&ours, &theirs) else { continue };
        let mm = |v: &[f64]| v.iter().map(|x| 1e3 * x).collect::<Vec<f64>>();
        let name = sampler.name().to_uppercase();
        groups.push(nerfsv_plot::Group {
            label: format!("{name}, per trajectory"),
            values: mm(&a.clearance_difference.values),
        });
        groups.push(nerfsv_plot::Group {
            label: format!("{name}, per step"),
            values: mm(&a.step_clearance_difference.values),
        });
    }
    groups.retain(|g| !g.values.is_empty());
    if groups.is_empty() {
        return None;
    }
    let fig = nerfsv_plot::HistogramFigure {
        title: "NeRF-sim against GT-sim: |Δ minimum clearance| on the same disturbances".into(),
        x_title: "|clearance difference| (mm)".into(),
        y_title: "count".into(),
        groups,
        bins: 30,
    };
    nerfsv_plot::histograms_png(&fig, 1100, 700).ok()
}

/// The study's answer from the stress stage: how likely the drone fails under the disturbance
/// prior (subset simulation's estimate where the stage ran it, else Monte Carlo's), how
/// NeRF-sim's failures carry over to GT-sim, and the most likely failure.
/// A rate with its interval: `3.0 % [1.0, 8.5]`.
fn rate_ci(value: f64, ci: [f64; 2]) -> String {
    format!("{} [{:.1}, {:.1}]", pct(value), 100.0 * ci[0], 100.0 * ci[1])
}

/// "MC 0.61 [0.51, 0.71] (18 of 548 steps disagree)": a sampler's step AUROC with its interval.
fn step_auroc_with_interval(a: &nerfsv_study::stress::StepAurocFigures) -> String {
    let ci = a.step_auroc_ci95.map_or(String::new(), |[lo, hi]| format!(" [{lo:.2}, {hi:.2}]"));
    format!(
        "{} {}{ci} ({} of {} steps disagree)",
        a.sampler.name().to_uppercase(),
        num(a.auroc.step_auroc, 2),
        a.auroc.disagreeing_steps,
        a.auroc.steps
    )
}

/// `k / n` with its Wilson 95 % interval, or "–" for `n = 0`.
fn proportion(k: usize, n: usize) -> String {
    if n == 0 {
        return "–".into();
    }
    let (lo, hi) = nerfsv_validation::wilson_interval(k, n);
    format!("{:.2} [{lo:.2}, {hi:.2}]", k as f64 / n as f64)
}

/// A proportion or coefficient with its interval, or "–".
fn estimate(e: Option<nerfsv_validation::Estimate>) -> String {
    e.map_or("–".into(), |e| format!("{:.2} [{:.2}, {:.2}]", e.value, e.ci95[0], e.ci95[1]))
}

/// Each world's crash rate and each NeRF world's agreement with GT-sim, a row per world.
fn transfer_table(t: &nerfsv_study::stress::TransferFigures) -> Table {
    let world = |name: &str, r: &nerfsv_study::stress::RateFigure, x: Option<&nerfsv_validation::Transfer>| {
        let mut row = vec![name.to_string(), format!("{} of {}", r.failures, r.rollouts), rate_ci(r.rate, r.ci95)];
        match x {
            Some(x) => row.extend([
                format!("{} / {}", x.confusion.false_positive, x.confusion.false_negative),
                format!("{:.2e}", x.mcnemar_p),
                estimate(x.precision),
                estimate(x.recall),
                estimate(x.mcc),
                format!(
                    "{} (majority {})",
                    x.accuracy.map_or("–".into(), |a| format!("{:.2}", a.value)),
                    num(x.majority_accuracy, 2)
                ),
            ]),
            None => row.extend(std::iter::repeat_n("–".to_string(), 6)),
        }
        row
    };
    Table::new(&[
        "world",
        "MC crashes",
        "crash rate [95 %]",
        "only NeRF / only GT",
        "McNemar exact p",
        "precision",
        "recall",
        "Matthews correlation",
        "accuracy",
    ])
    .row(world("NeRF-sim, deployed NeRF as the world", &t.nerf_deployed, Some(&t.deployed)))
    .row(world("NeRF-sim, the ensemble as the world", &t.nerf_ensemble, Some(&t.ensemble)))
    .row(world("GT-sim", &t.gt, None))
}

fn stress_answer(s: &mut Section, f: &StressFigures) {
    let find = |sampler: Sampler| f.samplers.iter().find(|s| s.sampler == sampler);
    let world = |s: &SamplerFigures| format!("{}-sim, {} estimator", s.world.name(), s.estimator.name());
    if let Some(p) = find(Sampler::Subset).or_else(|| find(Sampler::Mc)) {
        let how = match p.sampler {
            Sampler::Subset => "subset simulation",
            _ => "Monte Carlo",
        };
        let mut line = format!(
            "<b>How likely does the drone crash</b> under the disturbance prior ({})? P(fail) = {}, 95 % interval [{}, {}] \
             ({how}, {} rollouts)",
            esc(&world(p)),
            num(p.p_fail, 3),
            num(p.p_fail_interval.0, 3),
            num(p.p_fail_interval.1, 3),
            p.rollouts,
        );
        if let (Some(mc), Sampler::Subset) = (find(Sampler::Mc), p.sampler) {
            let _ = std::fmt::Write::write_fmt(
                &mut line,
                format_args!(
                    "; Monte Carlo alone: {} of {} [{}, {}]",
                    pct(mc.p_fail),
                    mc.rollouts,
                    num(mc.p_fail_interval.0, 3),
                    num(mc.p_fail_interval.1, 3)
                ),
            );
        }
        s.answer(10, line + ".");
    }
    if let Some(c) = find(Sampler::Mc).and_then(|s| s.confusion.as_ref()) {
        let t = &c.trajectories;
        let (tp, fp, fneg, tn) = (t.true_positive, t.false_positive, t.false_negative, t.true_negative);
        s.answer(
            20,
            format!(
                "<b>Do NeRF-sim's failures hold in GT-sim?</b> Of the Monte Carlo rollouts, {} crashed in NeRF-sim and {} in \
                 GT-sim with the same disturbances; {tp} crashed in both (precision {}, recall {}, Wilson 95 % \
                 intervals), {fp} only in NeRF-sim, {fneg} only in GT-sim, {tn} in neither (accuracy {} against {} for \
                 always predicting GT-sim's commoner outcome).",
                t.nerf_failures(),
                t.gt_failures(),
                proportion(tp, t.nerf_failures()),
                proportion(tp, t.gt_failures()),
                proportion(tp + tn, t.total()),
                num(t.majority_accuracy(), 2),
            ),
        );
    }
    if let Some(m) = find(Sampler::Cem).or_else(|| find(Sampler::Mc)).and_then(|s| s.most_likely_failure.as_ref()) {
        let replay = match m.replay_collided {
            Some(true) => "it crashes in GT-sim too",
            Some(false) => "it does not crash in GT-sim",
            None => "not replayed",
        };
        s.answer(
            30,
            format!(
                "<b>The most likely failure</b> found ({} {}/{}): log-likelihood {} (the steps after the crash at the prior's mode), collision at step {}; {replay}.",
                esc(&m.sampler.name().to_uppercase()),
                m.population,
                m.index,
                num(m.log_likelihood, 2),
                m.collision_step.map_or("–".into(), |k| k.to_string()),
            ),
        );
    }
}

impl Report for StressStage<'_> {
    const ABOUT: &'static str = "Monte Carlo, CEM and subset simulation in NeRF-sim, replayed in GT-sim";

    fn report(f: &StressFigures, cx: &ReportContext) -> Option<Section> {
        let title = match f.replay_world {
            Some(_) => "Stress tests: failure probability and NeRF-sim against GT-sim",
            None => "Stress tests: failure probability (nothing replayed in another world)",
        };
        let mut s = Section::new("stress", title, "stress tests");
        stress_answer(&mut s, f);
        if let Some(t) = &f.transfer {
            let table = transfer_table(t);
            s.answer(
                5,
                format!(
                    "<b>Do failures found in a NeRF predict failures in the world?</b> The same {} Monte Carlo rollouts \
                     (disturbances and seeds) in NeRF-sim with the deployed NeRF as the world, in NeRF-sim with the \
                     ensemble's other members as the world, and in GT-sim; each NeRF world against GT-sim, failure \
                     positive, 95 % intervals (rates and proportions Wilson, correlation bootstrap over rollouts):\n{}",
                    t.gt.rollouts,
                    table.html()
                ),
            );
            s.paragraph("The transfer table: the Monte Carlo rollouts in both NeRF worlds against GT-sim.");
            s.table(table);
            if !t.step_auroc.is_empty() {
                s.paragraph(
                    "How well the ensemble's uncertainty of the drone's view at each step (the mean density-aware \
                     spread of its NeRFs' renders of the view's rays, measured at the step's recorded pose, no \
                     ground-truth image) predicts the steps where NeRF-sim and GT-sim disagree (one touched geometry, \
                     the other not); per sampler, the step AUROC's interval from a bootstrap over rollouts:",
                );
                s.table(
                    Table::new(&[
                        "sampler",
                        "NeRF world",
                        "steps",
                        "disagreeing",
                        "step AUROC [95 %]",
                        "rollout AUROC",
                    ])
                    .rows(t.step_auroc.iter().map(|a| {
                        vec![
                            a.sampler.name().to_uppercase(),
                            a.nerf_world.name().into(),
                            a.auroc.steps.to_string(),
                            a.auroc.disagreeing_steps.to_string(),
                            match (a.auroc.step_auroc, a.step_auroc_ci95) {
                                (Some(v), Some(ci)) => format!("{v:.2} [{:.2}, {:.2}]", ci[0], ci[1]),
                                (v, _) => num(v, 2),
                            },
                            num(a.auroc.trajectory_auroc, 2),
                        ]
                    })),
                );
            }
        }
        let name = |x: &SamplerFigures| x.sampler.name().to_uppercase();
        s.table(
            Table::new(&[
                "sampler",
                "rollouts flown",
                "collision rate of the searched",
                "lost",
                "avg. collision step",
                "avg. log-likelihood",
                "P(fail) ± SE",
                "95 % interval",
            ])
            .rows(f.samplers.iter().map(|x| {
                vec![
                    name(x),
                    x.rollouts.to_string(),
                    // The rate is over the search's own rollouts (CEM: its populations, not the
                    // importance batch), which the first row of the sampler's table counts.
                    format!(
                        "{} of {}",
                        pct(x.collision_rate),
                        x.table.first().map_or("–".into(), |r| r.rollouts.to_string())
                    ),
                    pct(x.lost_rate),
                    num(x.avg_collision_step, 2),
                    num(x.avg_log_likelihood, 2),
                    format!("{} ± {}", num(x.p_fail, 3), num(x.p_fail_se, 3)),
                    format!("[{}, {}]", num(x.p_fail_interval.0, 3), num(x.p_fail_interval.1, 3)),
                ]
            })),
        );
        s.table(
            Table::new(&["sampler", "P(fail) estimator", "effective rollouts / failures", "paper's plain IS estimate"])
                .rows(f.samplers.iter().map(|x| {
                    vec![
                        name(x),
                        x.p_fail_estimator.clone(),
                        format!("{} / {}", num(x.effective_sample_size, 1), num(x.effective_failures, 1)),
                        num(x.p_fail_unnormalised, 3),
                    ]
                })),
        );
        s.paragraph(
            "Lost: rollouts whose state stopped being finite or left the field's grid without a collision, \
             neither passes nor failures. The CEM's P(fail) is the importance-sampling estimate with the weight as \
             control variate (its expectation under the proposal is 1), clamped to [0, 1]; the paper's plain estimate \
             (1/N) Σ 𝟙·p/q, unbiased but able to exceed 1, stands beside it. Effective rollouts and failures are \
             Kish's sizes (Σw)²/Σw² of the batch's and of the failures' weights: the number of rollouts the \
             estimate effectively rests on. SUBSET is subset simulation (Au & Beck): level 0 is independent draws \
             from the prior (the MC rollouts, then its own), each next level Markov chains held below the last \
             level's p0-quantile of the clearance (10 % by default); P(fail) is the product of the levels' shares, its \
             SE Au & Beck's bound from the chains' correlation, and its effective rollouts the Monte Carlo rollouts \
             with the same variance. It is the estimator whose ±2 SE interval covers the truth at 10⁻³ and 0.08 on a \
             72-dimensional test problem with these settings (the CEM's does not: BENCHMARKS.md); its rollouts are \
             driven towards failure, so their collision rate is not a rate of anything.",
        );
        s.paragraph(
            "Confusion of NeRF-sim (prediction) against GT-sim (truth) over each search's rollouts, failure positive, \
             each proportion with its Wilson 95 % interval; the majority baseline is the accuracy of always predicting \
             GT-sim's commoner outcome. The CEM's rollouts are driven towards failure: its rows describe those \
             rollouts, not the prior's.",
        );
        s.table(
            Table::new(&[
                "sampler",
                "TP",
                "FP",
                "FN",
                "TN",
                "accuracy",
                "majority baseline",
                "precision",
                "recall",
                "MCC",
                "|Δclearance| median / p90 / max (m)",
            ])
            .rows(f.samplers.iter().filter_map(|x| {
                let c = x.confusion.as_ref()?;
                let (t, d) = (&c.trajectories, &c.clearance_difference_m);
                Some(vec![
                    name(x),
                    t.true_positive.to_string(),
                    t.false_positive.to_string(),
                    t.false_negative.to_string(),
                    t.true_negative.to_string(),
                    proportion(t.true_positive + t.true_negative, t.total()),
                    num(t.majority_accuracy(), 2),
                    proportion(t.true_positive, t.nerf_failures()),
                    proportion(t.true_positive, t.gt_failures()),
                    num(nerfsv_validation::matthews(t), 2),
                    format!("{} / {} / {}", num(d.median, 4), num(d.p90, 4), num(d.max, 4)),
                ])
            })),
        );
        if !f.estimate_errors.is_empty() {
            s.paragraph(
                "The vision estimator's error after each image update, over every rollout the stage flew (the \
                 searches in NeRF-sim and their replays in GT-sim):",
            );
            s.table(
                Table::new(&["world", "images", "position error median / p90 (mm)", "attitude error median / p90 (°)"])
                    .rows(f.estimate_errors.iter().map(|e| {
                        vec![
                            format!("{}-sim", e.world.name()),
                            e.images.to_string(),
                            format!("{} / {}", mm(e.median_position_m), mm(e.p90_position_m)),
                            format!("{} / {}", num(e.median_attitude_deg, 2), num(e.p90_attitude_deg, 2)),
                        ]
                    })),
            );
        }
        for (file, caption) in [
            ("estimate_errors.png", "The vision estimator's position error after each image, both worlds"),
            ("most_likely_failure_mc_nerf.png", "MC's most likely failure in NeRF-sim"),
            ("most_likely_failure_mc_gt.png", "The same disturbances in GT-sim"),
            ("most_likely_failure_cem_nerf.png", "CEM's most likely failure in NeRF-sim"),
            ("most_likely_failure_cem_gt.png", "The same disturbances in GT-sim"),
        ] {
            s.picture(file, caption);
        }
        if draw(cx, CLEARANCE_PNG, clearance_figure(cx.dir)) {
            s.picture(CLEARANCE_PNG, "|clearance in NeRF-sim − in GT-sim| on the same disturbances");
        }
        s.csv(nerfsv_study::stress::TABLE_CSV, "stress_table.csv");
        Some(s)
    }
}

impl Report for OnlineStage<'_> {
    const ABOUT: &'static str = "per-step uncertainty and the rewards (Tables 1–2)";

    fn report(f: &OnlineFigures, _: &ReportContext) -> Option<Section> {
        let mut s =
            Section::new("online", "Tables 1–2: uncertainty in the search, with and without reward", "Tables 1–2");
        if !f.studies.is_empty() {
            let parts: Vec<String> = f
                .studies
                .iter()
                .map(|m| {
                    let d = &m.disagreement;
                    let per: Vec<String> = m.per_sampler.iter().map(step_auroc_with_interval).collect();
                    match per.is_empty() {
                        true => format!(
                            "{} {} ({} of {} steps disagree)",
                            esc(&m.method.name().to_uppercase()),
                            num(d.step_auroc, 2),
                            d.disagreeing_steps,
                            d.steps
                        ),
                        false => format!("{} {}", esc(&m.method.name().to_uppercase()), per.join(", ")),
                    }
                })
                .collect();
            s.answer(
                50,
                format!(
                    "<b>Does the uncertainty flag where NeRF-sim and GT-sim disagree?</b> AUROC of a step's uncertainty \
                     for a disagreeing step (0.5 is chance): {}.",
                    parts.join(", ")
                ),
            );
        }
        s.paragraph(format!(
            "A step's uncertainty is the view's GA {} or BLA {} (<code>uq.ga_measure</code>, <code>uq.bla_measure</code>).",
            esc(&f.ga_measure),
            esc(&f.bla_measure),
        ));
        for m in &f.studies {
            let d = &m.disagreement;
            s.html(format!(
                "<h3>{} ({} mode)</h3><p>AUROC of the step's uncertainty for a NeRF-sim/GT-sim disagreement: {} ({} of {} \
                 steps disagree, MC and CEM together; per sampler, 95 % by a bootstrap over rollouts: {}); of a \
                 rollout's mean: {} ({} of {}).</p>\n",
                esc(&m.method.name().to_uppercase()),
                esc(f.mode.name()),
                num(d.step_auroc, 3),
                d.disagreeing_steps,
                d.steps,
                m.per_sampler.iter().map(step_auroc_with_interval).collect::<Vec<_>>().join(", "),
                num(d.trajectory_auroc, 3),
                d.disagreeing_trajectories,
                d.trajectories,
            ));
            if let Some(t) = &m.transfer {
                let precision = |c: &nerfsv_validation::Confusion| {
                    format!(
                        "{} ({} of {} NeRF-sim failures)",
                        proportion(c.true_positive, c.nerf_failures()),
                        c.true_positive,
                        c.nerf_failures()
                    )
                };
                s.paragraph(format!(
                    "CEM's populations replayed in GT-sim: the share of its NeRF-sim failures that crash there too \
                     (precision, Wilson 95 %) is {} without the reward (the stress stage's CEM) and {} with it; \
                     GT-sim failures among the replays: {} and {} of {} and {}. Different rollouts after the shared \
                     first population: unpaired.",
                    precision(&t.without_reward),
                    precision(&t.with_reward),
                    t.without_reward.gt_failures(),
                    t.with_reward.gt_failures(),
                    t.without_reward.total(),
                    t.with_reward.total(),
                ));
            }
            s.table(
                Table::new(&[
                    "sampler",
                    "reward",
                    "rollouts",
                    "collision rate",
                    "lost",
                    "avg. collision step",
                    "avg. log-likelihood",
                    "avg. uncertainty",
                    "avg. reward",
                ])
                .rows(m.rows.iter().map(|r| {
                    vec![
                        r.row.sampler.name().to_uppercase(),
                        yes_no(r.reward),
                        r.row.rollouts.to_string(),
                        pct(r.row.collision_rate),
                        pct(r.row.lost_rate),
                        num(r.row.avg_collision_step, 2),
                        num(r.row.avg_log_likelihood, 2),
                        num(r.row.avg_uncertainty, 4),
                        num(r.row.avg_reward, 2),
                    ]
                })),
            );
        }
        s.paragraph(
            "The reward is the trajectory log-likelihood (a sum over the steps) less the penalty times the \
             rollout's <em>mean</em> per-step uncertainty (BLA's also times the paper's n perturbations), as in the \
             paper's eqs. 10–11; a rollout with no measured step has reward −∞ and ranks last, and the average \
             reward is over the rollouts with a finite one.",
        );
        s.csv(crate::online::ONLINE_TABLE_CSV, "online_table.csv");
        Some(s)
    }
}
