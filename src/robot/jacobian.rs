//! The identification Jacobian d(SMR position)/d(parameters) (paper eqs. (20)–(24)),
//! analytic, for any subset of the 42 parameters.
//!
//! Every geometric parameter is an elementary screw on part of the chain: a
//! rotation about an axis through a point, or a translation along an axis, that
//! moves the bodies from some link `s` on (the tool and payload are body 7). Its
//! column is the screw's velocity at the SMR on the deflected chain, plus the change
//! in deflection `k_i·dτ_i/dv` that the screw causes through the load torques on
//! the undeflected chain. The torque derivatives use the fact that a screw moves
//! everything downstream rigidly except gravity; see [`DeflectionMaps`].
//!
//! Cost per row: two chain evaluations (six `sin_cos`), seven 3×3 maps, then a
//! few 3×3 products per column; no allocation.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::frame::Frame;
use super::model::{
    Chain, LoadedChains, Loads, MAX_JOINTS, Prediction, PreparedRobot, Robot, Wrench,
};
use super::params::{ParamId, ParamKind, ParamValues};
use super::positioner::{MAX_POSITIONER_AXES, PositionerChain};

const DEG: f64 = std::f64::consts::PI / 180.0;
const MM: f64 = 1e-3;

/// An infinitesimal motion of part of the chain, in one frame's coordinates.
#[derive(Debug, Clone, Copy)]
enum Screw {
    /// Rotation (per radian) about `axis` through `point_mm`.
    Rotation {
        axis: Vector3<f64>,
        point_mm: Vector3<f64>,
    },
    /// Translation (per millimetre) along `axis`.
    Translation { axis: Vector3<f64> },
}

impl Screw {
    fn velocity_at(&self, point_mm: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Screw::Rotation { axis, point_mm: o } => axis.cross(&(point_mm - o)),
            Screw::Translation { axis } => *axis,
        }
    }

    /// Twist `(ω rad, v m)` per parameter unit, for the torque derivatives in SI units.
    fn twist_si(&self) -> (Vector3<f64>, Vector3<f64>) {
        match self {
            Screw::Rotation { axis, point_mm } => (axis * DEG, (point_mm * MM).cross(axis) * DEG),
            Screw::Translation { axis } => (Vector3::zeros(), axis * MM),
        }
    }

    /// Scale from the screw's natural unit to the parameter's unit (deg or mm).
    fn per_unit(&self) -> f64 {
        match self {
            Screw::Rotation { .. } => DEG,
            Screw::Translation { .. } => 1.0,
        }
    }
}

/// The screw of a geometric parameter on `chain`, and the first body it moves
/// (1..=n links, n+1 the tool and payload, n the joint count). `None` for world parameters, compliances
/// and joint-error terms, which need no torque term.
impl PreparedRobot<'_> {
    // Inlined: returned through memory, the screw costs a store-forwarding stall per column.
    #[inline(always)]
    fn chain_screw(&self, id: ParamId, chain: &Chain) -> Option<(Screw, usize)> {
        let flange = chain.flange();
        let tool_body = chain.joint_count + 1;
        Some(match id.kind() {
            ParamKind::Theta(i) => (
                Screw::Rotation {
                    axis: chain.joints[i + 1].axis(2),
                    point_mm: chain.joints[i + 1].origin_mm,
                },
                i + 1,
            ),
            ParamKind::Alpha(i) => (
                Screw::Rotation {
                    axis: chain.joints[i].axis(0),
                    point_mm: chain.joints[i].origin_mm,
                },
                i + 1,
            ),
            ParamKind::A(i) => (
                Screw::Translation {
                    axis: chain.joints[i].axis(0),
                },
                i + 1,
            ),
            ParamKind::D(i) => (
                Screw::Translation {
                    axis: chain.joints[i + 1].axis(2),
                },
                i + 1,
            ),
            ParamKind::ToolRotation(r) => {
                let local_axis = match r {
                    0 => Vector3::x(),
                    1 => self.tool_rx.column(1).into_owned(),
                    _ => self.tool_rxy.column(2).into_owned(),
                };
                (
                    Screw::Rotation {
                        axis: flange.rotation * local_axis,
                        point_mm: flange.origin_mm,
                    },
                    tool_body,
                )
            }
            ParamKind::ToolTranslation { axis, .. } => (
                Screw::Translation {
                    axis: chain.tool.axis(axis),
                },
                tool_body,
            ),
            ParamKind::WorldTranslation(_)
            | ParamKind::WorldRotation(_)
            | ParamKind::Compliance(_)
            | ParamKind::Backlash(_)
            | ParamKind::Harmonic { .. }
            | ParamKind::Track(_)
            | ParamKind::Positioner(_) => {
                return None;
            }
        })
    }
}

