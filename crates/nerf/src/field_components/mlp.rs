//! Bias-free linear layers (torch `nn.Linear(bias=False)`, weight `[out, in]` row-major) on
//! row-major activations `[n, width]`, and their activations.
//!
//! Layers up to [`SMALL_MAX`] wide (every layer of the default model) run in this module's own
//! kernels at the host's vector width ([`crate::kernels`]): the forward and input-gradient
//! products in [`small_gemm`], which keeps the weights in L1 and never packs the activations
//! (packing cost `matrixmultiply` nearly as much as its product at these sizes), and the weight
//! gradients (whose inner dimension is the batch) in a kernel that holds a block of the gradient
//! in registers while the samples stream through. Every output is one fused multiply-add chain
//! over its inner index in order, whatever the width (the portable kernels use
//! [`f32::mul_add`]), so the products are the same bits on every host. Wider layers use
//! `matrixmultiply::sgemm`, whose blocking and kernels depend on the host.
//!
//! Maths for `Y = X·Wᵀ` (`X: [n, in]`, `W: [out, in]`, `Y: [n, out]`):
//!   forward          `Y = X·Wᵀ`
//!   backward input   `∂L/∂X = ∂L/∂Y · W`
//!   backward weight  `∂L/∂W = (∂L/∂Y)ᵀ · X`
//! ReLU: `∂L/∂x = ∂L/∂y · [y > 0]`; sigmoid `s`: `∂L/∂x = ∂L/∂s · s(1 − s)`;
//! trunc_exp (torch-ngp): forward `exp(x)`, backward `exp(min(x, 15))`.

use crate::kernels::{self, Kernels};
#[cfg(target_arch = "x86_64")]
use crate::simd::{Avx2, Avx512, Lanes};

/// `Y[n,out] = X[n,in] · W[out,in]ᵀ` (overwrites `y`).
pub fn linear_forward(x: &[f32], w: &[f32], y: &mut [f32], n: usize, din: usize, dout: usize) {
    assert!(x.len() >= n * din && w.len() == dout * din && y.len() >= n * dout);
    if n == 0 {
        return;
    }
    // B = Wᵀ: B[k][o] = W[o][k].
    if small_gemm(x, Right::Transposed(w), y, n, din, dout) {
        return;
    }
    // SAFETY: the asserts above bound every index the strides reach.
    unsafe {
        matrixmultiply::sgemm(
            n,
            din,
            dout,
            1.0,
            x.as_ptr(),
            din as isize,
            1,
            w.as_ptr(),
            1,
            din as isize,
            0.0,
            y.as_mut_ptr(),
            dout as isize,
            1,
        );
    }
}

/// `dX[n,in] = dY[n,out] · W[out,in]` (overwrites `dx`).
pub fn linear_backward_input(dy: &[f32], w: &[f32], dx: &mut [f32], n: usize, din: usize, dout: usize) {
    assert!(dy.len() >= n * dout && w.len() == dout * din && dx.len() >= n * din);
    if n == 0 {
        return;
    }
    // B = W: B[k][i] = W[k][i].
    if small_gemm(dy, Right::Rows(w), dx, n, dout, din) {
        return;
    }
    // SAFETY: as above.
    unsafe {
        matrixmultiply::sgemm(
            n,
            dout,
            din,
            1.0,
            dy.as_ptr(),
            dout as isize,
            1,
            w.as_ptr(),
            din as isize,
            1,
            0.0,
            dx.as_mut_ptr(),
            din as isize,
            1,
        );
    }
}

/// `dW[out,in] (+)= dY[n,out]ᵀ · X[n,in]`; `accumulate = false` overwrites.
pub fn linear_backward_weight(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    n: usize,
    din: usize,
    dout: usize,
    accumulate: bool,
) {
    assert!(dy.len() >= n * dout && x.len() >= n * din && dw.len() == dout * din);
    if !accumulate {
        dw.fill(0.0);
    }
    if n == 0 {
        return;
    }
    if weight_gradient(kernels::active(), dy, x, dw, n, din, dout) {
        return;
    }
    // SAFETY: as above.
    unsafe {
        matrixmultiply::sgemm(
            dout,
            n,
            din,
            1.0,
            dy.as_ptr(),
            1,
            dout as isize,
            x.as_ptr(),
            din as isize,
            1,
            1.0,
            dw.as_mut_ptr(),
            din as isize,
            1,
        );
    }
}

