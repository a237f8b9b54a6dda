//! Yaskawa Motoman INFORM job (`<name>.jbi`, the job data format of the NX,
//! DX and YRC controllers' "offline teaching" interface): `/JOB`, `//NAME`,
//! `//POS` with one `Cnnnnn` per move, `//INST` with `MOVJ`/`MOVL`, `END`.
//!
//! Positions: joint moves go to pulse data (`///POSTYPE PULSE`: each axis's
//! controller angle times the robot file's `joints[i].pulses_per_deg`,
//! rounded to whole pulses; without pulse ratios the stage refuses joint
//! moves for this format); Cartesian moves go to rectangular data in the
//! robot coordinate system (`///POSTYPE ROBOT`, `///RECTAN`): X, Y, Z (mm,
//! 3 decimals) and Rx, Ry, Rz (deg, 4 decimals, fixed angles about x, y, z:
//! `R = Rot(z, Rz)·Rot(y, Ry)·Rot(x, Rx)`) with `///RCONF l,m,n,o,p,q,0,0`
//! on the NOMINAL arm at the joint command:
//!
//! * l: 0 flip (B > 0), 1 no-flip;
//! * m: 0 upper arm (the elbow on the side of the line from L to the wrist
//!   where it is at the robot file's zero), 1 lower arm;
//! * n: 0 front (wrist centre in front of S's axis), 1 rear;
//! * o, p, q: 1 when |R|, |T|, |S| ≥ 180°.
//!
//! Frames: a job cannot write a tool file. `///TOOL t` selects tool file
//! `t`, and the job's comments give the values it must hold; Cartesian
//! moves therefore carry a warning in the job, and the rows must use one
//! tool. The robot coordinate system must be the robot file's base.
//!
//! Every move ends in `PL=0` (positioning): `PL` levels are not radii, so
//! the stage refuses a zone for this format.
//!
//! A robot on a linear track moves its carriage as the base axis (`///GROUP1
//! RB1,BS1`): one `BCnnnnn` beside each `Cnnnnn`, in pulses of the robot
//! file's `[track] pulses_per_mm` (required then), named in each move
//! (`MOVJ C00000 BC00000 …`); the Cartesian positions stay in the robot
//! coordinate system riding on the carriage.
//!
//! A positioner is the job's station (`///GROUP1 RB1,ST1`, or
//! `RB1,BS1,ST1` on a track): one `ECnnnnn` beside each `Cnnnnn`, in pulses
//! of each axis's `positioner.axes[k].pulses_per_deg` (required then), named
//! in each move (`MOVL C00001 EC00001 …`).

use super::moves::{self, Destination, Move};
use super::{
    MASS_DECIMALS, MotionSettings, PROGRAM_JOINTS, Program, fixed, header_lines,
    narrow_comment_lines, positioner_lines, rotation_from_quaternion, skipped_lines, tool_lines,
    tool_names, track_lines, warning_lines, wrist_placement, zyx_angles,
};
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{MAX_JOINTS, Robot};

/// Longest job name (DX100 and later).
pub const MAX_NAME_LEN: usize = 32;
/// Width of a comment (`'`) the pendant shows whole.
const COMMENT_WIDTH: usize = 32;
/// Decimals of rectangular positions (mm) and of angles (deg).
const POSITION_DECIMALS: usize = 3;
const ANGLE_DECIMALS: usize = 4;

/// Why a job cannot be written.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum JobError {
    #[error(
        "joint moves in a Yaskawa job (the joint path, and the pre-positions before commands with approach directions) are pulse data, and the robot file gives no `joints[{joint}].pulses_per_deg` (the controller's pulse ratio of that axis); add them, or set `motion = \"linear\"` (with `pre_position_deg = 0` for commands with approach directions)"
    )]
    NoPulseRatio { joint: usize },
    #[error(
        "the rows use {tools} tools, and a Yaskawa job cannot set a tool file: Cartesian moves take one tool; export each target's rows separately, or use joint moves"
    )]
    SeveralTools { tools: usize },
    #[error(
        "the robot rides a track, which a Yaskawa job moves as its base axis in pulses (`BCnnnnn`), and the robot file's [track] gives no `pulses_per_mm` (the controller's pulse ratio of the base axis); add it"
    )]
    NoTrackPulseRatio,
    #[error(
        "the commands move the positioner, which a Yaskawa job moves as its station axes in pulses (`ECnnnnn`), and the robot file's `positioner.axes[{axis}].pulses_per_deg` (the controller's pulse ratio of that axis) is missing; add it"
    )]
    NoStationPulseRatio { axis: usize },
}

