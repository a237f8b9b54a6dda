//! Hardware in the loop: the measurement rig (robot controller, cable robot,
//! force/torque sensor, laser tracker) behind one interface, with two adapters —
//! the in-process [`simulator`] and an external driver process speaking the
//! line-delimited JSON [`protocol`] (see `schemas/driver-protocol.md`).
//!
//! A stage drives a rig row by row; the rig never sees tables or journals.

pub mod approach;
pub mod driver;
pub mod protocol;
pub mod reading_checks;
pub mod simulator;

use std::time::Duration;

use protocol::ErrorCode;

use crate::robot::MAX_JOINTS;
use crate::robot::positioner::MAX_POSITIONER_AXES;

/// Why a rig operation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RigError {
    /// Worth retrying the row (tracker lost the beam, controller busy, timeout).
    #[error("{0}")]
    Transient(String),
    /// This row cannot be measured (a target out of range): recorded as failed
    /// without retrying; the campaign goes on.
    #[error("{0}")]
    Row(String),
    /// The rig cannot go on (driver died, protocol violated, refused command).
    #[error("{0}")]
    Fatal(String),
    /// A device's failure in the driver protocol's vocabulary; what it means for
    /// the campaign follows from the code and `transient` ([`RigError::disposition`]).
    #[error("{}: {message}", code.as_str())]
    Device {
        code: ErrorCode,
        message: String,
        transient: bool,
    },
}

/// What a campaign does after a failed row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Disposition {
    /// Try the row again (up to the stage's `retries`).
    Retry,
    /// Record the row as failed and go on.
    FailRow,
    /// Stop the campaign; measured rows are kept and the next run resumes.
    Stop,
}

impl RigError {
    pub fn disposition(&self) -> Disposition {
        match self {
            RigError::Transient(_) => Disposition::Retry,
            RigError::Row(_) => Disposition::FailRow,
            RigError::Fatal(_) => Disposition::Stop,
            RigError::Device { code, .. } if code.stops_campaign() => Disposition::Stop,
            // Not ready, and a retry will not help (motors off, manual mode):
            // a person must act before any row can be measured.
            RigError::Device {
                code: ErrorCode::NotReady,
                transient: false,
                ..
            } => Disposition::Stop,
            RigError::Device {
                transient: true, ..
            } => Disposition::Retry,
            RigError::Device { .. } => Disposition::FailRow,
        }
    }

    pub fn is_transient(&self) -> bool {
        self.disposition() == Disposition::Retry
    }

    /// The protocol's code of a device error.
    pub fn code(&self) -> Option<ErrorCode> {
        match self {
            RigError::Device { code, .. } => Some(*code),
            _ => None,
        }
    }

    pub fn device(code: ErrorCode, transient: bool, message: impl Into<String>) -> RigError {
        RigError::Device {
            code,
            message: message.into(),
            transient,
        }
    }
}

/// One measurement rig.
pub trait Rig {
    /// Moves the robot to joint commands `q_deg` for conf-wrench row `cw_id`.
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; MAX_JOINTS]) -> Result<(), RigError>;
    /// Makes the cable robot apply a wrench (tool axes, at the tool origin).
    fn apply_wrench(&mut self, wrench: [f64; 6]) -> Result<(), RigError>;
    /// The force/torque sensor's reading of the applied wrench.
    fn read_wrench(&mut self) -> Result<[f64; 6], RigError>;
    /// The joint encoders' reading (deg).
    fn read_joints(&mut self) -> Result<[f64; MAX_JOINTS], RigError>;
    /// The laser tracker's SMR position in its own (world) frame, mm.
    fn measure(&mut self) -> Result<[f64; 3], RigError>;
    /// Releases the cable tension before the next move.
    fn release_wrench(&mut self) -> Result<(), RigError>;
    /// Moves a linear track's carriage to `e_mm` (robot files with a
    /// `[track]`), before the joints of conf-wrench row `cw_id` move.
    fn move_track(&mut self, cw_id: i64, e_mm: f64) -> Result<(), RigError> {
        let _ = (cw_id, e_mm);
        Err(RigError::Fatal(NO_TRACK.into()))
    }
    /// The track's position encoder (mm).
    fn read_track(&mut self) -> Result<f64, RigError> {
        Err(RigError::Fatal(NO_TRACK.into()))
    }
    /// Points the tracker at SMR `target_id` for the following
    /// [`Rig::measure`]s: the arm's SMR or a nest on the positioner's table
    /// (campaigns that measure a positioner's nests).
    fn select_target(&mut self, target_id: &str) -> Result<(), RigError> {
        let _ = target_id;
        Err(RigError::Fatal(NO_POSITIONER.into()))
    }
    /// Moves the positioner's axes to `p_deg` (deg; the robot file's axes,
    /// the rest 0) for conf-wrench row `cw_id`.
    fn move_positioner(
        &mut self,
        cw_id: i64,
        p_deg: [f64; MAX_POSITIONER_AXES],
    ) -> Result<(), RigError> {
        let _ = (cw_id, p_deg);
        Err(RigError::Fatal(NO_POSITIONER.into()))
    }
    /// How many axes the rig's positioner has (0 without one): the values
    /// `read_positioner` answers over the protocol.
    fn positioner_axes(&self) -> usize {
        0
    }
    /// The positioner's axis encoders (deg; the robot file's axes, the rest 0).
    fn read_positioner(&mut self) -> Result<[f64; MAX_POSITIONER_AXES], RigError> {
        Err(RigError::Fatal(NO_POSITIONER.into()))
    }
    /// Timestamp of the last tracker reading, µs since the epoch (UTC).
    fn measured_at_us(&self) -> i64;
    /// The tracker's own 1-σ uncertainty of the last reading (mm), when it gives one.
    fn measured_sigma_mm(&self) -> Option<[f64; 3]> {
        None
    }
    /// Whether the rig can serve: checked before a driver answers `hello`, so a
    /// device that cannot be reached fails the start, named.
    fn ready(&mut self) -> Result<(), RigError> {
        Ok(())
    }
    /// Releases the devices (sessions, streams) before a driver answers `shutdown`.
    fn shutdown(&mut self) {}
}

/// Why a rig without a track axis refuses the track's methods.
const NO_TRACK: &str =
    "this rig has no linear track axis (move_track, read_track), and the robot file has a [track]";

/// Why a rig without a positioner refuses its methods.
const NO_POSITIONER: &str = "this rig cannot measure a positioner's nests (select_target, move_positioner, read_positioner), and the rows measure them";

/// Per-request time limit of external drivers.
pub fn timeout_from_seconds(seconds: f64) -> Duration {
    Duration::from_secs_f64(seconds.max(0.001))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_decide_between_retrying_failing_the_row_and_stopping() {
        let d = |code, transient| RigError::device(code, transient, "m").disposition();
        assert_eq!(d(ErrorCode::BeamLost, true), Disposition::Retry);
        assert_eq!(d(ErrorCode::OutOfRange, false), Disposition::FailRow);
        assert_eq!(d(ErrorCode::NotReady, true), Disposition::Retry);
        assert_eq!(d(ErrorCode::NotReady, false), Disposition::Stop);
        for code in [
            ErrorCode::Estop,
            ErrorCode::NotConnected,
            ErrorCode::ExclusiveOwner,
            ErrorCode::UnitMismatch,
            ErrorCode::Protocol,
        ] {
            assert_eq!(d(code, true), Disposition::Stop, "{code:?}");
        }
        assert_eq!(
            RigError::device(ErrorCode::Timeout, true, "no reply").to_string(),
            "timeout: no reply"
        );
    }
}
