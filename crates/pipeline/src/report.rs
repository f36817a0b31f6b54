//! The report of a run folder (`RUN/report/`): one self-contained HTML page of the study's
//! tables and pictures, built from what the stages left (their `stage.json` records, figures
//! and CSVs), with the pictures copied beside it, `summary.json` and the tables as CSV.
//!
//! It is cheap (no computation, a few file copies) and is rebuilt at the end of every
//! `nerfsv run` and by `nerfsv report RUN_DIR`, so it always shows the folder's current stage
//! outputs. A stage that has not run leaves its section out with a line saying so.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::stage::RECORD;
use crate::{summary_path, PipelineError};

/// The report's folder under the run folder, and its page.
pub const REPORT: &str = "report";
pub const INDEX: &str = "index.html";
/// The run config the report shows, written beside the page (without the run folder's path).
pub const CONFIG: &str = "config.toml";

/// The stages in run order, with a line on what each does.
const STAGES: &[(&str, &str)] = &[
    ("dataset", "ground-truth renders of the scene (train, val, test)"),
    ("collision", "ground-truth signed collision field"),
    ("nerf", "NeRF training"),
    ("eval", "test-split PSNR, SSIM, depth error"),
    ("uq", "offline uncertainty: GA, BLA, depth AUSE"),
    ("nerf_collision", "the NeRF's collision field"),
    ("flight", "nominal flights in both worlds"),
    ("stress", "Monte Carlo and CEM in NeRF-sim, replayed in GT-sim"),
    ("online", "per-step uncertainty and the rewards (Tables 1–2)"),
];

/// Pictures copied into the report, `(stage, file, caption)`.
const PICTURES: &[(&str, &str, &str)] = &[
    ("eval", "compare.png", "Test views: ground truth (left) beside the NeRF (right)"),
    ("flight", "trajectory_gt_vision.png", "Nominal flight in GT-sim, vision estimator"),
    ("flight", "trajectory_nerf_vision.png", "Nominal flight in NeRF-sim, vision estimator"),
    (
        "flight",
        "trajectory_gt_vision_position_error.png",
        "GT-sim, vision estimator: position error of the estimate and the filter's 2σ",
    ),
    (
        "flight",
        "trajectory_gt_vision_attitude_error.png",
        "GT-sim, vision estimator: attitude error of the estimate and the filter's 2σ",
    ),
    (
        "flight",
        "trajectory_nerf_vision_position_error.png",
        "NeRF-sim, vision estimator: position error of the estimate and the filter's 2σ",
    ),
    ("stress", "estimate_errors.png", "The vision estimator's position error after each image, both worlds"),
    ("stress", "most_likely_failure_mc_nerf.png", "MC's most likely failure in NeRF-sim"),
    ("stress", "most_likely_failure_mc_gt.png", "The same disturbances in GT-sim"),
    ("stress", "most_likely_failure_cem_nerf.png", "CEM's most likely failure in NeRF-sim"),
    ("stress", "most_likely_failure_cem_gt.png", "The same disturbances in GT-sim"),
    (
        "uq",
        "uq_maps.png",
        "Per pixel, on one test view: the NeRF's depth error and GA's and BLA's depth standard deviations",
    ),
    ("uq", "uq_ga_sigma_d.png", "GA: σ_d per image and split"),
    ("uq", "uq_ga_mu_sigma.png", "GA: μ_d against σ_d"),
    ("uq", "uq_bla_trace.png", "BLA: normalised trace per image and split"),
    ("uq", "uq_bla_rmv.png", "BLA: rmv per image and split"),
    ("uq", "uq_bla_trace_rmv.png", "BLA: normalised trace against rmv"),
];

/// Tables copied as CSV, `(stage, file, name in the report)`.
const TABLES: &[(&str, &str, &str)] = &[
    ("stress", "table.csv", "stress_table.csv"),
    ("online", "table.csv", "online_table.csv"),
    ("uq", "ause.csv", "ause.csv"),
    ("uq", "ga.csv", "uq_ga.csv"),
    ("uq", "bla.csv", "uq_bla.csv"),
];

/// The collision-field slices the report draws.
const FIELDS_PNG: &str = "nerf_collision_slices.png";
/// The difference panel's colours saturate at this many metres.
const FIELD_DIFFERENCE_CLIP_M: f64 = 0.05;

