//! Inverse kinematics.
//!
//! * [`solve`]: every configuration of the nominal arm for a flange pose in the
//!   base frame; the entry point pose generation uses. It takes the closed form
//!   where the arm's geometry fits it and the numeric search otherwise.
//! * [`closed_form`]: every solution (up to 8, plus extra turns of joints whose
//!   range exceeds 360°) of the nominal arm with a spherical wrist.
//! * [`numeric`]: the same for any MDH table (UR's offset wrist, odd twists and
//!   offsets): Levenberg–Marquardt on the 6-dof pose error from a fixed set of
//!   starts spread over the joint ranges, converged solutions de-duplicated as
//!   configurations and their extra turns enumerated as the closed form does. It
//!   finds the solutions whose basins its starts reach, so it can miss one with a
//!   small basin (near a singularity); what it returns always satisfies the pose.
//! * [`solve_loaded`]: damped least squares on the full model (identified
//!   parameters, world and tool frames, compliance deflection under a wrench),
//!   seeded by a solution of the nominal arm: the joint command that puts the tool
//!   at a target while loaded.
//!
//! Singular and unreachable poses return an [`IkError`] (or, from [`numeric`], no
//! solution), never NaN. Everything is deterministic: the numeric starts are a
//! Halton sequence, not random draws.
//!
//! The closed form is written for the MDH structure of the ABB/KUKA/Fanuc family
//! (`alpha = 0, -90, 0, -90, 90, -90`, parallel axes 2 and 3, a spherical wrist);
//! other robot files get [`IkError::UnsupportedGeometry`] naming the first
//! mismatch (see [`closed_form_applies`]). It is hand-written rather than taken
//! from an OPW crate because it must work directly on the robot file's MDH values
//! and offsets and label branches.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

use super::frame::{Frame, rot_x, rot_z, rotation_vector};
use super::jacobian::deflected_tool_and_joints;
use super::model::{MAX_JOINTS, Robot, Wrench};
use super::params::{PARAM_COUNT, ParamValues};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// Why no joint vector was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IkError {
    #[error("unreachable: {0}")]
    Unreachable(String),
    #[error("singular: {0}")]
    Singular(String),
    #[error("closed-form inverse kinematics needs a spherical-wrist arm: {0}")]
    UnsupportedGeometry(String),
    #[error(
        "numeric inverse kinematics did not converge after {iterations} iterations (position error {position_error_mm:.3e} mm, orientation error {orientation_error_rad:.3e} rad)"
    )]
    NotConverged {
        iterations: usize,
        position_error_mm: f64,
        orientation_error_rad: f64,
    },
}

/// One inverse-kinematics solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkSolution {
    pub q_deg: [f64; MAX_JOINTS],
    /// Bit 0: shoulder back (joint 1 turned away from the wrist centre), bit 1:
    /// elbow down, bit 2: wrist flipped (the θ5 < 0 branch). Numeric solutions get
    /// the same bits from their geometry ([`branch_of`]).
    pub branch: u8,
}

/// Distance (mm) of the wrist centre from axis 1, and |sin θ5|, below which a pose
/// is singular and the closed form does not pick angles arbitrarily.
const SHOULDER_SINGULAR_MM: f64 = 1e-9;
const WRIST_SINGULAR_SIN: f64 = 1e-12;

struct Geometry {
    d1: f64,
    a2: f64,
    a3: f64,
    /// Forearm: length and angle of the vector from axis 3 to the wrist centre.
    forearm_mm: f64,
    forearm_angle: f64,
    d6: f64,
    offsets: [f64; MAX_JOINTS],
}

/// The redundancy rule of a seven-joint arm (issue #30): its joint 3 (0-based
/// 2, the upper arm's roll, which sets the elbow's plane) is held where the
/// seed has it (the target's branch hint, or the nominal solution found with
/// that joint given), and the other six place the tool. Of the seven joints
/// it leaves the six best conditioned: over 2000 random Panda configurations
/// the other six's scaled Jacobian had its smallest singular value below
/// 20 mm/rad in 492 (joint 7 held: 741, the wrist's q5 = ±90° then aligns
/// axes 4 and 6; joint 4 held: 1659).
pub const HELD_JOINT_OF_SEVEN: usize = 2;

/// The base frame, then the frames of the six joints the solvers move
/// ([`free_joints`]), from a chain's frames 0..=n: the roles a six-joint
/// arm's frames 0..=6 play (shoulder, elbow, wrist) in the measures of
/// branches and singularities. A six-joint arm's frames as they are.
pub fn role_frames(robot: &Robot, joints: &[Frame; MAX_JOINTS + 1]) -> [Frame; 7] {
    let free = free_joints(robot);
    std::array::from_fn(|role| {
        if role == 0 {
            joints[0]
        } else {
            joints[free[role - 1] + 1]
        }
    })
}

/// The six joints the solvers move: all of a six-joint arm's, a seven-joint
/// arm's but [`HELD_JOINT_OF_SEVEN`].
pub fn free_joints(robot: &Robot) -> [usize; 6] {
    let held = if robot.joint_count() > 6 {
        HELD_JOINT_OF_SEVEN
    } else {
        MAX_JOINTS
    };
    let mut free = [0; 6];
    for (slot, joint) in (0..robot.joint_count()).filter(|j| *j != held).enumerate() {
        free[slot] = joint;
    }
    free
}

fn geometry(robot: &Robot) -> Result<Geometry, IkError> {
    if robot.joint_count() != 6 {
        return Err(IkError::UnsupportedGeometry(format!(
            "the arm has {} joints; the closed form is for six",
            robot.joint_count()
        )));
    }
    if let Some(joint) = (0..6).find(|&joint| robot.is_prismatic(joint)) {
        return Err(IkError::UnsupportedGeometry(format!(
            "joint {} is prismatic; the closed form is for six revolute joints",
            joint + 1
        )));
    }
    let expected_alpha = [0.0, -90.0, 0.0, -90.0, 90.0, -90.0];
    for (i, expected) in expected_alpha.iter().enumerate() {
        let (alpha, ..) = robot.nominal_mdh(i);
        if (alpha - expected * DEG).abs() > 1e-12 {
            return Err(IkError::UnsupportedGeometry(format!(
                "joint {} alpha is {:.6} deg, expected {expected}",
                i + 1,
                alpha / DEG
            )));
        }
    }
    let zero = |what: &str, value: f64| {
        if value.abs() > 1e-12 {
            Err(IkError::UnsupportedGeometry(format!(
                "{what} is {value}, expected 0"
            )))
        } else {
            Ok(())
        }
    };
    zero("joint 1 a_mm", robot.nominal_mdh(0).1)?;
    zero("joint 2 d_mm", robot.nominal_mdh(1).3)?;
    zero("joint 3 d_mm", robot.nominal_mdh(2).3)?;
    zero("joint 5 a_mm", robot.nominal_mdh(4).1)?;
    zero("joint 5 d_mm", robot.nominal_mdh(4).3)?;
    zero("joint 6 a_mm", robot.nominal_mdh(5).1)?;
    let a4 = robot.nominal_mdh(3).1;
    let d4 = robot.nominal_mdh(3).3;
    Ok(Geometry {
        d1: robot.nominal_mdh(0).3,
        a2: robot.nominal_mdh(1).1,
        a3: robot.nominal_mdh(2).1,
        forearm_mm: a4.hypot(d4),
        forearm_angle: d4.atan2(a4),
        d6: robot.nominal_mdh(5).3,
        offsets: std::array::from_fn(|i| robot.nominal_mdh(i).2),
    })
}

