//! `import_measurements`: a tracker software's export (CSV or Parquet) as the
//! `measurements` table (spec §6, §7), for calibrating on data egcal did not
//! measure itself.
//!
//! The settings name the file (relative to the job file's folder) and map each
//! contract column to a source column (`columns.q1_deg = "shoulder_pan_joint"`);
//! `constant` gives fixed values (`constant.target_id = "nest1"`). Source units
//! are converted here, at this one boundary: joints rad → deg, lengths and
//! sigmas m → mm, moments N·mm → N·m, orientation angles and their sigmas
//! (6-D rows, spec §8) rad → deg. Wrench columns that are not mapped are 0
//! (no load). Extra source columns are not carried.
//!
//! The CSV is parsed by polars' reader (its `decimal_comma` option for `1,5`),
//! twice: once with every column as text (the names, and the raw cell for
//! messages) and once with the mapped columns typed, bad cells read as null.
//! A null is then explained from the raw text: every problem names the file,
//! the line (data row + header + skipped lines, 1-based), the source column, the
//! setting and what was expected. Measurements hold complete rows only, so an
//! empty, non-numeric or non-finite cell in a mapped column is bad input, as are
//! a repeated `cw_id`, a sigma that is not positive or absurd, and an
//! orientation angle beyond ±360°. Line numbers assume one
//! line per row (no line breaks inside quoted fields).
//!
//! The stage has no input tables: the file's content hash is part of its cache
//! key ([`Stage::external_key`], as `scan_logs` keys its log files), so an edited
//! export re-runs the stage and an unchanged one does not.

use std::collections::{BTreeMap, HashMap};
use std::ops::Range;
use std::path::{Path, PathBuf};

use polars::prelude::{Column, DataFrame, DataType, TimeUnit, TimeZone};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::import_source::{
    CsvLayout, FileSettings, Kind, Mapped, Source, SourceUnits, cannot_read, column_map_problems,
    read_source,
};
pub use super::import_source::{
    ForceUnit, JointConvention, JointUnit, LengthUnit, MomentUnit, SourceFormat,
};
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, settings_error,
};
use crate::calibration::row_checks::{
    MAX_ANGLE_DEG, MAX_SIGMA_DEG, MAX_SIGMA_MM, MIN_SIGMA_DEG, MIN_SIGMA_MM,
};
use crate::table::schema;

pub struct ImportMeasurementsStage;

/// Which source column holds each contract column. Required: the robot
/// file's joint columns (`q1_deg … q6_deg`; `q7_deg` for a seventh joint; a
/// prismatic joint's `q{i}_mm` in place of its `q{i}_deg`), `x_mm`, `y_mm`,
/// `z_mm`. The names are the contract's; the units of the source are those of
/// `joint_unit` (angles), `length_unit` (positions, a prismatic joint's
/// travel), `force_unit`, `moment_unit`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ColumnMap {
    /// Row id (whole numbers, unique); when absent, the 0-based data row number.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cw_id: Option<String>,
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
    /// A seven-joint robot file's seventh joint.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q7_deg: Option<String>,
    /// A prismatic joint's travel (in `length_unit`), in place of its
    /// `q{i}_deg`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q1_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q2_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q3_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q4_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q5_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q6_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q7_mm: Option<String>,
    /// Wrench on the robot, tool axes, at the tool origin: 0 where not mapped.
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
    /// SMR position in the tracker frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_mm: Option<String>,
    /// The tracker's 1-σ uncertainty per axis (> 0): all three or none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_x_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_y_mm: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_z_mm: Option<String>,
    /// A 6-D probe's tool orientation (spec §8), tracker frame:
    /// world←tool = Rot(x, rx)·Rot(y, ry)·Rot(z, rz) (`angle_unit`); all three or none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rx_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ry_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rz_deg: Option<String>,
    /// Their 1-σ uncertainties (> 0, `angle_unit`): all three or none, and only with the angles.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_rx_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_ry_deg: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_rz_deg: Option<String>,
    /// The direction each joint last moved before the reading (spec §8):
    /// −1, 0 (not known) or +1; for models with backlash.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dir1: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dir2: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dir3: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dir4: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dir5: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dir6: Option<String>,
    /// The carriage's position on the robot's linear track (robot file
    /// `[track]`), in `length_unit`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e1_mm: Option<String>,
    /// The positioner's first axis (robot file `[positioner]`), in
    /// `joint_unit`, on every row.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p1_deg: Option<String>,
    /// The positioner's second axis, in `joint_unit`, on every row.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p2_deg: Option<String>,
    /// Which SMR (nest) each row measured: a long table, one row per target reading.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_id: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub config_id: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot_id: Option<String>,
    /// Time of the reading: RFC 3339 UTC text (`2026-03-02T10:00:00Z`) in a CSV; a
    /// timestamp or such text in Parquet.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_at: Option<String>,
}

/// Values that are the same on every row (instead of a source column).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Constants {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_id: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot_id: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 0))]
    pub config_id: Option<i64>,
}

/// Settings of `import_measurements`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ImportMeasurementsSettings {
    /// The export file, relative to the job file's folder.
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
    pub columns: ColumnMap,
    /// Contract column → value on every row (target_id, robot_id, config_id).
    pub constant: Constants,
    /// Unit of the joint columns in the source: deg or rad.
    pub joint_unit: JointUnit,
    /// Whose joint values the source holds: `robot_file` (the default), or
    /// `controller` when they are the controller's as the robot file's
    /// `[controller]` describes them (a FANUC's J3, measured from the
    /// horizontal); those are converted to the robot file's on import.
    pub joint_convention: JointConvention,
    /// Unit of positions and sigmas in the source: mm or m.
    pub length_unit: LengthUnit,
    /// Unit of the force columns in the source: N only.
    pub force_unit: ForceUnit,
    /// Unit of the moment columns in the source: N·m (also N*m, Nm) or N·mm (also N*mm, Nmm).
    pub moment_unit: MomentUnit,
    /// Unit of the orientation columns and their sigmas in the source: deg or rad.
    pub angle_unit: JointUnit,
    /// Import only data rows start ≤ row < end (0-based, half-open), e.g. half of a
    /// series; the default cw_id stays the row's number in the whole file.
    #[schemars(inner(range(min = 0, max = 1_000_000_000)))]
    pub row_range: Option<[usize; 2]>,
}