/// Per-row linear maps from a screw's twist to the extra SMR velocity its
/// deflection change causes, `Σ_i k_i·(∂p/∂q_i)·dτ_i/dv`, one map per first moved
/// body `s` (1..=7).
///
/// `dτ_i/dv` is linear in the screw's twist `(ω, v)` (rad and m per parameter unit,
/// base frame, on the undeflected chain). For joints at or after `s` the joint axis,
/// the moved bodies and the wrench all move rigidly and only gravity stays put:
/// `dτ_i = −ω·(g × z_i × G_i)`, with `G_i` the first mass moment of bodies i..7 about
/// joint i. For joints before `s` the joint axis is fixed and the moved bodies'
/// centres of gravity, the wrench's point of application and its direction change:
/// `dτ_i = (t×(f×z_i) + M×z_i + f×(z_i×(t−o_i)))·ω + (f×z_i)·v + h_i·(ω×G_s + m_s·v)`,
/// with `h_i = g×z_i` and `m_s`, `G_s` the mass and first moment (about the base
/// origin) of bodies s..7. Summing over joints turns both into prefix and suffix
/// sums over `i`, so each parameter column costs three 3×3 products instead of a
/// loop over the joints.
///
/// A prismatic joint's load is the force `F_i = z_i·(m_i·g + f)` along its axis
/// (`m_i` the mass of bodies i..7). At or after `s` its axis and the wrench turn
/// together and only gravity stays put: `dF_i = m_i·(z_i×g)·ω`. Before `s` its
/// axis is fixed and only the wrench's direction turns: `dF_i = (f×z_i)·ω`.
struct DeflectionMaps {
    /// Coefficient of `ω` (without the `G_s` term), per first moved body.
    rotation: [Matrix3<f64>; MAX_JOINTS + 1],
    /// Coefficient of `v`, per first moved body.
    translation: [Matrix3<f64>; MAX_JOINTS + 1],
    /// `Σ_{i<s} k_i·(∂p/∂q_i)·h_iᵀ`, applied to `ω × G_s`.
    gravity: [Matrix3<f64>; MAX_JOINTS + 1],
    /// `G_s`, kg·m.
    moment_kgm: [Vector3<f64>; MAX_JOINTS + 1],
}

impl DeflectionMaps {
    /// `deflection_rates[i] = k_i·∂p/∂q_i` (mm per N·m, or per N for a
    /// prismatic joint) on the deflected chain.
    // Inlined: returned through memory, the 2.3 kB of maps cost a copy per row
    // (3 % of a pass, issue #31).
    #[inline(always)]
    fn new(
        undeflected: &Chain,
        loads: &Loads,
        gravity: &Vector3<f64>,
        deflection_rates: &[Vector3<f64>; MAX_JOINTS],
        prismatic: &[bool; MAX_JOINTS],
    ) -> Self {
        let tool_m = undeflected.tool.origin_mm * MM;
        let f = &loads.force_base_n;
        let moment = &loads.moment_base_nm;
        let mut before = [Matrix3::zeros(); 3];
        let mut maps = DeflectionMaps {
            rotation: [Matrix3::zeros(); MAX_JOINTS + 1],
            translation: [Matrix3::zeros(); MAX_JOINTS + 1],
            gravity: [Matrix3::zeros(); MAX_JOINTS + 1],
            moment_kgm: std::array::from_fn(|s| loads.suffix_moment_kgm[s + 1]),
        };
        // Joints before body s: prefix sums (index s − 1 holds joints 0..s−1).
        let n = undeflected.joint_count;
        let mut after = [Matrix3::zeros(); MAX_JOINTS];
        for i in 0..n {
            let s = i + 1;
            let [rotation, translation, gravity_part] = &before;
            maps.rotation[s - 1] = *rotation;
            maps.translation[s - 1] = translation + gravity_part * loads.suffix_mass_kg[s];
            maps.gravity[s - 1] = *gravity_part;

            let joint = &undeflected.joints[s];
            let z = joint.axis(2);
            let rate = &deflection_rates[i];
            if prismatic[i] {
                before[0] += rate * f.cross(&z).transpose();
                after[i] = rate * (z.cross(gravity) * loads.suffix_mass_kg[s]).transpose();
                continue;
            }
            let o = joint.origin_mm * MM;
            let wrench_arm = z.cross(&(tool_m - o));
            let rotation_coefficient =
                tool_m.cross(&f.cross(&z)) + moment.cross(&z) + f.cross(&wrench_arm);
            before[0] += rate * rotation_coefficient.transpose();
            before[1] += rate * f.cross(&z).transpose();
            before[2] += rate * gravity.cross(&z).transpose();

            let gravity_arm = z.cross(&(loads.suffix_moment_kgm[s] - o * loads.suffix_mass_kg[s]));
            after[i] = rate * (-gravity.cross(&gravity_arm)).transpose();
        }
        let [rotation, translation, gravity_part] = &before;
        maps.rotation[n] = *rotation;
        maps.translation[n] = translation + gravity_part * loads.suffix_mass_kg[n + 1];
        maps.gravity[n] = *gravity_part;
        // Joints at or after body s: suffix sums.
        let mut suffix = Matrix3::zeros();
        for i in (0..n).rev() {
            suffix += after[i];
            maps.rotation[i] += suffix;
        }
        maps
    }

