//! `export_program`: programs for the robot controller from a `commands` table
//! (spec §7): an ABB RAPID module, a KUKA KRL pair, a CSV, and (with a
//! parameters table) a URDF of the calibrated geometry. Writes files only, no
//! table; the runner publishes and caches them beside other stages' tables.
//!
//! The conventions live in `crate::export`; this file reads the rows, checks
//! the settings (names must be identifiers the controllers accept) and decides
//! what to do with rows whose status is not `ok` (`on_failed`).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, model_name_problem,
};
use crate::export::{self, Command, MotionSettings, Motions, Provenance, krl, rapid, urdf};
use crate::robot::ParamValues;
use crate::table::parameters::{self, ModelName};
use crate::table::schema::{
    self, COMMAND_POSITION_COLUMNS, COMMAND_QUATERNION_COLUMNS, JOINT_COLUMNS, f64_values,
    i64_values, str_values,
};
use crate::table::{self as tables, TableError};

pub struct ExportProgramStage;

/// A file format `export_program` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ProgramFormat {
    /// ABB RAPID module `<module_name>.mod`.
    Rapid,
    /// KUKA KRL pair `<module_name>.src` and `<module_name>.dat`.
    Krl,
    /// `commands.csv`.
    Csv,
    /// `robot.urdf` of the calibrated geometry (needs the `parameters` input).
    Urdf,
}

/// How the programs move to the targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MotionSetting {
    /// Joint moves to the joint commands (RAPID `MoveAbsJ`, KRL `PTP` E6AXIS):
    /// the controller's inverse kinematics is not involved.
    Joint,
    /// Cartesian moves to the corrected targets (RAPID `MoveJ` then `MoveL`, KRL
    /// `PTP` then `LIN` E6POS), with the configuration (confdata, Status/Turn).
    Linear,
    /// Both: the joint path, then the linear path.
    Both,
}

/// What to do with rows whose status is not `ok`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum OnFailedSetting {
    /// Leave them out of the motion and name them in each file's header.
    Skip,
    /// Fail (exit 2), naming the rows.
    Fail,
}

/// Zones RAPID predefines (`z0` … `z200`), in mm; KRL uses the same radius as
/// `$APO.CDIS`.
const ZONES_MM: [u32; 14] = [0, 1, 5, 10, 15, 20, 30, 40, 50, 60, 80, 100, 150, 200];

/// Settings of `export_program`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ExportProgramSettings {
    /// Files to write; by default every format that applies (URDF only with a
    /// `parameters` input).
    pub formats: Option<Vec<ProgramFormat>>,
    /// Model of the `parameters` input the URDF shows.
    pub model: String,
    /// RAPID module and KRL program name (and the files' base name): a letter,
    /// then letters, digits or `_`; at most 24 characters with KRL, 32 with RAPID.
    pub module_name: String,
    /// TCP speed, mm/s (RAPID speeddata `v_tcp`, KRL `$VEL.CP`).
    #[schemars(range(min = 1.0, max = 7000.0))]
    pub speed_mm_s: f64,
    /// Axis speed of KRL joint moves (`$VEL_AXIS`), percent.
    #[schemars(range(min = 1.0, max = 100.0))]
    pub joint_speed_percent: f64,
    /// `fine` (exact stop) or a RAPID predefined zone `z0` … `z200` (KRL:
    /// `$APO.CDIS` with `C_DIS` on linear moves).
    pub zone: String,
    /// RAPID tooldata name; it must hold the robot file's nominal tool.
    pub tool_name: String,
    /// RAPID work object name; it must be the robot base frame.
    pub wobj_name: String,
    /// KRL `TOOL_DATA` index of the robot file's nominal tool (0 = `$NULLFRAME`,
    /// the flange; KUKA's array has 16 entries).
    #[schemars(range(min = 0, max = 16))]
    pub krl_tool: u32,
    /// KRL `BASE_DATA` index of the robot base frame (0 = `$NULLFRAME`; KUKA's
    /// array has 32 entries).
    #[schemars(range(min = 0, max = 32))]
    pub krl_base: u32,
    /// `joint`, `linear` or `both`.
    pub motion: MotionSetting,
    /// Rows whose status is not `ok`: `skip` (named in the headers) or `fail`.
    pub on_failed: OnFailedSetting,
}

impl Default for ExportProgramSettings {
    fn default() -> Self {
        ExportProgramSettings {
            formats: None,
            model: ModelName::Elastogeometric.as_str().to_string(),
            module_name: "EGCAL_PROGRAM".into(),
            speed_mm_s: 100.0,
            joint_speed_percent: 20.0,
            zone: "fine".into(),
            tool_name: "tool0".into(),
            wobj_name: "wobj0".into(),
            krl_tool: 1,
            krl_base: 0,
            motion: MotionSetting::Joint,
            on_failed: OnFailedSetting::Skip,
        }
    }
}

