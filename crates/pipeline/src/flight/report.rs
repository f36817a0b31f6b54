//! The nominal flights' section of the report (the stage drew the pictures it names).
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use std::path::Path;

use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_study::flight::{estimate_error_png, ESTIMATE_ERRORS, FIELDS_PNG};

use crate::flight::{FlightStage, FlightStageFigures};
use crate::report::{num, world_label, yes_no, Section, Table};
use crate::{Report, ReportContext, Stage};

impl Report for FlightStage<'_> {
    const ABOUT: &'static str = "nominal flights in both worlds";

    fn describe(f: &FlightStageFigures) -> String {
        let mut s = format!("path {:.2} m", f.path_length_m);
        for fl in &f.flights {
            s.push_str("\n    ");
            s.push_str(&fl.describe());
        }
        s
    }

    fn report(f: &FlightStageFigures, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new(FlightStage::NAME, "Nominal flights", "nominal flights");
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
        // The vision flights the stage flew: their trajectories, then their estimate errors.
        let flown = |world: WorldKind| {
            f.flights.iter().any(|x| x.world == world && x.estimator == EstimatorKind::Vision).then_some(world)
        };
        let vision: Vec<WorldKind> = [WorldKind::Gt, WorldKind::Nerf].into_iter().filter_map(flown).collect();
        let png = |world: WorldKind| FlightStage::output(world, EstimatorKind::Vision, "png");
        for &world in &vision {
            s.picture(&png(world), &format!("Nominal flight in {}-sim, vision estimator", world_label(world)));
        }
        for &world in &vision {
            // GT-sim's position and attitude errors; NeRF-sim's position error.
            let shown = if world == WorldKind::Gt { &ESTIMATE_ERRORS[..] } else { &ESTIMATE_ERRORS[..1] };
            for what in shown {
                let file = estimate_error_png(Path::new(&png(world)), what);
                s.picture(
                    &file.to_string_lossy(),
                    &format!(
                        "{}-sim, vision estimator: {what} error of the estimate and the filter's 2σ",
                        world_label(world)
                    ),
                );
            }
        }
        if f.field_slices {
            s.picture(FIELDS_PNG, "Signed distance at flight altitude: ground truth, NeRF, and their difference");
        }
        Some(s)
    }
}
