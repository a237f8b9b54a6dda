//! A one- or two-axis positioner carrying the work (issue #30): its own
//! revolute chain, standing in the cell, whose table holds SMR nests the
//! tracker measures while the positioner turns.
//!
//! Why its own chain, calibrated jointly with the arm: the work sits on the
//! table, so where a target on the part lies in the robot's frame depends on
//! where the positioner's axes really are (their position and direction to a
//! few tenths of a millimetre and hundredths of a degree), not on the
//! drawing. The tracker sees the arm's SMR and the table's nests in one
//! frame, so one fit places both in the robot's base.
//!
//! The chain, from the robot's base (with the carriage at 0 on a track):
//!
//! `B · A_1(q_1) · A_2(q_2) · s`
//!
//! with `B` the positioner's base in eq. (3)'s convention
//! (`Rot(x,α)·Rot(y,β)·Rot(z,γ)·Trans(x,y,z)`, like the robot file's
//! `[world]`), each axis Craig's modified DH
//! `A_k = Rot(x,α_k)·Trans(x,a_k)·Rot(z,θ_k + q_k)·Trans(z,d_k)` like the
//! arm's joints, and `s` a nest's position on the table (its target's
//! translation, `x_t[id]` in the parameters table: in the table's frame, not
//! the flange's). The parameters are the base's six values (absolute, like
//! the world frame's: `x_p … gamma_p`) and per axis the four MDH errors
//! (`dtheta_p1, dalpha_p1, da_p1, dd_p1`, …). Many are dependent (the first
//! axis's four on the base; a nest's height on the last axis's `dd`); the
//! rank analysis holds them, as it does the arm's.
//!
//! The positioner carries no load the model knows: the work's weight bends
//! nothing here (a positioner's axes are stiff beside an arm's).

use nalgebra::{Matrix3, Vector3};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::file::TransformSpec;
use super::frame::{Frame, rot_x, rot_y};

/// Axes a positioner can have.
pub const MAX_POSITIONER_AXES: usize = 2;

/// Parameter slots of a positioner: the base's six, then four per axis.
pub const POSITIONER_TERM_COUNT: usize = 6 + 4 * MAX_POSITIONER_AXES;

/// Nests (SMR targets) a positioner's table can carry.
pub const MAX_POSITIONER_NESTS: usize = 4;

const DEG: f64 = std::f64::consts::PI / 180.0;

/// One revolute axis of the positioner (Craig's modified DH, as the arm's
/// joints).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PositionerAxisSpec {
    /// Twist about the previous x axis, degrees.
    pub alpha_deg: f64,
    /// Length along the previous x axis, millimetres.
    pub a_mm: f64,
    /// Constant added to the axis value to get the MDH angle, degrees.
    pub theta_offset_deg: f64,
    /// Offset along the axis (its z), millimetres.
    pub d_mm: f64,
    /// Software limits `[min, max]`, degrees.
    pub limits_deg: [f64; 2],
    /// The controller's pulse ratio of the axis (pulses per degree, signed):
    /// a Yaskawa job gives station axes in pulses (`EC` data), and needs it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulses_per_deg: Option<f64>,
}

/// The robot file's optional `[positioner]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PositionerSpec {
    /// Nominal robot base (carriage at 0) ← positioner base, eq. (3)'s
    /// convention like `[world]`: the base's z axis is the first axis when
    /// that axis's `alpha_deg`, `a_mm` are 0.
    pub base: TransformSpec,
    /// One or two revolute axes, from the base to the table. Rows record
    /// their values as `p1_deg`, `p2_deg`.
    pub axes: Vec<PositionerAxisSpec>,
    /// The `target_id`s of the SMR nests on the table (1 to
    /// [`MAX_POSITIONER_NESTS`]): rows measuring one of them are positioner
    /// rows, whose position the positioner's axes decide and the arm's do not.
    pub nests: Vec<String>,
}

/// Which coefficient of the positioner a parameter is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PositionerTerm {
    /// Base translation along axis 0, 1, 2 (mm; absolute).
    BaseTranslation(usize),
    /// Base rotation, eq. (3) order x, y, z (deg; absolute).
    BaseRotation(usize),
    /// Offset error of axis k (0-based), deg.
    Theta(usize),
    /// Twist error of axis k, deg.
    Alpha(usize),
    /// Length error of axis k, mm.
    A(usize),
    /// Offset error along axis k, mm.
    D(usize),
}