    /// Extra SMR velocity (mm per parameter unit, base frame) of a screw with twist
    /// `(ω, v)` that moves bodies `first_body..=7`.
    // Always inlined: as a call (5.9 % of a pass) its matrices went through memory.
    #[inline(always)]
    fn velocity(&self, first_body: usize, twist: &(Vector3<f64>, Vector3<f64>)) -> Vector3<f64> {
        let s = first_body - 1;
        let (omega, v) = twist;
        self.rotation[s] * omega
            + self.translation[s] * v
            + self.gravity[s] * omega.cross(&self.moment_kgm[s])
    }
}

impl PreparedRobot<'_> {
    /// One row's prediction and its Jacobian columns for `selected`, written to
    /// `columns[j]` (mm per parameter unit, world frame). Another target's
    /// translation has a zero column.
    pub fn jacobian_row(
        &self,
        row: &ConfWrench,
        selected: &[ParamId],
        columns: &mut [Vector3<f64>],
    ) -> Prediction {
        self.jacobian_row_inner(row, selected, columns, None).0
    }

    /// [`Self::jacobian_row`] for a 6-D row (spec §8): also the tool's
    /// orientation in the world (world ← tool rotation, deflected chain) and,
    /// in `angular[j]`, the rotation it makes per parameter unit as a world-frame
    /// rotation vector in degrees (`R(p + δ) ≈ exp([ω·δ]×)·R(p)`, ω in deg per unit).
    pub fn jacobian_row_with_orientation(
        &self,
        row: &ConfWrench,
        selected: &[ParamId],
        columns: &mut [Vector3<f64>],
        angular: &mut [Vector3<f64>],
    ) -> (Prediction, Matrix3<f64>) {
        self.jacobian_row_inner(row, selected, columns, Some(angular))
    }

    // Inlined so that the position-only caller compiles to the loop it always was.
    #[inline(always)]
    fn jacobian_row_inner(
        &self,
        row: &ConfWrench,
        selected: &[ParamId],
        columns: &mut [Vector3<f64>],
        mut angular: Option<&mut [Vector3<f64>]>,
    ) -> (Prediction, Matrix3<f64>) {
        let ConfWrench {
            q_deg,
            target,
            approach,
            track_mm,
            ..
        } = row;
        assert_eq!(
            selected.len(),
            columns.len(),
            "one column per selected parameter"
        );
        if let Some(angular) = angular.as_ref() {
            assert_eq!(selected.len(), angular.len(), "one angular column each");
        }
        if let Some((chain, nest_mm)) = self.positioner_nest(row) {
            return self.positioner_jacobian_row(row, &chain, &nest_mm, selected, columns, angular);
        }
        // Borrowed, not destructured: moving the chains out copied 2 kB a row.
        let chains = self.loaded_chains(row);
        let LoadedChains {
            undeflected,
            loads,
            deflections_deg,
            deflected,
        } = &chains;
        // The chain hangs from the world frame through the carriage (the
        // world frame alone without a track); the world parameters move
        // both, the chain's move what hangs from the carriage.
        let world_frame = &self.world_from_base;
        let carriage = self.carriage(*track_mm);
        let world_at_row = self.world_from_base_at(*track_mm);
        let world = &world_at_row;
        let tool_base = deflected.tool.origin_mm;
        let position_mm = world.transform_point(&tool_base);

        let robot = self.robot();
        let prismatic: [bool; MAX_JOINTS] = std::array::from_fn(|i| robot.is_prismatic(i));
        // d(position in base)/d(joint value i) per degree (per mm for a
        // prismatic joint), on the deflected chain.
        let joint_rates: [Vector3<f64>; MAX_JOINTS] = std::array::from_fn(|i| {
            let joint = &deflected.joints[i + 1];
            if prismatic[i] {
                joint.axis(2)
            } else {
                joint.axis(2).cross(&(tool_base - joint.origin_mm)) * DEG
            }
        });
        // The tool's rotation per unit of joint i: one degree per degree about
        // its axis; none for a prismatic joint.
        let joint_turns: [Vector3<f64>; MAX_JOINTS] = std::array::from_fn(|i| {
            if prismatic[i] {
                Vector3::zeros()
            } else {
                deflected.joints[i + 1].axis(2)
            }
        });
        let deflection_rates: [Vector3<f64>; MAX_JOINTS] =
            std::array::from_fn(|i| joint_rates[i] * self.compliance(i));
        let gravity = Vector3::from(robot.spec().gravity_mps2);
        let joints = undeflected.joint_count;
        // Without compliance (the kinematic model, nominal values) every map
        // is zero: a geometric column is its screw's velocity alone, and
        // neither the maps nor the screws on the undeflected chain are needed
        // (a quarter of the kinematic model's pass, issue #31).
        let compliant = (0..joints).any(|i| self.compliance(i) != 0.0);
        let maps = compliant.then(|| {
            DeflectionMaps::new(undeflected, loads, &gravity, &deflection_rates, &prismatic)
        });
        // The same maps for the tool's rotation.
        let angular_maps = (compliant && angular.is_some()).then(|| {
            let rates: [Vector3<f64>; MAX_JOINTS] =
                std::array::from_fn(|i| joint_turns[i] * self.compliance(i));
            DeflectionMaps::new(undeflected, loads, &gravity, &rates, &prismatic)
        });

        for (j, (column, &id)) in columns.iter_mut().zip(selected).enumerate() {
            let mut rotation_deg = Vector3::zeros();
            *column = match id.kind() {
                // A joint past the arm's (a six-joint arm's seventh) moves nothing.
                _ if id.joint().is_some_and(|i| i >= joints) => Vector3::zeros(),
                ParamKind::WorldTranslation(t) => world_frame.axis(t),
                ParamKind::Track(term) => match &carriage {
                    Some(carriage) => {
                        rotation_deg = world_frame.rotation * carriage.angular_rate(term);
                        world_frame.rotation * carriage.rate(term, &tool_base)
                    }
                    // A robot without a track: its terms move nothing.
                    None => Vector3::zeros(),
                },
                // The positioner carries the work, not the arm's SMR.
                ParamKind::Positioner(_) => Vector3::zeros(),
                ParamKind::WorldRotation(r) => {
                    rotation_deg = self.world_rotation_axes[r];
                    self.world_rotation_axes[r].cross(&position_mm) * DEG
                }
                ParamKind::Compliance(i) => {
                    rotation_deg = world.rotation * joint_turns[i] * loads.torques_nm[i];
                    world.rotation * joint_rates[i] * loads.torques_nm[i]
                }
                ParamKind::ToolTranslation { target: other, .. } if other != *target => {
                    Vector3::zeros()
                }
                // An angle added to joint i's reading: its column is the joint's
                // rate times the term's factor (the torques, on the readings'
                // chain, do not see it).
                ParamKind::Backlash(i) | ParamKind::Harmonic { joint: i, .. } => {
                    let factor = joint_term_factor(id, q_deg[i], approach[i], prismatic[i]);
                    rotation_deg = world.rotation * joint_turns[i] * factor;
                    world.rotation * joint_rates[i] * factor
                }
                _ => {
                    let (screw, _) = self
                        .chain_screw(id, deflected)
                        .expect("geometric parameter has a screw");
                    let own_turn = || match screw {
                        Screw::Rotation { axis, .. } => axis,
                        Screw::Translation { .. } => Vector3::zeros(),
                    };
                    let own_rate = screw.velocity_at(&tool_base) * screw.per_unit();
                    let rate = match &maps {
                        Some(maps) => {
                            let (torque_screw, first_body) = self
                                .chain_screw(id, undeflected)
                                .expect("geometric parameter has a screw");
                            let twist = torque_screw.twist_si();
                            if let Some(angular_maps) = angular_maps.as_ref() {
                                rotation_deg = world.rotation
                                    * (own_turn() + angular_maps.velocity(first_body, &twist));
                            }
                            own_rate + maps.velocity(first_body, &twist)
                        }
                        None => {
                            if angular.is_some() {
                                rotation_deg = world.rotation * own_turn();
                            }
                            own_rate
                        }
                    };
                    world.rotation * rate
                }
            };
            if let Some(angular) = angular.as_mut() {
                angular[j] = rotation_deg;
            }
        }
        (
            Prediction {
                position_mm,
                torques_nm: loads.torques_nm,
                deflections_deg: *deflections_deg,
            },
            world.rotation * deflected.tool.rotation,
        )
    }
}

