//! Training throughput on the default run's dataset, as `nerfsv run` trains: 400 steps to let the
//! occupancy grid settle (as `benches/nerf.rs` does), then `K` steps timed (default 200), with the
//! process's CPU time beside the wall time, so a step that leaves a core idle shows as fewer than
//! two cores busy. The bench's dataset (40 views) takes 512 rays a step; the default dataset's
//! steps take 512 or 768 (the count adapts to ≈ 24 576 samples), in chunks of 128 rays.
//!
//! ```sh
//! cargo run --release -- run                            # the default run's dataset
//! cargo run --release --example train_steps -- 200
//! ```
//!
//! `RUN=DIR` reads another run folder. Linux only (the CPU time is read from `/proc/self/stat`).

use std::time::Instant;

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::{NerfConfig, TrainConfig, Trainer};

/// The process's user + system CPU time in seconds (clock ticks of 10 ms).
fn cpu_seconds() -> anyhow::Result<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat")?;
    // Fields after the command name, which is in parentheses: utime and stime are the 12th and 13th.
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let tick = |i: usize| -> anyhow::Result<f64> {
        Ok(fields.get(i).ok_or_else(|| anyhow::anyhow!("/proc/self/stat: no field {i}"))?.parse::<f64>()? / 100.0)
    };
    Ok(tick(11)? + tick(12)?)
}

fn main() -> anyhow::Result<()> {
    let k: usize = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(200).max(1);
    let run = std::path::PathBuf::from(std::env::var("RUN").unwrap_or_else(|_| "runs/stonehenge".to_string()));
    let train = load_split(&run.join("dataset"), "train", LoadOptions::default())?;
    let mut trainer = Trainer::new(NerfConfig::default(), TrainConfig::default(), &train)?;
    for _ in 0..400 {
        trainer.step()?;
    }
    let (cpu0, t0) = (cpu_seconds()?, Instant::now());
    let (mut samples, mut rays) = (0, 0);
    for _ in 0..k {
        let s = trainer.step()?;
        samples += s.samples;
        rays += s.rays;
    }
    let (cpu, wall) = (cpu_seconds()? - cpu0, t0.elapsed().as_secs_f64());
    println!(
        "{k} steps: {:.2} ms wall, {:.2} ms CPU per step ({:.2} cores), {} rays and {} samples per step, {:.0} k samples/s",
        1e3 * wall / k as f64,
        1e3 * cpu / k as f64,
        cpu / wall,
        rays / k,
        samples / k,
        samples as f64 / wall / 1e3
    );
    Ok(())
}
