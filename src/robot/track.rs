//! A linear track carrying the arm (issue #30): the robot base rides on a
//! carriage at position `e` (mm, the axis value each row records as
//! `e1_mm`), moving along the base frame's x axis as it is at `e = 0`.
//!
//! Why errors as functions of the position: a track's rail is neither
//! straight nor flat to the arm's accuracy. Over a few metres it bends by
//! tenths of a millimetre (straightness) and the carriage rolls, pitches and
//! yaws by hundredths of a degree, and its scale differs from the encoder's.
//! No constant of the six-joint model absorbs an error that changes along
//! the travel, so the carriage's transform carries its own parameters:
//!
//! `C(e) = Trans(e + s·u, y(u), z(u)) · Rot(z, yaw(u)) · Rot(y, pitch(u)) · Rot(x, roll(u))`
//!
//! with `u = e / L` (`L` the travel's length), the scale error `s` (mm at
//! the full travel) and each of y, z (mm), roll, pitch, yaw (deg) a
//! polynomial `Σ c_k·u^k`, k = 1 … [`MAX_TRACK_ORDER`]. No constant terms:
//! at `e = 0` the carriage is the identity, so the world frame (world ←
//! base) keeps its meaning as the base at `e = 0`; a constant angle or
//! offset would be the world frame's own. The linear straightness terms are
//! the rail's misalignment with the base's x axis.
//!
//! The model places the whole arm, loads included, by `C(e)`; gravity is
//! taken in the base frame as the robot file gives it (a carriage tilt of
//! 0.02° changes a gravity torque by 3.5e-4 of itself).

use nalgebra::{Matrix3, Vector3};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::frame::{Frame, rot_x, rot_y, rot_z};

/// Highest polynomial order of the track's straightness and angle errors.
pub const MAX_TRACK_ORDER: usize = 3;

/// The error functions of a track: the scale, then per direction and order.
pub const TRACK_TERM_COUNT: usize = 1 + 5 * MAX_TRACK_ORDER;

const DEG: f64 = std::f64::consts::PI / 180.0;

/// The robot file's optional `[track]` table.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TrackSpec {
    /// The carriage's travel `[min, max]`, mm along the base frame's x axis
    /// at 0 (write the robot file's base so that its x axis runs along the
    /// rail).
    pub travel_mm: [f64; 2],
    /// Highest order of the straightness and angle polynomials the
    /// calibration fits (1 … 3; 1: misalignment and linear twist only).
    #[serde(default = "default_order")]
    pub polynomial_order: usize,
    /// Encoder pulses per millimetre of the carriage as the controller
    /// counts them, signed (a Yaskawa controller's base-axis pulse ratio).
    /// Optional; only Yaskawa jobs need it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulses_per_mm: Option<f64>,
}

fn default_order() -> usize {
    MAX_TRACK_ORDER
}

impl TrackSpec {
    /// The travel's length, mm: the scale of `u`.
    pub fn length_mm(&self) -> f64 {
        let [lo, hi] = self.travel_mm;
        hi.abs().max(lo.abs()).max(hi - lo)
    }
}

/// Which error function a track parameter is a coefficient of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackTerm {
    /// The scale error, mm at the full travel.
    Scale,
    /// Straightness across (axis 1: y) or up (axis 2: z), mm, of order k.
    Straightness { axis: usize, order: usize },
    /// Roll (axis 0), pitch (1) or yaw (2), deg, of order k.
    Angle { axis: usize, order: usize },
}

impl TrackTerm {
    /// The term in slot `slot` (0 … [`TRACK_TERM_COUNT`]): the scale, then
    /// per order y, z, roll, pitch, yaw.
    pub fn of_slot(slot: usize) -> TrackTerm {
        if slot == 0 {
            return TrackTerm::Scale;
        }
        let order = 1 + (slot - 1) / 5;
        match (slot - 1) % 5 {
            0 => TrackTerm::Straightness { axis: 1, order },
            1 => TrackTerm::Straightness { axis: 2, order },
            k => TrackTerm::Angle { axis: k - 2, order },
        }
    }