impl PreparedRobot<'_> {
    /// The Jacobian row of a positioner row (its SMR a nest on the table):
    /// only the world frame, the positioner's terms and the nest's own
    /// translation move it. The table's rotation stands for the row's
    /// orientation, which no parameter but those turns.
    fn positioner_jacobian_row(
        &self,
        row: &ConfWrench,
        chain: &PositionerChain,
        nest_mm: &Vector3<f64>,
        selected: &[ParamId],
        columns: &mut [Vector3<f64>],
        mut angular: Option<&mut [Vector3<f64>]>,
    ) -> (Prediction, Matrix3<f64>) {
        let world = &self.world_from_base;
        let position_mm = world.transform_point(nest_mm);
        let positioner = self
            .positioner
            .as_ref()
            .expect("a positioner row has a positioner");
        for (j, (column, &id)) in columns.iter_mut().zip(selected).enumerate() {
            let mut rotation_deg = Vector3::zeros();
            *column = match id.kind() {
                ParamKind::WorldTranslation(t) => world.axis(t),
                ParamKind::WorldRotation(r) => {
                    rotation_deg = self.world_rotation_axes[r];
                    self.world_rotation_axes[r].cross(&position_mm) * DEG
                }
                ParamKind::Positioner(term) => {
                    rotation_deg = world.rotation * positioner.angular_rate(chain, term);
                    world.rotation * positioner.rate(chain, term, nest_mm)
                }
                ParamKind::ToolTranslation { target, axis } if target == row.target => {
                    world.rotation * chain.table().axis(axis)
                }
                _ => Vector3::zeros(),
            };
            if let Some(angular) = angular.as_mut() {
                angular[j] = rotation_deg;
            }
        }
        (
            Prediction {
                position_mm,
                torques_nm: [0.0; MAX_JOINTS],
                deflections_deg: [0.0; MAX_JOINTS],
            },
            world.rotation * chain.table().rotation,
        )
    }
}