/// The manipulator type of a Cartesian position (`RCONF`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rconf {
    pub flip: bool,
    pub upper_arm: bool,
    pub front: bool,
    /// |R|, |T|, |S| ≥ 180°.
    pub r_beyond_180: bool,
    pub t_beyond_180: bool,
    pub s_beyond_180: bool,
}

impl Rconf {
    /// `l,m,n,o,p,q,0,0`.
    pub fn text(&self) -> String {
        let bit = |b: bool| u8::from(b).to_string();
        [
            bit(!self.flip),
            bit(!self.upper_arm),
            bit(!self.front),
            bit(self.r_beyond_180),
            bit(self.t_beyond_180),
            bit(self.s_beyond_180),
            "0".into(),
            "0".into(),
        ]
        .join(",")
    }
}

/// The manipulator type of the robot-file command `q_deg` on `robot`'s
/// nominal arm.
pub fn rconf(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> Rconf {
    let wrist = wrist_placement(robot, q_deg);
    let at_zero = wrist_placement(robot, &[0.0; MAX_JOINTS]).elbow_mm2;
    let controller = robot.spec().controller_joints_deg(q_deg);
    Rconf {
        flip: controller[4] > 0.0,
        upper_arm: wrist.elbow_mm2 * at_zero.signum() >= 0.0,
        front: wrist.front_of_axis1_mm >= 0.0,
        r_beyond_180: controller[3].abs() >= 180.0,
        t_beyond_180: controller[5].abs() >= 180.0,
        s_beyond_180: controller[0].abs() >= 180.0,
    }
}

/// Rx, Ry, Rz (deg) of a base ← tool quaternion (w, x, y, z).
pub fn rxyz_deg(quaternion_wxyz: [f64; 4]) -> [f64; 3] {
    let [a, b, c] = zyx_angles(&rotation_from_quaternion(quaternion_wxyz)).map(f64::to_degrees);
    [c, b, a]
}

/// The pulse ratios of `robot`'s axes, signed; `None` where the robot file
/// gives none.
fn pulse_ratios(robot: &Robot) -> [Option<f64>; MAX_JOINTS] {
    std::array::from_fn(|j| robot.spec().joints.get(j).and_then(|j| j.pulses_per_deg))
}

/// Pulses of the robot-file command `q_deg`.
pub fn pulses(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> Result<[i64; MAX_JOINTS], JobError> {
    let controller = robot.spec().controller_joints_deg(q_deg);
    let ratios = pulse_ratios(robot);
    let mut out = [0; MAX_JOINTS];
    for j in 0..robot.joint_count() {
        let ratio = ratios[j].ok_or(JobError::NoPulseRatio { joint: j })?;
        out[j] = (controller[j] * ratio).round() as i64;
    }
    Ok(out)
}

/// A robot-file command as pulses read back, robot-file degrees.
fn read_back(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
    let ratios = pulse_ratios(robot);
    match pulses(robot, q_deg) {
        Ok(p) => robot
            .spec()
            .robot_file_joints_deg(&std::array::from_fn(|j| {
                p[j] as f64 / ratios[j].unwrap_or(1.0)
            })),
        Err(_) => *q_deg,
    }
}

/// Base-axis pulses of the carriage position `track_mm`.
fn track_pulses(robot: &Robot, track_mm: f64) -> Result<i64, JobError> {
    let ratio = robot
        .spec()
        .track
        .and_then(|t| t.pulses_per_mm)
        .ok_or(JobError::NoTrackPulseRatio)?;
    Ok((track_mm * ratio).round() as i64)
}

/// Station-axis pulses of the positioner's axis values `p_deg`.
fn station_pulses(robot: &Robot, p_deg: &[f64; MAX_POSITIONER_AXES]) -> Result<Vec<i64>, JobError> {
    let axes = robot
        .spec()
        .positioner
        .as_ref()
        .map_or(&[][..], |p| &p.axes[..]);
    axes.iter()
        .zip(p_deg)
        .enumerate()
        .map(|(axis, (spec, value))| {
            let ratio = spec
                .pulses_per_deg
                .ok_or(JobError::NoStationPulseRatio { axis })?;
            Ok((value * ratio).round() as i64)
        })
        .collect()
}

/// The `//POS` line of position `index`.
fn position(robot: &Robot, index: usize, step: &Move) -> Result<String, JobError> {
    Ok(match &step.destination {
        Destination::Joints(q) => {
            let p = pulses(robot, q)?[..PROGRAM_JOINTS]
                .iter()
                .map(i64::to_string)
                .collect::<Vec<_>>()
                .join(",");
            format!("C{index:05}={p}")
        }
        Destination::Pose(pose) => {
            let [x, y, z] = pose.position_mm.map(|v| fixed(v, POSITION_DECIMALS));
            let [rx, ry, rz] = rxyz_deg(pose.quaternion_wxyz).map(|v| fixed(v, ANGLE_DECIMALS));
            format!("C{index:05}={x},{y},{z},{rx},{ry},{rz}")
        }
    })
}

/// The whole `.jbi` text; `tool_file` is the tool number `///TOOL` selects.
pub fn job(
    robot: &Robot,
    program: &Program,
    motion: &MotionSettings,
    tool_file: u32,
) -> Result<String, JobError> {
    let steps = moves::program_moves(program, motion);
    let cartesian = steps
        .iter()
        .any(|s| matches!(s.destination, Destination::Pose(_)));
    if cartesian && program.tools.len() > 1 {
        return Err(JobError::SeveralTools {
            tools: program.tools.len(),
        });
    }
    let joint_moves = steps
        .iter()
        .any(|s| matches!(s.destination, Destination::Joints(_)));
    let rounding = if joint_moves {
        let rounding_mm =
            moves::largest_rounding_mm(robot, program, &steps, |q| read_back(robot, q));
        format!(
            ", joints in whole pulses, which move the tool by at most {} mm at these commands on the nominal arm",
            fixed(rounding_mm, 4)
        )
    } else {
        String::new()
    };
    let mut remarks: Vec<String> = header_lines(
        &program.provenance,
        "Yaskawa INFORM job",
        format!(
            "Printed precision: positions {POSITION_DECIMALS} decimals (mm), angles {ANGLE_DECIMALS} decimals (deg){rounding}."
        ),
    );
    remarks.extend(tool_lines(
        program,
        &tool_names("tool", program.tools.len()),
    ));
    if cartesian {
        let tool = &program.tools[0];
        let [x, y, z] = tool.tcp_mm().map(|v| fixed(v, POSITION_DECIMALS));
        let [rx, ry, rz] = rxyz_deg(tool.quaternion_wxyz()).map(|v| fixed(v, ANGLE_DECIMALS));
        remarks.push(format!(
            "WARNING: a job cannot set a tool file. Tool file {tool_file} must hold X {x}, Y {y}, Z {z} mm, Rx {rx}, Ry {ry}, Rz {rz} deg before the Cartesian moves run."
        ));
        remarks.push(
            "Cartesian positions are in the robot coordinate system, which must be the robot file's base frame.".into(),
        );
    }
    if robot.spec().controller.j3_from_j2 != 0.0 {
        remarks.push(format!(
            "U is the controller's: q3 + {} * q2 of the robot file.",
            robot.spec().controller.j3_from_j2
        ));
    }
    remarks.push(match &program.payload {
        Some(payload) => format!(
            "Load: set the tool file's load to the robot file's payload, {} kg, before running.",
            fixed(payload.mass_kg, MASS_DECIMALS)
        ),
        None => "WARNING: the robot file gives no payload mass; set the real tool's load in the tool file before running.".into(),
    });
    // A track is the robot's base axis: one `BCnnnnn` (pulses) beside each
    // `Cnnnnn`, moved together.
    let base_axis: Option<Vec<i64>> = if steps.iter().any(|s| s.track_mm.is_some()) {
        Some(
            steps
                .iter()
                .map(|s| track_pulses(robot, s.track_mm.unwrap_or(0.0)))
                .collect::<Result<_, _>>()?,
        )
    } else {
        None
    };
    remarks.extend(track_lines(program, "the base axis BS1 (BC data, pulses)"));
    if let Some(ratio) = robot.spec().track.and_then(|t| t.pulses_per_mm)
        && base_axis.is_some()
    {
        remarks.push(format!(
            "Base axis: {ratio} pulses/mm; whole pulses place the carriage within {} mm.",
            fixed(0.5 / ratio.abs(), 4)
        ));
    }
    // A positioner is the station: one `ECnnnnn` (pulses) beside each
    // `Cnnnnn`, in the job's control group.
    let station: Option<Vec<Vec<i64>>> = steps
        .iter()
        .map(|s| s.positioner_deg.map(|p| station_pulses(robot, &p)))
        .collect::<Option<Result<_, _>>>()
        .transpose()?;
    remarks.extend(positioner_lines(
        program,
        "the station ST1's (EC data, in pulses)",
    ));
    if station.is_some() {
        remarks.push(
            "The job's control group must be the robot with its station (and base axis): R1+S1 or R1+B1+S1."
                .into(),
        );
        for (k, axis) in robot
            .spec()
            .positioner
            .iter()
            .flat_map(|p| &p.axes)
            .enumerate()
        {
            if let Some(ratio) = axis.pulses_per_deg {
                remarks.push(format!(
                    "Station axis {}: {ratio} pulses/deg; whole pulses place it within {} deg.",
                    k + 1,
                    fixed(0.5 / ratio.abs(), 6)
                ));
            }
        }
    }
    remarks.extend(warning_lines(program));
    remarks.extend(skipped_lines(&program.commands));

    let base_count = base_axis.as_ref().map_or(0, Vec::len);
    let station_count = station.as_ref().map_or(0, Vec::len);
    let mut out = format!(
        "/JOB\n//NAME {}\n//POS\n///NPOS {},{base_count},{station_count},0,0,0\n///TOOL {tool_file}\n",
        motion.name,
        steps.len()
    );
    let mut current_type: Option<bool> = None;
    for (k, step) in steps.iter().enumerate() {
        let joints = matches!(step.destination, Destination::Joints(_));
        if current_type != Some(joints) {
            out.push_str(if joints {
                "///POSTYPE PULSE\n///PULSE\n"
            } else {
                "///POSTYPE ROBOT\n///RECTAN\n"
            });
            current_type = Some(joints);
        }
        if let Destination::Pose(pose) = &step.destination {
            out.push_str(&format!("///RCONF {}\n", rconf(robot, &pose.q_deg).text()));
        }
        out.push_str(&position(robot, k, step)?);
        out.push('\n');
    }
    if let Some(base_axis) = &base_axis {
        if current_type != Some(true) {
            out.push_str("///POSTYPE PULSE\n///PULSE\n");
        }
        for (k, pulses) in base_axis.iter().enumerate() {
            out.push_str(&format!("BC{k:05}={pulses}\n"));
        }
        current_type = Some(true);
    }
    if let Some(station) = &station {
        if current_type != Some(true) {
            out.push_str("///POSTYPE PULSE\n///PULSE\n");
        }
        for (k, pulses) in station.iter().enumerate() {
            let pulses: Vec<String> = pulses.iter().map(i64::to_string).collect();
            out.push_str(&format!("EC{k:05}={}\n", pulses.join(",")));
        }
    }
    let group = match (base_axis.is_some(), station.is_some()) {
        (false, false) => "RB1",
        (true, false) => "RB1,BS1",
        (false, true) => "RB1,ST1",
        (true, true) => "RB1,BS1,ST1",
    };
    out.push_str(&format!("//INST\n///ATTR SC,RW\n///GROUP1 {group}\nNOP\n"));
    for text in narrow_comment_lines(&remarks, COMMENT_WIDTH, &[]) {
        out.push_str(&format!("'{text}\n"));
    }
    let joint_speed = fixed(motion.joint_speed_percent, 2);
    let linear_speed = fixed(motion.speed_mm_s, 1);
    for (k, step) in steps.iter().enumerate() {
        let mut base = if base_axis.is_some() {
            format!(" BC{k:05}")
        } else {
            String::new()
        };
        if station.is_some() {
            base.push_str(&format!(" EC{k:05}"));
        }
        out.push_str(&if step.linear {
            format!("MOVL C{k:05}{base} V={linear_speed} PL=0\n")
        } else {
            format!("MOVJ C{k:05}{base} VJ={joint_speed} PL=0\n")
        });
    }
    out.push_str("END\n");
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_support;
    use crate::robot::test_support::irb1600;

    #[test]
    fn rconf_on_fixed_commands() {
        let robot = irb1600();
        // Zero pose, wrist bent down: no-flip, upper arm, front.
        assert_eq!(
            rconf(&robot, &[0.0, 0.0, 0.0, 0.0, -90.0, 0.0, 0.0]).text(),
            "1,0,0,0,0,0,0,0"
        );
        assert_eq!(
            rconf(&robot, &[-190.0, 0.0, 0.0, 190.0, 30.0, -200.0, 0.0]).text(),
            "0,0,0,1,1,1,0,0"
        );
    }

    #[test]
    fn joint_moves_need_pulse_ratios() {
        let robot = irb1600();
        let program = test_support::program(&robot, &[1], None, None);
        let mut motion = test_support::motion(None, None);
        motion.motions.linear = false;
        assert_eq!(
            job(&robot, &program, &motion, 1).unwrap_err(),
            JobError::NoPulseRatio { joint: 0 }
        );
        // Cartesian moves alone need none.
        motion.motions = super::super::Motions {
            joint: false,
            linear: true,
        };
        let text = job(&robot, &program, &motion, 1).unwrap();
        assert!(
            text.contains("///POSTYPE ROBOT\n///RECTAN\n///RCONF "),
            "{text}"
        );
        assert!(text.contains("MOVJ C00000 VJ=20.00 PL=0\n"), "{text}");
        assert!(text.contains("///NPOS 1,0,0,0,0,0\n"));
        assert!(
            text.lines()
                .filter(|l| l.starts_with('\''))
                .all(|l| l.len() <= 33)
        );
    }
}
