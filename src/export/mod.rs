//! Programs for the robot controller, written from compensated joint commands
//! (`../shared/spec/model.md` §7, the `commands` table): an ABB RAPID module
//! ([`rapid`]), a KUKA KRL pair ([`krl`]), a FANUC TP program ([`fanuc`]), a
//! Yaskawa INFORM job ([`yaskawa`]; both from the list of moves in
//! [`moves`]), a plain CSV ([`csv`]) and a URDF of the calibrated geometry
//! ([`urdf`]).
//!
//! Why a module of its own: the conventions of each controller (ABB's quadrant
//! and `cfx` configuration, KUKA's Status/Turn bits and Z-Y-X Euler angles,
//! URDF's roll-pitch-yaw) are facts about vendors, not about calibration, and
//! each is checked here against fixed hand-computed cases. Knows nothing of
//! tables: the `export_program` stage reads the rows into [`Command`]s.
//!
//! What every file assumes, and says in its header: the controller runs its
//! NOMINAL model, with no vendor accuracy option (ABB Absolute Accuracy, KUKA's
//! absolutely accurate robot) active, because the compensation is already in the
//! numbers — an accuracy option would correct them a second time.
//!
//! What every program declares rather than assumes: the tool its Cartesian
//! targets are poses of (RAPID `PERS tooldata`, KRL `$TOOL`), the robot base as
//! the frame they are in (RAPID `PERS wobjdata`, KRL `$BASE`) and the load
//! (RAPID `tload`, KRL `$LOAD`); every Cartesian move names them, so a program
//! never moves a frame other than the one its targets were computed for
//! ([`cartesian`]).
//!
//! Printed precision (documented in each header and in docs/programs.md): joint angles 6
//! decimals in degrees, positions 4 decimals in mm, quaternions 9 decimals, Euler
//! angles 6 decimals in degrees. The controllers store these as 32-bit floats,
//! so the printed digits are never what limits them.

pub mod cartesian;
pub mod csv;
pub mod fanuc;
pub mod krl;
pub mod moves;
pub mod rapid;
pub mod urdf;
pub mod yaskawa;

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{Frame, MAX_JOINTS, ParamValues, Robot};
pub use cartesian::{Payload, ProgramTool, Stop};

/// Decimals of joint angles (deg) in every file.
pub const JOINT_DECIMALS: usize = 6;
/// Arm joints a controller program carries: RAPID, KRL, FANUC TP and INFORM
/// are written for six-axis controllers (`export_program` writes a
/// seven-joint arm's commands as CSV and URDF only), so a joint vector's first
/// six entries are the program's.
pub const PROGRAM_JOINTS: usize = 6;
/// Decimals of positions (mm).
pub const POSITION_DECIMALS: usize = 4;
/// Decimals of quaternion components.
pub const QUATERNION_DECIMALS: usize = 9;
/// Decimals of Euler angles (deg, KRL A, B, C).
pub const EULER_DECIMALS: usize = 6;
/// Decimals of masses (kg, the tool load).
pub const MASS_DECIMALS: usize = 3;

/// The status of a command a controller may execute.
pub const STATUS_OK: &str = "ok";

/// One row of the `commands` table, as the exporters need it.
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    pub target_id: i64,
    /// Joint command, robot-file convention, degrees.
    pub q_deg: [f64; MAX_JOINTS],
    /// `ok`, or why the compensation failed.
    pub status: String,
    pub residual_mm: f64,
    pub correction_mm: f64,
    pub elastic_mm: f64,
    /// Corrected Cartesian target in the robot base frame (nominal FK of the
    /// command, nominal flange → tool), mm.
    pub position_mm: [f64; 3],
    /// Its orientation, base ← tool, unit quaternion (w, x, y, z).
    pub quaternion_wxyz: [f64; 4],
    /// The target (SMR) whose tool the row was computed for (optional column
    /// `tool_id`); `None` when the table has no such column.
    pub tool_id: Option<String>,
    /// Joint-space distance to the nearest calibration row and the predicted
    /// 95 % uncertainty (spec §8; optional columns, null where not computed).
    pub envelope_distance: Option<f64>,
    pub u95_mm: Option<f64>,
    /// The direction each joint must reach the command from (spec §8 `dir1 …
    /// dir6`, −1, 0 or +1): the one the model's backlash was compensated for;
    /// all 0 when the table has none.
    pub approach: [i8; MAX_JOINTS],
    /// A linear track's carriage position for the command (`e1_mm`, mm):
    /// the programs move it as the first external axis. `None` without a
    /// track.
    pub track_mm: Option<f64>,
    /// The positioner's axis values for the command (`p1_deg`, `p2_deg`,
    /// deg; the robot file's axes, the rest 0): the programs move it with
    /// the arm. `None` when no command of the program moves it.
    pub positioner_deg: Option<[f64; MAX_POSITIONER_AXES]>,
}

impl Command {
    /// Whether the command was compensated for a direction of some joint.
    pub fn has_approach(&self) -> bool {
        self.approach.iter().any(|d| *d != 0)
    }

    pub fn is_ok(&self) -> bool {
        self.status == STATUS_OK
    }
}

