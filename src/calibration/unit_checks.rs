//! Unit mistakes in measured rows, caught before any fit.
//!
//! A tracker export in metres read as millimetres calibrates "perfectly": the
//! fit shrinks the arm 1000× (`da3 = -699 mm`) and validates at 0.002 mm.
//! Joints in radians read as degrees barely move the model. Neither is visible
//! in a residual, both are visible in the geometry of the rows: the measured
//! points spread over a volume the nominal robot, at the same joints, does not.
//!
//! The spread is the RMS distance of the points from their centroid: invariant
//! to the unknown tracker frame, and insensitive to an unknown tool of a few
//! hundred millimetres on an arm that moves over a metre.

use nalgebra::Vector3;

use crate::robot::{ConfWrench, ParamValues, Robot, batch_predict};

/// Measured-to-nominal spread ratios accepted as the same unit. A robot is
/// never 2× larger than its data sheet; the nearest unit mistakes are 10×
/// (cm) and 25.4× (inches).
pub const SPREAD_RATIO_RANGE: (f64, f64) = (0.5, 2.0);

/// Below this nominal spread (mm) the rows barely move the arm and the ratio
/// says nothing (a tool offset dominates it).
pub const MIN_NOMINAL_SPREAD_MM: f64 = 20.0;

/// Rows needed before a spread or a range of joint values means anything.
pub const MIN_ROWS: usize = 5;

/// Rows the spreads are computed on, evenly strided over larger tables: a
/// ratio that must fall within 0.5–2 is settled by 10 000 rows, and predicting
/// all of a million took a third of a second (issue #31).
pub const SPREAD_ROWS: usize = 10_000;

/// A likely unit mistake in the rows.
#[derive(Debug, Clone, PartialEq)]
pub enum UnitSuspicion {
    /// The measured points spread `ratio` times as far as the nominal robot's.
    Length {
        measured_spread_mm: f64,
        nominal_spread_mm: f64,
        ratio: f64,
        /// What the values most likely are in, e.g. "metres".
        likely_unit: &'static str,
    },
    /// Every joint value lies within ±2π "degrees".
    JointsInRadians { largest_abs_deg: f64 },
}

impl UnitSuspicion {
    /// What a user reads: the evidence and the likely unit.
    pub fn describe(&self) -> String {
        match self {
            UnitSuspicion::Length {
                measured_spread_mm,
                nominal_spread_mm,
                ratio,
                likely_unit,
            } => format!(
                "the measured points spread {measured_spread_mm:.4} mm (RMS about their centre) where the nominal robot at the same joints spreads {nominal_spread_mm:.1} mm (ratio {ratio:.4}): the positions look like {likely_unit} read as millimetres"
            ),
            UnitSuspicion::JointsInRadians { largest_abs_deg } => format!(
                "every joint value lies within ±2π (largest |q| {largest_abs_deg:.3}): the joints look like radians read as degrees"
            ),
        }
    }
}

/// Known length units by how many millimetres one of their units is, for the
/// name of the likely one.
const LENGTH_UNITS: [(f64, &str); 5] = [
    (1000.0, "metres"),
    (100.0, "decimetres"),
    (25.4, "inches"),
    (10.0, "centimetres"),
    (0.001, "micrometres"),
];

