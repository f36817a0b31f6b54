//! A stage defined here, outside the pipeline crate, reaches `summary.json` and the report
//! through its own `impl Stage` and `impl Report` alone: nothing else is touched.

use nerfsv_pipeline::report::{Section, Table};
use nerfsv_pipeline::{PipelineError, Report, ReportContext, Runner, Silent, Stage, StageContext};
use serde::{Deserialize, Serialize};

/// Writes the squares below `n`.
struct Squares {
    n: u32,
}

#[derive(Clone, Serialize, Deserialize)]
struct SquaresFigures {
    count: u32,
    largest: u32,
}

impl Stage for Squares {
    const NAME: &'static str = "squares";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &["squares.csv"];
    type Figures = SquaresFigures;

    fn config(&self) -> impl Serialize {
        self.n
    }

    fn run(&self, cx: &StageContext) -> Result<SquaresFigures, PipelineError> {
        let text: String = (0..self.n).map(|i| format!("{i},{}\n", i * i)).collect();
        std::fs::write(cx.dir.join("squares.csv"), text).map_err(|e| PipelineError::io(&cx.dir, e))?;
        Ok(SquaresFigures { count: self.n, largest: (self.n - 1).pow(2) })
    }
}

impl Report for Squares {
    const ABOUT: &'static str = "squares of the first integers";

    fn describe(f: &SquaresFigures) -> String {
        format!("{} squares", f.count)
    }

    fn report(f: &SquaresFigures, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new("squares", "Squares & more", "squares");
        s.answer(5, format!("<b>How large?</b> The largest square is {}.", f.largest));
        s.table(Table::new(&["count", "largest"]).row(vec![f.count.to_string(), f.largest.to_string()]));
        s.csv("squares.csv", "squares.csv");
        Some(s)
    }
}

#[test]
fn a_stage_defined_outside_the_pipeline_appears_in_the_summary_and_the_report() {
    let root = tempfile::tempdir().unwrap();
    let mut runner = Runner::new(root.path(), &Silent).unwrap();
    runner.run(&Squares { n: 5 }).unwrap();
    let summary = runner.finish(Some("n = 5\n")).unwrap();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.path().join("summary.json")).unwrap()).unwrap();
    assert_eq!(json["squares"]["largest"], 16, "{json}");
    assert_eq!(summary.stages.0.len(), 1);
    let html = std::fs::read_to_string(root.path().join("report/index.html")).unwrap();
    for part in [
        "<li><b>How large?</b> The largest square is 16.</li>",
        "<a href=\"#squares\">squares</a>",
        "<h2 id=\"squares\">Squares &amp; more</h2>",
        "<td>5</td><td>16</td>",
        "squares of the first integers",
        "<a href=\"squares.csv\">squares.csv</a>",
        "<pre>n = 5\n</pre>",
    ] {
        assert!(html.contains(part), "{part} missing from the report:\n{html}");
    }
    assert_eq!(std::fs::read_to_string(root.path().join("report/squares.csv")).unwrap(), "0,0\n1,1\n2,4\n3,9\n4,16\n");
    // `nerfsv report` rebuilds the same page from the folder alone.
    let again = nerfsv_pipeline::report::write_report(root.path(), None).unwrap();
    assert_eq!(std::fs::read_to_string(again.index).unwrap(), html);
    assert!(again.missing_stages.is_empty() && again.tables == 1);
    // A stage the summary lists whose record is gone says so, in its place.
    std::fs::remove_file(root.path().join("squares/stage.json")).unwrap();
    let partial = nerfsv_pipeline::report::write_report(root.path(), None).unwrap();
    assert_eq!(partial.missing_stages, ["squares"]);
    let html = std::fs::read_to_string(partial.index).unwrap();
    assert!(html.contains("The squares stage has not run in this folder."), "{html}");
    assert!(html.contains("No stage that answers it has run in this folder."), "{html}");
}
