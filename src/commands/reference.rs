//! The reference generated from the code: `egcal list-stages`, and the user
//! guide's pages of stage kinds and tables (`docs/reference/stages.md`,
//! `tables.md`). Both read the stage registry and the table schemas, so the
//! guide cannot disagree with what the parser accepts and the stages write;
//! `tests/schemas.rs` fails when the committed pages are stale.

use std::fmt::Write as _;

use crate::robot::params::{ParamId, ParamKind};
use crate::stages::{self, StageKind};
use crate::table;

/// One setting of a stage kind: its key (`simulator.noise_mm` for a nested
/// one), default (JSON) and description with its range.
struct SettingRow {
    key: String,
    default: serde_json::Value,
    description: String,
}

/// The settings of `kind`, in the schema's order.
fn setting_rows(kind: &dyn StageKind) -> Vec<SettingRow> {
    let schema = kind.settings_schema();
    let mut rows = Vec::new();
    collect_settings(&mut rows, &schema, &schema, &kind.defaults(), "");
    rows
}

/// A nested settings struct (`simulator`) lists its own settings as
/// `simulator.<name>`.
fn collect_settings(
    rows: &mut Vec<SettingRow>,
    schema: &serde_json::Value,
    root: &serde_json::Value,
    defaults: &serde_json::Value,
    prefix: &str,
) {
    let Some(props) = schema["properties"].as_object() else {
        return;
    };
    for (name, prop) in props {
        let key = format!("{prefix}{name}");
        let nested = prop["$ref"]
            .as_str()
            .and_then(|r| r.strip_prefix('#'))
            .and_then(|pointer| root.pointer(pointer))
            .filter(|s| s["properties"].is_object());
        if let Some(nested) = nested {
            collect_settings(rows, nested, root, &defaults[name], &format!("{key}."));
            continue;
        }
        let description = prop["description"]
            .as_str()
            .unwrap_or("")
            .replace('\n', " ");
        let range = stages::settings_check::range_text(prop, root)
            .map(|r| format!(" Range: {r}."))
            .unwrap_or_default();
        rows.push(SettingRow {
            key,
            default: defaults[name].clone(),
            description: format!("{description}{range}"),
        });
    }
}

/// `egcal list-stages`: every kind with inputs, outputs and settings with defaults.
pub fn list_stages() -> String {
    let mut out = String::new();
    for kind in stages::registry() {
        let info = kind.info();
        writeln!(
            out,
            "{} (code version {}): {}",
            info.kind, info.code_version, info.summary
        )
        .expect("write");
        for slot in info.inputs {
            let req = if slot.required {
                "required"
            } else {
                "optional"
            };
            writeln!(
                out,
                "  input  {:<16} {} table, {req}: {}",
                slot.name,
                (slot.schema)().kind,
                slot.meaning
            )
            .expect("write");
        }
        for slot in info.outputs {
            writeln!(
                out,
                "  output {:<16} {} table: {}",
                slot.name,
                (slot.schema)().kind,
                slot.meaning
            )
            .expect("write");
        }
        for row in setting_rows(kind) {
            writeln!(
                out,
                "  set    {:<16} = {:<12} {}",
                row.key, row.default, row.description
            )
            .expect("write");
        }
        out.push('\n');
    }
    out
}

/// Text for a Markdown table cell: no line breaks, `|` escaped, and in the
/// user's words (see [`without_spec_citations`]).
fn cell(text: &str) -> String {
    without_spec_citations(text)
        .replace('\n', " ")
        .replace('|', "\\|")
}