/// The first unit mistake the rows show, if any: joints first (with radians
/// read as degrees the nominal spread is meaningless), then lengths.
pub fn suspect_units(
    robot: &Robot,
    rows: &[ConfWrench],
    measured_mm: &[Vector3<f64>],
) -> Option<UnitSuspicion> {
    if rows.len() < MIN_ROWS || measured_mm.len() != rows.len() {
        return None;
    }
    // A prismatic joint's value is millimetres: only the revolute ones tell.
    let revolute: Vec<usize> = (0..robot.joint_count())
        .filter(|&joint| !robot.is_prismatic(joint))
        .collect();
    let largest_abs_deg = rows
        .iter()
        .flat_map(|r| revolute.iter().map(|&joint| r.q_deg[joint]))
        .fold(0.0_f64, |m, q| m.max(q.abs()));
    let limits_span_deg = revolute
        .iter()
        .map(|&joint| {
            let [lo, hi] = robot.joint_limits(joint);
            hi - lo
        })
        .fold(0.0_f64, f64::max);
    if largest_abs_deg <= std::f64::consts::TAU && limits_span_deg > 4.0 * std::f64::consts::PI {
        return Some(UnitSuspicion::JointsInRadians { largest_abs_deg });
    }
    let stride = rows.len().div_ceil(SPREAD_ROWS);
    let sampled_rows: Vec<ConfWrench> = rows.iter().step_by(stride).copied().collect();
    let sampled_measured_mm: Vec<Vector3<f64>> =
        measured_mm.iter().step_by(stride).copied().collect();
    let nominal = ParamValues::nominal(robot.spec());
    let predicted: Vec<Vector3<f64>> = batch_predict(robot, &nominal, &sampled_rows)
        .iter()
        .map(|p| p.position_mm)
        .collect();
    let nominal_spread_mm = spread(&predicted);
    if nominal_spread_mm < MIN_NOMINAL_SPREAD_MM {
        return None;
    }
    let measured_spread_mm = spread(&sampled_measured_mm);
    let ratio = measured_spread_mm / nominal_spread_mm;
    if (SPREAD_RATIO_RANGE.0..=SPREAD_RATIO_RANGE.1).contains(&ratio) || !ratio.is_finite() {
        return None;
    }
    // Values in unit U read as mm shrink the spread by U's size in mm.
    let likely_unit = LENGTH_UNITS
        .iter()
        .min_by(|a, b| {
            (ratio * a.0)
                .ln()
                .abs()
                .total_cmp(&(ratio * b.0).ln().abs())
        })
        .map_or("another unit", |(_, name)| *name);
    Some(UnitSuspicion::Length {
        measured_spread_mm,
        nominal_spread_mm,
        ratio,
        likely_unit,
    })
}

/// RMS distance of the points from their centroid (mm).
fn spread(points: &[Vector3<f64>]) -> f64 {
    let n = points.len() as f64;
    let centre = points.iter().sum::<Vector3<f64>>() / n;
    (points
        .iter()
        .map(|p| (p - centre).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::irb1600;
    use crate::robot::{Wrench, batch_predict};

    fn rows() -> Vec<ConfWrench> {
        (0..12)
            .map(|k| {
                let t = k as f64;
                ConfWrench::new(
                    [
                        -60.0 + 10.0 * t,
                        -20.0 + 4.0 * t,
                        10.0 - 3.0 * t,
                        5.0 * t,
                        30.0 + 2.0 * t,
                        t,
                        0.0,
                    ],
                    Wrench::zero(),
                )
            })
            .collect()
    }

    fn measured(scale: f64) -> Vec<Vector3<f64>> {
        let robot = irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        batch_predict(&robot, &nominal, &rows())
            .iter()
            .map(|p| (p.position_mm + Vector3::new(1000.0, -200.0, 50.0)) * scale)
            .collect()
    }

    #[test]
    fn millimetres_pass() {
        assert_eq!(suspect_units(&irb1600(), &rows(), &measured(1.0)), None);
    }

    #[test]
    fn metres_and_inches_are_named() {
        let robot = irb1600();
        for (scale, unit) in [
            (1e-3, "metres"),
            (1.0 / 25.4, "inches"),
            (0.1, "centimetres"),
        ] {
            match suspect_units(&robot, &rows(), &measured(scale)) {
                Some(UnitSuspicion::Length {
                    likely_unit, ratio, ..
                }) => {
                    assert_eq!(likely_unit, unit, "scale {scale}");
                    assert!((ratio / scale - 1.0).abs() < 1e-9, "{ratio}");
                }
                other => panic!("scale {scale}: {other:?}"),
            }
        }
    }

    #[test]
    fn radians_read_as_degrees_are_named() {
        let robot = irb1600();
        let radians: Vec<ConfWrench> = rows()
            .into_iter()
            .map(|mut r| {
                r.q_deg = r.q_deg.map(f64::to_radians);
                r
            })
            .collect();
        let found = suspect_units(&robot, &radians, &measured(1.0));
        assert!(
            matches!(found, Some(UnitSuspicion::JointsInRadians { .. })),
            "{found:?}"
        );
        assert!(
            found
                .unwrap()
                .describe()
                .contains("radians read as degrees")
        );
    }
}
