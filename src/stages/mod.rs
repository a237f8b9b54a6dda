//! Stage kinds: each a pure function from checked input tables and typed settings
//! to output tables. A stage never touches the cache, the lock or the job file;
//! the runner never knows a stage's maths.
//!
//! A stage kind is defined once, by implementing [`Stage`]: its settings struct
//! (serde + JSON Schema + defaults) is the single source for job-file parsing,
//! `egcal list-stages`, the job-file JSON Schema and the cache key.

pub mod accuracy;
pub mod accuracy_map;
pub mod budget;
pub mod compensate;
pub mod crossvalidate;
pub mod export_program;
pub mod gate;
pub mod held_out;
pub mod identifiability;
pub mod identify;
pub mod import_measurements;
mod import_source;
pub mod import_targets;
pub mod iso9283;
pub mod iso_cube;
pub mod measure;
pub mod nest_poses;
pub mod poses;
mod positioner_rows;
pub mod predict;
pub mod report;
pub mod residual_rung;
pub mod scan_logs;
pub mod select;
pub mod settings_check;
pub mod simulate_logs;
pub mod split;
mod target_slots;
pub mod validate;
pub mod wrenches;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use polars::prelude::DataFrame;
use schemars::JsonSchema;
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::cdpr::CableRobotSpec;
use crate::robot::{Robot, RobotSpec};
use crate::table::{TableError, TableSchema};

/// A named input or output table of a stage kind.
#[derive(Debug, Clone, Copy)]
pub struct TableSlot {
    pub name: &'static str,
    pub schema: fn() -> TableSchema,
    /// Optional inputs may be left out of a job.
    pub required: bool,
    pub meaning: &'static str,
}

/// What a stage kind declares about itself.
#[derive(Debug, Clone, Copy)]
pub struct StageInfo {
    pub kind: &'static str,
    pub summary: &'static str,
    /// Bump when the stage's maths or output changes: invalidates its cache entries.
    pub code_version: u32,
    pub inputs: &'static [TableSlot],
    pub outputs: &'static [TableSlot],
    /// Whether the stage reads the job's cable-robot geometry (then its hash is
    /// part of the cache key).
    pub uses_cable_robot: bool,
    /// An input file the stage may replace on purpose (the gate publishes over the
    /// calibration in service), so the runner does not report it as changed under
    /// the stage. Its new content re-keys the stage on the next run.
    pub updates_input: Option<&'static str>,
}

/// A checked input table and the file it came from.
#[derive(Debug, Clone)]
pub struct InputTable {
    pub path: PathBuf,
    pub df: DataFrame,
}

/// Receives progress from a long stage; the runner draws bars or log lines.
pub trait Progress: Sync {
    fn start(&self, total: u64, what: &str);
    fn advance(&self, done: u64);
    fn note(&self, message: &str);
}

/// A progress sink that discards everything (tests, `--quiet`).
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _: u64, _: &str) {}
    fn advance(&self, _: u64) {}
    fn note(&self, _: &str) {}
}

/// Everything a stage may use.
pub struct StageContext<'a> {
    pub robot: &'a Robot,
    /// The cable robot that applies the wrenches (the job's, or the default geometry).
    pub cable_robot: &'a CableRobotSpec,
    /// The job's seed mixed with the stage id, so stages draw independent streams.
    pub seed: u64,
    pub inputs: &'a BTreeMap<String, InputTable>,
    /// A folder the stage owns across runs (journals of resumable stages).
    pub work_dir: &'a Path,
    /// The job file's folder: relative paths in settings (driver commands) resolve here.
    pub job_dir: &'a Path,
    /// The run's date (day number, UTC): where relative time windows end.
    pub run_date: i64,
    pub progress: &'a dyn Progress,
}

impl StageContext<'_> {
    /// A required input (the runner has checked that required inputs are bound).
    pub fn input(&self, name: &str) -> Result<&InputTable, StageError> {
        self.inputs
            .get(name)
            .ok_or_else(|| StageError::Invalid(format!("input `{name}` is not bound")))
    }
}

