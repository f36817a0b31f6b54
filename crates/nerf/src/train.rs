//! Training: ray batches from `(seed, step)`, the fused chunk kernels in parallel, a
//! deterministic gradient reduction, Adam, occupancy-grid updates, checkpoints.
//!
//! Determinism: the rays of step `s` come from a ChaCha8 stream seeded by `(seed, s)`; rays are
//! cut into fixed chunks of [`TRAIN_CHUNK`] whatever the thread count; MLP gradients are summed in
//! chunk order; the hash-table gradient is scattered level by level (levels own disjoint table
//! rows), each level visiting samples in batch order. So the same seed gives bit-identical
//! weights with 1 or N threads, and no per-thread dense gradient table is needed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use nerfsv_scene::views::PosedImages;

pub use crate::checkpoint::TrainStats;
use crate::checkpoint::TrainingState;
use crate::config::{BackgroundMode, NerfConfig, TrainConfig};
use crate::fields::{ChunkWorkspace, RayInput};
use crate::memory::check_training_memory;
use crate::model::{mix, Nerf};
use crate::model_components::losses::psnr_from_mse;
use crate::optim::{Adam, AdamParams};
use crate::NerfError;

pub use crate::fields::{TRAIN_CHUNK, TRAIN_RAYS_MULTIPLE};

/// Statistics of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    /// MSE over rays and channels.
    pub loss: f64,
    pub psnr: f64,
    pub rays: usize,
    pub samples: usize,
}

/// Training pixels in one flat table.
struct Pixels {
    cameras: Vec<nerfsv_scene::Camera>,
    /// `[frames + 1]` cumulative pixel counts.
    start: Vec<usize>,
    /// Straight RGBA of every frame, concatenated `[Σ pixels, 4]`.
    rgba: Vec<f32>,
}

/// A model being trained with its optimiser state.
pub struct Trainer {
    nerf: Nerf,
    config: TrainConfig,
    adam: Adam,
    /// Rays of the next step (adapts to `target_samples_per_step`).
    n_rays: usize,
    /// Figures so far (`occupancy` is filled in by [`Trainer::stats`]).
    stats: TrainStats,
    /// Rays and samples of every step so far (all sessions).
    rays_total: f64,
    samples_total: f64,
    pixels: Pixels,
    ws: Vec<ChunkWorkspace>,
    grad: Vec<f32>,
    pos_all: Vec<f32>,
    denc_all: Vec<f32>,
    rays: Vec<RayInput>,
    targets: Vec<[f32; 3]>,
}

/// Raw pointer that may cross threads; used for disjoint writes into one buffer.
#[derive(Clone, Copy)]
struct SendPtr(*mut f32);
unsafe impl Send for SendPtr {}
unsafe impl Sync for SendPtr {}

impl Trainer {
    /// A fresh model from `seed`, checked against the dataset's cameras (see [`check_bounds`]).
    /// Both configs are validated, and a step's memory checked against the budget, before
    /// anything is allocated; errors name the key with its table (`train.batch_rays`).
    pub fn new(nerf_config: NerfConfig, config: TrainConfig, data: &impl PosedImages) -> Result<Self, NerfError> {
        nerf_config.validate().map_err(|e| e.within("nerf"))?;
        config.validate().map_err(|e| e.within("train"))?;
        check_training_memory(&nerf_config, &config)?;
        check_bounds(&nerf_config, data)?;
        let nerf = Nerf::new(nerf_config, config.seed)?;
        let n = nerf.field.n_params;
        let n_rays = config.batch_rays;
        Ok(Self::assemble(nerf, config, Adam::new(n), n_rays, TrainStats::default(), data))
    }

