//! The uncertainty field: BLA's node variance against `∇θσᵀΣ∇θσ` with the dense posterior, its
//! rank-K approximation, GA's splatting, the lookups, the maps and the file.

// Dense-matrix oracles read best as index loops.
#![allow(clippy::needless_range_loop)]

mod common;

use faer::linalg::solvers::{DenseSolveCore, Llt};
use faer::{Mat, Side};
use nalgebra::{Point3, Vector3};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use nerfsv_scene::{Camera, Intrinsics};
use nerfsv_uq::{
    data_term, density_param_count, ga_maps_from_samples, model_id, DensityPosterior, FieldFigures, FieldMethod,
    NodeValues, TrainingView, UncertaintyField, UqConfig, UqError,
};

const BG: [f32; 3] = [0.5, 0.5, 0.5];
const BLACK: [f32; 3] = [0.0; 3];

/// 8×8 pixels looking at the tiny model's box from 3 m, 60° wide, from `eye`.
fn camera(eye: [f32; 3]) -> Camera {
    let k = Intrinsics::from_fov_x(8, 8, 60f32.to_radians());
    Camera::look_at(Point3::from(eye), Point3::origin(), Vector3::z(), k)
}

fn cameras() -> Vec<Camera> {
    vec![camera([0.0, -3.0, 0.3]), camera([2.5, 1.0, 0.8]), camera([-1.0, 2.6, -0.5])]
}

/// A coarse field (4 cells/m: 9³ nodes over the ±1 m box), every hit ray of every view in the
/// data term, every eigenpair kept.
fn cfg() -> UqConfig {
    UqConfig { field_cells_per_metre: 4.0, field_rays_per_image: 1000, field_rank: 65_536, ..UqConfig::default() }
}

fn views<'a>(cams: &'a [Camera], refs: &'a [Vec<[f32; 3]>]) -> Vec<TrainingView<'a>> {
    cams.iter().zip(refs).map(|(c, r)| TrainingView { name: "view", camera: c, reference: r }).collect()
}

/// `D = Σ JᵀJ/σ_n²` over the R, G, B rows of every ray with a sample, by the naive triple loop,
/// as a full `[P, P]` matrix.
fn naive_data_term(nerf: &Nerf, cams: &[Camera], cfg: &UqConfig) -> Mat<f64> {
    let p = nerf.field.sigma_net_range().len();
    let mut d = Mat::<f64>::zeros(p, p);
    for cam in cams {
        let rays = camera_rays(cam, BG);
        let samples = nerf.render_rays_samples(&rays);
        let hit: Vec<_> = (0..rays.len()).filter(|&i| !samples.ray(i).1.is_empty()).map(|i| rays[i]).collect();
        let jac = nerf.render_rays_sigma_jacobian(&hit);
        for r in 0..hit.len() {
            let row = jac.ray(r);
            for c in 0..3 {
                let j = &row[c * p..(c + 1) * p];
                for a in 0..p {
                    if j[a] == 0.0 {
                        continue;
                    }
                    for b in 0..p {
                        d[(a, b)] += j[a] as f64 * j[b] as f64 / (cfg.noise_std * cfg.noise_std);
                    }
                }
            }
        }
    }
    d
}

/// `gᵀΣg` by the double sum.
fn quadratic_form(g: &[f32], sigma: &Mat<f64>) -> f64 {
    let mut s = 0.0;
    for a in 0..g.len() {
        for b in 0..g.len() {
            s += g[a] as f64 * sigma[(a, b)] * g[b] as f64;
        }
    }
    s
}

fn no_progress(_: usize, _: usize) {}

