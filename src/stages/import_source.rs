//! Reading a delimited-text or Parquet export whose columns a stage's settings
//! map onto a contract table: what `import_measurements` and `import_targets`
//! share. The file's layout (format, separator, decimal comma, preamble,
//! header), the source units, and a [`Source`] that reads each mapped column
//! as the contract's type and explains every bad cell by file, line (CSV,
//! 1-based, header and skipped lines counted) or row (Parquet, 0-based),
//! source column, setting and what was expected.
//!
//! The CSV's text is first made plain ([`csv_text`]: encoding, line ends,
//! preamble, blank lines, a units row, header names, cells trimmed), then
//! parsed by polars' reader (its `decimal_comma` option for `1,5`), twice: once
//! with every column as text (the names, and the raw cell for messages) and
//! once with the mapped columns typed, bad cells read as null. Messages give
//! the file line each row starts on.

use std::borrow::Cow;
use std::io::Cursor;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use polars::prelude::{
    Column, CsvEncoding, CsvReadOptions, DataFrame, DataType, ParquetReader, PlSmallStr, Schema,
    SerReader, TimeUnit, TimeZone,
};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{SettingsProblem, StageError};
use crate::table::time::parse_rfc3339_us;

mod csv_text;

/// The export's file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SourceFormat {
    /// Delimited text (see `separator`, `decimal_comma`, `skip_rows`, `has_header`).
    Csv,
    /// A Parquet file; numeric columns of any numeric type.
    Parquet,
}

/// Whose numbering a source's joint columns follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum JointConvention {
    /// The robot file's.
    RobotFile,
    /// The controller's (the robot file's `[controller]`, e.g. a FANUC's J3
    /// from the horizontal).
    Controller,
}

/// Turns an imported table's joints from the controller's numbering into
/// the robot file's (`q3 = J3 − j3_from_j2 · J2`, null where either is
/// null); `Ok(false)` when there is nothing to do (the robot file's
/// convention, no coupling, or no joint columns).
pub fn joints_to_robot_file(
    table: &mut polars::prelude::DataFrame,
    convention: JointConvention,
    robot: &crate::robot::RobotSpec,
    file: &Path,
) -> Result<bool, StageError> {
    let coupling = robot.controller.j3_from_j2;
    if convention == JointConvention::RobotFile || coupling == 0.0 {
        return Ok(false);
    }
    let joints = |name: &str| crate::table::schema::optional_f64_values(table, name, file);
    let (Some(q2), Some(q3)) = (joints("q2_deg")?, joints("q3_deg")?) else {
        return Ok(false);
    };
    let q3_robot_file: Vec<Option<f64>> = q2
        .iter()
        .zip(&q3)
        .map(|(q2, j3)| Some(j3.as_ref()? - coupling * q2.as_ref()?))
        .collect();
    table
        .with_column(polars::prelude::Column::new("q3_deg".into(), q3_robot_file))
        .map_err(|e| StageError::Invalid(format!("{}: {e}", file.display())))?;
    Ok(true)
}

/// Unit of the joint columns in the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
pub enum JointUnit {
    #[default]
    #[serde(rename = "deg")]
    Deg,
    #[serde(rename = "rad")]
    Rad,
}

/// Unit of the position and sigma columns in the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
pub enum LengthUnit {
    #[default]
    #[serde(rename = "mm")]
    Mm,
    #[serde(rename = "m")]
    M,
}

/// Unit of the force columns in the source (newtons only).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
pub enum ForceUnit {
    #[default]
    #[serde(rename = "N")]
    Newton,
}

/// Unit of the moment columns in the source: `N·m` (also `N*m`, `Nm`) or `N·mm`
/// (also `N*mm`, `Nmm`). The ASCII spellings mean the same and are stored as the
/// `·` form, so they share a cache key.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum MomentUnit {
    #[default]
    NewtonMetre,
    NewtonMillimetre,
}

