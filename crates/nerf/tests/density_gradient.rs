//! `Nerf::density_param_gradients`: the density's derivatives with respect to every
//! `sigma_net` weight against central differences of `Nerf::density`.

use nalgebra::Point3;
use nerfsv_nerf::{Nerf, NerfConfig};
use rand::{RngExt, SeedableRng};

/// A small random model (4 levels, `P = 64·8 + 16·64 = 1536`) whose embeddings are large
/// enough that the hidden units switch on and off across the points.
fn model() -> Nerf {
    let mut nerf = Nerf::new(NerfConfig::tiny(), 5).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let r = nerf.field.embeddings_range();
    for v in &mut nerf.params[r] {
        *v = 2.0 * rng.random::<f32>() - 1.0;
    }
    nerf
}

/// Every weight of every point against central differences (h = 1e-3, f64 quotient of f32
/// densities): error below 1 % of the derivative plus `5e-4·σ` (the f32 rounding of σ, a few
/// ulps over 2h). A difference across a ReLU kink (a hidden unit within `h·|e|` of 0, where the
/// one-sided differences disagree by more than 5 % plus their rounding) measures no derivative
/// and is skipped; at most 2 % are. A transposed
/// weight, a dropped ReLU mask or a gradient on the geometry rows is off by order one; the
/// geometry rows must be exactly 0.
#[test]
fn density_gradient_matches_central_differences_for_every_sigma_net_weight() {
    let mut nerf = model();
    let points = [[0.1f32, -0.3, 0.2], [-0.5, 0.4, -0.1], [0.7, 0.6, -0.8], [0.0, 0.05, 0.9]].map(Point3::from);
    let (sigma, grads) = nerf.density_param_gradients(&points);
    assert_eq!(sigma, nerf.density(&points), "densities are those of Nerf::density");
    let p = nerf.field.sigma_net_range().len();
    assert_eq!(p, 1536);
    assert_eq!(grads.len(), points.len() * p);
    assert!(sigma.iter().all(|&s| s > 0.0 && s.is_finite()), "{sigma:?}");
    let r0 = nerf.field.sigma_net_range().start;
    let (sh, e) = (nerf.field.sigma_hidden, nerf.field.enc_dim);
    let h = 1e-3f32;
    let mut worst = 0.0f64;
    let mut nonzero = 0;
    let mut kinks = 0;
    let base = nerf.density(&points);
    for k in 0..p {
        let w = nerf.params[r0 + k];
        nerf.params[r0 + k] = w + h;
        let plus = nerf.density(&points);
        nerf.params[r0 + k] = w - h;
        let minus = nerf.density(&points);
        nerf.params[r0 + k] = w;
        for i in 0..points.len() {
            let fd = (plus[i] as f64 - minus[i] as f64) / (2.0 * h as f64);
            let an = grads[i * p + k] as f64;
            let scale = grads[i * p..(i + 1) * p].iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
            let one_sided = [plus[i] as f64 - base[i] as f64, base[i] as f64 - minus[i] as f64].map(|d| d / h as f64);
            let noise = 5e-4 * sigma[i] as f64;
            if (one_sided[0] - one_sided[1]).abs() > 0.05 * fd.abs() + 2.0 * noise {
                kinks += 1;
                continue;
            }
            let err = (fd - an).abs();
            assert!(err < 1e-2 * an.abs() + noise, "point {i}, weight {k}: analytic {an:e}, fd {fd:e}");
            worst = worst.max(err / scale);
            if an != 0.0 {
                nonzero += 1;
            }
            // W1's geometry rows (1..) do not reach the density.
            if k >= sh * e + sh {
                assert_eq!(an, 0.0, "geometry row weight {k}");
            }
        }
    }
    assert!(nonzero > points.len() * p / 8, "only {nonzero} non-zero derivatives");
    assert!(kinks * 50 <= points.len() * p, "{kinks} differences across a ReLU kink");
    eprintln!("worst error / largest derivative {worst:e}, {kinks} kinks skipped");
}

/// Outside the box the model answers density 0, and its gradient is 0.
#[test]
fn outside_the_box_density_and_gradient_are_zero() {
    let nerf = model();
    let points = [[1.5f32, 0.0, 0.0], [0.0, -1.01, 0.0], [0.2, 0.1, 0.3]].map(Point3::from);
    let (sigma, grads) = nerf.density_param_gradients(&points);
    let p = nerf.field.sigma_net_range().len();
    assert_eq!(&sigma[..2], &[0.0, 0.0]);
    assert!(grads[..2 * p].iter().all(|&g| g == 0.0));
    assert!(sigma[2] > 0.0 && grads[2 * p..].iter().any(|&g| g != 0.0));
}

/// Many points (several parallel chunks) give the rows of one point at a time.
#[test]
fn batched_rows_equal_one_point_at_a_time() {
    let nerf = model();
    let points: Vec<Point3<f32>> = (0..700)
        .map(|i| Point3::new(((i * 37) % 100) as f32 / 60.0 - 0.8, ((i * 11) % 90) as f32 / 50.0 - 0.9, 0.1))
        .collect();
    let (sigma, grads) = nerf.density_param_gradients(&points);
    let p = nerf.field.sigma_net_range().len();
    for i in [0, 255, 256, 699] {
        let (s1, g1) = nerf.density_param_gradients(&points[i..i + 1]);
        assert_eq!(s1[0], sigma[i]);
        assert_eq!(&g1[..], &grads[i * p..(i + 1) * p]);
    }
}
