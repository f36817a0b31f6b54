//! Bias-free linear layers (torch `nn.Linear(bias=False)`, weight `[out, in]` row-major) on
//! row-major activations `[n, width]`, and their activations.
//!
//! The forward and input-gradient products have a short inner dimension (the layer widths, at
//! most [`SMALL_MAX`]): on AVX-512 hosts they run in [`small_gemm`], which keeps the weights in
//! L1 and never packs the activations (packing cost `matrixmultiply` nearly as much as its
//! product at these sizes). Each output is the same fused multiply-add chain over the inner
//! index in order that `matrixmultiply`'s FMA kernels compute, so the results are bit-identical
//! to it. The weight gradients (whose inner dimension is the batch) run in a kernel of their own
//! ([`linear_backward_weight`]) that holds a block of the gradient in registers while the samples
//! stream through (one fused multiply-add chain per output over the samples in order;
//! `matrixmultiply` splits that chain into blocks, so the two differ in the last bits). Other
//! hosts and wider layers use `matrixmultiply::sgemm`.
//!
//! Maths for `Y = X·Wᵀ` (`X: [n, in]`, `W: [out, in]`, `Y: [n, out]`):
//!   forward          `Y = X·Wᵀ`
//!   backward input   `∂L/∂X = ∂L/∂Y · W`
//!   backward weight  `∂L/∂W = (∂L/∂Y)ᵀ · X`
//! ReLU: `∂L/∂x = ∂L/∂y · [y > 0]`; sigmoid `s`: `∂L/∂x = ∂L/∂s · s(1 − s)`;
//! trunc_exp (torch-ngp): forward `exp(x)`, backward `exp(min(x, 15))`.

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
    if n == 0 {
        if !accumulate {
            dw.fill(0.0);
        }
        return;
    }
    // On AVX-512 hosts, layers up to SMALL_MAX wide: every `dW[o][i]` is the fused multiply-add
    // chain over the samples in order, `fma(dY[n−1][o], X[n−1][i], … fma(dY[0][o], X[0][i], c₀))`
    // with `c₀` = 0, or the old `dW[o][i]` when accumulating, whatever the tiling (test
    // `weight_gradient_is_the_fma_chain_over_samples`). Nothing is packed: four output rows × `in`
    // columns are held in up to 16 zmm accumulators while a tile of samples streams through, each
    // sample's `X` row loaded once per block and its four `dY` values broadcast.
    #[cfg(target_arch = "x86_64")]
    if din <= SMALL_MAX && dout <= SMALL_MAX && std::arch::is_x86_feature_detected!("avx512f") {
        if !accumulate {
            dw.fill(0.0);
        }
        // SAFETY: AVX-512F was detected; the assert above bounds every index the kernel reaches.
        unsafe {
            match din.div_ceil(16) {
                1 => weight_gradient_v::<1>(dy, x, dw, n, din, dout),
                2 => weight_gradient_v::<2>(dy, x, dw, n, din, dout),
                3 => weight_gradient_v::<3>(dy, x, dw, n, din, dout),
                _ => weight_gradient_v::<4>(dy, x, dw, n, din, dout),
            }
        }
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
            if accumulate { 1.0 } else { 0.0 },
            dw.as_mut_ptr(),
            din as isize,
            1,
        );
    }
}

/// The widest inner and outer dimension [`small_gemm`] takes.
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

/// `C[n, m] = A[n, k] · B[k, m]` for `k, m ≤ SMALL_MAX` on a host with AVX-512 (others keep
/// `matrixmultiply`, whose packing costs less there): every `C[i][j]` is `fma(A[i][k−1], B[k−1][j], … fma(A[i][0], B[0][j], 0))`, the chain
/// `matrixmultiply`'s FMA kernels compute (one accumulator per output, the inner index in order,
/// the product scaled by α = 1), so the two agree bit for bit. Returns false, having done
/// nothing, where it does not apply.
pub fn small_gemm(a: &[f32], b: Right<'_>, c: &mut [f32], n: usize, k: usize, m: usize) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        if k == 0 || m == 0 || k > SMALL_MAX || m > SMALL_MAX || !std::arch::is_x86_feature_detected!("avx512f") {
            return false;
        }
        let src = match b {
            Right::Rows(b) | Right::Transposed(b) => b,
        };
        assert!(src.len() >= k * m, "small_gemm: right-hand matrix too short");
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
            // SAFETY: AVX-512F was detected above; the asserts of the callers bound a and c.
            unsafe { rows_avx512(a, panel, c, n, k, m) }
        });
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (a, b, c, n, k, m);
        false
    }
}

