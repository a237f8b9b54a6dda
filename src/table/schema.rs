//! Table schemas (column, type, unit, required, meaning) and the checks every table
//! passes before a stage reads it.
//!
//! The schemas live here, in code, and `schemas/tables/*.json` is generated from them
//! (a test fails when the committed files are stale), so the docs cannot drift from
//! what the checks enforce. `measurements` and `parameters` follow
//! `../shared/spec/model.md` §6 exactly; extra columns are allowed and kept.

use std::path::{Path, PathBuf};

use polars::prelude::*;
use serde::Serialize;

use crate::robot::RobotSpec;
use crate::robot::file::JointKind;

/// Logical column type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ColumnType {
    Int64,
    /// Small integers (spec §8 `dir1 … dir6`); any integer type reads.
    Int8,
    Float64,
    Utf8,
    Boolean,
    /// Microseconds since the epoch, UTC.
    TimestampUs,
}

impl ColumnType {
    pub fn polars(self) -> DataType {
        match self {
            ColumnType::Int64 => DataType::Int64,
            ColumnType::Int8 => DataType::Int8,
            ColumnType::Float64 => DataType::Float64,
            ColumnType::Utf8 => DataType::String,
            ColumnType::Boolean => DataType::Boolean,
            ColumnType::TimestampUs => {
                DataType::Datetime(TimeUnit::Microseconds, Some(TimeZone::UTC))
            }
        }
    }

    pub fn accepts(self, dtype: &DataType) -> bool {
        match self {
            ColumnType::TimestampUs => matches!(dtype, DataType::Datetime(_, _)),
            // pandas and pyarrow write an all-null column as type null (spec §7).
            ColumnType::Float64 => matches!(dtype, DataType::Float64 | DataType::Null),
            ColumnType::Utf8 => matches!(dtype, DataType::String | DataType::Null),
            ColumnType::Int8 => matches!(
                dtype,
                DataType::Int8
                    | DataType::Int16
                    | DataType::Int32
                    | DataType::Int64
                    | DataType::Null
            ),
            other => &other.polars() == dtype,
        }
    }
}

/// One column of a table kind.
#[derive(Debug, Clone, Serialize)]
pub struct ColumnSpec {
    pub name: &'static str,
    #[serde(rename = "type")]
    pub dtype: ColumnType,
    pub unit: &'static str,
    pub required: bool,
    pub meaning: &'static str,
    /// A column that stands for this one when it is absent: a prismatic
    /// joint's `q{i}_mm` for `q{i}_deg` (the robot file says which a table
    /// must carry; [`joint_vectors`] holds it to that).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alternative: Option<&'static str>,
}

/// A table kind.
#[derive(Debug, Clone, Serialize)]
pub struct TableSchema {
    pub kind: &'static str,
    pub description: &'static str,
    pub columns: Vec<ColumnSpec>,
    /// Column whose values must be unique (e.g. `cw_id`).
    pub unique: Option<&'static str>,
}

/// A problem with a table, worded the same way for every table and stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TableError {
    #[error("{file}: missing required column `{column}` ({expected}){hint}")]
    MissingColumn {
        file: PathBuf,
        column: String,
        expected: String,
        hint: String,
    },
    #[error("{file}: column `{column}` has type {found}, expected {expected}")]
    WrongType {
        file: PathBuf,
        column: String,
        found: String,
        expected: String,
    },
    #[error("{file}: column `{column}` is null at row {row} (required)")]
    Null {
        file: PathBuf,
        column: String,
        row: usize,
    },
    #[error("{file}: column `{column}` is {value} at row {row}, expected a finite number")]
    NonFinite {
        file: PathBuf,
        column: String,
        row: usize,
        value: f64,
    },
    #[error(
        "{file}: column `{column}` repeats value {value} at row {row} (first at row {first_row}); it must be unique"
    )]
    Duplicate {
        file: PathBuf,
        column: String,
        value: String,
        row: usize,
        first_row: usize,
    },
    #[error("{file}: column `{column}`, row {row}: {message}")]
    BadValue {
        file: PathBuf,
        column: String,
        row: usize,
        message: String,
    },
    #[error("{file}: {message}")]
    Io { file: PathBuf, message: String },
}

impl TableSchema {
    pub fn column(&self, name: &str) -> Option<&ColumnSpec> {
        self.columns.iter().find(|c| c.name == name)
    }

    /// Checks `df` (read from `file`) against this schema: every required column
    /// present, every known column of the right type, no nulls in required columns,
    /// no NaN or infinity in float columns, unique key unique. Reports the first
    /// problem with its column and row (0-based, as in the file).
    pub fn check(&self, df: &DataFrame, file: &Path) -> Result<(), TableError> {
        let present: Vec<&str> = df.get_column_names().iter().map(|s| s.as_str()).collect();
        for spec in &self.columns {
            let name = match spec.alternative {
                Some(alternative) if df.column(spec.name).is_err() => alternative,
                _ => spec.name,
            };
            let Ok(column) = df.column(name) else {
                if spec.required {
                    return Err(TableError::MissingColumn {
                        file: file.to_path_buf(),
                        column: spec.name.to_string(),
                        expected: format!("{:?}, {}", spec.dtype, spec.meaning),
                        hint: crate::suggest::did_you_mean(spec.name, present.iter().copied())
                            .replace("did you mean", "found"),
                    });
                }
                continue;
            };
            if !spec.dtype.accepts(column.dtype()) {
                return Err(TableError::WrongType {
                    file: file.to_path_buf(),
                    column: name.to_string(),
                    found: column.dtype().to_string(),
                    expected: spec.dtype.polars().to_string(),
                });
            }
            if spec.required && column.null_count() > 0 {
                let row = column
                    .is_null()
                    .iter()
                    .position(|n| n == Some(true))
                    .unwrap_or(0);
                return Err(TableError::Null {
                    file: file.to_path_buf(),
                    column: name.to_string(),
                    row,
                });
            }
            if spec.dtype == ColumnType::Float64 && column.dtype() == &DataType::Float64 {
                let values = column.f64().map_err(|e| io_error(file, e))?;
                if let Some((row, value)) = values
                    .iter()
                    .enumerate()
                    .find_map(|(row, v)| v.filter(|v| !v.is_finite()).map(|v| (row, v)))
                {
                    return Err(TableError::NonFinite {
                        file: file.to_path_buf(),
                        column: name.to_string(),
                        row,
                        value,
                    });
                }
            }
        }
        if let Some(key) = self.unique {
            check_unique(df, key, file)?;
        }
        Ok(())
    }
}

fn check_unique(df: &DataFrame, key: &str, file: &Path) -> Result<(), TableError> {
    let Ok(column) = df.column(key) else {
        return Ok(());
    };
    let duplicate = |value: String, row: usize, first_row: usize| TableError::Duplicate {
        file: file.to_path_buf(),
        column: key.to_string(),
        value,
        row,
        first_row,
    };
    // Integer keys (ids) are compared as integers: formatting and hashing a
    // million of them as text took a quarter of a second, and hashing them
    // as integers still 0.2 s (issue #31). Ids usually ascend (a log's
    // counter): one comparison a row; otherwise sorting finds the repeat.
    if column.dtype() == &DataType::Int64 {
        let values = column.i64().map_err(|e| io_error(file, e))?;
        let mut previous = None;
        let ascending = values.iter().all(|value| {
            let rises = value.is_some() && (previous.is_none() || previous < value);
            previous = value;
            rises
        });
        if ascending {
            return Ok(());
        }
        return match first_repeat(values.iter().collect()) {
            Some((value, row, first_row)) => {
                let shown = value.map_or_else(|| "None".to_string(), |v| v.to_string());
                Err(duplicate(shown, row, first_row))
            }
            None => Ok(()),
        };
    }
    let values: Vec<String> = column
        .cast(&DataType::String)
        .map_err(|e| io_error(file, e))?
        .str()
        .map_err(|e| io_error(file, e))?
        .iter()
        .map(|v| format!("{v:?}"))
        .collect();
    let mut seen = std::collections::HashMap::with_capacity(values.len());
    for (row, value) in values.iter().enumerate() {
        if let Some(first_row) = seen.insert(value.as_str(), row) {
            let shown = value
                .trim_start_matches("Some(")
                .trim_end_matches(')')
                .to_string();
            return Err(duplicate(shown, row, first_row));
        }
    }
    Ok(())
}

/// The first row (in table order) whose value an earlier row already has:
/// `(value, row, that earlier row)`, as a scan with a set of seen values
/// reports it, found by sorting instead of hashing.
fn first_repeat<T: Ord + Copy>(values: Vec<T>) -> Option<(T, usize, usize)> {
    let mut by_value: Vec<(T, usize)> = values.into_iter().zip(0..).collect();
    by_value.sort_unstable();
    // Equal values sit together in row order: each pair of neighbours in a
    // group is a repeat (later row, earlier row); a group's earliest repeat
    // is its second row, paired with its first.
    by_value
        .windows(2)
        .filter(|pair| pair[0].0 == pair[1].0)
        .map(|pair| (pair[1].0, pair[1].1, pair[0].1))
        .min_by_key(|(_, row, _)| *row)
}

pub(crate) fn io_error(file: &Path, e: impl std::fmt::Display) -> TableError {
    TableError::Io {
        file: file.to_path_buf(),
        message: e.to_string(),
    }
}

fn col(
    name: &'static str,
    dtype: ColumnType,
    unit: &'static str,
    required: bool,
    meaning: &'static str,
) -> ColumnSpec {
    ColumnSpec {
        name,
        dtype,
        unit,
        required,
        meaning,
        alternative: None,
    }
}

/// A joint's column `q{i}_deg`, which a prismatic joint's `q{i}_mm` replaces.
fn joint_col(joint: usize, required: bool, meaning: &'static str) -> ColumnSpec {
    ColumnSpec {
        alternative: Some(ALL_PRISMATIC_JOINT_COLUMNS[joint]),
        ..col(
            ALL_JOINT_COLUMNS[joint],
            ColumnType::Float64,
            "deg",
            required,
            meaning,
        )
    }
}

/// `q1_deg … q6_deg`: the joint commands of a conf-wrench row, and
/// `q7_deg`, a seventh joint's (required for a seven-joint robot file,
/// refused otherwise); a prismatic joint's `q{i}_mm` (mm) in place of its
/// `q{i}_deg`.
fn joint_columns(columns: &mut Vec<ColumnSpec>, meaning: &'static str) {
    for joint in 0..JOINT_COLUMNS.len() {
        columns.push(joint_col(joint, true, meaning));
    }
    columns.push(joint_col(
        JOINT_COLUMNS.len(),
        false,
        "the seventh joint's value, for a seven-joint robot file (required there, refused for a six-joint one)",
    ));
}

