//! The Cartesian side of a program: the tool it declares, the load on it, and
//! the pose of that tool at each joint command on the NOMINAL arm (with the
//! approach points of drilling targets).
//!
//! Why the poses are computed here rather than copied from the `commands`
//! table: a controller reproduces a joint command from a Cartesian target only
//! when the target is the nominal pose of the very tool the move names. The
//! table's `x_cmd_mm …` are that pose for the tool `compensate` used, which the
//! table does not record; computing the pose from the joint command and the tool
//! the program declares makes the pair right by construction, whatever tool that
//! is. The table's values are then only compared ([`table_deviation`]), and a
//! difference becomes a warning in every file.

use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use super::Command;
use crate::robot::ik;
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{Frame, MAX_JOINTS, ParamValues, Robot};

/// The tool a program declares and whose point its Cartesian targets are: flange
/// → tool on the nominal arm.
#[derive(Debug, Clone, PartialEq)]
pub struct ProgramTool {
    /// Target (SMR) id of a several-target parameter set; `None` for the one
    /// tool of a one-target set or of the robot file.
    pub target_id: Option<String>,
    /// Where its values come from, for the headers.
    pub source: String,
    pub flange_from_tool: Frame,
}

impl ProgramTool {
    /// Its TCP (mm) and orientation (unit quaternion w, x, y, z, w ≥ 0) in the
    /// flange frame: RAPID's `tframe`, KRL's `$TOOL` before the Euler angles.
    pub fn tcp_mm(&self) -> [f64; 3] {
        self.flange_from_tool.origin_mm.into()
    }

    pub fn quaternion_wxyz(&self) -> [f64; 4] {
        quaternion_wxyz(&self.flange_from_tool)
    }
}

/// The load the tool carries: the robot file's payload (the only mass egcal
/// knows at the flange), a point mass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Payload {
    pub mass_kg: f64,
    /// Centre of gravity in the tool frame, as the robot file gives it, mm.
    pub cog_in_tool_mm: [f64; 3],
}

impl Payload {
    /// Its centre of gravity in the flange frame (where RAPID's `tload` and
    /// KRL's `$LOAD` want it) for `tool`, mm.
    pub fn cog_in_flange_mm(&self, tool: &ProgramTool) -> [f64; 3] {
        tool.flange_from_tool
            .transform_point(&Vector3::from(self.cog_in_tool_mm))
            .into()
    }
}

/// One pose a Cartesian move goes to: the declared tool's pose in the robot
/// base frame on the nominal arm at `q_deg`, the joint configuration there
/// (which the configuration data describe).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub position_mm: [f64; 3],
    /// Base ← tool, unit quaternion (w, x, y, z), w ≥ 0.
    pub quaternion_wxyz: [f64; 4],
    pub q_deg: [f64; MAX_JOINTS],
}

/// The Cartesian moves of one `ok` row.
#[derive(Debug, Clone, PartialEq)]
pub struct Stop {
    pub target_id: i64,
    /// Index into the program's tools.
    pub tool: usize,
    /// The joint command's pose: where the move to the target goes.
    pub target: Pose,
    /// The point `approach_mm` back along the tool's z axis, moved to before
    /// the target and again after it; `None` without approach moves.
    pub approach: Option<Pose>,
    /// The joint configuration moved to before the target so that each joint
    /// reaches it from the command's approach direction (backlash); `None`
    /// without pre-positioning or without a direction.
    pub pre_position_q_deg: Option<[f64; MAX_JOINTS]>,
    /// The track's carriage position at every move of the stop (mm): the
    /// arm's poses are in the base frame riding on it. `None` without a track.
    pub track_mm: Option<f64>,
    /// The positioner's axis values at every move of the stop (deg); `None`
    /// when the program does not move it.
    pub positioner_deg: Option<[f64; MAX_POSITIONER_AXES]>,
}

