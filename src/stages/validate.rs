//! `validate`: predicts the validation rows with every model of a parameters table
//! and compares each with the measurements (paper §VI, eq. (30), Table III), then
//! tests every pair of models on the same rows: paired t, Welch's t, Student's t
//! (the paper's) and the Wilcoxon signed-rank test (error norms are not normal).
//!
//! With the optional `covariance` input (identify's), each model's rows also get
//! their predicted-position uncertainty J·Σ·Jᵀ (spec §7) and whether the error
//! lies inside the 95 % ellipsoid of `J·Σ·Jᵀ + σ²·N`, σ² the fit's variance
//! factor (the `covariance` table's `variance_factor`) and `N` the identity, or
//! `diag(σ_row²)` for rows with the §7 per-point σ columns (validation rows are
//! taken to be weighted as the calibration rows were). `stats` gets the share
//! of covered rows, `coverage_95`: near 0.95 when the calibration's uncertainty
//! is honest, below when the model misses effects the noise does not explain.
//! Without the input those columns are left out; for a model without a
//! covariance (nominal) they are null.
//!
//! The `eg_residual` set (issue #29) needs the `residual_model` input: its
//! predictions add the residual's mean, its `J·Σ·Jᵀ` the residual's latent
//! variance, and its coverage takes the residual's noise variance as the
//! rows' noise (rows without σ columns).
//!
//! Rows with a measured tool orientation (6-D rows, spec §8) also get their
//! orientation error, the angle between the model's and the measured tool
//! orientation (`errors.error_deg`; `stats.mean_deg`, `rms_deg`, `max_deg`).
//! The hypothesis tests compare position errors only.

use nalgebra::Matrix3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::identify::{MeasuredRows, ids_with_role, measured_rows};
use super::{
    Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot, bound_covariance,
    covariance_columns, row_covariances,
};
use crate::calibration::fit::{MeasuredOrientation, Observations, orientation_residuals};
use crate::calibration::uncertainty::{chi_squared_3_quantile, within_ellipsoid};
use crate::robot::batch_predict;
use crate::stats::{self, TestResult};
use crate::table::parameters::{self, ModelName};
use crate::table::{frame, schema};

pub struct ValidateStage;

/// A two-sided test of two samples of error norms.
type TwoSampleTest = fn(&[f64], &[f64]) -> Result<TestResult, stats::StatsError>;

/// Settings of `validate` (none yet: the models are those of the parameters table).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ValidateSettings {}

static INFO: StageInfo = StageInfo {
    kind: "validate",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Validation errors per model, statistics (Table III) and pairwise hypothesis tests",
    code_version: 7,
    inputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "measured rows (a separate validation table, or all rows with a selection)",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: true,
            meaning: "parameter sets to compare",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: false,
            meaning: "rows with role = validation are used; all rows when absent",
        },
        super::COVARIANCE_INPUT,
        super::residual_rung::RESIDUAL_INPUT,
    ],
    outputs: &[
        TableSlot {
            name: "errors",
            schema: schema::errors,
            required: true,
            meaning: "per row and model: error components and norm; with a covariance, J·Σ·Jᵀ and whether the error is inside its 95 % ellipsoid",
        },
        TableSlot {
            name: "stats",
            schema: schema::stats,
            required: true,
            meaning: "per model: n, mean, std, median, rms, p95, max; coverage_95 with a covariance",
        },
        TableSlot {
            name: "tests",
            schema: schema::tests,
            required: true,
            meaning: "per pair of models and test: statistic, dof, p-value",
        },
    ],
};

