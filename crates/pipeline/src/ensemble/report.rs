//! The ensemble stage's section of the report.
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use crate::ensemble::{EnsembleFigures, EnsembleStage};
use crate::report::{num, Section, Table};
use crate::{Report, ReportContext, Stage};

impl Report for crate::ensemble::EnsembleStage<'_> {
    const ABOUT: &'static str = "the ensemble's other NeRFs and their collision fields";

    fn describe(f: &EnsembleFigures) -> String {
        if f.trained.is_empty() {
            return "one member, the deployed model: no other trained".into();
        }
        let psnr: Vec<String> = f.trained.iter().map(|m| format!("{:.2}", m.test_psnr)).collect();
        let deployed =
            f.deployed_test_psnr.map_or(String::new(), |p| format!("; the deployed model {p:.2} dB on the same views"));
        format!("{} more members of {} steps (test PSNR {} dB{deployed})", f.trained.len(), f.steps, psnr.join(", "))
    }

    fn report(f: &crate::ensemble::EnsembleFigures, _: &ReportContext) -> Option<Section> {
        if f.trained.is_empty() {
            return None;
        }
        let mut s =
            Section::new(EnsembleStage::NAME, "The ensemble: the NeRFs the same data could have given", "ensemble");
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
        if let Some(p) = f.deployed_test_psnr {
            s.paragraph(format!(
                "The deployed model (member 0) scores {} dB on the same {} test views.",
                num(p, 2),
                crate::ensemble::EnsembleStage::EVAL_VIEWS
            ));
        }
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
