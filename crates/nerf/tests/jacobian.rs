//! `Nerf::render_rays_jacobian`: the colour's derivatives with respect to ray origin and
//! direction (sample distances fixed) against central differences, and its agreement with
//! `render_rays`, on a model trained briefly on the tiny scene.

mod common;

use std::sync::OnceLock;

use common::{tiny_config, tiny_split, tiny_train_config};
use nerfsv_nerf::fields::Tensor;
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{Nerf, RayInput, Trainer};

/// 300 steps on 16 views of the tiny scene: sharp, non-trivial density and view-dependent colour.
fn model() -> &'static Nerf {
    static MODEL: OnceLock<Nerf> = OnceLock::new();
    MODEL.get_or_init(|| {
        let data = tiny_split(16, 24, 0.0);
        let mut t = Trainer::new(tiny_config(), tiny_train_config(2), &data).unwrap();
        for _ in 0..300 {
            t.step().unwrap();
        }
        t.into_nerf()
    })
}

/// The pixel rays of a held-out 24×24 view on a grey background.
fn view_rays() -> Vec<RayInput> {
    camera_rays(&tiny_split(1, 24, 0.37).frames[0].camera, [0.3, 0.5, 0.7])
}

fn frob(m: &[[f32; 3]; 3]) -> f64 {
    m.iter().flatten().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt()
}

/// An f64 re-implementation of the model's forward (hash encoding, `sigma_net`, SH, colour
/// net, compositing) from its public parameters, so that central differences can use steps
/// small enough (1e-6 m) to rarely straddle a hash-cell face or a ReLU kink: in f32 the
/// rounding noise forces h ≳ 1e-5 m, where the dense kinks of a trained model spoil a few
/// percent of the difference quotients.
mod reference {
    use nerfsv_nerf::fields::Tensor;
    use nerfsv_nerf::{Nerf, RayInput};

    fn encode(nerf: &Nerf, x: [f64; 3]) -> Vec<f64> {
        let emb = &nerf.params[nerf.field.embeddings_range()];
        let mut out = Vec::new();
        for lv in &nerf.field.encoding.levels {
            let (s, r) = (lv.scale as f64, lv.resolution);
            let p = x.map(|v| v.clamp(0.0, 1.0) * s + 0.5);
            let g = p.map(|v| v.floor());
            let mut y = [0.0f64; 2];
            for c in 0..8u32 {
                let ijk = [0, 1, 2].map(|d| g[d] as u32 + ((c >> d) & 1));
                let h = if lv.dense {
                    ijk[0].wrapping_add(ijk[1].wrapping_mul(r)).wrapping_add(ijk[2].wrapping_mul(r * r))
                } else {
                    ijk[0] ^ ijk[1].wrapping_mul(2_654_435_761) ^ ijk[2].wrapping_mul(805_459_861)
                };
                let row = (lv.offset + h % lv.size) as usize;
                let w: f64 =
                    (0..3).map(|d| if (c >> d) & 1 == 1 { p[d] - g[d] } else { 1.0 - (p[d] - g[d]) }).product();
                y[0] += w * emb[2 * row] as f64;
                y[1] += w * emb[2 * row + 1] as f64;
            }
            out.extend(y);
        }
        out
    }

    /// `y = W·x` for torch `[out, in]` weights, optionally ReLU'd.
    fn linear(nerf: &Nerf, tensor: Tensor, x: &[f64], relu: bool) -> Vec<f64> {
        let (shape, range) = &nerf.field.tensors[tensor.index()];
        let w = &nerf.params[range.clone()];
        (0..shape[0])
            .map(|o| {
                let v: f64 = x.iter().zip(&w[o * shape[1]..(o + 1) * shape[1]]).map(|(a, &b)| a * b as f64).sum();
                if relu {
                    v.max(0.0)
                } else {
                    v
                }
            })
            .collect()
    }

    /// `sigma_net` output `[o_0, geo…]` at a world point.
    fn sigma_net(nerf: &Nerf, p: [f64; 3]) -> Vec<f64> {
        let f = &nerf.field;
        let x = [0, 1, 2].map(|d| (p[d] - f.aabb_min[d] as f64) / (f.aabb_max[d] as f64 - f.aabb_min[d] as f64));
        let h = linear(nerf, Tensor::Sigma0, &encode(nerf, x), true);
        linear(nerf, Tensor::Sigma1, &h, false)
    }

