//! Trains on a Blender dataset for a wall-clock budget and prints test metrics at 60/120/300 s
//! of training time (evaluation time excluded), training throughput and render throughput.
//!
//! `cargo run --release -p nerfsv-nerf --example train_bench -- /work/data/stonehenge 300 [n_test]`

use std::time::Instant;

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::{evaluate, EvalOptions, NerfConfig, TrainConfig, Trainer};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::PathBuf::from(args.get(1).map(String::as_str).unwrap_or("/work/data/stonehenge"));
    let budget: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(300.0);
    let n_test: Option<usize> = args.get(3).and_then(|s| s.parse().ok());
    let train = load_split(&dir, "train", LoadOptions::default()).expect("train split");
    let test = load_split(&dir, "test", LoadOptions::default()).expect("test split");
    let mut cfg = NerfConfig::default();
    let mut tcfg = TrainConfig::default();
    if let Ok(s) = std::env::var("NERF_CONFIG") {
        cfg = serde_json::from_str(&s).expect("NERF_CONFIG json");
    }
    if let Ok(s) = std::env::var("TRAIN_CONFIG") {
        tcfg = serde_json::from_str(&s).expect("TRAIN_CONFIG json");
    }
    println!("threads {}  config {}", rayon::current_num_threads(), serde_json::to_string(&cfg).unwrap());
    let mut t = Trainer::new(cfg, tcfg, &train).expect("trainer");
    let marks = [30.0, 60.0, 120.0, 180.0, 300.0, 600.0];
    let mut next = 0;
    let mut trained = 0.0f64;
    let (mut rays, mut samples) = (0usize, 0usize);
    let mut last_print = 0.0;
    while trained < budget {
        let s0 = Instant::now();
        let st = t.step().expect("step");
        trained += s0.elapsed().as_secs_f64();
        rays += st.rays;
        samples += st.samples;
        if trained - last_print > 10.0 {
            last_print = trained;
            println!(
                "  t={trained:6.1}s step {:6} loss {:.5} psnr {:5.2} rays/step {} spr {:.1} occ {:.3}",
                t.step_count(),
                st.loss,
                st.psnr,
                st.rays,
                st.samples as f64 / st.rays as f64,
                t.nerf().grid.occupancy()
            );
        }
        if next < marks.len() && (trained >= marks[next] || trained >= budget) {
            while next < marks.len() && marks[next] <= trained {
                next += 1;
            }
            let e0 = Instant::now();
            let rep =
                evaluate(t.nerf(), &test, EvalOptions { max_images: n_test, ..Default::default() }).expect("evaluate");
            let ev = e0.elapsed().as_secs_f64();
            println!(
                "[{trained:6.1} s, step {}] test PSNR {:.2} dB  SSIM {:.4}  depth err {:.4} m  ({} images)  | train {:.0} samples/s {:.0} rays/s | eval {:.0} rays/s",
                t.step_count(),
                rep.psnr,
                rep.ssim,
                rep.depth_median_abs_err_m.unwrap_or(f64::NAN),
                rep.images,
                samples as f64 / trained,
                rays as f64 / trained,
                (rep.images * 10000) as f64 / ev
            );
        }
    }
    let cam = &test.frames[0].camera;
    let r0 = Instant::now();
    let reps = 5;
    for _ in 0..reps {
        std::hint::black_box(t.nerf().render_camera(cam, [1.0; 3]));
    }
    let px = cam.intrinsics.pixels() * reps;
    println!(
        "render: {:.0} rays/s ({}x{} view)",
        px as f64 / r0.elapsed().as_secs_f64(),
        cam.intrinsics.width,
        cam.intrinsics.height
    );
}
