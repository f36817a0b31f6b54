//! Multiresolution hash encoding (Müller et al. 2022, torch-ngp's `GridEncoder`).
//!
//! Level `l` has scale `s_l = base · b^l − 1` with `b = (finest/base)^(1/(L−1))` and
//! `r_l = ceil(s_l) + 2` grid vertices per axis. A point `x ∈ [0,1]³` maps to
//! `p = x·s_l + 0.5`; its cell corners are `floor(p) + {0,1}³` with trilinear weights.
//! A corner's table index is dense (`i + j·r + k·r²`) when `r³` fits the level's table, else
//! the spatial hash `i ⊕ j·2654435761 ⊕ k·805459861` (instant-ngp), both modulo the level size.
//!
//! Embeddings are one flat table `[n_entries, 2]` (`encoder.embeddings`), level `l` owning rows
//! `offset_l .. offset_l + size_l`. The encoding of a point is `[n_levels · 2]`, level-major.
//!
//! Maths (per level, feature f):
//!   forward   `y_f = Σ_c w_c · E[idx_c, f]`, `w_c = Π_d (frac_d or 1 − frac_d)`
//!   backward  `∂L/∂E[idx_c, f] += w_c · ∂L/∂y_f`
//!   position  `∂y_f/∂x_d = s_l · Σ_c (∂w_c/∂frac_d) · E[idx_c, f]`, `∂w_c/∂frac_d = ±Π_{d'≠d} w_{d'}`
//!             (+ for the upper corner along `d`); 0 along an axis where `x_d` is clamped (outside
//!             `[0,1]`). Continuous inside a cell, jumps across cell faces.

pub use super::hash_level::{corners, corners_frac, Level};
use crate::kernels::{self, Kernels};
#[cfg(target_arch = "x86_64")]
use crate::simd::{Avx2, Avx512, Lanes};

/// Features per level; fixed at 2 as in instant-ngp/torch-ngp.
pub const FEATURES: usize = 2;

/// The level layout of a hash encoding (the parameters live in a flat slice elsewhere).
#[derive(Clone, Debug, PartialEq)]
pub struct HashEncoding {
    pub levels: Vec<Level>,
    /// Total rows of the embedding table.
    pub n_entries: usize,
}

impl HashEncoding {
    /// `n_levels` levels from `base_resolution` to `finest_resolution`, at most `2^log2_table`
    /// rows per level (rounded up to a multiple of 8 as torch-ngp does).
    pub fn new(n_levels: usize, base_resolution: u32, finest_resolution: u32, log2_table: u32) -> Self {
        let max_size = 1u64 << log2_table;
        let b = if n_levels > 1 {
            ((finest_resolution as f64 / base_resolution as f64).ln() / (n_levels - 1) as f64).exp()
        } else {
            1.0
        };
        let mut levels = Vec::with_capacity(n_levels);
        let mut offset = 0u64;
        for l in 0..n_levels {
            let scale = base_resolution as f64 * b.powi(l as i32) - 1.0;
            let resolution = scale.ceil() as u64 + 2;
            let dense_size = resolution.pow(3);
            let dense = dense_size <= max_size;
            let size = dense_size.min(max_size).div_ceil(8) * 8;
            levels.push(Level {
                scale: scale as f32,
                resolution: resolution as u32,
                size: size as u32,
                offset: offset as u32,
                dense,
            });
            offset += size;
        }
        Self { levels, n_entries: offset as usize }
    }

    /// Output width: `n_levels · 2`.
    pub fn output_dim(&self) -> usize {
        self.levels.len() * FEATURES
    }

    /// Number of parameters: `n_entries · 2`.
    pub fn n_params(&self) -> usize {
        self.n_entries * FEATURES
    }

    /// Encodes one point `x ∈ [0,1]³` into `out: [n_levels · 2]` (all levels).
    #[inline]
    pub fn encode(&self, emb: &[f32], x: [f32; 3], out: &mut [f32]) {
        for (l, lv) in self.levels.iter().enumerate() {
            (out[2 * l], out[2 * l + 1]) = encode_one_level(lv, emb, x);
        }
    }

