//! The vector operations the NeRF's x86-64 kernels are written in, once for both widths.
//!
//! A kernel is a generic `#[inline(always)]` function over [`Lanes`]; its entry point is a
//! `#[target_feature]` function per width that calls it with [`Avx512`] (16 lanes) or [`Avx2`]
//! (8 lanes), so one source compiles to both. Each operation is one IEEE operation per lane
//! (nothing fused except [`Lanes::fmadd`], nothing reordered), so a kernel written with them
//! computes what its scalar form computes, bit for bit, at either width.
//!
//! Every method is `unsafe`: it may only run where the host has its width's features, which
//! [`crate::kernels::active`] checked before the entry point was called.

use std::arch::x86_64::*;

/// The most lanes of any width (sizes the kernels' stack buffers).
pub(crate) const MAX_LANES: usize = 16;

/// One vector width's operations on `N` lanes of `f32` and `u32`.
pub(crate) trait Lanes: Copy {
    const N: usize;
    type F: Copy;
    type I: Copy;
    unsafe fn splat(v: f32) -> Self::F;
    /// `N` floats from `p` (unaligned).
    unsafe fn load(p: *const f32) -> Self::F;
    unsafe fn store(p: *mut f32, v: Self::F);
    /// The first `n < N` floats from `p`, the other lanes 0; nothing past `p + n` is read.
    unsafe fn load_first(p: *const f32, n: usize) -> Self::F;
    /// The first `n < N` lanes to `p`; nothing past `p + n` is written.
    unsafe fn store_first(p: *mut f32, v: Self::F, n: usize);
    unsafe fn add(a: Self::F, b: Self::F) -> Self::F;
    unsafe fn sub(a: Self::F, b: Self::F) -> Self::F;
    unsafe fn mul(a: Self::F, b: Self::F) -> Self::F;
    /// `a·b + c` rounded once.
    unsafe fn fmadd(a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    /// `x` with its sign bit flipped (what `−1.0 · x` gives, zeros and NaNs included).
    unsafe fn negate(x: Self::F) -> Self::F;
    /// `clamp(x, 0, 1)` where a NaN lane becomes 0.
    unsafe fn clamp_unit(x: Self::F) -> Self::F;
    /// Truncation of non-negative lanes below 2³¹ to integers, and back.
    unsafe fn trunc(x: Self::F) -> Self::I;
    unsafe fn float(i: Self::I) -> Self::F;
    /// `x` where `x` is NaN, else `v`.
    unsafe fn nan_from(v: Self::F, x: Self::F) -> Self::F;
    /// `s` where `0 ≤ x ≤ 1`, else 0.
    unsafe fn where_unit(x: Self::F, s: f32) -> Self::F;
    unsafe fn splat_u(v: u32) -> Self::I;
    unsafe fn add_u(a: Self::I, b: Self::I) -> Self::I;
    /// Wrapping product.
    unsafe fn mul_u(a: Self::I, b: Self::I) -> Self::I;
    unsafe fn xor_u(a: Self::I, b: Self::I) -> Self::I;
    unsafe fn and_u(a: Self::I, b: Self::I) -> Self::I;
    unsafe fn store_u(p: *mut u32, v: Self::I);
    /// `(E[row, 0], E[row, 1])` of each lane's row of a two-column table.
    ///
    /// # Safety
    /// Every lane's row must be a row of `emb` (`2·row + 1 < emb.len()`).
    unsafe fn gather_pairs(emb: &[f32], rows: Self::I) -> (Self::F, Self::F);
    /// `(x_j, y_j)` of every lane `j`, as `N` consecutive pairs from `out`.
    unsafe fn interleave(x: Self::F, y: Self::F, out: *mut f32);
}

/// 512-bit vectors (AVX-512F).
#[derive(Clone, Copy)]
pub(crate) struct Avx512;

/// 256-bit vectors (AVX2 + FMA).
#[derive(Clone, Copy)]
pub(crate) struct Avx2;

fn first_mask16(n: usize) -> u16 {
    ((1u32 << n) - 1) as u16
}

impl Lanes for Avx512 {
    const N: usize = 16;
    type F = __m512;
    type I = __m512i;
    #[inline(always)]
    unsafe fn splat(v: f32) -> __m512 {
        _mm512_set1_ps(v)
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> __m512 {
        unsafe { _mm512_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m512) {
        unsafe { _mm512_storeu_ps(p, v) }
    }
    #[inline(always)]
    unsafe fn load_first(p: *const f32, n: usize) -> __m512 {
        unsafe { _mm512_maskz_loadu_ps(first_mask16(n), p) }
    }
    #[inline(always)]
    unsafe fn store_first(p: *mut f32, v: __m512, n: usize) {
        unsafe { _mm512_mask_storeu_ps(p, first_mask16(n), v) }
    }
    #[inline(always)]
    unsafe fn add(a: __m512, b: __m512) -> __m512 {
        _mm512_add_ps(a, b)
    }
    #[inline(always)]
    unsafe fn sub(a: __m512, b: __m512) -> __m512 {
        _mm512_sub_ps(a, b)
    }
    #[inline(always)]
    unsafe fn mul(a: __m512, b: __m512) -> __m512 {
        _mm512_mul_ps(a, b)
    }
    #[inline(always)]
    unsafe fn fmadd(a: __m512, b: __m512, c: __m512) -> __m512 {
        _mm512_fmadd_ps(a, b, c)
    }
    #[inline(always)]
    unsafe fn negate(x: __m512) -> __m512 {
        _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(x), _mm512_set1_epi32(i32::MIN)))
    }
    #[inline(always)]
    unsafe fn clamp_unit(x: __m512) -> __m512 {
        // `max` returns its second operand for a NaN lane.
        _mm512_min_ps(_mm512_max_ps(x, _mm512_setzero_ps()), _mm512_set1_ps(1.0))
    }
    #[inline(always)]
    unsafe fn trunc(x: __m512) -> __m512i {
        _mm512_cvttps_epu32(x)
    }
    #[inline(always)]
    unsafe fn float(i: __m512i) -> __m512 {
        _mm512_cvtepu32_ps(i)
    }
    #[inline(always)]
    unsafe fn nan_from(v: __m512, x: __m512) -> __m512 {
        _mm512_mask_mov_ps(v, _mm512_cmp_ps_mask::<_CMP_UNORD_Q>(x, x), x)
    }
    #[inline(always)]
    unsafe fn where_unit(x: __m512, s: f32) -> __m512 {
        let inside = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(x, _mm512_setzero_ps())
            & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(x, _mm512_set1_ps(1.0));
        _mm512_maskz_mov_ps(inside, _mm512_set1_ps(s))
    }
    #[inline(always)]
    unsafe fn splat_u(v: u32) -> __m512i {
        _mm512_set1_epi32(v as i32)
    }
    #[inline(always)]
    unsafe fn add_u(a: __m512i, b: __m512i) -> __m512i {
        _mm512_add_epi32(a, b)
    }
    #[inline(always)]
    unsafe fn mul_u(a: __m512i, b: __m512i) -> __m512i {
        _mm512_mullo_epi32(a, b)
    }
    #[inline(always)]
    unsafe fn xor_u(a: __m512i, b: __m512i) -> __m512i {
        _mm512_xor_si512(a, b)
    }
    #[inline(always)]
    unsafe fn and_u(a: __m512i, b: __m512i) -> __m512i {
        _mm512_and_si512(a, b)
    }
    #[inline(always)]
    unsafe fn store_u(p: *mut u32, v: __m512i) {
        unsafe { _mm512_storeu_si512(p as *mut __m512i, v) }
    }
    #[inline(always)]
    unsafe fn gather_pairs(emb: &[f32], rows: __m512i) -> (__m512, __m512) {
        debug_assert!(emb.len().is_multiple_of(2));
        let base = emb.as_ptr() as *const f64;
        // SAFETY: the caller's rows index pairs of `emb`; the pointer is only read through them.
        let (lo, hi) = unsafe {
            (
                _mm512_i32gather_pd::<8>(_mm512_castsi512_si256(rows), base),
                _mm512_i32gather_pd::<8>(_mm512_extracti64x4_epi64::<1>(rows), base),
            )
        };
        let (lo, hi) = (_mm512_castpd_ps(lo), _mm512_castpd_ps(hi));
        let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
        (_mm512_permutex2var_ps(lo, even, hi), _mm512_permutex2var_ps(lo, odd, hi))
    }
    #[inline(always)]
    unsafe fn interleave(x: __m512, y: __m512, out: *mut f32) {
        let first = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
        let second = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
        // SAFETY: the caller's `out` holds 2·16 floats.
        unsafe {
            _mm512_storeu_ps(out, _mm512_permutex2var_ps(x, first, y));
            _mm512_storeu_ps(out.add(16), _mm512_permutex2var_ps(x, second, y));
        }
    }
}

impl Lanes for Avx2 {
    const N: usize = 8;
    type F = __m256;
    type I = __m256i;
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
    unsafe fn fmadd(a: __m256, b: __m256, c: __m256) -> __m256 {
        _mm256_fmadd_ps(a, b, c)
    }
    #[inline(always)]
    unsafe fn negate(x: __m256) -> __m256 {
        _mm256_xor_ps(x, _mm256_set1_ps(-0.0))
    }
    #[inline(always)]
    unsafe fn clamp_unit(x: __m256) -> __m256 {
        // `max` returns its second operand for a NaN lane.
        _mm256_min_ps(_mm256_max_ps(x, _mm256_setzero_ps()), _mm256_set1_ps(1.0))
    }
    #[inline(always)]
    unsafe fn trunc(x: __m256) -> __m256i {
        // The lanes are below 2³¹, where the signed conversion is the unsigned one.
        _mm256_cvttps_epi32(x)
    }
    #[inline(always)]
    unsafe fn float(i: __m256i) -> __m256 {
        _mm256_cvtepi32_ps(i)
    }
    #[inline(always)]
    unsafe fn nan_from(v: __m256, x: __m256) -> __m256 {
        _mm256_blendv_ps(v, x, _mm256_cmp_ps::<_CMP_UNORD_Q>(x, x))
    }
    #[inline(always)]
    unsafe fn where_unit(x: __m256, s: f32) -> __m256 {
        let inside = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(x, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_LE_OQ>(x, _mm256_set1_ps(1.0)),
        );
        _mm256_and_ps(inside, _mm256_set1_ps(s))
    }
    #[inline(always)]
    unsafe fn splat_u(v: u32) -> __m256i {
        _mm256_set1_epi32(v as i32)
    }
    #[inline(always)]
    unsafe fn add_u(a: __m256i, b: __m256i) -> __m256i {
        _mm256_add_epi32(a, b)
    }
    #[inline(always)]
    unsafe fn mul_u(a: __m256i, b: __m256i) -> __m256i {
        _mm256_mullo_epi32(a, b)
    }
    #[inline(always)]
    unsafe fn xor_u(a: __m256i, b: __m256i) -> __m256i {
        _mm256_xor_si256(a, b)
    }
    #[inline(always)]
    unsafe fn and_u(a: __m256i, b: __m256i) -> __m256i {
        _mm256_and_si256(a, b)
    }
    #[inline(always)]
    unsafe fn store_u(p: *mut u32, v: __m256i) {
        unsafe { _mm256_storeu_si256(p as *mut __m256i, v) }
    }
    #[inline(always)]
    unsafe fn gather_pairs(emb: &[f32], rows: __m256i) -> (__m256, __m256) {
        debug_assert!(emb.len().is_multiple_of(2));
        let base = emb.as_ptr() as *const f64;
        // Eight 64-bit loads: on AMD Zen 3 `vgatherdpd` costs more than the loads and inserts
        // it stands for.
        let mut r = [0u32; 8];
        // SAFETY: `r` holds 8 lanes; the caller's rows index pairs of `emb`.
        let (lo, hi) = unsafe {
            _mm256_storeu_si256(r.as_mut_ptr() as *mut __m256i, rows);
            let pair = |j: usize| _mm_load_sd(base.add(r[j] as usize));
            let two = |j: usize| _mm_loadh_pd(pair(j), base.add(r[j + 1] as usize));
            (
                _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(two(0)), two(2)),
                _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(two(4)), two(6)),
            )
        };
        // lo = a0 b0 a1 b1 | a2 b2 a3 b3, hi = a4 b4 a5 b5 | a6 b6 a7 b7: within each half,
        // the even (odd) floats of lo then hi give a0 a1 a4 a5 | a2 a3 a6 a7, whose 64-bit
        // quarters in the order 0, 2, 1, 3 are a0 … a7.
        let (lo, hi) = (_mm256_castpd_ps(lo), _mm256_castpd_ps(hi));
        let order = |v: __m256| _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
        (order(_mm256_shuffle_ps::<0b10_00_10_00>(lo, hi)), order(_mm256_shuffle_ps::<0b11_01_11_01>(lo, hi)))
    }
    #[inline(always)]
    unsafe fn interleave(x: __m256, y: __m256, out: *mut f32) {
        // x0 y0 x1 y1 | x4 y4 x5 y5 and x2 y2 x3 y3 | x6 y6 x7 y7, halves reordered.
        let (lo, hi) = (_mm256_unpacklo_ps(x, y), _mm256_unpackhi_ps(x, y));
        // SAFETY: the caller's `out` holds 2·8 floats.
        unsafe {
            _mm256_storeu_ps(out, _mm256_permute2f128_ps::<0x20>(lo, hi));
            _mm256_storeu_ps(out.add(8), _mm256_permute2f128_ps::<0x31>(lo, hi));
        }
    }
}

/// The mask of `maskload`/`maskstore` that selects the first `n` of 8 lanes.
#[inline(always)]
unsafe fn first_mask8(n: usize) -> __m256i {
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    _mm256_cmpgt_epi32(_mm256_set1_epi32(n as i32), lane)
}