/// The header line of a program for a robot on a track: which external
/// axis (`axis`, the format's name and how it is declared) carries the
/// carriage, and the frame the Cartesian positions are in. None without a
/// track.
pub fn track_lines(program: &Program, axis: &str) -> Vec<String> {
    if program.commands.iter().all(|c| c.track_mm.is_none()) {
        return Vec::new();
    }
    vec![
        format!("Track: the carriage is {axis}, in mm, an external axis the arm's kinematics"),
        "do not carry: each Cartesian position is in the base frame riding on the carriage.".into(),
    ]
}

/// The values of a move's external axes in the order RAPID's `eax_a …` and
/// KRL's `E1 …` number them on a controller configured with exactly these
/// axes: the track's carriage (mm) first when the robot rides one, then the
/// positioner's axes (deg) when the program moves it.
pub fn external_axes(
    robot: &Robot,
    track_mm: Option<f64>,
    positioner_deg: Option<[f64; MAX_POSITIONER_AXES]>,
) -> Vec<f64> {
    let axes = positioner_axis_count(robot);
    track_mm
        .into_iter()
        .chain(
            positioner_deg
                .iter()
                .flat_map(|p| p[..axes].iter().copied()),
        )
        .collect()
}

/// How many axes the robot file's positioner has (0 without one).
pub fn positioner_axis_count(robot: &Robot) -> usize {
    robot.spec().positioner.as_ref().map_or(0, |p| p.axes.len())
}

/// The header lines of a program that moves a positioner: which of the
/// format's axes carry it (`axes`, e.g. "eax_a, eax_b (deg)"), and what the
/// Cartesian positions mean with it. None when no command moves it.
pub fn positioner_lines(program: &Program, axes: &str) -> Vec<String> {
    if program.commands.iter().all(|c| c.positioner_deg.is_none()) {
        return Vec::new();
    }
    vec![
        format!("Positioner: its axes are {axes}, moved with the arm but not coordinated:"),
        "each Cartesian position is in the robot base frame with the table at the command's axis"
            .into(),
        "values; a target off the table keeps the table where the move before left it.".into(),
    ]
}

/// What every file's header states besides its format's own lines.
#[derive(Debug, Clone)]
pub struct Provenance {
    /// egcal's version.
    pub version: String,
    /// The commands table's file name and content hash.
    pub source: String,
    /// The robot file's model name.
    pub robot: String,
}

/// Everything a program file is written from, computed once by the stage:
/// the table's rows, the tools, the Cartesian stops of the `ok` rows, and the
/// warnings every file must show.
#[derive(Debug, Clone)]
pub struct Program {
    /// Every row of the table, in order (those not `ok` only named).
    pub commands: Vec<Command>,
    /// The tools the `ok` rows use, in the order their names are numbered.
    pub tools: Vec<ProgramTool>,
    /// One per `ok` row, in order.
    pub stops: Vec<Stop>,
    /// The robot file's payload; `None` when it gives no mass.
    pub payload: Option<Payload>,
    /// Lines every file shows as a warning (and the stage prints).
    pub warnings: Vec<String>,
    pub provenance: Provenance,
}

/// Names of `count` declared tools: `base` for one, `base_1` … for several
/// (at most [`crate::robot::MAX_TARGETS`]).
pub fn tool_names(base: &str, count: usize) -> Vec<String> {
    if count == 1 {
        vec![base.to_string()]
    } else {
        (1..=count).map(|k| format!("{base}_{k}")).collect()
    }
}

/// Header lines naming the declared tools (`names[i]` for `program.tools[i]`)
/// and what the Cartesian targets are.
pub fn tool_lines(program: &Program, names: &[String]) -> Vec<String> {
    let mut lines: Vec<String> = program
        .tools
        .iter()
        .zip(names)
        .map(|(tool, name)| {
            let target = tool
                .target_id
                .as_deref()
                .map(|t| format!(" (target {})", one_line(t)))
                .unwrap_or_default();
            format!(
                "Tool {name}{target}: flange -> tool TCP [{}] mm, orientation [{}] (w, x, y, z), from {}.",
                tool.tcp_mm().map(|v| fixed(v, POSITION_DECIMALS)).join(", "),
                tool.quaternion_wxyz()
                    .map(|v| fixed(v, QUATERNION_DECIMALS))
                    .join(", "),
                one_line(&tool.source)
            )
        })
        .collect();
    lines.push(
        "Every Cartesian target is the pose of its move's tool in the robot BASE frame on the"
            .into(),
    );
    lines.push(
        "NOMINAL arm at the joint command, so the controller's inverse kinematics gives the command back;".into(),
    );
    lines.push("never run them with another tool or base.".into());
    lines
}

/// The warning lines of `program`: each warning prefixed `WARNING: ` and
/// wrapped at word boundaries to at most `WARNING_WIDTH` characters (where
/// a word allows), so that a controller's editor shows it whole.
pub fn warning_lines(program: &Program) -> Vec<String> {
    let mut lines = Vec::new();
    for warning in &program.warnings {
        let mut line = String::from("WARNING:");
        for word in one_line(warning).split_whitespace() {
            if line.len() + 1 + word.len() > WARNING_WIDTH && line.len() > "WARNING:".len() {
                lines.push(std::mem::take(&mut line));
                line.push_str("  ");
                line.push_str(word);
            } else {
                line.push(' ');
                line.push_str(word);
            }
        }
        lines.push(line);
    }
    lines
}