/// The six wrench columns of the spec (wrench on the robot, tool axes, tool origin).
pub const WRENCH_COLUMNS: [&str; 6] = ["fx_n", "fy_n", "fz_n", "mx_nm", "my_nm", "mz_nm"];
pub const JOINT_COLUMNS: [&str; 6] = ["q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg"];

/// A seventh joint's column (issue #30).
pub const SEVENTH_JOINT_COLUMN: &str = "q7_deg";

/// Every joint column a table may carry, `q1_deg … q7_deg`.
pub const ALL_JOINT_COLUMNS: [&str; crate::robot::MAX_JOINTS] = [
    "q1_deg",
    "q2_deg",
    "q3_deg",
    "q4_deg",
    "q5_deg",
    "q6_deg",
    SEVENTH_JOINT_COLUMN,
];

/// Every prismatic joint's column a table may carry, `q1_mm … q7_mm`: its
/// travel in millimetres, in place of `q{i}_deg`.
pub const ALL_PRISMATIC_JOINT_COLUMNS: [&str; crate::robot::MAX_JOINTS] = [
    "q1_mm", "q2_mm", "q3_mm", "q4_mm", "q5_mm", "q6_mm", "q7_mm",
];

/// Joint `joint`'s (0-based) column for a joint of `kind`.
pub fn joint_column_name(joint: usize, kind: JointKind) -> &'static str {
    match kind {
        JointKind::Revolute => ALL_JOINT_COLUMNS[joint],
        JointKind::Prismatic => ALL_PRISMATIC_JOINT_COLUMNS[joint],
    }
}

/// The joint columns of the robot file's arm, base to flange: `q{i}_deg`
/// for a revolute joint, `q{i}_mm` for a prismatic one (`q1_deg … q6_deg`,
/// and `q7_deg`, for a revolute arm).
pub fn joint_column_names(robot: &RobotSpec) -> Vec<&'static str> {
    robot
        .joints
        .iter()
        .take(crate::robot::MAX_JOINTS)
        .enumerate()
        .map(|(joint, spec)| joint_column_name(joint, spec.kind))
        .collect()
}

/// A joint column the robot file's arm does not have is an error: a
/// `q7_deg` for a six-joint arm, a `q3_mm` for a revolute joint 3, a
/// `q3_deg` for a prismatic one. It belongs to another robot's table, and
/// reading the table without it would drop a joint or mix units silently.
pub fn refuse_foreign_joint_columns(
    df: &DataFrame,
    file: &Path,
    robot: &RobotSpec,
) -> Result<(), TableError> {
    let own = joint_column_names(robot);
    let foreign = ALL_JOINT_COLUMNS
        .iter()
        .chain(&ALL_PRISMATIC_JOINT_COLUMNS)
        .find(|name| !own.contains(name) && df.column(name).is_ok());
    let Some(column) = foreign else {
        return Ok(());
    };
    let joint = ALL_JOINT_COLUMNS
        .iter()
        .chain(&ALL_PRISMATIC_JOINT_COLUMNS)
        .position(|name| name == column)
        .unwrap_or_default()
        % crate::robot::MAX_JOINTS;
    let message = match robot.joints.get(joint) {
        None => format!(
            "a joint {}'s value, but the robot file {} has {} joints: use the table of this robot, or drop the column",
            joint + 1,
            robot.path.display(),
            robot.joints.len()
        ),
        Some(spec) => format!(
            "joint {} of the robot file {} is {}: its values are `{}` ({}); use the table of this robot, or rename the column",
            joint + 1,
            robot.path.display(),
            match spec.kind {
                JointKind::Revolute => "revolute",
                JointKind::Prismatic => "prismatic",
            },
            own[joint],
            spec.kind.unit()
        ),
    };
    Err(TableError::BadValue {
        file: file.to_path_buf(),
        column: column.to_string(),
        row: 0,
        message,
    })
}

/// Each row's joint vector from the columns of the robot file's arm (zeros
/// past its joints; a prismatic joint's value in mm): a missing or null
/// column is an error naming it.
pub fn joint_vectors(
    df: &DataFrame,
    file: &Path,
    robot: &RobotSpec,
) -> Result<Vec<[f64; crate::robot::MAX_JOINTS]>, TableError> {
    refuse_foreign_joint_columns(df, file, robot)?;
    let columns = joint_column_names(robot)
        .iter()
        .map(|c| f64_values(df, c, file))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((0..df.height())
        .map(|k| std::array::from_fn(|i| columns.get(i).map_or(0.0, |c| c[k])))
        .collect())
}
pub const POSITION_COLUMNS: [&str; 3] = ["x_mm", "y_mm", "z_mm"];

/// Per-point tracker uncertainty columns of `measurements` (spec §7), mm.
pub const SIGMA_COLUMNS: [&str; 3] = ["sigma_x_mm", "sigma_y_mm", "sigma_z_mm"];

/// The 1-σ uncertainty of a 6-D row's orientation angles (spec §8), deg.
pub const ORIENTATION_SIGMA_COLUMNS: [&str; 3] = ["sigma_rx_deg", "sigma_ry_deg", "sigma_rz_deg"];

fn wrench_columns(columns: &mut Vec<ColumnSpec>) {
    for name in WRENCH_COLUMNS {
        let unit = if name.starts_with('f') { "N" } else { "N·m" };
        columns.push(col(
            name,
            ColumnType::Float64,
            unit,
            true,
            "wrench applied to the robot, tool-frame axes, reduced to the tool origin (0 where no load)",
        ));
    }
}

/// Conf-wrench rows: the input of `predict` and of design and measurement stages.
pub fn conf_wrenches() -> TableSchema {
    let mut columns = vec![col(
        "cw_id",
        ColumnType::Int64,
        "",
        true,
        "conf-wrench combination id, unique",
    )];
    joint_columns(&mut columns, "joint command");
    wrench_columns(&mut columns);
    for name in APPROACH_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Int8,
            "",
            false,
            "direction this joint must reach the command from (-1, 0 or +1; spec §8), as `compensate` writes for a model with backlash: `measure` moves to a pre-position first",
        ));
    }
    columns.push(track_column());
    columns.push(col(
        "target_id",
        ColumnType::Utf8,
        "",
        false,
        "which SMR the row measures (spec §7): the arm's, or a nest of the robot file's `[positioner]`, whose rows also give the positioner's axes; one target when absent",
    ));
    columns.extend(positioner_columns());
    TableSchema {
        kind: "conf_wrenches",
        description: "Joint configurations with the wrench applied at each (any table with these columns, e.g. candidates or measurements).",
        columns,
        unique: Some("cw_id"),
    }
}

/// `../shared/spec/model.md` §6 `measurements`.
pub fn measurements() -> TableSchema {
    let mut columns = vec![col(
        "cw_id",
        ColumnType::Int64,
        "",
        true,
        "conf-wrench combination id, unique",
    )];
    joint_columns(&mut columns, "joint angle read from the encoders");
    wrench_columns(&mut columns);
    for name in POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "SMR position measured in the tracker (world) frame",
        ));
    }
    columns.push(col(
        "config_id",
        ColumnType::Int64,
        "",
        false,
        "robot configuration id the row belongs to",
    ));
    columns.push(col(
        "robot_id",
        ColumnType::Utf8,
        "",
        false,
        "robot the row was measured on",
    ));
    columns.push(col(
        "measured_at",
        ColumnType::TimestampUs,
        "µs UTC",
        false,
        "time of the tracker reading",
    ));
    columns.push(col(
        "target_id",
        ColumnType::Utf8,
        "",
        false,
        "which SMR (nest) was measured; one target when absent (spec §7)",
    ));
    for name in SIGMA_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            false,
            "the tracker's 1-σ uncertainty of the point along this axis, > 0; rows are weighted by 1/σ² (spec §7)",
        ));
    }
    for name in ORIENTATION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "deg",
            false,
            "tool orientation measured by a 6-D probe, tracker (world) frame: world←tool = Rot(x, rx)·Rot(y, ry)·Rot(z, rz); all three or none (spec §8)",
        ));
    }
    for name in ORIENTATION_SIGMA_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "deg",
            false,
            "1-σ uncertainty of that orientation angle, > 0; with them the rotation residual is weighted by 1/σ² (σ the RMS of the three), else by `identify`'s `orientation_lever_mm` (spec §8)",
        ));
    }
    for name in APPROACH_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Int8,
            "",
            false,
            "direction in which this joint last moved before the reading: -1, 0 (not known) or +1; a campaign's from its previous command (spec §8)",
        ));
    }
    columns.push(track_column());
    columns.extend(positioner_columns());
    TableSchema {
        kind: "measurements",
        description: "Complete measured rows (spec §6). Incomplete rows go to measurement_failures, never here.",
        columns,
        unique: Some("cw_id"),
    }
}

/// `../shared/spec/model.md` §6 `parameters`.
pub fn parameters() -> TableSchema {
    TableSchema {
        kind: "parameters",
        description: "Parameter sets, one row per parameter and model (spec §6).",
        columns: vec![
            col(
                "model",
                ColumnType::Utf8,
                "",
                true,
                "nominal, registered, kinematic or elastogeometric",
            ),
            col(
                "name",
                ColumnType::Utf8,
                "",
                true,
                "parameter name from spec §4",
            ),
            col("unit", ColumnType::Utf8, "", true, "unit from spec §4"),
            col(
                "nominal",
                ColumnType::Float64,
                "unit",
                true,
                "nominal value",
            ),
            col(
                "value",
                ColumnType::Float64,
                "unit",
                true,
                "value in this model",
            ),
            col(
                "std_error",
                ColumnType::Float64,
                "unit",
                false,
                "standard error; null where not identified",
            ),
            col(
                "status",
                ColumnType::Utf8,
                "",
                true,
                "identified, dependent, fixed or held (spec §8: not determined by the data, kept at nominal by egcal)",
            ),
            col(
                "reason",
                ColumnType::Utf8,
                "",
                false,
                "why a parameter is held, fixed or dependent (e.g. `near-dependent on da6 (corr +1.000)`); a table without it reads as all-null",
            ),
        ],
        unique: None,
    }
}