/// `text` without its citations of the model spec's sections (`spec §8`,
/// `(spec §7, §8: …)`): the code's strings cite the spec for its engineers,
/// but the guide's reader has no spec, and the guide says the same in its
/// own pages.
fn without_spec_citations(text: &str) -> String {
    const MARK: &str = "spec §";
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(MARK) {
        let (before, from) = rest.split_at(at);
        // The citation: `spec §N`, then any `, §M`.
        let mut end = MARK.len() + section_len(&from[MARK.len()..]);
        while from[end..].starts_with(", §") {
            end += ", §".len() + section_len(&from[end + ", §".len()..]);
        }
        let after = &from[end..];
        let opened = before.ends_with('(');
        if opened && after.starts_with(')') {
            // ` (spec §8)`: the whole parenthesis goes.
            out.push_str(before[..before.len() - 1].trim_end());
            rest = &after[1..];
        } else if opened {
            // `(spec §8: text)`: the parenthesis keeps its text.
            out.push_str(before);
            rest = after
                .strip_prefix(": ")
                .or_else(|| after.strip_prefix(", "))
                .or_else(|| after.strip_prefix("; "))
                .or_else(|| after.strip_prefix(' '))
                .unwrap_or(after);
        } else if let Some(kept) = before
            .strip_suffix("; ")
            .or_else(|| before.strip_suffix(", "))
        {
            // `(text; spec §8)`.
            out.push_str(kept);
            rest = after;
        } else if let Some(kept) = before.strip_suffix(" from ") {
            // `parameter name from spec §4`: the names are the guide's own.
            out.push_str(kept);
            rest = after;
        } else {
            out.push_str(before);
            rest = after.strip_prefix("; ").unwrap_or(after);
        }
    }
    out.push_str(rest);
    out
}

/// Length of a section number such as `8` or `4b`.
fn section_len(text: &str) -> usize {
    text.find(|c: char| !c.is_ascii_alphanumeric())
        .unwrap_or(text.len())
}

/// `docs/reference/stages.md`: every stage kind, its tables and settings.
fn stages_page() -> String {
    let mut out = String::from(
        "# Stage kinds\n\n\
         Generated from the code by `egcal schemas --out schemas --guide docs/reference`\n\
         (the same source as `egcal list-stages` and `schemas/job.schema.json`); do\n\
         not edit by hand. A job file's stage names its kind with `kind = \"…\"`, binds\n\
         its inputs with `inputs = { name = \"stage\" }` (or `\"stage.table\"`, or a\n\
         Parquet path or glob), and sets any of the settings below as further keys.\n\
         The tables' columns are in [Tables](tables.md).\n\n",
    );
    for kind in stages::registry() {
        let info = kind.info();
        writeln!(out, "## `{}`\n\n{}\n", info.kind, cell(info.summary)).expect("write");
        if !info.inputs.is_empty() {
            out.push_str("| input | table | | meaning |\n|---|---|---|---|\n");
            for slot in info.inputs {
                let table_kind = (slot.schema)().kind;
                writeln!(
                    out,
                    "| `{}` | [`{table_kind}`](tables.md#{table_kind}) | {} | {} |",
                    slot.name,
                    if slot.required {
                        "required"
                    } else {
                        "optional"
                    },
                    cell(slot.meaning)
                )
                .expect("write");
            }
            out.push('\n');
        }
        out.push_str("| output | table | meaning |\n|---|---|---|\n");
        for slot in info.outputs {
            let table_kind = (slot.schema)().kind;
            writeln!(
                out,
                "| `{}` | [`{table_kind}`](tables.md#{table_kind}) | {} |",
                slot.name,
                cell(slot.meaning)
            )
            .expect("write");
        }
        out.push('\n');
        let rows = setting_rows(kind);
        if !rows.is_empty() {
            out.push_str("| setting | default | meaning |\n|---|---|---|\n");
            for row in rows {
                writeln!(
                    out,
                    "| `{}` | `{}` | {} |",
                    row.key,
                    cell(&row.default.to_string()),
                    cell(&row.description)
                )
                .expect("write");
            }
            out.push('\n');
        }
    }
    out
}

