//! Exact squared Euclidean distance transform with feature transform (nearest site), after
//! Felzenszwalb & Huttenlocher, "Distance Transforms of Sampled Functions" (2012).
//!
//! In 1-D, `D(q) = min_p ((q − p)² + f(p))` is the lower envelope of parabolas rooted at each
//! `p`; it is found in O(n) by a stack of parabolas `v[..]` and their boundaries `z[..]` (alg. 1).
//! The 3-D transform is separable: one 1-D pass per axis, each on the previous pass's output.
//! Distances are in cell units and exact (integers ≤ 2²⁴ are exact in f32).
//!
//! Passes run in parallel over lines; the per-line scratch lives in a [`LineScratch`] made once
//! per rayon job, never per line. Pass order z, x, y lets every pass write contiguous chunks
//! without `unsafe`: the z pass writes a `[y][z][x]` buffer, the x pass works on its contiguous
//! rows in place, and the y pass writes the final `[z][y][x]` (x-fastest) layout.

use rayon::prelude::*;

/// No site: the nearest-site index for lines or grids without any site.
pub const NO_SITE: u32 = u32::MAX;

/// Reusable buffers for one 1-D transform of up to `n` samples.
pub struct LineScratch {
    f: Vec<f32>,
    d: Vec<f32>,
    arg: Vec<u32>,
    v: Vec<u32>,
    z: Vec<f64>,
    /// Per-line auxiliary buffer (nearest-site indices before a pass).
    aux: Vec<u32>,
}

impl LineScratch {
    pub fn new(n: usize) -> Self {
        Self { f: vec![0.0; n], d: vec![0.0; n], arg: vec![0; n], v: vec![0; n], z: vec![0.0; n + 1], aux: vec![0; n] }
    }
}

/// 1-D squared distance transform of the sampled function `f` (use `f32::INFINITY` for "no
/// site"): `d[q] = min_p ((q − p)² + f[p])` and `arg[q]` = the minimising `p`, or [`NO_SITE`]
/// (with `d[q] = ∞`) when every `f[p]` is infinite. `v` and `z` are scratch of length `n` and
/// `n + 1`.
pub fn squared_edt_1d(f: &[f32], d: &mut [f32], arg: &mut [u32], v: &mut [u32], z: &mut [f64]) {
    let n = f.len();
    debug_assert!(d.len() >= n && arg.len() >= n && v.len() >= n && z.len() > n);
    // Envelope construction; infinite samples contribute no parabola.
    let mut k = 0usize;
    let mut have = false;
    for q in 0..n {
        let fq = f[q] as f64;
        if !fq.is_finite() {
            continue;
        }
        if !have {
            v[0] = q as u32;
            z[0] = f64::NEG_INFINITY;
            z[1] = f64::INFINITY;
            have = true;
            continue;
        }
        let qf = q as f64;
        loop {
            let p = v[k] as f64;
            let fp = f[v[k] as usize] as f64;
            // Intersection of the parabolas rooted at q and at v[k].
            let s = ((fq + qf * qf) - (fp + p * p)) / (2.0 * (qf - p));
            if s <= z[k] {
                // z[0] = −∞, so k never underflows.
                k -= 1;
            } else {
                k += 1;
                v[k] = q as u32;
                z[k] = s;
                z[k + 1] = f64::INFINITY;
                break;
            }
        }
    }
    if !have {
        d[..n].fill(f32::INFINITY);
        arg[..n].fill(NO_SITE);
        return;
    }
    let mut k = 0usize;
    for q in 0..n {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k] as usize;
        let dq = q as f64 - p as f64;
        d[q] = (dq * dq + f[p] as f64) as f32;
        arg[q] = p as u32;
    }
}

impl LineScratch {
    /// Transform `self.f[..n]` into `self.d` / `self.arg`.
    fn run(&mut self, n: usize) {
        squared_edt_1d(&self.f[..n], &mut self.d, &mut self.arg, &mut self.v, &mut self.z);
    }
}

/// Result of [`feature_transform`]: per node (x-fastest), the squared distance in cell units to
/// the nearest site and that site's flat index ([`NO_SITE`] if the grid has no site).
pub struct FeatureTransform {
    pub squared: Vec<f32>,
    pub nearest: Vec<u32>,
}

