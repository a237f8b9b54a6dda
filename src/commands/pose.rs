//! `egcal pose`: the flange and tool pose of a robot file (or of a calibrated
//! model) at joint values typed as the controller shows them. It is the check of
//! a new robot file against the teach pendant: the same joints must give the
//! pendant's flange position and angles, in the conventions each vendor prints.

use std::fmt::Write as _;
use std::path::Path;

use super::CommandError;
use super::frame::parameter_values;
use crate::export::cartesian::quaternion_wxyz;
use crate::export::zyx_angles;
use crate::robot::{MAX_JOINTS, Robot, RobotSpec};

/// `value` with `decimals`, without a minus sign on a printed zero.
fn fixed(value: f64, decimals: usize) -> String {
    let text = format!("{value:.decimals$}");
    match text.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => text,
    }
}

/// `  what: x = … mm, y = … mm, z = … mm`, to the micrometre.
fn position_line(what: &str, p_mm: &nalgebra::Vector3<f64>) -> String {
    format!(
        "  {what}: x = {} mm, y = {} mm, z = {} mm\n",
        fixed(p_mm.x, 3),
        fixed(p_mm.y, 3),
        fixed(p_mm.z, 3)
    )
}

/// `egcal pose`: `controller_joints` in the controller's numbering (deg, or mm
/// for a prismatic joint), unloaded.
pub fn pose_command(
    robot_file: &Path,
    params: Option<&Path>,
    model: &str,
    controller_joints: &[f64],
) -> Result<String, CommandError> {
    let spec = RobotSpec::load(robot_file)?;
    let (values, source) = parameter_values(&spec, robot_file, params, model)?;
    let has_track = spec.track.is_some();
    let robot = Robot::new(spec);
    let joint_count = robot.joint_count();
    if controller_joints.len() != joint_count {
        return Err(CommandError::Usage(format!(
            "--joints: {} has {joint_count} joints, found {} values",
            robot_file.display(),
            controller_joints.len()
        )));
    }
    let mut controller = [0.0; MAX_JOINTS];
    controller[..joint_count].copy_from_slice(controller_joints);
    let q = robot.spec().robot_file_joints_deg(&controller);
    for (i, value) in q.iter().take(joint_count).enumerate() {
        let [low, high] = robot.joint_limits(i);
        if !value.is_finite() || *value < low || *value > high {
            return Err(CommandError::Usage(format!(
                "--joints: joint {} is {} in the robot file's numbering, outside its limits [{low}, {high}] in {}",
                i + 1,
                crate::calibration::row_checks::compact(*value),
                robot_file.display()
            )));
        }
    }
    let (joints, tool) = robot.frames_in_base(&values, &q);
    let flange = joints[joint_count];
    let mut out = String::new();
    let joints_text = |v: &[f64]| {
        v.iter()
            .map(|x| crate::calibration::row_checks::compact(*x))
            .collect::<Vec<_>>()
            .join(", ")
    };
    writeln!(
        out,
        "{source}, unloaded, at controller joints [{}] (robot file: [{}]):",
        joints_text(controller_joints),
        joints_text(&q[..joint_count])
    )
    .expect("write to string");
    out.push_str(&position_line(
        "flange in the base frame",
        &flange.origin_mm,
    ));
    let quaternion = quaternion_wxyz(&flange).map(|v| fixed(v, 6)).join(", ");
    writeln!(
        out,
        "    quaternion (w, x, y, z) = [{quaternion}]  (ABB q1 … q4)"
    )
    .expect("write to string");
    let [a, b, c] = zyx_angles(&flange.rotation).map(|v| fixed(v.to_degrees(), 4));
    writeln!(
        out,
        "    Z-Y-X angles: A = {a}°, B = {b}°, C = {c}°  (KUKA A, B, C; FANUC and Yaskawa W = C, P = B, R = A)"
    )
    .expect("write to string");
    let rotation_vector = crate::robot::frame::rotation_vector(&flange.rotation)
        .iter()
        .map(|v| fixed(*v, 6))
        .collect::<Vec<_>>()
        .join(", ");
    writeln!(
        out,
        "    rotation vector = [{rotation_vector}] rad  (Universal Robots RX, RY, RZ)"
    )
    .expect("write to string");
    out.push_str(&position_line(
        "tool (SMR) in the base frame",
        &tool.origin_mm,
    ));
    if has_track {
        out.push_str("  (the arm rides a track: the tracker frame depends on the carriage; base frame only)\n");
    } else {
        let world = robot
            .world_from_base(&values)
            .transform_point(&tool.origin_mm);
        out.push_str(&position_line("tool (SMR) in the tracker frame", &world));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn robot_file() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("jobs/robots/irb1600_145.toml")
    }

    /// A hand-computed case: at all joints zero the IRB 1600's flange is at
    /// x = a2 + d4 + d6 = 150 + 600 + 65 = 815 mm (the wrist points along x
    /// at the upper arm's height), z = d1 + a3 = 486.5 + 700 = 1186.5 mm,
    /// with the flange's z axis along the base x: B = 90°.
    #[test]
    fn the_irb1600_at_zero_has_its_flange_where_the_data_sheet_puts_it() {
        let text = pose_command(&robot_file(), None, "elastogeometric", &[0.0; 6]).expect("pose");
        assert!(
            text.contains(
                "flange in the base frame: x = 815.000 mm, y = 0.000 mm, z = 1186.500 mm"
            ),
            "{text}"
        );
        assert!(text.contains("B = 90.0000°"), "{text}");
    }

    #[test]
    fn a_printed_zero_has_no_sign() {
        assert_eq!(fixed(-1e-14, 3), "0.000");
        assert_eq!(fixed(-0.0004, 3), "0.000");
        assert_eq!(fixed(-0.0006, 3), "-0.001");
        assert_eq!(fixed(-12.5, 1), "-12.5");
    }

    #[test]
    fn a_joint_outside_its_limits_or_a_missing_value_is_refused() {
        let far = pose_command(
            &robot_file(),
            None,
            "elastogeometric",
            &[0.0, 130.0, 0.0, 0.0, 0.0, 0.0],
        )
        .expect_err("outside");
        assert!(far.to_string().contains("joint 2 is 130"), "{far}");
        let short =
            pose_command(&robot_file(), None, "elastogeometric", &[0.0; 5]).expect_err("five");
        assert!(
            short.to_string().contains("6 joints, found 5 values"),
            "{short}"
        );
    }
}
