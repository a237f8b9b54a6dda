//! The exit codes of the `egcal` binary (the user guide's reference table) and
//! what a finished command prints. Its own module so that every layer that ends
//! a command (`job_run`, `fleet/`, `fixture_cases/`, `commands`) names the same
//! codes without importing from the layer above it.

use crate::runner::{RunError, lock::LockError};
use crate::stages::StageError;

pub const OK: u8 = 0;
/// An I/O failure in the output folder, or a bug.
pub const INTERNAL: u8 = 1;
/// Bad job file, robot file, table or arguments: fix the input.
pub const BAD_INPUT: u8 = 2;
/// A stage failed while running.
pub const STAGE_FAILED: u8 = 3;
/// Another run holds the output folder's lock.
pub const LOCKED: u8 = 5;
/// A gate stage published a new calibration (the run itself succeeded).
pub const GATE_PUBLISHED: u8 = 10;
/// A gate stage refused a candidate that should have replaced the calibration
/// in service: a person should look (the run itself succeeded).
pub const GATE_REFUSED: u8 = 11;

/// What a successful command prints, and its exit code: [`OK`], or a gate
/// stage's decision.
#[derive(Debug, Clone, PartialEq)]
pub struct Finished {
    pub message: String,
    pub code: u8,
}

impl From<String> for Finished {
    fn from(message: String) -> Self {
        Finished { message, code: OK }
    }
}

/// The exit code of a stage's error: its input is bad, or it failed running.
pub fn of_stage_error(e: &StageError) -> u8 {
    match e {
        StageError::Table(_) | StageError::Invalid(_) => BAD_INPUT,
        StageError::Failed(_) => STAGE_FAILED,
    }
}

/// The exit code of a runner's error.
pub fn of_run_error(e: &RunError) -> u8 {
    match e {
        RunError::Lock(LockError::Held { .. }) => LOCKED,
        RunError::Lock(_) | RunError::Io { .. } => INTERNAL,
        RunError::UnknownStage(..) | RunError::MissingUpstream { .. } | RunError::Table { .. } => {
            BAD_INPUT
        }
        RunError::InputChanged { .. } => STAGE_FAILED,
        RunError::Stage { source, .. } => of_stage_error(source),
    }
}
