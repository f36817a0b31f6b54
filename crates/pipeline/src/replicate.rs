//! The study replicated over seeds: the same config run `N` times, each time with another seed
//! for one source of randomness ([`Varied`]), and the headline figures of every run side by side
//! with their mean and standard deviation (`OUT/replicate.csv`, `OUT/replicate.json`,
//! `OUT/index.html`).
//!
//! - **Training seeds** (`OUT/seed_S/`): the NeRF's training seed, and so its ensemble, changes;
//!   the dataset, the ground truth and everything seeded apart from training (the disturbances of
//!   the stress tests, the flight's pixels) stay, so the spread is the training seed's alone and
//!   the runs' rollouts are paired. Seed `i` trains with `train.seed + i·MAX_MEMBERS`, so that no
//!   two runs share an ensemble member (member `k` of a run trains with its seed + `k`).
//! - **Disturbance seeds** (`OUT/stress_seed_S/`): the run seed `stress.seed + i` changes, so
//!   every sampler draws other disturbances and the calibration other route poses, pixels and
//!   starts (it takes the same seed); the models and fields stay, so the spread is that of the
//!   search and of the calibration's draws, not of training.
//!
//! Runs after the first share the first's stages that do not depend on what varies: their
//! folders are copied in before the run, and the runner takes them only if their keys match
//! (else it computes them again).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use nerfsv_sim::WorldKind;
use nerfsv_study::stress::{Sampler, StressFigures, TransferFigures};
use nerfsv_validation::{Confusion, Transfer};

use crate::config::MAX_MEMBERS;
use crate::eval::{EvalFigures, EvalStage};
use crate::stress::StressStage;
use crate::uq::{UqFigures, UqStage};
use crate::{Observer, PipelineError, RunConfig, Stage, Summary, Validate};

/// Which seed a replication varies from run to run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Varied {
    /// The NeRF's training seed (`train.seed`, then every `MAX_MEMBERS`-th after it).
    #[default]
    Training,
    /// The stress stage's run seed (`stress.seed`, then the next ones): the disturbances.
    Disturbances,
}

impl Varied {
    /// The config key it varies.
    pub fn key(self) -> &'static str {
        match self {
            Varied::Training => "train.seed",
            Varied::Disturbances => "stress.seed",
        }
    }

    /// The seed of replicate `i` of `cfg`.
    pub fn seed(self, cfg: &RunConfig, i: usize) -> u64 {
        match self {
            Varied::Training => replicate_seed(cfg.train.seed, i),
            Varied::Disturbances => cfg.stress.seed.wrapping_add(i as u64),
        }
    }

    /// `cfg` with its varied seed set to `seed`.
    fn with_seed(self, cfg: &RunConfig, seed: u64) -> RunConfig {
        let mut run = cfg.clone();
        match self {
            Varied::Training => run.train.seed = seed,
            Varied::Disturbances => run.stress.seed = seed,
        }
        run
    }

    /// The run folder of seed `seed` below `out`.
    pub fn folder(self, out: &Path, seed: u64) -> PathBuf {
        match self {
            Varied::Training => out.join(format!("seed_{seed}")),
            Varied::Disturbances => out.join(format!("stress_seed_{seed}")),
        }
    }

    /// The stages a replicate takes from the first run (they do not depend on this seed).
    fn shared_stages(self) -> &'static [&'static str] {
        match self {
            Varied::Training => &[crate::dataset::DatasetStage::NAME, crate::collision::CollisionStage::NAME],
            Varied::Disturbances => &[
                crate::dataset::DatasetStage::NAME,
                crate::collision::CollisionStage::NAME,
                crate::nerf::NerfStage::NAME,
                crate::eval::EvalStage::NAME,
                crate::ensemble::EnsembleStage::NAME,
                UqStage::NAME,
                crate::nerf_collision::NerfCollisionStage::NAME,
                crate::flight::FlightStage::NAME,
            ],
        }
    }

    /// What the page's title calls the runs' seeds.
    fn what(self) -> &'static str {
        match self {
            Varied::Training => "training seeds",
            Varied::Disturbances => "disturbance seeds",
        }
    }
}

