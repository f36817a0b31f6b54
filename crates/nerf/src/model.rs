//! [`Nerf`]: configuration, parameters and occupancy grid of a trained (or training) model, and
//! the batched queries on it: densities at points, and rendering of rays.

use std::sync::Mutex;

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use crate::config::NerfConfig;
use crate::fields::{ChunkWorkspace, DensityWorkspace, NgpField, RayInput, RENDER_CHUNK};
use crate::model_components::occupancy_grid::OccupancyGrid;
use crate::model_components::ray_samplers::march_lattice;

/// Points per parallel task of density queries.
const DENSITY_CHUNK: usize = 4096;

/// A NeRF: config, the flat parameter vector (see [`crate::fields`] for its blocks) and the
/// occupancy grid.
#[derive(Clone, Debug)]
pub struct Nerf {
    pub config: NerfConfig,
    pub field: NgpField,
    /// `[field.n_params]` all parameters (torch-ngp tensors, concatenated).
    pub params: Vec<f32>,
    pub grid: OccupancyGrid,
    /// Training steps taken to reach these weights (0 for a fresh model).
    pub step: u64,
    /// Seed of the initial weights and of every random choice of training.
    pub seed: u64,
}

/// Per-ray outputs of [`Nerf::render_rays`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayOutputs {
    /// `[r, 3]` colour composited on each ray's background.
    pub rgb: Vec<f32>,
    /// `[r]` accumulated alpha.
    pub opacity: Vec<f32>,
    /// `[r]` expected ray distance `Σ w t / Σ w` in metres (0 where opacity is 0).
    pub distance: Vec<f32>,
    /// Total samples evaluated (density), and samples coloured (before termination).
    pub samples: usize,
}

/// A pool of reusable workspaces (allocation-free after warm-up).
pub(crate) struct Pool<T>(Mutex<Vec<T>>);

impl<T: Default> Pool<T> {
    pub(crate) fn new() -> Self {
        Self(Mutex::new(Vec::new()))
    }
    pub(crate) fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        let mut ws = self.0.lock().unwrap().pop().unwrap_or_default();
        let r = f(&mut ws);
        self.0.lock().unwrap().push(ws);
        r
    }
}

impl Nerf {
    /// A fresh model with initial weights from `seed` and an all-occupied grid. The config is
    /// validated (and its memory estimate checked) first; the error's field is prefixed `nerf.`.
    pub fn new(config: NerfConfig, seed: u64) -> Result<Self, crate::NerfError> {
        config.validate().map_err(|e| e.within("nerf"))?;
        let field = NgpField::new(&config);
        let params = field.init_params(seed);
        let grid = OccupancyGrid::new(config.grid_resolution, config.aabb_min, config.aabb_max);
        Ok(Self { config, field, params, grid, step: 0, seed })
    }

    /// The `sigma_net` weights (`sigma_net.0.weight` `[64, 32]` then `sigma_net.1.weight`
    /// `[16, 64]`, row-major), the parameter block of the uncertainty stage.
    pub fn sigma_net_params(&self) -> &[f32] {
        &self.params[self.field.sigma_net_range()]
    }

    /// Mutable view of [`sigma_net_params`](Self::sigma_net_params).
    pub fn sigma_net_params_mut(&mut self) -> &mut [f32] {
        let r = self.field.sigma_net_range();
        &mut self.params[r]
    }

    /// Density σ in 1/m at world points (metres); 0 outside the scene box. Parallel.
    pub fn density(&self, points: &[Point3<f32>]) -> Vec<f32> {
        let mut out = vec![0.0; points.len()];
        self.density_into(points, &mut out);
        out
    }

    /// [`Nerf::density`] into `out` (one value per point), for a caller that owns the buffer
    /// (a grid filled batch by batch).
    pub fn density_into(&self, points: &[Point3<f32>], out: &mut [f32]) {
        let pool = Pool::<(DensityWorkspace, Vec<f32>)>::new();
        out.par_chunks_mut(DENSITY_CHUNK).zip(points.par_chunks(DENSITY_CHUNK)).for_each(|(o, p)| {
            pool.with(|(ws, pos)| {
                pos.clear();
                pos.extend(p.iter().flat_map(|q| self.field.normalize(q.coords.into())));
                self.field.density_batch(&self.params, pos, ws, o);
            })
        });
    }

    /// Density σ (1/m) and its gradient ∇σ (1/m², world frame) at world points (metres); both 0
    /// outside the scene box. Parallel. ∇σ is that of the hash encoding's trilinear interpolation
    /// (continuous inside a cell, jumping across cell faces).
    pub fn density_and_gradient(&self, points: &[Point3<f32>]) -> (Vec<f32>, Vec<Vector3<f32>>) {
        let mut sigma = vec![0.0; points.len()];
        let mut grad = vec![[0.0; 3]; points.len()];
        let pool = Pool::<(DensityWorkspace, Vec<f32>)>::new();
        sigma
            .par_chunks_mut(DENSITY_CHUNK)
            .zip(grad.par_chunks_mut(DENSITY_CHUNK))
            .zip(points.par_chunks(DENSITY_CHUNK))
            .for_each(|((s, g), p)| {
                pool.with(|(ws, pos)| {
                    pos.clear();
                    pos.extend(p.iter().flat_map(|q| self.field.normalize(q.coords.into())));
                    self.field.density_and_gradient_batch(&self.params, pos, ws, s, g);
                })
            });
        (sigma, grad.into_iter().map(Vector3::from).collect())
    }

