//! Why a CDPR spec, pose or wrench was rejected, or why a tension solve failed.

use std::path::PathBuf;

/// Errors of the [`crate::cdpr`] module.
#[derive(Debug, thiserror::Error)]
pub enum CdprError {
    /// The spec file could not be read.
    #[error("cannot read CDPR file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The spec text is not valid TOML.
    #[error("CDPR file {path}: {message}")]
    Parse { path: PathBuf, message: String },
    /// A key of a spec file is missing, unknown, of the wrong type or out of range.
    #[error("CDPR file {path}: key `{key}`: {message}")]
    InvalidFile {
        path: PathBuf,
        key: String,
        message: String,
    },
    /// A key of an in-memory spec is out of range (see [`super::CableRobotSpec::validate`]).
    #[error("CDPR spec: key `{key}`: {message}")]
    InvalidSpec { key: String, message: String },
    /// The tool pose handed to [`super::check_wrench`] is not a finite rigid transform.
    #[error("CDPR tool pose: {message}")]
    InvalidPose { message: String },
    /// The requested wrench has a non-finite component.
    #[error("CDPR wrench component {index}: expected a finite number, found {value}")]
    InvalidWrench { index: usize, value: f64 },
    /// At this pose the cables cannot act in all six wrench directions (e.g. a
    /// cable of zero length, or coplanar cables), so the available wrench set has no
    /// interior and no capacity margin.
    #[error("CDPR structure matrix has rank {rank} < 6 at this pose")]
    RankDeficient { rank: usize },
    /// Clarabel could not be set up or did not reach a verdict.
    #[error("CDPR tension solver: {message}")]
    Solver { message: String },
}
