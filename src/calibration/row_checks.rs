//! Checks of measured rows before any fit: a joint reading outside the robot
//! file's limits or an absurd value (a position kilometres away, a wrench of
//! tonnes, a σ of zero) is not a measurement of this robot, and a single such
//! row moves a least-squares calibration by tens of millimetres. Such rows are
//! named with their reason; the caller fails or drops them.
//!
//! The bounds are loose on purpose: they catch corrupt and mistyped rows, not
//! slightly wrong ones, which the robust fit handles ([`super::robust`]).

use nalgebra::Vector3;

use crate::robot::{ConfWrench, MAX_JOINTS, Robot};

/// How far beyond a joint limit a reading may lie: encoder noise and a soft
/// limit set a little inside the hard stop put real readings there (deg).
pub const JOINT_LIMIT_TOLERANCE_DEG: f64 = 0.5;
/// A position farther than this from the tracker is absurd (mm; trackers reach 80 m).
pub const MAX_POSITION_MM: f64 = 1.0e5;
/// A force above this is absurd for a robot cell (N; 10 t).
pub const MAX_FORCE_N: f64 = 1.0e5;
/// A moment above this is absurd (N·m).
pub const MAX_MOMENT_NM: f64 = 1.0e5;
/// A tracker uncertainty above this is absurd (mm).
pub const MAX_SIGMA_MM: f64 = 100.0;
/// A tracker uncertainty below this (0.1 µm) is no tracker's: it weighs its row
/// by 1/σ, and a σ of 1e-300 makes the fit diverge (mm).
pub const MIN_SIGMA_MM: f64 = 1.0e-4;

/// Why a measured row cannot be used; `None` when it can.
pub fn row_problem(
    robot: &Robot,
    row: &ConfWrench,
    measured_mm: &Vector3<f64>,
    sigma_mm: Option<&Vector3<f64>>,
) -> Option<String> {
    if let Some(problem) = joints_problem(robot, &row.q_deg) {
        return Some(problem);
    }
    let norm = measured_mm.norm();
    if norm.is_nan() || norm > MAX_POSITION_MM {
        return Some(format!(
            "the measured position is {} mm from the tracker (more than {MAX_POSITION_MM} mm)",
            compact(norm)
        ));
    }
    if let Some(problem) = wrench_problem(row) {
        return Some(problem);
    }
    if let Some(sigma) = sigma_mm {
        for (axis, s) in ["x", "y", "z"].iter().zip(sigma.iter()) {
            if !(*s >= MIN_SIGMA_MM && *s <= MAX_SIGMA_MM) {
                return Some(format!(
                    "sigma_{axis}_mm = {} (expected a tracker's 1-σ uncertainty, {MIN_SIGMA_MM} to {MAX_SIGMA_MM} mm)",
                    compact(*s)
                ));
            }
        }
    }
    None
}

/// An orientation angle beyond this is no Euler angle (deg): a unit slip
/// (radians declared, degrees given) or a corrupt cell.
pub const MAX_ANGLE_DEG: f64 = 360.0;
/// A 6-D probe's orientation uncertainty above this is absurd (deg).
pub const MAX_SIGMA_DEG: f64 = 10.0;
/// An orientation uncertainty below this (0.04 arc seconds) is no probe's: it
/// weighs its row by 1/σ (deg).
pub const MIN_SIGMA_DEG: f64 = 1.0e-5;

/// Why a 6-D row's measured orientation (`rx_deg, ry_deg, rz_deg`) or its σ
/// cannot be used; `None` when it can.
pub fn orientation_problem(
    angles_deg: &Vector3<f64>,
    sigma_deg: Option<&Vector3<f64>>,
) -> Option<String> {
    for (axis, a) in ["x", "y", "z"].iter().zip(angles_deg.iter()) {
        if a.is_nan() || a.abs() > MAX_ANGLE_DEG {
            return Some(format!(
                "r{axis}_deg = {} (expected an orientation angle within ±{MAX_ANGLE_DEG} deg)",
                compact(*a)
            ));
        }
    }
    if let Some(sigma) = sigma_deg {
        for (axis, s) in ["x", "y", "z"].iter().zip(sigma.iter()) {
            if !(*s >= MIN_SIGMA_DEG && *s <= MAX_SIGMA_DEG) {
                return Some(format!(
                    "sigma_r{axis}_deg = {} (expected a probe's 1-σ orientation uncertainty, {MIN_SIGMA_DEG} to {MAX_SIGMA_DEG} deg)",
                    compact(*s)
                ));
            }
        }
    }
    None
}

/// Why a commanded row (joints and wrench, nothing measured) is not one this
/// robot can take: what the model would predict for it is meaningless.
pub fn conf_wrench_problem(robot: &Robot, row: &ConfWrench) -> Option<String> {
    joints_problem(robot, &row.q_deg).or_else(|| wrench_problem(row))
}