/// How much of a joint-error term's angle a row carries: the approach
/// direction for a backlash, sin(n·q) or cos(n·q) for a harmonic (none on a
/// prismatic joint, which the model gives no harmonics).
fn joint_term_factor(id: ParamId, q_deg: f64, approach: i8, prismatic: bool) -> f64 {
    match id.kind() {
        ParamKind::Backlash(_) => f64::from(approach),
        ParamKind::Harmonic { .. } if prismatic => 0.0,
        ParamKind::Harmonic { order, cosine, .. } => {
            let (sine, cos) = (order as f64 * q_deg * DEG).sin_cos();
            if cosine { cos } else { sine }
        }
        _ => 0.0,
    }
}

/// One conf-wrench combination: joint commands (deg), the wrench on the robot,
/// which target (SMR nest, 0-based, spec §7) was measured, and the direction
/// each joint last moved before the reading (−1, 0 unknown, +1; spec §8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConfWrench {
    pub q_deg: [f64; MAX_JOINTS],
    pub wrench: Wrench,
    pub target: usize,
    pub approach: [i8; MAX_JOINTS],
    /// The carriage's position on the robot's track (mm, the row's
    /// `e1_mm`); 0 without a track.
    pub track_mm: f64,
    /// The positioner's axis values (deg, the row's `p1_deg`, `p2_deg`)
    /// when the measured SMR is a nest on its table; `None` when the SMR is
    /// on the arm. A positioner row's position depends on the positioner,
    /// the world frame and its nest's translation only.
    pub positioner_deg: Option<[f64; MAX_POSITIONER_AXES]>,
}