/// Width a warning line is wrapped to, characters.
const WARNING_WIDTH: usize = 96;

/// How the program moves to the targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Motions {
    /// Joint moves to the joint commands (RAPID `MoveAbsJ`, KRL `PTP` E6AXIS): the
    /// controller's inverse kinematics is not involved.
    pub joint: bool,
    /// Cartesian moves to the corrected targets (RAPID `MoveJ` to the first, then
    /// `MoveL`; KRL `PTP` E6POS to the first, then `LIN`): the controller's nominal
    /// inverse kinematics, guided by the configuration, gives back the command.
    pub linear: bool,
}

/// Motion parameters shared by RAPID and KRL.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionSettings {
    /// Program (RAPID module / KRL file) name, a valid identifier for both.
    pub name: String,
    /// TCP speed, mm/s.
    pub speed_mm_s: f64,
    /// Axis speed of joint moves in KRL, percent of the maximum.
    pub joint_speed_percent: f64,
    /// Zone (corner) radius, mm, one of RAPID's predefined zones; `None` =
    /// exact stop (`fine`).
    pub zone_mm: Option<u32>,
    pub motions: Motions,
    /// Approach and retract moves (drilling): the Cartesian path goes to the
    /// point this far back along the tool's z axis before and after each
    /// target, which it then reaches with an exact stop; `None` = off.
    pub approach_mm: Option<f64>,
    /// Pre-positioning (backlash): a joint move to the command minus this
    /// (deg) times each joint's approach direction before every target with
    /// one, so that each joint arrives moving the way the compensation
    /// assumed; `None` = off.
    pub pre_position_deg: Option<f64>,
}

/// The printed precision of RAPID, KRL and the CSV, for [`header_lines`].
pub fn printed_precision() -> String {
    format!(
        "Printed precision: joints {JOINT_DECIMALS} decimals (deg), positions {POSITION_DECIMALS} decimals (mm), quaternions {QUATERNION_DECIMALS} decimals, Euler angles {EULER_DECIMALS} decimals (deg)."
    )
}

/// The header lines every file carries (without comment markers), ending
/// with the file's `precision` line.
pub fn header_lines(provenance: &Provenance, file_kind: &str, precision: String) -> Vec<String> {
    vec![
        format!(
            "{file_kind} generated by egcal {}",
            one_line(&provenance.version)
        ),
        format!("from the commands table {}", one_line(&provenance.source)),
        format!("robot: {}", one_line(&provenance.robot)),
        "Assumes: the controller runs its NOMINAL kinematic model, with no vendor".into(),
        "accuracy option active (ABB Absolute Accuracy, KUKA absolutely accurate robot):".into(),
        "the compensation (geometry and load) is already in these numbers, and an".into(),
        "accuracy option would correct them a second time.".into(),
        precision,
    ]
}

/// Comment lines naming the rows that are not exported as motion.
pub fn skipped_lines(commands: &[Command]) -> Vec<String> {
    let failed: Vec<&Command> = commands.iter().filter(|c| !c.is_ok()).collect();
    if failed.is_empty() {
        return vec!["Every row has status ok; none is left out.".into()];
    }
    let mut lines = vec![format!(
        "{} row(s) not exported as motion (status not ok):",
        failed.len()
    )];
    lines.extend(failed.iter().map(|c| {
        let mut line = format!("  target_id {}: {}", c.target_id, one_line(&c.status));
        let envelope: Vec<String> = [
            ("envelope_distance", c.envelope_distance),
            ("u95_mm", c.u95_mm),
        ]
        .iter()
        .filter_map(|(name, value)| value.map(|v| format!("{name} {v}")))
        .collect();
        if !envelope.is_empty() {
            line.push_str(&format!(" ({})", envelope.join(", ")));
        }
        line
    }));
    lines
}

/// `lines` as remarks for a controller whose comments are short and plain
/// (FANUC `!`, Yaskawa `'`: 32 characters): printable ASCII only (anything
/// else becomes `?`, and each of `forbidden`, which would end the comment,
/// a `,`), wrapped at word boundaries to `width` characters, a longer word
/// cut. A line that starts in lower case continues the sentence before it
/// (the wider formats break sentences at about 90 characters), so it is
/// joined to it before wrapping.
pub fn narrow_comment_lines(lines: &[String], width: usize, forbidden: &[char]) -> Vec<String> {
    let mut paragraphs: Vec<String> = Vec::new();
    for text in lines {
        let continues = text.starts_with(|c: char| c.is_ascii_lowercase() || c == '(');
        match paragraphs.last_mut() {
            Some(last) if continues => {
                last.push(' ');
                last.push_str(text);
            }
            _ => paragraphs.push(text.clone()),
        }
    }
    let mut out = Vec::new();
    for text in &paragraphs {
        let plain: String = one_line(text)
            .chars()
            .map(|c| match c {
                c if forbidden.contains(&c) => ',',
                ' '..='~' => c,
                _ => '?',
            })
            .collect();
        let mut line = String::new();
        for word in plain.split_whitespace() {
            let mut word = word;
            while word.len() > width {
                if !line.is_empty() {
                    out.push(std::mem::take(&mut line));
                }
                out.push(word[..width].to_string());
                word = &word[width..];
            }
            if !line.is_empty() && line.len() + 1 + word.len() > width {
                out.push(std::mem::take(&mut line));
            }
            if !line.is_empty() {
                line.push(' ');
            }
            line.push_str(word);
        }
        if !line.is_empty() {
            out.push(line);
        }
    }
    out
}