/// The run folder of training seed `seed` below `out`.
pub fn seed_folder(out: &Path, seed: u64) -> PathBuf {
    Varied::Training.folder(out, seed)
}

/// The headline figures, as (label, how to read it from a run's figures). A figure a run does
/// not have (a stage skipped, a world without a ground truth) is left empty in its row.
const HEADLINES: [(&str, Headline); 15] = [
    ("test PSNR (dB)", |f| Some(f.eval?.psnr)),
    ("NeRF-sim MC failure rate, deployed model", |f| Some(f.transfer()?.nerf_deployed.rate)),
    ("NeRF-sim MC failure rate, ensemble world", |f| Some(f.transfer()?.nerf_ensemble.rate)),
    ("NeRF-sim MC failure rate, calibrated world", |f| Some(f.transfer()?.nerf_calibrated.as_ref()?.rate)),
    ("GT-sim failure rate (same disturbances)", |f| Some(f.transfer()?.gt.rate)),
    ("NeRF-sim / GT-sim rate ratio (calibrated world, else ensemble, else deployed)", |f| {
        let t = f.transfer()?;
        let finite = |v: f64| v.is_finite().then_some(v);
        let calibrated = t.nerf_calibrated.as_ref().and_then(|c| finite(c.rate));
        let nerf = calibrated.or(finite(t.nerf_ensemble.rate)).unwrap_or(t.nerf_deployed.rate);
        (t.gt.rate > 0.0).then(|| nerf / t.gt.rate)
    }),
    ("recall of GT-sim failures, calibrated world", |f| f.transfer()?.recall_calibrated),
    ("precision, calibrated world", |f| f.transfer()?.precision_calibrated),
    ("McNemar p, calibrated world", |f| f.transfer()?.mcnemar_p_calibrated),
    ("recall of GT-sim failures, ensemble world", |f| f.transfer()?.recall_ensemble),
    ("precision, ensemble world", |f| f.transfer()?.precision_ensemble),
    ("Matthews correlation, ensemble world", |f| f.transfer()?.mcc_ensemble),
    ("CEM P(fail), NeRF-sim", |f| {
        let stress = f.stress?;
        Some(stress.samplers.iter().find(|s| s.sampler == Sampler::Cem && s.world == WorldKind::Nerf)?.p_fail)
    }),
    ("step AUROC of the ensemble's spread, MC", |f| {
        f.transfer()?.step_auroc.iter().find(|a| a.sampler == Sampler::Mc)?.auroc.step_auroc
    }),
    ("depth AUSE, ensemble (GA's images)", |f| f.uq?.ensemble_ause.as_ref()?.on_ga_images),
];

/// The NeRF worlds whose comparison with GT-sim is pooled over the runs.
const POOLED_WORLDS: [&str; 3] = ["deployed", "ensemble", "calibrated"];

type Headline = for<'a> fn(&RunFigures<'a>) -> Option<f64>;

/// The figures of one run the headlines read, typed.
struct RunFigures<'a> {
    eval: Option<&'a EvalFigures>,
    stress: Option<&'a StressFigures>,
    uq: Option<&'a UqFigures>,
}

impl<'a> RunFigures<'a> {
    fn of(summary: &'a Summary) -> Self {
        Self {
            eval: summary.figures::<EvalStage>(),
            stress: summary.figures::<StressStage>(),
            uq: summary.figures::<UqStage>(),
        }
    }