impl PositionerTerm {
    /// The term in slot `slot` (0 … [`POSITIONER_TERM_COUNT`]).
    pub fn of_slot(slot: usize) -> PositionerTerm {
        match slot {
            0..=2 => PositionerTerm::BaseTranslation(slot),
            3..=5 => PositionerTerm::BaseRotation(slot - 3),
            _ => {
                let axis = (slot - 6) / 4;
                match (slot - 6) % 4 {
                    0 => PositionerTerm::Theta(axis),
                    1 => PositionerTerm::Alpha(axis),
                    2 => PositionerTerm::A(axis),
                    _ => PositionerTerm::D(axis),
                }
            }
        }
    }

    pub fn slot(self) -> usize {
        match self {
            PositionerTerm::BaseTranslation(i) => i,
            PositionerTerm::BaseRotation(i) => 3 + i,
            PositionerTerm::Theta(k) => 6 + 4 * k,
            PositionerTerm::Alpha(k) => 7 + 4 * k,
            PositionerTerm::A(k) => 8 + 4 * k,
            PositionerTerm::D(k) => 9 + 4 * k,
        }
    }

    /// The axis (0-based) an MDH term belongs to; `None` for the base.
    pub fn axis(self) -> Option<usize> {
        match self {
            PositionerTerm::BaseTranslation(_) | PositionerTerm::BaseRotation(_) => None,
            PositionerTerm::Theta(k)
            | PositionerTerm::Alpha(k)
            | PositionerTerm::A(k)
            | PositionerTerm::D(k) => Some(k),
        }
    }

    /// `x_p … gamma_p`, then `dtheta_p1, dalpha_p1, da_p1, dd_p1, …`.
    pub fn name(self) -> String {
        match self {
            PositionerTerm::BaseTranslation(i) => format!("{}_p", ["x", "y", "z"][i]),
            PositionerTerm::BaseRotation(i) => format!("{}_p", ["alpha", "beta", "gamma"][i]),
            PositionerTerm::Theta(k) => format!("dtheta_p{}", k + 1),
            PositionerTerm::Alpha(k) => format!("dalpha_p{}", k + 1),
            PositionerTerm::A(k) => format!("da_p{}", k + 1),
            PositionerTerm::D(k) => format!("dd_p{}", k + 1),
        }
    }

    pub fn unit(self) -> &'static str {
        match self {
            PositionerTerm::BaseTranslation(_) | PositionerTerm::A(_) | PositionerTerm::D(_) => {
                "mm"
            }
            _ => "deg",
        }
    }

    /// The robot file's value of an absolute term (the base's), 0 for an
    /// error term.
    pub fn nominal(self, spec: &PositionerSpec) -> f64 {
        let b = &spec.base;
        match self {
            PositionerTerm::BaseTranslation(i) => [b.x_mm, b.y_mm, b.z_mm][i],
            PositionerTerm::BaseRotation(i) => [b.alpha_deg, b.beta_deg, b.gamma_deg][i],
            _ => 0.0,
        }
    }
}

/// A positioner at one parameter set: what every row's evaluation shares.
#[derive(Debug, Clone, Copy)]
pub struct PositionerModel {
    axes: usize,
    /// Robot base ← positioner base.
    base: Frame,
    /// Axes (robot base frame, through its origin) of the base's rotations.
    base_rotation_axes: [Vector3<f64>; 3],
    alpha_sin_cos: [(f64, f64); MAX_POSITIONER_AXES],
    a_mm: [f64; MAX_POSITIONER_AXES],
    d_mm: [f64; MAX_POSITIONER_AXES],
    theta_zero_rad: [f64; MAX_POSITIONER_AXES],
}

/// The positioner's frames at one set of axis values, in the robot base.
#[derive(Debug, Clone, Copy)]
pub struct PositionerChain {
    /// `frames[0]` is the positioner's base, `frames[k]` axis k's MDH frame;
    /// `frames[axes]` is the table.
    pub frames: [Frame; MAX_POSITIONER_AXES + 1],
    pub axes: usize,
}

impl PositionerChain {
    /// Robot base ← table.
    pub fn table(&self) -> Frame {
        self.frames[self.axes]
    }
}

