//! Ray marching with empty-space skipping (instant-ngp): fixed steps Δt along the ray inside
//! the scene box, jumping over unoccupied grid cells to the next step past the cell's exit.
//!
//! Two walks. Training's ([`march_ray`], [`march_segment`]) goes cell by cell and accumulates
//! the lattice position (`t += k·Δt`); its sample positions fix a trained model's bits, so it
//! stays as it is. Rendering's ([`Lattice`]) computes each sample from its index
//! (`t = t₀ + m·Δt`), so it can jump any number of steps at once: it skips empty blocks of the
//! grid's coarse level ([`BLOCK`]³ cells) whole and empty cells inside occupied blocks one at a
//! time. Both sample the lattice points that lie in occupied cells; their `t` differ in the last
//! bits (accumulated against computed).

use super::occupancy_grid::{OccupancyGrid, BLOCK};

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

/// One ray's marching lattice for rendering: samples at `t_m = start + m·step`, `m = 0, 1, …`,
/// before `far` (the box's far side), each computed from its index.
#[derive(Clone, Copy, Debug)]
pub struct Lattice {
    o: [f32; 3],
    d: [f32; 3],
    inv_d: [f32; 3],
    start: f32,
    far: f32,
    step: f32,
    inv_step: f32,
}

impl Lattice {
    /// The lattice of the ray `o + t·d` over `span` (its entry and exit of the box, as
    /// [`ray_aabb`] gives them), offset by `jitter` steps (`[0, 1)`).
    pub fn on_span(o: [f32; 3], d: [f32; 3], span: (f32, f32), step: f32, jitter: f32) -> Self {
        let start = span.0 + jitter * step;
        Self { o, d, inv_d: d.map(|v| 1.0 / v), start, far: span.1, step, inv_step: 1.0 / step }
    }

    /// The distance of lattice point `m` (m).
    #[inline(always)]
    pub fn t(&self, m: u32) -> f32 {
        self.start + m as f32 * self.step
    }

    /// Whether lattice point `m` lies before the box's far side.
    #[inline(always)]
    pub fn inside(&self, m: u32) -> bool {
        self.t(m) < self.far
    }

    /// Appends to `ts` the lattice points from index `m` on that lie in occupied cells of
    /// `grid`, at most `max_new`; returns the index to continue from. Empty blocks of the grid's
    /// coarse level are crossed in one jump to the first lattice point past their exit, empty
    /// cells of occupied blocks in one jump each.
    pub fn march(&self, grid: &OccupancyGrid, mut m: u32, max_new: usize, ts: &mut Vec<f32>) -> u32 {
        let r = grid.resolution;
        let cs = grid.cell_size();
        let mut n = 0;
        while n < max_new {
            let t = self.t(m);
            if t >= self.far {
                break;
            }
            let p = [self.o[0] + t * self.d[0], self.o[1] + t * self.d[1], self.o[2] + t * self.d[2]];
            let c = grid.cell_of(p);
            let size = if !grid.is_block_occupied(c) {
                BLOCK
            } else if grid.is_occupied_index(c[0] + r * (c[1] + r * c[2])) {
                ts.push(t);
                n += 1;
                m += 1;
                continue;
            } else {
                1
            };
            // The exit of the empty cell or block: the nearest of its far faces.
            let mut t_exit = f32::INFINITY;
            for a in 0..3 {
                let face = (c[a] / size + (self.d[a] > 0.0) as usize) * size;
                let te = (grid.aabb_min[a] + face as f32 * cs[a] - self.o[a]) * self.inv_d[a];
                if te.is_finite() && te < t_exit {
                    t_exit = te;
                }
            }
            m = first_index_past((t_exit - self.start) * self.inv_step, m);
        }
        m
    }
}

/// The lattice index to continue from after an empty stretch that ends at `x` steps from the
/// lattice's start, coming from index `m`: `⌈x⌉`, at least `m + 1` (also for NaN), saturating.
#[inline(always)]
fn first_index_past(x: f32, m: u32) -> u32 {
    if x > (m + 1) as f32 {
        let i = x as u32; // saturates above u32::MAX
        if (i as f32) < x {
            i.saturating_add(1)
        } else {
            i
        }
    } else {
        m + 1
    }
}