/// Whether [`closed_form`] applies to this arm: `Err(UnsupportedGeometry)` naming
/// the first twist or offset that does not fit its structure.
pub fn closed_form_applies(robot: &Robot) -> Result<(), IkError> {
    geometry(robot).map(|_| ())
}

/// All closed-form solutions for a flange pose in the base frame, within joint
/// limits, distinct, with extra turns enumerated.
pub fn closed_form(robot: &Robot, flange_in_base: &Frame) -> Result<Vec<IkSolution>, IkError> {
    let g = geometry(robot)?;
    let wrist = flange_in_base.origin_mm - flange_in_base.axis(2) * g.d6;
    let radial = wrist.x.hypot(wrist.y);
    if radial < SHOULDER_SINGULAR_MM {
        return Err(IkError::Singular(format!(
            "wrist centre on axis 1 ({radial:.2e} mm away)"
        )));
    }
    let w = g.d1 - wrist.z;
    let mut raw = Vec::with_capacity(8);
    let mut reach_error = None;
    for shoulder_back in [false, true] {
        let theta1 = wrist.y.atan2(wrist.x)
            + if shoulder_back {
                std::f64::consts::PI
            } else {
                0.0
            };
        let u = if shoulder_back { -radial } else { radial } - g.a2;
        let cos_beta = (u * u + w * w - g.a3 * g.a3 - g.forearm_mm * g.forearm_mm)
            / (2.0 * g.a3 * g.forearm_mm);
        if cos_beta.abs() > 1.0 + 1e-12 {
            reach_error = Some(format!(
                "wrist centre {:.1} mm from axis 2, arm reaches {:.1}..{:.1} mm",
                u.hypot(w),
                (g.a3 - g.forearm_mm).abs(),
                g.a3 + g.forearm_mm
            ));
            continue;
        }
        let beta_abs = cos_beta.clamp(-1.0, 1.0).acos();
        for elbow_down in [false, true] {
            let beta = if elbow_down { -beta_abs } else { beta_abs };
            let theta2 =
                w.atan2(u) - (g.forearm_mm * beta.sin()).atan2(g.a3 + g.forearm_mm * beta.cos());
            let theta3 = beta - g.forearm_angle;
            // Frame 3 orientation in the base, then the wrist as ZYZ Euler angles:
            // Rx(90)·R36 = Rz(θ4)·Ry(-θ5)·Rz(θ6).
            let r3 = rot_z(theta1) * rot_x(-90.0 * DEG) * rot_z(theta2) * rot_z(theta3);
            let n = rot_x(90.0 * DEG) * r3.transpose() * flange_in_base.rotation;
            let sin_b = n[(0, 2)].hypot(n[(1, 2)]);
            if sin_b < WRIST_SINGULAR_SIN {
                return Err(IkError::Singular(format!(
                    "wrist singularity (axes 4 and 6 aligned, |sin q5| = {sin_b:.1e})"
                )));
            }
            for wrist_flip in [false, true] {
                // b = -θ5: the unflipped branch has θ5 > 0.
                let sign = if wrist_flip { 1.0 } else { -1.0 };
                let b = (sign * sin_b).atan2(n[(2, 2)]);
                let a = (sign * n[(1, 2)]).atan2(sign * n[(0, 2)]);
                let c = (sign * n[(2, 1)]).atan2(-sign * n[(2, 0)]);
                let thetas = [theta1, theta2, theta3, a, -b, c];
                let q_deg = crate::robot::joint_array(&std::array::from_fn::<f64, 6, _>(|i| {
                    wrap_deg((thetas[i] - g.offsets[i]) / DEG)
                }));
                // Elbow down is a bend the negative way about axis 3 from the upper
                // arm, which points along -x2 where a3 < 0.
                let bent_negative = elbow_down != (g.a3 < 0.0);
                let branch =
                    shoulder_back as u8 | (bent_negative as u8) << 1 | (wrist_flip as u8) << 2;
                raw.push(IkSolution { q_deg, branch });
            }
        }
    }
    if raw.is_empty() {
        return Err(IkError::Unreachable(reach_error.unwrap_or_default()));
    }
    let mut solutions: Vec<IkSolution> = Vec::new();
    for solution in raw {
        for q_deg in turns_within_limits(robot, &solution.q_deg) {
            let distinct = solutions.iter().all(|s| {
                s.q_deg
                    .iter()
                    .zip(&q_deg)
                    .any(|(a, b)| (a - b).abs() > 1e-9)
            });
            if distinct {
                solutions.push(IkSolution {
                    q_deg,
                    branch: solution.branch,
                });
            }
        }
    }
    if solutions.is_empty() {
        return Err(IkError::Unreachable(
            "every solution violates a joint limit".into(),
        ));
    }
    Ok(solutions)
}

fn wrap_deg(angle: f64) -> f64 {
    let wrapped = (angle + 180.0).rem_euclid(360.0) - 180.0;
    if wrapped == -180.0 { 180.0 } else { wrapped }
}

