//! Progress on stderr: bars on a terminal, a plain line every few seconds in a log, and with
//! `--json` (whose figures go to stdout) one JSON object a line, as often as a log's lines:
//! `{"stage", "done", "total", "seconds", "status"}` for progress, `{"stage", "note"}` for a
//! note.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use nerfsv_pipeline::Observer;

/// How often a log (stderr not a terminal) gets a progress line.
const LOG_EVERY: Duration = Duration::from_secs(5);

/// Shows what stages report.
pub struct Reporter {
    json: bool,
    terminal: bool,
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    /// The stage whose bar is shown, and the bar.
    bar: Option<(String, ProgressBar)>,
    /// When the current stage's progress started and was last logged.
    started: Option<Instant>,
    last_logged: Option<Instant>,
}

impl Reporter {
    /// `json`: JSON lines (the command prints its figures as JSON on stdout).
    pub fn new(json: bool) -> Self {
        Self { json, terminal: !json && std::io::stderr().is_terminal(), state: Mutex::new(State::default()) }
    }

    fn bar(total: u64, stage: &str) -> ProgressBar {
        let pb = ProgressBar::new(total);
        pb.set_style(
            ProgressStyle::with_template("{prefix:>14} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}")
                .expect("static template")
                .progress_chars("=> "),
        );
        pb.set_prefix(stage.to_string());
        pb
    }
}

impl Observer for Reporter {
    fn progress(&self, stage: &str, done: u64, total: u64, status: &str) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        if s.bar.as_ref().is_none_or(|(name, _)| name != stage) {
            if let Some((_, old)) = s.bar.take() {
                old.finish_and_clear();
            }
            let pb = if self.terminal { Self::bar(total, stage) } else { ProgressBar::hidden() };
            s.bar = Some((stage.to_string(), pb));
            s.started = Some(Instant::now());
            s.last_logged = None;
        }
        if let Some((_, pb)) = &s.bar {
            pb.set_length(total);
            pb.set_position(done);
            pb.set_message(status.to_string());
        }
        if !self.terminal {
            let now = Instant::now();
            let due = s.last_logged.is_none_or(|t| now - t >= LOG_EVERY) || done >= total;
            if due {
                let elapsed = s.started.map_or(0.0, |t| (now - t).as_secs_f64());
                if self.json {
                    let line = serde_json::json!({
                        "stage": stage, "done": done, "total": total, "seconds": elapsed, "status": status,
                    });
                    eprintln!("{line}");
                } else {
                    let eta = if done > 0 && done < total {
                        format!(", about {:.0} s left", elapsed * (total - done) as f64 / done as f64)
                    } else {
                        String::new()
                    };
                    let pct = 100.0 * done as f64 / total.max(1) as f64;
                    eprintln!("{stage}: {done}/{total} ({pct:.0} %) after {elapsed:.0} s{eta}  {status}");
                }
                s.last_logged = Some(now);
            }
        }
    }

    fn note(&self, stage: &str, message: &str) {
        if self.json {
            eprintln!("{}", serde_json::json!({ "stage": stage, "note": message }));
            return;
        }
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((name, pb)) = s.bar.take() {
            if name == stage {
                pb.finish_and_clear();
            } else {
                s.bar = Some((name, pb));
            }
        }
        match &s.bar {
            Some((_, pb)) => pb.suspend(|| eprintln!("{stage}: {message}")),
            None => eprintln!("{stage}: {message}"),
        }
    }
}
