//! Plain CSV of the commands a controller may execute (status `ok`): a header
//! line and one line per row, nothing else, so that any CSV reader takes it as
//! it is; in the `commands` table's column order and names, then the optional
//! columns the table had (`tool_id`, `envelope_distance`, `u95_mm`). What every
//! exported file says in its header (provenance, assumptions, the tool the
//! Cartesian columns are poses of, the rows left out) goes to the notes file
//! beside it ([`notes`], `commands.csv.txt`).
//!
//! `x_cmd_mm … qz_cmd` are the programs' Cartesian targets: the pose of the
//! notes' tool at the joint command on the nominal arm (see
//! [`super::cartesian`]); they equal the table's when the table was computed
//! for that tool, and the notes warn when it was not.

use super::{
    JOINT_DECIMALS, POSITION_DECIMALS, Program, QUATERNION_DECIMALS, fixed, header_lines,
    skipped_lines, tool_lines, warning_lines,
};

/// Column names, as in the `commands` table.
const COLUMNS: &str = "target_id,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,status,residual_mm,correction_mm,elastic_mm,x_cmd_mm,y_cmd_mm,z_cmd_mm,qw_cmd,qx_cmd,qy_cmd,qz_cmd";

/// Decimals of the diagnostic distances (residual, correction, elastic part), mm.
const DIAGNOSTIC_DECIMALS: usize = 6;

/// Name of the notes file written beside the CSV.
pub const NOTES_FILE: &str = "commands.csv.txt";

/// Which optional columns the CSV carries: those the table had.
struct Optional {
    tool_id: bool,
    envelope_distance: bool,
    u95_mm: bool,
}

impl Optional {
    fn of(program: &Program) -> Self {
        let any = |f: &dyn Fn(&super::Command) -> bool| program.commands.iter().any(f);
        Optional {
            tool_id: any(&|c| c.tool_id.is_some()),
            envelope_distance: any(&|c| c.envelope_distance.is_some()),
            u95_mm: any(&|c| c.u95_mm.is_some()),
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
pub fn table(program: &Program) -> String {
    let optional = Optional::of(program);
    let mut out = String::from(COLUMNS);
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
    out.push('\n');
    let ok = program.commands.iter().filter(|c| c.is_ok());
    for (c, stop) in ok.zip(&program.stops) {
        let mut fields = vec![c.target_id.to_string()];
        fields.extend(c.q_deg.iter().map(|v| fixed(*v, JOINT_DECIMALS)));
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
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    out
}

/// The notes file: what the CSV is, its tool, and the rows it leaves out.
pub fn notes(program: &Program) -> String {
    // The CSV declares no names; a tool is told apart by its target.
    let names = vec!["of the Cartesian columns".to_string(); program.tools.len()];
    let mut lines = header_lines(&program.provenance, "commands.csv");
    lines.extend([
        "commands.csv is plain CSV: a header line, then one line per row with status ok.".into(),
        "Columns as in the commands table (units in their names); x_cmd_mm, y_cmd_mm, z_cmd_mm and".into(),
        "qw_cmd, qx_cmd, qy_cmd, qz_cmd (unit quaternion, base <- tool) are the programs' Cartesian".into(),
        "targets, for the tool below.".into(),
    ]);
    lines.extend(tool_lines(program, &names));
    lines.extend(warning_lines(program));
    lines.extend(skipped_lines(&program.commands));
    let mut out = lines.join("\n");
    out.push('\n');
    out
}
