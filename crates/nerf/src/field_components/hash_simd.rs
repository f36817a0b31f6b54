//! The hash encoding's vector kernels: a vector of points (16 on AVX-512, 8 on AVX2) of one
//! level at a time, written once over [`Lanes`].
//!
//! The scalar code ([`super::hash_encoding`]) computes each point's cell, fraction, eight corner
//! rows and weights one lane at a time and then loads the table values one by one; here the cell
//! arithmetic runs on all lanes and each corner's two features of the lanes come in 64-bit
//! gathers. Every floating-point operation is the scalar code's, in its order and without
//! contraction (a multiply and an add stay two roundings), so the results are the scalar
//! functions' bit for bit; the tests in `hash_encoding.rs` check that at every width the host
//! has, on every level kind, on the edge cases of [`super::hash_level::corners_frac`] and on
//! batches whose length is not a multiple of the lanes.

use crate::simd::{Lanes, MAX_LANES};

use super::hash_level::Level;

/// A vector of points' box coordinates, one vector per axis; lanes past `n` repeat 0.5 (a point
/// inside every level's grid, so its gathers stay inside the table) and are never stored.
#[inline(always)]
pub(crate) unsafe fn load_points<L: Lanes>(pos: &[f32], i0: usize, n: usize) -> [L::F; 3] {
    let mut soa = [[0.5f32; MAX_LANES]; 3];
    for j in 0..n.min(L::N) {
        for (d, axis) in soa.iter_mut().enumerate() {
            axis[j] = pos[3 * (i0 + j) + d];
        }
    }
    // SAFETY: each array holds at least N floats. (Loops, not closures, here and below: a
    // closure is a function of its own without the entry point's target features, and the
    // intrinsics it calls stay out-of-line calls.)
    unsafe { [L::load(soa[0].as_ptr()), L::load(soa[1].as_ptr()), L::load(soa[2].as_ptr())] }
}

/// One level's cells of a vector of points: the eight corner rows (absolute, with the level's
/// offset; corner `c` is `+ (c & 1, c >> 1 & 1, c >> 2 & 1)`) and the fractions per axis, as
/// [`super::hash_level::corners_frac`] computes them lane by lane. A hashed level's size must
/// be a power of two (its modulo is a mask here; the callers check).
#[inline(always)]
pub(crate) unsafe fn cells<L: Lanes>(lv: &Level, x: &[L::F; 3]) -> ([L::I; 8], [L::F; 3]) {
    debug_assert!(lv.dense || lv.size.is_power_of_two(), "a hashed level of {} rows", lv.size);
    unsafe {
        let (scale, half) = (L::splat(lv.scale), L::splat(0.5));
        let mut g = [L::splat_u(0); 3];
        let mut f = [L::splat(0.0); 3];
        for d in 0..3 {
            // A NaN lane is clamped to 0 (cell 0, as `NaN as u32` is) and gets its NaN
            // fraction back below.
            let p = L::add(L::mul(L::clamp_unit(x[d]), scale), half);
            let i = L::trunc(p);
            g[d] = i;
            f[d] = L::nan_from(L::sub(p, L::float(i)), x[d]);
        }
        let one = L::splat_u(1);
        let offset = L::splat_u(lv.offset);
        let mut idx = [L::splat_u(0); 8];
        // Dense: i + j·r + k·r²; hashed: i ⊕ j·π₂ ⊕ k·π₃ masked to the table (wrapping
        // products; (j + 1)·m = j·m + m).
        let (my, mz) = if lv.dense {
            (lv.resolution, lv.resolution.wrapping_mul(lv.resolution))
        } else {
            (2_654_435_761u32, 805_459_861u32)
        };
        let xs = [g[0], L::add_u(g[0], one)];
        let y0 = L::mul_u(g[1], L::splat_u(my));
        let ys = [y0, L::add_u(y0, L::splat_u(my))];
        let z0 = L::mul_u(g[2], L::splat_u(mz));
        let zs = [z0, L::add_u(z0, L::splat_u(mz))];
        if lv.dense {
            for (c, ic) in idx.iter_mut().enumerate() {
                let h = L::add_u(L::add_u(xs[c & 1], ys[(c >> 1) & 1]), zs[(c >> 2) & 1]);
                *ic = L::add_u(offset, h);
            }
        } else {
            let mask = L::splat_u(lv.size - 1);
            for (c, ic) in idx.iter_mut().enumerate() {
                let h = L::xor_u(L::xor_u(xs[c & 1], ys[(c >> 1) & 1]), zs[(c >> 2) & 1]);
                *ic = L::add_u(offset, L::and_u(h, mask));
            }
        }
        (idx, f)
    }
}

/// A vector of points' outputs written to their rows: point `j < m`'s row is
/// `out[j·stride..]`, and gets `cols[t][0][j], cols[t][1][j]` at `2t, 2t + 1` for every pair
/// `t`. The pairs are interleaved in registers and each point's row is written with 64-bit
/// stores (a loop over points and columns of a lanes array was compiled into a masked gather
/// and store per point, the kernels' largest cost).
#[inline(always)]
pub(crate) unsafe fn store_rows<L: Lanes, const P: usize>(
    cols: &[[L::F; 2]; P],
    m: usize,
    out: &mut [f32],
    stride: usize,
) {
    let mut pairs = [[0u64; MAX_LANES]; P];
    for ([x, y], p) in cols.iter().zip(&mut pairs) {
        // SAFETY: `p` holds 16 × 8 bytes, at least N pairs of floats.
        unsafe { L::interleave(*x, *y, p.as_mut_ptr() as *mut f32) };
    }
    for j in 0..m.min(L::N) {
        let row = &mut out[j * stride..j * stride + 2 * P];
        for (t, p) in pairs.iter().enumerate() {
            // SAFETY: `row` holds 2·P floats; the store is unaligned.
            unsafe { std::ptr::write_unaligned(row.as_mut_ptr().add(2 * t) as *mut u64, p[j]) };
        }
    }
}

