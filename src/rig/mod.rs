//! Hardware in the loop: the measurement rig (robot controller, cable robot,
//! force/torque sensor, laser tracker) behind one interface, with two adapters —
//! the in-process [`simulator`] and an external driver process speaking the
//! line-delimited JSON [`protocol`] (see `schemas/driver-protocol.md`).
//!
//! A stage drives a rig row by row; the rig never sees tables or journals.

pub mod driver;
pub mod protocol;
pub mod reading_checks;
pub mod simulator;

use std::time::Duration;

/// Why a rig operation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RigError {
    /// Worth retrying the row (tracker lost the beam, controller busy, timeout).
    #[error("{0}")]
    Transient(String),
    /// The rig cannot go on (driver died, protocol violated, refused command).
    #[error("{0}")]
    Fatal(String),
}

impl RigError {
    pub fn is_transient(&self) -> bool {
        matches!(self, RigError::Transient(_))
    }
}

/// One measurement rig.
pub trait Rig {
    /// Moves the robot to joint commands `q_deg` for conf-wrench row `cw_id`.
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; 6]) -> Result<(), RigError>;
    /// Makes the cable robot apply a wrench (tool axes, at the tool origin).
    fn apply_wrench(&mut self, wrench: [f64; 6]) -> Result<(), RigError>;
    /// The force/torque sensor's reading of the applied wrench.
    fn read_wrench(&mut self) -> Result<[f64; 6], RigError>;
    /// The joint encoders' reading (deg).
    fn read_joints(&mut self) -> Result<[f64; 6], RigError>;
    /// The laser tracker's SMR position in its own (world) frame, mm.
    fn measure(&mut self) -> Result<[f64; 3], RigError>;
    /// Releases the cable tension before the next move.
    fn release_wrench(&mut self) -> Result<(), RigError>;
    /// Timestamp of the last tracker reading, µs since the epoch (UTC).
    fn measured_at_us(&self) -> i64;
}

/// Per-request time limit of external drivers.
pub fn timeout_from_seconds(seconds: f64) -> Duration {
    Duration::from_secs_f64(seconds.max(0.001))
}
