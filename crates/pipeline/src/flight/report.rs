//! The nominal flights' section of the report, with both collision fields drawn.
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use std::path::Path;

use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_study::flight::{estimate_error_png, ESTIMATE_ERRORS};

use crate::flight::{FlightStage, FlightStageFigures};
use crate::report::{draw, num, world_label, yes_no, Section, Table};
use crate::stages::{GroundTruthField, NerfField};
use crate::{Report, ReportContext, Stage};

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

    fn describe(f: &FlightStageFigures) -> String {
        let mut s = format!("path {:.2} m", f.path_length_m);
        for fl in &f.flights {
            s.push_str("\n    ");
            s.push_str(&fl.describe());
        }
        s
    }

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
        // Both collision fields at the planned path's mean altitude.
        let z = if f.waypoints.is_empty() {
            0.18
        } else {
            f.waypoints.iter().map(|w| w[2]).sum::<f64>() / f.waypoints.len() as f64
        };
        if draw(cx.dir, FIELDS_PNG, field_slices_figure(cx.root, z)) {
            s.picture(FIELDS_PNG, "Signed distance at flight altitude: ground truth, NeRF, and their difference");
        }
        Some(s)
    }
}
