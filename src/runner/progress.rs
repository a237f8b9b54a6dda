//! Progress reporting: indicatif bars when stderr is a terminal, plain log lines
//! otherwise (CI logs, cron mail), nothing with `--quiet`.

use std::io::IsTerminal;
use std::io::Write;
use std::sync::Mutex;
use std::time::Instant;

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};

use crate::stages::Progress;

/// How the runner talks to the user.
pub struct Reporter {
    mode: Mode,
}

enum Mode {
    Quiet,
    Lines,
    Bars(MultiProgress),
}

impl Reporter {
    pub fn new(quiet: bool) -> Self {
        let mode = if quiet {
            Mode::Quiet
        } else if std::io::stderr().is_terminal() {
            Mode::Bars(MultiProgress::new())
        } else {
            Mode::Lines
        };
        Reporter { mode }
    }

    /// A log line (above any bars).
    pub fn line(&self, message: &str) {
        match &self.mode {
            Mode::Quiet => {}
            // A closed log pipe must not stop the run (eprintln! would panic).
            Mode::Lines => {
                let _ = writeln!(std::io::stderr().lock(), "{message}");
            }
            Mode::Bars(multi) => {
                let _ = multi.println(message);
            }
        }
    }

    /// A progress sink for one stage.
    pub fn stage(&self, stage_id: &str) -> StageProgress<'_> {
        StageProgress {
            reporter: self,
            stage_id: stage_id.to_string(),
            bar: Mutex::new(None),
            started: Instant::now(),
            total: Mutex::new(0),
            last_line_percent: Mutex::new(0),
        }
    }
}

/// Progress of one running stage.
pub struct StageProgress<'a> {
    reporter: &'a Reporter,
    stage_id: String,
    bar: Mutex<Option<ProgressBar>>,
    started: Instant,
    total: Mutex<u64>,
    last_line_percent: Mutex<u64>,
}

impl Progress for StageProgress<'_> {
    fn start(&self, total: u64, what: &str) {
        *self.total.lock().expect("progress lock") = total;
        if let Mode::Bars(multi) = &self.reporter.mode {
            let bar = multi.add(ProgressBar::new(total));
            bar.set_style(
                ProgressStyle::with_template("{prefix:>12} [{bar:30}] {pos}/{len} {msg} ETA {eta}")
                    .expect("valid template")
                    .progress_chars("=> "),
            );
            bar.set_prefix(self.stage_id.clone());
            bar.set_message(what.to_string());
            *self.bar.lock().expect("progress lock") = Some(bar);
        }
    }

    fn advance(&self, done: u64) {
        match &self.reporter.mode {
            Mode::Bars(_) => {
                if let Some(bar) = self.bar.lock().expect("progress lock").as_ref() {
                    bar.set_position(done);
                }
            }
            Mode::Lines => {
                let total = *self.total.lock().expect("progress lock");
                if total == 0 {
                    return;
                }
                let percent = done * 100 / total;
                let mut last = self.last_line_percent.lock().expect("progress lock");
                if percent >= *last + 25 {
                    *last = percent;
                    self.reporter.line(&format!(
                        "{}: {done}/{total} ({percent}%) after {:.1} s",
                        self.stage_id,
                        self.started.elapsed().as_secs_f64()
                    ));
                }
            }
            Mode::Quiet => {}
        }
    }

    fn note(&self, message: &str) {
        self.reporter.line(&format!("{}: {message}", self.stage_id));
    }
}

impl Drop for StageProgress<'_> {
    fn drop(&mut self) {
        if let Some(bar) = self.bar.lock().expect("progress lock").take() {
            bar.finish_and_clear();
        }
    }
}