    /// The stress stage's comparison of NeRF-sim with GT-sim on the same rollouts.
    fn transfer(&self) -> Option<&'a TransferFigures> {
        self.stress?.transfer.as_ref()
    }

    /// The worlds' comparisons with GT-sim this run made, as (world, comparison), in
    /// [`POOLED_WORLDS`]' order.
    fn transfers(&self) -> Vec<(&'static str, &'a Transfer)> {
        let Some(t) = self.transfer() else { return Vec::new() };
        let worlds = [Some(&t.deployed), Some(&t.ensemble), t.calibrated.as_ref()];
        POOLED_WORLDS.iter().zip(worlds).filter_map(|(&w, t)| Some((w, t?))).collect()
    }

    /// Every headline, in order; a figure that is not a number (NaN) is left empty, as
    /// `summary.json` writes it (null).
    fn headlines(&self) -> Vec<Option<f64>> {
        HEADLINES.iter().map(|(_, read)| read(self).filter(|v| v.is_finite())).collect()
    }
}

/// One run's headline figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SeedRow {
    /// The value of the varied seed ([`Replication::varied`]) in this run.
    pub seed: u64,
    pub folder: PathBuf,
    /// In [`Replication::headlines`]' order; `None` where the run has no such figure.
    pub values: Vec<Option<f64>>,
}

/// One headline over the runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    pub headline: String,
    /// Runs that have the figure.
    pub n: usize,
    pub mean: Option<f64>,
    /// Sample standard deviation over the runs (`None` below two).
    pub sd: Option<f64>,
}

/// One NeRF world's comparison with GT-sim over every run's rollouts together.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PooledTransfer {
    /// `deployed`, `ensemble` or `calibrated`.
    pub world: String,
    /// Runs that flew it.
    pub runs: usize,
    /// The comparison of the runs' rollouts together (their confusion matrices summed): the
    /// rates, recall, precision and McNemar's test with intervals from all of them. Treat its
    /// intervals as the rollouts' alone: with training seeds the runs' rollouts are the same
    /// disturbances flown by other models, so they are not independent draws.
    pub transfer: Transfer,
}

/// The replicated study's figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Replication {
    /// Which seed the runs differ in.
    pub varied: Varied,
    pub headlines: Vec<Spread>,
    pub seeds: Vec<SeedRow>,
    /// Each NeRF world's comparison with GT-sim pooled over the runs.
    pub pooled: Vec<PooledTransfer>,
}

