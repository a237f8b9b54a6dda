//! `identify`: kinematic and elasto-geometric identification (paper §III) from
//! measured rows — all of them, or those a `selection` marks `calibration`.
//!
//! Writes the `parameters` table (spec §6) with one set per requested model, the
//! residuals of each model on its rows, and the convergence trace. Dependent
//! parameters are found numerically by rank analysis at nominal and held at
//! nominal (status `dependent`).
//!
//! The log and the output metadata (facts) carry, per fitted model, why the
//! iteration stopped, the condition number of the scaled Jacobian, the strongest
//! parameter correlations and the rows beyond the outlier threshold.

use std::collections::HashSet;

use nalgebra::Vector3;
use polars::prelude::{Column, DataFrame};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    InputTable, Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot,
    conf_wrench_rows,
};
use crate::calibration::fit::{Algorithm, FitOptions, Loss};
use crate::calibration::stream;
use crate::calibration::{CalibrationOptions, ModelResult, calibrate};
use crate::robot::{ConfWrench, ParamId, ParamValues};
use crate::table::frame;
use crate::table::parameters::{self, ModelName};
use crate::table::schema::{self, f64_values, i64_values, str_values};

pub struct IdentifyStage;

/// How the fit steps (see `calibration::fit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum AlgorithmSetting {
    /// Levenberg–Marquardt with column scaling: damped steps, taken only when the
    /// cost drops; stops on `stop_step_mm`, `stop_relative_cost` or `max_iterations`.
    LevenbergMarquardt,
    /// The paper's iteration (§III.B, eq. (25)): undamped Gauss–Newton steps, all
    /// taken; stops on `stop_step_mm` or `max_iterations`.
    Paper,
}

/// The cost of a row's residual.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LossSetting {
    /// Squared residuals: the paper's estimator, which the standard errors assume.
    LeastSquares,
    /// Huber on each row's residual norm with threshold `outlier_threshold_mm`
    /// (iteratively reweighted): rows beyond it weigh threshold / residual.
    Huber,
}

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
    /// levenberg_marquardt (robust default) or paper (eq. (25) as published).
    pub algorithm: AlgorithmSetting,
    /// Steps tried at most, rejected Levenberg–Marquardt steps included.
    pub max_iterations: usize,
    /// Stop when a step changes no predicted position by more than this (mm). The
    /// paper used 0.05 mm.
    pub stop_step_mm: f64,
    /// Levenberg–Marquardt: stop when an accepted step lowers the cost by less than
    /// this fraction.
    pub stop_relative_cost: f64,
    /// least_squares (default) or huber. Off by default: with Gaussian tracker noise
    /// least squares is the efficient estimator and its standard errors are exact,
    /// and a fixed threshold in mm would treat the kinematic model's systematic
    /// load errors (about 1 mm) as outliers.
    pub loss: LossSetting,
    /// Rows whose residual norm exceeds this are reported as outliers (always) and
    /// downweighted (with loss = huber) (mm). About 15 times the tracker noise.
    pub outlier_threshold_mm: f64,
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
            algorithm: AlgorithmSetting::LevenbergMarquardt,
            max_iterations: 30,
            stop_step_mm: 1e-4,
            stop_relative_cost: 1e-10,
            loss: LossSetting::LeastSquares,
            outlier_threshold_mm: 0.5,
        }
    }
}

impl IdentifySettings {
    /// The fit options these settings describe.
    pub fn fit_options(&self) -> Result<FitOptions, StageError> {
        if !(self.outlier_threshold_mm > 0.0 && self.outlier_threshold_mm.is_finite()) {
            return Err(StageError::Invalid(format!(
                "setting `outlier_threshold_mm`: must be a positive number of mm, found {}",
                self.outlier_threshold_mm
            )));
        }
        Ok(FitOptions {
            algorithm: match self.algorithm {
                AlgorithmSetting::LevenbergMarquardt => Algorithm::LevenbergMarquardt,
                AlgorithmSetting::Paper => Algorithm::Paper,
            },
            loss: match self.loss {
                LossSetting::LeastSquares => Loss::LeastSquares,
                LossSetting::Huber => Loss::Huber {
                    threshold_mm: self.outlier_threshold_mm,
                },
            },
            max_iterations: self.max_iterations,
            stop_step_mm: self.stop_step_mm,
            stop_relative_cost: self.stop_relative_cost,
            chunk_rows: stream::CHUNK_ROWS,
        })
    }
}