/// What a stage produced.
#[derive(Debug, Default)]
pub struct StageOutputs {
    pub tables: BTreeMap<String, DataFrame>,
    /// Other files by name (e.g. `report.html`), published beside the tables.
    pub files: BTreeMap<String, Vec<u8>>,
    /// Short facts to keep in provenance and print (rejection counts, ranks, ...).
    pub facts: BTreeMap<String, String>,
}

/// Why a stage failed.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error(transparent)]
    Table(#[from] TableError),
    #[error("{0}")]
    Invalid(String),
    #[error("{0}")]
    Failed(String),
}

/// A stage kind with typed settings.
pub trait Stage: Sync {
    type Settings: DeserializeOwned + Serialize + JsonSchema + Default;
    fn info(&self) -> &'static StageInfo;
    fn run(
        &self,
        ctx: &StageContext,
        settings: &Self::Settings,
    ) -> Result<StageOutputs, StageError>;

    /// What the stage reads besides its bound tables and settings (logged files
    /// found by a glob, the run date of a relative window), as a value the runner
    /// hashes into the cache key. Most stages read nothing else: `Null`.
    fn external_key(
        &self,
        _settings: &Self::Settings,
        _job_dir: &Path,
        _run_date: i64,
    ) -> Result<serde_json::Value, StageError> {
        Ok(serde_json::Value::Null)
    }

    /// Checks of the settings that a range on one value cannot express (one
    /// setting against another, model and parameter names, the robot, the
    /// machine's memory), run by job-file validation (`egcal check`) and before
    /// [`Stage::run`]. Only what settings, robot, cable robot and job folder
    /// decide belongs here; checks of input tables stay in `run`.
    fn check_settings(
        &self,
        _settings: &Self::Settings,
        _ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        Vec::new()
    }

    /// Checks of the user files the stage's settings name (an export to import),
    /// for `egcal check`: each file read and parsed as [`Stage::run`] would, with
    /// the same messages, under the setting that names it. `run` reads them
    /// anyway, so only `check` calls this. Most stages read no such file.
    fn check_sources(
        &self,
        _settings: &Self::Settings,
        _ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        Vec::new()
    }
}

/// What job-file validation knows when it checks a stage's settings: no tables yet.
pub struct SettingsContext<'a> {
    pub robot: &'a RobotSpec,
    pub cable_robot: &'a CableRobotSpec,
    /// The job file's folder: relative paths in settings resolve here.
    pub job_dir: &'a Path,
    /// Names of the inputs the stage is given (a setting may need one bound).
    pub bound_inputs: &'a [&'a str],
}

impl SettingsProblem {
    pub fn new(key: &str, message: impl Into<String>) -> Self {
        SettingsProblem {
            key: key.to_string(),
            message: message.into(),
        }
    }
}

/// Refuses a robot file with a prismatic joint for a stage or path that
/// reads or writes joint values as six or seven angles (`what` names it,
/// `instead` says what to use): a slide's millimetres in a degrees field
/// would be a wrong result, not a refusal.
pub fn refuse_prismatic_joints(
    robot: &crate::robot::RobotSpec,
    what: &str,
    instead: &str,
) -> Result<(), StageError> {
    match robot
        .joints
        .iter()
        .position(|j| j.kind == crate::robot::file::JointKind::Prismatic)
    {
        Some(joint) => Err(StageError::Invalid(format!(
            "the robot file {} has a prismatic joint (joint {}); {what} carries joint angles only: {instead}",
            robot.path.display(),
            joint + 1
        ))),
        None => Ok(()),
    }
}

/// A problem with a model name (`nominal`, `registered`, …) set under `key`.
pub fn model_name_problem(key: &str, name: &str) -> Option<SettingsProblem> {
    name.parse::<crate::table::parameters::ModelName>()
        .err()
        .map(|m| SettingsProblem::new(key, m))
}

/// Settings problems as one [`StageError::Invalid`], each line naming its setting.
pub fn settings_error(problems: &[SettingsProblem]) -> StageError {
    StageError::Invalid(
        problems
            .iter()
            .map(|p| format!("setting `{}`: {}", p.key, p.message))
            .collect::<Vec<_>>()
            .join("\n"),
    )
}

/// A settings value that failed to parse or check, with its key relative to the stage table.
#[derive(Debug, Clone, PartialEq)]
pub struct SettingsProblem {
    pub key: String,
    pub message: String,
}

