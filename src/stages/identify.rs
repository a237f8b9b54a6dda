//! `identify`: kinematic and elasto-geometric identification (paper §III) from
//! measured rows — all of them, or those a `selection` marks `calibration`.
//!
//! Writes the `parameters` table (spec §6) with one set per requested model and the
//! Gauss–Newton trace. Dependent parameters are found numerically by rank analysis
//! at nominal and held at nominal (status `dependent`).

use std::collections::HashSet;

use nalgebra::Vector3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    InputTable, Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot,
    conf_wrench_rows,
};
use crate::calibration::fit::FitOptions;
use crate::calibration::{CalibrationOptions, calibrate};
use crate::robot::{ConfWrench, ParamId, ParamValues};
use crate::table::frame;
use crate::table::parameters::{self, ModelName};
use crate::table::schema::{self, f64_values, i64_values, str_values};

pub struct IdentifyStage;

/// Settings of `identify`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IdentifySettings {
    /// Models to identify: nominal, registered, kinematic, elastogeometric.
    pub models: Vec<String>,
    /// Parameters that may be freed (empty: all 42); rank analysis drops dependent ones.
    pub candidates: Vec<String>,
    /// Relative tolerance of the rank analysis on the column-scaled Jacobian.
    pub rank_tolerance: f64,
    pub max_iterations: usize,
    /// Stop when a step changes no predicted position by more than this (mm).
    pub stop_step_mm: f64,
}

impl Default for IdentifySettings {
    fn default() -> Self {
        IdentifySettings {
            models: ModelName::ALL
                .iter()
                .map(|m| m.as_str().to_string())
                .collect(),
            candidates: Vec::new(),
            rank_tolerance: 1e-6,
            max_iterations: 30,
            stop_step_mm: 1e-4,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "identify",
    uses_cable_robot: false,
    summary: "Kinematic and elasto-geometric identification with rank analysis and standard errors",
    code_version: 1,
    inputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "measured rows (spec §6)",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: false,
            meaning: "rows with role = calibration are used; all rows when absent",
        },
    ],
    outputs: &[
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: true,
            meaning: "one set per model (spec §6)",
        },
        TableSlot {
            name: "identification_trace",
            schema: schema::identification_trace,
            required: true,
            meaning: "Gauss–Newton iterations per model",
        },
    ],
};

/// Measured rows: ids, model inputs (measured joints and wrench) and measured positions.
#[derive(Debug, Default)]
pub struct MeasuredRows {
    pub ids: Vec<i64>,
    pub rows: Vec<ConfWrench>,
    pub positions: Vec<Vector3<f64>>,
}

/// The measured rows of a table, optionally only those whose id is in `keep`.
pub fn measured_rows(
    table: &InputTable,
    keep: Option<&HashSet<i64>>,
) -> Result<MeasuredRows, StageError> {
    let (ids, rows) = conf_wrench_rows(table)?;
    let xyz = schema::POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    let mut out = MeasuredRows::default();
    for k in 0..ids.len() {
        if keep.is_none_or(|keep| keep.contains(&ids[k])) {
            out.ids.push(ids[k]);
            out.rows.push(rows[k]);
            out.positions
                .push(Vector3::new(xyz[0][k], xyz[1][k], xyz[2][k]));
        }
    }
    Ok(out)
}

/// The cw_ids a selection table gives `role`.
pub fn ids_with_role(table: &InputTable, role: &str) -> Result<HashSet<i64>, StageError> {
    let ids = i64_values(&table.df, "cw_id", &table.path)?;
    let roles = str_values(&table.df, "role", &table.path)?;
    for (row, r) in roles.iter().enumerate() {
        let r = r.as_deref().unwrap_or_default();
        if r != "calibration" && r != "validation" {
            return Err(StageError::Table(crate::table::TableError::BadValue {
                file: table.path.clone(),
                column: "role".into(),
                row,
                message: format!("expected calibration or validation, found `{r}`"),
            }));
        }
    }
    Ok(ids
        .into_iter()
        .zip(roles)
        .filter(|(_, r)| r.as_deref() == Some(role))
        .map(|(id, _)| id)
        .collect())
}

fn parse_candidates(names: &[String]) -> Result<Vec<ParamId>, StageError> {
    if names.is_empty() {
        return Ok(ParamId::all().collect());
    }
    names
        .iter()
        .map(|n| {
            ParamId::from_name(n).ok_or_else(|| {
                StageError::Invalid(format!(
                    "setting `candidates`: unknown parameter `{n}`{}",
                    crate::suggest::did_you_mean(n, ParamId::all().map(|p| p.name()))
                ))
            })
        })
        .collect()
}

impl Stage for IdentifyStage {
    type Settings = IdentifySettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &IdentifySettings,
    ) -> Result<StageOutputs, StageError> {
        let models: Vec<ModelName> = settings
            .models
            .iter()
            .map(|m| {
                m.parse()
                    .map_err(|e: String| StageError::Invalid(format!("setting `models`: {e}")))
            })
            .collect::<Result<_, _>>()?;
        let options = CalibrationOptions {
            candidates: parse_candidates(&settings.candidates)?,
            rank_tolerance: settings.rank_tolerance,
            fit: FitOptions {
                max_iterations: settings.max_iterations,
                stop_step_mm: settings.stop_step_mm,
            },
        };
        let keep = match ctx.inputs.get("selection") {
            Some(selection) => Some(ids_with_role(selection, "calibration")?),
            None => None,
        };
        let MeasuredRows {
            rows,
            positions: measured,
            ..
        } = measured_rows(ctx.input("measurements")?, keep.as_ref())?;
        if rows.is_empty() {
            return Err(StageError::Invalid(
                "no calibration rows (selection marks none, or measurements is empty)".into(),
            ));
        }
        let mut sets = Vec::new();
        let (mut t_model, mut t_iter, mut t_rms, mut t_max, mut t_step) =
            (vec![], vec![], vec![], vec![], vec![]);
        let mut outputs = StageOutputs::default();
        for model in models {
            ctx.progress
                .note(&format!("identifying {model} on {} rows", rows.len()));
            let result = calibrate(ctx.robot, model, &rows, &measured, &options)
                .map_err(|e| StageError::Failed(format!("{model}: {e}")))?;
            if let Some(rank) = &result.rank {
                outputs.facts.insert(
                    format!("{model}_identified"),
                    format!(
                        "{} of {} (svd rank {})",
                        rank.independent.len(),
                        rank.independent.len() + rank.dependent.len(),
                        rank.svd_rank
                    ),
                );
            }
            if !result.converged {
                ctx.progress.note(&format!(
                    "{model}: not converged after {} iterations",
                    settings.max_iterations
                ));
            }
            for it in &result.trace {
                t_model.push(model.as_str());
                t_iter.push(it.iteration as i64);
                t_rms.push(it.rms_mm);
                t_max.push(it.max_mm);
                t_step.push(it.step_mm);
            }
            sets.push(result.set);
        }
        let nominal = ParamValues::nominal(ctx.robot.spec());
        outputs
            .tables
            .insert("parameters".into(), parameters::to_frame(&nominal, &sets));
        outputs.tables.insert(
            "identification_trace".into(),
            frame(vec![
                Column::new("model".into(), t_model),
                Column::new("iteration".into(), t_iter),
                Column::new("rms_mm".into(), t_rms),
                Column::new("max_mm".into(), t_max),
                Column::new("step_mm".into(), t_step),
            ]),
        );
        outputs
            .facts
            .insert("calibration_rows".into(), rows.len().to_string());
        Ok(outputs)
    }
}
