//! Plain CSV of the commands a controller may execute (status `ok`), in the
//! `commands` table's column order and names, after `#` comment lines with the
//! header every exported file carries (read with e.g. `pandas.read_csv(path,
//! comment="#")`). Rows whose status is not `ok` are named in the comment only.

use super::{
    Command, JOINT_DECIMALS, POSITION_DECIMALS, Provenance, QUATERNION_DECIMALS, fixed,
    header_lines, skipped_lines,
};

/// Column names, as in the `commands` table.
const COLUMNS: &str = "target_id,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,status,residual_mm,correction_mm,elastic_mm,x_cmd_mm,y_cmd_mm,z_cmd_mm,qw_cmd,qx_cmd,qy_cmd,qz_cmd";

/// Decimals of the diagnostic distances (residual, correction, elastic part), mm.
const DIAGNOSTIC_DECIMALS: usize = 6;

/// The CSV text.
pub fn table(commands: &[Command], provenance: &Provenance) -> String {
    let mut out = String::new();
    for text in header_lines(provenance, "CSV of joint commands")
        .iter()
        .chain(&skipped_lines(commands))
    {
        out.push_str(&format!("# {text}\n"));
    }
    out.push_str(COLUMNS);
    out.push('\n');
    for c in commands.iter().filter(|c| c.is_ok()) {
        let mut fields = vec![c.target_id.to_string()];
        fields.extend(c.q_deg.iter().map(|v| fixed(*v, JOINT_DECIMALS)));
        fields.push(c.status.clone());
        fields.extend(
            [c.residual_mm, c.correction_mm, c.elastic_mm]
                .iter()
                .map(|v| fixed(*v, DIAGNOSTIC_DECIMALS)),
        );
        fields.extend(c.position_mm.iter().map(|v| fixed(*v, POSITION_DECIMALS)));
        fields.extend(
            c.quaternion_wxyz
                .iter()
                .map(|v| fixed(*v, QUATERNION_DECIMALS)),
        );
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    out
}
