//! Reading a field: values at points, the uncertainty of a view marched through the grid, and
//! per-pixel colour and depth maps.

use nalgebra::Point3;
use nerfsv_nerf::model_components::ray_samplers::ray_aabb;
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use nerfsv_scene::Camera;
use rayon::prelude::*;

use super::grid::{cell_of, interp, interp_masked};
use super::types::{FieldMethod, UncertaintyField, BLOCK, LOOKUP_MIN_TRANSMITTANCE};
use crate::maps::UncertaintyMaps;

/// Below this opacity a ray has no distance (as the renderer).
const MIN_OPACITY: f32 = 1e-6;

impl UncertaintyField {
    /// The looked-up value `v` at `p` (GA σ̂², BLA relative variance), `None` outside the grid
    /// or with no data around `p`.
    pub fn value_at(&self, p: Point3<f32>) -> Option<f32> {
        let (idx, w) = cell_of(&self.geometry, p.coords.into())?;
        interp_masked(&self.lookup, &idx, &w)
    }

    /// `(Σ_i w_i·v(x_i), Σ_i w_i)` of one ray marched through the grid (see the module docs):
    /// samples at `t0 + (n + ½)·Δt`, `Δt` half a cell; samples in empty cells add nothing, and
    /// empty blocks are jumped over to the first lattice sample past them.
    fn ray_sums(&self, o: [f32; 3], d: [f32; 3]) -> (f64, f64) {
        let g = &self.geometry;
        let b = g.bounds();
        let Some((t0, t1)) = ray_aabb(o, d, b.min.coords.into(), b.max.coords.into()) else {
            return (0.0, 0.0);
        };
        let step = 0.5 * g.cell;
        let block_side = g.cell * BLOCK as f32;
        let (mut num, mut den) = (0.0f64, 0.0f64);
        let mut trans = 1.0f32;
        let mut n = 0u32;
        loop {
            let t = t0 + (n as f32 + 0.5) * step;
            if t >= t1 || trans < LOOKUP_MIN_TRANSMITTANCE {
                break;
            }
            let x = [0, 1, 2].map(|a| o[a] + t * d[a]);
            let Some((idx, w)) = cell_of(g, x) else {
                n += 1;
                continue;
            };
            if self.cell_empty[idx[0]] {
                let [ci, cj, ck] = g.coords(idx[0]);
                let bi = [ci / BLOCK, cj / BLOCK, ck / BLOCK];
                if self.block_empty[bi[0] + self.blocks[0] * (bi[1] + self.blocks[1] * bi[2])] {
                    // Exit of the block's box along the ray, then the next lattice sample.
                    let mut t_exit = f32::INFINITY;
                    for a in 0..3 {
                        let lo = g.origin[a] + bi[a] as f32 * block_side;
                        let bound = if d[a] > 0.0 { lo + block_side } else { lo };
                        if d[a] != 0.0 {
                            t_exit = t_exit.min((bound - o[a]) / d[a]);
                        }
                    }
                    let next = ((t_exit - t0) / step - 0.5).ceil();
                    n = if next.is_finite() && next > n as f32 { next as u32 } else { n + 1 };
                } else {
                    n += 1;
                }
                continue;
            }
            let sigma = interp(&self.density, &idx, &w).max(0.0);
            let alpha = 1.0 - (-sigma * step).exp();
            let wi = trans * alpha;
            if let Some(v) = interp_masked(&self.lookup, &idx, &w) {
                num += wi as f64 * v as f64;
                den += wi as f64;
            }
            trans *= 1.0 - alpha;
            n += 1;
        }
        (num, den)
    }

