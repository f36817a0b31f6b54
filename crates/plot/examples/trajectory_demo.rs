//! Renders a synthetic flight past three stones to /tmp/trajectory_demo.png (and .svg):
//! `cargo run -p nerfsv-plot --example trajectory_demo [WIDTH HEIGHT]` (default 1200 680).

use nerfsv_plot::{trajectory_png, trajectory_svg, FieldSlice, Track, TrackKind, TrajectoryFigure};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // A 3.8 × 3.8 m slice at 40 cells/m with three stones (discs) and a pillar.
    let (cells_per_m, half) = (40.0, 1.9);
    let cell = 1.0 / cells_per_m;
    let n = (2.0 * half * cells_per_m) as usize + 1;
    let origin = [-half, -half];
    let stones = [([-0.4, 0.35], 0.38), ([0.55, -0.25], 0.3), ([0.3, 0.95], 0.22)];
    let sdf = |x: f64, y: f64| {
        let stone = stones.iter().map(|(c, r)| (x - c[0]).hypot(y - c[1]) - r).fold(f64::INFINITY, f64::min);
        let pillar = (x - 1.5).abs().max((y + 1.2).abs()) - 0.16; // a square pillar
        stone.min(pillar)
    };
    let values =
        (0..n * n).map(|k| sdf(origin[0] + cell * (k % n) as f64, origin[1] + cell * (k / n) as f64) as f32).collect();

    let waypoints = vec![[-1.5, -1.2, 0.9], [-0.9, -0.5, 1.0], [0.0, -0.1, 1.1], [0.6, 0.45, 1.15], [1.45, 1.35, 1.0]];
    // Planned: a smooth curve through the waypoints (Catmull–Rom).
    let planned = catmull_rom(&waypoints, 40);
    // True: after the middle, pulled off the plan towards the small stone until it hits it.
    let small_stone = stones[2].0;
    let true_track: Vec<[f64; 3]> = planned
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let t = k as f64 / (planned.len() - 1) as f64;
            let pull = 0.9 * ((t - 0.45).max(0.0) / 0.4).min(1.0).powf(1.5);
            [
                p[0] + pull * (small_stone[0] - p[0]),
                p[1] + pull * (small_stone[1] - p[1]),
                p[2] + 0.06 * (9.0 * t).sin(),
            ]
        })
        .take_while(|p| sdf(p[0], p[1]) > 0.05)
        .collect();
    let collision = *true_track.last().expect("the true track has points");
    // Estimated: the estimator's belief, offset by a slowly varying error.
    let estimated: Vec<[f64; 3]> = true_track
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let t = k as f64 * 0.05;
            [p[0] + 0.05 * t.sin(), p[1] - 0.06 + 0.03 * (1.7 * t).cos(), p[2] + 0.03 * t.cos()]
        })
        .collect();

    let fig = TrajectoryFigure {
        title: "Run 0042 · NeRF-sim · collision after 3.1 s".into(),
        slice: FieldSlice { origin, cell, dims: [n, n], values, altitude: 1.0 },
        tracks: vec![
            Track { label: "planned".into(), points: planned, kind: TrackKind::Planned },
            Track { label: "true (simulated)".into(), points: true_track, kind: TrackKind::True },
            Track { label: "estimated".into(), points: estimated, kind: TrackKind::Estimated },
        ],
        collision: Some(collision),
        start: waypoints[0],
        goal: *waypoints.last().expect("waypoints"),
        waypoints,
        altitude_band: [0.5, 1.5],
    };
    let args: Vec<u32> = std::env::args().skip(1).map(|a| a.parse()).collect::<Result<_, _>>()?;
    let (width, height) = match args[..] {
        [w, h] => (w, h),
        _ => (1200, 680),
    };
    let t0 = std::time::Instant::now();
    let png = trajectory_png(&fig, width, height)?;
    let t1 = t0.elapsed();
    let svg = trajectory_svg(&fig, width, height)?;
    std::fs::write("/tmp/trajectory_demo.png", &png)?;
    std::fs::write("/tmp/trajectory_demo.svg", &svg)?;
    println!(
        "wrote /tmp/trajectory_demo.png ({} KiB, {:.0} ms) and /tmp/trajectory_demo.svg ({} KiB)",
        png.len() / 1024,
        t1.as_secs_f64() * 1e3,
        svg.len() / 1024
    );
    Ok(())
}

/// A Catmull–Rom spline through `p` with `per_segment` samples per segment.
fn catmull_rom(p: &[[f64; 3]], per_segment: usize) -> Vec<[f64; 3]> {
    let at = |i: isize| p[i.clamp(0, p.len() as isize - 1) as usize];
    let mut out = Vec::new();
    for i in 0..p.len() as isize - 1 {
        let (p0, p1, p2, p3) = (at(i - 1), at(i), at(i + 1), at(i + 2));
        for k in 0..per_segment {
            let t = k as f64 / per_segment as f64;
            let (t2, t3) = (t * t, t * t * t);
            out.push(std::array::from_fn(|a| {
                0.5 * (2.0 * p1[a]
                    + (-p0[a] + p2[a]) * t
                    + (2.0 * p0[a] - 5.0 * p1[a] + 4.0 * p2[a] - p3[a]) * t2
                    + (-p0[a] + 3.0 * p1[a] - 3.0 * p2[a] + p3[a]) * t3)
            }));
        }
    }
    out.push(*p.last().expect("at least one point"));
    out
}
