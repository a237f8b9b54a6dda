//! The calibration's envelope in joint space: how far a command's configuration
//! lies from the configurations the calibration was identified on (issue 26,
//! spec §8 `envelope_distance`).
//!
//! A calibration is a fit: the offsets it identifies absorb what the model
//! cannot express (a transmission error, an unmodelled elasticity) as it looks
//! in the configurations that were measured, not elsewhere. The simulated loop
//! of `jobs/compensate_sim.toml` achieved 4× its validation error on targets at
//! q2 ≈ 14°, q3 ≈ −14° from a campaign at q2 ≈ 104°, q3 ≈ −170°. So a command is
//! trusted only near a calibration row.
//!
//! **Metric.** The distance of a configuration `q` to the calibration rows `r`
//! is `min over rows of max over joints 1–6 of |wrap(q_j − r_j)|` (degrees): the
//! Chebyshev (largest per-joint) distance to the nearest row. A distance of 20°
//! says: some calibration row has every joint within 20° of this command, and
//! none has them all closer. Chosen over a Euclidean norm because a calibration
//! engineer reasons per joint ("q2 was never above −90°"), because joints of
//! different reach count alike without a weighting to argue about, and because
//! one far joint is not diluted by five near ones. Each difference is wrapped
//! into [−180°, 180°]: the model (geometry and gravity) repeats every turn of a
//! joint, so a row at q6 = −350° measured the same arm as q6 = 10°.
//!
//! **On a track** the carriage is one more axis of the calibration's reach:
//! the track's errors are polynomials of its position fitted on the
//! positions the rows were measured at, and a polynomial extrapolates
//! badly. Between the measured positions they interpolate, so the check is
//! how far a command's carriage position lies beyond the rows' range (mm),
//! not its distance to the nearest row.
//!
//! **A gantry's slides** (prismatic joints) are left out of the distance:
//! their MDH geometry is a straight line along the travel, the same wherever
//! the rows were measured on it (a real slide's straightness error is not in
//! the model, as a track's is), so the distance is the revolute joints'.
//!
//! Cost: `O(rows × 6)` per configuration with an early exit per row, in the
//! caller's parallel loop; 10⁴ rows × 10³ targets is well under a second.

use super::Status;
use crate::robot::MAX_JOINTS;

/// `compensate`'s default [`EnvelopeLimits::max_distance_deg`] (deg): a job
/// that raises it accepts commands the default would flag, and the stage
/// and the report say how many.
pub const DEFAULT_MAX_DISTANCE_DEG: f64 = 40.0;

/// How far from the calibration a command may lie and still be `ok`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopeLimits {
    /// Largest [`JointEnvelope::distance_deg`] of an `ok` command (deg).
    pub max_distance_deg: f64,
    /// Largest predicted 95 % position uncertainty of an `ok` command (mm).
    pub max_u95_mm: f64,
    /// Largest [`JointEnvelope::track_beyond_mm`] of an `ok` command (mm).
    pub max_track_beyond_mm: f64,
}

/// What the envelope says of one command; `None` where not computed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnvelopeMeasures {
    pub distance_deg: Option<f64>,
    pub u95_mm: Option<f64>,
    pub track_beyond_mm: Option<f64>,
}

/// The status of a command after the envelope check: an `ok` command beyond
/// either limit is `outside_envelope`; every other status stays (it says
/// something worse). A value not computed (`None`: no envelope rows, no
/// covariance) checks nothing; the stage says so.
pub fn judged(status: Status, measures: &EnvelopeMeasures, limits: &EnvelopeLimits) -> Status {
    let beyond = measures
        .distance_deg
        .is_some_and(|d| d > limits.max_distance_deg)
        || measures.u95_mm.is_some_and(|u| u > limits.max_u95_mm)
        || measures
            .track_beyond_mm
            .is_some_and(|b| b > limits.max_track_beyond_mm);
    if status == Status::Ok && beyond {
        Status::OutsideEnvelope
    } else {
        status
    }
}

/// The joint configurations (deg) of the calibration rows, and on a track
/// the range of their carriage positions (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct JointEnvelope {
    rows_deg: Vec<[f64; MAX_JOINTS]>,
    track_range_mm: Option<[f64; 2]>,
    /// The prismatic joints, which the distance leaves out.
    slides: [bool; MAX_JOINTS],
}

impl JointEnvelope {
    /// `None` without rows: an envelope of nothing checks nothing.
    pub fn new(rows_deg: Vec<[f64; MAX_JOINTS]>) -> Option<Self> {
        (!rows_deg.is_empty()).then_some(JointEnvelope {
            rows_deg,
            track_range_mm: None,
            slides: [false; MAX_JOINTS],
        })
    }

    /// The same rows of an arm whose prismatic joints `slides` marks.
    pub fn with_slides(self, slides: [bool; MAX_JOINTS]) -> Self {
        JointEnvelope { slides, ..self }
    }

    /// The same rows measured at the carriage positions `track_mm` (one per
    /// row, or none without a track).
    pub fn with_track(self, track_mm: &[f64]) -> Self {
        let range = track_mm.iter().fold(None, |range: Option<[f64; 2]>, e| {
            Some(range.map_or([*e, *e], |[lo, hi]| [lo.min(*e), hi.max(*e)]))
        });
        JointEnvelope {
            track_range_mm: range,
            ..self
        }
    }