/// The widest inner and outer dimension [`small_gemm`] and the weight-gradient kernel take.
pub const SMALL_MAX: usize = 64;

thread_local! {
    /// Each thread's copy of the right-hand matrix, `[k, 64]`, columns zero-padded to 64.
    static PANEL: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The right-hand matrix `B[k, m]` of [`small_gemm`], as it is stored.
#[derive(Clone, Copy, Debug)]
pub enum Right<'a> {
    /// Row-major: `B[kk][j] = b[kk·m + j]`.
    Rows(&'a [f32]),
    /// Stored transposed (a layer's weights `W[m, k]`): `B[kk][j] = w[j·k + kk]`.
    Transposed(&'a [f32]),
}

/// `C[n, m] = A[n, k] · B[k, m]` for `k, m ≤ SMALL_MAX` at [`kernels::active`]'s width: every
/// `C[i][j]` is `fma(A[i][k−1], B[k−1][j], … fma(A[i][0], B[0][j], 0))` (one accumulator per
/// output, the inner index in order), the chain `matrixmultiply`'s FMA kernels compute too.
/// Returns false, having done nothing, where the sizes do not apply.
pub fn small_gemm(a: &[f32], b: Right<'_>, c: &mut [f32], n: usize, k: usize, m: usize) -> bool {
    small_gemm_with(kernels::active(), a, b, c, n, k, m)
}

/// [`small_gemm`] at the width `kernels` (which the host must have).
pub fn small_gemm_with(kernels: Kernels, a: &[f32], b: Right<'_>, c: &mut [f32], n: usize, k: usize, m: usize) -> bool {
    if k == 0 || m == 0 || k > SMALL_MAX || m > SMALL_MAX {
        return false;
    }
    assert!(kernels.available(), "{kernels:?} kernels on a host without them");
    let src = match b {
        Right::Rows(b) | Right::Transposed(b) => b,
    };
    assert!(src.len() >= k * m, "small_gemm: right-hand matrix too short");
    assert!(a.len() >= n * k && c.len() >= n * m, "small_gemm: a or c too short");
    PANEL.with_borrow_mut(|panel| {
        // Every row of the panel is written whole below (columns past m zeroed), so a panel
        // that is long enough is reused as it is.
        if panel.len() < k * SMALL_MAX {
            panel.resize(k * SMALL_MAX, 0.0);
        }
        let panel = &mut panel[..k * SMALL_MAX];
        match b {
            Right::Rows(b) => {
                for (row, src) in panel.chunks_exact_mut(SMALL_MAX).zip(b.chunks_exact(m)) {
                    row[..m].copy_from_slice(src);
                    row[m..].fill(0.0);
                }
            }
            Right::Transposed(w) => {
                for (j, col) in w.chunks_exact(k).take(m).enumerate() {
                    for (kk, &v) in col.iter().enumerate() {
                        panel[kk * SMALL_MAX + j] = v;
                    }
                }
                if m < SMALL_MAX {
                    for row in panel.chunks_exact_mut(SMALL_MAX) {
                        row[m..].fill(0.0);
                    }
                }
            }
        }
        match kernels {
            // SAFETY: the host has the width (asserted); the asserts above bound a, c and the
            // panel.
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx512 => unsafe { rows_avx512(a, panel, c, n, k, m) },
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx2 => unsafe { rows_avx2(a, panel, c, n, k, m) },
            _ => rows_portable(a, panel, c, n, k, m),
        }
    });
    true
}

/// The portable product: each row's outputs accumulated over the inner index in order.
fn rows_portable(a: &[f32], panel: &[f32], c: &mut [f32], n: usize, k: usize, m: usize) {
    for (arow, crow) in a.chunks_exact(k).zip(c.chunks_exact_mut(m)).take(n) {
        let mut acc = [0f32; SMALL_MAX];
        for (&av, prow) in arow.iter().zip(panel.chunks_exact(SMALL_MAX)) {
            for (s, &bv) in acc[..m].iter_mut().zip(&prow[..m]) {
                *s = av.mul_add(bv, *s);
            }
        }
        crow.copy_from_slice(&acc[..m]);
    }
}

/// The AVX-512 product: 4 rows × up to 64 columns (16 of the 32 zmm registers accumulate) at a
/// time.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn rows_avx512(a: &[f32], panel: &[f32], c: &mut [f32], n: usize, k: usize, m: usize) {
    unsafe { rows::<Avx512, 4, 4>(a, panel, c, n, k, m) }
}

/// The AVX2 product: 6 rows × 16 columns at a time (12 of the 16 ymm registers accumulate, the
/// shape of BLIS's Haswell kernel; wider blocks spill).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn rows_avx2(a: &[f32], panel: &[f32], c: &mut [f32], n: usize, k: usize, m: usize) {
    unsafe { rows::<Avx2, 6, 2>(a, panel, c, n, k, m) }
}

