//! Load-aware compensation: for each Cartesian target, the joint command that
//! puts the calibrated robot's tool there under the target's wrench, and what a
//! controller that keeps its nominal model must be sent instead of the target.
//!
//! Controllers keep their nominal kinematics, so a calibration pays off only
//! when someone turns it into motion offline. This module is that step, a pure
//! function over targets ([`compensate`]); the `compensate` stage only reads and
//! writes the tables (`../shared/spec/model.md` §7).
//!
//! The model is the one `predict` uses ([`Robot::tool_in_world`]): the chosen
//! parameter set's world and tool frames and geometry errors, and the compliance
//! deflection under the load torques of gravity (links and the robot file's
//! payload) plus the target's wrench. So a command is right for the load the
//! robot carries at that target, not only for its geometry. Each target names
//! the set's tool it aims ([`Target::tool`]: an SMR nest of a several-target
//! set, spec §7, §8); everything for that row (candidates, solve, residual,
//! elastic part) uses that tool's translation ([`ParamValues::aimed_at`]).
//!
//! Per target, in three passes (the first and last in parallel):
//!
//! 1. **Candidates.** Every configuration of the nominal arm ([`ik::solve`]: the
//!    closed form where it applies, else the numeric search) for the flange pose
//!    that puts the tool on the target with the chosen set's world and tool
//!    frames ([`ik::flange_target_in_base`]). Using the set's frames, not the
//!    robot file's, keeps the seeds right when the file's `[world]` is far off
//!    (a tracker put anywhere, spec §7).
//! 2. **Seed** (sequential, cheap). The target's branch hint (its q columns) when
//!    given, used as it is. Otherwise the candidate within the joint limits
//!    closest (Euclidean distance of the joint vectors in degrees) to the
//!    previous target's seed, so a path does not flip branches until its branch
//!    leaves the limits; the first target takes the candidate closest to the
//!    home configuration q = 0. Only when every candidate is beyond the limits
//!    does the closest of those seed the solve (status `joint_limit`). The previous *seed* rather than the previous
//!    command is the reference so that the solves stay independent (parallel);
//!    the two differ by the compensation, a fraction of a degree. A target without
//!    candidates is seeded by its hint, else the previous seed, else q = 0, so
//!    the solve still reports how close it gets.
//! 3. **Solve** ([`ik::solve_loaded_iterate`], Levenberg–Marquardt on the
//!    calibrated loaded model), then the status and the derived values.
//!
//! Statuses, first match wins (never NaN, never a clipped command):
//!
//! * converged: `joint_limit` when the command lies outside the robot file's
//!   limits (the command is kept and reported); `singular` when the scaled
//!   geometric Jacobian's smallest singular value at the command is below the
//!   threshold ([`Options::singular_sigma_min_mm_per_rad`]: a joint motion of
//!   1 rad moves the tool less than that along its weakest direction, 1 rad of
//!   tool rotation counting as 1000 mm); `ok` otherwise;
//! * not converged: `singular` when the nominal inverse kinematics found the
//!   pose singular; `unreachable` when the nominal arm has no configuration for
//!   it within the limits, or the solve stalled (no step lowers the pose error:
//!   a local minimum such as the arm stretched towards a point beyond its
//!   reach); `not_converged` when the iterations ran out while it still improved.
//!
//! A row that is not `ok` carries the solver's last iterate: the last joint
//! vector whose step lowered the error (the seed if none did), finite because the
//! seed is.

