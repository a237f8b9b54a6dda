//! FANUC TP program in its ASCII form (`<name>.ls`, compiled to `.tp` by
//! FANUC's offline tools or loaded by controllers with the ASCII upload
//! option): `/PROG`, `/ATTR`, `/MN` with the motion instructions, `/POS`
//! with one `P[n]` per move, `/END`.
//!
//! Positions: joint moves go to joint-form positions (`J1= … deg`, the
//! controller's joint values: with `[controller] j3_from_j2` in the robot
//! file, FANUC's J3 measured from the horizontal); Cartesian moves go to
//! `X, Y, Z` (mm) and `W, P, R` (deg, fixed angles about x, y, z:
//! `R = Rot(z, R)·Rot(y, P)·Rot(x, W)`) with the configuration string
//! `'F|N U|D T|B, t4, t5, t6'`, computed on the NOMINAL arm at the joint
//! command:
//!
//! * F (flip) when J5 > 0, else N;
//! * U (up) when the elbow is on the side of the line from joint 2 to the
//!   wrist centre where it is at the robot file's zero (upper arm up,
//!   forearm forward), else D;
//! * T (front) when the wrist centre is in front of J1's axis, else B;
//! * t4, t5, t6: turn numbers of J4, J5, J6, 0 for (−180°, 180°], 1 for
//!   (180°, 540°], −1 for (−540°, −180°].
//!
//! Printed precision is FANUC's own: 3 decimals (0.001°, 0.001 mm); the
//! header states what the joints' rounding moves the tool at these commands.
//!
//! Frames: the program declares its tool rather than assuming what a tool
//! frame holds: it writes the tool into a position register (`PR[r]`, made
//! Cartesian by `LPOS-LPOS`) and copies it to `UTOOL[t]`, again whenever the
//! tool changes; the positions are in `UFRAME_NUM=0`, the world frame, which
//! must be the robot file's base. The payload cannot be set from a TP
//! program: the header names the schedule's values to select.
//!
//! A positioner is motion group 2 (`DEFAULT_GROUP = 1,1,*,*,*`): each
//! position carries `GP2:` with its axes as `J1`, `J2` in deg, so every move
//! moves the table with the arm.
//!
//! Every move ends in `FINE`: FANUC's `CNT` is not a radius, so the stage
//! refuses a zone for this format.

use super::moves::{self, Destination, Move};
use super::{
    MASS_DECIMALS, MotionSettings, Program, fixed, header_lines, narrow_comment_lines,
    positioner_axis_count, positioner_lines, rotation_from_quaternion, skipped_lines, tool_lines,
    tool_names, track_lines, warning_lines, wrist_placement, zyx_angles,
};
use crate::robot::{MAX_JOINTS, Robot};

/// Longest program name (R-30iB and later).
pub const MAX_NAME_LEN: usize = 36;
/// Decimals FANUC prints positions with (deg and mm).
pub const DECIMALS: usize = 3;
/// Width of a remark the pendant shows whole.
const COMMENT_WIDTH: usize = 32;
/// Longest position comment (`P[n:"…"]`).
const POSITION_COMMENT_LEN: usize = 16;

/// The tool frame and position register the program overwrites to declare
/// its tool.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FanucFrames {
    /// `UTOOL[n]`, 1 … 10.
    pub user_tool: u32,
    /// `PR[n]` the tool is built in, 1 … 100 (the registers every controller has).
    pub position_register: u32,
}

/// FANUC's configuration of a joint command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Configuration {
    pub flip: bool,
    pub up: bool,
    pub front: bool,
    /// Turn numbers of J4, J5, J6.
    pub turns: [i64; 3],
}

impl Configuration {
    /// The `CONFIG` string's value: `N U T, 0, 0, 0`.
    pub fn text(&self) -> String {
        format!(
            "{} {} {}, {}, {}, {}",
            if self.flip { 'F' } else { 'N' },
            if self.up { 'U' } else { 'D' },
            if self.front { 'T' } else { 'B' },
            self.turns[0],
            self.turns[1],
            self.turns[2]
        )
    }
}

/// FANUC's turn number of an axis angle: 0 for (−180°, 180°], ±1 per turn
/// beyond.
pub fn turn_number(q_deg: f64) -> i64 {
    ((q_deg - 180.0) / 360.0).ceil() as i64
}

