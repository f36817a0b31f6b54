//! The Bayesian Laplace approximation: the closed-form Gaussian posterior of a linear model,
//! the exact evidence of that model, monotone Levenberg–Marquardt with λ = 0.01 (on a
//! nonlinear model and on a NeRF), and the whole per-image method on a small NeRF.

// Dense-matrix oracles read best as index loops.
#![allow(clippy::needless_range_loop)]

mod common;

use faer::Mat;
use nerfsv_uq::{
    bla_image, bla_view, laplace_at, laplace_summary_at, lm_map, NerfResiduals, ResidualModel, UqConfig, UqError,
};
use rand::{RngExt, SeedableRng};

/// `r(θ) = A·θ − y`.
struct Linear {
    a: Vec<Vec<f64>>,
    y: Vec<f64>,
}

impl Linear {
    fn random(m: usize, p: usize, seed: u64) -> Self {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let a = (0..m).map(|_| (0..p).map(|_| rng.random::<f64>() - 0.5).collect()).collect();
        let y = (0..m).map(|_| 2.0 * rng.random::<f64>() - 1.0).collect();
        Self { a, y }
    }
}

impl ResidualModel for Linear {
    fn n_params(&self) -> usize {
        self.a[0].len()
    }
    fn residuals(&mut self, theta: &[f64], r: &mut Vec<f64>) {
        r.clear();
        r.extend(self.a.iter().zip(&self.y).map(|(row, y)| row.iter().zip(theta).map(|(a, t)| a * t).sum::<f64>() - y));
    }
    fn residuals_and_jacobian(&mut self, theta: &[f64], r: &mut Vec<f64>, jacobian: &mut Mat<f64>) {
        self.residuals(theta, r);
        *jacobian = Mat::from_fn(self.a.len(), self.n_params(), |i, j| self.a[i][j]);
    }
}

/// Inverse and log-determinant of a small SPD matrix by Gauss–Jordan with partial pivoting
/// (an oracle independent of faer's Cholesky).
fn inverse_logdet(mut a: Vec<Vec<f64>>) -> (Vec<Vec<f64>>, f64) {
    let n = a.len();
    let mut inv: Vec<Vec<f64>> = (0..n).map(|i| (0..n).map(|j| (i == j) as u8 as f64).collect()).collect();
    let mut logdet = 0.0;
    for c in 0..n {
        let piv = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs())).unwrap();
        a.swap(c, piv);
        inv.swap(c, piv);
        let d = a[c][c];
        logdet += d.abs().ln();
        for j in 0..n {
            a[c][j] /= d;
            inv[c][j] /= d;
        }
        for i in 0..n {
            if i != c {
                let f = a[i][c];
                for j in 0..n {
                    a[i][j] -= f * a[c][j];
                    inv[i][j] -= f * inv[c][j];
                }
            }
        }
    }
    (inv, logdet)
}