    /// σ (1/m) at a world point inside the box.
    pub fn density(nerf: &Nerf, p: [f64; 3]) -> f64 {
        sigma_net(nerf, p)[0].min(80.0).exp()
    }

    fn sh(d: [f64; 3]) -> [f64; 16] {
        let [x, y, z] = d;
        let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
        [
            0.282_094_8,
            -0.488_602_52 * y,
            0.488_602_52 * z,
            -0.488_602_52 * x,
            1.092_548_5 * xy,
            -1.092_548_5 * yz,
            0.946_174_7 * zz - 0.315_391_57,
            -1.092_548_5 * xz,
            0.546_274_2 * (xx - yy),
            0.590_043_6 * y * (-3.0 * xx + yy),
            2.890_611_4 * xy * z,
            0.457_045_8 * y * (1.0 - 5.0 * zz),
            0.373_176_33 * z * (5.0 * zz - 3.0),
            0.457_045_8 * x * (1.0 - 5.0 * zz),
            1.445_305_7 * z * (xx - yy),
            0.590_043_6 * x * (-xx + 3.0 * yy),
        ]
    }

    /// The colour of a ray composited from samples at the fixed distances `ts`.
    pub fn colour(nerf: &Nerf, o: [f64; 3], d: [f64; 3], bg: [f32; 3], ts: &[f32]) -> [f64; 3] {
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let view = sh(d.map(|v| v / n));
        let dt = nerf.config.step_size as f64;
        let (mut trans, mut c) = (1.0f64, [0.0f64; 3]);
        for &t in ts {
            let out = sigma_net(nerf, [0, 1, 2].map(|a| o[a] + t as f64 * d[a]));
            let cin: Vec<f64> = view.iter().chain(&out[1..]).copied().collect();
            let h1 = linear(nerf, Tensor::Color0, &cin, true);
            let h2 = linear(nerf, Tensor::Color1, &h1, true);
            let rgb = linear(nerf, Tensor::Color2, &h2, false);
            let alpha = 1.0 - (-out[0].min(80.0).exp() * dt).exp();
            for ch in 0..3 {
                c[ch] += trans * alpha / (1.0 + (-rgb[ch]).exp());
            }
            trans *= 1.0 - alpha;
        }
        [0, 1, 2].map(|ch| c[ch] + trans * bg[ch] as f64)
    }

    /// A vector's components in f64.
    pub fn f64s(v: nalgebra::Vector3<f32>) -> [f64; 3] {
        [0, 1, 2].map(|a| f64::from(v[a]))
    }

    pub fn ray_colour(nerf: &Nerf, r: &RayInput, ts: &[f32]) -> [f64; 3] {
        colour(nerf, f64s(r.origin.coords), f64s(r.direction), r.background, ts)
    }
}

