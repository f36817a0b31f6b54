//! Adam (Kingma & Ba 2015) with bias correction and optional L2 weight decay, as torch.optim.Adam:
//!   `g ← g + λ·p` (on the decayed range), `m ← β₁m + (1−β₁)g`, `v ← β₂v + (1−β₂)g²`,
//!   `p ← p − lr · (m / (1−β₁ᵗ)) / (√(v / (1−β₂ᵗ)) + ε)`.
//! Element-wise over fixed blocks in parallel, so results do not depend on the thread count.

use std::ops::Range;

use rayon::prelude::*;

/// Adam moments; `t` counts the updates applied.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub t: u64,
}

/// Hyper-parameters of one update.
#[derive(Clone, Copy, Debug)]
pub struct AdamParams {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    pub weight_decay: f32,
}

const BLOCK: usize = 1 << 14;

impl Adam {
    pub fn new(n: usize) -> Self {
        Self { m: vec![0.0; n], v: vec![0.0; n], t: 0 }
    }

    /// One update of `params` with `grads`; weight decay applies to indices in `decay`.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32], h: AdamParams, decay: Range<usize>) {
        self.t += 1;
        let bc1 = 1.0 - (h.beta1 as f64).powi(self.t as i32);
        let bc2 = 1.0 - (h.beta2 as f64).powi(self.t as i32);
        let step_size = (h.lr as f64 / bc1) as f32;
        let inv_sqrt_bc2 = (1.0 / bc2.sqrt()) as f32;
        let step = Update { h, step_size, inv_sqrt_bc2 };
        params
            .par_chunks_mut(BLOCK)
            .zip(self.m.par_chunks_mut(BLOCK))
            .zip(self.v.par_chunks_mut(BLOCK))
            .zip(grads.par_chunks(BLOCK))
            .enumerate()
            .for_each(|(b, (((p, m), v), g))| {
                // The block's decayed indices `lo..hi`; three branch-free loops (which the
                // compiler vectorises) instead of a range test per element.
                let base = b * BLOCK;
                let (lo, hi) = if h.weight_decay != 0.0 {
                    let lo = decay.start.clamp(base, base + p.len()) - base;
                    (lo, (decay.end.clamp(base, base + p.len()) - base).max(lo))
                } else {
                    (0, 0)
                };
                crate::kernels::dispatch(
                    #[inline(always)]
                    || {
                        step.apply(&mut p[..lo], &mut m[..lo], &mut v[..lo], &g[..lo], false);
                        step.apply(&mut p[lo..hi], &mut m[lo..hi], &mut v[lo..hi], &g[lo..hi], true);
                        step.apply(&mut p[hi..], &mut m[hi..], &mut v[hi..], &g[hi..], false);
                    },
                );
            });
    }
}

/// One Adam update's constants: the hyper-parameters and the bias corrections of step `t`.
#[derive(Clone, Copy)]
struct Update {
    h: AdamParams,
    step_size: f32,
    inv_sqrt_bc2: f32,
}

impl Update {
    /// The update of one run of elements (`decayed`: with weight decay). A function, not a
    /// closure, so that it is inlined into each width's entry point of
    /// [`crate::kernels::dispatch`] (a closure would be compiled once, for the baseline).
    #[inline(always)]
    fn apply(self, p: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32], decayed: bool) {
        let Self { h, step_size, inv_sqrt_bc2 } = self;
        for (((p, m), v), &g) in p.iter_mut().zip(m).zip(v).zip(g) {
            let gi = if decayed { g + h.weight_decay * *p } else { g };
            *m = h.beta1 * *m + (1.0 - h.beta1) * gi;
            *v = h.beta2 * *v + (1.0 - h.beta2) * gi * gi;
            *p -= step_size * *m / (v.sqrt() * inv_sqrt_bc2 + h.eps);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocked, split update equals the per-element definition bit for bit, with a decayed
    /// range that starts and ends inside blocks and spans a block boundary.
    #[test]
    fn adam_matches_the_per_element_update_with_a_decayed_range_across_blocks() {
        let n = 2 * BLOCK + 500;
        let decay = BLOCK - 300..2 * BLOCK + 17;
        let h = AdamParams { lr: 0.01, beta1: 0.9, beta2: 0.99, eps: 1e-15, weight_decay: 1e-3 };
        let f =
            |i: usize, k: u32| ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(k) % 2001) as f32 / 1000.0 - 1.0;
        let mut p: Vec<f32> = (0..n).map(|i| f(i, 1)).collect();
        let mut want = p.clone();
        let mut a = Adam::new(n);
        let (mut m, mut v) = (vec![0.0f32; n], vec![0.0f32; n]);
        for t in 1..=3u32 {
            let g: Vec<f32> = (0..n).map(|i| if i % 7 == 0 { 0.0 } else { f(i, 10 + t) }).collect();
            a.step(&mut p, &g, h, decay.clone());
            let bc1 = 1.0 - (h.beta1 as f64).powi(t as i32);
            let bc2 = 1.0 - (h.beta2 as f64).powi(t as i32);
            let (step_size, inv_sqrt_bc2) = ((h.lr as f64 / bc1) as f32, (1.0 / bc2.sqrt()) as f32);
            for i in 0..n {
                let mut gi = g[i];
                if decay.contains(&i) {
                    gi += h.weight_decay * want[i];
                }
                m[i] = h.beta1 * m[i] + (1.0 - h.beta1) * gi;
                v[i] = h.beta2 * v[i] + (1.0 - h.beta2) * gi * gi;
                want[i] -= step_size * m[i] / (v[i].sqrt() * inv_sqrt_bc2 + h.eps);
            }
        }
        assert!(p.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(a.m.iter().zip(&m).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn adam_first_step_moves_each_parameter_by_lr_against_its_gradient_sign() {
        let mut p = vec![1.0f32, -2.0, 0.5];
        let g = vec![0.3f32, -4.0, 0.0];
        let mut a = Adam::new(3);
        a.step(&mut p, &g, AdamParams { lr: 0.1, beta1: 0.9, beta2: 0.99, eps: 1e-15, weight_decay: 0.0 }, 0..0);
        assert!((p[0] - 0.9).abs() < 1e-6 && (p[1] + 1.9).abs() < 1e-6 && p[2] == 0.5);
    }
}