/// Why a program's Cartesian moves cannot be written.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CartesianError {
    #[error(
        "target_id {target_id}: the approach point {approach_mm} mm back along the tool's z axis is out of the nominal arm's reach within its joint limits ({reason}); lower `approach_mm` or leave the target out"
    )]
    ApproachUnreachable {
        target_id: i64,
        approach_mm: f64,
        reason: String,
    },
    #[error(
        "target_id {target_id}: the approach point {approach_mm} mm back along the tool's z axis needs another arm configuration than the target (branch {approach_branch} instead of {target_branch}), so a linear move cannot join them; lower `approach_mm` or leave the target out"
    )]
    ApproachBranch {
        target_id: i64,
        approach_mm: f64,
        target_branch: u8,
        approach_branch: u8,
    },
    #[error(
        "target_id {target_id}: the pre-positioning move {pre_position_deg}° before the command on joint {joint} (to {q_deg}°, so that the joint reaches the command from the direction the backlash was compensated for) is outside the joint's limits [{lower_deg}°, {upper_deg}°]; compensate this target from the other direction (`compensate`'s `approach`) or leave it out"
    )]
    PrePositionOutsideLimits {
        target_id: i64,
        pre_position_deg: f64,
        joint: usize,
        q_deg: f64,
        lower_deg: f64,
        upper_deg: f64,
    },
    #[error(
        "target_id {target_id}: the command was compensated for joints reaching it from fixed directions (backlash), but a linear approach along the tool's z axis ({approach_mm} mm) decides the joints' directions itself; set `approach_mm` = 0, or `pre_position_deg` = 0 to write the program without pre-positioning (it then warns)"
    )]
    PrePositionWithApproach { target_id: i64, approach_mm: f64 },
}

/// The pose of `tool` at `q_deg` on `robot`'s nominal arm, base frame.
pub fn tool_in_base(robot: &Robot, tool: &ProgramTool, q_deg: &[f64; MAX_JOINTS]) -> Frame {
    let (frames, _) = robot.frames_in_base(&ParamValues::nominal(robot.spec()), q_deg);
    frames[robot.joint_count()].compose(&tool.flange_from_tool)
}

/// The Cartesian moves of the `ok` rows of `commands`, `row_tools[k]` being the
/// tool of row `k`. With `approach_mm`, each stop gets the point that far back
/// along the tool's z axis, with the nominal arm's configuration there nearest
/// the target's (which must be of the same branch).
///
/// With `pre_position_deg`, a row compensated for approach directions gets
/// the configuration that far back from its command along them.
///
/// Cost: one forward chain per row; with approach points, one nominal inverse
/// kinematics per row too (µs in closed form, about 1 ms numerically).
pub fn stops(
    robot: &Robot,
    commands: &[Command],
    tools: &[ProgramTool],
    row_tools: &[usize],
    approach_mm: Option<f64>,
    pre_position_deg: Option<f64>,
) -> Result<Vec<Stop>, CartesianError> {
    commands
        .iter()
        .zip(row_tools)
        .filter(|(c, _)| c.is_ok())
        .map(|(c, &tool_index)| {
            let tool = &tools[tool_index];
            let target_frame = tool_in_base(robot, tool, &c.q_deg);
            let approach = match approach_mm {
                Some(distance) => Some(approach_pose(robot, tool, &target_frame, c, distance)?),
                None => None,
            };
            let pre_position_q_deg = match pre_position_deg {
                Some(distance) if c.has_approach() => {
                    if let Some(approach_mm) = approach_mm {
                        return Err(CartesianError::PrePositionWithApproach {
                            target_id: c.target_id,
                            approach_mm,
                        });
                    }
                    Some(pre_position(robot, c, distance)?)
                }
                _ => None,
            };
            Ok(Stop {
                target_id: c.target_id,
                tool: tool_index,
                target: pose(&target_frame, c.q_deg),
                approach,
                pre_position_q_deg,
                track_mm: c.track_mm,
                positioner_deg: c.positioner_deg,
            })
        })
        .collect()
}

/// The command moved back by `distance_deg` against each joint's approach
/// direction, within the joint limits.
fn pre_position(
    robot: &Robot,
    command: &Command,
    distance_deg: f64,
) -> Result<[f64; MAX_JOINTS], CartesianError> {
    let mut q_deg = command.q_deg;
    for (joint, q) in q_deg.iter_mut().enumerate().take(robot.joint_count()) {
        *q -= f64::from(command.approach[joint]) * distance_deg;
        let [lower_deg, upper_deg] = robot.joint_limits(joint);
        if !(lower_deg..=upper_deg).contains(q) {
            return Err(CartesianError::PrePositionOutsideLimits {
                target_id: command.target_id,
                pre_position_deg: distance_deg,
                joint: joint + 1,
                q_deg: *q,
                lower_deg,
                upper_deg,
            });
        }
    }
    Ok(q_deg)
}

