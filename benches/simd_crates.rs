//! A SIMD crate (`pulp` 0.22, the one faer builds on) against the NeRF's own kernels, on one
//! core, for the question "one source of truth per kernel where a crate serves": is a kernel
//! written once over `pulp::Simd` as fast as ours, and does it give the same bits?
//!
//! - `simd_crates/adam_*`: Adam's element-wise update (`optim::Adam`, with a weight-decayed
//!   range that starts and ends off a vector boundary) on 2¹⁶ parameters, in elements:
//!   - `adam_scalar_baseline`: the update's plain loop compiled for the baseline target (SSE2,
//!     what the portable kernels are);
//!   - `adam_ours_autovec_avx2`: the same loop inside a `#[target_feature(enable = "avx2,fma")]`
//!     entry point, which is what `kernels::dispatch` does for Adam (the crate's form for
//!     element-wise kernels);
//!   - `adam_ours_step_public`: the public `Adam::step` itself in a one-thread rayon pool (the
//!     above plus its blocking, bias corrections and `install`);
//!   - `adam_ours_lanes_avx2`: the update written explicitly over a small `Lanes` trait
//!     (std::arch, masked tail loads and stores) as `simd.rs` writes the hash and layer kernels,
//!     re-implemented here because `simd.rs` is private;
//!   - `adam_pulp`: the update written once over `pulp::Simd` and run through
//!     `pulp::Arch::new().dispatch` (its masked `partial_load`/`partial_store` for the tails);
//!   - `adam_pulp_scalar_fallback`: the same at `pulp::Scalar`, what a host without AVX2 runs.
//! - `simd_crates/hash_*`: the hash encoding's forward (the default model's 16 levels of at
//!   most 2¹⁵ rows, 4096 points spread over the box), in lookups (8 corners per level and point):
//!   - `hash_ours_encode_batch`: `HashEncoding::encode_batch` at the host's widest kernels;
//!   - `hash_ours_portable`: `encode_batch_with(Kernels::Portable)`, the scalar reference;
//!   - `hash_pulp_arrays{,_unchecked}`: the kernel written once over `pulp::Simd`. pulp's trait
//!     has no gather and no float-to-integer conversion, so the cells' truncation and the
//!     corners' table reads go through lane arrays (scalar `as u32` and scalar loads, bounds
//!     checked or not); the rest (clamp, scale, hash arithmetic, weights, sums) is pulp vectors.
//!
//! Before timing, the setup asserts that every variant gives the same bytes as the scalar code
//! on random inputs, and reports whether pulp's `mul_add_f32s`/`mul_add_e_f32s` are fused.
//!
//! The variants of a kernel share its buffers. Besides criterion's runs (one variant after
//! another), the setup times them interleaved, round by round, and prints each one's median to
//! stderr: on a shared, noisy machine those are the figures to compare.
//!
//! `nice -n 5 cargo bench --bench simd_crates -- --warm-up-time 1 --measurement-time 3`;
//! criterion's medians are in `target/criterion/simd_crates/*/new/estimates.json`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nerfsv_nerf::field_components::hash_encoding::HashEncoding;
use nerfsv_nerf::kernels::Kernels;
use nerfsv_nerf::optim::{Adam, AdamParams};
use pulp::bytemuck;
use pulp::{Simd, WithSimd};

/// Parameters of the Adam runs (four of `optim`'s blocks of 2¹⁴).
const PARAMS: usize = 1 << 16;
/// Points of the hash runs.
const POINTS: usize = 4096;
const LEVELS: usize = 16;
/// The most `f32` lanes of any pulp width (AVX-512 with `x86-v4`).
const MAX_LANES: usize = 16;

/// A deterministic stream of floats in `[-1, 1)` (no `rand` in the root's dev-dependencies).
struct Stream(u64);

impl Stream {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }
}

// ---------------------------------------------------------------------------------------------
// Kernel 1: Adam's update.

/// One update's constants, as `Adam::step` computes them for step `t`.
#[derive(Clone, Copy)]
struct Update {
    h: AdamParams,
    step_size: f32,
    inv_sqrt_bc2: f32,
}

impl Update {
    fn at(h: AdamParams, t: u64) -> Self {
        let bc1 = 1.0 - (h.beta1 as f64).powi(t as i32);
        let bc2 = 1.0 - (h.beta2 as f64).powi(t as i32);
        Self { h, step_size: (h.lr as f64 / bc1) as f32, inv_sqrt_bc2: (1.0 / bc2.sqrt()) as f32 }
    }

