//! Whether a per-step measure predicts where NeRF-sim and GT-sim disagree *beyond what needs no
//! uncertainty at all*: each measure's step AUROC pooled over steps and matched by step index,
//! beside two baselines (the step index itself and NeRF-sim's own clearance at the step), with a
//! paired DeLong test against the clearance and Holm's adjustment across the family.
//!
//! Why matched: where the route passes an obstacle, both the disagreements and most measures
//! rise, so a pooled AUROC can score a measure that only knows *which* step it is. The matched
//! (stratified) AUROC is the probability that a disagreeing step outscores an agreeing step *of
//! the same index*, ties counting one half: Σ_s U_s / Σ_s P_s·N_s over step indices `s` with
//! `P_s` disagreeing and `N_s` agreeing steps and `U_s` their Mann–Whitney count. A measure that
//! depends on the step index alone scores exactly one half.
//!
//! The paired test is DeLong, DeLong & Clarke-Pearson (1988) on the matched AUROC: each stratum's
//! structural components (a positive's share of negatives it outscores, and the reverse) for both
//! measures on the same steps; the variance of the difference is Σ_s w_s²·(S_D,s/P_s + S_E,s/N_s)
//! with w_s = P_s·N_s / Σ P·N and S the within-stratum variances of the components'
//! differences (a stratum with one positive or negative takes the pooled within-stratum
//! variance). With one stratum it is the usual DeLong test.

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::label::Label;
use crate::online::{auroc, with_replays};
use crate::record::RolloutRecord;

/// The name of the step-index baseline in [`StepAurocRow::measure`].
pub const STEP_INDEX: &str = "step_index";
/// The name of the clearance baseline (NeRF-sim's own minimum clearance at the step, lower
/// scoring higher) in [`StepAurocRow::measure`].
pub const CLEARANCE: &str = "clearance";

/// An AUROC with its 95 % percentile interval from a bootstrap over rollouts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AurocInterval {
    /// `None` without both classes.
    pub auroc: Option<f64>,
    /// `None` when fewer than half of the resamples have both classes.
    pub ci95: Option<[f64; 2]>,
}

/// One measure's step AUROC for one sampler's rollouts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepAurocRow {
    /// The measure: a method's name, or [`STEP_INDEX`] or [`CLEARANCE`].
    pub measure: String,
    pub sampler: Label,
    /// Steps flown in both worlds with a finite value of the measure.
    pub steps: usize,
    /// Of those, steps where one world touched geometry and the other did not.
    pub disagreeing_steps: usize,
    /// Over all steps together.
    pub pooled: AurocInterval,
    /// Matched by step index (see the [module docs](self)).
    pub stratified: AurocInterval,
    /// The clearance baseline's matched AUROC on the same steps (what the paired test compares).
    pub clearance_stratified: Option<f64>,
    /// Two-sided p of the paired DeLong test of the matched AUROC against the clearance's on the
    /// same steps; `None` for the clearance itself, or without a variance.
    pub delong_p_vs_clearance: Option<f64>,
    /// `delong_p_vs_clearance` after Holm's step-down adjustment over every row of the table
    /// that has one.
    pub holm_p: Option<f64>,
}

/// A step flown in both worlds.
#[derive(Clone, Copy, Debug)]
struct Step {
    /// Which of the paired rollouts (an index into the caller's list).
    rollout: usize,
    /// The step's index along the rollout: the stratum.
    index: usize,
    disagree: bool,
    /// NeRF-sim's minimum clearance during the step.
    clearance: f64,
    /// The measure's value (non-finite where it was not measured).
    value: f64,
}

