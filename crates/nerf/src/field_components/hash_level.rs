//! One level of the multiresolution hash encoding and the one computation of a point's cell
//! corners on it (table rows and trilinear weights), shared by the scalar code
//! ([`super::hash_encoding`]) and the vector kernels.

/// Geometry of one level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Level {
    pub scale: f32,
    /// Grid vertices per axis.
    pub resolution: u32,
    /// Rows of the embedding table owned by this level.
    pub size: u32,
    /// First row of this level in the embedding table.
    pub offset: u32,
    pub dense: bool,
}

/// The 8 corner rows (absolute, including the level offset) and trilinear weights of `x`.
#[inline(always)]
pub fn corners(lv: &Level, x: [f32; 3]) -> ([u32; 8], [f32; 8]) {
    let (idx, f) = corners_frac(lv, x);
    let mut w = [0f32; 8];
    for (c, wc) in w.iter_mut().enumerate() {
        let wx = if c & 1 == 1 { f[0] } else { 1.0 - f[0] };
        let wy = if (c >> 1) & 1 == 1 { f[1] } else { 1.0 - f[1] };
        let wz = if (c >> 2) & 1 == 1 { f[2] } else { 1.0 - f[2] };
        *wc = wx * wy * wz;
    }
    (idx, w)
}

/// The 8 corner rows of `x` (corner `c` is `+ (c & 1, c >> 1 & 1, c >> 2 & 1)`) and the
/// fractional position `frac ∈ [0,1)³` inside the cell. The one corner-index computation shared
/// by the encoding's `encode`, `position_jacobian` and `backward_level`.
///
/// Bit-identical to the textbook `floor` / `h % size` form (`reference_corners_frac` in
/// `hash_encoding.rs`'s tests), but cheaper:
/// - `p = clamp(x, 0, 1)·s + 0.5 ≥ 0.5` (the scale `s = base·b^l − 1 ≥ 1`), so `floor(p)` is
///   the truncation `p as u32` (no libm `floorf` call) and `frac = p − (p as u32) as f32`. A NaN
///   coordinate gives cell 0 and a NaN fraction, as `floor` did.
/// - dense levels: the largest corner is `floor(s + 0.5) + 1 ≤ ceil(s) + 1 = r − 1`, so the
///   index is below `r³ ≤ size` and the modulo is the identity;
/// - hashed levels: the table size is `2^log2_table`, so `h % size = h & (size − 1)` (`%` is
///   kept for any other size).
#[inline(always)]
pub fn corners_frac(lv: &Level, x: [f32; 3]) -> ([u32; 8], [f32; 3]) {
    let mut g = [0u32; 3];
    let mut f = [0f32; 3];
    for d in 0..3 {
        let p = x[d].clamp(0.0, 1.0) * lv.scale + 0.5;
        let i = p as u32;
        g[d] = i;
        f[d] = p - i as f32;
    }
    let mut idx = [0u32; 8];
    let corner = |c: usize| [0, 1, 2].map(|d| g[d] + ((c >> d) & 1) as u32);
    if lv.dense {
        let r = lv.resolution;
        for (c, ic) in idx.iter_mut().enumerate() {
            let [i, j, k] = corner(c);
            let h = i.wrapping_add(j.wrapping_mul(r)).wrapping_add(k.wrapping_mul(r * r));
            debug_assert!(h < lv.size);
            *ic = lv.offset + h;
        }
    } else {
        let hash = |c: usize| {
            let [i, j, k] = corner(c);
            i ^ j.wrapping_mul(2_654_435_761) ^ k.wrapping_mul(805_459_861)
        };
        if lv.size.is_power_of_two() {
            let mask = lv.size - 1;
            for (c, ic) in idx.iter_mut().enumerate() {
                *ic = lv.offset + (hash(c) & mask);
            }
        } else {
            for (c, ic) in idx.iter_mut().enumerate() {
                *ic = lv.offset + hash(c) % lv.size;
            }
        }
    }
    (idx, f)
}