/// Every `q + 360·k` per revolute joint that lies within the limits, as a
/// cartesian product (a prismatic joint's one value, when within them).
fn turns_within_limits(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> Vec<[f64; MAX_JOINTS]> {
    let mut combos = vec![*q_deg];
    for i in 0..robot.joint_count() {
        let [lo, hi] = robot.joint_limits(i);
        if robot.is_prismatic(i) {
            combos.retain(|combo| (lo - 1e-9..=hi + 1e-9).contains(&combo[i]));
            continue;
        }
        let mut turns = Vec::new();
        let mut angle = q_deg[i] - 360.0 * ((q_deg[i] - lo) / 360.0).floor();
        while angle <= hi + 1e-9 {
            if angle >= lo - 1e-9 {
                turns.push(angle.clamp(lo, hi));
            }
            angle += 360.0;
        }
        combos = combos
            .iter()
            .flat_map(|combo| {
                turns.iter().map(move |&t| {
                    let mut c = *combo;
                    c[i] = t;
                    c
                })
            })
            .collect();
    }
    combos
}

/// Tolerances and limits of the numeric solver.
#[derive(Debug, Clone, Copy)]
pub struct NumericOptions {
    pub max_iterations: usize,
    pub position_tolerance_mm: f64,
    pub orientation_tolerance_rad: f64,
    /// Initial Levenberg–Marquardt damping (relative to the Jacobian's diagonal).
    pub damping: f64,
}

impl Default for NumericOptions {
    fn default() -> Self {
        NumericOptions {
            max_iterations: 100,
            position_tolerance_mm: 1e-10,
            orientation_tolerance_rad: 1e-12,
            damping: 1e-3,
        }
    }
}

/// Joint command (deg) that puts the tool at `tool_in_world` on the full loaded
/// model, each joint approached from `approach` (spec §8), by
/// Levenberg–Marquardt from `seed_deg`.
///
/// The step uses the geometric Jacobian of the deflected chain and neglects how the
/// deflection changes with q; the deflection is re-evaluated at every trial point,
/// so the fixed point is exact and convergence stays fast because `k·dτ/dq` is
/// small. A step is accepted only when it lowers the error, so the solver stays on
/// the seed's branch instead of wandering to another solution near singularities.
pub fn solve_loaded(
    robot: &Robot,
    p: &ParamValues,
    wrench: &Wrench,
    approach: &[i8; MAX_JOINTS],
    tool_in_world: &Frame,
    seed_deg: &[f64; MAX_JOINTS],
    options: &NumericOptions,
) -> Result<[f64; MAX_JOINTS], IkError> {
    solve_loaded_iterate(robot, p, wrench, approach, tool_in_world, seed_deg, options)
        .into_result(options)
}

/// [`solve_loaded`] that also returns where it stopped when it did not converge:
/// a caller that reports per row (compensation) keeps the last iterate and its
/// errors instead of an error value.
pub fn solve_loaded_iterate(
    robot: &Robot,
    p: &ParamValues,
    wrench: &Wrench,
    approach: &[i8; MAX_JOINTS],
    tool_in_world: &Frame,
    seed_deg: &[f64; MAX_JOINTS],
    options: &NumericOptions,
) -> Iterate {
    let prismatic = robot.prismatic_joints();
    let mut iterate = damped_least_squares(
        |q| deflected_tool_and_joints(robot, p, q, wrench, approach),
        tool_in_world,
        seed_deg,
        &free_joints(robot),
        &prismatic,
        options,
    );
    // The same configuration, in the turn of each revolute joint nearest the seed.
    for ((q, seed), prismatic) in iterate.q_deg.iter_mut().zip(seed_deg).zip(prismatic) {
        if !prismatic {
            *q -= 360.0 * ((*q - seed) / 360.0).round();
        }
    }
    iterate
}

/// Where the damped least-squares solver stopped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iterate {
    /// The last accepted joint vector (deg): the seed or a step that lowered a
    /// finite error, so it is finite whenever the seed is.
    pub q_deg: [f64; MAX_JOINTS],
    pub position_error_mm: f64,
    pub orientation_error_rad: f64,
    /// Both errors below the tolerances.
    pub converged: bool,
    /// Not converged because no damped step lowered the error any more (a local
    /// minimum of the pose error, e.g. the arm stretched towards a point beyond
    /// its reach) or the error was not finite, rather than because the
    /// iterations ran out.
    pub stalled: bool,
    pub iterations: usize,
}

impl Iterate {
    fn into_result(self, options: &NumericOptions) -> Result<[f64; MAX_JOINTS], IkError> {
        if self.converged {
            Ok(self.q_deg)
        } else {
            Err(IkError::NotConverged {
                iterations: options.max_iterations,
                position_error_mm: self.position_error_mm,
                orientation_error_rad: self.orientation_error_rad,
            })
        }
    }
}

/// The geometric Jacobian (6×6) at the tool of a chain given in one frame, of
/// the six `free` joints ([`free_joints`]): a revolute joint's column is its
/// axis's moment about the tool (mm/rad), then its axis scaled by
/// [`RAD_AS_MM`], so position and orientation rows weigh alike; a prismatic
/// joint's is its axis per [`RAD_AS_MM`] mm of travel, then zero, so that a
/// slide's column weighs like a revolute joint's and the singular values
/// (singularity margins, compensate's `singular` status) keep their meaning.
pub(crate) fn scaled_geometric_jacobian(
    tool: &Frame,
    joints: &[Frame; MAX_JOINTS + 1],
    free: &[usize; 6],
    prismatic: &[bool; MAX_JOINTS],
) -> Matrix6<f64> {
    let mut jacobian = Matrix6::zeros();
    for (column, &joint) in free.iter().enumerate() {
        let z = joints[joint + 1].axis(2);
        if prismatic[joint] {
            jacobian
                .fixed_view_mut::<3, 1>(0, column)
                .copy_from(&(z * RAD_AS_MM));
            continue;
        }
        let linear = z.cross(&(tool.origin_mm - joints[joint + 1].origin_mm));
        jacobian
            .fixed_view_mut::<3, 1>(0, column)
            .copy_from(&linear);
        jacobian
            .fixed_view_mut::<3, 1>(3, column)
            .copy_from(&(z * RAD_AS_MM));
    }
    jacobian
}

/// Orientation in mm-equivalent (1 rad ~ 1000 mm) so both errors count.
pub(crate) const RAD_AS_MM: f64 = 1000.0;

