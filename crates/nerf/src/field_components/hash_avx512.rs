//! The hash encoding's kernels for hosts with AVX-512: sixteen points of one level at a time.
//!
//! The scalar code ([`super::hash_encoding`]) computes each point's cell, fraction, eight corner
//! rows and weights one lane at a time and then gathers sixteen table values with scalar loads;
//! here the cell arithmetic runs on sixteen lanes and each corner's two features of sixteen
//! points come in two 64-bit gathers. Every floating-point operation is the scalar code's, in
//! its order and without contraction (a multiply and an add stay two roundings), so the results
//! are the scalar functions' bit for bit; the tests in `hash_encoding.rs` check that on every
//! level kind, on the edge cases of [`super::hash_encoding::corners_frac`] and on batches whose
//! length is not a multiple of sixteen.

use std::arch::x86_64::*;

use super::hash_encoding::Level;

/// Points per kernel call.
pub(crate) const LANES: usize = 16;

/// Sixteen points' box coordinates, one vector per axis; lanes past `n` repeat 0.5 (a point
/// inside every level's grid, so its gathers stay inside the table) and are never stored.
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) fn load_points(pos: &[f32], i0: usize, n: usize) -> [__m512; 3] {
    let mut soa = [[0.5f32; LANES]; 3];
    for j in 0..n.min(LANES) {
        for (d, axis) in soa.iter_mut().enumerate() {
            axis[j] = pos[3 * (i0 + j) + d];
        }
    }
    // SAFETY: each array holds exactly 16 floats.
    soa.map(|axis| unsafe { _mm512_loadu_ps(axis.as_ptr()) })
}

/// One level's cells of sixteen points: the eight corner rows (absolute, with the level's
/// offset; corner `c` is `+ (c & 1, c >> 1 & 1, c >> 2 & 1)`) and the fractions per axis, as
/// [`super::hash_encoding::corners_frac`] computes them lane by lane. A hashed level's size must
/// be a power of two (its modulo is a mask here; the callers check).
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) fn cells(lv: &Level, x: &[__m512; 3]) -> ([__m512i; 8], [__m512; 3]) {
    debug_assert!(lv.dense || lv.size.is_power_of_two(), "a hashed level of {} rows", lv.size);
    let (zero, one, half) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0), _mm512_set1_ps(0.5));
    let scale = _mm512_set1_ps(lv.scale);
    let mut g = [_mm512_setzero_si512(); 3];
    let mut f = [zero; 3];
    for d in 0..3 {
        // `clamp(0, 1)`: `max` returns its second operand for a NaN lane, which becomes 0 here
        // (cell 0, as `NaN as u32` is) and gets its NaN fraction back below.
        let c = _mm512_min_ps(_mm512_max_ps(x[d], zero), one);
        let p = _mm512_add_ps(_mm512_mul_ps(c, scale), half);
        let i = _mm512_cvttps_epu32(p);
        let frac = _mm512_sub_ps(p, _mm512_cvtepu32_ps(i));
        let nan = _mm512_cmp_ps_mask::<_CMP_UNORD_Q>(x[d], x[d]);
        g[d] = i;
        f[d] = _mm512_mask_mov_ps(frac, nan, x[d]);
    }
    let one_i = _mm512_set1_epi32(1);
    let offset = _mm512_set1_epi32(lv.offset as i32);
    let mut idx = [_mm512_setzero_si512(); 8];
    if lv.dense {
        // i + j·r + k·r² (wrapping): (j + 1)·r = j·r + r and (k + 1)·r² = k·r² + r².
        let r = lv.resolution;
        let rr = r.wrapping_mul(r);
        let xs = [g[0], _mm512_add_epi32(g[0], one_i)];
        let y0 = _mm512_mullo_epi32(g[1], _mm512_set1_epi32(r as i32));
        let ys = [y0, _mm512_add_epi32(y0, _mm512_set1_epi32(r as i32))];
        let z0 = _mm512_mullo_epi32(g[2], _mm512_set1_epi32(rr as i32));
        let zs = [z0, _mm512_add_epi32(z0, _mm512_set1_epi32(rr as i32))];
        for (c, ic) in idx.iter_mut().enumerate() {
            let h = _mm512_add_epi32(_mm512_add_epi32(xs[c & 1], ys[(c >> 1) & 1]), zs[(c >> 2) & 1]);
            *ic = _mm512_add_epi32(offset, h);
        }
    } else {
        // i ⊕ j·π₂ ⊕ k·π₃ masked to the table (wrapping products, as above).
        let (p2, p3) = (2_654_435_761u32, 805_459_861u32);
        let xs = [g[0], _mm512_add_epi32(g[0], one_i)];
        let y0 = _mm512_mullo_epi32(g[1], _mm512_set1_epi32(p2 as i32));
        let ys = [y0, _mm512_add_epi32(y0, _mm512_set1_epi32(p2 as i32))];
        let z0 = _mm512_mullo_epi32(g[2], _mm512_set1_epi32(p3 as i32));
        let zs = [z0, _mm512_add_epi32(z0, _mm512_set1_epi32(p3 as i32))];
        let mask = _mm512_set1_epi32((lv.size - 1) as i32);
        for (c, ic) in idx.iter_mut().enumerate() {
            let h = _mm512_xor_si512(_mm512_xor_si512(xs[c & 1], ys[(c >> 1) & 1]), zs[(c >> 2) & 1]);
            *ic = _mm512_add_epi32(offset, _mm512_and_si512(h, mask));
        }
    }
    (idx, f)
}

