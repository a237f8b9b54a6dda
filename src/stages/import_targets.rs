//! `import_targets`: a CSV or Parquet file of tool poses as the `targets` table
//! (spec §7, §8) a `compensate` stage reads, for targets written by hand, by a
//! CAD/CAM export or by a tracker's software rather than by egcal.
//!
//! It reads the file like `import_measurements` reads a tracker export (same
//! settings for the file's layout: `separator`, `decimal_comma`, `skip_rows`,
//! `has_header`, a byte-order mark and CRLF line ends read as usual; the shared
//! reader is `import_source`): `columns` maps each contract column to a source
//! column, `constant` gives `frame` or `tool_id` for every row, and units are
//! converted here, at this one boundary: lengths m → mm, orientation and hint
//! angles rad → deg, moments N·mm → N·m.
//!
//! Required: `x_mm, y_mm, z_mm, rx_deg, ry_deg, rz_deg` (every row needs them).
//! Optional, empty cells null: the wrench (null is no load), the branch hint
//! `q1_deg … q6_deg` (all six or none mapped, and `q7_deg` with them for a
//! seven-joint arm; a row with some cells empty is refused by `compensate`,
//! naming it), `frame` and `tool_id`, and a linear
//! track's carriage position `e1_mm` (in `length_unit`; when mapped, every
//! row needs one, and `compensate` checks it against the robot file's
//! travel). `target_id` (whole numbers, unique) defaults to the 0-based
//! data row number.
//!
//! Frame names are checked by the `compensate` stage that reads the table,
//! since the user frames are its settings. The file's content hash is part of
//! the cache key ([`Stage::external_key`]), as for `import_measurements`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use polars::prelude::{Column, DataFrame};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::import_source::{
    CsvLayout, FileSettings, ForceUnit, JointConvention, JointUnit, Kind, LengthUnit, Mapped,
    MomentUnit, Source, SourceFormat, SourceUnits, cannot_read, column_map_problems, read_source,
};
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, settings_error,
};
use crate::table::schema;

pub struct ImportTargetsStage;

/// Which source column holds each `targets` column. Required: `x_mm, y_mm,
/// z_mm, rx_deg, ry_deg, rz_deg`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TargetColumns {
    /// Target id (whole numbers, unique); when absent, the 0-based data row number.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_id: Option<String>,
    /// Tool point in the row's frame (`length_unit`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_mm: Option<String>,
    /// Tool orientation: frame←tool = Rot(x, rx)·Rot(y, ry)·Rot(z, rz) (`angle_unit`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rx_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ry_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rz_deg: Option<String>,
    /// Wrench on the robot at the target, tool axes, at the tool origin: null
    /// (no load) where not mapped or empty.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fx_n: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fy_n: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fz_n: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mx_nm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub my_nm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mz_nm: Option<String>,
    /// Branch hint (`joint_unit`): all six or none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q1_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q2_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q3_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q4_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q5_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q6_deg: Option<String>,
    /// A seven-joint arm's seventh hint joint: with the six, for such an arm
    /// only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q7_deg: Option<String>,
    /// The row's frame: world, base or a user frame of the compensate stage.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<String>,
    /// The parameters' target (SMR nest, tool) the row aims.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tool_id: Option<String>,
    /// A linear track's carriage position to reach the target from
    /// (`length_unit`; the robot file's `[track]` then needs it on every row).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e1_mm: Option<String>,
    /// The positioner's first axis for a target on its table (robot file
    /// `[positioner]`, frame `positioner`), in `joint_unit`; empty cells
    /// for targets off the table.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p1_deg: Option<String>,
    /// The positioner's second axis, as `p1_deg`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p2_deg: Option<String>,
}