    pub fn slot(self) -> usize {
        match self {
            TrackTerm::Scale => 0,
            TrackTerm::Straightness { axis, order } => 1 + 5 * (order - 1) + (axis - 1),
            TrackTerm::Angle { axis, order } => 1 + 5 * (order - 1) + 2 + axis,
        }
    }

    /// The parameter's name: `track_scale`, `track_y2`, `track_pitch1` …
    pub fn name(self) -> String {
        match self {
            TrackTerm::Scale => "track_scale".into(),
            TrackTerm::Straightness { axis, order } => {
                format!("track_{}{order}", ["x", "y", "z"][axis])
            }
            TrackTerm::Angle { axis, order } => {
                format!("track_{}{order}", ["roll", "pitch", "yaw"][axis])
            }
        }
    }

    pub fn unit(self) -> &'static str {
        match self {
            TrackTerm::Angle { .. } => "deg",
            _ => "mm",
        }
    }

    pub fn order(self) -> usize {
        match self {
            TrackTerm::Scale => 1,
            TrackTerm::Straightness { order, .. } | TrackTerm::Angle { order, .. } => order,
        }
    }
}

/// A track's error coefficients, in slot order (see [`TrackTerm`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackErrors {
    pub length_mm: f64,
    pub coefficients: [f64; TRACK_TERM_COUNT],
}

/// The carriage at one position: its frame and what the Jacobian needs.
#[derive(Debug, Clone, Copy)]
pub struct Carriage {
    /// Base at `e = 0` ← base at `e`.
    pub frame: Frame,
    /// `u = e / L`.
    pub u: f64,
    /// The axes (base-at-0 frame) the roll, pitch and yaw turn about:
    /// `Rz·Ry·x`, `Rz·y`, `z`.
    pub angle_axes: [Vector3<f64>; 3],
}

impl TrackErrors {
    fn polynomial(&self, u: f64, term: impl Fn(usize) -> TrackTerm) -> f64 {
        (1..=MAX_TRACK_ORDER)
            .map(|k| self.coefficients[term(k).slot()] * u.powi(k as i32))
            .sum()
    }

    /// The carriage at position `e_mm`.
    pub fn carriage(&self, e_mm: f64) -> Carriage {
        let u = e_mm / self.length_mm;
        let straight = |axis| self.polynomial(u, |order| TrackTerm::Straightness { axis, order });
        let angle = |axis| self.polynomial(u, |order| TrackTerm::Angle { axis, order }) * DEG;
        let (roll, pitch, yaw) = (angle(0), angle(1), angle(2));
        let rz = rot_z(yaw);
        let rzy = rz * rot_y(pitch);
        let rotation: Matrix3<f64> = rzy * rot_x(roll);
        let scale = self.coefficients[TrackTerm::Scale.slot()];
        Carriage {
            frame: Frame {
                rotation,
                origin_mm: Vector3::new(e_mm + scale * u, straight(1), straight(2)),
            },
            u,
            angle_axes: [
                rzy.column(0).into_owned(),
                rz.column(1).into_owned(),
                Vector3::z(),
            ],
        }
    }
}

impl Carriage {
    /// d(point)/d(coefficient of `term`), base-at-0 frame, per mm or per
    /// degree, for a point at `in_base_mm` in the carriage's (base) frame.
    pub fn rate(&self, term: TrackTerm, in_base_mm: &Vector3<f64>) -> Vector3<f64> {
        let power = self.u.powi(term.order() as i32);
        match term {
            TrackTerm::Scale => Vector3::x() * self.u,
            TrackTerm::Straightness { axis, .. } => {
                let mut v = Vector3::zeros();
                v[axis] = power;
                v
            }
            TrackTerm::Angle { axis, .. } => {
                self.angle_axes[axis].cross(&(self.frame.rotation * in_base_mm)) * DEG * power
            }
        }
    }

