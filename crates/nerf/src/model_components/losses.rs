//! Photometric loss and PSNR.

/// Mean squared error over rays and channels: `L = 1/(3n) Σ (C − target)²`, and its gradient
/// `∂L/∂C = 2 (C − target) / (3n)` with `n = n_total` (the whole batch, so chunks add up).
#[inline]
pub fn mse_and_grad(color: [f32; 3], target: [f32; 3], n_total: usize) -> (f64, [f32; 3]) {
    let scale = 2.0 / (3.0 * n_total as f32);
    let mut l = 0.0f64;
    let mut g = [0.0f32; 3];
    for ch in 0..3 {
        let e = color[ch] - target[ch];
        l += (e as f64) * (e as f64);
        g[ch] = scale * e;
    }
    (l, g)
}

/// PSNR in dB of a mean squared error on `[0, 1]` values.
pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.max(1e-20).log10()
}