/// `text` with line breaks and other control characters as spaces: a table's
/// string (a status, a robot name) must not end a comment line and put the
/// rest of itself into a program as code.
fn one_line(text: &str) -> String {
    text.chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect()
}

/// The largest magnitude of a number a program may print (mm, deg, kg, mm/s):
/// 10 km. Everything the files print is bounded far below it by the checks of
/// the stage's inputs; [`unprintable`] makes sure, so that `inf`, `NaN` or a
/// 301-digit number never reaches a controller.
pub const MAX_PRINTED: f64 = 1e7;

/// The first number the files of `program` would print that is not finite or
/// beyond [`MAX_PRINTED`], described; `None` when every one is printable.
pub fn unprintable(program: &Program, motion: &MotionSettings) -> Option<String> {
    let mut values: Vec<(String, f64)> = vec![
        ("setting `speed_mm_s`".into(), motion.speed_mm_s),
        (
            "setting `joint_speed_percent`".into(),
            motion.joint_speed_percent,
        ),
        (
            "setting `approach_mm`".into(),
            motion.approach_mm.unwrap_or(0.0),
        ),
        (
            "setting `pre_position_deg`".into(),
            motion.pre_position_deg.unwrap_or(0.0),
        ),
    ];
    for c in &program.commands {
        let row = |what: &str| format!("target_id {}: {what}", c.target_id);
        if c.is_ok() {
            values.extend(
                c.q_deg
                    .iter()
                    .enumerate()
                    .map(|(j, v)| (row(&format!("q{}_deg", j + 1)), *v)),
            );
            values.push((row("residual_mm"), c.residual_mm));
            values.push((row("correction_mm"), c.correction_mm));
            values.push((row("elastic_mm"), c.elastic_mm));
        }
        values.extend(c.track_mm.map(|v| (row("e1_mm"), v)));
        values.extend(
            c.positioner_deg
                .iter()
                .flatten()
                .map(|v| (row("positioner axis"), *v)),
        );
        values.extend(c.envelope_distance.map(|v| (row("envelope_distance"), v)));
        values.extend(c.u95_mm.map(|v| (row("u95_mm"), v)));
    }
    for stop in &program.stops {
        let poses = std::iter::once(("target", &stop.target))
            .chain(stop.approach.as_ref().map(|a| ("approach point", a)));
        for (what, pose) in poses {
            let name = format!("target_id {}: {what}", stop.target_id);
            values.extend(pose.position_mm.iter().map(|v| (name.clone(), *v)));
            values.extend(pose.quaternion_wxyz.iter().map(|v| (name.clone(), *v)));
            values.extend(pose.q_deg.iter().map(|v| (name.clone(), *v)));
        }
        if let Some(q) = &stop.pre_position_q_deg {
            let name = format!("target_id {}: pre-position", stop.target_id);
            values.extend(q.iter().map(|v| (name.clone(), *v)));
        }
    }
    for (k, tool) in program.tools.iter().enumerate() {
        let name = format!("tool {}", k + 1);
        values.extend(tool.tcp_mm().iter().map(|v| (name.clone(), *v)));
        values.extend(tool.quaternion_wxyz().iter().map(|v| (name.clone(), *v)));
        if let Some(payload) = &program.payload {
            values.push(("payload mass".into(), payload.mass_kg));
            values.extend(
                payload
                    .cog_in_flange_mm(tool)
                    .iter()
                    .map(|v| ("payload centre of gravity".into(), *v)),
            );
        }
    }
    values
        .into_iter()
        .find(|(_, v)| !v.is_finite() || v.abs() >= MAX_PRINTED)
        .map(|(what, v)| {
            format!(
                "{what} would be printed as {v:e}, beyond what a program may hold ({MAX_PRINTED:e})"
            )
        })
}

/// `value` with `decimals` decimals, never `-0.000`.
pub fn fixed(value: f64, decimals: usize) -> String {
    let text = format!("{value:.decimals$}");
    if text.starts_with('-') && text[1..].chars().all(|c| c == '0' || c == '.') {
        text[1..].to_string()
    } else {
        text
    }
}

/// The rotation of a unit quaternion (w, x, y, z), normalised first.
pub fn rotation_from_quaternion(wxyz: [f64; 4]) -> Matrix3<f64> {
    let [w, x, y, z] = wxyz;
    *UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
        .to_rotation_matrix()
        .matrix()
}

