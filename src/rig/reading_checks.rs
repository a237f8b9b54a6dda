//! Plausibility checks of one row's readings, before the row is recorded: a
//! driver that replies with a joint angle of 500°, a force of 10⁹ N or a position
//! 10³⁰⁰ mm away has not measured this robot (an uninitialised value, a unit or
//! frame mix-up, a saturated sensor), and such a row, once recorded, moves a
//! least-squares calibration by centimetres.
//!
//! A violation is a [`ReadingFault`], which the rig treats like any other reading
//! fault: the row is retried, and after its retries recorded as failed with the
//! fault as its reason — never as data. The bounds are the stage's settings; they
//! catch faults, not noise, so each is generous compared with a working rig.
//!
//! The checks of the *commanded* row (joint limits, wrench bounds) happen before
//! the move and stop the campaign; they are the measure stage's, not these.

use crate::calibration::row_checks::compact;
use crate::robot::{MAX_JOINTS, Robot};

use super::RigError;

/// The bounds a row's readings must keep.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadingBounds {
    /// The robot file's joint limits `[min, max]` (deg; mm for a prismatic
    /// joint).
    pub limits_deg: [[f64; 2]; MAX_JOINTS],
    /// Which joints are prismatic: their readings, limits and the two
    /// bounds below are in mm.
    pub prismatic: [bool; MAX_JOINTS],
    /// How far beyond a limit a joint reading may lie (deg).
    pub joint_tolerance_deg: f64,
    /// How far a joint reading may lie from its command (deg).
    pub max_joint_error_deg: f64,
    /// The force/torque sensor's range per force component (N).
    pub sensor_range_n: f64,
    /// The force/torque sensor's range per moment component (N·m).
    pub sensor_range_nm: f64,
    /// How far a force reading may lie from its command (N); unchecked when `None`.
    pub max_wrench_error_n: Option<f64>,
    /// How far a moment reading may lie from its command (N·m); unchecked when `None`.
    pub max_wrench_error_nm: Option<f64>,
    /// How far from the tracker (the origin of its frame) a position may lie (mm).
    pub max_tracker_distance_mm: f64,
}

/// The readings' names as the `measurements` columns spell them (`table` is a
/// layer above `rig`, so they are repeated here).
const JOINT_COLUMNS: [&str; MAX_JOINTS] = [
    "q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg", "q7_deg",
];
const PRISMATIC_JOINT_COLUMNS: [&str; MAX_JOINTS] = [
    "q1_mm", "q2_mm", "q3_mm", "q4_mm", "q5_mm", "q6_mm", "q7_mm",
];
const WRENCH_COLUMNS: [&str; 6] = ["fx_n", "fy_n", "fz_n", "mx_nm", "my_nm", "mz_nm"];

/// Names of the settings the bounds come from, in messages.
const JOINT_TOLERANCE: &str = "joint_tolerance_deg";
const MAX_JOINT_ERROR: &str = "max_joint_error_deg";
const SENSOR_RANGE_N: &str = "sensor_range_n";
const SENSOR_RANGE_NM: &str = "sensor_range_nm";
const MAX_WRENCH_ERROR_N: &str = "max_wrench_error_n";
const MAX_WRENCH_ERROR_NM: &str = "max_wrench_error_nm";
const MAX_TRACKER_DISTANCE: &str = "max_tracker_distance_mm";
const MAX_TRACK_ERROR: &str = "max_track_error_mm";

