//! `predict`: the forward model over a table of conf-wrench rows — SMR position,
//! load torques and deflections per row, for one model of a parameters table (or
//! the robot file's nominal values when no parameters table is bound).
//!
//! With the optional `covariance` input (identify's), also the predicted
//! position's uncertainty J·Σ·Jᵀ (spec §7, [`crate::calibration::uncertainty`]):
//! columns `cov_xx_mm2 … cov_zz_mm2`, null when the model identifies nothing
//! (nominal); without the input the columns are left out.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, bound_covariance, commanded_rows, covariance_binding_problem, covariance_columns,
    model_name_problem, model_set, row_covariances,
};
use crate::robot::{ParamValues, batch_predict};
use crate::table::frame;
use crate::table::parameters::ModelName;
use crate::table::schema::{self, DEFLECTION_COLUMNS, POSITION_COLUMNS, TORQUE_COLUMNS};
use polars::prelude::Column;

pub struct PredictStage;

/// Settings of `predict`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PredictSettings {
    /// Which model of the `parameters` input to use: nominal, registered, kinematic
    /// or elastogeometric. Ignored when no parameters table is bound (nominal).
    pub model: String,
}

impl Default for PredictSettings {
    fn default() -> Self {
        PredictSettings {
            model: ModelName::Elastogeometric.as_str().to_string(),
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "predict",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Forward model: SMR position, load torques and deflections for conf-wrench rows",
    code_version: 5,
    inputs: &[
        TableSlot {
            name: "conf_wrenches",
            schema: schema::conf_wrenches,
            required: true,
            meaning: "rows with cw_id, q1_deg..q6_deg and the six wrench columns",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: false,
            meaning: "parameter sets; nominal when absent",
        },
        super::COVARIANCE_INPUT,
        super::residual_rung::RESIDUAL_INPUT,
    ],
    outputs: &[TableSlot {
        name: "predictions",
        schema: schema::predictions,
        required: true,
        meaning: "cw_id, x_mm..z_mm, tau1_nm..tau6_nm, dq1_deg..dq6_deg, cov_xx_mm2..cov_zz_mm2 with a covariance",
    }],
};

impl Stage for PredictStage {
    type Settings = PredictSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &PredictSettings,
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
        settings: &PredictSettings,
    ) -> Result<StageOutputs, StageError> {
        let set = model_set(ctx, "parameters", "model", &settings.model)?;
        let values = set
            .as_ref()
            .map_or_else(|| ParamValues::nominal(ctx.robot.spec()), |set| set.values);
        let input = ctx.input("conf_wrenches")?;
        let (ids, mut rows) = commanded_rows(ctx, input)?;
        if let Some(set) = &set {
            super::aim_rows(input, set, &mut rows)?;
        }
        let mut predictions = batch_predict(ctx.robot, &values, &rows);
        let residual = match &set {
            Some(set) => super::residual_rung::add_mean(ctx, set, &rows, &mut predictions)?,
            None => None,
        };
        let mut columns = vec![Column::new("cw_id".into(), ids)];
        for (axis, name) in POSITION_COLUMNS.iter().enumerate() {
            let v: Vec<f64> = predictions.iter().map(|p| p.position_mm[axis]).collect();
            columns.push(Column::new((*name).into(), v));
        }
        // A prismatic joint's load is a force (N) and its deflection mm.
        let prismatic = ctx.robot.prismatic_joints();
        let named = |joint: usize, revolute: &[&'static str; 6], slide: &[&'static str; 6]| {
            if prismatic[joint] {
                slide[joint]
            } else {
                revolute[joint]
            }
        };
        for joint in 0..TORQUE_COLUMNS.len() {
            let name = named(joint, &TORQUE_COLUMNS, &schema::FORCE_COLUMNS);
            let v: Vec<f64> = predictions.iter().map(|p| p.torques_nm[joint]).collect();
            columns.push(Column::new(name.into(), v));
        }
        for joint in 0..DEFLECTION_COLUMNS.len() {
            let name = named(
                joint,
                &DEFLECTION_COLUMNS,
                &schema::SLIDE_DEFLECTION_COLUMNS,
            );
            let v: Vec<f64> = predictions
                .iter()
                .map(|p| p.deflections_deg[joint])
                .collect();
            columns.push(Column::new(name.into(), v));
        }
        if let Some(set) = &set
            && let Some(covariance) = bound_covariance(ctx, set)?
        {
            let mut covariances = row_covariances(ctx, set, covariance.as_ref(), &rows);
            if let Some((_, extra)) = &residual {
                super::residual_rung::add_variance(&mut covariances, extra);
            }
            columns.extend(covariance_columns(&covariances));
        }
        let mut outputs = StageOutputs::default();
        outputs.tables.insert("predictions".into(), frame(columns));
        outputs.facts.insert("rows".into(), rows.len().to_string());
        Ok(outputs)
    }
}