    /// Continues the run saved by [`save_checkpoint`](Self::save_checkpoint).
    pub fn resume(path: &Path, data: &impl PosedImages) -> Result<Self, NerfError> {
        let ck = crate::checkpoint::read(path, true)?;
        check_bounds(&ck.nerf.config, data)?;
        let tc = ck.train_config.ok_or_else(|| NerfError::Metadata {
            path: path.into(),
            field: "train_config".into(),
            message: "missing: not a training checkpoint".into(),
        })?;
        let adam = ck.adam.expect("read(.., true) returns optimiser state");
        // Checkpoints written before `train_stats` existed know only their step.
        let mut stats = ck.train_stats.unwrap_or(TrainStats { steps: ck.step, ..TrainStats::default() });
        // The wall-clock figures of the same step, if the file beside the checkpoint has them.
        let timing = std::fs::read_to_string(train_stats_path(path))
            .ok()
            .and_then(|t| serde_json::from_str::<TrainStats>(&t).ok())
            .filter(|t| t.validate(ck.step).is_ok());
        if let Some(t) = timing {
            stats = TrainStats {
                seconds: t.seconds,
                rays_per_second: t.rays_per_second,
                samples_per_second: t.samples_per_second,
                ..stats
            };
        }
        Ok(Self::assemble(ck.nerf, tc, adam, ck.n_rays, stats, data))
    }

    fn assemble(
        nerf: Nerf,
        config: TrainConfig,
        adam: Adam,
        n_rays: usize,
        stats: TrainStats,
        data: &impl PosedImages,
    ) -> Self {
        let mut start = vec![0];
        let mut rgba = Vec::with_capacity(data.pixels() * 4);
        for f in (0..data.len()).map(|i| data.view(i)) {
            start.push(start.last().unwrap() + f.image.width as usize * f.image.height as usize);
            rgba.extend_from_slice(&f.image.rgba);
        }
        let pixels = Pixels { cameras: (0..data.len()).map(|i| *data.view(i).camera).collect(), start, rgba };
        let n = nerf.field.n_params;
        Self {
            nerf,
            config,
            adam,
            n_rays,
            rays_total: stats.rays_per_second * stats.seconds,
            samples_total: stats.samples_per_second * stats.seconds,
            stats,
            pixels,
            ws: Vec::new(),
            grad: vec![0.0; n],
            pos_all: Vec::new(),
            denc_all: Vec::new(),
            rays: Vec::new(),
            targets: Vec::new(),
        }
    }

    pub fn nerf(&self) -> &Nerf {
        &self.nerf
    }

    pub fn into_nerf(self) -> Nerf {
        self.nerf
    }

    pub fn config(&self) -> &TrainConfig {
        &self.config
    }

    /// Steps completed.
    pub fn step_count(&self) -> u64 {
        self.nerf.step
    }

    /// Figures of the run so far, over every session (see [`TrainStats`]).
    pub fn stats(&self) -> TrainStats {
        TrainStats { occupancy: self.nerf.grid.occupancy(), ..self.stats.clone() }
    }

    /// Learning rate of the next step: `lr · 0.1^min(step / lr_decay_steps, 1)`.
    pub fn learning_rate(&self) -> f32 {
        let f = if self.config.lr_decay_steps == 0 {
            0.0
        } else {
            (self.nerf.step as f64 / self.config.lr_decay_steps as f64).min(1.0)
        };
        (self.config.lr as f64 * 0.1f64.powf(f)) as f32
    }

    /// Writes model, optimiser state, step and [`TrainStats`] atomically (see
    /// [`crate::checkpoint`]).
    pub fn save_checkpoint(&self, path: &Path) -> Result<(), NerfError> {
        let stats = self.stats();
        let state = TrainingState { config: &self.config, adam: &self.adam, n_rays: self.n_rays, stats: &stats };
        crate::checkpoint::write(path, &self.nerf, Some(state))?;
        let timing = train_stats_path(path);
        nerfsv_scene::io::atomic_write(&timing, |w| {
            serde_json::to_writer_pretty(w, &stats).map_err(std::io::Error::other)
        })
        .map_err(|e| NerfError::io(&timing, e))
    }

    fn generate_rays(&mut self) {
        let b = self.n_rays;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(mix(self.config.seed, 0xBA7C4, self.nerf.step));
        let total = *self.pixels.start.last().unwrap();
        self.rays.clear();
        self.targets.clear();
        for _ in 0..b {
            let p = rng.random_range(0..total);
            let f = self.pixels.start.partition_point(|&s| s <= p) - 1;
            let local = p - self.pixels.start[f];
            let cam = &self.pixels.cameras[f];
            let w = cam.intrinsics.width as usize;
            let ray = cam.pixel_ray((local % w) as u32, (local / w) as u32);
            let bg = match self.config.background {
                BackgroundMode::Random => [rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>()],
                BackgroundMode::Fixed(c) => c,
            };
            let jitter = rng.random::<f32>();
            let px = &self.pixels.rgba[4 * p..4 * p + 4];
            let a = px[3];
            // Straight alpha: target = rgb·a + bg·(1 − a).
            self.targets.push([0, 1, 2].map(|c| px[c] * a + bg[c] * (1.0 - a)));
            self.rays.push(RayInput { origin: ray.origin, direction: ray.direction, background: bg, jitter });
        }
    }

