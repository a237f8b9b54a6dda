//! `accuracy`: how close the robot came to its targets. Compares the tool points
//! measured while the robot ran a set of commands (a `measure` stage whose rows'
//! `cw_id` is the `target_id`) with the targets, and, when the same targets were
//! also run without compensation (`baseline`), both, on the same targets. This is
//! the closed loop of a compensation: the number a user buys a calibration for.

use std::collections::HashMap;

use nalgebra::Vector3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::identify::measured_rows;
use super::{InputTable, Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot};
use crate::stats;
use crate::table::frame;
use crate::table::schema::{self, POSITION_COLUMNS, f64_values, i64_values};

pub struct AccuracyStage;

/// Settings of `accuracy` (none: the runs are its inputs).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct AccuracySettings {}

static INFO: StageInfo = StageInfo {
    kind: "accuracy",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Position errors the robot achieved at its targets, with and without compensation",
    code_version: 1,
    inputs: &[
        TableSlot {
            name: "targets",
            schema: schema::targets,
            required: true,
            meaning: "where the tool had to be (world frame)",
        },
        TableSlot {
            name: "achieved",
            schema: schema::measurements,
            required: true,
            meaning: "tool points measured while running the commands; cw_id = target_id",
        },
        TableSlot {
            name: "baseline",
            schema: schema::measurements,
            required: false,
            meaning: "the same targets run without compensation (the controller's nominal IK)",
        },
    ],
    outputs: &[
        TableSlot {
            name: "target_errors",
            schema: schema::target_errors,
            required: true,
            meaning: "per target and run: error components and norm",
        },
        TableSlot {
            name: "target_stats",
            schema: schema::target_stats,
            required: true,
            meaning: "per run: n, missing, mean, std, median, rms, p95, max",
        },
    ],
};

impl Stage for AccuracyStage {
    type Settings = AccuracySettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(&self, ctx: &StageContext, _: &AccuracySettings) -> Result<StageOutputs, StageError> {
        let targets = target_points(ctx.input("targets")?)?;
        let mut runs = vec![("achieved", ctx.input("achieved")?)];
        if let Some(baseline) = ctx.inputs.get("baseline") {
            runs.push(("baseline", baseline));
        }
        let mut errors = ErrorColumns::default();
        let mut outputs = StageOutputs::default();
        let mut stats_columns = StatsColumns::default();
        for (run, table) in runs {
            let norms = run_errors(run, table, &targets, &mut errors)?;
            let summary = stats::summary(&norms).map_err(|e| {
                StageError::Invalid(format!(
                    "{}: {run}: {e} (rows whose cw_id is a target_id)",
                    table.path.display()
                ))
            })?;
            let missing = targets.len() - norms.len();
            stats_columns.push(run, &summary, missing);
            outputs.facts.insert(
                format!("{run}_mean_mm"),
                format!("{:.4} over {} targets", summary.mean, summary.n),
            );
            ctx.progress.note(&format!(
                "{run}: mean {:.4} mm, max {:.4} mm over {} targets ({missing} missing)",
                summary.mean, summary.max, summary.n
            ));
        }
        outputs
            .tables
            .insert("target_errors".into(), errors.into_frame());
        outputs
            .tables
            .insert("target_stats".into(), stats_columns.into_frame());
        Ok(outputs)
    }
}

/// Target id → target point (world frame, mm).
fn target_points(table: &InputTable) -> Result<HashMap<i64, Vector3<f64>>, StageError> {
    let ids = i64_values(&table.df, "target_id", &table.path)?;
    let axes = POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(ids
        .iter()
        .enumerate()
        .map(|(k, id)| (*id, Vector3::new(axes[0][k], axes[1][k], axes[2][k])))
        .collect())
}

/// Appends one run's errors; returns their norms. A measured row whose cw_id is
/// no target is bad input: the run was not of these targets.
fn run_errors(
    run: &'static str,
    table: &InputTable,
    targets: &HashMap<i64, Vector3<f64>>,
    errors: &mut ErrorColumns,
) -> Result<Vec<f64>, StageError> {
    let rows = measured_rows(table, None)?;
    let mut norms = Vec::with_capacity(rows.ids.len());
    for (k, id) in rows.ids.iter().enumerate() {
        let target = targets.get(id).ok_or_else(|| {
            StageError::Invalid(format!(
                "{}: row {} has cw_id {id}, which is no target_id of the targets table",
                table.path.display(),
                rows.file_rows[k]
            ))
        })?;
        let error = rows.positions[k] - target;
        errors.target_id.push(*id);
        errors.run.push(run);
        errors.ex.push(error.x);
        errors.ey.push(error.y);
        errors.ez.push(error.z);
        errors.norm.push(error.norm());
        norms.push(error.norm());
    }
    Ok(norms)
}

#[derive(Default)]
struct ErrorColumns {
    target_id: Vec<i64>,
    run: Vec<&'static str>,
    ex: Vec<f64>,
    ey: Vec<f64>,
    ez: Vec<f64>,
    norm: Vec<f64>,
}

impl ErrorColumns {
    fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("target_id".into(), self.target_id),
            Column::new("run".into(), self.run),
            Column::new("ex_mm".into(), self.ex),
            Column::new("ey_mm".into(), self.ey),
            Column::new("ez_mm".into(), self.ez),
            Column::new("error_mm".into(), self.norm),
        ])
    }
}

#[derive(Default)]
struct StatsColumns {
    run: Vec<&'static str>,
    n: Vec<i64>,
    missing: Vec<i64>,
    summaries: Vec<stats::Summary>,
}

impl StatsColumns {
    fn push(&mut self, run: &'static str, summary: &stats::Summary, missing: usize) {
        self.run.push(run);
        self.n.push(summary.n as i64);
        self.missing.push(missing as i64);
        self.summaries.push(*summary);
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        let column = |name: &str, value: fn(&stats::Summary) -> f64| {
            Column::new(
                name.into(),
                self.summaries.iter().map(value).collect::<Vec<_>>(),
            )
        };
        frame(vec![
            Column::new("run".into(), self.run),
            Column::new("n".into(), self.n),
            Column::new("missing".into(), self.missing),
            column("mean_mm", |s| s.mean),
            column("std_mm", |s| s.std),
            column("median_mm", |s| s.median),
            column("rms_mm", |s| s.rms),
            column("p95_mm", |s| s.p95),
            column("max_mm", |s| s.max),
        ])
    }
}