/// Exact 3-D squared EDT and nearest site of the node set `sites` (`sites[i + nx·(j + ny·k)]`).
pub fn feature_transform(sites: &[bool], dims: [usize; 3]) -> FeatureTransform {
    let [nx, ny, nz] = dims;
    let n = nx * ny * nz;
    assert_eq!(sites.len(), n, "sites must have one entry per node");
    assert!(n < NO_SITE as usize, "grid too large for u32 site indices");
    let longest = nx.max(ny).max(nz);
    let scratch = || LineScratch::new(longest);

    // Pass z: mask → buffer B in [y][z][x] layout; chunk y holds nz rows of nx.
    let mut b_sq = vec![0f32; n];
    let mut b_near = vec![0u32; n];
    b_sq.par_chunks_mut(nz * nx).zip(b_near.par_chunks_mut(nz * nx)).enumerate().for_each_init(
        scratch,
        |s, (y, (sq, near))| {
            for x in 0..nx {
                for z in 0..nz {
                    s.f[z] = if sites[x + nx * (y + ny * z)] { 0.0 } else { f32::INFINITY };
                }
                s.run(nz);
                for z in 0..nz {
                    sq[z * nx + x] = s.d[z];
                    let a = s.arg[z];
                    near[z * nx + x] = if a == NO_SITE { NO_SITE } else { (x + nx * (y + ny * a as usize)) as u32 };
                }
            }
        },
    );

    // Pass x: contiguous rows of B, in place.
    b_sq.par_chunks_mut(nx).zip(b_near.par_chunks_mut(nx)).for_each_init(scratch, |s, (sq, near)| {
        s.f[..nx].copy_from_slice(sq);
        s.aux[..nx].copy_from_slice(near);
        s.run(nx);
        for x in 0..nx {
            sq[x] = s.d[x];
            let a = s.arg[x];
            near[x] = if a == NO_SITE { NO_SITE } else { s.aux[a as usize] };
        }
    });

    // Pass y: B → final x-fastest layout, one z-slice per job.
    let mut squared = vec![0f32; n];
    let mut nearest = vec![0u32; n];
    squared.par_chunks_mut(nx * ny).zip(nearest.par_chunks_mut(nx * ny)).enumerate().for_each_init(
        scratch,
        |s, (z, (sq, near))| {
            for x in 0..nx {
                for y in 0..ny {
                    let bi = (y * nz + z) * nx + x;
                    s.f[y] = b_sq[bi];
                    s.aux[y] = b_near[bi];
                }
                s.run(ny);
                for y in 0..ny {
                    sq[y * nx + x] = s.d[y];
                    let a = s.arg[y];
                    near[y * nx + x] = if a == NO_SITE { NO_SITE } else { s.aux[a as usize] };
                }
            }
        },
    );
    FeatureTransform { squared, nearest }
}

/// Exact 3-D squared EDT (cell units) of the node set `sites`; `∞` everywhere if there is none.
pub fn squared_edt(sites: &[bool], dims: [usize; 3]) -> Vec<f32> {
    feature_transform(sites, dims).squared
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    #[test]
    fn one_dimensional_transform_equals_brute_force_on_random_functions() {
        let mut rng = Rng::new(1);
        for n in [1usize, 2, 5, 17, 64] {
            let mut s = LineScratch::new(n);
            for _ in 0..50 {
                let f: Vec<f32> = (0..n)
                    .map(|_| if rng.uniform() < 0.6 { f32::INFINITY } else { (rng.uniform() * 40.0).floor() })
                    .collect();
                squared_edt_1d(&f, &mut s.d, &mut s.arg, &mut s.v, &mut s.z);
                for q in 0..n {
                    let brute = (0..n).map(|p| (q as f32 - p as f32).powi(2) + f[p]).fold(f32::INFINITY, f32::min);
                    assert_eq!(s.d[q], brute, "n={n} q={q} f={f:?}");
                    if brute.is_finite() {
                        let p = s.arg[q] as usize;
                        assert_eq!((q as f32 - p as f32).powi(2) + f[p], brute);
                    } else {
                        assert_eq!(s.arg[q], NO_SITE);
                    }
                }
            }
        }
    }

    #[test]
    fn three_dimensional_transform_equals_brute_force_on_random_occupancy() {
        let mut rng = Rng::new(2);
        for (dims, density) in [([7usize, 5, 6], 0.05f32), ([9, 11, 4], 0.2), ([3, 8, 13], 0.01)] {
            let n = dims.iter().product();
            let sites: Vec<bool> = (0..n).map(|_| rng.uniform() < density).collect();
            let ft = feature_transform(&sites, dims);
            let pos = |i: usize| [i % dims[0], (i / dims[0]) % dims[1], i / (dims[0] * dims[1])];
            for q in 0..n {
                let pq = pos(q);
                let d2 = |p: usize| {
                    let pp = pos(p);
                    (0..3).map(|a| (pq[a] as f32 - pp[a] as f32).powi(2)).sum::<f32>()
                };
                let brute = (0..n).filter(|&p| sites[p]).map(d2).fold(f32::INFINITY, f32::min);
                assert_eq!(ft.squared[q], brute, "dims {dims:?} node {q}");
                if brute.is_finite() {
                    let p = ft.nearest[q] as usize;
                    assert!(sites[p], "nearest of {q} is not a site");
                    assert_eq!(d2(p), brute);
                } else {
                    assert_eq!(ft.nearest[q], NO_SITE);
                }
            }
        }
    }
}