    /// Jacobian of [`encode`](Self::encode) with respect to the position: `jac: [n_levels · 2, 3]`
    /// row-major, `jac[k][d] = ∂y_k/∂x_d` (x in box coordinates `[0,1]`; divide by the box extent
    /// for metres). An axis where `x_d ∉ [0,1]` (clamped) has zero derivative.
    #[inline]
    pub fn position_jacobian(&self, emb: &[f32], x: [f32; 3], jac: &mut [f32]) {
        let inside = x.map(|v| (0.0..=1.0).contains(&v));
        for (l, lv) in self.levels.iter().enumerate() {
            let (idx, f) = corners_frac(lv, x);
            let g = [0, 1, 2].map(|d| if inside[d] { lv.scale } else { 0.0 });
            let mut ja = [0.0f32; 3];
            let mut jb = [0.0f32; 3];
            for (c, &row) in idx.iter().enumerate() {
                let up = [c & 1 == 1, (c >> 1) & 1 == 1, (c >> 2) & 1 == 1];
                let wd = [0, 1, 2].map(|d| if up[d] { f[d] } else { 1.0 - f[d] });
                let sd = [0, 1, 2].map(|d| if up[d] { 1.0f32 } else { -1.0 });
                // ∂w_c/∂frac_d: the weight with axis d's factor replaced by ±1.
                let dw = [sd[0] * wd[1] * wd[2], sd[1] * wd[0] * wd[2], sd[2] * wd[0] * wd[1]];
                let (ea, eb) = (emb[row as usize * 2], emb[row as usize * 2 + 1]);
                for d in 0..3 {
                    ja[d] += dw[d] * ea;
                    jb[d] += dw[d] * eb;
                }
            }
            for d in 0..3 {
                jac[6 * l + d] = g[d] * ja[d];
                jac[6 * l + 3 + d] = g[d] * jb[d];
            }
        }
    }

    /// [`encode`](Self::encode) of many points: pos `[n, 3]`, out `[n, n_levels · 2]`, the same
    /// bits at every kernel width (a vector of points of a level at a time where the host has
    /// one).
    pub fn encode_batch(&self, emb: &[f32], pos: &[f32], out: &mut [f32]) {
        self.encode_batch_with(kernels::active(), emb, pos, out);
    }

    /// [`encode_batch`](Self::encode_batch) at the width `k` (which the host must have).
    pub fn encode_batch_with(&self, k: Kernels, emb: &[f32], pos: &[f32], out: &mut [f32]) {
        let e = self.output_dim();
        if !self.batch_on_vectors(k, emb, pos, out, e, Kernel::Encode) {
            per_point(pos, out, e, |x, row| self.encode(emb, x, row));
        }
    }

    /// [`position_jacobian`](Self::position_jacobian) of many points: pos `[n, 3]`, jac
    /// `[n, n_levels · 2 · 3]` (point `i`'s Jacobian in row `i`), the same bits.
    pub fn position_jacobian_batch(&self, emb: &[f32], pos: &[f32], jac: &mut [f32]) {
        self.position_jacobian_batch_with(kernels::active(), emb, pos, jac);
    }

    /// [`position_jacobian_batch`](Self::position_jacobian_batch) at the width `k`.
    pub fn position_jacobian_batch_with(&self, k: Kernels, emb: &[f32], pos: &[f32], jac: &mut [f32]) {
        let row = self.output_dim() * 3;
        if !self.batch_on_vectors(k, emb, pos, jac, row, Kernel::PositionJacobian) {
            per_point(pos, jac, row, |x, r| self.position_jacobian(emb, x, r));
        }
    }

    /// Checks a batch's slices (rows of `width` floats in `out`) and runs `kernel` on them at
    /// the width `k` where it has vectors (and every level a vector form); false, having done
    /// nothing, elsewhere.
    fn batch_on_vectors(
        &self,
        k: Kernels,
        emb: &[f32],
        pos: &[f32],
        out: &mut [f32],
        width: usize,
        kernel: Kernel,
    ) -> bool {
        assert!(
            emb.len() >= self.n_params() && out.len() >= pos.len() / 3 * width,
            "hash encoding batch: slices too short"
        );
        assert!(k.available(), "{k:?} kernels on a host without them");
        #[cfg(target_arch = "x86_64")]
        if self.levels.iter().all(has_vector_form) {
            // SAFETY: the host has the width's features (asserted); the assert above bounds
            // the table and the output.
            match k {
                Kernels::Avx512 => unsafe { self.batch_avx512(emb, pos, out, kernel) },
                Kernels::Avx2 => unsafe { self.batch_avx2(emb, pos, out, kernel) },
                Kernels::Portable => return false,
            }
            return true;
        }
        let _ = (k, kernel);
        false
    }