/// Z-Y-X Euler angles (rad) of a rotation: `R = Rot(z, a)·Rot(y, b)·Rot(x, c)`,
/// the convention of KUKA's A, B, C and of URDF's `rpy = (c, b, a)`. `b` lies in
/// [-π/2, π/2]; at `|b| = π/2` (gimbal lock) only `a ∓ c` is defined, and `c = 0`.
///
/// Why not the textbook split (`a = atan2(r10, r00)`, `c = atan2(r21, r22)`,
/// and c = 0 below a lock threshold such as cos b < 1e-12): near gimbal lock
/// (an MDH joint with α = −90° and θ_offset = −90° plus a tiny identified error
/// is one) those four elements are of order cos b, so that threshold moves the
/// rebuilt rotation by up to 1e-12·π rad (5e-9 mm at 1.5 m, more than the URDF
/// may lose), and an absolute rounding error ε in them errs a and c by ε/cos b
/// each. Here `a ∓ c`, the one combination that matters there, comes from
/// elements of order 1:
/// `r12 − r01 = (1 + sin b)·sin(a − c)`, `r11 + r02 = (1 + sin b)·cos(a − c)`,
/// `r12 + r01 = −(1 − sin b)·sin(a + c)`, `r11 − r02 = (1 − sin b)·cos(a + c)`;
/// the error left in the split then moves the rotation by a few ε, and the
/// lock threshold can be 1e-15.
pub fn zyx_angles(r: &Matrix3<f64>) -> [f64; 3] {
    let cos_b = r[(0, 0)].hypot(r[(1, 0)]);
    let b = (-r[(2, 0)]).atan2(cos_b);
    // a − c (b > 0) or a + c (b < 0), from elements of order 1.
    let (combination, sign) = if b >= 0.0 {
        ((r[(1, 2)] - r[(0, 1)]).atan2(r[(1, 1)] + r[(0, 2)]), 1.0)
    } else {
        (
            (-(r[(1, 2)] + r[(0, 1)])).atan2(r[(1, 1)] - r[(0, 2)]),
            -1.0,
        )
    };
    if cos_b < GIMBAL_LOCK_COS {
        return [combination, b, 0.0];
    }
    let a = r[(1, 0)].atan2(r[(0, 0)]);
    // c = a − (a − c), or (a + c) − a.
    [a, b, wrap_pi(sign * (a - combination))]
}

/// Below this cos b, [`zyx_angles`] takes c = 0: the split between a and c then
/// moves the rotation by less than cos b · π, a few ε.
const GIMBAL_LOCK_COS: f64 = 1e-15;

/// An angle (rad) moved by whole turns into (−π, π].
fn wrap_pi(angle: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    if angle > PI {
        angle - TAU
    } else if angle <= -PI {
        angle + TAU
    } else {
        angle
    }
}

/// Where the wrist is, for the configuration flags of ABB and KUKA, on the
/// NOMINAL arm at a joint command (the controller's model decides its
/// configuration). The wrist centre is MDH frame 5's origin: the intersection
/// of axes 4, 5 and 6 on a spherical wrist, a point on axis 5 otherwise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WristPlacement {
    /// x of the wrist centre in the axis-1 coordinate system (the base frame
    /// turned with axis 1): > 0 in front of axis 1, < 0 behind (overhead).
    pub front_of_axis1_mm: f64,
    /// `((o3 − o2) × (w − o3)) · z3`: its sign says on which side of the line
    /// through axes 2 and 3 the wrist centre lies, seen along axis 3; zero when
    /// the arm is stretched (KUKA's A3 = φ).
    pub elbow_mm2: f64,
    /// The same side seen along the axis-1 system's y axis: > 0 when the wrist
    /// centre is in front of the lower arm (ABB's definition).
    pub front_of_lower_arm_mm2: f64,
}

/// [`WristPlacement`] of `robot` at `q_deg`, nominal geometry.
pub fn wrist_placement(robot: &Robot, q_deg: &[f64; MAX_JOINTS]) -> WristPlacement {
    let nominal = ParamValues::nominal(robot.spec());
    let (frames, _) = robot.frames_in_base(&nominal, q_deg);
    let mut at_zero = *q_deg;
    at_zero[0] = 0.0;
    let (frames_zero, _) = robot.frames_in_base(&nominal, &at_zero);
    // Base coordinates of a point as if axis 1 were at zero: the point's
    // coordinates in the axis-1 coordinate system.
    let axis1_system: Frame = frames_zero[1].compose(&frames[1].inverse());
    let in_axis1 = |p: &Vector3<f64>| axis1_system.transform_point(p);
    let o2 = in_axis1(&frames[2].origin_mm);
    let o3 = in_axis1(&frames[3].origin_mm);
    let wrist = in_axis1(&frames[5].origin_mm);
    let z3 = axis1_system.rotation * frames[3].axis(2);
    let lower_arm = o3 - o2;
    WristPlacement {
        front_of_axis1_mm: wrist.x,
        elbow_mm2: lower_arm.cross(&(wrist - o3)).dot(&z3),
        front_of_lower_arm_mm2: Vector3::y().cross(&lower_arm).dot(&(wrist - o2)),
    }
}

/// Whether `name` is an identifier of RAPID and KRL alike: a letter, then
/// letters, digits or underscores, at most `max_len` characters, and not a
/// reserved word of either language. `None` when it is; what is wrong otherwise.
pub fn identifier_problem(name: &str, max_len: usize, language: &str) -> Option<String> {
    let mut chars = name.chars();
    let starts_with_letter = chars.next().is_some_and(|c| c.is_ascii_alphabetic());
    if !starts_with_letter || !chars.all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Some(format!(
            "`{name}` is not a {language} identifier: a letter, then letters, digits or `_`"
        ));
    }
    if name.len() > max_len {
        return Some(format!(
            "`{name}` has {} characters; {language} allows at most {max_len}",
            name.len()
        ));
    }
    let upper = name.to_ascii_uppercase();
    RESERVED
        .contains(&upper.as_str())
        .then(|| format!("`{name}` is a reserved word of RAPID or KRL"))
}