/// Levenberg–Marquardt on the 6-dof error between `target` and the tool frame of
/// `chain(q)`, which returns the tool and the joint frames 0..=n in the target's
/// frame, moving the six `free` joints (the others keep the seed's values). The
/// step uses the geometric Jacobian of those frames (a joint's column is its
/// axis and the axis's moment about the tool). A step is accepted only when it
/// lowers the error. Stops with the joint vector (deg, not wrapped) once the
/// position and orientation errors are below the tolerances, or where it got.
fn damped_least_squares(
    chain: impl Fn(&[f64; MAX_JOINTS]) -> (Frame, [Frame; MAX_JOINTS + 1]),
    target: &Frame,
    seed_deg: &[f64; MAX_JOINTS],
    free: &[usize; 6],
    prismatic: &[bool; MAX_JOINTS],
    options: &NumericOptions,
) -> Iterate {
    let residual = |q: &[f64; MAX_JOINTS]| {
        let (tool, joints) = chain(q);
        let position = target.origin_mm - tool.origin_mm;
        let orientation = rotation_vector(&(target.rotation * tool.rotation.transpose()));
        (tool, joints, position, orientation)
    };
    let stacked = |position: &Vector3<f64>, orientation: &Vector3<f64>| {
        let mut e = Vector6::zeros();
        e.fixed_rows_mut::<3>(0).copy_from(position);
        e.fixed_rows_mut::<3>(3)
            .copy_from(&(orientation * RAD_AS_MM));
        e
    };
    let mut q = *seed_deg;
    let (mut tool, mut joints, mut position, mut orientation) = residual(&q);
    let mut lambda = options.damping;
    let stop = |q, position: &Vector3<f64>, orientation: &Vector3<f64>, stalled, iterations| {
        let (position_error_mm, orientation_error_rad) = (position.norm(), orientation.norm());
        Iterate {
            q_deg: q,
            position_error_mm,
            orientation_error_rad,
            converged: position_error_mm < options.position_tolerance_mm
                && orientation_error_rad < options.orientation_tolerance_rad,
            stalled,
            iterations,
        }
    };
    for iteration in 0..options.max_iterations {
        if !(position.norm().is_finite() && orientation.norm().is_finite()) {
            return stop(q, &position, &orientation, true, iteration);
        }
        if position.norm() < options.position_tolerance_mm
            && orientation.norm() < options.orientation_tolerance_rad
        {
            return stop(q, &position, &orientation, false, iteration);
        }
        let jacobian = scaled_geometric_jacobian(&tool, &joints, free, prismatic);
        let error = stacked(&position, &orientation);
        let jtj = jacobian.transpose() * jacobian;
        let jte = jacobian.transpose() * error;
        let mut accepted = false;
        for _ in 0..30 {
            let damped = jtj
                + Matrix6::from_diagonal(&jtj.diagonal()) * lambda
                + Matrix6::identity() * 1e-12;
            let Some(step) = damped.cholesky().map(|c| c.solve(&jte)) else {
                lambda = lambda * 10.0 + 1e-6;
                continue;
            };
            let mut trial = q;
            for (column, &joint) in free.iter().enumerate() {
                // A revolute step is in radians, a prismatic one in
                // units of RAD_AS_MM mm.
                trial[joint] += if prismatic[joint] {
                    step[column] * RAD_AS_MM
                } else {
                    step[column] / DEG
                };
            }
            let candidate = residual(&trial);
            if stacked(&candidate.2, &candidate.3).norm() < error.norm() {
                q = trial;
                (tool, joints, position, orientation) = candidate;
                lambda = (lambda / 10.0).max(1e-15);
                accepted = true;
                break;
            }
            lambda = lambda * 10.0 + 1e-9;
        }
        if !accepted {
            return stop(q, &position, &orientation, true, iteration);
        }
    }
    stop(q, &position, &orientation, false, options.max_iterations)
}

/// Every configuration of the nominal arm that puts the flange at `flange_in_base`,
/// within joint limits, with extra turns enumerated: the closed form where the
/// arm's geometry fits it ([`closed_form_applies`]), otherwise [`numeric`] with
/// default options (no solution found is then [`IkError::Unreachable`]).
///
/// Cost: a few µs for the closed form; the numeric search runs
/// [`NumericIkOptions::starts`] local solves (about a millisecond in release).
///
/// A seven-joint arm needs the value of its held joint: [`solve_holding`].
pub fn solve(robot: &Robot, flange_in_base: &Frame) -> Result<Vec<IkSolution>, IkError> {
    if robot.joint_count() > 6 {
        return Err(IkError::UnsupportedGeometry(format!(
            "a seven-joint arm's inverse kinematics holds joint {} at a given value (solve_holding)",
            HELD_JOINT_OF_SEVEN + 1
        )));
    }
    if closed_form_applies(robot).is_ok() {
        return closed_form(robot, flange_in_base);
    }
    let options = NumericIkOptions::default();
    let solutions = numeric(robot, flange_in_base, &options);
    if solutions.is_empty() {
        return Err(IkError::Unreachable(format!(
            "numeric inverse kinematics found no solution within the joint limits from {} starts",
            options.starts
        )));
    }
    Ok(solutions)
}

/// [`solve`] for any arm: a seven-joint arm's joint [`HELD_JOINT_OF_SEVEN`]
/// stays at `held_deg` in every solution (the redundancy rule), a six-joint
/// arm ignores it.
pub fn solve_holding(
    robot: &Robot,
    flange_in_base: &Frame,
    held_deg: f64,
) -> Result<Vec<IkSolution>, IkError> {
    if robot.joint_count() == 6 {
        return solve(robot, flange_in_base);
    }
    let options = NumericIkOptions {
        held_deg: Some(held_deg),
        ..NumericIkOptions::default()
    };
    let solutions = numeric(robot, flange_in_base, &options);
    if solutions.is_empty() {
        return Err(IkError::Unreachable(format!(
            "numeric inverse kinematics found no solution within the joint limits from {} starts with joint {} held at {held_deg}°",
            options.starts,
            HELD_JOINT_OF_SEVEN + 1
        )));
    }
    Ok(solutions)
}

/// Options of [`numeric`].
#[derive(Debug, Clone, Copy)]
pub struct NumericIkOptions {
    /// Number of starts: the first points of a Halton sequence over one turn of
    /// each joint's range (fixed, so results are reproducible). With the default
    /// 64, the configuration that generated a random pose was among the solutions
    /// for 999 of 1000 poses of the UR10 and 1000 of 1000 of the IRB 1600 (16
    /// starts: 907 and 923; 128 starts found no configuration that 64 missed).
    pub starts: usize,
    /// A joint vector (deg) tried before the fixed starts, e.g. the current one.
    pub hint_deg: Option<[f64; MAX_JOINTS]>,
    /// A seven-joint arm's held joint ([`HELD_JOINT_OF_SEVEN`]): its value
    /// (deg) in every start and solution. Required for such an arm (without
    /// it there is no solution); a six-joint arm ignores it.
    pub held_deg: Option<f64>,
    /// The local solver's iterations, tolerances and damping.
    pub solver: NumericOptions,
    /// Two converged joint vectors are the same configuration when every joint
    /// differs by less than this (deg) modulo 360.
    pub same_configuration_deg: f64,
}

impl Default for NumericIkOptions {
    fn default() -> Self {
        NumericIkOptions {
            starts: 64,
            hint_deg: None,
            held_deg: None,
            solver: NumericOptions::default(),
            same_configuration_deg: 1e-6,
        }
    }
}