/// A reading outside its bounds: which field, its value, and the bound it broke.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReadingFault {
    #[error(
        "implausible reading: {column} = {} is outside the joint limits [{}, {}] by more than {JOINT_TOLERANCE} = {}{unit}",
        compact(*value), limits_deg[0], limits_deg[1], compact(*tolerance_deg)
    )]
    BeyondJointLimit {
        column: &'static str,
        value: f64,
        limits_deg: [f64; 2],
        tolerance_deg: f64,
        /// `°`, or ` mm` for a prismatic joint.
        unit: &'static str,
    },
    #[error(
        "implausible reading: {column} = {} is {}{unit} from the commanded {}, more than {MAX_JOINT_ERROR} = {}{unit}",
        compact(*value), compact((value - commanded).abs()), compact(*commanded), compact(*bound_deg)
    )]
    JointError {
        column: &'static str,
        value: f64,
        commanded: f64,
        bound_deg: f64,
        unit: &'static str,
    },
    #[error(
        "implausible reading: {column} = {} is beyond the force/torque sensor's range ±{} ({setting})",
        compact(*value), compact(*range)
    )]
    BeyondSensorRange {
        column: &'static str,
        value: f64,
        range: f64,
        setting: &'static str,
    },
    #[error(
        "implausible reading: {column} = {} is {} from the commanded {}, more than {setting} = {}",
        compact(*value), compact((value - commanded).abs()), compact(*commanded), compact(*bound)
    )]
    WrenchError {
        column: &'static str,
        value: f64,
        commanded: f64,
        bound: f64,
        setting: &'static str,
    },
    #[error(
        "implausible reading: position ({}, {}, {}) mm is {} mm from the tracker, more than {MAX_TRACKER_DISTANCE} = {} mm",
        compact(position_mm[0]), compact(position_mm[1]), compact(position_mm[2]),
        compact(*distance_mm), compact(*bound_mm)
    )]
    FarFromTracker {
        position_mm: [f64; 3],
        distance_mm: f64,
        bound_mm: f64,
    },
    #[error(
        "implausible reading: the tracker reports {column} = {}, expected a 1-σ uncertainty from {} to {} mm",
        compact(*value),
        crate::calibration::row_checks::MIN_SIGMA_MM,
        crate::calibration::row_checks::MAX_SIGMA_MM
    )]
    SigmaOutOfRange { column: &'static str, value: f64 },
    #[error(
        "implausible reading: e1_mm = {} is {} mm from the commanded carriage position {}, more than {MAX_TRACK_ERROR} = {} mm",
        compact(*value), compact((value - commanded).abs()), compact(*commanded), compact(*bound_mm)
    )]
    TrackError {
        value: f64,
        commanded: f64,
        bound_mm: f64,
    },
}

/// A track's position reading that is not its command within `bound_mm`
/// (NaN included): a carriage that stopped short, or an encoder in other units.
pub fn track_fault(commanded_mm: f64, read_mm: f64, bound_mm: f64) -> Option<ReadingFault> {
    let within = (read_mm - commanded_mm).abs() <= bound_mm;
    (!within).then_some(ReadingFault::TrackError {
        value: read_mm,
        commanded: commanded_mm,
        bound_mm,
    })
}

/// A tracker's reported 1-σ outside what any tracker reports (the bounds the
/// measurements table holds σ to): the weights 1/σ² of such a row would
/// decide the fit alone, or drop it.
pub fn sigma_fault(sigma_mm: &[f64; 3]) -> Option<ReadingFault> {
    use crate::calibration::row_checks::{MAX_SIGMA_MM, MIN_SIGMA_MM};
    ["sigma_x_mm", "sigma_y_mm", "sigma_z_mm"]
        .into_iter()
        .zip(sigma_mm)
        .find(|(_, s)| !(**s >= MIN_SIGMA_MM && **s <= MAX_SIGMA_MM))
        .map(|(column, value)| ReadingFault::SigmaOutOfRange {
            column,
            value: *value,
        })
}

/// A reading fault is worth retrying: the next attempt may read correctly (a
/// glitch on the bus, a sensor that had not settled); a rig that keeps reading
/// nonsense gets the row recorded as failed with this reason.
impl From<ReadingFault> for RigError {
    fn from(fault: ReadingFault) -> Self {
        RigError::Transient(fault.to_string())
    }
}

impl ReadingBounds {
    /// The robot's joint limits, for [`ReadingBounds::limits_deg`].
    pub fn limits_of(robot: &Robot) -> [[f64; 2]; MAX_JOINTS] {
        // Past the arm's joints, a zero reading within zero limits.
        std::array::from_fn(|i| {
            if i < robot.joint_count() {
                robot.joint_limits(i)
            } else {
                [0.0; 2]
            }
        })
    }

