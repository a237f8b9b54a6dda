//! Plain CSV of the commands a controller may execute (status `ok`): a header
//! line and one line per row, nothing else, so that any CSV reader takes it as
//! it is; in the `commands` table's column order and names, then the optional
//! columns the table had (`tool_id`, `envelope_distance`, `u95_mm`, `dir1 …
//! dir6`), and `pre_q1_deg … pre_q6_deg`, the configuration to move to before
//! the row (empty where none), when the program pre-positions (a seven-joint
//! arm adds `q7_deg`, `dir7` and `pre_q7_deg` after each sixth); `e1_mm` on a
//! track and `p1_deg`, `p2_deg` when the program moves a positioner (a row
//! off the table repeats where the table stands). What every
//! exported file says in its header (provenance, assumptions, the tool the
//! Cartesian columns are poses of, the rows left out) goes to the notes file
//! beside it ([`notes`], `commands.csv.txt`).
//!
//! `x_cmd_mm … qz_cmd` are the programs' Cartesian targets: the pose of the
//! notes' tool at the joint command on the nominal arm (see
//! [`super::cartesian`]); they equal the table's when the table was computed
//! for that tool, and the notes warn when it was not.

use crate::robot::Robot;
use crate::table::schema::{POSITIONER_COLUMNS, joint_column_names};

use super::{
    JOINT_DECIMALS, POSITION_DECIMALS, Program, QUATERNION_DECIMALS, fixed, header_lines,
    positioner_axis_count, positioner_lines, printed_precision, skipped_lines, tool_lines,
    track_lines, warning_lines,
};

/// Column names after the joints', as in the `commands` table.
const COLUMNS_AFTER_JOINTS: &str = "status,residual_mm,correction_mm,elastic_mm,x_cmd_mm,y_cmd_mm,z_cmd_mm,qw_cmd,qx_cmd,qy_cmd,qz_cmd";

/// Decimals of the diagnostic distances (residual, correction, elastic part), mm.
const DIAGNOSTIC_DECIMALS: usize = 6;

/// Name of the notes file written beside the CSV.
pub const NOTES_FILE: &str = "commands.csv.txt";

/// Which optional columns the CSV carries: those the table had.
struct Optional {
    tool_id: bool,
    envelope_distance: bool,
    u95_mm: bool,
    approach: bool,
    pre_position: bool,
    track: bool,
    /// How many positioner axis columns: the robot file's axes when the
    /// program moves the positioner, else 0.
    positioner_axes: usize,
}

impl Optional {
    fn of(robot: &Robot, program: &Program) -> Self {
        let any = |f: &dyn Fn(&super::Command) -> bool| program.commands.iter().any(f);
        Optional {
            tool_id: any(&|c| c.tool_id.is_some()),
            envelope_distance: any(&|c| c.envelope_distance.is_some()),
            u95_mm: any(&|c| c.u95_mm.is_some()),
            approach: any(&|c| c.has_approach()),
            pre_position: program.stops.iter().any(|s| s.pre_position_q_deg.is_some()),
            track: any(&|c| c.track_mm.is_some()),
            positioner_axes: if any(&|c| c.positioner_deg.is_some()) {
                positioner_axis_count(robot)
            } else {
                0
            },
        }
    }
}

