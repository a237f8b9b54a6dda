//! Job files: phase 1 ([`raw`]) turns TOML into plain structs; phase 2 ([`plan`])
//! resolves paths, stage kinds and input references, reads the footers of external
//! Parquet inputs and orders the stages. Both phases report every problem at once.

pub mod overrides;
pub mod plan;
pub mod raw;
pub mod schema;

use std::fmt;
use std::path::PathBuf;

pub use overrides::JobOverrides;
pub use plan::{InputSource, Plan, PlannedStage};

/// One problem in a job file.
#[derive(Debug, Clone, PartialEq)]
pub struct JobProblem {
    pub file: PathBuf,
    pub line: Option<usize>,
    /// Key path, e.g. `stages[2].per_config`; empty for whole-file problems.
    pub key: String,
    pub message: String,
}

impl fmt::Display for JobProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if self.key.is_empty() {
            write!(f, ": {}", self.message)
        } else {
            write!(f, ": {}: {}", self.key, self.message)
        }
    }
}

/// Every problem found in a job file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct JobProblems(pub Vec<JobProblem>);

impl fmt::Display for JobProblems {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.0.len();
        if n > 1 {
            writeln!(f, "{n} problems in the job file:")?;
        }
        for (i, problem) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            if n > 1 {
                write!(f, "  ")?;
            }
            write!(f, "{problem}")?;
        }
        Ok(())
    }
}