/// Object-safe view of a [`Stage`], for the registry and the runner.
pub trait StageKind: Sync {
    fn info(&self) -> &'static StageInfo;
    /// JSON Schema of the settings (an object schema).
    fn settings_schema(&self) -> serde_json::Value;
    /// Settings with defaults filled, as JSON: the canonical form hashed into cache keys.
    fn canonical_settings(
        &self,
        raw: &toml::Table,
    ) -> Result<serde_json::Value, Vec<SettingsProblem>>;
    fn defaults(&self) -> serde_json::Value;
    /// See [`Stage::check_settings`]; `canonical` comes from [`StageKind::canonical_settings`].
    fn check_settings(
        &self,
        canonical: &serde_json::Value,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem>;
    /// See [`Stage::check_sources`].
    fn check_sources(
        &self,
        canonical: &serde_json::Value,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem>;
    /// Runs the stage after [`StageKind::check_settings`], so library callers get
    /// the checks job-file validation makes.
    fn run(
        &self,
        ctx: &StageContext,
        canonical: &serde_json::Value,
    ) -> Result<StageOutputs, StageError>;
    /// See [`Stage::external_key`].
    fn external_key(
        &self,
        canonical: &serde_json::Value,
        job_dir: &Path,
        run_date: i64,
    ) -> Result<serde_json::Value, StageError>;
}

impl<S: Stage> StageKind for S {
    fn info(&self) -> &'static StageInfo {
        Stage::info(self)
    }

    fn settings_schema(&self) -> serde_json::Value {
        serde_json::to_value(schemars::schema_for!(S::Settings)).expect("schema serialises")
    }

    fn canonical_settings(
        &self,
        raw: &toml::Table,
    ) -> Result<serde_json::Value, Vec<SettingsProblem>> {
        let schema = self.settings_schema();
        let known: Vec<&str> = schema["properties"]
            .as_object()
            .map(|p| p.keys().map(String::as_str).collect())
            .unwrap_or_default();
        let unknown: Vec<SettingsProblem> = raw
            .keys()
            .filter(|k| !known.contains(&k.as_str()))
            .map(|k| SettingsProblem {
                key: k.clone(),
                message: format!(
                    "unknown setting `{k}` for stage kind `{}`{}",
                    self.info().kind,
                    crate::suggest::did_you_mean(k, known.iter().copied())
                ),
            })
            .collect();
        if !unknown.is_empty() {
            return Err(unknown);
        }
        // Before serde: JSON has no NaN, and serde_json would turn one into null.
        let mut problems = settings_check::non_finite_problems(raw);
        if !problems.is_empty() {
            return Err(problems);
        }
        // Check each key on its own so that every bad value is reported, not just
        // the first: its type, then its range (the other settings are defaults,
        // which are in range).
        for (key, value) in raw {
            let mut single = toml::Table::new();
            single.insert(key.clone(), value.clone());
            match parse_settings::<S::Settings>(&single) {
                Ok(settings) => problems.extend(settings_check::range_problems(
                    &serde_json::to_value(settings).expect("settings serialise"),
                    &schema,
                )),
                Err(mut e) => {
                    // A value of the wrong type (`per_config = 1e9`, `restarts = -1`)
                    // is told the range too.
                    if let Some(range) = schema["properties"]
                        .get(e.key.as_str())
                        .and_then(|p| settings_check::range_text(p, &schema))
                    {
                        e.message = format!("{} (range {range})", e.message);
                    }
                    problems.push(e);
                }
            }
        }
        if !problems.is_empty() {
            return Err(problems);
        }
        let settings = parse_settings::<S::Settings>(raw).map_err(|e| vec![e])?;
        Ok(serde_json::to_value(settings).expect("settings serialise"))
    }

    fn defaults(&self) -> serde_json::Value {
        serde_json::to_value(S::Settings::default()).expect("settings serialise")
    }

    fn check_settings(
        &self,
        canonical: &serde_json::Value,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        if let Some(problem) = track_problem(self.info().kind, ctx.robot) {
            return vec![problem];
        }
        match typed_settings::<S>(canonical) {
            Ok(settings) => Stage::check_settings(self, &settings, ctx),
            Err(e) => vec![SettingsProblem::new("", e.to_string())],
        }
    }

    fn check_sources(
        &self,
        canonical: &serde_json::Value,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        match typed_settings::<S>(canonical) {
            Ok(settings) => Stage::check_sources(self, &settings, ctx),
            Err(e) => vec![SettingsProblem::new("", e.to_string())],
        }
    }

    fn run(
        &self,
        ctx: &StageContext,
        canonical: &serde_json::Value,
    ) -> Result<StageOutputs, StageError> {
        let settings = typed_settings::<S>(canonical)?;
        let bound: Vec<&str> = ctx.inputs.keys().map(String::as_str).collect();
        let checks = SettingsContext {
            robot: ctx.robot.spec(),
            cable_robot: ctx.cable_robot,
            job_dir: ctx.job_dir,
            bound_inputs: &bound,
        };
        let mut problems: Vec<SettingsProblem> = track_problem(self.info().kind, ctx.robot.spec())
            .into_iter()
            .collect();
        if problems.is_empty() {
            problems = Stage::check_settings(self, &settings, &checks);
        }
        if !problems.is_empty() {
            return Err(settings_error(&problems));
        }
        Stage::run(self, ctx, &settings)
    }

    fn external_key(
        &self,
        canonical: &serde_json::Value,
        job_dir: &Path,
        run_date: i64,
    ) -> Result<serde_json::Value, StageError> {
        Stage::external_key(self, &typed_settings::<S>(canonical)?, job_dir, run_date)
    }
}

/// The stage kinds that handle a robot on a linear track (issue #30): those
/// that read measured or commanded rows with their `e1_mm` and evaluate
/// the model through the carriage, and the campaign's design and measurement
/// (poses at carriage stations, wrenches, the rig moving the carriage); the
/// ISO 9283 test at one carriage position; the accuracy map (each grid point
/// from its nearest row's carriage position) and the logs (simulated and
/// scanned with `e1_mm`); `import_targets` (mapping `e1_mm`). `nest_poses`
/// would write the nests' rows without a carriage position, so it refuses
/// such a robot.
const TRACK_STAGES: &[&str] = &[
    "poses",
    "accuracy_map",
    "simulate_logs",
    "scan_logs",
    "import_targets",
    "wrenches",
    "measure",
    "compensate",
    "export_program",
    "identifiability",
    "select",
    "import_measurements",
    "split",
    "identify",
    "crossvalidate",
    "validate",
    "gate",
    "predict",
    "accuracy",
    "report",
    "iso_cube",
    "iso9283",
];

/// Why stage `kind` cannot run for `robot`: a track it does not handle yet.
fn track_problem(kind: &str, robot: &crate::robot::RobotSpec) -> Option<SettingsProblem> {
    (robot.track.is_some() && !TRACK_STAGES.contains(&kind)).then(|| {
        SettingsProblem::new(
            "",
            format!(
                "the robot file {} has a [track], and stage kind `{kind}` does not handle a robot on a track yet: it would place the arm as if the carriage stood at 0 (kinds that do: {})",
                robot.path.display(),
                TRACK_STAGES.join(", ")
            ),
        )
    })
}

fn typed_settings<S: Stage>(canonical: &serde_json::Value) -> Result<S::Settings, StageError> {
    serde_json::from_value(canonical.clone())
        .map_err(|e| StageError::Invalid(format!("settings: {e}")))
}

fn parse_settings<T: DeserializeOwned>(raw: &toml::Table) -> Result<T, SettingsProblem> {
    let value = toml::Value::Table(raw.clone());
    serde_path_to_error::deserialize(value).map_err(|e| SettingsProblem {
        key: e.path().to_string(),
        message: e.inner().message().to_string(),
    })
}

/// Every stage kind, in pipeline order.
pub fn registry() -> Vec<&'static dyn StageKind> {
    vec![
        &poses::PosesStage,
        &wrenches::WrenchesStage,
        &identifiability::IdentifiabilityStage,
        &nest_poses::NestPosesStage,
        &select::SelectStage,
        &measure::MeasureStage,
        &simulate_logs::SimulateLogsStage,
        &scan_logs::ScanLogsStage,
        &import_measurements::ImportMeasurementsStage,
        &import_targets::ImportTargetsStage,
        &split::SplitStage,
        &identify::IdentifyStage,
        &crossvalidate::CrossvalidateStage,
        &validate::ValidateStage,
        &gate::GateStage,
        &predict::PredictStage,
        &iso_cube::IsoCubeStage,
        &compensate::CompensateStage,
        &export_program::ExportProgramStage,
        &accuracy::AccuracyStage,
        &iso9283::Iso9283Stage,
        &accuracy_map::AccuracyMapStage,
        &report::ReportStage,
    ]
}