    /// One optimisation step. Errors with [`NerfError::NonFinite`] (parameters untouched) if
    /// the loss or a gradient is NaN or infinite.
    pub fn step(&mut self) -> Result<StepStats, NerfError> {
        let started = Instant::now();
        let cfg = self.nerf.config.clone();
        let step = self.nerf.step;
        if step.is_multiple_of(cfg.grid_update_interval) {
            self.nerf.update_grid(self.config.seed, step / cfg.grid_update_interval);
        }
        self.generate_rays();
        let b = self.rays.len();
        let n_chunks = b.div_ceil(TRAIN_CHUNK);
        while self.ws.len() < n_chunks {
            self.ws.push(ChunkWorkspace::default());
        }
        let nerf = &self.nerf;
        self.ws[..n_chunks]
            .par_iter_mut()
            .zip(self.rays.par_chunks(TRAIN_CHUNK))
            .zip(self.targets.par_chunks(TRAIN_CHUNK))
            .for_each(|((ws, rays), tg)| {
                let c = &cfg;
                let march = crate::fields::March {
                    step: c.step_size,
                    max_samples: c.max_samples_per_ray,
                    t_min: c.early_stop_transmittance,
                    round: crate::fields::TRAIN_ROUND,
                    walk: crate::fields::Walk::CellByCell,
                };
                ws.forward(&nerf.field, &nerf.params, rays, &nerf.grid, &march);
                ws.backward(&nerf.field, &nerf.params, tg, b);
            });
        let ws = &self.ws[..n_chunks];
        let sq: f64 = ws.iter().map(|w| w.sq_err).sum();
        let mse = sq / (3 * b) as f64;
        if !mse.is_finite() {
            return Err(NerfError::NonFinite { step, what: "loss".into() });
        }
        // MLP gradients in chunk order.
        let field = &self.nerf.field;
        let mlp = field.mlp_range();
        let emb = field.embeddings_range();
        {
            let g = &mut self.grad[mlp.clone()];
            g.fill(0.0);
            for w in ws {
                for (a, &x) in g.iter_mut().zip(&w.grad_mlp) {
                    *a += x;
                }
            }
            if g.iter().any(|v| !v.is_finite()) {
                return Err(NerfError::NonFinite { step, what: "MLP gradient".into() });
            }
        }
        // Gather positions [N, 3] and ∂L/∂enc level-major [levels][N][2].
        let mut offs = vec![0usize];
        for w in ws {
            offs.push(offs.last().unwrap() + w.n_samples());
        }
        let n_total = *offs.last().unwrap();
        let levels = field.encoding.levels.len();
        let e = field.enc_dim;
        self.pos_all.resize(3 * n_total, 0.0);
        self.denc_all.resize(2 * levels * n_total, 0.0);
        let pp = SendPtr(self.pos_all.as_mut_ptr());
        let dp = SendPtr(self.denc_all.as_mut_ptr());
        ws.par_iter().zip(offs.par_iter()).for_each(|(w, &o)| {
            let (pp, dp) = (pp, dp);
            let n = w.n_samples();
            // SAFETY: chunk k writes only samples offs[k]..offs[k+1] of each array.
            unsafe {
                std::ptr::copy_nonoverlapping(w.pos.as_ptr(), pp.0.add(3 * o), 3 * n);
                for l in 0..levels {
                    let dst = dp.0.add(2 * (l * n_total + o));
                    for s in 0..n {
                        *dst.add(2 * s) = w.d_enc[s * e + 2 * l];
                        *dst.add(2 * s + 1) = w.d_enc[s * e + 2 * l + 1];
                    }
                }
            }
        });
        // Hash-table gradient, one level per task (disjoint rows), each task zeroing its rows and
        // checking its level's upstream gradient (no serial pass over either).
        let finite = {
            let mut slices = Vec::with_capacity(levels);
            let mut rest = &mut self.grad[emb.clone()];
            for lv in &field.encoding.levels {
                let (a, r) = rest.split_at_mut(lv.size as usize * 2);
                slices.push(a);
                rest = r;
            }
            debug_assert!(rest.is_empty(), "the levels cover the embedding table");
            let pos = &self.pos_all;
            let denc = &self.denc_all;
            slices
                .into_par_iter()
                .enumerate()
                .map(|(l, gl)| {
                    gl.fill(0.0);
                    let d = &denc[2 * l * n_total..2 * (l + 1) * n_total];
                    field.encoding.backward_level(l, pos, d, gl);
                    d.iter().all(|v| v.is_finite())
                })
                .reduce(|| true, |a, b| a && b)
        };
        if !finite {
            return Err(NerfError::NonFinite { step, what: "encoding gradient".into() });
        }
        let h = AdamParams {
            lr: self.learning_rate(),
            beta1: self.config.betas.0,
            beta2: self.config.betas.1,
            eps: self.config.eps,
            weight_decay: self.config.weight_decay,
        };
        self.adam.step(&mut self.nerf.params, &self.grad, h, mlp);
        self.nerf.step += 1;
        if self.config.target_samples_per_step > 0 {
            let spr = (n_total as f64 / b as f64).max(1.0);
            let want = (self.config.target_samples_per_step as f64 / spr) as usize;
            self.n_rays = want.clamp(TRAIN_RAYS_MULTIPLE, 1 << 16) / TRAIN_RAYS_MULTIPLE * TRAIN_RAYS_MULTIPLE;
        }
        let psnr = psnr_from_mse(mse);
        self.rays_total += b as f64;
        self.samples_total += n_total as f64;
        let s = &mut self.stats;
        s.steps = self.nerf.step;
        s.seconds += started.elapsed().as_secs_f64();
        s.train_batch_psnr = psnr;
        s.rays_per_second = self.rays_total / s.seconds.max(1e-9);
        s.samples_per_second = self.samples_total / s.seconds.max(1e-9);
        Ok(StepStats { loss: mse, psnr, rays: b, samples: n_total })
    }
}

