//! The `parameters` table (`../shared/spec/model.md` §6) ↔ parameter sets.
//!
//! One row per parameter and model. Reading is strict about names, units, models
//! and duplicates; parameters a model does not list take their nominal value with
//! status `fixed`, so a hand-written table with only a few corrections is usable.
//!
//! With several targets (spec §7) the tool translation of each is named by its
//! target id, `x_t[nest2]`; a set's targets are kept sorted by id, the order
//! [`crate::robot::ParamId::target_translation`] indexes them.

use std::path::Path;
use std::str::FromStr;

use polars::prelude::*;

use super::schema::{self, TableError, f64_values, str_values};
pub use crate::calibration::parameter_set::{ModelName, ParamStatus, ParameterSet, param_name};
use crate::robot::RobotSpec;
use crate::robot::params::{MAX_TARGETS, ParamId, ParamValues, TOOL_TRANSLATION_NAMES};

/// Why `id` cannot name a target, or `None` when it can. A target id becomes
/// part of the parameter names `x_t[ID]` and of the programs' tool names, so
/// it must read back the same: printable, without brackets, commas or quotes,
/// without surrounding spaces (` a` and `a` would be two SMRs), at most 64
/// characters.
pub fn target_id_problem(id: &str) -> Option<String> {
    const MAX_CHARS: usize = 64;
    if id.is_empty() {
        return Some("expected a target id, found an empty or null value".into());
    }
    if id.trim() != id {
        return Some(format!(
            "target id {id:?} starts or ends with white space (it would name another target than {:?})",
            id.trim()
        ));
    }
    if id.chars().count() > MAX_CHARS {
        return Some(format!(
            "target id {id:?} is longer than {MAX_CHARS} characters"
        ));
    }
    if let Some(bad) = id
        .chars()
        .find(|c| c.is_control() || matches!(c, '[' | ']' | ',' | '"' | '\'' | '\\'))
    {
        return Some(format!(
            "target id {id:?} holds {bad:?}; a target id is printable text without brackets, commas, quotes or backslashes"
        ));
    }
    None
}

/// Largest compliance a parameters table may hold (deg/(N·m)): a joint that
/// turned a degree per newton-metre would not hold its own arm.
pub const MAX_COMPLIANCE_DEG_PER_NM: f64 = 1.0;

/// Largest prismatic compliance that is not a typo (mm/N): a slide that
/// yields a millimetre per newton would not hold its own carriage.
pub const MAX_COMPLIANCE_MM_PER_N: f64 = 1.0;