/// `../shared/spec/model.md` §6 `measurement_failures`.
pub fn measurement_failures() -> TableSchema {
    TableSchema {
        kind: "measurement_failures",
        description: "Rows a measuring stage could not complete (spec §6).",
        columns: vec![
            col(
                "cw_id",
                ColumnType::Int64,
                "",
                true,
                "conf-wrench combination id",
            ),
            col("attempts", ColumnType::Int64, "", true, "attempts made"),
            col(
                "reason",
                ColumnType::Utf8,
                "",
                true,
                "last error (driver error, timeout, beam lost)",
            ),
            col(
                "failed_at",
                ColumnType::TimestampUs,
                "µs UTC",
                true,
                "time of the last attempt",
            ),
        ],
        unique: Some("cw_id"),
    }
}

/// Which rows calibrate and which validate.
pub fn selection() -> TableSchema {
    TableSchema {
        kind: "selection",
        description: "Role of each conf-wrench row: `calibration` (identify on it) or `validation`.",
        columns: vec![
            col(
                "cw_id",
                ColumnType::Int64,
                "",
                true,
                "conf-wrench combination id",
            ),
            col(
                "role",
                ColumnType::Utf8,
                "",
                true,
                "calibration or validation",
            ),
            col(
                "order",
                ColumnType::Int64,
                "",
                false,
                "1-based position among the calibration rows, as selected",
            ),
        ],
        unique: Some("cw_id"),
    }
}

/// Convergence of each identification (paper §III.B steps (b)–(g)).
pub fn identification_trace() -> TableSchema {
    TableSchema {
        kind: "identification_trace",
        description: "Steps tried by each identification (Levenberg–Marquardt or the paper's Gauss–Newton).",
        columns: vec![
            col(
                "model",
                ColumnType::Utf8,
                "",
                true,
                "registered, kinematic or elastogeometric",
            ),
            col(
                "iteration",
                ColumnType::Int64,
                "",
                true,
                "1-based iteration",
            ),
            col(
                "rms_mm",
                ColumnType::Float64,
                "mm",
                true,
                "residual RMS per coordinate before the step",
            ),
            col(
                "max_mm",
                ColumnType::Float64,
                "mm",
                true,
                "largest residual norm before the step",
            ),
            col(
                "step_mm",
                ColumnType::Float64,
                "mm",
                true,
                "largest change of a predicted position the step made (at the trial point against before the step)",
            ),
            col(
                "damping",
                ColumnType::Float64,
                "",
                false,
                "Levenberg–Marquardt damping λ relative to the unit-norm columns; null for the paper's undamped step",
            ),
            col(
                "accepted",
                ColumnType::Boolean,
                "",
                false,
                "whether the step was taken (Levenberg–Marquardt rejects steps that raise the cost)",
            ),
        ],
        unique: None,
    }
}

/// Per-row residuals of each identified model on its calibration rows.
pub fn residuals() -> TableSchema {
    let mut columns = vec![
        col(
            "cw_id",
            ColumnType::Int64,
            "",
            true,
            "conf-wrench combination id",
        ),
        col("model", ColumnType::Utf8, "", true, "parameter set"),
    ];
    for (name, meaning) in [
        ("rx_mm", "x residual (measured − predicted), world frame"),
        ("ry_mm", "y residual (measured − predicted), world frame"),
        ("rz_mm", "z residual (measured − predicted), world frame"),
        ("r_mm", "Euclidean norm of the residual"),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    columns.push(col(
        "weight",
        ColumnType::Float64,
        "",
        true,
        "the loss's weight of the row at the solution (1 for least squares; Huber: threshold / r beyond the threshold; 0: excluded by the robust fit)",
    ));
    columns.push(col(
        "outlier",
        ColumnType::Boolean,
        "",
        true,
        "excluded by the robust fit (loss = robust), or r_mm beyond outlier_threshold_mm (other losses)",
    ));
    TableSchema {
        kind: "residuals",
        description: "Residuals of each model on the rows it was identified from (paper eq. (23)).",
        columns,
        unique: None,
    }
}

/// The length-scale columns of `residual_model`, in the order of
/// [`crate::calibration::residual::FeatureLayout::joint_load`]'s groups.
pub const LENGTH_SCALE_COLUMNS: [&str; 12] = [
    "length_scale_q1",
    "length_scale_q2",
    "length_scale_q3",
    "length_scale_q4",
    "length_scale_q5",
    "length_scale_q6",
    "length_scale_fx",
    "length_scale_fy",
    "length_scale_fz",
    "length_scale_mx",
    "length_scale_my",
    "length_scale_mz",
];

/// The residual columns of `residual_model`: measured − the set's prediction.
pub const RESIDUAL_COLUMNS: [&str; 3] = ["residual_x_mm", "residual_y_mm", "residual_z_mm"];

/// The Gaussian-process residual of the `eg_residual` model (issue #29): its
/// training rows and hyperparameters, all a consumer needs to rebuild the same
/// posterior.
pub fn residual_model() -> TableSchema {
    let mut columns = vec![
        col(
            "model",
            ColumnType::Utf8,
            "",
            true,
            "the parameter set the residual is taken over (eg_residual)",
        ),
        col("cw_id", ColumnType::Int64, "", true, "the calibration row"),
    ];
    joint_columns(&mut columns, "measured joint angles of the row");
    wrench_columns(&mut columns);
    for name in RESIDUAL_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "measured position − the parameter set's prediction, world frame",
        ));
    }
    columns.push(col(
        "inducing",
        ColumnType::Boolean,
        "",
        true,
        "the row is an inducing point of the sparse posterior (all false: exact posterior)",
    ));
    columns.push(col(
        "signal_variance_mm2",
        ColumnType::Float64,
        "mm²",
        true,
        "prior variance of the residual per axis, the same on every row: the predictive variance far from the rows",
    ));
    columns.push(col(
        "noise_variance_mm2",
        ColumnType::Float64,
        "mm²",
        true,
        "measurement-noise variance per axis, the same on every row",
    ));
    for name in LENGTH_SCALE_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "",
            true,
            "kernel length scale of the joint (its sine and cosine) or of the wrench component (scaled by 100 N or 10 N·m), the same on every row",
        ));
    }
    TableSchema {
        kind: "residual_model",
        description: "The Gaussian-process residual of the eg_residual model over its parameter set (issue #29): training rows, inducing points and hyperparameters.",
        columns,
        unique: None,
    }
}

/// `../shared/spec/model.md` §7 `covariance`.
pub fn covariance() -> TableSchema {
    TableSchema {
        kind: "covariance",
        description: "Full covariance of each fitted model's identified parameters (spec §7), both orders.",
        columns: vec![
            col("model", ColumnType::Utf8, "", true, "parameter set"),
            col("name_i", ColumnType::Utf8, "", true, "identified parameter"),
            col("name_j", ColumnType::Utf8, "", true, "identified parameter"),
            col(
                "value",
                ColumnType::Float64,
                "unit_i·unit_j",
                true,
                "covariance, in the product of the two parameters' units",
            ),
            col(
                "variance_factor",
                ColumnType::Float64,
                "mm² (1 with per-point σ)",
                false,
                "σ² the covariance is scaled by, the same on every row of the model: the fit's residual variance per coordinate (without per-point σ), or the variance factor of the σ-weighted rows (a row's noise is then σ²·σ_row²); what `validate` adds to J·Σ·Jᵀ for its coverage",
            ),
        ],
        unique: None,
    }
}

/// Rows an identification did not use, and why.
pub fn excluded_rows() -> TableSchema {
    TableSchema {
        kind: "excluded_rows",
        description: "Measured rows left out of an identification: failed row checks (all models) or beyond the robust fit's threshold (one model).",
        columns: vec![
            col(
                "cw_id",
                ColumnType::Int64,
                "",
                true,
                "conf-wrench combination id",
            ),
            col(
                "model",
                ColumnType::Utf8,
                "",
                false,
                "the model whose robust fit excluded the row; null for a row check (every model)",
            ),
            col(
                "check",
                ColumnType::Utf8,
                "",
                true,
                "row_check (joint limits, absurd values) or robust_fit",
            ),
            col("reason", ColumnType::Utf8, "", true, "why, with the values"),
        ],
        unique: None,
    }
}

/// Which parameters the candidates can identify (rank analysis).
pub fn identifiability() -> TableSchema {
    TableSchema {
        kind: "identifiability",
        description: "Rank analysis of the scaled identification Jacobian: one row per candidate parameter.",
        columns: vec![
            col(
                "name",
                ColumnType::Utf8,
                "",
                true,
                "parameter name from spec §4",
            ),
            col("unit", ColumnType::Utf8, "", true, "unit from spec §4"),
            col(
                "identifiable",
                ColumnType::Boolean,
                "",
                true,
                "kept by the rank analysis",
            ),
            col(
                "combined_with",
                ColumnType::Utf8,
                "",
                false,
                "for a dependent parameter: the identifiable ones it is combined with (empty for a parameter with no effect at all on these rows)",
            ),
        ],
        unique: Some("name"),
    }
}

/// DETMAX exchanges (paper §IV.B).
pub fn observability() -> TableSchema {
    TableSchema {
        kind: "observability",
        description: "Each DETMAX exchange: the row added, the row removed, and O1 after it (iteration 0 is the random start); with a criterion other than O1 also that criterion's value.",
        columns: vec![
            col("iteration", ColumnType::Int64, "", true, "exchange number"),
            col("added_cw_id", ColumnType::Int64, "", false, "row added"),
            col("removed_cw_id", ColumnType::Int64, "", false, "row removed"),
            col(
                "o1",
                ColumnType::Float64,
                "",
                true,
                "observability index O1 of the selection (columns scaled to unit norm over all candidates)",
            ),
            col(
                "criterion",
                ColumnType::Utf8,
                "",
                false,
                "the index DETMAX maximised (O2–O5); present only when it is not O1",
            ),
            col(
                "criterion_value",
                ColumnType::Float64,
                "",
                false,
                "that index of the selection after the exchange (same column scaling as `o1`)",
            ),
        ],
        unique: None,
    }
}