/// Slices of the ground-truth and the NeRF's signed fields at the planned path's mean altitude
/// (0.18 m without a flight stage), sampled at the ground-truth grid's nodes in x and y, and
/// their difference NeRF − GT, clipped at ±[`FIELD_DIFFERENCE_CLIP_M`]; `None` without both
/// fields.
fn field_slices_figure(root: &Path, summary: &Value) -> Option<Vec<u8>> {
    let gt = nerfsv_collision::SdfGrid::load(root.join("collision/gt_sdf.safetensors")).ok()?;
    let nerf = nerfsv_collision::SdfGrid::load(root.join("nerf_collision/nerf_sdf.safetensors")).ok()?;
    let zs: Vec<f64> = summary["flight"]["waypoints"].as_array()?.iter().filter_map(|w| w[2].as_f64()).collect();
    let z = if zs.is_empty() { 0.18 } else { zs.iter().sum::<f64>() / zs.len() as f64 };
    let g = gt.geometry;
    let [nx, ny, _] = g.dims;
    let sample = |f: &nerfsv_collision::SdfGrid, i: usize, j: usize| -> f64 {
        let mut q = g.position_of(i, j, 0);
        q.z = z as f32;
        f.geometry.trilinear(&f.data, &q).in_grid().map_or(f64::NAN, f64::from)
    };
    let mut values = [Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny)];
    for j in 0..ny {
        for i in 0..nx {
            let (a, b) = (sample(&gt, i, j), sample(&nerf, i, j));
            values[0].push(a);
            values[1].push(b);
            values[2].push((b - a).clamp(-FIELD_DIFFERENCE_CLIP_M, FIELD_DIFFERENCE_CLIP_M));
        }
    }
    let [gt_v, nerf_v, diff_v] = values;
    let panel = |caption: String, colour_title: &str, values: Vec<f64>, scale| nerfsv_plot::Heatmap {
        caption,
        x_title: "x (m)".into(),
        y_title: "y (m)".into(),
        colour_title: colour_title.into(),
        origin: [f64::from(g.origin.x), f64::from(g.origin.y)],
        cell: [f64::from(g.cell); 2],
        dims: [nx, ny],
        values,
        scale,
    };
    let fig = nerfsv_plot::HeatmapFigure {
        title: format!("Signed distance at z = {z:.2} m"),
        panels: vec![
            panel("ground truth".into(), "signed distance (m)", gt_v, nerfsv_plot::ColourScale::Linear),
            panel("NeRF".into(), "signed distance (m)", nerf_v, nerfsv_plot::ColourScale::Linear),
            panel(
                format!("NeRF − ground truth (clipped at ±{:.0} cm)", 100.0 * FIELD_DIFFERENCE_CLIP_M),
                "difference (m)",
                diff_v,
                nerfsv_plot::ColourScale::Diverging,
            ),
        ],
    };
    nerfsv_plot::heatmap_png(&fig, 1500, 500).ok()
}

/// The clearance-difference histograms the report draws.
const CLEARANCE_PNG: &str = "stress_clearance_difference.png";

/// Histograms of |clearance in NeRF-sim − in GT-sim| (mm) per sampler, per trajectory and per
/// step, from the stress stage's rollouts and their replays; `None` without them.
fn clearance_figure(root: &Path) -> Option<Vec<u8>> {
    let dir = root.join(crate::stress::STAGE);
    let records = nerfsv_validation::read_csv_file(&dir.join(crate::stress::ROLLOUTS_CSV)).ok()?;
    let replays =
        nerfsv_validation::read_csv_file(&dir.join(crate::stress::replay_csv(nerfsv_sim::WorldKind::Gt))).ok()?;
    let mut groups = Vec::new();
    for sampler in [nerfsv_validation::SAMPLER_MC, nerfsv_validation::SAMPLER_CEM] {
        let ours: Vec<_> = records.iter().filter(|r| r.sampler == sampler).cloned().collect();
        let theirs: Vec<_> = replays.iter().filter(|r| r.sampler == sampler).cloned().collect();
        let Ok(a) = nerfsv_validation::compare(&ours, &theirs) else { continue };
        let mm = |v: &[f64]| v.iter().map(|x| 1e3 * x).collect::<Vec<f64>>();
        let name = sampler.to_uppercase();
        groups.push(nerfsv_plot::Group {
            label: format!("{name}, per trajectory"),
            values: mm(&a.clearance_difference.values),
        });
        groups.push(nerfsv_plot::Group {
            label: format!("{name}, per step"),
            values: mm(&a.step_clearance_difference.values),
        });
    }
    groups.retain(|g| !g.values.is_empty());
    if groups.is_empty() {
        return None;
    }
    let fig = nerfsv_plot::HistogramFigure {
        title: "NeRF-sim against GT-sim: |Δ minimum clearance| on the same disturbances".into(),
        x_title: "|clearance difference| (mm)".into(),
        y_title: "count".into(),
        groups,
        bins: 30,
    };
    nerfsv_plot::histograms_png(&fig, 1100, 700).ok()
}

/// What the report holds.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ReportFigures {
    pub index: PathBuf,
    pub pictures: usize,
    pub tables: usize,
    /// Stages without a record in the folder (their sections say so).
    pub missing_stages: Vec<String>,
}