    /// The step Δt (metres) the occupancy test `σ·Δt > threshold` uses: the marching step.
    pub fn occupancy_dt(&self) -> f32 {
        self.config.step_size
    }

    /// Renders rays (unit directions, world frame) without jitter, in parallel chunks.
    pub fn render_rays(&self, rays: &[RayInput]) -> RayOutputs {
        let r = rays.len();
        let mut out = RayOutputs { rgb: vec![0.0; 3 * r], opacity: vec![0.0; r], distance: vec![0.0; r], samples: 0 };
        let pool = Pool::<ChunkWorkspace>::new();
        let samples: usize = out
            .rgb
            .par_chunks_mut(3 * RENDER_CHUNK)
            .zip(out.opacity.par_chunks_mut(RENDER_CHUNK))
            .zip(out.distance.par_chunks_mut(RENDER_CHUNK))
            .zip(rays.par_chunks(RENDER_CHUNK))
            .map(|(((rgb, op), dist), rs)| {
                pool.with(|ws| {
                    self.forward_chunk(ws, rs);
                    rgb.copy_from_slice(&ws.color);
                    op.copy_from_slice(&ws.opacity);
                    for ((d, &o), &w) in dist.iter_mut().zip(&ws.opacity).zip(&ws.depth) {
                        *d = if o > 1e-6 { w / o } else { 0.0 };
                    }
                    ws.n_samples()
                })
            })
            .sum();
        out.samples = samples;
        out
    }

    /// Whether [`render_rays`](Self::render_rays) composites at least one sample of `ray`
    /// (its jitter included), without evaluating the networks: the ray meets an occupied cell of
    /// the occupancy grid inside the box on its marching lattice. The first sample of a ray is
    /// always composited (the early-stop transmittance is below 1), so this is exactly "has a
    /// sample": the rays a fit on the `sigma_net` weights can use.
    pub fn ray_composites_a_sample(&self, ray: &RayInput) -> bool {
        let mut ts = Vec::with_capacity(1);
        march_lattice(ray.o(), ray.d(), &self.grid, self.config.step_size, 1, ray.jitter, &mut ts) > 0
    }

    /// The indices (increasing) of the `rays` for which
    /// [`ray_composites_a_sample`](Self::ray_composites_a_sample) holds; parallel.
    pub fn rays_compositing_a_sample(&self, rays: &[RayInput]) -> Vec<usize> {
        (0..rays.len()).into_par_iter().filter(|&i| self.ray_composites_a_sample(&rays[i])).collect()
    }

    /// [`ChunkWorkspace::forward`] with the rendering settings of this model.
    pub(crate) fn forward_chunk(&self, ws: &mut ChunkWorkspace, rays: &[RayInput]) {
        let c = &self.config;
        let march = crate::fields::March {
            step: c.step_size,
            max_samples: c.max_samples_per_ray,
            t_min: c.early_stop_transmittance,
            round: crate::fields::RENDER_ROUND,
            walk: crate::fields::Walk::Blocks,
        };
        ws.forward(&self.field, &self.params, rays, &self.grid, &march);
    }

    /// One occupancy-grid update (`update_index` = how many came before): evaluates σ·Δt at a
    /// random point of every cell (warm-up) or of `res³/grid_partial_fraction` random cells plus
    /// as many random occupied ones; every cell decays by `grid_decay`, measured cells keep the max
    /// (warm-up updates replace the grid).
    /// Deterministic in `(seed, update_index)`.
    pub fn update_grid(&mut self, seed: u64, update_index: u64) {
        let res = self.grid.resolution;
        let n_cells = res.pow(3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(mix(seed, 0x6121D, update_index));
        let full = update_index < self.config.grid_warmup_updates;
        let cells: Vec<u32> = if full {
            (0..n_cells as u32).collect()
        } else {
            let k = n_cells / self.config.grid_partial_fraction;
            let occ: Vec<u32> = (0..n_cells as u32).filter(|&c| self.grid.is_occupied_index(c as usize)).collect();
            let mut v: Vec<u32> = (0..k).map(|_| rng.random_range(0..n_cells as u32)).collect();
            if !occ.is_empty() {
                v.extend((0..k).map(|_| occ[rng.random_range(0..occ.len())]));
            }
            v
        };
        let jit: Vec<[f32; 3]> = (0..cells.len()).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
        let mut values = vec![0.0f32; cells.len()];
        let pool = Pool::<(DensityWorkspace, Vec<f32>)>::new();
        let field = &self.field;
        let params = &self.params;
        let dt = self.config.step_size;
        values
            .par_chunks_mut(DENSITY_CHUNK)
            .zip(cells.par_chunks(DENSITY_CHUNK))
            .zip(jit.par_chunks(DENSITY_CHUNK))
            .for_each(|((o, c), j)| {
                pool.with(|(ws, pos)| {
                    pos.clear();
                    for (&cell, jj) in c.iter().zip(j) {
                        let cell = cell as usize;
                        let ijk = [cell % res, (cell / res) % res, cell / (res * res)];
                        for d in 0..3 {
                            pos.push((ijk[d] as f32 + jj[d]) / res as f32);
                        }
                    }
                    field.density_batch(params, pos, ws, o);
                    for v in o.iter_mut() {
                        *v *= dt;
                    }
                })
            });
        self.grid.apply(&cells, &values, self.config.grid_decay, self.config.grid_threshold, full);
    }
}

pub(crate) use nerfsv_scene::seed::mix;
