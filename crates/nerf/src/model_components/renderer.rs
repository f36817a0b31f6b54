//! Volume rendering of one ray (Max 1995; NeRF eq. 3), forward and backward.
//!
//! Samples `i = 0..k` have density `σ_i` (1/m), step `δ_i` (m), colour `c_i` and distance `t_i`.
//!   `α_i = 1 − exp(−σ_i δ_i)`, `T_i = Π_{j<i} (1 − α_j)`, `w_i = T_i α_i`
//!   `C = Σ_i w_i c_i + T_k · bg`, opacity `A = Σ_i w_i = 1 − T_k`, depth `D = Σ_i w_i t_i`.
//! Backward, with `g = ∂L/∂C` and `C_after_i = Σ_{j>i} w_j c_j + T_k · bg`:
//!   `∂L/∂c_i = w_i · g`
//!   `∂L/∂σ_i = δ_i · g·(T_{i+1} c_i − C_after_i)`   (since `T_j` for `j > i` carries `exp(−σ_i δ_i)`).
//! Early termination: a ray uses only its first [`active_count`] samples (until `T` drops below
//! a threshold); later samples have zero weight and zero gradient.

/// The number of leading samples a ray uses: sample `i` is used while `T_i ≥ t_min`.
#[inline]
pub fn active_count(sigma: &[f32], dt: &[f32], t_min: f32) -> usize {
    let mut trans = 1.0f32;
    for (i, (&s, &d)) in sigma.iter().zip(dt).enumerate() {
        if trans < t_min {
            return i;
        }
        trans *= (-s * d).exp();
    }
    sigma.len()
}

/// The composite of one ray.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Composite {
    pub color: [f32; 3],
    /// Accumulated alpha `1 − T_k`.
    pub opacity: f32,
    /// `Σ w_i t_i` (metres along the ray, not normalised by opacity).
    pub depth: f32,
}

/// sigma: `[k]`, rgb: `[k, 3]`, dt, t: `[k]`, bg: background colour.
pub fn composite_forward(sigma: &[f32], rgb: &[f32], dt: &[f32], t: &[f32], bg: [f32; 3]) -> Composite {
    let mut trans = 1.0f32;
    let mut c = [0.0f32; 3];
    let mut depth = 0.0f32;
    for i in 0..sigma.len() {
        let a = 1.0 - (-sigma[i] * dt[i]).exp();
        let w = trans * a;
        for ch in 0..3 {
            c[ch] += w * rgb[3 * i + ch];
        }
        depth += w * t[i];
        trans *= 1.0 - a;
    }
    for ch in 0..3 {
        c[ch] += trans * bg[ch];
    }
    Composite { color: c, opacity: 1.0 - trans, depth }
}

/// Backward of [`composite_forward`]'s colour. `color` is the forward output; writes
/// `d_sigma: [k]` and `d_rgb: [k, 3]`.
pub fn composite_backward(
    sigma: &[f32],
    rgb: &[f32],
    dt: &[f32],
    color: [f32; 3],
    d_color: [f32; 3],
    d_sigma: &mut [f32],
    d_rgb: &mut [f32],
) {
    let mut trans = 1.0f32;
    let mut after = color;
    for i in 0..sigma.len() {
        let e = (-sigma[i] * dt[i]).exp();
        let w = trans * (1.0 - e);
        let t_next = trans * e;
        let mut ds = 0.0f32;
        for ch in 0..3 {
            let ci = rgb[3 * i + ch];
            after[ch] -= w * ci;
            d_rgb[3 * i + ch] = w * d_color[ch];
            ds += d_color[ch] * (t_next * ci - after[ch]);
        }
        d_sigma[i] = dt[i] * ds;
        trans = t_next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn volume_rendering_backward_matches_finite_differences() {
        let k = 9;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut sigma: Vec<f32> = (0..k).map(|_| rng.random::<f32>() * 40.0).collect();
        let mut rgb: Vec<f32> = (0..3 * k).map(|_| rng.random::<f32>()).collect();
        let dt: Vec<f32> = (0..k).map(|_| 0.01 + 0.02 * rng.random::<f32>()).collect();
        let t: Vec<f32> = (0..k).map(|i| 1.0 + i as f32 * 0.03).collect();
        let bg = [0.2, 0.7, 0.4];
        let g = [0.3f32, -1.1, 0.8];
        let loss = |s: &[f32], c: &[f32]| -> f64 {
            let o = composite_forward(s, c, &dt, &t, bg);
            (0..3).map(|ch| (g[ch] * o.color[ch]) as f64).sum()
        };
        let out = composite_forward(&sigma, &rgb, &dt, &t, bg);
        let (mut ds, mut dc) = (vec![0.0; k], vec![0.0; 3 * k]);
        composite_backward(&sigma, &rgb, &dt, out.color, g, &mut ds, &mut dc);
        for i in 0..k {
            let h = 1e-2;
            let o = sigma[i];
            sigma[i] = o + h;
            let lp = loss(&sigma, &rgb);
            sigma[i] = o - h;
            let lm = loss(&sigma, &rgb);
            sigma[i] = o;
            let fd = (lp - lm) / (2.0 * h as f64);
            assert!((fd - ds[i] as f64).abs() < 1e-4 + 1e-2 * fd.abs(), "dσ_{i}: fd {fd} vs {}", ds[i]);
        }
        for i in 0..3 * k {
            let h = 1e-2;
            let o = rgb[i];
            rgb[i] = o + h;
            let lp = loss(&sigma, &rgb);
            rgb[i] = o - h;
            let lm = loss(&sigma, &rgb);
            rgb[i] = o;
            let fd = (lp - lm) / (2.0 * h as f64);
            assert!((fd - dc[i] as f64).abs() < 1e-4 + 1e-2 * fd.abs(), "dc_{i}: fd {fd} vs {}", dc[i]);
        }
    }

    #[test]
    fn opaque_first_sample_hides_the_rest_and_the_background() {
        let out = composite_forward(
            &[1e4, 1.0],
            &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            &[0.01, 0.01],
            &[2.0, 2.01],
            [0.0, 0.0, 1.0],
        );
        assert!((out.color[0] - 1.0).abs() < 1e-6 && out.color[2].abs() < 1e-6);
        assert!((out.opacity - 1.0).abs() < 1e-6 && (out.depth - 2.0).abs() < 1e-5);
        assert_eq!(active_count(&[1e4, 1.0], &[0.01, 0.01], 1e-4), 1);
    }
}