    /// `optim`'s `Update::apply`: the scalar loop that `dispatch` compiles at each width.
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

/// Adam's state and gradient, and the decayed range.
#[derive(Clone)]
struct AdamState {
    p: Vec<f32>,
    m: Vec<f32>,
    v: Vec<f32>,
    g: Vec<f32>,
    decay: std::ops::Range<usize>,
}

impl AdamState {
    /// Random parameters and gradients; `zeros`: every seventh gradient 0 (as in `optim`'s
    /// test; for the bit checks only, since m decays to subnormals on those over many steps).
    fn new(n: usize, seed: u64, zeros: bool) -> Self {
        let mut s = Stream(seed);
        let p = (0..n).map(|_| s.next()).collect();
        let g = (0..n)
            .map(|i| {
                let x = s.next();
                if zeros && i % 7 == 0 {
                    0.0
                } else if x.abs() < 1e-3 {
                    1e-3
                } else {
                    x
                }
            })
            .collect();
        Self { p, m: vec![0.0; n], v: vec![0.0; n], g, decay: n / 3 + 5..n - n / 5 + 3 }
    }

    /// Runs `f` on the three runs (undecayed, decayed, undecayed) as `Adam::step` splits a block.
    fn runs(&mut self, mut f: impl FnMut(&mut [f32], &mut [f32], &mut [f32], &[f32], bool)) {
        let (lo, hi) = (self.decay.start, self.decay.end);
        for (r, decayed) in [(0..lo, false), (lo..hi, true), (hi..self.p.len(), false)] {
            f(&mut self.p[r.clone()], &mut self.m[r.clone()], &mut self.v[r.clone()], &self.g[r], decayed);
        }
    }
}

#[inline(never)]
fn adam_scalar(s: &mut AdamState, u: Update) {
    s.runs(|p, m, v, g, d| u.apply(p, m, v, g, d));
}

/// # Safety
/// The host must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn adam_autovec_avx2(s: &mut AdamState, u: Update) {
    let (lo, hi) = (s.decay.start, s.decay.end);
    let n = s.p.len();
    // The three runs spelt out (a closure here would be compiled for the baseline).
    u.apply(&mut s.p[..lo], &mut s.m[..lo], &mut s.v[..lo], &s.g[..lo], false);
    u.apply(&mut s.p[lo..hi], &mut s.m[lo..hi], &mut s.v[lo..hi], &s.g[lo..hi], true);
    u.apply(&mut s.p[hi..n], &mut s.m[hi..n], &mut s.v[hi..n], &s.g[hi..n], false);
}

/// The `simd.rs` style: a small trait of `unsafe` std::arch operations per width, and one
/// generic `#[inline(always)]` kernel body compiled inside a `#[target_feature]` entry point.
#[cfg(target_arch = "x86_64")]
mod lanes {
    use super::Update;
    use std::arch::x86_64::*;

    pub trait Lanes: Copy {
        const N: usize;
        type F: Copy;
        unsafe fn splat(v: f32) -> Self::F;
        unsafe fn load(p: *const f32) -> Self::F;
        unsafe fn store(p: *mut f32, v: Self::F);
        unsafe fn load_first(p: *const f32, n: usize) -> Self::F;
        unsafe fn store_first(p: *mut f32, v: Self::F, n: usize);
        unsafe fn add(a: Self::F, b: Self::F) -> Self::F;
        unsafe fn sub(a: Self::F, b: Self::F) -> Self::F;
        unsafe fn mul(a: Self::F, b: Self::F) -> Self::F;
        unsafe fn div(a: Self::F, b: Self::F) -> Self::F;
        unsafe fn sqrt(a: Self::F) -> Self::F;
    }

    #[derive(Clone, Copy)]
    pub struct Avx2;

    #[inline(always)]
    unsafe fn first_mask8(n: usize) -> __m256i {
        _mm256_cmpgt_epi32(_mm256_set1_epi32(n as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7))
    }