/// The first row of a parameters table (already schema-checked) whose value or
/// nominal no robot could have: a length beyond ±[`crate::robot::file::MAX_LENGTH_MM`],
/// an angle beyond ±360°, a compliance beyond ±[`MAX_COMPLIANCE_DEG_PER_NM`];
/// and, unless `accept_deviation`, an identified length or angle error
/// (`da`, `dd`, `dtheta`, `dalpha`) farther from nominal than identify's
/// default plausibility bounds (`max_deviation_mm`, `max_deviation_deg`).
pub fn implausible_row(
    df: &DataFrame,
    file: &Path,
    max_deviation_mm: f64,
    max_deviation_deg: f64,
    accept_deviation: bool,
) -> Result<Option<TableError>, TableError> {
    let names = str_values(df, "name", file)?;
    let units = str_values(df, "unit", file)?;
    let statuses = str_values(df, "status", file)?;
    let models = str_values(df, "model", file)?;
    let values = f64_values(df, "value", file)?;
    let nominals = f64_values(df, "nominal", file)?;
    for row in 0..df.height() {
        let name = names[row].as_deref().unwrap_or_default();
        let unit = units[row].as_deref().unwrap_or_default();
        let model = models[row].as_deref().unwrap_or_default();
        // A unit the table may not hold is reported by the reader's unit check.
        let bound = match unit {
            "mm" => crate::robot::file::MAX_LENGTH_MM,
            "deg" => 360.0,
            "deg/(N·m)" => MAX_COMPLIANCE_DEG_PER_NM,
            "mm/N" => MAX_COMPLIANCE_MM_PER_N,
            _ => continue,
        };
        for (column, value) in [("value", values[row]), ("nominal", nominals[row])] {
            if value.abs() > bound {
                return Ok(Some(TableError::BadValue {
                    file: file.to_path_buf(),
                    column: column.into(),
                    row,
                    message: format!(
                        "model {model}, `{name}` = {} {unit} lies beyond ±{bound} {unit}",
                        crate::calibration::row_checks::compact(value)
                    ),
                }));
            }
        }
        let is_error = ["da", "dd", "dtheta", "dalpha"].iter().any(|prefix| {
            name.strip_prefix(prefix)
                .is_some_and(|rest| rest.len() == 1 && rest.chars().all(|c| c.is_ascii_digit()))
        });
        let deviation = values[row] - nominals[row];
        let limit = if unit == "mm" {
            max_deviation_mm
        } else {
            max_deviation_deg
        };
        if is_error
            && !accept_deviation
            && statuses[row].as_deref() == Some("identified")
            && deviation.abs() > limit
        {
            return Ok(Some(TableError::BadValue {
                file: file.to_path_buf(),
                column: "value".into(),
                row,
                message: format!(
                    "model {model}, `{name}` lies {deviation:+.4} {unit} from nominal, beyond the plausible ±{limit} {unit} identify accepts by default; a unit, joint zero or sign, or the robot file is wrong (put it in service anyway with --accept-implausible)"
                ),
            }));
        }
    }
    Ok(None)
}

/// The parameter [`param_name`] names `name` in a set of `targets`.
pub fn param_of_name(name: &str, targets: &[String]) -> Option<ParamId> {
    match parse_target_name(name) {
        Some((axis, id)) if targets.len() > 1 => targets
            .iter()
            .position(|t| t == id)
            .map(|target| ParamId::target_translation(target, axis)),
        Some(_) => None,
        // With several targets a bare `x_t` is ambiguous.
        None => {
            ParamId::from_name(name).filter(|id| targets.len() <= 1 || !id.is_tool_translation())
        }
    }
}

/// Splits `x_t[ID]` into the axis and the target id.
fn parse_target_name(name: &str) -> Option<(usize, &str)> {
    let (base, rest) = name.split_once('[')?;
    let id = rest.strip_suffix(']')?;
    let axis = TOOL_TRANSLATION_NAMES.iter().position(|n| *n == base)?;
    target_id_problem(id).is_none().then_some((axis, id))
}

/// The table for `sets` of the robot file's arm, with its nominal values in
/// the `nominal` column and each parameter's unit on that arm.
pub fn to_frame(robot: &RobotSpec, sets: &[ParameterSet]) -> DataFrame {
    let nominal = ParamValues::nominal(robot);
    let prismatic = robot.prismatic_joints();
    let mut model = Vec::new();
    let mut name = Vec::new();
    let mut unit = Vec::new();
    let mut nominal_col = Vec::new();
    let mut value = Vec::new();
    let mut std_error = Vec::new();
    let mut status = Vec::new();
    let mut reason = Vec::new();
    for set in sets {
        for id in set.ids() {
            model.push(set.model.as_str());
            name.push(set.name_of(id));
            unit.push(id.unit_on(&prismatic));
            nominal_col.push(nominal.get(id));
            value.push(set.values.get(id));
            std_error.push(set.std_errors[id.index()]);
            status.push(set.status[id.index()].as_str());
            reason.push(set.reasons[id.index()].clone());
        }
    }
    super::frame(vec![
        Column::new("model".into(), model),
        Column::new("name".into(), name),
        Column::new("unit".into(), unit),
        Column::new("nominal".into(), nominal_col),
        Column::new("value".into(), value),
        Column::new("std_error".into(), std_error),
        Column::new("status".into(), status),
        Column::new("reason".into(), reason),
    ])
}