    /// The uncertainty of a view from the grid alone: `√(Σ w·v / Σ w)` over the rays of
    /// `pixels` (`[column, row]`) of `camera`, in the units of GA's σ_d for both methods (see
    /// the [module docs](super)); 0 when no ray composites anything. The background does not
    /// change compositing weights; it is taken so that the call mirrors the exact mode's.
    /// Parallel over chunks of pixels, summed in a fixed order (the same value for any thread
    /// count).
    pub fn view_uncertainty(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> f64 {
        let _ = background;
        let sums: Vec<(f64, f64)> = pixels
            .par_chunks(64)
            .map(|chunk| {
                chunk.iter().fold((0.0, 0.0), |(n, d), &[i, j]| {
                    let r = camera.pixel_ray(i, j);
                    let (a, b) = self.ray_sums(r.origin.coords.into(), r.direction.into());
                    (n + a, d + b)
                })
            })
            .collect();
        let (num, den) = sums.iter().fold((0.0, 0.0), |(n, d), &(a, b)| (n + a, d + b));
        if den > 0.0 {
            (num / den).max(0.0).sqrt()
        } else {
            0.0
        }
    }

    /// Per-pixel colour and depth standard deviations of `camera` (see the
    /// [module docs](super)): samples rendered by `nerf` over `background`, uncertainty from the
    /// field at their positions. NaN where a ray has no sample (or, GA, no data on its samples);
    /// NaN depth where the opacity is ≤ 1e-6.
    pub fn maps(&self, nerf: &Nerf, camera: &Camera, background: [f32; 3]) -> UncertaintyMaps {
        let k = camera.intrinsics;
        let rays = camera_rays(camera, background);
        let samples = nerf.render_rays_samples(&rays);
        let delta = nerf.config.step_size;
        let (colour_std, depth_std): (Vec<f32>, Vec<f32>) = (0..rays.len())
            .into_par_iter()
            .map(|p| {
                let (c, w) = samples.ray(p);
                let ts = samples.ray_distances(p);
                if w.is_empty() {
                    return (f32::NAN, f32::NAN);
                }
                let ray = &rays[p];
                let at = |t: f32| Point3::from([0, 1, 2].map(|a| ray.origin[a] + t * ray.direction[a]));
                let opacity = samples.opacity[p];
                let z = camera.z_depth_factor((p as u32 % k.width) as f32 + 0.5, (p as u32 / k.width) as f32 + 0.5);
                let (var_c, var_d) = match self.method {
                    FieldMethod::Ga => {
                        // The ray's weighted mean stands in for samples without data.
                        let (mut sv, mut sw) = (0.0f64, 0.0f64);
                        for (&wi, &t) in w.iter().zip(ts) {
                            if let Some(v) = self.value_at(at(t)) {
                                sv += wi as f64 * v as f64;
                                sw += wi as f64;
                            }
                        }
                        if sw <= 0.0 {
                            return (f32::NAN, f32::NAN);
                        }
                        let fill = sv / sw;
                        let (mut vc, mut vd) = (0.0f64, 0.0f64);
                        for ((ci, &wi), &t) in c.iter().zip(w).zip(ts) {
                            let v = self.value_at(at(t)).map_or(fill, |v| v as f64);
                            let wi = wi as f64;
                            // Colours against the background, as GA's own maps.
                            let bg = ray.background;
                            vc += v * (0..3).map(|ch| ((ci[ch] - bg[ch]) as f64 * wi).powi(2)).sum::<f64>() / 3.0;
                            vd += v * (wi * t as f64).powi(2);
                        }
                        (vc, vd / (opacity as f64).powi(2))
                    }
                    FieldMethod::Bla | FieldMethod::Ensemble => {
                        let k_end = 1.0 - opacity as f64;
                        let colour = samples.rgb[p];
                        let dist = samples.distance[p] as f64;
                        let mut after = colour.map(|x| x as f64);
                        let mut d_after = dist * opacity as f64;
                        let mut trans = 1.0f64;
                        let (mut vc, mut vd) = (0.0f64, 0.0f64);
                        for ((ci, &wi), &t) in c.iter().zip(w).zip(ts) {
                            let wi = wi as f64;
                            let t_next = trans - wi;
                            let var = self.bla_variance_at(at(t)) as f64;
                            let mut g2 = 0.0;
                            for ch in 0..3 {
                                after[ch] -= wi * ci[ch] as f64;
                                let g = delta as f64 * (t_next * ci[ch] as f64 - after[ch]);
                                g2 += g * g;
                            }
                            vc += g2 / 3.0 * var;
                            d_after -= wi * t as f64;
                            if opacity > MIN_OPACITY {
                                let g = delta as f64 * (t_next * t as f64 - d_after - dist * k_end) / opacity as f64;
                                vd += g * g * var;
                            }
                            trans = t_next;
                        }
                        (vc, vd)
                    }
                };
                let depth = if opacity > MIN_OPACITY { (var_d.sqrt() * z as f64) as f32 } else { f32::NAN };
                (var_c.sqrt() as f32, depth)
            })
            .unzip();
        UncertaintyMaps { width: k.width, height: k.height, colour_std, depth_std }
    }

    /// BLA: `Var[σ]` at `p` (trilinear; 0 outside the grid).
    fn bla_variance_at(&self, p: Point3<f32>) -> f32 {
        cell_of(&self.geometry, p.coords.into()).map_or(0.0, |(idx, w)| interp(&self.variance, &idx, &w).max(0.0))
    }
}