    impl Lanes for Avx2 {
        const N: usize = 8;
        type F = __m256;
        #[inline(always)]
        unsafe fn splat(v: f32) -> __m256 {
            _mm256_set1_ps(v)
        }
        #[inline(always)]
        unsafe fn load(p: *const f32) -> __m256 {
            unsafe { _mm256_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn store(p: *mut f32, v: __m256) {
            unsafe { _mm256_storeu_ps(p, v) }
        }
        #[inline(always)]
        unsafe fn load_first(p: *const f32, n: usize) -> __m256 {
            unsafe { _mm256_maskload_ps(p, first_mask8(n)) }
        }
        #[inline(always)]
        unsafe fn store_first(p: *mut f32, v: __m256, n: usize) {
            unsafe { _mm256_maskstore_ps(p, first_mask8(n), v) }
        }
        #[inline(always)]
        unsafe fn add(a: __m256, b: __m256) -> __m256 {
            _mm256_add_ps(a, b)
        }
        #[inline(always)]
        unsafe fn sub(a: __m256, b: __m256) -> __m256 {
            _mm256_sub_ps(a, b)
        }
        #[inline(always)]
        unsafe fn mul(a: __m256, b: __m256) -> __m256 {
            _mm256_mul_ps(a, b)
        }
        #[inline(always)]
        unsafe fn div(a: __m256, b: __m256) -> __m256 {
            _mm256_div_ps(a, b)
        }
        #[inline(always)]
        unsafe fn sqrt(a: __m256) -> __m256 {
            _mm256_sqrt_ps(a)
        }
    }

    /// One vector of the update, in the scalar loop's operations and order.
    #[inline(always)]
    unsafe fn one<L: Lanes>(u: Update, decayed: bool, p: L::F, m: L::F, v: L::F, g: L::F) -> [L::F; 3] {
        unsafe {
            let h = u.h;
            let gi = if decayed { L::add(g, L::mul(L::splat(h.weight_decay), p)) } else { g };
            let m = L::add(L::mul(L::splat(h.beta1), m), L::mul(L::splat(1.0 - h.beta1), gi));
            let v = L::add(L::mul(L::splat(h.beta2), v), L::mul(L::mul(L::splat(1.0 - h.beta2), gi), gi));
            let den = L::add(L::mul(L::sqrt(v), L::splat(u.inv_sqrt_bc2)), L::splat(h.eps));
            [L::sub(p, L::div(L::mul(L::splat(u.step_size), m), den)), m, v]
        }
    }

    #[inline(always)]
    unsafe fn run<L: Lanes>(u: Update, p: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32], decayed: bool) {
        let n = p.len();
        assert!(m.len() == n && v.len() == n && g.len() == n);
        let (pp, mp, vp, gp) = (p.as_mut_ptr(), m.as_mut_ptr(), v.as_mut_ptr(), g.as_ptr());
        let mut i = 0;
        // SAFETY: every access is below `n` (full vectors while `i + N ≤ n`, then masked).
        unsafe {
            while i + L::N <= n {
                let [np, nm, nv] = one::<L>(
                    u,
                    decayed,
                    L::load(pp.add(i)),
                    L::load(mp.add(i)),
                    L::load(vp.add(i)),
                    L::load(gp.add(i)),
                );
                L::store(pp.add(i), np);
                L::store(mp.add(i), nm);
                L::store(vp.add(i), nv);
                i += L::N;
            }
            let r = n - i;
            if r > 0 {
                let (lp, lm) = (L::load_first(pp.add(i), r), L::load_first(mp.add(i), r));
                let (lv, lg) = (L::load_first(vp.add(i), r), L::load_first(gp.add(i), r));
                let [np, nm, nv] = one::<L>(u, decayed, lp, lm, lv, lg);
                L::store_first(pp.add(i), np, r);
                L::store_first(mp.add(i), nm, r);
                L::store_first(vp.add(i), nv, r);
            }
        }
    }

    /// # Safety
    /// The host must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn adam_avx2(s: &mut super::AdamState, u: Update) {
        let (lo, hi) = (s.decay.start, s.decay.end);
        let n = s.p.len();
        unsafe {
            run::<Avx2>(u, &mut s.p[..lo], &mut s.m[..lo], &mut s.v[..lo], &s.g[..lo], false);
            run::<Avx2>(u, &mut s.p[lo..hi], &mut s.m[lo..hi], &mut s.v[lo..hi], &s.g[lo..hi], true);
            run::<Avx2>(u, &mut s.p[hi..n], &mut s.m[hi..n], &mut s.v[hi..n], &s.g[hi..n], false);
        }
    }
}