    /// d(tool rotation)/d(coefficient of an angle term) as a rotation
    /// vector, base-at-0 frame, per degree; zero for the others.
    pub fn angular_rate(&self, term: TrackTerm) -> Vector3<f64> {
        match term {
            TrackTerm::Angle { axis, order } => self.angle_axes[axis] * self.u.powi(order as i32),
            _ => Vector3::zeros(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_and_names_go_both_ways() {
        let names: Vec<String> = (0..TRACK_TERM_COUNT)
            .map(|slot| {
                let term = TrackTerm::of_slot(slot);
                assert_eq!(term.slot(), slot);
                term.name()
            })
            .collect();
        assert_eq!(
            names[..7],
            [
                "track_scale",
                "track_y1",
                "track_z1",
                "track_roll1",
                "track_pitch1",
                "track_yaw1",
                "track_y2"
            ]
        );
        assert_eq!(names.last().map(String::as_str), Some("track_yaw3"));
    }

    fn errors() -> TrackErrors {
        let mut coefficients = [0.0; TRACK_TERM_COUNT];
        for (slot, c) in coefficients.iter_mut().enumerate() {
            *c = 0.1 * (slot as f64 + 1.0) * if slot % 2 == 0 { 1.0 } else { -1.0 };
        }
        TrackErrors {
            length_mm: 3000.0,
            coefficients,
        }
    }

    #[test]
    fn the_carriage_is_the_identity_at_zero_and_moves_along_x() {
        let mut nominal = errors();
        nominal.coefficients = [0.0; TRACK_TERM_COUNT];
        let at_zero = errors().carriage(0.0).frame;
        assert!(at_zero.origin_mm.norm() < 1e-12);
        assert!((at_zero.rotation - Matrix3::identity()).abs().max() < 1e-12);
        let moved = nominal.carriage(1234.5).frame;
        assert_eq!(moved.origin_mm, Vector3::new(1234.5, 0.0, 0.0));
        // y(u) = Σ c_k u^k by hand at u = 0.5 for the coefficients above.
        let e = errors();
        let c = |t: TrackTerm| e.coefficients[t.slot()];
        let y = |order| c(TrackTerm::Straightness { axis: 1, order });
        let expected = y(1) * 0.5 + y(2) * 0.25 + y(3) * 0.125;
        assert!((e.carriage(1500.0).frame.origin_mm.y - expected).abs() < 1e-12);
    }

    /// Every rate against central differences of the carriage's point.
    #[test]
    fn rates_match_finite_differences() {
        let point = Vector3::new(800.0, -300.0, 1200.0);
        for e_mm in [-500.0, 700.0, 2900.0] {
            for slot in 0..TRACK_TERM_COUNT {
                let term = TrackTerm::of_slot(slot);
                let at = |delta: f64| {
                    let mut moved = errors();
                    moved.coefficients[slot] += delta;
                    let carriage = moved.carriage(e_mm);
                    (
                        carriage.frame.transform_point(&point),
                        carriage.frame.rotation,
                    )
                };
                let h = 1e-4;
                let (plus, r_plus) = at(h);
                let (minus, r_minus) = at(-h);
                let numeric = (plus - minus) / (2.0 * h);
                let analytic = errors().carriage(e_mm).rate(term, &point);
                assert!(
                    (numeric - analytic).norm() < 1e-7 * (1.0 + analytic.norm()),
                    "{} at {e_mm}: {numeric:?} vs {analytic:?}",
                    term.name()
                );
                // The rotation's rate as a rotation vector (deg per unit).
                let r0 = errors().carriage(e_mm).frame.rotation;
                let skew = (r_plus - r_minus) / (2.0 * h) * r0.transpose();
                let numeric_angular = Vector3::new(skew[(2, 1)], skew[(0, 2)], skew[(1, 0)]) / DEG;
                let angular = errors().carriage(e_mm).angular_rate(term);
                assert!(
                    (numeric_angular - angular).norm() < 1e-6,
                    "{} angular: {numeric_angular:?} vs {angular:?}",
                    term.name()
                );
            }
        }
    }
}
