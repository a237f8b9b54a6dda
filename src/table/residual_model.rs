//! The `residual_model` table (issue #29): the Gaussian-process residual of an
//! `eg_residual` parameter set as rows a consumer rebuilds the posterior from.
//!
//! The table keeps the training rows (joints, wrench, residual), which of them
//! are inducing points, and the hyperparameters, rather than the posterior's
//! factors: rebuilding costs `O(n·m²)` (well under a second for 10⁴ rows) and
//! the file stays readable and checkable by any Parquet tool.

use std::path::Path;

use polars::prelude::*;

use super::parameters::ModelName;
use super::schema::{
    self, JOINT_COLUMNS, LENGTH_SCALE_COLUMNS, RESIDUAL_COLUMNS, TableError, WRENCH_COLUMNS,
    f64_values, str_values,
};
use crate::calibration::residual::{
    FeatureLayout, Hyperparameters, JOINT_LOAD_FEATURES, ResidualModel, joint_load_features,
};
use crate::robot::ConfWrench;

/// The features of a conf-wrench row: its joint angles and wrench.
pub fn row_features(row: &ConfWrench) -> [f64; JOINT_LOAD_FEATURES] {
    // Six joints: `residual_rung::fit_over` refuses a seven-joint arm.
    let q_deg: [f64; 6] = std::array::from_fn(|i| row.q_deg[i]);
    joint_load_features(&q_deg, &row.wrench.to_array())
}

/// The features of many rows, row-major.
pub fn features_of(rows: &[ConfWrench]) -> Vec<f64> {
    rows.iter().flat_map(row_features).collect()
}

/// One model's training rows: what [`to_frame`] writes.
pub struct TrainingRows<'a> {
    pub model: ModelName,
    pub ids: &'a [i64],
    pub rows: &'a [ConfWrench],
    /// Measured − predicted by the model's parameter set (mm).
    pub residuals_mm: &'a [[f64; 3]],
}