/// Parameter sets from a checked `parameters` table, in the order models first appear.
pub fn from_frame(
    df: &DataFrame,
    file: &Path,
    robot: &RobotSpec,
) -> Result<Vec<ParameterSet>, TableError> {
    schema::parameters().check(df, file)?;
    let nominal = &ParamValues::nominal(robot);
    let prismatic = robot.prismatic_joints();
    let models = str_values(df, "model", file)?;
    let names = str_values(df, "name", file)?;
    let units = str_values(df, "unit", file)?;
    let values = f64_values(df, "value", file)?;
    let statuses = str_values(df, "status", file)?;
    let std_errors: Vec<Option<f64>> = match df.column("std_error") {
        Ok(c) => c
            .cast(&DataType::Float64)
            .map_err(|e| schema::io_error(file, e))?
            .f64()
            .map_err(|e| schema::io_error(file, e))?
            .iter()
            .collect(),
        Err(_) => vec![None; df.height()],
    };
    // Written before spec §8 or by hand: no reasons.
    let reasons: Vec<Option<String>> = match df.column("reason") {
        Ok(_) => str_values(df, "reason", file)?,
        Err(_) => vec![None; df.height()],
    };
    let bad = |row: usize, column: &str, message: String| TableError::BadValue {
        file: file.to_path_buf(),
        column: column.to_string(),
        row,
        message,
    };
    // A value no robot has (1e300 mm) would turn every prediction into inf.
    if let Some(problem) = implausible_row(df, file, f64::INFINITY, f64::INFINITY, true)? {
        return Err(problem);
    }
    // First pass: each model's target ids, sorted, so that indices follow them.
    let mut targets: std::collections::BTreeMap<ModelName, std::collections::BTreeSet<String>> =
        Default::default();
    for row in 0..df.height() {
        let model_str = models[row].as_deref().unwrap_or_default();
        let model = ModelName::from_str(model_str).map_err(|m| bad(row, "model", m))?;
        let entry = targets.entry(model).or_default();
        if let Some((_, id)) = parse_target_name(names[row].as_deref().unwrap_or_default()) {
            entry.insert(id.to_string());
            if entry.len() > MAX_TARGETS {
                return Err(bad(
                    row,
                    "name",
                    format!("model `{model}` has more than {MAX_TARGETS} targets"),
                ));
            }
        }
    }
    let mut sets: Vec<ParameterSet> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for row in 0..df.height() {
        let model_str = models[row].as_deref().unwrap_or_default();
        let model = ModelName::from_str(model_str).map_err(|m| bad(row, "model", m))?;
        let name = names[row].as_deref().unwrap_or_default();
        let model_targets: Vec<String> = targets[&model].iter().cloned().collect();
        let target_id = parse_target_name(name).map(|(axis, id)| {
            let target = model_targets.iter().position(|t| t == id).unwrap_or(0);
            ParamId::target_translation(target, axis)
        });
        if model_targets.len() > 1
            && ParamId::from_name(name).is_some_and(|p| p.is_tool_translation())
        {
            return Err(bad(
                row,
                "name",
                format!(
                    "`{name}` is ambiguous: model `{model}` names its targets ({}), so write `{name}[ID]`",
                    model_targets.join(", ")
                ),
            ));
        }
        let id = target_id
            .or_else(|| ParamId::from_name(name))
            .ok_or_else(|| {
                bad(
                    row,
                    "name",
                    format!(
                        "unknown parameter `{name}`{}",
                        crate::suggest::did_you_mean(name, ParamId::known_names())
                    ),
                )
            })?;
        let unit = units[row].as_deref().unwrap_or_default();
        let expected = id.unit_on(&prismatic);
        if unit != expected {
            return Err(bad(
                row,
                "unit",
                format!("`{name}` is in {expected}, found `{unit}`"),
            ));
        }
        let status_str = statuses[row].as_deref().unwrap_or_default();
        let status = ParamStatus::parse(status_str).ok_or_else(|| {
            bad(
                row,
                "status",
                format!("expected identified, dependent, fixed or held, found `{status_str}`"),
            )
        })?;
        if !seen.insert((model, id)) {
            return Err(bad(
                row,
                "name",
                format!("`{name}` appears twice for model `{model}`"),
            ));
        }
        let index = match sets.iter().position(|s| s.model == model) {
            Some(i) => i,
            None => {
                let mut set = ParameterSet::fixed(model, *nominal);
                if model_targets.len() > 1 {
                    set.targets = model_targets;
                }
                sets.push(set);
                sets.len() - 1
            }
        };
        let set = &mut sets[index];
        set.values.set(id, values[row]);
        set.status[id.index()] = status;
        set.reasons[id.index()] = reasons[row].clone().filter(|r| !r.is_empty());
        set.std_errors[id.index()] = std_errors[row].filter(|v| v.is_finite());
    }
    Ok(sets)
}