pub mod envelope;

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::robot::frame::{Frame, rot_x, rot_y, rot_z};
use crate::robot::ik::{self, IkError, IkSolution, NumericOptions};
use crate::robot::jacobian::deflected_tool_and_joints;
use crate::robot::{MAX_JOINTS, ParamId, ParamValues, PreparedRobot, Robot, Wrench};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// One target row: where the tool must be, in the world (tracker) frame, the
/// wrench on the robot there, and which of the parameter set's tools (SMR
/// nests, spec §7) must be there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    pub tool_in_world: Frame,
    /// Applied to the robot, tool axes, at the tool origin.
    pub wrench: Wrench,
    /// A configuration near the wanted one (deg), used as the seed.
    pub hint_deg: Option<[f64; MAX_JOINTS]>,
    /// The set's target (0-based, [`crate::robot::ParamId::target_translation`])
    /// whose tool translation is aimed: 0 for a one-target set.
    pub tool: usize,
    /// Where a linear track's carriage stands for this target (mm; 0
    /// without a track): the arm reaches the target from there.
    pub track_mm: f64,
}

impl Target {
    /// From the `targets` columns: position (mm) and orientation
    /// world←tool = Rot(x, rx)·Rot(y, ry)·Rot(z, rz) (deg).
    pub fn from_columns(
        position_mm: [f64; 3],
        orientation_deg: [f64; 3],
        wrench: Wrench,
        hint_deg: Option<[f64; MAX_JOINTS]>,
    ) -> Self {
        Target {
            tool_in_world: pose_frame(position_mm, orientation_deg),
            wrench,
            hint_deg,
            tool: 0,
            track_mm: 0.0,
        }
    }

    /// The same target reached with the track's carriage at `track_mm`.
    pub fn at_track(self, track_mm: f64) -> Self {
        Target { track_mm, ..self }
    }

    /// The same target for the set's tool `tool` (0-based).
    pub fn with_tool(self, tool: usize) -> Self {
        Target { tool, ..self }
    }
}

/// The frame of a pose written as the `targets` columns: origin `position_mm`,
/// rotation Rot(x, rx)·Rot(y, ry)·Rot(z, rz) of `orientation_deg` (parent ←
/// child: the origin first, then the XYZ angles about the moved axes).
pub fn pose_frame(position_mm: [f64; 3], orientation_deg: [f64; 3]) -> Frame {
    let [rx, ry, rz] = orientation_deg.map(|a| a * DEG);
    Frame {
        rotation: rot_x(rx) * rot_y(ry) * rot_z(rz),
        origin_mm: Vector3::from(position_mm),
    }
}

/// Why a command is or is not one to send (see the module doc for the rules).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Status {
    Ok,
    Unreachable,
    JointLimit,
    Singular,
    NotConverged,
    /// Converged and within the limits, but farther from the calibration rows
    /// than allowed, or with a predicted 95 % uncertainty larger than allowed
    /// ([`envelope::judged`]): a command the calibration does not vouch for.
    OutsideEnvelope,
}

impl Status {
    pub const ALL: [Status; 6] = [
        Status::Ok,
        Status::Unreachable,
        Status::JointLimit,
        Status::Singular,
        Status::NotConverged,
        Status::OutsideEnvelope,
    ];

    /// The `status` value of the `commands` table.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Unreachable => "unreachable",
            Status::JointLimit => "joint_limit",
            Status::Singular => "singular",
            Status::NotConverged => "not_converged",
            Status::OutsideEnvelope => "outside_envelope",
        }
    }
}

/// The compensated command for one target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub q_deg: [f64; MAX_JOINTS],
    pub status: Status,
    /// Tool position error the solve left on the calibrated loaded model.
    pub residual_mm: f64,
    /// Distance between where the controller's nominal model puts the tool at
    /// this command and the target: nominal arm, robot file's flange → tool, zero
    /// compliance (so the wrench moves nothing), placed in the world with the
    /// chosen set's world frame, because a controller has no world frame of its
    /// own and the target reaches it through that registration.
    pub correction_mm: f64,
    /// The part due to the load: distance between the calibrated model's tool
    /// position at this command with and without the compliance deflection of
    /// gravity (links and payload) plus the target's wrench.
    pub elastic_mm: f64,
    /// The corrected Cartesian target for a controller with its nominal model:
    /// nominal forward kinematics of the command with the calibrated flange →
    /// tool of the row's SMR (the tool `export_program` declares), in the robot
    /// base frame.
    pub tool_in_base_cmd: Frame,
    /// Its orientation, base←tool, as a unit quaternion (w, x, y, z) with w ≥ 0
    /// (q and −q are the same rotation; the sign is fixed so the table is
    /// reproducible).
    pub quaternion_wxyz_cmd: [f64; 4],
    /// Smallest singular value of the scaled geometric Jacobian at the command
    /// (mm/rad), the singularity measure.
    pub sigma_min_mm_per_rad: f64,
}