impl ConfWrench {
    /// A row of the one-target cell, approach unknown.
    pub fn new(q_deg: [f64; MAX_JOINTS], wrench: Wrench) -> Self {
        ConfWrench {
            q_deg,
            wrench,
            target: 0,
            approach: [0; MAX_JOINTS],
            track_mm: 0.0,
            positioner_deg: None,
        }
    }
}

/// Predictions and the stacked identification Jacobian for many rows.
#[derive(Debug, Clone)]
pub struct BatchJacobian {
    pub predictions: Vec<Prediction>,
    /// Row-major `3n × m`: rows 3k..3k+3 are x, y, z of conf-wrench k.
    pub jacobian: Vec<f64>,
    pub columns: usize,
}

impl BatchJacobian {
    pub fn rows(&self) -> usize {
        self.predictions.len() * 3
    }

    pub fn entry(&self, row: usize, column: usize) -> f64 {
        self.jacobian[row * self.columns + column]
    }
}

/// Rows per parallel task: large enough that rayon's overhead is noise.
const CHUNK_ROWS: usize = 64;

/// Predictions and Jacobian for every row, in parallel chunks.
pub fn batch_jacobian(
    robot: &Robot,
    p: &ParamValues,
    rows: &[ConfWrench],
    selected: &[ParamId],
) -> BatchJacobian {
    let m = selected.len();
    let mut jacobian = vec![0.0; rows.len() * 3 * m];
    let mut predictions = vec![
        Prediction {
            position_mm: Vector3::zeros(),
            torques_nm: [0.0; MAX_JOINTS],
            deflections_deg: [0.0; MAX_JOINTS],
        };
        rows.len()
    ];
    let prepared = robot.prepare(p);
    let fill = |(rows, (out, preds)): (&[ConfWrench], (&mut [f64], &mut [Prediction]))| {
        let mut columns = vec![Vector3::zeros(); m];
        for (k, row) in rows.iter().enumerate() {
            preds[k] = prepared.jacobian_row(row, selected, &mut columns);
            for (j, column) in columns.iter().enumerate() {
                for axis in 0..3 {
                    out[(3 * k + axis) * m + j] = column[axis];
                }
            }
        }
    };
    if rows.len() > CHUNK_ROWS {
        rows.par_chunks(CHUNK_ROWS)
            .zip(
                jacobian
                    .par_chunks_mut(CHUNK_ROWS * 3 * m.max(1))
                    .zip(predictions.par_chunks_mut(CHUNK_ROWS)),
            )
            .for_each(fill);
    } else {
        fill((rows, (&mut jacobian, &mut predictions)));
    }
    BatchJacobian {
        predictions,
        jacobian,
        columns: m,
    }
}

/// Predictions for every row, in parallel chunks (no Jacobian).
pub fn batch_predict(robot: &Robot, p: &ParamValues, rows: &[ConfWrench]) -> Vec<Prediction> {
    let prepared = robot.prepare(p);
    rows.par_iter()
        .with_min_len(CHUNK_ROWS)
        .map(|row| prepared.predict_row(row))
        .collect()
}