const MOMENT_SPELLINGS: [(&str, MomentUnit); 6] = [
    ("N·m", MomentUnit::NewtonMetre),
    ("N*m", MomentUnit::NewtonMetre),
    ("Nm", MomentUnit::NewtonMetre),
    ("N·mm", MomentUnit::NewtonMillimetre),
    ("N*mm", MomentUnit::NewtonMillimetre),
    ("Nmm", MomentUnit::NewtonMillimetre),
];

impl TryFrom<String> for MomentUnit {
    type Error = String;
    fn try_from(text: String) -> Result<Self, String> {
        MOMENT_SPELLINGS
            .iter()
            .find(|(spelling, _)| *spelling == text)
            .map(|(_, unit)| *unit)
            .ok_or_else(|| {
                format!("`{text}` is not a moment unit; expected N·m (or N*m, Nm) or N·mm (or N*mm, Nmm)")
            })
    }
}

impl From<MomentUnit> for String {
    fn from(unit: MomentUnit) -> String {
        match unit {
            MomentUnit::NewtonMetre => "N·m",
            MomentUnit::NewtonMillimetre => "N·mm",
        }
        .to_string()
    }
}

impl JsonSchema for MomentUnit {
    fn schema_name() -> Cow<'static, str> {
        "MomentUnit".into()
    }

    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        let spellings: Vec<&str> = MOMENT_SPELLINGS.iter().map(|(s, _)| *s).collect();
        schemars::json_schema!({
            "type": "string",
            "enum": spellings,
            "description": "Unit of the moment columns in the source: N·m (also N*m, Nm) or N·mm (also N*mm, Nmm)."
        })
    }
}

/// What a contract column holds, which decides its parsing and unit conversion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Joint,
    Force,
    Moment,
    Position,
    Sigma,
    Integer,
    Text,
    Time,
    /// An orientation angle (targets' and 6-D measurements' rx_deg … rz_deg).
    Angle,
    /// The 1-σ uncertainty of an orientation angle (6-D measurements).
    AngleSigma,
}

/// A contract column and the source column it comes from.
#[derive(Debug, Clone)]
pub struct Mapped {
    pub contract: &'static str,
    pub kind: Kind,
    pub source: String,
}

/// A CSV file's layout, checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CsvLayout {
    pub separator: u8,
    pub decimal_comma: bool,
    pub skip_rows: usize,
    pub has_header: bool,
    /// The source units the settings declare, checked against a units row.
    pub units: SourceUnits,
}

/// The unit settings of an import stage, as the file should agree with them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SourceUnits {
    pub joint: JointUnit,
    /// Orientation angles and their sigmas (`angle_unit`).
    pub angle: JointUnit,
    pub length: LengthUnit,
    pub moment: MomentUnit,
}

/// The problems every column map shares, added to `problems`: a `required`
/// contract column left unmapped, a `contract` column mapped to an empty name,
/// and two contract columns reading one source column (a copy-paste slip; only
/// the three position sigmas, or the three angle sigmas, may share one: a
/// tracker's single isotropic σ).
/// `source_of` gives a contract column's source column.
pub fn column_map_problems<'a>(
    source_of: impl Fn(&str) -> Option<&'a str>,
    required: &[&str],
    contract: impl IntoIterator<Item = (&'static str, Kind)>,
    problems: &mut Vec<SettingsProblem>,
) {
    for key in required {
        if source_of(key).is_none() {
            problems.push(SettingsProblem::new(
                &format!("columns.{key}"),
                format!("required: the source column that holds `{key}`"),
            ));
        }
    }
    let mut seen: Vec<(&str, &str, Kind)> = Vec::new();
    for (key, kind) in contract {
        let Some(source) = source_of(key) else {
            continue;
        };
        if source.is_empty() {
            problems.push(SettingsProblem::new(
                &format!("columns.{key}"),
                "the source column name is empty",
            ));
            continue;
        }
        if let Some((first, _, _)) = seen.iter().find(|(_, s, k)| {
            *s == source && !(*k == kind && matches!(kind, Kind::Sigma | Kind::AngleSigma))
        }) {
            problems.push(SettingsProblem::new(
                &format!("columns.{key}"),
                format!(
                    "names source column `{source}`, which `columns.{first}` reads already: each contract column needs its own source column"
                ),
            ));
        }
        seen.push((key, source, kind));
    }
}