impl Default for ImportMeasurementsSettings {
    fn default() -> Self {
        ImportMeasurementsSettings {
            path: String::new(),
            format: None,
            separator: ",".into(),
            decimal_comma: false,
            skip_rows: 0,
            has_header: true,
            columns: ColumnMap::default(),
            constant: Constants::default(),
            joint_unit: JointUnit::Deg,
            joint_convention: JointConvention::RobotFile,
            length_unit: LengthUnit::Mm,
            force_unit: ForceUnit::Newton,
            moment_unit: MomentUnit::NewtonMetre,
            angle_unit: JointUnit::Deg,
            row_range: None,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "import_measurements",
    uses_cable_robot: false,
    updates_input: None,
    summary: "A tracker export (CSV or Parquet) as the measurements table, units converted",
    code_version: 5,
    inputs: &[],
    outputs: &[TableSlot {
        name: "measurements",
        schema: schema::measurements,
        required: true,
        meaning: "the file's rows (or row_range of them), in file order",
    }],
};

/// Every contract column a source column can be mapped to, in output order.
const CONTRACT: [(&str, Kind); 46] = [
    ("cw_id", Kind::Integer),
    ("q1_deg", Kind::Joint),
    ("q2_deg", Kind::Joint),
    ("q3_deg", Kind::Joint),
    ("q4_deg", Kind::Joint),
    ("q5_deg", Kind::Joint),
    ("q6_deg", Kind::Joint),
    ("q7_deg", Kind::Joint),
    ("q1_mm", Kind::Position),
    ("q2_mm", Kind::Position),
    ("q3_mm", Kind::Position),
    ("q4_mm", Kind::Position),
    ("q5_mm", Kind::Position),
    ("q6_mm", Kind::Position),
    ("q7_mm", Kind::Position),
    ("fx_n", Kind::Force),
    ("fy_n", Kind::Force),
    ("fz_n", Kind::Force),
    ("mx_nm", Kind::Moment),
    ("my_nm", Kind::Moment),
    ("mz_nm", Kind::Moment),
    ("x_mm", Kind::Position),
    ("y_mm", Kind::Position),
    ("z_mm", Kind::Position),
    ("sigma_x_mm", Kind::Sigma),
    ("sigma_y_mm", Kind::Sigma),
    ("sigma_z_mm", Kind::Sigma),
    ("rx_deg", Kind::Angle),
    ("ry_deg", Kind::Angle),
    ("rz_deg", Kind::Angle),
    ("sigma_rx_deg", Kind::AngleSigma),
    ("sigma_ry_deg", Kind::AngleSigma),
    ("sigma_rz_deg", Kind::AngleSigma),
    ("dir1", Kind::Integer),
    ("dir2", Kind::Integer),
    ("dir3", Kind::Integer),
    ("dir4", Kind::Integer),
    ("dir5", Kind::Integer),
    ("dir6", Kind::Integer),
    ("e1_mm", Kind::Position),
    ("p1_deg", Kind::Joint),
    ("p2_deg", Kind::Joint),
    ("target_id", Kind::Text),
    ("config_id", Kind::Integer),
    ("robot_id", Kind::Text),
    ("measured_at", Kind::Time),
];

/// Required whatever the robot: the position. The joint columns the robot
/// file needs are checked by [`ImportMeasurementsSettings::joint_map_problems`].
const REQUIRED: [&str; 3] = ["x_mm", "y_mm", "z_mm"];

impl ColumnMap {
    fn get(&self, contract: &str) -> Option<&str> {
        let value = match contract {
            "cw_id" => &self.cw_id,
            "q1_deg" => &self.q1_deg,
            "q2_deg" => &self.q2_deg,
            "q3_deg" => &self.q3_deg,
            "q4_deg" => &self.q4_deg,
            "q5_deg" => &self.q5_deg,
            "q6_deg" => &self.q6_deg,
            "q7_deg" => &self.q7_deg,
            "q1_mm" => &self.q1_mm,
            "q2_mm" => &self.q2_mm,
            "q3_mm" => &self.q3_mm,
            "q4_mm" => &self.q4_mm,
            "q5_mm" => &self.q5_mm,
            "q6_mm" => &self.q6_mm,
            "q7_mm" => &self.q7_mm,
            "fx_n" => &self.fx_n,
            "fy_n" => &self.fy_n,
            "fz_n" => &self.fz_n,
            "mx_nm" => &self.mx_nm,
            "my_nm" => &self.my_nm,
            "mz_nm" => &self.mz_nm,
            "x_mm" => &self.x_mm,
            "y_mm" => &self.y_mm,
            "z_mm" => &self.z_mm,
            "sigma_x_mm" => &self.sigma_x_mm,
            "sigma_y_mm" => &self.sigma_y_mm,
            "sigma_z_mm" => &self.sigma_z_mm,
            "rx_deg" => &self.rx_deg,
            "ry_deg" => &self.ry_deg,
            "rz_deg" => &self.rz_deg,
            "sigma_rx_deg" => &self.sigma_rx_deg,
            "sigma_ry_deg" => &self.sigma_ry_deg,
            "sigma_rz_deg" => &self.sigma_rz_deg,
            "dir1" => &self.dir1,
            "dir2" => &self.dir2,
            "dir3" => &self.dir3,
            "dir4" => &self.dir4,
            "dir5" => &self.dir5,
            "dir6" => &self.dir6,
            "e1_mm" => &self.e1_mm,
            "p1_deg" => &self.p1_deg,
            "p2_deg" => &self.p2_deg,
            "target_id" => &self.target_id,
            "config_id" => &self.config_id,
            "robot_id" => &self.robot_id,
            "measured_at" => &self.measured_at,
            _ => &None,
        };
        value.as_deref()
    }
}

/// Settings checked as a whole: every problem is reported at once.
#[derive(Debug)]
struct Checked {
    file: PathBuf,
    format: SourceFormat,
    layout: CsvLayout,
    mapped: Vec<Mapped>,
}

impl ImportMeasurementsSettings {
    /// The joint columns against the robot file's (`joints`, from
    /// [`schema::joint_column_names`]): each of them mapped, and no other
    /// joint column (a `q3_deg` for a prismatic joint 3, a `q7_deg` for a
    /// six-joint arm), since its values would be dropped or read in the
    /// wrong unit.
    fn joint_map_problems(&self, joints: &[&'static str]) -> Vec<SettingsProblem> {
        let mut problems = Vec::new();
        for name in joints {
            if self.columns.get(name).is_none() {
                problems.push(SettingsProblem::new(
                    &format!("columns.{name}"),
                    format!(
                        "required: the source column that holds `{name}` (the robot file's joints are {})",
                        joints.join(", ")
                    ),
                ));
            }
        }
        for name in schema::ALL_JOINT_COLUMNS
            .iter()
            .chain(&schema::ALL_PRISMATIC_JOINT_COLUMNS)
        {
            if self.columns.get(name).is_some() && !joints.contains(name) {
                problems.push(SettingsProblem::new(
                    &format!("columns.{name}"),
                    format!(
                        "the robot file has no such joint column: its joints are {}",
                        joints.join(", ")
                    ),
                ));
            }
        }
        problems
    }

    /// The settings resolved against the job folder, or every problem with them
    /// (by key). Reads nothing: the file is only named.
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
        for triple in [
            &schema::SIGMA_COLUMNS,
            &schema::ORIENTATION_COLUMNS,
            &schema::ORIENTATION_SIGMA_COLUMNS,
        ] {
            let mapped = triple.map(|c| self.columns.get(c).is_some());
            if mapped.contains(&true) && mapped.contains(&false) {
                problems.push(SettingsProblem::new(
                    &format!("columns.{}", triple[0]),
                    format!(
                        "`columns.{}`, `columns.{}`, `columns.{}`: map all three or none",
                        triple[0], triple[1], triple[2]
                    ),
                ));
            }
        }
        if self.columns.get("sigma_rx_deg").is_some() && self.columns.get("rx_deg").is_none() {
            problems.push(SettingsProblem::new(
                "columns.sigma_rx_deg",
                "orientation sigmas without the orientation: map `columns.rx_deg`, `columns.ry_deg`, `columns.rz_deg` too",
            ));
        }
        for (key, constant) in [
            ("target_id", self.constant.target_id.as_deref()),
            ("robot_id", self.constant.robot_id.as_deref()),
        ] {
            if constant.is_some_and(|c| c.trim().is_empty()) {
                problems.push(SettingsProblem::new(
                    &format!("constant.{key}"),
                    "must not be empty",
                ));
            }
        }
        for (key, constant) in [
            ("target_id", self.constant.target_id.is_some()),
            ("robot_id", self.constant.robot_id.is_some()),
            ("config_id", self.constant.config_id.is_some()),
        ] {
            if constant && self.columns.get(key).is_some() {
                problems.push(SettingsProblem::new(
                    &format!("constant.{key}"),
                    format!("`columns.{key}` and `constant.{key}` are both set: choose one"),
                ));
            }
        }
        if let Some([start, end]) = self.row_range
            && start >= end
        {
            problems.push(SettingsProblem::new(
                "row_range",
                format!("[{start}, {end}] is empty; it is [start, end) with start < end"),
            ));
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
}

impl Stage for ImportMeasurementsStage {
    type Settings = ImportMeasurementsSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn external_key(
        &self,
        settings: &ImportMeasurementsSettings,
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
        settings: &ImportMeasurementsSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems = settings.check(ctx.job_dir).err().unwrap_or_default();
        problems.extend(settings.joint_map_problems(&schema::joint_column_names(ctx.robot)));
        problems
    }

    /// The export read, converted and checked as `run` does it.
    fn check_sources(
        &self,
        settings: &ImportMeasurementsSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let checked = import_for(ctx.robot, settings, ctx.job_dir).and_then(|imported| {
            let robot = crate::robot::Robot::new(ctx.robot.clone());
            check_units(&robot, ctx.job_dir, settings, &imported.measurements)
        });
        match checked {
            Ok(()) => Vec::new(),
            Err(e) => vec![SettingsProblem::new("path", e.to_string())],
        }
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &ImportMeasurementsSettings,
    ) -> Result<StageOutputs, StageError> {
        let imported = import_for(ctx.robot.spec(), settings, ctx.job_dir)?;
        for note in &imported.notes {
            ctx.progress.note(note);
        }
        check_units(ctx.robot, ctx.job_dir, settings, &imported.measurements)?;
        let mut outputs = StageOutputs::default();
        outputs
            .tables
            .insert("measurements".into(), imported.measurements);
        outputs.facts = imported.facts;
        Ok(outputs)
    }
}

/// The imported table and the facts worth keeping with it.
#[derive(Debug)]
pub struct Imported {
    pub measurements: DataFrame,
    pub facts: BTreeMap<String, String>,
    /// Warnings about the file that did not stop the import, each naming the file.
    pub notes: Vec<String>,
}

/// [`import`], with joint values in the controller's convention turned into
/// the robot file's (`joint_convention`).
pub fn import_for(
    robot: &crate::robot::RobotSpec,
    settings: &ImportMeasurementsSettings,
    job_dir: &Path,
) -> Result<Imported, StageError> {
    let mut imported = import(settings, job_dir, &schema::joint_column_names(robot))?;
    let file = job_dir.join(&settings.path);
    if super::import_source::joints_to_robot_file(
        &mut imported.measurements,
        settings.joint_convention,
        robot,
        &file,
    )? {
        imported.facts.insert(
            "joint_convention".into(),
            format!("controller: q3 = J3 - {} * J2", robot.controller.j3_from_j2),
        );
    }
    Ok(imported)
}

/// Reads, converts and checks the export the settings name (relative paths
/// against `job_dir`). Reads the whole file into memory once.
fn import(
    settings: &ImportMeasurementsSettings,
    job_dir: &Path,
    joints: &[&'static str],
) -> Result<Imported, StageError> {
    let mut problems = settings.check(job_dir).err().unwrap_or_default();
    problems.extend(settings.joint_map_problems(joints));
    if !problems.is_empty() {
        return Err(settings_error(&problems));
    }
    let checked = settings.check(job_dir).map_err(|p| settings_error(&p))?;
    let bytes = std::fs::read(&checked.file).map_err(|e| cannot_read(&checked.file, e))?;
    let source = read_source(
        &checked.file,
        checked.format,
        &checked.layout,
        &checked.mapped,
        &bytes,
        "measurements hold complete rows only",
    )?;
    source.check_columns(&checked.mapped)?;
    let rows = match settings.row_range {
        None => 0..source.height(),
        Some([start, end]) if end <= source.height() => start..end,
        Some([start, end]) => {
            return Err(StageError::Invalid(format!(
                "setting `row_range`: [{start}, {end}) ends past the {} data rows of {}",
                source.height(),
                checked.file.display()
            )));
        }
    };
    if rows.is_empty() {
        return Err(StageError::Invalid(format!(
            "{}: no data rows (a header only?): measurements need at least one row",
            checked.file.display()
        )));
    }
    let measurements = build(&source, &checked.mapped, settings, rows.clone())?;
    schema::measurements().check(&measurements, &checked.file)?;
    let mut facts = BTreeMap::new();
    facts.insert(
        "imported_rows".to_string(),
        measurements.height().to_string(),
    );
    facts.insert("source".to_string(), settings.path.clone());
    facts.insert(
        "source_blake3".to_string(),
        blake3::hash(&bytes).to_hex().to_string(),
    );
    if settings.row_range.is_some() {
        facts.insert(
            "row_range".to_string(),
            format!(
                "[{}, {}) of {} data rows",
                rows.start,
                rows.end,
                source.height()
            ),
        );
    }
    Ok(Imported {
        measurements,
        facts,
        notes: source.notes.clone(),
    })
}

/// Refuses an import whose rows show a unit mistake
/// ([`crate::calibration::unit_checks`]), naming the file, the source columns
/// and the setting to change: a wrong unit would otherwise calibrate "perfectly"
/// onto an arm 1000× too small.
fn check_units(
    robot: &crate::robot::Robot,
    job_dir: &Path,
    settings: &ImportMeasurementsSettings,
    measurements: &DataFrame,
) -> Result<(), StageError> {
    let table = super::InputTable {
        path: job_dir.join(&settings.path),
        df: measurements.clone(),
    };
    let (_, rows) = super::conf_wrench_rows(&table, robot.spec())?;
    let xyz = schema::POSITION_COLUMNS
        .iter()
        .map(|c| schema::f64_values(measurements, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    let positions: Vec<nalgebra::Vector3<f64>> = (0..rows.len())
        .map(|k| nalgebra::Vector3::new(xyz[0][k], xyz[1][k], xyz[2][k]))
        .collect();
    let Some(suspicion) = crate::calibration::unit_checks::suspect_units(robot, &rows, &positions)
    else {
        return Ok(());
    };
    let sources = |names: &[&str]| {
        names
            .iter()
            .map(|n| settings.columns.get(n).unwrap_or(n).to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (columns, setting, unit) = match suspicion {
        crate::calibration::unit_checks::UnitSuspicion::JointsInRadians { .. } => (
            sources(&schema::joint_column_names(robot.spec())),
            "joint_unit",
            match settings.joint_unit {
                JointUnit::Deg => "deg",
                JointUnit::Rad => "rad",
            },
        ),
        crate::calibration::unit_checks::UnitSuspicion::Length { .. } => (
            sources(&schema::POSITION_COLUMNS),
            "length_unit",
            match settings.length_unit {
                LengthUnit::Mm => "mm",
                LengthUnit::M => "m",
            },
        ),
    };
    Err(StageError::Invalid(format!(
        "{}: columns {columns}: {} (setting `{setting}` = \"{unit}\" now){}",
        table.path.display(),
        suspicion.describe(),
        match &suspicion {
            crate::calibration::unit_checks::UnitSuspicion::JointsInRadians { .. } => {
                "; set `joint_unit = \"rad\"`".to_string()
            }
            crate::calibration::unit_checks::UnitSuspicion::Length { likely_unit, .. }
                if *likely_unit == "metres" =>
            {
                "; set `length_unit = \"m\"`".to_string()
            }
            crate::calibration::unit_checks::UnitSuspicion::Length { likely_unit, .. } => {
                format!("; convert the export from {likely_unit} to millimetres or metres")
            }
        }
    )))
}

/// The factor from the source unit of `kind` to the contract's unit.
fn factor(kind: Kind, settings: &ImportMeasurementsSettings) -> f64 {
    match kind {
        Kind::Joint => match settings.joint_unit {
            JointUnit::Deg => 1.0,
            JointUnit::Rad => 180.0 / std::f64::consts::PI,
        },
        Kind::Position | Kind::Sigma => match settings.length_unit {
            LengthUnit::Mm => 1.0,
            LengthUnit::M => 1000.0,
        },
        Kind::Moment => match settings.moment_unit {
            MomentUnit::NewtonMetre => 1.0,
            MomentUnit::NewtonMillimetre => 1e-3,
        },
        Kind::Angle | Kind::AngleSigma => match settings.angle_unit {
            JointUnit::Deg => 1.0,
            JointUnit::Rad => 180.0 / std::f64::consts::PI,
        },
        Kind::Force | Kind::Integer | Kind::Text | Kind::Time => 1.0,
    }
}

/// The measurements table from the source's `rows`, contract columns in order.
fn build(
    source: &Source,
    mapped: &[Mapped],
    settings: &ImportMeasurementsSettings,
    rows: Range<usize>,
) -> Result<DataFrame, StageError> {
    let n = rows.len();
    let find = |contract: &str| mapped.iter().find(|m| m.contract == contract);
    let mut columns = Vec::new();

    let ids: Vec<i64> = match find("cw_id") {
        Some(m) => {
            let ids = source.integers(m, rows.clone())?;
            let mut first = HashMap::with_capacity(n);
            for (k, id) in ids.iter().enumerate() {
                if let Some(earlier) = first.insert(*id, rows.start + k) {
                    return Err(source.problem(
                        rows.start + k,
                        m,
                        format!(
                            "cw_id {id} repeats the one on {}; it must be unique",
                            source.at(earlier)
                        ),
                    ));
                }
            }
            ids
        }
        None => rows.clone().map(|r| r as i64).collect(),
    };
    columns.push(Column::new("cw_id".into(), ids));

    let float_names = schema::ALL_JOINT_COLUMNS
        .iter()
        .chain(&schema::ALL_PRISMATIC_JOINT_COLUMNS)
        .chain(&schema::WRENCH_COLUMNS)
        .chain(&schema::POSITION_COLUMNS)
        .chain(&schema::SIGMA_COLUMNS)
        .chain(&schema::ORIENTATION_COLUMNS)
        .chain(&schema::ORIENTATION_SIGMA_COLUMNS)
        .chain(std::iter::once(&schema::TRACK_COLUMN))
        .chain(&schema::POSITIONER_COLUMNS);
    for name in float_names {
        let values = match find(name) {
            Some(m) => {
                let f = factor(m.kind, settings);
                let mut values = source.floats(m, rows.clone())?;
                for (k, v) in values.iter_mut().enumerate() {
                    *v *= f;
                    if m.kind == Kind::AngleSigma && !(MIN_SIGMA_DEG..=MAX_SIGMA_DEG).contains(v) {
                        let row = rows.start + k;
                        let text = source.raw(&m.source, row).unwrap_or_default();
                        return Err(source.problem(
                            row,
                            m,
                            format!(
                                "`{text}` is not a probe's 1-σ orientation uncertainty: expected {MIN_SIGMA_DEG} to {MAX_SIGMA_DEG} deg ({} deg after `angle_unit`){}",
                                crate::calibration::row_checks::compact(*v),
                                if *v <= 0.0 { "; sigma must be > 0" } else { "" }
                            ),
                        ));
                    }
                    if m.kind == Kind::Angle && v.abs() > MAX_ANGLE_DEG {
                        let row = rows.start + k;
                        let text = source.raw(&m.source, row).unwrap_or_default();
                        return Err(source.problem(
                            row,
                            m,
                            format!(
                                "`{text}` is not an orientation angle: expected within ±{MAX_ANGLE_DEG} deg ({} deg after `angle_unit`; degrees read as radians?)",
                                crate::calibration::row_checks::compact(*v)
                            ),
                        ));
                    }
                    if m.kind == Kind::Sigma && !(MIN_SIGMA_MM..=MAX_SIGMA_MM).contains(v) {
                        let row = rows.start + k;
                        let text = source.raw(&m.source, row).unwrap_or_default();
                        return Err(source.problem(
                            row,
                            m,
                            format!(
                                "`{text}` is not a tracker's 1-σ uncertainty: expected {MIN_SIGMA_MM} to {MAX_SIGMA_MM} mm ({} mm after `length_unit`){}",
                                crate::calibration::row_checks::compact(*v),
                                if *v <= 0.0 { "; sigma must be > 0" } else { "" }
                            ),
                        ));
                    }
                }
                values
            }
            // Optional columns: a wrench not given is no load; sigmas and
            // orientations are all or none.
            None if schema::WRENCH_COLUMNS.contains(name) => vec![0.0; n],
            None => continue,
        };
        columns.push(Column::new((*name).into(), values));
    }

    for name in schema::APPROACH_COLUMNS {
        let Some(m) = find(name) else { continue };
        let mut directions = Vec::with_capacity(n);
        for (k, value) in source.integers(m, rows.clone())?.into_iter().enumerate() {
            let direction = i8::try_from(value)
                .ok()
                .filter(|d| (-1..=1).contains(d))
                .ok_or_else(|| {
                    source.problem(
                        rows.start + k,
                        m,
                        format!("`{value}` is not an approach direction: expected -1, 0 or 1"),
                    )
                })?;
            directions.push(direction);
        }
        columns.push(Column::new(name.into(), directions));
    }

    for (name, constant) in [
        ("target_id", settings.constant.target_id.as_ref()),
        ("robot_id", settings.constant.robot_id.as_ref()),
    ] {
        if let Some(m) = find(name) {
            columns.push(Column::new(name.into(), source.texts(m, rows.clone())?));
        } else if let Some(value) = constant {
            columns.push(Column::new(name.into(), vec![value.clone(); n]));
        }
    }
    if let Some(m) = find("config_id") {
        columns.push(Column::new(
            "config_id".into(),
            source.integers(m, rows.clone())?,
        ));
    } else if let Some(value) = settings.constant.config_id {
        columns.push(Column::new("config_id".into(), vec![value; n]));
    }
    if let Some(m) = find("measured_at") {
        let stamps = Column::new("measured_at".into(), source.times_us(m, rows.clone())?)
            .cast(&DataType::Datetime(
                TimeUnit::Microseconds,
                Some(TimeZone::UTC),
            ))
            .map_err(|e| source.problem(rows.start, m, e))?;
        columns.push(stamps);
    }
    Ok(crate::table::frame(columns))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Settings from a TOML block, as a job's stage table would give them.
    /// [`super::import`] for the six revolute joints of the IRB 1600.
    fn import(settings: &ImportMeasurementsSettings, dir: &Path) -> Result<Imported, StageError> {
        super::import(settings, dir, &schema::JOINT_COLUMNS)
    }

    fn settings(toml: &str) -> ImportMeasurementsSettings {
        toml::from_str(toml).unwrap()
    }

    fn write(dir: &Path, name: &str, text: &str) {
        std::fs::write(dir.join(name), text).unwrap();
    }

    fn f64s(df: &DataFrame, name: &str) -> Vec<f64> {
        schema::f64_values(df, name, Path::new("t")).unwrap()
    }

    const JOINTS_XYZ: &str = r#"
[columns]
q1_deg = "a1"
q2_deg = "a2"
q3_deg = "a3"
q4_deg = "a4"
q5_deg = "a5"
q6_deg = "a6"
x_mm = "x"
y_mm = "y"
z_mm = "z"
"#;

    fn error(toml: &str, dir: &Path) -> String {
        import(&settings(toml), dir).unwrap_err().to_string()
    }

    /// A gantry's slides are mapped as `q{i}_mm` in `length_unit`, its wrist
    /// as `q{i}_deg` in `joint_unit`; a seven-joint arm's `q7_deg` too. A
    /// joint column the robot file does not have, or one of its own left
    /// out, is refused naming the key.
    #[test]
    fn the_robot_file_says_which_joint_columns_an_export_maps() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "g.csv",
            "x1,x2,x3,a4,a5,a6,a7,x,y,z\n1.5,0.25,0.125,0.5,-1.0,0.25,0.1,1.0,2.0,3.0\n",
        );
        let gantry = crate::robot::test_support::gantry();
        let toml = "path = \"g.csv\"\nlength_unit = \"m\"\njoint_unit = \"rad\"\n[columns]\nq1_mm = \"x1\"\nq2_mm = \"x2\"\nq3_mm = \"x3\"\nq4_deg = \"a4\"\nq5_deg = \"a5\"\nq6_deg = \"a6\"\nx_mm = \"x\"\ny_mm = \"y\"\nz_mm = \"z\"\n";
        let df = import_for(gantry.spec(), &settings(toml), dir.path())
            .unwrap()
            .measurements;
        assert_eq!(f64s(&df, "q1_mm"), [1500.0]);
        assert_eq!(f64s(&df, "q3_mm"), [125.0]);
        assert!((f64s(&df, "q4_deg")[0] - 0.5_f64.to_degrees()).abs() < 1e-12);
        assert!(df.column("q1_deg").is_err());
        schema::measurements().check(&df, Path::new("m")).unwrap();
        let rows = schema::joint_vectors(&df, Path::new("m"), gantry.spec()).unwrap();
        assert_eq!(rows[0][1], 250.0);

        // The revolute IRB 1600 given the gantry's map; the gantry given a
        // revolute map.
        let irb = crate::robot::test_support::irb1600();
        let error = import_for(irb.spec(), &settings(toml), dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("columns.q1_deg") && error.contains("columns.q1_mm"),
            "{error}"
        );
        let revolute = toml.replace("q1_mm", "q1_deg");
        let error = import_for(gantry.spec(), &settings(&revolute), dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("columns.q1_mm") && error.contains("q1_mm, q2_mm, q3_mm, q4_deg"),
            "{error}"
        );

        // A seven-joint arm's seventh joint.
        let panda = crate::robot::test_support::panda();
        let seven = format!("path = \"g.csv\"\n{JOINTS_XYZ}q7_deg = \"a7\"\n")
            .replace("\"a1\"", "\"x1\"")
            .replace("\"a2\"", "\"x2\"")
            .replace("\"a3\"", "\"x3\"");
        let df = import_for(panda.spec(), &settings(&seven), dir.path())
            .unwrap()
            .measurements;
        assert_eq!(f64s(&df, "q7_deg"), [0.1]);
        let error = import_for(
            panda.spec(),
            &settings(&format!("path = \"g.csv\"\n{JOINTS_XYZ}")),
            dir.path(),
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("columns.q7_deg"), "{error}");
    }

    #[test]
    fn a_track_position_is_imported_in_the_length_unit() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z,e\n1,2,3,4,5,6,1.0,0.0,0.5,2.25\n",
        );
        let toml = format!("path = \"e.csv\"\nlength_unit = \"m\"\n{JOINTS_XYZ}e1_mm = \"e\"\n");
        let df = import(&settings(&toml), dir.path()).unwrap().measurements;
        assert_eq!(f64s(&df, "e1_mm"), [2250.0]);
        assert_eq!(f64s(&df, "x_mm"), [1000.0]);
    }

    #[test]
    fn positioner_axes_are_imported_in_the_joint_unit() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "p.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z,t,tilt,turn\n0,0,0,0,0,0,1.0,0.0,0.5,table_a,0.5,-1.5\n",
        );
        let toml = format!(
            "path = \"p.csv\"\njoint_unit = \"rad\"\n{JOINTS_XYZ}target_id = \"t\"\np1_deg = \"tilt\"\np2_deg = \"turn\"\n"
        );
        let df = import(&settings(&toml), dir.path()).unwrap().measurements;
        assert!((f64s(&df, "p1_deg")[0] - 0.5_f64.to_degrees()).abs() < 1e-12);
        assert!((f64s(&df, "p2_deg")[0] + 1.5_f64.to_degrees()).abs() < 1e-12);
    }

    #[test]
    fn controller_joints_become_the_robot_file_s() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z\n1,30,-20,4,5,6,1000,0,500\n",
        );
        let plain = crate::robot::test_support::irb1600().spec().clone();
        let mut fanuc = plain.clone();
        fanuc.controller.j3_from_j2 = 1.0;
        let toml = format!("path = \"e.csv\"\njoint_convention = \"controller\"\n{JOINTS_XYZ}");
        // J3 = q3 + q2: the forearm's -20 deg from the horizontal is q3 = -50.
        let df = import_for(&fanuc, &settings(&toml), dir.path())
            .unwrap()
            .measurements;
        assert_eq!(f64s(&df, "q2_deg"), [30.0]);
        assert_eq!(f64s(&df, "q3_deg"), [-50.0]);
        // Without a coupling in the robot file, or in the robot file's
        // convention, the values stay.
        let df = import_for(&plain, &settings(&toml), dir.path())
            .unwrap()
            .measurements;
        assert_eq!(f64s(&df, "q3_deg"), [-20.0]);
        let toml = format!("path = \"e.csv\"\n{JOINTS_XYZ}");
        let df = import_for(&fanuc, &settings(&toml), dir.path())
            .unwrap()
            .measurements;
        assert_eq!(f64s(&df, "q3_deg"), [-20.0]);
    }

    #[test]
    fn units_are_converted_to_the_contract() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z,sx,sy,sz,mx,fz\n\
             3.141592653589793,-1.5707963267948966,0,0.5,1,-2,1.5,-0.25,0.002,0.00002,0.00003,0.00004,2500,-9.5\n",
        );
        let toml = format!(
            "path = \"e.csv\"\njoint_unit = \"rad\"\nlength_unit = \"m\"\nmoment_unit = \"Nmm\"\n{JOINTS_XYZ}sigma_x_mm = \"sx\"\nsigma_y_mm = \"sy\"\nsigma_z_mm = \"sz\"\nmx_nm = \"mx\"\nfz_n = \"fz\"\n"
        );
        let df = import(&settings(&toml), dir.path()).unwrap().measurements;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
        // Hand values: π rad = 180°, −π/2 = −90°, 0.5 rad = 28.64788975654116°,
        // 1 rad = 57.29577951308232°, −2 rad = −114.59155902616465°.
        let expected_q = [
            180.0,
            -90.0,
            0.0,
            28.64788975654116,
            57.29577951308232,
            -114.59155902616465,
        ];
        for (name, want) in schema::JOINT_COLUMNS.iter().zip(expected_q) {
            let got = f64s(&df, name)[0];
            assert!(close(got, want), "{name}: {got} vs {want}");
        }
        for (name, want) in [
            ("x_mm", 1500.0),
            ("y_mm", -250.0),
            ("z_mm", 2.0),
            ("sigma_x_mm", 0.02),
            ("sigma_y_mm", 0.03),
            ("sigma_z_mm", 0.04),
            ("mx_nm", 2.5),
            ("fz_n", -9.5),
            ("fx_n", 0.0),
            ("my_nm", 0.0),
        ] {
            let got = f64s(&df, name)[0];
            assert!(close(got, want), "{name}: {got} vs {want}");
        }
        assert_eq!(
            schema::i64_values(&df, "cw_id", Path::new("t")).unwrap(),
            [0]
        );
    }

    #[test]
    fn moment_unit_spellings_share_one_canonical_form() {
        for (text, want) in [
            ("N*m", "N·m"),
            ("Nm", "N·m"),
            ("N*mm", "N·mm"),
            ("Nmm", "N·mm"),
        ] {
            let s = settings(&format!("moment_unit = \"{text}\""));
            assert_eq!(serde_json::to_value(&s).unwrap()["moment_unit"], want);
        }
        let err = toml::from_str::<ImportMeasurementsSettings>("moment_unit = \"kNm\"")
            .unwrap_err()
            .to_string();
        assert!(err.contains("`kNm` is not a moment unit"), "{err}");
    }

    #[test]
    fn decimal_comma_with_semicolons_reads_like_the_tracker_export() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "a1;a2;a3;a4;a5;a6;x;y;z\r\n\
             1,5;-2,78E-05;0;0,0;-1,25;2;383,97123;-3240,7562;201,72621\r\n",
        );
        let toml =
            format!("path = \"e.csv\"\nseparator = \";\"\ndecimal_comma = true\n{JOINTS_XYZ}");
        let df = import(&settings(&toml), dir.path()).unwrap().measurements;
        assert_eq!(f64s(&df, "q1_deg"), [1.5]);
        assert_eq!(f64s(&df, "q2_deg"), [-2.78e-5]);
        assert_eq!(f64s(&df, "q5_deg"), [-1.25]);
        assert_eq!(f64s(&df, "x_mm"), [383.97123]);
        assert_eq!(f64s(&df, "y_mm"), [-3240.7562]);
        assert_eq!(f64s(&df, "z_mm"), [201.72621]);
    }

    #[test]
    fn a_bad_number_names_file_line_and_column() {
        let dir = tempfile::tempdir().unwrap();
        // Two preamble lines, the header, then data rows 0, 1, 2: row 2 is line 6.
        write(
            dir.path(),
            "e.csv",
            "tracker export\nunits: mm\na1;a2;a3;a4;a5;a6;x;y;z\n\
             1;2;3;4;5;6;7;8;9\n1;2;3;4;5;6;7;8;9\n1;2;3;4;5;6;7;8,5;9\n",
        );
        let toml = format!("path = \"e.csv\"\nseparator = \";\"\nskip_rows = 2\n{JOINTS_XYZ}");
        let err = error(&toml, dir.path());
        let file = dir.path().join("e.csv");
        assert_eq!(
            err,
            format!(
                "{}: line 6, column `y` (setting `columns.y_mm`): `8,5` is not a number (the file seems to use a decimal comma: set `decimal_comma = true`)",
                file.display()
            )
        );

        write(
            dir.path(),
            "f.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z\n1,2,3,4,5,6,7,8,9\n1,2,3,abc,5,6,7,8,9\n",
        );
        let err = error(&format!("path = \"f.csv\"\n{JOINTS_XYZ}"), dir.path());
        assert!(
            err.ends_with(
                "f.csv: line 3, column `a4` (setting `columns.q4_deg`): `abc` is not a number"
            ),
            "{err}"
        );
    }

    #[test]
    fn empty_and_non_finite_cells_are_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z\n1,2,3,4,5,6,7,8,9\n1,2,3,4,5,6,7,,9\n",
        );
        let err = error(&format!("path = \"e.csv\"\n{JOINTS_XYZ}"), dir.path());
        assert!(
            err.contains(
                "e.csv: line 3, column `y` (setting `columns.y_mm`): empty cell, expected a number"
            ),
            "{err}"
        );
        for bad in ["NaN", "inf", "-inf"] {
            write(
                dir.path(),
                "n.csv",
                &format!(
                    "a1,a2,a3,a4,a5,a6,x,y,z\n1,2,3,4,5,6,7,8,9\n1,2,3,4,5,6,7,8,9\n1,2,{bad},4,5,6,7,8,9\n"
                ),
            );
            let err = error(&format!("path = \"n.csv\"\n{JOINTS_XYZ}"), dir.path());
            assert!(
                err.contains("n.csv: line 4, column `a3` (setting `columns.q3_deg`): `"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn a_blank_line_is_skipped_and_keeps_the_line_count() {
        // A blank line is no row (tracker software ends files with one), and
        // the lines after it keep their numbers.
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "a1,a2,a3,a4,a5,a6,x,y,z\n1,2,3,4,5,6,7,8,9\n\n1,2,3,4,5,6,7,8,x\n",
        );
        let err = error(&format!("path = \"e.csv\"\n{JOINTS_XYZ}"), dir.path());
        assert!(
            err.contains("e.csv: line 4, column `z` (setting `columns.z_mm`): `x` is not a number"),
            "{err}"
        );
    }

    #[test]
    fn a_missing_column_names_the_setting_with_a_suggestion() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "e.csv",
            "shoulder_pan_joint,a2,a3,a4,a5,a6,x,y,z\n1,2,3,4,5,6,7,8,9\n",
        );
        let toml = format!("path = \"e.csv\"\n{JOINTS_XYZ}").replace("\"a1\"", "\"shoulder_pan\"");
        let err = error(&toml, dir.path());
        assert_eq!(
            err,
            format!(
                "{}: setting `columns.q1_deg` names source column `shoulder_pan`, which the file does not have (did you mean `shoulder_pan_joint`?)",
                dir.path().join("e.csv").display()
            )
        );
        let typo = toml.replace("shoulder_pan", "shoulder_pan_jiont");
        assert!(
            error(&typo, dir.path()).ends_with("(did you mean `shoulder_pan_joint`?)"),
            "{typo}"
        );
        // A column mapped elsewhere is not suggested: no std columns, no hint.
        let sigma = format!(
            "path = \"e.csv\"\n{JOINTS_XYZ}sigma_x_mm = \"x_std\"\nsigma_y_mm = \"y_std\"\nsigma_z_mm = \"z_std\"\n"
        );
        let err = error(&sigma, dir.path());
        assert!(
            err.contains(
                "`columns.sigma_x_mm` names source column `x_std`, which the file does not have\n"
            ),
            "{err}"
        );
        // A wrong separator: the whole header is one column, and the message says so.
        write(
            dir.path(),
            "s.csv",
            "a1;a2;a3;a4;a5;a6;x;y;z\n1;2;3;4;5;6;7;8;9\n",
        );
        let err = error(&format!("path = \"s.csv\"\n{JOINTS_XYZ}"), dir.path());
        assert!(
            err.contains("the header reads as one column `a1;a2;a3;a4;a5;a6;x;y;z` with separator ',', and holds ';': set `separator = \";\"`"),
            "{err}"
        );
    }

    #[test]
    fn settings_problems_are_reported_together_with_their_keys() {
        let dir = tempfile::tempdir().unwrap();
        let err = error(
            "path = \"e.csv\"\nseparator = \",,\"\ndecimal_comma = true\nrow_range = [5, 5]\n[columns]\nq1_deg = \"a\"\nsigma_x_mm = \"s\"\n[constant]\nrobot_id = \"\"\n",
            dir.path(),
        );
        for key in [
            "setting `separator`",
            "setting `columns.q2_deg`: required",
            "setting `columns.z_mm`: required",
            "map all three or none",
            "setting `constant.robot_id`: must not be empty",
            "setting `row_range`: [5, 5] is empty",
        ] {
            assert!(err.contains(key), "{key} in {err}");
        }
        let err = error(
            &format!(
                "path = \"e.csv\"\nseparator = \",\"\ndecimal_comma = true\n{JOINTS_XYZ}target_id = \"t\"\n[constant]\ntarget_id = \"nest1\"\n"
            ),
            dir.path(),
        );
        assert!(
            err.contains("setting `decimal_comma`: needs a separator other than"),
            "{err}"
        );
        assert!(
            err.contains("`columns.target_id` and `constant.target_id` are both set"),
            "{err}"
        );
        let err = error(&format!("path = \"absent.csv\"\n{JOINTS_XYZ}"), dir.path());
        assert!(err.starts_with("setting `path`: cannot read "), "{err}");
    }

    #[test]
    fn a_long_table_keeps_one_row_per_target_reading() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "long.csv",
            "id,nest,a1,a2,a3,a4,a5,a6,x,y,z\n\
             10,nest1,1,2,3,4,5,6,100,0,0\n\
             11,nest2,1,2,3,4,5,6,0,100,0\n\
             12,nest3,1,2,3,4,5,6,0,0,100\n\
             20,nest1,7,8,9,10,11,12,101,0,0\n\
             21,nest2,7,8,9,10,11,12,0,101,0\n",
        );
        let toml = format!(
            "path = \"long.csv\"\n[constant]\nrobot_id = \"ur10\"\nconfig_id = 3\n{JOINTS_XYZ}cw_id = \"id\"\ntarget_id = \"nest\"\n"
        );
        let imported = import(&settings(&toml), dir.path()).unwrap();
        let df = imported.measurements;
        assert_eq!(df.height(), 5);
        let t = Path::new("t");
        assert_eq!(
            schema::i64_values(&df, "cw_id", t).unwrap(),
            [10, 11, 12, 20, 21]
        );
        let targets: Vec<String> = schema::str_values(&df, "target_id", t)
            .unwrap()
            .into_iter()
            .flatten()
            .collect();
        assert_eq!(targets, ["nest1", "nest2", "nest3", "nest1", "nest2"]);
        assert_eq!(f64s(&df, "q1_deg"), [1.0, 1.0, 1.0, 7.0, 7.0]);
        assert_eq!(f64s(&df, "y_mm"), [0.0, 100.0, 0.0, 0.0, 101.0]);
        let robots = schema::str_values(&df, "robot_id", t).unwrap();
        assert!(robots.iter().all(|r| r.as_deref() == Some("ur10")));
        assert_eq!(schema::i64_values(&df, "config_id", t).unwrap(), [3; 5]);
        assert_eq!(imported.facts["imported_rows"], "5");
        assert_eq!(imported.facts["source"], "long.csv");

        // A repeated id is bad input, named with both lines.
        write(
            dir.path(),
            "dup.csv",
            "id,a1,a2,a3,a4,a5,a6,x,y,z\n10,1,2,3,4,5,6,1,2,3\n11,1,2,3,4,5,6,1,2,3\n10,1,2,3,4,5,6,1,2,3\n",
        );
        let err = error(
            &format!("path = \"dup.csv\"\n{JOINTS_XYZ}cw_id = \"id\"\n"),
            dir.path(),
        );
        assert!(
            err.contains(
                "line 4, column `id` (setting `columns.cw_id`): cw_id 10 repeats the one on line 2"
            ),
            "{err}"
        );
    }

    /// Approach directions (spec §8): −1, 0 and 1 import as int8; any other
    /// number, or a fraction, is named with its line and column.
    #[test]
    fn approach_directions_import_and_bad_ones_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let header = "a1,a2,a3,a4,a5,a6,x,y,z,d1,d2\n";
        let row = |d1: &str| format!("0,1,2,3,4,5,1000,0,500,{d1},-1\n");
        write(
            dir.path(),
            "e.csv",
            &format!("{header}{}{}", row("1"), row("0")),
        );
        let base = format!("path = \"e.csv\"\n{JOINTS_XYZ}dir1 = \"d1\"\ndir2 = \"d2\"\n");
        let df = import(&settings(&base), dir.path()).unwrap().measurements;
        schema::measurements().check(&df, Path::new("t")).unwrap();
        let dir1: Vec<Option<i8>> = df.column("dir1").unwrap().i8().unwrap().iter().collect();
        assert_eq!(dir1, [Some(1), Some(0)]);
        assert_eq!(df.column("dir2").unwrap().dtype(), &DataType::Int8);
        for (bad, expected) in [
            (
                "2",
                "line 2, column `d1` (setting `columns.dir1`): `2` is not an approach direction: expected -1, 0 or 1",
            ),
            ("0.5", "column `d1` (setting `columns.dir1`)"),
        ] {
            write(dir.path(), "e.csv", &format!("{header}{}", row(bad)));
            let error = import(&settings(&base), dir.path())
                .unwrap_err()
                .to_string();
            assert!(error.contains(expected), "{bad}: {error}");
        }
    }

    /// 6-D rows (spec §8): the orientation columns and their sigmas, in the
    /// UR10 files' layout (`;`, decimal comma, joints in rad, angles in deg);
    /// radians converted; and every bad cell or half-mapped triple named.
    #[test]
    fn orientation_columns_import_and_bad_ones_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let header = "a1;a2;a3;a4;a5;a6;x;y;z;rx;srx;ry;sry;rz;srz\n";
        let row = |rx: &str, srx: &str| {
            format!(
                "0;-1,5;1;0,5;0,25;0;383,97;-3240,75;201,72;{rx};{srx};-20,112975;0,0065397;-90,157388;0,008348\n"
            )
        };
        let good = format!(
            "{header}{}{}",
            row("-90,179563", "0,0024569"),
            row("-84,2", "0,001")
        );
        write(dir.path(), "e.csv", &good);
        let base = format!(
            "path = \"e.csv\"\nseparator = \";\"\ndecimal_comma = true\njoint_unit = \"rad\"\n{JOINTS_XYZ}rx_deg = \"rx\"\nry_deg = \"ry\"\nrz_deg = \"rz\"\nsigma_rx_deg = \"srx\"\nsigma_ry_deg = \"sry\"\nsigma_rz_deg = \"srz\"\n"
        );
        let df = import(&settings(&base), dir.path()).unwrap().measurements;
        schema::measurements().check(&df, Path::new("t")).unwrap();
        assert_eq!(f64s(&df, "rx_deg"), [-90.179563, -84.2]);
        assert_eq!(f64s(&df, "rz_deg"), [-90.157388, -90.157388]);
        assert_eq!(f64s(&df, "sigma_ry_deg"), [0.0065397, 0.0065397]);
        // Joints in rad, angles in deg: the units are independent.
        assert!((f64s(&df, "q2_deg")[0] + 85.943_669_6).abs() < 1e-6);
        // Angles and their sigmas in radians.
        write(
            dir.path(),
            "r.csv",
            &format!(
                "{header}0;-1,5;1;0,5;0,25;0;383,97;-3240,75;201,72;-1,5;0,0001;0,25;0,0001;3;0,0001\n"
            ),
        );
        let radians = base
            .replace("e.csv", "r.csv")
            .replace("[columns]", "angle_unit = \"rad\"\n[columns]");
        let df = import(&settings(&radians), dir.path())
            .unwrap()
            .measurements;
        assert!((f64s(&df, "rx_deg")[0] + 1.5f64.to_degrees()).abs() < 1e-12);
        assert!((f64s(&df, "sigma_rx_deg")[0] - 1e-4f64.to_degrees()).abs() < 1e-15);

        for (rx, srx, expected) in [
            (
                "",
                "0,001",
                "line 2, column `rx` (setting `columns.rx_deg`)",
            ),
            (
                "NaN",
                "0,001",
                "line 2, column `rx` (setting `columns.rx_deg`): `NaN` is not a finite number",
            ),
            (
                "5000",
                "0,001",
                "line 2, column `rx` (setting `columns.rx_deg`): `5000` is not an orientation angle: expected within ±360 deg",
            ),
            (
                "-90",
                "0",
                "line 2, column `srx` (setting `columns.sigma_rx_deg`): `0` is not a probe's 1-σ orientation uncertainty: expected 0.00001 to 10 deg",
            ),
            ("-90", "-0,01", "sigma must be > 0"),
            (
                "-90",
                "45",
                "`45` is not a probe's 1-σ orientation uncertainty",
            ),
        ] {
            write(dir.path(), "e.csv", &format!("{header}{}", row(rx, srx)));
            let err = error(&base, dir.path());
            assert!(
                err.contains("e.csv") && err.contains(expected),
                "{rx} {srx}: {err}"
            );
        }
        // Half a triple, and sigmas without their angles, are settings problems.
        let half = base.replace("rz_deg = \"rz\"\n", "");
        let problems = settings(&half).check(dir.path()).unwrap_err();
        assert!(
            problems
                .iter()
                .any(|p| p.key == "columns.rx_deg" && p.message.contains("map all three or none")),
            "{problems:?}"
        );
        let orphan = base.replace("rx_deg = \"rx\"\nry_deg = \"ry\"\nrz_deg = \"rz\"\n", "");
        let problems = settings(&orphan).check(dir.path()).unwrap_err();
        assert!(
            problems.iter().any(|p| p.key == "columns.sigma_rx_deg"
                && p.message.contains("without the orientation")),
            "{problems:?}"
        );
        let half_sigma = base.replace("sigma_ry_deg = \"sry\"\n", "");
        let problems = settings(&half_sigma).check(dir.path()).unwrap_err();
        assert!(
            problems.iter().any(|p| p.key == "columns.sigma_rx_deg"),
            "{problems:?}"
        );
    }

    #[test]
    fn sigma_must_be_positive_and_row_range_is_half_open() {
        let dir = tempfile::tempdir().unwrap();
        let mut text = String::from("a1,a2,a3,a4,a5,a6,x,y,z,s\n");
        for row in 0..6 {
            let sigma = if row == 4 { "0" } else { "0.01" };
            text += &format!("{row},0,0,0,0,0,{row},0,0,{sigma}\n");
        }
        write(dir.path(), "e.csv", &text);
        let base = format!(
            "path = \"e.csv\"\n{JOINTS_XYZ}sigma_x_mm = \"s\"\nsigma_y_mm = \"s\"\nsigma_z_mm = \"s\"\n"
        );
        let err = error(&base, dir.path());
        assert!(
            err.contains("line 6, column `s` (setting `columns.sigma_x_mm`): `0` is not a tracker's 1-σ uncertainty: expected 0.0001 to 100 mm"),
            "{err}"
        );
        // Rows 1, 2, 3 only: the zero sigma of row 4 is not imported; cw_id keeps
        // the row number in the whole file.
        let toml = base.replace("path = \"e.csv\"", "path = \"e.csv\"\nrow_range = [1, 4]");
        let imported = import(&settings(&toml), dir.path()).unwrap();
        let df = imported.measurements;
        assert_eq!(
            schema::i64_values(&df, "cw_id", Path::new("t")).unwrap(),
            [1, 2, 3]
        );
        assert_eq!(f64s(&df, "x_mm"), [1.0, 2.0, 3.0]);
        assert_eq!(imported.facts["row_range"], "[1, 4) of 6 data rows");
        let toml = base.replace("path = \"e.csv\"", "path = \"e.csv\"\nrow_range = [3, 7]");
        let err = error(&toml, dir.path());
        assert!(
            err.contains("setting `row_range`: [3, 7) ends past the 6 data rows"),
            "{err}"
        );
    }

    #[test]
    fn parquet_sources_are_cast_and_checked_by_row() {
        let dir = tempfile::tempdir().unwrap();
        let mut columns: Vec<Column> = ["a1", "a2", "a3", "a4", "a5", "a6", "x", "y"]
            .iter()
            .map(|n| Column::new((*n).into(), vec![1.0f64, 2.0]))
            .collect();
        // Integer positions in the source are fine: cast to f64.
        columns.push(Column::new("z".into(), vec![3i64, 4]));
        columns.push(Column::new(
            "t".into(),
            vec!["2026-03-02T10:00:00Z", "2026-03-02T10:00:01.5Z"],
        ));
        let mut df = crate::table::frame(columns);
        crate::table::write_parquet(&mut df, &dir.path().join("e.parquet"), None).unwrap();
        let toml = format!("path = \"e.parquet\"\n{JOINTS_XYZ}measured_at = \"t\"\n");
        let out = import(&settings(&toml), dir.path()).unwrap().measurements;
        assert_eq!(f64s(&out, "z_mm"), [3.0, 4.0]);
        let stamps = out
            .column("measured_at")
            .unwrap()
            .cast(&DataType::Int64)
            .unwrap();
        let base = crate::table::time::parse_date("2026-03-02").unwrap() * 86_400_000_000
            + 10 * 3_600_000_000;
        assert_eq!(
            stamps
                .i64()
                .unwrap()
                .into_no_null_iter()
                .collect::<Vec<_>>(),
            [base, base + 1_500_000]
        );

        let err = error(
            &format!("path = \"e.parquet\"\n{JOINTS_XYZ}").replace("\"x\"", "\"t\""),
            dir.path(),
        );
        assert!(
            err.contains("column `t` (setting `columns.x_mm`) has type str, expected a number"),
            "{err}"
        );
        let err = error(
            &format!("path = \"e.parquet\"\nseparator = \";\"\n{JOINTS_XYZ}"),
            dir.path(),
        );
        assert!(
            err.contains("setting `separator`: applies to CSV files only"),
            "{err}"
        );
    }
}
