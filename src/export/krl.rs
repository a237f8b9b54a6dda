//! KUKA KRL pair: `<name>.dat` declares an `E6AXIS` per joint command and an
//! `E6POS` per corrected Cartesian target; `<name>.src` moves to them (`PTP`
//! E6AXIS; `PTP` E6POS to the first, then `LIN`).
//!
//! A command compensated for approach directions (backlash) is reached from
//! its pre-position (`E6AXIS XB_<id>`): `PTP` there, then to the target with an
//! exact stop (`PTP` E6AXIS on the joint path, `LIN` on the linear one).
//!
//! Conventions (KUKA System Software expert programming, "Status and Turn";
//! the forum and application notes found with it agree on these bits):
//!
//! * A, B, C: Z-Y-X Euler angles in degrees, `R = Rot(z, A)·Rot(y, B)·Rot(x, C)`.
//! * Status S: bit 0 = 1 when the wrist root point's x in the A1 coordinate
//!   system is negative (overhead area); bit 1 = 1 when A3 ≥ φ (φ: the A3 angle
//!   at which the wrist root point lies on the line through A2 and A3), read
//!   geometrically as the wrist centre on the positive side of that line about
//!   A3's axis: KUKA gives φ = 0° only for arms whose axes 3 and 4 intersect
//!   and says it moves with the offset between them, which the geometric test
//!   covers without a table per robot type; bit 2 = 1 when A5 lies in
//!   [−180°, 0°) or at 180° and beyond (KUKA's table; plainly "A5 < 0" within
//!   ±180°).
//!   Bit 4 (point taught with an absolutely accurate robot) stays 0: the
//!   numbers assume the nominal model.
//! * Turn T: bit i−1 = 1 when axis i is negative.
//!
//! Status is computed on the NOMINAL arm at the joint command, like ABB's
//! `confdata`, and assumes the robot file's joint directions are the
//! controller's (they must be, for the E6AXIS values to mean anything).
//!
//! Frames: the `.dat` declares the tool the E6POS are poses of (`XTOOL`, the
//! flange → tool transform) and the robot base (`XBASE`, identity), and the
//! `.src` assigns them to `$TOOL` and `$BASE` (and the robot file's payload to
//! `$LOAD`) before the first move, rather than assuming what `TOOL_DATA` or
//! `$NULLFRAME` hold.
//!
//! External axes are `E1` … in every `E6AXIS` and `E6POS`
//! ([`super::external_axes`]): the track's carriage (mm), then the
//! positioner's axes (deg); unused ones are 0.0.

use super::cartesian::Pose;
use super::{
    EULER_DECIMALS, JOINT_DECIMALS, MASS_DECIMALS, MotionSettings, POSITION_DECIMALS,
    PROGRAM_JOINTS, Payload, Program, ProgramTool, external_axes, fixed, header_lines,
    positioner_axis_count, positioner_lines, printed_precision, rotation_from_quaternion,
    skipped_lines, tool_lines, tool_names, track_lines, warning_lines, wrist_placement, zyx_angles,
};
use crate::robot::{MAX_JOINTS, Robot};

/// Longest KRL name.
pub const MAX_IDENTIFIER_LEN: usize = 24;