impl PositionerModel {
    /// The positioner of `spec` with its parameters `values` (slot order).
    pub fn new(spec: &PositionerSpec, values: &[f64; POSITIONER_TERM_COUNT]) -> Self {
        let rx = rot_x(values[3] * DEG);
        let rxy = rx * rot_y(values[4] * DEG);
        let term = |t: PositionerTerm| values[t.slot()];
        let axis = |k: usize| spec.axes.get(k).copied();
        PositionerModel {
            axes: spec.axes.len().min(MAX_POSITIONER_AXES),
            base: Frame::from_xyz_euler_then_translation(
                [values[3] * DEG, values[4] * DEG, values[5] * DEG],
                Vector3::new(values[0], values[1], values[2]),
            ),
            base_rotation_axes: [
                Vector3::x(),
                rx.column(1).into_owned(),
                rxy.column(2).into_owned(),
            ],
            alpha_sin_cos: std::array::from_fn(|k| {
                ((axis(k).map_or(0.0, |a| a.alpha_deg) + term(PositionerTerm::Alpha(k))) * DEG)
                    .sin_cos()
            }),
            a_mm: std::array::from_fn(|k| {
                axis(k).map_or(0.0, |a| a.a_mm) + term(PositionerTerm::A(k))
            }),
            d_mm: std::array::from_fn(|k| {
                axis(k).map_or(0.0, |a| a.d_mm) + term(PositionerTerm::D(k))
            }),
            theta_zero_rad: std::array::from_fn(|k| {
                (axis(k).map_or(0.0, |a| a.theta_offset_deg) + term(PositionerTerm::Theta(k))) * DEG
            }),
        }
    }

    pub fn axes(&self) -> usize {
        self.axes
    }

    /// Robot base ← positioner base.
    pub fn base(&self) -> Frame {
        self.base
    }

    /// The frames at axis values `q_deg` (the second ignored on a one-axis
    /// positioner).
    pub fn chain(&self, q_deg: &[f64; MAX_POSITIONER_AXES]) -> PositionerChain {
        let mut frames = [self.base; MAX_POSITIONER_AXES + 1];
        for k in 0..self.axes {
            let (sa, ca) = self.alpha_sin_cos[k];
            let (st, ct) = (q_deg[k] * DEG + self.theta_zero_rad[k]).sin_cos();
            // Rot(x, α)·Trans(x, a)·Rot(z, θ)·Trans(z, d), expanded as the arm's.
            let local = Frame {
                rotation: Matrix3::new(ct, -st, 0.0, ca * st, ca * ct, -sa, sa * st, sa * ct, ca),
                origin_mm: Vector3::new(self.a_mm[k], -sa * self.d_mm[k], ca * self.d_mm[k]),
            };
            frames[k + 1] = frames[k].compose(&local);
        }
        PositionerChain {
            frames,
            axes: self.axes,
        }
    }

    /// d(point)/d(term) in the robot base per mm or degree, for a point at
    /// `point_mm` (robot base) carried by the table.
    pub fn rate(
        &self,
        chain: &PositionerChain,
        term: PositionerTerm,
        point_mm: &Vector3<f64>,
    ) -> Vector3<f64> {
        if term.axis().is_some_and(|k| k >= self.axes) {
            return Vector3::zeros();
        }
        let rotation_about =
            |axis: Vector3<f64>, through: Vector3<f64>| axis.cross(&(point_mm - through)) * DEG;
        let f = &chain.frames;
        match term {
            PositionerTerm::BaseTranslation(i) => self.base.axis(i),
            PositionerTerm::BaseRotation(i) => {
                rotation_about(self.base_rotation_axes[i], Vector3::zeros())
            }
            PositionerTerm::Theta(k) => rotation_about(f[k + 1].axis(2), f[k + 1].origin_mm),
            PositionerTerm::Alpha(k) => rotation_about(f[k].axis(0), f[k].origin_mm),
            PositionerTerm::A(k) => f[k].axis(0),
            PositionerTerm::D(k) => f[k + 1].axis(2),
        }
    }

