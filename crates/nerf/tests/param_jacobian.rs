//! `Nerf::render_rays_sigma_jacobian`: the colour's and distance's derivatives with respect to
//! the `sigma_net` weights against central differences of `render_rays`, and its composited
//! samples against the render.

use nerfsv_nerf::{Nerf, NerfConfig, RayInput};
use rand::{RngExt, SeedableRng};

/// A small random model (4 levels, so `P = 64·8 + 16·64 = 1536`) with embeddings large enough
/// for a density of a few 1/m, and a transmittance threshold so low that no ray terminates
/// early: the sample positions then do not depend on the weights, so central differences of
/// `render_rays` differentiate exactly the function the Jacobian is of.
fn model() -> Nerf {
    let cfg = NerfConfig { early_stop_transmittance: 1e-30, ..NerfConfig::tiny() };
    let mut nerf = Nerf::new(cfg, 9).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let r = nerf.field.embeddings_range();
    for v in &mut nerf.params[r] {
        *v = 2.0 * rng.random::<f32>() - 1.0;
    }
    // Colour-net weights 3× torch's init: colours that depend visibly on the geometry features.
    let c = nerf.field.range(nerfsv_nerf::fields::Tensor::Color0).start..nerf.field.n_params;
    for v in &mut nerf.params[c] {
        *v *= 3.0;
    }
    nerf
}

fn rays(n: usize, jitter: f32) -> Vec<RayInput> {
    (0..n)
        .map(|i| {
            let d = [0.3 * (i as f32 - 2.5), 1.0, -0.2 + 0.05 * i as f32];
            let nrm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            RayInput {
                origin: [0.1, -2.0, 0.1].into(),
                direction: d.map(|x| x / nrm).into(),
                background: [0.3, 0.5, 0.9],
                jitter,
            }
        })
        .collect()
}

/// Every (ray, colour) row of the Jacobian over all 1536 weights against central differences
/// (h = 1e-3): relative Frobenius error below 2e-2 per row (seen: ≤ 1e-2). f32 rounding of a
/// quotient is ≈1e-4 absolute per entry (median error 1e-5), which over 1536 entries is 1e-2 of
/// a row's norm; the distance rows (f32 ulp of 2 m over 2h = 1e-4 per entry, norms ≈ 0.04) are
/// checked along their own direction instead, as are the colour rows. A dropped path (geometry
/// features, density, the distance's opacity term, a transposed weight) is off by order one.
#[test]
fn sigma_net_jacobian_matches_central_differences_of_render_rays() {
    let mut nerf = model();
    let rays = rays(6, 0.3);
    let out = nerf.render_rays_sigma_jacobian(&rays);
    let n_p = out.n_params;
    assert_eq!(n_p, nerf.field.sigma_net_range().len());
    assert_eq!(n_p, 64 * 8 + 16 * 64);
    let outputs = |n: &Nerf| {
        let o = n.render_rays(&rays);
        (0..rays.len()).map(|i| [o.rgb[3 * i], o.rgb[3 * i + 1], o.rgb[3 * i + 2], o.distance[i]]).collect::<Vec<_>>()
    };
    let base = outputs(&nerf);
    assert!(out.samples.opacity.iter().all(|&o| o > 0.2 && o < 0.999), "{:?}", out.samples.opacity);
    let mut fd = vec![[0.0f64; 4]; rays.len() * n_p];
    let h = 1e-3f32;
    let r0 = nerf.field.sigma_net_range().start;
    let theta = nerf.params[r0..r0 + n_p].to_vec();
    for p in 0..n_p {
        let v = nerf.params[r0 + p];
        nerf.params[r0 + p] = v + h;
        let plus = outputs(&nerf);
        nerf.params[r0 + p] = v - h;
        let minus = outputs(&nerf);
        nerf.params[r0 + p] = v;
        for i in 0..rays.len() {
            for q in 0..4 {
                fd[i * n_p + p][q] = (plus[i][q] as f64 - minus[i][q] as f64) / (2.0 * h as f64);
            }
        }
    }
    for i in 0..rays.len() {
        for q in 0..4 {
            assert_eq!(if q < 3 { out.samples.rgb[i][q] } else { out.samples.distance[i] }, base[i][q]);
            let an = &out.ray(i)[q * n_p..(q + 1) * n_p];
            let norm = an.iter().map(|&a| (a as f64).powi(2)).sum::<f64>().sqrt();
            assert!(norm > 0.03, "ray {i} output {q}: Jacobian norm {norm:e} too small to test");
            if q < 3 {
                let err = (0..n_p).map(|p| (an[p] as f64 - fd[i * n_p + p][q]).powi(2)).sum::<f64>().sqrt();
                assert!(err < 2e-2 * norm, "ray {i} colour {q}: relative error {:.2e} (norm {norm:.3e})", err / norm);
            }
            // Along the Jacobian's own direction u = J/|J|, the derivative is |J|: one quotient
            // whose rounding (≈1e-4) is √P times smaller relative to it than the entries'.
            let u: Vec<f32> = an.iter().map(|&a| (a as f64 / norm) as f32).collect();
            let shifted = |s: f32, nerf: &mut Nerf| {
                for (p, &up) in u.iter().enumerate() {
                    nerf.params[r0 + p] += s * up;
                }
            };
            shifted(h, &mut nerf);
            let plus = outputs(&nerf)[i][q] as f64;
            shifted(-2.0 * h, &mut nerf);
            let minus = outputs(&nerf)[i][q] as f64;
            nerf.params[r0..r0 + n_p].copy_from_slice(&theta);
            let along = (plus - minus) / (2.0 * h as f64);
            assert!((along - norm).abs() < 1e-2 * norm, "ray {i} output {q}: along J/|J| fd {along:e} vs |J| {norm:e}");
        }
    }
}