/// Per-row position errors of each model on validation rows (paper eq. (30)).
pub fn errors() -> TableSchema {
    let mut schema = TableSchema {
        kind: "errors",
        description: "Position error (predicted − measured) of each model on each validation row.",
        columns: vec![
            col(
                "cw_id",
                ColumnType::Int64,
                "",
                true,
                "conf-wrench combination id",
            ),
            col("model", ColumnType::Utf8, "", true, "parameter set used"),
            col(
                "ex_mm",
                ColumnType::Float64,
                "mm",
                true,
                "x error, world frame",
            ),
            col(
                "ey_mm",
                ColumnType::Float64,
                "mm",
                true,
                "y error, world frame",
            ),
            col(
                "ez_mm",
                ColumnType::Float64,
                "mm",
                true,
                "z error, world frame",
            ),
            col(
                "error_mm",
                ColumnType::Float64,
                "mm",
                true,
                "Euclidean norm of the error",
            ),
        ],
        unique: None,
    };
    schema.columns.push(col(
        "error_deg",
        ColumnType::Float64,
        "deg",
        false,
        "angle between the predicted and the measured tool orientation; present when the validation rows carry orientations (spec §8)",
    ));
    position_covariance_columns(&mut schema.columns);
    schema.columns.push(col(
        "covered_95",
        ColumnType::Boolean,
        "",
        false,
        "whether the error lies inside the 95 % ellipsoid of J·Σ·Jᵀ plus the fit's residual noise; present when the input `covariance` is bound, null for a model without one",
    ));
    schema
}

/// Error statistics per model (the paper's Table III and more).
pub fn stats() -> TableSchema {
    let mut columns = vec![
        col("model", ColumnType::Utf8, "", true, "parameter set"),
        col("n", ColumnType::Int64, "", true, "validation rows"),
    ];
    for (name, meaning) in [
        ("mean_mm", "mean error norm"),
        ("std_mm", "sample standard deviation (n − 1)"),
        ("median_mm", "median"),
        ("rms_mm", "root mean square"),
        ("p95_mm", "95th percentile (linear interpolation)"),
        ("max_mm", "maximum"),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    for (name, meaning) in [
        (
            "mean_deg",
            "mean orientation error (angle between predicted and measured tool orientation); present when the validation rows carry orientations (spec §8)",
        ),
        ("rms_deg", "root mean square orientation error (6-D rows)"),
        ("max_deg", "largest orientation error (6-D rows)"),
    ] {
        columns.push(col(name, ColumnType::Float64, "deg", false, meaning));
    }
    columns.push(col(
        "coverage_95",
        ColumnType::Float64,
        "",
        false,
        "share of the rows whose error lies inside the 95 % ellipsoid of J·Σ·Jᵀ plus the fit's residual noise (0.95 when the uncertainty is honest); present when the input `covariance` is bound, null for a model without one",
    ));
    TableSchema {
        kind: "stats",
        description: "Statistics of the error norms per model on the validation rows.",
        columns,
        unique: Some("model"),
    }
}

/// Output of `accuracy`: the error the robot achieved at each target.
pub fn target_errors() -> TableSchema {
    let mut columns = vec![
        col("target_id", ColumnType::Int64, "", true, "the target's id"),
        col(
            "run",
            ColumnType::Utf8,
            "",
            true,
            "which measured run: achieved, or baseline (the same targets without compensation)",
        ),
    ];
    for (name, meaning) in [
        ("ex_mm", "x error (measured − target), world frame"),
        ("ey_mm", "y error, world frame"),
        ("ez_mm", "z error, world frame"),
        ("error_mm", "Euclidean norm of the error"),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    TableSchema {
        kind: "target_errors",
        description: "Position error the robot achieved at each target (measured tool point − target).",
        columns,
        unique: None,
    }
}

/// Output of `accuracy`: statistics of the achieved errors per run.
pub fn target_stats() -> TableSchema {
    let mut columns = vec![
        col("run", ColumnType::Utf8, "", true, "achieved or baseline"),
        col(
            "n",
            ColumnType::Int64,
            "",
            true,
            "targets compared: those measured in every run of the stage",
        ),
        col(
            "missing",
            ColumnType::Int64,
            "",
            true,
            "targets without a measurement in this run (not commanded, or failed)",
        ),
    ];
    for (name, meaning) in [
        ("mean_mm", "mean error norm"),
        ("std_mm", "sample standard deviation (n − 1)"),
        ("median_mm", "median"),
        ("rms_mm", "root mean square"),
        ("p95_mm", "95th percentile (linear interpolation)"),
        ("max_mm", "maximum"),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    TableSchema {
        kind: "target_stats",
        description: "Statistics of the achieved error norms per run.",
        columns,
        unique: Some("run"),
    }
}

/// Hypothesis tests between models on the same rows.
pub fn tests() -> TableSchema {
    TableSchema {
        kind: "tests",
        description: "Two-sided tests of equal error norms between each pair of models.",
        columns: vec![
            col("model_a", ColumnType::Utf8, "", true, "first model"),
            col("model_b", ColumnType::Utf8, "", true, "second model"),
            col(
                "test",
                ColumnType::Utf8,
                "",
                true,
                "paired_t, welch_t, student_t or wilcoxon",
            ),
            col(
                "statistic",
                ColumnType::Float64,
                "",
                true,
                "t, or the Wilcoxon signed-rank statistic",
            ),
            col(
                "dof",
                ColumnType::Float64,
                "",
                false,
                "degrees of freedom (t-tests)",
            ),
            col(
                "p_value",
                ColumnType::Float64,
                "",
                true,
                "two-sided p-value",
            ),
        ],
        unique: None,
    }
}

/// Columns shared by the crossvalidate tables: the protocol (grouping) and model.
fn protocol_and_model() -> Vec<ColumnSpec> {
    vec![
        col(
            "protocol",
            ColumnType::Utf8,
            "",
            true,
            "how the folds were made: configuration, region, load, time or random",
        ),
        col(
            "model",
            ColumnType::Utf8,
            "",
            true,
            "model identified on the other folds",
        ),
    ]
}

/// The four error figures of a set of held-out rows.
fn error_figures() -> Vec<ColumnSpec> {
    vec![
        col(
            "mean_mm",
            ColumnType::Float64,
            "mm",
            true,
            "mean error norm",
        ),
        col(
            "rms_mm",
            ColumnType::Float64,
            "mm",
            true,
            "root mean square error norm",
        ),
        col(
            "p997_mm",
            ColumnType::Float64,
            "mm",
            true,
            "99.7th percentile of the error norms (the 3σ figure vendors quote)",
        ),
        col(
            "max_mm",
            ColumnType::Float64,
            "mm",
            true,
            "largest error norm",
        ),
    ]
}

/// `crossvalidate`'s figures per fold.
pub fn crossvalidation_folds() -> TableSchema {
    let mut columns = vec![protocol_and_model().remove(0)];
    columns.push(col(
        "fold",
        ColumnType::Int64,
        "",
        true,
        "the fold validated (0-based)",
    ));
    columns.push(protocol_and_model().remove(1));
    columns.push(col(
        "calibration_rows",
        ColumnType::Int64,
        "",
        true,
        "rows of the other folds, identified on",
    ));
    columns.push(col(
        "validation_rows",
        ColumnType::Int64,
        "",
        true,
        "rows of this fold with an error",
    ));
    columns.extend(error_figures());
    TableSchema {
        kind: "crossvalidation_folds",
        description: "Held-out errors of each fold: the fold validated on a calibration of the other folds.",
        columns,
        unique: None,
    }
}

/// `crossvalidate`'s figures pooled over the folds.
pub fn crossvalidation_stats() -> TableSchema {
    let mut columns = protocol_and_model();
    columns.push(col(
        "rows",
        ColumnType::Int64,
        "",
        true,
        "held-out rows pooled over the folds",
    ));
    columns.extend(error_figures());
    TableSchema {
        kind: "crossvalidation_stats",
        description: "Held-out errors pooled over the folds, per protocol and model.",
        columns,
        unique: None,
    }
}

/// `crossvalidate`'s error of every held-out row.
pub fn crossvalidation_errors() -> TableSchema {
    let mut columns = vec![protocol_and_model().remove(0)];
    columns.push(col(
        "cw_id",
        ColumnType::Int64,
        "",
        true,
        "conf-wrench combination id",
    ));
    columns.push(col(
        "fold",
        ColumnType::Int64,
        "",
        true,
        "the row's fold (0-based)",
    ));
    columns.push(protocol_and_model().remove(1));
    columns.push(col(
        "error_mm",
        ColumnType::Float64,
        "mm",
        true,
        "norm of measured − predicted, the model identified without the row's fold",
    ));
    TableSchema {
        kind: "crossvalidation_errors",
        description: "Held-out error of every row and model.",
        columns,
        unique: None,
    }
}

/// `crossvalidate`'s paired comparisons of models on the same held-out rows.
pub fn crossvalidation_ladder() -> TableSchema {
    TableSchema {
        kind: "crossvalidation_ladder",
        description: "The model ladder on the grouped folds (issue #29): from the simplest model up, each compared with the one chosen so far on the same held-out rows; a rung is taken only when it is lower on average and both paired tests are significant.",
        columns: vec![
            protocol_and_model().remove(0),
            col(
                "model",
                ColumnType::Utf8,
                "",
                true,
                "the rung, simplest first",
            ),
            col(
                "mean_mm",
                ColumnType::Float64,
                "mm",
                true,
                "mean held-out error over the folds",
            ),
            col(
                "p997_mm",
                ColumnType::Float64,
                "mm",
                true,
                "99.7th percentile of the held-out errors",
            ),
            col(
                "max_mm",
                ColumnType::Float64,
                "mm",
                true,
                "largest held-out error",
            ),
            col(
                "compared_with",
                ColumnType::Utf8,
                "",
                false,
                "the rung chosen so far it was compared with; null for the first",
            ),
            col(
                "mean_difference_mm",
                ColumnType::Float64,
                "mm",
                false,
                "mean of this rung's error minus the other's, row by row",
            ),
            col(
                "paired_t_p",
                ColumnType::Float64,
                "",
                false,
                "paired t-test p-value (null: the errors are identical)",
            ),
            col(
                "wilcoxon_p",
                ColumnType::Float64,
                "",
                false,
                "Wilcoxon signed-rank p-value",
            ),
            col(
                "accepted",
                ColumnType::Boolean,
                "",
                true,
                "the climb moved to this rung (or started at it)",
            ),
            col(
                "chosen",
                ColumnType::Boolean,
                "",
                true,
                "the model chosen: the last rung accepted",
            ),
            col(
                "reason",
                ColumnType::Utf8,
                "",
                true,
                "why, with the figures",
            ),
        ],
        unique: None,
    }
}

pub fn crossvalidation_tests() -> TableSchema {
    TableSchema {
        kind: "crossvalidation_tests",
        description: "Paired two-sided tests between each pair of models on the same held-out rows.",
        columns: vec![
            protocol_and_model().remove(0),
            col("model_a", ColumnType::Utf8, "", true, "first model"),
            col("model_b", ColumnType::Utf8, "", true, "second model"),
            col(
                "rows",
                ColumnType::Int64,
                "",
                true,
                "rows both models predicted",
            ),
            col(
                "mean_difference_mm",
                ColumnType::Float64,
                "mm",
                true,
                "mean of model_a's error minus model_b's, row by row",
            ),
            col(
                "paired_t_p",
                ColumnType::Float64,
                "",
                true,
                "paired t-test p-value",
            ),
            col(
                "wilcoxon_p",
                ColumnType::Float64,
                "",
                true,
                "Wilcoxon signed-rank p-value",
            ),
        ],
        unique: None,
    }
}

/// Generated robot configurations (paper §IV.A (a)–(b)).
pub fn poses() -> TableSchema {
    let mut columns = vec![col(
        "config_id",
        ColumnType::Int64,
        "",
        true,
        "configuration id, unique",
    )];
    for (name, meaning) in [
        (
            "target_x_mm",
            "target SMR position, base frame (on a track: the base at the row's carriage position)",
        ),
        (
            "target_y_mm",
            "target SMR position, base frame (on a track: the base at the row's carriage position)",
        ),
        (
            "target_z_mm",
            "target SMR position, base frame (on a track: the base at the row's carriage position)",
        ),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    for name in ["tool_alpha_deg", "tool_beta_deg", "tool_gamma_deg"] {
        columns.push(col(
            name,
            ColumnType::Float64,
            "deg",
            true,
            "tool orientation in the base frame, Rot(x)·Rot(y)·Rot(z) as eq. (4)",
        ));
    }
    joint_columns(&mut columns, "joint command (nominal inverse kinematics)");
    columns.push(col(
        "branch",
        ColumnType::Int64,
        "",
        true,
        "IK branch: bit 0 shoulder back, bit 1 elbow down, bit 2 wrist flipped",
    ));
    columns.push(col(
        "clearance_mm",
        ColumnType::Float64,
        "mm",
        true,
        "smallest distance to any obstacle, link or beam",
    ));
    columns.push(col(
        "incidence_deg",
        ColumnType::Float64,
        "deg",
        true,
        "angle between the SMR axis and the direction to the tracker",
    ));
    columns.push(track_column());
    TableSchema {
        kind: "poses",
        description: "Robot configurations that reach the target points with the SMR facing the tracker, collision-free.",
        columns,
        unique: Some("config_id"),
    }
}

/// Conf-wrench candidates with the cable tensions that realise them (paper §IV.A (c)).
pub fn candidates() -> TableSchema {
    let mut schema = conf_wrenches();
    schema.kind = "candidates";
    schema.description =
        "Conf-wrench combinations: each configuration with wrenches feasible for the cable robot.";
    schema.columns.push(col(
        "config_id",
        ColumnType::Int64,
        "",
        true,
        "configuration the row belongs to",
    ));
    for name in TENSION_COLUMNS {
        schema.columns.push(col(
            name,
            ColumnType::Float64,
            "N",
            false,
            "cable tension (minimum-norm distribution); null on a row measuring a positioner's nest, which the cable robot does not load",
        ));
    }
    schema.columns.push(col("margin_n", ColumnType::Float64, "N", false, "capacity margin: distance of the wrench inside the available wrench set (moments scaled, see cdpr); null on a nest's row"));
    schema
}

pub const TENSION_COLUMNS: [&str; 8] = [
    "tension1_n",
    "tension2_n",
    "tension3_n",
    "tension4_n",
    "tension5_n",
    "tension6_n",
    "tension7_n",
    "tension8_n",
];

/// The predicted-position uncertainty columns (spec §7) and the entry of the
/// 3 × 3 covariance each holds.
pub const POSITION_COVARIANCE_COLUMNS: [(&str, usize, usize); 6] = [
    ("cov_xx_mm2", 0, 0),
    ("cov_xy_mm2", 0, 1),
    ("cov_xz_mm2", 0, 2),
    ("cov_yy_mm2", 1, 1),
    ("cov_yz_mm2", 1, 2),
    ("cov_zz_mm2", 2, 2),
];

/// The optional §7 uncertainty columns, present when the stage's `covariance`
/// input is bound.
fn position_covariance_columns(columns: &mut Vec<ColumnSpec>) {
    for (name, _, _) in POSITION_COVARIANCE_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm²",
            false,
            "covariance of the predicted position from the parameters' covariance alone (J·Σ·Jᵀ, world frame, measurement noise not included); present when the input `covariance` is bound, null for a model without one",
        ));
    }
}

/// Output of `predict`.
pub fn predictions() -> TableSchema {
    let mut columns = vec![col(
        "cw_id",
        ColumnType::Int64,
        "",
        true,
        "conf-wrench combination id",
    )];
    for name in POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "predicted SMR position in the world frame",
        ));
    }
    for (name, force) in TORQUE_COLUMNS.into_iter().zip(FORCE_COLUMNS) {
        columns.push(ColumnSpec {
            alternative: Some(force),
            ..col(
                name,
                ColumnType::Float64,
                "N·m",
                true,
                "load torque on the joint (gravity and external wrench); a prismatic joint's force{i}_n (N, along its axis) in its place",
            )
        });
    }
    for (name, slide) in DEFLECTION_COLUMNS.into_iter().zip(SLIDE_DEFLECTION_COLUMNS) {
        columns.push(ColumnSpec {
            alternative: Some(slide),
            ..col(
                name,
                ColumnType::Float64,
                "deg",
                true,
                "compliance deflection k_i·tau_i; a prismatic joint's dq{i}_mm (mm) in its place",
            )
        });
    }
    position_covariance_columns(&mut columns);
    TableSchema {
        kind: "predictions",
        description: "Model predictions for conf-wrench rows: position, load torques, deflections.",
        columns,
        unique: Some("cw_id"),
    }
}

