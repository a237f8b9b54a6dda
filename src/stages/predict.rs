//! `predict`: the forward model over a table of conf-wrench rows — SMR position,
//! load torques and deflections per row, for one model of a parameters table (or
//! the robot file's nominal values when no parameters table is bound).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, commanded_rows, model_name_problem, model_values,
};
use crate::robot::batch_predict;
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
    code_version: 1,
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
    ],
    outputs: &[TableSlot {
        name: "predictions",
        schema: schema::predictions,
        required: true,
        meaning: "cw_id, x_mm..z_mm, tau1_nm..tau6_nm, dq1_deg..dq6_deg",
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
        _: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        model_name_problem("model", &settings.model)
            .into_iter()
            .collect()
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &PredictSettings,
    ) -> Result<StageOutputs, StageError> {
        let values = model_values(ctx, "parameters", "model", &settings.model)?;
        let input = ctx.input("conf_wrenches")?;
        let (ids, rows) = commanded_rows(ctx, input)?;
        let predictions = batch_predict(ctx.robot, &values, &rows);
        let mut columns = vec![Column::new("cw_id".into(), ids)];
        for (axis, name) in POSITION_COLUMNS.iter().enumerate() {
            let v: Vec<f64> = predictions.iter().map(|p| p.position_mm[axis]).collect();
            columns.push(Column::new((*name).into(), v));
        }
        for (joint, name) in TORQUE_COLUMNS.iter().enumerate() {
            let v: Vec<f64> = predictions.iter().map(|p| p.torques_nm[joint]).collect();
            columns.push(Column::new((*name).into(), v));
        }
        for (joint, name) in DEFLECTION_COLUMNS.iter().enumerate() {
            let v: Vec<f64> = predictions
                .iter()
                .map(|p| p.deflections_deg[joint])
                .collect();
            columns.push(Column::new((*name).into(), v));
        }
        let mut outputs = StageOutputs::default();
        outputs.tables.insert("predictions".into(), frame(columns));
        outputs.facts.insert("rows".into(), rows.len().to_string());
        Ok(outputs)
    }
}