/// `C = A·panel` in blocks of `R` rows × `V ≤ VMAX ≤ 4` vectors of columns, the last rows one
/// at a time; one fused multiply-add per output and inner index, in order; outputs past `m`
/// (the panel's zero padding) are not stored.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn rows<L: Lanes, const R: usize, const VMAX: usize>(
    a: &[f32],
    panel: &[f32],
    c: &mut [f32],
    n: usize,
    k: usize,
    m: usize,
) {
    let mut j0 = 0;
    while j0 < m {
        // SAFETY (the block): the caller's host has L's width; a, c and the panel are bounded
        // by small_gemm's asserts, the columns j0 + N·V ≤ 64 by the panel's width.
        unsafe {
            match (m - j0).div_ceil(L::N).min(VMAX) {
                1 => rows_v::<L, R, 1>(a, panel, c, n, k, m, j0),
                2 => rows_v::<L, R, 2>(a, panel, c, n, k, m, j0),
                3 => rows_v::<L, R, 3>(a, panel, c, n, k, m, j0),
                _ => rows_v::<L, R, 4>(a, panel, c, n, k, m, j0),
            }
        }
        j0 += VMAX * L::N;
    }
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn rows_v<L: Lanes, const R: usize, const V: usize>(
    a: &[f32],
    panel: &[f32],
    c: &mut [f32],
    n: usize,
    k: usize,
    m: usize,
    j0: usize,
) {
    let mut i = 0;
    while i + R <= n {
        unsafe { block_v::<L, R, V>(a, panel, c, i, k, m, j0) };
        i += R;
    }
    while i < n {
        unsafe { block_v::<L, 1, V>(a, panel, c, i, k, m, j0) };
        i += 1;
    }
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn block_v<L: Lanes, const R: usize, const V: usize>(
    a: &[f32],
    panel: &[f32],
    c: &mut [f32],
    i: usize,
    k: usize,
    m: usize,
    j0: usize,
) {
    debug_assert!(a.len() >= (i + R) * k && c.len() >= (i + R) * m && panel.len() >= k * SMALL_MAX);
    debug_assert!(j0 + L::N * V <= SMALL_MAX);
    // SAFETY (the block): see `rows`.
    unsafe {
        let mut acc = [[L::splat(0.0); V]; R];
        let (ap, pp) = (a.as_ptr(), panel.as_ptr().add(j0));
        for kk in 0..k {
            let mut b = [L::splat(0.0); V];
            for (v, bv) in b.iter_mut().enumerate() {
                *bv = L::load(pp.add(kk * SMALL_MAX + L::N * v));
            }
            for (r, acc_r) in acc.iter_mut().enumerate() {
                let av = L::splat(*ap.add((i + r) * k + kk));
                for (s, &bv) in acc_r.iter_mut().zip(&b) {
                    *s = L::fmadd(av, bv, *s);
                }
            }
        }
        let cp = c.as_mut_ptr();
        for (r, acc_r) in acc.iter().enumerate() {
            for (v, &s) in acc_r.iter().enumerate() {
                let left = m - j0 - L::N * v;
                let out = cp.add((i + r) * m + j0 + L::N * v);
                if left >= L::N {
                    L::store(out, s);
                } else {
                    L::store_first(out, s, left);
                }
            }
        }
    }
}

/// Samples per tile of the weight-gradient kernel: a tile of the activations (`[64, ≤ 64]`,
/// 16 KiB) stays in L1 while every block of output rows passes over it.
const WG_TILE: usize = 64;

/// `dW += dY[n,out]ᵀ · X[n,in]` at the width `kernels` for layers up to [`SMALL_MAX`] wide: every
/// `dW[o][i]` is the fused multiply-add chain over the samples in order,
/// `fma(dY[n−1][o], X[n−1][i], … fma(dY[0][o], X[0][i], dW[o][i]))`, whatever the tiling (test
/// `weight_gradient_is_the_fma_chain_over_samples_at_every_width`). Nothing is packed: a block
/// of output rows × columns is held in accumulators while a tile of samples streams through,
/// each sample's `X` row loaded once per block and its `dY` values broadcast. Returns false,
/// having done nothing, for wider layers.
pub fn weight_gradient(
    kernels: Kernels,
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    n: usize,
    din: usize,
    dout: usize,
) -> bool {
    if din > SMALL_MAX || dout > SMALL_MAX {
        return false;
    }
    assert!(kernels.available(), "{kernels:?} kernels on a host without them");
    assert!(dy.len() >= n * dout && x.len() >= n * din && dw.len() == dout * din);
    match kernels {
        // SAFETY: the host has the width (asserted); the assert above bounds every index.
        #[cfg(target_arch = "x86_64")]
        Kernels::Avx512 => unsafe { weight_gradient_avx512(dy, x, dw, n, din, dout) },
        #[cfg(target_arch = "x86_64")]
        Kernels::Avx2 => unsafe { weight_gradient_avx2(dy, x, dw, n, din, dout) },
        _ => {
            for (g, xs) in dy.chunks_exact(dout).zip(x.chunks_exact(din)).take(n) {
                for (&go, row) in g.iter().zip(dw.chunks_exact_mut(din)) {
                    for (w, &xv) in row.iter_mut().zip(xs) {
                        *w = go.mul_add(xv, *w);
                    }
                }
            }
        }
    }
    true
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn weight_gradient_avx512(dy: &[f32], x: &[f32], dw: &mut [f32], n: usize, din: usize, dout: usize) {
    unsafe { weight_gradient_lanes::<Avx512, 4, 4>(dy, x, dw, n, din, dout) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn weight_gradient_avx2(dy: &[f32], x: &[f32], dw: &mut [f32], n: usize, din: usize, dout: usize) {
    unsafe { weight_gradient_lanes::<Avx2, 6, 2>(dy, x, dw, n, din, dout) }
}

/// Tiles of samples; in each, blocks of `R` output rows (the last rows one at a time) × up to
/// `VMAX ≤ 4` vectors of columns.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn weight_gradient_lanes<L: Lanes, const R: usize, const VMAX: usize>(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    n: usize,
    din: usize,
    dout: usize,
) {
    let mut s0 = 0;
    while s0 < n {
        let s1 = (s0 + WG_TILE).min(n);
        let mut j0 = 0;
        while j0 < din {
            let v = (din - j0).div_ceil(L::N).min(VMAX);
            let mut o = 0;
            while o < dout {
                let at = WgBlock { tile: s0..s1, o, j0, din, dout };
                // SAFETY: the caller's host has L's width; `weight_gradient` bounds every index.
                unsafe {
                    if o + R <= dout {
                        match v {
                            1 => wg_block::<L, R, 1>(dy, x, dw, at),
                            2 => wg_block::<L, R, 2>(dy, x, dw, at),
                            3 => wg_block::<L, R, 3>(dy, x, dw, at),
                            _ => wg_block::<L, R, 4>(dy, x, dw, at),
                        }
                        o += R;
                    } else {
                        match v {
                            1 => wg_block::<L, 1, 1>(dy, x, dw, at),
                            2 => wg_block::<L, 1, 2>(dy, x, dw, at),
                            3 => wg_block::<L, 1, 3>(dy, x, dw, at),
                            _ => wg_block::<L, 1, 4>(dy, x, dw, at),
                        }
                        o += 1;
                    }
                }
            }
            j0 += VMAX * L::N;
        }
        s0 = s1;
    }
}

/// Where a block of the weight gradient lies: its samples, first output row and first column,
/// and the layer's widths.
#[derive(Clone)]
struct WgBlock {
    tile: std::ops::Range<usize>,
    o: usize,
    j0: usize,
    din: usize,
    dout: usize,
}

/// Rows `o..o + R`, columns `j0..j0 + N·V` (within `din`) of `dW` over the block's samples:
/// loads them, adds the samples' products in order, stores them.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn wg_block<L: Lanes, const R: usize, const V: usize>(dy: &[f32], x: &[f32], dw: &mut [f32], at: WgBlock) {
    let WgBlock { tile, o, j0, din, dout } = at;
    let (xp, yp, wp) = (x.as_ptr(), dy.as_ptr(), dw.as_mut_ptr());
    let left = |v: usize| din - j0 - L::N * v;
    // SAFETY (the block): see `weight_gradient_lanes`; a column past `din` is neither loaded nor
    // stored.
    unsafe {
        let load = |p: *const f32, v: usize| if left(v) >= L::N { L::load(p) } else { L::load_first(p, left(v)) };
        let mut acc = [[L::splat(0.0); V]; R];
        for (r, acc_r) in acc.iter_mut().enumerate() {
            for (v, a) in acc_r.iter_mut().enumerate() {
                *a = load(wp.add((o + r) * din + j0 + L::N * v), v);
            }
        }
        for s in tile {
            let mut xv = [L::splat(0.0); V];
            for (v, xv) in xv.iter_mut().enumerate() {
                *xv = load(xp.add(s * din + j0 + L::N * v), v);
            }
            for (r, acc_r) in acc.iter_mut().enumerate() {
                let g = L::splat(*yp.add(s * dout + o + r));
                for (a, &xv) in acc_r.iter_mut().zip(&xv) {
                    *a = L::fmadd(g, xv, *a);
                }
            }
        }
        for (r, acc_r) in acc.iter().enumerate() {
            for (v, &a) in acc_r.iter().enumerate() {
                let p = wp.add((o + r) * din + j0 + L::N * v);
                if left(v) >= L::N {
                    L::store(p, a);
                } else {
                    L::store_first(p, a, left(v));
                }
            }
        }
    }
}

/// In-place ReLU.
#[inline]
pub fn relu(y: &mut [f32]) {
    for v in y {
        *v = v.max(0.0);
    }
}

/// `dy ← dy · [y > 0]` where `y` is the ReLU output.
#[inline]
pub fn relu_backward(y: &[f32], dy: &mut [f32]) {
    // A select rather than a conditional store, so that the compiler vectorises it and no
    // branch follows the sign of each activation (a NaN activation keeps `dy`, as before).
    for (d, &v) in dy.iter_mut().zip(y) {
        *d = if v <= 0.0 { 0.0 } else { *d };
    }
}

#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// torch-ngp's `trunc_exp` forward (clamped at 80 only to keep it finite in f32).
#[inline]
pub fn trunc_exp(x: f32) -> f32 {
    x.min(80.0).exp()
}

/// torch-ngp's `trunc_exp` derivative: `exp(min(x, 15))`.
#[inline]
pub fn trunc_exp_grad(x: f32) -> f32 {
    x.min(15.0).exp()
}

/// The true derivative of [`trunc_exp`]'s forward (`exp(x)`, 0 past the clamp at 80), for
/// Jacobians of rendered outputs; training uses torch-ngp's clipped [`trunc_exp_grad`].
#[inline]
pub fn trunc_exp_exact_grad(x: f32) -> f32 {
    if x < 80.0 {
        x.exp()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// `C = A·B` by `matrixmultiply::sgemm` (`B` row-major `[k, m]`).
    fn sgemm_reference(a: &[f32], b: &[f32], n: usize, k: usize, m: usize) -> Vec<f32> {
        let mut c = vec![f32::NAN; n * m];
        // SAFETY: the buffers are exactly [n, k], [k, m], [n, m].
        unsafe {
            matrixmultiply::sgemm(
                n,
                k,
                m,
                1.0,
                a.as_ptr(),
                k as isize,
                1,
                b.as_ptr(),
                m as isize,
                1,
                0.0,
                c.as_mut_ptr(),
                m as isize,
                1,
            );
        }
        c
    }

    /// `(inner, outer)` widths of every layer the NeRF uses, and ragged ones.
    const SHAPES: [(usize, usize); 10] =
        [(32, 64), (64, 16), (31, 64), (64, 64), (64, 3), (3, 64), (16, 64), (64, 31), (1, 1), (5, 7)];

    /// Values of mixed sign and magnitude (so that a different summation order would show).
    fn mixed(rng: &mut rand_chacha::ChaCha8Rng, len: usize) -> Vec<f32> {
        (0..len).map(|_| (rng.random::<f32>() - 0.5) * 10f32.powi(rng.random_range(-3..4))).collect()
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The small-matrix kernel computes the fused multiply-add chain over the inner index in
    /// order at every width (and so `matrixmultiply`'s bits on a host with FMA, whose kernels
    /// compute the same chain), on every layer shape the NeRF uses and on ragged ones (rows not
    /// a multiple of the kernel's block, widths not of the vector), on values of mixed sign and
    /// magnitude (so that a different summation order would show).
    #[test]
    fn small_gemm_is_the_fma_chain_at_every_width() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let fma_host = Kernels::Avx2.available() || Kernels::Avx512.available();
        for &(k, m) in SHAPES.iter().chain(&[(3, 0)]) {
            for n in [0, 1, 2, 3, 5, 8, 37, 130] {
                let (a, b) = (mixed(&mut rng, n * k), mixed(&mut rng, k * m));
                let chain: Vec<f32> = (0..n * m)
                    .map(|q| {
                        let (i, j) = (q / m, q % m);
                        (0..k).fold(0.0f32, |c, kk| a[i * k + kk].mul_add(b[kk * m + j], c))
                    })
                    .collect();
                if fma_host {
                    assert_eq!(
                        bits(&sgemm_reference(&a, &b, n, k, m)),
                        bits(&chain),
                        "matrixmultiply n {n}, k {k}, m {m}"
                    );
                }
                // B row-major, and the same B stored transposed (bt[j·k + kk] = b[kk·m + j]).
                let bt: Vec<f32> = (0..m * k).map(|q| b[(q % k) * m + q / k]).collect();
                for kernels in Kernels::on_this_host() {
                    for right in [Right::Rows(&b), Right::Transposed(&bt)] {
                        let mut c = vec![f32::NAN; n * m];
                        let applied = small_gemm_with(kernels, &a, right, &mut c, n, k, m);
                        assert_eq!(applied, m > 0, "{kernels:?} n {n}, k {k}, m {m}");
                        if applied {
                            assert_eq!(bits(&c), bits(&chain), "{kernels:?} n {n}, k {k}, m {m}, {right:?}");
                        }
                    }
                }
            }
        }
    }

    /// The weight-gradient kernel computes each output as one fused multiply-add chain over the
    /// samples in order (from 0, or from the old value when accumulating), bit for bit, at every
    /// width, on every layer shape the NeRF uses and ragged ones (sample counts across the tile
    /// size, widths not a multiple of the vector or of the row block), on values of mixed sign
    /// and magnitude.
    #[test]
    fn weight_gradient_is_the_fma_chain_over_samples_at_every_width() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        for &(din, dout) in &SHAPES {
            for n in [0, 1, 3, 63, 64, 65, 130, 200] {
                let (dy, x, old) = (mixed(&mut rng, n * dout), mixed(&mut rng, n * din), mixed(&mut rng, dout * din));
                for accumulate in [false, true] {
                    let want: Vec<f32> = (0..dout * din)
                        .map(|q| {
                            let (o, i) = (q / din, q % din);
                            let c0 = if accumulate { old[q] } else { 0.0 };
                            (0..n).fold(c0, |c, s| dy[s * dout + o].mul_add(x[s * din + i], c))
                        })
                        .collect();
                    for kernels in Kernels::on_this_host() {
                        let mut got = if accumulate { old.clone() } else { vec![0.0; dout * din] };
                        assert!(weight_gradient(kernels, &dy, &x, &mut got, n, din, dout));
                        assert_eq!(
                            bits(&got),
                            bits(&want),
                            "{kernels:?} n {n}, in {din}, out {dout}, accumulate {accumulate}"
                        );
                    }
                    let mut got = if accumulate { old.clone() } else { vec![f32::NAN; dout * din] };
                    linear_backward_weight(&dy, &x, &mut got, n, din, dout, accumulate);
                    assert_eq!(bits(&got), bits(&want), "linear_backward_weight n {n}, in {din}, out {dout}");
                }
            }
        }
    }

    /// Two layers with ReLU: L = Σ u · (relu(X W0ᵀ) W1ᵀ); checks ∂L/∂W0, ∂L/∂W1, ∂L/∂X.
    #[test]
    fn mlp_backward_matches_finite_differences_for_weights_and_inputs() {
        let (n, d0, d1, d2) = (7, 5, 6, 4);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut r = |k: usize| -> Vec<f32> { (0..k).map(|_| rng.random::<f32>() - 0.5).collect() };
        let (mut x, mut w0, mut w1, u) = (r(n * d0), r(d1 * d0), r(d2 * d1), r(n * d2));
        let fwd = |x: &[f32], w0: &[f32], w1: &[f32]| -> (Vec<f32>, Vec<f32>, f64) {
            let mut h = vec![0.0; n * d1];
            linear_forward(x, w0, &mut h, n, d0, d1);
            relu(&mut h);
            let mut y = vec![0.0; n * d2];
            linear_forward(&h, w1, &mut y, n, d1, d2);
            let l = y.iter().zip(&u).map(|(a, b)| (*a as f64) * (*b as f64)).sum();
            (h, y, l)
        };
        let (h, _, _) = fwd(&x, &w0, &w1);
        let mut dw1 = vec![0.0; d2 * d1];
        linear_backward_weight(&u, &h, &mut dw1, n, d1, d2, false);
        let mut dh = vec![0.0; n * d1];
        linear_backward_input(&u, &w1, &mut dh, n, d1, d2);
        relu_backward(&h, &mut dh);
        let mut dw0 = vec![0.0; d1 * d0];
        linear_backward_weight(&dh, &x, &mut dw0, n, d0, d1, false);
        let mut dx = vec![0.0; n * d0];
        linear_backward_input(&dh, &w0, &mut dx, n, d0, d1);

        let h_fd = 1e-3f32;
        let check = |an: f32, fd: f64, what: &str| {
            assert!((an as f64 - fd).abs() < 2e-3 + 1e-2 * fd.abs(), "{what}: analytic {an} vs fd {fd}");
        };
        for k in 0..w0.len() {
            let o = w0[k];
            w0[k] = o + h_fd;
            let lp = fwd(&x, &w0, &w1).2;
            w0[k] = o - h_fd;
            let lm = fwd(&x, &w0, &w1).2;
            w0[k] = o;
            check(dw0[k], (lp - lm) / (2.0 * h_fd as f64), "dW0");
        }
        for k in 0..w1.len() {
            let o = w1[k];
            w1[k] = o + h_fd;
            let lp = fwd(&x, &w0, &w1).2;
            w1[k] = o - h_fd;
            let lm = fwd(&x, &w0, &w1).2;
            w1[k] = o;
            check(dw1[k], (lp - lm) / (2.0 * h_fd as f64), "dW1");
        }
        for k in 0..x.len() {
            let o = x[k];
            x[k] = o + h_fd;
            let lp = fwd(&x, &w0, &w1).2;
            x[k] = o - h_fd;
            let lm = fwd(&x, &w0, &w1).2;
            x[k] = o;
            check(dx[k], (lp - lm) / (2.0 * h_fd as f64), "dX");
        }
        // Accumulation adds to what is there.
        let mut acc = dw1.clone();
        linear_backward_weight(&u, &h, &mut acc, n, d1, d2, true);
        assert!(acc.iter().zip(&dw1).all(|(a, b)| (a - 2.0 * b).abs() < 1e-5));
    }
}