/// The sample distances of one ray on its rendering [`Lattice`] (`jitter` steps in), at most
/// `max_samples`, appended to `ts`; returns the number appended.
pub fn march_lattice(
    o: [f32; 3],
    d: [f32; 3],
    grid: &OccupancyGrid,
    step: f32,
    max_samples: usize,
    jitter: f32,
    ts: &mut Vec<f32>,
) -> usize {
    let Some(span) = ray_aabb(o, d, grid.aabb_min, grid.aabb_max) else { return 0 };
    let before = ts.len();
    Lattice::on_span(o, d, span, step, jitter).march(grid, 0, max_samples, ts);
    ts.len() - before
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

    /// A grid with a few balls of occupied cells (and some single cells), the rest empty.
    fn balls(res: usize) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(res, [-1.0; 3], [1.0; 3]);
        g.fill_occupied(false);
        let centres = [[0.3, -0.2, 0.1, 0.25], [-0.5, 0.4, -0.3, 0.15], [0.1, 0.6, 0.5, 0.1]];
        for z in 0..res {
            for y in 0..res {
                for x in 0..res {
                    let p = [x, y, z].map(|v| -1.0 + 2.0 * (v as f32 + 0.5) / res as f32);
                    let inside =
                        centres.iter().any(|c| (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f32>() < c[3] * c[3]);
                    if inside || (x * 7 + y * 13 + z * 29) % 211 == 0 {
                        g.set_occupied(g.index([x, y, z]), true);
                    }
                }
            }
        }
        g
    }

    /// Random rays through the box from outside and from inside it.
    fn rays(n: usize) -> Vec<([f32; 3], [f32; 3], f32)> {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut u = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..n)
            .map(|i| {
                let scale = if i % 3 == 0 { 0.9 } else { 2.5 };
                let o = [0, 1, 2].map(|_| (2.0 * u() - 1.0) * scale);
                let mut d = [0, 1, 2].map(|_| 2.0 * u() - 1.0);
                if i % 17 == 0 {
                    d[i % 3] = 0.0; // parallel to a face
                }
                let len = d.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-6);
                (o, d.map(|v| v / len), u())
            })
            .collect()
    }

    /// Rendering's walk samples exactly the lattice points `t_m = start + m·step` whose cell is
    /// occupied (its `t` bit for bit), in order, against a brute-force scan of every lattice
    /// point: the points it misses (a point a cell's exit computation and its cell lookup place
    /// on different sides of a face, in the last bits) are at most 1 in 2000.
    #[test]
    fn the_rendering_walk_samples_the_occupied_lattice_points() {
        let g = balls(32);
        let (step, mut walked, mut missed, mut extra) = (0.013f32, 0usize, 0usize, 0usize);
        for (o, d, jitter) in rays(20_000) {
            let mut ts = Vec::new();
            march_lattice(o, d, &g, step, usize::MAX, jitter, &mut ts);
            assert!(ts.windows(2).all(|w| w[0] < w[1]), "increasing");
            let mut brute = Vec::new();
            if let Some(span) = ray_aabb(o, d, g.aabb_min, g.aabb_max) {
                let lat = Lattice::on_span(o, d, span, step, jitter);
                let mut m = 0;
                while lat.inside(m) {
                    let t = lat.t(m);
                    if g.is_occupied(g.cell_of([0, 1, 2].map(|a| o[a] + t * d[a]))) {
                        brute.push(t.to_bits());
                    }
                    m += 1;
                }
            }
            let got: Vec<u32> = ts.iter().map(|t| t.to_bits()).collect();
            extra += got.iter().filter(|t| !brute.contains(t)).count();
            missed += brute.iter().filter(|t| !got.contains(t)).count();
            walked += brute.len();
        }
        assert_eq!(extra, 0, "every sample is an occupied lattice point");
        assert!(walked > 10_000, "{walked}");
        assert!(missed * 2000 <= walked, "{missed} of {walked} missed");
    }

    /// Marching a ray in rounds (as the renderer does, a few samples per round) gives the same
    /// samples as one march, and the cell-by-cell walk the same ones within the last bits.
    #[test]
    fn the_rendering_walk_continues_across_rounds_and_agrees_with_the_cell_walk() {
        let g = balls(24);
        let step = 0.021f32;
        let (mut both, mut cells_total) = (0usize, 0usize);
        for (round, (o, d, _)) in rays(600).into_iter().enumerate() {
            let mut whole = Vec::new();
            march_lattice(o, d, &g, step, usize::MAX, 0.0, &mut whole);
            let mut rounds = Vec::new();
            if let Some(span) = ray_aabb(o, d, g.aabb_min, g.aabb_max) {
                let lat = Lattice::on_span(o, d, span, step, 0.0);
                let mut m = 0;
                while lat.inside(m) {
                    m = lat.march(&g, m, 1 + round % 5, &mut rounds);
                }
            }
            assert_eq!(whole, rounds);
            let mut cells = Vec::new();
            march_ray(o, d, &g, step, usize::MAX, 0.0, &mut cells);
            assert!(whole.len().abs_diff(cells.len()) <= 1 + cells.len() / 50, "{} vs {}", whole.len(), cells.len());
            both += whole.iter().zip(&cells).filter(|(a, b)| (*a - *b).abs() <= 1e-5 * b.abs().max(1.0)).count();
            cells_total += cells.len();
        }
        assert!(both * 100 >= cells_total * 99, "{both} of {cells_total} within the last bits");
    }

    /// [`first_index_past`] is `⌈x⌉` at least `m + 1`, saturating, for NaN and ±∞ too.
    #[test]
    fn the_index_past_an_empty_stretch_is_its_ceiling() {
        assert_eq!(first_index_past(f32::NAN, 4), 5);
        assert_eq!(first_index_past(f32::NEG_INFINITY, 4), 5);
        assert_eq!(first_index_past(f32::INFINITY, 4), u32::MAX);
        assert_eq!(first_index_past(1e12, 4), u32::MAX);
        assert_eq!(first_index_past(3.0, 4), 5);
        assert_eq!(first_index_past(5.0, 4), 5);
        assert_eq!(first_index_past(7.0, 4), 7);
        assert_eq!(first_index_past(7.25, 4), 8);
        assert_eq!(first_index_past(16_777_216.0, 0), 16_777_216);
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