/// Solver tolerances and the singularity threshold.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    pub solver: NumericOptions,
    /// A converged command whose scaled geometric Jacobian has a smallest
    /// singular value below this (mm/rad) is `singular`. For the IRB 1600 the
    /// wrist measure is about 7 mm/rad per degree of q5 near q5 = 0.
    pub singular_sigma_min_mm_per_rad: f64,
    /// The direction each joint approaches every command from (spec §8): a
    /// program's pre-positioning move makes it so. Zeros: not known, the
    /// middle of any backlash.
    pub approach: [i8; MAX_JOINTS],
    /// A seven-joint arm's held joint ([`ik::HELD_JOINT_OF_SEVEN`], joint 3)
    /// at a target without a branch hint (deg); a hint holds it at its own
    /// value. Ignored for a six-joint arm.
    pub held_joint_deg: f64,
}

/// The nominal model as the controller sees it, placed in the world by the
/// chosen set's world frame: robot file's geometry and tool, zero compliance.
///
/// A controller knows one tool, the robot file's. For a further target of a
/// several-target set (`tool` > 0) that tool is moved by the set's calibrated
/// offset between the target's translation and target 0's, so that the distance
/// between two SMR nests is not counted as a correction; `tool` 0 (every
/// one-target set) is the file's tool as it is.
fn controller_model(robot: &Robot, calibrated: &ParamValues, tool: usize) -> ParamValues {
    let mut values = ParamValues::nominal(robot.spec());
    values.0[..6].copy_from_slice(&calibrated.0[..6]);
    for axis in 0..3 {
        let offset = calibrated.get(ParamId::target_translation(tool, axis))
            - calibrated.get(ParamId::target_translation(0, axis));
        values.0[ParamId::target_translation(0, axis).index()] += offset;
    }
    values
}

/// The nominal arm with the calibrated flange → tool of target `tool` (its
/// translation and the set's tool rotation): the tool `export` declares in a
/// program, whose pose at a command is the corrected Cartesian target.
fn declared_tool_model(robot: &Robot, calibrated: &ParamValues, tool: usize) -> ParamValues {
    let mut values = ParamValues::nominal(robot.spec());
    for axis in 0..3 {
        let slot = ParamId::target_translation(0, axis);
        values.set(
            slot,
            calibrated.get(ParamId::target_translation(tool, axis)),
        );
        values.0[9 + axis] = calibrated.0[9 + axis];
    }
    values
}

/// What the nominal inverse kinematics says about one target.
enum Candidates {
    Found(Vec<IkSolution>),
    Singular,
    None,
}

/// The pose the arm must give its tool, with its base where the world frame
/// alone puts it, for `target` to be reached with the carriage at the
/// target's position: `W·C(e)⁻¹·W⁻¹·T`, the carriage's calibrated
/// transform `C(e)` taken out. The solvers place the arm by the world frame
/// `W`; the carriage moves the whole arm rigidly (loads in tool axes,
/// gravity in the base frame), so this target is exact. The target itself
/// without a track.
fn arm_target(prepared: &PreparedRobot, target: &Target) -> Frame {
    match prepared.carriage(target.track_mm) {
        None => target.tool_in_world,
        Some(_) => prepared
            .world_from_base
            .compose(&prepared.world_from_base_at(target.track_mm).inverse())
            .compose(&target.tool_in_world),
    }
}