impl Stage for ValidateStage {
    type Settings = ValidateSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(&self, ctx: &StageContext, _: &ValidateSettings) -> Result<StageOutputs, StageError> {
        let keep = match ctx.inputs.get("selection") {
            Some(selection) => Some(ids_with_role(selection, "validation")?),
            None => None,
        };
        let measurements = ctx.input("measurements")?;
        let mut data = measured_rows(measurements, ctx.robot.spec(), keep.as_ref())?;
        let left_out = data.leave_out_bad_rows(ctx.robot, &measurements.path);
        if let Some(summary) = &left_out {
            ctx.progress.note(&format!("warning: {summary}"));
        }
        let measured_rotations: Option<Vec<Option<MeasuredOrientation>>> =
            data.measured_rotations().map(|rotations| {
                rotations
                    .into_iter()
                    .map(|world_from_tool| {
                        Some(MeasuredOrientation {
                            world_from_tool,
                            scale_per_deg: 1.0,
                        })
                    })
                    .collect()
            });
        let MeasuredRows {
            ids,
            rows,
            positions: measured,
            target_ids,
            sigma_mm,
            ..
        } = data;
        if ids.len() < 2 {
            return Err(StageError::Invalid(format!(
                "{} validation rows; need at least 2",
                ids.len()
            )));
        }
        let table = ctx.input("parameters")?;
        let mut sets = parameters::from_frame(&table.df, &table.path, ctx.robot.spec())?;
        sets.sort_by_key(|s| s.model);

        let mut e = ErrorColumns::default();
        let mut norms: Vec<(ModelName, Vec<f64>)> = Vec::new();
        let mut angles: Vec<Vec<f64>> = Vec::new();
        let mut coverages: Vec<Option<f64>> = Vec::new();
        let radius_squared = chi_squared_3_quantile(COVERAGE_PROBABILITY);
        for set in &sets {
            // Each row's SMR: the set's translation of the row's target (spec §7).
            let targets = set
                .target_indices(target_ids.as_deref(), rows.len())
                .map_err(|m| {
                    StageError::Invalid(format!("{}: {m}", measurements.path.display()))
                })?;
            let mut rows = rows.clone();
            for (row, target) in rows.iter_mut().zip(&targets) {
                row.target = *target;
            }
            let mut predictions = batch_predict(ctx.robot, &set.values, &rows);
            let residual = super::residual_rung::add_mean(ctx, set, &rows, &mut predictions)?;
            if let Some(orientations) = &measured_rotations {
                let observations = Observations {
                    orientations: Some(orientations),
                    ..Observations::new(&rows, &measured)
                };
                let residuals = orientation_residuals(ctx.robot, &set.values, &observations);
                let model_angles: Vec<f64> = residuals
                    .iter()
                    .map(|r| r.map_or(f64::NAN, |r| r.norm()))
                    .collect();
                e.angle.extend(model_angles.iter().copied());
                angles.push(model_angles);
            }
            let covariance = bound_covariance(ctx, set)?;
            let mut model_norms = Vec::with_capacity(rows.len());
            let mut covered = Vec::with_capacity(rows.len());
            let mut covariances = covariance
                .as_ref()
                .map(|c| row_covariances(ctx, set, c.as_ref(), &rows));
            if let (Some(covariances), Some((_, extra))) = (covariances.as_mut(), &residual) {
                super::residual_rung::add_variance(covariances, extra);
            }
            // The residual model's noise is what its mean leaves; the fit's
            // variance factor counts the residual's signal as noise too.
            let variance_factor = match &residual {
                Some((model, _)) if sigma_mm.is_none() => {
                    Some(model.hyperparameters().noise_variance_mm2)
                }
                _ => covariance.flatten().and_then(|c| c.variance_factor),
            };
            for (k, prediction) in predictions.iter().enumerate() {
                let error = prediction.position_mm - measured[k];
                e.cw_id.push(ids[k]);
                e.model.push(set.model.as_str());
                e.ex.push(error.x);
                e.ey.push(error.y);
                e.ez.push(error.z);
                e.norm.push(error.norm());
                model_norms.push(error.norm());
                let inside = covariances.as_ref().and_then(|c| c[k]).and_then(|c| {
                    let noise = sigma_mm.as_ref().map_or_else(Matrix3::identity, |s| {
                        Matrix3::from_diagonal(&s[k].component_mul(&s[k]))
                    });
                    within_ellipsoid(&error, &(c + noise * variance_factor?), radius_squared)
                });
                covered.push(inside);
            }
            if let Some(c) = covariances {
                e.covariances.extend(c);
                e.covered.extend(&covered);
            }
            let checked: Vec<bool> = covered.iter().flatten().copied().collect();
            let coverage = (!checked.is_empty())
                .then(|| checked.iter().filter(|c| **c).count() as f64 / checked.len() as f64);
            norms.push((set.model, model_norms));
            coverages.push(coverage);
        }
        let with_covariance = ctx.inputs.contains_key(super::COVARIANCE_INPUT.name);

        let mut s = StatsColumns::default();
        for model_angles in &angles {
            let summary = stats::summary(model_angles)
                .map_err(|err| StageError::Failed(format!("orientation errors: {err}")))?;
            s.mean_deg.push(summary.mean);
            s.rms_deg.push(summary.rms);
            s.max_deg.push(summary.max);
        }
        for ((model, values), coverage) in norms.iter().zip(&coverages) {
            s.coverage_95.push(*coverage);
            let summary = stats::summary(values)
                .map_err(|err| StageError::Failed(format!("{model}: {err}")))?;
            s.model.push(model.as_str());
            s.n.push(summary.n as i64);
            s.mean.push(summary.mean);
            s.std.push(summary.std);
            s.median.push(summary.median);
            s.rms.push(summary.rms);
            s.p95.push(summary.p95);
            s.max.push(summary.max);
        }

        let mut t = TestColumns::default();
        let tests: [(&str, TwoSampleTest); 4] = [
            ("paired_t", stats::paired_t),
            ("welch_t", stats::welch_t),
            ("student_t", stats::student_t),
            ("wilcoxon", stats::wilcoxon_signed_rank),
        ];
        for (i, (model_a, a)) in norms.iter().enumerate() {
            for (model_b, b) in &norms[i + 1..] {
                for (name, test) in &tests {
                    match test(a, b) {
                        Ok(result) => t.push(model_a.as_str(), model_b.as_str(), name, &result),
                        Err(err) => ctx
                            .progress
                            .note(&format!("{name} {model_a} vs {model_b}: {err}")),
                    }
                }
            }
        }

        let mut outputs = StageOutputs::default();
        outputs
            .facts
            .insert("validation_rows".into(), ids.len().to_string());
        if let Some(summary) = left_out {
            outputs.facts.insert("rows_left_out".into(), summary);
        }
        for (k, ((model, values), coverage)) in norms.iter().zip(&coverages).enumerate() {
            let max = values.iter().cloned().fold(0.0, f64::max);
            outputs
                .facts
                .insert(format!("{model}_max_mm"), format!("{max:.3}"));
            if let Some(model_angles) = angles.get(k) {
                let max_deg = model_angles.iter().cloned().fold(0.0, f64::max);
                outputs
                    .facts
                    .insert(format!("{model}_max_deg"), format!("{max_deg:.4}"));
            }
            if let Some(coverage) = coverage {
                outputs
                    .facts
                    .insert(format!("{model}_coverage_95"), format!("{coverage:.3}"));
            }
        }
        outputs
            .tables
            .insert("errors".into(), e.into_frame(with_covariance));
        outputs
            .tables
            .insert("stats".into(), s.into_frame(with_covariance));
        outputs.tables.insert("tests".into(), t.into_frame());
        Ok(outputs)
    }
}