/// The steps of `nerf`'s rollouts (with `step_uncertainty` as the measure) flown in both worlds,
/// paired with their GT-sim replays by (sampler, population, index) and seed.
fn paired_steps(nerf: &[&RolloutRecord], gt: &[RolloutRecord]) -> Vec<Step> {
    let mut steps = Vec::new();
    for (rollout, (r, g)) in with_replays(nerf.iter().copied(), gt).enumerate() {
        for (index, (&a, &b)) in r.step_scores.iter().zip(&g.step_scores).enumerate() {
            if a.is_nan() || b.is_nan() {
                continue;
            }
            let value = r.step_uncertainty.get(index).copied().unwrap_or(f64::NAN);
            steps.push(Step { rollout, index, disagree: (a <= 0.0) != (b <= 0.0), clearance: a, value });
        }
    }
    steps
}

/// The matched AUROC of `scores` for `labels` within `strata` (see the [module docs](self));
/// `None` when no stratum holds both classes.
pub fn stratified_auroc(scores: &[f64], labels: &[bool], strata: &[usize]) -> Option<f64> {
    let (mut u, mut pairs) = (0.0, 0.0);
    for (s, l) in group(scores, labels, strata).into_values() {
        let p = l.iter().filter(|&&l| l).count() as f64;
        let n = l.len() as f64 - p;
        if let Some(a) = auroc(&s, &l) {
            u += a * p * n;
            pairs += p * n;
        }
    }
    (pairs > 0.0).then(|| u / pairs)
}

/// Scores and labels by stratum.
fn group(scores: &[f64], labels: &[bool], strata: &[usize]) -> BTreeMap<usize, (Vec<f64>, Vec<bool>)> {
    assert!(scores.len() == labels.len() && labels.len() == strata.len(), "one label and stratum per score");
    let mut groups: BTreeMap<usize, (Vec<f64>, Vec<bool>)> = BTreeMap::new();
    for ((&s, &l), &k) in scores.iter().zip(labels).zip(strata) {
        let g = groups.entry(k).or_default();
        g.0.push(s);
        g.1.push(l);
    }
    groups
}

/// The paired DeLong test of two measures' matched AUROCs on the same steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeLong {
    pub auroc_a: f64,
    pub auroc_b: f64,
    /// Standard error of `auroc_a − auroc_b`.
    pub se: f64,
    /// Two-sided p of `auroc_a = auroc_b`.
    pub p: f64,
}