/// Each world's confusion matrices summed over the runs that have it, and its comparison.
fn pooled(runs: &[Vec<(&'static str, &Transfer)>]) -> Vec<PooledTransfer> {
    POOLED_WORLDS
        .iter()
        .filter_map(|&world| {
            let mut sum = Confusion::default();
            let mut count = 0;
            for (_, t) in runs.iter().flatten().filter(|(w, _)| *w == world) {
                let c = &t.confusion;
                sum.true_positive += c.true_positive;
                sum.false_positive += c.false_positive;
                sum.false_negative += c.false_negative;
                sum.true_negative += c.true_negative;
                count += 1;
            }
            (count > 0).then(|| {
                let (nerf, gt) = sum.outcomes();
                PooledTransfer { world: world.to_string(), runs: count, transfer: Transfer::of(&nerf, &gt, 0) }
            })
        })
        .collect()
}

/// The training seed of replicate `i` of a config whose training seed is `base`.
pub fn replicate_seed(base: u64, i: usize) -> u64 {
    base.wrapping_add((i * MAX_MEMBERS) as u64)
}

/// What a replication reads (the config's world) and writes (its folder, named `out` in
/// messages: the key, or the flag that set it).
pub fn replicate_guard(cfg: &RunConfig, out: &str) -> crate::Guard {
    crate::run::world_inputs(cfg, crate::Guard::new().folder(out, &cfg.run_folder(), crate::OutputKind::Replication))
}

/// Runs `cfg` with `seeds` seeds of `varied` into their folders below its run folder (sharing the
/// first's stages that do not depend on that seed), then writes the figures side by side. Each
/// run studies the online uncertainty methods (`[online] methods`) only with `online_methods`:
/// no replicated figure reads them.
pub fn replicate(
    cfg: &RunConfig,
    seeds: usize,
    varied: Varied,
    online_methods: bool,
    observer: &dyn Observer,
) -> Result<Replication, PipelineError> {
    nerfsv_scene::validate::in_range("--seeds", seeds, 1, 1000)?;
    cfg.validate()?;
    let (scene, warnings) = cfg.ground_truth()?;
    for w in &warnings {
        observer.note("world", &format!("warning: {w}"));
    }
    // The replication's folder is nerfsv's (absent, empty or an earlier replication) before any
    // seed's run folder is made in it.
    replicate_guard(cfg, "out").claim()?.keep();
    let root = cfg.run_folder();
    let mut rows = Vec::with_capacity(seeds);
    let mut summaries = Vec::with_capacity(seeds);
    let mut first: Option<PathBuf> = None;
    for i in 0..seeds {
        let seed = varied.seed(cfg, i);
        let mut run = varied.with_seed(cfg, seed);
        if !online_methods {
            run.online.methods.clear();
        }
        let folder = varied.folder(&root, seed);
        run.out = Some(folder.clone());
        observer
            .note("replicate", &format!("{} = {seed} ({} of {seeds}) into {}", varied.key(), i + 1, folder.display()));
        nerfsv_scene::folder::claim_folder("out", &folder, nerfsv_scene::folder::OutputKind::Run)?;
        if let Some(first) = &first {
            for stage in varied.shared_stages() {
                share_stage(&first.join(stage), &folder.join(stage))?;
            }
        }
        let summary = crate::run_in(&run, scene.as_ref(), observer)?;
        rows.push(SeedRow { seed, folder: folder.clone(), values: RunFigures::of(&summary).headlines() });
        summaries.push(summary);
        first.get_or_insert(folder);
    }
    let transfers: Vec<_> = summaries.iter().map(|s| RunFigures::of(s).transfers()).collect();
    let replication = Replication { varied, headlines: spreads(&rows), seeds: rows, pooled: pooled(&transfers) };
    write(&root, &replication)?;
    Ok(replication)
}

/// Each headline's mean and standard deviation over the rows that have it.
fn spreads(rows: &[SeedRow]) -> Vec<Spread> {
    HEADLINES
        .iter()
        .enumerate()
        .map(|(h, (label, _))| {
            let values: Vec<f64> = rows.iter().filter_map(|r| r.values[h]).collect();
            let n = values.len();
            let mean = (n > 0).then(|| values.iter().sum::<f64>() / n as f64);
            let sd = mean
                .filter(|_| n > 1)
                .map(|m| (values.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt());
            Spread { headline: label.to_string(), n, mean, sd }
        })
        .collect()
}

/// `OUT/replicate.csv`: a row per seed, then the mean and the standard deviation;
/// `OUT/replicate.json`: the same figures; `OUT/index.html`: the table.
pub const CSV: &str = "replicate.csv";
pub const JSON: &str = "replicate.json";
pub const PAGE: &str = "index.html";

fn write(out: &Path, r: &Replication) -> Result<(), PipelineError> {
    let cell = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    let quote = |s: &str| format!("\"{}\"", s.replace('"', "\"\""));
    let seed_column = r.varied.key().replace('.', "_");
    let mut csv = format!("row,{seed_column}");
    for s in &r.headlines {
        csv.push(',');
        csv.push_str(&quote(&s.headline));
    }
    csv.push('\n');
    for row in &r.seeds {
        csv.push_str(&format!("seed,{}", row.seed));
        for v in &row.values {
            csv.push(',');
            csv.push_str(&cell(*v));
        }
        csv.push('\n');
    }
    for (name, pick) in [("mean", 0), ("sd", 1)] {
        csv.push_str(name);
        csv.push(',');
        for s in &r.headlines {
            csv.push(',');
            csv.push_str(&cell(if pick == 0 { s.mean } else { s.sd }));
        }
        csv.push('\n');
    }
    let json = serde_json::to_string_pretty(r).map_err(|e| PipelineError::Internal(e.to_string()))?;
    let mut header = vec!["figure", "mean ± sd", "runs"];
    let seed_labels: Vec<String> = r.seeds.iter().map(|s| format!("seed {}", s.seed)).collect();
    header.extend(seed_labels.iter().map(String::as_str));
    let short = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.3}"));
    let table = crate::report::Table::new(&header).rows(r.headlines.iter().enumerate().map(|(h, s)| {
        let mut cells = vec![s.headline.clone(), format!("{} ± {}", short(s.mean), short(s.sd)), s.n.to_string()];
        cells.extend(r.seeds.iter().map(|row| short(row.values[h])));
        cells
    }));
    let page = format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>nerfsv: the study over {n} {what}</title>\
         <style>body{{font-family:sans-serif;max-width:70em;margin:2em auto}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:.3em .6em;text-align:right}}td:first-child,th:first-child{{text-align:left}}</style>\
         </head><body><h1>The study over {n} {what}</h1><p>{how} Each headline's mean ± standard deviation over \
         the runs, then each run's value. Each run's own report is in its folder \
         (<code>{folder}/report/index.html</code>); the figures are in <code>{CSV}</code> and <code>{JSON}</code>.\
         </p>{}<h2>NeRF-sim against GT-sim, all runs' rollouts together</h2><p>Each NeRF world's confusion matrices \
         summed over the runs, with Wilson intervals for the rates, recall and precision and McNemar's exact test \
         on the summed discordant pairs. {pooled_caveat}</p>{}</body></html>\n",
        table.html(),
        pooled_table(&r.pooled).html(),
        n = r.seeds.len(),
        what = r.varied.what(),
        how = match r.varied {
            Varied::Training =>
                "The same config and disturbances, the NeRF (and its ensemble) trained with another \
                                 seed each time.",
            Varied::Disturbances =>
                "The same config, models and calibration, the stress stage's disturbances drawn \
                                     with another seed each time (<code>stress.seed</code>).",
        },
        folder = r.varied.folder(Path::new(""), 0).to_string_lossy().replace('0', "S"),
        pooled_caveat = match r.varied {
            Varied::Training =>
                "The runs fly the same disturbances, so their rollouts are not independent: the \
                                 intervals are narrower than the runs' spread warrants.",
            Varied::Disturbances =>
                "The runs' disturbances are independent draws, so the pooled rollouts are one \
                                     larger sample of each world.",
        },
    );
    for (name, bytes) in [(CSV, csv.into_bytes()), (JSON, json.into_bytes()), (PAGE, page.into_bytes())] {
        let path = out.join(name);
        nerfsv_scene::io::atomic_write_bytes(&path, &bytes).map_err(|e| PipelineError::io(&path, e))?;
    }
    Ok(())
}