impl TargetColumns {
    fn get(&self, contract: &str) -> Option<&str> {
        let value = match contract {
            "target_id" => &self.target_id,
            "x_mm" => &self.x_mm,
            "y_mm" => &self.y_mm,
            "z_mm" => &self.z_mm,
            "rx_deg" => &self.rx_deg,
            "ry_deg" => &self.ry_deg,
            "rz_deg" => &self.rz_deg,
            "fx_n" => &self.fx_n,
            "fy_n" => &self.fy_n,
            "fz_n" => &self.fz_n,
            "mx_nm" => &self.mx_nm,
            "my_nm" => &self.my_nm,
            "mz_nm" => &self.mz_nm,
            "q1_deg" => &self.q1_deg,
            "q2_deg" => &self.q2_deg,
            "q3_deg" => &self.q3_deg,
            "q4_deg" => &self.q4_deg,
            "q5_deg" => &self.q5_deg,
            "q6_deg" => &self.q6_deg,
            "q7_deg" => &self.q7_deg,
            "frame" => &self.frame,
            "tool_id" => &self.tool_id,
            "e1_mm" => &self.e1_mm,
            "p1_deg" => &self.p1_deg,
            "p2_deg" => &self.p2_deg,
            _ => &None,
        };
        value.as_deref()
    }
}

/// Values on every row instead of a source column.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TargetConstants {
    /// The frame of every row (else the compensate stage's `frame` setting).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<String>,
    /// The tool of every row (else the compensate stage's `tool` setting).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tool_id: Option<String>,
}

/// Settings of `import_targets`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ImportTargetsSettings {
    /// The file, relative to the job file's folder.
    pub path: String,
    /// csv or parquet; when absent, parquet for a `.parquet` or `.pq` file, else csv.
    pub format: Option<SourceFormat>,
    /// CSV field separator: one character, e.g. "," or ";" or "\t".
    pub separator: String,
    /// CSV numbers use a decimal comma (`1,5`); needs a separator other than ",".
    pub decimal_comma: bool,
    /// CSV lines to skip before the header (a preamble).
    #[schemars(range(min = 0, max = 1_000_000_000))]
    pub skip_rows: usize,
    /// The CSV's first (unskipped) line names the columns; without a header the
    /// source columns are `column_1`, `column_2`, …
    pub has_header: bool,
    /// Contract column → source column.
    pub columns: TargetColumns,
    /// Contract column → value on every row (frame, tool_id).
    pub constant: TargetConstants,
    /// Unit of the position columns in the source: mm or m.
    pub length_unit: LengthUnit,
    /// Unit of the orientation columns in the source: deg or rad.
    pub angle_unit: JointUnit,
    /// Unit of the branch-hint joint columns in the source: deg or rad.
    pub joint_unit: JointUnit,
    /// Whose joint values the branch hints are: `robot_file` (the default)
    /// or `controller` (the robot file's `[controller]`, a FANUC's J3 from
    /// the horizontal), converted to the robot file's on import.
    pub joint_convention: JointConvention,
    /// Unit of the force columns in the source: N only.
    pub force_unit: ForceUnit,
    /// Unit of the moment columns in the source: N·m (also N*m, Nm) or N·mm (also N*mm, Nmm).
    pub moment_unit: MomentUnit,
}