/// KUKA's Status of a joint command on `robot`'s nominal geometry.
pub fn status(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> u32 {
    let wrist = wrist_placement(robot, q_deg);
    let overhead = u32::from(wrist.front_of_axis1_mm < 0.0);
    let a3_at_or_past_phi = u32::from(wrist.elbow_mm2 >= 0.0);
    let a5 = q_deg[4];
    let a5_negative = u32::from((-180.0..0.0).contains(&a5) || a5 >= 180.0);
    overhead | (a3_at_or_past_phi << 1) | (a5_negative << 2)
}

/// KUKA's Turn: bit i−1 set when axis i is negative.
pub fn turn(q_deg: &[f64; MAX_JOINTS]) -> u32 {
    q_deg[..PROGRAM_JOINTS]
        .iter()
        .enumerate()
        .filter(|(_, q)| **q < 0.0)
        .map(|(i, _)| 1 << i)
        .sum()
}

/// KUKA's A, B, C (deg) of a base ← tool quaternion (w, x, y, z).
pub fn abc_deg(quaternion_wxyz: [f64; 4]) -> [f64; 3] {
    zyx_angles(&rotation_from_quaternion(quaternion_wxyz)).map(f64::to_degrees)
}

/// Name of a target's data: `<prefix><id>`, `N` for a minus sign.
pub fn data_name(prefix: &str, target_id: i64) -> String {
    if target_id < 0 {
        format!("{prefix}N{}", target_id.unsigned_abs())
    } else {
        format!("{prefix}{target_id}")
    }
}

/// Name of the base frame the `.dat` declares.
pub const BASE_NAME: &str = "XBASE";
/// Name (with `_1` … for several) of the tool frames the `.dat` declares.
pub const TOOL_NAME: &str = "XTOOL";
/// Prefix of the pre-positioning `E6AXIS` data (backlash).
const PRE_POSITION_PREFIX: &str = "XB_";

/// The fields `X ..,Y ..,Z ..,A ..,B ..,C ..` of a position (mm) and a
/// rotation (w, x, y, z), as a `FRAME` and an `E6POS` start.
fn frame_fields(position_mm: [f64; 3], quaternion_wxyz: [f64; 4]) -> String {
    let [x, y, z] = position_mm.map(|v| fixed(v, POSITION_DECIMALS));
    let [a, b, c] = abc_deg(quaternion_wxyz).map(|v| fixed(v, EULER_DECIMALS));
    format!("X {x},Y {y},Z {z},A {a},B {b},C {c}")
}

/// The `$LOAD` value of the robot file's payload on `tool`: mass, centre of
/// gravity in the flange frame, no inertia known.
fn load_value(payload: &Payload, tool: &ProgramTool) -> String {
    let [x, y, z] = payload
        .cog_in_flange_mm(tool)
        .map(|v| fixed(v, POSITION_DECIMALS));
    format!(
        "{{M {},CM {{X {x},Y {y},Z {z},A 0.0,B 0.0,C 0.0}},J {{X 0.0,Y 0.0,Z 0.0}}}}",
        fixed(payload.mass_kg, MASS_DECIMALS)
    )
}

fn header(out: &mut String, robot: &Robot, program: &Program, kind: &str) {
    let tools = tool_names(TOOL_NAME, program.tools.len());
    let load_lines: Vec<String> = match &program.payload {
        Some(payload) => vec![format!(
            "$LOAD: the robot file's payload, {} kg at its centre of gravity, a point mass (no inertia known).",
            fixed(payload.mass_kg, MASS_DECIMALS)
        )],
        None => vec![
            "WARNING: the robot file gives no payload mass, so this program leaves $LOAD as the controller has it.".into(),
            "Set the real tool's load data (or determine them) before running: a wrong load".into(),
            "degrades path accuracy and the collision detection.".into(),
        ],
    };
    for text in header_lines(&program.provenance, kind, printed_precision())
        .iter()
        .chain(&tool_lines(program, &tools))
        .chain(&[
            format!("$BASE = {BASE_NAME}: the robot base frame, identity relative to $WORLD, which must coincide with"),
            "the robot root ($ROBROOT = $WORLD: KUKA's default without a linear unit or other external".into(),
            "kinematics); $IPO_MODE = #BASE: the tool is on the flange.".into(),
        ])
        .chain(&track_lines(program, "E1 ($ROBROOT stays at $WORLD)"))
        .chain(&positioner_lines(program, &{
            let first = 1 + usize::from(robot.spec().track.is_some());
            let names: Vec<String> = (0..positioner_axis_count(robot))
                .map(|k| format!("E{}", first + k))
                .collect();
            format!("{} (deg)", names.join(", "))
        }))
        .chain(&load_lines)
        .chain(&[
            "Status/Turn from the nominal arm at each joint command; Status bit 4 (absolutely accurate) is 0.".into(),
        ])
        .chain(&warning_lines(program))
        .chain(&skipped_lines(&program.commands))
    {
        out.push_str(&format!("; {text}\n"));
    }
}

fn e6pos(robot: &Robot, pose: &Pose, externals: &str) -> String {
    format!(
        "{{{},S {},T {},{externals}}}",
        frame_fields(pose.position_mm, pose.quaternion_wxyz),
        status(robot, &pose.q_deg),
        turn(&pose.q_deg)
    )
}

/// The `.dat` file: the base and tool frames, then one `E6AXIS` and/or `E6POS`
/// (and an approach `E6POS`) per `ok` row.
pub fn dat(robot: &Robot, program: &Program, motion: &MotionSettings) -> String {
    let mut out = format!("DEFDAT {}\n", motion.name);
    header(&mut out, robot, program, "KUKA KRL data list");
    out.push_str(&format!(
        "DECL FRAME {BASE_NAME}={{{}}}\n",
        frame_fields([0.0; 3], [1.0, 0.0, 0.0, 0.0])
    ));
    for (name, tool) in tool_names(TOOL_NAME, program.tools.len())
        .iter()
        .zip(&program.tools)
    {
        out.push_str(&format!(
            "DECL FRAME {name}={{{}}}\n",
            frame_fields(tool.tcp_mm(), tool.quaternion_wxyz())
        ));
    }
    // The controller's joint values (the robot file's `[controller]`).
    let e6axis = |q_deg: &[f64; MAX_JOINTS], externals: &str| {
        let q_deg = robot.spec().controller_joints_deg(q_deg);
        let axes: Vec<String> = (0..PROGRAM_JOINTS)
            .map(|i| format!("A{} {}", i + 1, fixed(q_deg[i], JOINT_DECIMALS)))
            .collect();
        format!("{{{},{externals}}}", axes.join(","))
    };
    for stop in &program.stops {
        // The track (mm) and the positioner (deg) from E1 on; the other
        // external axes are unused.
        let external = external_axes(robot, stop.track_mm, stop.positioner_deg);
        let externals: Vec<String> = (0..6)
            .map(|k| {
                let value = external
                    .get(k)
                    .map_or_else(|| "0.0".to_string(), |v| fixed(*v, POSITION_DECIMALS));
                format!("E{} {value}", k + 1)
            })
            .collect();
        let externals = externals.join(",");
        let externals = externals.as_str();
        if let Some(q) = &stop.pre_position_q_deg {
            out.push_str(&format!(
                "DECL E6AXIS {}={}\n",
                data_name(PRE_POSITION_PREFIX, stop.target_id),
                e6axis(q, externals)
            ));
        }
        if motion.motions.joint {
            out.push_str(&format!(
                "DECL E6AXIS {}={}\n",
                data_name("XJ_", stop.target_id),
                e6axis(&stop.target.q_deg, externals)
            ));
        }
        if motion.motions.linear {
            if let Some(approach) = &stop.approach {
                out.push_str(&format!(
                    "DECL E6POS {}={}\n",
                    data_name("XA_", stop.target_id),
                    e6pos(robot, approach, externals)
                ));
            }
            out.push_str(&format!(
                "DECL E6POS {}={}\n",
                data_name("XP_", stop.target_id),
                e6pos(robot, &stop.target, externals)
            ));
        }
    }
    out.push_str("ENDDAT\n");
    out
}

/// The `.src` file: settings, the base, tool and load, then the motions to the
/// `ok` rows; with several tools, `$TOOL` (and `$LOAD`) change before the first
/// move of a row with another tool.
pub fn src(robot: &Robot, program: &Program, motion: &MotionSettings) -> String {
    let mut out = format!("DEF {}( )\n", motion.name);
    header(&mut out, robot, program, "KUKA KRL program");
    // KUKA's standard initialisation: accelerations, orientation control and
    // the other motion variables a program must set before its first move get
    // the controller's defaults; the lines after it set what egcal chooses.
    out.push_str("BAS(#INITMOV, 0)\n");
    for axis in 1..=PROGRAM_JOINTS {
        out.push_str(&format!(
            "$VEL_AXIS[{axis}] = {}\n",
            fixed(motion.joint_speed_percent, 1)
        ));
    }
    out.push_str(&format!(
        "$VEL.CP = {} ; m/s\n",
        fixed(motion.speed_mm_s / 1000.0, 4)
    ));
    let approximation = match motion.zone_mm {
        Some(radius) => {
            out.push_str(&format!("$APO.CDIS = {radius} ; mm\n"));
            " C_DIS"
        }
        None => "",
    };
    out.push_str(&format!("$BASE = {BASE_NAME}\n$IPO_MODE = #BASE\n"));
    let names = tool_names(TOOL_NAME, program.tools.len());
    let mut active: Option<usize> = None;
    let mut select = |out: &mut String, tool: usize| {
        if active != Some(tool) {
            out.push_str(&format!("$TOOL = {}\n", names[tool]));
            if let Some(payload) = &program.payload {
                out.push_str(&format!(
                    "$LOAD = {}\n",
                    load_value(payload, &program.tools[tool])
                ));
            }
            active = Some(tool);
        }
    };
    let stops = &program.stops;
    if let Some(first) = stops.first() {
        select(&mut out, first.tool);
    }
    if motion.motions.joint {
        out.push_str("; joint moves to the joint commands (exact stops)\n");
        for stop in stops {
            select(&mut out, stop.tool);
            // From the pre-position the joints arrive moving the way the
            // compensation assumed.
            if stop.pre_position_q_deg.is_some() {
                out.push_str(&format!(
                    "PTP {}{approximation}\n",
                    data_name(PRE_POSITION_PREFIX, stop.target_id)
                ));
            }
            out.push_str(&format!("PTP {}\n", data_name("XJ_", stop.target_id)));
        }
    }
    if motion.motions.linear {
        out.push_str("; Cartesian moves to the corrected targets\n");
        for (k, stop) in stops.iter().enumerate() {
            select(&mut out, stop.tool);
            let name = data_name("XP_", stop.target_id);
            // The last move stops exactly: there is nothing to blend into.
            let approximate = if k + 1 == stops.len() {
                ""
            } else {
                approximation
            };
            let first = if k == 0 { "PTP" } else { "LIN" };
            if stop.pre_position_q_deg.is_some() {
                out.push_str(&format!(
                    "PTP {}{approximation}\nLIN {name}\n",
                    data_name(PRE_POSITION_PREFIX, stop.target_id)
                ));
                continue;
            }
            match &stop.approach {
                None if k == 0 => out.push_str(&format!("PTP {name}\n")),
                None => out.push_str(&format!("LIN {name}{approximate}\n")),
                // Approach (blended), the target with an exact stop, retract.
                Some(_) => {
                    let approach = data_name("XA_", stop.target_id);
                    let blend = if k == 0 { "" } else { approximation };
                    out.push_str(&format!("{first} {approach}{blend}\n"));
                    out.push_str(&format!("LIN {name}\n"));
                    out.push_str(&format!("LIN {approach}{approximate}\n"));
                }
            }
        }
    }
    out.push_str("END\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_support;
    use crate::robot::test_support::irb1600;

    #[test]
    fn abc_of_fixed_quaternions() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let [a, b, c] = abc_deg([h, 0.0, 0.0, h]);
        assert!((a - 90.0).abs() < 1e-12 && b.abs() < 1e-12 && c.abs() < 1e-12);
        // -90° about x.
        let [a, b, c] = abc_deg([h, -h, 0.0, 0.0]);
        assert!(a.abs() < 1e-12 && b.abs() < 1e-12 && (c + 90.0).abs() < 1e-12);
    }

    #[test]
    fn turn_bits_are_the_negative_axes() {
        assert_eq!(turn(&[0.0; 7]), 0);
        assert_eq!(turn(&[91.0, -45.0, 37.0, 1.0, -1.0, 0.0, 0.0]), 0b010010);
        assert_eq!(turn(&[-1.0; 7]), 63);
    }

    #[test]
    fn status_on_fixed_configurations() {
        let robot = irb1600();
        // Arm in front, stretched elbow past φ, A5 positive: 'B010, like KUKA's HOME.
        assert_eq!(status(&robot, &[0.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0]), 2);
        assert_eq!(status(&robot, &[0.0, 0.0, 0.0, 0.0, -30.0, 0.0, 0.0]), 6);
        // Folded back over the lower arm: overhead, A3 below φ.
        assert_eq!(status(&robot, &[0.0, 0.0, -180.0, 0.0, 30.0, 0.0, 0.0]), 1);
    }

    #[test]
    fn every_declared_name_is_one_the_settings_check_refuses() {
        let motion = test_support::motion(None, Some(40.0));
        let program = test_support::program(&irb1600(), &[1, -2], Some(40.0), None);
        let text = dat(&irb1600(), &program, &motion);
        let declared: Vec<&str> = text
            .lines()
            .filter_map(|l| l.strip_prefix("DECL "))
            .filter_map(|rest| rest.split(['=', ' ']).nth(1))
            .collect();
        assert_eq!(
            declared,
            [
                "XBASE", "XTOOL", "XJ_1", "XA_1", "XP_1", "XJ_N2", "XA_N2", "XP_N2"
            ]
        );
        for name in declared {
            assert!(
                crate::export::generated_name_clash(name).is_some(),
                "{name}"
            );
        }
    }

    #[test]
    fn the_program_sets_its_base_tool_and_load_before_moving() {
        let robot = irb1600();
        let payload = Payload {
            mass_kg: 2.5,
            cog_in_tool_mm: [0.0, 0.0, -100.0],
        };
        let program = test_support::program(&robot, &[1, 2], Some(40.0), Some(payload));
        let motion = test_support::motion(Some(10), Some(40.0));
        let dat_text = dat(&robot, &program, &motion);
        assert!(
            dat_text.contains(
                "DECL FRAME XBASE={X 0.0000,Y 0.0000,Z 0.0000,A 0.000000,B 0.000000,C 0.000000}\n"
            ),
            "{dat_text}"
        );
        assert!(dat_text.contains(
            "DECL FRAME XTOOL={X 22.0000,Y 50.0000,Z 150.0000,A 0.000000,B 0.000000,C 0.000000}\n"
        ));
        let src_text = src(&robot, &program, &motion);
        let body: Vec<&str> = src_text.lines().filter(|l| !l.starts_with(';')).collect();
        let first_move = body.iter().position(|l| l.starts_with("PTP")).unwrap();
        for expected in [
            "$BASE = XBASE",
            "$TOOL = XTOOL",
            "$IPO_MODE = #BASE",
            "$LOAD = {M 2.500,CM {X 22.0000,Y 50.0000,Z 50.0000,A 0.0,B 0.0,C 0.0},J {X 0.0,Y 0.0,Z 0.0}}",
        ] {
            let at = body.iter().position(|l| *l == expected);
            assert!(
                at.is_some_and(|at| at < first_move),
                "{expected}\n{src_text}"
            );
        }
        assert!(!src_text.contains("$NULLFRAME") && !src_text.contains("TOOL_DATA"));
        let moves: Vec<&str> = body
            .iter()
            .copied()
            .filter(|l| l.starts_with("PTP") || l.starts_with("LIN"))
            .collect();
        assert_eq!(
            moves,
            [
                "PTP XJ_1",
                "PTP XJ_2",
                "PTP XA_1",
                "LIN XP_1",
                "LIN XA_1 C_DIS",
                "LIN XA_2 C_DIS",
                "LIN XP_2",
                "LIN XA_2"
            ]
        );
    }

    #[test]
    fn a_pre_positioned_target_is_reached_from_its_pre_position() {
        let robot = irb1600();
        let motion = test_support::motion(None, None);
        let mut program = test_support::program(&robot, &[3], None, None);
        program.stops[0].pre_position_q_deg = Some([9.0, 21.0, -30.0, 40.0, 50.0, 60.0, 0.0]);
        let dat = dat(&robot, &program, &motion);
        assert!(
            dat.contains("DECL E6AXIS XB_3={A1 9.000000,A2 21.000000,A3 -30.000000,A4 40.000000,A5 50.000000,A6 60.000000,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}"),
            "{dat}"
        );
        let moves: Vec<String> = src(&robot, &program, &motion)
            .lines()
            .filter(|l| l.starts_with("PTP") || l.starts_with("LIN"))
            .map(String::from)
            .collect();
        assert_eq!(moves, ["PTP XB_3", "PTP XJ_3", "PTP XB_3", "LIN XP_3"]);
    }

    #[test]
    fn negative_ids_get_a_letter() {
        assert_eq!(data_name("XP_", -12), "XP_N12");
    }
}