/// The test: the field's variance at a node is `∇θσᵀ Σ ∇θσ` with `Σ = (D + αI)⁻¹` the
/// dense posterior of all the training views' rays (inverted by Cholesky over all P = 1536
/// weights, not through the field's Schur complement and eigen-decomposition), within 1e-5
/// relative (f32 storage of the variance and of g).
#[test]
fn bla_field_variance_at_a_node_equals_the_dense_quadratic_form() {
    let nerf = common::tiny_nerf();
    let cams = cameras();
    let cfg = cfg();
    let refs: Vec<Vec<[f32; 3]>> = cams.iter().map(|c| vec![[0.5; 3]; c.intrinsics.pixels()]).collect();
    let field = UncertaintyField::build_bla(&nerf, "tiny", &views(&cams, &refs), BG, &cfg, &mut no_progress).unwrap();
    assert_eq!(field.method, FieldMethod::Bla);
    assert_eq!(field.geometry.dims, [9, 9, 9]);
    assert_eq!(field.figures.rank, Some(density_param_count(&nerf)));
    assert!(field.figures.rays > 100, "{:?}", field.figures);
    let p = nerf.field.sigma_net_range().len();
    let mut h = naive_data_term(&nerf, &cams, &cfg);
    for i in 0..p {
        h[(i, i)] += cfg.prior_precision;
    }
    let sigma = Llt::new(h.as_ref(), Side::Lower).unwrap().inverse();
    let g = field.geometry;
    let mut checked = 0;
    for node in (0..g.len()).step_by(37) {
        let [i, j, k] = g.coords(node);
        let (s, grad) = nerf.density_param_gradients(&[g.position_of(i, j, k)]);
        assert_eq!(field.density[node], s[0]);
        let dense = quadratic_form(&grad, &sigma);
        let prior_only = grad.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / cfg.prior_precision;
        let got = field.variance[node] as f64;
        assert!((got - dense).abs() <= 1e-5 * dense, "node {node}: field {got:e}, dense {dense:e}");
        // The data must matter: the posterior is tighter than the prior (by ≈ 3 % on this
        // random model seen by 3 views of 8×8 pixels).
        if dense < 0.99 * prior_only {
            checked += 1;
        }
    }
    assert!(checked >= 15, "the views constrain only {checked} of the 20 checked nodes");
}

/// Rank K: an upper bound that decreases monotonically with K to the dense value, exactly
/// reached at K = m (1e-9 relative, all in f64); the Cholesky route gives the dense value.
#[test]
fn rank_k_variance_decreases_with_k_to_the_dense_value() {
    let nerf = common::tiny_nerf();
    let cams = cameras();
    let cfg = cfg();
    let refs: Vec<Vec<[f32; 3]>> = cams.iter().map(|c| vec![[0.5; 3]; c.intrinsics.pixels()]).collect();
    let (d, images, _) = data_term(&nerf, &views(&cams, &refs), BG, &cfg, &mut no_progress);
    assert_eq!(images, 3);
    let m = density_param_count(&nerf);
    let post = DensityPosterior::new(&d, m, cfg.prior_precision).unwrap();
    assert!(post.eigenvalues.windows(2).all(|w| w[0] >= w[1]));
    let dense = post.covariance();
    let points: Vec<nalgebra::Point3<f32>> =
        (0..20).map(|i| nalgebra::Point3::new(0.09 * i as f32 - 0.9, 0.3 - 0.02 * i as f32, 0.1)).collect();
    let (_, grads) = nerf.density_param_gradients(&points);
    let p = nerf.field.sigma_net_range().len();
    let ranks = [4, 16, 64, 256, m];
    let per_rank: Vec<Vec<f64>> = ranks.iter().map(|&k| post.variances_low_rank(&grads, p, k)).collect();
    let exact_route = post.variances_exact(&grads, p);
    let mut strict = 0;
    for (n, _) in points.iter().enumerate() {
        let exact = quadratic_form(&grads[n * p..n * p + m], &dense);
        let errors: Vec<f64> = per_rank.iter().map(|v| v[n] - exact).collect();
        for w in errors.windows(2) {
            assert!(w[1] <= w[0] + 1e-9 * exact, "point {n}: errors {errors:?}");
        }
        assert!(errors[0] >= -1e-9 * exact, "rank-K is an upper bound: {errors:?}");
        assert!(errors[ranks.len() - 1].abs() <= 1e-9 * exact, "point {n}: K = m error {errors:?}");
        assert!((exact_route[n] - exact).abs() <= 1e-9 * exact, "point {n}: Cholesky route {}", exact_route[n]);
        if errors[0] > 1e-3 * exact {
            strict += 1;
        }
    }
    assert!(strict >= 10, "rank 4 is exact on {} of 20 points: the test sees no truncation", 20 - strict);
    assert!(post.mass_kept(4) < post.mass_kept(64) && (post.mass_kept(m) - 1.0).abs() < 1e-12);
}