    /// d(table rotation)/d(term) as a rotation vector in the robot base,
    /// per degree (zero for the translations).
    pub fn angular_rate(&self, chain: &PositionerChain, term: PositionerTerm) -> Vector3<f64> {
        if term.axis().is_some_and(|k| k >= self.axes) {
            return Vector3::zeros();
        }
        let f = &chain.frames;
        match term {
            PositionerTerm::BaseRotation(i) => self.base_rotation_axes[i],
            PositionerTerm::Theta(k) => f[k + 1].axis(2),
            PositionerTerm::Alpha(k) => f[k].axis(0),
            PositionerTerm::BaseTranslation(_) | PositionerTerm::A(_) | PositionerTerm::D(_) => {
                Vector3::zeros()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tilt-and-turn positioner: a horizontal tilt axis 1.2 m in front of
    /// the robot, the table's turn axis 350 mm above it.
    pub(crate) fn tilt_turn() -> PositionerSpec {
        let axis = |alpha_deg, d_mm| PositionerAxisSpec {
            alpha_deg,
            a_mm: 0.0,
            theta_offset_deg: 0.0,
            d_mm,
            limits_deg: [-180.0, 180.0],
            pulses_per_deg: None,
        };
        PositionerSpec {
            base: TransformSpec {
                x_mm: 1200.0,
                y_mm: 0.0,
                z_mm: 400.0,
                alpha_deg: 90.0,
                beta_deg: 0.0,
                gamma_deg: 0.0,
            },
            axes: vec![axis(0.0, 0.0), axis(-90.0, 350.0)],
            nests: vec!["a".into(), "b".into()],
        }
    }

    fn values(spec: &PositionerSpec) -> [f64; POSITIONER_TERM_COUNT] {
        std::array::from_fn(|slot| {
            let term = PositionerTerm::of_slot(slot);
            term.nominal(spec) + 0.05 * (slot as f64 + 1.0) * if slot % 2 == 0 { 1.0 } else { -1.0 }
        })
    }

    #[test]
    fn slots_names_and_units_go_both_ways() {
        let names: Vec<String> = (0..POSITIONER_TERM_COUNT)
            .map(|slot| {
                let term = PositionerTerm::of_slot(slot);
                assert_eq!(term.slot(), slot);
                term.name()
            })
            .collect();
        assert_eq!(
            names,
            [
                "x_p",
                "y_p",
                "z_p",
                "alpha_p",
                "beta_p",
                "gamma_p",
                "dtheta_p1",
                "dalpha_p1",
                "da_p1",
                "dd_p1",
                "dtheta_p2",
                "dalpha_p2",
                "da_p2",
                "dd_p2"
            ]
        );
        assert_eq!(PositionerTerm::of_slot(12).unit(), "mm");
        assert_eq!(PositionerTerm::of_slot(11).unit(), "deg");
    }

    /// The table at q = 0 of the nominal tilt-turn positioner, by hand: the
    /// base turned +90° about x puts its z along −y; the second axis's
    /// frame is 350 mm along the first's z, with the twist of −90° turning
    /// its z onto the base's y (robot's +z).
    #[test]
    fn the_nominal_table_is_where_the_drawing_puts_it() {
        let spec = tilt_turn();
        let nominal: [f64; POSITIONER_TERM_COUNT] =
            std::array::from_fn(|slot| PositionerTerm::of_slot(slot).nominal(&spec));
        let model = PositionerModel::new(&spec, &nominal);
        let table = model.chain(&[0.0, 0.0]).table();
        // Base origin: Rot(x, 90°)·(1200, 0, 400) = (1200, −400, 0).
        assert!((model.base.origin_mm - Vector3::new(1200.0, -400.0, 0.0)).norm() < 1e-9);
        // Axis 2 sits 350 mm along axis 1's z; Rot(x, −90°) turns z onto y
        // of frame 1, which the base turned onto the robot's z.
        let expected = model.base.origin_mm + model.base.axis(1) * 350.0;
        assert!((table.origin_mm - expected).norm() < 1e-9, "{table:?}");
        assert!((table.axis(2) - Vector3::z()).norm() < 1e-12);
    }

    /// Every rate against central differences of a point on the table.
    #[test]
    fn rates_match_finite_differences() {
        let spec = tilt_turn();
        let on_table = Vector3::new(120.0, -80.0, 35.0);
        for q in [[0.0, 0.0], [35.0, -120.0], [-70.0, 200.0]] {
            let model = PositionerModel::new(&spec, &values(&spec));
            let chain = model.chain(&q);
            let point = chain.table().transform_point(&on_table);
            for slot in 0..POSITIONER_TERM_COUNT {
                let term = PositionerTerm::of_slot(slot);
                let at = |delta: f64| {
                    let mut moved = values(&spec);
                    moved[slot] += delta;
                    PositionerModel::new(&spec, &moved)
                        .chain(&q)
                        .table()
                        .transform_point(&on_table)
                };
                let h = 1e-5;
                let numeric = (at(h) - at(-h)) / (2.0 * h);
                let analytic = model.rate(&chain, term, &point);
                assert!(
                    (numeric - analytic).norm() < 1e-6 * (1.0 + analytic.norm()),
                    "{} at {q:?}: {numeric:?} vs {analytic:?}",
                    term.name()
                );
                let rotation_at = |delta: f64| {
                    let mut moved = values(&spec);
                    moved[slot] += delta;
                    PositionerModel::new(&spec, &moved)
                        .chain(&q)
                        .table()
                        .rotation
                };
                let turn = rotation_at(h) * rotation_at(-h).transpose();
                let numeric_angular = crate::robot::frame::rotation_vector(&turn) / (2.0 * h) / DEG;
                let angular = model.angular_rate(&chain, term);
                assert!(
                    (numeric_angular - angular).norm() < 1e-6,
                    "{} angular at {q:?}: {numeric_angular:?} vs {angular:?}",
                    term.name()
                );
            }
        }
    }

    /// The whole positioner row (world frame, base, both axes with errors,
    /// a nest) through `Robot::predict_row`, against the independent numpy
    /// chain of `fixtures/tools/positioner_fk.py` (its output pasted).
    #[test]
    fn nest_positions_match_an_independent_chain() {
        use crate::robot::{ConfWrench, ParamId, ParamValues, Wrench};
        let robot = crate::robot::test_support::irb1600_with_positioner();
        let mut p = ParamValues::nominal(robot.spec());
        for (name, value) in [
            ("x_w", 1326.0),
            ("y_w", 1362.0),
            ("z_w", -1476.0),
            ("alpha_w", -180.0),
            ("beta_w", 0.0),
            ("gamma_w", 0.0),
            ("x_p", 1001.5),
            ("y_p", 299.2),
            ("z_p", 0.6),
            ("alpha_p", 90.05),
            ("beta_p", -0.04),
            ("gamma_p", 0.03),
            ("dalpha_p1", 0.02),
            ("da_p1", 0.3),
            ("dtheta_p1", 0.1),
            ("dd_p1", -0.2),
            ("dalpha_p2", 0.03),
            ("da_p2", 0.4),
            ("dtheta_p2", 0.5),
            ("dd_p2", 0.2),
        ] {
            p.set(ParamId::from_name(name).unwrap(), value);
        }
        for (axis, value) in [180.0, -60.0, 25.0].into_iter().enumerate() {
            p.set(ParamId::target_translation(2, axis), value);
        }
        let cases = [
            (
                [0.0, 0.0],
                [2508.120574976, -1301.780051617, 1000.768818855],
            ),
            (
                [30.0, 45.0],
                [2386.212508680, -1446.547982943, 939.591868163],
            ),
            (
                [-85.0, -270.0],
                [2507.620962911, -1540.990868637, 1218.973351883],
            ),
            (
                [60.0, 350.0],
                [2259.378789720, -1271.424835352, 943.445774926],
            ),
        ];
        for (p_deg, expected) in cases {
            let row = ConfWrench {
                target: 2,
                positioner_deg: Some(p_deg),
                ..ConfWrench::new([10.0; 7], Wrench::zero())
            };
            let got = robot.prepare(&p).predict_row(&row).position_mm;
            assert!(
                (got - Vector3::from(expected)).norm() < 1e-8,
                "{p_deg:?}: {got:?} vs {expected:?}"
            );
        }
    }

    #[test]
    fn a_one_axis_positioner_ignores_the_second_axis() {
        let mut spec = tilt_turn();
        spec.axes.truncate(1);
        let model = PositionerModel::new(&spec, &values(&spec));
        let a = model.chain(&[30.0, 0.0]).table();
        let b = model.chain(&[30.0, 90.0]).table();
        assert_eq!(a, b);
        let chain = model.chain(&[30.0, 0.0]);
        assert_eq!(
            model.rate(&chain, PositionerTerm::Theta(1), &Vector3::x()),
            Vector3::zeros()
        );
    }
}