/// `aimed` is the set aimed at the target's tool ([`ParamValues::aimed_at`]);
/// `tool_in_world` the pose its arm must reach ([`arm_target`]).
///
/// A seven-joint arm's candidates hold its joint 3 at `held_deg`.
fn candidates(
    robot: &Robot,
    aimed: &ParamValues,
    tool_in_world: &Frame,
    held_deg: f64,
) -> Candidates {
    let flange = ik::flange_target_in_base(robot, aimed, tool_in_world);
    match ik::solve_holding(robot, &flange, held_deg) {
        Ok(solutions) => Candidates::Found(solutions),
        Err(IkError::Singular(_)) => Candidates::Singular,
        Err(_) => Candidates::None,
    }
}

fn distance_deg(a: &[f64; MAX_JOINTS], b: &[f64; MAX_JOINTS]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The seed rule of the module doc, over all targets in order. A target's
/// candidates within the joint limits come first (the nearest of them to the
/// previous seed), so a path leaves its branch only where that branch leaves
/// the limits; only when every candidate is beyond them does the nearest of
/// those seed the solve (which then ends `joint_limit`).
fn seeds(robot: &Robot, targets: &[Target], candidates: &[Candidates]) -> Vec<[f64; MAX_JOINTS]> {
    let mut previous = [0.0; MAX_JOINTS];
    targets
        .iter()
        .zip(candidates)
        .map(|(target, found)| {
            let seed = match (target.hint_deg, found) {
                (Some(hint), _) => hint,
                (None, Candidates::Found(solutions)) => {
                    let nearest = |within_limits: bool| {
                        solutions
                            .iter()
                            .map(|s| s.q_deg)
                            .filter(|q| robot.within_limits(q) == within_limits)
                            .min_by(|a, b| {
                                distance_deg(a, &previous).total_cmp(&distance_deg(b, &previous))
                            })
                    };
                    nearest(true).or_else(|| nearest(false)).unwrap_or(previous)
                }
                (None, _) => previous,
            };
            previous = seed;
            seed
        })
        .collect()
}

/// The model rows of `commands`: each command's joints under its target's
/// wrench and tool, approached from `approach`; what J·Σ·Jᵀ and the residual
/// model are evaluated at.
pub fn command_rows(
    targets: &[Target],
    commands: &[Command],
    approach: [i8; MAX_JOINTS],
) -> Vec<crate::robot::ConfWrench> {
    targets
        .iter()
        .zip(commands)
        .map(|(target, command)| crate::robot::ConfWrench {
            target: target.tool,
            approach,
            track_mm: target.track_mm,
            positioner_deg: None,
            ..crate::robot::ConfWrench::new(command.q_deg, target.wrench)
        })
        .collect()
}

/// Compensates every target with the parameter set `calibrated`; one
/// [`Command`] per target, in order. An unreachable or singular target does not
/// affect the others' commands except as the previous seed of an unhinted
/// successor.
///
/// Cost per target: the nominal inverse kinematics (µs for the closed form, ~1 ms
/// for the numeric search of arms without one) and a few Levenberg–Marquardt
/// steps on the loaded model; the first and last run in parallel over targets.
pub fn compensate(
    robot: &Robot,
    calibrated: &ParamValues,
    targets: &[Target],
    options: &Options,
) -> Vec<Command> {
    // Per tool used: the set aimed at it, its prepared calibrated model and the
    // controller's (at most MAX_TARGETS of each, prepared once).
    let tools = targets.iter().map(|t| t.tool + 1).max().unwrap_or(0);
    let aimed: Vec<ParamValues> = (0..tools).map(|k| calibrated.aimed_at(k)).collect();
    let controller: Vec<ParamValues> = (0..tools)
        .map(|k| controller_model(robot, calibrated, k))
        .collect();
    let calibrated_prepared: Vec<_> = aimed.iter().map(|v| robot.prepare(v)).collect();
    let controller_prepared: Vec<_> = controller.iter().map(|v| robot.prepare(v)).collect();
    // The corrected Cartesian target is a pose of the tool a program declares
    // for the row (`export`): the nominal arm with the set's calibrated tool of
    // the row's SMR, so the table and the programs agree.
    let declared: Vec<ParamValues> = (0..tools)
        .map(|k| declared_tool_model(robot, calibrated, k))
        .collect();
    let declared_prepared: Vec<_> = declared.iter().map(|v| robot.prepare(v)).collect();
    let arm_targets: Vec<Frame> = targets
        .iter()
        .map(|t| arm_target(&calibrated_prepared[t.tool], t))
        .collect();
    let found: Vec<Candidates> = targets
        .par_iter()
        .zip(&arm_targets)
        .map(|(t, arm_target)| {
            let held_deg = t
                .hint_deg
                .map_or(options.held_joint_deg, |hint| hint[ik::HELD_JOINT_OF_SEVEN]);
            candidates(robot, &aimed[t.tool], arm_target, held_deg)
        })
        .collect();
    let seeds = seeds(robot, targets, &found);
    targets
        .par_iter()
        .zip(&arm_targets)
        .zip(&found)
        .zip(&seeds)
        .map(|(((target, arm_target), found), seed)| {
            let values = &aimed[target.tool];
            let iterate = ik::solve_loaded_iterate(
                robot,
                values,
                &target.wrench,
                &options.approach,
                arm_target,
                seed,
                &options.solver,
            );
            let q = iterate.q_deg;
            let (tool, joints) =
                deflected_tool_and_joints(robot, values, &q, &target.wrench, &options.approach);
            let sigma_min_mm_per_rad = ik::scaled_geometric_jacobian(
                &tool,
                &joints,
                &ik::free_joints(robot),
                &robot.prismatic_joints(),
            )
            .singular_values()
            .min();
            let status = if iterate.converged {
                if !robot.within_limits(&q) {
                    Status::JointLimit
                } else if sigma_min_mm_per_rad < options.singular_sigma_min_mm_per_rad {
                    Status::Singular
                } else {
                    Status::Ok
                }
            } else {
                match found {
                    Candidates::Singular => Status::Singular,
                    Candidates::None => Status::Unreachable,
                    Candidates::Found(_) if iterate.stalled => Status::Unreachable,
                    Candidates::Found(_) => Status::NotConverged,
                }
            };
            let calibrated = &calibrated_prepared[target.tool];
            let unloaded = calibrated.chain(&q, &[0.0; MAX_JOINTS]).tool;
            let elastic_mm = (calibrated
                .world_from_base
                .transform_point(&unloaded.origin_mm)
                - tool.origin_mm)
                .norm();
            // The controller's carriage is the nominal one: a translation.
            let controller = &controller_prepared[target.tool];
            let controller_tool = controller.chain(&q, &[0.0; MAX_JOINTS]).tool;
            let correction_mm = (controller
                .world_from_base_at(target.track_mm)
                .transform_point(&controller_tool.origin_mm)
                - target.tool_in_world.origin_mm)
                .norm();
            let tool_in_base_cmd = declared_prepared[target.tool]
                .chain(&q, &[0.0; MAX_JOINTS])
                .tool;
            Command {
                q_deg: q,
                status,
                residual_mm: iterate.position_error_mm,
                correction_mm,
                elastic_mm,
                tool_in_base_cmd,
                quaternion_wxyz_cmd: quaternion_wxyz(&tool_in_base_cmd),
                sigma_min_mm_per_rad,
            }
        })
        .collect()
}

/// Unit quaternion (w, x, y, z) of a frame's rotation, w ≥ 0.
fn quaternion_wxyz(frame: &Frame) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(frame.rotation));
    let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
    [q.w * sign, q.i * sign, q.j * sign, q.k * sign]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::joint_array;
    use crate::robot::test_support::{irb1600, truth_params};

    fn solution(q_deg: [f64; MAX_JOINTS]) -> IkSolution {
        IkSolution { q_deg, branch: 0 }
    }

    #[test]
    fn seeds_start_nearest_home_then_follow_the_previous_seed_or_the_hint() {
        let pose = Target::from_columns([0.0; 3], [0.0; 3], Wrench::zero(), None);
        let a = [10.0, 0.0, 0.0, 0.0, 30.0, 0.0];
        let b = [-170.0, 0.0, 0.0, 0.0, -30.0, 0.0];
        let hint = [-160.0, 0.0, 0.0, 0.0, -25.0, 0.0];
        let targets = [
            pose,
            pose,
            Target {
                hint_deg: Some(joint_array(&hint)),
                ..pose
            },
            pose,
            pose,
        ];
        let found = [
            Candidates::Found(vec![solution(joint_array(&b)), solution(joint_array(&a))]),
            Candidates::Found(vec![solution(joint_array(&b)), solution(joint_array(&a))]),
            Candidates::Found(vec![solution(joint_array(&a))]),
            Candidates::Found(vec![solution(joint_array(&a)), solution(joint_array(&b))]),
            Candidates::None,
        ];
        // Nearest q = 0, then nearest the previous seed; a hint is taken as it
        // is and becomes the reference; no candidates keeps the previous seed.
        assert_eq!(
            seeds(&irb1600(), &targets, &found),
            [a, a, hint, b, b].map(|q| joint_array(&q))
        );
    }

    #[test]
    fn a_candidate_within_the_limits_is_preferred_to_a_nearer_one_beyond() {
        let robot = irb1600();
        let pose = Target::from_columns([0.0; 3], [0.0; 3], Wrench::zero(), None);
        // q5 beyond its ±115° limit, nearer q = 0 than the other branch.
        let beyond = [0.0, 0.0, 0.0, 0.0, 120.0, 0.0];
        let within = [150.0, 0.0, 0.0, 0.0, -100.0, 0.0];
        let also_beyond = [0.0, 0.0, 0.0, 0.0, 130.0, 0.0];
        assert!(
            !robot.within_limits(&joint_array(&beyond))
                && robot.within_limits(&joint_array(&within))
        );
        let found = [
            Candidates::Found(vec![
                solution(joint_array(&beyond)),
                solution(joint_array(&within)),
            ]),
            Candidates::Found(vec![
                solution(joint_array(&also_beyond)),
                solution(joint_array(&beyond)),
            ]),
        ];
        // Every candidate beyond: the nearest of them (and `joint_limit` later).
        assert_eq!(
            seeds(&robot, &[pose, pose], &found),
            [within, beyond].map(|q| joint_array(&q))
        );
    }

    #[test]
    fn the_quaternion_has_w_at_least_zero_and_is_the_rotation() {
        for angle_deg in [0.0, 90.0, 179.0, 181.0, 350.0] {
            let frame = Frame {
                rotation: rot_z(angle_deg * DEG) * rot_x(0.3),
                origin_mm: Vector3::zeros(),
            };
            let [w, x, y, z] = quaternion_wxyz(&frame);
            assert!(w >= 0.0, "{angle_deg}");
            let back = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
            assert!((back.to_rotation_matrix().matrix() - frame.rotation).norm() < 1e-12);
        }
    }

    #[test]
    fn running_out_of_iterations_is_not_converged_and_keeps_a_finite_iterate() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let q = [10.0, 20.0, -10.0, 30.0, 40.0, 50.0];
        let wrench = Wrench::from_array([50.0, -80.0, 100.0, 5.0, 0.0, -5.0]);
        let target = Target {
            tool_in_world: robot.tool_in_world(&truth, &joint_array(&q), &wrench, &[0; MAX_JOINTS]),
            wrench,
            hint_deg: Some([12.0, 18.0, -12.0, 28.0, 42.0, 48.0, 0.0]),
            tool: 0,
            track_mm: 0.0,
        };
        let options = Options {
            solver: NumericOptions {
                max_iterations: 1,
                position_tolerance_mm: 1e-9,
                orientation_tolerance_rad: 1e-9,
                ..NumericOptions::default()
            },
            singular_sigma_min_mm_per_rad: 3.5,
            approach: [0; MAX_JOINTS],
            held_joint_deg: 0.0,
        };
        let one = compensate(&robot, &truth, &[target], &options)[0];
        assert_eq!(one.status, Status::NotConverged, "{one:?}");
        assert!(one.q_deg.iter().all(|v| v.is_finite()) && one.residual_mm > 1e-9);
        let options = Options {
            solver: NumericOptions {
                max_iterations: 100,
                ..options.solver
            },
            ..options
        };
        let done = compensate(&robot, &truth, &[target], &options)[0];
        assert_eq!(done.status, Status::Ok, "{done:?}");
        assert!(done.q_deg.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-6));
    }

    /// On a track, the command puts the loaded tool on the target through the
    /// calibrated carriage at the target's position, and the correction is
    /// measured from where the controller's perfect carriage puts the tool.
    #[test]
    fn on_a_track_the_command_reaches_the_target_through_the_carriage() {
        use crate::robot::ConfWrench;
        use crate::robot::test_support::irb1600_on_track;
        let robot = irb1600_on_track();
        let mut truth = truth_params(&robot);
        for (name, value) in [
            ("track_scale", 0.4),
            ("track_y2", -2.0),
            ("track_z1", 1.2),
            ("track_pitch1", 0.08),
            ("track_yaw2", -0.04),
        ] {
            truth.set(ParamId::from_name(name).unwrap(), value);
        }
        let q = [10.0, 20.0, -10.0, 30.0, 40.0, 50.0];
        let wrench = Wrench::from_array([50.0, -80.0, 100.0, 5.0, 0.0, -5.0]);
        let row = ConfWrench {
            track_mm: 1800.0,
            positioner_deg: None,
            ..ConfWrench::new(joint_array(&q), wrench)
        };
        let target = Target {
            tool_in_world: robot.tool_in_world_of_row(&truth, &row),
            wrench,
            hint_deg: Some([12.0, 18.0, -12.0, 28.0, 42.0, 48.0, 0.0]),
            tool: 0,
            track_mm: 1800.0,
        };
        let options = Options {
            solver: NumericOptions::default(),
            singular_sigma_min_mm_per_rad: 3.5,
            approach: [0; MAX_JOINTS],
            held_joint_deg: 0.0,
        };
        let command = compensate(&robot, &truth, &[target], &options)[0];
        assert_eq!(command.status, Status::Ok, "{command:?}");
        assert!(
            command
                .q_deg
                .iter()
                .zip(&q)
                .all(|(a, b)| (a - b).abs() < 1e-6),
            "{:?}",
            command.q_deg
        );
        // The controller: nominal arm and tool, the calibrated world frame, a
        // carriage that only translates by e along the base's x axis.
        let controller = controller_model(&robot, &truth, 0);
        let prepared = robot.prepare(&controller);
        let flange_tool = prepared.chain(&joint_array(&q), &[0.0; MAX_JOINTS]).tool;
        let controller_tool = prepared
            .world_from_base
            .transform_point(&(flange_tool.origin_mm + Vector3::new(1800.0, 0.0, 0.0)));
        let expected = (controller_tool - target.tool_in_world.origin_mm).norm();
        assert!(
            (command.correction_mm - expected).abs() < 1e-6,
            "{} against {expected}",
            command.correction_mm
        );
        // Without the carriage's errors the same command misses by millimetres.
        let mut perfect = truth;
        for id in ParamId::track_terms(crate::robot::track::MAX_TRACK_ORDER) {
            perfect.set(id, 0.0);
        }
        let perfect_rail = robot.tool_in_world_of_row(&perfect, &row);
        assert!((perfect_rail.origin_mm - target.tool_in_world.origin_mm).norm() > 0.5);
    }
}
