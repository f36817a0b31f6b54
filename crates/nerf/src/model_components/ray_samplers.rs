//! Ray marching with empty-space skipping (instant-ngp): fixed steps Δt along the ray inside
//! the scene box, jumping over unoccupied grid cells to the next step past the cell's exit.

use super::occupancy_grid::OccupancyGrid;

/// Slab test of the ray `o + t·d` against the box; `(t_near ≥ 0, t_far)` or `None`.
#[inline]
pub fn ray_aabb(o: [f32; 3], d: [f32; 3], min: [f32; 3], max: [f32; 3]) -> Option<(f32, f32)> {
    let mut t0 = 0.0f32;
    let mut t1 = f32::INFINITY;
    for a in 0..3 {
        let inv = 1.0 / d[a];
        let (mut lo, mut hi) = ((min[a] - o[a]) * inv, (max[a] - o[a]) * inv);
        if lo > hi {
            std::mem::swap(&mut lo, &mut hi);
        }
        if lo > t0 {
            t0 = lo;
        }
        if hi < t1 {
            t1 = hi;
        }
        if t0 > t1 {
            return None;
        }
    }
    Some((t0, t1))
}

/// Appends the sample distances of one ray to `ts` (metres along the unit direction `d`):
/// samples at `t_near + (jitter + m)·step`, `m = 0, 1, …`, inside the box and in occupied
/// cells, at most `max_samples`. Returns the number appended.
pub fn march_ray(
    o: [f32; 3],
    d: [f32; 3],
    grid: &OccupancyGrid,
    step: f32,
    max_samples: usize,
    jitter: f32,
    ts: &mut Vec<f32>,
) -> usize {
    let Some((t0, t1)) = ray_aabb(o, d, grid.aabb_min, grid.aabb_max) else { return 0 };
    let before = ts.len();
    march_segment(o, d, grid, step, t0 + jitter * step, t1, max_samples, ts);
    ts.len() - before
}

/// Continues a march from lattice position `t` (up to `t_far`), appending at most `max_new`
/// samples to `ts`; returns the next lattice position (≥ `t_far` when the ray has left the box).
#[allow(clippy::too_many_arguments)]
pub fn march_segment(
    o: [f32; 3],
    d: [f32; 3],
    grid: &OccupancyGrid,
    step: f32,
    mut t: f32,
    t_far: f32,
    max_new: usize,
    ts: &mut Vec<f32>,
) -> f32 {
    let cs = grid.cell_size();
    let r = grid.resolution;
    let inv_d = d.map(|v| 1.0 / v);
    let mut n = 0;
    while t < t_far && n < max_new {
        let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        let c = grid.cell_of(p);
        if grid.is_occupied_index(c[0] + r * (c[1] + r * c[2])) {
            ts.push(t);
            n += 1;
            t += step;
        } else {
            // Exit distance of this cell; advance a whole number of steps past it.
            let mut t_exit = f32::INFINITY;
            for a in 0..3 {
                let bound = grid.aabb_min[a] + (c[a] + (d[a] > 0.0) as usize) as f32 * cs[a];
                let te = (bound - o[a]) * inv_d[a];
                if te.is_finite() && te < t_exit {
                    t_exit = te;
                }
            }
            t += steps_past((t_exit - t) / step) * step;
        }
    }
    t
}

/// `ceil(x).max(1)`: the whole number of steps (at least one) that reaches past `x` steps, with
/// the same bits as `x.ceil().max(1.0)` (NaN gives 1) but without a libm `ceilf` call, which
/// x86-64's baseline instruction set has no instruction for.
#[inline(always)]
fn steps_past(x: f32) -> f32 {
    if x > 1.0 {
        if x < 8_388_608.0 {
            // 1 < x < 2²³: the truncation is exact and is the ceiling unless x had a fraction.
            let i = x as i32 as f32;
            if i < x {
                i + 1.0
            } else {
                i
            }
        } else {
            x // 2²³ and above (and ∞): already whole
        }
    } else {
        1.0 // x ≤ 1, and NaN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`steps_past`] is `ceil(x).max(1)` bit for bit: at whole numbers, next to them, across
    /// the range up to and past 2²³, at ±0, negatives, ∞ and NaN.
    #[test]
    fn steps_past_is_the_ceiling_at_least_one() {
        let mut xs = vec![0.0f32, -0.0, -1.5, 0.5, 1.0, 2.0, 8_388_607.5, 8_388_608.0, 1e30, f32::INFINITY];
        xs.extend([f32::NEG_INFINITY, f32::NAN, f32::MIN_POSITIVE]);
        for k in 0..40_000u32 {
            let v = (k as f32) * 0.37 + 1.0;
            xs.extend([v, f32::from_bits(v.to_bits() + 1), f32::from_bits(v.to_bits() - 1), (k as f32).powi(2)]);
        }
        for x in xs {
            let want = x.ceil().max(1.0);
            assert_eq!(steps_past(x).to_bits(), want.to_bits(), "x = {x}");
        }
    }

    #[test]
    fn marching_an_empty_grid_yields_no_samples_and_a_full_grid_fills_the_box() {
        let mut g = OccupancyGrid::new(8, [-1.0; 3], [1.0; 3]);
        let mut ts = Vec::new();
        let n = march_ray([-3.0, 0.1, 0.2], [1.0, 0.0, 0.0], &g, 0.1, 1000, 0.0, &mut ts);
        assert!((20..=21).contains(&n), "{n}");
        assert!((ts[0] - 2.0).abs() < 1e-5);
        g.fill_occupied(false);
        let c = g.cell_of([0.3, 0.1, 0.2]);
        let i = g.index(c);
        g.set_occupied(i, true);
        ts.clear();
        let n = march_ray([-3.0, 0.1, 0.2], [1.0, 0.0, 0.0], &g, 0.05, 1000, 0.0, &mut ts);
        // Only the cell [0.25, 0.5] in x is occupied: samples at 3.25, 3.30, ... < 3.5.
        assert!((4..=6).contains(&n), "{n}: {ts:?}");
        assert!(ts.iter().all(|&t| (3.25 - 1e-4..3.5 + 1e-4).contains(&t)));
    }
}