/// Builds `root/report/` from the run folder `root` (which must hold a `summary.json`);
/// `config` is the run config as TOML, if known (else a `report/config.toml` already there is
/// shown).
pub fn write_report(root: &Path, config: Option<&str>) -> Result<ReportFigures, PipelineError> {
    let summary_file = summary_path(root);
    let text = std::fs::read_to_string(&summary_file).map_err(|e| PipelineError::io(&summary_file, e))?;
    let summary: Value = serde_json::from_str(&text)
        .map_err(|e| PipelineError::Internal(format!("{}: not a run summary: {e}", summary_file.display())))?;
    let dir = root.join(REPORT);
    // Everything is gathered first and written all or nothing (`uq::write_files`).
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let config = match config {
        Some(c) => {
            files.push((CONFIG.to_owned(), c.as_bytes().to_vec()));
            Some(c.to_owned())
        }
        None => std::fs::read_to_string(dir.join(CONFIG)).ok(),
    };
    files.push(("summary.json".to_owned(), text.into_bytes()));
    let mut tables = Vec::new();
    for (stage, file, name) in TABLES {
        if let Ok(bytes) = std::fs::read(root.join(stage).join(file)) {
            files.push((name.to_string(), bytes));
            tables.push(*name);
        }
    }
    let mut pictures = Vec::new();
    for (stage, file, caption) in PICTURES {
        if let Ok(bytes) = std::fs::read(root.join(stage).join(file)) {
            let name = if file.starts_with(stage) { file.to_string() } else { format!("{stage}_{file}") };
            files.push((name.clone(), bytes));
            pictures.push((*stage, name, *caption));
        }
    }
    let drawn = [
        (
            "nerf_collision",
            FIELDS_PNG,
            "Signed distance at flight altitude: ground truth, NeRF, and their difference",
            field_slices_figure(root, &summary),
        ),
        (
            "stress",
            CLEARANCE_PNG,
            "|clearance in NeRF-sim − in GT-sim| on the same disturbances",
            clearance_figure(root),
        ),
    ];
    for (stage, name, caption, png) in drawn {
        if let Some(png) = png {
            files.push((name.to_owned(), png));
            pictures.push((stage, name.to_owned(), caption));
        }
    }
    let mut seconds = Vec::new();
    let mut missing = Vec::new();
    for (stage, what) in STAGES {
        let record = std::fs::read_to_string(root.join(stage).join(RECORD))
            .ok()
            .and_then(|t| serde_json::from_str::<Value>(&t).ok());
        match record.and_then(|r| r["seconds"].as_f64()) {
            Some(s) => seconds.push((*stage, *what, s)),
            None => missing.push(stage.to_string()),
        }
    }
    let html = page(&summary, config.as_deref(), &seconds, &pictures, &tables);
    files.push((INDEX.to_owned(), html.into_bytes()));
    crate::uq::write_files(&dir, &files)?;
    Ok(ReportFigures {
        index: dir.join(INDEX),
        pictures: pictures.len(),
        tables: tables.len(),
        missing_stages: missing,
    })
}

/// `s` with the HTML special characters escaped.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// A number for a table: `digits` decimals, or "–" when absent.
fn num(v: &Value, digits: usize) -> String {
    v.as_f64().map_or("–".into(), |x| format!("{x:.digits$}"))
}

/// Metres as millimetres, one decimal.
fn mm(v: &Value) -> String {
    v.as_f64().map_or("–".into(), |x| format!("{:.1}", 1e3 * x))
}

/// A percentage of a fraction.
fn pct(v: &Value) -> String {
    v.as_f64().map_or("–".into(), |x| format!("{:.1} %", 100.0 * x))
}