/// References over a black background (the untrained model's colours are ≈ 0.5, the grey
/// background's: against it every s would be ≈ 0 and the f32 references' rounding would
/// count) that make every ray's own GA term `mean_c (r − μ̂m)²/s` equal `c` with `μ̂ = 1`
/// exactly: the residual `e_c = √(c·s_c)·u_c` with `|u|² = 3` and `u ⊥ (m_c/√s_c)`, so each
/// ray adds nothing to `Σ r m/s − Σ m²/s`.
fn references_with_constant_ray_variance(nerf: &Nerf, cam: &Camera, c: f64) -> Vec<[f32; 3]> {
    let rays = camera_rays(cam, BLACK);
    let samples = nerf.render_rays_samples(&rays);
    (0..rays.len())
        .map(|i| {
            let (cols, w) = samples.ray(i);
            if w.is_empty() {
                return [0.3; 3];
            }
            let ga = nerfsv_uq::GaRay::from_samples(cols, w, [0.0; 3], BLACK);
            let a = [0, 1, 2].map(|ch| ga.m[ch] / ga.s[ch].sqrt());
            let b = [1.0, 2.0, 3.0];
            let mut u = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
            let n = (u.iter().map(|x| x * x).sum::<f64>() / 3.0).sqrt();
            u = u.map(|x| x / n);
            // ga.r = 0 − bg = 0, so the reference is m + √(c·s)·u.
            [0, 1, 2].map(|ch| (-ga.r[ch] + ga.m[ch] + (c * ga.s[ch]).sqrt() * u[ch]) as f32)
        })
        .collect()
}

/// GA: rays whose own σ̂² is a known constant give that constant at every node with weight,
/// and 0 with weight 0 elsewhere; some nodes have no data.
#[test]
fn ga_splat_of_rays_with_a_constant_variance_gives_it_at_every_node_with_weight() {
    let nerf = common::tiny_nerf();
    let cams = cameras();
    let c = 0.04;
    let refs: Vec<Vec<[f32; 3]>> =
        cams.iter().map(|cam| references_with_constant_ray_variance(&nerf, cam, c)).collect();
    let field =
        UncertaintyField::build_ga(&nerf, "tiny", &views(&cams, &refs), BLACK, &cfg(), &mut no_progress).unwrap();
    assert_eq!(field.figures.images, 3);
    let (mut with, mut without) = (0, 0);
    for (n, (&v, &w)) in field.variance.iter().zip(&field.weight).enumerate() {
        if w > 0.0 {
            with += 1;
            assert!((v as f64 - c).abs() < 1e-4 * c, "node {n}: {v} with weight {w}");
        } else {
            without += 1;
            assert_eq!(v, 0.0);
        }
    }
    assert!(with > 50, "{with} nodes with data, {without} without");
    assert_eq!(field.figures.nodes_with_data, with);
    // And the per-view lookup of such a field is √c.
    let pixels: Vec<[u32; 2]> = (0..8).flat_map(|j| (0..8).map(move |i| [i, j])).collect();
    let u = field.view_uncertainty(&cams[0], &pixels, BG);
    assert!((u - c.sqrt()).abs() < 1e-4, "{u}");
}

