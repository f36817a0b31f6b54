//! Building a field: GA's splatted per-ray σ̂², BLA's linearised posterior variance, an
//! ensemble's spread.

use std::time::Instant;

use nerfsv_collision::GridGeometry;
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use rayon::prelude::*;

use super::grid::{cell_of, field_geometry, node_positions};
use super::posterior::{data_term, density_param_count, DensityPosterior};
use super::types::{
    empty_density, model_id, summarise, FieldFigures, FieldMethod, NodeValues, TrainingView, UncertaintyField,
};
use crate::ga::{ga_fit_samples, GaRay};
use crate::{UqConfig, UqError};

/// Nodes per batch of the BLA variances (their gradients are `n × P` floats).
const NODE_BATCH: usize = 2048;

impl UncertaintyField {
    /// The GA field of `nerf` from its training `views` (see the [module docs](super)); images
    /// whose rays all miss the model are skipped. `checkpoint` names the model in messages.
    /// Errors: a bad config, references that do not match the cameras, or no image with a
    /// sample.
    pub fn build_ga(
        nerf: &Nerf,
        checkpoint: &str,
        views: &[TrainingView],
        background: [f32; 3],
        cfg: &UqConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, UqError> {
        cfg.validate().map_err(|e| e.within("uq"))?;
        let start = Instant::now();
        let geometry = field_geometry(nerf, cfg.field_cells_per_metre)?;
        let density = nerf.density(&node_positions(&geometry));
        let mut num = vec![0.0f64; geometry.len()];
        let mut den = vec![0.0f64; geometry.len()];
        let (mut images, mut n_rays) = (0, 0);
        for (v, view) in views.iter().enumerate() {
            progress(v, views.len());
            let rays = camera_rays(view.camera, background);
            let samples = nerf.render_rays_samples(&rays);
            let fit = match ga_fit_samples(view.name, &rays, &samples, view.reference, cfg.ga_sigma_max, cfg.noise_std)
            {
                Ok(f) => f,
                Err(UqError::AllRaysMiss { .. }) => continue,
                Err(e) => return Err(e),
            };
            images += 1;
            for (i, ray) in rays.iter().enumerate() {
                let (c, w) = samples.ray(i);
                let g = GaRay::from_samples(c, w, view.reference[i], ray.background);
                let (mut sum, mut terms) = (0.0f64, 0);
                for ch in 0..3 {
                    if g.s[ch] > 0.0 {
                        let e = g.r[ch] - fit.mu_d * g.m[ch];
                        sum += e * e / g.s[ch];
                        terms += 1;
                    }
                }
                if terms == 0 {
                    continue;
                }
                n_rays += 1;
                let var = sum / terms as f64;
                for (&wi, &t) in w.iter().zip(samples.ray_distances(i)) {
                    let x = [0, 1, 2].map(|a| ray.origin[a] + t * ray.direction[a]);
                    if let Some((idx, b)) = cell_of(&geometry, x) {
                        for c in 0..8 {
                            let wb = wi as f64 * b[c] as f64;
                            num[idx[c]] += wb * var;
                            den[idx[c]] += wb;
                        }
                    }
                }
            }
        }
        progress(views.len(), views.len());
        if images == 0 {
            return Err(UqError::AllRaysMiss { image: "every training image".into(), rays: views.len() });
        }
        let variance: Vec<f32> =
            num.iter().zip(&den).map(|(&n, &d)| if d > 0.0 { (n / d) as f32 } else { 0.0 }).collect();
        let weight: Vec<f32> = den.iter().map(|&d| d as f32).collect();
        let figures = FieldFigures { images, rays: n_rays, ..Default::default() };
        Self::finish(nerf, checkpoint, FieldMethod::Ga, geometry, [density, variance, weight], figures, start)
    }

    /// The field of `nerf` from its arrays, with the figures summarised and timed from `start`.
    fn finish(
        nerf: &Nerf,
        checkpoint: &str,
        method: FieldMethod,
        geometry: GridGeometry,
        [density, variance, weight]: [Vec<f32>; 3],
        mut figures: FieldFigures,
        start: Instant,
    ) -> Result<Self, UqError> {
        summarise(&variance, &weight, &mut figures);
        figures.seconds = start.elapsed().as_secs_f64();
        let mut field = Self::from_parts(
            method,
            geometry,
            NodeValues { density, variance, weight },
            model_id(nerf),
            checkpoint.into(),
            figures,
        )?;
        field.set_empty_density(empty_density(nerf));
        Ok(field)
    }

    /// The BLA field of `nerf` from its training `views` (cameras only; see the
    /// [module docs](super)), at rank [`UqConfig::field_rank`] (clamped to `m`).
    pub fn build_bla(
        nerf: &Nerf,
        checkpoint: &str,
        views: &[TrainingView],
        background: [f32; 3],
        cfg: &UqConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, UqError> {
        cfg.validate().map_err(|e| e.within("uq"))?;
        let start = Instant::now();
        let geometry = field_geometry(nerf, cfg.field_cells_per_metre)?;
        let (d, images, n_rays) = data_term(nerf, views, background, cfg, progress);
        if images == 0 {
            return Err(UqError::AllRaysMiss { image: "every training image".into(), rays: views.len() });
        }
        let m = density_param_count(nerf);
        let posterior = DensityPosterior::new(&d, m, cfg.prior_precision)?;
        drop(d);
        let posterior_seconds = start.elapsed().as_secs_f64();
        let rank = cfg.field_rank.min(m);
        let p = nerf.field.sigma_net_range().len();
        let positions = node_positions(&geometry);
        let mut density = Vec::with_capacity(positions.len());
        let mut variance = Vec::with_capacity(positions.len());
        for batch in positions.chunks(NODE_BATCH) {
            let (s, g) = nerf.density_param_gradients(batch);
            density.extend_from_slice(&s);
            variance.extend(posterior.variances(&g, p, rank).into_iter().map(|v| v as f32));
        }
        let weight = vec![1.0f32; geometry.len()];
        let figures = FieldFigures {
            images,
            rays: n_rays,
            rank: Some(rank),
            density_params: Some(m),
            eigenvalue_mass_kept: Some(posterior.mass_kept(rank)),
            posterior_seconds: Some(posterior_seconds),
            ..Default::default()
        };
        Self::finish(nerf, checkpoint, FieldMethod::Bla, geometry, [density, variance, weight], figures, start)
    }

    /// The ensemble's field: at every node the deployed model's (`members[0]`'s) density and the
    /// population variance of the members' densities, `Var_k[σ_k(x)]` (1/m²), the spread of the
    /// density at points (Sünderhauf et al.'s termination variance, before compositing). Lookups
    /// and maps treat it as BLA's: relative to the deployed density, propagated per sample.
    /// Errors: fewer than two members, or a member whose box is not the deployed model's.
    pub fn build_ensemble(members: &[&Nerf], checkpoint: &str, cfg: &UqConfig) -> Result<Self, UqError> {
        cfg.validate().map_err(|e| e.within("uq"))?;
        let start = Instant::now();
        let Some((&deployed, others)) = members.split_first().filter(|(_, o)| !o.is_empty()) else {
            return Err(UqError::FieldGrid {
                message: format!("an ensemble field needs at least two members, got {}", members.len()),
            });
        };
        let aabb = |n: &Nerf| (n.config.aabb_min, n.config.aabb_max);
        if let Some(k) = others.iter().position(|m| aabb(m) != aabb(deployed)) {
            return Err(UqError::FieldGrid {
                message: format!(
                    "member {} has the box {:?}, the deployed model {:?}",
                    k + 1,
                    aabb(others[k]),
                    aabb(deployed)
                ),
            });
        }
        let geometry = field_geometry(deployed, cfg.field_cells_per_metre)?;
        let positions = node_positions(&geometry);
        let densities: Vec<Vec<f32>> = members.par_iter().map(|m| m.density(&positions)).collect();
        let k = members.len() as f64;
        let variance: Vec<f32> = (0..positions.len())
            .map(|n| {
                let mean = densities.iter().map(|d| f64::from(d[n])).sum::<f64>() / k;
                (densities.iter().map(|d| (f64::from(d[n]) - mean).powi(2)).sum::<f64>() / k) as f32
            })
            .collect();
        let density = densities.into_iter().next().unwrap_or_default();
        let weight = vec![1.0f32; geometry.len()];
        let figures = FieldFigures::default();
        Self::finish(deployed, checkpoint, FieldMethod::Ensemble, geometry, [density, variance, weight], figures, start)
    }
}
