//! GA's σ_d on the drone's step views, and why the noise-floored σ_d the online study scores is
//! 0 on most of them. For the steps of a run's Monte Carlo rollouts (`stress/rollouts.csv`: the
//! camera at each flown step's end, as the online study measures it), on the online study's
//! pixels against the ground truth's render: the deployed NeRF's colour RMSE, the paper's σ_d,
//! and the noise-floored σ_d at several floors σ_n (the run's `uq.noise_std` among them).
//!
//! ```sh
//! cargo run --release -- run                          # a run folder
//! cargo run --release --example ga_floor -- 30        # the first 30 MC rollouts' steps
//! ```
//!
//! The run folder is `runs/stonehenge` (`RUN=DIR` for another); its `report/config.toml` is the
//! config (the default one without it).

use std::path::PathBuf;

use nerfsv_pipeline::flight::flight_inputs;
use nerfsv_pipeline::RunConfig;
use nerfsv_scene::stats::quantile_sorted;
use nerfsv_scene::Scene;
use nerfsv_sim::camera::drone_camera;
use nerfsv_sim::dynamics::so3_exp;
use nerfsv_sim::world::pixel_rays;
use nerfsv_sim::WorldKind;
use nerfsv_study::flight::world;
use nerfsv_study::online_pixels;
use nerfsv_uq::ga_image;
use nerfsv_validation::{read_csv_file, Label};

/// One step view's figures.
struct View {
    step: usize,
    rmse: f64,
    /// The paper's σ_d.
    paper: f64,
    /// The noise-floored σ_d at each floor.
    floored: Vec<f64>,
}

/// The floors σ_n tried besides the run's own.
const FLOORS: [f64; 4] = [0.0, 0.01, 0.02, 0.03];

fn main() -> anyhow::Result<()> {
    let n: usize = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(30);
    let run = PathBuf::from(std::env::var("RUN").unwrap_or_else(|_| "runs/stonehenge".to_string()));
    let config = run.join("report/config.toml");
    let cfg = if config.is_file() { RunConfig::load(&config)? } else { RunConfig::default() };
    let scene = Scene::builtin(&cfg.scene)?;
    let inputs = flight_inputs(&run, true)?;
    let flight = inputs.plan(&cfg.sim)?;
    let sim = flight.simulator(&cfg.sim, &inputs.nerf, cfg.camera_intrinsics());
    let gt = world(WorldKind::Gt, &inputs, Some(&scene), cfg.dataset.render_settings())?;
    let pixels = online_pixels(&sim.intrinsics, &cfg.uq);
    let records = read_csv_file(&run.join("stress/rollouts.csv"))?;
    let mut floors = FLOORS.to_vec();
    floors.push(cfg.uq.noise_std);
    let mut rows: Vec<View> = Vec::new();
    for r in records.iter().filter(|r| r.sampler == Label::Mc).take(n) {
        for (k, (p, a)) in r.step_positions.iter().zip(&r.step_attitudes).enumerate() {
            if !p.iter().all(|v| v.is_finite()) {
                continue;
            }
            let rotation = so3_exp(&nalgebra::Vector3::from(*a));
            let camera = drone_camera(sim.intrinsics, &nalgebra::Vector3::from(*p), &rotation);
            let rays = pixel_rays(&camera, &pixels, sim.background);
            let reference = gt.observe(&camera, &pixels, sim.background);
            let render = inputs.nerf.render_rays(&rays);
            let sq: f64 = render
                .rgb
                .chunks_exact(3)
                .zip(&reference)
                .map(|(c, o)| (0..3).map(|i| (f64::from(c[i]) - f64::from(o[i])).powi(2)).sum::<f64>())
                .sum();
            let rmse = (sq / (3 * pixels.len()) as f64).sqrt();
            let fits: Vec<_> = floors
                .iter()
                .map(|&floor| {
                    ga_image(&inputs.nerf, "step view", &rays, &reference, cfg.uq.ga_sigma_max, floor.max(1e-9))
                })
                .collect::<Result<_, _>>()?;
            rows.push(View {
                step: k,
                rmse,
                paper: fits[0].sigma_d,
                floored: fits.iter().map(|f| f.floored.sigma_d).collect(),
            });
        }
    }
    let column = |f: &dyn Fn(&View) -> f64, rows: &[&View]| {
        let mut v: Vec<f64> = rows.iter().map(|r| f(r)).collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let steps = rows.iter().map(|r| r.step).max().map_or(0, |m| m + 1);
    println!("{} step views of {} MC rollouts, {} pixels each ({})", rows.len(), n, pixels.len(), run.display());
    for k in (0..steps).map(Some).chain([None]) {
        let set: Vec<&View> = rows.iter().filter(|r| k.is_none_or(|k| r.step == k)).collect();
        if set.is_empty() {
            continue;
        }
        let rmse = column(&|r| r.rmse, &set);
        let paper = column(&|r| r.paper, &set);
        let label = k.map_or("all steps".to_string(), |k| format!("step {k}"));
        print!(
            "{label} ({} views): RMSE median {:.4} (p10 {:.4}, p90 {:.4}); paper σ_d median {:.3}",
            set.len(),
            quantile_sorted(&rmse, 0.5),
            quantile_sorted(&rmse, 0.1),
            quantile_sorted(&rmse, 0.9),
            quantile_sorted(&paper, 0.5)
        );
        for (i, floor) in floors.iter().enumerate() {
            let v = column(&|r| r.floored[i], &set);
            let zeros = v.iter().filter(|&&s| s == 0.0).count();
            print!("; σ_n {floor}: σ_d = 0 on {zeros}, median {:.3}", quantile_sorted(&v, 0.5));
        }
        println!();
    }
    Ok(())
}