fn constant_field(nerf: &Nerf, method: FieldMethod, c: f32) -> UncertaintyField {
    let geometry = nerfsv_uq::field_geometry(nerf, 4.0).unwrap();
    let density: Vec<f32> = (0..geometry.len()).map(|n| 0.5 + (n % 7) as f32).collect::<Vec<_>>();
    let variance = match method {
        FieldMethod::Ga => vec![c; geometry.len()],
        FieldMethod::Bla | FieldMethod::Ensemble => density.iter().map(|s| c * s * s).collect(),
    };
    let weight = vec![1.0; geometry.len()];
    UncertaintyField::from_parts(
        method,
        geometry,
        NodeValues { density, variance, weight },
        model_id(nerf),
        "m".into(),
        FieldFigures::default(),
    )
    .unwrap()
}

/// A field whose looked-up value is a constant c (GA σ̂² = c; BLA Var = c·σ²) answers √c for a
/// view that sees it, and 0 for a view whose rays miss the grid.
#[test]
fn view_uncertainty_of_a_constant_field_is_its_square_root() {
    let nerf = common::tiny_nerf();
    let pixels: Vec<[u32; 2]> = (0..8).flat_map(|j| (0..8).map(move |i| [i, j])).collect();
    for method in [FieldMethod::Ga, FieldMethod::Bla] {
        let field = constant_field(&nerf, method, 0.09);
        let u = field.view_uncertainty(&cameras()[0], &pixels, BG);
        assert!((u - 0.3).abs() < 1e-5, "{method:?}: {u}");
        let away = Camera::look_at(
            Point3::new(0.0, -3.0, 0.0),
            Point3::new(0.0, -6.0, 0.0),
            Vector3::z(),
            cameras()[0].intrinsics,
        );
        assert_eq!(field.view_uncertainty(&away, &pixels, BG), 0.0);
    }
    // No data anywhere (GA, weight 0): nothing composites.
    let mut empty = constant_field(&nerf, FieldMethod::Ga, 0.09);
    empty = UncertaintyField::from_parts(
        FieldMethod::Ga,
        empty.geometry,
        NodeValues { density: empty.density, variance: empty.variance, weight: vec![0.0; empty.weight.len()] },
        empty.checkpoint_id,
        empty.checkpoint,
        FieldFigures::default(),
    )
    .unwrap();
    assert_eq!(empty.view_uncertainty(&cameras()[0], &pixels, BG), 0.0);
}

/// GA maps of a constant field c are GA's maps with σ_d = √c (colour and depth, 1e-5); BLA's
/// standard deviations scale as the square root of the field's variance and vanish with it.
#[test]
fn maps_of_a_constant_ga_field_are_ga_maps_with_that_sigma_d() {
    let nerf = common::tiny_nerf();
    let cam = cameras()[0];
    let field = constant_field(&nerf, FieldMethod::Ga, 0.09);
    let close = |a: f32, b: f32| (a.is_nan() && b.is_nan()) || (a - b).abs() <= 1e-5 * b.abs().max(1e-6);
    // Over the grey background (the untrained model's colours are ≈ its grey, so the colour
    // standard deviations are small) and over black and white (they are not).
    for bg in [BG, BLACK, [1.0; 3]] {
        let maps = field.maps(&nerf, &cam, bg);
        let samples = nerf.render_rays_samples(&camera_rays(&cam, bg));
        let ga = ga_maps_from_samples("v", &cam, &samples, bg, 0.3).unwrap();
        let (mut finite, mut visible) = (0, 0);
        for p in 0..maps.colour_std.len() {
            assert!(
                close(maps.colour_std[p], ga.colour_std[p]),
                "pixel {p}: {} vs {}",
                maps.colour_std[p],
                ga.colour_std[p]
            );
            assert!(
                close(maps.depth_std[p], ga.depth_std[p]),
                "pixel {p}: {} vs {}",
                maps.depth_std[p],
                ga.depth_std[p]
            );
            finite += maps.colour_std[p].is_finite() as usize;
            visible += (maps.colour_std[p] > 1e-3) as usize;
        }
        assert!(finite > 20, "{finite}");
        assert!(bg == BG || visible > 20, "{visible} pixels with a colour standard deviation over {bg:?}");
    }

    let bla = constant_field(&nerf, FieldMethod::Bla, 0.09);
    let mut bla4 = bla.clone();
    bla4 = UncertaintyField::from_parts(
        FieldMethod::Bla,
        bla4.geometry,
        NodeValues {
            density: bla4.density,
            variance: bla4.variance.iter().map(|v| 4.0 * v).collect(),
            weight: bla4.weight,
        },
        bla4.checkpoint_id,
        bla4.checkpoint,
        FieldFigures::default(),
    )
    .unwrap();
    let (a, b) = (bla.maps(&nerf, &cam, BG), bla4.maps(&nerf, &cam, BG));
    let mut positive = 0;
    for p in 0..a.colour_std.len() {
        assert!(close(2.0 * a.colour_std[p], b.colour_std[p]), "pixel {p}");
        positive += (a.colour_std[p] > 0.0) as usize;
    }
    assert!(positive > 20);
}