/// The update over `pulp::Simd`: one vector of it.
#[inline(always)]
fn pulp_one<S: Simd>(s: S, u: Update, decayed: bool, p: S::f32s, m: S::f32s, v: S::f32s, g: S::f32s) -> [S::f32s; 3] {
    let h = u.h;
    let gi = if decayed { s.add_f32s(g, s.mul_f32s(s.splat_f32s(h.weight_decay), p)) } else { g };
    let m = s.add_f32s(s.mul_f32s(s.splat_f32s(h.beta1), m), s.mul_f32s(s.splat_f32s(1.0 - h.beta1), gi));
    let v =
        s.add_f32s(s.mul_f32s(s.splat_f32s(h.beta2), v), s.mul_f32s(s.mul_f32s(s.splat_f32s(1.0 - h.beta2), gi), gi));
    let den = s.add_f32s(s.mul_f32s(s.sqrt_f32s(v), s.splat_f32s(u.inv_sqrt_bc2)), s.splat_f32s(h.eps));
    [s.sub_f32s(p, s.div_f32s(s.mul_f32s(s.splat_f32s(u.step_size), m), den)), m, v]
}

/// One run of the update over `pulp::Simd`: whole vectors through `as_simd`, the tail through
/// pulp's masked `partial_load`/`partial_store`.
#[inline(always)]
fn pulp_run<S: Simd>(s: S, u: Update, p: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32], decayed: bool) {
    let (ph, pt) = S::as_mut_simd_f32s(p);
    let (mh, mt) = S::as_mut_simd_f32s(m);
    let (vh, vt) = S::as_mut_simd_f32s(v);
    let (gh, gt) = S::as_simd_f32s(g);
    for (((p, m), v), &g) in ph.iter_mut().zip(mh).zip(vh).zip(gh) {
        [*p, *m, *v] = pulp_one(s, u, decayed, *p, *m, *v, g);
    }
    if !pt.is_empty() {
        let ld = [s.partial_load_f32s(pt), s.partial_load_f32s(mt), s.partial_load_f32s(vt), s.partial_load_f32s(gt)];
        let [np, nm, nv] = pulp_one(s, u, decayed, ld[0], ld[1], ld[2], ld[3]);
        s.partial_store_f32s(pt, np);
        s.partial_store_f32s(mt, nm);
        s.partial_store_f32s(vt, nv);
    }
}

struct PulpAdam<'a> {
    s: &'a mut AdamState,
    u: Update,
}

impl WithSimd for PulpAdam<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Self { s, u } = self;
        let (lo, hi) = (s.decay.start, s.decay.end);
        let n = s.p.len();
        pulp_run(simd, u, &mut s.p[..lo], &mut s.m[..lo], &mut s.v[..lo], &s.g[..lo], false);
        pulp_run(simd, u, &mut s.p[lo..hi], &mut s.m[lo..hi], &mut s.v[lo..hi], &s.g[lo..hi], true);
        pulp_run(simd, u, &mut s.p[hi..n], &mut s.m[hi..n], &mut s.v[hi..n], &s.g[hi..n], false);
    }
}

fn adam_pulp(arch: pulp::Arch, s: &mut AdamState, u: Update) {
    arch.dispatch(PulpAdam { s, u });
}

fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

fn same_state(a: &AdamState, b: &AdamState) -> bool {
    same_bits(&a.p, &b.p) && same_bits(&a.m, &b.m) && same_bits(&a.v, &b.v)
}

/// Whether pulp's `mul_add_f32s` and `mul_add_e_f32s` round once, at `arch` and at pulp's
/// scalar fallback: `a·a − a²` with `a = 1 + 2⁻¹²` is `2⁻²⁴` fused and 0 unfused.
fn pulp_fma_fused(arch: pulp::Arch) -> [(bool, bool); 2] {
    struct Probe;
    impl WithSimd for Probe {
        type Output = (bool, bool);
        #[inline(always)]
        fn with_simd<S: Simd>(self, s: S) -> (bool, bool) {
            let a = 1.0f32 + 1.0 / 4096.0;
            let (va, vc) = (s.splat_f32s(a), s.splat_f32s(-(a * a)));
            let lane0 = |v: S::f32s| bytemuck::cast_slice::<S::f32s, f32>(std::slice::from_ref(&v))[0];
            (lane0(s.mul_add_f32s(va, va, vc)) != 0.0, lane0(s.mul_add_e_f32s(va, va, vc)) != 0.0)
        }
    }
    [arch.dispatch(Probe), pulp::Scalar::new().vectorize(Probe)]
}

