//! The README's opening figures are those of the run its first picture shows:
//! `docs/img/report.png` is a screenshot of the report of the run whose `summary.json` is
//! committed beside it as `docs/img/report_summary.json`. Each figure the README quotes is
//! formatted here from that summary and looked for in the README, so a README edited without a
//! new picture of its run (or a picture replaced without its summary) fails.

use std::path::Path;

use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A percentage with its interval, as the README writes a rate: `16 % [10.1, 24.4]`.
fn rate(v: &Value) -> String {
    let ci = &v["ci95"];
    format!("{:.0} % [{:.1}, {:.1}]", 100.0 * f(&v["rate"]), 100.0 * f(&ci[0]), 100.0 * f(&ci[1]))
}

/// A proportion with its interval: `0.25 [0.10, 0.49]`.
fn proportion(v: &Value) -> String {
    format!("{:.2} [{:.2}, {:.2}]", f(&v["value"]), f(&v["ci95"][0]), f(&v["ci95"][1]))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number in the summary: {v}"))
}

#[test]
fn the_readme_quotes_the_run_its_picture_shows() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    // Line breaks and indentation are layout: compare with single spaces.
    let readme = readme.split_whitespace().collect::<Vec<_>>().join(" ");
    assert!(readme.contains("![The report](docs/img/report.png)"), "the README's first picture");
    assert!(root().join("docs/img/report.png").is_file());
    let text = std::fs::read_to_string(root().join("docs/img/report_summary.json")).unwrap();
    let summary: Value = serde_json::from_str(&text).unwrap();
    let transfer = &summary["stress"]["transfer"];
    let calibrated = &transfer["calibrated"];
    let predictive = &transfer["nerf_calibrated"]["predictive95"];
    let sampler = |name: &str| {
        summary["stress"]["samplers"].as_array().unwrap().iter().find(|s| s["sampler"] == name).unwrap().clone()
    };
    let (cem, subset) = (sampler("cem"), sampler("subset"));
    let cem_confusion = &cem["confusion"]["trajectories"];
    let (tp, fp) =
        (cem_confusion["true_positive"].as_u64().unwrap(), cem_confusion["false_positive"].as_u64().unwrap());
    let cem_row = |measure: &str| {
        let rows = summary["online"]["step_auroc"].as_array().unwrap();
        rows.iter().find(|r| r["measure"] == measure && r["sampler"] == "cem").unwrap().clone()
    };
    let auroc = |measure: &str| {
        let pooled = &cem_row(measure)["pooled"];
        format!("{:.2} [{:.2}, {:.2}]", f(&pooled["auroc"]), f(&pooled["ci95"][0]), f(&pooled["ci95"][1]))
    };
    let ga = cem_row("ga");
    let interval = &subset["p_fail_interval"];
    let quoted = [
        format!("crash the drone {} in the ground truth", rate(&transfer["gt"])),
        format!("and {} in NeRF-sim's calibrated world", rate(&transfer["nerf_calibrated"])),
        format!("crashes in [{:.1}, {:.1}] %", 100.0 * f(&predictive[0]), 100.0 * f(&predictive[1])),
        format!(
            "finds {} of GT-sim's {} failures",
            calibrated["confusion"]["true_positive"], transfer["gt"]["failures"]
        ),
        format!("recall {}", proportion(&calibrated["recall"])),
        format!("precision {}", proportion(&calibrated["precision"])),
        format!("{tp} of {} crash in GT-sim too", tp + fp),
        format!("{:.2} [{:.3}, {:.3}] (subset simulation", f(&subset["p_fail"]), f(&interval[0]), f(&interval[1])),
        format!(
            "(AUROC GA {}, BLA {} over the CEM's {} steps, {} of them disagreeing",
            auroc("ga"),
            auroc("bla"),
            ga["steps"],
            ga["disagreeing_steps"]
        ),
    ];
    let missing: Vec<&String> = quoted.iter().filter(|q| !readme.contains(q.as_str())).collect();
    assert!(missing.is_empty(), "the README does not quote the pictured run's {missing:?}");
}