/// Checks that the dataset's cameras look at the model's box: the principal ray of at least
/// half of the frames must cross the box. Errors name the first frame that misses.
pub fn check_bounds(cfg: &NerfConfig, data: &impl PosedImages) -> Result<(), NerfError> {
    if data.is_empty() {
        return Err(NerfError::EmptySplit { path: data.source().to_path_buf() });
    }
    let mut misses = Vec::new();
    for (i, f) in (0..data.len()).map(|i| (i, data.view(i))) {
        let k = f.camera.intrinsics;
        let r = f.camera.ray(k.cx, k.cy);
        let o = [r.origin.x, r.origin.y, r.origin.z];
        let d = [r.direction.x, r.direction.y, r.direction.z];
        if crate::model_components::ray_samplers::ray_aabb(o, d, cfg.aabb_min, cfg.aabb_max).is_none() {
            misses.push(i);
        }
    }
    if misses.len() * 2 > data.len() {
        let i = misses[0];
        let p = data.view(i).camera.position();
        return Err(NerfError::Bounds {
            path: data.source().to_path_buf(),
            frame: i,
            message: format!(
                "{} of {} cameras do not look at the scene box {:?}..{:?} (this one at ({:.2}, {:.2}, {:.2})); \
                 the dataset does not match the model's bound",
                misses.len(),
                data.len(),
                cfg.aabb_min,
                cfg.aabb_max,
                p.x,
                p.y,
                p.z
            ),
        });
    }
    Ok(())
}

/// How long [`train`] runs: wall-clock seconds of this call, or a total step count (counting
/// steps done before a resume, so a resumed run ends where an uninterrupted one would).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    Seconds(f64),
    Steps(u64),
}

