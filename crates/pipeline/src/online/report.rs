//! The online stage's section of the report (the paper's Tables 1–2).
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use crate::online::{OnlineFigures, OnlineStage};
use crate::report::{esc, num, pct, proportion, step_auroc_with_interval, yes_no, Section, Table};
use crate::{Report, ReportContext};

impl Report for OnlineStage<'_> {
    const ABOUT: &'static str = "per-step uncertainty and the rewards (Tables 1–2)";

    fn describe(f: &OnlineFigures) -> String {
        f.describe()
    }

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
