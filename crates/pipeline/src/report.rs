//! The report of a run folder (`RUN/report/`): one self-contained HTML page of the study's
//! tables and pictures, assembled from the sections its stages left, with the pictures and
//! tables copied beside it, `summary.json` and the run's config.
//!
//! Each stage builds its own [`Section`] from its typed figures ([`crate::Report`]); the
//! [`crate::Runner`] keeps it in the stage's folder (`NAME/report.json`) after every run, up to
//! date or not. This module only lays the sections out: the study's answer first (the lines
//! the sections contribute, by their order), the contents, the sections in the order the
//! stages ran (`summary.json`'s), the config, and the stage timings last. It is cheap and is
//! rebuilt at the end of every `nerfsv run` and by `nerfsv report RUN_DIR`. A stage the
//! summary lists whose record is gone says so in its place.
//!
//! A section reads its stage's figures as typed fields, so a figure renamed in its stage is a
//! compile error in the section, not a "–" on the page:
//!
//! ```compile_fail
//! use nerfsv_pipeline::report::Section;
//! use nerfsv_pipeline::stages::EvalFigures;
//!
//! fn eval_section(f: &EvalFigures) -> Section {
//!     let mut s = Section::new("eval", "The NeRF against the ground truth", "NeRF");
//!     s.paragraph(format!("PSNR {:.2} dB", f.psnr_db)); // the field is `psnr`
//!     s
//! }
//! ```

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::layout::{summary_path, RECORD, REPORT_SECTION};
use crate::PipelineError;

/// The report's folder under the run folder, and its page.
pub const REPORT: &str = "report";
pub const INDEX: &str = "index.html";
/// The run config the report shows, written beside the page (without the run folder's path).
pub const CONFIG: &str = "config.toml";

/// What a stage leaves for the report in its folder ([`REPORT_SECTION`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    /// What the stage computes ([`crate::Report::ABOUT`]).
    pub about: String,
    pub section: Option<Section>,
}

/// A stage's section of the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Section {
    /// Anchor of the section (the stage's name by convention).
    pub id: String,
    /// Heading, and the contents' link text.
    pub title: String,
    pub contents: String,
    /// Lines of the study's answer at the top of the page (HTML).
    pub answer: Vec<AnswerLine>,
    /// The section's body, in page order.
    pub body: Vec<Block>,
    /// Files of the stage's folder offered as CSV: `(file, name in the report)`.
    pub csv: Vec<(String, String)>,
}

/// One line of the study's answer: the answer's lines are shown by `order`, whichever stage
/// gives them (the failure probability 10, how failures transfer to GT-sim 20, the most likely
/// failure 30, the uncertainty 40 and 50).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnswerLine {
    pub order: u32,
    pub html: String,
}

/// A part of a section's body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Block {
    /// HTML as given (the section escapes what it inserts).
    Html(String),
    Table(Table),
    /// A picture of the stage's folder (copied into the report when it exists).
    Picture {
        file: String,
        caption: String,
    },
}

/// A table; its cells are escaped when the page is written.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    pub fn new(header: &[&str]) -> Self {
        Self { header: header.iter().map(|h| h.to_string()).collect(), rows: Vec::new() }
    }

    /// The table with one more row.
    pub fn row(mut self, cells: Vec<String>) -> Self {
        self.rows.push(cells);
        self
    }

    /// The table with these rows added.
    pub fn rows(mut self, rows: impl IntoIterator<Item = Vec<String>>) -> Self {
        self.rows.extend(rows);
        self
    }

    /// The table as HTML (for an answer line).
    pub fn html(&self) -> String {
        let mut out = String::new();
        table(&mut out, &self.header, &self.rows);
        out
    }
}

impl Section {
    pub fn new(id: &str, title: &str, contents: &str) -> Self {
        Self { id: id.into(), title: title.into(), contents: contents.into(), ..Self::default() }
    }

    /// A line of the study's answer (HTML) at `order`.
    pub fn answer(&mut self, order: u32, html: String) {
        self.answer.push(AnswerLine { order, html });
    }