/// For `r = Aθ − y` with prior `N(θ₀, α⁻¹I)` (θ₀ where the fit starts) and noise σ_n, the
/// posterior is exactly Gaussian: `Σ = (AᵀA/σ_n² + αI)⁻¹`, mean `Σ·(Aᵀy/σ_n² + αθ₀)`, and the
/// evidence is `N(y; Aθ₀, σ_n²I + AAᵀ/α)`; the information gain is `½(ln det H − P ln α)`.
/// The BLA core must reproduce all four (covariance to 1e-9 relative; the mean to 1e-6, as a
/// step is accepted on a lower loss and the loss resolves θ only to about √ε), on both of
/// its solver paths: more residuals than parameters (P × P steps) and fewer (m × m steps).
#[test]
fn bla_on_a_linear_model_reproduces_the_closed_form_gaussian_posterior() {
    // Damped steps contract the error by λ/(λ + eig H) ≤ 0.01/0.71 each: 30 reach rounding.
    let cfg = UqConfig {
        prior_precision: 0.7,
        noise_std: 0.2,
        lm_iterations: 30,
        lm_tolerance: 1e-15,
        ..UqConfig::default()
    };
    let (alpha, var) = (cfg.prior_precision, cfg.noise_std * cfg.noise_std);
    for (m, p, seed) in [(40, 7, 1), (5, 9, 2)] {
        let mut model = Linear::random(m, p, seed);
        // Closed form.
        let h: Vec<Vec<f64>> = (0..p)
            .map(|i| {
                (0..p)
                    .map(|j| {
                        (0..m).map(|k| model.a[k][i] * model.a[k][j]).sum::<f64>() / var
                            + if i == j { alpha } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let (sigma, log_det_h) = inverse_logdet(h);
        let theta0 = vec![0.3; p];
        let aty: Vec<f64> =
            (0..p).map(|i| (0..m).map(|k| model.a[k][i] * model.y[k]).sum::<f64>() / var + alpha * theta0[i]).collect();
        let mean: Vec<f64> = (0..p).map(|i| (0..p).map(|j| sigma[i][j] * aty[j]).sum()).collect();
        let c: Vec<Vec<f64>> = (0..m)
            .map(|i| {
                (0..m)
                    .map(|j| {
                        (0..p).map(|k| model.a[i][k] * model.a[j][k]).sum::<f64>() / alpha
                            + if i == j { var } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let (c_inv, c_logdet) = inverse_logdet(c);
        let centred: Vec<f64> =
            (0..m).map(|i| model.y[i] - (0..p).map(|k| model.a[i][k] * theta0[k]).sum::<f64>()).collect();
        let quad: f64 = (0..m).map(|i| (0..m).map(|j| centred[i] * c_inv[i][j] * centred[j]).sum::<f64>()).sum();
        let evidence = -0.5 * quad - 0.5 * c_logdet - 0.5 * m as f64 * (2.0 * std::f64::consts::PI).ln();

        // One step is eq. 9 exactly: θ₁ = θ₀ − (H + λI)⁻¹ g, g = Aᵀ(Aθ₀ − y)/σ² (the prior's
        // term α(θ₀ − θ₀) is 0).
        let damped: Vec<Vec<f64>> = (0..p)
            .map(|i| {
                (0..p)
                    .map(|j| {
                        (0..m).map(|k| model.a[k][i] * model.a[k][j]).sum::<f64>() / var
                            + if i == j { alpha + cfg.lm_damping } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let (damped_inv, _) = inverse_logdet(damped);
        let mut r0 = Vec::new();
        model.residuals(&theta0, &mut r0);
        let g: Vec<f64> = (0..p).map(|i| (0..m).map(|k| model.a[k][i] * r0[k]).sum::<f64>() / var).collect();
        let one = lm_map(&mut model, &theta0, &UqConfig { lm_iterations: 1, ..cfg.clone() });
        for i in 0..p {
            let want = theta0[i] - (0..p).map(|j| damped_inv[i][j] * g[j]).sum::<f64>();
            assert!((one.theta[i] - want).abs() < 1e-10, "m={m}: first step θ₁[{i}] {} vs {want}", one.theta[i]);
        }
        let fit = lm_map(&mut model, &theta0, &cfg);
        let scale = mean.iter().map(|v| v.abs()).fold(0.0, f64::max);
        for i in 0..p {
            assert!((fit.theta[i] - mean[i]).abs() < 1e-6 * scale, "m={m}: θ̂[{i}] {} vs {}", fit.theta[i], mean[i]);
        }
        let lap = laplace_at("linear", &mut model, &fit.theta, &theta0, &cfg).unwrap();
        let gain = 0.5 * (log_det_h - p as f64 * alpha.ln());
        assert!((lap.information_gain - gain).abs() < 1e-9 * gain, "m={m}: {} vs {gain}", lap.information_gain);
        let smax = (0..p).map(|i| sigma[i][i]).fold(0.0, f64::max);
        for i in 0..p {
            for j in 0..p {
                let d = (lap.covariance[(i, j)] - sigma[i][j]).abs();
                assert!(d < 1e-9 * smax, "m={m}: Σ[{i},{j}] {} vs {}", lap.covariance[(i, j)], sigma[i][j]);
            }
        }
        let trace: f64 = (0..p).map(|i| sigma[i][i]).sum();
        assert!((lap.normalized_trace - trace / p as f64).abs() < 1e-12 * trace);
        assert!((lap.rmv - (trace / p as f64).sqrt()).abs() < 1e-12);
        assert_eq!(lap.residuals, m);
        assert!(
            (lap.log_evidence - evidence).abs() < 1e-8 * evidence.abs(),
            "m={m}: {} vs {evidence}",
            lap.log_evidence
        );
    }
}

/// Half the weights of a linear model are unseen by the data (zero columns of A): with the
/// prior centred at the trained weights they keep those weights exactly, and their posterior
/// variance is the prior's 1/α; the seen half moves to the data. The information gain is
/// `½ Σ_k ln(1 + s_k²/(σ²α))` for the seen columns' squared norms `s_k²` (A's columns are
/// orthogonal here, so those are the spectrum of AᵀA), and 0 for data that see nothing.
#[test]
fn unobserved_weights_keep_their_trained_values_and_the_information_gain_is_the_spectrum_s() {
    let (p, m) = (8, 12);
    let scales = [0.5, 1.0, 2.0, 3.0];
    // Column j < 4 is s_j times the unit vector e_{2j}: orthogonal; columns 4..8 are zero.
    let a: Vec<Vec<f64>> =
        (0..m).map(|k| (0..p).map(|j| if j < 4 && k == 2 * j { scales[j] } else { 0.0 }).collect()).collect();
    let y: Vec<f64> = (0..m).map(|k| 0.1 * k as f64 - 0.4).collect();
    let mut model = Linear { a, y };
    let cfg = UqConfig {
        prior_precision: 2.0,
        noise_std: 0.5,
        lm_iterations: 30,
        lm_tolerance: 1e-15,
        ..UqConfig::default()
    };
    let (alpha, var) = (cfg.prior_precision, cfg.noise_std * cfg.noise_std);
    let trained: Vec<f64> = (0..p).map(|j| 0.7 - 0.2 * j as f64).collect();
    let fit = lm_map(&mut model, &trained, &cfg);
    for j in 4..p {
        assert!((fit.theta[j] - trained[j]).abs() < 1e-12, "unseen weight {j}: {} from {}", fit.theta[j], trained[j]);
    }
    for (j, &s) in scales.iter().enumerate() {
        // Closed form: (s²/σ² + α)·θ = s·y/σ² + α·θ₀.
        let want = (s * model.y[2 * j] / var + alpha * trained[j]) / (s * s / var + alpha);
        // A step is kept on a lower loss, which resolves θ to about √ε.
        assert!((fit.theta[j] - want).abs() < 1e-6, "seen weight {j}: {} vs {want}", fit.theta[j]);
    }
    let lap = laplace_at("half", &mut model, &fit.theta, &trained, &cfg).unwrap();
    for j in 4..p {
        assert!((lap.covariance[(j, j)] - 1.0 / alpha).abs() < 1e-12);
    }
    let gain: f64 = scales.iter().map(|s| 0.5 * (s * s / (var * alpha)).ln_1p()).sum();
    assert!((lap.information_gain - gain).abs() < 1e-10 * gain, "{} vs {gain}", lap.information_gain);
    let summary = laplace_summary_at("half", &mut model, &fit.theta, &trained, &cfg).unwrap();
    assert!((summary.information_gain - gain).abs() < 1e-9 * gain);
    // The variance ratio over the 4 seen directions only.
    let ratio: f64 = scales.iter().map(|s| alpha / (alpha + s * s / var)).sum::<f64>() / 4.0;
    assert!((summary.data_variance_ratio - ratio).abs() < 1e-9, "{} vs {ratio}", summary.data_variance_ratio);
    // The trace still reads mostly the prior: half its weights are the prior's 1/α.
    assert!(lap.normalized_trace > 0.5 / alpha);
    // Data that see nothing teach nothing.
    let mut blind = Linear { a: vec![vec![0.0; p]; m], y: model.y.clone() };
    let none = laplace_summary_at("blind", &mut blind, &trained, &trained, &cfg).unwrap();
    assert_eq!((none.information_gain, none.data_variance_ratio), (0.0, 1.0));
}

/// With a grid of prior precisions, the evidence of each (mode held at the configured α's) is
/// the Laplace formula at that α, and the covariance uses the best; for a linear model the mode
/// moves with α, so the grid's figures are those at the configured α's mode.
#[test]
fn the_prior_precision_grid_picks_the_highest_laplace_evidence() {
    let grid = vec![0.01, 0.1, 1.0, 10.0, 100.0];
    let base = UqConfig { prior_precision: 1.0, noise_std: 0.3, lm_iterations: 20, ..UqConfig::default() };
    for (m, p) in [(30, 6), (4, 6)] {
        let mut model = Linear::random(m, p, 7);
        let fit = lm_map(&mut model, &vec![0.0; p], &base);
        let with_grid = UqConfig { prior_precision_grid: grid.clone(), ..base.clone() };
        let zero = vec![0.0; p];
        let lap = laplace_at("grid", &mut model, &fit.theta, &zero, &with_grid).unwrap();
        assert_eq!(lap.evidence_grid.len(), grid.len());
        // Each grid value equals the dense formula evaluated with that α.
        for &(a, e) in &lap.evidence_grid {
            let one = UqConfig { prior_precision: a, ..base.clone() };
            let direct = laplace_at("grid", &mut model, &fit.theta, &zero, &one).unwrap();
            assert!((direct.log_evidence - e).abs() < 1e-9 * e.abs(), "α {a}: {e} vs {}", direct.log_evidence);
        }
        let best = lap.evidence_grid.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
        assert_eq!(lap.prior_precision, best.0);
        assert_eq!(lap.log_evidence, best.1);
    }
}

/// The covariance-free summaries (eigenvalues of the Gram matrix on its smaller side) equal the
/// dense Laplace approximation's, with fewer residuals than parameters and with more, with and
/// without a grid of prior precisions.
#[test]
fn the_summary_from_the_gram_spectrum_equals_the_dense_laplace_approximation() {
    let base = UqConfig { prior_precision: 0.7, noise_std: 0.2, lm_iterations: 20, ..UqConfig::default() };
    for (m, p) in [(5, 40), (40, 6), (12, 12)] {
        for grid in [vec![], vec![0.05, 0.5, 5.0]] {
            let cfg = UqConfig { prior_precision_grid: grid, ..base.clone() };
            let mut model = Linear::random(m, p, 11);
            let fit = lm_map(&mut model, &vec![0.0; p], &cfg);
            let zero = vec![0.0; p];
            let dense = laplace_at("lin", &mut model, &fit.theta, &zero, &cfg).unwrap();
            let summary = laplace_summary_at("lin", &mut model, &fit.theta, &zero, &cfg).unwrap();
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(1.0);
            assert_eq!(summary.prior_precision, dense.prior_precision, "m {m} p {p}");
            assert!(
                close(summary.normalized_trace, dense.normalized_trace),
                "{summary:?} vs {}",
                dense.normalized_trace
            );
            assert!(close(summary.rmv, dense.rmv));
            assert!(close(summary.information_gain, dense.information_gain), "{summary:?}");
            assert!(
                close(summary.log_evidence, dense.log_evidence),
                "{} vs {}",
                summary.log_evidence,
                dense.log_evidence
            );
            assert_eq!(summary.evidence_grid.len(), dense.evidence_grid.len());
            for (a, b) in summary.evidence_grid.iter().zip(&dense.evidence_grid) {
                assert!(a.0 == b.0 && close(a.1, b.1), "{a:?} vs {b:?}");
            }
            assert_eq!(summary.residuals, m);
        }
    }
}

/// `r_k(θ) = exp(θ₀ x_k) + θ₁ sin(θ₂ x_k) − y_k`: curved enough that undamped Gauss–Newton
/// overshoots from a far start.
struct Curved {
    x: Vec<f64>,
    y: Vec<f64>,
}

impl ResidualModel for Curved {
    fn n_params(&self) -> usize {
        3
    }
    fn residuals(&mut self, t: &[f64], r: &mut Vec<f64>) {
        r.clear();
        r.extend(self.x.iter().zip(&self.y).map(|(x, y)| (t[0] * x).exp() + t[1] * (t[2] * x).sin() - y));
    }
    fn residuals_and_jacobian(&mut self, t: &[f64], r: &mut Vec<f64>, jacobian: &mut Mat<f64>) {
        self.residuals(t, r);
        let x = &self.x;
        *jacobian = Mat::from_fn(x.len(), 3, |k, j| match j {
            0 => x[k] * (t[0] * x[k]).exp(),
            1 => (t[2] * x[k]).sin(),
            _ => t[1] * x[k] * (t[2] * x[k]).cos(),
        });
    }
}

#[test]
fn levenberg_marquardt_with_lambda_0_01_decreases_the_loss_monotonically() {
    let x: Vec<f64> = (0..60).map(|k| k as f64 / 20.0).collect();
    let y = x.iter().map(|x| (0.7 * x).exp() + 1.5 * (2.0 * x).sin()).collect();
    let mut model = Curved { x, y };
    let cfg = UqConfig {
        prior_precision: 1e-3,
        noise_std: 0.1,
        lm_iterations: 60,
        lm_tolerance: 1e-12,
        ..UqConfig::default()
    };
    assert_eq!(cfg.lm_damping, 0.01);
    let fit = lm_map(&mut model, &[1.4, -1.0, 1.2], &cfg);
    assert!(fit.losses.len() >= 5, "{:?}", fit.losses);
    assert!(fit.losses.windows(2).all(|w| w[1] < w[0]), "not monotone: {:?}", fit.losses);
    assert!(fit.rejected > 0, "no step was rejected: the start is not far enough to test the damping");
    assert!(fit.loss < 1e-3 * fit.losses[0], "{:?}", fit.losses);
    // The generating weights, up to the symmetry θ₁ sin(θ₂x) = (−θ₁) sin(−θ₂x).
    let t = &fit.theta;
    assert!((t[0] - 0.7).abs() < 1e-3 && (t[1].abs() - 1.5).abs() < 1e-2 && (t[1] * t[2] - 3.0).abs() < 2e-2, "{t:?}");
}

/// The reference colours of a second, slightly different model: the fit has something to do.
fn shifted_reference(rays: &[nerfsv_nerf::RayInput]) -> Vec<[f32; 3]> {
    let mut other = common::tiny_nerf();
    for v in other.sigma_net_params_mut().iter_mut().step_by(3) {
        *v *= 1.3;
    }
    let out = other.render_rays(rays);
    out.rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

#[test]
fn levenberg_marquardt_on_the_sigma_net_weights_of_a_nerf_decreases_the_loss_monotonically() {
    let mut nerf = common::tiny_nerf();
    let rays = common::view_rays(10);
    let reference = shifted_reference(&rays);
    let theta0: Vec<f64> = nerf.sigma_net_params().iter().map(|&v| v as f64).collect();
    let cfg = UqConfig { lm_iterations: 6, ..UqConfig::default() };
    let mut model = NerfResiduals::new(&mut nerf, rays, reference);
    let fit = lm_map(&mut model, &theta0, &cfg);
    assert!(fit.losses.len() >= 3, "{:?}", fit.losses);
    assert!(fit.losses.windows(2).all(|w| w[1] < w[0]), "not monotone: {:?}", fit.losses);
    // The prior holds the weights at the trained ones where the 30 rays say little: the fit
    // takes about 30 % off the loss (0.99e-3 → 0.70e-3), not all of the shifted model's change.
    assert!(fit.loss < 0.8 * fit.losses[0], "{:?}", fit.losses);
}

#[test]
fn bla_of_a_nerf_image_keeps_the_lowest_loss_perturbation_and_a_positive_definite_covariance() {
    let nerf = common::tiny_nerf();
    let rays = common::view_rays(12);
    let reference = shifted_reference(&rays);
    let cfg =
        UqConfig { max_rays: 60, lm_iterations: 3, prior_precision_grid: vec![0.1, 1.0, 10.0], ..UqConfig::default() };
    let fit = bla_image(&nerf, "r_3", &rays, &reference, &cfg).unwrap();
    assert_eq!(fit.perturbation_losses.len(), 3);
    let min = fit.perturbation_losses.iter().cloned().fold(f64::INFINITY, f64::min);
    assert_eq!(fit.perturbation_losses[fit.perturbation], min);
    assert_eq!(fit.map.loss, min);
    assert_eq!(fit.rays, 60);
    assert_eq!(fit.laplace.residuals, 180);
    let p = nerf.field.sigma_net_range().len();
    assert_eq!((fit.laplace.covariance.nrows(), fit.laplace.covariance.ncols()), (p, p));
    // Data shrink the prior's variance 1/α: 0 < tr(Σ)/P < 1/α, and rmv is its square root.
    let lap = &fit.laplace;
    assert!(lap.normalized_trace > 0.0 && lap.normalized_trace < 1.0 / lap.prior_precision, "{}", lap.normalized_trace);
    assert!((lap.rmv * lap.rmv - lap.normalized_trace).abs() < 1e-12);
    assert!(cfg.prior_precision_grid.contains(&lap.prior_precision));
    // Same inputs, same answer.
    let again = bla_image(&nerf, "r_3", &rays, &reference, &cfg).unwrap();
    assert_eq!(again.map, fit.map);
    assert_eq!(again.laplace.normalized_trace, lap.normalized_trace);
}

/// The view's BLA (the online reward's) is the image's BLA without the covariance: same MAP,
/// same summaries.
#[test]
fn the_view_bla_matches_the_image_bla_without_its_covariance() {
    let nerf = common::tiny_nerf();
    let rays = common::view_rays(12);
    let reference = shifted_reference(&rays);
    let cfg = UqConfig { max_rays: 40, lm_iterations: 3, ..UqConfig::default() };
    let image = bla_image(&nerf, "v", &rays, &reference, &cfg).unwrap();
    let view = bla_view(&nerf, "v", &rays, &reference, &cfg, 40).unwrap();
    assert_eq!(view.map, image.map);
    assert_eq!((view.perturbation, view.rays), (image.perturbation, image.rays));
    let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
    assert!(rel(view.laplace.normalized_trace, image.laplace.normalized_trace) < 1e-6);
    assert!(rel(view.laplace.log_evidence, image.laplace.log_evidence) < 1e-6);
    // Fewer rays, less data: more posterior variance.
    let fewer = bla_view(&nerf, "v", &rays, &reference, &cfg, 8).unwrap();
    assert!(fewer.laplace.normalized_trace > view.laplace.normalized_trace);
}

#[test]
fn bla_refuses_bad_config_and_an_image_whose_rays_all_miss_naming_them() {
    let nerf = common::tiny_nerf();
    let rays = common::view_rays(4);
    let reference = vec![[0.5f32; 3]; rays.len()];
    for (cfg, key) in [
        (UqConfig { prior_precision: 0.0, ..UqConfig::default() }, "uq.prior_precision"),
        (UqConfig { noise_std: -1.0, ..UqConfig::default() }, "uq.noise_std"),
        (UqConfig { prior_precision_grid: vec![1.0, f64::NAN], ..UqConfig::default() }, "uq.prior_precision_grid[1]"),
    ] {
        let err = bla_image(&nerf, "r_0", &rays, &reference, &cfg).unwrap_err();
        assert!(matches!(err, UqError::Config(_)) && err.to_string().starts_with(key), "{err}");
    }
    let away: Vec<_> = rays
        .iter()
        .map(|r| nerfsv_nerf::RayInput { origin: [0.0, 5.0, 0.0].into(), direction: [0.0, 1.0, 0.0].into(), ..*r })
        .collect();
    let err = bla_image(&nerf, "r_9", &away, &reference, &UqConfig::default()).unwrap_err();
    assert!(err.to_string().starts_with("r_9: all 16 rays miss"), "{err}");
}

#[test]
fn uq_config_reads_toml_refuses_unknown_keys_and_non_positive_values() {
    let c: UqConfig = toml::from_str("noise_std = 0.1\nperturbations = 5").unwrap();
    assert_eq!((c.noise_std, c.perturbations, c.lm_damping, c.prior_precision), (0.1, 5, 0.01, 1.0));
    assert!(toml::from_str::<UqConfig>("noise = 0.1").unwrap_err().to_string().contains("unknown field `noise`"));
    let e = UqConfig { prior_precision: -2.0, ..UqConfig::default() }.validate().unwrap_err();
    assert_eq!(e.to_string(), "prior_precision: must be a positive number, found -2");
    assert!(UqConfig::default().validate().is_ok());
}

/// The same image gives bit-identical BLA at any thread count (the stage files of `nerfsv run`
/// promise it): the dense products and the factorisation split their work the same way however
/// many threads run it.
#[test]
fn bla_of_a_nerf_image_is_bit_identical_at_one_and_three_threads() {
    let nerf = common::tiny_nerf();
    let rays = common::view_rays(12);
    let reference = shifted_reference(&rays);
    let cfg = UqConfig { max_rays: 40, lm_iterations: 2, perturbations: 2, ..UqConfig::default() };
    let fit = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| bla_image(&nerf, "r_3", &rays, &reference, &cfg).unwrap())
    };
    let (a, b) = (fit(1), fit(3));
    assert!(a.map == b.map, "the MAP differs between 1 and 3 threads");
    assert_eq!(a.perturbation_losses, b.perturbation_losses);
    assert_eq!(a.laplace.log_evidence.to_bits(), b.laplace.log_evidence.to_bits());
    assert_eq!(a.laplace.normalized_trace.to_bits(), b.laplace.normalized_trace.to_bits());
    assert!(a.laplace.covariance == b.laplace.covariance, "the covariance differs between 1 and 3 threads");
}