impl ExportProgramSettings {
    /// The formats to write, given whether a parameters table is bound.
    fn formats(&self, parameters_bound: bool) -> Vec<ProgramFormat> {
        match &self.formats {
            Some(formats) => formats.clone(),
            None => {
                let mut all = vec![ProgramFormat::Rapid, ProgramFormat::Krl, ProgramFormat::Csv];
                if parameters_bound {
                    all.push(ProgramFormat::Urdf);
                }
                all
            }
        }
    }

    /// The zone radius in mm, `None` for `fine`; an error for another name.
    fn zone_mm(&self) -> Result<Option<u32>, String> {
        if self.zone == "fine" {
            return Ok(None);
        }
        self.zone
            .strip_prefix('z')
            .and_then(|n| n.parse::<u32>().ok())
            .filter(|n| ZONES_MM.contains(n))
            .map(Some)
            .ok_or_else(|| {
                format!(
                    "unknown zone `{}`, expected fine or one of {}",
                    self.zone,
                    ZONES_MM.map(|z| format!("z{z}")).join(", ")
                )
            })
    }
}

static INFO: StageInfo = StageInfo {
    kind: "export_program",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Programs for the controller from joint commands: ABB RAPID (.mod), KUKA KRL (.src/.dat), CSV, and a URDF of the calibrated geometry",
    code_version: 1,
    inputs: &[
        TableSlot {
            name: "commands",
            schema: schema::commands,
            required: true,
            meaning: "joint commands and corrected Cartesian targets (compensate)",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: false,
            meaning: "identified parameters; the URDF shows the model `model`",
        },
    ],
    outputs: &[],
};

impl Stage for ExportProgramStage {
    type Settings = ExportProgramSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &ExportProgramSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems: Vec<SettingsProblem> = model_name_problem("model", &settings.model)
            .into_iter()
            .collect();
        let parameters_bound = ctx.bound_inputs.contains(&"parameters");
        let formats = settings.formats(parameters_bound);
        if formats.is_empty() {
            problems.push(SettingsProblem::new(
                "formats",
                "no format given: list at least one of rapid, krl, csv, urdf",
            ));
        }
        if let Some(i) = formats.iter().position(|f| *f == ProgramFormat::Urdf)
            && !parameters_bound
        {
            problems.push(SettingsProblem::new(
                &format!("formats[{i}]"),
                "format `urdf` needs the input `parameters` (the calibrated geometry)",
            ));
        }
        let rapid = formats.contains(&ProgramFormat::Rapid);
        let krl = formats.contains(&ProgramFormat::Krl);
        let mut name_checks: Vec<(&str, &str, usize, &str)> = Vec::new();
        if rapid {
            name_checks.push((
                "module_name",
                &settings.module_name,
                rapid::MAX_IDENTIFIER_LEN,
                "RAPID",
            ));
            name_checks.push((
                "tool_name",
                &settings.tool_name,
                rapid::MAX_IDENTIFIER_LEN,
                "RAPID",
            ));
            name_checks.push((
                "wobj_name",
                &settings.wobj_name,
                rapid::MAX_IDENTIFIER_LEN,
                "RAPID",
            ));
        }
        if krl {
            name_checks.push((
                "module_name",
                &settings.module_name,
                krl::MAX_IDENTIFIER_LEN,
                "KRL",
            ));
        }
        for (key, name, max_len, language) in name_checks {
            if problems.iter().any(|p| p.key == key) {
                continue;
            }
            if let Some(message) = export::identifier_problem(name, max_len, language)
                .or_else(|| export::generated_name_clash(name))
            {
                problems.push(SettingsProblem::new(key, message));
            }
        }
        if let Err(message) = settings.zone_mm() {
            problems.push(SettingsProblem::new("zone", message));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &ExportProgramSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("commands")?;
        let commands = read_commands(&input.df, &input.path)?;
        let failed: Vec<String> = commands
            .iter()
            .filter(|c| !c.is_ok())
            .map(|c| format!("{} ({})", c.target_id, c.status))
            .collect();
        if settings.on_failed == OnFailedSetting::Fail && !failed.is_empty() {
            return Err(StageError::Invalid(format!(
                "{}: {} row(s) have a status other than ok and `on_failed = \"fail\"`: target_id {}",
                input.path.display(),
                failed.len(),
                failed.join(", ")
            )));
        }
        let provenance = Provenance {
            version: env!("CARGO_PKG_VERSION").to_string(),
            source: describe(&input.path, &input.df),
            robot: ctx.robot.spec().name.clone(),
        };
        let motion = MotionSettings {
            name: settings.module_name.clone(),
            speed_mm_s: settings.speed_mm_s,
            joint_speed_percent: settings.joint_speed_percent,
            zone_mm: settings
                .zone_mm()
                .map_err(|m| StageError::Invalid(format!("setting `zone`: {m}")))?,
            motions: Motions {
                joint: settings.motion != MotionSetting::Linear,
                linear: settings.motion != MotionSetting::Joint,
            },
        };
        let frames = krl::Frames {
            tool: settings.krl_tool,
            base: settings.krl_base,
        };
        let mut outputs = StageOutputs::default();
        let name = &settings.module_name;
        for format in settings.formats(ctx.inputs.contains_key("parameters")) {
            match format {
                ProgramFormat::Rapid => {
                    let text = rapid::module(
                        ctx.robot,
                        &commands,
                        &motion,
                        &settings.tool_name,
                        &settings.wobj_name,
                        &provenance,
                    );
                    outputs
                        .files
                        .insert(format!("{name}.mod"), text.into_bytes());
                }
                ProgramFormat::Krl => {
                    let src = krl::src(&commands, &motion, frames, &provenance);
                    let dat = krl::dat(ctx.robot, &commands, &motion, frames, &provenance);
                    outputs
                        .files
                        .insert(format!("{name}.src"), src.into_bytes());
                    outputs
                        .files
                        .insert(format!("{name}.dat"), dat.into_bytes());
                }
                ProgramFormat::Csv => {
                    let text = export::csv::table(&commands, &provenance);
                    outputs
                        .files
                        .insert("commands.csv".into(), text.into_bytes());
                }
                ProgramFormat::Urdf => {
                    let text = urdf_text(ctx, settings)?;
                    outputs.files.insert("robot.urdf".into(), text.into_bytes());
                }
            }
        }
        let exported = commands.len() - failed.len();
        outputs
            .facts
            .insert("exported".into(), exported.to_string());
        outputs
            .facts
            .insert("skipped".into(), failed.len().to_string());
        outputs.facts.insert(
            "files".into(),
            outputs.files.keys().cloned().collect::<Vec<_>>().join(","),
        );
        Ok(outputs)
    }
}