/// Save/load is bit-identical; a truncated file and a field of another model are refused with
/// messages naming the field file (and both checkpoints); no temporary file is left.
#[test]
fn field_file_round_trips_and_bad_files_are_refused_by_name() {
    let nerf = common::tiny_nerf();
    let cams = cameras();
    let refs: Vec<Vec<[f32; 3]>> =
        cams.iter().map(|cam| references_with_constant_ray_variance(&nerf, cam, 0.02)).collect();
    let field =
        UncertaintyField::build_ga(&nerf, "tiny.safetensors", &views(&cams, &refs), BLACK, &cfg(), &mut no_progress)
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("field_ga.safetensors");
    field.save(&path).unwrap();
    let back = UncertaintyField::load(&path).unwrap();
    assert_eq!(back.method, field.method);
    assert_eq!(back.geometry, field.geometry);
    assert_eq!(
        (&back.checkpoint_id, &back.checkpoint, &back.figures),
        (&field.checkpoint_id, &field.checkpoint, &field.figures)
    );
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&back.density), bits(&field.density));
    assert_eq!(bits(&back.variance), bits(&field.variance));
    assert_eq!(bits(&back.weight), bits(&field.weight));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "a temporary file was left");

    back.check_checkpoint(&path, &model_id(&nerf)).unwrap();
    let mut other = nerf.clone();
    other.params[0] += 1.0;
    let other_id = model_id(&other);
    assert_ne!(other_id, field.checkpoint_id);
    let err = back.check_checkpoint(&path, &other_id).unwrap_err();
    assert!(matches!(err, UqError::FieldCheckpoint { .. }));
    let msg = err.to_string();
    assert!(
        msg.contains("field_ga.safetensors") && msg.contains(&field.checkpoint_id) && msg.contains(&other_id),
        "{msg}"
    );

    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.safetensors");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let err = UncertaintyField::load(&cut).unwrap_err();
    assert!(matches!(err, UqError::FieldFile { .. }), "{err:?}");
    assert!(err.to_string().contains("cut.safetensors"), "{err}");
    let missing = UncertaintyField::load(&dir.path().join("nope.safetensors")).unwrap_err();
    assert!(missing.to_string().contains("nope.safetensors"), "{missing}");
}

/// `(C, D̄)` of one ray in f64 from densities (composite as the renderer does).
fn composite(sigma: &[f64], colours: &[[f32; 3]], t: &[f32], delta: f64, bg: [f32; 3]) -> ([f64; 4], f64) {
    let (mut trans, mut c, mut depth) = (1.0f64, [0.0f64; 3], 0.0f64);
    for i in 0..sigma.len() {
        let w = trans * (1.0 - (-sigma[i] * delta).exp());
        for ch in 0..3 {
            c[ch] += w * colours[i][ch] as f64;
        }
        depth += w * t[i] as f64;
        trans -= w;
    }
    let a = 1.0 - trans;
    ([c[0] + trans * bg[0] as f64, c[1] + trans * bg[1] as f64, c[2] + trans * bg[2] as f64, depth / a], a)
}

