//! URDF of the CALIBRATED rigid geometry: the identified MDH parameters of one
//! model of a parameters table as URDF joint origins, the world and tool frames
//! as fixed joints, the robot file's joint limits.
//!
//! Craig's MDH link transform `Rot(x, α)·Trans(a, 0, 0)·Rot(z, θ)·Trans(0, 0, d)`
//! with `θ = q + θ_offset + Δθ` splits into a fixed part, the joint `origin`
//! (`Rot(x, α)·Rot(z, θ_offset + Δθ)` at `(a, −d·sin α, d·cos α)`), and a
//! rotation about the joint's own z axis by `q` (the translation along z commutes
//! with it): URDF's `origin` then `axis = 0 0 1`. URDF orientations are
//! `rpy = (roll, pitch, yaw)` with `R = Rot(z, yaw)·Rot(y, pitch)·Rot(x, roll)`,
//! the same Z-Y-X angles as KUKA's A, B, C. Lengths are metres, angles radians,
//! printed with Rust's shortest round-trip form so that nothing is lost.
//!
//! Compliance (the joint stiffness) has no place in URDF; the file says so and
//! states that it is the unloaded geometry.
//!
//! Joint `<limit>`: URDF requires `effort` and `velocity` on a revolute joint
//! (urdfdom refuses the file without them), and planners read them: a velocity
//! of 0 says the joint cannot move. They come from the robot file's
//! `max_velocity_deg_s` and `max_torque_nm`; where a joint has none, a
//! placeholder is written and an XML comment names the joints that carry it:
//! [`UNKNOWN_VELOCITY_RAD_S`], slower than any axis of an industrial arm, so a
//! planner that times a path with it is never faster than the arm can go, and
//! [`UNKNOWN_EFFORT_NM`], large, because this URDF has no inertia from which a
//! consumer could compute a torque to compare it with: it should only never
//! be the reason a motion is refused.

use nalgebra::Vector3;

use super::zyx_angles;
use crate::robot::frame::rot_x;
use crate::robot::{Frame, JointParam, ParamId, ParamValues, Robot};

/// Where the URDF's values come from, for its header.
#[derive(Debug, Clone)]
pub struct UrdfSource {
    pub version: String,
    /// The parameters table's file name and content hash.
    pub parameters: String,
    pub model: String,
    /// Target (SMR) ids of a several-target set, sorted; empty for one target.
    pub targets: Vec<String>,
}

const DEG: f64 = std::f64::consts::PI / 180.0;

/// `<limit velocity>` of a joint whose robot file gives no `max_velocity_deg_s`,
/// rad/s (about 29°/s; the slowest axes of the IRB 1600 and the UR10 do 150 and
/// 120°/s).
pub const UNKNOWN_VELOCITY_RAD_S: f64 = 0.5;
/// `<limit effort>` of a joint whose robot file gives no `max_torque_nm`, N·m.
pub const UNKNOWN_EFFORT_NM: f64 = 10_000.0;
/// `<limit velocity>` of a prismatic joint (the robot file has no speed
/// for one), m/s: slower than a gantry's axes.
pub const UNKNOWN_SLIDE_VELOCITY_M_S: f64 = 0.1;
/// `<limit effort>` of a prismatic joint, N: large, like [`UNKNOWN_EFFORT_NM`].
pub const UNKNOWN_SLIDE_FORCE_N: f64 = 100_000.0;

/// The fixed part of MDH link `i` (0-based) at parameter set `p`: `A(i−1←i)`
/// at q = 0.
pub fn joint_origin(robot: &Robot, p: &ParamValues, i: usize) -> Frame {
    let joint = &robot.spec().joints[i];
    let error = |kind| p.get(ParamId::of_joint(kind, i));
    let alpha = (joint.alpha_deg + error(JointParam::Alpha)) * DEG;
    let a = joint.a_mm + error(JointParam::A);
    let theta = (joint.theta_offset_deg + error(JointParam::Theta)) * DEG;
    let d = joint.d_mm + error(JointParam::D);
    Frame {
        rotation: rot_x(alpha) * crate::robot::frame::rot_z(theta),
        origin_mm: Vector3::new(a, -alpha.sin() * d, alpha.cos() * d),
    }
}

/// XML text with `&`, `<`, `>`, `"` and `'` escaped (for names in attributes).
pub fn escape(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            '&' => "&amp;".to_string(),
            '<' => "&lt;".to_string(),
            '>' => "&gt;".to_string(),
            '"' => "&quot;".to_string(),
            '\'' => "&apos;".to_string(),
            c => c.to_string(),
        })
        .collect()
}