/// Every configuration the numeric search finds that puts the flange of the
/// nominal arm at `flange_in_base` (to the solver's tolerances), within joint
/// limits, with extra turns enumerated, in a canonical order (branch, then joint
/// angles). Works for any MDH table. Empty when the pose is unreachable (or every
/// solution found violates a joint limit).
///
/// Cost: `options.starts` (+1 with a hint) Levenberg–Marquardt solves of ~10–50
/// steps, each a forward chain, a 6×6 Jacobian and a Cholesky solve.
pub fn numeric(
    robot: &Robot,
    flange_in_base: &Frame,
    options: &NumericIkOptions,
) -> Vec<IkSolution> {
    let prepared = robot.prepare(&ParamValues([0.0; PARAM_COUNT]));
    let chain = |q: &[f64; MAX_JOINTS]| {
        let chain = prepared.chain(q, &[0.0; MAX_JOINTS]);
        (*chain.flange(), chain.joints)
    };
    let held = match (robot.joint_count() > 6, options.held_deg) {
        (false, _) => None,
        (true, Some(value)) => Some(value),
        (true, None) => return Vec::new(),
    };
    let starts = options
        .hint_deg
        .into_iter()
        .chain(start_points(robot, options.starts))
        .map(|mut start| {
            if let Some(value) = held {
                start[HELD_JOINT_OF_SEVEN] = value;
            }
            start
        });
    let free = free_joints(robot);
    let prismatic = robot.prismatic_joints();
    // A revolute joint's value wrapped into one turn; a prismatic one's as it is.
    let wrap = |joint: usize, value: f64| {
        if prismatic[joint] {
            value
        } else {
            wrap_deg(value)
        }
    };
    let mut configurations: Vec<[f64; MAX_JOINTS]> = Vec::new();
    for start in starts {
        let Ok(q) = damped_least_squares(
            chain,
            flange_in_base,
            &start,
            &free,
            &prismatic,
            &options.solver,
        )
        .into_result(&options.solver) else {
            continue;
        };
        let wrapped: [f64; MAX_JOINTS] = std::array::from_fn(|joint| wrap(joint, q[joint]));
        let known = configurations.iter().any(|c| {
            (0..MAX_JOINTS).all(|joint| {
                wrap(joint, c[joint] - wrapped[joint]).abs() < options.same_configuration_deg
            })
        });
        if !known {
            configurations.push(wrapped);
        }
    }
    // Turns do not change the geometry, so a configuration's branch holds for all.
    let mut solutions: Vec<IkSolution> = configurations
        .iter()
        .flat_map(|q| {
            let branch = branch_of(robot, q);
            turns_within_limits(robot, q)
                .into_iter()
                .map(move |q_deg| IkSolution { q_deg, branch })
        })
        .collect();
    solutions.sort_by(|a, b| {
        a.branch.cmp(&b.branch).then_with(|| {
            a.q_deg
                .iter()
                .zip(&b.q_deg)
                .map(|(x, y)| x.total_cmp(y))
                .find(|o| o.is_ne())
                .unwrap_or(std::cmp::Ordering::Equal)
        })
    });
    solutions
}

/// The first `count` points (from index 1) of the Halton sequence with bases
/// 2, 3, 5, 7, 11, 13, scaled to one turn of each revolute joint's range:
/// `[lo, lo + 360]` clipped to the upper limit (a prismatic joint's whole
/// travel).
fn start_points(robot: &Robot, count: usize) -> impl Iterator<Item = [f64; MAX_JOINTS]> + '_ {
    const BASES: [u64; MAX_JOINTS] = [2, 3, 5, 7, 11, 13, 17];
    (1..=count as u64).map(move |index| {
        robot.joint_vector(|i| {
            let [lo, hi] = robot.joint_limits(i);
            let span = if robot.is_prismatic(i) {
                hi - lo
            } else {
                hi.min(lo + 360.0) - lo
            };
            lo + radical_inverse(index, BASES[i]) * span
        })
    })
}

/// Van der Corput radical inverse of `index` in `base`, in [0, 1).
fn radical_inverse(mut index: u64, base: u64) -> f64 {
    let mut value = 0.0;
    let mut scale = 1.0 / base as f64;
    while index > 0 {
        value += (index % base) as f64 * scale;
        index /= base;
        scale /= base as f64;
    }
    value
}