// ---------------------------------------------------------------------------------------------
// Kernel 2: the hash encoding's forward.

#[inline(always)]
fn load_f<S: Simd>(a: &[f32; MAX_LANES]) -> S::f32s {
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&a[..S::F32_LANES]))
}

#[inline(always)]
fn load_u<S: Simd>(a: &[u32; MAX_LANES]) -> S::u32s {
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&a[..S::U32_LANES]))
}

#[inline(always)]
fn store_f<S: Simd>(v: S::f32s, a: &mut [f32; MAX_LANES]) {
    bytemuck::cast_slice_mut::<f32, u8>(&mut a[..S::F32_LANES]).copy_from_slice(bytemuck::bytes_of(&v));
}

#[inline(always)]
fn store_u<S: Simd>(v: S::u32s, a: &mut [u32; MAX_LANES]) {
    bytemuck::cast_slice_mut::<u32, u8>(&mut a[..S::U32_LANES]).copy_from_slice(bytemuck::bytes_of(&v));
}

/// `encode_batch` over `pulp::Simd`; `CHECKED`: bounds-checked table reads (pulp's safe idiom)
/// or not.
struct PulpEncode<'a, const CHECKED: bool> {
    enc: &'a HashEncoding,
    emb: &'a [f32],
    pos: &'a [f32],
    out: &'a mut [f32],
}

impl<const CHECKED: bool> WithSimd for PulpEncode<'_, CHECKED> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, s: S) {
        let Self { enc, emb, pos, out } = self;
        let lanes = S::F32_LANES;
        assert!(lanes <= MAX_LANES && emb.len() >= enc.n_params());
        let (n, e) = (pos.len() / 3, enc.output_dim());
        assert!(out.len() >= n * e);
        let (zero, one, half) = (s.splat_f32s(0.0), s.splat_f32s(1.0), s.splat_f32s(0.5));
        let mut i0 = 0;
        while i0 < n {
            let m = (n - i0).min(lanes);
            // Lanes past `m` repeat 0.5, inside every level's grid.
            let mut soa = [[0.5f32; MAX_LANES]; 3];
            for j in 0..m {
                for (d, axis) in soa.iter_mut().enumerate() {
                    axis[j] = pos[3 * (i0 + j) + d];
                }
            }
            let x = [load_f::<S>(&soa[0]), load_f::<S>(&soa[1]), load_f::<S>(&soa[2])];
            for (l, lv) in enc.levels.iter().enumerate() {
                // Cells: vector clamp and scale; truncation per lane (no conversion in the trait).
                let scale = s.splat_f32s(lv.scale);
                let mut g = [s.splat_u32s(0); 3];
                let mut f = [zero; 3];
                for d in 0..3 {
                    let p = s.add_f32s(s.mul_f32s(s.min_f32s(s.max_f32s(x[d], zero), one), scale), half);
                    let (mut pa, mut ia, mut fa) = ([0f32; MAX_LANES], [0u32; MAX_LANES], [0f32; MAX_LANES]);
                    store_f::<S>(p, &mut pa);
                    for j in 0..lanes {
                        ia[j] = pa[j] as u32;
                        fa[j] = ia[j] as f32;
                    }
                    g[d] = load_u::<S>(&ia);
                    f[d] = s.sub_f32s(p, load_f::<S>(&fa));
                }
                // Rows: the hash (or dense index) in u32 vectors.
                let (my, mz) = if lv.dense {
                    (lv.resolution, lv.resolution.wrapping_mul(lv.resolution))
                } else {
                    (2_654_435_761u32, 805_459_861u32)
                };
                let one_u = s.splat_u32s(1);
                let xs = [g[0], s.add_u32s(g[0], one_u)];
                let y0 = s.mul_u32s(g[1], s.splat_u32s(my));
                let ys = [y0, s.add_u32s(y0, s.splat_u32s(my))];
                let z0 = s.mul_u32s(g[2], s.splat_u32s(mz));
                let zs = [z0, s.add_u32s(z0, s.splat_u32s(mz))];
                let (offset, mask) = (s.splat_u32s(lv.offset), s.splat_u32s(lv.size.wrapping_sub(1)));
                let mut rows = [[0u32; MAX_LANES]; 8];
                for (c, r) in rows.iter_mut().enumerate() {
                    let h = if lv.dense {
                        s.add_u32s(s.add_u32s(xs[c & 1], ys[(c >> 1) & 1]), zs[(c >> 2) & 1])
                    } else {
                        s.and_u32s(s.xor_u32s(s.xor_u32s(xs[c & 1], ys[(c >> 1) & 1]), zs[(c >> 2) & 1]), mask)
                    };
                    store_u::<S>(s.add_u32s(offset, h), r);
                }
                // Weights (wx·wy)·wz and the sums from 0, corner by corner, as the scalar code.
                let w = [[s.sub_f32s(one, f[0]), f[0]], [s.sub_f32s(one, f[1]), f[1]], [s.sub_f32s(one, f[2]), f[2]]];
                let (mut a, mut b) = (zero, zero);
                for (c, r) in rows.iter().enumerate() {
                    let (mut ea, mut eb) = ([0f32; MAX_LANES], [0f32; MAX_LANES]);
                    for j in 0..lanes {
                        let k = 2 * r[j] as usize;
                        if CHECKED {
                            (ea[j], eb[j]) = (emb[k], emb[k + 1]);
                        } else {
                            // SAFETY: the rows are rows of this level, inside `emb` (asserted).
                            unsafe { (ea[j], eb[j]) = (*emb.get_unchecked(k), *emb.get_unchecked(k + 1)) };
                        }
                    }
                    let wc = s.mul_f32s(s.mul_f32s(w[0][c & 1], w[1][(c >> 1) & 1]), w[2][(c >> 2) & 1]);
                    a = s.add_f32s(a, s.mul_f32s(wc, load_f::<S>(&ea)));
                    b = s.add_f32s(b, s.mul_f32s(wc, load_f::<S>(&eb)));
                }
                let (mut aa, mut ba) = ([0f32; MAX_LANES], [0f32; MAX_LANES]);
                store_f::<S>(a, &mut aa);
                store_f::<S>(b, &mut ba);
                for j in 0..m {
                    out[(i0 + j) * e + 2 * l] = aa[j];
                    out[(i0 + j) * e + 2 * l + 1] = ba[j];
                }
            }
            i0 += m;
        }
    }
}

