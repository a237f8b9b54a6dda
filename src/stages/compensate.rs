//! `compensate`: the joint command per target that puts the calibrated, loaded
//! robot's tool on it, and the corrected Cartesian target for a controller that
//! keeps its nominal model (`../shared/spec/model.md` §7; the maths is
//! [`crate::compensation`]). This file only reads and checks the `targets`
//! rows and writes `commands` and `conf_wrenches`.
//!
//! `conf_wrenches` holds the `ok` commands as conf-wrench rows (cw_id =
//! target_id, q = the command, the target's wrench), so a `measure` stage can run
//! them on a rig or the simulator and the achieved positions can be compared
//! with the targets.
//!
//! With the optional `covariance` input, `commands` also carries the predicted
//! position's uncertainty at each command (spec §7, J·Σ·Jᵀ at the command and
//! the target's wrench): how well the calibration knows where the command puts
//! the tool. Null for a model without a covariance; absent without the input.

use polars::prelude::{Column, DataFrame, DataType};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, bound_covariance, covariance_binding_problem, covariance_columns,
    model_name_problem, model_set, row_covariances,
};
use crate::calibration::row_checks::{MAX_POSITION_MM, compact, joints_problem, wrench_problem};
use crate::compensation::{self, Command, Options, Status, Target};
use crate::robot::ik::NumericOptions;
use crate::robot::{ConfWrench, JOINTS, ParamValues, Robot, Wrench};
use crate::table::frame;
use crate::table::parameters::ModelName;
use crate::table::schema::{
    self, COMMAND_POSITION_COLUMNS, COMMAND_QUATERNION_COLUMNS, JOINT_COLUMNS, ORIENTATION_COLUMNS,
    POSITION_COLUMNS, WRENCH_COLUMNS, f64_values, i64_values, io_error,
};

pub struct CompensateStage;

/// Settings of `compensate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CompensateSettings {
    /// Which model of the `parameters` input to compensate with: nominal,
    /// registered, kinematic or elastogeometric. Ignored when no parameters table
    /// is bound (nominal).
    pub model: String,
    /// A command is converged when the tool position is within this of the target (mm).
    #[schemars(range(min = 1e-12, max = 1.0))]
    pub position_tolerance_mm: f64,
    /// ... and the tool orientation within this (rad).
    #[schemars(range(min = 1e-14, max = 0.01))]
    pub orientation_tolerance_rad: f64,
    /// Levenberg–Marquardt iterations per target before `not_converged`.
    #[schemars(range(min = 1, max = 10_000))]
    pub max_iterations: usize,
    /// A converged command is `singular` when the smallest singular value of the
    /// geometric Jacobian at the tool (1 rad of rotation counted as 1000 mm) is
    /// below this (mm/rad); about 7 mm/rad per degree of q5 from the IRB 1600's
    /// straight wrist, so the default flags |q5| below about 0.5°. 0 reports no singularity of a converged command.
    #[schemars(range(min = 0.0, max = 10_000.0))]
    pub singular_sigma_min_mm_per_rad: f64,
}

