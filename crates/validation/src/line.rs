//! The Cross-Entropy Method's update along one direction ([`CemUpdate::Line`]).
//!
//! In the drone's 72 dimensions (6 steps × 12) the paper's update — each step's mean and
//! variances refitted to five elites, weighted by their likelihood ratio — moves the proposal
//! by the elites' noise in every direction the failure does not depend on. The proposal then
//! sits several prior standard deviations from the prior in directions that matter to nothing,
//! its importance weights span tens of orders of magnitude and the estimate rests on one or two
//! failures.
//!
//! This update keeps the prior's covariance and moves the mean along one line only, in the
//! prior's whitened coordinates z (z ~ N(0, I) under the prior):
//!
//! 1. **The direction** u is that of steepest descent of a ridge regression of the score on z
//!    over every rollout of the search so far (the ridge penalty chosen by leave-one-out error
//!    from a fixed grid): the failure-informed direction of a linear response surface (as the
//!    gradient of the limit state spans the failure-informed subspace in Uribe, Papaioannou,
//!    Marzouk & Straub 2021, here estimated from the rollouts' scores instead of a gradient).
//! 2. **The distance** t along it is the cross-entropy optimum within the family N(t·u, I):
//!    t = E_p[u·z | failure], estimated by self-normalised importance sampling over the search's
//!    failures, each weighted by p / q̄ with q̄ the mixture of every proposal that drew the
//!    search's populations (at least `m_elite` failures needed); before that, the mean of u·z
//!    over the current population's `m_elite` lowest scores (equal weights), which moves the
//!    proposal outwards level by level as the paper's update does.
//!
//! The importance weights of one proposal of this family have log-variance t², whatever the
//! dimension, so the estimate's weights stay bounded by how far along the line the failures are.

use nalgebra::{DMatrix, DVector};

use crate::gaussian::{Gaussian, Prior, Proposal};
use crate::record::{log_sum_exp, RolloutRecord};

/// The ridge penalties tried (the scores' regression on whitened coordinates, whose Gram matrix
/// grows as the number of rollouts).
const RIDGE_GRID: [f64; 8] = [1e-6, 1e-3, 1e-2, 0.1, 1.0, 10.0, 100.0, 1000.0];

/// The next proposal of the line update, from the search's rollouts so far (`records`, each
/// drawn from `proposals[record.population]`) and the latest population (`latest`).
pub(crate) fn line_proposal(
    prior: &Prior,
    records: &[RolloutRecord],
    proposals: &[Proposal],
    latest: &[RolloutRecord],
    m_elite: usize,
) -> Proposal {
    let z: Vec<DVector<f64>> = records.iter().map(|r| whiten(prior, r)).collect();
    let scores: Vec<f64> = records.iter().map(|r| r.score).collect();
    let Some(u) = descent_direction(&z, &scores) else {
        return prior.to_proposal();
    };
    let failures = records.iter().filter(|r| r.failed).count();
    let t = if failures >= m_elite.max(1) {
        failure_projection(prior, records, proposals, &z, &u)
    } else {
        elite_projection(prior, latest, m_elite, &u)
    };
    along(prior, &u, t.max(0.0))
}

/// The rollout's disturbances in the prior's whitened coordinates, steps end to end.
fn whiten(prior: &Prior, record: &RolloutRecord) -> DVector<f64> {
    DVector::from_iterator(
        prior.steps() * prior.dim(),
        record.disturbances.rows().flat_map(|x| prior.step().to_standard(x)),
    )
}

/// The proposal N(t·u, I) in whitened coordinates: each step's mean moved, the prior's
/// covariance kept.
fn along(prior: &Prior, u: &DVector<f64>, t: f64) -> Proposal {
    let d = prior.dim();
    let step = prior.step();
    Proposal::new(
        (0..prior.steps())
            .map(|s| {
                let shift: Vec<f64> = (0..d).map(|j| t * u[s * d + j]).collect();
                Gaussian::new(step.from_standard(&shift), step.covariance().clone())
                    .expect("the prior's covariance is positive definite")
            })
            .collect(),
    )
}