static INFO: StageInfo = StageInfo {
    kind: "identify",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Kinematic and elasto-geometric identification with rank analysis and standard errors",
    code_version: 3,
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
            meaning: "steps tried per model (rms, max, step, damping, accepted)",
        },
        TableSlot {
            name: "residuals",
            schema: schema::residuals,
            required: true,
            meaning: "each model's residual and weight on each calibration row",
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
/// All rows are converted once and filtered in place, so a large table is not
/// copied twice.
pub fn measured_rows(
    table: &InputTable,
    keep: Option<&HashSet<i64>>,
) -> Result<MeasuredRows, StageError> {
    let (ids, rows) = conf_wrench_rows(table)?;
    let xyz = schema::POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    let positions = (0..ids.len())
        .map(|k| Vector3::new(xyz[0][k], xyz[1][k], xyz[2][k]))
        .collect();
    let mut out = MeasuredRows {
        ids,
        rows,
        positions,
    };
    if let Some(keep) = keep {
        let wanted: Vec<bool> = out.ids.iter().map(|id| keep.contains(id)).collect();
        retain_wanted(&mut out.ids, &wanted);
        retain_wanted(&mut out.rows, &wanted);
        retain_wanted(&mut out.positions, &wanted);
    }
    Ok(out)
}

/// Keeps the elements whose flag in `wanted` (one per element) is set.
fn retain_wanted<T>(values: &mut Vec<T>, wanted: &[bool]) {
    let mut flags = wanted.iter();
    values.retain(|_| flags.next().copied().unwrap_or(false));
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
            fit: settings.fit_options()?,
        };
        let keep = match ctx.inputs.get("selection") {
            Some(selection) => Some(ids_with_role(selection, "calibration")?),
            None => None,
        };
        let MeasuredRows {
            ids,
            rows,
            positions: measured,
        } = measured_rows(ctx.input("measurements")?, keep.as_ref())?;
        if rows.is_empty() {
            return Err(StageError::Invalid(
                "no calibration rows (selection marks none, or measurements is empty)".into(),
            ));
        }
        let mut sets = Vec::new();
        let mut trace = TraceColumns::default();
        let mut residuals: Option<DataFrame> = None;
        let mut outputs = StageOutputs::default();
        for model in models {
            ctx.progress
                .note(&format!("identifying {model} on {} rows", rows.len()));
            let result = calibrate(ctx.robot, model, &rows, &measured, &options)
                .map_err(|e| StageError::Failed(format!("{model}: {e}")))?;
            if !result.converged {
                ctx.progress.note(&format!(
                    "{model}: not converged after {} iterations",
                    settings.max_iterations
                ));
            }
            for (key, value) in model_facts(model, &result, &ids, settings.outlier_threshold_mm) {
                ctx.progress.note(&format!("{model}: {key} = {value}"));
                outputs.facts.insert(format!("{model}_{key}"), value);
            }
            trace.push(model, &result);
            let part = residual_frame(
                model,
                &result.residuals_mm,
                &result.weights,
                &ids,
                settings.outlier_threshold_mm,
            );
            match residuals.as_mut() {
                // Appends the columns' chunks; no copy.
                Some(all) => {
                    all.vstack_mut(&part)
                        .expect("residual frames share one schema");
                }
                None => residuals = Some(part),
            }
            sets.push(result.set);
        }
        let nominal = ParamValues::nominal(ctx.robot.spec());
        outputs
            .tables
            .insert("parameters".into(), parameters::to_frame(&nominal, &sets));
        outputs
            .tables
            .insert("identification_trace".into(), trace.into_frame());
        let residuals =
            residuals.unwrap_or_else(|| residual_frame(ModelName::Nominal, &[], &[], &[], 0.0));
        outputs.tables.insert("residuals".into(), residuals);
        outputs
            .facts
            .insert("calibration_rows".into(), rows.len().to_string());
        Ok(outputs)
    }
}