/// Orientation columns of `targets` (spec §7): world←tool = Rot(x, rx)·Rot(y, ry)·Rot(z, rz).
pub const ORIENTATION_COLUMNS: [&str; 3] = ["rx_deg", "ry_deg", "rz_deg"];

/// Approach direction of each joint (spec §8).
pub const APPROACH_COLUMNS: [&str; 6] = ["dir1", "dir2", "dir3", "dir4", "dir5", "dir6"];

/// The carriage's position on the robot's linear track (issue #30).
pub const TRACK_COLUMN: &str = "e1_mm";

/// How far a command's carriage position lies beyond the calibration rows'
/// positions (`commands`, a robot on a track with an envelope).
pub const TRACK_BEYOND_COLUMN: &str = "track_beyond_mm";

/// A positioner's axis values (robot file `[positioner]`), deg.
pub const POSITIONER_COLUMNS: [&str; crate::robot::positioner::MAX_POSITIONER_AXES] =
    ["p1_deg", "p2_deg"];

/// The optional [`POSITIONER_COLUMNS`] of a table of rows.
fn positioner_columns() -> [ColumnSpec; crate::robot::positioner::MAX_POSITIONER_AXES] {
    [
        col(
            POSITIONER_COLUMNS[0],
            ColumnType::Float64,
            "deg",
            false,
            "value of the positioner's first axis (robot file `[positioner]`), within its `limits_deg`: in measurements, the axis when the row was measured (required on rows whose `target_id` is one of the positioner's `nests`); in targets and commands, the axis the target on the table is reached at (required on targets in the frame `positioner`); only allowed when the robot file has a positioner",
        ),
        col(
            POSITIONER_COLUMNS[1],
            ColumnType::Float64,
            "deg",
            false,
            "value of the positioner's second axis, as `p1_deg`; only allowed for a two-axis positioner",
        ),
    ]
}

/// The optional [`TRACK_COLUMN`] of a table of rows.
fn track_column() -> ColumnSpec {
    col(
        TRACK_COLUMN,
        ColumnType::Float64,
        "mm",
        false,
        "position of the carriage on the robot's linear track (robot file `[track]`), within its `travel_mm`; required, and only allowed, when the robot file has a track",
    )
}
/// The corrected Cartesian target of `commands` (spec §7), robot base frame.
pub const COMMAND_POSITION_COLUMNS: [&str; 3] = ["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"];
/// Its orientation as a unit quaternion (w, x, y, z), base←tool.
pub const COMMAND_QUATERNION_COLUMNS: [&str; 4] = ["qw_cmd", "qx_cmd", "qy_cmd", "qz_cmd"];

/// `targets` (spec §7): where the tool must be, and the wrench on it there.
pub fn targets() -> TableSchema {
    let mut columns = vec![col(
        "target_id",
        ColumnType::Int64,
        "",
        true,
        "target id, unique; commands keep it",
    )];
    for name in POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "tool point in the tracker (world) frame",
        ));
    }
    for name in ORIENTATION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "deg",
            true,
            "tool orientation in the world frame: world←tool = Rot(x, rx)·Rot(y, ry)·Rot(z, rz)",
        ));
    }
    for name in WRENCH_COLUMNS {
        let unit = if name.starts_with('f') { "N" } else { "N·m" };
        columns.push(col(
            name,
            ColumnType::Float64,
            unit,
            false,
            "wrench on the robot at this target, tool axes, at the tool origin (0 when absent)",
        ));
    }
    for joint in 0..ALL_JOINT_COLUMNS.len() {
        columns.push(joint_col(
            joint,
            false,
            "a configuration near the wanted one (branch hint; q7_deg only for a seven-joint robot file, whose held joint 3 the hint sets; a prismatic joint's q{i}_mm in place of its q{i}_deg)",
        ));
    }
    columns.push(col(
        "frame",
        ColumnType::Utf8,
        "",
        false,
        "frame of the row's pose (spec §8): world (the tracker frame), base (the robot's base frame) or a user frame the compensate stage's `frames` setting declares; null or absent: the stage's `frame` setting (default world)",
    ));
    columns.push(col(
        "tool_id",
        ColumnType::Utf8,
        "",
        false,
        "which target (SMR nest, tool) of the parameters' set must be on the pose (spec §8); null or absent: the stage's `tool` setting; needed with a several-target set",
    ));
    columns.push(track_column());
    columns.extend(positioner_columns());
    TableSchema {
        kind: "targets",
        description: "Where the tool must be (spec §7, §8): what a `compensate` stage reads. Stages that compare with tracker measurements (accuracy, iso9283) take world-frame rows only.",
        columns,
        unique: Some("target_id"),
    }
}