/// One model's parameter covariance from a `covariance` table (spec §7).
#[derive(Debug, Clone, PartialEq)]
pub struct ModelCovariance {
    /// The identified parameters, in the order of `matrix`.
    pub free: Vec<ParamId>,
    /// Row-major `m × m`, in the products of the parameters' units.
    pub matrix: Vec<f64>,
    /// σ² the covariance is scaled by; `None` for a table without the column.
    pub variance_factor: Option<f64>,
}

/// Relative tolerance of the checks that a covariance belongs to its parameter
/// set: identify writes both from the same numbers, so only rounding differs.
const COVARIANCE_MATCH: f64 = 1e-9;

/// The covariance of `set`'s model from a `covariance` table, checked against
/// the set: exactly its identified parameters, every pair once, symmetric,
/// with the diagonal equal to the squared `std_error`s. A table from another
/// calibration fails these checks, naming the row, rather than giving a
/// confident uncertainty for the wrong parameters. `None` when the model
/// identifies nothing (nominal) and the table has no rows for it.
pub fn covariance_of(
    df: &DataFrame,
    file: &Path,
    set: &ParameterSet,
) -> Result<Option<ModelCovariance>, TableError> {
    schema::covariance().check(df, file)?;
    let models = str_values(df, "model", file)?;
    let names_i = str_values(df, "name_i", file)?;
    let names_j = str_values(df, "name_j", file)?;
    let values = f64_values(df, "value", file)?;
    let factors: Option<Vec<Option<f64>>> = match df.column("variance_factor") {
        Ok(c) => Some(
            c.cast(&DataType::Float64)
                .map_err(|e| schema::io_error(file, e))?
                .f64()
                .map_err(|e| schema::io_error(file, e))?
                .iter()
                .collect(),
        ),
        Err(_) => None,
    };
    let bad = |row: usize, column: &str, message: String| TableError::BadValue {
        file: file.to_path_buf(),
        column: column.to_string(),
        row,
        message,
    };
    let model = set.model;
    let free: Vec<ParamId> = set
        .ids()
        .filter(|id| set.status[id.index()] == ParamStatus::Identified)
        .collect();
    let names: Vec<String> = free.iter().map(|id| set.name_of(*id)).collect();
    let m = free.len();
    let rows: Vec<usize> = (0..df.height())
        .filter(|row| models[*row].as_deref() == Some(model.as_str()))
        .collect();
    if rows.is_empty() {
        if m == 0 {
            return Ok(None);
        }
        return Err(bad(
            0,
            "model",
            format!("no rows for model `{model}`, whose parameters identify {m}"),
        ));
    }
    let mut matrix = vec![f64::NAN; m * m];
    let index = |row: usize, column: &str, name: &Option<String>| {
        let name = name.as_deref().unwrap_or_default();
        names.iter().position(|n| n == name).ok_or_else(|| {
            bad(
                row,
                column,
                format!(
                    "`{name}` is not an identified parameter of the `{model}` parameters; the covariance belongs to another calibration"
                ),
            )
        })
    };
    for row in &rows {
        let (i, j) = (
            index(*row, "name_i", &names_i[*row])?,
            index(*row, "name_j", &names_j[*row])?,
        );
        if !matrix[i * m + j].is_nan() {
            return Err(bad(
                *row,
                "name_j",
                format!(
                    "the pair ({}, {}) appears twice for model `{model}`",
                    names[i], names[j]
                ),
            ));
        }
        matrix[i * m + j] = values[*row];
    }
    if let Some(missing) = matrix.iter().position(|v| v.is_nan()) {
        return Err(bad(
            rows[0],
            "name_i",
            format!(
                "model `{model}` lacks the pair ({}, {}); the covariance has both orders of every pair of identified parameters",
                names[missing / m],
                names[missing % m]
            ),
        ));
    }
    for i in 0..m {
        let variance = matrix[i * m + i];
        if variance <= 0.0 {
            return Err(bad(
                rows[0],
                "value",
                format!("the variance of `{}` is {variance}, expected > 0", names[i]),
            ));
        }
        if let Some(std_error) = set.std_errors[free[i].index()]
            && (variance.sqrt() - std_error).abs() > COVARIANCE_MATCH * std_error
        {
            return Err(bad(
                rows[0],
                "value",
                format!(
                    "the standard deviation of `{}` is {:e}, but the parameters table's std_error is {std_error:e}; the covariance belongs to another calibration",
                    names[i],
                    variance.sqrt()
                ),
            ));
        }
        for j in 0..i {
            let (a, b) = (matrix[i * m + j], matrix[j * m + i]);
            let scale = (variance * matrix[j * m + j]).sqrt();
            if (a - b).abs() > COVARIANCE_MATCH * scale {
                return Err(bad(
                    rows[0],
                    "value",
                    format!(
                        "not symmetric: ({0}, {1}) is {a:e} but ({1}, {0}) is {b:e}",
                        names[i], names[j]
                    ),
                ));
            }
        }
    }
    let variance_factor = factors.and_then(|f| f[rows[0]]);
    Ok(Some(ModelCovariance {
        free,
        matrix,
        variance_factor,
    }))
}