fn simd_crates(c: &mut Criterion) {
    let arch = pulp::Arch::new();
    let avx2 = Kernels::Avx2.available();
    let name = match arch {
        pulp::Arch::Scalar => "Scalar",
        #[cfg(target_arch = "x86_64")]
        pulp::Arch::V3(_) => "V3",
        #[allow(unreachable_patterns)]
        _ => "other",
    };
    eprintln!("pulp::Arch::new() = {name}; our widest kernels: {:?}", Kernels::widest());
    let [(f_arch, fe_arch), (f_scalar, fe_scalar)] = pulp_fma_fused(arch);
    eprintln!(
        "pulp mul_add_f32s fused: {f_arch} at {name}, {f_scalar} at Scalar; \
         mul_add_e_f32s fused: {fe_arch} at {name}, {fe_scalar} at Scalar"
    );

    // Kernel 1: the bits first (a step from the same state, zero gradients included; three
    // steps, so that m and v are not zero going in), then the times.
    let h = AdamParams { lr: 1e-2, beta1: 0.9, beta2: 0.99, eps: 1e-15, weight_decay: 1e-3 };
    let start = AdamState::new(PARAMS + 13, 7, true);
    let mut want = start.clone();
    for t in 1..=3 {
        adam_scalar(&mut want, Update::at(h, t));
    }
    let mut ours = Adam::new(start.p.len());
    let mut ours_p = start.p.clone();
    for _ in 1..=3 {
        ours.step(&mut ours_p, &start.g, h, start.decay.clone());
    }
    assert!(same_bits(&ours_p, &want.p) && same_bits(&ours.m, &want.m) && same_bits(&ours.v, &want.v));
    let mut got = start.clone();
    for t in 1..=3 {
        adam_pulp(arch, &mut got, Update::at(h, t));
    }
    assert!(same_state(&got, &want), "pulp's Adam differs from the scalar loop");
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        for f in [adam_autovec_avx2, lanes::adam_avx2] {
            let mut got = start.clone();
            for t in 1..=3 {
                // SAFETY: AVX2 and FMA were detected.
                unsafe { f(&mut got, Update::at(h, t)) };
            }
            assert!(same_state(&got, &want), "an AVX2 Adam differs from the scalar loop");
        }
    }
    let mut got = start.clone();
    for t in 1..=3 {
        pulp::Scalar::new().vectorize(PulpAdam { s: &mut got, u: Update::at(h, t) });
    }
    assert!(same_state(&got, &want), "pulp's scalar-fallback Adam differs from the scalar loop");
    eprintln!("adam: scalar, Adam::step, autovec AVX2, lanes AVX2, pulp ({name} and Scalar): same bytes");

    // Kernel 2: the default model's levels (as `ceiling`), points spread over the box.
    let enc = HashEncoding::new(LEVELS, 16, 512, 15);
    let emb: Vec<f32> = (0..enc.n_params()).map(|i| ((i % 97) as f32 - 48.0) * 1e-3).collect();
    let pos: Vec<f32> =
        (0..3 * POINTS).map(|i| ((i as u64 * 2_654_435_761) % 1_000_003) as f32 / 1_000_003.0).collect();
    let e = enc.output_dim();
    // The bits: random points, the box's faces and points outside it (clamped), a batch length
    // that is no multiple of the lanes, random embeddings.
    let mut st = Stream(3);
    let check_emb: Vec<f32> = (0..enc.n_params()).map(|_| st.next()).collect();
    let mut check_pos: Vec<f32> = (0..3 * 1001).map(|_| st.next() * 0.7 + 0.5).collect();
    check_pos.extend([0.0, 0.0, 0.0, 1.0, 1.0, 1.0, -0.5, 1.5, 0.999_999_9, 0.5, 0.0, 1.0]);
    let nc = check_pos.len() / 3;
    let mut want = vec![0f32; nc * e];
    enc.encode_batch_with(Kernels::Portable, &check_emb, &check_pos, &mut want);
    let mut got = vec![0f32; nc * e];
    enc.encode_batch(&check_emb, &check_pos, &mut got);
    assert!(same_bits(&got, &want), "encode_batch differs from the portable encoding");
    for checked in [true, false] {
        got.fill(0.0);
        let (emb, pos, out) = (&check_emb[..], &check_pos[..], &mut got[..]);
        if checked {
            arch.dispatch(PulpEncode::<true> { enc: &enc, emb, pos, out });
        } else {
            arch.dispatch(PulpEncode::<false> { enc: &enc, emb, pos, out });
        }
        assert!(same_bits(&got, &want), "pulp's encoding differs from the portable one");
    }
    got.fill(0.0);
    pulp::Scalar::new().vectorize(PulpEncode::<true> { enc: &enc, emb: &check_emb, pos: &check_pos, out: &mut got });
    assert!(same_bits(&got, &want), "pulp's scalar-fallback encoding differs from the portable one");
    eprintln!("hash: encode_batch ({:?}), portable, pulp ({name} and Scalar): same bytes", Kernels::widest());

    // The timed variants, kernel 1's then kernel 2's. The variants of a kernel share its
    // buffers (the same addresses, so the same cache-set and 4K-aliasing luck).
    use std::{cell::RefCell, rc::Rc};
    let u = Update::at(h, 1);
    let state = Rc::new(RefCell::new(AdamState::new(PARAMS, 11, false)));
    let adam_elems = PARAMS as u64;
    let mut variants: Vec<Variant> = Vec::new();
    macro_rules! add {
        ($name:expr, $elements:expr, $f:expr $(,)?) => {
            variants.push(Variant { name: $name, elements: $elements, f: $f })
        };
    }
    let s = state.clone();
    add!("adam_scalar_baseline", adam_elems, Box::new(move || adam_scalar(&mut s.borrow_mut(), u)));
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        let s = state.clone();
        // SAFETY (both): AVX2 and FMA were detected.
        add!(
            "adam_ours_autovec_avx2",
            adam_elems,
            Box::new(move || unsafe { adam_autovec_avx2(&mut s.borrow_mut(), u) })
        );
        let s = state.clone();
        add!("adam_ours_lanes_avx2", adam_elems, Box::new(move || unsafe { lanes::adam_avx2(&mut s.borrow_mut(), u) }));
    }
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("a rayon pool");
    let (s, mut t) = (state.clone(), 0);
    add!(
        "adam_ours_step_public",
        adam_elems,
        Box::new(move || {
            // The shared moments lent to an `Adam` (moved, not copied).
            let s = &mut *s.borrow_mut();
            let mut adam = Adam { m: std::mem::take(&mut s.m), v: std::mem::take(&mut s.v), t };
            one_thread.install(|| adam.step(&mut s.p, &s.g, h, s.decay.clone()));
            (s.m, s.v, t) = (adam.m, adam.v, adam.t);
        }),
    );
    let s = state.clone();
    add!("adam_pulp", adam_elems, Box::new(move || adam_pulp(arch, &mut s.borrow_mut(), u)));
    let s = state;
    add!(
        "adam_pulp_scalar_fallback",
        adam_elems,
        Box::new(move || pulp::Scalar::new().vectorize(PulpAdam { s: &mut s.borrow_mut(), u })),
    );

    let lookups = (POINTS * LEVELS * 8) as u64;
    let (enc, emb, pos) = (&enc, &emb[..], &pos[..]);
    let out = Rc::new(RefCell::new(vec![0f32; POINTS * e]));
    let o = out.clone();
    add!("hash_ours_encode_batch", lookups, Box::new(move || enc.encode_batch(emb, pos, &mut o.borrow_mut())));
    let o = out.clone();
    add!(
        "hash_ours_portable",
        lookups,
        Box::new(move || enc.encode_batch_with(Kernels::Portable, emb, pos, &mut o.borrow_mut())),
    );
    let o = out.clone();
    add!(
        "hash_pulp_arrays",
        lookups,
        Box::new(move || arch.dispatch(PulpEncode::<true> { enc, emb, pos, out: &mut o.borrow_mut() })),
    );
    let o = out;
    add!(
        "hash_pulp_arrays_unchecked",
        lookups,
        Box::new(move || arch.dispatch(PulpEncode::<false> { enc, emb, pos, out: &mut o.borrow_mut() })),
    );

    interleaved(&mut variants, INTERLEAVED_ROUNDS);
    let mut g = c.benchmark_group("simd_crates");
    g.sample_size(20);
    for v in &mut variants {
        g.throughput(Throughput::Elements(v.elements));
        g.bench_function(v.name, |b| b.iter(&mut v.f));
    }
    g.finish();
}