/// The pooled comparisons as a table: a row per NeRF world.
fn pooled_table(pooled: &[PooledTransfer]) -> crate::report::Table {
    let rate = |r: &nerfsv_validation::Rate| format!("{:.3} [{:.3}, {:.3}]", r.rate, r.ci95[0], r.ci95[1]);
    let estimate = |e: &Option<nerfsv_validation::Estimate>| {
        e.as_ref().map_or("–".to_string(), |e| format!("{:.2} [{:.2}, {:.2}]", e.value, e.ci95[0], e.ci95[1]))
    };
    crate::report::Table::new(&[
        "NeRF world",
        "runs",
        "rollouts",
        "NeRF-sim rate",
        "GT-sim rate",
        "recall",
        "precision",
        "MCC",
        "McNemar p",
    ])
    .rows(pooled.iter().map(|p| {
        let t = &p.transfer;
        vec![
            p.world.clone(),
            p.runs.to_string(),
            t.n.to_string(),
            rate(&t.nerf),
            rate(&t.gt),
            estimate(&t.recall),
            estimate(&t.precision),
            estimate(&t.mcc),
            if t.mcnemar_p < 0.001 { "< 0.001".to_owned() } else { format!("{:.3}", t.mcnemar_p) },
        ]
    }))
}

/// Copies the stage folder `from` to `to` unless `to` exists (through a temporary sibling
/// renamed into place, so an interrupted copy leaves nothing the runner could take).
fn share_stage(from: &Path, to: &Path) -> Result<(), PipelineError> {
    if to.exists() || !from.is_dir() {
        return Ok(());
    }
    let parent = to.parent().ok_or_else(|| PipelineError::Internal(format!("{}: no parent", to.display())))?;
    std::fs::create_dir_all(parent).map_err(|e| PipelineError::io(parent, e))?;
    let name = to.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let tmp = parent.join(format!(".{name}.copy"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| PipelineError::io(&tmp, e))?;
    }
    copy_dir(from, &tmp)?;
    std::fs::rename(&tmp, to).map_err(|e| PipelineError::io(to, e))
}

