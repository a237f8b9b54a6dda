//! The moves of a program as a list, for the formats whose positions are
//! numbered data rather than named declarations (FANUC TP's `P[n]`, Yaskawa
//! INFORM's `Cnnnnn`): each format then only prints positions and motion
//! instructions. Every move ends in an exact stop: these formats' corner
//! settings (FANUC `CNT`, Yaskawa `PL`) are not radii, so the stage refuses a
//! zone for them.
//!
//! The order is the one RAPID and KRL write: the joint path moves to each
//! command (from its pre-position when it carries approach directions); the
//! linear path moves joint-interpolated to its first point, then linearly,
//! through approach, target and retract for drilling, and from the
//! pre-position (a joint move) to a target with approach directions.

use super::cartesian::{Pose, tool_in_base};
use super::{MotionSettings, Program};
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{MAX_JOINTS, Robot};

/// Where a move goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Destination {
    /// A joint configuration (robot-file convention, deg).
    Joints([f64; MAX_JOINTS]),
    /// A pose of the move's tool in the robot base frame.
    Pose(Pose),
}

/// What a move is for, named in the programs' position comments.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The joint configuration each joint reaches the target from (backlash).
    PrePosition,
    /// The point back along the tool's z axis before a drilling target.
    Approach,
    Target,
    /// Back to the approach point after the target.
    Retract,
}

impl Role {
    /// A short word for comments (FANUC position comments hold 16 characters).
    pub fn word(self) -> &'static str {
        match self {
            Role::PrePosition => "pre",
            Role::Approach => "approach",
            Role::Target => "target",
            Role::Retract => "retract",
        }
    }
}

/// One motion instruction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Move {
    pub target_id: i64,
    /// Index into the program's tools.
    pub tool: usize,
    pub role: Role,
    /// Linear (FANUC `L`, Yaskawa `MOVL`) rather than joint-interpolated.
    pub linear: bool,
    pub destination: Destination,
    /// The track's carriage position (mm), the first external axis; `None`
    /// without a track.
    pub track_mm: Option<f64>,
    /// The positioner's axis values (deg); `None` when the program does not
    /// move it.
    pub positioner_deg: Option<[f64; MAX_POSITIONER_AXES]>,
}

/// The joint path: joint moves to every `ok` row's command.
pub fn joint_path(program: &Program) -> Vec<Move> {
    let mut moves = Vec::new();
    for stop in &program.stops {
        let joint_move = |role, q_deg| Move {
            target_id: stop.target_id,
            tool: stop.tool,
            role,
            linear: false,
            destination: Destination::Joints(q_deg),
            track_mm: stop.track_mm,
            positioner_deg: stop.positioner_deg,
        };
        if let Some(q) = stop.pre_position_q_deg {
            moves.push(joint_move(Role::PrePosition, q));
        }
        moves.push(joint_move(Role::Target, stop.target.q_deg));
    }
    moves
}

/// The linear path: Cartesian moves to every `ok` row's target.
pub fn linear_path(program: &Program) -> Vec<Move> {
    let mut moves = Vec::new();
    for (k, stop) in program.stops.iter().enumerate() {
        let to = |role, linear, destination| Move {
            target_id: stop.target_id,
            tool: stop.tool,
            role,
            linear,
            destination,
            track_mm: stop.track_mm,
            positioner_deg: stop.positioner_deg,
        };
        // The first move of the path is joint-interpolated: where the robot
        // starts is unknown.
        let first_linear = k > 0;
        if let Some(q) = stop.pre_position_q_deg {
            moves.push(to(Role::PrePosition, false, Destination::Joints(q)));
            moves.push(to(Role::Target, true, Destination::Pose(stop.target)));
            continue;
        }
        match &stop.approach {
            None => moves.push(to(
                Role::Target,
                first_linear,
                Destination::Pose(stop.target),
            )),
            Some(approach) => {
                moves.push(to(
                    Role::Approach,
                    first_linear,
                    Destination::Pose(*approach),
                ));
                moves.push(to(Role::Target, true, Destination::Pose(stop.target)));
                moves.push(to(Role::Retract, true, Destination::Pose(*approach)));
            }
        }
    }
    moves
}

/// The moves `motion` asks for: the joint path, then the linear path.
pub fn program_moves(program: &Program, motion: &MotionSettings) -> Vec<Move> {
    let mut moves = Vec::new();
    if motion.motions.joint {
        moves.extend(joint_path(program));
    }
    if motion.motions.linear {
        moves.extend(linear_path(program));
    }
    moves
}

/// How far the tool moves, at most over the joint moves of `moves`, when
/// each joint command is replaced by what the file prints and the
/// controller reads back (`printed`: robot-file degrees to robot-file
/// degrees), on the nominal arm, mm. Why: FANUC prints joints to 0.001° and
/// Yaskawa counts whole pulses, which at a 1.5 m reach is a few µm, and the
/// header says how many.
pub fn largest_rounding_mm(
    robot: &Robot,
    program: &Program,
    moves: &[Move],
    printed: impl Fn(&[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS],
) -> f64 {
    moves
        .iter()
        .filter_map(|m| match &m.destination {
            Destination::Joints(q) => Some((m.tool, q)),
            Destination::Pose(_) => None,
        })
        .map(|(tool, q)| {
            let tool = &program.tools[tool];
            let exact = tool_in_base(robot, tool, q).origin_mm;
            let read_back = tool_in_base(robot, tool, &printed(q)).origin_mm;
            (exact - read_back).norm()
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_support;
    use crate::robot::test_support::irb1600;

    fn summary(moves: &[Move]) -> Vec<(i64, Role, bool, bool)> {
        moves
            .iter()
            .map(|m| {
                (
                    m.target_id,
                    m.role,
                    m.linear,
                    matches!(m.destination, Destination::Joints(_)),
                )
            })
            .collect()
    }

    #[test]
    fn drilling_targets_are_approached_and_left_linearly() {
        let robot = irb1600();
        let program = test_support::program(&robot, &[1, 2], Some(20.0), None);
        let moves = program_moves(&program, &test_support::motion(None, Some(20.0)));
        assert_eq!(
            summary(&moves),
            [
                (1, Role::Target, false, true),
                (2, Role::Target, false, true),
                (1, Role::Approach, false, false),
                (1, Role::Target, true, false),
                (1, Role::Retract, true, false),
                (2, Role::Approach, true, false),
                (2, Role::Target, true, false),
                (2, Role::Retract, true, false),
            ]
        );
    }

    #[test]
    fn a_pre_positioned_target_is_reached_from_its_pre_position() {
        let robot = irb1600();
        let mut program = test_support::program(&robot, &[3], None, None);
        let pre = [9.0, 21.0, -30.0, 40.0, 50.0, 60.0];
        program.stops[0].pre_position_q_deg = Some(crate::robot::joint_array(&pre));
        let moves = program_moves(&program, &test_support::motion(None, None));
        assert_eq!(
            summary(&moves),
            [
                (3, Role::PrePosition, false, true),
                (3, Role::Target, false, true),
                (3, Role::PrePosition, false, true),
                (3, Role::Target, true, false),
            ]
        );
        assert_eq!(
            moves[0].destination,
            Destination::Joints(crate::robot::joint_array(&pre))
        );
    }
}