/// Tool frame in the world on the deflected chain, each joint approached from
/// `approach`; shared with the inverse kinematics.
pub(crate) fn deflected_tool_and_joints(
    robot: &Robot,
    p: &ParamValues,
    q_deg: &[f64; MAX_JOINTS],
    wrench: &Wrench,
    approach: &[i8; MAX_JOINTS],
) -> (Frame, [Frame; MAX_JOINTS + 1]) {
    let prepared = robot.prepare(p);
    let (_, deflections) = prepared.deflections(q_deg, wrench);
    let terms = prepared.joint_terms.angles_deg(q_deg, approach);
    let chain = prepared.chain(q_deg, &std::array::from_fn(|i| deflections[i] + terms[i]));
    let world = &prepared.world_from_base;
    (
        world.compose(&chain.tool),
        chain.joints.map(|j| world.compose(&j)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::params::{BASE_PARAM_COUNT, MAX_TARGETS, PARAM_COUNT};

    /// Every slot in slot order: the 42, the further targets' translations,
    /// the joint terms, the track's terms, the positioner's, a seventh
    /// joint's (which a six-joint arm's rows do not move).
    fn every_slot() -> Vec<ParamId> {
        (0..PARAM_COUNT).filter_map(ParamId::from_index).collect()
    }

    /// A row with random joints, load, target and approach directions; every
    /// third a positioner row at random axis values.
    fn random_row(robot: &Robot, trial: usize, rng: &mut StdRng) -> ConfWrench {
        ConfWrench {
            q_deg: random_q(robot, rng),
            wrench: random_wrench(rng),
            target: trial % MAX_TARGETS,
            approach: std::array::from_fn(|_| rng.random_range(-1..=1)),
            track_mm: rng.random_range(-200.0..3000.0),
            positioner_deg: (trial % 3 == 2).then(|| {
                [
                    rng.random_range(-90.0..90.0),
                    rng.random_range(-360.0..360.0),
                ]
            }),
        }
    }
    use crate::robot::test_support::{
        gantry, irb1600, irb1600_in_full_cell, random_q, random_wrench, truth_params,
    };
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// Central difference step per parameter unit: small enough that the O(h²)
    /// truncation error is below 1e-9 relative, large enough for round-off.
    /// The track's terms scale with `u^k`, which can be 1e-5, and a
    /// compliance with a torque that can be 0.3 N·m: their columns are that
    /// small, so their steps are larger to keep round-off (about 1e-12 of
    /// positions a few metres from the world origin, divided by the step)
    /// below the tolerance; their truncation error is zero (translations)
    /// or below 1e-8 relative.
    fn step(id: ParamId) -> f64 {
        if id.is_compliance() {
            1e-5
        } else if id.is_track_term() {
            1e-2
        } else {
            1e-4
        }
    }

    /// The truth, and on odd trials random errors away from it; the targets
    /// 1.. with translations of their own.
    fn params_for_trial(
        robot: &Robot,
        all: &[ParamId],
        trial: usize,
        rng: &mut StdRng,
    ) -> ParamValues {
        let mut p = truth_params(robot);
        for id in all {
            if !id.is_compliance() && !id.is_world() && trial % 2 == 1 {
                p.0[id.index()] += rng.random_range(-0.5..0.5);
            }
            if id.is_joint_term() {
                p.0[id.index()] = rng.random_range(-0.05..0.05);
            } else if id.is_track_term() {
                p.0[id.index()] = rng.random_range(-0.5..0.5);
            } else if id.is_positioner_term() {
                p.0[id.index()] += rng.random_range(-2.0..2.0);
            } else if id.index() >= BASE_PARAM_COUNT {
                p.0[id.index()] += rng.random_range(-80.0..80.0);
            }
        }
        p
    }

    #[test]
    fn analytic_jacobian_matches_central_differences_for_every_slot() {
        check_position_columns(&irb1600_in_full_cell(), 7, 1e-9);
    }

    /// A gantry's prismatic joints: their travel, deflection (mm/N of the
    /// force along the axis) and backlash columns, and the changes every
    /// other parameter makes to those forces.
    #[test]
    fn analytic_jacobian_matches_central_differences_on_prismatic_joints() {
        // The gantry's tool reaches 3.6 m from its base: round-off in the
        // differences is larger (1e-16 of 3.6e3 mm over a 2e-4 step).
        check_position_columns(&gantry(), 17, 5e-9);
    }

    fn check_position_columns(robot: &Robot, seed: u64, absolute_mm: f64) {
        let robot = robot.clone();
        let all = every_slot();
        assert_eq!(all.len(), PARAM_COUNT);
        let mut rng = StdRng::seed_from_u64(seed);
        for trial in 0..40 {
            let p = params_for_trial(&robot, &all, trial, &mut rng);
            let row = random_row(&robot, trial, &mut rng);
            let mut columns = vec![Vector3::zeros(); PARAM_COUNT];
            robot.prepare(&p).jacobian_row(&row, &all, &mut columns);
            for id in &all {
                let h = step(*id);
                let mut plus = p;
                plus.0[id.index()] += h;
                let mut minus = p;
                minus.0[id.index()] -= h;
                let at = |v: &ParamValues| robot.prepare(v).predict_row(&row);
                let fd = (at(&plus).position_mm - at(&minus).position_mm) / (2.0 * h);
                let analytic = columns[id.index()];
                let scale = analytic.norm().max(fd.norm());
                assert!(
                    (fd - analytic).norm() <= 1e-6 * scale + absolute_mm,
                    "trial {trial} {id}: analytic {analytic:?} fd {fd:?}"
                );
            }
        }
    }

    /// The orientation columns of 6-D rows against central differences of the
    /// tool rotation (`Robot::tool_in_world`, an independent path through the
    /// model): `log(R(p + h)·R(p − h)ᵀ)/2h`, in degrees, for every slot, loaded
    /// rows, several targets and parameters away from the truth. The position
    /// columns are those of `jacobian_row`, bit for bit.
    #[test]
    fn orientation_columns_match_central_differences_for_every_slot() {
        check_orientation_columns(&irb1600_in_full_cell(), 8, 1e-9);
    }

    #[test]
    fn orientation_columns_match_central_differences_on_prismatic_joints() {
        check_orientation_columns(&gantry(), 18, 5e-9);
    }

    fn check_orientation_columns(robot: &Robot, seed: u64, absolute: f64) {
        let robot = robot.clone();
        let all = every_slot();
        let mut rng = StdRng::seed_from_u64(seed);
        for trial in 0..40 {
            let mut p = params_for_trial(&robot, &all, trial, &mut rng);
            // Tool and world rotations far from zero, so their axes are not the
            // coordinate axes.
            for (name, value) in [("alpha_t", 20.0), ("beta_t", -35.0), ("gamma_t", 80.0)] {
                p.set(ParamId::from_name(name).unwrap(), value);
            }
            let row = random_row(&robot, trial, &mut rng);
            let mut columns = vec![Vector3::zeros(); PARAM_COUNT];
            let mut angular = vec![Vector3::zeros(); PARAM_COUNT];
            let prepared = robot.prepare(&p);
            let (prediction, rotation) =
                prepared.jacobian_row_with_orientation(&row, &all, &mut columns, &mut angular);
            let mut position_only = vec![Vector3::zeros(); PARAM_COUNT];
            assert_eq!(
                prepared.jacobian_row(&row, &all, &mut position_only),
                prediction
            );
            assert_eq!(position_only, columns);
            let tool = robot.tool_in_world_of_row(&p, &row);
            assert!((tool.rotation - rotation).norm() < 1e-13);
            for id in &all {
                let h = step(*id);
                let mut plus = p;
                plus.0[id.index()] += h;
                let mut minus = p;
                minus.0[id.index()] -= h;
                let at = |v: &ParamValues| robot.tool_in_world_of_row(v, &row);
                let turn = at(&plus).rotation * at(&minus).rotation.transpose();
                let fd =
                    super::super::frame::rotation_vector(&turn).map(f64::to_degrees) / (2.0 * h);
                let analytic = angular[id.index()];
                let scale = analytic.norm().max(fd.norm());
                assert!(
                    (fd - analytic).norm() <= 1e-6 * scale + absolute,
                    "trial {trial} {id}: analytic {analytic:?} fd {fd:?}"
                );
            }
            if row.positioner_deg.is_some() || robot.has_prismatic_joint() {
                continue;
            }
            // Every kind of parameter turns the tool somewhere, except translations.
            for name in [
                "alpha_w", "gamma_t", "dtheta6", "dalpha3", "k2", "sin2q3", "cos1q5",
            ] {
                let id = ParamId::from_name(name).unwrap();
                assert!(angular[id.index()].norm() > 1e-6, "{name}");
            }
            for name in ["x_w", "z_t"] {
                let id = ParamId::from_name(name).unwrap();
                // A translation turns nothing rigidly; under load it changes the
                // torques, and so the deflections, a little.
                assert!(angular[id.index()].norm() < 1e-2, "{name}");
            }
        }
    }

    #[test]
    fn batch_equals_row_by_row_for_a_subset() {
        let robot = irb1600();
        let p = truth_params(&robot);
        let selected: Vec<ParamId> = ["x_w", "dtheta2", "dd4", "k6", "gamma_t"]
            .iter()
            .map(|n| ParamId::from_name(n).unwrap())
            .collect();
        let mut rng = StdRng::seed_from_u64(9);
        let rows: Vec<ConfWrench> = (0..200)
            .map(|_| ConfWrench::new(random_q(&robot, &mut rng), random_wrench(&mut rng)))
            .collect();
        let batch = batch_jacobian(&robot, &p, &rows, &selected);
        assert_eq!(batch.rows(), 600);
        let mut columns = vec![Vector3::zeros(); selected.len()];
        let prepared = robot.prepare(&p);
        for (k, row) in rows.iter().enumerate() {
            let pred = prepared.jacobian_row(row, &selected, &mut columns);
            assert_eq!(pred, batch.predictions[k]);
            for (j, column) in columns.iter().enumerate() {
                for axis in 0..3 {
                    assert_eq!(batch.entry(3 * k + axis, j), column[axis]);
                }
            }
        }
    }
}
