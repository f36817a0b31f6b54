//! Bias-free linear layers (torch `nn.Linear(bias=False)`, weight `[out, in]` row-major) on
//! row-major activations `[n, width]`, via `matrixmultiply::sgemm`, and their activations.
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
    for (d, &v) in dy.iter_mut().zip(y) {
        if v <= 0.0 {
            *d = 0.0;
        }
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
