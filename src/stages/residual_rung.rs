//! The `eg_residual` rung across stages (issue #29): `identify` fits the
//! Gaussian-process residual over the rung's parameters and writes it as the
//! `residual_model` table; `validate`, `crossvalidate` and `compensate` read it
//! back ([`bound_residual`]) and add its mean to the parametric prediction and
//! its variance to the prediction's uncertainty.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use super::{StageContext, StageError, TableSlot};
use crate::calibration::ModelResult;
use crate::calibration::residual::{
    FeatureLayout, ResidualModel, ResidualOptions, ResidualPrediction,
};
use crate::robot::ConfWrench;
use crate::table::parameters::{ModelName, ParameterSet};
use crate::table::residual_model::{self, TrainingRows, features_of};
use crate::table::schema;

/// The optional input of the stages that predict with a parameter set.
pub const RESIDUAL_INPUT: TableSlot = TableSlot {
    name: "residual_model",
    schema: schema::residual_model,
    required: false,
    meaning: "identify's residual_model: needed (and used) by the eg_residual set, whose predictions add the residual's mean and variance",
};

/// The output of `identify`.
pub const RESIDUAL_OUTPUT: TableSlot = TableSlot {
    name: "residual_model",
    schema: schema::residual_model,
    required: true,
    meaning: "the eg_residual model's Gaussian-process residual: training rows, inducing points, hyperparameters (no rows without that model)",
};

/// A fitted residual with the rows it was fitted on.
pub struct FittedResidual {
    pub model: ModelName,
    pub ids: Vec<i64>,
    pub rows: Vec<ConfWrench>,
    pub residuals_mm: Vec<[f64; 3]>,
    pub fitted: ResidualModel,
}

/// Fits the residual of `result` (a parametric fit) on its rows the fit used
/// (weight > 0: robust exclusions stay out).
pub fn fit_over(
    model: ModelName,
    result: &ModelResult,
    ids: &[i64],
    rows: &[ConfWrench],
    options: &ResidualOptions,
    file: &Path,
) -> Result<FittedResidual, StageError> {
    // The features are six joints' angles and the wrench (`row_features`).
    if rows.iter().any(|row| row.q_deg[6] != 0.0) {
        return Err(StageError::Invalid(format!(
            "{}: model {model}'s residual features cover six joints; a seven-joint arm's residual rung is not built yet: use eg_harmonic or elastogeometric",
            file.display()
        )));
    }
    let used: Vec<usize> = (0..rows.len())
        .filter(|k| result.weights[*k] > 0.0)
        .collect();
    let ids: Vec<i64> = used.iter().map(|k| ids[*k]).collect();
    let rows: Vec<ConfWrench> = used.iter().map(|k| rows[*k]).collect();
    let residuals_mm: Vec<[f64; 3]> = used
        .iter()
        .map(|k| {
            let r = result.residuals_mm[*k];
            [r.x, r.y, r.z]
        })
        .collect();
    let fitted = ResidualModel::fit(
        &FeatureLayout::joint_load(),
        &features_of(&rows),
        &residuals_mm,
        options,
    )
    .map_err(|e| {
        StageError::Invalid(format!(
            "{}: {model}: the residual model: {e}",
            file.display()
        ))
    })?;
    Ok(FittedResidual {
        model,
        ids,
        rows,
        residuals_mm,
        fitted,
    })
}

