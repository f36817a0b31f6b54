//! The Gaussian approximation: recovery of a known (μ, σ), the closed form against a numerical
//! minimiser, the paper's exclusions, rays without samples, and a render against itself.

mod common;

use nerfsv_uq::{ga_fit, ga_floored_objective, ga_image, ga_objective, GaExclusion, GaRay, UqError};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

/// `n` rays of 1–24 samples (colours `U(0, 1)`, weights `U(0, 0.08)`), every 50th without
/// samples, with reference colours drawn from the GA model itself: `r = μ·m + σ·√s·ε`.
fn synthetic(n: usize, mu: f64, sigma: f64, seed: u64) -> Vec<GaRay> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|i| {
            let k = if i % 50 == 7 { 0 } else { rng.random_range(1..25) };
            let c: Vec<[f32; 3]> = (0..k).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
            let w: Vec<f32> = (0..k).map(|_| 0.08 * rng.random::<f32>()).collect();
            let mut ray = GaRay::from_samples(&c, &w, [0.0; 3], [0.0; 3]);
            for ch in 0..3 {
                let e: f64 = StandardNormal.sample(&mut rng);
                ray.r[ch] = mu * ray.m[ch] + sigma * ray.s[ch].sqrt() * e;
            }
            ray
        })
        .collect()
}

/// 4000 rays (11 760 terms): the standard error of σ̂ is σ/√(2N) ≈ 0.65 % and that of μ̂
/// σ/√Σ(m²/s) ≤ σ/√N ≈ 0.003; the bounds are about 4 standard errors.
#[test]
fn ga_recovers_known_sigma_and_mu_from_synthetic_rays() {
    for (mu, sigma, seed) in [(0.8, 0.3, 1), (1.0, 0.05, 2), (1.3, 1.7, 3)] {
        let rays = synthetic(4000, mu, sigma, seed);
        let fit = ga_fit("synthetic", &rays, 3.0, 0.05).unwrap();
        assert_eq!(fit.rays_without_samples, 80);
        assert_eq!(fit.terms, 3 * 3920);
        assert!((fit.sigma_d / sigma - 1.0).abs() < 0.03, "σ: {} vs {sigma}", fit.sigma_d);
        assert!((fit.mu_d - mu).abs() < 4.0 * sigma / (fit.terms as f64).sqrt(), "μ: {} vs {mu}", fit.mu_d);
        assert_eq!(fit.excluded, None);
        // The standardised residuals have mean square 1 and are NaN exactly on the empty rays.
        let z: Vec<f64> = fit.standardized.iter().flatten().filter(|v| !v.is_nan()).map(|&v| v as f64).collect();
        assert_eq!(z.len(), fit.terms);
        assert!((z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64 - 1.0).abs() < 1e-5);
        assert!(fit.standardized[7].iter().all(|v| v.is_nan()));
        assert!(fit.pixel_rms()[7].is_nan() && fit.pixel_rms()[8] > 0.0);
    }
}