/// The kernel for AVX-512 hosts: `V` vectors of 16 outputs (`m ≤ 16·V`) for 4 rows at a time,
/// `4·V` zmm accumulators, one `vfmadd` per output and inner index in order; the last rows one
/// at a time; the outputs past `m` (the panel's zero padding) are not stored.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn rows_avx512(a: &[f32], panel: &[f32], c: &mut [f32], n: usize, k: usize, m: usize) {
    match m.div_ceil(16) {
        0 => {}
        1 => rows_v::<1>(a, panel, c, n, k, m),
        2 => rows_v::<2>(a, panel, c, n, k, m),
        3 => rows_v::<3>(a, panel, c, n, k, m),
        _ => rows_v::<4>(a, panel, c, n, k, m),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn rows_v<const V: usize>(a: &[f32], panel: &[f32], c: &mut [f32], n: usize, k: usize, m: usize) {
    let mut i = 0;
    while i + 4 <= n {
        block_v::<4, V>(a, panel, c, i, k, m);
        i += 4;
    }
    while i < n {
        block_v::<1, V>(a, panel, c, i, k, m);
        i += 1;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn block_v<const R: usize, const V: usize>(
    a: &[f32],
    panel: &[f32],
    c: &mut [f32],
    i: usize,
    k: usize,
    m: usize,
) {
    use std::arch::x86_64::*;
    debug_assert!(a.len() >= (i + R) * k && c.len() >= (i + R) * m && panel.len() >= k * SMALL_MAX);
    let mut acc = [[_mm512_setzero_ps(); V]; R];
    let (ap, pp) = (a.as_ptr(), panel.as_ptr());
    for kk in 0..k {
        let mut b = [_mm512_setzero_ps(); V];
        for (v, bv) in b.iter_mut().enumerate() {
            *bv = _mm512_loadu_ps(pp.add(kk * SMALL_MAX + 16 * v));
        }
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av = _mm512_set1_ps(*ap.add((i + r) * k + kk));
            for (s, &bv) in acc_r.iter_mut().zip(&b) {
                *s = _mm512_fmadd_ps(av, bv, *s);
            }
        }
    }
    let cp = c.as_mut_ptr();
    for (r, acc_r) in acc.iter().enumerate() {
        for (v, &s) in acc_r.iter().enumerate() {
            let left = m - 16 * v;
            let out = cp.add((i + r) * m + 16 * v);
            if left >= 16 {
                _mm512_storeu_ps(out, s);
            } else {
                _mm512_mask_storeu_ps(out, ((1u32 << left) - 1) as u16, s);
            }
        }
    }
}

/// Samples per tile of [`linear_backward_weight`]'s AVX-512 kernel: a tile of the activations
/// (`[64, ≤ 64]`, 16 KiB) stays in L1 while every block of output rows passes over it.
const WG_TILE: usize = 64;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn weight_gradient_v<const V: usize>(dy: &[f32], x: &[f32], dw: &mut [f32], n: usize, din: usize, dout: usize) {
    let mut s0 = 0;
    while s0 < n {
        let s1 = (s0 + WG_TILE).min(n);
        let mut o = 0;
        while o + 4 <= dout {
            weight_gradient_block::<4, V>(dy, x, dw, s0..s1, o, din, dout);
            o += 4;
        }
        match dout - o {
            1 => weight_gradient_block::<1, V>(dy, x, dw, s0..s1, o, din, dout),
            2 => weight_gradient_block::<2, V>(dy, x, dw, s0..s1, o, din, dout),
            3 => weight_gradient_block::<3, V>(dy, x, dw, s0..s1, o, din, dout),
            _ => {}
        }
        s0 = s1;
    }
}

/// Rows `o..o + R` of `dW` over the samples `tile`: loads them, adds the tile's products in
/// sample order, stores them. Columns past `din` are neither loaded nor stored (masked).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn weight_gradient_block<const R: usize, const V: usize>(
    dy: &[f32],
    x: &[f32],
    dw: &mut [f32],
    tile: std::ops::Range<usize>,
    o: usize,
    din: usize,
    dout: usize,
) {
    use std::arch::x86_64::*;
    let mask = |v: usize| -> u16 {
        let left = din - 16 * v;
        if left >= 16 {
            u16::MAX
        } else {
            ((1u32 << left) - 1) as u16
        }
    };
    let (xp, yp, wp) = (x.as_ptr(), dy.as_ptr(), dw.as_mut_ptr());
    let mut acc = [[_mm512_setzero_ps(); V]; R];
    for (r, acc_r) in acc.iter_mut().enumerate() {
        for (v, a) in acc_r.iter_mut().enumerate() {
            *a = _mm512_maskz_loadu_ps(mask(v), wp.add((o + r) * din + 16 * v));
        }
    }
    for s in tile {
        let mut xv = [_mm512_setzero_ps(); V];
        for (v, xv) in xv.iter_mut().enumerate() {
            *xv = _mm512_maskz_loadu_ps(mask(v), xp.add(s * din + 16 * v));
        }
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let g = _mm512_set1_ps(*yp.add(s * dout + o + r));
            for (a, &xv) in acc_r.iter_mut().zip(&xv) {
                *a = _mm512_fmadd_ps(g, xv, *a);
            }
        }
    }
    for (r, acc_r) in acc.iter().enumerate() {
        for (v, &a) in acc_r.iter().enumerate() {
            _mm512_mask_storeu_ps(wp.add((o + r) * din + 16 * v), mask(v), a);
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

    /// Whether this host runs the AVX-512 kernels.
    fn avx512() -> bool {
        #[cfg(target_arch = "x86_64")]
        return std::arch::is_x86_feature_detected!("avx512f");
        #[cfg(not(target_arch = "x86_64"))]
        false
    }

    /// On an AVX-512 host a kernel that declines every case tests nothing.
    fn assert_applied(applied: usize) {
        assert!(!avx512() || applied > 0, "the AVX-512 kernel was never used");
    }

    /// The small-matrix kernel gives `matrixmultiply`'s bits on every layer shape the NeRF uses
    /// and on ragged ones (rows not a multiple of the kernel's block, widths not of the vector),
    /// on values of mixed sign and magnitude (so that a different summation order would show).
    #[test]
    fn small_gemm_is_bit_identical_to_matrixmultiply() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let mut applied = 0;
        for &(k, m) in SHAPES.iter().chain(&[(3, 0)]) {
            for n in [0, 1, 2, 3, 5, 8, 37, 130] {
                let (a, b) = (mixed(&mut rng, n * k), mixed(&mut rng, k * m));
                let want = sgemm_reference(&a, &b, n, k, m);
                // B row-major, and the same B stored transposed (bt[j·k + kk] = b[kk·m + j]).
                let bt: Vec<f32> = (0..m * k).map(|q| b[(q % k) * m + q / k]).collect();
                for right in [Right::Rows(&b), Right::Transposed(&bt)] {
                    let mut c = vec![f32::NAN; n * m];
                    if !small_gemm(&a, right, &mut c, n, k, m) {
                        continue;
                    }
                    applied += 1;
                    assert_eq!(bits(&c), bits(&want), "n {n}, k {k}, m {m}, {right:?}");
                }
            }
        }
        assert_applied(applied);
    }

    /// The weight-gradient kernel computes each output as one fused multiply-add chain over the
    /// samples in order (from 0, or from the old value when accumulating), bit for bit, on every
    /// layer shape the NeRF uses and ragged ones (sample counts across the tile size, widths not
    /// a multiple of the vector or of the four-row block), on values of mixed sign and magnitude.
    #[test]
    fn weight_gradient_is_the_fma_chain_over_samples() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        let (mut applied, avx512) = (0, avx512());
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
                    let mut got = if accumulate { old.clone() } else { vec![f32::NAN; dout * din] };
                    linear_backward_weight(&dy, &x, &mut got, n, din, dout, accumulate);
                    if !avx512 {
                        // matrixmultiply (other hosts) splits the chain at its blocks.
                        continue;
                    }
                    applied += 1;
                    assert_eq!(bits(&got), bits(&want), "n {n}, in {din}, out {dout}, accumulate {accumulate}");
                }
            }
        }
        assert_applied(applied);
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