/// Reported by [`train`] after every step.
#[derive(Clone, Copy, Debug, Default)]
pub struct Progress {
    pub step: u64,
    /// Fraction of the budget used, `[0, 1]`.
    pub fraction: f64,
    pub elapsed_s: f64,
    pub loss: f64,
    /// PSNR of the step's batch (dB, on the random backgrounds).
    pub psnr: f64,
    pub rays_per_s: f64,
    pub samples_per_s: f64,
    /// Samples per ray in the last step.
    pub samples_per_ray: f64,
    /// Fraction of occupied grid cells.
    pub occupancy: f64,
    /// A checkpoint was written after this step.
    pub checkpointed: bool,
}

impl Progress {
    /// The status line of a training step, as the progress bars show it.
    pub fn status(&self) -> String {
        format!(
            "step {:>5} loss {:.5} psnr {:5.2} dB {:>6.0} rays/s {:>4.1} spr{}",
            self.step,
            self.loss,
            self.psnr,
            self.rays_per_s,
            self.samples_per_ray,
            if self.checkpointed { " [saved]" } else { "" }
        )
    }
}

/// The file beside a checkpoint with its run's [`TrainStats`], wall-clock figures included.
pub fn train_stats_path(checkpoint: &Path) -> PathBuf {
    checkpoint.with_file_name("train_stats.json")
}

/// The checkpoint file [`train`] keeps in its output folder.
pub fn checkpoint_path(out_dir: &Path) -> PathBuf {
    out_dir.join("checkpoint.safetensors")
}

/// Trains on `data` into `out_dir/checkpoint.safetensors` (model + optimiser state, written
/// atomically every `checkpoint_every_s` seconds / `checkpoint_every_steps` steps and at the
/// end). With `resume` and an existing checkpoint, continues it (the configs passed are then
/// ignored in favour of the checkpoint's). On a NaN the error is returned and the last
/// checkpoint is left as it was.
///
/// Returns the model and the run's [`TrainStats`] (cumulative over every session, restored from
/// the checkpoint, so they are real figures even when the budget was already reached).
pub fn train(
    data: &impl PosedImages,
    out_dir: &Path,
    budget: Budget,
    resume: bool,
    nerf_config: NerfConfig,
    train_config: TrainConfig,
    mut on_progress: impl FnMut(&Progress),
) -> Result<(Nerf, TrainStats), NerfError> {
    std::fs::create_dir_all(out_dir).map_err(|e| NerfError::io(out_dir, e))?;
    let ck = checkpoint_path(out_dir);
    let mut trainer = if resume && ck.exists() {
        Trainer::resume(&ck, data)?
    } else {
        Trainer::new(nerf_config, train_config, data)?
    };
    let t0 = Instant::now();
    let mut last_ck = Instant::now();
    let mut last_ck_step = trainer.step_count();
    let (mut rays, mut samples) = (0usize, 0usize);
    loop {
        let done = match budget {
            Budget::Seconds(s) => t0.elapsed().as_secs_f64() >= s,
            Budget::Steps(n) => trainer.step_count() >= n,
        };
        if done {
            break;
        }
        let st = trainer.step()?;
        rays += st.rays;
        samples += st.samples;
        let el = t0.elapsed().as_secs_f64();
        let c = trainer.config();
        let due = (c.checkpoint_every_s > 0.0 && last_ck.elapsed().as_secs_f64() >= c.checkpoint_every_s)
            || (c.checkpoint_every_steps > 0 && trainer.step_count() - last_ck_step >= c.checkpoint_every_steps);
        if due {
            trainer.save_checkpoint(&ck)?;
            last_ck = Instant::now();
            last_ck_step = trainer.step_count();
        }
        let fraction = match budget {
            Budget::Seconds(s) => (el / s).min(1.0),
            Budget::Steps(n) => (trainer.step_count() as f64 / n.max(1) as f64).min(1.0),
        };
        on_progress(&Progress {
            step: trainer.step_count(),
            fraction,
            elapsed_s: el,
            loss: st.loss,
            psnr: st.psnr,
            rays_per_s: rays as f64 / el.max(1e-9),
            samples_per_s: samples as f64 / el.max(1e-9),
            samples_per_ray: st.samples as f64 / st.rays.max(1) as f64,
            occupancy: trainer.nerf().grid.occupancy(),
            checkpointed: due,
        });
    }
    trainer.save_checkpoint(&ck)?;
    let stats = trainer.stats();
    Ok((trainer.into_nerf(), stats))
}
