//! ABB RAPID module (`.mod`): `CONST jointtarget` data moved to with `MoveAbsJ`,
//! and `CONST robtarget` data (position, quaternion, `confdata`) moved to with
//! `MoveJ` (the first) and `MoveL` (the rest).
//!
//! A command compensated for approach directions (backlash) is reached from
//! its pre-position (`CONST jointtarget jp_<id>`, [`Stop::pre_position_q_deg`]):
//! `MoveAbsJ` there, then to the target with an exact stop (`MoveAbsJ` on the
//! joint path, `MoveL` on the linear one).
//!
//! `confdata` [cf1, cf4, cf6, cfx] follows ABB's definition (RAPID reference
//! manual, data type `confdata`; table reproduced in
//! CEAD-group/py-opw-kinematics `AXIS_CONFIGURATION.md`): cf1, cf4, cf6 are the
//! quadrants of axes 1, 4 and 6, ⌊q/90°⌋ (0 for 0…90°, 1 for 90…180°, −1 for
//! −90…0°, …); cfx is 0…7 = 4·(wrist centre behind axis 1) + 2·(wrist centre
//! behind the lower arm) + (axis 5 negative). They are computed on the NOMINAL
//! arm at the joint command, since the controller's nominal model is what
//! matches them, so `ConfL\On` (the default) gives back the command.
//!
//! Quaternions are `[q1, q2, q3, q4] = [w, x, y, z]`, ABB's order.
//!
//! The module declares the tool its robtargets are poses of (`PERS tooldata`:
//! `tframe` the flange → tool transform, `tload` the robot file's payload) and
//! the robot base as a work object (`PERS wobjdata`, identity frames), and every
//! move names both; `tool0`, ABB's flange, is never used, since it cannot be
//! redefined and the robtargets are not poses of the flange.
//!
//! External axes fill `extjoint` from `eax_a` on ([`super::external_axes`]):
//! the track's carriage (mm), then the positioner's axes (deg), as a
//! controller with exactly these axes numbers them; unused ones are 9E9.

use super::cartesian::Pose;
use super::{
    JOINT_DECIMALS, MASS_DECIMALS, MotionSettings, POSITION_DECIMALS, PROGRAM_JOINTS, Payload,
    Program, ProgramTool, QUATERNION_DECIMALS, Stop, external_axes, fixed, header_lines,
    positioner_axis_count, positioner_lines, printed_precision, skipped_lines, tool_lines,
    tool_names, track_lines, warning_lines, wrist_placement,
};
use crate::robot::{MAX_JOINTS, Robot};

/// Longest RAPID identifier.
pub const MAX_IDENTIFIER_LEN: usize = 32;

/// ABB's `confdata` of a joint command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConfData {
    pub cf1: i64,
    pub cf4: i64,
    pub cf6: i64,
    pub cfx: i64,
}

/// The quadrant ABB numbers an axis angle by: ⌊q/90°⌋.
pub fn quadrant(q_deg: f64) -> i64 {
    (q_deg / 90.0).floor() as i64
}

