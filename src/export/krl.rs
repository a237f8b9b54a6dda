//! KUKA KRL pair: `<name>.dat` declares an `E6AXIS` per joint command and an
//! `E6POS` per corrected Cartesian target; `<name>.src` moves to them (`PTP`
//! E6AXIS; `PTP` E6POS to the first, then `LIN`).
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

use super::{
    Command, EULER_DECIMALS, JOINT_DECIMALS, MotionSettings, POSITION_DECIMALS, Provenance, fixed,
    header_lines, rotation_from_quaternion, skipped_lines, wrist_placement, zyx_angles,
};
use crate::robot::{JOINTS, Robot};

/// Longest KRL name.
pub const MAX_IDENTIFIER_LEN: usize = 24;

/// KUKA's Status of a joint command on `robot`'s nominal geometry.
pub fn status(robot: &Robot, q_deg: &[f64; JOINTS]) -> u32 {
    let wrist = wrist_placement(robot, q_deg);
    let overhead = u32::from(wrist.front_of_axis1_mm < 0.0);
    let a3_at_or_past_phi = u32::from(wrist.elbow_mm2 >= 0.0);
    let a5 = q_deg[4];
    let a5_negative = u32::from((-180.0..0.0).contains(&a5) || a5 >= 180.0);
    overhead | (a3_at_or_past_phi << 1) | (a5_negative << 2)
}

/// KUKA's Turn: bit i−1 set when axis i is negative.
pub fn turn(q_deg: &[f64; JOINTS]) -> u32 {
    q_deg
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

/// KUKA tool and base selection: `TOOL_DATA[tool]`, `BASE_DATA[base]` (0 =
/// `$NULLFRAME`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frames {
    pub tool: u32,
    pub base: u32,
}

fn frame_text(array: &str, index: u32) -> String {
    if index == 0 {
        "$NULLFRAME".to_string()
    } else {
        format!("{array}[{index}]")
    }
}

fn header(
    out: &mut String,
    provenance: &Provenance,
    kind: &str,
    commands: &[Command],
    frames: Frames,
) {
    for text in header_lines(provenance, kind)
        .iter()
        .chain(&[
            format!(
                "$TOOL = {} must hold the robot file's nominal [tool]; $BASE = {} must be the robot base frame.",
                frame_text("TOOL_DATA", frames.tool),
                frame_text("BASE_DATA", frames.base)
            ),
            "Status/Turn from the nominal arm at each joint command; Status bit 4 (absolutely accurate) is 0.".into(),
        ])
        .chain(&skipped_lines(commands))
    {
        out.push_str(&format!("; {text}\n"));
    }
}

/// The `.dat` file: one `E6AXIS` and/or `E6POS` per `ok` row.
pub fn dat(
    robot: &Robot,
    commands: &[Command],
    motion: &MotionSettings,
    frames: Frames,
    provenance: &Provenance,
) -> String {
    let mut out = format!("DEFDAT {}\n", motion.name);
    header(&mut out, provenance, "KUKA KRL data list", commands, frames);
    let externals = "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0";
    for c in commands.iter().filter(|c| c.is_ok()) {
        if motion.motions.joint {
            let axes: Vec<String> = (0..JOINTS)
                .map(|i| format!("A{} {}", i + 1, fixed(c.q_deg[i], JOINT_DECIMALS)))
                .collect();
            out.push_str(&format!(
                "DECL E6AXIS {}={{{},{externals}}}\n",
                data_name("XJ_", c.target_id),
                axes.join(",")
            ));
        }
        if motion.motions.linear {
            let [x, y, z] = c.position_mm.map(|v| fixed(v, POSITION_DECIMALS));
            let [a, b, cc] = abc_deg(c.quaternion_wxyz).map(|v| fixed(v, EULER_DECIMALS));
            out.push_str(&format!(
                "DECL E6POS {}={{X {x},Y {y},Z {z},A {a},B {b},C {cc},S {},T {},{externals}}}\n",
                data_name("XP_", c.target_id),
                status(robot, &c.q_deg),
                turn(&c.q_deg)
            ));
        }
    }
    out.push_str("ENDDAT\n");
    out
}

/// The `.src` file: settings, then the motions to the `ok` rows.
pub fn src(
    commands: &[Command],
    motion: &MotionSettings,
    frames: Frames,
    provenance: &Provenance,
) -> String {
    let mut out = format!("DEF {}( )\n", motion.name);
    header(&mut out, provenance, "KUKA KRL program", commands, frames);
    // KUKA's standard initialisation: accelerations, orientation control and
    // the other motion variables a program must set before its first move get
    // the controller's defaults; the lines after it set what egcal chooses.
    out.push_str("BAS(#INITMOV, 0)\n");
    for axis in 1..=JOINTS {
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
    out.push_str(&format!(
        "$TOOL = {}\n$BASE = {}\n",
        frame_text("TOOL_DATA", frames.tool),
        frame_text("BASE_DATA", frames.base)
    ));
    let ok: Vec<&Command> = commands.iter().filter(|c| c.is_ok()).collect();
    if motion.motions.joint {
        out.push_str("; joint moves to the joint commands (exact stops)\n");
        for c in &ok {
            out.push_str(&format!("PTP {}\n", data_name("XJ_", c.target_id)));
        }
    }
    if motion.motions.linear {
        out.push_str("; Cartesian moves to the corrected targets\n");
        for (k, c) in ok.iter().enumerate() {
            let name = data_name("XP_", c.target_id);
            // The last move stops exactly: there is nothing to blend into.
            let approximate = if k + 1 == ok.len() { "" } else { approximation };
            if k == 0 {
                out.push_str(&format!("PTP {name}\n"));
            } else {
                out.push_str(&format!("LIN {name}{approximate}\n"));
            }
        }
    }
    out.push_str("END\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
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
        assert_eq!(turn(&[0.0; 6]), 0);
        assert_eq!(turn(&[91.0, -45.0, 37.0, 1.0, -1.0, 0.0]), 0b010010);
        assert_eq!(turn(&[-1.0; 6]), 63);
    }

    #[test]
    fn status_on_fixed_configurations() {
        let robot = irb1600();
        // Arm in front, stretched elbow past φ, A5 positive: 'B010, like KUKA's HOME.
        assert_eq!(status(&robot, &[0.0, 0.0, 0.0, 0.0, 30.0, 0.0]), 2);
        assert_eq!(status(&robot, &[0.0, 0.0, 0.0, 0.0, -30.0, 0.0]), 6);
        // Folded back over the lower arm: overhead, A3 below φ.
        assert_eq!(status(&robot, &[0.0, 0.0, -180.0, 0.0, 30.0, 0.0]), 1);
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
            zone_mm: None,
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
        let frames = Frames { tool: 1, base: 0 };
        let text = dat(
            &irb1600(),
            &[command(1), command(-2)],
            &motion,
            frames,
            &provenance,
        );
        let declared: Vec<&str> = text
            .lines()
            .filter_map(|l| l.strip_prefix("DECL "))
            .filter_map(|rest| rest.split(['=', ' ']).nth(1))
            .collect();
        assert_eq!(declared, ["XJ_1", "XP_1", "XJ_N2", "XP_N2"]);
        for name in declared {
            assert!(
                crate::export::generated_name_clash(name).is_some(),
                "{name}"
            );
        }
    }

    #[test]
    fn negative_ids_get_a_letter() {
        assert_eq!(data_name("XP_", -12), "XP_N12");
    }
}