    /// Backward of one level over many points, accumulating into that level's gradient rows in
    /// the points' order (so the sums' bits do not depend on the host).
    ///
    /// positions: `[n, 3]` in `[0,1]`; d_out: `[n, 2]` (∂L/∂y of this level);
    /// grad_level: `[size_l, 2]`, the level's slice of the embedding gradient.
    pub fn backward_level(&self, l: usize, positions: &[f32], d_out: &[f32], grad_level: &mut [f32]) {
        self.backward_level_with(kernels::active(), l, positions, d_out, grad_level);
    }

    /// [`backward_level`](Self::backward_level) at the width `k`.
    pub fn backward_level_with(&self, k: Kernels, l: usize, positions: &[f32], d_out: &[f32], grad_level: &mut [f32]) {
        let lv = self.levels[l];
        let n = d_out.len() / 2;
        assert!(
            positions.len() >= 3 * n && grad_level.len() >= 2 * lv.size as usize,
            "backward_level: slices too short"
        );
        assert!(k.available(), "{k:?} kernels on a host without them");
        let scatter = |grad_level: &mut [f32], i: usize, idx: &[u32; 8], w: &[f32; 8]| {
            let (ga, gb) = (d_out[2 * i], d_out[2 * i + 1]);
            for c in 0..8 {
                let k = (idx[c] - lv.offset) as usize * 2;
                grad_level[k] += w[c] * ga;
                grad_level[k + 1] += w[c] * gb;
            }
        };
        let live = |i: usize| d_out[2 * i] != 0.0 || d_out[2 * i + 1] != 0.0;
        #[cfg(target_arch = "x86_64")]
        if k != Kernels::Portable && has_vector_form(&lv) {
            let lanes = if k == Kernels::Avx512 { Avx512::N } else { Avx2::N };
            let mut i0 = 0;
            while i0 < n {
                let m = (n - i0).min(lanes);
                if (i0..i0 + m).any(live) {
                    // SAFETY: the host has the width (asserted); the level's corners are rows of
                    // the level.
                    let (idx, w) = unsafe {
                        match k {
                            Kernels::Avx512 => block_corners_avx512(&lv, positions, i0, m),
                            _ => block_corners_avx2(&lv, positions, i0, m),
                        }
                    };
                    for j in (0..m).filter(|&j| live(i0 + j)) {
                        scatter(grad_level, i0 + j, &idx[j], &w[j]);
                    }
                }
                i0 += m;
            }
            return;
        }
        for i in (0..n).filter(|&i| live(i)) {
            let (idx, w) = corners(&lv, [positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]]);
            scatter(grad_level, i, &idx, &w);
        }
    }

    /// The vector batch kernels: a vector of points at a time, level by level, each level's
    /// encoding (`out` `[n, 2·levels]`) or position Jacobian (`out` `[n, 2·levels·3]`).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn batch_lanes<L: Lanes>(&self, emb: &[f32], pos: &[f32], out: &mut [f32], kernel: Kernel) {
        use super::hash_simd::{cells, encode_level, jacobian_level, load_points, store_rows};
        let (n, e) = (pos.len() / 3, self.output_dim());
        let mut i0 = 0;
        while i0 < n {
            let m = (n - i0).min(L::N);
            // SAFETY (the block): the caller runs this where the host has L's width; `cells`
            // gives rows of this level, which `emb` holds (asserted by the caller).
            unsafe {
                let x = load_points::<L>(pos, i0, m);
                for (l, lv) in self.levels.iter().enumerate() {
                    let (idx, f) = cells::<L>(lv, &x);
                    match kernel {
                        // Row of a point: (y₀, y₁) per level.
                        Kernel::Encode => {
                            let (a, b) = encode_level::<L>(emb, &idx, &f);
                            store_rows::<L, 1>(&[[a, b]], m, &mut out[i0 * e + 2 * l..], e);
                        }
                        // Row of a point: ∂y₀/∂x_d then ∂y₁/∂x_d per level.
                        Kernel::PositionJacobian => {
                            let [[a0, a1, a2], [b0, b1, b2]] = jacobian_level::<L>(emb, lv.scale, &x, &idx, &f);
                            store_rows::<L, 3>(
                                &[[a0, a1], [a2, b0], [b1, b2]],
                                m,
                                &mut out[i0 * 3 * e + 6 * l..],
                                3 * e,
                            );
                        }
                    }
                }
            }
            i0 += m;
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn batch_avx512(&self, emb: &[f32], pos: &[f32], out: &mut [f32], kernel: Kernel) {
        unsafe { self.batch_lanes::<Avx512>(emb, pos, out, kernel) }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn batch_avx2(&self, emb: &[f32], pos: &[f32], out: &mut [f32], kernel: Kernel) {
        unsafe { self.batch_lanes::<Avx2>(emb, pos, out, kernel) }
    }
}

/// Whether the vector kernels can compute `lv`'s corners: a dense level, or a hashed one whose
/// table size is a power of two (its modulo a mask; every config makes one, but a hand-built
/// level need not).
fn has_vector_form(lv: &Level) -> bool {
    lv.dense || lv.size.is_power_of_two()
}

/// Which batch kernel [`HashEncoding::batch_on_vectors`] runs.
#[derive(Clone, Copy)]
enum Kernel {
    Encode,
    PositionJacobian,
}

/// `f(point, row)` for each point of `pos` (`[n, 3]`) and its row of `width` floats in `out`.
fn per_point(pos: &[f32], out: &mut [f32], width: usize, mut f: impl FnMut([f32; 3], &mut [f32])) {
    for (p, row) in pos.chunks_exact(3).zip(out.chunks_exact_mut(width)) {
        f([p[0], p[1], p[2]], row);
    }
}

/// One level of [`HashEncoding::encode`] at one point.
#[inline(always)]
fn encode_one_level(lv: &Level, emb: &[f32], x: [f32; 3]) -> (f32, f32) {
    let (idx, w) = corners(lv, x);
    let (mut a, mut b) = (0.0f32, 0.0f32);
    for c in 0..8 {
        let k = idx[c] as usize * 2;
        a += w[c] * emb[k];
        b += w[c] * emb[k + 1];
    }
    (a, b)
}

/// The corner rows and weights of points `i0 .. i0 + m` (`m ≤ 16`) of one level, per point.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn block_corners_avx512(lv: &Level, positions: &[f32], i0: usize, m: usize) -> ([[u32; 8]; 16], [[f32; 8]; 16]) {
    unsafe { super::hash_simd::block_corners::<Avx512>(lv, positions, i0, m) }
}

