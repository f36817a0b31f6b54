//! The stress stage's section of the report: the study's answer, the transfer table, the
//! samplers' figures and the clearance differences drawn.
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use nerfsv_study::stress::{
    most_likely_failure_png, most_likely_failure_view, other_world, Sampler, SamplerFigures, StressFigures,
    TransferFigures, CLEARANCE_PNG, ESTIMATE_ERRORS_PNG,
};

use crate::report::{esc, estimate, mm, num, pct, proportion, rate_ci, world_label, Section, Table};
use crate::stress::StressStage;
use crate::{Report, ReportContext, Stage};

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
    let mut table = Table::new(&[
        "world",
        "MC crashes",
        "crash rate [95 %]",
        "only NeRF / only GT",
        "McNemar exact p",
        "precision",
        "recall",
        "Matthews correlation",
        "accuracy",
    ]);
    if let (Some(r), Some(x)) = (&t.nerf_calibrated, &t.calibrated) {
        let rate =
            nerfsv_study::stress::RateFigure { rate: r.rate, ci95: r.ci95, failures: r.failures, rollouts: r.rollouts };
        table = table.row(world("NeRF-sim, calibrated world", &rate, Some(x)));
    }
    table
        .row(world("NeRF-sim, the ensemble as the world", &t.nerf_ensemble, Some(&t.ensemble)))
        .row(world("NeRF-sim, deployed NeRF as the world", &t.nerf_deployed, Some(&t.deployed)))
        .row(world("GT-sim", &t.gt, None))
}

/// Of each replayed search's NeRF-sim failures, how many crash in GT-sim too.
fn searched_precision(f: &StressFigures) -> Table {
    Table::new(&["sampler", "NeRF-sim failures replayed", "crash in GT-sim too", "precision [95 %]"]).rows(
        f.samplers.iter().filter_map(|x| {
            let t = &x.confusion.as_ref()?.trajectories;
            Some(vec![
                x.sampler.name().to_uppercase(),
                t.nerf_failures().to_string(),
                t.true_positive.to_string(),
                proportion(t.true_positive, t.nerf_failures()),
            ])
        }),
    )
}

/// The study's answer from the stress stage: how likely the drone fails under the disturbance
/// prior (subset simulation's estimate where the stage ran it, else Monte Carlo's), how
/// NeRF-sim's failures carry over to GT-sim, and the most likely failure.
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
                    "; Monte Carlo alone: {} [{}, {}] ({} rollouts)",
                    num(mc.p_fail, 3),
                    num(mc.p_fail_interval.0, 3),
                    num(mc.p_fail_interval.1, 3),
                    mc.rollouts
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

    fn describe(f: &StressFigures) -> String {
        f.describe()
    }

    fn report(f: &StressFigures, _: &ReportContext) -> Option<Section> {
        let title = match f.replay_world {
            Some(_) => "Stress tests: failure probability and NeRF-sim against GT-sim",
            None => "Stress tests: failure probability (nothing replayed in another world)",
        };
        let mut s = Section::new(StressStage::NAME, title, "stress tests");
        stress_answer(&mut s, f);
        if let Some(t) = &f.transfer {
            transfer_part(&mut s, t);
        }
        if f.samplers.iter().any(|x| x.confusion.is_some() && x.sampler != Sampler::Mc) {
            s.paragraph(
                "Searched failures replayed: of each search's NeRF-sim failures, how many crash in GT-sim with the same \
                 disturbances (subset simulation's rollouts are not replayed).",
            );
            s.table(searched_precision(f));
        }
        sampler_tables(&mut s, f);
        confusion_table(&mut s, f);
        estimator_errors_and_failures(&mut s, f);
        if f.clearance_drawn {
            s.picture(CLEARANCE_PNG, "|clearance in NeRF-sim − in GT-sim| on the same disturbances");
        }
        s.csv(nerfsv_study::stress::TABLE_CSV, "stress_table.csv");
        Some(s)
    }
}

/// The transfer table and the ensemble's step AUROC per sampler.
fn transfer_part(s: &mut Section, t: &TransferFigures) {
    let table = transfer_table(t);
    s.answer(
        5,
        format!(
            "<b>Do failures found in a NeRF predict failures in the world?</b> The same {} Monte Carlo rollouts \
             (disturbances and seeds) in each NeRF-sim world and in GT-sim: {}the ensemble's other members as the \
             world, and the deployed NeRF as the world; each NeRF world against GT-sim, failure positive, 95 % \
             intervals (rates and proportions Wilson, correlation bootstrap over rollouts){}:\n{}",
            t.gt.rollouts,
            if t.nerf_calibrated.is_some() {
                "the calibrated world (the ensemble's members, each rollout's camera images displaced by a draw of the \
                 perception error model measured on calibration views), "
            } else {
                ""
            },
            if let Some(c) = &t.nerf_calibrated {
                format!(
                    "; the calibrated world's 95 % predictive interval, the rate of one world (a member and one error \
                     function) drawn like its {} worlds (a beta-binomial over them), is [{}, {}], and GT-sim's rate \
                     lies {} it",
                    c.worlds,
                    pct(c.predictive95[0]),
                    pct(c.predictive95[1]),
                    if (c.predictive95[0]..=c.predictive95[1]).contains(&t.gt.rate) { "inside" } else { "outside" }
                )
            } else {
                String::new()
            },
            table.html()
        ),
    );
    s.paragraph("The transfer table: the Monte Carlo rollouts in each NeRF world against GT-sim.");
    s.table(table);
    if !t.step_auroc.is_empty() {
        s.paragraph(
            "How well the ensemble's uncertainty of the drone's view at each step (the mean density-aware \
             spread of its NeRFs' renders of the view's rays, measured at the step's recorded pose, no \
             ground-truth image) predicts the steps where NeRF-sim and GT-sim disagree (one touched geometry, \
             the other not); per sampler, the step AUROC's interval from a bootstrap over rollouts:",
        );
        s.table(
            Table::new(&["sampler", "NeRF world", "steps", "disagreeing", "step AUROC [95 %]", "rollout AUROC"]).rows(
                t.step_auroc.iter().map(|a| {
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
                }),
            ),
        );
    }
}

