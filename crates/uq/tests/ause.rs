//! AUSE: 0 for an uncertainty that ranks pixels as their error does, clearly above 0 for a
//! random one, a hand-computed value, and the bad inputs it refuses.

use nerfsv_uq::{depth_ause, depth_errors, mean_ause, sparsification, UqError};
use rand::{RngExt, SeedableRng};

/// `n` errors `Exp(1)` (inverse transform) and `n` uncertainties `U(0, 1)` independent of them.
fn exponential_errors_and_random_uncertainty(n: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let e = (0..n).map(|_| -(1.0 - rng.random::<f32>()).ln()).collect();
    let u = (0..n).map(|_| rng.random::<f32>()).collect();
    (e, u)
}

#[test]
fn ause_of_the_true_error_as_uncertainty_is_zero() {
    let (e, _) = exponential_errors_and_random_uncertainty(5000, 1);
    let s = sparsification("r_0", &e, &e).unwrap();
    assert_eq!(s.pixels, 5000);
    assert!(s.ause.abs() < 1e-12, "AUSE {}", s.ause);
    assert_eq!(s.by_uncertainty, s.oracle);
    // Any increasing function of the error ranks the same way.
    let u: Vec<f32> = e.iter().map(|v| 3.0 * v.sqrt() + 1.0).collect();
    assert!(sparsification("r_0", &e, &u).unwrap().ause.abs() < 1e-12);
}

#[test]
fn ause_of_a_random_uncertainty_is_clearly_above_zero() {
    let (e, u) = exponential_errors_and_random_uncertainty(20_000, 2);
    let s = sparsification("r_0", &e, &u).unwrap();
    // Random ranking: the curve stays near the mean error 1 while the oracle's falls to
    // E[X | X < q_(1−x)] (0.31 of the mean at x = 0.5): AUSE ≈ 0.5 here.
    assert!(s.ause > 0.3, "AUSE of a random uncertainty {}", s.ause);
    assert!(s.ause < 0.8, "AUSE {}", s.ause);
    assert!(s.by_uncertainty.iter().chain(&s.oracle).all(|&v| (0.0..=1.0).contains(&v)));
    assert_eq!(s.by_uncertainty.iter().chain(&s.oracle).copied().fold(0.0, f64::max), 1.0);
    // The oracle is never worse than the ranking.
    assert!(s.by_uncertainty.iter().zip(&s.oracle).all(|(a, b)| a >= b));
}

#[test]
fn ause_of_the_reversed_ranking_is_the_hand_computed_value() {
    // Errors 1..=100 ranked backwards (the least uncertain pixel has the largest error): after
    // removing k pixels the curve keeps {k+1, …, 100}, mean (101 + k)/2, the oracle keeps
    // {1, …, 100 − k}, mean (101 − k)/2; the shared maximum is 100 (curve at k = 99), so the
    // normalised gap is k/100 and its trapezoid over x = 0, 0.01, …, 0.99 is 0.99²/2.
    let e: Vec<f32> = (1..=100).map(|v| v as f32).collect();
    let u: Vec<f32> = e.iter().map(|v| -v).collect();
    let s = sparsification("r_0", &e, &u).unwrap();
    assert_eq!(s.max_error, 100.0);
    assert!((s.by_uncertainty[10] - 55.5 / 100.0).abs() < 1e-12);
    assert!((s.oracle[10] - 45.5 / 100.0).abs() < 1e-12);
    assert!((s.ause - 0.49005).abs() < 1e-12, "AUSE {}", s.ause);
    assert_eq!(s.fractions[99], 0.99);
}

#[test]
fn pixels_without_ground_truth_are_left_out_and_pixels_without_uncertainty_rank_most_uncertain() {
    // 150 valid pixels plus one without ground truth (NaN error) and two with an error but no
    // finite uncertainty: the first is left out, the two count as the most uncertain pixels,
    // exactly as if their uncertainty were larger than any other.
    let (e, u) = exponential_errors_and_random_uncertainty(150, 3);
    let mut e2 = e.clone();
    let mut u2 = u.clone();
    e2.extend([f32::NAN, 0.5, 2.0]);
    u2.extend([0.1, f32::NAN, f32::INFINITY]);
    let b = sparsification("r_0", &e2, &u2).unwrap();
    assert_eq!((b.pixels, b.unscored), (152, 2));
    let mut e3 = e.clone();
    let mut u3 = u.clone();
    e3.extend([0.5, 2.0]);
    u3.extend([1e30, 1e30]);
    let c = sparsification("r_0", &e3, &u3).unwrap();
    assert_eq!((b.ause, &b.by_uncertainty, &b.oracle), (c.ause, &c.by_uncertainty, &c.oracle));
    assert_eq!(c.unscored, 0);
    // Leaving them out instead (scoring only the scored pixels) gives another figure.
    let a = sparsification("r_0", &e, &u).unwrap();
    assert_ne!(a.ause, b.ause);
    let e = sparsification("r_3", &e2[..99], &u2[..99]).unwrap_err();
    assert!(matches!(e, UqError::TooFewPixels { pixels: 99, .. }) && e.to_string().contains("r_3"), "{e}");
    assert!(matches!(sparsification("r_0", &e2, &u), Err(UqError::MapSize { .. })));
}

#[test]
fn depth_ause_refuses_an_image_without_ground_truth_depth() {
    let rendered = vec![1.0f32; 200];
    let e = depth_ause("test/r_12", &rendered, None, &rendered).unwrap_err();
    assert!(matches!(e, UqError::NoGroundTruthDepth { .. }), "{e}");
    assert!(e.to_string().contains("test/r_12"), "{e}");
    // Ground truth 0 (no surface) is not an error of 1 m: those pixels are left out.
    let mut gt = vec![1.5f32; 200];
    gt[..60].fill(0.0);
    let err = depth_errors("r_0", &rendered, Some(&gt)).unwrap();
    assert!(err[..60].iter().all(|v| v.is_nan()));
    assert!(err[60..].iter().all(|&v| (v - 0.5).abs() < 1e-6));
    let unc: Vec<f32> = (0..200).map(|i| i as f32).collect();
    assert_eq!(depth_ause("r_0", &rendered, Some(&gt), &unc).unwrap().pixels, 140);
    assert!(matches!(depth_errors("r_0", &rendered, Some(&gt[..10])), Err(UqError::MapSize { .. })));
    let a = sparsification("a", &err, &unc).unwrap();
    assert_eq!(mean_ause(&[a.clone(), a.clone()]), Some(a.ause));
    assert_eq!(mean_ause(&[]), None);
}

/// The bootstrap standard error of a mean converges to the population standard deviation over
/// √n: for 1, 2, …, 100 that is √((n² − 1)/12)/√n = 2.8866; 2000 resamples get within a few %.
/// Seeded: the same seed, the same figure.
#[test]
fn the_bootstrap_standard_error_of_a_mean_matches_the_closed_form() {
    let values: Vec<f64> = (1..=100).map(f64::from).collect();
    let (mean, se) = nerfsv_uq::ause::bootstrap_mean(&values, 7).unwrap();
    assert_eq!(mean, 50.5);
    let closed = ((100.0f64 * 100.0 - 1.0) / 12.0).sqrt() / 10.0;
    assert!((se / closed - 1.0).abs() < 0.06, "bootstrap {se} vs {closed}");
    assert_eq!(nerfsv_uq::ause::bootstrap_mean(&values, 7).unwrap().1.to_bits(), se.to_bits());
    assert!(nerfsv_uq::ause::bootstrap_mean(&[], 7).is_none());
}
