//! Fixture cases (issue #19): a stage kind run on a case's files and checked
//! against what the case expects, the format of `fixtures/<kind>/<case>/case.toml`.
//! `egcal test` runs a lab's own cases with this module, and so does egcal's
//! own test suite (`tests/fixtures.rs`), so the two cannot drift apart.
//!
//! * `case.rs`: the case file, parsed strictly and checked (line and key of a
//!   problem), and its JSON Schema;
//! * `run.rs`: finding cases, running each as an `egcal stage` process in
//!   parallel, judging its exit code, error text, tables, files and output;
//! * `compare.rs`: expected against actual tables, cell by cell;
//! * `junit.rs`: the JUnit XML report;
//! * `record.rs`: `egcal test record`, a regression case from today's output.

pub mod case;
pub mod compare;
pub mod junit;
pub mod record;
pub mod run;

use std::path::Path;

pub use record::{RecordOptions, record};
pub use run::{CaseResult, Outcome, Summary, TestOptions, run};

/// Why `egcal test` or `egcal test record` could not do its work (a failing or
/// malformed case is a result, not an error).
#[derive(Debug, thiserror::Error)]
pub enum FixtureError {
    /// Arguments, folders or files given on the command line.
    #[error("{0}")]
    Usage(String),
    /// The recording could not produce a case that passes.
    #[error("{0}")]
    Record(String),
    #[error("writing {file}: {message}")]
    Write { file: String, message: String },
}

impl FixtureError {
    pub fn exit_code(&self) -> u8 {
        match self {
            FixtureError::Usage(_) => crate::exit_code::BAD_INPUT,
            FixtureError::Record(_) => crate::exit_code::STAGE_FAILED,
            FixtureError::Write { .. } => crate::exit_code::INTERNAL,
        }
    }
}

/// Refuses a `--junit` path that cannot be written before any case runs, so a
/// typo does not cost the run's results.
pub fn check_report_path(path: &Path) -> Result<(), FixtureError> {
    let bad =
        |message: String| FixtureError::Usage(format!("--junit {}: {message}", path.display()));
    if path.is_dir() {
        return Err(bad("is a folder; name a file".into()));
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| bad(format!("cannot create its folder: {e}")))?;
    let probe = dir.join(crate::fsio::sweep::staging_folder_name("junit-probe"));
    std::fs::create_dir(&probe).map_err(|e| bad(format!("its folder is not writable: {e}")))?;
    let _ = std::fs::remove_dir(&probe);
    Ok(())
}

/// Writes the JUnit XML report atomically.
pub fn write_junit(summary: &Summary, path: &Path) -> Result<(), FixtureError> {
    let timestamp = crate::table::time::now_rfc3339();
    crate::fsio::write_bytes_atomic(path, junit::to_xml(summary, &timestamp).as_bytes()).map_err(
        |e| FixtureError::Write {
            file: path.display().to_string(),
            message: e.to_string(),
        },
    )
}