/// The set of `model` from a parameters file.
pub fn load_model(
    path: &Path,
    model: ModelName,
    robot: &RobotSpec,
) -> Result<ParameterSet, TableError> {
    let df = super::read_parquet(path)?;
    let sets = from_frame(&df, path, robot)?;
    let available: Vec<&str> = sets.iter().map(|s| s.model.as_str()).collect();
    sets.iter()
        .find(|s| s.model == model)
        .cloned()
        .ok_or_else(|| TableError::BadValue {
            file: path.to_path_buf(),
            column: "model".into(),
            row: 0,
            message: format!(
                "no rows for model `{model}` (the table has: {})",
                available.join(", ")
            ),
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, truth_params};

    #[test]
    fn round_trip_through_parquet() {
        let robot = irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        let mut eg = ParameterSet::fixed(ModelName::Elastogeometric, truth_params(&robot));
        eg.status[5] = ParamStatus::Identified;
        eg.std_errors[5] = Some(0.001);
        eg.status[12] = ParamStatus::Dependent;
        eg.status[16] = ParamStatus::Held;
        eg.reasons[16] = Some("std error 10.6 deg > 0.05".into());
        let sets = vec![ParameterSet::fixed(ModelName::Nominal, nominal), eg];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("parameters.parquet");
        super::super::write_parquet(&mut to_frame(robot.spec(), &sets), &path, None).unwrap();
        let back = from_frame(
            &super::super::read_parquet(&path).unwrap(),
            &path,
            robot.spec(),
        )
        .unwrap();
        assert_eq!(back, sets);
        let loaded = load_model(&path, ModelName::Elastogeometric, robot.spec()).unwrap();
        assert_eq!(loaded, sets[1]);
        let err = load_model(&path, ModelName::Kinematic, robot.spec())
            .unwrap_err()
            .to_string();
        assert!(err.contains("no rows for model `kinematic`"), "{err}");
    }

    #[test]
    fn several_targets_are_named_by_their_ids_and_read_back() {
        let robot = irb1600();
        let mut set = ParameterSet::fixed(ModelName::Elastogeometric, truth_params(&robot));
        set.targets = vec!["nest_a".into(), "nest_b".into(), "nest_c".into()];
        let z_b = ParamId::target_translation(1, 2);
        set.values.set(z_b, 131.5);
        set.status[z_b.index()] = ParamStatus::Identified;
        set.std_errors[z_b.index()] = Some(0.01);
        let df = to_frame(robot.spec(), &[set.clone()]);
        assert_eq!(df.height(), 42 + 6);
        let names = str_values(&df, "name", Path::new("p")).unwrap();
        for name in ["x_t[nest_a]", "z_t[nest_b]", "y_t[nest_c]"] {
            assert!(names.iter().any(|n| n.as_deref() == Some(name)), "{name}");
        }
        assert!(!names.iter().any(|n| n.as_deref() == Some("x_t")));
        let back = from_frame(&df, Path::new("p.parquet"), robot.spec()).unwrap();
        assert_eq!(back, vec![set.clone()]);
        let rows = [Some("nest_c".to_string()), Some("nest_a".to_string())];
        assert_eq!(set.target_indices(Some(&rows), 2).unwrap(), vec![2, 0]);
        let unknown = [Some("nest_z".to_string())];
        let err = set.target_indices(Some(&unknown), 1).unwrap_err();
        assert!(
            err.contains("`nest_z`") && err.contains("nest_a, nest_b, nest_c"),
            "{err}"
        );
        let missing = set.target_indices(None, 3).unwrap_err();
        assert!(
            missing.contains("no `target_id` column") && missing.contains("nest_a, nest_b, nest_c"),
            "{missing}"
        );
    }

    /// The covariance must be the one identify wrote with these parameters.
    #[test]
    fn a_covariance_is_checked_against_its_parameters() {
        let robot = irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        let mut set = ParameterSet::fixed(ModelName::Kinematic, nominal);
        for (name, se) in [("x_w", 0.1), ("dtheta2", 0.002)] {
            let id = ParamId::from_name(name).unwrap();
            set.status[id.index()] = ParamStatus::Identified;
            set.std_errors[id.index()] = Some(se);
        }
        let table = |names: [(&str, &str); 4], values: [f64; 4]| {
            super::super::frame(vec![
                Column::new("model".into(), vec!["kinematic"; 4]),
                Column::new("name_i".into(), names.map(|n| n.0).to_vec()),
                Column::new("name_j".into(), names.map(|n| n.1).to_vec()),
                Column::new("value".into(), values.to_vec()),
                Column::new("variance_factor".into(), vec![0.0004; 4]),
            ])
        };
        let pairs = [
            ("x_w", "x_w"),
            ("x_w", "dtheta2"),
            ("dtheta2", "x_w"),
            ("dtheta2", "dtheta2"),
        ];
        let file = Path::new("c.parquet");
        let good = covariance_of(&table(pairs, [0.01, 1e-5, 1e-5, 4e-6]), file, &set)
            .unwrap()
            .unwrap();
        assert_eq!(good.matrix, vec![0.01, 1e-5, 1e-5, 4e-6]);
        assert_eq!(good.variance_factor, Some(0.0004));
        let err = |df: DataFrame| covariance_of(&df, file, &set).unwrap_err().to_string();
        let wrong_se = err(table(pairs, [0.02, 1e-5, 1e-5, 4e-6]));
        assert!(wrong_se.contains("std_error"), "{wrong_se}");
        let asymmetric = err(table(pairs, [0.01, 1e-5, 2e-5, 4e-6]));
        assert!(asymmetric.contains("not symmetric"), "{asymmetric}");
        let mut other = pairs;
        other[3] = ("dtheta3", "dtheta3");
        let unknown = err(table(other, [0.01, 1e-5, 1e-5, 4e-6]));
        assert!(unknown.contains("`dtheta3`"), "{unknown}");
        let nominal_set = ParameterSet::fixed(ModelName::Nominal, nominal);
        assert_eq!(
            covariance_of(&table(pairs, [0.01, 1e-5, 1e-5, 4e-6]), file, &nominal_set).unwrap(),
            None
        );
    }

    #[test]
    fn unknown_name_and_wrong_unit_are_rejected() {
        let robot = irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        let good = to_frame(
            robot.spec(),
            &[ParameterSet::fixed(ModelName::Kinematic, nominal)],
        );
        let mut names: Vec<String> = str_values(&good, "name", Path::new("p"))
            .unwrap()
            .into_iter()
            .flatten()
            .collect();
        names[3] = "alpha_ww".into();
        let mut df = good.clone();
        df.with_column(Column::new("name".into(), names)).unwrap();
        let err = from_frame(&df, Path::new("p.parquet"), robot.spec())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("row 3") && err.contains("did you mean `alpha_w`"),
            "{err}"
        );

        let mut units: Vec<String> = str_values(&good, "unit", Path::new("p"))
            .unwrap()
            .into_iter()
            .flatten()
            .collect();
        units[0] = "m".into();
        let mut df = good;
        df.with_column(Column::new("unit".into(), units)).unwrap();
        let err = from_frame(&df, Path::new("p.parquet"), robot.spec())
            .unwrap_err()
            .to_string();
        assert!(err.contains("`x_w` is in mm, found `m`"), "{err}");
    }

    /// A prismatic joint's compliance is in mm/N and its backlash in mm; a
    /// table giving one in a revolute joint's unit is another robot's.
    #[test]
    fn a_prismatic_joint_s_units_are_written_and_required() {
        let robot = crate::robot::test_support::gantry();
        let mut set =
            ParameterSet::fixed(ModelName::EgBacklash, ParamValues::nominal(robot.spec()));
        let k1 = ParamId::of_joint(crate::robot::JointParam::Compliance, 0);
        set.values.set(k1, 0.002);
        set.status[k1.index()] = ParamStatus::Identified;
        for name in ["backlash3", "backlash4"] {
            set.values.set(ParamId::from_name(name).unwrap(), 0.01);
        }
        let df = to_frame(robot.spec(), &[set.clone()]);
        let names = str_values(&df, "name", Path::new("p")).unwrap();
        let units = str_values(&df, "unit", Path::new("p")).unwrap();
        let unit_of = |wanted: &str| {
            let row = names
                .iter()
                .position(|n| n.as_deref() == Some(wanted))
                .unwrap();
            units[row].clone().unwrap()
        };
        assert_eq!(unit_of("k1"), "mm/N");
        assert_eq!(unit_of("k4"), "deg/(N·m)");
        assert_eq!(unit_of("backlash3"), "mm");
        assert_eq!(unit_of("backlash4"), "deg");
        assert_eq!(
            from_frame(&df, Path::new("p.parquet"), robot.spec()).unwrap(),
            vec![set]
        );
        let err = from_frame(&df, Path::new("p.parquet"), irb1600().spec())
            .unwrap_err()
            .to_string();
        assert!(err.contains("`k1` is in deg/(N·m), found `mm/N`"), "{err}");
    }
}