/// The file settings every import stage has, as written (see
/// `import_measurements`' settings for their meaning).
pub struct FileSettings<'s> {
    pub path: &'s str,
    pub format: Option<SourceFormat>,
    pub separator: &'s str,
    pub decimal_comma: bool,
    pub skip_rows: usize,
    pub has_header: bool,
    pub units: SourceUnits,
}

impl FileSettings<'_> {
    /// The file (relative to `job_dir`), its format and CSV layout; each
    /// problem is pushed to `problems` under its setting's key. Reads nothing.
    pub fn check(
        &self,
        job_dir: &Path,
        problems: &mut Vec<SettingsProblem>,
    ) -> (std::path::PathBuf, SourceFormat, CsvLayout) {
        if self.path.trim().is_empty() {
            problems.push(SettingsProblem::new(
                "path",
                "required: the export file, relative to the job file's folder",
            ));
        }
        let file = job_dir.join(self.path);
        let format = self.format.unwrap_or_else(|| format_of(&file));
        let separator = match self.separator.as_bytes() {
            [b] if b.is_ascii() && !matches!(b, b'"' | b'\n' | b'\r') => *b,
            _ => {
                problems.push(SettingsProblem::new(
                    "separator",
                    format!(
                        "`{}` is not one ASCII character (other than a quote or a line break)",
                        self.separator.escape_debug()
                    ),
                ));
                b','
            }
        };
        if self.decimal_comma && separator == b',' {
            problems.push(SettingsProblem::new(
                "decimal_comma",
                "needs a separator other than \",\" (e.g. `separator = \";\"`)",
            ));
        }
        if format == SourceFormat::Parquet {
            for (key, set) in [
                ("separator", self.separator != ","),
                ("decimal_comma", self.decimal_comma),
                ("skip_rows", self.skip_rows != 0),
                ("has_header", !self.has_header),
            ] {
                if set {
                    problems.push(SettingsProblem::new(
                        key,
                        format!(
                            "applies to CSV files only, and {} is read as Parquet",
                            file.display()
                        ),
                    ));
                }
            }
        }
        let layout = CsvLayout {
            separator,
            decimal_comma: self.decimal_comma,
            skip_rows: self.skip_rows,
            has_header: self.has_header,
            units: self.units,
        };
        (file, format, layout)
    }
}

/// The source table of `file`'s `bytes` in `format`.
pub fn read_source<'a>(
    file: &'a Path,
    format: SourceFormat,
    layout: &CsvLayout,
    mapped: &[Mapped],
    bytes: &[u8],
    empty_note: &'static str,
) -> Result<Source<'a>, StageError> {
    match format {
        SourceFormat::Csv => Source::csv(file, layout, mapped, bytes, empty_note),
        SourceFormat::Parquet => Source::parquet(file, bytes, empty_note),
    }
}

pub fn cannot_read(file: &Path, e: std::io::Error) -> StageError {
    StageError::Invalid(format!(
        "setting `path`: cannot read {}: {e}",
        file.display()
    ))
}

/// The source table: typed mapped columns, and for a CSV every cell as text.
pub struct Source<'a> {
    file: &'a Path,
    /// Mapped numeric columns as f64 / i64 (CSV: unparsable cells null), others as read.
    typed: DataFrame,
    /// CSV: every column as text, for the names and for messages.
    text: Option<DataFrame>,
    /// CSV: the 1-based file line of each data row; Parquet: none (rows are named).
    lines: Option<Vec<usize>>,
    decimal_comma: bool,
    separator: u8,
    /// Why an empty cell of a required column is bad, for messages
    /// ("measurements hold complete rows only").
    empty_note: &'static str,
    /// Warnings about the file that did not stop the import (encoding guessed,
    /// units row skipped, an unused duplicate column name), each naming the file.
    pub notes: Vec<String>,
}

