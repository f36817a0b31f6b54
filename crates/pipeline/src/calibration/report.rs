//! The calibration stage's section of the report.
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use nerfsv_sim::perception::AXES;
use nerfsv_study::calibration::CalibrationFigures;

use crate::calibration::CalibrationStage;
use crate::report::{num, Section, Table};
use crate::{Report, ReportContext, Stage};

impl Report for CalibrationStage<'_> {
    const ABOUT: &'static str = "the estimator's error on views the NeRF never saw, and its error model";

    fn describe(f: &CalibrationFigures) -> String {
        let cv = &f.cross_validation.gaussian_process.coverage90;
        format!(
            "{} route, {} recorded route and {} held-out views, {} fits: median error {:.1} mm / {:.2}°; the model's 90 % interval covers \
             {:.0}–{:.0} % of held-out fits per axis",
            f.route_views,
            f.route_dataset_views,
            f.held_out_views,
            f.fits,
            f.position_error_mm[0],
            f.rotation_error_deg[0],
            100.0 * cv.iter().cloned().fold(f64::INFINITY, f64::min),
            100.0 * cv.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        )
    }

    fn report(f: &CalibrationFigures, _: &ReportContext) -> Option<Section> {
        let mut s =
            Section::new(CalibrationStage::NAME, "Calibration: how the estimator errs on real images", "calibration");
        s.paragraph(format!(
            "The vision estimator fitted, as in flight, to images of the world at known poses that the deployed NeRF \
             never trained on: {} views of a route capture (ground-truth renders along the planned route, each moved \
             off it as a disturbed drone is){} and {} views of the dataset's held-out test split, {} fits in all (one from \
             the true pose, the others from starts drawn like the filter's prediction). Their errors: median {} mm \
             (p90 {}) and {}° (p90 {}), {} renders a fit. A Gaussian process per error axis over the camera's position \
             and viewing direction models them; NeRF-sim's calibrated world renders each rollout's images from the true \
             pose displaced by one draw of it.",
            f.route_views,
            match f.route_dataset_views {
                0 => String::new(),
                n => format!(", {n} views of your own route capture ([calibration] route_dataset)"),
            },
            f.held_out_views,
            f.fits,
            num(f.position_error_mm[0], 1),
            num(f.position_error_mm[1], 1),
            num(f.rotation_error_deg[0], 2),
            num(f.rotation_error_deg[1], 2),
            num(f.renders_per_fit, 1),
        ));
        s.picture(
            CalibrationStage::ROUTE_PNG,
            "Position error of each route fit along the route, and the model's mean and 90 % band",
        );
        let cv = &f.cross_validation;
        let pct = |v: f64| format!("{:.0} %", 100.0 * v);
        s.paragraph(format!(
            "Coverage of the 90 % predictive interval on views held out of the model's fit ({}-fold by view, {} fits); \
             the goal is 85–95 % on every axis. The alternative without spatial correlation (one Gaussian per axis) \
             beside it, and each model's mean log predictive density (higher is better).",
            cv.folds, cv.gaussian_process.held_out_fits
        ));
        let mut table = Table::new(&["model", AXES[0], AXES[1], AXES[2], AXES[3], AXES[4], AXES[5], "log density"]);
        for (name, c) in [
            ("Gaussian process over the view", &cv.gaussian_process),
            ("independent, one Gaussian per axis", &cv.independent),
        ] {
            let mut row = vec![name.to_string()];
            row.extend(c.coverage90.iter().map(|&v| pct(v)));
            row.push(num(c.log_density, 2));
            table = table.row(row);
        }
        s.table(table);
        s.table(
            Table::new(&[
                "axis",
                "mean error (mm or mrad)",
                "length scale, position (m)",
                "length scale, direction",
                "signal sd (mm or mrad)",
                "noise sd (mm or mrad)",
            ])
            .rows(f.kernels.iter().zip(AXES).zip(f.mean_error).map(|((k, axis), mean)| {
                vec![
                    axis.to_string(),
                    num(mean * 1e3, 2),
                    num(k.length_position_m, 3),
                    num(k.length_direction, 2),
                    num(k.signal_var.sqrt() * 1e3, 2),
                    num(k.noise_var.sqrt() * 1e3, 2),
                ]
            })),
        );
        if !f.member_mean_difference.is_empty() {
            s.paragraph(
                "The calibrated world does not draw the real error itself: each ensemble member's own images of the same \
                 views (same pixels, same starts) are fitted too, and that member's model is of the real error less the \
                 member's, so that a member's rendering errors are not counted twice. The mean of that difference per \
                 member (mm and mrad):",
            );
            s.table(Table::new(&["member", AXES[0], AXES[1], AXES[2], AXES[3], AXES[4], AXES[5]]).rows(
                f.member_mean_difference.iter().enumerate().map(|(k, d)| {
                    let mut row = vec![(k + 1).to_string()];
                    row.extend(d.iter().map(|v| num(v * 1e3, 2)));
                    row
                }),
            ));
        }
        if !f.member_image_noise.is_empty() {
            s.paragraph(
                "A member's draw is a smooth function of the view, so its images scatter from image to image only as \
                 much as the member's own fits do. The scatter of one real fit beyond the member's (standard deviation \
                 per axis, mm and mrad: the square root of the real fits' variance about their view's mean less the \
                 member's, pooled over the route capture's views, lost fits left out; zero where the member scatters \
                 as much); with [calibration] image_noise = true each of the calibrated world's images adds an \
                 independent error of this size:",
            );
            s.table(Table::new(&["member", AXES[0], AXES[1], AXES[2], AXES[3], AXES[4], AXES[5]]).rows(
                f.member_image_noise.iter().enumerate().map(|(k, d)| {
                    let mut row = vec![(k + 1).to_string()];
                    row.extend(d.iter().map(|v| num(v * 1e3, 2)));
                    row
                }),
            ));
        }
        model_error(f, &mut s);
        route_geometry(f, &mut s);
        s.csv(CalibrationStage::VIEWS_CSV, "calibration_fits.csv");
        Some(s)
    }
}