/// The paired DeLong test of `a`'s matched AUROC against `b`'s (same steps, `labels`, `strata`;
/// see the [module docs](self)). `None` when no stratum has both classes, or the difference has
/// no variance while the AUROCs differ.
pub fn delong_paired(a: &[f64], b: &[f64], labels: &[bool], strata: &[usize]) -> Option<DeLong> {
    assert_eq!(a.len(), b.len(), "two measures of the same steps");
    let psi = |x: f64, y: f64| match x.total_cmp(&y) {
        std::cmp::Ordering::Greater => 1.0,
        std::cmp::Ordering::Equal => 0.5,
        std::cmp::Ordering::Less => 0.0,
    };
    let index: Vec<usize> = (0..a.len()).collect();
    let as_f64: Vec<f64> = index.iter().map(|&i| i as f64).collect();
    // Per stratum: its pair count, both AUROCs, and the components' differences.
    struct Stratum {
        pairs: f64,
        auroc: [f64; 2],
        d: Vec<f64>,
        e: Vec<f64>,
    }
    let mut strata_out = Vec::new();
    for (_, (ids, l)) in group(&as_f64, labels, strata) {
        let pos: Vec<usize> = ids.iter().zip(&l).filter(|(_, &l)| l).map(|(&i, _)| i as usize).collect();
        let neg: Vec<usize> = ids.iter().zip(&l).filter(|(_, &l)| !l).map(|(&i, _)| i as usize).collect();
        if pos.is_empty() || neg.is_empty() {
            continue;
        }
        let (np, nn) = (pos.len() as f64, neg.len() as f64);
        let v10 = |m: &[f64], i: usize| neg.iter().map(|&j| psi(m[i], m[j])).sum::<f64>() / nn;
        let v01 = |m: &[f64], j: usize| pos.iter().map(|&i| psi(m[i], m[j])).sum::<f64>() / np;
        let d: Vec<f64> = pos.iter().map(|&i| v10(a, i) - v10(b, i)).collect();
        let e: Vec<f64> = neg.iter().map(|&j| v01(a, j) - v01(b, j)).collect();
        let auroc_of = |m: &[f64]| pos.iter().map(|&i| v10(m, i)).sum::<f64>() / np;
        strata_out.push(Stratum { pairs: np * nn, auroc: [auroc_of(a), auroc_of(b)], d, e });
    }
    let total: f64 = strata_out.iter().map(|s| s.pairs).sum();
    if total == 0.0 {
        return None;
    }
    // Within-stratum sums of squares, and their pooled variance for strata of one.
    let ss = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - m) * (x - m)).sum::<f64>()
    };
    let pooled = |pick: fn(&Stratum) -> &Vec<f64>| {
        let (num, dof) = strata_out
            .iter()
            .map(pick)
            .filter(|v| v.len() > 1)
            .fold((0.0, 0.0), |(n, d), v| (n + ss(v), d + (v.len() - 1) as f64));
        if dof > 0.0 {
            num / dof
        } else {
            0.0
        }
    };
    let (pooled_d, pooled_e) = (pooled(|s| &s.d), pooled(|s| &s.e));
    let variance_of = |v: &[f64], pooled: f64| if v.len() > 1 { ss(v) / (v.len() - 1) as f64 } else { pooled };
    let (mut auroc_a, mut auroc_b, mut var) = (0.0, 0.0, 0.0);
    for s in &strata_out {
        let w = s.pairs / total;
        auroc_a += w * s.auroc[0];
        auroc_b += w * s.auroc[1];
        var +=
            w * w * (variance_of(&s.d, pooled_d) / s.d.len() as f64 + variance_of(&s.e, pooled_e) / s.e.len() as f64);
    }
    let diff = auroc_a - auroc_b;
    let se = var.sqrt();
    let p = if se > 0.0 {
        nerfsv_scene::stats::normal_two_sided_p(diff / se)
    } else if diff.abs() < 1e-12 {
        1.0
    } else {
        return None;
    };
    Some(DeLong { auroc_a, auroc_b, se, p })
}

/// Holm's step-down adjustment of a family of p-values (those present; `None` stays `None`):
/// the `k`-th smallest of `m` becomes max over the first `k` of min(1, (m − j + 1)·p_(j)).
pub fn holm(p: &[Option<f64>]) -> Vec<Option<f64>> {
    let mut order: Vec<usize> = (0..p.len()).filter(|&i| p[i].is_some()).collect();
    order.sort_by(|&i, &j| p[i].unwrap_or(1.0).total_cmp(&p[j].unwrap_or(1.0)));
    let m = order.len();
    let mut adjusted = vec![None; p.len()];
    let mut running: f64 = 0.0;
    for (k, &i) in order.iter().enumerate() {
        running = running.max(((m - k) as f64 * p[i].unwrap_or(1.0)).min(1.0));
        adjusted[i] = Some(running);
    }
    adjusted
}