    /// A paragraph of HTML.
    pub fn paragraph(&mut self, html: impl Into<String>) {
        self.body.push(Block::Html(format!("<p>{}</p>\n", html.into())));
    }

    /// HTML as given.
    pub fn html(&mut self, html: impl Into<String>) {
        self.body.push(Block::Html(html.into()));
    }

    pub fn table(&mut self, table: Table) {
        self.body.push(Block::Table(table));
    }

    /// A picture from the stage's folder.
    pub fn picture(&mut self, file: &str, caption: &str) {
        self.body.push(Block::Picture { file: file.into(), caption: caption.into() });
    }

    /// A CSV file of the stage's folder, copied into the report as `name`.
    pub fn csv(&mut self, file: &str, name: &str) {
        self.csv.push((file.into(), name.into()));
    }
}

/// What the report holds.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ReportFigures {
    pub index: PathBuf,
    pub pictures: usize,
    pub tables: usize,
    /// Stages the summary lists without a record in the folder (their sections say so).
    pub missing_stages: Vec<String>,
}

/// The stage names of a run summary in the order the stages ran: its keys after `run`.
fn stage_order(text: &str) -> Result<Vec<String>, serde_json::Error> {
    struct Keys(Vec<String>);
    impl<'de> Deserialize<'de> for Keys {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct Visitor;
            impl<'de> serde::de::Visitor<'de> for Visitor {
                type Value = Vec<String>;

                fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                    f.write_str("an object of stage figures")
                }

                fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Vec<String>, A::Error> {
                    let mut keys = Vec::new();
                    while let Some(key) = map.next_key::<String>()? {
                        map.next_value::<serde::de::IgnoredAny>()?;
                        keys.push(key);
                    }
                    Ok(keys)
                }
            }
            d.deserialize_map(Visitor).map(Keys)
        }
    }
    let Keys(keys) = serde_json::from_str(text)?;
    Ok(keys.into_iter().filter(|k| k != "run").collect())
}

/// One stage as the page shows it.
struct Shown {
    name: String,
    /// Seconds of its last run, from its record; `None`: no record (not run in this folder).
    seconds: Option<f64>,
    report: Option<StageReport>,
    /// Its pictures' names in the report folder, by file in its folder.
    pictures: Vec<(String, String)>,
}

/// Builds `root/report/` from the run folder `root` (which must hold a `summary.json`) and the
/// sections its stages left; `config` is the run config as TOML, if known (else a
/// `report/config.toml` already there is shown).
pub fn write_report(root: &Path, config: Option<&str>) -> Result<ReportFigures, PipelineError> {
    let summary_file = summary_path(root);
    let text = std::fs::read_to_string(&summary_file).map_err(|e| PipelineError::io(&summary_file, e))?;
    let not_a_summary =
        |e: serde_json::Error| PipelineError::Internal(format!("{}: not a run summary: {e}", summary_file.display()));
    let summary: serde_json::Value = serde_json::from_str(&text).map_err(not_a_summary)?;
    let order = stage_order(&text).map_err(not_a_summary)?;
    let dir = root.join(REPORT);
    // Everything is gathered first and written all or nothing.
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let config = match config {
        Some(c) => {
            files.push((CONFIG.to_owned(), c.as_bytes().to_vec()));
            Some(c.to_owned())
        }
        None => std::fs::read_to_string(dir.join(CONFIG)).ok(),
    };
    files.push(("summary.json".to_owned(), text.into_bytes()));
    let mut stages = Vec::new();
    let mut tables = Vec::new();
    for name in order {
        let stage_dir = root.join(&name);
        let seconds = std::fs::read_to_string(stage_dir.join(RECORD))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|r| r["seconds"].as_f64());
        let report = seconds.and(
            std::fs::read_to_string(stage_dir.join(REPORT_SECTION))
                .ok()
                .and_then(|t| serde_json::from_str::<StageReport>(&t).ok()),
        );
        let mut shown = Shown { name, seconds, report, pictures: Vec::new() };
        if let Some(section) = shown.report.as_ref().and_then(|r| r.section.as_ref()) {
            for (file, report_name) in &section.csv {
                if let Ok(bytes) = std::fs::read(stage_dir.join(file)) {
                    files.push((report_name.clone(), bytes));
                    tables.push(report_name.clone());
                }
            }
            for block in &section.body {
                if let Block::Picture { file, .. } = block {
                    if let Ok(bytes) = std::fs::read(stage_dir.join(file)) {
                        let as_named =
                            if file.starts_with(&shown.name) { file.clone() } else { format!("{}_{file}", shown.name) };
                        files.push((as_named.clone(), bytes));
                        shown.pictures.push((file.clone(), as_named));
                    }
                }
            }
        }
        stages.push(shown);
    }
    let run = summary["run"].as_str().unwrap_or("?");
    let html = page(run, &stages, config.as_deref(), &tables);
    files.push((INDEX.to_owned(), html.into_bytes()));
    nerfsv_uq::offline::write_files(&dir, &files)?;
    Ok(ReportFigures {
        index: dir.join(INDEX),
        pictures: stages.iter().map(|s| s.pictures.len()).sum(),
        tables: tables.len(),
        missing_stages: stages.iter().filter(|s| s.seconds.is_none()).map(|s| s.name.clone()).collect(),
    })
}