/// A table's file name and content hash, for the headers (not the full path,
/// which differs between machines and cache entries).
fn describe(path: &std::path::Path, df: &polars::prelude::DataFrame) -> String {
    let file = path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    );
    format!("{file} (content hash {})", &tables::content_hash(df))
}

fn urdf_text(ctx: &StageContext, settings: &ExportProgramSettings) -> Result<String, StageError> {
    let table = ctx.input("parameters")?;
    let model: ModelName = settings
        .model
        .parse()
        .map_err(|m: String| StageError::Invalid(format!("setting `model`: {m}")))?;
    let nominal = ParamValues::nominal(ctx.robot.spec());
    let set = parameters::from_frame(&table.df, &table.path, &nominal)?
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
    let source = urdf::UrdfSource {
        version: env!("CARGO_PKG_VERSION").to_string(),
        parameters: describe(&table.path, &table.df),
        model: model.to_string(),
        targets: set.targets.clone(),
    };
    Ok(urdf::robot_urdf(ctx.robot, &set.values, &source))
}

/// The rows of a checked `commands` table; a quaternion far from unit length is
/// refused, naming its row.
pub fn read_commands(
    df: &polars::prelude::DataFrame,
    path: &std::path::Path,
) -> Result<Vec<Command>, TableError> {
    let ids = i64_values(df, "target_id", path)?;
    let joints: Vec<Vec<f64>> = JOINT_COLUMNS
        .iter()
        .map(|c| f64_values(df, c, path))
        .collect::<Result<_, _>>()?;
    let status = str_values(df, "status", path)?;
    let [residual, correction, elastic] =
        ["residual_mm", "correction_mm", "elastic_mm"].map(|c| f64_values(df, c, path));
    let (residual, correction, elastic) = (residual?, correction?, elastic?);
    let position: Vec<Vec<f64>> = COMMAND_POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(df, c, path))
        .collect::<Result<_, _>>()?;
    let quaternion: Vec<Vec<f64>> = COMMAND_QUATERNION_COLUMNS
        .iter()
        .map(|c| f64_values(df, c, path))
        .collect::<Result<_, _>>()?;
    let mut rows = Vec::with_capacity(ids.len());
    for (row, id) in ids.iter().enumerate() {
        let q: [f64; 4] = std::array::from_fn(|k| quaternion[k][row]);
        let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(TableError::BadValue {
                file: path.to_path_buf(),
                column: "qw_cmd".into(),
                row,
                message: format!(
                    "quaternion (qw_cmd, qx_cmd, qy_cmd, qz_cmd) has norm {norm}, expected a unit quaternion"
                ),
            });
        }
        rows.push(Command {
            target_id: *id,
            q_deg: std::array::from_fn(|j| joints[j][row]),
            status: status[row].clone().unwrap_or_default(),
            residual_mm: residual[row],
            correction_mm: correction[row],
            elastic_mm: elastic[row],
            position_mm: std::array::from_fn(|k| position[k][row]),
            quaternion_wxyz: q,
        });
    }
    Ok(rows)
}

/// How far from 1 a quaternion's norm may be: the table stores a unit
/// quaternion, so more than rounding means a wrong column.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-6;