/// Central differences (f64 reference, h = 1e-8) of the fixed-distance colour in each component
/// of the origin and the direction, against the analytic Jacobians, on rays that hit the
/// geometry.
///
/// Tolerance, relative to the Jacobian's Frobenius norm: 1e-3 for 90 % of them, 1e-2 for all.
/// The analytic f32 Jacobian sums ~100 samples' terms of either sign (≈3e-5 relative rounding
/// seen); the f64 quotient's own rounding is ≈1e-7. The colour is only piecewise smooth: a
/// stencil straddling a hash-cell face or a ReLU kink averages two slopes — at h = 1e-6 that
/// happened on a few percent of the rays (errors up to 2 %), at h = 1e-8 it is a per-mille event,
/// hence the looser bound for the few. A dropped or mis-scaled term (view direction, density or
/// colour path, box extent, a `t_i` factor) is off by far more on most rays.
#[test]
fn ray_jacobians_match_central_differences_with_fixed_sample_distances() {
    let nerf = model();
    let all = view_rays();
    let out = nerf.render_rays_jacobian(&all);
    let picks: Vec<usize> = (0..all.len()).filter(|&i| out.opacity[i] > 0.9).step_by(5).take(24).collect();
    assert!(picks.len() >= 16, "only {} rays hit the geometry", picks.len());
    let rays: Vec<RayInput> = picks.iter().map(|&i| all[i]).collect();
    let ts = nerf.composited_sample_distances(&rays);
    // The f32 path of the same function (the doc-hidden helper) agrees with the render.
    let fixed = nerf.render_rays_at_distances(&rays, &ts);
    let h = 1e-8f64;
    let (mut errs, mut norms) = (Vec::new(), Vec::new());
    for (k, &i) in picks.iter().enumerate() {
        let base = reference::ray_colour(nerf, &rays[k], &ts[k]);
        for c in 0..3 {
            assert!((fixed[k][c] - out.rgb[i][c]).abs() < 1e-5, "ray {i}: {:?} vs {:?}", fixed[k], out.rgb[i]);
            assert!((base[c] - out.rgb[i][c] as f64).abs() < 1e-4, "ray {i}: f64 {base:?} vs f32 {:?}", out.rgb[i]);
        }
        for (which, an) in [("origin", &out.d_origin[i]), ("direction", &out.d_direction[i])] {
            let mut fd = [[0.0f64; 3]; 3];
            for a in 0..3 {
                let shifted = |s: f64| {
                    let (mut o, mut d) = (reference::f64s(rays[k].origin.coords), reference::f64s(rays[k].direction));
                    let v = if which == "origin" { &mut o } else { &mut d };
                    v[a] += s;
                    reference::colour(nerf, o, d, rays[k].background, &ts[k])
                };
                let (p, m) = (shifted(h), shifted(-h));
                for c in 0..3 {
                    fd[c][a] = (p[c] - m[c]) / (2.0 * h);
                }
            }
            let norm = frob(an);
            let err = (0..9).map(|q| (an[q / 3][q % 3] as f64 - fd[q / 3][q % 3]).powi(2)).sum::<f64>().sqrt() / norm;
            assert!(err < 1e-2, "ray {i} ∂rgb/∂{which}: analytic {an:?} vs fd {fd:?} (relative error {err:.2e})");
            errs.push(err);
            norms.push(norm);
        }
    }
    errs.sort_by(f64::total_cmp);
    let p90 = errs[errs.len() * 9 / 10];
    eprintln!("relative error: median {:.1e}, p90 {p90:.1e}, max {:.1e}", errs[errs.len() / 2], errs[errs.len() - 1]);
    assert!(p90 < 1e-3, "90th percentile of the relative error {p90:.2e}");
    // The check has teeth only if the Jacobians are large (surface rays).
    assert!(norms.iter().all(|&n| n > 0.5), "{norms:?}");
}

#[test]
fn ray_jacobian_render_gives_render_rays_colour_opacity_and_distance_bit_for_bit() {
    let nerf = model();
    let rays = view_rays();
    let plain = nerf.render_rays(&rays);
    let jac = nerf.render_rays_jacobian(&rays);
    assert_eq!(jac.rgb.len(), rays.len());
    for i in 0..rays.len() {
        assert_eq!(jac.rgb[i], [plain.rgb[3 * i], plain.rgb[3 * i + 1], plain.rgb[3 * i + 2]], "ray {i}");
    }
    assert_eq!(jac.opacity, plain.opacity);
    assert_eq!(jac.distance, plain.distance);
    assert!(jac.opacity.iter().any(|&o| o > 0.9) && jac.opacity.iter().any(|&o| o < 0.1));
}

#[test]
fn ray_jacobians_are_bit_identical_with_one_or_two_threads() {
    let nerf = model();
    let rays = view_rays();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| nerf.render_rays_jacobian(&rays))
    };
    let (a, b) = (run(1), run(2));
    assert!(a.d_origin.iter().any(|m| frob(m) > 0.0));
    assert!(a == b, "Jacobians differ between 1 and 2 threads");
}