/// BLA maps of a field with a constant `Var[σ] = v` are `√(v·Σ_i (∂q/∂σ_i)²)` with the
/// derivatives taken by central differences of the composite (the densities recovered from the
/// samples' weights), for the colour (mean over channels) and the distance (as z-depth), 1e-3.
#[test]
fn bla_maps_propagate_the_density_variance_with_the_composites_derivatives() {
    let nerf = common::tiny_nerf();
    let cam = cameras()[0];
    let v = 0.7f32;
    let geometry = nerfsv_uq::field_geometry(&nerf, 4.0).unwrap();
    let n = geometry.len();
    let field = UncertaintyField::from_parts(
        FieldMethod::Bla,
        geometry,
        NodeValues { density: vec![1.0; n], variance: vec![v; n], weight: vec![1.0; n] },
        model_id(&nerf),
        "m".into(),
        FieldFigures::default(),
    )
    .unwrap();
    let maps = field.maps(&nerf, &cam, BG);
    let rays = camera_rays(&cam, BG);
    let samples = nerf.render_rays_samples(&rays);
    let delta = nerf.config.step_size as f64;
    let mut checked = 0;
    for p in 0..rays.len() {
        let (c, w) = samples.ray(p);
        let t = samples.ray_distances(p);
        if w.is_empty() || samples.opacity[p] < 0.05 {
            continue;
        }
        let mut trans = 1.0f64;
        let sigma: Vec<f64> = w
            .iter()
            .map(|&wi| {
                let a = wi as f64 / trans;
                trans -= wi as f64;
                -(1.0 - a).ln() / delta
            })
            .collect();
        let (mut vc, mut vd) = (0.0f64, 0.0f64);
        for i in 0..sigma.len() {
            let h = 1e-4 * sigma[i].max(1.0);
            let mut s = sigma.clone();
            s[i] += h;
            let (plus, _) = composite(&s, c, t, delta, BG);
            s[i] -= 2.0 * h;
            let (minus, _) = composite(&s, c, t, delta, BG);
            let g: Vec<f64> = (0..4).map(|q| (plus[q] - minus[q]) / (2.0 * h)).collect();
            vc += v as f64 * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) / 3.0;
            vd += v as f64 * g[3] * g[3];
        }
        let k = cam.intrinsics;
        let z = cam.z_depth_factor((p as u32 % k.width) as f32 + 0.5, (p as u32 / k.width) as f32 + 0.5) as f64;
        let (want_c, want_d) = (vc.sqrt(), vd.sqrt() * z);
        let (got_c, got_d) = (maps.colour_std[p] as f64, maps.depth_std[p] as f64);
        assert!((got_c - want_c).abs() <= 1e-3 * want_c + 1e-7, "pixel {p}: colour {got_c:e} vs {want_c:e}");
        assert!((got_d - want_d).abs() <= 1e-3 * want_d + 1e-7, "pixel {p}: depth {got_d:e} vs {want_d:e}");
        checked += 1;
    }
    assert!(checked > 20, "{checked} pixels checked");
}