impl<'a> Source<'a> {
    /// The CSV `bytes` of `file` as laid out by `layout`, the `mapped` columns typed.
    pub fn csv(
        file: &'a Path,
        layout: &CsvLayout,
        mapped: &[Mapped],
        bytes: &[u8],
        empty_note: &'static str,
    ) -> Result<Self, StageError> {
        let (text, encoding_note) = csv_text::decode(file, bytes)?;
        let plain = csv_text::plain(file, &text, layout, mapped)?;
        let mut notes: Vec<String> = encoding_note
            .map(|n| match n.strip_prefix("warning: ") {
                Some(w) => format!("warning: {}: {w}", file.display()),
                None => format!("{}: {n}", file.display()),
            })
            .into_iter()
            .collect();
        notes.extend(plain.notes);
        let bytes = plain.text.as_bytes();
        let options = |typed: Option<Schema>| {
            let projection: Option<Arc<[PlSmallStr]>> = typed
                .as_ref()
                .map(|s| s.iter_names().cloned().collect::<Vec<_>>().into());
            CsvReadOptions::default()
                .with_has_header(layout.has_header)
                .with_infer_schema_length(Some(0))
                .with_schema_overwrite(typed.map(Arc::new))
                .with_columns(projection)
                .with_ignore_errors(true)
                .map_parse_options(|p| {
                    p.with_separator(layout.separator)
                        .with_decimal_comma(layout.decimal_comma)
                        .with_encoding(CsvEncoding::LossyUtf8)
                })
        };
        let unreadable = |e: polars::error::PolarsError| {
            StageError::Invalid(format!(
                "{}: not a readable CSV file with separator {:?} (are `separator`, `skip_rows` and `has_header` right?): {e}",
                file.display(),
                layout.separator as char
            ))
        };
        let text = if plain.lines.is_empty() && !layout.has_header {
            DataFrame::empty()
        } else {
            options(None)
                .into_reader_with_file_handle(Cursor::new(bytes))
                .finish()
                .map_err(unreadable)?
        };
        let present: Vec<&str> = text.get_column_names().iter().map(|s| s.as_str()).collect();
        let typed_schema: Schema = mapped
            .iter()
            .filter(|m| present.contains(&m.source.as_str()))
            .map(|m| {
                let dtype = match m.kind {
                    Kind::Integer => DataType::Int64,
                    Kind::Text | Kind::Time => DataType::String,
                    _ => DataType::Float64,
                };
                (PlSmallStr::from(m.source.as_str()), dtype)
            })
            .collect();
        let typed = if typed_schema.is_empty() {
            DataFrame::empty()
        } else {
            let typed = options(Some(typed_schema))
                .into_reader_with_file_handle(Cursor::new(bytes))
                .finish()
                .map_err(unreadable)?;
            if typed.height() != text.height() {
                return Err(StageError::Failed(format!(
                    "{}: read {} rows as numbers but {} as text",
                    file.display(),
                    typed.height(),
                    text.height()
                )));
            }
            typed
        };
        if text.height() != plain.lines.len() {
            return Err(StageError::Failed(format!(
                "{}: read {} data rows, but the file has {} data lines",
                file.display(),
                text.height(),
                plain.lines.len()
            )));
        }
        Ok(Source {
            file,
            typed,
            text: Some(text),
            lines: Some(plain.lines),
            decimal_comma: layout.decimal_comma,
            separator: layout.separator,
            empty_note,
            notes,
        })
    }

    /// The Parquet `bytes` of `file`.
    pub fn parquet(
        file: &'a Path,
        bytes: &[u8],
        empty_note: &'static str,
    ) -> Result<Self, StageError> {
        let typed = ParquetReader::new(Cursor::new(bytes))
            .finish()
            .map_err(|e| {
                StageError::Invalid(format!(
                    "{}: not a readable Parquet file: {e}",
                    file.display()
                ))
            })?;
        Ok(Source {
            file,
            typed,
            text: None,
            lines: None,
            decimal_comma: false,
            separator: b',',
            empty_note,
            notes: Vec::new(),
        })
    }