/// `docs/reference/tables.md`: every table kind's columns, units and meaning.
fn tables_page() -> String {
    let mut out = String::from(
        "# Tables\n\n\
         Generated from the code by `egcal schemas --out schemas --guide docs/reference`\n\
         (the same source as `schemas/tables/*.json` and the checks every stage makes\n\
         of its inputs); do not edit by hand. Every table is a Parquet file. A stage\n\
         checks each input table before it runs: a missing required column, a column\n\
         of another type, a null, NaN or infinity where a value is required, or a\n\
         repeated id ends the run with the file, the column and the first bad row.\n\
         Columns a table does not list are kept where a stage passes rows on, and\n\
         ignored otherwise. Every file egcal writes also carries its provenance (job,\n\
         stage, cache key, input hashes, version) in the Parquet key-value metadata\n\
         under `egcal.provenance`; `egcal show FILE` prints it.\n\n",
    );
    out.push_str(
        "## The parameters\n\n\
         The `parameters` table names each parameter as below; a robot with several\n\
         SMR nests has one tool translation per nest (`x_t[nest2]`), a seventh joint\n\
         adds `dtheta7 … k7`, and the model ladder, a track and a positioner add\n\
         their own terms. A prismatic joint's compliance is in mm/N.\n\n\
         | parameter | unit | meaning |\n|---|---|---|\n",
    );
    for id in ParamId::all() {
        writeln!(
            out,
            "| `{}` | {} | {} |",
            id.name(),
            id.unit(),
            parameter_meaning(id)
        )
        .expect("write");
    }
    out.push('\n');
    let mut schemas = table::schema::all();
    schemas.sort_by_key(|s| s.kind);
    for schema in schemas {
        writeln!(out, "## {}\n\n{}\n", schema.kind, cell(schema.description)).expect("write");
        if let Some(unique) = schema.unique {
            writeln!(out, "`{unique}` is unique.\n").expect("write");
        }
        out.push_str("| column | type | unit | | meaning |\n|---|---|---|---|---|\n");
        for column in &schema.columns {
            let dtype = serde_json::to_value(column.dtype)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default();
            let alternative = column
                .alternative
                .map(|a| format!(" (or `{a}`)"))
                .unwrap_or_default();
            writeln!(
                out,
                "| `{}`{alternative} | {dtype} | {} | {} | {} |",
                column.name,
                cell(column.unit),
                if column.required {
                    "required"
                } else {
                    "optional"
                },
                cell(column.meaning)
            )
            .expect("write");
        }
        out.push('\n');
    }
    out
}

/// What a parameter of the 42 is, in words.
fn parameter_meaning(id: ParamId) -> String {
    const AXES: [&str; 3] = ["x", "y", "z"];
    match id.kind() {
        ParamKind::WorldTranslation(axis) => format!(
            "tracker ← base translation along {} (applied after the rotation)",
            AXES[axis]
        ),
        ParamKind::WorldRotation(axis) => {
            format!("tracker ← base rotation about {}", AXES[axis])
        }
        ParamKind::ToolTranslation { axis, .. } => {
            format!("flange → tool (SMR) translation along {}", AXES[axis])
        }
        ParamKind::ToolRotation(axis) => format!("flange → tool rotation about {}", AXES[axis]),
        ParamKind::Theta(joint) => format!("error of joint {}'s zero (θ offset)", joint + 1),
        ParamKind::Alpha(joint) => format!("error of joint {}'s twist α", joint + 1),
        ParamKind::A(joint) => format!("error of joint {}'s length a", joint + 1),
        ParamKind::D(joint) => format!("error of joint {}'s offset d", joint + 1),
        ParamKind::Compliance(joint) => format!(
            "compliance of joint {}: its deflection per unit of the torque it carries",
            joint + 1
        ),
        _ => String::new(),
    }
}

/// The guide's generated pages: (file name in `docs/reference/`, content).
pub fn generated_guide_pages() -> Vec<(String, String)> {
    vec![
        ("stages.md".to_string(), stages_page()),
        ("tables.md".to_string(), tables_page()),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_citations_leave_the_words_around_them() {
        assert_eq!(without_spec_citations("rows (spec §6). Next"), "rows. Next");
        assert_eq!(
            without_spec_citations("rows (spec §8: `rx_deg`)"),
            "rows (`rx_deg`)"
        );
        assert_eq!(without_spec_citations("be (spec §7, §8): x"), "be: x");
        assert_eq!(without_spec_citations("(`held`, spec §8) a"), "(`held`) a");
        assert_eq!(without_spec_citations("name from spec §4"), "name");
        assert_eq!(
            without_spec_citations("work (spec §7 targets)"),
            "work (targets)"
        );
        assert_eq!(without_spec_citations("no citation"), "no citation");
    }
}