/// As [`block_corners_avx512`], `m ≤ 8`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_corners_avx2(lv: &Level, positions: &[f32], i0: usize, m: usize) -> ([[u32; 8]; 16], [[f32; 8]; 16]) {
    unsafe { super::hash_simd::block_corners::<Avx2>(lv, positions, i0, m) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// The textbook corner computation (`floor`, `h % size` on every level) that
    /// [`corners_frac`] must reproduce bit for bit.
    fn reference_corners_frac(lv: &Level, x: [f32; 3]) -> ([u32; 8], [f32; 3]) {
        let mut g = [0u32; 3];
        let mut f = [0f32; 3];
        for d in 0..3 {
            let p = x[d].clamp(0.0, 1.0) * lv.scale + 0.5;
            let fl = p.floor();
            g[d] = fl as u32;
            f[d] = p - fl;
        }
        let mut idx = [0u32; 8];
        let r = lv.resolution;
        for (c, ic) in idx.iter_mut().enumerate() {
            let (cx, cy, cz) = ((c & 1) as u32, ((c >> 1) & 1) as u32, ((c >> 2) & 1) as u32);
            let (i, j, k) = (g[0] + cx, g[1] + cy, g[2] + cz);
            let h = if lv.dense {
                i.wrapping_add(j.wrapping_mul(r)).wrapping_add(k.wrapping_mul(r * r))
            } else {
                i ^ j.wrapping_mul(2_654_435_761) ^ k.wrapping_mul(805_459_861)
            };
            *ic = lv.offset + h % lv.size;
        }
        (idx, f)
    }

    /// [`corners_frac`] (truncation instead of `floor`, no modulo on dense levels, a mask on
    /// power-of-two hashed levels) equals the `floor`/`%` reference on every level of the default
    /// config and of a few others, at random points and at the edge cases: 0, 1, just below 1,
    /// cell boundaries and their neighbouring floats, outside the box, ±0, ±∞ and NaN.
    #[test]
    fn corner_indices_match_the_floor_and_modulo_reference() {
        let d = crate::config::NerfConfig::default();
        let configs = [
            (d.hash_levels, d.base_resolution, d.finest_resolution, d.log2_hashmap_size),
            (16, 16, 512, 14),
            (16, 16, 2048, 19),
            (4, 4, 64, 10),
            (8, 2, 4096, 8),
            (3, 7, 33, 12),
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let below_one = 1.0f32 - f32::EPSILON / 2.0;
        let specials = [0.0, -0.0, 1.0, below_one, f32::MIN_POSITIVE, 0.5, -1e-7, 1.0 + 1e-7, 2.0, -3.0];
        let specials = specials.into_iter().chain([f32::INFINITY, f32::NEG_INFINITY, f32::NAN]);
        let specials: Vec<f32> = specials.collect();
        let same = |a: ([u32; 8], [f32; 3]), b: ([u32; 8], [f32; 3])| {
            a.0 == b.0 && a.1.iter().zip(b.1).all(|(u, v)| u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan()))
        };
        let mut n = 0usize;
        for (levels, base, finest, log2) in configs {
            let e = HashEncoding::new(levels, base, finest, log2);
            for lv in &e.levels {
                // Coordinates on and next to every cell boundary `(i − 0.5)/s` of this level.
                let mut xs = specials.clone();
                let s = lv.scale;
                for i in 0..=lv.resolution {
                    let b = (i as f32 - 0.5) / s;
                    xs.extend([
                        b,
                        f32::from_bits(b.to_bits().wrapping_add(1)),
                        f32::from_bits(b.to_bits().wrapping_sub(1)),
                    ]);
                }
                xs.extend((0..2000).map(|_| rng.random::<f32>()));
                xs.retain(|v| v.is_nan() || (-4.0..=4.0).contains(v) || v.is_infinite());
                for (t, &a) in xs.iter().enumerate() {
                    // Each coordinate on each axis, the other two from the list too (rotating).
                    for x in [
                        [a, 0.3, 0.7],
                        [0.9, a, 0.1],
                        [0.2, 0.6, a],
                        [a, xs[(t * 7) % xs.len()], xs[(t * 13) % xs.len()]],
                    ] {
                        let (got, want) = (corners_frac(lv, x), reference_corners_frac(lv, x));
                        assert!(same(got, want), "level {lv:?} x {x:?}: {got:?} vs {want:?}");
                        assert!(got.0.iter().all(|&r| r >= lv.offset && r < lv.offset + lv.size));
                        n += 1;
                    }
                }
            }
        }
        assert!(n > 100_000, "{n} points");
    }

    /// Points for the batch kernels: random ones inside, outside and on cell boundaries, and the
    /// edge cases of `corners_frac` (0, 1, ±∞, NaN, just outside), on each axis.
    fn batch_points(e: &HashEncoding, n: usize, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let specials =
            [0.0, -0.0, 1.0, 1.0 - f32::EPSILON / 2.0, -1e-7, 1.0 + 1e-7, 2.0, -3.0, f32::INFINITY, f32::NAN];
        (0..n)
            .flat_map(|i| {
                let mut p: [f32; 3] = [rng.random(), rng.random(), rng.random()];
                match i % 7 {
                    0 => p[i % 3] = specials[(i / 7) % specials.len()],
                    1 => {
                        let lv = &e.levels[i % e.levels.len()];
                        p[(i + 1) % 3] = ((i % lv.resolution as usize) as f32 - 0.5) / lv.scale;
                    }
                    2 => p = p.map(|v| 1.4 * v - 0.2),
                    _ => {}
                }
                p
            })
            .collect()
    }

    fn same_bits(a: &[f32], b: &[f32]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(u, v)| u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan()))
    }

    /// The batch kernels (sixteen points of a level at a time on AVX-512 hosts) give the
    /// per-point functions' bits: the encoding, the position Jacobian and the backward's
    /// accumulated gradient, for batch lengths around multiples of sixteen, on the default
    /// config's dense and hashed levels and on a hashed level whose size is not a power of two.
    #[test]
    fn batch_kernels_at_every_width_are_bit_identical_to_the_per_point_functions() {
        let d = crate::config::NerfConfig::default();
        let mut odd = HashEncoding::new(3, 4, 40, 9);
        let last = odd.levels[2];
        assert!(!last.dense);
        odd.levels[2] = Level { size: 500, ..last };
        odd.n_entries = (last.offset + 500) as usize;
        let encodings =
            [HashEncoding::new(d.hash_levels, d.base_resolution, d.finest_resolution, d.log2_hashmap_size), odd];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for (t, e) in encodings.iter().enumerate() {
            let emb: Vec<f32> = (0..e.n_params()).map(|_| rng.random::<f32>() - 0.5).collect();
            let (w, row) = (e.output_dim(), e.output_dim() * 3);
            for n in [0, 1, 15, 16, 17, 33, 200] {
                let pos = batch_points(e, n, 100 * t as u64 + n as u64);
                let mut want = vec![0f32; n * w];
                let mut want_jac = vec![0f32; n * row];
                for i in 0..n {
                    let x = [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
                    e.encode(&emb, x, &mut want[i * w..(i + 1) * w]);
                    e.position_jacobian(&emb, x, &mut want_jac[i * row..(i + 1) * row]);
                }
                for k in Kernels::on_this_host() {
                    let mut got = vec![7f32; n * w];
                    e.encode_batch_with(k, &emb, &pos, &mut got);
                    assert!(same_bits(&got, &want), "{k:?}: encoding {t}, n {n}");
                    let mut got_jac = vec![7f32; n * row];
                    e.position_jacobian_batch_with(k, &emb, &pos, &mut got_jac);
                    assert!(same_bits(&got_jac, &want_jac), "{k:?}: Jacobian {t}, n {n}");
                }
                // Backward: some points without gradient (skipped), the rest accumulated in order.
                let d_out: Vec<f32> =
                    (0..2 * n).map(|k| if (k / 2) % 5 == 3 { 0.0 } else { rng.random::<f32>() - 0.5 }).collect();
                for (l, lv) in e.levels.iter().enumerate() {
                    let d: Vec<f32> = d_out.clone();
                    let mut want_g = vec![0f32; 2 * lv.size as usize];
                    for i in (0..n).filter(|&i| d[2 * i] != 0.0 || d[2 * i + 1] != 0.0) {
                        let (idx, wc) = corners(lv, [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]]);
                        for c in 0..8 {
                            let k = (idx[c] - lv.offset) as usize * 2;
                            want_g[k] += wc[c] * d[2 * i];
                            want_g[k + 1] += wc[c] * d[2 * i + 1];
                        }
                    }
                    for k in Kernels::on_this_host() {
                        let mut got_g = vec![0f32; 2 * lv.size as usize];
                        e.backward_level_with(k, l, &pos, &d, &mut got_g);
                        assert!(same_bits(&got_g, &want_g), "{k:?}: backward {t}, n {n}, level {l}");
                    }
                }
            }
        }
    }

    #[test]
    fn levels_grow_geometrically_and_coarse_levels_are_dense() {
        let e = HashEncoding::new(16, 16, 512, 15);
        assert_eq!(e.levels.len(), 16);
        assert!(e.levels[0].dense && !e.levels[15].dense);
        assert!((e.levels[15].scale - 511.0).abs() < 0.5);
        assert!(e.levels.iter().all(|l| l.size <= 1 << 15 && l.size % 8 == 0));
    }

    /// ∂y/∂x of every level (dense and hashed) against central differences of an f64
    /// re-evaluation of the same cell's trilinear interpolation, at 200 random points; points
    /// whose stencil would leave the cell are skipped (the encoding is only C⁰ across faces).
    #[test]
    fn hash_encoding_position_jacobian_matches_finite_differences_on_every_level() {
        let e = HashEncoding::new(16, 16, 512, 14);
        assert!(e.levels[0].dense && !e.levels[15].dense);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let emb: Vec<f32> = (0..e.n_params()).map(|_| rng.random::<f32>() - 0.5).collect();
        let mut jac = vec![0.0f32; e.output_dim() * 3];
        let mut checked = vec![0usize; e.levels.len()];
        for _ in 0..200 {
            let x: [f32; 3] = [rng.random(), rng.random(), rng.random()];
            e.position_jacobian(&emb, x, &mut jac);
            for (l, lv) in e.levels.iter().enumerate() {
                let (idx, _) = corners_frac(lv, x);
                let s = lv.scale as f64;
                // y_f(x) of this cell in f64; `None` when x is too near a face for the stencil.
                let h = 1e-3 / s;
                let eval = |q: [f64; 3]| -> [f64; 2] {
                    let fr = [0, 1, 2].map(|d| {
                        let p = q[d] * s + 0.5;
                        p - p.floor()
                    });
                    let mut y = [0.0f64; 2];
                    for c in 0..8 {
                        let w: f64 = (0..3).map(|d| if (c >> d) & 1 == 1 { fr[d] } else { 1.0 - fr[d] }).product();
                        y[0] += w * emb[idx[c] as usize * 2] as f64;
                        y[1] += w * emb[idx[c] as usize * 2 + 1] as f64;
                    }
                    y
                };
                let fr = [0, 1, 2].map(|d| (x[d] as f64 * s + 0.5).fract());
                if fr.iter().any(|&f| !(0.01..0.99).contains(&f)) {
                    continue;
                }
                for d in 0..3 {
                    let mut xp = x.map(|v| v as f64);
                    let mut xm = xp;
                    xp[d] += h;
                    xm[d] -= h;
                    let (yp, ym) = (eval(xp), eval(xm));
                    for f in 0..2 {
                        let fd = (yp[f] - ym[f]) / (2.0 * h);
                        let an = jac[(2 * l + f) * 3 + d] as f64;
                        // f32 cell fractions differ from f64 by ~s·6e-8; |∂y/∂x| ≤ s·max|E|.
                        assert!((an - fd).abs() <= 1e-4 * s, "level {l} feature {f} axis {d}: {an} vs fd {fd}");
                    }
                }
                checked[l] += 1;
            }
        }
        assert!(checked.iter().all(|&c| c >= 100), "points checked per level: {checked:?}");
        // Clamped axes (outside the box) have no derivative.
        e.position_jacobian(&emb, [1.2, 0.5, -0.1], &mut jac);
        assert!(jac.chunks(3).all(|r| r[0] == 0.0 && r[2] == 0.0) && jac.chunks(3).any(|r| r[1] != 0.0));
    }

    #[test]
    fn hash_encoding_backward_matches_finite_differences_of_embeddings() {
        let e = HashEncoding::new(4, 4, 64, 10);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut emb: Vec<f32> = (0..e.n_params()).map(|_| rng.random::<f32>() - 0.5).collect();
        let n = 5;
        let pos: Vec<f32> = (0..3 * n).map(|_| rng.random::<f32>()).collect();
        let upstream: Vec<f32> = (0..n * e.output_dim()).map(|_| rng.random::<f32>() - 0.5).collect();
        // L = Σ upstream · y
        let loss = |emb: &[f32]| -> f64 {
            let mut out = vec![0.0; e.output_dim()];
            let mut s = 0.0f64;
            for i in 0..n {
                e.encode(emb, [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]], &mut out);
                for (k, o) in out.iter().enumerate() {
                    s += (*o as f64) * upstream[i * e.output_dim() + k] as f64;
                }
            }
            s
        };
        let mut grad = vec![0.0f32; e.n_params()];
        for (l, lv) in e.levels.iter().enumerate() {
            let d: Vec<f32> = (0..n).flat_map(|i| [upstream[i * 8 + 2 * l], upstream[i * 8 + 2 * l + 1]]).collect();
            let s = lv.offset as usize * 2;
            e.backward_level(l, &pos, &d, &mut grad[s..s + lv.size as usize * 2]);
        }
        let mut checked = 0;
        for k in (0..e.n_params()).filter(|&k| grad[k] != 0.0).take(40) {
            let h = 1e-2f32;
            let old = emb[k];
            emb[k] = old + h;
            let lp = loss(&emb);
            emb[k] = old - h;
            let lm = loss(&emb);
            emb[k] = old;
            let fd = (lp - lm) / (2.0 * h as f64);
            assert!((fd - grad[k] as f64).abs() < 1e-4 + 1e-3 * fd.abs(), "k={k} fd={fd} an={}", grad[k]);
            checked += 1;
        }
        assert!(checked >= 20);
    }
}