/// The `residual_model` table of the fitted residuals (no rows without any).
pub fn to_frame(fitted: &[FittedResidual]) -> polars::prelude::DataFrame {
    let parts: Vec<(TrainingRows<'_>, &ResidualModel)> = fitted
        .iter()
        .map(|f| {
            (
                TrainingRows {
                    model: f.model,
                    ids: &f.ids,
                    rows: &f.rows,
                    residuals_mm: &f.residuals_mm,
                },
                &f.fitted,
            )
        })
        .collect();
    residual_model::to_frame(&parts)
}

/// The residual `set` predicts with: `None` for a model without one; an
/// error when the set needs one and the input is not bound or has no rows of it.
pub fn bound_residual(
    ctx: &StageContext,
    set: &ParameterSet,
) -> Result<Option<ResidualModel>, StageError> {
    if !set.model.has_residual_model() {
        return Ok(None);
    }
    let Some(table) = ctx.inputs.get(RESIDUAL_INPUT.name) else {
        return Err(StageError::Invalid(format!(
            "parameter set {} needs the input `residual_model` (identify's output of that name): without it its predictions would be {}'s",
            set.model,
            ModelName::EgHarmonic
        )));
    };
    residual_model::model_of(&table.df, &table.path, set.model)?
        .map(Some)
        .ok_or_else(|| {
            StageError::Invalid(format!(
                "{}: no rows of model {}; bind the `residual_model` written with the parameters",
                table.path.display(),
                set.model
            ))
        })
}

/// The residual's prediction at each row (mean and latent variance).
pub fn predict_rows(
    residual: &ResidualModel,
    rows: &[ConfWrench],
) -> Result<Vec<ResidualPrediction>, StageError> {
    residual
        .predict(&features_of(rows))
        .map_err(|e| StageError::Failed(format!("the residual model's prediction: {e}")))
}

/// For a set with a residual: its prediction at each row, with its mean added
/// to `predictions`' positions. `None` (nothing changed) for other sets.
pub fn add_mean(
    ctx: &StageContext,
    set: &ParameterSet,
    rows: &[ConfWrench],
    predictions: &mut [crate::robot::Prediction],
) -> Result<Option<(ResidualModel, Vec<ResidualPrediction>)>, StageError> {
    let Some(residual) = bound_residual(ctx, set)? else {
        return Ok(None);
    };
    let extra = predict_rows(&residual, rows)?;
    for (prediction, r) in predictions.iter_mut().zip(&extra) {
        prediction.position_mm += mean_mm(r);
    }
    Ok(Some((residual, extra)))
}

/// Adds the residual's variance to each row's `J·Σ·Jᵀ` (rows without one stay
/// `None`).
pub fn add_variance(covariances: &mut [Option<Matrix3<f64>>], extra: &[ResidualPrediction]) {
    for (c, r) in covariances.iter_mut().zip(extra) {
        *c = c.map(|c| c + covariance_mm2(r));
    }
}

/// The residual's mean as a vector (mm).
pub fn mean_mm(prediction: &ResidualPrediction) -> Vector3<f64> {
    Vector3::from(prediction.mean_mm)
}

/// The residual's latent covariance (mm², the same variance on each axis),
/// what adds to `J·Σ·Jᵀ`.
pub fn covariance_mm2(prediction: &ResidualPrediction) -> Matrix3<f64> {
    Matrix3::identity() * prediction.latent_variance_mm2
}

/// Passes of [`compensate_with_residual`]: the residual's mean changes by
/// about `|∇r|·Δq` between passes, and a pass moves the command by the mean
/// (hundredths of a mm, thousandths of a degree), so the second pass changes
/// it by far less than the tracker resolves.
const RESIDUAL_PASSES: usize = 2;

/// The commands that put the calibrated tool plus the residual's mean on the
/// targets: the targets are shifted by `−r(q)` at the command found, and
/// solved again from it (`hint_deg`), [`RESIDUAL_PASSES`] times. Returns the
/// commands and the residual's prediction at each of them. The commands'
/// `correction_mm` is measured from the shifted target (it differs by at most
/// the residual's mean, which the stage reports).
pub fn compensate_with_residual(
    robot: &crate::robot::Robot,
    values: &crate::robot::ParamValues,
    targets: &[crate::compensation::Target],
    options: &crate::compensation::Options,
    residual: &ResidualModel,
    approach: [i8; crate::robot::MAX_JOINTS],
) -> Result<(Vec<crate::compensation::Command>, Vec<ResidualPrediction>), StageError> {
    let rows_at = |commands: &[crate::compensation::Command]| {
        crate::compensation::command_rows(targets, commands, approach)
    };
    let mut commands = crate::compensation::compensate(robot, values, targets, options);
    let mut predictions = predict_rows(residual, &rows_at(&commands))?;
    for _ in 0..RESIDUAL_PASSES {
        let shifted: Vec<crate::compensation::Target> = targets
            .iter()
            .zip(&commands)
            .zip(&predictions)
            .map(|((target, command), r)| {
                let mut shifted = *target;
                shifted.tool_in_world.origin_mm -= mean_mm(r);
                if command.status == crate::compensation::Status::Ok {
                    shifted.hint_deg = Some(command.q_deg);
                }
                shifted
            })
            .collect();
        commands = crate::compensation::compensate(robot, values, &shifted, options);
        predictions = predict_rows(residual, &rows_at(&commands))?;
    }
    Ok((commands, predictions))
}
