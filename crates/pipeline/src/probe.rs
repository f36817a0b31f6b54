//! A stage with a config table of its own, compiled only into the pipeline's unit tests: it
//! holds the recipe of "How to add a stage" to account. Its table is its struct here, its
//! `RunConfig` field (`probe`) and its run line (in the test); `nerfsv config`'s tables,
//! `RunConfig::default`, `RunConfig::validate`, `--set` and the run reach it through those alone.

use serde::{Deserialize, Serialize};

use crate::report::{Section, Table};
use crate::stage::{Report, ReportContext, Stage, StageContext};
use crate::PipelineError;

/// The probe stage's table, `[probe]`.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProbeConfig {
    /// Lines the stage writes, 1 to 100.
    pub lines: u32,
}

impl Default for ProbeConfig {
    fn default() -> Self {
        Self { lines: 3 }
    }
}

impl ProbeConfig {
    /// The first value out of range, named by its key in the table.
    pub fn validate(&self) -> Result<(), nerfsv_scene::InvalidValue> {
        nerfsv_scene::validate::in_range("lines", self.lines, 1, 100)
    }
}

/// Writes `lines` numbered lines to `probe.txt`.
pub struct ProbeStage<'a> {
    pub probe: &'a ProbeConfig,
}

impl ProbeStage<'_> {
    pub const TXT: &'static str = "probe.txt";
}

impl Stage for ProbeStage<'_> {
    const NAME: &'static str = "probe";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::TXT];
    type Figures = u32;

    fn config(&self) -> impl Serialize {
        self.probe
    }

    fn run(&self, cx: &StageContext) -> Result<u32, PipelineError> {
        let text: String = (1..=self.probe.lines).map(|i| format!("line {i}\n")).collect();
        let path = cx.dir.join(Self::TXT);
        nerfsv_scene::io::atomic_write_bytes(&path, text.as_bytes()).map_err(|e| PipelineError::io(&path, e))?;
        Ok(self.probe.lines)
    }
}

impl Report for ProbeStage<'_> {
    const ABOUT: &'static str = "writes numbered lines";

    fn describe(lines: &u32) -> String {
        format!("{lines} lines")
    }

    fn report(lines: &u32, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new("probe", "ProbeStage", "lines");
        s.table(Table::new(&["lines"]).row(vec![lines.to_string()]));
        Some(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{RunConfig, Runner, Silent};

    #[test]
    fn a_stage_table_in_its_own_module_is_listed_validated_set_and_run_through_its_field() {
        // Listed with its documentation, as `nerfsv config --default` prints every table.
        let mut tables = Vec::new();
        RunConfig::tables("", &mut tables);
        let (_, name, docs) = tables.iter().find(|(path, ..)| path == "probe").expect("the [probe] table");
        assert_eq!((*name, *docs), ("ProbeConfig", &[("lines", "Lines the stage writes, 1 to 100.")][..]));
        assert_eq!(toml::to_string(&RunConfig::default()).unwrap().matches("[probe]\nlines = 3\n").count(), 1);

        // Validated by `RunConfig::validate`, its error naming `table.key`, from a file and from `--set`.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.toml");
        std::fs::write(&path, "[probe]\nlines = 0\n").unwrap();
        let error = RunConfig::load(&path).unwrap_err().to_string();
        assert!(error.contains("run.toml") && error.contains("probe.lines") && error.contains('0'), "{error}");
        let error = RunConfig::default().set(&["probe.lines=101".to_owned()]).unwrap_err().to_string();
        assert!(error.contains("probe.lines") && error.contains("101"), "{error}");

        // Its run line runs it with the table's values.
        let cfg = RunConfig::default().set(&["probe.lines=2".to_owned()]).unwrap();
        let mut r = Runner::new(dir.path().join("run"), &Silent).unwrap();
        assert_eq!(r.run(&ProbeStage { probe: &cfg.probe }).unwrap(), 2);
        let text = std::fs::read_to_string(dir.path().join("run/probe").join(ProbeStage::TXT)).unwrap();
        assert_eq!(text, "line 1\nline 2\n");
    }
}