/// Names the programs declare themselves (RAPID's speed data and routines,
/// KRL's base and tool frames).
const GENERATED_NAMES: [&str; 6] = [
    "egcal_speed",
    "main",
    "path_joint",
    "path_linear",
    "xbase",
    "xtool",
];
/// Prefixes of the per-target data names (RAPID `jt_`, `pt_`, `pa_`; KRL `XJ_`,
/// `XP_`, `XA_`) and of several KRL tools (`XTOOL_1`).
const GENERATED_PREFIXES: [&str; 9] = [
    "jt_", "jp_", "pt_", "pa_", "xj_", "xp_", "xa_", "xb_", "xtool_",
];

/// ABB's predefined data (module BASE), which a module cannot declare again,
/// and `tool0`, the flange, which cannot be redefined.
pub const ABB_PREDEFINED: [&str; 3] = ["tool0", "wobj0", "load0"];

/// Whether a user-chosen name (module, tool, work object) would clash with a
/// name the programs declare or ABB predefines: both languages ignore case, and
/// the controller refuses a module that declares a name twice. `None` when it
/// does not.
pub fn generated_name_clash(name: &str) -> Option<String> {
    let lower = name.to_ascii_lowercase();
    if ABB_PREDEFINED.contains(&lower.as_str()) {
        return Some(format!(
            "`{name}` is ABB's predefined data, which a module cannot declare again (tool0 is the bare flange); the program declares its own"
        ));
    }
    if GENERATED_NAMES.contains(&lower.as_str()) {
        return Some(format!("`{name}` is a name the exported programs declare"));
    }
    GENERATED_PREFIXES
        .iter()
        .find(|p| lower.starts_with(*p))
        .map(|p| format!("`{name}` starts with `{p}`, the prefix of the exported target data"))
}

/// Reserved words of RAPID and KRL that a program, tool or work-object name
/// could plausibly collide with.
const RESERVED: &[&str] = &[
    "AND",
    "BACKWARD",
    "CASE",
    "CONNECT",
    "CONST",
    "DEFAULT",
    "DIV",
    "DO",
    "ELSE",
    "ELSEIF",
    "ENDFOR",
    "ENDFUNC",
    "ENDIF",
    "ENDMODULE",
    "ENDPROC",
    "ENDRECORD",
    "ENDTEST",
    "ENDTRAP",
    "ENDWHILE",
    "ERROR",
    "EXIT",
    "FALSE",
    "FOR",
    "FROM",
    "FUNC",
    "GOTO",
    "IF",
    "INOUT",
    "LOCAL",
    "MOD",
    "MODULE",
    "NOSTEPIN",
    "NOT",
    "NOVIEW",
    "OR",
    "PERS",
    "PROC",
    "RAISE",
    "READONLY",
    "RECORD",
    "RETRY",
    "RETURN",
    "STEP",
    "SYSMODULE",
    "TASK",
    "TEST",
    "THEN",
    "TO",
    "TRAP",
    "TRUE",
    "TRYNEXT",
    "UNDO",
    "VAR",
    "VIEWONLY",
    "WHILE",
    "WITH",
    "XOR",
    "DEF",
    "DEFFCT",
    "DEFDAT",
    "END",
    "ENDFCT",
    "ENDDAT",
    "DECL",
    "GLOBAL",
    "PUBLIC",
    "PTP",
    "LIN",
    "CIRC",
    "PTP_REL",
    "LIN_REL",
    "CONTINUE",
    "HALT",
    "WAIT",
    "SEC",
    "LOOP",
    "ENDLOOP",
    "REPEAT",
    "UNTIL",
    "SWITCH",
    "ENDSWITCH",
    "INT",
    "REAL",
    "BOOL",
    "CHAR",
    "STRUC",
    "ENUM",
    "SIGNAL",
    "INTERRUPT",
    "TRIGGER",
    "ANIN",
    "ANOUT",
    "BRAKE",
    "RESUME",
    "IMPORT",
    "IS",
    "EXT",
    "EXTFCT",
];

/// Programs of a few rows for the format modules' tests.
#[cfg(test)]
pub(crate) mod test_support {
    use super::*;

    pub fn motion(zone_mm: Option<u32>, approach_mm: Option<f64>) -> MotionSettings {
        MotionSettings {
            name: "EGCAL_PROGRAM".into(),
            speed_mm_s: 100.0,
            joint_speed_percent: 20.0,
            zone_mm,
            motions: Motions {
                joint: true,
                linear: true,
            },
            approach_mm,
            pre_position_deg: None,
        }
    }