    pub fn height(&self) -> usize {
        self.text.as_ref().unwrap_or(&self.typed).height()
    }

    pub fn names(&self) -> Vec<&str> {
        self.text
            .as_ref()
            .unwrap_or(&self.typed)
            .get_column_names()
            .iter()
            .map(|s| s.as_str())
            .collect()
    }

    /// Every mapped source column present, else one line per missing column.
    pub fn check_columns(&self, mapped: &[Mapped]) -> Result<(), StageError> {
        let names = self.names();
        // Suggest only columns no other setting uses: `measurement_std_x` is not
        // `measurement_x`, which already holds the positions.
        let unmapped: Vec<&str> = names
            .iter()
            .copied()
            .filter(|n| !mapped.iter().any(|m| m.source == *n))
            .collect();
        let mut problems: Vec<String> = mapped
            .iter()
            .filter(|m| !names.contains(&m.source.as_str()))
            .map(|m| {
                format!(
                    "{}: setting `columns.{}` names source column `{}`, which the file does not have{}",
                    self.file.display(),
                    m.contract,
                    m.source,
                    suggestion(&m.source, &unmapped)
                )
            })
            .collect();
        if problems.is_empty() {
            return Ok(());
        }
        if let [only] = names.as_slice()
            && let Some(other) = [';', ',', '\t', '|']
                .into_iter()
                .find(|c| *c != self.separator as char && only.contains(*c))
        {
            problems.push(format!(
                "{}: the file reads as one column `{only}`: is `separator` right? (its header holds {other:?})",
                self.file.display()
            ));
        }
        Err(StageError::Invalid(problems.join("\n")))
    }

    /// "line 7" (CSV, 1-based file line) or "row 5" (Parquet, 0-based data row).
    pub fn at(&self, row: usize) -> String {
        match self.lines.as_ref().and_then(|lines| lines.get(row)) {
            Some(line) => format!("line {line}"),
            None => format!("row {row}"),
        }
    }

    /// The cell as written in the file (CSV), or its value as text (Parquet).
    pub fn raw(&self, source: &str, row: usize) -> Option<String> {
        let frame = self.text.as_ref().unwrap_or(&self.typed);
        let column = frame.column(source).ok()?;
        match column.dtype() {
            DataType::String => column.str().ok()?.get(row).map(str::to_string),
            _ => column.get(row).ok().map(|v| v.to_string()),
        }
    }

    pub fn problem(&self, row: usize, m: &Mapped, message: impl std::fmt::Display) -> StageError {
        StageError::Invalid(format!(
            "{}: {}, column `{}` (setting `columns.{}`): {message}",
            self.file.display(),
            self.at(row),
            m.source,
            m.contract
        ))
    }

    /// Why a cell read as null: it is empty, or its text (quoted, with a hint when
    /// it looks like a decimal comma) is not `expected`.
    pub fn unreadable_cell(&self, m: &Mapped, row: usize, expected: &str) -> StageError {
        match self.raw(&m.source, row).filter(|t| !t.trim().is_empty()) {
            None => self.problem(
                row,
                m,
                format!("empty cell, expected {expected} ({})", self.empty_note),
            ),
            Some(text) => {
                let hint = if !self.decimal_comma
                    && text.contains(',')
                    && text.replace(',', ".").trim().parse::<f64>().is_ok()
                {
                    " (the file seems to use a decimal comma: set `decimal_comma = true`)"
                } else {
                    ""
                };
                self.problem(row, m, format!("`{text}` is not {expected}{hint}"))
            }
        }
    }

    pub fn floats(&self, m: &Mapped, rows: Range<usize>) -> Result<Vec<f64>, StageError> {
        let column = self.column(m)?;
        if !column.dtype().is_primitive_numeric() {
            return Err(self.wrong_type(m, column.dtype(), "a number"));
        }
        let cast = column
            .cast(&DataType::Float64)
            .map_err(|e| self.problem(rows.start, m, e))?;
        let values = cast.f64().map_err(|e| self.problem(rows.start, m, e))?;
        rows.map(|row| match values.get(row) {
            Some(v) if v.is_finite() => Ok(v),
            Some(v) => {
                let text = self.raw(&m.source, row).unwrap_or_else(|| v.to_string());
                Err(self.problem(row, m, format!("`{text}` is not a finite number")))
            }
            None => Err(self.unreadable_cell(m, row, "a number")),
        })
        .collect()
    }