/// ∇σ of the trained model against central differences of the f64 reference (h = 1e-8 m), at
/// points around the sphere's surface where the density is large; points whose stencil crosses
/// a hash-cell face at any level are skipped (σ is only C⁰ there). Tolerance 1e-3 of |∇σ|:
/// f32 rounding of the analytic gradient is ≈1e-5, a ReLU kink inside so small a stencil rare.
#[test]
fn density_gradient_matches_central_differences_on_a_trained_model() {
    use nerfsv_nerf::field_components::hash_encoding::corners_frac;
    let nerf = model();
    let f = &nerf.field;
    let h = 1e-8f64;
    let mut checked = 0;
    for i in 0..400 {
        // Points near the sphere's surface (centre (0, 0, 0.3), r = 0.45).
        let (th, ph) = (i as f32 * 2.399, (i as f32 * 0.618).fract() * std::f32::consts::PI);
        let r = 0.4 + 0.1 * ((i * 7 % 11) as f32 / 10.0);
        let p = [r * ph.sin() * th.cos(), r * ph.sin() * th.sin(), 0.3 + r * ph.cos()];
        let crosses = (0..3).any(|a| {
            [1e-5f32, -1e-5].iter().any(|&s| {
                let mut q = p;
                q[a] += s;
                let (x0, x1) = (f.normalize(p), f.normalize(q));
                f.encoding.levels.iter().any(|lv| corners_frac(lv, x0).0 != corners_frac(lv, x1).0)
            })
        });
        let (sigma, grad) = nerf.density_and_gradient(&[p.into()]);
        assert_eq!(sigma[0], nerf.density(&[p.into()])[0]);
        if crosses || sigma[0] < 1.0 {
            continue;
        }
        let p64 = p.map(f64::from);
        let mut fd = [0.0f64; 3];
        for a in 0..3 {
            let (mut qp, mut qm) = (p64, p64);
            qp[a] += h;
            qm[a] -= h;
            fd[a] = (reference::density(nerf, qp) - reference::density(nerf, qm)) / (2.0 * h);
        }
        let g = reference::f64s(grad[0]);
        let err = ((0..3).map(|a| (g[a] - fd[a]).powi(2)).sum::<f64>()).sqrt();
        let norm = (g.iter().map(|v| v * v).sum::<f64>()).sqrt();
        assert!(err <= 1e-3 * norm, "at {p:?} (σ = {}): ∇σ {g:?} vs fd {fd:?}", sigma[0]);
        checked += 1;
    }
    assert!(checked >= 30, "only {checked} points checked");
    // Outside the box: no density, no gradient.
    assert_eq!(nerf.density_and_gradient(&[[5.0, 0.0, 0.0].into()]), (vec![0.0], vec![nalgebra::Vector3::zeros()]));
}

/// The forward pass kept for later differentiation: a `RayRender` reused for a second, different
/// batch of rays gives that batch exactly what `render_rays_jacobian` gives, colours before the
/// reverse pass included.
#[test]
fn a_reused_ray_render_gives_the_one_call_jacobians_of_its_last_rays() {
    let nerf = model();
    let rays = view_rays();
    let mut r = nerf.ray_render();
    r.render(&rays[..100]);
    let tail = &rays[rays.len() - 70..];
    r.render(tail);
    let once = nerf.render_rays_jacobian(tail);
    assert_eq!(r.rgb(), &once.rgb[..]);
    assert_eq!((r.opacity(), r.distance()), (&once.opacity[..], &once.distance[..]));
    assert_eq!(r.jacobians(), once);
    assert!(once.d_origin.iter().any(|m| frob(m) > 0.5));
}

/// The density-only path of [`RayRender::jacobians_above`]: on a model whose colours do not
/// depend on position (the colour net's geometry-feature weights zeroed), a sample's whole
/// contribution to `∂C/∂o` is its density term, so taking every sample through the density
/// path alone must give the full reverse pass's `∂C/∂o` (up to rounding).
#[test]
fn the_density_only_path_is_exact_when_colours_do_not_depend_on_position() {
    let mut nerf = model().clone();
    // color_net.0.weight [hidden, 16 + geo]
    let (shape, range) = nerf.field.tensors[Tensor::Color0.index()].clone();
    for row in nerf.params[range].chunks_exact_mut(shape[1]) {
        row[16..].fill(0.0);
    }
    let rays = view_rays();
    let mut r = nerf.ray_render();
    r.render(&rays);
    let (full, thin) = (r.jacobians(), r.jacobians_above(2.0));
    let mut checked = 0;
    for (i, (a, b)) in full.d_origin.iter().zip(&thin.d_origin).enumerate() {
        let err = (0..9).map(|q| ((a[q / 3][q % 3] - b[q / 3][q % 3]) as f64).powi(2)).sum::<f64>().sqrt();
        assert!(err <= 1e-4 * frob(a).max(1e-3), "ray {i}: full {a:?} vs density only {b:?}");
        checked += (frob(a) > 0.1) as usize;
    }
    assert!(checked > 50, "only {checked} rays with a Jacobian to compare");
}