/// Text safe inside an XML comment (which must not contain `--`).
fn comment_safe(text: &str) -> String {
    let mut out = text.replace("--", "- -");
    while out.contains("--") {
        out = out.replace("--", "- -");
    }
    out
}

fn origin(frame: &Frame) -> String {
    let [yaw, pitch, roll] = zyx_angles(&frame.rotation);
    let xyz = frame.origin_mm / 1000.0;
    format!(
        "<origin xyz=\"{} {} {}\" rpy=\"{roll} {pitch} {yaw}\"/>",
        xyz.x, xyz.y, xyz.z
    )
}

/// The first value the URDF of `robot` at `p` would print that is not finite
/// or beyond [`super::MAX_PRINTED`] (a parameter, a joint origin, a limit),
/// described; `None` when every one is printable.
pub fn unprintable(robot: &Robot, p: &ParamValues) -> Option<String> {
    let mut values: Vec<(String, f64)> =
        p.0.iter()
            .enumerate()
            .map(|(i, v)| (format!("parameter {i}"), *v))
            .collect();
    for i in 0..robot.joint_count() {
        let origin = joint_origin(robot, p, i);
        values.extend(
            origin
                .origin_mm
                .iter()
                .chain(zyx_angles(&origin.rotation).iter())
                .map(|v| (format!("the origin of joint {}", i + 1), *v)),
        );
    }
    values
        .into_iter()
        .find(|(_, v)| !v.is_finite() || v.abs() >= super::MAX_PRINTED)
        .map(|(what, v)| format!("{what} would be printed as {v:e}, beyond what a URDF may hold"))
}