/// `s` with the HTML special characters escaped.
pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn table(out: &mut String, header: &[String], rows: &[Vec<String>]) {
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

/// The page: the study's answer, the contents, each stage's section in run order, the config,
/// the stage timings.
fn page(run: &str, stages: &[Shown], config: Option<&str>, tables: &[String]) -> String {
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
    let _ = writeln!(o, "<p>Run folder: <code>{}</code></p>", esc(run));
    let sections: Vec<&Section> =
        stages.iter().filter_map(|s| s.report.as_ref().and_then(|r| r.section.as_ref())).collect();
    // The answer: every section's lines, by their order (stable: a stage's own order kept).
    let mut lines: Vec<&AnswerLine> = sections.iter().flat_map(|s| &s.answer).collect();
    lines.sort_by_key(|l| l.order);
    o.push_str("<h2 id=\"answer\">The study's answer</h2>\n");
    if lines.is_empty() {
        o.push_str("<p class=\"missing\">No stage that answers it has run in this folder.</p>\n");
    } else {
        o.push_str("<ul class=\"answer\">\n");
        for l in lines {
            let _ = writeln!(o, "<li>{}</li>", l.html);
        }
        o.push_str("</ul>\n");
    }
    o.push_str("<nav><p>Contents:");
    let contents = sections
        .iter()
        .map(|s| (s.id.as_str(), s.contents.as_str()))
        .chain([("config", "run config"), ("stages", "stage timings")]);
    for (i, (id, title)) in contents.enumerate() {
        let _ = write!(o, "{} <a href=\"#{}\">{}</a>", if i == 0 { "" } else { " ·" }, esc(id), esc(title));
    }
    o.push_str("</p></nav>\n");
    for stage in stages {
        match (&stage.seconds, stage.report.as_ref().map(|r| &r.section)) {
            (None, _) => {
                let _ = writeln!(
                    o,
                    "<h2 id=\"{0}\">{0}</h2>\n<p class=\"missing\">The {0} stage has not run in this folder.</p>",
                    esc(&stage.name)
                );
            }
            (Some(_), None) => {
                let _ = writeln!(
                    o,
                    "<h2 id=\"{0}\">{0}</h2>\n<p class=\"missing\">The {0} stage left no report section (a run \
                     folder from an older nerfsv: <code>nerfsv run</code> on it rebuilds the sections).</p>",
                    esc(&stage.name)
                );
            }
            (Some(_), Some(None)) => {}
            (Some(_), Some(Some(section))) => {
                let _ = writeln!(o, "<h2 id=\"{}\">{}</h2>", esc(&section.id), esc(&section.title));
                for block in &section.body {
                    match block {
                        Block::Html(h) => o.push_str(h),
                        Block::Table(t) => table(&mut o, &t.header, &t.rows),
                        Block::Picture { file, caption } => {
                            if let Some((_, name)) = stage.pictures.iter().find(|(f, _)| f == file) {
                                figure(&mut o, name, caption);
                            }
                        }
                    }
                }
            }
        }
    }
    o.push_str("<h2 id=\"config\">Run config</h2>\n");
    match config {
        Some(c) => {
            let _ = writeln!(o, "<pre>{}</pre>", esc(c));
        }
        None => o.push_str("<p class=\"missing\">No config was recorded with this report.</p>\n"),
    }
    o.push_str("<h2 id=\"stages\">Stage timings</h2>\n");
    let rows: Vec<Vec<String>> = stages
        .iter()
        .map(|s| {
            vec![
                s.name.clone(),
                s.report.as_ref().map_or("–".into(), |r| r.about.clone()),
                s.seconds.map_or("not run".into(), |t| format!("{t:.1}")),
            ]
        })
        .collect();
    table(&mut o, &["stage".into(), "what".into(), "seconds (when it last ran)".into()], &rows);
    o.push_str("<p>Files: <a href=\"summary.json\">summary.json</a>");
    for name in tables {
        let _ = write!(o, ", <a href=\"{0}\">{0}</a>", esc(name));
    }
    o.push_str(".</p>\n</body></html>\n");
    o
}

/// A number for a table: `digits` decimals, or "–" when absent.
pub(crate) fn num(v: impl Into<Option<f64>>, digits: usize) -> String {
    v.into().map_or("–".into(), |x| format!("{x:.digits$}"))
}

/// Metres as millimetres, one decimal.
pub(crate) fn mm(v: f64) -> String {
    format!("{:.1}", 1e3 * v)
}

/// A percentage of a fraction.
pub(crate) fn pct(v: f64) -> String {
    format!("{:.1} %", 100.0 * v)
}

pub(crate) fn yes_no(v: bool) -> String {
    if v { "yes" } else { "no" }.into()
}

/// A rate with its interval: `3.0 % [1.0, 8.5]`.
pub(crate) fn rate_ci(value: f64, ci: [f64; 2]) -> String {
    format!("{} [{:.1}, {:.1}]", pct(value), 100.0 * ci[0], 100.0 * ci[1])
}

/// "MC 0.61 [0.51, 0.71] (18 of 548 steps disagree)": a sampler's step AUROC with its interval.
pub(crate) fn step_auroc_with_interval(a: &nerfsv_study::stress::StepAurocFigures) -> String {
    let ci = a.step_auroc_ci95.map_or(String::new(), |[lo, hi]| format!(" [{lo:.2}, {hi:.2}]"));
    format!(
        "{} {}{ci} ({} of {} steps disagree)",
        a.sampler.name().to_uppercase(),
        num(a.auroc.step_auroc, 2),
        a.auroc.disagreeing_steps,
        a.auroc.steps
    )
}

/// `k / n` with its Wilson 95 % interval, or "–" for `n = 0`.
pub(crate) fn proportion(k: usize, n: usize) -> String {
    if n == 0 {
        return "–".into();
    }
    let (lo, hi) = nerfsv_validation::wilson_interval(k, n);
    format!("{:.2} [{lo:.2}, {hi:.2}]", k as f64 / n as f64)
}

/// A proportion or coefficient with its interval, or "–".
pub(crate) fn estimate(e: Option<nerfsv_validation::Estimate>) -> String {
    e.map_or("–".into(), |e| format!("{:.2} [{:.2}, {:.2}]", e.value, e.ci95[0], e.ci95[1]))
}

/// A world as the captions name it: `GT` or `NeRF`.
pub(crate) fn world_label(world: nerfsv_sim::WorldKind) -> &'static str {
    match world {
        nerfsv_sim::WorldKind::Gt => "GT",
        nerfsv_sim::WorldKind::Nerf => "NeRF",
    }
}