impl Default for CompensateSettings {
    fn default() -> Self {
        CompensateSettings {
            model: ModelName::Elastogeometric.as_str().to_string(),
            position_tolerance_mm: 1e-6,
            orientation_tolerance_rad: 1e-6,
            max_iterations: 100,
            singular_sigma_min_mm_per_rad: 3.5,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "compensate",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Load-aware compensation: joint commands that put the calibrated, loaded tool on each target, and corrected Cartesian targets for the nominal controller",
    code_version: 2,
    inputs: &[
        TableSlot {
            name: "targets",
            schema: schema::targets,
            required: true,
            meaning: "target_id, tool pose in the world frame, optional wrench and branch hint",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: false,
            meaning: "parameter sets; nominal when absent",
        },
        super::COVARIANCE_INPUT,
    ],
    outputs: &[
        TableSlot {
            name: "commands",
            schema: schema::commands,
            required: true,
            meaning: "one row per target, in target order: command, status, residual, correction, corrected Cartesian target",
        },
        TableSlot {
            name: "conf_wrenches",
            schema: schema::conf_wrenches,
            required: true,
            meaning: "the ok commands as conf-wrench rows (cw_id = target_id) for a measure stage",
        },
    ],
};

impl Stage for CompensateStage {
    type Settings = CompensateSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &CompensateSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        model_name_problem("model", &settings.model)
            .into_iter()
            .chain(covariance_binding_problem(ctx))
            .collect()
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &CompensateSettings,
    ) -> Result<StageOutputs, StageError> {
        let set = model_set(ctx, "parameters", "model", &settings.model)?;
        let values = set
            .as_ref()
            .map_or_else(|| ParamValues::nominal(ctx.robot.spec()), |set| set.values);
        let input = ctx.input("targets")?;
        let (ids, targets) = target_rows(ctx.robot, &input.df, &input.path)?;
        let options = Options {
            solver: NumericOptions {
                max_iterations: settings.max_iterations,
                position_tolerance_mm: settings.position_tolerance_mm,
                orientation_tolerance_rad: settings.orientation_tolerance_rad,
                ..NumericOptions::default()
            },
            singular_sigma_min_mm_per_rad: settings.singular_sigma_min_mm_per_rad,
        };
        let commands = compensation::compensate(ctx.robot, &values, &targets, &options);
        let mut commands_table = commands_frame(&ids, &commands);
        if let Some(set) = &set
            && let Some(covariance) = bound_covariance(ctx, set)?
        {
            // Compensation aims the set's first target (one-target tool).
            let rows: Vec<ConfWrench> = targets
                .iter()
                .zip(&commands)
                .map(|(target, command)| ConfWrench::new(command.q_deg, target.wrench))
                .collect();
            let covariances = row_covariances(ctx, set, covariance.as_ref(), &rows);
            for column in covariance_columns(&covariances) {
                commands_table
                    .with_column(column)
                    .map_err(|e| StageError::Failed(format!("commands: {e}")))?;
            }
        }
        let mut outputs = StageOutputs::default();
        outputs.tables.insert("commands".into(), commands_table);
        outputs.tables.insert(
            "conf_wrenches".into(),
            conf_wrenches_frame(&ids, &targets, &commands),
        );
        outputs
            .facts
            .insert("targets".into(), ids.len().to_string());
        for status in Status::ALL {
            let count = commands.iter().filter(|c| c.status == status).count();
            outputs
                .facts
                .insert(status.as_str().into(), count.to_string());
        }
        Ok(outputs)
    }
}

/// Values of an optional f64 column: `None` where absent or null (a column
/// pandas wrote all-null has type null).
fn optional_f64(
    df: &DataFrame,
    name: &str,
    file: &std::path::Path,
) -> Result<Vec<Option<f64>>, StageError> {
    match df.column(name) {
        Err(_) => Ok(vec![None; df.height()]),
        Ok(column) if column.dtype() == &DataType::Null => Ok(vec![None; df.height()]),
        Ok(column) => Ok(column
            .f64()
            .map_err(|e| io_error(file, e))?
            .iter()
            .collect()),
    }
}

/// The checked `targets` rows. A missing wrench value is 0; a branch hint is used
/// only when all six q columns are given on the row. Refused, naming the row: a
/// position farther than [`MAX_POSITION_MM`] from the tracker, a wrench beyond
/// `row_checks`' bounds, a partial hint, a hint outside the robot file's joint
/// limits (a seed there asks for a branch the robot cannot take, and says the
/// row was typed for another robot or in radians).
fn target_rows(
    robot: &Robot,
    df: &DataFrame,
    file: &std::path::Path,
) -> Result<(Vec<i64>, Vec<Target>), StageError> {
    let ids = i64_values(df, "target_id", file)?;
    let required = |names: &[&str]| {
        names
            .iter()
            .map(|c| f64_values(df, c, file))
            .collect::<Result<Vec<_>, _>>()
    };
    let position = required(&POSITION_COLUMNS)?;
    let orientation = required(&ORIENTATION_COLUMNS)?;
    let optional = |names: &[&str]| {
        names
            .iter()
            .map(|c| optional_f64(df, c, file))
            .collect::<Result<Vec<_>, _>>()
    };
    let wrench = optional(&WRENCH_COLUMNS)?;
    let hint = optional(&JOINT_COLUMNS)?;
    let bad = |row: usize, message: String| {
        StageError::Invalid(format!(
            "{}: row {row} (target_id {}): {message}",
            file.display(),
            ids[row]
        ))
    };
    let mut targets = Vec::with_capacity(ids.len());
    for row in 0..ids.len() {
        let position_mm: [f64; 3] = std::array::from_fn(|i| position[i][row]);
        let distance = nalgebra::Vector3::from(position_mm).norm();
        // A NaN too, should one get past the schema check.
        if distance.is_nan() || distance > MAX_POSITION_MM {
            return Err(bad(
                row,
                format!(
                    "the target is {} mm from the tracker (more than {MAX_POSITION_MM} mm)",
                    compact(distance)
                ),
            ));
        }
        let wrench = Wrench::from_array(std::array::from_fn(|i| wrench[i][row].unwrap_or(0.0)));
        if let Some(problem) = wrench_problem(&ConfWrench::new([0.0; JOINTS], wrench)) {
            return Err(bad(row, problem));
        }
        let given: Vec<f64> = hint.iter().filter_map(|c| c[row]).collect();
        let hint_deg = match given.len() {
            0 => None,
            JOINTS => {
                let hint_deg: [f64; JOINTS] = std::array::from_fn(|i| given[i]);
                if let Some(problem) = joints_problem(robot, &hint_deg) {
                    return Err(bad(row, format!("branch hint: {problem}")));
                }
                Some(hint_deg)
            }
            n => {
                return Err(bad(
                    row,
                    format!(
                        "a branch hint needs all of {}, found {n} of them",
                        JOINT_COLUMNS.join(", ")
                    ),
                ));
            }
        };
        targets.push(Target::from_columns(
            position_mm,
            std::array::from_fn(|i| orientation[i][row]),
            wrench,
            hint_deg,
        ));
    }
    Ok((ids, targets))
}

fn commands_frame(ids: &[i64], commands: &[Command]) -> DataFrame {
    let mut columns = vec![Column::new("target_id".into(), ids.to_vec())];
    let float = |name: &str, f: &dyn Fn(&Command) -> f64| {
        Column::new(name.into(), commands.iter().map(f).collect::<Vec<f64>>())
    };
    for (joint, name) in JOINT_COLUMNS.iter().enumerate() {
        columns.push(float(name, &|c| c.q_deg[joint]));
    }
    columns.push(Column::new(
        "status".into(),
        commands
            .iter()
            .map(|c| c.status.as_str())
            .collect::<Vec<_>>(),
    ));
    columns.push(float("residual_mm", &|c| c.residual_mm));
    columns.push(float("correction_mm", &|c| c.correction_mm));
    columns.push(float("elastic_mm", &|c| c.elastic_mm));
    for (axis, name) in COMMAND_POSITION_COLUMNS.iter().enumerate() {
        columns.push(float(name, &|c| c.tool_in_base_cmd.origin_mm[axis]));
    }
    for (k, name) in COMMAND_QUATERNION_COLUMNS.iter().enumerate() {
        columns.push(float(name, &|c| c.quaternion_wxyz_cmd[k]));
    }
    frame(columns)
}

fn conf_wrenches_frame(ids: &[i64], targets: &[Target], commands: &[Command]) -> DataFrame {
    let ok: Vec<usize> = (0..ids.len())
        .filter(|&k| commands[k].status == Status::Ok)
        .collect();
    let mut columns = vec![Column::new(
        "cw_id".into(),
        ok.iter().map(|&k| ids[k]).collect::<Vec<_>>(),
    )];
    for (joint, name) in JOINT_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            ok.iter()
                .map(|&k| commands[k].q_deg[joint])
                .collect::<Vec<_>>(),
        ));
    }
    for (i, name) in WRENCH_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            ok.iter()
                .map(|&k| targets[k].wrench.to_array()[i])
                .collect::<Vec<_>>(),
        ));
    }
    frame(columns)
}