/// Golden-section search, `f` unimodal on `[a, b]`, to a bracket of `tol`.
fn golden(mut a: f64, mut b: f64, tol: f64, f: impl Fn(f64) -> f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while b - a > tol {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = f(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    (a + b) / 2.0
}

/// The closed form against a nested golden-section search on eq. 2 itself (μ outside in
/// [−5, 5], log σ inside in [−10, 3]; f is convex in μ for each σ and unimodal in log σ):
/// same optimum to 1e-6 and the same objective value to 1e-9 relative.
#[test]
fn ga_closed_form_matches_a_numerical_minimiser_of_eq_2() {
    let rays = synthetic(300, 0.9, 0.4, 4);
    let fit = ga_fit("synthetic", &rays, 3.0, 0.05).unwrap();
    let best_sigma = |mu: f64| golden(-10.0, 3.0, 1e-10, |ls| ga_objective(&rays, mu, ls.exp())).exp();
    let mu = golden(-5.0, 5.0, 1e-10, |mu| ga_objective(&rays, mu, best_sigma(mu)));
    let sigma = best_sigma(mu);
    assert!((mu - fit.mu_d).abs() < 1e-6, "μ: search {mu} vs closed form {}", fit.mu_d);
    assert!((sigma - fit.sigma_d).abs() < 1e-6, "σ: search {sigma} vs closed form {}", fit.sigma_d);
    let (f_closed, f_search) = (ga_objective(&rays, fit.mu_d, fit.sigma_d), ga_objective(&rays, mu, sigma));
    assert!((fit.objective - f_closed).abs() < 1e-9 * f_closed.abs());
    assert!(f_closed <= f_search + 1e-9 * f_search.abs(), "closed form {f_closed} above search {f_search}");
}

#[test]
fn ga_flags_the_papers_exclusions_and_refuses_an_image_whose_rays_all_miss() {
    let fit = ga_fit("wild", &synthetic(500, 1.0, 4.0, 5), 3.0, 0.05).unwrap();
    assert_eq!(fit.excluded, Some(GaExclusion::AbsolutelyUncertain));
    let exact: Vec<GaRay> = synthetic(100, 1.0, 1.0, 6).into_iter().map(|r| GaRay { r: r.m, ..r }).collect();
    let fit = ga_fit("exact", &exact, 3.0, 0.05).unwrap();
    assert_eq!((fit.mu_d, fit.sigma_d, fit.excluded), (1.0, 0.0, Some(GaExclusion::AbsolutelyCertain)));
    assert!(fit.standardized.iter().flatten().all(|&v| v == 0.0 || v.is_nan()));
    let empty = vec![GaRay::from_samples(&[], &[], [0.2; 3], [1.0; 3]); 10];
    let err = ga_fit("r_17", &empty, 3.0, 0.05).unwrap_err();
    assert!(matches!(err, UqError::AllRaysMiss { rays: 10, .. }));
    assert!(err.to_string().starts_with("r_17: all 10 rays miss"), "{err}");
}

/// The model's own render as reference: the samples explain it exactly (colours relative to
/// the background), so μ_d = 1 and σ_d is f32 rounding; the render of its weights scaled by 0.8
/// (its opacity scaled with them, on a grey background) gives μ_d = 0.8 and σ_d ≈ 0 again,
/// which a model holding the background term at the unscaled transmittance does not.
#[test]
fn ga_of_a_render_against_itself_has_unit_mu_and_vanishing_sigma() {
    let nerf = common::tiny_nerf();
    let mut rays = common::view_rays(24);
    rays.push(nerfsv_nerf::RayInput { origin: [5.0, 5.0, 5.0].into(), direction: [0.0, 0.0, 1.0].into(), ..rays[0] });
    let render = nerf.render_rays(&rays);
    let reference: Vec<[f32; 3]> = render.rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    assert!(render.opacity.iter().any(|&o| o > 0.5) && render.opacity.iter().any(|&o| o < 0.3));
    let fit = ga_image(&nerf, "self", &rays, &reference, 3.0, 0.05).unwrap();
    assert!((fit.mu_d - 1.0).abs() < 1e-5, "μ_d {}", fit.mu_d);
    assert!(fit.sigma_d < 1e-3, "σ_d {}", fit.sigma_d);
    assert_eq!(fit.rays_without_samples, 1);
    // The render with every compositing weight scaled by 0.8: bg + 0.8·Σ d_i (c_i − bg).
    let samples = nerf.render_rays_samples(&rays);
    let scaled: Vec<[f32; 3]> = (0..rays.len())
        .map(|i| {
            let (c, w) = samples.ray(i);
            let bg = rays[i].background;
            [0, 1, 2].map(|ch| {
                let sum: f64 = c.iter().zip(w).map(|(c, &w)| (c[ch] - bg[ch]) as f64 * w as f64).sum();
                (bg[ch] as f64 + 0.8 * sum) as f32
            })
        })
        .collect();
    let fit2 = ga_image(&nerf, "scaled", &rays, &scaled, 3.0, 0.05).unwrap();
    assert!((fit2.mu_d - 0.8).abs() < 1e-4, "μ_d {}", fit2.mu_d);
    assert!(fit2.sigma_d < 1e-3, "σ_d {}", fit2.sigma_d);
    // A colour change no density scale explains (the reference 20 % darker): a larger σ_d.
    let dim: Vec<[f32; 3]> = reference.iter().map(|c| c.map(|v| 0.8 * v)).collect();
    let fit3 = ga_image(&nerf, "dim", &rays, &dim, 3.0, 0.05).unwrap();
    assert!(fit3.sigma_d > 10.0 * fit.sigma_d, "{} {}", fit3.mu_d, fit3.sigma_d);
    // Bad input names the image.
    let err = ga_image(&nerf, "short", &rays, &reference[1..], 3.0, 0.05).unwrap_err();
    assert!(err.to_string().starts_with("short: "), "{err}");
    let mut nan = reference.clone();
    nan[3][1] = f32::NAN;
    let err = ga_image(&nerf, "nan", &rays, &nan, 3.0, 0.05).unwrap_err();
    assert!(err.to_string().starts_with("nan: reference colour of pixel 3"), "{err}");
}

/// An exact model (r = m) seen through 0.02 pixel noise, a tenth of its rays nearly transparent
/// (opacity 0.02, so s is tiny): the paper's σ_d is driven far from 0 by those rays alone,
/// while the noise-floored σ_d, which knows the noise, is ≈ 0. Its optimum equals a dense scan
/// of the objective over σ (μ optimal at each σ by a golden-section search of its own).
#[test]
fn the_noise_floored_sigma_d_is_near_zero_for_an_exact_model_whose_faint_rays_drive_the_papers() {
    let noise = 0.02;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let rays: Vec<GaRay> = (0..3000)
        .map(|i| {
            let faint = i % 10 == 3;
            let k = rng.random_range(4..16);
            let c: Vec<[f32; 3]> = (0..k).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
            let total = if faint { 0.02 } else { 0.9 + 0.1 * rng.random::<f32>() };
            let w: Vec<f32> = vec![total / k as f32; k];
            let mut ray = GaRay::from_samples(&c, &w, [0.0; 3], [0.0; 3]);
            for ch in 0..3 {
                let e: f64 = StandardNormal.sample(&mut rng);
                ray.r[ch] = ray.m[ch] + noise * e;
            }
            ray
        })
        .collect();
    let fit = ga_fit("noisy", &rays, 3.0, noise).unwrap();
    let opaque: Vec<GaRay> = rays.iter().enumerate().filter(|(i, _)| i % 10 != 3).map(|(_, r)| *r).collect();
    let plain_opaque = ga_fit("opaque", &opaque, 3.0, noise).unwrap().sigma_d;
    eprintln!(
        "paper's σ_d {:.3} (opaque rays alone {plain_opaque:.3}); noise-floored σ_d {:.4}, μ_d {:.4}",
        fit.sigma_d, fit.floored.sigma_d, fit.floored.mu_d
    );
    assert!(fit.sigma_d > 0.5, "the paper's σ_d {} should be driven up by the faint rays", fit.sigma_d);
    assert!(fit.sigma_d > 5.0 * plain_opaque);
    assert!(fit.floored.sigma_d < 0.01, "noise-floored σ_d {}", fit.floored.sigma_d);
    assert!((fit.floored.mu_d - 1.0).abs() < 0.01, "μ_d {}", fit.floored.mu_d);

    // With signal beyond the noise (σ = 0.3 on the same rays), the optimum against a scan.
    let scaled: Vec<GaRay> = rays
        .iter()
        .map(|r| {
            let mut r = *r;
            for ch in 0..3 {
                let (e1, e2): (f64, f64) = (StandardNormal.sample(&mut rng), StandardNormal.sample(&mut rng));
                r.r[ch] = 0.9 * r.m[ch] + 0.3 * r.s[ch].sqrt() * e1 + noise * e2;
            }
            r
        })
        .collect();
    let f = ga_fit("scaled", &scaled, 3.0, noise).unwrap().floored;
    let best_mu = |sigma: f64| golden(0.0, 2.0, 1e-10, |mu| ga_floored_objective(&scaled, mu, sigma, noise));
    let (mut best, mut at) = (f64::INFINITY, 0.0);
    for k in 0..=2000 {
        let sigma = k as f64 * 1e-3;
        let v = ga_floored_objective(&scaled, best_mu(sigma), sigma, noise);
        if v < best {
            (best, at) = (v, sigma);
        }
    }
    assert!((f.sigma_d - at).abs() <= 1e-3, "golden σ_d {} vs scan {at}", f.sigma_d);
    assert!(f.objective <= best + 1e-9 * best.abs(), "{} vs scan {best}", f.objective);
    assert!(
        (f.sigma_d - 0.3).abs() < 0.03 && (f.mu_d - 0.9).abs() < 0.01,
        "σ_d {} μ_d {}: (0.3, 0.9)",
        f.sigma_d,
        f.mu_d
    );
    // Without noise the floored fit is the paper's.
    let exact = ga_fit("scaled", &scaled, 3.0, 1e-9).unwrap();
    assert!((exact.floored.sigma_d - exact.sigma_d).abs() < 1e-6 * exact.sigma_d);
}

/// A profile with two minima: 1000 terms the model explains exactly (their slope at σ = 0 is
/// positive and outweighs the rest there) and 100 faint ones off by ±0.5, which a σ near 1.3
/// explains at a far lower objective. The noise-floored fit takes the lower minimum (a search that
/// stopped at σ = 0, where the slope starts positive, would report the noise alone explaining
/// the image), within a scan's resolution.
#[test]
fn the_noise_floored_fit_takes_the_lower_of_two_minima() {
    let noise = 0.05;
    let mut rays = Vec::new();
    for i in 0..1100 {
        let (m, s, r) = if i < 1000 { (0.5, 0.2, 0.5) } else { (0.5, 0.01, if i % 2 == 0 { 0.0 } else { 1.0 }) };
        rays.push(GaRay { m: [m, 0.0, 0.0], s: [s, 0.0, 0.0], r: [r, 0.0, 0.0] });
    }
    let profile = |sigma: f64| {
        let v = |r: &GaRay| sigma * sigma * r.s[0] + noise * noise;
        let num: f64 = rays.iter().map(|r| r.r[0] * r.m[0] / v(r)).sum();
        let den: f64 = rays.iter().map(|r| r.m[0] * r.m[0] / v(r)).sum();
        ga_floored_objective(&rays, num / den, sigma, noise)
    };
    let (mut best, mut at) = (f64::INFINITY, 0.0);
    for k in 0..=3000 {
        let sigma = k as f64 * 1e-3;
        if profile(sigma) < best {
            (best, at) = (profile(sigma), sigma);
        }
    }
    // The case is what it says: a local minimum at 0, the global one inside.
    assert!(profile(0.0) < profile(0.01) && at > 1.0 && best < profile(0.0) - 1000.0, "{at} {best}");
    let f = ga_fit("two minima", &rays, 3.0, noise).unwrap().floored;
    assert!((f.sigma_d - at).abs() <= 1e-3, "σ_d {} vs scan {at}", f.sigma_d);
    assert!(f.objective <= best + 1e-9 * best.abs(), "{} vs scan {best}", f.objective);
}