/// [`ConfData`] of `q_deg` on `robot`'s nominal geometry. On a boundary (the
/// wrist centre on axis 1 or on the lower arm's line, axis 5 at zero: the
/// singularities) "in front of" and "positive" win.
pub fn confdata(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> ConfData {
    let wrist = wrist_placement(robot, q_deg);
    let behind_axis1 = i64::from(wrist.front_of_axis1_mm < 0.0);
    let behind_lower_arm = i64::from(wrist.front_of_lower_arm_mm2 < 0.0);
    let axis5_negative = i64::from(q_deg[4] < 0.0);
    ConfData {
        cf1: quadrant(q_deg[0]),
        cf4: quadrant(q_deg[3]),
        cf6: quadrant(q_deg[5]),
        cfx: 4 * behind_axis1 + 2 * behind_lower_arm + axis5_negative,
    }
}

/// A `jointtarget` value: the controller's six joint values (the robot
/// file's `[controller]`) and the external axes ([`external_axes`]).
fn jointtarget(robot: &Robot, q_deg: &[f64; MAX_JOINTS], external: &[f64]) -> String {
    let q = robot.spec().controller_joints_deg(q_deg)[..PROGRAM_JOINTS]
        .iter()
        .map(|v| fixed(*v, JOINT_DECIMALS))
        .collect::<Vec<_>>()
        .join(", ");
    format!("[[{q}], {}]", extjoint(external))
}

/// The names of RAPID's external axes, `eax_a` … `eax_f`.
const EXTERNAL_AXIS_NAMES: [&str; 6] = ["eax_a", "eax_b", "eax_c", "eax_d", "eax_e", "eax_f"];

/// The `eax_…` names of the positioner's axes: those after the track's.
fn positioner_axis_names(robot: &Robot) -> String {
    let first = usize::from(robot.spec().track.is_some());
    let names = &EXTERNAL_AXIS_NAMES[first..first + positioner_axis_count(robot)];
    format!("{} (deg)", names.join(", "))
}

/// An `extjoint` value: the external axes in order from `eax_a` (the
/// track's mm, the positioner's deg), the rest unused (9E9).
fn extjoint(external: &[f64]) -> String {
    let values: Vec<String> = (0..EXTERNAL_AXIS_NAMES.len())
        .map(|k| {
            external
                .get(k)
                .map_or_else(|| "9E9".to_string(), |v| fixed(*v, POSITION_DECIMALS))
        })
        .collect();
    format!("[{}]", values.join(", "))
}

/// Name of a target's data: `<prefix><id>`, `n` for a minus sign.
pub fn data_name(prefix: &str, target_id: i64) -> String {
    if target_id < 0 {
        format!("{prefix}n{}", target_id.unsigned_abs())
    } else {
        format!("{prefix}{target_id}")
    }
}

/// The minimal load RAPID accepts in a `tooldata` (ABB's `load0`): a tool's
/// mass must be positive.
const MINIMAL_LOAD: &str = "[0.001, [0, 0, 0.001], [1, 0, 0, 0], 0, 0, 0]";

/// The work object of the robot base: `uframe` and `oframe` identity, fixed
/// (not robot-held), programmed user frame.
const BASE_WOBJ: &str = "[FALSE, TRUE, \"\", [[0, 0, 0], [1, 0, 0, 0]], [[0, 0, 0], [1, 0, 0, 0]]]";

/// The `tooldata` value of `tool` carrying `payload` (`robhold` TRUE: the
/// robot holds it).
pub fn tooldata(tool: &ProgramTool, payload: Option<&Payload>) -> String {
    let tcp = tool
        .tcp_mm()
        .map(|v| fixed(v, POSITION_DECIMALS))
        .join(", ");
    let orientation = tool
        .quaternion_wxyz()
        .map(|v| fixed(v, QUATERNION_DECIMALS))
        .join(", ");
    let load = match payload {
        Some(payload) => format!(
            "[{}, [{}], [1, 0, 0, 0], 0, 0, 0]",
            fixed(payload.mass_kg, MASS_DECIMALS),
            payload
                .cog_in_flange_mm(tool)
                .map(|v| fixed(v, POSITION_DECIMALS))
                .join(", ")
        ),
        None => MINIMAL_LOAD.to_string(),
    };
    format!("[TRUE, [[{tcp}], [{orientation}]], {load}]")
}

fn robtarget(robot: &Robot, pose: &Pose, external: &[f64]) -> String {
    let p = pose
        .position_mm
        .map(|v| fixed(v, POSITION_DECIMALS))
        .join(", ");
    let q = normalised(pose.quaternion_wxyz)
        .map(|v| fixed(v, QUATERNION_DECIMALS))
        .join(", ");
    let conf = confdata(robot, &pose.q_deg);
    format!(
        "[[{p}], [{q}], [{}, {}, {}, {}], {}]",
        conf.cf1,
        conf.cf4,
        conf.cf6,
        conf.cfx,
        extjoint(external)
    )
}

/// The whole module text. Rows whose status is not `ok` are listed in a
/// comment and get no data and no motion. `tool_name` names the tool (with a
/// suffix `_1` … when the rows use several), `wobj_name` the work object; the
/// module declares both, and every move names them.
pub fn module(
    robot: &Robot,
    program: &Program,
    motion: &MotionSettings,
    tool_name: &str,
    wobj_name: &str,
) -> String {
    let mut out = String::new();
    let line = |out: &mut String, text: &str| {
        out.push_str(text);
        out.push('\n');
    };
    let tools = tool_names(tool_name, program.tools.len());
    let load_lines = match &program.payload {
        Some(payload) => vec![format!(
            "Tool load (tload): the robot file's payload, {} kg at its centre of gravity, a point mass (no inertia known).",
            fixed(payload.mass_kg, MASS_DECIMALS)
        )],
        None => vec![
            "WARNING: the robot file gives no payload mass, so tload is ABB's minimal load (0.001 kg, as load0).".into(),
            "Enter the real tool's load (or run LoadIdentify) before running: a wrong load".into(),
            "degrades path accuracy and the motion supervision.".into(),
        ],
    };
    line(&mut out, &format!("MODULE {}", motion.name));
    for text in header_lines(&program.provenance, "ABB RAPID module", printed_precision())
        .iter()
        .chain(&tool_lines(program, &tools))
        .chain(&[
            format!("Work object {wobj_name}: the robot base frame (uframe and oframe identity, like wobj0 relative to"),
            "the controller's world frame, which must coincide with the robot base: ABB's default for a".into(),
            "floor-mounted robot without track or positioner).".into(),
        ])
        .chain(&track_lines(program, "eax_a (not coordinated)"))
        .chain(&positioner_lines(program, &positioner_axis_names(robot)))
        .chain(&load_lines)
        .chain(&[
            "The tool and work object get their values again in main: a PERS of the same name in another".into(),
            "loaded module shares one value with them.".into(),
            "Configuration: confdata from the nominal arm at each joint command (ConfL/ConfJ on).".into(),
        ])
        .chain(&warning_lines(program))
        .chain(&skipped_lines(&program.commands))
    {
        line(&mut out, &format!("  ! {text}"));
    }
    let tool_values: Vec<String> = program
        .tools
        .iter()
        .map(|t| tooldata(t, program.payload.as_ref()))
        .collect();
    for (name, value) in tools.iter().zip(&tool_values) {
        line(&mut out, &format!("  PERS tooldata {name} := {value};"));
    }
    line(
        &mut out,
        &format!("  PERS wobjdata {wobj_name} := {BASE_WOBJ};"),
    );
    // Not derived from the module name, so it never collides with it and stays
    // within the identifier limit.
    let speed = "egcal_speed";
    line(
        &mut out,
        &format!(
            "  CONST speeddata {speed} := [{}, 500, 5000, 1000];",
            fixed(motion.speed_mm_s, 1)
        ),
    );
    let zone = match motion.zone_mm {
        Some(radius) => format!("z{radius}"),
        None => "fine".to_string(),
    };
    let stops = &program.stops;
    let external = |stop: &Stop| external_axes(robot, stop.track_mm, stop.positioner_deg);
    for stop in stops {
        if let Some(q) = &stop.pre_position_q_deg {
            line(
                &mut out,
                &format!(
                    "  CONST jointtarget {} := {};",
                    data_name("jp_", stop.target_id),
                    jointtarget(robot, q, &external(stop))
                ),
            );
        }
    }
    if motion.motions.joint {
        for stop in stops {
            line(
                &mut out,
                &format!(
                    "  CONST jointtarget {} := {};",
                    data_name("jt_", stop.target_id),
                    jointtarget(robot, &stop.target.q_deg, &external(stop))
                ),
            );
        }
    }
    if motion.motions.linear {
        for stop in stops {
            if let Some(approach) = &stop.approach {
                line(
                    &mut out,
                    &format!(
                        "  CONST robtarget {} := {};",
                        data_name("pa_", stop.target_id),
                        robtarget(robot, approach, &external(stop))
                    ),
                );
            }
            line(
                &mut out,
                &format!(
                    "  CONST robtarget {} := {};",
                    data_name("pt_", stop.target_id),
                    robtarget(robot, &stop.target, &external(stop))
                ),
            );
        }
    }
    line(&mut out, "");
    line(&mut out, "  PROC main()");
    for (name, value) in tools.iter().zip(&tool_values) {
        line(&mut out, &format!("    {name} := {value};"));
    }
    line(&mut out, &format!("    {wobj_name} := {BASE_WOBJ};"));
    if motion.motions.joint {
        line(&mut out, "    path_joint;");
    }
    if motion.motions.linear {
        line(&mut out, "    path_linear;");
    }
    line(&mut out, "  ENDPROC");
    let tail = |stop: &Stop, zone: &str| {
        format!("{speed}, {zone}, {}\\WObj:={wobj_name};", tools[stop.tool])
    };
    // The last move of a path stops exactly: a corner zone there has no next
    // move to blend into.
    let zone_at = |k: usize| if k + 1 == stops.len() { "fine" } else { &zone };
    if motion.motions.joint {
        line(&mut out, "");
        line(&mut out, "  PROC path_joint()");
        for (k, stop) in stops.iter().enumerate() {
            // From the pre-position the joints arrive moving the way the
            // compensation assumed; the target then stops exactly.
            let zone_here = match &stop.pre_position_q_deg {
                Some(_) => {
                    line(
                        &mut out,
                        &format!(
                            "    MoveAbsJ {}, {}",
                            data_name("jp_", stop.target_id),
                            tail(stop, &zone)
                        ),
                    );
                    "fine"
                }
                None => zone_at(k),
            };
            line(
                &mut out,
                &format!(
                    "    MoveAbsJ {}, {}",
                    data_name("jt_", stop.target_id),
                    tail(stop, zone_here)
                ),
            );
        }
        line(&mut out, "  ENDPROC");
    }
    if motion.motions.linear {
        line(&mut out, "");
        line(&mut out, "  PROC path_linear()");
        for (k, stop) in stops.iter().enumerate() {
            let first = if k == 0 { "MoveJ" } else { "MoveL" };
            let target = data_name("pt_", stop.target_id);
            if stop.pre_position_q_deg.is_some() {
                line(
                    &mut out,
                    &format!(
                        "    MoveAbsJ {}, {}",
                        data_name("jp_", stop.target_id),
                        tail(stop, &zone)
                    ),
                );
                line(
                    &mut out,
                    &format!("    MoveL {target}, {}", tail(stop, "fine")),
                );
                continue;
            }
            match &stop.approach {
                None => line(
                    &mut out,
                    &format!("    {first} {target}, {}", tail(stop, zone_at(k))),
                ),
                // Approach, the target with an exact stop, retract to the
                // approach point.
                Some(_) => {
                    let approach = data_name("pa_", stop.target_id);
                    line(
                        &mut out,
                        &format!("    {first} {approach}, {}", tail(stop, &zone)),
                    );
                    line(
                        &mut out,
                        &format!("    MoveL {target}, {}", tail(stop, "fine")),
                    );
                    line(
                        &mut out,
                        &format!("    MoveL {approach}, {}", tail(stop, zone_at(k))),
                    );
                }
            }
        }
        line(&mut out, "  ENDPROC");
    }
    line(&mut out, "ENDMODULE");
    out
}

/// The quaternion scaled to unit length (the table's is unit to rounding).
fn normalised(q: [f64; 4]) -> [f64; 4] {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / norm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_support;
    use crate::robot::test_support::irb1600;

    #[test]
    fn quadrants_follow_abb() {
        assert_eq!(quadrant(0.0), 0);
        assert_eq!(quadrant(45.0), 0);
        assert_eq!(quadrant(90.0), 1);
        assert_eq!(quadrant(135.0), 1);
        assert_eq!(quadrant(-10.0), -1);
        assert_eq!(quadrant(-100.0), -2);
        assert_eq!(quadrant(370.0), 4);
    }

    #[test]
    fn confdata_on_fixed_configurations() {
        let robot = irb1600();
        // Everything in front, axis 5 positive.
        let c = confdata(&robot, &[10.0, 0.0, 0.0, 100.0, 30.0, -45.0, 0.0]);
        assert_eq!(
            c,
            ConfData {
                cf1: 0,
                cf4: 1,
                cf6: -1,
                cfx: 0
            }
        );
        // Axis 5 negative.
        assert_eq!(
            confdata(&robot, &[0.0, 0.0, 0.0, 0.0, -30.0, 0.0, 0.0]).cfx,
            1
        );
        // Upper arm folded back: wrist behind the lower arm and behind axis 1.
        assert_eq!(
            confdata(&robot, &[-95.0, 0.0, -180.0, 0.0, 30.0, 0.0, 0.0]),
            ConfData {
                cf1: -2,
                cf4: 0,
                cf6: 0,
                cfx: 6
            }
        );
    }

    #[test]
    fn every_declared_name_is_one_the_settings_check_refuses() {
        let motion = test_support::motion(Some(10), Some(50.0));
        let program = test_support::program(&irb1600(), &[1, -2], Some(50.0), None);
        let text = module(&irb1600(), &program, &motion, "egcal_tool", "egcal_wobj");
        let declared: Vec<&str> = text
            .lines()
            .filter_map(|l| {
                let l = l.trim();
                l.strip_prefix("PROC ")
                    .map(|rest| rest.trim_end_matches("()"))
                    .or_else(|| {
                        l.strip_prefix("CONST ")
                            .and_then(|rest| rest.split_whitespace().nth(1))
                    })
            })
            .collect();
        assert_eq!(declared.len(), 10, "{declared:?}");
        for name in declared {
            assert!(
                crate::export::generated_name_clash(name).is_some(),
                "{name}"
            );
        }
    }

    #[test]
    fn moves_name_the_declared_tool_and_work_object_never_tool0() {
        let robot = irb1600();
        let motion = test_support::motion(Some(10), Some(50.0));
        let program = test_support::program(&robot, &[1, 2], Some(50.0), None);
        let text = module(&robot, &program, &motion, "egcal_tool", "egcal_wobj");
        assert!(text.contains("  PERS tooldata egcal_tool := [TRUE, [[22.0000, 50.0000, 150.0000], [1.000000000, 0.000000000, 0.000000000, 0.000000000]], [0.001, [0, 0, 0.001], [1, 0, 0, 0], 0, 0, 0]];"), "{text}");
        assert!(text.contains("  PERS wobjdata egcal_wobj := [FALSE, TRUE, \"\", [[0, 0, 0], [1, 0, 0, 0]], [[0, 0, 0], [1, 0, 0, 0]]];"));
        assert!(text.contains("WARNING: the robot file gives no payload mass"));
        let moves: Vec<&str> = text
            .lines()
            .map(str::trim)
            .filter(|l| l.starts_with("Move"))
            .collect();
        // Joint path 2, linear path 3 per target: approach, target, retract.
        assert_eq!(moves.len(), 2 + 6, "{moves:?}");
        for m in &moves {
            assert!(m.ends_with("egcal_tool\\WObj:=egcal_wobj;"), "{m}");
            assert!(!m.contains("tool0"));
        }
        assert_eq!(
            moves[2],
            "MoveJ pa_1, egcal_speed, z10, egcal_tool\\WObj:=egcal_wobj;"
        );
        assert_eq!(
            moves[3],
            "MoveL pt_1, egcal_speed, fine, egcal_tool\\WObj:=egcal_wobj;"
        );
        assert_eq!(
            moves[4],
            "MoveL pa_1, egcal_speed, z10, egcal_tool\\WObj:=egcal_wobj;"
        );
        assert_eq!(
            moves[7],
            "MoveL pa_2, egcal_speed, fine, egcal_tool\\WObj:=egcal_wobj;"
        );
    }

    #[test]
    fn a_payload_is_the_tool_load_with_its_centre_of_gravity_in_the_flange_frame() {
        let robot = irb1600();
        let payload = Payload {
            mass_kg: 2.5,
            cog_in_tool_mm: [0.0, 0.0, -100.0],
        };
        let program = test_support::program(&robot, &[1], None, Some(payload));
        let text = module(
            &robot,
            &program,
            &test_support::motion(None, None),
            "gripper",
            "base_wobj",
        );
        // Tool (22, 50, 150) without rotation: the centre of gravity 100 mm
        // back along its z is at z = 50 in the flange frame.
        assert!(
            text.contains("[2.500, [22.0000, 50.0000, 50.0000], [1, 0, 0, 0], 0, 0, 0]]"),
            "{text}"
        );
        assert!(!text.contains("WARNING"));
        assert!(text.contains("    gripper := [TRUE,"));
    }

    #[test]
    fn a_pre_positioned_target_is_reached_from_its_pre_position_with_an_exact_stop() {
        let robot = irb1600();
        let motion = test_support::motion(Some(10), None);
        let mut program = test_support::program(&robot, &[1, 2], None, None);
        for stop in &mut program.stops {
            stop.pre_position_q_deg = Some(stop.target.q_deg.map(|q| q - 1.0));
        }
        let text = module(&robot, &program, &motion, "egcal_tool", "egcal_wobj");
        assert!(
            text.contains("  CONST jointtarget jp_1 := [[9.000000, 19.000000, -31.000000, 39.000000, 49.000000, 59.000000], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];"),
            "{text}"
        );
        let moves: Vec<&str> = text
            .lines()
            .map(str::trim)
            .filter_map(|l| l.strip_prefix("Move"))
            .map(|l| l.split(", egcal_tool").next().unwrap())
            .collect();
        assert_eq!(
            moves,
            [
                "AbsJ jp_1, egcal_speed, z10",
                "AbsJ jt_1, egcal_speed, fine",
                "AbsJ jp_2, egcal_speed, z10",
                "AbsJ jt_2, egcal_speed, fine",
                "AbsJ jp_1, egcal_speed, z10",
                "L pt_1, egcal_speed, fine",
                "AbsJ jp_2, egcal_speed, z10",
                "L pt_2, egcal_speed, fine",
            ]
        );
    }

    #[test]
    fn data_names_encode_negative_ids() {
        assert_eq!(data_name("jt_", 7), "jt_7");
        assert_eq!(data_name("pt_", -3), "pt_n3");
    }
}
