//! Per-pixel uncertainty maps: GA's closed form (NaN without samples, linear in σ_d) and BLA's
//! batched `|j·L|²` against the quadratic form `jᵀΣj` computed naively.

// Dense-matrix oracles read best as index loops.
#![allow(clippy::needless_range_loop)]

mod common;

use faer::Mat;
use nalgebra::{Point3, Vector3};
use nerfsv_nerf::render::camera_rays;
use nerfsv_scene::{Camera, Intrinsics};
use nerfsv_uq::maps::{bla_ray_variances, ga_ray_std};
use nerfsv_uq::{bla_maps, ga_maps, CovarianceFactor, UqError};
use rand::{RngExt, SeedableRng};

const BG: [f32; 3] = [0.5, 0.5, 0.5];

/// 12×10 pixels looking at the tiny model's box from 3 m along −y, 80° wide: the outer columns
/// miss the box.
fn camera() -> Camera {
    let k = Intrinsics::from_fov_x(12, 10, 80f32.to_radians());
    Camera::look_at(Point3::new(0.0, -3.0, 0.0), Point3::origin(), Vector3::z(), k)
}

/// A random symmetric positive definite `[p, p]`: `B·Bᵀ·0.02/r + 0.001·I`, `B` `[p, r]` in
/// `U(−1, 1)`.
fn random_covariance(p: usize, r: usize, seed: u64) -> Mat<f64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let b = Mat::from_fn(p, r, |_, _| 2.0 * rng.random::<f64>() - 1.0);
    let mut s = &b * b.transpose() * faer::Scale(0.02 / r as f64);
    for i in 0..p {
        s[(i, i)] += 1e-3;
    }
    s
}

/// `j Σ jᵀ` by the double sum.
fn naive_quadratic_form(j: &[f32], sigma: &Mat<f64>) -> f64 {
    let p = j.len();
    let mut v = 0.0;
    for a in 0..p {
        let mut row = 0.0;
        for b in 0..p {
            row += sigma[(a, b)] * j[b] as f64;
        }
        v += j[a] as f64 * row;
    }
    v
}

#[test]
fn ga_ray_std_is_nan_without_samples_and_matches_its_closed_form() {
    let [c, d] = ga_ray_std(&[], &[], &[], BG, 0.4);
    assert!(c.is_nan() && d.is_nan(), "a ray without samples (s = 0) must give NaN, got {c}, {d}");
    let colours = [[0.2f32, 0.4, 0.6], [0.8, 0.1, 0.5]];
    let weights = [0.3f32, 0.5];
    let t = [1.5f32, 2.0];
    let bg = [0.25f32, 0.5, 1.0];
    let [c, d] = ga_ray_std(&colours, &weights, &t, bg, 0.4);
    let s: [f64; 3] = [0, 1, 2]
        .map(|ch| (0..2).map(|i| ((colours[i][ch] as f64 - bg[ch] as f64) * weights[i] as f64).powi(2)).sum::<f64>());
    let want_c = 0.4 * ((s[0] + s[1] + s[2]) / 3.0).sqrt();
    let a = 0.3f64 + 0.5f64;
    let want_d = 0.4 * ((0.3f64 * 1.5).powi(2) + (0.5f64 * 2.0).powi(2)).sqrt() / a;
    assert!((c - want_c).abs() < 1e-7, "colour std {c} vs {want_c}");
    assert!((d - want_d).abs() < 1e-7, "depth std {d} vs {want_d}");
    // Zero compositing weight: no information, NaN (not 0).
    let [c, _] = ga_ray_std(&colours, &[0.0, 0.0], &t, bg, 0.4);
    assert!(c.is_nan());
}