/// The composited samples are those of the render: Σ w_i c_i + (1 − Σ w_i)·bg is the colour
/// (to f32 rounding), Σ w_i the opacity; a ray that misses the box has none and a zero
/// Jacobian; the colours are bit-identical to `render_rays`, and so is everything for 1 or 2
/// threads.
#[test]
fn composited_samples_rebuild_the_render_and_are_thread_count_independent() {
    let nerf = model();
    let mut rs = rays(40, 0.0);
    rs[7].origin = [5.0, 5.0, 5.0].into(); // pointing away from the box: no samples
    rs[7].direction = [0.0, 0.0, 1.0].into();
    let plain = nerf.render_rays(&rs);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| (nerf.render_rays_sigma_jacobian(&rs), nerf.render_rays_samples(&rs)))
    };
    let (a, b) = (run(1), run(2));
    assert!(a == b, "outputs differ between 1 and 2 threads");
    let (jac, samples) = a;
    assert_eq!(jac.samples, samples);
    for (i, ray) in rs.iter().enumerate() {
        assert_eq!(samples.rgb[i], [plain.rgb[3 * i], plain.rgb[3 * i + 1], plain.rgb[3 * i + 2]], "ray {i}");
        assert_eq!(samples.opacity[i], plain.opacity[i]);
        assert_eq!(samples.distance[i], plain.distance[i]);
        let (c, w) = samples.ray(i);
        let a: f32 = w.iter().sum();
        assert!((a - samples.opacity[i]).abs() < 1e-5, "ray {i}: Σw {a} vs opacity {}", samples.opacity[i]);
        for ch in 0..3 {
            let col: f32 = c.iter().zip(w).map(|(c, w)| c[ch] * w).sum::<f32>() + (1.0 - a) * ray.background[ch];
            assert!((col - samples.rgb[i][ch]).abs() < 1e-5, "ray {i}: {col} vs {}", samples.rgb[i][ch]);
        }
        // The sample distances rebuild the expected distance D̄ = Σ w_i t_i / A.
        let t = samples.ray_distances(i);
        assert_eq!(t.len(), w.len());
        assert!(t.windows(2).all(|p| p[0] < p[1]), "ray {i}: distances not increasing");
        if a > 1e-6 {
            let d: f32 = t.iter().zip(w).map(|(t, w)| t * w).sum::<f32>() / a;
            assert!((d - samples.distance[i]).abs() < 1e-4, "ray {i}: Σwt/A {d} vs {}", samples.distance[i]);
        }
    }
    assert!(samples.ray(7).0.is_empty());
    assert!(jac.ray(7).iter().all(|&v| v == 0.0));
    assert!(jac.ray(3).iter().any(|&v| v != 0.0));
}

/// The colour-only Jacobian is the full one without its distance rows, bit for bit, with the
/// same composited samples.
#[test]
fn colour_sigma_jacobian_is_the_full_one_without_the_distance_rows() {
    let nerf = model();
    let rays = rays(6, 0.7);
    let full = nerf.render_rays_sigma_jacobian(&rays);
    let colour = nerf.render_rays_colour_sigma_jacobian(&rays);
    let p = full.n_params;
    assert_eq!((full.outputs, colour.outputs, colour.n_params), (4, 3, p));
    assert_eq!(colour.jacobian.len(), rays.len() * 3 * p);
    assert_eq!(colour.samples, full.samples);
    for i in 0..rays.len() {
        assert_eq!(colour.ray(i), &full.ray(i)[..3 * p], "ray {i}");
        assert!(full.ray(i)[3 * p..].iter().any(|&v| v != 0.0), "ray {i}: the distance row must be non-zero to tell");
    }
}