/// The unit direction in which the ridge regression of `scores` on `z` falls fastest; `None`
/// when the scores do not vary or fewer than three rollouts are given.
pub(crate) fn descent_direction(z: &[DVector<f64>], scores: &[f64]) -> Option<DVector<f64>> {
    let n = z.len();
    if n < 3 {
        return None;
    }
    let dim = z[0].len();
    let mean_z = z.iter().fold(DVector::zeros(dim), |a, v| a + v) / n as f64;
    let mean_y = scores.iter().sum::<f64>() / n as f64;
    let x = DMatrix::from_fn(n, dim, |i, j| z[i][j] - mean_z[j]);
    let y = DVector::from_iterator(n, scores.iter().map(|s| s - mean_y));
    if y.norm() == 0.0 || !y.norm().is_finite() {
        return None;
    }
    let svd = x.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = &svd.singular_values;
    let uty = u.transpose() * &y;
    // Leave-one-out residuals of ridge regression: r_i / (1 − h_ii), the hat matrix of the
    // centred fit plus 1/n for the intercept.
    let fit = |lambda: f64| -> (f64, DVector<f64>) {
        let shrink = DVector::from_iterator(s.len(), s.iter().map(|&v| v * v / (v * v + lambda)));
        let fitted = &u * uty.component_mul(&shrink);
        let loo = (0..n)
            .map(|i| {
                let h = (0..s.len()).map(|k| u[(i, k)] * u[(i, k)] * shrink[k]).sum::<f64>() + 1.0 / n as f64;
                let r = (y[i] - fitted[i]) / (1.0 - h).max(1e-9);
                r * r
            })
            .sum::<f64>();
        let coef = DVector::from_iterator(s.len(), s.iter().zip(uty.iter()).map(|(&v, &c)| v * c / (v * v + lambda)));
        (loo, v_t.transpose() * coef)
    };
    let (_, g) = RIDGE_GRID.iter().map(|&l| fit(l)).min_by(|a, b| a.0.total_cmp(&b.0)).expect("a non-empty grid");
    let norm = g.norm();
    (norm > 0.0 && norm.is_finite()).then(|| -g / norm)
}

/// t = E_p[u·z | failure] by self-normalised importance sampling over the search's failures,
/// each weighted by p / q̄ (q̄ the equal-count mixture of the proposals that drew them).
fn failure_projection(
    prior: &Prior,
    records: &[RolloutRecord],
    proposals: &[Proposal],
    z: &[DVector<f64>],
    u: &DVector<f64>,
) -> f64 {
    let mut counts = vec![0usize; proposals.len()];
    records.iter().for_each(|r| counts[r.population] += 1);
    let n = records.len() as f64;
    let log_w: Vec<(f64, f64)> = records
        .iter()
        .zip(z)
        .filter(|(r, _)| r.failed)
        .map(|(r, zi)| {
            let log_mix = counts
                .iter()
                .zip(proposals)
                .filter(|(&c, _)| c > 0)
                .map(|(&c, q)| (c as f64 / n).ln() + q.log_pdf(&r.disturbances))
                .fold(f64::NEG_INFINITY, log_sum_exp);
            (prior.log_likelihood(&r.disturbances) - log_mix, u.dot(zi))
        })
        .collect();
    let max = log_w.iter().map(|w| w.0).fold(f64::NEG_INFINITY, f64::max);
    let (num, den) = log_w.iter().fold((0.0, 0.0), |(num, den), &(lw, p)| {
        let w = (lw - max).exp();
        (num + w * p, den + w)
    });
    num / den
}

/// The mean of u·z over the `m_elite` lowest scores of `latest`, equally weighted.
fn elite_projection(prior: &Prior, latest: &[RolloutRecord], m_elite: usize, u: &DVector<f64>) -> f64 {
    let mut order: Vec<&RolloutRecord> = latest.iter().collect();
    order.sort_by(|a, b| a.score.total_cmp(&b.score));
    let elites = &order[..m_elite.clamp(1, order.len().max(1)).min(order.len())];
    if elites.is_empty() {
        return 0.0;
    }
    elites.iter().map(|r| u.dot(&whiten(prior, r))).sum::<f64>() / elites.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// With more rollouts than dimensions and a score linear in z, the fitted direction is the
    /// score's own (to the ridge's rounding); with scores that do not vary there is none.
    #[test]
    fn the_direction_of_a_linear_score_is_recovered() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let dim = 12;
        let a = DVector::from_iterator(dim, (0..dim).map(|i| (i as f64 * 0.7).sin() + 0.1)).normalize();
        let z: Vec<DVector<f64>> =
            (0..40).map(|_| DVector::from_iterator(dim, (0..dim).map(|_| StandardNormal.sample(&mut rng)))).collect();
        let scores: Vec<f64> = z.iter().map(|v| 2.0 - a.dot(v)).collect();
        let u = descent_direction(&z, &scores).unwrap();
        assert!(u.dot(&a) > 0.999_999, "cos = {}", u.dot(&a));
        assert!(descent_direction(&z, &vec![1.0; 40]).is_none());
        assert!(descent_direction(&z[..2], &scores[..2]).is_none());
    }
}