/// The table of `fitted` (the models in `parts`, each with its fitted
/// residual); no rows when `parts` is empty.
pub fn to_frame(parts: &[(TrainingRows<'_>, &ResidualModel)]) -> DataFrame {
    let mut model: Vec<&str> = Vec::new();
    let mut cw_id: Vec<i64> = Vec::new();
    let mut joints: [Vec<f64>; 6] = Default::default();
    let mut wrench: [Vec<f64>; 6] = Default::default();
    let mut residual: [Vec<f64>; 3] = Default::default();
    let mut inducing: Vec<bool> = Vec::new();
    let mut signal: Vec<f64> = Vec::new();
    let mut noise: Vec<f64> = Vec::new();
    let mut scales: [Vec<f64>; 12] = Default::default();
    for (training, fitted) in parts {
        let h = fitted.hyperparameters();
        let mut chosen = vec![false; training.rows.len()];
        for k in fitted.inducing_rows() {
            chosen[*k] = true;
        }
        for (k, row) in training.rows.iter().enumerate() {
            model.push(training.model.as_str());
            cw_id.push(training.ids[k]);
            for (j, q) in row.q_deg.iter().take(joints.len()).enumerate() {
                joints[j].push(*q);
            }
            for (c, v) in row.wrench.to_array().into_iter().enumerate() {
                wrench[c].push(v);
            }
            for (a, r) in training.residuals_mm[k].iter().enumerate() {
                residual[a].push(*r);
            }
            inducing.push(chosen[k]);
            signal.push(h.signal_variance_mm2);
            noise.push(h.noise_variance_mm2);
            for (g, s) in h.length_scales.iter().enumerate() {
                scales[g].push(*s);
            }
        }
    }
    let mut columns = vec![
        Column::new("model".into(), model),
        Column::new("cw_id".into(), cw_id),
    ];
    let named = JOINT_COLUMNS
        .iter()
        .zip(joints)
        .chain(WRENCH_COLUMNS.iter().zip(wrench))
        .chain(RESIDUAL_COLUMNS.iter().zip(residual));
    columns.extend(named.map(|(name, values)| Column::new((*name).into(), values)));
    columns.push(Column::new("inducing".into(), inducing));
    columns.push(Column::new("signal_variance_mm2".into(), signal));
    columns.push(Column::new("noise_variance_mm2".into(), noise));
    columns.extend(
        LENGTH_SCALE_COLUMNS
            .iter()
            .zip(scales)
            .map(|(name, values)| Column::new((*name).into(), values)),
    );
    DataFrame::new_infer_height(columns).expect("residual_model columns have one length")
}

/// The residual of `model` rebuilt from the table; `None` when the table has
/// no rows of it. A hyperparameter that differs between rows, a bad value or
/// a posterior that cannot be factorised is an error naming the file.
pub fn model_of(
    df: &DataFrame,
    file: &Path,
    model: ModelName,
) -> Result<Option<ResidualModel>, TableError> {
    schema::residual_model().check(df, file)?;
    let models = str_values(df, "model", file)?;
    let rows: Vec<usize> = (0..df.height())
        .filter(|k| models[*k].as_deref() == Some(model.as_str()))
        .collect();
    if rows.is_empty() {
        return Ok(None);
    }
    let bad = |row: usize, column: &str, message: String| TableError::BadValue {
        file: file.to_path_buf(),
        column: column.to_string(),
        row,
        message,
    };
    let column = |name: &str| -> Result<Vec<f64>, TableError> {
        let all = f64_values(df, name, file)?;
        let picked: Vec<f64> = rows.iter().map(|k| all[*k]).collect();
        if let Some(i) = picked.iter().position(|v| !v.is_finite()) {
            return Err(bad(rows[i], name, "expected a finite number".into()));
        }
        Ok(picked)
    };
    let constant = |name: &str| -> Result<f64, TableError> {
        let values = column(name)?;
        let first = values[0];
        match values.iter().position(|v| *v != first) {
            Some(i) => Err(bad(
                rows[i],
                name,
                format!(
                    "{} differs from the model's first row ({first}): one value per model expected",
                    values[i]
                ),
            )),
            None => Ok(first),
        }
    };
    let joints = JOINT_COLUMNS
        .iter()
        .map(|c| column(c))
        .collect::<Result<Vec<_>, _>>()?;
    let wrench = WRENCH_COLUMNS
        .iter()
        .map(|c| column(c))
        .collect::<Result<Vec<_>, _>>()?;
    let residual = RESIDUAL_COLUMNS
        .iter()
        .map(|c| column(c))
        .collect::<Result<Vec<_>, _>>()?;
    let hyperparameters = Hyperparameters {
        signal_variance_mm2: constant("signal_variance_mm2")?,
        noise_variance_mm2: constant("noise_variance_mm2")?,
        length_scales: LENGTH_SCALE_COLUMNS
            .iter()
            .map(|c| constant(c))
            .collect::<Result<Vec<_>, _>>()?,
    };
    let inducing_all: Vec<bool> = df
        .column("inducing")
        .and_then(|c| {
            c.bool()
                .map(|b| b.iter().map(|v| v.unwrap_or(false)).collect())
        })
        .map_err(|e| schema::io_error(file, e))?;
    let mut features = Vec::with_capacity(rows.len() * JOINT_LOAD_FEATURES);
    let mut inducing = Vec::new();
    let mut residuals_mm = Vec::with_capacity(rows.len());
    for (i, k) in rows.iter().enumerate() {
        let q: [f64; 6] = std::array::from_fn(|j| joints[j][i]);
        let w: [f64; 6] = std::array::from_fn(|c| wrench[c][i]);
        let f = joint_load_features(&q, &w);
        features.extend_from_slice(&f);
        if inducing_all[*k] {
            inducing.extend_from_slice(&f);
        }
        residuals_mm.push([residual[0][i], residual[1][i], residual[2][i]]);
    }
    ResidualModel::with_hyperparameters(
        &FeatureLayout::joint_load(),
        &features,
        &residuals_mm,
        &hyperparameters,
        (!inducing.is_empty()).then_some(inducing.as_slice()),
    )
    .map(Some)
    .map_err(|e| {
        bad(
            rows[0],
            "model",
            format!("the residual of {model} cannot be rebuilt: {e}"),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::residual::ResidualOptions;
    use crate::robot::Wrench;
    use nalgebra::Vector3;

    fn training(n: usize) -> (Vec<i64>, Vec<ConfWrench>, Vec<[f64; 3]>) {
        let ids: Vec<i64> = (0..n as i64).collect();
        let rows: Vec<ConfWrench> = (0..n)
            .map(|k| {
                let t = k as f64;
                let q = [
                    t * 7.0 % 180.0,
                    t * 3.0 % 90.0 - 45.0,
                    20.0,
                    t % 60.0,
                    30.0,
                    0.0,
                ];
                let wrench = Wrench {
                    force_n: Vector3::new(0.0, 0.0, -(t % 5.0) * 20.0),
                    moment_nm: Vector3::zeros(),
                };
                ConfWrench::new(crate::robot::joint_array(&q), wrench)
            })
            .collect();
        let residuals = rows
            .iter()
            .map(|r| {
                let s = r.q_deg[0].to_radians().sin();
                [0.05 * s, -0.03 * s, 0.01 * r.q_deg[1].to_radians().cos()]
            })
            .collect();
        (ids, rows, residuals)
    }

    /// `n` training rows fitted with `inducing_points`, and their table.
    fn fitted_table(
        n: usize,
        inducing_points: usize,
    ) -> (Vec<ConfWrench>, ResidualModel, DataFrame) {
        let (ids, rows, residuals) = training(n);
        let options = ResidualOptions {
            inducing_points,
            ..ResidualOptions::default()
        };
        let fitted = ResidualModel::fit(
            &FeatureLayout::joint_load(),
            &features_of(&rows),
            &residuals,
            &options,
        )
        .expect("fit");
        let training = TrainingRows {
            model: ModelName::EgResidual,
            ids: &ids,
            rows: &rows,
            residuals_mm: &residuals,
        };
        let df = to_frame(&[(training, &fitted)]);
        (rows, fitted, df)
    }

    /// Written and read back, the model predicts what the fitted one does,
    /// exact and sparse.
    #[test]
    fn the_table_rebuilds_the_same_posterior() {
        for inducing_points in [256, 40] {
            let (rows, fitted, df) = fitted_table(120, inducing_points);
            let at = features_of(&rows[..10]);
            let path = Path::new("residual_model.parquet");
            let read = model_of(&df, path, ModelName::EgResidual)
                .expect("read")
                .expect("rows of eg_residual");
            assert_eq!(read.inducing_points(), fitted.inducing_points());
            let expected = fitted.predict(&at).expect("predict");
            for (a, b) in read.predict(&at).expect("predict").iter().zip(&expected) {
                for axis in 0..3 {
                    assert!((a.mean_mm[axis] - b.mean_mm[axis]).abs() < 1e-9);
                }
                assert!((a.latent_variance_mm2 - b.latent_variance_mm2).abs() < 1e-9);
            }
            assert!(
                model_of(&df, path, ModelName::EgHarmonic)
                    .expect("read")
                    .is_none()
            );
        }
    }

    /// A hyperparameter that changes between rows is refused, naming its row.
    #[test]
    fn a_hyperparameter_that_differs_between_rows_is_refused() {
        let (_, _, mut df) = fitted_table(40, 256);
        let mut noise = f64_values(&df, "noise_variance_mm2", Path::new("t")).expect("noise");
        noise[7] *= 2.0;
        df.replace(
            "noise_variance_mm2",
            Column::new("noise_variance_mm2".into(), noise),
        )
        .expect("replace");
        let error = model_of(&df, Path::new("r.parquet"), ModelName::EgResidual)
            .expect_err("refused")
            .to_string();
        assert!(
            error.contains("noise_variance_mm2") && error.contains("r.parquet"),
            "{error}"
        );
    }
}