impl Default for ImportTargetsSettings {
    fn default() -> Self {
        ImportTargetsSettings {
            path: String::new(),
            format: None,
            separator: ",".into(),
            decimal_comma: false,
            skip_rows: 0,
            has_header: true,
            columns: TargetColumns::default(),
            constant: TargetConstants::default(),
            length_unit: LengthUnit::Mm,
            angle_unit: JointUnit::Deg,
            joint_unit: JointUnit::Deg,
            joint_convention: JointConvention::RobotFile,
            force_unit: ForceUnit::Newton,
            moment_unit: MomentUnit::NewtonMetre,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "import_targets",
    uses_cable_robot: false,
    updates_input: None,
    summary: "A file of tool poses (CSV or Parquet) as the targets table for compensate, units converted",
    code_version: 4,
    inputs: &[],
    outputs: &[TableSlot {
        name: "targets",
        schema: schema::targets,
        required: true,
        meaning: "the file's rows, in file order",
    }],
};

/// Every contract column, in output order.
const CONTRACT: [(&str, Kind); 25] = [
    ("target_id", Kind::Integer),
    ("x_mm", Kind::Position),
    ("y_mm", Kind::Position),
    ("z_mm", Kind::Position),
    ("rx_deg", Kind::Angle),
    ("ry_deg", Kind::Angle),
    ("rz_deg", Kind::Angle),
    ("fx_n", Kind::Force),
    ("fy_n", Kind::Force),
    ("fz_n", Kind::Force),
    ("mx_nm", Kind::Moment),
    ("my_nm", Kind::Moment),
    ("mz_nm", Kind::Moment),
    ("q1_deg", Kind::Joint),
    ("q2_deg", Kind::Joint),
    ("q3_deg", Kind::Joint),
    ("q4_deg", Kind::Joint),
    ("q5_deg", Kind::Joint),
    ("q6_deg", Kind::Joint),
    ("q7_deg", Kind::Joint),
    ("frame", Kind::Text),
    ("tool_id", Kind::Text),
    ("e1_mm", Kind::Position),
    ("p1_deg", Kind::Joint),
    ("p2_deg", Kind::Joint),
];

/// The branch hint against the robot file's joint count: `columns.q7_deg`
/// mapped for a six-joint arm, or a seven-joint arm's hint without it.
fn seven_joint_hint_problem(
    columns: &TargetColumns,
    robot: &crate::robot::RobotSpec,
) -> Option<SettingsProblem> {
    let joints = robot.joints.len();
    let seventh = columns.q7_deg.is_some();
    let hinted = columns.q1_deg.is_some();
    let prismatic = robot
        .joints
        .iter()
        .position(|j| j.kind == crate::robot::file::JointKind::Prismatic);
    if let Some(joint) = prismatic.filter(|_| hinted || seventh) {
        return Some(SettingsProblem::new(
            "columns.q1_deg",
            format!(
                "the robot file {} has a prismatic joint (joint {}): a branch hint maps joint angles only; leave `columns.q1_deg` … out (compensate then seeds from the nominal solution)",
                robot.path.display(),
                joint + 1
            ),
        ));
    }
    let message = if seventh && joints <= 6 {
        format!(
            "the robot file {} has {joints} joints: a hint has no seventh joint (remove the key)",
            robot.path.display()
        )
    } else if hinted && !seventh && joints > 6 {
        format!(
            "the robot file {} has {joints} joints: its branch hint needs `columns.q7_deg` with the six others",
            robot.path.display()
        )
    } else {
        return None;
    };
    Some(SettingsProblem::new("columns.q7_deg", message))
}

const REQUIRED: [&str; 6] = ["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"];

/// The settings resolved against the job folder.
#[derive(Debug)]
struct Checked {
    file: PathBuf,
    format: SourceFormat,
    layout: CsvLayout,
    mapped: Vec<Mapped>,
}

impl ImportTargetsSettings {
    /// Every problem with the settings, by key; reads nothing.
    fn check(&self, job_dir: &Path) -> Result<Checked, Vec<SettingsProblem>> {
        let mut problems = Vec::new();
        let (file, format, layout) = FileSettings {
            path: &self.path,
            format: self.format,
            separator: &self.separator,
            decimal_comma: self.decimal_comma,
            skip_rows: self.skip_rows,
            has_header: self.has_header,
            units: SourceUnits {
                joint: self.joint_unit,
                angle: self.angle_unit,
                length: self.length_unit,
                moment: self.moment_unit,
            },
        }
        .check(job_dir, &mut problems);
        column_map_problems(
            |key| self.columns.get(key),
            &REQUIRED,
            CONTRACT.iter().copied(),
            &mut problems,
        );
        let hints = schema::JOINT_COLUMNS.map(|c| self.columns.get(c).is_some());
        if hints.contains(&true) && hints.contains(&false) {
            problems.push(SettingsProblem::new(
                "columns.q1_deg",
                "the branch hint `columns.q1_deg` … `columns.q6_deg`: map all six or none",
            ));
        }
        if self.columns.q7_deg.is_some() && !hints.contains(&true) {
            problems.push(SettingsProblem::new(
                "columns.q7_deg",
                "a seventh joint's hint comes with the six others (`columns.q1_deg` … `columns.q6_deg`)",
            ));
        }
        for (key, constant) in [
            ("frame", self.constant.frame.as_deref()),
            ("tool_id", self.constant.tool_id.as_deref()),
        ] {
            if constant.is_some_and(|c| c.trim().is_empty()) {
                problems.push(SettingsProblem::new(
                    &format!("constant.{key}"),
                    "must not be empty",
                ));
            }
            if constant.is_some() && self.columns.get(key).is_some() {
                problems.push(SettingsProblem::new(
                    &format!("constant.{key}"),
                    format!("`columns.{key}` and `constant.{key}` are both set: choose one"),
                ));
            }
        }
        if !problems.is_empty() {
            return Err(problems);
        }
        let mapped = CONTRACT
            .iter()
            .filter_map(|(contract, kind)| {
                self.columns.get(contract).map(|source| Mapped {
                    contract,
                    kind: *kind,
                    source: source.to_string(),
                })
            })
            .collect();
        Ok(Checked {
            file,
            format,
            layout,
            mapped,
        })
    }

    /// The factor from the source unit of `kind` to the contract's unit.
    fn factor(&self, kind: Kind) -> f64 {
        let angle = |unit: JointUnit| match unit {
            JointUnit::Deg => 1.0,
            JointUnit::Rad => 180.0 / std::f64::consts::PI,
        };
        match kind {
            Kind::Angle | Kind::AngleSigma => angle(self.angle_unit),
            Kind::Joint => angle(self.joint_unit),
            Kind::Position | Kind::Sigma => match self.length_unit {
                LengthUnit::Mm => 1.0,
                LengthUnit::M => 1000.0,
            },
            Kind::Moment => match self.moment_unit {
                MomentUnit::NewtonMetre => 1.0,
                MomentUnit::NewtonMillimetre => 1e-3,
            },
            Kind::Force | Kind::Integer | Kind::Text | Kind::Time => 1.0,
        }
    }
}

impl Stage for ImportTargetsStage {
    type Settings = ImportTargetsSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn external_key(
        &self,
        settings: &ImportTargetsSettings,
        job_dir: &Path,
        _run_date: i64,
    ) -> Result<serde_json::Value, StageError> {
        let checked = settings.check(job_dir).map_err(|p| settings_error(&p))?;
        let hash =
            crate::fsio::hash_file(&checked.file).map_err(|e| cannot_read(&checked.file, e))?;
        Ok(serde_json::json!({ "source_blake3": hash }))
    }

    fn check_settings(
        &self,
        settings: &ImportTargetsSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems = settings.check(ctx.job_dir).err().unwrap_or_default();
        problems.extend(seven_joint_hint_problem(&settings.columns, ctx.robot));
        problems
    }

    /// The file read, converted and checked as `run` does it.
    fn check_sources(
        &self,
        settings: &ImportTargetsSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        match import(settings, ctx.job_dir) {
            Ok(_) => Vec::new(),
            Err(e) => vec![SettingsProblem::new("path", e.to_string())],
        }
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &ImportTargetsSettings,
    ) -> Result<StageOutputs, StageError> {
        let (mut targets, source_blake3, notes) = import(settings, ctx.job_dir)?;
        super::import_source::joints_to_robot_file(
            &mut targets,
            settings.joint_convention,
            ctx.robot.spec(),
            &ctx.job_dir.join(&settings.path),
        )?;
        for note in &notes {
            ctx.progress.note(note);
        }
        let mut outputs = StageOutputs::default();
        outputs
            .facts
            .insert("imported_rows".into(), targets.height().to_string());
        outputs.facts.insert("source".into(), settings.path.clone());
        outputs.facts.insert("source_blake3".into(), source_blake3);
        outputs.tables.insert("targets".into(), targets);
        Ok(outputs)
    }
}

/// Reads, converts and checks the file the settings name (relative paths
/// against `job_dir`): the targets table, the file's content hash and the
/// warnings about the file.
fn import(
    settings: &ImportTargetsSettings,
    job_dir: &Path,
) -> Result<(DataFrame, String, Vec<String>), StageError> {
    let checked = settings.check(job_dir).map_err(|p| settings_error(&p))?;
    let bytes = std::fs::read(&checked.file).map_err(|e| cannot_read(&checked.file, e))?;
    let source = read_source(
        &checked.file,
        checked.format,
        &checked.layout,
        &checked.mapped,
        &bytes,
        "every target needs one",
    )?;
    source.check_columns(&checked.mapped)?;
    if source.height() == 0 {
        return Err(StageError::Invalid(format!(
            "{}: no data rows (a header only?): at least one target is needed",
            checked.file.display()
        )));
    }
    let targets = build(&source, &checked.mapped, settings)?;
    schema::targets().check(&targets, &checked.file)?;
    Ok((
        targets,
        blake3::hash(&bytes).to_hex().to_string(),
        source.notes.clone(),
    ))
}

/// The targets table from every row of the source, contract columns in order.
fn build(
    source: &Source,
    mapped: &[Mapped],
    settings: &ImportTargetsSettings,
) -> Result<DataFrame, StageError> {
    let rows = 0..source.height();
    let n = rows.len();
    let find = |contract: &str| mapped.iter().find(|m| m.contract == contract);
    let mut columns = Vec::new();
    let ids: Vec<i64> = match find("target_id") {
        Some(m) => {
            let ids = source.integers(m, rows.clone())?;
            let mut first = HashMap::with_capacity(n);
            for (row, id) in ids.iter().enumerate() {
                if let Some(earlier) = first.insert(*id, row) {
                    return Err(source.problem(
                        row,
                        m,
                        format!(
                            "target_id {id} repeats the one on {}; it must be unique",
                            source.at(earlier)
                        ),
                    ));
                }
            }
            ids
        }
        None => rows.clone().map(|r| r as i64).collect(),
    };
    columns.push(Column::new("target_id".into(), ids));
    for (name, kind) in &CONTRACT[1..19] {
        let Some(m) = find(name) else { continue };
        let factor = settings.factor(*kind);
        if REQUIRED.contains(name) {
            let values: Vec<f64> = source
                .floats(m, rows.clone())?
                .into_iter()
                .map(|v| v * factor)
                .collect();
            columns.push(Column::new((*name).into(), values));
        } else {
            let values: Vec<Option<f64>> = source
                .optional_floats(m, rows.clone())?
                .into_iter()
                .map(|v| v.map(|v| v * factor))
                .collect();
            columns.push(Column::new((*name).into(), values));
        }
    }
    for (name, constant) in [
        ("frame", settings.constant.frame.as_ref()),
        ("tool_id", settings.constant.tool_id.as_ref()),
    ] {
        if let Some(m) = find(name) {
            columns.push(Column::new(
                name.into(),
                source.optional_texts(m, rows.clone())?,
            ));
        } else if let Some(value) = constant {
            columns.push(Column::new(name.into(), vec![value.trim().to_string(); n]));
        }
    }
    if let Some(m) = find("e1_mm") {
        let factor = settings.factor(Kind::Position);
        let values: Vec<f64> = source
            .floats(m, rows.clone())?
            .into_iter()
            .map(|v| v * factor)
            .collect();
        columns.push(Column::new(schema::TRACK_COLUMN.into(), values));
    }
    for name in schema::POSITIONER_COLUMNS {
        if let Some(m) = find(name) {
            let factor = settings.factor(Kind::Joint);
            let values: Vec<Option<f64>> = source
                .optional_floats(m, rows.clone())?
                .into_iter()
                .map(|v| v.map(|v| v * factor))
                .collect();
            columns.push(Column::new(name.into(), values));
        }
    }
    Ok(crate::table::frame(columns))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(toml: &str) -> ImportTargetsSettings {
        toml::from_str(toml).unwrap()
    }

    const POSE: &str = r#"
separator = ";"
decimal_comma = true
length_unit = "m"
angle_unit = "rad"
[columns]
target_id = "id"
x_mm = "x"
y_mm = "y"
z_mm = "z"
rx_deg = "a"
ry_deg = "b"
rz_deg = "c"
fz_n = "force"
frame = "in"
"#;

    #[test]
    fn a_carriage_column_is_read_in_the_length_unit_and_needed_on_every_row() {
        let dir = tempfile::tempdir().unwrap();
        let with_track = format!("path = \"t.csv\"\n{POSE}e1_mm = \"rail\"\n");
        std::fs::write(
            dir.path().join("t.csv"),
            "id;x;y;z;a;b;c;force;in;rail\n7;0,9;0;1;0;0;0;;;1,5\n8;1;0;1;0;0;0;;;0,25\n",
        )
        .unwrap();
        let (df, _, _) = import(&settings(&with_track), dir.path()).unwrap();
        assert_eq!(
            schema::f64_values(&df, "e1_mm", Path::new("t")).unwrap(),
            [1500.0, 250.0]
        );
        std::fs::write(
            dir.path().join("t.csv"),
            "id;x;y;z;a;b;c;force;in;rail\n7;0,9;0;1;0;0;0;;;1,5\n8;1;0;1;0;0;0;;;\n",
        )
        .unwrap();
        let err = import(&settings(&with_track), dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("line 3") && err.contains("columns.e1_mm") && err.contains("empty cell"),
            "{err}"
        );
    }

    #[test]
    fn positioner_axes_are_read_in_the_joint_unit_and_may_be_empty() {
        let dir = tempfile::tempdir().unwrap();
        let toml = format!(
            "path = \"t.csv\"\njoint_unit = \"rad\"\n{POSE}p1_deg = \"tilt\"\np2_deg = \"turn\"\n"
        );
        std::fs::write(
            dir.path().join("t.csv"),
            "id;x;y;z;a;b;c;force;in;tilt;turn\n7;0,9;0;1;0;0;0;;positioner;0,5;-1\n8;1;0;1;0;0;0;;;;\n",
        )
        .unwrap();
        let (df, _, _) = import(&settings(&toml), dir.path()).unwrap();
        let p1 = df.column("p1_deg").unwrap().f64().unwrap().clone();
        assert!((p1.get(0).unwrap() - 0.5_f64.to_degrees()).abs() < 1e-12);
        assert_eq!(p1.get(1), None);
    }

    #[test]
    fn a_csv_with_a_bom_crlf_and_decimal_commas_is_read_in_contract_units() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("t.csv"),
            "\u{feff}id;x;y;z;a;b;c;force;in\r\n\
             7;0,9;-0,1;1,25;3,141592653589793;0;0;-100;base\r\n\
             8;1;0;1;0;0;1,5707963267948966;;\r\n",
        )
        .unwrap();
        let (df, _, _) =
            import(&settings(&format!("path = \"t.csv\"\n{POSE}")), dir.path()).unwrap();
        let f = |c: &str| {
            df.column(c)
                .unwrap()
                .f64()
                .unwrap()
                .iter()
                .collect::<Vec<_>>()
        };
        assert_eq!(
            schema::i64_values(&df, "target_id", Path::new("t")).unwrap(),
            [7, 8]
        );
        assert_eq!(f("x_mm"), [Some(900.0), Some(1000.0)]);
        assert!((f("rx_deg")[0].unwrap() - 180.0).abs() < 1e-12);
        assert!((f("rz_deg")[1].unwrap() - 90.0).abs() < 1e-12);
        // An empty optional cell is null: no load, the stage's frame.
        assert_eq!(f("fz_n"), [Some(-100.0), None]);
        assert_eq!(
            schema::str_values(&df, "frame", Path::new("t")).unwrap(),
            [Some("base".to_string()), None]
        );
        schema::targets().check(&df, Path::new("t")).unwrap();
    }