/// `commands` (spec §7): the joint command per target and what it corrects.
pub fn commands() -> TableSchema {
    let mut columns = vec![col(
        "target_id",
        ColumnType::Int64,
        "",
        true,
        "the target's id",
    )];
    for joint in 0..JOINT_COLUMNS.len() {
        columns.push(joint_col(
            joint,
            true,
            "joint command that puts the calibrated, loaded robot's tool on the target (status ok); the solver's last iterate otherwise (a prismatic joint's q{i}_mm, mm, in its place)",
        ));
    }
    columns.push(joint_col(
        JOINT_COLUMNS.len(),
        false,
        "a seven-joint robot file's joint 7",
    ));
    columns.push(col(
        "status",
        ColumnType::Utf8,
        "",
        true,
        "ok, or why not: unreachable, joint_limit, singular, not_converged, outside_envelope (spec §8: farther from the calibration rows, or more uncertain, than the stage allows)",
    ));
    columns.push(col(
        "residual_mm",
        ColumnType::Float64,
        "mm",
        true,
        "position error the solve left at the target",
    ));
    columns.push(col(
        "correction_mm",
        ColumnType::Float64,
        "mm",
        true,
        "distance between where the nominal model puts this command and the target",
    ));
    columns.push(col(
        "elastic_mm",
        ColumnType::Float64,
        "mm",
        true,
        "the part of the correction due to the load",
    ));
    for name in COMMAND_POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "corrected Cartesian target for a controller with its nominal model: nominal FK of the command, nominal flange→tool, robot base frame",
        ));
    }
    for name in COMMAND_QUATERNION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "",
            true,
            "orientation of the corrected Cartesian target, unit quaternion (w, x, y, z), base←tool",
        ));
    }
    columns.push(col(
        "tool_id",
        ColumnType::Utf8,
        "",
        false,
        "the parameters' target (SMR nest, tool) the command puts on the target; null for a one-target set given no tool id",
    ));
    columns.push(col(
        "envelope_distance",
        ColumnType::Float64,
        "deg",
        false,
        "joint-space distance of the command to the nearest calibration row: the largest per-joint difference (wrapped to ±180°) over joints 1–6 (spec §8); null without envelope rows",
    ));
    columns.push(col(
        "u95_mm",
        ColumnType::Float64,
        "mm",
        false,
        "radius of the predicted position's 95 % uncertainty, sqrt(χ²₃(0.95)·λmax(J·Σ·Jᵀ)) (spec §8); null without a covariance",
    ));
    columns.push(col(
        TRACK_BEYOND_COLUMN,
        ColumnType::Float64,
        "mm",
        false,
        "a robot on a linear track: how far the command's carriage position lies beyond the calibration rows' positions (0 between them); absent without a track or an envelope",
    ));
    position_covariance_columns(&mut columns);
    for name in APPROACH_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Int8,
            "",
            false,
            "direction this joint must reach the command from for the model's backlash to hold: -1 or +1 (0: any); a program moves so with a pre-positioning move (spec §8); absent when no direction was used",
        ));
    }
    columns.push(track_column());
    columns.extend(positioner_columns());
    TableSchema {
        kind: "commands",
        description: "Joint commands per target and the corrected Cartesian targets (spec §7): what `compensate` writes.",
        columns,
        unique: Some("target_id"),
    }
}

/// `envelope` of a `compensate` stage: the calibration rows' configurations
/// (any table with `cw_id` and the six joint columns, e.g. the measurements
/// `identify` was given).
pub fn envelope() -> TableSchema {
    let mut columns = vec![col(
        "cw_id",
        ColumnType::Int64,
        "",
        true,
        "row id (a selection's calibration rows are chosen by it)",
    )];
    joint_columns(
        &mut columns,
        "a configuration the calibration was identified on",
    );
    TableSchema {
        kind: "envelope",
        description: "The configurations a calibration was identified on (spec §8): `compensate` measures each command's joint-space distance to the nearest of them.",
        columns,
        unique: Some("cw_id"),
    }
}

/// `targets` of an ISO 9283 test (what `iso_cube` writes): the spec §7
/// `targets` columns, one row per visit in the order the robot runs them, with
/// the point and the cycle each row is. A `compensate` stage reads it as any
/// `targets` table (extra columns are allowed).
pub fn iso_targets() -> TableSchema {
    let mut schema = targets();
    schema.kind = "iso_targets";
    schema.description = "An ISO 9283 cycle plan as targets (spec §7 columns), one row per visit in running order: what `iso_cube` writes and `compensate` reads.";
    schema.columns.push(col(
        "point",
        ColumnType::Utf8,
        "",
        true,
        "ISO 9283 test point: P1 (cube centre) … P5",
    ));
    schema.columns.push(col(
        "cycle",
        ColumnType::Int64,
        "",
        true,
        "test cycle, from 1",
    ));
    schema
}

/// Input of `iso9283`: the positions an ISO 9283 pose test attained.
pub fn iso_measurements() -> TableSchema {
    let mut columns = vec![
        col(
            "point",
            ColumnType::Utf8,
            "",
            true,
            "ISO 9283 test point: P1 … P5",
        ),
        col(
            "cycle",
            ColumnType::Int64,
            "",
            true,
            "test cycle; one row per (point, cycle)",
        ),
    ];
    for name in COMMAND_POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "commanded position of the point, tracker (world) frame; the same in every cycle",
        ));
    }
    for name in POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "attained position measured by the tracker, tracker (world) frame",
        ));
    }
    TableSchema {
        kind: "iso_measurements",
        description: "Commanded and attained positions of an ISO 9283 pose test, one row per point and cycle: what `iso9283` reads.",
        columns,
        unique: None,
    }
}

/// Output of `iso9283`: pose accuracy and repeatability per point (positions only).
pub fn iso9283() -> TableSchema {
    let mut columns = vec![
        col("point", ColumnType::Utf8, "", true, "ISO 9283 test point"),
        col("n", ColumnType::Int64, "", true, "cycles measured"),
    ];
    for (name, meaning) in [
        (
            "ap_mm",
            "pose accuracy AP_P: distance of the barycentre of the attained positions from the commanded one",
        ),
        ("apx_mm", "x̄ − x_c, tracker frame"),
        ("apy_mm", "ȳ − y_c, tracker frame"),
        ("apz_mm", "z̄ − z_c, tracker frame"),
        (
            "rp_mm",
            "pose repeatability RP_l = l̄ + 3·S_l, l the distances from the barycentre, S_l with the n − 1 divisor",
        ),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    TableSchema {
        kind: "iso9283",
        description: "ISO 9283 §7.2 pose accuracy and repeatability per test point, positions only.",
        columns,
        unique: Some("point"),
    }
}

/// Output of `iso9283`: distance accuracy and repeatability per pair of points.
pub fn iso9283_distances() -> TableSchema {
    let mut columns = vec![
        col(
            "from",
            ColumnType::Utf8,
            "",
            true,
            "first point of the pair",
        ),
        col("to", ColumnType::Utf8, "", true, "second point of the pair"),
        col(
            "n",
            ColumnType::Int64,
            "",
            true,
            "cycles in which both points were measured",
        ),
    ];
    for (name, meaning) in [
        ("d_cmd_mm", "commanded distance D_c"),
        ("d_mean_mm", "mean attained distance D̄"),
        ("ad_mm", "distance accuracy AD = |D̄ − D_c|"),
        (
            "rd_mm",
            "distance repeatability RD = 3·S_D, S_D with the n − 1 divisor (the standard writes ±RD)",
        ),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    TableSchema {
        kind: "iso9283_distances",
        description: "ISO 9283 §7.3 distance accuracy and repeatability per pair of test points, positions only.",
        columns,
        unique: None,
    }
}

/// Output of `accuracy_map`: the predicted 95 % position uncertainty per grid
/// point around the calibration rows (`crate::calibration::accuracy_map`).
pub fn accuracy_map() -> TableSchema {
    let mut columns = vec![
        col(
            "point_id",
            ColumnType::Int64,
            "",
            true,
            "grid point, 0-based, slice by slice, y then x within a slice",
        ),
        col(
            "slice",
            ColumnType::Int64,
            "",
            true,
            "horizontal slice (world z level), 0 at the bottom",
        ),
    ];
    for name in POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "grid point, world (tracker) frame",
        ));
    }
    columns.push(col(
        "inside_box",
        ColumnType::Boolean,
        "",
        true,
        "whether the point lies in the bounding box of the calibration rows' tool positions (false: in the margin, an extrapolation)",
    ));
    columns.push(col(
        "status",
        ColumnType::Utf8,
        "",
        true,
        "reachable, unreachable (no configuration within the joint limits) or singular; only reachable points have an uncertainty",
    ));
    joint_columns(
        &mut columns,
        "configuration used: nominal IK for the orientation of the nearest calibration pose, the solution closest to its configuration; null when not reachable",
    );
    for column in columns.iter_mut().filter(|c| c.name.starts_with('q')) {
        column.required = false;
    }
    columns.push(col(
        TRACK_COLUMN,
        ColumnType::Float64,
        "mm",
        false,
        "on a robot's linear track: the carriage position the point is reached from, its nearest calibration row's; null when not reachable, absent without a track",
    ));
    position_covariance_columns(&mut columns);
    for column in columns.iter_mut().filter(|c| c.name.starts_with("cov_")) {
        column.meaning = "covariance of the position from the parameters' covariance alone (J·Σ·Jᵀ, world frame, no external wrench, measurement noise not included); null when not reachable";
    }
    columns.push(col(
        "u95_mm",
        ColumnType::Float64,
        "mm",
        false,
        "radius of the 95 % uncertainty: sqrt(χ²₃(0.95)·λ_max(J·Σ·Jᵀ)), the longest semi-axis of the 95 % ellipsoid; null when not reachable",
    ));
    TableSchema {
        kind: "accuracy_map",
        description: "Predicted 95 % position uncertainty over a grid of the workspace the calibration rows covered, and a margin beyond it.",
        columns,
        unique: Some("point_id"),
    }
}

/// Output of `accuracy_map`: the calibration rows' tool positions the map was
/// built around.
pub fn calibration_positions() -> TableSchema {
    let mut columns = vec![col("cw_id", ColumnType::Int64, "", true, "calibration row")];
    for name in POSITION_COLUMNS {
        columns.push(col(
            name,
            ColumnType::Float64,
            "mm",
            true,
            "unloaded tool position under the calibrated parameters, world (tracker) frame",
        ));
    }
    TableSchema {
        kind: "calibration_positions",
        description: "Tool positions of the calibration rows an accuracy map was built around.",
        columns,
        unique: Some("cw_id"),
    }
}