    /// Checks one row's readings against the bounds and the row's commands, in
    /// the order the rig reads them (wrench, joints, position); the first fault
    /// found is returned. A NaN breaks every bound.
    pub fn check(
        &self,
        commanded_q_deg: &[f64; MAX_JOINTS],
        commanded_wrench: &[f64; 6],
        q_deg: &[f64; MAX_JOINTS],
        wrench: &[f64; 6],
        position_mm: &[f64; 3],
    ) -> Result<(), ReadingFault> {
        for (i, column) in WRENCH_COLUMNS.iter().enumerate() {
            let (range, range_setting, error_bound, error_setting) = if i < 3 {
                let bound = self.max_wrench_error_n;
                (
                    self.sensor_range_n,
                    SENSOR_RANGE_N,
                    bound,
                    MAX_WRENCH_ERROR_N,
                )
            } else {
                let bound = self.max_wrench_error_nm;
                (
                    self.sensor_range_nm,
                    SENSOR_RANGE_NM,
                    bound,
                    MAX_WRENCH_ERROR_NM,
                )
            };
            let value = wrench[i];
            if !at_most(value.abs(), range) {
                return Err(ReadingFault::BeyondSensorRange {
                    column,
                    value,
                    range,
                    setting: range_setting,
                });
            }
            if let Some(bound) = error_bound
                && !at_most((value - commanded_wrench[i]).abs(), bound)
            {
                return Err(ReadingFault::WrenchError {
                    column,
                    value,
                    commanded: commanded_wrench[i],
                    bound,
                    setting: error_setting,
                });
            }
        }
        for i in 0..MAX_JOINTS {
            let (column, unit) = if self.prismatic[i] {
                (PRISMATIC_JOINT_COLUMNS[i], " mm")
            } else {
                (JOINT_COLUMNS[i], "°")
            };
            let value = q_deg[i];
            let [lo, hi] = self.limits_deg[i];
            let tolerance_deg = self.joint_tolerance_deg;
            if !(value >= lo - tolerance_deg && value <= hi + tolerance_deg) {
                return Err(ReadingFault::BeyondJointLimit {
                    column,
                    value,
                    limits_deg: [lo, hi],
                    tolerance_deg,
                    unit,
                });
            }
            if !at_most((value - commanded_q_deg[i]).abs(), self.max_joint_error_deg) {
                return Err(ReadingFault::JointError {
                    column,
                    value,
                    commanded: commanded_q_deg[i],
                    bound_deg: self.max_joint_error_deg,
                    unit,
                });
            }
        }
        // `hypot`, not a sum of squares: the squares of 1e300 overflow, and the
        // message should show the distance, not infinity.
        let [x, y, z] = *position_mm;
        let distance_mm = x.hypot(y).hypot(z);
        if !at_most(distance_mm, self.max_tracker_distance_mm) {
            return Err(ReadingFault::FarFromTracker {
                position_mm: *position_mm,
                distance_mm,
                bound_mm: self.max_tracker_distance_mm,
            });
        }
        Ok(())
    }
}

