//! The occupancy grid (instant-ngp/torch-ngp): a `res³` grid over the scene box holding a running
//! max of the optical thickness `σ·Δt` (Δt = the ray-marching step, [`crate::NerfConfig::step_size`]);
//! a cell is occupied when its value exceeds `min(grid_threshold, mean)`. Ray marching skips
//! unoccupied cells.
//!
//! Cell `(i, j, k)` (x, y, z) has index `i + res·(j + res·k)` and covers
//! `aabb_min + ([i, i+1], [j, j+1], [k, k+1]) · cell_size`.

/// Occupancy grid state.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    pub resolution: usize,
    pub aabb_min: [f32; 3],
    pub aabb_max: [f32; 3],
    /// `[res³]` running max of σ·Δt (dimensionless).
    pub density: Vec<f32>,
    /// `[res³]` 1 where occupied.
    pub occupied: Vec<u8>,
    /// Mean of `density` at the last update.
    pub mean: f32,
    /// The threshold in force: `min(grid_threshold, mean)`.
    pub threshold: f32,
}

impl OccupancyGrid {
    /// A grid with every cell occupied (before the first update).
    pub fn new(resolution: usize, aabb_min: [f32; 3], aabb_max: [f32; 3]) -> Self {
        let n = resolution.pow(3);
        Self { resolution, aabb_min, aabb_max, density: vec![0.0; n], occupied: vec![1; n], mean: 0.0, threshold: 0.0 }
    }

    /// Cell edge lengths in metres.
    pub fn cell_size(&self) -> [f32; 3] {
        let r = self.resolution as f32;
        [0, 1, 2].map(|d| (self.aabb_max[d] - self.aabb_min[d]) / r)
    }

    /// The cell containing world point `p` (clamped into the grid).
    #[inline]
    pub fn cell_of(&self, p: [f32; 3]) -> [usize; 3] {
        let r = self.resolution;
        // A loop rather than `[0, 1, 2].map`, which the compiler left as a call per sample.
        let mut c = [0usize; 3];
        for d in 0..3 {
            let u = (p[d] - self.aabb_min[d]) / (self.aabb_max[d] - self.aabb_min[d]) * r as f32;
            c[d] = (u.max(0.0) as usize).min(r - 1);
        }
        c
    }

    #[inline]
    pub fn index(&self, c: [usize; 3]) -> usize {
        c[0] + self.resolution * (c[1] + self.resolution * c[2])
    }

    #[inline]
    pub fn is_occupied(&self, c: [usize; 3]) -> bool {
        self.occupied[self.index(c)] != 0
    }

    /// Fraction of occupied cells.
    pub fn occupancy(&self) -> f64 {
        self.occupied.iter().map(|&o| o as u64).sum::<u64>() as f64 / self.occupied.len() as f64
    }

    /// Applies new measurements `(cell, σ·Δt)` as instant-ngp does: every cell decays,
    /// `d ← d·decay`, measured cells then take `max(d, new)` (a cell measured twice keeps the
    /// larger value); then recomputes the mean, the threshold and the bitfield.
    /// With `replace` (a full warm-up update that measured every cell) the grid forgets its
    /// past: `d ← new`, so the untrained initial density (σ ≈ 1 everywhere) is dropped at once.
    pub fn apply(&mut self, cells: &[u32], values: &[f32], decay: f32, threshold: f32, replace: bool) {
        let decay = if replace { 0.0 } else { decay };
        for d in &mut self.density {
            *d *= decay;
        }
        for (&c, &v) in cells.iter().zip(values) {
            let d = &mut self.density[c as usize];
            *d = d.max(v);
        }
        self.refresh(threshold);
    }

    /// Recomputes mean, threshold and bitfield from `density` (deterministic: fixed order).
    pub fn refresh(&mut self, threshold: f32) {
        let sum: f64 = self.density.chunks(4096).map(|c| c.iter().map(|&v| v.max(0.0) as f64).sum::<f64>()).sum();
        self.mean = (sum / self.density.len() as f64) as f32;
        self.threshold = threshold.min(self.mean);
        let th = self.threshold;
        for (o, &d) in self.occupied.iter_mut().zip(&self.density) {
            *o = (d > th) as u8;
        }
    }
}