    /// As [`Source::floats`] for an optional column: an empty cell (or a
    /// Parquet null) is `None`; text that is not a number is still refused.
    pub fn optional_floats(
        &self,
        m: &Mapped,
        rows: Range<usize>,
    ) -> Result<Vec<Option<f64>>, StageError> {
        let column = self.column(m)?;
        if column.dtype() == &DataType::Null {
            return Ok(vec![None; rows.len()]);
        }
        if !column.dtype().is_primitive_numeric() {
            return Err(self.wrong_type(m, column.dtype(), "a number"));
        }
        let cast = column
            .cast(&DataType::Float64)
            .map_err(|e| self.problem(rows.start, m, e))?;
        let values = cast.f64().map_err(|e| self.problem(rows.start, m, e))?;
        rows.map(|row| match values.get(row) {
            Some(v) if v.is_finite() => Ok(Some(v)),
            Some(v) => {
                let text = self.raw(&m.source, row).unwrap_or_else(|| v.to_string());
                Err(self.problem(row, m, format!("`{text}` is not a finite number")))
            }
            None if self.raw(&m.source, row).is_none_or(|t| t.trim().is_empty()) => Ok(None),
            None => Err(self.unreadable_cell(m, row, "a number or an empty cell")),
        })
        .collect()
    }

    /// Text cells of an optional column, trimmed: an empty cell is `None`.
    pub fn optional_texts(
        &self,
        m: &Mapped,
        rows: Range<usize>,
    ) -> Result<Vec<Option<String>>, StageError> {
        let column = self.column(m)?;
        if column.dtype() == &DataType::Null {
            return Ok(vec![None; rows.len()]);
        }
        let cast = column
            .cast(&DataType::String)
            .map_err(|_| self.wrong_type(m, column.dtype(), "text or numbers"))?;
        let values = cast.str().map_err(|e| self.problem(rows.start, m, e))?;
        Ok(rows
            .map(|row| {
                values
                    .get(row)
                    .map(str::trim)
                    .filter(|t| !t.is_empty())
                    .map(str::to_string)
            })
            .collect())
    }

    pub fn integers(&self, m: &Mapped, rows: Range<usize>) -> Result<Vec<i64>, StageError> {
        let column = self.column(m)?;
        if !column.dtype().is_integer() {
            return Err(self.wrong_type(m, column.dtype(), "whole numbers"));
        }
        let cast = column
            .cast(&DataType::Int64)
            .map_err(|e| self.problem(rows.start, m, e))?;
        let values = cast.i64().map_err(|e| self.problem(rows.start, m, e))?;
        rows.map(|row| {
            values
                .get(row)
                .ok_or_else(|| self.unreadable_cell(m, row, "a whole number"))
        })
        .collect()
    }

    pub fn texts(&self, m: &Mapped, rows: Range<usize>) -> Result<Vec<String>, StageError> {
        let column = self.column(m)?;
        let cast = column
            .cast(&DataType::String)
            .map_err(|_| self.wrong_type(m, column.dtype(), "text or numbers"))?;
        let values = cast.str().map_err(|e| self.problem(rows.start, m, e))?;
        rows.map(|row| match values.get(row).map(str::trim) {
            Some(text) if !text.is_empty() => Ok(text.to_string()),
            _ => Err(self.problem(
                row,
                m,
                format!(
                    "empty cell, expected a `{}` ({})",
                    m.contract, self.empty_note
                ),
            )),
        })
        .collect()
    }