/// Each sampler's rates and failure probability, and how its estimate was made.
fn sampler_tables(s: &mut Section, f: &StressFigures) {
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
         neither passes nor failures. The CEM moves its proposal along one line by default (stress.cem.update = \
         line): the direction in which a ridge regression of the clearance on all its rollouts so far falls \
         fastest, by the cross-entropy optimum along it, with the prior's covariance kept, so that its weights do \
         not spread over the 72 dimensions the paper's refit of every mean and variance moves (update = elites). \
         Its P(fail) is the importance-sampling estimate of its last batch with the weight as \
         control variate (its expectation under the proposal is 1), clamped to [0, 1]; the paper's plain estimate \
         (1/N) Σ 𝟙·p/q, unbiased but able to exceed 1, stands beside it. Effective rollouts and failures are \
         Kish's sizes (Σw)²/Σw² of the batch's and of the failures' weights: the number of rollouts the \
         estimate effectively rests on. SUBSET is subset simulation (Au & Beck): level 0 is independent draws \
         from the prior (the MC rollouts, then its own), each next level Markov chains held below the last \
         level's p0-quantile of the clearance (10 % by default); P(fail) is the product of the levels' shares, its \
         SE Au & Beck's bound from the chains' correlation, and its effective rollouts the Monte Carlo rollouts \
         with the same variance. Both estimators' ±2 SE intervals cover the truth at 10⁻³ and 0.08 in at least \
         90 % of runs on a 72-dimensional linear test problem with these settings (BENCHMARKS.md; the CEM's only \
         while the disturbances decide the outcome: where the rollout's seed decides part of it, noise half the \
         size of the disturbances' effect, the CEM is less precise than Monte Carlo at 0.08 and subset \
         simulation is the one to trust); their rollouts are driven towards failure, so their collision rate is not a rate of anything.",
    );
}

/// NeRF-sim against GT-sim over each search's rollouts.
fn confusion_table(s: &mut Section, f: &StressFigures) {
    let name = |x: &SamplerFigures| x.sampler.name().to_uppercase();
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
}

/// The estimator's errors after its image updates, their histograms and the most likely
/// failures' flights.
fn estimator_errors_and_failures(s: &mut Section, f: &StressFigures) {
    if !f.estimate_errors.is_empty() {
        s.paragraph(
            "The vision estimator's error after each image update, over every rollout the stage flew (the \
             searches in NeRF-sim and their replays in GT-sim), and what its filter did with the images: the \
             share whose normalised innovation squared (NIS) exceeds χ²₆'s 95th percentile (5 % for a filter whose \
             covariance is right; more means it is overconfident, fewer that it is too cautious), the images the \
             innovation gate refused, the fits lost (too little of the image explained), the relocalisations and \
             those the next image undid (a relocalised fit is taken whatever its innovation, so the image after it \
             must pass the gate, or the belief returns to the one it replaced), and the renders each image's fit \
             took. Each rollout's image log lies beside its journal entry \
             (stress/journal/, the files ending in .images.csv).",
        );
        s.table(
            Table::new(&[
                "world",
                "images",
                "position error median / p90 (mm)",
                "attitude error median / p90 (°)",
                "NIS > χ²₆(0.95)",
                "median NIS",
                "refused by the gate / lost / relocalised (undone)",
                "renders per image",
            ])
            .rows(f.estimate_errors.iter().map(|e| {
                vec![
                    format!("{}-sim", e.world.name()),
                    e.images.to_string(),
                    format!("{} / {}", mm(e.median_position_m), mm(e.p90_position_m)),
                    format!("{} / {}", num(e.median_attitude_deg, 2), num(e.p90_attitude_deg, 2)),
                    format!("{:.1} %", 100.0 * e.nis_above_chi2_95 as f64 / e.images as f64),
                    num(e.median_nis, 2),
                    format!("{} / {} / {} ({})", e.refused_by_gate, e.lost, e.relocalised, e.relocalisations_undone),
                    num(e.mean_renders, 2),
                ]
            })),
        );
        s.picture(ESTIMATE_ERRORS_PNG, "The vision estimator's position error after each image, both worlds");
    }
    // The most likely failures the searches found, flown in their world and replayed.
    for sf in f.samplers.iter().filter(|sf| matches!(sf.sampler, Sampler::Mc | Sampler::Cem)) {
        let Some(failure) = &sf.most_likely_failure else { continue };
        let name = sf.sampler.name().to_uppercase();
        let png = |world| most_likely_failure_png(sf.sampler, world);
        s.picture(&png(sf.world), &format!("{name}'s most likely failure in {}-sim", world_label(sf.world)));
        let replayed = failure.replay_collided.is_some();
        if replayed {
            let other = other_world(sf.world);
            s.picture(&png(other), &format!("The same disturbances in {}-sim", world_label(other)));
        }
        let worlds = if replayed {
            format!("in {}-sim (left) and {}-sim (right)", world_label(sf.world), world_label(other_world(sf.world)))
        } else {
            format!("in {}-sim", world_label(sf.world))
        };
        s.picture(
            &most_likely_failure_view(sf.sampler),
            &format!(
                "What the drone's camera saw along {name}'s most likely failure {worlds}, in real time: + where the \
                 camera aims, × where the estimate believes it aims, a red frame once it has crashed"
            ),
        );
    }
}