/// The configuration of the robot-file command `q_deg` on `robot`'s nominal
/// arm (turn numbers from the controller's joint values).
pub fn configuration(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> Configuration {
    let wrist = wrist_placement(robot, q_deg);
    let at_zero = wrist_placement(robot, &[0.0; MAX_JOINTS]).elbow_mm2;
    let controller = robot.spec().controller_joints_deg(q_deg);
    Configuration {
        flip: controller[4] > 0.0,
        up: wrist.elbow_mm2 * at_zero.signum() >= 0.0,
        front: wrist.front_of_axis1_mm >= 0.0,
        turns: [3, 4, 5].map(|j| turn_number(controller[j])),
    }
}

/// W, P, R (deg) of a base ← tool quaternion (w, x, y, z).
pub fn wpr_deg(quaternion_wxyz: [f64; 4]) -> [f64; 3] {
    let [a, b, c] = zyx_angles(&rotation_from_quaternion(quaternion_wxyz)).map(f64::to_degrees);
    [c, b, a]
}

/// A robot-file command as printed and read back: the controller's joint
/// values rounded to [`DECIMALS`], in robot-file degrees.
pub fn read_back(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
    let scale = 10f64.powi(DECIMALS as i32);
    let printed = robot
        .spec()
        .controller_joints_deg(q_deg)
        .map(|v| (v * scale).round() / scale);
    robot.spec().robot_file_joints_deg(&printed)
}

/// The `/POS` entry of position `index` for `step`.
fn position(robot: &Robot, index: usize, step: &Move, frames: &FanucFrames) -> String {
    let comment = format!("{} {}", step.role.word(), step.target_id);
    let label = if comment.len() <= POSITION_COMMENT_LEN {
        format!("P[{index}:\"{comment}\"]")
    } else {
        format!("P[{index}]")
    };
    let frame_line = format!("\tUF : 0, UT : {},", frames.user_tool);
    let body = match &step.destination {
        Destination::Joints(q) => {
            let j = robot
                .spec()
                .controller_joints_deg(q)
                .map(|v| fixed(v, DECIMALS));
            format!(
                "{frame_line}\n\tJ1= {} deg,\tJ2= {} deg,\tJ3= {} deg,\n\tJ4= {} deg,\tJ5= {} deg,\tJ6= {} deg",
                j[0], j[1], j[2], j[3], j[4], j[5]
            )
        }
        Destination::Pose(pose) => {
            let [x, y, z] = pose.position_mm.map(|v| fixed(v, DECIMALS));
            let [w, p, r] = wpr_deg(pose.quaternion_wxyz).map(|v| fixed(v, DECIMALS));
            format!(
                "{frame_line}\t\tCONFIG : '{}',\n\tX = {x}  mm,\tY = {y}  mm,\tZ = {z}  mm,\n\tW = {w} deg,\tP = {p} deg,\tR = {r} deg",
                configuration(robot, &pose.q_deg).text()
            )
        }
    };
    // The track: group 1's extended axis E1, in mm.
    let track = step
        .track_mm
        .map(|e| format!(",\n\tE1= {}  mm", fixed(e, DECIMALS)))
        .unwrap_or_default();
    // The positioner: motion group 2's joints J1, J2 in deg.
    let positioner = step
        .positioner_deg
        .map(|p_deg| {
            let joints: Vec<String> = p_deg[..positioner_axis_count(robot)]
                .iter()
                .enumerate()
                .map(|(k, v)| format!("J{}= {} deg", k + 1, fixed(*v, DECIMALS)))
                .collect();
            format!("\n   GP2:\n{frame_line}\n\t{}", joints.join(",\t"))
        })
        .unwrap_or_default();
    format!("{label}{{\n   GP1:\n{body}{track}{positioner}\n}};\n")
}

/// The lines that put `program`'s tool `tool` into `UTOOL[t]`.
fn tool_assignment(program: &Program, tool: usize, frames: &FanucFrames) -> Vec<String> {
    let declared = &program.tools[tool];
    let [x, y, z] = declared.tcp_mm().map(|v| fixed(v, DECIMALS));
    let [w, p, r] = wpr_deg(declared.quaternion_wxyz()).map(|v| fixed(v, DECIMALS));
    let register = frames.position_register;
    let mut lines = vec![format!("PR[{register}]=LPOS-LPOS")];
    for (element, value) in [x, y, z, w, p, r].iter().enumerate() {
        lines.push(format!("PR[{register},{}]={value}", element + 1));
    }
    lines.push(format!("UTOOL[{}]=PR[{register}]", frames.user_tool));
    lines
}

/// The whole `.ls` text.
pub fn program(
    robot: &Robot,
    program: &Program,
    motion: &MotionSettings,
    frames: &FanucFrames,
) -> String {
    let steps = moves::program_moves(program, motion);
    let rounding_mm = moves::largest_rounding_mm(robot, program, &steps, |q| read_back(robot, q));
    let tools = tool_names("tool", program.tools.len());
    let payload_lines = match &program.payload {
        Some(payload) => vec![format!(
            "Payload: select (PAYLOAD[i]) the schedule of the robot file's payload, {} kg at [{}] mm in the flange frame, before running; this program does not change it.",
            fixed(payload.mass_kg, MASS_DECIMALS),
            payload
                .cog_in_flange_mm(&program.tools[0])
                .map(|v| fixed(v, DECIMALS))
                .join(", ")
        )],
        None => vec![
            "WARNING: the robot file gives no payload mass; select the real tool's payload schedule before running.".into(),
        ],
    };
    let mut remarks: Vec<String> = header_lines(
        &program.provenance,
        "FANUC TP program",
        format!(
            "Printed precision: FANUC's {DECIMALS} decimals (deg, mm); the joints' rounding moves the tool by at most {} mm at these commands on the nominal arm.",
            fixed(rounding_mm, 4)
        ),
    );
    remarks.extend(tool_lines(program, &tools));
    remarks.push(format!(
        "Tools: written to PR[{}] and UTOOL[{}] (both overwritten) before the moves that use them.",
        frames.position_register, frames.user_tool
    ));
    remarks.push(
        "Frame: UFRAME_NUM=0, the world frame, which must be the robot file's base frame.".into(),
    );
    remarks.extend(track_lines(program, "E1 of group 1 (not integrated)"));
    remarks.extend(positioner_lines(
        program,
        &format!(
            "group 2's J1 ... J{} (deg, DEFAULT_GROUP 1,1)",
            positioner_axis_count(robot)
        ),
    ));
    let moves_positioner = program.commands.iter().any(|c| c.positioner_deg.is_some());
    if robot.spec().controller.j3_from_j2 != 0.0 {
        remarks.push(format!(
            "J3 is FANUC's, from the horizontal: J3 = q3 + {} * q2 of the robot file.",
            robot.spec().controller.j3_from_j2
        ));
    }
    remarks.extend(payload_lines);
    remarks.extend(warning_lines(program));
    remarks.extend(skipped_lines(&program.commands));

    let mut main: Vec<String> = narrow_comment_lines(&remarks, COMMENT_WIDTH, &[';'])
        .into_iter()
        .map(|text| format!("  !{text} ;"))
        .collect();
    main.push("  UFRAME_NUM=0 ;".into());
    let mut positions = String::new();
    let mut current_tool = None;
    let joint_speed = format!("{:.0}%", motion.joint_speed_percent.round().max(1.0));
    let linear_speed = format!("{:.0}mm/sec", motion.speed_mm_s.round().max(1.0));
    for (k, step) in steps.iter().enumerate() {
        if current_tool != Some(step.tool) {
            main.extend(
                tool_assignment(program, step.tool, frames)
                    .into_iter()
                    .map(|line| format!("  {line} ;")),
            );
            if current_tool.is_none() {
                main.push(format!("  UTOOL_NUM={} ;", frames.user_tool));
            }
            current_tool = Some(step.tool);
        }
        let index = k + 1;
        main.push(if step.linear {
            format!("L P[{index}] {linear_speed} FINE ;")
        } else {
            format!("J P[{index}] {joint_speed} FINE ;")
        });
        positions.push_str(&position(robot, index, step, frames));
    }

    let mut out = format!("/PROG  {}\n/ATTR\n", motion.name);
    for line in [
        "OWNER\t\t= MNEDITOR;".to_string(),
        "COMMENT\t\t= \"egcal\";".into(),
        "PROG_SIZE\t= 0;".into(),
        "FILE_NAME\t= ;".into(),
        "VERSION\t\t= 0;".into(),
        format!("LINE_COUNT\t= {};", main.len()),
        "MEMORY_SIZE\t= 0;".into(),
        "PROTECT\t\t= READ_WRITE;".into(),
        "TCD:  STACK_SIZE\t= 0,".into(),
        "      TASK_PRIORITY\t= 50,".into(),
        "      TIME_SLICE\t= 0,".into(),
        "      BUSY_LAMP_OFF\t= 0,".into(),
        "      ABORT_REQUEST\t= 0,".into(),
        "      PAUSE_REQUEST\t= 0;".into(),
        if moves_positioner {
            "DEFAULT_GROUP\t= 1,1,*,*,*;".into()
        } else {
            "DEFAULT_GROUP\t= 1,*,*,*,*;".into()
        },
        "CONTROL_CODE\t= 00000000 00000000;".into(),
    ] {
        out.push_str(&line);
        out.push('\n');
    }
    out.push_str("/MN\n");
    for (k, line) in main.iter().enumerate() {
        // Motion lines start with their type right after the colon.
        out.push_str(&format!("{:>4}:{line}\n", k + 1));
    }
    out.push_str("/POS\n");
    out.push_str(&positions);
    out.push_str("/END\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_support;
    use crate::robot::test_support::irb1600;

    #[test]
    fn turn_numbers_follow_fanuc() {
        assert_eq!(turn_number(0.0), 0);
        assert_eq!(turn_number(180.0), 0);
        assert_eq!(turn_number(-179.9), 0);
        assert_eq!(turn_number(180.1), 1);
        assert_eq!(turn_number(540.0), 1);
        assert_eq!(turn_number(-180.1), -1);
        assert_eq!(turn_number(-400.0), -1);
    }

    #[test]
    fn configuration_on_fixed_commands() {
        let robot = irb1600();
        // The zero pose with the wrist bent down: elbow up, in front.
        let c = configuration(&robot, &[0.0, 0.0, 0.0, 0.0, -90.0, 0.0, 0.0]);
        assert_eq!(c.text(), "N U T, 0, 0, 0");
        let c = configuration(&robot, &[0.0, 0.0, 0.0, 190.0, 30.0, -200.0, 0.0]);
        assert_eq!(c.text(), "F U T, 1, 0, -1");
        // Upper arm folded back over the lower arm: wrist behind axis 1, and
        // the elbow on the other side of the line to the wrist.
        let c = configuration(&robot, &[0.0, 0.0, -180.0, 0.0, 30.0, 0.0, 0.0]);
        assert!(!c.front && !c.up, "{c:?}");
    }

    #[test]
    fn wpr_are_fixed_angles_about_x_y_z() {
        // Rot(z, 90°): W = P = 0, R = 90.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let [w, p, r] = wpr_deg([h, 0.0, 0.0, h]);
        assert!(w.abs() < 1e-9 && p.abs() < 1e-9 && (r - 90.0).abs() < 1e-9);
        // Rot(x, 180°): W = 180.
        let [w, p, r] = wpr_deg([0.0, 1.0, 0.0, 0.0]);
        assert!((w.abs() - 180.0).abs() < 1e-9 && p.abs() < 1e-9 && r.abs() < 1e-9);
    }

    #[test]
    fn the_program_declares_its_tool_and_counts_its_lines() {
        let robot = irb1600();
        let program = test_support::program(&robot, &[1, 2], Some(20.0), None);
        let frames = FanucFrames {
            user_tool: 10,
            position_register: 100,
        };
        let text = self::program(
            &robot,
            &program,
            &test_support::motion(None, Some(20.0)),
            &frames,
        );
        let main: Vec<&str> = text
            .split("/MN\n")
            .nth(1)
            .and_then(|rest| rest.split("/POS\n").next())
            .unwrap()
            .lines()
            .collect();
        assert!(text.contains(&format!("LINE_COUNT\t= {};", main.len())));
        let tool_at = main
            .iter()
            .position(|l| l.ends_with("UTOOL[10]=PR[100] ;"))
            .unwrap();
        let first_move = main.iter().position(|l| l.contains(":J P[1]")).unwrap();
        assert!(tool_at < first_move);
        assert!(main.iter().any(|l| l.ends_with("PR[100,1]=22.000 ;")));
        assert!(main.iter().any(|l| l.ends_with("PR[100,3]=150.000 ;")));
        // Two joint moves, then approach, target, retract per target.
        let motions: Vec<&str> = main
            .iter()
            .filter_map(|l| l.split(':').nth(1))
            .filter(|l| l.starts_with('J') || l.starts_with('L'))
            .collect();
        assert_eq!(motions.len(), 8, "{motions:?}");
        assert!(motions[2].starts_with("J P[3]") && motions[3].starts_with("L P[4]"));
        // Remarks are short enough for the pendant.
        assert!(
            main.iter()
                .filter_map(|l| l.split_once(":  !"))
                .all(|(_, remark)| remark.len() <= COMMENT_WIDTH + 2)
        );
        assert!(text.contains("P[8:\"retract 2\"]{"), "{text}");
        assert!(text.ends_with("/END\n"));
    }
}