/// Looks a stage kind up by name.
pub fn lookup(kind: &str) -> Option<&'static dyn StageKind> {
    registry().into_iter().find(|s| s.info().kind == kind)
}

/// "unknown stage kind `x` (did you mean `y`?); known kinds: …"
pub fn unknown_kind_message(kind: &str) -> String {
    let known: Vec<&str> = registry().iter().map(|k| k.info().kind).collect();
    format!(
        "unknown stage kind `{kind}`{}; known kinds: {}",
        crate::suggest::did_you_mean(kind, known.iter().copied()),
        known.join(", ")
    )
}

/// The values of one model of a bound parameters table (`setting` names the
/// setting that chose the model, for messages), or the robot's nominal values
/// when the input is not bound.
pub fn model_values(
    ctx: &StageContext,
    input: &str,
    setting: &str,
    model: &str,
) -> Result<crate::robot::ParamValues, StageError> {
    Ok(model_set(ctx, input, setting, model)?.map_or_else(
        || crate::robot::ParamValues::nominal(ctx.robot.spec()),
        |set| set.values,
    ))
}

/// The parameter set of one model of a bound parameters table, as
/// [`model_values`]; `None` when the input is not bound.
pub fn model_set(
    ctx: &StageContext,
    input: &str,
    setting: &str,
    model: &str,
) -> Result<Option<crate::table::parameters::ParameterSet>, StageError> {
    use crate::table::parameters::{self, ModelName};
    let Some(table) = ctx.inputs.get(input) else {
        return Ok(None);
    };
    let model: ModelName = model
        .parse()
        .map_err(|m: String| StageError::Invalid(format!("setting `{setting}`: {m}")))?;
    let set = parameters::from_frame(&table.df, &table.path, ctx.robot.spec())?
        .into_iter()
        .find(|s| s.model == model)
        .ok_or_else(|| {
            StageError::Table(TableError::BadValue {
                file: table.path.clone(),
                column: "model".into(),
                row: 0,
                message: format!("no rows for model `{model}`"),
            })
        })?;
    joints_of_the_arm(ctx, table, &set)?;
    Ok(Some(set))
}