/// A timed variant: its name, the elements (or lookups) of one call, the call.
struct Variant<'a> {
    name: &'static str,
    elements: u64,
    f: Box<dyn FnMut() + 'a>,
}

/// Rounds of [`interleaved`].
const INTERLEAVED_ROUNDS: usize = 40;
/// The timed length of one variant's turn in a round (after one untimed call).
const TURN: std::time::Duration = std::time::Duration::from_millis(5);

/// The variants timed in turn, `rounds` rounds of about [`TURN`] each, so that the shared
/// machine's load falls on all of them alike (criterion runs them one after another); prints
/// each one's median per call and element.
fn interleaved(variants: &mut [Variant], rounds: usize) {
    use std::time::Instant;
    let reps: Vec<u32> = variants
        .iter_mut()
        .map(|v| {
            (v.f)();
            let t = Instant::now();
            (v.f)();
            (TURN.as_secs_f64() / t.elapsed().as_secs_f64().max(1e-9)).clamp(1.0, 1e6) as u32
        })
        .collect();
    let mut times = vec![Vec::with_capacity(rounds); variants.len()];
    for _ in 0..rounds {
        for ((v, &r), ts) in variants.iter_mut().zip(&reps).zip(&mut times) {
            // One untimed call first: the variants' buffers evict each other's from the caches.
            (v.f)();
            let t = Instant::now();
            for _ in 0..r {
                (v.f)();
            }
            ts.push(t.elapsed().as_secs_f64() / r as f64);
        }
    }
    eprintln!("interleaved, {rounds} rounds, medians (and the rounds' 25th–75th percentiles) per call:");
    for (v, ts) in variants.iter().zip(&mut times) {
        ts.sort_by(f64::total_cmp);
        let q = |f: f64| ts[((ts.len() - 1) as f64 * f).round() as usize];
        let (med, lo, hi) = (q(0.5), q(0.25), q(0.75));
        eprintln!(
            "  {:<28} {:>10.1} µs  [{:>8.1} {:>8.1}]  {:>7.3} ns/element  {:>8.1} M/s",
            v.name,
            med * 1e6,
            lo * 1e6,
            hi * 1e6,
            med * 1e9 / v.elements as f64,
            v.elements as f64 / med / 1e6
        );
    }
}

criterion_group!(benches, simd_crates);
criterion_main!(benches);