/// The filter's model error the calibration measured, pooled and per kind of view.
fn model_error(f: &CalibrationFigures, s: &mut Section) {
    if let Some(m) = &f.model_error {
        s.paragraph(format!(
            "The filter's model error measured on the same fits: a fit's error has a standard deviation of {} m \
             [{}, {}] per axis of position and {}° [{}, {}] per axis of attitude per unit of its colour RMSE (root \
             mean square of error ÷ RMSE over {} fits of {} views, lost fits left out; 95 % intervals from a \
             bootstrap over views), against the config's {} m and {}° (sim.vision.model_error_per_rmse). With \
             [calibration] filter_model_error = true the stress and online stages' filter takes the measured \
             value in every world, GT-sim's included (one estimator ships); but images taken close together in \
             flight share their error, which this measurement of single fits does not see. By default \
             ([calibration] filter_bias) the filter instead carries the kernels' shared error (the \
             squared-exponential variance plus the mean squared, length scales stretched by √(π/2) for its \
             Gauss–Markov form) as a bias it considers but never estimates, and takes each image's own error \
             from the kernels' noise; the model error per RMSE is then unused.",
            num(m.per_rmse[0], 3),
            num(m.position_ci95[0], 3),
            num(m.position_ci95[1], 3),
            num(m.per_rmse[1], 1),
            num(m.rotation_ci95[0], 1),
            num(m.rotation_ci95[1], 1),
            m.fits,
            m.views,
            num(f.config_model_error[0], 3),
            num(f.config_model_error[1], 1),
        ));
    }
    if f.model_error_by_source.len() > 1 {
        let mut t = Table::new(&["views", "fits", "m per RMSE [95 %]", "° per RMSE [95 %]"]);
        for (source, m) in &f.model_error_by_source {
            let at = |v: f64, ci: [f64; 2], p| format!("{} [{}, {}]", num(v, p), num(ci[0], p), num(ci[1], p));
            t = t.row(vec![
                source.name().replace('_', " "),
                m.fits.to_string(),
                at(m.per_rmse[0], m.position_ci95, 3),
                at(m.per_rmse[1], m.rotation_ci95, 1),
            ]);
        }
        s.paragraph("The same measured on each kind of view alone (the filter takes the value over all of them):");
        s.table(t);
    }
}

/// The NeRFs' signed fields along the planned path against the ground truth's.
fn route_geometry(f: &CalibrationFigures, s: &mut Section) {
    let Some(g) = &f.route_geometry else { return };
    s.paragraph(format!(
        "What the error model cannot see: NeRF-sim detects a crash in its NeRF's signed field, not the real one. \
         Along the planned path ({} points a centimetre apart; within {} m of the real geometry, {} beside an \
         obstacle and {} above the ground) the ground truth's surface comes closest at {} % of the way, {} mm from \
         the body's centre. Each field's distance there less the ground truth's, over the points beside \
         obstacles, and over those above the ground (negative: the NeRF's surface lies nearer the route, so \
         NeRF-sim crashes where the world would not):",
        g.points,
        num(nerfsv_study::calibration::geometry::NEAR_M, 2),
        g.near_points,
        g.ground_points,
        num(100.0 * g.tight_pass_fraction, 0),
        num(g.gt_min_distance_m * 1e3, 1),
    ));
    let mm = |v: f64| num(v * 1e3, 1);
    let or_dash = |v: Option<f64>| v.map_or_else(|| "–".to_string(), mm);
    s.table(
        Table::new(&[
            "field",
            "least distance from the path (mm)",
            "error at the tight pass (mm)",
            "mean error beside obstacles (mm)",
            "least / greatest (mm)",
            "mean error above the ground (mm)",
        ])
        .row(vec!["ground truth".into(), mm(g.gt_min_distance_m), "0".into(), "0".into(), String::new(), "0".into()])
        .rows(g.fields.iter().map(|r| {
            vec![
                r.field.clone(),
                mm(r.min_distance_m),
                mm(r.error_at_tight_pass_m),
                or_dash(r.near_mean_error_m),
                format!("{} / {}", or_dash(r.near_min_error_m), or_dash(r.near_max_error_m)),
                or_dash(r.ground_mean_error_m),
            ]
        })),
    );
}