/// Refuses a set with a value for a joint the robot file does not have (a
/// seven-joint arm's `k7` given to a six-joint one): the model would never
/// read it, so the table is another arm's.
fn joints_of_the_arm(
    ctx: &StageContext,
    table: &InputTable,
    set: &crate::table::parameters::ParameterSet,
) -> Result<(), StageError> {
    use crate::robot::{MAX_JOINTS, ParamId};
    let joints = ctx.robot.joint_count();
    let Some(id) = ParamId::of_arm(MAX_JOINTS)
        .chain(ParamId::joint_terms())
        .find(|id| id.joint().is_some_and(|j| j >= joints) && set.values.get(*id) != 0.0)
    else {
        return Ok(());
    };
    let names = crate::table::schema::str_values(&table.df, "name", &table.path)?;
    let row = names
        .iter()
        .position(|n| n.as_deref() == Some(id.name()))
        .unwrap_or(0);
    Err(StageError::Table(TableError::BadValue {
        file: table.path.clone(),
        column: "name".into(),
        row,
        message: format!(
            "`{id}` = {} belongs to joint {}, but the robot file {} has {joints} joints: use this robot's parameters",
            set.values.get(id),
            id.joint().map_or(0, |j| j + 1),
            ctx.robot.spec().path.display()
        ),
    }))
}