    pub fn times_us(&self, m: &Mapped, rows: Range<usize>) -> Result<Vec<i64>, StageError> {
        let column = self.column(m)?;
        let expected = "a UTC time like 2026-03-02T10:00:00Z";
        match column.dtype() {
            DataType::Datetime(..) => {
                let cast = column
                    .cast(&DataType::Datetime(
                        TimeUnit::Microseconds,
                        Some(TimeZone::UTC),
                    ))
                    .and_then(|c| c.cast(&DataType::Int64))
                    .map_err(|e| self.problem(rows.start, m, e))?;
                let values = cast.i64().map_err(|e| self.problem(rows.start, m, e))?;
                rows.map(|row| {
                    values.get(row).ok_or_else(|| {
                        self.problem(row, m, format!("empty cell, expected {expected}"))
                    })
                })
                .collect()
            }
            DataType::String => {
                let values = column.str().map_err(|e| self.problem(rows.start, m, e))?;
                rows.map(|row| match values.get(row).map(str::trim) {
                    Some(text) if !text.is_empty() => parse_rfc3339_us(text)
                        .ok_or_else(|| self.problem(row, m, format!("`{text}` is not {expected}"))),
                    _ => Err(self.problem(row, m, format!("empty cell, expected {expected}"))),
                })
                .collect()
            }
            other => Err(self.wrong_type(m, other, "timestamps or RFC 3339 text")),
        }
    }

    pub fn column(&self, m: &Mapped) -> Result<&Column, StageError> {
        self.typed.column(&m.source).map_err(|e| {
            StageError::Failed(format!(
                "{}: column `{}`: {e}",
                self.file.display(),
                m.source
            ))
        })
    }

    pub fn wrong_type(&self, m: &Mapped, found: &DataType, expected: &str) -> StageError {
        StageError::Invalid(format!(
            "{}: column `{}` (setting `columns.{}`) has type {found}, expected {expected}",
            self.file.display(),
            m.source,
            m.contract
        ))
    }
}

/// Parquet for a `.parquet` or `.pq` file, else CSV.
pub fn format_of(file: &Path) -> SourceFormat {
    match file.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("parquet") || e.eq_ignore_ascii_case("pq") => {
            SourceFormat::Parquet
        }
        _ => SourceFormat::Csv,
    }
}

/// " (did you mean `x`?)" by edit distance, else the one source column whose name
/// contains the wanted one (ignoring case): `shoulder_pan` → `shoulder_pan_joint`.
pub fn suggestion(wanted: &str, names: &[&str]) -> String {
    let close = crate::suggest::did_you_mean(wanted, names.iter().copied());
    if !close.is_empty() {
        return close;
    }
    let lower = wanted.to_lowercase();
    match names
        .iter()
        .filter(|n| n.to_lowercase().contains(&lower))
        .collect::<Vec<_>>()
        .as_slice()
    {
        [one] => format!(" (did you mean `{one}`?)"),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use polars::prelude::{Column, DataFrame};

    fn table() -> DataFrame {
        DataFrame::new(
            2,
            vec![
                Column::new("q2_deg".into(), vec![Some(30.0), None]),
                Column::new("q3_deg".into(), vec![Some(-20.0), Some(5.0)]),
            ],
        )
        .unwrap()
    }

    #[test]
    fn controller_joints_become_the_robot_file_s_and_nulls_stay_null() {
        let mut fanuc = crate::robot::test_support::irb1600().spec().clone();
        fanuc.controller.j3_from_j2 = 1.0;
        let file = Path::new("t.csv");
        let mut converted = table();
        assert!(
            joints_to_robot_file(&mut converted, JointConvention::Controller, &fanuc, file)
                .unwrap()
        );
        let q3 = crate::table::schema::optional_f64_values(&converted, "q3_deg", file)
            .unwrap()
            .unwrap();
        // J3 = q3 + q2: -20 from the horizontal at q2 = 30 is q3 = -50; a
        // row without q2 (no branch hint) keeps none.
        assert_eq!(q3, [Some(-50.0), None]);
        let mut kept = table();
        assert!(
            !joints_to_robot_file(&mut kept, JointConvention::RobotFile, &fanuc, file).unwrap()
        );
        assert_eq!(kept, table());
    }
}
