//! The online stage's section of the report (the paper's Tables 1–2).
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use crate::online::{OnlineFigures, OnlineStage};
use crate::report::{esc, num, pct, proportion, step_auroc_with_interval, yes_no, Section, Table};
use crate::{Report, ReportContext, Stage};

impl Report for OnlineStage<'_> {
    const ABOUT: &'static str = "per-step uncertainty and the rewards (Tables 1–2)";

    fn describe(f: &OnlineFigures) -> String {
        f.describe()
    }

    fn report(f: &OnlineFigures, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new(
            OnlineStage::NAME,
            "Tables 1–2: uncertainty in the search, with and without reward",
            "Tables 1–2",
        );
        if !f.step_auroc.is_empty() {
            s.answer(50, step_auroc_answer(f));
        } else if !f.studies.is_empty() {
            let parts: Vec<String> = f
                .studies
                .iter()
                .map(|m| {
                    let per: Vec<String> = m.per_sampler.iter().map(step_auroc_with_interval).collect();
                    format!("{} {}", esc(&m.method.name().to_uppercase()), per.join(", "))
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
        baselines_table(&mut s, f);
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

/// A measure's name as the table shows it.
fn measure_label(measure: &str) -> String {
    match measure {
        nerfsv_validation::STEP_INDEX => "step index (baseline)".to_owned(),
        nerfsv_validation::CLEARANCE => "NeRF-sim's clearance (baseline)".to_owned(),
        "ga" | "bla" => format!("{} (exact: needs the ground truth's render)", measure.to_uppercase()),
        "ga-paper" => "GA, the paper's σ_d without the noise floor (exact)".to_owned(),
        "ga-floored" => "GA, the noise-floored σ_d (exact)".to_owned(),
        "ensemble" => "ensemble spread".to_owned(),
        other => other.to_owned(),
    }
}

fn with_interval(a: &nerfsv_validation::AurocInterval) -> String {
    let ci = a.ci95.map_or(String::new(), |[lo, hi]| format!(" [{lo:.2}, {hi:.2}]"));
    format!("{}{ci}", num(a.auroc, 2))
}

fn p_value(p: Option<f64>) -> String {
    match p {
        None => "–".to_owned(),
        Some(p) if p < 0.001 => "< 0.001".to_owned(),
        Some(p) => format!("{p:.3}"),
    }
}

/// The section's answer in words: which measure, if any, adds to NeRF-sim's clearance.
fn step_auroc_answer(f: &OnlineFigures) -> String {
    use nerfsv_validation::{CLEARANCE, STEP_INDEX};
    let measures = f.step_auroc.iter().filter(|r| r.measure != CLEARANCE && r.measure != STEP_INDEX);
    let beats: Vec<String> = measures
        .clone()
        .filter(|r| {
            r.holm_p.is_some_and(|p| p < 0.05)
                && matches!((r.stratified.auroc, r.clearance_stratified), (Some(a), Some(c)) if a > c)
        })
        .map(|r| format!("{} ({})", measure_label(&r.measure), r.sampler.name().to_uppercase()))
        .collect();
    let clearance: Vec<String> = f
        .step_auroc
        .iter()
        .filter(|r| r.measure == CLEARANCE)
        .map(|r| match r.stratified.auroc {
            Some(_) => format!("{} {}", r.sampler.name().to_uppercase(), with_interval(&r.stratified)),
            // No step of its studied rollouts disagrees, so no AUROC is defined.
            None => format!("{} – (no disagreeing step among its {} steps)", r.sampler.name().to_uppercase(), r.steps),
        })
        .collect();
    let best = measures
        .filter_map(|r| r.stratified.auroc.map(|a| (a, r)))
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, r)| {
            format!(
                "; the best measure, {} on {}, scores {}",
                measure_label(&r.measure),
                r.sampler.name().to_uppercase(),
                with_interval(&r.stratified)
            )
        })
        .unwrap_or_default();
    let verdict = if beats.is_empty() {
        "No uncertainty measure adds to a baseline that needs none".to_owned()
    } else {
        format!("Better than NeRF-sim's own clearance (Holm p &lt; 0.05): {}", esc(&beats.join(", ")))
    };
    format!(
        "<b>Does the uncertainty flag where NeRF-sim and GT-sim disagree?</b> {verdict}: NeRF-sim's own clearance \
         at the step scores a matched AUROC of {}{} (0.5 is chance, and a measure of the step index alone).",
        clearance.join(", "),
        esc(&best)
    )
}

/// Each measure against the two baselines, as a table (nothing without rows).
fn baselines_table(s: &mut Section, f: &OnlineFigures) {
    if f.step_auroc.is_empty() {
        return;
    }
    s.html("<h3>Each measure against two baselines that need no uncertainty</h3>\n".to_owned());
    s.paragraph(
        "A step is positive when one world touched geometry during it and the other did not. <em>Pooled</em>: \
                 the AUROC over all steps; <em>matched</em>: the probability that a disagreeing step outscores an \
                 agreeing step of the same index (ties ½), so that a measure knowing only where along the route the \
                 drone is scores 0.5. Baselines: the step index, and NeRF-sim's own clearance at the step (lower \
                 scoring higher). Intervals: 95 % from 2000 bootstraps over rollouts. DeLong: the paired test of the \
                 matched AUROC against the clearance's on the same steps; Holm: adjusted over every test of the \
                 table. GA and BLA run in exact mode: they need the ground truth's render of the view, so they \
                 cannot run on a real drone; the ensemble's spread needs only the NeRFs. GA's other σ_d stands \
                 beside the configured one: the noise floor (uq.noise_std) zeroes the floored σ_d on every view whose \
                 colour error is below it, which on the drone's views is about half of them.",
    );
    s.table(
        Table::new(&[
            "sampler",
            "measure",
            "steps (disagreeing)",
            "pooled AUROC",
            "matched AUROC",
            "clearance, same steps",
            "DeLong p",
            "Holm p",
        ])
        .rows(f.step_auroc.iter().map(|r| {
            vec![
                r.sampler.name().to_uppercase(),
                measure_label(&r.measure),
                format!("{} ({})", r.steps, r.disagreeing_steps),
                with_interval(&r.pooled),
                with_interval(&r.stratified),
                num(r.clearance_stratified, 2),
                p_value(r.delong_p_vs_clearance),
                p_value(r.holm_p),
            ]
        })),
    );
}