/// `value ≤ bound`, false for a NaN value: a NaN reading breaks every bound.
fn at_most(value: f64, bound: f64) -> bool {
    value <= bound
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::irb1600;

    const Q: [f64; MAX_JOINTS] = [10.0, 20.0, -20.0, 30.0, 40.0, 50.0, 0.0];
    const W: [f64; 6] = [100.0, -50.0, 20.0, 5.0, -2.0, 1.0];
    const P: [f64; 3] = [1200.0, -300.0, 900.0];

    #[test]
    fn a_track_reading_far_from_its_command_or_not_a_number_is_a_fault() {
        assert_eq!(track_fault(1500.0, 1500.4, 1.0), None);
        let far = track_fault(1500.0, 1.5, 1.0).expect("a reading in metres");
        assert!(
            far.to_string().contains("max_track_error_mm = 1 mm"),
            "{far}"
        );
        assert!(track_fault(1500.0, f64::NAN, 1.0).is_some());
    }

    fn bounds(max_wrench_error: Option<f64>) -> ReadingBounds {
        ReadingBounds {
            limits_deg: ReadingBounds::limits_of(&irb1600()),
            prismatic: [false; MAX_JOINTS],
            joint_tolerance_deg: 0.5,
            max_joint_error_deg: 1.0,
            sensor_range_n: 2500.0,
            sensor_range_nm: 400.0,
            max_wrench_error_n: max_wrench_error,
            max_wrench_error_nm: max_wrench_error.map(|b| b / 10.0),
            max_tracker_distance_mm: 40_000.0,
        }
    }

    fn message(q: [f64; MAX_JOINTS], w: [f64; 6], p: [f64; 3], b: &ReadingBounds) -> String {
        b.check(&Q, &W, &q, &w, &p).unwrap_err().to_string()
    }

    #[test]
    fn a_reported_sigma_outside_a_trackers_range_is_a_fault() {
        assert_eq!(sigma_fault(&[0.01, 0.02, 0.015]), None);
        let fault = sigma_fault(&[0.01, 1e-300, 0.015]).unwrap().to_string();
        assert!(
            fault.contains("sigma_y_mm") && fault.contains("1e-300"),
            "{fault}"
        );
        assert!(sigma_fault(&[f64::NAN, 0.01, 0.01]).is_some());
        assert!(sigma_fault(&[0.01, 0.01, 1e6]).is_some());
    }

    #[test]
    fn a_plausible_reading_passes() {
        let mut q = Q;
        q[2] += 0.01;
        let mut w = W;
        w[0] += 3.0;
        assert_eq!(bounds(Some(50.0)).check(&Q, &W, &q, &w, &P), Ok(()));
    }

    #[test]
    fn each_fault_names_the_field_its_value_and_the_bound() {
        let b = bounds(Some(50.0));
        let mut q = Q;
        q[1] = 500.0;
        let m = message(q, W, P, &b);
        assert!(
            m.contains("q2_deg = 500 is outside the joint limits [-90, 120]")
                && m.contains("joint_tolerance_deg = 0.5"),
            "{m}"
        );
        q[1] = 1e300;
        assert!(message(q, W, P, &b).contains("q2_deg = 1e300"));
        // Within the limits but 10° from the command: an encoder or axis fault.
        let mut q = Q;
        q[5] = 60.0;
        let m = message(q, W, P, &b);
        assert!(
            m.contains("q6_deg = 60 is 10° from the commanded 50")
                && m.contains("max_joint_error_deg = 1°"),
            "{m}"
        );
        let mut w = W;
        w[2] = 1e9;
        let m = message(Q, w, P, &b);
        assert!(
            m.contains(
                "fz_n = 1e9 is beyond the force/torque sensor's range ±2500 (sensor_range_n)"
            ),
            "{m}"
        );
        let mut w = W;
        w[4] = -401.0;
        assert!(message(Q, w, P, &b).contains("my_nm = -401"));
        // A slack cable: the sensor reads nothing of the commanded 100 N.
        let mut w = W;
        w[0] = 0.0;
        let m = message(Q, w, P, &b);
        assert!(
            m.contains("fx_n = 0 is 100 from the commanded 100, more than max_wrench_error_n = 50"),
            "{m}"
        );
        let m = message(Q, W, [1e300, 1.0, 2.0], &b);
        assert!(
            m.contains("position (1e300, 1, 2) mm is 1e300 mm from the tracker")
                && m.contains("max_tracker_distance_mm = 40000 mm"),
            "{m}"
        );
    }

    #[test]
    fn the_wrench_error_is_unchecked_unless_set_and_nan_breaks_every_bound() {
        let mut w = W;
        w[0] = 0.0;
        assert_eq!(bounds(None).check(&Q, &W, &Q, &w, &P), Ok(()));
        let b = bounds(None);
        let mut q = Q;
        q[0] = f64::NAN;
        assert!(message(q, W, P, &b).contains("q1_deg = NaN"));
        let mut w = W;
        w[3] = f64::INFINITY;
        assert!(message(Q, w, P, &b).contains("mx_nm = inf"));
        assert!(message(Q, W, [0.0, f64::NAN, 0.0], &b).contains("NaN mm from the tracker"));
    }
}