#[test]
fn ga_maps_scale_linearly_with_sigma_d_and_are_nan_where_rays_miss() {
    let nerf = common::tiny_nerf();
    let cam = camera();
    let a = ga_maps(&nerf, "r_0", &cam, BG, 0.25).unwrap();
    let b = ga_maps(&nerf, "r_0", &cam, BG, 0.75).unwrap();
    assert_eq!((a.width, a.height, a.colour_std.len(), a.depth_std.len()), (12, 10, 120, 120));
    let samples = nerf.render_rays_samples(&camera_rays(&cam, BG));
    let (mut misses, mut hits) = (0, 0);
    for p in 0..120 {
        let empty = samples.ray(p).1.is_empty();
        for (x, y) in [(a.colour_std[p], b.colour_std[p]), (a.depth_std[p], b.depth_std[p])] {
            if empty {
                assert!(x.is_nan() && y.is_nan(), "pixel {p} has no sample: NaN expected, got {x}, {y}");
            } else {
                assert!(x.is_finite() && x > 0.0, "pixel {p}: {x}");
                assert!((y / x - 3.0).abs() < 1e-5, "pixel {p}: σ_d ×3 gives ×{}", y / x);
            }
        }
        if empty {
            misses += 1;
        } else {
            hits += 1;
        }
    }
    assert!(misses >= 20 && hits >= 40, "{misses} misses, {hits} hits: the view must have both");
    // One pixel against the per-ray formula in z-depth.
    let (i, j) = (6u32, 5u32);
    let p = (j * 12 + i) as usize;
    let (c, w) = samples.ray(p);
    let [_, d] = ga_ray_std(c, w, samples.ray_distances(p), BG, 0.25);
    let z = cam.z_depth_factor(i as f32 + 0.5, j as f32 + 0.5) as f64;
    assert!((a.depth_std[p] as f64 - d * z).abs() < 1e-6 * d.abs().max(1.0));
    assert!(matches!(ga_maps(&nerf, "r_0", &cam, BG, -1.0), Err(UqError::Config(_))));
    assert!(matches!(ga_maps(&nerf, "r_0", &cam, BG, f64::NAN), Err(UqError::Config(_))));
}

#[test]
fn bla_pixel_variance_equals_the_naive_quadratic_form() {
    let nerf = common::tiny_nerf();
    let p = nerf.field.sigma_net_range().len();
    let sigma = random_covariance(p, 48, 3);
    let factor = CovarianceFactor::new("r_0", &sigma).unwrap();
    let mut rays = common::view_rays(6);
    rays[4].origin = [5.0, 5.0, 5.0].into(); // away from the box: no samples
    rays[4].direction = [0.0, 0.0, 1.0].into();
    let jac = nerf.render_rays_sigma_jacobian(&rays);
    let var = bla_ray_variances(&jac, &factor);
    assert_eq!(var.len(), rays.len());
    assert!(var[4].iter().all(|v| v.is_nan()), "a ray without samples: {:?}", var[4]);
    for i in [0, 7, 14, 21, 35] {
        assert!(!jac.samples.ray(i).1.is_empty(), "ray {i} must hit the box");
        for q in 0..4 {
            let j = &jac.ray(i)[q * p..(q + 1) * p];
            let want = naive_quadratic_form(j, &sigma);
            assert!(want > 0.0);
            assert!((var[i][q] - want).abs() <= 1e-9 * want, "ray {i} output {q}: |jL|² {} vs jΣjᵀ {want}", var[i][q]);
        }
    }
}

#[test]
fn bla_maps_are_the_per_pixel_quadratic_forms_in_z_depth() {
    let nerf = common::tiny_nerf();
    let p = nerf.field.sigma_net_range().len();
    let sigma = random_covariance(p, 32, 5);
    let cam = camera();
    let maps = bla_maps(&nerf, "r_0", &cam, BG, &sigma).unwrap();
    let rays = camera_rays(&cam, BG);
    let jac = nerf.render_rays_sigma_jacobian(&rays);
    let mut checked = 0;
    for pix in 0..rays.len() {
        if jac.samples.ray(pix).1.is_empty() {
            assert!(maps.colour_std[pix].is_nan() && maps.depth_std[pix].is_nan(), "pixel {pix}");
            continue;
        }
        if pix % 7 != 0 {
            continue;
        }
        let q: Vec<f64> = (0..4).map(|q| naive_quadratic_form(&jac.ray(pix)[q * p..(q + 1) * p], &sigma)).collect();
        let colour = ((q[0] + q[1] + q[2]) / 3.0).sqrt();
        let (i, j) = ((pix % 12) as f32, (pix / 12) as f32);
        let depth = q[3].sqrt() * cam.z_depth_factor(i + 0.5, j + 0.5) as f64;
        assert!((maps.colour_std[pix] as f64 - colour).abs() <= 1e-5 * colour, "pixel {pix}");
        assert!((maps.depth_std[pix] as f64 - depth).abs() <= 1e-5 * depth, "pixel {pix}");
        checked += 1;
    }
    assert!(checked >= 5, "{checked} pixels checked");
    // A covariance of another model's size is refused, naming the image.
    let wrong = Mat::<f64>::identity(p - 1, p - 1);
    let e = bla_maps(&nerf, "r_7", &cam, BG, &wrong).unwrap_err();
    assert!(matches!(e, UqError::CovarianceShape { .. }) && e.to_string().contains("r_7"), "{e}");
    // Not positive definite.
    let neg = Mat::<f64>::identity(p, p) * faer::Scale(-1.0);
    assert!(matches!(bla_maps(&nerf, "r_0", &cam, BG, &neg), Err(UqError::NotPositiveDefinite { .. })));
}