/// The URDF text of `robot` at parameter set `p`.
pub fn robot_urdf(robot: &Robot, p: &ParamValues, source: &UrdfSource) -> String {
    let spec = robot.spec();
    let compliances: Vec<String> = (0..robot.joint_count())
        .map(|i| {
            let k = ParamId::of_joint(JointParam::Compliance, i);
            format!("{k} = {}", p.get(k))
        })
        .collect();
    let mut comment = vec![
        format!("URDF generated by egcal {}", source.version),
        format!(
            "from model `{}` of the parameters table {}",
            source.model, source.parameters
        ),
        format!("robot file: {}", spec.name),
        "Joint origins: the identified MDH parameters (Craig: Rot(x,alpha) Trans(a) Rot(z,theta) Trans(d),".into(),
        "theta = q + theta_offset + dtheta), joint axes z; world and tool are fixed joints.".into(),
        "Joint positions are the robot file's joint commands in radians.".into(),
        "Compliance (joint stiffness) cannot be expressed in URDF: this is the RIGID, unloaded".into(),
        format!(
            "calibrated geometry. The model's joint compliances, deg/(N m), are NOT in it: {}.",
            compliances.join(", ")
        ),
        "Under gravity, payload or process forces the real arm deflects by k_i tau_i at each".into(),
        "joint; use egcal's model (predict, compensate) for loaded positions.".into(),
        "Limits: position from the robot file's limits_deg, velocity from its max_velocity_deg_s,".into(),
        "effort from its max_torque_nm.".into(),
        "No visual, collision or inertial elements.".into(),
    ];
    let missing = |has: &dyn Fn(usize) -> bool| -> Vec<String> {
        (0..robot.joint_count())
            .filter(|&i| !has(i))
            .map(|i| format!("joint{}", i + 1))
            .collect()
    };
    let prismatic = robot.prismatic_joints();
    let slides = missing(&|i| !prismatic[i]);
    if !slides.is_empty() {
        comment.push(format!(
            "Prismatic joints ({}): type prismatic along z, positions in metres (the robot file's",
            slides.join(", ")
        ));
        comment.push(format!(
            "q_mm / 1000), limits from its limits_mm, their compliances in mm/N; their velocity = {UNKNOWN_SLIDE_VELOCITY_M_S} m/s and effort = {UNKNOWN_SLIDE_FORCE_N} N are placeholders."
        ));
    }
    // A slide's placeholders are said above.
    let no_velocity = missing(&|i| prismatic[i] || spec.joints[i].max_velocity_deg_s.is_some());
    let no_effort = missing(&|i| prismatic[i] || spec.joints[i].max_torque_nm.is_some());
    if !no_velocity.is_empty() {
        comment.push(format!(
            "WARNING: the robot file gives no max_velocity_deg_s for {}: their velocity = {UNKNOWN_VELOCITY_RAD_S} rad/s",
            no_velocity.join(", ")
        ));
        comment.push(
            "is a slow placeholder, not the arm's (a planner timing a path with it is never too fast).".into(),
        );
    }
    if !no_effort.is_empty() {
        comment.push(format!(
            "WARNING: the robot file gives no max_torque_nm for {}: their effort = {UNKNOWN_EFFORT_NM} N m",
            no_effort.join(", ")
        ));
        comment.push(
            "is a placeholder, not the arm's (large, so that no motion is refused on it).".into(),
        );
    }
    if let Some(track) = &spec.track {
        comment.push(format!(
            "WARNING: the arm rides a linear track (travel {} to {} mm) that this file does not hold:",
            track.travel_mm[0], track.travel_mm[1]
        ));
        comment.push(
            "the world -> base_link joint is the base with the carriage at 0, and the track's calibrated".into(),
        );
        comment.push(
            "errors along its travel (track_* parameters) are not in it; use egcal's model for the cell.".into(),
        );
    }
    let mut out = String::from("<?xml version=\"1.0\"?>\n<!--\n");
    for line in comment {
        out.push_str(&format!("  {}\n", comment_safe(&line)));
    }
    out.push_str("-->\n");
    out.push_str(&format!("<robot name=\"{}\">\n", escape(&spec.name)));
    let mut links = vec!["world".to_string(), "base_link".to_string()];
    links.extend((1..=robot.joint_count()).map(|i| format!("link{i}")));
    let targets: Vec<String> = if source.targets.len() > 1 {
        source.targets.iter().map(|t| format!("tool_{t}")).collect()
    } else {
        vec!["tool".to_string()]
    };
    links.extend(targets.iter().cloned());
    for link in &links {
        out.push_str(&format!("  <link name=\"{}\"/>\n", escape(link)));
    }
    let fixed_joint = |out: &mut String, name: &str, parent: &str, child: &str, f: &Frame| {
        out.push_str(&format!(
            "  <joint name=\"{}\" type=\"fixed\">\n    <parent link=\"{}\"/>\n    <child link=\"{}\"/>\n    {}\n  </joint>\n",
            escape(name),
            escape(parent),
            escape(child),
            origin(f)
        ));
    };
    fixed_joint(
        &mut out,
        "world_to_base",
        "world",
        "base_link",
        &robot.world_from_base(p),
    );
    for (i, (joint, &slide)) in spec.joints.iter().zip(&prismatic).enumerate() {
        let parent = if i == 0 {
            "base_link".to_string()
        } else {
            format!("link{i}")
        };
        let [lo, hi] = joint.limits();
        // A revolute joint's limits in radians; a prismatic one's in metres.
        let (kind, scale, velocity, effort) = if slide {
            (
                "prismatic",
                1e-3,
                UNKNOWN_SLIDE_VELOCITY_M_S,
                UNKNOWN_SLIDE_FORCE_N,
            )
        } else {
            (
                "revolute",
                DEG,
                joint
                    .max_velocity_deg_s
                    .map_or(UNKNOWN_VELOCITY_RAD_S, |v| v * DEG),
                joint.max_torque_nm.unwrap_or(UNKNOWN_EFFORT_NM),
            )
        };
        out.push_str(&format!(
            "  <joint name=\"joint{}\" type=\"{kind}\">\n    <parent link=\"{parent}\"/>\n    <child link=\"link{}\"/>\n    {}\n    <axis xyz=\"0 0 1\"/>\n    <limit lower=\"{}\" upper=\"{}\" effort=\"{effort}\" velocity=\"{velocity}\"/>\n  </joint>\n",
            i + 1,
            i + 1,
            origin(&joint_origin(robot, p, i)),
            lo * scale,
            hi * scale
        ));
    }
    let flange_link = format!("link{}", robot.joint_count());
    for (target, tool) in targets.iter().enumerate() {
        let flange_from_tool = robot.flange_from_tool(p, target);
        fixed_joint(
            &mut out,
            &format!("flange_to_{tool}"),
            &flange_link,
            tool,
            &flange_from_tool,
        );
    }
    out.push_str("</robot>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_names_and_comments() {
        assert_eq!(escape("a<b & \"c\""), "a&lt;b &amp; &quot;c&quot;");
        assert!(!comment_safe("a --- b").contains("--"));
    }
}