/// What the log and the metadata say about one model's fit.
fn model_facts(
    model: ModelName,
    result: &ModelResult,
    ids: &[i64],
    outlier_threshold_mm: f64,
) -> Vec<(&'static str, String)> {
    let mut facts = Vec::new();
    if let Some(rank) = &result.rank {
        facts.push((
            "identified",
            format!(
                "{} of {} (svd rank {})",
                rank.independent.len(),
                rank.independent.len() + rank.dependent.len(),
                rank.svd_rank
            ),
        ));
    }
    if let Some(diagnostics) = &result.diagnostics {
        facts.push((
            "stop",
            format!(
                "{} after {} steps",
                diagnostics.stop.as_str(),
                result.trace.len()
            ),
        ));
        facts.push((
            "condition_number",
            format!("{:.3e}", diagnostics.condition_number),
        ));
        facts.push((
            "correlations",
            diagnostics
                .correlations
                .iter()
                .map(|(a, b, rho)| format!("{a}/{b}={rho:+.4}"))
                .collect::<Vec<_>>()
                .join(","),
        ));
    }
    if model != ModelName::Nominal {
        // Counted over all rows, formatted only for those listed.
        let beyond = || {
            ids.iter()
                .zip(&result.residuals_mm)
                .map(|(id, r)| (*id, r.norm()))
                .filter(|(_, r_mm)| *r_mm > outlier_threshold_mm)
        };
        let count = beyond().count();
        let shown = beyond()
            .take(OUTLIERS_LISTED)
            .map(|(id, r_mm)| format!("{id}:{r_mm:.3}"))
            .collect::<Vec<_>>()
            .join(",");
        let more = count.saturating_sub(OUTLIERS_LISTED);
        facts.push((
            "outliers",
            format!(
                "{count} rows beyond {outlier_threshold_mm} mm{}{shown}{}",
                if count == 0 { "" } else { " (cw_id:r_mm) " },
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            ),
        ));
    }
    facts
}

/// Outlier rows named in the log and metadata per model (all are in `residuals`).
const OUTLIERS_LISTED: usize = 10;

/// Columns of `identification_trace`.
#[derive(Default)]
struct TraceColumns {
    model: Vec<&'static str>,
    iteration: Vec<i64>,
    rms_mm: Vec<f64>,
    max_mm: Vec<f64>,
    step_mm: Vec<f64>,
    damping: Vec<Option<f64>>,
    accepted: Vec<bool>,
}

impl TraceColumns {
    fn push(&mut self, model: ModelName, result: &ModelResult) {
        for it in &result.trace {
            self.model.push(model.as_str());
            self.iteration.push(it.iteration as i64);
            self.rms_mm.push(it.rms_mm);
            self.max_mm.push(it.max_mm);
            self.step_mm.push(it.step_mm);
            self.damping.push(it.damping);
            self.accepted.push(it.accepted);
        }
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("model".into(), self.model),
            Column::new("iteration".into(), self.iteration),
            Column::new("rms_mm".into(), self.rms_mm),
            Column::new("max_mm".into(), self.max_mm),
            Column::new("step_mm".into(), self.step_mm),
            Column::new("damping".into(), self.damping),
            Column::new("accepted".into(), self.accepted),
        ])
    }
}

/// The `residuals` rows of one model. Built as soon as the model is fitted, with
/// exact sizes, so that a million rows per model cost only the table's own
/// columns (about 64 bytes a row) and no growing buffers.
fn residual_frame(
    model: ModelName,
    residuals_mm: &[Vector3<f64>],
    weights: &[f64],
    ids: &[i64],
    threshold_mm: f64,
) -> DataFrame {
    let axis = |a: usize| -> Vec<f64> { residuals_mm.iter().map(|r| r[a]).collect() };
    let norms: Vec<f64> = residuals_mm.iter().map(|r| r.norm()).collect();
    let outlier: Vec<bool> = norms.iter().map(|r| *r > threshold_mm).collect();
    frame(vec![
        Column::new("cw_id".into(), ids),
        Column::new("model".into(), vec![model.as_str(); ids.len()]),
        Column::new("rx_mm".into(), axis(0)),
        Column::new("ry_mm".into(), axis(1)),
        Column::new("rz_mm".into(), axis(2)),
        Column::new("r_mm".into(), norms),
        Column::new("weight".into(), weights),
        Column::new("outlier".into(), outlier),
    ])
}
