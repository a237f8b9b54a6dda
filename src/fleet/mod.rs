//! A fleet's nightly re-calibration: one job template run for every robot of a
//! plant, on this machine (`egcal fleet run`) or as a Slurm job array
//! (`egcal fleet submit`, each task `egcal fleet task`), and the night's
//! decisions gathered into one table and page (`egcal fleet gather`).
//!
//! Every executor runs the same robot-night ([`night::run_night`]) and leaves the
//! same record (`nights/<date>/results/<robot_id>.json`, written atomically), so
//! gathering does not care where a night ran, and a night already recorded is not
//! run again when a task is requeued or a killed `fleet run` is restarted. A
//! gate's "published" and "refused" are results, not failures: a task that
//! recorded them exits 0, and only gathering turns them into exit codes.
//!
//! Outputs and published calibrations stay on POSIX storage shared by the nodes
//! (publishing relies on an atomic rename); logs may be on S3.

pub mod file;
pub mod gather;
pub mod local;
pub mod manifest;
pub mod night;
pub mod slurm;

use std::path::PathBuf;

pub use file::Fleet;

/// Why a fleet command failed (a robot-night's own failure is a record, not this).
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    #[error("{}{}: {message}", file.display(), if key.is_empty() { String::new() } else { format!(": {key}") })]
    File {
        file: PathBuf,
        key: String,
        message: String,
    },
    #[error("{}: {message}", path.display())]
    Io { path: PathBuf, message: String },
    #[error("{0}")]
    Usage(String),
    #[error("Slurm: {0}")]
    Slurm(String),
    #[error(transparent)]
    Table(Box<crate::table::TableError>),
}

impl From<crate::table::TableError> for FleetError {
    fn from(e: crate::table::TableError) -> Self {
        FleetError::Table(Box::new(e))
    }
}

impl FleetError {
    pub(crate) fn io(path: &std::path::Path, e: impl std::fmt::Display) -> FleetError {
        FleetError::Io {
            path: path.to_path_buf(),
            message: e.to_string(),
        }
    }

    /// Exit code: bad fleet file or arguments 2, Slurm or storage trouble 3.
    pub fn exit_code(&self) -> u8 {
        use crate::exit_code;
        match self {
            FleetError::File { .. } | FleetError::Usage(_) | FleetError::Table(_) => {
                exit_code::BAD_INPUT
            }
            FleetError::Io { .. } | FleetError::Slurm(_) => exit_code::STAGE_FAILED,
        }
    }
}