/// A CSV field: quoted (with quotes doubled) when it holds a comma, a quote or a
/// line break.
fn field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// The CSV text: header line, then the `ok` rows.
pub fn table(robot: &Robot, program: &Program) -> String {
    let optional = Optional::of(robot, program);
    // The arm's joints: `q1_deg … q6_deg`, and `q7_deg` (`dir7`, `pre_q7_deg`)
    // for a seventh.
    let joints = robot.joint_count();
    let joint_names = joint_column_names(robot.spec());
    let mut out = format!("target_id,{},{COLUMNS_AFTER_JOINTS}", joint_names.join(","));
    for (present, name) in [
        (optional.tool_id, "tool_id"),
        (optional.envelope_distance, "envelope_distance"),
        (optional.u95_mm, "u95_mm"),
    ] {
        if present {
            out.push(',');
            out.push_str(name);
        }
    }
    if optional.approach {
        for joint in 1..=joints {
            out.push_str(&format!(",dir{joint}"));
        }
    }
    if optional.pre_position {
        for name in joint_names {
            out.push_str(&format!(",pre_{name}"));
        }
    }
    if optional.track {
        out.push_str(",e1_mm");
    }
    for name in &POSITIONER_COLUMNS[..optional.positioner_axes] {
        out.push(',');
        out.push_str(name);
    }
    out.push('\n');
    let ok = program.commands.iter().filter(|c| c.is_ok());
    for (c, stop) in ok.zip(&program.stops) {
        let mut fields = vec![c.target_id.to_string()];
        fields.extend(c.q_deg[..joints].iter().map(|v| fixed(*v, JOINT_DECIMALS)));
        fields.push(field(&c.status));
        fields.extend(
            [c.residual_mm, c.correction_mm, c.elastic_mm]
                .iter()
                .map(|v| fixed(*v, DIAGNOSTIC_DECIMALS)),
        );
        fields.extend(
            stop.target
                .position_mm
                .iter()
                .map(|v| fixed(*v, POSITION_DECIMALS)),
        );
        fields.extend(
            stop.target
                .quaternion_wxyz
                .iter()
                .map(|v| fixed(*v, QUATERNION_DECIMALS)),
        );
        if optional.tool_id {
            fields.push(field(c.tool_id.as_deref().unwrap_or_default()));
        }
        // Empty for a null, as CSV readers read a missing value.
        let number = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
        if optional.envelope_distance {
            fields.push(number(c.envelope_distance));
        }
        if optional.u95_mm {
            fields.push(number(c.u95_mm));
        }
        if optional.approach {
            fields.extend(c.approach[..joints].iter().map(i8::to_string));
        }
        if optional.pre_position {
            match &stop.pre_position_q_deg {
                Some(q) => fields.extend(q[..joints].iter().map(|v| fixed(*v, JOINT_DECIMALS))),
                None => fields.extend(std::iter::repeat_n(String::new(), joints)),
            }
        }
        if optional.track {
            fields.push(number(c.track_mm));
        }
        if let Some(p_deg) = c.positioner_deg {
            fields.extend(
                p_deg[..optional.positioner_axes]
                    .iter()
                    .map(|v| fixed(*v, JOINT_DECIMALS)),
            );
        }
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    out
}

/// The notes file: what the CSV is, its tool, and the rows it leaves out.
pub fn notes(robot: &Robot, program: &Program) -> String {
    // The CSV declares no names; a tool is told apart by its target.
    let names = vec!["of the Cartesian columns".to_string(); program.tools.len()];
    let mut lines = header_lines(&program.provenance, "commands.csv", printed_precision());
    lines.extend([
        "commands.csv is plain CSV: a header line, then one line per row with status ok.".into(),
        "Columns as in the commands table (units in their names); x_cmd_mm, y_cmd_mm, z_cmd_mm and".into(),
        "qw_cmd, qx_cmd, qy_cmd, qz_cmd (unit quaternion, base <- tool) are the programs' Cartesian".into(),
        "targets, for the tool below.".into(),
    ]);
    lines.extend(tool_lines(program, &names));
    lines.extend(track_lines(program, "column e1_mm"));
    lines.extend(positioner_lines(
        program,
        &format!(
            "columns {} (deg)",
            POSITIONER_COLUMNS[..positioner_axis_count(robot)].join(", ")
        ),
    ));
    lines.extend(warning_lines(program));
    lines.extend(skipped_lines(&program.commands));
    let mut out = lines.join("\n");
    out.push('\n');
    out
}