/// Skipping empty space changes nothing where the empty cells hold no density: a field whose
/// density is a ball (σ = 5/m within 0.5 m of a point, 0 elsewhere) gives the same view value
/// (1e-9) with `empty_density` 0 (every cell marched) and 1/m (empty cells and blocks jumped),
/// and a threshold above every density empties the view.
#[test]
fn empty_space_skipping_leaves_the_view_value_unchanged() {
    let nerf = common::tiny_nerf();
    let geometry = nerfsv_uq::field_geometry(&nerf, 20.0).unwrap();
    let n = geometry.len();
    let density: Vec<f32> = (0..n)
        .map(|i| {
            let [a, b, c] = geometry.coords(i);
            let p = geometry.position_of(a, b, c);
            if (p - Point3::new(0.2, -0.1, 0.1)).norm() < 0.5 {
                5.0
            } else {
                0.0
            }
        })
        .collect();
    let variance: Vec<f32> = (0..n).map(|i| 0.01 + (i % 13) as f32 * 0.003).collect();
    let mut field = UncertaintyField::from_parts(
        FieldMethod::Ga,
        geometry,
        NodeValues { density, variance, weight: vec![1.0; n] },
        model_id(&nerf),
        "m".into(),
        FieldFigures::default(),
    )
    .unwrap();
    let pixels: Vec<[u32; 2]> = (0..8).flat_map(|j| (0..8).map(move |i| [i, j])).collect();
    for cam in cameras() {
        let all = field.view_uncertainty(&cam, &pixels, BG);
        field.set_empty_density(1.0);
        let skipping = field.view_uncertainty(&cam, &pixels, BG);
        field.set_empty_density(0.0);
        assert!(all > 0.1, "{all}");
        assert!((all - skipping).abs() <= 1e-9 * all, "{all} marched, {skipping} skipping");
    }
    field.set_empty_density(6.0);
    assert_eq!(field.view_uncertainty(&cameras()[0], &pixels, BG), 0.0);
}

/// Two 32×32 views from 2.5 m and 2.4 m, most of whose rays composite samples.
fn two_close_views() -> [Camera; 2] {
    let k = Intrinsics::from_fov_x(32, 32, 60f32.to_radians());
    [
        Camera::look_at(Point3::new(0.0, -2.5, 0.3), Point3::origin(), Vector3::z(), k),
        Camera::look_at(Point3::new(2.2, 1.0, 0.6), Point3::origin(), Vector3::z(), k),
    ]
}

/// The data term accumulated in batches (rows flushed mid-image) equals `JᵀJ/σ_n²` of all the
/// rows stacked, in one product (lower triangle, 1e-9 relative to its largest entry).
#[test]
fn data_term_in_batches_equals_one_product_of_all_rows() {
    let nerf = common::tiny_nerf();
    let cams = two_close_views();
    let cfg = UqConfig { field_rays_per_image: 5000, ..cfg() };
    let refs: Vec<Vec<[f32; 3]>> = cams.iter().map(|c| vec![[0.5; 3]; c.intrinsics.pixels()]).collect();
    let (d, images, rays) = data_term(&nerf, &views(&cams, &refs), BG, &cfg, &mut no_progress);
    assert_eq!(images, 2);
    assert!(3 * rays > 1536 + 3, "{rays} rays: the batches are not exercised");
    let p = nerf.field.sigma_net_range().len();
    let mut stacked: Vec<f32> = Vec::new();
    for cam in &cams {
        let all = camera_rays(cam, BG);
        let samples = nerf.render_rays_samples(&all);
        let hit: Vec<_> = (0..all.len()).filter(|&i| !samples.ray(i).1.is_empty()).map(|i| all[i]).collect();
        let jac = nerf.render_rays_sigma_jacobian(&hit);
        for r in 0..hit.len() {
            stacked.extend_from_slice(&jac.ray(r)[..3 * p]);
        }
    }
    let m = stacked.len() / p;
    assert_eq!(m, 3 * rays);
    let j = Mat::from_fn(m, p, |r, c| stacked[r * p + c] as f64);
    let full = j.transpose() * &j * faer::Scale(1.0 / (cfg.noise_std * cfg.noise_std));
    let scale = (0..p).map(|i| full[(i, i)]).fold(0.0f64, f64::max);
    for a in 0..p {
        for b in 0..=a {
            assert!((d[(a, b)] - full[(a, b)]).abs() <= 1e-9 * scale, "({a}, {b}): {} vs {}", d[(a, b)], full[(a, b)]);
        }
    }
}