/// Output of `select` with the `targets` input: the predicted uncertainty of
/// the selected rows at each work target.
pub fn work_targets() -> TableSchema {
    let mut columns = vec![
        col(
            "target_id",
            ColumnType::Int64,
            "",
            true,
            "target of the `targets` input",
        ),
        col(
            "status",
            ColumnType::Utf8,
            "",
            true,
            "status of the target's nominal loaded IK (as `compensate` with model = nominal); only `ok` targets are designed for",
        ),
    ];
    joint_columns(
        &mut columns,
        "the target's configuration: nominal loaded IK, seeded by its branch hint or the previous target's solution",
    );
    columns.push(col(
        "branch",
        ColumnType::Int64,
        "",
        false,
        "IK branch of that configuration: bit 0 shoulder back, bit 1 elbow down, bit 2 wrist flipped; null when the target is not ok",
    ));
    position_covariance_columns(&mut columns);
    for column in columns
        .iter_mut()
        .filter(|c| c.name.starts_with("cov_") || c.name.starts_with('q'))
    {
        column.required = false;
    }
    for column in columns.iter_mut().filter(|c| c.name.starts_with("cov_")) {
        column.meaning = "predicted covariance of the position after identification on the selected rows, σ²·J_t·(JᵀJ)⁻¹·J_tᵀ with σ the setting tracker_sigma_mm (world frame, nominal model, the target's wrench); null when the target is not ok";
    }
    columns.push(col(
        "u95_mm",
        ColumnType::Float64,
        "mm",
        false,
        "sqrt(χ²₃(0.95)·λ_max) of that covariance, the longest semi-axis of the 95 % ellipsoid; null when the target is not ok",
    ));
    TableSchema {
        kind: "work_targets",
        description: "Predicted 95 % position uncertainty at each work target after identification on the selected rows.",
        columns,
        unique: Some("target_id"),
    }
}

/// Output of `select` with the `targets` input: the stopping rule's curve.
pub fn u95_curve() -> TableSchema {
    TableSchema {
        kind: "u95_curve",
        description: "Predicted u95 at the work targets of the best n rows found, against n (the stopping rule).",
        columns: vec![
            col("n", ColumnType::Int64, "", true, "rows selected"),
            col(
                "mean_u95_mm",
                ColumnType::Float64,
                "mm",
                true,
                "mean over the ok targets of the predicted u95",
            ),
            col(
                "max_u95_mm",
                ColumnType::Float64,
                "mm",
                true,
                "largest predicted u95 over the ok targets",
            ),
        ],
        unique: Some("n"),
    }
}

pub const TORQUE_COLUMNS: [&str; 6] = [
    "tau1_nm", "tau2_nm", "tau3_nm", "tau4_nm", "tau5_nm", "tau6_nm",
];
pub const DEFLECTION_COLUMNS: [&str; 6] = [
    "dq1_deg", "dq2_deg", "dq3_deg", "dq4_deg", "dq5_deg", "dq6_deg",
];
/// A prismatic joint's load (the force along its axis, N) in place of its
/// `tau{i}_nm`.
pub const FORCE_COLUMNS: [&str; 6] = [
    "force1_n", "force2_n", "force3_n", "force4_n", "force5_n", "force6_n",
];
/// A prismatic joint's deflection (mm) in place of its `dq{i}_deg`.
pub const SLIDE_DEFLECTION_COLUMNS: [&str; 6] =
    ["dq1_mm", "dq2_mm", "dq3_mm", "dq4_mm", "dq5_mm", "dq6_mm"];

/// Every table kind, for schema generation and `egcal show`.
/// The nightly gate's decision: one row.
pub fn gate_decision() -> TableSchema {
    let mut columns = vec![
        col(
            "decision",
            ColumnType::Utf8,
            "",
            true,
            "kept, published or refused",
        ),
        col(
            "reasons",
            ColumnType::Utf8,
            "",
            true,
            "why, one sentence per line",
        ),
        col("model", ColumnType::Utf8, "", true, "the model compared"),
        col(
            "holdout_rows",
            ColumnType::Int64,
            "",
            true,
            "hold-out rows compared",
        ),
        col(
            "in_service_mean_mm",
            ColumnType::Float64,
            "mm",
            true,
            "in-service set's mean hold-out error",
        ),
        col(
            "candidate_mean_mm",
            ColumnType::Float64,
            "mm",
            true,
            "candidate's mean hold-out error",
        ),
        col(
            "t_statistic",
            ColumnType::Float64,
            "",
            false,
            "paired t of in-service minus candidate errors; null when all differences are equal",
        ),
        col("dof", ColumnType::Float64, "", false, "degrees of freedom"),
        col(
            "p_value",
            ColumnType::Float64,
            "",
            false,
            "two-sided p-value",
        ),
    ];
    for (name, meaning) in [
        (
            "mean_position_change_mm",
            "mean predicted position change over the reference poses",
        ),
        (
            "max_position_change_mm",
            "largest predicted position change over the reference poses",
        ),
    ] {
        columns.push(col(name, ColumnType::Float64, "mm", true, meaning));
    }
    columns.push(col(
        "drift_since",
        ColumnType::Utf8,
        "",
        false,
        "first day (YYYY-MM-DD) of a significant rise of the in-service error in the window",
    ));
    columns.push(col(
        "published_as",
        ColumnType::Utf8,
        "",
        false,
        "the installed file, when published",
    ));
    columns.push(col(
        "retired_as",
        ColumnType::Utf8,
        "",
        false,
        "where the replaced calibration was kept, when published",
    ));
    TableSchema {
        kind: "gate_decision",
        description: "Whether the night's candidate calibration replaced the one in service, and why.",
        columns,
        unique: None,
    }
}