/// With a threshold, samples of little compositing weight lose only their colour's own change
/// with position: on the trained model the pose Jacobians of the rays that hit the geometry
/// stay within a few percent of the exact ones, and the threshold does change them (the cheap
/// path ran). A threshold of 0 is the exact pass, bit for bit.
#[test]
fn a_weight_threshold_changes_the_jacobians_by_a_few_percent() {
    let nerf = model();
    let rays = view_rays();
    let mut r = nerf.ray_render();
    r.render(&rays);
    let exact = r.jacobians();
    assert_eq!(r.jacobians_above(0.0), exact);
    let approx = r.jacobians_above(0.01);
    let (mut errs, mut changed) = (Vec::new(), 0);
    for i in (0..rays.len()).filter(|&i| exact.opacity[i] > 0.9) {
        for (a, b) in [(&exact.d_origin[i], &approx.d_origin[i]), (&exact.d_direction[i], &approx.d_direction[i])] {
            let err = (0..9).map(|q| ((a[q / 3][q % 3] - b[q / 3][q % 3]) as f64).powi(2)).sum::<f64>().sqrt();
            changed += (err > 0.0) as usize;
            errs.push(err / frob(a).max(1e-6));
        }
    }
    errs.sort_by(f64::total_cmp);
    let (median, p90) = (errs[errs.len() / 2], errs[errs.len() * 9 / 10]);
    eprintln!("relative change: median {median:.1e}, p90 {p90:.1e}, max {:.1e}", errs[errs.len() - 1]);
    assert!(changed > errs.len() / 10, "the threshold changed only {changed} of {} Jacobians", errs.len());
    assert!(median < 0.05 && p90 < 0.15, "relative change median {median:.1e}, p90 {p90:.1e}");
}

/// Rendering marches in rounds of `RENDER_ROUND` samples, training in rounds of `TRAIN_ROUND`:
/// with either walk, a ray's colour, opacity and depth do not depend on the round (only how many
/// samples past its termination get a density), bit for bit, and shorter rounds evaluate fewer
/// samples.
#[test]
fn a_rays_render_does_not_depend_on_the_marching_round() {
    use nerfsv_nerf::fields::{ChunkWorkspace, March, Walk};
    let nerf = model();
    let rays = view_rays();
    let c = &nerf.config;
    for walk in [Walk::CellByCell, Walk::Blocks] {
        let render = |round: usize| {
            let mut ws = ChunkWorkspace::default();
            let mut out = (Vec::new(), Vec::new(), Vec::new(), 0);
            for chunk in rays.chunks(64) {
                let march = March {
                    step: c.step_size,
                    max_samples: c.max_samples_per_ray,
                    t_min: c.early_stop_transmittance,
                    round,
                    walk,
                };
                ws.forward(&nerf.field, &nerf.params, chunk, &nerf.grid, &march);
                out.0.extend_from_slice(&ws.color);
                out.1.extend_from_slice(&ws.opacity);
                out.2.extend_from_slice(&ws.depth);
                out.3 += ws.n_samples();
            }
            out
        };
        let long = render(16);
        for round in [1, 4] {
            let short = render(round);
            assert_eq!((&short.0, &short.1, &short.2), (&long.0, &long.1, &long.2), "{walk:?}, round {round}");
            assert!(short.3 < long.3, "{walk:?}, round {round}: {} samples against {}", short.3, long.3);
        }
    }
}

/// Rendering's walk (the lattice by index, empty blocks skipped) and training's (cell by cell,
/// the lattice position accumulated) sample the same occupied lattice points, whose distances
/// differ in the last bits: the same view renders to within 1e-4 per channel with either, and
/// the two evaluate the same number of samples within a few.
#[test]
fn rendering_and_training_walks_render_the_same_view() {
    use nerfsv_nerf::fields::{ChunkWorkspace, March, Walk, RENDER_ROUND};
    let nerf = model();
    let rays = view_rays();
    let c = &nerf.config;
    let render = |walk: Walk| {
        let mut ws = ChunkWorkspace::default();
        let (mut rgb, mut samples) = (Vec::new(), 0);
        for chunk in rays.chunks(64) {
            let march = March {
                step: c.step_size,
                max_samples: c.max_samples_per_ray,
                t_min: c.early_stop_transmittance,
                round: RENDER_ROUND,
                walk,
            };
            ws.forward(&nerf.field, &nerf.params, chunk, &nerf.grid, &march);
            rgb.extend_from_slice(&ws.color);
            samples += ws.n_samples();
        }
        (rgb, samples)
    };
    let ((cells, n_cells), (blocks, n_blocks)) = (render(Walk::CellByCell), render(Walk::Blocks));
    let worst = cells.iter().zip(&blocks).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    eprintln!("{n_cells} against {n_blocks} samples, largest colour difference {worst:.1e}");
    assert!(n_cells > 1000 && n_cells.abs_diff(n_blocks) <= 4, "{n_cells} against {n_blocks} samples");
    assert!(worst < 1e-4, "largest colour difference {worst:.1e}");
    assert_eq!(nerf.render_rays(&rays).rgb, blocks, "render_rays walks by blocks");
}