    /// `ok` rows with `ids` at one joint command, the IRB 1600's nominal tool
    /// (22, 50, 150) mm.
    pub fn program(
        robot: &Robot,
        ids: &[i64],
        approach_mm: Option<f64>,
        payload: Option<Payload>,
    ) -> Program {
        let commands: Vec<Command> = ids
            .iter()
            .map(|&target_id| Command {
                target_id,
                q_deg: [10.0, 20.0, -30.0, 40.0, 50.0, 60.0, 0.0],
                status: STATUS_OK.into(),
                residual_mm: 0.0,
                correction_mm: 0.0,
                elastic_mm: 0.0,
                position_mm: [900.0, 0.0, 800.0],
                quaternion_wxyz: [1.0, 0.0, 0.0, 0.0],
                tool_id: None,
                envelope_distance: None,
                u95_mm: None,
                approach: [0; MAX_JOINTS],
                track_mm: None,
                positioner_deg: None,
            })
            .collect();
        let tool = ProgramTool {
            target_id: None,
            source: "the robot file's [tool]".into(),
            flange_from_tool: Frame {
                rotation: Matrix3::identity(),
                origin_mm: Vector3::new(22.0, 50.0, 150.0),
            },
        };
        let row_tools = vec![0; commands.len()];
        let stops = cartesian::stops(
            robot,
            &commands,
            std::slice::from_ref(&tool),
            &row_tools,
            approach_mm,
            None,
        )
        .unwrap();
        Program {
            commands,
            tools: vec![tool],
            stops,
            payload,
            warnings: Vec::new(),
            provenance: Provenance {
                version: "0".into(),
                source: "commands.parquet".into(),
                robot: "r".into(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::frame::{rot_x, rot_y, rot_z};
    use crate::robot::test_support::irb1600;

    const DEG: f64 = std::f64::consts::PI / 180.0;

    #[test]
    fn an_unprintable_number_is_found_wherever_it_is() {
        let robot = irb1600();
        let motion = test_support::motion(None, None);
        let good = test_support::program(&robot, &[1, 2], None, None);
        assert_eq!(unprintable(&good, &motion), None);
        let mut bad = good.clone();
        bad.commands[1].residual_mm = 1e300;
        let problem = unprintable(&bad, &motion).unwrap();
        assert!(
            problem.contains("target_id 2: residual_mm") && problem.contains("1e300"),
            "{problem}"
        );
        let mut bad = good.clone();
        bad.stops[0].target.position_mm[2] = f64::NAN;
        assert!(
            unprintable(&bad, &motion)
                .unwrap()
                .contains("target_id 1: target")
        );
        let mut bad = good.clone();
        bad.tools[0].flange_from_tool.origin_mm.x = f64::INFINITY;
        assert!(unprintable(&bad, &motion).unwrap().contains("tool 1"));
        let mut fast = test_support::motion(None, None);
        fast.speed_mm_s = f64::NAN;
        assert!(unprintable(&good, &fast).unwrap().contains("speed_mm_s"));
    }

    #[test]
    fn zyx_angles_of_fixed_rotations() {
        // 90° about z: quaternion (cos 45°, 0, 0, sin 45°), A = 90, B = C = 0.
        let h = (45.0 * DEG).cos();
        let r = rotation_from_quaternion([h, 0.0, 0.0, h]);
        let [a, b, c] = zyx_angles(&r);
        assert!((a - 90.0 * DEG).abs() < 1e-12 && b.abs() < 1e-12 && c.abs() < 1e-12);
        // 30° about y: (cos 15°, 0, sin 15°, 0) → B = 30.
        let r = rotation_from_quaternion([(15.0 * DEG).cos(), 0.0, (15.0 * DEG).sin(), 0.0]);
        let [a, b, c] = zyx_angles(&r);
        assert!(a.abs() < 1e-12 && (b - 30.0 * DEG).abs() < 1e-12 && c.abs() < 1e-12);
        // Composite: Rot(z, 30)·Rot(y, 20)·Rot(x, 10) gives them back.
        let r = rot_z(30.0 * DEG) * rot_y(20.0 * DEG) * rot_x(10.0 * DEG);
        let [a, b, c] = zyx_angles(&r);
        assert!((a - 30.0 * DEG).abs() < 1e-12);
        assert!((b - 20.0 * DEG).abs() < 1e-12);
        assert!((c - 10.0 * DEG).abs() < 1e-12);
    }

    #[test]
    fn zyx_angles_at_gimbal_lock_rebuild_the_rotation() {
        for b in [90.0, -90.0] {
            let r = rot_z(40.0 * DEG) * rot_y(b * DEG) * rot_x(15.0 * DEG);
            let [a2, b2, c2] = zyx_angles(&r);
            assert_eq!(c2, 0.0);
            let back = rot_z(a2) * rot_y(b2) * rot_x(c2);
            assert!((back - r).norm() < 1e-9, "{b}");
        }
    }

    #[test]
    fn zyx_angles_near_gimbal_lock_rebuild_the_rotation_to_rounding() {
        // The MDH joint 2 of an IRB-like arm, α = −90°, θ_offset = −90°, with
        // identified errors from tiny to none.
        for error_deg in [1e-1, 1e-4, 1e-7, 1e-9, 1e-12, 0.0] {
            for (alpha, theta) in [(-90.0, -90.0), (90.0, -90.0), (-90.0, 90.0)] {
                let r = rot_x((alpha + error_deg) * DEG) * rot_z((theta - error_deg) * DEG);
                let [a, b, c] = zyx_angles(&r);
                let back = rot_z(a) * rot_y(b) * rot_x(c);
                let worst = (back - r).abs().max();
                assert!(worst < 1e-15, "{alpha} {theta} {error_deg}: {worst:e}");
            }
        }
        // Direct: b a hair away from ±90°.
        for (cos_b, sign) in [(1e-5, 1.0), (1e-10, 1.0), (1e-13, -1.0), (1e-10, -1.0)] {
            let b = sign * (std::f64::consts::FRAC_PI_2 - cos_b);
            let r = rot_z(2.5) * rot_y(b) * rot_x(-1.2);
            let [a2, b2, c2] = zyx_angles(&r);
            let back = rot_z(a2) * rot_y(b2) * rot_x(c2);
            assert!((back - r).abs().max() < 1e-15, "{cos_b} {sign}");
            assert!(c2.abs() <= std::f64::consts::PI);
        }
    }

    #[test]
    fn comment_text_stays_on_one_line() {
        let command = Command {
            target_id: 3,
            q_deg: [0.0; MAX_JOINTS],
            status: "unreachable\nMoveAbsJ jt_1".into(),
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
        };
        let lines = skipped_lines(std::slice::from_ref(&command));
        assert_eq!(lines[1], "  target_id 3: unreachable MoveAbsJ jt_1");
        let outside = Command {
            status: "outside_envelope".into(),
            envelope_distance: Some(2.5),
            u95_mm: Some(0.75),
            ..command
        };
        let lines = skipped_lines(std::slice::from_ref(&outside));
        assert_eq!(
            lines[1],
            "  target_id 3: outside_envelope (envelope_distance 2.5, u95_mm 0.75)"
        );
    }

    #[test]
    fn warnings_are_wrapped_whole() {
        let mut program = test_support::program(&irb1600(), &[1], None, None);
        let words: Vec<String> = (0..60).map(|k| format!("w{k}")).collect();
        program.warnings = vec![words.join(" ")];
        let lines = warning_lines(&program);
        assert!(lines.len() > 1 && lines.iter().all(|l| l.len() <= WARNING_WIDTH));
        assert!(lines[0].starts_with("WARNING: w0 w1"));
        assert!(lines[1..].iter().all(|l| l.starts_with("  w")));
        let back: Vec<&str> = lines.iter().flat_map(|l| l.split_whitespace()).collect();
        assert_eq!(
            back[1..],
            words.iter().map(String::as_str).collect::<Vec<_>>()[..]
        );
    }

    #[test]
    fn fixed_never_prints_negative_zero() {
        assert_eq!(fixed(-0.00001, 4), "0.0000");
        assert_eq!(fixed(-1.5, 1), "-1.5");
        assert_eq!(fixed(2.0, 2), "2.00");
    }

    #[test]
    fn wrist_placement_of_the_irb1600_home_and_flipped_arm() {
        let robot = irb1600();
        // Zero: lower arm up, upper arm forward, wrist 150 + 600 mm in front.
        let home = wrist_placement(&robot, &[0.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0]);
        assert!((home.front_of_axis1_mm - 750.0).abs() < 1e-9, "{home:?}");
        assert!(home.front_of_lower_arm_mm2 > 0.0);
        // Axis 1 turned: the axis-1 system turns with it.
        let turned = wrist_placement(&robot, &[120.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0]);
        assert!((turned.front_of_axis1_mm - 750.0).abs() < 1e-9);
        // Upper arm folded back over the lower arm (q3 = -180): wrist behind it.
        let folded = wrist_placement(&robot, &[0.0, 0.0, -180.0, 0.0, 30.0, 0.0, 0.0]);
        assert!(folded.front_of_lower_arm_mm2 < 0.0, "{folded:?}");
        assert!((folded.front_of_axis1_mm - (150.0 - 600.0)).abs() < 1e-9);
    }

    #[test]
    fn narrow_comments_join_sentences_wrap_and_stay_plain_ascii() {
        let lines = [
            "Assumes: the controller runs its NOMINAL model, with no".to_string(),
            "accuracy option; a µm matters.".into(),
            "WARNING: 0123456789012345678901234567890123456789".into(),
        ];
        let narrow = narrow_comment_lines(&lines, 20, &[';']);
        assert_eq!(
            narrow,
            [
                "Assumes: the",
                "controller runs its",
                "NOMINAL model, with",
                "no accuracy option,",
                "a ?m matters.",
                "WARNING:",
                "01234567890123456789",
                "01234567890123456789",
            ]
        );
    }

    #[test]
    fn identifiers_are_checked() {
        assert!(identifier_problem("EGCAL_PROGRAM", 24, "KRL").is_none());
        assert!(identifier_problem("1abc", 32, "RAPID").is_some());
        assert!(identifier_problem("a-b", 32, "RAPID").is_some());
        assert!(identifier_problem(&"a".repeat(25), 24, "KRL").is_some());
        assert!(identifier_problem("module", 32, "RAPID").is_some());
        assert!(identifier_problem("", 32, "RAPID").is_some());
        assert!(generated_name_clash("egcal_tool").is_none());
        assert!(generated_name_clash("tool0").is_some());
        assert!(generated_name_clash("WOBJ0").is_some());
        assert!(generated_name_clash("XA_3").is_some());
        assert!(generated_name_clash("Main").is_some());
        assert!(generated_name_clash("EGCAL_SPEED").is_some());
        assert!(generated_name_clash("XP_7").is_some());
    }
}