/// A fleet's night, one row per robot (`egcal fleet gather`).
pub fn fleet_decisions() -> TableSchema {
    use ColumnType::{Float64, Int64, Utf8};
    let spec: [(&'static str, ColumnType, &'static str, bool, &'static str); 17] = [
        ("run_date", Utf8, "", true, "the night, YYYY-MM-DD"),
        ("robot_id", Utf8, "", true, "the robot"),
        (
            "outcome",
            Utf8,
            "",
            true,
            "kept, published, refused, failed, or missing (no record: the task never ran or was killed)",
        ),
        (
            "exit_code",
            Int64,
            "",
            false,
            "`egcal run`'s exit code for this night alone; null when missing",
        ),
        (
            "task_index",
            Int64,
            "",
            false,
            "array task that ran it (`fleet submit`); null for `fleet run`",
        ),
        ("gate_stage", Utf8, "", false, "the job's first gate stage"),
        ("gate_decision", Utf8, "", false, "its decision"),
        ("reasons", Utf8, "", false, "why, one sentence per line"),
        ("holdout_rows", Int64, "", false, "hold-out rows compared"),
        (
            "in_service_mean_mm",
            Float64,
            "mm",
            false,
            "in-service set's mean hold-out error",
        ),
        (
            "candidate_mean_mm",
            Float64,
            "mm",
            false,
            "candidate's mean hold-out error",
        ),
        (
            "p_value",
            Float64,
            "",
            false,
            "the gate test's two-sided p-value",
        ),
        (
            "max_position_change_mm",
            Float64,
            "mm",
            false,
            "largest predicted position change over the reference poses",
        ),
        (
            "published_as",
            Utf8,
            "",
            false,
            "the installed file, when published",
        ),
        ("message", Utf8, "", true, "the job's summary, or its error"),
        ("host", Utf8, "", false, "the machine that ran it"),
        (
            "seconds",
            Float64,
            "s",
            false,
            "wall-clock time of the night",
        ),
    ];
    TableSchema {
        kind: "fleet_decisions",
        description: "Every robot's decision of one fleet night, gathered from the nights' records.",
        columns: spec
            .into_iter()
            .map(|(name, dtype, unit, required, meaning)| col(name, dtype, unit, required, meaning))
            .collect(),
        unique: Some("robot_id"),
    }
}

/// Per-parameter change between the in-service set and the candidate.
pub fn parameter_changes() -> TableSchema {
    TableSchema {
        kind: "parameter_changes",
        description: "Candidate minus in-service value of each parameter either set identifies, in units of its standard error.",
        columns: vec![
            col("name", ColumnType::Utf8, "", true, "parameter (spec §3)"),
            col("unit", ColumnType::Utf8, "", true, "unit of the values"),
            col(
                "in_service",
                ColumnType::Float64,
                "",
                true,
                "in-service value",
            ),
            col(
                "candidate",
                ColumnType::Float64,
                "",
                true,
                "candidate value",
            ),
            col(
                "change",
                ColumnType::Float64,
                "",
                true,
                "candidate − in-service",
            ),
            col(
                "std_error",
                ColumnType::Float64,
                "",
                false,
                "√(se_candidate² + se_in_service²) of the available standard errors",
            ),
            col(
                "z",
                ColumnType::Float64,
                "",
                false,
                "change / std_error; |z| > 3 is a change the data sees",
            ),
        ],
        unique: Some("name"),
    }
}

/// Per-day errors of both sets over the scanned window.
pub fn daily_errors() -> TableSchema {
    TableSchema {
        kind: "daily_errors",
        description: "Mean error norm per logged day of the in-service set and the candidate.",
        columns: vec![
            col("date", ColumnType::Utf8, "", true, "day (UTC), YYYY-MM-DD"),
            col("rows", ColumnType::Int64, "", true, "rows logged that day"),
            col(
                "role",
                ColumnType::Utf8,
                "",
                true,
                "calibration or validation (the day's rows in the selection)",
            ),
            col(
                "in_service_mean_mm",
                ColumnType::Float64,
                "mm",
                true,
                "in-service set's mean error",
            ),
            col(
                "candidate_mean_mm",
                ColumnType::Float64,
                "mm",
                true,
                "candidate's mean error",
            ),
        ],
        unique: Some("date"),
    }
}

pub fn all() -> Vec<TableSchema> {
    vec![
        conf_wrenches(),
        measurements(),
        measurement_failures(),
        parameters(),
        predictions(),
        targets(),
        commands(),
        envelope(),
        iso_targets(),
        iso_measurements(),
        iso9283(),
        iso9283_distances(),
        accuracy_map(),
        calibration_positions(),
        work_targets(),
        u95_curve(),
        target_errors(),
        target_stats(),
        selection(),
        identification_trace(),
        residuals(),
        covariance(),
        residual_model(),
        excluded_rows(),
        identifiability(),
        observability(),
        errors(),
        stats(),
        tests(),
        crossvalidation_folds(),
        crossvalidation_stats(),
        crossvalidation_errors(),
        crossvalidation_tests(),
        crossvalidation_ladder(),
        poses(),
        candidates(),
        gate_decision(),
        parameter_changes(),
        daily_errors(),
        fleet_decisions(),
    ]
}

/// Values of a required f64 column (after [`TableSchema::check`]).
pub fn f64_values(df: &DataFrame, name: &str, file: &Path) -> Result<Vec<f64>, TableError> {
    let column = df.column(name).map_err(|e| io_error(file, e))?;
    let values = column.f64().map_err(|e| io_error(file, e))?;
    Ok(values_or(values, f64::NAN))
}

/// A column's values with nulls as `null`: without nulls, copied as slices (a value at a time through `Option`s, a million-row table's
/// columns took a tenth of a second each, issue #31).
fn values_or<T>(values: &ChunkedArray<T>, null: T::Native) -> Vec<T::Native>
where
    T: PolarsNumericType,
{
    if values.null_count() > 0 {
        return values.iter().map(|v| v.unwrap_or(null)).collect();
    }
    let mut out = Vec::with_capacity(values.len());
    for chunk in values.downcast_iter() {
        out.extend_from_slice(chunk.values().as_slice());
    }
    out
}

/// Values of a required i64 column (after [`TableSchema::check`]).
pub fn i64_values(df: &DataFrame, name: &str, file: &Path) -> Result<Vec<i64>, TableError> {
    let column = df.column(name).map_err(|e| io_error(file, e))?;
    let values = column.i64().map_err(|e| io_error(file, e))?;
    Ok(values_or(values, 0))
}

/// Values of an optional column the schema does not declare: `None` when the
/// table has no such column, else its values (nulls as `None`); a column of
/// another type than `dtype` is an error naming it. An all-null column written
/// by pandas (type null) reads as nulls.
fn optional_values<T>(
    df: &DataFrame,
    name: &str,
    file: &Path,
    dtype: ColumnType,
    values: impl Fn(&Column) -> PolarsResult<Vec<Option<T>>>,
) -> Result<Option<Vec<Option<T>>>, TableError> {
    let Ok(column) = df.column(name) else {
        return Ok(None);
    };
    if column.dtype() == &DataType::Null {
        return Ok(Some((0..df.height()).map(|_| None).collect()));
    }
    if !dtype.accepts(column.dtype()) {
        return Err(TableError::WrongType {
            file: file.to_path_buf(),
            column: name.to_string(),
            found: column.dtype().to_string(),
            expected: format!("{dtype:?}").to_lowercase(),
        });
    }
    values(column).map(Some).map_err(|e| io_error(file, e))
}

/// [`optional_values`] of a float64 column.
pub fn optional_f64_values(
    df: &DataFrame,
    name: &str,
    file: &Path,
) -> Result<Option<Vec<Option<f64>>>, TableError> {
    optional_values(df, name, file, ColumnType::Float64, |c| {
        Ok(c.f64()?.iter().collect())
    })
}

/// [`optional_values`] of a utf8 column.
pub fn optional_str_values(
    df: &DataFrame,
    name: &str,
    file: &Path,
) -> Result<Option<Vec<Option<String>>>, TableError> {
    optional_values(df, name, file, ColumnType::Utf8, |c| {
        Ok(c.str()?.iter().map(|v| v.map(str::to_string)).collect())
    })
}

/// The approach directions (spec §8) of each row from `dir1..dir6`, 0 where a
/// column or value is absent (not known); a value other than −1, 0 or 1 is an
/// error naming its column and row.
pub fn approach_values(
    df: &DataFrame,
    file: &Path,
) -> Result<Vec<[i8; crate::robot::MAX_JOINTS]>, TableError> {
    let mut approach = vec![[0i8; crate::robot::MAX_JOINTS]; df.height()];
    for (joint, name) in APPROACH_COLUMNS.iter().enumerate() {
        let Some(values) = optional_values(df, name, file, ColumnType::Int8, |c| {
            Ok(c.cast(&DataType::Int64)?.i64()?.iter().collect())
        })?
        else {
            continue;
        };
        for (row, value) in values.into_iter().enumerate() {
            let Some(value) = value else { continue };
            approach[row][joint] = i8::try_from(value)
                .ok()
                .filter(|d| (-1..=1).contains(d))
                .ok_or_else(|| TableError::BadValue {
                    file: file.to_path_buf(),
                    column: (*name).to_string(),
                    row,
                    message: format!("`{value}` is not an approach direction: expected -1, 0 or 1"),
                })?;
        }
    }
    Ok(approach)
}

/// Each row's carriage position (`e1_mm`): `None` when the table has no
/// such column; a null, non-finite value is an error naming its row.
pub fn track_values(df: &DataFrame, file: &Path) -> Result<Option<Vec<f64>>, TableError> {
    let Some(values) = optional_f64_values(df, TRACK_COLUMN, file)? else {
        return Ok(None);
    };
    values
        .into_iter()
        .enumerate()
        .map(|(row, value)| match value {
            Some(v) if v.is_finite() => Ok(v),
            Some(value) => Err(TableError::NonFinite {
                file: file.to_path_buf(),
                column: TRACK_COLUMN.into(),
                row,
                value,
            }),
            None => Err(TableError::Null {
                file: file.to_path_buf(),
                column: TRACK_COLUMN.into(),
                row,
            }),
        })
        .collect::<Result<Vec<f64>, TableError>>()
        .map(Some)
}

/// Values of a utf8 column (nulls as `None`).
pub fn str_values(
    df: &DataFrame,
    name: &str,
    file: &Path,
) -> Result<Vec<Option<String>>, TableError> {
    let column = df.column(name).map_err(|e| io_error(file, e))?;
    // An all-null column written by pandas or pyarrow has type null.
    if column.dtype() == &DataType::Null {
        return Ok(vec![None; column.len()]);
    }
    let values = column.str().map_err(|e| io_error(file, e))?;
    Ok(values.iter().map(|v| v.map(str::to_string)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(cw: Vec<i64>, q1: Vec<f64>) -> DataFrame {
        let n = cw.len();
        let mut columns = vec![Column::new("cw_id".into(), cw)];
        for name in JOINT_COLUMNS.iter().chain(&WRENCH_COLUMNS) {
            let values = if *name == "q1_deg" {
                q1.clone()
            } else {
                vec![0.0; n]
            };
            columns.push(Column::new((*name).into(), values));
        }
        DataFrame::new(n, columns).unwrap()
    }

    #[test]
    fn good_table_passes() {
        conf_wrenches()
            .check(
                &frame(vec![1, 2, 3], vec![0.0, 1.0, 2.0]),
                Path::new("t.parquet"),
            )
            .unwrap();
    }

    #[test]
    fn nan_is_reported_with_row_and_column() {
        let err = conf_wrenches()
            .check(
                &frame(vec![1, 2, 3], vec![0.0, f64::NAN, 2.0]),
                Path::new("t.parquet"),
            )
            .unwrap_err();
        assert_eq!(
            err.to_string(),
            "t.parquet: column `q1_deg` is NaN at row 1, expected a finite number"
        );
    }

    #[test]
    fn duplicate_id_is_reported() {
        let err = conf_wrenches()
            .check(&frame(vec![1, 2, 1], vec![0.0; 3]), Path::new("t.parquet"))
            .unwrap_err();
        assert!(
            err.to_string()
                .contains("repeats value 1 at row 2 (first at row 0)"),
            "{err}"
        );
    }

    /// Sorting reports the repeat a scan with a set of seen values reports:
    /// the earliest row whose value came before, with that value's first row.
    #[test]
    fn the_sorted_search_finds_the_scan_s_first_repeat() {
        let scan = |values: &[Option<i64>]| {
            let mut seen = std::collections::HashMap::new();
            values
                .iter()
                .enumerate()
                .find_map(|(row, v)| seen.insert(*v, row).map(|first| (*v, row, first)))
        };
        let mut state = 7_u64;
        for case in 0..200 {
            let rows = 1 + case % 40;
            let values: Vec<Option<i64>> = (0..rows)
                .map(|_| {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
                    let draw = (state >> 33) % (2 * rows as u64);
                    (draw > 0).then_some(draw as i64 - 5)
                })
                .collect();
            assert_eq!(first_repeat(values.clone()), scan(&values), "{values:?}");
        }
        for ascending in [vec![Some(1), Some(2), Some(9)], vec![None], vec![]] {
            assert_eq!(first_repeat(ascending.clone()), scan(&ascending));
        }
    }

    #[test]
    fn missing_and_mistyped_columns_are_reported() {
        let df = frame(vec![1], vec![0.0]).drop("fz_n").unwrap();
        let err = conf_wrenches()
            .check(&df, Path::new("t.parquet"))
            .unwrap_err();
        assert!(
            err.to_string().contains("missing required column `fz_n`"),
            "{err}"
        );

        let mut df = frame(vec![1], vec![0.0]);
        df.with_column(Column::new("q2_deg".into(), vec!["a"]))
            .unwrap();
        let err = conf_wrenches()
            .check(&df, Path::new("t.parquet"))
            .unwrap_err();
        assert!(
            err.to_string()
                .contains("column `q2_deg` has type str, expected f64"),
            "{err}"
        );
    }

    #[test]
    fn optional_columns_are_absent_null_or_of_their_type() {
        let file = Path::new("commands.parquet");
        let df = DataFrame::new(
            2,
            vec![
                Column::new("u95_mm".into(), [Some(0.5), None]),
                Column::full_null("envelope_distance".into(), 2, &DataType::Null),
                Column::new("tool_id".into(), [3i64, 4]),
            ],
        )
        .unwrap();
        assert_eq!(optional_f64_values(&df, "missing", file).unwrap(), None);
        assert_eq!(
            optional_f64_values(&df, "u95_mm", file).unwrap(),
            Some(vec![Some(0.5), None])
        );
        assert_eq!(
            optional_f64_values(&df, "envelope_distance", file).unwrap(),
            Some(vec![None, None])
        );
        let err = optional_str_values(&df, "tool_id", file)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("column `tool_id` has type i64, expected utf8"),
            "{err}"
        );
    }
}