/// Sixteen points' outputs written to their rows: point `j < m`'s row is
/// `out[j·stride..]`, and gets `cols[t][0][j], cols[t][1][j]` at `2t, 2t + 1` for every pair
/// `t`. The pairs are interleaved in registers and each point's row is written with 64-bit
/// stores (a loop over points and columns of a `[[f32; 16]; k]` array was compiled into a
/// masked gather and store per point, the kernels' largest cost).
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) fn store_rows<const P: usize>(cols: &[[__m512; 2]; P], m: usize, out: &mut [f32], stride: usize) {
    let first = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
    let second = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
    let mut pairs = [[0u64; LANES]; P];
    for ([x, y], p) in cols.iter().zip(&mut pairs) {
        let ptr = p.as_mut_ptr() as *mut f32;
        // SAFETY: `p` holds 16 × 8 bytes, two vectors of 16 floats.
        unsafe {
            _mm512_storeu_ps(ptr, _mm512_permutex2var_ps(*x, first, *y));
            _mm512_storeu_ps(ptr.add(LANES), _mm512_permutex2var_ps(*x, second, *y));
        }
    }
    for j in 0..m.min(LANES) {
        let row = &mut out[j * stride..j * stride + 2 * P];
        for (t, p) in pairs.iter().enumerate() {
            // SAFETY: `row` holds 2·P floats; the store is unaligned.
            unsafe { std::ptr::write_unaligned(row.as_mut_ptr().add(2 * t) as *mut u64, p[j]) };
        }
    }
}

/// The trilinear weights `(wx·wy)·wz` of the eight corners.
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) fn weights(f: &[__m512; 3]) -> [__m512; 8] {
    let one = _mm512_set1_ps(1.0);
    let w = f.map(|fd| [_mm512_sub_ps(one, fd), fd]);
    std::array::from_fn(|c| _mm512_mul_ps(_mm512_mul_ps(w[0][c & 1], w[1][(c >> 1) & 1]), w[2][(c >> 2) & 1]))
}

/// Both features of one corner row per lane: `(E[row, 0], E[row, 1])` of sixteen rows, in two
/// 64-bit gathers split into the two features.
///
/// # Safety
/// Every lane of `rows` must be a row of `emb` (`2·row + 1 < emb.len()`).
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) unsafe fn gather_pairs(emb: &[f32], rows: __m512i) -> (__m512, __m512) {
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

/// One level's encoding `(y₀, y₁)` of sixteen points: `Σ_c w_c·E[row_c]` from 0, corner by corner.
///
/// # Safety
/// `idx` must come from [`cells`] on a level of the encoding that owns `emb`.
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) unsafe fn encode_level(emb: &[f32], idx: &[__m512i; 8], f: &[__m512; 3]) -> (__m512, __m512) {
    let w = weights(f);
    let (mut a, mut b) = (_mm512_setzero_ps(), _mm512_setzero_ps());
    for c in 0..8 {
        // SAFETY: the caller's rows are rows of `emb`.
        let (ea, eb) = unsafe { gather_pairs(emb, idx[c]) };
        a = _mm512_add_ps(a, _mm512_mul_ps(w[c], ea));
        b = _mm512_add_ps(b, _mm512_mul_ps(w[c], eb));
    }
    (a, b)
}

/// One level's position Jacobian of sixteen points: `[feature][axis]`, each
/// `g_d · Σ_c (±Π_{d'≠d} w_{d'})·E[row_c, feature]` in the scalar code's order, where `g_d` is
/// the level's scale inside the box and 0 along an axis where the point is outside.
///
/// # Safety
/// As [`encode_level`].
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) unsafe fn jacobian_level(
    emb: &[f32],
    scale: f32,
    x: &[__m512; 3],
    idx: &[__m512i; 8],
    f: &[__m512; 3],
) -> [[__m512; 3]; 2] {
    let (zero, one) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0));
    let w = f.map(|fd| [_mm512_sub_ps(one, fd), fd]);
    let mut ja = [zero; 3];
    let mut jb = [zero; 3];
    for (c, &rows) in idx.iter().enumerate() {
        let up = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
        let wd = [0, 1, 2].map(|d| w[d][up[d]]);
        // (±1 · w_a) · w_b: the product with −1 is the sign bit flipped, zeros and NaNs included.
        let signed = |d: usize, v: __m512| if up[d] == 1 { v } else { negate(v) };
        let dw = [
            _mm512_mul_ps(signed(0, wd[1]), wd[2]),
            _mm512_mul_ps(signed(1, wd[0]), wd[2]),
            _mm512_mul_ps(signed(2, wd[0]), wd[1]),
        ];
        // SAFETY: the caller's rows are rows of `emb`.
        let (ea, eb) = unsafe { gather_pairs(emb, rows) };
        for d in 0..3 {
            ja[d] = _mm512_add_ps(ja[d], _mm512_mul_ps(dw[d], ea));
            jb[d] = _mm512_add_ps(jb[d], _mm512_mul_ps(dw[d], eb));
        }
    }
    let s = _mm512_set1_ps(scale);
    let g = x.map(|xd| {
        let inside = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(xd, zero) & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(xd, one);
        _mm512_maskz_mov_ps(inside, s)
    });
    [ja, jb].map(|j| std::array::from_fn(|d| _mm512_mul_ps(g[d], j[d])))
}

/// `−v` as `−1.0 · v` gives it: the sign bit flipped.
#[target_feature(enable = "avx512f")]
#[inline]
fn negate(v: __m512) -> __m512 {
    _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(v), _mm512_set1_epi32(i32::MIN)))
}