#[derive(Default)]
struct ErrorColumns {
    cw_id: Vec<i64>,
    model: Vec<&'static str>,
    ex: Vec<f64>,
    ey: Vec<f64>,
    ez: Vec<f64>,
    norm: Vec<f64>,
    /// Orientation error (deg) per row, filled only for 6-D rows.
    angle: Vec<f64>,
    /// J·Σ·Jᵀ per row, filled only with a covariance input.
    covariances: Vec<Option<Matrix3<f64>>>,
    covered: Vec<Option<bool>>,
}

impl ErrorColumns {
    /// The table; with `with_covariance`, also the uncertainty columns.
    fn into_frame(self, with_covariance: bool) -> polars::prelude::DataFrame {
        let mut columns = vec![
            Column::new("cw_id".into(), self.cw_id),
            Column::new("model".into(), self.model),
            Column::new("ex_mm".into(), self.ex),
            Column::new("ey_mm".into(), self.ey),
            Column::new("ez_mm".into(), self.ez),
            Column::new("error_mm".into(), self.norm),
        ];
        if !self.angle.is_empty() {
            columns.push(Column::new("error_deg".into(), self.angle));
        }
        if with_covariance {
            columns.extend(covariance_columns(&self.covariances));
            columns.push(Column::new("covered_95".into(), self.covered));
        }
        frame(columns)
    }
}

/// The probability of the ellipsoid `coverage_95` counts rows inside.
const COVERAGE_PROBABILITY: f64 = 0.95;

#[derive(Default)]
struct StatsColumns {
    model: Vec<&'static str>,
    n: Vec<i64>,
    mean: Vec<f64>,
    std: Vec<f64>,
    median: Vec<f64>,
    rms: Vec<f64>,
    p95: Vec<f64>,
    max: Vec<f64>,
    /// Orientation error statistics, filled only for 6-D rows.
    mean_deg: Vec<f64>,
    rms_deg: Vec<f64>,
    max_deg: Vec<f64>,
    coverage_95: Vec<Option<f64>>,
}

impl StatsColumns {
    /// The table; with `with_covariance`, also `coverage_95`.
    fn into_frame(self, with_covariance: bool) -> polars::prelude::DataFrame {
        let mut columns = vec![
            Column::new("model".into(), self.model),
            Column::new("n".into(), self.n),
            Column::new("mean_mm".into(), self.mean),
            Column::new("std_mm".into(), self.std),
            Column::new("median_mm".into(), self.median),
            Column::new("rms_mm".into(), self.rms),
            Column::new("p95_mm".into(), self.p95),
            Column::new("max_mm".into(), self.max),
        ];
        if !self.mean_deg.is_empty() {
            columns.push(Column::new("mean_deg".into(), self.mean_deg));
            columns.push(Column::new("rms_deg".into(), self.rms_deg));
            columns.push(Column::new("max_deg".into(), self.max_deg));
        }
        if with_covariance {
            columns.push(Column::new("coverage_95".into(), self.coverage_95));
        }
        frame(columns)
    }
}

/// Rows of a `tests` table (also written by `accuracy`).
#[derive(Default)]
pub(super) struct TestColumns {
    model_a: Vec<&'static str>,
    model_b: Vec<&'static str>,
    test: Vec<&'static str>,
    statistic: Vec<f64>,
    dof: Vec<Option<f64>>,
    p_value: Vec<f64>,
}

impl TestColumns {
    pub(super) fn push(
        &mut self,
        model_a: &'static str,
        model_b: &'static str,
        test: &'static str,
        result: &TestResult,
    ) {
        self.model_a.push(model_a);
        self.model_b.push(model_b);
        self.test.push(test);
        self.statistic.push(result.statistic);
        self.dof.push(result.dof);
        self.p_value.push(result.p_value);
    }

    pub(super) fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("model_a".into(), self.model_a),
            Column::new("model_b".into(), self.model_b),
            Column::new("test".into(), self.test),
            Column::new("statistic".into(), self.statistic),
            Column::new("dof".into(), self.dof),
            Column::new("p_value".into(), self.p_value),
        ])
    }
}