/// The pooled and matched AUROCs of `score` over `steps`, each with its bootstrap interval over
/// rollouts (`resamples`, seeded by `seed`).
fn scored(steps: &[Step], score: impl Fn(&Step) -> f64, resamples: usize, seed: u64) -> [AurocInterval; 2] {
    use rand::{RngExt, SeedableRng};
    let columns = |steps: &mut dyn Iterator<Item = &Step>| {
        let (mut s, mut l, mut k) = (Vec::new(), Vec::new(), Vec::new());
        for st in steps {
            s.push(score(st));
            l.push(st.disagree);
            k.push(st.index);
        }
        (s, l, k)
    };
    let (s, l, k) = columns(&mut steps.iter());
    let point = [auroc(&s, &l), stratified_auroc(&s, &l, &k)];
    // Whole rollouts are resampled: a rollout's steps are not independent.
    let mut by_rollout: BTreeMap<usize, Vec<Step>> = BTreeMap::new();
    for st in steps {
        by_rollout.entry(st.rollout).or_default().push(*st);
    }
    let rollouts: Vec<Vec<Step>> = by_rollout.into_values().collect();
    let mut values = [Vec::with_capacity(resamples), Vec::with_capacity(resamples)];
    if !rollouts.is_empty() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        for _ in 0..resamples {
            let picks: Vec<usize> = (0..rollouts.len()).map(|_| rng.random_range(0..rollouts.len())).collect();
            let (s, l, k) = columns(&mut picks.iter().flat_map(|&i| &rollouts[i]));
            if let Some(a) = auroc(&s, &l) {
                values[0].push(a);
            }
            if let Some(a) = stratified_auroc(&s, &l, &k) {
                values[1].push(a);
            }
        }
    }
    let interval = |mut v: Vec<f64>| {
        if v.is_empty() || v.len() * 2 < resamples {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let at = |q| nerfsv_scene::stats::quantile_sorted(&v, q);
        Some([at(0.025), at(0.975)])
    };
    let [pooled, stratified] = values;
    [
        AurocInterval { auroc: point[0], ci95: interval(pooled) },
        AurocInterval { auroc: point[1], ci95: interval(stratified) },
    ]
}

/// One measure to score: its name and NeRF-sim rollouts whose `step_uncertainty` holds it.
#[derive(Clone, Copy, Debug)]
pub struct Measured<'a> {
    pub measure: &'a str,
    pub rollouts: &'a [RolloutRecord],
}