fn approach_pose(
    robot: &Robot,
    tool: &ProgramTool,
    target: &Frame,
    command: &Command,
    approach_mm: f64,
) -> Result<Pose, CartesianError> {
    let back = Frame {
        rotation: nalgebra::Matrix3::identity(),
        origin_mm: Vector3::new(0.0, 0.0, -approach_mm),
    };
    let approach = target.compose(&back);
    let flange = approach.compose(&tool.flange_from_tool.inverse());
    let unreachable = |reason: String| CartesianError::ApproachUnreachable {
        target_id: command.target_id,
        approach_mm,
        reason,
    };
    let solutions = ik::solve(robot, &flange).map_err(|e| unreachable(e.to_string()))?;
    let distance = |q: &[f64; MAX_JOINTS]| {
        q.iter()
            .zip(&command.q_deg)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
    };
    let nearest = solutions
        .iter()
        .map(|s| s.q_deg)
        .min_by(|a, b| distance(a).total_cmp(&distance(b)))
        .ok_or_else(|| unreachable("no configuration".into()))?;
    let (target_branch, approach_branch) = (
        ik::branch_of(robot, &command.q_deg),
        ik::branch_of(robot, &nearest),
    );
    if target_branch != approach_branch {
        return Err(CartesianError::ApproachBranch {
            target_id: command.target_id,
            approach_mm,
            target_branch,
            approach_branch,
        });
    }
    Ok(pose(&approach, nearest))
}

fn pose(frame: &Frame, q_deg: [f64; MAX_JOINTS]) -> Pose {
    Pose {
        position_mm: frame.origin_mm.into(),
        quaternion_wxyz: quaternion_wxyz(frame),
        q_deg,
    }
}

/// Unit quaternion (w, x, y, z) of a frame's rotation, w ≥ 0 (q and −q are the
/// same rotation; the sign is fixed so files are reproducible).
pub fn quaternion_wxyz(frame: &Frame) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(frame.rotation));
    let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
    [q.w * sign, q.i * sign, q.j * sign, q.k * sign]
}

/// Largest difference between the table's Cartesian targets and the stops'.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// Row (target_id) of the largest position difference.
    pub target_id: i64,
    pub position_mm: f64,
    /// Largest orientation difference over the rows, rad.
    pub angle_rad: f64,
}

/// Beyond these the table's `x_cmd_mm …` were not computed for the program's
/// tool: the same nominal chain in f64 agrees to about 1e-12 mm.
pub const TABLE_POSITION_TOLERANCE_MM: f64 = 1e-6;
pub const TABLE_ANGLE_TOLERANCE_RAD: f64 = 1e-9;

