//! The error of the uncertainty field's rank-K BLA variance against the dense value, on nodes of
//! non-negligible density (σ ≥ 1/m, i.e. σ·Δt ≥ 0.05 over a 5 cm cell) of a trained model.
//!
//! `cargo run --release -p nerfsv-uq --example field_rank_error -- [RUN] [SAMPLES]`
//! (RUN defaults to `runs/stonehenge`, made by `nerfsv run`; SAMPLES to 2000 nodes).
//!
//! "Dense" is the exact `gᵀΣ₁₁g = |L⁻¹g|²` (Cholesky of the Schur complement), itself checked
//! against `gᵀ H⁻¹ g` with the full `[P, P]` `H = D + αI` factorised by Cholesky on the first
//! 200 sampled nodes; the eigen-form at K = m is printed too.

use std::path::PathBuf;
use std::time::Instant;

use faer::linalg::solvers::{Llt, Solve};
use faer::{Mat, Side};
use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::Nerf;
use nerfsv_uq::{data_term, density_param_count, field_geometry, DensityPosterior, TrainingView, UqConfig};

const BG: [f32; 3] = [1.0; 3];

fn quantiles(mut v: Vec<f64>) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    let q = |f: f64| nerfsv_scene::stats::quantile_sorted(&v, f);
    (q(0.5), q(0.9), q(1.0))
}

fn main() {
    let mut args = std::env::args().skip(1);
    let run = args.next().map_or_else(|| PathBuf::from("runs/stonehenge"), PathBuf::from);
    let samples: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(2000);
    let nerf = Nerf::load(&run.join("nerf/checkpoint.safetensors")).expect("checkpoint");
    let split = load_split(
        &run.join("dataset"),
        "train",
        LoadOptions { downscale: 1, load_depth: false, ..Default::default() },
    )
    .expect("train split");
    let refs: Vec<Vec<[f32; 3]>> = split
        .frames
        .iter()
        .map(|f| f.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + BG[c] * (1.0 - p[3]))).collect())
        .collect();
    let views: Vec<TrainingView> = split
        .frames
        .iter()
        .zip(&refs)
        .map(|(f, r)| TrainingView { name: &f.file_path, camera: &f.camera, reference: r })
        .collect();
    let cfg = UqConfig::default();
    let t = Instant::now();
    let (d, images, rays) = data_term(&nerf, &views, BG, &cfg, &mut |_, _| {});
    println!("data term: {images} images, {rays} rays, {:.1} s", t.elapsed().as_secs_f64());
    let m = density_param_count(&nerf);
    let t = Instant::now();
    let post = DensityPosterior::new(&d, m, cfg.prior_precision).expect("posterior");
    println!("Schur complement + eigen-decomposition of {m}²: {:.1} s", t.elapsed().as_secs_f64());
    let g = field_geometry(&nerf, cfg.field_cells_per_metre).expect("grid");
    let positions: Vec<nalgebra::Point3<f32>> = (0..g.len())
        .map(|n| {
            let [i, j, k] = g.coords(n);
            g.position_of(i, j, k)
        })
        .collect();
    let sigma = nerf.density(&positions);
    let dense_nodes: Vec<usize> = (0..g.len()).filter(|&n| sigma[n] >= 1.0).collect();
    let n = dense_nodes.len().min(samples);
    let picked: Vec<nalgebra::Point3<f32>> =
        (0..n).map(|q| positions[dense_nodes[q * dense_nodes.len() / n]]).collect();
    println!("{} of {} nodes have σ ≥ 1/m; {n} sampled", dense_nodes.len(), g.len());
    let (_, grads) = nerf.density_param_gradients(&picked);
    let p = nerf.field.sigma_net_range().len();
    let t = Instant::now();
    let exact = post.variances_exact(&grads, p);
    println!("exact (Cholesky) route: {:.1} µs per node", 1e6 * t.elapsed().as_secs_f64() / n as f64);
    let prior: Vec<f64> = (0..n)
        .map(|i| grads[i * p..i * p + m].iter().map(|&x| (x as f64).powi(2)).sum::<f64>() / cfg.prior_precision)
        .collect();
    let (a, b, c) = quantiles((0..n).map(|i| exact[i] / prior[i]).collect());
    println!("dense / prior-only variance: median {a:.4}, p90 {b:.4}, max {c:.4}");
    for k in [32, 64, 128, 256, 512, 1024, 2048, m] {
        let t = Instant::now();
        let approx = post.variances_low_rank(&grads, p, k);
        let secs = t.elapsed().as_secs_f64();
        let rel: Vec<f64> = (0..n).map(|i| (approx[i] - exact[i]).abs() / exact[i]).collect();
        let (a, b, c) = quantiles(rel);
        println!(
            "K = {k:4}: eigenvalue mass kept {:.4}; relative error median {a:.3e}, p90 {b:.3e}, max {c:.3e} ({:.1} µs per node)",
            post.mass_kept(k),
            1e6 * secs / n as f64
        );
    }
    // The Schur/eigen route against the full dense posterior.
    let mut h = Mat::from_fn(p, p, |i, j| if i >= j { d[(i, j)] } else { d[(j, i)] });
    for i in 0..p {
        h[(i, i)] += cfg.prior_precision;
    }
    let llt = Llt::new(h.as_ref(), Side::Lower).expect("H positive definite");
    let check = n.min(200);
    let rhs = Mat::from_fn(p, check, |r, i| grads[i * p + r] as f64);
    let sol = llt.solve(rhs.as_ref());
    let mut worst = 0.0f64;
    for i in 0..check {
        let full: f64 = (0..p).map(|r| rhs[(r, i)] * sol[(r, i)]).sum();
        worst = worst.max((full - exact[i]).abs() / full);
    }
    println!("K = m against gᵀ H⁻¹ g with the full {p}² H: max relative difference {worst:.3e} over {check} nodes");
}