/// The online study's step AUROC table: per sampler of `samplers`, the two baselines
/// ([`STEP_INDEX`], [`CLEARANCE`], scored on every step the first measure's rollouts flew in both
/// worlds) and each measure, every row pooled and matched with bootstrap intervals (`resamples`,
/// seeded by `seed`), tested against the clearance on its own steps, and Holm-adjusted across
/// all rows with a test. `gt` holds the GT-sim replays of the measures' rollouts.
pub fn step_auroc_table(
    measures: &[Measured],
    gt: &[RolloutRecord],
    samplers: &[Label],
    resamples: usize,
    seed: u64,
) -> Vec<StepAurocRow> {
    // (measure, sampler, its steps, how a step scores)
    type Score = fn(&Step) -> f64;
    let mut jobs: Vec<(String, Label, Vec<Step>, Score)> = Vec::new();
    for &sampler in samplers {
        let of = |rollouts: &[RolloutRecord]| {
            let ours: Vec<&RolloutRecord> = rollouts.iter().filter(|r| r.sampler == sampler).collect();
            paired_steps(&ours, gt)
        };
        if let Some(first) = measures.first() {
            let all = of(first.rollouts);
            jobs.push((STEP_INDEX.to_owned(), sampler, all.clone(), |s| s.index as f64));
            jobs.push((CLEARANCE.to_owned(), sampler, all, |s| -s.clearance));
        }
        for m in measures {
            let steps: Vec<Step> = of(m.rollouts).into_iter().filter(|s| s.value.is_finite()).collect();
            jobs.push((m.measure.to_owned(), sampler, steps, |s| s.value));
        }
    }
    let mut rows: Vec<StepAurocRow> = jobs
        .into_par_iter()
        .map(|(measure, sampler, steps, score)| {
            let [pooled, stratified] = scored(&steps, score, resamples, seed);
            let labels: Vec<bool> = steps.iter().map(|s| s.disagree).collect();
            let strata: Vec<usize> = steps.iter().map(|s| s.index).collect();
            let clearance: Vec<f64> = steps.iter().map(|s| -s.clearance).collect();
            let clearance_stratified = stratified_auroc(&clearance, &labels, &strata);
            let delong_p_vs_clearance = (measure != CLEARANCE)
                .then(|| {
                    let values: Vec<f64> = steps.iter().map(score).collect();
                    delong_paired(&values, &clearance, &labels, &strata).map(|d| d.p)
                })
                .flatten();
            StepAurocRow {
                measure,
                sampler,
                steps: steps.len(),
                disagreeing_steps: labels.iter().filter(|&&l| l).count(),
                pooled,
                stratified,
                clearance_stratified,
                delong_p_vs_clearance,
                holm_p: None,
            }
        })
        .collect();
    let adjusted = holm(&rows.iter().map(|r| r.delong_p_vs_clearance).collect::<Vec<_>>());
    for (row, p) in rows.iter_mut().zip(adjusted) {
        row.holm_p = p;
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn the_matched_auroc_of_a_measure_of_the_step_index_alone_is_one_half() {
        // Disagreements concentrate at step 2; a measure that is the step's index (or any
        // function of it) scores high pooled and exactly one half matched.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut s, mut l, mut k) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..200 {
            for step in 0..5 {
                let p = if step == 2 { 0.4 } else { 0.03 };
                s.push(if step == 2 { 1.0 } else { 0.0 });
                l.push(rng.random::<f64>() < p);
                k.push(step);
            }
        }
        assert!(auroc(&s, &l).unwrap() > 0.8);
        assert_eq!(stratified_auroc(&s, &l, &k), Some(0.5));
    }

    #[test]
    fn the_matched_auroc_is_the_pair_share_within_strata() {
        // Stratum 0: positive 3 over negatives 1, 2 (2 of 2); stratum 1: positive 0 over
        // negative 5 (0 of 1), tie with 0 (½): (2 + 0 + 0.5) / (2 + 2).
        let s = [3.0, 1.0, 2.0, 0.0, 5.0, 0.0];
        let l = [true, false, false, true, false, false];
        let k = [0, 0, 0, 1, 1, 1];
        assert_eq!(stratified_auroc(&s, &l, &k), Some(2.5 / 4.0));
        // A stratum with one class only adds nothing.
        assert_eq!(stratified_auroc(&[1.0, 2.0], &[true, true], &[0, 0]), None);
    }

    #[test]
    fn delong_of_one_stratum_matches_the_closed_form_components() {
        // a: positives 0.9, 0.6; negatives 0.7, 0.2, 0.1. b: a constant (AUROC ½, no spread).
        let a = [0.9, 0.6, 0.7, 0.2, 0.1];
        let b = [0.0; 5];
        let l = [true, true, false, false, false];
        let d = delong_paired(&a, &b, &l, &[0; 5]).unwrap();
        // V10: 1, 2/3 → AUROC 5/6; V01: 1/2, 1, 1. Differences from b's ½ components: 1/2, 1/6
        // (variance 1/18) and 0, 1/2, 1/2 (variance 1/12): var = 1/36 + 1/36.
        assert!((d.auroc_a - 5.0 / 6.0).abs() < 1e-12);
        assert_eq!(d.auroc_b, 0.5);
        assert!((d.se - (2.0f64 / 36.0).sqrt()).abs() < 1e-12, "{}", d.se);
        let z = (5.0 / 6.0 - 0.5) / d.se;
        assert!((d.p - nerfsv_scene::stats::normal_two_sided_p(z)).abs() < 1e-15);
        // Identical measures: no difference, p = 1.
        assert_eq!(delong_paired(&a, &a, &l, &[0; 5]).unwrap().p, 1.0);
    }

    #[test]
    fn delong_holds_its_level_between_two_uninformative_measures_and_finds_a_real_difference() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (mut rejections, trials) = (0, 600);
        let mut powered = 0;
        for _ in 0..trials {
            let n = 150;
            let l: Vec<bool> = (0..n).map(|_| rng.random::<f64>() < 0.15).collect();
            let k: Vec<usize> = (0..n).map(|_| rng.random_range(0..4)).collect();
            let a: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
            let b: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
            if delong_paired(&a, &b, &l, &k).is_some_and(|d| d.p < 0.05) {
                rejections += 1;
            }
            let good: Vec<f64> = l.iter().map(|&l| if l { 1.0 } else { 0.0 } + rng.random::<f64>()).collect();
            if delong_paired(&good, &b, &l, &k).is_some_and(|d| d.p < 0.05) {
                powered += 1;
            }
        }
        let rate = rejections as f64 / trials as f64;
        assert!((0.02..=0.09).contains(&rate), "type I error {rate}");
        assert!(powered as f64 / trials as f64 > 0.95, "power {powered}/{trials}");
    }

    fn rollout(index: usize, nerf: &[f64], gt: &[f64], u: &[f64]) -> (RolloutRecord, RolloutRecord) {
        let r = RolloutRecord { sampler: Label::Mc, index, seed: index as u64, ..Default::default() };
        (
            RolloutRecord { step_scores: nerf.to_vec(), step_uncertainty: u.to_vec(), ..r.clone() },
            RolloutRecord { step_scores: gt.to_vec(), ..r },
        )
    }

    #[test]
    fn in_the_table_a_measure_of_the_step_index_alone_has_a_matched_interval_holding_one_half() {
        // GT-sim crashes at step 2 in a third of the rollouts (NeRF-sim never does); a measure
        // that is high at step 2 only scores well pooled and one half matched, and NeRF-sim's
        // clearance (its own, smallest at step 2 and smaller where GT-sim crashed) beats it.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (mut nerf, mut gt) = (Vec::new(), Vec::new());
        for i in 0..90 {
            let crash = rng.random::<f64>() < 0.35;
            let near = if crash { 0.02 } else { 0.05 } + 0.05 * rng.random::<f64>();
            let n = [0.5, 0.3, near, 0.4, 0.5];
            let g = [0.5, 0.3, if crash { -0.01 } else { 0.05 }, 0.4, 0.5];
            let u = [0.1, 0.1, 0.9, 0.1, 0.1];
            let (a, b) = rollout(i, &n, &g, &u);
            nerf.push(a);
            gt.push(b);
        }
        let rows = step_auroc_table(&[Measured { measure: "step-only", rollouts: &nerf }], &gt, &[Label::Mc], 500, 1);
        let row = |m: &str| rows.iter().find(|r| r.measure == m).unwrap();
        let measure = row("step-only");
        assert!(measure.pooled.auroc.unwrap() > 0.85);
        assert_eq!(measure.stratified.auroc, Some(0.5));
        let [lo, hi] = measure.stratified.ci95.unwrap();
        assert!(lo <= 0.5 && 0.5 <= hi, "[{lo}, {hi}]");
        assert_eq!(row(STEP_INDEX).stratified.auroc, Some(0.5));
        let clearance = row(CLEARANCE);
        assert!(clearance.stratified.auroc.unwrap() > 0.75);
        assert_eq!(clearance.delong_p_vs_clearance, None);
        assert!(measure.holm_p.unwrap() < 0.01 && measure.holm_p >= measure.delong_p_vs_clearance);
        assert_eq!(measure.steps, 450);
    }

    #[test]
    fn holm_adjusts_step_down_and_keeps_missing_values() {
        let p = [Some(0.01), Some(0.04), None, Some(0.03), Some(0.005)];
        let h = holm(&p);
        let want = [0.03, 0.06, f64::NAN, 0.06, 0.02];
        for (i, w) in want.iter().enumerate() {
            match h[i] {
                Some(v) => assert!((v - w).abs() < 1e-12, "{i}: {v} vs {w}"),
                None => assert!(w.is_nan()),
            }
        }
        assert_eq!(holm(&[Some(0.9), Some(0.8)]), vec![Some(1.0), Some(1.0)]);
    }
}