/// How far the `ok` rows' table targets (`x_cmd_mm …`, `qw_cmd …`) are from the
/// stops computed for the program's tools; `None` when within the tolerances.
pub fn table_deviation(commands: &[Command], stops: &[Stop]) -> Option<Deviation> {
    let mut worst: Option<Deviation> = None;
    let mut angle_rad: f64 = 0.0;
    for (command, stop) in commands.iter().filter(|c| c.is_ok()).zip(stops) {
        let position_mm =
            (Vector3::from(command.position_mm) - Vector3::from(stop.target.position_mm)).norm();
        let [w, x, y, z] = command.quaternion_wxyz;
        let table = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        let [w, x, y, z] = stop.target.quaternion_wxyz;
        let ours = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        angle_rad = angle_rad.max(table.angle_to(&ours));
        if worst.is_none_or(|w| position_mm > w.position_mm) {
            worst = Some(Deviation {
                target_id: command.target_id,
                position_mm,
                angle_rad: 0.0,
            });
        }
    }
    worst.map(|w| Deviation { angle_rad, ..w }).filter(|w| {
        w.position_mm > TABLE_POSITION_TOLERANCE_MM || w.angle_rad > TABLE_ANGLE_TOLERANCE_RAD
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::frame::rot_x;
    use crate::robot::test_support::irb1600;

    fn command(target_id: i64, q_deg: [f64; MAX_JOINTS]) -> Command {
        Command {
            target_id,
            q_deg,
            status: super::super::STATUS_OK.into(),
            residual_mm: 0.0,
            correction_mm: 0.0,
            elastic_mm: 0.0,
            position_mm: [0.0; 3],
            quaternion_wxyz: [1.0, 0.0, 0.0, 0.0],
            tool_id: None,
            envelope_distance: None,
            u95_mm: None,
            approach: [0; MAX_JOINTS],
            track_mm: None,
            positioner_deg: None,
        }
    }

    fn tool() -> ProgramTool {
        ProgramTool {
            target_id: None,
            source: "test".into(),
            flange_from_tool: Frame {
                rotation: rot_x(0.3),
                origin_mm: Vector3::new(22.0, 50.0, 150.0),
            },
        }
    }

    #[test]
    fn approach_points_lie_back_along_the_tool_axis_on_the_same_branch() {
        let robot = irb1600();
        let q = [10.0, 20.0, -10.0, 30.0, 40.0, 50.0];
        let stops = stops(
            &robot,
            &[command(1, crate::robot::joint_array(&q))],
            &[tool()],
            &[0],
            Some(50.0),
            None,
        )
        .unwrap();
        let stop = &stops[0];
        let approach = stop.approach.unwrap();
        let target = tool_in_base(&robot, &tool(), &crate::robot::joint_array(&q));
        let back = Vector3::from(approach.position_mm) - target.origin_mm;
        // 50 mm along the tool's −z.
        assert!((back + target.axis(2) * 50.0).norm() < 1e-9, "{back}");
        assert_eq!(approach.quaternion_wxyz, stop.target.quaternion_wxyz);
        // The approach configuration puts the tool there and stays near q.
        let at = tool_in_base(&robot, &tool(), &approach.q_deg);
        assert!((at.origin_mm - Vector3::from(approach.position_mm)).norm() < 1e-6);
        assert!(
            approach
                .q_deg
                .iter()
                .zip(q)
                .all(|(a, b)| (a - b).abs() < 10.0)
        );
    }

    #[test]
    fn a_command_with_directions_is_reached_from_below_them_within_the_limits() {
        let robot = irb1600();
        let row = Command {
            approach: [1, -1, 0, 1, 1, -1, 0],
            ..command(4, [10.0, 20.0, -30.0, 40.0, 50.0, 60.0, 0.0])
        };
        let stop = &stops(
            &robot,
            std::slice::from_ref(&row),
            &[tool()],
            &[0],
            None,
            Some(0.5),
        )
        .unwrap()[0];
        assert_eq!(
            stop.pre_position_q_deg,
            Some([9.5, 20.5, -30.0, 39.5, 49.5, 60.5, 0.0])
        );
        // Without pre-positioning, or without a direction, none.
        let plain = stops(
            &robot,
            std::slice::from_ref(&row),
            &[tool()],
            &[0],
            None,
            None,
        )
        .unwrap();
        assert_eq!(plain[0].pre_position_q_deg, None);
        let undirected = stops(
            &robot,
            &[command(4, row.q_deg)],
            &[tool()],
            &[0],
            None,
            Some(0.5),
        );
        assert_eq!(undirected.unwrap()[0].pre_position_q_deg, None);
        // A pre-position beyond a joint limit is refused, naming row and joint.
        let [lower, _] = robot.joint_limits(1);
        let at_limit = Command {
            q_deg: [10.0, lower + 0.2, -30.0, 40.0, 50.0, 60.0, 0.0],
            approach: [0, 1, 0, 0, 0, 0, 0],
            ..row.clone()
        };
        let err = stops(&robot, &[at_limit], &[tool()], &[0], None, Some(0.5)).unwrap_err();
        assert!(
            matches!(
                err,
                CartesianError::PrePositionOutsideLimits {
                    target_id: 4,
                    joint: 2,
                    ..
                }
            ),
            "{err}"
        );
        // A linear approach along the tool axis would decide the directions.
        let err = stops(&robot, &[row], &[tool()], &[0], Some(50.0), Some(0.5)).unwrap_err();
        assert!(
            matches!(err, CartesianError::PrePositionWithApproach { .. }),
            "{err}"
        );
    }

    #[test]
    fn an_approach_point_out_of_reach_is_refused_naming_the_target() {
        let robot = irb1600();
        // 5 m back along the tool axis is beyond a 1.45 m arm's reach.
        let err = stops(
            &robot,
            &[command(7, [0.0, 0.0, -90.0, 0.0, 30.0, 0.0, 0.0])],
            &[tool()],
            &[0],
            Some(5000.0),
            None,
        )
        .unwrap_err();
        assert!(err.to_string().contains("target_id 7"), "{err}");
    }

    #[test]
    fn the_table_deviation_finds_another_tool() {
        let robot = irb1600();
        let q = [10.0, 20.0, -10.0, 30.0, 40.0, 50.0];
        let mut row = command(3, crate::robot::joint_array(&q));
        let stops = stops(
            &robot,
            std::slice::from_ref(&row),
            &[tool()],
            &[0],
            None,
            None,
        )
        .unwrap();
        row.position_mm = stops[0].target.position_mm;
        row.quaternion_wxyz = stops[0].target.quaternion_wxyz;
        assert_eq!(table_deviation(std::slice::from_ref(&row), &stops), None);
        row.position_mm[2] += 1.5;
        let d = table_deviation(std::slice::from_ref(&row), &stops).unwrap();
        assert_eq!(d.target_id, 3);
        assert!((d.position_mm - 1.5).abs() < 1e-9);
    }
}