fn table(out: &mut String, header: &[&str], rows: &[Vec<String>]) {
    out.push_str("<table><thead><tr>");
    for h in header {
        let _ = write!(out, "<th>{}</th>", esc(h));
    }
    out.push_str("</tr></thead><tbody>");
    for r in rows {
        out.push_str("<tr>");
        for c in r {
            // Numbers align right, words left.
            let numeric = c.trim_end_matches(" %").parse::<f64>().is_ok() || c == "–";
            let class = if numeric { "" } else { " class=\"t\"" };
            let _ = write!(out, "<td{class}>{}</td>", esc(c));
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>\n");
}

fn figure(out: &mut String, file: &str, caption: &str) {
    let _ = writeln!(
        out,
        "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        esc(file),
        esc(caption),
        esc(caption)
    );
}

/// The report's sections after the answer, `(anchor, title)`, in page order.
const CONTENTS: &[(&str, &str)] = &[
    ("eval", "NeRF"),
    ("nerf_collision", "collision fields"),
    ("flight", "nominal flights"),
    ("stress", "stress tests"),
    ("online", "Tables 1–2"),
    ("uq", "offline uncertainty"),
    ("config", "run config"),
    ("stages", "stage timings"),
];

/// The study's answer, first on the page: how likely the drone fails under the disturbance
/// prior (subset simulation's estimate where the stress stage ran it, else Monte Carlo's), how
/// NeRF-sim's failures carry over to GT-sim, the most likely failure, and the uncertainty
/// figures that say how far the NeRF can be trusted. Each line only when its stage ran.
fn answer(o: &mut String, summary: &Value) {
    let mut lines: Vec<String> = Vec::new();
    let samplers = summary["stress"]["samplers"].as_array().cloned().unwrap_or_default();
    let find = |name: &str| samplers.iter().find(|s| s["sampler"].as_str() == Some(name));
    let world = |s: &Value| {
        format!("{}-sim, {} estimator", s["world"].as_str().unwrap_or("?"), s["estimator"].as_str().unwrap_or("?"))
    };
    if let Some(s) = find("subset").or_else(|| find("mc")) {
        let i = &s["p_fail_interval"];
        let how = if s["sampler"].as_str() == Some("subset") {
            format!("subset simulation, {} rollouts", num(&s["rollouts"], 0))
        } else {
            format!("Monte Carlo, {} rollouts", num(&s["rollouts"], 0))
        };
        let mut line = format!(
            "<b>How likely does the drone crash</b> under the disturbance prior ({})? P(fail) = {}, 95 % interval [{}, {}] ({how})",
            esc(&world(s)),
            num(&s["p_fail"], 3),
            num(&i[0], 3),
            num(&i[1], 3),
        );
        if let (Some(mc), Some("subset")) = (find("mc"), s["sampler"].as_str()) {
            let j = &mc["p_fail_interval"];
            let _ = write!(
                line,
                "; Monte Carlo alone: {} of {} [{}, {}]",
                pct(&mc["p_fail"]),
                num(&mc["rollouts"], 0),
                num(&j[0], 3),
                num(&j[1], 3)
            );
        }
        lines.push(line + ".");
    }
    if let Some(c) = find("mc").map(|s| &s["confusion"]).filter(|c| c.is_object()) {
        let t = &c["trajectories"];
        let n = |k: &str| t[k].as_u64().unwrap_or(0);
        let (tp, fp, fneg, tn) = (n("true_positive"), n("false_positive"), n("false_negative"), n("true_negative"));
        lines.push(format!(
            "<b>Do NeRF-sim's failures hold in GT-sim?</b> Of the Monte Carlo rollouts, {} crashed in NeRF-sim and {} in \
             GT-sim with the same disturbances; {tp} crashed in both (precision {}, recall {}), {fp} only in NeRF-sim, \
             {fneg} only in GT-sim, {tn} in neither.",
            tp + fp,
            tp + fneg,
            num(&c["precision"], 2),
            num(&c["recall"], 2),
        ));
    }
    if let Some(f) = find("cem").or_else(|| find("mc")).map(|s| &s["most_likely_failure"]).filter(|f| f.is_object()) {
        let replay = match f["replay_collided"].as_bool() {
            Some(true) => "it crashes in GT-sim too",
            Some(false) => "it does not crash in GT-sim",
            None => "not replayed",
        };
        lines.push(format!(
            "<b>The most likely failure</b> found ({} {}/{}): log-likelihood {}, collision at step {}; {replay}.",
            esc(&f["sampler"].as_str().unwrap_or("?").to_uppercase()),
            num(&f["population"], 0),
            num(&f["index"], 0),
            num(&f["log_likelihood"], 2),
            num(&f["collision_step"], 0),
        ));
    }
    let u = &summary["uq"]["test"];
    if u.is_object() {
        lines.push(format!(
            "<b>How far can the NeRF be trusted?</b> On its test images GA's noise-floored σ_d has median {} (the \
             paper's σ_d: {}, {} of {} images excluded at σ_d ≥ 3); BLA's information gain averages {} nats; depth \
             AUSE GA {}, BLA {} (lower ranks errors better).",
            num(&u["ga_floored_median_sigma_d"], 3),
            num(&u["ga_median_sigma_d"], 2),
            num(&u["ga_excluded"], 0),
            num(&u["ga_images"], 0),
            num(&u["bla_mean_information_gain"], 1),
            num(&summary["uq"]["ause_ga"], 3),
            num(&summary["uq"]["ause_bla"], 3),
        ));
    }
    let studies = summary["online"]["studies"].as_array().cloned().unwrap_or_default();
    if !studies.is_empty() {
        let parts: Vec<String> = studies
            .iter()
            .map(|m| {
                let d = &m["disagreement"];
                format!(
                    "{} {} ({} of {} steps disagree)",
                    esc(&m["method"].as_str().unwrap_or("?").to_uppercase()),
                    num(&d["step_auroc"], 2),
                    num(&d["disagreeing_steps"], 0),
                    num(&d["steps"], 0)
                )
            })
            .collect();
        lines.push(format!(
            "<b>Does the uncertainty flag where NeRF-sim and GT-sim disagree?</b> AUROC of a step's uncertainty for a \
             disagreeing step (0.5 is chance): {}.",
            parts.join(", ")
        ));
    }
    o.push_str("<h2 id=\"answer\">The study's answer</h2>\n");
    if lines.is_empty() {
        o.push_str("<p class=\"missing\">No stage that answers it has run in this folder.</p>\n");
        return;
    }
    o.push_str("<ul class=\"answer\">\n");
    for l in lines {
        let _ = writeln!(o, "<li>{l}</li>");
    }
    o.push_str("</ul>\n");
}

fn page(
    summary: &Value,
    config: Option<&str>,
    seconds: &[(&str, &str, f64)],
    pictures: &[(&str, String, &str)],
    tables: &[&str],
) -> String {
    let mut o = String::new();
    o.push_str(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>nerfsv report</title>\n<style>\n\
         body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}\n\
         table{border-collapse:collapse;margin:0.8em 0;font-size:0.9em;max-width:100%}\n\
         th,td{border:1px solid #bbb;padding:0.25em 0.6em;text-align:right}\n\
         th{background:#eee;text-align:left}td:first-child,td.t{text-align:left}\n\
         figure{display:inline-block;margin:0.5em;max-width:100%;vertical-align:top}\n\
         img{max-width:100%;height:auto;border:1px solid #ddd}figcaption{font-size:0.85em;color:#555}\n\
         pre{background:#f6f6f6;padding:0.8em;overflow:auto;max-height:30em;font-size:0.8em}\n\
         .missing{color:#a00}ul.answer li{margin:0.4em 0}nav{font-size:0.9em}\n</style></head><body>\n<h1>nerfsv report</h1>\n",
    );
    let _ = writeln!(o, "<p>Run folder: <code>{}</code></p>", esc(summary["run"].as_str().unwrap_or("?")));
    answer(&mut o, summary);
    o.push_str("<nav><p>Contents:");
    for (i, (id, title)) in CONTENTS.iter().enumerate() {
        let _ = write!(o, "{} <a href=\"#{id}\">{}</a>", if i == 0 { "" } else { " ·" }, esc(title));
    }
    o.push_str("</p></nav>\n");
    let section = |o: &mut String, stage: &str, title: &str| -> bool {
        let _ = writeln!(o, "<h2 id=\"{}\">{}</h2>", esc(stage), esc(title));
        if summary.get(stage).is_none() {
            let _ = writeln!(o, "<p class=\"missing\">The {} stage has not run in this folder.</p>", esc(stage));
            return false;
        }
        true
    };
    let pictures_of = |o: &mut String, stage: &str| {
        for (_, file, caption) in pictures.iter().filter(|(s, ..)| *s == stage) {
            figure(o, file, caption);
        }
    };

    if section(&mut o, "eval", "The NeRF against the ground truth") {
        let e = &summary["eval"];
        table(
            &mut o,
            &["test images", "PSNR (dB)", "SSIM", "median depth error (m)"],
            &[vec![num(&e["images"], 0), num(&e["psnr"], 2), num(&e["ssim"], 3), num(&e["depth_median_abs_err_m"], 4)]],
        );
        pictures_of(&mut o, "eval");
    }
    if section(&mut o, "nerf_collision", "Collision fields: the NeRF's against the ground truth") {
        let a = &summary["nerf_collision"]["agreement_with_ground_truth"];
        table(
            &mut o,
            &["occupancy IoU", "IoU in the flight band", "|SDF diff| mean (m)", "|SDF diff| p95 (m)"],
            &[vec![
                num(&a["iou"], 3),
                num(&a["band_iou"], 3),
                num(&a["band_mean_abs_diff"], 4),
                num(&a["band_p95_abs_diff"], 4),
            ]],
        );
        pictures_of(&mut o, "nerf_collision");
    }
    if section(&mut o, "flight", "Nominal flights") {
        let rows: Vec<Vec<String>> = summary["flight"]["flights"]
            .as_array()
            .map(|fs| {
                fs.iter()
                    .map(|f| {
                        vec![
                            format!(
                                "{}-sim, {}",
                                f["world"].as_str().unwrap_or("?"),
                                f["estimator"].as_str().unwrap_or("?")
                            ),
                            f["collided"].as_bool().map_or("–".into(), |c| if c { "yes" } else { "no" }.into()),
                            num(&f["min_clearance_m"], 3),
                            f["reached_goal"].as_bool().map_or("–".into(), |c| if c { "yes" } else { "no" }.into()),
                            num(&f["mean_position_error_m"], 4),
                            num(&f["mean_rotation_error_deg"], 2),
                            format!("{} / {}", num(&f["images"], 0), num(&f["rejected_images"], 0)),
                            num(&f["mean_nees"], 1),
                        ]
                    })
                    .collect()
            })
            .unwrap_or_default();
        table(
            &mut o,
            &[
                "flight",
                "collided",
                "min clearance (m)",
                "reached goal",
                "mean position error (m)",
                "mean rotation error (°)",
                "images / rejected by the gate",
                "mean NEES (12 if consistent)",
            ],
            &rows,
        );
        o.push_str(
            "<p>The vision estimator is a filter on the 12-D state whose measurement is the camera image aligned \
             against the NeRF; errors are after each image's update, NEES is the normalised estimation error squared \
             of the whole state (χ²(12) when the filter's covariance is honest).</p>\n",
        );
        pictures_of(&mut o, "flight");
    }
    if section(&mut o, "stress", "Stress tests: failure probability and NeRF-sim against GT-sim") {
        let samplers = summary["stress"]["samplers"].as_array().cloned().unwrap_or_default();
        let rows: Vec<Vec<String>> = samplers
            .iter()
            .map(|s| {
                let i = &s["p_fail_interval"];
                vec![
                    s["sampler"].as_str().unwrap_or("?").to_uppercase(),
                    num(&s["rollouts"], 0),
                    // The rate is over the search's own rollouts (CEM: its populations, not the
                    // importance batch), which the first row of the sampler's table counts.
                    format!("{} of {}", pct(&s["collision_rate"]), num(&s["table"][0]["rollouts"], 0)),
                    pct(&s["lost_rate"]),
                    num(&s["avg_collision_step"], 2),
                    num(&s["avg_log_likelihood"], 2),
                    format!("{} ± {}", num(&s["p_fail"], 3), num(&s["p_fail_se"], 3)),
                    format!("[{}, {}]", num(&i[0], 3), num(&i[1], 3)),
                ]
            })
            .collect();
        let how: Vec<Vec<String>> = samplers
            .iter()
            .map(|s| {
                vec![
                    s["sampler"].as_str().unwrap_or("?").to_uppercase(),
                    esc(s["p_fail_estimator"].as_str().unwrap_or("?")),
                    format!("{} / {}", num(&s["effective_sample_size"], 1), num(&s["effective_failures"], 1)),
                    num(&s["p_fail_unnormalised"], 3),
                ]
            })
            .collect();
        table(
            &mut o,
            &[
                "sampler",
                "rollouts flown",
                "collision rate of the searched",
                "lost",
                "avg. collision step",
                "avg. log-likelihood",
                "P(fail) ± SE",
                "95 % interval",
            ],
            &rows,
        );
        table(
            &mut o,
            &["sampler", "P(fail) estimator", "effective rollouts / failures", "paper's plain IS estimate"],
            &how,
        );
        o.push_str(
            "<p>Lost: rollouts whose state stopped being finite or left the field's grid without a collision, \
             neither passes nor failures. The CEM's P(fail) is the importance-sampling estimate with the weight as \
             control variate (its expectation under the proposal is 1), clamped to [0, 1]; the paper's plain estimate \
             (1/N) Σ 𝟙·p/q, unbiased but able to exceed 1, stands beside it. Effective rollouts and failures are \
             Kish's sizes (Σw)²/Σw² of the batch's and of the failures' weights: the number of rollouts the \
             estimate effectively rests on. SUBSET is subset simulation (Au & Beck): level 0 is independent draws \
             from the prior (the MC rollouts, then its own), each next level Markov chains held below the last \
             level's p0-quantile of the clearance (10 % by default); P(fail) is the product of the levels' shares, its SE Au & \
             Beck's bound from the chains' correlation, and its effective rollouts the Monte Carlo rollouts with \
             the same variance. It is the estimator whose ±2 SE interval covers the truth at 10⁻³ and 0.08 on a \
             72-dimensional test problem with these settings (the CEM's does not: BENCHMARKS.md); its rollouts are \
             driven towards failure, so their collision rate is not a rate of anything.</p>\n",
        );
        let rows: Vec<Vec<String>> = samplers
            .iter()
            .filter(|s| s["confusion"].is_object())
            .map(|s| {
                let c = &s["confusion"];
                let t = &c["trajectories"];
                let d = &c["clearance_difference_m"];
                vec![
                    s["sampler"].as_str().unwrap_or("?").to_uppercase(),
                    num(&t["true_positive"], 0),
                    num(&t["false_positive"], 0),
                    num(&t["false_negative"], 0),
                    num(&t["true_negative"], 0),
                    num(&c["accuracy"], 3),
                    num(&c["precision"], 3),
                    num(&c["recall"], 3),
                    format!("{} / {} / {}", num(&d["median"], 4), num(&d["p90"], 4), num(&d["max"], 4)),
                ]
            })
            .collect();
        o.push_str("<p>Confusion of NeRF-sim (prediction) against GT-sim (truth) over each search's rollouts, failure positive:</p>\n");
        table(
            &mut o,
            &[
                "sampler",
                "TP",
                "FP",
                "FN",
                "TN",
                "accuracy",
                "precision",
                "recall",
                "|Δclearance| median / p90 / max (m)",
            ],
            &rows,
        );
        let errors: Vec<Vec<String>> = summary["stress"]["estimate_errors"]
            .as_array()
            .map(|es| {
                es.iter()
                    .map(|e| {
                        vec![
                            format!("{}-sim", e["world"].as_str().unwrap_or("?")),
                            num(&e["images"], 0),
                            format!("{} / {}", mm(&e["median_position_m"]), mm(&e["p90_position_m"])),
                            format!("{} / {}", num(&e["median_attitude_deg"], 2), num(&e["p90_attitude_deg"], 2)),
                        ]
                    })
                    .collect()
            })
            .unwrap_or_default();
        if !errors.is_empty() {
            o.push_str(
                "<p>The vision estimator's error after each image update, over every rollout the stage flew (the \
                 searches in NeRF-sim and their replays in GT-sim):</p>\n",
            );
            table(
                &mut o,
                &["world", "images", "position error median / p90 (mm)", "attitude error median / p90 (°)"],
                &errors,
            );
        }
        pictures_of(&mut o, "stress");
    }
    if section(&mut o, "online", "Tables 1–2: uncertainty in the search, with and without reward") {
        let online = &summary["online"];
        let _ = writeln!(
            o,
            "<p>A step's uncertainty is the view's GA {} or BLA {} (<code>uq.ga_measure</code>, \
             <code>uq.bla_measure</code>).</p>",
            esc(online["ga_measure"].as_str().unwrap_or("σ_d")),
            esc(online["bla_measure"].as_str().unwrap_or("rmv · normalised trace")),
        );
        for m in online["studies"].as_array().cloned().unwrap_or_default() {
            let method = m["method"].as_str().unwrap_or("?").to_uppercase();
            let d = &m["disagreement"];
            let _ = writeln!(
                o,
                "<h3>{} ({} mode)</h3><p>AUROC of the step's uncertainty for a NeRF-sim/GT-sim disagreement: {} ({} of {} steps \
                 disagree); of a rollout's mean: {} ({} of {}).</p>",
                esc(&method),
                esc(online["mode"].as_str().unwrap_or("?")),
                num(&d["step_auroc"], 3),
                num(&d["disagreeing_steps"], 0),
                num(&d["steps"], 0),
                num(&d["trajectory_auroc"], 3),
                num(&d["disagreeing_trajectories"], 0),
                num(&d["trajectories"], 0),
            );
            let rows: Vec<Vec<String>> = m["rows"]
                .as_array()
                .map(|rs| {
                    rs.iter()
                        .map(|r| {
                            vec![
                                r["sampler"].as_str().unwrap_or("?").to_uppercase(),
                                if r["reward"].as_bool() == Some(true) { "yes" } else { "no" }.into(),
                                num(&r["rollouts"], 0),
                                pct(&r["collision_rate"]),
                                pct(&r["lost_rate"]),
                                num(&r["avg_collision_step"], 2),
                                num(&r["avg_log_likelihood"], 2),
                                num(&r["avg_uncertainty"], 4),
                                num(&r["avg_reward"], 2),
                            ]
                        })
                        .collect()
                })
                .unwrap_or_default();
            table(
                &mut o,
                &[
                    "sampler",
                    "reward",
                    "rollouts",
                    "collision rate",
                    "lost",
                    "avg. collision step",
                    "avg. log-likelihood",
                    "avg. uncertainty",
                    "avg. reward",
                ],
                &rows,
            );
        }
        o.push_str(
            "<p>The reward is the trajectory log-likelihood (a sum over the steps) less the penalty times the \
             rollout's <em>mean</em> per-step uncertainty (BLA's also times the paper's n perturbations), as in the \
             paper's eqs. 10–11; a rollout with no measured step has reward −∞ and ranks last, and the average \
             reward is over the rollouts with a finite one.</p>\n",
        );
    }
    if section(&mut o, "uq", "Offline uncertainty per image, and its calibration") {
        let u = &summary["uq"];
        let rows: Vec<Vec<String>> = ["train", "val", "test"]
            .iter()
            .map(|s| {
                let x = &u[*s];
                vec![
                    s.to_string(),
                    num(&x["ga_images"], 0),
                    num(&x["ga_excluded"], 0),
                    num(&x["ga_mean_sigma_d"], 3),
                    num(&x["ga_median_sigma_d"], 3),
                    num(&x["ga_floored_excluded"], 0),
                    num(&x["ga_floored_mean_sigma_d"], 3),
                    num(&x["ga_floored_median_sigma_d"], 3),
                ]
            })
            .collect();
        let bla_rows: Vec<Vec<String>> = ["train", "val", "test"]
            .iter()
            .map(|s| {
                let x = &u[*s];
                vec![
                    s.to_string(),
                    num(&x["bla_images"], 0),
                    num(&x["bla_mean_normalized_trace"], 4),
                    num(&x["bla_mean_rmv"], 4),
                    num(&x["bla_mean_information_gain"], 1),
                ]
            })
            .collect();
        table(
            &mut o,
            &[
                "split",
                "GA images",
                "excluded (σ_d ≥ 3)",
                "mean σ_d",
                "median σ_d",
                "noise-floored: excluded (≥ 3)",
                "mean σ_d",
                "median σ_d",
            ],
            &rows,
        );
        table(
            &mut o,
            &["split", "BLA images", "mean normalised trace", "mean rmv", "mean information gain (nats)"],
            &bla_rows,
        );
        o.push_str(
            "<p>GA's σ_d is the paper's eq. 2, which has no pixel-noise term: a nearly transparent ray (tiny \
             s = Σ c²d²) turns any noise in its colour into a huge (r − μm)²/s and drives σ_d, which is why the \
             paper's σ_d ≥ 3 exclusion removes many images. The noise-floored σ_d fits r ~ N(μm, σ_d²s + σ_n²) with \
             σ_n the pixel noise (uq.noise_std): 0 when the model explains the image up to its noise; it is shown \
             beside the paper's, and the online measure and reward use it by default (uq.ga_measure). GA's \
             per-pixel maps keep the paper's σ_d: a map is σ_d times a per-pixel factor, so its ranking, which the \
             AUSE measures, does not depend on it. Over the white background, colours are taken relative to it \
             (c − bg, r = reference − bg): scaling the weights by μ scales the opacity too, so μ = 0.8 is exactly the \
             render with every weight scaled by 0.8 (the paper writes eq. 2 without a background).</p>\n",
        );
        o.push_str(
            "<p>BLA's prior is centred at the trained weights. The normalised trace tr(Σ)/P and rmv are the \
             paper's (its eq. 11 reward uses their product); in the directions an image's rays do not see, Σ is the \
             prior's 1/α, so with m residuals and P weights the trace cannot fall below (P − m)/(P·α): it mostly \
             measures the prior. The information gain ½ Σ<sub>k</sub> ln(1 + e<sub>k</sub>/(σ<sub>n</sub>²α)) \
             counts only the data's directions: 0 for an image that constrains nothing.</p>\n",
        );
        table(
            &mut o,
            &["method", "test images", "depth AUSE (0 is perfect)"],
            &[
                vec!["GA".into(), num(&u["ause_ga_images"], 0), num(&u["ause_ga"], 3)],
                vec!["BLA".into(), num(&u["ause_bla_images"], 0), num(&u["ause_bla"], 3)],
            ],
        );
        o.push_str(
            "<p>Depth AUSE protocol: every test pixel with a ground-truth depth counts; a pixel whose ray composites \
             no sample has no uncertainty and ranks as the most uncertain (removed first), not dropped. Bayes' Rays \
             score only the pixels their method gives a value, so where many pixels are unscored the figures are not \
             directly comparable (ause.csv counts them per image).</p>\n",
        );
        pictures_of(&mut o, "uq");
    }
    o.push_str("<h2 id=\"config\">Run config</h2>\n");
    match config {
        Some(c) => {
            let _ = writeln!(o, "<pre>{}</pre>", esc(c));
        }
        None => o.push_str("<p class=\"missing\">No config was recorded with this report.</p>\n"),
    }
    o.push_str("<h2 id=\"stages\">Stage timings</h2>\n");
    let rows: Vec<Vec<String>> =
        seconds.iter().map(|(s, what, t)| vec![s.to_string(), what.to_string(), format!("{t:.1}")]).collect();
    table(&mut o, &["stage", "what", "seconds (when it last ran)"], &rows);
    o.push_str("<p>Files: <a href=\"summary.json\">summary.json</a>");
    for name in tables {
        let _ = write!(o, ", <a href=\"{0}\">{0}</a>", esc(name));
    }
    o.push_str(".</p>\n</body></html>\n");
    o
}
