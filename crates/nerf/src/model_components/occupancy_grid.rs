//! The occupancy grid (instant-ngp/torch-ngp): a `res³` grid over the scene box holding a running
//! max of the optical thickness `σ·Δt` (Δt = the ray-marching step, [`crate::NerfConfig::step_size`]);
//! a cell is occupied when its value exceeds `min(grid_threshold, mean)`. Ray marching skips
//! unoccupied cells.
//!
//! Cell `(i, j, k)` (x, y, z) has index `i + res·(j + res·k)` and covers
//! `aabb_min + ([i, i+1], [j, j+1], [k, k+1]) · cell_size`.

/// Edge of a block of the grid's coarse level, in cells.
pub const BLOCK: usize = 4;

/// Occupancy grid state.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    pub resolution: usize,
    pub aabb_min: [f32; 3],
    pub aabb_max: [f32; 3],
    /// `[res³]` running max of σ·Δt (dimensionless).
    pub density: Vec<f32>,
    /// `[⌈res³/64⌉]` one bit per cell (cell `i` is bit `i % 64` of word `i / 64`), set where
    /// occupied: 256 KiB at 128³, so that marching's lookups stay in the L2 cache (a byte per
    /// cell, 2 MiB, did not). Read and written through [`Self::is_occupied_index`],
    /// [`Self::set_occupied`] and [`Self::fill_occupied`].
    occupied: Vec<u64>,
    /// The coarse level rendering's walk skips by: one bit per block of
    /// [`BLOCK`]³ cells (blocks per axis `⌈res/BLOCK⌉`, block `(i, j, k)` is bit
    /// `i + nb·(j + nb·k)`), set where any of its cells is occupied; kept with `occupied` by
    /// every writer (4 KiB at 128³: in the L1 cache).
    blocks: Vec<u64>,
    /// Mean of `density` at the last update.
    pub mean: f32,
    /// The threshold in force: `min(grid_threshold, mean)`.
    pub threshold: f32,
}

impl OccupancyGrid {
    /// A grid with every cell occupied (before the first update).
    pub fn new(resolution: usize, aabb_min: [f32; 3], aabb_max: [f32; 3]) -> Self {
        let n = resolution.pow(3);
        let mut grid = Self {
            resolution,
            aabb_min,
            aabb_max,
            density: vec![0.0; n],
            occupied: Vec::new(),
            blocks: Vec::new(),
            mean: 0.0,
            threshold: 0.0,
        };
        grid.fill_occupied(true);
        grid
    }

    /// Whether cell `i` (an [`index`](Self::index)) is occupied.
    #[inline(always)]
    pub fn is_occupied_index(&self, i: usize) -> bool {
        (self.occupied[i >> 6] >> (i & 63)) & 1 != 0
    }

    /// Whether any cell of the block containing cell `c` is occupied (the coarse level).
    #[inline(always)]
    pub fn is_block_occupied(&self, c: [usize; 3]) -> bool {
        let i = self.block_index(c);
        (self.blocks[i >> 6] >> (i & 63)) & 1 != 0
    }

    /// Blocks per axis of the coarse level.
    #[inline(always)]
    fn blocks_per_axis(&self) -> usize {
        self.resolution.div_ceil(BLOCK)
    }

    #[inline(always)]
    fn block_index(&self, c: [usize; 3]) -> usize {
        let nb = self.blocks_per_axis();
        c[0] / BLOCK + nb * (c[1] / BLOCK + nb * (c[2] / BLOCK))
    }

    /// Marks cell `i` occupied or not.
    pub fn set_occupied(&mut self, i: usize, occupied: bool) {
        let (w, b) = (i >> 6, 1u64 << (i & 63));
        if occupied {
            self.occupied[w] |= b;
        } else {
            self.occupied[w] &= !b;
        }
        let r = self.resolution;
        let c = [i % r, (i / r) % r, i / (r * r)];
        self.refresh_block(c);
    }

    /// Recomputes the coarse bit of the block containing cell `c` from its cells.
    fn refresh_block(&mut self, c: [usize; 3]) {
        let r = self.resolution;
        let lo = c.map(|v| v / BLOCK * BLOCK);
        let mut any = false;
        for z in lo[2]..(lo[2] + BLOCK).min(r) {
            for y in lo[1]..(lo[1] + BLOCK).min(r) {
                for x in lo[0]..(lo[0] + BLOCK).min(r) {
                    any |= self.is_occupied_index(x + r * (y + r * z));
                }
            }
        }
        let i = self.block_index(c);
        let (w, b) = (i >> 6, 1u64 << (i & 63));
        if any {
            self.blocks[w] |= b;
        } else {
            self.blocks[w] &= !b;
        }
    }