/// The branch bits of [`IkSolution::branch`] from a configuration's geometry on
/// the nominal arm, for any MDH table; on the closed form's arms they equal the
/// closed form's labels.
///
/// * bit 0, shoulder back: the wrist point (origin of frame 5, where axes 5 and 6
///   meet on the arms egcal knows) lies behind axis 1 along frame 1's x axis;
/// * bit 1, elbow down: the forearm (frame 3 to frame 4 origins) turns negatively
///   about axis 3 from the upper arm (frame 2 to frame 3 origins), both seen along
///   axis 3;
/// * bit 2, wrist flipped: sin θ5 < 0, with θ5 = q5 plus its nominal offset.
///
/// A seven-joint arm's bits are those of its six free joints
/// ([`role_frames`]): its joint 4 is the elbow, joint 6 the wrist's q5.
pub fn branch_of(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> u8 {
    let all = robot
        .prepare(&ParamValues([0.0; PARAM_COUNT]))
        .chain(q_deg, &[0.0; MAX_JOINTS])
        .joints;
    let joints = role_frames(robot, &all);
    let wrist_joint = free_joints(robot)[4];
    let shoulder_back = (joints[5].origin_mm - joints[1].origin_mm).dot(&joints[1].axis(0)) < 0.0;
    let axis3 = joints[3].axis(2);
    let across = |v: Vector3<f64>| v - axis3 * axis3.dot(&v);
    let upper = across(joints[3].origin_mm - joints[2].origin_mm);
    let fore = across(joints[4].origin_mm - joints[3].origin_mm);
    let elbow_down = upper.cross(&fore).dot(&axis3) < 0.0;
    let wrist_flip = (q_deg[wrist_joint] * DEG + robot.nominal_mdh(wrist_joint).2).sin() < 0.0;
    shoulder_back as u8 | (elbow_down as u8) << 1 | (wrist_flip as u8) << 2
}

/// Flange pose in the base frame that puts the tool at `tool_in_world` for the
/// nominal world and tool frames of `p`.
pub fn flange_target_in_base(robot: &Robot, p: &ParamValues, tool_in_world: &Frame) -> Frame {
    let v = &p.0;
    let flange_from_tool = Frame::from_xyz_euler_then_translation(
        [v[9] * DEG, v[10] * DEG, v[11] * DEG],
        Vector3::new(v[6], v[7], v[8]),
    );
    robot
        .world_from_base(p)
        .inverse()
        .compose(tool_in_world)
        .compose(&flange_from_tool.inverse())
}

/// Rotation that points the tool's z axis along `direction` (unit), with the
/// remaining roll given in radians; used to aim the SMR at the tracker.
pub fn frame_with_z_along(
    direction: &Vector3<f64>,
    roll_rad: f64,
    origin_mm: Vector3<f64>,
) -> Frame {
    let z = direction.normalize();
    let helper = if z.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let x = helper.cross(&z).normalize();
    let y = z.cross(&x);
    Frame {
        rotation: Matrix3::from_columns(&[x, y, z]) * rot_z(roll_rad),
        origin_mm,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::joint_array;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params, ur10};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    #[test]
    fn fk_of_every_closed_form_solution_is_the_pose() {
        let robot = irb1600();
        let mut rng = StdRng::seed_from_u64(11);
        let mut checked = 0;
        let mut singular = 0;
        for _ in 0..3000 {
            let q = random_q(&robot, &mut rng);
            let pose = robot.nominal_flange_in_base(&q);
            let solutions = match closed_form(&robot, &pose) {
                Ok(s) => s,
                Err(IkError::Singular(_)) => {
                    singular += 1;
                    continue;
                }
                Err(e) => panic!("{q:?}: {e}"),
            };
            // The generating configuration is among the solutions.
            assert!(
                solutions
                    .iter()
                    .any(|s| s.q_deg.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-6)),
                "{q:?} not in {solutions:?}"
            );
            for (k, s) in solutions.iter().enumerate() {
                assert!(robot.within_limits(&s.q_deg), "{s:?}");
                let fk = robot.nominal_flange_in_base(&s.q_deg);
                let (dp, da) = ((fk.origin_mm - pose.origin_mm).norm(), fk.angle_to(&pose));
                assert!(
                    dp < 1e-9 && da < 1e-9,
                    "{q:?} -> {s:?}: {dp:e} mm, {da:e} rad"
                );
                for other in &solutions[k + 1..] {
                    assert!(
                        s.q_deg
                            .iter()
                            .zip(&other.q_deg)
                            .any(|(a, b)| (a - b).abs() > 1e-9)
                    );
                }
                checked += 1;
            }
        }
        assert!(singular < 10, "{singular} singular of 3000");
        assert!(checked > 6000, "{checked}");
    }

    #[test]
    fn singular_and_unreachable_poses_are_reported_not_nan() {
        let robot = irb1600();
        // Wrist singularity: q5 = 0.
        let pose = robot.nominal_flange_in_base(&[10.0, 20.0, -10.0, 30.0, 0.0, 40.0, 0.0]);
        assert!(matches!(
            closed_form(&robot, &pose),
            Err(IkError::Singular(_))
        ));
        // Shoulder singularity: wrist centre on axis 1.
        let mut on_axis = Frame::identity();
        on_axis.origin_mm = Vector3::new(0.0, 0.0, 1200.0 + 65.0);
        assert!(matches!(
            closed_form(&robot, &on_axis),
            Err(IkError::Singular(_))
        ));
        // Far away.
        let mut far = Frame::identity();
        far.origin_mm = Vector3::new(5000.0, 0.0, 500.0);
        assert!(matches!(
            closed_form(&robot, &far),
            Err(IkError::Unreachable(_))
        ));
    }

    #[test]
    fn joint_6_extra_turns_are_enumerated() {
        let robot = irb1600();
        let q = [0.0, 10.0, 10.0, 0.0, 45.0, 20.0];
        let solutions =
            closed_form(&robot, &robot.nominal_flange_in_base(&joint_array(&q))).unwrap();
        let mut turns: Vec<f64> = solutions
            .iter()
            .filter(|s| {
                s.q_deg[..5]
                    .iter()
                    .zip(&q)
                    .all(|(a, b)| (a - b).abs() < 1e-9)
            })
            .map(|s| s.q_deg[5])
            .collect();
        turns.sort_by(f64::total_cmp);
        assert_eq!(turns.len(), 3, "{turns:?}");
        for (got, want) in turns.iter().zip([-340.0, 20.0, 380.0]) {
            assert!((got - want).abs() < 1e-9, "{turns:?}");
        }
        // The unflipped wrist of an elbow-up, shoulder-front pose is branch 0.
        assert!(
            solutions
                .iter()
                .any(|s| s.branch == 0 && (s.q_deg[4] - 45.0).abs() < 1e-9)
        );
    }

    #[test]
    fn numeric_solver_converges_on_a_loaded_calibrated_model() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let mut rng = StdRng::seed_from_u64(5);
        let mut well_conditioned = 0;
        for _ in 0..100 {
            let q_true = random_q(&robot, &mut rng);
            let wrench = random_wrench(&mut rng);
            let target = robot.tool_in_world(&truth, &q_true, &wrench, &[0; MAX_JOINTS]);
            // Seed from the closed form of the nominal arm placed with the model's
            // world and tool frames, as a stage that commands a calibrated robot does.
            let flange = flange_target_in_base(&robot, &truth, &target);
            let Ok(solutions) = closed_form(&robot, &flange) else {
                continue;
            };
            let seed = solutions
                .iter()
                .min_by(|a, b| distance(&a.q_deg, &q_true).total_cmp(&distance(&b.q_deg, &q_true)))
                .unwrap();
            let q = solve_loaded(
                &robot,
                &truth,
                &wrench,
                &[0; MAX_JOINTS],
                &target,
                &seed.q_deg,
                &NumericOptions::default(),
            )
            .unwrap();
            let reached = robot.tool_in_world(&truth, &q, &wrench, &[0; MAX_JOINTS]);
            assert!((reached.origin_mm - target.origin_mm).norm() < 1e-9);
            assert!(reached.angle_to(&target) < 1e-9);
            // Where the nominal seed is near the generating configuration the loaded
            // solution is that configuration; near a singularity the seed may sit on
            // another branch, which reaches the same pose.
            if distance(&seed.q_deg, &q_true) < 2.0 {
                assert!(distance(&q, &q_true) < 1e-6, "{q:?} vs {q_true:?}");
                well_conditioned += 1;
            }
        }
        assert!(well_conditioned > 80, "{well_conditioned}");
    }

    /// An arm with no closed form: odd twists, offsets on every joint, lengths
    /// and offsets of both signs, axes 2 and 3 not parallel, no spherical wrist.
    fn odd_arm() -> Robot {
        let mut spec = irb1600().spec().clone();
        let table = [
            // alpha, a, theta offset, d, limits
            (0.0, 0.0, 15.0, 400.0, [-170.0, 170.0]),
            (-80.0, 120.0, -75.0, 35.0, [-100.0, 130.0]),
            (10.0, 650.0, 20.0, -40.0, [-220.0, 70.0]),
            (-95.0, -30.0, 0.0, 550.0, [-360.0, 360.0]),
            (70.0, 20.0, -30.0, 60.0, [-125.0, 125.0]),
            (-100.0, 10.0, 180.0, 90.0, [-400.0, 400.0]),
        ];
        for (joint, (alpha, a, offset, d, limits)) in spec.joints.iter_mut().zip(table) {
            joint.alpha_deg = alpha;
            joint.a_mm = a;
            joint.theta_offset_deg = offset;
            joint.d_mm = d;
            joint.limits_deg = Some(limits);
        }
        Robot::new(spec)
    }

    fn same_configuration(
        a: &[f64; MAX_JOINTS],
        b: &[f64; MAX_JOINTS],
        tolerance_deg: f64,
    ) -> bool {
        a.iter()
            .zip(b)
            .all(|(x, y)| wrap_deg(x - y).abs() < tolerance_deg)
    }

    /// Every numeric solution reaches the pose, lies within the limits, is listed
    /// once, and the joint vector that generated the pose is among them.
    fn check_numeric_round_trips(robot: &Robot, seed: u64, poses: usize) -> (usize, usize) {
        let mut rng = StdRng::seed_from_u64(seed);
        let (mut found, mut solutions_total) = (0, 0);
        for _ in 0..poses {
            let q = random_q(robot, &mut rng);
            let pose = robot.nominal_flange_in_base(&q);
            let solutions = numeric(robot, &pose, &NumericIkOptions::default());
            for (k, s) in solutions.iter().enumerate() {
                assert!(robot.within_limits(&s.q_deg), "{s:?}");
                let fk = robot.nominal_flange_in_base(&s.q_deg);
                let (dp, da) = ((fk.origin_mm - pose.origin_mm).norm(), fk.angle_to(&pose));
                assert!(
                    dp < 1e-9 && da < 1e-9,
                    "{q:?} -> {s:?}: {dp:e} mm, {da:e} rad"
                );
                assert_eq!(s.branch, branch_of(robot, &s.q_deg));
                for other in &solutions[k + 1..] {
                    assert!(
                        s.q_deg
                            .iter()
                            .zip(&other.q_deg)
                            .any(|(a, b)| (a - b).abs() > 1e-6),
                        "{s:?} listed twice"
                    );
                }
            }
            solutions_total += solutions.len();
            // The generator itself, in its own turn of every joint.
            if solutions
                .iter()
                .any(|s| s.q_deg.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-6))
            {
                found += 1;
            }
        }
        (found, solutions_total)
    }

    /// A seven-joint arm (the Panda) with its joint 3 held at the
    /// generating configuration's value: the six others find that
    /// configuration among the solutions, every solution reaches the pose
    /// and keeps the held joint.
    #[test]
    fn numeric_ik_of_a_seven_joint_arm_holds_its_joint_3() {
        let robot = crate::robot::test_support::panda();
        assert_eq!(free_joints(&robot), [0, 1, 3, 4, 5, 6]);
        assert!(matches!(
            solve(&robot, &Frame::identity()),
            Err(IkError::UnsupportedGeometry(_))
        ));
        let mut rng = StdRng::seed_from_u64(31);
        let (mut found, poses) = (0, 100);
        for _ in 0..poses {
            let q = random_q(&robot, &mut rng);
            let pose = robot.nominal_flange_in_base(&q);
            let held = q[HELD_JOINT_OF_SEVEN];
            let solutions = solve_holding(&robot, &pose, held).unwrap_or_default();
            for s in &solutions {
                assert!(robot.within_limits(&s.q_deg), "{s:?}");
                assert_eq!(s.q_deg[HELD_JOINT_OF_SEVEN], wrap_deg(held));
                let fk = robot.nominal_flange_in_base(&s.q_deg);
                assert!((fk.origin_mm - pose.origin_mm).norm() < 1e-9 && fk.angle_to(&pose) < 1e-9);
            }
            if solutions
                .iter()
                .any(|s| s.q_deg.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-6))
            {
                found += 1;
            }
        }
        assert!(
            found >= 95,
            "the generating configuration in {found} of {poses}"
        );
    }

    /// The loaded solver on a seven-joint arm keeps the seed's held joint and
    /// puts the loaded tool on the target.
    #[test]
    fn loaded_ik_of_a_seven_joint_arm_keeps_the_held_joint() {
        let robot = crate::robot::test_support::panda();
        let mut p = ParamValues::nominal(robot.spec());
        for joint in 0..7 {
            p.0[crate::robot::ParamId::of_joint(crate::robot::JointParam::Compliance, joint)
                .index()] = 0.005;
            p.0[crate::robot::ParamId::of_joint(crate::robot::JointParam::A, joint).index()] = 0.3;
        }
        let mut rng = StdRng::seed_from_u64(32);
        let mut solved = 0;
        for _ in 0..30 {
            let q_true = random_q(&robot, &mut rng);
            let wrench = random_wrench(&mut rng);
            let target = robot.tool_in_world(&p, &q_true, &wrench, &[0; MAX_JOINTS]);
            // Off the solution in every joint but the held one.
            let mut seed = q_true;
            for (joint, value) in seed.iter_mut().enumerate() {
                if joint != HELD_JOINT_OF_SEVEN {
                    *value += if joint % 2 == 0 { 0.5 } else { -0.5 };
                }
            }
            let Ok(q) = solve_loaded(
                &robot,
                &p,
                &wrench,
                &[0; MAX_JOINTS],
                &target,
                &seed,
                &NumericOptions::default(),
            ) else {
                continue;
            };
            solved += 1;
            assert_eq!(q[HELD_JOINT_OF_SEVEN], q_true[HELD_JOINT_OF_SEVEN]);
            let reached = robot.tool_in_world(&p, &q, &wrench, &[0; MAX_JOINTS]);
            assert!((reached.origin_mm - target.origin_mm).norm() < 1e-9);
            assert!(reached.angle_to(&target) < 1e-9);
        }
        assert!(solved >= 27, "{solved} of 30 converged");
    }

    /// A gantry (three prismatic joints, then a wrist): the closed form
    /// refuses it, the numeric search finds the generating configuration,
    /// and the loaded IK moves the slides by millimetres to reach a pose
    /// under load.
    #[test]
    fn numeric_ik_of_a_gantry_finds_the_generating_configuration() {
        let robot = crate::robot::test_support::gantry();
        let refusal = closed_form_applies(&robot).unwrap_err().to_string();
        assert!(refusal.contains("joint 1 is prismatic"), "{refusal}");
        let (found, total) = check_numeric_round_trips(&robot, 23, 100);
        assert!(found >= 99, "{found} of 100 generators found");
        assert!(total >= 100, "{total}");

        let mut p = ParamValues::nominal(robot.spec());
        for joint in 0..3 {
            p.set(
                crate::robot::ParamId::of_joint(crate::robot::JointParam::Compliance, joint),
                2e-3,
            );
        }
        let mut rng = StdRng::seed_from_u64(24);
        for _ in 0..20 {
            let q_true = random_q(&robot, &mut rng);
            let wrench = Wrench::from_array([0.0, 0.0, 150.0, 0.0, 0.0, 0.0]);
            let target = robot.tool_in_world(&p, &q_true, &wrench, &[0; MAX_JOINTS]);
            let seed = robot.joint_vector(|joint| q_true[joint] + 2.0);
            let q = solve_loaded(
                &robot,
                &p,
                &wrench,
                &[0; MAX_JOINTS],
                &target,
                &seed,
                &NumericOptions::default(),
            )
            .unwrap();
            let reached = robot.tool_in_world(&p, &q, &wrench, &[0; MAX_JOINTS]);
            assert!((reached.origin_mm - target.origin_mm).norm() < 1e-6);
            for joint in 0..6 {
                assert!((q[joint] - q_true[joint]).abs() < 1e-6, "{q:?} {q_true:?}");
            }
        }
    }

    #[test]
    fn numeric_ik_of_the_ur10_finds_the_generating_configuration() {
        let robot = ur10();
        assert!(matches!(
            closed_form_applies(&robot),
            Err(IkError::UnsupportedGeometry(_))
        ));
        let (found, total) = check_numeric_round_trips(&robot, 21, 100);
        assert!(found >= 99, "{found} of 100 generators found");
        // Up to 8 configurations, each in 2^6 turns within ±360°.
        assert!(total > 100 * 64, "{total}");
    }

    #[test]
    fn numeric_ik_of_an_arm_with_odd_twists_and_offsets_finds_the_generating_configuration() {
        let robot = odd_arm();
        assert!(closed_form_applies(&robot).is_err());
        let (found, _) = check_numeric_round_trips(&robot, 22, 100);
        assert!(found >= 99, "{found} of 100 generators found");
    }

    #[test]
    fn numeric_ik_finds_the_closed_form_solutions_of_the_irb1600() {
        let robot = irb1600();
        let mut rng = StdRng::seed_from_u64(23);
        let mut compared = 0;
        for _ in 0..100 {
            let q = random_q(&robot, &mut rng);
            let pose = robot.nominal_flange_in_base(&q);
            let Ok(exact) = closed_form(&robot, &pose) else {
                continue;
            };
            let found = numeric(&robot, &pose, &NumericIkOptions::default());
            for s in &exact {
                let twin = found.iter().find(|f| {
                    f.q_deg
                        .iter()
                        .zip(&s.q_deg)
                        .all(|(a, b)| (a - b).abs() < 1e-6)
                });
                let twin = twin.unwrap_or_else(|| panic!("{s:?} not found in {found:?}"));
                assert_eq!(twin.branch, s.branch, "{s:?}");
                assert_eq!(branch_of(&robot, &s.q_deg), s.branch, "{s:?}");
            }
            // The closed form is complete: the search finds nothing else.
            assert_eq!(found.len(), exact.len(), "{q:?}");
            compared += 1;
        }
        assert!(compared > 95, "{compared}");
    }

    #[test]
    fn closed_form_handles_any_signs_and_offsets_of_its_family() {
        let mut spec = irb1600().spec().clone();
        // Same twists and zeros, other lengths' signs and every theta offset set.
        for (joint, (a, offset, d)) in spec.joints.iter_mut().zip([
            (0.0, 25.0, -300.0),
            (-150.0, 40.0, 0.0),
            (-700.0, -60.0, 0.0),
            (120.0, 10.0, -600.0),
            (0.0, 90.0, 0.0),
            (0.0, -20.0, -80.0),
        ]) {
            joint.a_mm = a;
            joint.theta_offset_deg = offset;
            joint.d_mm = d;
        }
        let robot = Robot::new(spec);
        closed_form_applies(&robot).unwrap();
        let mut rng = StdRng::seed_from_u64(24);
        let mut found = 0;
        for _ in 0..300 {
            let q = random_q(&robot, &mut rng);
            let pose = robot.nominal_flange_in_base(&q);
            let Ok(solutions) = closed_form(&robot, &pose) else {
                continue;
            };
            for s in &solutions {
                let fk = robot.nominal_flange_in_base(&s.q_deg);
                assert!((fk.origin_mm - pose.origin_mm).norm() < 1e-9, "{s:?}");
                assert!(fk.angle_to(&pose) < 1e-9, "{s:?}");
                assert_eq!(branch_of(&robot, &s.q_deg), s.branch, "{s:?}");
            }
            if solutions
                .iter()
                .any(|s| s.q_deg.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-6))
            {
                found += 1;
            }
        }
        assert!(found > 290, "{found}");
    }

    #[test]
    fn unreachable_poses_have_no_numeric_solution() {
        let mut far = Frame::identity();
        far.origin_mm = Vector3::new(3000.0, 0.0, 500.0);
        for robot in [ur10(), odd_arm()] {
            assert!(numeric(&robot, &far, &NumericIkOptions::default()).is_empty());
            assert!(matches!(solve(&robot, &far), Err(IkError::Unreachable(_))));
        }
    }

    #[test]
    fn solve_takes_the_closed_form_where_it_applies_and_the_numeric_search_elsewhere() {
        let irb = irb1600();
        let q = [10.0, 20.0, -10.0, 30.0, 40.0, 50.0];
        let pose = irb.nominal_flange_in_base(&joint_array(&q));
        assert_eq!(solve(&irb, &pose), closed_form(&irb, &pose));
        let ur = ur10();
        let pose = ur.nominal_flange_in_base(&joint_array(&q));
        let numeric = numeric(&ur, &pose, &NumericIkOptions::default());
        assert_eq!(solve(&ur, &pose).unwrap(), numeric);
        // A hint is tried first and found like any start.
        let hinted = super::numeric(
            &ur,
            &pose,
            &NumericIkOptions {
                starts: 0,
                hint_deg: Some([12.0, 18.0, -11.0, 29.0, 41.0, 52.0, 0.0]),
                ..NumericIkOptions::default()
            },
        );
        assert!(
            hinted
                .iter()
                .any(|s| same_configuration(&s.q_deg, &joint_array(&q), 1e-6)),
            "{hinted:?}"
        );
    }

    fn distance(a: &[f64; MAX_JOINTS], b: &[f64; MAX_JOINTS]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            .sqrt()
    }
}