/// Why a joint vector lies outside the robot file's limits (beyond
/// [`JOINT_LIMIT_TOLERANCE_DEG`]), naming the first such joint.
pub fn joints_problem(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> Option<String> {
    for (joint, &q) in q_deg.iter().enumerate().take(robot.joint_count()) {
        let [lo, hi] = robot.joint_limits(joint);
        if !(q >= lo - JOINT_LIMIT_TOLERANCE_DEG && q <= hi + JOINT_LIMIT_TOLERANCE_DEG) {
            // A prismatic joint's value, limits and tolerance are in mm.
            let (unit, symbol) = if robot.is_prismatic(joint) {
                ("mm", " mm")
            } else {
                ("deg", "°")
            };
            return Some(format!(
                "q{}_{unit} = {} is outside the joint limits [{lo}, {hi}] of the robot file (by more than {JOINT_LIMIT_TOLERANCE_DEG}{symbol})",
                joint + 1,
                compact(q)
            ));
        }
    }
    None
}

/// Why a row's wrench is absurd (a force or moment beyond the bounds above).
pub fn wrench_problem(row: &ConfWrench) -> Option<String> {
    let force = row.wrench.force_n.norm();
    if force.is_nan() || force > MAX_FORCE_N {
        return Some(format!(
            "the force is {} N (more than {MAX_FORCE_N} N)",
            compact(force)
        ));
    }
    let moment = row.wrench.moment_nm.norm();
    if moment.is_nan() || moment > MAX_MOMENT_NM {
        return Some(format!(
            "the moment is {} N·m (more than {MAX_MOMENT_NM} N·m)",
            compact(moment)
        ));
    }
    None
}

/// A value as a person reads it: plain, or in exponent form when huge or tiny.
pub(crate) fn compact(value: f64) -> String {
    if value != 0.0 && (value.abs() >= 1e6 || value.abs() < 1e-3) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::Wrench;
    use crate::robot::test_support::irb1600;

    #[test]
    fn names_the_joint_and_its_limits() {
        let robot = irb1600();
        let mut q = [0.0; MAX_JOINTS];
        q[1] = 130.0;
        let row = ConfWrench::new(q, Wrench::zero());
        let problem = row_problem(&robot, &row, &Vector3::new(1.0, 2.0, 3.0), None).unwrap();
        assert!(
            problem.contains("q2_deg = 130") && problem.contains("[-90, 120]"),
            "{problem}"
        );
        // Within the slack: an encoder reading just past a soft limit.
        q[1] = 120.3;
        let row = ConfWrench::new(q, Wrench::zero());
        assert_eq!(row_problem(&robot, &row, &Vector3::zeros(), None), None);
        q[1] = 0.0;
        q[0] = 1e300;
        let row = ConfWrench::new(q, Wrench::zero());
        assert!(row_problem(&robot, &row, &Vector3::zeros(), None).is_some());
    }

    #[test]
    fn absurd_orientations_and_their_sigmas_are_named() {
        let ok = Vector3::new(-90.2, -20.1, 179.9);
        assert_eq!(
            orientation_problem(&ok, Some(&Vector3::repeat(0.003))),
            None
        );
        assert_eq!(orientation_problem(&ok, None), None);
        let nan = orientation_problem(&Vector3::new(0.0, f64::NAN, 0.0), None).unwrap();
        assert!(nan.starts_with("ry_deg = NaN"), "{nan}");
        // Degrees declared as radians: 180 rad.
        let slip = orientation_problem(&Vector3::new(0.0, 0.0, 10313.0), None).unwrap();
        assert!(slip.starts_with("rz_deg = 10313"), "{slip}");
        let zero = orientation_problem(&ok, Some(&Vector3::new(0.003, 0.0, 0.003))).unwrap();
        assert!(zero.starts_with("sigma_ry_deg = 0 "), "{zero}");
        let absurd = orientation_problem(&ok, Some(&Vector3::new(0.003, 0.003, 45.0))).unwrap();
        assert!(absurd.starts_with("sigma_rz_deg = 45"), "{absurd}");
    }

    #[test]
    fn absurd_positions_wrenches_and_sigmas_are_named() {
        let robot = irb1600();
        let ok = ConfWrench::new(
            [0.0; MAX_JOINTS],
            Wrench::from_array([100.0, 0.0, 0.0, 5.0, 0.0, 0.0]),
        );
        let p = Vector3::new(1000.0, 2000.0, -500.0);
        assert_eq!(
            row_problem(&robot, &ok, &p, Some(&Vector3::repeat(0.01))),
            None
        );
        let far = row_problem(&robot, &ok, &Vector3::new(1e9, 0.0, 0.0), None).unwrap();
        assert!(far.contains("from the tracker"), "{far}");
        let heavy = ConfWrench::new(
            [0.0; MAX_JOINTS],
            Wrench::from_array([0.0, 0.0, -1e7, 0.0, 0.0, 0.0]),
        );
        assert!(
            row_problem(&robot, &heavy, &p, None)
                .unwrap()
                .contains("force")
        );
        let zero_sigma =
            row_problem(&robot, &ok, &p, Some(&Vector3::new(0.01, 0.0, 0.01))).unwrap();
        assert!(zero_sigma.contains("sigma_y_mm = 0"), "{zero_sigma}");
    }
}