/// Each row's target (SMR, tool) of `set` from the table's optional utf8
/// `target_id` column (spec §8: every stage that evaluates the model uses the
/// row's own tool): an error names the file and a target the set does not
/// know, or a several-target set without the column.
pub fn row_targets(
    input: &InputTable,
    set: &crate::table::parameters::ParameterSet,
    rows: usize,
) -> Result<Vec<usize>, StageError> {
    let ids = match input.df.column("target_id") {
        Ok(_) => Some(crate::table::schema::str_values(
            &input.df,
            "target_id",
            &input.path,
        )?),
        Err(_) => None,
    };
    set.target_indices(ids.as_deref(), rows)
        .map_err(|m| StageError::Invalid(format!("{}: {m}", input.path.display())))
}

/// Sets each row's target from [`row_targets`].
pub fn aim_rows(
    input: &InputTable,
    set: &crate::table::parameters::ParameterSet,
    rows: &mut [crate::robot::ConfWrench],
) -> Result<(), StageError> {
    let targets = row_targets(input, set, rows.len())?;
    for (row, target) in rows.iter_mut().zip(targets) {
        row.target = target;
    }
    Ok(())
}

/// The optional input of the stages that write the §7 predicted-position
/// uncertainty (`predict`, `validate`, `compensate`).
pub const COVARIANCE_INPUT: TableSlot = TableSlot {
    name: "covariance",
    schema: crate::table::schema::covariance,
    required: false,
    meaning: "identify's parameter covariance: adds cov_xx_mm2..cov_zz_mm2 (J·Σ·Jᵀ), null for a model without one; the columns are absent when not bound",
};

/// The covariance input's rows for `set` ([`crate::table::parameters::covariance_of`]):
/// `None` when the input is not bound, `Some(None)` when the model identifies nothing.
pub fn bound_covariance(
    ctx: &StageContext,
    set: &crate::table::parameters::ParameterSet,
) -> Result<Option<Option<crate::table::parameters::ModelCovariance>>, StageError> {
    let Some(table) = ctx.inputs.get(COVARIANCE_INPUT.name) else {
        return Ok(None);
    };
    Ok(Some(crate::table::parameters::covariance_of(
        &table.df,
        &table.path,
        set,
    )?))
}

/// The problem of a `covariance` input bound without the `parameters` it
/// belongs to (a covariance of nominal values means nothing).
pub fn covariance_binding_problem(ctx: &SettingsContext) -> Option<SettingsProblem> {
    (ctx.bound_inputs.contains(&COVARIANCE_INPUT.name) && !ctx.bound_inputs.contains(&"parameters"))
        .then(|| {
            SettingsProblem::new(
                "inputs.covariance",
                "input `covariance` needs the input `parameters` it was identified with",
            )
        })
}

/// `J·Σ·Jᵀ` of each row under `set` with its covariance; `None` per row for a
/// model without a covariance.
pub fn row_covariances(
    ctx: &StageContext,
    set: &crate::table::parameters::ParameterSet,
    covariance: Option<&crate::table::parameters::ModelCovariance>,
    rows: &[crate::robot::ConfWrench],
) -> Vec<Option<nalgebra::Matrix3<f64>>> {
    match covariance {
        Some(c) => crate::calibration::uncertainty::position_covariances(
            ctx.robot,
            &set.values,
            &c.free,
            &c.matrix,
            rows,
        )
        .into_iter()
        .map(Some)
        .collect(),
        None => vec![None; rows.len()],
    }
}

/// The six §7 columns `cov_xx_mm2 … cov_zz_mm2` of `covariances`, null where a
/// row has none.
pub fn covariance_columns(
    covariances: &[Option<nalgebra::Matrix3<f64>>],
) -> Vec<polars::prelude::Column> {
    use crate::table::schema::POSITION_COVARIANCE_COLUMNS;
    POSITION_COVARIANCE_COLUMNS
        .iter()
        .map(|(name, i, j)| {
            polars::prelude::Column::new(
                (*name).into(),
                covariances
                    .iter()
                    .map(|c| c.map(|c| c[(*i, *j)]))
                    .collect::<Vec<Option<f64>>>(),
            )
        })
        .collect()
}