    /// How far (mm) the carriage position `e_mm` lies beyond the rows'
    /// positions (0 within them); `None` without a track.
    pub fn track_beyond_mm(&self, e_mm: f64) -> Option<f64> {
        self.track_range_mm
            .map(|[lo, hi]| (lo - e_mm).max(e_mm - hi).max(0.0))
    }

    pub fn len(&self) -> usize {
        self.rows_deg.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows_deg.is_empty()
    }

    /// The module doc's distance (deg) of `q_deg` to the nearest row.
    pub fn distance_deg(&self, q_deg: &[f64; MAX_JOINTS]) -> f64 {
        let mut best = f64::INFINITY;
        for row in &self.rows_deg {
            let mut largest = 0.0_f64;
            for ((q, r), slide) in q_deg.iter().zip(row).zip(&self.slides) {
                if *slide {
                    continue;
                }
                largest = largest.max(wrapped_difference_deg(*q, *r).abs());
                if largest >= best {
                    break;
                }
            }
            best = best.min(largest);
        }
        best
    }
}

/// `a − b` wrapped into [−180°, 180°].
pub fn wrapped_difference_deg(a: f64, b: f64) -> f64 {
    (a - b + 180.0).rem_euclid(360.0) - 180.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_distance_is_the_largest_joint_difference_to_the_nearest_row() {
        let envelope = JointEnvelope::new(vec![
            [0.0, -120.0, 90.0, 0.0, 45.0, 0.0, 0.0],
            [30.0, -100.0, 60.0, 10.0, 45.0, 0.0, 0.0],
        ])
        .expect("rows");
        // Row 0: largest difference 40 (q2); row 1: 30 (q1), 20 (q2): 30.
        assert_eq!(
            envelope.distance_deg(&[0.0, -80.0, 80.0, 0.0, 45.0, 0.0, 0.0]),
            30.0
        );
        // On a row.
        assert_eq!(
            envelope.distance_deg(&[30.0, -100.0, 60.0, 10.0, 45.0, 0.0, 0.0]),
            0.0
        );
    }

    #[test]
    fn differences_wrap_a_full_turn() {
        assert_eq!(wrapped_difference_deg(10.0, -350.0), 0.0);
        assert_eq!(wrapped_difference_deg(170.0, -170.0), -20.0);
        assert_eq!(wrapped_difference_deg(-170.0, 170.0), 20.0);
        let envelope =
            JointEnvelope::new(vec![[0.0, 0.0, 0.0, 0.0, 0.0, -350.0, 0.0]]).expect("rows");
        assert_eq!(
            envelope.distance_deg(&[0.0, 0.0, 0.0, 0.0, 0.0, 15.0, 0.0]),
            5.0
        );
    }

    #[test]
    fn only_an_ok_command_beyond_a_limit_is_outside_the_envelope() {
        let limits = EnvelopeLimits {
            max_distance_deg: 30.0,
            max_u95_mm: 0.5,
            max_track_beyond_mm: 50.0,
        };
        let judge = |status, distance_deg, u95_mm| {
            let measures = EnvelopeMeasures {
                distance_deg,
                u95_mm,
                track_beyond_mm: None,
            };
            judged(status, &measures, &limits)
        };
        assert_eq!(judge(Status::Ok, Some(30.0), Some(0.5)), Status::Ok);
        assert_eq!(
            judge(Status::Ok, Some(30.1), Some(0.1)),
            Status::OutsideEnvelope
        );
        assert_eq!(
            judge(Status::Ok, Some(1.0), Some(0.6)),
            Status::OutsideEnvelope
        );
        assert_eq!(judge(Status::Ok, None, None), Status::Ok);
        assert_eq!(
            judge(Status::JointLimit, Some(90.0), None),
            Status::JointLimit
        );
    }

    #[test]
    fn a_carriage_beyond_the_rows_positions_is_outside_the_envelope() {
        let envelope = JointEnvelope::new(vec![[0.0; MAX_JOINTS]; 3])
            .expect("rows")
            .with_track(&[750.0, 0.0, 1500.0]);
        assert_eq!(envelope.track_beyond_mm(375.0), Some(0.0), "between rows");
        assert_eq!(envelope.track_beyond_mm(1600.0), Some(100.0));
        assert_eq!(envelope.track_beyond_mm(-20.0), Some(20.0));
        let untracked = JointEnvelope::new(vec![[0.0; MAX_JOINTS]]).expect("rows");
        assert_eq!(untracked.track_beyond_mm(1600.0), None);
        let limits = EnvelopeLimits {
            max_distance_deg: 30.0,
            max_u95_mm: 0.5,
            max_track_beyond_mm: 50.0,
        };
        let at = |e_mm| EnvelopeMeasures {
            track_beyond_mm: envelope.track_beyond_mm(e_mm),
            ..EnvelopeMeasures::default()
        };
        assert_eq!(judged(Status::Ok, &at(1540.0), &limits), Status::Ok);
        assert_eq!(
            judged(Status::Ok, &at(1600.0), &limits),
            Status::OutsideEnvelope
        );
    }

    #[test]
    fn no_rows_is_no_envelope() {
        assert!(JointEnvelope::new(Vec::new()).is_none());
    }
}