/// A subsample of each view's rays, each counted for the rays it stands for, estimates the
/// information of all of them: the traces agree to within a fifth, where the unweighted
/// subsample held about rays/hits of it.
#[test]
fn a_weighted_subsample_of_rays_estimates_the_whole_images_information() {
    let nerf = common::tiny_nerf();
    let cams = two_close_views();
    let refs: Vec<Vec<[f32; 3]>> = cams.iter().map(|c| vec![[0.5; 3]; c.intrinsics.pixels()]).collect();
    let trace = |rays: usize| {
        let cfg = UqConfig { field_rays_per_image: rays, ..cfg() };
        let (d, _, used) = data_term(&nerf, &views(&cams, &refs), BG, &cfg, &mut no_progress);
        ((0..d.nrows()).map(|i| d[(i, i)]).sum::<f64>(), used)
    };
    let (full, all) = trace(5000);
    let (sub, used) = trace(64);
    assert_eq!(used, 128);
    assert!(all > 4 * used, "{all} rays hit: the subsample is not a subsample");
    let ratio = sub / full;
    assert!((0.8..1.25).contains(&ratio), "subsample trace {sub} against all rays' {full} (ratio {ratio})");
}

/// A resolution whose grid would not fit the memory budget is refused before anything is
/// allocated, naming the key.
#[test]
fn a_field_over_the_memory_budget_is_refused_naming_the_key() {
    let nerf = common::tiny_nerf();
    // 400 cells/m over the 2 m box: 801³ nodes, about 23 GB.
    nerfsv_scene::validate::MemoryBudget::set(1 << 30);
    let err = nerfsv_uq::field_geometry(&nerf, 400.0).unwrap_err();
    nerfsv_scene::validate::MemoryBudget::set(u64::MAX);
    assert!(err.to_string().contains("uq.field_cells_per_metre"), "{err}");
}

/// The ensemble's field: identical members spread nothing; two members give, at every node, the
/// population variance ((σ_a − σ_b)/2)² of their densities, the deployed model's density, and
/// BLA's lookup (the variance relative to that density). Fewer than two members are refused.
#[test]
fn ensemble_field_is_the_members_density_variance_at_each_node() {
    let a = common::tiny_nerf();
    let mut b = a.clone();
    for (i, w) in b.params.iter_mut().enumerate() {
        *w += 0.05 * ((i % 5) as f32 - 2.0);
    }
    let cfg = cfg();
    let same = UncertaintyField::build_ensemble(&[&a, &a, &a], "a", &cfg).unwrap();
    assert!(same.variance.iter().all(|&v| v == 0.0));
    let field = UncertaintyField::build_ensemble(&[&a, &b], "a", &cfg).unwrap();
    assert_eq!(field.method, FieldMethod::Ensemble);
    assert_eq!(field.checkpoint_id, model_id(&a));
    let positions: Vec<Point3<f32>> = (0..field.geometry.len())
        .map(|n| {
            let [i, j, k] = field.geometry.coords(n);
            field.geometry.position_of(i, j, k)
        })
        .collect();
    let (sa, sb) = (a.density(&positions), b.density(&positions));
    assert_eq!(field.density, sa);
    let mut differ = 0;
    for n in 0..positions.len() {
        let expected = ((f64::from(sa[n]) - f64::from(sb[n])) / 2.0).powi(2);
        assert!((f64::from(field.variance[n]) - expected).abs() <= 1e-5 * expected.max(1e-3), "node {n}");
        differ += usize::from(expected > 0.0);
    }
    assert!(differ > positions.len() / 2, "{differ}");
    let p = positions[positions.len() / 2];
    let looked_up = field.value_at(p).unwrap();
    assert!(looked_up.is_finite() && looked_up >= 0.0);
    assert!(matches!(UncertaintyField::build_ensemble(&[&a], "a", &cfg), Err(UqError::FieldGrid { .. })));
}

#[test]
fn a_field_method_names_the_per_image_method_it_comes_from() {
    use nerfsv_uq::Method;
    for m in Method::ALL {
        assert_eq!(FieldMethod::from(m).method(), Some(m));
    }
    assert_eq!(FieldMethod::Ensemble.method(), None);
}