    /// Recomputes the whole coarse level from the cells: visits the set bits only (a few
    /// percent of the cells once trained), word by word.
    fn refresh_blocks(&mut self) {
        let nb = self.blocks_per_axis();
        self.blocks.clear();
        self.blocks.resize((nb * nb * nb).div_ceil(64), 0);
        let r = self.resolution;
        for (w, &word) in self.occupied.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let cell = 64 * w + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let i = self.block_index([cell % r, (cell / r) % r, cell / (r * r)]);
                self.blocks[i >> 6] |= 1 << (i & 63);
            }
        }
    }

    /// Marks every cell occupied or none.
    pub fn fill_occupied(&mut self, occupied: bool) {
        let n = self.resolution.pow(3);
        self.occupied.clear();
        self.occupied.resize(n.div_ceil(64), 0);
        if occupied {
            for i in 0..n {
                self.occupied[i >> 6] |= 1 << (i & 63);
            }
        }
        self.refresh_blocks();
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
        self.is_occupied_index(self.index(c))
    }

    /// Fraction of occupied cells.
    pub fn occupancy(&self) -> f64 {
        self.occupied.iter().map(|w| w.count_ones() as u64).sum::<u64>() as f64 / self.density.len() as f64
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
        for (w, chunk) in self.occupied.iter_mut().zip(self.density.chunks(64)) {
            *w = chunk.iter().enumerate().fold(0u64, |acc, (b, &d)| acc | (((d > th) as u64) << b));
        }
        self.refresh_blocks();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bitfield holds exactly `density > threshold` per cell after a refresh, on a grid whose
    /// cell count is not a multiple of 64; set/fill change one cell or all, and the occupancy is
    /// the fraction of set cells.
    #[test]
    fn the_bitfield_is_the_threshold_of_every_cell() {
        let mut g = OccupancyGrid::new(7, [-1.0; 3], [1.0; 3]);
        let n = 7usize.pow(3);
        assert!((0..n).all(|i| g.is_occupied_index(i)) && g.occupancy() == 1.0);
        for (i, d) in g.density.iter_mut().enumerate() {
            *d = ((i * 37) % 11) as f32 / 10.0;
        }
        g.refresh(0.45);
        let th = g.threshold;
        assert!((0..n).all(|i| g.is_occupied_index(i) == (g.density[i] > th)));
        let set = (0..n).filter(|&i| g.density[i] > th).count();
        assert_eq!(g.occupancy(), set as f64 / n as f64);
        g.fill_occupied(false);
        g.set_occupied(200, true);
        assert!((0..n).all(|i| g.is_occupied_index(i) == (i == 200)));
        assert!(g.is_occupied([4, 0, 4]) == (g.index([4, 0, 4]) == 200));
        g.set_occupied(200, false);
        assert_eq!(g.occupancy(), 0.0);
    }

    /// Every block's coarse bit is "some cell of it is occupied" after each writer (a refresh, a
    /// fill, setting and clearing one cell), on a grid whose side (7) leaves partial blocks.
    #[test]
    fn the_coarse_level_is_any_occupied_cell_of_each_block() {
        let agree = |g: &OccupancyGrid| {
            let r = g.resolution;
            for z in 0..r {
                for y in 0..r {
                    for x in 0..r {
                        let lo = [x, y, z].map(|v| v / BLOCK * BLOCK);
                        let mut any = false;
                        for k in lo[2]..(lo[2] + BLOCK).min(r) {
                            for j in lo[1]..(lo[1] + BLOCK).min(r) {
                                for i in lo[0]..(lo[0] + BLOCK).min(r) {
                                    any |= g.is_occupied([i, j, k]);
                                }
                            }
                        }
                        assert_eq!(g.is_block_occupied([x, y, z]), any, "cell {x} {y} {z}");
                    }
                }
            }
        };
        let mut g = OccupancyGrid::new(7, [-1.0; 3], [1.0; 3]);
        agree(&g);
        for (i, d) in g.density.iter_mut().enumerate() {
            *d = if i % 29 == 0 { 1.0 } else { 0.0 };
        }
        g.refresh(0.5);
        agree(&g);
        assert!((0..7).any(|x| !g.is_block_occupied([x, 6, 6])), "some block is empty");
        g.fill_occupied(false);
        agree(&g);
        g.set_occupied(g.index([5, 6, 2]), true);
        agree(&g);
        assert!(g.is_block_occupied([4, 4, 0]) && !g.is_block_occupied([0, 0, 0]));
        g.set_occupied(g.index([5, 6, 2]), false);
        agree(&g);
        assert!(!g.is_block_occupied([4, 4, 0]));
    }
}
