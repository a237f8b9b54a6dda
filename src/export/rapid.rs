//! ABB RAPID module (`.mod`): `CONST jointtarget` data moved to with `MoveAbsJ`,
//! and `CONST robtarget` data (position, quaternion, `confdata`) moved to with
//! `MoveJ` (the first) and `MoveL` (the rest).
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

use super::{
    Command, JOINT_DECIMALS, MotionSettings, POSITION_DECIMALS, Provenance, QUATERNION_DECIMALS,
    fixed, header_lines, skipped_lines, wrist_placement,
};
use crate::robot::{JOINTS, Robot};

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
pub fn confdata(robot: &Robot, q_deg: &[f64; JOINTS]) -> ConfData {
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

/// Name of a target's data: `<prefix><id>`, `n` for a minus sign.
pub fn data_name(prefix: &str, target_id: i64) -> String {
    if target_id < 0 {
        format!("{prefix}n{}", target_id.unsigned_abs())
    } else {
        format!("{prefix}{target_id}")
    }
}

/// The whole module text. Rows whose status is not `ok` are listed in a
/// comment and get no data and no motion.
pub fn module(
    robot: &Robot,
    commands: &[Command],
    motion: &MotionSettings,
    tool_name: &str,
    wobj_name: &str,
    provenance: &Provenance,
) -> String {
    let mut out = String::new();
    let line = |out: &mut String, text: &str| {
        out.push_str(text);
        out.push('\n');
    };
    line(&mut out, &format!("MODULE {}", motion.name));
    for text in header_lines(provenance, "ABB RAPID module")
        .iter()
        .chain(&[
            format!("Tool `{tool_name}` must hold the robot file's nominal [tool]; work object `{wobj_name}` must be the robot base frame."),
            "Configuration: confdata from the nominal arm at each joint command (ConfL/ConfJ on).".into(),
        ])
        .chain(&skipped_lines(commands))
    {
        line(&mut out, &format!("  ! {text}"));
    }
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
    let ok: Vec<&Command> = commands.iter().filter(|c| c.is_ok()).collect();
    if motion.motions.joint {
        for c in &ok {
            let q = c.q_deg.map(|v| fixed(v, JOINT_DECIMALS)).join(", ");
            line(
                &mut out,
                &format!(
                    "  CONST jointtarget {} := [[{q}], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];",
                    data_name("jt_", c.target_id)
                ),
            );
        }
    }
    if motion.motions.linear {
        for c in &ok {
            let p = c
                .position_mm
                .map(|v| fixed(v, POSITION_DECIMALS))
                .join(", ");
            let q = normalised(c.quaternion_wxyz)
                .map(|v| fixed(v, QUATERNION_DECIMALS))
                .join(", ");
            let conf = confdata(robot, &c.q_deg);
            line(
                &mut out,
                &format!(
                    "  CONST robtarget {} := [[{p}], [{q}], [{}, {}, {}, {}], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];",
                    data_name("pt_", c.target_id),
                    conf.cf1,
                    conf.cf4,
                    conf.cf6,
                    conf.cfx
                ),
            );
        }
    }
    line(&mut out, "");
    line(&mut out, "  PROC main()");
    if motion.motions.joint {
        line(&mut out, "    path_joint;");
    }
    if motion.motions.linear {
        line(&mut out, "    path_linear;");
    }
    line(&mut out, "  ENDPROC");
    // The last move of a path stops exactly: a corner zone there has no next
    // move to blend into.
    let tail = |k: usize| {
        let zone = if k + 1 == ok.len() { "fine" } else { &zone };
        format!("{speed}, {zone}, {tool_name}\\WObj:={wobj_name};")
    };
    if motion.motions.joint {
        line(&mut out, "");
        line(&mut out, "  PROC path_joint()");
        for (k, c) in ok.iter().enumerate() {
            line(
                &mut out,
                &format!(
                    "    MoveAbsJ {}, {}",
                    data_name("jt_", c.target_id),
                    tail(k)
                ),
            );
        }
        line(&mut out, "  ENDPROC");
    }
    if motion.motions.linear {
        line(&mut out, "");
        line(&mut out, "  PROC path_linear()");
        for (k, c) in ok.iter().enumerate() {
            let instruction = if k == 0 { "MoveJ" } else { "MoveL" };
            line(
                &mut out,
                &format!(
                    "    {instruction} {}, {}",
                    data_name("pt_", c.target_id),
                    tail(k)
                ),
            );
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
        let c = confdata(&robot, &[10.0, 0.0, 0.0, 100.0, 30.0, -45.0]);
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
        assert_eq!(confdata(&robot, &[0.0, 0.0, 0.0, 0.0, -30.0, 0.0]).cfx, 1);
        // Upper arm folded back: wrist behind the lower arm and behind axis 1.
        assert_eq!(
            confdata(&robot, &[-95.0, 0.0, -180.0, 0.0, 30.0, 0.0]),
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
        let command = |target_id| Command {
            target_id,
            q_deg: [10.0, 20.0, -30.0, 40.0, 50.0, 60.0],
            status: crate::export::STATUS_OK.into(),
            residual_mm: 0.0,
            correction_mm: 0.0,
            elastic_mm: 0.0,
            position_mm: [900.0, 0.0, 800.0],
            quaternion_wxyz: [1.0, 0.0, 0.0, 0.0],
        };
        let motion = MotionSettings {
            name: "EGCAL_PROGRAM".into(),
            speed_mm_s: 100.0,
            joint_speed_percent: 20.0,
            zone_mm: Some(10),
            motions: crate::export::Motions {
                joint: true,
                linear: true,
            },
        };
        let provenance = Provenance {
            version: "0".into(),
            source: "commands.parquet".into(),
            robot: "r".into(),
        };
        let text = module(
            &irb1600(),
            &[command(1), command(-2)],
            &motion,
            "tool0",
            "wobj0",
            &provenance,
        );
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
        assert_eq!(declared.len(), 8, "{declared:?}");
        for name in declared {
            assert!(
                crate::export::generated_name_clash(name).is_some(),
                "{name}"
            );
        }
    }

    #[test]
    fn data_names_encode_negative_ids() {
        assert_eq!(data_name("jt_", 7), "jt_7");
        assert_eq!(data_name("pt_", -3), "pt_n3");
    }
}