/// Each axis's two corner factors `[1 − f, f]`.
#[inline(always)]
unsafe fn corner_factors<L: Lanes>(f: &[L::F; 3]) -> [[L::F; 2]; 3] {
    unsafe {
        let one = L::splat(1.0);
        [[L::sub(one, f[0]), f[0]], [L::sub(one, f[1]), f[1]], [L::sub(one, f[2]), f[2]]]
    }
}

/// The trilinear weights `(wx·wy)·wz` of the eight corners.
#[inline(always)]
pub(crate) unsafe fn weights<L: Lanes>(f: &[L::F; 3]) -> [L::F; 8] {
    unsafe {
        let w = corner_factors::<L>(f);
        let mut out = [L::splat(0.0); 8];
        for (c, o) in out.iter_mut().enumerate() {
            *o = L::mul(L::mul(w[0][c & 1], w[1][(c >> 1) & 1]), w[2][(c >> 2) & 1]);
        }
        out
    }
}

/// One level's encoding `(y₀, y₁)` of a vector of points: `Σ_c w_c·E[row_c]` from 0, corner by
/// corner.
///
/// # Safety
/// `idx` must come from [`cells`] on a level of the encoding that owns `emb`.
#[inline(always)]
pub(crate) unsafe fn encode_level<L: Lanes>(emb: &[f32], idx: &[L::I; 8], f: &[L::F; 3]) -> (L::F, L::F) {
    unsafe {
        let w = weights::<L>(f);
        let (mut a, mut b) = (L::splat(0.0), L::splat(0.0));
        for c in 0..8 {
            let (ea, eb) = L::gather_pairs(emb, idx[c]);
            a = L::add(a, L::mul(w[c], ea));
            b = L::add(b, L::mul(w[c], eb));
        }
        (a, b)
    }
}

/// One level's position Jacobian of a vector of points: `[feature][axis]`, each
/// `g_d · Σ_c (±Π_{d'≠d} w_{d'})·E[row_c, feature]` in the scalar code's order, where `g_d` is
/// the level's scale inside the box and 0 along an axis where the point is outside.
///
/// # Safety
/// As [`encode_level`].
#[inline(always)]
pub(crate) unsafe fn jacobian_level<L: Lanes>(
    emb: &[f32],
    scale: f32,
    x: &[L::F; 3],
    idx: &[L::I; 8],
    f: &[L::F; 3],
) -> [[L::F; 3]; 2] {
    unsafe {
        let zero = L::splat(0.0);
        let w = corner_factors::<L>(f);
        let mut ja = [zero; 3];
        let mut jb = [zero; 3];
        for (c, &rows) in idx.iter().enumerate() {
            let up = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let wd = [w[0][up[0]], w[1][up[1]], w[2][up[2]]];
            // (±1 · w_a) · w_b: the product with −1 is the sign bit flipped.
            let mut a = [wd[1], wd[0], wd[0]];
            for d in 0..3 {
                if up[d] == 0 {
                    a[d] = L::negate(a[d]);
                }
            }
            let dw = [L::mul(a[0], wd[2]), L::mul(a[1], wd[2]), L::mul(a[2], wd[1])];
            let (ea, eb) = L::gather_pairs(emb, rows);
            for d in 0..3 {
                ja[d] = L::add(ja[d], L::mul(dw[d], ea));
                jb[d] = L::add(jb[d], L::mul(dw[d], eb));
            }
        }
        let mut out = [[zero; 3]; 2];
        for d in 0..3 {
            let g = L::where_unit(x[d], scale);
            out[0][d] = L::mul(g, ja[d]);
            out[1][d] = L::mul(g, jb[d]);
        }
        out
    }
}

/// The corner rows and weights of points `i0 .. i0 + m` (`m ≤ N`) of one level, per point.
#[inline(always)]
pub(crate) unsafe fn block_corners<L: Lanes>(
    lv: &Level,
    positions: &[f32],
    i0: usize,
    m: usize,
) -> ([[u32; 8]; MAX_LANES], [[f32; 8]; MAX_LANES]) {
    unsafe {
        let x = load_points::<L>(positions, i0, m);
        let (idx, f) = cells::<L>(lv, &x);
        let w = weights::<L>(&f);
        let (mut vi, mut vw) = ([[0u32; MAX_LANES]; 8], [[0f32; MAX_LANES]; 8]);
        for c in 0..8 {
            L::store_u(vi[c].as_mut_ptr(), idx[c]);
            L::store(vw[c].as_mut_ptr(), w[c]);
        }
        (
            std::array::from_fn(|j| std::array::from_fn(|c| vi[c][j])),
            std::array::from_fn(|j| std::array::from_fn(|c| vw[c][j])),
        )
    }
}