fn copy_dir(from: &Path, to: &Path) -> Result<(), PipelineError> {
    std::fs::create_dir_all(to).map_err(|e| PipelineError::io(to, e))?;
    for entry in std::fs::read_dir(from).map_err(|e| PipelineError::io(from, e))? {
        let entry = entry.map_err(|e| PipelineError::io(from, e))?;
        let (src, dst) = (entry.path(), to.join(entry.file_name()));
        if src.is_dir() {
            copy_dir(&src, &dst)?;
        } else {
            std::fs::copy(&src, &dst).map_err(|e| PipelineError::io(&src, e))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage::StageFigure;

    #[test]
    fn spreads_are_the_mean_and_sample_sd_of_the_runs_that_have_the_figure() {
        let row = |seed: u64, v: Option<f64>| SeedRow {
            seed,
            folder: PathBuf::new(),
            values: (0..HEADLINES.len()).map(|h| if h == 0 { v } else { None }).collect(),
        };
        let s = spreads(&[row(0, Some(1.0)), row(16, Some(3.0)), row(32, None)]);
        assert_eq!((s[0].n, s[0].mean, s[0].sd), (2, Some(2.0), Some(2f64.sqrt())));
        assert_eq!((s[1].n, s[1].mean, s[1].sd), (0, None, None));
        assert_eq!(replicate_seed(5, 2), 5 + 2 * MAX_MEMBERS as u64);
    }

    #[test]
    fn headlines_read_the_typed_figures_and_leave_out_what_a_run_has_not() {
        let eval = EvalFigures { psnr: 27.5, ssim: 0.9, depth_median_abs_err_m: None, images: 4, background: [1.0; 3] };
        let summary = |stages: Vec<StageFigure>| Summary { run: PathBuf::new(), stages: crate::StageFigures(stages) };
        // The stress stage's figures under another stage's name are not the stress stage's.
        let ran = summary(vec![
            StageFigure::new(EvalStage::NAME, eval.clone()).unwrap(),
            StageFigure::new("stress", 3u32).unwrap(),
        ]);
        let values = RunFigures::of(&ran).headlines();
        assert_eq!(values.len(), HEADLINES.len());
        assert_eq!(values[0], Some(27.5));
        assert!(values[1..].iter().all(Option::is_none), "{values:?}");
        // A NaN figure is empty, as summary.json writes it.
        let nan = summary(vec![StageFigure::new(EvalStage::NAME, EvalFigures { psnr: f64::NAN, ..eval }).unwrap()]);
        assert_eq!(RunFigures::of(&nan).headlines()[0], None);
        assert_eq!(serde_json::to_value(&nan).unwrap()["eval"]["psnr"], serde_json::Value::Null);
    }
}