    #[test]
    fn a_bad_cell_is_named_by_line_column_and_setting() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("t.csv"),
            "id;x;y;z;a;b;c;force;in\n1;1;2;3;0;0;0;;\n2;1;two;3;0;0;0;;\n",
        )
        .unwrap();
        let message = import(&settings(&format!("path = \"t.csv\"\n{POSE}")), dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("line 3, column `y` (setting `columns.y_mm`): `two` is not a number"),
            "{message}"
        );
        std::fs::write(
            dir.path().join("t.csv"),
            "id;x;y;z;a;b;c;force;in\n1;1;2;3;0;0;0;;\n2;1;;3;0;0;0;;\n",
        )
        .unwrap();
        let message = import(&settings(&format!("path = \"t.csv\"\n{POSE}")), dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("line 3, column `y` (setting `columns.y_mm`): empty cell, expected a number (every target needs one)"),
            "{message}"
        );
    }

    #[test]
    fn missing_required_columns_and_half_a_hint_are_settings_problems() {
        let problems = settings("path = \"t.csv\"\n[columns]\nx_mm = \"x\"\nq1_deg = \"j1\"\n")
            .check(Path::new("."))
            .unwrap_err();
        let keys: Vec<&str> = problems.iter().map(|p| p.key.as_str()).collect();
        for key in ["columns.y_mm", "columns.rz_deg", "columns.q1_deg"] {
            assert!(keys.contains(&key), "{keys:?}");
        }
    }
}