/// Reads conf-wrench rows (cw_id, q1..q6 and a seventh joint's, wrench, approach directions where
/// given, the carriage position on a track) from a checked table.
pub fn conf_wrench_rows(
    input: &InputTable,
    robot: &crate::robot::RobotSpec,
) -> Result<(Vec<i64>, Vec<crate::robot::ConfWrench>), StageError> {
    use crate::table::schema::{WRENCH_COLUMNS, f64_values, i64_values, joint_vectors};
    let path = &input.path;
    let ids = i64_values(&input.df, "cw_id", path)?;
    let joints = joint_vectors(&input.df, path, robot)?;
    let wrench = WRENCH_COLUMNS
        .iter()
        .map(|c| f64_values(&input.df, c, path))
        .collect::<Result<Vec<_>, _>>()?;
    let approach = crate::table::schema::approach_values(&input.df, path)?;
    let track = track_positions(&input.df, &input.path, robot)?;
    let positioner = positioner_rows::positioner_axes_of_rows(&input.df, &input.path, robot)?;
    let rows = (0..ids.len())
        .map(|k| crate::robot::ConfWrench {
            q_deg: joints[k],
            wrench: crate::robot::Wrench::from_array(std::array::from_fn(|i| wrench[i][k])),
            target: 0,
            approach: approach[k],
            track_mm: track[k],
            positioner_deg: positioner[k],
        })
        .collect();
    Ok((ids, rows))
}

/// Each row's carriage position (`e1_mm`), checked against the robot
/// file's track: required with a track, refused without one (a position
/// nothing would read is a table meant for another cell), and within the
/// travel. Zeros without a track.
pub(crate) fn track_positions(
    df: &DataFrame,
    path: &Path,
    robot: &crate::robot::RobotSpec,
) -> Result<Vec<f64>, StageError> {
    use crate::table::schema::{TRACK_COLUMN, track_values};
    let values = track_values(df, path)?;
    match (&robot.track, values) {
        (None, None) => Ok(vec![0.0; df.height()]),
        (None, Some(_)) => Err(StageError::Invalid(format!(
            "{}: column `{TRACK_COLUMN}` gives a track position, but the robot file {} has no [track]: add it, or use the table of this robot",
            path.display(),
            robot.path.display()
        ))),
        (Some(_), None) => Err(StageError::Invalid(format!(
            "{}: the robot file {} has a [track], so every row needs its carriage position in column `{TRACK_COLUMN}` (mm)",
            path.display(),
            robot.path.display()
        ))),
        (Some(track), Some(values)) => {
            let [lo, hi] = track.travel_mm;
            if let Some((row, value)) = values
                .iter()
                .enumerate()
                .find(|(_, v)| !(lo..=hi).contains(*v))
            {
                return Err(StageError::Invalid(format!(
                    "{}: column `{TRACK_COLUMN}`, row {row}: {value} mm is outside the track's travel [{lo}, {hi}] mm (robot file {})",
                    path.display(),
                    robot.path.display()
                )));
            }
            Ok(values)
        }
    }
}

/// Conf-wrench rows that command the robot (candidates, rows to predict or to
/// simulate): a row beyond the joint limits or with an absurd wrench is not one
/// this robot can take, and what a stage computed for it would be nonsense (a
/// force of 1e300 N "deflects" the tool by 1e299 mm). The table is refused,
/// naming its first such row.
pub fn commanded_rows(
    ctx: &StageContext,
    input: &InputTable,
) -> Result<(Vec<i64>, Vec<crate::robot::ConfWrench>), StageError> {
    let (ids, rows) = conf_wrench_rows(input, ctx.robot.spec())?;
    let mut bad = rows.iter().enumerate().filter_map(|(k, row)| {
        crate::calibration::row_checks::conf_wrench_problem(ctx.robot, row).map(|p| (k, p))
    });
    if let Some((first, problem)) = bad.next() {
        let more = bad.count();
        return Err(StageError::Invalid(format!(
            "{}: row {first} (cw_id {}): {problem}{}",
            input.path.display(),
            ids[first],
            if more > 0 {
                format!(" ({more} more such rows)")
            } else {
                String::new()
            }
        )));
    }
    Ok((ids, rows))
}
